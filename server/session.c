/* session.c — sessions, their kept frames, events and job records (see session.h). */
#include "session.h"

#include "animate.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>
#include <time.h>
#include <unistd.h>

struct sessions {
    pthread_mutex_t lock;
    uint32_t max;
    uint32_t count;
    struct session **items;           /* max slots */
    uint64_t next_id;
    uint32_t salt;
};

struct sessions *sessions_new(uint32_t max_sessions)
{
    struct sessions *t = calloc(1, sizeof *t);
    if (!t) return NULL;
    t->items = calloc(max_sessions ? max_sessions : 1, sizeof *t->items);
    if (!t->items) {
        free(t);
        return NULL;
    }
    pthread_mutex_init(&t->lock, NULL);
    t->max = max_sessions;
    t->next_id = 1;
    /* Session ids are not secrets, but one must not name another session where a client may
     * still hold it: on a restarted daemon, or on another daemon behind the same proxy once a
     * scene has moved there. Daemons started in the same second must not count alike, so the
     * salt is random; time and process id stand in if the kernel has no randomness yet. */
    if (getrandom(&t->salt, sizeof t->salt, GRND_NONBLOCK) != (ssize_t)sizeof t->salt)
        t->salt = ((uint32_t)time(NULL) ^ (uint32_t)getpid() << 16) * 2654435761u;
    return t;
}

void sessions_free(struct sessions *t)
{
    if (!t) return;
    pthread_mutex_destroy(&t->lock);
    free(t->items);
    free(t);
}

void job_destroy(struct job *j)
{
    if (!j) return;
    free(j->frames);
    free(j->rows);
    animate_destroy(&j->anim);
    ref_image_release(j->reference);
    scene_release(j->ref_scene);
    free(j);
}

static void session_free(struct session *s)
{
    if (s->budget) budget_release(s->budget, BUDGET_SESSIONS, s->budget_bytes);
    view_destroy(&s->view);
    for (uint32_t i = 0; i < s->frames_kept; i++) image_destroy(&s->ring[i].img);
    free(s->ring);
    for (int i = 0; i < SESSION_EVENTS; i++) free(s->events[i].data);
    for (uint32_t i = 0; i < s->job_count; i++) job_destroy(s->jobs[i]);
    pthread_cond_destroy(&s->cond);
    pthread_mutex_destroy(&s->lock);
    free(s);
}

void session_retain(struct session *s)
{
    atomic_fetch_add(&s->refcount, 1);
}

void session_release(struct session *s)
{
    if (s && atomic_fetch_sub(&s->refcount, 1) == 1) session_free(s);
}

struct session *sessions_create(struct sessions *t, const char *scene_id, const char *id, struct scene *scene,
                                const struct view_params *params, uint32_t frames_kept, unsigned threads,
                                struct budget *budget, uint64_t budget_bytes, struct err *err)
{
    struct session *s = calloc(1, sizeof *s);
    if (!s) {
        if (budget) budget_release(budget, BUDGET_SESSIONS, budget_bytes);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for a session"), NULL;
    }
    s->frames_kept = frames_kept ? frames_kept : 1;
    s->ring = calloc(s->frames_kept, sizeof *s->ring);
    if (!s->ring || !view_init(&s->view, scene, params, threads, err)) {
        if (budget) budget_release(budget, BUDGET_SESSIONS, budget_bytes);
        if (!s->ring) err_set(err, ERR_NOMEM, NULL, "out of memory for a session");
        free(s->ring);
        free(s);
        return NULL;
    }
    s->budget = budget;  /* from here on session_free gives the bytes back */
    s->budget_bytes = budget_bytes;
    pthread_mutex_init(&s->lock, NULL);
    pthread_cond_init(&s->cond, NULL);
    s->camera = s->view.camera;
    atomic_init(&s->refcount, 2);  /* the table's and the caller's */
    snprintf(s->scene_id, sizeof s->scene_id, "%s", scene_id);

