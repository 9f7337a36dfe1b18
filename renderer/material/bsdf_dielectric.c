/* bsdf_dielectric.c — dielectric interface (+z = outside, ior = inside / outside): smooth
 * (delta reflection with probability F, delta refraction with 1 - F) or GGX-rough (Walter et al.
 * 2007, visible-normal sampling of m, then reflect with probability F(wo.m) else refract).
 * Lobe 0 = reflection, lobe 1 = transmission. Radiance transport scales refraction by
 * (eta_wo / eta_wi)^2; importance transport does not (Veach 1997 §5.2).
 * Called only through material.c (bsdf.h). Refs: Walter et al. 2007 eqs. 14, 16-17, 20-22;
 * Heitz 2018 (visible normals); Veach 1997 §5.2 (non-symmetric scattering). */
#include "material/bsdf.h"
#include "material/fresnel.h"
#include "material/microfacet.h"

/* Every routine works in wo's frame: directions mirrored so that wo.z > 0, and eta is the
 * relative IOR eta_other_side / eta_wo_side (> 1 when wo is outside a denser medium). */
struct bsdf_dielectric_side {
    float sign;            /* sign of the original wo.z */
    float eta;             /* eta_wi / eta_wo for a transmission */
    float eta_wo, eta_wi;  /* absolute indices (outside = 1) for fresnel_dielectric_transmittance */
};

static struct bsdf_dielectric_side bsdf_dielectric_side_of(const struct material *m, float wo_z)
{
    struct bsdf_dielectric_side s;
    bool outside = wo_z > 0.0f;
    s.sign = outside ? 1.0f : -1.0f;
    s.eta = outside ? m->ior : 1.0f / m->ior;
    s.eta_wo = outside ? 1.0f : m->ior;
    s.eta_wi = outside ? m->ior : 1.0f;
    return s;
}

/* Refracts w (w.n > 0, pointing away) through the plane with normal n, eta = eta_t / eta_i.
 * Snell's law in vector form; false under total internal reflection. */
static bool bsdf_dielectric_refract(struct vec3 w, struct vec3 n, float eta, struct vec3 *out)
{
    float cos_i = vec3_dot(w, n);
    float sin2_t = (1.0f - cos_i * cos_i) / (eta * eta);
    if (!(sin2_t < 1.0f)) return false;
    float cos_t = sqrtf(1.0f - sin2_t);
    *out = vec3_add(vec3_scale(w, -1.0f / eta), vec3_scale(n, cos_i / eta - cos_t));
    return true;
}

/* The microfacet normal that maps wo to wi (both in wo's frame) and the cosines with it.
 * Reflection: m = normalize(wo + wi) (Walter eq. 13). Transmission: the generalized half vector
 * m = -normalize(eta_o wo + eta_i wi) (Walter eq. 16), oriented to m.z > 0, valid only when wo
 * and wi lie on opposite sides of the microfacet. */
static bool bsdf_dielectric_half(struct vec3 wo, struct vec3 wi, float eta, bool reflect,
                                 struct vec3 *mh, float *wo_m, float *wi_m)
{
    struct vec3 h = reflect ? vec3_add(wo, wi) : vec3_madd(wo, wi, eta);
    if (!(vec3_length2(h) > 0.0f)) return false;
    h = vec3_normalize(h);
    if (h.z < 0.0f) h = vec3_neg(h);
    *mh = h;
    *wo_m = vec3_dot(wo, h);
    *wi_m = vec3_dot(wi, h);
    if (!(*wo_m > 0.0f)) return false;
    return reflect ? *wi_m > 0.0f : *wi_m < 0.0f;
}

