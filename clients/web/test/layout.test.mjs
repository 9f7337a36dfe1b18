// The preview page's layout at common window sizes, and the session it opens on. The daemon is
// started as `make run` starts it, with a default session on cornell-box. Screenshots go to
// $WEB_TEST_OUT (build/web-test) as layout-WxH.png.
import assert from 'node:assert/strict';
import { mkdirSync, rmSync } from 'node:fs';
import path from 'node:path';
import { after, before, test } from 'node:test';
import { OUT, launchBrowser, startDaemon, stopDaemon } from '../harness.mjs';

const SIZES = [[1280, 800], [1920, 1080]];
const DEFAULT = '/v1/scenes/cornell-box/sessions/default';
let daemon;
let base;
let browser;

async function api(method, href, json) {
  const response = await fetch(base + href, {
    method,
    headers: json === undefined ? {} : { 'Content-Type': 'application/json' },
    body: json === undefined ? undefined : JSON.stringify(json),
  });
  assert.ok(response.ok, `${method} ${href}: ${response.status} ${await response.clone().text()}`);
  return response.json();
}

async function open([width, height]) {
  const page = await browser.newPage({ viewport: { width, height } });
  page.setDefaultTimeout(20000);
  await page.goto(`${base}/`);
  await page.waitForSelector('body[data-ready="true"]');
  return page;
}

before(async () => {
  mkdirSync(OUT, { recursive: true });
  daemon = await startDaemon({ logName: 'layout-daemon.log', args: ['--default-session', 'cornell-box'] });
  base = `http://127.0.0.1:${daemon.port}`;
  browser = await launchBrowser();
});

after(async () => {
  await browser?.close();
  if (daemon) {
    assert.equal(await stopDaemon(daemon), 0, 'the daemon stops cleanly');
    rmSync(daemon.dir, { recursive: true, force: true });
  }
});

test('on load the page follows the daemon\'s default session as A and shows its frame', async () => {
  assert.equal((await api('GET', DEFAULT)).frames_rendered, 0, 'a fresh default session has no frame');
  const page = await open(SIZES[0]);
  await page.waitForFunction(() => document.getElementById('image').dataset.shown === 'a');
  assert.equal(await page.$eval('#session-a', (s) => s.value), 'default');
  assert.equal(await page.$eval('#scene', (s) => s.value), 'cornell-box');
  assert.equal(await page.$eval('#existing', (s) => s.value), 'default');
  assert.equal(await page.$$eval('#sessions tbody tr', (rows) => rows.map((r) => r.dataset.session).join()), 'default');
  const canvas = await page.$eval('#image', (c) => {
    const px = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let sum = 0;
    for (let i = 0; i < px.length; i += 4) sum += px[i] + px[i + 1] + px[i + 2];
    return { width: c.width, height: c.height, mean: sum / (px.length * 0.75) };
  });
  assert.deepEqual([canvas.width, canvas.height], [256, 256], 'the default session\'s size');
  assert.ok(canvas.mean > 5, `the frame is not black (mean ${canvas.mean})`);
  assert.equal((await api('GET', DEFAULT)).frames_rendered, 1, 'the page rendered its first frame');
  await page.close();
});

