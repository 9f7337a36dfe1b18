/* distrib.h — discrete distributions sampled in O(1) with Walker's alias method
 * (Vose 1991 construction). Used to pick emitters proportionally to power. */
#ifndef RESTIRD_DISTRIB_H
#define RESTIRD_DISTRIB_H

#include <stdint.h>

#include "core/err.h"

struct distrib {
    uint32_t count;
    float count_f;      /* (float)count, which distrib_sample scales u by: converted once */
    float *threshold;   /* per column: keep the column when the fraction < threshold */
    uint32_t *alias;    /* per column: the other entry */
    float *pmf;         /* probability of each entry */
    double total;       /* sum of the weights given to distrib_init */
};

/* Builds from `count` non-negative finite weights with a positive sum. */
bool distrib_init(struct distrib *d, const double *weights, uint32_t count, struct err *err);
void distrib_destroy(struct distrib *d);
/* Index for u in [0,1); *pmf receives its probability. */
uint32_t distrib_sample(const struct distrib *d, float u, float *pmf);

#endif
