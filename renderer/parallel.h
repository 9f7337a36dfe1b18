/* parallel.h — runs `job_count` independent jobs on worker threads (dynamic scheduling with
 * an atomic counter). Results must not depend on which worker runs a job: seed per job/pixel,
 * never per worker. The caller's thread reports progress while the workers run. */
#ifndef RESTIRD_PARALLEL_H
#define RESTIRD_PARALLEL_H

#include <stdint.h>

#include "err.h"

typedef void parallel_job_fn(void *ctx, uint32_t job, unsigned worker);
typedef void parallel_progress_fn(void *ctx, uint32_t done, uint32_t total);

/* Number of worker threads to use by default: the online CPU count. */
unsigned parallel_default_threads(void);
/* Runs all jobs with `threads` workers (0 = default); `progress` (may be NULL) is called from
 * the calling thread about every 20 ms and once at the end. */
bool parallel_run(unsigned threads, uint32_t job_count, parallel_job_fn *fn, void *ctx,
                  parallel_progress_fn *progress, void *progress_ctx, struct err *err);

#endif
