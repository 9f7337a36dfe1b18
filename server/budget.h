/* budget.h — the daemon's memory budget: one byte count shared by sessions (their buffers and
 * kept frames, as planned at creation), uploaded scenes (registry scene_bytes), references
 * (their pixels) and request bodies being received. Admission reserves before the memory stays
 * in use, so a full budget refuses the request (ERR_BUSY → 503 + Retry-After) instead of
 * growing without bound; what is already
 * held is charged without refusal (uploads reloaded at start). Figures are planning estimates,
 * not an allocator account. Thread-safe. */
#ifndef RESTIRD_BUDGET_H
#define RESTIRD_BUDGET_H

#include <pthread.h>
#include <stdbool.h>
#include <stdint.h>

#include "core/err.h"

/* BUDGET_UPLOADS: request bodies as they arrive, and reference images while they decode. */
enum budget_kind { BUDGET_SESSIONS, BUDGET_SCENES, BUDGET_REFERENCES, BUDGET_UPLOADS, BUDGET_KINDS };

struct budget {
    pthread_mutex_t lock;
    uint64_t limit;                  /* bytes; 0 = no limit */
    uint64_t used[BUDGET_KINDS];
};

void budget_init(struct budget *b, uint64_t limit);
void budget_destroy(struct budget *b);
/* Adds `bytes` to `kind` when the total stays within the limit; else ERR_BUSY naming the use. */
bool budget_reserve(struct budget *b, enum budget_kind kind, uint64_t bytes, struct err *err);
/* Adds without a check (memory already held). */
void budget_charge(struct budget *b, enum budget_kind kind, uint64_t bytes);
void budget_release(struct budget *b, enum budget_kind kind, uint64_t bytes);
uint64_t budget_used(struct budget *b, enum budget_kind kind);
uint64_t budget_total(struct budget *b);

#endif
