/* light_sampler.c — emitters of a committed scene: every emissive triangle, every emissive
 * sphere, and the constant environment, picked by an alias table proportional to emitted power
 * and sampled uniformly by area (environment: uniformly over the sphere of directions); from a
 * shading point (light_sampler_sample_from), a triangle seen close by is sampled uniformly in
 * the solid angle it subtends instead (core/spherical.h), a rectangle (two triangles) seen close
 * by uniformly in its solid angle as one spherical rectangle, and another quad whose two
 * triangles are both seen close by uniformly over its whole solid angle as a pair of spherical
 * triangles. Geometry is captured in world space at creation (the scene's transforms). */
#include "scene/light_sampler.h"

#include <stdio.h>
#include <stdlib.h>

#include "core/distrib.h"
#include "core/sampling.h"
#include "core/spherical.h"
#include "scene/scene.h"

/* light_sampler_sample_from samples a triangle's solid angle when the shading point is closer to
 * the triangle's centroid than its bounding radius r (the farthest vertex from the centroid)
 * over this ratio, 5 r, and by area otherwise. Area sampling's solid-angle pdf, pdf_a d^2 / cos,
 * varies over the triangle as d^3 (the cosine at the light is the plane's distance over d), so
 * its extra variance grows with the spread of d over the triangle, about r / d, while the warp
 * costs the same at any distance (about 630 instructions a sample more than area sampling).
 * Farther away the receiver's cosine, which neither sampling follows, dominates, and area
 * sampling's d^3 can even follow it better. Measured on the Cornell box's direct light
 * (docs/benchmarks.md, "Solid-angle sampling of triangle lights"): at 1 / 0.2 the back wall's
 * variance is 0.40 of area sampling's for 1.14 times the instructions; at 1 / 0.25, 0.51 for
 * 1.08 times; at 1 / 0.35 the gain is gone; at 1 / 0.15 the green wall's variance read 1.27
 * times area sampling's, which a later comparison with Cycles contradicts (0.5 times; the docs
 * mark the row). */
#define LIGHT_SOLID_ANGLE_MIN_RATIO 0.2f

enum light_kind { LIGHT_TRIANGLE, LIGHT_SPHERE, LIGHT_ENV };

/* A two-triangle emitter whose four corners form a rectangle: sampled from a shading point close
 * by as one spherical rectangle (Urena et al. 2013, core/spherical.h), which costs one warp where
 * the pair of spherical triangles costs two solid angles and a warp. The same distance rule as a
 * triangle's, from the rectangle's centre with half its diagonal as the radius. */
struct light_rect {
    struct dvec3 x, y, z;       /* unit edge directions, orthogonal, and z = x cross y */
    double lx, ly;              /* the points are corner + s x + t y, s in [0, lx], t in [0, ly] */
    /* The barycentrics of triangle k (entry first + k) at (s, t): b1 = bary[k][0] + bary[k][1] s
     * + bary[k][2] t, b2 likewise from bary[k][3..5] (its dual basis applied to corner + s x +
     * t y - p0). */
    double bary[2][6];
    struct vec3 corner, centre, n;   /* n: the triangles' unit front normal */
    float solid_angle_dist2;
    bool one_sided;
    uint32_t first;             /* the lower of the two triangles' entries */
};

struct light_entry {
    enum light_kind kind;
    uint32_t shape, prim;
    struct vec3 p0, e1, e2;  /* triangle: p0 + b1 e1 + b2 e2; sphere: p0 = centre, e1.x = radius */
    struct vec3 n;           /* triangle: unit front normal */
    float area;
    /* Triangle: its centroid and the squared distance from it within which
     * light_sampler_sample_from samples the solid angle (LIGHT_SOLID_ANGLE_MIN_RATIO); whether it
     * emits on its front side only (from behind, any sample is black). */
    struct vec3 centroid;
    float solid_angle_dist2;
    bool one_sided;
    /* Triangle: the dual basis of (e1, e2) in its plane, (q - p0) . dual_k = b_k for a point q
     * of the plane: dual1 = (e2 x N) / |N|^2, dual2 = (N x e1) / |N|^2 with N = e1 x e2. */
    struct vec3 dual1, dual2;
    const struct material *material;  /* surfaces: the emitter's (its emission) */
    /* Triangle of a two-triangle emitter (a quad): the other triangle's entry, else -1. Where both
     * sample their solid angle from the shading point, the pair is sampled as one: picked by power
     * together, then one of the two in proportion to its solid angle, so that directions are
     * uniform over the quad's whole solid angle (light_sampler_sample_from). */
    int64_t partner;
    /* A pair that forms a rectangle: its entry in light_sampler.rects, else -1 (both entries). */
    int32_t rect;
};

