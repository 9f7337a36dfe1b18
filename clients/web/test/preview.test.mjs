// Browser tests of the preview page (the browser tier, tests/README.md): the real daemon on an
// ephemeral loopback port, Debian's chromium driven headless by playwright-core. Each step checks
// what the page shows against what the daemon says: canvas pixels before and after a change, the
// hovered float value against OpenImageIO's reading of the same EXR, the chart's last point against
// GET …/metrics, a 422's message against the daemon's problem. The steps share one page and run in
// order. Screenshots and the daemon's log go to $WEB_TEST_OUT (build/web-test, emptied by make).
import assert from 'node:assert/strict';
import { execFileSync } from 'node:child_process';
import { createHash } from 'node:crypto';
import { mkdirSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import path from 'node:path';
import { after, before, test } from 'node:test';
import * as harness from '../harness.mjs';
import { OUT, launchBrowser, stopDaemon } from '../harness.mjs';

const PYTHON = process.env.PYTHON ?? '/usr/bin/python3';
const SIDE = 64;

let daemon;
let base;
let dataDir;
let browser;
let page;
const consoleErrors = [];

function startDaemon(options) {
  return harness.startDaemon(options).then((d) => {
    if (!dataDir) dataDir = d.dir;
    return d;
  });
}

async function api(method, href, { json, accept = 'application/json' } = {}) {
  const headers = { Accept: accept };
  if (json !== undefined) headers['Content-Type'] = 'application/json';
  const response = await fetch(base + href, { method, headers, body: json === undefined ? undefined : JSON.stringify(json) });
  return response;
}

async function screenshot(name) {
  await page.screenshot({ path: path.join(OUT, `${name}.png`), fullPage: true });
}

// SHA-256 and mean of the canvas's RGBA bytes.
async function canvasState() {
  const bytes = await page.evaluate(() => {
    const c = document.getElementById('image');
    return Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data);
  });
  const hash = createHash('sha256').update(Uint8Array.from(bytes)).digest('hex');
  let sum = 0;
  for (let i = 0; i < bytes.length; i += 4) sum += bytes[i] + bytes[i + 1] + bytes[i + 2];
  return { hash, mean: sum / ((bytes.length / 4) * 3), bytes };
}

const dataset = (selector) => page.$eval(selector, (el) => ({ ...el.dataset }));
const waitData = (selector, key, value) =>
  page.waitForFunction(([s, k, v]) => document.querySelector(s)?.dataset[k] === v, [selector, key, value]);

// The pixel (x, y) of an EXR as OpenImageIO reads it: a reader independent of the page's.
function oiioPixel(exrPath, x, y) {
  const script = `
import json, sys
import OpenImageIO as oiio
inp = oiio.ImageInput.open(sys.argv[1])
px = inp.read_image(oiio.FLOAT)
inp.close()
x, y = int(sys.argv[2]), int(sys.argv[3])
print(json.dumps([float(v) for v in px[y, x, :3]]))`;
  return JSON.parse(execFileSync(PYTHON, ['-c', script, exrPath, String(x), String(y)], { encoding: 'utf8' }));
}

before(async () => {
  mkdirSync(OUT, { recursive: true });
  daemon = await startDaemon();
  base = `http://127.0.0.1:${daemon.port}`;
  browser = await launchBrowser();
  page = await browser.newPage({ viewport: { width: 1280, height: 1000 } });
  page.setDefaultTimeout(20000);
  page.on('console', (msg) => {
    // Chromium logs every non-2xx fetch as "Failed to load resource"; those are expected here.
    if (msg.type() === 'error' && !msg.text().startsWith('Failed to load resource')) consoleErrors.push(msg.text());
  });
  page.on('pageerror', (err) => consoleErrors.push(String(err)));
});

after(async () => {
  await browser?.close();
  if (daemon) {
    assert.equal(await stopDaemon(daemon), 0, 'the daemon stops cleanly');
  }
  if (dataDir) rmSync(dataDir, { recursive: true, force: true });
});

