/* microfacet.h — the isotropic GGX microfacet distribution: normal distribution D, Smith
 * masking (Lambda, G1) and height-correlated masking-shadowing G2, and sampling of the
 * distribution of visible normals with its pdf. Knows nothing about Fresnel or materials.
 * Every function works in the local shading frame (z = macro normal); microfacet normals m
 * always lie in the upper hemisphere. Pure functions, thread-safe.
 * Refs: Walter et al. 2007 (GGX, eqs. 33-34); Heitz 2014 "Understanding the Masking-Shadowing
 * Function in Microfacet-Based BRDFs" (Lambda, height-correlated G2); Heitz 2018 "Sampling the
 * GGX Distribution of Visible Normals" (JCGT 7(4)). */
#ifndef RESTIRD_MICROFACET_H
#define RESTIRD_MICROFACET_H

#include <stdbool.h>

#include "core/vec.h"

/* Below this alpha a lobe is treated as a perfect (delta) mirror / refractor: D's peak
 * 1 / (pi alpha^2) exceeds 3e7 and the lobe is narrower than float direction precision can
 * resolve reliably in eval, so delta sampling is both cheaper and more accurate. */
#define MICROFACET_DELTA_ALPHA 1e-4f

static inline bool microfacet_is_delta(float alpha) { return !(alpha >= MICROFACET_DELTA_ALPHA); }

/* GGX normal distribution D(m) (Walter et al. 2007 eq. 33); m unit length. Measure: per unit
 * solid angle of m, normalised so that the projected area integral of D(m) m.z dw_m is 1.
 * Zero for m.z <= 0. */
float microfacet_d(struct vec3 m, float alpha);

/* Smith Lambda(w) for GGX (Heitz 2014): (-1 + sqrt(1 + alpha^2 tan^2 theta)) / 2. Depends on
 * |w.z| only, so it serves both sides of the macro surface. +infinity for w.z == 0. */
float microfacet_lambda(struct vec3 w, float alpha);

/* Smith masking G1(w) = 1 / (1 + Lambda(w)) (equals Walter et al. 2007 eq. 34). The caller
 * checks the side condition chi+((w.m) / (w.n)). */
float microfacet_g1(struct vec3 w, float alpha);

/* Height-correlated masking-shadowing G2 = 1 / (1 + Lambda(wo) + Lambda(wi)) (Heitz 2014).
 * Chosen over the separable G1(wo) G1(wi) because it does not count the correlation between
 * masking and shadowing twice (less energy loss) and is still symmetric in wo, wi, which
 * reciprocity needs. Used for transmission too, where the exact height-correlated form is a
 * Beta function (Heitz 2014); this symmetric approximation is the common choice. */
float microfacet_g2(struct vec3 wo, struct vec3 wi, float alpha);

/* Samples a microfacet normal from the distribution of normals visible from wo,
 * D_wo(m) = G1(wo) max(0, wo.m) D(m) / wo.z (Heitz 2018), by projecting a uniform disk
 * sample onto the hemisphere in the stretched (alpha = 1) configuration. Requires wo.z > 0.
 * Returns a unit m with m.z >= 0. */
struct vec3 microfacet_sample_visible(struct vec3 wo, float alpha, float u1, float u2);

/* Solid-angle (of m) pdf of microfacet_sample_visible: D_wo(m). Zero when wo.z <= 0 or
 * wo.m <= 0. */
float microfacet_pdf_visible(struct vec3 wo, struct vec3 m, float alpha);

/* v mirrored through the tangent plane when sign < 0 (BSDFs evaluate with wo in the upper
 * hemisphere and mirror the result back). */
static inline struct vec3 microfacet_flip_z(struct vec3 v, float sign) { return vec3_make(v.x, v.y, v.z * sign); }

/* wo reflected about the microfacet normal m, given wo_m = wo.m: 2 (wo.m) m - wo. */
static inline struct vec3 microfacet_reflect(struct vec3 wo, struct vec3 m, float wo_m)
{
    return vec3_sub(vec3_scale(m, 2.0f * wo_m), wo);
}

#endif
