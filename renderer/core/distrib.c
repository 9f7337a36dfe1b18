/* distrib.c — alias tables (see distrib.h). Construction is O(n) with two work lists. */
#include "core/distrib.h"

#include <math.h>
#include <stdlib.h>

bool distrib_init(struct distrib *d, const double *weights, uint32_t count, struct err *err)
{
    d->count = 0;
    d->count_f = 0.0f;
    d->threshold = NULL;
    d->alias = NULL;
    d->pmf = NULL;
    d->total = 0.0;
    if (count == 0) return err_set(err, ERR_INVALID, NULL, "distribution with no entries");
    double total = 0.0;
    for (uint32_t i = 0; i < count; i++) {
        if (!(weights[i] >= 0.0) || !isfinite(weights[i]))
            return err_set(err, ERR_INVALID, NULL, "distribution weight %u is %g", i, weights[i]);
        total += weights[i];
    }
    if (!(total > 0.0)) return err_set(err, ERR_INVALID, NULL, "distribution weights sum to zero");

    d->threshold = malloc(count * sizeof *d->threshold);
    d->alias = malloc(count * sizeof *d->alias);
    d->pmf = malloc(count * sizeof *d->pmf);
    double *scaled = malloc(count * sizeof *scaled);
    uint32_t *small = malloc(count * sizeof *small), *large = malloc(count * sizeof *large);
    if (!d->threshold || !d->alias || !d->pmf || !scaled || !small || !large) {
        free(scaled);
        free(small);
        free(large);
        distrib_destroy(d);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for a distribution of %u entries", count);
    }
    uint32_t ns = 0, nl = 0;
    for (uint32_t i = 0; i < count; i++) {
        d->pmf[i] = (float)(weights[i] / total);
        scaled[i] = weights[i] / total * count;
        if (scaled[i] < 1.0) small[ns++] = i;
        else large[nl++] = i;
    }
    while (ns && nl) {
        uint32_t s = small[--ns], l = large[--nl];
        d->threshold[s] = (float)scaled[s];
        d->alias[s] = l;
        scaled[l] = (scaled[l] + scaled[s]) - 1.0;
        if (scaled[l] < 1.0) small[ns++] = l;
        else large[nl++] = l;
    }
    /* Leftovers are 1 up to rounding. */
    while (nl) { uint32_t l = large[--nl]; d->threshold[l] = 1.0f; d->alias[l] = l; }
    while (ns) { uint32_t s = small[--ns]; d->threshold[s] = 1.0f; d->alias[s] = s; }
    free(scaled);
    free(small);
    free(large);
    d->count = count;
    d->count_f = (float)count;
    d->total = total;
    return true;
}

void distrib_destroy(struct distrib *d)
{
    free(d->threshold);
    free(d->alias);
    free(d->pmf);
    d->threshold = NULL;
    d->alias = NULL;
    d->pmf = NULL;
    d->count = 0;
    d->count_f = 0.0f;
}

uint32_t distrib_sample(const struct distrib *d, float u, float *pmf)
{
    float x = u * d->count_f;
    uint32_t col = (uint32_t)x;
    if (col >= d->count) col = d->count - 1;
    float frac = x - (float)col;
    uint32_t i = frac < d->threshold[col] ? col : d->alias[col];
    if (pmf) *pmf = d->pmf[i];
    return i;
}
