// WebXR: an "Enter VR" button where the browser offers immersive-vr (three's VRButton, which says
// why where it cannot: no WebXR, not a secure context, no headset), stereo rendering of the same
// scene by three's XR manager, and controllers that grab a light with the trigger and move it
// (the thumbstick dims and brightens the light held, the grip steps through colours).

import { BufferGeometry, Group, Line, LineBasicMaterial, Matrix4, Vector3 } from 'three';
import { VRButton } from 'three/addons/webxr/VRButton.js';

import { markerPosition, moveLight, scaleLight } from './lights.js';

const GRAB_REACH = 0.25; // metres from the controller's ray to a light marker that still grabs it
const STICK_DEAD_ZONE = 0.2;
const DIM_RATE = Math.log(4); // a full push scales the light by 4× (or ¼) a second
const MOVE_EPSILON = 1e-5; // of the scene's radius: closer than this is holding still
// The colours the grip steps through, from white: warm and cool whites, then saturated ones.
const PALETTE = [
  [1, 1, 1],
  [1, 0.75, 0.5],
  [0.65, 0.8, 1],
  [1, 0.25, 0.2],
  [0.3, 1, 0.35],
  [0.3, 0.45, 1],
];

function sameColour(a, b) {
  return a.every((v, i) => Math.abs(v - b[i]) < 1e-6);
}

export class Xr {
  constructor(viewer) {
    this.viewer = viewer;
    const renderer = viewer.renderer;
    renderer.xr.enabled = true;
    // The headset stands where the desktop camera is, on the scene's floor.
    this.rig = new Group();
    viewer.scene.add(this.rig);
    renderer.xr.addEventListener('sessionstart', () => this.enter());
    renderer.xr.addEventListener('sessionend', () => this.leave());
    this.button = VRButton.createButton(renderer);
    this.button.id = 'vr-button';
    viewer.root.appendChild(this.button);
    this.controllers = [0, 1].map((i) => this.controller(i));
    this.grabbed = new Map(); // controller → {index, offset}
  }

  controller(i) {
    const c = this.viewer.renderer.xr.getController(i);
    const ray = new Line(
      new BufferGeometry().setFromPoints([new Vector3(0, 0, 0), new Vector3(0, 0, -1)]),
      new LineBasicMaterial({ color: 0xffffff }),
    );
    ray.scale.z = 5;
    c.add(ray);
    c.addEventListener('connected', (e) => {
      c.userData.gamepad = e.data.gamepad;
      c.userData.handedness = e.data.handedness;
      c.userData.tracked = true;
    });
    c.addEventListener('disconnected', () => {
      c.userData.tracked = false;
    });
    c.addEventListener('selectstart', () => this.grab(c));
    c.addEventListener('selectend', () => this.grabbed.delete(c));
    c.addEventListener('squeezestart', () => this.recolour(c));
    this.rig.add(c);
    return c;
  }

  // three poses the XR camera relative to the camera's parent: the rig.
  enter() {
    const v = this.viewer;
    this.saved = { position: v.camera.position.clone(), quaternion: v.camera.quaternion.clone() };
    this.rig.position.set(v.camera.position.x, v.bounds.min.y, v.camera.position.z);
    // A metre of the headset's is `xrScale` scene units: the rig (and so the eyes, their distance
    // and the controllers) is scaled, not the scene.
    this.rig.scale.setScalar(v.params.xrScale ?? 1);
    this.rig.add(v.camera);
    v.camera.position.set(0, 0, 0);
    v.camera.quaternion.identity();
  }

  leave() {
    const v = this.viewer;
    this.grabbed.clear();
    v.scene.add(v.camera);
    if (this.saved) {
      v.camera.position.copy(this.saved.position);
      v.camera.quaternion.copy(this.saved.quaternion);
    }
  }

  // The marker nearest the controller's ray, within reach.
  grab(c) {
    const v = this.viewer;
    if (!v.writable) {
      v.message('read-only viewer: this page has no write token the server accepts');
      return;
    }
    const origin = new Vector3().setFromMatrixPosition(c.matrixWorld);
    const dir = new Vector3(0, 0, -1).transformDirection(c.matrixWorld);
    let best = -1;
    let bestDistance = GRAB_REACH * this.rig.scale.x;
    v.lights.lights.forEach((l, i) => {
      const p = markerPosition(l, v.bounds);
      const along = Math.max(p.clone().sub(origin).dot(dir), 0);
      const d = origin.clone().addScaledVector(dir, along).distanceTo(p);
      if (d < bestDistance) {
        best = i;
        bestDistance = d;
      }
    });
    if (best < 0) return;
    v.select(best);
    // Held rigidly: the light keeps its place relative to the controller.
    const inverse = new Matrix4().copy(c.matrixWorld).invert();
    const offset = markerPosition(v.lights.lights[best], v.bounds).applyMatrix4(inverse);
    this.grabbed.set(c, { index: best, offset });
  }

  // The grip, while a light is held: its next colour from PALETTE (the desktop has a colour
  // picker; a headset has buttons).
  recolour(c) {
    const g = this.grabbed.get(c);
    if (!g) return;
    this.viewer.editLights((set) => {
      const l = set.lights[g.index];
      if (!l) return null;
      const now = PALETTE.findIndex((p) => sameColour(p, l.color ?? [1, 1, 1]));
      l.color = [...PALETTE[(now + 1) % PALETTE.length]];
      return set;
    });
  }

  // Called every animation frame with its length in seconds: the lights held follow their
  // controllers. Only a change is an edit, so a light held still sends nothing.
  update(dt) {
    const v = this.viewer;
    if (!v.renderer.xr.isPresenting) return;
    for (const [c, g] of this.grabbed) {
      const p = g.offset.clone().applyMatrix4(c.matrixWorld);
      const stick = c.userData.gamepad?.axes?.[3] ?? 0;
      // Pushed fully forward (-1 on the y axis) brightens by DIM_RATE a second, pulled back dims:
      // by time, not by frame, so a 72 Hz and a 120 Hz headset dim alike.
      const factor = Math.abs(stick) > STICK_DEAD_ZONE ? Math.exp(-stick * DIM_RATE * dt) : 1;
      const held = v.lights.lights[g.index];
      if (!held) continue;
      const moved = markerPosition(held, v.bounds).distanceTo(p) > MOVE_EPSILON * v.bounds.radius;
      if (!moved && factor === 1) continue;
      v.editLights((set) => {
        const l = set.lights[g.index];
        if (!l) return null;
        moveLight(l, p, v.bounds);
        scaleLight(l, factor);
        return set;
      });
    }
  }

  // The controller the probe-lit sphere rides: the right hand's when it is tracked, else the
  // other one's, else null.
  trackedController() {
    const tracked = this.controllers.filter((c) => c.userData.tracked && c.visible);
    return tracked.find((c) => c.userData.handedness === 'right') ?? tracked[0] ?? null;
  }

  // What the tests read: whether a session is presenting, where the rig stands (the reference
  // space's origin in the scene; it is never rotated) and its scale, and the lights held.
  get state() {
    return {
      presenting: this.viewer.renderer.xr.isPresenting,
      rig: this.rig.position.toArray(),
      scale: this.rig.scale.x,
      held: [...this.grabbed.values()].map((g) => g.index),
    };
  }
}
