/* test_manifold.c — manifold walks against analytic solutions: a flat mirror, a flat refractive
 * interface and a flat two-interface slab from perturbed seeds; curved casters (a glass and a
 * mirror sphere) checked by re-tracing the solved path with the BSDF's own sampling; the
 * generalized geometry term against the unfolded mirror path and against finite differences
 * of the analytic refraction solution; and the manifold shift (a walk from a solution to a
 * moved x1, at most 5 Newton steps) inverted by walking back. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "material/fresnel.h"
#include "integrators/manifold.h"
#include "material/material.h"
#include "core/rng.h"
#include "scene/scene.h"
#include "scene/surface.h"
#include "test.h"
#include "scene_fixture.h"

#define SCENE_HEAD "{\"camera\": {\"position\": [0, 5, 5], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], \"fov_deg\": 40}, "

static const char *mirror_json = SCENE_HEAD
    "\"materials\": {\"m\": {\"type\": \"conductor\", \"eta\": [0.2, 0.9, 1.1], \"k\": [3.9, 2.4, 2.1], \"roughness\": 0}},"
    "\"shapes\": [{\"type\": \"quad\", \"material\": \"m\", \"caustic_caster\": true,"
    " \"vertices\": [[-2, 0, -2], [-2, 0, 2], [2, 0, 2], [2, 0, -2]]}]}";

/* The flat mirror's chain and ends: the light's mirror image is (0.7, -2, -0.3). */
static const struct manifold_chain mirror_chain = {.shape = 0, .length = 1, .events = {MANIFOLD_REFLECT}};
static const struct manifold_ends mirror_ends = {.x1 = {-0.5f, 1.0f, 0.1f}, .ng1 = {0, 1, 0}, .xe = {0.7f, 2.0f, -0.3f},
                                                 .nge = {0, -1, 0}};

static const char *interface_json = SCENE_HEAD
    "\"materials\": {\"g\": {\"type\": \"dielectric\", \"ior\": 1.5}},"
    "\"shapes\": [{\"type\": \"quad\", \"material\": \"g\", \"caustic_caster\": true,"
    " \"vertices\": [[-3, 0, -3], [-3, 0, 3], [3, 0, 3], [3, 0, -3]]}]}";

static const char *slab_json = SCENE_HEAD
    "\"materials\": {\"g\": {\"type\": \"dielectric\", \"ior\": 1.5}},"
    "\"shapes\": [{\"type\": \"box\", \"material\": \"g\", \"caustic_caster\": true, \"min\": [-3, 0, -3], \"max\": [3, 0.3, 3]}]}";

static const char *spheres_json = SCENE_HEAD
    "\"materials\": {\"g\": {\"type\": \"dielectric\", \"ior\": 1.5},"
    " \"m\": {\"type\": \"conductor\", \"eta\": [0.2, 0.9, 1.1], \"k\": [3.9, 2.4, 2.1], \"roughness\": 0}},"
    "\"shapes\": [{\"type\": \"sphere\", \"material\": \"g\", \"caustic_caster\": true, \"center\": [0, 0, 0], \"radius\": 1},"
    " {\"type\": \"sphere\", \"material\": \"m\", \"caustic_caster\": true, \"center\": [0, 0, 0], \"radius\": 1,"
    "  \"transform\": {\"translate\": [10, 0, 0], \"scale\": 0.8}}]}";

static struct vec3 rand_vec(struct rng *r, float a)
{
    return vec3_make((rng_next_float(r) * 2.0f - 1.0f) * a, (rng_next_float(r) * 2.0f - 1.0f) * a,
                     (rng_next_float(r) * 2.0f - 1.0f) * a);
}

/* Seeds towards the solution plus a perturbation in the caster's plane; every walk must reach
 * the analytic solution. Returns the number of converged walks. */
static int walk_from_perturbed(const struct scene *s, const struct manifold_chain *ch, const struct manifold_ends *e,
                               const struct vec3 *expect, float spread, int trials, uint32_t *max_it)
{
    struct rng r = rng_make(7, 1, 2, 3);
    int converged = 0;
    *max_it = 0;
    for (int t = 0; t < trials; t++) {
        struct vec3 d = rand_vec(&r, spread);
        d.y = 0.0f;
        struct manifold_vertex v[MANIFOLD_MAX_CHAIN];
        struct ray_counters rc = {0, 0};
        if (!manifold_seed_path(s, ch, e, vec3_add(expect[0], d), v, &rc)) continue;
        struct manifold_stats st = {0};
        bool ok = manifold_walk(s, ch, e, v, MANIFOLD_MAX_ITERATIONS, &st, &rc);
        if (!ok) continue;
        converged++;
        if (st.iterations > *max_it) *max_it = st.iterations;
        for (uint32_t i = 0; i < ch->length; i++)
            CHECK_MSG(vec3_length(vec3_sub(v[i].p, expect[i])) < 1e-4f, "vertex %u at (%g %g %g), expected (%g %g %g)",
                      i, (double)v[i].p.x, (double)v[i].p.y, (double)v[i].p.z, (double)expect[i].x,
                      (double)expect[i].y, (double)expect[i].z);
        CHECK(manifold_check(s, ch, e, v, &rc));
        CHECK(manifold_constraint_norm(s, ch, e, v) < MANIFOLD_TOLERANCE);
    }
    return converged;
}

