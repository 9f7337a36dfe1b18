#!/usr/bin/python3
"""Direct light's per-pixel variance on the Cornell box: pt (`light_sampling` area and
solid_angle) against Blender Cycles, measured side by side in the same run.

Usage: /usr/bin/python3 bench/direct_light_cycles.py [--runs 4096] [--size 64] [--settings area,solid_angle]
           [--bin build/restir] [--params JSON] [--work DIR] [--maps FILE.npz] [--bootstrap 200]
           [--bsdf-only-runs 64 --bsdf-only-spp 1024]

Each renderer renders `--runs` single frames of 1 spp of direct light only, and the sample
variance of the luminance is taken per pixel over those frames (as bench/light_sampling.py does):
- pt: `restir render scenes/cornell-box/scene.json --method pt --frames 1 --seed S --params
  '{"light_sampling": X, "spp": 1, "max_depth": 1}'`, seeds 0..runs-1. max_depth 1 is the camera
  ray's hit (its emission), next-event estimation there and the emission the BSDF-sampled ray
  from it reaches, the two MIS-weighted (power heuristic);
- Cycles (Blender 3.4): bench/crosscheck_cycles.py with `--max-bounces 0 --spp 1 --sample-offset 1
  --runs N` in one Blender process (seeds from its run_seed). Cycles' max_bounces 0 is the same
  estimator: its path stops at the second hit (bounce 1 > 0) after that hit's emission is added
  with its MIS weight, before any light sampling there (max_bounces 1 adds a diffuse bounce).
  Cycles takes its sample 0 at the pixel's centre, so without the offset its 1-spp frames would
  leave out the variance of the pixel position that pt's include (on the back wall 0.67 of
  Cycles' variance measured against 0.70 with centre samples; the light's edge pixels far more).
  Cycles 3.4 picks an emissive triangle by area and, for the Cornell box's light, samples it by
  solid angle from every point (its test, longest edge^2 > (N0 . (V0 - P) / |N0|^2)^2 with
  N0 = e0 x e1 unnormalised, compares an edge with a distance over twice the area, and holds for
  any triangle of more than unit size here).
Both filter with a box of one pixel, a uniform position in the pixel per sample.

Printed (one JSON object), per crop of bench/light_sampling.py (at 64x64, scaled with --size):
- the mean images' agreement, which is what makes the variances comparable: each crop's mean per
  renderer, pt's over Cycles' with its standard error, and per pixel z = (mean_pt - mean_cycles) /
  sqrt(var_pt / N + var_cycles / N), whose mean should be about 0 and root mean square about 1.
  Cycles' light sampling is biased low on this scene (docs/crosscheck.md: -1.3 % on the upper
  back wall), which these show; --bsdf-only-runs adds the check that settles it, pt's crop means
  over those of Cycles with light sampling off (BSDF sampling only, unbiased), with the standard
  error of both;
- variance_ratio: each setting's mean per-pixel variance over Cycles' (the ratio of the crop's
  summed variances) and the mean of the per-pixel ratios, each with the standard deviation of a
  bootstrap over the frames (resampled with replacement, each renderer independently) and the two
  halves' values (frames 0..N/2-1 against N/2..N-1).

Environment: BLENDER (blender), the Debian package's 3.4 (not installed by scripts/install-deps.sh).
About 4 minutes for Cycles' 4096 frames and 4 for pt's 2 x 4096 on two loaded cores, 5 more for
--bsdf-only-runs 64 at 1024 spp. --work DIR keeps Cycles' frames (and reuses them when the
settings match), so that a scratch build of pt can be compared again with --bin and --settings
alone; --params adds pt parameters (e.g. '{"sampler": "random"}'); --maps writes the per-pixel
means and variances."""
import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from exrimage import read_rgb  # noqa: E402
from light_sampling import LUMINANCE, SCENE, crops  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def cycles_frames(blender, work, size, runs, seed, threads, spp=1, light_sampling="on"):
    """Luminance of Cycles' runs frames of direct light, runs x size x size (rendered into work
    unless there from a run with the same settings)."""
    name = "cycles" if light_sampling == "on" else "cycles-bsdf-only"
    stamp = {"scene": str(SCENE), "size": size, "runs": runs, "seed": seed, "max_bounces": 0, "spp": spp,
             "sample_offset": 1, "light_sampling": light_sampling}
    meta = work / f"{name}.json"
    paths = [work / f"{name}-{k}.exr" for k in range(runs)]
    if not (meta.exists() and json.loads(meta.read_text()) == stamp and all(p.exists() for p in paths)):
        cmd = [blender, "-b", "--factory-startup", "-P", str(ROOT / "bench" / "crosscheck_cycles.py"), "--",
               "--scene", str(SCENE), "--size", f"{size}x{size}", "--spp", str(spp), "--seed", str(seed),
               "--max-bounces", "0", "--sample-offset", "1", "--light-sampling", light_sampling,
               "--threads", str(threads), "--runs", str(runs), "--out", str(work / f"{name}-{{run}}.exr")]
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0 or not all(p.exists() for p in paths):
            sys.exit(f"direct_light_cycles: {' '.join(cmd)} failed:\n{res.stderr[-2000:]}")
        meta.write_text(json.dumps(stamp))
    return np.stack([read_rgb(p) @ LUMINANCE for p in paths]).astype(np.float32)


