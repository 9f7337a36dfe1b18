/* test_parallel.c — parallel_run's contract: every job runs exactly once, worker indices are
 * < threads and never shared by two executors at the same moment, progress comes from the
 * calling thread with a non-decreasing count and a final (total, total); concurrent and nested
 * callers, parallel_shutdown (idempotent, and the pool comes back after it), and the per-call
 * overhead of many small runs (printed). Jobs only record into atomics; the CHECKs run on the
 * test's own thread. */
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <time.h>

#include "core/parallel.h"
#include "test.h"

#define MAX_WORKERS 1024

struct run_ctx {
    uint32_t job_count;
    unsigned threads;
    _Atomic uint32_t *hits;                /* per job */
    _Atomic uint32_t in_use[MAX_WORKERS];  /* per worker index: executors inside a job */
    _Atomic uint32_t bad_worker;           /* worker >= threads */
    _Atomic uint32_t shared_worker;        /* two executors with one index at once */
    _Atomic uint32_t bad_job;              /* job >= job_count */
    unsigned spin;                         /* busy work per job, to overlap executors */
};

static void record_job(void *vctx, uint32_t job, unsigned worker)
{
    struct run_ctx *c = vctx;
    if (job >= c->job_count) {
        atomic_fetch_add(&c->bad_job, 1);
        return;
    }
    if (worker >= c->threads || worker >= MAX_WORKERS) {
        atomic_fetch_add(&c->bad_worker, 1);
    } else if (atomic_fetch_add(&c->in_use[worker], 1) != 0) {
        atomic_fetch_add(&c->shared_worker, 1);
    }
    volatile unsigned sink = 0;
    for (unsigned i = 0; i < c->spin; i++) sink += i;
    (void)sink;
    atomic_fetch_add(&c->hits[job], 1);
    if (worker < c->threads && worker < MAX_WORKERS) atomic_fetch_sub(&c->in_use[worker], 1);
}

struct progress_log {
    pthread_t caller;
    uint32_t calls, last_done, last_total;
    bool wrong_thread, went_back, over_total;
};

static void record_progress(void *vctx, uint32_t done, uint32_t total)
{
    struct progress_log *p = vctx;
    if (!pthread_equal(pthread_self(), p->caller)) p->wrong_thread = true;
    if (p->calls > 0 && done < p->last_done) p->went_back = true;
    if (done > total) p->over_total = true;
    p->calls++;
    p->last_done = done;
    p->last_total = total;
}

/* Runs one parallel_run and checks everything about it; returns false on any failure (and
 * CHECKs only when `check` is set, i.e. on the test's main thread). */
static bool run_and_verify(unsigned threads, uint32_t job_count, bool with_progress, unsigned spin, bool check)
{
    struct run_ctx *c = calloc(1, sizeof *c);
    _Atomic uint32_t *hits = calloc(job_count ? job_count : 1, sizeof *hits);
    if (!c || !hits) {
        free(c);
        free(hits);
        if (check) CHECK(!"out of memory in the test");
        return false;
    }
    c->job_count = job_count;
    c->threads = threads ? threads : parallel_default_threads();
    if (c->threads > MAX_WORKERS) c->threads = MAX_WORKERS;
    c->hits = hits;
    c->spin = spin;
    struct progress_log log = {.caller = pthread_self()};
    struct err err = {0};
    bool ran = parallel_run(threads, job_count, record_job, c, with_progress ? record_progress : NULL, &log, &err);
    uint32_t missing = 0, repeated = 0;
    for (uint32_t j = 0; j < job_count; j++) {
        uint32_t h = atomic_load(&hits[j]);
        if (h == 0) missing++;
        if (h > 1) repeated++;
    }
    bool ok = ran && missing == 0 && repeated == 0 && !c->bad_worker && !c->shared_worker && !c->bad_job;
    if (with_progress) {
        ok = ok && log.calls >= 1 && !log.wrong_thread && !log.went_back && !log.over_total &&
             log.last_done == job_count && log.last_total == job_count;
    } else {
        ok = ok && log.calls == 0;
    }
    if (check && !ok) {
        CHECK_MSG(ok, "threads %u jobs %u progress %d: ran %d missing %u repeated %u bad_worker %u shared %u bad_job %u "
                      "progress calls %u last (%u,%u) wrong_thread %d went_back %d over %d (%s)",
                  threads, job_count, with_progress, ran, missing, repeated, (unsigned)c->bad_worker,
                  (unsigned)c->shared_worker, (unsigned)c->bad_job, log.calls, log.last_done, log.last_total,
                  log.wrong_thread, log.went_back, log.over_total, err.message);
    }
    free(hits);
    free(c);
    return ok;
}

