// The six-direction irradiance volume, exactly as client/src/volume.rs defines it (its module doc
// is the convention): one RGBA16F 3D texture per face direction (+X, −X, +Y, −Y, +Z, −Z), texel
// (x, y, z) of grid f holding the patch on face f of voxel (x, y, z): rgb its indirect
// irradiance, a its coverage (1 where a patch is, 0 elsewhere). The shader in shading.js samples
// it the way `Volume::sample` does; `sample` below is the same function on the CPU, for tests.

import { ClampToEdgeWrapping, Data3DTexture, DataUtils, HalfFloatType, LinearFilter, RGBAFormat } from 'three';

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

  // One grid filtered trilinearly at p (clamp to edge, texel centres at voxel centres): [r, g, b, a].
  filter(face, p) {
    const [dx, dy, dz] = this.dims;
    const u = [0, 1, 2].map((a) => (p[a] - this.origin[a]) / this.voxelSize - 0.5);
    const max = [dx - 1, dy - 1, dz - 1];
    const lo = u.map((x, a) => Math.min(Math.max(Math.floor(x), -1), max[a] + 1));
    const frac = u.map((x) => Math.min(Math.max(x - Math.floor(x), 0), 1));
    const acc = [0, 0, 0, 0];
    const d = this.data[face];
    for (let corner = 0; corner < 8; corner++) {
      const step = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
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

  // Indirect irradiance at p with normal n: Volume::sample (client/src/volume.rs).
  sample(p, n) {
    const sq = n.map((x) => x * x);
    const len = sq[0] + sq[1] + sq[2];
    const w = len > 0 && Number.isFinite(len) ? sq.map((x) => x / len) : [1 / 3, 1 / 3, 1 / 3];
    const sum = [0, 0, 0];
    let covered = 0;
    for (let axis = 0; axis < 3; axis++) {
      if (w[axis] === 0) continue;
      const face = axis * 2 + (n[axis] >= 0 ? 0 : 1);
      const v = this.filter(face, p);
      if (v[3] >= MIN_COVERAGE) {
        for (let c = 0; c < 3; c++) sum[c] += (w[axis] * v[c]) / v[3];
        covered += w[axis];
      }
    }
    return covered > 0 ? sum.map((x) => x / covered) : [0, 0, 0];
  }

  dispose() {
    for (const t of this.textures) t.dispose();
  }
}

const FACE_NAMES = ['FACE_POS_X', 'FACE_NEG_X', 'FACE_POS_Y', 'FACE_NEG_Y', 'FACE_POS_Z', 'FACE_NEG_Z'];

// A face as the layout JSON carries it: the code, or the proto enum's name.
function faceCode(f) {
  if (Number.isInteger(f) && f >= 0 && f < 6) return f;
  const i = FACE_NAMES.indexOf(f);
  return i >= 0 ? i : undefined;
}
