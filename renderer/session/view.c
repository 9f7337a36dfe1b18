/* view.c — per-session persistent state and the frame driver (see view.h). */
#include "session/view.h"

#include <stdlib.h>
#include <string.h>
#include <time.h>

struct view_params view_params_defaults(enum render_method method, uint32_t width, uint32_t height)
{
    struct view_params p = {.method = method, .width = width, .height = height, .seed = 0};
    p.pt = (struct view_pt_params){.spp = 1, .max_depth = 64, .rr_depth = 3, .nee = true};
    p.restir_pt = restir_pt_defaults();
    p.bdpt = bdpt_defaults();
    p.sms = sms_defaults();
    p.restir_sss = restir_sss_defaults();
    p.ssp = ssp_defaults();
    p.restir_bdpt = restir_bdpt_defaults();
    p.restir_sms = restir_sms_defaults();
    return p;
}

bool view_method_parse(const char *name, enum render_method *out)
{
    if (strcmp(name, "pt") == 0) { *out = RENDER_METHOD_PT; return true; }
    if (strcmp(name, "restir_pt") == 0) { *out = RENDER_METHOD_RESTIR_PT; return true; }
    if (strcmp(name, "bdpt") == 0) { *out = RENDER_METHOD_BDPT; return true; }
    if (strcmp(name, "sms") == 0) { *out = RENDER_METHOD_SMS; return true; }
    if (strcmp(name, "restir_sss") == 0) { *out = RENDER_METHOD_RESTIR_SSS; return true; }
    if (strcmp(name, "sms_ssp") == 0) { *out = RENDER_METHOD_SMS_SSP; return true; }
    if (strcmp(name, "restir_bdpt") == 0) { *out = RENDER_METHOD_RESTIR_BDPT; return true; }
    if (strcmp(name, "restir_sms") == 0) { *out = RENDER_METHOD_RESTIR_SMS; return true; }
    return false;
}

const char *view_method_name(enum render_method method)
{
    switch (method) {
    case RENDER_METHOD_PT: return "pt";
    case RENDER_METHOD_RESTIR_PT: return "restir_pt";
    case RENDER_METHOD_BDPT: return "bdpt";
    case RENDER_METHOD_SMS: return "sms";
    case RENDER_METHOD_RESTIR_SSS: return "restir_sss";
    case RENDER_METHOD_SMS_SSP: return "sms_ssp";
    case RENDER_METHOD_RESTIR_BDPT: return "restir_bdpt";
    case RENDER_METHOD_RESTIR_SMS: return "restir_sms";
    }
    return NULL;
}

static void view_drop_history(struct view *v)
{
    scene_release(v->prev_scene);
    v->prev_scene = NULL;
    v->prev_camera = v->camera;
    v->frame = 0;
    v->accum_count = 0;
    restir_pt_reset(&v->restir);
    restir_sss_reset(&v->sss);
    restir_bdpt_reset(&v->rbdpt);
    restir_sms_reset(&v->rsms);
    if (v->accum.pixels) memset(v->accum.pixels, 0, (size_t)v->accum.width * v->accum.height * sizeof *v->accum.pixels);
}

