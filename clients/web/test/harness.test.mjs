// The harness itself: a daemon that never names its port is not left behind.
import assert from 'node:assert/strict';
import { chmodSync, mkdirSync, readdirSync, writeFileSync } from 'node:fs';
import path from 'node:path';
import { test } from 'node:test';
import { OUT, startDaemon } from '../harness.mjs';

test('a daemon that does not start in time is killed, and its log file is not left open', async () => {
  mkdirSync(OUT, { recursive: true });
  const silent = path.join(OUT, 'silent-daemon.sh');
  writeFileSync(silent, '#!/bin/sh\nexec sleep 60\n');
  chmodSync(silent, 0o755);
  const files = readdirSync('/proc/self/fd').length;
  const error = await startDaemon({ bin: silent, logName: 'silent.log', startTimeoutMs: 300 }).then(
    () => assert.fail('a daemon that prints nothing started'),
    (e) => e,
  );
  assert.match(error.message, /did not start within 300 ms/);
  assert.throws(() => process.kill(error.pid, 0), { code: 'ESRCH' }, 'the process is gone');
  assert.equal(readdirSync('/proc/self/fd').length, files, 'no file descriptor is left open');
});
