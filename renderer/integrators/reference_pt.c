/* reference_pt.c — method `pt` (see reference_pt.h).
 * Estimator per path vertex (Veach 1997 §9.2, one-sample-each MIS with the power heuristic):
 *   emission reached by BSDF sampling, weighted w_bsdf = p_bsdf^2 / (p_bsdf^2 + p_light^2),
 *   plus NEE towards one light sample, weighted w_light = p_light^2 / (p_light^2 + p_bsdf^2),
 * with all pdfs in solid angle at the shading point (area pdfs converted by dist^2 / |cos|).
 * Russian roulette survival q = min(0.95, max(throughput)) after rr_depth bounces keeps the
 * estimator unbiased. Random numbers come from a PCG stream per (seed, frame, pixel, sample),
 * or with the Sobol' sampler (reference_pt.h, PT_SAMPLER_SOBOL) partly from Owen-scrambled Sobol'
 * dimensions keyed by (seed, pixel), so images do not depend on the thread count. */
#include "integrators/reference_pt.h"

#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "scene/accel.h"
#include "material/bssrdf.h"
#include "scene/camera.h"
#include "scene/light_sampler.h"
#include "material/material.h"
#include "core/rng.h"
#include "core/sampling.h"
#include "core/sobol.h"
#include "scene/surface.h"

#define PT_TILE 16
/* rng_pixel_make's last word for the pixel's sample streams (rng.h). */
#define PT_SAMPLE_STREAM 0x7074ull
#define PT_MAX_WORKERS 1024

/* The Sobol' sampler's padded dimensions (core/sobol.h): the pixel position, then at each of the
 * first PT_SOBOL_BOUNCES vertices the light sample's point, the BSDF sample's direction and the
 * pair (light pick, lobe choice). One dimension per decision, so no two decisions share a shuffle
 * (which would correlate them); the pick and the lobe choice share one as its two coordinates,
 * each stratified on its own and jointly. Russian roulette has none: it starts at rr_depth 3 by
 * default, past the Sobol' vertices, and a session that starts it earlier draws it from the PCG
 * stream. Seven dimensions fit one group of eight lanes of sobol_batch_draw; with roulette's two
 * they took two. */
enum { PT_DIM_PIXEL, PT_DIM_FIRST_VERTEX };
enum { PT_DIM_LIGHT_POINT, PT_DIM_BSDF_DIRECTION, PT_DIM_CHOICES, PT_DIMS_PER_VERTEX };
#define PT_SOBOL_DIMS (PT_DIM_FIRST_VERTEX + PT_SOBOL_BOUNCES * PT_DIMS_PER_VERTEX)
/* The constant in pt_sobol_epoch_key, which keeps the Sobol' seeds apart from other streams. */
#define PT_SOBOL_STREAM 0x736f626full
/* A pixel's Sobol' index is the sample's index in the session, frame * spp + sample, in epochs of
 * 2^31 samples: each epoch (the bits above) gets its own randomisation. A session's frame f at
 * spp s is in epoch f * s / 2^31, a reference pass (frames from REFERENCE_PT_PASS_FRAME0 = 2^31
 * on, at its own spp r per pass) in epoch r or above: the two share a randomisation (and their
 * samples would be correlated) only once f * s reaches 2^31 * r, some 2^31 samples per pixel of
 * the session. */
#define PT_SOBOL_INDEX_BITS 31

/* One sample's Sobol' numbers and the seeds they come from: the seeds of every dimension depend on
 * (session seed, pixel, epoch) only, so they are derived once per pixel, not per sample; a
 * sample's dimensions are then drawn all at once (eight lanes at a time with AVX2), before its
 * path needs them, and a pixel's samples together (sobol_batch_draw_run, below). With AVX2,
 * drawing a dimension that the path does not reach costs less than deciding lazily would: a lane
 * of a batch costs about a seventh of a sobol_2d (docs/benchmarks.md, "pt's Sobol' sampler").
 * Without it each lane is a sobol_2d, and a path that ends at its first vertex pays for seven
 * instead of about four (not measured on such a processor). */
#define PT_SOBOL_LANES ((PT_SOBOL_DIMS + SOBOL_BATCH_LANES - 1) / SOBOL_BATCH_LANES * SOBOL_BATCH_LANES)
_Static_assert(PT_SOBOL_LANES <= SOBOL_BATCH_DIMS, "one sobol_batch holds every dimension of a sample");
/* One sample's numbers, lane d for dimension d. */
struct pt_sobol {
    float u0[PT_SOBOL_LANES], u1[PT_SOBOL_LANES];
};
/* A pixel's seeds, and the numbers of up to PT_SOBOL_RUN of its samples, drawn by one
 * sobol_batch_draw_run before the first of them is traced: drawn sample by sample, each draw paid
 * again for its call, the processor check, the vector constants and its index's bit reversal,
 * some 45 instructions a sample (about 10 a ray on the diffuse Cornell box). 1 KiB of stack. */
#define PT_SOBOL_RUN 16
struct pt_sobol_pixel {
    struct sobol_batch seeds;
    struct pt_sobol run[PT_SOBOL_RUN];
};

/* The hash of (session seed, epoch) that every pixel's Sobol' seed starts from: a tile derives it
 * once for its first sample's epoch, so that a pixel adds only one SplitMix64 of its own. */
static inline uint64_t pt_sobol_epoch_key(uint64_t seed, uint64_t epoch)
{
    return rng_mix64(seed ^ rng_mix64(epoch ^ rng_mix64(PT_SOBOL_STREAM)));
}

static void pt_sobol_pixel(struct pt_sobol_pixel *q, uint64_t epoch_key, uint64_t pixel)
{
    sobol_batch_seed(&q->seeds, rng_mix64(epoch_key ^ pixel), PT_SOBOL_LANES);
}

struct pt_job {
    const struct scene *scene;
    const struct sms_scene *sms_scene;   /* method sms: the casters */
    const struct pt_params *params;
    struct camera camera;
    struct image *out;
    uint32_t tiles_x;
    struct render_stats worker_stats[PT_MAX_WORKERS];
};

struct pt_params reference_pt_defaults(uint32_t width, uint32_t height)
{
    return (struct pt_params){.width = width, .height = height, .spp = 16, .max_depth = 64, .rr_depth = 3, .nee = true};
}

struct pt_params reference_pt_rest(uint32_t width, uint32_t height, uint32_t max_depth, uint32_t rr_depth)
{
    struct pt_params p = reference_pt_defaults(width, height);
    p.max_depth = max_depth;
    p.rr_depth = rr_depth;
    p.nee = true;
    return p;
}

/* The emitter normal on the side that direction `wi` (towards the emitter) arrives from. */
static inline struct vec3 pt_emitter_side(struct vec3 n, struct vec3 wi)
{
    return vec3_dot(wi, n) < 0.0f ? n : vec3_neg(n);
}

