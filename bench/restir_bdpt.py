#!/usr/bin/env python3
"""bench/restir_bdpt.py — `make bench`: ReSTIR BDPT (lightweight and full variants, caustic
temporal reuse) against pt, restir_pt and bdpt on the caustic scenes: error against time, frame
cost, and a moving light frame by frame.

Benchmarks are not tests: nothing here passes or fails on a timing. In one
run, on lamp-in-glass and caustic-sphere (BENCH_RBDPT_SCENES) at 256x256 (BENCH_RBDPT_SIZE):
  0. restir_bdpt runs with its defaults (lightweight, caustic and non-caustic reuse), without
     caustic reuse, with caustic reuse only (`"reuse": false`), and as the full variant
     (`"variant": "full"`: bdpt's vertex connections too), with and without `reuse`;
  1. a `bdpt` reference per scene of REF_FRAMES frames (bench/bdpt.py's, shared cache in
     build/refs/; `pt` cannot converge on these scenes: their light arrives through glass);
  2. MAPE against time ([ReSTIR BDPT footnote 3], `restir compare`), each over SEEDS seeds: `pt` at
     1, 2, 4 ... spp, and for `bdpt`, `restir_pt` and each restir_bdpt run the mean of a
     session's first 1, 2, 4 ... frames (time: the sum of
     those frames' render times, as the CLI reports it);
     For the methods with temporal reuse (restir_pt, restir_bdpt) such a mean averages correlated
     frames, which is neither of the report's regimes (docs/benchmarks.md, "Two regimes"): these
     curves and the equal-time ratios below are a record, not a ranking; `make bench-report`
     compares the methods;
  3. equal time: each compared restir_bdpt variant's MAPE over restir_pt's interpolated (log-log) at the same time,
     at restir_bdpt's longest point; the single frame after WARMUP frames of each reusing method
     (its MAPE) and the frame cost, the mean frame time of that session, as the ratio
     restir_bdpt / restir_pt;
  4. caustic-sphere with its light moving (scenes/caustic-sphere/animations/light-path.json, 30
     frames): every frame of one session of each method against its own `bdpt` reference (the
     light held at that frame's position, ANIM_REF_FRAMES frames): MAPE of the whole frame and
     of the caustic (the pixels whose reference luminance is over 3x the reference's median,
     the sphere's focus on the floor), frame by frame;
  5. writes build/bench/restir_bdpt.json, the charts build/bench/restir_bdpt_<scene>.svg (MAPE
     vs ms, log-log) and build/bench/restir_bdpt_moving.svg, caustic_moving.svg (per frame),
     and prints Markdown tables (medians over the seeds).
  6. the biased switches (`--biased` runs this part alone): `copy_mis` and `reject_unshiftable`
     beside the unbiased non-caustic reuse, BIAS_SESSIONS sessions of BIAS_FRAMES frames each
     at BIAS_SIZE on both scenes, the three variants of a seed rendered one after the other
     with the same seed, so their difference is mostly the bias: the whole image's mean
     relative to the unbiased one's with its paired t, the darkest 8x8-pixel block's, how many
     blocks are darker by over 3 standard errors, and the frame time.
QUICK=1: 64x64, 1 seed, 1-16 frames, references of 256 frames (128 per moving-light frame),
warm-up 16: a few minutes on 2 cores. Environment: BENCH_RBDPT_SEEDS (2), BENCH_RBDPT_REF_FRAMES
(512), BENCH_RBDPT_WARMUP (32), BENCH_RBDPT_ANIM_REF_FRAMES (256), BENCH_RBDPT_BIAS_SIZE (64x64),
BENCH_RBDPT_BIAS_SESSIONS (16; 4 with QUICK), BENCH_RBDPT_BIAS_FRAMES (32), BENCH_THREADS (all
cores).
`bench/restir_bdpt.py --charts` redraws the charts from the last run's JSON."""
import json
import os
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bdpt as bdpt_bench  # noqa: E402
from bdpt import compare, run  # noqa: E402
from cputime import cli_frame_ms  # noqa: E402
from exrimage import read_rgb  # noqa: E402
from restir_pt import pt_mape_at  # noqa: E402
from svgplot import chart, loglog  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "build" / "bench"
QUICK = os.environ.get("QUICK", "0") not in ("", "0")
SCENES = os.environ.get("BENCH_RBDPT_SCENES", "lamp-in-glass caustic-sphere").split()
SIZE = os.environ.get("BENCH_RBDPT_SIZE", "64x64" if QUICK else "256x256")
SEEDS = int(os.environ.get("BENCH_RBDPT_SEEDS", "1" if QUICK else "2"))
REF_FRAMES = int(os.environ.get("BENCH_RBDPT_REF_FRAMES", "256" if QUICK else "512"))
WARMUP = int(os.environ.get("BENCH_RBDPT_WARMUP", "16" if QUICK else "32"))
ANIM_REF_FRAMES = int(os.environ.get("BENCH_RBDPT_ANIM_REF_FRAMES", "128" if QUICK else "256"))
COUNTS = [1, 2, 4, 8, 16] if QUICK else [1, 2, 4, 8, 16, 32]
ANIMATION = ROOT / "scenes" / "caustic-sphere" / "animations" / "light-path.json"
BIAS_SIZE = os.environ.get("BENCH_RBDPT_BIAS_SIZE", "64x64")
BIAS_SESSIONS = int(os.environ.get("BENCH_RBDPT_BIAS_SESSIONS", "4" if QUICK else "16"))
BIAS_FRAMES = int(os.environ.get("BENCH_RBDPT_BIAS_FRAMES", "32"))
# The biased switches of the non-caustic reuse, each against the unbiased reuse (the first).
BIASED = [("reuse", {"reuse": True}), ("copy_mis", {"reuse": True, "copy_mis": True}),
          ("reject_unshiftable", {"reuse": True, "reject_unshiftable": True})]

