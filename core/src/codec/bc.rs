//! BC1 and BC4 block compression of 8-bit transport-matrix "images" (docs/design.md §3).
//!
//! This module owns the bit formats only: encoding an RGB8 image to BC1 (via texpresso's
//! iterative cluster fit), encoding an 8-bit single-channel image to BC4 (our own encoder),
//! and CPU decoders for both that reproduce what GPU texture hardware returns, so CPU
//! matvec loops and error measurements see the same numbers the GPU path does.
//!
//! Images are row-major; width and height must be multiples of 4 (callers pad). Blocks are
//! 8 bytes each, stored row-major by block. Exact zeros are preserved by both encoders:
//! in the transport matrix a zero means "no light path", and turning it into a small
//! positive value would leak light across the whole matrix after the log transform is undone.
//!
//! Decoder interpolation follows bcdec (the D3D10 reference formulas with bcdec's integer
//! rounding), which is what the tests compare against bit for bit.

use rayon::prelude::*;
use texpresso::{Algorithm, COLOUR_WEIGHTS_UNIFORM, Format, Params};

/// Bytes per BC1 or BC4 block.
pub const BLOCK_BYTES: usize = 8;

/// Size in bytes of a BC1 or BC4 encoding of a `width` x `height` image.
pub fn encoded_len(width: usize, height: usize) -> usize {
    (width / 4) * (height / 4) * BLOCK_BYTES
}

fn check_dims(width: usize, height: usize) {
    assert!(
        width.is_multiple_of(4) && height.is_multiple_of(4),
        "BC images must be padded to multiples of 4, got {width}x{height}"
    );
}

// ---------------------------------------------------------------------------------------------
// BC1
// ---------------------------------------------------------------------------------------------

/// BC1 (DXT1) encode of a row-major RGB8 image, 8 bytes per 4x4 block, blocks row-major.
///
/// Pixels whose RGB is exactly (0,0,0) decode to exactly (0,0,0): any block containing one is
/// written in BC1's 3-colour mode (`color0 <= color1`) with those pixels on index 3 (black).
/// Other pixels may still decode to black if their colour rounds there in RGB565.
///
/// Panics if `rgb.len() != width * height` or the dimensions are not multiples of 4.
pub fn encode_bc1(rgb: &[[u8; 3]], width: usize, height: usize) -> Vec<u8> {
    encode_bc1_with(rgb, width, height, Fit::Cluster)
}

/// How hard the BC1 encoder searches for a block's endpoints.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Fit {
    /// texpresso's iterative cluster fit: the bake's choice, the best blocks it can find.
    #[default]
    Cluster,
    /// texpresso's range fit (endpoints from the colours' principal axis): tens of times faster
    /// and coarser. For sizes a benchmark synthesises, where the blocks' bytes matter and their
    /// error does not.
    Range,
}

/// [`encode_bc1`] with the endpoint search chosen.
pub fn encode_bc1_with(rgb: &[[u8; 3]], width: usize, height: usize, fit: Fit) -> Vec<u8> {
    check_dims(width, height);
    assert_eq!(rgb.len(), width * height, "rgb length must be width*height");
    let mut out = vec![0u8; encoded_len(width, height)];
    if out.is_empty() {
        return out;
    }
    let params = Params {
        algorithm: match fit {
            Fit::Cluster => Algorithm::IterativeClusterFit,
            Fit::Range => Algorithm::RangeFit,
        },
        // The channels are independent matrix entries, not a picture for a human eye, so
        // perceptual weighting would trade green accuracy for red/blue error for no reason.
        weights: COLOUR_WEIGHTS_UNIFORM,
        weigh_colour_by_alpha: false,
    };
    let bw = width / 4;
    out.par_chunks_mut(bw * BLOCK_BYTES)
        .enumerate()
        .for_each(|(by, row)| {
            for (bx, block) in row.chunks_exact_mut(BLOCK_BYTES).enumerate() {
                let mut rgba = [[0u8; 4]; 16];
                for (i, px) in rgba.iter_mut().enumerate() {
                    let [r, g, b] = rgb[(by * 4 + i / 4) * width + bx * 4 + i % 4];
                    // texpresso treats alpha < 128 as "transparent": such pixels are excluded
                    // from the fit and the block is forced into 3-colour mode with them on
                    // index 3, which decodes to RGB (0,0,0) — exactly the zero we need.
                    let a = if (r, g, b) == (0, 0, 0) { 0 } else { 255 };
                    *px = [r, g, b, a];
                }
                Format::Bc1.compress_block_masked(rgba, 0xFFFF, params, block);
            }
        });
    out
}

