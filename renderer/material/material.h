/* material.h — materials and the BSDF interface every integrator uses.
 * All directions are in the local shading frame (z = shading normal) and point away from the
 * surface: wo towards the viewer/previous vertex, wi towards the next vertex. Values f are the
 * BSDF without the cosine factor. Opaque materials (diffuse, conductor) are two-sided: they
 * shade the side that wo is on and return 0 for wi in the other hemisphere. Dielectrics
 * treat +z as outside (ior is inside/outside).
 * material.c holds the only switch on material kind; the Lambertian pieces below are inline so
 * that a path loop can take them without the dispatch, and material_diffuse_path says where
 * they apply (the one test of the kind outside material.c). Thread-safe: pure functions. */
#ifndef RESTIRD_MATERIAL_H
#define RESTIRD_MATERIAL_H

#include <math.h>
#include <stdbool.h>

#include "core/rng.h"
#include "core/sampling.h"
#include "core/vec.h"

enum material_kind {
    MATERIAL_DIFFUSE,     /* Lambertian, albedo */
    MATERIAL_CONDUCTOR,   /* GGX microfacet conductor, complex IOR (eta, k); roughness 0 = mirror */
    MATERIAL_DIELECTRIC,  /* smooth or GGX-rough dielectric interface, ior */
    MATERIAL_TRANSLUCENT, /* subsurface scattering (bssrdf.h): Burley diffusion behind a smooth
                             dielectric boundary (ior) with albedo and per-channel mean free path;
                             as a BSDF (material_eval etc.) it is the local stand-in of bssrdf.h */
};

/* Lobe flags. A lobe is exactly one of DIFFUSE, GLOSSY, DELTA, and REFLECTION or TRANSMISSION. */
enum bsdf_flag {
    BSDF_REFLECTION = 1u << 0,
    BSDF_TRANSMISSION = 1u << 1,
    BSDF_DIFFUSE = 1u << 2,
    BSDF_GLOSSY = 1u << 3,
    BSDF_DELTA = 1u << 4,
};

/* Which quantity a path carries. Refraction scales radiance by 1/eta^2 but not importance
 * (Veach 1997 §5.2), so light tracing must pass TRANSPORT_IMPORTANCE. */
enum transport_mode { TRANSPORT_RADIANCE, TRANSPORT_IMPORTANCE };

#define MATERIAL_MAX_LOBES 2

struct material {
    enum material_kind kind;
    struct vec3 albedo;       /* DIFFUSE: reflectance in [0, 1] */
    struct vec3 eta, k;       /* CONDUCTOR: complex index of refraction per channel */
    float ior;                /* DIELECTRIC, TRANSLUCENT: interior / exterior index, > 0, != 1 */
    struct vec3 mfp;          /* TRANSLUCENT: mean free path l per channel (scene units), > 0 */
    struct vec3 sss_d;        /* TRANSLUCENT: Burley's d = l / s(albedo) per channel (bssrdf_prepare) */
    struct vec3 sss_r_max;    /* TRANSLUCENT: the profile's cut-off radius per channel (bssrdf_prepare) */
    float sss_c;              /* TRANSLUCENT: 1 - 2 (first Fresnel moment), normalises the boundary
                                 transmission term (bssrdf_prepare) */
    float roughness;          /* CONDUCTOR, DIELECTRIC: GGX alpha; 0 = perfectly smooth (delta).
                                 Below MICROFACET_DELTA_ALPHA (1e-4) it is treated as 0. */
    struct vec3 emission;     /* radiance leaving the front face (any kind); zero = not emissive */
    bool two_sided_emission;  /* emits from both faces */
};

struct bsdf_sample {
    struct vec3 wi;   /* sampled direction, local frame, unit length */
    struct vec3 f;    /* BSDF value of the sampled lobe (for delta lobes: the weight that, times
                         |cos wi| / pdf_w, gives the throughput; pdf_w is then the discrete
                         lobe probability) */
    float pdf_w;      /* solid-angle pdf of wi given wo, including the lobe choice */
    float pdf_rev_w;  /* solid-angle pdf of sampling wo given wi through the same lobe, i.e.
                         material_pdf_lobe(m, lobe, wi, wo); for delta lobes the discrete
                         probability of choosing that lobe from wi (refraction: the reverse
                         crossing's 1 - F) */
    int lobe;         /* index of the sampled lobe, 0 .. material_lobe_count()-1 */
    unsigned flags;   /* flags of the sampled lobe */
};

