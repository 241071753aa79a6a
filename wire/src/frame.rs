//! Frames: a session's per-patch indirect irradiance in the one byte layout that gRPC carries as
//! `bytes` and a WebSocket will carry as a binary message. "Indirect" is the light a viewer does
//! not draw itself: the bounces (emitting surfaces' light on others included), and under a sky the
//! sky's direct light too (a viewer draws only the punctual lights, with its shadow maps).
//!
//! Layout (little-endian), a 32-byte header then the payload:
//!
//! | offset | size | field                                                            |
//! |-------:|-----:|------------------------------------------------------------------|
//! | 0      | 4    | magic `BNCF`                                                     |
//! | 4      | 2    | format version, 1                                                |
//! | 6      | 2    | encoding, 1 = RGB9E5                                             |
//! | 8      | 4    | flags: bit 0 some input non-finite, bit 1 some input over max    |
//! | 12     | 4    | patch count `n`                                                  |
//! | 16     | 8    | sequence: the session's frame counter, from 1                    |
//! | 24     | 8    | lights version the frame answers                                 |
//! | 32     | 4·n  | per patch one RGB9E5 word (see [`rgb9e5`])                       |
//!
//! A scene baked with irradiance probes also has **probe frames**: the same layout under the magic
//! `BNCP`, the count then being the probe directions (six a probe, in the face-code order, probe
//! after probe) and the payload their irradiance. A probe frame travels beside its patch frame
//! with the same sequence and lights version ([`Frame::probes`]): in gRPC's `Frame.probes`, and on
//! a WebSocket that asked for them as the binary message after the patch frame. A reader of patch
//! frames refuses it by its magic, so a client that knows nothing of probes never mistakes one.
//!
//! RGB9E5 is a GPU texture format (`GL_RGB9_E5`, `Rgb9e5Ufloat` in wgpu), so a client can upload
//! the payload as it is. The u64 fields sit 8-byte aligned and the payload 4-byte aligned.

use bytes::Bytes;
use thiserror::Error;

pub use rgb9e5::{RGB9E5_MAX, decode_rgb9e5, encode_rgb9e5};

/// `BNCF`: bounce frame.
pub const MAGIC: [u8; 4] = *b"BNCF";
/// `BNCP`: bounce probe frame.
pub const PROBE_MAGIC: [u8; 4] = *b"BNCP";
pub const FORMAT_VERSION: u16 = 1;
/// The only encoding so far; an f16 one could follow under another number.
pub const ENCODING_RGB9E5: u16 = 1;
pub const HEADER_LEN: usize = 32;

/// Some input value was NaN or infinite (written as 0, or as the maximum for +∞).
pub const FLAG_NON_FINITE: u32 = 1;
/// Some input value was above [`RGB9E5_MAX`] (written as the maximum).
pub const FLAG_CLAMPED: u32 = 2;

/// A frame's header fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameHeader {
    pub flags: u32,
    pub patch_count: u32,
    pub sequence: u64,
    pub lights_version: u64,
}

/// An encoded frame: its header fields and its bytes (header included), shared cheaply.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    pub header: FrameHeader,
    bytes: Bytes,
    /// The probe frame that goes with this patch frame, if the scene has probes.
    probes: Option<Box<Frame>>,
}

#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum FrameError {
    #[error("frame is {0} bytes, shorter than its {HEADER_LEN}-byte header")]
    Short(usize),
    #[error("not a bounce frame (magic {0:?})")]
    Magic([u8; 4]),
    #[error("frame format version {0}, this reader knows {FORMAT_VERSION}")]
    Version(u16),
    #[error("frame encoding {0}, this reader knows {ENCODING_RGB9E5} (RGB9E5)")]
    Encoding(u16),
    #[error("frame says {count} patches but carries {payload} payload bytes")]
    Length { count: u32, payload: usize },
    #[error("{0} patches do not fit a frame (at most u32::MAX)")]
    TooManyPatches(usize),
}

