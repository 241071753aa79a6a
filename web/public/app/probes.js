// The probe-lit test object (issue 22): a sphere that is none of the baked surfaces, lit the way
// a moving object is, from the scene's irradiance probes. The twin of render/src/object.rs, whose
// module doc is the convention:
//
// - the probes nearest the sphere's centre (BLEND_PROBES of them, weights 1/d², a probe's own
//   values where the centre is on it) blend into one ambient cube, six irradiance values in the
//   face order +X, −X, +Y, −Y, +Z, −Z;
// - a fragment of unit normal n gets E(n) = n.x² E[±X] + n.y² E[±Y] + n.z² E[±Z] (the sign of
//   each component picking the side), plus the lights' direct light and shadows as any surface.
//
// On the desktop the sphere floats ahead of the camera (radius 3% of the scene's diagonal, six
// radii ahead), as in `bounce view`; in a headset it rides just ahead of the right controller (the
// other one when only it is tracked), else ahead of the headset. The blend is blind to walls, and the sphere casts no
// shadow and is not in the baked light.

import { Mesh, SphereGeometry, Vector3 } from 'three';

import { decodeRgb9e5 } from './frame.js';
import { objectMaterial } from './shading.js';

export const BLEND_PROBES = 8; // render::object::BLEND_PROBES
const ALBEDO = 0.8; // ProbeSphere::ahead_of's light grey

// The scene's probes: their positions from the layout, their newest light from probe frames.
export class Probes {
  // `flat`: the layout's probe_positions, x, y, z a probe.
  constructor(flat) {
    if (!Array.isArray(flat) || flat.length % 3 !== 0 || !flat.every(Number.isFinite)) {
      throw new Error('the layout\'s probe_positions are not x, y, z triples of numbers');
    }
    this.count = flat.length / 3;
    this.positions = Float32Array.from(flat);
    this.values = null; // Float32Array: 3 per probe direction, 6 directions a probe
    this.frame = null; // the parsed probe frame `values` came from
  }

  // A parsed probe frame (frame.js) into `values`.
  apply(frame) {
    if (frame.kind !== 'probes' || frame.patchCount !== 6 * this.count) {
      throw new Error(`a probe frame of ${frame.patchCount} values for ${this.count} probes: not this scene's`);
    }
    const values = new Float32Array(3 * frame.patchCount);
    for (let i = 0; i < frame.patchCount; i++) {
      values.set(decodeRgb9e5(frame.words[i]), 3 * i);
    }
    this.values = values;
    this.frame = frame;
  }

  // The ambient cube at `at` ([x, y, z]): render::object::ambient_cube. Null without probe light.
  ambientCube(at) {
    if (!this.values || this.count === 0 || !at.every(Number.isFinite)) return null;
    // The nearest few by a partial insertion sort: BLEND_PROBES is small, the probes are many.
    const near = [];
    for (let k = 0; k < this.count; k++) {
      const dx = this.positions[3 * k] - at[0];
      const dy = this.positions[3 * k + 1] - at[1];
      const dz = this.positions[3 * k + 2] - at[2];
      const d2 = dx * dx + dy * dy + dz * dz;
      if (near.length === BLEND_PROBES && d2 >= near[near.length - 1][0]) continue;
      let i = near.length === BLEND_PROBES ? near.length - 1 : near.length;
      while (i > 0 && near[i - 1][0] > d2) {
        near[i] = near[i - 1];
        i -= 1;
      }
      near[i] = [d2, k];
    }
    const own = (k) => Array.from({ length: 6 }, (_, d) => Array.from(this.values.subarray(18 * k + 3 * d, 18 * k + 3 * d + 3)));
    if (near[0][0] <= 1e-12) return own(near[0][1]);
    const sum = Array.from({ length: 6 }, () => [0, 0, 0]);
    let total = 0;
    for (const [d2, k] of near) {
      const w = 1 / d2;
      total += w;
      for (let d = 0; d < 6; d++) {
        for (let c = 0; c < 3; c++) sum[d][c] += w * this.values[18 * k + 3 * d + c];
      }
    }
    return sum.map((s) => s.map((v) => v / total));
  }
}

// The cube's irradiance for a surface of unit normal n: render::object::cube_irradiance, and the
// shader's bounceCubeIrradiance.
export function cubeIrradiance(cube, n) {
  const out = [0, 0, 0];
  for (let a = 0; a < 3; a++) {
    const side = cube[2 * a + (n[a] < 0 ? 1 : 0)];
    for (let c = 0; c < 3; c++) out[c] += side[c] * n[a] * n[a];
  }
  return out;
}

// The sphere in the scene: where it goes each frame, and its ambient cube in the shader.
export class ProbeSphere {
  constructor(scene, bounds, probes) {
    this.probes = probes;
    this.bounds = bounds;
    this.radius = Math.max(bounds.max.clone().sub(bounds.min).length() * 0.03, 1e-3);
    this.material = objectMaterial(ALBEDO);
    this.mesh = new Mesh(new SphereGeometry(1, 48, 24), this.material);
    this.mesh.scale.setScalar(this.radius);
    this.mesh.castShadow = false; // as the native sphere: it is not in anyone's light
    this.mesh.receiveShadow = true;
    this.mesh.visible = false;
    scene.add(this.mesh);
    this.on = true;
    this.pinned = null; // {centre, radius} set by a test or the console: stays put
    this.cube = null;
    this.cubeFor = null; // [centre, probe frame] the cube was blended for
  }

  // Once an animation frame: the sphere's place (pinned, or ahead of the camera or controller)
  // and, when it moved or new probe light came, its ambient cube.
  update(viewer) {
    const centre = new Vector3();
    if (this.pinned) {
      centre.fromArray(this.pinned.centre);
      this.mesh.scale.setScalar(this.pinned.radius);
    } else {
      this.mesh.scale.setScalar(this.radius);
      this.follow(viewer, centre);
    }
    this.mesh.position.copy(centre);
    const at = centre.toArray();
    const frame = this.probes.frame;
    const moved = !this.cubeFor || this.cubeFor[1] !== frame || at.some((v, i) => v !== this.cubeFor[0][i]);
    if (moved) {
      this.cube = this.probes.ambientCube(at);
      this.cubeFor = [at, frame];
      if (this.cube) this.cube.forEach((e, d) => this.material.userData.cube.value[d].fromArray(e));
    }
    // Without probe light yet there is nothing true to draw it with.
    this.mesh.visible = this.on && this.cube !== null;
    this.material.userData.indirect.value = viewer.terms.indirect ? 1 : 0;
  }

  follow(viewer, centre) {
    const xr = viewer.renderer.xr;
    let anchor = viewer.camera;
    let ahead = 6;
    if (xr.isPresenting) {
      // The first controller the headset tracks, else the headset itself.
      const hand = viewer.xr.trackedController();
      anchor = hand ?? xr.getCamera();
      ahead = hand ? 1.5 : 6;
    }
    anchor.updateMatrixWorld();
    centre.setFromMatrixPosition(anchor.matrixWorld);
    const dir = new Vector3(0, 0, -1).transformDirection(anchor.matrixWorld);
    centre.addScaledVector(dir, this.radius * ahead);
  }

  // What the tests read.
  get state() {
    return {
      on: this.on,
      visible: this.mesh.visible,
      centre: this.mesh.position.toArray(),
      radius: this.mesh.scale.x,
      cube: this.cube,
    };
  }
}
