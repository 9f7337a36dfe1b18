/* parallel.c — a fork-join worker pool over pthreads (see parallel.h).
 *
 * A ReSTIR frame runs several short passes (G-buffer, initial, temporal, spatial, shade) on
 * small images at interactive rates, so creating and joining threads per pass would dominate.
 * The pool is process-wide and persistent:
 *
 * - Created on the first parallel_run that needs helper threads, with the default thread count
 *   (or more if that caller asks for more); grown when a later caller asks for more threads, up
 *   to PARALLEL_MAX_THREADS. parallel_shutdown joins and frees it; the next call recreates it.
 * - Each pool thread sleeps on its own condition variable between calls, so a call wakes only
 *   the threads it uses and an idle pool costs no CPU. Jobs are handed out by an atomic counter
 *   (dynamic scheduling). Pool threads are created with every signal blocked, so they never take
 *   a process-directed signal meant for the daemon's sigwait.
 * - Without a progress callback the calling thread runs jobs too, as worker 0, and the pool
 *   threads it wakes are workers 1..threads-1; with one, the caller only reports progress and
 *   the pool threads are workers 0..threads-1. A call never wakes more threads than it has jobs,
 *   and one that needs no helper (threads == 1, or one job) runs inline without the pool.
 * - Concurrency: one call owns the pool at a time. A call that finds the pool owned (another
 *   thread renders at the same time, or a job itself calls parallel_run) does not wait: it falls
 *   back to the original create-threads-per-call path, which is always correct and keeps
 *   concurrent renders from queueing behind each other (a minutes-long reference render would
 *   otherwise stall an interactive frame) and nested calls from deadlocking. Only that rare
 *   path allocates.
 * - Steady state (the pool exists and is free): two mutex round trips, one condvar signal per
 *   helper and a wait for the helpers that started on the batch (one that had not woken by the
 *   time every job was claimed is not waited for); no allocation. Each helper reads its thread's
 *   CPU clock twice, for parallel_cpu_ms.
 * - If threads cannot be created (or memory for them is short), the jobs run on the threads
 *   that exist, at worst on the calling thread alone: slower but still correct. */
#include "core/parallel.h"

#include <errno.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

#define PARALLEL_MAX_THREADS 1024u
#define PARALLEL_PROGRESS_NS (20 * 1000 * 1000)

/* One parallel_run's jobs, on the caller's stack. `next` is 64-bit so that every executor's
 * final, failing increment cannot wrap it even when job_count is close to UINT32_MAX. */
struct parallel_batch {
    parallel_job_fn *fn;
    void *ctx;
    uint32_t job_count;
    _Atomic uint64_t next;
    _Atomic uint32_t done; /* jobs finished, for progress only */
    _Atomic bool stop;     /* parallel_stop was called: running jobs may end early */
    _Atomic uint64_t helper_cpu_ns; /* CPU time the threads other than the caller spent on it */
};

/* The batch whose job this thread is running (NULL outside a job), for parallel_stopped. */
static _Thread_local struct parallel_batch *parallel_current;

/* Set by parallel_stop from a progress callback; read by the parallel_run on the same thread. */
static _Thread_local bool parallel_stopping;

void parallel_stop(void)
{
    parallel_stopping = true;
}

/* After a progress call: when it asked to stop, no job not yet claimed will start (storing
 * job_count makes every later claim fail; a claim already made runs to its end). */
static void parallel_check_stop(struct parallel_batch *b)
{
    if (!parallel_stopping) return;
    atomic_store_explicit(&b->stop, true, memory_order_relaxed);
    atomic_store_explicit(&b->next, (uint64_t)b->job_count, memory_order_relaxed);
}

bool parallel_stopped(void)
{
    return parallel_current && atomic_load_explicit(&parallel_current->stop, memory_order_relaxed);
}

/* CPU time the calling thread's parallel_runs had other threads spend (parallel_cpu_ms). */
static _Thread_local uint64_t parallel_helpers_ns;

static uint64_t parallel_thread_cpu_ns(void)
{
    struct timespec t;
    if (clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t) != 0) return 0;
    return (uint64_t)t.tv_sec * 1000000000u + (uint64_t)t.tv_nsec;
}

