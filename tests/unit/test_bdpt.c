/* test_bdpt.c — the recursive MIS of `bdpt` (renderer/integrators/bdpt_mis.h) against a brute-force
 * recomputation. Random paths x_0 (pinhole camera) .. x_{n-1} (area emitter) with diffuse,
 * glossy (GGX conductor) and delta vertices are built; every technique that can produce the
 * path — emitter hit (s = 0), next-event estimation (s = 1), vertex connections (2 <= s <=
 * n-2), light tracing (t = 1) — gets its full path pdf as a product of per-vertex area pdfs
 * (light tracing times N_L), and its weight Mis(p_s) / sum_i Mis(p_i) over the techniques whose
 * connection edge joins two non-delta vertices. The recursive weights, from the subpaths'
 * dVCM / dVC carried vertex by vertex exactly as the renderer carries them, must equal these
 * (relative 2e-3, float against double) and sum to 1, for the balance and the power heuristic.
 * The same weights with one technique left out of the brute-force sum must not match, so the
 * test can fail. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "integrators/bdpt.h"
#include "integrators/bdpt_mis.h"
#include "material/material.h"
#include "core/rng.h"
#include "scene/scene.h"
#include "session_buffers.h"
#include "test.h"
#include "scene_fixture.h"
#include "session/view.h"

#include "bdpt_paths.h"

/* Whether technique s (light vertices) can produce the path. */
static bool available(const struct tpath *t, int s)
{
    int n = t->n, tt = n - s;
    if (s == 0) return true;
    if (s == 1) return !t->delta[n - 2];
    if (tt == 1) return !t->delta[1];
    return !t->delta[tt - 1] && !t->delta[tt];
}

static double brute_pdf(const struct tpath *t, int s)
{
    int n = t->n, tt = n - s;
    double p = 1.0;
    for (int i = 1; i <= tt - 1; i++) p *= pc(t, i);
    for (int i = tt; i <= n - 1; i++) p *= pl(t, i);
    if (tt == 1) p *= t->n_light;
    return p;
}

static double mis_d(double x, bool power) { return power ? x * x : x; }

/* Recursive weights of every technique, with the renderer's state updates. */
static void recursive_weights(const struct tpath *t, bool power, double w[MAXV + 1])
{
    int n = t->n;
    struct bdpt_mis C[MAXV], L[MAXV];
    C[1] = bdpt_mis_camera_start(t->n_light, camera_pdf_w(t), power);
    bdpt_mis_hit(&C[1], dist2(t, 0, 1), cos_at(t, 1, 0), power);
    for (int i = 1; i <= n - 2; i++) {
        C[i + 1] = C[i];
        float fwd = t->delta[i] ? t->p_cam[i] : pdf_w(t, i, i - 1, i + 1);
        float rev = t->delta[i] ? t->p_light[i] : pdf_w(t, i, i + 1, i - 1);
        bdpt_mis_scatter(&C[i + 1], cos_at(t, i, i + 1), fwd, rev, t->delta[i], power);
        bdpt_mis_hit(&C[i + 1], dist2(t, i, i + 1), cos_at(t, i + 1, i), power);
    }
    float cos_l = cos_at(t, n - 1, n - 2);
    float emission_pdf_w = t->pdf_a * cos_l * INV_PI_F;
    L[n - 2] = bdpt_mis_light_start(t->pdf_a, emission_pdf_w, cos_l, power);
    bdpt_mis_hit(&L[n - 2], dist2(t, n - 1, n - 2), cos_at(t, n - 2, n - 1), power);
    for (int i = n - 2; i >= 2; i--) {
        L[i - 1] = L[i];
        float fwd = t->delta[i] ? t->p_light[i] : pdf_w(t, i, i + 1, i - 1);
        float rev = t->delta[i] ? t->p_cam[i] : pdf_w(t, i, i - 1, i + 1);
        bdpt_mis_scatter(&L[i - 1], cos_at(t, i, i - 1), fwd, rev, t->delta[i], power);
        bdpt_mis_hit(&L[i - 1], dist2(t, i, i - 1), cos_at(t, i - 1, i), power);
    }
    for (int s = 0; s <= n - 1; s++) {
        int tt = n - s;
        w[s] = 0.0;
        if (!available(t, s)) continue;
        if (s == 0) {
            w[s] = bdpt_mis_weight_emission(&C[n - 1], t->pdf_a, emission_pdf_w, power);
        } else if (s == 1) {
            int v = n - 2;
            float d2 = dist2(t, v, n - 1);
            w[s] = bdpt_mis_weight_nee(&C[v], pdf_w(t, v, v - 1, n - 1), pdf_w(t, v, n - 1, v - 1),
                                       t->pdf_a * d2 / cos_l, emission_pdf_w, cos_at(t, v, n - 1), cos_l, power);
        } else if (tt == 1) {
            float cam_a = camera_pdf_w(t) * cos_at(t, 1, 0) / dist2(t, 0, 1);
            w[s] = bdpt_mis_weight_camera(&L[1], cam_a, t->n_light, pdf_w(t, 1, 0, 2), power);
        } else {
            int a = tt - 1, b = tt;   /* camera vertex a, light vertex b */
            float d2 = dist2(t, a, b);
            float cam_fwd_a = pdf_w(t, a, a - 1, b) * cos_at(t, b, a) / d2;
            float light_fwd_a = pdf_w(t, b, b + 1, a) * cos_at(t, a, b) / d2;
            w[s] = bdpt_mis_weight_connect(&C[a], &L[b], cam_fwd_a, pdf_w(t, a, b, a - 1), light_fwd_a,
                                           pdf_w(t, b, a, b + 1), power);
        }
    }
}

