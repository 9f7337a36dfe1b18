/* api_sessions.c — sessions, frames, animation and reference jobs, and server-sent events.
 * Path segments: seg[2] scene id, seg[4] session id, seg[6] frame number / job id / name. */
#include "api.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <math.h>

#include "animate.h"
#include "image/tonemap.h"

static const char *const api_image_types[] = {"image/x-exr", "image/png", "application/json", NULL};

/* The session of the path, retained; answers 404 (not-found or scene-not-loaded) when absent. */
static struct session *api_session(struct api_call *c)
{
    struct session *s = sessions_get(c->d->sessions, c->seg[2], c->seg[4]);
    if (s) return s;
    if (api_scene_exists(c, c->seg[2]))
        api_problem(c, 404, "not-found", NULL, "scene '%s' has no session '%s'", c->seg[2], c->seg[4]);
    return NULL;
}

static void api_write_vec3(struct jsonw *w, struct vec3 v)
{
    jsonw_array_begin(w);
    jsonw_double(w, v.x);
    jsonw_double(w, v.y);
    jsonw_double(w, v.z);
    jsonw_array_end(w);
}

static void api_write_camera(struct jsonw *w, const struct camera_desc *cam)
{
    jsonw_object_begin(w);
    jsonw_key(w, "position"); api_write_vec3(w, cam->position);
    jsonw_key(w, "look_at"); api_write_vec3(w, cam->look_at);
    jsonw_key(w, "up"); api_write_vec3(w, cam->up);
    jsonw_key(w, "fov_deg"); jsonw_double(w, cam->fov_deg);
    jsonw_object_end(w);
}

static void api_write_session(struct jsonw *w, struct session *s)
{
    struct view_buffer_bytes b[VIEW_MAX_BUFFERS];
    size_t total = 0;
    uint32_t nb = view_bytes(&s->view, b, &total);
    size_t reservoir = 0;
    for (uint32_t i = 0; i < nb; i++)
        if (strncmp(b[i].name, "reservoir", 9) == 0) reservoir += b[i].bytes;
    size_t memory = session_bytes(s);
    const struct view_params *p = &s->view.params;
    pthread_mutex_lock(&s->lock);
    bool busy = s->busy;
    uint32_t frames = s->frames_done;
    struct camera_desc cam = s->camera;
    char job[24] = "";
    for (uint32_t i = 0; i < s->job_count; i++)
        if (s->jobs[i]->kind == JOB_ANIMATION && s->jobs[i]->status <= JOB_RUNNING) snprintf(job, sizeof job, "%s", s->jobs[i]->id);
    pthread_mutex_unlock(&s->lock);
    char href[192];
    snprintf(href, sizeof href, "/v1/scenes/%s/sessions/%s", s->scene_id, s->id);

    jsonw_object_begin(w);
    jsonw_key(w, "id"); jsonw_string(w, s->id);
    jsonw_key(w, "scene"); jsonw_string(w, s->scene_id);
    jsonw_key(w, "method"); jsonw_string(w, p->method->name);
    jsonw_key(w, "width"); jsonw_uint(w, p->width);
    jsonw_key(w, "height"); jsonw_uint(w, p->height);
    jsonw_key(w, "seed"); jsonw_uint(w, p->seed);
    jsonw_key(w, "profile"); jsonw_string(w, method_profile_names[p->profile]);
    jsonw_key(w, "params");
    protocol_write_method_params(w, p->method, p->method_params);
    jsonw_key(w, "frames_rendered"); jsonw_uint(w, frames);
    jsonw_key(w, "busy"); jsonw_bool(w, busy);
    jsonw_key(w, "job");
    if (job[0]) jsonw_string(w, job); else jsonw_null(w);
    jsonw_key(w, "camera"); api_write_camera(w, &cam);
    jsonw_key(w, "reservoir_bytes"); jsonw_uint(w, reservoir);
    jsonw_key(w, "reservoir_bytes_per_pixel");
    jsonw_uint(w, view_reservoir_bytes_per_pixel(p, NULL));  /* the view resolved light_reservoirs */
    jsonw_key(w, "buffers");
    jsonw_object_begin(w);
    for (uint32_t i = 0; i < nb; i++) {
        jsonw_key(w, b[i].name);
        jsonw_uint(w, b[i].bytes);
    }
    jsonw_object_end(w);
    jsonw_key(w, "memory_bytes"); jsonw_uint(w, memory);
    jsonw_key(w, "reserved_bytes"); jsonw_uint(w, s->budget_bytes);
    jsonw_key(w, "frames_kept"); jsonw_uint(w, s->frames_kept);
    jsonw_key(w, "href"); jsonw_string(w, href);
    jsonw_object_end(w);
}

/* Admits a session: refuses one larger than max_session_bytes (ERR_LIMIT at "", the size
 * depends on width and height together) and reserves its planned bytes from the memory budget
 * (ERR_BUSY, *budget_full set) before anything is allocated; then creates it. */
static struct session *api_session_admit(struct daemon *d, const char *scene_id, const char *id, struct scene *scene,
                                         const struct view_params *params, bool *budget_full, struct err *e)
{
    *budget_full = false;
    uint64_t planned = session_bytes_planned(params, scene, d->cfg.frames_kept);
    if (planned > d->cfg.max_session_bytes) {
        /* A method whose buffers grow with the scene says so, and how to ask for less. */
        char hint[128] = "";
        if (params->method->size_hint) params->method->size_hint(params->method_params, scene, hint, sizeof hint);
        err_set(e, ERR_LIMIT, "", "a %ux%u session holds up to %llu bytes (its buffers and %u kept frames), more than "
                "max_session_bytes (%llu)%s", params->width, params->height, (unsigned long long)planned,
                d->cfg.frames_kept, (unsigned long long)d->cfg.max_session_bytes, hint);
        return NULL;
    }
    if (!budget_reserve(&d->budget, BUDGET_SESSIONS, planned, e)) {
        *budget_full = true;
        return NULL;
    }
    return sessions_create(d->sessions, scene_id, id, scene, params, d->cfg.frames_kept, d->cfg.threads, &d->budget,
                           planned, e);
}