static void test_every_job_runs_once(void)
{
    static const unsigned threads[] = {0, 1, 2, 3, 4, 7, 16, 33};
    static const uint32_t jobs[] = {0, 1, 2, 3, 5, 16, 17, 100, 1000, 4099};
    for (size_t t = 0; t < sizeof threads / sizeof threads[0]; t++) {
        for (size_t j = 0; j < sizeof jobs / sizeof jobs[0]; j++) {
            run_and_verify(threads[t], jobs[j], false, 0, true);
            run_and_verify(threads[t], jobs[j], true, 0, true);
            run_and_verify(threads[t], jobs[j], false, 2000, true);
        }
    }
}

static void test_more_threads_than_default_and_clamp(void)
{
    /* Grows the pool past the default, then smaller calls reuse it; 5000 asks for the cap. */
    run_and_verify(64, 10000, false, 100, true);
    run_and_verify(64, 10000, true, 100, true);
    run_and_verify(2, 100, false, 100, true);
    run_and_verify(5000, 3, false, 0, true);
    run_and_verify(5000, 3, true, 0, true);
}

static void slow_job(void *ctx, uint32_t job, unsigned worker)
{
    (void)job;
    (void)worker;
    struct timespec ts = {0, 1000 * 1000}; /* 1 ms */
    nanosleep(&ts, NULL);
    atomic_fetch_add((_Atomic uint32_t *)ctx, 1);
}

static void test_progress_during_and_at_end(void)
{
    /* 120 jobs of 1 ms on 2 threads: ~60 ms, so several 20 ms ticks before the final call. */
    _Atomic uint32_t count = 0;
    struct progress_log log = {.caller = pthread_self()};
    struct err err = {0};
    CHECK(parallel_run(2, 120, slow_job, &count, record_progress, &log, &err));
    CHECK(atomic_load(&count) == 120);
    CHECK_MSG(log.calls >= 2, "%u progress calls", log.calls);
    CHECK(!log.wrong_thread);
    CHECK(!log.went_back);
    CHECK(!log.over_total);
    CHECK(log.last_done == 120 && log.last_total == 120);
}

/* A job of 1 ms per "pixel" for 200 pixels that gives up between pixels once its run is
 * stopped; counts the pixels it did. */
struct stop_ctx {
    _Atomic uint32_t started, pixels, progress_calls;
};

static void stoppable_job(void *vctx, uint32_t job, unsigned worker)
{
    (void)job;
    (void)worker;
    struct stop_ctx *c = vctx;
    atomic_fetch_add(&c->started, 1);
    for (int i = 0; i < 200; i++) {
        if (parallel_stopped()) return;
        struct timespec ts = {0, 1000 * 1000};
        nanosleep(&ts, NULL);
        atomic_fetch_add(&c->pixels, 1);
    }
}

static void stop_after_two_calls(void *vctx, uint32_t done, uint32_t total)
{
    (void)done;
    (void)total;
    struct stop_ctx *c = vctx;
    if (atomic_fetch_add(&c->progress_calls, 1) >= 1) parallel_stop();
}

static void test_stop_from_progress(void)
{
    /* 64 jobs of 200 ms on 2 threads would take 6.4 s; stopped at the second progress call
     * (~20 ms), the running jobs end at their next pixel and no other job starts. */
    for (int round = 0; round < 2; round++) {
        struct stop_ctx c = {0};
        struct err err = {0};
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        CHECK(parallel_run(2, 64, stoppable_job, &c, stop_after_two_calls, &c, &err));
        clock_gettime(CLOCK_MONOTONIC, &t1);
        double s = (double)(t1.tv_sec - t0.tv_sec) + (double)(t1.tv_nsec - t0.tv_nsec) * 1e-9;
        CHECK_MSG(s < 1.0, "stopped run took %.3f s", s);
        CHECK_MSG(atomic_load(&c.started) <= 4, "%u jobs started", atomic_load(&c.started));
        CHECK_MSG(atomic_load(&c.pixels) < 200, "%u pixels done", atomic_load(&c.pixels));
        CHECK(!parallel_stopped());  /* outside a job */
    }
    /* The next run, without a stop, runs everything. */
    _Atomic uint32_t count = 0;
    struct progress_log log = {.caller = pthread_self()};
    struct err err = {0};
    CHECK(parallel_run(2, 120, slow_job, &count, record_progress, &log, &err));
    CHECK(atomic_load(&count) == 120);
}

struct caller_arg {
    unsigned threads;
    bool with_progress;
    int rounds;
    int failures;
};

static void *caller_main(void *varg)
{
    struct caller_arg *a = varg;
    for (int i = 0; i < a->rounds; i++) {
        uint32_t jobs = (uint32_t)(1 + (i * 37) % 300);
        if (!run_and_verify(a->threads, jobs, a->with_progress, (unsigned)(i % 3) * 500, false)) a->failures++;
    }
    return NULL;
}

