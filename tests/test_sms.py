"""Specular manifold sampling (method `sms`) against path tracing restricted to the paths it owns.

The split (renderer/integrators/sms.h): after a non-delta vertex, a path that crosses exactly one caster's
chain of delta vertices into an emitter belongs to SMS; `pt` with params.subset = "caustic"
renders exactly those paths (the filtered reference) and "rest" all others.

- The split is exact: caustic + rest == all for the same seed, pixel by pixel, and the path-traced
  part of `sms` is that same rest image (SMS draws from its own random stream), so `sms` counts
  nothing twice: sms = rest + SMS estimate.
- The SMS estimate is unbiased: K independent runs of `sms` (caustics only, Bernoulli trials
  uncapped) pass the per-pixel z-test (tests/stats.py: Šidák at 0.01, >= 99.75 % of pixels, global
  mean within the t threshold) against K_REF runs of the filtered reference on refractive-slab at
  32x32, and the same runs scaled by 1.03 fail it. Pixel values the reference met in fewer than
  REF_MIN_HITS of its runs are left out of the per-pixel part (their standard error is unknown),
  at most MAX_UNTESTED of them; the global mean holds them.
- The Bernoulli cap loses energy ([SMS-SSP Fig. 7]): a cap of 1 trial drops every solution not
  found again at once, and the counters report it.

The filtered reference is path tracing hitting two 0.1 x 0.1 lights through a glass slab: its
per-pixel distribution is heavy-tailed (a pixel at 32x32 may see a single path in 10^5 samples),
so it needs many samples; it is rendered once and kept in build/refs/, keyed by the scene files,
the parameters and the sources that define the estimator."""
import hashlib
import json

import numpy as np
import pytest

from conftest import ROOT, render, seed_offset
from stats import assert_agree, ztest_runs

SCENE = "refractive-slab"
K = 16               # sms runs
SMS_SPP = 32
K_REF = 32           # reference runs
REF_SPP = 4096
# The reference is path tracing towards two 0.1 x 0.1 lights through glass: at the caustic's
# edges a pixel may see its paths in none of the K_REF runs, where its sample variance is 0.
REF_MIN_HITS = 3
MAX_UNTESTED = 0.01  # of the image's sum (both sides' means)
REF_SOURCES = ["renderer/integrators/reference_pt.c", "renderer/integrators/sms.c", "renderer/material/material.c", "renderer/material/bsdf_dielectric.c",
               "renderer/material/bsdf_diffuse.c", "renderer/scene/light_sampler.c", "renderer/scene/surface.c", "renderer/scene/camera.c",
               "renderer/methods/method_pt.c", "renderer/core/sobol.h", "renderer/core/rng.h"]


def _params(d):
    return ["--params", json.dumps(d)]


def test_split_is_exact(tmp_path, scenes):
    sc = scenes / SCENE / "scene.json"
    # pt with the random sampler: sms's path-traced part draws pt's PCG streams (the Sobol'
    # sampler, pt's default, is pt's alone), so that its rest is pt's rest sample for sample.
    pt = ["--method", "pt", "--frames", "1"]
    rnd = {"spp": 8, "sampler": "random"}
    full, _ = render(sc, tmp_path / "all.exr", seed=3, extra=[*pt, *_params(rnd)])
    caustic, _ = render(sc, tmp_path / "c.exr", seed=3, extra=[*pt, *_params({**rnd, "subset": "caustic"})])
    rest, _ = render(sc, tmp_path / "r.exr", seed=3, extra=[*pt, *_params({**rnd, "subset": "rest"})])
    assert caustic.max() > 0 and rest.max() > 0
    np.testing.assert_allclose(caustic + rest, full, rtol=1e-5, atol=1e-6)
    # sms = the same rest + its own estimate of the caustic part.
    sms_all, st = render(sc, tmp_path / "s.exr", seed=3, extra=["--method", "sms", *_params({"spp": 8})])
    sms_c, _ = render(sc, tmp_path / "sc.exr", seed=3,
                      extra=["--method", "sms", *_params({"spp": 8, "caustics_only": True})])
    np.testing.assert_allclose(sms_all - sms_c, rest, rtol=1e-4, atol=1e-5)
    assert st["sms"]["solutions"] > 0 and sms_c.mean() > 0


