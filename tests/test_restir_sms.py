"""ReSTIR over specular manifold samples (method `restir_sms`, [SMS-SSP §5]) against path tracing
restricted to the paths SMS owns (`pt` with subset "caustic", the filtered reference of
tests/test_sms.py, shared with it through its cache).

- Unbiased with a still camera: K independent sessions (caustics only, Bernoulli trials
  uncapped), each the mean of its last frames, pass the per-pixel z-test (tests/stats.py: Šidák
  at 0.01, >= 99.75 % of pixels, global mean within the t threshold) on refractive-slab at 32x32,
  and the same runs scaled by 1.05 fail it; with a reservoir per light (the default, one for each
  of the slab's two lights) and with one reservoir for both.
- Unbiased with the camera moving: the camera travels away and back before the averaged frames,
  so those frames resample reservoirs that went through temporal shifts under camera motion
  (control: the runs scaled by 1.07 fail).
- The failure case of [SMS-SSP] (the prior misses a light): with one prior walk per 16x16 block a
  block finds at most one of the two (light, caster) pairs, so every block falls back to
  partitioning alone (alpha = 0) for the other light; the estimate stays unbiased (same z-test).
  bench/sms.py charts what it costs.
- A light switched off during a session (reservoirs holding history from both lights) agrees
  with fresh sessions on a copy without it.
- Receivers behind delta vertices (the caustic seen in reflective-plane's mirror) agree with
  `sms`, which estimates at every vertex itself; leaving out the prefix's throughput fails it.
- The test can fail on a real bias too: with a Bernoulli cap of 1 trial (solutions not found
  again at once are dropped, [SMS-SSP Fig. 7]) the same test fails.

Each of K sessions renders FRAMES frames and averages the last AVG (one run's mean has a relative
standard deviation of ~4 % here, so K = 24 runs put the x1.05 control at t ~ 5-6); the frames of one session are
correlated, the sessions are independent, which is what the z-test's per-pixel variance needs.
The sessions run under the real-time profile (the defaults); the unbiasedness tests with a still
and a moving camera also under the converge profile (temporal and spatial reuse off, a fresh primary
ray position every frame, plain SMS candidates unless the parameters name the sampler, and with
the partitioned one a prior of the frame's own walks: independent frames; the still camera with
both samplers), averaging the same
frames (with the camera still, a converge session renders only those: it has no history to warm
up)."""
import json
import shutil

import numpy as np
import pytest

from conftest import render, sky_all_round
from stats import assert_agree, ztest_runs
from test_sms import SCENE, _cached_reference

K = 24
FRAMES = 32
AVG = 24
# tiles 8 as in the sms_ssp test: at 32x32 the 16-pixel prior blocks are coarse, and N = 8 keeps
# the weight of a solution outside the prior (up to N^2 / (9 (1 - alpha))) affordable.
PARAMS = {"caustics_only": True, "bernoulli_cap": 0, "tiles": 8}


def _runs(tmp_path, sc, params, anim=None, tag="r", frames=FRAMES, avg=AVG, k=K, every=None, profile="real-time"):
    """K sessions; the last one's statistics (and each one's appended to `every` when given)."""
    runs, stats = [], None
    for s in range(k):
        extra = ["--method", "restir_sms", "--params", json.dumps(params), "--frames", str(frames),
                 "--average-last", str(avg), "--profile", profile]
        if anim:
            extra += ["--animation", str(anim)]
        img, stats = render(sc, tmp_path / f"{tag}{s}.exr", seed=s, extra=extra)
        runs.append(img)
        if every is not None:
            every.append(stats)
    return np.stack(runs), stats


# The moving-camera runs: 16 frames of motion (away and back), then the averaged frames; 16
# sessions (the x1.07 control's t is ~5 with 24, ~4.5 with 16, against a threshold of ~3.3).
MOVING_FRAMES, MOVING_AVG = 40, 24


