/* test_restir.c — the reuse passes of restir.c on a toy technique whose answer is known.
 * Each pixel p integrates f_p(x) = a_p max(0, sin 2π(x + φ_p)) over x in [0, 1) (exact: a_p / π);
 * the pixels' supports differ, so a neighbour's sample is often worth nothing here and the MIS
 * weights decide the result. The shift is the identity (|J| = 1). Over many independent trials
 * (two frames: initial + temporal + spatial reuse) the per-pixel estimates F(Y) W must be
 * unbiased, paired and unpaired; a shift that lies about its Jacobian must be caught. The frame
 * driver (restir_frame_*) is tested on the same toy: its shade pass's writes and where its
 * spatial rounds leave the history. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "reuse/restir.h"
#include "core/rng.h"
#include "image/image.h"
#include "test.h"

#define W_PX 16u
#define H_PX 12u
#define N_PX (W_PX * H_PX)

struct toy_elem {
    struct restir_head head;
    float x;  /* the sample */
    float f;  /* f_p(x) in the element's own pixel */
    float pad;
};

struct toy_ctx {
    bool wrong_jacobian;  /* the control: x -> x^2 reported with |J| = 1 */
};

static bool toy_valid_pixel(uint32_t p) { return p % 7u != 3u; }

static double toy_f(uint32_t p, double x)
{
    double a = 1.0 + (double)(p % 5u), phase = fmod(0.37 * (double)p, 1.0);
    double s = sin(2.0 * M_PI * (x + phase));
    return s > 0.0 ? a * s : 0.0;
}

static double toy_exact(uint32_t p) { return (1.0 + (double)(p % 5u)) / M_PI; }

static float toy_target(const void *ctx, const void *elem)
{
    (void)ctx;
    return ((const struct toy_elem *)elem)->f;
}

static void toy_shift(const void *ctx, const void *src, struct restir_domain from, struct restir_domain to, void *dst,
                      float *target, float *jacobian, struct restir_counters *c)
{
    (void)from;
    (void)c;
    const struct toy_ctx *t = ctx;
    const struct toy_elem *s = src;
    float y = t->wrong_jacobian ? s->x * s->x : s->x;
    float f = (float)toy_f(to.pixel, y);
    if (dst) {
        struct toy_elem *d = dst;
        *d = *s;
        d->x = y;
        d->f = f;
    }
    *target = f;
    *jacobian = 1.0f;
}

/* A contribution vector whose first component is not proportional to the target f:
 * F = (2 f x, f, f), so selecting one sample adds noise there that its expectation over the
 * selection does not. */
static struct vec3 toy_value(const void *ctx, const void *elem)
{
    (void)ctx;
    const struct toy_elem *e = elem;
    return vec3_make(e->f * 2.0f * e->x, e->f, e->f);
}

/* The integral over x of F's first component (midpoint rule, 20000 steps). */
static double toy_exact_x(uint32_t p)
{
    double sum = 0.0;
    for (int i = 0; i < 20000; i++) {
        double x = (i + 0.5) / 20000.0;
        sum += toy_f(p, x) * 2.0 * x;
    }
    return sum / 20000.0;
}

static bool toy_domain_valid(const void *ctx, struct restir_domain d)
{
    (void)ctx;
    return toy_valid_pixel(d.pixel);
}

static const struct restir_ops toy_ops = {
    .stride = sizeof(struct toy_elem), .target = toy_target, .shift = toy_shift, .domain_valid = toy_domain_valid,
    .value = toy_value};

/* One candidate per pixel, x uniform: W = 1 when f > 0. */
static void toy_initial(struct toy_elem *e, uint64_t seed, uint32_t frame)
{
    for (uint32_t p = 0; p < N_PX; p++) {
        struct rng r = rng_make(seed, frame, p, 0x746f79u);
        float x = rng_next_float(&r);
        float f = toy_valid_pixel(p) ? (float)toy_f(p, x) : 0.0f;
        e[p] = (struct toy_elem){.head = {.W = f > 0.0f ? 1.0f : 0.0f, .M = 1}, .x = x, .f = f};
    }
}