def test_bernoulli_cap_loses_energy(tmp_path, scenes):
    sc = scenes / SCENE / "scene.json"
    runs = {}
    for cap in (0, 1):
        img, st = render(sc, tmp_path / f"cap{cap}.exr", size="16x16", seed=5,
                         extra=["--method", "sms", *_params({"spp": 16, "caustics_only": True, "bernoulli_cap": cap})])
        runs[cap] = (img.mean(), st["sms"])
    assert runs[0][1]["capped"] == 0
    assert runs[1][1]["capped"] > 0 and runs[1][1]["trials"] == runs[1][1]["solutions"] + runs[1][1]["capped"]
    assert runs[1][0] < runs[0][0]


def _cached_reference(tmp_path, sc):
    h = hashlib.sha256()
    for f in sorted((sc.parent).iterdir()):
        if f.suffix in (".json", ".obj"):
            h.update(f.read_bytes())
    for src in REF_SOURCES:
        h.update((ROOT / src).read_bytes())
    h.update(f"{K_REF} {REF_SPP} 32x32 caustic {seed_offset()}".encode())
    cache = ROOT / "build" / "refs" / f"sms-{SCENE}-{h.hexdigest()[:16]}.npy"
    if cache.exists():
        return np.load(cache)
    pt = ["--method", "pt", "--frames", "1", *_params({"spp": REF_SPP, "subset": "caustic"})]
    ref = np.stack([render(sc, tmp_path / f"ref{s}.exr", seed=100000 + s, extra=pt)[0] for s in range(K_REF)])
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.save(cache, ref)
    return ref


def _assert_unbiased(name, runs, ref, control, info):
    """The z-test of `runs` against the filtered reference's runs, and of runs scaled by `control`,
    which must fail; values the reference did not resolve stay out of the per-pixel part."""
    res = ztest_runs(runs, ref, min_nonzero_b=REF_MIN_HITS)
    bad = ztest_runs(runs * control, ref, min_nonzero_b=REF_MIN_HITS)
    print(f"{name} vs filtered reference: {res}; x{control}: {bad}; {info}")
    assert res.untested_share <= MAX_UNTESTED, f"the reference leaves too much of the image unresolved: {res}"
    assert_agree(res, f"{name} vs pt subset caustic")
    assert not bad.passed, f"a bias of x{control} went unseen: {bad}"


@pytest.mark.statistical
def test_sms_unbiased_against_filtered_reference(tmp_path, scenes):
    sc = scenes / SCENE / "scene.json"
    ref = _cached_reference(tmp_path, sc)
    runs, stats = [], None
    for s in range(K):
        img, stats = render(sc, tmp_path / f"sms{s}.exr", seed=s,
                            extra=["--method", "sms", *_params({"spp": SMS_SPP, "caustics_only": True,
                                                                "bernoulli_cap": 0})])
        runs.append(img)
    runs = np.stack(runs)
    assert np.isfinite(runs).all() and stats["nonfinite"] == 0 and stats["sms"]["capped"] == 0
    _assert_unbiased("sms", runs, ref, 1.03, f"counters of the last run: {stats['sms']}")


@pytest.mark.statistical
def test_sms_ssp_unbiased_against_filtered_reference(tmp_path, scenes):
    """sms_ssp (tiles, 3x3 trust regions, Bernoulli trials in the conditional space with eqs. 8-9,
    the per-frame prior) renders the same subset without bias. N = 8 tiles: at 32x32 a 16-pixel
    prior block covers a quarter of the image, so the prior is coarse and solutions outside it
    carry weights up to 1/P(C) = N^2 / (9 (1 - alpha)); N = 8 keeps the variance, and the test's
    time, affordable. The control is x1.05 (its t is ~6 here; x1.03 sits at the threshold).
    Each run is the mean of a still view's first 4 frames at 16 spp: frames 2-4 draw from the
    union of the walks kept so far (prior_frames, default 4), so the union is tested too."""
    sc = scenes / SCENE / "scene.json"
    ref = _cached_reference(tmp_path, sc)
    runs, stats = [], None
    for s in range(24):
        img, stats = render(sc, tmp_path / f"ssp{s}.exr", seed=s,
                            extra=["--method", "sms_ssp", "--frames", "4", "--average-last", "4",
                                   *_params({"spp": 16, "caustics_only": True, "bernoulli_cap": 0, "tiles": 8})])
        runs.append(img)
    runs = np.stack(runs)
    assert np.isfinite(runs).all() and stats["nonfinite"] == 0 and stats["sms"]["capped"] == 0
    assert stats["prior"]["solutions"] > 0
    _assert_unbiased("sms_ssp", runs, ref, 1.05, f"last run: {stats['sms']}, prior {stats['prior']}")


