//! `bounce render --indirect only` against an outside renderer, and against light that must not
//! be there.
//!
//! 1. The Cornell box baked at 2,000 surface patches with all bounces, drawn indirect-only to a
//!    PFM (linear radiance), against Mitsuba 3's indirect-only image of the same camera: its
//!    all-bounce path tracer minus its direct-only render (tests/mitsuba/render_indirect.py, which
//!    reads the glTF with its own loader, not bounce's importer). Compared on the pixels where
//!    Mitsuba's ray through the pixel centre meets a surface, as relative L2 over those pixels and
//!    RGB.
//! 2. Two rooms parted by a wall much thinner than a voxel, lit in the left room only: the right
//!    room's indirect light must be essentially zero in the image.
//!
//! `bounce render` needs a GPU adapter (lavapipe will do): without one these fail, unless
//! `BOUNCE_ALLOW_NO_GPU=1` says skipping is intended. The Mitsuba test needs Python with Mitsuba 3
//! (`scripts/test` installs it in the build directory; `bounce_testkit::python` finds it):
//! without it, it fails, unless `BOUNCE_ALLOW_NO_MITSUBA=1` says skipping is intended. CI sets
//! neither; both failures name `scripts/test`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use bounce_core::format::Baked;
use serde_json::{Value, json};

mod common;
use common::{bounce, cornell, gpu_ran, ok, run};

/// The point light of both tests' lights files, in glTF units (candela).
const INTENSITY: f32 = 5.0;

/// Linear RGB pixels, rows top to bottom.
struct Pfm {
    width: usize,
    height: usize,
    pixels: Vec<[f32; 3]>,
}

/// A colour or greyscale PFM (`PF` / `Pf`), either byte order, rows stored bottom to top.
fn read_pfm(path: &Path) -> Pfm {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut fields = Vec::new();
    let mut start = 0;
    for (i, &b) in bytes.iter().enumerate() {
        if b.is_ascii_whitespace() {
            if i > start {
                fields.push(std::str::from_utf8(&bytes[start..i]).unwrap().to_string());
            }
            start = i + 1;
            if fields.len() == 4 {
                break;
            }
        }
    }
    let channels = match fields[0].as_str() {
        "PF" => 3,
        "Pf" => 1,
        other => panic!("{}: not a PFM ({other:?})", path.display()),
    };
    let width: usize = fields[1].parse().unwrap();
    let height: usize = fields[2].parse().unwrap();
    let little = fields[3].parse::<f32>().unwrap() < 0.0;
    let data = &bytes[start..];
    assert_eq!(
        data.len(),
        width * height * channels * 4,
        "{}",
        path.display()
    );
    let value = |k: usize| {
        let b: [u8; 4] = data[4 * k..4 * k + 4].try_into().unwrap();
        if little {
            f32::from_le_bytes(b)
        } else {
            f32::from_be_bytes(b)
        }
    };
    let mut pixels = Vec::with_capacity(width * height);
    for row in (0..height).rev() {
        for x in 0..width {
            let k = (row * width + x) * channels;
            pixels.push(if channels == 3 {
                [value(k), value(k + 1), value(k + 2)]
            } else {
                [value(k); 3]
            });
        }
    }
    Pfm {
        width,
        height,
        pixels,
    }
}

/// `bounce render` succeeded, or it could not find a GPU adapter and skipping is allowed
/// (`false`: skip the test).
fn rendered(out: &Output) -> bool {
    gpu_ran(out, "bounce render")
}

/// `bounce render SCENE --baked BAKED --lights LIGHTS --indirect MODE` to a PFM at 160×120.
fn render(scene: &Path, baked: &Path, lights: &Path, camera: &str, mode: &str, out: &Path) -> bool {
    rendered(&run(bounce()
        .arg("render")
        .arg(scene)
        .arg("--baked")
        .arg(baked)
        .arg("--lights")
        .arg(lights)
        .args(["--camera", camera, "--indirect", mode])
        .args(["--width", "160", "--height", "120", "--out"])
        .arg(out)))
}

