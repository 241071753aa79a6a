// The server's HTTP API (server/src/http.rs) as the page uses it. Every refusal becomes an
// ApiError carrying the server's `code` and `message`, so the page can say what went wrong.

export class ApiError extends Error {
  constructor(status, code, message) {
    super(message);
    this.status = status;
    this.code = code;
  }
}

async function request(method, path, { body, token } = {}) {
  const headers = {};
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  if (token) headers.Authorization = `Bearer ${token}`;
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
export const modelUrl = (scene) => `/v1/scenes/${seg(scene)}/model`;
// Newest first; `limit` (1 to 1000) keeps the first few.
export const listSessions = (scene, limit) =>
  json('GET', `/v1/sessions?scene=${seg(scene)}${limit ? `&limit=${limit}` : ''}`);
export const getSession = (id) => json('GET', `/v1/sessions/${seg(id)}`);
export const createSession = (scene, lights, token) =>
  json('POST', '/v1/sessions', { body: { scene, lights: lights.lights }, token });
export const putLights = (id, lights, token) =>
  json('PUT', `/v1/sessions/${seg(id)}/lights`, { body: { lights: lights.lights }, token });

export function socketUrl(id, token) {
  const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
  const query = token ? `?token=${seg(token)}` : '';
  return `${scheme}//${location.host}/v1/sessions/${seg(id)}/ws${query}`;
}