void api_sessions_post(struct api_call *c)
{
    if (!api_require_json(c)) return;
    struct scene *scene = registry_acquire(c->d->registry, c->seg[2]);
    if (!scene) {
        api_scene_exists(c, c->seg[2]);
        return;
    }
    struct view_params params;
    struct err e = {0};
    if (!protocol_parse_session_create(c->req->body, c->req->body_len, &c->d->cfg.limits, &params, &e)) {
        scene_release(scene);
        api_error(c, &e);
        return;
    }
    if (!api_check_work(c, api_frame_samples(&params), "/params/spp", "a frame of this session")) {
        scene_release(scene);
        return;
    }
    if (!registry_session_added(c->d->registry, c->seg[2], &e)) {
        scene_release(scene);
        api_scene_exists(c, c->seg[2]);
        return;
    }
    bool budget_full;
    struct session *s = api_session_admit(c->d, c->seg[2], NULL, scene, &params, &budget_full, &e);
    scene_release(scene);
    if (!s) {
        registry_session_removed(c->d->registry, c->seg[2]);
        if (budget_full) api_budget_error(c, &e);
        else if (e.code == ERR_BUSY) api_problem_limit(c, 429, "too-many-sessions", NULL, c->d->cfg.max_sessions, "%s", e.message);
        else if (e.code == ERR_LIMIT) api_problem_limit(c, 422, "limit-exceeded", "", (double)c->d->cfg.max_session_bytes, "%s", e.message);
        else api_error(c, &e);
        return;
    }
    struct jsonw w;
    jsonw_init(&w);
    api_write_session(&w, s);
    http_response_header(c->resp, "Location", "/v1/scenes/%s/sessions/%s", s->scene_id, s->id);
    session_release(s);
    api_json(c, 201, &w);
}

void api_sessions_list(struct api_call *c)
{
    if (!api_scene_exists(c, c->seg[2])) return;
    struct session *list[1024];
    uint32_t n = sessions_list(c->d->sessions, c->seg[2], list, 1024);
    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "sessions");
    jsonw_array_begin(&w);
    for (uint32_t i = 0; i < n; i++) {
        api_write_session(&w, list[i]);
        session_release(list[i]);
    }
    jsonw_array_end(&w);
    jsonw_object_end(&w);
    api_json(c, 200, &w);
}

void api_session_get(struct api_call *c)
{
    struct session *s = api_session(c);
    if (!s) return;
    struct jsonw w;
    jsonw_init(&w);
    api_write_session(&w, s);
    session_release(s);
    api_json(c, 200, &w);
}

void api_session_delete(struct api_call *c)
{
    if (!sessions_remove(c->d->sessions, c->seg[2], c->seg[4])) {
        if (api_scene_exists(c, c->seg[2]))
            api_problem(c, 404, "not-found", NULL, "scene '%s' has no session '%s'", c->seg[2], c->seg[4]);
        return;
    }
    registry_session_removed(c->d->registry, c->seg[2]);
    c->resp->status = 204;
}

void api_session_reset(struct api_call *c)
{
    if (!api_require_json(c)) return;
    if (c->req->body_len > 0) {
        /* reset takes no parameters; accept only an empty object so typos are not ignored */
        struct protocol_frame_request fr;
        struct err e = {0};
        if (!protocol_parse_frame_request(c->req->body, c->req->body_len, &fr, &e)) {
            api_error(c, &e);
            return;
        }
        if (fr.camera.has_position || fr.camera.has_look_at || fr.camera.has_up || fr.camera.has_fov_deg ||
            fr.shape_count || fr.has_time) {
            api_problem(c, 422, "invalid-field", "", "reset takes no members; send an empty body");
            return;
        }
    }
    struct session *s = api_session(c);
    if (!s) return;
    struct err e = {0};
    if (!session_claim(s, &e)) {
        session_release(s);
        api_error(c, &e);
        return;
    }
    session_reset(s);
    session_unclaim(s);
    session_release(s);
    c->resp->status = 204;
}

/* Completes a partial camera over `base`; answers 422 at `ptr` when it cannot form an image. */
static bool api_complete_camera(struct api_call *c, const struct protocol_camera *pc, const struct camera_desc *base,
                                const char *ptr, struct camera_desc *out)
{
    const char *why = NULL;
    if (animate_complete_camera(pc, base, out, &why)) return true;
    api_problem(c, 422, "invalid-field", ptr, "%s", why);
    return false;
}

/* Reference named by ?reference= (NULL when absent); answers and returns false on error. */
static bool api_query_reference(struct api_call *c, const struct view_params *p, struct ref_image **out)
{
    *out = NULL;
    const char *name = http_query(c->req, "reference");
    if (!name) return true;
    if (!protocol_valid_id(name, strlen(name))) {
        api_problem(c, 400, "bad-query", "?reference", "'%s' is not a valid reference name", name);
        return false;
    }
    struct ref_image *r = refstore_get(c->d->refs, c->seg[2], name);
    if (!r) {
        api_problem(c, 404, "not-found", "?reference", "scene '%s' has no reference '%s'", c->seg[2], name);
        return false;
    }
    if (r->img.width != p->width || r->img.height != p->height) {
        api_problem(c, 422, "reference-mismatch", "?reference", "reference '%s' is %ux%u, the session renders %ux%u", name,
                    r->img.width, r->img.height, p->width, p->height);
        ref_image_release(r);
        return false;
    }
    *out = r;
    return true;
}

struct api_frame_json {
    struct session *s;
    uint32_t n;
    const struct frame_stats *stats;
    const struct image *img;
    struct ref_image *ref;
};

