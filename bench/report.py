"""bench/report.py — `make bench-report`: speed against accuracy for every scene and the methods
that apply to it, stability over frames, and a peer renderer on the same axes. Writes
docs/report/ (README.md, the CSV every chart is drawn from, SVG charts); work files go to
build/report/, references are cached in build/refs/.

  /usr/bin/python3 bench/report.py            # 256x256, 3 seeds (under an hour on 2 cores, references included)
  QUICK=1 /usr/bin/python3 bench/report.py    # 64x64, 1 seed, short ladders (a few minutes)

What it measures, per scene (SCENES) and method (METHODS):
  * error against time: each method's own ladder of settings — `pt` at 1, 2, 4 ... spp; a
    method of sessions as the mean of the first k frames after its warm-up frames in one daemon
    session per seed (k = 1, 2, 4 ...; time = their render times) — with MAPE and RMSE against a
    reference (medians over seeds), charted log-log; which method has the lowest MAPE at three time
    budgets (pt's time at 1, 4 and 16 spp), and by what factor over the next best; a method
    is compared only inside the time range it was measured over;
  * per-pass times of one frame (the reusing methods' passes) and memory per session;
  * stability on cornell-box: flicker, correlation of consecutive frames, fast camera motion, a
    camera teleport, the light switched off and on (per-frame series through the daemon),
    non-finite pixels over 100 frames of every scene, and restir_pt's known weak case (a light
    behind glass);
  * the papers' failure cases: bdpt's light tracing wasted on a light the camera cannot see
    ([ReSTIR BDPT Fig. 10]), ReSTIR SSS's shifts on a shadow boundary ([ReSTIR SSS Fig. 5]) and the
    sample-space prior missing a light ([SMS-SSP Fig. 10]);
  * the peer: Blender Cycles (Debian's `blender`, CPU, bench/crosscheck_cycles.py) on
    cornell-box at several spp, on the same error axes against the same reference, with and
    without its light sampling, and the radiometric agreement of its converged image with ours.
Environment: QUICK=1, BENCH_THREADS (all cores), REPORT_SCENES (comma list), REPORT_NO_CYCLES=1."""
import csv
import hashlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# bench/ first: `daemon` is bench/daemon.py (as for every bench), whose test_daemon is
# tests/daemon.py's (sessions through req()), which the report drives; the tests' helpers
# (test_stability, test_failure_cases, stats) come from tests/.
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "bench"))
import restir_pt  # noqa: E402
from daemon import test_daemon  # noqa: E402
import svgplot  # noqa: E402
from curves import loglog_at  # noqa: E402
from restir_pt import compare_all as compare  # noqa: E402

QUICK = os.environ.get("QUICK") == "1"
BIN = str(ROOT / "build" / "restir")
OUT = ROOT / "docs" / "report"
WORK = ROOT / "build" / "report"
REFS = ROOT / "build" / "refs"
THREADS = os.environ.get("BENCH_THREADS", str(os.cpu_count() or 1))
SIDE = 64 if QUICK else 256
SIZE = f"{SIDE}x{SIDE}"
SEEDS = 1 if QUICK else 3
REF_SPP = 256 if QUICK else 2048
STAB_SIDE = 32 if QUICK else 64

# How each method is run. "spp": one frame at each spp of the ladder. "frames": one session,
# `warmup` frames, then the mean of the next k frames for each k of the ladder.
METHODS = {
    "pt": {"kind": "spp", "params": {}, "ladder": [1, 4, 16] if QUICK else [1, 2, 4, 8, 16, 32, 64]},
    "restir_pt": {"kind": "frames", "params": {}, "warmup": 8 if QUICK else 32,
                  "ladder": [1, 4] if QUICK else [1, 2, 4, 8, 16]},
    # One bidirectional sample per pixel per frame, frames independent: the mean of k frames.
    "bdpt": {"kind": "frames", "params": {}, "warmup": 0, "ladder": [1, 4, 16] if QUICK else [1, 2, 4, 8, 16, 32]},
    # Its caustic reservoirs carry over frames: warm-up first, as the other reusing methods.
    "restir_bdpt": {"kind": "frames", "params": {}, "warmup": 8 if QUICK else 32,
                    "ladder": [1, 4] if QUICK else [1, 2, 4, 8, 16]},
    # Path tracing with specular manifold sampling, spp per frame (default Bernoulli cap).
    "sms": {"kind": "spp", "params": {}, "ladder": [1, 4] if QUICK else [1, 2, 4, 8, 16]},
    "sms_ssp": {"kind": "spp", "params": {}, "ladder": [1, 4] if QUICK else [1, 2, 4, 8, 16]},
    "restir_sss": {"kind": "frames", "params": {}, "warmup": 8 if QUICK else 32,
                   "ladder": [1, 4] if QUICK else [1, 2, 4, 8, 16]},
    "restir_sms": {"kind": "frames", "params": {}, "warmup": 8 if QUICK else 32,
                   "ladder": [1, 4] if QUICK else [1, 2, 4, 8, 16]},
}
ALL_SCENES = {"cornell-box": ["pt", "restir_pt", "bdpt", "restir_bdpt"],
              "cornell-glossy": ["pt", "restir_pt", "bdpt", "restir_bdpt"],
              "door-ajar": ["pt", "restir_pt", "bdpt", "restir_bdpt"],
              "lamp-in-glass": ["pt", "restir_pt", "bdpt", "restir_bdpt"],
              "caustic-sphere": ["pt", "restir_pt", "bdpt", "restir_bdpt", "sms", "sms_ssp", "restir_sms"],
              "refractive-slab": ["pt", "restir_pt", "sms", "sms_ssp", "restir_sms"],
              "reflective-plane": ["pt", "restir_pt", "sms", "sms_ssp", "restir_sms"], "translucent": ["pt", "restir_sss"]}