impl Frame {
    /// Packs `irradiance` (one RGB triple a patch) as RGB9E5 behind a header.
    pub fn encode(
        sequence: u64,
        lights_version: u64,
        irradiance: &[[f32; 3]],
    ) -> Result<Frame, FrameError> {
        Frame::encode_as(MAGIC, sequence, lights_version, irradiance)
    }

    /// Packs probe irradiance (one RGB triple a probe direction) as a probe frame (`BNCP`).
    pub fn encode_probes(
        sequence: u64,
        lights_version: u64,
        irradiance: &[[f32; 3]],
    ) -> Result<Frame, FrameError> {
        Frame::encode_as(PROBE_MAGIC, sequence, lights_version, irradiance)
    }

    fn encode_as(
        magic: [u8; 4],
        sequence: u64,
        lights_version: u64,
        irradiance: &[[f32; 3]],
    ) -> Result<Frame, FrameError> {
        let patch_count = u32::try_from(irradiance.len())
            .map_err(|_| FrameError::TooManyPatches(irradiance.len()))?;
        let mut flags = 0;
        let mut out = Vec::with_capacity(HEADER_LEN + 4 * irradiance.len());
        out.extend_from_slice(&[0; HEADER_LEN]);
        for rgb in irradiance {
            let (word, f) = encode_rgb9e5(*rgb);
            flags |= f;
            out.extend_from_slice(&word.to_le_bytes());
        }
        let header = FrameHeader {
            flags,
            patch_count,
            sequence,
            lights_version,
        };
        write_header(magic, &header, &mut out[..HEADER_LEN]);
        Ok(Frame {
            header,
            bytes: Bytes::from(out),
            probes: None,
        })
    }

    /// Reads a patch frame's bytes, checking the header against the length.
    pub fn parse(bytes: Bytes) -> Result<Frame, FrameError> {
        let header = read_header(MAGIC, &bytes)?;
        Ok(Frame {
            header,
            bytes,
            probes: None,
        })
    }

    /// Reads a probe frame's bytes (`BNCP`), checking the header against the length.
    pub fn parse_probes(bytes: Bytes) -> Result<Frame, FrameError> {
        let header = read_header(PROBE_MAGIC, &bytes)?;
        Ok(Frame {
            header,
            bytes,
            probes: None,
        })
    }

    /// This patch frame with its probe frame beside it.
    pub fn with_probes(mut self, probes: Frame) -> Frame {
        self.probes = Some(Box::new(probes));
        self
    }

    /// The probe frame beside this patch frame, if the scene has probes.
    pub fn probes(&self) -> Option<&Frame> {
        self.probes.as_deref()
    }

    /// The whole frame, header and payload.
    pub fn bytes(&self) -> &Bytes {
        &self.bytes
    }

    /// The RGB9E5 words, one a patch.
    pub fn words(&self) -> impl ExactSizeIterator<Item = u32> + '_ {
        self.bytes[HEADER_LEN..]
            .chunks_exact(4)
            .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
    }

    /// The irradiance per patch, decoded.
    pub fn irradiance(&self) -> Vec<[f32; 3]> {
        self.words().map(decode_rgb9e5).collect()
    }
}

fn write_header(magic: [u8; 4], h: &FrameHeader, out: &mut [u8]) {
    out[0..4].copy_from_slice(&magic);
    out[4..6].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
    out[6..8].copy_from_slice(&ENCODING_RGB9E5.to_le_bytes());
    out[8..12].copy_from_slice(&h.flags.to_le_bytes());
    out[12..16].copy_from_slice(&h.patch_count.to_le_bytes());
    out[16..24].copy_from_slice(&h.sequence.to_le_bytes());
    out[24..32].copy_from_slice(&h.lights_version.to_le_bytes());
}