/* A light sample as seen from p: the direction towards it, the radiance it sends to p and the
 * solid-angle pdf of having sampled it, from its area pdf (a sample of light_sampler_sample_from
 * gives back its pdf_w to within float rounding: its pdf_a is pdf_w converted from p). False
 * when it cannot contribute (zero distance or pdf). */
static bool pt_light_toward(const struct scene *scene, const struct light_sample *ls, struct vec3 p, struct vec3 *wi_world,
                            struct vec3 *Le, float *pdf_light_w)
{
    if (ls->is_env) {
        *wi_world = ls->dir;
        *pdf_light_w = ls->pdf_w;
        *Le = scene->env_radiance;
        return *pdf_light_w > 0.0f;
    }
    struct vec3 d = vec3_sub(ls->p, p);
    float d2 = vec3_length2(d);
    if (!(d2 > 0.0f)) return false;
    *wi_world = vec3_scale(d, 1.0f / sqrtf(d2));
    float cos_l = -vec3_dot(*wi_world, ls->n);
    *Le = light_sampler_emitted(ls->material, cos_l);
    *pdf_light_w = sampling_area_to_solid_angle(ls->pdf_a, d2, cos_l);
    return *pdf_light_w > 0.0f;
}

/* One light sample for next-event estimation at p, as params->light_sampling asks. */
static inline bool pt_sample_light(const struct light_sampler *lights, bool solid_angle, struct vec3 p, float ul,
                                   float u1, float u2, struct light_sample *ls)
{
    return solid_angle ? light_sampler_sample_from(lights, p, ul, u1, u2, ls) : light_sampler_sample(lights, ul, u1, u2, ls);
}

/* Subsurface scattering at the primary hit x1 on a translucent material ([ReSTIR SSS §2.1, §3.1]):
 * one probe of BSSRDF importance sampling; every hit x2_j on the same shape is an entry point,
 * each weighted by S / bssrdf_pdf_a (eq. 10: all intersections, not one picked at random), and
 * each gets next-event estimation towards one light sample through the entry lobe
 * (1 - F(wi)) / (c pi). Direct light at the entry points is counted by NEE alone (no MIS): the
 * continuation below skips emission at its first hit (*skip_emission). Without NEE
 * (params->nee false) that emission is counted instead, with weight 1 — a second unbiased
 * estimator of the same integral. The path continues from one entry point picked uniformly
 * (weight N, the number of hits) with a cosine-sampled direction. Returns false when the path
 * ends; otherwise updates beta, the next ray and the vertex it leaves from. With sss_direct false
 * (a split whose rest is someone else's: sms's caustics_only) the NEE at the entry points is left
 * out and so is the continuation's emission that would duplicate it. Out of line: at most once per path, and inlined
 * into the flattened path loop (pt_radiance) it would only crowd it. */
__attribute__((noinline, cold)) static bool
pt_sss_primary(const struct scene *scene, const struct pt_params *params, const struct material *m,
               const struct surface *s, struct vec3 wo_world, struct vec3 *beta, struct vec3 *L, struct rng *rng,
               struct ray_counters *rc, struct vec3 *org, struct vec3 *dir, struct vec3 *prev_p, bool *skip_emission,
               bool sss_direct)
{
    const struct light_sampler *lights = scene->lights;
    const bool nee = params->nee && light_sampler_count(lights) > 0;
    float cos_o = vec3_dot(wo_world, s->ns);
    /* Light leaves through the front (outside) only. */
    float ut = rng_next_float(rng), ur = rng_next_float(rng), ua = rng_next_float(rng), upick = rng_next_float(rng);
    if (!(cos_o > 0.0f) || !(vec3_dot(wo_world, s->ng) > 0.0f)) return false;
    int axis, channel;
    bssrdf_pick_technique(ut, &axis, &channel);
    struct bssrdf_probe probe;
    if (!bssrdf_probe_make(m, s->p, &s->frame, axis, channel, ur, ua, &probe)) return false;
    struct hit hits[BSSRDF_MAX_HITS];
    uint32_t n = accel_intersect_shape_all(scene->accel, s->shape, probe.org, probe.dir, 0.0f, probe.tmax, hits,
                                           BSSRDF_MAX_HITS, rc);
    if (n == 0) return false;
    uint32_t pick = (uint32_t)(upick * (float)n);
    if (pick >= n) pick = n - 1;
    struct vec3 beta_o = vec3_scale(*beta, bssrdf_transmittance(m, cos_o));
    struct vec3 beta_pick = vec3_splat(0.0f);
    struct surface s_pick = *s;  /* overwritten by the picked hit; read only when one was picked */
    for (uint32_t j = 0; j < n; j++) {
        struct surface s2;
        surface_from_hit(scene, &hits[j], probe.org, probe.dir, &s2);
        float pdf = bssrdf_pdf_a(m, s->p, &s->frame, s2.p, s2.ng);
        if (!(pdf > 0.0f)) continue;
        struct vec3 w = vec3_scale(vec3_mul(beta_o, bssrdf_profile(m, vec3_length(vec3_sub(s2.p, s->p)))), 1.0f / pdf);
        if (j == pick) {
            beta_pick = w;
            s_pick = s2;
        }
        if (!nee || !sss_direct) continue;
        float ul = rng_next_float(rng), u1 = rng_next_float(rng), u2 = rng_next_float(rng);
        struct light_sample ls;
        const bool solid_angle = params->light_sampling == PT_LIGHT_SAMPLING_SOLID_ANGLE;
        if (!pt_sample_light(lights, solid_angle, s2.p, ul, u1, u2, &ls)) continue;
        struct vec3 wi_world, Le;
        float pdf_light_w;
        if (!pt_light_toward(scene, &ls, s2.p, &wi_world, &Le, &pdf_light_w)) continue;
        float cos_i = vec3_dot(wi_world, s2.ns);
        if (vec3_is_zero(Le) || !(cos_i > 0.0f) || !(vec3_dot(wi_world, s2.ng) > 0.0f)) continue;
        /* Offset end to offset end, as next-event estimation in pt_radiance. */
        struct vec3 sorg = surface_offset_along(s2.p, s2.ng), sdir = wi_world;
        float tmax = INFINITY;
        if (!ls.is_env) {
            struct vec3 seg = vec3_sub(surface_offset_along(ls.p, pt_emitter_side(ls.n, wi_world)), sorg);
            float len = vec3_length(seg);
            if (!(len > 0.0f)) continue;
            sdir = vec3_scale(seg, 1.0f / len);
            tmax = len * (1.0f - 1e-4f);
        }
        if (accel_occluded(scene->accel, sorg, sdir, 0.0f, tmax, rc)) continue;
        float f = bssrdf_entry_eval(m, cos_i);
        *L = vec3_add(*L, vec3_mul(w, vec3_scale(Le, f * cos_i / pdf_light_w)));
    }
    if (vec3_is_zero(beta_pick)) return false;
    /* Continue from the picked entry point: cosine sampling of the entry lobe, whose weight
     * f cos / pdf is (1 - F(wi)) / c. */
    float u1 = rng_next_float(rng), u2 = rng_next_float(rng);
    struct vec3 wi = sampling_cosine_hemisphere(u1, u2);
    if (!(wi.z > 0.0f)) return false;
    struct vec3 wi_world = frame_to_world(&s_pick.frame, wi);
    if (!(vec3_dot(wi_world, s_pick.ng) > 0.0f)) return false;
    *beta = vec3_scale(beta_pick, (float)n * bssrdf_entry_eval(m, wi.z) * PI_F);
    *org = surface_offset_along(s_pick.p, s_pick.ng);
    *dir = wi_world;
    *prev_p = s_pick.p;
    *skip_emission = nee;
    return true;
}

