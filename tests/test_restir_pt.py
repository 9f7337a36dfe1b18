"""restir_pt is unbiased (statistical, tests/README.md): K independent sessions (fresh seeds) of
temporal and spatial reuse are compared per pixel with the reference path tracer on 32x32
images, with the camera still and moving: all of cornell-glossy, and a crop of door-ajar (the
camera narrowed to 14 degrees on the door opening, where the light from the next room enters).
Each session contributes the mean of its last frames, every one of them after at least 8 frames
of reuse: one frame alone is too heavy-tailed for a per-pixel test at this K (rare bright paths
make the sample variance small and the mean low in the same runs; plain `pt` fails the same way
at equal samples: on the whole door-ajar view, 128 runs of 8 spp pass only 87 % of pixels).
door-ajar's crop takes 256 sessions against 16 x 4096 spp: with 64 sessions against 16 x 1024
spp, a few pixels near the crop's bottom passed or failed with the draw of the reference's rare
paths (5 to 9 values over the threshold, where 7 are allowed), and a 4096-spp reference failed
them; 256 fresh sessions agree with that reference (the means of its first and last 4 rows
within 1.2 %), and pass against it with 99.97 % (still) and 100 % (moving) of the values.
With a moving camera the reference averages pt over the same cameras. Each case runs under the
real-time profile (the defaults: temporal reuse) and under the converge profile (no temporal
reuse, 3 spatial rounds of 6 neighbours: independent frames), averaging the same frames.
Šidák-corrected per-pixel z-test at 0.01, >= 99.75 % of pixels passing, global mean within 3
sigma (tests/stats.py). Each comparison also rejects the same renders scaled by 1.03 (door-ajar's
crop, noisier at this budget: 1.05), so the test can see a bias of that size."""
import json

import numpy as np
import pytest

from conftest import render, seed_offset
from stats import assert_agree, ztest_runs

FPS = 30.0
K_REF = 16       # reference renders

# Per scene: sessions K, frames per session, how many of the last frames a session averages
# (door-ajar's light arrives through a door gap: its paths are far more heavy-tailed), the
# reference spp, the camera's slide over the session, the camera (None: the scene's) and the
# scale of the negative control.
CASES = {
    "cornell-glossy": {"k": 256, "frames": 16, "averaged": 8, "ref_spp": 512, "move": [60.0, 0.0, 0.0],
                       "camera": None, "control": 1.03},
    "door-ajar": {"k": 256, "frames": 40, "averaged": 32, "ref_spp": 4096, "move": [0.06, 0.0, 0.04],
                  "camera": {"position": [0.8, 1.2, 0.4], "look_at": [3.7, 0.4, 5.6], "fov_deg": 14}, "control": 1.05},
}


def _animation(tmp_path, name, frames, keys):
    path = tmp_path / name
    path.write_text(json.dumps({"animation": {"fps": FPS, "frames": frames, "interpolation": "linear",
                                              "camera_keys": keys}}))
    return path


def _animations(scene_path, tmp_path, case, moving):
    """The sessions' animation (the camera slides by `move` over all frames, or stays) and the
    reference's: the same cameras for the averaged frames only."""
    cam = case["camera"] or json.loads(scene_path.read_text())["camera"]
    move = case["move"] if moving else [0.0, 0.0, 0.0]
    frames, averaged = case["frames"], case["averaged"]

    def at(frac):
        return {"position": [a + frac * b for a, b in zip(cam["position"], move)],
                "look_at": [a + frac * b for a, b in zip(cam["look_at"], move)],
                **({"fov_deg": cam["fov_deg"]} if "fov_deg" in cam else {})}

    first = frames - averaged
    sessions = _animation(tmp_path, "sessions.json", frames,
                          [{"t": 0, **at(0.0)}, {"t": (frames - 1) / FPS, **at(1.0)}])
    reference = _animation(tmp_path, "reference.json", averaged,
                           [{"t": 0, **at(first / (frames - 1))}, {"t": (averaged - 1) / FPS, **at(1.0)}])
    return sessions, reference


_REF = {}   # the references by scene and motion, shared by the profiles


