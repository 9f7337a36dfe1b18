/* bsdf_diffuse.c — the Lambertian BRDF f = albedo / pi, two-sided: it shades the hemisphere
 * wo is in and is zero across the surface. Sampling is cosine-weighted on wo's side, so the
 * sample weight f |cos| / pdf_w is exactly the albedo.
 * Called only through material.c (bsdf.h). Refs: Lambert 1760; Shirley & Chiu 1997 (warp). */
#include "material/bsdf.h"
#include "core/sampling.h"

struct vec3 bsdf_diffuse_eval(const struct material *m, struct vec3 wo, struct vec3 wi)
{
    return material_diffuse_f(m, wo.z, wi.z);
}

float bsdf_diffuse_pdf(struct vec3 wo, struct vec3 wi)
{
    return material_diffuse_pdf(wo.z, wi.z);
}

bool bsdf_diffuse_sample(const struct material *m, struct vec3 wo, float u1, float u2,
                         struct bsdf_sample *out)
{
    struct vec3 wi;
    if (!material_diffuse_direction(wo.z, u1, u2, &wi)) return false;  /* the rim: zero pdf */
    out->wi = wi;
    out->f = bsdf_diffuse_eval(m, wo, wi);
    out->pdf_w = bsdf_diffuse_pdf(wo, wi);
    out->pdf_rev_w = bsdf_diffuse_pdf(wi, wo);
    out->lobe = 0;
    return out->pdf_w > 0.0f;
}
