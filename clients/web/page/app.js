// app.js — the preview page: wires the controls to the daemon's API (protocol/API.md) and to
// the image view and the chart. The page follows a few sessions, each through its event stream
// (GET …/events): every new frame, whether this page or another client asked for it, updates
// the session's stats, its image when shown as A or B, and its MAPE point when a reference fits.
// Every failure ends up in #messages as the daemon's own words (title, detail, field).
import { ApiError, eventsUrl, getExrBytes, getJson, request, sendJson } from './api.js';
import { orbitAnimation, stillAnimation } from './animation.js';
import { MapeChart } from './chart.js';
import { decodeExr } from './exr.js';
import { describeParam, initialText, loadMethods, profileDefault } from './methods.js';
import { HdrViewer } from './viewer.js';

document.body.dataset.started = 'true'; // boot.js reports a page whose modules never ran

const $ = (id) => document.getElementById(id);
// Each followed session holds an event stream open, and browsers give a host six HTTP/1.1
// connections: four streams leave two for everything else.
const MAX_FOLLOWED = 4;
const MAX_MESSAGES = 6;
const METRICS_BACKLOG = 32;

const state = {
  sessions: new Map(), // id -> followed session (see follow())
  a: '',
  b: '', // a session id, 'reference' or ''
  reference: null, // {scene, name, width, height, spp, image}
  animJob: null, // {session, id}
  refJob: null, // {session, id, name}
  errorMapFor: '',
  pointer: null, // the image pixel last under the pointer
  methods: new Map(), // the daemon's method registry, by name (methods.js)
};
const viewer = new HdrViewer($('image'), $('split-line'));
const chart = new MapeChart($('chart'));

// ---- messages ----

function asProblem(err) {
  if (err instanceof ApiError) return err;
  return new ApiError({ status: 0, title: 'The page failed', detail: String(err?.message ?? err) });
}

function showProblem(context, err) {
  const p = asProblem(err);
  const box = document.createElement('div');
  box.className = 'problem';
  box.dataset.status = String(p.status);
  box.dataset.type = p.type;
  if (p.field !== undefined && p.field !== null) box.dataset.field = p.field;
  const close = document.createElement('button');
  close.type = 'button';
  close.textContent = '×';
  close.title = 'dismiss';
  close.addEventListener('click', () => box.remove());
  const title = document.createElement('strong');
  title.textContent = `${context}: ${p.title}${p.status ? ` (HTTP ${p.status})` : ''}`;
  box.append(close, title);
  if (p.detail) box.append(document.createTextNode(` — ${p.detail}`));
  if (p.field !== undefined && p.field !== null) {
    const field = document.createElement('code');
    field.textContent = p.field === '' ? '(the whole body)' : p.field;
    box.append(document.createTextNode(' at '), field);
  }
  if (p.limit !== undefined) box.append(document.createTextNode(` (limit ${p.limit})`));
  const list = $('messages');
  list.prepend(box);
  while (list.children.length > MAX_MESSAGES) list.lastElementChild.remove();
}

window.addEventListener('error', (e) => showProblem('Page', e.error ?? e.message));
window.addEventListener('unhandledrejection', (e) => showProblem('Page', e.reason));

// A button that runs `fn` and reports its failure; disabled while it runs so that a double
// click does not send the request twice.
function action(id, context, fn) {
  const button = $(id);
  button.addEventListener('click', async () => {
    button.disabled = true;
    try {
      await fn();
    } catch (err) {
      showProblem(context, err);
    } finally {
      button.disabled = false;
      updateControls();
    }
  });
}

// ---- form values ----

// What the user typed, as the daemon should see it: a number when it reads as one, the text
// otherwise (the daemon answers with the field at fault), nothing when empty (its default).
function typed(input) {
  const text = input.value.trim();
  if (text === '') return undefined;
  const n = Number(text);
  return Number.isFinite(n) ? n : text;
}

function withDefined(object) {
  return Object.fromEntries(Object.entries(object).filter(([, v]) => v !== undefined));
}

