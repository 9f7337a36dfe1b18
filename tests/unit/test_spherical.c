/* test_spherical.c — solid-angle sampling of triangles (core/spherical.h) and the light
 * sampler's next-event entry that uses it (light_sampler_sample_from / light_sampler_pdf_w_from).
 *
 * - Uniformity: directions sampled for a near, a far and a thin triangle are binned by the
 *   barycentric cell of the triangle they pass through (8 x 8 rows of the barycentric grid, 64
 *   cells), and the counts are checked by chi-square against each cell's share of the solid
 *   angle, itself computed by spherical_triangle_solid_angle on the cell. A negative control,
 *   the same warp with u1 replaced by u1^1.02, must be rejected in every case.
 * - The pdf integrates to 1: 1 / Omega times an independent ray-triangle hit test, averaged over
 *   uniform directions (on the sphere, or in a cone around the far triangle), is 1 within four
 *   standard errors, and spherical_triangle_contains agrees with the hit test.
 * - The inverse: sampling then inverting returns (u1, u2), down to tiny solid angles.
 * - The arc tangent the solid angle is taken with agrees with libm's.
 * - Rectangles (spherical_rect_*): samples binned by an 8 x 8 grid of the rectangle are uniform
 *   in solid angle (chi-square against each cell's solid angle as two triangles'), the solid
 *   angle agrees with the two triangles' sum, and controls with u1 or u2 skewed are rejected.
 * - The light sampler: for random points and emitters its sampling and its pdf function make the
 *   same decision and give the same solid-angle pdf, both decisions are exercised, the pick is
 *   light_sampler_sample's, and its solid-angle samples are uniform too (chi-square as above),
 *   over a quad's two triangles and over a rectangle's. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "core/rng.h"
#include "core/sampling.h"
#include "core/spherical.h"
#include "scene/light_sampler.h"
#include "scene_fixture.h"
#include "test.h"

/* ---------------------------------------------------------------- the arc tangent */

/* spherical_atan2_upper against libm over the upper half plane, magnitudes from 1e-12 to 1e6. */
static void test_atan2_upper_matches_libm(void)
{
    double worst = 0.0;
    for (int i = 0; i <= 200000; i++) {
        double angle = SPHERICAL_PI * i / 200000.0, radius = pow(10.0, -12.0 + 18.0 * ((i * 7919) % 1000) / 999.0);
        double y = radius * sin(angle), x = radius * cos(angle);
        if (y < 0.0) y = 0.0;
        double want = atan2(y, x), got = spherical_atan2_upper(y, x);
        double err = want > 0.0 ? fabs(got - want) / want : fabs(got);
        if (err > worst) worst = err;
    }
    printf("  worst relative error %.2g\n", worst);
    CHECK_MSG(worst < 2e-9, "worst relative error %.3g", worst);
    CHECK(spherical_atan2_upper(0.0, 1.0) == 0.0 && spherical_atan2_upper(0.0, 0.0) == 0.0);
    CHECK_NEAR(spherical_atan2_upper(0.0, -2.0), SPHERICAL_PI, 1e-15);
    CHECK_NEAR(spherical_atan2_upper(3.0, 0.0), 0.5 * SPHERICAL_PI, 1e-15);
    CHECK_NEAR(spherical_atan2_upper(1e-30, 1.0), 1e-30, 1e-45);
}

/* ---------------------------------------------------------------- chi-square over cells */

/* The barycentric grid: row i of CELLS_N holds the cells with floor(b1 N) = i; cell (i, j) is
 * the lower triangle (i, j), (i+1, j), (i, j+1) in units of 1 / N, or the upper one (i+1, j),
 * (i+1, j+1), (i, j+1). Cells are numbered 2 (i N + j) + upper; unused numbers stay empty. */
enum { CELLS_N = 8, CELLS = 2 * CELLS_N * CELLS_N };

static int cell_of(double b1, double b2)
{
    double x = b1 * CELLS_N, y = b2 * CELLS_N;
    int i = (int)floor(x), j = (int)floor(y);
    if (i < 0) i = 0;
    if (j < 0) j = 0;
    if (i + j > CELLS_N - 1) {  /* on the far edge (b1 + b2 = 1 rounded over): the last lower cell */
        if (i > CELLS_N - 1) i = CELLS_N - 1;
        j = CELLS_N - 1 - i;
        return 2 * (i * CELLS_N + j);
    }
    int upper = (x - i) + (y - j) > 1.0 && i + j < CELLS_N - 1;
    return 2 * (i * CELLS_N + j) + upper;
}

/* Each cell's solid angle from p over the whole triangle's: the expected share of its samples. */
static void cell_shares(struct vec3 p, struct vec3 v0, struct vec3 e1, struct vec3 e2, double share[CELLS])
{
    double total = 0.0;
    for (int c = 0; c < CELLS; c++) share[c] = 0.0;
    for (int i = 0; i < CELLS_N; i++) {
        for (int j = 0; i + j < CELLS_N; j++) {
            for (int upper = 0; upper < 2; upper++) {
                if (upper && i + j == CELLS_N - 1) continue;
                double c1[3] = {i, i + 1, i}, c2[3] = {j, j, j + 1};
                if (upper) c1[0] = i + 1, c2[0] = j, c1[1] = i + 1, c2[1] = j + 1, c1[2] = i, c2[2] = j + 1;
                struct vec3 q[3];
                for (int k = 0; k < 3; k++) {
                    float b1 = (float)(c1[k] / CELLS_N), b2 = (float)(c2[k] / CELLS_N);
                    q[k] = vec3_add(v0, vec3_add(vec3_scale(e1, b1), vec3_scale(e2, b2)));
                }
                double w = spherical_triangle_solid_angle(p, q[0], q[1], q[2]);
                share[2 * (i * CELLS_N + j) + upper] = w;
                total += w;
            }
        }
    }
    for (int c = 0; c < CELLS; c++) share[c] /= total;
}

