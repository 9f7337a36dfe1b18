/* reference_pt.h — the ground-truth path tracer (method `pt`): unidirectional path tracing with
 * next-event estimation and BSDF sampling combined by the power heuristic, Russian roulette,
 * and a box pixel filter (one uniformly jittered position per sample). Every other method is
 * tested against it, so it favours plain, checkable code over tricks. */
#ifndef RESTIRD_REFERENCE_PT_H
#define RESTIRD_REFERENCE_PT_H

#include <stdint.h>

#include "image/image.h"
#include "core/parallel.h"
#include "scene/scene.h"
#include "integrators/sms.h"
#include "integrators/frame.h"
#include "integrators/sms_ssp.h"

/* The random numbers of pt's paths. PT_SAMPLER_RANDOM: a PCG stream per sample. PT_SAMPLER_SOBOL:
 * the pixel position and, at the first PT_SOBOL_BOUNCES vertices, the light sample (pick and
 * point) and the BSDF sample (lobe and direction) take Owen-scrambled Sobol' dimensions
 * (core/sobol.h), one padded dimension each, with sample index frame * spp + sample, so a pixel's
 * samples over a session's frames are one stratified sequence; everything else (deeper vertices,
 * Russian roulette, subsurface probes, SMS) keeps the PCG stream. Either is unbiased; Sobol' stratifies
 * the first bounces, where most of the variance of direct and one-bounce light is. */
enum pt_sampler { PT_SAMPLER_RANDOM, PT_SAMPLER_SOBOL };
#define PT_SOBOL_BOUNCES 2
/* How next-event estimation samples a point on an emissive triangle: uniformly by area (every
 * emitter, light_sampler_sample), or uniformly in the solid angle the triangle subtends where the
 * shading point sees it close by (light_sampler_sample_from; spheres and the environment as
 * with area). Both are unbiased; solid angle has less variance near large lights and costs
 * more per sample (docs/methods.md). */
enum pt_light_sampling { PT_LIGHT_SAMPLING_AREA, PT_LIGHT_SAMPLING_SOLID_ANGLE };

struct pt_params {
    uint32_t width, height;
    uint32_t spp;          /* samples per pixel, >= 1 */
    uint32_t max_depth;    /* maximum number of scattering events (bounces); 0 = emitters only */
    uint32_t rr_depth;     /* Russian roulette starts after this many bounces */
    uint64_t seed;
    uint32_t frame;        /* decorrelates frames of one session */
    bool nee;              /* next-event estimation + MIS (default); false = BSDF sampling only,
                              a second unbiased estimator that tests the first one's MIS weights */
    enum pt_sampler sampler;  /* where a path's random numbers come from (reference_pt_defaults: random, as
                                 the other methods' paths; method pt's default is Sobol', pt_method_defaults) */
    enum pt_light_sampling light_sampling;  /* default PT_LIGHT_SAMPLING_AREA */
    unsigned threads;      /* 0 = all cores */
    const struct camera_desc *camera;  /* NULL = the scene's camera */
    /* Optional crop (inclusive-exclusive pixel window); all zero = the whole image. */
    uint32_t crop_x0, crop_y0, crop_x1, crop_y1;
    /* Which light transport the image holds (sms.h: PT_SUBSET_CAUSTIC = exactly the paths
     * specular manifold sampling owns, the filtered reference of `sms`; PT_SUBSET_REST = the
     * others). Default PT_SUBSET_ALL. */
    enum pt_subset subset;
    /* Non-NULL: method `sms` — the PT_SUBSET_REST paths plus an SMS estimate at every non-delta
     * vertex (only the SMS estimates when sms->caustics_only). */
    const struct sms_params *sms;
    /* Non-NULL (with sms = &ssp->sms): method `sms_ssp` — the SMS estimates use sample-space
     * partitioning and this frame's prior (built by the caller). */
    const struct ssp_params *ssp;
    const struct ssp_prior *ssp_prior;
};

/* Defaults: 16 spp, max_depth 64, rr_depth 3, NEE on (area sampling), random sampler, seed 0, all cores,
 * whole image. */