#[inline]
fn bc1_palette(c0: u16, c1: u16) -> [[u8; 3]; 4] {
    let (r0, g0, b0) = (
        u32::from(c0 >> 11) & 0x1F,
        u32::from(c0 >> 5) & 0x3F,
        u32::from(c0) & 0x1F,
    );
    let (r1, g1, b1) = (
        u32::from(c1 >> 11) & 0x1F,
        u32::from(c1 >> 5) & 0x3F,
        u32::from(c1) & 0x1F,
    );
    // Bit replication written as bcdec's multiply-shift; identical results for 5/6-bit inputs.
    let e5 = |v: u32| ((v * 527 + 23) >> 6) as u8;
    let e6 = |v: u32| ((v * 259 + 33) >> 6) as u8;
    let mut p = [[0u8; 3]; 4];
    p[0] = [e5(r0), e6(g0), e5(b0)];
    p[1] = [e5(r1), e6(g1), e5(b1)];
    if c0 > c1 {
        // Interpolate in 5/6-bit space with rounding, as bcdec does; this differs by up to 1
        // from interpolating the expanded 8-bit values with truncation.
        let t5 = |s: u32| ((s * 351 + 61) >> 7) as u8;
        let t6 = |s: u32| ((s * 2763 + 1039) >> 11) as u8;
        p[2] = [t5(2 * r0 + r1), t6(2 * g0 + g1), t5(2 * b0 + b1)];
        p[3] = [t5(r0 + 2 * r1), t6(g0 + 2 * g1), t5(b0 + 2 * b1)];
    } else {
        let h5 = |s: u32| ((s * 1053 + 125) >> 8) as u8;
        let h6 = |s: u32| ((s * 4145 + 1019) >> 11) as u8;
        p[2] = [h5(r0 + r1), h6(g0 + g1), h5(b0 + b1)];
        p[3] = [0, 0, 0];
    }
    p
}

/// Decodes one BC1 block to 16 RGB8 texels, row-major within the block. Any 8 bytes are valid.
#[inline]
pub fn decode_bc1_block(block: &[u8; 8]) -> [[u8; 3]; 16] {
    let c0 = u16::from_le_bytes([block[0], block[1]]);
    let c1 = u16::from_le_bytes([block[2], block[3]]);
    let palette = bc1_palette(c0, c1);
    let mut idx = u32::from_le_bytes([block[4], block[5], block[6], block[7]]);
    let mut out = [[0u8; 3]; 16];
    for texel in &mut out {
        *texel = palette[(idx & 3) as usize];
        idx >>= 2;
    }
    out
}

/// Decodes a BC1 image to row-major RGB8 of `width * height` texels.
///
/// Precondition: `blocks.len() == (width/4)*(height/4)*8` and dimensions are multiples of 4
/// (checked in debug builds). In release builds a short input leaves the missing blocks black
/// and extra bytes are ignored; it never panics on the content of the bytes.
pub fn decode_bc1(blocks: &[u8], width: usize, height: usize) -> Vec<[u8; 3]> {
    debug_assert!(width.is_multiple_of(4) && height.is_multiple_of(4));
    debug_assert_eq!(blocks.len(), encoded_len(width, height));
    decode_image(blocks, width, height, [0u8; 3], decode_bc1_block)
}

// ---------------------------------------------------------------------------------------------
// BC4
// ---------------------------------------------------------------------------------------------

const W6: [u32; 6] = [9363, 18724, 28086, 37450, 46812, 56173];
const W4: [u32; 4] = [13107, 26215, 39321, 52429];

/// The 8 palette values of a BC4 block with endpoints `e0`, `e1` (bcdec's rounding).
#[inline]
fn bc4_palette(e0: u8, e1: u8) -> [u8; 8] {
    let (a0, a1) = (u32::from(e0), u32::from(e1));
    let mut p = [0u8; 8];
    p[0] = e0;
    p[1] = e1;
    if e0 > e1 {
        for j in 0..6 {
            p[2 + j] = ((W6[5 - j] * a0 + W6[j] * a1 + 32768) >> 16) as u8;
        }
    } else {
        for j in 0..4 {
            p[2 + j] = ((W4[3 - j] * a0 + W4[j] * a1 + 32768) >> 16) as u8;
        }
        p[6] = 0;
        p[7] = 255;
    }
    p
}

/// Decodes one BC4 (unsigned) block to 16 texels, row-major within the block.
#[inline]
pub fn decode_bc4_block(block: &[u8; 8]) -> [u8; 16] {
    let palette = bc4_palette(block[0], block[1]);
    let mut idx = u64::from_le_bytes(*block) >> 16;
    let mut out = [0u8; 16];
    for v in &mut out {
        *v = palette[(idx & 7) as usize];
        idx >>= 3;
    }
    out
}

