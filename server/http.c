/* http.c — libmicrohttpd behind the small interface of http.h (the only includer of
 * microhttpd.h). See http.h for the thread model and the body rules.
 * Refs: libmicrohttpd 0.9.75 manual (thread-per-connection mode, MHD_quiesce_daemon,
 * MHD_OPTION_NOTIFY_COMPLETED, content-reader callbacks). */
#include "http.h"

#include <arpa/inet.h>
#include <errno.h>
#include <poll.h>
#include <microhttpd.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

/* Bodies over the limit up to this size are read and discarded so that the client reads the
 * 413; larger ones get the answer at once and the connection closes. */
#define HTTP_DISCARD_MAX ((unsigned long long)64 << 20)
/* A body's buffer starts at this size and doubles as the body arrives. */
#define HTTP_BODY_FIRST ((size_t)64 << 10)

/* One open connection, as the watchdog sees it (MHD's socket context). A connection is always
 * in one of three phases: waiting for a request's line and headers (since it opened or since
 * its previous answer), receiving a body, or busy (a handler runs or an answer is being sent). */
enum http_phase { HTTP_HEAD, HTTP_BODY, HTTP_BUSY };

struct http_sock {
    struct http_sock *prev, *next;
    int fd;
    enum http_phase phase;
    struct timespec since;     /* when the phase began */
    uint64_t body_bytes;       /* received in HTTP_BODY */
    bool cut;                  /* shut down by the watchdog */
};

struct http {
    struct MHD_Daemon *mhd;
    struct http_app app;
    char served_by[192];       /* app.served_by points here; written before the first request */
    atomic_uint_fast64_t next_id;
    uint32_t boot;             /* start time, so request ids differ across restarts */
    /* The watchdog: slow clients (see http.h, struct http_options). */
    unsigned head_timeout_s, min_body_rate;
    pthread_mutex_t socks_lock;
    pthread_cond_t socks_wake;
    struct http_sock *socks;   /* open connections */
    bool watchdog_running, watchdog_stop;
    pthread_t watchdog;
};

/* Per-request state, MHD's con_cls. */
struct http_conn {
    struct timespec start;
    char method[16];
    char path[512];
    char request_id[72];
    const char *route;
    int status;
    uint64_t bytes;
    bool responded;            /* a response was queued (possibly before the body was read) */
    int reject_status;         /* refused from the headers; the body is being discarded */
    bool discard;              /* a body nobody asked for, being dropped */
    bool close;                /* answer with Connection: close (the framing was refused) */
    size_t reject_limit;
    char *body;
    size_t body_len, body_cap;
    size_t body_want;          /* Content-Length: the buffer grows to it as the body arrives */
    size_t body_charged;       /* bytes of the buffer charged to the app (body_charge) */
    struct http *http;
    struct http_sock *sock;    /* the connection's watchdog entry, or NULL */
};

static double http_since_s(const struct timespec *t0, const struct timespec *now)
{
    return (double)(now->tv_sec - t0->tv_sec) + (double)(now->tv_nsec - t0->tv_nsec) * 1e-9;
}

static void http_phase(struct http *h, struct http_sock *s, enum http_phase phase)
{
    if (!s) return;
    pthread_mutex_lock(&h->socks_lock);
    if (s->phase != phase) {
        s->phase = phase;
        s->body_bytes = 0;
        clock_gettime(CLOCK_MONOTONIC, &s->since);
    }
    pthread_mutex_unlock(&h->socks_lock);
}

static void http_body_bytes(struct http *h, struct http_sock *s, size_t n)
{
    if (!s) return;
    pthread_mutex_lock(&h->socks_lock);
    s->body_bytes += n;
    pthread_mutex_unlock(&h->socks_lock);
}

