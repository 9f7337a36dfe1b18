#!/usr/bin/env python3
"""bench/bdpt.py — `make bench`: bidirectional path tracing against path tracing and ReSTIR PT
on the caustic scenes, error against time.

Benchmarks are not tests: nothing here passes or fails on a timing. In one
run, on lamp-in-glass and caustic-sphere at 256x256 (BENCH_BDPT_SCENES, _SIZE):
  1. a reference per scene: `bdpt` averaged over REF_FRAMES frames (`pt` cannot converge on
     these scenes in any reasonable time: their light arrives through glass), cached in
     build/refs/ under the scene file's hash, the size and the frame count;
  2. `pt` at 1, 2, 4 ... 32 spp; `bdpt` averaged over 1, 2, 4 ... 32 frames (its time is the sum
     of the frames'); `restir_pt` (defaults) as the frame after WARMUP warm-up frames: each over
     SEEDS seeds, time and MAPE ([ReSTIR BDPT footnote 3], `restir compare`) against the reference;
  3. the equal-time error ratios bdpt / pt and restir_pt / pt (pt's MAPE interpolated log-log at
     the other's time) and the frame cost ratios against pt at 1 spp;
  4. writes build/bench/bdpt.json, one SVG chart per scene (MAPE vs ms, log-log) in
     build/bench/, and prints a Markdown table (medians over the seeds).
The reference is the method itself with other seeds, so bdpt's error is its noise alone (a bias
of bdpt would not show here; tests/test_bdpt.py checks it against pt where pt converges).
Environment: BENCH_BDPT_SEEDS (2), BENCH_BDPT_REF_FRAMES (512), BENCH_BDPT_WARMUP (32),
BENCH_THREADS (all cores). `bench/bdpt.py --charts` redraws the charts from the last run's JSON."""
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cputime import cli_frame_ms  # noqa: E402
from restir_pt import pt_mape_at  # noqa: E402
from svgplot import loglog  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
BIN = os.environ.get("RESTIR_BIN", str(ROOT / "build" / "restir"))
OUT = ROOT / "build" / "bench"
REFS = ROOT / "build" / "refs"
SCENES = os.environ.get("BENCH_BDPT_SCENES", "lamp-in-glass caustic-sphere").split()
SIZE = os.environ.get("BENCH_BDPT_SIZE", "256x256")
SEEDS = int(os.environ.get("BENCH_BDPT_SEEDS", "2"))
REF_FRAMES = int(os.environ.get("BENCH_BDPT_REF_FRAMES", "512"))
WARMUP = int(os.environ.get("BENCH_BDPT_WARMUP", "32"))
THREADS = os.environ.get("BENCH_THREADS", "0")
COUNTS = [1, 2, 4, 8, 16, 32]


def run(args):
    res = subprocess.run([BIN, *args, "--threads", THREADS], capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"bench: {' '.join(args)}: {res.stderr.strip()}")
    return json.loads(res.stdout)


def compare(img, ref):
    res = subprocess.run([BIN, "compare", str(img), str(ref)], capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"bench: compare {img}: {res.stderr.strip()}")
    return json.loads(res.stdout)["mape"]


def reference(scene, size=None, frames=None, animation=None):
    """A bdpt reference of `frames` frames at `size` (the module's settings by default), cached
    under the scene file's hash; `animation`: a file whose keys hold the scene still in a changed
    state (a light moved), part of the cache key."""
    size, frames = size or SIZE, frames or REF_FRAMES
    path = ROOT / "scenes" / scene / "scene.json"
    h = hashlib.sha256(path.read_bytes())
    if animation:
        h.update(Path(animation).read_bytes())
    key = h.hexdigest()[:16]
    REFS.mkdir(parents=True, exist_ok=True)
    ref = REFS / f"{scene}-{size}-bdpt{frames}-{key}.exr"
    if not ref.exists():
        print(f"bench: rendering the {scene} reference ({size}, bdpt, {frames} frames) ...", file=sys.stderr,
              flush=True)
        tmp = ref.with_suffix(".tmp.exr")
        anim = ["--animation", str(animation)] if animation else []
        run(["render", str(path), "--method", "bdpt", "--size", size, "--frames", str(frames), "--average-last",
             str(frames), "--seed", "999983", "--json", "-o", str(tmp), *anim])
        tmp.rename(ref)
    return path, ref


