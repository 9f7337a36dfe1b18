/* prom.c — counters and the Prometheus text format (see prom.h). */
#include "prom.h"

#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <dirent.h>
#include <unistd.h>

#include "version.h"

/* Frame render time buckets in seconds: from a 16x16 preview to a large reference pass. */
static const double prom_bounds[PROM_BUCKETS] = {0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 10};

void prom_init(struct prom *p)
{
    memset(p, 0, sizeof *p);
    pthread_mutex_init(&p->lock, NULL);
}

void prom_destroy(struct prom *p)
{
    pthread_mutex_destroy(&p->lock);
}

void prom_count_request(struct prom *p, const char *route, int code)
{
    if (!route) route = "unmatched";
    pthread_mutex_lock(&p->lock);
    unsigned i = 0;
    for (; i < p->request_series; i++)
        if (p->requests[i].code == code && strcmp(p->requests[i].route, route) == 0) break;
    if (i == p->request_series && i < PROM_MAX_SERIES) {
        p->requests[i].route = route;
        p->requests[i].code = code;
        p->request_series++;
    }
    if (i < PROM_MAX_SERIES) p->requests[i].count++;
    pthread_mutex_unlock(&p->lock);
}

void prom_observe_frame(struct prom *p, double seconds)
{
    pthread_mutex_lock(&p->lock);
    int b = 0;
    while (b < PROM_BUCKETS && seconds > prom_bounds[b]) b++;
    if (b < PROM_BUCKETS) p->frame_buckets[b]++;
    p->frame_count++;
    p->frame_sum_s += seconds;
    pthread_mutex_unlock(&p->lock);
}

void prom_count_cut(struct prom *p, bool head)
{
    pthread_mutex_lock(&p->lock);
    if (head) p->cut_head++;
    else p->cut_body++;
    pthread_mutex_unlock(&p->lock);
}

void prom_printf(struct prom_buf *b, const char *fmt, ...)
{
    if (b->failed) return;
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        int n = vsnprintf(b->s + b->len, b->cap - b->len, fmt, ap);
        va_end(ap);
        if (n < 0) { b->failed = true; return; }
        if ((size_t)n < b->cap - b->len) { b->len += (size_t)n; return; }
        size_t cap = 2 * b->cap + (size_t)n;
        char *s = realloc(b->s, cap);
        if (!s) { b->failed = true; return; }
        b->s = s;
        b->cap = cap;
    }
}

/* The process_* metrics every Prometheus client library exports, read from /proc/self as they
 * do, so dashboards made for other services work unchanged. A figure that cannot be read is
 * left out rather than reported as 0. */
static void prom_process(struct prom_buf *b)
{
    long ticks = sysconf(_SC_CLK_TCK), page = sysconf(_SC_PAGESIZE);
    char stat[1024];
    FILE *f = fopen("/proc/self/stat", "r");
    size_t n = f ? fread(stat, 1, sizeof stat - 1, f) : 0;
    if (f) fclose(f);
    stat[n] = '\0';
    /* The command name (field 2) may hold spaces and parentheses: fields are counted from the
     * last ')'. After it: state (3) ... utime (14), stime (15) ... starttime (22), vsize (23),
     * rss (24). */
    const char *p = strrchr(stat, ')');
    unsigned long long v[25] = {0};
    int got = 0;
    if (p && ticks > 0) {
        p += 2;
        for (int field = 3; field <= 24 && *p; field++) {
            if (field != 3) v[field] = strtoull(p, NULL, 10);
            got = field;
            p = strchr(p, ' ');
            if (!p) break;
            p++;
        }
    }
    if (got >= 24) {
        prom_printf(b, "# HELP process_cpu_seconds_total Total user and system CPU time spent in seconds.\n"
                       "# TYPE process_cpu_seconds_total counter\nprocess_cpu_seconds_total %.2f\n",
                    (double)(v[14] + v[15]) / (double)ticks);
        prom_printf(b, "# HELP process_virtual_memory_bytes Virtual memory size in bytes.\n"
                       "# TYPE process_virtual_memory_bytes gauge\nprocess_virtual_memory_bytes %llu\n", v[23]);
        prom_printf(b, "# HELP process_resident_memory_bytes Resident memory size in bytes.\n"
                       "# TYPE process_resident_memory_bytes gauge\nprocess_resident_memory_bytes %llu\n",
                    v[24] * (unsigned long long)(page > 0 ? page : 4096));
        /* starttime counts ticks since boot; the boot time (btime) is in /proc/stat. */
        unsigned long long btime = 0;
        char line[256];
        FILE *sf = fopen("/proc/stat", "r");
        while (sf && fgets(line, sizeof line, sf))
            if (strncmp(line, "btime ", 6) == 0) btime = strtoull(line + 6, NULL, 10);
        if (sf) fclose(sf);
        if (btime)
            prom_printf(b, "# HELP process_start_time_seconds Start time of the process since unix epoch in seconds.\n"
                           "# TYPE process_start_time_seconds gauge\nprocess_start_time_seconds %.2f\n",
                        (double)btime + (double)v[22] / (double)ticks);
    }
    DIR *fds = opendir("/proc/self/fd");
    if (fds) {
        unsigned long open_fds = 0;
        for (struct dirent *e; (e = readdir(fds));)
            if (e->d_name[0] != '.') open_fds++;
        closedir(fds);
        if (open_fds) open_fds--;  /* the descriptor of the listing itself */
        prom_printf(b, "# HELP process_open_fds Number of open file descriptors.\n"
                       "# TYPE process_open_fds gauge\nprocess_open_fds %lu\n", open_fds);
    }
    long max_fds = sysconf(_SC_OPEN_MAX);
    if (max_fds > 0)
        prom_printf(b, "# HELP process_max_fds Maximum number of open file descriptors.\n"
                       "# TYPE process_max_fds gauge\nprocess_max_fds %ld\n", max_fds);
}