bool view_init(struct view *v, struct scene *scene, const struct view_params *params, unsigned threads,
               struct err *err)
{
    memset(v, 0, sizeof *v);
    if (params->width == 0 || params->height == 0)
        return err_set(err, ERR_INVALID, "/width", "image size must be at least 1x1");
    if (params->method != RENDER_METHOD_RESTIR_PT && params->pt.spp == 0)
        return err_set(err, ERR_INVALID, "/params/spp", "spp must be at least 1");
    if (params->method == RENDER_METHOD_SMS || params->method == RENDER_METHOD_SMS_SSP) {
        struct sms_scene ss;
        if (!sms_params_valid(&params->sms, err) || !ssp_params_valid(&params->ssp, err) ||
            !sms_scene_init(scene, &ss, err))
            return false;
    }
    if (params->method == RENDER_METHOD_SMS_SSP && !ssp_prior_init(&v->prior, params->width, params->height, params->ssp.prior_frames, err))
        return false;
    if (params->method == RENDER_METHOD_RESTIR_PT) {
        if (!restir_pt_params_valid(&params->restir_pt, err)) return false;
        if (!restir_pt_init(&v->restir, scene, &params->restir_pt, params->width, params->height, err)) return false;
    }
    if (params->method == RENDER_METHOD_BDPT &&
        !bdpt_init(&v->bdpt, scene, &params->bdpt, params->width, params->height, err))
        return false;
    if (params->method == RENDER_METHOD_RESTIR_BDPT &&
        !restir_bdpt_init(&v->rbdpt, scene, &params->restir_bdpt, params->width, params->height, err))
        return false;
    if (params->method == RENDER_METHOD_RESTIR_SSS) {
        if (!restir_sss_params_valid(&params->restir_sss, err)) return false;
        if (!restir_sss_init(&v->sss, &params->restir_sss, params->width, params->height, err)) return false;
    }
    if (params->method == RENDER_METHOD_RESTIR_SMS) {
        struct sms_scene ss;
        if (!restir_sms_params_valid(&params->restir_sms, err) || !sms_scene_init(scene, &ss, err)) return false;
        if (!restir_sms_init(&v->rsms, scene, &params->restir_sms, params->width, params->height, err)) return false;
    }
    /* pt needs its frame and the accumulation buffer: no reservoirs, no G-buffer. */
    if (!image_init(&v->output, params->width, params->height, err) ||
        !image_init(&v->accum, params->width, params->height, err)) {
        image_destroy(&v->output);
        restir_pt_destroy(&v->restir);
        bdpt_destroy(&v->bdpt);
        restir_bdpt_destroy(&v->rbdpt);
        restir_sss_destroy(&v->sss);
        restir_sms_destroy(&v->rsms);
        ssp_prior_destroy(&v->prior);
        return false;
    }
    v->changes = calloc(scene->shape_count ? scene->shape_count : 1, sizeof *v->changes);
    if (!v->changes) {
        image_destroy(&v->output);
        image_destroy(&v->accum);
        restir_pt_destroy(&v->restir);
        bdpt_destroy(&v->bdpt);
        restir_bdpt_destroy(&v->rbdpt);
        restir_sss_destroy(&v->sss);
        restir_sms_destroy(&v->rsms);
        ssp_prior_destroy(&v->prior);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for a view");
    }
    v->params = *params;
    if (params->method == RENDER_METHOD_RESTIR_PT && params->restir_pt.nee_candidates == RESTIR_PT_NEE_BY_SCENE)
        v->params.restir_pt.nee_candidates = v->restir.nee_by_scene;  /* the session reports what it uses */
    if (params->method == RENDER_METHOD_RESTIR_SMS) v->params.restir_sms.light_reservoirs = v->rsms.layers;  /* likewise */
    v->threads = threads;
    scene_retain(scene);
    scene_retain(scene);
    v->base = v->scene = scene;
    v->camera = v->prev_camera = scene->camera;
    return true;
}

void view_destroy(struct view *v)
{
    scene_release(v->prev_scene);
    scene_release(v->scene);
    scene_release(v->base);
    image_destroy(&v->output);
    image_destroy(&v->accum);
    restir_pt_destroy(&v->restir);
    bdpt_destroy(&v->bdpt);
    restir_bdpt_destroy(&v->rbdpt);
    restir_sss_destroy(&v->sss);
    restir_sms_destroy(&v->rsms);
    ssp_prior_destroy(&v->prior);
    free(v->changes);
    memset(v, 0, sizeof *v);
}

void view_reset(struct view *v)
{
    view_drop_history(v);
}

/* Merges `in` into the changes in force; false (nothing changed) on a bad shape index. */
static bool view_merge_changes(struct view *v, const struct view_shape_change *in, uint32_t n, struct err *err)
{
    for (uint32_t i = 0; i < n; i++)
        if (in[i].shape >= v->base->shape_count)
            return err_set(err, ERR_INVALID, NULL, "shape index %u out of range", in[i].shape);
    for (uint32_t i = 0; i < n; i++) {
        struct view_shape_change *c = NULL;
        for (uint32_t k = 0; k < v->change_count; k++)
            if (v->changes[k].shape == in[i].shape) c = &v->changes[k];
        if (!c) {
            c = &v->changes[v->change_count++];
            memset(c, 0, sizeof *c);
            c->shape = in[i].shape;
        }
        /* position and transform both address the transform: the newer one wins. */
        if (in[i].has_transform) {
            c->has_transform = true, c->has_position = false;
            c->transform = in[i].transform;
        }
        if (in[i].has_position) {
            c->has_position = true;
            c->position = in[i].position;
        }
        if (in[i].has_emission) {
            c->has_emission = true;
            c->emission = in[i].emission;
        }
    }
    return true;
}

