/* fresnel.h — exact unpolarised Fresnel reflectance: dielectric interfaces (real relative IOR)
 * and conductors (complex IOR eta + i k, one value per RGB channel). Header-only, pure.
 * No Schlick approximation: the smooth dielectric's lobe probabilities and the adjoint tests
 * rely on F being exact and symmetric under reversal of the light path.
 * Refs: Born & Wolf, Principles of Optics §1.5 (Fresnel equations); Walter et al. 2007 eq. 22. */
#ifndef RESTIRD_FRESNEL_H
#define RESTIRD_FRESNEL_H

#include <math.h>

#include "core/vec.h"

/* Reflectance of a dielectric interface for light arriving at cosine cos_i (measured on the
 * incident side, clamped to [0, 1]) with relative IOR eta = eta_transmitted / eta_incident.
 * Returns 1 under total internal reflection. */
static inline float fresnel_dielectric(float cos_i, float eta)
{
    float ci = fminf(fmaxf(cos_i, 0.0f), 1.0f);
    float sin2_t = (1.0f - ci * ci) / (eta * eta);  /* Snell: eta_i sin_i = eta_t sin_t */
    if (!(sin2_t < 1.0f)) return 1.0f;
    float ct = sqrtf(1.0f - sin2_t);
    float rs = (ci - eta * ct) / (ci + eta * ct);  /* s (perpendicular) amplitude */
    float rp = (eta * ci - ct) / (eta * ci + ct);  /* p (parallel) amplitude */
    return 0.5f * (rs * rs + rp * rp);
}

/* Transmittance 1 - F of a dielectric interface for a refraction pair: cos_i and cos_t are the
 * (non-negative) cosines on the incident and transmitted sides, eta_i and eta_t their indices.
 * With r = (a - b) / (a + b) the amplitude ratio, 1 - r^2 = 4 a b / (a + b)^2, so nothing
 * cancels when F -> 1 near total internal reflection (1 - fresnel_dielectric loses all digits
 * there), and swapping the two sides gives bit-identical results: the refraction adjoint and
 * the forward / reverse pdfs of a transmission rely on both. */
static inline float fresnel_dielectric_transmittance(float cos_i, float cos_t, float eta_i, float eta_t)
{
    float a = eta_i * cos_i, b = eta_t * cos_t;  /* s polarisation */
    float c = eta_t * cos_i, d = eta_i * cos_t;  /* p polarisation */
    float ab = a + b, cd = c + d;
    if (!(ab > 0.0f) || !(cd > 0.0f)) return 0.0f;
    return 2.0f * (a * b / (ab * ab) + c * d / (cd * cd));
}

/* Reflectance of a conductor with complex relative IOR eta + i k at incident cosine cos_i.
 * Writing the transmitted-side term sqrt((eta + i k)^2 - sin^2) = a + i b, the Fresnel equations
 * give R_s = (a^2 + b^2 - 2 a c + c^2) / (a^2 + b^2 + 2 a c + c^2) and
 * R_p = R_s (c^2 (a^2 + b^2) - 2 a c s^2 + s^4) / (c^2 (a^2 + b^2) + 2 a c s^2 + s^4).
 * Evaluated in double: for large k, a^2 + b^2 ~ k^2 and the difference giving a cancels
 * catastrophically in float. k = 0 reduces to fresnel_dielectric. */
static inline float fresnel_conductor(float cos_i, float eta, float k)
{
    double c = fmin(fmax((double)cos_i, 0.0), 1.0);
    double c2 = c * c, s2 = 1.0 - c2;
    double e2 = (double)eta * eta, k2 = (double)k * k;
    double t0 = e2 - k2 - s2;
    double a2b2 = sqrt(t0 * t0 + 4.0 * e2 * k2);  /* |(eta + i k)^2 - sin^2| = a^2 + b^2 */
    double a = sqrt(fmax(0.0, 0.5 * (a2b2 + t0)));
    double t1 = a2b2 + c2, t2 = 2.0 * a * c;
    if (!(t1 + t2 > 0.0)) return 1.0f;
    double rs = (t1 - t2) / (t1 + t2);
    double t3 = c2 * a2b2 + s2 * s2, t4 = t2 * s2;
    double rp = t3 + t4 > 0.0 ? rs * (t3 - t4) / (t3 + t4) : rs;
    return (float)(0.5 * (rs + rp));
}

static inline struct vec3 fresnel_conductor_rgb(float cos_i, struct vec3 eta, struct vec3 k)
{
    return vec3_make(fresnel_conductor(cos_i, eta.x, k.x), fresnel_conductor(cos_i, eta.y, k.y),
                     fresnel_conductor(cos_i, eta.z, k.z));
}

#endif
