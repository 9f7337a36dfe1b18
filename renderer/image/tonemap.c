/* tonemap.c — 8-bit previews of float images and error false-colour maps, encoded as PNG
 * (see tonemap.h for contracts). Owns the PNG writer: signature, IHDR, IDAT chunks holding one
 * zlib stream (through deflate.h), IEND, each chunk with its CRC-32. Must not print, exit or
 * keep state between calls; single-threaded per call (the server's render gate owns the cores).
 * Refs: PNG specification (ISO/IEC 15948, W3C 2nd ed.) §5 chunks, §9 filters, §12.8 filter
 * heuristic; IEC 61966-2-1 (sRGB transfer function); Reinhard et al. 2002 (x / (1 + x));
 * Narkowicz 2016, "ACES Filmic Tone Mapping Curve" (the rational fit of the ACES RRT + ODT). */
#include "image/tonemap.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "image/deflate.h"
#include "image/metrics.h"

/* Image sides accepted, as image_init allows: keeps every size computation far from
 * overflow and the raw PNG data (< 805 MB) addressable. */
#define TONEMAP_MAX_SIDE 16384u
/* zlib level of the PNG stream. Previews are interactive: on Cornell-box frames level 1 gave
 * the smallest file of levels 1..9 at 16 spp and was within 6 % of level 9 at 256 spp, in
 * half of level 9's encode time. */
#define TONEMAP_PNG_LEVEL 1
/* IDAT payload limit: PNG allows 2^31 - 1, but moderate chunks keep streaming decoders'
 * buffering small and exercise the multi-chunk path on ordinary images. */
#define TONEMAP_IDAT_MAX (1u << 20)
/* Exposed values are clipped here before a curve: every curve is 1 (to 8 bits) long before,
 * and it keeps x/(1+x) and the ACES rational finite for a huge exposure. */
#define TONEMAP_X_MAX 1e9

static const unsigned char tonemap_magenta[3] = {255, 0, 255};

bool tonemap_curve_parse(const char *name, enum tonemap_curve *out)
{
    static const enum tonemap_curve all[] = {TONEMAP_CLAMP, TONEMAP_REINHARD, TONEMAP_ACES};
    if (!name) return false;
    for (size_t i = 0; i < sizeof all / sizeof all[0]; i++) {
        if (strcmp(name, tonemap_curve_name(all[i])) == 0) {
            if (out) *out = all[i];
            return true;
        }
    }
    return false;
}

const char *tonemap_curve_name(enum tonemap_curve curve)
{
    switch (curve) {
    case TONEMAP_CLAMP: return "clamp";
    case TONEMAP_REINHARD: return "reinhard";
    case TONEMAP_ACES: return "aces";
    }
    return NULL;
}

/* ---- PNG writer -------------------------------------------------------------------------- */

static unsigned char *tonemap_put_u32(unsigned char *p, uint32_t v)
{
    p[0] = (unsigned char)(v >> 24);
    p[1] = (unsigned char)(v >> 16);
    p[2] = (unsigned char)(v >> 8);
    p[3] = (unsigned char)v;
    return p + 4;
}

/* One chunk: length, type, data, CRC-32 over type and data (PNG §5.3). Returns the end. */
static unsigned char *tonemap_chunk(unsigned char *p, const char type[4], const unsigned char *data, uint32_t n)
{
    unsigned char *start = tonemap_put_u32(p, n);
    memcpy(start, type, 4);
    if (n) memcpy(start + 4, data, n);
    return tonemap_put_u32(start + 4 + n, deflate_crc32(0, start, 4 + (size_t)n));
}

/* Paeth's predictor (PNG §9.4) from the bytes to the left (a), above (b), above-left (c). */
static unsigned tonemap_paeth(unsigned a, unsigned b, unsigned c)
{
    int p = (int)a + (int)b - (int)c;
    int pa = abs(p - (int)a), pb = abs(p - (int)b), pc = abs(p - (int)c);
    return (pa <= pb && pa <= pc) ? a : (pb <= pc ? b : c);
}

/* The predictor of filter `type` (PNG §9.2): 0 none, 1 sub, 2 up, 3 average, 4 Paeth. */
static unsigned tonemap_predict(int type, unsigned a, unsigned b, unsigned c)
{
    switch (type) {
    case 1: return a;
    case 2: return b;
    case 3: return (a + b) / 2;
    case 4: return tonemap_paeth(a, b, c);
    default: return 0;
    }
}

