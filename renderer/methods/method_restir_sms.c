/* method_restir_sms.c — method `restir_sms`: spatiotemporal resampling of specular manifold
 * samples (integrators/restir_sms.h): manifold sampling candidates at the primary hits, reused
 * through the manifold shift; the rest of the light is restir_pt's (or the path tracer's). */
#include <stddef.h>
#include <stdio.h>

#include "integrators/restir_sms.h"
#include "methods/adapter.h"
#include "methods/method.h"
#include "methods/passes.h"
#include "methods/prior_stats.h"

METHOD_FITS(struct restir_sms_params, METHOD_PARAMS_BYTES);
METHOD_FITS(struct restir_sms_stats, METHOD_COUNTERS_BYTES);
METHOD_ENUM_IS_INT(enum restir_sms_sampler);
METHOD_ENUM_IS_INT(enum restir_sms_rest);

METHOD_DEFAULTS_OP(rsms_defaults, struct restir_sms_params, restir_sms_defaults)
/* The converge profile: nothing carried from frame to frame, so that a session's frames are
 * independent: temporal reuse off, primary rays jittered afresh each frame (jitter_walk 0: not
 * walked from the previous frame's positions) and a prior of the frame's own walks alone
 * (prior_frames 1, for a session that asks for the ssp sampler). Without its history a frame's
 * spatial reuse costs more than it gains: at the CPU time of pt at 64 spp, against sms at 1 spp a
 * frame, one neighbour (or three) left 1.12x sms's MAPE on reflective-plane where no spatial reuse
 * left 1.02x, and no reuse was as good or better on refractive-slab and caustic-sphere. Of the two
 * samplers without reuse, plain SMS is the one within 1.1x of sms on all three scenes (1.02, 1.07,
 * 0.93 by MAPE; the partitioned sampler 1.10 on the plane). docs/benchmarks.md, "restir_sms's
 * converge profile". */
static void rsms_converge(void *params)
{
    struct restir_sms_params *p = params;
    p->temporal = false;
    p->jitter_walk = 0.0f;
    p->ssp.prior_frames = 1;
    p->spatial_neighbors = 0;
    p->sampler = RESTIR_SMS_SAMPLER_SMS;
}

METHOD_VALIDATE_OP(rsms_validate, struct restir_sms_params, restir_sms_params_valid)
/* Both sessions forget their history: the caustics' and, with rest = restir_pt, the rest's. */
static void rsms_reset(void *state)
{
    struct restir_sms_state *st = state;
    restir_session_reset(&st->rs);
    if (st->has_rest) restir_session_reset(&st->rest.rs);
}
METHOD_STATE_OP(rsms_destroy, struct restir_sms_state, restir_sms_destroy)

static bool rsms_init(void *state, const struct scene *scene, void *params, uint32_t width, uint32_t height,
                      struct err *err)
{
    struct restir_sms_params *p = params;
    struct sms_scene ss;
    if (!sms_scene_init(scene, &ss, err) || !restir_sms_init(state, scene, p, width, height, err)) return false;
    /* The session reports the reservoirs per pixel it uses, and who renders the rest. */
    p->light_reservoirs = ((struct restir_sms_state *)state)->rs.layers;
    p->rest = restir_sms_rest_of(p, scene);
    return true;
}

static bool rsms_render(void *state, const void *params, const struct method_frame *f, struct image *out,
                        struct frame_stats *stats, parallel_progress_fn *progress, void *progress_ctx, struct err *err)
{
    struct restir_sms_stats *c = METHOD_COUNTERS(struct restir_sms_stats, stats);
    if (!restir_sms_render(state, params, f, out, c, err)) return false;
    /* The prior pass counts as part of the initial pass (it only serves the candidates). */
    struct render_stats r = method_pass_render_stats(out, f->threads, &c->pass, c->prior_ms + c->rest_ms);
    r.sms = c->sms;
    return method_frame_done(stats, r, progress, progress_ctx);
}

static uint64_t rsms_bytes_planned(const void *params, const struct scene *scene, uint32_t width, uint32_t height)
{
    return restir_sms_bytes_planned(params, scene, width, height);
}