static void http_notify_connection(void *cls, struct MHD_Connection *c, void **socket_context,
                                   enum MHD_ConnectionNotificationCode code)
{
    struct http *h = cls;
    if (code == MHD_CONNECTION_NOTIFY_STARTED) {
        const union MHD_ConnectionInfo *ci = MHD_get_connection_info(c, MHD_CONNECTION_INFO_CONNECTION_FD);
        struct http_sock *s = ci ? calloc(1, sizeof *s) : NULL;
        *socket_context = s;
        if (!s) return;  /* not watched: only the idle timeout applies */
        s->fd = ci->connect_fd;
        s->phase = HTTP_HEAD;
        clock_gettime(CLOCK_MONOTONIC, &s->since);
        pthread_mutex_lock(&h->socks_lock);
        s->next = h->socks;
        if (h->socks) h->socks->prev = s;
        h->socks = s;
        pthread_mutex_unlock(&h->socks_lock);
        return;
    }
    /* Closed: MHD closes the socket after this returns, so the watchdog, which shuts sockets
     * down under the same lock, never touches a descriptor that was reused. */
    struct http_sock *s = *socket_context;
    if (!s) return;
    pthread_mutex_lock(&h->socks_lock);
    if (s->prev) s->prev->next = s->next;
    else h->socks = s->next;
    if (s->next) s->next->prev = s->prev;
    pthread_mutex_unlock(&h->socks_lock);
    free(s);
    *socket_context = NULL;
}

/* Every 200 ms: a connection that has not delivered a request's line and headers within
 * head_timeout_s of opening (or of its previous answer), or whose body, after the same grace,
 * arrives slower than min_body_rate bytes/s on average, is shut down. Its thread then sees the
 * end of the stream and MHD closes it: the connection slot is free again. */
static void *http_watchdog(void *arg)
{
    struct http *h = arg;
    pthread_mutex_lock(&h->socks_lock);
    while (!h->watchdog_stop) {
        struct timespec now;
        clock_gettime(CLOCK_MONOTONIC, &now);
        for (struct http_sock *s = h->socks; s; s = s->next) {
            if (s->cut || s->phase == HTTP_BUSY) continue;
            double t = http_since_s(&s->since, &now);
            bool slow_head = s->phase == HTTP_HEAD && h->head_timeout_s && t > h->head_timeout_s;
            bool slow_body = s->phase == HTTP_BODY && h->min_body_rate && t > h->head_timeout_s &&
                             (double)s->body_bytes < (double)h->min_body_rate * t;
            if (!slow_head && !slow_body) continue;
            shutdown(s->fd, SHUT_RDWR);
            s->cut = true;
            if (h->app.cut) h->app.cut(h->app.ctx, slow_head);
        }
        struct timespec until = now;
        until.tv_nsec += 200 * 1000 * 1000;
        if (until.tv_nsec >= 1000000000L) {
            until.tv_sec++;
            until.tv_nsec -= 1000000000L;
        }
        pthread_cond_timedwait(&h->socks_wake, &h->socks_lock, &until);
    }
    pthread_mutex_unlock(&h->socks_lock);
    return NULL;
}


struct http_stream_box {
    http_stream_fn *fn;
    void *ctx;
    void (*free_fn)(void *ctx);
    uint64_t bytes;
};

const char *http_query(const struct http_request *r, const char *key)
{
    return MHD_lookup_connection_value(r->internal, MHD_GET_ARGUMENT_KIND, key);
}

const char *http_header(const struct http_request *r, const char *name)
{
    return MHD_lookup_connection_value(r->internal, MHD_HEADER_KIND, name);
}

bool http_client_gone(const struct http_request *r)
{
    const union MHD_ConnectionInfo *ci = MHD_get_connection_info(r->internal, MHD_CONNECTION_INFO_CONNECTION_FD);
    if (!ci) return false;
    struct pollfd p = {.fd = ci->connect_fd, .events = POLLIN};
    if (poll(&p, 1, 0) <= 0) return false;
    if (p.revents & (POLLHUP | POLLERR)) return true;
    if (!(p.revents & POLLIN)) return false;
    /* Readable: either the next pipelined request (the client is there) or the end of the
     * stream (it closed). MHD reads nothing while this connection's handler runs. */
    char b;
    ssize_t n = recv(ci->connect_fd, &b, 1, MSG_PEEK | MSG_DONTWAIT);
    return n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR);
}

struct http_query_buf { char *buf; size_t size, len; bool overflow; };

static void http_query_append(struct http_query_buf *q, const char *s)
{
    static const char hex[] = "0123456789ABCDEF";
    for (; *s; s++) {
        unsigned char ch = (unsigned char)*s;
        bool plain = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') || ch == '-' ||
                     ch == '_' || ch == '.' || ch == '~';
        size_t need = plain ? 1 : 3;
        if (q->len + need + 1 > q->size) {
            q->overflow = true;
            return;
        }
        if (plain) {
            q->buf[q->len++] = (char)ch;
        } else {
            q->buf[q->len++] = '%';
            q->buf[q->len++] = hex[ch >> 4];
            q->buf[q->len++] = hex[ch & 15];
        }
    }
    q->buf[q->len] = '\0';
}

