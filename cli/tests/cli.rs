//! End-to-end: the real `bounce` binary on real files.

use std::path::Path;
use std::process::Command;

use bounce_core::format::Baked;
use serde_json::Value;

mod common;
use common::{ServeChild, bounce, cornell, gpu_ran, run, serve_command, stderr};

fn inspect_json(file: &Path) -> Value {
    let out = run(bounce().arg("inspect").arg(file).arg("--json"));
    assert!(out.status.success(), "{}", stderr(&out));
    serde_json::from_slice(&out.stdout).expect("inspect --json prints JSON")
}

#[test]
fn bake_then_inspect_the_cornell_box() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("cornell.bounce");
    let out = run(bounce()
        .args([
            "bake",
            "--patches",
            "400",
            "--rays",
            "1024",
            "--codec",
            "dense-f32",
            "--quiet",
            "-o",
        ])
        .arg(&file)
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));
    let summary = String::from_utf8_lossy(&out.stdout);
    assert!(summary.contains("patches"), "{summary}");

    let j = inspect_json(&file);
    assert_eq!(j["format_version"], 13);
    assert_eq!(
        j["sample_albedo"], true,
        "version 11 keeps each sample's albedo for the near field"
    );
    assert_eq!(
        j["near_field_albedo"], true,
        "version 12 keeps the albedo where each near-field entry's rays landed"
    );
    assert_eq!(j["near_field_radius"], 1.0, "a near field by default");
    assert!(j["near_field_entries"].as_u64().unwrap() > 0);
    assert_eq!(
        j["near_field_sky_view"], true,
        "version 9 keeps each sample's view of the sky with the near field"
    );
    assert_eq!(j["geometry"], "surface", "surface patches are the default");
    assert_eq!(
        j["surface_samples"], 32,
        "32 direct-light samples a patch by default"
    );
    assert_eq!(
        j["landing_samples"], 8,
        "a quarter of them where near-field rays land (version 13)"
    );
    assert_eq!(j["settings"]["landing_samples"], 8);
    assert_eq!(
        j["bounces"], "all",
        "every bounce by default, as a camera sees them"
    );
    assert_eq!(
        j["all_bounces"], "clustered",
        "the tail on clusters by default"
    );
    assert_eq!(j["channels"], 3, "the Cornell box has coloured walls");
    assert_eq!(j["codec"], "dense-f32");
    let n = j["patches"].as_u64().unwrap();
    assert!((300..=500).contains(&n), "{n} patches for a target of 400");
    // The transport's rows are the elements: at least one a patch.
    let rows = Baked::read(&file).unwrap().transport_layout().len() as u64;
    assert!(rows >= n, "{rows} rows for {n} patches");
    assert_eq!(j["matrix_bytes"].as_u64().unwrap(), rows * rows * 3 * 4);
    // Every row's view of the sky is kept; the box is open at the front, so some rays escape.
    assert_eq!(j["sky_view_rows"].as_u64(), Some(rows));
    let escaped = j["sky_view_escaped_share"].as_f64().unwrap();
    assert!((0.01..0.9).contains(&escaped), "{escaped}");
    let row_max = j["row_sum_max"].as_f64().unwrap();
    assert!(row_max <= 1.0 + 1e-5 && row_max > 0.5, "{row_max}");
    // Per-entry reciprocity is limited by ray noise: 1024 rays over a few hundred visible
    // patches is a few hits an entry, so tens of per cent here, not a bias.
    let recip = j["reciprocity_error"].as_f64().unwrap();
    assert!((0.0..0.3).contains(&recip), "{recip}");
    assert_eq!(j["import_report"]["triangles"], 32);

    // The same file read by the library: the layout matches the JSON.
    let baked = Baked::read(&file).unwrap();
    assert_eq!(baked.layout.len() as u64, n);

    // Text mode says the same things to a person.
    let out = run(bounce().arg("inspect").arg(&file));
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for word in [
        "format",
        "patches",
        "dense-f32",
        "row sums",
        "reciprocity",
        "sky view",
        "SKYV",
    ] {
        assert!(text.contains(word), "inspect text lacks '{word}':\n{text}");
    }

    // The model is kept by default, as the scene packed into one GLB, and shown by inspect.
    let model = bounce_core::import::pack_glb(&cornell()).unwrap();
    assert_eq!(baked.model.as_ref(), Some(&model));
    assert_eq!(j["model_stored"], true);
    assert_eq!(j["model_bytes"], model.len());
    assert!(text.contains("model") && text.contains("GLB"), "{text}");
    assert!(summary.contains("model"), "{summary}");

    // --no-model leaves it out, and says so.
    let bare = dir.path().join("bare.bounce");
    let out = run(bounce()
        .args([
            "bake",
            "--patches",
            "400",
            "--rays",
            "64",
            "--no-model",
            "-qo",
        ])
        .arg(&bare)
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(Baked::read(&bare).unwrap().model, None);
    let j = inspect_json(&bare);
    assert_eq!(j["model_stored"], false);
    assert_eq!(j["model_bytes"], Value::Null);
    let out = run(bounce().arg("inspect").arg(&bare));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("model         none"), "{text}");
}

#[test]
fn all_bounces_and_single_bounce() {
    let dir = tempfile::tempdir().unwrap();
    for (bounces, channels) in [("all", 3), ("1", 1)] {
        let file = dir.path().join(format!("b{bounces}.bounce"));
        let out = run(bounce()
            .args(["bake", "--patches", "200", "--rays", "128", "-q"])
            .args(["--bounces", bounces, "-o"])
            .arg(&file)
            .arg(cornell()));
        assert!(out.status.success(), "{}", stderr(&out));
        let j = inspect_json(&file);
        let want: Value = if bounces == "all" {
            "all".into()
        } else {
            1.into()
        };
        assert_eq!(j["bounces"], want);
        assert_eq!(j["channels"], channels);
    }
}

/// The transport carries one grey channel when colour changes the indirect light by at most
/// `--max-grey-error`: the Cornell box's red and green walls change it by about 5%, so the
/// default keeps three channels and a loose budget takes one. The choice and the measured change
/// are recorded; a budget outside 0..1 is refused.
#[test]
fn one_grey_channel_only_where_colour_matters_little() {
    let dir = tempfile::tempdir().unwrap();
    for (max, channels) in [(None, 3), (Some("0.5"), 1)] {
        let file = dir.path().join(format!("g{channels}.bounce"));
        let mut cmd = bounce();
        cmd.args(["bake", "--patches", "200", "--rays", "128", "-o"])
            .arg(&file)
            .arg(cornell());
        if let Some(max) = max {
            cmd.args(["--max-grey-error", max]);
        }
        let out = run(&mut cmd);
        assert!(out.status.success(), "{}", stderr(&out));
        let summary = String::from_utf8_lossy(&out.stdout);
        let j = inspect_json(&file);
        assert_eq!(j["channels"], channels, "{summary}");
        let change = j["stats"]["grey_rel_l2"].as_f64().unwrap();
        assert!((0.02..0.5).contains(&change), "{change}");
        let budget = max.map_or(0.02, |m| m.parse().unwrap());
        assert_eq!(j["settings"]["max_grey_error"].as_f64(), Some(budget));
        let said = if channels == 1 {
            "1 grey channel"
        } else {
            "3 channels"
        };
        assert!(summary.contains(said), "{summary}");
    }
    let out = run(bounce()
        .args(["bake", "--max-grey-error", "2", "-o"])
        .arg(dir.path().join("x.bounce"))
        .arg(cornell()));
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("--max-grey-error must be from 0 to 1"),
        "{}",
        stderr(&out)
    );
    // Every landing sample needs an area sample beside it for the mean.
    let out = run(bounce()
        .args([
            "bake",
            "--direct-samples",
            "4",
            "--landing-samples",
            "4",
            "-o",
        ])
        .arg(dir.path().join("x.bounce"))
        .arg(cornell()));
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("--landing-samples must be less than --direct-samples (4), got 4"),
        "{}",
        stderr(&out)
    );
}

/// `bake` and `demo` default to `--codec auto --max-error 0.01`: the smallest matrix within 1% of
/// the indirect light, recorded with the choice and its measured error. (The first-run `serve`
/// bakes the demo with `demo`'s defaults: `cli/src/demo.rs`.)
#[test]
fn bake_and_demo_default_to_the_smallest_codec_within_one_percent() {
    let dir = tempfile::tempdir().unwrap();
    let baked = dir.path().join("default.bounce");
    let out = run(bounce()
        .args(["bake", "--patches", "300", "--rays", "256", "-q", "-o"])
        .arg(&baked)
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));
    let demo_dir = dir.path().join("demo");
    let out = run(bounce()
        .args(["demo", "--patches", "300", "-q", "--dir"])
        .arg(&demo_dir));
    assert!(out.status.success(), "{}", stderr(&out));
    for file in [baked, demo_dir.join("cornell-box.bounce")] {
        let j = inspect_json(&file);
        assert_eq!(j["settings"]["codec"], "auto", "{}", file.display());
        assert_eq!(j["settings"]["max_error"], 0.01, "{}", file.display());
        let err = j["stats"]["codec_eind_rel_l2"].as_f64().unwrap();
        assert!(err <= 0.01, "{}: {err}", file.display());
        // Smaller than the exact matrix: at 1% some codec always fits on the Cornell box.
        let n = j["patches"].as_u64().unwrap();
        assert_ne!(j["codec"], "dense-f32", "{}", file.display());
        assert!(j["matrix_bytes"].as_u64().unwrap() < n * n * 3 * 4);
    }
}