# (label, CLI arguments) of the session methods; frames are averaged over a session's first n.
SESSIONS = [("bdpt", ["--method", "bdpt"]), ("restir_pt", ["--method", "restir_pt"]),
            ("restir_bdpt", ["--method", "restir_bdpt"]),
            ("restir_bdpt, no caustic reuse", ["--method", "restir_bdpt", "--params", '{"caustic_temporal": false}']),
            ("restir_bdpt, caustic reuse only", ["--method", "restir_bdpt", "--params", '{"reuse": false}']),
            ("restir_bdpt, full", ["--method", "restir_bdpt", "--params", '{"variant": "full"}']),
            ("restir_bdpt, full, caustic reuse only", ["--method", "restir_bdpt", "--params",
                                                       '{"variant": "full", "reuse": false}'])]
# The variants of restir_bdpt whose equal-time error and frame cost are compared with restir_pt's.
COMPARED = ["restir_bdpt", "restir_bdpt, caustic reuse only", "restir_bdpt, full", "restir_bdpt, full, caustic reuse only"]


def render(scene_path, out, seed, args):
    return run(["render", str(scene_path), "--size", SIZE, "--seed", str(seed), "--json", "-o", str(out), *args])


def curve(scene_path, ref, tmp, name, args_of):
    rows = []
    for n in COUNTS:
        ms, mape = [], []
        for s in range(SEEDS):
            img = tmp / f"{name}{n}_{s}.exr"
            ms.append(cli_frame_ms(render(scene_path, img, s, args_of(n))))
            mape.append(compare(img, ref))
        rows.append({"n": n, "ms": statistics.median(ms), "mape": statistics.median(mape)})
    return rows


def caustic_mask(ref):
    """The caustic: pixels whose reference luminance is over 3x the reference's median."""
    lum = ref @ np.array([0.2126, 0.7152, 0.0722])
    return lum > 3.0 * np.median(lum)


def masked_mape(img, ref, mask):
    rel = np.abs(img - ref) / (ref + 0.01 * ref.mean())
    return float(rel[mask].mean()) if mask.any() else float("nan")


def after_warmup(scene_path, ref, tmp, name, args):
    """The frame after WARMUP frames: its MAPE and its caustic's, and the session's mean frame
    time."""
    r = read_rgb(ref)
    mask = caustic_mask(r)
    ms, mape, cm = [], [], []
    for s in range(SEEDS):
        img = tmp / f"{name}_w{s}.exr"
        st = render(scene_path, img, s, [*args, "--frames", str(WARMUP + 1)])
        ms.append(cli_frame_ms(st, WARMUP + 1))
        mape.append(compare(img, ref))
        cm.append(masked_mape(read_rgb(img), r, mask))
    return {"frame_ms": statistics.median(ms), "mape": statistics.median(mape), "caustic_mape": statistics.median(cm),
            "caustic_pixels": int(mask.sum())}


