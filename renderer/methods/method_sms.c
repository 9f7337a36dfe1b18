/* method_sms.c — methods `sms` and `sms_ssp`: the path tracer with specular manifold sampling at
 * every non-delta vertex for the caustic paths through the scene's casters (integrators/sms.h),
 * and the same with sample-space partitioning and a per-frame prior of earlier walks
 * (integrators/sms_ssp.h). The rest of the light transport is the path tracer's own. */
#include <stddef.h>
#include <string.h>

#include "integrators/reference_pt.h"
#include "methods/adapter.h"
#include "methods/method.h"
#include "methods/path_params.h"
#include "methods/prior_stats.h"
#include "scene/camera.h"

METHOD_FITS(struct sms_method_params, METHOD_PARAMS_BYTES);
METHOD_FITS(struct ssp_method_params, METHOD_PARAMS_BYTES);
METHOD_FITS(struct ssp_prior_counters, METHOD_COUNTERS_BYTES);

#define PATH_MAX_DEPTH 1024

/* ---- sms ---- */

static void sms_defaults_op(void *params)
{
    struct sms_method_params *p = params;
    p->pt = pt_method_defaults();
    p->sms = sms_defaults();
}

static bool sms_validate(const void *params, struct err *err)
{
    const struct sms_method_params *p = params;
    /* sms names its parameters bare; the session's are under /params. */
    return pt_method_params_valid(&p->pt, err) && (sms_params_valid(&p->sms, err) || err_under(err, "/params"));
}

/* Both methods refuse a scene whose casters sms_scene_init cannot hold. */
static bool sms_init(void *state, const struct scene *scene, void *params, uint32_t width, uint32_t height,
                     struct err *err)
{
    (void)state, (void)params, (void)width, (void)height;
    struct sms_scene ss;
    return sms_scene_init(scene, &ss, err);
}

static bool sms_render(void *state, const void *params, const struct method_frame *f, struct image *out,
                       struct frame_stats *stats, parallel_progress_fn *progress, void *progress_ctx, struct err *err)
{
    (void)state;
    const struct sms_method_params *sp = params;
    struct pt_params p = pt_method_frame_params(&sp->pt, f, out);
    p.sms = &sp->sms;
    return reference_pt_render_into(f->scene, &p, out, &stats->render, progress, progress_ctx, err);
}

#define PATH_PARAMS(type)                                                                                              \
    {.key = "spp", .kind = METHOD_PARAM_UINT, .offset = offsetof(type, pt.spp), .min = 1, .max = UINT32_MAX,          \
     .flags = METHOD_PARAM_SPP_LIMIT, .help = "samples per pixel and frame"},                                         \
        METHOD_PARAM_AT("max_depth", type, pt.max_depth, METHOD_PARAM_UINT, 0, PATH_MAX_DEPTH,                         \
                        "scattering events before a path stops"),                                                      \
        METHOD_PARAM_AT("rr_depth", type, pt.rr_depth, METHOD_PARAM_UINT, 0, PATH_MAX_DEPTH,                           \
                        "Russian roulette after this many bounces"),                                                   \
        METHOD_PARAM_AT("nee", type, pt.nee, METHOD_PARAM_BOOL, 0, 1,                                                  \
                        "next-event estimation with MIS at the path-traced vertices")
#define SMS_PARAMS(type, member)                                                                                       \
    METHOD_PARAM_AT("bernoulli_cap", type, member.bernoulli_cap, METHOD_PARAM_UINT, 0, SMS_HARD_TRIAL_LIMIT,           \
                    "Bernoulli trials per solution before it is dropped; 0 = uncapped"),                                \
        METHOD_PARAM_AT("max_iterations", type, member.max_iterations, METHOD_PARAM_UINT, 1, 100,                      \
                        "Newton steps per manifold walk"),                                                             \
        METHOD_PARAM_AT("caustics_only", type, member.caustics_only, METHOD_PARAM_BOOL, 0, 1,                          \
                        "render only the manifold sampling estimate (no path-traced rest)")

static const struct method_param sms_params_table[] = {
    PATH_PARAMS(struct sms_method_params),
    SMS_PARAMS(struct sms_method_params, sms),
};

const struct method_desc method_sms = {
    .name = "sms",
    .summary = "path tracing with specular manifold sampling for caustics through the scene's casters",
    .caps = METHOD_TAKES_SPP | METHOD_MANIFOLD_COUNTERS,
    .refuses = "scenes with more casters than manifold sampling can hold",
    METHOD_PARAM_TABLE(sms_params_table),
    .defaults = sms_defaults_op,
    .validate = sms_validate,
    .init = sms_init,
    .destroy = method_stateless_destroy,
    .render = sms_render,
};

/* ---- sms_ssp ---- */

static void ssp_defaults_op(void *params)
{
    struct ssp_method_params *p = params;
    p->pt = pt_method_defaults();
    p->ssp = ssp_defaults();
}

static bool ssp_validate(const void *params, struct err *err)
{
    const struct ssp_method_params *p = params;
    return pt_method_params_valid(&p->pt, err) &&
           ((sms_params_valid(&p->ssp.sms, err) && ssp_params_valid(&p->ssp, err)) || err_under(err, "/params"));
}

