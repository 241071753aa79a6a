// The server's HTTP API (server/src/http.rs) as the page uses it. Every refusal becomes an
// ApiError carrying the server's `code` and `message`, so the page can say what went wrong.

export class ApiError extends Error {
  constructor(status, code, message) {
    super(message);
    this.status = status;
    this.code = code;
  }
}

// The page's token (from its URL, see main.js): sent with every request, as a server with a
// read token (`serve --read-token`) wants it on reads too, and the write token also reads.
let pageToken = '';
export function useToken(t) {
  pageToken = t || '';
}

async function request(method, path, { body, token } = {}) {
  const headers = {};
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  const presented = token || pageToken;
  if (presented) headers.Authorization = `Bearer ${presented}`;
  let response;
  try {
    response = await fetch(path, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
  } catch (e) {
    throw new ApiError(0, 'unavailable', `the server cannot be reached (${e.message})`);
  }
  if (response.ok) {
    return response;
  }
  let code = 'internal';
  let message = `${method} ${path}: HTTP ${response.status}`;
  try {
    const e = await response.json();
    code = e.code ?? code;
    message = e.message ?? message;
  } catch {
    // Not our JSON (a proxy's page, say): the status says enough.
  }
  throw new ApiError(response.status, code, message);
}

const json = async (method, path, options) => (await request(method, path, options)).json();
const seg = encodeURIComponent;

export const listScenes = () => json('GET', '/v1/scenes');
export const layoutOf = (scene) => json('GET', `/v1/scenes/${seg(scene)}/layout`);
// The model goes to three.js's loader as a URL, so its token rides in the query.
export const modelUrl = (scene) =>
  `/v1/scenes/${seg(scene)}/model${pageToken ? `?token=${seg(pageToken)}` : ''}`;
// Newest first; `limit` (1 to 1000) keeps the first few.
export const listSessions = (scene, limit) =>
  json('GET', `/v1/sessions?scene=${seg(scene)}${limit ? `&limit=${limit}` : ''}`);
export const getSession = (id) => json('GET', `/v1/sessions/${seg(id)}`);
export const createSession = (scene, lights, token) =>
  json('POST', '/v1/sessions', { body: { scene, lights: lights.lights }, token });
export const putLights = (id, lights, token) =>
  json('PUT', `/v1/sessions/${seg(id)}/lights`, { body: { lights: lights.lights }, token });

// `probes`: ask for each patch frame's probe frame too (server/src/http/ws.rs).
export function socketUrl(id, token, { probes = false } = {}) {
  const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
  const presented = token || pageToken;
  const query = new URLSearchParams();
  if (presented) query.set('token', presented);
  if (probes) query.set('probes', '1');
  const q = query.toString();
  return `${scheme}//${location.host}/v1/sessions/${seg(id)}/ws${q ? `?${q}` : ''}`;
}