def _reference(scene_path, tmp_path, case, anim, key=None):
    key = key and (*key, seed_offset())
    if key in _REF:
        return _REF[key]
    n = case["averaged"]
    extra = ["--frames", str(n), "--average-last", str(n), "--animation", str(anim)]
    ref = np.stack([render(scene_path, tmp_path / f"ref{s}.exr", spp=case["ref_spp"] // n, seed=100000 + s,
                           extra=extra)[0] for s in range(K_REF)])
    if key is not None:
        _REF[key] = ref
    return ref


def _sessions(scene_path, tmp_path, case, anim, params=None, profile="real-time"):
    extra = ["--method", "restir_pt", "--frames", str(case["frames"]), "--average-last", str(case["averaged"]),
             "--animation", str(anim), "--profile", profile, *(["--params", json.dumps(params)] if params else [])]
    runs, stats = [], None
    for s in range(case["k"]):
        img, stats = render(scene_path, tmp_path / f"rp{s}.exr", spp=1, seed=s, extra=extra)
        runs.append(img)
    return np.stack(runs), stats


UNBIASED_CASES = [(scene, motion, profile) for profile in ("real-time", "converge") for scene in sorted(CASES)
                  for motion in ("static", "moving camera")]


@pytest.mark.statistical
@pytest.mark.parametrize("scene,motion,profile", UNBIASED_CASES, ids=["-".join(c) for c in UNBIASED_CASES])
def test_restir_pt_unbiased(tmp_path, scenes, scene, motion, profile):
    case = CASES[scene]
    # A converge session has no history to warm up: with the camera still it renders only the
    # frames it averages; with the camera moving, the real-time sessions' frames, so that the
    # reference over the averaged frames' cameras serves both.
    if profile == "converge" and motion == "static":
        case = {**case, "frames": case["averaged"]}
    sc = scenes / scene / "scene.json"
    anim, ref_anim = _animations(sc, tmp_path, case, motion != "static")
    ref = _reference(sc, tmp_path, case, ref_anim, (scene, motion))
    runs, stats = _sessions(sc, tmp_path, case, anim, profile=profile)
    # The sessions really reused: the last frame shifted samples between pixels (and, in real
    # time, frames).
    assert stats["last_frame"]["shifts"] > 0 and stats["reservoir_bytes_per_pixel"] <= 64
    # Non-finite pixel values are zeroed and counted by the shade pass: none may occur.
    assert np.isfinite(runs).all() and stats["nonfinite"] == 0
    res = ztest_runs(runs, ref)
    bad = ztest_runs(runs * case["control"], ref)
    print(f"{scene}, {motion}, {profile}: {res}; x{case['control']}: {bad}")
    assert_agree(res, f"{scene}, {motion}, {profile}")
    assert not bad.passed, f"{scene}, {motion}, {profile}: a bias of x{case['control']} went unseen: {bad}"


@pytest.mark.statistical
def test_restir_pt_rejection_and_replay_cap_unbiased(tmp_path, scenes):
    """Spatial neighbours rejected by normal and depth (`reject_normal_cos`, `reject_depth`, a
    symmetric test of the G-buffer) and the history of random-replay-only samples capped at 1
    (`temporal_cap_replay`, a class every shift keeps), on cornell-glossy with the camera moving.
    Each option is first shown to act: with the same seed, rejection shifts fewer samples here, and
    the cap alone changes lamp-in-glass's image (at 64x64: its paths through the glass have no
    reconnection vertex; on cornell-glossy's 32x32 image, and on lamp-in-glass's, the cap changed
    nothing: no selected sample there lacked one)."""
    case = CASES["cornell-glossy"]
    sc = scenes / "cornell-glossy" / "scene.json"
    anim, ref_anim = _animations(sc, tmp_path, case, True)

    def one(scene, params, *anim_args, size="32x32"):
        extra = ["--method", "restir_pt", "--frames", str(case["frames"]), *anim_args, "--profile", "real-time",
                 "--params", json.dumps(params)]
        return render(scene, tmp_path / "one.exr", spp=1, size=size, seed=7, extra=extra)

    _, base = one(sc, {}, "--animation", str(anim))
    _, rejecting = one(sc, {"reject_normal_cos": 0.5, "reject_depth": 0.1}, "--animation", str(anim))
    assert rejecting["last_frame"]["shifts"] < base["last_frame"]["shifts"], (rejecting["last_frame"], base["last_frame"])
    lamp = scenes / "lamp-in-glass" / "scene.json"
    assert not np.array_equal(one(lamp, {"temporal_cap_replay": 1}, size="64x64")[0], one(lamp, {}, size="64x64")[0])
    ref = _reference(sc, tmp_path, case, ref_anim)
    runs, stats = _sessions(sc, tmp_path, case, anim,
                            {"reject_normal_cos": 0.5, "reject_depth": 0.1, "temporal_cap_replay": 1})
    assert stats["last_frame"]["shifts"] > 0 and np.isfinite(runs).all() and stats["nonfinite"] == 0
    res = ztest_runs(runs, ref)
    assert_agree(res, "rejection and replay cap")
    bad = ztest_runs(runs * case["control"], ref)
    assert not bad.passed, f"rejection and replay cap: a bias of x{case['control']} went unseen: {bad}"


