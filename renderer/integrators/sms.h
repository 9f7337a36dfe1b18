/* sms.h — specular manifold sampling (Zeltner et al. 2020; [SMS-SSP §3.1]) as an estimator
 * inside the path tracer (method `sms`), and the split of light transport it needs so that
 * nothing is counted twice.
 *
 * Which paths SMS owns. A path is SMS-owned when, after some non-delta scattering vertex x1
 * (a vertex where path tracing samples a diffuse or glossy lobe and does next-event
 * estimation), it continues through exactly the chain of one caustic caster — `caustic_
 * interfaces` delta vertices on that one shape, each the caster's event (conductor:
 * reflection; dielectric: transmission) — and then hits an emitter surface. The emission such
 * a path carries is what sms_estimate() returns at x1, and what path tracing must then leave
 * out. Everything else (next-event estimation, every other emission, the environment) stays
 * with path tracing. Each emission event of a path is classified once, so
 *     pt = pt[subset caustic] + pt[subset rest]     exactly, sample by sample, and
 *     sms = pt[subset rest] + SMS                   with E[SMS] = E[pt[subset caustic]].
 * Only delta casters (roughness 0) form chains; a glossy caster is left to path tracing.
 *
 * The estimator at x1 (eq. 1 and eq. 12-13): pick a caster uniformly (1/C), a light point x_n
 * (area pdf p(x_n)), a seed u in [0,1)^2 mapped to a point of the caster's seed plane, trace
 * the seed path, walk it to a solution x̄*; the contribution is
 *     f(x1) |cos θ1| T(x̄*) G(x1 ↔ x_n) L_e · C / p(x_n) · W,
 * with T the specular throughput, G the generalized geometry term |dω1/dA(x_n)| and W the
 * number of Bernoulli trials (fresh seeds walked until one reaches the same solution again),
 * whose expectation is 1 / P(x̄*) (Booth 2007; [SMS-SSP eq. 2]). With a cap, a solution whose
 * trials exceed it contributes 0 (biased: energy lost, counted); cap 0 = uncapped.
 *
 * The seed map: u picks a point on the surface of the caster's world bounding box (a face by
 * area, then the point on it; spheres: the sphere itself). A ray from x1 towards that point is
 * the seed path's first segment. Every ray from x1 that meets the caster crosses its bounding
 * box's surface, so every first vertex x2 is some seed's (a seed plane through the box missed
 * paths entering through the upper part of a slab's side walls: −2.6 % of the caustic on
 * refractive-slab). The map is continuous within a face, and its pdf never enters the
 * estimate: only P(x̄*) does, through W. */
#ifndef RESTIRD_SMS_H
#define RESTIRD_SMS_H

#include <stdint.h>

#include "core/alias.h"
#include "scene/light_sampler.h"
#include "scene/scene.h"
#include "integrators/manifold.h"
#include "material/material.h"
#include "core/rng.h"
#include "scene/surface.h"

struct scene;

#define SMS_MAX_CASTERS 64
/* "Uncapped" still stops somewhere: a solution needing this many trials is dropped and counted
 * (sms_counters.capped); the tests check that it never happens. */
#define SMS_HARD_TRIAL_LIMIT (1u << 20)

/* Which part of the light transport a path-traced image contains (see above). */
enum pt_subset { PT_SUBSET_ALL, PT_SUBSET_CAUSTIC, PT_SUBSET_REST };

struct RESTIRD_STORED_IN_BYTES sms_params {
    uint32_t bernoulli_cap;    /* max Bernoulli trials per solution; 0 = uncapped (default 128,
                                  as [SMS-SSP §6]) */
    uint32_t max_iterations;   /* Newton steps per walk (default 20) */
    bool caustics_only;        /* render only the SMS estimate (no path-traced rest) */
};

/* Table 1 of [SMS-SSP] (manifold sampling columns). */
struct RESTIRD_STORED_IN_BYTES sms_counters {
    uint64_t samples;          /* SMS estimates attempted (one per x1) */
    uint64_t solutions;        /* of those, a valid solution with a non-zero contribution */
    uint64_t newton_sample;    /* Newton steps of the sampling walks */
    uint64_t trials;           /* Bernoulli trials (walks) of the solutions */
    uint64_t newton_trials;    /* Newton steps of those trials */
    uint64_t capped;           /* solutions dropped at the Bernoulli cap (energy lost) */
    uint64_t with_prior;       /* ssp_sample: samples seeded from the prior (α > 0); the others fell back */
    double sample_ms;          /* time in sms_estimate (summed over threads) */
};

/* *sum += c: a pass counts into a job-local copy and adds it once per job, since per-worker slots
 * side by side share cache lines (see restir_counters_add). */