static void api_frame_json_fn(struct api_call *c, struct jsonw *w, void *ctx)
{
    (void)c;
    struct api_frame_json *f = ctx;
    const struct render_stats *r = &f->stats->render;
    double rays = (double)(r->rays_intersect + r->rays_occluded);
    char href[256];
    snprintf(href, sizeof href, "/v1/scenes/%s/sessions/%s/frames/%u", f->s->scene_id, f->s->id, f->n);
    jsonw_object_begin(w);
    jsonw_key(w, "frame"); jsonw_uint(w, f->n);
    jsonw_key(w, "time_s"); jsonw_double(w, f->stats->time_s);
    jsonw_key(w, "render_ms"); jsonw_double(w, r->render_ms);
    jsonw_key(w, "render_cpu_ms"); jsonw_double(w, r->render_cpu_ms);
    jsonw_key(w, "scene_update_ms"); jsonw_double(w, f->stats->scene_update_ms);
    jsonw_key(w, "rays"); jsonw_uint(w, (uint64_t)rays);
    jsonw_key(w, "rays_per_s"); jsonw_double(w, r->render_ms > 0 ? rays / (r->render_ms * 1e-3) : 0.0);
    jsonw_key(w, "samples"); jsonw_uint(w, r->samples);
    jsonw_key(w, "nonfinite"); jsonw_uint(w, r->nonfinite);
    jsonw_key(w, "threads"); jsonw_uint(w, r->threads);
    jsonw_key(w, "accumulated"); jsonw_uint(w, f->stats->accumulated);
    protocol_write_method_counters(w, f->s->view.params.method, f->stats);
    if (f->s->view.params.method->caps & METHOD_MANIFOLD_COUNTERS) {
        /* [SMS-SSP Table 1], manifold sampling columns, for this frame. */
        const struct sms_counters *sc = &r->sms;
        double n = (double)sc->samples, sol = (double)sc->solutions;
        jsonw_key(w, "sms");
        jsonw_object_begin(w);
        jsonw_key(w, "samples"); jsonw_uint(w, sc->samples);
        jsonw_key(w, "solutions"); jsonw_uint(w, sc->solutions);
        jsonw_key(w, "newton_sample"); jsonw_uint(w, sc->newton_sample);
        jsonw_key(w, "trials"); jsonw_uint(w, sc->trials);
        jsonw_key(w, "newton_trials"); jsonw_uint(w, sc->newton_trials);
        jsonw_key(w, "capped"); jsonw_uint(w, sc->capped);
        jsonw_key(w, "with_prior"); jsonw_uint(w, sc->with_prior);
        jsonw_key(w, "sample_ms"); jsonw_double(w, sc->sample_ms);
        jsonw_key(w, "success_rate"); jsonw_double(w, n > 0 ? sol / n : 0.0);
        jsonw_key(w, "newtons_per_sample"); jsonw_double(w, n > 0 ? (double)sc->newton_sample / n : 0.0);
        jsonw_key(w, "bernoulli_per_solution"); jsonw_double(w, sol > 0 ? (double)sc->trials / sol : 0.0);
        jsonw_key(w, "newtons_per_solution");
        jsonw_double(w, sol > 0 ? (double)(sc->newton_sample + sc->newton_trials) / sol : 0.0);
        jsonw_object_end(w);
    }
    jsonw_key(w, "href"); jsonw_string(w, href);
    if (f->ref) {
        struct metrics m;
        struct err e;
        jsonw_key(w, "metrics");
        if (metrics_compare(f->img, &f->ref->img, &m, &e)) api_write_metrics(w, f->ref->name, &m);
        else jsonw_null(w);
    }
    jsonw_object_end(w);
}

static void api_frame_etag(char *out, size_t size, struct session *s, uint32_t epoch, uint32_t n, const char *type,
                           struct api_call *c)
{
    const char *px = http_query(c->req, "pixel");
    const char *ex = http_query(c->req, "exposure");
    const char *tm = http_query(c->req, "tonemap");
    const char *ref = http_query(c->req, "reference");
    char variant[160];
    const char *cz = http_query(c->req, "compression");
    enum exrio_compression comp = API_EXR_COMPRESSION;
    if (cz) api_exr_compression(cz, &comp);  /* checked by api_check_image_query */
    if (strcmp(type, "image/x-exr") == 0)
        snprintf(variant, sizeof variant, "exr-%s-%s", px ? px : "float", exrio_compression_name(comp));
    else if (strcmp(type, "image/png") == 0) snprintf(variant, sizeof variant, "png-%s-%s", ex ? ex : "0", tm ? tm : "clamp");
    else snprintf(variant, sizeof variant, "json-%s", ref ? ref : "");
    snprintf(out, size, "\"%s-%u-%u-%s\"", s->id, epoch, n, variant);
}

void api_frames_post(struct api_call *c)
{
    if (!api_require_json(c)) return;
    struct protocol_frame_request *fr = malloc(sizeof *fr);
    if (!fr) {
        api_problem(c, 503, "busy", NULL, "out of memory");
        return;
    }
    struct err e = {0};
    if (!protocol_parse_frame_request(c->req->body, c->req->body_len, fr, &e)) {
        free(fr);
        api_error(c, &e);
        return;
    }
    struct session *s = api_session(c);
    if (!s) {
        free(fr);
        return;
    }
    const char *type = api_negotiate(c, api_image_types);
    struct ref_image *ref = NULL;
    if (!type || !api_check_image_query(c) || !api_query_reference(c, &s->view.params, &ref)) {
        session_release(s);
        free(fr);
        return;
    }
    if (!session_claim(s, &e)) {
        api_error(c, &e);
        goto out;
    }
    /* Translate the request against the session's state (stable while claimed). */
    struct view_frame_change change = {.has_time = fr->has_time, .time_s = fr->time_s};
    struct view_shape_change shapes[PROTOCOL_MAX_SHAPE_CHANGES];
    bool ok = true;
    const struct protocol_camera *pc = &fr->camera;
    if (pc->has_position || pc->has_look_at || pc->has_up || pc->has_fov_deg) {
        change.has_camera = true;
        ok = api_complete_camera(c, pc, &s->view.camera, "/camera", &change.camera);
    }
    for (uint32_t i = 0; ok && i < fr->shape_count; i++) {
        const struct protocol_shape_change *sc = &fr->shapes[i];
        char ptr[160];
        json_pointer_key(ptr, sizeof ptr, "/lights", sc->name);
        int idx = scene_find_shape(s->view.base, sc->name);
        if (idx < 0) {
            api_problem(c, 422, "invalid-field", ptr, "scene '%s' has no shape named '%s'", s->scene_id, sc->name);
            ok = false;
            break;
        }
        struct view_shape_change *vc = &shapes[i];
        memset(vc, 0, sizeof *vc);
        vc->shape = (uint32_t)idx;
        vc->has_position = sc->state.has_position;
        vc->position = sc->state.position;
        vc->has_emission = sc->state.has_emission;
        vc->emission = sc->state.emission;
        if (sc->state.has_transform) {
            vc->has_transform = true;
            if (!xform_from_trs(&sc->state.transform, &vc->transform)) {
                char tp[192];
                snprintf(tp, sizeof tp, "%s/transform", ptr);
                api_problem(c, 422, "invalid-field", tp, "the transform overflows the 32-bit float range");
                ok = false;
            }
        }
    }
    change.shapes = shapes;
    change.shape_count = fr->shape_count;
    uint32_t n = 0;
    struct frame_stats stats;
    if (ok) {
        ok = session_render(s, &c->d->gate, true, &change, NULL, &n, &stats, api_client_gone, c, &e);
        if (ok) prom_observe_frame(&c->d->prom, stats.render.render_ms * 1e-3);
        else api_error(c, &e);
    }
    uint32_t epoch = s->epoch;
    session_unclaim(s);
    if (ok) {
        struct image img;
        if (!session_frame_copy(s, n, &img, NULL, &e)) {
            api_error(c, &e);
            goto out;
        }
        char etag[256];
        api_frame_etag(etag, sizeof etag, s, epoch, n, type, c);
        http_response_header(c->resp, "X-Frame", "%u", n);
        http_response_header(c->resp, "X-Render-Ms", "%.3f", stats.render.render_ms);
        http_response_header(c->resp, "Content-Location", "/v1/scenes/%s/sessions/%s/frames/%u", s->scene_id, s->id, n);
        http_response_header(c->resp, "ETag", "%s", etag);
        struct api_frame_json fj = {s, n, &stats, &img, ref};
        api_send_image(c, type, &img, NULL, api_frame_json_fn, &fj);
        image_destroy(&img);
    }
out:
    ref_image_release(ref);
    session_release(s);
    free(fr);
}

