/* method_restir_pt.c — method `restir_pt`: ReSTIR path tracing with the Enhanced improvements
 * (integrators/restir_pt.h): one initial path per pixel, temporal and spatial reuse of
 * path-space reservoirs through the hybrid shift. */
#include <stddef.h>

#include "integrators/restir_pt.h"
#include "methods/adapter.h"
#include "methods/method.h"
#include "methods/passes.h"
#include "methods/path_params.h"

METHOD_FITS(struct restir_pt_params, METHOD_PARAMS_BYTES);
METHOD_FITS(struct restir_pass_stats, METHOD_COUNTERS_BYTES);
METHOD_ENUM_IS_INT(enum pt_subset);

METHOD_DEFAULTS_OP(rpt_defaults, struct restir_pt_params, restir_pt_defaults)
/* The converge profile: restir_pt_converge. */
static void rpt_converge(void *params) { restir_pt_converge(params); }

METHOD_VALIDATE_OP(rpt_validate, struct restir_pt_params, restir_pt_params_valid)
METHOD_SESSION_RESET_OP(rpt_reset, struct restir_pt_state)
METHOD_STATE_OP(rpt_destroy, struct restir_pt_state, restir_pt_destroy)

static bool rpt_init(void *state, const struct scene *scene, void *params, uint32_t width, uint32_t height,
                     struct err *err)
{
    struct restir_pt_params *p = params;
    if (!restir_pt_init(state, scene, p, width, height, err)) return false;
    /* The session reports the NEE candidates it uses. */
    if (p->nee_candidates == RESTIR_PT_NEE_BY_SCENE) p->nee_candidates = ((struct restir_pt_state *)state)->nee_by_scene;
    if (p->candidates == RESTIR_PT_CANDIDATES_BY_SCENE)
        p->candidates = ((struct restir_pt_state *)state)->candidates_by_scene;
    /* And the radius that its resolution gives (restir_radius_auto). */
    if (p->spatial_radius == 0.0f) p->spatial_radius = restir_radius_auto(width, height);
    return true;
}

static bool rpt_render(void *state, const void *params, const struct method_frame *f, struct image *out,
                       struct frame_stats *stats, parallel_progress_fn *progress, void *progress_ctx, struct err *err)
{
    struct restir_pass_stats *c = METHOD_COUNTERS(struct restir_pass_stats, stats);
    return restir_pt_render(state, params, f, out, c, err) &&
           method_frame_done(stats, method_pass_render_stats(out, f->threads, c, 0.0), progress, progress_ctx);
}

static uint64_t rpt_bytes_planned(const void *params, const struct scene *scene, uint32_t width, uint32_t height)
{
    return restir_pt_bytes_planned(params, width, height, scene);
}

static uint32_t rpt_reservoir_bytes(const void *params, const struct scene *scene)
{
    (void)params, (void)scene;
    return RESTIR_PT_RESERVOIR_BYTES;
}

static uint32_t rpt_buffers(const void *state, const void *params, struct view_buffer_bytes *out, uint32_t room)
{
    (void)params;
    const struct restir_pt_state *st = state;
    uint32_t n = 0;
    method_buffer(out, room, &n, "reservoirs", restir_session_reservoir_bytes(&st->rs));
    method_buffer(out, room, &n, "gbuffers", restir_session_gbuffer_bytes(&st->rs));
    method_buffer(out, room, &n, "primitive_table", ((size_t)st->shape_count + 1) * sizeof *st->prim_first);
    if (st->rs.pair_scratch) method_buffer(out, room, &n, "spatial_pairs", restir_session_pair_bytes(&st->rs));
    method_buffer(out, room, &n, "primary_hits", restir_session_hit_bytes(&st->rs));
    if (st->rs.gbuf[0].emission) method_buffer(out, room, &n, "emission", restir_session_emission_bytes(&st->rs));
    return n;
}

static const struct method_stat rpt_stats[] = {
    METHOD_PASS_STATS(struct restir_pass_stats, , METHOD_PASS_INITIAL(struct restir_pass_stats, )),
};