#[test]
fn bake_with_a_codec_or_auto() {
    let dir = tempfile::tempdir().unwrap();
    let (mut bc1_bytes, mut bc1_err) = (0, 0.0);
    for (codec, want) in [
        ("bc1", &["bc1"][..]),
        ("dense-f16", &["dense-f16"]),
        // The smallest within 5% of those auto weighs: bc1-resid, with bc1's blocks (auto
        // leaves bc1 out: the same bytes give more error).
        ("auto", &["bc1-resid"]),
    ] {
        let file = dir.path().join(format!("{codec}.bounce"));
        let out = run(bounce()
            .args(["bake", "--patches", "200", "--rays", "256", "-q"])
            .args(["--codec", codec, "--max-error", "0.05", "-o"])
            .arg(&file)
            .arg(cornell()));
        assert!(out.status.success(), "{}", stderr(&out));
        let j = inspect_json(&file);
        let got = j["codec"].as_str().unwrap_or_default().to_string();
        assert!(want.contains(&got.as_str()), "--codec {codec}: {got}");
        let bytes = j["matrix_bytes"].as_u64().unwrap();
        let err = j["stats"]["codec_eind_rel_l2"].as_f64().unwrap();
        assert!(err < 0.05, "{codec}: {err}");
        match codec {
            "bc1" => (bc1_bytes, bc1_err) = (bytes, err),
            "auto" => {
                // Within a few exact entries of bc1's bytes, and with less error.
                assert!(
                    bytes * 100 <= bc1_bytes * 101,
                    "auto {got}: {bytes} against bc1's {bc1_bytes}"
                );
                assert!(err < bc1_err, "auto {got}: {err} against bc1's {bc1_err}");
            }
            _ => {}
        }
        assert_eq!(j["settings"]["codec"], codec);
    }
    let unknown = run(bounce()
        .args(["bake", "--codec", "bc7", "-o"])
        .arg(dir.path().join("x.bounce"))
        .arg(cornell()));
    assert_eq!(unknown.status.code(), Some(1));
    assert!(
        stderr(&unknown).contains("unknown codec 'bc7'"),
        "{}",
        stderr(&unknown)
    );
}

#[test]
fn morton_order_numbers_the_same_patches_differently() {
    let dir = tempfile::tempdir().unwrap();
    let mut layouts = Vec::new();
    for order in ["scan", "morton"] {
        let file = dir.path().join(format!("{order}.bounce"));
        let out = run(bounce()
            .args(["bake", "--patches", "300", "--rays", "64", "-q"])
            .args(["--patch-order", order, "-o"])
            .arg(&file)
            .arg(cornell()));
        assert!(out.status.success(), "{}", stderr(&out));
        assert_eq!(inspect_json(&file)["settings"]["patch_order"], order);
        layouts.push(Baked::read(&file).unwrap().layout.patches);
    }
    assert_ne!(layouts[0], layouts[1]);
    let key = |p: &bounce_core::patch::Patch| (p.voxel, p.face);
    let mut a: Vec<_> = layouts[0].iter().map(key).collect();
    let mut b: Vec<_> = layouts[1].iter().map(key).collect();
    a.sort();
    b.sort();
    assert_eq!(a, b);
}

#[test]
fn the_thread_count_does_not_change_the_result() {
    let dir = tempfile::tempdir().unwrap();
    let mut bakes = Vec::new();
    for threads in ["1", "2"] {
        let file = dir.path().join(format!("t{threads}.bounce"));
        let out = run(bounce()
            .env("RAYON_NUM_THREADS", threads)
            .args(["bake", "--patches", "300", "--rays", "128", "-q", "-o"])
            .arg(&file)
            .arg(cornell()));
        assert!(out.status.success(), "{}", stderr(&out));
        bakes.push(Baked::read(&file).unwrap());
    }
    assert_eq!(bakes[0].layout, bakes[1].layout);
    assert_eq!(bakes[0].transport, bakes[1].transport);
    // Only timings may differ.
    assert_eq!(bakes[0].meta.stats, bakes[1].meta.stats);
}

#[test]
fn user_errors_read_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let out_file = dir.path().join("x.bounce");

    let missing = run(bounce()
        .args(["bake", "-o"])
        .arg(&out_file)
        .arg(dir.path().join("nope.gltf")));
    assert_eq!(missing.status.code(), Some(1));
    assert!(
        stderr(&missing).contains("not found"),
        "{}",
        stderr(&missing)
    );

    let text = dir.path().join("notes.gltf");
    std::fs::write(&text, "these are not the triangles you are looking for").unwrap();
    let not_gltf = run(bounce().args(["bake", "-o"]).arg(&out_file).arg(&text));
    assert_eq!(not_gltf.status.code(), Some(1));
    assert!(
        stderr(&not_gltf).contains("not a glTF"),
        "{}",
        stderr(&not_gltf)
    );

    let absurd = run(bounce()
        .args(["bake", "--patches", "5000000", "-o"])
        .arg(&out_file)
        .arg(cornell()));
    assert_eq!(absurd.status.code(), Some(1));
    assert!(
        stderr(&absurd).contains("out of range"),
        "{}",
        stderr(&absurd)
    );

    let zero_rays = run(bounce()
        .args(["bake", "--rays", "0", "-o"])
        .arg(&out_file)
        .arg(cornell()));
    assert_eq!(zero_rays.status.code(), Some(1));

    let bad_bounces = run(bounce()
        .args(["bake", "--bounces", "0", "-o"])
        .arg(&out_file)
        .arg(cornell()));
    assert_eq!(bad_bounces.status.code(), Some(2), "clap rejects it");
    assert!(stderr(&bad_bounces).contains("at least 1"));

    // One open plate: every ray escapes.
    let plate = dir.path().join("plate.gltf");
    std::fs::write(&plate, single_plate_gltf()).unwrap();
    let open = run(bounce()
        .args(["bake", "--patches", "50", "--rays", "64", "-o"])
        .arg(&out_file)
        .arg(&plate));
    assert_eq!(open.status.code(), Some(1));
    assert!(
        stderr(&open).contains("no patch sees another"),
        "{}",
        stderr(&open)
    );

    assert!(!out_file.exists(), "failed bakes leave no file behind");
}

#[test]
fn damaged_files_are_refused_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("c.bounce");
    let out = run(bounce()
        .args(["bake", "--patches", "150", "--rays", "64", "-q", "-o"])
        .arg(&file)
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));
    let bytes = std::fs::read(&file).unwrap();

    let truncated = dir.path().join("truncated.bounce");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let out = run(bounce().arg("inspect").arg(&truncated));
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("truncated"), "{}", stderr(&out));

    let mut flipped = bytes.clone();
    let k = flipped.len() - 100;
    flipped[k] ^= 0x40;
    let damaged = dir.path().join("damaged.bounce");
    std::fs::write(&damaged, &flipped).unwrap();
    let out = run(bounce().arg("inspect").arg(&damaged));
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("checksum"), "{}", stderr(&out));

    let out = run(bounce()
        .arg("inspect")
        .arg(dir.path().join("absent.bounce")));
    assert_eq!(out.status.code(), Some(1));
}

#[test]
fn every_command_has_help() {
    for args in [
        vec!["--help"],
        vec!["bake", "--help"],
        vec!["inspect", "--help"],
        vec!["demo", "--help"],
        vec!["relight", "--help"],
        vec!["bench", "--help"],
        vec!["bench", "bake", "--help"],
        vec!["bench", "rays", "--help"],
        vec!["bench", "codecs", "--help"],
        vec!["bench", "engines", "--help"],
        vec!["bench", "direct", "--help"],
        vec!["bench", "serve", "--help"],
        vec!["serve", "--help"],
        vec!["reference", "--help"],
        vec!["verify", "--help"],
        vec!["render", "--help"],
        vec!["view", "--help"],
    ] {
        let out = run(bounce().args(&args));
        assert!(out.status.success(), "{args:?}");
        assert!(String::from_utf8_lossy(&out.stdout).contains("Usage"));
    }
}

