/* bdpt_paths.h — random test paths for the MIS tests of bdpt and restir_bdpt: x_0 a pinhole
 * camera, x_1 .. x_{n-2} diffuse, glossy or delta surfaces, x_{n-1} an area emitter, with the
 * per-vertex quantities a brute-force recomputation of every technique's path pdf needs. */
#ifndef RESTIRD_TEST_BDPT_PATHS_H
#define RESTIRD_TEST_BDPT_PATHS_H

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "material/material.h"
#include "core/rng.h"
#include "core/vec.h"

#define MAXV 10

struct tpath {
    int n;                         /* vertices: x_0 camera, x_1..x_{n-2} surfaces, x_{n-1} emitter */
    struct vec3 x[MAXV], nrm[MAXV];
    struct material mat[MAXV];
    bool delta[MAXV];
    float p_cam[MAXV], p_light[MAXV];   /* delta vertices: lobe probability from the camera / light side */
    struct vec3 forward;            /* camera */
    float plane2, n_light, pdf_a;   /* image-plane distance^2 (pixels), N_L, emitter area pdf */
};

static struct vec3 dir_to(const struct tpath *t, int i, int j)
{
    return vec3_normalize(vec3_sub(t->x[j], t->x[i]));
}
static float dist2(const struct tpath *t, int i, int j)
{
    return vec3_length2(vec3_sub(t->x[j], t->x[i]));
}
static float cos_at(const struct tpath *t, int i, int j)
{
    return fabsf(vec3_dot(t->nrm[i], dir_to(t, i, j)));
}
/* BSDF pdf at surface vertex i of sampling the direction to `to` given the direction to `from`. */
static float pdf_w(const struct tpath *t, int i, int from, int to)
{
    struct frame f = frame_from_normal(t->nrm[i]);
    return material_pdf(&t->mat[i], frame_to_local(&f, dir_to(t, i, from)), frame_to_local(&f, dir_to(t, i, to)));
}
static float camera_pdf_w(const struct tpath *t)
{
    float c = vec3_dot(dir_to(t, 0, 1), t->forward);
    return t->plane2 / (c * c * c);
}

static float frand(struct rng *r) { return rng_next_float(r); }

static void make_path(struct tpath *t, struct rng *r, int n)
{
    memset(t, 0, sizeof *t);
    t->n = n;
    for (int i = 0; i < n; i++)
        t->x[i] = vec3_make(4.0f * frand(r) - 2.0f, 4.0f * frand(r) - 2.0f, 4.0f * frand(r) - 2.0f);
    /* Normals on the side of both neighbours (reflection), tilted a little. */
    for (int i = 1; i < n - 1; i++) {
        struct vec3 h = vec3_add(dir_to(t, i, i - 1), dir_to(t, i, i + 1));
        h = vec3_add(vec3_normalize(h), vec3_make(0.3f * (frand(r) - 0.5f), 0.3f * (frand(r) - 0.5f), 0.3f * (frand(r) - 0.5f)));
        t->nrm[i] = vec3_normalize(h);
        float u = frand(r);
        if (u < 0.4f) {
            t->mat[i] = (struct material){.kind = MATERIAL_DIFFUSE, .albedo = vec3_splat(0.7f)};
        } else if (u < 0.75f) {
            t->mat[i] = (struct material){.kind = MATERIAL_CONDUCTOR, .eta = vec3_splat(0.2f), .k = vec3_splat(3.0f),
                                          .roughness = 0.15f + 0.5f * frand(r)};
        } else {
            t->delta[i] = true;
            t->p_cam[i] = 0.1f + 0.9f * frand(r);
            t->p_light[i] = 0.1f + 0.9f * frand(r);
        }
    }
    t->nrm[n - 1] = vec3_normalize(vec3_add(dir_to(t, n - 1, n - 2), vec3_make(0.2f * frand(r), 0.2f * frand(r), 0.0f)));
    t->forward = vec3_normalize(vec3_add(dir_to(t, 0, 1), vec3_make(0.3f * (frand(r) - 0.5f), 0.3f * (frand(r) - 0.5f), 0.0f)));
    t->plane2 = 100.0f + 10000.0f * frand(r);
    t->n_light = 16.0f + 4096.0f * frand(r);
    t->pdf_a = 0.05f + 2.0f * frand(r);
}

/* Brute force: area pdf of x_i sampled from the camera side (from x_{i-1}, x_{i-2}) and from
 * the light side (from x_{i+1}, x_{i+2}); delta vertices give their lobe probability, the delta
 * itself being common to every technique that can produce the path. */
static double pc(const struct tpath *t, int i)
{
    double g = cos_at(t, i, i - 1) / dist2(t, i - 1, i);
    if (i == 1) return camera_pdf_w(t) * g;
    if (t->delta[i - 1]) return t->p_cam[i - 1] * g;
    return pdf_w(t, i - 1, i - 2, i) * g;
}
static double pl(const struct tpath *t, int i)
{
    int n = t->n;
    if (i == n - 1) return t->pdf_a;
    double g = cos_at(t, i, i + 1) / dist2(t, i + 1, i);
    if (i == n - 2) return cos_at(t, n - 1, n - 2) * INV_PI_F * g;
    if (t->delta[i + 1]) return t->p_light[i + 1] * g;
    return pdf_w(t, i + 1, i + 2, i) * g;
}

#endif