#define P(key, kind, lo, hi, help) METHOD_PARAM(struct restir_pt_params, key, kind, lo, hi, help)
static const struct method_param rpt_params[] = {
    P(max_depth, METHOD_PARAM_UINT, 1, 126, "scattering events before a path stops"),
    P(candidates, METHOD_PARAM_UINT, 0, 64,
      "initial paths per pixel and frame, resampled into its reservoir; 0 = by scene (8 with a near-specular surface, else 1)"),
    P(rr_depth, METHOD_PARAM_UINT, 0, 1000000, "Russian roulette from this vertex on"),
    P(rr, METHOD_PARAM_BOOL, 0, 1, "Russian roulette on initial paths (decoupled from the primary sample space)"),
    {.key = "nee_candidates", .kind = METHOD_PARAM_UINT, .offset = offsetof(struct restir_pt_params, nee_candidates),
     .min = 0, .max = 64, .flags = METHOD_PARAM_SCENE_DEFAULT,
     .help = "RIS next-event estimation candidates; 1 = plain NEE, 0 = none; by default chosen from the scene's emitters"},
    P(unify_di, METHOD_PARAM_BOOL, 0, 1, "direct light resampled together with indirect"),
    P(temporal, METHOD_PARAM_BOOL, 0, 1, "temporal reuse"),
    P(temporal_cap, METHOD_PARAM_UINT, 1, 1000, "previous confidence capped at this multiple of the current"),
    P(temporal_cap_replay, METHOD_PARAM_UINT, 0, 1000,
      "the cap for samples without a reconnection vertex (random replay only); 0 = temporal_cap"),
    P(history_check, METHOD_PARAM_BOOL, 0, 1,
      "a pixel whose previous pixel saw another surface takes no history, one that covers less area a share"),
    P(jitter_walk, METHOD_PARAM_FLOAT, 0, 0.5, "pixels the primary ray's position may move per frame and axis; 0 = afresh"),
    P(emission_samples, METHOD_PARAM_UINT, 1, 256,
      "rays per frame for the emission seen directly in pixels an emitter's edge crosses; 1 = the primary ray's own"),
    P(spatial_neighbors, METHOD_PARAM_UINT, 0, 64, "spatial neighbours per round; 0 = no spatial reuse"),
    P(spatial_radius, METHOD_PARAM_FLOAT, 0, 256, "spatial reuse radius in pixels; 0 = by resolution"),
    P(spatial_rounds, METHOD_PARAM_UINT, 1, 8, "spatial reuse rounds"),
    P(reject_normal_cos, METHOD_PARAM_FLOAT, 0, 1,
      "a spatial neighbour whose shading normal's cosine with the pixel's is below this is not reused; 0 = no test"),
    P(reject_depth, METHOD_PARAM_FLOAT, 0, 1,
      "a spatial neighbour whose hit distance differs by more than this fraction of the larger is not reused; 0 = no test"),
    P(paired_spatial, METHOD_PARAM_BOOL, 0, 1, "neighbours paired so a pair's shifts serve both pixels"),
    P(expected_shading, METHOD_PARAM_BOOL, 0, 1,
      "shade with the last spatial pass's expected contribution over its selection"),
    P(footprint, METHOD_PARAM_BOOL, 0, 1, "dual ray-footprint threshold for reconnection (else a near-field distance)"),
    {.key = "footprint_c", .kind = METHOD_PARAM_FLOAT, .offset = offsetof(struct restir_pt_params, footprint_c), .min = 0,
     .min_open = true, .max = 100, .help = "c of the footprint threshold"},
    P(near_distance, METHOD_PARAM_FLOAT, 0, 1, "without footprint: minimum segment length, fraction of the scene"),
    P(pdf_connect, METHOD_PARAM_BOOL, 0, 1, "PDF-based connectability (else lobe roughness)"),
    {.key = "roughness_min", .kind = METHOD_PARAM_FLOAT, .offset = offsetof(struct restir_pt_params, roughness_min),
     .min = 0, .min_open = true, .max = 1, .help = "alpha_min of both connectability tests"},
    METHOD_ENUM(struct restir_pt_params, subset, pt_subset_names,
                "which light transport the image holds, as pt's: all, the caustic paths SMS owns, or the rest"),
};
#undef P

const struct method_desc method_restir_pt = {
    .name = "restir_pt",
    .summary = "ReSTIR path tracing (Enhanced): temporal and spatial reuse of whole paths through the hybrid shift",
    .caps = METHOD_REUSES_FRAMES | METHOD_REUSES_PIXELS | METHOD_NO_TRANSLUCENT,
    .refuses = "translucent materials (subsurface scattering is not sampled)",
    METHOD_PARAM_TABLE(rpt_params),
    METHOD_STAT_TABLE(rpt_stats),
    .defaults = rpt_defaults,
    .converge = rpt_converge,
    .validate = rpt_validate,
    .state_bytes = sizeof(struct restir_pt_state),
    .init = rpt_init,
    .reset = rpt_reset,
    .destroy = rpt_destroy,
    .render = rpt_render,
    .bytes_planned = rpt_bytes_planned,
    .reservoir_bytes_per_pixel = rpt_reservoir_bytes,
    .buffers = rpt_buffers,
};