/// `bounce relight` on both engines: a batch of two light files, JSON and CSV out, the same light
/// on both engines, and clear errors for bad lights, a scene without lights and a bad output.
#[test]
fn relight_the_cornell_box_on_both_engines() {
    let dir = tempfile::tempdir().unwrap();
    let baked = dir.path().join("box.bounce");
    // The exact matrix: the engines must then agree to 1e-4. (On a block codec the GPU's texture
    // unit may decode a palette entry one 8-bit code from the CPU's decoder, see
    // engine/tests/it/gpu.rs.)
    let out = run(bounce()
        .args(["bake", "--patches", "300", "--rays", "512"])
        .args(["--codec", "dense-f32", "--quiet", "-o"])
        .arg(&baked)
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));
    let lights = dir.path().join("lights.json");
    std::fs::write(
        &lights,
        r#"{"lights": [{"type": "point", "position": [0, 1.5, 0], "intensity": 5},
                       {"type": "directional", "direction": [0.3, -1, 0.2], "intensity": 3}]}"#,
    )
    .unwrap();
    let dim = dir.path().join("dim.json");
    std::fs::write(
        &dim,
        r#"{"lights": [{"type": "point", "position": [0, 1.5, 0], "intensity": 1}]}"#,
    )
    .unwrap();

    let mut results = Vec::new();
    for engine in ["cpu", "gpu"] {
        let json = dir.path().join(format!("{engine}.json"));
        let out = run(bounce()
            .arg("relight")
            .arg(&baked)
            .arg("--lights")
            .arg(&lights)
            .arg("--lights")
            .arg(&dim)
            .args(["--engine", engine, "--out"])
            .arg(&json));
        if !gpu_ran(&out, &format!("bounce relight --engine {engine}")) {
            continue;
        }
        assert!(
            stderr(&out).contains(&format!("engine: {engine}")),
            "{}",
            stderr(&out)
        );
        let v: Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
        let sets = v["sets"].as_array().unwrap();
        assert_eq!(sets.len(), 2);
        let total = |set: &Value, key: &str| -> f64 {
            set[key]
                .as_array()
                .unwrap()
                .iter()
                .flat_map(|p| p.as_array().unwrap().iter().map(|c| c.as_f64().unwrap()))
                .sum()
        };
        let (direct, indirect) = (total(&sets[0], "direct"), total(&sets[0], "indirect"));
        assert!(direct > 0.0 && indirect > 0.0, "{direct} {indirect}");
        // The dim file is one fifth of the point light and no sun: less light everywhere.
        assert!(total(&sets[1], "indirect") < indirect);
        results.push(indirect);
    }
    if let [cpu, gpu] = results[..] {
        assert!((cpu - gpu).abs() <= 1e-4 * cpu, "cpu {cpu} gpu {gpu}");
    }

    let csv = dir.path().join("out.csv");
    let out = run(bounce()
        .arg("relight")
        .arg(&baked)
        .arg("--lights")
        .arg(&lights)
        .args(["--engine", "cpu", "--out"])
        .arg(&csv));
    assert!(out.status.success(), "{}", stderr(&out));
    let text = std::fs::read_to_string(&csv).unwrap();
    assert!(text.starts_with("set,patch,direct_r"));
    let patches = Baked::read(&baked).unwrap().layout.len();
    assert_eq!(text.lines().count(), 1 + patches);

    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, r#"{"lights": [{"type": "spot", "position": [0, 1, 0], "direction": [0, -1, 0], "intensity": -2}]}"#).unwrap();
    for (args, message) in [
        (
            vec!["--lights", bad.to_str().unwrap()],
            "lights[0].intensity",
        ),
        (vec![], "no lights of its own"),
        (
            vec!["--lights", lights.to_str().unwrap(), "--out", "x.txt"],
            ".json or .csv",
        ),
        (
            vec!["--lights", lights.to_str().unwrap(), "--engine", "tpu"],
            "unknown engine",
        ),
    ] {
        let out = run(bounce().arg("relight").arg(&baked).args(&args));
        assert!(!out.status.success(), "{args:?}");
        assert!(stderr(&out).contains(message), "{args:?}: {}", stderr(&out));
    }
}

/// A sky lights a new bake; an older file (the fuzz corpus' version-3 seed) reads and relights,
/// gets nothing from the sky, and says why; a bad sky is refused naming its field.
#[test]
fn a_sky_lights_new_files_and_old_ones_say_why_not() {
    let dir = tempfile::tempdir().unwrap();
    let sky = dir.path().join("sky.json");
    std::fs::write(&sky, r#"{"lights": [{"type": "sky", "color": [1, 1, 1]}]}"#).unwrap();
    let relight = |baked: &Path, name: &str| {
        let json = dir.path().join(name);
        let out = run(bounce()
            .arg("relight")
            .arg(baked)
            .arg("--lights")
            .arg(&sky)
            .args(["--engine", "cpu", "--out"])
            .arg(&json));
        assert!(out.status.success(), "{}", stderr(&out));
        let v: Value = serde_json::from_slice(&std::fs::read(json).unwrap()).unwrap();
        let total = |key: &str| -> f64 {
            v["sets"][0][key]
                .as_array()
                .unwrap()
                .iter()
                .flat_map(|p| p.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
                .sum()
        };
        (stderr(&out), total("direct"), total("indirect"))
    };
    let new = dir.path().join("box.bounce");
    let out = run(bounce()
        .args(["bake", "--patches", "200", "--rays", "256"])
        .args(["--codec", "dense-f32", "--quiet", "-o"])
        .arg(&new)
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));
    let (err, direct, indirect) = relight(&new, "new.json");
    assert!(!err.contains("sky visibility"), "{err}");
    assert!(direct > 0.0 && indirect > 0.0, "{direct} {indirect}");

    let old =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus/baked_file/cornell-30.bounce");
    let (err, direct, indirect) = relight(&old, "old.json");
    assert!(
        err.contains("has no sky visibility") && err.contains("bake the scene again"),
        "{err}"
    );
    assert_eq!((direct, indirect), (0.0, 0.0));
    let text = String::from_utf8_lossy(&run(bounce().arg("inspect").arg(&old)).stdout).into_owned();
    assert!(text.contains("sky view      none"), "{text}");

    std::fs::write(&sky, r#"{"lights": [{"type": "sky", "sh": [[1, 1, 1]]}]}"#).unwrap();
    let out = run(bounce().arg("relight").arg(&new).arg("--lights").arg(&sky));
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("lights[0].sh: must hold exactly 9 coefficients"),
        "{}",
        stderr(&out)
    );
}

/// The emissive Cornell box: `inspect` lists its lamp, a relight can dim and recolour it and
/// `verify` takes the change to the reference; a change naming no emitter is refused naming the
/// light and what the scene has; the version-3 seed lists none and says why.
#[test]
fn emissive_surfaces_change_at_run_time() {
    let dir = tempfile::tempdir().unwrap();
    let scene =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box-emissive/CornellBox.glb");
    let baked = dir.path().join("lamp.bounce");
    let out = run(bounce()
        .args(["bake", "--patches", "200", "--rays", "256"])
        .args(["--codec", "dense-f32", "--quiet", "-o"])
        .arg(&baked)
        .arg(&scene));
    assert!(out.status.success(), "{}", stderr(&out));
    let j = inspect_json(&baked);
    assert_eq!(j["emitters"][0]["material"], "Emitter_Light_temp");
    assert_eq!(j["emitters"][0]["strength"], 100.0);
    assert_eq!(j["emitters"][0]["node"], "Light");
    let text =
        String::from_utf8_lossy(&run(bounce().arg("inspect").arg(&baked)).stdout).into_owned();
    assert!(text.contains("emitters      1 over"), "{text}");

    let write = |name: &str, json: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, json).unwrap();
        path
    };
    let none = write("none.json", r#"{"lights": []}"#);
    let half = write(
        "half.json",
        r#"{"lights": [{"type": "emissive", "material": "Emitter_Light_temp", "strength": 50}]}"#,
    );
    // The same lamp by its node.
    let half_node = write(
        "half-node.json",
        r#"{"lights": [{"type": "emissive", "node": "Light", "strength": 50}]}"#,
    );
    let out_json = dir.path().join("out.json");
    let out = run(bounce()
        .arg("relight")
        .arg(&baked)
        .args(["--engine", "cpu", "--lights"])
        .arg(&none)
        .arg("--lights")
        .arg(&half)
        .arg("--lights")
        .arg(&half_node)
        .arg("--out")
        .arg(&out_json));
    assert!(out.status.success(), "{}", stderr(&out));
    let v: Value = serde_json::from_slice(&std::fs::read(&out_json).unwrap()).unwrap();
    let total = |set: usize| -> f64 {
        v["sets"][set]["indirect"]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|p| p.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
            .sum()
    };
    assert_eq!(
        v["sets"][1]["indirect"], v["sets"][2]["indirect"],
        "by node"
    );
    // Half the strength, half the light: the lamp is the box's only source.
    assert!(total(0) > 0.0);
    assert!(
        (total(1) / total(0) - 0.5).abs() < 1e-4,
        "{} {}",
        total(1),
        total(0)
    );

    let out = run(bounce()
        .arg("verify")
        .arg(&baked)
        .arg(&scene)
        .args(["--spp", "64", "--quiet", "--json", "--lights"])
        .arg(&half));
    assert!(out.status.success(), "{}", stderr(&out));

    let wrong = write(
        "wrong.json",
        r#"{"lights": [{"type": "emissive", "material": "Lamp", "color": [1, 0, 0]}]}"#,
    );
    let out = run(bounce()
        .arg("relight")
        .arg(&baked)
        .arg("--lights")
        .arg(&wrong));
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains(
            "lights[0].material: the scene has no emissive material 'Lamp' (its emissive \
             materials: Emitter_Light_temp; on nodes: Light)"
        ),
        "{}",
        stderr(&out)
    );
    let old =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus/baked_file/cornell-30.bounce");
    let out = run(bounce().arg("relight").arg(&old).arg("--lights").arg(&half));
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("this baked file lists no emitters"),
        "{}",
        stderr(&out)
    );
    let text = String::from_utf8_lossy(&run(bounce().arg("inspect").arg(&old)).stdout).into_owned();
    assert!(text.contains("emitters      none listed"), "{text}");
}