def pt_frames(binary, size, runs, setting, extra):
    """Luminance of pt's runs frames (seeds 0..runs-1), runs x size x size."""
    out = np.empty((runs, size, size), np.float32)
    params = json.dumps({"light_sampling": setting, "spp": 1, "max_depth": 1, **extra})
    with tempfile.TemporaryDirectory() as tmp:
        exr = Path(tmp) / "f.exr"
        for seed in range(runs):
            cmd = [binary, "render", str(SCENE), "--method", "pt", "--size", f"{size}x{size}", "--frames", "1",
                   "--seed", str(seed), "--params", params, "-o", str(exr)]
            res = subprocess.run(cmd, capture_output=True, text=True)
            if res.returncode != 0:
                sys.exit(f"direct_light_cycles: {' '.join(cmd)}: {res.stderr}")
            out[seed] = read_rgb(exr) @ LUMINANCE
    return out


def variance(x):
    """Per-pixel sample variance over axis 0 (float64)."""
    return np.var(x, axis=0, dtype=np.float64, ddof=1)


def ratios(x, ref):
    """(ratio of mean per-pixel variances, mean of per-pixel ratios) of frames x over frames ref
    (frames x pixels), over the pixels ref varies at."""
    vx, vr = variance(x), variance(ref)
    lit = vr > 0
    return float(vx[lit].sum() / vr[lit].sum()), float(np.mean(vx[lit] / vr[lit]))


