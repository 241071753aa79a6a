//! Every GPU kernel against its CPU twin (the codec's `MatrixOp`) on transport-like matrices.
//!
//! These run for real on whatever adapter wgpu finds; in CI that is lavapipe (software Vulkan).
//! Without an adapter they fail, unless `BOUNCE_ALLOW_NO_GPU=1` says skipping is intended.

use bounce_core::codec::dense::{DenseF16, DenseF32};
use bounce_core::codec::logblock::LogBlock;
use bounce_core::codec::{Codec, decode};
use bounce_core::matrix::{DenseMatrix, EncodedMatrix};
use bounce_engine::gpu::{BatchKernel, CHUNK, GpuError, GpuMatrix, Split};

use crate::common::context;

/// Deterministic uniform numbers in [0, 1).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Transport-like: non-negative, entries over about six decades, a zero diagonal and a fifth of
/// the entries exactly zero (occluded pairs), channels alike but not equal.
fn transport(n: usize, channels: usize, seed: u64) -> DenseMatrix {
    let mut rng = Lcg(seed);
    let mut m = DenseMatrix::zeros(n, channels);
    for i in 0..n {
        for j in 0..n {
            let visible = i != j && rng.next() >= 0.2;
            let v = (rng.next() * 20.0 - 20.0).exp2() * 0.2;
            for c in 0..channels {
                let tint = 0.6 + 0.4 * rng.next();
                m.channel_mut(c)[i * n + j] = if visible { v * tint } else { 0.0 };
            }
        }
    }
    m
}

/// `sets` light configurations: non-negative, some patches unlit, a few bright.
fn lights(n: usize, sets: usize, seed: u64) -> Vec<[f32; 3]> {
    let mut rng = Lcg(seed);
    (0..n * sets)
        .map(|_| {
            if rng.next() < 0.3 {
                [0.0; 3]
            } else {
                let s = (rng.next() * 10.0).exp2();
                [s * rng.next(), s * rng.next(), s * rng.next()]
            }
        })
        .collect()
}

fn cpu(m: &EncodedMatrix, x: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let mut out = vec![[0.0; 3]; x.len()];
    decode(m).unwrap().matvec_batch(x, &mut out).unwrap();
    out
}

fn gpu(m: &GpuMatrix, x: &[[f32; 3]]) -> Vec<[f32; 3]> {
    let mut out = vec![[f32::NAN; 3]; x.len()];
    m.matvec_batch(x, &mut out).unwrap();
    out
}

fn norm(v: &[[f32; 3]]) -> f64 {
    v.iter()
        .flatten()
        .map(|&a| f64::from(a) * f64::from(a))
        .sum::<f64>()
        .sqrt()
}

/// Per light set, `‖got − want‖₂ / ‖want‖₂`; the largest over the batch.
fn rel_l2(got: &[[f32; 3]], want: &[[f32; 3]], n: usize) -> f64 {
    got.chunks(n)
        .zip(want.chunks(n))
        .map(|(g, w)| {
            let diff: Vec<[f32; 3]> = g
                .iter()
                .zip(w)
                .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
                .collect();
            let (d, w) = (norm(&diff), norm(w));
            if w == 0.0 { d } else { d / w }
        })
        .fold(0.0, f64::max)
}

/// Sizes around the kernels' edges: a single patch, fewer patches than a workgroup's threads,
/// sizes off the multiples of 4 (block rows) and 64 (thread stride).
const SIZES: [usize; 4] = [1, 5, 37, 130];