/// A 1 × 1 plate facing up, two triangles, as glTF with an embedded buffer.
fn single_plate_gltf() -> String {
    let positions: [[f32; 3]; 4] = [[0., 0., 0.], [0., 0., 1.], [1., 0., 1.], [1., 0., 0.]];
    let indices: [u16; 6] = [0, 1, 2, 0, 2, 3];
    let mut buf = Vec::new();
    for p in positions {
        for c in p {
            buf.extend_from_slice(&c.to_le_bytes());
        }
    }
    for i in indices {
        buf.extend_from_slice(&i.to_le_bytes());
    }
    let b64 = base64_encode(&buf);
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
        "buffers":[{{"byteLength":{len},"uri":"data:application/octet-stream;base64,{b64}"}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":12}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,0,1]}},
                     {{"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR"}}]}}"#,
        len = buf.len()
    )
}

fn base64_encode(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(T[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// `bounce serve` on free loopback ports with scenes from `scenes` and sessions in `data`.
fn serve(scenes: &Path, data: &Path) -> ServeChild {
    ServeChild::spawn(serve_command(scenes, data, "127.0.0.1:0"))
}

/// The process is killed with SIGKILL between a change and the restart: no shutdown code runs,
/// so only what the store committed before acknowledging can bring the session back.
#[test]
fn serve_keeps_sessions_across_kill_9() {
    use bounce_server::frame::Frame;
    use bounce_server::proto::{self, bounce_client::BounceClient};

    let dir = tempfile::tempdir().unwrap();
    let scenes = dir.path().join("scenes");
    let data = dir.path().join("data");
    std::fs::create_dir_all(&scenes).unwrap();
    let out = run(bounce()
        .args(["bake", "--patches", "200", "--rays", "256", "--quiet", "-o"])
        .arg(scenes.join("box.bounce"))
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));

    let rt = tokio::runtime::Runtime::new().unwrap();
    let light = |intensity: f32| proto::Light {
        r#type: "point".into(),
        position: vec![0.0, 1.0, 0.0],
        intensity: Some(intensity),
        ..Default::default()
    };
    let mut first = serve(&scenes, &data);
    let (id, before) = rt.block_on(async {
        let mut c = BounceClient::connect(first.grpc.clone()).await.unwrap();
        let id = c
            .create_session(proto::CreateSessionRequest {
                scene: "box".into(),
                lights: vec![light(4.0)],
            })
            .await
            .unwrap()
            .into_inner()
            .session_id;
        let v = c
            .set_lights(proto::SetLightsRequest {
                session_id: id.clone(),
                lights: vec![light(11.0)],
                token: String::new(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(v.lights_version, 2);
        let mut frames = c
            .subscribe(proto::SubscribeRequest {
                session_id: id.clone(),
            })
            .await
            .unwrap()
            .into_inner();
        loop {
            let f = frames.message().await.unwrap().expect("a frame");
            if f.lights_version == 2 {
                break (id, f.data);
            }
        }
    });
    first.kill();

    let second = serve(&scenes, &data);
    rt.block_on(async {
        let mut c = BounceClient::connect(second.grpc.clone()).await.unwrap();
        let mut frames = c
            .subscribe(proto::SubscribeRequest {
                session_id: id.clone(),
            })
            .await
            .expect("the session id is known after the restart")
            .into_inner();
        let f = frames.message().await.unwrap().expect("a frame");
        assert_eq!(f.lights_version, 2);
        let (a, b) = (
            Frame::parse(f.data).unwrap().irradiance(),
            Frame::parse(before).unwrap().irradiance(),
        );
        assert_eq!(
            a, b,
            "the same lights give the same light after the restart"
        );
    });
}

/// `render --server` takes its indirect light from a running server as a viewer does; it must
/// draw the same image as `render --baked` on the same file, up to the frame's RGB9E5 rounding.
#[test]
fn render_from_a_server_matches_render_in_process() {
    let dir = tempfile::tempdir().unwrap();
    let scenes = dir.path().join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    let baked = scenes.join("box.bounce");
    let out = run(bounce()
        .args(["bake", "--patches", "300", "--rays", "256", "--quiet", "-o"])
        .arg(&baked)
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));
    let lights = dir.path().join("spot.json");
    std::fs::write(
        &lights,
        r#"{"lights":[{"type":"spot","position":[0,1.9,0],"direction":[0,-1,0],"intensity":15,"inner_cone_angle":0.8,"outer_cone_angle":1.0}]}"#,
    )
    .unwrap();
    let server = serve(&scenes, &dir.path().join("data"));
    let render = |source: &[&std::ffi::OsStr], png: &Path| {
        let out = run(bounce()
            .arg("render")
            .arg(cornell())
            .args(source)
            .arg("--lights")
            .arg(&lights)
            .args([
                "--engine", "cpu", "--width", "160", "--height", "120", "--out",
            ])
            .arg(png)
            .env("XDG_RUNTIME_DIR", std::env::temp_dir()));
        assert!(out.status.success(), "{}", stderr(&out));
        image::open(png).expect("a PNG").to_rgba8()
    };
    let here = render(
        &["--baked".as_ref(), baked.as_os_str()],
        &dir.path().join("here.png"),
    );
    let grpc = server.grpc.clone();
    let remote = render(
        &[
            "--server".as_ref(),
            grpc.as_ref(),
            "--scene-name".as_ref(),
            "box".as_ref(),
        ],
        &dir.path().join("remote.png"),
    );
    assert_eq!(here.dimensions(), remote.dimensions());
    let diffs: Vec<i32> = here
        .as_raw()
        .iter()
        .zip(remote.as_raw())
        .map(|(a, b)| (i32::from(*a) - i32::from(*b)).abs())
        .collect();
    let max = diffs.iter().copied().max().unwrap_or(0);
    let mean = diffs.iter().sum::<i32>() as f64 / diffs.len() as f64;
    assert!(max <= 3 && mean < 0.5, "max {max}, mean {mean}");
    // And not trivially: the image has light in it.
    assert!(here.as_raw().iter().map(|&v| u64::from(v)).sum::<u64>() > 160 * 120 * 40);
}

// `bounce render`: needs a GPU adapter (lavapipe will do); without one these fail unless
// `BOUNCE_ALLOW_NO_GPU=1` says skipping is intended.
#[test]
fn render_a_baked_cornell_box_to_png() {
    let dir = tempfile::tempdir().unwrap();
    let baked = dir.path().join("cb.bounce");
    let out = run(bounce()
        .arg("bake")
        .arg(cornell())
        .arg("-o")
        .arg(&baked)
        .args(["--patches", "200", "--rays", "256", "--quiet"]));
    assert!(out.status.success(), "{}", stderr(&out));
    let lights = dir.path().join("l.json");
    std::fs::write(
        &lights,
        r#"{"lights":[{"type":"point","position":[0,1.8,0],"intensity":8}]}"#,
    )
    .unwrap();
    let render = |png: &Path, indirect: &str| {
        run(bounce()
            .arg("render")
            .arg(cornell())
            .arg("--baked")
            .arg(&baked)
            .arg("--lights")
            .arg(&lights)
            .arg("--out")
            .arg(png)
            .args(["--width", "64", "--height", "48", "--engine", "cpu"])
            .args(["--indirect", indirect])
            .args(["--camera", "0,1,3.5,0,1,0,50"]))
    };
    let on = dir.path().join("on.png");
    let out = render(&on, "on");
    if !gpu_ran(&out, "bounce render") {
        return;
    }
    let off = dir.path().join("off.png");
    let out = render(&off, "off");
    assert!(out.status.success(), "{}", stderr(&out));
    let on = image::open(&on).unwrap().to_rgba8();
    let off = image::open(&off).unwrap().to_rgba8();
    assert_eq!(on.dimensions(), (64, 48));
    let sum = |img: &image::RgbaImage| -> u64 { img.as_raw().iter().map(|&v| u64::from(v)).sum() };
    // Indirect light only adds.
    assert!(sum(&on) > sum(&off), "{} vs {}", sum(&on), sum(&off));
}

#[test]
fn render_user_errors_read_clearly() {
    let check = |args: &[&str], want: &str| {
        let out = run(bounce().arg("render").arg(cornell()).args(args));
        assert_eq!(out.status.code(), Some(1), "{args:?}: {}", stderr(&out));
        assert!(stderr(&out).contains(want), "{args:?}: {}", stderr(&out));
    };
    let dir = tempfile::tempdir().unwrap();
    let lights = dir.path().join("lights.json");
    std::fs::write(
        &lights,
        r#"{"lights":[{"type":"point","position":[0,1.5,0],"intensity":5}]}"#,
    )
    .unwrap();
    let lights = lights.to_str().unwrap();
    // Nothing listens on port 1.
    check(
        &[
            "--server",
            "http://127.0.0.1:1",
            "--scene-name",
            "box",
            "--lights",
            lights,
            "--out",
            "x.png",
        ],
        "127.0.0.1:1",
    );
    check(&["--out", "x.png"], "--baked");
    check(
        &[
            "--baked",
            "x.bounce",
            "--out",
            "x.png",
            "--indirect",
            "maybe",
        ],
        "--indirect must be on or off",
    );
    check(
        &["--baked", "x.bounce", "--out", "x.png", "--camera", "1,2,3"],
        "--camera takes 6 or 7 numbers",
    );
    check(
        &["--baked", "x.bounce", "--out", "x.png"],
        "no lights of its own",
    );
}

/// An X server of the test's own (Xvfb picks a free display and prints it), for the window.
/// Without Xvfb the window tests fail, naming `scripts/test` (which installs it), unless
/// `BOUNCE_ALLOW_NO_GPU=1` says skipping is intended.
struct Xvfb {
    child: std::process::Child,
    display: String,
}

impl Xvfb {
    fn start() -> Option<Xvfb> {
        use std::io::{BufRead, BufReader};
        let spawned = Command::new("Xvfb")
            .args([
                "-displayfd",
                "1",
                "-screen",
                "0",
                "1024x768x24",
                "-nolisten",
                "tcp",
            ])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null())
            .spawn();
        let mut child = match spawned {
            Ok(c) => c,
            Err(e) => {
                return bounce_testkit::missing(bounce_testkit::Tool::Xvfb, format!("Xvfb: {e}"));
            }
        };
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("stdout"))
            .read_line(&mut line)
            .expect("Xvfb prints its display");
        let display = format!(":{}", line.trim());
        assert!(display.len() > 1, "Xvfb printed no display number");
        Some(Xvfb { child, display })
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

const SPOT: &str = r#"{"lights":[{"type":"spot","position":[0,1.9,0],"direction":[0,-1,0],"intensity":15,"inner_cone_angle":0.8,"outer_cone_angle":1.0}]}"#;

/// The real window under Xvfb on lavapipe: it opens, draws frames with indirect light, writes
/// what its surface showed, and exits by itself. The picture is the one `bounce render` draws
/// of the same frame (same stage, same shader), and brighter than direct light alone.
#[test]
fn the_window_opens_renders_and_exits_under_xvfb() {
    let Some(x) = Xvfb::start() else { return };
    let dir = tempfile::tempdir().unwrap();
    let baked = dir.path().join("cb.bounce");
    let out = run(bounce()
        .args(["bake", "--patches", "300", "--rays", "256", "--quiet", "-o"])
        .arg(&baked)
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));
    let lights = dir.path().join("spot.json");
    std::fs::write(&lights, SPOT).unwrap();
    let camera = "0,1,3.5,0,1,0,50";
    let shot = dir.path().join("window.png");
    let stats = dir.path().join("stats.json");
    let out = run(bounce()
        .arg("view")
        .arg(cornell())
        .arg("--baked")
        .arg(&baked)
        .arg("--lights")
        .arg(&lights)
        .args(["--camera", camera, "--width", "320", "--height", "240"])
        .args(["--engine", "cpu", "--vsync", "off", "--overlay", "off"])
        .args(["--frames", "5", "--timeout", "120", "--screenshot"])
        .arg(&shot)
        .arg("--stats")
        .arg(&stats)
        .env("DISPLAY", &x.display)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir()));
    assert!(out.status.success(), "{}", stderr(&out));
    let stats: Value = serde_json::from_slice(&std::fs::read(&stats).unwrap()).unwrap();
    assert!(stats["frames"].as_u64().unwrap() >= 5, "{stats}");
    assert!(stats["first_indirect_ms"].as_f64().is_some(), "{stats}");
    assert!(
        stats["screenshot"].as_str().unwrap().contains("surface"),
        "the screenshot should be the window's own surface: {stats}"
    );

    let headless = |indirect: &str| {
        let png = dir.path().join(format!("headless-{indirect}.png"));
        let out = run(bounce()
            .arg("render")
            .arg(cornell())
            .arg("--baked")
            .arg(&baked)
            .arg("--lights")
            .arg(&lights)
            .args(["--camera", camera, "--width", "320", "--height", "240"])
            .args(["--engine", "cpu", "--indirect", indirect, "--out"])
            .arg(&png)
            .env("XDG_RUNTIME_DIR", std::env::temp_dir()));
        assert!(out.status.success(), "{}", stderr(&out));
        image::open(&png).unwrap().to_rgba8()
    };
    let window = image::open(&shot).unwrap().to_rgba8();
    let on = headless("on");
    let off = headless("off");
    assert_eq!(window.dimensions(), (320, 240));
    let diffs: Vec<i32> = window
        .as_raw()
        .iter()
        .zip(on.as_raw())
        .map(|(a, b)| (i32::from(*a) - i32::from(*b)).abs())
        .collect();
    let max = diffs.iter().copied().max().unwrap_or(0);
    let mean = diffs.iter().sum::<i32>() as f64 / diffs.len() as f64;
    assert!(
        max <= 2 && mean < 0.1,
        "window vs headless: max {max}, mean {mean}"
    );
    // The top rows see the ceiling, which the spot does not light: only indirect light does.
    let top = |img: &image::RgbaImage| -> u64 {
        img.as_raw()[..(320 * 40 * 4)]
            .iter()
            .map(|&v| u64::from(v))
            .sum()
    };
    assert!(
        top(&window) > top(&off) + 320 * 40 * 3 * 5,
        "the ceiling with indirect light {} vs without {}",
        top(&window),
        top(&off)
    );
}

/// The window as a server's viewer: it creates a session, moves the light twice (each move
/// once the last one's indirect light is on screen), times each move to the frame that shows
/// it, and the session on the server ends with the moved light.
#[test]
fn the_window_moves_a_sessions_light_on_a_server() {
    use bounce_server::proto::{self, bounce_client::BounceClient};

    let Some(x) = Xvfb::start() else { return };
    let dir = tempfile::tempdir().unwrap();
    let scenes = dir.path().join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    let out = run(bounce()
        .args(["bake", "--patches", "200", "--rays", "256", "--quiet", "-o"])
        .arg(scenes.join("box.bounce"))
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));
    let lights = dir.path().join("l.json");
    std::fs::write(
        &lights,
        r#"{"lights":[{"type":"point","position":[0.5,1.5,0],"intensity":8}]}"#,
    )
    .unwrap();
    let server = serve(&scenes, &dir.path().join("data"));
    let stats = dir.path().join("stats.json");
    let out = run(bounce()
        .arg("view")
        .arg(cornell())
        .args(["--server", &server.grpc, "--scene-name", "box", "--lights"])
        .arg(&lights)
        .args(["--width", "200", "--height", "150", "--vsync", "off"])
        .args(["--frames", "3", "--auto-move", "2", "--timeout", "120"])
        .arg("--stats")
        .arg(&stats)
        .env("DISPLAY", &x.display)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir()));
    assert!(out.status.success(), "{}", stderr(&out));
    let stats: Value = serde_json::from_slice(&std::fs::read(&stats).unwrap()).unwrap();
    assert_eq!(stats["gi_latency_ms"]["count"], 2, "{stats}");
    assert!(stats["gi_latency_ms"]["max"].as_f64().unwrap() > 0.0);
    let session = stderr(&out)
        .lines()
        .find_map(|l| l.strip_prefix("session ").map(str::to_owned))
        .expect("view prints its session");
    let rt = tokio::runtime::Runtime::new().unwrap();
    let state = rt.block_on(async {
        let mut c = BounceClient::connect(server.grpc.clone()).await.unwrap();
        c.get_session(proto::GetSessionRequest {
            session_id: session.trim().to_string(),
        })
        .await
        .expect("the viewer's session")
        .into_inner()
    });
    assert_eq!(state.scene, "box");
    assert_eq!(state.lights_version, 3, "created, then moved twice");
    let p = &state.lights[0].position;
    // Turned 40° about the vertical axis through the box's centre: no longer at x = 0.5.
    assert!(
        (p[0] - 0.5).abs() > 0.05 && (p[1] - 1.5).abs() < 1e-4,
        "{p:?}"
    );
}

