//! White furnace: a closed box of uniform albedo ρ, lit uniformly. Every ray from a wall lands on a
//! wall, so `k` bounces return `ρ(1−ρ^k)/(1−ρ)` of the direct light as indirect irradiance and all
//! bounces `ρ/(1−ρ)` (docs/design.md §1). Runs the real voxeliser, ray caster and transport.

use bounce_core::formfactor::{RayScene, form_factors, stats};
use bounce_core::meta::Bounces;
use bounce_core::scene::{Scene, Triangle};
use bounce_core::tail::Clusters;
use bounce_core::transport::{Tail, choose_channels, transport};
use bounce_core::voxel::{Resolution, voxelize};
use glam::Vec3;

fn no_progress(_: u64) {}

/// An axis-aligned box `[0, size]³` whose one-sided walls face inwards.
pub(crate) fn closed_box(size: f32, albedo: f32) -> Scene {
    let mut triangles = Vec::new();
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z) * size;
    // Each wall as four corners; the winding is fixed below so that every normal points inwards.
    let walls = [
        [c(0., 0., 0.), c(1., 0., 0.), c(1., 0., 1.), c(0., 0., 1.)], // floor, +Y
        [c(0., 1., 0.), c(0., 1., 1.), c(1., 1., 1.), c(1., 1., 0.)], // ceiling, −Y
        [c(0., 0., 0.), c(0., 0., 1.), c(0., 1., 1.), c(0., 1., 0.)], // x = 0, +X
        [c(1., 0., 0.), c(1., 1., 0.), c(1., 1., 1.), c(1., 0., 1.)], // x = 1, −X
        [c(0., 0., 0.), c(0., 1., 0.), c(1., 1., 0.), c(1., 0., 0.)], // z = 0, +Z
        [c(0., 0., 1.), c(1., 0., 1.), c(1., 1., 1.), c(0., 1., 1.)], // z = 1, −Z
    ];
    for w in walls {
        for mut tri in [[w[0], w[1], w[2]], [w[0], w[2], w[3]]] {
            let inward = Vec3::splat(size * 0.5) - (tri[0] + tri[1] + tri[2]) / 3.0;
            if (tri[1] - tri[0]).cross(tri[2] - tri[0]).dot(inward) < 0.0 {
                tri.swap(1, 2);
            }
            triangles.push(Triangle {
                positions: tri,
                albedo: Vec3::splat(albedo),
                emission: Vec3::ZERO,
                double_sided: false,
                material: 0,
            });
        }
    }
    Scene {
        triangles,
        ..Default::default()
    }
}

#[test]
fn white_furnace_k_bounces_and_all() {
    for (rho, size) in [(0.5f32, 1.0f32), (0.8, 3.0)] {
        let scene = closed_box(size, rho);
        let vox = voxelize(&scene, Resolution::TargetPatches(300)).unwrap();
        let layout = &vox.layout;
        let n = layout.len();
        assert!((200..450).contains(&n), "{n} patches");
        for p in &layout.patches {
            assert!((p.albedo[0] - rho).abs() < 1e-5);
        }
        let rays = RayScene::new(&layout.quads(), &vox.occluders);
        let (f, tally) = form_factors(&rays, 1024, 7, &no_progress).unwrap();
        assert_eq!(
            tally.patch,
            tally.total(),
            "a closed box loses no ray: {tally:?}"
        );
        let st = stats(&f, &vec![layout.patch_area(); n]);
        assert!(st.row_sum_max <= 1.0 + 1e-5, "{st:?}");
        assert!(st.row_sum_min > 0.999, "the voxel box leaks: {st:?}");

        let albedo: Vec<[f32; 3]> = layout.patches.iter().map(|p| p.albedo).collect();
        let direct = 1.0f32; // uniform direct irradiance on every patch
        let b0: Vec<f32> = albedo.iter().map(|a| a[0] * direct).collect();
        let r = rho as f64;
        let clusters = Clusters::of_layout(layout, &f);
        assert!(
            clusters.len() < n,
            "{} clusters of {n} rows",
            clusters.len()
        );
        for (bounces, tail, want) in [
            (Bounces::K(1), Tail::Exact, r),
            (
                Bounces::K(2),
                Tail::Exact,
                r * (1.0 - r.powi(2)) / (1.0 - r),
            ),
            (
                Bounces::K(4),
                Tail::Exact,
                r * (1.0 - r.powi(4)) / (1.0 - r),
            ),
            (Bounces::All, Tail::Exact, r / (1.0 - r)),
            (Bounces::All, Tail::Clustered(&clusters), r / (1.0 - r)),
        ] {
            let channels = choose_channels(&f, &albedo, bounces, &[], 0.0)
                .unwrap()
                .channels;
            let t = transport(&f, &albedo, bounces, tail, channels, &no_progress).unwrap();
            assert_eq!(t.channels, 1, "grey albedo needs one channel");
            for i in 0..n {
                let e: f64 = (0..n).map(|j| t.get(0, i, j) as f64 * b0[j] as f64).sum();
                let rel = (e - want).abs() / want;
                assert!(
                    rel < 0.01,
                    "ρ={rho} {bounces} {tail:?}: patch {i} gets {e}, want {want}"
                );
            }
        }
    }
}