fn read_header(expected: [u8; 4], b: &[u8]) -> Result<FrameHeader, FrameError> {
    let Some(head) = b.get(..HEADER_LEN) else {
        return Err(FrameError::Short(b.len()));
    };
    let u16_at = |o: usize| u16::from_le_bytes([head[o], head[o + 1]]);
    let u32_at = |o: usize| u32::from_le_bytes([head[o], head[o + 1], head[o + 2], head[o + 3]]);
    let u64_at = |o: usize| u64::from(u32_at(o)) | (u64::from(u32_at(o + 4)) << 32);
    let magic = [head[0], head[1], head[2], head[3]];
    if magic != expected {
        return Err(FrameError::Magic(magic));
    }
    if u16_at(4) != FORMAT_VERSION {
        return Err(FrameError::Version(u16_at(4)));
    }
    if u16_at(6) != ENCODING_RGB9E5 {
        return Err(FrameError::Encoding(u16_at(6)));
    }
    let header = FrameHeader {
        flags: u32_at(8),
        patch_count: u32_at(12),
        sequence: u64_at(16),
        lights_version: u64_at(24),
    };
    let payload = b.len() - HEADER_LEN;
    if payload as u64 != 4 * u64::from(header.patch_count) {
        return Err(FrameError::Length {
            count: header.patch_count,
            payload,
        });
    }
    Ok(header)
}

/// The shared-exponent format of OpenGL's `EXT_texture_shared_exponent`: three 9-bit mantissas
/// and one 5-bit exponent (bias 15), no sign, no Inf or NaN.
mod rgb9e5 {
    use super::{FLAG_CLAMPED, FLAG_NON_FINITE};

    const MANTISSA_BITS: i32 = 9;
    const EXP_BIAS: i32 = 15;
    const MAX_EXP: i32 = 31;

    /// The largest value RGB9E5 holds: `(2^9 − 1)/2^9 · 2^(31 − 15)` = 65408.
    pub const RGB9E5_MAX: f32 = 65408.0;

    /// `2^e` for the small exponents used here, exactly.
    fn pow2(e: i32) -> f64 {
        f64::from(e).exp2()
    }

    /// Packs a linear RGB triple; also returns [`FLAG_NON_FINITE`] / [`FLAG_CLAMPED`] when a
    /// component had to be replaced. NaN becomes 0, +∞ and anything above [`RGB9E5_MAX`] the
    /// maximum, negatives 0 (irradiance is never negative; a lossy codec's tiny negative noise is
    /// not worth a flag).
    pub fn encode_rgb9e5(rgb: [f32; 3]) -> (u32, u32) {
        let mut flags = 0;
        let c = rgb.map(|x| {
            if x.is_nan() {
                flags |= FLAG_NON_FINITE;
                0.0
            } else if x == f32::INFINITY {
                flags |= FLAG_NON_FINITE;
                f64::from(RGB9E5_MAX)
            } else if x > RGB9E5_MAX {
                flags |= FLAG_CLAMPED;
                f64::from(RGB9E5_MAX)
            } else {
                // −∞ and negatives land here: 0.
                f64::from(x.max(0.0))
            }
        });
        let max = c[0].max(c[1]).max(c[2]);
        // floor(log2(max)) from the float's exponent: exact, unlike a rounded log2. Values below
        // 2^-16 (subnormals and zero included) all take the smallest exponent.
        let floor_log2 = if max >= pow2(-EXP_BIAS - 1) {
            ((max.to_bits() >> 52) & 0x7ff) as i32 - 1023
        } else {
            -EXP_BIAS - 1
        };
        let mut exp = floor_log2.max(-EXP_BIAS - 1) + 1 + EXP_BIAS;
        let max_mantissa = (1i32 << MANTISSA_BITS) as f64;
        let scale = |e: i32| pow2(e - EXP_BIAS - MANTISSA_BITS);
        // Rounding can carry the largest mantissa to 2^9: take the next exponent instead.
        if (max / scale(exp) + 0.5).floor() >= max_mantissa {
            exp += 1;
        }
        debug_assert!((0..=MAX_EXP).contains(&exp));
        let s = scale(exp);
        let m = c.map(|x| ((x / s + 0.5).floor() as u32).min((1 << MANTISSA_BITS) - 1));
        let word = m[0] | (m[1] << 9) | (m[2] << 18) | ((exp as u32) << 27);
        (word, flags)
    }