/* Wilson–Hilferty: the chi-square statistic with `dof` degrees of freedom as a standard normal z
 * (accurate to a few hundredths at the tail for dof >= 30). */
static double chi2_as_z(double chi2, int dof)
{
    double k = dof, v = 2.0 / (9.0 * k);
    return (cbrt(chi2 / k) - (1.0 - v)) / sqrt(v);
}

/* Chi-square z of `cells` counts against shares (n samples, cells of zero share must stay empty). */
static double cells_z(const long *counts, const double *share, int cells, long n, const char *what)
{
    double chi2 = 0.0;
    int dof = -1;
    for (int c = 0; c < cells; c++) {
        if (share[c] <= 0.0) {
            CHECK_MSG(counts[c] == 0, "%s: %ld samples in a cell of no solid angle", what, counts[c]);
            continue;
        }
        double e = share[c] * (double)n;
        CHECK_MSG(e >= 20.0, "%s: cell %d expects only %.1f samples", what, c, e);
        chi2 += (counts[c] - e) * (counts[c] - e) / e;
        dof++;
    }
    return chi2_as_z(chi2, dof);
}

/* Barycentrics of the point where the ray p + t dir meets the plane of v0 + b1 e1 + b2 e2
 * (Cramer's rule in double). False when it misses the plane in front of p. */
static bool plane_barycentrics(struct vec3 p, struct dvec3 dir, struct vec3 v0, struct vec3 e1,
                               struct vec3 e2, double *b1, double *b2, double *t_out)
{
    struct dvec3 de1 = dvec3_from(e1), de2 = dvec3_from(e2);
    struct dvec3 pv = dvec3_cross(dir, de2);
    double det = dvec3_dot(de1, pv);
    if (det == 0.0) return false;
    struct dvec3 tv = dvec3_sub(dvec3_from(p), dvec3_from(v0));
    struct dvec3 qv = dvec3_cross(tv, de1);
    *b1 = dvec3_dot(tv, pv) / det;
    *b2 = dvec3_dot(dir, qv) / det;
    double t = dvec3_dot(de2, qv) / det;
    if (t_out) *t_out = t;
    return t > 0.0;
}

struct tri_case {
    const char *name;
    struct vec3 p, v0, v1, v2;
};

/* p at the origin throughout: a triangle nearly as close as it is large, one 100 times farther
 * than its size, and a sliver 400 times longer than wide, seen obliquely. */
static const struct tri_case tri_cases[] = {
    {"near", {0, 0, 0}, {-0.6f, -0.4f, 0.5f}, {0.9f, -0.2f, 0.7f}, {0.1f, 0.8f, 0.4f}},
    {"far", {0, 0, 0}, {-0.3f, 50.0f, 100.0f}, {0.5f, 50.1f, 100.4f}, {0.1f, 50.6f, 99.8f}},
    {"thin", {0, 0, 0}, {-1.0f, 0.3f, 1.0f}, {1.0f, 0.305f, 1.2f}, {0.2f, 0.3f, 1.5f}},
};

/* (u1, u2) -> direction, optionally with u1 skewed to u1^1.02 (the negative control). */
static struct dvec3 sample_dir(const struct spherical_triangle *st, float u1, float u2, bool skew)
{
    if (skew) u1 = powf(u1, 1.02f);
    return spherical_triangle_sample_d(st, u1, u2);
}

static double warp_chi2_z(const struct tri_case *tc, bool skew, long n, uint64_t seed)
{
    struct vec3 e1 = vec3_sub(tc->v1, tc->v0), e2 = vec3_sub(tc->v2, tc->v0);
    struct spherical_triangle st;
    CHECK_MSG(spherical_triangle_init(&st, tc->p, tc->v0, e1, e2), "%s: init", tc->name);
    double share[CELLS];
    cell_shares(tc->p, tc->v0, e1, e2, share);
    static long counts[CELLS];
    for (int c = 0; c < CELLS; c++) counts[c] = 0;
    struct rng r = rng_make(seed, 1, 2, 3);
    long misses = 0;
    for (long i = 0; i < n; i++) {
        float u1 = rng_next_float(&r), u2 = rng_next_float(&r);
        double b1, b2;
        if (!plane_barycentrics(tc->p, sample_dir(&st, u1, u2, skew), tc->v0, e1, e2, &b1, &b2, NULL) ||
            b1 < -1e-6 || b2 < -1e-6 || b1 + b2 > 1.0 + 1e-6) {
            misses++;
            continue;
        }
        counts[cell_of(b1, b2)]++;
    }
    CHECK_MSG(misses == 0, "%s: %ld of %ld directions miss the triangle", tc->name, misses, n);
    return cells_z(counts, share, CELLS, n, tc->name);
}

static void test_warp_uniform_chi2(void)
{
    const long n = 400000;
    for (size_t k = 0; k < sizeof tri_cases / sizeof tri_cases[0]; k++) {
        double z = warp_chi2_z(&tri_cases[k], false, n, 11 + k);
        double z_bad = warp_chi2_z(&tri_cases[k], true, n, 11 + k);
        printf("  %s: chi-square z %.2f (skewed control %.2f)\n", tri_cases[k].name, z, z_bad);
        CHECK_MSG(z < 4.0, "%s: chi-square z %.2f", tri_cases[k].name, z);
        CHECK_MSG(z_bad > 4.0, "%s: the skewed control passes (z %.2f)", tri_cases[k].name, z_bad);
    }
}

