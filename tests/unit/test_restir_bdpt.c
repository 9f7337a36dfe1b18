/* test_restir_bdpt.c — ReSTIR BDPT, lightweight variant (renderer/integrators/restir_bdpt.h).
 *  - The lightweight MIS: over random paths (built as in tests/unit/test_bdpt.c), the recursive
 *    weights of s = 0, s = 1 and t = 1 equal a brute-force recomputation and sum to 1; the full
 *    bdpt normalisation must disagree (the test can fail).
 *  - The caustic random-replay shift: round trips give back pixel and contribution exactly.
 *  - The non-caustic shifts with reuse (hybrid, reverse hybrid, random replay): a sample shifted
 *    to another pixel and back has its own target again, and the Jacobians multiply to 1.
 *  - The full variant's MIS: the same state updates, with dVCM kept after the first scattering,
 *    give the weights of all of bdpt's techniques (brute force) and sum to 1.
 *  - The recursive reconnection MIS (the hybrid shift's): a path whose prefix up to x_k changes
 *    gets from its suffix's two constants the weight a recomputation along the whole path gives.
 *  - Parameters: the full variant's non-caustic reuse is refused naming /params/reuse; planned
 *    bytes = allocated, the light vertex cache included.
 *  - The session method: a view's planned bytes equal its named buffers' sum (with and without
 *    the non-caustic reuse); frames report their counters; scenes with environment light or
 *    translucent materials are refused.
 *  - Determinism: frames are bit-identical with 1 and 2 threads (the light-traced samples are
 *    bucketed by a counting sort in light-subpath order).
 *  - Unbiasedness: per-pixel z-test (Šidák at 0.01 over the pixels, >= 99.75 % passing, image
 *    mean within 3 sigma) of restir_bdpt frames against `bdpt` frames at 32x32 on caustic-sphere
 *    and a crop of lamp-in-glass; the same frames scaled by 1.03 must fail. Frames of both
 *    methods are independent (no reuse), so per-frame pixel values are i.i.d. samples.
 *  - Caustic temporal reuse: sessions with it on and off share their seeds (so their
 *    non-caustic reservoirs agree frame by frame); the mean difference must be 0 within 3 sigma,
 *    and not with the reused images scaled by 1.03. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "integrators/bdpt.h"
#include "integrators/bdpt_mis.h"
#include "integrators/restir_bdpt.h"
#include "scene/scene.h"
#include "material/material.h"
#include "core/rng.h"
#include "session_buffers.h"
#include "test.h"
#include "scene_fixture.h"
#include "session/view.h"

/* The statistical tests render thousands of frames: skipped in the sanitizer builds (ASan and
 * TSan), where they would take minutes (as the pytest `statistical` marker is). */
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define STATISTICAL 0
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define STATISTICAL 0
#endif
#endif
#ifndef STATISTICAL
#define STATISTICAL 1
#endif
#define SKIP_IF_SANITIZED()                                                    \
    do {                                                                       \
        if (!STATISTICAL) {                                                    \
            printf("    skipped: statistical, sanitizer build\n");            \
            return;                                                            \
        }                                                                      \
    } while (0)

#include "bdpt_paths.h"

/* Whether one of the path's scattering vertices is delta: only then does the lightweight set
 * keep t = 1 (rbdpt_mis_vertex). */
static bool has_caster(const struct tpath *t)
{
    for (int i = 1; i <= t->n - 2; i++)
        if (t->delta[i]) return true;
    return false;
}

/* Whether technique s (light vertices) of the lightweight set (s = 0, s = 1, t = 1 where the path
 * has a delta vertex) can produce the path. */
