#!/usr/bin/env python3
"""bench/restir_sss.py — `make bench`: path tracing against ReSTIR SSS on the translucent region,
error against time (as [ReSTIR SSS Fig. 6]), over scaled mean free paths (as Fig. 9), and the hybrid
criterion's choice per pixel (Fig. 4).

Benchmarks are not tests: nothing here passes or fails on a timing. In one
run, on scenes/translucent at 128x128 (BENCH_SSS_SIZE), for each mean-free-path scale k
(BENCH_SSS_MFP_SCALES, "1 4 16"; k = 1 is the scene as it is, k > 1 a copy in build/bench/ with
every translucent material's mfp times k: [ReSTIR SSS §6] finds the method gains little with short
mean free paths and one dominant light (Fig. 8) and more as they grow (Fig. 9); its Fig. 6 is a
"highly scattering object"):
  1. a reference: `pt` at REF_SPP, cached in build/refs/ under the scene file's hash, the size
     and the spp;
  2. the translucent region: pixels whose primary hit is on a translucent material, from
     build/bench/sss_hybrid_map (bench/sss_hybrid_map.c, built here against librenderer.a),
     which also writes the hybrid criterion's choice per pixel (k = 1: build/bench/restir_sss_hybrid.exr;
     blue = reconnection, yellow = delayed, grey = translucent without a sample);
  3. RMSE on the region against the reference: `pt` at 1, 2, 4 ... 32 spp and `restir_sss` with
     each shift (reconnection, delayed, hybrid, sequential in its exact mode) at 1, 2 and 4
     candidates, with each target (luminance: one reservoir per pixel; per_channel: one per colour
     channel), each the median over SEEDS seeds; restir_sss's image is the frame after WARMUP
     frames of one session (`restir render`; errors do not depend on the machine's load);
  4. time, frame by frame in one daemon (bench/daemon.py), as restir_pt's frame cost: pt sessions
     at 1, 4 and 16 spp live throughout; each restir_sss setting gets a session, WARMUP frames,
     then ROUNDS rounds of one restir_sss frame and one frame of each pt session. A round puts
     the restir_sss frame's time on pt's time curve of that round (linear in spp between the
     three), which gives the spp pt affords in the same time; its median over the rounds,
     with quartiles, is the equal-time spp. On a machine whose speed drifts by tens of per cent
     within seconds, times of separate renders moved the equal-time ratio by as much;
  5. the equal-time ratio RMSE(restir_sss) / RMSE(pt at the equal-time spp, log-log interpolated
     in spp) (the issue's target: the best shift at <= 0.5);
  6. writes build/bench/restir_sss.json and one chart per scale (build/bench/restir_sss.svg for
     k = 1, restir_sss_mfp<k>.svg), prints Markdown tables (medians over the seeds) and a summary
     of the best shift per scale.
Environment: BENCH_SSS_SEEDS (3), BENCH_SSS_REF_SPP (2048), BENCH_SSS_WARMUP (16),
BENCH_SSS_SHIFTS ("reconnection delayed hybrid sequential"), BENCH_SSS_CANDIDATES ("1 2 4"),
BENCH_SSS_TARGETS ("luminance per_channel"),
BENCH_SSS_MFP_SCALES ("1 4 16"), BENCH_SSS_ROUNDS (16), BENCH_SSS_PARAMS (a JSON object of more session params, "{}"),
BENCH_SSS_MAX_DEPTH (unset: every method's default of 64; 1 is the direct-lighting case of [ReSTIR SSS §3],
paths camera - entry - exit - light, which its evaluation and Fig. 6 use: pt, its reference and
restir_sss all get this max_depth, so on the translucent region both estimate exactly the paths
restir_sss's reservoirs hold and restir_sss has no path-traced rest there; outputs get a
"_depth<N>" suffix), BENCH_THREADS (all cores).
`--charts` redraws the charts from the last run's JSON (same BENCH_SSS_MAX_DEPTH) without measuring."""
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
from daemon import Daemon  # noqa: E402
from exrimage import read_rgb  # noqa: E402
from svgplot import loglog  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
BIN = os.environ.get("RESTIR_BIN", str(ROOT / "build" / "restir"))
RESTIRD = os.environ.get("RESTIRD_BIN", str(ROOT / "build" / "restird"))
OUT = ROOT / "build" / "bench"
REFS = ROOT / "build" / "refs"
SCENE = ROOT / "scenes" / "translucent" / "scene.json"
SIZE = os.environ.get("BENCH_SSS_SIZE", "128x128")
SEEDS = int(os.environ.get("BENCH_SSS_SEEDS", "3"))
REF_SPP = int(os.environ.get("BENCH_SSS_REF_SPP", "2048"))
WARMUP = int(os.environ.get("BENCH_SSS_WARMUP", "16"))
THREADS = os.environ.get("BENCH_THREADS", "0")
PT_SPPS = [1, 2, 4, 8, 16, 32]
PT_TIMED_SPPS = [1, 4, 16]
ROUNDS = int(os.environ.get("BENCH_SSS_ROUNDS", "16"))
SHIFTS = [x for x in os.environ.get("BENCH_SSS_SHIFTS", "reconnection delayed hybrid sequential").split()]
CANDIDATES = [int(c) for c in os.environ.get("BENCH_SSS_CANDIDATES", "1 2 4").split()]
TARGETS = os.environ.get("BENCH_SSS_TARGETS", "luminance per_channel").split()
# More session params for every restir_sss run, e.g. '{"expected_shading": false}'.
EXTRA = json.loads(os.environ.get("BENCH_SSS_PARAMS", "{}"))
MFP_SCALES = [float(k) for k in os.environ.get("BENCH_SSS_MFP_SCALES", "1 4 16").split()]
MAX_DEPTH = int(os.environ["BENCH_SSS_MAX_DEPTH"]) if os.environ.get("BENCH_SSS_MAX_DEPTH") else None
DEPTH_ARGS = ["--max-depth", str(MAX_DEPTH)] if MAX_DEPTH is not None else []
DEPTH_PARAMS = {"max_depth": MAX_DEPTH} if MAX_DEPTH is not None else {}
SUFFIX = f"_depth{MAX_DEPTH}" if MAX_DEPTH is not None else ""