@pytest.mark.statistical
def test_restir_pt_ris_nee_unbiased(tmp_path, scenes):
    """RIS NEE with 4 candidates and its multi-sample MIS weights ([ReSTIR PT Enhanced §5]), the default
    under two or more lights, asked for here on cornell-glossy (one light: plain NEE by default)
    with the camera moving."""
    case = CASES["cornell-glossy"]
    sc = scenes / "cornell-glossy" / "scene.json"
    anim, ref_anim = _animations(sc, tmp_path, case, True)
    ref = _reference(sc, tmp_path, case, ref_anim)
    runs, stats = _sessions(sc, tmp_path, case, anim, {"nee_candidates": 4})
    assert stats["last_frame"]["shifts"] > 0 and np.isfinite(runs).all() and stats["nonfinite"] == 0
    res = ztest_runs(runs, ref)
    assert_agree(res, "4 NEE candidates")
    bad = ztest_runs(runs * case["control"], ref)
    assert not bad.passed, f"4 NEE candidates: a bias of x{case['control']} went unseen: {bad}"


def test_restir_pt_candidates_lower_initial_variance(tmp_path, scenes):
    """`candidates` 4 resamples four paths per pixel into the initial reservoir: without reuse,
    a frame's per-pixel variance over 32 seeds falls (measured 2.2x on cornell-box; not 4x, as
    the paths share the primary hit and the emission seen directly), and the image's mean stays.
    A session that ignored the parameter would give a ratio near 1."""
    sc = scenes / "cornell-box" / "scene.json"

    def frames(candidates):
        params = json.dumps({"candidates": candidates, "spatial_neighbors": 0, "temporal": False})
        return np.stack([render(sc, tmp_path / "c.exr", seed=s, extra=["--method", "restir_pt", "--params", params])[0]
                         for s in range(32)])

    one, four = frames(1), frames(4)
    ratio = one.var(axis=0).mean() / four.var(axis=0).mean()
    assert ratio > 1.6, f"variance of 1 candidate / 4 candidates: {ratio:.2f}"
    assert abs(four.mean() / one.mean() - 1) < 0.02, (four.mean(), one.mean())


def test_restir_pt_independent_of_thread_count(tmp_path, scenes):
    """Every random decision comes from a per-pixel stream: 1 and 3 threads give the same frames,
    here with the camera and a sphere moving (temporal reuse across changed scenes)."""
    anim = tmp_path / "anim.json"
    anim.write_text(json.dumps({"animation": {"fps": 30, "frames": 5, "camera_keys": [
        {"t": 0, "position": [278, 273, -800]}, {"t": 0.15, "position": [300, 273, -790]}],
        "light_keys": {"gold_sphere": [{"t": 0, "position": [0, 0, 0]}, {"t": 0.15, "position": [12, 0, 6]}]}}}))
    extra = ["--method", "restir_pt", "--animation", str(anim)]
    sc = scenes / "cornell-glossy" / "scene.json"
    a, sa = render(sc, tmp_path / "a.exr", spp=1, size="40x32", seed=4, extra=[*extra, "--threads", "1"])
    b, _ = render(sc, tmp_path / "b.exr", spp=1, size="40x32", seed=4, extra=[*extra, "--threads", "3"])
    assert sa["last_frame"]["shifts"] > 0
    assert np.array_equal(a, b)



