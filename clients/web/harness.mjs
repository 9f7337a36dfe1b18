// What the browser tests share: the real daemon on an ephemeral loopback port, and Debian's
// chromium driven headless by playwright-core.
import { spawn } from 'node:child_process';
import { closeSync, mkdtempSync, openSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

export const ROOT = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
export const BIN = process.env.RESTIRD_BIN ?? path.join(ROOT, 'build/restird');
export const OUT = process.env.WEB_TEST_OUT ?? path.join(ROOT, 'build/web-test');
const CHROMIUM = process.env.CHROMIUM ?? '/usr/bin/chromium';

// Starts build/restird (or `bin`) on a fresh data directory with `args` added; resolves to
// {proc, port, dir} once it names its port. Its stderr goes to OUT/logName. One that does not
// name its port within startTimeoutMs is killed, and its data directory removed, before the
// promise rejects: a failed start leaves nothing running and no file open.
export function startDaemon({ logName = 'daemon.log', env = {}, args = [], bin = BIN, startTimeoutMs = 30000 } = {}) {
  const dir = mkdtempSync(path.join(tmpdir(), 'restird-web-'));
  const log = openSync(path.join(OUT, logName), 'w');
  let proc;
  try {
    proc = spawn(bin, ['--listen', '127.0.0.1:0', '--data-dir', dir, ...args], {
      stdio: ['ignore', 'pipe', log],
      env: { ...process.env, ...env },
    });
  } finally {
    closeSync(log); // the child has its own copy of it
  }
  return new Promise((resolve, reject) => {
    let text = '';
    let timedOut = false;
    const fail = (message) => {
      clearTimeout(timer);
      rmSync(dir, { recursive: true, force: true });
      reject(Object.assign(new Error(message), { pid: proc.pid }));
    };
    const timer = setTimeout(() => {
      timedOut = true;
      proc.kill('SIGKILL'); // rejected once it has exited, below
    }, startTimeoutMs);
    proc.stdout.on('data', (chunk) => {
      text += chunk;
      const m = /restird listening on http:\/\/127\.0\.0\.1:(\d+)/.exec(text);
      if (m) {
        clearTimeout(timer);
        resolve({ proc, port: Number(m[1]), dir });
      }
    });
    proc.on('error', (e) => fail(`${bin} did not start: ${e.message}`));
    proc.on('exit', (code) =>
      fail(timedOut ? `restird did not start within ${startTimeoutMs} ms: ${text}` : `restird exited with ${code}: ${text}`),
    );
  });
}

// SIGTERM, and the exit code once it has stopped.
export function stopDaemon(daemon) {
  const exited = new Promise((resolve) => daemon.proc.on('exit', (code) => resolve(code)));
  daemon.proc.kill('SIGTERM');
  return exited;
}

export function launchBrowser() {
  return chromium.launch({
    executablePath: CHROMIUM,
    args: ['--no-sandbox', '--disable-gpu', '--disable-background-networking'],
  });
}
