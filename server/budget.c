/* budget.c — the shared memory budget (see budget.h). A mutex over four counters: admissions
 * are rare next to renders, so contention does not matter. */
#include "budget.h"

static const char *const budget_names[BUDGET_KINDS] = {"sessions", "scenes", "references", "uploads"};

void budget_init(struct budget *b, uint64_t limit)
{
    pthread_mutex_init(&b->lock, NULL);
    b->limit = limit;
    for (int k = 0; k < BUDGET_KINDS; k++) b->used[k] = 0;
}

void budget_destroy(struct budget *b)
{
    pthread_mutex_destroy(&b->lock);
}

static uint64_t budget_total_locked(const struct budget *b)
{
    uint64_t t = 0;
    for (int k = 0; k < BUDGET_KINDS; k++) t += b->used[k];
    return t;
}

bool budget_reserve(struct budget *b, enum budget_kind kind, uint64_t bytes, struct err *err)
{
    pthread_mutex_lock(&b->lock);
    uint64_t total = budget_total_locked(b);
    bool ok = b->limit == 0 || (bytes <= b->limit && total <= b->limit - bytes);
    if (ok) b->used[kind] += bytes;
    pthread_mutex_unlock(&b->lock);
    if (!ok)
        return err_set(err, ERR_BUSY, NULL,
                       "the memory budget is full: %llu of %llu bytes in use, %s need %llu more",
                       (unsigned long long)total, (unsigned long long)b->limit, budget_names[kind],
                       (unsigned long long)bytes);
    return true;
}

void budget_charge(struct budget *b, enum budget_kind kind, uint64_t bytes)
{
    pthread_mutex_lock(&b->lock);
    b->used[kind] += bytes;
    pthread_mutex_unlock(&b->lock);
}

void budget_release(struct budget *b, enum budget_kind kind, uint64_t bytes)
{
    pthread_mutex_lock(&b->lock);
    b->used[kind] -= bytes <= b->used[kind] ? bytes : b->used[kind];
    pthread_mutex_unlock(&b->lock);
}

uint64_t budget_used(struct budget *b, enum budget_kind kind)
{
    pthread_mutex_lock(&b->lock);
    uint64_t u = b->used[kind];
    pthread_mutex_unlock(&b->lock);
    return u;
}

uint64_t budget_total(struct budget *b)
{
    pthread_mutex_lock(&b->lock);
    uint64_t t = budget_total_locked(b);
    pthread_mutex_unlock(&b->lock);
    return t;
}
