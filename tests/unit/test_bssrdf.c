/* test_bssrdf.c — Burley diffusion and BSSRDF importance sampling (renderer/bssrdf.c) and the
 * probe query it relies on (accel_intersect_shape_all):
 * - the CDF is the integral of the profile pdf; sampled radii pass a chi-square test against
 *   that CDF, and the same test rejects radii drawn with a 5 % larger d (the test can fail);
 * - the 9-technique pdf over a flat plane: each normal-axis technique integrates to 1, the
 *   tangent axes to 0 (their probes run parallel to the plane), so the MIS sum to 1/2; real
 *   probes against a translucent quad find 1/2 hit per probe on average, and
 *   sum_j R(x_j) / pdf(x_j) estimates the profile's integral over the plane, 1;
 * - the same over a unit sphere whose profile reaches ~0.9 of its radius (strongly curved):
 *   quadrature of the MIS pdf over the sphere equals the mean number of probe hits, and the
 *   estimator equals the quadrature of the profile over the sphere, 1 (checked to fail, by
 *   2.6 / 1.7 / 1.3 against 1, when the pdf leaves out the tangent axes — which a plane cannot
 *   show, since those axes never reach it);
 * - probe hits come back ordered by distance on the one shape asked for;
 * - probabilistic inversion (seed 004 Algorithm 4) round trips, and it picks techniques in
 *   proportion to P(t) p_t(x2);
 * - the translucent stand-in BSDF is reciprocal and its directional albedo is albedo (1 - F). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "accel.h"
#include "bssrdf.h"
#include "material.h"
#include "rng.h"
#include "sampling.h"
#include "scene.h"
#include "surface.h"
#include "test.h"

static struct material test_material(struct vec3 albedo, struct vec3 mfp, float ior)
{
    struct material m;
    memset(&m, 0, sizeof m);
    m.kind = MATERIAL_TRANSLUCENT;
    m.albedo = albedo;
    m.mfp = mfp;
    m.ior = ior;
    bssrdf_prepare(&m);
    return m;
}

static void test_cdf_is_integral_of_pdf(void)
{
    const float d = 0.7f;
    /* integral_0^R 2 pi r p(r) dr by the midpoint rule (2 pi r p(r) is bounded at 0). */
    double acc = 0.0, r_prev = 0.0;
    const int n = 200000;
    const double r_end = 30.0 * d;
    for (int i = 1; i <= n; i++) {
        double r = r_end * i / n, rm = 0.5 * (r + r_prev);
        acc += 2.0 * M_PI * rm * bssrdf_profile_pdf((float)rm, d) * (r - r_prev);
        r_prev = r;
        if (i % 20000 == 0) CHECK_NEAR(acc, bssrdf_profile_cdf((float)r, d), 2e-4);
    }
    CHECK_NEAR(bssrdf_profile_cdf(bssrdf_r_max(d), d), BSSRDF_CDF_MAX, 1e-5);
    /* The inverse CDF inverts the CDF (Cardano's root), including near both ends. */
    const float us[] = {1e-6f, 0.01f, 0.3f, 0.5f, 0.9f, 0.99f, 0.999f};
    for (size_t i = 0; i < sizeof us / sizeof us[0]; i++)
        CHECK_NEAR(bssrdf_profile_cdf(bssrdf_profile_sample(us[i], d), d), us[i], 2e-6);
}

/* Chi-square of `n` radii sampled with d_sample against the CDF for d over K equal-probability
 * bins of [0, r_max) (edges found by bisection on the CDF, not with the sampler). */
