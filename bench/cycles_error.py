"""pt's error against Blender Cycles' at equal samples per pixel, or at equal CPU time, on a
Cycles-converged reference.

Renders the scene (default: the Cornell box at 256x256) with Cycles at REF_SPP as the reference,
then, for each seed, Cycles, pt (its default sampler) and pt with the random sampler at SPP, and
prints each one's RMSE (whole image, and away from the light: pixels farther than 2 from any
pixel brighter than 1 in the reference), MAPE, and the ratios of pt's to Cycles', and each
renderer's per-pixel variance of the luminance over the seeds, near and away from the light (a
sample position that no seed moves shows as low variance and high error). Samples, not
seconds: each renderer's work per sample differs, and this machine's timings are noisy; the
samples' quality is what the comparison isolates. Cycles runs through bench/crosscheck_cycles.py,
with everything that would change its image in expectation switched off (see there). Both
renderers run with CYCLES_THREADS threads (default: all cores).

Equal time (CYCLES_SECONDS=S, or a list S1,S2,...): each renderer gets S seconds of all
CYCLES_THREADS threads, a budget of S x threads CPU seconds (user + system of its process tree)
of rendering. First its marginal CPU seconds per sample per pixel at SIZE are measured: renders
at the two counts of CYCLES_COST_SPP (16,80) are differenced, so that start-up (Blender's launch
and scene conversion, scene loading, BVH builds, the EXR write) cancels, CYCLES_COST_REPS (5)
times, the renderers and the two counts in alternating order, the median difference kept. Each
renderer then renders every seed at round(budget / cost) spp (at least 1), and the output gives,
per budget, each renderer's cost and spp, its errors per seed and their medians, and pt's
ratios to Cycles' (from the mean MSE over the seeds as in the equal-spp mode, the ratio of the
medians over the seeds and each seed's own ratio).

    /usr/bin/python3 bench/cycles_error.py                      # 16 spp, seeds 1-4, 2048-spp reference
    CYCLES_SPP=4 CYCLES_SEEDS=1,2,3,4,5,6 /usr/bin/python3 bench/cycles_error.py
    CYCLES_SECONDS=1,2,4 CYCLES_SEEDS=1,2,3,4,5,6 nice -n 19 /usr/bin/python3 bench/cycles_error.py

Environment: CYCLES_SCENE, CYCLES_SIZE (256), CYCLES_SPP (16), CYCLES_REF_SPP (2048),
CYCLES_SEEDS (1,2,3,4), CYCLES_THREADS (all cores), CYCLES_SECONDS (unset: equal samples),
CYCLES_COST_SPP (16,80), CYCLES_COST_REPS (5), CYCLES_OUT (build/bench/cycles_error; the
reference is kept there and reused while its scene, size and spp are the same), BLENDER
(blender), RESTIR_BIN (build/restir).
Needs Debian's blender (3.4; not installed by scripts/install-deps.sh). The 2048-spp reference
takes about 6 minutes on two loaded cores."""
import json
import os
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
from cputime import run_timed  # noqa: E402
from exrimage import read_rgb  # noqa: E402


def run(cmd, out):
    """Runs cmd, which must write out; returns the CPU seconds (user + system) of its process tree."""
    res, cpu = run_timed(cmd)
    if res.returncode != 0 or not out.exists():
        sys.exit(f"cycles_error: {' '.join(cmd)} failed:\n{res.stderr[-2000:]}")
    return cpu


def cycles(blender, scene, size, spp, seed, out, threads):
    cmd = [blender, "-b", "--factory-startup", "-P", str(ROOT / "bench" / "crosscheck_cycles.py"), "--",
           "--scene", str(scene), "--size", size, "--spp", str(spp), "--seed", str(seed),
           "--threads", str(threads), "--out", str(out)]
    return run(cmd, out)


def ours(restir, scene, size, spp, seed, out, threads, params=None):
    cmd = [restir, "render", str(scene), "--spp", str(spp), "--size", size, "--seed", str(seed),
           "--threads", str(threads), "-o", str(out)]
    if params:
        cmd += ["--frames", "1", "--params", json.dumps(params)]
    return run(cmd, out)


