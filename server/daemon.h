/* daemon.h — the daemon's configuration and the state every request handler shares. Built
 * and torn down by main.c; the handlers in api*.c read it. */
#ifndef RESTIRD_DAEMON_H
#define RESTIRD_DAEMON_H

#include <limits.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "budget.h"
#include "gate.h"
#include "jobs.h"
#include "prom.h"
#include "protocol.h"
#include "refstore.h"
#include "registry.h"
#include "session.h"

struct daemon_config {
    char host[64];
    uint16_t port;
    char data_dir[PATH_MAX];
    char library_dir[PATH_MAX];
    char id[128];                       /* X-Served-By; default host:port */
    struct protocol_limits limits;
    uint32_t max_sessions, frames_kept;
    uint64_t memory_budget;             /* sessions + uploaded scenes + references, bytes */
    uint64_t max_session_bytes;         /* one session's buffers and kept frames, bytes */
    size_t max_json_body, max_asset_body, max_reference_body;
    unsigned render_slots, render_queue, job_queue, job_workers;
    unsigned connection_limit, per_ip_limit, timeout_s;
    unsigned head_timeout_s, min_body_rate;  /* slow clients (http.h, struct http_options) */
    char health_host[64];                    /* --health-listen: a listener for the health checks */
    uint16_t health_port;                    /* only; "" = none */
    unsigned threads;                   /* render threads, 0 = all cores */
    uint64_t max_work;                  /* samples (pixels x spp) one frame or reference may take */
    char default_scene[65];             /* "" = no default session */
    /* Who may ask: Host names accepted besides the loopback names and the listen address
     * (--allow-host; "*" = any), the bearer token ("" = none) and whether /metrics is open
     * without it. */
#define DAEMON_MAX_ALLOW_HOSTS 16
    char allow_hosts[DAEMON_MAX_ALLOW_HOSTS][256];
    unsigned allow_host_count;
    char auth_token[256];
    bool metrics_open;
};

/* The request limits a daemon starts with (main.c; the options --max-side etc. change them), one
 * definition for the daemon and the tests that build its state. */
static inline struct protocol_limits daemon_default_limits(void)
{
    return (struct protocol_limits){.max_side = 4096, .max_pixels = 16u << 20, .max_spp = 65536, .max_frames = 10000,
                                    .max_keys = 4096};
}

struct daemon {
    struct daemon_config cfg;
    struct registry *registry;
    struct sessions *sessions;
    struct gate gate;
    struct jobs *jobs;
    struct refstore *refs;
    struct budget budget;
    struct prom prom;
    atomic_bool draining;
    atomic_bool loaded;                 /* the stored scenes are loaded (/readyz) */
    atomic_bool stop_loading;
};

#endif