static bool available(const struct tpath *t, int s)
{
    int n = t->n, tt = n - s;
    if (s == 0) return true;
    if (s == 1) return !t->delta[n - 2];
    if (tt == 1) return !t->delta[1] && has_caster(t);
    return false;
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

/* Whether technique s of all of bdpt's can produce the path (connections join non-delta
 * vertices). */
static bool available_full(const struct tpath *t, int s)
{
    int tt = t->n - s;
    if (tt == 1) return !t->delta[1];   /* the full variant keeps t = 1 on every path */
    if (s <= 1) return available(t, s);
    return tt >= 2 && !t->delta[tt - 1] && !t->delta[tt];
}

/* The lightweight weights of s = 0, s = 1 and t = 1 with the renderer's state updates; with
 * `full` (the full variant) the same functions' states, and bdpt's connection weight from them,
 * for every technique. */
static void recursive_weights(const struct tpath *t, bool power, bool full, double w[MAXV + 1])
{
    int n = t->n;
    struct restir_bdpt_mis C[MAXV], L[MAXV];
    C[1] = restir_bdpt_mis_camera_start(t->n_light, camera_pdf_w(t), power);
    C[1].full = full;
    restir_bdpt_mis_hit(&C[1], dist2(t, 0, 1), cos_at(t, 1, 0), power);
    for (int i = 1; i <= n - 2; i++) {
        C[i].caster = C[i].caster || t->delta[i];   /* rbdpt_mis_vertex at x_i */
        C[i + 1] = C[i];
        float fwd = t->delta[i] ? t->p_cam[i] : pdf_w(t, i, i - 1, i + 1);
        float rev = t->delta[i] ? t->p_light[i] : pdf_w(t, i, i + 1, i - 1);
        restir_bdpt_mis_scatter(&C[i + 1], cos_at(t, i, i + 1), fwd, rev, t->delta[i], power);
        restir_bdpt_mis_hit(&C[i + 1], dist2(t, i, i + 1), cos_at(t, i + 1, i), power);
    }
    float cos_l = cos_at(t, n - 1, n - 2);
    float emission_pdf_w = t->pdf_a * cos_l * INV_PI_F;
    L[n - 2] = restir_bdpt_mis_light_start(t->pdf_a, emission_pdf_w, cos_l, power);
    L[n - 2].full = full;
    restir_bdpt_mis_hit(&L[n - 2], dist2(t, n - 1, n - 2), cos_at(t, n - 2, n - 1), power);
    for (int i = n - 2; i >= 2; i--) {
        L[i].caster = L[i].caster || t->delta[i];   /* rbdpt_mis_vertex at x_i */
        L[i - 1] = L[i];
        float fwd = t->delta[i] ? t->p_light[i] : pdf_w(t, i, i + 1, i - 1);
        float rev = t->delta[i] ? t->p_cam[i] : pdf_w(t, i, i - 1, i + 1);
        restir_bdpt_mis_scatter(&L[i - 1], cos_at(t, i, i - 1), fwd, rev, t->delta[i], power);
        restir_bdpt_mis_hit(&L[i - 1], dist2(t, i, i - 1), cos_at(t, i - 1, i), power);
    }
    L[1].caster = L[1].caster || t->delta[1];
    for (int s = 0; s <= n - 1; s++) {
        int tt = n - s;
        w[s] = 0.0;
        if (!(full ? available_full(t, s) : available(t, s))) continue;
        if (s == 0) {
            w[s] = restir_bdpt_mis_emission(&C[n - 1], t->pdf_a, emission_pdf_w, power);
        } else if (s == 1) {
            int v = n - 2;
            float d2 = dist2(t, v, n - 1);
            w[s] = restir_bdpt_mis_nee(&C[v], pdf_w(t, v, v - 1, n - 1), pdf_w(t, v, n - 1, v - 1),
                                       t->pdf_a * d2 / cos_l, emission_pdf_w, cos_at(t, v, n - 1), cos_l, power);
        } else if (tt == 1) {
            float cam_a = camera_pdf_w(t) * cos_at(t, 1, 0) / dist2(t, 0, 1);
            w[s] = restir_bdpt_mis_camera(&L[1], cam_a, t->n_light, pdf_w(t, 1, 0, 2), power);
        } else {
            int a = tt - 1, b = tt;   /* camera vertex a, light vertex b */
            float d2 = dist2(t, a, b);
            float cam_fwd_a = pdf_w(t, a, a - 1, b) * cos_at(t, b, a) / d2;
            float light_fwd_a = pdf_w(t, b, b + 1, a) * cos_at(t, a, b) / d2;
            const struct bdpt_mis ca = {C[a].dvcm, C[a].dvc}, lb = {L[b].dvcm, L[b].dvc};
            w[s] = bdpt_mis_weight_connect(&ca, &lb, cam_fwd_a, pdf_w(t, a, b, a - 1), light_fwd_a,
                                           pdf_w(t, b, a, b + 1), power);
        }
    }
}

/* Over random paths, the recursive weights equal Mis(p_s) / sum Mis(p_i) (brute force in double)
 * and sum to 1: over the three lightweight techniques, or with `full` (the same state updates
 * with dVCM kept after the first scattering) over all of bdpt's. The lightweight case has a
 * control: the full normalisation (vertex connections included) must disagree on paths that
 * connections can produce. */
static void check_mis(bool power, bool full)
{
    struct rng r = rng_make(full ? 19 : 9, power, 0, 0);
    int paths = 0, multi = 0, control = 0, connected = 0;
    double worst = 0.0;
    for (int trial = 0; trial < 4000; trial++) {
        struct tpath t;
        make_path(&t, &r, 3 + (int)(frand(&r) * 7.0f));
        double bf[MAXV + 1], rec[MAXV + 1], total = 0.0, all = 0.0;
        int avail = 0;
        bool any_connection = false;
        for (int s = 0; s <= t.n - 1; s++) {
            bool here = full ? available_full(&t, s) : available(&t, s);
            bf[s] = here ? mis_d(brute_pdf(&t, s), power) : 0.0;
            total += bf[s];
            avail += here;
            all += available_full(&t, s) ? mis_d(brute_pdf(&t, s), power) : 0.0;
            any_connection = any_connection || (s >= 2 && t.n - s >= 2 && available_full(&t, s));
        }
        bool reachable = true;
        for (int i = 1; i <= t.n - 1; i++) reachable = reachable && pc(&t, i) > 0.0 && pl(&t, i) > 0.0;
        if (!reachable || !(total > 0.0) || !isfinite(total) || !isfinite(all)) continue;
        recursive_weights(&t, power, full, rec);
        paths++;
        multi += avail > 1;
        connected += any_connection;
        double sum = 0.0;
        for (int s = 0; s <= t.n - 1; s++) {
            double want = bf[s] / total;
            double e = fabs(rec[s] - want) / fmax(want, 1e-3);
            if (e > worst) worst = e;
            CHECK_MSG(e < 2e-3, "%s, n %d, s %d: recursive %.9g, brute force %.9g", full ? "full" : "lightweight", t.n,
                      s, rec[s], want);
            sum += rec[s];
        }
        CHECK_MSG(fabs(sum - 1.0) < 2e-3, "n %d: weights sum to %.9g", t.n, sum);
        if (bf[0] > 0.0 && fabs(rec[0] - bf[0] / all) / (bf[0] / all) > 2e-3) control++;
    }
    printf("    %s, %s: %d paths (%d with several techniques, %d with a connection technique), worst relative "
           "error %.2e, %d differ from full bdpt\n",
           full ? "full" : "lightweight", power ? "power" : "balance", paths, multi, connected, worst, control);
    CHECK(paths > 3000 && multi > 1000 && connected > 1000);
    CHECK(full ? control == 0 : control > 100);
}

static void test_mis_lightweight(void)
{
    check_mis(true, false);
    check_mis(false, false);
}

static void test_mis_full(void)
{
    check_mis(true, true);
    check_mis(false, true);
}

/* ---- the recursive reconnection MIS -------------------------------------------------------- */

/* A camera subpath's per-vertex quantities for the MIS state: x_1 .. x_e (x_e the emitter of an
 * s = 0 path; for s = 1 x_e stands for the light sample, reached by NEE from x_{e-1}). */
struct rc_path {
    float camera_pdf_w;
    float hit_d2[16], hit_cos[16];               /* arriving at x_j */
    float out_cos[16], pf[16], pr[16];           /* scattering at x_j */
    bool delta[16];
    float nee_fwd, nee_rev;                      /* s = 1: x_{e-1}'s pdfs towards the light and back */
};

static float urand(struct rng *r, float lo, float hi) { return lo + (hi - lo) * rng_next_float(r); }

static void rc_path_random(struct rng *r, struct rc_path *p, uint32_t e)
{
    p->camera_pdf_w = urand(r, 0.5f, 40.0f);
    for (uint32_t j = 1; j <= e; j++) {
        p->hit_d2[j] = urand(r, 0.01f, 9.0f);
        p->hit_cos[j] = urand(r, 0.05f, 1.0f) * (rng_next_float(r) < 0.5f ? -1.0f : 1.0f);
        p->out_cos[j] = urand(r, 0.05f, 1.0f);
        p->pf[j] = urand(r, 0.05f, 5.0f);
        p->pr[j] = urand(r, 0.05f, 5.0f);
        p->delta[j] = rng_next_float(r) < 0.2f;
    }
    p->nee_fwd = urand(r, 0.05f, 5.0f);
    p->nee_rev = urand(r, 0.05f, 5.0f);
}

/* The MIS state after x_upto's hit (and its scattering when `scatter`), as a path tracer
 * accumulates it; the vertices that scatter count towards the caster flag (x_upto without
 * `scatter` is the emitter, or an NEE vertex, which is rough). */
static struct restir_bdpt_mis rc_path_state(const struct rc_path *p, uint32_t upto, bool scatter, bool power)
{
    struct restir_bdpt_mis m = restir_bdpt_mis_camera_start(1000.0f, p->camera_pdf_w, power);
    for (uint32_t j = 1; j <= upto; j++) {
        restir_bdpt_mis_hit(&m, p->hit_d2[j], p->hit_cos[j], power);
        if (j < upto || scatter) {
            m.caster = m.caster || p->delta[j];
            restir_bdpt_mis_scatter(&m, p->out_cos[j], p->pf[j], p->pr[j], p->delta[j], power);
        }
    }
    return m;
}

/* Whether a vertex after x_k that scatters (before x_end) is delta: the rc's mis_c. */
static bool rc_path_suffix_caster(const struct rc_path *p, uint32_t k, uint32_t end)
{
    for (uint32_t j = k + 1; j < end; j++)
        if (p->delta[j]) return true;
    return false;
}

/* What dVC gains from x_k's scattering to x_end's hit: the same updates applied to dVC = 1. */
static float rc_path_suffix(const struct rc_path *p, uint32_t k, uint32_t end, bool power)
{
    struct restir_bdpt_mis m = {0.0f, 1.0f, false, false};
    for (uint32_t j = k + 1; j <= end; j++) {
        restir_bdpt_mis_hit(&m, p->hit_d2[j], p->hit_cos[j], power);
        if (j < end) restir_bdpt_mis_scatter(&m, p->out_cos[j], p->pf[j], p->pr[j], p->delta[j], power);
    }
    return m.dvc;
}

/* The weight of the path's technique (s = 0 or s = 1), recomputed along the whole path. */
static float rc_path_weight(const struct rc_path *p, uint32_t e, int s, float dpa, float epw, float dpw, float cos_cam,
                            float cos_light, bool power)
{
    if (s == 0) {
        struct restir_bdpt_mis m = rc_path_state(p, e, false, power);
        return restir_bdpt_mis_emission(&m, dpa, epw, power);
    }
    struct restir_bdpt_mis m = rc_path_state(p, e - 1, false, power);
    return restir_bdpt_mis_nee(&m, p->nee_fwd, p->nee_rev, dpw, epw, cos_cam, cos_light, power);
}

/* Over random paths of 3 to 12 vertices, both techniques, both heuristics and every k in
 * 2 .. e - 1: a path whose vertices up to x_k are replaced (new distances, cosines and pdfs
 * arriving at x_k, and x_k's own pdfs, which depend on its new incoming direction) gets from
 * restir_bdpt_mis_reconnect — the base path's two constants and the new state at x_k — the weight
 * that recomputing the MIS along the whole new path gives. The constants of another path's
 * suffix must give a different weight (the test can fail). */
static void test_mis_reconnect(void)
{
    struct rng r = rng_make(7, 0, 0, 0x6d6973);
    double worst = 0.0;
    uint32_t cases = 0, wrong_suffix_differs = 0, wrong_suffix_cases = 0, keeps_t1 = 0;
    for (int it = 0; it < 4000; it++) {
        const bool power = it & 1;
        const int s = (it >> 1) & 1;
        const uint32_t e = 3 + (uint32_t)(rng_next_float(&r) * 10.0f);
        const uint32_t k = 2 + (uint32_t)(rng_next_float(&r) * (float)(e - 2));   /* 2 .. e - 1 */
        struct rc_path base;
        rc_path_random(&r, &base, e);
        /* The reconnection pair and x_k itself are rough; an NEE vertex is too. */
        base.delta[k - 1] = base.delta[k] = false;
        if (s == 1) base.delta[e - 1] = false;
        const float dpa = urand(&r, 0.1f, 3.0f), epw = urand(&r, 0.1f, 3.0f), dpw = urand(&r, 0.1f, 30.0f);
        const float cos_cam = urand(&r, 0.05f, 1.0f), cos_light = urand(&r, 0.05f, 1.0f);
        const bool last = k + 1 == e;
        const enum restir_bdpt_rc_kind kind = !last ? RBDPT_RC_AFTER : s == 0 ? RBDPT_RC_EMIT_LAST : RBDPT_RC_NEE_LAST;
        /* The base path's constants, where its weight is computed. */
        float a, b;
        const float suffix = rc_path_suffix(&base, k, s == 0 ? e : e - 1, power);
        if (s == 0) {
            struct restir_bdpt_mis m = rc_path_state(&base, e, false, power);
            restir_bdpt_rc_mis_emission(&m, dpa, epw, base.hit_d2[e], base.hit_cos[e], last, suffix, power, &a, &b);
        } else {
            restir_bdpt_rc_mis_nee(base.nee_fwd, base.nee_rev, dpw, epw, cos_cam, cos_light, last, suffix, power, &a,
                                   &b);
        }
        /* The shifted path: a new prefix up to x_k, x_k's pdfs anew, the rest kept. */
        struct rc_path sh = base, fresh;
        rc_path_random(&r, &fresh, e);
        sh.camera_pdf_w = fresh.camera_pdf_w;
        for (uint32_t j = 1; j <= k; j++) {
            sh.hit_d2[j] = fresh.hit_d2[j];
            sh.hit_cos[j] = fresh.hit_cos[j];
            sh.pf[j] = fresh.pf[j];
            sh.pr[j] = fresh.pr[j];
            if (j < k) {
                sh.out_cos[j] = fresh.out_cos[j];
                sh.delta[j] = j == k - 1 ? false : fresh.delta[j];
            }
        }
        if (s == 1 && last) sh.nee_fwd = fresh.nee_fwd, sh.nee_rev = fresh.nee_rev;
        const float brute = rc_path_weight(&sh, e, s, dpa, epw, dpw, cos_cam, cos_light, power);
        struct restir_bdpt_mis at_k = rc_path_state(&sh, k, kind != RBDPT_RC_NEE_LAST, power);
        /* The kept suffix's flag (restir_bdpt_reuse.c: rc.mis_c joins the new prefix's). */
        at_k.caster = at_k.caster || rc_path_suffix_caster(&base, k, s == 0 ? e : e - 1);
        keeps_t1 += at_k.caster;
        const float fwd = kind == RBDPT_RC_NEE_LAST ? sh.nee_fwd : sh.pf[k];
        const float rev = kind == RBDPT_RC_NEE_LAST ? sh.nee_rev : sh.pr[k];
        const float rec = restir_bdpt_mis_reconnect(kind, a, b, &at_k, fwd, rev, power);
        const double rel = fabs((double)rec - brute) / brute;
        if (rel > worst) worst = rel;
        cases++;
        /* Another path's suffix constants (its own distances past x_k): the weight must move. */
        if (k + 2 < e && at_k.caster) {
            struct rc_path other = base;
            other.hit_cos[k + 1] *= 0.5f;
            float a2, b2;
            const float suffix2 = rc_path_suffix(&other, k, s == 0 ? e : e - 1, power);
            if (s == 0) {
                struct restir_bdpt_mis m = rc_path_state(&other, e, false, power);
                restir_bdpt_rc_mis_emission(&m, dpa, epw, other.hit_d2[e], other.hit_cos[e], last, suffix2, power, &a2,
                                            &b2);
            } else {
                restir_bdpt_rc_mis_nee(other.nee_fwd, other.nee_rev, dpw, epw, cos_cam, cos_light, last, suffix2,
                                       power, &a2, &b2);
            }
            wrong_suffix_cases++;
            if (fabsf(restir_bdpt_mis_reconnect(kind, a2, b2, &at_k, fwd, rev, power) - brute) > 1e-3f * brute)
                wrong_suffix_differs++;
        }
    }
    printf("    %u reconnections (%u keep t = 1): worst relative error %.2g; another suffix's constants moved the "
           "weight in %u of %u\n",
           cases, keeps_t1, worst, wrong_suffix_differs, wrong_suffix_cases);
    CHECK(worst < 1e-4 && keeps_t1 > cases / 4 && keeps_t1 < cases * 3 / 4);
    CHECK(wrong_suffix_differs > wrong_suffix_cases / 2);
}

static void test_params(void)
{
    struct err err = {0};
    struct restir_bdpt_params p = restir_bdpt_defaults();
    CHECK(restir_bdpt_params_valid(&p, &err));
    p.variant = RESTIR_BDPT_FULL;
    CHECK(restir_bdpt_params_valid(&p, &err));
    p.reuse = true;
    CHECK(restir_bdpt_params_valid(&p, &err));
    p.copy_mis = true;   /* the full variant's shifts always recompute the MIS weight */
    CHECK(!restir_bdpt_params_valid(&p, &err) && strcmp(err.where, "/params/copy_mis") == 0 &&
          strstr(err.message, "lightweight variant"));
    p = restir_bdpt_defaults();
    p.lvc_capacity = 65;
    CHECK(!restir_bdpt_params_valid(&p, &err) && strcmp(err.where, "/params/lvc_capacity") == 0);
    p = restir_bdpt_defaults();
    p.lt_capacity = 0;
    CHECK(!restir_bdpt_params_valid(&p, &err) && strcmp(err.where, "/params/lt_capacity") == 0);
    p = restir_bdpt_defaults();
    p.max_depth = 0;
    CHECK(!restir_bdpt_params_valid(&p, &err) && strcmp(err.where, "/params/max_depth") == 0);
    p.max_depth = RESTIR_BDPT_MAX_DEPTH;  /* the deepest a sample's 8-bit vertex count holds */
    CHECK(restir_bdpt_params_valid(&p, &err));
    p.max_depth = RESTIR_BDPT_MAX_DEPTH + 1;
    CHECK(!restir_bdpt_params_valid(&p, &err) && strcmp(err.where, "/params/max_depth") == 0);

    struct scene *sc = fixture_load("scenes/caustic-sphere/scene.json");
    if (!sc) return;
    p = restir_bdpt_defaults();
    p.light_paths = 1000;
    struct restir_bdpt_state st;
    CHECK(restir_bdpt_init(&st, sc, &p, 40, 24, &err));
    CHECK(restir_bdpt_bytes(&st) == restir_bdpt_bytes_planned(&p, sc, 40, 24));
    restir_bdpt_destroy(&st);
    /* With reuse, the emission seen directly is estimated apart where a shape emits, and a scene
     * without one (a dark box: restir_bdpt takes no environment light) keeps no buffers for it. */
    p.reuse = true;
    CHECK(restir_bdpt_init(&st, sc, &p, 40, 24, &err));
    CHECK_MSG(st.gbuf[0].emission != NULL, "caustic-sphere, reuse: no emission buffer");
    CHECK(restir_bdpt_bytes(&st) == restir_bdpt_bytes_planned(&p, sc, 40, 24));
    restir_bdpt_destroy(&st);
    scene_release(sc);
    struct scene *dark = fixture_load_json(
        "{\"format\": 1, \"camera\": {\"position\": [0, 0, 3], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], \"fov_deg\": 40},"
        " \"materials\": {\"grey\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}},"
        " \"shapes\": [{\"type\": \"quad\", \"material\": \"grey\","
        " \"vertices\": [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]}]}", ".");
    if (!dark) return;
    CHECK(restir_bdpt_init(&st, dark, &p, 40, 24, &err));
    CHECK_MSG(st.gbuf[0].emission == NULL, "no emitting shape, reuse: an emission buffer all the same");
    CHECK(restir_bdpt_bytes(&st) == restir_bdpt_bytes_planned(&p, dark, 40, 24));
    restir_bdpt_destroy(&st);
    scene_release(dark);
}

struct series {
    uint32_t n;          /* frames */
    double *sum, *sum2;  /* per pixel, luminance */
    double *img_means;   /* per frame: mean luminance of the image */
};

/* `frames` independent frames (no reuse) of restir_bdpt or of bdpt: per-pixel sums. */
static bool render_series(const struct scene *sc, const struct camera_desc *cam, bool restir, uint32_t w, uint32_t h,
                          uint32_t frames, uint32_t light_paths, uint64_t seed, struct series *out,
                          struct restir_bdpt_stats *last)
{
    struct err err = {0};
    struct image img;
    if (!image_init(&img, w, h, &err)) return false;
    out->n = frames;
    out->sum = calloc((size_t)w * h, sizeof(double));
    out->sum2 = calloc((size_t)w * h, sizeof(double));
    out->img_means = calloc(frames, sizeof(double));
    struct restir_bdpt_params rp = restir_bdpt_defaults();
    struct bdpt_params bp = bdpt_defaults();
    rp.light_paths = bp.light_paths = light_paths;
    struct restir_bdpt_state rs;
    struct bdpt_state bs;
    bool ok = restir ? restir_bdpt_init(&rs, sc, &rp, w, h, &err) : bdpt_init(&bs, sc, &bp, w, h, &err);
    CHECK_MSG(ok, "%s", err.message);
    if (!ok) return false;
    rp.caustic_temporal = false;
    for (uint32_t f = 0; f < frames && ok; f++) {
        if (restir) {
            struct method_frame fr = {.scene = sc, .camera = cam, .seed = seed, .frame = f, .threads = 2};
            ok = restir_bdpt_render(&rs, &rp, &fr, &img, last, &err);
        } else {
            struct method_frame fr = {.scene = sc, .camera = cam, .seed = seed, .frame = f, .threads = 2};
            ok = bdpt_render(&bs, &bp, &fr, &img, NULL, &err);
        }
        CHECK_MSG(ok, "%s", err.message);
        double m = 0.0;
        for (uint32_t i = 0; i < w * h; i++) {
            double v = vec3_luminance(img.pixels[i]);
            out->sum[i] += v;
            out->sum2[i] += v * v;
            m += v;
        }
        out->img_means[f] = m / (w * h);
    }
    if (restir) restir_bdpt_destroy(&rs); else bdpt_destroy(&bs);
    image_destroy(&img);
    return ok;
}

static void series_free(struct series *s)
{
    free(s->sum);
    free(s->sum2);
    free(s->img_means);
}

/* The z-test of `a` (scaled by `scale`) against `b`; prints and returns whether it passed. */
static bool ztest(const struct series *a, const struct series *b, uint32_t npix, double scale, const char *label)
{
    double alpha = 1.0 - pow(0.99, 1.0 / npix);  /* Šidák */
    uint32_t pass = 0;
    for (uint32_t i = 0; i < npix; i++) {
        double ma = a->sum[i] / a->n * scale, mb = b->sum[i] / b->n;
        /* Variances of the two means: (E[x^2] - mean^2) / (n - 1). */
        double va = (a->sum2[i] / a->n * scale * scale - ma * ma) / (a->n - 1);
        double vb = (b->sum2[i] / b->n - mb * mb) / (b->n - 1);
        double se = sqrt((va > 0 ? va : 0) + (vb > 0 ? vb : 0));
        if (se == 0.0) {
            pass += fabs(ma - mb) <= 1e-12 * (fabs(ma) + fabs(mb) + 1e-30);
            continue;
        }
        double p = erfc(fabs(ma - mb) / se / sqrt(2.0));
        pass += p > alpha;
    }
    double ga = 0, ga2 = 0, gb = 0, gb2 = 0;
    for (uint32_t f = 0; f < a->n; f++) { double v = a->img_means[f] * scale; ga += v; ga2 += v * v; }
    for (uint32_t f = 0; f < b->n; f++) { double v = b->img_means[f]; gb += v; gb2 += v * v; }
    ga /= a->n;
    gb /= b->n;
    double gse = sqrt((ga2 / a->n - ga * ga) / (a->n - 1) + (gb2 / b->n - gb * gb) / (b->n - 1));
    double gz = (ga - gb) / gse;
    double frac = (double)pass / npix;
    bool ok = frac >= 0.9975 && fabs(gz) <= 3.0;
    printf("    %s: %.2f %% of pixels pass, image mean %.5g +- %.2g vs %.5g +- %.2g (z = %.2f): %s\n", label,
           100.0 * frac, ga, sqrt((ga2 / a->n - ga * ga) / (a->n - 1)), gb, sqrt((gb2 / b->n - gb * gb) / (b->n - 1)),
           gz, ok ? "accepted" : "rejected");
    return ok;
}

static void compare(const char *scene_path, const struct camera_desc *crop, uint32_t frames_r, uint32_t frames_b,
                    uint32_t light_paths)
{
    SKIP_IF_SANITIZED();
    struct scene *sc = fixture_load(scene_path);
    if (!sc) return;
    const struct camera_desc *cam = crop ? crop : &sc->camera;
    const uint32_t w = 32, h = 32;
    struct series a = {0}, b = {0};
    struct restir_bdpt_stats st = {0};
    bool ok = render_series(sc, cam, true, w, h, frames_r, light_paths, 11, &a, &st) &&
              render_series(sc, cam, false, w, h, frames_b, light_paths, 12, &b, NULL);
    if (ok) {
        printf("    %s: light-traced %llu (caustic %llu) in the last frame, dropped %llu\n", scene_path,
               (unsigned long long)st.light_traced, (unsigned long long)st.caustic_samples,
               (unsigned long long)st.lt_dropped);
        CHECK(st.light_traced > 0 && st.lt_dropped == 0 && st.rejected == 0);
        CHECK_MSG(ztest(&a, &b, w * h, 1.0, scene_path), "%s: restir_bdpt differs from bdpt", scene_path);
        CHECK_MSG(!ztest(&a, &b, w * h, 1.03, "x1.03"), "%s: a bias of x1.03 went unseen", scene_path);
    }
    series_free(&a);
    series_free(&b);
    scene_release(sc);
}

/* The crop: the floor beside the glass sphere, with the caustic, from where the sphere itself is
 * out of view (seen through the sphere, the small bright light is reachable by emitter hits
 * only, with weight 1 in both methods: fireflies that hide a bias of a few percent). */
static void test_matches_bdpt_caustic_sphere(void)
{
    struct camera_desc crop = {.position = {-2.0f, 0.6f, -0.1f}, .look_at = {-0.45f, 0, -0.05f}, .up = {0, 1, 0},
                               .fov_deg = 6};
    compare("scenes/caustic-sphere/scene.json", &crop, 1024, 1024, 8192);
}

/* The lamp's table top under the shade, lit mostly by light-traced samples: the crop of the
 * unbiasedness tests (tests/test_restir_bdpt.py) and of the shift tests below. */
static const struct camera_desc LAMP_CROP = {.position = {0, 1.45f, -1.8f}, .look_at = {0, 0.68f, 1.2f},
                                             .up = {0, 1, 0}, .fov_deg = 4};

static void test_matches_bdpt_lamp_in_glass(void)
{
    compare("scenes/lamp-in-glass/scene.json", &LAMP_CROP, 1024, 1024, 0);
}

/* The random-replay shift: replaying a caustic sample in its own frame gives back its pixel and
 * contribution exactly; replayed into a moved camera and back, again exactly (T^-1 T = id; the
 * Jacobian in primary sample space is 1 by construction). */
static void test_caustic_replay_round_trip(void)
{
    struct scene *sc = fixture_load("scenes/caustic-sphere/scene.json");
    if (!sc) return;
    struct err err = {0};
    struct restir_bdpt_params p = restir_bdpt_defaults();
    p.light_paths = 8192;
    struct camera_desc a = {.position = {-2.0f, 0.6f, -0.1f}, .look_at = {-0.45f, 0, -0.05f}, .up = {0, 1, 0},
                            .fov_deg = 6};
    struct camera_desc b = a;
    b.position.x += 0.01f;
    b.look_at.z += 0.01f;
    struct restir_bdpt_state st;
    struct image img;
    CHECK(image_init(&img, 32, 32, &err));
    CHECK(restir_bdpt_init(&st, sc, &p, 32, 32, &err));
    struct method_frame fa = {.scene = sc, .camera = &a, .seed = 3, .frame = 7, .threads = 2};
    struct method_frame fb = fa;
    fb.camera = &b;
    CHECK_MSG(restir_bdpt_render(&st, &p, &fa, &img, NULL, &err), "%s", err.message);
    uint32_t tried = 0, moved = 0;
    for (uint32_t px = 0; px < 32 * 32; px++) {
        const struct restir_bdpt_reservoir *r = &st.caustic_prev[px];   /* the frame just rendered */
        if (!(r->head.W > 0.0f)) continue;
        uint32_t depth = (uint32_t)(r->head.bits >> 8) - 1u, q = 0, q2 = 0, q3 = 0;
        struct vec3 F, F2, F3;
        CHECK((r->head.bits & 0xffu) == RESTIR_BDPT_TECH_LT && r->origin_frame == 7);
        CHECK(restir_bdpt_caustic_replay(&st, &p, &fa, 7, r->light_path, depth, &q, &F));
        CHECK(q == px && memcmp(&F, &r->F, sizeof F) == 0);
        tried++;
        if (!restir_bdpt_caustic_replay(&st, &p, &fb, 7, r->light_path, depth, &q2, &F2)) continue;
        moved += q2 != px;
        CHECK(restir_bdpt_caustic_replay(&st, &p, &fa, 7, r->light_path, depth, &q3, &F3));
        CHECK(q3 == px && memcmp(&F3, &r->F, sizeof F) == 0);
    }
    printf("    %u caustic samples replayed, %u landed in another pixel with the moved camera\n", tried, moved);
    CHECK(tried > 10 && moved > 0);
    restir_bdpt_destroy(&st);
    image_destroy(&img);
    scene_release(sc);
}

/* The non-caustic shifts with reuse, on the samples a few frames leave in the reservoirs: each
 * shifted into the pixel (3, 1) away in the same frame and back gives its own target again, and
 * the two Jacobians multiply to 1 — for the hybrid shift of camera-side samples, the reverse
 * hybrid shift of light-traced ones and random replay alike. Both kinds of reconnection must
 * occur. With `copy_mis` the same holds for the variant that keeps the base path's MIS weight,
 * and for light-traced samples that weight must differ from the recomputed one in most reverse
 * hybrid shifts (else the variant would copy nothing). With `full` the full variant's, whose
 * connections (s >= 2) shift their light subpath by random replay and their camera subpath by
 * the hybrid shift or random replay (kinds 4 and 3). need[kind]: round trips required. */
static void shift_round_trips(const char *path, struct camera_desc cam, uint32_t light_paths, const uint32_t need[5],
                              const char *light_name, bool copy_mis, bool full, bool canonical)
{
    struct scene *sc = fixture_load(path);
    if (!sc) return;
    struct err err = {0};
    struct restir_bdpt_params p = restir_bdpt_defaults();
    p.reuse = true;
    p.copy_mis = copy_mis;
    p.light_paths = light_paths;
    if (full) p.variant = RESTIR_BDPT_FULL;
    /* canonical: one frame without spatial reuse, so each reservoir holds a sample as the camera
     * pass made it (its target computed there), which the shift back must reproduce. */
    if (canonical) p.spatial_neighbors = 0;
    struct restir_bdpt_params p_recompute = p;
    p_recompute.copy_mis = false;
    const uint32_t W = 32, H = 32;
    struct restir_bdpt_state st;
    struct image img;
    CHECK(image_init(&img, W, H, &err));
    CHECK(restir_bdpt_init(&st, sc, &p, W, H, &err));
    struct method_frame f = {.scene = sc, .camera = &cam, .seed = 5, .frame = 0, .threads = 2};
    for (uint32_t k = 0; k < (canonical ? 1u : 4u); k++) {
        f.frame = k;
        f.prev_scene = k ? sc : NULL;
        f.prev_camera = k ? &cam : NULL;
        CHECK_MSG(restir_bdpt_render(&st, &p, &f, &img, NULL, &err), "%s", err.message);
    }
    /* With light_name: into a scene whose light moved (and back), in the same pixel: the hybrid
     * shift traces a reconnected sample's suffix again there. */
    struct scene *moved = NULL;
    if (light_name) {
        int light = scene_find_shape(sc, light_name);
        CHECK(light >= 0);
        struct scene_shape_override o = {.shape = (uint32_t)light, .has_to_world = true};
        o.to_world = sc->shapes[light].to_world;
        o.to_world.m[0][3] += 0.02f;
        o.to_world.m[1][3] += 0.01f;
        moved = scene_derive(sc, &o, 1, &err);
        CHECK_MSG(moved != NULL, "%s", err.message);
        if (!moved) return;
    }
    struct method_frame f_moved = f;
    f_moved.scene = moved;
    uint32_t there[5] = {0}, back[5] = {0}, wrong = 0, copied = 0, differs = 0;
    double worst = 0.0;
    for (uint32_t y = 0; y + 1 < H; y++) {
        for (uint32_t x = 0; x + 3 < W; x++) {
            float t[3], jj;
            int kind = moved ? restir_bdpt_shift_round_trip(&st, &p, &f, &f_moved, y * W + x, y * W + x, t, &jj)
                             : restir_bdpt_shift_round_trip(&st, &p, &f, NULL, y * W + x, (y + 1) * W + x + 3, t, &jj);
            if (kind < 0 || !(t[1] > 0.0f)) continue;
            there[kind]++;
            if (!(t[2] > 0.0f)) continue;
            back[kind]++;
            double e = fmax(fabs((double)t[2] - t[0]) / t[0], fabs((double)jj - 1.0));
            if (e > worst) worst = e;
            wrong += e > 2e-3;
            if (copy_mis && kind == 1) {
                /* The same light-traced sample's reverse hybrid shift with its weight recomputed. */
                float tr[3], jr;
                restir_bdpt_shift_round_trip(&st, &p_recompute, &f, NULL, y * W + x, (y + 1) * W + x + 3, tr, &jr);
                copied++;
                differs += fabs((double)tr[1] - t[1]) > 1e-3 * t[1];
            }
        }
    }
    if (copy_mis) {
        printf("    copy_mis: the recomputed weight differs from the copied one in %u of %u reverse hybrid shifts\n", differs,
               copied);
        CHECK(copied > 0 && differs * 2 > copied);
    }
    printf("    %s%s%s: shifted there / and back: reverse hybrid %u / %u, hybrid %u / %u, replay %u / %u, "
           "connection by replay %u / %u, by the hybrid shift %u / %u; worst relative error %.2g, %u over 2e-3\n",
           path, full ? " (full)" : "", moved ? ", light moved" : "", there[1], back[1], there[2], back[2], there[0],
           back[0], there[3], back[3], there[4], back[4], worst, wrong);
    for (int k = 0; k < 5; k++) CHECK(there[k] >= need[k] && back[k] * 100 >= there[k] * 99);
    CHECK(wrong == 0);
    restir_bdpt_destroy(&st);
    image_destroy(&img);
    if (moved) scene_release(moved);
    scene_release(sc);
}

static void test_shift_round_trips(void)
{
    /* The crops of the unbiasedness tests: the lamp's table top, lit mostly by light-traced
     * samples; the caustic sphere's floor. */
    shift_round_trips("scenes/lamp-in-glass/scene.json", LAMP_CROP, 0, (uint32_t[5]){20, 20, 20, 0, 0}, NULL, false,
                      false, false);
    shift_round_trips("scenes/caustic-sphere/scene.json",
                      (struct camera_desc){.position = {-2.0f, 0.6f, -0.1f}, .look_at = {-0.45f, 0, -0.05f},
                                           .up = {0, 1, 0}, .fov_deg = 6},
                      8192, (uint32_t[5]){5, 0, 20, 0, 0}, NULL, false, false, false);
    shift_round_trips("scenes/caustic-sphere/scene.json",
                      (struct camera_desc){.position = {-2.0f, 0.6f, -0.1f}, .look_at = {-0.45f, 0, -0.05f},
                                           .up = {0, 1, 0}, .fov_deg = 6},
                      8192, (uint32_t[5]){5, 0, 20, 0, 0}, "light", false, false, false);
    shift_round_trips("scenes/lamp-in-glass/scene.json", LAMP_CROP, 0, (uint32_t[5]){20, 20, 20, 0, 0}, NULL, true,
                      false, false);
    /* cornell-glossy's back wall and gold sphere: the sphere (GGX 0.02) is rough enough to be a
     * reconnection vertex and a caustic caster, so a reconnected path keeps t = 1 through its
     * x_k alone (rbdpt_mis_vertex), which its shift must count as the camera pass did. */
    shift_round_trips("scenes/cornell-glossy/scene.json",
                      (struct camera_desc){.position = {278, 273, -800}, .look_at = {186, 225, 168}, .up = {0, 1, 0},
                                           .fov_deg = 25},
                      0, (uint32_t[5]){5, 0, 20, 0, 0}, NULL, false, false, true);
    /* The full variant on the lamp's table top, in one frame and into the frame whose lamp moved. */
    shift_round_trips("scenes/lamp-in-glass/scene.json", LAMP_CROP, 0, (uint32_t[5]){1, 1, 1, 1, 1}, NULL, false, true, false);
    shift_round_trips("scenes/lamp-in-glass/scene.json", LAMP_CROP, 0, (uint32_t[5]){1, 1, 1, 1, 1}, "filament", false,
                      true, false);
}

/* The full variant's recursive reconnection MIS: the reconnected samples a few frames leave in
 * the reservoirs of lamp-in-glass, shifted 3 px away with their suffix's constants (what w_k
 * carries back and the three MIS constants), get the target and Jacobian of the same shift
 * with the suffix traced again from x_k — whose weight is bdpt's forward recursion over the
 * whole new path (test_mis_full checks that against brute force). Camera-side samples and
 * connections must both occur, and the constants must matter: the weights differ from the
 * unshifted ones. */
static void test_full_reconnect_mis(void)
{
    struct scene *sc = fixture_load("scenes/lamp-in-glass/scene.json");
    if (!sc) return;
    struct err err = {0};
    const struct camera_desc *cam = &LAMP_CROP;
    struct restir_bdpt_params p = restir_bdpt_defaults();
    p.reuse = true;
    p.variant = RESTIR_BDPT_FULL;
    const uint32_t W = 32, H = 32;
    struct restir_bdpt_state st;
    struct image img;
    CHECK(image_init(&img, W, H, &err));
    CHECK_MSG(restir_bdpt_init(&st, sc, &p, W, H, &err), "%s", err.message);
    struct method_frame f = {.scene = sc, .camera = cam, .seed = 7, .threads = 2};
    for (uint32_t k = 0; k < 4; k++) {
        f.frame = k;
        f.prev_scene = k ? sc : NULL;
        f.prev_camera = k ? cam : NULL;
        CHECK_MSG(restir_bdpt_render(&st, &p, &f, &img, NULL, &err), "%s", err.message);
    }
    uint32_t agree[5] = {0}, one_failed = 0, changed = 0, n = 0;
    double worst = 0.0;
    for (uint32_t y = 0; y + 1 < H; y++) {
        for (uint32_t x = 0; x + 3 < W; x++) {
            float t[2], j[2];
            int kind = restir_bdpt_shift_retrace_pair(&st, &p, &f, y * W + x, (y + 1) * W + x + 3, t, j);
            if (kind < 0 || (!(t[0] > 0.0f) && !(t[1] > 0.0f))) continue;
            n++;
            if (!(t[0] > 0.0f) || !(t[1] > 0.0f)) {
                one_failed++;
                continue;
            }
            double e = fmax(fabs((double)t[0] - t[1]) / t[1], fabs((double)j[0] - j[1]) / j[1]);
            if (e > worst) worst = e;
            agree[kind] += e < 1e-4;
            /* The shifted target differs from the base path's (new prefix, new weight). */
            changed += fabs((double)t[0] - vec3_luminance(st.res_prev[y * W + x].r.F)) > 1e-3 * t[0];
        }
    }
    printf("    full variant: %u reconnection shifts, camera-side %u and connections %u agree with the retraced "
           "suffix (worst relative difference %.2g), %u failed one way only, %u changed the target\n",
           n, agree[2], agree[4], worst, one_failed, changed);
    CHECK(agree[2] >= 5 && agree[4] >= 20);
    CHECK(agree[2] + agree[4] + one_failed == n && one_failed * 100 <= n);
    CHECK(changed * 2 > agree[2] + agree[4]);
    restir_bdpt_destroy(&st);
    image_destroy(&img);
    scene_release(sc);
}

/* The x_2 cache of the reverse hybrid shift only saves replays: the same session rendered with
 * the cache and without it (its buffer withheld) gives bit-identical frames, and with it fewer
 * rays (else the cache would never be hit). With 3 spatial rounds (the converge profile's), the
 * later rounds read the entries of the round before. */
static void x2_cache_case(enum restir_bdpt_variant variant, uint32_t rounds)
{
    struct scene *sc = fixture_load("scenes/lamp-in-glass/scene.json");
    if (!sc) return;
    struct err err = {0};
    struct restir_bdpt_params p = restir_bdpt_defaults();
    p.reuse = true;
    p.variant = variant;
    p.spatial_rounds = rounds;
    const uint32_t W = 32, H = 32;
    struct image img[2];
    uint64_t rays[2] = {0, 0};
    for (int cached = 0; cached < 2; cached++) {
        struct restir_bdpt_state st;
        CHECK(image_init(&img[cached], W, H, &err));
        CHECK_MSG(restir_bdpt_init(&st, sc, &p, W, H, &err), "%s", err.message);
        struct rbdpt_x2_entry *keep = st.x2c;
        CHECK(keep != NULL);
        if (!cached) st.x2c = NULL;
        for (uint32_t k = 0; k < 4; k++) {
            struct method_frame f = {.scene = sc, .camera = &LAMP_CROP, .prev_scene = k ? sc : NULL,
                                          .prev_camera = k ? &LAMP_CROP : NULL, .seed = 9, .frame = k, .threads = 2};
            struct restir_bdpt_stats s;
            CHECK_MSG(restir_bdpt_render(&st, &p, &f, &img[cached], &s, &err), "%s", err.message);
            rays[cached] += s.rays_intersect;
        }
        st.x2c = keep;
        restir_bdpt_destroy(&st);
    }
    printf("    %s, %u spatial round(s), 4 frames: %llu rays without the cache, %llu with it\n",
           restir_bdpt_variant_name(variant), rounds, (unsigned long long)rays[0], (unsigned long long)rays[1]);
    CHECK(memcmp(img[0].pixels, img[1].pixels, (size_t)W * H * sizeof *img[0].pixels) == 0);
    CHECK(rays[1] < rays[0]);
    image_destroy(&img[0]);
    image_destroy(&img[1]);
    scene_release(sc);
}

/* The same for the full variant, whose cache also keeps the light vertices of connections. */
static void test_x2_cache_changes_nothing(void)
{
    x2_cache_case(RESTIR_BDPT_LIGHTWEIGHT, 1);
    x2_cache_case(RESTIR_BDPT_FULL, 1);
    x2_cache_case(RESTIR_BDPT_LIGHTWEIGHT, 3);
    x2_cache_case(RESTIR_BDPT_FULL, 3);
}

/* A still view's shortcuts (a history sample shifted into its own pixel taken as evaluated the
 * render before, caustic replays taken as stored) only save work: a session rendered with them
 * and with them withheld gives bit-identical frames, and with them fewer rays (else they were
 * never taken). The camera moves once, at frame 3, so that a still run ends and a new one begins
 * (frame 3 renders in full, frames 4 and 5 are still again). */
static void still_case(enum restir_bdpt_variant variant)
{
    struct scene *sc = fixture_load("scenes/lamp-in-glass/scene.json");
    if (!sc) return;
    struct camera_desc moved = LAMP_CROP;
    moved.position.x += 0.01f;
    struct err err = {0};
    struct restir_bdpt_params p = restir_bdpt_defaults();
    p.variant = variant;
    const uint32_t W = 32, H = 32, FRAMES = 6;
    struct image img[2];
    uint64_t rays[2] = {0, 0};
    bool same_frames = true;
    struct restir_bdpt_state st[2];
    for (int k = 0; k < 2; k++) {
        CHECK(image_init(&img[k], W, H, &err));
        CHECK_MSG(restir_bdpt_init(&st[k], sc, &p, W, H, &err), "%s", err.message);
    }
    st[0].still_withheld = true;
    for (uint32_t f = 0; f < FRAMES; f++) {
        const struct camera_desc *cam = f < 3 ? &LAMP_CROP : &moved;
        const struct camera_desc *prev = f == 0 ? NULL : f - 1 < 3 ? &LAMP_CROP : &moved;
        struct method_frame fr = {.scene = sc, .camera = cam, .prev_scene = f ? sc : NULL, .prev_camera = prev,
                                  .seed = 5, .frame = f, .threads = 2};
        for (int k = 0; k < 2; k++) {
            struct restir_bdpt_stats s;
            CHECK_MSG(restir_bdpt_render(&st[k], &p, &fr, &img[k], &s, &err), "%s", err.message);
            rays[k] += s.rays_intersect + s.rays_occluded;
        }
        same_frames = same_frames && memcmp(img[0].pixels, img[1].pixels, (size_t)W * H * sizeof *img[0].pixels) == 0;
    }
    printf("    %s, %u frames: %llu rays with the shortcuts withheld, %llu with them\n",
           restir_bdpt_variant_name(variant), FRAMES, (unsigned long long)rays[0], (unsigned long long)rays[1]);
    CHECK(same_frames);
    CHECK(rays[1] < rays[0]);
    for (int k = 0; k < 2; k++) {
        restir_bdpt_destroy(&st[k]);
        image_destroy(&img[k]);
    }
    scene_release(sc);
}

static void test_still_shortcuts_change_nothing(void)
{
    still_case(RESTIR_BDPT_LIGHTWEIGHT);
    still_case(RESTIR_BDPT_FULL);
}

/* Paired: the same sessions (same seeds, so the same non-caustic reservoirs frame by frame) with
 * caustic temporal reuse on and off; the difference of their images is the difference of the
 * caustic estimates alone, which must be 0 in expectation. With `moving`, the light slides and
 * the camera pans from frame to frame (derived scenes, as a session's animation makes them), so
 * replayed caustics move between pixels and the eq. 51–52 weights see different targets in the
 * two frames. */
static void caustic_temporal_paired(bool moving)
{
    SKIP_IF_SANITIZED();
    enum { FRAMES = 8 };
    struct scene *base = fixture_load("scenes/caustic-sphere/scene.json");
    if (!base) return;
    struct err err = {0};
    struct scene *scenes[FRAMES];
    struct camera_desc cams[FRAMES];
    int light = scene_find_shape(base, "light");
    CHECK(light >= 0);
    for (uint32_t f = 0; f < FRAMES; f++) {
        cams[f] = (struct camera_desc){.position = {-2.0f, 0.6f, -0.1f}, .look_at = {-0.45f, 0, -0.05f},
                                       .up = {0, 1, 0}, .fov_deg = 6};
        scenes[f] = base;
        if (!moving) continue;
        cams[f].look_at.z += 0.004f * (float)f;
        struct scene_shape_override o = {.shape = (uint32_t)light, .has_to_world = true};
        o.to_world = base->shapes[light].to_world;
        o.to_world.m[0][3] += 0.03f * (float)f;
        o.to_world.m[2][3] -= 0.02f * (float)f;
        scenes[f] = scene_derive(base, &o, 1, &err);
        CHECK_MSG(scenes[f] != NULL, "%s", err.message);
        if (!scenes[f]) return;
    }
    const uint32_t w = 32, h = 32, sessions = 128, avg = 6;
    struct image img;
    CHECK(image_init(&img, w, h, &err));
    struct restir_bdpt_state st;
    struct restir_bdpt_params p = restir_bdpt_defaults();
    p.light_paths = 8192;
    CHECK(restir_bdpt_init(&st, base, &p, w, h, &err));
    double sd = 0, sd2 = 0, sc2 = 0, sc22 = 0, son = 0, soff = 0;
    struct restir_bdpt_stats last = {0};
    for (uint32_t k = 0; k < sessions; k++) {
        double m[2] = {0, 0};
        for (int on = 0; on < 2; on++) {
            p.caustic_temporal = on;
            restir_bdpt_reset(&st);
            for (uint32_t f = 0; f < FRAMES; f++) {
                struct method_frame fr = {.scene = scenes[f], .camera = &cams[f],
                                               .prev_scene = f ? scenes[f - 1] : NULL,
                                               .prev_camera = f ? &cams[f - 1] : NULL, .seed = 500 + k, .frame = f,
                                               .threads = 2};
                CHECK(restir_bdpt_render(&st, &p, &fr, &img, on ? &last : NULL, &err));
                if (f + avg < FRAMES) continue;
                for (uint32_t i = 0; i < w * h; i++) m[on] += vec3_luminance(img.pixels[i]) / (avg * w * h);
            }
        }
        double d = m[1] - m[0], dc = 1.03 * m[1] - m[0];
        sd += d;
        sd2 += d * d;
        sc2 += dc;
        sc22 += dc * dc;
        son += m[1];
        soff += m[0];
    }
    double md = sd / sessions, se = sqrt((sd2 / sessions - md * md) / (sessions - 1));
    double mc = sc2 / sessions, sec = sqrt((sc22 / sessions - mc * mc) / (sessions - 1));
    printf("    %s, %u sessions: on %.5f, off %.5f: difference %.5f +- %.5f (z = %.2f); on x1.03: z = %.2f\n",
           moving ? "moving" : "static", sessions, son / sessions, soff / sessions, md, se, md / se, mc / sec);
    printf("    last frame: caustic shifts %llu, replay failed %llu, turned rough %llu, no predecessor %llu\n",
           (unsigned long long)last.caustic_shifts, (unsigned long long)last.caustic_replay_failed,
           (unsigned long long)last.caustic_not_caustic, (unsigned long long)last.caustic_inverse_failed);
    CHECK(last.caustic_shifts > 0);
    CHECK_MSG(fabs(md / se) <= 3.0, "caustic temporal reuse changed the image's mean: z = %.2f", md / se);
    CHECK_MSG(fabs(mc / sec) > 3.0, "a bias of x1.03 went unseen: z = %.2f", mc / sec);
    restir_bdpt_destroy(&st);
    image_destroy(&img);
    if (moving)
        for (uint32_t f = 0; f < FRAMES; f++) scene_release(scenes[f]);
    scene_release(base);
}

static void test_caustic_temporal_paired(void) { caustic_temporal_paired(false); }
static void test_caustic_temporal_paired_moving(void) { caustic_temporal_paired(true); }

/* The largest confidence of the frame just rendered (whose caustic reservoirs the frame's end
 * swapped into caustic_prev, the next frame's history). */
static uint32_t max_caustic_m(const struct restir_bdpt_state *st)
{
    uint32_t m = 0;
    for (uint32_t i = 0; i < st->width * st->height; i++)
        if (st->caustic_prev[i].head.M > m) m = st->caustic_prev[i].head.M;
    return m;
}

/* The caustic confidence grows up to temporal_cap over still frames, is capped at moving_cap in
 * a frame whose light moved, and grows again from there once the scene is still. */
static void test_moving_cap(void)
{
    struct scene *base = fixture_load("scenes/caustic-sphere/scene.json");
    if (!base) return;
    struct err err = {0};
    int light = scene_find_shape(base, "light");
    CHECK(light >= 0);
    struct scene_shape_override o = {.shape = (uint32_t)light, .has_to_world = true};
    o.to_world = base->shapes[light].to_world;
    o.to_world.m[0][3] += 0.03f;
    struct scene *moved = scene_derive(base, &o, 1, &err);
    CHECK_MSG(moved != NULL, "%s", err.message);
    if (!moved) return;
    struct restir_bdpt_params p = restir_bdpt_defaults();
    CHECK(p.moving_cap == 1);   /* the default; 4 here, so that the cap shows in the confidences */
    p.temporal_cap = 7;
    p.moving_cap = 4;
    struct image img;
    CHECK(image_init(&img, 24, 20, &err));
    struct restir_bdpt_state st;
    CHECK(restir_bdpt_init(&st, base, &p, 24, 20, &err));
    const struct scene *seq[12] = {base, base, base, base, base, base, base, base, base, moved, moved, moved};
    uint32_t m[12];
    for (uint32_t f = 0; f < 12; f++) {
        struct method_frame fr = {.scene = seq[f], .camera = &base->camera, .prev_scene = f ? seq[f - 1] : NULL,
                                       .prev_camera = f ? &base->camera : NULL, .seed = 9, .frame = f, .threads = 2};
        CHECK_MSG(restir_bdpt_render(&st, &p, &fr, &img, NULL, &err), "%s", err.message);
        m[f] = max_caustic_m(&st);
    }
    printf("    largest caustic confidence per frame:");
    for (uint32_t f = 0; f < 12; f++) printf(" %u", m[f]);
    printf("\n");
    CHECK(m[0] == 1 && m[8] == 7);       /* still: 1, 2, ... up to temporal_cap */
    CHECK(m[9] == 4);                    /* the light moved: moving_cap */
    CHECK(m[10] == 5 && m[11] == 6);     /* still again: growing from there */
    restir_bdpt_destroy(&st);
    image_destroy(&img);
    scene_release(moved);
    scene_release(base);
}

static void test_thread_determinism(void)
{
    struct scene *sc = fixture_load("scenes/caustic-sphere/scene.json");
    if (!sc) return;
    struct err err = {0};
    struct restir_bdpt_params p = restir_bdpt_defaults();
    struct image img[2];
    for (int k = 0; k < 2; k++) {
        CHECK(image_init(&img[k], 24, 20, &err));
        struct restir_bdpt_state st;
        CHECK(restir_bdpt_init(&st, sc, &p, 24, 20, &err));
        for (uint32_t f = 0; f < 3; f++) {
            struct method_frame fr = {.scene = sc, .camera = &sc->camera, .prev_scene = f ? sc : NULL,
                                           .prev_camera = f ? &sc->camera : NULL, .seed = 5, .frame = f,
                                           .threads = k ? 2u : 1u};
            CHECK_MSG(restir_bdpt_render(&st, &p, &fr, &img[k], NULL, &err), "%s", err.message);
        }
        restir_bdpt_destroy(&st);
    }
    CHECK(memcmp(img[0].pixels, img[1].pixels, 24 * 20 * sizeof *img[0].pixels) == 0);
    double sum = 0;
    for (uint32_t i = 0; i < 24 * 20; i++) sum += img[0].pixels[i].x;
    CHECK(sum > 0);
    image_destroy(&img[0]);
    image_destroy(&img[1]);
    scene_release(sc);
}

/* restir_bdpt as a view's method: planned = allocated (default and a given N_L and capacity),
 * the buffers by name, the frame counters; environment light and translucent scenes refused. */
static void test_view_method(void)
{
    struct scene *sc = fixture_load("scenes/caustic-sphere/scene.json");
    if (!sc) return;
    struct err err = {0};
    for (int k = 0; k < 5; k++) {
        struct view_params vp = view_params_defaults(method_find("restir_bdpt"), 40, 24);
        if (k == 1) {
            VIEW_METHOD_PARAMS(&vp, struct restir_bdpt_params)->light_paths = 1000;
            VIEW_METHOD_PARAMS(&vp, struct restir_bdpt_params)->lt_capacity = 3;
        }
        const bool reuse = k == 2 || k == 4, full = k >= 3;
        VIEW_METHOD_PARAMS(&vp, struct restir_bdpt_params)->reuse = reuse;
        if (full) {   /* the full variant, with its light vertex cache (k = 4: and reuse) */
            VIEW_METHOD_PARAMS(&vp, struct restir_bdpt_params)->variant = RESTIR_BDPT_FULL;
            VIEW_METHOD_PARAMS(&vp, struct restir_bdpt_params)->lvc_capacity = 5;
        }
        struct view v;
        CHECK_MSG(view_init(&v, sc, &vp, 2, &err), "%s", err.message);
        struct session_buffers sb;
        CHECK(session_buffers_agree(&v, &vp, sc, &sb));
        const size_t reservoirs = session_buffer(&sb, "reservoirs"), lvc = session_buffer(&sb, "light_vertex_cache");
        /* 4 blocks of 256 light subpaths, 5 vertices each of 52 bytes (with reuse 4 more, the
         * vertex's light subpath), and the block tables. */
        CHECK(lvc == (full ? 4u * 256 * 5 * (reuse ? 56 : 52) + 4 * 8 + 5 * 8 : 0u));
        /* Non-caustic reservoirs with their reconnections (three with reuse), two caustic ones. */
        CHECK(reservoirs == ((reuse ? 3u : 1u) * RESTIR_BDPT_PATH_BYTES + 2u * RESTIR_BDPT_RESERVOIR_BYTES) * 40 * 24);
        struct frame_stats fs = {0};
        for (int f = 0; f < 3; f++) CHECK_MSG(view_render(&v, NULL, &fs, NULL, NULL, &err), "%s", err.message);
        const struct restir_bdpt_stats *rs = (const struct restir_bdpt_stats *)(const void *)fs.counters;
        CHECK(rs->light_subpaths == (k == 1 ? 1000u : 40u * 24) && rs->light_vertices >= rs->light_traced);
        CHECK((rs->reuse_shifts > rs->reuse_shift_failures) == reuse);
        CHECK((rs->reuse_reconnections > 0) == reuse && rs->reuse_reconnections <= rs->reuse_shifts);
        CHECK(rs->light_traced > 0 && rs->caustic_samples > 0 && rs->caustic_shifts > 0 && rs->lt_dropped == 0);
        CHECK((rs->connections > 0) == full && rs->lvc_dropped == 0);
        CHECK(rs->reservoir_bytes == reservoirs && fs.render.nonfinite == 0 && fs.render.samples == 40 * 24);
        view_destroy(&v);
    }
    scene_release(sc);
    struct view_params vp = view_params_defaults(method_find("restir_bdpt"), 8, 8);
    struct view v;
    const char *refused[] = {"scenes/furnace/scene.json", "scenes/translucent/scene.json"};
    const char *why[] = {"environment", "subsurface"};
    for (int k = 0; k < 2; k++) {
        struct scene *bad = fixture_load(refused[k]);
        if (!bad) continue;
        CHECK_MSG(!view_init(&v, bad, &vp, 1, &err) && err.code == ERR_INVALID && strcmp(err.where, "/method") == 0 &&
                      strstr(err.message, why[k]),
                  "%s: %s", refused[k], err.message);
        scene_release(bad);
    }
}

TEST_MAIN(TEST(test_mis_lightweight), TEST(test_mis_full), TEST(test_mis_reconnect), TEST(test_params), TEST(test_view_method), TEST(test_thread_determinism),
          TEST(test_moving_cap),
          TEST(test_caustic_replay_round_trip), TEST(test_shift_round_trips), TEST(test_full_reconnect_mis), TEST(test_x2_cache_changes_nothing), TEST(test_still_shortcuts_change_nothing),
          TEST(test_matches_bdpt_caustic_sphere),
          TEST(test_matches_bdpt_lamp_in_glass), TEST(test_caustic_temporal_paired),
          TEST(test_caustic_temporal_paired_moving))
