/* test_api_jobs.c — POST …/renders and POST …/references/{name} through the daemon's HTTP front
 * (server/http.c, api*.c) on loopback, with a stand-in job pool: this file defines jobs_submit
 * and jobs_queued, the only functions of server/jobs.c the API calls, so the library's jobs.o is
 * never linked. The stand-in does inside jobs_submit what workers and other requests may do as
 * soon as a job is queued: it runs the job to its end and lets go of it as a worker does, and
 * then another job is added to the session, which forgets (frees) the finished one to make room.
 * A handler that reads its job after jobs_submit reads freed memory: heap-use-after-free under
 * make SAN=1, and in the plain build a 202 that shows the job `done` or another id. */
#include <arpa/inet.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include "api.h"
#include "http.h"
#include "test.h"

/* ---- the stand-in job pool ---- */

enum pool_mode {
    POOL_HOLD,              /* keep the job queued until the test ends */
    POOL_FINISH_AND_FORGET, /* end it at once, then let the session forget it (see the top) */
    POOL_REFUSE             /* the queue is full */
};

struct jobs {
    pthread_mutex_t lock;   /* the test sets the mode; jobs_submit runs on a connection thread */
    enum pool_mode mode;
    struct job *held[SESSION_JOBS];
    unsigned held_count;
};

/* What a worker does last with every job it takes (jobs_worker): the final status with the
 * animation's claim, the job let go of and the session reference jobs_submit took given back. From here
 * on, a job added to the session may free this one. */
static void pool_end_job(struct job *j, enum job_status status)
{
    struct session *s = j->session;
    pthread_mutex_lock(&s->lock);
    j->status = status;
    if (j->kind == JOB_ANIMATION) session_unclaim_locked(s);
    j->released = true;
    pthread_mutex_unlock(&s->lock);
    session_release(s);
}

/* Another request's job added to the session, as its POST does before queueing it: with the
 * session's SESSION_JOBS records taken, it forgets the oldest one its worker has let go of. */
static void pool_add_other_job(struct session *s)
{
    struct err e = {0};
    struct job *other = job_new(s, JOB_REFERENCE, NULL, 0, &e);
    bool exists;
    bool added = other && session_job_add(s, other, false, &exists, &e);
    CHECK_MSG(added, "%s", e.message);
    if (!added) job_destroy(other);
}

bool jobs_submit(struct jobs *q, struct job *j, struct err *err)
{
    pthread_mutex_lock(&q->lock);
    enum pool_mode mode = q->mode;
    bool full = mode == POOL_REFUSE || (mode == POOL_HOLD && q->held_count == SESSION_JOBS);
    if (!full) session_retain(j->session);  /* as the real pool: a queued job holds its session */
    if (!full && mode == POOL_HOLD) q->held[q->held_count++] = j;
    pthread_mutex_unlock(&q->lock);
    if (full) return err_set(err, ERR_BUSY, NULL, "the job queue is full (stand-in pool)"), false;
    if (mode == POOL_FINISH_AND_FORGET) {
        struct session *s = j->session;  /* the handler's reference keeps it */
        pool_end_job(j, JOB_DONE);
        pool_add_other_job(s);
    }
    return true;
}

unsigned jobs_queued(struct jobs *q)
{
    pthread_mutex_lock(&q->lock);
    unsigned n = q->held_count;
    pthread_mutex_unlock(&q->lock);
    return n;
}

static void pool_set_mode(struct jobs *q, enum pool_mode mode)
{
    pthread_mutex_lock(&q->lock);
    q->mode = mode;
    pthread_mutex_unlock(&q->lock);
}

/* Ends the held jobs cancelled, as jobs_stop does, so their sessions can be freed. */
static void pool_end_held(struct jobs *q)
{
    pthread_mutex_lock(&q->lock);
    for (unsigned i = 0; i < q->held_count; i++) pool_end_job(q->held[i], JOB_CANCELLED);
    q->held_count = 0;
    pthread_mutex_unlock(&q->lock);
}

/* ---- the daemon under test and a client ---- */

struct fixture {
    struct daemon d;
    struct jobs pool;
    struct http *http;
    uint16_t port;
    char data_dir[64];
    char session[192];       /* the href of the session the test works on */
};

struct reply {
    int status;
    char location[256];      /* "" when absent */
    char body[16384];
};