function sceneHref(scene) {
  return `/v1/scenes/${encodeURIComponent(scene)}`;
}

function setOptions(select, options, selected) {
  select.replaceChildren(
    ...options.map(([value, label]) => {
      const o = document.createElement('option');
      o.value = value;
      o.textContent = label;
      return o;
    }),
  );
  if (options.some(([value]) => value === selected)) select.value = selected;
}

// ---- sessions ----

function describe(info) {
  return `${info.id} (${info.method} ${info.width}×${info.height})`;
}

function sessionA() {
  const s = state.sessions.get(state.a);
  if (!s) throw new ApiError({ title: 'No session A', detail: 'create a session or follow one first' });
  return s;
}

async function follow(info) {
  const known = state.sessions.get(info.id);
  if (known) return known;
  if (state.sessions.size >= MAX_FOLLOWED)
    throw new ApiError({
      title: 'Too many sessions followed',
      detail: `the page follows at most ${MAX_FOLLOWED} sessions at once (one event stream each); delete or forget one first`,
    });
  const s = {
    id: info.id,
    info,
    href: info.href,
    lastFrame: -1,
    renderS: 0,
    stats: null,
    latestHref: '',
    image: null,
    imageHref: '',
    imageFrame: -1,
    loading: false,
    metricsQueue: [],
    metricsBusy: false,
    endedJobs: new Map(), // job id -> final status
  };
  if (info.frames_rendered > 0) {
    s.lastFrame = info.frames_rendered - 1;
    s.latestHref = `${info.href}/frames/${s.lastFrame}`;
  }
  state.sessions.set(s.id, s);
  addRow(s);
  s.events = openEvents(s);
  // A frame rendered before the stream is open would be missed: wait for it (briefly).
  await new Promise((resolve) => {
    s.events.addEventListener('open', resolve, { once: true });
    setTimeout(resolve, 3000);
  });
  return s;
}

function forget(s) {
  s.events.close();
  state.sessions.delete(s.id);
  chart.clear(s.id);
  document.querySelector(`#sessions tr[data-session="${CSS.escape(s.id)}"]`)?.remove();
  if (state.a === s.id) state.a = '';
  if (state.b === s.id) state.b = '';
  if (state.animJob?.session === s) state.animJob = null;
  updateSelectors();
  refreshView();
}

function addRow(s) {
  const row = document.createElement('tr');
  row.dataset.session = s.id;
  for (const text of [s.id, s.info.scene, s.info.method, `${s.info.width}×${s.info.height}`, '', '']) {
    const cell = document.createElement('td');
    cell.textContent = text;
    row.append(cell);
  }
  const cell = document.createElement('td');
  const del = document.createElement('button');
  del.type = 'button';
  del.textContent = 'delete';
  del.addEventListener('click', async () => {
    s.closing = true; // the daemon ends the stream: that is no failure to report
    try {
      await sendJson('DELETE', s.href);
    } catch (err) {
      if (err.status !== 404) {
        s.closing = false;
        return showProblem(`Delete session ${s.id}`, err);
      }
    }
    forget(s);
  });
  cell.append(del);
  row.append(cell);
  document.querySelector('#sessions tbody').append(row);
  updateRow(s);
}

function updateRow(s) {
  const row = document.querySelector(`#sessions tr[data-session="${CSS.escape(s.id)}"]`);
  if (!row) return;
  row.cells[4].textContent = String(s.lastFrame + 1);
  row.cells[5].textContent = s.renderS.toFixed(2);
}

function updateSelectors() {
  const sessions = [...state.sessions.values()].map((s) => [s.id, describe(s.info)]);
  if (!state.sessions.has(state.a)) state.a = sessions[0]?.[0] ?? '';
  setOptions($('session-a'), sessions, state.a);
  const bOptions = [['', '(none)'], ...sessions];
  if (state.reference) bOptions.push(['reference', `reference '${state.reference.name}'`]);
  if (!bOptions.some(([v]) => v === state.b)) state.b = '';
  setOptions($('session-b'), bOptions, state.b);
}