/* The scene with the changes in force, derived from the loaded one. */
static struct scene *view_build_scene(const struct view *v, struct err *err)
{
    struct scene_shape_override ov[v->change_count ? v->change_count : 1];
    for (uint32_t i = 0; i < v->change_count; i++) {
        const struct view_shape_change *c = &v->changes[i];
        struct xform xf = c->has_transform ? c->transform : v->base->shapes[c->shape].to_world;
        if (c->has_position) {
            xf.m[0][3] = c->position.x;
            xf.m[1][3] = c->position.y;
            xf.m[2][3] = c->position.z;
        }
        ov[i] = (struct scene_shape_override){.shape = c->shape, .has_to_world = c->has_position || c->has_transform,
                                              .to_world = xf, .has_emission = c->has_emission,
                                              .emission = c->emission};
    }
    return scene_derive(v->base, ov, v->change_count, err);
}

/* The render stats of a frame a reusing or bidirectional method rendered in one go: one sample
 * per pixel, the method's own ray and non-finite counts and pass times. */
static struct render_stats view_frame_stats(const struct view *v, const struct image *out, uint64_t intersect,
                                            uint64_t occluded, uint64_t nonfinite, double ms)
{
    return (struct render_stats){.rays_intersect = intersect, .rays_occluded = occluded,
                                 .samples = (uint64_t)out->width * out->height, .nonfinite = nonfinite,
                                 .threads = v->threads ? v->threads : parallel_default_threads(), .render_ms = ms};
}

static double view_ms_since(const struct timespec *t0)
{
    struct timespec t1;
    clock_gettime(CLOCK_MONOTONIC, &t1);
    return (double)(t1.tv_sec - t0->tv_sec) * 1e3 + (double)(t1.tv_nsec - t0->tv_nsec) * 1e-6;
}