struct toy_stats {
    double sum[N_PX], sum2[N_PX];
    double total_sum, total_sum2;
    uint32_t trials;
    bool first_component;  /* the estimates are of F's first component (toy_exact_x) */
    uint64_t shifts;       /* shifts the passes made, over all trials */
};

/* With depth_rel > 0 the toy's primary hits lie at two depths, the left half of the image at 1 and
 * the right half at 1.5, and the spatial passes reject neighbours across that step
 * (restir_reuse.max_depth_rel). */
static float toy_depth_rel;

/* With a class other than TOY_CLASS_NONE the temporal pass caps the history of that class's samples
 * at 1 rather than 20 (restir_ops.capped_low): x < 0.5, which the toy's shift (x kept) keeps, or,
 * the control, "the element holds a fresh sample" (M = 1), a property of the reservoir rather than
 * of the sample, so the two weights of one sample use different confidences. */
enum toy_class { TOY_CLASS_NONE, TOY_CLASS_X, TOY_CLASS_FRESH };

/* With toy_share each pixel takes a share in [0.05, 1) of its history's confidence
 * (gbuffer_pixel.prev_share, the history check's), fixed per pixel; otherwise all of it. */
static bool toy_share;
static float toy_share_of(uint32_t p)
{
    return toy_share ? 0.05f + 0.95f * (float)((p * 2654435761u) >> 16 & 0xffffu) / 65536.0f : 1.0f;
}
static enum toy_class toy_class;

static bool toy_capped_low(const void *ctx, const void *elem)
{
    (void)ctx;
    const struct toy_elem *e = elem;
    return toy_class == TOY_CLASS_X ? e->x < 0.5f : e->head.M == 1;
}

static const struct restir_ops toy_ops_classes = {
    .stride = sizeof(struct toy_elem), .target = toy_target, .shift = toy_shift, .domain_valid = toy_domain_valid,
    .value = toy_value, .capped_low = toy_capped_low};

/* Runs `trials` independent two-frame sessions and gathers the second frame's estimates: the
 * selected sample's F W, or with `expected` the spatial pass's expected contribution over its
 * selection (restir_reuse.estimate). */
static void toy_run(bool paired, bool wrong_jacobian, bool expected, uint32_t trials, struct toy_stats *st,
                    struct toy_stats *selected_x)
{
    memset(st, 0, sizeof *st);
    st->trials = trials;
    st->first_component = expected;
    if (selected_x) {  /* with `expected`: the selected sample's F.x W beside it */
        memset(selected_x, 0, sizeof *selected_x);
        selected_x->trials = trials;
        selected_x->first_component = true;
    }
    struct toy_ctx ctx = {.wrong_jacobian = wrong_jacobian};
    static struct toy_elem a[N_PX], b[N_PX], hist[N_PX];
    static struct vec3 estimate[N_PX];
    static struct gbuffer_pixel px[N_PX];
    for (uint32_t p = 0; p < N_PX; p++)  /* a static camera: each pixel's predecessor is itself */
        px[p] = (struct gbuffer_pixel){.t = toy_depth_rel > 0.0f && p % W_PX >= W_PX / 2 ? 1.5f : 1.0f,
                                       .prev_x = (float)(p % W_PX) + 0.5f, .prev_y = (float)(p / W_PX) + 0.5f,
                                       .prev_share = toy_share_of(p)};
    struct gbuffer g = {.width = W_PX, .height = H_PX, .px = px};
    void *scratch = malloc(restir_pair_scratch_bytes(W_PX, H_PX));
    CHECK(scratch != NULL);
    if (!scratch) return;
    for (uint32_t t = 0; t < trials; t++) {
        struct restir_reuse r = {.ops = toy_class ? &toy_ops_classes : &toy_ops, .ctx = &ctx, .width = W_PX, .height = H_PX, .seed = 1000u + t,
                                 .threads = 1, .gbuf = &g, .temporal_cap = 20, .neighbors = 3, .radius = 8.0f,
                                 .paired = paired, .pair_scratch = scratch, .max_depth_rel = toy_depth_rel,
                                 .temporal_cap_low = toy_class ? 1u : 0u};
        struct restir_counters c = {0};
        struct err err = {0};
        for (uint32_t frame = 0; frame < 2; frame++) {
            r.frame = frame;
            r.history = frame ? (const uint8_t *)hist : NULL;
            toy_initial(a, r.seed, frame);
            memset(estimate, 0, sizeof estimate);
            r.estimate = expected ? estimate : NULL;
            CHECK(restir_temporal_pass(&r, (uint8_t *)a, &c, &err));
            CHECK(restir_spatial_pass(&r, (const uint8_t *)a, (uint8_t *)b, &c, &err));
            memcpy(hist, b, sizeof hist);
        }
        st->shifts += c.shifts;
        double total = 0.0, total_x = 0.0;
        for (uint32_t p = 0; p < N_PX; p++) {
            if (!toy_valid_pixel(p)) continue;
            double est = b[p].head.W > 0.0f ? (double)b[p].f * b[p].head.W : 0.0;
            if (selected_x) {
                double ex = b[p].head.W > 0.0f ? (double)toy_value(NULL, &b[p]).x * b[p].head.W : 0.0;
                selected_x->sum[p] += ex;
                selected_x->sum2[p] += ex * ex;
                total_x += ex;
            }
            if (expected) est = (double)estimate[p].x;
            st->sum[p] += est;
            st->sum2[p] += est * est;
            total += est;
        }
        st->total_sum += total;
        st->total_sum2 += total * total;
        if (selected_x) {
            selected_x->total_sum += total_x;
            selected_x->total_sum2 += total_x * total_x;
        }
    }
    free(scratch);
}