function formatRate(perS) {
  if (perS >= 1e9) return `${(perS / 1e9).toFixed(2)} G`;
  if (perS >= 1e6) return `${(perS / 1e6).toFixed(2)} M`;
  if (perS >= 1e3) return `${(perS / 1e3).toFixed(2)} k`;
  return perS.toFixed(0);
}

function showStats() {
  const out = $('frame-stats');
  const s = state.sessions.get(state.a);
  for (const key of ['frame', 'renderMs', 'raysPerS', 'session']) delete out.dataset[key];
  if (!s?.stats) {
    out.textContent = 'no frame yet';
    return;
  }
  const { frame, render_ms: ms, rays_per_s: rate } = s.stats;
  out.textContent = `frame ${frame} · ${ms.toFixed(1)} ms · ${formatRate(rate)}rays/s · ${s.renderS.toFixed(2)} s rendered`;
  Object.assign(out.dataset, { frame: String(frame), renderMs: String(ms), raysPerS: String(rate), session: s.id });
}

// ---- events and frames ----

function openEvents(s) {
  const events = new EventSource(eventsUrl(`${s.href}/events`));
  const parse = (handler) => (e) => handler(s, JSON.parse(e.data));
  events.addEventListener('frame', parse(onFrame));
  events.addEventListener('progress', parse(onProgress));
  events.addEventListener('done', parse(onDone));
  events.addEventListener('open', () => {
    s.streamLost = false;
  });
  // "error" is both the daemon's event (a job failed: data is a problem) and the stream's own
  // signal that the connection dropped (no data; the browser reconnects unless it is closed).
  events.addEventListener('error', (e) => {
    if (e.data) {
      onJobError(s, JSON.parse(e.data));
    } else if (s.closing) {
      events.close();
    } else if (events.readyState === EventSource.CLOSED) {
      showProblem(`Session ${s.id}`, new ApiError({ title: 'The event stream closed', detail: 'the session is gone or the daemon refused the stream' }));
    } else if (!s.streamLost) {
      s.streamLost = true;
      showProblem(`Session ${s.id}`, new ApiError({ title: 'The event stream dropped', detail: 'reconnecting; frames rendered meanwhile are fetched on the next event' }));
    }
  });
  return events;
}

function onFrame(s, ev) {
  if (ev.frame <= s.lastFrame) return; // already seen (the POST's answer and the stream both bring it)
  s.lastFrame = ev.frame;
  s.renderS += ev.render_ms / 1000;
  s.stats = ev;
  s.latestHref = ev.href;
  updateRow(s);
  if (s.id === state.a) showStats();
  if (s.id === state.a || s.id === state.b) loadImage(s);
  queueMetrics(s, ev.href, s.renderS, ev.frame);
}

function frameOf(href) {
  return Number(href.slice(href.lastIndexOf('/') + 1));
}

// Fetches the session's newest frame; frames that arrive meanwhile are skipped, not queued.
async function loadImage(s) {
  if (s.loading) return;
  s.loading = true;
  try {
    while (s.latestHref && s.latestHref !== s.imageHref) {
      const href = s.latestHref;
      try {
        s.image = await decodeExr(await getExrBytes(href));
        s.imageHref = href;
        s.imageFrame = frameOf(href);
      } catch (err) {
        if (err.status !== 410) throw err;
        s.imageHref = href; // evicted already: a newer frame is on its way
        continue;
      }
      refreshView();
    }
  } catch (err) {
    showProblem(`Frame of session ${s.id}`, err);
  } finally {
    s.loading = false;
  }
}

function referenceFits(s) {
  const r = state.reference;
  return r && r.scene === s.info.scene && r.width === s.info.width && r.height === s.info.height;
}

function queueMetrics(s, href, timeS, frame) {
  if (!referenceFits(s)) return;
  s.metricsQueue.push({ href, timeS, frame, reference: state.reference.name });
  if (s.metricsQueue.length > METRICS_BACKLOG) s.metricsQueue.splice(0, s.metricsQueue.length - METRICS_BACKLOG);
  drainMetrics(s);
}