fn point_light(dir: &Path, position: [f32; 3]) -> PathBuf {
    let path = dir.join("lights.json");
    let lights = json!({"lights": [{
        "type": "point", "position": position, "color": [1, 1, 1], "intensity": INTENSITY,
    }]});
    std::fs::write(&path, lights.to_string()).unwrap();
    path
}

fn bake(scene: &Path, out: &Path, args: &[&str]) {
    ok(bounce()
        .arg("bake")
        .arg(scene)
        .arg("-o")
        .arg(out)
        // The exact transport: these tests measure the method, not a codec's error on top.
        .args(["--bounces", "all", "--codec", "dense-f32", "--quiet"])
        .args(args));
}

/// The camera of the Mitsuba comparison: from in front of the box's open side, a little back so
/// that the box's front edges and some background are in view (the mask check needs both).
const CORNELL_EYE: [f32; 3] = [0.0, 1.0, 3.4];
const CORNELL_TARGET: [f32; 3] = [0.0, 1.0, 0.0];
const CORNELL_FOV_Y: f32 = 40.0;

#[test]
fn indirect_only_matches_mitsuba_on_the_cornell_box() {
    let Some(python) = bounce_testkit::mitsuba_python() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let lights = point_light(dir.path(), [0.0, 1.5, 0.0]);
    let baked = dir.path().join("cornell.bounce");
    bake(&cornell(), &baked, &["--patches", "2000", "--rays", "2048"]);
    let camera = [CORNELL_EYE, CORNELL_TARGET]
        .iter()
        .flatten()
        .chain([&CORNELL_FOV_Y])
        .map(f32::to_string)
        .collect::<Vec<_>>()
        .join(",");
    let ours = dir.path().join("bounce.pfm");
    if !render(&cornell(), &baked, &lights, &camera, "only", &ours) {
        return;
    }
    let ours_direct = dir.path().join("bounce-direct.pfm");
    assert!(render(
        &cornell(),
        &baked,
        &lights,
        &camera,
        "off",
        &ours_direct
    ));

    // 4 batches of 1,024 samples a pixel: about 80 s on two cores with the scalar variant,
    // and a reference whose own noise is about 2.6% relative L2.
    let spp: u32 = std::env::var("BOUNCE_MITSUBA_SPP")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1024);
    let mitsuba = dir.path().join("mitsuba");
    let job = json!({
        "gltf": cornell(),
        "lights": [{"position": [0.0, 1.5, 0.0], "intensity": [INTENSITY, INTENSITY, INTENSITY]}],
        "camera": {"eye": CORNELL_EYE, "target": CORNELL_TARGET, "fov_y_deg": CORNELL_FOV_Y},
        "width": 160, "height": 120, "spp": spp, "batches": 4, "out": mitsuba,
    });
    let job_path = dir.path().join("job.json");
    std::fs::write(&job_path, job.to_string()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/mitsuba/render_indirect.py");
    let out = Command::new(&python)
        .arg(&script)
        .arg(&job_path)
        .output()
        .unwrap_or_else(|e| panic!("running {}: {e}", python.display()));
    assert!(
        out.status.success(),
        "Mitsuba failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stats: Value =
        serde_json::from_slice(&std::fs::read(mitsuba.join("stats.json")).unwrap()).unwrap();
    let theirs = read_pfm(&mitsuba.join("indirect.pfm"));
    let theirs_direct = read_pfm(&mitsuba.join("direct.pfm"));
    let mask = read_pfm(&mitsuba.join("mask.pfm"));
    let ours = read_pfm(&ours);
    let ours_direct = read_pfm(&ours_direct);
    assert_eq!((ours.width, ours.height), (theirs.width, theirs.height));
    assert_eq!((mask.width, mask.height), (theirs.width, theirs.height));

    // The same camera: bounce's background (cleared to 0) is where Mitsuba's rays miss. The
    // box's inside has indirect light everywhere, so a surface pixel is never 0 in bounce's.
    let hit: Vec<bool> = mask.pixels.iter().map(|p| p[0] > 0.5).collect();
    let disagree = hit
        .iter()
        .zip(&ours.pixels)
        .filter(|&(&h, p)| h != p.iter().any(|&c| c > 0.0))
        .count();
    let surface = hit.iter().filter(|&&h| h).count();
    eprintln!(
        "{surface} surface pixels of {}; the masks disagree on {disagree}",
        hit.len()
    );
    assert!(surface > hit.len() / 2 && surface < hit.len(), "{surface}");
    // Measured: 4 pixels (rays through cracks between the boxes' triangles).
    assert!(disagree * 200 < hit.len(), "{disagree} pixels");

    let rel_l2 = |a: &Pfm, b: &Pfm| {
        let (mut diff, mut norm) = (0.0f64, 0.0f64);
        for ((pa, pb), _) in a
            .pixels
            .iter()
            .zip(&b.pixels)
            .zip(&hit)
            .filter(|(_, h)| **h)
        {
            for c in 0..3 {
                diff += f64::from(pa[c] - pb[c]).powi(2);
                norm += f64::from(pb[c]).powi(2);
            }
        }
        (diff / norm).sqrt()
    };
    let ratio = |a: &Pfm, b: &Pfm| {
        let sum = |p: &Pfm| -> f64 {
            p.pixels
                .iter()
                .zip(&hit)
                .filter(|(_, h)| **h)
                .map(|(p, _)| p.iter().map(|&c| f64::from(c)).sum::<f64>())
                .sum()
        };
        sum(a) / sum(b)
    };
    let noise = stats["noise"].as_f64().unwrap_or(f64::NAN);
    let rel = rel_l2(&ours, &theirs);
    let mean = ratio(&ours, &theirs);
    let direct = ratio(&ours_direct, &theirs_direct);
    eprintln!(
        "Mitsuba {} ({}, {} triangles from its own glTF loader, {spp}×4 spp, {:.0} s)",
        stats["mitsuba"], stats["variant"], stats["triangles"], stats["seconds"]
    );
    println!(
        "indirect only, Cornell box at 2000 surface patches, 160x120: relative L2 against \
         Mitsuba {:.2}% (Mitsuba's own noise {:.2}%, so about {:.2}% from bounce), mean \
         bounce/Mitsuba {mean:.4}; direct light mean bounce/Mitsuba {direct:.4}",
        rel * 100.0,
        noise * 100.0,
        (rel * rel - noise * noise).max(0.0).sqrt() * 100.0
    );
    // The direct light is the renderer's own (shadow maps), independent of the bake: it checks
    // that both sides light the scene alike (units, camera). Measured 1.008.
    assert!((direct - 1.0).abs() < 0.03, "direct light ratio {direct}");
    // Measured 7.32% with 1,024×4 spp: Mitsuba's own noise is 2.56%, so about 6.9% is bounce's,
    // most of it a uniform deficit of the patches' indirect irradiance (mean ratio 0.948; 0.957
    // at 8,000 patches, where the relative L2 is 6.6%). The volume sampling that blended the
    // three directions a normal leans to measured 7.46%, reading every voxel's own patch alone
    // (no interpolation) 7.90%. The target is 10% at 2,000 patches.
    assert!(rel < 0.09, "relative L2 {rel} (target 0.10)");
    // Measured 0.948.
    assert!((mean - 1.0).abs() < 0.08, "mean ratio {mean}");
}

/// Two rooms in a closed 4 × 2 × 2 box (x from 0 to 4), parted at x = 2 by a wall `thickness`
/// thick made of two single-sided faces back to back; every face faces into its room. Written as
/// `rooms.gltf` + `rooms.bin` in `dir`.
fn two_rooms(dir: &Path, thickness: f32) -> PathBuf {
    let (l, h, d) = (4.0f32, 2.0f32, 2.0f32);
    let (a, b) = (2.0 - thickness / 2.0, 2.0 + thickness / 2.0);
    // Corners counter-clockwise seen from the side the face faces.
    let quads: [[[f32; 3]; 4]; 8] = [
        [[0., 0., 0.], [0., 0., d], [l, 0., d], [l, 0., 0.]], // floor, +Y
        [[0., h, 0.], [l, h, 0.], [l, h, d], [0., h, d]],     // ceiling, −Y
        [[0., 0., 0.], [l, 0., 0.], [l, h, 0.], [0., h, 0.]], // back, +Z
        [[0., 0., d], [0., h, d], [l, h, d], [l, 0., d]],     // front, −Z
        [[0., 0., 0.], [0., h, 0.], [0., h, d], [0., 0., d]], // left end, +X
        [[l, 0., 0.], [l, 0., d], [l, h, d], [l, h, 0.]],     // right end, −X
        [[a, 0., 0.], [a, 0., d], [a, h, d], [a, h, 0.]],     // wall, left side, −X
        [[b, 0., 0.], [b, h, 0.], [b, h, d], [b, 0., d]],     // wall, right side, +X
    ];
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    for q in &quads {
        let k = (positions.len() / 12) as u32;
        for p in q {
            for c in p {
                positions.extend_from_slice(&c.to_le_bytes());
            }
        }
        for i in [k, k + 1, k + 2, k, k + 2, k + 3] {
            indices.extend_from_slice(&i.to_le_bytes());
        }
    }
    let mut bin = positions.clone();
    bin.extend_from_slice(&indices);
    std::fs::write(dir.join("rooms.bin"), &bin).unwrap();
    let gltf = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "rooms"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{
            "name": "white", "doubleSided": false,
            "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1.0], "metallicFactor": 0.0},
        }],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": positions.len() / 12, "type": "VEC3",
             "min": [0.0, 0.0, 0.0], "max": [l, h, d]},
            {"bufferView": 1, "componentType": 5125, "count": indices.len() / 4, "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": positions.len()},
            {"buffer": 0, "byteOffset": positions.len(), "byteLength": indices.len()},
        ],
        "buffers": [{"uri": "rooms.bin", "byteLength": bin.len()}],
    });
    let path = dir.join("rooms.gltf");
    std::fs::write(&path, gltf.to_string()).unwrap();
    path
}