SCENES = {s: ALL_SCENES[s] for s in os.environ.get("REPORT_SCENES", ",".join(ALL_SCENES)).split(",")}
# Scenes whose light pt practically never finds are referenced by the method that finds it:
# bdpt (mean of independent frames) through glass and for point-like caustics, sms (spp, no
# Bernoulli cap: unbiased) for the caustics of the slab and the bumpy mirror.
REF_BY = {"lamp-in-glass": ("bdpt", 128 if QUICK else 512), "caustic-sphere": ("bdpt", 128 if QUICK else 512),
          "refractive-slab": ("sms", 64 if QUICK else 128), "reflective-plane": ("sms", 64 if QUICK else 128)}
PASSES = ["gbuffer_ms", "initial_ms", "temporal_ms", "spatial_ms", "shade_ms", "light_ms", "splat_ms", "sort_ms",
          "camera_ms", "reuse_ms"]


def log(msg):
    print(f"report: {msg}", file=sys.stderr, flush=True)


def run(args):
    return restir_pt.run([str(a) for a in args])


def reference(scene_path, side=SIDE, spp=REF_SPP, camera=None, method="pt"):
    """A cached reference of a scene file (optionally with another camera): pt at `spp`, sms at
    `spp` without a Bernoulli cap, or bdpt as the mean of `spp` frames."""
    text = scene_path.read_text()
    if camera:
        sj = json.loads(text)
        sj["camera"] = camera
        text = json.dumps(sj)
    key = hashlib.sha256(text.encode()).hexdigest()[:16]
    REFS.mkdir(parents=True, exist_ok=True)
    ref = REFS / f"report-{key}-{side}-{spp}spp-{method}.exr"
    if not ref.exists():
        log(f"rendering a {method} reference of {scene_path.name} ({side}x{side}, {spp} spp)")
        src = scene_path
        if camera:
            # The changed scene goes into a folder of its own with the mesh files it names.
            folder = WORK / f"ref-{key}"
            folder.mkdir(parents=True, exist_ok=True)
            for shape in json.loads(text)["shapes"]:
                if "file" in shape:
                    shutil.copy(scene_path.parent / shape["file"], folder / shape["file"])
            src = folder / "scene.json"
            src.write_text(text)
        tmp = ref.with_suffix(".tmp.exr")
        how = {"pt": ["--spp", spp],
               "sms": ["--method", "sms", "--params", json.dumps({"spp": spp, "bernoulli_cap": 0})],
               "bdpt": ["--method", "bdpt", "--frames", spp, "--average-last", spp]}[method]
        run(["render", src, "--size", f"{side}x{side}", *how, "--seed", 999983, "--json", "-o", tmp])
        tmp.rename(ref)
    return ref


# ---- error against time ------------------------------------------------------------------------

def measure(scene, method, ref, d):
    """A method's rows: for "spp", one CLI render per setting and seed; for "frames", one daemon
    session per seed whose frames after the warm-up are fetched one by one, the mean of the
    first k of them being the image of setting k and the sum of their render times its time.
    (A session's frames depend only on its seed and frame numbers, so this is the image a
    session of warm-up + k frames averaging its last k would give, without rendering the
    warm-up once per setting.)"""
    m = METHODS[method]
    path = ROOT / "scenes" / scene / "scene.json"
    if m["kind"] == "frames":
        per = {k: {"ms": [], "mape": [], "rmse": [], "passes": []} for k in m["ladder"]}
        mem = None
        for seed in range(SEEDS):
            r = d.req("POST", f"/v1/scenes/{scene}/sessions",
                      json_body={"method": method, "width": SIDE, "height": SIDE, "seed": seed, "params": m["params"]})
            if r.status != 201:
                raise SystemExit(f"report: {scene} {method} session: {r!r}")
            sess = r.json()
            mem = sess["memory_bytes"]
            acc, ms = None, 0.0
            for i in range(m["warmup"] + max(m["ladder"])):
                r = d.req("POST", sess["href"] + "/frames", headers={"Accept": "application/json"})
                if r.status != 200:
                    raise SystemExit(f"report: {scene} {method} frame: {r!r}")
                st = r.json()
                if i < m["warmup"]:
                    continue
                r = d.req("GET", st["href"], headers={"Accept": "image/x-exr"})
                if r.status != 200:
                    raise SystemExit(f"report: {scene} {method} frame image: {r!r}")
                frame = WORK / "frame.exr"
                frame.write_bytes(r.body)
                img = read_rgb(frame)
                acc = img if acc is None else acc + img
                ms += st["render_ms"]
                k = i - m["warmup"] + 1
                if k in per:
                    out = WORK / f"{scene}-{method}-{k}-{seed}.exr"
                    write_rgb(out, acc / k)
                    c = compare(out, ref)
                    for key, v in (("ms", ms), ("mape", c["mape"]), ("rmse", c["rmse"]), ("passes", frame_passes(st))):
                        per[k][key].append(v)
            d.req("DELETE", sess["href"])
        rows = []
        for k, v in per.items():
            row = {"scene": scene, "method": method, "setting": k, "unit": "frames averaged after the warm-up",
                   "ms": statistics.median(v["ms"]), "mape": statistics.median(v["mape"]),
                   "rmse": statistics.median(v["rmse"]), "session_bytes": mem}
            if v["passes"] and v["passes"][0]:
                row["passes"] = {x: statistics.median(p[x] for p in v["passes"]) for x in v["passes"][0]}
            rows.append(row)
            log(f"{scene} {method} {k}: {row['ms']:.1f} ms, MAPE {row['mape']:.3f}")
        return rows
    rows = []
    for setting in m["ladder"]:
        ms, mape, rmse, mem = [], [], [], None
        for seed in range(SEEDS):
            img = WORK / f"{scene}-{method}-{setting}-{seed}.exr"
            st = run(["render", path, "--method", method, "--size", SIZE, "--spp", setting, "--seed", seed,
                      "--json", "-o", img])
            ms.append(st["time_ms"])
            mem = st.get("session_bytes")
            c = compare(img, ref)
            mape.append(c["mape"])
            rmse.append(c["rmse"])
        row = {"scene": scene, "method": method, "setting": setting, "unit": "spp",
               "ms": statistics.median(ms), "mape": statistics.median(mape), "rmse": statistics.median(rmse),
               "session_bytes": mem}
        rows.append(row)
        log(f"{scene} {method} {setting}: {row['ms']:.1f} ms, MAPE {row['mape']:.3f}")
    return rows


