//! What the containers and jobs run, run here on real files: the sharded bake's three commands as
//! an Indexed Job runs them (the index from JOB_COMPLETION_INDEX), against a one-process bake;
//! their refusals; and the compose file's bake script.

use std::path::PathBuf;
use std::process::Command;

use bounce_core::format::Baked;

mod common;
use common::{bounce, cornell, ok, refused, repo, run};

const BAKE: [&str; 4] = ["--patches", "300", "--rays", "128"];

#[test]
fn a_sharded_bake_on_the_command_line_equals_the_one_process_bake() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let one = d.join("one.bounce");
    ok(bounce()
        .arg("bake")
        .arg(cornell())
        .args(BAKE)
        .arg("-qo")
        .arg(&one));

    // Phase 1 as an Indexed Job of 3 runs it: the count on the command line, the index in the
    // environment, a directory as the output.
    for i in 0..3 {
        ok(bounce()
            .env("JOB_COMPLETION_INDEX", i.to_string())
            .arg("bake")
            .arg(cornell())
            .args(BAKE)
            .args(["--shard", "3", "-q", "-o"])
            .arg(format!("{}/ff/", d.display())));
    }
    // Phase 2 in 2 shards with explicit indices, then the merge of the directory.
    for i in 0..2 {
        ok(bounce()
            .args([
                "bake",
                "transport",
                "--shard",
                &format!("{i}/2"),
                "-q",
                "-o",
            ])
            .arg(d.join("t"))
            .arg(d.join("ff")));
    }
    let merged = d.join("merged.bounce");
    let out = ok(bounce()
        .args(["bake", "merge", "-q"])
        .arg(d.join("t"))
        .arg("-o")
        .arg(&merged));
    assert!(String::from_utf8_lossy(&out.stdout).contains("sums over its shards"));

    let (a, b) = (Baked::read(&one).unwrap(), Baked::read(&merged).unwrap());
    assert_eq!(a.layout, b.layout);
    assert_eq!(a.transport, b.transport);
    assert_eq!(a.occupancy, b.occupancy);
    assert_eq!(a.meta.stats, b.meta.stats);
    assert_eq!(a.meta.settings, b.meta.settings);
    // The model travels through the shards into the merged file, and the files are the same
    // bytes but for the recorded timings.
    assert!(a.model.is_some());
    assert_eq!(a.model, b.model);
    let (mut a, mut b) = (a, b);
    a.meta.timings.clear();
    b.meta.timings.clear();
    assert!(
        a.to_bytes().unwrap() == b.to_bytes().unwrap(),
        "the merged file differs from the one-process bake beyond timings"
    );

    // A served scene can come from a merge: inspect reads it like any other.
    ok(bounce().arg("inspect").arg(&merged));

    // The refusals a user meets.
    refused(
        bounce()
            .env_remove("JOB_COMPLETION_INDEX")
            .arg("bake")
            .arg(cornell())
            .args(["--shard", "3", "-o"])
            .arg(d.join("x.bshard")),
        "JOB_COMPLETION_INDEX",
    );
    refused(
        bounce()
            .arg("bake")
            .arg(cornell())
            .args(["--shard", "3/3", "-o"])
            .arg(d.join("x.bshard")),
        "does not exist",
    );
    std::fs::remove_file(d.join("ff/ff-00001-of-00003.bshard")).unwrap();
    refused(
        bounce()
            .args(["bake", "transport", "--shard", "0/1", "-o"])
            .arg(d.join("t2"))
            .arg(d.join("ff")),
        "1 of 3 shards missing: 1",
    );
    refused(
        bounce()
            .args(["bake", "merge", "-o"])
            .arg(d.join("m.bounce"))
            .arg(&one),
        "baked file, not a bake shard",
    );
    refused(
        bounce()
            .arg("inspect")
            .arg(d.join("t/t-00000-of-00002.bshard")),
        "bake shard, not a baked file",
    );
    for step in ["transport", "merge"] {
        let out = ok(bounce().args(["bake", step, "--help"]));
        assert!(String::from_utf8_lossy(&out.stdout).contains("JOB_COMPLETION_INDEX"));
    }
}

/// The compose file's one-shot bake service runs deploy/bake-all.sh; so does this.
#[test]
fn the_bake_all_script_bakes_every_scene_once() {
    let dir = tempfile::tempdir().unwrap();
    let scenes = dir.path().join("scenes");
    let baked = dir.path().join("baked");
    // A scene in its own folder, named after it.
    let folder = scenes.join("box");
    std::fs::create_dir_all(&folder).unwrap();
    for f in ["scene.gltf", "scene.bin"] {
        std::fs::copy(repo().join("assets/cornell-box").join(f), folder.join(f)).unwrap();
    }
    let bin = PathBuf::from(env!("CARGO_BIN_EXE_bounce"));
    let script = || {
        let mut c = Command::new("sh");
        c.arg(repo().join("deploy/bake-all.sh"))
            .arg(&scenes)
            .arg(&baked)
            .env("BOUNCE_BIN", &bin)
            .env("BOUNCE_BAKE_ARGS", "--patches 200 --rays 64")
            .env_remove("BOUNCE_REBAKE")
            .env_remove("BOUNCE_DEMO_SCENE");
        c
    };
    let out = ok(&mut script());
    assert!(String::from_utf8_lossy(&out.stdout).contains("1 scene(s)"));
    let file = baked.join("box.bounce");
    let first = Baked::read(&file).expect("the script bakes box/scene.gltf into box.bounce");
    assert!(
        (100..300).contains(&first.layout.len()),
        "--patches 200 applied"
    );
    // Without a codec in BOUNCE_BAKE_ARGS the compose bake takes bake's default: the smallest
    // codec within 1% of the indirect light.
    assert_eq!(first.meta.settings.codec, "auto");
    assert_eq!(first.meta.settings.max_error, Some(0.01));

    // A second run keeps the newer baked file.
    let out = ok(&mut script());
    assert!(String::from_utf8_lossy(&out.stdout).contains("kept"));

    // No scene and no demo: a clear failure, not an empty server.
    std::fs::remove_dir_all(&folder).unwrap();
    let out = run(&mut script());
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no .gltf or .glb scene"));
    // With the demo scene, as the image has it.
    let out = ok(script().env("BOUNCE_DEMO_SCENE", cornell()));
    assert!(String::from_utf8_lossy(&out.stdout).contains("demo Cornell box"));
    Baked::read(&baked.join("cornell-box.bounce")).expect("the demo baked");
}