static double radius_chi2(float d, float d_sample, int n, int K)
{
    double edges[65];
    float r_max = bssrdf_r_max(d);
    for (int i = 0; i <= K; i++) {
        double target = (double)BSSRDF_CDF_MAX * i / K, lo = 0.0, hi = r_max;
        for (int it = 0; it < 60; it++) {
            double mid = 0.5 * (lo + hi);
            if (bssrdf_profile_cdf((float)mid, d) < target) lo = mid;
            else hi = mid;
        }
        edges[i] = 0.5 * (lo + hi);
    }
    edges[K] = INFINITY;
    int counts[64] = {0};
    struct rng rng = rng_make(7, 1, 2, 3);
    for (int i = 0; i < n; i++) {
        float r = bssrdf_profile_sample(rng_next_float(&rng) * BSSRDF_CDF_MAX, d_sample);
        int b = 0;
        while (b < K - 1 && r >= edges[b + 1]) b++;
        counts[b]++;
    }
    double expected = (double)n / K, chi2 = 0.0;
    for (int b = 0; b < K; b++) chi2 += (counts[b] - expected) * (counts[b] - expected) / expected;
    return chi2;
}

static void test_radius_chi2(void)
{
    /* 39 degrees of freedom: the 0.999 quantile of chi-square(39) is 72.05. */
    const double crit = 72.05;
    double good = radius_chi2(0.7f, 0.7f, 200000, 40);
    double bad = radius_chi2(0.7f, 0.7f * 1.05f, 200000, 40);
    printf("     radius chi2 = %.1f (crit %.1f), with d x1.05: %.1f\n", good, crit, bad);
    CHECK(good < crit);
    CHECK(bad > crit);
}

/* ---- flat plane ---- */

static struct scene *load_scene(const char *json)
{
    struct err err = {0};
    struct scene *s = scene_load_json(json, strlen(json), ".", &err);
    if (!s || !scene_commit(s, &err)) {
        fprintf(stderr, "scene: %s at %s\n", err.message, err.where);
        if (s) scene_release(s);
        return NULL;
    }
    return s;
}

/* mfp with albedo 0.8 (s = 1.1): d = (0.04545, 0.02273, 0.01136), r_max ~ (0.91, 0.45, 0.23). */
#define TEST_MAT "\"sss\": {\"type\": \"translucent\", \"albedo\": [0.8, 0.8, 0.8], \"mfp\": [0.05, 0.025, 0.0125], \"ior\": 1.4}"

static const char plane_json[] =
    "{\"format\": 1, \"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], \"fov_deg\": 30},"
    "\"materials\": {" TEST_MAT "},"
    "\"shapes\": [{\"type\": \"quad\", \"material\": \"sss\", \"vertices\": [[-40, -40, 0], [40, -40, 0], [40, 40, 0], [-40, 40, 0]]}]}";

static const char sphere_json[] =
    "{\"format\": 1, \"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], \"fov_deg\": 30},"
    "\"materials\": {" TEST_MAT "},"
    "\"shapes\": [{\"type\": \"quad\", \"material\": \"sss\", \"vertices\": [[-9, -9, -3], [9, -9, -3], [9, 9, -3], [-9, 9, -3]]},"
    "{\"type\": \"sphere\", \"material\": \"sss\", \"center\": [0, 0, 0], \"radius\": 1}]}";

/* Monte Carlo over real probes from x1: mean hits per probe and mean of sum_j g(x_j)/pdf(x_j)
 * with g the channel-k profile R_k / albedo_k (so that its plane integral is 1), with their
 * standard errors. */
struct probe_stats { double hits, hits_se, est, est_se; uint64_t dropped; };

