"""bench/regimes.py — the two regimes the report measures each method in (docs/benchmarks.md,
"Two regimes"), through one daemon.

Real time: a session renders frames continuously and the user sees each one. The figure is the
error of single frames after WARMUP warm-up frames (frames WARMUP + o for o in MEASURED), against
the frame's render time. A method buys a longer frame with more samples of its own kind
(LADDER: spp for pt and sms; light subpaths for bdpt and restir_bdpt; spatial neighbours for
restir_pt and restir_sms; BSSRDF candidates for restir_sss), so at any frame time each method is
read off its own curve and none leaves time unspent. Shown for a still view, and (for the methods
that keep state across frames; the others' frames are the same either way) for a camera sliding
and a light moving to and fro: each moves as sin(2 pi i / PERIOD) and is back at rest in every
frame a multiple of PERIOD / 2, where the measured frames are, so the still reference judges
them while the history behind them moved.

Converge: the user wants one still image as fast as possible. The figure is the error of the
image the user would keep against the total time spent since the session began: pt, sms and
sms_ssp the first frame of a session at a higher spp (its time includes the session's first-frame
set-up, as every converge time does; real-time frames of these come after sms_ssp's prior has
gathered its prior_frames); bdpt the mean of its
first k frames (independent); a method with temporal reuse either in its converge profile (the
session's "profile": temporal reuse off, more spatial reuse), the mean of its first k frames
(independent draws), or in the real-time defaults, its k-th frame alone (its history is its
accumulation; averaging its correlated frames would be neither regime).

Every session's frames depend only on its seed and frame numbers; medians are over seeds (and
the measured frames of each).

A frame's time is its CPU time over its threads (frame_ms: the daemon's render_cpu_ms divided by
the frame's threads), the wall-clock time the frame would take with every thread busy on a machine
with nothing else to do: on a shared machine the wall clock of a frame stretches whenever another
process takes a turn on a core, and by different amounts for rows measured minutes apart, which
moves a ratio between two methods by more than the methods differ; the CPU time does not stretch
so. What it leaves out is a thread's wait at a pass's join, which a multi-pass frame pays and a
one-pass frame barely does (about 5 % of a restir_pt frame on two threads: docs/benchmarks.md,
"Is the frame cost the worker pool's?")."""
import json
import math
import os
import statistics
from pathlib import Path

import numpy as np

from cputime import frame_time_ms, progress as log
from exrimage import read_rgb, write_rgb

