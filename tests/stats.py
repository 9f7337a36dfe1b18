"""Statistical comparisons of Monte Carlo images (the pytest tier, tests/README.md).

Two sets of independent renders (or one set and a known analytic image) are compared per pixel
with Welch's z statistic; the per-pixel threshold is Šidák-corrected so that the whole image
is tested at significance 0.01. A comparison passes when at least 99.75 % of the pixels pass
*and* the image means agree at the 3-sigma level (two-sided p = 0.0027). The image means'
standard error is estimated from K runs, so that statistic follows Student's t with Welch's
degrees of freedom, not the normal law: with K = 16 a normal 3-sigma threshold would reject a
correct renderer about one time in a hundred.

Confirmation. About fifty comparisons run in `make test`, each at about 0.003 for its image
means, so that every change of a sampler's random numbers redraws them all with a fair chance of
one false rejection; and estimators with rare bright paths (a few reuse methods after a jump, a
reference through glass) make the sample variance small exactly where the mean is low, which
leans the statistic the same way. A rejected comparison is therefore run once more on renders
with independent seeds (conftest.py's pytest_pyfunc_call: every seed a test gives `render` is
shifted), and the test fails only when both reject. A correct renderer then fails a comparison
with a probability near the square of its level; a biased one fails both unless its bias is at
the edge of the test's power, which the negative controls bound: every comparison also rejects
the same renders scaled by a few per cent, and a control that passes fails the test at once, in
either run."""
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np


GLOBAL_P = 0.0027  # two-sided, the normal law's 3 sigma


def t_quantile(p_upper, dof):
    """Upper quantile of Student's t (Cornish-Fisher expansion; error < 1e-3 for dof >= 5)."""
    z = NormalDist().inv_cdf(1.0 - p_upper)
    if not np.isfinite(dof):
        return z
    v = dof
    return (z + (z**3 + z) / (4 * v) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * v**2)
            + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * v**3))


@dataclass
class ZTest:
    fraction_pass: float
    worst_z: float
    global_z: float
    threshold: float
    global_threshold: float
    untested: int = 0  # pixel values left out of the per-pixel test (ztest_runs' min_nonzero_b)
    untested_share: float = 0.0  # their share of both sides' summed means

    @property
    def passed(self):
        return self.fraction_pass >= 0.9975 and abs(self.global_z) <= self.global_threshold

    def __str__(self):
        text = (f"pixels passing {100 * self.fraction_pass:.3f}% (threshold |z| <= {self.threshold:.2f}), "
                f"worst |z| {self.worst_z:.2f}, global mean t {self.global_z:.2f} "
                f"(threshold {self.global_threshold:.2f})")
        if self.untested:
            text += f", {self.untested} values untested ({100 * self.untested_share:.2f} % of the image's sum)"
        return text


class NullRejected(AssertionError):
    """A comparison rejected equal means: conftest.py confirms it on independent renders."""


def assert_agree(res, what=""):
    """Fails the test (NullRejected) when comparison `res` rejected equal means."""
    if not res.passed:
        raise NullRejected(f"{what}: {res}" if what else str(res))


def sidak_threshold(n_tests, alpha=0.01):
    per_test = 1.0 - (1.0 - alpha) ** (1.0 / n_tests)
    return NormalDist().inv_cdf(1.0 - per_test / 2.0)


FLOAT_REL_FLOOR = 1e-5


def ztest_runs(runs_a, runs_b=None, expected=None, rel_floor=FLOAT_REL_FLOOR, min_nonzero_b=0):
    """runs_a, runs_b: arrays K x H x W x C of independent renders. Either runs_b (a second set)
    or `expected` (an exact image, H x W x C, or a scalar) is the comparison.

    min_nonzero_b: pixel values where fewer of runs_b than this are nonzero are left out of the
    per-pixel test (and counted in ZTest.untested, with their share of the image's sum), unless
    every run of both sides is zero there; the image means still hold them. A reference
    that met a pixel's rare paths in a run or two, or in none, has a sample variance of 0 or of
    one or two samples, so its standard error there says nothing, and a correct estimator's mean
    reads as many sigma away. Path tracing towards small lights seen through glass leaves such pixels at any
    affordable sample count.

    rel_floor: a standard-error floor relative to the value. Pixels whose paths all carry the
    same weight up to float rounding (e.g. lossless specular paths that end before Russian
    roulette) have a sample variance of ~1e-14; without a floor their rounding error of ~1e-7
    would read as a huge z. A difference below float precision is not evidence of bias."""
    a = np.asarray(runs_a, dtype=np.float64)
    ka = a.shape[0]
    mean_a = a.mean(axis=0)
    var_a = a.var(axis=0, ddof=1) / ka
    img_a = a.reshape(ka, -1).mean(axis=1)  # per-run image means
    if runs_b is not None:
        b = np.asarray(runs_b, dtype=np.float64)
        kb = b.shape[0]
        mean_b = b.mean(axis=0)
        var_b = b.var(axis=0, ddof=1) / kb
        img_b = b.reshape(kb, -1).mean(axis=1)
        g_diff = img_a.mean() - img_b.mean()
        va, vb = img_a.var(ddof=1) / ka, img_b.var(ddof=1) / kb
        g_se = np.sqrt(va + vb)
        dof = (va + vb) ** 2 / (va**2 / (ka - 1) + vb**2 / (kb - 1)) if va + vb > 0 else np.inf
    else:
        mean_b = np.broadcast_to(np.asarray(expected, dtype=np.float64), mean_a.shape)
        var_b = np.zeros_like(mean_a)
        g_diff = img_a.mean() - mean_b.mean()
        g_se = np.sqrt(img_a.var(ddof=1) / ka)
        dof = ka - 1
    se = np.sqrt(var_a + var_b + (rel_floor * np.maximum(np.abs(mean_a), np.abs(mean_b))) ** 2)
    diff = mean_a - mean_b
    # Where both sides have zero variance the values must agree exactly (up to float rounding).
    exact = se == 0
    agree = np.abs(diff) <= 1e-6 * (1 + np.abs(mean_b))
    z = np.where(exact, np.where(agree, 0.0, np.inf), diff / np.where(exact, 1, se))
    tested = np.ones(z.shape, dtype=bool)
    if min_nonzero_b and runs_b is not None:
        # Values both sides left at zero in every run agree exactly and stay in.
        hits_b = np.count_nonzero(b, axis=0)
        tested = (hits_b >= min_nonzero_b) | ((hits_b == 0) & (np.count_nonzero(a, axis=0) == 0))
    n = int(np.count_nonzero(tested))
    if n == 0:  # nothing left to test per pixel: fail, rather than pass vacuously
        return ZTest(0.0, float("inf"), float("inf"), float("inf"), t_quantile(GLOBAL_P / 2, dof), z.size)
    thr = sidak_threshold(n)
    frac = float(np.mean(np.abs(z[tested]) <= thr))
    g_se = np.sqrt(g_se**2 + (rel_floor * abs(mean_b.mean())) ** 2)
    global_z = float(g_diff / g_se) if g_se > 0 else (0.0 if abs(g_diff) < 1e-9 else float("inf"))
    weight = np.abs(mean_a) + np.abs(mean_b)
    share = float(weight[~tested].sum() / weight.sum()) if weight.sum() > 0 else 0.0
    return ZTest(frac, float(np.max(np.abs(z[tested]))), global_z, thr, t_quantile(GLOBAL_P / 2, dof), z.size - n,
                 share)