/* What pt_radiance adds (sms.h explains the split): emission of SMS-owned paths, everything
 * else path tracing does, and SMS estimates. */
struct pt_split {
    bool owned, rest, tracked;
    const struct sms_scene *ss;
    struct sms_counters *sc;
    struct rng *sms_rng;
    uint32_t px, py;     /* the pixel (sms_ssp's prior block) */
    bool sms_after_primary;  /* restir_sms: no SMS estimate at its receiver (sms.h), the reservoirs' */
    /* The caller's G-buffer pass found the camera ray's first hit already: `primary` (NULL: the
     * ray escaped) stands for the first query, so the ray is not traced twice. */
    bool primary_given;
    const struct hit *primary;
    /* The emission seen at the first hit (or the environment the ray escapes to) is left out: the
     * ray from a subsurface entry point, whose direct light next-event estimation there counts. */
    bool skip_primary_emission;
    /* The depth of the first vertex: 0 for a camera ray; 1 for the ray that leaves a subsurface
     * entry point (restir_sss's indirect samples), so that the vertex it finds scatters as the
     * second vertex of a pt path does (a translucent surface there by its BSDF) and max_depth and
     * rr_depth count as in pt. */
    uint32_t first_depth;
};

/* Specular manifold sampling's estimate at a vertex (methods sms and restir_sms only): kept out
 * of the path loop, which is flattened (see pt_radiance), so that plain path tracing does not
 * carry the solver inlined. */
__attribute__((noinline)) static struct vec3 pt_sms_at(const struct scene *scene, const struct pt_params *params,
                                                       const struct pt_split *split, bool receiver,
                                                       const struct surface *s, const struct material *m,
                                                       struct vec3 wo, uint32_t room, struct ray_counters *rc)
{
    if (params->ssp)
        return ssp_estimate(scene, split->ss, params->ssp, receiver ? params->ssp_prior : NULL, split->px, split->py, s,
                            m, wo, room, split->sms_rng, split->sc, rc);
    return sms_estimate(scene, split->ss, params->sms, s, m, wo, room, split->sms_rng, split->sc, rc);
}

/* pt_sss_primary's arguments, copied in and out so that the path loop's own variables stay
 * registers (see pt_radiance). Every field pt_sss_primary may write (beta, L, rng, rc, org, dir,
 * prev_p, skip_emission) is copied back after the call, whether the path goes on or not; s is
 * only read. */
struct pt_sss_io {
    struct surface s;
    struct vec3 beta, L, org, dir, prev_p;
    struct rng rng;
    struct ray_counters rc;
    bool skip_emission;
};

/* What pt_radiance reads of the scene, the parameters and the split that no path changes: a
 * caller's local, made once by pt_tile_body for all the paths of its tile (by the other entry
 * points once per path). Its address goes nowhere but pt_radiance, which is inlined, so the
 * compiler keeps these values where they are across the Embree calls; read from the split and
 * the parameters, which outside code can reach (pt_sms_at gets the split), they were read again
 * and copied for every path, some 25 instructions a sample. */
struct pt_setup {
    const struct material *materials;
    const struct light_sampler *lights;
    const struct accel *accel;
    const struct sms_scene *ss;
    uint32_t max_depth, rr_depth;
    bool part_owned, part_rest, tracked;
    bool mis;            /* params->nee: MIS weights on emission found by BSDF sampling */
    bool nee;            /* ... and there are lights to sample */
    bool canonical;      /* the first vertex may be an SMS receiver (pt_radiance's `canonical`) */
    bool primary_given;  /* split->primary_given */
    uint32_t first_depth;  /* split->first_depth */
};

static inline struct pt_setup pt_setup_make(const struct scene *scene, const struct pt_params *params,
                                            const struct pt_split *split)
{
    return (struct pt_setup){.materials = scene->materials,
                             .lights = scene->lights,
                             .accel = scene->accel,
                             .ss = split->ss,
                             .max_depth = params->max_depth,
                             .rr_depth = params->rr_depth,
                             .part_owned = split->owned,
                             .part_rest = split->rest,
                             .tracked = split->tracked,
                             .mis = params->nee,
                             .nee = params->nee && light_sampler_count(scene->lights) > 0,
                             .canonical = split->ss && (split->sms_after_primary || params->ssp),
                             .primary_given = split->primary_given,
                             .first_depth = split->first_depth};
}

/* Radiance along one camera ray. The per-vertex work around the two ray queries is most of
 * what a ray costs besides Embree's traversal (docs/benchmarks.md, instructions per ray; `make
 * test-perf` keeps it from growing), so the loop keeps it lean: what no path changes comes from
 * the caller's pt_setup, and the random stream and the ray counters are the caller's locals
 * (every Embree call is opaque to the compiler, so values behind pointers that outside code can
 * reach would be reloaded after each ray), Embree's query structs are the caller's accel_query
 * (their constant fields written once), and the offset origin of the shadow ray is reused by the
 * continuation ray when both leave on the same side. `flatten` inlines every helper it calls
 * (material, surface, accel, light sampler, from their own files through link-time
 * optimisation), except the out-of-line SMS and subsurface branches: left to its heuristics,
 * link-time optimisation stopped inlining them once this function grew. Without `flatten` here
 * and on the tile loop the diffuse Cornell box costs 1038.3 instructions per ray against 937.9
 * (glossy: 1437.9 against 1327.3), without it on the tile loop alone 958.8 (see pt_tile_body),
 * so this function's own share is about 80 instructions per ray (2026-11-28, `RESTIR_BIN=B bash
 * tests/perf/instr_guard.sh`, B each build). qmc is the sample's Sobol' numbers with the Sobol'
 * sampler, else NULL: every caller but pt_tile_sobol passes a constant NULL, and takes this
 * function in with `flatten`, so that the branches on it fold away. */
