/* gate.h — the render gate: at most `slots` renders run at once (each render already uses
 * every core, so more would only oversubscribe them), and at most `queue` synchronous requests
 * wait for a slot; beyond that a request is refused at once (ERR_BUSY → 503 + Retry-After)
 * rather than piling up threads. Background jobs wait without the queue bound: the job queue
 * bounds them. Thread-safe. */
#ifndef RESTIRD_GATE_H
#define RESTIRD_GATE_H

#include <pthread.h>
#include <stdbool.h>

#include "core/err.h"

struct gate {
    pthread_mutex_t lock;
    pthread_cond_t cond;
    unsigned slots, running, waiting, queue;
    bool closed;
};

void gate_init(struct gate *g, unsigned slots, unsigned queue);
void gate_destroy(struct gate *g);
/* Waits for a slot. bounded: refuse (ERR_BUSY) when `queue` requests already wait. Fails with
 * ERR_BUSY after gate_close. */
bool gate_enter(struct gate *g, bool bounded, struct err *err);
void gate_leave(struct gate *g);
/* Wakes every waiter with ERR_BUSY and refuses new entries (shutdown). */
void gate_close(struct gate *g);
/* Renders waiting for a slot (the queue depth metric). */
unsigned gate_waiting(struct gate *g);

#endif