struct vec3 bsdf_dielectric_eval_lobe(const struct material *m, int lobe, struct vec3 wo,
                                      struct vec3 wi, enum transport_mode mode)
{
    float alpha = m->roughness;
    if (microfacet_is_delta(alpha) || wo.z == 0.0f || wi.z == 0.0f) return vec3_splat(0.0f);
    bool reflect = wo.z * wi.z > 0.0f;
    if (reflect != (lobe == 0)) return vec3_splat(0.0f);
    struct bsdf_dielectric_side side = bsdf_dielectric_side_of(m, wo.z);
    wo = microfacet_flip_z(wo, side.sign);
    wi = microfacet_flip_z(wi, side.sign);
    struct vec3 mh;
    float wo_m, wi_m;
    if (!bsdf_dielectric_half(wo, wi, side.eta, reflect, &mh, &wo_m, &wi_m)) return vec3_splat(0.0f);
    float dg = microfacet_d(mh, alpha) * microfacet_g2(wo, wi, alpha);
    if (reflect)  /* Walter eq. 20 */
        return vec3_splat(fresnel_dielectric(wo_m, side.eta) * dg / (4.0f * wo.z * wi.z));
    /* Walter eq. 21 in relative indices eta_wo = 1, eta_wi = eta (wo's frame):
     *   f = |wi.m| |wo.m| / (|wi.n| |wo.n|) eta_wo^2 (1 - F) G2 D / (eta_wo wo.m + eta_wi wi.m)^2.
     * This is the radiance BTDF (light arrives along wi, leaves along wo). It obeys
     * f(wo, wi) / eta_wo^2 = f(wi, wo) / eta_wi^2 (Veach 1997 eq. 5.14), and its adjoint, the
     * BTDF for importance, is f*(wo, wi) = f(wi, wo) = eta^2 f(wo, wi).
     * 1 - F comes from fresnel_dielectric_transmittance, exact near TIR and symmetric. */
    float den = wo_m + side.eta * wi_m;
    float den2 = den * den;
    if (!(den2 > 0.0f)) return vec3_splat(0.0f);
    float tr = fresnel_dielectric_transmittance(wo_m, -wi_m, side.eta_wo, side.eta_wi);
    float ft = tr * dg * fabsf(wo_m * wi_m) / (wo.z * fabsf(wi.z) * den2);
    if (mode == TRANSPORT_IMPORTANCE) ft *= side.eta * side.eta;
    return vec3_splat(ft);
}

float bsdf_dielectric_pdf_lobe(const struct material *m, int lobe, struct vec3 wo, struct vec3 wi)
{
    float alpha = m->roughness;
    if (microfacet_is_delta(alpha) || wo.z == 0.0f || wi.z == 0.0f) return 0.0f;
    bool reflect = wo.z * wi.z > 0.0f;
    if (reflect != (lobe == 0)) return 0.0f;
    struct bsdf_dielectric_side side = bsdf_dielectric_side_of(m, wo.z);
    wo = microfacet_flip_z(wo, side.sign);
    wi = microfacet_flip_z(wi, side.sign);
    struct vec3 mh;
    float wo_m, wi_m;
    if (!bsdf_dielectric_half(wo, wi, side.eta, reflect, &mh, &wo_m, &wi_m)) return 0.0f;
    float pdf_m = microfacet_pdf_visible(wo, mh, alpha);
    /* Lobe choice F(wo.m) or 1 - F(wo.m), times the Jacobian dw_m / dw_i:
     * reflection 1 / (4 |wo.m|) (Walter eq. 14), refraction eta_i^2 |wi.m| / (eta_o wo.m +
     * eta_i wi.m)^2 (Walter eq. 17, with the roles of i and o as sampled here). */
    if (reflect) return fresnel_dielectric(wo_m, side.eta) * pdf_m / (4.0f * wo_m);
    float den = wo_m + side.eta * wi_m;
    float den2 = den * den;
    if (!(den2 > 0.0f)) return 0.0f;
    /* The sampler chose refraction with probability 1 - fresnel_dielectric(wo.m); the
     * transmittance form equals it up to float rounding (absolute ~1e-7) and stays accurate
     * where 1 - F is tiny. */
    float tr = fresnel_dielectric_transmittance(wo_m, -wi_m, side.eta_wo, side.eta_wi);
    return tr * pdf_m * side.eta * side.eta * fabsf(wi_m) / den2;
}

