// The viewer: the scene's own model drawn with the session's lights (three.js, shadow maps) and
// the indirect light streamed over the session's WebSocket, sampled per fragment from the
// six-direction volume exactly as the native viewer does (shading.js, volume.js). A scene baked
// with probes also gets probe frames, which light a sphere that follows the camera or, in a
// headset, the controller (probes.js).

import {
  Box3,
  Group,
  PerspectiveCamera,
  Raycaster,
  ReinhardToneMapping,
  Scene,
  ShaderChunk,
  SRGBColorSpace,
  Vector2,
  Vector3,
  WebGLRenderer,
} from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

import { ApiError, getSession, layoutOf, listScenes, modelUrl, putLights } from './api.js';
import { Connection } from './connection.js';
import {
  Bounds,
  Markers,
  applyEmissive,
  buildLights,
  defaultLights,
  markerPosition,
  moveLight,
  scaleLight,
} from './lights.js';
import { Overlay } from './overlay.js';
import { Probes, ProbeSphere } from './probes.js';
import {
  bindVolume,
  convertMaterial,
  installShadowOffset,
  installSpotFalloff,
  shadowDepthMaterials,
  volumeUniforms,
} from './shading.js';
import { Volume } from './volume.js';
import { Xr } from './xr.js';

installSpotFalloff(ShaderChunk);
installShadowOffset(ShaderChunk);

export const TERMS = {
  both: { direct: true, indirect: true },
  direct: { direct: true, indirect: false },
  indirect: { direct: false, indirect: true },
};

// What the page exposes for tests and for anyone curious in the console: read-only figures and
// a few actions. Nothing here is needed by the page itself.
function testHooks(viewer) {
  return {
    get ready() {
      return viewer.ready;
    },
    get stats() {
      return viewer.overlay.snapshot();
    },
    get lights() {
      return structuredClone(viewer.lights);
    },
    get drawn() {
      return viewer.drawn;
    },
    // Every frame kept from the WebSocket, in order: {sequence, lightsVersion, checksum}.
    get received() {
      return viewer.received.slice();
    },
    get connection() {
      return viewer.connectionState;
    },
    get writable() {
      return viewer.writable;
    },
    get message() {
      return viewer.messageText;
    },
    // The emissive materials as drawn: {name, node, emissive: [r, g, b]} (applyEmissive).
    get emissive() {
      return (viewer.emissive ?? []).map((e) => ({
        name: e.name,
        node: e.node,
        emissive: e.material.emissive.toArray(),
      }));
    },
    setTerms: (t) => viewer.setTerms(t),
    // Sets the lights as a local edit would; resolves to the server's answer and when the edit
    // was made (epoch ms, comparable across tabs).
    setLights: async (set) => {
      const pending = viewer.editLights(() => structuredClone(set));
      const editedAt = viewer.editedAtEpoch;
      return { answer: await pending, edited_at_epoch_ms: editedAt };
    },
    sample: (p, n) => viewer.volume.sample(p, n),
    // Resolves once a frame answering `lightsVersion` (or newer) has been drawn.
    drawnVersion: (lightsVersion) => viewer.waitDrawn(lightsVersion),
    // Where light `i`'s marker is on the page, in CSS pixels (for driving the mouse).
    markerOnScreen: (i) => viewer.markerOnScreen(i),
    // {presenting, rig, held}: an immersive session, the rig's place, the lights held.
    get xr() {
      return viewer.xr.state;
    },
    // The scene's probes: {count, sequence, lightsVersion, checksum} of the probe frame on
    // screen (null before one), or null for a scene without probes.
    get probes() {
      const p = viewer.probes;
      if (!p) return null;
      const f = p.frame;
      return { count: p.count, frame: f ? { sequence: f.sequence, lightsVersion: f.lightsVersion, checksum: checksum(f.words) } : null };
    },
    // The ambient cube the probes give at a point (six [r, g, b], face order), or null.
    ambientCube: (p) => viewer.probes?.ambientCube(p) ?? null,
    // The probe-lit sphere: {on, visible, centre, radius, cube}, or null without probes.
    get object() {
      return viewer.sphere?.state ?? null;
    },
    // Pins the sphere at `centre` with `radius` (null: it follows the camera again).
    placeObject: (centre, radius) => {
      if (viewer.sphere) viewer.sphere.pinned = centre ? { centre, radius } : null;
    },
  };
}