static void test_flat_mirror(void)
{
    struct scene *s = fixture_load_json(mirror_json, NULL);
    if (!s) return;
    struct manifold_chain ch = mirror_chain;
    struct manifold_ends e = mirror_ends;
    /* Mirror image of the light; the path crosses y = 0 a third of the way to it. */
    struct vec3 img = vec3_make(0.7f, -2.0f, -0.3f);
    struct vec3 expect = vec3_add(e.x1, vec3_scale(vec3_sub(img, e.x1), 1.0f / 3.0f));
    uint32_t max_it;
    int n = walk_from_perturbed(s, &ch, &e, &expect, 0.8f, 64, &max_it);
    CHECK_MSG(n == 64, "%d of 64 converged", n);
    CHECK(max_it <= MANIFOLD_MAX_ITERATIONS);
    /* Generalized geometry of a plane mirror: that of the unfolded straight path, cos θe / L². */
    struct manifold_vertex v[1];
    struct ray_counters rc = {0, 0};
    CHECK(manifold_seed_path(s, &ch, &e, expect, v, &rc) && manifold_walk(s, &ch, &e, v, 20, NULL, &rc));
    struct vec3 d = vec3_sub(img, e.x1);
    double L = vec3_length(d);
    double cos_e = fabs(vec3_dot(vec3_scale(d, 1.0f / (float)L), e.nge));
    double G = manifold_geometry(s, &ch, &e, v), Gx = cos_e / (L * L);
    CHECK_MSG(fabs(G / Gx - 1.0) < 1e-4, "G %g, expected %g", G, Gx);
    /* Throughput: the conductor's Fresnel reflectance at the reflection angle. */
    struct vec3 T = manifold_throughput(s, &ch, &e, v);
    struct vec3 F = fresnel_conductor_rgb((float)(-d.y / L), s->materials[0].eta, s->materials[0].k);
    CHECK_NEAR(T.x, F.x, 1e-5);
    CHECK_NEAR(T.z, F.z, 1e-5);
    scene_release(s);
}

/* Snell point on y = 0 between a and b at depths ha (index na) and hb (index nb). */
static struct vec3 snell_point(struct vec3 a, float ha, double na, struct vec3 b, float hb, double nb)
{
    double dx = b.x - a.x, dz = b.z - a.z, D = sqrt(dx * dx + dz * dz);
    double lo = 0.0, hi = 1.0;
    for (int i = 0; i < 200; i++) {
        double s = 0.5 * (lo + hi), x = s * D, y = (1.0 - s) * D;
        double f = na * x / sqrt(x * x + (double)ha * ha) - nb * y / sqrt(y * y + (double)hb * hb);
        if (f > 0.0) hi = s; else lo = s;
    }
    double s = 0.5 * (lo + hi);
    return vec3_make((float)(a.x + s * dx), 0.0f, (float)(a.z + s * dz));
}

static void test_flat_interface(void)
{
    struct scene *s = fixture_load_json(interface_json, NULL);
    if (!s) return;
    struct manifold_chain ch = {.shape = 0, .length = 1, .events = {MANIFOLD_REFRACT}, .ior = 1.5f};
    struct manifold_ends e = {.x1 = vec3_make(-0.3f, -1.0f, 0.2f), .ng1 = vec3_make(0, 1, 0),
                              .xe = vec3_make(0.5f, 1.5f, -0.1f), .nge = vec3_make(0, -1, 0)};
    struct vec3 expect = snell_point(e.x1, 1.0f, 1.5, e.xe, 1.5f, 1.0);
    uint32_t max_it;
    /* Seeds within 0.3 of the solution: farther, the seed path from x1 (inside) meets the surface
     * beyond the critical angle, where refraction and hence C is undefined. */
    int n = walk_from_perturbed(s, &ch, &e, &expect, 0.3f, 64, &max_it);
    CHECK_MSG(n == 64, "%d of 64 converged", n);
    /* Generalized geometry against finite differences of the analytic solution's direction
     * at x1 as the light point moves along its tangent plane. */
    struct manifold_vertex v[1];
    struct ray_counters rc = {0, 0};
    CHECK(manifold_seed_path(s, &ch, &e, expect, v, &rc) && manifold_walk(s, &ch, &e, v, 20, NULL, &rc));
    double G = manifold_geometry(s, &ch, &e, v);
    const double h = 1e-3;
    double dw[2][3];
    struct vec3 tan[2] = {vec3_make(1, 0, 0), vec3_make(0, 0, 1)};
    for (int a = 0; a < 2; a++) {
        double w[2][3];
        for (int sg = 0; sg < 2; sg++) {
            struct vec3 xe = vec3_madd(e.xe, tan[a], (float)(sg ? -h : h));
            struct vec3 q = snell_point(e.x1, 1.0f, 1.5, xe, xe.y, 1.0);
            struct vec3 wv = vec3_normalize(vec3_sub(q, e.x1));
            w[sg][0] = wv.x, w[sg][1] = wv.y, w[sg][2] = wv.z;
        }
        for (int c = 0; c < 3; c++) dw[a][c] = (w[0][c] - w[1][c]) / (2.0 * h);
    }
    struct vec3 w0 = vec3_normalize(vec3_sub(expect, e.x1));
    double cx = dw[0][1] * dw[1][2] - dw[0][2] * dw[1][1], cy = dw[0][2] * dw[1][0] - dw[0][0] * dw[1][2],
           cz = dw[0][0] * dw[1][1] - dw[0][1] * dw[1][0];
    double Gx = fabs(cx * w0.x + cy * w0.y + cz * w0.z);
    CHECK_MSG(fabs(G / Gx - 1.0) < 2e-3, "G %g, finite differences %g", G, Gx);
    /* Throughput from inside to outside: (1 - F) (1.5 / 1)^2 as the smooth dielectric weighs it. */
    struct vec3 T = manifold_throughput(s, &ch, &e, v);
    float ci = (float)(w0.y), co = sqrtf(1.0f - 1.5f * 1.5f * (1.0f - ci * ci));
    float Fx = 1.0f - fresnel_dielectric(ci, 1.0f / 1.5f);
    CHECK_NEAR(T.y, Fx * 2.25f, 1e-4);
    (void)co;
    scene_release(s);
}

