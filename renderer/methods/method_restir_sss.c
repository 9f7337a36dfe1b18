/* method_restir_sss.c — method `restir_sss`: ReSTIR for subsurface scattering
 * (integrators/restir_sss.h): BSSRDF probe candidates at translucent primary hits, reused
 * temporally and spatially through the reconnection, delayed, hybrid or sequential shift; the rest
 * of the light is restir_pt's (or the path tracer's). */
#include <stddef.h>

#include "integrators/restir_sss.h"
#include "methods/adapter.h"
#include "methods/method.h"
#include "methods/passes.h"

METHOD_FITS(struct restir_sss_params, METHOD_PARAMS_BYTES);
METHOD_FITS(struct restir_sss_stats, METHOD_COUNTERS_BYTES);
METHOD_ENUM_IS_INT(enum restir_sss_shift);
METHOD_ENUM_IS_INT(enum restir_sss_target);
METHOD_ENUM_IS_INT(enum restir_sss_rest);

METHOD_DEFAULTS_OP(sss_defaults, struct restir_sss_params, restir_sss_defaults)
/* The converge profile: temporal reuse off, so that a session's frames are independent; the
 * spatial reuse (spatial_neighbors, one round) keeps its default. Without temporal reuse the rest
 * is pt's (restir_sss_rest_of), and two of its paths a frame at the pixels off the translucent
 * surfaces took the accumulated image's MAPE from 1.18x pt's at equal time to 1.09x (docs/benchmarks.md,
 * "restir_sss: more of the rest's paths when converging"). */
static void sss_converge(void *params)
{
    struct restir_sss_params *p = params;
    p->temporal = false;
    p->rest_samples = 2;
}

METHOD_VALIDATE_OP(sss_validate, struct restir_sss_params, restir_sss_params_valid)
/* Both sessions forget their history: the BSSRDF reservoirs' and, with rest restir_pt, the rest's. */
static void sss_reset(void *state)
{
    restir_sss_reset(state);
}
METHOD_STATE_OP(sss_destroy, struct restir_sss_state, restir_sss_destroy)

static bool sss_init(void *state, const struct scene *scene, void *params, uint32_t width, uint32_t height,
                     struct err *err)
{
    struct restir_sss_params *p = params;
    if (!restir_sss_init(state, scene, p, width, height, err)) return false;
    p->rest = restir_sss_rest_of(p);   /* the session reports who renders the rest */
    return true;
}

static bool sss_render(void *state, const void *params, const struct method_frame *f, struct image *out,
                       struct frame_stats *stats, parallel_progress_fn *progress, void *progress_ctx, struct err *err)
{
    struct restir_sss_stats *c = METHOD_COUNTERS(struct restir_sss_stats, stats);
    return restir_sss_render(state, params, f, out, c, err) &&
           method_frame_done(stats, method_pass_render_stats(out, f->threads, &c->pass, c->rest_ms), progress,
                             progress_ctx);
}

static uint64_t sss_bytes_planned(const void *params, const struct scene *scene, uint32_t width, uint32_t height)
{
    return restir_sss_bytes_planned(params, scene, width, height);
}

static uint32_t sss_reservoir_bytes(const void *params, const struct scene *scene)
{
    (void)scene;
    return RESTIR_SSS_RESERVOIR_BYTES * restir_sss_layers(params);
}

static uint32_t sss_buffers(const void *state, const void *params, struct view_buffer_bytes *out, uint32_t room)
{
    (void)params;
    const struct restir_sss_state *st = state;
    uint32_t n = 0;
    method_buffer(out, room, &n, "reservoirs", restir_session_reservoir_bytes(&st->rs));
    method_buffer(out, room, &n, "gbuffers", restir_session_gbuffer_bytes(&st->rs));
    method_buffer(out, room, &n, "primary_hits", restir_session_hit_bytes(&st->rs));
    if (st->rs.pair_scratch) method_buffer(out, room, &n, "spatial_pairs", restir_session_pair_bytes(&st->rs));
    if (st->has_rest) method_rest_buffers(out, room, &n, &st->rest, &st->rest_image);
    return n;
}