__attribute__((flatten)) static struct vec3 pt_radiance(const struct scene *scene, const struct pt_params *params,
                                                        const struct pt_setup *setup, struct vec3 org, struct vec3 dir,
                                                        struct rng *rng, struct ray_counters *rc,
                                                        const struct pt_split *split,
                                                        const struct pt_sobol *qmc, const bool solid_angle,
                                                        struct accel_query *aq)
{
    /* The random stream and the ray counters are the caller's locals, whose address goes nowhere
     * else (pt_sss_primary gets copies): state behind pointers from further out could be changed
     * by any Embree call as far as the compiler knows, so it would be stored and reloaded around
     * every ray. The rest comes from `setup`, for the same reason. */
    const bool part_owned = setup->part_owned, part_rest = setup->part_rest, tracked = setup->tracked;
    const struct sms_scene *ss = setup->ss;
    const struct material *materials = setup->materials;
    const struct light_sampler *lights = setup->lights;
    const struct accel *accel = setup->accel;
    const bool mis = setup->mis;
    const bool nee = setup->nee;
    const uint32_t max_depth = setup->max_depth, rr_depth = setup->rr_depth;
    vec3_v4 L = {0.0f, 0.0f, 0.0f, 0.0f}, beta = {1.0f, 1.0f, 1.0f, 0.0f};
    /* The product of 1 / material_radiance_scale over the path's refractions: beta times this
     * is the throughput the path will have outside the glass it is in, which is what Russian
     * roulette weighs. Weighing beta itself, which inside glass of ior 1.5 is 1 / 2.25 of that,
     * kills two in three of the paths that kept 75 % of their energy and weights the survivors
     * by 3: a floor point lit through a slab's side wall then reads 2.4 times the light's
     * radiance. */
    float rr_scale = 1.0f;
    float prev_pdf_w = 0.0f;   /* solid-angle pdf of the BSDF sample that produced `dir` */
    bool prev_delta = true;    /* camera rays and delta scattering get no MIS on emission */
    struct vec3 prev_p = org;
    struct sms_track track = sms_track_start();
    bool skip_emission = split->skip_primary_emission;  /* else after subsurface scattering with NEE
                                                           (pt_sss_primary) */
    /* Every vertex so far delta and through its canonical lobe (sms.h): the next non-delta
     * vertex is the pixel's receiver, restir_sms's and the one sms_ssp's prior was built at. */
    bool canonical = setup->canonical;