/* Per-pixel z-scores against the exact integrals: the count passing at Šidák-corrected 1 %, and
 * the z of the image total (pixels share samples, so the total's variance is taken across
 * trials, where trials are independent). */
static void toy_z(const struct toy_stats *st, uint32_t *pass, uint32_t *valid, double *z_total)
{
    const double n = st->trials;
    *pass = *valid = 0;
    double exact_total = 0.0;
    for (uint32_t p = 0; p < N_PX; p++) {
        if (!toy_valid_pixel(p)) continue;
        (*valid)++;
        exact_total += st->first_component ? toy_exact_x(p) : toy_exact(p);
    }
    /* Šidák: per-pixel alpha = 1 - 0.99^(1/valid); two-sided normal quantile by bisection. */
    double alpha = 1.0 - pow(0.99, 1.0 / (double)*valid), lo = 0.0, hi = 10.0;
    for (int i = 0; i < 60; i++) {
        double mid = 0.5 * (lo + hi);
        if (erfc(mid / M_SQRT2) > alpha) lo = mid;
        else hi = mid;
    }
    for (uint32_t p = 0; p < N_PX; p++) {
        if (!toy_valid_pixel(p)) continue;
        double mean = st->sum[p] / n, var = (st->sum2[p] / n - mean * mean) * n / (n - 1.0);
        double z = (mean - (st->first_component ? toy_exact_x(p) : toy_exact(p))) / sqrt(var / n + 1e-30);
        if (fabs(z) <= lo) (*pass)++;
    }
    double mean = st->total_sum / n, var = (st->total_sum2 / n - mean * mean) * n / (n - 1.0);
    *z_total = (mean - exact_total) / sqrt(var / n);
}

