/* jobs.h — background jobs (animations and server-rendered references) run by a fixed pool of
 * worker threads from a bounded FIFO. A full queue refuses a job at once (ERR_BUSY → 429).
 * Every frame a job renders passes the render gate like a synchronous frame, so jobs and
 * interactive requests share the cores fairly. Cancellation takes effect between frames
 * (animation) or between passes (reference). */
#ifndef RESTIRD_JOBS_H
#define RESTIRD_JOBS_H

#include <stdbool.h>

#include "gate.h"
#include "refstore.h"
#include "session.h"

struct jobs;

/* Statistics hook: called after every rendered frame with its render time. */
typedef void jobs_frame_fn(void *ctx, double render_ms);

struct jobs *jobs_new(unsigned workers, unsigned queue, struct gate *gate, struct refstore *refs,
                      jobs_frame_fn *on_frame, void *on_frame_ctx, struct err *err);
/* Queues j (QUEUED, added by session_job_add; an animation's session already claimed).
 * Retains the session until the job ends. The record stays the session's: a worker reads it
 * until it sets j->released, its last step with every job it takes, cancelled ones included,
 * and the session forgets no job before that. ERR_BUSY when the queue is full, ERR_BUSY after
 * jobs_stop began. */
bool jobs_submit(struct jobs *q, struct job *j, struct err *err);
/* Cancels queued and running jobs, waits for the workers, frees the pool. */
void jobs_stop(struct jobs *q);
/* Jobs waiting in the queue. */
unsigned jobs_queued(struct jobs *q);

/* Passes per reference render: the reference is the mean of this many equal-spp passes, so
 * that it reports progress and can be cancelled. */
#define JOBS_REFERENCE_PASSES 16

#endif
