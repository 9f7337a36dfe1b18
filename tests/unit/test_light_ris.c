/* test_light_ris.c — RIS next-event estimation is unbiased for every candidate count: its
 * direct-light estimate at fixed points of the Cornell box agrees (Welch z-test) with plain NEE
 * (M = 1, whose W is exactly 1 / pdf), and more candidates lower the variance there. A W off by
 * the 1/M factor, or a target that ignores the cosine, would move the mean or the variance. */
#include <math.h>

#include "scene/accel.h"
#include "scene/light_ris.h"
#include "core/rng.h"
#include "scene/scene.h"
#include "scene/surface.h"
#include "test.h"

struct stats { double sum, sum2; unsigned n; };

static void stats_add(struct stats *s, double v)
{
    s->sum += v;
    s->sum2 += v * v;
    s->n++;
}
static double stats_mean(const struct stats *s) { return s->sum / s->n; }
static double stats_var(const struct stats *s)
{
    double m = stats_mean(s);
    return (s->sum2 / s->n - m * m) * s->n / (s->n - 1);
}

/* Luminance of one direct-light estimate f |cos| Le V W at surface s (0 when nothing is found). */
static double estimate(const struct scene *sc, const struct surface *s, struct vec3 wo, uint32_t M, struct rng *r)
{
    struct light_ris_sample ls = {0};
    const struct material *m = &sc->materials[s->material];
    struct ray_counters rc = {0, 0};
    if (!light_ris_sample(sc, s, m, wo, M, r, &ls, NULL)) return 0.0;
    struct vec3 org = surface_offset_along(s->p, vec3_dot(ls.wi_world, s->ng) < 0.0f ? vec3_neg(s->ng) : s->ng);
    float tmax = isfinite(ls.dist) ? ls.dist * (1.0f - 1e-4f) : INFINITY;
    if (accel_occluded(sc->accel, org, ls.wi_world, 0.0f, tmax, &rc)) return 0.0;
    return vec3_luminance(vec3_mul(ls.f_cos, ls.Le)) * ls.W;
}

static void test_ris_nee_unbiased_and_lower_variance(void)
{
    struct err err = {0};
    struct scene *sc = scene_load_file("scenes/cornell-box/scene.json", &err);
    CHECK_MSG(sc != NULL, "%s", err.message);
    if (!sc) return;
    CHECK(scene_commit(sc, &err));
    /* Points on the floor, the back wall and the short block's top, seen from above/in front. */
    const struct { struct vec3 org, dir; } probes[] = {
        {{120, 400, 400}, {0, -1, 0}},
        {{450, 400, 120}, {0, -1, 0}},
        {{278, 273, 100}, {0, 0, 1}},
        {{160, 400, 150}, {0, -1, 0}},
    };
    for (size_t k = 0; k < sizeof probes / sizeof probes[0]; k++) {
        struct hit h = {0};
        struct vec3 dir = vec3_normalize(probes[k].dir);
        struct ray_counters rc = {0, 0};
        CHECK(accel_intersect(sc->accel, probes[k].org, dir, 0, INFINITY, &h, &rc));
        struct surface s;
        surface_from_hit(sc, &h, probes[k].org, dir, &s);
        struct vec3 wo = frame_to_local(&s.frame, vec3_neg(dir));
        struct stats one = {0}, eight = {0};
        for (unsigned i = 0; i < 200000; i++) {
            struct rng r = rng_make(21, k, i, 1);
            stats_add(&one, estimate(sc, &s, wo, 1, &r));
        }
        for (unsigned i = 0; i < 100000; i++) {
            struct rng r = rng_make(22, k, i, 8);
            stats_add(&eight, estimate(sc, &s, wo, 8, &r));
        }
        double m1 = stats_mean(&one), m8 = stats_mean(&eight);
        double z = (m8 - m1) / sqrt(stats_var(&one) / one.n + stats_var(&eight) / eight.n);
        CHECK_MSG(m1 > 0.0, "probe %zu sees no light", k);
        CHECK_MSG(fabs(z) < 4.5, "probe %zu: M=8 mean %.6g vs M=1 %.6g, z %.2f", k, m8, m1, z);
        CHECK_MSG(stats_var(&eight) < stats_var(&one), "probe %zu: variance M=8 %.4g not below M=1 %.4g", k,
                  stats_var(&eight), stats_var(&one));
    }
    scene_release(sc);
}

TEST_MAIN(TEST(test_ris_nee_unbiased_and_lower_variance))
