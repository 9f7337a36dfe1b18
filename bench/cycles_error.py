"""pt's error against Blender Cycles' at equal samples per pixel, on a Cycles-converged reference.

Renders the scene (default: the Cornell box at 256x256) with Cycles at REF_SPP as the reference,
then, for each seed, Cycles, pt (its default sampler) and pt with the random sampler at SPP, and
prints each one's RMSE (whole image, and away from the light: pixels farther than 2 from any
pixel brighter than 1 in the reference), MAPE, and the ratios of pt's to Cycles'. Samples, not
seconds: each renderer's work per sample differs, and this machine's timings are noisy; the
samples' quality is what the comparison isolates. Cycles runs through bench/crosscheck_cycles.py,
with everything that would change its image in expectation switched off (see there).

    /usr/bin/python3 bench/cycles_error.py                      # 16 spp, seeds 1-4, 2048-spp reference
    CYCLES_SPP=4 CYCLES_SEEDS=1,2,3,4,5,6 /usr/bin/python3 bench/cycles_error.py

Environment: CYCLES_SCENE, CYCLES_SIZE (256), CYCLES_SPP (16), CYCLES_REF_SPP (2048),
CYCLES_SEEDS (1,2,3,4), CYCLES_OUT (build/bench/cycles_error; the reference is kept there and
reused while its scene, size and spp are the same), BLENDER (blender), RESTIR_BIN (build/restir).
Needs Debian's blender (3.4; not installed by scripts/install-deps.sh). The 2048-spp reference
takes about 6 minutes on two loaded cores."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
from exrimage import read_rgb  # noqa: E402


def cycles(blender, scene, size, spp, seed, out):
    cmd = [blender, "-b", "--factory-startup", "-P", str(ROOT / "bench" / "crosscheck_cycles.py"), "--",
           "--scene", str(scene), "--size", size, "--spp", str(spp), "--seed", str(seed), "--out", str(out)]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0 or not out.exists():
        sys.exit(f"cycles_error: {' '.join(cmd)} failed:\n{res.stderr[-2000:]}")


def ours(restir, scene, size, spp, seed, out, params=None):
    cmd = [restir, "render", str(scene), "--spp", str(spp), "--size", size, "--seed", str(seed), "-o", str(out)]
    if params:
        cmd += ["--frames", "1", "--params", json.dumps(params)]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        sys.exit(f"cycles_error: {' '.join(cmd)} failed:\n{res.stderr[-2000:]}")


def errors(img, ref, away):
    sq = ((img - ref) ** 2).mean(axis=2)
    return {"mse": float(sq.mean()), "mse_away": float(sq[away].mean()),
            "mape": float(np.mean(np.abs(img - ref) / (ref + 0.01 * ref.mean())))}


def main():
    env = os.environ.get
    scene = Path(env("CYCLES_SCENE", str(ROOT / "scenes" / "cornell-box" / "scene.json")))
    size, spp, ref_spp = env("CYCLES_SIZE", "256"), int(env("CYCLES_SPP", "16")), int(env("CYCLES_REF_SPP", "2048"))
    seeds = [int(s) for s in env("CYCLES_SEEDS", "1,2,3,4").split(",")]
    out = Path(env("CYCLES_OUT", str(ROOT / "build" / "bench" / "cycles_error")))
    blender, restir = env("BLENDER", "blender"), env("RESTIR_BIN", str(ROOT / "build" / "restir"))
    out.mkdir(parents=True, exist_ok=True)
    wh = f"{size}x{size}"
    ref_path = out / f"ref-{scene.parent.name}-{size}-{ref_spp}.exr"
    if not ref_path.exists():
        cycles(blender, scene, wh, ref_spp, 0, ref_path)
    ref = read_rgb(ref_path)
    lum = ref.mean(axis=2)
    h, w = lum.shape
    bright = np.pad(lum > 1.0, 2)
    near = np.any([bright[2 + dy:2 + dy + h, 2 + dx:2 + dx + w] for dy in range(-2, 3) for dx in range(-2, 3)], axis=0)
    rows = {"cycles": [], "pt": [], "pt_random": []}
    for seed in seeds:
        cycles(blender, scene, wh, spp, seed, out / f"cycles{seed}.exr")
        ours(restir, scene, wh, spp, seed, out / f"pt{seed}.exr")
        ours(restir, scene, wh, spp, seed, out / f"pt_random{seed}.exr", {"sampler": "random"})
        for name in rows:
            rows[name].append(errors(read_rgb(out / f"{name}{seed}.exr"), ref, ~near))
    mean = {name: {k: float(np.mean([r[k] for r in rs])) for k in rs[0]} for name, rs in rows.items()}
    ratios = {name: {"rmse": round(float(np.sqrt(mean[name]["mse"] / mean["cycles"]["mse"])), 3),
                     "rmse_away_from_light": round(float(np.sqrt(mean[name]["mse_away"] / mean["cycles"]["mse_away"])), 3),
                     "mape": round(mean[name]["mape"] / mean["cycles"]["mape"], 3)}
              for name in ("pt", "pt_random")}
    print(json.dumps({"scene": str(scene.relative_to(ROOT)) if scene.is_relative_to(ROOT) else str(scene),
                      "size": wh, "spp": spp, "reference_spp": ref_spp, "seeds": seeds,
                      "pixels_near_light": int(near.sum()), "mean": mean, "over_cycles": ratios}, indent=1))


if __name__ == "__main__":
    main()
