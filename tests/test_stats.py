"""The z-test of tests/stats.py on synthetic runs whose truth is known: it passes equal means,
fails a bias, and leaves out of the per-pixel part exactly the values a reference never resolved
(min_nonzero_b), without passing a bias or passing when nothing is left to test."""
import numpy as np

from stats import ztest_runs

H, W, C = 16, 16, 3
KA, KB = 16, 32


def _runs(rng, k, scale=1.0):
    return scale * rng.normal(1.0, 0.1, size=(k, H, W, C))


def test_equal_means_pass_and_a_bias_fails():
    rng = np.random.default_rng(1)
    a, b = _runs(rng, KA), _runs(rng, KB)
    assert ztest_runs(a, b).passed
    assert not ztest_runs(a * 1.05, b).passed


def test_values_the_reference_never_met_are_left_out():
    rng = np.random.default_rng(2)
    a, b = _runs(rng, KA), _runs(rng, KB)
    # Dim values (a caustic's edge) that the reference met in no run, so its sample variance
    # there is 0, or in two; the method's runs see them, as a correct estimator would.
    a[:, 0, :10, 0] = rng.normal(0.003, 0.001, size=(KA, 10))
    b[:, 0, :10, 0] = 0.0
    a[:, 1, :5, 1] = rng.normal(0.003, 0.001, size=(KA, 5))
    b[:, 1, :5, 1] = 0.0
    b[:2, 1, :5, 1] = 0.024  # two hits in 32 runs: the same mean, 0.003
    a[:, 2, :7, 2] = b[:, 2, :7, 2] = 0.0  # no caustic here: both zero, tested and agreeing
    plain = ztest_runs(a, b)
    assert not plain.passed and plain.worst_z > 10
    res = ztest_runs(a, b, min_nonzero_b=3)
    assert res.untested == 15 and res.passed, res
    # Leaving them out hides no bias elsewhere.
    assert not ztest_runs(a * 1.05, b, min_nonzero_b=3).passed


def test_nothing_left_to_test_fails():
    rng = np.random.default_rng(3)
    a = _runs(rng, KA)
    res = ztest_runs(a, np.zeros((KB, H, W, C)), min_nonzero_b=1)
    assert res.untested == H * W * C and not res.passed
