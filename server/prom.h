/* prom.h — the daemon's counters and the Prometheus text exposition (format 0.0.4) of
 * GET /metrics. Counters are updated from connection and job threads. Thread-safe. */
#ifndef RESTIRD_PROM_H
#define RESTIRD_PROM_H

#include <pthread.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define PROM_MAX_SERIES 256
#define PROM_BUCKETS 12

struct prom {
    pthread_mutex_t lock;
    struct { const char *route; int code; uint64_t count; } requests[PROM_MAX_SERIES];
    unsigned request_series;
    uint64_t frame_buckets[PROM_BUCKETS];   /* cumulative at exposition, counts per bucket here */
    uint64_t frame_count;
    double frame_sum_s;
    uint64_t cut_head, cut_body;            /* connections closed for a slow head or body */
};

/* Gauges read at scrape time. */
struct prom_gauges {
    uint32_t sessions, scenes;
    uint64_t session_bytes, reservoir_bytes, reference_bytes;
    unsigned render_queue, job_queue;
};

void prom_init(struct prom *p);
void prom_destroy(struct prom *p);
/* `route` must be a string with static storage (a route template). */
void prom_count_request(struct prom *p, const char *route, int code);
void prom_observe_frame(struct prom *p, double seconds);
/* A connection closed for a slow request head (head) or a slow body (!head). */
void prom_count_cut(struct prom *p, bool head);
/* A text buffer that grows as it is written: `s` starts malloc'd with `cap` bytes. prom_printf
 * appends; after a failed allocation it appends nothing more and sets `failed` (`s` is still
 * the caller's to free). Also for other text answers (a job's metrics as CSV). */
struct prom_buf { char *s; size_t len, cap; bool failed; };
void prom_printf(struct prom_buf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* The exposition text, malloc'd (caller frees); NULL on allocation failure. */
char *prom_format(struct prom *p, const struct prom_gauges *g, size_t *len);

#endif
