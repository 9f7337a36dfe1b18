"""bench/sweep.py — configurations of one method that cost the same per frame, compared at an
equal number of frames (so at equal time) against the report's reference of the scene; or, with
SWEEP_BUDGET_SPP, configurations of any cost converging a still image at equal CPU time.

Each configuration renders SWEEP_SEEDS sessions of SWEEP_FRAMES frames with `restir render`
(seeds 7000, 7001, ...: the same for every configuration, so that they differ only by their
parameters); the last frame is scored against the scene's reference of `make bench-report`
(bench/references.py: the same chunks, cache and own error) and the medians over the seeds are
printed with the median frame time, which shows whether the costs really are equal, and the
median CPU time a frame (the session's, all threads and its start-up included, over its frames):
on a shared machine the wall clock of one run can stretch several times, its CPU time far less
(BENCH_THREADS=1 keeps thread waits out of it too), so that column is the one to read the costs
of configurations, or of methods swept one after the other, against each other. A
configuration that costs more than another is not compared here: `make bench-report` with
REPORT_PARAMS compares at equal time. Usage:

  /usr/bin/python3 bench/sweep.py SCENE METHOD PARAMS_JSON [PARAMS_JSON ...]
  /usr/bin/python3 bench/sweep.py cornell-glossy restir_pt '{"spatial_radius": 20}' '{"spatial_radius": 0}'

Environment: SWEEP_SIZE (256: the side of the square image), SWEEP_SEEDS (5), SWEEP_FRAMES
(33: the frame after the report's 32 warm-up frames), RESTIR_BIN (build/restir), BENCH_THREADS
(all cores), REPORT_REF_BIN (bench/references.py), SWEEP_COLOUR=1 (two more columns: MAPE and
relMSE were each pixel's colour exact, errors.colour_exact, so that the rest of the error is
colour).

The converge regime (SWEEP_BUDGET_SPP=N): the budget is the CPU time (user + system, all threads)
of `pt` at N spp on the scene; each configuration starts from the method's converge profile
(`--profile converge`: independent frames) and averages as many frames as fit in the budget (its
frame cost taken from a 1- and a 9-frame session), and pt at N spp is the first row. CPU time
rather than wall time: the figure holds on a shared machine, where other work stretches the wall
clock but not the CPU time a render spends (BENCH_THREADS=1 keeps it free of thread waits too).
SWEEP_BASELINES (e.g. "bdpt") adds those methods with their defaults at the same budget, or with
parameters after a colon, in JSON without spaces (e.g. 'sms:{"spp":1}': one sample a frame, so that
the budget holds several of its frames rather than a fraction of one). A row
spends whole frames, so its CPU time misses the budget by up to half a frame, more when the frame
cost measured in calibration differs from the one in the runs (a loaded machine): the last three
columns scale its errors to the budget as independent frames' errors scale with time (relMSE as
1 / time, MAPE and RMSE as 1 / sqrt(time); the converge profiles and pt keep no history, so their
frames are independent), which compares rows at the same time rather than at their own. Read them
beside the frame count: from one or two frames the scaling reaches further than the law holds. E.g.

  SWEEP_BUDGET_SPP=16 SWEEP_BASELINES=bdpt BENCH_THREADS=1 /usr/bin/python3 bench/sweep.py \
      lamp-in-glass restir_bdpt '{}' '{"spatial_rounds": 1}'"""
import json
import os
import statistics
import sys
from pathlib import Path

import errors
from cputime import run_timed
from exrimage import read_rgb
from references import Reference, reference_method
from restir_pt import BIN, THREADS

ROOT = Path(__file__).resolve().parent.parent
SIDE = int(os.environ.get("SWEEP_SIZE", "256"))
SEEDS = int(os.environ.get("SWEEP_SEEDS", "5"))
FRAMES = int(os.environ.get("SWEEP_FRAMES", "33"))
FIRST_SEED = 7000
BUDGET_SPP = int(os.environ.get("SWEEP_BUDGET_SPP", "0"))
BASELINES = os.environ.get("SWEEP_BASELINES", "").split()
COLOUR = os.environ.get("SWEEP_COLOUR") == "1"
CALIB = 8  # frames whose CPU time gives a configuration's frame cost in the converge regime


def cpu_render(args):
    """Runs `restir render ARGS` and returns the CPU seconds it spent (its own and its threads')."""
    res, cpu = run_timed([BIN, "render", *args, "--threads", THREADS])
    if res.returncode != 0:
        raise SystemExit(f"sweep: {' '.join(map(str, args))}: {res.stderr.strip()}")
    return cpu