static bool bsdf_dielectric_sample_smooth(const struct material *m, struct vec3 wo, float u_lobe,
                                          enum transport_mode mode, struct bsdf_sample *out)
{
    struct bsdf_dielectric_side side = bsdf_dielectric_side_of(m, wo.z);
    float cos_o = fabsf(wo.z);
    float fr = fresnel_dielectric(cos_o, side.eta);
    /* pdf_w are the discrete lobe probabilities (material.h); f is chosen so that
     * f |cos wi| / pdf_w is 1 for reflection and (eta_wo / eta_wi)^2 or 1 for refraction. */
    if (u_lobe < fr) {
        out->wi = vec3_make(-wo.x, -wo.y, wo.z);
        out->f = vec3_splat(fr / cos_o);
        out->pdf_w = fr;
        out->pdf_rev_w = fr;  /* same angle seen from wi: same F */
        out->lobe = 0;
        return true;
    }
    struct vec3 wt;
    if (!bsdf_dielectric_refract(microfacet_flip_z(wo, side.sign), vec3_make(0.0f, 0.0f, 1.0f),
                                 side.eta, &wt))
        return false;  /* unreachable: TIR means fr = 1 > u_lobe */
    float cos_t = fabsf(wt.z);
    if (!(cos_t > 0.0f)) return false;
    float scale = mode == TRANSPORT_RADIANCE ? 1.0f / (side.eta * side.eta) : 1.0f;
    /* 1 - F in the transmittance form: accurate near TIR, and the reverse crossing (pdf_rev_w)
     * gets bit-identical probability. */
    float tr = fresnel_dielectric_transmittance(cos_o, cos_t, side.eta_wo, side.eta_wi);
    out->wi = microfacet_flip_z(wt, side.sign);
    out->f = vec3_splat(tr * scale / cos_t);
    out->pdf_w = tr;
    out->pdf_rev_w = fresnel_dielectric_transmittance(cos_t, cos_o, side.eta_wi, side.eta_wo);
    out->lobe = 1;
    return out->pdf_w > 0.0f;
}

bool bsdf_dielectric_sample(const struct material *m, struct vec3 wo, float u_lobe, float u1,
                            float u2, enum transport_mode mode, struct bsdf_sample *out)
{
    if (wo.z == 0.0f) return false;
    float alpha = m->roughness;
    if (microfacet_is_delta(alpha)) return bsdf_dielectric_sample_smooth(m, wo, u_lobe, mode, out);

    struct bsdf_dielectric_side side = bsdf_dielectric_side_of(m, wo.z);
    struct vec3 wo_up = microfacet_flip_z(wo, side.sign);
    struct vec3 mh = microfacet_sample_visible(wo_up, alpha, u1, u2);
    float wo_m = vec3_dot(wo_up, mh);
    if (!(wo_m > 0.0f)) return false;
    float fr = fresnel_dielectric(wo_m, side.eta);
    struct vec3 wi_up;
    int lobe;
    if (u_lobe < fr) {
        wi_up = microfacet_reflect(wo_up, mh, wo_m);
        if (!(wi_up.z > 0.0f)) return false;  /* reflected below the horizon: lost */
        lobe = 0;
    } else {
        if (!bsdf_dielectric_refract(wo_up, mh, side.eta, &wi_up)) return false;
        if (!(wi_up.z < 0.0f)) return false;  /* refracted back above the surface: lost */
        lobe = 1;
    }
    struct vec3 wi = vec3_normalize(microfacet_flip_z(wi_up, side.sign));
    /* Re-evaluated from (wo, wi) so that sample() agrees with eval_lobe()/pdf_lobe() exactly
     * (the lobe probability F(wo.m) is part of pdf_lobe). */
    out->wi = wi;
    out->lobe = lobe;
    out->f = bsdf_dielectric_eval_lobe(m, lobe, wo, wi, mode);
    out->pdf_w = bsdf_dielectric_pdf_lobe(m, lobe, wo, wi);
    out->pdf_rev_w = bsdf_dielectric_pdf_lobe(m, lobe, wi, wo);
    return out->pdf_w > 0.0f && isfinite(out->pdf_w);
}