bool view_render(struct view *v, const struct view_frame_change *change, struct frame_stats *stats,
                 parallel_progress_fn *progress, void *progress_ctx, struct err *err)
{
    struct image *out = &v->output;
    struct camera_desc camera = v->camera;
    struct scene *scene = v->scene;
    bool restart = false;
    double update_ms = 0.0;

    scene_retain(scene);
    if (change && change->has_camera) {
        camera = change->camera;
        restart = restart || memcmp(&camera, &v->camera, sizeof camera) != 0;
    }
    if (change && change->shape_count) {
        /* Work on a copy so that a failure leaves the view as it was. */
        struct view_shape_change saved[v->change_count ? v->change_count : 1];
        uint32_t saved_count = v->change_count;
        memcpy(saved, v->changes, saved_count * sizeof *saved);
        struct timespec t0;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        struct scene *derived = NULL;
        if (view_merge_changes(v, change->shapes, change->shape_count, err)) derived = view_build_scene(v, err);
        if (!derived) {
            memcpy(v->changes, saved, saved_count * sizeof *saved);
            v->change_count = saved_count;
            scene_release(scene);
            return false;
        }
        scene_release(scene);
        scene = derived;
        update_ms = view_ms_since(&t0);
        restart = true;
    }

    struct render_stats rs;
    struct restir_pt_stats passes;
    struct bdpt_stats bstats;
    struct restir_bdpt_stats rbstats;
    struct ssp_prior_counters prior = {0};
    struct restir_sms_stats ms;
    memset(&ms, 0, sizeof ms);
    bool ok;
    if (v->params.method == RENDER_METHOD_RESTIR_PT) {
        /* The previous frame's scene and camera are the view's current ones until the commit
         * below: temporal reuse evaluates the previous domain with them. */
        struct restir_pt_frame f = {.scene = scene, .camera = &camera, .prev_scene = v->frame ? v->scene : NULL,
                                    .prev_camera = &v->camera, .seed = v->params.seed, .frame = v->frame,
                                    .threads = v->threads};
        ok = restir_pt_render(&v->restir, &v->params.restir_pt, &f, out, &passes, err);
        if (ok) {
            rs = view_frame_stats(v, out, passes.rays_intersect, passes.rays_occluded, passes.nonfinite,
                                  passes.gbuffer_ms + passes.initial_ms + passes.temporal_ms + passes.spatial_ms +
                                      passes.shade_ms);
            if (progress) progress(progress_ctx, 1, 1);
        }
    } else if (v->params.method == RENDER_METHOD_BDPT) {
        struct bdpt_frame f = {.scene = scene, .camera = &camera, .seed = v->params.seed, .frame = v->frame,
                               .threads = v->threads};
        ok = bdpt_render(&v->bdpt, &v->params.bdpt, &f, out, &bstats, err);
        if (ok) {
            rs = view_frame_stats(v, out, bstats.rays_intersect, bstats.rays_occluded, bstats.nonfinite,
                                  bstats.light_ms + bstats.splat_ms + bstats.camera_ms);
            if (progress) progress(progress_ctx, 1, 1);
        }
    } else if (v->params.method == RENDER_METHOD_RESTIR_BDPT) {
        /* The previous scene and camera: where the caustic reservoirs' history was rendered. */
        struct restir_bdpt_frame f = {.scene = scene, .camera = &camera, .prev_scene = v->frame ? v->scene : NULL,
                                      .prev_camera = &v->camera, .seed = v->params.seed, .frame = v->frame,
                                      .threads = v->threads};
        ok = restir_bdpt_render(&v->rbdpt, &v->params.restir_bdpt, &f, out, &rbstats, err);
        if (ok) {
            rs = view_frame_stats(v, out, rbstats.rays_intersect, rbstats.rays_occluded, rbstats.rejected,
                                  rbstats.light_ms + rbstats.sort_ms + rbstats.camera_ms + rbstats.reuse_ms);
            if (progress) progress(progress_ctx, 1, 1);
        }
    } else if (v->params.method == RENDER_METHOD_RESTIR_SSS) {
        struct restir_sss_frame f = {.scene = scene, .camera = &camera, .prev_scene = v->frame ? v->scene : NULL,
                                     .prev_camera = &v->camera, .seed = v->params.seed, .frame = v->frame,
                                     .threads = v->threads};
        struct restir_sss_stats ss;
        ok = restir_sss_render(&v->sss, &v->params.restir_sss, &f, out, &ss, err);
        if (ok) {
            memset(&passes, 0, sizeof passes);
            passes.gbuffer_ms = ss.gbuffer_ms, passes.initial_ms = ss.initial_ms, passes.temporal_ms = ss.temporal_ms;
            passes.spatial_ms = ss.spatial_ms, passes.shade_ms = ss.shade_ms;
            passes.rays_intersect = ss.rays_intersect, passes.rays_occluded = ss.rays_occluded;
            passes.shifts = ss.shifts, passes.shift_failures = ss.shift_failures, passes.rejected = ss.rejected;
            passes.nonfinite = ss.nonfinite;
            rs = view_frame_stats(v, out, ss.rays_intersect, ss.rays_occluded, ss.nonfinite,
                                  ss.gbuffer_ms + ss.initial_ms + ss.temporal_ms + ss.spatial_ms + ss.shade_ms);
            if (progress) progress(progress_ctx, 1, 1);
        }
    } else if (v->params.method == RENDER_METHOD_RESTIR_SMS) {
        struct restir_sms_frame f = {.scene = scene, .camera = &camera, .prev_scene = v->frame ? v->scene : NULL,
                                     .prev_camera = &v->camera, .seed = v->params.seed, .frame = v->frame,
                                     .threads = v->threads};
        ok = restir_sms_render(&v->rsms, &v->params.restir_sms, &f, out, &ms, err);
        if (ok) {
            memset(&passes, 0, sizeof passes);
            passes.gbuffer_ms = ms.gbuffer_ms, passes.temporal_ms = ms.temporal_ms;
            /* The prior pass counts as part of the initial pass (it only serves the candidates). */
            passes.initial_ms = ms.prior_ms + ms.initial_ms;
            passes.spatial_ms = ms.spatial_ms, passes.shade_ms = ms.shade_ms;
            passes.rays_intersect = ms.rays_intersect, passes.rays_occluded = ms.rays_occluded;
            passes.shifts = ms.shifts, passes.shift_failures = ms.shift_failures, passes.rejected = ms.rejected;
            passes.nonfinite = ms.nonfinite;
            rs = view_frame_stats(v, out, ms.rays_intersect, ms.rays_occluded, ms.nonfinite,
                                  ms.gbuffer_ms + ms.prior_ms + ms.initial_ms + ms.temporal_ms + ms.spatial_ms +
                                      ms.shade_ms);
            rs.sms = ms.sms;
            prior = ms.prior;
            if (progress) progress(progress_ctx, 1, 1);
        }
    } else {
        struct pt_params p = reference_pt_defaults(v->params.width, v->params.height);
        p.spp = v->params.pt.spp;
        p.max_depth = v->params.pt.max_depth;
        p.rr_depth = v->params.pt.rr_depth;
        p.nee = v->params.pt.nee;
        struct sms_scene ss;
        if (v->params.method == RENDER_METHOD_SMS) {
            p.sms = &v->params.sms;
        } else if (v->params.method == RENDER_METHOD_SMS_SSP) {
            /* The prior pass ([SMS-SSP §4.1]) before the frame, under this frame's scene and camera. */
            struct camera cam;
            struct ray_counters prc = {0, 0};
            camera_init(&cam, &camera, v->params.width, v->params.height);
            memset(&prior, 0, sizeof prior);
            if (!sms_scene_init(scene, &ss, err)) {
                scene_release(scene);
                return false;
            }
            /* The walks kept from earlier frames describe this one while nothing moved. */
            bool still = v->frame > 0 && memcmp(&camera, &v->camera, sizeof camera) == 0 && !scene_moved(v->scene, scene);
            if (!ssp_prior_build(&v->prior, scene, &ss, &v->params.ssp, &cam, v->params.seed, v->frame, still, v->threads,
                                 &prior, &prc, err)) {
                scene_release(scene);
                return false;
            }
            p.sms = &v->params.ssp.sms;
            p.ssp = &v->params.ssp;
            p.ssp_prior = &v->prior;
        } else {
            p.subset = v->params.pt.subset;
        }
        p.seed = v->params.seed;
        p.frame = v->frame;
        p.threads = v->threads;
        p.camera = &camera;
        ok = reference_pt_render_into(scene, &p, out, &rs, progress, progress_ctx, err);
        if (ok && p.ssp) rs.render_ms += prior.ms;
    }
    if (!ok) {
        scene_release(scene);
        return false;
    }

    /* Commit: the current frame becomes the previous one. */
    scene_release(v->prev_scene);
    v->prev_scene = v->scene;
    v->scene = scene;
    v->prev_camera = v->camera;
    v->camera = camera;
    if (change && change->has_time) v->time_s = change->time_s;
    if (restart) {
        v->accum_count = 0;
        memset(v->accum.pixels, 0, (size_t)v->accum.width * v->accum.height * sizeof *v->accum.pixels);
    }
    size_t n = (size_t)out->width * out->height;
    for (size_t i = 0; i < n; i++) v->accum.pixels[i] = vec3_add(v->accum.pixels[i], out->pixels[i]);
    v->accum_count++;

    if (stats) {
        memset(stats, 0, sizeof *stats);
        stats->frame = v->frame;
        stats->time_s = v->time_s;
        stats->render = rs;
        stats->scene_update_ms = update_ms;
        stats->accumulated = v->accum_count;
        stats->has_passes = v->params.method == RENDER_METHOD_RESTIR_PT || v->params.method == RENDER_METHOD_RESTIR_SSS ||
                            v->params.method == RENDER_METHOD_RESTIR_SMS;
        if (stats->has_passes) stats->passes = passes;
        stats->has_bdpt = v->params.method == RENDER_METHOD_BDPT;
        if (stats->has_bdpt) stats->bdpt = bstats;
        stats->has_restir_bdpt = v->params.method == RENDER_METHOD_RESTIR_BDPT;
        if (stats->has_restir_bdpt) stats->restir_bdpt = rbstats;
        stats->has_sms = v->params.method == RENDER_METHOD_SMS || v->params.method == RENDER_METHOD_SMS_SSP ||
                         v->params.method == RENDER_METHOD_RESTIR_SMS;
        stats->has_prior = v->params.method == RENDER_METHOD_SMS_SSP || v->params.method == RENDER_METHOD_RESTIR_SMS;
        stats->prior = prior;
        stats->has_manifold_shift = v->params.method == RENDER_METHOD_RESTIR_SMS;
        stats->shift_newton = ms.shift_newton;
        stats->shift_not_invertible = ms.shift_not_invertible;
    }
    v->frame++;
    return true;
}

