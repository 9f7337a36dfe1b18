/* session.h — rendering sessions and their background jobs.
 * A session wraps a renderer `struct view` (persistent per-method state) with what the server
 * adds: an id, the frames it keeps for fetching, an event log for server-sent events, and the
 * animation/reference jobs submitted to it. One frame at a time per session: `busy` is set
 * while a synchronous frame renders and for the whole life of a job, and a second request gets
 * ERR_CONFLICT (409) instead of interleaving with the ordered frame sequence.
 * Locking: sessions_lock guards the table; session->lock guards a session's fields except
 * `view`, which only the holder of `busy` touches (outside the lock, during a render).
 * Lifetime: sessions are reference counted; the table holds one reference, every request or
 * job working on a session another. */
#ifndef RESTIRD_SESSION_H
#define RESTIRD_SESSION_H

#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>

#include "scene/animation.h"
#include "budget.h"
#include "gate.h"
#include "image/metrics.h"
#include "protocol.h"
#include "refstore.h"
#include "session/view.h"

#define SESSION_EVENTS 64          /* events kept for SSE readers that fall behind */
#define SESSION_JOBS 16            /* jobs remembered per session (oldest released dropped) */

enum job_kind { JOB_ANIMATION, JOB_REFERENCE };
enum job_status { JOB_QUEUED, JOB_RUNNING, JOB_DONE, JOB_CANCELLED, JOB_FAILED };

/* One frame of an animation job. `m` is the frame's own error (the real-time figure); `conv`
 * is the error of the image a user keeping a still view would keep after this frame (the
 * converge figure): the session's accumulation (`conv_frames` frames since the last change) for
 * a method whose frames are independent, the frame itself (`conv_frames` 0) for one that
 * reuses earlier frames, whose history already is its accumulation and whose correlated frames
 * are never averaged (docs/benchmarks.md, "Two regimes"). */
struct job_row {
    uint32_t frame;
    double time_s, render_ms;
    bool has_metrics, has_conv;
    bool conv_is_frame;              /* `conv` scores the frame (a method that reuses frames), not an accumulation */
    uint32_t conv_frames;
    struct metrics m, conv;
};

struct session;

struct job {
    char id[24];
    char idempotency_key[65];
    uint64_t request_hash;           /* what the keyed request asked for (see api_job_replay); set at creation */
    enum job_kind kind;
    enum job_status status;          /* under the session lock */
    bool released;                   /* under the session lock: its worker has let go of it, so
                                        the session may forget it (session_job_add) */
    atomic_bool cancel;
    struct session *session;         /* not retained: the session outlives its jobs' records,
                                        and a queued job holds a session reference itself */
    uint32_t epoch;                  /* the session's sequence its frames belong to */
    uint32_t frames_total, frames_done;
    uint32_t *frames;                /* session frame numbers, frames_done of them */
    struct job_row *rows;            /* animation: one per frame */
    /* animation */
    double fps;
    struct view_animation anim;      /* arrays owned by the job */
    struct ref_image *reference;     /* retained while the job runs, or NULL */
    /* reference (an animation's: the name of the one it is measured against, or "") */
    char ref_name[65];
    uint32_t ref_spp;
    enum protocol_reference_method ref_method;
    struct scene *ref_scene;         /* retained: the session's scene when submitted */
    struct camera_desc ref_camera;
    /* failure */
    int error_status;
    char error_slug[32];
    struct err error;
};

struct session_frame {
    bool valid;
    uint32_t n;
    struct image img;
    struct frame_stats stats;
    char job[24];
};

struct session_event {
    uint64_t seq;
    char type[12];
    char *data;                      /* JSON text, malloc'd */
};

struct session {
    char id[24];
    char scene_id[65];
    atomic_int refcount;
    pthread_mutex_t lock;
    pthread_cond_t cond;             /* signalled on new events and on deletion */
    bool busy, deleted;
    struct view view;
    uint32_t epoch;                  /* bumped by reset: frame numbers restart */
    /* Copies of view state published under the lock for readers that do not hold `busy`. */
    uint32_t frames_done;            /* frames rendered in this sequence (= view.frame) */
    struct camera_desc camera;       /* the camera of the last frame (= view.camera) */
    uint32_t frames_kept;
    struct session_frame *ring;      /* frames_kept slots, frame n in slot n % frames_kept */
    uint64_t event_seq;              /* next event number */
    struct session_event events[SESSION_EVENTS];
    struct job *jobs[SESSION_JOBS];
    uint32_t job_count;
    uint64_t next_job;
    struct budget *budget;           /* reserved from at creation; NULL = none */
    uint64_t budget_bytes;
};

struct sessions;

struct sessions *sessions_new(uint32_t max_sessions);
/* Frees the table; every session must have been removed (sessions_remove_all). */
void sessions_free(struct sessions *t);

/* Creates a session on `scene` (retained by its view). Errors: ERR_BUSY (max_sessions),
 * ERR_INVALID, ERR_NOMEM. The new session is returned retained. */