def frame_passes(st):
    """A daemon frame's per-pass times: every `*_ms` member of its method's statistics object."""
    return {k: v for obj in st.values() if isinstance(obj, dict) for k, v in obj.items() if k.endswith("_ms")}


def write_rgb(path, img):
    import numpy as np
    import OpenImageIO as oiio
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), oiio.ImageSpec(img.shape[1], img.shape[0], 3, oiio.FLOAT)):
        raise SystemExit(f"report: cannot write {path}: {oiio.geterror()}")
    out.write_image(np.ascontiguousarray(img, dtype=np.float32))
    out.close()


def at_time(rows, ms, key="mape"):
    """A method's error at a time, interpolated log-log inside its measured range (None outside)."""
    return loglog_at([(r["ms"], r[key]) for r in rows], ms)


# ---- stability (through the daemon) ------------------------------------------------------------

CORNELL = ROOT / "scenes" / "cornell-box" / "scene.json"
TELEPORT_CAMERA = {"position": [60, 480, 60], "look_at": [380, 100, 380], "up": [0, 1, 0], "fov_deg": 50.0}


def read_rgb(path):
    from conftest import read_exr
    return read_exr(path)[:, :, :3]


def np_mape(img, ref):
    import numpy as np
    return float(np.mean(np.abs(img - ref) / (ref + 0.01 * ref.mean())))


class Frames:
    """One daemon session whose frames come back as arrays."""

    def __init__(self, d, scene, method, seed, side, params=None):
        if params is None:
            params = METHODS[method]["params"] if method != "pt" else {"spp": 1}
        r = d.req("POST", f"/v1/scenes/{scene}/sessions",
                  json_body={"method": method, "width": side, "height": side, "seed": seed, "params": params})
        if r.status != 201:
            raise SystemExit(f"report: session: {r!r}")
        self.d, self.href, self.path = d, r.json()["href"], WORK / "frame.exr"

    def next(self, body=None):
        r = self.d.req("POST", self.href + "/frames", headers={"Accept": "image/x-exr"}, json_body=body)
        if r.status != 200:
            raise SystemExit(f"report: frame: {r!r}")
        self.path.write_bytes(r.body)
        return read_rgb(self.path)

    def close(self):
        self.d.req("DELETE", self.href)


def glass_lamp_scene():
    sj = json.loads(CORNELL.read_text())
    sj["shapes"] = [s for s in sj["shapes"] if s.get("name") != "ceiling_light"]
    sj["materials"]["lamp"] = {"type": "diffuse", "albedo": [0, 0, 0], "emission": [34, 24, 8]}
    sj["materials"]["glass"] = {"type": "dielectric", "ior": 1.5}
    sj["shapes"] += [{"type": "sphere", "material": "lamp", "center": [278, 420, 280], "radius": 25},
                     {"type": "sphere", "material": "glass", "center": [278, 420, 280], "radius": 40}]
    path = WORK / "glass-lamp.json"
    path.write_text(json.dumps(sj))
    return path