/* Number of lobes and each lobe's flags and GGX roughness (0 for diffuse and delta lobes count
 * as: diffuse -> 1, delta -> 0). Diffuse: 1 lobe; conductor: 1; dielectric: 2 (0 reflection,
 * 1 transmission); translucent: 1 (its diffuse stand-in). */
int material_lobe_count(const struct material *m);
unsigned material_lobe_flags(const struct material *m, int lobe);
float material_lobe_roughness(const struct material *m, int lobe);
/* Union of the flags of all lobes. */
unsigned material_flags(const struct material *m);
/* Whether m scatters through a near-specular lobe: a delta lobe, no diffuse or glossy one, or a
 * glossy lobe of GGX roughness below alpha_min. A path through such a vertex is found by the
 * camera's sampling only through a narrow lobe, and no shift reconnects at it. */
bool material_near_specular(const struct material *m, float alpha_min);
static inline bool material_is_emissive(const struct material *m) { return !vec3_is_zero(m->emission); }

/* BSDF value f(wo, wi) summed over non-delta lobes; 0 for delta-only materials. */
struct vec3 material_eval(const struct material *m, struct vec3 wo, struct vec3 wi, enum transport_mode mode);
/* Solid-angle pdf that material_sample returns wi given wo, summed over non-delta lobes with
 * their selection probabilities. The reverse pdf is material_pdf(m, wi, wo). */
float material_pdf(const struct material *m, struct vec3 wo, struct vec3 wi);
/* The same restricted to one lobe (lobe-indexed paths, [ReSTIR PT Enhanced §1]): eval of that lobe
 * alone and pdf of sampling wi *through* that lobe, including its selection probability. */
struct vec3 material_eval_lobe(const struct material *m, int lobe, struct vec3 wo, struct vec3 wi,
                               enum transport_mode mode);
float material_pdf_lobe(const struct material *m, int lobe, struct vec3 wo, struct vec3 wi);
/* Samples a lobe (with u_lobe) and a direction (with u1, u2). Returns false when no direction
 * can be produced (wo grazing, total absorption, wi below the surface): the path ends.
 * For non-delta lobes f and pdf_w are material_eval_lobe / material_pdf_lobe recomputed at the
 * returned wi, so they agree with later evaluations exactly. Weights f |cos wi| / pdf_w:
 * diffuse = albedo; conductor F(wo.m) G2 / G1(wo) <= F; dielectric reflection <= 1, refraction <= 1 in
 * TRANSPORT_IMPORTANCE and <= (eta_wo / eta_wi)^2 in TRANSPORT_RADIANCE (Veach 1997 §5.2:
 * f_radiance(wo, wi) / eta_wo^2 = f_radiance(wi, wo) / eta_wi^2, f_importance(wo, wi) =
 * f_radiance(wi, wo)). */
bool material_sample(const struct material *m, struct vec3 wo, float u_lobe, float u1, float u2,
                     enum transport_mode mode, struct bsdf_sample *out);
/* Whether the material_diffuse_* pieces below stand in for material_eval, material_pdf and
 * material_sample at m, bit for bit (tests/unit/test_bsdf.c): a path loop's fast path. */
static inline bool material_diffuse_path(const struct material *m) { return m->kind == MATERIAL_DIFFUSE; }
/* The flags of that path's one lobe: material_flags(m) and every sample's bsdf_sample.flags. */
static inline unsigned material_diffuse_flags(void) { return BSDF_REFLECTION | BSDF_DIFFUSE; }
/* The Lambertian BRDF (MATERIAL_DIFFUSE, and bsdf_diffuse.c builds on these) needs only the
 * cosines of wo and wi with the shading normal, not the whole local directions: f = albedo / pi
 * when both are on the same side, and the cosine-weighted pdf of wi. Bit for bit what
 * material_eval and material_pdf return for a diffuse material. */
