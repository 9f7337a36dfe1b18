/* test_jobs.c — the job workers (server/jobs.c) against a session's job records
 * (server/session.c), driven directly: the records a session forgets to make room for new jobs
 * are never ones a worker still uses or a request is reading, and an animation whose session is
 * deleted mid-frame ends cancelled. A use after free here shows under the sanitizers (make
 * SAN=1, make test-tsan); the plain build checks the events the workers post and the ids of the
 * records requests read. */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "jobs.h"
#include "scene_fixture.h"
#include "session.h"
#include "test.h"

struct fixture {
    struct scene *scene;
    struct gate gate;
    struct refstore *refs;
    struct sessions *table;
    struct session *s;       /* retained by the test */
    struct jobs *q;
};

static bool fixture_open(struct fixture *f, uint32_t side, uint32_t spp)
{
    memset(f, 0, sizeof *f);
    f->scene = fixture_load("scenes/cornell-box/scene.json");
    if (!f->scene) return false;
    struct err err = {0};
    gate_init(&f->gate, 1, 4);
    f->refs = refstore_new(NULL);
    f->table = sessions_new(2);
    struct view_params p = view_params_defaults(method_find("pt"), side, side);
    CHECK(view_params_set_uint(&p, "spp", spp));
    f->s = sessions_create(f->table, "cb", NULL, f->scene, &p, 2, 1, NULL, 0, &err);
    CHECK_MSG(f->s != NULL, "%s", err.message);
    f->q = f->s ? jobs_new(1, 2 * SESSION_JOBS, &f->gate, f->refs, NULL, NULL, &err) : NULL;
    CHECK_MSG(!f->s || f->q != NULL, "%s", err.message);
    return f->q != NULL;
}

static void fixture_close(struct fixture *f)
{
    jobs_stop(f->q);
    if (f->table) sessions_remove_all(f->table);
    session_release(f->s);
    sessions_free(f->table);
    refstore_free(f->refs);
    gate_destroy(&f->gate);
    scene_release(f->scene);
}

