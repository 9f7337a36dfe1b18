"""Load run (`make load`): the long form of tests/test_load.py, bounded in time, loopback only.

Starts build/restird on a free port (LOAD_THREADS render threads) and measures, in one run:
  1. /healthz under wrk (LOAD_WRK_SECONDS s, 32 connections);
  2. frames across 4 sessions under wrk (8x8, 1 spp, one connection per session);
  3. resident memory over LOAD_FRAMES (10000) frame requests of 8x8 at 1 spp over 4 sessions,
     sampled 20 times;
  4. overload: render slot 1, render queue 1, 8 sessions of 48x48 sending 2000 frames at once
     (every answer must be 200 or 503 + Retry-After), and RSS before and after.
Prints one JSON object on stdout and a summary on stderr; exits 1 when a property fails
(an error status, a dead daemon, RSS growing more than LOAD_MAX_GROWTH_KIB after warm-up).
"""
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests"))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import loadgen  # noqa: E402
from daemon import Daemon  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.environ.get("RESTIRD_BIN", os.path.join(ROOT, "build", "restird"))
FRAMES = int(os.environ.get("LOAD_FRAMES", "10000"))
WRK_SECONDS = int(os.environ.get("LOAD_WRK_SECONDS", "10"))
THREADS = os.environ.get("LOAD_THREADS", "1")
MAX_GROWTH_KIB = int(os.environ.get("LOAD_MAX_GROWTH_KIB", "1024"))


def main():
    out, failures = {}, []
    d = Daemon(BIN, THREADS)
    port = d.port
    try:
        r = loadgen.wrk(port, "/healthz", WRK_SECONDS, connections=32)
        out["healthz_wrk"] = {k: r[k] for k in ("cmd", "requests", "rps", "p50_ms", "p99_ms", "non_2xx", "socket_errors")}
        if r["non_2xx"] or r["socket_errors"] or r["requests"] == 0:
            failures.append("healthz: errors under wrk")

        hrefs = loadgen.new_sessions(port, 4)
        r = loadgen.wrk(port, "/", WRK_SECONDS, connections=4, threads=4, lua=loadgen.WRK_FRAMES_LUA,
                        args=[h + "/frames" for h in hrefs])
        out["frames_wrk"] = {k: r[k] for k in ("requests", "rps", "p50_ms", "p99_ms", "non_2xx", "socket_errors",
                                               "statuses")}
        if set(r["statuses"]) != {200} or r["socket_errors"]:
            failures.append(f"frames under wrk: {r['statuses']}, socket errors {r['socket_errors']}")

        statuses, trace, secs, bad = loadgen.frame_storm(port, d.pid, hrefs, FRAMES)
        growth, base = loadgen.rss_growth_kib(trace)
        out["memory"] = {"frames": FRAMES, "seconds": round(secs, 2), "statuses": statuses,
                         "rss_kib_after_warmup": base, "rss_growth_kib": growth, "trace": trace}
        if bad or statuses != {200: FRAMES}:
            failures.append(f"frame storm: {statuses}, first bad answer {bad}")
        if growth > MAX_GROWTH_KIB:
            failures.append(f"RSS grew {growth} KiB after warm-up (limit {MAX_GROWTH_KIB})")
    finally:
        rc = d.close()
        if rc != 0:
            failures.append(f"daemon exit code {rc}")

    d = Daemon(BIN, THREADS, "--render-slots", "1", "--render-queue", "1")
    port = d.port
    try:
        hrefs = loadgen.new_sessions(port, 8, width=48, height=48, spp=2)
        before = loadgen.rss_kib(d.pid)
        statuses, trace, secs, bad = loadgen.frame_storm(port, d.pid, hrefs, 2000, accept="application/json")
        out["overload"] = {"sessions": 8, "requests": 2000, "seconds": round(secs, 2), "statuses": statuses,
                           "rss_kib_before": before, "rss_kib_max": max(k for _, k in trace)}
        if bad or not set(statuses) <= {200, 503} or not statuses.get(503):
            failures.append(f"overload: {statuses}, first bad answer {bad}")
    finally:
        rc = d.close()
        if rc != 0:
            failures.append(f"overload daemon exit code {rc}")

    out["failures"] = failures
    print(json.dumps(out, indent=1))
    h, f, m, o = out["healthz_wrk"], out["frames_wrk"], out.get("memory", {}), out.get("overload", {})
    print(f"healthz {h['rps']:.0f} req/s (p99 {h['p99_ms']} ms); frames {f['rps']:.0f} req/s; "
          f"{m.get('frames')} frames: RSS {m.get('rss_kib_after_warmup')} KiB after warm-up, "
          f"+{m.get('rss_growth_kib')} KiB; overload {o.get('statuses')}; failures: {failures or 'none'}",
          file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