static inline struct vec3 material_diffuse_f(const struct material *m, float cos_o, float cos_i)
{
    if (!(cos_o * cos_i > 0.0f)) return vec3_splat(0.0f);
    return vec3_scale(m->albedo, INV_PI_F);
}
static inline float material_diffuse_pdf(float cos_o, float cos_i)
{
    if (!(cos_o * cos_i > 0.0f)) return 0.0f;
    return sampling_cosine_hemisphere_pdf_w(fabsf(cos_i));
}
/* The local direction a diffuse material samples for (u1, u2): cosine-weighted on the side of
 * cos_o. False on the disk rim (zero pdf) and for wo in the surface. */
static inline bool material_diffuse_direction(float cos_o, float u1, float u2, struct vec3 *wi)
{
    if (cos_o == 0.0f) return false;
    *wi = sampling_cosine_hemisphere(u1, u2);
    if (cos_o < 0.0f) wi->z = -wi->z;
    return wi->z != 0.0f;
}
/* material_sample for a diffuse material, reduced to what a path needs: the direction, its pdf
 * and the weight f |cos wi| / pdf_w, the same bits as from material_sample's f and pdf_w. The
 * checks material_sample adds for degenerate samples cannot fail here: albedo is in [0, 1]
 * (the scene loader's range), |wi.z| <= 1. */
static inline bool material_diffuse_sample(const struct material *m, float cos_o, float u1, float u2, struct vec3 *wi,
                                           float *pdf_w, struct vec3 *weight)
{
    if (!material_diffuse_direction(cos_o, u1, u2, wi)) return false;
    *pdf_w = material_diffuse_pdf(cos_o, wi->z);
    if (!(*pdf_w > 0.0f)) return false;
    *weight = vec3_scale(material_diffuse_f(m, cos_o, wi->z), fabsf(wi->z) / *pdf_w);
    return true;
}

/* A path's continuation by BSDF sampling at a surface with shading frame `fr` and geometric
 * normal ng (wo in the frame): the lobe and the direction from the next three numbers of rng,
 * the direction in world space and its cosine with ng. False when nothing was sampled, or the
 * direction leaves through the other side of the geometric surface than of the shading frame (a
 * light leak of shading normals, which every integrator ends there). */
static inline bool material_sample_at(const struct material *m, const struct frame *fr, struct vec3 ng, struct vec3 wo,
                                      struct rng *rng, enum transport_mode mode, struct bsdf_sample *bs,
                                      struct vec3 *wi_world, float *cos_i_ng)
{
    float ulobe = rng_next_float(rng), v1 = rng_next_float(rng), v2 = rng_next_float(rng);
    if (!material_sample(m, wo, ulobe, v1, v2, mode, bs)) return false;
    *wi_world = frame_to_world(fr, bs->wi);
    *cos_i_ng = vec3_dot(*wi_world, ng);
    return *cos_i_ng * bs->wi.z > 0.0f;
}

/* A light subpath's continuation (importance transport) from wo_world: material_sample_at, and
 * the throughput weight with the adjoint shading-normal correction (Veach 1997 eq. 5.19),
 * f |wo.ns| |wi.ng| / (|wo.ng| pdf). False also when wo_world lies in the geometric surface. */
static inline bool material_sample_importance(const struct material *m, const struct frame *fr, struct vec3 ng,
                                              struct vec3 wo_world, struct rng *rng, struct bsdf_sample *bs,
                                              struct vec3 *wi_world, float *cos_i_ng, struct vec3 *weight)
{
    struct vec3 wo = frame_to_local(fr, wo_world);
    float cos_o_ng = vec3_dot(wo_world, ng);
    if (!material_sample_at(m, fr, ng, wo, rng, TRANSPORT_IMPORTANCE, bs, wi_world, cos_i_ng) || cos_o_ng == 0.0f)
        return false;
    *weight = vec3_scale(bs->f, fabsf(wo.z) * fabsf(*cos_i_ng) / (fabsf(cos_o_ng) * bs->pdf_w));
    return true;
}

/* The factor (eta_wo / eta_wi)^2 that TRANSPORT_RADIANCE puts into a refraction from wo to wi
 * through a dielectric (wo and wi on opposite sides); 1 for every other scattering. A camera
 * path's throughput carries the product of these factors, which cancels when the path leaves
 * the medium it entered: Russian roulette that divides it out decides on the energy the path
 * will carry out of the medium, not on the 1 / eta^2 it carries inside (Veach 1997 §5.2). */
float material_radiance_scale(const struct material *m, struct vec3 wo, struct vec3 wi);

#endif