/* Resolves the frame segment ("latest" or a number); answers 404 when there is none yet. */
static bool api_frame_number(struct api_call *c, struct session *s, uint32_t *n)
{
    pthread_mutex_lock(&s->lock);
    uint32_t frames = s->frames_done;
    pthread_mutex_unlock(&s->lock);
    if (strcmp(c->seg[6], "latest") == 0) {
        if (frames == 0) {
            api_problem(c, 404, "not-found", NULL, "the session has not rendered a frame yet");
            return false;
        }
        *n = frames - 1;
        return true;
    }
    *n = (uint32_t)strtoul(c->seg[6], NULL, 10);
    return true;
}

static bool api_frame_fetch(struct api_call *c, struct session *s, uint32_t n, struct image *img, struct frame_stats *st)
{
    struct err e = {0};
    if (session_frame_copy(s, n, img, st, &e)) return true;
    if (e.code == ERR_LIMIT) api_problem(c, 410, "frame-evicted", NULL, "%s", e.message);
    else api_error(c, &e);
    return false;
}

void api_frame_get(struct api_call *c)
{
    struct session *s = api_session(c);
    if (!s) return;
    uint32_t n;
    if (!api_frame_number(c, s, &n)) goto out;
    if (strcmp(c->seg[6], "latest") == 0) {
        /* The query (exposure, tonemap, pixel, reference) goes along with the redirect. */
        char query[256];
        http_query_string(c->req, query, sizeof query);
        c->resp->status = 303;
        http_response_header(c->resp, "Location", "/v1/scenes/%s/sessions/%s/frames/%u%s", s->scene_id, s->id, n, query);
        http_response_header(c->resp, "Cache-Control", "no-store");
        goto out;
    }
    const char *type = api_negotiate(c, api_image_types);
    struct ref_image *ref = NULL;
    if (!type || !api_check_image_query(c) || !api_query_reference(c, &s->view.params, &ref)) goto out;
    struct image img;
    struct frame_stats st;
    if (api_frame_fetch(c, s, n, &img, &st)) {
        char etag[256];
        pthread_mutex_lock(&s->lock);
        uint32_t epoch = s->epoch;
        pthread_mutex_unlock(&s->lock);
        api_frame_etag(etag, sizeof etag, s, epoch, n, type, c);
        http_response_header(c->resp, "X-Frame", "%u", n);
        struct api_frame_json fj = {s, n, &st, &img, ref};
        api_send_image(c, type, &img, etag, api_frame_json_fn, &fj);
        image_destroy(&img);
    }
    ref_image_release(ref);
out:
    session_release(s);
}

/* ?reference= is required for these two. */
static bool api_require_reference(struct api_call *c, struct session *s, struct ref_image **ref)
{
    if (!http_query(c->req, "reference")) {
        api_problem(c, 400, "bad-query", "?reference", "name the reference to compare with: ?reference=NAME");
        return false;
    }
    return api_query_reference(c, &s->view.params, ref);
}

void api_frame_metrics(struct api_call *c)
{
    struct session *s = api_session(c);
    if (!s) return;
    struct ref_image *ref = NULL;
    uint32_t n;
    struct image img;
    if (api_frame_number(c, s, &n) && api_require_reference(c, s, &ref) && api_frame_fetch(c, s, n, &img, NULL)) {
        struct metrics m;
        struct err e = {0};
        if (metrics_compare(&img, &ref->img, &m, &e)) {
            struct jsonw w;
            jsonw_init(&w);
            api_write_metrics(&w, ref->name, &m);
            api_json(c, 200, &w);
        } else {
            api_error(c, &e);
        }
        image_destroy(&img);
    }
    ref_image_release(ref);
    session_release(s);
}

void api_frame_error_png(struct api_call *c)
{
    struct session *s = api_session(c);
    if (!s) return;
    struct ref_image *ref = NULL;
    uint32_t n;
    struct image img;
    const char *sc = http_query(c->req, "scale");
    double scale = 0.0;
    char *end = NULL;
    if (sc) {
        scale = strtod(sc, &end);
        if (*end || !(scale > 0.0) || !isfinite(scale)) {
            api_problem(c, 400, "bad-query", "?scale", "scale must be a positive number, got '%s'", sc);
            session_release(s);
            return;
        }
    }
    if (api_frame_number(c, s, &n) && api_require_reference(c, s, &ref) && api_frame_fetch(c, s, n, &img, NULL)) {
        unsigned char *png = NULL;
        size_t size = 0;
        float used = 0.0f;
        struct err e = {0};
        if (tonemap_error_png(&img, &ref->img, (float)scale, &used, &png, &size, &e)) {
            c->resp->status = 200;
            c->resp->content_type = "image/png";
            c->resp->body = (char *)png;
            c->resp->body_len = size;
            http_response_header(c->resp, "X-Error-Scale", "%.9g", (double)used);
        } else {
            api_error(c, &e);
        }
        image_destroy(&img);
    }
    ref_image_release(ref);
    session_release(s);
}

struct api_accum_json { uint32_t count; };

static void api_accum_json_fn(struct api_call *c, struct jsonw *w, void *ctx)
{
    (void)c;
    jsonw_object_begin(w);
    jsonw_key(w, "frames");
    jsonw_uint(w, ((struct api_accum_json *)ctx)->count);
    jsonw_object_end(w);
}

void api_accumulation_get(struct api_call *c)
{
    struct session *s = api_session(c);
    if (!s) return;
    const char *type = api_negotiate(c, api_image_types);
    struct err e = {0};
    if (type && api_check_image_query(c)) {
        /* The accumulation buffer belongs to the frame in progress: read it between frames. */
        if (!session_claim(s, &e)) {
            api_error(c, &e);
        } else {
            struct image img;
            uint32_t count = 0;
            bool ok = view_accumulated(&s->view, &img, &count, &e);
            session_unclaim(s);
            if (!ok) {
                if (e.code == ERR_INVALID) api_problem(c, 404, "not-found", NULL, "%s", e.message);
                else api_error(c, &e);
            } else {
                struct api_accum_json ctx = {count};
                http_response_header(c->resp, "X-Accumulated-Frames", "%u", count);
                api_send_image(c, type, &img, NULL, api_accum_json_fn, &ctx);
                image_destroy(&img);
            }
        }
    }
    session_release(s);
}

