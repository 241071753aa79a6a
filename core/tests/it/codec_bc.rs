//! BC1/BC4 codec tests: bit-exactness of our decoders against bcdec_rs (and within 1 of
//! texture2ddecoder, which truncates instead of rounding), exact-zero preservation, sizes, and
//! encoder quality against naive min/max encoders.
//!
//! Run with `--nocapture` to see the RMSE figures.

use bounce_core::codec::bc::*;

/// SplitMix64: deterministic, dependency-free test data.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn byte(&mut self) -> u8 {
        (self.next() >> 56) as u8
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

// ---------------------------------------------------------------------------------------------
// Reference decoders
// ---------------------------------------------------------------------------------------------

fn bcdec_bc1(block: &[u8; 8]) -> [[u8; 3]; 16] {
    let mut rgba = [0u8; 64];
    bcdec_rs::bc1(block, &mut rgba, 16);
    std::array::from_fn(|i| [rgba[4 * i], rgba[4 * i + 1], rgba[4 * i + 2]])
}

fn t2d_bc1(block: &[u8; 8]) -> [[u8; 3]; 16] {
    let mut px = [0u32; 16];
    texture2ddecoder::decode_bc1_block(block, &mut px);
    // texture2ddecoder packs pixels as u32::from_le_bytes([b, g, r, a]).
    std::array::from_fn(|i| {
        let [b, g, r, _a] = px[i].to_le_bytes();
        [r, g, b]
    })
}

fn bcdec_bc4(block: &[u8; 8]) -> [u8; 16] {
    let mut out = [0u8; 16];
    bcdec_rs::bc4(block, &mut out, 4, false);
    out
}

fn t2d_bc4(block: &[u8; 8]) -> [u8; 16] {
    let mut px = [0u32; 16];
    texture2ddecoder::decode_bc4_block(block, &mut px);
    std::array::from_fn(|i| px[i].to_le_bytes()[2])
}

fn blocks_of(data: &[u8]) -> impl Iterator<Item = &[u8; 8]> {
    data.chunks_exact(8)
        .map(|c| <&[u8; 8]>::try_from(c).expect("chunks_exact yields 8 bytes"))
}

fn assert_bc1_block_matches(block: &[u8; 8]) {
    let ours = decode_bc1_block(block);
    assert_eq!(
        ours,
        bcdec_bc1(block),
        "bcdec mismatch on block {block:02x?}"
    );
    let t2d = t2d_bc1(block);
    for (a, b) in ours.iter().zip(t2d.iter()) {
        for c in 0..3 {
            assert!(
                a[c].abs_diff(b[c]) <= 1,
                "texture2ddecoder differs by >1 on block {block:02x?}"
            );
        }
    }
}