    pthread_mutex_lock(&t->lock);
    uint32_t slot = t->max;
    for (uint32_t i = 0; i < t->max; i++)
        if (!t->items[i]) {
            slot = i;
            break;
        }
    if (slot == t->max) {
        pthread_mutex_unlock(&t->lock);
        atomic_store(&s->refcount, 1);
        session_release(s);
        return err_set(err, ERR_BUSY, NULL, "too many sessions (limit %u): delete one first", t->max), NULL;
    }
    for (uint32_t i = 0; id && i < t->max; i++)
        if (t->items[i] && strcmp(t->items[i]->id, id) == 0) {
            pthread_mutex_unlock(&t->lock);
            atomic_store(&s->refcount, 1);
            session_release(s);
            return err_set(err, ERR_CONFLICT, NULL, "session id '%s' is taken", id), NULL;
        }
    uint64_t n = t->next_id++;
    if (id)
        snprintf(s->id, sizeof s->id, "%s", id);
    else
        snprintf(s->id, sizeof s->id, "s%llx%08x", (unsigned long long)n,
                 (unsigned)(t->salt ^ (uint32_t)(n * 2654435761u)));
    t->items[slot] = s;
    t->count++;
    pthread_mutex_unlock(&t->lock);
    return s;
}

/* Slot of the session (call with t->lock held), or t->max. */
static uint32_t sessions_slot(const struct sessions *t, const char *scene_id, const char *sid)
{
    for (uint32_t i = 0; i < t->max; i++) {
        const struct session *s = t->items[i];
        if (s && strcmp(s->id, sid) == 0 && strcmp(s->scene_id, scene_id) == 0) return i;
    }
    return t->max;
}

struct session *sessions_get(struct sessions *t, const char *scene_id, const char *sid)
{
    pthread_mutex_lock(&t->lock);
    uint32_t i = sessions_slot(t, scene_id, sid);
    struct session *found = i < t->max ? t->items[i] : NULL;
    if (found) session_retain(found);
    pthread_mutex_unlock(&t->lock);
    return found;
}

static void session_mark_deleted(struct session *s)
{
    pthread_mutex_lock(&s->lock);
    s->deleted = true;
    for (uint32_t i = 0; i < s->job_count; i++) atomic_store(&s->jobs[i]->cancel, true);
    pthread_cond_broadcast(&s->cond);
    pthread_mutex_unlock(&s->lock);
}

bool sessions_remove(struct sessions *t, const char *scene_id, const char *sid)
{
    pthread_mutex_lock(&t->lock);
    uint32_t i = sessions_slot(t, scene_id, sid);
    struct session *found = i < t->max ? t->items[i] : NULL;
    if (found) {
        t->items[i] = NULL;
        t->count--;
    }
    pthread_mutex_unlock(&t->lock);
    if (!found) return false;
    session_mark_deleted(found);
    session_release(found);
    return true;
}

void sessions_remove_all(struct sessions *t)
{
    for (;;) {
        struct session *s = NULL;
        pthread_mutex_lock(&t->lock);
        for (uint32_t i = 0; i < t->max && !s; i++)
            if (t->items[i]) {
                s = t->items[i];
                t->items[i] = NULL;
                t->count--;
            }
        pthread_mutex_unlock(&t->lock);
        if (!s) return;
        session_mark_deleted(s);
        session_release(s);
    }
}

uint32_t sessions_list(struct sessions *t, const char *scene_id, struct session **out, uint32_t max)
{
    uint32_t n = 0;
    pthread_mutex_lock(&t->lock);
    for (uint32_t i = 0; i < t->max && n < max; i++) {
        struct session *s = t->items[i];
        if (s && (!scene_id || strcmp(s->scene_id, scene_id) == 0)) {
            session_retain(s);
            out[n++] = s;
        }
    }
    pthread_mutex_unlock(&t->lock);
    return n;
}

uint32_t sessions_count(struct sessions *t)
{
    pthread_mutex_lock(&t->lock);
    uint32_t n = t->count;
    pthread_mutex_unlock(&t->lock);
    return n;
}

uint64_t session_bytes_planned(const struct view_params *params, const struct scene *scene, uint32_t frames_kept)
{
    uint64_t frame = (uint64_t)params->width * params->height * sizeof(struct vec3);
    return view_bytes_planned(params, scene) + (uint64_t)(frames_kept ? frames_kept : 1) * frame;
}

