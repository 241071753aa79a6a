//! Every scene in the repository's `assets/` bakes end to end at a small size: patches near the
//! target, form-factor rows never above 1, and a finite, non-negative transport.

use std::path::Path;

use bounce_core::bake::{BakeOptions, NoProgress, bake_file};
use bounce_core::meta::Bounces;
use bounce_core::voxel::Resolution;

#[test]
fn every_repository_scene_bakes() {
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
    assert!(
        scenes.is_dir(),
        "the repository's scenes missing at {}",
        scenes.display()
    );
    let files = [
        "cornell-box/scene.gltf",
        "cornell-box-emissive/CornellBox.glb",
        "pandora/pandora.glb",
        "room-with-objects/room.glb",
        "sheen-chair-sun/MixedLightingExample.gltf",
        "small-room/IrradianceVolumeExample.glb",
    ];
    // A scene added to assets/ is baked here too: the list must name every folder.
    let mut folders: Vec<String> = std::fs::read_dir(&scenes)
        .unwrap()
        .map(|e| e.unwrap())
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    folders.sort();
    let mut listed: Vec<&str> = files.iter().filter_map(|f| f.split('/').next()).collect();
    listed.sort();
    assert_eq!(
        folders, listed,
        "every folder of assets/ is a scene this test bakes"
    );
    for file in files {
        let options = BakeOptions {
            resolution: Resolution::TargetPatches(300),
            rays: 128,
            bounces: Bounces::K(2),
            ..BakeOptions::default()
        };
        let baked = bake_file(&scenes.join(file), &options, &NoProgress)
            .unwrap_or_else(|e| panic!("{file}: {e}"));
        let s = &baked.meta.stats;
        assert!(
            (200..=420).contains(&s.patches),
            "{file}: {} patches for a target of 300",
            s.patches
        );
        assert!(s.row_sum_max <= 1.0 + 1e-5, "{file}: {s:?}");
        assert_eq!(s.rays.total(), s.rays_total, "{file}: every ray tallied");
        let t = baked.transport.decode().unwrap();
        assert!(
            t.data.iter().all(|v| v.is_finite() && *v >= 0.0),
            "{file}: transport has a negative or non-finite entry"
        );
        // The transport's rows are the elements (at least one a patch).
        assert_eq!(t.n, baked.transport_layout().len());
        assert_eq!(t.n, s.elements);
        assert!(t.n >= s.patches);
        assert!(baked.layout.patches.iter().all(|p| {
            p.albedo.iter().all(|a| (0.0..=1.0).contains(a))
                && (glam::Vec3::from(p.normal).length() - 1.0).abs() < 1e-3
        }));
    }
}