    /// Unpacks a word into linear RGB: `mantissa · 2^(exponent − 24)`.
    pub fn decode_rgb9e5(word: u32) -> [f32; 3] {
        let exp = (word >> 27) as i32;
        let s = pow2(exp - EXP_BIAS - MANTISSA_BITS);
        [0, 9, 18].map(|shift| (f64::from((word >> shift) & 0x1ff) * s) as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Per component, the encoding is within half a step of the shared exponent: at most
    /// `max/511` (the step is at most `max/2^8`, or `max/511.5` after a carry), plus `2^-25` for
    /// values below the smallest exponent's step.
    fn bound(rgb: [f32; 3]) -> f64 {
        let max = rgb.iter().fold(0.0f64, |m, &x| m.max(f64::from(x)));
        max / 511.0 + 2f64.powi(-25)
    }

    #[track_caller]
    fn assert_round_trip(rgb: [f32; 3]) {
        let (word, flags) = encode_rgb9e5(rgb);
        assert_eq!(flags, 0, "{rgb:?}");
        let back = decode_rgb9e5(word);
        for k in 0..3 {
            let err = (f64::from(back[k]) - f64::from(rgb[k])).abs();
            assert!(
                err <= bound(rgb),
                "{rgb:?} → {back:?}: error {err} > {}",
                bound(rgb)
            );
        }
    }

    #[test]
    fn probe_frames_are_their_own_kind() {
        let probes = Frame::encode_probes(3, 2, &[[1.0, 2.0, 4.0]; 12]).unwrap();
        assert_eq!(&probes.bytes()[..4], b"BNCP");
        assert_eq!(probes.header.patch_count, 12);
        let back = Frame::parse_probes(probes.bytes().clone()).unwrap();
        assert_eq!(back.irradiance(), vec![[1.0, 2.0, 4.0]; 12]);
        // A patch-frame reader refuses a probe frame by its magic, and the other way round.
        assert_eq!(
            Frame::parse(probes.bytes().clone()),
            Err(FrameError::Magic(*b"BNCP"))
        );
        let patches = Frame::encode(3, 2, &[[0.5; 3]; 4]).unwrap();
        assert!(Frame::parse_probes(patches.bytes().clone()).is_err());
        // The patch frame's bytes do not change when probes go beside it.
        let both = patches.clone().with_probes(probes.clone());
        assert_eq!(both.bytes(), patches.bytes());
        assert_eq!(both.probes(), Some(&probes));
        assert_eq!(patches.probes(), None);
    }

    #[test]
    fn round_trip_within_the_bound() {
        // A deterministic spread over the whole range: 1e-9 .. 6e4, mixed channel ratios.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..100_000 {
            let scale = 10f64.powf(-9.0 + 13.8 * next());
            let rgb = [next(), next(), next()].map(|u| (u * scale) as f32);
            assert_round_trip(rgb);
        }
        // Edges: powers of two, the carry case (a mantissa rounding up to 2^9), the max.
        for rgb in [
            [1.0, 0.5, 0.25],
            [511.5 / 512.0, 0.0, 0.0],
            [0.99951, 0.3, 0.0],
            [RGB9E5_MAX, RGB9E5_MAX, RGB9E5_MAX],
            [2f32.powi(-24), 0.0, 2f32.powi(-20)],
            [1e-30, 0.0, 0.0],
        ] {
            assert_round_trip(rgb);
        }
        // Exact for what the format holds exactly.
        assert_eq!(
            decode_rgb9e5(encode_rgb9e5([1.0, 0.5, 0.25]).0),
            [1.0, 0.5, 0.25]
        );
        assert_eq!(
            decode_rgb9e5(encode_rgb9e5([RGB9E5_MAX; 3]).0),
            [RGB9E5_MAX; 3]
        );
    }

    #[test]
    fn zero_is_zero() {
        let (word, flags) = encode_rgb9e5([0.0; 3]);
        assert_eq!((word, flags), (0, 0));
        assert_eq!(decode_rgb9e5(0), [0.0; 3]);
        // Negative zero and small negatives (codec noise) are zero, unflagged.
        assert_eq!(encode_rgb9e5([-0.0, -1e-6, 0.0]), (0, 0));
    }

    #[test]
    fn huge_values_clamp_to_the_max_and_are_flagged() {
        let (word, flags) = encode_rgb9e5([1e6, 2.0, f32::MAX]);
        assert_eq!(flags, FLAG_CLAMPED);
        let back = decode_rgb9e5(word);
        assert_eq!(back[0], RGB9E5_MAX);
        assert_eq!(back[2], RGB9E5_MAX);
        assert!(back.iter().all(|x| x.is_finite()));
        // 2 next to 65408 is below the shared exponent's step: it rounds to 0, within the bound.
        assert!(back[1] <= 2.0 + RGB9E5_MAX / 511.0);
    }

    #[test]
    fn nan_and_infinity_are_flagged_never_written() {
        let (word, flags) = encode_rgb9e5([f32::NAN, 1.0, f32::INFINITY]);
        assert_eq!(flags, FLAG_NON_FINITE);
        let back = decode_rgb9e5(word);
        assert!(back.iter().all(|x| x.is_finite()), "{back:?}");
        assert_eq!(back[0], 0.0);
        assert_eq!(back[2], RGB9E5_MAX);
        let (word, flags) = encode_rgb9e5([f32::NEG_INFINITY, f32::NAN, 0.5]);
        assert_eq!(flags, FLAG_NON_FINITE);
        assert_eq!(decode_rgb9e5(word), [0.0, 0.0, 0.5]);
        // The frame carries the flag in its header.
        let frame = Frame::encode(1, 1, &[[0.5; 3], [f32::NAN, 0.0, 0.0]]).unwrap();
        assert_eq!(frame.header.flags, FLAG_NON_FINITE);
        assert_eq!(frame.irradiance()[1], [0.0; 3]);
    }

    #[test]
    fn frame_bytes_round_trip_and_refuse_damage() {
        let irr = vec![[0.1, 0.2, 0.3], [4.0, 5.0, 6.0], [0.0; 3]];
        let frame = Frame::encode(7, 42, &irr).unwrap();
        let bytes = frame.bytes().clone();
        assert_eq!(bytes.len(), HEADER_LEN + 4 * irr.len());
        assert_eq!(&bytes[..4], b"BNCF");
        let back = Frame::parse(bytes.clone()).unwrap();
        assert_eq!(back, frame);
        assert_eq!(
            back.header,
            FrameHeader {
                flags: 0,
                patch_count: 3,
                sequence: 7,
                lights_version: 42
            }
        );
        for (got, want) in back.irradiance().iter().zip(&irr) {
            for k in 0..3 {
                assert!((f64::from(got[k]) - f64::from(want[k])).abs() <= bound(*want));
            }
        }
        assert_eq!(Frame::parse(bytes.slice(..10)), Err(FrameError::Short(10)));
        assert!(matches!(
            Frame::parse(bytes.slice(..bytes.len() - 1)),
            Err(FrameError::Length { count: 3, .. })
        ));
        let mut bad = bytes.to_vec();
        bad[0] = b'X';
        assert!(matches!(
            Frame::parse(Bytes::from(bad)),
            Err(FrameError::Magic(_))
        ));
        let mut bad = bytes.to_vec();
        bad[4] = 2;
        assert_eq!(Frame::parse(Bytes::from(bad)), Err(FrameError::Version(2)));
    }
}