/* ---------------------------------------------------------------- the pdf's integral */

/* Möller–Trumbore in double: does the ray from p along dir hit the triangle? */
static bool ray_hits_triangle(struct vec3 p, struct dvec3 dir, struct vec3 v0, struct vec3 v1, struct vec3 v2)
{
    double b1, b2;
    return plane_barycentrics(p, dir, v0, vec3_sub(v1, v0), vec3_sub(v2, v0), &b1, &b2, NULL) && b1 >= 0.0 &&
           b2 >= 0.0 && b1 + b2 <= 1.0;
}

static void test_pdf_integrates_to_one(void)
{
    const long n = 2000000;
    for (size_t k = 0; k < sizeof tri_cases / sizeof tri_cases[0]; k++) {
        const struct tri_case *tc = &tri_cases[k];
        struct vec3 e1 = vec3_sub(tc->v1, tc->v0), e2 = vec3_sub(tc->v2, tc->v0);
        struct spherical_triangle st;
        if (!spherical_triangle_init(&st, tc->p, tc->v0, e1, e2)) {
            CHECK_MSG(false, "%s: init", tc->name);
            continue;
        }
        /* Uniform over the sphere, or for the far and the thin triangle uniform in the cone around
         * the centroid's direction that holds the vertices (the sphere would hit them once in
         * 10^5 and in 250 directions). */
        bool cone = strcmp(tc->name, "near") != 0;
        struct vec3 axis = vec3_normalize(vec3_scale(vec3_add(tc->v0, vec3_add(tc->v1, tc->v2)), 1.0f / 3.0f));
        double cos_max = 1.0;
        const struct vec3 vs[3] = {tc->v0, tc->v1, tc->v2};
        for (int i = 0; i < 3; i++) cos_max = fmin(cos_max, vec3_dot(axis, vec3_normalize(vs[i])));
        cos_max -= 1e-3 * (1.0 - cos_max);   /* a margin: the cone holds the triangle */
        struct frame f = frame_from_normal(axis);
        double dir_pdf = cone ? 1.0 / (2.0 * M_PI * (1.0 - cos_max)) : 1.0 / (4.0 * M_PI);
        struct rng r = rng_make(5, k, 0, 0);
        double sum = 0.0, sum2 = 0.0;
        long disagree = 0;
        for (long i = 0; i < n; i++) {
            double u1 = rng_next_double(&r), u2 = rng_next_double(&r);
            double z = cone ? 1.0 - u1 * (1.0 - cos_max) : 1.0 - 2.0 * u1;
            double s = sqrt(fmax(0.0, 1.0 - z * z)), phi = 2.0 * M_PI * u2;
            struct dvec3 local = {s * cos(phi), s * sin(phi), z};
            struct dvec3 d = cone ? dvec3_add(dvec3_add(dvec3_scale(dvec3_from(f.s), local.x),
                                                                         dvec3_scale(dvec3_from(f.t), local.y)),
                                                           dvec3_scale(dvec3_from(f.n), local.z))
                                           : local;
            bool hit = ray_hits_triangle(tc->p, d, tc->v0, tc->v1, tc->v2);
            struct vec3 df = vec3_make((float)d.x, (float)d.y, (float)d.z);
            disagree += hit != spherical_triangle_contains(&st, df);
            double x = hit ? spherical_triangle_pdf_w(&st) / dir_pdf : 0.0;
            sum += x;
            sum2 += x * x;
        }
        double mean = sum / n, se = sqrt((sum2 / n - mean * mean) / n);
        printf("  %s: integral %.5f +- %.5f (Omega %.4g sr), contains() disagrees with the hit test %ld times\n",
               tc->name, mean, se, st.solid_angle, disagree);
        CHECK_MSG(fabs(mean - 1.0) < 4.0 * se, "%s: the pdf integrates to %.5f +- %.5f", tc->name, mean, se);
        /* Only directions within float rounding of an edge may disagree. */
        CHECK_MSG(disagree <= n / 100000, "%s: contains() and the hit test disagree %ld times", tc->name, disagree);
    }
}

/* ---------------------------------------------------------------- the inverse */

