//! The triangle tracer against a scan of every triangle: on a real level (`pandora`, 60,694
//! triangles), rays leaving its surfaces as form-factor and shadow rays do must meet the same
//! nearest crossing, and be blocked exactly when some triangle blocks them.

use std::path::Path;

use bounce_core::direct::hash_u32;
use bounce_core::import::import_path;
use bounce_core::trimesh::{MeshTri, TriMesh, extent_of, intersect, offset_origin};
use glam::Vec3;

fn unit(bits: u32) -> f32 {
    (bits >> 8) as f32 / (1u32 << 24) as f32
}

/// The nearest crossing over every triangle, by the tracer's own triangle test.
fn scan(tris: &[MeshTri], origin: Vec3, dir: Vec3, t_max: f32) -> Option<f32> {
    tris.iter()
        .filter_map(|t| intersect(t, origin, dir, t_max))
        .min_by(f32::total_cmp)
}

#[test]
fn nearest_crossings_and_shadows_match_a_scan_of_every_triangle() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/pandora/pandora.glb");
    let scene = import_path(&path).expect("pandora imports");
    let mesh = TriMesh::new(
        scene
            .triangles
            .iter()
            .map(|t| (t.positions, t.double_sided)),
    );
    let corners: Vec<Vec3> = scene.triangles.iter().flat_map(|t| t.positions).collect();
    let extent = extent_of(&corners);
    let tris = mesh.triangles();
    let (mut hits, mut blocked) = (0, 0);
    let rays = 1500u32;
    for k in 0..rays {
        let h = |d: u32| unit(hash_u32(k.wrapping_mul(7919).wrapping_add(d)));
        let tri = &scene.triangles[(hash_u32(k) as usize) % scene.triangles.len()];
        let [a, b, c] = tri.positions;
        let (mut u, mut v) = (h(1), h(2));
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let n = tri.cross().normalize_or_zero();
        if n == Vec3::ZERO {
            continue;
        }
        // Either side, a direction into that side's hemisphere.
        let side = if h(3) < 0.5 { n } else { -n };
        let p = offset_origin(a + (b - a) * u + (c - a) * v, side, extent);
        let mut dir = Vec3::new(h(4) - 0.5, h(5) - 0.5, h(6) - 0.5).normalize_or_zero();
        if dir.dot(side) < 0.0 {
            dir = -dir;
        }
        if dir == Vec3::ZERO {
            continue;
        }
        let expected = scan(tris, p, dir, f32::INFINITY);
        let found = mesh.closest(p, dir, f32::INFINITY).map(|hit| hit.t);
        assert_eq!(found, expected, "ray {k}: nearest crossing");
        hits += usize::from(expected.is_some());
        // A shadow ray to a point part-way along: blocked exactly when a scan finds a crossing.
        let reach = expected.map_or(extent, |t| t * 2.0 * h(7));
        let shadowed = scan(tris, p, dir, reach).is_some();
        assert_eq!(mesh.occluded(p, dir, reach), shadowed, "ray {k}: shadow");
        blocked += usize::from(shadowed);
    }
    // The rays are not trivial: most meet a surface, and about half the shadow rays are blocked.
    assert!(hits > rays as usize * 6 / 10, "{hits} of {rays} rays hit");
    assert!(
        blocked > rays as usize / 4 && blocked < rays as usize * 3 / 4,
        "{blocked} blocked"
    );
}
