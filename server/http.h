/* http.h — the HTTP server under the API: connections, request bodies, responses, the access
 * log hook. The only home of libmicrohttpd (http.c); nothing above it sees MHD types.
 * Thread model: one thread per connection, bounded by a connection limit and a per-IP limit,
 * with an idle timeout. A handler may therefore block (a render waits on the render gate)
 * without delaying any other connection: /healthz is answered on its own thread.
 * Bodies: the route's body limit is looked up from the method and path before a byte is read;
 * over the limit → 413 at once, no Content-Length on a route that needs a body or a chunked
 * body → 411. The body is then buffered whole (it is at most the limit), in a buffer that grows
 * as it arrives and is charged to the app (body_charge) before each step, and handed over. */
#ifndef RESTIRD_HTTP_H
#define RESTIRD_HTTP_H

#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/types.h>

#include "core/err.h"

#define HTTP_MAX_HEADERS 12

struct http_request {
    const char *method;
    const char *path;          /* percent-decoded, without the query */
    const char *body;          /* NULL when empty; not NUL-terminated */
    size_t body_len;
    const char *request_id;
    void *internal;
};

/* Query parameter / request header value, or NULL. */
const char *http_query(const struct http_request *r, const char *key);
const char *http_header(const struct http_request *r, const char *name);
/* The request's query re-encoded ("?a=1&b=x%2Fy", or "" when there is none) into buf; false
 * when it does not fit (buf then holds ""). For redirects that must keep the query. */
bool http_query_string(const struct http_request *r, char *buf, size_t size);

/* True when the client has closed its side of the connection (or reset it) while its request
 * is being handled; cheap (a poll with no wait), for a long handler to call now and then. */
bool http_client_gone(const struct http_request *r);

/* Streaming body (server-sent events): returns bytes written into buf (> 0), or
 * HTTP_STREAM_END. May block (its own connection thread). */
#define HTTP_STREAM_END ((ssize_t)-1)
typedef ssize_t http_stream_fn(void *ctx, char *buf, size_t max);

struct http_response {
    int status;
    const char *content_type;  /* static string */
    char *body;                /* malloc'd; owned by the HTTP layer once the handler returns */
    size_t body_len;
    struct { char name[40]; char value[320]; } headers[HTTP_MAX_HEADERS];
    int header_count;
    http_stream_fn *stream;    /* instead of body */
    void *stream_ctx;
    void (*stream_free)(void *ctx);
    const char *route;         /* route template for metrics, e.g. "/v1/scenes/{scene}" */
};

void http_response_header(struct http_response *r, const char *name, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* The application's side. All callbacks run on connection threads, concurrently. */
struct http_app {
    void *ctx;
    /* Maximum body bytes for this method and path (0 = no body allowed), and whether a body is
     * required (PUT) so that a missing Content-Length is a 411. */
    void (*body_policy)(void *ctx, const char *method, const char *path, size_t *max_body, bool *required);
    void (*handle)(void *ctx, const struct http_request *req, struct http_response *resp);
    /* A request body's buffer is about to grow by `bytes` past its first 64 KiB (which are not
     * charged): false refuses (what was received is freed, the rest is read and dropped, and
     * the request gets a 503 from reject). Every byte charged is given back with body_release
     * by the end of the request. Both may be NULL. */
    bool (*body_charge)(void *ctx, size_t bytes);
    void (*body_release)(void *ctx, size_t bytes);
    /* Fill resp with the problem for a request the HTTP layer refused (411, 413; 503 when
     * body_charge refused, `limit` then the announced body size). */
    void (*reject)(void *ctx, const struct http_request *req, struct http_response *resp, int status, size_t limit);
    /* Fill resp with the 400 for a request whose framing is refused: the header at fault and
     * why. */
    void (*reject_framing)(void *ctx, const struct http_request *req, struct http_response *resp, const char *header,
                           const char *why);
    /* After every response: one access-log line and the request counters. */
    void (*completed)(void *ctx, const char *method, const char *path, const char *route, int status,
                      uint64_t bytes, double ms, const char *request_id);
    /* A connection was shut down for a slow request head (head) or body (!head); may be NULL.
     * Called from the watchdog thread with its lock held: must not block. */
    void (*cut)(void *ctx, bool head);
    /* X-Served-By, added to every response; NULL or "" = "host:port" of the bound socket. */
    const char *served_by;
};

struct http_options {
    const char *host;          /* numeric IPv4 or IPv6 address */
    uint16_t port;             /* 0 = any free port */
    unsigned connection_limit, per_ip_limit, timeout_s;
    /* Slow clients: a request's line and headers must arrive within head_timeout_s of the
     * connection opening or of its previous answer; a body must arrive at min_body_rate
     * bytes/s on average once it has had head_timeout_s. A connection that falls behind is
     * shut down. 0 = no such check (the idle timeout, timeout_s, still applies). */
    unsigned head_timeout_s, min_body_rate;
};

struct http;
/* Starts listening; *bound_port gets the port (useful with port 0). Errors: ERR_INVALID (host),
 * ERR_IO (bind). */
struct http *http_start(const struct http_options *opts, const struct http_app *app, uint16_t *bound_port,
                        struct err *err);
/* Stops accepting connections; requests in flight continue. */
void http_quiesce(struct http *h);
/* Closes every connection, waits for the connection threads, frees. */
void http_stop(struct http *h);

#endif
