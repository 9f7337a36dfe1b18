/* metrics.c — MAPE, RMSE, relMSE and non-finite pixel counts (contracts in metrics.h).
 * Two passes over the pixels: the first finds ref_mean (MAPE's denominator needs it), the
 * second accumulates the errors. Must not allocate or print.
 * Refs: [ReSTIR BDPT footnote 3] (MAPE definition). */
#include "image/metrics.h"

#include <float.h>
#include <math.h>
#include <stdio.h>

static bool metrics_pixel_finite(struct vec3 p)
{
    return isfinite(p.x) && isfinite(p.y) && isfinite(p.z);
}

/* One pixel's MAPE terms summed over R, G, B: |I - R| / (max(R, 0) + offset) per channel, offset
 * being METRICS_MAPE_MEAN_FRACTION * ref_mean (> 0 whenever MAPE is defined). The error image and
 * MAPE share it, so a pixel's error there is exactly its share of MAPE. A negative R is no
 * radiance: taken as is it could bring the denominator to 0 or below and a term to +-huge; as 0
 * every term stays >= 0 and finite. */
static double metrics_abs_rel_sum(struct vec3 a, struct vec3 b, double offset)
{
    double sum = 0.0;
    for (int c = 0; c < 3; c++) {
        double vr = vec3_comp(b, c);
        sum += fabs(vec3_comp(a, c) - vr) / (fmax(vr, 0.0) + offset);
    }
    return sum;
}

static bool metrics_pixel_has_nan(struct vec3 p) { return isnan(p.x) || isnan(p.y) || isnan(p.z); }
static bool metrics_pixel_has_inf(struct vec3 p) { return isinf(p.x) || isinf(p.y) || isinf(p.z); }

bool metrics_compare(const struct image *image, const struct image *ref, struct metrics *out,
                     struct err *err)
{
    if (!image || !ref || !out) return err_set(err, ERR_INVALID, NULL, "metrics need two images");
    if (!image->pixels || !ref->pixels || image->width == 0 || image->height == 0)
        return err_set(err, ERR_INVALID, NULL, "metrics need non-empty images");
    if (image->width != ref->width || image->height != ref->height)
        return err_set(err, ERR_INVALID, NULL, "image is %ux%u but reference is %ux%u",
                       image->width, image->height, ref->width, ref->height);

    struct metrics m = {.width = image->width, .height = image->height};
    const size_t w = image->width;
    /* Sums are formed per row, then rows are added: with up to 64 Mi pixels a single running
     * sum would lose ~n*eps relative accuracy, per-row partials keep it near (w + h)*eps. */
    double ref_sum[3] = {0, 0, 0}, image_sum[3] = {0, 0, 0};
    for (size_t y = 0; y < image->height; y++) {
        double row_ref[3] = {0, 0, 0}, row_image[3] = {0, 0, 0};
        for (size_t i = y * w; i < (y + 1) * w; i++) {
            struct vec3 a = image->pixels[i], b = ref->pixels[i];
            m.nan_image += metrics_pixel_has_nan(a);
            m.inf_image += metrics_pixel_has_inf(a);
            m.nan_ref += metrics_pixel_has_nan(b);
            m.inf_ref += metrics_pixel_has_inf(b);
            m.nonfinite_image += !metrics_pixel_finite(a);
            m.nonfinite_ref += !metrics_pixel_finite(b);
            if (!metrics_pixel_finite(a) || !metrics_pixel_finite(b)) continue;
            m.pixels_used++;
            for (int c = 0; c < 3; c++) {
                row_ref[c] += vec3_comp(b, c);
                row_image[c] += vec3_comp(a, c);
            }
        }
        for (int c = 0; c < 3; c++) {
            ref_sum[c] += row_ref[c];
            image_sum[c] += row_image[c];
        }
    }
    m.samples = 3 * m.pixels_used;
    if (m.samples == 0) {
        m.mape = m.rmse = m.relmse = m.ref_mean = m.mean_rel_diff_max = NAN;
        for (int c = 0; c < 3; c++) m.mean_image[c] = m.mean_ref[c] = m.mean_rel_diff[c] = NAN;
        *out = m;
        return true;
    }
    m.ref_mean = (ref_sum[0] + ref_sum[1] + ref_sum[2]) / (double)m.samples;
    for (int c = 0; c < 3; c++) {
        m.mean_image[c] = image_sum[c] / (double)m.pixels_used;
        m.mean_ref[c] = ref_sum[c] / (double)m.pixels_used;
        double d = m.mean_image[c] == m.mean_ref[c] ? 0.0 : fabs(m.mean_image[c] / m.mean_ref[c] - 1.0);
        m.mean_rel_diff[c] = d;
        m.mean_rel_diff_max = c == 0 || d > m.mean_rel_diff_max ? d : m.mean_rel_diff_max;
    }