fn assert_bc4_block_matches(block: &[u8; 8]) {
    let ours = decode_bc4_block(block);
    assert_eq!(
        ours,
        bcdec_bc4(block),
        "bcdec mismatch on block {block:02x?}"
    );
    let t2d = t2d_bc4(block);
    for (a, b) in ours.iter().zip(t2d.iter()) {
        assert!(
            a.abs_diff(*b) <= 1,
            "texture2ddecoder differs by >1 on block {block:02x?}"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Test images
// ---------------------------------------------------------------------------------------------

const W: usize = 64;
const H: usize = 48;

fn rgb_gradient(w: usize, h: usize) -> Vec<[u8; 3]> {
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            [
                (x * 255 / (w - 1)) as u8,
                (y * 255 / (h - 1)) as u8,
                ((x + y) * 255 / (w + h - 2)) as u8,
            ]
        })
        .collect()
}

fn rgb_noise(w: usize, h: usize, seed: u64) -> Vec<[u8; 3]> {
    let mut rng = Rng(seed);
    (0..w * h)
        .map(|_| [rng.byte(), rng.byte(), rng.byte()])
        .collect()
}

/// Resembles a log-quantised transport matrix: smooth, mostly grey-ish, with zero entries.
fn rgb_matrix_like(w: usize, h: usize, seed: u64) -> Vec<[u8; 3]> {
    let mut rng = Rng(seed);
    (0..w * h)
        .map(|i| {
            if rng.below(5) == 0 {
                return [0, 0, 0];
            }
            let (x, y) = (i % w, i / w);
            let base = 120.0 + 60.0 * ((x as f32) * 0.2).sin() * ((y as f32) * 0.15).cos();
            let jitter = |rng: &mut Rng| rng.below(9) as f32 - 4.0;
            [
                (base + jitter(&mut rng)).clamp(1.0, 255.0) as u8,
                (base * 0.9 + jitter(&mut rng)).clamp(1.0, 255.0) as u8,
                (base * 0.7 + jitter(&mut rng)).clamp(1.0, 255.0) as u8,
            ]
        })
        .collect()
}

/// Non-zero random pixels with ~1 in `k` set to exact zero.
fn rgb_scattered_zeros(w: usize, h: usize, k: u64, seed: u64) -> Vec<[u8; 3]> {
    let mut rng = Rng(seed);
    (0..w * h)
        .map(|_| {
            if rng.below(k) == 0 {
                [0, 0, 0]
            } else {
                // Any non-(0,0,0) colour, including ones with some zero channels.
                loop {
                    let c = [rng.byte(), rng.byte(), rng.byte()];
                    if c != [0, 0, 0] {
                        break c;
                    }
                }
            }
        })
        .collect()
}

fn grey_gradient(w: usize, h: usize) -> Vec<u8> {
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            ((x * 3 + y * 2) * 255 / ((w - 1) * 3 + (h - 1) * 2)) as u8
        })
        .collect()
}

fn grey_noise(w: usize, h: usize, seed: u64) -> Vec<u8> {
    let mut rng = Rng(seed);
    (0..w * h).map(|_| rng.byte()).collect()
}

fn grey_scattered_zeros(w: usize, h: usize, k: u64, seed: u64) -> Vec<u8> {
    let mut rng = Rng(seed);
    (0..w * h)
        .map(|_| {
            if rng.below(k) == 0 {
                0
            } else {
                1 + rng.below(255) as u8
            }
        })
        .collect()
}

fn rgb_images() -> Vec<(&'static str, Vec<[u8; 3]>)> {
    vec![
        ("gradient", rgb_gradient(W, H)),
        ("noise", rgb_noise(W, H, 1)),
        ("matrix-like", rgb_matrix_like(W, H, 2)),
        ("scattered-zeros", rgb_scattered_zeros(W, H, 7, 3)),
        ("all-zero", vec![[0, 0, 0]; W * H]),
        ("all-white", vec![[255, 255, 255]; W * H]),
        (
            "near-black",
            rgb_noise(W, H, 4)
                .iter()
                .map(|c| c.map(|v| v % 3))
                .collect(),
        ),
    ]
}

fn grey_images() -> Vec<(&'static str, Vec<u8>)> {
    vec![
        ("gradient", grey_gradient(W, H)),
        ("noise", grey_noise(W, H, 5)),
        ("scattered-zeros", grey_scattered_zeros(W, H, 5, 6)),
        ("zeros-and-255", {
            let mut rng = Rng(7);
            (0..W * H)
                .map(|_| if rng.below(2) == 0 { 0 } else { 255 })
                .collect()
        }),
        ("all-zero", vec![0; W * H]),
        (
            "low-values",
            grey_noise(W, H, 8).iter().map(|v| v % 4).collect(),
        ),
    ]
}

// ---------------------------------------------------------------------------------------------
// Error measures and naive encoders
// ---------------------------------------------------------------------------------------------

fn rmse_rgb(a: &[[u8; 3]], b: &[[u8; 3]]) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |c| (f64::from(p[c]) - f64::from(q[c])).powi(2)))
        .sum();
    (sum / (a.len() * 3) as f64).sqrt()
}

fn rmse_grey(a: &[u8], b: &[u8]) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .map(|(p, q)| (f64::from(*p) - f64::from(*q)).powi(2))
        .sum();
    (sum / a.len() as f64).sqrt()
}