export class Viewer {
  constructor(root, params) {
    this.root = root;
    this.params = params;
    this.ready = false;
    this.drawn = null; // {sequence, lightsVersion, at} of the newest frame on screen
    this.firstDrawnAt = null;
    this.pendingFrame = null;
    this.lights = { lights: [] };
    this.lightsVersion = 0;
    this.writable = !params.readOnly;
    this.terms = TERMS[params.terms] ?? TERMS.both;
    this.selected = -1;
    this.sendState = { inFlight: false, queued: false };
    this.editTimes = new Map(); // lights version → when the edit that made it happened
    this.drawnWaiters = [];
    this.received = [];
    this.connectionState = { state: 'connecting', detail: '' };
    this.messageText = '';
    window.bounce = testHooks(this);
  }

  async start() {
    const p = this.params;
    this.message(`loading ${p.scene}…`);
    const loader = new GLTFLoader();
    // The scene list first: on a server that wants a token for reads, its refusal (with the
    // server's words) is what the page shows, not the model loader's bare 401.
    const scenes = await listScenes();
    const [layout, gltf, session] = await Promise.all([
      layoutOf(p.scene),
      loader.loadAsync(modelUrl(p.scene)).catch((e) => {
        throw new Error(`the scene's model could not be loaded: ${e.message ?? e}`);
      }),
      getSession(p.session),
    ]);
    if (session.scene !== p.scene) {
      throw new Error(`session ${p.session} belongs to scene ${session.scene}, not ${p.scene}`);
    }
    // Without a token on a server that wants one, this is a spectator: it says so when a light
    // is touched rather than failing the write.
    if (scenes.writes_need_token && !p.token) this.writable = false;
    this.volume = new Volume(layout);
    this.probes = layout.probe_positions?.length ? new Probes(layout.probe_positions) : null;
    this.buildScene(gltf);
    this.applyRemoteLights(session.lights_version, { lights: session.lights ?? [] });
    this.connection = new Connection(
      p.session,
      p.token,
      {
        onFrame: (frame, at) => this.onFrame(frame, at),
        onProbes: (frame) => {
          this.pendingProbes = frame;
          this.overlay.receivedProbes(frame);
        },
        onState: (s) => this.onConnectionState(s),
      },
      { probes: this.probes !== null },
    );
    this.ready = true;
    this.message('');
  }

  buildScene(gltf) {
    const p = this.params;
    this.scene = new Scene();
    this.uniforms = volumeUniforms();
    bindVolume(this.uniforms, this.volume);
    const model = gltf.scene;
    // The session's lights light the scene, not the file's own.
    const fileLights = [];
    model.traverse((o) => {
      if (o.isLight) fileLights.push(o);
    });
    for (const l of fileLights) l.parent.remove(l);
    // One converted material per source material, and per (emissive material, node): a session
    // may change one lamp of many that share a material by naming its node, as the bake keeps
    // them apart (one emitter group per pair).
    const converted = new Map();
    const shadowDepth = shadowDepthMaterials();
    model.traverse((o) => {
      if (!o.isMesh) return;
      const materials = Array.isArray(o.material) ? o.material : [o.material];
      const mine = materials.map((m) => {
        const node = emits(m) ? nodeName(gltf, o) : null;
        const key = node === null ? m : `${m.uuid}\u0000${node}`;
        if (!converted.has(key)) {
          converted.set(key, { source: m, node, material: convertMaterial(m, this.uniforms) });
        }
        return converted.get(key).material;
      });
      o.material = Array.isArray(o.material) ? mine : mine[0];
      if (!o.geometry.attributes.normal) {
        // glTF draws a primitive without normals flat (the shader derives the triangle's
        // normal), but three's shadow lookup offsets along the vertex normal: without one it
        // does not offset at all and surfaces shadow themselves. Per-triangle normals here.
        o.geometry = o.geometry.index ? o.geometry.toNonIndexed() : o.geometry;
        o.geometry.computeVertexNormals();
      }
      o.castShadow = true;
      o.receiveShadow = true;
      o.customDepthMaterial = shadowDepth.depth;
      o.customDistanceMaterial = shadowDepth.distance;
    });
    // The emissive materials, by glTF material and node name, with the file's factor and
    // strength: what a session's emissive changes replace (applyEmissive).
    this.emissive = [];
    for (const { source, node, material } of converted.values()) {
      if (node === null) continue;
      this.emissive.push({
        material,
        name: source.name,
        node,
        factor: source.emissive.toArray(),
        strength: source.emissiveIntensity ?? 1,
      });
    }
    this.scene.add(model);
    model.updateMatrixWorld(true);
    this.bounds = new Bounds(new Box3().setFromObject(model));
    this.lightGroup = new Group();
    this.scene.add(this.lightGroup);
    this.markers = new Markers(this.scene, this.bounds);
    this.markers.setVisible(p.markers);
    if (this.probes) {
      this.sphere = new ProbeSphere(this.scene, this.bounds, this.probes);
      this.sphere.on = p.object !== false;
    }
    if (!p.ui) {
      this.root.querySelector('#panel').hidden = true;
    }

    const canvas = this.root.querySelector('canvas');
    this.renderer = new WebGLRenderer({ canvas, antialias: p.antialias, preserveDrawingBuffer: p.preserve });
    this.renderer.setPixelRatio(p.pixelRatio ?? window.devicePixelRatio);
    this.renderer.outputColorSpace = SRGBColorSpace;
    this.renderer.toneMapping = ReinhardToneMapping;
    this.renderer.toneMappingExposure = p.exposure;
    this.renderer.shadowMap.enabled = true;
    this.renderer.setClearColor(0x000000, 1);

    const cam = p.camera ?? framing(this.bounds);
    this.camera = new PerspectiveCamera(cam.fov, 1, 0.01, 100);
    this.camera.position.fromArray(cam.eye);
    this.camera.lookAt(new Vector3().fromArray(cam.target));
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.target.fromArray(cam.target);
    this.controls.update();
    this.fly = { on: false, keys: new Set(), yaw: 0, pitch: 0 };
    this.overlay = new Overlay(this.root.querySelector('#overlay'), p.overlay);
    this.xr = new Xr(this);
    if (!p.ui) this.xr.button.remove();
    this.bindInput(canvas);
    this.bindPanel();
    window.addEventListener('resize', () => this.resize());
    this.resize();
    this.last = performance.now();
    this.renderer.setAnimationLoop((t) => this.frame(t));
  }

