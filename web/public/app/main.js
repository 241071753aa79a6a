// The page's entry: with a scene and a session in the URL, the viewer; with a scene alone
// (`/?scene=cornell-box`), the viewer on that scene's newest session, or on a new one when it has
// none; with neither, the list of scenes and their sessions (open one, or start a new one).
//
// URL parameters: scene, session, token (a write or read token; kept for this tab only), camera
// (eye_x,eye_y,eye_z,target_x,target_y,target_z[,fov_deg], as `bounce render --camera`),
// exposure, terms (both|direct|indirect), xr_scale (the scene's units in a metre, for a headset:
// glTF says metres, but a game level may not be), object (on|off: the probe-lit sphere, in a
// scene baked with probes), overlay (on|off), aa (on|off), markers (on|off),
// ui (on|off: the buttons), pixel_ratio. The last few are for comparing pictures with
// `bounce render`, which draws neither markers nor buttons.

import { Box3, Vector3 } from 'three';

import { ApiError, createSession, layoutOf, listScenes, listSessions, useToken } from './api.js';
import { Bounds, defaultLights } from './lights.js';
import { Viewer } from './viewer.js';

const params = new URLSearchParams(location.search);

function onOff(name, fallback) {
  const v = params.get(name);
  if (v === null) return fallback;
  return v !== 'off' && v !== '0' && v !== 'false';
}

function camera() {
  const text = params.get('camera');
  if (!text) return null;
  const v = text.split(',').map(Number);
  if (!(v.length === 6 || v.length === 7) || v.some((x) => !Number.isFinite(x))) {
    throw new Error(`camera= takes 6 or 7 numbers (eye, target[, fov]), not "${text}"`);
  }
  return { eye: v.slice(0, 3), target: v.slice(3, 6), fov: v[6] ?? 45 };
}

// The token: from the URL once, then this tab's storage, so a reload keeps it but the address
// bar (and anything copied from it) need not. Every request sends it (see api.js).
function token() {
  const t = params.get('token');
  if (t) {
    sessionStorage.setItem('bounce-token', t);
    return t;
  }
  return sessionStorage.getItem('bounce-token') ?? '';
}
useToken(token());

function show(id) {
  for (const el of document.querySelectorAll('main > section')) el.hidden = el.id !== id;
}

function fail(text) {
  const el = document.getElementById('message');
  el.textContent = text;
  el.hidden = false;
  window.bounceError = text;
}

async function landing() {
  show('home');
  const list = document.getElementById('scenes');
  const answer = await listScenes();
  const needsToken = answer.writes_need_token === true;
  const tok = token();
  document.getElementById('engine').textContent = `engine: ${answer.engine}${needsToken ? ' · writes need a token' : ''}`;
  if (!answer.scenes.length) {
    list.textContent = 'No scenes: put baked files in the server\'s --scenes directory.';
    return;
  }
  list.replaceChildren();
  for (const s of answer.scenes) {
    const li = document.createElement('li');
    const title = document.createElement('h2');
    const open = document.createElement('a');
    open.href = `?scene=${encodeURIComponent(s.name)}`;
    open.title = 'open the newest session, or a new one';
    open.textContent = s.name;
    title.append(open);
    const facts = document.createElement('p');
    facts.textContent = `${s.patch_count} patches · ${s.codec}${s.has_model === false ? ' · no model kept: cannot be viewed here' : ''}`;
    const sessions = document.createElement('ul');
    sessions.className = 'sessions';
    const create = document.createElement('button');
    create.textContent = 'New session';
    create.disabled = s.has_model === false || (needsToken && !tok);
    if (needsToken && !tok) create.title = 'this server needs a write token: open the page with ?token=…';
    create.addEventListener('click', async () => {
      create.disabled = true;
      try {
        const made = await createSession(s.name, await startingLights(s), tok);
        location.search = `?scene=${encodeURIComponent(s.name)}&session=${encodeURIComponent(made.session_id)}`;
      } catch (e) {
        fail(`creating a session: ${e.message}`);
        create.disabled = false;
      }
    });
    li.append(title, facts, sessions, create);
    list.append(li);
    listSessions(s.name)
      .then((answer) => {
        for (const sess of answer.sessions) {
          const item = document.createElement('li');
          const a = document.createElement('a');
          a.href = `?scene=${encodeURIComponent(s.name)}&session=${encodeURIComponent(sess.session_id)}`;
          a.textContent = sess.session_id;
          item.append(a, ` · lights v${sess.lights_version}${sess.viewers !== undefined ? ` · ${sess.viewers} viewing` : ''}`);
          sessions.append(item);
        }
      })
      .catch((e) => {
        sessions.textContent = `sessions: ${e.message}`;
      });
  }
}

