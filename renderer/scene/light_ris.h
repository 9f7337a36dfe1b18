/* light_ris.h — next-event estimation by resampled importance sampling (RIS): M light samples
 * from the power-proportional light sampler, one kept with probability proportional to its
 * unshadowed contribution luminance(f * Le * |cos|) / pdf. The kept sample comes with its
 * unbiased contribution weight W (solid angle), so f * Le * |cos| * V * W estimates direct
 * light without bias for any M >= 1 (M = 1 is plain NEE). One shadow ray, whatever M.
 * Allocation-free, thread-safe.
 * Refs: [ReSTIR PT Enhanced §5] (RIS-based NEE; its MIS weight against BSDF sampling is
 * M p_light / (M p_light + p_bsdf)); Talbot et al. 2005 (RIS); docs/methods.md (restir_pt). */
#ifndef RESTIRD_LIGHT_RIS_H
#define RESTIRD_LIGHT_RIS_H

#include <stdint.h>

#include "scene/light_sampler.h"
#include "material/material.h"
#include "core/rng.h"
#include "scene/scene.h"
#include "scene/surface.h"

struct light_ris_sample {
    struct light_sample light;  /* the kept light sample (point, emitter, barycentrics) */
    struct vec3 wi_world;   /* towards the light */
    float dist;             /* INFINITY for the environment */
    struct vec3 Le;         /* emitted radiance towards the shading point */
    struct vec3 f_cos;      /* f(wo, wi) |cos wi| at the shading point (unshadowed) */
    float pdf_light_w;      /* the light sampler's solid-angle pdf of this sample */
    float W;                /* unbiased contribution weight (1 / solid angle) */
};

/* Draws M candidates (from rng) at surface s with outgoing local direction wo and keeps one.
 * False when no candidate contributes (then the estimate is 0). The caller traces the shadow
 * ray. Non-finite candidate weights are dropped (counted in *rejected when non-NULL). */
bool light_ris_sample(const struct scene *scene, const struct surface *s, const struct material *m, struct vec3 wo,
                      uint32_t M, struct rng *rng, struct light_ris_sample *out, unsigned *rejected);

#endif