size_t session_bytes(struct session *s)
{
    struct view_buffer_bytes b[VIEW_MAX_BUFFERS];
    size_t total = 0;
    view_bytes(&s->view, b, &total);
    pthread_mutex_lock(&s->lock);
    for (uint32_t i = 0; i < s->frames_kept; i++)
        total += (size_t)s->ring[i].img.width * s->ring[i].img.height * sizeof(struct vec3);
    pthread_mutex_unlock(&s->lock);
    return total;
}

static bool session_claim_locked(struct session *s, struct err *err)
{
    if (s->busy || s->deleted)
        return err_set(err, s->deleted ? ERR_NOT_FOUND : ERR_CONFLICT, NULL,
                       s->deleted ? "the session was deleted" : "the session is rendering (one frame or job at a time)");
    s->busy = true;
    return true;
}

bool session_claim(struct session *s, struct err *err)
{
    pthread_mutex_lock(&s->lock);
    bool ok = session_claim_locked(s, err);
    pthread_mutex_unlock(&s->lock);
    return ok;
}

void session_unclaim_locked(struct session *s)
{
    s->busy = false;
    pthread_cond_broadcast(&s->cond);
}

void session_unclaim(struct session *s)
{
    pthread_mutex_lock(&s->lock);
    session_unclaim_locked(s);
    pthread_mutex_unlock(&s->lock);
}

void session_post_event(struct session *s, const char *type, const char *json)
{
    char *copy = strdup(json);
    pthread_mutex_lock(&s->lock);
    struct session_event *e = &s->events[s->event_seq % SESSION_EVENTS];
    free(e->data);
    e->seq = s->event_seq++;
    snprintf(e->type, sizeof e->type, "%s", type);
    e->data = copy;  /* NULL on allocation failure: readers skip it */
    pthread_cond_broadcast(&s->cond);
    pthread_mutex_unlock(&s->lock);
}

/* Whether the frame being rendered is still wanted: its session not deleted, its requester
 * (the `stop` callback: a client that hung up) still there. A job's own cancel takes effect
 * between frames, as before. */
struct session_watch {
    struct session *s;
    bool (*stop)(void *ctx);
    void *stop_ctx;
    bool stopped;
    bool cut;                      /* the renderer was stopped with work left: the frame is not whole */
    enum err_code code;
    const char *why;
};

static bool session_watch_stop(struct session_watch *w)
{
    if (w->stopped) return true;
    pthread_mutex_lock(&w->s->lock);
    bool deleted = w->s->deleted;
    pthread_mutex_unlock(&w->s->lock);
    if (deleted) {
        w->code = ERR_NOT_FOUND;
        w->why = "the session was deleted while its frame rendered";
    } else if (w->stop && w->stop(w->stop_ctx)) {
        w->code = ERR_CONFLICT;
        w->why = "the client went away while its frame rendered";
    }
    w->stopped = w->why != NULL;
    return w->stopped;
}

/* The renderer's progress callback (about every 20 ms, on the rendering thread). Once every
 * job is done there is nothing left to skip: a frame whose client leaves then is whole, and the
 * session keeps it (and its reuse history) as any other; one whose session was deleted is
 * dropped by session_render. */
static void session_watch_progress(void *ctx, uint32_t done, uint32_t total)
{
    struct session_watch *w = ctx;
    if (done < total && session_watch_stop(w)) {
        w->cut = true;
        parallel_stop();
    }
}