// A new session's lights: the scene's own (from its glTF), else a default light for its extent.
async function startingLights(s) {
  return s.lights?.length ? { lights: s.lights } : defaultLights(await layoutBounds(s.name));
}

// `?scene=NAME` alone: open the scene rather than the list. It joins the scene's newest session
// (the one someone most likely just made, or shared), and starts one when there is none. The
// address bar then names the session, so a reload or a copied link opens the same one; a write
// token leaves the address bar, as it does everywhere (see token()).
async function openScene(name) {
  const tok = token();
  const answer = await listScenes();
  const s = answer.scenes.find((x) => x.name === name);
  if (!s) {
    const names = answer.scenes.map((x) => x.name).join(', ') || 'none';
    throw new Error(`no scene "${name}" on this server (its scenes: ${names})`);
  }
  if (s.has_model === false) {
    throw new Error(`scene "${name}" was baked without its model (bounce bake --no-model), so this page cannot draw it`);
  }
  let id = (await listSessions(name, 1)).sessions[0]?.session_id;
  if (!id) {
    if (answer.writes_need_token === true && !tok) {
      throw new Error(`scene "${name}" has no session yet, and starting one needs this server's write token: open the page with &token=…`);
    }
    id = (await createSession(name, await startingLights(s), tok)).session_id;
  }
  params.delete('token');
  params.set('session', id);
  history.replaceState(null, '', `?${params}`);
  return view(name, id);
}

// The scene's extent from its layout (the voxel grid), for a default light.
async function layoutBounds(scene) {
  const l = await layoutOf(scene);
  const min = new Vector3().fromArray(l.origin);
  const max = min.clone().add(new Vector3().fromArray(l.dims).multiplyScalar(l.voxel_size));
  return new Bounds(new Box3(min, max));
}

// A positive number from the URL, or `fallback` where it is missing or not one.
function positive(name, fallback) {
  const v = Number(params.get(name));
  return params.has(name) && Number.isFinite(v) && v > 0 ? v : fallback;
}

async function view(scene, session) {
  show('view');
  document.title = `bounce · ${scene}`;
  const viewer = new Viewer(document.getElementById('view'), {
    scene,
    session,
    token: token(),
    readOnly: false,
    camera: camera(),
    exposure: Number(params.get('exposure') ?? 1) || 1,
    terms: params.get('terms') ?? 'both',
    xrScale: positive('xr_scale', 1),
    overlay: onOff('overlay', true),
    antialias: onOff('aa', true),
    markers: onOff('markers', true),
    object: onOff('object', true),
    ui: onOff('ui', true),
    preserve: onOff('preserve', false),
    pixelRatio: params.has('pixel_ratio') ? Number(params.get('pixel_ratio')) : undefined,
  });
  await viewer.start();
  return viewer;
}

async function main() {
  const scene = params.get('scene');
  const session = params.get('session');
  try {
    if (scene && session) {
      await view(scene, session);
    } else if (scene) {
      await openScene(scene);
    } else {
      await landing();
    }
  } catch (e) {
    let what = e instanceof ApiError && e.status === 404 ? `not found: ${e.message}` : e.message ?? String(e);
    if (e instanceof ApiError && e.status === 401) what += '. Open the page with ?token=… (the read or the write token).';
    fail(what);
    console.warn('bounce:', what);
  }
}

main();
