#!/usr/bin/env python3
"""bench/restir_pt.py — `make bench`: path tracing against ReSTIR PT, error against time.

Benchmarks are not tests: nothing here passes or fails on a timing. In one
run, on cornell-box, cornell-glossy and door-ajar at 256x256 (BENCH_RESTIR_SCENES, _SIZE):
  1. a reference per scene: `pt` at REF_SPP, cached in build/refs/ under the scene file's hash,
     the size and the spp (delete the folder to re-render);
  2. `pt` at 1, 2, 4 ... 64 spp and `restir_pt` (default parameters, and with more spatial
     reuse), each over SEEDS seeds: frame time and MAPE ([ReSTIR BDPT footnote 3], `restir compare`)
     against the reference. restir_pt's point is the frame after 32 warm-up frames of one
     session: single-frame quality, as a session delivers it;
  3. the equal-time error ratio restir_pt / pt (pt's MAPE interpolated log-log at restir_pt's
     frame time) and the frame cost ratio restir_pt / pt at 1 spp, from frames of the two
     rendered in turn by one daemon (measure_frame_cost);
  4. an ablation on door-ajar as [ReSTIR PT Enhanced Table 1]: pass times and MAPE with each Enhanced
     feature switched off in turn;
  5. writes build/bench/restir_pt.json, one SVG chart per scene (MAPE vs ms, log-log) in
     build/bench/, and prints Markdown tables (medians over the seeds).
Environment: BENCH_RESTIR_SEEDS (3), BENCH_RESTIR_REF_SPP (2048), BENCH_RESTIR_WARMUP (32),
BENCH_THREADS (all cores), BENCH_RESTIR_ABLATION (door-ajar; empty = skip), BENCH_RESTIR_COST_ROUNDS
(48), RESTIR_BIN and RESTIRD_BIN (build/restir, build/restird).
`bench/restir_pt.py --charts` redraws the charts from the last run's JSON.
`bench/restir_pt.py --frame-cost` measures only the frame cost ratio restir_pt / pt at 1 spp
(no references, a few minutes): one daemon, a pt session at 1 spp and restir_pt sessions with its
defaults, with unpaired spatial reuse and with four NEE candidates, warmed up, then rounds of one
frame of each in turn; the median of the rounds' ratios and their quartiles."""
import hashlib
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cputime import cli_frame_ms  # noqa: E402
from daemon import Daemon  # noqa: E402
from svgplot import loglog  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
BIN = os.environ.get("RESTIR_BIN", str(ROOT / "build" / "restir"))
OUT = ROOT / "build" / "bench"
REFS = ROOT / "build" / "refs"
SCENES = os.environ.get("BENCH_RESTIR_SCENES", "cornell-box cornell-glossy door-ajar").split()
SIZE = os.environ.get("BENCH_RESTIR_SIZE", "256x256")
SEEDS = int(os.environ.get("BENCH_RESTIR_SEEDS", "3"))
REF_SPP = int(os.environ.get("BENCH_RESTIR_REF_SPP", "2048"))
WARMUP = int(os.environ.get("BENCH_RESTIR_WARMUP", "32"))
THREADS = os.environ.get("BENCH_THREADS", "0")
ABLATION_SCENE = os.environ.get("BENCH_RESTIR_ABLATION", "door-ajar")
PT_SPPS = [1, 2, 4, 8, 16, 32, 64]
RESTIR_VARIANTS = [("restir_pt", "{}"),
                   ("restir_pt, 6 neighbours x 2 rounds", '{"spatial_neighbors": 6, "spatial_rounds": 2}')]