  resize() {
    const canvas = this.renderer.domElement;
    const w = canvas.clientWidth || window.innerWidth;
    const h = canvas.clientHeight || window.innerHeight;
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
  }

  // One animation frame: the newest indirect light into the volume, the camera moved, drawn.
  frame(now) {
    const dt = Math.min((now - this.last) / 1000, 0.1);
    this.last = now;
    let applied = null;
    if (this.pendingFrame) {
      const { frame, at } = this.pendingFrame;
      this.pendingFrame = null;
      try {
        this.volume.apply(frame);
        applied = { frame, at };
      } catch (e) {
        this.message(e.message);
      }
    }
    if (this.pendingProbes) {
      try {
        this.probes.apply(this.pendingProbes);
      } catch (e) {
        this.message(e.message);
      }
      this.pendingProbes = null;
    }
    if (this.fly.on) this.flyStep(dt);
    this.markers.scaleFor(this.camera);
    this.xr.update(dt);
    this.sphere?.update(this);
    this.updateDepthRange();
    this.uniforms.bounceIndirect.value = this.terms.indirect && (this.drawn || applied) ? 1 : 0;
    this.lightGroup.visible = this.terms.direct;
    const t0 = performance.now();
    this.renderer.render(this.scene, this.camera);
    const drawAt = performance.now();
    this.overlay.frameTime(now, drawAt - t0);
    if (applied) {
      const f = applied.frame;
      // `at_epoch_ms` compares across tabs (each tab's performance.now() has its own origin).
      this.drawn = {
        sequence: f.sequence,
        lightsVersion: f.lightsVersion,
        at: drawAt,
        at_epoch_ms: performance.timeOrigin + drawAt,
        bytes: f.bytes,
      };
      if (this.firstDrawnAt === null) this.firstDrawnAt = drawAt;
      const edit = this.editTimes.get(f.lightsVersion);
      if (edit !== undefined) {
        this.overlay.latency(drawAt - edit);
        this.editTimes.delete(f.lightsVersion);
      }
      for (const v of [...this.editTimes.keys()]) if (v < f.lightsVersion) this.editTimes.delete(v);
      this.overlay.frame(f, drawAt - applied.at, this.firstDrawnAt);
      this.drawnWaiters = this.drawnWaiters.filter((w) => {
        if (f.lightsVersion >= w.version) w.resolve(this.drawn);
        return f.lightsVersion < w.version;
      });
    }
    this.overlay.render({
      connection: this.connectionState,
      lightsVersion: this.lightsVersion,
      terms: this.terms,
      writable: this.writable,
      selected: this.selected,
      lights: this.lights,
      fly: this.fly.on,
      object: this.sphere ? objectStatus(this.sphere, this.probes) : null,
    });
  }

