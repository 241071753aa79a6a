// The six-direction irradiance volume, exactly as client/src/volume.rs defines it (its module doc
// is the convention): one RGBA16F 3D texture per face direction (+X, −X, +Y, −Y, +Z, −Z), texel
// (x, y, z) of grid f holding the patch on face f of voxel (x, y, z): rgb its indirect
// irradiance, a its coverage (1 where a patch is, 0 elsewhere); and a seventh grid of one byte a
// voxel, the separators (bit f set when a thin wall parts the voxel from its neighbour in
// direction f). The shader in shading.js samples it the way `Volume::sample` does: the grid of
// the normal's dominant face, interpolated around the point's own voxel without reading across a
// separator; `sample` below is the same function on the CPU, for tests.

import {
  ClampToEdgeWrapping,
  Data3DTexture,
  DataUtils,
  HalfFloatType,
  LinearFilter,
  NearestFilter,
  RedFormat,
  RGBAFormat,
  UnsignedByteType,
} from 'three';

import { decodeRgb9e5 } from './frame.js';

export const MIN_COVERAGE = 1 / 256; // client::volume::MIN_COVERAGE
const MAX_VOLUME_DIM = 2048; // client::volume::MAX_VOLUME_DIM
const MAX_TEXELS = 1 << 24; // client::volume::MAX_TEXELS
const HALF_ONE = DataUtils.toHalfFloat(1);

export class Volume {
  // `layout` is GET /v1/scenes/{name}/layout: origin, voxel_size, dims, patch_count, voxels, faces.
  constructor(layout) {
    const [dx, dy, dz] = layout.dims;
    if (Math.max(dx, dy, dz) > MAX_VOLUME_DIM || dx * dy * dz > MAX_TEXELS) {
      throw new Error(`a ${layout.dims.join('×')} voxel grid is too large for a volume texture`);
    }
    this.origin = layout.origin;
    this.voxelSize = layout.voxel_size;
    this.dims = layout.dims;
    this.patchCount = layout.patch_count;
    const texels = dx * dy * dz;
    this.data = Array.from({ length: 6 }, () => new Uint16Array(texels * 4));
    // Per patch, where its value goes (grid and texel offset), so a frame is one pass.
    this.grid = new Uint8Array(this.patchCount);
    this.offset = new Uint32Array(this.patchCount);
    for (let i = 0; i < this.patchCount; i++) {
      const [x, y, z] = [layout.voxels[3 * i], layout.voxels[3 * i + 1], layout.voxels[3 * i + 2]];
      const face = faceCode(layout.faces[i]);
      if (!(x < dx && y < dy && z < dz) || face === undefined) {
        throw new Error(`layout patch ${i}: voxel [${x}, ${y}, ${z}] face ${layout.faces[i]} is not in the grid`);
      }
      this.grid[i] = face;
      this.offset[i] = 4 * (x + dx * (y + dy * z));
      this.data[face][this.offset[i] + 3] = HALF_ONE;
    }
    this.separators = separators(this.dims, this.data);
    this.textures = this.data.map((d) => {
      const t = new Data3DTexture(d, dx, dy, dz);
      t.format = RGBAFormat;
      t.type = HalfFloatType;
      t.minFilter = LinearFilter;
      t.magFilter = LinearFilter;
      t.wrapS = t.wrapT = t.wrapR = ClampToEdgeWrapping;
      t.unpackAlignment = 1;
      t.generateMipmaps = false;
      t.needsUpdate = true;
      return t;
    });
    // Read with texelFetch: the byte itself, no filtering.
    const sep = new Data3DTexture(this.separators, dx, dy, dz);
    sep.format = RedFormat;
    sep.type = UnsignedByteType;
    sep.minFilter = NearestFilter;
    sep.magFilter = NearestFilter;
    sep.wrapS = sep.wrapT = sep.wrapR = ClampToEdgeWrapping;
    sep.unpackAlignment = 1;
    sep.generateMipmaps = false;
    sep.needsUpdate = true;
    this.separatorTexture = sep;
    // Linear values as written (after RGB9E5 decoding), for `sample` and tests.
    this.values = new Float32Array(this.patchCount * 3);
  }

  // Writes a parsed frame's irradiance into the grids and marks the textures for upload.
  apply(frame) {
    if (frame.patchCount !== this.patchCount) {
      throw new Error(`the frame has ${frame.patchCount} patches and the layout ${this.patchCount}: not this scene's frame`);
    }
    const words = frame.words;
    for (let i = 0; i < this.patchCount; i++) {
      const rgb = decodeRgb9e5(words[i]);
      const d = this.data[this.grid[i]];
      const o = this.offset[i];
      for (let c = 0; c < 3; c++) {
        this.values[3 * i + c] = rgb[c];
        // RGB9E5's largest value (65408) fits f16: no clamping needed here.
        d[o + c] = DataUtils.toHalfFloat(rgb[c]);
      }
    }
    for (const t of this.textures) {
      t.needsUpdate = true;
    }
  }

