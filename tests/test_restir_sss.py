"""restir_sss is unbiased for each shift it offers (statistical, tests/README.md): K independent
sessions (fresh seeds) of temporal and spatial reuse on the library scene `translucent`, the
camera narrowed onto the wax sphere's upper half (32 x 32, most pixels on the sphere, its lit top, the
occluder's shadow edge and the glow below it), compared per pixel with `pt` over the same
cameras, camera still and sliding. Each session contributes the mean of its last frames, each
after at least 8 frames of reuse. Šidák-corrected per-pixel z-test at 0.01, >= 99.75 % of pixels
passing, global mean within 3 sigma (tests/stats.py); each comparison also rejects the same
renders scaled by 1.03, so the test can see a bias of that size. The sequential shift is tested
in its exact mode (its index shortcut is labelled slightly biased and not z-tested). The
per_channel target (three reservoirs per pixel, each reused on its own) is tested with the shifts
whose passes differ most: hybrid under camera motion and sequential's two spatial passes. The
sessions run under the real-time profile (the defaults, temporal reuse); the default shift also
under the converge profile (no temporal reuse, the confidence cap its default: there is no history
for it to cap), averaging the same frames as the real-time sessions. Each profile's default rest
(restir_pt's reservoirs in real time, one pt path a pixel converging) is tested, and the other rest
under each profile once. The reservoirs hold direct light and, within max_depth >= 2, the light
arriving at the entry points after a bounce; max_depth 1 tests the direct part alone, and a
variant of the scene whose sphere the lamp cannot see tests the indirect samples alone."""
import json

import numpy as np
import pytest

from conftest import render, run_cli, seed_offset, sky_all_round
from stats import assert_agree, ztest_runs

FPS = 30.0
SIZE = "32x32"
K = 64
K_REF = 16
FRAMES, AVERAGED = 12, 6
REF_SPP = 384
CAMERA = {"position": [2.0, 1.0, 3.0], "look_at": [0.1, 0.62, 0.0], "fov_deg": 8}
MOVE = [0.25, 0.0, -0.1]
# The confidence cap of the history, as a multiple of the current M. The default (20, [ReSTIR SSS]
# §5.1) keeps a sample alive for dozens of frames on a still camera, and the reconnection shift
# then spreads one rare bright entry point over many pixels: a session's frames are so strongly
# correlated that a per-pixel test at this K sees heavy tails, not bias (reconnection at cap 20
# fails 0.6 % of pixels with every one of them too dark and the global mean within 1.8 sigma;
# at cap 4 it passes). Unbiasedness does not depend on the cap, so the test uses 4.
TEMPORAL_CAP = 4


def _animation(tmp_path, name, frames, keys):
    path = tmp_path / name
    path.write_text(json.dumps({"animation": {"fps": FPS, "frames": frames, "interpolation": "linear",
                                              "camera_keys": keys}}))
    return path


def _animations(tmp_path, moving, frames=FRAMES):
    """The sessions' animation over `frames` frames, and the reference's over the last AVERAGED."""
    move = MOVE if moving else [0.0, 0.0, 0.0]

    def at(frac):
        return {"position": [a + frac * b for a, b in zip(CAMERA["position"], move)],
                "look_at": [a + frac * b for a, b in zip(CAMERA["look_at"], move)], "fov_deg": CAMERA["fov_deg"]}

    first = frames - AVERAGED
    sessions = _animation(tmp_path, "sessions.json", frames, [{"t": 0, **at(0.0)}, {"t": (frames - 1) / FPS, **at(1.0)}])
    reference = _animation(tmp_path, "reference.json", AVERAGED,
                           [{"t": 0, **at(first / (frames - 1))}, {"t": (AVERAGED - 1) / FPS, **at(1.0)}])
    return sessions, reference


_REF_CACHE = {}


def _reference(sc, tmp_path, moving, depth=()):
    key = (moving, *depth, seed_offset())
    if key in _REF_CACHE:
        return _REF_CACHE[key]
    _, anim = _animations(tmp_path, moving)
    extra = ["--frames", str(AVERAGED), "--average-last", str(AVERAGED), "--animation", str(anim), *depth]
    ref = np.stack([render(sc, tmp_path / f"ref{s}.exr", spp=REF_SPP // AVERAGED, size=SIZE, seed=100000 + s,
                           extra=extra)[0]
                    for s in range(K_REF)])
    _REF_CACHE[key] = ref
    return ref