// One request at a time per session, in frame order, so the chart's line never goes back.
async function drainMetrics(s) {
  if (s.metricsBusy) return;
  s.metricsBusy = true;
  try {
    while (s.metricsQueue.length) {
      const m = s.metricsQueue.shift();
      try {
        const metrics = await getJson(`${m.href}/metrics?reference=${encodeURIComponent(m.reference)}`);
        chart.add(s.id, describe(s.info), m.timeS, metrics.mape, m.frame);
      } catch (err) {
        if (err.status !== 410) throw err; // an evicted frame has no metrics any more: skip it
      }
    }
  } catch (err) {
    s.metricsQueue = [];
    showProblem(`Metrics of session ${s.id}`, err);
  } finally {
    s.metricsBusy = false;
  }
}

// ---- jobs ----

function setAnimStatus(status, job) {
  const out = $('anim-status');
  out.textContent = job ? `${job}: ${status}` : status;
  out.dataset.status = status;
  if (job) out.dataset.job = job;
  updateControls();
}

function onProgress(s, ev) {
  if (state.animJob?.session === s && state.animJob.id === ev.job) {
    const bar = $('anim-progress');
    bar.max = ev.frames_total;
    bar.value = ev.frames_done;
    setAnimStatus(`running, ${ev.frames_done}/${ev.frames_total} frames`, ev.job);
    $('anim-status').dataset.status = 'running';
  } else if (state.refJob?.session === s && state.refJob.id === ev.job) {
    setRefStatus('rendering', `'${state.refJob.name}': pass ${ev.frames_done} of ${ev.frames_total}`);
  }
}

// A job's end, from its "done" or "error" event. Recorded per session because a short job can
// end before the answer to the POST that started it has arrived; settleJobs() then finds it.
function onDone(s, ev) {
  s.endedJobs.set(ev.job, ev.status);
  settleJobs(s);
}

function onJobError(s, problem) {
  showProblem(`Job ${problem.job ?? ''} of session ${s.id}`, new ApiError(problem));
  onDone(s, { job: problem.job, status: 'failed' });
}

function settleJobs(s) {
  const anim = state.animJob;
  if (anim?.session === s && s.endedJobs.has(anim.id)) {
    state.animJob = null;
    setAnimStatus(s.endedJobs.get(anim.id), anim.id);
  }
  const ref = state.refJob;
  if (ref?.session === s && s.endedJobs.has(ref.id)) {
    state.refJob = null;
    const status = s.endedJobs.get(ref.id);
    if (status === 'done') useReference(s.info.scene, ref.name).catch((err) => showProblem('Reference', err));
    else setRefStatus(status, `'${ref.name}' ${status}`);
  }
}

function animationSettings() {
  return { frames: typed($('anim-frames')), fps: typed($('anim-fps')), degrees: Number(typed($('anim-degrees')) ?? 30) };
}

// The orbit preset starts where session A's camera is now.
async function orbitOf(s) {
  return orbitAnimation((await getJson(s.href)).camera, animationSettings());
}

async function animationRequest(s) {
  const preset = $('anim-preset').value;
  if (preset === 'keyframes') {
    try {
      return JSON.parse($('anim-keyframes').value);
    } catch (err) {
      throw new ApiError({ title: 'The keyframes are not JSON', detail: err.message });
    }
  }
  if (preset === 'orbit') return orbitOf(s);
  return withDefined(stillAnimation(animationSettings()));
}

// ---- references ----

function setRefStatus(stateName, text) {
  const out = $('ref-status');
  out.dataset.state = stateName;
  out.textContent = text;
}

async function useReference(scene, name) {
  const href = `${sceneHref(scene)}/references/${encodeURIComponent(name)}`;
  const info = await getJson(href);
  const image = await decodeExr(await getExrBytes(href));
  state.reference = { scene, name, width: info.width, height: info.height, spp: info.spp, image };
  state.errorMapFor = '';
  setRefStatus('ready', `'${name}' of ${scene}: ${info.width}×${info.height}, ${info.spp} spp`);
  $('ref-status').dataset.name = name;
  updateSelectors();
  refreshView();
}