static enum MHD_Result http_query_each(void *cls, enum MHD_ValueKind kind, const char *key, const char *value)
{
    (void)kind;
    struct http_query_buf *q = cls;
    if (q->len + 2 > q->size) {
        q->overflow = true;
        return MHD_NO;
    }
    char sep = q->len == 0 ? '?' : '&';
    q->buf[q->len++] = sep;
    q->buf[q->len] = '\0';
    http_query_append(q, key);
    if (value) {
        if (q->len + 2 > q->size) {
            q->overflow = true;
            return MHD_NO;
        }
        q->buf[q->len++] = '=';
        q->buf[q->len] = '\0';
        http_query_append(q, value);
    }
    return q->overflow ? MHD_NO : MHD_YES;
}

bool http_query_string(const struct http_request *r, char *buf, size_t size)
{
    if (size == 0) return false;
    struct http_query_buf q = {buf, size, 0, false};
    buf[0] = '\0';
    MHD_get_connection_values(r->internal, MHD_GET_ARGUMENT_KIND, http_query_each, &q);
    if (q.overflow) buf[0] = '\0';
    return !q.overflow;
}

void http_response_header(struct http_response *r, const char *name, const char *fmt, ...)
{
    if (r->header_count >= HTTP_MAX_HEADERS) return;
    int i = r->header_count++;
    snprintf(r->headers[i].name, sizeof r->headers[i].name, "%s", name);
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(r->headers[i].value, sizeof r->headers[i].value, fmt, ap);
    va_end(ap);
}

static bool http_valid_request_id(const char *s)
{
    size_t n = 0;
    for (; s[n]; n++) {
        char c = s[n];
        if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '-' || c == '_'))
            return false;
    }
    return n >= 1 && n <= 64;
}

static ssize_t http_stream_reader(void *cls, uint64_t pos, char *buf, size_t max)
{
    (void)pos;
    struct http_stream_box *box = cls;
    ssize_t n = box->fn(box->ctx, buf, max);
    if (n < 0) return MHD_CONTENT_READER_END_OF_STREAM;
    box->bytes += (uint64_t)n;
    return n;
}

static void http_stream_done(void *cls)
{
    struct http_stream_box *box = cls;
    if (box->free_fn) box->free_fn(box->ctx);
    free(box);
}

/* Queues `resp` on the connection; takes ownership of resp->body. */
static enum MHD_Result http_send(struct http *h, struct MHD_Connection *c, struct http_conn *hc,
                                 struct http_response *resp)
{
    struct MHD_Response *r;
    bool no_body = resp->status == 204 || resp->status == 304;
    /* HEAD: a buffered body gives its Content-Length and MHD leaves the bytes out; a stream
     * (an event stream) is not started at all. */
    if (strcmp(hc->method, "HEAD") == 0 && resp->stream) {
        if (resp->stream_free) resp->stream_free(resp->stream_ctx);
        resp->stream = NULL;
        resp->stream_free = NULL;
    }
    if (resp->stream && !no_body) {
        struct http_stream_box *box = calloc(1, sizeof *box);
        if (!box) {
            if (resp->stream_free) resp->stream_free(resp->stream_ctx);
            return MHD_NO;
        }
        box->fn = resp->stream;
        box->ctx = resp->stream_ctx;
        box->free_fn = resp->stream_free;
        r = MHD_create_response_from_callback(MHD_SIZE_UNKNOWN, 4096, http_stream_reader, box, http_stream_done);
        if (!r) {
            http_stream_done(box);
            return MHD_NO;
        }
    } else {
        if (resp->stream && resp->stream_free) resp->stream_free(resp->stream_ctx);
        if (no_body || !resp->body) {
            free(resp->body);
            resp->body = NULL;
            resp->body_len = 0;
            r = MHD_create_response_from_buffer(0, (void *)"", MHD_RESPMEM_PERSISTENT);
        } else {
            r = MHD_create_response_from_buffer(resp->body_len, resp->body, MHD_RESPMEM_MUST_FREE);
            if (!r) free(resp->body);
        }
        resp->body = NULL;
        if (!r) return MHD_NO;
    }
    if (resp->content_type && !no_body) MHD_add_response_header(r, MHD_HTTP_HEADER_CONTENT_TYPE, resp->content_type);
    MHD_add_response_header(r, "X-Request-Id", hc->request_id);
    if (h->app.served_by) MHD_add_response_header(r, "X-Served-By", h->app.served_by);
    if (hc->close) MHD_add_response_header(r, MHD_HTTP_HEADER_CONNECTION, "close");
    for (int i = 0; i < resp->header_count; i++) MHD_add_response_header(r, resp->headers[i].name, resp->headers[i].value);
    hc->status = resp->status;
    hc->bytes = resp->stream ? 0 : resp->body_len;
    hc->route = resp->route;
    hc->responded = true;
    http_phase(h, hc->sock, HTTP_BUSY);
    enum MHD_Result ret = MHD_queue_response(c, (unsigned)resp->status, r);
    MHD_destroy_response(r);
    return ret;
}

