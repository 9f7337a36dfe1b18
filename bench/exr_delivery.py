"""bench/exr_delivery.py — which EXR compression delivers a daemon frame fastest (part of
`make bench`; figures in docs/benchmarks.md, "EXR frames: which compression").

Starts build/restird on a free loopback port, renders one 1-spp pt frame of cornell-box at each
size, then fetches that same frame (no rendering) with every ?compression= and ?pixel= in turn,
REPS rounds, on one keep-alive connection. Prints, per size and variant, the median and first
quartile of the client's round trip (encode + loopback transfer + decode of nothing: the body is
only read) and the body's size against raw float RGB. A link slower than loopback adds
size / bandwidth to each figure.

  /usr/bin/python3 bench/exr_delivery.py            # 256x256 (60 rounds) and 1024x1024 (15)
Environment: RESTIRD_BIN (build/restird), BENCH_THREADS (2)."""
import http.client
import os
import statistics
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))
from daemon import Daemon  # noqa: E402

VARIANTS = [(c, p) for c in ("none", "zip", "piz") for p in ("float", "half")]


def measure(d, side, reps):
    r = d.req("POST", "/v1/scenes/cornell-box/sessions",
              json_body={"method": "pt", "width": side, "height": side, "params": {"spp": 1}})
    href = r.json()["href"]
    d.req("POST", href + "/frames", headers={"Accept": "application/json"})
    conn = http.client.HTTPConnection("127.0.0.1", d.port, timeout=120)
    times, sizes = {v: [] for v in VARIANTS}, {}
    for _ in range(reps):
        for c, p in VARIANTS:  # interleaved: a slow minute of the machine hits every variant
            t0 = time.perf_counter()
            conn.request("GET", f"{href}/frames/0?compression={c}&pixel={p}", headers={"Accept": "image/x-exr"})
            resp = conn.getresponse()
            body = resp.read()
            times[(c, p)].append((time.perf_counter() - t0) * 1000.0)
            if resp.status != 200:
                raise SystemExit(f"exr_delivery: {c} {p}: {resp.status} {body[:200]!r}")
            sizes[(c, p)] = len(body)
    conn.close()
    d.req("DELETE", href)
    raw = side * side * 3 * 4
    for v in VARIANTS:
        print(f"| {side}×{side} | {v[0]} | {v[1]} | {statistics.median(times[v]):.2f} | "
              f"{statistics.quantiles(times[v], n=4)[0]:.2f} | {sizes[v]} | {100.0 * sizes[v] / raw:.1f} % |")


def main():
    d = Daemon(os.path.join(ROOT, "build", "bench", "exr_delivery"), "--threads", os.environ.get("BENCH_THREADS", "2"))
    try:
        print(f"load average {os.getloadavg()[0]:.1f}")
        print("| frame | compression | pixel | median ms | q1 ms | bytes | of raw float |")
        print("|---|---|---|---|---|---|---|")
        measure(d, 256, 60)
        measure(d, 1024, 15)
    finally:
        d.stop()


if __name__ == "__main__":
    main()