struct pt_params reference_pt_defaults(uint32_t width, uint32_t height);
/* The paths a ReSTIR method traces for the light its reservoirs do not carry, one per pixel from
 * the G-buffer's primary ray: the defaults with the method's depths, NEE on. */
struct pt_params reference_pt_rest(uint32_t width, uint32_t height, uint32_t max_depth, uint32_t rr_depth);

/* Renders into `out` (initialised here to width x height; pixels outside a crop stay 0). */
bool reference_pt_render(const struct scene *scene, const struct pt_params *params, struct image *out,
                         struct render_stats *stats, parallel_progress_fn *progress, void *progress_ctx,
                         struct err *err);

/* The same into an image the caller allocated at width x height (its pixels are overwritten;
 * outside a crop they become 0). Allocates nothing: for renderers that keep their frame
 * buffer across frames. ERR_INVALID when the image has another size. */
bool reference_pt_render_into(const struct scene *scene, const struct pt_params *params, struct image *out,
                              struct render_stats *stats, parallel_progress_fn *progress, void *progress_ctx,
                              struct err *err);

struct rng;
struct ray_counters;
/* Radiance along one camera ray (org, unit dir) whose first hit the caller already has
 * (`primary`, as accel_intersect reports it; NULL when the ray escaped), as `pt` estimates it,
 * from the caller's random stream (restir_sss's pt rest). Thread-safe, allocation-free. */
struct hit;
struct vec3 reference_pt_radiance(const struct scene *scene, const struct pt_params *params, struct vec3 org,
                                  struct vec3 dir, const struct hit *primary, struct rng *rng,
                                  struct ray_counters *rc);

/* Radiance arriving at a subsurface entry point along the ray (org, unit dir) that leaves it,
 * whose first hit the caller already has (`first`; NULL when the ray escaped), as `pt` estimates
 * the rest of its path after subsurface scattering at the primary hit: the vertex found is the
 * path's second (depth 1, so params' max_depth and rr_depth count as in pt, and a translucent
 * surface there scatters by its BSDF), and its emission (or the environment) is left out, since
 * next-event estimation at the entry point carries that light. restir_sss's indirect samples.
 * Thread-safe, allocation-free. */
struct vec3 reference_pt_radiance_after_sss(const struct scene *scene, const struct pt_params *params,
                                            struct vec3 org, struct vec3 dir, const struct hit *first,
                                            struct rng *rng, struct ray_counters *rc);

/* Radiance along one camera ray whose first hit the caller already has (`primary`, as above) as
 * `sms` / `sms_ssp` estimate it (params->sms set; params->ssp and ssp_prior for sample-space
 * partitioning), except that no SMS estimate is made at the restir_sms receiver (sms.h: the
 * first diffuse or glossy vertex after delta vertices that all took their canonical lobe):
 * restir_sms adds the caustic paths that start there from its reservoirs, weighted by the delta
 * prefix's expected throughput. The other SMS estimates draw from sms_rng; (px, py) picks the
 * prior block. */
struct vec3 reference_pt_radiance_sms(const struct scene *scene, const struct pt_params *params,
                                      const struct sms_scene *ss, uint32_t px, uint32_t py, struct vec3 org,
                                      struct vec3 dir, const struct hit *primary, struct rng *rng,
                                      struct rng *sms_rng, struct sms_counters *sc, struct ray_counters *rc);

/* References rendered in passes (so that a long render reports progress and can stop between
 * passes): pass i renders `params` with frame REFERENCE_PT_PASS_FRAME0 + i — a seed stream no
 * frame of a session reaches, so the reference's noise is independent of the frames compared
 * with it — into `scratch` and adds it into `sum` (both width x height; the caller zeroes sum
 * first and divides by the pass count at the end, e.g. with image_scale). Allocates nothing. */
#define REFERENCE_PT_PASS_FRAME0 0x80000000u
bool reference_pt_add_pass(const struct scene *scene, const struct pt_params *params, uint32_t pass, struct image *sum,
                           struct image *scratch, struct render_stats *stats, struct err *err);

#endif