/* ---- jobs ---- */

static const char *api_job_status(enum job_status st)
{
    static const char *const names[] = {"queued", "running", "done", "cancelled", "failed"};
    return names[st];
}

/* Call with s->lock held. */
static void api_write_job(struct jsonw *w, struct session *s, const struct job *j)
{
    char base[192];
    snprintf(base, sizeof base, "/v1/scenes/%s/sessions/%s", s->scene_id, s->id);
    /* The job's own path is "location" (as the Location of its POST): "href" of a reference
     * job has long named the reference it makes. */
    char location[256];
    snprintf(location, sizeof location, "%s/renders/%s", base, j->id);
    jsonw_object_begin(w);
    jsonw_key(w, "id"); jsonw_string(w, j->id);
    jsonw_key(w, "location"); jsonw_string(w, location);
    jsonw_key(w, "kind"); jsonw_string(w, j->kind == JOB_ANIMATION ? "animation" : "reference");
    jsonw_key(w, "status"); jsonw_string(w, api_job_status(j->status));
    jsonw_key(w, "progress");
    jsonw_object_begin(w);
    jsonw_key(w, "frames_done"); jsonw_uint(w, j->frames_done);
    jsonw_key(w, "frames_total"); jsonw_uint(w, j->frames_total);
    jsonw_object_end(w);
    /* The session keeps only its last frames_kept frames (and none after a reset): a job's
     * frames still kept are the newest of them, and only those are offered. */
    uint32_t first_kept = j->frames_done;
    if (j->kind == JOB_ANIMATION)
        while (first_kept > 0 && session_frame_kept_locked(s, j->epoch, j->frames[first_kept - 1])) first_kept--;
    jsonw_key(w, "frames");
    jsonw_array_begin(w);
    for (uint32_t i = first_kept; i < j->frames_done; i++) {
        char href[256];
        snprintf(href, sizeof href, "%s/frames/%u", base, j->frames[i]);
        jsonw_string(w, href);
    }
    jsonw_array_end(w);
    jsonw_key(w, "frames_kept");
    if (first_kept < j->frames_done) {
        jsonw_array_begin(w);
        jsonw_uint(w, j->frames[first_kept]);
        jsonw_uint(w, j->frames[j->frames_done - 1]);
        jsonw_array_end(w);
    } else {
        jsonw_null(w);
    }
    jsonw_key(w, "frames_evicted"); jsonw_uint(w, j->kind == JOB_ANIMATION ? first_kept : 0);
    jsonw_key(w, "reference");
    if (j->ref_name[0]) jsonw_string(w, j->ref_name);
    else jsonw_null(w);
    if (j->kind == JOB_REFERENCE) {
        char href[256];
        snprintf(href, sizeof href, "/v1/scenes/%s/references/%s", s->scene_id, j->ref_name);
        jsonw_key(w, "spp"); jsonw_uint(w, j->ref_spp);
        jsonw_key(w, "method"); jsonw_string(w, protocol_reference_method_name(j->ref_method));
        jsonw_key(w, "href"); jsonw_string(w, href);
    }
    jsonw_key(w, "error");
    if (j->status == JOB_FAILED) {
        const struct protocol_problem p = {.status = j->error_status, .slug = j->error_slug,
                                           .title = protocol_problem_title(j->error_slug),
                                           .detail = j->error.message, .instance = location};
        jsonw_object_begin(w);
        protocol_problem_members(w, &p);
        jsonw_object_end(w);
    } else {
        jsonw_null(w);
    }
    jsonw_object_end(w);
}

/* The 202 of a job's POST: the job object and its Location, written while the job can be read
 * (api_job_accepted_write_locked) and sent later (api_job_accepted_send), when nothing of the
 * job is read any more. */
struct api_job_accepted {
    struct jsonw body;
    char location[256];
};

/* Call with s->lock held: the job is read whole, and cannot be forgotten meanwhile. */
static void api_job_accepted_write_locked(struct session *s, const struct job *j, struct api_job_accepted *a)
{
    jsonw_init(&a->body);
    api_write_job(&a->body, s, j);
    snprintf(a->location, sizeof a->location, "/v1/scenes/%s/sessions/%s/renders/%s", s->scene_id, s->id, j->id);
}

static void api_job_accepted_send(struct api_call *c, struct api_job_accepted *a)
{
    http_response_header(c->resp, "Location", "%s", a->location);
    api_json(c, 202, &a->body);
}

/* Queues job j, just added to the session (api_job_add), and answers 202 with it; when the
 * queue refuses it, answers 429 and returns false, and the caller forgets j. The answer is
 * written before j is queued, while j is this request's alone: from jobs_submit on, a worker
 * may run it to its end and let go of it at once, and the session may then forget (free) it
 * to make room for another job, so nothing of j is read after. It shows the job queued, as it
 * is when the POST answers. */
static bool api_job_submit(struct api_call *c, struct session *s, struct job *j)
{
    struct api_job_accepted a;
    pthread_mutex_lock(&s->lock);
    api_job_accepted_write_locked(s, j, &a);
    pthread_mutex_unlock(&s->lock);
    struct err e = {0};
    if (!jobs_submit(c->d->jobs, j, &e)) {
        jsonw_destroy(&a.body);
        api_problem(c, 429, "queue-full", NULL, "%s", e.message);
        return false;
    }
    api_job_accepted_send(c, &a);
    return true;
}

void api_renders_list(struct api_call *c)
{
    struct session *s = api_session(c);
    if (!s) return;
    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "renders");
    jsonw_array_begin(&w);
    pthread_mutex_lock(&s->lock);
    for (uint32_t i = 0; i < s->job_count; i++) api_write_job(&w, s, s->jobs[i]);
    pthread_mutex_unlock(&s->lock);
    jsonw_array_end(&w);
    jsonw_object_end(&w);
    session_release(s);
    api_json(c, 200, &w);
}

/* What a keyed job request asks for: its kind, the name in its path (a reference's) and its
 * body, as FNV-1a, so a retry can be told from a different request under the same key. */
