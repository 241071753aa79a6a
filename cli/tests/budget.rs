//! `bounce bake --max-seconds / --max-memory`: a bake over its budget ends with an error naming
//! the budget and the stage it was in, and leaves no file behind (issue 19).

mod common;

use std::path::Path;

use common::{bounce, cornell, ok, run, stderr};

/// The stage names a bake reports (`bounce_core::bake::Stage::name`), the start, and the model.
const STAGES: [&str; 9] = [
    "start",
    "import",
    "voxelize",
    "ray scene",
    "form factors",
    "transport",
    "encode",
    "read shards",
    "pack model",
];

/// The bake failed cleanly, said `says` and a stage, and `dir` is as empty as before.
fn stopped(cmd: &mut std::process::Command, says: &str, dir: &Path) {
    let out = run(cmd);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{cmd:?}: {err}");
    assert!(err.contains(says), "{cmd:?} should say '{says}':\n{err}");
    assert!(
        STAGES
            .iter()
            .any(|s| err.contains(&format!("in stage \"{s}\""))),
        "{cmd:?} should name the stage:\n{err}"
    );
    assert!(err.contains("nothing was written"), "{err}");
    let left: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert!(left.is_empty(), "{cmd:?} left {left:?} behind");
}

#[test]
fn a_bake_over_its_budget_ends_naming_it_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out_file = dir.path().join("box.bounce");

    // 2,000 patches at 4,096 rays take seconds, in any build.
    stopped(
        bounce()
            .args([
                "bake",
                "--quiet",
                "--rays",
                "4096",
                "--max-seconds",
                "0.3",
                "-o",
            ])
            .arg(&out_file)
            .arg(cornell()),
        "over --max-seconds 0.3",
        dir.path(),
    );
    // Any process's peak memory is over 1 MiB.
    stopped(
        bounce()
            .args(["bake", "--quiet", "--max-memory", "1MiB", "-o"])
            .arg(&out_file)
            .arg(cornell()),
        "over --max-memory 1.0 MiB (1048576 bytes)",
        dir.path(),
    );
    // Phase 1 of a sharded bake takes the same budget; its output directory is made before the
    // bake, and stays empty.
    let shards = dir.path().join("ff");
    stopped(
        bounce()
            .args(["bake", "--quiet", "--shard", "0/2", "--rays", "4096"])
            .args(["--max-seconds", "0.3", "-o"])
            .arg(&shards)
            .arg(cornell()),
        "over --max-seconds 0.3",
        &shards,
    );
    std::fs::remove_dir(&shards).unwrap();

    // Nonsense budgets are refused before anything runs.
    common::refused(
        bounce()
            .args(["bake", "--max-seconds", "0", "-o"])
            .arg(&out_file)
            .arg(cornell()),
        "--max-seconds must be a positive number",
    );
    let bad_unit = run(bounce()
        .args(["bake", "--max-memory", "12 parsecs", "-o"])
        .arg(&out_file)
        .arg(cornell()));
    assert!(!bad_unit.status.success());
    assert!(
        stderr(&bad_unit).contains("unknown unit"),
        "{}",
        stderr(&bad_unit)
    );

    // Within its budget a bake is untouched: the file is written and reads.
    ok(bounce()
        .args(["bake", "--quiet", "--patches", "200", "--rays", "256"])
        .args(["--max-seconds", "600", "--max-memory", "16GiB", "-o"])
        .arg(&out_file)
        .arg(cornell()));
    ok(bounce().arg("inspect").arg(&out_file));
}

/// Issue 19's bake amplification: the Cornell box with one vertex moved to `far` (x of the
/// first POSITION of its first mesh primitive), written with its buffer into `dir`.
fn cornell_with_far_vertex(dir: &Path, far: f32) -> std::path::PathBuf {
    let gltf_path = cornell();
    let mut gltf: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&gltf_path).unwrap()).unwrap();
    let mut bin = std::fs::read(gltf_path.with_file_name("scene.bin")).unwrap();
    let accessor = gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
        .as_u64()
        .unwrap() as usize;
    let a = gltf["accessors"][accessor].clone();
    let view = &gltf["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
    let at =
        (view["byteOffset"].as_u64().unwrap_or(0) + a["byteOffset"].as_u64().unwrap_or(0)) as usize;
    bin[at..at + 4].copy_from_slice(&far.to_le_bytes());
    gltf["accessors"][accessor]["max"][0] = serde_json::json!(far);
    let out = dir.join("stray.gltf");
    std::fs::write(&out, serde_json::to_vec(&gltf).unwrap()).unwrap();
    std::fs::write(dir.join("scene.bin"), bin).unwrap();
    out
}

/// One vertex at 1e9 made `--patches 200` voxelise for minutes and a gigabyte; the scene is
/// refused at once, naming the vertex, and nothing is written. "At once" without a timer: a bake
/// that started voxelising would end on its 10 s budget instead, with the budget's message.
#[test]
fn a_stray_vertex_is_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let out_file = dir.path().join("stray.bounce");
    for far in [1e9f32, 1e15] {
        let scene = cornell_with_far_vertex(dir.path(), far);
        common::refused(
            bounce()
                .args([
                    "bake",
                    "--quiet",
                    "--patches",
                    "200",
                    "--max-seconds",
                    "10",
                    "-o",
                ])
                .arg(&out_file)
                .arg(&scene),
            "a stray vertex",
        );
        assert!(!out_file.exists());
    }
}