/// `bounce verify` on a compressed Cornell box: every key of the report, an error split that adds
/// up, a histogram over all patches; `bounce reference` at given points and at the patches, to
/// JSON and CSV; clear errors for what a user gets wrong.
#[test]
fn verify_and_reference_on_the_cornell_box() {
    let dir = tempfile::tempdir().unwrap();
    let baked = dir.path().join("cornell-bc1.bounce");
    let out = run(bounce()
        .args([
            "bake",
            "--patches",
            "300",
            "--rays",
            "256",
            "--codec",
            "bc1",
            "--quiet",
            "-o",
        ])
        .arg(&baked)
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));
    let lights = dir.path().join("point.json");
    std::fs::write(
        &lights,
        r#"{"lights":[{"type":"point","position":[0,1.5,0],"intensity":5}]}"#,
    )
    .unwrap();
    let patches_csv = dir.path().join("patches.csv");
    let out = run(bounce()
        .arg("verify")
        .arg(&baked)
        .arg(cornell())
        .arg("--lights")
        .arg(&lights)
        .args(["--spp", "64", "--json", "--quiet", "--patches-out"])
        .arg(&patches_csv));
    assert!(out.status.success(), "{}", stderr(&out));
    let report: Value = serde_json::from_slice(&out.stdout).expect("verify --json prints JSON");
    let get = |k: &str| {
        report[k]
            .as_f64()
            .unwrap_or_else(|| panic!("{k} in {report}"))
    };
    for key in [
        "codec_rel_l2",
        "method_rel_l2",
        "total_rel_l2",
        "worst_patch_rel",
        "reference_rel_stderr",
        "direct_at_patches_rel_l2",
        "transport_rel_l2",
        // A surface bake: the first bounce with the light where each ray lands.
        "source_rel_l2",
        "method_pointwise_source_rel_l2",
        // Three bounces and a near field: what carrying it through the later bounces gains.
        "method_without_near_field_rel_l2",
        "method_first_bounce_near_field_rel_l2",
    ] {
        let v = get(key);
        assert!(v.is_finite() && v >= 0.0, "{key} = {v}");
    }
    let patches = report["patches"].as_u64().unwrap() as usize;
    // bc1 is lossy; the method error of 300 voxel patches is far from zero.
    assert!(get("codec_rel_l2") > 1e-4 && get("codec_rel_l2") < 0.2);
    assert!(get("method_rel_l2") > 0.01);
    // The triangle inequality on the three L2 errors (reference norms are the same).
    assert!(get("total_rel_l2") <= get("method_rel_l2") + get("codec_rel_l2") * 1.5 + 1e-9);
    let histogram: usize = report["histogram"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() as usize)
        .sum();
    assert_eq!(histogram, patches);
    let csv = std::fs::read_to_string(&patches_csv).unwrap();
    assert_eq!(csv.lines().count(), patches + 1);
    // The per-patch columns hold what the report's errors are made of: the method error
    // with the pointwise first bounce, summed again from them, is the report's.
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let column = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("{name} in {header:?}"))
    };
    let reference = column("ref_r");
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    for cells in &rows {
        assert_eq!(cells.len(), header.len(), "{cells:?}");
    }
    for (name, key) in [
        ("pointwise_r", "method_pointwise_source_rel_l2"),
        (
            "first_bounce_near_r",
            "method_first_bounce_near_field_rel_l2",
        ),
    ] {
        let at = column(name);
        let (mut diff, mut norm) = (0.0f64, 0.0f64);
        for cells in &rows {
            for c in 0..3 {
                let r: f64 = cells[reference + c].parse().unwrap();
                let p: f64 = cells[at + c].parse().unwrap();
                diff += (p - r) * (p - r);
                norm += r * r;
            }
        }
        let summed = (diff / norm).sqrt();
        let reported = get(key);
        assert!(
            (summed - reported).abs() < 1e-4 * reported.max(1.0),
            "{name}: {summed} from the CSV against {key} {reported} reported"
        );
    }
    // The near field in the first bounce alone is another relight, not the same numbers.
    assert_ne!(
        get("method_first_bounce_near_field_rel_l2"),
        get("method_rel_l2")
    );

    // Without the source split: the same report less its rows, its columns left empty.
    let unsplit_csv = dir.path().join("unsplit.csv");
    let out = run(bounce()
        .arg("verify")
        .arg(&baked)
        .arg(cornell())
        .arg("--lights")
        .arg(&lights)
        .args([
            "--spp",
            "64",
            "--json",
            "--quiet",
            "--no-source-split",
            "--patches-out",
        ])
        .arg(&unsplit_csv));
    assert!(out.status.success(), "{}", stderr(&out));
    let unsplit: Value = serde_json::from_slice(&out.stdout).expect("verify --json prints JSON");
    for key in [
        "method_rel_l2",
        "codec_rel_l2",
        "method_without_near_field_rel_l2",
    ] {
        assert_eq!(unsplit[key], report[key], "{key}");
    }
    for key in ["source_rel_l2", "method_pointwise_source_rel_l2"] {
        assert!(unsplit[key].is_null(), "{key}: {}", unsplit[key]);
    }
    let text = std::fs::read_to_string(&unsplit_csv).unwrap();
    let at = column("pointwise_r");
    for line in text.lines().skip(1) {
        let cells: Vec<&str> = line.split(',').collect();
        assert_eq!(cells.len(), header.len(), "{line}");
        assert!(cells[at..at + 3].iter().all(|c| c.is_empty()), "{line}");
    }

    // The same table for a person.
    let out = run(bounce()
        .arg("verify")
        .arg(&baked)
        .arg(cornell())
        .arg("--lights")
        .arg(&lights)
        .args(["--spp", "16", "--quiet"]));
    assert!(out.status.success(), "{}", stderr(&out));
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("codec: compressed T vs exact T"), "{table}");
    assert!(table.contains("re-baked as dense-f32"), "{table}");

    // Given points, to CSV; the patches, to JSON.
    let points = dir.path().join("points.json");
    std::fs::write(
        &points,
        r#"[{"position":[0,0.001,0.9],"normal":[0,1,0]},{"position":[0.6,1.989,0.5],"normal":[0,-1,0]}]"#,
    )
    .unwrap();
    let csv_out = dir.path().join("ref.csv");
    let out = run(bounce()
        .arg("reference")
        .arg(cornell())
        .arg("--lights")
        .arg(&lights)
        .arg("--points")
        .arg(&points)
        .args(["--spp", "256", "--bounces", "2", "--quiet", "--out"])
        .arg(&csv_out));
    assert!(out.status.success(), "{}", stderr(&out));
    let rows: Vec<Vec<f64>> = std::fs::read_to_string(&csv_out)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 2);
    for row in &rows {
        // Both points see lit walls: positive indirect light with a smaller standard error.
        assert!(row[7] > 0.0 && row[10] > 0.0 && row[10] < row[7], "{row:?}");
    }
    let json_out = dir.path().join("ref.json");
    let out = run(bounce()
        .arg("reference")
        .arg(cornell())
        .arg("--baked")
        .arg(&baked)
        .arg("--lights")
        .arg(&lights)
        .args(["--spp", "8", "--quiet", "--out"])
        .arg(&json_out));
    assert!(out.status.success(), "{}", stderr(&out));
    let traced: Value = serde_json::from_slice(&std::fs::read(&json_out).unwrap()).unwrap();
    assert_eq!(traced["points"].as_array().unwrap().len(), patches);

    // What a user gets wrong reads clearly.
    let out = run(bounce()
        .arg("reference")
        .arg(cornell())
        .arg("--lights")
        .arg(&lights));
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("--points footprints needs --baked"),
        "{}",
        stderr(&out)
    );
    let out = run(bounce()
        .arg("reference")
        .arg(cornell())
        .arg("--lights")
        .arg(&lights)
        .args(["--points", "patches", "--spp", "1", "--baked"])
        .arg(&baked));
    assert!(!out.status.success());
    assert!(stderr(&out).contains("at least 2"), "{}", stderr(&out));
    let out = run(bounce().arg("verify").arg(&baked).arg(cornell()));
    assert!(!out.status.success());
    assert!(
        stderr(&out).contains("no lights of its own"),
        "{}",
        stderr(&out)
    );
}