@pytest.mark.statistical
def test_restir_pt_furnace(tmp_path, scenes):
    """The environment light: scenes/furnace's sphere of albedo 0.5 in a uniform environment of
    radiance 1 shows 0.5 on the sphere and 1 on the background (test_pt.py's analytic furnace).
    Every light path ends on the environment, so next-event estimation and the reconnection shift
    both work with environment directions, and the G-buffer's rays that escape must show it.
    K sessions of 12 frames, each the mean of its last 4; only pixels wholly on or off the
    sphere have a known expectation."""
    from test_pt import _sphere_coverage
    size = 24
    path = scenes / "furnace" / "albedo-half.json"
    cam = json.loads(path.read_text())["camera"]
    runs = np.stack([render(path, tmp_path / f"f{s}.exr", spp=1, size=f"{size}x{size}", seed=s,
                            extra=["--method", "restir_pt", "--frames", "12", "--average-last", "4",
                                   "--profile", "real-time"])[0]
                     for s in range(32)])
    cov = _sphere_coverage(size, cam["position"], cam["look_at"], cam["fov_deg"], [0, 0, 0], 1.0)
    known = (cov == 0) | (cov == 1)
    assert (cov == 1).sum() > 50 and (cov == 0).sum() > 50
    # Pixels clear of a slightly larger sphere cannot hold a sliver of the real one.
    clear = _sphere_coverage(size, cam["position"], cam["look_at"], cam["fov_deg"], [0, 0, 0], 1.05) == 0
    assert clear.sum() > 50 and np.all(runs[:, clear] == 1.0), "an escaped camera ray must show the environment"
    expected = np.where(cov == 1, 0.5, 1.0)[..., None].repeat(3, axis=2)
    res = ztest_runs(runs[:, known], expected=expected[known])
    assert_agree(res)
    bad = ztest_runs(runs[:, known] * 1.03, expected=expected[known])
    assert not bad.passed, str(bad)


@pytest.mark.parametrize("method,still", [
    ("restir_pt", {"temporal": False, "spatial_neighbors": 0}),
    ("restir_bdpt", {"reuse_temporal": False, "spatial_neighbors": 0, "caustic_temporal": False})])
def test_emission_seen_directly_spends_its_rays(tmp_path, scenes, method, still):
    """A frame shows the G-buffer's estimate of the emission seen directly (gbuffer.h): on
    cornell-box's light edge, 64 rays a frame scatter the pixels' values over 8 seeds at most a
    fifth as much as the primary ray's own (`emission_samples` 1), and the rest of the image is the
    same estimate either way (no reuse, the same seeds: the same paths; restir_bdpt's camera
    subpaths offer one candidate fewer only where their primary ray hits the light)."""
    path = scenes / "cornell-box" / "scene.json"
    runs = {}
    for k in (1, 64):
        params = json.dumps({"emission_samples": k, **still})
        runs[k] = np.stack([render(path, tmp_path / f"e{k}-{s}.exr", size="64x64", seed=s,
                                   extra=["--method", method, "--frames", "1", "--params", params])[0]
                            for s in range(8)]).mean(-1)
    light = runs[64].mean(0) > 2.0   # on or astride the light (its radiance is 12-17 a channel)
    edge = light & (runs[1].std(0) > 0.5)
    # Three pixels clear of anything either run saw of the light.
    seen = np.pad((runs[1].max(0) > 1.0) | (runs[64].max(0) > 1.0), 3)
    h, w = light.shape
    away = ~np.any([seen[3 + dy:3 + dy + h, 3 + dx:3 + dx + w] for dy in range(-3, 4) for dx in range(-3, 4)], axis=0)
    assert edge.sum() >= 8 and away.sum() > 3000, f"{edge.sum()} pixels astride the light's edge, {away.sum()} away"
    spread = {k: float(r[:, edge].std(0).mean()) for k, r in runs.items()}
    assert spread[64] < 0.2 * spread[1], f"the light's edge pixels scatter {spread} (by emission_samples)"
    assert np.array_equal(runs[1][:, away], runs[64][:, away]), "pixels away from the light changed"