@pytest.mark.statistical
@pytest.mark.parametrize("shift,motion,max_depth,target,profile,rest",
                         [(shift, motion, None, "luminance", "real-time", "by_scene")
                          for shift in ("reconnection", "delayed", "hybrid", "sequential")
                          for motion in ("static", "moving camera")] +
                         # The direct-lighting case of [ReSTIR SSS §3] (camera, entry, exit, light), which
                         # its evaluation and bench/restir_sss.py's BENCH_SSS_MAX_DEPTH=1 use: pt then
                         # stops after next-event estimation at the exit points and restir_sss
                         # traces no rest on the object; both must still estimate the same paths.
                         [("hybrid", "static", 1, "luminance", "real-time", "by_scene"),
                          # One bounce after the entry points (NEE at x3, emission found from it):
                          # the indirect samples' paths count their depth as pt's do.
                          ("hybrid", "static", 2, "luminance", "real-time", "by_scene"),
                          ("hybrid", "moving camera", None, "per_channel", "real-time", "by_scene"),
                          ("sequential", "static", None, "per_channel", "real-time", "by_scene")] +
                         [("hybrid", motion, None, "luminance", "converge", "by_scene")
                          for motion in ("static", "moving camera")] +
                         # The rest asked for against the profile's default (restir_pt's reservoirs in
                         # real time, one pt path a pixel when converging).
                         [("hybrid", "moving camera", None, "luminance", "real-time", "pt"),
                          ("hybrid", "static", None, "luminance", "converge", "restir_pt")])
def test_restir_sss_unbiased(tmp_path, scenes, shift, motion, max_depth, target, profile, rest):
    sc = scenes / "translucent" / "scene.json"
    moving = motion != "static"
    converge = profile == "converge"
    # A converge session has no history to warm up: with the camera still it renders only the
    # frames it averages; with the camera moving, the real-time sessions' frames, so that the
    # reference over the averaged frames' cameras serves both.
    frames = AVERAGED if converge and not moving else FRAMES
    depth = ("--max-depth", str(max_depth)) if max_depth is not None else ()
    ref = _reference(sc, tmp_path, moving, depth)
    anim, _ = _animations(tmp_path, moving, frames)   # after the reference's, which writes its own
    params = {"shift": shift, "target": target, "rest": rest,
              **({} if converge else {"temporal_cap": TEMPORAL_CAP}), **({"max_depth": max_depth} if max_depth else {})}
    extra = ["--method", "restir_sss", "--frames", str(frames), "--average-last", str(AVERAGED),
             "--animation", str(anim), "--profile", profile, "--params", json.dumps(params)]
    runs, stats = [], None
    for s in range(K):
        img, stats = render(sc, tmp_path / f"s{s}.exr", spp=1, size=SIZE, seed=s, extra=extra)
        runs.append(img)
    runs = np.stack(runs)
    layers = 3 if target == "per_channel" else 1
    assert stats["last_frame"]["shifts"] > 0 and stats["reservoir_bytes_per_pixel"] == 72 * layers
    by_restir_pt = rest == "restir_pt" or (rest == "by_scene" and not converge)
    assert (stats["rest_ms"] > 0) == by_restir_pt, stats
    assert np.isfinite(runs).all() and stats["nonfinite"] == 0
    res = ztest_runs(runs, ref)
    bad = ztest_runs(runs * 1.03, ref)
    what = f"{shift}, {motion}, {target}, {profile}, rest {rest}"
    print(f"{what}: {res}; x1.03: {bad}")
    assert_agree(res, what)
    assert not bad.passed, f"{what}: a bias of x1.03 went unseen: {bad}"


def test_restir_sss_bad_params(tmp_path, scenes):
    sc = scenes / "translucent" / "scene.json"
    for params, field, text in [({"shift": "teleport"}, "/params/shift", "unknown shift"),
                                ({"shift": "sequential", "spatial_neighbors": 3}, "/params/spatial_neighbors", "even"),
                                ({"index_shortcut": True}, "/params/index_shortcut", "only the sequential"),
                                ({"target": "rgb"}, "/params/target", "unknown target \"rgb\" (luminance or per_channel)"),
                                ({"target": 3}, "/params/target", "string"),
                                ({"rest_samples": 0}, "/params/rest_samples", "must be >= 1, got 0"),
                                ({"rest_samples": 65}, "/params/rest_samples", "must be <= 64, got 65")]:
        res = run_cli("render", sc, "--method", "restir_sss", "--size", "8x8", "--params", json.dumps(params),
                      "-o", tmp_path / "x.exr")
        assert res.returncode == 2 and field in res.stderr and text in res.stderr, res.stderr