test('the daemon serves the page at / and the page lists the scenes', async () => {
  const response = await page.goto(`${base}/`);
  assert.equal(response.status(), 200);
  assert.match(response.headers()['content-type'], /^text\/html/);
  await page.waitForSelector('body[data-ready="true"]');
  assert.equal((await dataset('#daemon')).state, 'ok');
  const scenes = await page.$$eval('#scene option', (os) => os.map((o) => o.value));
  const listed = (await (await api('GET', '/v1/scenes')).json()).scenes.map((s) => s.id);
  assert.deepEqual(scenes, listed);
  assert.equal(await page.$eval('#scene', (s) => s.value), 'cornell-box');
  await screenshot('01-start');
});

// The form's fields for the method now selected: name -> value as the page shows it.
const formFields = (p = page) =>
  p.$$eval('#params input', (inputs) =>
    Object.fromEntries(inputs.map((i) => [i.dataset.param, i.type === 'checkbox' ? i.checked : i.value])),
  );

test('the session form is built from the daemon\'s method registry', async () => {
  const { methods } = await (await api('GET', '/v1/methods')).json();
  const offered = await page.$$eval('#method option', (os) => os.map((o) => o.value));
  assert.deepEqual(offered, methods.map((m) => m.name), 'every method, in the registry\'s order');
  for (const m of methods) {
    await page.selectOption('#method', m.name);
    const want = Object.fromEntries(
      m.params.map((p) => [p.name, p.type === 'boolean' ? p.default : p.default === null ? '' : String(p.default)]),
    );
    assert.deepEqual(await formFields(), want, m.name);
  }

  // The converge profile (in a page of its own, so this page's state stays as it was): the form
  // shows the registry's converge defaults, and the session made from it is a converge session
  // with them.
  const conv = await browser.newPage();
  await conv.goto(`${base}/`);
  await conv.waitForSelector('body[data-ready="true"]');
  await conv.selectOption('#method', 'restir_pt');
  await conv.selectOption('#profile', 'converge');
  const rpt = methods.find((m) => m.name === 'restir_pt');
  const converge = Object.fromEntries(rpt.params.map((p) => {
    const v = p.converge_default !== undefined ? p.converge_default : p.default;
    return [p.name, p.type === 'boolean' ? v : v === null ? '' : String(v)];
  }));
  assert.equal(converge.temporal, false, 'restir_pt\'s converge profile turns temporal reuse off');
  assert.deepEqual(await formFields(conv), converge);
  await conv.fill('#width', '8');
  await conv.fill('#height', '8');
  await conv.click('#create-session');
  await conv.waitForFunction(() => document.getElementById('session-a').value !== '');
  const madeId = await conv.$eval('#session-a', (s) => s.value);
  await conv.close();
  const made = await (await api('GET', `/v1/scenes/cornell-box/sessions/${madeId}`)).json();
  assert.equal(made.profile, 'converge');
  assert.equal(made.params.temporal, false);
  assert.equal(made.params.spatial_rounds, rpt.params.find((p) => p.name === 'spatial_rounds').converge_default);
  await api('DELETE', made.href);
  await page.selectOption('#method', 'pt');

  // A parameter the registry gains appears in the form with no change to the page.
  const other = await browser.newPage();
  await other.route('**/v1/methods', async (route) => {
    const body = await (await route.fetch()).json();
    body.methods.find((m) => m.name === 'restir_pt').params.push(
      { name: 'extra_knob', type: 'integer', default: 7, minimum: 0, maximum: 9, help: 'a parameter added to the descriptor' });
    await route.fulfill({ json: body });
  });
  await other.goto(`${base}/`);
  await other.waitForSelector('body[data-ready="true"]');
  await other.selectOption('#method', 'restir_pt');
  assert.equal(await other.$eval('#param-extra_knob', (i) => i.value), '7');
  assert.match(await other.$eval('#param-extra_knob', (i) => i.parentElement.title), /added to the descriptor — \[0, 9\]/);
  await other.close();
});

