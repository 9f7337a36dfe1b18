/* main.c — `build/restird`, the render daemon: parses the command line, builds the shared state
 * (scene registry, sessions, render gate, job workers), serves HTTP until SIGTERM or SIGINT,
 * then shuts down in order: stop accepting, refuse new work, cancel jobs between frames, let
 * frames in flight finish, close connections, free everything. The only file that may exit.
 * Exit status: 0 after a clean shutdown, 1 when start-up fails, 2 for a wrong command line. */
#include <arpa/inet.h>
#include <errno.h>
#include <limits.h>
#include <netdb.h>
#include <signal.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "api.h"
#include "http.h"
#include "version.h"

#define MAIN_USAGE                                                                                  \
    "usage: restird [--listen HOST:PORT] [--data-dir DIR] [--scenes DIR] [--id NAME]\n"             \
    "               [--default-session SCENE] [--threads N] [--max-sessions N] [--frames-kept N]\n" \
    "               [--max-side N] [--max-pixels N] [--max-spp N] [--max-frames N] [--max-keys N]\n" \
    "               [--max-json-body BYTES] [--max-asset-body BYTES] [--max-reference-body BYTES]\n" \
    "               [--render-slots N] [--render-queue N] [--job-queue N] [--job-workers N]\n"    \
    "               [--connection-limit N] [--per-ip-limit N] [--timeout-s N] [--max-work SAMPLES]\n" \
    "               [--memory-budget BYTES] [--max-session-bytes BYTES]\n"                          \
    "               [--head-timeout-s N] [--min-body-rate BYTES] [--health-listen HOST:PORT]\n"  \
    "               [--allow-host NAME]... [--auth-token-file PATH] [--metrics-auth required|open]\n" \
    "defaults: --listen 127.0.0.1:8080, --data-dir $XDG_STATE_HOME/restird (~/.local/state/restird),\n" \
    "--scenes: the scenes/ folder next to the build folder; limits as GET /v1/limits lists them.\n" \
    "The bearer token is read from --auth-token-file, else from $RESTIRD_AUTH_TOKEN; it is required\n" \
    "to listen on any address but loopback.\n"                                                        \
    "HOST is a numeric address or a name (localhost); port 0 picks a free port; the first line\n"   \
    "on stdout names the address listened on.\n"                   \
    "--version prints the version and the commit it was built from.\n"

static int main_usage(const char *fmt, const char *arg)
{
    fprintf(stderr, "restird: ");
    fprintf(stderr, fmt, arg);
    fprintf(stderr, "\n%s", MAIN_USAGE);
    return 2;
}

static bool main_parse_u64(const char *s, uint64_t min, uint64_t max, uint64_t *out)
{
    if (!s || !*s || *s == '-' || *s == '+') return false;
    errno = 0;
    char *end;
    unsigned long long v = strtoull(s, &end, 10);
    if (errno || *end || v < min || v > max) return false;
    *out = v;
    return true;
}

/* A host name given to --listen becomes the numeric address it resolves to (the first IPv4 one,
 * else the first IPv6 one: "localhost" is 127.0.0.1), so the loopback check and the bind see the
 * address actually listened on. NULL on success, else why not. */
static const char *main_resolve_host(char *host, size_t host_size)
{
    unsigned char probe[sizeof(struct in6_addr)];
    if (inet_pton(AF_INET, host, probe) == 1 || inet_pton(AF_INET6, host, probe) == 1) return NULL;
    struct addrinfo hints = {.ai_family = AF_UNSPEC, .ai_socktype = SOCK_STREAM}, *res = NULL;
    int rc = getaddrinfo(host, NULL, &hints, &res);
    if (rc != 0) return gai_strerror(rc);
    const struct addrinfo *pick = NULL;
    for (const struct addrinfo *a = res; a; a = a->ai_next)
        if (a->ai_family == AF_INET || (a->ai_family == AF_INET6 && !pick)) {
            pick = a;
            if (a->ai_family == AF_INET) break;
        }
    const char *why = "no IPv4 or IPv6 address";
    if (pick) {
        const void *addr = pick->ai_family == AF_INET ? (const void *)&((struct sockaddr_in *)pick->ai_addr)->sin_addr
                                                      : (const void *)&((struct sockaddr_in6 *)pick->ai_addr)->sin6_addr;
        why = inet_ntop(pick->ai_family, addr, host, (socklen_t)host_size) ? NULL : "address too long";
    }
    freeaddrinfo(res);
    return why;
}