def run(args):
    res = subprocess.run([BIN, *args, "--threads", THREADS], capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"bench: {' '.join(args)}: {res.stderr.strip()}")
    return json.loads(res.stdout)


def scaled_scene(k):
    """The scene with every translucent material's mean free path times k (k = 1: the scene itself).
    The copy lives in build/bench/, so the scene must not name files relative to its folder."""
    if k == 1:
        return SCENE
    doc = json.loads(SCENE.read_text())
    for m in doc["materials"].values():
        if m.get("type") == "translucent":
            m["mfp"] = [x * k for x in m["mfp"]]
    path = OUT / f"translucent-mfp{k:g}" / "scene.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1))
    return path


def reference(scene):
    key = hashlib.sha256(scene.read_bytes()).hexdigest()[:16]
    REFS.mkdir(parents=True, exist_ok=True)
    ref = REFS / f"translucent-{SIZE}-{REF_SPP}spp{SUFFIX}-{key}.exr"
    if not ref.exists():
        print(f"bench: rendering the reference {ref.name} ...", file=sys.stderr, flush=True)
        run(["render", str(scene), "--spp", str(REF_SPP), "--size", SIZE, "--seed", "999", *DEPTH_ARGS, "--json",
             "-o", str(ref)])
    return read_rgb(ref)


def region_map(scene, out):
    tool = OUT / "sss_hybrid_map"
    counts = json.loads(subprocess.run([str(tool), str(scene), SIZE, str(out), "16"], capture_output=True, text=True,
                                       check=True).stdout)
    img = read_rgb(out)
    mask = img.sum(axis=2) > 0  # every class but "not translucent" has a colour
    return mask, counts


def rmse(img, ref, mask):
    d = (img - ref)[mask]
    return float(np.sqrt(np.mean(d * d)))


def spp_at(pt_ms, t):
    """The spp a pt frame affords in time t, on the curve through (spp, ms) of PT_TIMED_SPPS
    (linear; beyond its ends, the nearest segment's line)."""
    pts = list(zip(PT_TIMED_SPPS, pt_ms))
    for (n0, t0), (n1, t1) in zip(pts, pts[1:]):
        if t <= t1 or (n1, t1) == pts[-1]:
            return max(n0 + (t - t0) * (n1 - n0) / (t1 - t0), 0.25)
    return pts[-1][0]


def timed(d, scene_id, params):
    """One restir_sss setting against pt, frame by frame in daemon `d` (see the module doc): its
    median frame ms, pt's median ms per timed spp, and the equal-time spp with its quartiles."""
    w, h = (int(v) for v in SIZE.split("x"))
    pts = [d.session(scene_id, "pt", w, h, {"spp": n, **DEPTH_PARAMS}) for n in PT_TIMED_SPPS]
    s = d.session(scene_id, "restir_sss", w, h, params)
    try:
        for _ in range(WARMUP):
            d.frame_ms(s)
        ms, pt_ms, spp = [], [[] for _ in pts], []
        for _ in range(ROUNDS):
            ms.append(d.frame_ms(s))
            for i, p in enumerate(pts):
                pt_ms[i].append(d.frame_ms(p))
            spp.append(spp_at([c[-1] for c in pt_ms], ms[-1]))
    finally:
        for x in [s, *pts]:
            d.delete(x)
    q1, _, q3 = statistics.quantiles(spp, n=4)
    return {"ms": statistics.median(ms), "pt_ms": [statistics.median(c) for c in pt_ms],
            "cost": statistics.median(t / p for t, p in zip(ms, pt_ms[0])),
            "spp": statistics.median(spp), "spp_q1": q1, "spp_q3": q3}