bool session_render(struct session *s, struct gate *gate, bool bounded, const struct view_frame_change *change,
                    struct job *job, uint32_t *n, struct frame_stats *stats, bool (*stop)(void *ctx), void *stop_ctx,
                    struct err *err)
{
    struct session_watch watch = {.s = s, .stop = stop, .stop_ctx = stop_ctx};
    if (!gate_enter(gate, bounded, err)) return false;
    /* A frame that waited in the queue for a client that has gone is not rendered. */
    if (session_watch_stop(&watch)) {
        gate_leave(gate);
        return err_set(err, watch.code, NULL, "%s", watch.why);
    }
    bool ok = view_render(&s->view, change, stats, session_watch_progress, &watch, err);
    gate_leave(gate);
    if (!ok) return false;
    if (watch.cut) {
        /* The renderer skipped the rest of the frame: what it left in the view's accumulation
         * and history is not a frame. The sequence starts over, as after a reset. */
        session_reset(s);
        return err_set(err, watch.code, NULL, "%s%s", watch.why,
                       watch.code == ERR_NOT_FOUND ? "" : " (the session's frames start over)");
    }

    /* Kept frames live in slots allocated on first use and reused: a session in its steady
     * state allocates nothing per frame. */
    const struct image *img = &s->view.output;
    pthread_mutex_lock(&s->lock);
    if (s->deleted) {
        /* Deleted while a frame rendered that was not cut: a method that reports progress only
         * at a frame's end, or a frame near its end. Nobody can fetch it, and its request must
         * not answer as if the session still were. */
        pthread_mutex_unlock(&s->lock);
        return err_set(err, ERR_NOT_FOUND, NULL, "the session was deleted while its frame rendered");
    }
    uint32_t frame = stats->frame;
    struct session_frame *slot = &s->ring[frame % s->frames_kept];
    if (!slot->img.pixels && !image_init(&slot->img, img->width, img->height, err)) {
        slot->valid = false;
        pthread_mutex_unlock(&s->lock);
        return false;
    }
    memcpy(slot->img.pixels, img->pixels, (size_t)img->width * img->height * sizeof *img->pixels);
    slot->valid = true;
    slot->n = frame;
    slot->stats = *stats;
    s->frames_done = s->view.frame;
    s->camera = s->view.camera;
    snprintf(slot->job, sizeof slot->job, "%s", job ? job->id : "");
    char sid[24], scene[65];
    snprintf(sid, sizeof sid, "%s", s->id);
    snprintf(scene, sizeof scene, "%s", s->scene_id);
    pthread_mutex_unlock(&s->lock);
    *n = frame;

    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "frame");
    jsonw_uint(&w, frame);
    jsonw_key(&w, "render_ms");
    jsonw_double(&w, stats->render.render_ms);
    double rays = (double)(stats->render.rays_intersect + stats->render.rays_occluded);
    jsonw_key(&w, "rays_per_s");
    jsonw_double(&w, stats->render.render_ms > 0 ? rays / (stats->render.render_ms * 1e-3) : 0.0);
    char href[256];
    snprintf(href, sizeof href, "/v1/scenes/%s/sessions/%s/frames/%u", scene, sid, frame);
    jsonw_key(&w, "href");
    jsonw_string(&w, href);
    if (job) {
        jsonw_key(&w, "job");
        jsonw_string(&w, job->id);
    }
    jsonw_object_end(&w);
    char *text = jsonw_finish(&w, NULL);
    if (text) session_post_event(s, "frame", text);
    free(text);
    return true;
}

bool session_frame_copy(struct session *s, uint32_t n, struct image *out, struct frame_stats *stats,
                        struct err *err)
{
    pthread_mutex_lock(&s->lock);
    uint32_t rendered = s->frames_done;
    struct session_frame *slot = &s->ring[n % s->frames_kept];
    bool ok = false;
    if (n >= rendered || !slot->valid || slot->n > n) {
        if (n < rendered)
            err_set(err, ERR_LIMIT, NULL, "frame %u is no longer kept (the session keeps the last %u)", n, s->frames_kept);
        else
            err_set(err, ERR_NOT_FOUND, NULL, "frame %u has not been rendered (%u so far)", n, rendered);
    } else if (slot->n != n) {
        err_set(err, ERR_LIMIT, NULL, "frame %u is no longer kept (the session keeps the last %u)", n, s->frames_kept);
    } else if (image_init(out, slot->img.width, slot->img.height, err)) {
        memcpy(out->pixels, slot->img.pixels, (size_t)out->width * out->height * sizeof *out->pixels);
        if (stats) *stats = slot->stats;
        ok = true;
    }
    pthread_mutex_unlock(&s->lock);
    return ok;
}

