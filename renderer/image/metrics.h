/* metrics.h — image error metrics against a reference: MAPE, RMSE, relMSE, non-finite counts.
 * Pure functions over two `struct image`s; no I/O, no allocation, no global state.
 * Must not let a NaN/Inf pixel poison a sum: such pixels are counted and left out.
 * Refs: MAPE as in [ReSTIR BDPT footnote 3]; relMSE as in Rousselle et al. 2011 /
 * common denoising practice. */
#ifndef RESTIRD_METRICS_H
#define RESTIRD_METRICS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "core/err.h"
#include "image/image.h"

/* relMSE denominator offset: (I - I_ref)^2 / (I_ref^2 + METRICS_RELMSE_EPS). 1e-2 is the usual
 * choice: it keeps near-black reference pixels from dominating without hiding errors on
 * pixels of ordinary brightness (~0.1 and up). */
#define METRICS_RELMSE_EPS 1e-2
/* MAPE denominator: I_ref + METRICS_MAPE_MEAN_FRACTION * mean(I_ref) ([ReSTIR BDPT footnote 3]). */
#define METRICS_MAPE_MEAN_FRACTION 0.01

/* All sums run over "used" pixels: pixels whose three channels are finite in BOTH images.
 * Each used pixel contributes three samples (R, G, B); every mean is over those samples.
 *   mape     = mean |I - R| / (max(R, 0) + 0.01 * ref_mean)
 *   rmse     = sqrt(mean (I - R)^2)
 *   relmse   = mean (I - R)^2 / (R^2 + METRICS_RELMSE_EPS)
 *   ref_mean = mean R  (the reference mean used by MAPE, over used samples only)
 *   mean_image[c], mean_ref[c] = per-channel means of I and R over the used pixels
 *   mean_rel_diff[c] = |mean_image[c] / mean_ref[c] - 1|  (0 when both means are 0, +Inf when
 *              only the reference's is), and mean_rel_diff_max the largest of the three: a
 *              bias of the whole image, which per-pixel noise hides from the metrics above but
 *              the means average away
 * With no used pixels every metric is NaN. MAPE is NaN when ref_mean <= 0 (an all-black or
 * negative reference leaves the paper's formula undefined). A negative reference sample (no
 * radiance image has one) counts as 0 in MAPE's denominator, so every term is >= 0 and finite;
 * it still counts as itself in |I - R| and in ref_mean. */
struct metrics {
    uint32_t width, height;
    uint64_t pixels_used;          /* pixels in the sums */
    uint64_t samples;              /* 3 * pixels_used */
    double mape, rmse, relmse, ref_mean;
    double mean_image[3], mean_ref[3], mean_rel_diff[3], mean_rel_diff_max;
    uint64_t nan_image, nan_ref;   /* pixels with at least one NaN channel */
    uint64_t inf_image, inf_ref;   /* pixels with at least one +-Inf channel */
    uint64_t nonfinite_image, nonfinite_ref; /* pixels with a NaN or +-Inf channel, each once */
};

/* Compares `image` against `ref`. Sizes must match (ERR_INVALID naming both sizes otherwise);
 * a NULL or empty image is ERR_INVALID. Accumulates in double. */
bool metrics_compare(const struct image *image, const struct image *ref, struct metrics *out,
                     struct err *err);

/* Each pixel's relative error as MAPE counts it: the mean over R, G, B of
 *   |I - R| / (max(R, 0) + METRICS_MAPE_MEAN_FRACTION * m->ref_mean),
 * so the mean of the error image over the used pixels is m->mape. `m` is metrics_compare's
 * answer for the same pair. Pixels left out of the sums: one with a non-finite channel in the
 * image (and a finite reference) is +Inf, an error without bound; one with a non-finite
 * reference channel is NaN, nothing to compare it with; and every pixel is NaN when MAPE is
 * (ref_mean <= 0). The three channels of `out` (the images' size, allocated by the caller)
 * hold the same value. ERR_INVALID when a size differs. */
bool metrics_error_image(const struct image *image, const struct image *ref, const struct metrics *m,
                         struct image *out, struct err *err);

/* The fraction of an error image's pixels (metrics_error_image) whose error is above
 * `threshold`, over the pixels that are not NaN: a +Inf pixel (a non-finite image pixel) is
 * counted and above any threshold. NaN when every pixel is NaN. */
double metrics_fraction_above(const struct image *errors, double threshold);

/* Per-channel mean over the image's finite pixels, accumulated in double; returns how many
 * pixels were left out because a channel was NaN or Inf. An empty image gives means of 0. */
uint64_t metrics_image_mean(const struct image *img, double mean[3]);

/* One JSON object, no newline, numbers as %.9g and non-finite values as null:
 *   {"width":W,"height":H,"pixels_used":N,"samples":S,"mape":x,"rmse":x,"relmse":x,
 *    "ref_mean":x,"nan":{"a":n,"b":n},"inf":{"a":n,"b":n},"nonfinite":{"a":n,"b":n},
 *    "mean":{"a":[r,g,b],"b":[r,g,b]},"mean_rel_diff":[r,g,b],"mean_rel_diff_max":x}
 * where "a" is the image and "b" the reference. Fits in METRICS_JSON_MAX bytes; false with
 * ERR_LIMIT if `size` is too small (buf then holds a truncated, unusable string). */
#define METRICS_JSON_MAX 1024
bool metrics_format_json(const struct metrics *m, char *buf, size_t size, struct err *err);

#endif