static uint64_t api_request_hash(enum job_kind kind, const char *name, const char *body, size_t len)
{
    uint64_t h = 1469598103934665603ull;
    const unsigned char k = (unsigned char)kind;
    const struct { const void *p; size_t n; } parts[] = {{&k, 1}, {name, strlen(name) + 1}, {body ? body : "", body ? len : 0}};
    for (size_t i = 0; i < sizeof parts / sizeof parts[0]; i++)
        for (size_t b = 0; b < parts[i].n; b++) h = (h ^ ((const unsigned char *)parts[i].p)[b]) * 1099511628211ull;
    return h;
}

/* A POST that carries an Idempotency-Key already used on this session: the same request gets
 * the job it made the first time (202 again, nothing new is rendered), another one a 409.
 * Returns true when it answered. */
static bool api_job_replay(struct api_call *c, struct session *s, const char *key, uint64_t hash)
{
    if (!key) return false;
    pthread_mutex_lock(&s->lock);
    struct job *prev = session_job_find_key(s, key);
    bool same = prev && prev->request_hash == hash;
    struct api_job_accepted a;
    if (same) api_job_accepted_write_locked(s, prev, &a);
    char id[24] = "";
    if (prev) snprintf(id, sizeof id, "%s", prev->id);
    bool other = prev && prev->request_hash != hash;
    pthread_mutex_unlock(&s->lock);
    if (same) api_job_accepted_send(c, &a);
    if (other)
        api_problem(c, 409, "conflict", "Idempotency-Key",
                    "Idempotency-Key '%s' was sent with another request, which made job '%s'; use a new key", key, id);
    return prev != NULL;
}

/* Adds j to the session, or answers for the job a request under the same key added meanwhile:
 * requests sent at once with one key all pass the first api_job_replay, and session_job_add
 * lets one of them add its job. (A job found there whose submission then failed is gone again
 * when the replay looks: the loop adds j after all.) false when j was not added: *answered
 * tells whether a replay answered, else *e says why. */
static bool api_job_add(struct api_call *c, struct session *s, struct job *j, bool claim, bool *answered,
                        struct err *e)
{
    for (;;) {
        bool exists;
        if (session_job_add(s, j, claim, &exists, e)) return true;
        *answered = exists && api_job_replay(c, s, j->idempotency_key, j->request_hash);
        if (!exists || *answered) return false;
    }
}

/* Idempotency-Key: NULL when absent; answers 400 and returns false when malformed. */
static bool api_idempotency_key(struct api_call *c, const char **key)
{
    *key = http_header(c->req, "Idempotency-Key");
    if (*key && !protocol_valid_id(*key, strlen(*key))) {
        api_problem(c, 400, "bad-header", "Idempotency-Key", "Idempotency-Key must match [A-Za-z0-9_-]{1,64}");
        return false;
    }
    return true;
}

void api_renders_post(struct api_call *c)
{
    if (!api_require_json(c)) return;
    const char *key;
    if (!api_idempotency_key(c, &key)) return;
    struct protocol_render_request rq;
    struct err e = {0};
    if (!protocol_parse_render_request(c->req->body, c->req->body_len, &c->d->cfg.limits, &rq, &e)) {
        protocol_render_request_destroy(&rq);
        api_error(c, &e);
        return;
    }
    struct session *s = api_session(c);
    if (!s) {
        protocol_render_request_destroy(&rq);
        return;
    }
    uint64_t hash = api_request_hash(JOB_ANIMATION, "", c->req->body, c->req->body_len);
    if (api_job_replay(c, s, key, hash)) goto out;
    struct ref_image *ref = NULL;
    if (rq.reference[0]) {
        ref = refstore_get(c->d->refs, s->scene_id, rq.reference);
        if (!ref) {
            api_problem(c, 422, "invalid-field", "/reference", "scene '%s' has no reference '%s'", s->scene_id, rq.reference);
            goto out;
        }
        if (ref->img.width != s->view.params.width || ref->img.height != s->view.params.height) {
            api_problem(c, 422, "reference-mismatch", "/reference", "reference '%s' is %ux%u, the session renders %ux%u",
                        rq.reference, ref->img.width, ref->img.height, s->view.params.width, s->view.params.height);
            ref_image_release(ref);
            goto out;
        }
    }
    /* Filled in before it is added: a request under the same key may show it from then on. */
    struct job *j = job_new(s, JOB_ANIMATION, key, hash, &e);
    if (!j) {
        ref_image_release(ref);
        api_error(c, &e);
        goto out;
    }
    j->reference = ref;
    if (ref) snprintf(j->ref_name, sizeof j->ref_name, "%s", ref->name);
    j->fps = rq.fps;
    j->frames_total = rq.frames;
    j->frames = calloc(rq.frames, sizeof *j->frames);
    j->rows = calloc(rq.frames, sizeof *j->rows);
    bool answered = false;
    if (!j->frames || !j->rows || !api_job_add(c, s, j, true, &answered, &e)) {
        if (!j->frames || !j->rows) api_problem(c, 503, "busy", NULL, "out of memory for the job");
        else if (!answered) api_error(c, &e);
        job_destroy(j);
        goto out;
    }
    /* The session's camera is stable while it is claimed: it is where the animation starts. */
    bool ok = animate_resolve(&rq, s->view.base, &s->view.camera, &j->anim, &e);
    if (!ok) {
        if (e.code == ERR_NOMEM) api_error(c, &e);
        else api_problem(c, 422, "invalid-field", e.where, "%s", e.message);
    }
    if (!ok || !api_job_submit(c, s, j)) {
        session_job_forget(s, j);
        session_unclaim(s);
    }
out:
    protocol_render_request_destroy(&rq);
    session_release(s);
}

/* Runs use() on job seg[6] of the session under the session lock (session_job_use), or answers
 * 404 and returns false when the session has no such job. */
static bool api_job_use(struct api_call *c, struct session *s,
                        void (*use)(struct session *s, struct job *j, void *ctx), void *ctx)
{
    if (session_job_use(s, c->seg[6], use, ctx)) return true;
    api_problem(c, 404, "not-found", NULL, "session '%s' has no job '%s'", s->id, c->seg[6]);
    return false;
}

/* session_job_use callbacks: the job object into the writer `ctx` (initialised here); the same
 * after asking the job to stop. */
static void api_job_write(struct session *s, struct job *j, void *ctx)
{
    jsonw_init(ctx);
    api_write_job(ctx, s, j);
}

static void api_job_cancel(struct session *s, struct job *j, void *ctx)
{
    atomic_store(&j->cancel, true);
    api_job_write(s, j, ctx);
}

void api_render_get(struct api_call *c)
{
    struct session *s = api_session(c);
    if (!s) return;
    struct jsonw w;
    if (api_job_use(c, s, api_job_write, &w)) api_json(c, 200, &w);
    session_release(s);
}

