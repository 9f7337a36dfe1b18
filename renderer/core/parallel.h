/* parallel.h — runs `job_count` independent jobs on worker threads (dynamic scheduling with
 * an atomic counter) from a persistent, process-wide pool. Results must not depend on which
 * worker runs a job: seed per job/pixel, never per worker. The caller's thread reports progress
 * while the workers run. */
#ifndef RESTIRD_PARALLEL_H
#define RESTIRD_PARALLEL_H

#include <stdint.h>
#include <time.h>

#include "core/err.h"

typedef void parallel_job_fn(void *ctx, uint32_t job, unsigned worker);
typedef void parallel_progress_fn(void *ctx, uint32_t done, uint32_t total);

/* Number of worker threads to use by default: the online CPU count. */
unsigned parallel_default_threads(void);
/* `requested` threads (0 = parallel_default_threads()), at most `cap`. */
unsigned parallel_threads(unsigned requested, unsigned cap);

/* Milliseconds on CLOCK_MONOTONIC since *t0, and *t0 moved to now: one clock times consecutive
 * passes of a frame. */
double parallel_lap_ms(struct timespec *t0);
/* CPU time in milliseconds, a counter that only grows, for the calling thread: its own CPU time
 * plus what the threads of its finished parallel_runs spent on them (and on the parallel_runs
 * their jobs made in turn). The difference of two readings around a piece of work is that work's
 * CPU time on every thread it used, free of the time other processes took from the machine,
 * which a shared machine's wall clock is not. */
double parallel_cpu_ms(void);
/* Runs all jobs with `threads` workers (0 = default, at most 1024) and returns when every job
 * has run exactly once. `worker` is < threads and unique among the threads running jobs of this
 * call at the same moment (per-worker scratch indexed by it needs no locking). `progress` (may
 * be NULL) is called from the calling thread about every 20 ms with a non-decreasing `done`, and
 * once at the end with (job_count, job_count); without it the calling thread runs jobs itself
 * as worker 0. Safe to call from several threads at once, and from inside a job. After the pool
 * exists, a call allocates nothing (unless another call is using the pool at the same moment).
 * Returns false only when a fallback path runs out of memory. */
bool parallel_run(unsigned threads, uint32_t job_count, parallel_job_fn *fn, void *ctx,
                  parallel_progress_fn *progress, void *progress_ctx, struct err *err);
/* Called from a progress callback: the jobs of that parallel_run that have not started are
 * skipped (those running finish), and parallel_run returns true as usual, with the work
 * incomplete: the caller that asked knows its output is not to be used. Later calls of the
 * callback in the same run do nothing more; the next parallel_run starts afresh. */
void parallel_stop(void);
/* Inside a job: true once parallel_stop was called for its parallel_run, so a long job can
 * return early (its output is discarded). Cheap enough to call once per pixel. */
bool parallel_stopped(void);
/* Joins the pool's threads and frees it, so a program can exit with nothing allocated.
 * Idempotent; a later parallel_run creates the pool again. Waits for a parallel_run in progress
 * on the pool; must not be called from inside a job or a progress callback. */
void parallel_shutdown(void);

#endif