test('a page whose first frame of the default session loses to another page\'s (409) shows that frame, and asks for the sessions once', async () => {
  const reset = await fetch(`${base}${DEFAULT}/reset`, { method: 'POST', headers: { 'Content-Type': 'application/json' } });
  assert.equal(reset.status, 204);
  assert.equal((await api('GET', DEFAULT)).frames_rendered, 0, 'no frame since the reset');
  const page = await browser.newPage({ viewport: { width: SIZES[0][0], height: SIZES[0][1] } });
  page.setDefaultTimeout(20000);
  const listings = [];
  page.on('request', (r) => {
    if (r.method() === 'GET' && new URL(r.url()).pathname === '/v1/scenes/cornell-box/sessions') listings.push(r.url());
  });
  // As two tabs opened at once on a fresh `make run`: the other one's frame is rendering when
  // this page asks, so this page gets the daemon's 409, and the other frame follows.
  let otherFrame;
  await page.route(`**${DEFAULT}/frames`, async (route) => {
    if (route.request().method() !== 'POST') return route.continue();
    await route.fulfill({
      status: 409,
      contentType: 'application/problem+json',
      body: JSON.stringify({ type: 'urn:restird:problem:conflict', title: 'Conflict', status: 409, detail: 'the session is rendering' }),
    });
    otherFrame = fetch(`${base}${DEFAULT}/frames`, {
      method: 'POST', headers: { 'Content-Type': 'application/json', Accept: 'application/json' }, body: '{}',
    }).then((r) => r.status);
  });
  await page.goto(`${base}/`);
  await page.waitForSelector('body[data-ready="true"]');
  await page.waitForFunction(() => document.getElementById('image').dataset.shown === 'a');
  assert.equal(await otherFrame, 200, 'the other page\'s frame');
  assert.deepEqual(await page.$$eval('.problem', (boxes) => boxes.map((b) => b.textContent)), [], 'no problem is shown');
  assert.equal(listings.length, 1, `the page lists the scene's sessions once: ${listings}`);
  await page.close();
});

// The fitted image against its area: the image's size on screen, the area's, the factor.
function fitOf(page) {
  return page.$eval('#canvas-wrap', (wrap) => {
    const c = document.getElementById('image');
    return {
      areaW: wrap.clientWidth, areaH: wrap.clientHeight, w: c.offsetWidth, h: c.offsetHeight,
      width: c.width, height: c.height, scale: Number(c.dataset.scale), rendering: getComputedStyle(c).imageRendering,
    };
  });
}

// 'fit' is the largest whole factor (below 1: the largest 1/n) at which the image fits its area.
function assertFitted(fit) {
  const what = JSON.stringify(fit);
  const factors = fit.scale >= 1 ? [fit.scale, fit.scale + 1] : [fit.scale, 1 / (1 / fit.scale - 1)];
  assert.ok(fit.scale >= 1 ? Number.isInteger(fit.scale) : Number.isInteger(1 / fit.scale), `a whole factor or 1/n: ${what}`);
  assert.deepEqual([fit.w, fit.h], [Math.floor(fit.width * fit.scale), Math.floor(fit.height * fit.scale)], what);
  assert.ok(fit.w <= fit.areaW && fit.h <= fit.areaH, `the image fits its area: ${what}`);
  assert.ok(fit.width * factors[1] > fit.areaW || fit.height * factors[1] > fit.areaH, `the next factor would not: ${what}`);
  assert.equal(fit.rendering, fit.scale >= 1 ? 'pixelated' : 'auto', `square pixels from 1× up, smoothed below: ${what}`);
}

test('zoom "fit" is the largest whole factor that fits the viewer\'s area, also after a resize; 1× and 2× are still there', async () => {
  const page = await open(SIZES[0]);
  await page.waitForFunction(() => document.getElementById('image').dataset.shown === 'a');
  assert.equal(await page.$eval('#zoom', (s) => s.value), 'fit');
  const fit = await fitOf(page);
  assertFitted(fit);
  assert.ok(fit.scale >= 2, `a 256×256 image at least doubles at ${SIZES[0].join('×')}: ${JSON.stringify(fit)}`);
  // A window too small for the image at 1×, then a larger one: the factor follows the area.
  await page.setViewportSize({ width: 800, height: 400 });
  await page.waitForFunction(() => document.getElementById('image').dataset.scale === '0.5');
  assertFitted(await fitOf(page));
  await page.setViewportSize({ width: SIZES[1][0], height: SIZES[1][1] });
  await page.waitForFunction((s) => Number(document.getElementById('image').dataset.scale) > s, fit.scale);
  assertFitted(await fitOf(page));
  for (const zoom of ['1', '2']) {
    await page.selectOption('#zoom', zoom);
    assert.equal(await page.$eval('#image', (c) => c.offsetWidth), 256 * Number(zoom));
  }
  await page.close();
});

