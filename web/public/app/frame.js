// Frames as the server sends them (wire/src/frame.rs): a 32-byte little-endian header, then one
// RGB9E5 word per patch. A scene with irradiance probes also sends probe frames, the same layout
// under the magic BNCP, one word per probe direction (six a probe, +X, −X, +Y, −Y, +Z, −Z); each
// follows its patch frame with the same sequence and lights version. This module only reads
// bytes; what a frame means for the picture is volume.js's and probes.js's business.

export const HEADER_LEN = 32;
const MAGIC = 0x46434e42; // "BNCF" read as a little-endian u32
const PROBE_MAGIC = 0x50434e42; // "BNCP"
const FORMAT_VERSION = 1;
const ENCODING_RGB9E5 = 1;
export const FLAG_NON_FINITE = 1;
export const FLAG_CLAMPED = 2;

export class FrameError extends Error {}

// The header's fields and a view of the payload words. Sequences and lights versions are u64 on
// the wire; they stay exact as Numbers up to 2^53, far beyond any session's count. `kind` is
// 'patches' or 'probes'; `patchCount` is the payload's word count either way (probe directions
// for a probe frame, as the wire's header names it).
export function parseFrame(buffer) {
  if (!(buffer instanceof ArrayBuffer)) {
    throw new FrameError('a frame must be binary');
  }
  if (buffer.byteLength < HEADER_LEN) {
    throw new FrameError(`frame is ${buffer.byteLength} bytes, shorter than its ${HEADER_LEN}-byte header`);
  }
  const view = new DataView(buffer);
  const magic = view.getUint32(0, true);
  if (magic !== MAGIC && magic !== PROBE_MAGIC) {
    throw new FrameError('not a bounce frame (bad magic)');
  }
  const kind = magic === MAGIC ? 'patches' : 'probes';
  const version = view.getUint16(4, true);
  if (version !== FORMAT_VERSION) {
    throw new FrameError(`frame format version ${version}, this page reads ${FORMAT_VERSION}`);
  }
  const encoding = view.getUint16(6, true);
  if (encoding !== ENCODING_RGB9E5) {
    throw new FrameError(`frame encoding ${encoding}, this page reads ${ENCODING_RGB9E5} (RGB9E5)`);
  }
  const flags = view.getUint32(8, true);
  const patchCount = view.getUint32(12, true);
  const payload = buffer.byteLength - HEADER_LEN;
  if (payload !== patchCount * 4) {
    throw new FrameError(`frame says ${patchCount} patches but carries ${payload} payload bytes`);
  }
  if (kind === 'probes' && patchCount % 6 !== 0) {
    throw new FrameError(`a probe frame carries six values a probe, not ${patchCount}`);
  }
  return {
    kind,
    flags,
    patchCount,
    sequence: Number(view.getBigUint64(16, true)),
    lightsVersion: Number(view.getBigUint64(24, true)),
    bytes: buffer.byteLength,
    words: new Uint32Array(buffer, HEADER_LEN, patchCount),
  };
}

// One RGB9E5 word to [r, g, b]: 9-bit mantissas (bits 0-8, 9-17, 18-26) sharing a 5-bit exponent
// (bits 27-31) with bias 15, no implicit leading one: value = m · 2^(e − 15 − 9).
export function decodeRgb9e5(word) {
  const scale = 2 ** ((word >>> 27) - 24);
  return [(word & 0x1ff) * scale, ((word >>> 9) & 0x1ff) * scale, ((word >>> 18) & 0x1ff) * scale];
}