static inline void sms_counters_add(struct sms_counters *sum, const struct sms_counters *c)
{
    sum->samples += c->samples;
    sum->solutions += c->solutions;
    sum->newton_sample += c->newton_sample;
    sum->trials += c->trials;
    sum->newton_trials += c->newton_trials;
    sum->capped += c->capped;
    sum->with_prior += c->with_prior;
    sum->sample_ms += c->sample_ms;
}

struct sms_caster {
    struct manifold_chain chain;
    bool sphere;
    struct vec3 lo, hi;        /* world bounding box (meshes) */
    struct vec3 centre;        /* spheres */
    float radius;
    float face_cdf[6];         /* meshes: the box faces (-x, +x, -y, +y, -z, +z) by area */
};

/* The casters of a committed scene under its current transforms; no allocation. */
struct sms_scene {
    uint32_t count;
    struct sms_caster casters[SMS_MAX_CASTERS];
};

struct sms_params sms_defaults(void);
bool sms_params_valid(const struct sms_params *p, struct err *err);

/* The chain of shape `shape` when it is a delta caster SMS handles; false otherwise. */
bool sms_chain_of(const struct scene *scene, uint32_t shape, struct manifold_chain *out);
/* Collects the casters (at most SMS_MAX_CASTERS; ERR_LIMIT beyond). */
bool sms_scene_init(const struct scene *scene, struct sms_scene *out, struct err *err);

/* The caster (its index) and the light point of one manifold sample, from uc (the caster,
 * uniformly) and ul, l1, l2 (the light): false when the caster's chain is longer than max_chain or no finite light
 * point with a positive density was sampled. ss holds at least one caster. */
static inline bool sms_pick(const struct scene *scene, const struct sms_scene *ss, float uc, float ul, float l1,
                            float l2, uint32_t max_chain, uint32_t *ci, struct light_sample *ls)
{
    *ci = (uint32_t)(uc * (float)ss->count);
    if (*ci >= ss->count) *ci = ss->count - 1;
    return ss->casters[*ci].chain.length <= max_chain && light_sampler_sample(scene->lights, ul, l1, l2, ls) &&
           !ls->is_env && ls->pdf_a > 0.0f;
}
/* The seed target for u in [0,1)^2 on caster c. */
struct vec3 sms_seed_point(const struct sms_caster *c, float u1, float u2);

/* Path tracing's side of the split: the chain state after the path's latest non-delta vertex. */
struct sms_track {
    bool open;                 /* a non-delta vertex, then only matching chain vertices so far */
    int32_t shape;             /* the caster of the chain so far (-1: none yet) */
    uint32_t length;
};
static inline struct sms_track sms_track_start(void) { return (struct sms_track){false, -1, 0}; }
/* After scattering at surface s through a lobe with `flags`. */
void sms_track_scatter(const struct scene *scene, struct sms_track *t, const struct surface *s, unsigned flags);
/* At an emitter hit: does the emission belong to SMS? */
bool sms_track_owned(const struct scene *scene, const struct sms_track *t);

/* f(x1) |cos θ1| T G L_e of a checked solution (eq. 13 with the generalized geometry term);
 * zero when x1's side rules (those of next-event estimation) or any factor rule it out. */
struct vec3 sms_solution_value(const struct scene *scene, const struct manifold_chain *chain,
                               const struct manifold_ends *e, const struct manifold_vertex *v, const struct surface *s,
                               const struct material *m, struct vec3 wo, const struct material *light);
double sms_now_ms(void);

/* One Bernoulli trial: a fresh seed drawn from rng, walked to a solution in w (false: none). */
typedef bool sms_trial_fn(const void *ctx, struct rng *rng, struct manifold_vertex *w, struct sms_counters *c,
                          struct ray_counters *rc);
/* Bernoulli trials (Booth 2007; [SMS-SSP §3.1]): how many fresh seeds, each drawn and walked by
 * `trial`, it takes until one reaches the solution v (chain length n, from x1) again — the same
 * solution within 1e-4 of |x1 - x2| — whose expectation is 1 / P(v) (the seed distribution's).
 * 0 when p->bernoulli_cap trials (0: SMS_HARD_TRIAL_LIMIT) do not find it: that solution's
 * energy is lost. Counts the trials, and the solution as found or capped. Inline, so that the
 * sampler's trial is a direct call. */
static inline uint32_t sms_bernoulli(const struct sms_params *p, const struct manifold_vertex *v, uint32_t n,
                                     struct vec3 x1, sms_trial_fn *trial, const void *ctx, struct rng *rng,
                                     struct sms_counters *c, struct ray_counters *rc)
{
    float tol = 1e-4f * vec3_length(vec3_sub(v[0].p, x1));
    uint32_t limit = p->bernoulli_cap ? p->bernoulli_cap : SMS_HARD_TRIAL_LIMIT;
    struct manifold_vertex w[MANIFOLD_MAX_CHAIN];
    uint32_t trials = 0;
    bool found = false;
    while (trials < limit) {
        trials++;
        if (trial(ctx, rng, w, c, rc) && manifold_same(w, v, n, tol)) {
            found = true;
            break;
        }
    }
    c->trials += trials;
    if (!found) {
        c->capped++;
        return 0;
    }
    c->solutions++;
    return trials;
}

