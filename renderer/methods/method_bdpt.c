/* method_bdpt.c — methods `bdpt` and `restir_bdpt`: bidirectional path tracing with a light vertex
 * cache (integrators/bdpt.h), and ReSTIR BDPT (integrators/restir_bdpt.h): light-traced and
 * caustic reservoirs, and with `reuse` temporal and spatial reuse of the non-caustic reservoirs. */
#include <stddef.h>

#include "integrators/bdpt.h"
#include "integrators/restir_bdpt.h"
#include "methods/adapter.h"
#include "methods/method.h"

METHOD_FITS(struct bdpt_params, METHOD_PARAMS_BYTES);
METHOD_FITS(struct bdpt_stats, METHOD_COUNTERS_BYTES);
METHOD_FITS(struct restir_bdpt_params, METHOD_PARAMS_BYTES);
METHOD_FITS(struct restir_bdpt_stats, METHOD_COUNTERS_BYTES);
METHOD_ENUM_IS_INT(enum bdpt_heuristic);
METHOD_ENUM_IS_INT(enum restir_bdpt_variant);

static const char *const bdpt_heuristics[] = {"power", "balance", NULL};
#define BDPT_REFUSES "environment light, and translucent materials (bidirectional subsurface sampling is not implemented)"

/* ---- bdpt ---- */

METHOD_DEFAULTS_OP(bdpt_defaults_op, struct bdpt_params, bdpt_defaults)
METHOD_VALIDATE_OP(bdpt_validate, struct bdpt_params, bdpt_params_valid)
METHOD_INIT_OP(bdpt_init_op, struct bdpt_state, struct bdpt_params, bdpt_init)
METHOD_STATE_OP(bdpt_destroy_op, struct bdpt_state, bdpt_destroy)

static bool bdpt_render_op(void *state, const void *params, const struct method_frame *f, struct image *out,
                           struct frame_stats *stats, parallel_progress_fn *progress, void *progress_ctx,
                           struct err *err)
{
    struct bdpt_stats *c = METHOD_COUNTERS(struct bdpt_stats, stats);
    if (!bdpt_render(state, params, f, out, c, err)) return false;
    const double ms = c->light_ms + c->splat_ms + c->camera_ms;
    return method_frame_done(
        stats, method_frame_render_stats(out, f->threads, c->rays_intersect, c->rays_occluded, c->nonfinite, ms),
        progress, progress_ctx);
}

static uint64_t bdpt_bytes_planned_op(const void *params, const struct scene *scene, uint32_t width, uint32_t height)
{
    (void)scene;
    return bdpt_bytes_planned(params, width, height);
}

static uint32_t bdpt_buffers(const void *state, const void *params, struct view_buffer_bytes *out, uint32_t room)
{
    (void)params;
    uint32_t n = 0;
    method_buffer(out, room, &n, "light_vertex_cache", bdpt_lvc_bytes(state));
    method_buffer(out, room, &n, "lvc_blocks", bdpt_block_bytes(state));
    return n;
}

#define T struct bdpt_stats
static const struct method_stat bdpt_stats_table[] = {
    {"bdpt", "last_frame", METHOD_STAT_BEGIN, 0, 0},
    {"light_ms", NULL, METHOD_STAT_MS, offsetof(T, light_ms), 0},
    {"splat_ms", NULL, METHOD_STAT_MS, offsetof(T, splat_ms), 0},
    {"camera_ms", NULL, METHOD_STAT_MS, offsetof(T, camera_ms), 0},
    {"light_subpaths", NULL, METHOD_STAT_U64, offsetof(T, light_subpaths), 0},
    {"lvc_vertices", NULL, METHOD_STAT_U64, offsetof(T, lvc_vertices), 0},
    {"lvc_dropped", NULL, METHOD_STAT_U64, offsetof(T, lvc_dropped), 0},
    {"light_traced", NULL, METHOD_STAT_U64, offsetof(T, light_traced), 0},
    {"connections", NULL, METHOD_STAT_U64, offsetof(T, connections), 0},
    {"bdpt", NULL, METHOD_STAT_END, 0, 0},
    {NULL, "session_bytes", METHOD_STAT_SESSION_BYTES, 0, 0},
};
#undef T

