"""bench/sweep.py — configurations of one method that cost the same per frame, compared at an
equal number of frames (so at equal time) against the report's reference of the scene.

Each configuration renders SWEEP_SEEDS sessions of SWEEP_FRAMES frames with `restir render`
(seeds 7000, 7001, ...: the same for every configuration, so that they differ only by their
parameters); the last frame is scored against the scene's reference of `make bench-report`
(bench/references.py: the same chunks, cache and own error) and the medians over the seeds are
printed with the median frame time, which shows whether the costs really are equal. A
configuration that costs more than another is not compared here: `make bench-report` with
REPORT_PARAMS compares at equal time. Usage:

  /usr/bin/python3 bench/sweep.py SCENE METHOD PARAMS_JSON [PARAMS_JSON ...]
  /usr/bin/python3 bench/sweep.py cornell-glossy restir_pt '{"spatial_radius": 20}' '{"spatial_radius": 0}'

Environment: SWEEP_SIZE (256: the side of the square image), SWEEP_SEEDS (5), SWEEP_FRAMES
(33: the frame after the report's 32 warm-up frames), RESTIR_BIN (build/restir), BENCH_THREADS
(all cores), REPORT_REF_BIN (bench/references.py)."""
import json
import os
import statistics
import sys
from pathlib import Path

import errors
from exrimage import read_rgb
from references import Reference, reference_method
from restir_pt import run

ROOT = Path(__file__).resolve().parent.parent
SIDE = int(os.environ.get("SWEEP_SIZE", "256"))
SEEDS = int(os.environ.get("SWEEP_SEEDS", "5"))
FRAMES = int(os.environ.get("SWEEP_FRAMES", "33"))
FIRST_SEED = 7000


def main(argv):
    if len(argv) < 3:
        raise SystemExit(__doc__)
    scene, method, configs = argv[0], argv[1], argv[2:]
    for text in configs:
        try:
            if not isinstance(json.loads(text), dict):
                raise ValueError("not an object")
        except ValueError as e:
            raise SystemExit(f"sweep: {text!r}: parameters must be a JSON object ({e})")
    path = ROOT / "scenes" / scene / "scene.json"
    if not path.is_file():
        raise SystemExit(f"sweep: no scene {scene!r} in scenes/")
    work = ROOT / "build" / "sweep"
    work.mkdir(parents=True, exist_ok=True)
    ref_method, chunk = reference_method(scene)
    ref = Reference(path, SIDE, ref_method, chunk, work)
    own = ", ".join(f"{k} {v:.4g}" for k, v in ref.own.items())
    print(f"# {method} on {scene}, {SIDE}x{SIDE}, frame {FRAMES} of a session, medians over {SEEDS} seeds; "
          f"reference {ref_method} ({ref.samples} samples), its own error {own}")
    print(f"# command: /usr/bin/python3 bench/sweep.py {scene} {method} " + " ".join(f"'{c}'" for c in configs))
    print("\n| params | ms a frame | MAPE | relMSE | RMSE |\n|---|---|---|---|---|")
    for text in configs:
        scores, ms = [], []
        for s in range(SEEDS):
            out = work / f"{scene}-{method}-{s}.exr"
            st = run(["render", str(path), "--size", f"{SIDE}x{SIDE}", "--method", method, "--frames", str(FRAMES),
                      "--seed", str(FIRST_SEED + s), "--params", text, "--json", "-o", str(out)])
            ms.append(st["time_ms"] / FRAMES)
            scores.append(errors.metrics(read_rgb(out), ref.image))
        med = {k: statistics.median(sc[k] for sc in scores) for k in errors.KEYS}
        print(f"| `{text}` | {statistics.median(ms):.1f} | {med['mape']:.4g} | {med['relmse']:.4g} | {med['rmse']:.4g} |",
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