    for (uint32_t depth = setup->first_depth;; depth++) {
        struct hit hit;
        bool found;
        if (depth == setup->first_depth && setup->primary_given) {
            found = split->primary != NULL;
            if (found) hit = *split->primary;
        } else {
            found = accel_query_intersect(accel, aq, org, dir, INFINITY, &hit, rc);
        }
        if (!found) {
            if (part_rest && !vec3_is_zero(scene->env_radiance) && !skip_emission) {
                float w = 1.0f;
                if (!prev_delta && mis) w = sampling_power_heuristic(prev_pdf_w, light_sampler_env_pdf_w(lights));
                L = L + beta * vec3_v4_pack(scene->env_radiance) * w;
            }
            break;
        }
        struct surface s;
        surface_from_hit(scene, &hit, org, dir, &s);
        const struct material *m = &materials[s.material];

        bool owned = tracked && sms_track_owned(scene, &track);
        if (material_is_emissive(m) && (owned ? part_owned : part_rest) && !skip_emission) {
            struct vec3 Le = light_sampler_emitted(m, -vec3_dot(dir, s.ng));
            if (!vec3_is_zero(Le)) {
                float w = 1.0f;
                if (!prev_delta && mis) {
                    /* The pdf NEE from the previous vertex has of sampling this point. */
                    float pdf_light_w;
                    if (solid_angle) {
                        pdf_light_w = light_sampler_pdf_w_from(lights, prev_p, s.shape, s.prim, s.p);
                    } else {
                        float d2 = vec3_length2(vec3_sub(s.p, prev_p));
                        pdf_light_w = sampling_area_to_solid_angle(light_sampler_pdf_a(lights, s.shape, s.prim), d2,
                                                                   vec3_dot(dir, s.ng));
                    }
                    w = sampling_power_heuristic(prev_pdf_w, pdf_light_w);
                }
                L = L + beta * vec3_v4_pack(Le) * w;
            }
        }
        if (depth >= max_depth) break;
        skip_emission = false;

        if (depth == 0 && m->kind == MATERIAL_TRANSLUCENT) {
            /* With next-event estimation the path through the entry points adds light only by NEE
             * there (the emission its next vertex finds is skipped) or after a further bounce: at
             * max_depth 1 (the direct-lighting case of [ReSTIR SSS §3], which its evaluation uses)
             * nothing is left to add once NEE at the entry points is someone else's, and no
             * continuation ray needs tracing. */
            const bool direct_here = part_rest;
            if (nee && !direct_here && depth + 1 >= max_depth) break;
            /* Direct light at the entry points belongs to the rest of the light transport; the
             * track stays where it was, so no path through subsurface scattering counts as owned
             * by specular manifold sampling (which does not sample from entry points). */
            struct pt_sss_io io = {.s = s, .beta = vec3_v4_unpack(beta), .L = vec3_v4_unpack(L), .rng = *rng,
                                   .rc = *rc, .org = org, .dir = dir, .prev_p = prev_p,
                                   .skip_emission = skip_emission};
            bool more = pt_sss_primary(scene, params, m, &io.s, vec3_neg(dir), &io.beta, &io.L, &io.rng, &io.rc,
                                       &io.org, &io.dir, &io.prev_p, &io.skip_emission, direct_here);
            beta = vec3_v4_pack(io.beta);
            L = vec3_v4_pack(io.L);
            *rng = io.rng;
            *rc = io.rc;
            org = io.org;
            dir = io.dir;
            prev_p = io.prev_p;
            skip_emission = io.skip_emission;
            if (!more) break;
            if (skip_emission && depth + 1 >= max_depth) break;
            canonical = false;
            /* A cosine-sampled direction: emission it reaches is MIS-weighted like a diffuse
             * bounce's when NEE is off (weight 1 then) — it is skipped when NEE is on. */
            prev_delta = true;
            prev_pdf_w = 0.0f;
            float u_rr = rng_next_float(rng);
            if (depth + 1 >= rr_depth) {
                float mx = vec3_v4_max_comp(beta);
                float q = mx < 0.95f ? mx : 0.95f;
                if (!(q > 0.0f) || u_rr >= q) break;
                beta = beta * (1.0f / q);
            }
            continue;
        }

        struct vec3 wo_world = vec3_neg(dir);
        /* Lambertian vertices, most of them in most scenes, skip the material dispatch (and,
         * without SMS, the local frame's first two axes): material_diffuse_* give the same
         * bits. */
        const bool diffuse = material_diffuse_path(m);
        struct vec3 wo = diffuse && !ss ? vec3_make(0.0f, 0.0f, vec3_dot(wo_world, s.frame.n))
                                        : frame_to_local(&s.frame, wo_world);
        unsigned flags = diffuse ? material_diffuse_flags() : material_flags(m);
        /* Offset origin of the shadow ray, and which side of ng it is on (-1: none traced). */
        struct vec3 shadow_org = s.p;
        int shadow_side = -1;

        /* The Sobol' numbers of this vertex's dimensions, when qdims (otherwise every number comes
         * from the PCG stream). With qmc a constant NULL (pt_tile_random, the other methods' entry
         * points) the branches on it fold away and the loop is the random sampler's alone. */
        const bool qdims = qmc && depth < PT_SOBOL_BOUNCES;
        const uint32_t qbase = PT_DIM_FIRST_VERTEX + (qdims ? depth : 0) * PT_DIMS_PER_VERTEX;
        const float *qu0 = qmc ? qmc->u0 + qbase : NULL, *qu1 = qmc ? qmc->u1 + qbase : NULL;

        /* Specular manifold sampling owns the caustic chains that start here (sms.h). */
        const bool receiver = canonical && depth <= SMS_RECEIVER_MAX_PREFIX && m->kind != MATERIAL_TRANSLUCENT;
        if (ss && (flags & (BSDF_DIFFUSE | BSDF_GLOSSY)) && !(receiver && split->sms_after_primary)) {
            uint32_t room = max_depth > depth + 1 ? max_depth - depth - 1 : 0;
            /* The block's prior describes its receivers' solutions; seen from any other vertex
             * its tiles are arbitrary, and a solution outside them would carry the uniform
             * share's weight, N² / (9 (1 − α)). Elsewhere seeds come from plain partitioning. */
            struct pt_sss_io io = {.s = s, .rc = *rc};  /* copies, as for pt_sss_primary */
            L = L + beta * vec3_v4_pack(pt_sms_at(scene, params, split, receiver, &io.s, m, wo, room, &io.rc));
            *rc = io.rc;
        }
        /* Next-event estimation: one light sample, MIS-weighted against BSDF sampling. */
        if (nee && part_rest && (flags & (BSDF_DIFFUSE | BSDF_GLOSSY))) {
            float ul, u1, u2;
            if (qdims) {
                ul = qu0[PT_DIM_CHOICES];
                u1 = qu0[PT_DIM_LIGHT_POINT];
                u2 = qu1[PT_DIM_LIGHT_POINT];
            } else {
                ul = rng_next_float(rng);
                u1 = rng_next_float(rng);
                u2 = rng_next_float(rng);
            }
            struct light_sample ls;
            if (pt_sample_light(lights, solid_angle, s.p, ul, u1, u2, &ls)) {
                struct vec3 wi_world, Le;
                float pdf_light_w;
                bool ok = pt_light_toward(scene, &ls, s.p, &wi_world, &Le, &pdf_light_w);
                /* The cheap rejections first (back of a one-sided emitter, zero pdf), before the
                 * frame conversion and the BSDF. */
                if (ok && !vec3_is_zero(Le)) {
                    /* A diffuse BRDF needs only the cosine with the shading normal. */
                    struct vec3 wi = diffuse ? vec3_make(0.0f, 0.0f, vec3_dot(wi_world, s.frame.n))
                                             : frame_to_local(&s.frame, wi_world);
                    /* Reject directions on different sides of the geometric and shading normals:
                     * they would leak light through the surface. */
                    float cos_ng = vec3_dot(wi_world, s.ng);
                    if (cos_ng * wi.z > 0.0f) {
                        struct vec3 f = diffuse ? material_diffuse_f(m, wo.z, wi.z)
                                                : material_eval(m, wo, wi, TRANSPORT_RADIANCE);
                        if (!vec3_is_zero(f)) {
                            shadow_side = cos_ng < 0.0f;
                            shadow_org = surface_offset_along(s.p, shadow_side ? vec3_neg(s.ng) : s.ng);
                            /* To an emitter, the ray spans from the offset origin to
                             * the light point offset towards it: a length measured from s.p
                             * lets a short ray from large coordinates (offset 256 ulps, 0.016
                             * near 500) reach the emitter itself and count it as occluder. */
                            struct vec3 sdir = wi_world;
                            float tmax = INFINITY;
                            if (!ls.is_env) {
                                struct vec3 end = surface_offset_along(ls.p, pt_emitter_side(ls.n, wi_world));
                                /* The segment itself as the direction (Embree's occlusion query
                                 * takes any length): t in [0, 1) spans it, no normalisation. */
                                sdir = vec3_sub(end, shadow_org);
                                /* Also a relative margin: near the origin the end's offset is an
                                 * absolute 1/65536, below a long ray's intersection error. */
                                tmax = vec3_is_zero(sdir) ? 0.0f : 1.0f - 1e-4f;
                            }
                            if (tmax > 0.0f && !accel_query_occluded(accel, aq, shadow_org, sdir, tmax, rc)) {
                                float pdf_bsdf_w = diffuse ? material_diffuse_pdf(wo.z, wi.z) : material_pdf(m, wo, wi);
                                float w = sampling_power_heuristic(pdf_light_w, pdf_bsdf_w);
                                struct vec3 c = vec3_scale(vec3_mul(f, Le), fabsf(wi.z) * w / pdf_light_w);
                                L = L + beta * vec3_v4_pack(c);
                            }
                        }
                    }
                }
            }
        } else if (!qdims) {
            /* Keep the random stream aligned whether or not NEE ran. */
            rng_skip(rng);
            rng_skip(rng);
            rng_skip(rng);
        }

        /* BSDF sampling continues the path. */
        struct bsdf_sample bs;
        struct vec3 weight;  /* f |cos wi| / pdf_w */
        if (diffuse) {
            float u1, u2;
            if (qdims) {
                u1 = qu0[PT_DIM_BSDF_DIRECTION];
                u2 = qu1[PT_DIM_BSDF_DIRECTION];
            } else {
                rng_skip(rng);  /* the lobe choice: one lobe */
                u1 = rng_next_float(rng);
                u2 = rng_next_float(rng);
            }
            if (!material_diffuse_sample(m, wo.z, u1, u2, &bs.wi, &bs.pdf_w, &weight)) break;
            bs.flags = material_diffuse_flags();
            bs.lobe = 0;
        } else {
            float u_lobe, u1, u2;
            if (qdims) {
                u_lobe = qu1[PT_DIM_CHOICES];
                u1 = qu0[PT_DIM_BSDF_DIRECTION];
                u2 = qu1[PT_DIM_BSDF_DIRECTION];
            } else {
                u_lobe = rng_next_float(rng);
                u1 = rng_next_float(rng);
                u2 = rng_next_float(rng);
            }
            if (!material_sample(m, wo, u_lobe, u1, u2, TRANSPORT_RADIANCE, &bs)) break;  /* pdf_w > 0 then */
            weight = vec3_scale(bs.f, fabsf(bs.wi.z) / bs.pdf_w);
        }
        struct vec3 wi_world = frame_to_world(&s.frame, bs.wi);
        float cos_ng = vec3_dot(wi_world, s.ng);
        if (cos_ng * bs.wi.z <= 0.0f) break;
        beta = beta * vec3_v4_pack(weight);
        if (bs.flags & BSDF_TRANSMISSION) rr_scale /= material_radiance_scale(m, wo, bs.wi);
        if (tracked) sms_track_scatter(scene, &track, &s, bs.flags);
        if (canonical) {
            struct bsdf_sample cb;
            canonical = (bs.flags & BSDF_DELTA) && sms_canonical_lobe(m, wo, &cb) && cb.lobe == bs.lobe;
        }
        prev_delta = (bs.flags & BSDF_DELTA) != 0;
        prev_pdf_w = bs.pdf_w;
        prev_p = s.p;

        /* Drawn whether or not roulette is played, to keep the PCG stream aligned (at a Sobol'
         * vertex nothing else is drawn from it). */
        float u_rr = qdims ? 0.0f : rng_next_float(rng);
        if (depth + 1 >= rr_depth) {
            if (qdims) u_rr = rng_next_float(rng);
            /* fminf(0.95f, max) spelled out: fminf is a libm call at -O2 (NaN rules), and a NaN
             * max gives 0.95 either way. */
            float mx = vec3_v4_max_comp(beta) * rr_scale;
            float q = mx < 0.95f ? mx : 0.95f;
            if (!(q > 0.0f) || u_rr >= q) break;
            beta = beta * (1.0f / q);
        }
        int side = cos_ng < 0.0f;
        org = side == shadow_side ? shadow_org : surface_offset_along(s.p, side ? vec3_neg(s.ng) : s.ng);
        dir = wi_world;
    }
    return vec3_v4_unpack(L);
}

