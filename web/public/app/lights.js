// A session's lights (the server's JSON: bounce_core::light, glTF KHR_lights_punctual units) as
// three.js lights with shadow maps, and the small markers the mouse and controllers grab.

import {
  DirectionalLight,
  Group,
  Mesh,
  MeshBasicMaterial,
  PointLight,
  SphereGeometry,
  SpotLight,
  Vector3,
} from 'three';

const SHADOW_SIZE = 1024; // render/src/renderer.rs SHADOW_SIZE

// Everything the page knows of the scene's extent, for light placement and shadow frusta.
export class Bounds {
  constructor(box) {
    this.min = box.min.clone();
    this.max = box.max.clone();
    this.centre = box.getCenter(new Vector3());
    this.radius = Math.max(box.getSize(new Vector3()).length() / 2, 1e-3);
  }
}

// Makes `group`'s three.js lights match `set` ({"lights": [...]}). A light of the same type at the
// same index is updated in place, so dragging a light does not reallocate its shadow map.
export function buildLights(group, set, bounds) {
  const existing = group.children.filter((c) => c.isLight);
  set.lights.forEach((l, index) => {
    let light = existing[index];
    if (light && light.userData.type !== l.type) {
      removeLight(group, light);
      light = undefined;
    }
    if (!light) {
      light = createLight(l.type);
      if (!light) return;
      light.userData.type = l.type;
      group.add(light);
      if (light.target) group.add(light.target);
      existing[index] = light;
    }
    configure(light, l, bounds);
  });
  for (const extra of existing.slice(set.lights.length)) {
    if (extra) removeLight(group, extra);
  }
}

// The scene's emissive materials as `set`'s emissive changes leave them: a change names a glTF
// material, a node, or that material on that node, and gives a new emissive factor (`color`), a
// new strength, or both; where two changes reach one material the later wins, and a material no
// change reaches keeps the file's. `materials` holds {material, name, node, factor: [r, g, b],
// strength} per converted emissive material and node. Emission is drawn as convertMaterial draws
// the file's: factor × strength / π.
export function applyEmissive(materials, set) {
  const changes = set.lights.filter((l) => l.type === 'emissive');
  for (const e of materials) {
    let change;
    for (const l of changes) {
      const reaches =
        (l.material === undefined || l.material === e.name) &&
        (l.node === undefined || l.node === e.node);
      if (reaches) change = l;
    }
    const factor = change?.color ?? e.factor;
    const strength = change?.strength ?? e.strength;
    e.material.emissive.setRGB(factor[0], factor[1], factor[2]).multiplyScalar(strength / Math.PI);
  }
}

function removeLight(group, light) {
  group.remove(light);
  if (light.target) group.remove(light.target);
  light.dispose?.();
}

function createLight(type) {
  let light;
  if (type === 'point') light = new PointLight();
  else if (type === 'spot') light = new SpotLight();
  else if (type === 'directional') light = new DirectionalLight();
  else return null;
  light.castShadow = true;
  light.shadow.mapSize.set(SHADOW_SIZE, SHADOW_SIZE);
  return light;
}

function configure(light, l, bounds) {
  const colour = l.color ?? [1, 1, 1];
  light.color.setRGB(colour[0], colour[1], colour[2]);
  light.intensity = l.intensity;
  if (l.type === 'point' || l.type === 'spot') {
    light.position.fromArray(l.position);
    light.distance = l.range ?? 0;
    light.decay = 2;
  }
  if (l.type === 'spot') {
    const outer = l.outer_cone_angle ?? Math.PI / 4;
    const inner = Math.min(l.inner_cone_angle ?? 0, outer);
    // three's cone: angle = outer, penumbra chosen so that its inner cosine is glTF's inner
    // cone; shading.js swaps three's smoothstep for glTF's squared linear falloff.
    light.angle = outer;
    light.penumbra = outer > 0 ? 1 - inner / outer : 0;
    light.target.position.copy(light.position).add(new Vector3().fromArray(l.direction));
  }
  if (l.type === 'directional') {
    const dir = new Vector3().fromArray(l.direction).normalize();
    light.position.copy(bounds.centre).addScaledVector(dir, -2 * bounds.radius);
    light.target.position.copy(bounds.centre);
    const cam = light.shadow.camera;
    cam.left = cam.bottom = -bounds.radius;
    cam.right = cam.top = bounds.radius;
    cam.near = 0;
    cam.far = 4 * bounds.radius;
  } else {
    const reach = light.position.distanceTo(bounds.centre) + bounds.radius;
    light.shadow.camera.near = Math.max(reach / 1000, 1e-4);
    light.shadow.camera.far = reach;
  }
  light.shadow.camera.updateProjectionMatrix();
  // Offsetting along the normal keeps surfaces from shadowing themselves (shade.wgsl's
  // normal_offset is 0.4% of the scene's radius).
  light.shadow.normalBias = bounds.radius * 0.004;
  light.shadow.bias = 0;
}

