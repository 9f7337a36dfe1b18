/* light_sampler.c — emitters of a committed scene: every emissive triangle, every emissive
 * sphere, and the constant environment, picked by an alias table proportional to emitted power
 * and sampled uniformly by area (environment: uniformly over the sphere of directions).
 * Geometry is captured in world space at creation (the scene's transforms). */
#include "scene/light_sampler.h"

#include <stdio.h>
#include <stdlib.h>

#include "core/distrib.h"
#include "core/sampling.h"
#include "scene/scene.h"

enum light_kind { LIGHT_TRIANGLE, LIGHT_SPHERE, LIGHT_ENV };

struct light_entry {
    enum light_kind kind;
    uint32_t shape, prim;
    struct vec3 p0, e1, e2;  /* triangle: p0 + b1 e1 + b2 e2; sphere: p0 = centre, e1.x = radius */
    struct vec3 n;           /* triangle: unit front normal */
    float area;
    const struct material *material;  /* surfaces: the emitter's (its emission) */
};

struct light_sampler {
    uint32_t count;
    struct light_entry *entries;
    struct distrib dist;
    int64_t *shape_first;    /* shape -> index of its first entry, or -1 */
    uint32_t shape_count;
    int64_t env_entry;       /* -1 without environment */
};

static struct vec3 light_sampler_world(const struct shape *s, uint32_t v)
{
    return xform_point(&s->to_world, s->positions[v]);
}

struct light_sampler *light_sampler_new(const struct scene *scene, struct err *err)
{
    struct light_sampler *ls = calloc(1, sizeof *ls);
    if (!ls) goto nomem;
    ls->shape_count = scene->shape_count;
    ls->env_entry = -1;
    ls->shape_first = malloc((scene->shape_count ? scene->shape_count : 1) * sizeof *ls->shape_first);
    if (!ls->shape_first) goto nomem;

    uint64_t count = 0;
    for (uint32_t i = 0; i < scene->shape_count; i++) {
        const struct shape *s = &scene->shapes[i];
        if (material_is_emissive(&scene->materials[s->material]))
            count += s->kind == SHAPE_MESH ? s->triangle_count : 1;
    }
    bool has_env = !vec3_is_zero(scene->env_radiance);
    count += has_env;
    if (count > UINT32_MAX / 2) {
        light_sampler_free(ls);
        err_set(err, ERR_LIMIT, NULL, "too many emissive primitives (%llu)", (unsigned long long)count);
        return NULL;
    }
    ls->entries = calloc(count ? count : 1, sizeof *ls->entries);
    double *power = calloc(count ? count : 1, sizeof *power);
    if (!ls->entries || !power) {
        free(power);
        goto nomem;
    }

    uint32_t k = 0;
    for (uint32_t i = 0; i < scene->shape_count; i++) {
        const struct shape *s = &scene->shapes[i];
        const struct material *m = &scene->materials[s->material];
        ls->shape_first[i] = -1;
        if (!material_is_emissive(m)) continue;
        ls->shape_first[i] = k;
        /* Power of a Lambertian emitter: pi * L * area per emitting side (luminance weighted). */
        double sides = m->two_sided_emission ? 2.0 : 1.0;
        double lum = fmax(vec3_luminance(m->emission), 1e-6 * vec3_max_comp(m->emission));
        if (s->kind == SHAPE_MESH) {
            for (uint32_t t = 0; t < s->triangle_count; t++, k++) {
                struct light_entry *e = &ls->entries[k];
                struct vec3 a = light_sampler_world(s, s->indices[3 * t]);
                struct vec3 b = light_sampler_world(s, s->indices[3 * t + 1]);
                struct vec3 c = light_sampler_world(s, s->indices[3 * t + 2]);
                e->kind = LIGHT_TRIANGLE;
                e->material = m;
                e->shape = i;
                e->prim = t;
                e->p0 = a;
                e->e1 = vec3_sub(b, a);
                e->e2 = vec3_sub(c, a);
                struct vec3 cr = vec3_cross(e->e1, e->e2);
                e->area = 0.5f * vec3_length(cr);
                e->n = vec3_normalize(cr);
                power[k] = PI_F * lum * e->area * sides;
            }
        } else {
            struct light_entry *e = &ls->entries[k];
            e->kind = LIGHT_SPHERE;
            e->material = m;
            e->shape = i;
            e->prim = 0;
            e->p0 = xform_point(&s->to_world, s->center);
            /* Emissive spheres have a uniform scale (validated at load). */
            float r = s->radius * vec3_length(xform_vector(&s->to_world, vec3_make(1, 0, 0)));
            e->e1 = vec3_make(r, 0, 0);
            e->area = 4.0f * PI_F * r * r;
            power[k] = PI_F * lum * e->area;
            k++;
        }
    }
    if (has_env) {
        /* Flux of a constant environment through the scene's bounding sphere: 4 pi^2 R^2 L. */
        struct vec3 ext = vec3_sub(scene->bounds_max, scene->bounds_min);
        double r = fmax(0.5 * vec3_length(ext), 1e-3);
        ls->entries[k].kind = LIGHT_ENV;
        ls->env_entry = k;
        power[k] = 4.0 * PI_F * PI_F * r * r * fmax(vec3_luminance(scene->env_radiance), 1e-6);
        k++;
    }
    ls->count = k;
    if (k > 0 && !distrib_init(&ls->dist, power, k, err)) {
        free(power);
        light_sampler_free(ls);
        return NULL;
    }
    free(power);
    return ls;

nomem:
    light_sampler_free(ls);
    err_set(err, ERR_NOMEM, NULL, "out of memory building the light sampler");
    return NULL;
}

