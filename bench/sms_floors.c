/* bench/sms_floors.c — the error a restir_sms frame that shades one selected path per pixel
 * cannot go below on a scene, whatever its reuse, as a fraction of a 1-spp `sms` frame's error.
 * Such a frame shades one jittered point x1 per pixel with one path, so even perfect resampling
 * (the reservoir's path distributed exactly in proportion to the target p̂ = luminance, [SMS-SSP]
 * §5) leaves
 *   - the jitter part: how much the caustic varies over the pixel (Var over x1 of L(x1));
 *   - the colour part: one path carries one light's colour. Grouping paths by light k, with L_k
 *     the RGB radiance of light k's paths and l_k its luminance, an exactly resampled path
 *     estimates channel c with variance  sum_k L_kc² l / l_k − L_c²  (l = sum_k l_k), exact when
 *     every path of a light has the light's colour (colourless casters, as the library's).
 * (restir_sms's expected shading averages the spatial pass's candidates, more than one path, and
 * can go somewhat below the colour part.)
 * Both are measured against the variance of one `sms` sample (uncapped Bernoulli trials) at the
 * same jittered points, summed over RGB and over the pixels whose first hit is a diffuse or glossy
 * receiver (pixels that see receivers through a caster are left out): floor / 1-spp RMSE. Built
 * and run by bench/sms.py (a benchmark helper, not part of the daemon); prints one JSON object:
 * jitter_floor, colour_floor, floor (the two together), and colour_floor_norm_target, the colour
 * part had the target been the RGB vector's length instead of its luminance.
 * usage: sms_floors SCENE.json WIDTHxHEIGHT [samples per point] [points per pixel] [pixel step] */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "scene/accel.h"
#include "scene/camera.h"
#include "material/material.h"
#include "core/rng.h"
#include "scene/scene.h"
#include "integrators/sms.h"
#include "scene/surface.h"

#define FLOORS_MAX_LIGHTS 32
#define FLOORS_MAX_POINTS 64

/* Per light shape: the mean RGB of one jittered point's samples that used it. */
struct floors_point {
    uint32_t light[FLOORS_MAX_LIGHTS];
    double L[FLOORS_MAX_LIGHTS][3];
    uint32_t lights;
    double mean[3], var[3];  /* of one sample's RGB estimate */
};

static bool floors_point(const struct scene *sc, const struct sms_scene *ss, const struct sms_params *p,
                         const struct surface *x1, struct vec3 wo, uint32_t n, struct rng *rng,
                         struct floors_point *out, struct ray_counters *rc)
{
    const struct material *m = &sc->materials[x1->material];
    double sum[3] = {0, 0, 0}, sum2[3] = {0, 0, 0};
    out->lights = 0;
    for (uint32_t i = 0; i < n; i++) {
        struct sms_solution sol;
        struct sms_counters c = {0};
        if (!sms_sample(sc, ss, p, x1, m, wo, MANIFOLD_MAX_CHAIN, rng, &sol, &c, rc)) continue;
        const double v[3] = {sol.value.x * sol.W, sol.value.y * sol.W, sol.value.z * sol.W};
        uint32_t k = 0;
        while (k < out->lights && out->light[k] != sol.light.shape) k++;
        if (k == out->lights) {
            if (k == FLOORS_MAX_LIGHTS) return false;
            out->light[k] = sol.light.shape;
            out->L[k][0] = out->L[k][1] = out->L[k][2] = 0.0;
            out->lights++;
        }
        for (int a = 0; a < 3; a++) {
            sum[a] += v[a];
            sum2[a] += v[a] * v[a];
            out->L[k][a] += v[a] / n;
        }
    }
    for (int a = 0; a < 3; a++) {
        out->mean[a] = sum[a] / n;
        out->var[a] = sum2[a] / n - out->mean[a] * out->mean[a];
    }
    return true;
}

/* Sum over RGB of the variance of one path resampled exactly by a scalar target (the colour
 * part): luminance, restir_sms's, or (`norm`) the RGB vector's length, which minimises that sum
 * among scalar targets. */
static double floors_colour(const struct floors_point *q, bool norm)
{
    double l = 0.0, lk[FLOORS_MAX_LIGHTS];
    for (uint32_t k = 0; k < q->lights; k++) {
        const double *c = q->L[k];
        lk[k] = norm ? sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]) : 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
        l += lk[k];
    }
    double v = 0.0;
    for (int a = 0; a < 3; a++) {
        double e2 = 0.0;
        for (uint32_t k = 0; k < q->lights; k++)
            if (lk[k] > 0.0) e2 += q->L[k][a] * q->L[k][a] * l / lk[k];
        v += e2 - q->mean[a] * q->mean[a];
    }
    return v > 0.0 ? v : 0.0;
}