/* |f| for a filtered byte read as signed. */
static unsigned tonemap_abs8(unsigned f)
{
    f &= 0xffu;
    return f < 128 ? f : 256u - f;
}

/* Filters one row in place: row[0] receives the filter type, row[1..n] hold the unfiltered
 * bytes on entry and the filtered ones on return; `above` is the unfiltered row above (NULL
 * for the first row: zeros). The type is the one whose output has the smallest sum of
 * absolute values read as signed bytes, the heuristic PNG §12.8 recommends (on Cornell-box
 * frames 14 to 25 % smaller streams than type 0 alone). Bytes are rewritten right to left so
 * the left neighbours a predictor reads are still unfiltered. */
static void tonemap_filter_row(unsigned char *row, const unsigned char *above, size_t n)
{
    unsigned char *px = row + 1;
    uint64_t sum[5] = {0, 0, 0, 0, 0};
    for (size_t i = 0; i < n; i++) {
        unsigned x = px[i], a = i >= 3 ? px[i - 3] : 0, b = above ? above[i] : 0;
        unsigned c = (above && i >= 3) ? above[i - 3] : 0;
        sum[0] += tonemap_abs8(x);
        sum[1] += tonemap_abs8(x - a);
        sum[2] += tonemap_abs8(x - b);
        sum[3] += tonemap_abs8(x - (a + b) / 2);
        sum[4] += tonemap_abs8(x - tonemap_paeth(a, b, c));
    }
    int best = 0;
    for (int type = 1; type <= 4; type++)
        if (sum[type] < sum[best]) best = type;
    row[0] = (unsigned char)best;
    if (best == 0) return;
    for (size_t i = n; i-- > 0;) {
        unsigned a = i >= 3 ? px[i - 3] : 0, b = above ? above[i] : 0;
        unsigned c = (above && i >= 3) ? above[i - 3] : 0;
        px[i] = (unsigned char)(px[i] - tonemap_predict(best, a, b, c));
    }
}

/* Writes row y's 3 * width bytes of 8-bit RGB. */
typedef void tonemap_row_fn(const void *ctx, uint32_t y, unsigned char *rgb);

/* Encodes a w x h 8-bit RGB image whose rows come from fill(). Peak memory: the raw filtered
 * data plus the zlib stream, then the stream plus the PNG. */
static bool tonemap_encode(uint32_t w, uint32_t h, tonemap_row_fn *fill, const void *ctx, unsigned char **png,
                           size_t *size, struct err *err)
{
    size_t row_n = 3 * (size_t)w, stride = 1 + row_n, raw_n = stride * h;
    unsigned char *raw = malloc(raw_n);
    if (!raw) return err_set(err, ERR_NOMEM, NULL, "out of memory for a %ux%u preview", w, h);
    for (uint32_t y = 0; y < h; y++) fill(ctx, y, raw + (size_t)y * stride + 1);
    /* Bottom-up, so the row above a filtered row is still unfiltered. */
    for (uint32_t y = h; y-- > 0;)
        tonemap_filter_row(raw + (size_t)y * stride, y ? raw + (size_t)(y - 1) * stride + 1 : NULL, row_n);

    struct deflate *d = deflate_new(TONEMAP_PNG_LEVEL, err);
    if (!d) {
        free(raw);
        return false;
    }
    size_t bound = deflate_zlib_bound(d, raw_n);
    unsigned char *z = malloc(bound);
    size_t zn = z ? deflate_zlib(d, raw, raw_n, z, bound) : 0;
    deflate_free(d);
    free(raw);
    if (!z) return err_set(err, ERR_NOMEM, NULL, "out of memory for a %zu-byte zlib stream", bound);
    if (zn == 0) {
        free(z);
        return err_set(err, ERR_INTERNAL, NULL, "zlib stream exceeded its own bound");
    }

    static const unsigned char signature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    size_t idat_count = (zn + TONEMAP_IDAT_MAX - 1) / TONEMAP_IDAT_MAX;
    size_t total = sizeof signature + (12 + 13) + 12 * idat_count + zn + 12;
    unsigned char *out = malloc(total);
    if (!out) {
        free(z);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for a %zu-byte PNG", total);
    }
    unsigned char ihdr[13];
    tonemap_put_u32(ihdr, w);
    tonemap_put_u32(ihdr + 4, h);
    ihdr[8] = 8;   /* bits per sample */
    ihdr[9] = 2;   /* colour type: RGB */
    ihdr[10] = 0;  /* compression: zlib deflate */
    ihdr[11] = 0;  /* filter method: adaptive, five types */
    ihdr[12] = 0;  /* no interlace */
    unsigned char *p = out;
    memcpy(p, signature, sizeof signature);
    p = tonemap_chunk(p + sizeof signature, "IHDR", ihdr, sizeof ihdr);
    for (size_t off = 0; off < zn; off += TONEMAP_IDAT_MAX) {
        size_t n = zn - off < TONEMAP_IDAT_MAX ? zn - off : TONEMAP_IDAT_MAX;
        p = tonemap_chunk(p, "IDAT", z + off, (uint32_t)n);
    }
    p = tonemap_chunk(p, "IEND", NULL, 0);
    free(z);
    *png = out;
    *size = (size_t)(p - out);
    return true;
}

