/* light_sampler.h — picks emitters proportionally to emitted power (alias table over emissive
 * triangles, emissive spheres and the constant environment) and samples points on them
 * uniformly by area, or, from a known shading point, triangles and rectangles seen close by
 * uniformly in the solid angle they subtend there (light_sampler_sample_from). pdfs are explicit
 * about their measure: pdf_a on surfaces, pdf_w for the environment and for samples from a
 * shading point.
 * Immutable after creation; thread-safe. */
#ifndef RESTIRD_LIGHT_SAMPLER_H
#define RESTIRD_LIGHT_SAMPLER_H

#include <stdint.h>

#include "core/err.h"
#include "core/vec.h"

struct scene;
struct light_sampler;

struct light_sample {
    bool is_env;        /* environment: `dir` is set, p/n are not */
    bool solid_angle;   /* light_sampler_sample_from sampled the triangle's solid angle */
    struct vec3 p, n;   /* point on the emitter and its geometric normal (front side) */
    struct vec3 dir;    /* environment: direction towards the environment */
    uint32_t shape, prim;
    /* Surfaces: the emitter's material, &scene->materials[scene->shapes[shape].material], kept
     * in the sampler so that next-event estimation does not chase it per shadow ray. */
    const struct material *material;
    float b1, b2;       /* triangles: barycentrics of p (the point code surface_at takes) */
    float pdf_a;        /* area pdf of p including the emitter choice (surfaces) */
    /* Solid-angle pdf including the emitter choice: of dir (environment), and, for samples of
     * light_sampler_sample_from, of the direction from the shading point to p (surfaces). */
    float pdf_w;
};

struct light_sampler *light_sampler_new(const struct scene *scene, struct err *err);
void light_sampler_free(struct light_sampler *ls);
/* Number of emitters (triangles + spheres + environment); 0 = no light at all. */
uint32_t light_sampler_count(const struct light_sampler *ls);
bool light_sampler_sample(const struct light_sampler *ls, float u_pick, float u1, float u2, struct light_sample *out);
/* Area pdf that light_sampler_sample produces the point on (shape, prim): used for MIS when a
 * BSDF-sampled ray hits an emitter. */
float light_sampler_pdf_a(const struct light_sampler *ls, uint32_t shape, uint32_t prim);
/* Next-event estimation from the shading point p: picks an emitter as light_sampler_sample does
 * (the same u_pick gives the same shape) and samples it by area, except a triangle that p sees
 * close by (closer to its centroid than 5 times its bounding radius, and in front of it unless it
 * emits on both sides: light_sampler.c says why), whose solid angle from p is sampled uniformly
 * (Arvo 1995) and whose point is where that direction meets it. A two-triangle emitter that is
 * a rectangle is sampled as one (Urena et al. 2013) when p is within 5 half diagonals of its
 * centre and in front of it; another two-triangle emitter (a quad) whose triangles both qualify
 * is sampled uniformly over its whole solid angle: either of its triangles, in proportion to its
 * solid angle. Either way the sample's prim is the triangle holding the point. Sets pdf_w, the
 * solid-angle pdf at p including the pick, for every emitter, and pdf_a (surfaces) to the same density per area of the light;
 * `solid_angle` tells which sampling ran. False when the sample cannot contribute (pdf_w 0). */
bool light_sampler_sample_from(const struct light_sampler *ls, struct vec3 p, float u_pick, float u1, float u2,
                               struct light_sample *out);
/* Solid-angle pdf at p with which light_sampler_sample_from produces the point q on emitter
 * (shape, prim) (a sphere or triangle): for MIS when a BSDF-sampled ray from p hits it. It
 * decides between area and solid-angle sampling as light_sampler_sample_from does, from p, the
 * emitter and a quad's other triangle (or its rectangle) alone. 0 when (shape, prim) is no
 * emitter. */
float light_sampler_pdf_w_from(const struct light_sampler *ls, struct vec3 p, uint32_t shape, uint32_t prim,
                               struct vec3 q);
/* That decision: whether light_sampler_sample_from samples the solid angle of emissive triangle
 * (shape, prim), or of the rectangle it is half of, from p. */
bool light_sampler_solid_angle_from(const struct light_sampler *ls, struct vec3 p, uint32_t shape, uint32_t prim);
/* The point with code (b1, b2) on emissive triangle `prim` of `shape`, and its front normal, as
 * light_sampler_sample computes them for that code (the same bits), from the sampler's
 * world-space table: no transform and no normalisation. False (nothing written) when (shape,
 * prim) is not an emissive triangle. */
bool light_sampler_triangle_point(const struct light_sampler *ls, uint32_t shape, uint32_t prim, float b1, float b2,
                                  struct vec3 *p, struct vec3 *n);
/* Solid-angle pdf of sampling the environment in any direction (uniform sphere). */
float light_sampler_env_pdf_w(const struct light_sampler *ls);

#include "material/material.h"

/* Radiance a material emits towards a direction making cosine `cos_front` with the emitter's
 * front (geometric) normal: one-sided emitters are black from behind. */
static inline struct vec3 light_sampler_emitted(const struct material *m, float cos_front)
{
    if (cos_front > 0.0f || (m->two_sided_emission && cos_front < 0.0f)) return m->emission;
    return vec3_splat(0.0f);
}

#endif
