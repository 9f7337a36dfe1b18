"""bench/ctool.py — builds a benchmark helper written in C (bench/NAME.c) against this build's
build/obj/librenderer.a into build/bench/NAME, for the bench scripts that run one (helpers, not
part of the daemon)."""
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def build(name):
    """Compiles bench/<name>.c; returns the path of the program."""
    out = ROOT / "build" / "bench" / name
    out.parent.mkdir(parents=True, exist_ok=True)
    exr = subprocess.run(["pkg-config", "--cflags", "OpenEXR"], capture_output=True, text=True).stdout.split()
    subprocess.run(["cc", "-O2", "-std=c17", "-D_DEFAULT_SOURCE", "-Wall", "-Wextra", "-Irenderer", *exr,
                    f"bench/{name}.c", "build/obj/librenderer.a", "-lOpenEXRCore", "-ldeflate", "-lembree3",
                    "-lassimp", "-lcjson", "-lm", "-pthread", "-o", str(out)], cwd=ROOT, check=True)
    return out
