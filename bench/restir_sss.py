#!/usr/bin/env python3
"""bench/restir_sss.py — `make bench`: path tracing against ReSTIR SSS on the translucent region,
error against time (as seed 004 Fig. 6), and the hybrid criterion's choice per pixel (Fig. 4).

Benchmarks are not tests (design TESTING.md): nothing here passes or fails on a timing. In one
run, on scenes/translucent at 128x128 (BENCH_SSS_SIZE):
  1. a reference: `pt` at REF_SPP, cached in build/refs/ under the scene file's hash, the size
     and the spp;
  2. the translucent region: pixels whose primary hit is on a translucent material, from
     build/bench/sss_hybrid_map (bench/sss_hybrid_map.c, built here against librenderer.a),
     which also writes the hybrid criterion's choice per pixel to build/bench/restir_sss_hybrid.exr
     (blue = reconnection, yellow = delayed, grey = translucent without a sample);
  3. `pt` at 1, 2, 4 ... 32 spp and `restir_sss` with each shift (reconnection, delayed, hybrid,
     sequential in its exact mode) at 1, 2 and 4 candidates, each over SEEDS seeds: frame time and RMSE on the region against
     the reference. restir_sss's point is the frame after WARMUP frames of one session;
  4. the equal-time ratio RMSE(restir_sss) / RMSE(pt), pt's RMSE interpolated log-log at the
     restir_sss frame time (the issue's target: the best shift at <= 0.5);
  5. writes build/bench/restir_sss.json and build/bench/restir_sss.svg, prints Markdown tables
     (medians over the seeds).
Environment: BENCH_SSS_SEEDS (3), BENCH_SSS_REF_SPP (2048), BENCH_SSS_WARMUP (16),
BENCH_SSS_SHIFTS ("reconnection delayed hybrid sequential"), BENCH_SSS_CANDIDATES ("1 2 4"),
BENCH_SSS_PARAMS (a JSON object of more session params, "{}"), BENCH_THREADS (all cores)."""
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
import OpenImageIO as oiio

sys.path.insert(0, str(Path(__file__).resolve().parent))
from svgplot import loglog  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
BIN = os.environ.get("RESTIR_BIN", str(ROOT / "build" / "restir"))
OUT = ROOT / "build" / "bench"
REFS = ROOT / "build" / "refs"
SCENE = ROOT / "scenes" / "translucent" / "scene.json"
SIZE = os.environ.get("BENCH_SSS_SIZE", "128x128")
SEEDS = int(os.environ.get("BENCH_SSS_SEEDS", "3"))
REF_SPP = int(os.environ.get("BENCH_SSS_REF_SPP", "2048"))
WARMUP = int(os.environ.get("BENCH_SSS_WARMUP", "16"))
THREADS = os.environ.get("BENCH_THREADS", "0")
PT_SPPS = [1, 2, 4, 8, 16, 32]
SHIFTS = [x for x in os.environ.get("BENCH_SSS_SHIFTS", "reconnection delayed hybrid sequential").split()]
CANDIDATES = [int(c) for c in os.environ.get("BENCH_SSS_CANDIDATES", "1 2 4").split()]
# More session params for every restir_sss run, e.g. '{"expected_shading": false}'.
EXTRA = json.loads(os.environ.get("BENCH_SSS_PARAMS", "{}"))