let first; // the first session: {id, href}
let firstLook; // its canvas after the exposure change

test('a new session renders frames and each frame updates the image and the stats', async () => {
  await page.fill('#width', String(SIDE));
  await page.fill('#height', String(SIDE));
  await page.click('#create-session');
  await page.waitForFunction(() => document.getElementById('session-a').value !== '');
  const id = await page.$eval('#session-a', (s) => s.value);
  first = { id, href: `/v1/scenes/cornell-box/sessions/${id}` };

  await page.click('#render-frame');
  await waitData('#view', 'aFrame', '0');
  const frame0 = await canvasState();
  await page.click('#render-frame');
  await waitData('#view', 'aFrame', '1');
  const frame1 = await canvasState();
  assert.notEqual(frame1.hash, frame0.hash, 'a new frame (new noise) changes the pixels');
  assert.ok(frame1.mean > 5, 'the image is not black');

  const stats = await dataset('#frame-stats');
  assert.equal(stats.frame, '1');
  assert.ok(Number(stats.renderMs) > 0);
  assert.ok(Number(stats.raysPerS) > 0);
  assert.match(await page.textContent('#frame-stats'), /frame 1 · [\d.]+ ms · [\d.]+ [kMG]?rays\/s/);
  const session = await (await api('GET', first.href)).json();
  assert.equal(session.frames_rendered, 2);
  assert.equal(session.width, SIDE);
  await screenshot('02-frames');
});

// Moves the pointer to the centre of image pixel (x, y) at the zoom on show, and returns what
// the readout says.
async function hover(x, y) {
  const box = await page.locator('#image').boundingBox();
  const scale = box.width / SIDE;
  await page.mouse.move(box.x + (x + 0.5) * scale, box.y + (y + 0.5) * scale);
  await page.waitForFunction(([px, py]) => {
    const { x: sx, y: sy } = document.getElementById('pixel').dataset;
    return sx === String(px) && sy === String(py);
  }, [x, y]);
  return dataset('#pixel');
}

test('hovering shows the float value the daemon sent, at 8× and at fit', async () => {
  const exr = Buffer.from(await (await api('GET', `${first.href}/frames/1`, { accept: 'image/x-exr' })).arrayBuffer());
  const exrPath = path.join(OUT, 'frame1.exr');
  writeFileSync(exrPath, exr);

  await page.selectOption('#zoom', '8');
  const box = await page.locator('#image').boundingBox();
  assert.equal(Math.round(box.width), SIDE * 8, 'zoom 8 makes one image pixel 8 screen pixels wide');
  assert.deepEqual(JSON.parse((await hover(21, 37)).a), oiioPixel(exrPath, 21, 37));

  await page.selectOption('#zoom', 'fit');
  const fit = Number((await dataset('#image')).scale);
  assert.ok(fit > 1 && fit !== 8, `fit is another zoom here (${fit})`);
  assert.deepEqual(JSON.parse((await hover(50, 9)).a), oiioPixel(exrPath, 50, 9));
});

// The daemon's PNG preview of the same frame, decoded by the browser, as RGBA bytes.
async function daemonPreview(href, exposure, tonemap) {
  return page.evaluate(async (url) => {
    const response = await fetch(url, { headers: { Accept: 'image/png' } });
    const bitmap = await createImageBitmap(await response.blob());
    const canvas = new OffscreenCanvas(bitmap.width, bitmap.height);
    const ctx = canvas.getContext('2d');
    ctx.drawImage(bitmap, 0, 0);
    return Array.from(ctx.getImageData(0, 0, bitmap.width, bitmap.height).data);
  }, `${href}?exposure=${exposure}&tonemap=${tonemap}`);
}