def light_at(anim, t):
    """The light's position at time t on the animation's linear keys (held after the last)."""
    keys = anim["light_keys"]["light"]
    if t <= keys[0]["t"]:
        return keys[0]["position"]
    for a, b in zip(keys, keys[1:]):
        if a["t"] <= t <= b["t"]:
            f = (t - a["t"]) / (b["t"] - a["t"])
            return [pa + f * (pb - pa) for pa, pb in zip(a["position"], b["position"])]
    return keys[-1]["position"]


def moving(tmp):
    """Every frame of one session per method, with the light on its path, against a `bdpt`
    reference of that frame's light position. A session's frame i is its last with --frames i+1
    (frames are seeded per frame, so the first i+1 frames are those of the whole session)."""
    anim = json.loads(ANIMATION.read_text())["animation"]
    fps, frames = anim["fps"], anim["frames"]
    scene_path = ROOT / "scenes" / "caustic-sphere" / "scene.json"
    # restir_bdpt caps the caustic confidence at `moving_cap` (1) while the light moves; beside it
    # caps of 4 (the earlier default) and of the still scene (20) in every frame: [ReSTIR BDPT §9.1]
    # notes that the proxy confidence (eq. 27) follows the diffuse motion vectors, which moving
    # caustics do not.
    methods = [("pt, 1 spp", ["--spp", "1"]), *SESSIONS,
               ("restir_bdpt, cap 4 while moving", ["--method", "restir_bdpt", "--params", '{"moving_cap": 4}']),
               ("restir_bdpt, cap 20 while moving", ["--method", "restir_bdpt", "--params", '{"moving_cap": 20}']),
               ("restir_bdpt, reuse, no camera-side reconnection",
                ["--method", "restir_bdpt", "--params", '{"reuse": true, "camera_reconnect": false}'])]
    series = {m: {"mape": [], "caustic_mape": []} for m, _ in methods}
    refs = []
    for i in range(frames):
        still = tmp / f"still{i}.json"
        pos = light_at(anim, i / fps)
        still.write_text(json.dumps({"animation": {"fps": fps, "frames": 1, "light_keys": {
            "light": [{"t": 0, "position": [round(v, 6) for v in pos]}]}}}))
        _, ref = bdpt_bench.reference("caustic-sphere", SIZE, ANIM_REF_FRAMES, still)
        refs.append(ref)
        r = read_rgb(ref)
        mask = caustic_mask(r)
        for m, args in methods:
            img = tmp / f"mv_{i}.exr"
            render(scene_path, img, 0, [*args, "--frames", str(i + 1), "--animation", str(ANIMATION)])
            x = read_rgb(img)
            series[m]["mape"].append(masked_mape(x, r, np.ones_like(mask)))
            series[m]["caustic_mape"].append(masked_mape(x, r, mask))
        print(f"bench: moving light, frame {i + 1}/{frames}", file=sys.stderr, flush=True)
    return {"frames": frames, "fps": fps, "ref_frames": ANIM_REF_FRAMES, "series": series}