def _moving_camera(tmp_path, sc, frames, avg):
    """The camera moves 10 % of the way towards its target and sideways, then comes back, and stays
    at its own position for the last `avg` frames (those the runs average)."""
    cam = json.loads(sc.read_text())["camera"]
    pos, at = np.array(cam["position"]), np.array(cam["look_at"])
    away = (pos + 0.1 * (at - pos) + np.array([0.15, 0.0, 0.0])).tolist()
    fps = 30.0
    back = (frames - avg - 1) / fps
    anim = tmp_path / "anim.json"
    anim.write_text(json.dumps({"animation": {"fps": fps, "frames": frames, "camera_keys": [
        {"t": 0.0, "position": pos.tolist(), "look_at": at.tolist()},
        {"t": back / 2, "position": away, "look_at": at.tolist()},
        {"t": back, "position": pos.tolist(), "look_at": at.tolist()},
        {"t": (frames - 1) / fps, "position": pos.tolist(), "look_at": at.tolist()}]}}))
    return anim


@pytest.mark.statistical
@pytest.mark.parametrize("light_reservoirs,profile,sampler", [(0, "real-time", "ssp"), (1, "real-time", "ssp"),
                                                              (0, "converge", "ssp"), (0, "converge", None)])
def test_restir_sms_unbiased_still_camera(tmp_path, scenes, light_reservoirs, profile, sampler):
    """The paper's sampler (partitioning with the prior), with a reservoir per light (the default:
    the slab's two) and with one for both, in both profiles; and the converge profile with its
    own sampler (plain SMS candidates: `sampler` None leaves the profile's choice). Plain SMS
    candidates under real-time reuse are z-tested on reflective-plane below (against sms)."""
    sc = scenes / SCENE / "scene.json"
    ref = _cached_reference(tmp_path, sc)
    params = {**PARAMS, "light_reservoirs": light_reservoirs}
    if sampler:
        params["sampler"] = sampler
    runs, st = _runs(tmp_path, sc, params, tag=f"r{light_reservoirs}",
                     frames=AVG if profile == "converge" else FRAMES, profile=profile)
    assert np.isfinite(runs).all() and st["nonfinite"] == 0 and st["sms"]["capped"] == 0
    # The converge profile's own sampler is plain SMS, which walks no prior; the partitioned one does.
    assert (st["prior"]["samples"] > 0) == (sampler == "ssp")
    # The converge profile reuses nothing (no history, no spatial neighbour), so it shifts nothing.
    assert (st["last_frame"]["shifts"] > 0) == (profile == "real-time")
    # 64 bytes per reservoir: one per light (the slab's two) when left to the scene.
    assert st["reservoir_bytes_per_pixel"] == 64 * (light_reservoirs or 2)
    res = ztest_runs(runs, ref)
    bad = ztest_runs(runs * 1.05, ref)
    print(f"restir_sms ({sampler or 'sms: the profile default'}, still, {profile}) vs filtered reference: {res}; "
          f"x1.05: {bad}; last run: {st['last_frame']}, {st['manifold_shift']}")
    assert_agree(res, "restir_sms vs pt subset caustic")
    assert not bad.passed, f"a bias of x1.05 went unseen: {bad}"


@pytest.mark.statistical
@pytest.mark.parametrize("profile", ["real-time", "converge"])
def test_restir_sms_unbiased_moving_camera(tmp_path, scenes, profile):
    sc = scenes / SCENE / "scene.json"
    ref = _cached_reference(tmp_path, sc)
    anim = _moving_camera(tmp_path, sc, MOVING_FRAMES, MOVING_AVG)
    runs, st = _runs(tmp_path, sc, PARAMS, anim=anim, tag="m", frames=MOVING_FRAMES, avg=MOVING_AVG, k=16,
                     profile=profile)
    assert np.isfinite(runs).all() and st["nonfinite"] == 0 and st["sms"]["capped"] == 0
    res = ztest_runs(runs, ref)
    # x1.07: the runs' spread is as large as the still camera's but the control's t there is only
    # 3.7-4.5 against a threshold of ~3.2, too close for a check that must fail every time.
    bad = ztest_runs(runs * 1.07, ref)
    print(f"restir_sms (moving camera, {profile}) vs filtered reference: {res}; x1.07: {bad}; "
          f"last run: {st['last_frame']}")
    assert_agree(res, "restir_sms under camera motion vs pt subset caustic")
    assert not bad.passed, f"a bias of x1.07 went unseen: {bad}"