/// Decodes a BC4 image to row-major 8-bit values, `width * height` of them.
///
/// Precondition: `blocks.len() == (width/4)*(height/4)*8` and dimensions are multiples of 4
/// (checked in debug builds). In release builds a short input leaves the missing blocks zero
/// and extra bytes are ignored; it never panics on the content of the bytes.
pub fn decode_bc4(blocks: &[u8], width: usize, height: usize) -> Vec<u8> {
    debug_assert!(width.is_multiple_of(4) && height.is_multiple_of(4));
    debug_assert_eq!(blocks.len(), encoded_len(width, height));
    decode_image(blocks, width, height, 0u8, decode_bc4_block)
}

/// Decode a row-major grid of 4×4 blocks with `decode_block`; the shared half of the BC1 and
/// BC4 image decoders. Missing blocks stay `zero`, extra bytes are ignored.
fn decode_image<T: Copy + Send + Sync>(
    blocks: &[u8],
    width: usize,
    height: usize,
    zero: T,
    decode_block: impl Fn(&[u8; 8]) -> [T; 16] + Sync,
) -> Vec<T> {
    let mut out = vec![zero; width * height];
    let bw = width / 4;
    if bw == 0 {
        return out;
    }
    out.par_chunks_mut(width * 4)
        .zip(blocks.par_chunks(bw * BLOCK_BYTES))
        .for_each(|(rows, src)| {
            if rows.len() < width * 4 {
                return;
            }
            for (bx, chunk) in src.chunks_exact(BLOCK_BYTES).enumerate() {
                let Ok(block) = <&[u8; 8]>::try_from(chunk) else {
                    continue;
                };
                for (i, t) in decode_block(block).iter().enumerate() {
                    rows[(i / 4) * width + bx * 4 + i % 4] = *t;
                }
            }
        });
    out
}

/// A candidate BC4 encoding of one block: squared error, endpoints, per-texel palette indices.
#[derive(Clone, Copy)]
struct Bc4Fit {
    err: u32,
    e0: u8,
    e1: u8,
    idx: [u8; 16],
}

impl Bc4Fit {
    const NONE: Bc4Fit = Bc4Fit {
        err: u32::MAX,
        e0: 0,
        e1: 0,
        idx: [0; 16],
    };

    fn pack(&self) -> [u8; 8] {
        let mut bits = u64::from(self.e0) | (u64::from(self.e1) << 8);
        for (i, &k) in self.idx.iter().enumerate() {
            bits |= u64::from(k & 7) << (16 + 3 * i);
        }
        bits.to_le_bytes()
    }
}

/// Best indices for endpoints (e0, e1), or `None` when a zero texel cannot be hit exactly
/// or the error exceeds `bound`.
fn bc4_eval(v: &[u8; 16], e0: u8, e1: u8, bound: u32) -> Option<Bc4Fit> {
    let palette = bc4_palette(e0, e1);
    let mut fit = Bc4Fit {
        err: 0,
        e0,
        e1,
        idx: [0; 16],
    };
    for (i, &x) in v.iter().enumerate() {
        let mut best = u32::MAX;
        let mut best_k = 0u8;
        for (k, &p) in palette.iter().enumerate() {
            // Zeros must stay zeros, so only an exact-zero palette entry may represent them.
            if x == 0 && p != 0 {
                continue;
            }
            let d = u32::from(x.abs_diff(p));
            if d * d < best {
                best = d * d;
                best_k = k as u8;
            }
        }
        if best == u32::MAX {
            return None;
        }
        fit.err += best;
        if fit.err > bound {
            return None;
        }
        fit.idx[i] = best_k;
    }
    Some(fit)
}

/// Weight of endpoint e0 (out of 1) for each palette index, used by the least-squares refit.
const BC4_W8: [f32; 8] = [
    1.0,
    0.0,
    6.0 / 7.0,
    5.0 / 7.0,
    4.0 / 7.0,
    3.0 / 7.0,
    2.0 / 7.0,
    1.0 / 7.0,
];
const BC4_W6: [f32; 6] = [1.0, 0.0, 4.0 / 5.0, 3.0 / 5.0, 2.0 / 5.0, 1.0 / 5.0];

/// Least-squares endpoints for fixed indices; texels on the fixed 0/255 codes of the 6-mode
/// do not depend on the endpoints and are skipped.
fn bc4_lsq(v: &[u8; 16], fit: &Bc4Fit, eight: bool) -> Option<(f32, f32)> {
    let (mut aa, mut ab, mut bb, mut ax, mut bx) = (0f32, 0f32, 0f32, 0f32, 0f32);
    for (&x, &k) in v.iter().zip(fit.idx.iter()) {
        let a = if eight {
            BC4_W8[k as usize]
        } else if (k as usize) < 6 {
            BC4_W6[k as usize]
        } else {
            continue;
        };
        let b = 1.0 - a;
        let x = f32::from(x);
        aa += a * a;
        ab += a * b;
        bb += b * b;
        ax += a * x;
        bx += b * x;
    }
    let det = aa * bb - ab * ab;
    if det.abs() < 1e-6 {
        return None;
    }
    Some(((ax * bb - bx * ab) / det, (bx * aa - ax * ab) / det))
}

