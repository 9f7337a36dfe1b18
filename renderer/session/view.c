/* view.c — per-session persistent state and the frame driver (see view.h). */
#include "session/view.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

struct view_params view_params_defaults(const struct method_desc *method, uint32_t width, uint32_t height)
{
    struct view_params p;
    memset(&p, 0, sizeof p);
    p.method = method;
    p.width = width;
    p.height = height;
    method_profile_defaults(method, METHOD_PROFILE_REAL_TIME, p.method_params);
    return p;
}

void view_params_set_profile(struct view_params *p, enum method_profile profile)
{
    p->profile = profile;
    memset(p->method_params, 0, sizeof p->method_params);
    method_profile_defaults(p->method, profile, p->method_params);
}

/* The parameter `key` of p's method if it is of `kind`, else NULL. */
static const struct method_param *view_param(const struct view_params *p, const char *key, enum method_param_kind kind)
{
    const struct method_param *mp = method_param_find(p->method, key);
    return mp && mp->kind == kind ? mp : NULL;
}

bool view_params_get_uint(const struct view_params *p, const char *key, uint32_t *out)
{
    const struct method_param *mp = view_param(p, key, METHOD_PARAM_UINT);
    if (mp) memcpy(out, p->method_params + mp->offset, sizeof *out);
    return mp != NULL;
}

bool view_params_set_uint(struct view_params *p, const char *key, uint32_t value)
{
    const struct method_param *mp = view_param(p, key, METHOD_PARAM_UINT);
    if (mp) memcpy(p->method_params + mp->offset, &value, sizeof value);
    return mp != NULL;
}

bool view_params_set_bool(struct view_params *p, const char *key, bool value)
{
    const struct method_param *mp = view_param(p, key, METHOD_PARAM_BOOL);
    if (mp) memcpy(p->method_params + mp->offset, &value, sizeof value);
    return mp != NULL;
}

static void view_drop_history(struct view *v)
{
    scene_release(v->prev_scene);
    v->prev_scene = NULL;
    v->prev_camera = v->camera;
    v->frame = 0;
    v->accum_count = 0;
    if (v->params.method->reset) v->params.method->reset(v->state);
    if (v->accum.pixels) memset(v->accum.pixels, 0, (size_t)v->accum.width * v->accum.height * sizeof *v->accum.pixels);
}

static bool view_has_environment(const struct scene *scene)
{
    return !vec3_is_zero(scene->env_radiance);
}

/* Refuses a scene with a feature the method refuses (method.h's METHOD_NO_*), naming the
 * methods that render it. */
static bool view_scene_supported(const struct method_desc *m, const struct scene *scene, struct err *err)
{
    static const struct {
        unsigned cap;
        bool (*has)(const struct scene *scene);
        const char *what;
    } features[] = {
        {METHOD_NO_ENVIRONMENT, view_has_environment, "does not support environment light (the scene has env_radiance)"},
        {METHOD_NO_TRANSLUCENT, scene_has_translucent,
         "does not sample subsurface scattering (the scene has translucent materials)"},
    };
    for (size_t f = 0; f < sizeof features / sizeof features[0]; f++) {
        if (!(m->caps & features[f].cap) || !features[f].has(scene)) continue;
        char others[256] = "";
        size_t n = 0;
        for (uint32_t i = 0; i < method_count() && n < sizeof others; i++)
            if (!(method_at(i)->caps & features[f].cap))
                n += (size_t)snprintf(others + n, sizeof others - n, "%s%s", n ? ", " : "", method_at(i)->name);
        return err_set(err, ERR_INVALID, "/method", "%s %s; methods that do: %s", m->name, features[f].what, others);
    }
    return true;
}

/* Frees the method's state and the view's buffers (any of them may be missing). */
static void view_free(struct view *v)
{
    if (v->state) v->params.method->destroy(v->state);
    free(v->state);
    image_destroy(&v->output);
    image_destroy(&v->accum);
    free(v->changes);
}

