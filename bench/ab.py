#!/usr/bin/env python3
"""bench/ab.py — two builds of the daemon side by side, frame by frame: is B faster than A?

  /usr/bin/python3 bench/ab.py A/restird B/restird [--scene S] [--method M] [--params JSON]
                               [--size WxH] [--warmup N] [--rounds N] [--threads N]

Starts both daemons with one session each (same scene, method, parameters and seed; both builds
must render the same frames for the comparison to mean anything), warms both up, then renders
rounds of one frame of A and one of B in turn, and a last frame of A. A round's ratio divides B's
frame time by the mean of the two A frames around it, rendered within a fraction of a second of
it, so a machine whose speed drifts by tens of per cent within seconds still gives a steady
median. A frame's time is its CPU time over its threads (cputime.frame_time_ms) when both builds
report it, else both wall times (render_ms), so that an older build is compared like for like.
Prints the median of the rounds' ratios B/A and their quartiles, the median frame time of
each, and for the ReSTIR methods the median time of each pass. Defaults: cornell-box, restir_pt,
{}, 256x256, 16 warm-up frames, 60 rounds, all cores. Benchmarks are not tests: nothing fails on
a timing."""
import argparse
import json
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cputime import frame_time_ms  # noqa: E402
from daemon import Daemon  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description="two daemon builds, frame by frame")
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--scene", default="cornell-box")
    ap.add_argument("--method", default="restir_pt")
    ap.add_argument("--params", default="{}")
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--warmup", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=60)
    ap.add_argument("--threads", default="0")
    o = ap.parse_args()
    w, h = (int(v) for v in o.size.split("x"))
    params = json.loads(o.params)
    da, db = Daemon(o.a, o.threads), Daemon(o.b, o.threads)
    try:
        sa = da.session(o.scene, o.method, w, h, params)
        sb = db.session(o.scene, o.method, w, h, params)
        for _ in range(o.warmup):
            da.frame(sa)
            db.frame(sb)
        fa, fb = [da.frame(sa)], []
        for _ in range(o.rounds):
            fb.append(db.frame(sb))
            fa.append(da.frame(sa))
    finally:
        da.close()
        db.close()
    both_cpu = all("render_cpu_ms" in f for f in fa + fb)
    ta, tb = ([frame_time_ms(f) if both_cpu else f["render_ms"] for f in fs] for fs in (fa, fb))
    ratios = [t / ((ta[i] + ta[i + 1]) / 2) for i, t in enumerate(tb)]
    q1, _, q3 = statistics.quantiles(ratios, n=4)
    print(f"{o.scene} {o.method} {o.params} {o.size}, {o.rounds} rounds: B/A {statistics.median(ratios):.3f} "
          f"[{q1:.3f}-{q3:.3f}]; frame {'CPU ms a thread' if both_cpu else 'ms'} A {statistics.median(ta):.1f}, B {statistics.median(tb):.1f}")
    if "passes" in fb[0]:
        for k in ("gbuffer_ms", "initial_ms", "temporal_ms", "spatial_ms", "shade_ms"):
            print(f"  {k}: A {statistics.median(f['passes'][k] for f in fa):.2f}, "
                  f"B {statistics.median(f['passes'][k] for f in fb):.2f}")


if __name__ == "__main__":
    main()
