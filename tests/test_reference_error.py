"""The report's reference-error estimate (bench/errors.py) on synthetic images whose truth and
noise are known, and its metrics against `restir compare`'s.

A reference is the mean of two independent halves; the estimate of its own error is a half
scored against the full reference. Here the truth is known, so the estimate can be held against
the reference's actual error, over many independent draws. The same check must reject the two
ways the estimate goes wrong: halves that share part of their noise, and a half scored against
the other half instead of against the full reference."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import errors  # noqa: E402
import references  # noqa: E402
from exrimage import write_rgb  # noqa: E402
from conftest import BIN, read_exr  # noqa: E402

SIDE, DRAWS = 64, 24
# The estimate's ratio to the actual error, averaged over DRAWS images of SIDE^2 x 3 values,
# has a standard error well under 1 %; a correct estimate lands within 4 %, while correlated
# halves (rho = 0.2: ratio (1 - rho) / (1 + rho) = 0.67 for relMSE, its root for RMSE) or the wrong
# scale (2x MAPE and RMSE, 4x relMSE) land far outside.
TOLERANCE = 0.04


def truth():
    """A positive image with a range of values like a render's: dark corners, a bright band."""
    y, x = np.mgrid[0:SIDE, 0:SIDE] / SIDE
    base = 0.02 + 0.6 * np.exp(-((x - 0.6) ** 2 + (y - 0.4) ** 2) / 0.05) + 0.1 * x
    return np.stack([base, 0.8 * base, 1.2 * base], axis=-1)


def halves(rng, t, rho=0.0, skewed=False):
    """Two noisy halves of t, noise 10 % of t (as a Monte Carlo mean's roughly is), with
    correlation rho between them. skewed: each half's noise is a mean of 8 exponentials
    (skewness 0.7), as a mean of few light samples' is."""
    sigma = 0.1 * t
    if skewed:
        def draw():
            return (rng.exponential(1.0, size=(8, *t.shape)).mean(axis=0) - 1.0) * np.sqrt(8)
        n1, n2 = draw(), draw()
    else:
        n1, n2 = rng.standard_normal(t.shape), rng.standard_normal(t.shape)
    return t + sigma * n1, t + sigma * (rho * n1 + np.sqrt(1.0 - rho * rho) * n2)


def ratios(estimate, rho=0.0, skewed=False, seed=1):
    """Mean estimated error over the mean actual error of the full reference, per metric."""
    rng = np.random.default_rng(seed)
    t = truth()
    est, act = {k: 0.0 for k in errors.KEYS}, {k: 0.0 for k in errors.KEYS}
    for _ in range(DRAWS):
        a, b = halves(rng, t, rho, skewed)
        e, x = estimate(a, b), errors.metrics(errors.combine(a, b), t)
        for k in errors.KEYS:
            est[k] += e[k]
            act[k] += x[k]
    return {k: est[k] / act[k] for k in errors.KEYS}


def agrees(r, keys=errors.KEYS):
    return all(abs(r[k] - 1.0) <= TOLERANCE for k in keys)


def test_the_estimate_matches_the_references_actual_error():
    r = ratios(errors.reference_error)
    assert agrees(r), r


def test_rmse_needs_no_symmetry():
    # E[(a+b)^2] = E[(a-b)^2] for any independent zero-mean a, b: RMSE holds for skewed noise
    # too. (MAPE, a mean absolute value, leans on the symmetry; relMSE divides by the noisy
    # reference as well.)
    r = ratios(errors.reference_error, skewed=True)
    assert agrees(r, ("rmse",)), r


def test_correlated_halves_are_caught():
    r = ratios(errors.reference_error, rho=0.2)
    assert not agrees(r), r
    assert r["relmse"] < 0.75, r


def test_a_half_against_the_other_half_is_caught():
    r = ratios(lambda a, b: errors.metrics(a, b))
    assert not agrees(r), r
    assert abs(r["mape"] - 2.0) < 0.1 and abs(r["relmse"] - 4.0) < 0.3, r


def test_flags_follow_the_factor():
    # 3x in the image's units, 9x in relMSE (a squared error).
    own = {"mape": 0.1, "rmse": 0.01, "relmse": 0.02}
    assert errors.within_noise({"mape": 0.29, "rmse": 0.031, "relmse": 0.17}, own) == \
        {"mape": True, "rmse": False, "relmse": True}
    assert errors.within_noise({"mape": 0.31, "rmse": 0.029, "relmse": 0.19}, own) == \
        {"mape": False, "rmse": True, "relmse": False}
    best = {"mape": 0.3, "rmse": 0.03, "relmse": 0.06}
    assert errors.long_enough({"mape": 0.17, "rmse": 0.017, "relmse": 0.019}, best)
    for k, v in (("mape", 0.18), ("rmse", 0.018), ("relmse", 0.021)):
        assert not errors.long_enough({**{"mape": 0.17, "rmse": 0.017, "relmse": 0.019}, k: v}, best), k


