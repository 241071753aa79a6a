//! The voxel-grid tracer against the BVH tracer on the same patches: the two must agree on where
//! rays go (they may differ only on exact edge and corner hits), so either can estimate `F`.

use std::path::Path;

use bounce_core::formfactor::{RayScene, Tracer, form_factors, isolated_patches};
use bounce_core::import::import_path;
use bounce_core::voxel::{Resolution, voxelize};

fn no_progress(_: u64) {}

fn compare(scene_path: &Path, patches: u32, rays: u32) {
    let scene = import_path(scene_path).expect("scene imports");
    let mut vox = voxelize(&scene, Resolution::TargetPatches(patches)).unwrap();
    let probe = RayScene::voxels(&vox.layout, &vox.occupied, &vox.occluders, Tracer::Grid);
    let isolated = isolated_patches(&probe, 64, 1);
    vox.drop_patches(&isolated, &[]);

    let grid = RayScene::voxels(&vox.layout, &vox.occupied, &vox.occluders, Tracer::Grid);
    let bvh = RayScene::voxels(&vox.layout, &vox.occupied, &vox.occluders, Tracer::Bvh);
    assert_eq!(grid.tracer(), Tracer::Grid);
    assert_eq!(bvh.tracer(), Tracer::Bvh);
    let (fg, tg) = form_factors(&grid, rays, 5, &no_progress).unwrap();
    let (fb, tb) = form_factors(&bvh, rays, 5, &no_progress).unwrap();

    let total = tg.total() as f64;
    for (what, a, b) in [
        ("patch", tg.patch, tb.patch),
        ("escaped", tg.escaped, tb.escaped),
        ("occluder", tg.occluder, tb.occluder),
    ] {
        let diff = (a as f64 - b as f64).abs() / total;
        assert!(diff < 1e-3, "{what}: grid {a} vs bvh {b} of {total}");
    }
    assert_eq!(tg.back_face, 0, "the grid walks only through empty voxels");

    // Entry by entry: a ray that lands on an edge may go to either neighbour, so a few entries
    // differ by a ray or two; the matrices must otherwise be the same.
    let n = fg.n;
    let step = 1.0 / rays as f32;
    let mut differing = 0usize;
    for (a, b) in fg.data.iter().zip(&fb.data) {
        if a != b {
            differing += 1;
            assert!((a - b).abs() <= 4.0 * step + 1e-6, "{a} vs {b}");
        }
    }
    let nonzero = fg.data.iter().filter(|&&v| v > 0.0).count();
    assert!(
        (differing as f64) < 0.01 * nonzero as f64,
        "{differing} of {nonzero} nonzero entries differ ({n} patches)"
    );
}

#[test]
fn grid_and_bvh_agree_on_the_cornell_box() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box/scene.gltf");
    compare(&path, 300, 512);
}

#[test]
fn grid_and_bvh_agree_on_pandora() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/pandora/pandora.glb");
    assert!(path.exists(), "pandora missing at {}", path.display());
    compare(&path, 400, 256);
}
