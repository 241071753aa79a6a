//! A sharded bake (phase-1 shards of `F`, phase-2 shards of `T`, merge) through real shard files
//! gives the baked file one process gives, bit for bit but for the recorded timings; and every way
//! of handing a step the wrong shards is refused with a message that says what is wrong.

use std::path::{Path, PathBuf};

use bounce_core::bake::shard::{self, Phase, ShardError, ShardSpec, shard_rows};
use bounce_core::bake::{BakeOptions, CodecRequest, NoProgress, bake_file};
use bounce_core::format::{Baked, FormatError, ShardFile};
use bounce_core::import::pack_glb;
use bounce_core::meta::Bounces;
use bounce_core::probe::ProbeOptions;
use bounce_core::voxel::Resolution;

fn cornell() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box/scene.gltf")
}

fn options() -> BakeOptions {
    BakeOptions {
        resolution: Resolution::TargetPatches(290),
        rays: 128,
        ..BakeOptions::default()
    }
}

fn spec(index: u32, count: u32) -> ShardSpec {
    ShardSpec { index, count }
}

/// Phase 1 in `count` shards written under `dir`; their paths.
fn phase1(scene: &Path, options: &BakeOptions, count: u32, dir: &Path) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    (0..count)
        .map(|i| {
            let mut file = shard::form_factor_shard(scene, options, spec(i, count), &NoProgress)
                .unwrap_or_else(|e| panic!("phase 1, shard {i}/{count}: {e}"));
            // As `bounce bake --shard` does: each shard carries the packed scene.
            file.model = Some(pack_glb(scene).unwrap());
            let path = dir.join(Phase::FormFactors.file_name(spec(i, count)));
            file.write_atomic(&path).unwrap();
            path
        })
        .collect()
}

/// Phase 2 in `count` shards from `inputs`, written under `dir`; their paths.
fn phase2(inputs: &[PathBuf], count: u32, dir: &Path) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    (0..count)
        .map(|i| {
            let file = shard::transport_shard(inputs, spec(i, count), &NoProgress)
                .unwrap_or_else(|e| panic!("phase 2, shard {i}/{count}: {e}"));
            let path = dir.join(Phase::Transport.file_name(spec(i, count)));
            file.write_atomic(&path).unwrap();
            path
        })
        .collect()
}

/// The one-process bake, keeping the model as `bounce bake` does.
fn bake_one(scene: &Path, options: &BakeOptions) -> Baked {
    let mut one = bake_file(scene, options, &NoProgress).unwrap();
    one.model = Some(pack_glb(scene).unwrap());
    one
}

/// The two bakes agree in everything but timings, down to the bytes of the written file.
fn assert_same_bake(one: &Baked, merged: &Baked, what: &str) {
    assert_eq!(one.layout, merged.layout, "{what}: layout");
    assert_eq!(one.occupancy, merged.occupancy, "{what}: occupancy");
    assert_eq!(one.transport, merged.transport, "{what}: transport");
    assert_eq!(
        one.form_factors, merged.form_factors,
        "{what}: form factors"
    );
    assert_eq!(one.meta.stats, merged.meta.stats, "{what}: statistics");
    assert!(
        merged.model.is_some(),
        "{what}: the merged file keeps the model"
    );
    assert_eq!(one.model, merged.model, "{what}: model");
    assert_eq!(one.near_field, merged.near_field, "{what}: near field");
    assert!(one.sky.is_some(), "{what}: the bake keeps a sky view");
    assert_eq!(one.sky, merged.sky, "{what}: sky view");
    assert!(
        one.emitters.is_some(),
        "{what}: the bake lists its emitters"
    );
    assert_eq!(one.emitters, merged.emitters, "{what}: emitters");
    assert_eq!(one.probes, merged.probes, "{what}: probes");
    let stages =
        |b: &Baked| -> Vec<String> { b.meta.timings.iter().map(|t| t.stage.clone()).collect() };
    assert!(
        stages(merged).contains(&"form factors".to_string()),
        "{what}"
    );
    let (mut a, mut b) = (one.clone(), merged.clone());
    a.meta.timings.clear();
    b.meta.timings.clear();
    assert!(
        a.to_bytes().unwrap() == b.to_bytes().unwrap(),
        "{what}: the files differ beyond timings"
    );
}