/* One path of an entry point outside pt's tile loop: the set-up, the Embree query and locals of
 * the random stream and counters that the tile loop keeps per tile, made for this path (the
 * locals' addresses go nowhere but the inlined pt_radiance; see pt_setup), then handed back.
 * Inlined into each flattened caller. */
static inline struct vec3 pt_radiance_one(const struct scene *scene, const struct pt_params *params,
                                          const struct pt_split *split, struct vec3 org, struct vec3 dir,
                                          struct rng *rng, struct ray_counters *rc)
{
    const struct pt_setup setup = pt_setup_make(scene, params, split);
    struct accel_query aq;
    accel_query_init(&aq);
    struct rng rng_local = *rng;
    struct ray_counters rc_local = {0, 0};
    struct vec3 L =
        pt_radiance(scene, params, &setup, org, dir, &rng_local, &rc_local, split, NULL, false, &aq);
    *rng = rng_local;
    rc->intersect += rc_local.intersect;
    rc->occluded += rc_local.occluded;
    return L;
}

/* The two entry points for the other methods' paths take in pt_radiance themselves (`flatten`), so
 * that its Sobol' and solid-angle branches fold away with qmc a constant NULL and solid_angle a
 * constant false there too (those paths sample lights by area: pt_params' light_sampling is pt's
 * alone). Called out of line,
 * pt_radiance would be compiled once more with qmc unknown, since pt_tile_sobol passes one:
 * restir_sss spent 0.4 % more instructions (translucent, 64x64, 4 frames) that way, and 0.6 %
 * fewer this way than before the sampler existed (182,089,056 against 183,158,651, callgrind). */
__attribute__((flatten)) struct vec3 reference_pt_radiance(const struct scene *scene, const struct pt_params *params,
                                                           struct vec3 org, struct vec3 dir, const struct hit *primary,
                                                           struct rng *rng, struct ray_counters *rc)
{
    const struct pt_split all = {.owned = true, .rest = true, .primary_given = true, .primary = primary};
    return pt_radiance_one(scene, params, &all, org, dir, rng, rc);
}

__attribute__((flatten)) struct vec3 reference_pt_radiance_after_sss(const struct scene *scene,
                                                                     const struct pt_params *params, struct vec3 org,
                                                                     struct vec3 dir, const struct hit *first,
                                                                     struct rng *rng, struct ray_counters *rc)
{
    const struct pt_split after = {.owned = true, .rest = true, .primary_given = true, .primary = first,
                                   .skip_primary_emission = true, .first_depth = 1};
    return pt_radiance_one(scene, params, &after, org, dir, rng, rc);
}

__attribute__((flatten)) struct vec3
reference_pt_radiance_sms(const struct scene *scene, const struct pt_params *params, const struct sms_scene *ss,
                          uint32_t px, uint32_t py, struct vec3 org, struct vec3 dir, const struct hit *primary,
                          struct rng *rng, struct rng *sms_rng, struct sms_counters *sc, struct ray_counters *rc)
{
    const struct pt_split split = {.owned = false, .rest = !params->sms->caustics_only, .tracked = true, .ss = ss,
                                   .sc = sc, .sms_rng = sms_rng, .px = px, .py = py, .sms_after_primary = true,
                                   .primary_given = true, .primary = primary};
    return pt_radiance_one(scene, params, &split, org, dir, rng, rc);
}

/* The tile loop, flattened (by its two callers below) for the same reason as pt_radiance, which
 * it takes in with the camera ray. The price is a copy of the path loop per caller: pt_tile_random
 * is 40,911 bytes of code, pt_tile_sobol 45,607, reference_pt_radiance 33,028 and
 * reference_pt_radiance_sms 36,412, where the tile loop without `flatten` was 2,044 (`nm -S
 * --size-sort build/restir`, GCC 12). It buys about 21 instructions per ray, which the budget of
 * tests/perf/instr_budget.json needs (2026-11-28: 958.8 without it against 937.9 on the diffuse
 * Cornell box, `bash tests/perf/instr_guard.sh`). With `sobol` a constant in each copy, the
 * random sampler's loop holds no Sobol' code: 928.5 instructions per ray against 925.4 before
 * the sampler existed (2026-11-29; code placement, as far as callgrind_annotate shows: the extra
 * instructions are spread thinly over the inlined helpers, none in sobol.h). */
