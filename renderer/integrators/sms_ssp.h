/* sms_ssp.h — specular manifold sampling with sample-space partitioning and per-frame priors
 * (method `sms_ssp`, [SMS-SSP §3-4]). It owns the same caustic paths as `sms` (sms.h) and only
 * changes how the estimate at a vertex x1 is made:
 *
 * Seed space (§3.1). u in [0,1)^2 is a direction from x1 inside a cone that holds the caster
 * (spheres: the cone of the sphere; meshes: the narrowest cone about the direction to the world
 * bounding box's centre that holds its 8 corners): the concentric map takes u to a point (x, y)
 * of the unit disk, and 1 − cos θ = (x² + y²)(1 − cos θmax), φ = atan2(y, x) (the whole sphere
 * when x1 is inside the box or the cone would be wider than a hemisphere). The map keeps areas
 * and tiles near-square, and it is continuous and invertible, so every walk iterate has a u:
 * the direction from x1 to its first vertex.
 *
 * Trust regions (§3.3). U is cut into N × N tiles; the trust region R(u) is the 3 × 3 tiles
 * around u's tile (periodic in both coordinates) and a walk that leaves it stops. A solution u*
 * is then reached only from its conditional space C(u*) = R(u*), so
 *     P'(x*) = P(C(u*)) · E_{u ~ p|C}[u reaches u* inside R(u)],
 * and W = (Bernoulli trials drawn from p restricted to C(u*)) / P(C(u*)) has E[W] = 1/P'.
 *
 * Prior (§4). Before a frame, for every B × B pixel block (B = 16), `prior_samples` unrestricted
 * walks from the shading points of random pixels of the block, each towards a random caster and
 * light point, mark the tiles of the solutions they find per (light shape, caster) pair. A
 * pixel's shading point is its receiver (sms_receiver_trace): the primary hit, or for a pixel
 * seen through glass or in a mirror the surface behind the delta vertices. Seeds
 * are then drawn from p(u) = α p_I(u) + (1 − α) p_U(u) (eq. 7), with the closed-form marginal
 * P(C(u*)) = α #(I ∩ C)/#I + (1 − α) 9/N² (eq. 8) and trials drawn inside I ∩ C with probability
 * α' = α #(I ∩ C)/#I / P(C) (eq. 9), else uniformly in C. A pair the prior has nothing for falls
 * back to α = 0 (plain partitioning), and so does a receiver far from the receivers whose walks
 * built the pair's tile set (outside their box grown by its largest extent): at a slab's far
 * edge, floor seen along the slab by total internal reflection moves far with a small step in
 * the pixel, and a tile set from one such receiver missed its neighbours' solutions, which then
 * carried the uniform share's weight. The prior serves only the vertex it was built at, the
 * pixel's receiver (its block's); every other vertex of the path, after a diffuse bounce or a
 * delta lobe other than the canonical one, samples with α = 0 too (pr = NULL), since a tile set
 * seen from another point marks arbitrary tiles.
 * Still views (K = prior_frames > 1). §4.1 builds the prior afresh each frame from 128 walks
 * per block (256 for its two-light scene). While the camera and the scene stay as they were,
 * the walks of the last K frames describe the same receivers, so the prior is the union of
 * their tile sets (and boxes) per pair: K times the walks at one frame's cost. On
 * refractive-slab the receivers seen along the slab by total internal reflection are rare
 * among a block's walks, and 128 walks often missed their tiles. Each frame's walks use their
 * own random stream, independent of the frame's samples, so any union leaves the estimate
 * unbiased. When the camera or the scene changes the kept walks are dropped and the prior is
 * the frame's own, as in the paper. The newest frame's pairs come first; a pair seen only in
 * older frames is left out when a block's SSP_PRIOR_ENTRIES are taken.
 * Casters and light points are picked as in `sms` (the prior's pair importance sampling of §4.2
 * is not used). Deterministic per seed, frame and pixel, whatever the number of workers. */
#ifndef RESTIRD_SMS_SSP_H
#define RESTIRD_SMS_SSP_H

#include <stddef.h>
#include <stdint.h>

#include "core/alias.h"
#include "scene/camera.h"
#include "integrators/sms.h"