fn pack565(c: [u8; 3]) -> u16 {
    let r = (u16::from(c[0]) * 31 + 127) / 255;
    let g = (u16::from(c[1]) * 63 + 127) / 255;
    let b = (u16::from(c[2]) * 31 + 127) / 255;
    (r << 11) | (g << 5) | b
}

/// The textbook "range" encoder: per-channel bounding box corners as endpoints, 4-colour
/// mode, nearest palette entry per texel.
fn naive_bc1(rgb: &[[u8; 3]], w: usize, h: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity((w / 4) * (h / 4) * 8);
    for by in 0..h / 4 {
        for bx in 0..w / 4 {
            let px: Vec<[u8; 3]> = (0..16)
                .map(|i| rgb[(by * 4 + i / 4) * w + bx * 4 + i % 4])
                .collect();
            let lo = (0..3).map(|c| px.iter().map(|p| p[c]).min().unwrap_or(0));
            let hi = (0..3).map(|c| px.iter().map(|p| p[c]).max().unwrap_or(0));
            let lo: Vec<u8> = lo.collect();
            let hi: Vec<u8> = hi.collect();
            let mut c0 = pack565([hi[0], hi[1], hi[2]]);
            let mut c1 = pack565([lo[0], lo[1], lo[2]]);
            if c0 < c1 {
                std::mem::swap(&mut c0, &mut c1);
            }
            // Decode a probe block with indices 0,1,2,3 on the first four texels to get the palette.
            let mut probe = [0u8; 8];
            probe[..2].copy_from_slice(&c0.to_le_bytes());
            probe[2..4].copy_from_slice(&c1.to_le_bytes());
            probe[4] = 0b1110_0100;
            let pal = decode_bc1_block(&probe);
            let mut bits = 0u32;
            for (i, p) in px.iter().enumerate() {
                let d = |q: &[u8; 3]| -> u32 {
                    (0..3).map(|c| u32::from(p[c].abs_diff(q[c])).pow(2)).sum()
                };
                let k = (0..4).min_by_key(|&k| d(&pal[k])).unwrap_or(0);
                bits |= (k as u32) << (2 * i);
            }
            out.extend_from_slice(&probe[..4]);
            out.extend_from_slice(&bits.to_le_bytes());
        }
    }
    out
}

fn bc4_block_with(e0: u8, e1: u8, v: &[u8; 16], zero_exact: bool) -> Option<([u8; 8], u32)> {
    let mut probe = [0u8; 8];
    probe[0] = e0;
    probe[1] = e1;
    // Indices 0..7 on texels 0..7.
    let mut bits: u64 = 0;
    for k in 0..8u64 {
        bits |= k << (3 * k);
    }
    probe[2..8].copy_from_slice(&bits.to_le_bytes()[..6]);
    let pal = decode_bc4_block(&probe);
    let mut idx: u64 = 0;
    let mut err = 0u32;
    for (i, &x) in v.iter().enumerate() {
        let best = (0..8)
            .filter(|&k| !(zero_exact && x == 0 && pal[k] != 0))
            .min_by_key(|&k| x.abs_diff(pal[k]))?;
        err += u32::from(x.abs_diff(pal[best])).pow(2);
        idx |= (best as u64) << (3 * i);
    }
    let mut block = [0u8; 8];
    block[0] = e0;
    block[1] = e1;
    block[2..8].copy_from_slice(&idx.to_le_bytes()[..6]);
    Some((block, err))
}

fn block_values(values: &[u8], w: usize, bx: usize, by: usize) -> [u8; 16] {
    std::array::from_fn(|i| values[(by * 4 + i / 4) * w + bx * 4 + i % 4])
}

fn sq_err(a: &[u8; 16], b: &[u8; 16]) -> u32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| u32::from(x.abs_diff(*y)).pow(2))
        .sum()
}

// ---------------------------------------------------------------------------------------------
// Tests
// ---------------------------------------------------------------------------------------------

