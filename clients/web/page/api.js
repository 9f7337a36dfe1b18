// api.js — the page's only door to the daemon (protocol/API.md). Every failure becomes an
// ApiError carrying the daemon's problem+json members (status, type, title, detail, field), so
// the page can always say what went wrong; a daemon that does not answer becomes one too.

export class ApiError extends Error {
  constructor(problem) {
    super(problem.detail || problem.title || `HTTP ${problem.status}`);
    this.status = problem.status ?? 0;
    this.type = problem.type ?? '';
    this.title = problem.title ?? 'Request failed';
    this.detail = problem.detail ?? '';
    this.field = problem.field;
    this.limit = problem.limit;
    this.instance = problem.instance;
  }
}

async function problemOf(response) {
  const text = await response.text();
  const type = response.headers.get('Content-Type') || '';
  if (type.startsWith('application/problem+json') || type.startsWith('application/json')) {
    try {
      return new ApiError({ status: response.status, ...JSON.parse(text) });
    } catch {
      // not JSON after all: fall through to the plain text
    }
  }
  return new ApiError({
    status: response.status,
    title: response.statusText || `HTTP ${response.status}`,
    detail: text.slice(0, 300),
  });
}

// The daemon's bearer token, when it has one (docs/deploy.md): given once in the page's address
// as #token=..., it is kept for this tab (sessionStorage) and taken out of the address bar.
const TOKEN_KEY = 'restird.token';
function takeTokenFromAddress() {
  const m = /(?:^#|&)token=([^&]+)/.exec(window.location.hash);
  if (!m) return;
  try {
    window.sessionStorage.setItem(TOKEN_KEY, decodeURIComponent(m[1]));
  } catch {
    // storage refused (private mode): the token is not kept
  }
  window.history.replaceState(null, '', window.location.pathname + window.location.search);
}
takeTokenFromAddress();

export function authToken() {
  try {
    return window.sessionStorage.getItem(TOKEN_KEY) || '';
  } catch {
    return '';
  }
}

// An event stream's address: EventSource cannot send headers, so the token goes as the
// access_token query parameter (which the daemon accepts on event streams only).
export function eventsUrl(path) {
  const token = authToken();
  return token ? `${path}?access_token=${encodeURIComponent(token)}` : path;
}

// fetch() with the daemon's error contract; resolves to the Response when it is 2xx.
export async function request(method, path, { json, accept } = {}) {
  const headers = {};
  if (accept) headers.Accept = accept;
  const token = authToken();
  if (token) headers.Authorization = `Bearer ${token}`;
  let body;
  if (json !== undefined) {
    headers['Content-Type'] = 'application/json';
    body = JSON.stringify(json);
  } else if (method === 'POST' || method === 'PUT') {
    // The daemon requires the declared type of every body route, an empty body included.
    headers['Content-Type'] = 'application/json';
    body = '';
  }
  let response;
  try {
    response = await fetch(path, { method, headers, body, cache: 'no-store' });
  } catch (err) {
    throw new ApiError({ status: 0, title: 'The daemon does not answer', detail: `${method} ${path}: ${err.message}` });
  }
  if (!response.ok) throw await problemOf(response);
  return response;
}

export async function getJson(path) {
  return (await request('GET', path, { accept: 'application/json' })).json();
}

export async function sendJson(method, path, json) {
  const response = await request(method, path, { json, accept: 'application/json' });
  return response.status === 204 ? null : response.json();
}

export async function getExrBytes(path) {
  return (await request('GET', path, { accept: 'image/x-exr' })).arrayBuffer();
}