static void test_concurrent_callers(void)
{
    /* Four threads call parallel_run at once, with and without progress: one owns the pool,
     * the others take the fallback path, and every call must still be exact. */
    struct caller_arg args[4] = {{2, false, 150, 0}, {4, false, 150, 0}, {3, true, 60, 0}, {0, false, 150, 0}};
    pthread_t tids[4];
    bool started[4] = {false};
    for (int i = 0; i < 4; i++) started[i] = pthread_create(&tids[i], NULL, caller_main, &args[i]) == 0;
    for (int i = 0; i < 4; i++) {
        CHECK(started[i]);
        if (started[i]) pthread_join(tids[i], NULL);
        CHECK_MSG(args[i].failures == 0, "caller %d: %d failed runs", i, args[i].failures);
    }
}

struct nested_ctx {
    _Atomic uint32_t outer_hits[8];
    _Atomic uint32_t inner_total;
    _Atomic uint32_t inner_failed;
};

static void inner_job(void *ctx, uint32_t job, unsigned worker)
{
    (void)job;
    (void)worker;
    atomic_fetch_add(&((struct nested_ctx *)ctx)->inner_total, 1);
}

static void outer_job(void *vctx, uint32_t job, unsigned worker)
{
    (void)worker;
    struct nested_ctx *c = vctx;
    atomic_fetch_add(&c->outer_hits[job], 1);
    if (!parallel_run(2, 50, inner_job, c, NULL, NULL, NULL)) atomic_fetch_add(&c->inner_failed, 1);
}

static void test_nested_call_does_not_deadlock(void)
{
    struct nested_ctx c;
    for (int i = 0; i < 8; i++) atomic_init(&c.outer_hits[i], 0);
    atomic_init(&c.inner_total, 0);
    atomic_init(&c.inner_failed, 0);
    struct err err = {0};
    CHECK(parallel_run(3, 8, outer_job, &c, NULL, NULL, &err));
    for (int i = 0; i < 8; i++) CHECK(atomic_load(&c.outer_hits[i]) == 1);
    CHECK(atomic_load(&c.inner_total) == 8 * 50);
    CHECK(atomic_load(&c.inner_failed) == 0);
}

static void test_shutdown_then_run(void)
{
    parallel_shutdown();
    parallel_shutdown(); /* idempotent, also with no pool */
    run_and_verify(0, 100, false, 0, true);
    run_and_verify(4, 100, true, 0, true);
    parallel_shutdown();
    parallel_shutdown();
    run_and_verify(3, 1000, false, 100, true);
    parallel_shutdown();
    run_and_verify(3, 1000, true, 100, true);
}

static void test_shutdown_while_others_run(void)
{
    /* parallel_shutdown waits for the owner; calls during it take the fallback path. */
    struct caller_arg args[2] = {{3, false, 200, 0}, {2, true, 40, 0}};
    pthread_t tids[2];
    bool started[2];
    for (int i = 0; i < 2; i++) started[i] = pthread_create(&tids[i], NULL, caller_main, &args[i]) == 0;
    for (int i = 0; i < 50; i++) {
        parallel_shutdown();
        struct timespec ts = {0, 200 * 1000};
        nanosleep(&ts, NULL);
    }
    for (int i = 0; i < 2; i++) {
        CHECK(started[i]);
        if (started[i]) pthread_join(tids[i], NULL);
        CHECK_MSG(args[i].failures == 0, "caller %d: %d failed runs", i, args[i].failures);
    }
    parallel_shutdown();
}

