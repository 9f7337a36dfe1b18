"""bench/region_errors.py, which splits an image's error between a masked region and the rest, on
made-up images whose answers are known: the whole image's figures are errors.metrics' (which
`restir compare` agrees with, tests/test_reference_error.py), MAPE and relMSE are the
pixel-weighted mix of the two parts, an image exact inside scores its whole-image figure as the
floor, and a non-finite pixel is left out as metrics() leaves it out."""
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import errors  # noqa: E402
import region_errors  # noqa: E402


def images(seed=3):
    rng = np.random.default_rng(seed)
    ref = rng.uniform(0.05, 2.0, (24, 32, 3))
    img = ref * rng.lognormal(0.0, 0.4, ref.shape)
    mask = np.zeros((24, 32), dtype=bool)
    mask[4:14, 6:20] = True
    return img, ref, mask


def test_whole_image_is_metrics_and_the_parts_mix():
    img, ref, mask = images()
    fig = region_errors.region_figures(img, ref, mask)
    whole = errors.metrics(img, ref)
    share = mask.mean()
    for key in ("mape", "relmse", "rmse"):
        assert fig[key]["all"] == pytest.approx(whole[key], rel=1e-12)
    for key in ("mape", "relmse"):
        mix = share * fig[key]["inside"] + (1 - share) * fig[key]["outside"]
        assert fig[key]["all"] == pytest.approx(mix, rel=1e-12)
    rmse = fig["rmse"]
    assert rmse["all"] ** 2 == pytest.approx(share * rmse["inside"] ** 2 + (1 - share) * rmse["outside"] ** 2, rel=1e-12)


def test_exact_inside_scores_the_floor():
    img, ref, mask = images()
    exact_inside = np.where(mask[..., None], ref, img)
    floor = region_errors.region_figures(img, ref, mask)
    exact = region_errors.region_figures(exact_inside, ref, mask)
    for key in ("mape", "relmse", "rmse"):
        assert exact[key]["inside"] == 0.0
        assert exact[key]["all"] == pytest.approx(floor[key]["if_exact_inside"], rel=1e-12)
        assert floor[key]["if_exact_inside"] < floor[key]["all"]


def test_a_non_finite_pixel_is_left_out():
    img, ref, mask = images()
    img[5, 7, 1] = math.nan
    img[20, 30, 0] = math.inf
    fig = region_errors.region_figures(img, ref, mask)
    whole = errors.metrics(img, ref)
    for key in ("mape", "relmse", "rmse"):
        assert math.isfinite(fig[key]["inside"]) and math.isfinite(fig[key]["outside"])
        assert fig[key]["all"] == pytest.approx(whole[key], rel=1e-12)
