/* surface.h — the local geometry at a ray hit: world position, geometric and shading normals,
 * shading frame, material; and robust ray spawning off a surface.
 * Refs: Wächter & Binder, "A Fast and Robust Method for Avoiding Self-Intersection",
 * Ray Tracing Gems (2019) ch. 6 — origin offsets in integer ULPs along the geometric normal. */
#ifndef RESTIRD_SURFACE_H
#define RESTIRD_SURFACE_H

#include <stdint.h>

#include "accel.h"
#include "vec.h"

struct scene;

struct surface {
    struct vec3 p;        /* world position (reconstructed from the primitive, not from t) */
    struct vec3 ng;       /* unit geometric normal on the front side */
    struct vec3 ns;       /* unit shading normal, in the same hemisphere as ng */
    struct frame frame;   /* shading frame around ns */
    uint32_t shape, prim, material;
};

/* `org`/`dir` are the ray that produced `hit` (spheres reconstruct the point from it). */
void surface_from_hit(const struct scene *scene, const struct hit *hit, struct vec3 org, struct vec3 dir,
                      struct surface *out);
/* Origin for a ray leaving `p` towards the side of `ng` that `dir` points into. */
struct vec3 surface_offset(struct vec3 p, struct vec3 ng, struct vec3 dir);

#endif