static void check_unbiased(bool paired)
{
    static struct toy_stats st, ex, sx;
    toy_run(paired, false, false, 4000, &st, NULL);
    uint32_t pass, valid;
    double z;
    toy_z(&st, &pass, &valid, &z);
    printf("  %s: %u of %u pixels pass, total z = %.2f\n", paired ? "paired" : "unpaired", pass, valid, z);
    CHECK_MSG(pass * 1000u >= valid * 995u, "%u of %u pixels", pass, valid);
    CHECK_MSG(fabs(z) < 3.0, "total z %.2f", z);
    /* The expected contribution over the last selection: unbiased too, and less noisy. */
    toy_run(paired, false, true, 4000, &ex, &sx);
    toy_z(&ex, &pass, &valid, &z);
    uint32_t pass_x, valid_x;
    double z_x;
    toy_z(&sx, &pass_x, &valid_x, &z_x);
    double v_ex = 0.0, v_sx = 0.0;  /* summed per-pixel variances */
    for (uint32_t p = 0; p < N_PX; p++) {
        if (!toy_valid_pixel(p)) continue;
        v_ex += ex.sum2[p] / ex.trials - (ex.sum[p] / ex.trials) * (ex.sum[p] / ex.trials);
        v_sx += sx.sum2[p] / sx.trials - (sx.sum[p] / sx.trials) * (sx.sum[p] / sx.trials);
    }
    printf("  %s, F = (2 f x, f, f): expected contribution %u of %u pixels pass, total z = %.2f; selected "
           "sample %u pass, z = %.2f; summed pixel variance %.4g against %.4g\n", paired ? "paired" : "unpaired", pass,
           valid, z, pass_x, z_x, v_ex, v_sx);
    CHECK_MSG(pass * 1000u >= valid * 995u, "%u of %u pixels", pass, valid);
    CHECK_MSG(fabs(z) < 3.0, "total z %.2f", z);
    CHECK_MSG(pass_x * 1000u >= valid_x * 995u && fabs(z_x) < 3.0, "selected sample: %u pixels, z %.2f", pass_x, z_x);
    CHECK(v_ex < v_sx);  /* the same runs: the expectation over a selection never adds variance */
}

static void test_reuse_unbiased_unpaired(void) { check_unbiased(false); }
static void test_reuse_unbiased_paired(void) { check_unbiased(true); }

/* Neighbours rejected by depth (restir_neighbours_similar): the passes shift fewer samples, across the depth
 * step none, and the estimate stays unbiased, drawn and paired alike, because the test reads only
 * the G-buffer and holds from both sides of a pair. */
static void check_unbiased_with_rejection(bool paired)
{
    static struct toy_stats all, rejecting;
    toy_depth_rel = 0.0f;
    toy_run(paired, false, false, 1000, &all, NULL);
    toy_depth_rel = 0.1f;
    toy_run(paired, false, false, 4000, &rejecting, NULL);
    toy_depth_rel = 0.0f;
    uint32_t pass, valid;
    double z;
    toy_z(&rejecting, &pass, &valid, &z);
    const double per_trial_all = (double)all.shifts / all.trials, per_trial = (double)rejecting.shifts / rejecting.trials;
    printf("  %s, depth step rejected: %u of %u pixels pass, total z = %.2f; %.1f shifts a trial against %.1f\n",
           paired ? "paired" : "unpaired", pass, valid, z, per_trial, per_trial_all);
    CHECK_MSG(pass * 1000u >= valid * 995u, "%u of %u pixels", pass, valid);
    CHECK_MSG(fabs(z) < 3.0, "total z %.2f", z);
    CHECK_MSG(per_trial < 0.97 * per_trial_all, "%.1f shifts a trial against %.1f: nothing was rejected", per_trial,
              per_trial_all);
}
static void test_reuse_unbiased_rejecting_unpaired(void) { check_unbiased_with_rejection(false); }

/* A share of the history's confidence per pixel (the history check's, gbuffer.h): both temporal
 * MIS weights of a pixel use the same shared confidence, so they still sum to one and the
 * estimate stays unbiased; and the share acts (the same seeds give other estimates). */
static void test_history_share_unbiased(void)
{
    static struct toy_stats full, shared, shared_few;
    toy_run(true, false, false, 400, &full, NULL);
    toy_share = true;
    toy_run(true, false, false, 4000, &shared, NULL);
    toy_run(true, false, false, 400, &shared_few, NULL);
    toy_share = false;
    uint32_t pass, valid;
    double z;
    toy_z(&shared, &pass, &valid, &z);
    uint32_t differ = 0;  /* pixels whose estimates over the same 400 seeds changed */
    for (uint32_t p = 0; p < N_PX; p++) differ += shared_few.sum[p] != full.sum[p];
    printf("  history shares in [0.05, 1): %u of %u pixels pass, total z = %.2f\n", pass, valid, z);
    CHECK_MSG(pass * 1000u >= valid * 995u, "%u of %u pixels", pass, valid);
    CHECK_MSG(fabs(z) < 3.0, "total z %.2f", z);
    CHECK_MSG(differ > valid / 2, "the shares changed %u of %u pixels' estimates", differ, valid);
}
static void test_reuse_unbiased_rejecting_paired(void) { check_unbiased_with_rejection(true); }

