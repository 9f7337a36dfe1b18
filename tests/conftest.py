"""Shared fixtures for the Python test tier: the CLI binary, renders and EXR reading.

Run through `make test` (which builds build/restir first) with Debian's /usr/bin/python3 so that
numpy and OpenImageIO are importable."""
import functools
import json
import os
import subprocess
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from stats import NullRejected

ROOT = Path(__file__).resolve().parent.parent
BIN = os.environ.get("RESTIR_BIN", str(ROOT / "build" / "restir"))


def pytest_configure(config):
    # `make test-tsan` runs the tests carrying this mark against a ThreadSanitizer daemon.
    config.addinivalue_line("markers", "concurrency: requests that overlap in the daemon (run under TSan too)")
    # `make SAN=1 test` leaves these out: hundreds of renders that test statistics, not memory;
    # the code they run is exercised under the sanitizers by smaller tests (unit/test_restir_pt.c,
    # test_daemon.py's restir_pt session).
    config.addinivalue_line("markers", "statistical: long statistical comparisons (left out of the sanitizer run)")


# Seeds of the confirming run (tests/stats.py, "Confirmation"): while a test runs a second time
# after one of its comparisons rejected equal means, every seed it gives `render` is shifted by
# this, past the largest seed a test uses (100000 + run), so that the renders are independent of
# the first run's. Caches of renders key on seed_offset().
CONFIRM_SEED_OFFSET = 1 << 20
_seed_offset = 0


def seed_offset():
    return _seed_offset


@pytest.hookimpl(tryfirst=True)
def pytest_pyfunc_call(pyfuncitem):
    """Runs the test; when a comparison rejects equal means (stats.NullRejected), runs it once more
    on independent seeds and fails only if a comparison rejects again (tests/stats.py). Any other
    failure, a negative control's included, fails at once."""
    global _seed_offset
    args = {name: pyfuncitem.funcargs[name] for name in pyfuncitem._fixtureinfo.argnames}
    try:
        pyfuncitem.obj(**args)
    except NullRejected as first:
        print(f"\n{pyfuncitem.nodeid}: rejected ({first}); confirming on independent seeds")
        if "tmp_path" in args:  # a folder of its own: what the first run wrote stays out of the way
            args["tmp_path"] = args["tmp_path"] / "confirm"
            args["tmp_path"].mkdir()
        _seed_offset = CONFIRM_SEED_OFFSET
        try:
            pyfuncitem.obj(**args)
        except NullRejected as second:
            raise NullRejected(f"rejected on two independent sets of renders: {first}; then {second}") from None
        finally:
            _seed_offset = 0
        print(f"{pyfuncitem.nodeid}: confirmed: the independent renders agree")
    return True


def read_exr(path):
    """Reads an EXR with OpenImageIO (independent of our reader): float32 array H x W x C."""
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    try:
        pixels = inp.read_image(oiio.FLOAT)
    finally:
        inp.close()
    assert pixels is not None
    return np.asarray(pixels, dtype=np.float64)


@functools.cache
def methods_taking_spp():
    """The registry's methods that take spp (the rest refuse --spp), and the default method."""
    res = subprocess.run([BIN, "methods", "--json"], capture_output=True, text=True, timeout=60, check=True)
    methods = json.loads(res.stdout)["methods"]
    return {m["name"] for m in methods if m["capabilities"]["takes_spp"]}, methods[0]["name"]


def render(scene, out, *, spp=4, size="32x32", seed=0, extra=()):
    """Runs `restir render --json` and returns (image RGB, stats dict). `spp` goes to a method
    that takes it, unless --params in `extra` sets spp itself: the CLI refuses --spp for the
    others (they trace one path per pixel and frame) and an spp given twice. In a confirming run
    the seed is shifted by seed_offset() (pytest_pyfunc_call)."""
    extra = [str(x) for x in extra]
    taking, default = methods_taking_spp()
    method = extra[extra.index("--method") + 1] if "--method" in extra else default
    params = json.loads(extra[extra.index("--params") + 1]) if "--params" in extra else {}
    spp_args = ["--spp", str(spp)] if method in taking and "spp" not in params else []
    cmd = [BIN, "render", str(scene), *spp_args, "--size", size, "--seed", str(seed + _seed_offset),
           "--json", "-o", str(out), *extra]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, f"{cmd}: {res.stderr}"
    return read_exr(out)[:, :, :3], json.loads(res.stdout)


def sky_all_round(sky):
    """The pixels of boolean image `sky` whose 3x3 neighbourhood is sky too (outside the image
    counts as sky). A pixel that holds a sliver of an object a reference render never hit borders
    one that holds more of it, so these pixels are surely all environment."""
    pad = np.pad(sky, 1, constant_values=True)
    h, w = sky.shape
    return np.all([pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)


def run_cli(*args, timeout=120):
    return subprocess.run([BIN, *map(str, args)], capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def scenes():
    return ROOT / "scenes"


def build_commit(binary):
    """The commit a binary this Makefile built must report: the one in the stamp make wrote
    beside its objects (build/obj/commit-stamp, which follows HEAD or COMMIT= at every make, so
    a tree that moved on since its build still agrees), else HEAD of this checkout, else
    "unknown" (a tree without git and no COMMIT=)."""
    stamp = Path(binary).resolve().parent / "obj" / "commit-stamp"
    if stamp.exists():
        return stamp.read_text().strip()
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return head.stdout.strip() if head.returncode == 0 else "unknown"
