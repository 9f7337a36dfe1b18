/* surface.c — reconstructs hit geometry from scene data under the accel's current transform
 * (ray origin offsets are inline in surface.h). */
#include "surface.h"

#include "scene.h"

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

/* Runs once per path vertex. The shape's inverse transform comes from the accel, which keeps
 * it per shape, instead of being recomputed here per hit; identity transforms (shapes written in
 * world coordinates) are skipped: x * 1 + y * 0 + z * 0 + 0 == x, so no bit of the result
 * changes (except that a -0 coordinate would become +0). */
void surface_from_hit(const struct scene *scene, const struct hit *hit, struct vec3 org, struct vec3 dir,
                      struct surface *out)
{
    const struct accel *accel = scene->accel;
    const struct shape *s = &scene->shapes[hit->shape];
    bool identity = accel_shape_is_identity(accel, hit->shape);
    out->shape = hit->shape;
    out->prim = hit->prim;
    out->material = s->material;
    out->ng = hit->ng;
    if (s->kind == SHAPE_MESH) {
        const uint32_t *tri = &s->indices[3 * hit->prim];
        float b0 = 1.0f - hit->b1 - hit->b2;
        struct vec3 p = vec3_add(vec3_add(vec3_scale(s->positions[tri[0]], b0), vec3_scale(s->positions[tri[1]], hit->b1)),
                                 vec3_scale(s->positions[tri[2]], hit->b2));
        out->p = identity ? p : xform_point(accel_shape_to_world(accel, hit->shape), p);
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