def converge(path, work, ref, method, configs):
    """The converge regime: every configuration at the CPU time of pt at BUDGET_SPP spp."""
    base = [path, "--size", f"{SIDE}x{SIDE}", "--json"]
    budget = statistics.median(cpu_render([*base, "--method", "pt", "--spp", BUDGET_SPP, "--seed", FIRST_SEED + s,
                                           "-o", work / "budget.exr"]) for s in range(2))
    threads = "all cores" if THREADS == "0" else f"{THREADS} thread{'' if THREADS == '1' else 's'}"
    print(f"\nConverge at equal CPU time: {budget:.2f} CPU-s, pt's at {BUDGET_SPP} spp ({threads}).\n")
    print("| method | params | frames | CPU-s | MAPE | relMSE | RMSE | at the budget: MAPE | relMSE | RMSE |\n"
          "|---|---|---|---|---|---|---|---|---|---|")
    rows = [("pt", None)] + [baseline(b) for b in BASELINES] + [(method, c) for c in configs]
    for m, text in rows:
        if text is None:
            args, frames = ["--method", "pt", "--spp", BUDGET_SPP], BUDGET_SPP
        else:
            session = [*base, "--method", m, "--params", text, "--profile", "converge", "--seed", FIRST_SEED]
            # A frame's CPU time from sessions of 1 and 1 + CALIB frames: the difference leaves out
            # the start-up (scene, BVH), and over CALIB frames the clock's tick is small beside it.
            one = cpu_render([*session, "--frames", 1, "-o", work / "calib.exr"])
            more = cpu_render([*session, "--frames", 1 + CALIB, "--average-last", 1 + CALIB, "-o", work / "calib.exr"])
            per = max((more - one) / CALIB, 1e-3)
            frames = max(1, round((budget - max(one - per, 0.0)) / per))
            args = ["--method", m, "--params", text, "--profile", "converge", "--frames", frames,
                    "--average-last", frames]
        scores, cpu = [], []
        for s in range(SEEDS):
            out = work / f"converge-{s}.exr"
            cpu.append(cpu_render([*base, *args, "--seed", FIRST_SEED + s, "-o", out]))
            scores.append(errors.metrics(read_rgb(out), ref.image))
        med = {k: statistics.median(sc[k] for sc in scores) for k in errors.KEYS}
        label = f"`{text}`" if text is not None else f"{BUDGET_SPP} spp"
        spent = statistics.median(cpu) / budget
        print(f"| {m} | {label} | {frames} | {statistics.median(cpu):.2f} | {med['mape']:.4g} | {med['relmse']:.4g} | "
              f"{med['rmse']:.4g} | {med['mape'] * spent ** 0.5:.4g} | {med['relmse'] * spent:.4g} | "
              f"{med['rmse'] * spent ** 0.5:.4g} |", flush=True)


def params_text(text, what):
    """text, when it is a JSON object; else stops, naming `what` (the argument or the entry)."""
    try:
        if not isinstance(json.loads(text), dict):
            raise ValueError("not an object")
    except ValueError as e:
        raise SystemExit(f"sweep: {what}: parameters must be a JSON object ({e})")
    return text


def baseline(entry):
    """(method, parameters' JSON text) of a SWEEP_BASELINES entry: METHOD or METHOD:{JSON}."""
    m, _, text = entry.partition(":")
    return m, params_text(text or "{}", f"SWEEP_BASELINES {entry!r}")


def main(argv):
    if len(argv) < 3:
        raise SystemExit(__doc__)
    scene, method, configs = argv[0], argv[1], argv[2:]
    for text in configs:
        params_text(text, repr(text))
    for entry in BASELINES:
        baseline(entry)
    path = ROOT / "scenes" / scene / "scene.json"
    if not path.is_file():
        raise SystemExit(f"sweep: no scene {scene!r} in scenes/")
    work = ROOT / "build" / "sweep"
    work.mkdir(parents=True, exist_ok=True)
    ref_method, chunk = reference_method(scene)
    ref = Reference(path, SIDE, ref_method, chunk, work)
    own = ", ".join(f"{k} {v:.4g}" for k, v in ref.own.items())
    what = (f"converging at pt {BUDGET_SPP} spp's CPU time" if BUDGET_SPP else f"frame {FRAMES} of a session")
    print(f"# {method} on {scene}, {SIDE}x{SIDE}, {what}, medians over {SEEDS} seeds; "
          f"reference {ref_method} ({ref.samples} samples), its own error {own}")
    print(f"# command: /usr/bin/python3 bench/sweep.py {scene} {method} " + " ".join(f"'{c}'" for c in configs))
    if BUDGET_SPP:
        converge(path, work, ref, method, configs)
        return
    extra = (" MAPE, colour exact | relMSE, colour exact |", "---|---|") if COLOUR else ("", "")
    print(f"\n| params | ms a frame | CPU-ms a frame | MAPE | relMSE | RMSE |{extra[0]}\n|---|---|---|---|---|---|{extra[1]}")
    for text in configs:
        scores, ms, cpu_ms = [], [], []
        for s in range(SEEDS):
            out = work / f"{scene}-{method}-{s}.exr"
            res, cpu = run_timed([BIN, "render", path, "--size", f"{SIDE}x{SIDE}", "--method", method, "--frames",
                                  FRAMES, "--seed", FIRST_SEED + s, "--params", text, "--json", "-o", out,
                                  "--threads", THREADS])
            if res.returncode != 0:
                raise SystemExit(f"sweep: {method} {text}: {res.stderr.strip()}")
            ms.append(json.loads(res.stdout)["time_ms"] / FRAMES)
            cpu_ms.append(1000.0 * cpu / FRAMES)
            img = read_rgb(out)
            scores.append(errors.metrics(img, ref.image))
            if COLOUR:
                exact = errors.metrics(errors.colour_exact(img, ref.image), ref.image)
                scores[-1].update({"mape_ce": exact["mape"], "relmse_ce": exact["relmse"]})
        med = {k: statistics.median(sc[k] for sc in scores) for k in scores[0]}
        cols = f" {med['mape_ce']:.4g} | {med['relmse_ce']:.4g} |" if COLOUR else ""
        print(f"| `{text}` | {statistics.median(ms):.1f} | {statistics.median(cpu_ms):.1f} | {med['mape']:.4g} | "
              f"{med['relmse']:.4g} | {med['rmse']:.4g} |{cols}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