static inline __attribute__((always_inline)) void pt_tile_body(void *ctx, uint32_t tile, unsigned worker,
                                                                 const bool sobol, const bool solid_angle)
{
    struct pt_job *job = ctx;
    const struct pt_params *p = job->params;
    /* Counted job-locally and added to the worker's slot at the end (see sms_counters_add). */
    struct render_stats local = {0};
    struct render_stats *st = &local;
    struct ray_counters rc = {0, 0};
    struct pt_split split = {.owned = p->subset != PT_SUBSET_REST && !p->sms, .rest = p->subset != PT_SUBSET_CAUSTIC,
                             .ss = job->sms_scene, .sc = &st->sms, .primary_given = true};
    if (p->sms) split.rest = !p->sms->caustics_only;
    split.tracked = p->subset != PT_SUBSET_ALL || p->sms;
    uint32_t tx = tile % job->tiles_x, ty = tile / job->tiles_x;
    uint32_t x0 = p->crop_x0 + tx * PT_TILE, y0 = p->crop_y0 + ty * PT_TILE;
    uint32_t x1 = x0 + PT_TILE < p->crop_x1 ? x0 + PT_TILE : p->crop_x1;
    uint32_t y1 = y0 + PT_TILE < p->crop_y1 ? y0 + PT_TILE : p->crop_y1;
    const uint64_t first_index = (uint64_t)p->frame * p->spp, first_epoch = first_index >> PT_SOBOL_INDEX_BITS;
    const uint64_t first_epoch_key = sobol ? pt_sobol_epoch_key(p->seed, first_epoch) : 0;
    /* Set up once for the tile's rays (accel.h) and paths. */
    struct accel_query aq;
    accel_query_init(&aq);
    const struct pt_setup setup = pt_setup_make(job->scene, p, &split);
    /* Locals for the same reason as setup: the camera and the sample count behind job and p would
     * be read again (and the image size converted to float again) for every sample. */
    const struct camera cam = job->camera;
    const uint32_t spp = p->spp;
    const struct scene *scene = job->scene;
    for (uint32_t y = y0; y < y1; y++) {
        for (uint32_t x = x0; x < x1; x++) {
            if (parallel_stopped()) break;  /* the frame was given up: its pixels are not used */
            uint64_t pixel = (uint64_t)y * p->width + x;
            double acc[3] = {0, 0, 0};
            const struct rng_pixel streams = rng_pixel_make(p->seed, p->frame, pixel, PT_SAMPLE_STREAM);
            struct pt_sobol_pixel qpix;
            uint64_t epoch = UINT64_MAX;  /* none yet: the first sample derives the seeds */
            uint32_t run_first = 0, run_end = 0;  /* the samples whose numbers qpix.run holds */
            split.px = x;
            split.py = y;
            /* The pixel's samples go in groups of up to ACCEL_BUNDLE whose camera rays are traced
             * as one packet (accel_intersect_bundle; they leave one point through one pixel, so
             * they visit nearly the same BVH nodes). A group stays within one run of Sobol'
             * numbers. Each sample keeps its own stream and numbers, so the image is the one the
             * samples would give traced one by one. */
            for (uint32_t s = 0; s < spp;) {
                if (sobol && s == run_end) {
                    const uint64_t index = first_index + s;
                    if (index >> PT_SOBOL_INDEX_BITS != epoch) {
                        epoch = index >> PT_SOBOL_INDEX_BITS;
                        const uint64_t key =
                            epoch == first_epoch ? first_epoch_key : pt_sobol_epoch_key(p->seed, epoch);
                        pt_sobol_pixel(&qpix, key, pixel);
                    }
                    /* A run ends at the pixel's last sample, and at the end of an epoch (the next
                     * one has other seeds). */
                    const uint32_t in_epoch = (uint32_t)index & ((1u << PT_SOBOL_INDEX_BITS) - 1u);
                    uint32_t n = spp - s < PT_SOBOL_RUN ? spp - s : PT_SOBOL_RUN;
                    if (n > (1u << PT_SOBOL_INDEX_BITS) - in_epoch) n = (1u << PT_SOBOL_INDEX_BITS) - in_epoch;
                    sobol_batch_draw_run(&qpix.seeds, in_epoch, n, PT_SOBOL_LANES, qpix.run[0].u0, qpix.run[0].u1,
                                         (uint32_t)(sizeof qpix.run[0] / sizeof(float)));
                    run_first = s;
                    run_end = s + n;
                }
                const uint32_t left = (sobol ? run_end : spp) - s;
                const uint32_t g = left < ACCEL_BUNDLE ? left : ACCEL_BUNDLE;
                struct rng rngs[ACCEL_BUNDLE];
                struct vec3 dirs[ACCEL_BUNDLE];
                struct hit hits[ACCEL_BUNDLE];
                bool found[ACCEL_BUNDLE];
                for (uint32_t i = 0; i < g; i++) {
                    rngs[i] = rng_sample(&streams, s + i);
                    float jx, jy;
                    if (sobol) {
                        jx = qpix.run[s + i - run_first].u0[PT_DIM_PIXEL];
                        jy = qpix.run[s + i - run_first].u1[PT_DIM_PIXEL];
                    } else {
                        jx = rng_next_float(&rngs[i]);
                        jy = rng_next_float(&rngs[i]);
                    }
                    dirs[i] = camera_ray_dir(&cam, (float)x + jx, (float)y + jy);
                }
                accel_intersect_bundle(scene->accel, cam.position, dirs, g, hits, found, &rc);
                for (uint32_t i = 0; i < g; i++, s++) {
                    /* SMS draws from its own stream, so the path-traced part of `sms` is the same
                     * sample as pt's PT_SUBSET_REST image; without SMS nothing draws from it, and
                     * hashing it would cost every sample two rng_make. */
                    struct rng sms_rng;
                    if (setup.ss) {
                        sms_rng = rng_make(p->seed, p->frame, pixel, ((uint64_t)1 << 40) | s);
                        split.sms_rng = &sms_rng;
                    }
                    split.primary = found[i] ? &hits[i] : NULL;
                    struct rng rng = rngs[i];
                    struct vec3 L = pt_radiance(scene, p, &setup, cam.position, dirs[i], &rng, &rc, &split,
                                                sobol ? &qpix.run[s - run_first] : NULL, solid_angle, &aq);
                    if (!vec3_is_finite(L)) {
                        st->nonfinite++;
                        continue;
                    }
                    acc[0] += L.x;
                    acc[1] += L.y;
                    acc[2] += L.z;
                }
            }
            double inv = 1.0 / spp;
            job->out->pixels[pixel] = vec3_make((float)(acc[0] * inv), (float)(acc[1] * inv), (float)(acc[2] * inv));
            st->samples += spp;
        }
    }
    struct render_stats *sum = &job->worker_stats[worker];
    sum->rays_intersect += rc.intersect;
    sum->rays_occluded += rc.occluded;
    sum->samples += local.samples;
    sum->nonfinite += local.nonfinite;
    sms_counters_add(&sum->sms, &local.sms);
}