/* "'HOST': why" for a usage message (one static buffer: the usage ends the run). */
static const char *main_why(const char *host, const char *why)
{
    static char buf[160];
    snprintf(buf, sizeof buf, "'%s': %s", host, why);
    return buf;
}

static bool main_parse_listen(const char *s, char *out_host, size_t host_size, uint16_t *out_port)
{
    const char *colon = strrchr(s, ':');
    if (!colon || colon == s || (size_t)(colon - s) >= host_size) return false;
    const char *host = s;
    size_t hl = (size_t)(colon - s);
    if (host[0] == '[' && host[hl - 1] == ']') host++, hl -= 2;  /* [::1]:8080 */
    memcpy(out_host, host, hl);
    out_host[hl] = '\0';
    uint64_t port;
    if (!main_parse_u64(colon + 1, 0, 65535, &port)) return false;
    *out_port = (uint16_t)port;
    return true;
}

/* The scene library: --scenes, else scenes/ beside the build folder the binary is in
 * (build/restird and build/san/restird), else ./scenes. */
static void main_default_library(char *out, size_t size)
{
    char exe[PATH_MAX];
    ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
    if (n > 0) {
        exe[n] = '\0';
        char *slash = strrchr(exe, '/');
        if (slash) *slash = '\0';
        const char *ups[] = {"/../scenes", "/../../scenes"};
        for (int i = 0; i < 2; i++) {
            char cand[PATH_MAX + 32];
            snprintf(cand, sizeof cand, "%s%s", exe, ups[i]);
            struct stat st;
            if (stat(cand, &st) == 0 && S_ISDIR(st.st_mode) && realpath(cand, out)) return;
        }
    }
    snprintf(out, size, "scenes");
}

static void main_default_data_dir(char *out, size_t size)
{
    const char *xdg = getenv("XDG_STATE_HOME");
    const char *home = getenv("HOME");
    if (xdg && xdg[0] == '/') snprintf(out, size, "%s/restird", xdg);
    else if (home && home[0] == '/') snprintf(out, size, "%s/.local/state/restird", home);
    else snprintf(out, size, "restird-data");
}

/* A token is 16 to 255 printable characters without spaces; a file's trailing line end (and
 * spaces) are not part of it. Returns NULL or what is wrong. */
static const char *main_set_token(struct daemon_config *cfg, const char *s, size_t n)
{
    while (n > 0 && (s[n - 1] == '\n' || s[n - 1] == '\r' || s[n - 1] == ' ' || s[n - 1] == '\t')) n--;
    if (n < 16) return "is shorter than 16 characters";
    if (n >= sizeof cfg->auth_token) return "is longer than 255 characters";
    for (size_t i = 0; i < n; i++)
        if ((unsigned char)s[i] <= ' ' || (unsigned char)s[i] >= 0x7f)
            return "has a character that is not printable ASCII";
    memcpy(cfg->auth_token, s, n);
    cfg->auth_token[n] = '\0';
    return NULL;
}

static const char *main_read_token(struct daemon_config *cfg, const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f) return strerror(errno);
    char buf[512];
    size_t n = fread(buf, 1, sizeof buf, f);
    fclose(f);
    if (n == sizeof buf) return "is longer than 255 characters";
    return main_set_token(cfg, buf, n);
}

/* Loopback: 127.0.0.0/8 and ::1. Anything else can be reached from other hosts. */
static bool main_loopback(const char *host)
{
    return strncmp(host, "127.", 4) == 0 || strcmp(host, "::1") == 0;
}