def stability():
    import numpy as np
    from test_stability import SWEEP, SWEEP_FRAMES, swept_camera
    side = STAB_SIDE
    frames = 24 if QUICK else 40
    # The methods cornell-box is a scene for (sms and restir_sss would render it as pt does:
    # tests/test_stability.py checks them on refractive-slab and translucent).
    methods = [m for m in ("pt", "restir_pt", "bdpt", "restir_bdpt") if m in METHODS]
    d = test_daemon.Daemon(Path(tempfile.mkdtemp(dir=WORK)) / "data", "--threads", THREADS, "--frames-kept", "2")
    out = {"side": side, "frames": frames, "series": {}, "correlation": {}, "nonfinite": {},
           "sweep_fraction": SWEEP, "sweep_frames": SWEEP_FRAMES}
    try:
        ref_a = read_rgb(reference(CORNELL, side, REF_SPP))
        ref_b = read_rgb(reference(CORNELL, side, REF_SPP, TELEPORT_CAMERA))
        # Fast camera motion (tests/test_stability.py): SWEEP_FRAMES frames sliding sideways,
        # each against a reference from its own camera.
        sweep_cams = [swept_camera("cornell-box", SWEEP * i / SWEEP_FRAMES) for i in range(1, SWEEP_FRAMES + 1)]
        sweep_refs = [read_rgb(reference(CORNELL, side, REF_SPP, c)) for c in sweep_cams]
        lamp = glass_lamp_scene()
        r = d.req("PUT", "/v1/scenes/glass-lamp", body=lamp.read_bytes(), headers={"Content-Type": "application/json"})
        if r.status not in (200, 201):
            raise SystemExit(f"report: glass-lamp: {r!r}")
        ref_lamp = read_rgb(reference(lamp, side, REF_SPP * 2))
        half = frames // 2
        for m in methods:
            log(f"stability: {m}")
            s = Frames(d, "cornell-box", m, 1, side)
            still = [s.next() for _ in range(frames)]
            s.close()
            flicker = [float(np.mean(np.abs(b - a) / (ref_a + 0.01 * ref_a.mean()))) for a, b in zip(still, still[1:])]
            s = Frames(d, "cornell-box", m, 2, side)
            tele = [np_mape(s.next(), ref_a) for _ in range(half)]
            tele += [np_mape(s.next({"camera": TELEPORT_CAMERA} if i == 0 else None), ref_b) for i in range(frames - half)]
            s.close()
            s = Frames(d, "cornell-box", m, 6, side)
            sweep = [np_mape(s.next(), ref_a) for _ in range(half)]
            sweep += [np_mape(s.next({"camera": c}), r) for c, r in zip(sweep_cams, sweep_refs)]
            sweep += [np_mape(s.next(), sweep_refs[-1]) for _ in range(frames - half - SWEEP_FRAMES)]
            s.close()
            s = Frames(d, "cornell-box", m, 3, side)
            light, off_max = [], 0.0
            for i in range(frames):
                body = ({"lights": {"ceiling_light": {"emission": [0, 0, 0]}}} if i == half - 4 else
                        {"lights": {"ceiling_light": {"emission": [17, 12, 4]}}} if i == half else None)
                img = s.next(body)
                if half - 4 <= i < half:
                    off_max = max(off_max, float(img.max()))
                    light.append(None)
                else:
                    light.append(np_mape(img, ref_a))
            s.close()
            s = Frames(d, "glass-lamp", m, 4, side)
            glass = [np_mape(s.next(), ref_lamp) for _ in range(frames)]
            s.close()
            # Correlation: mean of 8 consecutive frames vs the same frame of 8 independent sessions.
            s = Frames(d, "cornell-box", m, 5, side)
            seq = [s.next() for _ in range(16)]
            s.close()
            ind = []
            for k in range(8):
                s = Frames(d, "cornell-box", m, 100 + k, side)
                ind.append([s.next() for _ in range(9)][-1])
                s.close()
            ratio = np_mape(np.mean(seq[8:], axis=0), ref_a) / np_mape(np.mean(ind, axis=0), ref_a)
            out["series"][m] = {"flicker": flicker, "teleport": tele, "sweep": sweep, "light": light, "light_off_max": off_max,
                                "glass_lamp": glass}
            out["correlation"][m] = ratio
        for scene, ms in ALL_SCENES.items():
            for m in ms:
                st = run(["render", ROOT / "scenes" / scene / "scene.json", "--method", m, "--size", "16x16",
                          "--frames", 100, "--seed", 7, "--json", "-o", WORK / "nf.exr"])
                out["nonfinite"][f"{scene}/{m}"] = st["nonfinite"]
    finally:
        d.stop()
    return out


# ---- the papers' failure cases (tests/test_failure_cases.py checks them at 32x32) ----------------

SSS_SHIFTS = ["reconnection", "delayed", "hybrid", "sequential"]


def failure_cases():
    """Light tracing wasted on a light the camera cannot see ([ReSTIR BDPT Fig. 10]): bdpt's
    light-traced samples per light subpath and its light pass's share of the frame, per scene.
    Shadow boundaries for ReSTIR SSS's hybrid shift ([ReSTIR SSS Fig. 5]): per shift, the RMSE per
    frame on the wax sphere's shadow-boundary band, and on its lit and shadowed parts."""
    import numpy as np
    from test_failure_cases import boundary_masks
    out = {"light_tracing": {}, "sss": {}}
    for scene, ms in ALL_SCENES.items():
        if "bdpt" not in ms:
            continue
        st = run(["render", ROOT / "scenes" / scene / "scene.json", "--method", "bdpt", "--size", SIZE, "--frames", 4,
                  "--seed", 1, "--json", "-o", WORK / "lt.exr"])
        f = st["last_frame"]
        out["light_tracing"][scene] = {k: f[k] for k in ("light_subpaths", "light_traced", "light_ms", "camera_ms")}
    side, frames = STAB_SIDE, 24 if QUICK else 40
    work = WORK / "sss-boundary"
    work.mkdir(parents=True, exist_ok=True)
    sphere, band, lit, dark = boundary_masks(work, side)
    regions = {"band": band, "lit": lit & ~band, "shadowed": dark & ~band}
    ref = read_rgb(reference(ROOT / "scenes" / "translucent" / "scene.json", side, REF_SPP))
    out["sss"] = {"side": side, "frames": frames, "pixels": {k: int(v.sum()) for k, v in regions.items()},
                  "series": {}}
    d = test_daemon.Daemon(Path(tempfile.mkdtemp(dir=WORK)) / "data", "--threads", THREADS, "--frames-kept", "2")
    try:
        for name, method, params in ([("pt 1 spp", "pt", {"spp": 1})] +
                                     [(sh, "restir_sss", {"shift": sh}) for sh in SSS_SHIFTS]):
            log(f"failure cases: translucent, {name}")
            per_seed = []
            for seed in range(SEEDS):
                s = Frames(d, "translucent", method, 40 + seed, side, params)
                imgs = [s.next() for _ in range(frames)]
                s.close()
                per_seed.append({k: [float(np.sqrt(np.mean((im[m] - ref[m]) ** 2))) for im in imgs]
                                 for k, m in regions.items()})
            out["sss"]["series"][name] = {k: [statistics.median(ps[k][i] for ps in per_seed) for i in range(frames)]
                                          for k in regions}
    finally:
        d.stop()
    out["prior"] = prior_misses_a_light(side)
    return out