/* The prior, and the image size it was made for (its blocks follow the frame). */
struct ssp_state {
    struct ssp_prior prior;
    uint32_t width, height;
};

static bool ssp_init(void *state, const struct scene *scene, void *params, uint32_t width, uint32_t height,
                     struct err *err)
{
    const struct ssp_method_params *p = params;
    struct ssp_state *st = state;
    st->width = width, st->height = height;
    return sms_init(state, scene, params, width, height, err) &&
           ssp_prior_init(&st->prior, width, height, p->ssp.prior_frames, err);
}

static void ssp_destroy(void *state)
{
    ssp_prior_destroy(&((struct ssp_state *)state)->prior);
}

static bool ssp_render(void *state, const void *params, const struct method_frame *f, struct image *out,
                       struct frame_stats *stats, parallel_progress_fn *progress, void *progress_ctx, struct err *err)
{
    const struct ssp_method_params *sp = params;
    struct ssp_state *st = state;
    struct ssp_prior_counters *prior = METHOD_COUNTERS(struct ssp_prior_counters, stats);
    /* The prior pass ([SMS-SSP §4.1]) before the frame, under this frame's scene and camera. */
    struct camera cam;
    struct ray_counters prc = {0, 0};
    struct sms_scene ss;
    camera_init(&cam, f->camera, out->width, out->height);
    if (!sms_scene_init(f->scene, &ss, err)) return false;
    /* The walks kept from earlier frames describe this one while nothing moved. */
    bool still = f->prev_scene && memcmp(f->camera, f->prev_camera, sizeof *f->camera) == 0 &&
                 !scene_moved(f->prev_scene, f->scene);
    if (!ssp_prior_build(&st->prior, f->scene, &ss, &sp->ssp, &cam, f->seed, f->frame, still, f->threads, prior, &prc, err))
        return false;
    struct pt_params p = pt_method_frame_params(&sp->pt, f, out);
    p.sms = &sp->ssp.sms;
    p.ssp = &sp->ssp;
    p.ssp_prior = &st->prior;
    if (!reference_pt_render_into(f->scene, &p, out, &stats->render, progress, progress_ctx, err)) return false;
    stats->render.render_ms += prior->ms;
    return true;
}

static uint64_t ssp_bytes_planned(const void *params, const struct scene *scene, uint32_t width, uint32_t height)
{
    (void)scene;
    return ssp_prior_bytes(width, height, ((const struct ssp_method_params *)params)->ssp.prior_frames);
}

static uint32_t ssp_buffers(const void *state, const void *params, struct view_buffer_bytes *out, uint32_t room)
{
    (void)params;
    const struct ssp_state *st = state;
    uint32_t n = 0;
    method_buffer(out, room, &n, "prior", ssp_prior_bytes(st->width, st->height, st->prior.frames));
    return n;
}

static const struct method_stat ssp_stats[] = {METHOD_PRIOR_STATS(struct ssp_prior_counters, )};

static const struct method_param ssp_params_table[] = {
    PATH_PARAMS(struct ssp_method_params),
    SMS_PARAMS(struct ssp_method_params, ssp.sms),
    METHOD_PARAM_AT("tiles", struct ssp_method_params, ssp.tiles, METHOD_PARAM_UINT, 3, SSP_MAX_TILES,
                    "N: tiles per axis of the sample-space partition"),
    METHOD_PARAM_AT("prior", struct ssp_method_params, ssp.prior, METHOD_PARAM_BOOL, 0, 1,
                    "build and use the per-frame prior"),
    METHOD_PARAM_AT("prior_samples", struct ssp_method_params, ssp.prior_samples, METHOD_PARAM_UINT, 0, 4096,
                    "prior walks per block"),
    {.key = "alpha", .kind = METHOD_PARAM_FLOAT, .offset = offsetof(struct ssp_method_params, ssp.alpha), .min = 0,
     .max = 1, .max_open = true, .help = "mixing weight of the prior"},
    METHOD_PARAM_AT("prior_frames", struct ssp_method_params, ssp.prior_frames, METHOD_PARAM_UINT, 1,
                    SSP_MAX_PRIOR_FRAMES, "K: frames whose walks a still view's prior unites"),
};

const struct method_desc method_sms_ssp = {
    .name = "sms_ssp",
    .summary = "specular manifold sampling with sample-space partitioning and a per-frame prior",
    .caps = METHOD_TAKES_SPP | METHOD_MANIFOLD_COUNTERS,
    .refuses = "scenes with more casters than manifold sampling can hold",
    METHOD_PARAM_TABLE(ssp_params_table),
    METHOD_STAT_TABLE(ssp_stats),
    .defaults = ssp_defaults_op,
    .validate = ssp_validate,
    .state_bytes = sizeof(struct ssp_state),
    .init = ssp_init,
    .destroy = ssp_destroy,
    .render = ssp_render,
    .bytes_planned = ssp_bytes_planned,
    .buffers = ssp_buffers,
};
