/* sampling.h — warps from the unit square to directions and surfaces, with their pdfs, and
 * MIS heuristics. Header-only, allocation-free. Measures: `_w` solid angle, `_a` area. */
#ifndef RESTIRD_SAMPLING_H
#define RESTIRD_SAMPLING_H

#include "vec.h"

/* Concentric disk mapping (Shirley & Chiu 1997): unit square -> unit disk, area-preserving. */
static inline void sampling_concentric_disk(float u1, float u2, float *dx, float *dy)
{
    float a = 2.0f * u1 - 1.0f, b = 2.0f * u2 - 1.0f;
    if (a == 0.0f && b == 0.0f) { *dx = 0.0f; *dy = 0.0f; return; }
    float r, phi;
    if (fabsf(a) > fabsf(b)) { r = a; phi = (PI_F / 4.0f) * (b / a); }
    else { r = b; phi = (PI_F / 2.0f) - (PI_F / 4.0f) * (a / b); }
    *dx = r * cosf(phi);
    *dy = r * sinf(phi);
}

/* Cosine-weighted hemisphere around +z; pdf_w = cos(theta) / pi. */
static inline struct vec3 sampling_cosine_hemisphere(float u1, float u2)
{
    float x, y;
    sampling_concentric_disk(u1, u2, &x, &y);
    float z = sqrtf(fmaxf(0.0f, 1.0f - x * x - y * y));
    return vec3_make(x, y, z);
}
static inline float sampling_cosine_hemisphere_pdf_w(float cos_theta)
{
    return cos_theta > 0.0f ? cos_theta * INV_PI_F : 0.0f;
}

/* Uniform direction on the unit sphere; pdf_w = 1 / (4 pi). */
static inline struct vec3 sampling_uniform_sphere(float u1, float u2)
{
    float z = 1.0f - 2.0f * u1;
    float r = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    float phi = 2.0f * PI_F * u2;
    return vec3_make(r * cosf(phi), r * sinf(phi), z);
}
#define SAMPLING_UNIFORM_SPHERE_PDF_W (1.0f / (4.0f * PI_F))

/* Uniform point on a triangle as barycentrics (b1, b2) of vertices 1 and 2; pdf_a = 1/area.
 * Uses the square-root parameterisation (Osada et al. 2002). */
static inline void sampling_uniform_triangle(float u1, float u2, float *b1, float *b2)
{
    float su = sqrtf(u1);
    *b1 = 1.0f - su;
    *b2 = u2 * su;
}

/* Power heuristic with beta = 2 for one sample of each strategy (Veach 1997 §9.2.4). */
static inline float sampling_power_heuristic(float pdf_a, float pdf_b)
{
    float a2 = pdf_a * pdf_a, b2 = pdf_b * pdf_b;
    if (!(a2 > 0.0f)) return 0.0f;
    if (isinf(a2)) return 1.0f;
    return a2 / (a2 + b2);
}

/* Solid-angle pdf of a point sampled with area pdf `pdf_a` seen from distance `dist2` at
 * cosine `cos_at_point` on the sampled surface. Zero for grazing points. */
static inline float sampling_area_to_solid_angle(float pdf_a, float dist2, float cos_at_point)
{
    float c = fabsf(cos_at_point);
    return c > 0.0f ? pdf_a * dist2 / c : 0.0f;
}

#endif