/* One request on a connection of its own; false (a failed CHECK) when it got no answer. */
static bool call(const struct fixture *f, const char *method, const char *path, const char *json, struct reply *out)
{
    memset(out, 0, sizeof *out);
    char req[1024];
    int len = snprintf(req, sizeof req, "%s %s HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n", method, path);
    if (json)
        len += snprintf(req + len, sizeof req - (size_t)len,
                        "Content-Type: application/json\r\nContent-Length: %zu\r\n\r\n%s", strlen(json), json);
    else
        len += snprintf(req + len, sizeof req - (size_t)len, "\r\n");
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in addr = {.sin_family = AF_INET, .sin_port = htons(f->port)};
    addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    struct timeval timeout = {30, 0};
    bool ok = fd >= 0 && setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout) == 0 &&
              connect(fd, (struct sockaddr *)&addr, sizeof addr) == 0 && send(fd, req, (size_t)len, 0) == len;
    static char raw[32768];  /* one call at a time: the test's own thread */
    size_t got = 0;
    while (ok && got < sizeof raw - 1) {  /* Connection: close, so the answer ends the stream */
        ssize_t n = recv(fd, raw + got, sizeof raw - 1 - got, 0);
        if (n <= 0) break;
        got += (size_t)n;
    }
    if (fd >= 0) close(fd);
    raw[got] = '\0';
    char *body = strstr(raw, "\r\n\r\n");
    ok = ok && body && sscanf(raw, "HTTP/1.1 %d", &out->status) == 1;
    CHECK_MSG(ok, "%s %s: no answer", method, path);
    if (!ok) return false;
    *body = '\0';
    const char *loc = strstr(raw, "\r\nLocation: ");
    if (loc) snprintf(out->location, sizeof out->location, "%.*s", (int)strcspn(loc + 12, "\r"), loc + 12);
    snprintf(out->body, sizeof out->body, "%s", body + 4);
    return true;
}

/* The string member `key` of a JSON object written by the daemon (compact) into out, or "". */
static void json_string_member(const char *json, const char *key, char *out, size_t size)
{
    char pattern[64];
    snprintf(pattern, sizeof pattern, "\"%s\":\"", key);
    const char *at = strstr(json, pattern);
    if (at) at += strlen(pattern);
    snprintf(out, size, "%.*s", at ? (int)strcspn(at, "\"") : 0, at ? at : "");
}

static void fixture_close(struct fixture *f)
{
    pool_end_held(&f->pool);
    http_stop(f->http);
    if (f->d.sessions) sessions_remove_all(f->d.sessions);
    sessions_free(f->d.sessions);
    refstore_free(f->d.refs);
    registry_free(f->d.registry);
    budget_destroy(&f->d.budget);
    gate_destroy(&f->d.gate);
    prom_destroy(&f->d.prom);
    pthread_mutex_destroy(&f->pool.lock);
    if (f->data_dir[0]) {
        /* The registry makes only its scenes/ folder there: nothing is uploaded. */
        char scenes[sizeof f->data_dir + 8];
        snprintf(scenes, sizeof scenes, "%s/scenes", f->data_dir);
        rmdir(scenes);
        rmdir(f->data_dir);
    }
}

/* The daemon's state as main.c builds it, on the built-in scenes and a fresh data directory,
 * listening on a free loopback port, with an 8x8 session of the Cornell box. */
static bool fixture_open(struct fixture *f)
{
    memset(f, 0, sizeof *f);
    pthread_mutex_init(&f->pool.lock, NULL);
    struct daemon_config *cfg = &f->d.cfg;
    snprintf(cfg->host, sizeof cfg->host, "127.0.0.1");
    cfg->limits = daemon_default_limits();
    cfg->max_sessions = 4;
    cfg->frames_kept = 2;
    cfg->memory_budget = 1ull << 30;
    cfg->max_session_bytes = 1ull << 30;
    cfg->max_json_body = 1u << 20;
    cfg->threads = 1;
    cfg->max_work = 1ull << 32;
    budget_init(&f->d.budget, cfg->memory_budget);
    gate_init(&f->d.gate, 1, 4);
    prom_init(&f->d.prom);
    atomic_init(&f->d.draining, false);
    atomic_init(&f->d.loaded, true);
    atomic_init(&f->d.stop_loading, false);
    f->d.jobs = &f->pool;
    snprintf(f->data_dir, sizeof f->data_dir, "/tmp/restird-api-jobs-XXXXXX");
    if (!mkdtemp(f->data_dir)) f->data_dir[0] = '\0';
    CHECK(f->data_dir[0]);
    struct err e = {0};
    f->d.registry = f->data_dir[0] ? registry_new("scenes", f->data_dir, NULL, NULL, &e) : NULL;
    CHECK_MSG(f->d.registry, "%s", e.message);
    if (f->d.registry) registry_set_budget(f->d.registry, &f->d.budget);
    f->d.sessions = sessions_new(cfg->max_sessions);
    f->d.refs = refstore_new(&f->d.budget);
    const struct http_options ho = {.host = cfg->host, .connection_limit = 16, .per_ip_limit = 16, .timeout_s = 30};
    const struct http_app app = {.ctx = &f->d, .body_policy = api_body_policy, .handle = api_handle,
                                 .reject = api_reject, .reject_framing = api_reject_framing,
                                 .body_charge = api_body_charge, .body_release = api_body_release};
    f->http = f->d.registry && f->d.sessions && f->d.refs ? http_start(&ho, &app, &f->port, &e) : NULL;
    CHECK_MSG(f->http, "%s", e.message);
    if (!f->http) return false;
    struct reply r;
    if (!call(f, "POST", "/v1/scenes/cornell-box/sessions", "{\"width\": 8, \"height\": 8}", &r)) return false;
    CHECK_MSG(r.status == 201, "%d %s", r.status, r.body);
    json_string_member(r.body, "href", f->session, sizeof f->session);
    return r.status == 201 && f->session[0];
}

