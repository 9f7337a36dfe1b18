/* jobs.c — the job worker pool (see jobs.h) and what each job kind does. */
#include "jobs.h"

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "integrators/reference_pt.h"
#include "methods/path_params.h"

struct jobs {
    pthread_mutex_t lock;
    pthread_cond_t cond;
    struct job **fifo;
    unsigned cap, head, count;
    bool stopping;
    unsigned worker_count;
    pthread_t *workers;
    struct gate *gate;
    struct refstore *refs;
    jobs_frame_fn *on_frame;
    void *on_frame_ctx;
};

static const char *jobs_status_name(enum job_status s)
{
    static const char *const names[] = {"queued", "running", "done", "cancelled", "failed"};
    return names[s];
}

/* Call with the session lock held. A reference an animation is measured against (its pixels,
 * and its bytes in the memory budget once it has been deleted) is held while the job runs, not
 * while its record is kept: it is let go before the job is seen to end. So is an animation's
 * claim on its session, in the same step: a client that sees the job ended (its status, or the
 * `done` event posted after this) may render the session's next frame at once, and would be
 * refused as busy if the claim were given back later. */
static void jobs_set_status_locked(struct job *j, enum job_status st)
{
    if (st >= JOB_DONE) {
        ref_image_release(j->reference);
        j->reference = NULL;
        if (j->kind == JOB_ANIMATION && j->status < JOB_DONE) session_unclaim_locked(j->session);
    }
    j->status = st;
}

static void jobs_set_status(struct job *j, enum job_status st)
{
    pthread_mutex_lock(&j->session->lock);
    jobs_set_status_locked(j, st);
    pthread_mutex_unlock(&j->session->lock);
}

static void jobs_post(struct job *j, const char *type)
{
    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "job");
    jsonw_string(&w, j->id);
    if (strcmp(type, "progress") == 0) {
        jsonw_key(&w, "frames_done");
        jsonw_uint(&w, j->frames_done);
        jsonw_key(&w, "frames_total");
        jsonw_uint(&w, j->frames_total);
    } else if (strcmp(type, "done") == 0) {
        jsonw_key(&w, "status");
        jsonw_string(&w, jobs_status_name(j->status));
    } else {
        char instance[256];
        snprintf(instance, sizeof instance, "/v1/scenes/%s/sessions/%s/renders/%s", j->session->scene_id,
                 j->session->id, j->id);
        const struct protocol_problem p = {.status = j->error_status, .slug = j->error_slug,
                                           .title = protocol_problem_title(j->error_slug),
                                           .detail = j->error.message, .instance = instance};
        protocol_problem_members(&w, &p);
    }
    jsonw_object_end(&w);
    char *text = jsonw_finish(&w, NULL);
    if (text) session_post_event(j->session, type, text);
    free(text);
}

static void jobs_fail(struct job *j, int status, const char *slug)
{
    pthread_mutex_lock(&j->session->lock);
    jobs_set_status_locked(j, JOB_FAILED);
    j->error_status = status;
    snprintf(j->error_slug, sizeof j->error_slug, "%s", slug);
    pthread_mutex_unlock(&j->session->lock);
    jobs_post(j, "error");
}

/* The row's converge figure (struct job_row): the frame's own for a method that reuses earlier
 * frames under the real-time profile (its correlated frames are not averaged), else the
 * accumulation's — under the converge profile such a method's frames are unbiased draws of their own, and
 * their mean is the image it converges. An animation job holds the session's claim for its whole
 * run (jobs_run), so the accumulation is read here between its frames without claiming again. */
static void jobs_converge_metrics(struct session *s, const struct image *ref, struct job_row *row)
{
    if ((s->view.params.method->caps & METHOD_REUSES_FRAMES) && s->view.params.profile != METHOD_PROFILE_CONVERGE) {
        row->has_conv = row->has_metrics;
        row->conv_is_frame = true;
        row->conv = row->m;
        row->conv_frames = 0;
        return;
    }
    struct err e = {0};
    struct image acc;
    uint32_t count = 0;
    if (!view_accumulated(&s->view, &acc, &count, &e)) return;
    row->has_conv = metrics_compare(&acc, ref, &row->conv, &e);
    row->conv_frames = count;
    image_destroy(&acc);
}