def errors(img, ref, away):
    sq = ((img - ref) ** 2).mean(axis=2)
    return {"mse": float(sq.mean()), "mse_away": float(sq[away].mean()),
            "mape": float(np.mean(np.abs(img - ref) / (ref + 0.01 * ref.mean())))}


def cost_per_spp(render, names, lo, hi, reps, out):
    """Each renderer's marginal CPU seconds per sample per pixel: the CPU time of a render at hi
    spp minus that of one at lo spp, divided by hi - lo; reps pairs, the renderers and the two
    counts in alternating order, the median kept (with the pairs' range)."""
    diffs = {name: [] for name in names}
    for rep in range(reps):
        order = names if rep % 2 == 0 else names[::-1]
        counts = (lo, hi) if rep % 2 == 0 else (hi, lo)
        for name in order:
            cpu = {n: render[name](n, rep + 1, out / f"cost-{name}.exr") for n in counts}
            diffs[name].append((cpu[hi] - cpu[lo]) / (hi - lo))
    return {name: {"cpu_s_per_spp": statistics.median(d), "range": [min(d), max(d)],
                   "runs": [round(x, 5) for x in d]} for name, d in diffs.items()}


def equal_time(render, names, seeds, budgets, threads, cost, ref, away, out):
    """Renders every seed with each renderer at the spp its cost buys in each budget (seconds of
    all threads) and returns, per budget, the spp, the errors per seed, and pt's ratios to Cycles'."""
    results = []
    for seconds in budgets:
        spp = {name: max(1, round(seconds * threads / cost[name]["cpu_s_per_spp"])) for name in names}
        rows = {name: [] for name in names}
        cpu = {name: [] for name in names}
        for i, seed in enumerate(seeds):
            for name in (names if i % 2 == 0 else names[::-1]):
                path = out / f"{name}{seed}-{seconds:g}s.exr"
                cpu[name].append(render[name](spp[name], seed, path))
                e = errors(read_rgb(path), ref, away)
                rows[name].append({"seed": seed, "rmse": round(e["mse"] ** 0.5, 6),
                                   "rmse_away": round(e["mse_away"] ** 0.5, 6), "mape": round(e["mape"], 6)})
        keys = ("rmse", "rmse_away", "mape")
        med = {name: {k: statistics.median(r[k] for r in rs) for k in keys} for name, rs in rows.items()}
        mean_mse = {name: {k: float(np.mean([r[k] ** 2 for r in rs])) for k in ("rmse", "rmse_away")}
                    for name, rs in rows.items()}
        over = {}
        for name in names[1:]:
            per_seed = [{k: round(a[k] / b[k], 3) for k in keys} for a, b in zip(rows[name], rows["cycles"])]
            over[name] = {
                "from_mean_mse": {"rmse": round((mean_mse[name]["rmse"] / mean_mse["cycles"]["rmse"]) ** 0.5, 3),
                                  "rmse_away_from_light": round((mean_mse[name]["rmse_away"]
                                                                 / mean_mse["cycles"]["rmse_away"]) ** 0.5, 3),
                                  "mape": round(float(np.mean([r["mape"] for r in rows[name]]))
                                                / float(np.mean([r["mape"] for r in rows["cycles"]])), 3)},
                "of_medians": {k: round(med[name][k] / med["cycles"][k], 3) for k in keys},
                "median_of_per_seed": {k: statistics.median(r[k] for r in per_seed) for k in keys},
                "per_seed_range": {k: [min(r[k] for r in per_seed), max(r[k] for r in per_seed)] for k in keys},
                "per_seed": per_seed}
        results.append({"seconds": seconds, "budget_cpu_s": seconds * threads, "spp": spp,
                        "render_cpu_s_median": {name: statistics.median(c) for name, c in cpu.items()},
                        "median": med, "per_seed": rows, "over_cycles": over})
    return results