/// Mean and largest luminance (channel mean) of an image.
fn mean_max(image: &Pfm) -> (f64, f64) {
    let lum: Vec<f64> = image
        .pixels
        .iter()
        .map(|p| p.iter().map(|&c| f64::from(c)).sum::<f64>() / 3.0)
        .collect();
    let mean = lum.iter().sum::<f64>() / lum.len() as f64;
    (mean, lum.iter().copied().fold(0.0, f64::max))
}

/// The voxel (along X) each side of the wall lies in, from the baked layout's grid.
fn wall_voxels(baked: &Path, thickness: f32) -> (u32, u32, usize) {
    let baked = Baked::read(baked).unwrap();
    let layout = &baked.layout;
    let voxel = |x: f32| ((x - layout.origin[0]) / layout.voxel_size).floor() as u32;
    (
        voxel(2.0 - thickness / 2.0),
        voxel(2.0 + thickness / 2.0),
        layout.patches.len(),
    )
}

/// The left room (lit), and the right room seen two ways: square at the wall, and at the corner
/// where the wall meets the floor and the back wall, where interpolation would reach across.
const LEFT_ROOM: &str = "0.2,1,1,2,1,1,70";
const RIGHT_ROOM: [&str; 2] = ["3.8,1,1,2,1,1,70", "3.9,1.9,1.9,2,0.5,0.3,80"];