def interp_loglog(points, x):
    """pt's RMSE at x (spp), log-log interpolation (or extrapolation from the nearest pair)."""
    pts = sorted(points)
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        if x <= x1 or (x1, y1) == pts[-1]:
            t = (math.log(x) - math.log(x0)) / (math.log(x1) - math.log(x0))
            return math.exp(math.log(y0) + t * (math.log(y1) - math.log(y0)))
    return pts[-1][1]


def measure(d, scene, label, title, img_path):
    """One scale: pt's curve and every restir_sss setting on `scene`; files named after `label`."""
    ref = reference(scene)
    mask, counts = region_map(scene, OUT / f"{label}_hybrid.exr")
    scene_id = f"bench-{label.replace('_', '-')}"
    d.put_scene(scene_id, scene.read_text())
    res = {"region_pixels": int(mask.sum()), "hybrid_choice": counts, "pt": [], "restir_sss": {}}
    for spp in PT_SPPS:
        err = []
        for s in range(SEEDS):
            run(["render", str(scene), "--spp", str(spp), "--size", SIZE, "--seed", str(s), *DEPTH_ARGS, "--json",
                 "-o", str(img_path)])
            err.append(rmse(read_rgb(img_path), ref, mask))
        res["pt"].append({"spp": spp, "rmse": statistics.median(err)})
    pt_pts = [(x["spp"], x["rmse"]) for x in res["pt"]]
    pt_ms = []
    for shift, target, cand in ((sh, tg, c) for sh in SHIFTS for tg in TARGETS for c in CANDIDATES):
        params = {"shift": shift, "candidates": cand, "target": target, **DEPTH_PARAMS, **EXTRA}
        err, fails = [], []
        for s in range(SEEDS):
            st = run(["render", str(scene), "--method", "restir_sss", "--frames", str(WARMUP), "--size", SIZE,
                      "--seed", str(s), "--params", json.dumps(params), "--json", "-o", str(img_path)])
            err.append(rmse(read_rgb(img_path), ref, mask))
            lf = st["last_frame"]
            fails.append(lf["shift_failures"] / max(lf["shifts"], 1))
        t = timed(d, scene_id, params)
        pt_ms.append(t["pt_ms"])
        e, pt_e = statistics.median(err), interp_loglog(pt_pts, t["spp"])
        name = f"{shift}, {cand} cand." + (", per_channel" if target == "per_channel" else "")
        res["restir_sss"][name] = {
            "shift": shift, "target": target, "candidates": cand, "rmse": e, "shift_failure_rate": statistics.median(fails), **t,
            "pt_rmse_at_equal_time": pt_e, "ratio": e / pt_e,
            "ratio_range": [e / interp_loglog(pt_pts, t["spp_q1"]), e / interp_loglog(pt_pts, t["spp_q3"])]}
    # pt's time per timed spp: the median over every setting's rounds' medians.
    res["pt_ms"] = {n: statistics.median(m[i] for m in pt_ms) for i, n in enumerate(PT_TIMED_SPPS)} if pt_ms else {}
    draw(res, label, title, SIZE)
    return res


def draw(res, label, title, size):
    """One scale's chart. Its time axis is in 1-spp pt frames: pt at its timed spp, restir_sss at
    its cost (the median of its rounds' frame time over the round's 1-spp pt frame)."""
    t1 = res["pt_ms"].get(1) or res["pt_ms"].get("1")
    pt_ms = {int(n): m for n, m in res["pt_ms"].items()}
    pt_curve = [(pt_ms[x["spp"]] / t1, x["rmse"]) for x in res["pt"] if x["spp"] in pt_ms] if t1 else []
    settings = list(res["restir_sss"].values())
    shifts = list(dict.fromkeys(v["shift"] for v in settings))
    targets = list(dict.fromkeys(v.get("target", "luminance") for v in settings))
    loglog(OUT / f"{label}.svg", f"{title}, {size}: RMSE on the translucent region against time",
           "frame time (1-spp pt frames)", "RMSE", [("pt, 1/4/16 spp", pt_curve, "line")] +
           # A shift's colour for both targets; per_channel dashed.
           [(shift + ("" if target == "luminance" else f", {target}"),
             [(v["cost"], v["rmse"]) for v in settings if (v["shift"], v.get("target", "luminance")) == (shift, target)],
             "line" if target == "luminance" else "dashed", 1 + k) for k, shift in enumerate(shifts) for target in targets])


