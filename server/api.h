/* api.h — the HTTP API: routing (api.c) and the handlers of each resource (api.c: service and
 * scenes; api_sessions.c: sessions, frames, jobs, events). The only place that maps `struct
 * err` codes to HTTP statuses and writes problem+json bodies.
 * Refs: protocol/API.md (the contract), RFC 9457 (problem details), RFC 9110 (semantics). */
#ifndef RESTIRD_API_H
#define RESTIRD_API_H

#include "daemon.h"
#include "http.h"
#include "image/exrio.h"

/* The http_app callbacks; ctx is the struct daemon. */
void api_body_policy(void *ctx, const char *method, const char *path, size_t *max_body, bool *required);
void api_handle(void *ctx, const struct http_request *req, struct http_response *resp);
void api_reject(void *ctx, const struct http_request *req, struct http_response *resp, int status, size_t limit);
/* Counts a connection the HTTP layer closed for slowness (in /metrics). */
void api_cut(void *ctx, bool head);
/* The memory budget's side of request bodies (BUDGET_UPLOADS). */
bool api_body_charge(void *ctx, size_t bytes);
void api_body_release(void *ctx, size_t bytes);
void api_reject_framing(void *ctx, const struct http_request *req, struct http_response *resp, const char *header,
                        const char *why);
/* The health listener's callbacks (--health-listen): GET /healthz and /readyz, nothing else. */
void api_health_body_policy(void *ctx, const char *method, const char *path, size_t *max_body, bool *required);
void api_handle_health(void *ctx, const struct http_request *req, struct http_response *resp);
void api_completed(void *ctx, const char *method, const char *path, const char *route, int status, uint64_t bytes,
                   double ms, const char *request_id);

/* ---- shared by the handler files ---- */

#define API_MAX_SEGMENTS 10

struct api_call {
    struct daemon *d;
    const struct http_request *req;
    struct http_response *resp;
    const char *seg[API_MAX_SEGMENTS];  /* path segments; the {placeholders} are the ids */
    int nseg;
    char buf[1024];                     /* segment storage */
};

/* True when the client of the call (a struct api_call *) has closed its connection: a long
 * render polls it to give up a frame nobody will read. */
bool api_client_gone(void *call);

/* The samples (pixels x samples per pixel) one frame of a session with these params takes. */
uint64_t api_frame_samples(const struct view_params *p);
/* True when `samples` is within max_work; else answers 422 limit-exceeded at `field` with the
 * limit, naming `what` and the value. */
bool api_check_work(struct api_call *c, uint64_t samples, const char *field, const char *what);

/* Problem response; `field` may be NULL; detail is printf-formatted. */
void api_problem(struct api_call *c, int status, const char *slug, const char *field, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));
/* Same with a "limit" member. */
/* A refusal by the memory budget (ERR_BUSY): 503 "memory-budget" with the budget as "limit" and
 * Retry-After; any other error as api_error. */
void api_budget_error(struct api_call *c, const struct err *e);
void api_problem_limit(struct api_call *c, int status, const char *slug, const char *field, double limit,
                       const char *fmt, ...) __attribute__((format(printf, 6, 7)));
/* Maps an error to its problem: ERR_PARSE 400, ERR_INVALID/UNSUPPORTED 422, ERR_LIMIT 422
 * limit-exceeded, ERR_NOT_FOUND 404, ERR_CONFLICT 409, ERR_BUSY/NOMEM 503 + Retry-After,
 * ERR_IO/INTERNAL 500. field = err->where. */
void api_error(struct api_call *c, const struct err *e);
/* JSON body from a finished writer (500 on allocation failure). */
void api_json(struct api_call *c, int status, struct jsonw *w);
/* Requires Content-Type application/json when the body is non-empty (415 otherwise). */
bool api_require_json(struct api_call *c);

/* Negotiation: picks one of `offered` (the first is the default) from the Accept header;
 * NULL after answering 406. */
const char *api_negotiate(struct api_call *c, const char *const *offered);

/* Image answers: EXR (?pixel=), PNG (?exposure=, ?tonemap=), or JSON written by `json_fn`.
 * etag may be NULL (no caching headers). Takes nothing over. */
typedef void api_json_fn(struct api_call *c, struct jsonw *w, void *ctx);
void api_send_image(struct api_call *c, const char *type, const struct image *img, const char *etag,
                    api_json_fn *json_fn, void *json_ctx);
/* Validates the image query parameters before any work is done (400 bad-query). */
bool api_check_image_query(struct api_call *c);

/* The EXR compression when a request names none (?compression=none|zip|piz): measured in
 * docs/benchmarks.md, "EXR frames: which compression". */
#define API_EXR_COMPRESSION EXRIO_NONE
/* The compression a request names (exrio_compression_name in lower case); false when it names
 * none a frame may be written with. */
bool api_exr_compression(const char *name, enum exrio_compression *out);

/* Writes a metrics object {"reference","mape","rmse","relmse","pixels","nonfinite"}. */
void api_write_metrics(struct jsonw *w, const char *reference, const struct metrics *m);

/* Looks up the scene for a scene-scoped route: 404 scene-not-loaded when absent. */
bool api_scene_exists(struct api_call *c, const char *scene_id);

/* Handlers in api_sessions.c; seg[2] is the scene id, seg[4] the session id. */
void api_sessions_post(struct api_call *c);
void api_sessions_list(struct api_call *c);
void api_session_get(struct api_call *c);
void api_session_delete(struct api_call *c);
void api_session_reset(struct api_call *c);
void api_frames_post(struct api_call *c);
void api_frame_get(struct api_call *c);
void api_frame_metrics(struct api_call *c);
void api_frame_error_png(struct api_call *c);
void api_accumulation_get(struct api_call *c);
void api_renders_list(struct api_call *c);
void api_renders_post(struct api_call *c);
void api_render_get(struct api_call *c);
void api_render_delete(struct api_call *c);
void api_render_metrics(struct api_call *c);
void api_session_reference_post(struct api_call *c);
void api_events_get(struct api_call *c);

/* Creates a session at start-up (make run's default session); false on failure (printed). */
bool api_default_session(struct daemon *d, const char *scene_id, char *href, size_t size);

#endif