  // One grid filtered trilinearly at p (clamp to edge, texel centres at voxel centres), leaving
  // out the texels across a separator from p's own voxel: [r, g, b, a].
  filter(face, p) {
    if (!p.every(Number.isFinite)) return [0, 0, 0, 0];
    const [dx, dy, dz] = this.dims;
    // Math.fround: the same f32 arithmetic as Volume::filter, so the own voxel is the same.
    const f = Math.fround;
    const u = [0, 1, 2].map((a) => f(f(f(f(p[a]) - f(this.origin[a])) / f(this.voxelSize)) - 0.5));
    const max = [dx - 1, dy - 1, dz - 1];
    const lo = u.map((x, a) => Math.min(Math.max(Math.floor(x), -1), max[a] + 1));
    const frac = u.map((x) => Math.min(Math.max(f(x - Math.floor(x)), 0), 1));
    // The own voxel: the corner nearest p.
    const own = frac.map((x) => (x >= 0.5 ? 1 : 0));
    const cell = [0, 1, 2].map((a) => Math.min(Math.max(lo[a] + own[a], 0), max[a]));
    const separated = this.separators[cell[0] + dx * (cell[1] + dy * cell[2])];
    const acc = [0, 0, 0, 0];
    const d = this.data[face];
    for (let corner = 0; corner < 8; corner++) {
      const step = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
      let blocked = false;
      for (let a = 0; a < 3; a++) {
        if (step[a] !== own[a] && separated & (1 << (2 * a + (step[a] > own[a] ? 0 : 1)))) {
          blocked = true;
        }
      }
      if (blocked) continue;
      let w = 1;
      const t = [0, 0, 0];
      for (let a = 0; a < 3; a++) {
        w *= step[a] ? frac[a] : 1 - frac[a];
        t[a] = Math.min(Math.max(lo[a] + step[a], 0), max[a]);
      }
      if (w === 0) continue;
      const o = 4 * (t[0] + dx * (t[1] + dy * t[2]));
      for (let c = 0; c < 4; c++) {
        acc[c] += w * DataUtils.fromHalfFloat(d[o + c]);
      }
    }
    return acc;
  }

  // Indirect irradiance at p on a surface whose seen side has normal n: Volume::sample
  // (client/src/volume.rs), the patch of n's dominant face, interpolated.
  sample(p, n) {
    if (!(n.every(Number.isFinite) && n[0] * n[0] + n[1] * n[1] + n[2] * n[2] > 0)) return [0, 0, 0];
    const v = this.filter(dominantFace(n), p);
    return v[3] >= MIN_COVERAGE ? [v[0] / v[3], v[1] / v[3], v[2] / v[3]] : [0, 0, 0];
  }

  dispose() {
    for (const t of this.textures) t.dispose();
    this.separatorTexture.dispose();
  }
}

// The face a normal faces most: bounce_core::voxel::dominant_face (ties to X, then Y).
export function dominantFace(n) {
  const a = n.map(Math.abs);
  if (a[0] >= a[1] && a[0] >= a[2]) return n[0] >= 0 ? 0 : 1;
  if (a[1] >= a[2]) return n[1] >= 0 ? 2 : 3;
  return n[2] >= 0 ? 4 : 5;
}

// Per voxel, bit f set when the voxel and its neighbour in direction f hold, between them,
// patches facing both ways along f's axis (client/src/volume.rs's `separators`).
function separators(dims, data) {
  const [dx, dy, dz] = dims;
  const count = dx * dy * dz;
  const faces = new Uint8Array(count);
  for (let f = 0; f < 6; f++) {
    const d = data[f];
    for (let i = 0; i < count; i++) {
      if (d[4 * i + 3] !== 0) faces[i] |= 1 << f;
    }
  }
  const out = new Uint8Array(count);
  const strides = [1, dx, dx * dy];
  for (let z = 0; z < dz; z++) {
    for (let y = 0; y < dy; y++) {
      for (let x = 0; x < dx; x++) {
        const v = [x, y, z];
        const i = x + dx * (y + dy * z);
        for (let a = 0; a < 3; a++) {
          if (v[a] + 1 >= dims[a]) continue;
          const j = i + strides[a];
          const both = 3 << (2 * a);
          if (((faces[i] | faces[j]) & both) === both) {
            out[i] |= 1 << (2 * a);
            out[j] |= 1 << (2 * a + 1);
          }
        }
      }
    }
  }
  return out;
}

const FACE_NAMES = ['FACE_POS_X', 'FACE_NEG_X', 'FACE_POS_Y', 'FACE_NEG_Y', 'FACE_POS_Z', 'FACE_NEG_Z'];

// A face as the layout JSON carries it: the code, or the proto enum's name.
function faceCode(f) {
  if (Number.isInteger(f) && f >= 0 && f < 6) return f;
  const i = FACE_NAMES.indexOf(f);
  return i >= 0 ? i : undefined;
}