char *prom_format(struct prom *p, const struct prom_gauges *g, size_t *len)
{
    struct prom_buf b = {.cap = 4096};
    b.s = malloc(b.cap);
    if (!b.s) return NULL;
    pthread_mutex_lock(&p->lock);
    prom_printf(&b, "# HELP restird_requests_total HTTP requests answered, by route template and status.\n"
                    "# TYPE restird_requests_total counter\n");
    for (unsigned i = 0; i < p->request_series; i++)
        prom_printf(&b, "restird_requests_total{route=\"%s\",code=\"%d\"} %llu\n", p->requests[i].route,
                    p->requests[i].code, (unsigned long long)p->requests[i].count);
    prom_printf(&b, "# HELP restird_frame_render_seconds Render time of each frame (synchronous and jobs).\n"
                    "# TYPE restird_frame_render_seconds histogram\n");
    uint64_t cum = 0;
    for (int i = 0; i < PROM_BUCKETS; i++) {
        cum += p->frame_buckets[i];
        prom_printf(&b, "restird_frame_render_seconds_bucket{le=\"%g\"} %llu\n", prom_bounds[i], (unsigned long long)cum);
    }
    prom_printf(&b, "restird_frame_render_seconds_bucket{le=\"+Inf\"} %llu\n", (unsigned long long)p->frame_count);
    prom_printf(&b, "restird_frame_render_seconds_sum %.9g\n", p->frame_sum_s);
    prom_printf(&b, "restird_frame_render_seconds_count %llu\n", (unsigned long long)p->frame_count);
    prom_printf(&b, "# HELP restird_connections_cut_total Connections closed for sending a request head or body too "
                    "slowly.\n# TYPE restird_connections_cut_total counter\n"
                    "restird_connections_cut_total{phase=\"head\"} %llu\n"
                    "restird_connections_cut_total{phase=\"body\"} %llu\n",
                (unsigned long long)p->cut_head, (unsigned long long)p->cut_body);
    pthread_mutex_unlock(&p->lock);
    prom_printf(&b, "# HELP restird_sessions Live sessions.\n# TYPE restird_sessions gauge\nrestird_sessions %u\n", g->sessions);
    prom_printf(&b, "# HELP restird_scenes Scenes held.\n# TYPE restird_scenes gauge\nrestird_scenes %u\n", g->scenes);
    prom_printf(&b, "# HELP restird_session_bytes Memory of all sessions (buffers and kept frames).\n"
                    "# TYPE restird_session_bytes gauge\nrestird_session_bytes %llu\n", (unsigned long long)g->session_bytes);
    prom_printf(&b, "# HELP restird_reservoir_bytes Reservoir memory of all sessions.\n"
                    "# TYPE restird_reservoir_bytes gauge\nrestird_reservoir_bytes %llu\n", (unsigned long long)g->reservoir_bytes);
    prom_printf(&b, "# HELP restird_reference_bytes Memory of reference images.\n"
                    "# TYPE restird_reference_bytes gauge\nrestird_reference_bytes %llu\n", (unsigned long long)g->reference_bytes);
    prom_printf(&b, "# HELP restird_render_queue_depth Synchronous frames waiting for the render gate.\n"
                    "# TYPE restird_render_queue_depth gauge\nrestird_render_queue_depth %u\n", g->render_queue);
    prom_printf(&b, "# HELP restird_job_queue_depth Jobs waiting for a worker.\n"
                    "# TYPE restird_job_queue_depth gauge\nrestird_job_queue_depth %u\n", g->job_queue);
    prom_printf(&b, "# HELP restird_build_info The daemon's release and the commit it was built from.\n"
                    "# TYPE restird_build_info gauge\nrestird_build_info{version=\"%s\",commit=\"%s\"} 1\n",
                RESTIRD_VERSION, restird_commit);
    prom_process(&b);
    if (b.failed) {
        free(b.s);
        return NULL;
    }
    *len = b.len;
    return b.s;
}