ABLATION = [("Enhanced (defaults)", "{}"),
            ("no dual footprint (near-field distance)", '{"footprint": false}'),
            ("no PDF connectability (lobe roughness)", '{"pdf_connect": false}'),
            ("no Russian roulette", '{"rr": false}'),
            ("Russian roulette from the third bounce", '{"rr_depth": 3}'),
            ("unpaired spatial reuse", '{"paired_spatial": false}'),
            ("2 NEE candidates", '{"nee_candidates": 2}'),
            ("4 NEE candidates", '{"nee_candidates": 4}'),
            ("DI outside the reservoir", '{"unify_di": false}'),
            ("no temporal reuse", '{"temporal": false}'),
            ("2 spatial neighbours", '{"spatial_neighbors": 2}'),
            ("1 spatial neighbour", '{"spatial_neighbors": 1}'),
            ("no spatial reuse", '{"spatial_neighbors": 0}')]


def run(args, binary=None):
    res = subprocess.run([binary or BIN, *args, "--threads", THREADS], capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"bench: {' '.join(args)}: {res.stderr.strip()}")
    return json.loads(res.stdout)


def compare_all(img, ref):
    """`restir compare`'s metrics of img against ref (mape, rmse, relmse, ...)."""
    res = subprocess.run([BIN, "compare", str(img), str(ref)], capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"bench: compare {img}: {res.stderr.strip()}")
    return json.loads(res.stdout)


def compare(img, ref):
    return compare_all(img, ref)["mape"]


def reference(scene):
    path = ROOT / "scenes" / scene / "scene.json"
    key = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    REFS.mkdir(parents=True, exist_ok=True)
    ref = REFS / f"{scene}-{SIZE}-{REF_SPP}spp-{key}.exr"
    if not ref.exists():
        print(f"bench: rendering the {scene} reference ({SIZE}, {REF_SPP} spp) ...", file=sys.stderr, flush=True)
        tmp = ref.with_suffix(".tmp.exr")
        run(["render", str(path), "--size", SIZE, "--spp", str(REF_SPP), "--seed", "999983", "--json", "-o", str(tmp)])
        tmp.rename(ref)
    return path, ref


def measure_pt(scene_path, ref, tmp):
    rows = []
    for spp in PT_SPPS:
        ms, mape = [], []
        for s in range(SEEDS):
            img = tmp / f"pt{spp}_{s}.exr"
            st = run(["render", str(scene_path), "--size", SIZE, "--spp", str(spp), "--seed", str(s), "--json",
                      "-o", str(img)])
            ms.append(cli_frame_ms(st))
            mape.append(compare(img, ref))
        rows.append({"spp": spp, "ms": statistics.median(ms), "mape": statistics.median(mape)})
    return rows


def measure_restir(scene_path, ref, tmp, params):
    ms, mape, passes = [], [], []
    for s in range(SEEDS):
        img = tmp / f"rp_{s}.exr"
        st = run(["render", str(scene_path), "--method", "restir_pt", "--size", SIZE, "--seed", str(s),
                  "--frames", str(WARMUP + 1), "--params", params, "--json", "-o", str(img)])
        ms.append(cli_frame_ms(st, last_frame=True))
        mape.append(compare(img, ref))
        passes.append(st["last_frame"])
    med = {k: statistics.median(p[k] for p in passes) for k in ("gbuffer_ms", "initial_ms", "temporal_ms",
                                                                  "spatial_ms", "shade_ms")}
    return {"ms": statistics.median(ms), "mape": statistics.median(mape), "passes": med,
            "reservoir_bytes_per_pixel": st["reservoir_bytes_per_pixel"], "session_bytes": st["session_bytes"]}


def pt_mape_at(pt_rows, ms):
    """pt's MAPE at a frame time, interpolated on the log-log curve; below 1 spp, extrapolated
    along the Monte Carlo rate (error ~ time^-1/2) from the 1-spp point."""
    pts = sorted((r["ms"], r["mape"]) for r in pt_rows)
    if ms <= pts[0][0]:
        return pts[0][1] * math.sqrt(pts[0][0] / ms)
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        if x0 <= ms <= x1:
            f = (math.log(ms) - math.log(x0)) / (math.log(x1) - math.log(x0))
            return math.exp(math.log(y0) + f * (math.log(y1) - math.log(y0)))
    x1, y1 = pts[-1]
    return y1 * math.sqrt(x1 / ms)