// Every visible button, input, select and textarea, the error map's legend and the image's box
// (a zoomed image scrolls inside it, so it must not grow over the others): its box in page
// coordinates, and whether the element at the box's centre is the control (or inside it).
function layoutOf(page) {
  return page.evaluate(() => {
    const controls = [...document.querySelectorAll('button, input, select, textarea, #error-legend, #canvas-wrap')].filter(
      (el) => el.getClientRects().length > 0 && getComputedStyle(el).visibility !== 'hidden',
    );
    return controls.map((el) => {
      el.scrollIntoView({ block: 'center', inline: 'center' });
      const r = el.getBoundingClientRect();
      const hit = document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2);
      const name = el.id || `${el.tagName.toLowerCase()}[${el.name || el.textContent.trim()}]${el.value ? '=' + el.value : ''}`;
      return {
        name,
        x: r.left + scrollX, y: r.top + scrollY, w: r.width, h: r.height,
        own: hit !== null && (hit === el || el.contains(hit)),
        hit: hit ? hit.id || hit.tagName : null,
      };
    });
  });
}

// No sideways scrolling, and every box of layoutOf inside the page, clear of the others and
// taking its own clicks.
async function assertLaidOut(page, what) {
  const { scrollWidth, clientWidth, scrollHeight } = await page.evaluate(() => {
    const { scrollWidth, clientWidth, scrollHeight } = document.documentElement; // the window less its scroll bar
    return { scrollWidth, clientWidth, scrollHeight };
  });
  assert.ok(scrollWidth <= clientWidth, `${what}: no sideways scrolling: the page is ${scrollWidth} px wide, its window ${clientWidth}`);
  const boxes = await layoutOf(page);
  for (const name of ['error-legend', 'create-session', 'canvas-wrap'])
    assert.ok(boxes.some((b) => b.name === name), `${what}: ${name} is on show`);
  for (const b of boxes) {
    const box = JSON.stringify(b);
    assert.ok(b.w > 0 && b.h > 0, `${what}: ${b.name} has a box: ${box}`);
    assert.ok(b.x >= 0 && b.x + b.w <= clientWidth && b.y >= 0 && b.y + b.h <= scrollHeight,
      `${what}: ${b.name} lies inside the page (${clientWidth}×${scrollHeight}): ${box}`);
    assert.ok(b.own, `${what}: a click at the centre of ${b.name} reaches it, not ${b.hit}`);
  }
  for (let i = 0; i < boxes.length; i++) {
    for (let j = i + 1; j < boxes.length; j++) {
      const [a, b] = [boxes[i], boxes[j]];
      const overlapX = Math.min(a.x + a.w, b.x + b.w) - Math.max(a.x, b.x);
      const overlapY = Math.min(a.y + a.h, b.y + b.h) - Math.max(a.y, b.y);
      assert.ok(overlapX < 0.5 || overlapY < 0.5, `${what}: ${a.name} and ${b.name} overlap: ${JSON.stringify([a, b])}`);
    }
  }
}

for (const size of SIZES) {
  test(`at ${size[0]}×${size[1]}, fitted and at 32×, every visible control is inside the page, overlaps no other and takes its own clicks`, async () => {
    const page = await open(size);
    await page.waitForFunction(() => document.getElementById('image').dataset.shown === 'a');
    // Everything on show at once: a reference, the error map and its legend, the swipe's split.
    await page.fill('#ref-spp', '16');
    await page.click('#render-reference');
    await page.waitForFunction(() => document.getElementById('ref-status').dataset.state === 'ready');
    await page.check('input[name="mode"][value="error"]');
    await page.waitForFunction(() => document.getElementById('image').dataset.shown === 'error');
    await page.screenshot({ path: path.join(OUT, `layout-${size[0]}x${size[1]}.png`) });
    await page.screenshot({ path: path.join(OUT, `layout-${size[0]}x${size[1]}-full.png`), fullPage: true });
    await assertLaidOut(page, 'fit');
    // A 256×256 image at 32× is 8192 px square: it scrolls inside its box, which stays as it was.
    await page.selectOption('#zoom', '32');
    await page.waitForFunction(() => document.getElementById('image').offsetWidth === 256 * 32);
    await page.screenshot({ path: path.join(OUT, `layout-${size[0]}x${size[1]}-32x.png`), fullPage: true });
    await assertLaidOut(page, '32×');
    await page.close();
  });
}