#[test]
fn encoded_sizes() {
    for (w, h) in [(4, 4), (8, 4), (4, 12), (64, 48), (0, 0), (0, 8)] {
        let rgb = vec![[10, 20, 30]; w * h];
        let grey = vec![10; w * h];
        let expect = (w / 4) * (h / 4) * 8;
        assert_eq!(encode_bc1(&rgb, w, h).len(), expect);
        assert_eq!(encode_bc4(&grey, w, h).len(), expect);
        assert_eq!(encoded_len(w, h), expect);
        assert_eq!(decode_bc1(&vec![0; expect], w, h).len(), w * h);
        assert_eq!(decode_bc4(&vec![0; expect], w, h).len(), w * h);
    }
}

#[test]
#[should_panic]
fn encode_rejects_unpadded() {
    encode_bc1(&[[1, 2, 3]; 30], 6, 5);
}

#[test]
fn bc1_decoder_matches_reference_on_encoded_blocks() {
    for (name, img) in rgb_images() {
        let enc = encode_bc1(&img, W, H);
        for block in blocks_of(&enc) {
            assert_bc1_block_matches(block);
        }
        // The image-level decoder must place block texels where the block decoder says.
        let dec = decode_bc1(&enc, W, H);
        let bw = W / 4;
        for (b, block) in blocks_of(&enc).enumerate() {
            let texels = bcdec_bc1(block);
            for (i, t) in texels.iter().enumerate() {
                let (x, y) = ((b % bw) * 4 + i % 4, (b / bw) * 4 + i / 4);
                assert_eq!(dec[y * W + x], *t, "{name}: texel ({x},{y})");
            }
        }
    }
}

#[test]
fn bc4_decoder_matches_reference_on_encoded_blocks() {
    for (name, img) in grey_images() {
        let enc = encode_bc4(&img, W, H);
        for block in blocks_of(&enc) {
            assert_bc4_block_matches(block);
        }
        let dec = decode_bc4(&enc, W, H);
        let bw = W / 4;
        for (b, block) in blocks_of(&enc).enumerate() {
            let texels = bcdec_bc4(block);
            for (i, t) in texels.iter().enumerate() {
                let (x, y) = ((b % bw) * 4 + i % 4, (b / bw) * 4 + i / 4);
                assert_eq!(dec[y * W + x], *t, "{name}: texel ({x},{y})");
            }
        }
    }
}

#[test]
fn decoders_match_reference_on_random_blocks() {
    let mut rng = Rng(0xB1B1);
    for n in 0..100_000u32 {
        let mut block: [u8; 8] = rng.next().to_le_bytes();
        // Make equal and nearly-equal endpoints common: they select the mode boundaries.
        match n % 8 {
            0 => {
                block[2] = block[0];
                block[3] = block[1];
            }
            1 => block[1] = block[0],
            2 => block[1] = block[0].wrapping_add(1),
            _ => {}
        }
        assert_bc1_block_matches(&block);
        assert_bc4_block_matches(&block);
    }
}

#[test]
fn decoders_match_reference_on_all_endpoint_pairs() {
    // Every BC4 endpoint pair, and every BC1 endpoint pair sharing a colour with a sparse
    // grid, with all 8 (BC4) / 4 (BC1) indices present in the block.
    for e0 in 0..=255u8 {
        for e1 in 0..=255u8 {
            let mut block = [e0, e1, 0b1000_1000, 0b1100_0110, 0b1111_1010, 0, 0, 0];
            assert_bc4_block_matches(&block);
            block[2] = e0 ^ 0x5A;
            block[3] = e1;
            block[4] = 0b1110_0100;
            block[5] = 0b0001_1011;
            assert_bc1_block_matches(&block);
        }
    }
}

#[test]
fn random_bytes_decode_without_panic() {
    let mut rng = Rng(99);
    let data: Vec<u8> = (0..encoded_len(W, H)).map(|_| rng.byte()).collect();
    let a = decode_bc1(&data, W, H);
    let b = decode_bc4(&data, W, H);
    assert_eq!(a.len(), W * H);
    assert_eq!(b.len(), W * H);
}