/* The two points of the straight-through path x1 -> slab [0, 0.3] -> xe (outside angle a,
 * inside b with sin a = 1.5 sin b; horizontal reach (h1 + h2) tan a + 0.3 tan b). */
static void slab_points(struct vec3 x1, struct vec3 xe, struct vec3 out[2])
{
    double dx = xe.x - x1.x, dz = xe.z - x1.z, D = sqrt(dx * dx + dz * dz), H = (double)-x1.y + (xe.y - 0.3);
    double lo = 0.0, hi = M_PI / 2 - 1e-9;
    for (int i = 0; i < 200; i++) {
        double a = 0.5 * (lo + hi), b = asin(sin(a) / 1.5);
        if (H * tan(a) + 0.3 * tan(b) > D) hi = a; else lo = a;
    }
    double a = 0.5 * (lo + hi), b = asin(sin(a) / 1.5);
    double r1 = -x1.y * tan(a) / D, r2 = (-x1.y * tan(a) + 0.3 * tan(b)) / D;
    out[0] = vec3_make((float)(x1.x + r1 * dx), 0.0f, (float)(x1.z + r1 * dz));
    out[1] = vec3_make((float)(x1.x + r2 * dx), 0.3f, (float)(x1.z + r2 * dz));
}

static void test_flat_slab(void)
{
    struct scene *s = fixture_load_json(slab_json, NULL);
    if (!s) return;
    struct manifold_chain ch = {.shape = 0, .length = 2, .events = {MANIFOLD_REFRACT, MANIFOLD_REFRACT}, .ior = 1.5f};
    struct manifold_ends e = {.x1 = vec3_make(-0.3f, -1.0f, 0.2f), .ng1 = vec3_make(0, 1, 0),
                              .xe = vec3_make(0.6f, 1.5f, -0.4f), .nge = vec3_make(0, -1, 0)};
    struct vec3 expect[2];
    slab_points(e.x1, e.xe, expect);
    uint32_t max_it;
    int n = walk_from_perturbed(s, &ch, &e, expect, 0.8f, 64, &max_it);
    CHECK_MSG(n == 64, "%d of 64 converged", n);
    /* Generalized geometry of the two-vertex chain against finite differences of the analytic
     * path's direction at x1 as the light point moves. */
    struct manifold_vertex v[2];
    struct ray_counters rc = {0, 0};
    CHECK(manifold_seed_path(s, &ch, &e, expect[0], v, &rc) && manifold_walk(s, &ch, &e, v, 20, NULL, &rc));
    double G = manifold_geometry(s, &ch, &e, v);
    const double h = 1e-3;
    double dw[2][3];
    struct vec3 tan[2] = {vec3_make(1, 0, 0), vec3_make(0, 0, 1)};
    for (int a = 0; a < 2; a++) {
        double w[2][3];
        for (int sg = 0; sg < 2; sg++) {
            struct vec3 q[2];
            slab_points(e.x1, vec3_madd(e.xe, tan[a], (float)(sg ? -h : h)), q);
            struct vec3 wv = vec3_normalize(vec3_sub(q[0], e.x1));
            w[sg][0] = wv.x, w[sg][1] = wv.y, w[sg][2] = wv.z;
        }
        for (int c = 0; c < 3; c++) dw[a][c] = (w[0][c] - w[1][c]) / (2.0 * h);
    }
    struct vec3 w0 = vec3_normalize(vec3_sub(expect[0], e.x1));
    double cx = dw[0][1] * dw[1][2] - dw[0][2] * dw[1][1], cy = dw[0][2] * dw[1][0] - dw[0][0] * dw[1][2],
           cz = dw[0][0] * dw[1][1] - dw[0][1] * dw[1][0];
    double Gx = fabs(cx * w0.x + cy * w0.y + cz * w0.z);
    CHECK_MSG(fabs(G / Gx - 1.0) < 2e-3, "G %g, finite differences %g", G, Gx);
    scene_release(s);
}