static struct probe_stats run_probes(const struct scene *sc, uint32_t shape, struct vec3 p1, const struct frame *f1,
                                     int channel, int n)
{
    const struct material *m = &sc->materials[0];
    struct rng rng = rng_make(11, 22, 33, (uint64_t)channel);
    struct ray_counters rc = {0, 0};
    double sh = 0, sh2 = 0, se = 0, se2 = 0;
    struct probe_stats st = {0};
    for (int i = 0; i < n; i++) {
        float ut = rng_next_float(&rng), ur = rng_next_float(&rng), ua = rng_next_float(&rng);
        int axis, ch;
        bssrdf_pick_technique(ut, &axis, &ch);
        struct bssrdf_probe pr;
        double count = 0, est = 0;
        if (bssrdf_probe_make(m, p1, f1, axis, ch, ur, ua, &pr)) {
            struct hit hits[BSSRDF_MAX_HITS];
            uint32_t nh = accel_intersect_shape_all(sc->accel, shape, pr.org, pr.dir, 0.0f, pr.tmax, hits,
                                                    BSSRDF_MAX_HITS, &rc);
            if (nh == BSSRDF_MAX_HITS) st.dropped++;
            for (uint32_t j = 0; j < nh; j++) {
                struct surface s2;
                surface_from_hit(sc, &hits[j], pr.org, pr.dir, &s2);
                float pdf = bssrdf_pdf_a(m, p1, f1, s2.p, s2.ng);
                count += 1.0;
                if (pdf > 0.0f)
                    est += vec3_comp(bssrdf_profile(m, vec3_length(vec3_sub(s2.p, p1))), channel) /
                           vec3_comp(m->albedo, channel) / pdf;
            }
        }
        sh += count, sh2 += count * count, se += est, se2 += est * est;
    }
    st.hits = sh / n;
    st.hits_se = sqrt(fmax(sh2 / n - st.hits * st.hits, 0.0) / n);
    st.est = se / n;
    st.est_se = sqrt(fmax(se2 / n - st.est * st.est, 0.0) / n);
    return st;
}

static void test_mis_pdf_flat_plane(void)
{
    struct scene *sc = load_scene(plane_json);
    CHECK(sc != NULL);
    if (!sc) return;
    const struct material *m = &sc->materials[0];
    struct vec3 p1 = vec3_make(0.123f, -0.077f, 0.0f), n1 = vec3_make(0, 0, 1);
    struct frame f1 = frame_from_normal(n1);

    /* Quadrature in polar coordinates about x1 (r dr dphi removes the 1/r of the profile). The
     * integrand is smooth in r on [0, r_max) and the rule's error is far below the tolerance
     * 1e-3, which is there for float rounding of 1e6 terms summed in double. */
    double sum_mis = 0.0, sum_t[BSSRDF_TECHNIQUES] = {0};
    const int nr = 2000, nphi = 64;
    const float r_end = vec3_max_comp(m->sss_r_max) * 1.01f;
    for (int i = 0; i < nr; i++) {
        double r = r_end * (i + 0.5) / nr, dr = (double)r_end / nr;
        for (int j = 0; j < nphi; j++) {
            double phi = 2.0 * M_PI * (j + 0.5) / nphi, dA = r * dr * 2.0 * M_PI / nphi;
            struct vec3 p2 = vec3_add(p1, vec3_make((float)(r * cos(phi)), (float)(r * sin(phi)), 0.0f));
            for (int t = 0; t < BSSRDF_TECHNIQUES; t++)
                sum_t[t] += bssrdf_pdf_technique(m, p1, &f1, t / 3, t % 3, p2, n1) * dA;
            sum_mis += bssrdf_pdf_a(m, p1, &f1, p2, n1) * dA;
        }
    }
    for (int c = 0; c < 3; c++) {
        CHECK_NEAR(sum_t[c], 1.0, 1e-3);      /* normal axis: integrates to 1 */
        CHECK_NEAR(sum_t[3 + c], 0.0, 1e-6);  /* tangent axes never reach the plane */
        CHECK_NEAR(sum_t[6 + c], 0.0, 1e-6);
    }
    CHECK_NEAR(sum_mis, 0.5, 1e-3);

    /* Real probes: 1/2 hit per probe; the estimator of the profile's integral over the plane
     * (1 for every channel: the renormalised profile on [0, r_max)) within 4 standard errors. */
    for (int c = 0; c < 3; c++) {
        struct probe_stats st = run_probes(sc, 0, p1, &f1, c, 200000);
        printf("     plane, channel %d: hits/probe %.4f +- %.4f, integral of R %.4f +- %.4f\n", c, st.hits, st.hits_se,
               st.est, st.est_se);
        CHECK_NEAR(st.hits, 0.5, 4.0 * st.hits_se + 1e-3);
        CHECK_NEAR(st.est, 1.0, 4.0 * st.est_se + 2e-3);
        CHECK(st.dropped == 0);
    }
    scene_release(sc);
}

