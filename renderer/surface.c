/* surface.c — reconstructs hit geometry from scene data under the accel's current transform,
 * and offsets ray origins so a spawned ray does not re-hit its own surface. */
#include "surface.h"

#include <string.h>

#include "scene.h"

void surface_from_hit(const struct scene *scene, const struct hit *hit, struct vec3 org, struct vec3 dir,
                      struct surface *out)
{
    const struct shape *s = &scene->shapes[hit->shape];
    const struct xform *xf = accel_shape_to_world(scene->accel, hit->shape);
    out->shape = hit->shape;
    out->prim = hit->prim;
    out->material = s->material;
    out->ng = hit->ng;
    if (s->kind == SHAPE_MESH) {
        const uint32_t *tri = &s->indices[3 * hit->prim];
        float b0 = 1.0f - hit->b1 - hit->b2;
        struct vec3 p = vec3_add(vec3_add(vec3_scale(s->positions[tri[0]], b0), vec3_scale(s->positions[tri[1]], hit->b1)),
                                 vec3_scale(s->positions[tri[2]], hit->b2));
        out->p = xform_point(xf, p);
        out->ns = out->ng;
        if (s->normals) {
            struct vec3 n = vec3_add(vec3_add(vec3_scale(s->normals[tri[0]], b0), vec3_scale(s->normals[tri[1]], hit->b1)),
                                     vec3_scale(s->normals[tri[2]], hit->b2));
            struct xform inv;
            if (xform_invert(xf, &inv)) {
                n = vec3_normalize(xform_normal(&inv, n));
                if (vec3_length2(n) > 0.5f) {
                    /* Keep the shading normal on the geometric front side so "front" means one
                     * thing for both normals. */
                    out->ns = vec3_dot(n, out->ng) < 0.0f ? vec3_neg(n) : n;
                }
            }
        }
    } else {
        /* Sphere: the hit point is re-projected onto the exact surface in object space, which
         * removes the intersector's distance error before the origin offset is applied. */
        struct xform inv;
        struct vec3 pw = vec3_madd(org, dir, hit->t);
        if (xform_invert(xf, &inv)) {
            struct vec3 d = vec3_normalize(vec3_sub(xform_point(&inv, pw), s->center));
            pw = xform_point(xf, vec3_madd(s->center, d, s->radius));
            struct vec3 n = vec3_normalize(xform_normal(&inv, d));
            if (vec3_length2(n) > 0.5f) out->ng = n;
        }
        out->p = pw;
        out->ns = out->ng;
    }
    out->frame = frame_from_normal(out->ns);
}

static inline int32_t surface_float_as_int(float f)
{
    int32_t i;
    memcpy(&i, &f, sizeof i);
    return i;
}
static inline float surface_int_as_float(int32_t i)
{
    float f;
    memcpy(&f, &i, sizeof f);
    return f;
}

static inline float surface_offset_comp(float p, float n)
{
    /* Far from the origin move a fixed number of ULPs (scales with |p|); near it, where ULPs
     * are tiny, move a small absolute distance instead. */
    const float origin = 1.0f / 32.0f, float_scale = 1.0f / 65536.0f, int_scale = 256.0f;
    int32_t of = (int32_t)(int_scale * n);
    float pi = surface_int_as_float(surface_float_as_int(p) + (p < 0.0f ? -of : of));
    return fabsf(p) < origin ? p + float_scale * n : pi;
}

struct vec3 surface_offset(struct vec3 p, struct vec3 ng, struct vec3 dir)
{
    struct vec3 n = vec3_dot(dir, ng) < 0.0f ? vec3_neg(ng) : ng;
    return vec3_make(surface_offset_comp(p.x, n.x), surface_offset_comp(p.y, n.y), surface_offset_comp(p.z, n.z));
}
