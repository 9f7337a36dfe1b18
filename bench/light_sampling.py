#!/usr/bin/python3
"""pt's `light_sampling`: the per-pixel variance of next-event estimation by area and by solid
angle on the Cornell box, and the instructions each costs.

Usage: /usr/bin/python3 bench/light_sampling.py [--size 64] [--runs 1000] [--max-depth 1] [--no-cost]

Variance: `--runs` single frames of 1 spp per setting (seeds 0..runs-1, the same for both
settings), the luminance's sample variance per pixel; printed as the ratio solid_angle / area per
pixel, averaged over crops of the back wall (between the ceiling and the blocks), the red and
the green wall, and over the whole image (where the light's own edge pixels dominate), together
with the ratio of the crops' summed variances. `--max-depth 1` is direct light alone (NEE and the
emitter hits it is MIS-weighted against).

Cost: callgrind's instruction count of tests/perf/instr_guard.sh's diffuse render (64x64, one
thread, max depth 8) and of the same render at the variance run's max depth, each at 4 and 12 spp
and differenced (start-up cancels), per ray and per sample, for both settings. Instruction counts
do not depend on the machine's load. Prints one JSON object."""
import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from exrimage import read_rgb  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "scenes/cornell-box/scene.json"
SETTINGS = ("area", "solid_angle")
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
# Crops at 64x64 (rows, columns; half-open), scaled with --size: surfaces the light falls on
# directly, away from their edges.
CROPS_64 = {"back wall": (14, 27, 14, 50), "red wall": (10, 49, 2, 10), "green wall": (10, 49, 53, 62)}


def params(setting, **extra):
    return json.dumps({"light_sampling": setting, **extra})


def render(binary, out, size, seed, setting, max_depth, spp=1, threads=None):
    cmd = [binary, "render", str(SCENE), "--method", "pt", "--size", f"{size}x{size}", "--frames", "1",
           "--seed", str(seed), "--params", params(setting, spp=spp, max_depth=max_depth), "--json", "-o", str(out)]
    if threads:
        cmd += ["--threads", str(threads)]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        sys.exit(f"bench: {' '.join(cmd)}: {res.stderr}")
    return json.loads(res.stdout)


def variances(binary, size, runs, max_depth):
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for setting in SETTINGS:
            s1 = s2 = 0.0
            for seed in range(runs):
                exr = Path(tmp) / "f.exr"
                render(binary, exr, size, seed, setting, max_depth)
                lum = read_rgb(exr) @ LUMINANCE
                s1 = s1 + lum
                s2 = s2 + lum * lum
            mean = s1 / runs
            out[setting] = (mean, (s2 / runs - mean * mean) * runs / (runs - 1))
    return out


def crops(size):
    k = size / 64
    c = {name: tuple(int(round(v * k)) for v in box) for name, box in CROPS_64.items()}
    c["whole image"] = (0, size, 0, size)
    return c


def instructions(binary, setting, max_depth, spp):
    """callgrind's total for the diffuse guard render at `spp` (and its ray count)."""
    with tempfile.TemporaryDirectory() as tmp:
        exr = Path(tmp) / "i.exr"
        rays = render(binary, exr, 64, 0, setting, max_depth, spp=spp, threads=1)["rays"]
        cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={tmp}/cg.out", binary, "render", str(SCENE),
               "--method", "pt", "--size", "64x64", "--threads", "1", "--frames", "1", "--seed", "0",
               "--params", params(setting, spp=spp, max_depth=max_depth), "-o", str(exr)]
        res = subprocess.run(cmd, capture_output=True, text=True)
        m = re.search(r"Collected : (\d+)", res.stderr)
        if res.returncode != 0 or not m:
            sys.exit(f"bench: {' '.join(cmd)} gave no instruction count: {res.stderr[-2000:]}")
        return int(m.group(1)), rays


def cost(binary, setting, max_depth):
    (i_lo, r_lo), (i_hi, r_hi) = instructions(binary, setting, max_depth, 4), instructions(binary, setting, max_depth, 12)
    return {"instr_per_ray": round((i_hi - i_lo) / (r_hi - r_lo), 1),
            "instr_per_sample": round((i_hi - i_lo) / (64 * 64 * 8), 1),
            "rays_per_sample": round((r_hi - r_lo) / (64 * 64 * 8), 3)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--max-depth", type=int, default=1)
    ap.add_argument("--no-cost", action="store_true")
    ap.add_argument("--bin", default=str(ROOT / "build/restir"))
    a = ap.parse_args()
    v = variances(a.bin, a.size, a.runs, a.max_depth)
    (mean_a, var_a), (mean_s, var_s) = v["area"], v["solid_angle"]
    result = {"size": a.size, "runs": a.runs, "max_depth": a.max_depth, "crops": {}}
    for name, (y0, y1, x0, x1) in crops(a.size).items():
        va, vs = var_a[y0:y1, x0:x1], var_s[y0:y1, x0:x1]
        lit = va > 0
        result["crops"][name] = {
            "rows": [y0, y1 - 1], "columns": [x0, x1 - 1],
            "variance_ratio_per_pixel": round(float(np.mean(vs[lit] / va[lit])), 3),
            "variance_ratio_of_sums": round(float(vs.sum() / va.sum()), 3),
            "mean_area": round(float(mean_a[y0:y1, x0:x1].mean()), 5),
            "mean_solid_angle": round(float(mean_s[y0:y1, x0:x1].mean()), 5)}
    if not a.no_cost:
        depths = sorted({8, a.max_depth})
        result["cost"] = {f"max_depth {d}": {s: cost(a.bin, s, d) for s in SETTINGS} for d in depths}
    result["command"] = ("restir render scenes/cornell-box/scene.json --method pt --frames 1 --seed S --params "
                         f"'{{\"light_sampling\": X, \"spp\": 1, \"max_depth\": {a.max_depth}}}' --size {a.size}x{a.size}")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