static void test_sample_invert_round_trip(void)
{
    /* The near triangle's shape scaled down towards p's view axis: solid angles from 0.3 sr down
     * to 3e-9 sr, and a 500:1 sliver down to 1e-9 sr. */
    const double scales[] = {1.0, 1e-1, 1e-2, 1e-3, 1e-4};
    for (int shape = 0; shape < 2; shape++) {
        for (size_t k = 0; k < sizeof scales / sizeof scales[0]; k++) {
            double sc = scales[k];
            struct vec3 v0, v1, v2;
            if (shape == 0) {
                v0 = vec3_make((float)(-0.3 * sc), (float)(-0.2 * sc), 1.0f);
                v1 = vec3_make((float)(0.5 * sc), (float)(-0.1 * sc), 1.1f);
                v2 = vec3_make((float)(0.1 * sc), (float)(0.6 * sc), 0.9f);
            } else {
                v0 = vec3_make((float)(-0.5 * sc), 0.0f, 1.0f);
                v1 = vec3_make((float)(0.5 * sc), (float)(0.001 * sc), 1.0f);
                v2 = vec3_make((float)(0.5 * sc), (float)(-0.001 * sc), 1.0f);
            }
            struct spherical_triangle st;
            bool ok = spherical_triangle_init(&st, vec3_splat(0.0f), v0, vec3_sub(v1, v0), vec3_sub(v2, v0));
            if (!ok) {
                CHECK_MSG(st.solid_angle <= SPHERICAL_MIN_SOLID_ANGLE, "init refused %.3g sr", st.solid_angle);
                continue;
            }
            struct rng r = rng_make(9, shape, k, 0);
            double worst = 0.0;
            for (int i = 0; i < 20000; i++) {
                float u1 = rng_next_float(&r), u2 = rng_next_float(&r);
                struct dvec3 d = spherical_triangle_sample_d(&st, u1, u2);
                CHECK(fabs(dvec3_dot(d, d) - 1.0) < 1e-12);
                double w1, w2;
                spherical_triangle_invert_d(&st, d, &w1, &w2);
                /* u2 is undefined where the arc b-C' has no length (u1 = 0). */
                worst = fmax(worst, fmax(fabs(w1 - u1), u1 > 1e-4f ? fabs(w2 - u2) : 0.0));
            }
            printf("  %s x %.0e: %.3g sr, worst round trip %.2g\n", shape ? "sliver" : "triangle", sc, st.solid_angle,
                   worst);
            CHECK_MSG(worst < 2e-6, "%s scale %g (%.3g sr): sample/invert round trip off by %.3g",
                      shape ? "sliver" : "triangle", sc, st.solid_angle, worst);
        }
    }
}


/* ---------------------------------------------------------------- rectangles */

struct rect_case {
    const char *name;
    struct vec3 corner, ex, ey;   /* orthogonal edges; p at the origin */
};

/* A rectangle about as close as it is large, one seen at a grazing angle from beside its edge,
 * one 30 times farther than its size (the light sampler's rule stops at 5 radii), and a strip
 * 60 times longer than wide that p sees across; each rotated out of the axes. */
static const struct rect_case rect_cases[] = {
    {"near", {-0.7f, -0.5f, 0.6f}, {1.3f, 0.2f, 0.1f}, {-0.16f, 0.9f, 0.28f}},
    {"grazing", {1.2f, -0.5f, 0.05f}, {1.5f, 0.0f, 0.3f}, {0.0f, 1.0f, 0.0f}},
    {"far", {0.2f, 30.0f, 2.0f}, {0.8f, 0.1f, 0.3f}, {-0.15f, 0.6f, 0.2f}},
    {"strip", {-3.0f, 0.5f, 1.0f}, {6.0f, 0.0f, 0.0f}, {0.0f, 0.06f, 0.08f}},
};

/* The cell of the 8 x 8 grid of the rectangle (s, t in [0, 1]) holding (s, t). */
static int rect_cell_of(double s, double t)
{
    int i = (int)floor(s * CELLS_N), j = (int)floor(t * CELLS_N);
    i = i < 0 ? 0 : (i > CELLS_N - 1 ? CELLS_N - 1 : i);
    j = j < 0 ? 0 : (j > CELLS_N - 1 ? CELLS_N - 1 : j);
    return i * CELLS_N + j;
}

/* Each cell's solid angle (as its two triangles') over the sum: the shares; the sum in *total. */
static void rect_cell_shares(struct vec3 p, struct vec3 corner, struct vec3 ex, struct vec3 ey, double share[CELLS],
                             double *total)
{
    *total = 0.0;
    for (int c = 0; c < CELLS; c++) share[c] = 0.0;
    for (int i = 0; i < CELLS_N; i++) {
        for (int j = 0; j < CELLS_N; j++) {
            /* In double: float corners would move a thin strip's cells by 1e-6 of their width. */
            struct dvec3 q[4];
            for (int k = 0; k < 4; k++) {
                double s = (double)(i + (k == 1 || k == 2)) / CELLS_N, t = (double)(j + (k >= 2)) / CELLS_N;
                q[k] = dvec3_add(dvec3_sub(dvec3_from(corner), dvec3_from(p)),
                                 dvec3_add(dvec3_scale(dvec3_from(ex), s), dvec3_scale(dvec3_from(ey), t)));
            }
            double w = spherical_solid_angle_edges(q[0], dvec3_sub(q[1], q[0]), dvec3_sub(q[2], q[0]), NULL, NULL) +
                       spherical_solid_angle_edges(q[0], dvec3_sub(q[2], q[0]), dvec3_sub(q[3], q[0]), NULL, NULL);
            share[i * CELLS_N + j] = w;
            *total += w;
        }
    }
    for (int c = 0; c < CELLS; c++) share[c] /= *total;
}

/* Chi-square z of spherical_rect_sample_st's points over the cells, u1 (skew 1) or u2 (skew 2)
 * taken to the power 1.03 for the controls; the solid angle over the cells' sum in *ratio. The
 * rectangle's frame is the edges' directions and lengths in double, as the light sampler's is
 * from its float table. */
