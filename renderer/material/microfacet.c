/* microfacet.c — GGX D, Smith Lambda / G1 / height-correlated G2, and visible-normal sampling
 * (see microfacet.h for the contracts). No Fresnel, no material knowledge, no allocation.
 * Refs: Walter et al. 2007 eqs. 33-34; Heitz 2014 (Smith Lambda, height-correlated G2);
 * Heitz 2018 "Sampling the GGX Distribution of Visible Normals". */
#include "material/microfacet.h"

float microfacet_d(struct vec3 m, float alpha)
{
    if (!(m.z > 0.0f)) return 0.0f;
    /* Walter eq. 33, alpha^2 / (pi cos^4 (alpha^2 + tan^2)^2), rewritten without tan so that it
     * stays finite at m.z -> 0: 1 / (pi alpha^2 ((x^2 + y^2) / alpha^2 + z^2)^2). */
    float a2 = alpha * alpha;
    float t = (m.x * m.x + m.y * m.y) / a2 + m.z * m.z;
    return 1.0f / (PI_F * a2 * t * t);
}

float microfacet_lambda(struct vec3 w, float alpha)
{
    float z2 = w.z * w.z;
    if (!(z2 > 0.0f)) return INFINITY;
    float a2_tan2 = alpha * alpha * (w.x * w.x + w.y * w.y) / z2;
    return 0.5f * (sqrtf(1.0f + a2_tan2) - 1.0f);
}

float microfacet_g1(struct vec3 w, float alpha)
{
    return 1.0f / (1.0f + microfacet_lambda(w, alpha));
}

float microfacet_g2(struct vec3 wo, struct vec3 wi, float alpha)
{
    return 1.0f / (1.0f + microfacet_lambda(wo, alpha) + microfacet_lambda(wi, alpha));
}

struct vec3 microfacet_sample_visible(struct vec3 wo, float alpha, float u1, float u2)
{
    /* Heitz 2018: scaling x, y by alpha maps the GGX microsurface to the hemisphere of radius 1
     * (alpha = 1), whose visible normals are the hemisphere points seen from the stretched view
     * direction. Their projection onto the plane orthogonal to the view is a unit disk whose
     * far half is partly hidden: a uniform disk sample with its far half squeezed by
     * (1 + vz) / 2 and lifted back onto the hemisphere is distributed as the visible normals. */
    struct vec3 v = vec3_normalize(vec3_make(alpha * wo.x, alpha * wo.y, wo.z));

    /* Basis (t1, t2, v) with t1 horizontal, so the squeeze acts along t2. */
    float len2 = v.x * v.x + v.y * v.y;
    struct vec3 t1 = len2 > 0.0f ? vec3_scale(vec3_make(-v.y, v.x, 0.0f), 1.0f / sqrtf(len2))
                                 : vec3_make(1.0f, 0.0f, 0.0f);
    struct vec3 t2 = vec3_cross(v, t1);

    float r = sqrtf(u1);
    float phi = 2.0f * PI_F * u2;
    float p1 = r * cosf(phi);
    float p2 = r * sinf(phi);
    float s = 0.5f * (1.0f + v.z);
    p2 = (1.0f - s) * sqrtf(fmaxf(0.0f, 1.0f - p1 * p1)) + s * p2;
    float pv = sqrtf(fmaxf(0.0f, 1.0f - p1 * p1 - p2 * p2));
    struct vec3 nh = vec3_add(vec3_add(vec3_scale(t1, p1), vec3_scale(t2, p2)), vec3_scale(v, pv));

    /* Unstretch: normals transform with the inverse transpose, i.e. x, y scale by alpha. */
    return vec3_normalize(vec3_make(alpha * nh.x, alpha * nh.y, fmaxf(0.0f, nh.z)));
}

float microfacet_pdf_visible(struct vec3 wo, struct vec3 m, float alpha)
{
    if (!(wo.z > 0.0f)) return 0.0f;
    float wo_m = vec3_dot(wo, m);
    if (!(wo_m > 0.0f)) return 0.0f;
    return microfacet_g1(wo, alpha) * wo_m * microfacet_d(m, alpha) / wo.z;
}
