#!/usr/bin/env python3
"""bench/sms.py — `make bench`: path tracing against specular manifold sampling (`sms`), its
sample-space partitioning with per-frame priors (`sms_ssp`) and ReSTIR over its samples
(`restir_sms`): error against time, and [SMS-SSP Table 1]'s statistics (prior construction and
manifold sampling, sms / sms_ssp).

Benchmarks are not tests: nothing here passes or fails on a timing. On
refractive-slab and reflective-plane at 128x128 (BENCH_SMS_SCENES, BENCH_SMS_SIZE):
  1. a reference per scene: `pt` subset rest at REF_SPP plus `sms` caustics only, uncapped
     (or capped at BENCH_SMS_REF_CAP trials), at REF_SMS_SPP (path tracing alone does not
     converge on these caustics in any reasonable time; tests/test_sms.py shows the SMS part
     unbiased against path tracing restricted to the same paths), cached in build/refs/ under the scene files' hash and the spps; each part is two
     halves with independent seeds, whose difference estimates the reference's own RMSE: it is
     printed, drawn in the charts, and a ratio whose RMSEs are within 3x of it is flagged (uncapped
     SMS is heavy-tailed where the casters are bumpy, see BENCH_SMS_SCALE);
  2. `pt`, `sms` and `sms_ssp` (Bernoulli cap 128 and N = 16, as [SMS-SSP §6]) at 1, 2, 4 ...
     spp, over SEEDS seeds: render time and RMSE against the reference ([SMS-SSP] reports RMSE);
     `restir_sms` (same sampler, 1 candidate per pixel and frame, reuse on) as sessions of 1, 2,
     4 ... frames whose mean is the image and whose summed frame times are its time (the
     warm-up of the reservoirs is paid for, as an accumulating viewer would);
  3. Table 1 of `sms` and `sms_ssp` at 1 spp: prior construction (success rate, Newton steps
     per sample, ms) and manifold sampling (sample success rate, Newton steps per sample,
     Bernoulli trials per solution, Newton steps per solution, time in the estimates);
  4. the failure case of [SMS-SSP Fig. 10]: a prior that misses pairs (2 walks per block instead
     of 128; `prior: false` is the fallback everywhere) — RMSE at equal spp (sms_ssp) and equal
     frames (restir_sms);
  5. how bumpy the casters are: copies of both scenes with the wave numbers of their bumps
     scaled by each S of BENCH_SMS_BUMPS (1 2 3 4; the library's scenes have 1), written by
     scenes/refractive-slab/generate.py into build/bench/bumps-S/, and Table 1's manifold
     sampling statistics of `sms` and `sms_ssp` (N = 16 and 32, both [SMS-SSP]'s) at 1 spp on
     each, at BENCH_SMS_BUMPS_SIZE (128x128; not in the quick run);
  6. step 2's curves and real-time case again on the caustic component alone ([SMS-SSP Fig. 5] measures on a
     crop of the caustic): every SMS method with `caustics_only`, pt with subset "caustic",
     against the reference's SMS part. The rest of the image is one path-traced sample per pixel
     and frame in every method, and on reflective-plane its noise is most of a whole image's
     RMSE; here each method is measured on the paths it estimates itself;
  7. writes build/bench/sms.json, two SVG charts per scene (RMSE vs ms, log-log: the whole image,
     sms-<scene>.svg, and the caustic component, sms-<scene>-caustic.svg; each restir_sms
     variant's real-time case, its frame WARMUP + 1, as an open square) and prints Markdown
     tables (medians over the seeds); the real-time case (over STEADY_SEEDS sessions: its median
     and the root of its mean square) is also compared at equal time: one frame's RMSE against
     sms's curve at the same time per frame;
  8. beside the real-time case of the caustic component, what a frame shading one selected path
     per pixel and reservoir cannot go below whatever its reuse (build/bench/sms_floors,
     bench/sms_floors.c, built here against librenderer.a): the caustic's variation over a pixel
     (one jittered point per frame) and, with one reservoir for all lights, the colour of one path
     selected by luminance, as a fraction of a 1-spp sms frame's RMSE, and the equal-time ratio
     that leaves at restir_sms's time per frame (its default, a reservoir per light, has no colour
     part with the library's colourless casters).
With BENCH_SMS_SCALE=S, steps 1-4 run on the copies at scale S instead of the library's scenes
([SMS-SSP]'s regime: S = 3), and the outputs are named sms-bumps-S.json, sms-<scene>-bumps-S.svg.
Environment: BENCH_SMS_SEEDS (3), BENCH_SMS_STEADY_SEEDS (16: the real-time case's sessions), BENCH_SMS_REF_SPP (1024), BENCH_SMS_REF_SMS_SPP (256),
BENCH_SMS_REF_CAP (0: the caustic reference uncapped; [SMS-SSP Fig. 7] uses 1024),
BENCH_SMS_BUMPS ("1 2 3 4"; empty: no sweep), BENCH_SMS_BUMPS_SIZE (128x128), BENCH_SMS_SCALE
(unset), BENCH_SMS_TILES (unset: N = 16; outputs named sms-tiles-N.json, ...), BENCH_THREADS (all
cores); BENCH_SMS_QUICK=1 is a small run for a shared machine
(refractive-slab only, 32x32, 1 seed, shorter curves, reference 1024 + 1024 spp, no sweep) unless
those are set too. `--charts` redraws the charts from the last run's JSON without measuring."""
import hashlib
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ctool  # noqa: E402
from cputime import cli_frame_ms  # noqa: E402
from curves import loglog_at  # noqa: E402
from exrimage import read_rgb  # noqa: E402
from svgplot import loglog  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
BIN = os.environ.get("RESTIR_BIN", str(ROOT / "build" / "restir"))
OUT = ROOT / "build" / "bench"
REFS = ROOT / "build" / "refs"
QUICK = os.environ.get("BENCH_SMS_QUICK") == "1"
SCENES = os.environ.get("BENCH_SMS_SCENES", "refractive-slab" if QUICK else "refractive-slab reflective-plane").split()
# 128x128: the prior's 16 x 16 pixel blocks are a quarter of a 64x64 image, where a block mixes
# very different shading points ([SMS-SSP] renders 1920x1080), and the caustic's variation within a
# pixel is a larger part of the error (docs/benchmarks.md); 64x64 runs in a third of the time.
SIZE = os.environ.get("BENCH_SMS_SIZE", "32x32" if QUICK else "128x128")
SEEDS = int(os.environ.get("BENCH_SMS_SEEDS", "1" if QUICK else "3"))
# The real-time case's seeds: one restir_sms frame's RMSE is heavy-tailed (a rare candidate with a
# large weight can make most of a frame's error), so it is measured over more sessions than the
# curves and reported both as the median and as the root of the mean squared error over them
# (what a viewer sees on average over frames).
STEADY_SEEDS = int(os.environ.get("BENCH_SMS_STEADY_SEEDS", "1" if QUICK else "16"))
REF_SPP = int(os.environ.get("BENCH_SMS_REF_SPP", "1024"))
# The quick run's 32x32 reference can afford 4x the samples of the full run's 64x64 one (the
# ratios below need a reference well under the compared errors).
REF_SMS_SPP = int(os.environ.get("BENCH_SMS_REF_SMS_SPP", "1024" if QUICK else "256"))
# The caustic reference's Bernoulli cap: 0 (uncapped, unbiased) by default. Where the casters are
# bumpy, uncapped SMS is too heavy-tailed for any affordable reference; [SMS-SSP Fig. 7] renders its
# references with a cap of 1024, which bounds a solution's weight and loses the energy of
# solutions needing more trials (the methods here, capped at 128, lose more).
REF_CAP = int(os.environ.get("BENCH_SMS_REF_CAP", "0"))
THREADS = os.environ.get("BENCH_THREADS", "0")
PT_SPPS = [1, 4, 16, 64] if QUICK else [1, 4, 16, 64, 256]
SMS_SPPS = [1, 2, 4, 8] if QUICK else [1, 2, 4, 8, 16]
RESTIR_FRAMES = [1, 2, 4, 8, 16] if QUICK else [1, 2, 4, 8, 16, 32]
WARMUP = 16
SCALE = os.environ.get("BENCH_SMS_SCALE")
# N of the partitioned sampler in every sms_ssp and restir_sms run that does not set its own (unset:
# the methods' default, [SMS-SSP]'s 16).
TILES = os.environ.get("BENCH_SMS_TILES")
# The outputs of a run on the copies, or with other tiles, carry it in their names.
SUFFIX = (f"-bumps-{float(SCALE):g}" if SCALE else "") + (f"-tiles-{int(TILES)}" if TILES else "")
BUMPS = [float(x) for x in os.environ.get("BENCH_SMS_BUMPS", "" if QUICK else "1 2 3 4").split()]
# The prior works on 16 x 16 pixel blocks: at 64x64 a block is a sixteenth of the image and mixes
# very different shading points ([SMS-SSP] renders 1920x1080), so the sweep renders at 128x128.
BUMPS_SIZE = os.environ.get("BENCH_SMS_BUMPS_SIZE", "128x128")