#[test]
fn sharded_bakes_equal_the_one_process_bake() {
    let dir = tempfile::tempdir().unwrap();
    let scene = cornell();
    let one = bake_one(&scene, &options());
    // Shards hold rows of the transport: the elements.
    let n = one.transport_layout().len();
    assert_eq!(one.meta.stats.channels, 3, "coloured walls: three channels");
    // Three shards of a row count that 3 does not divide, so the split is uneven.
    assert_ne!(
        n % 3,
        0,
        "{n} rows: pick a target whose count 3 does not divide"
    );

    for (ff_count, t_count) in [(1, 1), (2, 2), (3, 3), (3, 2)] {
        let what = format!("{ff_count} form-factor shards, {t_count} transport shards");
        let base = dir.path().join(format!("{ff_count}-{t_count}"));
        let ff = phase1(&scene, &options(), ff_count, &base.join("ff"));
        // Each shard holds exactly its rows.
        for (i, path) in ff.iter().enumerate() {
            let file = ShardFile::read(path).unwrap();
            let rows = shard_rows(n, i as u32, ff_count);
            assert_eq!(
                (file.header.meta.first_row, file.header.meta.end_row),
                (rows.start, rows.end)
            );
            assert_eq!(file.rows.len(), rows.len() * n, "{what}");
        }
        let t = phase2(&ff, t_count, &base.join("t"));
        // A directory stands for its shards.
        let merged = shard::merge(&[base.join("t")], &NoProgress).unwrap();
        assert_same_bake(&one, &merged, &what);
        let _ = t;
    }

    // Straight from phase 1 (the merge computes the transport itself).
    let ff = phase1(&scene, &options(), 2, &dir.path().join("direct"));
    let merged = shard::merge(&ff, &NoProgress).unwrap();
    assert_same_bake(&one, &merged, "merge of phase-1 shards");
}

#[test]
fn an_emissive_scene_shards_with_its_emitters() {
    let dir = tempfile::tempdir().unwrap();
    let scene =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box-emissive/CornellBox.glb");
    let one = bake_one(&scene, &options());
    assert!(
        one.emitters.as_ref().is_some_and(|e| !e.entries.is_empty()),
        "the ceiling lamp covers rows"
    );
    let ff = phase1(&scene, &options(), 2, &dir.path().join("ff"));
    let t = phase2(&ff, 3, &dir.path().join("t"));
    let merged = shard::merge(&t, &NoProgress).unwrap();
    assert_same_bake(&one, &merged, "the emissive box");
}

#[test]
fn probes_shard_too() {
    let dir = tempfile::tempdir().unwrap();
    let scene = cornell();
    let options = BakeOptions {
        probes: Some(ProbeOptions {
            spacing: None,
            rays: 64,
        }),
        ..options()
    };
    let one = bake_one(&scene, &options);
    let probes = one.probes.as_ref().expect("the bake places probes");
    let gathers = probes.len() * bounce_core::probe::DIRECTIONS;
    assert!(
        probes.len() >= 4,
        "{} probes: enough for three shards",
        probes.len()
    );
    let ff = phase1(&scene, &options, 3, &dir.path().join("ff"));
    // Each phase-1 shard gathers its share of the rows, and places every probe.
    for (i, path) in ff.iter().enumerate() {
        let rows = ShardFile::read(path).unwrap().probe_rows.unwrap();
        assert_eq!(rows.range, shard_rows(gathers, i as u32, 3));
        assert_eq!(rows.positions, probes.positions);
    }
    let t = phase2(&ff, 2, &dir.path().join("t"));
    assert_same_bake(&one, &shard::merge(&t, &NoProgress).unwrap(), "probes");
    assert_same_bake(
        &one,
        &shard::merge(&ff, &NoProgress).unwrap(),
        "probes, merge of phase-1 shards",
    );
    // A shard holding another shard's share of the probes is refused on reading.
    let mut wrong = ShardFile::read(&ff[0]).unwrap();
    wrong.probe_rows = ShardFile::read(&ff[1]).unwrap().probe_rows;
    let e = wrong.to_bytes().unwrap_err().to_string();
    assert!(e.contains("gather rows"), "{e}");
}

#[test]
fn all_bounces_a_codec_and_kept_form_factors_shard_too() {
    let dir = tempfile::tempdir().unwrap();
    let scene = cornell();
    let options = BakeOptions {
        bounces: Bounces::All,
        keep_form_factors: true,
        codec: CodecRequest::Named("bc1".to_string()),
        ..options()
    };
    let one = bake_one(&scene, &options);
    assert!(one.form_factors.is_some());
    let ff = phase1(&scene, &options, 2, &dir.path().join("ff"));
    let t = phase2(&ff, 3, &dir.path().join("t"));
    let merged = shard::merge(&t, &NoProgress).unwrap();
    assert_eq!(merged.transport.codec, "bc1");
    assert_same_bake(&one, &merged, "all bounces, bc1, F kept");
}