/* The stored (uploaded) scenes, loaded on a thread of their own once the daemon listens: its
 * health checks answer meanwhile, and /readyz says "loading" until they are in. */
static void *main_load_stored(void *arg)
{
    struct daemon *d = arg;
    struct err e = {0};
    if (!registry_load_stored(d->registry, &d->stop_loading, &e)) {
        char msg[1024];
        fprintf(stderr, "restird: warning: stored scenes not loaded: %s\n", err_format(&e, msg, sizeof msg));
    }
    atomic_store(&d->loaded, true);
    return NULL;
}

static void main_warn(void *ctx, const char *message)
{
    (void)ctx;
    fprintf(stderr, "restird: warning: %s\n", message);
}

static void main_on_frame(void *ctx, double render_ms)
{
    prom_observe_frame(&((struct daemon *)ctx)->prom, render_ms * 1e-3);
}

/* mkdir -p for the data directory's parents (the registry creates the directory itself). */
static bool main_mkdirs(const char *path)
{
    char buf[PATH_MAX];
    snprintf(buf, sizeof buf, "%s", path);
    for (char *p = buf + 1; *p; p++) {
        if (*p != '/') continue;
        *p = '\0';
        if (mkdir(buf, 0755) != 0 && errno != EEXIST) return false;
        *p = '/';
    }
    return mkdir(buf, 0755) == 0 || errno == EEXIST;
}