/* On a sphere the area within chord distance r of a point is pi r^2 (Archimedes' hat-box
 * theorem), so the profile integrates to exactly 1 over the sphere as over the plane: the
 * curved-surface test of the estimator has the same target, 1, without any approximation.
 * Quadrature over the unit sphere about x1 = north pole: theta (geodesic angle from x1) graded
 * as theta_max s^2 to resolve the 1/r peak at x1, phi uniform. Returns the integral of the MIS
 * pdf and of the channel's normalised profile. */
static void sphere_quadrature(const struct material *m, struct vec3 p1, const struct frame *f1, int channel,
                              double *int_pdf, double *int_profile)
{
    float r_reach = vec3_max_comp(m->sss_r_max);
    double theta_max = r_reach >= 2.0f ? M_PI : 2.0 * asin(r_reach / 2.0);
    const int ns = 1500, nphi = 720;
    double sp = 0.0, sg = 0.0;
    for (int i = 0; i < ns; i++) {
        double s = (i + 0.5) / ns, theta = theta_max * s * s, dtheta = theta_max * 2.0 * s / ns;
        for (int j = 0; j < nphi; j++) {
            double phi = 2.0 * M_PI * (j + 0.5) / nphi;
            struct vec3 n2 = vec3_make((float)(sin(theta) * cos(phi)), (float)(sin(theta) * sin(phi)), (float)cos(theta));
            double dA = sin(theta) * dtheta * 2.0 * M_PI / nphi;
            sp += bssrdf_pdf_a(m, p1, f1, n2, n2) * dA;
            sg += vec3_comp(bssrdf_profile(m, vec3_length(vec3_sub(n2, p1))), channel) / vec3_comp(m->albedo, channel) * dA;
        }
    }
    *int_pdf = sp;
    *int_profile = sg;
}

static void test_mis_pdf_curved_surface(void)
{
    struct scene *sc = load_scene(sphere_json);
    CHECK(sc != NULL);
    if (!sc) return;
    const struct material *m = &sc->materials[0];
    struct vec3 p1 = vec3_make(0, 0, 1);
    struct frame f1 = frame_from_normal(p1);
    /* Tolerances: 4 standard errors of the Monte Carlo side plus 3e-3 for the quadrature (the
     * graded rule converges slowly only near the tangent axes' grazing hits at x1; halving the
     * grid moves the results by < 1e-3). */
    for (int c = 0; c < 3; c++) {
        double qp, qg;
        sphere_quadrature(m, p1, &f1, c, &qp, &qg);
        struct probe_stats st = run_probes(sc, 1, p1, &f1, c, 200000);
        printf("     sphere, channel %d: hits/probe %.4f +- %.4f vs integral of pdf %.4f; "
               "integral of R %.4f +- %.4f vs quadrature %.4f\n",
               c, st.hits, st.hits_se, qp, st.est, st.est_se, qg);
        CHECK_NEAR(st.hits, qp, 4.0 * st.hits_se + 3e-3);
        CHECK_NEAR(st.est, qg, 4.0 * st.est_se + 3e-3);
        CHECK(st.dropped == 0);
        /* Curvature matters here: the tangent axes find the sphere, so more than the plane's 1/2. */
        CHECK(qp > 0.55);
    }
    scene_release(sc);
}