fn err(r: Result<impl std::fmt::Debug, ShardError>) -> String {
    r.expect_err("the step must refuse these shards")
        .to_string()
}

#[test]
fn wrong_sets_of_shards_are_refused_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = cornell();
    let ff = phase1(&scene, &options(), 3, &d.join("ff"));
    let t = phase2(&ff, 2, &d.join("t"));

    let e = err(shard::merge(&[], &NoProgress));
    assert!(e.contains("no shards"), "{e}");

    let e = err(shard::merge(&[ff[0].clone(), ff[2].clone()], &NoProgress));
    assert!(e.contains("1 of 3 shards missing: 1"), "{e}");

    let e = err(shard::merge(
        &[ff[0].clone(), ff[1].clone(), ff[1].clone(), ff[2].clone()],
        &NoProgress,
    ));
    assert!(e.contains("shard 1/3 is given twice"), "{e}");

    // Another split's shard in the directory (a stale run).
    let stale = phase1(&scene, &options(), 2, &d.join("stale"));
    let e = err(shard::merge(
        &[ff[0].clone(), ff[1].clone(), stale[1].clone()],
        &NoProgress,
    ));
    assert!(
        e.contains("one of 2 shards") && e.contains("one split"),
        "{e}"
    );

    // Phase 1 and phase 2 mixed; phase 2 handed phase-2 shards.
    let e = err(shard::merge(&[t[0].clone(), ff[1].clone()], &NoProgress));
    assert!(e.contains("form-factor (phase 1) rows"), "{e}");
    let e = err(shard::transport_shard(&t, spec(0, 1), &NoProgress));
    assert!(
        e.contains("holds transport (phase 2) rows, but this step reads form-factor"),
        "{e}"
    );

    // Other settings: another seed.
    let reseeded = BakeOptions {
        seed: 7,
        ..options()
    };
    let other = phase1(&scene, &reseeded, 3, &d.join("seed"));
    let e = err(shard::merge(
        &[ff[0].clone(), other[1].clone(), ff[2].clone()],
        &NoProgress,
    ));
    assert!(
        e.contains("not shards of the same bake") && e.contains("settings"),
        "{e}"
    );

    // Another scene (the same glTF under another name, with its buffer beside it).
    let copy = d.join("copy");
    std::fs::create_dir_all(&copy).unwrap();
    let src = cornell();
    let src_dir = src.parent().unwrap();
    std::fs::copy(src_dir.join("scene.bin"), copy.join("scene.bin")).unwrap();
    std::fs::copy(&src, copy.join("other.gltf")).unwrap();
    let renamed = phase1(&copy.join("other.gltf"), &options(), 3, &d.join("renamed"));
    let e = err(shard::merge(
        &[ff[0].clone(), ff[1].clone(), renamed[2].clone()],
        &NoProgress,
    ));
    assert!(e.contains("source scenes"), "{e}");

    // Phase-2 shards computed from different phase-1 shards.
    let t_other = phase2(&other, 2, &d.join("t-seed"));
    let e = err(shard::merge(
        &[t[0].clone(), t_other[1].clone()],
        &NoProgress,
    ));
    assert!(e.contains("differ"), "{e}");

    // A damaged shard: one flipped byte in its rows, or cut short.
    let damaged = d.join("damaged.bshard");
    let mut bytes = std::fs::read(&ff[1]).unwrap();
    let last = bytes.len() - 3;
    bytes[last] ^= 0x40;
    std::fs::write(&damaged, &bytes).unwrap();
    let e = err(shard::merge(
        &[ff[0].clone(), damaged.clone(), ff[2].clone()],
        &NoProgress,
    ));
    assert!(
        e.contains("damaged.bshard") && e.contains("checksum mismatch in section 'ROWS'"),
        "{e}"
    );
    std::fs::write(&damaged, &bytes[..bytes.len() / 2]).unwrap();
    let e = err(shard::merge(
        &[ff[0].clone(), damaged.clone(), ff[2].clone()],
        &NoProgress,
    ));
    assert!(e.contains("truncated"), "{e}");

    // A baked file is not a shard, and a shard is not a baked file.
    let baked = d.join("x.bounce");
    shard::merge(&ff, &NoProgress)
        .unwrap()
        .write_atomic(&baked)
        .unwrap();
    let e = err(shard::merge(std::slice::from_ref(&baked), &NoProgress));
    assert!(e.contains("baked file, not a bake shard"), "{e}");
    match Baked::read(&ff[0]) {
        Err(FormatError::ShardNotBaked) => {}
        other => panic!("a shard read as a baked file: {other:?}"),
    }
}
