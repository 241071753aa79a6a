//! Every codec behind the one interface, on a real baked transport: products equal
//! decode-then-dense products, reordering is lossless, errors stay bounded, and damaged payloads
//! are refused.

use std::path::Path;
use std::sync::OnceLock;

use bounce_core::bake::{BakeOptions, NoProgress, bake_file};
use bounce_core::codec::error::{entry_errors, irradiance_errors, probe_light_sets};
use bounce_core::codec::logblock::LogBlock;
use bounce_core::codec::{Codec, all, decode};
use bounce_core::matrix::DenseMatrix;
use bounce_core::meta::Bounces;
use bounce_core::patch::PatchLayout;
use bounce_core::voxel::Resolution;

/// The Cornell box at about 300 patches, 3 bounces: a small real transport.
fn cornell() -> &'static (DenseMatrix, PatchLayout) {
    static BAKED: OnceLock<(DenseMatrix, PatchLayout)> = OnceLock::new();
    BAKED.get_or_init(|| {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/cornell-box/scene.gltf");
        let options = BakeOptions {
            resolution: Resolution::TargetPatches(300),
            rays: 1024,
            bounces: Bounces::K(3),
            ..BakeOptions::default()
        };
        let baked = bake_file(&path, &options, &NoProgress).unwrap();
        (baked.transport.decode().unwrap(), baked.layout)
    })
}

#[test]
fn every_codec_multiplies_like_its_decoded_matrix() {
    let (t, layout) = cornell();
    let b0 = probe_light_sets(layout, 3);
    for codec in all() {
        let op = decode(&codec.encode(t).unwrap()).unwrap();
        let dense = bounce_core::codec::dense::DenseOp::from(op.to_dense());
        let mut a = vec![[0.0; 3]; b0.len()];
        let mut b = vec![[0.0; 3]; b0.len()];
        op.matvec_batch(&b0, &mut a).unwrap();
        bounce_core::codec::MatrixOp::matvec_batch(&dense, &b0, &mut b).unwrap();
        // Same terms, different summation order (blocks and sparse part apart): rounding only.
        let scale = b.iter().flatten().fold(0.0f32, |m, v| m.max(v.abs()));
        let worst = a
            .iter()
            .flatten()
            .zip(b.iter().flatten())
            .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(
            worst <= 1e-5 * scale,
            "{}: products differ by {worst} (scale {scale})",
            codec.name()
        );
    }
}

#[test]
fn with_everything_sparse_the_thesis_codec_is_exact_in_any_order() {
    let (t, _) = cornell();
    for passes in [0, 1, 2] {
        for base in [LogBlock::bc1(), LogBlock::bc4()] {
            let codec = LogBlock {
                sparse_share: 1.0,
                passes,
                ..base
            };
            let got = decode(&codec.encode(t).unwrap()).unwrap().to_dense();
            assert_eq!(&got, t, "{} with {passes} passes", codec.name());
        }
    }
}

#[test]
fn errors_are_bounded_and_ordered_as_expected() {
    let (t, layout) = cornell();
    let b0 = probe_light_sets(layout, 4);
    let exact = decode(&all()[0].encode(t).unwrap()).unwrap();
    let mut report = Vec::new();
    for codec in all() {
        let enc = codec.encode(t).unwrap();
        let op = decode(&enc).unwrap();
        let entries = entry_errors(t, &op.to_dense());
        let eind = irradiance_errors(exact.as_ref(), op.as_ref(), &b0).unwrap();
        report.push((codec.name(), enc.payload.len(), entries, eind));
    }
    let by = |name: &str| report.iter().find(|r| r.0 == name).unwrap();
    let msg = format!("{report:#?}");
    assert_eq!(by("dense-f32").3.rel_l2, 0.0);
    assert!(by("dense-f16").3.rel_l2 < 1e-3, "{msg}");
    // The thesis codec: a few per cent of E_ind at a sixth of a byte an entry and channel.
    assert!(by("bc1").3.rel_l2 < 0.05, "{msg}");
    assert!(by("bc4").3.rel_l2 < by("bc1").3.rel_l2, "{msg}");
    assert!(
        by("bc1").1 < by("bc4").1 && by("bc4").1 < by("dense-f16").1,
        "{msg}"
    );
}

#[test]
fn auto_picks_the_smallest_codec_within_the_error_budget() {
    let (t, layout) = cornell();
    let b0 = probe_light_sets(layout, 8);
    for max_error in [1e-9, 1e-4, 1e-3, 0.05] {
        let choice = bounce_core::codec::choose(t, &b0, max_error, 0.04).unwrap();
        assert_eq!(choice.candidates.len(), all().len());
        let within: Vec<_> = choice
            .candidates
            .iter()
            .filter(|(_, _, err)| *err <= max_error)
            .collect();
        match within.iter().min_by_key(|(_, bytes, _)| *bytes) {
            Some((name, bytes, err)) => {
                assert_eq!(
                    &choice.encoded.codec, name,
                    "{max_error}: {:?}",
                    choice.candidates
                );
                assert_eq!(choice.encoded.payload.len(), *bytes);
                assert_eq!(choice.rel_l2, *err);
            }
            // Nothing lossy fits: the exact matrix, never something over budget.
            None => assert_eq!(choice.encoded.codec, "dense-f32"),
        }
        assert!(choice.rel_l2 <= max_error);
    }
}

#[test]
fn damaged_payloads_are_refused_not_trusted() {
    let (t, _) = cornell();
    for codec in [LogBlock::bc1(), LogBlock::bc4()] {
        let enc = codec.encode(t).unwrap();
        let mut short = enc.clone();
        short.payload.truncate(enc.payload.len() / 2);
        assert!(decode(&short).is_err());
        let mut long = enc.clone();
        long.payload.push(0);
        assert!(decode(&long).is_err());
        let mut bad_perm = enc.clone();
        bad_perm.payload[0..4].copy_from_slice(&1u32.to_le_bytes());
        bad_perm.payload[4..8].copy_from_slice(&1u32.to_le_bytes());
        assert!(decode(&bad_perm).is_err());
        let mut bad_params = enc.clone();
        bad_params.params["max"] = serde_json::json!([f32::MAX, -1.0, 0.0]);
        assert!(decode(&bad_params).is_err());
        let mut no_params = enc;
        no_params.params = serde_json::json!({});
        assert!(decode(&no_params).is_err());
    }
}