function maxDifference(a, b) {
  assert.equal(a.length, b.length);
  let max = 0;
  for (let i = 0; i < a.length; i++) max = Math.max(max, Math.abs(a[i] - b[i]));
  return max;
}

test('exposure and the tone curve change the pixels as the daemon previews them', async () => {
  const before0 = await canvasState();
  await page.locator('#exposure').fill('2');
  await page.waitForFunction(() => document.getElementById('exposure-value').textContent === '+2.0 EV');
  const brighter = await canvasState();
  assert.notEqual(brighter.hash, before0.hash);
  assert.ok(brighter.mean > before0.mean + 10, `+2 EV brightens the image (${before0.mean} -> ${brighter.mean})`);
  // The page tone-maps in the browser; it must agree with the daemon's own preview of the
  // frame to within one 8-bit step (rounding of the sRGB encoding).
  assert.ok(maxDifference(brighter.bytes, await daemonPreview(`${first.href}/frames/1`, 2, 'clamp')) <= 1);
  await page.selectOption('#tonemap', 'aces');
  const aces = await canvasState();
  assert.notEqual(aces.hash, brighter.hash);
  assert.ok(maxDifference(aces.bytes, await daemonPreview(`${first.href}/frames/1`, 2, 'aces')) <= 1);
  await page.selectOption('#tonemap', 'clamp');
  firstLook = await canvasState();
  assert.equal(firstLook.hash, brighter.hash, 'back to clamp, back to the same pixels');
  await screenshot('03-exposure');
});

let second;
let secondLook;

test('A/B: a second session becomes A, the first B; the toggle and the swipe show either', async () => {
  await page.fill('#seed', '1');
  await page.click('#create-session');
  await page.waitForFunction((old) => document.getElementById('session-a').value !== old, first.id);
  const id = await page.$eval('#session-a', (s) => s.value);
  second = { id, href: `/v1/scenes/cornell-box/sessions/${id}` };
  assert.equal(await page.$eval('#session-b', (s) => s.value), first.id);
  await page.click('#render-frame');
  await waitData('#view', 'aFrame', '0');
  secondLook = await canvasState();
  assert.notEqual(secondLook.hash, firstLook.hash, 'another seed, another image');

  await page.check('input[name="mode"][value="b"]');
  await waitData('#image', 'shown', 'b');
  assert.equal((await canvasState()).hash, firstLook.hash, 'B shows the first session at the same exposure');
  await screenshot('04-b');
  await page.check('input[name="mode"][value="a"]');
  await waitData('#image', 'shown', 'a');
  assert.equal((await canvasState()).hash, secondLook.hash, 'A again');
  await page.check('input[name="mode"][value="swipe"]');
  await waitData('#image', 'shown', 'swipe');
  const swipe = await canvasState();
  assert.notEqual(swipe.hash, secondLook.hash);
  assert.notEqual(swipe.hash, firstLook.hash);
  // Left of the split is A's, right of it B's: compare one pixel row byte for byte.
  const row = 10 * SIDE * 4;
  assert.deepEqual(swipe.bytes.slice(row, row + 4), secondLook.bytes.slice(row, row + 4));
  const right = row + (SIDE - 1) * 4;
  assert.deepEqual(swipe.bytes.slice(right, right + 4), firstLook.bytes.slice(right, right + 4));
  await screenshot('05-swipe');
  await page.check('input[name="mode"][value="a"]');
});