QUICK = os.environ.get("QUICK") == "1"
WARMUP = 8 if QUICK else 32
MEASURED = [0, 8] if QUICK else [0, 8, 16]
PERIOD = 16
# The measured frames are at rest (moving_bodies): every offset a multiple of half the period.
assert WARMUP % (PERIOD // 2) == 0 and all(o % (PERIOD // 2) == 0 for o in MEASURED)
CAMERA_SLIDE = 0.05  # of the camera's distance to its look-at point, at the crest
LIGHT_SLIDE = 0.02   # of the same distance; lamp-in-glass's filament has 3.5 cm of room in its bulb
LIGHT_SLIDE_ABS = {"lamp-in-glass": 0.02}
MOVING_LIGHT = {"cornell-box": "ceiling_light", "cornell-glossy": "ceiling_light", "door-ajar": "lamp",
                "lamp-in-glass": "filament", "caustic-sphere": "light", "refractive-slab": "warm_light",
                "reflective-plane": "lamp", "translucent": "lamp"}

SPP_LADDER = [1, 4, 16] if QUICK else [1, 2, 4, 8, 16, 32, 64]
SMS_LADDER = [1, 4] if QUICK else [1, 2, 4, 8, 16]
FRAMES_LADDER = [1, 4, 8] if QUICK else [1, 2, 4, 8, 16, 32]
# The real-time ladder: (parameter, values), the first value the method's default; "x" values
# multiply the pixel count, "auto" is the parameter's 0 (restir_bdpt: the pixel count, or no light
# subpaths in a scene without a caustic caster).
LADDER = {"pt": ("spp", SPP_LADDER), "sms": ("spp", SMS_LADDER), "sms_ssp": ("spp", SMS_LADDER),
          "bdpt": ("light_paths", ["1x", "2x", "4x", "8x"]), "restir_bdpt": ("light_paths", ["auto", "2x", "4x", "8x"]),
          "restir_pt": ("spatial_neighbors", [3, 6, 12, 24, 48]), "restir_sss": ("candidates", [1, 2, 4, 8]),
          "restir_sms": ("spatial_neighbors", [1, 2, 4, 8])}
def extra_params(text):
    """REPORT_PARAMS: {method: {param: value}} given to every session of that method, so that a
    configuration other than the defaults is measured in both regimes. The ladder's parameter is
    given over them (it is what a row measures); the converge rows' sessions are in the converge
    profile, whose values these override too."""
    try:
        value = json.loads(text)
    except ValueError as e:
        raise SystemExit(f"report: REPORT_PARAMS is not JSON: {e}")
    if not isinstance(value, dict) or not all(isinstance(v, dict) for v in value.values()):
        raise SystemExit("report: REPORT_PARAMS must be an object of method name to an object of parameters")
    unknown = sorted(set(value) - set(LADDER))
    if unknown:
        raise SystemExit(f"report: REPORT_PARAMS/{unknown[0]}: not a method the report measures "
                         f"({', '.join(sorted(LADDER))})")
    return value


EXTRA_PARAMS = extra_params(os.environ.get("REPORT_PARAMS", "{}"))


class Session:
    """One daemon session; frames come back with their statistics, images on request."""

    def __init__(self, d, scene, method, params, seed, side, work, profile=None):
        params = {**EXTRA_PARAMS.get(method, {}), **params}
        body = {"method": method, "width": side, "height": side, "seed": seed, "params": params}
        if profile:
            body["profile"] = profile
        r = d.req("POST", f"/v1/scenes/{scene}/sessions", json_body=body)
        if r.status != 201:
            raise SystemExit(f"report: {scene} {method} {params} session: {r!r}")
        s = r.json()
        self.d, self.href, self.memory, self.work = d, s["href"], s["memory_bytes"], Path(work)

    def frame(self, body=None):
        r = self.d.req("POST", self.href + "/frames", headers={"Accept": "application/json"}, json_body=body)
        if r.status != 200:
            raise SystemExit(f"report: frame: {r!r}")
        return r.json()

    def image(self, st, path):
        r = self.d.req("GET", st["href"], headers={"Accept": "image/x-exr"})
        if r.status != 200:
            raise SystemExit(f"report: frame image: {r!r}")
        Path(path).write_bytes(r.body)
        return path

    def next(self, body=None):
        """The next frame as an array (H x W x 3)."""
        r = self.d.req("POST", self.href + "/frames", headers={"Accept": "image/x-exr"}, json_body=body)
        if r.status != 200:
            raise SystemExit(f"report: frame: {r!r}")
        path = self.work / "frame.exr"
        path.write_bytes(r.body)
        return read_rgb(path)

    def close(self):
        self.d.req("DELETE", self.href)


def frame_passes(st):
    """A daemon frame's per-pass times: every `*_ms` member of its method's statistics object."""
    return {k: v for obj in st.values() if isinstance(obj, dict) for k, v in obj.items() if k.endswith("_ms")}


def moving_bodies(scene, scene_path):
    """Frame bodies of the moving camera and the moving light: body(i) for frame i."""
    sj = json.loads(Path(scene_path).read_text())
    cam = sj["camera"]
    pos, at = np.array(cam["position"], float), np.array(cam["look_at"], float)
    fwd = at - pos
    dist = float(np.linalg.norm(fwd))
    side = np.cross(fwd, np.array(cam.get("up", [0, 1, 0]), float))
    side /= np.linalg.norm(side)

    def wave(i):
        # Exactly at rest in every measured frame (i a multiple of PERIOD / 2).
        return 0.0 if i % (PERIOD // 2) == 0 else math.sin(2 * math.pi * i / PERIOD)

    def camera(i):
        off = side * CAMERA_SLIDE * dist * wave(i)
        return {"camera": {"position": (pos + off).tolist(), "look_at": (at + off).tolist()}}

    name = MOVING_LIGHT[scene]
    shape = next(s for s in sj["shapes"] if s.get("name") == name)
    base = np.array(shape.get("transform", {}).get("translate", [0, 0, 0]), float)
    amp = LIGHT_SLIDE_ABS.get(scene, LIGHT_SLIDE * dist)

    def light(i):
        return {"lights": {name: {"position": (base + np.array([amp * wave(i), 0, 0])).tolist()}}}

    return {"moving camera": camera, "moving light": light}


# A frame's time for the report: its CPU time over its threads (module text), or its wall time
# from a daemon that does not report CPU time.
frame_ms = frame_time_ms


def ladder_params(method, value, side):
    key, _ = LADDER[method]
    if value == "auto":
        return {key: 0}
    if isinstance(value, str) and value.endswith("x"):
        return {key: int(value[:-1]) * side * side}
    return {key: value}


def row(scene, method, regime, variant, setting, unit, ms, images, memory=None, passes=None):
    return {"scene": scene, "method": method, "regime": regime, "variant": variant, "setting": setting,
            "unit": unit, "ms": ms, "images": images, "session_bytes": memory, "passes": passes}


def median_passes(ps):
    ps = [p for p in ps if p]
    return {k: statistics.median(p[k] for p in ps) for k in ps[0]} if ps else None


def param_default(desc, name, fallback):
    """A parameter's default from the method's registry entry (GET /v1/methods)."""
    return next((p.get("default") for p in desc["params"] if p["name"] == name), fallback)


def past(reach, regime, ms):
    """Whether a rung measured at ms lies beyond the time `reach` says the tables read the ladder
    at in that regime (no reach: never)."""
    return reach is not None and ms > reach[regime]


def measure_method(d, scene, scene_path, desc, seeds, side, work, reach=None):
    """Every row of one method on one scene, both regimes (images on disk, metrics later).
    desc: the method's entry of GET /v1/methods. reach: None, or the longest times the report's
    tables read this method's curves at ({"real-time": ms, "converge": ms}, report.ladder_reach):
    a ladder then stops after its first rung past them, in both regimes for a ladder of spp, so
    every curve still brackets every time it is read at and no rung is rendered only for a chart."""
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    method, caps = desc["name"], desc["capabilities"]
    tag = f"{scene}-{method}"
    key, values = LADDER[method]
    rows = []
    stateful = caps.get("reuses_frames", False)
    if caps.get("takes_spp"):
        # Per spp value: a fresh session's first frame is the converged image of a user who
        # asked for one still image at that spp (its time includes the first frame's set-up,
        # as every other method's converge time does); the real-time frames come after the
        # frames a method's per-frame prior unites (sms_ssp's prior_frames; 1 for the others).
        start = max(1, param_default(desc, "prior_frames", 1) or 1)
        for spp in values:
            ms, conv_ms, imgs, conv_imgs, mem = [], [], [], [], None
            for seed in range(seeds):
                s = Session(d, scene, method, {"spp": spp}, seed, side, work)
                mem = s.memory
                st = s.frame()
                conv_ms.append(frame_ms(st))
                conv_imgs.append(s.image(st, work / f"{tag}-{spp}-{seed}-first.exr"))
                per = []
                for i in range(1, start + len(MEASURED)):
                    st = s.frame()
                    if i >= start:
                        per.append(frame_ms(st))
                        imgs.append(s.image(st, work / f"{tag}-{spp}-{seed}-{i}.exr"))
                s.close()
                ms.append(statistics.median(per))
            rows.append(row(scene, method, "real-time", "", spp, "spp", statistics.median(ms), imgs, mem))
            rows.append(row(scene, method, "converge", "", spp, "spp", statistics.median(conv_ms), conv_imgs, mem))
            log(f"{scene} {method} {spp} spp: {statistics.median(ms):.1f} ms a frame, {statistics.median(conv_ms):.1f} ms "
                "the first")
            if past(reach, "real-time", statistics.median(ms)) and past(reach, "converge", statistics.median(conv_ms)):
                log(f"{scene} {method}: the ladder stops at {spp} spp, past the times the tables read it at")
                break
        return rows
    # Real time, still: each ladder value; the default value's sessions also give the converge
    # rows with temporal reuse on (frame k alone, k <= WARMUP).
    last = WARMUP + max(MEASURED)
    # A stateless method (bdpt) needs no warm-up: frame 0 is skipped for first-frame set-up.
    count = last + 1 if stateful else 1 + len(MEASURED)
    conv_on = {k: {"ms": [], "images": []} for k in FRAMES_LADDER} if stateful else {}
    for value in values:
        default = value == values[0]
        ms, imgs, mem, passes = [], [], None, []
        for seed in range(seeds):
            s = Session(d, scene, method, ladder_params(method, value, side), seed, side, work)
            mem = s.memory
            total, per = 0.0, []
            for i in range(count):
                st = s.frame()
                total += frame_ms(st)
                if default and (i + 1) in conv_on:
                    conv_on[i + 1]["ms"].append(total)
                    conv_on[i + 1]["images"].append(s.image(st, work / f"{tag}-on-{i + 1}-{seed}.exr"))
                if (i - WARMUP in MEASURED) if stateful else i >= 1:
                    per.append(frame_ms(st))
                    passes.append(frame_passes(st))
                    imgs.append(s.image(st, work / f"{tag}-rt-{value}-{seed}-{i}.exr"))
            s.close()
            ms.append(statistics.median(per))
        rows.append(row(scene, method, "real-time", "", value, key, statistics.median(ms), imgs, mem,
                        median_passes(passes)))
        log(f"{scene} {method} real-time {key}={value}: {statistics.median(ms):.1f} ms")
        if past(reach, "real-time", statistics.median(ms)):
            log(f"{scene} {method}: the ladder stops at {key}={value}, past the times the tables read it at")
            break
    if stateful:
        for variant, body_of in moving_bodies(scene, scene_path).items():
            ms, imgs = [], []
            for seed in range(seeds):
                # The still rows' seeds: the same random numbers, only the motion differs.
                s = Session(d, scene, method, {}, seed, side, work)
                per = []
                for i in range(last + 1):
                    st = s.frame(body_of(i))
                    if i - WARMUP in MEASURED:
                        per.append(frame_ms(st))
                        imgs.append(s.image(st, work / f"{tag}-{variant.replace(' ', '_')}-{seed}-{i}.exr"))
                s.close()
                ms.append(statistics.median(per))
            rows.append(row(scene, method, variant, "", values[0], key, statistics.median(ms), imgs))
            log(f"{scene} {method} {variant}: {statistics.median(ms):.1f} ms")
        for k, v in conv_on.items():
            rows.append(row(scene, method, "converge", "temporal reuse on", k, "frames", statistics.median(v["ms"]),
                            v["images"]))
    # Converge by the mean of independent frames: bdpt as it is, the others in their converge
    # profile (the session's "profile": what a user asking for a still image gets).
    profile = "converge" if stateful else None
    variant = "converge profile" if stateful else ""
    acc_ms = {k: [] for k in FRAMES_LADDER}
    acc_imgs = {k: [] for k in FRAMES_LADDER}
    for seed in range(seeds):
        s = Session(d, scene, method, {}, 200 + seed, side, work, profile)
        acc, total = None, 0.0
        for i in range(max(FRAMES_LADDER)):
            st = s.frame()
            total += frame_ms(st)
            img = read_rgb(s.image(st, work / "frame.exr"))
            acc = img if acc is None else acc + img
            if i + 1 in acc_ms:
                acc_ms[i + 1].append(total)
                out = work / f"{tag}-off-{i + 1}-{seed}.exr"
                write_rgb(out, acc / (i + 1))
                acc_imgs[i + 1].append(out)
        s.close()
    for k in FRAMES_LADDER:
        rows.append(row(scene, method, "converge", variant, k, "frames", statistics.median(acc_ms[k]), acc_imgs[k]))
    log(f"{scene} {method} converge ({variant or 'independent frames'}): {statistics.median(acc_ms[max(FRAMES_LADDER)]):.0f} ms "
        f"for {max(FRAMES_LADDER)} frames")
    return rows