REST_CASE = {"k": 128, "frames": 16, "averaged": 8, "ref_spp": 512, "control": 1.05}


def _light_animation(tmp_path, name, light, frames, first, last):
    """The shape `light` slid sideways from offset `first` to `last` (x) over `frames`."""
    path = tmp_path / name
    path.write_text(json.dumps({"animation": {"fps": FPS, "frames": frames, "light_keys": {light: [
        {"t": 0, "position": [first, 0, 0]}, {"t": (frames - 1) / FPS, "position": [last, 0, 0]}]}}}))
    return path


@pytest.mark.statistical
@pytest.mark.parametrize("motion,profile", [("static", "real-time"), ("moving light", "real-time"),
                                            ("static", "converge")])
def test_restir_pt_rest_subset_unbiased(tmp_path, scenes, motion, profile):
    """restir_pt restricted to the light that specular manifold sampling does not own (`subset`
    "rest", what restir_sms takes the rest of its image from; sms.h defines the split) against pt
    restricted the same way, on reflective-plane at 32x32, whose caustic from the mirror on the
    wall is the other part: K sessions, each the mean of its last 8 of 16 frames, with the scene
    still and with the lamp sliding (temporal shifts between scenes re-trace the suffix, and a
    re-traced path is classified again); the runs scaled by 1.05 fail. With the scene still, the
    same sessions without the restriction fail against it: the test sees the caustic. The
    converge profile (restir_sms's rest when its frames are independent: 8 initial paths a pixel
    here, 3 rounds of 6 neighbours) renders only the frames it averages.
    (refractive-slab's rest is no test bed at this size: under the caustic it holds paths through
    the glass by internal reflection, rare and bright, which 128 sessions of pt's own sampler miss
    as often as restir_pt's.)"""
    case = REST_CASE
    sc = scenes / "reflective-plane" / "scene.json"
    frames, averaged = case["frames"], case["averaged"]
    if profile == "converge":
        frames = averaged
    sessions_anim, ref_anim = [], []
    if motion != "static":
        slide = 0.2
        start = slide * (frames - averaged) / (frames - 1)
        sessions_anim = ["--animation", str(_light_animation(tmp_path, "s.json", "lamp", frames, 0.0, slide))]
        ref_anim = ["--animation", str(_light_animation(tmp_path, "r.json", "lamp", averaged, start, slide))]
    ref = np.stack([render(sc, tmp_path / f"ref{s}.exr", spp=case["ref_spp"] // averaged, seed=100000 + s,
                           extra=["--method", "pt", "--params", json.dumps({"subset": "rest"}),
                                  "--frames", str(averaged), "--average-last", str(averaged), *ref_anim])[0]
                    for s in range(K_REF)])

    def sessions(subset):
        runs, stats = [], None
        for s in range(case["k"]):
            img, stats = render(sc, tmp_path / f"rp{s}.exr", spp=1, seed=s,
                                extra=["--method", "restir_pt", "--params", json.dumps({"subset": subset}),
                                       "--frames", str(frames), "--average-last", str(averaged),
                                       "--profile", profile, *sessions_anim])
            runs.append(img)
        return np.stack(runs), stats

    runs, stats = sessions("rest")
    assert stats["last_frame"]["shifts"] > 0 and np.isfinite(runs).all() and stats["nonfinite"] == 0
    res = ztest_runs(runs, ref)
    bad = ztest_runs(runs * case["control"], ref)
    print(f"restir_pt subset rest, {motion}, {profile}: {res}; x{case['control']}: {bad}")
    assert_agree(res, f"restir_pt subset rest, {motion}, {profile}")
    assert not bad.passed, f"a bias of x{case['control']} went unseen: {bad}"
    if motion == "static" and profile == "real-time":
        whole, _ = sessions("all")
        unrestricted = ztest_runs(whole, ref)
        print(f"restir_pt subset all against the rest: {unrestricted}")
        assert not unrestricted.passed, f"restir_pt with the caustics agrees with the rest alone: {unrestricted}"