test('a reference: MAPE chart points equal the daemon metrics; error map and its scale; B = reference', async () => {
  await page.fill('#ref-spp', '32');
  await page.selectOption('#ref-method', 'sms');
  await page.click('#render-reference');
  await waitData('#ref-status', 'state', 'ready');
  assert.equal((await dataset('#ref-status')).name, 'ref');
  const refInfo = await (await api('GET', '/v1/scenes/cornell-box/references/ref')).json();
  assert.equal(refInfo.method, 'sms', 'the page sends the chosen reference method');
  assert.equal(refInfo.spp, 32);

  await page.click('#render-frame');
  await waitData('#view', 'aFrame', '1');
  await page.click('#render-frame');
  await waitData('#view', 'aFrame', '2');
  await waitData('#chart', 'lastFrame', '2');
  const chart = await dataset('#chart');
  assert.equal(chart.lastSession, second.id);
  const metrics = await (await api('GET', `${second.href}/frames/2/metrics?reference=ref`)).json();
  assert.equal(Number(chart.lastMape), metrics.mape, 'the chart shows the daemon MAPE of the last frame');
  assert.equal(chart.points, '2', 'one point per frame rendered since the reference');
  assert.ok(await page.$('#chart .uplot canvas'), 'uPlot drew the chart');

  await page.check('input[name="mode"][value="error"]');
  await waitData('#image', 'shown', 'error');
  const daemonMap = await api('GET', `${second.href}/frames/2/error.png?reference=ref`, { accept: 'image/png' });
  await page.waitForFunction(() => document.getElementById('error-scale').dataset.scale);
  assert.equal(Number((await dataset('#error-scale')).scale), Number(daemonMap.headers.get('X-Error-Scale')));
  assert.equal(await page.isVisible('#error-legend'), true);
  await screenshot('06-error-map');

  await page.selectOption('#session-b', 'reference');
  await page.check('input[name="mode"][value="b"]');
  await waitData('#image', 'shown', 'b');
  assert.equal(await page.isVisible('#error-legend'), false, 'the legend goes with the error map');
  const reference = await canvasState();
  assert.notEqual(reference.hash, secondLook.hash);
  await screenshot('07-reference');
  await page.check('input[name="mode"][value="a"]');
});

test('animations: an orbit runs to done with live frames; a long one stops on Stop', async () => {
  await page.selectOption('#anim-preset', 'orbit');
  await page.fill('#anim-frames', '4');
  await page.fill('#anim-fps', '4');
  await page.click('#start-animation');
  await waitData('#anim-status', 'status', 'done');
  await waitData('#frame-stats', 'frame', '6');
  await waitData('#view', 'aFrame', '6');
  const job = (await dataset('#anim-status')).job;
  const done = await (await api('GET', `${second.href}/renders/${job}`)).json();
  assert.equal(done.status, 'done');
  assert.equal(done.progress.frames_done, 4);
  const session = await (await api('GET', second.href)).json();
  assert.notDeepEqual(session.camera.position, [278, 273, -800], 'the orbit moved the camera');
  await screenshot('08-orbit');

  // The keyframe editor starts from the orbit of A's camera as it is now.
  await page.selectOption('#anim-preset', 'keyframes');
  await page.waitForFunction(() => document.getElementById('anim-keyframes').value !== '');
  const keyframes = JSON.parse(await page.inputValue('#anim-keyframes'));
  assert.equal(keyframes.frames, 4);
  assert.deepEqual(keyframes.camera_keys[0].position, session.camera.position);

  await page.selectOption('#anim-preset', 'still');
  await page.fill('#anim-frames', '10000');
  await page.click('#start-animation');
  await waitData('#anim-status', 'status', 'running');
  await page.click('#stop-animation');
  await waitData('#anim-status', 'status', 'cancelled');
  const stopped = (await dataset('#anim-status')).job;
  const cancelled = await (await api('GET', `${second.href}/renders/${stopped}`)).json();
  assert.equal(cancelled.status, 'cancelled');
  assert.ok(cancelled.progress.frames_done < 10000);
});