static void jobs_run_animation(struct jobs *q, struct job *j)
{
    struct session *s = j->session;
    struct view_shape_change changes[j->anim.track_count ? j->anim.track_count : 1];
    for (uint32_t i = 0; i < j->frames_total; i++) {
        if (atomic_load(&j->cancel)) {
            jobs_set_status(j, JOB_CANCELLED);
            return;
        }
        double t = (double)i / j->fps;
        struct view_frame_change change;
        if (!view_animation_change(&j->anim, t, &change, changes, &j->error)) {
            jobs_fail(j, 422, "invalid-field");
            return;
        }

        uint32_t n = 0;  /* set by a successful session_render; the LTO build cannot tell */
        struct frame_stats stats;
        if (!session_render(s, q->gate, false, &change, j, &n, &stats, NULL, NULL, &j->error)) {
            /* The gate closed (shutting down), or the session was deleted while the frame
             * rendered (ERR_NOT_FOUND, session_render): the job was cancelled, as between
             * frames, and nothing failed. */
            if (j->error.code == ERR_BUSY || j->error.code == ERR_NOT_FOUND) {
                jobs_set_status(j, JOB_CANCELLED);
                return;
            }
            jobs_fail(j, j->error.code == ERR_NOMEM ? 503 : 422, j->error.code == ERR_NOMEM ? "busy" : "invalid-field");
            return;
        }
        if (q->on_frame) q->on_frame(q->on_frame_ctx, stats.render.render_ms);
        struct job_row row = {.frame = n, .time_s = t, .render_ms = stats.render.render_ms};
        if (j->reference) {
            struct image img;
            struct err e;
            if (session_frame_copy(s, n, &img, NULL, &e)) {
                row.has_metrics = metrics_compare(&img, &j->reference->img, &row.m, &e);
                image_destroy(&img);
            }
            jobs_converge_metrics(s, &j->reference->img, &row);
        }
        pthread_mutex_lock(&s->lock);
        j->frames[j->frames_done] = n;
        j->rows[j->frames_done] = row;
        j->frames_done++;
        pthread_mutex_unlock(&s->lock);
        jobs_post(j, "progress");
    }
    jobs_set_status(j, JOB_DONE);
}

static void jobs_run_reference(struct jobs *q, struct job *j)
{
    struct session *s = j->session;
    const struct view_params *vp = &s->view.params;  /* immutable after creation */
    struct image sum;
    if (!image_init(&sum, vp->width, vp->height, &j->error)) {
        jobs_fail(j, 503, "busy");
        return;
    }
    struct image scratch;
    if (!image_init(&scratch, vp->width, vp->height, &j->error)) {
        image_destroy(&sum);
        jobs_fail(j, 503, "busy");
        return;
    }
    uint32_t passes = j->frames_total;
    uint32_t spp_pass = j->ref_spp / passes;
    struct pt_params p = reference_pt_defaults(vp->width, vp->height);
    p.spp = spp_pass;
    /* At least the session's own depth (64 when its method has none). */
    uint32_t depth = 64;
    view_params_get_uint(vp, "max_depth", &depth);
    p.max_depth = depth > 64 ? depth : 64;
    p.seed = vp->seed;
    p.threads = s->view.threads;
    p.camera = &j->ref_camera;
    /* Uncapped Bernoulli trials: a capped count returns 0 past the cap, which loses energy
     * ([SMS-SSP Fig. 7]); a reference must not. */
    struct sms_params sms = sms_defaults();
    sms.bernoulli_cap = 0;
    if (j->ref_method == PROTOCOL_REFERENCE_SMS) p.sms = &sms;
    else p.sampler = pt_method_defaults().sampler;  /* pt's reference, with pt's sampler */
    bool ok = true;
    for (uint32_t i = 0; ok && i < passes; i++) {
        if (atomic_load(&j->cancel) || !gate_enter(q->gate, false, &j->error)) {
            jobs_set_status(j, JOB_CANCELLED);  /* cancelled, or the gate closed: shutting down */
            ok = false;
            break;
        }
        struct render_stats rs;
        ok = reference_pt_add_pass(j->ref_scene, &p, i, &sum, &scratch, &rs, &j->error);
        gate_leave(q->gate);
        if (!ok) {
            jobs_fail(j, 503, "busy");
            break;
        }
        pthread_mutex_lock(&s->lock);
        j->frames_done++;
        pthread_mutex_unlock(&s->lock);
        jobs_post(j, "progress");
    }
    image_destroy(&scratch);
    if (!ok) {
        image_destroy(&sum);
        return;
    }
    image_scale(&sum, 1.0f / (float)passes);
    /* Cancelled during its last pass (the job deleted, or its session, which a client deletes
     * before the reference when it cleans up): nothing is stored. The check and the store are
     * one step under the session lock, so once a DELETE of the session has answered, the
     * reference is either stored already or never will be. */
    pthread_mutex_lock(&s->lock);
    bool cancelled = atomic_load(&j->cancel) || s->deleted;
    bool replaced, stored = false;
    if (cancelled) {
        image_destroy(&sum);
        jobs_set_status_locked(j, JOB_CANCELLED);
    } else {
        stored = refstore_put(q->refs, s->scene_id, j->ref_name, &sum, spp_pass * passes,
                              protocol_reference_method_name(j->ref_method), &replaced, &j->error);
        if (stored) jobs_set_status_locked(j, JOB_DONE);
    }
    pthread_mutex_unlock(&s->lock);
    if (!cancelled && !stored) jobs_fail(j, 503, j->error.code == ERR_BUSY ? "memory-budget" : "busy");
}

