#!/usr/bin/env python3
"""bench/ab_noise.py — two builds' estimators side by side: which one has less noise per second?

  /usr/bin/python3 bench/ab_noise.py A/restir B/restir [--scene S] [--method M] [--params JSON]
                                     [--size WxH] [--seeds N] [--threads N]

Renders the same scene, method and parameters with seeds 0 .. N-1 on each CLI build (interleaved,
A then B for each seed) and compares their noise without a reference: each image's error is its
RMSE against the mean of the other N - 1 images of its build, scaled by sqrt((N - 1) / N), which
estimates its RMSE against the build's own expectation. Two unbiased estimators of the same image
differ only there, so their noise per unit of time is what tells them apart; a bias would not
show (the statistical tests check that). Prints, per build, the median and RMS of the images'
errors, the largest pixel value (mean of channels) and the median render time, then the
efficiency B/A = (err_A^2 t_A) / (err_B^2 t_B) from the RMS errors and median times: above 1, B
reaches a given error sooner. --params is the CLI's (protocol/API.md's session params; pt takes
spp there). Defaults: refractive-slab, pt, {"spp": 16}, 128x128, 24 seeds, all cores. Benchmarks
are not tests: nothing fails on these figures."""
import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from exrimage import read_rgb  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def render(binary, scene, method, params, size, seed, threads, out):
    cmd = [binary, "render", str(scene), "--size", size, "--method", method, "--frames", "1", "--seed", str(seed),
           "--params", params, "--json", "-o", str(out)]
    if threads:
        cmd += ["--threads", threads]
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"bench: {' '.join(cmd)}: {run.stderr.strip()}")
    stats = json.loads(run.stdout.strip().splitlines()[-1])
    return read_rgb(out), stats["time_ms"]


def noise(images):
    n = len(images)
    total = images.sum(axis=0)
    scale = np.sqrt((n - 1) / n)
    return [float(np.sqrt(np.mean((img - (total - img) / (n - 1)) ** 2)) * scale) for img in images]


def main():
    ap = argparse.ArgumentParser(description="two builds' noise per second, side by side")
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--scene", default="refractive-slab")
    ap.add_argument("--method", default="pt")
    ap.add_argument("--params", default='{"spp": 16}')
    ap.add_argument("--size", default="128x128")
    ap.add_argument("--seeds", type=int, default=24)
    ap.add_argument("--threads", default="")
    o = ap.parse_args()
    if o.seeds < 3:
        ap.error("--seeds: at least 3 (each image is compared with the mean of the others)")
    scene = Path(o.scene) if Path(o.scene).exists() else ROOT / "scenes" / o.scene
    imgs = {"A": [], "B": []}
    times = {"A": [], "B": []}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(o.seeds):
            for name, binary in (("A", o.a), ("B", o.b)):
                # A new file per render: OpenImageIO caches images by file name.
                img, ms = render(binary, scene, o.method, o.params, o.size, seed, o.threads,
                                 Path(tmp) / f"{name}-{seed}.exr")
                imgs[name].append(img)
                times[name].append(ms)
    print(f"{scene.name} {o.method} {o.params} {o.size}, seeds 0-{o.seeds - 1}")
    rms = {}
    for name in ("A", "B"):
        stack = np.stack(imgs[name])
        err = noise(stack)
        rms[name] = float(np.sqrt(np.mean(np.square(err))))
        print(f"  {name}: error median {statistics.median(err):.4f}, RMS {rms[name]:.4f}; largest pixel "
              f"{stack.mean(axis=-1).max():.1f}; mean {stack.mean():.5f}; render ms {statistics.median(times[name]):.1f}")
    ta, tb = statistics.median(times["A"]), statistics.median(times["B"])
    print(f"  efficiency B/A {rms['A'] ** 2 * ta / (rms['B'] ** 2 * tb):.3f}")


if __name__ == "__main__":
    main()