/* SESSION_JOBS - 1 references the stand-in pool keeps queued: the session's records are then
 * one short of full, so the next job added fills them and the one after forgets the oldest
 * record let go of. */
static bool hold_all_records_but_one(struct fixture *f)
{
    pool_set_mode(&f->pool, POOL_HOLD);
    bool ok = true;
    for (unsigned i = 0; ok && i < SESSION_JOBS - 1; i++) {
        char path[256];
        snprintf(path, sizeof path, "%s/references/held%u", f->session, i);
        struct reply r;
        ok = call(f, "POST", path, "{\"spp\": 1}", &r) && r.status == 202;
        CHECK_MSG(ok, "%s: %d %s", path, r.status, r.body);
    }
    return ok;
}

/* The two POSTs that queue a job: the path under the session, a body, and the job's kind. */
struct job_post {
    const char *path, *json, *kind;
};
static const struct job_post reference_post = {"/references/fast", "{\"spp\": 1}", "reference"};
static const struct job_post render_post = {"/renders", "{\"animation\": {\"fps\": 10, \"frames\": 1}}", "animation"};

/* Sends `post` to a session whose records are all taken but one, with a pool that ends the job,
 * and lets the session forget it, before jobs_submit returns: the 202 is the job as it was
 * queued, and names it in its body and its Location alike. */
static void check_answer_precedes_forgetting(const struct job_post *post)
{
    struct fixture f;
    if (!fixture_open(&f) || !hold_all_records_but_one(&f)) {
        fixture_close(&f);
        return;
    }
    pool_set_mode(&f.pool, POOL_FINISH_AND_FORGET);
    char path[256];
    snprintf(path, sizeof path, "%s%s", f.session, post->path);
    struct reply r;
    if (call(&f, "POST", path, post->json, &r)) {
        CHECK_MSG(r.status == 202, "%d %s", r.status, r.body);
        char id[32], status[32], kind[32], location[256];
        json_string_member(r.body, "id", id, sizeof id);
        json_string_member(r.body, "status", status, sizeof status);
        json_string_member(r.body, "kind", kind, sizeof kind);
        json_string_member(r.body, "location", location, sizeof location);
        CHECK_MSG(strcmp(status, "queued") == 0, "status '%s' in %s", status, r.body);
        CHECK_MSG(strcmp(kind, post->kind) == 0, "kind '%s' in %s", kind, r.body);
        char want[256];
        snprintf(want, sizeof want, "%s/renders/%s", f.session, id);
        CHECK_MSG(id[0] == 'r' && strcmp(r.location, want) == 0 && strcmp(location, want) == 0,
                  "id '%s', Location '%s', location '%s'", id, r.location, location);
        /* The premise: the job was forgotten before the POST answered (so a read of it after
         * jobs_submit would have been a read of freed memory). */
        char member[64];
        snprintf(member, sizeof member, "\"id\":\"%s\"", id);
        snprintf(path, sizeof path, "%s/renders", f.session);
        if (call(&f, "GET", path, NULL, &r))
            CHECK_MSG(r.status == 200 && !strstr(r.body, member), "%d, %s still listed", r.status, id);
    }
    fixture_close(&f);
}

static void test_reference_post_answers_before_its_job_can_be_freed(void)
{
    check_answer_precedes_forgetting(&reference_post);
}

static void test_render_post_answers_before_its_job_can_be_freed(void)
{
    check_answer_precedes_forgetting(&render_post);
}

/* A job the queue refuses: 429 queue-full with no Location (the 202 written before the
 * submission is dropped), the job forgotten, and an animation's claim on the session let go. */
static void test_refused_submission_answers_429_and_forgets_the_job(void)
{
    struct fixture f;
    if (!fixture_open(&f)) {
        fixture_close(&f);
        return;
    }
    pool_set_mode(&f.pool, POOL_REFUSE);
    char path[256];
    struct reply r;
    const struct job_post *const posts[] = {&reference_post, &render_post};
    for (size_t i = 0; i < sizeof posts / sizeof posts[0]; i++) {
        snprintf(path, sizeof path, "%s%s", f.session, posts[i]->path);
        if (!call(&f, "POST", path, posts[i]->json, &r)) continue;
        CHECK_MSG(r.status == 429 && strstr(r.body, "queue-full") && !r.location[0], "%s: %d, Location '%s', %s", path,
                  r.status, r.location, r.body);
    }
    snprintf(path, sizeof path, "%s/renders", f.session);
    if (call(&f, "GET", path, NULL, &r)) CHECK_MSG(r.status == 200 && strstr(r.body, "\"renders\":[]"), "%s", r.body);
    if (call(&f, "GET", f.session, NULL, &r))
        CHECK_MSG(r.status == 200 && strstr(r.body, "\"busy\":false"), "%d %s", r.status, r.body);
    fixture_close(&f);
}

TEST_MAIN(TEST(test_reference_post_answers_before_its_job_can_be_freed),
          TEST(test_render_post_answers_before_its_job_can_be_freed),
          TEST(test_refused_submission_answers_429_and_forgets_the_job))