/// `bounce bench engines` on a small bake: the file's own transport (its rows are the
/// elements, more than the patches) and a synthetic size tiled from it, both engines, every
/// product measured against the exact one. The dense product must be exact to f32 rounding on
/// both engines, the block codec within its codec error.
#[test]
fn bench_engines_measures_the_file_and_synthetic_sizes() {
    let dir = tempfile::tempdir().unwrap();
    let baked = dir.path().join("box.bounce");
    let out = run(bounce()
        .args(["bake", "--patches", "200", "--rays", "256"])
        .args(["--codec", "dense-f32", "--quiet", "-o"])
        .arg(&baked)
        .arg(cornell()));
    assert!(out.status.success(), "{}", stderr(&out));
    let patches = inspect_json(&baked)["patches"].as_u64().unwrap() as usize;
    for synthetic in [None, Some("300")] {
        let csv = dir.path().join("engines.csv");
        let mut cmd = bounce();
        cmd.args(["bench", "engines"])
            .arg(&baked)
            .args([
                "--codecs",
                "dense-f32,bc1",
                "--batches",
                "1,9",
                "--repeat",
                "1",
                "--warm-up",
                "0",
                "--columns",
                "lit,all",
            ])
            .arg("--csv")
            .arg(&csv);
        if let Some(n) = synthetic {
            cmd.args(["--synthetic", n]);
        }
        let out = run(&mut cmd);
        assert!(out.status.success(), "{}", stderr(&out));
        let text = std::fs::read_to_string(&csv).unwrap();
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
        let rows: Vec<Vec<String>> = lines
            .map(|l| l.split(',').map(str::to_string).collect())
            .collect();
        // One row per engine, codec and batch: a device with tensor cores adds its own
        // `gpu-tensor` rows past 8 sets.
        let products: Vec<&Vec<String>> = rows
            .iter()
            .filter(|r| r[col("codec")] == "dense-f32" || r[col("codec")] == "bc1")
            .filter(|r| r[col("engine")] != "gpu-tensor")
            .filter(|r| r[col("engine")] != "gpu-all-columns")
            .collect();
        let engines: Vec<&str> = products.iter().map(|r| r[col("engine")].as_str()).collect();
        if !engines.contains(&"gpu") {
            bounce_testkit::missing::<()>(bounce_testkit::Tool::GpuAdapter, stderr(&out));
        }
        let engine_count = if engines.contains(&"gpu") { 2 } else { 1 };
        assert_eq!(products.len(), 2 * 2 * engine_count, "{text}");
        for r in &products {
            let n: usize = r[col("rows")].parse().unwrap();
            match synthetic {
                Some(s) => assert_eq!(n, s.parse::<usize>().unwrap()),
                None => assert!(n > patches, "{n} transport rows, {patches} patches"),
            }
            let err: f64 = r[col("eind_rel_l2")].parse().unwrap();
            // A synthetic size is block-encoded without the reorder pass (as `--help` says),
            // which leaves more error than the file's own encoding: 11% measured at 300 rows.
            let bound = match (r[col("codec")].as_str(), synthetic) {
                ("dense-f32", _) => 1e-5,
                (_, None) => 0.1,
                (_, Some(_)) => 0.2,
            };
            assert!(err <= bound, "{r:?}");
            let ms: f64 = r[col("latency_ms_p50")].parse().unwrap();
            assert!(ms > 0.0, "{r:?}");
        }
        // The GPU's one-set products walking every column: the same result as skipping the dark
        // groups (the same bits, so the same error), and the whole matrix read.
        let all: Vec<&Vec<String>> = rows
            .iter()
            .filter(|r| r[col("engine")] == "gpu-all-columns")
            .collect();
        assert_eq!(all.len(), if engine_count == 2 { 2 } else { 0 }, "{text}");
        for r in all {
            let lit = products
                .iter()
                .find(|p| {
                    p[col("engine")] == "gpu"
                        && p[col("codec")] == r[col("codec")]
                        && p[col("batch")] == r[col("batch")]
                })
                .unwrap();
            assert_eq!(r[col("batch")], "1", "{r:?}");
            assert_eq!(r[col("walked")], "1.000", "{r:?}");
            assert_eq!(
                r[col("eind_rel_l2")],
                lit[col("eind_rel_l2")],
                "{r:?} {lit:?}"
            );
            let walked: f64 = lit[col("walked")].parse().unwrap();
            assert!(walked > 0.0 && walked <= 1.0, "{lit:?}");
        }
        // The file's run also times direct light on each engine; a synthetic one has no scene.
        let direct = rows
            .iter()
            .filter(|r| r[col("codec")].starts_with("direct light"));
        assert_eq!(direct.count() > 0, synthetic.is_none(), "{text}");
    }
}