static void check_heuristic(bool power)
{
    struct rng r = rng_make(7, power, 0, 0);
    int paths = 0, compared = 0, mismatched_control = 0, multi = 0;
    double worst = 0.0, worst_sum = 0.0;
    for (int trial = 0; trial < 4000; trial++) {
        struct tpath t;
        make_path(&t, &r, 3 + (int)(frand(&r) * 7.0f));   /* 1..7 surface vertices */
        double bf[MAXV + 1], rec[MAXV + 1], total = 0.0;
        int avail = 0;
        for (int s = 0; s <= t.n - 1; s++) {
            bf[s] = available(&t, s) ? mis_d(brute_pdf(&t, s), power) : 0.0;
            total += bf[s];
            avail += available(&t, s);
        }
        /* Every vertex must be reachable from both sides (a zero pdf would mean a subpath that
         * no tracer can follow, whose recursive state the renderer never forms). */
        bool reachable = true;
        for (int i = 1; i <= t.n - 1; i++) reachable = reachable && pc(&t, i) > 0.0 && pl(&t, i) > 0.0;
        if (!reachable || !(total > 0.0) || !isfinite(total)) continue;
        recursive_weights(&t, power, rec);
        paths++;
        multi += avail > 1;
        double sum = 0.0;
        for (int s = 0; s <= t.n - 1; s++) {
            double want = bf[s] / total;
            double err = fabs(rec[s] - want) / fmax(want, 1e-3);
            if (err > worst) worst = err;
            CHECK_MSG(err < 2e-3, "n %d, s %d: recursive %.9g, brute force %.9g", t.n, s, rec[s], want);
            sum += rec[s];
            compared++;
        }
        if (fabs(sum - 1.0) > worst_sum) worst_sum = fabs(sum - 1.0);
        CHECK_MSG(fabs(sum - 1.0) < 2e-3, "n %d: weights sum to %.9g", t.n, sum);
        /* Control: leaving the emitter-hit technique out of the brute-force normalisation must
         * change a weight visibly whenever it carries any. */
        double without = total - bf[0];
        if (avail > 1 && bf[0] / total > 0.01 && without > 0.0) {
            int s = 1;
            while (s <= t.n - 1 && bf[s] == 0.0) s++;
            if (s <= t.n - 1 && fabs(rec[s] - bf[s] / without) / (bf[s] / without) > 2e-3) mismatched_control++;
        }
    }
    printf("  %s: %d paths (%d with several techniques), %d weights, worst relative error %.2e, worst |sum - 1| %.2e, "
           "control mismatches %d\n",
           power ? "power" : "balance", paths, multi, compared, worst, worst_sum, mismatched_control);
    CHECK(paths > 3000);
    CHECK(multi > 1000);
    CHECK(mismatched_control > 100);
}

static void test_mis_power(void) { check_heuristic(true); }
static void test_mis_balance(void) { check_heuristic(false); }