bool session_frame_kept_locked(const struct session *s, uint32_t epoch, uint32_t n)
{
    const struct session_frame *slot = &s->ring[n % s->frames_kept];
    return epoch == s->epoch && n < s->frames_done && slot->valid && slot->n == n;
}

struct job *job_new(struct session *s, enum job_kind kind, const char *idempotency_key, uint64_t request_hash,
                    struct err *err)
{
    struct job *j = calloc(1, sizeof *j);
    if (!j) return err_set(err, ERR_NOMEM, NULL, "out of memory for a job"), NULL;
    j->kind = kind;
    j->status = JOB_QUEUED;
    j->session = s;
    j->request_hash = request_hash;
    atomic_init(&j->cancel, false);
    snprintf(j->idempotency_key, sizeof j->idempotency_key, "%s", idempotency_key ? idempotency_key : "");
    return j;
}

bool session_job_add(struct session *s, struct job *j, bool claim, bool *exists, struct err *err)
{
    /* Looking the key up, claiming and inserting are one step: of requests sent at once with
     * the same key, one adds its job and the others find it. */
    pthread_mutex_lock(&s->lock);
    *exists = j->idempotency_key[0] && session_job_find_key(s, j->idempotency_key);
    bool ok = !*exists;
    uint32_t k = SESSION_JOBS;
    if (ok && s->job_count == SESSION_JOBS) {
        /* Forget the oldest finished job its worker has let go of. */
        for (uint32_t i = 0; i < s->job_count && k == SESSION_JOBS; i++)
            if (s->jobs[i]->released) k = i;
        if (k == SESSION_JOBS) ok = err_set(err, ERR_BUSY, NULL, "the session has %u unfinished jobs", SESSION_JOBS);
    }
    if (ok && claim) ok = session_claim_locked(s, err);
    if (ok) {
        if (k < SESSION_JOBS) {
            job_destroy(s->jobs[k]);
            memmove(&s->jobs[k], &s->jobs[k + 1], (s->job_count - k - 1) * sizeof *s->jobs);
            s->job_count--;
        }
        snprintf(j->id, sizeof j->id, "r%llu", (unsigned long long)++s->next_job);
        j->epoch = s->epoch;
        s->jobs[s->job_count++] = j;
    }
    pthread_mutex_unlock(&s->lock);
    return ok;
}

struct job *session_job_find(struct session *s, const char *rid)
{
    for (uint32_t i = 0; i < s->job_count; i++)
        if (strcmp(s->jobs[i]->id, rid) == 0) return s->jobs[i];
    return NULL;
}

bool session_job_use(struct session *s, const char *rid, void (*use)(struct session *s, struct job *j, void *ctx),
                     void *ctx)
{
    pthread_mutex_lock(&s->lock);
    struct job *j = session_job_find(s, rid);
    if (j) use(s, j, ctx);
    pthread_mutex_unlock(&s->lock);
    return j != NULL;
}

struct job *session_job_find_key(struct session *s, const char *key)
{
    for (uint32_t i = 0; i < s->job_count; i++)
        if (s->jobs[i]->idempotency_key[0] && strcmp(s->jobs[i]->idempotency_key, key) == 0) return s->jobs[i];
    return NULL;
}

void session_reset(struct session *s)
{
    view_reset(&s->view);
    pthread_mutex_lock(&s->lock);
    s->epoch++;
    s->frames_done = 0;
    for (uint32_t i = 0; i < s->frames_kept; i++) s->ring[i].valid = false;
    pthread_mutex_unlock(&s->lock);
}

void session_job_forget(struct session *s, struct job *j)
{
    pthread_mutex_lock(&s->lock);
    for (uint32_t i = 0; i < s->job_count; i++)
        if (s->jobs[i] == j) {
            memmove(&s->jobs[i], &s->jobs[i + 1], (s->job_count - i - 1) * sizeof *s->jobs);
            s->job_count--;
            break;
        }
    pthread_mutex_unlock(&s->lock);
    job_destroy(j);
}
