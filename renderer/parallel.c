/* parallel.c — a fork-join worker pool over pthreads (see parallel.h). Threads are created per
 * call: a frame's jobs run for milliseconds to minutes, so creation cost is negligible. */
#include "parallel.h"

#include <pthread.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

struct parallel_state {
    parallel_job_fn *fn;
    void *ctx;
    uint32_t job_count;
    uint32_t next;   /* atomic */
    uint32_t done;   /* atomic */
};

struct parallel_worker {
    struct parallel_state *state;
    unsigned index;
};

static void *parallel_worker_main(void *arg)
{
    struct parallel_worker *w = arg;
    struct parallel_state *st = w->state;
    for (;;) {
        uint32_t job = __atomic_fetch_add(&st->next, 1, __ATOMIC_RELAXED);
        if (job >= st->job_count) break;
        st->fn(st->ctx, job, w->index);
        __atomic_fetch_add(&st->done, 1, __ATOMIC_RELEASE);
    }
    return NULL;
}

unsigned parallel_default_threads(void)
{
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (unsigned)n : 1u;
}

bool parallel_run(unsigned threads, uint32_t job_count, parallel_job_fn *fn, void *ctx,
                  parallel_progress_fn *progress, void *progress_ctx, struct err *err)
{
    if (threads == 0) threads = parallel_default_threads();
    if (threads > 1024) threads = 1024;
    struct parallel_state st = {fn, ctx, job_count, 0, 0};
    pthread_t *tids = calloc(threads, sizeof *tids);
    struct parallel_worker *workers = calloc(threads, sizeof *workers);
    if (!tids || !workers) {
        free(tids);
        free(workers);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for %u worker threads", threads);
    }
    unsigned started = 0;
    for (unsigned i = 0; i < threads; i++) {
        workers[i] = (struct parallel_worker){&st, i};
        if (pthread_create(&tids[i], NULL, parallel_worker_main, &workers[i]) != 0) break;
        started++;
    }
    if (started == 0) {
        /* No thread could be created: run everything here, still correct. */
        workers[0] = (struct parallel_worker){&st, 0};
        parallel_worker_main(&workers[0]);
    } else if (progress) {
        while (__atomic_load_n(&st.done, __ATOMIC_ACQUIRE) < job_count) {
            progress(progress_ctx, __atomic_load_n(&st.done, __ATOMIC_ACQUIRE), job_count);
            struct timespec ts = {0, 20 * 1000 * 1000};
            nanosleep(&ts, NULL);
        }
    }
    for (unsigned i = 0; i < started; i++) pthread_join(tids[i], NULL);
    if (progress) progress(progress_ctx, job_count, job_count);
    free(tids);
    free(workers);
    return true;
}