# [SMS-SSP Fig. 10]: the per-frame prior misses (light, caster) pairs. refractive-slab has two
# lights; with 2 prior walks per 16x16 block most blocks find no solution for one or both of
# them, and a pair without one falls back to partitioning alone (alpha = 0) in that block;
# `prior: false` is that fallback everywhere.
PRIOR_CASES = [("sms", "sms", {}), ("sms_ssp", "sms_ssp", {}),
               ("sms_ssp, prior of 2 walks per block", "sms_ssp", {"prior_samples": 2}),
               ("sms_ssp, no prior (fallback)", "sms_ssp", {"prior": False}),
               ("restir_sms", "restir_sms", {}),
               ("restir_sms, prior of 2 walks per block", "restir_sms", {"prior_samples": 2}),
               ("restir_sms, no prior (fallback)", "restir_sms", {"prior": False})]
# The chart's bar labels (the table names them in full).
PRIOR_TAGS = {"sms": "sms", "sms_ssp": "ssp", "sms_ssp, prior of 2 walks per block": "ssp·2",
              "sms_ssp, no prior (fallback)": "ssp·0", "restir_sms": "rsms",
              "restir_sms, prior of 2 walks per block": "rsms·2", "restir_sms, no prior (fallback)": "rsms·0"}
PRIOR_SPP, PRIOR_FRAMES = 4, 9


def prior_misses_a_light(side):
    """Per setting on refractive-slab: time, RMSE against the uncapped sms reference, and the
    manifold walks' success rate. sms and sms_ssp at PRIOR_SPP spp; restir_sms the last frame of
    a PRIOR_FRAMES-frame session (its reservoirs carry the history)."""
    scene = ROOT / "scenes" / "refractive-slab" / "scene.json"
    ref = reference(scene, side, REF_BY["refractive-slab"][1], method="sms")
    rows = {}
    for name, method, params in PRIOR_CASES:
        log(f"failure cases: refractive-slab, {name}")
        ms, rmse, rate, prior = [], [], [], []
        for seed in range(SEEDS):
            img = WORK / f"prior-{len(rows)}-{seed}.exr"
            if method == "restir_sms":
                how = ["--params", json.dumps(params), "--frames", PRIOR_FRAMES]
            else:
                how = ["--params", json.dumps({"spp": PRIOR_SPP, **params})]
            st = run(["render", scene, "--method", method, "--size", f"{side}x{side}", "--seed", 60 + seed, *how,
                      "--json", "-o", img])
            frames = PRIOR_FRAMES if method == "restir_sms" else 1
            ms.append(st["time_ms"] / frames)
            rmse.append(compare(img, ref)["rmse"])
            rate.append(st["sms"]["solutions"] / max(1, st["sms"]["samples"]))
            prior.append(st.get("prior", {}).get("solutions", 0))
        rows[name] = {"ms": statistics.median(ms), "rmse": statistics.median(rmse),
                      "success": statistics.median(rate), "prior_solutions": statistics.median(prior)}
    return {"side": side, "spp": PRIOR_SPP, "frames": PRIOR_FRAMES, "rows": rows}


# ---- the peer: Blender Cycles ------------------------------------------------------------------

def cycles(ref, our_rows):
    if os.environ.get("REPORT_NO_CYCLES") == "1" or not shutil.which("blender"):
        log("Blender not found (or REPORT_NO_CYCLES=1): no peer")
        return None
    out = {"rows": [], "converged": None}
    ladder = [1, 16] if QUICK else [1, 4, 16, 64, 256]
    for ls in ("on", "off"):
        for spp in ladder:
            ms, mape, rmse = [], [], []
            for seed in range(SEEDS):
                img = WORK / f"cycles-{ls}-{spp}-{seed}.exr"
                res = subprocess.run(["blender", "-b", "--factory-startup", "-P", str(ROOT / "bench" / "crosscheck_cycles.py"),
                                      "--", "--scene", str(CORNELL), "--size", SIZE, "--spp", str(spp), "--seed", str(seed),
                                      "--threads", THREADS, "--light-sampling", ls, "--out", str(img)],
                                     capture_output=True, text=True, timeout=3600)
                line = [x for x in res.stdout.splitlines() if "render_ms" in x]
                if res.returncode != 0 or not line:
                    raise SystemExit(f"report: blender: {res.stderr[-2000:]}")
                ms.append(float(line[-1].split()[-1]))
                c = compare(img, ref)
                mape.append(c["mape"])
                rmse.append(c["rmse"])
            row = {"method": f"cycles (light sampling {ls})", "setting": spp, "unit": "spp",
                   "ms": statistics.median(ms), "mape": statistics.median(mape), "rmse": statistics.median(rmse)}
            out["rows"].append(row)
            log(f"cycles {ls} {spp} spp: {row['ms']:.1f} ms, MAPE {row['mape']:.3f}")
    # Radiometric agreement: Cycles at the reference's spp (light sampling off: unbiased here,
    # docs/crosscheck.md) against our reference, channel by channel.
    img = WORK / "cycles-converged.exr"
    res = subprocess.run(["blender", "-b", "--factory-startup", "-P", str(ROOT / "bench" / "crosscheck_cycles.py"),
                          "--", "--scene", str(CORNELL), "--size", SIZE, "--spp", str(REF_SPP), "--seed", "7",
                          "--threads", THREADS, "--light-sampling", "off", "--out", str(img)],
                         capture_output=True, text=True, timeout=7200)
    if res.returncode != 0:
        raise SystemExit(f"report: blender: {res.stderr[-2000:]}")
    a, b = read_rgb(img), read_rgb(ref)
    out["converged"] = {"spp": REF_SPP, "mean_cycles": a.mean(axis=(0, 1)).tolist(), "mean_ours": b.mean(axis=(0, 1)).tolist(),
                        "ratio": (a.mean(axis=(0, 1)) / b.mean(axis=(0, 1))).tolist(), "mape": compare(img, ref)["mape"]}
    return out