def test_sms_ssp_prior_and_fallback(tmp_path, scenes):
    """The prior raises the rate of solutions found over partitioning alone (the fallback, which a
    pair missing from the prior gets), and both stay unbiased estimates of the same mean (checked
    loosely here; the z-test above is the real check)."""
    sc = scenes / SCENE / "scene.json"
    out = {}
    for prior in (True, False):
        img, st = render(sc, tmp_path / f"p{prior}.exr", size="64x64", seed=2,
                         extra=["--method", "sms_ssp", *_params({"spp": 4, "caustics_only": True, "prior": prior})])
        out[prior] = (img.mean(), st["sms"]["solutions"] / st["sms"]["samples"], st["prior"])
    assert out[True][2]["samples"] > 0 and out[False][2]["samples"] == 0
    assert out[True][1] > 3 * out[False][1], out


def test_prior_seeds_only_receivers(tmp_path, scenes):
    """The prior holds the tiles of solutions seen from its block's receivers (sms_ssp.h), so only
    a pixel's receiver draws seeds from it: at most one SMS sample per camera path (sms_ssp) or per
    pixel and frame (restir_sms, whose candidates are made there). Every other vertex of a path
    falls back to partitioning alone (sms_ssp) or plain SMS (restir_sms). On reflective-plane,
    whose wall and floor meet, paths reach diffuse surfaces more than once, so there are more
    samples than receivers."""
    sc = scenes / "reflective-plane" / "scene.json"
    w = h = 32
    _, st = render(sc, tmp_path / "ssp.exr", size=f"{w}x{h}", seed=1,
                   extra=["--method", "sms_ssp", *_params({"spp": 4, "caustics_only": True})])
    n = st["sms"]
    assert 0 < n["with_prior"] <= w * h * 4 < n["samples"], n
    _, st = render(sc, tmp_path / "restir.exr", size=f"{w}x{h}", seed=1,
                   extra=["--method", "restir_sms", "--frames", "2", *_params({"caustics_only": True})])
    n = st["sms"]
    assert 0 < n["with_prior"] <= w * h * 2 < n["samples"], n
    # With SMS candidates nothing is drawn from a prior.
    _, st = render(sc, tmp_path / "sms.exr", size=f"{w}x{h}", seed=1,
                   extra=["--method", "restir_sms", *_params({"caustics_only": True, "sampler": "sms"})])
    assert st["sms"]["with_prior"] == 0 and st["sms"]["samples"] > 0, st["sms"]