def read_exr(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    try:
        px = inp.read_image(oiio.FLOAT)
    finally:
        inp.close()
    return np.asarray(px, dtype=np.float64)[..., :3]


def run(args):
    res = subprocess.run([BIN, *args, "--threads", THREADS], capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"bench: {' '.join(args)}: {res.stderr.strip()}")
    return json.loads(res.stdout)


def reference():
    key = hashlib.sha256(SCENE.read_bytes()).hexdigest()[:16]
    REFS.mkdir(parents=True, exist_ok=True)
    ref = REFS / f"translucent-{SIZE}-{REF_SPP}spp-{key}.exr"
    if not ref.exists():
        run(["render", str(SCENE), "--spp", str(REF_SPP), "--size", SIZE, "--seed", "999", "--json", "-o", str(ref)])
    return read_exr(ref)


def region_map():
    tool = OUT / "sss_hybrid_map"
    cflags = subprocess.run(["pkg-config", "--cflags", "OpenEXR"], capture_output=True, text=True).stdout.split()
    subprocess.run(["cc", "-O2", "-std=c17", "-D_DEFAULT_SOURCE", "-Irenderer", "bench/sss_hybrid_map.c",
                    "build/obj/librenderer.a", "-lOpenEXRCore", "-ldeflate", "-lembree3", "-lassimp", "-lcjson", "-lm",
                    "-pthread", *cflags, "-o", str(tool)], cwd=ROOT, check=True)
    out = OUT / "restir_sss_hybrid.exr"
    counts = json.loads(subprocess.run([str(tool), str(SCENE), SIZE, str(out), "16"], capture_output=True, text=True,
                                       check=True).stdout)
    img = read_exr(out)
    mask = img.sum(axis=2) > 0  # every class but "not translucent" has a colour
    return mask, counts


def rmse(img, ref, mask):
    d = (img - ref)[mask]
    return float(np.sqrt(np.mean(d * d)))


def frame_ms(st):
    lf = st.get("last_frame")
    if not lf:
        return st["time_ms"]
    return lf["gbuffer_ms"] + lf["initial_ms"] + lf["temporal_ms"] + lf["spatial_ms"] + lf["shade_ms"]


def interp_loglog(points, x):
    """pt's RMSE at time x, log-log interpolation (or extrapolation from the nearest pair)."""
    pts = sorted(points)
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        if x <= x1 or (x1, y1) == pts[-1]:
            t = (math.log(x) - math.log(x0)) / (math.log(x1) - math.log(x0))
            return math.exp(math.log(y0) + t * (math.log(y1) - math.log(y0)))
    return pts[-1][1]


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    ref = reference()
    mask, counts = region_map()
    results = {"size": SIZE, "ref_spp": REF_SPP, "warmup": WARMUP, "seeds": SEEDS, "region_pixels": int(mask.sum()),
               "hybrid_choice": counts, "pt": [], "restir_sss": {}}
    with tempfile.TemporaryDirectory() as tmp:
        img_path = Path(tmp) / "img.exr"
        for spp in PT_SPPS:
            ms, err = [], []
            for s in range(SEEDS):
                st = run(["render", str(SCENE), "--spp", str(spp), "--size", SIZE, "--seed", str(s), "--json",
                          "-o", str(img_path)])
                ms.append(st["time_ms"])
                err.append(rmse(read_exr(img_path), ref, mask))
            results["pt"].append({"spp": spp, "ms": statistics.median(ms), "rmse": statistics.median(err)})
        pt_pts = [(x["ms"], x["rmse"]) for x in results["pt"]]
        for shift in SHIFTS:
            for cand in CANDIDATES:
                ms, err, fails = [], [], []
                for s in range(SEEDS):
                    st = run(["render", str(SCENE), "--method", "restir_sss", "--frames", str(WARMUP), "--size", SIZE,
                              "--seed", str(s), "--params", json.dumps({"shift": shift, "candidates": cand, **EXTRA}), "--json",
                              "-o", str(img_path)])
                    ms.append(frame_ms(st))
                    err.append(rmse(read_exr(img_path), ref, mask))
                    lf = st["last_frame"]
                    fails.append(lf["shift_failures"] / max(lf["shifts"], 1))
                m, e = statistics.median(ms), statistics.median(err)
                results["restir_sss"][f"{shift}, {cand} cand."] = {
                    "shift": shift, "candidates": cand, "ms": m, "rmse": e, "shift_failure_rate": statistics.median(fails),
                    "pt_rmse_at_equal_time": interp_loglog(pt_pts, m), "ratio": e / interp_loglog(pt_pts, m)}
    (OUT / "restir_sss.json").write_text(json.dumps(results, indent=1))
    loglog(OUT / "restir_sss.svg", f"translucent, {SIZE}: RMSE on the translucent region against frame time",
           "frame time (ms)", "RMSE", [("pt, 1-32 spp", pt_pts, "line")] +
           [(shift, [(v["ms"], v["rmse"]) for v in results["restir_sss"].values() if v["shift"] == shift], "line")
            for shift in SHIFTS])
    print(f"## translucent, {SIZE}, RMSE on the translucent region ({results['region_pixels']} pixels), "
          f"median of {SEEDS} seeds, reference pt {REF_SPP} spp\n")
    print("| method | frame ms | RMSE | pt RMSE at equal time | ratio | shift failures |")
    print("|---|---|---|---|---|---|")
    for x in results["pt"]:
        print(f"| pt {x['spp']} spp | {x['ms']:.1f} | {x['rmse']:.4f} | | | |")
    for name, v in results["restir_sss"].items():
        print(f"| restir_sss {name} | {v['ms']:.1f} | {v['rmse']:.4f} | {v['pt_rmse_at_equal_time']:.4f} | "
              f"{v['ratio']:.2f} | {100 * v['shift_failure_rate']:.0f} % |")
    print(f"\nhybrid criterion's choice (initial samples, 16 candidates): {json.dumps(counts)}; "
          f"image: build/bench/restir_sss_hybrid.exr")


if __name__ == "__main__":
    main()