/* What the request's framing headers say, counted over every header line (MHD's lookup sees
 * only the first of a repeated header, and frames the body by it). */
struct http_framing {
    int content_length, transfer_encoding, host;
};

static enum MHD_Result http_framing_each(void *cls, enum MHD_ValueKind kind, const char *key, const char *value)
{
    (void)kind;
    (void)value;
    struct http_framing *f = cls;
    if (strcasecmp(key, MHD_HTTP_HEADER_CONTENT_LENGTH) == 0) f->content_length++;
    else if (strcasecmp(key, MHD_HTTP_HEADER_TRANSFER_ENCODING) == 0) f->transfer_encoding++;
    else if (strcasecmp(key, MHD_HTTP_HEADER_HOST) == 0) f->host++;
    return MHD_YES;
}

/* The framing problem of a request, or NULL: a body must be framed one way only (RFC 9112
 * §6.3: a repeated Content-Length, Transfer-Encoding beside Content-Length, or a transfer coding
 * other than chunked would let a proxy and this server see different requests), and an HTTP/1.1
 * request names its Host exactly once. */
static const char *http_framing_problem(struct MHD_Connection *c, const char *version, bool *chunked,
                                        const char **header)
{
    struct http_framing f = {0};
    MHD_get_connection_values(c, MHD_HEADER_KIND, http_framing_each, &f);
    *chunked = false;
    *header = MHD_HTTP_HEADER_CONTENT_LENGTH;
    if (f.content_length > 1) return "the request has more than one Content-Length header";
    *header = MHD_HTTP_HEADER_TRANSFER_ENCODING;
    if (f.transfer_encoding > 1) return "the request has more than one Transfer-Encoding header";
    if (f.transfer_encoding && f.content_length) return "the request has both Transfer-Encoding and Content-Length";
    if (f.transfer_encoding) {
        const char *te = MHD_lookup_connection_value(c, MHD_HEADER_KIND, MHD_HTTP_HEADER_TRANSFER_ENCODING);
        if (!te || strcasecmp(te, "chunked") != 0) return "the only Transfer-Encoding accepted is chunked";
        *chunked = true;
    }
    *header = MHD_HTTP_HEADER_HOST;
    if (f.host > 1) return "the request has more than one Host header";
    if (f.host == 0 && version && strcmp(version, MHD_HTTP_VERSION_1_1) == 0)
        return "an HTTP/1.1 request needs a Host header";
    return NULL;
}