def test_restir_sss_renders_and_reuses(tmp_path, scenes):
    """Short sessions on the full view (the default hybrid shift, and the sequential shift with its
    index shortcut): finite and reusing."""
    sc = scenes / "translucent" / "scene.json"
    for params in [{}, {"shift": "sequential", "index_shortcut": True}]:
        img, st = render(sc, tmp_path / "a.exr", spp=1, size="32x32", seed=3,
                         extra=["--method", "restir_sss", "--frames", "4", "--params", json.dumps(params)])
        assert np.isfinite(img).all() and st["nonfinite"] == 0 and st["last_frame"]["shifts"] > 0


def test_restir_sss_per_channel_targets_one_channel(tmp_path, scenes):
    """With a channel as a reservoir's target, the sample's value in its channel is its target, so
    the spatial pass's expected contribution sum_i m_i W_i F_c(Y_i) is the selected sample's
    F_c(Y) W (both sum the resampling weights): per_channel renders the same image with and
    without expected shading, to float rounding. With the luminance target the two differ (the
    selected sample's colour is not the expectation's). A layer whose target were not its own
    channel would break the equality; a layer adding the other channels would also triple the
    image against luminance's."""
    sc = scenes / "translucent" / "scene.json"

    def img(params):
        out, st = render(sc, tmp_path / f"{len(list(tmp_path.iterdir()))}.exr", spp=1, size="32x32", seed=7,
                         extra=["--method", "restir_sss", "--frames", "4", "--params",
                                json.dumps({"shift": "delayed", **params})])
        assert np.isfinite(out).all() and st["nonfinite"] == 0
        return out

    pc_on, pc_off = img({"target": "per_channel"}), img({"target": "per_channel", "expected_shading": False})
    lum_on, lum_off = img({}), img({"expected_shading": False})
    assert np.allclose(pc_on, pc_off, rtol=1e-4, atol=1e-7), float(np.abs(pc_on - pc_off).max())
    assert (np.abs(lum_on - lum_off) > 1e-4 * (np.abs(lum_off) + 1e-3)).any(axis=-1).sum() >= 10
    assert 0.8 < pc_on.mean() / lum_on.mean() < 1.25


@pytest.mark.statistical
def test_restir_sss_environment_unbiased(tmp_path, scenes):
    """The same z-test with an environment light and a view whose upper rows see the sky: x3 can
    then be a direction (the environment's sample), and the path-traced rest starts from a
    G-buffer entry whose ray escaped. Still camera, the default hybrid shift."""
    doc = json.loads((scenes / "translucent" / "scene.json").read_text())
    env = [0.5, 0.55, 0.6]
    doc["environment"] = {"radiance": env}
    sc = tmp_path / "scene.json"
    sc.write_text(json.dumps(doc))
    camera = {"position": [2.0, 0.8, 3.0], "look_at": [0.0, 0.85, 0.0], "fov_deg": 14}
    anim = _animation(tmp_path, "still.json", FRAMES, [{"t": 0, **camera}])
    ref_anim = _animation(tmp_path, "still_ref.json", AVERAGED, [{"t": 0, **camera}])
    ref = np.stack([render(sc, tmp_path / f"ref{s}.exr", spp=REF_SPP // AVERAGED, size=SIZE, seed=100000 + s,
                           extra=["--frames", str(AVERAGED), "--average-last", str(AVERAGED), "--animation",
                                  str(ref_anim)])[0]
                    for s in range(K_REF)])
    sky = np.all(np.abs(ref - np.array(env)) < 1e-6, axis=(0, 3))
    assert 0.1 < sky.mean() < 0.6, f"the view should hold sky and object: {sky.mean():.2f} of the pixels are sky"
    clear = sky_all_round(sky)
    extra = ["--method", "restir_sss", "--frames", str(FRAMES), "--average-last", str(AVERAGED),
             "--animation", str(anim), "--profile", "real-time", "--params", json.dumps({"temporal_cap": TEMPORAL_CAP})]
    runs = np.stack([render(sc, tmp_path / f"s{s}.exr", spp=1, size=SIZE, seed=s, extra=extra)[0] for s in range(K)])
    assert np.isfinite(runs).all()
    assert clear.sum() > 20 and np.all(np.abs(runs[:, clear] - np.array(env)) < 1e-6), \
        "an escaped camera ray must show the environment"
    res = ztest_runs(runs, ref)
    assert_agree(res, "environment")
    bad = ztest_runs(runs * 1.03, ref)
    assert not bad.passed, f"environment: a bias of x1.03 went unseen: {bad}"