bool view_accumulated(const struct view *v, struct image *out, uint32_t *count, struct err *err)
{
    if (v->accum_count == 0) return err_set(err, ERR_INVALID, NULL, "no frame accumulated since the last change");
    if (!image_init(out, v->accum.width, v->accum.height, err)) return false;
    float inv = 1.0f / (float)v->accum_count;
    size_t n = (size_t)out->width * out->height;
    for (size_t i = 0; i < n; i++) out->pixels[i] = vec3_scale(v->accum.pixels[i], inv);
    *count = v->accum_count;
    return true;
}

uint32_t view_reservoir_bytes_per_pixel(const struct view_params *params, const struct scene *scene)
{
    switch (params->method) {
    case RENDER_METHOD_RESTIR_PT: return RESTIR_PT_RESERVOIR_BYTES;
    case RENDER_METHOD_RESTIR_SSS: return RESTIR_SSS_RESERVOIR_BYTES * restir_sss_layers(&params->restir_sss);
    case RENDER_METHOD_RESTIR_BDPT: return RESTIR_BDPT_PATH_BYTES;
    case RENDER_METHOD_RESTIR_SMS:
        return RESTIR_SMS_RESERVOIR_BYTES *
               (scene ? restir_sms_layers(&params->restir_sms, scene) : params->restir_sms.light_reservoirs);
    default: return 0;
    }
}

