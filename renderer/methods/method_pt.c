/* method_pt.c — method `pt`: the reference path tracer (integrators/reference_pt.h), `spp` paths per
 * pixel and frame. Its frames are unbiased estimates each, independent draws with the random sampler
 * and one continued stratified sequence with the Sobol' sampler (the default), so the session's
 * accumulation converges to the ground truth every other method is tested against. */
#include <stddef.h>

#include "integrators/reference_pt.h"
#include "methods/adapter.h"
#include "methods/method.h"
#include "methods/path_params.h"

METHOD_FITS(struct pt_method_params, METHOD_PARAMS_BYTES);
METHOD_ENUM_IS_INT(enum pt_subset);
METHOD_ENUM_IS_INT(enum pt_sampler);
METHOD_ENUM_IS_INT(enum pt_light_sampling);

/* Depths of every path method: the same bound as the CLI's --max-depth. */
#define PATH_MAX_DEPTH 1024

/* The Sobol' sampler measured best at equal CPU time from 4 samples per pixel on (docs/benchmarks.md,
 * "pt: the sampler"); sms and sms_ssp take no sampler and never read it. */
struct pt_method_params pt_method_defaults(void)
{
    return (struct pt_method_params){.spp = 1, .max_depth = 64, .rr_depth = 3, .nee = true, .subset = PT_SUBSET_ALL,
                                     .sampler = PT_SAMPLER_SOBOL, .light_sampling = PT_LIGHT_SAMPLING_AREA};
}

bool pt_method_params_valid(const struct pt_method_params *p, struct err *err)
{
    if (p->spp == 0) return err_set(err, ERR_INVALID, "/params/spp", "spp must be at least 1");
    return true;
}

METHOD_DEFAULTS_OP(pt_defaults, struct pt_method_params, pt_method_defaults)
METHOD_VALIDATE_OP(pt_validate, struct pt_method_params, pt_method_params_valid)

struct pt_params pt_method_frame_params(const struct pt_method_params *pp, const struct method_frame *f,
                                        const struct image *out)
{
    struct pt_params p = reference_pt_defaults(out->width, out->height);
    p.spp = pp->spp;
    p.max_depth = pp->max_depth;
    p.rr_depth = pp->rr_depth;
    p.nee = pp->nee;
    p.seed = f->seed;
    p.frame = f->frame;
    p.threads = f->threads;
    p.camera = f->camera;
    return p;
}

static bool pt_render(void *state, const void *params, const struct method_frame *f, struct image *out,
                      struct frame_stats *stats, parallel_progress_fn *progress, void *progress_ctx, struct err *err)
{
    (void)state;
    const struct pt_method_params *pp = params;
    struct pt_params p = pt_method_frame_params(pp, f, out);
    p.subset = pp->subset;
    p.sampler = pp->sampler;
    p.light_sampling = pp->light_sampling;
    return reference_pt_render_into(f->scene, &p, out, &stats->render, progress, progress_ctx, err);
}

const char *const pt_subset_names[] = {"all", "caustic", "rest", NULL};
static const char *const pt_samplers[] = {"random", "sobol", NULL};
static const char *const pt_light_samplings[] = {"area", "solid_angle", NULL};

#define P(key, kind, lo, hi, help) METHOD_PARAM(struct pt_method_params, key, kind, lo, hi, help)
static const struct method_param pt_params_table[] = {
    {.key = "spp", .kind = METHOD_PARAM_UINT, .offset = offsetof(struct pt_method_params, spp), .min = 1,
     .max = UINT32_MAX, .flags = METHOD_PARAM_SPP_LIMIT, .help = "samples per pixel and frame"},
    P(max_depth, METHOD_PARAM_UINT, 0, PATH_MAX_DEPTH, "scattering events before a path stops; 0 = emitters only"),
    P(rr_depth, METHOD_PARAM_UINT, 0, PATH_MAX_DEPTH, "Russian roulette after this many bounces"),
    P(nee, METHOD_PARAM_BOOL, 0, 1, "next-event estimation with MIS (false: BSDF sampling only)"),
    METHOD_ENUM(struct pt_method_params, subset, pt_subset_names,
                "which light transport the image holds: all, the caustic paths SMS owns, or the rest"),
    METHOD_ENUM(struct pt_method_params, sampler, pt_samplers,
                "random numbers: sobol (Owen-scrambled Sobol' for the pixel position and the first two bounces) or "
                "random (a PCG stream per sample)"),
    METHOD_ENUM(struct pt_method_params, light_sampling, pt_light_samplings,
                "how next-event estimation samples emissive triangles: area, or the solid angle of those seen close by"),
};
#undef P

const struct method_desc method_pt = {
    .name = "pt",
    .summary = "reference path tracer: unidirectional, next-event estimation with MIS, Russian roulette",
    .caps = METHOD_TAKES_SPP | METHOD_STILL_CROP,
    METHOD_PARAM_TABLE(pt_params_table),
    .defaults = pt_defaults,
    .validate = pt_validate,
    .init = method_stateless_init,
    .destroy = method_stateless_destroy,
    .render = pt_render,
};