#[test]
fn bc1_exact_zeros_survive() {
    for seed in 0..8 {
        for k in [2, 5, 16] {
            let img = rgb_scattered_zeros(W, H, k, 100 + seed);
            let dec = decode_bc1(&encode_bc1(&img, W, H), W, H);
            for (i, (src, out)) in img.iter().zip(&dec).enumerate() {
                if *src == [0, 0, 0] {
                    assert_eq!(*out, [0, 0, 0], "seed {seed} k {k} texel {i}");
                }
            }
        }
    }
    let zero = vec![[0u8; 3]; W * H];
    let enc = encode_bc1(&zero, W, H);
    assert!(decode_bc1(&enc, W, H).iter().all(|p| *p == [0, 0, 0]));
    // Single zero in an otherwise bright block, and a block of one colour plus zeros.
    for fill in [[255, 255, 255], [1, 1, 1], [200, 3, 90], [0, 0, 1]] {
        for zero_at in [0, 5, 15] {
            let mut img = vec![fill; 16];
            img[zero_at] = [0, 0, 0];
            let enc = encode_bc1(&img, 4, 4);
            let c0 = u16::from_le_bytes([enc[0], enc[1]]);
            let c1 = u16::from_le_bytes([enc[2], enc[3]]);
            assert!(c0 <= c1, "block with a zero must use 3-colour mode");
            let dec = decode_bc1(&enc, 4, 4);
            assert_eq!(dec[zero_at], [0, 0, 0]);
        }
    }
}

#[test]
fn bc4_exact_zeros_survive() {
    for seed in 0..8 {
        for k in [2, 5, 16] {
            let img = grey_scattered_zeros(W, H, k, 200 + seed);
            let dec = decode_bc4(&encode_bc4(&img, W, H), W, H);
            for (i, (src, out)) in img.iter().zip(&dec).enumerate() {
                if *src == 0 {
                    assert_eq!(*out, 0, "seed {seed} k {k} texel {i}");
                }
            }
        }
    }
    let dec = decode_bc4(&encode_bc4(&vec![0; W * H], W, H), W, H);
    assert!(dec.iter().all(|&v| v == 0));
    // Zeros next to values that pull an 8-mode fit away from 0.
    for hi in [1u8, 2, 7, 128, 250, 254, 255] {
        let mut v = [hi; 16];
        v[3] = 0;
        v[9] = hi.saturating_sub(1);
        let dec = decode_bc4(&encode_bc4(&v, 4, 4), 4, 4);
        assert_eq!(dec[3], 0, "hi {hi}");
    }
}

#[test]
fn bc4_constant_blocks_round_trip_exactly() {
    for c in 0..=255u8 {
        let v = [c; 16];
        let dec = decode_bc4(&encode_bc4(&v, 4, 4), 4, 4);
        assert_eq!(dec, v, "constant {c}");
    }
}

#[test]
fn bc1_quality_vs_naive() {
    for (name, img) in [
        ("gradient", rgb_gradient(W, H)),
        ("noise", rgb_noise(W, H, 11)),
        ("matrix-like", rgb_matrix_like(W, H, 12)),
    ] {
        let ours = rmse_rgb(&img, &decode_bc1(&encode_bc1(&img, W, H), W, H));
        let naive = rmse_rgb(&img, &decode_bc1(&naive_bc1(&img, W, H), W, H));
        println!("BC1 RMSE {name}: ours {ours:.3}, naive min/max {naive:.3}");
        assert!(
            ours <= naive,
            "{name}: ours {ours} worse than naive {naive}"
        );
    }
    // The 2-D gradient above puts each block's colours on a plane, which BC1's single line
    // cannot follow; a ramp along one colour direction is what it can represent, to within
    // RGB565 endpoint precision plus interpolant rounding.
    let ramp: Vec<[u8; 3]> = (0..W * H)
        .map(|i| {
            let t = (i % W) * 255 / (W - 1);
            [t as u8, (t * 3 / 4) as u8, (t / 2) as u8]
        })
        .collect();
    let ours = rmse_rgb(&ramp, &decode_bc1(&encode_bc1(&ramp, W, H), W, H));
    let naive = rmse_rgb(&ramp, &decode_bc1(&naive_bc1(&ramp, W, H), W, H));
    println!("BC1 RMSE 1-D colour ramp: ours {ours:.3}, naive min/max {naive:.3}");
    assert!(ours <= naive && ours < 2.0, "BC1 ramp RMSE {ours}");
}