/// Renders the two rooms indirect-only: the left room's mean, and per right-room view its mean
/// and largest luminance. `None`: no GPU adapter, skipping allowed.
fn rooms_indirect(dir: &Path, scene: &Path, baked: &Path) -> Option<(f64, Vec<(f64, f64)>)> {
    let lights = point_light(dir, [1.0, 1.0, 1.0]);
    let image = |camera: &str, name: &str| {
        let out = dir.join(name);
        render(scene, baked, &lights, camera, "only", &out).then(|| read_pfm(&out))
    };
    let (left, _) = mean_max(&image(LEFT_ROOM, "left.pfm")?);
    let right = RIGHT_ROOM
        .iter()
        .enumerate()
        .map(|(i, camera)| image(camera, &format!("right{i}.pfm")).map(|p| mean_max(&p)))
        .collect::<Option<Vec<_>>>()?;
    for (i, (mean, max)) in right.iter().enumerate() {
        println!(
            "right room view {i}: indirect radiance mean {:.4}%, largest {:.4}% of the lit left \
             room's mean ({left:.4})",
            mean / left * 100.0,
            max / left * 100.0
        );
    }
    Some((left, right))
}

/// A wall 0.02 thick (a twelfth of a voxel) across the plane between two voxels of the bake's
/// grid: `--voxel-size 0.24` (1,120 patches) makes the grid 18 voxels along X, centred on the box,
/// so x = 2 is a grid plane; the wall's sides lie in the two voxels either side of it, and every
/// patch holds surface of one room only. The image must then show no light right of the wall:
/// the volume's interpolation must not reach across it (the left room's floor, ceiling and back
/// and front walls lie one voxel away from the right room's).
#[test]
fn indirect_light_does_not_bleed_through_a_thin_wall() {
    let dir = tempfile::tempdir().unwrap();
    let thickness = 0.02;
    let scene = two_rooms(dir.path(), thickness);
    let baked = dir.path().join("rooms.bounce");
    bake(&scene, &baked, &["--voxel-size", "0.24"]);
    let (left_voxel, right_voxel, patches) = wall_voxels(&baked, thickness);
    assert_eq!(
        right_voxel,
        left_voxel + 1,
        "the wall should straddle a plane"
    );
    assert!((900..1300).contains(&patches), "{patches} patches");
    let Some((left, right)) = rooms_indirect(dir.path(), &scene, &baked) else {
        return;
    };
    assert!(left > 1.0, "the lit room's indirect radiance {left}");
    // Measured: means 0.020% and 0.012%, largest 0.28% and 0.27% of the left room's mean, all
    // of it in the patches that also hold the floor, ceiling and walls inside the wall (the
    // 0.01-wide strips between its two faces see the other room's strips). The volume sampling
    // before the separators read the left room's light up to half a voxel into the right room:
    // largest 44% of the left room's mean.
    for (mean, max) in right {
        assert!(mean < 1e-3 * left, "mean {mean} against {left}");
        assert!(max < 1e-2 * left, "largest {max} against {left}");
    }
}