// ---- the view ----

function currentB() {
  if (state.b === 'reference') return state.reference?.image ?? null;
  return state.sessions.get(state.b)?.image ?? null;
}

function refreshView() {
  const a = state.sessions.get(state.a);
  const b = state.sessions.get(state.b);
  const view = $('view');
  view.dataset.aFrame = a && a.imageFrame >= 0 ? String(a.imageFrame) : '';
  view.dataset.bFrame = b && b.imageFrame >= 0 ? String(b.imageFrame) : state.b === 'reference' ? 'reference' : '';
  viewer.set({ a: a?.image ?? null, b: currentB() });
  if (viewer.mode === 'error') loadErrorMap(a);
  showPixel(state.pointer);
}

// The daemon's false-colour map of A's shown frame against the reference (…/error.png), with
// the scale it used (X-Error-Scale: the 99th percentile of the errors).
async function loadErrorMap(a) {
  const legend = $('error-legend');
  legend.hidden = false;
  if (!a?.imageHref) return;
  if (!referenceFits(a)) {
    const key = `nofit:${a.id}`;
    if (state.errorMapFor !== key) {
      state.errorMapFor = key;
      viewer.set({ errorMap: null });
      showProblem('Error map', new ApiError({ title: 'No reference fits session A', detail: 'render or use a reference of the same scene and size first' }));
    }
    return;
  }
  const url = `${a.imageHref}/error.png?reference=${encodeURIComponent(state.reference.name)}`;
  if (state.errorMapFor === url) return;
  state.errorMapFor = url;
  try {
    const response = await request('GET', url, { accept: 'image/png' });
    const bitmap = await createImageBitmap(await response.blob());
    if (state.errorMapFor !== url) return; // a newer frame took over meanwhile
    const scale = Number(response.headers.get('X-Error-Scale'));
    $('error-scale').textContent = `≥ ${scale.toPrecision(3)}`;
    $('error-scale').dataset.scale = String(scale);
    viewer.set({ errorMap: bitmap });
  } catch (err) {
    if (err.status !== 410) showProblem('Error map', err);
  }
}

function formatRgb(v) {
  return v ? v.map((c) => (Number.isFinite(c) ? c.toPrecision(4) : String(c))).join(' ') : '–';
}

function showPixel(p) {
  const out = $('pixel');
  if (!p) return;
  const a = HdrViewer.value(viewer.a, p.x, p.y);
  const b = HdrViewer.value(viewer.b, p.x, p.y);
  out.textContent = `(${p.x}, ${p.y})  A ${formatRgb(a)}  B ${formatRgb(b)}`;
  Object.assign(out.dataset, { x: String(p.x), y: String(p.y), a: JSON.stringify(a), b: JSON.stringify(b) });
}

// ---- controls ----

function updateControls() {
  $('stop-animation').disabled = !state.animJob;
  const preset = $('anim-preset').value;
  $('anim-keyframes').hidden = preset !== 'keyframes';
  document.querySelector('.orbit-only').hidden = preset !== 'orbit';
  document.querySelector('.swipe-only').hidden = viewer.mode !== 'swipe';
  $('error-legend').hidden = viewer.mode !== 'error';
}

function buildParams() {
  const method = state.methods.get($('method').value);
  const profile = $('profile').value;
  $('method').title = method ? method.summary : '';
  const box = $('params');
  box.replaceChildren(
    ...(method ? method.params : []).map((p) => {
      const label = document.createElement('label');
      label.title = describeParam(p);
      const input = document.createElement('input');
      input.id = `param-${p.name}`;
      input.dataset.param = p.name;
      if (p.type === 'boolean') {
        input.type = 'checkbox';
        input.checked = profileDefault(p, profile);
      } else {
        input.type = 'text';
        if (p.type !== 'string') input.inputMode = 'numeric';
        input.size = p.type === 'string' ? 10 : 5;
        input.value = initialText(p, profile);
      }
      label.append(`${p.name} `, input);
      return label;
    }),
  );
}