/* A class of samples whose history is capped lower (restir_reuse.temporal_cap_low): unbiased when
 * the shift keeps the class, biased (the control) when the class is the reservoir's, not the
 * sample's. */
static void check_class_cap(enum toy_class cls)
{
    static struct toy_stats st;
    memset(&st, 0, sizeof st);
    toy_class = cls;
    toy_run(false, false, false, 4000, &st, NULL);
    toy_class = TOY_CLASS_NONE;
    uint32_t pass, valid;
    double z;
    toy_z(&st, &pass, &valid, &z);
    printf("  history capped at 1 for %s: %u of %u pixels pass, total z = %.2f\n",
           cls == TOY_CLASS_X ? "samples with x < 0.5" : "fresh reservoirs (the control)", pass, valid, z);
    if (cls == TOY_CLASS_X) {
        CHECK_MSG(pass * 1000u >= valid * 995u, "%u of %u pixels", pass, valid);
        CHECK_MSG(fabs(z) < 3.0, "total z %.2f", z);
    } else {
        CHECK_MSG(fabs(z) > 5.0, "total z %.2f: a class the shift does not keep went unseen", z);
    }
}
static void test_class_cap_unbiased(void) { check_class_cap(TOY_CLASS_X); }
static void test_class_cap_of_the_reservoir_is_caught(void) { check_class_cap(TOY_CLASS_FRESH); }

/* The control: a shift that squares x but claims |J| = 1 must fail the same test. */
static void test_wrong_jacobian_is_caught(void)
{
    static struct toy_stats st;
    toy_run(true, true, false, 4000, &st, NULL);
    uint32_t pass, valid;
    double z;
    toy_z(&st, &pass, &valid, &z);
    printf("  wrong |J|: %u of %u pixels pass, total z = %.2f\n", pass, valid, z);
    CHECK_MSG(fabs(z) > 5.0, "total z %.2f: the test cannot see a wrong Jacobian", z);
}

/* A paired spatial pass gives the same reservoirs, byte for byte, whatever its thread count: it
 * visits pixels by bands of blocks (split into groups of columns for more threads) or by rows
 * (an image of few blocks), and a pixel's candidates must not depend on which. Radius 4 (blocks of
 * 4: bands, then groups), 8 (bands with one thread, rows with more) and 64 (one block: rows);
 * 1, 3 and 5 threads, three rounds. */
static void test_paired_pass_threads_agree(void)
{
    static struct toy_elem a[N_PX], out[3][N_PX];
    static struct gbuffer_pixel px[N_PX];
    for (uint32_t p = 0; p < N_PX; p++)
        px[p] = (struct gbuffer_pixel){.t = 1.0f, .prev_x = (float)(p % W_PX) + 0.5f,
                                       .prev_y = (float)(p / W_PX) + 0.5f, .prev_share = 1.0f};
    struct gbuffer g = {.width = W_PX, .height = H_PX, .px = px};
    void *scratch = malloc(restir_pair_scratch_bytes(W_PX, H_PX));
    CHECK(scratch != NULL);
    if (!scratch) return;
    struct toy_ctx ctx = {0};
    const float radii[3] = {4.0f, 8.0f, 64.0f};
    const unsigned threads[3] = {1, 3, 5};
    for (int ri = 0; ri < 3; ri++) {
        uint64_t shifts[3] = {0};
        for (int ti = 0; ti < 3; ti++) {
            struct restir_reuse r = {.ops = &toy_ops, .ctx = &ctx, .width = W_PX, .height = H_PX, .seed = 77,
                                     .threads = threads[ti], .gbuf = &g, .temporal_cap = 20, .neighbors = 5,
                                     .radius = radii[ri], .paired = true, .pair_scratch = scratch};
            struct restir_counters c = {0};
            struct err err = {0};
            toy_initial(a, r.seed, 0);
            memset(out[ti], 0, sizeof out[ti]);
            for (uint32_t round = 0; round < 3; round++) {
                r.frame = round;
                CHECK(restir_spatial_pass(&r, (const uint8_t *)a, (uint8_t *)out[ti], &c, &err));
                memcpy(a, out[ti], sizeof a);   /* the next round reads this one's output */
            }
            shifts[ti] = c.shifts;
        }
        for (int ti = 1; ti < 3; ti++)
            CHECK_MSG(memcmp(out[0], out[ti], sizeof out[0]) == 0 && shifts[0] == shifts[ti],
                      "radius %.0f: %u threads differ from 1 (%llu shifts against %llu)", (double)radii[ri],
                      threads[ti], (unsigned long long)shifts[ti], (unsigned long long)shifts[0]);
        printf("  radius %.0f: %llu shifts, the same reservoirs with 1, 3 and 5 threads\n", (double)radii[ri],
               (unsigned long long)shifts[0]);
    }
    free(scratch);
}