def measure(scene_path, ref, tmp, name, args_of):
    rows = []
    for n in COUNTS:
        ms, mape = [], []
        for s in range(SEEDS):
            img = tmp / f"{name}{n}_{s}.exr"
            st = run(["render", str(scene_path), "--size", SIZE, "--seed", str(s), "--json", "-o", str(img),
                      *args_of(n)])
            ms.append(cli_frame_ms(st))
            mape.append(compare(img, ref))
        rows.append({"n": n, "ms": statistics.median(ms), "mape": statistics.median(mape)})
    return rows


def measure_restir(scene_path, ref, tmp):
    ms, mape = [], []
    for s in range(SEEDS):
        img = tmp / f"rp_{s}.exr"
        st = run(["render", str(scene_path), "--method", "restir_pt", "--size", SIZE, "--seed", str(s),
                  "--frames", str(WARMUP + 1), "--json", "-o", str(img)])
        lf = st["last_frame"]
        ms.append(lf["gbuffer_ms"] + lf["initial_ms"] + lf["temporal_ms"] + lf["spatial_ms"] + lf["shade_ms"])
        mape.append(compare(img, ref))
    return {"ms": statistics.median(ms), "mape": statistics.median(mape)}


def charts(results):
    for scene, r in results["scenes"].items():
        loglog(OUT / f"bdpt_{scene}.svg", f"{scene}, {results['size']}: MAPE against time",
               "time (ms)", "MAPE",
               [("pt, 1-32 spp", [(x["ms"], x["mape"]) for x in r["pt"]], "line"),
                ("bdpt, 1-32 frames", [(x["ms"], x["mape"]) for x in r["bdpt"]], "line"),
                ("restir_pt (one frame)", [(r["restir_pt"]["ms"], r["restir_pt"]["mape"])], "points")])


def main():
    if sys.argv[1:] == ["--charts"]:
        charts(json.loads((OUT / "bdpt.json").read_text()))
        return
    OUT.mkdir(parents=True, exist_ok=True)
    results = {"size": SIZE, "seeds": SEEDS, "ref_frames": REF_FRAMES, "warmup": WARMUP, "threads": THREADS,
               "scenes": {}}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        for scene in SCENES:
            scene_path, ref = reference(scene)
            print(f"bench: {scene} ...", file=sys.stderr, flush=True)
            pt_rows = measure(scene_path, ref, tmp, "pt", lambda n: ["--spp", str(n)])
            bd_rows = measure(scene_path, ref, tmp, "bd", lambda n: ["--method", "bdpt", "--frames", str(n),
                                                                      "--average-last", str(n)])
            rp = measure_restir(scene_path, ref, tmp)
            bd1 = bd_rows[0]
            results["scenes"][scene] = {
                "pt": pt_rows, "bdpt": bd_rows, "restir_pt": rp,
                "bdpt_equal_time_mape_ratio": bd1["mape"] / pt_mape_at(pt_rows, bd1["ms"]),
                "restir_pt_equal_time_mape_ratio": rp["mape"] / pt_mape_at(pt_rows, rp["ms"]),
                "bdpt_frame_cost_ratio_1spp": bd1["ms"] / pt_rows[0]["ms"],
                "restir_pt_frame_cost_ratio_1spp": rp["ms"] / pt_rows[0]["ms"]}
    (OUT / "bdpt.json").write_text(json.dumps(results, indent=1) + "\n")
    charts(results)

    print(f"\n### pt, restir_pt and bdpt against a bdpt reference ({REF_FRAMES} frames), {SIZE}, medians of "
          f"{SEEDS} seeds\n")
    print("| scene | pt 1 spp ms | bdpt frame ms | restir_pt frame ms | bdpt 1-frame MAPE | restir_pt MAPE | "
          "pt MAPE at bdpt's time | bdpt / pt equal time | restir_pt / pt equal time |")
    print("|---|---|---|---|---|---|---|---|---|")
    for scene, r in results["scenes"].items():
        b, rp = r["bdpt"][0], r["restir_pt"]
        print(f"| {scene} | {r['pt'][0]['ms']:.1f} | {b['ms']:.1f} | {rp['ms']:.1f} | {b['mape']:.3f} | "
              f"{rp['mape']:.3f} | {pt_mape_at(r['pt'], b['ms']):.3f} | {r['bdpt_equal_time_mape_ratio']:.2f} | "
              f"{r['restir_pt_equal_time_mape_ratio']:.2f} |")
    print(f"\ncharts: {', '.join(str(OUT / f'bdpt_{s}.svg') for s in results['scenes'])}")


if __name__ == "__main__":
    main()