static double rect_chi2_z(const struct rect_case *rc, int skew, long n, uint64_t seed, double *ratio)
{
    const double lx = dvec3_length(dvec3_from(rc->ex)), ly = dvec3_length(dvec3_from(rc->ey));
    const struct dvec3 x = dvec3_scale(dvec3_from(rc->ex), 1.0 / lx), y = dvec3_scale(dvec3_from(rc->ey), 1.0 / ly);
    const struct vec3 p = vec3_splat(0.0f);
    struct spherical_rect sr;
    /* p at the origin: corner - p is the corner. */
    CHECK_MSG(spherical_rect_init(&sr, dvec3_from(rc->corner), x, y, dvec3_cross(x, y), lx, ly), "%s: init", rc->name);
    double share[CELLS], total;
    rect_cell_shares(p, rc->corner, rc->ex, rc->ey, share, &total);
    *ratio = sr.solid_angle / total;
    static long counts[CELLS];
    for (int c = 0; c < CELLS; c++) counts[c] = 0;
    struct rng r = rng_make(seed, 5, 6, 7);
    long off = 0;
    for (long i = 0; i < n; i++) {
        float u1 = rng_next_float(&r), u2 = rng_next_float(&r);
        if (skew == 1) u1 = powf(u1, 1.03f);
        if (skew == 2) u2 = powf(u2, 1.03f);
        double s, t;
        spherical_rect_sample_st(&sr, u1, u2, &s, &t);
        s /= lx;
        t /= ly;
        /* Outside [0, 1]^2 (beyond the rounding of (x1 - x0) / lx) or NaN: counted here, and kept
         * out of the cells. */
        if (!(s >= 0.0 && s <= 1.0 + 1e-9 && t >= 0.0 && t <= 1.0 + 1e-9)) {
            off++;
            continue;
        }
        counts[rect_cell_of(s, t)]++;
    }
    CHECK_MSG(off == 0, "%s: %ld of %ld points off the rectangle", rc->name, off, n);
    return cells_z(counts, share, CELLS_N * CELLS_N, n, rc->name);
}

static void test_rect_warp_uniform_chi2(void)
{
    const long n = 400000;
    for (size_t k = 0; k < sizeof rect_cases / sizeof rect_cases[0]; k++) {
        double ratio;
        double z = rect_chi2_z(&rect_cases[k], 0, n, 21 + k, &ratio);
        double z_u1 = rect_chi2_z(&rect_cases[k], 1, n, 21 + k, &(double){0});
        double z_u2 = rect_chi2_z(&rect_cases[k], 2, n, 21 + k, &(double){0});
        printf("  %s: solid angle / the triangles' - 1: %.2g, chi-square z %.2f (skewed controls %.2f, %.2f)\n",
               rect_cases[k].name, ratio - 1.0, z, z_u1, z_u2);
        CHECK_MSG(fabs(ratio - 1.0) < 1e-7, "%s: solid angle off by %.3g", rect_cases[k].name, ratio - 1.0);
        CHECK_MSG(z < 4.0, "%s: chi-square z %.2f", rect_cases[k].name, z);
        CHECK_MSG(z_u1 > 4.0 && z_u2 > 4.0, "%s: a skewed control passes (z %.2f, %.2f)", rect_cases[k].name, z_u1, z_u2);
    }
    /* In the rectangle's plane: nothing to sample. */
    struct spherical_rect sr;
    CHECK(!spherical_rect_init(&sr, (struct dvec3){1.0, 0.0, 0.0}, (struct dvec3){1.0, 0.0, 0.0},
                               (struct dvec3){0.0, 1.0, 0.0}, (struct dvec3){0.0, 0.0, 1.0}, 1.0, 1.0));
}

/* ---------------------------------------------------------------- the light sampler */

/* Emissive parallelograms (two triangles each) of random size and orientation around the
 * origin, a one-sided sphere emitter and an environment, so that every kind of emitter is picked. */
static struct scene *random_emitters_scene(struct rng *r, int quads)
{
    char *json = malloc(16384);
    if (!json) return NULL;
    int len = snprintf(json, 16384,
                       "{\"format\": 1, \"camera\": {\"position\": [0, 0, 30], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], "
                       "\"fov_deg\": 30}, \"materials\": {\"lamp\": {\"type\": \"diffuse\", \"albedo\": [0, 0, 0], "
                       "\"emission\": [2, 3, 4]}, \"lamp2\": {\"type\": \"diffuse\", \"albedo\": [0, 0, 0], "
                       "\"emission\": [1, 1, 1], \"two_sided\": true}}, \"environment\": {\"radiance\": [0.002, 0.002, 0.002]}, "
                       "\"shapes\": [{\"type\": \"sphere\", \"material\": \"lamp2\", \"center\": [3, -2, 1], \"radius\": 0.7}");
    for (int q = 0; q < quads; q++) {
        float c[3], a[3], b[3];
        float size = 0.2f + 3.0f * rng_next_float(r);
        for (int i = 0; i < 3; i++) {
            c[i] = 8.0f * (rng_next_float(r) - 0.5f);
            a[i] = size * (rng_next_float(r) - 0.5f);
            b[i] = size * (rng_next_float(r) - 0.5f) * (q % 3 == 0 ? 0.05f : 1.0f);  /* some slivers */
        }
        if (q % 4 == 1) {  /* some rectangles, sampled as spherical rectangles */
            float ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2], aa = a[0] * a[0] + a[1] * a[1] + a[2] * a[2];
            for (int i = 0; i < 3; i++) b[i] -= ab / aa * a[i];
        }
        len += snprintf(json + len, 16384 - (size_t)len,
                        ", {\"type\": \"quad\", \"material\": \"%s\", \"vertices\": [[%.9g, %.9g, %.9g], "
                        "[%.9g, %.9g, %.9g], [%.9g, %.9g, %.9g], [%.9g, %.9g, %.9g]]}",
                        q % 2 ? "lamp2" : "lamp", c[0], c[1], c[2], c[0] + a[0], c[1] + a[1], c[2] + a[2],
                        c[0] + a[0] + b[0], c[1] + a[1] + b[1], c[2] + a[2] + b[2], c[0] + b[0], c[1] + b[1],
                        c[2] + b[2]);
    }
    snprintf(json + len, 16384 - (size_t)len, "]}");
    struct scene *s = fixture_load_json(json, NULL);
    free(json);
    return s;
}