@pytest.mark.statistical
@pytest.mark.parametrize("shift,max_depth", [("hybrid", 2), ("hybrid", None), ("delayed", None)])
def test_restir_sss_indirect_only_unbiased(tmp_path, scenes, shift, max_depth):
    """The same z-test on the wax sphere lit only after a bounce: the occluder raised to 1.2 hides
    the sphere from the lamp, whose light reaches it from the floor beside the occluder. Every
    reservoir sample that carries light is then an indirect one (x3 the surface after the entry
    point, with its incoming radiance), so the shifts, Jacobians and depths of those samples decide
    the image alone: at max_depth 2 pt counts one bounce after the entry points (next-event
    estimation at x3, emission found from it), and so must they."""
    doc = json.loads((scenes / "translucent" / "scene.json").read_text())
    for shape in doc["shapes"]:
        if shape.get("name") == "occluder":
            shape["vertices"] = [[0.9, 0, -0.7], [0.9, 1.2, -0.7], [0.9, 1.2, 0.7], [0.9, 0, 0.7]]
    sc = tmp_path / "scene.json"
    sc.write_text(json.dumps(doc))
    camera = {"position": [2.0, 1.0, 3.0], "look_at": [0.0, 0.5, 0.0], "fov_deg": 12}
    depth = ["--max-depth", str(max_depth)] if max_depth else []
    anim = _animation(tmp_path, "still.json", FRAMES, [{"t": 0, **camera}])
    ref_anim = _animation(tmp_path, "still_ref.json", AVERAGED, [{"t": 0, **camera}])
    ref = np.stack([render(sc, tmp_path / f"ref{s}.exr", spp=REF_SPP // AVERAGED, size=SIZE, seed=100000 + s,
                           extra=["--frames", str(AVERAGED), "--average-last", str(AVERAGED), "--animation",
                                  str(ref_anim), *depth])[0]
                    for s in range(K_REF)])
    assert ref.mean() > 1e-3, "the sphere must receive light after a bounce"
    params = {"shift": shift, "temporal_cap": TEMPORAL_CAP, **({"max_depth": max_depth} if max_depth else {})}
    extra = ["--method", "restir_sss", "--frames", str(FRAMES), "--average-last", str(AVERAGED),
             "--animation", str(anim), "--profile", "real-time", "--params", json.dumps(params)]
    runs = np.stack([render(sc, tmp_path / f"s{s}.exr", spp=1, size=SIZE, seed=s, extra=extra)[0] for s in range(K)])
    assert np.isfinite(runs).all()
    what = f"indirect only, {shift}, max_depth {max_depth}"
    res = ztest_runs(runs, ref)
    bad = ztest_runs(runs * 1.03, ref)
    print(f"{what}: {res}; x1.03: {bad}")
    assert_agree(res, what)
    assert not bad.passed, f"{what}: a bias of x1.03 went unseen: {bad}"


@pytest.mark.statistical
def test_restir_sss_converge_rest_unbiased(tmp_path, scenes):
    """The converge profile's rest on a wider view, where most pixels are not on the wax (the
    narrowed view above holds few of them): there the profile traces rest_samples pt paths a
    pixel and frame from the primary hit and averages them. Still camera, the mean of AVERAGED
    frames of independent sessions against pt. (The library view's far corners hold pixels that
    pt lights in a few of 384 samples: a per-pixel test there sees the tail, not a bias.)"""
    sc = scenes / "translucent" / "scene.json"
    camera = {"position": [2.0, 1.0, 3.0], "look_at": [0.1, 0.5, 0.0], "fov_deg": 24}
    anim = _animation(tmp_path, "still.json", AVERAGED, [{"t": 0, **camera}])
    ref = np.stack([render(sc, tmp_path / f"ref{s}.exr", spp=REF_SPP // AVERAGED, size=SIZE, seed=100000 + s,
                           extra=["--frames", str(AVERAGED), "--average-last", str(AVERAGED), "--animation",
                                  str(anim)])[0]
                    for s in range(K_REF)])
    extra = ["--method", "restir_sss", "--frames", str(AVERAGED), "--average-last", str(AVERAGED),
             "--animation", str(anim), "--profile", "converge"]
    runs, stats = [], None
    for s in range(K):
        img, stats = render(sc, tmp_path / f"s{s}.exr", spp=1, size=SIZE, seed=s, extra=extra)
        runs.append(img)
    runs = np.stack(runs)
    assert stats["rest_ms"] == 0, stats   # the pt rest
    assert np.isfinite(runs).all() and stats["nonfinite"] == 0
    res = ztest_runs(runs, ref)
    bad = ztest_runs(runs * 1.03, ref)
    print(f"converge rest: {res}; x1.03: {bad}")
    assert_agree(res, "converge rest")
    assert not bad.passed, f"converge rest: a bias of x1.03 went unseen: {bad}"
