"""The z-test of tests/stats.py on synthetic runs whose truth is known: it passes equal means,
fails a bias, and leaves out of the per-pixel part exactly the values a reference never resolved
(min_nonzero_b), without passing a bias or passing when nothing is left to test; and the
confirming run of a rejected comparison (conftest.pytest_pyfunc_call) on independent seeds."""
import numpy as np
import pytest

import conftest
from stats import NullRejected, assert_agree, ztest_runs

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


class _Item:
    """The parts of a pytest item that conftest.pytest_pyfunc_call reads."""

    class _Info:
        def __init__(self, argnames):
            self.argnames = argnames

    def __init__(self, fn, **funcargs):
        self.obj, self.funcargs, self.nodeid = fn, funcargs, fn.__name__
        self._fixtureinfo = self._Info(tuple(funcargs))


def test_a_rejection_is_confirmed_on_independent_seeds(tmp_path):
    """A comparison that rejects once is run again with every render seed shifted, in a folder of
    its own, and the test passes only if that run agrees; two rejections, or any other failure,
    fail it."""
    rng = np.random.default_rng(4)
    agree, differ = ztest_runs(_runs(rng, KA), _runs(rng, KB)), ztest_runs(_runs(rng, KA, 1.05), _runs(rng, KB))
    assert agree.passed and not differ.passed
    offsets = []

    folders = []

    def unlucky_once(tmp_path):
        offsets.append(conftest.seed_offset())
        folders.append(tmp_path)
        assert not (tmp_path / "made").exists()  # what the first run made is not in the way
        (tmp_path / "made").mkdir()
        assert_agree(differ if conftest.seed_offset() == 0 else agree, "first draw")

    assert conftest.pytest_pyfunc_call(_Item(unlucky_once, tmp_path=tmp_path)) is True
    assert offsets == [0, conftest.CONFIRM_SEED_OFFSET] and conftest.seed_offset() == 0
    assert folders[0] == tmp_path and folders[1] != tmp_path

    def biased():
        assert_agree(differ, "biased")

    with pytest.raises(NullRejected, match="two independent sets"):
        conftest.pytest_pyfunc_call(_Item(biased))
    assert conftest.seed_offset() == 0
    offsets.clear()

    def control_accepted():
        offsets.append(conftest.seed_offset())
        assert not agree.passed, "a bias went unseen"

    with pytest.raises(AssertionError, match="went unseen") as failure:
        conftest.pytest_pyfunc_call(_Item(control_accepted))
    assert not isinstance(failure.value, NullRejected) and offsets == [0]


def test_a_confirming_run_renders_other_seeds(tmp_path, scenes):
    """render() shifts its seed by the offset of a confirming run: seed s then renders what seed
    s + CONFIRM_SEED_OFFSET renders otherwise."""
    sc = scenes / "cornell-box" / "scene.json"
    plain, _ = conftest.render(sc, tmp_path / "a.exr", spp=1, size="8x8", seed=3 + conftest.CONFIRM_SEED_OFFSET)
    first, _ = conftest.render(sc, tmp_path / "b.exr", spp=1, size="8x8", seed=3)
    conftest._seed_offset = conftest.CONFIRM_SEED_OFFSET
    try:
        shifted, _ = conftest.render(sc, tmp_path / "c.exr", spp=1, size="8x8", seed=3)
    finally:
        conftest._seed_offset = 0
    assert np.array_equal(shifted, plain) and not np.array_equal(shifted, first)
