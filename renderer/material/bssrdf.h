/* bssrdf.h — the translucent material's subsurface scattering: Burley's normalized diffusion
 * profile behind a smooth dielectric boundary, and BSSRDF importance sampling by probe rays.
 *
 *   S(x1, wo, x2, wi) = (1 - F(wo)) R(|x2 - x1|) (1 - F(wi)) / (c pi)   ([ReSTIR SSS eq. 2])
 *   R_k(r) = A_k p_k(r) / P_k(r_max,k) for r < r_max,k, else 0                      (eq. 3)
 *   p(r) = (e^{-r/d} + e^{-r/3d}) / (8 pi d r),  P(r) = 1 - e^{-r/d}/4 - 3 e^{-r/3d}/4  (eq. 4)
 *
 * per colour channel k, with d = l / s(A) (Christensen 2015: s = 1.9 - A + 3.5 (A - 0.8)^2 for
 * the diffuse surface albedo A and mean free path l), c = 1 - 2 FM1 (the first Fresnel moment)
 * so that (1 - F(wi)) cos / (c pi) integrates to 1 over the hemisphere, F the exact dielectric
 * reflectance for light arriving from outside (ior = inside / outside). p is a density per unit
 * area of the plane (its integral over the plane is 1), so on a flat, uniformly lit surface the
 * diffusion returns A (1 - F(wo)) of the incident irradiance / pi: energy is conserved.
 * The profile is cut at r_max = P^-1(0.999) and renormalised, so each channel's profile is zero
 * where its own sampling technique cannot reach.
 *
 * Sampling (King et al. 2013; [ReSTIR SSS §2.1, §3.1]): a technique is a projection axis of the
 * frame at x1 (normal 1/2, tangent 1/4, bitangent 1/4) and a channel (1/3 each); a radius r is
 * drawn by inverting P on [0, 0.999) and an angle uniformly, giving a point on the disk through
 * x1 perpendicular to the axis; a probe segment along the axis through it, inside the sphere of
 * radius r_max around x1, finds every intersection with the same shape (accel_intersect_shape_all,
 * ordered by distance from the probe's start, so the intersection index is deterministic).
 * Every such hit is a candidate entry point x2 (eq. 10). The density of hits of one technique at
 * x2 (area measure) is p(r_perp) / 0.999 |n2 . axis| for |x2 - x1| < r_max, r_perp the distance
 * from x1 in the disk plane; bssrdf_pdf_a is the sum over the 9 techniques weighted by their
 * probabilities (one-sample MIS, balance heuristic), so sum_j f(x2_j) / bssrdf_pdf_a(x2_j) over
 * all hits of one probe is an unbiased estimate of the integral of f over the surface covered.
 * Pure functions, thread-safe; the probe itself is traced by the caller (accel.h). */
#ifndef RESTIRD_BSSRDF_H
#define RESTIRD_BSSRDF_H

#include <stdbool.h>
#include <stdint.h>

#include "material/material.h"
#include "core/vec.h"

#define BSSRDF_CDF_MAX 0.999f  /* the profile and its sampling are cut at P(r_max) = 0.999 */
#define BSSRDF_MAX_HITS 16     /* probe hits kept per probe (more are dropped: documented bias) */
#define BSSRDF_AXES 3
#define BSSRDF_CHANNELS 3
#define BSSRDF_TECHNIQUES (BSSRDF_AXES * BSSRDF_CHANNELS)

/* Fills m->sss_d and m->sss_c from albedo, mfp and ior (scene loading calls it once). */
void bssrdf_prepare(struct material *m);
/* Christensen's scaling s(A) for the diffuse surface albedo A. */
float bssrdf_scaling(float albedo);
/* c = 1 - 2 FM1 for a boundary of relative index eta (inside / outside); numerical quadrature. */
float bssrdf_fresnel_norm(float eta);

/* The radial profile for one channel (eq. 4): density per unit area, CDF of the radius, its
 * inverse (u in [0, 1)), and r_max = P^-1(BSSRDF_CDF_MAX). */
float bssrdf_profile_pdf(float r, float d);
float bssrdf_profile_cdf(float r, float d);
float bssrdf_profile_sample(float u, float d);
float bssrdf_r_max(float d);

/* R(r) of the material per channel (truncated and renormalised, albedo included). */
struct vec3 bssrdf_profile(const struct material *m, float r);
/* Boundary transmission 1 - F at a cosine on the outside (0 for cos <= 0). */
float bssrdf_transmittance(const struct material *m, float cos_out);
/* The entry lobe (1 - F(wi)) / (c pi): the wi-dependent factor of S at x2 (without cos). */
float bssrdf_entry_eval(const struct material *m, float cos_in);

/* Technique selection: axis 0 = normal (1/2), 1 = tangent (1/4), 2 = bitangent (1/4); channel
 * uniform. One uniform number picks both (the axis by its first half/quarters, the channel by
 * the remainder rescaled). */
void bssrdf_pick_technique(float u, int *axis, int *channel);
float bssrdf_technique_prob(int axis, int channel);

/* The projection axis and the disk's two in-plane directions for an axis of frame f at x1. */
void bssrdf_axis_basis(const struct frame *f, int axis, struct vec3 *a, struct vec3 *du, struct vec3 *dv);

/* A probe: the segment org + t dir, t in [0, tmax], through the disk point. */
struct bssrdf_probe {
    struct vec3 org, dir;
    float tmax;
    float r;  /* sampled radius on the disk */
};
/* Builds the probe for technique (axis, channel) with radius number u_radius in [0, 1) and
 * angle number u_angle in [0, 1). False for a degenerate probe (radius at r_max). */
bool bssrdf_probe_make(const struct material *m, struct vec3 p1, const struct frame *f1, int axis, int channel,
                       float u_radius, float u_angle, struct bssrdf_probe *out);

/* Area density at x2 (geometric normal n2) of one technique's probe hits, and the 9-technique
 * MIS sum (the pdf of a candidate entry point, eq. 10's 1 / W). Zero where x2 is out of reach. */
float bssrdf_pdf_technique(const struct material *m, struct vec3 p1, const struct frame *f1, int axis, int channel,
                           struct vec3 p2, struct vec3 n2);
float bssrdf_pdf_a(const struct material *m, struct vec3 p1, const struct frame *f1, struct vec3 p2, struct vec3 n2);
/* The same sum, and in *pdf_t its term of technique (axis, channel): probability times pdf. */
float bssrdf_pdf_a_and(const struct material *m, struct vec3 p1, const struct frame *f1, struct vec3 p2, struct vec3 n2,
                       int axis, int channel, float *pdf_t);

/* Probabilistic inversion of the disk sampling for a fixed technique ([ReSTIR SSS Algorithm 4],
 * lines 2–9): the radius and angle numbers that put the disk point of (axis, channel) under
 * x2. False when x2 is out of that technique's reach. */
bool bssrdf_invert(const struct material *m, struct vec3 p1, const struct frame *f1, int axis, int channel,
                   struct vec3 p2, float *u_radius, float *u_angle);
/* Algorithm 4 line 1: picks the technique that produced x2 with probability proportional to
 * P(technique) p_technique(x2), using gamma in [0, 1). False when no technique reaches x2. */
bool bssrdf_invert_technique(const struct material *m, struct vec3 p1, const struct frame *f1, struct vec3 p2,
                             struct vec3 n2, float gamma, int *axis, int *channel);

#endif