// A marker per positioned light (directional lights sit on the bounds' sphere, where they come
// from), tinted with the light's colour.
export class Markers {
  constructor(scene, bounds) {
    this.bounds = bounds;
    this.group = new Group();
    this.group.name = 'light markers';
    scene.add(this.group);
    this.geometry = new SphereGeometry(1, 16, 12);
    this.size = bounds.radius * 0.03;
    this.selected = -1;
  }

  update(set) {
    for (const child of [...this.group.children]) {
      this.group.remove(child);
      child.material.dispose();
    }
    set.lights.forEach((l, index) => {
      // A sky and an emissive change have no place to mark.
      if (l.type !== 'directional' && !l.position) return;
      const m = new Mesh(this.geometry, new MeshBasicMaterial({ toneMapped: false }));
      const c = l.color ?? [1, 1, 1];
      const peak = Math.max(c[0], c[1], c[2], 1e-6);
      m.material.color.setRGB(c[0] / peak, c[1] / peak, c[2] / peak);
      m.position.copy(markerPosition(l, this.bounds));
      m.scale.setScalar(index === this.selected ? this.size * 1.6 : this.size);
      m.userData.index = index;
      // Markers are not part of the lit scene: no shadows from them.
      m.castShadow = false;
      m.receiveShadow = false;
      this.group.add(m);
    });
  }

  // About 1.5% of the view's height wherever the camera is.
  scaleFor(camera) {
    const eye = camera.getWorldPosition(new Vector3());
    const k = 2 * Math.tan((camera.fov * Math.PI) / 360) * 0.015;
    for (const m of this.group.children) {
      const s = Math.max(m.position.distanceTo(eye) * k, 1e-6);
      m.scale.setScalar(m.userData.index === this.selected ? s * 1.6 : s);
    }
  }

  setVisible(visible) {
    this.group.visible = visible;
  }
}

export function markerPosition(l, bounds) {
  if (l.type === 'directional') {
    const dir = new Vector3().fromArray(l.direction).normalize();
    return bounds.centre.clone().addScaledVector(dir, -bounds.radius);
  }
  return new Vector3().fromArray(l.position);
}

// The light moved so its marker sits at `p`: a directional light turns to shine from there
// through the scene's centre.
export function moveLight(l, p, bounds) {
  if (l.type === 'directional') {
    const dir = bounds.centre.clone().sub(p);
    if (dir.lengthSq() > 0) l.direction = dir.normalize().toArray();
  } else {
    l.position = p.toArray();
  }
}

export function scaleLight(l, factor) {
  const scale = (v) => Math.min(Math.max(v * factor, 0), 1e9);
  if (l.type === 'emissive') {
    // A change gives a strength, a colour or both (the server checks): the strength if it can.
    if (l.strength !== undefined) l.strength = scale(l.strength);
    else if (l.color) l.color = l.color.map(scale);
  } else if (l.type === 'sky') {
    if (l.color) l.color = l.color.map(scale);
  } else {
    l.intensity = scale(l.intensity);
  }
}

// A light for a scene that has none of its own: a point light near the top of the middle,
// bright enough to light a room of that size.
export function defaultLights(bounds) {
  const size = bounds.max.clone().sub(bounds.min);
  const p = bounds.centre.clone();
  p.y = bounds.min.y + 0.75 * size.y;
  return { lights: [{ type: 'point', position: p.toArray(), intensity: 2.5 * size.y * size.y }] };
}