/* The params' ranges and names. */
static void test_params(void)
{
    struct err err = {0};
    struct bdpt_params p = bdpt_defaults();
    CHECK(bdpt_params_valid(&p, &err));
    p.lvc_capacity = 0;
    CHECK(!bdpt_params_valid(&p, &err) && strcmp(err.where, "/params/lvc_capacity") == 0);
    p = bdpt_defaults();
    p.max_depth = 0;
    CHECK(!bdpt_params_valid(&p, &err) && strcmp(err.where, "/params/max_depth") == 0);
}

/* The memory budget reserves what a session will allocate: planned bytes = allocated bytes,
 * for the default and for a given N_L and cache size. */
static void test_session_bytes_planned_match_allocated(void)
{
    struct scene *sc = fixture_load("scenes/lamp-in-glass/scene.json");
    if (!sc) return;
    for (int k = 0; k < 2; k++) {
        struct err err = {0};
        struct view_params vp = view_params_defaults(method_find("bdpt"), 40, 24);
        if (k) {
            VIEW_METHOD_PARAMS(&vp, struct bdpt_params)->light_paths = 1000;
            VIEW_METHOD_PARAMS(&vp, struct bdpt_params)->lvc_capacity = 3;
        }
        struct view v;
        CHECK(view_init(&v, sc, &vp, 1, &err));
        struct session_buffers sb;
        CHECK(session_buffers_agree(&v, &vp, sc, &sb));
        CHECK(session_buffer(&sb, "light_vertex_cache") > 0);
        view_destroy(&v);
    }
    scene_release(sc);
}

/* Frames of a view: every technique contributes, nothing is dropped or non-finite, and a
 * scene with environment light is refused at creation. */
static void test_frames_and_stats(void)
{
    struct scene *sc = fixture_load("scenes/caustic-sphere/scene.json");
    if (!sc) return;
    struct err err = {0};
    struct view_params vp = view_params_defaults(method_find("bdpt"), 24, 16);
    struct view v;
    CHECK(view_init(&v, sc, &vp, 2, &err));
    struct frame_stats fs = {0};
    for (int f = 0; f < 2; f++) CHECK_MSG(view_render(&v, NULL, &fs, NULL, NULL, &err), "%s", err.message);
    const struct bdpt_stats *bs = (const struct bdpt_stats *)(const void *)fs.counters;
    CHECK(bs->light_subpaths == 24 * 16 && bs->lvc_vertices > 0 && bs->lvc_dropped == 0);
    CHECK(bs->light_traced > 0 && bs->connections > 0 && fs.render.nonfinite == 0);
    double sum = 0.0;
    for (uint32_t i = 0; i < 24 * 16; i++) sum += v.output.pixels[i].x;
    CHECK(sum > 0.0 && isfinite(sum));
    view_destroy(&v);
    scene_release(sc);

    struct scene *env = fixture_load("scenes/furnace/scene.json");
    if (!env) return;
    CHECK(!view_init(&v, env, &vp, 1, &err) && err.code == ERR_INVALID && strstr(err.message, "environment"));
    scene_release(env);
}

/* A failed allocation of the block counters is an error, and leaves nothing allocated: a huge
 * counter array (2^32 - 1 per block for 2^24 - 1 blocks) is more than the address space. Skipped
 * under the sanitizers, whose allocators abort on such a request. */
static void test_blocks_alloc_fails_cleanly(void)
{
#if !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
    struct err err = {0};
    struct bdpt_blocks b;
    CHECK(!bdpt_blocks_alloc(&b, UINT32_MAX - 255u, 1, UINT32_MAX, 1, 1, &err) && err.code == ERR_NOMEM);
    CHECK(!b.count && !b.dropped && !b.rays && b.blocks == 0);
    CHECK(bdpt_blocks_alloc(&b, 1000, 2, 0, 1, 1, &err) && b.count && b.dropped && !b.rays && b.blocks == 4);
    bdpt_blocks_destroy(&b);
#endif
}

TEST_MAIN(TEST(test_mis_power), TEST(test_mis_balance), TEST(test_params), TEST(test_session_bytes_planned_match_allocated),
          TEST(test_frames_and_stats), TEST(test_blocks_alloc_fails_cleanly))