/* Re-traces a solution independently: from x1 towards the first vertex, then scattered by the
 * material's own delta sampling (forced lobe); the last ray must pass through the light point. */
static bool retrace(const struct scene *s, const struct manifold_chain *ch, const struct manifold_ends *e,
                    const struct manifold_vertex *v, double *miss)
{
    struct vec3 org = e->x1, dir = vec3_normalize(vec3_sub(v[0].p, e->x1)), ng = e->ng1;
    struct vec3 last = org;
    for (uint32_t i = 0; i < ch->length; i++) {
        struct hit h;
        struct ray_counters rc = {0, 0};
        struct vec3 o = surface_offset(org, ng, dir);
        /* Aimed from the offset origin: a ray parallel to the x1 -> v[0] line but shifted by the
         * offset lands beside v[0], where a curved caster's normal differs and turns the
         * scattered ray (aimed so, the misses measured here are 2-3x smaller on all four
         * casters). */
        if (i == 0) dir = vec3_normalize(vec3_sub(v[0].p, o));
        if (!accel_intersect(s->accel, o, dir, 0.0f, INFINITY, &h, &rc) || h.shape != ch->shape) return false;
        struct surface sf;
        surface_from_hit(s, &h, o, dir, &sf);
        const struct material *m = &s->materials[sf.material];
        struct bsdf_sample bs;
        float u_lobe = ch->events[i] == MANIFOLD_REFRACT ? 0.999999f : 0.0f;
        if (!material_sample(m, frame_to_local(&sf.frame, vec3_neg(dir)), u_lobe, 0.5f, 0.5f, TRANSPORT_RADIANCE, &bs))
            return false;
        if ((ch->events[i] == MANIFOLD_REFRACT) != ((bs.flags & BSDF_TRANSMISSION) != 0)) return false;
        dir = frame_to_world(&sf.frame, bs.wi);
        org = sf.p;
        ng = sf.ng;
        last = sf.p;
    }
    /* Distance of the light point from the outgoing ray, relative to the distance along it. */
    struct vec3 to = vec3_sub(e->xe, last);
    double along = vec3_dot(to, dir);
    *miss = vec3_length(vec3_sub(to, vec3_scale(dir, (float)along))) / along;
    return along > 0.0;
}

/* Walks `v` as manifold_walk does (analytic Jacobians) and a copy of it with the Newton steps'
 * Jacobians by forward differences: both must succeed or fail alike and end at the same
 * solution (1e-6); each one's Newton steps add to steps[0] (analytic) and steps[1]. */
static bool walk_both_ways(const struct scene *s, const struct manifold_chain *ch, const struct manifold_ends *e,
                           struct manifold_vertex *v, uint32_t max_iterations, uint32_t steps[2],
                           struct ray_counters *rc)
{
    struct manifold_vertex w[MANIFOLD_MAX_CHAIN];
    memcpy(w, v, ch->length * sizeof *v);
    struct manifold_stats sa = {0}, sf = {0};
    bool ok = manifold_walk(s, ch, e, v, max_iterations, &sa, rc);
    bool okf = manifold_test_walk_forward_differences(s, ch, e, w, max_iterations, &sf, rc);
    CHECK_MSG(ok == okf, "analytic walk %s, forward differences %s", ok ? "converged" : "failed",
              okf ? "converged" : "failed");
    CHECK(!(ok && okf) || manifold_same(v, w, ch->length, 1e-6f));
    steps[0] += sa.iterations;
    steps[1] += sf.iterations;
    return ok;
}

/* Random seeds on a curved caster; every solution must pass manifold_check and re-trace to
 * the light point within `tol` of the path length. Every walk is also taken with
 * forward-difference Jacobians (walk_both_ways), the Newton steps adding to all_steps. */
static void curved(const struct scene *s, const struct manifold_chain *ch, const struct manifold_ends *e,
                   struct vec3 centre, struct vec3 spread, double tol, const char *what, uint32_t all_steps[2])
{
    struct rng r = rng_make(11, ch->shape, ch->length, 0);
    int converged = 0, retraced = 0, tried = 0;
    double worst = 0.0;
    uint32_t steps[2] = {0, 0};
    for (int t = 0; t < 200; t++) {
        struct manifold_vertex v[MANIFOLD_MAX_CHAIN];
        struct ray_counters rc = {0, 0};
        struct vec3 d = vec3_mul(rand_vec(&r, 1.0f), spread);
        if (!manifold_seed_path(s, ch, e, vec3_add(centre, d), v, &rc)) continue;
        tried++;
        if (!walk_both_ways(s, ch, e, v, MANIFOLD_MAX_ITERATIONS, steps, &rc) || !manifold_check(s, ch, e, v, &rc))
            continue;
        converged++;
        double miss;
        if (retrace(s, ch, e, v, &miss)) {
            retraced++;
            if (miss > worst) worst = miss;
        }
    }
    printf("  %s: %d seeds, %d solutions, worst miss %.3g; Newton steps %u analytic, %u forward differences\n",
           what, tried, converged, worst, steps[0], steps[1]);
    all_steps[0] += steps[0];
    all_steps[1] += steps[1];
    CHECK_MSG(converged > 10, "%s: %d of %d", what, converged, tried);
    CHECK_MSG(retraced == converged, "%s: %d of %d retraced", what, retraced, converged);
    CHECK_MSG(worst < tol, "%s: a re-traced path misses the light by %g of its length", what, worst);
}

