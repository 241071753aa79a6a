//! The reference against an outside renderer: Mitsuba 3 (which `scripts/test` installs in a
//! virtual environment in the build directory; `bounce_testkit::python` finds it) renders the
//! Cornell box's indirect irradiance at the same points under the same point light, through its
//! own path integrator (tests/mitsuba/irradiance.py). A test that cannot run Mitsuba fails,
//! naming `scripts/test`, unless BOUNCE_ALLOW_NO_MITSUBA=1 says skipping is wanted (CI never
//! sets it).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;
use std::process::Command;

use bounce_core::import::import_path;
use bounce_core::light::{Light, LightSet};
use bounce_core::meta::Bounces;
use bounce_reference::{Options, Point, Reference};
use serde_json::{Value, json};

fn cornell() -> bounce_core::scene::Scene {
    import_path(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box/scene.gltf"))
        .expect("importing the Cornell box")
}

/// Points just inside the white surfaces (floor, ceiling around the light quad, back wall), facing
/// into the room. The box spans x −1.02..1, y 0..1.99, z −1.04..0.98.
fn points() -> Vec<Point> {
    let at = |position: [f32; 3], normal: [f32; 3]| Point { position, normal };
    let inset = 1e-3;
    let mut points = Vec::new();
    for (x, z) in [(-0.6, -0.5), (0.6, -0.5), (-0.6, 0.5), (0.6, 0.5)] {
        points.push(at([x, 1.99 - inset, z], [0.0, -1.0, 0.0]));
    }
    for (x, y) in [(-0.5, 1.6), (0.0, 1.85), (0.5, 1.6)] {
        points.push(at([x, y, -1.04 + inset], [0.0, 0.0, 1.0]));
    }
    for (x, z) in [(-0.6, 0.75), (0.6, 0.75), (0.0, 0.9)] {
        points.push(at([x, inset, z], [0.0, 1.0, 0.0]));
    }
    points
}

/// Mitsuba's input: the triangles as OBJ files, one per (albedo, sidedness).
fn mitsuba_job(dir: &Path, lights: &LightSet, bounces: u32) -> Value {
    let scene = cornell();
    // Keyed by the albedo's bits: f32 is not Ord.
    let mut groups: BTreeMap<([u32; 3], bool), String> = BTreeMap::new();
    for t in &scene.triangles {
        let key = (t.albedo.to_array().map(f32::to_bits), t.double_sided);
        let obj = groups.entry(key).or_default();
        for p in t.positions {
            let _ = writeln!(obj, "v {} {} {}", p.x, p.y, p.z);
        }
        let k = obj.lines().filter(|l| l.starts_with("v ")).count();
        let _ = writeln!(obj, "f {} {} {}", k - 2, k - 1, k);
    }
    let meshes: Vec<Value> = groups
        .into_iter()
        .enumerate()
        .map(|(i, ((albedo, double_sided), obj))| {
            let path = dir.join(format!("mesh{i}.obj"));
            std::fs::write(&path, obj).unwrap();
            json!({"obj": path, "albedo": albedo.map(f32::from_bits), "double_sided": double_sided})
        })
        .collect();
    let lights: Vec<Value> = lights
        .lights
        .iter()
        .map(|l| match l {
            Light::Point {
                position,
                color,
                intensity,
                ..
            } => json!({"position": position, "intensity": color.map(|c| c * intensity)}),
            other => panic!("this test gives Mitsuba point lights only, not {other:?}"),
        })
        .collect();
    // White surfaces only: E_ind is recovered by dividing by the albedo.
    let white = [0.725f32, 0.71, 0.68];
    let points: Vec<Value> = points()
        .iter()
        .map(|p| json!({"position": p.position, "normal": p.normal, "albedo": white}))
        .collect();
    json!({
        "meshes": meshes, "lights": lights, "points": points,
        "bounces": bounces, "spp": 4096, "batches": 8,
    })
}

#[test]
fn the_reference_agrees_with_mitsuba_on_the_cornell_box() {
    let Some(python) = bounce_testkit::mitsuba_python() else {
        return;
    };
    let white = cornell()
        .triangles
        .iter()
        .any(|t| (t.albedo - glam::Vec3::new(0.725, 0.71, 0.68)).length() < 1e-3);
    assert!(
        white,
        "the Cornell box's white albedo is what the test divides by"
    );

    let lights = LightSet {
        lights: vec![Light::Point {
            position: [0.0, 1.5, 0.0],
            color: [1.0, 1.0, 1.0],
            intensity: 5.0,
            range: None,
            name: None,
        }],
    };
    let bounces = 3;
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("job.json");
    let output = dir.path().join("out.json");
    std::fs::write(
        &input,
        mitsuba_job(dir.path(), &lights, bounces).to_string(),
    )
    .unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/mitsuba/irradiance.py");
    let run = Command::new(&python)
        .arg(&script)
        .arg(&input)
        .arg(&output)
        .output()
        .unwrap_or_else(|e| panic!("running {}: {e}", python.display()));
    assert!(
        run.status.success(),
        "Mitsuba failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let theirs: Value = serde_json::from_slice(&std::fs::read(&output).unwrap()).unwrap();

    let reference = Reference::new(&cornell()).unwrap();
    let options = Options {
        spp: 32_768,
        bounces: Bounces::K(bounces),
        seed: 3,
    };
    let ours = reference
        .estimate(&lights, &points(), &options, &|_| {})
        .unwrap();

    let (mut diff2, mut norm2) = (0.0, 0.0);
    for (i, (mine, them)) in ours
        .iter()
        .zip(theirs["points"].as_array().unwrap())
        .enumerate()
    {
        for c in 0..3 {
            let m = them["mean"][c].as_f64().unwrap();
            let s = them["stderr"][c].as_f64().unwrap();
            let sigma = (s * s + mine.stderr[c] * mine.stderr[c]).sqrt();
            eprintln!(
                "point {i} channel {c}: bounce {:.4} ± {:.4}, Mitsuba {m:.4} ± {s:.4}",
                mine.mean[c], mine.stderr[c]
            );
            assert!(
                (mine.mean[c] - m).abs() <= 4.0 * sigma + 0.01 * m.abs(),
                "point {i} channel {c}: {} ± {} against Mitsuba {m} ± {s}",
                mine.mean[c],
                mine.stderr[c]
            );
            diff2 += (mine.mean[c] - m).powi(2);
            norm2 += m * m;
        }
    }
    let rel = (diff2 / norm2).sqrt();
    eprintln!(
        "relative L2 against Mitsuba {}: {:.3}%",
        theirs["mitsuba"],
        rel * 100.0
    );
    assert!(rel < 0.02, "{rel}");
}
