/* bsdf.h — internal: the per-kind BSDF functions that material.c dispatches to. Only
 * material.c and the bsdf_*.c files include this header; integrators use material.h.
 * Conventions are material.h's (local frame, wo/wi point away, f without cosine, pdf_w in
 * solid angle). The sample functions fill wi, f, pdf_w, pdf_rev_w and lobe; material.c fills
 * flags. A function returning false leaves *out unspecified. */
#ifndef RESTIRD_BSDF_H
#define RESTIRD_BSDF_H

#include <stdbool.h>

#include "material/material.h"
#include "core/vec.h"

struct vec3 bsdf_diffuse_eval(const struct material *m, struct vec3 wo, struct vec3 wi);
float bsdf_diffuse_pdf(struct vec3 wo, struct vec3 wi);
bool bsdf_diffuse_sample(const struct material *m, struct vec3 wo, float u1, float u2,
                         struct bsdf_sample *out);

/* Conductor: one lobe, glossy GGX or (roughness < MICROFACET_DELTA_ALPHA) a delta mirror,
 * for which eval and pdf are 0. */
struct vec3 bsdf_conductor_eval(const struct material *m, struct vec3 wo, struct vec3 wi);
float bsdf_conductor_pdf(const struct material *m, struct vec3 wo, struct vec3 wi);
bool bsdf_conductor_sample(const struct material *m, struct vec3 wo, float u1, float u2,
                           struct bsdf_sample *out);

/* Dielectric: lobe 0 reflection, lobe 1 transmission; both delta when smooth. */
struct vec3 bsdf_dielectric_eval_lobe(const struct material *m, int lobe, struct vec3 wo,
                                      struct vec3 wi, enum transport_mode mode);
float bsdf_dielectric_pdf_lobe(const struct material *m, int lobe, struct vec3 wo, struct vec3 wi);
bool bsdf_dielectric_sample(const struct material *m, struct vec3 wo, float u_lobe, float u1,
                            float u2, enum transport_mode mode, struct bsdf_sample *out);

/* Translucent: the local stand-in for the BSSRDF at vertices after the primary hit ([ReSTIR SSS]
 * §2.1): f = albedo (1 - F(wo)) (1 - F(wi)) / (sss_c pi), Burley's diffusion integrated over a
 * flat, uniformly lit surface; two-sided like the diffuse BRDF, cosine-weighted sampling. */
struct vec3 bsdf_translucent_eval(const struct material *m, struct vec3 wo, struct vec3 wi);
bool bsdf_translucent_sample(const struct material *m, struct vec3 wo, float u1, float u2,
                             struct bsdf_sample *out);

#endif