/* restir_sms's receivers (restir_sms.h): the first diffuse or glossy vertex of a camera path
 * whose delta vertices before it (at most SMS_RECEIVER_MAX_PREFIX) all took their material's
 * canonical lobe — the one material_sample picks for u_lobe -> 1: refraction through a smooth
 * dielectric (reflection under total internal reflection), a smooth conductor's reflection. The
 * path tracer leaves the SMS estimate at exactly such a vertex to restir_sms. */
#define SMS_RECEIVER_MAX_PREFIX 4
/* The canonical lobe at a delta vertex (false when the material has none: not delta, or no lobe
 * can be sampled). */
bool sms_canonical_lobe(const struct material *m, struct vec3 wo, struct bsdf_sample *out);
/* Follows a camera ray from its first hit (`primary`, of the ray org + t dir) through canonical
 * delta lobes to the receiver, stepping exactly as path tracing does (the same hits, scattering
 * and ray offsets as reference_pt.c), so that every method agrees on which vertex is the
 * receiver. Out: the receiver's hit and surface, the direction back along the last segment (wo),
 * the prefix's expected throughput T (the product of f |cos| over its delta vertices) and its
 * depth (delta vertices before it). False when the path ends before one: it escapes, a lobe
 * cannot be taken, it meets a translucent surface, or it would need more than max_depth or
 * SMS_RECEIVER_MAX_PREFIX delta vertices. */
bool sms_receiver_trace(const struct scene *scene, uint32_t max_depth, struct vec3 org, struct vec3 dir,
                        const struct hit *primary, struct hit *hit, struct surface *s, struct vec3 *wo,
                        struct vec3 *T, uint32_t *depth, struct ray_counters *rc);

/* One SMS sample at x1, as an estimator's sample rather than its estimate: the caster (index into
 * the sms_scene), the light point, the checked solution, its value (sms_solution_value) and its
 * unbiased contribution weight W (an estimate of 1 / p(caster, x_n, x̄*) with the Bernoulli
 * trials; the estimate is value · W). False (W = 0) when no solution was found or the Bernoulli
 * cap was reached. */
struct sms_solution {
    uint32_t caster;
    struct light_sample light;
    struct manifold_vertex v[MANIFOLD_MAX_CHAIN];
    struct vec3 value;
    double W;
};
/* The start both manifold samplers (sms_sample, ssp_sample) share: the caster (ci, cs) and light
 * point (ls, which carries the light's material) sms_pick chose, the walk's two ends (x1 the
 * shading point, xe the light point) and the sample's clock (its time goes to
 * sms_counters.sample_ms). */
struct sms_draw {
    uint32_t ci;
    const struct sms_caster *cs;
    struct light_sample ls;
    struct manifold_ends e;
    double t0;
};
/* Counts the sample, starts its clock and picks its caster and light point from uc, ul, l1, l2
 * (sms_pick); false when nothing was picked (the sample has no weight). ss holds a caster. */
bool sms_draw_begin(const struct scene *scene, const struct sms_scene *ss, float uc, float ul, float l1, float l2,
                    uint32_t max_chain, const struct surface *s, struct sms_counters *c, struct sms_draw *d);
/* A solution's caster, light point and value, from the draw that found it. */
static inline void sms_draw_keep(const struct sms_draw *d, struct vec3 value, struct sms_solution *out)
{
    out->caster = d->ci;
    out->light = d->ls;
    out->value = value;
}
/* The sample's end: its time goes to sample_ms; true when it has a weight. */
static inline bool sms_draw_end(const struct sms_draw *d, const struct sms_solution *out, struct sms_counters *c)
{
    c->sample_ms += sms_now_ms() - d->t0;
    return out->W > 0.0;
}

/* sms_estimate's sampling half (same random numbers): W = trials · C / p(x_n). */
bool sms_sample(const struct scene *scene, const struct sms_scene *ss, const struct sms_params *p,
                const struct surface *s, const struct material *m, struct vec3 wo, uint32_t max_chain,
                struct rng *rng, struct sms_solution *out, struct sms_counters *c, struct ray_counters *rc);

/* The SMS estimate at x1 (surface s, material m, wo in s's local frame), for chains that end
 * within `max_chain` vertices (path tracing's depth limit); radiance towards wo, without the
 * path throughput up to x1. */
struct vec3 sms_estimate(const struct scene *scene, const struct sms_scene *ss, const struct sms_params *p,
                         const struct surface *s, const struct material *m, struct vec3 wo, uint32_t max_chain,
                         struct rng *rng, struct sms_counters *c, struct ray_counters *rc);

#endif