/* The walks on the four casters take no more Newton steps in all with analytic Jacobians than
 * with forward differences (the same seeds reach the same solutions: walk_both_ways). A single
 * walk may take one more or one fewer: in a walk that wanders near a fold, where J is badly
 * conditioned, the Jacobians' ~1e-7 difference changes the step by ~1e-3 and the path of step
 * halvings with it; or the last step lands on the other side of the polishing tolerance. */
static void test_curved(void)
{
    struct err err = {0};
    uint32_t steps[2] = {0, 0};
    /* Meshes with interpolated normals: the bumpy glass slab (two refractions) and the bumpy
     * metal plane (one reflection) of the scene library. */
    struct scene *s = scene_load_file("scenes/refractive-slab/scene.json", &err);
    CHECK_MSG(s && scene_commit(s, &err), "%s", err.message);
    if (s) {
        int slab = scene_find_shape(s, "slab");
        CHECK(slab >= 0);
        struct manifold_chain ch = {.shape = (uint32_t)slab, .length = 2, .events = {MANIFOLD_REFRACT, MANIFOLD_REFRACT},
                                    .ior = 1.5f};
        struct manifold_ends e = {.x1 = vec3_make(0.1f, 0.0f, 0.05f), .ng1 = vec3_make(0, 1, 0),
                                  .xe = vec3_make(-0.3f, 2.4f, -0.05f), .nge = vec3_make(0, -1, 0)};
        curved(s, &ch, &e, vec3_make(0.1f, 0.82f, 0.0f), vec3_make(0.3f, 0.0f, 0.3f), 1e-4, "bumpy slab, two refractions",
               steps);
        scene_release(s);
    }
    s = scene_load_file("scenes/reflective-plane/scene.json", &err);
    CHECK_MSG(s && scene_commit(s, &err), "%s", err.message);
    if (s) {
        int plane = scene_find_shape(s, "plane");
        CHECK(plane >= 0);
        struct manifold_chain ch = {.shape = (uint32_t)plane, .length = 1, .events = {MANIFOLD_REFLECT}};
        struct manifold_ends e = {.x1 = vec3_make(0.1f, 0.8f, -1.2f), .ng1 = vec3_make(0, 0, 1),
                                  .xe = vec3_make(0.0f, 1.0f, 1.3f), .nge = vec3_make(0, -1, 0)};
        curved(s, &ch, &e, vec3_make(0, 0, 0), vec3_make(0.8f, 0.0f, 0.8f), 1e-4, "bumpy metal plane, one reflection",
               steps);
        scene_release(s);
    }
    /* Analytic spheres: Embree intersects them in float, and the hit is re-projected radially,
     * which moves path tracing's own hit off the ray by up to ~4e-5 of the radius: the re-traced
     * path is only that accurate, while the walk solves the exact sphere in double. */
    s = fixture_load_json(spheres_json, NULL);
    if (!s) return;
    struct manifold_chain glass = {.shape = 0, .length = 2, .events = {MANIFOLD_REFRACT, MANIFOLD_REFRACT}, .ior = 1.5f};
    struct manifold_ends eg = {.x1 = vec3_make(0.2f, -2.5f, 0.1f), .ng1 = vec3_make(0, 1, 0),
                               .xe = vec3_make(-0.3f, 3.0f, 0.2f), .nge = vec3_make(0, -1, 0)};
    curved(s, &glass, &eg, vec3_make(0, 0, 0), vec3_splat(0.7f), 2e-3, "glass sphere, two refractions", steps);
    struct manifold_chain mirror = {.shape = 1, .length = 1, .events = {MANIFOLD_REFLECT}};
    struct manifold_ends em = {.x1 = vec3_make(10.5f, 2.0f, 1.0f), .ng1 = vec3_make(0, 1, 0),
                               .xe = vec3_make(8.0f, 1.5f, -1.5f), .nge = vec3_make(1, 0, 0)};
    curved(s, &mirror, &em, vec3_make(10, 0, 0), vec3_splat(0.7f), 2e-3, "mirror sphere (scaled), one reflection", steps);
    scene_release(s);
    printf("  Newton steps in all: %u analytic, %u forward differences\n", steps[0], steps[1]);
    CHECK_MSG(steps[0] <= steps[1], "%u Newton steps with analytic Jacobians, %u with differences", steps[0], steps[1]);
}

