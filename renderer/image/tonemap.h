/* tonemap.h — 8-bit previews of linear HDR images: exposure, a tone curve, the sRGB transfer
 * function, PNG encoding; and false-colour maps of the error of an image against a reference.
 * Previews are for eyes only: every number the server reports comes from the float images.
 * Thread-safe and stateless; the returned buffer is the only allocation that outlives a call
 * (while it encodes, a call holds scratch of a few bytes per pixel). */
#ifndef RESTIRD_TONEMAP_H
#define RESTIRD_TONEMAP_H

#include <stdbool.h>
#include <stddef.h>

#include "core/err.h"
#include "image/image.h"

enum tonemap_curve {
    TONEMAP_CLAMP,     /* linear, clipped at 1 */
    TONEMAP_REINHARD,  /* x / (1 + x) per channel */
    TONEMAP_ACES,      /* Narkowicz's 2016 rational fit of the ACES filmic curve (1 -> 0.80),
                          clipped at 1 */
};

struct tonemap_opts {
    float exposure_ev;          /* pixel values are multiplied by 2^exposure_ev; finite */
    enum tonemap_curve curve;
};

/* Name <-> enum for the wire ("clamp", "reinhard", "aces"); false/NULL when unknown. */
bool tonemap_curve_parse(const char *name, enum tonemap_curve *out);
const char *tonemap_curve_name(enum tonemap_curve curve);

/* Encodes img as an 8-bit RGB PNG: per channel v * 2^exposure_ev (negative values as 0), the
 * curve, the sRGB transfer function, rounded to 8 bits. A pixel with a NaN or Inf channel is
 * magenta (255, 0, 255). On success *png is malloc'd (caller frees); on failure it is NULL and
 * *size 0. Errors: ERR_INVALID (options, missing or empty image), ERR_LIMIT (a side over
 * 16384), ERR_NOMEM. */
bool tonemap_png(const struct image *img, const struct tonemap_opts *opts, unsigned char **png, size_t *size,
                 struct err *err);

/* False-colour map of each pixel's relative error as metrics_error_image gives it (MAPE's
 * per-pixel term, [ReSTIR BDPT footnote 3]: the mean over the three channels of
 * |img - ref| / (max(ref, 0) + 0.01 * mean(ref)), the mean over the pixels compared), mapped
 * from 0 to `scale_max` through a perceptually ordered colour ramp (lightness rising from dark
 * indigo at 0 through blue, teal and green to pale yellow at scale_max and above; the anchors
 * are listed in tonemap.c); scale_max <= 0 picks the 99th percentile (nearest rank) of the
 * compared pixels' errors, at least 1e-6. *used_scale (may be NULL) returns the scale used (for
 * a legend). A pixel with a non-finite channel in either image is magenta, and so is every
 * pixel when the reference's mean is 0 or below (MAPE undefined). Errors: ERR_INVALID (sizes
 * differ, missing image, non-finite scale_max), ERR_LIMIT (a side over 16384), ERR_NOMEM. */
bool tonemap_error_png(const struct image *img, const struct image *ref, float scale_max, float *used_scale,
                       unsigned char **png, size_t *size, struct err *err);

#endif