/* Each pairing is an involution, partners stay inside the block (B - 1 pixels per axis), never
 * the pixel itself, and every pixel not at an image edge has a partner most of the time. */
static void test_pairing_is_an_involution(void)
{
    const uint32_t w = 53, h = 41;
    struct restir_reuse r = {.width = w, .height = h, .seed = 7, .radius = 20.0f};
    uint32_t found = 0, total = 0;
    for (uint32_t frame = 0; frame < 4; frame++) {
        r.frame = frame;
        for (uint32_t m = 0; m < 3; m++)
            for (uint32_t p = 0; p < w * h; p++) {
                uint32_t q, back;
                total++;
                if (!restir_pair_partner(&r, m, p, &q)) continue;
                found++;
                CHECK(q != p);
                CHECK(q < w * h);
                CHECK(restir_pair_partner(&r, m, q, &back) && back == p);
                int dx = abs((int)(q % w) - (int)(p % w)), dy = abs((int)(q / w) - (int)(p / w));
                CHECK_MSG(dx <= 15 && dy <= 15, "offset (%d, %d) for radius 20 (blocks of 16)", dx, dy);
            }
    }
    printf("  %u of %u pixels had a partner\n", found, total);
    CHECK(found * 10u >= total * 6u);
}

/* The neighbour test is symmetric: paired reuse counts each pixel's neighbours from its own side and
 * relies on a pair being valid from both. Depths 1 and 1.1 at a tolerance of 0.095 are the case a
 * test relative to the centre pixel's depth gets wrong (0.1 > 0.095 * 1 but < 0.095 * 1.1); normals
 * on both sides of the threshold, escaped rays and misses among random pixels. */
static void test_neighbour_test_is_symmetric(void)
{
    enum { N = 64 };
    static struct gbuffer_pixel px[N];
    static struct gbuffer_surface surf[N];
    struct rng rng = rng_make(11, 0, 0, 0);
    for (uint32_t i = 0; i < N; i++) {
        const float u = rng_next_float(&rng), phi = 6.2831853f * rng_next_float(&rng), z = 2.0f * rng_next_float(&rng) - 1.0f;
        const float s = sqrtf(fmaxf(0.0f, 1.0f - z * z));
        const bool miss = i % 13 == 5;
        px[i].t = miss ? INFINITY : 1.0f + 0.3f * u;
        surf[i] = (struct gbuffer_surface){.ns = {s * cosf(phi), s * sinf(phi), z}, .material = miss ? GBUFFER_NO_HIT : 0};
    }
    px[0].t = 1.0f, px[1].t = 1.1f;
    surf[0].ns = surf[1].ns = (struct vec3){0, 0, 1};
    struct gbuffer g = {.width = N, .height = 1, .px = px, .surf = surf};
    struct restir_reuse r = {.width = N, .height = 1, .gbuf = &g, .min_normal_cos = 0.5f, .max_depth_rel = 0.095f};
    CHECK(restir_neighbours_similar(&r, 0, 1) && restir_neighbours_similar(&r, 1, 0));
    uint32_t similar = 0;
    for (uint32_t a = 0; a < N; a++)
        for (uint32_t b = 0; b < N; b++) {
            const bool ab = restir_neighbours_similar(&r, a, b);
            CHECK_MSG(ab == restir_neighbours_similar(&r, b, a), "pixels %u and %u", a, b);
            similar += ab;
        }
    printf("  %u of %u ordered pairs similar\n", similar, N * N);
    CHECK(similar > N && similar < N * N / 2);  /* both tests reject some pairs and accept others */
}