static void sleep_ms(long ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

static enum job_status job_status(struct session *s, const struct job *j)
{
    pthread_mutex_lock(&s->lock);
    enum job_status st = j->status;
    pthread_mutex_unlock(&s->lock);
    return st;
}

static bool gate_rendering(struct gate *g)
{
    pthread_mutex_lock(&g->lock);
    bool busy = g->running > 0;
    pthread_mutex_unlock(&g->lock);
    return busy;
}

/* Adds and queues a one-pass, one-sample reference job as POST …/references/{name} does;
 * false when the session's records are all unfinished jobs (ERR_BUSY). */
static bool add_tiny_reference(struct fixture *f, unsigned i)
{
    struct err e = {0};
    struct job *j = job_new(f->s, JOB_REFERENCE, NULL, 0, &e);
    if (!j) return false;
    snprintf(j->ref_name, sizeof j->ref_name, "ref%u", i % 4);
    j->frames_total = 1;
    j->ref_spp = 1;
    j->ref_method = PROTOCOL_REFERENCE_PT;
    bool exists;
    if (!session_job_add(f->s, j, true, &exists, &e)) {
        CHECK_MSG(e.code == ERR_BUSY, "%s", e.message);
        job_destroy(j);
        return false;
    }
    j->ref_scene = f->s->view.scene;
    scene_retain(j->ref_scene);
    j->ref_camera = f->s->view.camera;
    session_unclaim(f->s);
    bool queued = jobs_submit(f->q, j, &e);
    CHECK_MSG(queued, "%s", e.message);
    if (!queued) session_job_forget(f->s, j);
    return queued;
}

/* Adds and queues an animation of `frames` still frames at 30 fps, claiming the session as
 * POST …/renders does; NULL (after a failed CHECK) when it could not. */
static struct job *submit_animation(struct fixture *f, uint32_t frames)
{
    struct err e = {0};
    struct job *j = job_new(f->s, JOB_ANIMATION, NULL, 0, &e);
    CHECK(j != NULL);
    if (!j) return NULL;
    j->fps = 30;
    j->frames_total = frames;
    j->frames = calloc(frames, sizeof *j->frames);
    j->rows = calloc(frames, sizeof *j->rows);
    bool exists, added = j->frames && j->rows && session_job_add(f->s, j, true, &exists, &e);
    CHECK_MSG(added, "%s", e.message);
    if (!added) {
        job_destroy(j);
        return NULL;
    }
    bool queued = jobs_submit(f->q, j, &e);
    CHECK_MSG(queued, "%s", e.message);
    return queued ? j : NULL;
}

/* Adds tiny references, as many as 20000 or as fit in 3 s, each as soon as the session has a
 * record to spare. */
static void add_tiny_references(struct fixture *f)
{
    struct timespec t0, t;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    unsigned added = 0;
    while (added < 20000) {
        if (add_tiny_reference(f, added)) added++;
        clock_gettime(CLOCK_MONOTONIC, &t);
        if (t.tv_sec - t0.tv_sec >= 3) break;  /* enough rounds on a slow build */
    }
    CHECK_MSG(added > 100, "only %u jobs added", added);
}

/* The session's records fill with queued jobs faster than the one worker ends them, so each
 * job the worker ends is at once the oldest finished record, which the next add forgets while
 * the worker may still be posting its `done` event. */
static void test_finished_jobs_are_forgotten_only_once_their_worker_let_go(void)
{
    struct fixture f;
    if (!fixture_open(&f, 2, 1)) {
        fixture_close(&f);
        return;
    }
    add_tiny_references(&f);
    jobs_stop(f.q);
    f.q = NULL;
    /* Every `done` event names a job by its id and a final status: one read from a record
     * freed (and reused by the next job) would show another job's or an empty id, or `queued`. */
    pthread_mutex_lock(&f.s->lock);
    unsigned dones = 0;
    for (uint64_t seq = f.s->event_seq > SESSION_EVENTS ? f.s->event_seq - SESSION_EVENTS : 0; seq < f.s->event_seq;
         seq++) {
        const struct session_event *ev = &f.s->events[seq % SESSION_EVENTS];
        if (strcmp(ev->type, "done") != 0 || !ev->data) continue;
        dones++;
        CHECK_MSG(strstr(ev->data, "\"job\":\"r") != NULL, "%s", ev->data);
        CHECK_MSG(strstr(ev->data, "\"status\":\"done\"") || strstr(ev->data, "\"status\":\"cancelled\""), "%s",
                  ev->data);
    }
    CHECK(dones > 0);
    for (uint32_t i = 0; i < f.s->job_count; i++) CHECK(f.s->jobs[i]->status >= JOB_DONE && f.s->jobs[i]->released);
    pthread_mutex_unlock(&f.s->lock);
    fixture_close(&f);
}

/* A reader that looks jobs up by id as GET/DELETE …/renders/{rid} and its metrics do
 * (session_job_use), always the session's oldest record: the one the next add forgets. */
struct job_reader {
    struct session *s;
    atomic_bool stop;
    unsigned looked, found, wrong;   /* read by the test once the reader has ended */
};

struct job_lookup {
    char rid[24];
    bool same;                       /* the record found is job rid's */
};

static void job_reader_check(struct session *s, struct job *j, void *ctx)
{
    (void)s;
    struct job_lookup *l = ctx;
    /* A record freed meanwhile (and perhaps reused by the next job) has another or no id. */
    l->same = strcmp(j->id, l->rid) == 0 && j->kind == JOB_REFERENCE && strncmp(j->ref_name, "ref", 3) == 0;
}

static void *job_reader_run(void *arg)
{
    struct job_reader *r = arg;
    while (!atomic_load(&r->stop)) {
        struct job_lookup l = {""};
        pthread_mutex_lock(&r->s->lock);
        if (r->s->job_count) snprintf(l.rid, sizeof l.rid, "%s", r->s->jobs[0]->id);
        pthread_mutex_unlock(&r->s->lock);
        if (!l.rid[0]) continue;
        r->looked++;
        if (session_job_use(r->s, l.rid, job_reader_check, &l)) {
            r->found++;
            if (!l.same) r->wrong++;
        }
    }
    return NULL;
}

/* Requests read a job while submissions to its session forget the oldest finished ones: what
 * a request reads of a job it found is never a record forgotten meanwhile. */
static void test_jobs_read_by_id_stay_valid_while_submissions_forget_old_ones(void)
{
    struct fixture f;
    if (!fixture_open(&f, 2, 1)) {
        fixture_close(&f);
        return;
    }
    struct job_reader r = {.s = f.s};
    atomic_init(&r.stop, false);
    pthread_t reader;
    CHECK(pthread_create(&reader, NULL, job_reader_run, &r) == 0);
    add_tiny_references(&f);
    atomic_store(&r.stop, true);
    pthread_join(reader, NULL);
    CHECK_MSG(r.found > 100, "%u of %u lookups found their job", r.found, r.looked);
    CHECK_MSG(r.wrong == 0, "%u of %u jobs found were another job's record", r.wrong, r.found);
    fixture_close(&f);
}

/* An animation whose session is deleted while a frame renders ends cancelled, as a DELETE of
 * the session promises, not failed. The session is deleted once the frame holds the render
 * gate, so within the frame (or just before it starts rendering), never between frames, where
 * the cancel flag the deletion sets ends the job anyway. */
static void test_animation_ends_cancelled_when_its_session_is_deleted_mid_frame(void)
{
    struct fixture f;
    if (!fixture_open(&f, 32, 4096)) {  /* a frame of seconds, cut within 20 ms of the deletion */
        fixture_close(&f);
        return;
    }
    struct job *j = submit_animation(&f, 2);
    if (!j) {
        fixture_close(&f);
        return;
    }
    for (int ms = 0; ms < 10000 && job_status(f.s, j) <= JOB_RUNNING && !gate_rendering(&f.gate); ms++) sleep_ms(1);
    CHECK(job_status(f.s, j) == JOB_RUNNING);
    CHECK(sessions_remove(f.table, "cb", f.s->id));
    jobs_stop(f.q);  /* waits for the worker */
    f.q = NULL;
    pthread_mutex_lock(&f.s->lock);
    CHECK_MSG(j->status == JOB_CANCELLED, "status %d, error %s", (int)j->status, j->error.message);
    CHECK(j->frames_done == 0);
    const struct session_event *last = &f.s->events[(f.s->event_seq - 1) % SESSION_EVENTS];
    CHECK_MSG(strcmp(last->type, "done") == 0 && last->data && strstr(last->data, "\"status\":\"cancelled\""),
              "%s %s", last->type, last->data ? last->data : "");
    pthread_mutex_unlock(&f.s->lock);
    fixture_close(&f);
}

/* A client that sees an animation ended (its status, or the `done` event) renders the session's
 * next frame at once: the session must not still be claimed by the ended job, or that frame is
 * refused as busy. The status and the claim are read in one step, as a request reads them; the
 * worker used to give the claim back only after posting `done`. */
static void test_an_ended_animation_has_given_its_session_back(void)
{
    struct fixture f;
    if (!fixture_open(&f, 8, 1)) {
        fixture_close(&f);
        return;
    }
    int still_claimed = 0, rounds = 0;
    for (; rounds < 200; rounds++) {
        struct job *j = submit_animation(&f, 1);
        if (!j) break;
        enum job_status st = JOB_QUEUED;
        bool busy = true;
        struct timespec t0, t;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        do {  /* spins: the window between the two used to be microseconds */
            pthread_mutex_lock(&f.s->lock);
            st = j->status;
            busy = f.s->busy;
            pthread_mutex_unlock(&f.s->lock);
            clock_gettime(CLOCK_MONOTONIC, &t);
        } while (st <= JOB_RUNNING && t.tv_sec - t0.tv_sec < 20);
        CHECK_MSG(st == JOB_DONE, "round %d: status %d, error %s", rounds, (int)st, j->error.message);
        if (st != JOB_DONE) break;
        still_claimed += busy;
        bool released = false;  /* the next add may forget this record only once it is let go */
        for (int ms = 0; ms < 10000 && !released; ms++) {
            pthread_mutex_lock(&f.s->lock);
            released = j->released;
            pthread_mutex_unlock(&f.s->lock);
            if (!released) sleep_ms(1);
        }
        CHECK(released);
        if (!released) break;
    }
    CHECK_MSG(still_claimed == 0, "the session was still claimed when %d of %d ended animations were seen done",
              still_claimed, rounds);
    fixture_close(&f);
}

TEST_MAIN(TEST(test_finished_jobs_are_forgotten_only_once_their_worker_let_go),
          TEST(test_jobs_read_by_id_stay_valid_while_submissions_forget_old_ones),
          TEST(test_animation_ends_cancelled_when_its_session_is_deleted_mid_frame),
          TEST(test_an_ended_animation_has_given_its_session_back))