def main():
    env = os.environ.get
    scene = Path(env("CYCLES_SCENE", str(ROOT / "scenes" / "cornell-box" / "scene.json")))
    size, spp, ref_spp = env("CYCLES_SIZE", "256"), int(env("CYCLES_SPP", "16")), int(env("CYCLES_REF_SPP", "2048"))
    seeds = [int(s) for s in env("CYCLES_SEEDS", "1,2,3,4").split(",")]
    out = Path(env("CYCLES_OUT", str(ROOT / "build" / "bench" / "cycles_error")))
    blender, restir = env("BLENDER", "blender"), env("RESTIR_BIN", str(ROOT / "build" / "restir"))
    threads = int(env("CYCLES_THREADS", str(os.cpu_count())))
    out.mkdir(parents=True, exist_ok=True)
    wh = f"{size}x{size}"
    ref_path = out / f"ref-{scene.parent.name}-{size}-{ref_spp}.exr"
    if not ref_path.exists():
        cycles(blender, scene, wh, ref_spp, 0, ref_path, threads)
    ref = read_rgb(ref_path)
    lum = ref.mean(axis=2)
    h, w = lum.shape
    bright = np.pad(lum > 1.0, 2)
    near = np.any([bright[2 + dy:2 + dy + h, 2 + dx:2 + dx + w] for dy in range(-2, 3) for dx in range(-2, 3)], axis=0)
    render = {"cycles": lambda n, seed, path: cycles(blender, scene, wh, n, seed, path, threads),
              "pt": lambda n, seed, path: ours(restir, scene, wh, n, seed, path, threads),
              "pt_random": lambda n, seed, path: ours(restir, scene, wh, n, seed, path, threads,
                                                      {"sampler": "random"})}
    names = list(render)
    scene_name = str(scene.relative_to(ROOT)) if scene.is_relative_to(ROOT) else str(scene)
    if env("CYCLES_SECONDS"):
        budgets = [float(s) for s in env("CYCLES_SECONDS").split(",")]
        lo, hi = (int(s) for s in env("CYCLES_COST_SPP", "16,80").split(","))
        reps = int(env("CYCLES_COST_REPS", "5"))
        load_start = os.getloadavg()
        cost = cost_per_spp(render, names, lo, hi, reps, out)
        results = equal_time(render, names, seeds, budgets, threads, cost, ref, ~near, out)
        print(json.dumps({"scene": scene_name, "size": wh, "threads": threads, "reference_spp": ref_spp,
                          "seeds": seeds, "pixels_near_light": int(near.sum()),
                          "cost": {"spp": [lo, hi], "repetitions": reps, **cost},
                          "loadavg": {"start": load_start, "end": os.getloadavg()},
                          "equal_time": results}, indent=1))
        return
    rows = {name: [] for name in names}
    for seed in seeds:
        for name in names:
            render[name](spp, seed, out / f"{name}{seed}.exr")
        for name in rows:
            rows[name].append(errors(read_rgb(out / f"{name}{seed}.exr"), ref, ~near))
    mean = {name: {k: float(np.mean([r[k] for r in rs])) for k in rs[0]} for name, rs in rows.items()}
    ratios = {name: {"rmse": round(float(np.sqrt(mean[name]["mse"] / mean["cycles"]["mse"])), 3),
                     "rmse_away_from_light": round(float(np.sqrt(mean[name]["mse_away"] / mean["cycles"]["mse_away"])), 3),
                     "mape": round(mean[name]["mape"] / mean["cycles"]["mape"], 3)}
              for name in ("pt", "pt_random")}
    # Near the light, error can be variance or a bias that no seed changes (a sample position fixed
    # per pixel): the per-pixel variance over the seeds tells them apart.
    spread = {}
    for name in names:
        imgs = np.array([read_rgb(out / f"{name}{seed}.exr").mean(axis=2) for seed in seeds])
        var = imgs.var(axis=0, ddof=1) if len(seeds) > 1 else np.zeros_like(imgs[0])
        spread[name] = {"variance_near_light": float(var[near].mean()), "variance_away": float(var[~near].mean())}
    print(json.dumps({"scene": scene_name, "size": wh, "threads": threads, "spp": spp, "reference_spp": ref_spp,
                      "seeds": seeds, "pixels_near_light": int(near.sum()), "mean": mean, "over_cycles": ratios,
                      "variance_over_seeds": spread}, indent=1))


if __name__ == "__main__":
    main()