static void test_probe_hits_ordered_on_one_shape(void)
{
    struct scene *sc = load_scene(sphere_json);
    CHECK(sc != NULL);
    if (!sc) return;
    struct ray_counters rc = {0, 0};
    struct hit hits[8];
    /* Straight down through the sphere's centre onto the quad below: two sphere hits, in order. */
    uint32_t n = accel_intersect_shape_all(sc->accel, 1, vec3_make(0, 0, 5), vec3_make(0, 0, -1), 0.0f, 100.0f, hits,
                                           8, &rc);
    CHECK(n == 2);
    if (n == 2) {
        CHECK_NEAR(hits[0].t, 4.0, 1e-4);
        CHECK_NEAR(hits[1].t, 6.0, 1e-4);
        CHECK(hits[0].shape == 1 && hits[1].shape == 1);
    }
    /* The quad alone, behind the sphere which is skipped. */
    n = accel_intersect_shape_all(sc->accel, 0, vec3_make(0, 0, 5), vec3_make(0, 0, -1), 0.0f, 100.0f, hits, 8, &rc);
    CHECK(n == 1 && n == 1 && fabsf(hits[0].t - 8.0f) < 1e-4f);
    /* max_hits caps the list; tmax cuts it. */
    CHECK(accel_intersect_shape_all(sc->accel, 1, vec3_make(0, 0, 5), vec3_make(0, 0, -1), 0.0f, 100.0f, hits, 1, &rc) ==
          1);
    CHECK(accel_intersect_shape_all(sc->accel, 1, vec3_make(0, 0, 5), vec3_make(0, 0, -1), 0.0f, 5.0f, hits, 8, &rc) ==
          1);
    scene_release(sc);
}

static void test_inversion_round_trip(void)
{
    struct material m = test_material(vec3_make(0.9f, 0.6f, 0.3f), vec3_make(0.3f, 0.1f, 0.05f), 1.33f);
    struct rng rng = rng_make(3, 4, 5, 6);
    int checked = 0;
    double worst = 0.0, worst_u = 0.0;
    for (int i = 0; i < 20000; i++) {
        struct vec3 n1 = sampling_uniform_sphere(rng_next_float(&rng), rng_next_float(&rng));
        struct frame f1 = frame_from_normal(n1);
        struct vec3 p1 = vec3_make(rng_next_float(&rng) * 4 - 2, rng_next_float(&rng) * 4 - 2, rng_next_float(&rng));
        int axis, ch;
        bssrdf_pick_technique(rng_next_float(&rng), &axis, &ch);
        float ur = rng_next_float(&rng), ua = rng_next_float(&rng);
        struct bssrdf_probe pr;
        if (!bssrdf_probe_make(&m, p1, &f1, axis, ch, ur, ua, &pr)) continue;
        /* A point anywhere on the probe segment stands for a hit there. */
        struct vec3 p2 = vec3_madd(pr.org, pr.dir, pr.tmax * (0.05f + 0.9f * rng_next_float(&rng)));
        float ur2, ua2;
        if (!bssrdf_invert(&m, p1, &f1, axis, ch, p2, &ur2, &ua2)) {
            /* Only a radius at the rounding edge of the disk centre may fail. */
            CHECK(pr.r < 1e-5f * vec3_comp(m.sss_d, ch));
            continue;
        }
        /* The round trip must give back the same probe (the path's x2 lies on it): its start
         * within 1e-4 r_max. The numbers themselves agree to 1e-4 for radii above d/10; below,
         * the angle of the float disk offset (|p1| ~ 2, so ~2e-7 absolute) is ill-conditioned. */
        struct bssrdf_probe pr2;
        CHECK(bssrdf_probe_make(&m, p1, &f1, axis, ch, ur2, ua2, &pr2));
        double e = vec3_length(vec3_sub(pr2.org, pr.org)) / vec3_comp(m.sss_r_max, ch);
        if (e > worst) worst = e;
        if (pr.r > 0.1f * vec3_comp(m.sss_d, ch)) {
            double eu = fmax(fabs(ur2 - ur), fmin(fabs(ua2 - ua), 1.0 - fabs(ua2 - ua)));
            if (eu > worst_u) worst_u = eu;
        }
        checked++;
    }
    printf("     inversion round trip: %d probes, worst probe shift %.2e r_max, worst |u - u'| = %.2e\n", checked,
           worst, worst_u);
    CHECK(checked > 19000);
    CHECK(worst < 1e-4);
    CHECK(worst_u < 1e-4);

    /* Algorithm 4 line 1: the technique is picked with probability P(t) p_t(x2) / sum. */
    struct vec3 n1 = vec3_make(0, 0, 1), p1 = vec3_make(0, 0, 0);
    struct frame f1 = frame_from_normal(n1);
    struct vec3 p2 = vec3_make(0.05f, 0.02f, -0.03f), n2 = vec3_normalize(vec3_make(0.3f, 0.2f, 1.0f));
    double w[BSSRDF_TECHNIQUES], wsum = 0.0;
    for (int t = 0; t < BSSRDF_TECHNIQUES; t++)
        wsum += w[t] = bssrdf_technique_prob(t / 3, t % 3) * bssrdf_pdf_technique(&m, p1, &f1, t / 3, t % 3, p2, n2);
    int counts[BSSRDF_TECHNIQUES] = {0};
    const int n = 90000;
    for (int i = 0; i < n; i++) {
        int a = 0, c = 0;
        CHECK(bssrdf_invert_technique(&m, p1, &f1, p2, n2, rng_next_float(&rng), &a, &c));
        counts[a * 3 + c]++;
    }
    double chi2 = 0.0;
    int dof = -1;
    for (int t = 0; t < BSSRDF_TECHNIQUES; t++) {
        double e = n * w[t] / wsum;
        if (e > 0.0) chi2 += (counts[t] - e) * (counts[t] - e) / e, dof++;
        else CHECK(counts[t] == 0);
    }
    printf("     technique inversion chi2 = %.1f (%d dof)\n", chi2, dof);
    CHECK(dof == 8);
    CHECK(chi2 < 26.1); /* 0.999 quantile of chi-square(8) */
}

