/* material.c — the material interface of material.h: lobe structure (count, flags, roughness)
 * and dispatch of eval / pdf / sample to bsdf_diffuse.c, bsdf_conductor.c, bsdf_dielectric.c,
 * bsdf_translucent.c.
 * This is the only switch on material kind in the renderer; the BSDF mathematics lives in the
 * bsdf_*.c files, microfacet.c and fresnel.h, never here.
 * Refs: [ReSTIR PT Enhanced §1] (lobe-indexed paths: sampling reports the lobe; eval/pdf per
 * lobe). */
#include "material/material.h"

#include "material/bsdf.h"
#include "material/microfacet.h"

int material_lobe_count(const struct material *m)
{
    switch (m->kind) {
    case MATERIAL_DIFFUSE: return 1;
    case MATERIAL_CONDUCTOR: return 1;
    case MATERIAL_DIELECTRIC: return 2;
    case MATERIAL_TRANSLUCENT: return 1;
    }
    return 0;
}

static bool material_lobe_valid(const struct material *m, int lobe)
{
    return lobe >= 0 && lobe < material_lobe_count(m);
}

unsigned material_lobe_flags(const struct material *m, int lobe)
{
    if (!material_lobe_valid(m, lobe)) return 0;
    unsigned spread = microfacet_is_delta(m->roughness) ? BSDF_DELTA : BSDF_GLOSSY;
    switch (m->kind) {
    case MATERIAL_DIFFUSE: return material_diffuse_flags();
    case MATERIAL_CONDUCTOR: return BSDF_REFLECTION | spread;
    case MATERIAL_DIELECTRIC: return (lobe == 0 ? BSDF_REFLECTION : BSDF_TRANSMISSION) | spread;
    case MATERIAL_TRANSLUCENT: return BSDF_REFLECTION | BSDF_DIFFUSE;
    }
    return 0;
}

float material_lobe_roughness(const struct material *m, int lobe)
{
    unsigned flags = material_lobe_flags(m, lobe);
    if (flags & BSDF_DIFFUSE) return 1.0f;
    if (flags & BSDF_GLOSSY) return m->roughness;
    return 0.0f;  /* delta lobe, or no such lobe */
}

unsigned material_flags(const struct material *m)
{
    /* The union of material_lobe_flags over all lobes, spelled out: it is asked at every path
     * vertex. */
    unsigned spread = microfacet_is_delta(m->roughness) ? BSDF_DELTA : BSDF_GLOSSY;
    switch (m->kind) {
    case MATERIAL_DIFFUSE: return material_diffuse_flags();
    case MATERIAL_CONDUCTOR: return BSDF_REFLECTION | spread;
    case MATERIAL_DIELECTRIC: return BSDF_REFLECTION | BSDF_TRANSMISSION | spread;
    case MATERIAL_TRANSLUCENT: return BSDF_REFLECTION | BSDF_DIFFUSE;
    }
    return 0;
}

struct vec3 material_eval_lobe(const struct material *m, int lobe, struct vec3 wo, struct vec3 wi,
                               enum transport_mode mode)
{
    if (!material_lobe_valid(m, lobe)) return vec3_splat(0.0f);
    switch (m->kind) {
    case MATERIAL_DIFFUSE: return bsdf_diffuse_eval(m, wo, wi);
    case MATERIAL_CONDUCTOR: return bsdf_conductor_eval(m, wo, wi);
    case MATERIAL_DIELECTRIC: return bsdf_dielectric_eval_lobe(m, lobe, wo, wi, mode);
    case MATERIAL_TRANSLUCENT: return bsdf_translucent_eval(m, wo, wi);
    }
    return vec3_splat(0.0f);
}