fn dense_against_cpu(codec: &dyn Codec) {
    let Some(ctx) = context() else { return };
    for channels in [1, 3] {
        for n in SIZES {
            let enc = codec.encode(&transport(n, channels, n as u64)).unwrap();
            let m = GpuMatrix::upload(ctx, &enc).unwrap();
            for sets in [1, 3, 8, 64, 70] {
                let x = lights(n, sets, 7 + sets as u64);
                let err = rel_l2(&gpu(&m, &x), &cpu(&enc, &x), n);
                // Same f32 products summed in another order: a few ulps times log2(n). A log8
                // matrix on tensor cores takes its large batches with f16 inputs: 2^-11 each.
                let tensor = m.batch_kernel() == BatchKernel::Tensor && sets > CHUNK as usize;
                let close = if tensor { 3e-3 } else { 1e-4 };
                assert!(
                    err <= close,
                    "{} n={n} channels={channels} sets={sets}: rel L2 {err:e}",
                    codec.name()
                );
            }
        }
    }
}

#[test]
fn dense_f32_matvec_matches_cpu() {
    dense_against_cpu(&DenseF32);
}

/// `log8`'s codes go up as an 8-bit texture, which decodes exactly (`q / 255`): unlike the BC
/// formats, the GPU applies the same matrix as the CPU, up to `exp` in f32 against the CPU
/// table's f64.
#[test]
fn log8_matvec_matches_cpu() {
    dense_against_cpu(&LogBlock::log8());
}

#[test]
fn dense_f16_matvec_matches_cpu() {
    // Both sides widen the same halves to f32 exactly, so the f32 tolerance holds.
    dense_against_cpu(&DenseF16);
}

/// How far, in codes of the log quantisation (a code is a factor `e^{25/255}`), a texture
/// unit's decode of a block texel may land from the CPU's (bcdec's). Block decoding is the one
/// place where a GPU does not compute what its CPU twin does: the formats leave the palette's
/// rounding to the decoder.
/// - Software (Mesa's lavapipe, what CI runs): bcdec expands 5- and 6-bit endpoints with
///   rounding (up to ½ code) and interpolates in integers with truncation (under 1 code); Mesa
///   returns whole codes at most 1 off. Bound: 1.5 codes.
/// - Hardware: vendors interpolate BC1 in their own fixed point (rgbcx models NVIDIA's and AMD's
///   BC1 as separate decoders). Measured on an H100 (NVIDIA 580): BC1 green and BC4 land up to
///   about 3 codes off. Bound: 4 codes.
///
/// What this costs the service is the product's error, which averages over many entries: on the
/// H100 a bc1 product is 1.2% (rel. L2) from the CPU's, and `bench engines` shows the GPU's
/// error against the exact matrix within a few percent of the CPU's.
fn code_step(ctx: &bounce_engine::gpu::GpuContext) -> f64 {
    let codes = if ctx.adapter().software { 1.5 } else { 4.0 };
    (25.0 * codes / 255.0f64).exp() - 1.0
}

/// The block kernels against the CPU decode of the same blocks. Texture hardware interpolates
/// BC palettes with its own rounding (see `logblock.wgsl`), which may land up to 1.5 8-bit codes
/// away from the CPU decoder (bcdec's rounding; see [`code_step`]). Codes
/// 0 decode to exactly 0 on both (zero endpoints, BC1's transparent black). So every block entry
/// is within code_step relative of the CPU's, the sparse entries are the same f32s, and with
/// non-negative entries and lights every output is within code_step relative, plus f32 rounding.
/// Any larger deviation is a kernel bug (wrong texel, permutation or channel), not rounding.
fn blocks_against_cpu(codec: LogBlock) {
    let Some(ctx) = context() else { return };
    let step = code_step(ctx);
    for channels in [1, 3] {
        for n in SIZES {
            let enc = codec
                .encode(&transport(n, channels, 100 + n as u64))
                .unwrap();
            let m = GpuMatrix::upload(ctx, &enc).unwrap();
            let mut worst = 0.0f64;
            for sets in [1, 3, 8, 64, 70] {
                let x = lights(n, sets, 11 + sets as u64);
                let (got, want) = (gpu(&m, &x), cpu(&enc, &x));
                for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                    for c in 0..3 {
                        let (g, w) = (f64::from(g[c]), f64::from(w[c]));
                        assert!(
                            (g - w).abs() <= (step + 1e-4) * w + 1e-30,
                            "{} n={n} ch={channels} sets={sets} out[{k}][{c}]: gpu {g:e} cpu {w:e}",
                            enc.codec
                        );
                    }
                }
                worst = worst.max(rel_l2(&got, &want, n));
            }
            eprintln!(
                "{} n={n} ch={channels}: GPU vs CPU rel L2 {worst:.2e}",
                enc.codec
            );
        }
    }
}

