/* prior_stats.h — the statistics lines of a per-frame manifold sampling prior ([SMS-SSP Table 1],
 * prior construction), shared by sms_ssp and restir_sms. MEMBER: the path of the prior's
 * counters in the method's counters struct, with a trailing '.', or empty. */
#ifndef RESTIRD_PRIOR_STATS_H
#define RESTIRD_PRIOR_STATS_H

#include <stddef.h>

#include "methods/method.h"

#define METHOD_PRIOR_STATS(type, MEMBER)                                                                               \
    {"prior", NULL, METHOD_STAT_BEGIN, 0, 0},                                                                          \
        {"samples", NULL, METHOD_STAT_U64, offsetof(type, MEMBER samples), 0},                                        \
        {"solutions", NULL, METHOD_STAT_U64, offsetof(type, MEMBER solutions), 0},                                    \
        {"newton", NULL, METHOD_STAT_U64, offsetof(type, MEMBER newton), 0},                                          \
        {"dropped_pairs", NULL, METHOD_STAT_U64, offsetof(type, MEMBER dropped_pairs), 0},                            \
        {"ms", NULL, METHOD_STAT_MS, offsetof(type, MEMBER ms), 0}, {"prior", NULL, METHOD_STAT_END, 0, 0}

#endif