/* scene NULL: the params of a view, whose init resolved light_reservoirs. */
static uint32_t rsms_reservoir_bytes(const void *params, const struct scene *scene)
{
    const struct restir_sms_params *p = params;
    return RESTIR_SMS_RESERVOIR_BYTES * (scene ? restir_sms_layers(p, scene) : p->light_reservoirs);
}

static uint32_t rsms_buffers(const void *state, const void *params, struct view_buffer_bytes *out, uint32_t room)
{
    (void)params;
    const struct restir_sms_state *st = state;
    uint32_t n = 0;
    method_buffer(out, room, &n, "reservoirs", restir_session_reservoir_bytes(&st->rs));
    method_buffer(out, room, &n, "gbuffers", restir_session_gbuffer_bytes(&st->rs));
    method_buffer(out, room, &n, "receivers", restir_sms_receiver_bytes(st));
    if (st->prior.entries) method_buffer(out, room, &n, "prior", restir_sms_prior_bytes(st));
    if (st->rs.pair_scratch) method_buffer(out, room, &n, "spatial_pairs", restir_session_pair_bytes(&st->rs));
    if (st->has_rest) method_rest_buffers(out, room, &n, &st->rest, &st->rest_image);
    return n;
}

/* Its reservoirs grow with the scene's lights by default: say so, and how to ask for fewer. */
static void rsms_size_hint(const void *params, const struct scene *scene, char *out, size_t size)
{
    uint32_t layers = restir_sms_layers(params, scene);
    if (layers > 1)
        snprintf(out, size, "; it keeps %u reservoirs per pixel, by light (/params/light_reservoirs sets fewer)", layers);
}

#define T struct restir_sms_stats
/* The prior pass counts as part of the initial pass (it only serves the candidates). */
#define RSMS_INITIAL {"initial_ms", NULL, METHOD_STAT_MS_SUM, offsetof(T, prior_ms), offsetof(T, pass.initial_ms)}
static const struct method_stat rsms_stats[] = {
    METHOD_PASS_STATS(T, pass., RSMS_INITIAL),
    METHOD_PRIOR_STATS(T, prior.),
    /* The rest's restir_pt frame (rest = restir_pt), counted in the frame's time and rays. */
    {"rest_ms", NULL, METHOD_STAT_MS, offsetof(T, rest_ms), 0},
    /* The resampling column of [SMS-SSP Table 1]: the shifts' Newton steps (both walks) and the
     * walks back that missed the base chain. */
    {"manifold_shift", NULL, METHOD_STAT_BEGIN, 0, 0},
    {"newton", NULL, METHOD_STAT_U64, offsetof(T, shift_newton), 0},
    {"newtons_per_shift", "", METHOD_STAT_RATIO, offsetof(T, shift_newton), offsetof(T, pass.shifts)},
    {"not_invertible", NULL, METHOD_STAT_U64, offsetof(T, shift_not_invertible), 0},
    {"success_rate", "", METHOD_STAT_SUCCESS, offsetof(T, pass.shift_failures), offsetof(T, pass.shifts)},
    {"manifold_shift", NULL, METHOD_STAT_END, 0, 0},
};
#undef RSMS_INITIAL
#undef T

static const char *const rsms_samplers[] = {"ssp", "sms", NULL};
static const char *const rsms_rests[] = {"by_scene", "pt", "restir_pt", NULL};

