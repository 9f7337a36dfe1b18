/* surface.c — reconstructs hit geometry from scene data under the accel's current transform
 * (ray origin offsets are inline in surface.h). */
#include "scene/surface.h"

#include <math.h>
#include <string.h>

#include "scene/scene.h"

/* Interpolated vertex normal, or ng when it degenerates. */
static struct vec3 surface_shading_normal(const struct accel *accel, const struct shape *s, const uint32_t *tri,
                                          uint32_t shape, float b0, float b1, float b2, struct vec3 ng)
{
    struct vec3 n = vec3_add(vec3_add(vec3_scale(s->normals[tri[0]], b0), vec3_scale(s->normals[tri[1]], b1)),
                             vec3_scale(s->normals[tri[2]], b2));
    if (!accel_shape_is_identity(accel, shape)) n = xform_normal(accel_shape_to_object(accel, shape), n);
    n = vec3_normalize(n);
    if (!(vec3_length2(n) > 0.5f)) return ng;
    /* Keep the shading normal on the geometric front side so "front" means one thing for both
     * normals. */
    return vec3_dot(n, ng) < 0.0f ? vec3_neg(n) : n;
}

/* A mesh point's world position from its barycentrics (b0 = 1 - b1 - b2). */
static struct vec3 surface_mesh_point(const struct accel *accel, const struct shape *s, uint32_t shape,
                                      const uint32_t *tri, float b0, float b1, float b2)
{
    struct vec3 p = vec3_add(vec3_add(vec3_scale(s->positions[tri[0]], b0), vec3_scale(s->positions[tri[1]], b1)),
                             vec3_scale(s->positions[tri[2]], b2));
    return accel_shape_is_identity(accel, shape) ? p : xform_point(accel_shape_to_world(accel, shape), p);
}

/* A triangle's unit geometric normal as accel_intersect reports it: the object-space winding
 * normal, carried by the inverse transpose (so a mirroring transform does not flip the front). */
static struct vec3 surface_mesh_ng(const struct accel *accel, const struct shape *s, uint32_t shape,
                                   const uint32_t *tri)
{
    struct vec3 p0 = s->positions[tri[0]];
    struct vec3 ng = vec3_cross(vec3_sub(s->positions[tri[1]], p0), vec3_sub(s->positions[tri[2]], p0));
    if (!accel_shape_is_identity(accel, shape)) ng = xform_normal(accel_shape_to_object(accel, shape), ng);
    return vec3_normalize(ng);
}

/* Runs once per path vertex. The shape's inverse transform comes from the accel, which keeps
 * it per shape, instead of being recomputed here per hit; identity transforms (shapes written in
 * world coordinates) are skipped: x * 1 + y * 0 + z * 0 + 0 == x, so no bit of the result
 * changes (except that a -0 coordinate would become +0). */
void surface_from_hit(const struct scene *scene, const struct hit *hit, struct vec3 org, struct vec3 dir,
                      struct surface *out)
{
    const struct accel *accel = scene->accel;
    const struct shape *s = &scene->shapes[hit->shape];
    out->shape = hit->shape;
    out->prim = hit->prim;
    out->material = s->material;
    out->ng = hit->ng;
    if (s->kind == SHAPE_MESH) {
        const uint32_t *tri = &s->indices[3 * hit->prim];
        float b0 = 1.0f - hit->b1 - hit->b2;
        out->p = surface_mesh_point(accel, s, hit->shape, tri, b0, hit->b1, hit->b2);
        out->ns = s->normals ? surface_shading_normal(accel, s, tri, hit->shape, b0, hit->b1, hit->b2, out->ng) : out->ng;
    } else {
        /* Sphere: the hit point is re-projected onto the exact surface in object space, which
         * removes the intersector's distance error before the origin offset is applied. */
        const struct xform *xf = accel_shape_to_world(accel, hit->shape);
        const struct xform *inv = accel_shape_to_object(accel, hit->shape);
        struct vec3 pw = vec3_madd(org, dir, hit->t);
        struct vec3 d = vec3_normalize(vec3_sub(xform_point(inv, pw), s->center));
        pw = xform_point(xf, vec3_madd(s->center, d, s->radius));
        struct vec3 n = vec3_normalize(xform_normal(inv, d));
        if (vec3_length2(n) > 0.5f) out->ng = n;
        out->p = pw;
        out->ns = out->ng;
    }
    out->frame = frame_from_normal(out->ns);
}

void surface_oct_encode(struct vec3 d, float *u, float *v)
{
    float l1 = fabsf(d.x) + fabsf(d.y) + fabsf(d.z);
    float x = d.x / l1, y = d.y / l1;
    if (d.z < 0.0f) {
        float ox = (1.0f - fabsf(y)) * (x >= 0.0f ? 1.0f : -1.0f);
        float oy = (1.0f - fabsf(x)) * (y >= 0.0f ? 1.0f : -1.0f);
        x = ox, y = oy;
    }
    *u = x;
    *v = y;
}