struct light_sampler {
    uint32_t count;
    struct light_entry *entries;
    struct distrib dist;
    int64_t *shape_first;    /* shape -> index of its first entry, or -1 */
    uint32_t shape_count;
    int64_t env_entry;       /* -1 without environment */
    struct light_rect *rects;
    uint32_t rect_count;
};

static struct vec3 light_sampler_world(const struct shape *s, uint32_t v)
{
    return xform_point(&s->to_world, s->positions[v]);
}

/* Whether the two triangles of shape s, entries e and f (sharing two vertex indices, as a quad's
 * do), form a rectangle, and if so its light_rect. The corners that are not shared, a of e and b of f,
 * are opposite; with c1, c2 the shared ones, a + (c1 - a) + (c2 - a) must be b and the two edges
 * at a orthogonal, both to 1e-5 of the edges' lengths (float vertices after a transform); the
 * triangles must face the same way. A quad off a rectangle by less than that is sampled as the
 * rectangle: a sample a little outside a triangle is clamped onto its edge. */
static bool light_rect_of(const struct shape *s, const struct light_entry *e, const struct light_entry *f,
                          struct light_rect *r)
{
    const uint32_t *ia = &s->indices[0], *ib = &s->indices[3];
    int a = -1, b = -1, shared = 0;
    for (int i = 0; i < 3; i++) {
        bool in_b = ia[i] == ib[0] || ia[i] == ib[1] || ia[i] == ib[2];
        bool in_a = ib[i] == ia[0] || ib[i] == ia[1] || ib[i] == ia[2];
        shared += in_b;
        if (!in_b) a = i;
        if (!in_a) b = i;
    }
    if (shared != 2 || a < 0 || b < 0) return false;
    struct vec3 pa = light_sampler_world(s, ia[a]), pb = light_sampler_world(s, ib[b]);
    struct vec3 c1 = light_sampler_world(s, ia[(a + 1) % 3]), c2 = light_sampler_world(s, ia[(a + 2) % 3]);
    struct vec3 ex = vec3_sub(c1, pa), ey = vec3_sub(c2, pa);
    float lx = vec3_length(ex), ly = vec3_length(ey);
    if (!(lx > 0.0f && ly > 0.0f) || !(e->area > 0.0f && f->area > 0.0f)) return false;
    float tol = 1e-5f * (lx + ly);
    if (fabsf(vec3_dot(ex, ey)) > tol * fmaxf(lx, ly) ||
        vec3_length(vec3_sub(vec3_add(pa, vec3_add(ex, ey)), pb)) > tol || vec3_dot(e->n, f->n) < 0.99999f)
        return false;
    r->corner = pa;
    r->lx = lx;
    r->ly = ly;
    r->x = dvec3_scale(dvec3_from(ex), 1.0 / lx);
    r->y = dvec3_scale(dvec3_from(ey), 1.0 / ly);
    r->z = dvec3_cross(r->x, r->y);
    for (int k = 0; k < 2; k++) {
        const struct light_entry *tri = k ? f : e;
        const struct dvec3 off = dvec3_sub(dvec3_from(pa), dvec3_from(tri->p0));
        const struct dvec3 dual[2] = {dvec3_from(tri->dual1), dvec3_from(tri->dual2)};
        for (int j = 0; j < 2; j++) {
            r->bary[k][3 * j] = dvec3_dot(dual[j], off);
            r->bary[k][3 * j + 1] = dvec3_dot(dual[j], r->x);
            r->bary[k][3 * j + 2] = dvec3_dot(dual[j], r->y);
        }
    }
    r->centre = vec3_scale(vec3_add(pa, pb), 0.5f);
    r->n = e->n;
    float radius2 = 0.25f * (lx * lx + ly * ly);
    r->solid_angle_dist2 = radius2 / (LIGHT_SOLID_ANGLE_MIN_RATIO * LIGHT_SOLID_ANGLE_MIN_RATIO);
    r->one_sided = e->one_sided;
    return true;
}