def render(scene, out, method, params, seed, frames=None, extra=(), size=None):
    if TILES and method in ("sms_ssp", "restir_sms") and "tiles" not in params:
        params = {**params, "tiles": int(TILES)}
    cmd = [BIN, "render", str(scene), "--method", method, "--size", size or SIZE, "--seed", str(seed),
           "--threads", THREADS, "--params", json.dumps(params), "--json", "-o", str(out)]
    if method == "pt":
        cmd += ["--frames", "1"]
    if frames:
        # A session of `frames` frames: the image is their mean, the time their sum.
        cmd += ["--frames", str(frames), "--average-last", str(frames)]
    cmd += list(extra)
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"bench: {' '.join(cmd)}: {res.stderr.strip()}")
    return read_rgb(out), json.loads(res.stdout)


def reference(scene, tmp):
    """The whole image's reference, its caustic component's (the sms part), and each one's own
    RMSE. Each part is rendered as two halves with independent seeds: the reference is their mean,
    and RMS(half 1 - half 2) / 2 estimates the mean's own error (the halves' difference has twice
    a half's variance, the mean half of it). Uncapped SMS is heavy-tailed where basins are small: a
    rare solution found after thousands of trials makes a pixel hundreds of times its mean, and a
    reference holding one measures itself in every method's RMSE."""
    h = hashlib.sha256()
    for f in sorted(scene.parent.iterdir()):
        if f.suffix in (".json", ".obj"):
            h.update(f.read_bytes())
    h.update(f"{SIZE} {REF_SPP} {REF_SMS_SPP} halves".encode() + (f" cap {REF_CAP}".encode() if REF_CAP else b""))
    path = REFS / f"sms-bench-{scene.parent.name}-{h.hexdigest()[:16]}-halves.npy"
    if path.exists():
        rest1, rest2, caus1, caus2 = np.load(path)
    else:
        rest1, rest2 = (render(scene, tmp / f"ref_rest{i}.exr", "pt", {"spp": REF_SPP // 2, "subset": "rest"}, seed)[0]
                        for i, seed in ((1, 900001), (2, 900003)))
        caus1, caus2 = (render(scene, tmp / f"ref_caus{i}.exr", "sms",
                               {"spp": REF_SMS_SPP // 2, "caustics_only": True, "bernoulli_cap": REF_CAP}, seed)[0]
                        for i, seed in ((1, 900002), (2, 900004)))
        REFS.mkdir(parents=True, exist_ok=True)
        np.save(path, np.stack([rest1, rest2, caus1, caus2]))
    caus = (caus1 + caus2) / 2
    own = {"image": rmse(rest1 + caus1, rest2 + caus2) / 2, "caustic": rmse(caus1, caus2) / 2}
    return (rest1 + rest2) / 2 + caus, caus, own


def rmse(img, ref):
    return float(np.sqrt(np.mean((img - ref) ** 2)))


TOP_PIXELS = 10


def top_share(img, ref):
    """The share of an image's squared error held by its TOP_PIXELS worst pixels. Where a few
    candidates carry most of a frame's error (docs/benchmarks.md, "What stops the plane's reuse
    at S = 4"), the RMSE measures those pixels, and reuse that cannot dilute them leaves it."""
    e = np.sort(((img - ref) ** 2).sum(axis=-1).ravel())[::-1]
    total = float(e.sum())
    return float(e[:TOP_PIXELS].sum()) / total if total > 0 else 0.0


def table1(st, prior=None):
    n, sol = st["samples"], st["solutions"]
    row = {"success_rate": sol / n if n else 0.0, "newtons_per_sample": st["newton_sample"] / n if n else 0.0,
           "bernoulli_per_solution": st["trials"] / sol if sol else 0.0,
           "newtons_per_solution": (st["newton_sample"] + st["newton_trials"]) / sol if sol else 0.0,
           "sms_ms": st["sample_ms"], "capped": st["capped"],
           "prior_success": 0.0, "prior_newtons": 0.0, "prior_ms": 0.0}
    if prior and prior["samples"]:
        row.update(prior_success=prior["solutions"] / prior["samples"], prior_newtons=prior["newton"] / prior["samples"],
                   prior_ms=prior["ms"])
    return row


def bumpy_copies(scale):
    """Copies of refractive-slab and reflective-plane whose bumps have their wave numbers scaled."""
    d = OUT / f"bumps-{scale:g}"
    subprocess.run([sys.executable, str(ROOT / "scenes" / "refractive-slab" / "generate.py"), "--out", str(d),
                    "--slab-freq", str(scale), "--plane-freq", str(scale)], check=True)
    return d


def bumps_sweep(tmp):
    """Table 1's sampling statistics (sms, sms_ssp at 1 spp, medians over the seeds) on copies of
    both scenes whose bumps have their wave numbers scaled by each of BUMPS."""
    rows = []
    for scale in BUMPS:
        d = bumpy_copies(scale)
        for name in ("refractive-slab", "reflective-plane"):
            t = {}
            # sms_ssp with both tile counts of [SMS-SSP] (N = 16 and 32).
            for label, method, extra in (("sms", "sms", {}), ("sms_ssp", "sms_ssp", {}),
                                         ("sms_ssp32", "sms_ssp", {"tiles": 32})):
                rs = []
                for seed in range(SEEDS):
                    out = tmp / f"bumps-{scale:g}-{name}-{label}-{seed}.exr"
                    _, st = render(d / name / "scene.json", out, method, {"spp": 1, "bernoulli_cap": 128, **extra},
                                   seed, size=BUMPS_SIZE)
                    rs.append(table1(st["sms"], st.get("prior")))
                t[label] = {k: statistics.median(r[k] for r in rs) for k in rs[0]}
            rows.append({"scale": scale, "scene": name, **t})
    return rows


def print_bumps(rows):
    print(f"\n# How bumpy the casters are: sms / sms_ssp at 1 spp ({BUMPS_SIZE}, medians over {SEEDS} seeds; "
          "the wave numbers of the bumps scaled by S; the library's scenes have S = 1)\n")
    print("| S | scene | sms success | sms Bernoulli / solution | sms Newtons / solution | sms_ssp success (x sms) | "
          "sms_ssp Newtons / solution (x sms) | N = 32: success (x sms) | N = 32: Newtons / solution (x sms) |")
    print("|---|---|---|---|---|---|---|---|---|")

    def versus(a, b):
        rs = b["success_rate"] / a["success_rate"] if a["success_rate"] else float("nan")
        rn = b["newtons_per_solution"] / a["newtons_per_solution"] if a["newtons_per_solution"] else float("nan")
        return f"{100 * b['success_rate']:.1f} % ({rs:.2f}x) | {b['newtons_per_solution']:.1f} ({rn:.2f}x)"

    for r in rows:
        a = r["sms"]
        print(f"| {r['scale']:g} | {r['scene']} | {100 * a['success_rate']:.1f} % | {a['bernoulli_per_solution']:.2f} | "
              f"{a['newtons_per_solution']:.1f} | {versus(a, r['sms_ssp'])} | {versus(a, r['sms_ssp32'])} |")


# The runs of one measurement: (label, method, spps or frame counts, params).
IMAGE_RUNS = [("pt", "pt", PT_SPPS, {}), ("sms", "sms", SMS_SPPS, {"bernoulli_cap": 128}),
              ("sms_ssp", "sms_ssp", SMS_SPPS, {"bernoulli_cap": 128}),
              ("sms_ssp, prior of 2 walks per block", "sms_ssp", [4], {"prior_samples": 2}),
              ("sms_ssp, no prior (fallback)", "sms_ssp", [4], {"prior": False}),
              ("restir_sms", "restir_sms", RESTIR_FRAMES, {"bernoulli_cap": 128}),
              ("restir_sms, sms sampler", "restir_sms", RESTIR_FRAMES, {"bernoulli_cap": 128, "sampler": "sms"}),
              # The prior misses a light: one walk per block finds at most one of the two
              # (light, caster) pairs, so every block falls back to alpha = 0 for the other.
              ("restir_sms, prior misses a light (1 walk per block)", "restir_sms", [8], {"prior_samples": 1}),
              ("restir_sms, no prior (fallback)", "restir_sms", [8], {"prior": False})]
# The caustic component alone ([SMS-SSP Fig. 5] measures on a crop of the caustic): the paths SMS
# owns, which every method here but pt renders with its own estimator, while the rest of the image
# is one path-traced sample per pixel and frame in all of them. pt renders them as the filtered
# reference does (subset caustic).
CAUSTIC_RUNS = [("pt", "pt", PT_SPPS, {"subset": "caustic"}),
                ("sms", "sms", SMS_SPPS, {"bernoulli_cap": 128, "caustics_only": True}),
                ("sms_ssp", "sms_ssp", SMS_SPPS, {"bernoulli_cap": 128, "caustics_only": True}),
                ("restir_sms", "restir_sms", RESTIR_FRAMES, {"bernoulli_cap": 128, "caustics_only": True}),
                ("restir_sms, sms sampler", "restir_sms", RESTIR_FRAMES,
                 {"bernoulli_cap": 128, "sampler": "sms", "caustics_only": True})]
RATIOS = (("sms", "pt"), ("sms_ssp", "pt"), ("sms_ssp", "sms"), ("restir_sms", "sms"), ("restir_sms", "sms_ssp"),
          ("restir_sms, sms sampler", "sms"))


def measure(scene, name, ref, tmp, runs, tag):
    """Curves (median time, median RMSE per spp or frame count) of `runs`, Table 1 of sms and
    sms_ssp at 1 spp, and the real-time case: one frame after WARMUP frames of reuse."""
    curves = {label: [] for label, *_ in runs}
    t1 = {"sms": [], "sms_ssp": []}
    for label, method, spps, extra in runs:
        for spp in spps:
            ms, err = [], []
            for seed in range(SEEDS):
                # A new file per render: OpenImageIO caches images by file name.
                out = tmp / f"{name}-{tag}-{len(curves[label])}-{label[:12].replace(' ', '_')}-{spp}-{seed}.exr"
                if method == "restir_sms":
                    img, st = render(scene, out, method, extra, seed, frames=spp)
                else:
                    img, st = render(scene, out, method, {"spp": spp, **extra}, seed)
                ms.append(cli_frame_ms(st))
                err.append(rmse(img, ref))
                if label in t1 and spp == 1:
                    t1[label].append(table1(st["sms"], st.get("prior")))
            curves[label].append((statistics.median(ms), statistics.median(err), spp))
    # Real-time use ([SMS-SSP §6]: 1 spp per frame): the error of one frame after WARMUP frames of
    # reuse, with its time per frame (the warm-up's frames included).
    steady = {}
    for label, method, spps, params in runs:
        if method != "restir_sms" or label not in ("restir_sms", "restir_sms, sms sampler"):
            continue
        ms, err, top = [], [], []
        for seed in range(STEADY_SEEDS):
            out = tmp / f"{name}-{tag}-steady-{label[:14].replace(' ', '_')}-{seed}.exr"
            img, st = render(scene, out, method, params, seed, extra=["--frames", str(WARMUP + 1), "--average-last", "1",
                                                                    "--profile", "real-time"])
            ms.append(cli_frame_ms(st, WARMUP + 1))
            err.append(rmse(img, ref))
            top.append(top_share(img, ref))
        steady[label] = (statistics.median(ms), statistics.median(err), math.sqrt(sum(e * e for e in err) / len(err)),
                         sorted(err), statistics.median(top))
    table = {m: {k: statistics.median(r[k] for r in rows) for k in rows[0]} for m, rows in t1.items() if rows}
    return {"curves": curves, "steady": steady, "table1": table}


def floors(scene):
    """What one reservoir per pixel cannot go below, as a fraction of a 1-spp sms frame's RMSE."""
    run = subprocess.run([str(OUT / "sms_floors"), str(scene), SIZE], capture_output=True, text=True, check=True)
    return json.loads(run.stdout)


def at_time(curve, ms):
    """A curve's RMSE at time ms (curve: (ms, RMSE, spp) points)."""
    return loglog_at([(a, e) for a, e, _ in curve], ms)


# A measured RMSE m is sqrt(t^2 + r^2) for a method's own error t and the reference's r. At m >= 3 r,
# t >= 2.83 r and m overstates t by at most 6 %; below that a ratio of two RMSEs says more about
# the reference than about the methods, and the bench says so beside it.
NEAR_REFERENCE = 3.0


def near_reference(err, r):
    own = r.get("reference_rmse")
    return f" [within {NEAR_REFERENCE:g}x the reference's own RMSE {own:.3g}: not a measurement of the method]" \
        if own is not None and err < NEAR_REFERENCE * own else ""


def print_curves(name, r, what):
    if "reference_rmse" in r:
        print(f"\n{name} ({what}): the reference's own RMSE, from its two independent halves: {r['reference_rmse']:.4g}")
    print(f"\n| scene | method | spp (restir_sms: frames) | time (ms) | RMSE ({what}) |")
    print("|---|---|---|---|---|")
    for method, pts in r["curves"].items():
        for ms, err, spp in pts:
            print(f"| {name} | {method} | {spp} | {ms:.1f} | {err:.4g} |")
    # Equal time: the other curve's RMSE interpolated log-log at each point's time.
    for m, base in RATIOS:
        ref_curve = sorted(r["curves"][base])
        pairs = [(err, e) for ms, err, _ in r["curves"][m] if (e := at_time(ref_curve, ms))]
        if pairs:
            print(f"\n{name} ({what}): RMSE of {m} / {base} at equal time: median "
                  f"{statistics.median(a / b for a, b in pairs):.3f} over {len(pairs)} points"
                  + near_reference(min(min(p) for p in pairs), r))
        else:
            print(f"\n{name} ({what}): RMSE of {m} / {base} at equal time: the curves do not overlap in time")
    st = r["steady"]
    sms = sorted(r["curves"]["sms"])
    print(f"\n{name} ({what}), one frame after {WARMUP} frames of reuse, {STEADY_SEEDS} sessions (time per frame, "
          f"RMSE: median, root mean square over the sessions, each session's; the median share of a frame's "
          f"squared error in its {TOP_PIXELS} worst pixels): " +
          ", ".join(f"{k} {v[0]:.1f} ms {v[1]:.4g} {v[2]:.4g} [{' '.join(f'{e:.3g}' for e in v[3])}] "
                    f"{100 * v[4]:.0f} %" for k, v in st.items()))
    own = r.get("reference_rmse", 0.0)
    for k, (ms, err, rms, *_) in st.items():
        e = at_time(sms, ms)
        eq = f"{err / e:.3f} (root mean square: {rms / e:.3f})" if e else "outside the sms curve"
        if e and own and err > own and e > own:
            # The reference's error is independent of both: its variance adds to each mean square.
            eq += f"; without the reference's own error in either: {math.sqrt((err * err - own * own) / (e * e - own * own)):.3f}"
        print(f"{name} ({what}): RMSE of one {k} frame / sms 1 spp: {err / sms[0][1]:.3f} at {ms / sms[0][0]:.2f}x "
              f"its time per frame; / sms at the same time per frame: {eq}" + near_reference(err, r))
    f = r.get("floors")
    if f and "floor" in f:
        # sms at x times the time per frame has about 1/sqrt(x) of its 1-spp RMSE. restir_sms keeps
        # a reservoir per light by default: each light's paths have that light's colour here
        # (colourless casters), so only the jitter part is left to it.
        print(f"{name} ({what}): one selected path per pixel for all lights cannot go below {f['floor']:.3f} of a "
              f"1-spp sms frame's RMSE (jitter {f['jitter_floor']:.3f}, colour {f['colour_floor']:.3f}; "
              f"bench/sms_floors.c, {f['pixels']} pixels that see a receiver directly; expected shading averages "
              f"more than one path and can go somewhat below the colour part); one per light (restir_sms's default) "
              f"not below the jitter part, so no better than "
              + ", ".join(f"{f['jitter_floor'] * math.sqrt(ms / sms[0][0]):.3f} for one {k} frame"
                          for k, (ms, *_) in st.items())
              + " / sms at the same time per frame")


def charts(results):
    for name, r in results.items():
        for rr, path, title in ((r, f"sms-{name}{SUFFIX}.svg", f"{name}: RMSE vs time"),
                                (r["caustic"], f"sms-{name}-caustic{SUFFIX}.svg",
                                 f"{name}, caustic component: RMSE vs time")):
            labels = list(rr["curves"])
            # The curves (restir_sms: the mean of a session's frames), and each restir_sms variant's
            # real-time case (the median of one frame after WARMUP frames of reuse) as an open
            # square in its colour.
            series = [(m, [(a, b) for a, b, _ in pts], "line") for m, pts in rr["curves"].items()]
            series += [(f"{k}, frame {WARMUP + 1}", [(v[0], v[1])], "squares", labels.index(k))
                       for k, v in rr["steady"].items() if k in labels]
            if "reference_rmse" in rr:
                # Below this line a curve measures the reference's own noise more than the method.
                ms = [a for _, pts, *_ in series for a, _ in pts]
                series.append(("the reference's own RMSE", [(min(ms), rr["reference_rmse"]),
                                                              (max(ms), rr["reference_rmse"])], "dashed", 5))
            loglog(OUT / path, title, "render time (ms)", "RMSE", series)


def main():
    if "--charts" in sys.argv[1:]:
        # The charts again from the last run's JSON (same BENCH_SMS_SCALE and BENCH_SMS_TILES).
        charts(json.loads((OUT / f"sms{SUFFIX}.json").read_text())["scenes"])
        return
    OUT.mkdir(parents=True, exist_ok=True)
    results = {}
    ctool.build("sms_floors")
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        bumps = bumps_sweep(tmp)
        scenes = bumpy_copies(float(SCALE)) if SCALE else ROOT / "scenes"
        for name in SCENES:
            scene = scenes / name / "scene.json"
            ref, caustic_ref, own = reference(scene, tmp)
            results[name] = measure(scene, name, ref, tmp, IMAGE_RUNS, "image")
            results[name]["caustic"] = measure(scene, name, caustic_ref, tmp, CAUSTIC_RUNS, "caustic")
            results[name]["reference_rmse"] = own["image"]
            results[name]["caustic"]["reference_rmse"] = own["caustic"]
            results[name]["caustic"]["floors"] = floors(scene)
    (OUT / f"sms{SUFFIX}.json").write_text(json.dumps({"scenes": results, "bumps": bumps}, indent=1))
    where = f"bumps scaled by {SCALE}, {scenes.relative_to(ROOT)}/" if SCALE else "the library's scenes"
    print(f"# pt vs sms vs restir_sms ({where}; {SIZE}, medians over {SEEDS} seeds; reference: pt rest {REF_SPP} spp + "
          f"sms caustics {REF_SMS_SPP} spp " + (f"with a Bernoulli cap of {REF_CAP}" if REF_CAP else "uncapped") +
          ", each in two halves)\n")
    print("| scene | prior success | prior Newtons / sample | prior ms | success rate (sms / sms_ssp) | "
          "Newtons / sample | Bernoulli / solution | Newtons / solution | ms in the estimates (1 spp) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, r in results.items():
        a, b = r["table1"]["sms"], r["table1"]["sms_ssp"]
        print(f"| {name} | {100 * b['prior_success']:.1f} % | {b['prior_newtons']:.2f} | {b['prior_ms']:.1f} | "
              f"{100 * a['success_rate']:.1f} % / {100 * b['success_rate']:.1f} % | "
              f"{a['newtons_per_sample']:.2f} / {b['newtons_per_sample']:.2f} | "
              f"{a['bernoulli_per_solution']:.2f} / {b['bernoulli_per_solution']:.2f} | "
              f"{a['newtons_per_solution']:.2f} / {b['newtons_per_solution']:.2f} | "
              f"{a['sms_ms']:.1f} / {b['sms_ms']:.1f} |")
    for name, r in results.items():
        print_curves(name, r, "image")
        print_curves(name, r["caustic"], "caustic component")
    charts(results)
    if bumps:
        print_bumps(bumps)


if __name__ == "__main__":
    main()