static void test_light_sampler_decision_and_pdf_agree(void)
{
    struct rng r = rng_make(3, 1, 4, 1);
    struct scene *s = random_emitters_scene(&r, 12);
    if (!s) return;
    const struct light_sampler *ls = s->lights;
    long solid = 0, area = 0, spheres = 0, env = 0, mismatched = 0;
    for (int i = 0; i < 200000; i++) {
        /* Points from inside the cluster of lights out to 10 times its size, and every other one
         * within 4 units of a point on a light, where solid-angle sampling starts. */
        float dist = 0.2f + 40.0f * powf(rng_next_float(&r), 3.0f);
        struct vec3 p = vec3_scale(sampling_uniform_sphere(rng_next_float(&r), rng_next_float(&r)), dist);
        struct light_sample near;
        if (i % 2 && light_sampler_sample(ls, rng_next_float(&r), rng_next_float(&r), rng_next_float(&r), &near) &&
            !near.is_env)
            p = vec3_add(near.p, vec3_scale(sampling_uniform_sphere(rng_next_float(&r), rng_next_float(&r)),
                                            4.0f * rng_next_float(&r)));
        float u_pick = rng_next_float(&r), u1 = rng_next_float(&r), u2 = rng_next_float(&r);
        struct light_sample a, b = {0};
        bool ok_from = light_sampler_sample_from(ls, p, u_pick, u1, u2, &a);
        bool ok = light_sampler_sample(ls, u_pick, u1, u2, &b);
        CHECK(ok);
        /* The same emitter as light_sampler_sample for the same u_pick; a quad's other triangle
         * only where the pair was sampled by solid angle (then either of its two). */
        CHECK(a.shape == b.shape && a.is_env == b.is_env);
        CHECK(a.prim == b.prim || (a.solid_angle && s->shapes[a.shape].kind == SHAPE_MESH &&
                                    s->shapes[a.shape].triangle_count == 2));
        if (!ok_from) continue;
        if (a.is_env) {
            CHECK(a.pdf_w == b.pdf_w);
            env++;
            continue;
        }
        const struct shape *sh = &s->shapes[a.shape];
        float back = light_sampler_pdf_w_from(ls, p, a.shape, a.prim, a.p);
        bool decision = sh->kind == SHAPE_MESH && light_sampler_solid_angle_from(ls, p, a.shape, a.prim);
        /* A sphere's normal is the sampled direction for the sample and (q - centre) / r for the
         * pdf function: the same to float rounding, which 1 / cos at the light magnifies; the
         * values are compared where that cosine is above 0.05. */
        struct vec3 d = vec3_sub(a.p, p);
        float d2 = vec3_length2(d), cos_light = fabsf(vec3_dot(d, a.n)) / sqrtf(d2);
        bool compare = sh->kind == SHAPE_MESH || cos_light > 0.05f;
        float tolerance = sh->kind == SHAPE_MESH ? 2e-6f : 1e-4f;
        if (decision != a.solid_angle || (compare && !(fabsf(back - a.pdf_w) <= tolerance * a.pdf_w))) {
            if (mismatched++ < 5)
                fprintf(stderr, "  p (%g %g %g) emitter %u/%u: sampled %s pdf %g, pdf function %s %g\n", (double)p.x,
                        (double)p.y, (double)p.z, a.shape, a.prim, a.solid_angle ? "solid angle" : "area",
                        (double)a.pdf_w, decision ? "solid angle" : "area", (double)back);
        }
        /* pdf_a is the same density per area of the light. */
        float back_w = sampling_area_to_solid_angle(a.pdf_a, d2, vec3_dot(d, a.n) / sqrtf(d2));
        CHECK_MSG(fabsf(back_w - a.pdf_w) <= 1e-4f * a.pdf_w, "pdf_a %g gives %g, pdf_w %g", (double)a.pdf_a,
                  (double)back_w, (double)a.pdf_w);
        if (sh->kind != SHAPE_MESH) spheres++;
        else if (a.solid_angle) solid++;
        else area++;
    }
    printf("  %ld solid-angle samples, %ld area-sampled triangles, %ld spheres, %ld environment; %ld disagree\n", solid,
           area, spheres, env, mismatched);
    CHECK_MSG(mismatched == 0, "%ld samples whose pdf function disagrees", mismatched);
    CHECK(solid > 10000 && area > 10000 && spheres > 1000 && env > 1000);
    /* Not an emitter, or no such triangle: no pdf. */
    CHECK(light_sampler_pdf_w_from(ls, vec3_splat(0.0f), s->shape_count, 0, vec3_splat(1.0f)) == 0.0f);
    CHECK(!light_sampler_solid_angle_from(ls, vec3_splat(0.0f), 0, 0));  /* the sphere */
    scene_release(s);
}

/* A sample of light_sampler_sample_from at p with random numbers from r, if it fell on shape 0
 * (the tests' quad), which it must have sampled by solid angle. */
static bool quad_sample_from(const struct light_sampler *lights, struct vec3 p, struct rng *r, struct light_sample *ls)
{
    float u_pick = rng_next_float(r), u1 = rng_next_float(r), u2 = rng_next_float(r);
    if (!light_sampler_sample_from(lights, p, u_pick, u1, u2, ls) || ls->shape != 0) return false;
    CHECK(ls->prim < 2 && ls->solid_angle);
    return true;
}