#define P(key, kind, lo, hi, help) METHOD_PARAM(struct bdpt_params, key, kind, lo, hi, help)
static const struct method_param bdpt_params_table[] = {
    P(max_depth, METHOD_PARAM_UINT, 1, 1024, "scattering events of a full path"),
    P(rr_depth, METHOD_PARAM_UINT, 0, 1024, "Russian roulette after this many bounces of a subpath"),
    P(light_paths, METHOD_PARAM_UINT, 0, 1u << 26, "light subpaths per frame; 0 = the pixel count"),
    P(lvc_capacity, METHOD_PARAM_UINT, 1, 64, "light vertices cached per light subpath on average"),
    METHOD_ENUM(struct bdpt_params, heuristic, bdpt_heuristics, "the MIS heuristic: power (beta = 2) or balance"),
};
#undef P

const struct method_desc method_bdpt = {
    .name = "bdpt",
    .summary = "bidirectional path tracing with a light vertex cache and recursive MIS",
    .caps = METHOD_NO_ENVIRONMENT | METHOD_NO_TRANSLUCENT,
    .refuses = BDPT_REFUSES,
    METHOD_PARAM_TABLE(bdpt_params_table),
    METHOD_STAT_TABLE(bdpt_stats_table),
    .defaults = bdpt_defaults_op,
    .validate = bdpt_validate,
    .state_bytes = sizeof(struct bdpt_state),
    .init = bdpt_init_op,
    .destroy = bdpt_destroy_op,
    .render = bdpt_render_op,
    .bytes_planned = bdpt_bytes_planned_op,
    .buffers = bdpt_buffers,
};

/* ---- restir_bdpt ---- */

METHOD_DEFAULTS_OP(rbdpt_defaults, struct restir_bdpt_params, restir_bdpt_defaults)
/* The converge profile: the non-caustic reservoirs reused spatially, in three rounds of 3
 * neighbours ([ReSTIR BDPT Fig. 12]'s offline mode has 3 rounds of 6; a restir_bdpt shift replays
 * a light subpath, so fewer neighbours a round), and nothing carried from frame to frame (neither
 * caustic nor non-caustic history), so that a session's frames are independent: a history capped
 * as low as 1 left more error at equal time than none. One light subpath per pixel, as in real
 * time: twice as many gain on lamp-in-glass at equal time but lose on cornell-box and
 * caustic-sphere. docs/benchmarks.md measures it. */
static void rbdpt_converge(void *params)
{
    struct restir_bdpt_params *p = params;
    p->reuse = true;
    p->caustic_temporal = false;
    p->reuse_temporal = false;
    p->spatial_rounds = 3;
    p->spatial_neighbors = 3;
}

METHOD_VALIDATE_OP(rbdpt_validate, struct restir_bdpt_params, restir_bdpt_params_valid)
static bool rbdpt_init(void *state, const struct scene *scene, void *params, uint32_t width, uint32_t height,
                       struct err *err)
{
    struct restir_bdpt_params *p = params;
    if (!restir_bdpt_init(state, scene, p, width, height, err)) return false;
    /* The session reports the radius that its resolution gives (restir_radius_auto). */
    if (p->spatial_radius == 0.0f) p->spatial_radius = restir_radius_auto(width, height);
    return true;
}
METHOD_STATE_OP(rbdpt_reset, struct restir_bdpt_state, restir_bdpt_reset)
METHOD_STATE_OP(rbdpt_destroy, struct restir_bdpt_state, restir_bdpt_destroy)

static bool rbdpt_render(void *state, const void *params, const struct method_frame *f, struct image *out,
                         struct frame_stats *stats, parallel_progress_fn *progress, void *progress_ctx,
                         struct err *err)
{
    struct restir_bdpt_stats *c = METHOD_COUNTERS(struct restir_bdpt_stats, stats);
    if (!restir_bdpt_render(state, params, f, out, c, err)) return false;
    const double ms = c->light_ms + c->sort_ms + c->camera_ms + c->reuse_ms;
    return method_frame_done(
        stats, method_frame_render_stats(out, f->threads, c->rays_intersect, c->rays_occluded, c->rejected, ms),
        progress, progress_ctx);
}

static uint64_t rbdpt_bytes_planned(const void *params, const struct scene *scene, uint32_t width, uint32_t height)
{
    return restir_bdpt_bytes_planned(params, scene, width, height);
}