  // The native viewer's depth range: from the eye to past the scene's far side.
  updateDepthRange() {
    const distance = this.camera.getWorldPosition(new Vector3()).distanceTo(this.bounds.centre);
    const far = distance + this.bounds.radius * 2;
    const near = Math.max(far / 2000, 1e-4);
    if (this.camera.far !== far || this.camera.near !== near) {
      this.camera.far = far;
      this.camera.near = near;
      this.camera.updateProjectionMatrix();
    }
  }

  waitDrawn(version) {
    if (this.drawn && this.drawn.lightsVersion >= version) return Promise.resolve(this.drawn);
    return new Promise((resolve) => this.drawnWaiters.push({ version, resolve }));
  }

  onFrame(frame, at) {
    // Only the newest frame is applied at the next animation frame; older ones are skipped.
    this.pendingFrame = { frame, at };
    this.overlay.received(frame);
    this.received.push({ sequence: frame.sequence, lightsVersion: frame.lightsVersion, checksum: checksum(frame.words) });
    if (this.received.length > 1000) this.received.shift();
    if (frame.lightsVersion > this.lightsVersion && !this.sendState.inFlight && !this.dragging) {
      // Someone else changed the lights: read them, for direct light.
      const version = frame.lightsVersion;
      getSession(this.params.session)
        .then((s) => {
          if (s.lights_version >= version) this.applyRemoteLights(s.lights_version, { lights: s.lights ?? [] });
        })
        .catch((e) => this.message(`reading the session's lights: ${e.message}`));
    }
  }

  onConnectionState(s) {
    this.connectionState = s;
  }

  applyRemoteLights(version, set) {
    if (version < this.lightsVersion) return;
    this.lightsVersion = version;
    this.lights = set;
    this.selected = Math.min(this.selected, set.lights.length - 1);
    this.rebuildLights();
  }

  rebuildLights() {
    buildLights(this.lightGroup, this.lights, this.bounds);
    applyEmissive(this.emissive ?? [], this.lights);
    this.markers.selected = this.selected;
    this.markers.update(this.lights);
  }

  setTerms(name) {
    if (TERMS[name]) this.terms = TERMS[name];
  }

  // A local edit: shown at once (direct light), sent to the session (indirect light follows).
  editLights(edit) {
    if (!this.writable) {
      this.message('read-only viewer: this page has no write token the server accepts');
      return Promise.resolve(null);
    }
    const next = edit(structuredClone(this.lights));
    if (!next) return Promise.resolve(null);
    this.lights = next;
    this.rebuildLights();
    this.editedAt = performance.now();
    this.editedAtEpoch = performance.timeOrigin + this.editedAt;
    return this.send();
  }

  // At most one write in flight; edits made meanwhile are coalesced into the next one, so a drag
  // sends as fast as the server answers and never queues stale positions.
  send() {
    const s = this.sendState;
    if (s.inFlight) {
      s.queued = true;
      return s.promise;
    }
    s.inFlight = true;
    const editedAt = this.editedAt;
    s.promise = putLights(this.params.session, this.lights, this.params.token)
      .then((answer) => {
        this.lightsVersion = Math.max(this.lightsVersion, answer.lights_version);
        if (answer.changed) this.editTimes.set(answer.lights_version, editedAt);
        return answer;
      })
      .catch((e) => {
        if (e instanceof ApiError && e.code === 'unauthenticated') {
          this.writable = false;
          this.message(`read-only viewer: ${e.message}. Open the page with ?token=… to move lights.`);
        } else {
          this.message(`the server refused the lights: ${e.message}`);
        }
        // Back to what the session holds.
        getSession(this.params.session)
          .then((sess) => this.applyRemoteLights(sess.lights_version, { lights: sess.lights ?? [] }))
          .catch(() => {});
        return null;
      })
      .finally(() => {
        s.inFlight = false;
        if (s.queued && this.writable) {
          s.queued = false;
          this.send();
        }
      });
    return s.promise;
  }

  message(text) {
    this.messageText = text;
    const el = document.getElementById('message');
    el.textContent = text;
    el.hidden = !text;
  }