bool view_init(struct view *v, struct scene *scene, const struct view_params *params, unsigned threads,
               struct err *err)
{
    memset(v, 0, sizeof *v);
    if (params->width == 0 || params->height == 0)
        return err_set(err, ERR_INVALID, "/width", "image size must be at least 1x1");
    const struct method_desc *m = params->method;
    if (!m->validate(params->method_params, err) || !view_scene_supported(m, scene, err)) return false;
    v->params = *params;
    if (m->state_bytes && !(v->state = calloc(1, m->state_bytes))) {
        memset(v, 0, sizeof *v);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for a view");
    }
    /* The method may resolve defaults left to the scene in the view's own copy of its params:
     * the session reports what it uses. */
    if (!m->init(v->state, scene, v->params.method_params, params->width, params->height, err)) {
        free(v->state);
        memset(v, 0, sizeof *v);
        return false;
    }
    /* Every method needs its frame and the accumulation buffer. */
    if (!image_init(&v->output, params->width, params->height, err) ||
        !image_init(&v->accum, params->width, params->height, err)) {
        view_free(v);
        memset(v, 0, sizeof *v);
        return false;
    }
    v->changes = calloc(scene->shape_count ? scene->shape_count : 1, sizeof *v->changes);
    if (!v->changes) {
        view_free(v);
        memset(v, 0, sizeof *v);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for a view");
    }
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
    view_free(v);
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

    /* The previous frame's scene and camera are the view's current ones until the commit
     * below: temporal reuse evaluates the previous domain with them. */
    const struct method_frame f = {.scene = scene, .camera = &camera, .prev_scene = v->frame ? v->scene : NULL,
                                   .prev_camera = &v->camera, .seed = v->params.seed, .frame = v->frame,
                                   .threads = v->threads};
    struct frame_stats fs;
    memset(&fs, 0, sizeof fs);
    const double cpu0 = parallel_cpu_ms();
    if (!v->params.method->render(v->state, v->params.method_params, &f, out, &fs, progress, progress_ctx, err)) {
        scene_release(scene);
        return false;
    }
    fs.render.render_cpu_ms = parallel_cpu_ms() - cpu0;

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
        fs.frame = v->frame;
        fs.time_s = v->time_s;
        fs.scene_update_ms = update_ms;
        fs.accumulated = v->accum_count;
        *stats = fs;
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
    const struct method_desc *m = params->method;
    return m->reservoir_bytes_per_pixel ? m->reservoir_bytes_per_pixel(params->method_params, scene) : 0;
}

uint64_t view_bytes_planned(const struct view_params *params, const struct scene *scene)
{
    const uint32_t shape_count = scene->shape_count;
    /* The same buffers view_init allocates: every method's frame, accumulation and shape
     * changes, and the method's own. */
    uint64_t pixels = (uint64_t)params->width * params->height;
    uint64_t bytes = 2 * pixels * sizeof(struct vec3) + (uint64_t)(shape_count ? shape_count : 1) * sizeof(struct view_shape_change);
    const struct method_desc *m = params->method;
    if (m->bytes_planned) bytes += m->bytes_planned(params->method_params, scene, params->width, params->height);
    return bytes;
}

uint32_t view_bytes(const struct view *v, struct view_buffer_bytes out[VIEW_MAX_BUFFERS], size_t *total)
{
    uint32_t n = 0;
    out[n++] = (struct view_buffer_bytes){"frame", (size_t)v->output.width * v->output.height * sizeof *v->output.pixels};
    out[n++] = (struct view_buffer_bytes){"accumulation", (size_t)v->accum.width * v->accum.height * sizeof *v->accum.pixels};
    out[n++] = (struct view_buffer_bytes){"shape_changes", (size_t)(v->base->shape_count ? v->base->shape_count : 1) * sizeof *v->changes};
    const struct method_desc *m = v->params.method;
    /* A method with more buffers than the room would be listed short (never overrun): the list
     * is a report, the memory budget counts view_bytes_planned. */
    if (m->buffers) {
        uint32_t room = VIEW_MAX_BUFFERS - n, k = m->buffers(v->state, v->params.method_params, out + n, room);
        n += k < room ? k : room;
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