    const double mape_offset = METRICS_MAPE_MEAN_FRACTION * m.ref_mean;
    double abs_rel = 0.0, sq = 0.0, rel_sq = 0.0;
    for (size_t y = 0; y < image->height; y++) {
        double row_abs_rel = 0.0, row_sq = 0.0, row_rel_sq = 0.0;
        for (size_t i = y * w; i < (y + 1) * w; i++) {
            struct vec3 a = image->pixels[i], b = ref->pixels[i];
            if (!metrics_pixel_finite(a) || !metrics_pixel_finite(b)) continue;
            row_abs_rel += metrics_abs_rel_sum(a, b, mape_offset);
            for (int c = 0; c < 3; c++) {
                double va = vec3_comp(a, c), vr = vec3_comp(b, c);
                double d = va - vr;
                row_sq += d * d;
                row_rel_sq += d * d / (vr * vr + METRICS_RELMSE_EPS);
            }
        }
        abs_rel += row_abs_rel;
        sq += row_sq;
        rel_sq += row_rel_sq;
    }
    const double ns = (double)m.samples;
    m.mape = m.ref_mean > 0.0 ? abs_rel / ns : NAN;
    m.rmse = sqrt(sq / ns);
    m.relmse = rel_sq / ns;
    *out = m;
    return true;
}

bool metrics_error_image(const struct image *image, const struct image *ref, const struct metrics *m,
                         struct image *out, struct err *err)
{
    if (!image || !ref || !m || !out || !image->pixels || !ref->pixels || !out->pixels)
        return err_set(err, ERR_INVALID, NULL, "the error image needs two images, their metrics and an output");
    if (image->width != ref->width || image->height != ref->height || out->width != image->width ||
        out->height != image->height)
        return err_set(err, ERR_INVALID, NULL, "image is %ux%u, reference %ux%u, error image %ux%u", image->width,
                       image->height, ref->width, ref->height, out->width, out->height);
    const double offset = METRICS_MAPE_MEAN_FRACTION * m->ref_mean;
    const bool defined = m->ref_mean > 0.0;
    const size_t n = (size_t)image->width * image->height;
    for (size_t i = 0; i < n; i++) {
        struct vec3 a = image->pixels[i], b = ref->pixels[i];
        float e = NAN;
        /* A finite pair's error stays finite (at most FLT_MAX, for a tiny ref_mean): +Inf is kept
         * for an image pixel that is not finite. */
        if (defined && metrics_pixel_finite(b))
            e = metrics_pixel_finite(a) ? (float)fmin(metrics_abs_rel_sum(a, b, offset) / 3.0, FLT_MAX) : INFINITY;
        out->pixels[i] = (struct vec3){e, e, e};
    }
    return true;
}

double metrics_fraction_above(const struct image *errors, double threshold)
{
    uint64_t counted = 0, above = 0;
    const size_t n = (size_t)errors->width * errors->height;
    for (size_t i = 0; i < n; i++) {
        double e = errors->pixels[i].x;
        if (isnan(e)) continue; /* +Inf (a non-finite image pixel) is above any threshold */
        counted++;
        above += e > threshold;
    }
    return counted ? (double)above / (double)counted : NAN;
}