#define P(key, kind, lo, hi, help) METHOD_PARAM(struct restir_sms_params, key, kind, lo, hi, help)
#define S(key, member, kind, lo, hi, help) METHOD_PARAM_AT(key, struct restir_sms_params, member, kind, lo, hi, help)
static const struct method_param rsms_params[] = {
    METHOD_ENUM(struct restir_sms_params, sampler, rsms_samplers,
                "the candidates' sampler: ssp (partitioned, with the prior) or plain sms"),
    P(shift_iterations, METHOD_PARAM_UINT, 1, MANIFOLD_MAX_ITERATIONS, "Newton steps of each walk of a shift"),
    P(temporal_cap, METHOD_PARAM_UINT, 1, 1000, "previous confidence capped at this multiple of the current"),
    P(spatial_neighbors, METHOD_PARAM_UINT, 0, 32, "spatial neighbours; 0 = no spatial reuse"),
    {.key = "rest", .kind = METHOD_PARAM_ENUM, .offset = offsetof(struct restir_sms_params, rest), .choices = rsms_rests,
     .flags = METHOD_PARAM_SCENE_DEFAULT,
     .help = "who renders the light SMS does not own: restir_pt (its reservoirs, subset rest) or pt (one path a "
             "frame); by_scene (the default) = restir_pt unless the scene has translucent materials"},
    P(max_depth, METHOD_PARAM_UINT, 0, 1024,
      "scattering events of the path that carries the SMS estimates at later vertices (and of the rest)"),
    P(rr_depth, METHOD_PARAM_UINT, 0, SMS_HARD_TRIAL_LIMIT, "Russian roulette of that path"),
    P(temporal, METHOD_PARAM_BOOL, 0, 1, "temporal reuse"),
    P(spatial_radius, METHOD_PARAM_FLOAT, 1, 256, "spatial radius in pixels"),
    P(paired_spatial, METHOD_PARAM_BOOL, 0, 1, "neighbours paired so a pair's shifts serve both pixels"),
    P(expected_shading, METHOD_PARAM_BOOL, 0, 1, "shade with the spatial pass's expected contribution"),
    P(jitter_walk, METHOD_PARAM_FLOAT, 0, 0.5, "pixels the primary ray's position may move per frame and axis"),
    {.key = "light_reservoirs", .kind = METHOD_PARAM_UINT, .offset = offsetof(struct restir_sms_params, light_reservoirs),
     .min = 0, .max = RESTIR_SMS_MAX_LIGHT_RESERVOIRS, .flags = METHOD_PARAM_SCENE_DEFAULT,
     .help = "reservoirs per pixel, each for its share of the emitters; 0 (the default) = one per emissive shape"},
    S("bernoulli_cap", ssp.sms.bernoulli_cap, METHOD_PARAM_UINT, 0, SMS_HARD_TRIAL_LIMIT,
      "Bernoulli trials per solution before it is dropped; 0 = uncapped"),
    S("max_iterations", ssp.sms.max_iterations, METHOD_PARAM_UINT, 1, 100, "Newton steps per sampling walk"),
    S("caustics_only", ssp.sms.caustics_only, METHOD_PARAM_BOOL, 0, 1, "render only the caustic paths"),
    S("tiles", ssp.tiles, METHOD_PARAM_UINT, 3, SSP_MAX_TILES, "ssp sampler: tiles per axis"),
    S("prior", ssp.prior, METHOD_PARAM_BOOL, 0, 1, "ssp sampler: build and use the per-frame prior"),
    S("prior_samples", ssp.prior_samples, METHOD_PARAM_UINT, 0, 4096, "ssp sampler: prior walks per block"),
    {.key = "alpha", .kind = METHOD_PARAM_FLOAT, .offset = offsetof(struct restir_sms_params, ssp.alpha), .min = 0,
     .max = 1, .max_open = true, .help = "ssp sampler: mixing weight of the prior"},
    S("prior_frames", ssp.prior_frames, METHOD_PARAM_UINT, 1, SSP_MAX_PRIOR_FRAMES,
      "ssp sampler: frames whose walks a still view's prior unites"),
};
#undef S
#undef P

const struct method_desc method_restir_sms = {
    .name = "restir_sms",
    .summary = "ReSTIR over specular manifold samples: caustic paths reused through the manifold shift",
    .caps = METHOD_REUSES_FRAMES | METHOD_REUSES_PIXELS | METHOD_MANIFOLD_COUNTERS,
    .refuses = "scenes with more casters than manifold sampling can hold",
    METHOD_PARAM_TABLE(rsms_params),
    METHOD_STAT_TABLE(rsms_stats),
    .defaults = rsms_defaults,
    .converge = rsms_converge,
    .validate = rsms_validate,
    .state_bytes = sizeof(struct restir_sms_state),
    .init = rsms_init,
    .reset = rsms_reset,
    .destroy = rsms_destroy,
    .render = rsms_render,
    .bytes_planned = rsms_bytes_planned,
    .reservoir_bytes_per_pixel = rsms_reservoir_bytes,
    .buffers = rsms_buffers,
    .size_hint = rsms_size_hint,
};