double parallel_cpu_ms(void)
{
    return (double)(parallel_thread_cpu_ns() + parallel_helpers_ns) * 1e-6;
}

/* `helper`: this thread is not the batch's caller, so its CPU time (with that of the helpers of
 * any parallel_run its jobs made) is added to the batch's, which the caller takes over when the
 * batch ends; the caller's own is in its thread clock already. */
static void parallel_batch_work(struct parallel_batch *b, unsigned worker, bool helper)
{
    struct parallel_batch *outer = parallel_current;  /* a job may run a parallel_run of its own */
    const uint64_t cpu0 = helper ? parallel_thread_cpu_ns() : 0, nested0 = parallel_helpers_ns;
    parallel_current = b;
    for (;;) {
        uint64_t job = atomic_fetch_add_explicit(&b->next, 1, memory_order_relaxed);
        if (job >= b->job_count) break;
        b->fn(b->ctx, (uint32_t)job, worker);
        atomic_fetch_add_explicit(&b->done, 1, memory_order_release);
    }
    parallel_current = outer;
    if (helper) {
        uint64_t spent = parallel_thread_cpu_ns() - cpu0 + (parallel_helpers_ns - nested0);
        parallel_helpers_ns = nested0;
        atomic_fetch_add_explicit(&b->helper_cpu_ns, spent, memory_order_relaxed);
    }
}

/* The caller of a finished batch takes over its helpers' CPU time. */
static void parallel_take_helpers(struct parallel_batch *b)
{
    parallel_helpers_ns += atomic_load_explicit(&b->helper_cpu_ns, memory_order_relaxed);
}

static void parallel_sleep_tick(void)
{
    struct timespec ts = {0, PARALLEL_PROGRESS_NS};
    nanosleep(&ts, NULL);
}

unsigned parallel_default_threads(void)
{
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    if (n < 1) return 1u;
    return n > (long)PARALLEL_MAX_THREADS ? PARALLEL_MAX_THREADS : (unsigned)n;
}

unsigned parallel_threads(unsigned requested, unsigned cap)
{
    unsigned n = requested ? requested : parallel_default_threads();
    return n > cap ? cap : n;
}

double parallel_lap_ms(struct timespec *t0)
{
    struct timespec t1;
    clock_gettime(CLOCK_MONOTONIC, &t1);
    double ms = (double)(t1.tv_sec - t0->tv_sec) * 1e3 + (double)(t1.tv_nsec - t0->tv_nsec) * 1e-6;
    *t0 = t1;
    return ms;
}

/* ---- the fallback: threads created and joined per call ------------------------------------ */

struct spawned_worker {
    pthread_t tid;
    struct parallel_batch *batch;
    unsigned index;
};

static void *spawned_worker_main(void *arg)
{
    struct spawned_worker *w = arg;
    parallel_batch_work(w->batch, w->index, true);
    return NULL;
}

/* `helpers` new threads run as workers base..base+helpers-1; the caller is worker 0 when base
 * is 1 (or when no thread could be created). */
static bool parallel_run_spawned(struct parallel_batch *b, unsigned helpers, unsigned base,
                                 parallel_progress_fn *progress, void *progress_ctx, struct err *err)
{
    struct spawned_worker *w = calloc(helpers, sizeof *w);
    if (!w) return err_set(err, ERR_NOMEM, NULL, "out of memory for %u worker threads", helpers);
    unsigned started = 0;
    for (; started < helpers; started++) {
        w[started] = (struct spawned_worker){.batch = b, .index = started + base};
        if (pthread_create(&w[started].tid, NULL, spawned_worker_main, &w[started]) != 0) break;
    }
    if (base == 1 || started == 0) {
        parallel_batch_work(b, 0, false);
    } else if (progress) {
        uint32_t done;
        while (!parallel_stopping && (done = atomic_load_explicit(&b->done, memory_order_acquire)) < b->job_count) {
            progress(progress_ctx, done, b->job_count);
            parallel_check_stop(b);
            if (!parallel_stopping) parallel_sleep_tick();
        }
    }
    for (unsigned i = 0; i < started; i++) pthread_join(w[i].tid, NULL);
    free(w);
    parallel_take_helpers(b);
    if (progress) progress(progress_ctx, b->job_count, b->job_count);
    return true;
}