float material_pdf_lobe(const struct material *m, int lobe, struct vec3 wo, struct vec3 wi)
{
    if (!material_lobe_valid(m, lobe)) return 0.0f;
    switch (m->kind) {
    case MATERIAL_DIFFUSE: return bsdf_diffuse_pdf(wo, wi);
    case MATERIAL_CONDUCTOR: return bsdf_conductor_pdf(m, wo, wi);
    case MATERIAL_DIELECTRIC: return bsdf_dielectric_pdf_lobe(m, lobe, wo, wi);
    case MATERIAL_TRANSLUCENT: return bsdf_diffuse_pdf(wo, wi);
    }
    return 0.0f;
}

/* The dielectric's lobes occupy disjoint hemispheres (reflection: wi on wo's side), so the sum
 * over lobes is the one lobe that can be non-zero. */
static int material_dielectric_lobe_of(struct vec3 wo, struct vec3 wi) { return wo.z * wi.z > 0.0f ? 0 : 1; }

struct vec3 material_eval(const struct material *m, struct vec3 wo, struct vec3 wi, enum transport_mode mode)
{
    switch (m->kind) {
    case MATERIAL_DIFFUSE: return bsdf_diffuse_eval(m, wo, wi);
    case MATERIAL_CONDUCTOR: return bsdf_conductor_eval(m, wo, wi);
    case MATERIAL_DIELECTRIC:
        return bsdf_dielectric_eval_lobe(m, material_dielectric_lobe_of(wo, wi), wo, wi, mode);
    case MATERIAL_TRANSLUCENT: return bsdf_translucent_eval(m, wo, wi);
    }
    return vec3_splat(0.0f);
}

float material_pdf(const struct material *m, struct vec3 wo, struct vec3 wi)
{
    switch (m->kind) {
    case MATERIAL_DIFFUSE: return bsdf_diffuse_pdf(wo, wi);
    case MATERIAL_CONDUCTOR: return bsdf_conductor_pdf(m, wo, wi);
    case MATERIAL_DIELECTRIC: return bsdf_dielectric_pdf_lobe(m, material_dielectric_lobe_of(wo, wi), wo, wi);
    case MATERIAL_TRANSLUCENT: return bsdf_diffuse_pdf(wo, wi);
    }
    return 0.0f;
}

float material_radiance_scale(const struct material *m, struct vec3 wo, struct vec3 wi)
{
    if (m->kind != MATERIAL_DIELECTRIC || material_dielectric_lobe_of(wo, wi) != 1) return 1.0f;
    const float eta = wo.z > 0.0f ? m->ior : 1.0f / m->ior;  /* eta_wi / eta_wo */
    return 1.0f / (eta * eta);
}

bool material_sample(const struct material *m, struct vec3 wo, float u_lobe, float u1, float u2,
                     enum transport_mode mode, struct bsdf_sample *out)
{
    bool ok = false;
    switch (m->kind) {
    case MATERIAL_DIFFUSE: ok = bsdf_diffuse_sample(m, wo, u1, u2, out); break;
    case MATERIAL_CONDUCTOR: ok = bsdf_conductor_sample(m, wo, u1, u2, out); break;
    case MATERIAL_DIELECTRIC: ok = bsdf_dielectric_sample(m, wo, u_lobe, u1, u2, mode, out); break;
    case MATERIAL_TRANSLUCENT: ok = bsdf_translucent_sample(m, wo, u1, u2, out); break;
    }
    if (!ok) return false;
    out->flags = material_lobe_flags(m, out->lobe);
    /* Render kernels never fail: a degenerate sample (NaN from a broken input direction, an
     * infinite weight) ends the path instead of poisoning the image. */
    return out->pdf_w > 0.0f && isfinite(out->pdf_w) && vec3_is_finite(out->f) && vec3_is_finite(out->wi);
}

bool material_near_specular(const struct material *m, float alpha_min)
{
    const unsigned f = material_flags(m);
    if (!(f & (BSDF_DIFFUSE | BSDF_GLOSSY)) || (f & BSDF_DELTA)) return true;
    const int n = material_lobe_count(m);
    for (int i = 0; i < n; i++)
        if ((material_lobe_flags(m, i) & BSDF_GLOSSY) && material_lobe_roughness(m, i) < alpha_min) return true;
    return false;
}