function sessionRequest() {
  const params = {};
  for (const input of $('params').querySelectorAll('input')) {
    params[input.dataset.param] = input.type === 'checkbox' ? input.checked : typed(input);
  }
  return withDefined({
    method: $('method').value,
    profile: $('profile').value,
    width: typed($('width')),
    height: typed($('height')),
    seed: typed($('seed')),
    params: withDefined(params),
  });
}

// The sessions of the chosen scene, offered to follow.
function showExisting(sessions) {
  setOptions($('existing'), sessions.map((s) => [s.id, describe(s)]), '');
  $('existing').dataset.sessions = JSON.stringify(sessions);
}

// Asks for the chosen scene's sessions and offers them; returns them.
async function listExisting() {
  const scene = $('scene').value;
  if (!scene) return [];
  const { sessions } = await getJson(`${sceneHref(scene)}/sessions`);
  showExisting(sessions);
  return sessions;
}

async function showAsA(s) {
  const previous = state.a;
  state.a = s.id;
  if (previous && previous !== s.id) state.b = previous;
  updateSelectors();
  showStats();
  refreshView();
  await Promise.all([loadImage(s), state.sessions.has(state.b) ? loadImage(state.sessions.get(state.b)) : null]);
}

action('create-session', 'Create session', async () => {
  const info = await sendJson('POST', `${sceneHref($('scene').value)}/sessions`, sessionRequest());
  await showAsA(await follow(info));
  await listExisting();
});

// Follows the session chosen in the list of existing ones and shows it as A; returns it and
// what the list said of it.
async function followChosen() {
  const sessions = JSON.parse($('existing').dataset.sessions || '[]');
  const info = sessions.find((s) => s.id === $('existing').value);
  if (!info) throw new ApiError({ title: 'No session chosen', detail: 'the scene has no session to follow' });
  const s = await follow(info);
  await showAsA(s);
  return { s, info };
}

action('follow-session', 'Follow session', followChosen);

// The daemon's default session (`restird --default-session SCENE`, as `make run` starts it) is
// the one session whose id the daemon did not make up: "default". The page opens on it, with a
// first frame rendered if it has none yet, so a fresh `make run` shows its scene at once.
// `listed` is what listExisting() found for the scene chosen now; other scenes are asked.
async function showDefaultSession(scenes, listed) {
  for (const scene of scenes.filter((sc) => sc.sessions > 0)) {
    const chosen = scene.id === $('scene').value;
    const sessions = chosen ? listed : (await getJson(`${sceneHref(scene.id)}/sessions`)).sessions;
    if (!sessions.some((s) => s.id === 'default')) continue;
    if (!chosen) {
      $('scene').value = scene.id;
      showExisting(sessions);
    }
    $('existing').value = 'default';
    const { s, info } = await followChosen();
    if (info.frames_rendered > 0) return;
    try {
      onFrame(s, await sendJson('POST', `${s.href}/frames`, {}));
    } catch (err) {
      // Another page (a second tab on the same fresh daemon) is rendering the first frame: it
      // arrives on the event stream follow() opened.
      if (asProblem(err).status !== 409) throw err;
    }
    return;
  }
}

action('render-frame', 'Render a frame', async () => {
  const s = sessionA();
  onFrame(s, await sendJson('POST', `${s.href}/frames`, {}));
});

action('reset-session', 'Reset', async () => {
  const s = sessionA();
  await sendJson('POST', `${s.href}/reset`);
  Object.assign(s, { lastFrame: -1, renderS: 0, stats: null, metricsQueue: [] });
  chart.clear(s.id);
  updateRow(s);
  showStats();
});

action('start-animation', 'Start animation', async () => {
  const s = sessionA();
  const animation = await animationRequest(s);
  const job = await sendJson('POST', `${s.href}/renders`, { animation });
  state.animJob = { session: s, id: job.id };
  const bar = $('anim-progress');
  bar.max = job.progress.frames_total;
  bar.value = 0;
  setAnimStatus(job.status, job.id);
  settleJobs(s);
});