/* `id` NULL = a generated id; otherwise that id (ERR_CONFLICT if taken). `budget_bytes`, already
 * reserved by the caller from `budget` (BUDGET_SESSIONS; NULL = none), become the session's:
 * given back when it is freed, or at once when the creation fails. */
struct session *sessions_create(struct sessions *t, const char *scene_id, const char *id, struct scene *scene,
                                const struct view_params *params, uint32_t frames_kept, unsigned threads,
                                struct budget *budget, uint64_t budget_bytes, struct err *err);
/* Clears the history of a claimed session (frame numbers restart, kept frames dropped). */
void session_reset(struct session *s);
/* Forgets a job that never ran (its submission failed). */
void session_job_forget(struct session *s, struct job *j);
/* The session, retained, or NULL. */
struct session *sessions_get(struct sessions *t, const char *scene_id, const char *sid);
/* Removes it from the table, cancels its job, ends its event streams. false when unknown. */
bool sessions_remove(struct sessions *t, const char *scene_id, const char *sid);
/* Removes every session (shutdown). */
void sessions_remove_all(struct sessions *t);
/* Retained sessions of a scene (NULL scene_id = all) into out[max]; returns the count stored. */
uint32_t sessions_list(struct sessions *t, const char *scene_id, struct session **out, uint32_t max);
uint32_t sessions_count(struct sessions *t);

void session_retain(struct session *s);
void session_release(struct session *s);

/* The most a session of these parameters holds: its view's buffers and `frames_kept` frames
 * (what the budget reserves for it, before anything is allocated). */
uint64_t session_bytes_planned(const struct view_params *params, const struct scene *scene, uint32_t frames_kept);
/* Memory of the session: its view's buffers plus kept frames. */
size_t session_bytes(struct session *s);

/* Claims the session for one frame or a job; ERR_CONFLICT when busy or deleted. */
bool session_claim(struct session *s, struct err *err);
void session_unclaim(struct session *s);
/* The same with s->lock held by the caller. */
void session_unclaim_locked(struct session *s);

/* Renders the next frame of a claimed session through the gate (bounded = a synchronous
 * request, which may be refused with ERR_BUSY when the queue is full), keeps it, and posts a
 * `frame` event. *n gets the frame number. `job` may be NULL. The image stays in the ring:
 * use session_frame_copy to read it.
 * The frame is given up, nothing kept, when the session is deleted (ERR_NOT_FOUND) or `stop`
 * (may be NULL; polled about every 20 ms) says its requester has gone (ERR_CONFLICT):
 * before it starts when it waited in the queue, and mid-frame for the methods that render in
 * samples per pixel (the methods that take spp), after which the session's sequence starts over.
 * A whole frame is kept when its requester has gone, not when its session was deleted. */
bool session_render(struct session *s, struct gate *gate, bool bounded, const struct view_frame_change *change,
                    struct job *job, uint32_t *n, struct frame_stats *stats, bool (*stop)(void *ctx), void *stop_ctx,
                    struct err *err);

/* Copies kept frame n (image and stats). ERR_NOT_FOUND when never rendered in this sequence,
 * ERR_LIMIT when rendered but evicted. `out` is initialised on success. */
bool session_frame_copy(struct session *s, uint32_t n, struct image *out, struct frame_stats *stats,
                        struct err *err);

/* Whether frame n of sequence `epoch` is still kept. Call with s->lock held. */
bool session_frame_kept_locked(const struct session *s, uint32_t epoch, uint32_t n);

/* Appends an event (type and JSON data, copied) and wakes readers. */
void session_post_event(struct session *s, const char *type, const char *json);

/* Jobs. A new job (QUEUED, its key and `request_hash` set; NULL on ERR_NOMEM) is filled in by
 * its caller, then added to the session; job_destroy frees one that was not added. */
struct job *job_new(struct session *s, enum job_kind kind, const char *idempotency_key, uint64_t request_hash,
                    struct err *err);
/* Adds j and gives it its id, and with `claim` claims the session for it (an animation, which
 * stays claimed until it ends). A full list first forgets (frees) its oldest job that is
 * released: finished, and let go of by its worker, which still reads a finished job while it
 * posts the job's last event. When a job of the session already has j's idempotency key,
 * nothing is added or claimed: false with *exists set. Other errors: ERR_CONFLICT/ERR_NOT_FOUND
 * (the session is busy or deleted), ERR_BUSY (too many unfinished jobs). */
bool session_job_add(struct session *s, struct job *j, bool claim, bool *exists, struct err *err);
/* Calls use(s, j, ctx) on the session's job `rid` with the session lock held, for everything a
 * request reads or sets of a job: a submission may forget (free) a finished job as soon as the
 * lock is let go, so a job found under one locked section is not used in another. false, and
 * use is not called, when the session has no such job. */
bool session_job_use(struct session *s, const char *rid, void (*use)(struct session *s, struct job *j, void *ctx),
                     void *ctx);
/* Both: call with s->lock held. */
struct job *session_job_find(struct session *s, const char *rid);
struct job *session_job_find_key(struct session *s, const char *key);
void job_destroy(struct job *j);

#endif