/* One copy of the tile loop per sampler with area light sampling, and one for solid-angle
 * sampling (either sampler, read at run time), each flattened (see pt_tile_body): in the first
 * two every solid-angle branch folds away, and in the random one every Sobol' branch. With the
 * solid-angle branches left in, the random sampler's loop cost 935.1 instructions per ray against
 * 929.4 with them folded away (diffuse Cornell box, `bash tests/perf/instr_guard.sh`, 2026-11-29). */
__attribute__((flatten)) static void pt_tile_random(void *ctx, uint32_t tile, unsigned worker)
{
    pt_tile_body(ctx, tile, worker, false, false);
}

__attribute__((flatten)) static void pt_tile_sobol(void *ctx, uint32_t tile, unsigned worker)
{
    pt_tile_body(ctx, tile, worker, true, false);
}

__attribute__((flatten)) static void pt_tile_solid_angle(void *ctx, uint32_t tile, unsigned worker)
{
    const struct pt_job *job = ctx;
    pt_tile_body(ctx, tile, worker, job->params->sampler == PT_SAMPLER_SOBOL, true);
}

bool reference_pt_render(const struct scene *scene, const struct pt_params *params, struct image *out,
                         struct render_stats *stats, parallel_progress_fn *progress, void *progress_ctx,
                         struct err *err)
{
    if (!image_init(out, params->width, params->height, err)) return false;
    if (reference_pt_render_into(scene, params, out, stats, progress, progress_ctx, err)) return true;
    image_destroy(out);
    return false;
}

bool reference_pt_render_into(const struct scene *scene, const struct pt_params *params, struct image *out,
                              struct render_stats *stats, parallel_progress_fn *progress, void *progress_ctx,
                              struct err *err)
{
    if (!scene->accel || !scene->lights) return err_set(err, ERR_INVALID, NULL, "scene is not committed");
    if (params->spp == 0) return err_set(err, ERR_INVALID, "spp", "spp must be at least 1");
    if (params->sampler != PT_SAMPLER_RANDOM && params->sampler != PT_SAMPLER_SOBOL)
        return err_set(err, ERR_INVALID, "sampler", "unknown sampler %d", (int)params->sampler);
    struct pt_params p = *params;
    if (p.crop_x1 == 0 && p.crop_y1 == 0) {
        p.crop_x0 = p.crop_y0 = 0;
        p.crop_x1 = p.width;
        p.crop_y1 = p.height;
    }
    if (p.crop_x0 >= p.crop_x1 || p.crop_y0 >= p.crop_y1 || p.crop_x1 > p.width || p.crop_y1 > p.height)
        return err_set(err, ERR_INVALID, "crop", "crop window [%u,%u)x[%u,%u) is empty or outside %ux%u", p.crop_x0,
                       p.crop_x1, p.crop_y0, p.crop_y1, p.width, p.height);
    if (out->width != p.width || out->height != p.height || !out->pixels)
        return err_set(err, ERR_INVALID, NULL, "the output image is %ux%u, the render %ux%u", out->width, out->height,
                       p.width, p.height);
    /* Pixels outside a crop keep 0, as in a fresh image. */
    if (p.crop_x0 != 0 || p.crop_y0 != 0 || p.crop_x1 != p.width || p.crop_y1 != p.height)
        memset(out->pixels, 0, (size_t)p.width * p.height * sizeof *out->pixels);

    /* On the stack (per-worker counters, ~57 KiB): a steady-state frame allocates nothing. */
    struct pt_job job_storage;
    struct pt_job *job = &job_storage;
    memset(job, 0, sizeof *job);
    job->scene = scene;
    job->params = &p;
    job->out = out;
    struct sms_scene sms_scene;   /* ~6 KiB on the stack, like the job */
    if (p.sms) {
        if (!sms_params_valid(p.sms, err) || !sms_scene_init(scene, &sms_scene, err)) return false;
        job->sms_scene = &sms_scene;
    }
    camera_init(&job->camera, p.camera ? p.camera : &scene->camera, p.width, p.height);
    job->tiles_x = (p.crop_x1 - p.crop_x0 + PT_TILE - 1) / PT_TILE;
    uint32_t tiles_y = (p.crop_y1 - p.crop_y0 + PT_TILE - 1) / PT_TILE;
    unsigned threads = p.threads ? p.threads : parallel_default_threads();
    if (threads > PT_MAX_WORKERS) threads = PT_MAX_WORKERS;

    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    const double cpu0 = parallel_cpu_ms();
    parallel_job_fn *tile_fn = p.light_sampling == PT_LIGHT_SAMPLING_SOLID_ANGLE ? pt_tile_solid_angle
                               : p.sampler == PT_SAMPLER_SOBOL                  ? pt_tile_sobol
                                                                                : pt_tile_random;
    bool ok = parallel_run(threads, job->tiles_x * tiles_y, tile_fn, job, progress, progress_ctx, err);
    clock_gettime(CLOCK_MONOTONIC, &t1);
    const double cpu_ms = parallel_cpu_ms() - cpu0;

    if (stats) {
        memset(stats, 0, sizeof *stats);
        for (unsigned i = 0; i < threads; i++) {
            stats->rays_intersect += job->worker_stats[i].rays_intersect;
            stats->rays_occluded += job->worker_stats[i].rays_occluded;
            stats->samples += job->worker_stats[i].samples;
            stats->nonfinite += job->worker_stats[i].nonfinite;
            sms_counters_add(&stats->sms, &job->worker_stats[i].sms);
        }
        stats->threads = threads;
        stats->render_ms = (double)(t1.tv_sec - t0.tv_sec) * 1e3 + (double)(t1.tv_nsec - t0.tv_nsec) * 1e-6;
        stats->render_cpu_ms = cpu_ms;
    }
    return ok;
}

bool reference_pt_add_pass(const struct scene *scene, const struct pt_params *params, uint32_t pass, struct image *sum,
                           struct image *scratch, struct render_stats *stats, struct err *err)
{
    if (sum->width != params->width || sum->height != params->height || !sum->pixels)
        return err_set(err, ERR_INVALID, NULL, "the sum image is %ux%u, the render %ux%u", sum->width, sum->height,
                       params->width, params->height);
    struct pt_params p = *params;
    p.frame = REFERENCE_PT_PASS_FRAME0 + pass;
    if (!reference_pt_render_into(scene, &p, scratch, stats, NULL, NULL, err)) return false;
    size_t n = (size_t)p.width * p.height;
    for (size_t i = 0; i < n; i++) sum->pixels[i] = vec3_add(sum->pixels[i], scratch->pixels[i]);
    return true;
}