/// The same wall inside one voxel (`--patches 1000` gives 0.2528-wide voxels, 17 along X, one of
/// them centred on x = 2): the floor, ceiling, back and front wall pieces either side of the wall
/// then share one patch per direction, which averages both rooms' light and sends the lit room's
/// into the dark one. That is the bake's patch definition (core), which the renderer cannot
/// undo: the whole right room is lit, mean 11% of the left room's and up to 51% in the strip
/// between the wall and the next voxel plane. Measured with the separators of the volume
/// sampling in place; they keep the mixed patches from being interpolated further in. Transport
/// elements (cut finer where the wall meets the floor) bring the mean to 6.0% and 3.6% of the
/// left room's (two views), up to 49%: the transport no longer mixes the rooms as much, but a
/// patch still streams one value for both sides of the wall. Elements told apart by the space
/// they face (the two sides of the wall are two elements of one patch, and the transport never
/// mixes them) bring the means to 2.8% and 0.75%, still up to 47%: all of it is the strip of
/// patches that hold both rooms' floor, which the layout streams as one value.
#[test]
#[ignore = "bake: a patch holds both rooms' floor, ceiling and walls in the voxels a thin wall \
            passes through (right room at 0.75-2.8% of the left, up to 47%; see the doc)"]
fn indirect_light_does_not_bleed_through_a_thin_wall_inside_a_voxel() {
    let dir = tempfile::tempdir().unwrap();
    let thickness = 0.02;
    let scene = two_rooms(dir.path(), thickness);
    let baked = dir.path().join("rooms.bounce");
    bake(&scene, &baked, &["--patches", "1000"]);
    let (left_voxel, right_voxel, _) = wall_voxels(&baked, thickness);
    assert_eq!(right_voxel, left_voxel, "the wall should be inside a voxel");
    let Some((left, right)) = rooms_indirect(dir.path(), &scene, &baked) else {
        return;
    };
    for (mean, max) in right {
        assert!(mean < 1e-3 * left, "mean {mean} against {left}");
        assert!(max < 1e-2 * left, "largest {max} against {left}");
    }
}