uint64_t view_bytes_planned(const struct view_params *params, const struct scene *scene)
{
    const uint32_t shape_count = scene->shape_count;
    /* The same buffers view_init allocates for the method (every method: frame and accumulation;
     * restir_pt: its reservoirs, G-buffers and primitive table too). */
    uint64_t pixels = (uint64_t)params->width * params->height;
    uint64_t bytes = 2 * pixels * sizeof(struct vec3) + (uint64_t)(shape_count ? shape_count : 1) * sizeof(struct view_shape_change);
    if (params->method == RENDER_METHOD_RESTIR_PT) bytes += restir_pt_bytes_planned(&params->restir_pt, params->width, params->height, shape_count);
    if (params->method == RENDER_METHOD_BDPT) bytes += bdpt_bytes_planned(&params->bdpt, params->width, params->height);
    if (params->method == RENDER_METHOD_RESTIR_BDPT)
        bytes += restir_bdpt_bytes_planned(&params->restir_bdpt, params->width, params->height);
    if (params->method == RENDER_METHOD_RESTIR_SSS) bytes += restir_sss_bytes_planned(&params->restir_sss, params->width, params->height);
    if (params->method == RENDER_METHOD_SMS_SSP) bytes += ssp_prior_bytes(params->width, params->height, params->ssp.prior_frames);
    if (params->method == RENDER_METHOD_RESTIR_SMS) bytes += restir_sms_bytes_planned(&params->restir_sms, scene, params->width, params->height);
    return bytes;
}