#[test]
fn bc1_matvec_matches_cpu_decode() {
    blocks_against_cpu(LogBlock::bc1());
}

/// `bc1-resid`: the same blocks plus corrections computed against the CPU decode, which may be
/// negative. Where the GPU decodes a corrected texel a code away from the CPU, the correction no
/// longer cancels that difference, so the bound is a code step of the block part alone:
/// `|gpu − cpu| ≤ code_step · (cpu + Σ_j |correction_ij| x_j)` (the block part is `cpu − Σ corr·x`).
#[test]
fn bc1_resid_matvec_matches_cpu_decode() {
    let Some(ctx) = context() else { return };
    let step = code_step(ctx);
    for channels in [1, 3] {
        for n in SIZES {
            let enc = LogBlock::bc1_resid()
                .encode(&transport(n, channels, 300 + n as u64))
                .unwrap();
            let sparse = bounce_core::codec::logblock::decode(
                &enc,
                bounce_core::codec::logblock::Blocks::Bc1,
            )
            .unwrap()
            .sparse()
            .clone();
            let m = GpuMatrix::upload(ctx, &enc).unwrap();
            for sets in [1, 3, 8] {
                let x = lights(n, sets, 17 + sets as u64);
                let (got, want) = (gpu(&m, &x), cpu(&enc, &x));
                for k in 0..sets {
                    for i in 0..n {
                        for c in 0..3 {
                            let cc = c.min(channels - 1);
                            let corr: f64 = (sparse.row_ptr[i]..sparse.row_ptr[i + 1])
                                .map(|e| {
                                    let j = sparse.col_idx[e as usize] as usize;
                                    f64::from(sparse.values[cc * sparse.nnz() + e as usize]).abs()
                                        * f64::from(x[k * n + j][c])
                                })
                                .sum();
                            let (g, w) =
                                (f64::from(got[k * n + i][c]), f64::from(want[k * n + i][c]));
                            let bound = (step + 1e-4) * (w.abs() + corr) + 1e-30;
                            assert!(
                                (g - w).abs() <= bound,
                                "n={n} ch={channels} sets={sets} out[{k}][{i}][{c}]: gpu {g:e} cpu {w:e}"
                            );
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn bc4_matvec_matches_cpu_decode() {
    blocks_against_cpu(LogBlock::bc4());
}

/// The matrix the GPU effectively applies, read out column by column with one-hot lights (one
/// batch of n sets), against the CPU decode: zeros stay exactly zero, others within code_step.
/// No sparse part, so every entry comes from the texture.
#[test]
fn block_entries_decode_like_the_cpu() {
    let Some(ctx) = context() else { return };
    let step = code_step(ctx);
    let n = 37;
    for base in [LogBlock::bc1(), LogBlock::bc4()] {
        for channels in [1, 3] {
            let codec = LogBlock {
                sparse_share: 0.0,
                ..base
            };
            let enc = codec.encode(&transport(n, channels, 5)).unwrap();
            let exact = decode(&enc).unwrap().to_dense();
            let m = GpuMatrix::upload(ctx, &enc).unwrap();
            let mut x = vec![[0.0f32; 3]; n * n];
            for k in 0..n {
                x[k * n + k] = [1.0; 3];
            }
            let got = gpu(&m, &x);
            let (mut off, mut codes) = (0, 0.0f64);
            for k in 0..n {
                for i in 0..n {
                    for (c, &g) in got[k * n + i].iter().enumerate() {
                        let g = f64::from(g);
                        let w = f64::from(exact.get(c.min(channels - 1), i, k));
                        if w == 0.0 {
                            assert_eq!(g, 0.0, "{} ch={channels} ({i},{k}) c{c}", enc.codec);
                        }
                        assert!(
                            (g - w).abs() <= step * w * (1.0 + 1e-4),
                            "{} ch={channels} ({i},{k}) c{c}: gpu {g:e} cpu {w:e}",
                            enc.codec
                        );
                        if (g - w).abs() > 1e-5 * w {
                            off += 1;
                        }
                        if w > 0.0 && g > 0.0 {
                            codes = codes.max((g / w).ln().abs() * 255.0 / 25.0);
                        }
                    }
                }
            }
            eprintln!(
                "{} ch={channels}: {off} of {} entries decode off the CPU value by > 1e-5, \
                 at most {codes:.3} codes",
                enc.codec,
                3 * n * n
            );
        }
    }
}

/// A set's result does not depend on the sets beside it in the batch. Batches of up to CHUNK
/// sets run the matrix-vector kernel, where each set's sums run in the same order whatever chunk
/// it lands in: bit for bit the sets one by one. Larger batches run the tiled kernel, which sums
/// each row over the columns in order: bit for bit the same set in any other large batch (here
/// at another place among other sets), and the one-by-one result to f32 rounding.
#[test]
fn batched_equals_one_by_one() {
    let Some(ctx) = context() else { return };
    let n = 37;
    let t = transport(n, 3, 9);
    let codecs: [Box<dyn Codec>; 4] = [
        Box::new(DenseF32),
        Box::new(DenseF16),
        Box::new(LogBlock::bc1()),
        Box::new(LogBlock::bc4()),
    ];
    for codec in codecs {
        let enc = codec.encode(&t).unwrap();
        let m = GpuMatrix::upload(ctx, &enc).unwrap();
        for sets in [1, 3, 8, 9, 64, 70] {
            let x = lights(n, sets, 3);
            let batched = gpu(&m, &x);
            // The same sets in reverse order, after one more.
            let mut other = lights(n, 1, 4);
            for k in (0..sets).rev() {
                other.extend_from_slice(&x[k * n..(k + 1) * n]);
            }
            let moved = gpu(&m, &other);
            // The tensor kernel's f16 inputs put its sums about 1e-3 from the FP32 kernels'.
            let close = match m.batch_kernel() {
                BatchKernel::Tensor => 3e-3,
                _ => 1e-5,
            };
            for k in 0..sets {
                let got = &batched[k * n..(k + 1) * n];
                let one = gpu(&m, &x[k * n..(k + 1) * n]);
                if sets <= CHUNK as usize {
                    assert_eq!(got, &one[..], "{} set {k} of {sets}", enc.codec);
                } else {
                    let at = (sets - k) * n;
                    assert_eq!(
                        got,
                        &moved[at..at + n],
                        "{} set {k} of {sets}, moved",
                        enc.codec
                    );
                    let err = rel_l2(got, &one, n);
                    assert!(err <= close, "{} set {k} of {sets}: {err:e}", enc.codec);
                }
            }
        }
    }
}

/// The tensor-core kernel against its FP32 twin (the tiled kernel, same upload) and the CPU
/// decode, for the block codecs and batches over CHUNK sets, on matrices with columns off the
/// 32-column step and rows off the 64-row tile. The f16 inputs cost 2^-11 relative each, so the
/// sums stay within 3e-3 (rel. L2) of the FP32 kernel's; against the CPU the bound is the code
/// step of `blocks_against_cpu` plus that. Where the device has no tensor cores (lavapipe: no
/// cooperative matrices) the engine must say so and run the FP32 kernel: that is what this
/// checks there, and the kernel itself is checked on the machines that have them.
#[test]
fn tensor_kernel_matches_its_fp32_twin() {
    let Some(ctx) = context() else { return };
    let step = code_step(ctx);
    for codec in [LogBlock::bc1(), LogBlock::bc4(), LogBlock::bc1_resid()] {
        for (n, channels) in [(5, 3), (37, 1), (130, 3), (300, 3)] {
            let enc = codec
                .encode(&transport(n, channels, 500 + n as u64))
                .unwrap();
            let mut m = GpuMatrix::upload(ctx, &enc).unwrap();
            let took = m.set_kernel(BatchKernel::Tensor);
            if !ctx.adapter().tensor_cores {
                assert_eq!(took, BatchKernel::Tiled, "no tensor cores: the FP32 kernel");
                assert!(m.tensor_refused().is_none());
            } else {
                assert_eq!(
                    took,
                    BatchKernel::Tensor,
                    "{}: the driver refused the tensor kernel: {:?}",
                    enc.codec,
                    m.tensor_refused()
                );
            }
            for sets in [9, 64, 130] {
                let x = lights(n, sets, 23 + sets as u64);
                m.set_kernel(BatchKernel::Tensor);
                let tensor = gpu(&m, &x);
                m.set_kernel(BatchKernel::Tiled);
                let tiled = gpu(&m, &x);
                let want = cpu(&enc, &x);
                let err = rel_l2(&tensor, &tiled, n);
                eprintln!(
                    "{} n={n} ch={channels} sets={sets} ({took:?}): against FP32 rel L2 {err:.2e}",
                    enc.codec
                );
                assert!(err <= 3e-3, "{} n={n} sets={sets}: {err:e}", enc.codec);
                if enc.codec != "bc1-resid" {
                    for (k, (g, w)) in tensor.iter().zip(&want).enumerate() {
                        for c in 0..3 {
                            let (g, w) = (f64::from(g[c]), f64::from(w[c]));
                            assert!(
                                (g - w).abs() <= (step + 3e-3) * w + 1e-30,
                                "{} n={n} sets={sets} out[{k}][{c}]: tensor {g:e} cpu {w:e}",
                                enc.codec
                            );
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn bad_input_is_an_error() {
    let Some(ctx) = context() else { return };
    let enc = DenseF32.encode(&transport(6, 1, 1)).unwrap();
    let m = GpuMatrix::upload(ctx, &enc).unwrap();
    let mut out = vec![[0.0; 3]; 7];
    assert!(m.matvec_batch(&[[0.0; 3]; 7], &mut out).is_err());
    let mut out = vec![[0.0; 3]; 12];
    assert!(m.matvec_batch(&[[0.0; 3]; 6], &mut out).is_err());
    let unknown = EncodedMatrix {
        codec: "bc6h".into(),
        ..enc.clone()
    };
    assert!(matches!(
        GpuMatrix::upload(ctx, &unknown),
        Err(GpuError::UnsupportedCodec(_))
    ));
    let mut short = enc;
    short.payload.pop();
    assert!(GpuMatrix::upload(ctx, &short).is_err());
}

/// Limits small enough that every matrix below is cut: dense bands of 7 rows, block tiles of
/// 16 texels (so 37 columns make 3 × 3 tiles).
/// Every codec the GPU uploads, with the bytes a dense entry takes (1 for the block codecs, whose
/// pieces are texture tiles, not bands of entries).
fn every_codec() -> [(Box<dyn Codec>, usize); 6] {
    [
        (Box::new(DenseF32), 4),
        (Box::new(DenseF16), 2),
        (Box::new(LogBlock::bc1()), 1),
        (Box::new(LogBlock::bc1_resid()), 1),
        (Box::new(LogBlock::bc4()), 1),
        (Box::new(LogBlock::log8()), 1),
    ]
}

fn small_split(n: usize, channels: usize, width: usize) -> Split {
    Split {
        binding_bytes: (7 * n * channels * width) as u64,
        texture_side: 16,
        texture_layers: 256,
    }
}

/// A matrix over the device's limits goes up in row bands (dense, and the block codecs' sparse
/// part) or texture tiles (block codecs). Every codec, cut small on this adapter: the product equals the uncut upload bit for
/// bit (each row's sum runs in the same order), and so stays the CPU twin's.
#[test]
fn split_matrices_equal_whole_ones() {
    let Some(ctx) = context() else { return };
    let step = code_step(ctx);
    for (codec, width) in &every_codec() {
        for channels in [1, 3] {
            for n in [5, 37, 130] {
                let enc = codec
                    .encode(&transport(n, channels, 700 + n as u64))
                    .unwrap();
                let whole = GpuMatrix::upload(ctx, &enc).unwrap();
                let cut =
                    GpuMatrix::upload_split(ctx, &enc, small_split(n, channels, *width)).unwrap();
                assert_eq!(whole.pieces(), 1, "{} n={n}", enc.codec);
                let expect = if *width > 1 {
                    n.div_ceil(7)
                } else {
                    (n.div_ceil(4) * 4).div_ceil(16).pow(2)
                };
                assert_eq!(cut.pieces(), expect, "{} n={n} ch={channels}", enc.codec);
                // The exactly kept entries (4–8% of n², 4 bytes a channel) outgrow 7 rows' worth
                // of bytes at n = 130: they go in row bands too.
                assert!(whole.sparse_bands() <= 1, "{}", enc.codec);
                if *width == 1 && n == 130 {
                    assert!(cut.sparse_bands() > 1, "{} ch={channels}", enc.codec);
                }
                for sets in [1, 3, 9] {
                    let x = lights(n, sets, 23 + sets as u64);
                    let got = gpu(&cut, &x);
                    assert_eq!(
                        got,
                        gpu(&whole, &x),
                        "{} n={n} ch={channels} sets={sets}: cut against whole",
                        enc.codec
                    );
                    let err = rel_l2(&got, &cpu(&enc, &x), n);
                    assert!(
                        err <= step,
                        "{} n={n} ch={channels}: rel L2 {err:e} against the CPU",
                        enc.codec
                    );
                }
            }
        }
    }
}

/// A matrix that needs more tiles than a texture array holds is refused with the reason (the
/// engine then keeps that scene's transport on the CPU), not uploaded wrong.
#[test]
fn too_many_tiles_is_refused() {
    let Some(ctx) = context() else { return };
    let enc = LogBlock::bc4().encode(&transport(37, 3, 3)).unwrap();
    let split = Split {
        texture_layers: 8,
        ..small_split(37, 3, 1)
    };
    match GpuMatrix::upload_split(ctx, &enc, split) {
        Err(GpuError::TooLarge { what, needed, .. }) => {
            assert!(what.contains("tiles"), "{what}");
            assert_eq!(needed, 27, "3 × 3 tiles of 3 channels");
        }
        Err(e) => panic!("wrong error: {e}"),
        Ok(_) => panic!("27 layers uploaded into 8"),
    }
}

/// The bandwidth probe reads every word: its checksum is the CPU's wrapping sum of the buffer,
/// on a size that is no multiple of a dispatch's stride.
#[test]
fn bandwidth_probe_reads_every_word() {
    use bounce_engine::gpu::bandwidth::{checksum, measure, pattern};
    let Some(ctx) = context() else { return };
    let bytes = (3 << 20) + 48;
    let b = measure(ctx, bytes, 2).unwrap();
    assert_eq!(b.bytes, bytes);
    assert_eq!(b.checksum, checksum((0..(bytes / 4) as u32).map(pattern)));
    assert!(b.bytes_per_s.is_finite() && b.bytes_per_s > 0.0);
}

/// Where the device has timestamp queries (lavapipe and NVIDIA do), a product reports the time
/// its kernels took: positive and within the product's wall time, which also holds the light's
/// upload, the readback and the submission.
#[test]
fn products_time_their_kernels() {
    let Some(ctx) = context() else { return };
    let n = 130;
    let enc = DenseF32.encode(&transport(n, 3, 41)).unwrap();
    let m = GpuMatrix::upload(ctx, &enc).unwrap();
    let x = lights(n, 9, 5);
    gpu(&m, &x);
    let start = std::time::Instant::now();
    gpu(&m, &x);
    let wall = start.elapsed().as_secs_f64();
    let timed = ctx
        .device()
        .features()
        .contains(wgpu::Features::TIMESTAMP_QUERY);
    eprintln!("timestamp queries on {}: {timed}", ctx.adapter());
    match m.last_kernel_seconds() {
        Some(k) => assert!(timed && k > 0.0 && k <= wall, "kernel {k} s, wall {wall} s"),
        None => assert!(
            !timed,
            "the device has timestamp queries but no time came back"
        ),
    }
}

/// `sets` light sets of `n` patches, dark but for some of the `lit` patches (each set its own
/// subset, so a batch's union is more than any one set).
fn lit_only(n: usize, sets: usize, lit: &[usize]) -> Vec<[f32; 3]> {
    let mut x = vec![[0.0; 3]; n * sets];
    for k in 0..sets {
        for (q, &j) in lit.iter().enumerate() {
            if (q + k) % 2 == 0 || sets == 1 {
                x[k * n + j] = [1.0 + q as f32, 0.5, 0.25 * (k + 1) as f32];
            }
        }
    }
    x
}

/// The matrix-vector kernels skip the column groups every set of the batch leaves dark. A dark
/// column adds exactly zero, and each thread keeps its own columns in the same order, so the
/// product has the same bits as walking every column: for every codec, whole and cut to the
/// device's forced small limits, one set, a chunk, and a batch the matrix-vector kernel runs in
/// several passes. A dense matrix lit in two of five groups walks two fifths of them; an all-dark
/// batch walks none and returns zeros.
#[test]
fn dark_column_groups_are_skipped_without_changing_a_bit() {
    let Some(ctx) = context() else { return };
    let step = code_step(ctx);
    let n = 300;
    let lit = [70, 71, 75, 133, 290, 291];
    for (codec, width) in &every_codec() {
        let enc = codec.encode(&transport(n, 3, 41)).unwrap();
        let whole = GpuMatrix::upload(ctx, &enc).unwrap();
        // Row bands of 7 rows, or texture tiles of 128 texels a side.
        let split = Split {
            texture_side: 128,
            ..small_split(n, 3, *width)
        };
        let cut = GpuMatrix::upload_split(ctx, &enc, split).unwrap();
        assert!(cut.pieces() > 1, "{}", enc.codec);
        for mut m in [whole, cut] {
            m.set_kernel(BatchKernel::Matvec);
            for sets in [1, 3, CHUNK as usize, 20] {
                let x = lit_only(n, sets, &lit);
                m.set_gather(true);
                let skipped = gpu(&m, &x);
                let share = m.last_lit_share().expect("a matrix-vector product ran");
                m.set_gather(false);
                let walked = gpu(&m, &x);
                assert_eq!(m.last_lit_share(), Some(1.0), "{}", enc.codec);
                assert_eq!(
                    skipped,
                    walked,
                    "{} pieces={} sets={sets}",
                    enc.codec,
                    m.pieces()
                );
                assert!(share < 1.0, "{} sets={sets}: walked {share}", enc.codec);
                if enc.codec.starts_with("dense") {
                    // Groups 1 (64..128), 2 (128..192) and 4 (256..300) of five.
                    assert_eq!(share, 3.0 / 5.0, "{} sets={sets}", enc.codec);
                }
                let err = rel_l2(&skipped, &cpu(&enc, &x), n);
                assert!(
                    err <= step,
                    "{} sets={sets}: {err:e} against the CPU",
                    enc.codec
                );
            }
            m.set_gather(true);
            let dark = vec![[0.0f32; 3]; 2 * n];
            assert!(
                gpu(&m, &dark).iter().all(|v| *v == [0.0; 3]),
                "{}",
                enc.codec
            );
            assert_eq!(m.last_lit_share(), Some(0.0), "{}", enc.codec);
        }
    }
}