/// `bench direct` times each file under each motion that changes the light set, takes the
/// voxel-face file as the baseline wherever it stands on the command line, and refuses what it
/// cannot measure before timing anything.
#[test]
fn bench_direct_times_every_file_under_every_motion() {
    let dir = tempfile::tempdir().unwrap();
    let (surface, voxels) = (dir.path().join("s.bounce"), dir.path().join("v.bounce"));
    for (file, geometry) in [(&surface, "surface"), (&voxels, "voxel-faces")] {
        common::ok(
            bounce()
                .args([
                    "bake",
                    "--patches",
                    "200",
                    "--rays",
                    "256",
                    "--geometry",
                    geometry,
                ])
                .args(["--codec", "dense-f32", "--quiet", "-o"])
                .arg(file)
                .arg(cornell()),
        );
    }
    let lights = dir.path().join("l.json");
    std::fs::write(
        &lights,
        r#"{"lights":[{"type":"point","position":[0,1.5,0],"intensity":5},
                      {"type":"directional","direction":[0.3,-1,0.2],"intensity":2}]}"#,
    )
    .unwrap();
    let csv = dir.path().join("d.csv");
    let out = common::ok(
        bounce()
            .args(["bench", "direct"])
            .arg(&surface)
            .arg(&voxels)
            .arg("--lights")
            .arg(&lights)
            .args(["--sets", "3", "--rounds", "2", "--csv"])
            .arg(&csv),
    );
    let text = std::fs::read_to_string(&csv).unwrap();
    let printed = String::from_utf8_lossy(&out.stdout).to_string();
    assert_eq!(
        text.lines().next(),
        printed
            .lines()
            .next()
            .map(|h| h.split_whitespace().collect::<Vec<_>>().join(","))
            .as_deref(),
        "the CSV has the table's header"
    );
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<String>> = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    assert_eq!(rows.len(), 2 * 4, "two files, four motions:\n{text}");
    for motion in ["move", "turn", "still", "dim"] {
        let of = |geometry: &str| {
            rows.iter()
                .find(|r| r[col("motion")] == motion && r[col("geometry")] == geometry)
                .unwrap_or_else(|| panic!("{motion} {geometry}:\n{text}"))
        };
        let (s, v) = (of("surface"), of("voxel-faces"));
        assert_eq!(v[col("total_x_baseline")], "1.00", "{text}");
        assert_eq!(v[col("later_x_baseline")], "1.00", "{text}");
        for r in [s, v] {
            for c in ["first_ms", "later_ms_per_set", "total_ms"] {
                let t: f64 = r[col(c)].parse().unwrap();
                assert!(t > 0.0 && t.is_finite(), "{c}: {text}");
            }
            assert_eq!(r[col("sets")], "3");
        }
        assert_eq!(
            s[col("samples")],
            "32",
            "every sample a surface bake stores"
        );
    }
    // A sky alone: moving, turning and dimming change nothing, and are left out with a note.
    let sky = dir.path().join("sky.json");
    std::fs::write(&sky, r#"{"lights":[{"type":"sky","color":[1,1,1]}]}"#).unwrap();
    let out = common::ok(
        bounce()
            .args(["bench", "direct"])
            .arg(&surface)
            .arg("--lights")
            .arg(&sky)
            .args(["--sets", "2", "--rounds", "1"]),
    );
    assert!(stderr(&out).contains("move: left out"), "{}", stderr(&out));
    let table = String::from_utf8_lossy(&out.stdout).to_string();
    assert_eq!(
        table.lines().count(),
        2,
        "a header and the still row:\n{table}"
    );
    common::refused(
        bounce()
            .args(["bench", "direct"])
            .arg(&surface)
            .arg("--lights")
            .arg(&sky)
            .args(["--motions", "move,turn"]),
        "no motion changes the light set",
    );
    common::refused(
        bounce()
            .args(["bench", "direct", "--sets", "1"])
            .arg(&surface),
        "--sets must be at least 2",
    );
    common::refused(
        bounce()
            .args(["bench", "direct"])
            .arg(dir.path().join("none.bounce")),
        "none.bounce",
    );
}