COST_VARIANTS = [("defaults", "{}"), ("unpaired spatial reuse", '{"paired_spatial": false}'),
                 ("4 NEE candidates", '{"nee_candidates": 4}')]
COST_ROUNDS = int(os.environ.get("BENCH_RESTIR_COST_ROUNDS", "48"))
RESTIRD = os.environ.get("RESTIRD_BIN", str(ROOT / "build" / "restird"))


def measure_frame_cost(scene, variants, rounds):
    """restir_pt's frame cost over pt's at 1 spp, frame by frame: one daemon holds a pt session and,
    one variant after the other, a restir_pt session warmed up with WARMUP frames; then each round
    renders one frame of pt and one of the variant, and a last pt frame closes the rounds. A
    round's ratio divides the variant's frame time by the mean of the two pt frames around it,
    rendered within a fraction of a second of it: on a shared machine whose speed drifts by tens
    of per cent within seconds, ratios of whole sessions rendered one after the other moved by as
    much between runs. Only one restir_pt session lives at a time, as in use: several would evict
    each other's reservoirs from the caches between their frames. Returns the median ms of each,
    and per variant the median of the rounds' ratios and their quartiles."""
    d = Daemon(RESTIRD, THREADS)
    w, h = (int(v) for v in SIZE.split("x"))
    pt_all, out = [], {"rounds": rounds, "variants": {}}
    try:
        pt = d.session(scene, "pt", w, h, {"spp": 1})
        for name, params in variants:
            s = d.session(scene, "restir_pt", w, h, json.loads(params))
            for _ in range(WARMUP):
                d.frame_ms(s)
            pt_ms, ms = [d.frame_ms(pt)], []
            for _ in range(rounds):
                ms.append(d.frame_ms(s))
                pt_ms.append(d.frame_ms(pt))
            d.delete(s)
            ratios = [t / ((pt_ms[i] + pt_ms[i + 1]) / 2) for i, t in enumerate(ms)]
            q1, _, q3 = statistics.quantiles(ratios, n=4)
            out["variants"][name] = {"ms": statistics.median(ms), "ratio": statistics.median(ratios),
                                     "ratio_q1": q1, "ratio_q3": q3}
            pt_all += pt_ms
    finally:
        d.close()
    out["pt_ms"] = statistics.median(pt_all)
    return out


def frame_cost_cell(v):
    return f"{v['ms']:.1f}, {v['ratio']:.2f}× [{v['ratio_q1']:.2f}–{v['ratio_q3']:.2f}]"


COST_TITLE = (f"restir_pt / pt at 1 spp, {SIZE}: frame times after {WARMUP} warm-up frames, {COST_ROUNDS} rounds "
              "of one frame each in one daemon, medians (ratio: median of the rounds' ratios, quartiles in brackets)")


def frame_cost():
    print(f"\n### Frame cost {COST_TITLE}\n")
    print("| scene | pt 1 spp ms | " + " | ".join(f"restir_pt {n} ms, ratio" for n, _ in COST_VARIANTS) + " |")
    print("|---|---|" + "---|" * len(COST_VARIANTS))
    for scene in SCENES:
        fc = measure_frame_cost(scene, COST_VARIANTS, COST_ROUNDS)
        cells = [frame_cost_cell(v) for v in fc["variants"].values()]
        print(f"| {scene} | {fc['pt_ms']:.1f} | " + " | ".join(cells) + " |", flush=True)


def charts(results):
    for scene, r in results["scenes"].items():
        loglog(OUT / f"restir_pt_{scene}.svg", f"{scene}, {results['size']}: MAPE against frame time",
               "frame time (ms)", "MAPE", [("pt, 1-64 spp", [(x["ms"], x["mape"]) for x in r["pt"]], "line")] +
               [(name, [(v["ms"], v["mape"])], "points") for name, v in r["restir_pt"].items()])