static const struct method_stat sss_stats[] = {
    METHOD_PASS_STATS(struct restir_sss_stats, pass., METHOD_PASS_INITIAL(struct restir_sss_stats, pass.)),
    /* The rest's restir_pt frame (rest restir_pt), counted in the frame's time and rays. */
    {"rest_ms", NULL, METHOD_STAT_MS, offsetof(struct restir_sss_stats, rest_ms), 0},
};

static const char *const sss_shifts[] = {"reconnection", "delayed", "hybrid", "sequential", NULL};
static const char *const sss_targets[] = {"luminance", "per_channel", NULL};
static const char *const sss_rests[] = {"by_scene", "pt", "restir_pt", NULL};

#define P(key, kind, lo, hi, help) METHOD_PARAM(struct restir_sss_params, key, kind, lo, hi, help)
static const struct method_param sss_params[] = {
    METHOD_ENUM(struct restir_sss_params, shift, sss_shifts, "the shift between pixels and frames"),
    P(candidates, METHOD_PARAM_UINT, 1, 32, "BSSRDF probes per pixel and frame, each with one light sample"),
    P(temporal, METHOD_PARAM_BOOL, 0, 1, "temporal reuse"),
    P(temporal_cap, METHOD_PARAM_UINT, 1, 1000, "previous confidence capped at this multiple of the current"),
    P(spatial_neighbors, METHOD_PARAM_UINT, 0, 32, "spatial neighbours (even for the sequential shift); 0 = none"),
    P(spatial_radius, METHOD_PARAM_FLOAT, 0, 256,
      "spatial radius in pixels; 0 = from the profile's extent at the translucent pixels' distance"),
    P(kappa_orientation, METHOD_PARAM_FLOAT, -1, 1, "hybrid shift: reconnect when the normals' dot is at most this"),
    P(max_depth, METHOD_PARAM_UINT, 0, 1024, "scattering events of the paths of indirect samples and of the path-traced rest"),
    P(rr_depth, METHOD_PARAM_UINT, 0, 1000000, "Russian roulette of those paths after this many bounces"),
    P(index_shortcut, METHOD_PARAM_BOOL, 0, 1, "sequential shift only: the slightly biased intersection-index shortcut"),
    P(paired_spatial, METHOD_PARAM_BOOL, 0, 1, "neighbours paired so a pair's shifts serve both pixels"),
    P(expected_shading, METHOD_PARAM_BOOL, 0, 1,
      "shade with the last spatial pass's expected contribution over its selection"),
    METHOD_ENUM(struct restir_sss_params, target, sss_targets,
                "the resampling target: luminance (one reservoir per pixel) or per channel (three)"),
    {.key = "rest", .kind = METHOD_PARAM_ENUM, .offset = offsetof(struct restir_sss_params, rest), .choices = sss_rests,
     .flags = METHOD_PARAM_SCENE_DEFAULT,
     .help = "who renders the light the BSSRDF reservoirs do not carry: restir_pt (its reservoirs at the pixels "
             "not on translucent materials) or pt (rest_samples paths a pixel there); by_scene (the default) = "
             "restir_pt with temporal reuse on and max_depth in its 1..126, else pt"},
    P(rest_samples, METHOD_PARAM_UINT, 1, RESTIR_SSS_MAX_REST_SAMPLES,
      "rest pt: paths a pixel and frame at the pixels not on translucent materials, from the same primary hit"),
};
#undef P

const struct method_desc method_restir_sss = {
    .name = "restir_sss",
    .summary = "ReSTIR subsurface scattering: reuse of BSSRDF probe samples across pixels and frames",
    .caps = METHOD_REUSES_FRAMES | METHOD_REUSES_PIXELS,
    METHOD_PARAM_TABLE(sss_params),
    METHOD_STAT_TABLE(sss_stats),
    .defaults = sss_defaults,
    .converge = sss_converge,
    .validate = sss_validate,
    .state_bytes = sizeof(struct restir_sss_state),
    .init = sss_init,
    .reset = sss_reset,
    .destroy = sss_destroy,
    .render = sss_render,
    .bytes_planned = sss_bytes_planned,
    .reservoir_bytes_per_pixel = sss_reservoir_bytes,
    .buffers = sss_buffers,
};