def rounded(v, digits=4):
    return round(float(v), digits)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=4096)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--settings", default="area,solid_angle", help="pt's light_sampling values to measure")
    ap.add_argument("--bin", default=str(ROOT / "build/restir"))
    ap.add_argument("--params", default="{}", help="more of pt's parameters, a JSON object (e.g. the sampler)")
    ap.add_argument("--seed", type=int, default=0, help="Cycles' base seed (crosscheck_cycles.py's run_seed)")
    ap.add_argument("--cycles-threads", type=int, default=1)
    ap.add_argument("--bootstrap", type=int, default=200, help="bootstrap resamples (0: none)")
    ap.add_argument("--work", help="keep (and reuse) Cycles' frames here")
    ap.add_argument("--maps", help="also write each renderer's per-pixel mean and variance to this .npz")
    ap.add_argument("--bsdf-only-runs", type=int, default=0,
                    help="also check the means against Cycles without light sampling (BSDF sampling "
                         "only, unbiased): this many frames of --bsdf-only-spp (0: skip)")
    ap.add_argument("--bsdf-only-spp", type=int, default=1024)
    a = ap.parse_args()
    if a.runs < 4:
        ap.error("--runs must be at least 4")
    settings = [s for s in a.settings.split(",") if s]
    blender = os.environ.get("BLENDER", "blender")

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(a.work) if a.work else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        frames = {"cycles": cycles_frames(blender, work, a.size, a.runs, a.seed, a.cycles_threads)}
        bsdf_only = (cycles_frames(blender, work, a.size, a.bsdf_only_runs, a.seed + 1, a.cycles_threads,
                                   a.bsdf_only_spp, "off") if a.bsdf_only_runs > 1 else None)
    for s in settings:
        frames[s] = pt_frames(a.bin, a.size, a.runs, s, json.loads(a.params))

    if a.maps:
        np.savez(a.maps, **{f"{k}_{what}": f(v) for k, v in frames.items()
                            for what, f in (("mean", lambda v: v.mean(axis=0, dtype=np.float64)), ("var", variance))})
    n, half = a.runs, a.runs // 2
    rng = np.random.default_rng(12345)
    result = {"size": a.size, "runs": n, "pt_params": json.loads(a.params), "crops": {}}
    for name, (y0, y1, x0, x1) in crops(a.size).items():
        f = {k: v[:, y0:y1, x0:x1].reshape(n, -1).astype(np.float64) for k, v in frames.items()}
        ref = f["cycles"]
        mean_c, var_c = ref.mean(axis=0), variance(ref)
        c = {"rows": [y0, y1 - 1], "columns": [x0, x1 - 1], "mean": {"cycles": rounded(mean_c.mean(), 6)},
             "mean_over_cycles": {}, "z": {}, "variance_ratio": {}}
        for s in settings:
            mean_s, var_s = f[s].mean(axis=0), variance(f[s])
            c["mean"][s] = rounded(mean_s.mean(), 6)
            # Standard error of the crop mean's ratio (pixels independent; frames independent).
            se = np.sqrt(var_s.sum() + var_c.sum()) / np.sqrt(n) / mean_s.size
            c["mean_over_cycles"][s] = [rounded(mean_s.mean() / mean_c.mean()), rounded(se / mean_c.mean())]
            live = (var_s + var_c) > 0
            z = (mean_s - mean_c)[live] / np.sqrt((var_s + var_c)[live] / n)
            c["z"][s] = {"mean": rounded(z.mean(), 3), "rms": rounded(np.sqrt(np.mean(z * z)), 3)}
            of_sums, per_pixel = ratios(f[s], ref)
            h1, h2 = ratios(f[s][:half], ref[:half]), ratios(f[s][half:], ref[half:])
            boot = []
            for _ in range(a.bootstrap):
                boot.append(ratios(f[s][rng.integers(0, n, n)], ref[rng.integers(0, n, n)]))
            sd = np.std(boot, axis=0, ddof=1) if a.bootstrap > 1 else [float("nan")] * 2
            c["variance_ratio"][s] = {
                "of_means": [rounded(of_sums, 3), rounded(sd[0], 3)],
                "per_pixel": [rounded(per_pixel, 3), rounded(sd[1], 3)],
                "halves_of_means": [rounded(h1[0], 3), rounded(h2[0], 3)]}
        if bsdf_only is not None:
            b = bsdf_only[:, y0:y1, x0:x1].mean(axis=(1, 2), dtype=np.float64)
            pt = f[settings[0]]
            ratio = pt.mean() / b.mean()
            rel_se_pt = np.sqrt(variance(pt).sum() / n) / pt.shape[1] / pt.mean()
            rel_se_b = b.std(ddof=1) / np.sqrt(b.size) / b.mean()
            c["pt_over_cycles_bsdf_only"] = [rounded(ratio), rounded(ratio * np.hypot(rel_se_pt, rel_se_b))]
        c["variance_cycles"] = rounded(var_c.mean(), 8)
        result["crops"][name] = c
    result["format"] = ("mean_over_cycles: [ratio, standard error]; variance_ratio (pt over Cycles): of_means and "
                        "per_pixel [value, bootstrap standard deviation], halves_of_means [frames 0..N/2-1, N/2..N-1]")
    result["commands"] = {
        "pt": ("restir render scenes/cornell-box/scene.json --method pt --frames 1 --seed S --params "
               f"'{{\"light_sampling\": X, \"spp\": 1, \"max_depth\": 1}}' --size {a.size}x{a.size}, S = 0..{n - 1}"),
        "cycles": ("blender -b --factory-startup -P bench/crosscheck_cycles.py -- --scene scenes/cornell-box/scene.json "
                   f"--size {a.size}x{a.size} --spp 1 --seed {a.seed} --max-bounces 0 --sample-offset 1 "
                   f"--threads {a.cycles_threads} "
                   f"--runs {n} --out DIR/cycles-{{run}}.exr")}
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
