//! Emissive surfaces as run-time lights (`bounce_core::emitter`): the bake's per-row weights
//! give back the rows' baked emission, a light set's change moves exactly the rows the material
//! covers, and the weights survive the baked file and the sharded bake.

use std::path::{Path, PathBuf};

use bounce_core::bake::{BakeOptions, NoProgress, bake_scene, simplify};
use bounce_core::emitter::{Emitters, apply_to_scene, check_names, materials_of, nodes_of};
use bounce_core::format::Baked;
use bounce_core::import::import_path;
use bounce_core::light::LightSet;
use bounce_core::meta::Bounces;
use bounce_core::voxel::Resolution;
use glam::Vec3;

const LAMP: &str = "Emitter_Light_temp";

fn box_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box-emissive/CornellBox.glb")
}

fn options() -> BakeOptions {
    BakeOptions {
        resolution: Resolution::TargetPatches(300),
        rays: 128,
        bounces: Bounces::K(2),
        ..BakeOptions::default()
    }
}

fn set(json: &str) -> LightSet {
    LightSet::from_json(json).unwrap()
}

#[test]
fn weights_give_back_each_rows_baked_emission() {
    let scene = import_path(&box_path()).unwrap();
    let vox = simplify(&scene, &options()).unwrap();
    let pieces = vox
        .pieces
        .as_ref()
        .expect("surface geometry keeps its pieces");
    let rows = vox.transport_layout();
    let e = Emitters::of_pieces(&scene, pieces);
    e.check(rows.len()).unwrap();
    assert_eq!(materials_of(&e.names()), vec![LAMP.to_string()]);
    assert_eq!(e.groups[0].color, [1.0; 3]);
    assert_eq!(e.groups[0].strength, 100.0);
    let covered = (0..rows.len()).filter(|&r| !e.row(r).is_empty()).count();
    assert!(covered > 0, "the ceiling lamp covers some rows");
    for (r, p) in rows.patches.iter().enumerate() {
        let mut sum = Vec3::ZERO;
        for entry in e.row(r) {
            sum += Vec3::from(entry.weight) * e.groups[entry.group as usize].emission();
        }
        let baked = Vec3::from(p.emission);
        assert!(
            (sum - baked).abs().max_element() <= 1e-4 * baked.max_element().max(1.0),
            "row {r}: weights give {sum}, the bake {baked}"
        );
        // The lamp is untextured: one weight for all channels, a share of the row's area.
        for entry in e.row(r) {
            assert!(entry.weight[0] > 0.0 && entry.weight[0] <= 1.0 + 1e-6);
            assert_eq!(entry.weight[0], entry.weight[1]);
        }
    }

    // A change moves only the covered rows, linearly, and colour and strength compose.
    let base: Vec<[f32; 3]> = rows.patches.iter().map(|p| p.emission).collect();
    let emission = |json: &str| {
        e.emission(base.iter().copied(), &set(json))
            .unwrap()
            .expect("the set changes the lamp")
    };
    let off = emission(
        r#"{"lights":[{"type":"emissive","material":"Emitter_Light_temp","strength":0}]}"#,
    );
    assert!(
        off.iter().flatten().all(|&v| v == 0.0),
        "the box's only emitter off"
    );
    let red = emission(
        r#"{"lights":[{"type":"emissive","material":"Emitter_Light_temp","color":[1,0,0],"strength":50}]}"#,
    );
    for (r, (new, old)) in red.iter().zip(&base).enumerate() {
        let want = [old[0] * 0.5, 0.0, 0.0];
        for c in 0..3 {
            assert!(
                (new[c] - want[c]).abs() <= 1e-4 * old[0].max(1.0),
                "row {r}: {new:?} against {want:?}"
            );
        }
    }
    // A set that changes nothing leaves the bake's emission to the caller.
    let point = set(r#"{"lights":[{"type":"point","position":[278,500,278],"intensity":1}]}"#);
    assert_eq!(e.emission(base.iter().copied(), &point).unwrap(), None);

    // Unknown names are refused naming the light, the material and what the scene has.
    let wrong = set(
        r#"{"lights":[{"type":"sky","color":[1,1,1]},{"type":"emissive","material":"Lamp","strength":2}]}"#,
    );
    let err = e.resolve(&wrong).unwrap_err().to_string();
    assert_eq!(
        err,
        format!(
            "lights[1].material: the scene has no emissive material 'Lamp' (its emissive \
             materials: {LAMP}; on nodes: Light)"
        )
    );
    assert_eq!(
        check_names(Some(&e.names()), &wrong)
            .unwrap_err()
            .to_string(),
        err
    );
    let err = check_names(None, &wrong).unwrap_err().to_string();
    assert!(
        err.starts_with("lights[1].material: this baked file lists no emitters"),
        "{err}"
    );

    // The reference's scene: the lamp's triangles at the new emission, the rest as they were.
    let mut changed = scene.clone();
    apply_to_scene(
        &mut changed,
        &set(r#"{"lights":[{"type":"emissive","material":"Emitter_Light_temp","color":[0,0,1]}]}"#),
    )
    .unwrap();
    for (a, b) in scene.triangles.iter().zip(&changed.triangles) {
        if scene.materials[a.material as usize].name == LAMP {
            assert_eq!(b.emission, Vec3::new(0.0, 0.0, 100.0));
        } else {
            assert_eq!(a.emission, b.emission);
        }
    }
    assert!(apply_to_scene(&mut changed, &wrong).is_err());
}

#[test]
fn a_baked_file_keeps_its_emitters_and_a_bake_without_emission_has_none() {
    let scene = import_path(&box_path()).unwrap();
    let baked = bake_scene(&scene, "CornellBox.glb", &options(), &NoProgress).unwrap();
    let e = baked
        .emitters
        .as_ref()
        .expect("a surface bake lists its emitters");
    assert_eq!(materials_of(&e.names()), vec![LAMP.to_string()]);
    let back = Baked::from_bytes(&baked.to_bytes().unwrap()).unwrap();
    assert_eq!(back.emitters, baked.emitters);

    let plain = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box/scene.gltf");
    let plain = bake_scene(
        &import_path(&plain).unwrap(),
        "scene.gltf",
        &options(),
        &NoProgress,
    )
    .unwrap();
    let none = plain
        .emitters
        .as_ref()
        .expect("an empty list, not a missing one");
    assert!(none.groups.is_empty() && none.entries.is_empty());
}

#[test]
fn emitters_sharing_a_material_are_changed_apart_by_node() {
    let dir = tempfile::tempdir().unwrap();
    let scene = import_path(&bounce_testkit::scenes::two_lamps(dir.path())).unwrap();
    // One material entry per (emissive material, node): the lamp's own for its first node.
    let lamps: Vec<(usize, Option<&str>)> = scene
        .materials
        .iter()
        .enumerate()
        .filter(|(_, m)| m.name == LAMP)
        .map(|(i, m)| (i, m.node.as_deref()))
        .collect();
    assert_eq!(lamps, vec![(0, Some("Light")), (5, Some("Lamp 2"))]);
    assert!(
        scene.materials[1..5].iter().all(|m| m.node.is_none()),
        "materials that emit nothing are one entry whatever places them"
    );

    let baked = bake_scene(&scene, "two-lamps.glb", &options(), &NoProgress).unwrap();
    let e = baked.emitters.as_ref().unwrap();
    assert_eq!(materials_of(&e.names()), vec![LAMP.to_string()]);
    let mut nodes = nodes_of(&e.names());
    nodes.sort();
    assert_eq!(nodes, vec!["Lamp 2", "Light"]);
    let back = Baked::from_bytes(&baked.to_bytes().unwrap()).unwrap();
    assert_eq!(back.emitters, baked.emitters, "the nodes survive the file");

    let rows = baked.transport_layout();
    let base: Vec<[f32; 3]> = rows.patches.iter().map(|p| p.emission).collect();
    let emission = |json: &str| {
        e.emission(base.iter().copied(), &set(json))
            .unwrap()
            .unwrap()
    };
    let off = |what: &str| {
        emission(&format!(
            r#"{{"lights":[{{"type":"emissive",{what},"strength":0}}]}}"#
        ))
    };
    let first_off = off(r#""node":"Light""#);
    let second_off = off(r#""node":"Lamp 2""#);
    let both_off = off(&format!(r#""material":"{LAMP}""#));
    let lit = |v: &[[f32; 3]]| v.iter().filter(|e| e[0] > 0.0).count();
    let (all, first, second) = (lit(&base), lit(&first_off), lit(&second_off));
    assert!(
        first > 0 && second > 0 && first < all && second < all,
        "each lamp covers rows of its own: {all} lit, {first} with the first off, {second} with \
         the second off"
    );
    assert_eq!(lit(&both_off), 0, "the material reaches both lamps");
    // Emission is linear in the groups: each lamp's own light adds up to the whole.
    for r in 0..base.len() {
        for c in 0..3 {
            let sum = first_off[r][c] + second_off[r][c] - both_off[r][c];
            assert!(
                (sum - base[r][c]).abs() <= 1e-4 * base[r][c].max(1.0),
                "row {r}: {sum} against {}",
                base[r][c]
            );
        }
    }
    // The material on one node reaches what that node alone reaches.
    assert_eq!(
        off(&format!(r#""material":"{LAMP}","node":"Lamp 2""#)),
        second_off
    );
    // A later change wins where two reach the same lamp.
    let both = emission(&format!(
        r#"{{"lights":[{{"type":"emissive","material":"{LAMP}","strength":0}},
                       {{"type":"emissive","node":"Light","strength":100}}]}}"#
    ));
    assert_eq!(both, second_off);

    // An unknown node is refused naming what the scene has.
    let wrong = set(r#"{"lights":[{"type":"emissive","node":"Desk","strength":2}]}"#);
    let err = e.resolve(&wrong).unwrap_err().to_string();
    assert_eq!(
        err,
        format!(
            "lights[0].node: the scene has no emissive node 'Desk' (its emissive materials: \
             {LAMP}; on nodes: Lamp 2, Light)"
        )
    );
    assert_eq!(
        check_names(Some(&e.names()), &wrong)
            .unwrap_err()
            .to_string(),
        err
    );
    // A file from before nodes: its groups have none, and a change by node says to bake again.
    let mut old = e.clone();
    for g in &mut old.groups {
        g.node = None;
    }
    let err = old.resolve(&wrong).unwrap_err().to_string();
    assert!(
        err.contains("bake it again to change emitters by node"),
        "{err}"
    );

    // The reference's scene: only the second lamp's triangles go dark.
    let mut changed = scene.clone();
    apply_to_scene(
        &mut changed,
        &set(r#"{"lights":[{"type":"emissive","node":"Lamp 2","strength":0}]}"#),
    )
    .unwrap();
    let mut dark = 0;
    for (a, b) in scene.triangles.iter().zip(&changed.triangles) {
        if scene.materials[a.material as usize].node.as_deref() == Some("Lamp 2") {
            assert_eq!(b.emission, Vec3::ZERO);
            dark += 1;
        } else {
            assert_eq!(a.emission, b.emission);
        }
    }
    assert!(dark > 0);
}