void light_sampler_free(struct light_sampler *ls)
{
    if (!ls) return;
    distrib_destroy(&ls->dist);
    free(ls->entries);
    free(ls->shape_first);
    free(ls);
}

uint32_t light_sampler_count(const struct light_sampler *ls)
{
    return ls->count;
}

static inline struct vec3 light_sampler_triangle_at(const struct light_entry *e, float b1, float b2)
{
    return vec3_add(e->p0, vec3_add(vec3_scale(e->e1, b1), vec3_scale(e->e2, b2)));
}

bool light_sampler_sample(const struct light_sampler *ls, float u_pick, float u1, float u2, struct light_sample *out)
{
    if (ls->count == 0) return false;
    float pmf;
    uint32_t i = distrib_sample(&ls->dist, u_pick, &pmf);
    const struct light_entry *e = &ls->entries[i];
    /* Every field defined. */
    *out = (struct light_sample){.shape = e->shape, .prim = e->prim, .material = e->material};
    switch (e->kind) {
    case LIGHT_TRIANGLE: {
        sampling_uniform_triangle(u1, u2, &out->b1, &out->b2);
        out->p = light_sampler_triangle_at(e, out->b1, out->b2);
        out->n = e->n;
        out->pdf_a = pmf / e->area;
        break;
    }
    case LIGHT_SPHERE: {
        struct vec3 d = sampling_uniform_sphere(u1, u2);
        out->p = vec3_madd(e->p0, d, e->e1.x);
        out->n = d;
        out->pdf_a = pmf / e->area;
        break;
    }
    case LIGHT_ENV:
        out->is_env = true;
        out->dir = sampling_uniform_sphere(u1, u2);
        out->pdf_w = pmf * SAMPLING_UNIFORM_SPHERE_PDF_W;
        break;
    }
    return out->pdf_a > 0.0f || out->pdf_w > 0.0f;
}

float light_sampler_pdf_a(const struct light_sampler *ls, uint32_t shape, uint32_t prim)
{
    if (shape >= ls->shape_count || ls->shape_first[shape] < 0) return 0.0f;
    uint64_t i = (uint64_t)ls->shape_first[shape] + (ls->entries[ls->shape_first[shape]].kind == LIGHT_TRIANGLE ? prim : 0);
    /* Zero-area triangles (accepted in mesh files) get zero power and are never sampled. */
    if (i >= ls->count || !(ls->entries[i].area > 0.0f)) return 0.0f;
    return ls->dist.pmf[i] / ls->entries[i].area;
}

bool light_sampler_triangle_point(const struct light_sampler *ls, uint32_t shape, uint32_t prim, float b1, float b2,
                                  struct vec3 *p, struct vec3 *n)
{
    if (shape >= ls->shape_count || ls->shape_first[shape] < 0) return false;
    uint64_t i = (uint64_t)ls->shape_first[shape] + prim;
    if (ls->entries[ls->shape_first[shape]].kind != LIGHT_TRIANGLE || i >= ls->count) return false;
    const struct light_entry *e = &ls->entries[i];
    if (e->shape != shape || e->prim != prim) return false;
    *p = light_sampler_triangle_at(e, b1, b2);
    *n = e->n;
    return true;
}

float light_sampler_env_pdf_w(const struct light_sampler *ls)
{
    return ls->env_entry < 0 ? 0.0f : ls->dist.pmf[ls->env_entry] * SAMPLING_UNIFORM_SPHERE_PDF_W;
}