/* The largest |a - b| over an r × c block, and the largest |b|. */
static void block_error(const double *a, const double *b, int rows, int cols, int stride, double *diff, double *scale)
{
    for (int i = 0; i < rows; i++)
        for (int j = 0; j < cols; j++) {
            *diff = fmax(*diff, fabs(a[i * stride + j] - b[i * stride + j]));
            *scale = fmax(*scale, fabs(b[i * stride + j]));
        }
}

/* Analytic J = dC / d(u, v) and B = dC / d(end point) against central differences at seed paths
 * aimed around `centre` (not solutions) and at the solutions walked from them: max |ΔJ| ≤
 * JAC_TOL max |J| + 1e-8, B likewise. */
#define JAC_TOL 1e-9
static void derivatives_hold(const struct scene *s, const struct manifold_chain *ch, const struct manifold_ends *e,
                             struct vec3 centre, struct vec3 spread, const char *what)
{
    enum { N = 2 * MANIFOLD_MAX_CHAIN };
    const int n2 = 2 * (int)ch->length;
    struct rng r = rng_make(13, ch->shape, ch->length, 1);
    int checked[2] = {0, 0};
    double worst[2] = {0.0, 0.0};
    for (int t = 0; t < 24; t++) {
        struct manifold_vertex v[MANIFOLD_MAX_CHAIN];
        struct ray_counters rc = {0, 0};
        if (!manifold_seed_path(s, ch, e, vec3_add(centre, vec3_mul(rand_vec(&r, 1.0f), spread)), v, &rc)) continue;
        for (int solved = 0; solved < 2; solved++) {
            if (solved && !manifold_walk(s, ch, e, v, MANIFOLD_MAX_ITERATIONS, NULL, &rc)) break;
            double Ja[N][N], Ba[N][2], Jd[N][N], Bd[N][2];
            bool oka = manifold_test_derivatives(s, ch, e, v, false, Ja, Ba);
            bool okd = manifold_test_derivatives(s, ch, e, v, true, Jd, Bd);
            CHECK_MSG(oka || !okd, "%s: analytic derivatives undefined where differences are not", what);
            if (!oka || !okd) continue;
            double dj = 0.0, sj = 0.0, db = 0.0, sb = 0.0;
            block_error(&Ja[0][0], &Jd[0][0], n2, n2, N, &dj, &sj);
            block_error(&Ba[0][0], &Bd[0][0], n2, 2, 2, &db, &sb);
            CHECK_MSG(dj <= JAC_TOL * sj + 1e-8 && db <= JAC_TOL * sb + 1e-8,
                      "%s (%s): max |dJ| %.3g of max |J| %.3g, max |dB| %.3g of %.3g", what,
                      solved ? "solution" : "seed path", dj, sj, db, sb);
            checked[solved]++;
            worst[solved] = fmax(worst[solved], fmax(dj / sj, db / sb));
        }
    }
    printf("  %s: %d seed paths, %d solutions; worst relative error %.2g, %.2g\n", what, checked[0], checked[1],
           worst[0], worst[1]);
    CHECK_MSG(checked[0] >= 8 && checked[1] >= 8, "%s: %d seed paths, %d solutions checked", what, checked[0],
              checked[1]);
}