def test_sms_session_in_the_daemon(tmp_path):
    """An sms session: its parameters with defaults, no buffers beyond pt's, and frames that report
    [SMS-SSP Table 1]'s counters; a bad parameter is a 422 naming it."""
    from daemon import Daemon
    d = Daemon(tmp_path / "data", "--threads", "2")
    try:
        r = d.req("POST", f"/v1/scenes/{SCENE}/sessions",
                  json_body={"method": "sms", "width": 16, "height": 16, "params": {"bernoulli_cap": 0}})
        assert r.status == 201, repr(r)
        s = r.json()
        assert s["method"] == "sms" and s["params"]["bernoulli_cap"] == 0 and s["params"]["max_iterations"] == 20
        assert s["params"]["caustics_only"] is False and s["reservoir_bytes"] == 0
        assert set(s["buffers"]) == {"frame", "accumulation", "shape_changes"}
        f = d.req("POST", s["href"] + "/frames", headers={"Accept": "application/json"})
        assert f.status == 200, repr(f)
        st = f.json()["sms"]
        assert st["samples"] > 0 and 0 < st["success_rate"] <= 1 and st["capped"] == 0
        assert st["newtons_per_solution"] >= st["newtons_per_sample"] > 0 and st["bernoulli_per_solution"] >= 1
        for params, field in [({"bernoulli_cap": -1}, "/params/bernoulli_cap"),
                              ({"max_iterations": 0}, "/params/max_iterations"),
                              ({"subset": "caustic"}, "/params/subset")]:
            r = d.req("POST", f"/v1/scenes/{SCENE}/sessions", json_body={"method": "sms", "params": params})
            assert r.status == 422 and r.json().get("field") == field, (params, repr(r))
        # sms_ssp: its prior is its only buffer beyond pt's (8 pair entries of 168 bytes per 16x16 block,
        # in the table sampled from and in each of the prior_frames tables of kept walks).
        r = d.req("POST", f"/v1/scenes/{SCENE}/sessions",
                  json_body={"method": "sms_ssp", "width": 40, "height": 20, "params": {"tiles": 8, "alpha": 0.5}})
        assert r.status == 201, repr(r)
        s = r.json()
        assert s["params"]["tiles"] == 8 and s["params"]["alpha"] == 0.5 and s["params"]["prior_samples"] == 128
        assert set(s["buffers"]) == {"frame", "accumulation", "shape_changes", "prior"}
        assert s["params"]["prior_frames"] == 4 and s["buffers"]["prior"] == (1 + 4) * 3 * 2 * 8 * 168
        r = d.req("POST", f"/v1/scenes/{SCENE}/sessions",
                  json_body={"method": "sms_ssp", "width": 40, "height": 20, "params": {"prior_frames": 1}})
        assert r.status == 201 and r.json()["buffers"]["prior"] == 3 * 2 * 8 * 168, repr(r)
        f = d.req("POST", s["href"] + "/frames", headers={"Accept": "application/json"}).json()
        assert f["prior"]["samples"] > 0 and f["sms"]["samples"] > 0
        for params, field in [({"alpha": 1}, "/params/alpha"), ({"tiles": 33}, "/params/tiles"),
                              ({"prior": 1}, "/params/prior"), ({"prior_frames": 0}, "/params/prior_frames"),
                              ({"prior_frames": 17}, "/params/prior_frames")]:
            r = d.req("POST", f"/v1/scenes/{SCENE}/sessions", json_body={"method": "sms_ssp", "params": params})
            assert r.status == 422 and r.json().get("field") == field, (params, repr(r))
        r = d.req("POST", f"/v1/scenes/{SCENE}/sessions", json_body={"method": "pt", "params": {"subset": "some"}})
        assert r.status == 422 and r.json().get("field") == "/params/subset", repr(r)
    finally:
        rc, _ = d.stop()
        assert rc == 0, d.stderr()[-3000:]


def test_prior_unites_walks_of_a_still_view(tmp_path, scenes):
    """The prior of a still view is the union of the last prior_frames frames' walks (sms_ssp.h):
    under the scene's camera, prior_frames 4 and 1 give different frames from the same samples'
    streams. When the camera moves every frame the kept walks are dropped, so both give the same
    frames byte for byte, for restir_sms and for an sms_ssp session alike."""
    sc = scenes / SCENE / "scene.json"
    moving = tmp_path / "moving.json"
    moving.write_text(json.dumps({"animation": {"fps": 30, "frames": 3, "camera_keys": [
        {"t": 0, "position": [0, 2.2, 2.6], "look_at": [0, 0.2, 0]},
        {"t": 0.1, "position": [0.3, 2.2, 2.5], "look_at": [0, 0.2, 0]}]}}))
    for method, params in [("restir_sms", {"caustics_only": True}), ("sms_ssp", {"caustics_only": True, "spp": 2})]:
        img = {}
        for k in (1, 4):
            for still in (True, False):
                extra = ["--method", method, "--frames", "3", *_params({**params, "prior_frames": k})]
                img[k, still], _ = render(sc, tmp_path / f"{method}{k}{still}.exr", size="32x32", seed=3,
                                          extra=extra if still else [*extra, "--animation", str(moving)])
        assert img[1, True].mean() > 0 and img[1, False].mean() > 0, method
        assert not np.array_equal(img[1, True], img[4, True]), method
        assert np.array_equal(img[1, False], img[4, False]), method


@pytest.mark.parametrize("method", ["sms", "sms_ssp"])
def test_independent_of_thread_count(tmp_path, scenes, method):
    """Every random decision (seeds, light points, Bernoulli trials, the prior's walks) comes from
    per-pixel or per-block streams: 1 and 3 threads give the same image."""
    sc = scenes / SCENE / "scene.json"
    extra = ["--method", method, *_params({"spp": 2})]
    a, _ = render(sc, tmp_path / "a.exr", size="40x32", seed=4, extra=[*extra, "--threads", "1"])
    b, _ = render(sc, tmp_path / "b.exr", size="40x32", seed=4, extra=[*extra, "--threads", "3"])
    assert a.mean() > 0 and np.array_equal(a, b)