struct vec3 surface_oct_decode(float u, float v)
{
    struct vec3 d = vec3_make(u, v, 1.0f - fabsf(u) - fabsf(v));
    if (d.z < 0.0f) {
        float ox = (1.0f - fabsf(v)) * (u >= 0.0f ? 1.0f : -1.0f);
        float oy = (1.0f - fabsf(u)) * (v >= 0.0f ? 1.0f : -1.0f);
        d.x = ox, d.y = oy;
    }
    return vec3_normalize(d);
}

void surface_at(const struct scene *scene, uint32_t shape, uint32_t prim, float b1, float b2, struct surface *out)
{
    const struct accel *accel = scene->accel;
    const struct shape *s = &scene->shapes[shape];
    const struct xform *xf = accel_shape_to_world(accel, shape);
    struct hit h = surface_hit_at(scene, shape, prim, 0.0f, b1, b2);
    if (s->kind == SHAPE_MESH) {
        surface_from_hit(scene, &h, s->positions[s->indices[3 * prim]], vec3_make(0.0f, 0.0f, 1.0f), out);
        return;
    }
    /* Sphere: a ray from the centre along the coded direction lands on the surface at t = r in
     * object space; surface_from_hit re-projects it exactly. */
    struct vec3 d = surface_oct_decode(b1, b2);
    struct vec3 pw = xform_point(xf, vec3_madd(s->center, d, s->radius));
    h.ng = d;
    surface_from_hit(scene, &h, pw, vec3_make(0.0f, 0.0f, 1.0f), out);
}

struct hit surface_hit_at(const struct scene *scene, uint32_t shape, uint32_t prim, float t, float b1, float b2)
{
    const struct shape *s = &scene->shapes[shape];
    struct hit h = {.t = t, .shape = shape, .prim = prim, .b1 = b1, .b2 = b2, .ng = vec3_make(0.0f, 0.0f, 1.0f)};
    if (s->kind == SHAPE_MESH) h.ng = surface_mesh_ng(scene->accel, s, shape, &s->indices[3 * prim]);
    return h;
}

void surface_point_at(const struct scene *scene, uint32_t shape, uint32_t prim, float b1, float b2, struct vec3 *p,
                      struct vec3 *ng)
{
    const struct shape *s = &scene->shapes[shape];
    if (s->kind != SHAPE_MESH) {  /* a sphere's point needs the whole reconstruction anyway */
        struct surface full;
        surface_at(scene, shape, prim, b1, b2, &full);
        *p = full.p;
        *ng = full.ng;
        return;
    }
    const uint32_t *tri = &s->indices[3 * prim];
    *ng = surface_mesh_ng(scene->accel, s, shape, tri);
    *p = surface_mesh_point(scene->accel, s, shape, tri, 1.0f - b1 - b2, b1, b2);
}

void surface_point_code(const struct scene *scene, const struct hit *h, const struct surface *s, float *b1, float *b2)
{
    const struct shape *sh = &scene->shapes[h->shape];
    if (sh->kind == SHAPE_MESH) {
        *b1 = h->b1;
        *b2 = h->b2;
        return;
    }
    struct vec3 d = vec3_normalize(vec3_sub(xform_point(accel_shape_to_object(scene->accel, h->shape), s->p), sh->center));
    surface_oct_encode(d, b1, b2);
}

/* Area scale of the affine map `xf` on a surface element with object-space normal n:
 * |det A| |A^-T n| (Nanson's formula). */
static float surface_area_scale(const struct xform *xf, const struct xform *inv, struct vec3 n)
{
    return fabsf(xform_det3(xf)) * vec3_length(xform_normal(inv, n));
}

float surface_area_ratio(const struct scene *from, const struct scene *to, uint32_t shape, uint32_t prim, float b1,
                         float b2)
{
    const struct xform *xa = accel_shape_to_world(from->accel, shape), *xb = accel_shape_to_world(to->accel, shape);
    if (from == to || memcmp(xa, xb, sizeof *xa) == 0) return 1.0f;
    const struct shape *s = &from->shapes[shape];
    struct vec3 n;
    if (s->kind == SHAPE_MESH) {
        const uint32_t *tri = &s->indices[3 * prim];
        n = vec3_normalize(vec3_cross(vec3_sub(s->positions[tri[1]], s->positions[tri[0]]),
                                      vec3_sub(s->positions[tri[2]], s->positions[tri[0]])));
    } else {
        n = surface_oct_decode(b1, b2);
    }
    float a = surface_area_scale(xa, accel_shape_to_object(from->accel, shape), n);
    float b = surface_area_scale(xb, accel_shape_to_object(to->accel, shape), n);
    return a > 0.0f ? b / a : 0.0f;
}