def redraw():
    """--charts: the charts again from build/bench/restir_sss<suffix>.json, without measuring."""
    results = json.loads((OUT / f"restir_sss{SUFFIX}.json").read_text())
    for k, res in results["scales"].items():
        label = ("restir_sss" if k == "1" else f"restir_sss_mfp{k}") + SUFFIX
        depth = results.get("max_depth")
        title = ("translucent" if k == "1" else f"translucent, mean free path x{k}") + \
            (f", max depth {depth}" if depth is not None else "")
        draw(res, label, title, results["size"])


def main():
    if "--charts" in sys.argv[1:]:
        redraw()
        return
    OUT.mkdir(parents=True, exist_ok=True)
    ctool.build("sss_hybrid_map")
    results = {"size": SIZE, "max_depth": MAX_DEPTH, "ref_spp": REF_SPP, "warmup": WARMUP, "seeds": SEEDS, "rounds": ROUNDS, "scales": {}}
    d = Daemon(RESTIRD, THREADS)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            img_path = Path(tmp) / "img.exr"
            for k in MFP_SCALES:
                label = ("restir_sss" if k == 1 else f"restir_sss_mfp{k:g}") + SUFFIX
                print(f"bench: translucent, mean free path x{k:g} ...", file=sys.stderr, flush=True)
                title = ("translucent" if k == 1 else f"translucent, mean free path x{k:g}") + \
                    (f", max depth {MAX_DEPTH}" if MAX_DEPTH is not None else "")
                results["scales"][f"{k:g}"] = measure(d, scaled_scene(k), label, title, img_path)
    finally:
        d.close()
    (OUT / f"restir_sss{SUFFIX}.json").write_text(json.dumps(results, indent=1))
    for k, res in results["scales"].items():
        depth = f", max depth {MAX_DEPTH}" if MAX_DEPTH is not None else ""
        print(f"## translucent, mean free path x{k}{depth}, {SIZE}, RMSE on the translucent region "
              f"({res['region_pixels']} pixels), median of {SEEDS} seeds, reference pt {REF_SPP} spp\n")
        print("pt's RMSE per spp: " + ", ".join(f"{x['spp']} spp {x['rmse']:.4f}" for x in res["pt"]) +
              "; pt's frame ms in the rounds: " + ", ".join(f"{n} spp {m:.1f}" for n, m in res["pt_ms"].items()) + "\n")
        print("| restir_sss | frame ms | cost (1-spp pt frames) | RMSE | equal-time pt spp [quartiles] | "
              "pt RMSE at equal time | ratio [range] | shift failures |")
        print("|---|---|---|---|---|---|---|---|")
        for name, v in res["restir_sss"].items():
            print(f"| {name} | {v['ms']:.1f} | {v['cost']:.2f} | {v['rmse']:.4f} | "
                  f"{v['spp']:.2f} [{v['spp_q1']:.2f}–{v['spp_q3']:.2f}] | {v['pt_rmse_at_equal_time']:.4f} | "
                  f"{v['ratio']:.2f} [{min(v['ratio_range']):.2f}–{max(v['ratio_range']):.2f}] | "
                  f"{100 * v['shift_failure_rate']:.0f} % |")
        print(f"\nhybrid criterion's choice (initial samples, 16 candidates): {json.dumps(res['hybrid_choice'])}\n")
    print("## Best setting per mean-free-path scale (equal-time RMSE ratio to pt; target <= 0.5)\n")
    print("| mfp scale | best setting | cost (1-spp pt frames) | RMSE | ratio [range] | best of each shift |")
    print("|---|---|---|---|---|---|")
    for k, res in results["scales"].items():
        if not res["restir_sss"]:
            continue
        name, v = min(res["restir_sss"].items(), key=lambda kv: kv[1]["ratio"])
        per_shift = ", ".join(f"{sh} {min(x['ratio'] for x in res['restir_sss'].values() if x['shift'] == sh):.2f}"
                              for sh in SHIFTS)
        print(f"| x{k} | {name} | {v['cost']:.2f} | {v['rmse']:.4f} | {v['ratio']:.2f} "
              f"[{min(v['ratio_range']):.2f}–{max(v['ratio_range']):.2f}] | {per_shift} |")
    print("\ncharts: " + ", ".join(str(OUT / (("restir_sss" if k == "1" else f"restir_sss_mfp{k}") + SUFFIX + ".svg"))
                                   for k in results["scales"]))


if __name__ == "__main__":
    main()