@pytest.mark.statistical
def test_restir_sms_capped_bernoulli_is_caught(tmp_path, scenes):
    """A real bias, not a scaled image: one Bernoulli trial per solution drops every solution not
    found again at once. The z-test must see the energy lost."""
    sc = scenes / SCENE / "scene.json"
    ref = _cached_reference(tmp_path, sc)
    runs, st = _runs(tmp_path, sc, {**PARAMS, "bernoulli_cap": 1}, tag="c", frames=16, avg=8, k=8)
    assert st["sms"]["capped"] > 0
    res = ztest_runs(runs, ref)
    print(f"restir_sms with bernoulli_cap 1: {res}; mean ratio {runs.mean() / ref.mean():.3f}")
    assert not res.passed, f"the capped estimator's energy loss went unseen: {res}"


@pytest.mark.statistical
def test_restir_sms_prior_missing_a_light_stays_unbiased(tmp_path, scenes):
    sc = scenes / SCENE / "scene.json"
    ref = _cached_reference(tmp_path, sc)
    every = []
    runs, st = _runs(tmp_path, sc, {**PARAMS, "prior_samples": 1}, tag="p", every=every)
    # 32x32 is 4 blocks of 16x16: at most 4 walks and solutions per frame, one pair per block, two
    # lights. Whether one frame's 4 walks find anything is luck; over the sessions' last frames
    # some priors must hold solutions, or this would test the fallback alone.
    assert all(e["prior"]["samples"] <= 4 and e["prior"]["solutions"] <= 4 for e in every)
    assert sum(e["prior"]["solutions"] for e in every) > 0
    assert np.isfinite(runs).all() and st["nonfinite"] == 0 and st["sms"]["capped"] == 0
    res = ztest_runs(runs, ref)
    # The fallback's heavier tail (solutions outside any prior tile weigh up to N^2 / 9 in the
    # pair without a prior) leaves this test the power to see ~10 %, not 5 %: the control is x1.12.
    bad = ztest_runs(runs * 1.12, ref)
    print(f"restir_sms, prior of 1 walk per block: {res}; x1.12: {bad}; prior {st['prior']}")
    assert_agree(res, "restir_sms with a prior that misses a light vs pt subset caustic")
    assert not bad.passed, f"a bias of x1.12 went unseen: {bad}"


PLANE = "reflective-plane"
PLANE_SIZE = "24x24"


@pytest.mark.statistical
def test_restir_sms_receivers_behind_a_mirror(tmp_path, scenes):
    """reflective-plane: part of the caustic is seen in the mirror, so those pixels' receivers lie
    behind a delta vertex (the prefix's throughput is in the target, and the path tracer leaves
    exactly that vertex to the reservoirs). Compared with `sms` (caustics only, 32 spp per run),
    which makes its estimate at every vertex itself: path tracing cannot be the reference here, it
    never finds some of the dim mirror paths in 32 x 4096 samples (zero-variance pixels that fail
    `sms` itself), while the global means agree. x1.05 fails."""
    sc = scenes / PLANE / "scene.json"
    params = {**PARAMS, "sampler": "sms"}
    runs, base = [], []
    st = None
    # Fewer and shorter runs than on the slab: the mirror scene's estimates are far less
    # heavy-tailed, and the x1.05 control still sits at t ~ 30.
    for s in range(16):
        img, st = render(sc, tmp_path / f"pl{s}.exr", size=PLANE_SIZE, seed=s,
                         extra=["--method", "restir_sms", "--params", json.dumps(params),
                                "--frames", "24", "--average-last", "16", "--profile", "real-time"])
        runs.append(img)
        ref, _ = render(sc, tmp_path / f"sms{s}.exr", size=PLANE_SIZE, seed=1000 + s,
                        extra=["--method", "sms", "--params", json.dumps({"spp": 32, "caustics_only": True,
                                                                          "bernoulli_cap": 0})])
        base.append(ref)
    runs, base = np.stack(runs), np.stack(base)
    assert np.isfinite(runs).all() and st["nonfinite"] == 0 and st["sms"]["capped"] == 0
    res = ztest_runs(runs, base)
    bad = ztest_runs(runs * 1.05, base)
    print(f"restir_sms on {PLANE} vs sms: {res}; x1.05: {bad}")
    assert_agree(res, f"restir_sms on {PLANE} vs sms")
    assert not bad.passed, f"a bias of x1.05 went unseen: {bad}"