/* Appends a JSON number or null; JSON has no NaN/Infinity literals. */
static int metrics_json_number(char *buf, size_t size, double v)
{
    return isfinite(v) ? snprintf(buf, size, "%.9g", v) : snprintf(buf, size, "null");
}

bool metrics_format_json(const struct metrics *m, char *buf, size_t size, struct err *err)
{
    if (!m || !buf || size == 0) return err_set(err, ERR_INVALID, NULL, "no metrics or buffer");
    size_t used = 0;
    int r;
#define METRICS_PUT(expr)                                                       \
    do {                                                                        \
        r = (expr);                                                             \
        if (r < 0 || (size_t)r >= size - used)                                  \
            return err_set(err, ERR_LIMIT, NULL, "metrics JSON needs more than %zu bytes", size); \
        used += (size_t)r;                                                      \
    } while (0)
    METRICS_PUT(snprintf(buf + used, size - used,
                         "{\"width\":%u,\"height\":%u,\"pixels_used\":%llu,\"samples\":%llu,\"mape\":",
                         m->width, m->height, (unsigned long long)m->pixels_used,
                         (unsigned long long)m->samples));
    METRICS_PUT(metrics_json_number(buf + used, size - used, m->mape));
    METRICS_PUT(snprintf(buf + used, size - used, ",\"rmse\":"));
    METRICS_PUT(metrics_json_number(buf + used, size - used, m->rmse));
    METRICS_PUT(snprintf(buf + used, size - used, ",\"relmse\":"));
    METRICS_PUT(metrics_json_number(buf + used, size - used, m->relmse));
    METRICS_PUT(snprintf(buf + used, size - used, ",\"ref_mean\":"));
    METRICS_PUT(metrics_json_number(buf + used, size - used, m->ref_mean));
    METRICS_PUT(snprintf(buf + used, size - used,
                         ",\"nan\":{\"a\":%llu,\"b\":%llu},\"inf\":{\"a\":%llu,\"b\":%llu},"
                         "\"nonfinite\":{\"a\":%llu,\"b\":%llu}",
                         (unsigned long long)m->nan_image, (unsigned long long)m->nan_ref,
                         (unsigned long long)m->inf_image, (unsigned long long)m->inf_ref,
                         (unsigned long long)m->nonfinite_image, (unsigned long long)m->nonfinite_ref));
    /* The two means, then their relative differences: three arrays of three numbers. */
    const double *const arrays[3] = {m->mean_image, m->mean_ref, m->mean_rel_diff};
    static const char *const before[3] = {",\"mean\":{\"a\":[", "],\"b\":[", "]},\"mean_rel_diff\":["};
    for (int k = 0; k < 3; k++) {
        METRICS_PUT(snprintf(buf + used, size - used, "%s", before[k]));
        for (int c = 0; c < 3; c++) {
            if (c) METRICS_PUT(snprintf(buf + used, size - used, ","));
            METRICS_PUT(metrics_json_number(buf + used, size - used, arrays[k][c]));
        }
    }
    METRICS_PUT(snprintf(buf + used, size - used, "],\"mean_rel_diff_max\":"));
    METRICS_PUT(metrics_json_number(buf + used, size - used, m->mean_rel_diff_max));
    METRICS_PUT(snprintf(buf + used, size - used, "}"));
#undef METRICS_PUT
    return true;
}

uint64_t metrics_image_mean(const struct image *img, double mean[3])
{
    double s[3] = {0, 0, 0};
    size_t n = (size_t)img->width * img->height, used = 0;
    for (size_t i = 0; i < n; i++) {
        struct vec3 p = img->pixels[i];
        if (!vec3_is_finite(p)) continue;
        s[0] += p.x;
        s[1] += p.y;
        s[2] += p.z;
        used++;
    }
    for (int c = 0; c < 3; c++) mean[c] = used ? s[c] / (double)used : 0.0;
    return n - used;
}