uint32_t view_bytes(const struct view *v, struct view_buffer_bytes out[VIEW_MAX_BUFFERS], size_t *total)
{
    uint32_t n = 0;
    out[n++] = (struct view_buffer_bytes){"frame", (size_t)v->output.width * v->output.height * sizeof *v->output.pixels};
    out[n++] = (struct view_buffer_bytes){"accumulation", (size_t)v->accum.width * v->accum.height * sizeof *v->accum.pixels};
    out[n++] = (struct view_buffer_bytes){"shape_changes", (size_t)(v->base->shape_count ? v->base->shape_count : 1) * sizeof *v->changes};
    if (v->params.method == RENDER_METHOD_RESTIR_PT) {
        out[n++] = (struct view_buffer_bytes){"reservoirs", restir_pt_reservoir_bytes(&v->restir)};
        out[n++] = (struct view_buffer_bytes){"gbuffers", restir_pt_gbuffer_bytes(&v->restir)};
        out[n++] = (struct view_buffer_bytes){"primitive_table", ((size_t)v->restir.shape_count + 1) * sizeof *v->restir.prim_first};
        if (v->restir.pair_scratch) out[n++] = (struct view_buffer_bytes){"spatial_pairs", restir_pt_pair_bytes(&v->restir)};
        out[n++] = (struct view_buffer_bytes){"primary_hits", restir_pt_hit_bytes(&v->restir)};
    }
    if (v->params.method == RENDER_METHOD_BDPT) {
        out[n++] = (struct view_buffer_bytes){"light_vertex_cache", bdpt_lvc_bytes(&v->bdpt)};
        out[n++] = (struct view_buffer_bytes){"lvc_blocks", bdpt_block_bytes(&v->bdpt)};
    }
    if (v->params.method == RENDER_METHOD_RESTIR_BDPT) {
        out[n++] = (struct view_buffer_bytes){"reservoirs", restir_bdpt_reservoir_bytes(&v->rbdpt)};
        out[n++] = (struct view_buffer_bytes){"light_traced_samples", restir_bdpt_lt_bytes(&v->rbdpt)};
        out[n++] = (struct view_buffer_bytes){"caustic_shifts", restir_bdpt_shift_bytes(&v->rbdpt)};
        out[n++] = (struct view_buffer_bytes){"pixel_buckets", restir_bdpt_bucket_bytes(&v->rbdpt)};
        out[n++] = (struct view_buffer_bytes){"light_blocks", restir_bdpt_block_bytes(&v->rbdpt)};
        if (v->rbdpt.lvc) out[n++] = (struct view_buffer_bytes){"light_vertex_cache", restir_bdpt_lvc_bytes(&v->rbdpt)};
        if (v->rbdpt.gbuf.px) out[n++] = (struct view_buffer_bytes){"gbuffer", gbuffer_bytes(&v->rbdpt.gbuf)};
        if (v->rbdpt.pair_scratch)
            out[n++] = (struct view_buffer_bytes){"spatial_pairs", restir_bdpt_pair_bytes(&v->rbdpt)};
        if (v->rbdpt.x2c) out[n++] = (struct view_buffer_bytes){"light_x2_cache", restir_bdpt_x2_bytes(&v->rbdpt)};
    }
    if (v->params.method == RENDER_METHOD_RESTIR_SSS) {
        out[n++] = (struct view_buffer_bytes){"reservoirs", restir_sss_reservoir_bytes(&v->sss)};
        out[n++] = (struct view_buffer_bytes){"gbuffers", restir_sss_gbuffer_bytes(&v->sss)};
        out[n++] = (struct view_buffer_bytes){"primary_hits", restir_sss_hit_bytes(&v->sss)};
        if (v->sss.pair_scratch) out[n++] = (struct view_buffer_bytes){"spatial_pairs", restir_sss_pair_bytes(&v->sss)};
    }
    if (v->params.method == RENDER_METHOD_SMS_SSP) out[n++] = (struct view_buffer_bytes){"prior", ssp_prior_bytes(v->output.width, v->output.height, v->prior.frames)};
    if (v->params.method == RENDER_METHOD_RESTIR_SMS) {
        out[n++] = (struct view_buffer_bytes){"reservoirs", restir_sms_reservoir_bytes(&v->rsms)};
        out[n++] = (struct view_buffer_bytes){"gbuffers", restir_sms_gbuffer_bytes(&v->rsms)};
        out[n++] = (struct view_buffer_bytes){"receivers", restir_sms_receiver_bytes(&v->rsms)};
        if (v->rsms.prior.entries) out[n++] = (struct view_buffer_bytes){"prior", restir_sms_prior_bytes(&v->rsms)};
        if (v->rsms.pair_scratch) out[n++] = (struct view_buffer_bytes){"spatial_pairs", restir_sms_pair_bytes(&v->rsms)};
    }
    size_t sum = 0;
    for (uint32_t i = 0; i < n; i++) sum += out[i].bytes;
    if (total) *total = sum;
    return n;
}

bool view_animation_change(const struct view_animation *a, double t_s, struct view_frame_change *out,
                           struct view_shape_change *shapes, struct err *err)
{
    memset(out, 0, sizeof *out);
    out->has_time = true;
    out->time_s = t_s;
    if (a->camera_key_count) {
        animation_camera_at(a->camera_keys, a->camera_key_count, a->interp, t_s, &out->camera);
        out->has_camera = true;
    }
    for (uint32_t k = 0; k < a->track_count; k++) {
        struct animation_shape_state st;
        animation_shape_at(a->tracks[k].keys, a->tracks[k].key_count, a->interp, t_s, &st);
        struct view_shape_change *c = &shapes[k];
        memset(c, 0, sizeof *c);
        c->shape = a->tracks[k].shape;
        c->has_position = st.has_position;
        c->position = st.position;
        c->has_emission = st.has_emission;
        c->emission = st.emission;
        if (st.has_transform) {
            c->has_transform = true;
            if (!xform_from_trs(&st.transform, &c->transform))
                return err_set(err, ERR_INVALID, NULL, "at t = %g s the interpolated transform overflows", t_s);
        }
    }
    out->shapes = shapes;
    out->shape_count = a->track_count;
    return true;
}