static enum MHD_Result http_access(void *cls, struct MHD_Connection *c, const char *url, const char *method,
                                   const char *version, const char *upload_data, size_t *upload_data_size,
                                   void **con_cls)
{
    struct http *h = cls;
    struct http_conn *hc = *con_cls;
    struct http_request req = {.method = method, .path = url, .internal = c};
    struct http_response resp = {.status = 500};

    if (!hc) {
        hc = calloc(1, sizeof *hc);
        if (!hc) return MHD_NO;
        *con_cls = hc;
        hc->http = h;
        const union MHD_ConnectionInfo *si = MHD_get_connection_info(c, MHD_CONNECTION_INFO_SOCKET_CONTEXT);
        hc->sock = si ? si->socket_context : NULL;
        http_phase(h, hc->sock, HTTP_BODY);
        clock_gettime(CLOCK_MONOTONIC, &hc->start);
        snprintf(hc->method, sizeof hc->method, "%s", method);
        snprintf(hc->path, sizeof hc->path, "%s", url);
        const char *rid = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "X-Request-Id");
        if (rid && http_valid_request_id(rid))
            snprintf(hc->request_id, sizeof hc->request_id, "%s", rid);
        else
            snprintf(hc->request_id, sizeof hc->request_id, "%08x-%llu", h->boot,
                     (unsigned long long)atomic_fetch_add(&h->next_id, 1));
        req.request_id = hc->request_id;

        bool chunked = false;
        const char *header = NULL;
        const char *bad = http_framing_problem(c, version, &chunked, &header);
        if (bad) {
            /* The connection closes after the answer: where its body ends is not known. */
            h->app.reject_framing(h->app.ctx, &req, &resp, header, bad);
            hc->close = true;
            return http_send(h, c, hc, &resp);
        }
        size_t max_body = 0;
        bool required = false;
        h->app.body_policy(h->app.ctx, method, url, &max_body, &required);
        const char *cl = MHD_lookup_connection_value(c, MHD_HEADER_KIND, MHD_HTTP_HEADER_CONTENT_LENGTH);
        unsigned long long length = 0;
        if (cl) {
            char *end = NULL;
            length = strtoull(cl, &end, 10);
            if (end == cl || *end) cl = NULL;  /* MHD refuses malformed lengths before we get here */
        }
        /* 411: a chunked body (its length is unknown, so no limit can be decided up front), or
         * no length where a body is required. */
        if (chunked || (!cl && required)) {
            h->app.reject(h->app.ctx, &req, &resp, 411, max_body);
            return http_send(h, c, hc, &resp);
        }
        if (max_body == 0 && length > 0 && length <= HTTP_DISCARD_MAX) {
            /* No body is expected here (or the path matches no route): read and drop it, and
             * let the handler answer what it would answer without one (404, 405, ...). */
            hc->discard = true;
            return MHD_YES;
        }
        if (length > max_body) {
            /* The verdict is made now, from the header. A client that asked "Expect:
             * 100-continue" gets it before sending anything; one that sends the body anyway
             * (most HTTP libraries) would see its connection reset mid-upload and never read
             * the 413, so a moderately sized body is read and thrown away first. */
            const char *expect = MHD_lookup_connection_value(c, MHD_HEADER_KIND, MHD_HTTP_HEADER_EXPECT);
            if ((expect && strcasecmp(expect, "100-continue") == 0) || length > HTTP_DISCARD_MAX) {
                h->app.reject(h->app.ctx, &req, &resp, 413, max_body);
                return http_send(h, c, hc, &resp);
            }
            hc->reject_status = 413;
            hc->reject_limit = max_body;
            return MHD_YES;
        }
        /* The buffer grows as the body arrives (http_body_append), each step charged to the app
         * first: a client that announces a large body and sends it slowly holds only what it
         * sent, and the memory budget sees it. */
        hc->body_want = (size_t)length;
        return MHD_YES;
    }
    req.request_id = hc->request_id;
    http_body_bytes(h, hc->sock, *upload_data_size);
    if (hc->responded) {
        /* The response went out before the body; discard what still arrives. */
        *upload_data_size = 0;
        return MHD_YES;
    }
    if (hc->reject_status) {
        if (*upload_data_size > 0) {
            *upload_data_size = 0;  /* discarded */
            return MHD_YES;
        }
        h->app.reject(h->app.ctx, &req, &resp, hc->reject_status, hc->reject_limit);
        return http_send(h, c, hc, &resp);
    }
    if (hc->discard && *upload_data_size > 0) {
        *upload_data_size = 0;
        return MHD_YES;
    }
    if (*upload_data_size > 0) {
        size_t n = *upload_data_size;
        if (n > hc->body_want - hc->body_len) n = hc->body_want - hc->body_len;  /* MHD enforces the length */
        *upload_data_size = 0;
        if (n == 0) return MHD_YES;
        if (hc->body_len + n > hc->body_cap) {
            size_t cap = hc->body_cap ? hc->body_cap : HTTP_BODY_FIRST;
            while (cap < hc->body_len + n) cap = cap > SIZE_MAX / 2 ? SIZE_MAX : cap * 2;
            if (cap > hc->body_want) cap = hc->body_want;
            /* The first HTTP_BODY_FIRST bytes of a body are not charged (at most that much per
             * connection): a full budget still lets small JSON requests through. */
            size_t free_part = hc->body_cap > HTTP_BODY_FIRST ? hc->body_cap : HTTP_BODY_FIRST;
            size_t more = cap > free_part ? cap - free_part : 0;
            char *grown = NULL;
            bool charged = more == 0 || !h->app.body_charge || h->app.body_charge(h->app.ctx, more);
            if (charged) grown = realloc(hc->body, cap);
            if (!grown) {
                if (charged && more && h->app.body_release) h->app.body_release(h->app.ctx, more);
                /* The budget (or malloc) refused: what was received is freed now, the rest is
                 * read and dropped (as for a 413), and the answer is a 503. */
                free(hc->body);
                hc->body = NULL;
                hc->body_len = hc->body_cap = 0;
                if (hc->body_charged && h->app.body_release) h->app.body_release(h->app.ctx, hc->body_charged);
                hc->body_charged = 0;
                hc->reject_status = 503;
                hc->reject_limit = hc->body_want;
                return MHD_YES;
            }
            hc->body = grown;
            hc->body_cap = cap;
            hc->body_charged += more;
        }
        memcpy(hc->body + hc->body_len, upload_data, n);
        hc->body_len += n;
        return MHD_YES;
    }
    req.body = hc->body;
    req.body_len = hc->body_len;
    http_phase(h, hc->sock, HTTP_BUSY);
    h->app.handle(h->app.ctx, &req, &resp);
    return http_send(h, c, hc, &resp);
}