static uint32_t rbdpt_reservoir_bytes(const void *params, const struct scene *scene)
{
    (void)params, (void)scene;
    return RESTIR_BDPT_PATH_BYTES;
}

static uint32_t rbdpt_buffers(const void *state, const void *params, struct view_buffer_bytes *out, uint32_t room)
{
    (void)params;
    const struct restir_bdpt_state *st = state;
    uint32_t n = 0;
    method_buffer(out, room, &n, "reservoirs", restir_bdpt_reservoir_bytes(st));
    method_buffer(out, room, &n, "light_traced_samples", restir_bdpt_lt_bytes(st));
    method_buffer(out, room, &n, "caustic_shifts", restir_bdpt_shift_bytes(st));
    method_buffer(out, room, &n, "pixel_buckets", restir_bdpt_bucket_bytes(st));
    method_buffer(out, room, &n, "light_blocks", restir_bdpt_block_bytes(st));
    if (st->lvc) method_buffer(out, room, &n, "light_vertex_cache", restir_bdpt_lvc_bytes(st));
    if (st->gbuf[0].px) method_buffer(out, room, &n, "gbuffers", gbuffer_bytes(&st->gbuf[0]) + gbuffer_bytes(&st->gbuf[1]));
    if (st->gbuf[0].emission)
        method_buffer(out, room, &n, "emission", gbuffer_emission_bytes(&st->gbuf[0]) + gbuffer_emission_bytes(&st->gbuf[1]));
    if (st->pair_scratch) method_buffer(out, room, &n, "spatial_pairs", restir_bdpt_pair_bytes(st));
    if (st->x2c) method_buffer(out, room, &n, "light_x2_cache", restir_bdpt_x2_bytes(st));
    return n;
}

#define T struct restir_bdpt_stats
#define U(key, member, cli) {key, cli, METHOD_STAT_U64, offsetof(T, member), 0}
static const struct method_stat rbdpt_stats[] = {
    {"restir_bdpt", "last_frame", METHOD_STAT_BEGIN, 0, 0},
    {"light_ms", NULL, METHOD_STAT_MS, offsetof(T, light_ms), 0},
    {"sort_ms", NULL, METHOD_STAT_MS, offsetof(T, sort_ms), 0},
    {"camera_ms", NULL, METHOD_STAT_MS, offsetof(T, camera_ms), 0},
    U("light_subpaths", light_subpaths, NULL),
    U("light_vertices", light_vertices, NULL),
    U("light_traced", light_traced, NULL),
    U("lt_dropped", lt_dropped, NULL),
    U("lt_unshiftable", lt_unshiftable, NULL),
    U("lvc_dropped", lvc_dropped, NULL),
    U("connections", connections, NULL),
    U("caustic_samples", caustic_samples, NULL),
    U("camera_candidates", camera_candidates, ""),
    U("caustic_shifts", caustic_shifts, NULL),
    {"shift_failures", NULL, METHOD_STAT_BEGIN, 0, 0},
    U("replay", caustic_replay_failed, NULL),
    U("not_caustic", caustic_not_caustic, NULL),
    U("inverse", caustic_inverse_failed, NULL),
    {"shift_failures", NULL, METHOD_STAT_END, 0, 0},
    {"reuse_ms", NULL, METHOD_STAT_MS, offsetof(T, reuse_ms), 0},
    U("reuse_shifts", reuse_shifts, NULL),
    U("reuse_shift_failures", reuse_shift_failures, NULL),
    U("reuse_reconnections", reuse_reconnections, NULL),
    U("reservoir_bytes", reservoir_bytes, NULL),
    {"restir_bdpt", NULL, METHOD_STAT_END, 0, 0},
    {NULL, "session_bytes", METHOD_STAT_SESSION_BYTES, 0, 0},
};
#undef U
#undef T

static const char *const rbdpt_variants[] = {"lightweight", "full", NULL};