def main():
    if sys.argv[1:] == ["--charts"]:
        # Redraw the charts from the last run's numbers (build/bench/restir_pt.json).
        charts(json.loads((OUT / "restir_pt.json").read_text()))
        return
    if "--frame-cost" in sys.argv[1:]:
        frame_cost()
        return
    OUT.mkdir(parents=True, exist_ok=True)
    results = {"size": SIZE, "seeds": SEEDS, "ref_spp": REF_SPP, "warmup": WARMUP, "threads": THREADS, "scenes": {}}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        for scene in SCENES:
            scene_path, ref = reference(scene)
            print(f"bench: {scene} ...", file=sys.stderr, flush=True)
            pt_rows = measure_pt(scene_path, ref, tmp)
            variants = {name: measure_restir(scene_path, ref, tmp, params) for name, params in RESTIR_VARIANTS}
            main_v = variants["restir_pt"]
            cost = measure_frame_cost(scene, [("defaults", "{}")], COST_ROUNDS)
            results["scenes"][scene] = {
                "pt": pt_rows, "restir_pt": variants,
                "equal_time_mape_ratio": main_v["mape"] / pt_mape_at(pt_rows, main_v["ms"]),
                "frame_cost": cost}
        if ABLATION_SCENE:
            scene_path, ref = reference(ABLATION_SCENE)
            print(f"bench: ablation on {ABLATION_SCENE} ...", file=sys.stderr, flush=True)
            results["ablation"] = {"scene": ABLATION_SCENE,
                                   "rows": [{"name": n, **measure_restir(scene_path, ref, tmp, p)} for n, p in ABLATION]}
    (OUT / "restir_pt.json").write_text(json.dumps(results, indent=1) + "\n")
    charts(results)

    print(f"\n### pt vs restir_pt, {SIZE}, medians of {SEEDS} seeds ({WARMUP} warm-up frames)\n")
    print("| scene | pt 1 spp ms | restir_pt frame ms | restir_pt MAPE | pt MAPE at equal time | equal-time ratio |")
    print("|---|---|---|---|---|---|")
    for scene, r in results["scenes"].items():
        v = r["restir_pt"]["restir_pt"]
        print(f"| {scene} | {r['pt'][0]['ms']:.1f} | {v['ms']:.1f} | "
              f"{v['mape']:.3f} | {pt_mape_at(r['pt'], v['ms']):.3f} | {r['equal_time_mape_ratio']:.2f} |")
    print(f"\n### Frame cost {COST_TITLE}\n")
    print("| scene | pt 1 spp ms | restir_pt ms, frame cost ratio |")
    print("|---|---|---|")
    for scene, r in results["scenes"].items():
        fc = r["frame_cost"]
        print(f"| {scene} | {fc['pt_ms']:.1f} | {frame_cost_cell(fc['variants']['defaults'])} |")
    if "ablation" in results:
        print(f"\n### Ablation on {results['ablation']['scene']} ([ReSTIR PT Enhanced Table 1]), ms per pass, medians\n")
        print("| setting | G-buffer | initial | temporal | spatial | shade | frame | MAPE |")
        print("|---|---|---|---|---|---|---|---|")
        for row in results["ablation"]["rows"]:
            p = row["passes"]
            print(f"| {row['name']} | {p['gbuffer_ms']:.1f} | {p['initial_ms']:.1f} | {p['temporal_ms']:.1f} | "
                  f"{p['spatial_ms']:.1f} | {p['shade_ms']:.1f} | {row['ms']:.1f} | {row['mape']:.3f} |")
    print(f"\ncharts: {', '.join(str(OUT / f'restir_pt_{s}.svg') for s in results['scenes'])}")


if __name__ == "__main__":
    main()
