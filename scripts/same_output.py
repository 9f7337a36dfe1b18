#!/usr/bin/python3
"""Checks that two builds of the offline CLI render the same bytes.

For every method the new build's registry lists (`restir methods --json`) and every library
scene it renders 32x32, 4 frames, a fixed seed, with each
build, and compares the EXR files byte for byte and the --json statistics with their timings
removed (times differ from run to run; counts, means and sizes must not). A method that refuses
a scene must refuse it in both builds at the same place (the message's JSON pointer or file);
where the words differ, both messages are printed beside the pair.

    /usr/bin/python3 scripts/same_output.py OLD/restir NEW/restir [--keep DIR]

Prints one line per pair and a closing 'N passed, N failed' line; exits 1 on any difference.
Used to show that a refactoring changed no image and no counter.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES_DIR = os.path.join(HERE, "..", "scenes")


def methods(binary):
    """Every method the CLI knows (its `methods --json`, the registry)."""
    out = subprocess.run([binary, "methods", "--json"], capture_output=True, text=True, check=True).stdout
    return [m["name"] for m in json.loads(out)["methods"]]


def timing_free(stats):
    """The statistics without the keys that measure time."""
    if isinstance(stats, dict):
        return {k: timing_free(v) for k, v in stats.items()
                if not (k.endswith("_ms") or k == "ms" or k.endswith("_per_s") or k == "threads")}
    if isinstance(stats, list):
        return [timing_free(v) for v in stats]
    return stats


def render(binary, scene, method, out_dir):
    exr = os.path.join(out_dir, f"{method}-{scene}.exr")
    cmd = [binary, "render", os.path.join(SCENES_DIR, scene), "--method", method, "--size", "32x32",
           "--frames", "4", "--seed", "7", "--json", "-o", exr]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    result = {"rc": run.returncode}
    message = run.stderr.strip()
    if run.returncode:
        # "restir: /method: ..." -> "/method": where the refusal points.
        result["refused_at"] = message.split(": ")[1] if message.count(": ") >= 2 else message
        result["message"] = message
    if run.returncode == 0:
        result["stats"] = timing_free(json.loads(run.stdout))
        with open(exr, "rb") as f:
            result["exr"] = f.read()
    return result


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("--keep", help="write the renders here instead of a temporary folder")
    args = ap.parse_args()
    scenes = sorted(d for d in os.listdir(SCENES_DIR) if os.path.isfile(os.path.join(SCENES_DIR, d, "scene.json")))
    passed = failed = 0
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or tmp
        dirs = [os.path.join(root, "old"), os.path.join(root, "new")]
        for d in dirs:
            os.makedirs(d, exist_ok=True)
        # The new build's methods: a build from before `restir methods` existed is the old one.
        for method in methods(args.new):
            for scene in scenes:
                a = render(args.old, scene, method, dirs[0])
                b = render(args.new, scene, method, dirs[1])
                what = "refused" if a["rc"] else "rendered"
                diff = [k for k in sorted(set(a) | set(b)) if k != "message" and a.get(k) != b.get(k)]
                if not diff:
                    passed += 1
                    print(f"same  {method:12s} {scene:18s} {what}")
                    if a.get("message") != b.get("message"):
                        print(f"      old words: {a['message']}\n      new words: {b['message']}")
                else:
                    failed += 1
                    print(f"DIFF  {method:12s} {scene:18s} {', '.join(diff)}")
                    if "message" in a or "message" in b:
                        print(f"      old: {a.get('message')}\n      new: {b.get('message')}")
    print(f"{passed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
