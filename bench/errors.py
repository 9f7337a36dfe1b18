"""bench/errors.py — the error of an image against a reference, and the error of the reference
itself, for the report (bench/report.py) and its unit test (tests/test_reference_error.py).

The metrics are those of `restir compare` (renderer/image/metrics.c), computed here in numpy so
that hundreds of images can be scored again whenever their reference gets longer; the test checks
that the two agree.

A reference's own error. A reference R is rendered as two independent halves A and B (same
method, same sample count, different seeds) and R = (A + B) / 2. Per pixel, with T the true
value and a = A - T, b = B - T independent and identically distributed with a symmetric
distribution (the mean of many samples is close to normal), a + b and a - b have the same
distribution; so R - T = (a + b) / 2 is distributed as (a - b) / 2 = A - R. Any metric of A against R is therefore an estimate of the same metric of R against the
truth: the reference's own error. (MAPE and relMSE divide by the reference, which here is R
where the truth would be T; while a half's relative noise per pixel is small that changes
little: at 10 % the estimate is within 2 % of the actual error, at 20 % relMSE reads 4 % high.)
That is "half against half, scaled to the full reference" with the scale built in (MAPE and
RMSE scale with |A - B| / 2, relMSE with its square). Two things break it, and the test shows
each would be caught: halves that share random numbers (A - R then underestimates R's error) and
scoring a half against the other half (twice the MAPE and RMSE, four times the relMSE).

How a row's error relates to it: for independent image X and reference, the expected squared
error against R is that against T plus R's own (E[(X-R)^2] = E[(X-T)^2] + E[(R-T)^2]); a row
whose measured error is less than NOISE_FACTOR times the reference's own error cannot be told
from a better one by this reference."""
import math

import numpy as np

# renderer/image/metrics.h: METRICS_MAPE_MEAN_FRACTION and METRICS_RELMSE_EPS.
MAPE_MEAN_FRACTION = 0.01
RELMSE_EPS = 1e-2
# A row measured at less than this multiple of the reference's own error is "within reference
# noise" and is not ranked against another row. The factor is for the metrics in the image's
# units (MAPE, RMSE); relMSE is a squared error, so its factor is the square: a row's measured
# squared error is its own plus the reference's (module text), and RMSE < 3 x own is the same
# statement as MSE < 9 x own's.
NOISE_FACTOR = 3.0
# A reference is long enough when, in every metric, its own error is at most the best row's over
# this divisor (squared for relMSE, as above).
REFERENCE_DIVISOR = 3.0 ** 0.5
SQUARED = {"relmse"}
KEYS = ("mape", "rmse", "relmse")


def pixel_terms(img, ref):
    """Each pixel's share of metrics(img, ref): per pixel the mean over RGB of MAPE's, relMSE's
    and the squared error's terms ("mape", "relmse", "sq"), and the mask of the pixels scored
    ("ok": no non-finite channel in either image; the terms are 0 elsewhere). metrics() is the
    mean of each over the scored pixels (RMSE its square root), so a region's share of an
    image's error is the sum of its pixels' terms. None when no pixel is scored."""
    a = np.asarray(img, dtype=np.float64)[..., :3]
    r = np.asarray(ref, dtype=np.float64)[..., :3]
    if a.shape != r.shape:
        raise ValueError(f"image is {a.shape[1]}x{a.shape[0]} but reference is {r.shape[1]}x{r.shape[0]}")
    ok = np.isfinite(a).all(axis=-1) & np.isfinite(r).all(axis=-1)
    if not ok.any():
        return None
    a, r = np.where(ok[..., None], a, 0.0), np.where(ok[..., None], r, 0.0)
    mean = float(r[ok].mean())
    d = a - r
    sq = d * d
    mape = np.abs(d) / (r + MAPE_MEAN_FRACTION * mean) if mean > 0 else np.full_like(d, math.nan)
    return {"mape": np.where(ok, mape.mean(-1), 0.0), "relmse": (sq / (r * r + RELMSE_EPS)).mean(-1),
            "sq": sq.mean(-1), "ok": ok}


def metrics(img, ref):
    """MAPE, RMSE and relMSE of img against ref (H x W x >=3 arrays; RGB used), as
    metrics_compare() computes them: pixels with a non-finite channel in either image are left
    out; MAPE's denominator is the reference plus 1 % of its mean; relMSE's adds RELMSE_EPS to
    the reference squared."""
    t = pixel_terms(img, ref)
    if t is None:
        return {k: math.nan for k in KEYS}
    ok = t["ok"]
    return {"mape": float(t["mape"][ok].mean()), "rmse": float(math.sqrt(t["sq"][ok].mean())),
            "relmse": float(t["relmse"][ok].mean())}


# renderer/core/vec.h: vec3_luminance, the reuse methods' target.
LUMINANCE = (0.2126, 0.7152, 0.0722)


def colour_exact(img, ref):
    """img with each pixel's colour replaced by the reference's at the pixel's own luminance:
    ref * lum(img) / lum(ref) (pixels whose reference is black, or with a non-finite channel,
    keep img's value). Its metrics() are what img's error would be were only its luminance
    wrong; the rest of img's error is colour. A reuse method that selects one path per pixel by
    luminance gives each pixel one path's colour, which averaging fewer paths leaves noisier
    than pt's sum of all of them (docs/benchmarks.md, "restir_pt in real time: each pixel shows one
    path's colour")."""
    a = np.asarray(img, dtype=np.float64)[..., :3]
    r = np.asarray(ref, dtype=np.float64)[..., :3]
    w = np.asarray(LUMINANCE)
    la, lr = (a * w).sum(-1), (r * w).sum(-1)
    keep = ~(lr > 0) | ~np.isfinite(la) | ~np.isfinite(lr)
    scale = np.where(keep, 0.0, la / np.where(keep, 1.0, lr))
    return np.where(keep[..., None], a, r * scale[..., None])


def combine(half_a, half_b):
    """The full reference of two halves rendered with the same number of samples."""
    return (np.asarray(half_a, dtype=np.float64) + np.asarray(half_b, dtype=np.float64)) / 2.0


def reference_error(half_a, half_b):
    """The estimated MAPE, RMSE and relMSE of combine(half_a, half_b) against the truth: a half
    against the full reference (the module's text says why that is the scale)."""
    return metrics(half_a, combine(half_a, half_b))


def factor(key, f):
    """A factor for the linear metrics, applied to `key`: squared for a squared metric."""
    return f * f if key in SQUARED else f


def within_noise(row, own):
    """Per metric: is the row's error (dict) below NOISE_FACTOR times the reference's own?"""
    return {k: bool(row[k] < factor(k, NOISE_FACTOR) * own[k]) for k in KEYS if k in row and k in own}


def long_enough(own, best):
    """Is the reference's own error, in every metric, at most the best row's (dict of the
    lowest row value per metric) over REFERENCE_DIVISOR?"""
    return all(own[k] * factor(k, REFERENCE_DIVISOR) <= best[k] for k in KEYS)