struct light_sampler *light_sampler_new(const struct scene *scene, struct err *err)
{
    struct light_sampler *ls = calloc(1, sizeof *ls);
    if (!ls) goto nomem;
    ls->shape_count = scene->shape_count;
    ls->env_entry = -1;
    ls->shape_first = malloc((scene->shape_count ? scene->shape_count : 1) * sizeof *ls->shape_first);
    if (!ls->shape_first) goto nomem;

    uint64_t count = 0, pairs = 0;
    for (uint32_t i = 0; i < scene->shape_count; i++) {
        const struct shape *s = &scene->shapes[i];
        if (material_is_emissive(&scene->materials[s->material])) {
            count += s->kind == SHAPE_MESH ? s->triangle_count : 1;
            pairs += s->kind == SHAPE_MESH && s->triangle_count == 2;
        }
    }
    bool has_env = !vec3_is_zero(scene->env_radiance);
    count += has_env;
    if (count > UINT32_MAX / 2) {
        light_sampler_free(ls);
        err_set(err, ERR_LIMIT, NULL, "too many emissive primitives (%llu)", (unsigned long long)count);
        return NULL;
    }
    ls->entries = calloc(count ? count : 1, sizeof *ls->entries);
    ls->rects = malloc((pairs ? pairs : 1) * sizeof *ls->rects);
    double *power = calloc(count ? count : 1, sizeof *power);
    if (!ls->entries || !ls->rects || !power) {
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
                e->centroid = vec3_scale(vec3_add(a, vec3_add(b, c)), 1.0f / 3.0f);
                float r2 = fmaxf(vec3_length2(vec3_sub(a, e->centroid)),
                                 fmaxf(vec3_length2(vec3_sub(b, e->centroid)), vec3_length2(vec3_sub(c, e->centroid))));
                e->solid_angle_dist2 = r2 / (LIGHT_SOLID_ANGLE_MIN_RATIO * LIGHT_SOLID_ANGLE_MIN_RATIO);
                e->one_sided = !m->two_sided_emission;
                float cr2 = vec3_length2(cr);
                if (cr2 > 0.0f) {
                    e->dual1 = vec3_scale(vec3_cross(e->e2, cr), 1.0f / cr2);
                    e->dual2 = vec3_scale(vec3_cross(cr, e->e1), 1.0f / cr2);
                }
                power[k] = PI_F * lum * e->area * sides;
                e->partner = -1;
                e->rect = -1;
            }
            if (s->triangle_count == 2) {
                ls->entries[k - 2].partner = (int64_t)k - 1;
                ls->entries[k - 1].partner = (int64_t)k - 2;
                struct light_rect *r = &ls->rects[ls->rect_count];
                if (light_rect_of(s, &ls->entries[k - 2], &ls->entries[k - 1], r)) {
                    r->first = k - 2;
                    ls->entries[k - 2].rect = ls->entries[k - 1].rect = (int32_t)ls->rect_count++;
                }
            }
        } else {
            struct light_entry *e = &ls->entries[k];
            e->kind = LIGHT_SPHERE;
            e->partner = -1;
            e->rect = -1;
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
        ls->entries[k].partner = -1;
        ls->entries[k].rect = -1;
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
    free(ls->rects);
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

/* Area sampling of entry e, picked with probability pmf (every field of *out set). */
static inline void light_sampler_sample_entry(const struct light_entry *e, float pmf, float u1, float u2,
                                              struct light_sample *out)
{
    *out = (struct light_sample){.shape = e->shape, .prim = e->prim, .material = e->material};
    /* Triangles, the common emitters, tested first: as a switch case, GCC tested the other two
     * kinds before them (four more instructions per light sample in pt's loop). */
    if (__builtin_expect(e->kind == LIGHT_TRIANGLE, 1)) {
        sampling_uniform_triangle(u1, u2, &out->b1, &out->b2);
        out->p = light_sampler_triangle_at(e, out->b1, out->b2);
        out->n = e->n;
        out->pdf_a = pmf / e->area;
        return;
    }
    switch (e->kind) {
    case LIGHT_TRIANGLE:  /* above */
        break;
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
}

bool light_sampler_sample(const struct light_sampler *ls, float u_pick, float u1, float u2, struct light_sample *out)
{
    if (ls->count == 0) return false;
    float pmf;
    uint32_t i = distrib_sample(&ls->dist, u_pick, &pmf);
    light_sampler_sample_entry(&ls->entries[i], pmf, u1, u2, out);
    return out->pdf_a > 0.0f || out->pdf_w > 0.0f;
}

/* Index of the entry of (shape, prim), or -1 when it is no emitter or a zero-area triangle
 * (accepted in mesh files; zero power, never sampled). */
static inline int64_t light_sampler_entry_of(const struct light_sampler *ls, uint32_t shape, uint32_t prim)
{
    if (shape >= ls->shape_count || ls->shape_first[shape] < 0) return -1;
    uint64_t i = (uint64_t)ls->shape_first[shape] + (ls->entries[ls->shape_first[shape]].kind == LIGHT_TRIANGLE ? prim : 0);
    if (i >= ls->count || !(ls->entries[i].area > 0.0f)) return -1;
    return (int64_t)i;
}

float light_sampler_pdf_a(const struct light_sampler *ls, uint32_t shape, uint32_t prim)
{
    int64_t i = light_sampler_entry_of(ls, shape, prim);
    return i < 0 ? 0.0f : ls->dist.pmf[i] / ls->entries[i].area;
}

/* Whether light_sampler_sample_from samples entry e's solid angle from p (the spherical triangle
 * then in *st): a triangle whose centroid is closer to p than its solid_angle_dist2 allows, that
 * p is in front of unless it emits on both sides (behind a one-sided emitter every sample is
 * black, and the cheap one is as good: the Cornell box's ceiling is behind its light), and whose
 * solid angle the warp takes. light_sampler_sample_from and light_sampler_pdf_w_from both decide
 * here (and, for a quad, in light_pair_solid_angle_from, from the two entries), from p and the
 * entries alone, so that the MIS weight of an emitter hit uses the pdf next-event estimation
 * from the same point has. */
static inline bool light_entry_solid_angle_from(const struct light_entry *e, struct vec3 p, struct spherical_triangle *st)
{
    return e->kind == LIGHT_TRIANGLE && vec3_length2(vec3_sub(p, e->centroid)) < e->solid_angle_dist2 &&
           (!e->one_sided || vec3_dot(vec3_sub(p, e->p0), e->n) > 0.0f) &&
           spherical_triangle_init(st, p, e->p0, e->e1, e->e2);
}

/* The solid-angle pdf of a direction into the spherical triangle st, with the emitter's pick. */
static inline float light_entry_solid_angle_pdf(float pmf, const struct spherical_triangle *st)
{
    return (float)((double)pmf * spherical_triangle_pdf_w(st));
}

/* Solid-angle pdf at p of area-sampling the point q with normal n at area pdf pdf_a. */
static inline float light_sampler_area_pdf_w(float pdf_a, struct vec3 p, struct vec3 q, struct vec3 n)
{
    struct vec3 d = vec3_sub(q, p);
    float d2 = vec3_length2(d);
    return d2 > 0.0f ? sampling_area_to_solid_angle(pdf_a, d2, vec3_dot(d, n) / sqrtf(d2)) : 0.0f;
}

/* The sample at barycentrics (b1, b2) of triangle e, found by a solid-angle warp from p with
 * density pdf_w there: the barycentrics are clamped to the triangle (rounding of a direction on
 * an edge) and the point is computed from them as area sampling does. */
static bool light_sampler_solid_angle_point(const struct light_entry *e, struct vec3 p, double b1, double b2,
                                            float pdf_w, struct light_sample *out)
{
    *out = (struct light_sample){.shape = e->shape, .prim = e->prim, .material = e->material, .n = e->n,
                                 .solid_angle = true};
    b1 = b1 > 0.0 ? b1 : 0.0;
    b2 = b2 > 0.0 ? b2 : 0.0;
    if (b1 + b2 > 1.0) {
        double sum = b1 + b2;
        b1 /= sum;
        b2 /= sum;
    }
    out->b1 = (float)b1;
    out->b2 = (float)b2;
    out->p = light_sampler_triangle_at(e, out->b1, out->b2);
    out->pdf_w = pdf_w;
    /* The same density per area, for callers that weigh in area measure. */
    struct vec3 d = vec3_sub(out->p, p);
    float d2 = vec3_length2(d);
    out->pdf_a = d2 > 0.0f ? out->pdf_w * fabsf(vec3_dot(d, e->n)) / (d2 * sqrtf(d2)) : 0.0f;
    return out->pdf_w > 0.0f;
}

/* A direction uniform in the solid angle of triangle e from p, and the point where it meets the
 * triangle's plane, p + t dir with t = (p0 - p) . n / dir . n, as barycentrics from the dual
 * basis (in double: the direction is). */
static bool light_sampler_sample_solid_angle(const struct light_entry *e, const struct spherical_triangle *st,
                                             struct vec3 p, float pdf_w, float u1, float u2, struct light_sample *out)
{
    struct dvec3 dir = spherical_triangle_sample_d(st, u1, u2), n = dvec3_from(e->n);
    double t = dvec3_dot(st->to_v0, n) / dvec3_dot(dir, n);
    if (!(t > 0.0) || !isfinite(t)) {
        *out = (struct light_sample){.shape = e->shape, .prim = e->prim, .material = e->material, .n = e->n,
                                     .solid_angle = true};
        return false;
    }
    struct dvec3 w = dvec3_sub(dvec3_scale(dir, t), st->to_v0);   /* p + t dir - p0 */
    return light_sampler_solid_angle_point(e, p, dvec3_dot(w, dvec3_from(e->dual1)), dvec3_dot(w, dvec3_from(e->dual2)),
                                           pdf_w, out);
}

/* Whether light_sampler_sample_from samples rectangle r's solid angle from p (the spherical
 * rectangle then in *sr): the rule of light_entry_solid_angle_from, from the rectangle's centre. */
static inline bool light_rect_solid_angle_from(const struct light_rect *r, struct vec3 p, struct spherical_rect *sr)
{
    return vec3_length2(vec3_sub(p, r->centre)) < r->solid_angle_dist2 &&
           (!r->one_sided || vec3_dot(vec3_sub(p, r->corner), r->n) > 0.0f) &&
           spherical_rect_init(sr, dvec3_sub(dvec3_from(r->corner), dvec3_from(p)), r->x, r->y, r->z, r->lx, r->ly);
}

/* The rectangle's density in solid angle: its two triangles picked together, uniform over the
 * spherical rectangle, (pmf_A + pmf_B) / Omega. */
static inline float light_rect_pdf_w(const struct light_sampler *ls, const struct light_rect *r,
                                     const struct spherical_rect *sr)
{
    return (float)(((double)ls->dist.pmf[r->first] + (double)ls->dist.pmf[r->first + 1]) / sr->solid_angle);
}

/* A point of rectangle r uniform in its solid angle from p, on whichever of the two triangles
 * holds it (on the shared diagonal either). */
static bool light_rect_sample(const struct light_sampler *ls, const struct light_rect *r, const struct spherical_rect *sr,
                              struct vec3 p, float u1, float u2, struct light_sample *out)
{
    double s, t;
    spherical_rect_sample_st(sr, u1, u2, &s, &t);
    int k = 0;
    const double *c = r->bary[0];
    double b1 = c[0] + c[1] * s + c[2] * t, b2 = c[3] + c[4] * s + c[5] * t;
    if (!(b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0)) {
        k = 1;
        c = r->bary[1];
        b1 = c[0] + c[1] * s + c[2] * t;
        b2 = c[3] + c[4] * s + c[5] * t;
    }
    return light_sampler_solid_angle_point(&ls->entries[r->first + k], p, b1, b2, light_rect_pdf_w(ls, r, sr), out);
}

/* Whether entry e and its partner both sample their solid angle from p (the two spherical triangles
 * then in st[0] for the pair's lower entry and st[1] for the higher, and *lower the lower entry's
 * index). */
static inline bool light_pair_solid_angle_from(const struct light_sampler *ls, const struct light_entry *e,
                                               struct vec3 p, const struct spherical_triangle *st_e,
                                               struct spherical_triangle st[2], int64_t *lower)
{
    if (e->partner < 0) return false;
    const struct light_entry *f = &ls->entries[e->partner];
    const bool e_lower = e < f;
    if (!light_entry_solid_angle_from(f, p, &st[e_lower])) return false;
    st[!e_lower] = *st_e;
    *lower = e_lower ? e - ls->entries : e->partner;
    return true;
}

/* The pair's density in solid angle: picked together, each of its triangles in proportion to its
 * solid angle, uniform within it: (pmf_A + pmf_B) / (Omega_A + Omega_B) over the whole quad. */
static inline float light_pair_pdf_w(const struct light_sampler *ls, int64_t lower, const struct spherical_triangle st[2])
{
    double pmf = (double)ls->dist.pmf[lower] + (double)ls->dist.pmf[lower + 1];
    return (float)(pmf / (st[0].solid_angle + st[1].solid_angle));
}

bool light_sampler_sample_from(const struct light_sampler *ls, struct vec3 p, float u_pick, float u1, float u2,
                               struct light_sample *out)
{
    if (ls->count == 0) return false;
    float pmf;
    uint32_t i = distrib_sample(&ls->dist, u_pick, &pmf);
    const struct light_entry *e = &ls->entries[i];
    struct spherical_triangle st;
    if (e->rect >= 0) {
        const struct light_rect *r = &ls->rects[e->rect];
        struct spherical_rect sr;
        if (light_rect_solid_angle_from(r, p, &sr)) return light_rect_sample(ls, r, &sr, p, u1, u2, out);
    } else if (light_entry_solid_angle_from(e, p, &st)) {
        struct spherical_triangle pair[2];
        int64_t lower;
        if (!light_pair_solid_angle_from(ls, e, p, &st, pair, &lower))
            return light_sampler_sample_solid_angle(e, &st, p, light_entry_solid_angle_pdf(pmf, &st), u1, u2, out);
        /* One of the two by solid angle, u1 rescaled to [0, 1) within the choice (the triangle's
         * warp takes it as its first number). */
        const double share0 = pair[0].solid_angle / (pair[0].solid_angle + pair[1].solid_angle);
        const int k = (double)u1 >= share0;
        const double u = k ? ((double)u1 - share0) / (1.0 - share0) : (double)u1 / share0;
        float uk = (float)u;  /* rounding can reach 1 */
        if (!(uk < 1.0f)) uk = 0x1.fffffep-1f;
        return light_sampler_sample_solid_angle(&ls->entries[lower + k], &pair[k], p, light_pair_pdf_w(ls, lower, pair),
                                                uk, u2, out);
    }
    light_sampler_sample_entry(e, pmf, u1, u2, out);
    if (!out->is_env) out->pdf_w = light_sampler_area_pdf_w(out->pdf_a, p, out->p, out->n);
    return out->pdf_w > 0.0f;
}

float light_sampler_pdf_w_from(const struct light_sampler *ls, struct vec3 p, uint32_t shape, uint32_t prim,
                               struct vec3 q)
{
    int64_t i = light_sampler_entry_of(ls, shape, prim);
    if (i < 0) return 0.0f;
    const struct light_entry *e = &ls->entries[i];
    float pmf = ls->dist.pmf[i];
    struct spherical_triangle st;
    if (e->rect >= 0) {
        const struct light_rect *r = &ls->rects[e->rect];
        struct spherical_rect sr;
        if (light_rect_solid_angle_from(r, p, &sr)) return light_rect_pdf_w(ls, r, &sr);
    } else if (light_entry_solid_angle_from(e, p, &st)) {
        struct spherical_triangle pair[2];
        int64_t lower;
        if (light_pair_solid_angle_from(ls, e, p, &st, pair, &lower)) return light_pair_pdf_w(ls, lower, pair);
        return light_entry_solid_angle_pdf(pmf, &st);
    }
    struct vec3 n = e->kind == LIGHT_TRIANGLE ? e->n : vec3_normalize(vec3_sub(q, e->p0));
    return light_sampler_area_pdf_w(pmf / e->area, p, q, n);
}

bool light_sampler_solid_angle_from(const struct light_sampler *ls, struct vec3 p, uint32_t shape, uint32_t prim)
{
    int64_t i = light_sampler_entry_of(ls, shape, prim);
    if (i < 0) return false;
    const struct light_entry *e = &ls->entries[i];
    if (e->rect >= 0) {
        struct spherical_rect sr;
        return light_rect_solid_angle_from(&ls->rects[e->rect], p, &sr);
    }
    struct spherical_triangle st;
    return light_entry_solid_angle_from(e, p, &st);
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