/* ---- the frame driver, on the toy technique ---- */

struct toy_pass {
    struct restir_frame fr;
    uint64_t seed;
};
RESTIR_FRAME_FIRST(struct toy_pass);

/* Initial rows: the toy's candidates into the working reservoirs, all of them in job 0 (toy_initial
 * draws the whole image); the other jobs have nothing to do. */
static void toy_initial_rows(void *ctx, uint32_t job, unsigned worker)
{
    (void)worker;
    struct toy_pass *tp = ctx;
    if (job == 0) toy_initial((struct toy_elem *)tp->fr.s->res[0], tp->seed, tp->fr.f->frame);
}

/* Shade rows: every pixel through restir_frame_store, a NaN at every 5th pixel, +Inf and -Inf at
 * the ones after it, finite values elsewhere. */
static struct vec3 toy_shade_value(uint32_t p)
{
    switch (p % 5u) {
    case 0: return vec3_make(1.0f, NAN, 2.0f);
    case 1: return vec3_splat(INFINITY);
    case 2: return vec3_make(0.5f, -INFINITY, 0.0f);
    default: return vec3_make((float)p, 1.0f, 2.0f);
    }
}
static void toy_shade_rows(void *ctx, uint32_t job, unsigned worker)
{
    struct toy_pass *tp = ctx;
    uint32_t y0, y1;
    restir_frame_rows(&tp->fr, job, &y0, &y1);
    for (uint32_t p = y0 * W_PX; p < y1 * W_PX; p++) restir_frame_store(&tp->fr, worker, p, toy_shade_value(p));
}

/* A session with a static camera's G-buffer (as toy_run's) and a frame of the toy opened on it. */
static bool toy_frame_open(struct restir_session *s, struct toy_pass *tp, const struct method_frame *f,
                           struct image *out, struct restir_pass_stats *stats, struct err *err)
{
    if (!restir_session_init(s, W_PX, H_PX, 1, sizeof(struct toy_elem), false, false, err)) return false;
    for (int i = 0; i < 2; i++)
        for (uint32_t p = 0; p < N_PX; p++)
            s->gbuf[i].px[p] = (struct gbuffer_pixel){.t = 1.0f, .prev_x = (float)(p % W_PX) + 0.5f,
                                                      .prev_y = (float)(p / W_PX) + 0.5f, .prev_share = 1.0f};
    struct restir_pass_stats local;
    if (!restir_frame_open(&tp->fr, sizeof *tp, s, f, out, false, stats, &local, sizeof local, err)) return false;
    tp->seed = f->seed;
    return true;
}

static const struct camera_desc toy_camera = {.look_at = {0.0f, 0.0f, 1.0f}, .up = {0.0f, 1.0f, 0.0f},
                                              .fov_deg = 45.0f};

/* restir_frame_store: a value that is not finite becomes 0 and is counted, per worker, into the
 * frame's nonfinite; finite values pass unchanged; the shade pass leaves a history. */