  bindInput(canvas) {
    const raycaster = new Raycaster();
    const pointer = new Vector2();
    const pick = (event) => {
      const r = canvas.getBoundingClientRect();
      pointer.set(((event.clientX - r.left) / r.width) * 2 - 1, -((event.clientY - r.top) / r.height) * 2 + 1);
      raycaster.setFromCamera(pointer, this.camera);
      const hit = raycaster.intersectObjects(this.markers.group.children, false)[0];
      return hit ? hit.object.userData.index : -1;
    };
    canvas.addEventListener('pointerdown', (event) => {
      if (event.button !== 0) return;
      const index = pick(event);
      if (index < 0) return;
      this.select(index);
      if (!this.writable) {
        this.message('read-only viewer: this page has no write token the server accepts');
        return;
      }
      // Drag in the plane through the light that faces the camera.
      this.controls.enabled = false;
      this.dragging = { index, pointerId: event.pointerId };
      canvas.setPointerCapture(event.pointerId);
      event.preventDefault();
    });
    canvas.addEventListener('pointermove', (event) => {
      if (!this.dragging || event.pointerId !== this.dragging.pointerId) {
        if (this.fly.on && event.buttons & 1) {
          this.fly.yaw -= event.movementX * 0.004;
          this.fly.pitch = Math.max(-1.5, Math.min(1.5, this.fly.pitch - event.movementY * 0.004));
        }
        return;
      }
      const light = this.lights.lights[this.dragging.index];
      if (!light) return;
      const at = markerPosition(light, this.bounds);
      const normal = this.camera.getWorldDirection(new Vector3());
      const r = canvas.getBoundingClientRect();
      pointer.set(((event.clientX - r.left) / r.width) * 2 - 1, -((event.clientY - r.top) / r.height) * 2 + 1);
      raycaster.setFromCamera(pointer, this.camera);
      const denom = raycaster.ray.direction.dot(normal);
      if (Math.abs(denom) < 1e-6) return;
      const t = at.clone().sub(raycaster.ray.origin).dot(normal) / denom;
      if (t <= 0) return;
      const p = raycaster.ray.at(t, new Vector3());
      const index = this.dragging.index;
      this.editLights((set) => {
        moveLight(set.lights[index], p, this.bounds);
        return set;
      });
    });
    const endDrag = () => {
      this.dragging = null;
      this.controls.enabled = !this.fly.on;
    };
    canvas.addEventListener('pointerup', endDrag);
    canvas.addEventListener('pointercancel', endDrag);
    canvas.addEventListener(
      'wheel',
      (event) => {
        const index = pick(event);
        if (index < 0) return;
        // Over a light the wheel dims and brightens it instead of zooming.
        event.preventDefault();
        event.stopImmediatePropagation();
        this.select(index);
        this.editLights((set) => {
          scaleLight(set.lights[index], event.deltaY < 0 ? 1.25 : 0.8);
          return set;
        });
      },
      { passive: false, capture: true },
    );
    window.addEventListener('keydown', (event) => {
      if (event.target instanceof HTMLInputElement) return;
      this.fly.keys.add(event.code);
      switch (event.code) {
        case 'Digit1':
          this.setTerms('both');
          break;
        case 'Digit2':
          this.setTerms('direct');
          break;
        case 'Digit3':
          this.setTerms('indirect');
          break;
        case 'KeyH':
          this.overlay.toggle();
          break;
        case 'KeyF':
          this.toggleFly();
          break;
        case 'KeyP':
          if (this.sphere) this.sphere.on = !this.sphere.on;
          break;
        case 'Tab':
          if (this.lights.lights.length) {
            event.preventDefault();
            this.select((this.selected + 1) % this.lights.lights.length);
          }
          break;
        case 'Equal':
        case 'NumpadAdd':
          this.scaleSelected(1.25);
          break;
        case 'Minus':
        case 'NumpadSubtract':
          this.scaleSelected(0.8);
          break;
        default:
      }
    });
    window.addEventListener('keyup', (event) => this.fly.keys.delete(event.code));
    window.addEventListener('blur', () => this.fly.keys.clear());
  }

  bindPanel() {
    for (const b of this.root.querySelectorAll('[data-terms]')) {
      b.addEventListener('click', () => this.setTerms(b.dataset.terms));
    }
    const colour = this.root.querySelector('#light-colour');
    colour.addEventListener('input', () => {
      const hex = colour.value.replace('#', '');
      const rgb = [0, 2, 4].map((i) => parseInt(hex.slice(i, i + 2), 16) / 255);
      // The picker speaks sRGB; lights are linear.
      this.setSelectedColour(rgb.map((c) => (c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4)));
    });
    this.colourInput = colour;
  }