#[test]
fn bc4_quality() {
    let img = grey_gradient(W, H);
    let rmse = rmse_grey(&img, &decode_bc4(&encode_bc4(&img, W, H), W, H));
    println!("BC4 RMSE gradient: {rmse:.3}");
    assert!(rmse < 2.0, "BC4 gradient RMSE {rmse}");

    // A steeper gradient (larger per-block range) is the harder case for 8 interpolants.
    let steep: Vec<u8> = (0..W * H)
        .map(|i| ((i % W) * 4 + (i / W) * 3) as u8)
        .collect();
    let rmse = rmse_grey(&steep, &decode_bc4(&encode_bc4(&steep, W, H), W, H));
    println!("BC4 RMSE steep gradient (wraps): {rmse:.3}");

    for (name, img) in [
        ("noise", grey_noise(W, H, 21)),
        ("scattered-zeros", grey_scattered_zeros(W, H, 5, 22)),
    ] {
        let enc = encode_bc4(&img, W, H);
        let ours = rmse_grey(&img, &decode_bc4(&enc, W, H));
        // Per block, our search includes the naive 8-mode (max, min) endpoints, so it can
        // never lose to them.
        let bw = W / 4;
        let mut naive_sum = 0u64;
        for (b, block) in blocks_of(&enc).enumerate() {
            let v = block_values(&img, W, b % bw, b / bw);
            let ours_err = sq_err(&v, &decode_bc4_block(block));
            let hi = *v.iter().max().unwrap_or(&0);
            let lo = *v.iter().min().unwrap_or(&0);
            let naive = if hi > lo {
                bc4_block_with(hi, lo, &v, false).map(|(_, e)| e)
            } else {
                Some(0)
            };
            let naive = naive.unwrap_or(u32::MAX);
            naive_sum += u64::from(naive);
            assert!(
                ours_err <= naive,
                "{name} block {b}: ours {ours_err} naive {naive}"
            );
        }
        let naive_rmse = (naive_sum as f64 / img.len() as f64).sqrt();
        println!("BC4 RMSE {name}: ours {ours:.3}, naive min/max 8-mode {naive_rmse:.3}");
    }
}

#[test]
fn bc4_close_to_exhaustive_optimum() {
    // Brute force over all 65,536 endpoint pairs (both modes) for a few random blocks, with the
    // same zero constraint; report how far the encoder's heuristic search is from optimal.
    let mut rng = Rng(31);
    let (mut ours_total, mut best_total) = (0u64, 0u64);
    for n in 0..12 {
        let v: [u8; 16] = std::array::from_fn(|_| match n % 3 {
            0 => rng.byte(),
            1 => 100 + rng.below(40) as u8,
            _ => {
                if rng.below(4) == 0 {
                    0
                } else {
                    30 + rng.below(100) as u8
                }
            }
        });
        let ours = sq_err(
            &v,
            &decode_bc4(&encode_bc4(&v, 4, 4), 4, 4)
                .try_into()
                .unwrap_or([0; 16]),
        );
        let mut best = u32::MAX;
        for e0 in 0..=255u8 {
            for e1 in 0..=255u8 {
                if let Some((_, e)) = bc4_block_with(e0, e1, &v, true) {
                    best = best.min(e);
                }
            }
        }
        assert!(ours >= best, "brute force must be a lower bound");
        ours_total += u64::from(ours);
        best_total += u64::from(best);
    }
    let ratio = ours_total as f64 / best_total.max(1) as f64;
    println!(
        "BC4 squared error vs exhaustive optimum: ours {ours_total}, optimum {best_total}, ratio {ratio:.3}"
    );
    assert!(ratio < 1.25, "heuristic far from optimum: {ratio}");
}
