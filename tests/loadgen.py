"""Load on a running daemon, loopback only: wrk runs and frame storms across several sessions,
with the daemon's resident memory sampled as they go. Used by the short load tests
(test_load.py, in make test) and by the long form (bench/load.py, make load), so both measure
the same way. Stdlib only; wrk comes from Debian (scripts/install-deps.sh)."""
import collections
import http.client
import json
import os
import re
import shutil
import statistics
import subprocess
import tempfile
import threading
import time

# One session per wrk thread (wrk -tN -cN: one connection each), so a session never gets a
# second frame while one renders; every status is counted, not only the errors wrk reports.
WRK_FRAMES_LUA = r"""
local counter, threads = 0, {}
function setup(thread)
  counter = counter + 1
  thread:set("id", counter)
  table.insert(threads, thread)
end
function init(args)
  path = args[id]
  statuses = {}
end
function request()
  return wrk.format("POST", path, {["Accept"] = "application/json", ["Content-Type"] = "application/json",
                                   ["Content-Length"] = "0"})
end
function response(status, headers, body)
  statuses[status] = (statuses[status] or 0) + 1
end
function done(summary, latency, requests)
  for _, t in ipairs(threads) do
    for k, v in pairs(t:get("statuses")) do io.write(string.format("status %d %d\n", k, v)) end
  end
end
"""


def rss_kib(pid):
    """Resident set size of a process in KiB (VmRSS)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for {pid}")


def _unit(value, unit, table):
    return float(value) * table[unit]


def wrk(port, path, seconds, connections, threads=2, lua=None, args=()):
    """Runs wrk against 127.0.0.1:port/path; returns requests, req/s, p50/p99 latency (ms), the
    non-2xx/3xx count, socket errors and, with the frames script, the count of each status."""
    exe = shutil.which("wrk")
    if exe is None:
        raise RuntimeError("wrk is not installed (scripts/install-deps.sh installs it)")
    cmd = [exe, f"-t{threads}", f"-c{connections}", f"-d{seconds}s", "--latency", "--timeout", "30s"]
    script = None
    if lua:
        script = tempfile.NamedTemporaryFile("w", suffix=".lua", delete=False)
        script.write(lua)
        script.close()
        cmd += ["-s", script.name]
    cmd.append(f"http://127.0.0.1:{port}{path}")
    if args:
        cmd += ["--", *args]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=seconds + 60).stdout
    finally:
        if script:
            os.unlink(script.name)
    ms = {"us": 1e-3, "ms": 1.0, "s": 1e3, "m": 6e4}
    res = {"cmd": " ".join(cmd[:-1] if not args else cmd), "output": out}
    m = re.search(r"(\d+) requests in ([0-9.]+)(\w+)", out)
    res["requests"] = int(m.group(1)) if m else 0
    m = re.search(r"Requests/sec:\s+([0-9.]+)", out)
    res["rps"] = float(m.group(1)) if m else 0.0
    for p in ("50", "99"):
        m = re.search(rf"^\s+{p}%\s+([0-9.]+)(us|ms|s|m)\s*$", out, re.M)
        res[f"p{p}_ms"] = round(_unit(m.group(1), m.group(2), ms), 3) if m else None
    m = re.search(r"Non-2xx or 3xx responses: (\d+)", out)
    res["non_2xx"] = int(m.group(1)) if m else 0
    m = re.search(r"Socket errors: connect (\d+), read (\d+), write (\d+), timeout (\d+)", out)
    res["socket_errors"] = sum(int(x) for x in m.groups()) if m else 0
    statuses = collections.Counter()
    for k, v in re.findall(r"^status (\d+) (\d+)$", out, re.M):  # one line per thread and status
        statuses[int(k)] += int(v)
    res["statuses"] = dict(statuses)
    return res


def request(conn, method, path, body=None, headers=None):
    hdrs = dict(headers or {})
    data = None
    if body is not None:
        data = json.dumps(body).encode()
    if body is not None or method in ("POST", "PUT"):
        hdrs["Content-Type"] = "application/json"   # an empty body declares its type too
    conn.request(method, path, body=data, headers=hdrs)
    r = conn.getresponse()
    return r.status, r.headers, r.read()


def new_sessions(port, count, width=8, height=8, spp=1, scene="cornell-box"):
    """Creates `count` sessions; returns their hrefs."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    hrefs = []
    try:
        for _ in range(count):
            st, hdr, body = request(conn, "POST", f"/v1/scenes/{scene}/sessions",
                                    {"width": width, "height": height, "params": {"spp": spp}})
            if st != 201:
                raise AssertionError(f"session create: {st} {body[:300]!r}")
            hrefs.append(hdr["Location"])
    finally:
        conn.close()
    return hrefs


def frame_storm(port, pid, hrefs, total, samples=20, accept="image/x-exr"):
    """Sends `total` frame requests spread over the sessions (one thread and one keep-alive
    connection per session). Returns (status counts, [(requests done, RSS KiB)], seconds, the
    first unexpected answer or None). An answer counts as expected when it is 200 with a body,
    or 503/429 with Retry-After and a problem body."""
    statuses = collections.Counter()
    trace = [(0, rss_kib(pid))]
    done = [0]
    bad = []
    lock = threading.Lock()
    every = max(1, total // samples)
    per = [total // len(hrefs) + (1 if i < total % len(hrefs) else 0) for i in range(len(hrefs))]

    def worker(href, n):
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
        try:
            for _ in range(n):
                st, hdr, body = request(conn, "POST", href + "/frames", headers={"Accept": accept})
                ok = (st == 200 and len(body) > 0) or (
                    st in (429, 503) and hdr.get("Retry-After") and hdr.get("Content-Type", "").startswith(
                        "application/problem+json"))
                with lock:
                    statuses[st] += 1
                    done[0] += 1
                    if not ok and not bad:
                        bad.append((st, dict(hdr), body[:300]))
                    if done[0] % every == 0:
                        trace.append((done[0], rss_kib(pid)))
        finally:
            conn.close()

    t0 = time.monotonic()
    threads = [threading.Thread(target=worker, args=(h, n)) for h, n in zip(hrefs, per)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return dict(statuses), trace, time.monotonic() - t0, (bad[0] if bad else None)


def rss_growth_kib(trace, warmup_fraction=0.2):
    """RSS growth over the run after the warm-up: the median of the last quarter of the samples
    minus the median of the first quarter (medians, because an allocator's RSS wobbles by a
    few hundred KiB from sample to sample without growing; ASan's more than glibc's). Returns
    (growth, the first sample after the warm-up)."""
    total = trace[-1][0]
    after = [kib for n, kib in trace if n >= warmup_fraction * total]
    quarter = max(1, len(after) // 4)
    return statistics.median(after[-quarter:]) - statistics.median(after[:quarter]), after[0]