void api_render_delete(struct api_call *c)
{
    struct session *s = api_session(c);
    if (!s) return;
    struct jsonw w;
    if (api_job_use(c, s, api_job_cancel, &w)) api_json(c, 202, &w);
    session_release(s);
}

/* Which image a row's converge figure scores (struct job_row). */
static const char *api_converge_image(const struct job_row *row)
{
    return row->conv_is_frame ? "frame" : "accumulation";
}

/* What the metrics of a job answer with, copied under the session lock (session_job_use). */
struct api_job_series {
    enum job_kind kind;
    uint32_t n;
    struct job_row *rows;            /* an animation's n rows (malloc'd, NULL when out of memory) */
    char ref_name[65];
};

static void api_job_series_copy(struct session *s, struct job *j, void *ctx)
{
    (void)s;
    struct api_job_series *x = ctx;
    x->kind = j->kind;
    snprintf(x->ref_name, sizeof x->ref_name, "%s", j->ref_name);
    if (j->kind != JOB_ANIMATION) return;
    x->n = j->frames_done;
    x->rows = malloc((x->n ? x->n : 1) * sizeof *x->rows);
    if (x->rows) memcpy(x->rows, j->rows, x->n * sizeof *x->rows);
}

void api_render_metrics(struct api_call *c)
{
    static const char *const types[] = {"application/json", "text/csv", NULL};
    struct session *s = api_session(c);
    if (!s) return;
    struct api_job_series x = {0};
    const char *type = api_job_use(c, s, api_job_series_copy, &x) ? api_negotiate(c, types) : NULL;
    struct ref_image *other = NULL;
    struct job_row *rows = x.rows;
    uint32_t n = x.n;
    if (!type || !api_query_reference(c, &s->view.params, &other)) goto out;
    if (x.kind != JOB_ANIMATION) {
        api_problem(c, 404, "not-found", NULL, "job '%s' renders a reference and has no frame series", c->seg[6]);
        goto out;
    }
    char ref_name[sizeof x.ref_name];
    snprintf(ref_name, sizeof ref_name, "%s", other ? other->name : x.ref_name);
    if (!rows) {
        api_problem(c, 503, "busy", NULL, "out of memory");
        goto out;
    }
    if (other) {
        for (uint32_t i = 0; i < n; i++) {
            struct image img;
            struct err e;
            rows[i].has_metrics = rows[i].has_conv = false;  /* accumulations are not kept */
            if (session_frame_copy(s, rows[i].frame, &img, NULL, &e)) {
                rows[i].has_metrics = metrics_compare(&img, &other->img, &rows[i].m, &e);
                image_destroy(&img);
            }
        }
    }
    if (strcmp(type, "text/csv") == 0) {
        struct prom_buf csv = {.cap = 256 + (size_t)n * 192};
        csv.s = malloc(csv.cap);
        if (csv.s)
            prom_printf(&csv, "frame,time_s,render_ms,mape,rmse,relmse,converge_image,converge_frames,"
                              "converge_mape,converge_rmse,converge_relmse\n");
        for (uint32_t i = 0; csv.s && i < n; i++) {
            prom_printf(&csv, "%u,%.9g,%.6g", rows[i].frame, rows[i].time_s, rows[i].render_ms);
            if (rows[i].has_metrics)
                prom_printf(&csv, ",%.9g,%.9g,%.9g", rows[i].m.mape, rows[i].m.rmse, rows[i].m.relmse);
            else
                prom_printf(&csv, ",,,");
            if (rows[i].has_conv)
                prom_printf(&csv, ",%s,%u,%.9g,%.9g,%.9g\n", api_converge_image(&rows[i]), rows[i].conv_frames,
                            rows[i].conv.mape, rows[i].conv.rmse, rows[i].conv.relmse);
            else
                prom_printf(&csv, ",,,,,\n");
        }
        if (!csv.s || csv.failed) {
            free(csv.s);
            api_problem(c, 503, "busy", NULL, "out of memory");
            goto out;
        }
        c->resp->status = 200;
        c->resp->content_type = "text/csv; charset=utf-8";
        c->resp->body = csv.s;
        c->resp->body_len = csv.len;
    } else {
        struct jsonw w;
        jsonw_init(&w);
        jsonw_object_begin(&w);
        jsonw_key(&w, "reference");
        if (ref_name[0]) jsonw_string(&w, ref_name); else jsonw_null(&w);
        jsonw_key(&w, "series");
        jsonw_array_begin(&w);
        for (uint32_t i = 0; i < n; i++) {
            jsonw_object_begin(&w);
            jsonw_key(&w, "frame"); jsonw_uint(&w, rows[i].frame);
            jsonw_key(&w, "time_s"); jsonw_double(&w, rows[i].time_s);
            jsonw_key(&w, "render_ms"); jsonw_double(&w, rows[i].render_ms);
            jsonw_key(&w, "mape"); if (rows[i].has_metrics) jsonw_double(&w, rows[i].m.mape); else jsonw_null(&w);
            jsonw_key(&w, "rmse"); if (rows[i].has_metrics) jsonw_double(&w, rows[i].m.rmse); else jsonw_null(&w);
            jsonw_key(&w, "relmse"); if (rows[i].has_metrics) jsonw_double(&w, rows[i].m.relmse); else jsonw_null(&w);
            jsonw_key(&w, "converge");
            if (rows[i].has_conv) {
                jsonw_object_begin(&w);
                jsonw_key(&w, "image"); jsonw_string(&w, api_converge_image(&rows[i]));
                jsonw_key(&w, "frames"); jsonw_uint(&w, rows[i].conv_frames);
                jsonw_key(&w, "mape"); jsonw_double(&w, rows[i].conv.mape);
                jsonw_key(&w, "rmse"); jsonw_double(&w, rows[i].conv.rmse);
                jsonw_key(&w, "relmse"); jsonw_double(&w, rows[i].conv.relmse);
                jsonw_object_end(&w);
            } else {
                jsonw_null(&w);
            }
            jsonw_object_end(&w);
        }
        jsonw_array_end(&w);
        jsonw_object_end(&w);
        api_json(c, 200, &w);
    }
out:
    free(rows);
    ref_image_release(other);
    session_release(s);
}