static void test_frame_store_zeroes_nonfinite(void)
{
    struct restir_session s;
    struct toy_pass tp;
    struct image out = {0};
    struct restir_pass_stats stats;
    struct err err = {0};
    const struct method_frame f = {.camera = &toy_camera, .seed = 5, .threads = 2};
    CHECK(image_init(&out, W_PX, H_PX, &err));
    CHECK_MSG(toy_frame_open(&s, &tp, &f, &out, &stats, &err), "%s", err.message);
    CHECK(!s.has_history);
    CHECK_MSG(restir_frame_shade(&tp.fr, toy_shade_rows, &err), "%s", err.message);
    uint64_t bad = 0;
    for (uint32_t p = 0; p < N_PX; p++) {
        const struct vec3 v = toy_shade_value(p), got = out.pixels[p];
        const bool finite = vec3_is_finite(v);
        bad += !finite;
        CHECK_MSG(finite ? memcmp(&got, &v, sizeof v) == 0 : got.x == 0.0f && got.y == 0.0f && got.z == 0.0f,
                  "pixel %u: (%g, %g, %g)", p, got.x, got.y, got.z);
    }
    CHECK_MSG(stats.nonfinite == bad && bad == 3u * ((N_PX + 4u) / 5u) - 1u, "nonfinite %llu of %llu",
              (unsigned long long)stats.nonfinite, (unsigned long long)bad);
    CHECK(s.has_history);
    image_destroy(&out);
    restir_session_destroy(&s);
}

/* The driver's spatial rounds end in res[1], the next frame's history: after one round and after
 * two (which ping-pong through res[0]) it holds exactly what the same rounds run by hand give. */
static void check_history_after(uint32_t rounds)
{
    struct restir_session s;
    struct toy_pass tp;
    struct image out = {0};
    struct restir_pass_stats stats;
    struct err err = {0};
    struct toy_ctx ctx = {0};
    const struct method_frame f = {.camera = &toy_camera, .seed = 11, .frame = 0, .threads = 1};
    CHECK(image_init(&out, W_PX, H_PX, &err));
    CHECK_MSG(toy_frame_open(&s, &tp, &f, &out, &stats, &err), "%s", err.message);
    CHECK_MSG(restir_frame_initial(&tp.fr, toy_initial_rows, &err), "%s", err.message);
    struct restir_reuse *r = restir_frame_reuse(&tp.fr, &toy_ops, &ctx, 0, 20, 3, 8.0f, false);
    CHECK_MSG(restir_frame_temporal(&tp.fr, &err), "%s", err.message);
    for (uint32_t round = 0; round < rounds; round++) {
        r->frame = round;
        CHECK_MSG(restir_frame_spatial(&tp.fr, false, round + 1 == rounds, &err), "%s", err.message);
    }
    restir_frame_reused(&tp.fr);

    static struct toy_elem want[2][N_PX];
    struct restir_reuse hand = {.ops = &toy_ops, .ctx = &ctx, .width = W_PX, .height = H_PX, .seed = f.seed,
                                .threads = 1, .gbuf = &s.gbuf[s.cur], .temporal_cap = 20, .neighbors = 3,
                                .radius = 8.0f};
    struct restir_counters c = {0};
    toy_initial(want[0], f.seed, f.frame);
    for (uint32_t round = 0; round < rounds; round++) {
        hand.frame = round;
        CHECK(restir_spatial_pass(&hand, (const uint8_t *)want[round & 1u], (uint8_t *)want[(round + 1) & 1u], &c,
                                  &err));
    }
    const struct toy_elem *history = (const struct toy_elem *)s.res[1];
    CHECK_MSG(memcmp(history, want[rounds & 1u], sizeof want[0]) == 0,
              "%u round(s): the history is not the last round's output", rounds);
    CHECK_MSG(memcmp(want[0], want[1], sizeof want[0]) != 0, "the rounds changed nothing: the test sees nothing");
    image_destroy(&out);
    restir_session_destroy(&s);
}
static void test_frame_history_one_round(void) { check_history_after(1); }
static void test_frame_history_two_rounds(void) { check_history_after(2); }

TEST_MAIN(TEST(test_frame_store_zeroes_nonfinite), TEST(test_frame_history_one_round),
          TEST(test_frame_history_two_rounds), TEST(test_pairing_is_an_involution), TEST(test_paired_pass_threads_agree), TEST(test_neighbour_test_is_symmetric), TEST(test_reuse_unbiased_unpaired),
          TEST(test_reuse_unbiased_paired), TEST(test_reuse_unbiased_rejecting_unpaired),
          TEST(test_reuse_unbiased_rejecting_paired), TEST(test_history_share_unbiased), TEST(test_class_cap_unbiased),
          TEST(test_class_cap_of_the_reservoir_is_caught), TEST(test_wrong_jacobian_is_caught))