int main(int argc, char **argv)
{
    if (argc < 3) {
        fprintf(stderr, "usage: %s SCENE.json WIDTHxHEIGHT [samples] [points] [step]\n", argv[0]);
        return 2;
    }
    unsigned w = 0, h = 0;
    if (sscanf(argv[2], "%ux%u", &w, &h) != 2 || w == 0 || h == 0) return 2;
    const uint32_t n = argc > 3 ? (uint32_t)atoi(argv[3]) : 256, points = argc > 4 ? (uint32_t)atoi(argv[4]) : 8;
    const uint32_t step = argc > 5 ? (uint32_t)atoi(argv[5]) : 4;
    if (n < 2 || points < 2 || points > FLOORS_MAX_POINTS || step == 0) return 2;
    struct err err = {0};
    struct scene *sc = scene_load_file(argv[1], &err);
    struct sms_scene ss;
    if (!sc || !scene_commit(sc, &err) || !sms_scene_init(sc, &ss, &err)) {
        fprintf(stderr, "%s: %s\n", argv[1], err.message);
        if (sc) scene_release(sc);
        return 1;
    }
    struct camera cam;
    camera_init(&cam, &sc->camera, w, h);
    struct sms_params p = sms_defaults();
    p.bernoulli_cap = 0;
    struct ray_counters rc = {0, 0};
    static struct floors_point q[FLOORS_MAX_POINTS];
    double one = 0.0, jitter = 0.0, colour = 0.0, colour_norm = 0.0;
    uint32_t pixels = 0;
    for (uint32_t py = step / 2; py < h; py += step)
        for (uint32_t px = step / 2; px < w; px += step) {
            const uint32_t pixel = py * w + px;
            struct rng jr = rng_make(3, pixel, 0, 0);
            uint32_t hits = 0;
            for (uint32_t j = 0; j < points; j++) {
                /* A pixel counts only when every point lands on a receiver (see above). */
                struct floors_point *pt = &q[j];
                *pt = (struct floors_point){0};
                struct vec3 dir = camera_ray_dir(&cam, (float)px + rng_next_float(&jr), (float)py + rng_next_float(&jr));
                struct hit hit;
                if (!accel_intersect(sc->accel, cam.position, dir, 0.0f, INFINITY, &hit, &rc)) continue;
                struct surface x1;
                surface_from_hit(sc, &hit, cam.position, dir, &x1);
                if (!(material_flags(&sc->materials[x1.material]) & (BSDF_DIFFUSE | BSDF_GLOSSY))) continue;
                struct rng rng = rng_make(7, pixel, j, 1);
                if (!floors_point(sc, &ss, &p, &x1, frame_to_local(&x1.frame, vec3_scale(dir, -1.0f)), n, &rng, pt,
                                  &rc)) {
                    fprintf(stderr, "more than %d light shapes\n", FLOORS_MAX_LIGHTS);
                    scene_release(sc);
                    return 1;
                }
                hits++;
            }
            if (hits < points) continue;
            pixels++;
            for (int a = 0; a < 3; a++) {
                double mean = 0.0, within = 0.0, between = 0.0;
                for (uint32_t j = 0; j < points; j++) mean += q[j].mean[a] / points, within += q[j].var[a] / points;
                for (uint32_t j = 0; j < points; j++)
                    between += (q[j].mean[a] - mean) * (q[j].mean[a] - mean) / (points - 1);
                /* The spread of the points' means less what their own sampling noise adds to it. */
                const double jit = between - within / n;
                one += within + jit;
                jitter += jit > 0.0 ? jit : 0.0;
            }
            for (uint32_t j = 0; j < points; j++) {
                colour += floors_colour(&q[j], false) / points;
                colour_norm += floors_colour(&q[j], true) / points;
            }
        }
    scene_release(sc);
    if (!(one > 0.0)) {
        printf("{\"pixels\":%u,\"error\":\"no caustic radiance at directly seen receivers\"}\n", pixels);
        return 0;
    }
    printf("{\"pixels\":%u,\"samples\":%u,\"points\":%u,\"jitter_floor\":%.4f,\"colour_floor\":%.4f,\"floor\":%.4f,"
           "\"colour_floor_norm_target\":%.4f}\n",
           pixels, n, points, sqrt(jitter / one), sqrt(colour / one), sqrt((jitter + colour) / one), sqrt(colour_norm / one));
    return 0;
}