static bool tonemap_check_image(const struct image *img, const char *what, struct err *err)
{
    if (!img || !img->pixels || img->width == 0 || img->height == 0)
        return err_set(err, ERR_INVALID, NULL, "%s image is missing or empty", what);
    if (img->width > TONEMAP_MAX_SIDE || img->height > TONEMAP_MAX_SIDE)
        return err_set(err, ERR_LIMIT, NULL, "%s image %ux%u is larger than %ux%u", what, img->width, img->height,
                       TONEMAP_MAX_SIDE, TONEMAP_MAX_SIDE);
    return true;
}

/* ---- previews ---------------------------------------------------------------------------- */

/* min for values known not to be NaN: fmin's NaN rules make it a libm call in the pixel loops. */
static inline double tonemap_min(double a, double b) { return a < b ? a : b; }

/* Display value in [0, 1] of an exposed linear value x >= 0. */
static double tonemap_curve_apply(enum tonemap_curve curve, double x)
{
    switch (curve) {
    case TONEMAP_CLAMP: return tonemap_min(x, 1.0);
    case TONEMAP_REINHARD: return x / (1.0 + x);
    case TONEMAP_ACES:
        /* Narkowicz's fit: x (a x + b) / (x (c x + d) + e) with a = 2.51, b = 0.03, c = 2.43,
         * d = 0.59, e = 0.14, applied to the exposed value as is (1 maps to 0.80). It tends
         * to 2.51 / 2.43 > 1, so it is clipped to 1 (from x ~ 10 on). */
        return tonemap_min(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 1.0);
    }
    return x;
}

/* Inverse of the sRGB transfer function (IEC 61966-2-1) on [0, 1]. */
static double tonemap_srgb_inverse(double e)
{
    return e <= 0.04045 ? e / 12.92 : pow((e + 0.055) / 1.055, 2.4);
}

/* The 8-bit code of display value v is round(255 * oetf(v)), that is the number of k in
 * 1..255 with v >= oetf^-1((k - 0.5) / 255). A pow per channel was most of an encode's time;
 * instead, per image, the 255 thresholds and the code at each of TONEMAP_SRGB_BINS + 1 evenly
 * spaced values. Between two such values the code rises by at most one (the OETF's steepest
 * slope, 12.92, times 255 / 4096 is < 1), so one comparison finishes the lookup exactly. */
#define TONEMAP_SRGB_BINS 4096
struct tonemap_srgb_table {
    double thr[257];                          /* thr[k], k = 1..255; thr[256] = +inf */
    unsigned char code[TONEMAP_SRGB_BINS + 1]; /* code at v = i / TONEMAP_SRGB_BINS */
};

static void tonemap_srgb_table_init(struct tonemap_srgb_table *t)
{
    t->thr[0] = -INFINITY;
    for (int k = 1; k < 256; k++) t->thr[k] = tonemap_srgb_inverse((k - 0.5) / 255.0);
    t->thr[256] = INFINITY;
    unsigned k = 0;
    for (int i = 0; i <= TONEMAP_SRGB_BINS; i++) {
        double v = (double)i / TONEMAP_SRGB_BINS;
        while (v >= t->thr[k + 1]) k++;
        t->code[i] = (unsigned char)k;
    }
}

