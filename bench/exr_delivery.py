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
import os
import statistics
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "bench"))
from daemon import Daemon  # noqa: E402  (bench/daemon.py: a daemon and one keep-alive connection)

VARIANTS = [(c, p) for c in ("none", "zip", "piz") for p in ("float", "half")]


def measure(d, side, reps):
    session = d.session("cornell-box", "pt", side, side, {"spp": 1})
    d.frame(session)
    times, sizes = {v: [] for v in VARIANTS}, {}
    for _ in range(reps):
        for c, p in VARIANTS:  # interleaved: a slow minute of the machine hits every variant
            t0 = time.perf_counter()
            d.conn.request("GET", f"{session}/frames/0?compression={c}&pixel={p}", headers={"Accept": "image/x-exr"})
            resp = d.conn.getresponse()
            body = resp.read()
            times[(c, p)].append((time.perf_counter() - t0) * 1000.0)
            if resp.status != 200:
                raise SystemExit(f"exr_delivery: {c} {p}: {resp.status} {body[:200]!r}")
            sizes[(c, p)] = len(body)
    d.delete(session)
    raw = side * side * 3 * 4
    for v in VARIANTS:
        print(f"| {side}×{side} | {v[0]} | {v[1]} | {statistics.median(times[v]):.2f} | "
              f"{statistics.quantiles(times[v], n=4)[0]:.2f} | {sizes[v]} | {100.0 * sizes[v] / raw:.1f} % |")


def main():
    d = Daemon(os.environ.get("RESTIRD_BIN", os.path.join(ROOT, "build", "restird")),
               os.environ.get("BENCH_THREADS", "2"))
    try:
        print(f"load average {os.getloadavg()[0]:.1f}")
        print("| frame | compression | pixel | median ms | q1 ms | bytes | of raw float |")
        print("|---|---|---|---|---|---|---|")
        measure(d, 256, 60)
        measure(d, 1024, 15)
    finally:
        d.close()


if __name__ == "__main__":
    main()