# ---- the report --------------------------------------------------------------------------------

def fmt_bytes(n):
    return f"{n / 2**20:.1f} MiB" if n else "—"


def write(results, stab, peer, fail, started, elapsed):
    OUT.mkdir(parents=True, exist_ok=True)
    for old in OUT.glob("*.svg"):
        old.unlink()
    rows = [r for scene in results.values() for rs in scene.values() for r in rs]
    with open(OUT / "error_vs_time.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scene", "method", "setting", "unit", "ms", "mape", "rmse", "session_bytes", *PASSES])
        for r in rows + [{"scene": "cornell-box", **p, "session_bytes": None} for p in (peer or {}).get("rows", [])]:
            p = r.get("passes", {})
            w.writerow([r["scene"], r["method"], r["setting"], r["unit"], f"{r['ms']:.3f}", f"{r['mape']:.5f}",
                        f"{r['rmse']:.6f}", r["session_bytes"] or "", *[f"{p[k]:.3f}" if k in p else "" for k in PASSES]])
    md = ["# Speed against accuracy: the report", "",
          f"Generated by `{'QUICK=1 ' if QUICK else ''}make bench-report` on {started} UTC in {elapsed / 60:.1f} minutes "
          f"({os.cpu_count()} cores, {THREADS} threads). Every number and chart below comes from that run; the data "
          "are in [error_vs_time.csv](error_vs_time.csv) and [stability.json](stability.json).", "",
          f"Images {SIZE}; references: `pt` at {REF_SPP} spp, or where pt practically never finds the light "
          + ", ".join(f"{sc}: `{m}` ({n} {'frames' if m == 'bdpt' else 'spp, no Bernoulli cap'})" for sc, (m, n) in REF_BY.items())
          + f"; cached in build/refs/; medians over {SEEDS} seed(s). "
          "Errors: MAPE as [ReSTIR BDPT footnote 3] and RMSE, against the reference. Time: a frame's render time "
          "(`pt`, `sms`, `sms_ssp`: the frame at that spp; a method of sessions: the summed render times of the k "
          "frames after its warm-up frames whose mean is the image, one daemon session per seed).", "", "## Which method wins each scene", "",
          "Lowest MAPE at three time budgets (pt's frame time at 1, 4 and 16 spp); a method counts only inside "
          "the time range it was measured over; the factor is the next best's MAPE over the winner's.", "",
          "| scene | budget | winner | MAPE | next best | factor |", "|---|---|---|---|---|---|"]
    for scene, per in results.items():
        pt = {r["setting"]: r["ms"] for r in per.get("pt", [])}
        for spp in (1, 4, 16):
            if spp not in pt:
                continue
            ms = pt[spp]
            cands = sorted((v, m) for m, rs in per.items() if (v := at_time(rs, ms)) is not None)
            if not cands:
                continue
            nxt = f"{cands[1][1]} ({cands[1][0]:.3f})" if len(cands) > 1 else "—"
            fac = f"{cands[1][0] / cands[0][0]:.2f}×" if len(cands) > 1 else "—"
            md.append(f"| {scene} | {ms:.0f} ms | {cands[0][1]} | {cands[0][0]:.3f} | {nxt} | {fac} |")
    md += ["", "## Error against time", ""]
    for scene, per in results.items():
        for key, label in (("mape", "MAPE"), ("rmse", "RMSE")):
            series = [(m, [(r["ms"], r[key]) for r in rs], "line") for m, rs in per.items()]
            if scene == "cornell-box" and peer:
                for name in sorted({r["method"] for r in peer["rows"]}):
                    series.append((name, [(r["ms"], r[key]) for r in peer["rows"] if r["method"] == name], "line"))
            svgplot.loglog(OUT / f"{scene}_{key}.svg", f"{scene}: {label} against time ({SIZE})",
                           "time (ms)", label, series)
        md += [f"### {scene}", "", f"![MAPE]({scene}_mape.svg)", "", f"![RMSE]({scene}_rmse.svg)", "",
               "| method | setting | ms | MAPE | RMSE |", "|---|---|---|---|---|"]
        for m, rs in per.items():
            for r in rs:
                setting = f"{r['setting']} spp" if r["unit"] == "spp" else f"mean of the last {r['setting']} frame(s)"
                md.append(f"| {m} | {setting} | {r['ms']:.1f} | {r['mape']:.4f} | {r['rmse']:.5f} |")
        md.append("")
    md += ["## Where a frame's time goes, and memory", "",
           "One frame of each reusing method (the 1-frame setting), per pass, and each session's memory "
           "(`memory_bytes` of its daemon session, or `session_bytes` of the CLI for the methods rendered by spp: "
           "the buffers a session of that method and size holds).", ""]
    bars = [(f"{s}/{m}", rs[0]["passes"]) for s, per in results.items() for m, rs in per.items()
            if rs and "passes" in rs[0]]
    if bars:
        parts = [k for k in PASSES if any(k in b for _, b in bars)]
        svgplot.stacked_bars(OUT / "passes.svg", f"passes of one frame ({SIZE})", "ms", bars, parts)
        md += ["![passes](passes.svg)", ""]
    md += ["| scene | method | " + " | ".join(PASSES) + " | frame ms | session memory |",
           "|---|---|" + "---|" * (len(PASSES) + 2)]
    for s, per in results.items():
        for m, rs in per.items():
            p = rs[0].get("passes") or {}
            cells = [f"{p[k]:.1f}" if k in p else "—" for k in PASSES]
            md.append(f"| {s} | {m} | " + " | ".join(cells) + f" | {rs[0]['ms']:.1f} | {fmt_bytes(rs[0]['session_bytes'])} |")
    md.append("")
    if stab:
        (OUT / "stability.json").write_text(json.dumps(stab, indent=1) + "\n")
        ser = stab["series"]
        n = stab["frames"]
        svgplot.chart(OUT / "flicker.svg", "frame-to-frame change, still camera (cornell-box)", "frame", "change (MAPE between frames)",
                      [(m, list(enumerate(v["flicker"], 1)), "line") for m, v in ser.items()], xlog=False, ylog=False)
        svgplot.chart(OUT / "teleport.svg", f"MAPE per frame; camera teleported at frame {n // 2}", "frame", "MAPE",
                      [(m, list(enumerate(v["teleport"])), "line") for m, v in ser.items()], xlog=False, ylog=True)
        svgplot.chart(OUT / "sweep.svg", f"MAPE per frame; camera sliding sideways over frames {n // 2}–"
                      f"{n // 2 + stab['sweep_frames'] - 1}", "frame", "MAPE",
                      [(m, list(enumerate(v["sweep"])), "line") for m, v in ser.items()], xlog=False, ylog=True)
        svgplot.chart(OUT / "light.svg", f"MAPE per frame; light off at {n // 2 - 4}, on at {n // 2}", "frame", "MAPE",
                      [(m, [(i, e) for i, e in enumerate(v["light"]) if e is not None], "points") for m, v in ser.items()],
                      xlog=False, ylog=True)
        svgplot.chart(OUT / "glass_lamp.svg", "a light behind glass (NEE always blocked): MAPE per frame", "frame", "MAPE",
                      [(m, list(enumerate(v["glass_lamp"])), "line") for m, v in ser.items()], xlog=False, ylog=True)
        md += ["## Stability over frames", "",
               f"cornell-box at {stab['side']}×{stab['side']} through the daemon, {n} frames per run "
               "(`tests/test_stability.py` asserts the same properties at 32×32).", "",
               "![flicker](flicker.svg)", "", "![teleport](teleport.svg)", "",
               f"Fast camera motion: the camera slides sideways by {100 * stab['sweep_fraction'] / stab['sweep_frames']:g} % "
               f"of its viewing distance per frame for {stab['sweep_frames']} frames, each frame against a reference from its own camera; "
               "parallax uncovers surfaces behind the boxes every frame.", "", "![fast camera motion](sweep.svg)", "",
               "![light](light.svg)", "",
               "![glass lamp](glass_lamp.svg)", "",
               "| method | mean flicker | MAPE of the mean of 8 consecutive ÷ 8 independent frames | largest pixel while the light is off |",
               "|---|---|---|---|"]
        for m, v in ser.items():
            md.append(f"| {m} | {statistics.mean(v['flicker']):.3f} | {stab['correlation'][m]:.2f} | {v['light_off_max']:g} |")
        md += ["", "Non-finite pixels over 100 frames (16×16, the CLI's sum over frames): " +
               ", ".join(f"{k}: {v}" for k, v in stab["nonfinite"].items()) + ".", ""]
    if fail:
        (OUT / "failure_cases.json").write_text(json.dumps(fail, indent=1) + "\n")
        md += ["## The papers' failure cases", "",
               "`tests/test_failure_cases.py` checks the same cases at 32×32 (the regime is there; the method stays "
               "unbiased in it); restir_pt with its light behind glass is in the stability section above.", "",
               "### Light tracing wasted on a light the camera cannot see ([ReSTIR BDPT Fig. 10])", "",
               f"`bdpt`, 4 frames at {SIZE}, the last frame's statistics: door-ajar's only light is outside the room, "
               "so its light subpaths almost never reach a point the camera sees, while the light pass still traces "
               "all of them.", "",
               "| scene | light subpaths | light-traced samples | per subpath | light pass ms | camera pass ms |",
               "|---|---|---|---|---|---|"]
        for scene, v in fail["light_tracing"].items():
            md.append(f"| {scene} | {v['light_subpaths']} | {v['light_traced']} | "
                      f"{v['light_traced'] / v['light_subpaths']:.3f} | {v['light_ms']:.1f} | {v['camera_ms']:.1f} |")
        svgplot.stacked_bars(OUT / "light_tracing.svg", "bdpt: light-traced samples per light subpath", "samples",
                             [(sc, {"per subpath": v["light_traced"] / v["light_subpaths"]})
                              for sc, v in fail["light_tracing"].items()], ["per subpath"])
        md += ["", "![light-traced samples per light subpath](light_tracing.svg)"]
        sss = fail["sss"]
        ser = sss["series"]
        svgplot.chart(OUT / "sss_boundary.svg", f"translucent: RMSE per frame on the shadow-boundary band "
                      f"({sss['pixels']['band']} pixels)", "frame", "RMSE",
                      [(name, list(enumerate(v["band"], 1)), "line") for name, v in ser.items()], xlog=False, ylog=True)
        half = sss["frames"] // 2
        md += ["", "### Shadow boundaries for the hybrid shift of ReSTIR SSS ([ReSTIR SSS Fig. 5])", "",
               f"scenes/translucent at {sss['side']}×{sss['side']}, {sss['frames']} frames per session through the "
               "daemon, medians over seeds. Regions of the wax sphere from two variants of the scene (the sphere "
               "emissive: which pixels it covers; the sphere white diffuse, direct light only: which the lamp lights): "
               f"the band along the occluder's shadow ({sss['pixels']['band']} pixels), the lit part "
               f"({sss['pixels']['lit']}) and the shadowed part ({sss['pixels']['shadowed']}) away from it.", "",
               "![shadow-boundary band](sss_boundary.svg)", "",
               f"| setting | RMSE band | RMSE lit | RMSE shadowed | (means over frames {half + 1}–{sss['frames']}) |",
               "|---|---|---|---|---|"]
        for name, v in ser.items():
            cells = [f"{statistics.mean(v[k][half:]):.4f}" for k in ("band", "lit", "shadowed")]
            md.append(f"| {name} | " + " | ".join(cells) + " | |")
        pr = fail["prior"]
        md += ["", "### The sample-space prior misses a light ([SMS-SSP Fig. 10])", "",
               f"scenes/refractive-slab (two lights) at {pr['side']}×{pr['side']}, medians over seeds, RMSE against the "
               f"uncapped `sms` reference: `sms` and `sms_ssp` at {pr['spp']} spp, `restir_sms` its last frame of "
               f"{pr['frames']} (time per frame). With 2 prior walks per 16×16 block (the default is 128) most blocks "
               "find no solution for one or both of the two (light, caster) pairs; a pair without one falls back to "
               "partitioning without a prior there, and `prior: false` is that fallback everywhere. The estimates stay unbiased (`tests/test_restir_sms.py`, `tests/test_sms.py`); "
               "what the missed light costs is solutions and error.", "",
               "| setting | ms | RMSE | manifold walks that found a solution | prior solutions |", "|---|---|---|---|---|"]
        for name, v in pr["rows"].items():
            md.append(f"| {name} | {v['ms']:.1f} | {v['rmse']:.4f} | {100 * v['success']:.1f} % | "
                      f"{v['prior_solutions']:g} |")
        svgplot.stacked_bars(OUT / "prior.svg", "refractive-slab: RMSE with the prior, a sparse prior and none", "RMSE",
                             [(PRIOR_TAGS[name], {"RMSE": v["rmse"]}) for name, v in pr["rows"].items()], ["RMSE"])
        md += ["", "![RMSE by prior](prior.svg)", "",
               "Bars: ssp = `sms_ssp`, rsms = `restir_sms`; ·2 = a prior of 2 walks per block, ·0 = no prior.", ""]
    if peer:
        c = peer["converged"]
        md += ["## The peer: Blender Cycles", "",
               "Cycles (Debian's blender, CPU, `bench/crosscheck_cycles.py`: no clamping, no denoising, box filter, "
               "64 bounces) on cornell-box; its curves are in the cornell-box charts above, against the same reference. "
               "Its time is Cycles' own render call (scene sync, BVH and sampling), not Blender's start-up. With light "
               "sampling on, Cycles' mesh-light sampling loses about 1.3 % of the direct light on this scene "
               "([docs/crosscheck.md](../crosscheck.md)); off, it finds the light by BSDF sampling only.", "",
               "| Cycles | spp | ms | MAPE | RMSE |", "|---|---|---|---|---|"]
        for r in peer["rows"]:
            md.append(f"| {r['method']} | {r['setting']} | {r['ms']:.1f} | {r['mape']:.4f} | {r['rmse']:.5f} |")
        md += ["", f"Converged images ({c['spp']} spp each; Cycles with light sampling off): Cycles ÷ restird image "
               f"mean per channel {', '.join(f'{x:.4f}' for x in c['ratio'])}; MAPE of Cycles against our reference "
               f"{c['mape']:.4f} (both images carry their own noise).", ""]
    (OUT / "README.md").write_text("\n".join(md) + "\n")
    log(f"wrote {OUT / 'README.md'}")


def main():
    if not Path(BIN).exists():
        raise SystemExit("report: build/restir is missing (run make first)")
    WORK.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    started = time.strftime("%Y-%m-%d %H:%M", time.gmtime())
    results = {}
    d = test_daemon.Daemon(Path(tempfile.mkdtemp(dir=WORK)) / "data", "--threads", THREADS, "--frames-kept", "2")
    try:
        for scene, methods in SCENES.items():
            path = ROOT / "scenes" / scene / "scene.json"
            ref = reference(path, spp=REF_BY[scene][1], method=REF_BY[scene][0]) if scene in REF_BY else reference(path)
            results[scene] = {m: measure(scene, m, ref, d) for m in methods}
    finally:
        d.stop()
    peer = cycles(reference(CORNELL), results.get("cornell-box", {})) if "cornell-box" in SCENES else None
    stab = stability()
    fail = failure_cases()
    write(results, stab, peer, fail, started, time.monotonic() - t0)


if __name__ == "__main__":
    main()