/* v in [0, 1]. */
static unsigned char tonemap_srgb8(const struct tonemap_srgb_table *t, double v)
{
    unsigned k = t->code[(int)(v * TONEMAP_SRGB_BINS)];
    return (unsigned char)(k + (v >= t->thr[k + 1]));
}

struct tonemap_preview {
    const struct image *img;
    double scale;  /* 2^exposure_ev */
    enum tonemap_curve curve;
    struct tonemap_srgb_table srgb;
};

static void tonemap_preview_row(const void *ctx, uint32_t y, unsigned char *rgb)
{
    const struct tonemap_preview *pv = ctx;
    const struct vec3 *px = pv->img->pixels + (size_t)y * pv->img->width;
    for (uint32_t x = 0; x < pv->img->width; x++, rgb += 3) {
        if (!vec3_is_finite(px[x])) {
            memcpy(rgb, tonemap_magenta, 3);
            continue;
        }
        for (int c = 0; c < 3; c++) {
            /* Negative radiance has no display value: black. Exposure in double, so that
             * 0 * 2^ev stays 0 however large ev is. */
            double v = vec3_comp(px[x], c);
            v = v > 0.0 ? tonemap_min(v * pv->scale, TONEMAP_X_MAX) : 0.0;
            rgb[c] = tonemap_srgb8(&pv->srgb, tonemap_curve_apply(pv->curve, v));
        }
    }
}

bool tonemap_png(const struct image *img, const struct tonemap_opts *opts, unsigned char **png, size_t *size,
                 struct err *err)
{
    if (!png || !size) return err_set(err, ERR_INVALID, NULL, "no output buffer pointer");
    *png = NULL;
    *size = 0;
    if (!opts) return err_set(err, ERR_INVALID, NULL, "no tone-mapping options");
    if (!isfinite(opts->exposure_ev))
        return err_set(err, ERR_INVALID, "/exposure_ev", "must be finite, got %g", (double)opts->exposure_ev);
    if (!tonemap_curve_name(opts->curve))
        return err_set(err, ERR_INVALID, "/curve", "unknown curve %d", (int)opts->curve);
    if (!tonemap_check_image(img, "the", err)) return false;
    struct tonemap_preview pv = {img, exp2((double)opts->exposure_ev), opts->curve, {{0}}};
    tonemap_srgb_table_init(&pv.srgb);
    return tonemap_encode(img->width, img->height, tonemap_preview_row, &pv, png, size, err);
}

/* ---- error maps -------------------------------------------------------------------------- */

/* The ramp from zero error to scale_max: anchors in sRGB 8-bit, evenly spaced, interpolated
 * linearly in sRGB. Chosen by us so that CIE L* rises steadily (about 6, 30, 51, 71, 94) and
 * the hue runs dark indigo -> blue -> teal -> green -> pale yellow, never near magenta, which
 * marks non-finite pixels. With lightness monotone the ramp reads correctly in greyscale and
 * for colour-blind viewers (test_tonemap_anim.c checks L* increases along it). */
#define TONEMAP_RAMP_N 5
static const unsigned char tonemap_ramp[TONEMAP_RAMP_N][3] = {
    {12, 14, 48},    /* 0: dark indigo (zero error) */
    {42, 64, 150},   /* 1/4: blue */
    {22, 134, 150},  /* 1/2: teal */
    {104, 194, 88},  /* 3/4: green */
    {252, 240, 134}, /* 1: pale yellow (scale_max and above) */
};

/* The errors are metrics_error_image's (one value per pixel in every channel; .x is read):
 * >= 0 where compared, +Inf or NaN where not. */
struct tonemap_errmap {
    const struct vec3 *err;
    uint32_t width;
    double inv_scale;
};

static void tonemap_error_row(const void *ctx, uint32_t y, unsigned char *rgb)
{
    const struct tonemap_errmap *em = ctx;
    const struct vec3 *e = em->err + (size_t)y * em->width;
    for (uint32_t x = 0; x < em->width; x++, rgb += 3) {
        if (!isfinite(e[x].x)) {
            memcpy(rgb, tonemap_magenta, 3);
            continue;
        }
        double u = tonemap_min((double)e[x].x * em->inv_scale, 1.0) * (TONEMAP_RAMP_N - 1);
        int k = (int)u;
        if (k > TONEMAP_RAMP_N - 2) k = TONEMAP_RAMP_N - 2;
        double f = u - k;
        for (int c = 0; c < 3; c++) {
            double v = tonemap_ramp[k][c] + (tonemap_ramp[k + 1][c] - tonemap_ramp[k][c]) * f;
            rgb[c] = (unsigned char)(v + 0.5);
        }
    }
}

