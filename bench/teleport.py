"""How a reuse method recovers from a camera teleport, over seeds and parameter sets.

The teleport of tests/test_stability.py (12 frames at the home scene's camera, then a jump to a
far camera for 8 frames), measured as that test does (MAPE at 32x32 against a 2048-spp reference
of the new view) but over several seeds and configurations: for each configuration, the medians
over the seeds of the first and the 8th frame after the jump, each over a fresh session's first and
8th frame at the new camera (means over fresh seeds 31-34). The test checks one seed against
1.3x; this gives the rows of docs/benchmarks.md's teleport tables.

    /usr/bin/python3 bench/teleport.py restir_bdpt '{"reuse": true, "history_check": false}' '{}'

Environment: TELEPORT_SEEDS (default 41,42,43,44,45), RESTIR_BIN / RESTIRD_BIN (default build/).
Each configuration's parameters are merged over the test's own for the method (METHODS there)."""
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
import test_stability as stability  # noqa: E402  (the teleport, its references and sessions)
from daemon import Daemon  # noqa: E402

FRESH_SEEDS = (31, 32, 33, 34)


def main(argv):
    if len(argv) < 3 or argv[1] not in stability.HOME:
        print(__doc__.strip(), file=sys.stderr)
        print(f"methods: {', '.join(sorted(stability.HOME))}", file=sys.stderr)
        return 2
    method, configs = argv[1], []
    for i, text in enumerate(argv[2:], start=2):
        try:
            params = json.loads(text)
        except json.JSONDecodeError as e:
            print(f"argument {i}: not JSON ({e})", file=sys.stderr)
            return 2
        if not isinstance(params, dict):
            print(f"argument {i}: expected a JSON object of parameters", file=sys.stderr)
            return 2
        configs.append((text, params))
    seeds = [int(s) for s in os.environ.get("TELEPORT_SEEDS", "41,42,43,44,45").split(",")]
    tmp = Path(tempfile.mkdtemp(prefix="teleport-"))
    (tmp / "refs").mkdir()
    home_name = stability.HOME[method]
    camera = stability.HOMES[home_name]["teleport"]
    base = dict(stability.METHODS[method])
    d = Daemon(tmp / "data", "--threads", "2", "--frames-kept", "4")
    try:
        ref = stability.Refs(tmp / "refs")(home_name, "teleport")
        print(f"{method} on {home_name}, seeds {seeds}: first and 8th frame after the teleport over a fresh "
              "session's", flush=True)
        for text, params in configs:
            stability.METHODS[method] = {**base, **params}
            f1 = stability._fresh_error(d, tmp, ref, method, camera, 1, seeds=FRESH_SEEDS)
            f8 = stability._fresh_error(d, tmp, ref, method, camera, 8, seeds=FRESH_SEEDS)
            first, eighth = [], []
            for seed in seeds:
                s = stability.Session(d, tmp, method, seed=seed)
                s.frames(12)
                after = s.frames(8, {"camera": camera})
                s.close()
                first.append(stability.mape(after[0], ref))
                eighth.append(stability.mape(after[7], ref))
            print(f"{text}: first {np.median(first) / f1:.2f} (median MAPE {np.median(first):.3f}, fresh {f1:.3f}), "
                  f"8th {np.median(eighth) / f8:.2f} ({np.median(eighth):.3f}, fresh {f8:.3f})", flush=True)
    finally:
        d.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