void api_session_reference_post(struct api_call *c)
{
    if (!api_require_json(c)) return;
    struct protocol_reference_request req;
    struct err e = {0};
    if (!protocol_parse_reference_request(c->req->body, c->req->body_len, &c->d->cfg.limits, &req, &e)) {
        api_error(c, &e);
        return;
    }
    const char *key;
    if (!api_idempotency_key(c, &key)) return;
    struct session *s = api_session(c);
    if (!s) return;
    uint64_t hash = api_request_hash(JOB_REFERENCE, c->seg[6], c->req->body, c->req->body_len);
    if (api_job_replay(c, s, key, hash) ||
        !api_check_work(c, (uint64_t)s->view.params.width * s->view.params.height * req.spp, "/spp",
                        "this reference")) {
        session_release(s);
        return;
    }
    /* Filled in before it is added: a request under the same key may show it from then on. */
    struct job *j = job_new(s, JOB_REFERENCE, key, hash, &e);
    if (!j) {
        api_error(c, &e);
        session_release(s);
        return;
    }
    snprintf(j->ref_name, sizeof j->ref_name, "%s", c->seg[6]);
    j->frames_total = req.spp < JOBS_REFERENCE_PASSES ? req.spp : JOBS_REFERENCE_PASSES;
    j->ref_spp = req.spp / j->frames_total * j->frames_total;
    j->ref_method = req.method;
    /* Added with the session claimed, to snapshot its current scene and camera: the reference
     * shows what the next frame would show. */
    bool answered = false;
    if (!api_job_add(c, s, j, true, &answered, &e)) {
        if (!answered) api_error(c, &e);
        job_destroy(j);
        session_release(s);
        return;
    }
    j->ref_scene = s->view.scene;
    scene_retain(j->ref_scene);
    j->ref_camera = s->view.camera;
    session_unclaim(s);
    /* The casters SMS would walk on, checked now: past the job's start a failure would only
     * read as a failed job. */
    if (req.method == PROTOCOL_REFERENCE_SMS) {
        struct sms_scene ss;  /* ~6 KiB */
        if (!sms_scene_init(j->ref_scene, &ss, &e)) {
            if (!e.where[0]) snprintf(e.where, sizeof e.where, "/method");
            api_error(c, &e);
            session_job_forget(s, j);
            session_release(s);
            return;
        }
    }
    if (!api_job_submit(c, s, j)) session_job_forget(s, j);
    session_release(s);
}

/* ---- server-sent events ---- */

struct api_sse {
    struct session *s;
    struct daemon *d;
    uint64_t next;                    /* next event sequence number to send */
    char pending[8192];
    size_t pending_len, pending_off;
};

static ssize_t api_sse_read(void *ctx, char *buf, size_t max)
{
    struct api_sse *x = ctx;
    if (x->pending_off == x->pending_len) {
        x->pending_off = x->pending_len = 0;
        struct session *s = x->s;
        pthread_mutex_lock(&s->lock);
        struct timespec until;
        clock_gettime(CLOCK_REALTIME, &until);
        until.tv_sec += 15;
        int rc = 0;
        while (x->next == s->event_seq && !s->deleted && !atomic_load(&x->d->draining) && rc != ETIMEDOUT)
            rc = pthread_cond_timedwait(&s->cond, &s->lock, &until);
        if (x->next < s->event_seq) {
            if (s->event_seq - x->next > SESSION_EVENTS) x->next = s->event_seq - SESSION_EVENTS;  /* fell behind */
            const struct session_event *e = &s->events[x->next % SESSION_EVENTS];
            if (e->data)
                x->pending_len = (size_t)snprintf(x->pending, sizeof x->pending, "id: %llu\nevent: %s\ndata: %s\n\n",
                                                  (unsigned long long)e->seq, e->type, e->data);
            if (x->pending_len >= sizeof x->pending) x->pending_len = 0;  /* never split a cut event */
            x->next++;
        } else if (s->deleted || atomic_load(&x->d->draining)) {
            pthread_mutex_unlock(&s->lock);
            return HTTP_STREAM_END;
        } else {
            x->pending_len = (size_t)snprintf(x->pending, sizeof x->pending, ": keepalive\n\n");
        }
        pthread_mutex_unlock(&s->lock);
        if (x->pending_len == 0) return api_sse_read(ctx, buf, max);
    }
    size_t n = x->pending_len - x->pending_off;
    if (n > max) n = max;
    memcpy(buf, x->pending + x->pending_off, n);
    x->pending_off += n;
    return (ssize_t)n;
}

static void api_sse_free(void *ctx)
{
    struct api_sse *x = ctx;
    session_release(x->s);
    free(x);
}

void api_events_get(struct api_call *c)
{
    static const char *const types[] = {"text/event-stream", NULL};
    struct session *s = api_session(c);
    if (!s) return;
    if (!api_negotiate(c, types)) {
        session_release(s);
        return;
    }
    struct api_sse *x = calloc(1, sizeof *x);
    if (!x) {
        session_release(s);
        api_problem(c, 503, "busy", NULL, "out of memory");
        return;
    }
    x->s = s;  /* the reference moves to the stream */
    x->d = c->d;
    pthread_mutex_lock(&s->lock);
    x->next = s->event_seq;
    const char *last = http_header(c->req, "Last-Event-ID");
    if (last) {
        char *end = NULL;
        unsigned long long id = strtoull(last, &end, 10);
        if (!*end && id < s->event_seq) x->next = id + 1;
    }
    pthread_mutex_unlock(&s->lock);
    /* A first comment so the client sees the stream open at once. */
    x->pending_len = (size_t)snprintf(x->pending, sizeof x->pending, ": connected to session %s\n\n", s->id);
    c->resp->status = 200;
    c->resp->content_type = "text/event-stream";
    c->resp->stream = api_sse_read;
    c->resp->stream_ctx = x;
    c->resp->stream_free = api_sse_free;
    http_response_header(c->resp, "Cache-Control", "no-store");
    http_response_header(c->resp, "X-Accel-Buffering", "no");
}

bool api_default_session(struct daemon *d, const char *scene_id, char *href, size_t size)
{
    struct err e = {0};
    struct scene *scene = registry_acquire(d->registry, scene_id);
    if (!scene) {
        fprintf(stderr, "restird: no scene '%s' for the default session\n", scene_id);
        return false;
    }
    struct view_params p = view_params_defaults(method_default(), 256, 256);
    view_params_set_uint(&p, "spp", 16);
    if (!registry_session_added(d->registry, scene_id, &e)) {
        scene_release(scene);
        return false;
    }
    bool budget_full;
    struct session *s = api_session_admit(d, scene_id, "default", scene, &p, &budget_full, &e);
    scene_release(scene);
    if (!s) {
        registry_session_removed(d->registry, scene_id);
        fprintf(stderr, "restird: default session: %s\n", e.message);
        return false;
    }
    snprintf(href, size, "/v1/scenes/%s/sessions/%s", scene_id, s->id);
    session_release(s);
    return true;
}