static void test_standin_bsdf(void)
{
    struct material m = test_material(vec3_make(0.9f, 0.5f, 0.2f), vec3_make(0.3f, 0.1f, 0.05f), 1.4f);
    /* c normalises the entry lobe: (1/pi) int (1 - F) cos dw / c = 1 (hemisphere quadrature). */
    double acc = 0.0;
    const int n = 4000;
    for (int i = 0; i < n; i++) {
        double mu = (i + 0.5) / n;
        acc += bssrdf_entry_eval(&m, (float)mu) * mu * 2.0 * M_PI / n;
    }
    CHECK_NEAR(acc, 1.0, 1e-4);
    CHECK(m.sss_c > 0.85f && m.sss_c < 0.95f); /* 1 - 2 FM1 for eta 1.4 is about 0.9 */
    /* Reciprocity, and the sampled weight's mean is the directional albedo albedo (1 - F(wo)). */
    struct vec3 wo = vec3_normalize(vec3_make(0.4f, -0.2f, 0.7f)), wi = vec3_normalize(vec3_make(-0.1f, 0.5f, 0.3f));
    struct vec3 a = material_eval(&m, wo, wi, TRANSPORT_RADIANCE), b = material_eval(&m, wi, wo, TRANSPORT_RADIANCE);
    CHECK_NEAR(a.x, b.x, 1e-7);
    struct rng rng = rng_make(1, 1, 1, 1);
    double sum = 0.0;
    const int ns = 200000;
    for (int i = 0; i < ns; i++) {
        struct bsdf_sample bs;
        if (material_sample(&m, wo, rng_next_float(&rng), rng_next_float(&rng), rng_next_float(&rng),
                            TRANSPORT_RADIANCE, &bs))
            sum += bs.f.x * fabsf(bs.wi.z) / bs.pdf_w;
    }
    CHECK_NEAR(sum / ns, 0.9 * bssrdf_transmittance(&m, wo.z), 2e-3);
    CHECK(material_flags(&m) == (BSDF_REFLECTION | BSDF_DIFFUSE));
}

TEST_MAIN(TEST(test_cdf_is_integral_of_pdf), TEST(test_radius_chi2), TEST(test_mis_pdf_flat_plane),
          TEST(test_mis_pdf_curved_surface), TEST(test_probe_hits_ordered_on_one_shape), TEST(test_inversion_round_trip),
          TEST(test_standin_bsdf))