#define P(key, kind, lo, hi, help) METHOD_PARAM(struct restir_bdpt_params, key, kind, lo, hi, help)
static const struct method_param rbdpt_params[] = {
    METHOD_ENUM(struct restir_bdpt_params, variant, rbdpt_variants,
                "lightweight (s = 0, s = 1, t = 1 resampled per pixel) or full (adds vertex connections)"),
    P(max_depth, METHOD_PARAM_UINT, 1, RESTIR_BDPT_MAX_DEPTH, "scattering events of a full path"),
    P(rr_depth, METHOD_PARAM_UINT, 0, 1024, "Russian roulette after this many bounces of a subpath"),
    P(light_paths, METHOD_PARAM_UINT, 0, 1u << 26,
      "light subpaths per frame; 0 = the pixel count, or none for the lightweight variant in a scene without a caustic caster"),
    P(lt_capacity, METHOD_PARAM_UINT, 1, 64, "light-traced samples kept per light subpath on average"),
    P(lvc_capacity, METHOD_PARAM_UINT, 1, 64, "full variant: light vertices cached per light subpath on average"),
    METHOD_ENUM(struct restir_bdpt_params, heuristic, bdpt_heuristics, "the MIS heuristic: power or balance"),
    P(caustic_temporal, METHOD_PARAM_BOOL, 0, 1, "temporal reuse of the caustic reservoirs"),
    P(temporal_cap, METHOD_PARAM_UINT, 1, 65535, "caustic confidence cap; with reuse, the non-caustic history's multiple"),
    P(moving_cap, METHOD_PARAM_UINT, 1, 65535, "the caustic confidence cap in a frame whose shapes or lights changed"),
    P(reuse, METHOD_PARAM_BOOL, 0, 1, "temporal and spatial reuse of the non-caustic reservoirs"),
    P(reuse_temporal, METHOD_PARAM_BOOL, 0, 1, "with reuse: the non-caustic reservoirs reuse the previous frame's"),
    P(history_check, METHOD_PARAM_BOOL, 0, 1,
      "with reuse_temporal: a pixel whose previous pixel saw another surface takes no history"),
    P(emission_samples, METHOD_PARAM_UINT, 1, 256,
      "with reuse: rays per frame for the emission seen directly in pixels an emitter's edge crosses; 1 = the camera subpath's own"),
    P(spatial_neighbors, METHOD_PARAM_UINT, 0, 32, "with reuse: spatial neighbours per pixel and round"),
    P(spatial_rounds, METHOD_PARAM_UINT, 1, 8, "with reuse: spatial passes in a row, each reusing the last one's output"),
    P(spatial_radius, METHOD_PARAM_FLOAT, 0, 256, "with reuse: spatial radius in pixels; 0 = by resolution"),
    P(paired_spatial, METHOD_PARAM_BOOL, 0, 1, "with reuse: neighbours paired so a pair's shifts serve both"),
    P(expected_shading, METHOD_PARAM_BOOL, 0, 1,
      "with reuse: add the spatial pass's expected contribution over its selection instead of the selected sample's"),
    P(camera_reconnect, METHOD_PARAM_BOOL, 0, 1, "with reuse: camera-side samples reconnect (the hybrid shift)"),
    P(copy_mis, METHOD_PARAM_BOOL, 0, 1, "with reuse, lightweight: keep the base path's MIS weight (biased)"),
    P(reject_unshiftable, METHOD_PARAM_BOOL, 0, 1, "drop non-caustic t = 1 candidates that cannot shift (biased)"),
};
#undef P

const struct method_desc method_restir_bdpt = {
    .name = "restir_bdpt",
    .summary = "ReSTIR BDPT: resampled bidirectional paths with caustic reservoirs reused across frames",
    .caps = METHOD_REUSES_FRAMES | METHOD_NO_ENVIRONMENT | METHOD_NO_TRANSLUCENT,
    .refuses = BDPT_REFUSES,
    METHOD_PARAM_TABLE(rbdpt_params),
    METHOD_STAT_TABLE(rbdpt_stats),
    .defaults = rbdpt_defaults,
    .converge = rbdpt_converge,
    .validate = rbdpt_validate,
    .state_bytes = sizeof(struct restir_bdpt_state),
    .init = rbdpt_init,
    .reset = rbdpt_reset,
    .destroy = rbdpt_destroy,
    .render = rbdpt_render,
    .bytes_planned = rbdpt_bytes_planned,
    .reservoir_bytes_per_pixel = rbdpt_reservoir_bytes,
    .buffers = rbdpt_buffers,
};
