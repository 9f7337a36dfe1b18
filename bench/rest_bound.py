"""bench/rest_bound.py — what the rest of the light costs restir_sms in real time, and what reusing it
gains.

A restir_sms frame takes its caustics from its reservoirs; the rest of its light (sms.h's split)
comes either from one path-traced sample a pixel (`"rest": "pt"`) or from a restir_pt session
restricted to that subset (`"rest": "restir_pt"`, the default). Exact caustics (sms with
caustics_only at 256 spp) over the rest at 1 and 2 spp (pt with subset "rest") is the least error
a frame of the first kind could have, and over restir_pt's rest at frame 33 what the second kind's
rest leaves. These are printed beside restir_sms's frame 33 with either rest and sms at 1 and 2
spp, all scored against the scene's reference of `make bench-report` (bench/references.py),
medians over 3 seeds, 256x256, one thread, with each render's CPU time a frame (of the last frame
for the sessions). The last columns put restir_sms's frame beside sms at the same CPU time: sms's
1-spp error scaled as independent samples' errors scale (MAPE and RMSE by 1 / sqrt(c), relMSE by
1 / c, c = the frame's CPU time over sms's at 1 spp). For restir_sms's frames it also prints the
largest per-pixel shares of relMSE (the pixels that set it). docs/benchmarks.md reads the figures.
Usage:

  /usr/bin/python3 bench/rest_bound.py reflective-plane
  /usr/bin/python3 bench/rest_bound.py refractive-slab"""
import json
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np

import errors
from exrimage import read_rgb
from references import Reference, reference_method
from restir_pt import BIN

ROOT = Path(__file__).resolve().parent.parent
SEEDS = 3
KEYS = ("mape", "relmse", "rmse")


def render(scene, out, *args):
    """The image and the CPU time (ms) of its last frame."""
    res = subprocess.run([BIN, "render", str(scene), "--size", "256x256", "--threads", "1", "--json", "-o", str(out),
                          *map(str, args)], capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"rest_bound: {res.stderr.strip()}")
    return read_rgb(out)[..., :3], json.loads(res.stdout)["last_frame_cpu_ms"]


def main(argv):
    if len(argv) != 1:
        raise SystemExit(__doc__)
    scene = ROOT / "scenes" / argv[0] / "scene.json"
    if not scene.is_file():
        raise SystemExit(f"rest_bound: no scene {argv[0]!r} in scenes/")
    work = ROOT / "build" / "sweep"
    work.mkdir(parents=True, exist_ok=True)
    method, chunk = reference_method(argv[0])
    ref = Reference(scene, 256, method, chunk, work).image
    caustics, _ = render(scene, work / "bound-caustics.exr", "--method", "sms", "--frames", 1, "--params",
                         '{"spp": 256, "caustics_only": true}', "--seed", 9)
    rows = {}

    def score(name, img, ms):
        rows.setdefault(name, []).append({**errors.metrics(img, ref), "ms": ms})

    for s in range(SEEDS):
        for spp in (1, 2):
            rest, ms = render(scene, work / "bound-rest.exr", "--method", "pt", "--frames", 1, "--params",
                              f'{{"spp": {spp}, "subset": "rest"}}', "--seed", 600 + s)
            score(f"pt's rest at {spp} spp + exact caustics", rest + caustics, ms)
        rest, ms = render(scene, work / "bound-rest.exr", "--method", "restir_pt", "--frames", 33, "--params",
                          '{"subset": "rest"}', "--seed", 600 + s)
        score("restir_pt's rest, frame 33 + exact caustics", rest + caustics, ms)
        for rest_by in ("pt", "restir_pt"):
            img, ms = render(scene, work / "bound-restir_sms.exr", "--method", "restir_sms", "--frames", 33,
                             "--params", json.dumps({"rest": rest_by}), "--seed", 700 + s)
            score(f"restir_sms (rest {rest_by}), frame 33", img, ms)
            terms = errors.pixel_terms(img, ref)["relmse"]
            top = np.sort(terms.ravel())[::-1][:3] / terms.sum()
            print(f"# restir_sms (rest {rest_by}) seed {700 + s}: relMSE {terms.mean():.4g}, its 3 largest pixels "
                  "hold " + ", ".join(f"{t:.2f}" for t in top), flush=True)
        for spp in (1, 2):
            img, ms = render(scene, work / "bound-sms.exr", "--method", "sms", "--frames", 1, "--params",
                             f'{{"spp": {spp}}}', "--seed", 800 + s)
            score(f"sms, {spp} spp", img, ms)
    med = {name: {k: statistics.median(x[k] for x in scores) for k in (*KEYS, "ms")} for name, scores in rows.items()}
    sms1 = med["sms, 1 spp"]
    print("\n| scene | image | MAPE | relMSE | RMSE | CPU ms a frame | over sms at equal CPU time: MAPE | relMSE |")
    print("|---|---|---|---|---|---|---|---|")
    for name, m in med.items():
        ratio = " | |"
        if name.startswith("restir_sms"):
            c = m["ms"] / sms1["ms"]
            ratio = f" {m['mape'] / (sms1['mape'] / c ** 0.5):.2f} | {m['relmse'] / (sms1['relmse'] / c):.2f} |"
        print(f"| {argv[0]} | {name} | " + " | ".join(f"{m[k]:.4g}" for k in KEYS) + f" | {m['ms']:.0f} |{ratio}")


if __name__ == "__main__":
    main(sys.argv[1:])