static void count_job(void *ctx, uint32_t job, unsigned worker)
{
    (void)worker;
    atomic_fetch_add((_Atomic uint64_t *)ctx, job + 1u);
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

/* The baseline build of the old per-call-threads code sets this lower: it slept 20 ms per call
 * with a progress callback. */
#ifndef PROGRESS_RUNS
#define PROGRESS_RUNS 10000
#endif

static void time_small_runs(unsigned threads, uint32_t jobs, bool with_progress)
{
    const int RUNS = with_progress ? PROGRESS_RUNS : 10000;
    _Atomic uint64_t sum = 0;
    struct progress_log log = {.caller = pthread_self()};
    struct err err = {0};
    parallel_run(threads, jobs, count_job, &sum, NULL, NULL, &err); /* warm-up: creates the pool */
    atomic_store(&sum, 0);
    double t0 = now_s();
    bool all_ok = true;
    for (int i = 0; i < RUNS; i++) {
        all_ok &= parallel_run(threads, jobs, count_job, &sum, with_progress ? record_progress : NULL, &log, &err);
    }
    double dt = now_s() - t0;
    CHECK(all_ok);
    CHECK(atomic_load(&sum) == (uint64_t)RUNS * jobs * (jobs + 1) / 2);
    printf("     %d runs of %u jobs, threads %u%s: %.2f us per call (%.3f s)\n", RUNS, jobs,
           threads ? threads : parallel_default_threads(), with_progress ? ", progress" : "", dt / RUNS * 1e6, dt);
    /* Generous (sanitizer builds, loaded machines): thread creation per call would be ~10x
     * slower than the pool but still under this; the printed number is the measurement. */
    CHECK_MSG(dt < 30.0, "%.3f s for %d runs", dt, RUNS);
}

static void test_many_small_runs_are_fast(void)
{
    time_small_runs(0, 16, false);
    time_small_runs(4, 16, false);
    time_small_runs(4, 16, true);
    time_small_runs(2, 1, false);
    parallel_shutdown();
}

/* ---- parallel_cpu_ms: the CPU time of every thread a call used -------------------------------- */

#define BURN_MS 4.0

static double thread_cpu_ms(void)
{
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return (double)t.tv_sec * 1e3 + (double)t.tv_nsec * 1e-6;
}

/* Spends BURN_MS of its own thread's CPU time, whichever thread that is. */
static void burn_job(void *ctx, uint32_t job, unsigned worker)
{
    (void)ctx, (void)job, (void)worker;
    double t0 = thread_cpu_ms();
    volatile unsigned sink = 0;
    while (thread_cpu_ms() - t0 < BURN_MS) sink = sink + 1;
}

/* A job that runs 4 burning jobs of its own on 2 threads. */
static void nested_burn_job(void *ctx, uint32_t job, unsigned worker)
{
    (void)job, (void)worker;
    struct err err = {0};
    parallel_run(2, 4, burn_job, ctx, NULL, NULL, &err);
}

static void noop_progress(void *ctx, uint32_t done, uint32_t total) { (void)ctx, (void)done, (void)total; }

struct cpu_caller {
    unsigned threads;
    uint32_t jobs;
    double ms;
};

static void *cpu_caller_main(void *arg)
{
    struct cpu_caller *c = arg;
    struct err err = {0};
    double t0 = parallel_cpu_ms();
    parallel_run(c->threads, c->jobs, burn_job, NULL, NULL, NULL, &err);
    c->ms = parallel_cpu_ms() - t0;
    return NULL;
}

/* Each case's jobs burn jobs x BURN_MS of CPU time in all, on whichever threads run them; the
 * caller's reading must count all of it (the helpers' too: with a progress callback the caller
 * runs no job, so counting its own thread alone reads about 0) and not much more (waiting for the
 * helpers costs no CPU). Two callers at once: one of them runs on the threads created for it
 * (the pool is busy), and each counts its own jobs only. */
static void test_cpu_time_counts_every_thread(void)
{
    struct err err = {0};
    struct { unsigned threads; uint32_t jobs; parallel_progress_fn *progress; parallel_job_fn *fn; double burnt; } cases[] = {
        {1, 8, NULL, burn_job, 8 * BURN_MS},
        {4, 16, NULL, burn_job, 16 * BURN_MS},
        {4, 16, noop_progress, burn_job, 16 * BURN_MS},
        {2, 2, NULL, nested_burn_job, 8 * BURN_MS},
        {2, 2, noop_progress, nested_burn_job, 8 * BURN_MS},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        double t0 = parallel_cpu_ms();
        CHECK(parallel_run(cases[i].threads, cases[i].jobs, cases[i].fn, NULL, cases[i].progress, NULL, &err));
        double ms = parallel_cpu_ms() - t0;
        printf("  case %zu: %.1f CPU-ms for %.1f burnt\n", i, ms, cases[i].burnt);
        CHECK(ms >= cases[i].burnt);
        CHECK(ms < 1.5 * cases[i].burnt + 10.0);
    }
    struct cpu_caller callers[2] = {{3, 12, 0.0}, {3, 6, 0.0}};
    pthread_t tid[2];
    for (int i = 0; i < 2; i++) CHECK(pthread_create(&tid[i], NULL, cpu_caller_main, &callers[i]) == 0);
    for (int i = 0; i < 2; i++) pthread_join(tid[i], NULL);
    for (int i = 0; i < 2; i++) {
        double burnt = callers[i].jobs * BURN_MS;
        printf("  concurrent caller %d: %.1f CPU-ms for %.1f burnt\n", i, callers[i].ms, burnt);
        CHECK(callers[i].ms >= burnt);
        CHECK(callers[i].ms < 1.5 * burnt + 10.0);
    }
}

TEST_MAIN(TEST(test_every_job_runs_once), TEST(test_more_threads_than_default_and_clamp),
          TEST(test_progress_during_and_at_end), TEST(test_concurrent_callers),
          TEST(test_nested_call_does_not_deadlock), TEST(test_shutdown_then_run),
          TEST(test_shutdown_while_others_run), TEST(test_many_small_runs_are_fast),
          TEST(test_stop_from_progress), TEST(test_cpu_time_counts_every_thread))