/// `bench tradeoff` measures both geometries against one reference per patch count, and the
/// surface patches beat the thesis' voxel faces at every count (the gain shown, not asserted in
/// prose only).
#[test]
fn bench_tradeoff_puts_both_geometries_on_one_table() {
    let dir = tempfile::tempdir().unwrap();
    let lights = dir.path().join("point.json");
    std::fs::write(
        &lights,
        r#"{"lights":[{"type":"point","position":[0,1.5,0],"intensity":5}]}"#,
    )
    .unwrap();
    let csv = dir.path().join("t.csv");
    let plot = dir.path().join("t.svg");
    let out = run(bounce()
        .args(["bench", "tradeoff"])
        .arg(cornell())
        .arg("--lights")
        .arg(&lights)
        .args([
            "--patches",
            "100,200",
            "--rays",
            "128",
            "--codecs",
            "dense-f32",
            "--near-field",
            "0,1",
        ])
        .args(["--spp", "64", "--repeat", "1", "--csv"])
        .arg(&csv)
        .arg("--plot")
        .arg(&plot));
    assert!(out.status.success(), "{}", stderr(&out));
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<String>> = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    // Two counts: surface with and without the near field, and voxel faces once (they have
    // neither sample points nor a near field).
    assert_eq!(rows.len(), 6, "{text}");
    let method = |geometry: &str, near: &str, i: usize| -> f64 {
        rows.iter()
            .filter(|r| r[col("geometry")] == geometry && r[col("near_field")] == near)
            .nth(i)
            .unwrap()[col("method_rel_l2")]
        .parse()
        .unwrap()
    };
    for i in 0..2 {
        let voxels = method("voxel-faces", "0", i);
        for near in ["0", "1"] {
            let surface = method("surface", near, i);
            assert!(surface.is_finite() && surface > 0.0);
            assert!(
                surface < voxels,
                "count {i}, near field {near}: surface {surface} against voxel faces {voxels}"
            );
        }
    }
    assert!(std::fs::read_to_string(&plot).unwrap().contains("<svg"));
}

/// A bake with probes: `inspect` lists them, `relight --out X.json` gives their light per
/// direction, `verify` checks them against the reference; probe options that cannot run are
/// refused before any work, naming the flag.
#[test]
fn probes_bake_relight_and_verify() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("p.bounce");
    let lights = dir.path().join("point.json");
    std::fs::write(
        &lights,
        r#"{"lights":[{"type":"point","position":[0,1.5,0],"intensity":10}]}"#,
    )
    .unwrap();
    let out = run(bounce()
        .arg("bake")
        .arg(cornell())
        .args(["--patches", "300", "--rays", "256", "--codec", "dense-f32"])
        .args(["--probes", "--probe-rays", "256", "-o"])
        .arg(&file));
    assert!(out.status.success(), "{}", stderr(&out));
    let j = inspect_json(&file);
    let count = j["probes"]["count"].as_u64().unwrap();
    assert!(count > 0, "{j}");
    assert_eq!(j["probes"]["rays_per_direction"], 256);
    // The box is open on one side: some of the probes' rays see the sky.
    let escaped = j["probes"]["sky_escaped"].as_f64().unwrap();
    assert!(escaped > 0.01 && escaped < 0.5, "{j}");
    let json = dir.path().join("r.json");
    let out = run(bounce()
        .arg("relight")
        .arg(&file)
        .arg("--lights")
        .arg(&lights)
        .args(["--engine", "cpu", "--out"])
        .arg(&json));
    assert!(out.status.success(), "{}", stderr(&out));
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(r["probe_positions"].as_array().unwrap().len() as u64, count);
    let probes = r["sets"][0]["probes"].as_array().unwrap();
    assert_eq!(probes.len() as u64, count);
    assert_eq!(probes[0].as_array().unwrap().len(), 6);
    let out = run(bounce()
        .arg("verify")
        .arg(&file)
        .arg(cornell())
        .arg("--lights")
        .arg(&lights)
        .args(["--spp", "16", "--probe-spp", "64", "--json", "--quiet"]));
    assert!(out.status.success(), "{}", stderr(&out));
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["probes"]["probes"].as_u64(), Some(count));
    let err = v["probes"]["rel_l2"].as_f64().unwrap();
    assert!(err.is_finite() && err < 0.5, "{v}");
    // `bench engines` reports what the probes add: the gather's own rows, equal to the relight's.
    let csv = dir.path().join("engines.csv");
    let out = run(bounce()
        .args(["bench", "engines"])
        .arg(&file)
        .args([
            "--engines",
            "cpu",
            "--codecs",
            "dense-f32",
            "--batches",
            "1,2",
        ])
        .args(["--repeat", "1", "--warm-up", "0", "--csv"])
        .arg(&csv));
    assert!(out.status.success(), "{}", stderr(&out));
    let text = std::fs::read_to_string(&csv).unwrap();
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let rel = header.iter().position(|h| *h == "eind_rel_l2").unwrap();
    let gathers: Vec<Vec<&str>> = text
        .lines()
        .filter(|l| l.contains("probe gather"))
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(gathers.len(), 2, "{text}");
    for g in gathers {
        assert_eq!(g[rel].parse::<f64>().unwrap(), 0.0, "{text}");
    }
    // Under a sky too: the probes hold the sky they see, and the reference adds it.
    let sky = dir.path().join("sky.json");
    std::fs::write(&sky, r#"{"lights":[{"type":"sky","color":[1,1,1]}]}"#).unwrap();
    let out = run(bounce()
        .arg("verify")
        .arg(&file)
        .arg(cornell())
        .arg("--lights")
        .arg(&sky)
        .args(["--spp", "16", "--probe-spp", "64", "--json", "--quiet"]));
    assert!(out.status.success(), "{}", stderr(&out));
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let err = v["probes"]["rel_l2"].as_f64().unwrap();
    assert!(err.is_finite() && err < 0.5, "{v}");
    for (args, says) in [
        (&["--probe-spacing=-1"][..], "--probe-spacing"),
        (&["--probes", "--probe-rays", "0"][..], "--probe-rays"),
        (
            &["--probes", "--geometry", "voxel-faces"][..],
            "surface geometry",
        ),
    ] {
        let out = run(bounce()
            .arg("bake")
            .arg(cornell())
            .args(args)
            .arg("-o")
            .arg(dir.path().join("no.bounce")));
        assert!(!out.status.success());
        assert!(stderr(&out).contains(says), "{args:?}: {}", stderr(&out));
        assert!(!dir.path().join("no.bounce").exists());
    }
}

/// `bounce sky`: an OpenEXR environment map becomes a light file with its SH sky (the core's
/// projection of the same file, times `--scale`), which a relight takes; a file that is no HDR
/// image, or a bad scale, is refused with the reason.
#[test]
fn sky_turns_an_hdr_map_into_a_sky_light() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("courtyard.exr");
    let (w, h) = (128u32, 64u32);
    let img = image::Rgb32FImage::from_fn(w, h, |_, y| {
        // Bright overhead, dark below the horizon.
        let up = 1.0 - 2.0 * (y as f32 + 0.5) / h as f32;
        let v = if up > 0.0 { 0.5 + up } else { 0.05 };
        image::Rgb([v, v, v * 1.2])
    });
    img.save(&map).unwrap();
    let want = bounce_core::environment::sh_from_image(&std::fs::read(&map).unwrap()).unwrap();
    let out_file = dir.path().join("sky.json");
    let out = run(bounce()
        .arg("sky")
        .arg(&map)
        .args(["--scale", "2", "-o"])
        .arg(&out_file));
    assert!(out.status.success(), "{}", stderr(&out));
    let text = std::fs::read_to_string(&out_file).unwrap();
    let set = bounce_core::light::LightSet::from_json(&text).expect("a valid light file");
    let sh = set.sky_sh().expect("a sky");
    for (got, want) in sh.iter().flatten().zip(want.sh.iter().flatten()) {
        assert_eq!(*got, 2.0 * want);
    }
    assert!(sh[1][0] > 0.0, "brighter overhead: {sh:?}");
    // The light file lights a bake as any sky does.
    let file = dir.path().join("box.bounce");
    common::ok(
        bounce()
            .arg("bake")
            .arg(cornell())
            .args(["--patches", "200", "--rays", "128", "--quiet", "-o"])
            .arg(&file),
    );
    let lit = dir.path().join("lit.json");
    common::ok(
        bounce()
            .arg("relight")
            .arg(&file)
            .arg("--lights")
            .arg(&out_file)
            .args(["--engine", "cpu", "--out"])
            .arg(&lit),
    );
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&lit).unwrap()).unwrap();
    let direct = r["sets"][0]["direct"].as_array().unwrap();
    assert!(
        direct.iter().any(|d| d[0].as_f64().unwrap() > 0.0),
        "the sky lights the box through its opening"
    );
    let junk = dir.path().join("junk.hdr");
    std::fs::write(&junk, "not an image").unwrap();
    common::refused(bounce().arg("sky").arg(&junk), "not an image");
    common::refused(bounce().arg("sky").arg(&map).arg("--scale=-1"), "--scale");
    common::refused(
        bounce().arg("sky").arg(dir.path().join("missing.hdr")),
        "reading",
    );

    // A sun's direction: the sun and its sky, two lights of a valid file.
    let out = common::ok(bounce().args(["sky", "--sun", "0.3,0.9,-0.2", "--scale", "0.1"]));
    let set = bounce_core::light::LightSet::from_json(&String::from_utf8_lossy(&out.stdout))
        .expect("a valid light file");
    assert_eq!(set.lights.len(), 2);
    assert!(set.sky_sh().is_some());
    common::refused(
        bounce().args(["sky", "--sun", "0.3,-0.9,-0.2"]),
        "below the horizon",
    );
    common::refused(
        bounce().args(["sky", "--sun", "0,1,0", "--turbidity", "50"]),
        "turbidity",
    );
}