action('stop-animation', 'Stop animation', async () => {
  const job = state.animJob;
  if (!job) return;
  await sendJson('DELETE', `${job.session.href}/renders/${job.id}`);
  // The job's "done" event may have come before this answer: then it is over already.
  if (state.animJob === job) setAnimStatus('stopping', job.id);
});

action('render-reference', 'Render reference', async () => {
  const s = sessionA();
  const name = $('ref-name').value.trim();
  const body = withDefined({ spp: typed($('ref-spp')), method: $('ref-method').value });
  const job = await sendJson('POST', `${s.href}/references/${encodeURIComponent(name)}`, body);
  state.refJob = { session: s, id: job.id, name };
  setRefStatus('rendering', `'${name}': queued`);
  settleJobs(s);
});

action('use-reference', 'Use reference', async () => {
  const scene = state.sessions.get(state.a)?.info.scene ?? $('scene').value;
  await useReference(scene, $('ref-name').value.trim());
});

$('method').addEventListener('change', buildParams);
$('profile').addEventListener('change', buildParams);
$('scene').addEventListener('change', () => listExisting().catch((err) => showProblem('Sessions of the scene', err)));

$('session-a').addEventListener('change', () => {
  state.a = $('session-a').value;
  showStats();
  refreshView();
  const s = state.sessions.get(state.a);
  if (s) loadImage(s);
});

$('session-b').addEventListener('change', () => {
  state.b = $('session-b').value;
  refreshView();
  const s = state.sessions.get(state.b);
  if (s) loadImage(s);
});

$('anim-preset').addEventListener('change', async () => {
  updateControls();
  const area = $('anim-keyframes');
  if ($('anim-preset').value !== 'keyframes' || area.value.trim()) return;
  // Start the editor from the orbit preset of session A, or from a still run without one.
  try {
    const s = state.sessions.get(state.a);
    const animation = s ? await orbitOf(s) : withDefined(stillAnimation(animationSettings()));
    area.value = JSON.stringify(animation, null, 1);
  } catch (err) {
    showProblem('Keyframes', err);
  }
});

for (const radio of document.querySelectorAll('input[name="mode"]')) {
  radio.addEventListener('change', () => {
    viewer.mode = radio.value;
    $('view').dataset.mode = radio.value;
    updateControls();
    refreshView();
  });
}

$('exposure').addEventListener('input', () => {
  const ev = Number($('exposure').value);
  $('exposure-value').textContent = `${ev >= 0 ? '+' : ''}${ev.toFixed(1)} EV`;
  viewer.set({ exposure: ev });
});
$('tonemap').addEventListener('change', () => viewer.set({ curve: $('tonemap').value }));
$('zoom').addEventListener('change', () => {
  const zoom = $('zoom').value;
  viewer.set({ zoom: zoom === 'fit' ? 'fit' : Number(zoom) });
});
$('split').addEventListener('input', () => viewer.set({ split: Number($('split').value) }));

$('image').addEventListener('mousemove', (e) => {
  state.pointer = viewer.pixelAt(e);
  showPixel(state.pointer);
});

// ---- start ----

async function start() {
  $('view').dataset.mode = viewer.mode;
  updateControls();
  try {
    const health = await fetch('/healthz', { cache: 'no-store' });
    $('daemon').textContent = `daemon ${health.headers.get('X-Served-By') ?? ''}: ${health.ok ? 'ok' : health.status}`;
    $('daemon').dataset.state = health.ok ? 'ok' : 'down';
    state.methods = await loadMethods();
    // The registry's first method is the daemon's default.
    setOptions($('method'), [...state.methods.keys()].map((name) => [name, name]), state.methods.keys().next().value);
    buildParams();
    const { scenes } = await getJson('/v1/scenes');
    setOptions($('scene'), scenes.map((s) => [s.id, s.id]), 'cornell-box');
    const listed = await listExisting();
    await showDefaultSession(scenes, listed).catch((err) => showProblem('Default session', err));
  } catch (err) {
    $('daemon').textContent = 'daemon not reachable';
    $('daemon').dataset.state = 'down';
    showProblem('Start', err);
  }
  document.body.dataset.ready = 'true';
}

start();