def biased(tmp):
    """Each biased switch against the unbiased reuse, paired by seed (part 6 of the docstring)."""
    out = {}
    for scene in SCENES:
        scene_path = ROOT / "scenes" / scene / "scene.json"
        lum = {m: [] for m, _ in BIASED}
        ms = {m: [] for m, _ in BIASED}
        dropped = {m: 0 for m, _ in BIASED}
        for s in range(BIAS_SESSIONS):
            for m, params in BIASED:
                img = tmp / "bias.exr"
                st = run(["render", str(scene_path), "--size", BIAS_SIZE, "--seed", str(2000 + s), "--json", "-o",
                          str(img), "--method", "restir_bdpt", "--params", json.dumps(params), "--frames",
                          str(BIAS_FRAMES), "--average-last", str(BIAS_FRAMES), "--profile", "real-time"])
                lum[m].append(read_rgb(img).mean(axis=2))
                ms[m].append(cli_frame_ms(st, BIAS_FRAMES))
                dropped[m] += st["last_frame"]["lt_unshiftable"]
        base = np.stack(lum[BIASED[0][0]])
        h, w = base.shape[1:]
        blocks = lambda a: a[:, :h - h % 8, :w - w % 8].reshape(a.shape[0], h // 8, 8, w // 8, 8).mean(axis=(2, 4))
        rows = {BIASED[0][0]: {"frame_ms": statistics.median(ms[BIASED[0][0]])}}
        for m, _ in BIASED[1:]:
            d = np.stack(lum[m]) - base
            g = d.mean(axis=(1, 2))
            t = g.mean() / (g.std(ddof=1) / np.sqrt(len(g))) if g.std(ddof=1) > 0 else 0.0
            db, bb = blocks(d), blocks(base).mean(axis=0)
            zb = db.mean(axis=0) / np.maximum(db.std(axis=0, ddof=1) / np.sqrt(len(g)), 1e-12)
            rows[m] = {"relative": float(g.mean() / base.mean()), "t": float(t),
                       "darkest_block": float((db.mean(axis=0) / np.maximum(bb, 1e-9)).min()),
                       "blocks_darker": int((zb < -3).sum()), "blocks": int(zb.size),
                       "frame_ms": statistics.median(ms[m]), "lt_unshiftable_last_frames": dropped[m]}
        out[scene] = rows
        print(f"bench: biased switches on {scene} done", file=sys.stderr, flush=True)
    return {"size": BIAS_SIZE, "sessions": BIAS_SESSIONS, "frames": BIAS_FRAMES, "scenes": out}


def print_biased(b):
    if not b["scenes"]:
        return
    print(f"\nBiased switches against the unbiased reuse ({b['size']}, {b['sessions']} sessions of {b['frames']} "
          f"frames each, paired by seed): image mean relative to reuse's (paired t), darkest 8x8 block, blocks "
          f"darker by over 3 standard errors, frame ms (reuse's in brackets)\n")
    print("| scene | switch | image mean | darkest block | blocks darker | frame ms |")
    print("|---|---|---|---|---|---|")
    for scene, rows in b["scenes"].items():
        for m, r in rows.items():
            if m == BIASED[0][0]:
                continue
            print(f"| {scene} | {m} | {r['relative']:+.4f} (t {r['t']:.1f}) | {r['darkest_block']:+.4f} | "
                  f"{r['blocks_darker']} of {r['blocks']} | {r['frame_ms']:.1f} ({rows[BIASED[0][0]]['frame_ms']:.1f}) |")


def charts(results):
    for scene, r in results["scenes"].items():
        loglog(OUT / f"restir_bdpt_{scene}.svg", f"{scene}, {results['size']}: MAPE against time",
               "time (ms)", "MAPE",
               [("pt, 1-N spp", [(x["ms"], x["mape"]) for x in r["pt"]], "line")] +
               [(f"{m}, mean of 1-N frames", [(x["ms"], x["mape"]) for x in r[m]], "line") for m, _ in SESSIONS])
    mv = results.get("moving")
    if mv:
        for key, name, what in (("mape", "restir_bdpt_moving.svg", "MAPE"),
                                ("caustic_mape", "restir_bdpt_caustic_moving.svg", "MAPE of the caustic")):
            chart(OUT / name, f"caustic-sphere, {results['size']}, light moving: {what} per frame", "frame", what,
                  [(m, [(i, v) for i, v in enumerate(s[key])], "line") for m, s in mv["series"].items()],
                  xlog=False, ylog=True)


def main():
    if sys.argv[1:] == ["--charts"]:
        charts(json.loads((OUT / "restir_bdpt.json").read_text()))
        return
    OUT.mkdir(parents=True, exist_ok=True)
    if sys.argv[1:] == ["--biased"]:
        with tempfile.TemporaryDirectory() as td:
            b = biased(Path(td))
        (OUT / "restir_bdpt_biased.json").write_text(json.dumps(b, indent=1) + "\n")
        print_biased(b)
        return
    results = {"size": SIZE, "seeds": SEEDS, "ref_frames": REF_FRAMES, "warmup": WARMUP, "quick": QUICK,
               "threads": bdpt_bench.THREADS, "scenes": {}}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        for scene in SCENES:
            scene_path, ref = bdpt_bench.reference(scene, SIZE, REF_FRAMES)
            print(f"bench: {scene} ...", file=sys.stderr, flush=True)
            r = {"pt": curve(scene_path, ref, tmp, "pt", lambda n: ["--spp", str(n)])}
            for m, args in SESSIONS:
                r[m] = curve(scene_path, ref, tmp, m.replace(" ", "_").replace(",", ""),
                             lambda n, a=args: [*a, "--frames", str(n), "--average-last", str(n),
                                                   "--profile", "real-time"])
            r["after_warmup"] = {m: after_warmup(scene_path, ref, tmp, f"w{k}", args)
                                 for k, (m, args) in enumerate(SESSIONS) if m != "bdpt"}
            r["vs_restir_pt"] = {}
            for m in COMPARED:
                last = r[m][-1]
                r["vs_restir_pt"][m] = {
                    "equal_time_mape_ratio": last["mape"] / pt_mape_at(r["restir_pt"], last["ms"]),
                    "frame_cost_ratio": r["after_warmup"][m]["frame_ms"] / r["after_warmup"]["restir_pt"]["frame_ms"]}
            results["scenes"][scene] = r
        if os.environ.get("BENCH_RBDPT_MOVING", "1") != "0":
            results["moving"] = moving(tmp)
        results["biased"] = biased(tmp)
    (OUT / "restir_bdpt.json").write_text(json.dumps(results, indent=1) + "\n")
    charts(results)

    print(f"\n### restir_bdpt against pt, bdpt and restir_pt ({'QUICK, ' if QUICK else ''}{SIZE}, bdpt reference "
          f"of {REF_FRAMES} frames, medians of {SEEDS} seed(s))\n")
    print("Time ms / MAPE; pt by spp, the others the mean of a session's first n frames.\n")
    print("| scene | method | " + " | ".join(str(n) for n in COUNTS) + " |")
    print("|---|---|" + "---|" * len(COUNTS))
    for scene, r in results["scenes"].items():
        for m in ["pt"] + [m for m, _ in SESSIONS]:
            print(f"| {scene} | {m} | " + " | ".join(f"{x['ms']:.0f} / {x['mape']:.3f}" for x in r[m]) + " |")
    reusing = [m for m, _ in SESSIONS if m != "bdpt"]
    print(f"\nThe frame after {WARMUP} warm-up frames: mean frame ms / MAPE / caustic MAPE\n")
    print("| scene | " + " | ".join(reusing) + " |")
    print("|---|" + "---|" * len(reusing))
    for scene, r in results["scenes"].items():
        w = r["after_warmup"]
        print(f"| {scene} | " + " | ".join(f"{w[m]['frame_ms']:.1f} / {w[m]['mape']:.3f} / {w[m]['caustic_mape']:.3f}"
                                           for m in reusing) + " |")
    print(f"\nAgainst restir_pt: MAPE ratio at equal time (at the variant's {COUNTS[-1]} frames) and frame cost ratio "
          "(means of correlated frames: a record, not a ranking; make bench-report ranks the methods)\n")
    print("| scene | " + " | ".join(f"{m}: equal-time MAPE / frame cost" for m in COMPARED) + " |")
    print("|---|" + "---|" * len(COMPARED))
    for scene, r in results["scenes"].items():
        v = r["vs_restir_pt"]
        print(f"| {scene} | " + " | ".join(f"{v[m]['equal_time_mape_ratio']:.2f} / {v[m]['frame_cost_ratio']:.2f}"
                                           for m in COMPARED) + " |")
    mv = results.get("moving")
    if mv:
        print(f"\nLight moving on caustic-sphere ({mv['frames']} frames, references of {mv['ref_frames']} bdpt "
              f"frames per frame): MAPE / caustic MAPE, frames 1-5, 11-15, 26-30 (means)\n")
        print("| method | frames 1-5 | frames 11-15 | frames 26-30 |")
        print("|---|---|---|---|")
        for m, s in mv["series"].items():
            cells = []
            for lo in (0, 10, 25):
                cells.append(f"{np.mean(s['mape'][lo:lo + 5]):.3f} / {np.nanmean(s['caustic_mape'][lo:lo + 5]):.3f}")
            print(f"| {m} | " + " | ".join(cells) + " |")
    print_biased(results["biased"])
    names = [f"restir_bdpt_{s}.svg" for s in results["scenes"]] + (
        ["restir_bdpt_moving.svg", "restir_bdpt_caustic_moving.svg"] if mv else [])
    print(f"\ncharts: {', '.join(str(OUT / n) for n in names)}")


if __name__ == "__main__":
    main()
