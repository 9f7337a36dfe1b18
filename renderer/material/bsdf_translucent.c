/* bsdf_translucent.c — the translucent material as a BSDF: the stand-in used wherever the
 * BSSRDF is not sampled (every vertex after the primary hit, [ReSTIR SSS §2.1]). It is Burley's
 * diffusion (bssrdf.h) with the entry point taken at the exit point: integrating the profile over
 * a flat plane leaves albedo (1 - F(wo)) (1 - F(wi)) / (c pi), reciprocal and energy-conserving
 * (its directional albedo is albedo (1 - F(wo)) <= albedo). Two-sided, cosine-weighted sampling.
 * Called only through material.c (bsdf.h). */
#include "material/bsdf.h"
#include "material/bssrdf.h"
#include "core/sampling.h"

struct vec3 bsdf_translucent_eval(const struct material *m, struct vec3 wo, struct vec3 wi)
{
    if (!(wo.z * wi.z > 0.0f)) return vec3_splat(0.0f);
    float t = bssrdf_transmittance(m, fabsf(wo.z)) * bssrdf_entry_eval(m, fabsf(wi.z));
    return vec3_scale(m->albedo, t);
}

bool bsdf_translucent_sample(const struct material *m, struct vec3 wo, float u1, float u2,
                             struct bsdf_sample *out)
{
    if (wo.z == 0.0f) return false;
    struct vec3 wi = sampling_cosine_hemisphere(u1, u2);
    if (wo.z < 0.0f) wi.z = -wi.z;
    if (wi.z == 0.0f) return false;
    out->wi = wi;
    out->f = bsdf_translucent_eval(m, wo, wi);
    out->pdf_w = bsdf_diffuse_pdf(wo, wi);
    out->pdf_rev_w = bsdf_diffuse_pdf(wi, wo);
    out->lobe = 0;
    return out->pdf_w > 0.0f;
}