@pytest.mark.statistical
def test_restir_sms_light_switched_off_stays_unbiased(tmp_path, scenes):
    """refractive-slab's warm light goes off at frame 8 of a session, so the reservoirs resample
    history gathered under both lights (the warm light's paths then shift to black and drop out,
    the cool light's stay in their reservoir): the mean of frames 16-31 agrees with that of fresh
    sessions on a copy whose warm light is off from the start (a fresh session is z-tested against
    path tracing above), 16 of each; x1.07 fails."""
    sc = scenes / SCENE / "scene.json"
    doc = json.loads(sc.read_text())
    warm = doc["materials"]["warm"]["emission"]
    fps, frames = 30.0, 32
    anim = tmp_path / "off.json"
    anim.write_text(json.dumps({"animation": {"fps": fps, "frames": frames, "light_keys": {"warm_light": [
        {"t": 7 / fps, "emission": warm}, {"t": 8 / fps, "emission": [0, 0, 0]}]}}}))
    dark = tmp_path / "dark"
    shutil.copytree(scenes / SCENE, dark)
    doc["materials"]["warm"]["emission"] = [0, 0, 0]
    (dark / "scene.json").write_text(json.dumps(doc))
    runs, base = [], []
    st = None
    for s in range(16):
        img, st = render(sc, tmp_path / f"off{s}.exr", seed=s,
                         extra=["--method", "restir_sms", "--params", json.dumps({**PARAMS, "sampler": "sms"}),
                                "--frames", str(frames), "--average-last", "16", "--animation", str(anim),
                                "--profile", "real-time"])
        runs.append(img)
        ref, _ = render(dark / "scene.json", tmp_path / f"dark{s}.exr", seed=1000 + s,
                        extra=["--method", "restir_sms", "--params", json.dumps({**PARAMS, "sampler": "sms"}),
                               "--frames", str(frames), "--average-last", "16", "--profile", "real-time"])
        base.append(ref)
    runs, base = np.stack(runs), np.stack(base)
    assert np.isfinite(runs).all() and st["nonfinite"] == 0 and st["sms"]["capped"] == 0
    assert base.mean() > 0.0
    res = ztest_runs(runs, base)
    bad = ztest_runs(runs * 1.07, base)
    print(f"restir_sms, warm light off at frame 8, vs fresh sessions without it: {res}; x1.07: {bad}")
    assert_agree(res, "restir_sms after a light went off vs fresh sessions without it")
    assert not bad.passed, f"a bias of x1.07 went unseen: {bad}"


def test_restir_sms_environment_shows_through(tmp_path, scenes):
    """With an environment light, a pixel whose camera ray escapes (the G-buffer's entry without a
    hit) shows the environment exactly, as in pt, and the rest of the image stays finite: the
    scene's own views have no sky. refractive-slab copied with an environment and a camera that
    looks over the slab at the horizon."""
    folder = tmp_path / "slab-sky"
    shutil.copytree(scenes / SCENE, folder)
    doc = json.loads((folder / "scene.json").read_text())
    env = [0.2, 0.3, 0.5]
    doc["environment"] = {"radiance": env}
    doc["camera"] = {"position": [0, 0.6, 2.6], "look_at": [0, 0.7, 0], "up": [0, 1, 0], "fov_deg": 38}
    (folder / "scene.json").write_text(json.dumps(doc))
    ref, _ = render(folder, tmp_path / "pt.exr", spp=16, size="24x24", seed=1)
    sky = np.all(np.abs(ref - np.array(env)) < 1e-6, axis=2)
    assert 0.1 < sky.mean() < 0.7, f"{sky.mean():.2f} of the pixels are sky"
    clear = sky_all_round(sky)
    img, st = render(folder, tmp_path / "r.exr", spp=1, size="24x24", seed=2,
                     extra=["--method", "restir_sms", "--frames", "3"])
    assert st["nonfinite"] == 0 and np.isfinite(img).all()
    assert clear.sum() > 20 and np.all(np.abs(img[clear] - np.array(env)) < 1e-6)
    assert img[~sky].mean() > 0.0