  markerOnScreen(i) {
    const l = this.lights.lights[i];
    if (!l) return null;
    const p = markerPosition(l, this.bounds).project(this.camera);
    const r = this.renderer.domElement.getBoundingClientRect();
    return { x: r.left + ((p.x + 1) / 2) * r.width, y: r.top + ((1 - p.y) / 2) * r.height };
  }

  select(index) {
    this.selected = index;
    this.markers.selected = index;
    this.markers.update(this.lights);
  }

  scaleSelected(factor) {
    const index = this.selected;
    if (index < 0) return;
    this.editLights((set) => {
      scaleLight(set.lights[index], factor);
      return set;
    });
  }

  setSelectedColour(rgb) {
    const index = this.selected;
    if (index < 0) return;
    this.editLights((set) => {
      set.lights[index].color = rgb;
      return set;
    });
  }

  toggleFly() {
    this.fly.on = !this.fly.on;
    this.controls.enabled = !this.fly.on;
    if (this.fly.on) {
      const d = this.camera.getWorldDirection(new Vector3());
      this.fly.yaw = Math.atan2(-d.x, -d.z);
      this.fly.pitch = Math.asin(Math.max(-1, Math.min(1, d.y)));
    } else {
      const d = this.camera.getWorldDirection(new Vector3());
      this.controls.target.copy(this.camera.position).addScaledVector(d, this.bounds.radius);
      this.controls.update();
    }
  }

  // WASD along the view, Q/E down and up, Shift faster: the native viewer's keys.
  flyStep(dt) {
    const k = this.fly.keys;
    const axis = (plus, minus) => (k.has(plus) ? 1 : 0) - (k.has(minus) ? 1 : 0);
    this.camera.rotation.set(this.fly.pitch, this.fly.yaw, 0, 'YXZ');
    const forward = this.camera.getWorldDirection(new Vector3());
    const right = new Vector3().crossVectors(forward, this.camera.up).normalize();
    const speed = this.bounds.radius * 0.5 * (k.has('ShiftLeft') || k.has('ShiftRight') ? 4 : 1);
    const move = new Vector3()
      .addScaledVector(forward, axis('KeyW', 'KeyS'))
      .addScaledVector(right, axis('KeyD', 'KeyA'))
      .addScaledVector(this.camera.up, axis('KeyE', 'KeyQ'));
    if (move.lengthSq() > 0) this.camera.position.addScaledVector(move.normalize(), speed * dt);
  }
}

// The overlay's word on the probe-lit sphere (the native viewer's sphere_status).
function objectStatus(sphere, probes) {
  if (!sphere.on) return 'off';
  if (!probes.frame) return 'waiting for probe light';
  return `on (${probes.count} probes)`;
}

// FNV-1a over the payload words: lets a test compare the frame a tab got with another client's.
function checksum(words) {
  let h = 0x811c9dc5;
  for (let i = 0; i < words.length; i++) {
    h = Math.imul(h ^ words[i], 0x01000193) >>> 0;
  }
  return h;
}

// render/src/camera.rs's Camera::framing: the whole of the bounds from +Z, 45° vertical.
export function framing(bounds) {
  const fov = 45;
  const half = bounds.max.clone().sub(bounds.min).multiplyScalar(0.5);
  const reach = Math.max(Math.max(half.x, half.y) / Math.tan(((fov / 2) * Math.PI) / 180), 1e-3);
  const eye = bounds.centre.clone();
  eye.z += half.z + reach * 1.1;
  return { eye: eye.toArray(), target: bounds.centre.toArray(), fov };
}

export { defaultLights };

function emits(material) {
  return Boolean(material.emissive) && material.emissive.getHex() !== 0;
}

// The glTF name of the node that places mesh `o` (`node #i` for an unnamed one, as the importer
// names it): the nearest object up the tree the loader associates with a node. A mesh of one
// primitive is its node's object, a mesh of several the node's children.
function nodeName(gltf, o) {
  for (let x = o; x; x = x.parent) {
    const index = gltf.parser.associations.get(x)?.nodes;
    if (index !== undefined) return gltf.parser.json.nodes[index]?.name ?? `node #${index}`;
  }
  return '';
}