test('a 422 from the daemon is shown as its title, detail and field', async () => {
  await page.fill('#width', '0');
  await page.click('#create-session');
  const message = page.locator('#messages .problem[data-status="422"]').first();
  await message.waitFor();
  const text = await message.textContent();
  const problem = await (
    await api('POST', '/v1/scenes/cornell-box/sessions', { json: { method: 'pt', width: 0, height: SIDE, seed: 1, params: { spp: 1, max_depth: 64, rr_depth: 3, nee: true } } })
  ).json();
  assert.equal(problem.status, 422);
  assert.ok(text.includes(problem.title), text);
  assert.ok(text.includes(problem.detail), text);
  assert.equal(await message.getAttribute('data-field'), '/width');
  assert.equal(await message.locator('code').textContent(), '/width');
  assert.equal(await page.isVisible('#image'), true, 'the page is still there');
  await screenshot('09-problem');
  await page.fill('#width', String(SIDE));
});

test('deleting a session ends it on the daemon and in the page, with no error shown', async () => {
  const messages = await page.locator('#messages .problem').count();
  await page.click(`#sessions tr[data-session="${first.id}"] button`);
  await page.waitForSelector(`#sessions tr[data-session="${first.id}"]`, { state: 'detached' });
  assert.equal((await api('GET', first.href)).status, 404);
  assert.notEqual(await page.$eval('#session-b', (s) => s.value), first.id);
  // The daemon ends the session's event stream; the page must not report that as a failure.
  // Only a short wait can show that nothing arrives.
  await page.waitForTimeout(500);
  assert.equal(await page.locator('#messages .problem').count(), messages);
});

test('a page whose scripts cannot load says so', async () => {
  const broken = await browser.newPage();
  try {
    await broken.route('**/ui/uPlot.esm.js', (route) => route.abort());
    await broken.goto(`${base}/`);
    const message = broken.locator('#messages .problem');
    await message.waitFor();
    assert.match(await message.textContent(), /The page did not start/);
  } finally {
    await broken.close();
  }
});

test('a daemon with a token: the page takes it from its address, keeps it out of it, and sends it', async () => {
  const token = 'web-test-token-0123456789abcdef';
  const guarded = await startDaemon({ logName: 'guarded.log', env: { RESTIRD_AUTH_TOKEN: token } });
  const gbase = `http://127.0.0.1:${guarded.port}`;
  const p = await browser.newPage({ viewport: { width: 1280, height: 1000 } });
  p.setDefaultTimeout(20000);
  try {
    assert.equal((await fetch(`${gbase}/v1/scenes`)).status, 401, 'the daemon wants the token');
    await p.goto(`${gbase}/#token=${token}`);
    await p.waitForSelector('body[data-ready="true"]');
    assert.equal(await p.$eval('#daemon', (el) => el.dataset.state), 'ok');
    assert.equal(new URL(p.url()).hash, '', 'the token left the address bar');
    assert.ok((await p.$$eval('#scene option', (os) => os.length)) > 0, 'the scenes were listed with the token');
    await p.fill('#width', '16');
    await p.fill('#height', '16');
    await p.click('#create-session');
    await p.waitForFunction(() => document.getElementById('session-a').value !== '');
    await p.click('#render-frame');
    await p.waitForFunction(() => document.querySelector('#view')?.dataset.aFrame === '0');
    await p.reload();   // the token is kept for the tab
    await p.waitForSelector('body[data-ready="true"]');
    assert.equal(await p.$eval('#daemon', (el) => el.dataset.state), 'ok');
  } finally {
    await p.close();
    assert.equal(await stopDaemon(guarded), 0, 'the guarded daemon stops cleanly');
    rmSync(guarded.dir, { recursive: true, force: true });
  }
  // The event stream went with the token in its query (EventSource sends no headers).
  const log = readFileSync(path.join(OUT, 'guarded.log'), 'utf8');
  assert.match(log, / GET \/v1\/scenes\/cornell-box\/sessions\/[^ ]+\/events 200 /);
  assert.doesNotMatch(log, /\/events 401 /);
});

test('the page logged no errors of its own', () => {
  assert.deepEqual(consoleErrors, []);
});
