// The server's REST API as the viewer uses it: JSON reads, token-carrying writes, and errors
// that say what went wrong in words a user can act on.

export class ApiError extends Error {
  constructor(message, status = 0, code = '') {
    super(message);
    this.status = status;
    this.code = code;
  }
}

const TOKEN_KEY = 'raillomer.token';

export function savedToken() {
  try {
    return localStorage.getItem(TOKEN_KEY) || '';
  } catch {
    return '';
  }
}

export function saveToken(token) {
  try {
    if (token) localStorage.setItem(TOKEN_KEY, token);
    else localStorage.removeItem(TOKEN_KEY);
  } catch {
    // Private windows may refuse storage; the token then lasts the page.
  }
}

/** The error a refused answer names (`{"error": {"code", "message"}}`), as an ApiError. */
export async function errorOf(res) {
  let message = `${res.status} ${res.statusText}`;
  let code = '';
  try {
    const body = await res.json();
    if (body && body.error) {
      message = body.error.message || message;
      code = body.error.code || '';
    }
  } catch {
    // Not JSON: keep the status line.
  }
  if (res.status === 401) message = `the server refused the token: ${message}`;
  return new ApiError(message, res.status, code);
}

/** fetch that turns a network failure into "the server is unreachable". */
export async function request(path, options = {}) {
  let res;
  try {
    res = await fetch(path, options);
  } catch (e) {
    if (e.name === 'AbortError') throw e;
    throw new ApiError(`the server is unreachable (${path})`, 0, 'unreachable');
  }
  if (!res.ok && res.status !== 304) throw await errorOf(res);
  return res;
}

/** An answer index.html started fetching before the viewer loaded, taken once. */
function prefetched(path) {
  const pending = window.__raillomerPrefetch;
  const p = pending?.get(path);
  if (p) pending.delete(path);
  return p;
}

/** A GET's body as `as` ('json' or 'text'), from index.html's prefetch when it started one. */
async function read(path, as) {
  const early = prefetched(path);
  if (early) {
    try {
      return await early;
    } catch {
      // Ask again: the error then says what went wrong.
    }
  }
  return (await request(path))[as]();
}

export const getJson = (path) => read(path, 'json');
const getText = (path) => read(path, 'text');

/** A write with the ingest token (PATCH, POST, DELETE). */
export async function send(method, path, body, token) {
  const headers = {};
  if (token) headers.Authorization = `Bearer ${token}`;
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  const res = await request(path, {
    method,
    headers,
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const text = await res.text();
  return text ? JSON.parse(text) : null;
}

export const api = {
  info: () => getJson('/api/v1/info'),
  runs: () => getJson('/api/v1/runs').then((r) => r.runs),
  tiles: (run, level, bbox) =>
    getJson(`/api/v1/runs/${run}/tiles?level=${level}${bbox ? `&bbox=${bbox.join(',')}` : ''}`),
  trajectoryTum: (run) => getText(`/api/v1/runs/${run}/trajectory?format=tum`),
  trajectoryGeo: (run) => getJson(`/api/v1/runs/${run}/trajectory?format=geojson`),
  segment: (line, fromKm, toKm) =>
    getJson(
      `/api/v1/lines/${encodeURIComponent(line)}/segment?from_km=${fromKm}&to_km=${toKm}`,
    ),
  changes: (run) => getJson(`/api/v1/runs/${run}/changes`),
  registration: (run) => getJson(`/api/v1/runs/${run}/changes/registration`),
  pois: (line) => getJson(`/api/v1/pois?line=${encodeURIComponent(line)}`),
};