/* light_sampler_sample_from's solid-angle samples of a quad from a point close to it are uniform
 * over the quad's whole solid angle: each triangle is chosen in proportion to its solid angle
 * (binomial z against Omega_k / (Omega_0 + Omega_1), 0.608 and 0.392 from p), and within each
 * the barycentrics it returns are uniform in solid angle (binned as in test_warp_uniform_chi2);
 * every sample's pdf, and the pdf function's on either triangle, is the pair's, (pmf_0 + pmf_1) /
 * (Omega_0 + Omega_1), with pick probabilities that differ (a trapezoid) and do not add up to 1
 * (a sphere beside it). Fails with the triangle picked by power (split z -35.8), and with the
 * pair's pick probability left out of its pdf. */
static void test_light_sampler_solid_angle_uniform_chi2(void)
{
    const char *json = "{\"format\": 1, \"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], "
                       "\"fov_deg\": 30}, \"materials\": {\"lamp\": {\"type\": \"diffuse\", \"albedo\": [0, 0, 0], "
                       "\"emission\": [1, 1, 1], \"two_sided\": true}}, \"shapes\": [{\"type\": \"quad\", \"material\": "
                       "\"lamp\", \"vertices\": [[-1, -1, 1], [1.5, -1, 1.2], [0.8, 1.2, 1.2], [-1, 1.2, 1]]}, "
                       "{\"type\": \"sphere\", \"material\": \"lamp\", \"center\": [0, 0, -6], \"radius\": 1}]}";
    struct scene *s = fixture_load_json(json, NULL);
    if (!s) return;
    const struct vec3 p = vec3_make(0.3f, 0.2f, 0.1f);
    double share[2][CELLS], omega[2], pmf[2];
    for (uint32_t t = 0; t < 2; t++) {
        struct vec3 v0, v1, v2, n;
        /* The triangle's vertices, from the sampler's own table. */
        CHECK(light_sampler_triangle_point(s->lights, 0, t, 0.0f, 0.0f, &v0, &n));
        CHECK(light_sampler_triangle_point(s->lights, 0, t, 1.0f, 0.0f, &v1, &n));
        CHECK(light_sampler_triangle_point(s->lights, 0, t, 0.0f, 1.0f, &v2, &n));
        CHECK(light_sampler_solid_angle_from(s->lights, p, 0, t));
        cell_shares(p, v0, vec3_sub(v1, v0), vec3_sub(v2, v0), share[t]);
        struct spherical_triangle st;
        CHECK(spherical_triangle_init(&st, p, v0, vec3_sub(v1, v0), vec3_sub(v2, v0)));
        omega[t] = st.solid_angle;
        /* The triangle's pick probability by power: its area pdf times its area. */
        pmf[t] = (double)light_sampler_pdf_a(s->lights, 0, t) * 0.5 * vec3_length(vec3_cross(vec3_sub(v1, v0), vec3_sub(v2, v0)));
    }
    /* A trapezoid beside a sphere: the two triangles' pick probabilities differ, and with the
     * sphere they do not add up to 1. */
    CHECK(fabs(pmf[0] - pmf[1]) > 0.05 && pmf[0] + pmf[1] < 0.9);
    const float pdf_pair = (float)((pmf[0] + pmf[1]) / (omega[0] + omega[1]));
    static long counts[2][CELLS];
    struct rng r = rng_make(17, 0, 0, 0);
    long n_samples = 0, per[2] = {0, 0}, pdf_off = 0;
    while (n_samples < 400000) {
        struct light_sample ls;
        if (!quad_sample_from(s->lights, p, &r, &ls)) continue;
        pdf_off += !(fabsf(ls.pdf_w - pdf_pair) <= 1e-5f * pdf_pair);
        counts[ls.prim][cell_of(ls.b1, ls.b2)]++;
        per[ls.prim]++;
        n_samples++;
    }
    const double expect0 = omega[0] / (omega[0] + omega[1]);
    const double z_split = ((double)per[0] - expect0 * (double)n_samples) /
                           sqrt(expect0 * (1.0 - expect0) * (double)n_samples);
    printf("  light sampler: triangle 0 holds %.4f of the samples, %.4f of the solid angle (z %.2f; Omega %.4f, %.4f)\n",
           (double)per[0] / (double)n_samples, expect0, z_split, omega[0], omega[1]);
    CHECK_MSG(fabs(z_split) < 4.0, "light sampler: the split between the triangles is off, z %.2f", z_split);
    CHECK_MSG(pdf_off == 0, "%ld samples whose pdf is not the pair's %g", pdf_off, (double)pdf_pair);
    /* The pdf function gives the pair's density on either triangle. */
    for (uint32_t t = 0; t < 2; t++) {
        struct vec3 q, n;
        CHECK(light_sampler_triangle_point(s->lights, 0, t, 0.3f, 0.3f, &q, &n));
        const float back = light_sampler_pdf_w_from(s->lights, p, 0, t, q);
        CHECK_MSG(fabsf(back - pdf_pair) <= 1e-5f * pdf_pair, "triangle %u: pdf %g, the pair's %g", t, (double)back,
                  (double)pdf_pair);
    }
    for (int t = 0; t < 2; t++) {
        double z = cells_z(counts[t], share[t], CELLS, per[t], "light sampler");
        printf("  light sampler, triangle %d: chi-square z %.2f\n", t, z);
        CHECK_MSG(z < 4.0, "light sampler, triangle %d: chi-square z %.2f", t, z);
    }
    scene_release(s);
}


