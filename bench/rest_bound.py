"""bench/rest_bound.py — how far reusing the caustics alone can take restir_sms in real time.

A restir_sms frame takes its caustics from its reservoirs and the rest of its light from one
path-traced sample a pixel. Exact caustics (sms with caustics_only at 256 spp) over the rest at 1
and 2 spp (pt with subset "rest", the light SMS does not own: sms.h) is the least error such a
frame could have; it is printed beside restir_sms's frame 33 and sms at 1 and 2 spp, all scored
against the scene's reference of `make bench-report` (bench/references.py), medians over 3 seeds,
256x256. For restir_sms's frames it also prints the largest per-pixel shares of relMSE (the
pixels that set it). docs/benchmarks.md reads the figures. Usage:

  /usr/bin/python3 bench/rest_bound.py reflective-plane
  /usr/bin/python3 bench/rest_bound.py refractive-slab"""
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


def render(scene, out, *args):
    res = subprocess.run([BIN, "render", str(scene), "--size", "256x256", "-o", str(out), *map(str, args)],
                         capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"rest_bound: {res.stderr.strip()}")
    return read_rgb(out)[..., :3]


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
    caustics = render(scene, work / "bound-caustics.exr", "--method", "sms", "--frames", 1, "--params",
                      '{"spp": 256, "caustics_only": true}', "--seed", 9)
    rows = {k: [] for k in ("rest 1 spp + exact caustics", "rest 2 spp + exact caustics", "restir_sms, frame 33",
                            "sms, 1 spp", "sms, 2 spp")}
    for s in range(SEEDS):
        for spp in (1, 2):
            rest = render(scene, work / "bound-rest.exr", "--method", "pt", "--frames", 1, "--params",
                          f'{{"spp": {spp}, "subset": "rest"}}', "--seed", 600 + s)
            rows[f"rest {spp} spp + exact caustics"].append(errors.metrics(rest + caustics, ref))
        img = render(scene, work / "bound-restir_sms.exr", "--method", "restir_sms", "--frames", 33, "--seed", 700 + s)
        rows["restir_sms, frame 33"].append(errors.metrics(img, ref))
        terms = errors.pixel_terms(img, ref)["relmse"]
        top = np.sort(terms.ravel())[::-1][:3] / terms.sum()
        print(f"# restir_sms seed {700 + s}: relMSE {terms.mean():.4g}, its 3 largest pixels hold "
              + ", ".join(f"{t:.2f}" for t in top), flush=True)
        for spp in (1, 2):
            rows[f"sms, {spp} spp"].append(errors.metrics(
                render(scene, work / "bound-sms.exr", "--method", "sms", "--frames", 1, "--params",
                       f'{{"spp": {spp}}}', "--seed", 800 + s), ref))
    print("\n| scene | image | MAPE | relMSE | RMSE |\n|---|---|---|---|---|")
    for name, scores in rows.items():
        print(f"| {argv[0]} | {name} | " + " | ".join(f"{statistics.median(x[k] for x in scores):.4g}"
                                                  for k in ("mape", "relmse", "rmse")) + " |")


if __name__ == "__main__":
    main(sys.argv[1:])