#define SSP_MAX_TILES 32          /* N <= 32: a tile set is 1024 bits */
#define SSP_BLOCK 16              /* B: prior pixel blocks */
#define SSP_PRIOR_ENTRIES 8       /* (light shape, caster) pairs kept per block */
#define SSP_MAX_PRIOR_FRAMES 16u  /* prior_frames <= 16 */
#define SSP_PRIOR_WORKERS 64u     /* the prior pass's workers at most (per-worker counters) */

struct RESTIRD_STORED_IN_BYTES ssp_params {
    struct sms_params sms;        /* bernoulli_cap, max_iterations, caustics_only */
    uint32_t tiles;               /* N (default 16) */
    bool prior;                   /* build and use the per-frame prior (default true) */
    uint32_t prior_samples;       /* walks per block (default 128) */
    float alpha;                  /* mixing weight of the prior (default 0.8) */
    uint32_t prior_frames;        /* K: frames whose walks a still view's prior unites (default 4) */
};

struct ssp_entry {
    int32_t light_shape, caster;  /* -1: unused */
    uint32_t count;               /* tiles in the set */
    float lo[3], hi[3];           /* the box of the receivers whose walks found its solutions */
    uint64_t bits[SSP_MAX_TILES * SSP_MAX_TILES / 64];
};

/* Prior construction counters ([SMS-SSP Table 1], first columns). */
struct RESTIRD_STORED_IN_BYTES ssp_prior_counters {
    uint64_t samples, solutions, newton, dropped_pairs;
    double ms;
};

/* The per-session prior: one entry table per pixel block, the one seeds are drawn from; with
 * K = prior_frames > 1 also the tables of the last K frames' walks, whose union it is. */
struct ssp_prior {
    uint32_t blocks_x, blocks_y;
    uint32_t frames;              /* K */
    uint32_t kept, next;          /* frames of walks in `walks` since the view last changed; the next slot */
    struct ssp_entry *entries;    /* blocks_x * blocks_y * SSP_PRIOR_ENTRIES */
    struct ssp_entry *walks;      /* K > 1: K such tables, one per frame; else NULL */
};

struct ssp_params ssp_defaults(void);
bool ssp_params_valid(const struct ssp_params *p, struct err *err);
/* Bytes of a prior for prior_frames K: one table, plus K with K > 1. */
size_t ssp_prior_bytes(uint32_t width, uint32_t height, uint32_t frames);
bool ssp_prior_init(struct ssp_prior *pr, uint32_t width, uint32_t height, uint32_t frames, struct err *err);
void ssp_prior_destroy(struct ssp_prior *pr);

/* Builds this frame's prior (all entries are rewritten) with `threads` workers (0 = all cores,
 * at most SSP_PRIOR_WORKERS); the result does not depend on the count. `still`: the camera and
 * the scene are those of the previous frame built, so the walks kept from earlier frames still
 * describe the blocks' receivers; otherwise they are dropped. False only when parallel_run runs
 * out of memory. */
bool ssp_prior_build(struct ssp_prior *pr, const struct scene *scene, const struct sms_scene *ss,
                     const struct ssp_params *p, const struct camera *cam, uint64_t seed, uint32_t frame, bool still,
                     unsigned threads, struct ssp_prior_counters *c, struct ray_counters *rc, struct err *err);

/* One sample at x1 (the sampling half of ssp_estimate, consuming the random stream exactly as
 * it does; sms.h's struct sms_solution), with pixel (px, py)'s block of prior `pr` when x1 is that
 * pixel's receiver, or pr = NULL (plain partitioning), and
 *     W = trials / P(C(u*)) · C / p(x_n),   E[W | x̄*, x_n] = 1 / p(caster, x_n, x̄*)
 * (eqs. 2 and 8 with the caster and light choices). */
bool ssp_sample(const struct scene *scene, const struct sms_scene *ss, const struct ssp_params *p,
                const struct ssp_prior *pr, uint32_t px, uint32_t py, const struct surface *s, const struct material *m,
                struct vec3 wo, uint32_t max_chain, struct rng *rng, struct sms_solution *out, struct sms_counters *c,
                struct ray_counters *rc);

/* The estimate at x1 (as sms_estimate) for a path of pixel (px, py): value · W of ssp_sample. */
struct vec3 ssp_estimate(const struct scene *scene, const struct sms_scene *ss, const struct ssp_params *p,
                         const struct ssp_prior *pr, uint32_t px, uint32_t py, const struct surface *s,
                         const struct material *m, struct vec3 wo, uint32_t max_chain, struct rng *rng,
                         struct sms_counters *c, struct ray_counters *rc);

#endif