static void test_analytic_jacobian(void)
{
    struct scene *s = fixture_load_json(mirror_json, NULL);
    if (s) {
        struct manifold_chain ch = mirror_chain;
        struct manifold_ends e = mirror_ends;
        derivatives_hold(s, &ch, &e, vec3_make(-0.1f, 0, 0), vec3_make(0.8f, 0, 0.8f), "plane mirror");
        scene_release(s);
    }
    s = fixture_load_json(interface_json, NULL);
    if (s) {
        struct manifold_chain ch = {.shape = 0, .length = 1, .events = {MANIFOLD_REFRACT}, .ior = 1.5f};
        struct manifold_ends e = {.x1 = vec3_make(-0.3f, -1.0f, 0.2f), .ng1 = vec3_make(0, 1, 0),
                                  .xe = vec3_make(0.5f, 1.5f, -0.1f), .nge = vec3_make(0, -1, 0)};
        derivatives_hold(s, &ch, &e, snell_point(e.x1, 1.0f, 1.5, e.xe, 1.5f, 1.0), vec3_make(0.3f, 0, 0.3f),
                         "flat refractive interface");
        scene_release(s);
    }
    s = fixture_load_json(slab_json, NULL);
    if (s) {
        struct manifold_chain ch = {.shape = 0, .length = 2, .events = {MANIFOLD_REFRACT, MANIFOLD_REFRACT}, .ior = 1.5f};
        struct manifold_ends e = {.x1 = vec3_make(-0.3f, -1.0f, 0.2f), .ng1 = vec3_make(0, 1, 0),
                                  .xe = vec3_make(0.6f, 1.5f, -0.4f), .nge = vec3_make(0, -1, 0)};
        struct vec3 q[2];
        slab_points(e.x1, e.xe, q);
        derivatives_hold(s, &ch, &e, q[0], vec3_make(0.8f, 0, 0.8f), "flat slab");
        scene_release(s);
    }
    s = fixture_load_json(spheres_json, NULL);
    if (s) {
        struct manifold_chain glass = {.shape = 0, .length = 2, .events = {MANIFOLD_REFRACT, MANIFOLD_REFRACT},
                                       .ior = 1.5f};
        struct manifold_ends eg = {.x1 = vec3_make(0.2f, -2.5f, 0.1f), .ng1 = vec3_make(0, 1, 0),
                                   .xe = vec3_make(-0.3f, 3.0f, 0.2f), .nge = vec3_make(0, -1, 0)};
        derivatives_hold(s, &glass, &eg, vec3_make(0, 0, 0), vec3_splat(0.7f), "glass sphere");
        struct manifold_chain mirror = {.shape = 1, .length = 1, .events = {MANIFOLD_REFLECT}};
        struct manifold_ends em = {.x1 = vec3_make(10.5f, 2.0f, 1.0f), .ng1 = vec3_make(0, 1, 0),
                                   .xe = vec3_make(8.0f, 1.5f, -1.5f), .nge = vec3_make(1, 0, 0)};
        derivatives_hold(s, &mirror, &em, vec3_make(10, 0, 0), vec3_splat(0.7f), "mirror sphere (scaled)");
        scene_release(s);
    }
    /* Meshes with interpolated normals: the frame turns with the normal across a triangle. */
    struct err err = {0};
    s = scene_load_file("scenes/refractive-slab/scene.json", &err);
    CHECK_MSG(s && scene_commit(s, &err), "%s", err.message);
    if (s) {
        struct manifold_chain ch = {.shape = (uint32_t)scene_find_shape(s, "slab"), .length = 2,
                                    .events = {MANIFOLD_REFRACT, MANIFOLD_REFRACT}, .ior = 1.5f};
        struct manifold_ends e = {.x1 = vec3_make(0.1f, 0.0f, 0.05f), .ng1 = vec3_make(0, 1, 0),
                                  .xe = vec3_make(-0.3f, 2.4f, -0.05f), .nge = vec3_make(0, -1, 0)};
        derivatives_hold(s, &ch, &e, vec3_make(0.1f, 0.82f, 0), vec3_make(0.3f, 0, 0.3f), "bumpy slab mesh");
        scene_release(s);
    }
    s = scene_load_file("scenes/reflective-plane/scene.json", &err);
    CHECK_MSG(s && scene_commit(s, &err), "%s", err.message);
    if (s) {
        struct manifold_chain ch = {.shape = (uint32_t)scene_find_shape(s, "plane"), .length = 1,
                                    .events = {MANIFOLD_REFLECT}};
        struct manifold_ends e = {.x1 = vec3_make(0.1f, 0.8f, -1.2f), .ng1 = vec3_make(0, 0, 1),
                                  .xe = vec3_make(0.0f, 1.0f, 1.3f), .nge = vec3_make(0, -1, 0)};
        derivatives_hold(s, &ch, &e, vec3_make(0, 0, 0), vec3_make(0.8f, 0, 0.8f), "bumpy metal plane mesh");
        scene_release(s);
    }
}

/* The manifold shift: walk a solution to a moved x1 in at most 5 steps; walking the result back
 * to the original x1 must give the original solution. */
static void test_shift_inverts(void)
{
    struct scene *s = fixture_load_json(spheres_json, NULL);
    if (!s) return;
    struct manifold_chain ch = {.shape = 0, .length = 2, .events = {MANIFOLD_REFRACT, MANIFOLD_REFRACT}, .ior = 1.5f};
    struct manifold_ends e = {.x1 = vec3_make(0.2f, -2.5f, 0.1f), .ng1 = vec3_make(0, 1, 0),
                              .xe = vec3_make(-0.3f, 3.0f, 0.2f), .nge = vec3_make(0, -1, 0)};
    struct rng r = rng_make(5, 5, 5, 5);
    int bases = 0, shifted = 0, inverted = 0;
    uint32_t steps[2] = {0, 0};
    for (int t = 0; t < 100; t++) {
        struct manifold_vertex base[2], y[2], back[2];
        struct ray_counters rc = {0, 0};
        struct vec3 x1 = vec3_add(e.x1, rand_vec(&r, 0.3f));
        struct manifold_ends eb = e;
        eb.x1 = x1;
        if (!manifold_seed_path(s, &ch, &eb, rand_vec(&r, 0.6f), base, &rc) || !walk_both_ways(s, &ch, &eb, base, 20, steps, &rc) ||
            !manifold_check(s, &ch, &eb, base, &rc))
            continue;
        bases++;
        struct manifold_ends es = eb;
        es.x1 = vec3_add(x1, rand_vec(&r, 0.05f));
        memcpy(y, base, sizeof y);
        if (!walk_both_ways(s, &ch, &es, y, 5, steps, &rc) || !manifold_check(s, &ch, &es, y, &rc)) continue;
        shifted++;
        memcpy(back, y, sizeof back);
        if (walk_both_ways(s, &ch, &eb, back, 5, steps, &rc) && manifold_same(back, base, 2, 1e-4f)) inverted++;
    }
    printf("  %d solutions, %d shifted, %d walked back to the base; Newton steps %u analytic, %u forward differences\n",
           bases, shifted, inverted, steps[0], steps[1]);
    CHECK_MSG(steps[0] <= steps[1], "%u Newton steps with analytic Jacobians, %u with differences", steps[0], steps[1]);
    CHECK(bases > 20);
    CHECK_MSG(shifted >= bases * 3 / 4, "%d of %d shifted", shifted, bases);
    CHECK_MSG(inverted == shifted, "%d of %d inverted", inverted, shifted);
    scene_release(s);
}