/* A rectangle's samples from a point close to it (light_sampler_sample_from) are uniform over
 * its whole solid angle as one spherical rectangle: binned by an 8 x 8 grid of the rectangle,
 * chi-square against each cell's solid angle; every sample's pdf, and the pdf function's on
 * either triangle, is (pmf_0 + pmf_1) / Omega with Omega the two triangles' solid angles
 * (van Oosterom & Strackee, not the rectangle's own angle sum). The rectangle is rotated out of
 * the axes and sits beside a sphere, so that its pick probability is not 1. */
static void test_light_sampler_rect_uniform_chi2(void)
{
    /* corner (-1, -0.8, 1), edges (2, 0.4, 0.3) and (-0.3, 1.5, 0) (orthogonal: -0.6 + 0.6 + 0). */
    const char *json = "{\"format\": 1, \"camera\": {\"position\": [0, 0, 5], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], "
                       "\"fov_deg\": 30}, \"materials\": {\"lamp\": {\"type\": \"diffuse\", \"albedo\": [0, 0, 0], "
                       "\"emission\": [1, 1, 1]}}, \"shapes\": [{\"type\": \"quad\", \"material\": "
                       "\"lamp\", \"vertices\": [[-1, -0.8, 1], [1, -0.4, 1.3], [0.7, 1.1, 1.3], [-1.3, 0.7, 1]]}, "
                       "{\"type\": \"sphere\", \"material\": \"lamp\", \"center\": [0, 0, -6], \"radius\": 1}]}";
    struct scene *s = fixture_load_json(json, NULL);
    if (!s) return;
    const struct vec3 corner = vec3_make(-1.0f, -0.8f, 1.0f), ex = vec3_make(2.0f, 0.4f, 0.3f),
                      ey = vec3_make(-0.3f, 1.5f, 0.0f);
    /* In front of the one-sided lamp: its normal, ex x ey = (-0.45, -0.09, 3.12), points to +z
     * for (v0, v1, v2) as the loader orders them; p is on the side the lamp faces. */
    struct vec3 n;
    CHECK(light_sampler_triangle_point(s->lights, 0, 0, 0.0f, 0.0f, &(struct vec3){0}, &n));
    const struct vec3 p = vec3_add(vec3_make(0.1f, 0.2f, 1.15f), vec3_scale(n, 0.8f));
    double share[CELLS], omega;
    rect_cell_shares(p, corner, ex, ey, share, &omega);
    double pmf = 0.0;
    for (uint32_t t = 0; t < 2; t++) {
        CHECK(light_sampler_solid_angle_from(s->lights, p, 0, t));
        pmf += (double)light_sampler_pdf_a(s->lights, 0, t) * 0.5 * (double)vec3_length(vec3_cross(ex, ey));
    }
    CHECK(pmf > 0.05 && pmf < 0.95);
    const float pdf_rect = (float)(pmf / omega);
    static long counts[CELLS];
    struct rng r = rng_make(19, 0, 0, 0);
    long n_samples = 0, per[2] = {0, 0}, pdf_off = 0, off = 0;
    const float lx = vec3_length(ex), ly = vec3_length(ey);
    while (n_samples < 400000) {
        struct light_sample ls;
        if (!quad_sample_from(s->lights, p, &r, &ls)) continue;
        pdf_off += !(fabsf(ls.pdf_w - pdf_rect) <= 1e-5f * pdf_rect);
        struct vec3 w = vec3_sub(ls.p, corner);
        double u = vec3_dot(w, ex) / (lx * lx), v = vec3_dot(w, ey) / (ly * ly);
        off += !(u > -1e-5 && u < 1.0 + 1e-5 && v > -1e-5 && v < 1.0 + 1e-5);
        counts[rect_cell_of(u, v)]++;
        per[ls.prim]++;
        n_samples++;
    }
    CHECK_MSG(off == 0, "%ld samples off the rectangle", off);
    CHECK_MSG(per[0] > 0 && per[1] > 0, "one triangle never sampled (%ld, %ld)", per[0], per[1]);
    CHECK_MSG(pdf_off == 0, "%ld samples whose pdf is not the rectangle's %g", pdf_off, (double)pdf_rect);
    for (uint32_t t = 0; t < 2; t++) {
        struct vec3 q;
        CHECK(light_sampler_triangle_point(s->lights, 0, t, 0.3f, 0.3f, &q, &n));
        const float back = light_sampler_pdf_w_from(s->lights, p, 0, t, q);
        CHECK_MSG(fabsf(back - pdf_rect) <= 1e-5f * pdf_rect, "triangle %u: pdf %g, the rectangle's %g", t, (double)back,
                  (double)pdf_rect);
    }
    double chi2 = 0.0;
    for (int c = 0; c < CELLS_N * CELLS_N; c++) {
        double e = share[c] * (double)n_samples;
        chi2 += (counts[c] - e) * (counts[c] - e) / e;
    }
    double z = chi2_as_z(chi2, CELLS_N * CELLS_N - 1);
    printf("  light sampler, rectangle: Omega %.4f, triangles %ld / %ld, chi-square z %.2f\n", omega, per[0], per[1], z);
    CHECK_MSG(z < 4.0, "light sampler, rectangle: chi-square z %.2f", z);
    scene_release(s);
}

TEST_MAIN(TEST(test_atan2_upper_matches_libm), TEST(test_warp_uniform_chi2), TEST(test_pdf_integrates_to_one),
          TEST(test_sample_invert_round_trip), TEST(test_rect_warp_uniform_chi2),
          TEST(test_light_sampler_decision_and_pdf_agree), TEST(test_light_sampler_solid_angle_uniform_chi2),
          TEST(test_light_sampler_rect_uniform_chi2))