def test_restir_sms_expected_shading_changes_only_the_shading(tmp_path, scenes):
    """`expected_shading` shades with the spatial pass's expectation over its candidates: the same
    reservoirs and shifts (so the same statistics), a different image; with no spatial pass it has
    nothing to shade from and the image is the selected samples' exactly. Its unbiasedness is the
    z-tests' above, which run with it (the default)."""
    sc = scenes / SCENE / "scene.json"

    def run(tag, **params):
        extra = ["--method", "restir_sms", "--frames", "4", "--params", json.dumps({**PARAMS, **params})]
        return render(sc, tmp_path / f"{tag}.exr", spp=1, seed=3, extra=extra)

    on, st_on = run("on")
    off, st_off = run("off", expected_shading=False)
    assert st_on["last_frame"]["shifts"] > 0
    for key in ("shifts", "shift_failures"):
        assert st_on["last_frame"][key] == st_off["last_frame"][key]
    for group in ("sms", "manifold_shift"):
        counts = {k: v for k, v in st_on[group].items() if not k.endswith("_ms")}
        assert counts == {k: st_off[group][k] for k in counts}, group
    differ = np.any(on != off, axis=2)
    assert differ.sum() >= 10, f"{differ.sum()} pixels differ"
    assert np.isfinite(on).all() and st_on["nonfinite"] == 0
    no_spatial_on, _ = run("ns_on", spatial_neighbors=0)
    no_spatial_off, _ = run("ns_off", spatial_neighbors=0, expected_shading=False)
    assert np.array_equal(no_spatial_on, no_spatial_off)


@pytest.mark.parametrize("profile", ["real-time", "converge"])
def test_restir_sms_rest_is_restir_pt_beside_the_caustics(tmp_path, scenes, profile):
    """By default (`rest` by_scene, restir_pt on a scene without translucent materials) a restir_sms
    frame is exactly the sum of two estimates, each z-tested on its own: a restir_pt session
    restricted to the light SMS does not own (`subset` "rest": test_restir_pt.py's
    test_restir_pt_rest_subset_unbiased) and restir_sms's caustics alone (`caustics_only`: the tests
    above), each with the same seed, in either profile (the rest takes restir_pt's converge profile
    when restir_sms's frames are independent). With `rest` "pt" the frame is another (one path a
    pixel for the rest)."""
    sc = scenes / SCENE / "scene.json"
    common = ["--frames", "6", "--profile", profile]
    full, st = render(sc, tmp_path / "full.exr", seed=5, extra=["--method", "restir_sms", *common])
    assert st["rest_ms"] > 0, st
    # assert_allclose would pass NaNs found at the same pixel on both sides: none may occur.
    assert np.isfinite(full).all() and st["nonfinite"] == 0
    rest, rst = render(sc, tmp_path / "rest.exr", seed=5,
                       extra=["--method", "restir_pt", "--params", json.dumps({"subset": "rest"}), *common])
    caustics, _ = render(sc, tmp_path / "caustics.exr", seed=5,
                         extra=["--method", "restir_sms", "--params", json.dumps({"caustics_only": True}), *common])
    assert rst["last_frame"]["shifts"] > 0 and rest.mean() > 0 and caustics.mean() > 0
    np.testing.assert_allclose(full, rest + caustics, rtol=1e-5, atol=1e-6)
    by_pt, pst = render(sc, tmp_path / "pt.exr", seed=5,
                        extra=["--method", "restir_sms", "--params", json.dumps({"rest": "pt"}), *common])
    assert pst["rest_ms"] == 0, pst
    assert not np.allclose(by_pt, full, rtol=1e-3)