static void *jobs_worker(void *arg)
{
    struct jobs *q = arg;
    for (;;) {
        pthread_mutex_lock(&q->lock);
        while (q->count == 0 && !q->stopping) pthread_cond_wait(&q->cond, &q->lock);
        if (q->count == 0) {
            pthread_mutex_unlock(&q->lock);
            return NULL;
        }
        struct job *j = q->fifo[q->head];
        q->head = (q->head + 1) % q->cap;
        q->count--;
        pthread_mutex_unlock(&q->lock);

        struct session *s = j->session;
        if (atomic_load(&j->cancel)) {
            jobs_set_status(j, JOB_CANCELLED);
        } else {
            jobs_set_status(j, JOB_RUNNING);
            if (j->kind == JOB_ANIMATION)
                jobs_run_animation(q, j);
            else
                jobs_run_reference(q, j);
        }
        /* Only this thread writes the status, so it is read here without the lock. An
         * animation's claim went with its final status (jobs_set_status_locked). */
        if (j->status != JOB_FAILED) jobs_post(j, "done");
        /* The last touch: once released, a job added to the session may free it at once. */
        pthread_mutex_lock(&s->lock);
        j->released = true;
        pthread_mutex_unlock(&s->lock);
        session_release(s);
    }
}

struct jobs *jobs_new(unsigned workers, unsigned queue, struct gate *gate, struct refstore *refs,
                      jobs_frame_fn *on_frame, void *on_frame_ctx, struct err *err)
{
    struct jobs *q = calloc(1, sizeof *q);
    if (!q) return err_set(err, ERR_NOMEM, NULL, "out of memory"), NULL;
    q->cap = queue ? queue : 1;
    q->fifo = calloc(q->cap, sizeof *q->fifo);
    q->workers = calloc(workers ? workers : 1, sizeof *q->workers);
    if (!q->fifo || !q->workers) {
        free(q->fifo), free(q->workers), free(q);
        return err_set(err, ERR_NOMEM, NULL, "out of memory"), NULL;
    }
    pthread_mutex_init(&q->lock, NULL);
    pthread_cond_init(&q->cond, NULL);
    q->gate = gate;
    q->refs = refs;
    q->on_frame = on_frame;
    q->on_frame_ctx = on_frame_ctx;
    for (unsigned i = 0; i < (workers ? workers : 1); i++) {
        if (pthread_create(&q->workers[i], NULL, jobs_worker, q) != 0) {
            jobs_stop(q);
            return err_set(err, ERR_INTERNAL, NULL, "cannot start job worker threads"), NULL;
        }
        q->worker_count++;
    }
    return q;
}

bool jobs_submit(struct jobs *q, struct job *j, struct err *err)
{
    pthread_mutex_lock(&q->lock);
    if (q->stopping || q->count == q->cap) {
        bool stopping = q->stopping;
        pthread_mutex_unlock(&q->lock);
        return err_set(err, ERR_BUSY, NULL, stopping ? "the daemon is shutting down" : "the job queue is full (%u jobs)",
                       q->cap);
    }
    session_retain(j->session);
    q->fifo[(q->head + q->count) % q->cap] = j;
    q->count++;
    pthread_cond_signal(&q->cond);
    pthread_mutex_unlock(&q->lock);
    return true;
}

void jobs_stop(struct jobs *q)
{
    if (!q) return;
    pthread_mutex_lock(&q->lock);
    q->stopping = true;
    for (unsigned i = 0; i < q->count; i++) atomic_store(&q->fifo[(q->head + i) % q->cap]->cancel, true);
    pthread_cond_broadcast(&q->cond);
    pthread_mutex_unlock(&q->lock);
    for (unsigned i = 0; i < q->worker_count; i++) pthread_join(q->workers[i], NULL);
    pthread_cond_destroy(&q->cond);
    pthread_mutex_destroy(&q->lock);
    free(q->fifo);
    free(q->workers);
    free(q);
}

unsigned jobs_queued(struct jobs *q)
{
    pthread_mutex_lock(&q->lock);
    unsigned n = q->count;
    pthread_mutex_unlock(&q->lock);
    return n;
}