/* ---- the persistent pool ------------------------------------------------------------------ */

struct pool_worker {
    pthread_t tid;
    pthread_cond_t wake;
    bool pending; /* a batch is waiting for this thread; guarded by pool.mu */
    unsigned slot;
};

/* Everything below is guarded by pool.mu. `busy` marks the pool owned by one parallel_run (or
 * by parallel_shutdown); only the owner changes `count`, `workers`, `batch`, `base`. */
static struct {
    pthread_mutex_t mu;
    pthread_cond_t finished; /* `running` reached 0 (CLOCK_MONOTONIC for timed waits) */
    pthread_cond_t released; /* `busy` went false (parallel_shutdown waits on it) */
    bool busy, stop;
    unsigned count;          /* pool threads alive: workers[0..count-1] */
    unsigned running;        /* pool threads still working on the current batch */
    struct parallel_batch *batch;
    unsigned base;           /* worker index of slot 0 in the current batch */
    struct pool_worker *workers[PARALLEL_MAX_THREADS];
} pool = {.mu = PTHREAD_MUTEX_INITIALIZER, .released = PTHREAD_COND_INITIALIZER};

static pthread_once_t pool_once = PTHREAD_ONCE_INIT;

static void pool_init_once(void)
{
    pthread_condattr_t attr;
    pthread_condattr_init(&attr);
    pthread_condattr_setclock(&attr, CLOCK_MONOTONIC);
    pthread_cond_init(&pool.finished, &attr);
    pthread_condattr_destroy(&attr);
}

static void *pool_worker_main(void *arg)
{
    struct pool_worker *w = arg;
    pthread_mutex_lock(&pool.mu);
    for (;;) {
        while (!w->pending && !pool.stop) pthread_cond_wait(&w->wake, &pool.mu);
        if (!w->pending) break; /* stop, and nothing left for this thread */
        w->pending = false;
        struct parallel_batch *b = pool.batch;
        unsigned index = pool.base + w->slot;
        pthread_mutex_unlock(&pool.mu);
        parallel_batch_work(b, index, true);
        pthread_mutex_lock(&pool.mu);
        if (--pool.running == 0) pthread_cond_signal(&pool.finished);
    }
    pthread_mutex_unlock(&pool.mu);
    return NULL;
}

/* Adds pool threads up to `target`; called by the owner with pool.mu held. Stops at the first
 * failure: the caller then uses the threads that exist. */
static void pool_grow(unsigned target)
{
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old); /* new threads inherit "everything blocked" */
    while (pool.count < target) {
        struct pool_worker *w = calloc(1, sizeof *w);
        if (!w) break;
        w->slot = pool.count;
        if (pthread_cond_init(&w->wake, NULL) != 0) {
            free(w);
            break;
        }
        if (pthread_create(&w->tid, NULL, pool_worker_main, w) != 0) {
            pthread_cond_destroy(&w->wake);
            free(w);
            break;
        }
        pool.workers[pool.count++] = w;
    }
    pthread_sigmask(SIG_SETMASK, &old, NULL);
}

