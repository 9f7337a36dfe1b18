"""bench/references.py — the report's references: each the mean of two independent halves, so
that its own error is known (bench/errors.py), lengthened until that error is small beside the
rows it judges.

A reference is built from chunks, each one render of the scene file by `restir render` with its
own seed: chunk j goes to half A when j is even, to half B when odd; n pairs of chunks make
halves of n chunks each. Lengthening adds pairs (doubling them each time), so the chunks already
rendered stay in use. Chunks are cached in build/refs/ under the hash of the scene text (with
any camera override), the size, the method and the chunk's samples, with their render time
beside them; a later run with more chunks cached starts from all of them. The cache key holds
everything a chunk's pixels depend on: the scene text (with any camera override) and the mesh
files it names, the size, the method, the chunk's samples and the command that renders it, and
the renderer's sources (their git tree, or the binary's hash outside a checkout), so a changed
renderer never mixes old chunks with new ones in one reference.

REPORT_REF_BIN names another `restir` binary to render the references with, keyed by its hash: a
build whose reference methods (pt, bdpt, sms) give the same pixels as the build under test (check
with scripts/same_output.py), so that trying changes to the reuse methods renders each
reference once rather than after every change to renderer/."""
import functools
import hashlib
import json
import shutil
import subprocess
from pathlib import Path

import os

import numpy as np

import errors
from cputime import progress as log
from exrimage import read_rgb, write_rgb
from restir_pt import BIN, run

ROOT = Path(__file__).resolve().parent.parent
REFS = ROOT / "build" / "refs"
FIRST_SEED = 1000003
REF_BIN = os.environ.get("REPORT_REF_BIN")
QUICK = os.environ.get("QUICK") == "1"
REF_SPP = 256 if QUICK else 2048
# The scenes whose reference is not pt's, and the samples of each of their chunks: bdpt where pt
# practically never reaches the light, sms where caustics through smooth casters are the image.
REF_BY = {"lamp-in-glass": ("bdpt", 64 if QUICK else 256), "caustic-sphere": ("bdpt", 64 if QUICK else 256),
          "refractive-slab": ("sms", 32 if QUICK else 64), "reflective-plane": ("sms", 32 if QUICK else 64)}


def reference_method(scene):
    """(method, samples per chunk) of a library scene's reference."""
    return REF_BY.get(scene, ("pt", REF_SPP // 2))


# How a chunk of `n` samples is rendered by each unbiased reference method: pt at n spp; sms at n
# spp without a Bernoulli cap (the cap is what makes sms biased); bdpt as the mean of n frames.
HOW = {"pt": lambda n: ["--spp", n],
       "sms": lambda n: ["--method", "sms", "--params", json.dumps({"spp": n, "bernoulli_cap": 0})],
       "bdpt": lambda n: ["--method", "bdpt", "--frames", n, "--average-last", n]}
UNIT = {"pt": "spp", "sms": "spp", "bdpt": "frames"}


@functools.lru_cache(maxsize=None)
def renderer_version():
    """What the renderer's output depends on: the git tree of renderer/ (unchanged by commits
    elsewhere), else the hash of the binary; with REPORT_REF_BIN, that binary's hash."""
    if REF_BIN:
        return "bin-" + hashlib.sha256(Path(REF_BIN).read_bytes()).hexdigest()
    res = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD:renderer"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "renderer"], capture_output=True, text=True)
    if res.returncode == 0 and not dirty.stdout.strip():
        return res.stdout.strip()
    return hashlib.sha256(Path(BIN).read_bytes()).hexdigest()


class Reference:
    """A scene's reference at one size: halves A and B, the full image R, its own error."""

    def __init__(self, scene_path, side, method, chunk, work, camera=None):
        self.scene_path, self.side, self.method, self.chunk = Path(scene_path), side, method, chunk
        self.work, self.camera = Path(work), camera
        text = self.scene_path.read_text()
        if camera:
            sj = json.loads(text)
            sj["camera"] = camera
            text = json.dumps(sj)
        self.text = text
        h = hashlib.sha256(text.encode())
        for f in self._mesh_files():
            h.update(f.encode() + b"\0" + (self.scene_path.parent / f).read_bytes())
        h.update(json.dumps([side, method, chunk, FIRST_SEED, [str(a) for a in HOW[method](chunk)],
                             renderer_version()]).encode())
        self.key = h.hexdigest()[:16]
        REFS.mkdir(parents=True, exist_ok=True)
        self.chunks = 0
        while self._path(self.chunks).exists() and self._path(self.chunks + 1).exists():
            self.chunks += 2
        if self.chunks == 0:
            self._render_upto(2)
        self._load()

    def _mesh_files(self):
        return [sh["file"] for sh in json.loads(self.text)["shapes"] if "file" in sh]

    def _path(self, j):
        return REFS / f"ref-{self.key}-{self.side}-{self.method}-{self.chunk}-c{j}.exr"

    def _source(self):
        """The scene file to render: the original, or with the camera override a copy in a folder
        of its own with the mesh files it names."""
        if not self.camera:
            return self.scene_path
        folder = self.work / f"ref-{self.key}"
        folder.mkdir(parents=True, exist_ok=True)
        for f in self._mesh_files():
            (folder / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(self.scene_path.parent / f, folder / f)
        src = folder / "scene.json"
        src.write_text(self.text)
        return src

    def _render_upto(self, count):
        src = self._source()
        for j in range(self.chunks, count):
            path = self._path(j)
            log(f"reference chunk {j + 1}/{count} of {self.scene_path.parent.name} ({self.side}x{self.side}, "
                f"{self.method}, {self.chunk} {UNIT[self.method]})")
            tmp = path.with_suffix(".tmp.exr")
            st = run([str(a) for a in ["render", src, "--size", f"{self.side}x{self.side}",
                                       *HOW[self.method](self.chunk), "--seed", FIRST_SEED + j, "--json", "-o", tmp]], REF_BIN)
            path.with_suffix(".json").write_text(json.dumps({"time_ms": st.get("time_ms")}) + "\n")
            tmp.rename(path)
        self.chunks = max(self.chunks, count)

    def _load(self):
        a = [read_rgb(self._path(j)) for j in range(0, self.chunks, 2)]
        b = [read_rgb(self._path(j)) for j in range(1, self.chunks, 2)]
        self.half_a, self.half_b = np.mean(a, axis=0), np.mean(b, axis=0)
        self.image = errors.combine(self.half_a, self.half_b)
        self.own = errors.reference_error(self.half_a, self.half_b)
        self.seconds = sum(json.loads(self._path(j).with_suffix(".json").read_text())["time_ms"] or 0.0
                           for j in range(self.chunks)) / 1000.0
        self.path = self.work / f"ref-{self.key}-{self.side}-{self.method}.exr"
        write_rgb(self.path, self.image)

    @property
    def samples(self):
        return self.chunks * self.chunk

    def grow(self):
        """Twice the chunks: half the variance, so half the relMSE."""
        self._render_upto(2 * self.chunks)
        self._load()

    def describe(self):
        return {"method": self.method, "samples": self.samples, "unit": UNIT[self.method], "chunks": self.chunks,
                "seconds": self.seconds, "own": self.own}
