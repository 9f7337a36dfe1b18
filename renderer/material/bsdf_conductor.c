/* bsdf_conductor.c — GGX microfacet conductor (isotropic alpha = roughness) with the exact
 * complex-IOR Fresnel per RGB channel; a delta mirror when roughness < MICROFACET_DELTA_ALPHA.
 * Two-sided: everything is mirrored to wo.z > 0 and wi on the other side gives 0.
 * Sampling draws visible normals, so the weight f |cos| / pdf_w = F G2 / G1(wo) <= F.
 * Called only through material.c (bsdf.h). Refs: Walter et al. 2007 eqs. 14, 20; Heitz 2018. */
#include "material/bsdf.h"
#include "material/fresnel.h"
#include "material/microfacet.h"

struct vec3 bsdf_conductor_eval(const struct material *m, struct vec3 wo, struct vec3 wi)
{
    float alpha = m->roughness;
    if (microfacet_is_delta(alpha) || !(wo.z * wi.z > 0.0f)) return vec3_splat(0.0f);
    float sign = wo.z > 0.0f ? 1.0f : -1.0f;
    wo = microfacet_flip_z(wo, sign);
    wi = microfacet_flip_z(wi, sign);
    struct vec3 h = vec3_add(wo, wi);
    if (!(vec3_length2(h) > 0.0f)) return vec3_splat(0.0f);
    struct vec3 mh = vec3_normalize(h);  /* reflection half vector (Walter eq. 13) */
    /* Walter eq. 20: f = F(wo.m) D(m) G2(wo, wi) / (4 |wo.n| |wi.n|). */
    struct vec3 fr = fresnel_conductor_rgb(vec3_dot(wo, mh), m->eta, m->k);
    float s = microfacet_d(mh, alpha) * microfacet_g2(wo, wi, alpha) / (4.0f * wo.z * wi.z);
    return vec3_scale(fr, s);
}

float bsdf_conductor_pdf(const struct material *m, struct vec3 wo, struct vec3 wi)
{
    float alpha = m->roughness;
    if (microfacet_is_delta(alpha) || !(wo.z * wi.z > 0.0f)) return 0.0f;
    float sign = wo.z > 0.0f ? 1.0f : -1.0f;
    wo = microfacet_flip_z(wo, sign);
    wi = microfacet_flip_z(wi, sign);
    struct vec3 h = vec3_add(wo, wi);
    if (!(vec3_length2(h) > 0.0f)) return 0.0f;
    struct vec3 mh = vec3_normalize(h);
    float wo_m = vec3_dot(wo, mh);
    if (!(wo_m > 0.0f)) return 0.0f;
    /* Visible-normal pdf times the reflection Jacobian dw_m / dw_i = 1 / (4 |wo.m|)
     * (Walter eq. 14). */
    return microfacet_pdf_visible(wo, mh, alpha) / (4.0f * wo_m);
}

bool bsdf_conductor_sample(const struct material *m, struct vec3 wo, float u1, float u2,
                           struct bsdf_sample *out)
{
    if (wo.z == 0.0f) return false;
    float alpha = m->roughness;
    out->lobe = 0;
    if (microfacet_is_delta(alpha)) {
        /* Mirror: pdf_w = 1 is the discrete lobe probability (material.h); f |cos| / pdf = F. */
        float cos_o = fabsf(wo.z);
        out->wi = vec3_make(-wo.x, -wo.y, wo.z);
        out->f = vec3_scale(fresnel_conductor_rgb(cos_o, m->eta, m->k), 1.0f / cos_o);
        out->pdf_w = 1.0f;
        out->pdf_rev_w = 1.0f;
        return true;
    }
    float sign = wo.z > 0.0f ? 1.0f : -1.0f;
    struct vec3 wo_up = microfacet_flip_z(wo, sign);
    struct vec3 mh = microfacet_sample_visible(wo_up, alpha, u1, u2);
    float wo_m = vec3_dot(wo_up, mh);
    if (!(wo_m > 0.0f)) return false;
    struct vec3 wi_up = microfacet_reflect(wo_up, mh, wo_m);
    if (!(wi_up.z > 0.0f)) return false;  /* reflected below the horizon: the sample is lost */
    struct vec3 wi = vec3_normalize(microfacet_flip_z(wi_up, sign));
    /* f and pdf are re-evaluated from (wo, wi) rather than taken from the sampled m so that
     * sample() and eval()/pdf() agree to the last bit; shift mappings depend on that. */
    out->wi = wi;
    out->f = bsdf_conductor_eval(m, wo, wi);
    out->pdf_w = bsdf_conductor_pdf(m, wo, wi);
    out->pdf_rev_w = bsdf_conductor_pdf(m, wi, wo);
    return out->pdf_w > 0.0f && isfinite(out->pdf_w);
}