/* One pass of the radix selection: counts, among the finite errors whose bits match `prefix`
 * under `mask`, the digit (bits >> shift) & (bins - 1). Returns the errors counted. */
static uint64_t tonemap_error_histogram(const struct vec3 *err, size_t n, uint32_t mask, uint32_t prefix, int shift,
                                        uint32_t *hist, uint32_t bins)
{
    memset(hist, 0, bins * sizeof *hist);
    uint64_t counted = 0;
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(err[i].x)) continue;
        uint32_t bits;
        memcpy(&bits, &err[i].x, sizeof bits);
        if ((bits & mask) != prefix) continue;
        hist[(bits >> shift) & (bins - 1)]++;
        counted++;
    }
    return counted;
}

/* The digit holding the element of rank *k (0-based); *k becomes its rank within the digit. */
static uint32_t tonemap_select_digit(const uint32_t *hist, uint32_t bins, uint64_t *k)
{
    uint32_t d = 0;
    while (d + 1 < bins && *k >= hist[d]) *k -= hist[d++];
    return d;
}

/* The 99th percentile (nearest rank: the ceil(0.99 m)-th smallest of the m finite errors),
 * 0 when there are none. Exact and O(n) without sorting or reordering: non-negative floats
 * (metrics_error_image's are) order like their bit patterns, so three histogram passes over
 * 11 + 11 + 10 bits pick the value digit by digit. */
static float tonemap_error_p99(const struct vec3 *err, size_t n)
{
    uint32_t hist[2048];
    uint64_t m = tonemap_error_histogram(err, n, 0, 0, 21, hist, 2048);
    if (m == 0) return 0.0f;
    uint64_t k = (99 * m + 99) / 100 - 1;
    uint32_t hi = tonemap_select_digit(hist, 2048, &k);
    tonemap_error_histogram(err, n, 0xffe00000u, hi << 21, 10, hist, 2048);
    uint32_t mid = tonemap_select_digit(hist, 2048, &k);
    uint32_t prefix = hi << 21 | mid << 10;
    tonemap_error_histogram(err, n, 0xfffffc00u, prefix, 0, hist, 1024);
    uint32_t bits = prefix | tonemap_select_digit(hist, 1024, &k);
    float e;
    memcpy(&e, &bits, sizeof e);
    return e;
}

bool tonemap_error_png(const struct image *img, const struct image *ref, float scale_max, float *used_scale,
                       unsigned char **png, size_t *size, struct err *err)
{
    if (!png || !size) return err_set(err, ERR_INVALID, NULL, "no output buffer pointer");
    *png = NULL;
    *size = 0;
    if (!isfinite(scale_max))
        return err_set(err, ERR_INVALID, "/scale_max", "must be finite, got %g", (double)scale_max);
    if (!tonemap_check_image(img, "the", err) || !tonemap_check_image(ref, "the reference", err)) return false;
    if (img->width != ref->width || img->height != ref->height)
        return err_set(err, ERR_INVALID, NULL, "image %ux%u and reference %ux%u differ in size", img->width,
                       img->height, ref->width, ref->height);
    /* The errors are computed once, by metrics_error_image, so the map shows the values MAPE
     * averages and `restir compare --diff` writes; the percentile passes and the colouring
     * read them. */
    struct metrics m = {0};
    struct image e = {0};
    bool ok = metrics_compare(img, ref, &m, err) && image_init(&e, img->width, img->height, err) &&
              metrics_error_image(img, ref, &m, &e, err);
    if (ok) {
        size_t n = (size_t)img->width * img->height;
        float scale = scale_max > 0.0f ? scale_max : fmaxf(tonemap_error_p99(e.pixels, n), 1e-6f);
        if (used_scale) *used_scale = scale;
        struct tonemap_errmap em = {e.pixels, img->width, 1.0 / (double)scale};
        ok = tonemap_encode(img->width, img->height, tonemap_error_row, &em, png, size, err);
    }
    image_destroy(&e);
    return ok;
}