/* The scene key that sets a caster's chain: defaults by material, explicit 1 on a dielectric. */
static void test_caustic_interfaces_key(void)
{
    struct err err = {0};
    struct scene *s = scene_load_file("scenes/refractive-slab/scene.json", &err);
    CHECK_MSG(s != NULL, "%s", err.message);
    if (s) {
        CHECK(s->shapes[scene_find_shape(s, "slab")].caustic_interfaces == 2);
        CHECK(s->shapes[scene_find_shape(s, "floor")].caustic_interfaces == 0);
        scene_release(s);
    }
    s = scene_load_file("scenes/reflective-plane/scene.json", &err);
    CHECK_MSG(s != NULL, "%s", err.message);
    if (s) {
        CHECK(s->shapes[scene_find_shape(s, "plane")].caustic_interfaces == 1);
        scene_release(s);
    }
    static const char *json = SCENE_HEAD "\"materials\": {\"g\": {\"type\": \"dielectric\", \"ior\": 1.33}},"
        "\"shapes\": [{\"type\": \"quad\", \"material\": \"g\", \"caustic_caster\": true, \"caustic_interfaces\": 1,"
        " \"vertices\": [[-3, 0, -3], [-3, 0, 3], [3, 0, 3], [3, 0, -3]]}]}";
    s = scene_load_json(json, strlen(json), NULL, &err);
    CHECK_MSG(s != NULL, "%s", err.message);
    if (s) {
        CHECK(s->shapes[0].caustic_interfaces == 1);
        scene_release(s);
    }
}

/* The constraint is linear near a solution: ‖C‖ / t stays the same as the vertex moves t away
 * from it, on both sides of the point where a small angle stops being taken as r - r³/3 and
 * goes to atan2 (|Δ| = 1e-3 rad: between t = 6e-4 and 2e-3 here), on a flat mirror and a flat
 * refractive interface. (Below t ~ 1e-4 the float points of the seed path blur the ratio.) */
static void constraint_linear_across(const struct scene *s, const struct manifold_chain *ch,
                                     const struct manifold_ends *e, const struct vec3 *expect, const char *name)
{
    const struct vec3 dir = vec3_normalize(vec3_make(1.0f, 0.0f, 0.3f));
    static const double ts[] = {1e-4, 3e-4, 6e-4, 2e-3, 4e-3};
    double ratio[5];
    for (int k = 0; k < 5; k++) {
        struct manifold_vertex v[MANIFOLD_MAX_CHAIN];
        struct ray_counters rc = {0, 0};
        CHECK(manifold_seed_path(s, ch, e, vec3_add(expect[0], vec3_scale(dir, (float)ts[k])), v, &rc));
        ratio[k] = manifold_constraint_norm(s, ch, e, v) / ts[k];
    }
    for (int k = 0; k < 5; k++)
        CHECK_MSG(fabs(ratio[k] / ratio[1] - 1.0) < 5e-3, "%s: |C| / t = %.6g at t = %g, %.6g at t = 3e-4", name,
                  ratio[k], ts[k], ratio[1]);
}

static void test_constraint_is_continuous(void)
{
    struct scene *m = fixture_load_json(mirror_json, NULL);
    if (m) {
        struct manifold_chain ch = mirror_chain;
        struct manifold_ends e = mirror_ends;
        struct vec3 img = vec3_make(0.7f, -2.0f, -0.3f);
        struct vec3 expect = vec3_add(e.x1, vec3_scale(vec3_sub(img, e.x1), 1.0f / 3.0f));
        constraint_linear_across(m, &ch, &e, &expect, "mirror");
        scene_release(m);
    }
    struct scene *g = fixture_load_json(interface_json, NULL);
    if (g) {
        struct manifold_chain ch = {.shape = 0, .length = 1, .events = {MANIFOLD_REFRACT}, .ior = 1.5f};
        struct vec3 a = vec3_make(-0.6f, 1.2f, 0.2f), b = vec3_make(0.5f, -0.9f, -0.4f);
        struct manifold_ends e = {.x1 = a, .ng1 = vec3_make(0, 1, 0), .xe = b, .nge = vec3_make(0, 1, 0)};
        struct vec3 expect = snell_point(a, 1.2f, 1.0, b, 0.9f, 1.5);
        constraint_linear_across(g, &ch, &e, &expect, "interface");
        scene_release(g);
    }
}

TEST_MAIN(TEST(test_caustic_interfaces_key), TEST(test_flat_mirror), TEST(test_flat_interface), TEST(test_flat_slab), TEST(test_curved),
          TEST(test_analytic_jacobian), TEST(test_shift_inverts), TEST(test_constraint_is_continuous))