/// Best encoding of one block in one mode: exhaustive search in a small window around the
/// range endpoints, then a few least-squares refits each followed by a +-1 search.
fn bc4_fit_mode(v: &[u8; 16], eight: bool) -> Bc4Fit {
    // (hi, lo) of the texels the endpoints must cover.
    let range = if eight {
        let (lo, hi) = v
            .iter()
            .fold((255u8, 0u8), |(l, h), &x| (l.min(x), h.max(x)));
        Some((hi, lo))
    } else {
        v.iter().filter(|&&x| x != 0 && x != 255).fold(
            None,
            |acc: Option<(u8, u8)>, &x| match acc {
                None => Some((x, x)),
                Some((h, l)) => Some((h.max(x), l.min(x))),
            },
        )
    };
    let mut best = Bc4Fit::NONE;
    let consider = |best: &mut Bc4Fit, hi: i32, lo: i32| {
        let (hi, lo) = (hi.clamp(0, 255) as u8, lo.clamp(0, 255) as u8);
        // 8-mode needs e0 > e1, 6-mode e0 <= e1; the pair (hi, lo) is ordered per mode.
        let (e0, e1) = if eight {
            if hi <= lo {
                return;
            }
            (hi, lo)
        } else {
            if lo > hi {
                return;
            }
            (lo, hi)
        };
        if let Some(f) = bc4_eval(v, e0, e1, best.err)
            && f.err < best.err
        {
            *best = f;
        }
    };
    let Some((hi, lo)) = range else {
        // Only 0 and 255 present: the 6-mode's fixed codes represent them exactly.
        consider(&mut best, 0, 0);
        return best;
    };
    if hi == lo {
        if eight {
            consider(&mut best, i32::from(hi), i32::from(hi) - 1);
            consider(&mut best, i32::from(hi) + 1, i32::from(hi));
        } else {
            consider(&mut best, i32::from(hi), i32::from(hi));
        }
        if best.err == 0 {
            return best;
        }
    }
    const WINDOW: i32 = 2;
    for dh in -WINDOW..=WINDOW {
        for dl in -WINDOW..=WINDOW {
            consider(&mut best, i32::from(hi) + dh, i32::from(lo) + dl);
        }
    }
    for _ in 0..3 {
        if best.err == 0 || best.err == u32::MAX {
            break;
        }
        let before = best.err;
        let Some((w0, w1)) = bc4_lsq(v, &best, eight) else {
            break;
        };
        let (a, b) = (w0.round() as i32, w1.round() as i32);
        let (h, l) = if eight { (a, b) } else { (b, a) };
        for dh in -1..=1 {
            for dl in -1..=1 {
                consider(&mut best, h + dh, l + dl);
            }
        }
        if best.err >= before {
            break;
        }
    }
    best
}

fn bc4_encode_block(v: &[u8; 16]) -> [u8; 8] {
    let six = bc4_fit_mode(v, false);
    if six.err == 0 {
        return six.pack();
    }
    let eight = bc4_fit_mode(v, true);
    // The 6-mode always has a valid fit (0 and 255 are exact codes), so `six` is never NONE.
    if eight.err < six.err {
        eight.pack()
    } else {
        six.pack()
    }
}

/// BC4 (unsigned, one 8-bit channel) encode of a row-major image, 8 bytes per 4x4 block.
///
/// Per block, both modes are fitted (8 interpolants with `e0 > e1`, 6 interpolants plus exact
/// 0 and 255 with `e0 <= e1`) and the lower squared error wins. Texels equal to 0 always decode
/// to exactly 0.
///
/// Panics if `values.len() != width * height` or the dimensions are not multiples of 4.
pub fn encode_bc4(values: &[u8], width: usize, height: usize) -> Vec<u8> {
    check_dims(width, height);
    assert_eq!(
        values.len(),
        width * height,
        "values length must be width*height"
    );
    let mut out = vec![0u8; encoded_len(width, height)];
    if out.is_empty() {
        return out;
    }
    let bw = width / 4;
    out.par_chunks_mut(bw * BLOCK_BYTES)
        .enumerate()
        .for_each(|(by, row)| {
            for (bx, block) in row.chunks_exact_mut(BLOCK_BYTES).enumerate() {
                let mut v = [0u8; 16];
                for (i, x) in v.iter_mut().enumerate() {
                    *x = values[(by * 4 + i / 4) * width + bx * 4 + i % 4];
                }
                block.copy_from_slice(&bc4_encode_block(&v));
            }
        });
    out
}
