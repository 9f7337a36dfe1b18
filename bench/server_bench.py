"""Server benchmark (the daemon part of `make bench`), stdlib only.

Starts build/restird on a free loopback port and measures, in one run:
  1. per-request overhead: N synchronous 16x16 1-spp frame requests (Accept: application/json)
     on one keep-alive connection; overhead = client round trip - the render_ms the daemon
     reports for that frame (parsing, session bookkeeping, the frame copy, JSON, HTTP);
     and the same for EXR answers (adds the EXR encode of the 16x16 frame, uncompressed by default);
  2. /healthz latency while a 256x256 64-spp frame renders on another connection;
  3. /healthz throughput with wrk (loopback, WRK_CONNECTIONS connections, WRK_SECONDS s).
Prints one JSON object (medians and percentiles) on stdout; progress on stderr.
Environment: RESTIRD_BIN (build/restird), BENCH_N (300), WRK_SECONDS (5), WRK_CONNECTIONS (16).
"""
import http.client
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))
from daemon import Daemon  # noqa: E402
from loadgen import request  # noqa: E402  (the request helper shared with the load tests)

BIN = os.environ.get("RESTIRD_BIN", os.path.join(ROOT, "build", "restird"))
N = int(os.environ.get("BENCH_N", "300"))


def pct(xs, p):
    xs = sorted(xs)
    k = min(len(xs) - 1, max(0, int(round(p / 100.0 * (len(xs) - 1)))))
    return xs[k]


def main():
    d = Daemon(BIN)
    try:
        port = d.port
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=120)
        st, hdr, body = request(conn, "POST", "/v1/scenes/cornell-box/sessions",
                                {"width": 16, "height": 16, "params": {"spp": 1}})
        assert st == 201, body
        base = hdr["Location"]
        results = {"n": N}
        for kind, accept in (("json", "application/json"), ("exr", "image/x-exr")):
            over, rtt = [], []
            for i in range(N + 10):
                t0 = time.perf_counter()
                st, hdr, body = request(conn, "POST", base + "/frames", None, {"Accept": accept})
                t1 = time.perf_counter()
                assert st == 200, body
                if i < 10:
                    continue  # warm-up
                render_ms = float(hdr["X-Render-Ms"])
                rtt.append((t1 - t0) * 1e3)
                over.append((t1 - t0) * 1e3 - render_ms)
            results[f"overhead_ms_{kind}"] = {"median": statistics.median(over), "p90": pct(over, 90)}
            results[f"round_trip_ms_{kind}"] = {"median": statistics.median(rtt)}
            print(f"{kind}: overhead median {statistics.median(over):.3f} ms", file=sys.stderr)

        # /healthz while a large frame renders.
        st, hdr, body = request(conn, "POST", "/v1/scenes/cornell-box/sessions",
                                {"width": 256, "height": 256, "params": {"spp": 64}})
        big = hdr["Location"]
        done = threading.Event()

        def render():
            c2 = http.client.HTTPConnection("127.0.0.1", port, timeout=300)
            request(c2, "POST", big + "/frames", None, {"Accept": "application/json"})
            done.set()

        th = threading.Thread(target=render)
        th.start()
        time.sleep(0.2)
        lat = []
        hc = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        while not done.is_set() and len(lat) < 2000:
            t0 = time.perf_counter()
            st, _, _ = request(hc, "GET", "/healthz")
            lat.append((time.perf_counter() - t0) * 1e3)
            assert st == 200
        th.join()
        results["healthz_during_render_ms"] = {"n": len(lat), "p50": pct(lat, 50), "p99": pct(lat, 99),
                                               "max": max(lat)}
        print(f"healthz during render: p50 {pct(lat, 50):.3f} ms p99 {pct(lat, 99):.3f} ms", file=sys.stderr)

        wrk = shutil.which("wrk")
        if wrk:
            secs = os.environ.get("WRK_SECONDS", "5")
            conns = os.environ.get("WRK_CONNECTIONS", "16")
            out = subprocess.run([wrk, "-t2", f"-c{conns}", f"-d{secs}s", "--latency",
                                  f"http://127.0.0.1:{port}/healthz"], capture_output=True, text=True).stdout
            m = re.search(r"Requests/sec:\s+([\d.]+)", out)
            p99 = re.search(r"99%\s+([\d.]+)(us|ms|s)", out)
            results["healthz_wrk"] = {"connections": int(conns), "seconds": int(secs),
                                      "requests_per_s": float(m.group(1)) if m else None,
                                      "p99": (p99.group(1) + p99.group(2)) if p99 else None}
            print(out, file=sys.stderr)
        print(json.dumps(results, indent=1))
    finally:
        d.close()


if __name__ == "__main__":
    main()
