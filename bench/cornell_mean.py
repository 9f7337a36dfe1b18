#!/usr/bin/python3
"""Mean pixel value of a scene with its standard error, from K independent renders.

Usage: /usr/bin/python3 bench/cornell_mean.py [--scene S] [--size 256x256] [--spp 64] [--runs 8]
Each run uses its own seed; the standard error is the spread of the per-run image means over
sqrt(K). Prints one JSON object (per-channel mean, standard error, and the command)."""
import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from exrimage import read_rgb  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default=str(ROOT / "scenes/cornell-box/scene.json"))
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--bin", default=str(ROOT / "build/restir"))
    a = ap.parse_args()
    means = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(a.runs):
            out = Path(tmp) / f"run{k}.exr"
            cmd = [a.bin, "render", a.scene, "--method", "pt", "--spp", str(a.spp), "--size", a.size,
                   "--seed", str(1000 + k), "--json", "-o", str(out)]
            res = subprocess.run(cmd, capture_output=True, text=True)
            if res.returncode != 0:
                sys.exit(f"render failed: {res.stderr}")
            px = read_rgb(out)
            means.append(px.reshape(-1, 3).mean(axis=0))
    m = np.array(means)
    mean = m.mean(axis=0)
    se = m.std(axis=0, ddof=1) / np.sqrt(len(m))
    print(json.dumps({
        "scene": str(Path(a.scene).relative_to(ROOT)) if Path(a.scene).is_relative_to(ROOT) else a.scene,
        "size": a.size, "spp_per_run": a.spp, "runs": a.runs,
        "mean_rgb": [round(float(x), 6) for x in mean],
        "stderr_rgb": [round(float(x), 6) for x in se],
        "mean_luminance": round(float(mean @ [0.2126, 0.7152, 0.0722]), 6),
    }))


if __name__ == "__main__":
    main()