def compare_json(a, b):
    res = subprocess.run([BIN, "compare", str(a), str(b), "--json"], capture_output=True, text=True, timeout=60)
    return json.loads(res.stdout)


def test_metrics_are_restir_compares(tmp_path):
    scene = ROOT / "scenes" / "cornell-box" / "scene.json"
    paths = []
    for seed in (1, 2):
        out = tmp_path / f"s{seed}.exr"
        res = subprocess.run([BIN, "render", str(scene), "--spp", "2", "--size", "24x24", "--seed", str(seed),
                              "-o", str(out)], capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stderr
        paths.append(out)
    # Non-finite pixels on either side are left out by both; a reference of mean 0 has no MAPE.
    a, b = read_exr(paths[0])[..., :3], read_exr(paths[1])[..., :3]
    a[0, 0, 1], a[3, 5, 0], b[7, 7, 2] = np.nan, np.inf, -np.inf
    write_rgb(tmp_path / "a.exr", a)
    write_rgb(tmp_path / "b.exr", b)
    write_rgb(tmp_path / "zero.exr", np.zeros_like(b))
    for x, y in ((paths[0], paths[1]), (tmp_path / "a.exr", tmp_path / "b.exr"), (tmp_path / "a.exr", tmp_path / "zero.exr")):
        c, ours = compare_json(x, y), errors.metrics(read_exr(x), read_exr(y))
        for k in errors.KEYS:
            if c[k] is None:
                assert np.isnan(ours[k]), (x.name, y.name, k, ours[k])
            else:
                assert abs(ours[k] - c[k]) <= 1e-6 * abs(c[k]), (x.name, y.name, k, ours[k], c[k])


def test_reference_halves_are_independent_chunks(tmp_path, monkeypatch):
    """bench/references.py: chunk j is rendered with its own seed and goes to half A when even,
    B when odd; a longer reference keeps the chunks it had; a cached reference starts from all
    of them."""
    monkeypatch.setattr(references, "REFS", tmp_path / "refs")
    scene = ROOT / "scenes" / "cornell-box" / "scene.json"
    ref = references.Reference(scene, 8, "pt", 1, tmp_path)
    assert ref.chunks == 2 and not np.array_equal(ref.half_a, ref.half_b)
    c = [read_exr(ref._path(j))[..., :3] for j in range(2)]
    assert np.array_equal(ref.half_a, c[0]) and np.array_equal(ref.half_b, c[1])
    ref.grow()
    c += [read_exr(ref._path(j))[..., :3] for j in range(2, 4)]
    assert ref.chunks == 4 and len({x.tobytes() for x in c}) == 4
    assert np.allclose(ref.half_a, (c[0] + c[2]) / 2) and np.allclose(ref.half_b, (c[1] + c[3]) / 2)
    again = references.Reference(scene, 8, "pt", 1, tmp_path)
    assert again.chunks == 4 and np.array_equal(again.image, ref.image)


def test_colour_exact_separates_luminance_from_colour():
    """errors.colour_exact keeps an image whose only error is luminance (every pixel the
    reference's colour at another brightness) and makes exact one whose only error is colour
    (the reference's luminance in another colour); a black or non-finite reference pixel keeps
    the image's value."""
    rng = np.random.default_rng(11)
    ref = rng.uniform(0.05, 2.0, (16, 24, 3))
    w = np.asarray(errors.LUMINANCE)
    bright = ref * rng.lognormal(0.0, 0.5, (16, 24, 1))
    assert np.allclose(errors.colour_exact(bright, ref), bright, rtol=1e-12)
    assert errors.metrics(bright, ref)["mape"] > 0.3

    tint = ref * rng.uniform(0.3, 3.0, ref.shape)
    tint *= ((ref * w).sum(-1) / (tint * w).sum(-1))[..., None]  # the reference's luminance, other colours
    assert errors.metrics(tint, ref)["mape"] > 0.3
    exact = errors.metrics(errors.colour_exact(tint, ref), ref)
    assert exact["mape"] < 1e-12 and exact["relmse"] < 1e-24

    ref[2, 3] = 0.0
    ref[4, 5, 1] = np.nan
    out = errors.colour_exact(tint, ref)
    assert np.array_equal(out[2, 3], tint[2, 3]) and np.array_equal(out[4, 5], tint[4, 5])