bool parallel_run(unsigned threads, uint32_t job_count, parallel_job_fn *fn, void *ctx,
                  parallel_progress_fn *progress, void *progress_ctx, struct err *err)
{
    if (threads == 0) threads = parallel_default_threads();
    if (threads > PARALLEL_MAX_THREADS) threads = PARALLEL_MAX_THREADS;
    struct parallel_batch b = {.fn = fn, .ctx = ctx, .job_count = job_count};
    atomic_init(&b.next, 0);
    atomic_init(&b.done, 0);
    atomic_init(&b.stop, false);
    atomic_init(&b.helper_cpu_ns, 0);
    parallel_stopping = false;

    /* Without a progress callback the caller is worker 0 and takes jobs as well. */
    unsigned base = progress ? 0u : 1u;
    unsigned helpers = threads - base;
    uint32_t helper_jobs = job_count > base ? job_count - base : 0;
    if (helpers > helper_jobs) helpers = helper_jobs;
    if (helpers == 0) {
        parallel_batch_work(&b, 0, false);
        if (progress) progress(progress_ctx, job_count, job_count);
        return true;
    }

    pthread_once(&pool_once, pool_init_once);
    pthread_mutex_lock(&pool.mu);
    if (pool.busy) {
        pthread_mutex_unlock(&pool.mu);
        return parallel_run_spawned(&b, helpers, base, progress, progress_ctx, err);
    }
    pool.busy = true;
    if (pool.count < helpers) {
        unsigned target = helpers;
        if (pool.count == 0 && target < parallel_default_threads()) target = parallel_default_threads();
        pool_grow(target);
        if (helpers > pool.count) helpers = pool.count;
    }
    pool.batch = &b;
    pool.base = base;
    pool.running = helpers;
    for (unsigned i = 0; i < helpers; i++) pool.workers[i]->pending = true;
    pthread_mutex_unlock(&pool.mu);
    /* Safe without the lock: only the owner (us) or parallel_shutdown, which waits for us,
     * changes `workers`. */
    for (unsigned i = 0; i < helpers; i++) pthread_cond_signal(&pool.workers[i]->wake);

    if (base == 1 || helpers == 0) parallel_batch_work(&b, 0, false);

    pthread_mutex_lock(&pool.mu);
    if (base == 1) {
        /* Every job has been claimed: a helper that has not woken up yet would find nothing,
         * so take its ticket back rather than wait for it to wake (on small runs the caller
         * often does all the work while the helpers are still being scheduled). */
        for (unsigned i = 0; i < helpers; i++) {
            if (pool.workers[i]->pending) {
                pool.workers[i]->pending = false;
                pool.running--;
            }
        }
    }
    if (progress) {
        while (pool.running > 0) {
            pthread_mutex_unlock(&pool.mu);
            progress(progress_ctx, atomic_load_explicit(&b.done, memory_order_acquire), job_count);
            parallel_check_stop(&b);
            struct timespec deadline;
            clock_gettime(CLOCK_MONOTONIC, &deadline);
            deadline.tv_nsec += PARALLEL_PROGRESS_NS;
            if (deadline.tv_nsec >= 1000000000L) {
                deadline.tv_sec++;
                deadline.tv_nsec -= 1000000000L;
            }
            pthread_mutex_lock(&pool.mu);
            while (pool.running > 0 && pthread_cond_timedwait(&pool.finished, &pool.mu, &deadline) != ETIMEDOUT) {
            }
        }
    } else {
        while (pool.running > 0) pthread_cond_wait(&pool.finished, &pool.mu);
    }
    pool.batch = NULL;
    pool.busy = false;
    pthread_cond_broadcast(&pool.released);
    pthread_mutex_unlock(&pool.mu);
    parallel_take_helpers(&b);
    if (progress) progress(progress_ctx, job_count, job_count);
    return true;
}

void parallel_shutdown(void)
{
    pthread_once(&pool_once, pool_init_once);
    pthread_mutex_lock(&pool.mu);
    while (pool.busy) pthread_cond_wait(&pool.released, &pool.mu);
    unsigned n = pool.count;
    if (n == 0) {
        pthread_mutex_unlock(&pool.mu);
        return;
    }
    /* Own the pool while joining: concurrent parallel_run calls take the fallback path. */
    pool.busy = true;
    pool.stop = true;
    pthread_mutex_unlock(&pool.mu);
    for (unsigned i = 0; i < n; i++) pthread_cond_signal(&pool.workers[i]->wake);
    for (unsigned i = 0; i < n; i++) {
        pthread_join(pool.workers[i]->tid, NULL);
        pthread_cond_destroy(&pool.workers[i]->wake);
        free(pool.workers[i]);
        pool.workers[i] = NULL;
    }
    pthread_mutex_lock(&pool.mu);
    pool.count = 0;
    pool.stop = false;
    pool.busy = false;
    pthread_cond_broadcast(&pool.released);
    pthread_mutex_unlock(&pool.mu);
}