int main(int argc, char **argv)
{
    static struct daemon d;
    struct daemon_config *cfg = &d.cfg;
    snprintf(cfg->host, sizeof cfg->host, "127.0.0.1");
    cfg->port = 8080;
    main_default_data_dir(cfg->data_dir, sizeof cfg->data_dir);
    main_default_library(cfg->library_dir, sizeof cfg->library_dir);
    cfg->limits = daemon_default_limits();
    cfg->max_sessions = 64;
    cfg->frames_kept = 16;
    cfg->memory_budget = 8ull << 30;
    cfg->max_session_bytes = 2ull << 30;
    cfg->max_json_body = 1u << 20;
    cfg->max_asset_body = 256u << 20;
    cfg->max_reference_body = 256u << 20;
    cfg->render_slots = 1;
    cfg->render_queue = 16;
    cfg->job_queue = 64;
    cfg->job_workers = 2;
    cfg->connection_limit = 256;
    cfg->per_ip_limit = 64;
    cfg->timeout_s = 60;
    cfg->max_work = 1ull << 32;
    cfg->head_timeout_s = 10;
    cfg->min_body_rate = 1024;

    static const struct { const char *name; size_t offset; uint64_t min, max; int size; } nums[] = {
#define N(opt, field, lo, hi) {opt, offsetof(struct daemon_config, field), lo, hi, (int)sizeof(((struct daemon_config *)0)->field)}
        N("--threads", threads, 0, 1024),
        N("--max-sessions", max_sessions, 1, 100000),
        N("--frames-kept", frames_kept, 1, 100000),
        N("--memory-budget", memory_budget, 1, 1ull << 50),
        N("--max-session-bytes", max_session_bytes, 1, 1ull << 50),
        N("--max-side", limits.max_side, 1, 16384),
        N("--max-pixels", limits.max_pixels, 1, 16384ull * 16384ull),
        N("--max-spp", limits.max_spp, 1, 1u << 24),
        N("--max-frames", limits.max_frames, 1, 1000000),
        N("--max-keys", limits.max_keys, 1, 1000000),
        N("--max-json-body", max_json_body, 2, 64u << 20),
        N("--max-asset-body", max_asset_body, 1, 1ull << 32),
        N("--max-reference-body", max_reference_body, 1, 1ull << 32),
        N("--render-slots", render_slots, 1, 64),
        N("--render-queue", render_queue, 0, 10000),
        N("--job-queue", job_queue, 1, 100000),
        N("--job-workers", job_workers, 1, 64),
        N("--connection-limit", connection_limit, 1, 100000),
        N("--per-ip-limit", per_ip_limit, 1, 100000),
        N("--timeout-s", timeout_s, 1, 86400),
        N("--max-work", max_work, 1, 1ull << 50),
        N("--head-timeout-s", head_timeout_s, 0, 86400),
        N("--min-body-rate", min_body_rate, 0, 1u << 30),
#undef N
    };
    const char *token_file = NULL;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--help") == 0 || strcmp(a, "-h") == 0) {
            fputs(MAIN_USAGE, stdout);
            return 0;
        }
        if (strcmp(a, "--version") == 0) {
            printf("restird %s (commit %s)\n", RESTIRD_VERSION, restird_commit);
            return 0;
        }
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!v) return main_usage("option %s needs a value (or is unknown)", a);
        i++;
        const char *why;
        if (strcmp(a, "--listen") == 0) {
            if (!main_parse_listen(v, cfg->host, sizeof cfg->host, &cfg->port))
                return main_usage("--listen: expected HOST:PORT, got '%s'", v);
            if ((why = main_resolve_host(cfg->host, sizeof cfg->host)))
                return main_usage("--listen: cannot resolve %s", main_why(cfg->host, why));
        } else if (strcmp(a, "--health-listen") == 0) {
            if (!main_parse_listen(v, cfg->health_host, sizeof cfg->health_host, &cfg->health_port))
                return main_usage("--health-listen: expected HOST:PORT, got '%s'", v);
            if ((why = main_resolve_host(cfg->health_host, sizeof cfg->health_host)))
                return main_usage("--health-listen: cannot resolve %s", main_why(cfg->health_host, why));
        } else if (strcmp(a, "--data-dir") == 0) {
            if (!*v || strlen(v) >= sizeof cfg->data_dir) return main_usage("--data-dir: bad path '%s'", v);
            snprintf(cfg->data_dir, sizeof cfg->data_dir, "%s", v);
        } else if (strcmp(a, "--scenes") == 0) {
            if (!*v || strlen(v) >= sizeof cfg->library_dir) return main_usage("--scenes: bad path '%s'", v);
            snprintf(cfg->library_dir, sizeof cfg->library_dir, "%s", v);
        } else if (strcmp(a, "--id") == 0) {
            if (!*v || strlen(v) >= sizeof cfg->id || strpbrk(v, "\r\n")) return main_usage("--id: bad name '%s'", v);
            snprintf(cfg->id, sizeof cfg->id, "%s", v);
        } else if (strcmp(a, "--allow-host") == 0) {
            if (cfg->allow_host_count == DAEMON_MAX_ALLOW_HOSTS)
                return main_usage("--allow-host: more than 16 names%s", "");
            if (!*v || strlen(v) >= sizeof cfg->allow_hosts[0] || strpbrk(v, " :/[]@\t\r\n"))
                return main_usage("--allow-host: '%s' is not a host name (no port, no brackets)", v);
            snprintf(cfg->allow_hosts[cfg->allow_host_count++], sizeof cfg->allow_hosts[0], "%s", v);
        } else if (strcmp(a, "--auth-token-file") == 0) {
            token_file = v;
        } else if (strcmp(a, "--metrics-auth") == 0) {
            if (strcmp(v, "required") != 0 && strcmp(v, "open") != 0)
                return main_usage("--metrics-auth: expected required or open, got '%s'", v);
            cfg->metrics_open = strcmp(v, "open") == 0;
        } else if (strcmp(a, "--default-session") == 0) {
            if (!protocol_valid_id(v, strlen(v))) return main_usage("--default-session: '%s' is not a scene id", v);
            snprintf(cfg->default_scene, sizeof cfg->default_scene, "%s", v);
        } else {
            size_t k = 0;
            for (; k < sizeof nums / sizeof nums[0]; k++)
                if (strcmp(a, nums[k].name) == 0) break;
            if (k == sizeof nums / sizeof nums[0]) return main_usage("unknown option '%s'", a);
            uint64_t x;
            if (!main_parse_u64(v, nums[k].min, nums[k].max, &x)) return main_usage("%s: value out of range", a);
            char *field = (char *)cfg + nums[k].offset;
            if (nums[k].size == 2) *(uint16_t *)field = (uint16_t)x;
            else if (nums[k].size == 4) *(uint32_t *)field = (uint32_t)x;
            else *(uint64_t *)field = x;
        }
    }

    const char *env_token = getenv("RESTIRD_AUTH_TOKEN");
    if (token_file) {
        const char *bad = main_read_token(cfg, token_file);
        if (bad) {
            fprintf(stderr, "restird: --auth-token-file %s: %s\n", token_file, bad);
            return 1;
        }
    } else if (env_token && *env_token) {
        const char *bad = main_set_token(cfg, env_token, strlen(env_token));
        if (bad) {
            fprintf(stderr, "restird: RESTIRD_AUTH_TOKEN %s\n", bad);
            return 1;
        }
    }
    if (!cfg->auth_token[0] && !main_loopback(cfg->host)) {
        fprintf(stderr, "restird: listening on %s (beyond loopback) needs a bearer token: give "
                        "--auth-token-file PATH or set RESTIRD_AUTH_TOKEN (16 to 255 printable characters)\n",
                cfg->host);
        return 1;
    }

    /* Signals are taken by sigwait in this thread; every thread started from here on
     * inherits the mask, so no render thread is interrupted. */
    sigset_t sigs;
    sigemptyset(&sigs);
    sigaddset(&sigs, SIGTERM);
    sigaddset(&sigs, SIGINT);
    pthread_sigmask(SIG_BLOCK, &sigs, NULL);
    signal(SIGPIPE, SIG_IGN);
    /* A write past a file-size limit (RLIMIT_FSIZE) then fails with EFBIG, which the registry
     * reports as a full disk (507), instead of the signal ending the daemon. */
    signal(SIGXFSZ, SIG_IGN);

    struct err e = {0};
    char msg[1024];
    if (!main_mkdirs(cfg->data_dir)) {
        fprintf(stderr, "restird: cannot create the data directory %s: %s\n", cfg->data_dir, strerror(errno));
        return 1;
    }
    d.registry = registry_new_deferred(cfg->library_dir, cfg->data_dir, main_warn, NULL, &e);
    if (!d.registry) {
        fprintf(stderr, "restird: %s\n", err_format(&e, msg, sizeof msg));
        return 1;
    }
    budget_init(&d.budget, cfg->memory_budget);
    registry_set_budget(d.registry, &d.budget);  /* the uploads, loaded later, are charged as they come */
    d.sessions = sessions_new(cfg->max_sessions);
    d.refs = refstore_new(&d.budget);
    gate_init(&d.gate, cfg->render_slots, cfg->render_queue);
    prom_init(&d.prom);
    atomic_init(&d.draining, false);
    atomic_init(&d.loaded, false);
    atomic_init(&d.stop_loading, false);
    pthread_t loader;
    bool loading = false;
    d.jobs = d.sessions && d.refs ? jobs_new(cfg->job_workers, cfg->job_queue, &d.gate, d.refs, main_on_frame, &d, &e) : NULL;
    int status = 1;
    struct http *http = NULL, *health_http = NULL;
    if (!d.sessions || !d.refs || !d.jobs) {
        fprintf(stderr, "restird: cannot start: %s\n", e.message[0] ? e.message : "out of memory");
        goto done;
    }

    uint16_t port = 0, health_port = 0;
    struct http_options ho = {.host = cfg->host, .port = cfg->port, .connection_limit = cfg->connection_limit,
                              .per_ip_limit = cfg->per_ip_limit, .timeout_s = cfg->timeout_s,
                              .head_timeout_s = cfg->head_timeout_s, .min_body_rate = cfg->min_body_rate};
    struct http_app app = {.ctx = &d, .body_policy = api_body_policy, .handle = api_handle, .reject = api_reject,
                           .reject_framing = api_reject_framing,
                           .body_charge = api_body_charge, .body_release = api_body_release, .cut = api_cut,
                           .completed = api_completed, .served_by = cfg->id};
    http = http_start(&ho, &app, &port, &e);
    if (!http) {
        fprintf(stderr, "restird: %s\n", err_format(&e, msg, sizeof msg));
        goto done;
    }
    /* The health listener: its own connections, so /healthz answers while slow or hostile
     * clients hold every connection the main port allows (docs/reliability.md). */
    char health[128] = "";
    if (cfg->health_host[0]) {
        struct http_options hh = {.host = cfg->health_host, .port = cfg->health_port, .connection_limit = 16,
                                  .per_ip_limit = 16, .timeout_s = 10, .head_timeout_s = cfg->head_timeout_s,
                                  .min_body_rate = cfg->min_body_rate};
        struct http_app happ = app;
        happ.body_policy = api_health_body_policy;
        happ.handle = api_handle_health;
        health_http = http_start(&hh, &happ, &health_port, &e);
        if (!health_http) {
            fprintf(stderr, "restird: --health-listen: %s\n", err_format(&e, msg, sizeof msg));
            goto done;
        }
        bool v6 = strchr(cfg->health_host, ':') != NULL;
        snprintf(health, sizeof health, "health http://%s%s%s:%u, ", v6 ? "[" : "", cfg->health_host, v6 ? "]" : "",
                 health_port);
    }
    const char *bracket_l = strchr(cfg->host, ':') ? "[" : "", *bracket_r = strchr(cfg->host, ':') ? "]" : "";
    printf("restird listening on http://%s%s%s:%u (%sdata %s, %zu built-in scenes; loading the stored ones)\n",
           bracket_l, cfg->host, bracket_r, port, health, cfg->data_dir, registry_list(d.registry, NULL, 0));
    fflush(stdout);
    loading = pthread_create(&loader, NULL, main_load_stored, &d) == 0;
    if (!loading) main_load_stored(&d);
    if (cfg->default_scene[0]) {
        /* The default session may be of a stored scene: wait for them. */
        if (loading) {
            pthread_join(loader, NULL);
            loading = false;
        }
        char href[256];
        if (api_default_session(&d, cfg->default_scene, href, sizeof href)) {
            /* The token itself is not printed: the output may end up in a log. */
            printf("default session ready; fetch a frame as EXR with:\n"
                   "  curl -sf -X POST -H 'Content-Type: application/json'%s -o frame.exr http://%s%s%s:%u%s/frames\n",
                   cfg->auth_token[0] ? " -H \"Authorization: Bearer $TOKEN\"" : "", bracket_l, cfg->host, bracket_r,
                   port, href);
        }
    }
    fflush(stdout);

    int sig = 0;
    sigwait(&sigs, &sig);
    fprintf(stderr, "restird: %s: shutting down\n", sig == SIGINT ? "SIGINT" : "SIGTERM");
    atomic_store(&d.stop_loading, true); /* between two stored scenes */
    if (loading) pthread_join(loader, NULL);
    loading = false;
    http_quiesce(http);                  /* no new connections */
    http_quiesce(health_http);
    atomic_store(&d.draining, true);     /* new work on open connections gets 503 draining */
    sessions_remove_all(d.sessions);     /* cancels jobs between frames, ends event streams */
    jobs_stop(d.jobs);                   /* waits for the frame each worker is rendering */
    d.jobs = NULL;
    gate_close(&d.gate);
    http_stop(http);                     /* waits for requests in flight (a frame finishes) */
    http = NULL;
    http_stop(health_http);
    health_http = NULL;
    status = 0;
done:
    atomic_store(&d.stop_loading, true);
    if (loading) pthread_join(loader, NULL);
    http_stop(http);
    http_stop(health_http);
    jobs_stop(d.jobs);
    if (d.sessions) sessions_remove_all(d.sessions);
    sessions_free(d.sessions);
    refstore_free(d.refs);
    registry_free(d.registry);
    budget_destroy(&d.budget);
    gate_destroy(&d.gate);
    prom_destroy(&d.prom);
    parallel_shutdown(); /* last: no render can be running any more; joins the worker pool */
    fprintf(stderr, "restird: stopped\n");
    return status;
}