static void http_completed(void *cls, struct MHD_Connection *c, void **con_cls, enum MHD_RequestTerminationCode toe)
{
    (void)c;
    (void)toe;
    struct http *h = cls;
    struct http_conn *hc = *con_cls;
    if (!hc) return;
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    double ms = (double)(now.tv_sec - hc->start.tv_sec) * 1e3 + (double)(now.tv_nsec - hc->start.tv_nsec) * 1e-6;
    if (h->app.completed)
        h->app.completed(h->app.ctx, hc->method, hc->path, hc->route, hc->status, hc->bytes, ms, hc->request_id);
    http_phase(h, hc->sock, HTTP_HEAD);  /* the next request's head is due from now */
    free(hc->body);
    if (hc->body_charged && h->app.body_release) h->app.body_release(h->app.ctx, hc->body_charged);
    free(hc);
    *con_cls = NULL;
}

static int http_hex(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* Percent-decoding for paths and query arguments that leaves "%2F" (and "%00") encoded: an
 * encoded slash inside a path segment must not become a segment separator (a scene id or asset
 * name "a%2F..%2Fb" stays one segment, which then fails the id rules), and NUL must not cut a
 * string short. MHD's default decoder turns both into raw bytes before we see the path. */
static size_t http_unescape(void *cls, struct MHD_Connection *c, char *s)
{
    (void)cls;
    (void)c;
    char *r = s, *w = s;
    while (*r) {
        int hi, lo;
        if (r[0] == '%' && (hi = http_hex(r[1])) >= 0 && (lo = http_hex(r[2])) >= 0) {
            int v = hi * 16 + lo;
            if (v != '/' && v != 0) {
                *w++ = (char)v;
                r += 3;
                continue;
            }
        }
        *w++ = *r++;
    }
    *w = '\0';
    return (size_t)(w - s);
}

static void http_mhd_log(void *cls, const char *fmt, va_list ap)
{
    (void)cls;
    fputs("restird: http: ", stderr);
    vfprintf(stderr, fmt, ap);
}

struct http *http_start(const struct http_options *opts, const struct http_app *app, uint16_t *bound_port,
                        struct err *err)
{
    struct sockaddr_storage ss;
    memset(&ss, 0, sizeof ss);
    unsigned flags = MHD_USE_THREAD_PER_CONNECTION | MHD_USE_INTERNAL_POLLING_THREAD | MHD_USE_ITC | MHD_USE_ERROR_LOG;
    struct sockaddr_in *a4 = (struct sockaddr_in *)&ss;
    struct sockaddr_in6 *a6 = (struct sockaddr_in6 *)&ss;
    if (inet_pton(AF_INET, opts->host, &a4->sin_addr) == 1) {
        a4->sin_family = AF_INET;
        a4->sin_port = htons(opts->port);
    } else if (inet_pton(AF_INET6, opts->host, &a6->sin6_addr) == 1) {
        a6->sin6_family = AF_INET6;
        a6->sin6_port = htons(opts->port);
        flags |= MHD_USE_IPv6;
    } else {
        return err_set(err, ERR_INVALID, "--listen", "'%s' is not a numeric IPv4 or IPv6 address", opts->host), NULL;
    }
    /* The socket is bound here rather than by MHD so the port (0 = any) is known before the
     * first connection is served: X-Served-By defaults to host:port, and writing it after
     * MHD_start_daemon raced with the first requests (ThreadSanitizer, make test-tsan). */
    int fd = socket(ss.ss_family, SOCK_STREAM | SOCK_CLOEXEC, 0);
    int one = 1;
    socklen_t slen = ss.ss_family == AF_INET ? (socklen_t)sizeof *a4 : (socklen_t)sizeof *a6;
    if (fd < 0 || setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one) != 0 ||
        bind(fd, (struct sockaddr *)&ss, slen) != 0 || listen(fd, 128) != 0 ||
        getsockname(fd, (struct sockaddr *)&ss, &slen) != 0) {
        if (fd >= 0) close(fd);
        return err_set(err, ERR_IO, "--listen", "cannot listen on %s port %u (in use, or not an address of this host)",
                       opts->host, opts->port), NULL;
    }
    uint16_t port = ntohs(ss.ss_family == AF_INET ? a4->sin_port : a6->sin6_port);
    struct http *h = calloc(1, sizeof *h);
    if (!h) {
        close(fd);
        return err_set(err, ERR_NOMEM, NULL, "out of memory"), NULL;
    }
    h->app = *app;
    h->head_timeout_s = opts->head_timeout_s;
    h->min_body_rate = opts->min_body_rate;
    pthread_mutex_init(&h->socks_lock, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&h->socks_wake, &ca);
    pthread_condattr_destroy(&ca);
    bool v6 = ss.ss_family == AF_INET6;
    if (app->served_by && app->served_by[0])
        snprintf(h->served_by, sizeof h->served_by, "%s", app->served_by);
    else
        snprintf(h->served_by, sizeof h->served_by, "%s%s%s:%u", v6 ? "[" : "", opts->host, v6 ? "]" : "", port);
    h->app.served_by = h->served_by;
    h->boot = (uint32_t)time(NULL);
    atomic_init(&h->next_id, 1);
    h->mhd = MHD_start_daemon(flags, port, NULL, NULL, http_access, h,
                              MHD_OPTION_EXTERNAL_LOGGER, http_mhd_log, NULL,
                              MHD_OPTION_LISTEN_SOCKET, (MHD_socket)fd,
                              MHD_OPTION_CONNECTION_LIMIT, (unsigned)opts->connection_limit,
                              MHD_OPTION_PER_IP_CONNECTION_LIMIT, (unsigned)opts->per_ip_limit,
                              MHD_OPTION_CONNECTION_TIMEOUT, (unsigned)opts->timeout_s,
                              MHD_OPTION_CONNECTION_MEMORY_LIMIT, (size_t)(64 * 1024),
                              MHD_OPTION_NOTIFY_COMPLETED, http_completed, h,
                              MHD_OPTION_NOTIFY_CONNECTION, http_notify_connection, h,
                              MHD_OPTION_UNESCAPE_CALLBACK, http_unescape, NULL,
                              MHD_OPTION_END);
    if (!h->mhd) {
        close(fd);
        pthread_cond_destroy(&h->socks_wake);
        pthread_mutex_destroy(&h->socks_lock);
        free(h);
        return err_set(err, ERR_IO, "--listen", "cannot serve on %s port %u", opts->host, port), NULL;
    }
    if ((h->head_timeout_s || h->min_body_rate) && pthread_create(&h->watchdog, NULL, http_watchdog, h) == 0)
        h->watchdog_running = true;
    if (bound_port) *bound_port = port;
    return h;
}

void http_quiesce(struct http *h)
{
    if (!h || !h->mhd) return;
    MHD_socket s = MHD_quiesce_daemon(h->mhd);
    if (s != MHD_INVALID_SOCKET) close(s);
}

void http_stop(struct http *h)
{
    if (!h) return;
    if (h->watchdog_running) {
        pthread_mutex_lock(&h->socks_lock);
        h->watchdog_stop = true;
        pthread_cond_signal(&h->socks_wake);
        pthread_mutex_unlock(&h->socks_lock);
        pthread_join(h->watchdog, NULL);
    }
    if (h->mhd) MHD_stop_daemon(h->mhd);
    pthread_cond_destroy(&h->socks_wake);
    pthread_mutex_destroy(&h->socks_lock);
    free(h);
}
