/* api.c — routing, the shared answer helpers, and the service and scene endpoints.
 * Sessions, frames, jobs and events are in api_sessions.c. See api.h. */
#include "api.h"

#include <ctype.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>
#include <math.h>

#include "scene/light_sampler.h"
#include "image/tonemap.h"
#include "webui.h"

/* The API description, linked in from protocol/openapi.yaml (see the Makefile). */
extern const char _binary_protocol_openapi_yaml_start[];
extern const char _binary_protocol_openapi_yaml_end[];

/* ---- problems ---- */


static void api_problem_v(struct api_call *c, int status, const char *slug, const char *field, bool has_limit,
                          double limit, const char *fmt, va_list ap)
{
    char detail[768];
    vsnprintf(detail, sizeof detail, fmt, ap);
    const char *title = protocol_problem_title(slug);
    struct protocol_problem p = {.status = status, .slug = slug, .title = title, .detail = detail,
                                 .instance = c->req->path, .field = field,
                                 .has_limit = has_limit, .limit = limit};
    size_t len = 0;
    char *body = protocol_problem_json(&p, &len);
    c->resp->status = body ? status : 500;
    c->resp->content_type = "application/problem+json";
    free(c->resp->body);
    c->resp->body = body;
    c->resp->body_len = body ? len : 0;
    if (status == 429 || status == 503) http_response_header(c->resp, "Retry-After", "%d", status == 503 ? 1 : 2);
}

void api_problem(struct api_call *c, int status, const char *slug, const char *field, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    api_problem_v(c, status, slug, field, false, 0.0, fmt, ap);
    va_end(ap);
}

void api_problem_limit(struct api_call *c, int status, const char *slug, const char *field, double limit,
                       const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    api_problem_v(c, status, slug, field, true, limit, fmt, ap);
    va_end(ap);
}

/* The configured limit a protocol error points at, for the problem's "limit" member. */
static bool api_limit_of(const struct daemon *d, const char *where, double *limit)
{
    const struct protocol_limits *l = &d->cfg.limits;
    if (strcmp(where, "/width") == 0 || strcmp(where, "/height") == 0) *limit = l->max_side;
    else if (strcmp(where, "") == 0) *limit = (double)l->max_pixels;
    else if (strstr(where, "spp")) *limit = l->max_spp;
    else if (strcmp(where, "/lights") == 0 || strcmp(where, "/animation/light_keys") == 0)
        *limit = PROTOCOL_MAX_SHAPE_CHANGES;
    else if (strcmp(where, "/animation/frames") == 0) *limit = l->max_frames;
    else if (strstr(where, "_keys")) *limit = l->max_keys;
    else return false;
    return true;
}

void api_error(struct api_call *c, const struct err *e)
{
    const char *f = e->where;
    double limit;
    switch (e->code) {
    case ERR_PARSE: api_problem(c, 400, "malformed-json", f, "%s", e->message); return;
    case ERR_LIMIT:
        if (api_limit_of(c->d, f, &limit)) api_problem_limit(c, 422, "limit-exceeded", f, limit, "%s", e->message);
        else api_problem(c, 422, "limit-exceeded", f, "%s", e->message);
        return;
    case ERR_NONE:
    case ERR_INVALID:
    case ERR_UNSUPPORTED: api_problem(c, 422, "invalid-field", f, "%s", e->message); return;
    case ERR_NOT_FOUND: api_problem(c, 404, "not-found", NULL, "%s", e->message); return;
    case ERR_CONFLICT: api_problem(c, 409, "conflict", NULL, "%s", e->message); return;
    case ERR_BUSY:
        if (atomic_load(&c->d->draining)) api_problem(c, 503, "draining", NULL, "%s", e->message);
        else api_problem(c, 503, "busy", NULL, "%s", e->message);
        return;
    case ERR_NOMEM: api_problem(c, 503, "busy", NULL, "out of memory: %s", e->message); return;
    case ERR_STORAGE: api_problem(c, 507, "insufficient-storage", NULL, "%s", e->message); return;
    case ERR_IO:
    case ERR_INTERNAL: api_problem(c, 500, "internal", NULL, "%s", e->message); return;
    }
    api_problem(c, 500, "internal", NULL, "%s", e->message);
}

void api_budget_error(struct api_call *c, const struct err *e)
{
    if (e->code == ERR_BUSY && !atomic_load(&c->d->draining))
        api_problem_limit(c, 503, "memory-budget", NULL, (double)c->d->cfg.memory_budget, "%s", e->message);
    else
        api_error(c, e);
}

bool api_client_gone(void *call)
{
    return http_client_gone(((struct api_call *)call)->req);
}

uint64_t api_frame_samples(const struct view_params *p)
{
    /* Methods that take spp trace that many paths per pixel; the others one. */
    uint32_t spp = 1;
    if (p->method->caps & METHOD_TAKES_SPP) view_params_get_uint(p, "spp", &spp);
    return (uint64_t)p->width * p->height * spp;
}

bool api_check_work(struct api_call *c, uint64_t samples, const char *field, const char *what)
{
    uint64_t max = c->d->cfg.max_work;
    if (samples <= max) return true;
    api_problem_limit(c, 422, "limit-exceeded", field, (double)max,
                      "%s takes %llu samples (pixels x spp), over max_work (%llu): fewer pixels or samples, "
                      "or more frames of fewer samples", what, (unsigned long long)samples, (unsigned long long)max);
    return false;
}

void api_json(struct api_call *c, int status, struct jsonw *w)
{
    size_t len = 0;
    char *body = jsonw_finish(w, &len);
    if (!body) {
        api_problem(c, 503, "busy", NULL, "out of memory writing the answer");
        return;
    }
    free(c->resp->body);
    c->resp->status = status;
    c->resp->content_type = "application/json";
    c->resp->body = body;
    c->resp->body_len = len;
}

static bool api_content_type_is(const char *ct, const char *want)
{
    if (!ct) return false;
    size_t n = strlen(want);
    return strncasecmp(ct, want, n) == 0 && (ct[n] == '\0' || ct[n] == ';' || ct[n] == ' ');
}

/* Every body route requires its media type even when the body is empty: a cross-site page can
 * send an empty POST without a preflight, but not one that declares application/json. */
bool api_require_json(struct api_call *c)
{
    const char *ct = http_header(c->req, "Content-Type");
    if (api_content_type_is(ct, "application/json")) return true;
    api_problem(c, 415, "unsupported-media-type", NULL, "the body must be application/json, got %s", ct ? ct : "no Content-Type");
    return false;
}

/* ---- negotiation and images ---- */

const char *api_negotiate(struct api_call *c, const char *const *offered)
{
    const char *accept = http_header(c->req, "Accept");
    if (!accept || !*accept) return offered[0];
    char list[512];
    snprintf(list, sizeof list, "%s", accept);
    char *save = NULL;
    for (char *item = strtok_r(list, ",", &save); item; item = strtok_r(NULL, ",", &save)) {
        while (*item == ' ' || *item == '\t') item++;
        char *semi = strchr(item, ';');
        bool zero_q = false;
        if (semi) {
            *semi = '\0';
            const char *q = strstr(semi + 1, "q=");
            zero_q = q && strtod(q + 2, NULL) == 0.0;
        }
        char *end = item + strlen(item);
        while (end > item && (end[-1] == ' ' || end[-1] == '\t')) *--end = '\0';
        if (zero_q) continue;
        if (strcmp(item, "*/*") == 0) return offered[0];
        for (int i = 0; offered[i]; i++) {
            if (strcasecmp(item, offered[i]) == 0) return offered[i];
            size_t tl = strcspn(offered[i], "/");
            if (strlen(item) == tl + 2 && strncasecmp(item, offered[i], tl) == 0 && strcmp(item + tl, "/*") == 0)
                return offered[i];
        }
    }
    char types[256] = "";
    for (int i = 0; offered[i]; i++) {
        strncat(types, i ? ", " : "", sizeof types - strlen(types) - 1);
        strncat(types, offered[i], sizeof types - strlen(types) - 1);
    }
    api_problem(c, 406, "not-acceptable", NULL, "Accept '%s' names none of: %s", accept, types);
    return NULL;
}

static bool api_parse_double(const char *s, double *out)
{
    char *end = NULL;
    if (!s || !*s) return false;
    *out = strtod(s, &end);
    return *end == '\0' && isfinite(*out);
}

bool api_exr_compression(const char *name, enum exrio_compression *out)
{
    /* The codecs a frame may be written with, named as exrio names them, in lower case. */
    static const enum exrio_compression offered[] = {EXRIO_NONE, EXRIO_ZIP, EXRIO_PIZ};
    for (size_t i = 0; i < sizeof offered / sizeof offered[0]; i++) {
        const char *n = exrio_compression_name(offered[i]);
        size_t k = 0;
        while (n[k] && name[k] == tolower((unsigned char)n[k])) k++;
        if (!n[k] && !name[k]) {
            *out = offered[i];
            return true;
        }
    }
    return false;
}

bool api_check_image_query(struct api_call *c)
{
    const char *px = http_query(c->req, "pixel");
    if (px && strcmp(px, "float") != 0 && strcmp(px, "half") != 0) {
        api_problem(c, 400, "bad-query", "?pixel", "pixel must be 'float' or 'half', got '%s'", px);
        return false;
    }
    const char *cz = http_query(c->req, "compression");
    enum exrio_compression comp;
    if (cz && !api_exr_compression(cz, &comp)) {
        api_problem(c, 400, "bad-query", "?compression", "compression must be 'none', 'zip' or 'piz', got '%s'", cz);
        return false;
    }
    const char *ex = http_query(c->req, "exposure");
    double ev;
    if (ex && (!api_parse_double(ex, &ev) || fabs(ev) > 64.0)) {
        api_problem(c, 400, "bad-query", "?exposure", "exposure must be a number of stops in [-64, 64], got '%s'", ex);
        return false;
    }
    const char *tm = http_query(c->req, "tonemap");
    enum tonemap_curve curve;
    if (tm && !tonemap_curve_parse(tm, &curve)) {
        api_problem(c, 400, "bad-query", "?tonemap", "tonemap must be clamp, reinhard or aces, got '%s'", tm);
        return false;
    }
    return true;
}

void api_send_image(struct api_call *c, const char *type, const struct image *img, const char *etag,
                    api_json_fn *json_fn, void *json_ctx)
{
    struct err e = {0};
    struct http_response *r = c->resp;
    if (etag) {
        const char *inm = http_header(c->req, "If-None-Match");
        http_response_header(r, "ETag", "%s", etag);
        http_response_header(r, "Cache-Control", "private, max-age=31536000, immutable");
        if (inm && strcmp(inm, etag) == 0) {
            r->status = 304;
            return;
        }
    }
    if (strcmp(type, "application/json") == 0) {
        struct jsonw w;
        jsonw_init(&w);
        json_fn(c, &w, json_ctx);
        if (c->resp->status >= 400 && c->resp->body) {  /* json_fn answered with a problem */
            jsonw_destroy(&w);
            return;
        }
        api_json(c, 200, &w);
        return;
    }
    unsigned char *data = NULL;
    size_t size = 0;
    bool ok;
    if (strcmp(type, "image/png") == 0) {
        const char *ex = http_query(c->req, "exposure");
        const char *tm = http_query(c->req, "tonemap");
        struct tonemap_opts o = {.exposure_ev = ex ? (float)strtod(ex, NULL) : 0.0f, .curve = TONEMAP_CLAMP};
        if (tm) tonemap_curve_parse(tm, &o.curve);
        ok = tonemap_png(img, &o, &data, &size, &e);
    } else {
        const char *px = http_query(c->req, "pixel");
        const char *cz = http_query(c->req, "compression");
        struct exrio_write_opts o = {.pixel = (px && strcmp(px, "half") == 0) ? EXRIO_HALF : EXRIO_FLOAT,
                                     .compression = API_EXR_COMPRESSION};
        if (cz) api_exr_compression(cz, &o.compression);  /* checked by api_check_image_query */
        ok = exrio_write_mem(img, &o, &data, &size, &e);
    }
    if (!ok) {
        api_error(c, &e);
        return;
    }
    r->status = 200;
    r->content_type = type;
    r->body = (char *)data;
    r->body_len = size;
}

void api_write_metrics(struct jsonw *w, const char *reference, const struct metrics *m)
{
    jsonw_object_begin(w);
    jsonw_key(w, "reference");
    jsonw_string(w, reference);
    jsonw_key(w, "mape");
    jsonw_double(w, m->mape);
    jsonw_key(w, "rmse");
    jsonw_double(w, m->rmse);
    jsonw_key(w, "relmse");
    jsonw_double(w, m->relmse);
    jsonw_key(w, "pixels");
    jsonw_uint(w, m->pixels_used);
    jsonw_key(w, "nonfinite");  /* left out: NaN or Inf in either image, each pixel once */
    jsonw_uint(w, (uint64_t)m->width * m->height - m->pixels_used);
    jsonw_object_end(w);
}

bool api_scene_exists(struct api_call *c, const char *scene_id)
{
    struct registry_info info;
    if (registry_info(c->d->registry, scene_id, &info)) return true;
    api_problem(c, 404, "scene-not-loaded", NULL, "this daemon does not hold scene '%s' (PUT it first)", scene_id);
    return false;
}

/* ---- service ---- */

static void api_healthz(struct api_call *c)
{
    /* No lock, no allocation beyond the body: this must answer while everything else is busy. */
    static const char body[] = "{\"status\":\"ok\"}";
    c->resp->status = 200;
    c->resp->content_type = "application/json";
    c->resp->body = strdup(body);
    c->resp->body_len = c->resp->body ? sizeof body - 1 : 0;
}

static void api_readyz(struct api_call *c)
{
    if (atomic_load(&c->d->draining)) {
        api_problem(c, 503, "draining", NULL, "the daemon is shutting down");
        return;
    }
    if (!atomic_load(&c->d->loaded)) {
        api_problem(c, 503, "loading", NULL, "the daemon is loading its stored scenes");
        return;
    }
    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "status");
    jsonw_string(&w, "ready");
    jsonw_object_end(&w);
    api_json(c, 200, &w);
}

static void api_metrics(struct api_call *c)
{
    struct daemon *d = c->d;
    struct prom_gauges g = {0};
    struct session *list[256];
    uint32_t n = sessions_list(d->sessions, NULL, list, 256);
    g.sessions = sessions_count(d->sessions);
    for (uint32_t i = 0; i < n; i++) {
        g.session_bytes += session_bytes(list[i]);
        session_release(list[i]);
    }
    g.scenes = (uint32_t)registry_list(d->registry, NULL, 0);
    g.reference_bytes = refstore_bytes(d->refs);
    g.render_queue = gate_waiting(&d->gate);
    g.job_queue = jobs_queued(d->jobs);
    size_t len = 0;
    char *text = prom_format(&d->prom, &g, &len);
    if (!text) {
        api_problem(c, 503, "busy", NULL, "out of memory");
        return;
    }
    c->resp->status = 200;
    c->resp->content_type = "text/plain; version=0.0.4; charset=utf-8";
    c->resp->body = text;
    c->resp->body_len = len;
}

/* The method registry: every method's name, summary, capabilities and parameters with their
 * defaults and ranges (spp within this daemon's max_spp). Clients build their forms from it. */
static void api_methods(struct api_call *c)
{
    struct jsonw w;
    jsonw_init(&w);
    protocol_write_methods(&w, &c->d->cfg.limits);
    api_json(c, 200, &w);
}

static void api_limits(struct api_call *c)
{
    const struct daemon_config *cfg = &c->d->cfg;
    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "max_side"); jsonw_uint(&w, cfg->limits.max_side);
    jsonw_key(&w, "max_pixels"); jsonw_uint(&w, cfg->limits.max_pixels);
    jsonw_key(&w, "max_spp"); jsonw_uint(&w, cfg->limits.max_spp);
    jsonw_key(&w, "max_frames"); jsonw_uint(&w, cfg->limits.max_frames);
    jsonw_key(&w, "max_keys"); jsonw_uint(&w, cfg->limits.max_keys);
    jsonw_key(&w, "max_sessions"); jsonw_uint(&w, cfg->max_sessions);
    jsonw_key(&w, "frames_kept"); jsonw_uint(&w, cfg->frames_kept);
    jsonw_key(&w, "max_json_body"); jsonw_uint(&w, cfg->max_json_body);
    jsonw_key(&w, "max_asset_body"); jsonw_uint(&w, cfg->max_asset_body);
    jsonw_key(&w, "max_reference_body"); jsonw_uint(&w, cfg->max_reference_body);
    jsonw_key(&w, "render_slots"); jsonw_uint(&w, cfg->render_slots);
    jsonw_key(&w, "render_queue"); jsonw_uint(&w, cfg->render_queue);
    jsonw_key(&w, "job_queue"); jsonw_uint(&w, cfg->job_queue);
    jsonw_key(&w, "connection_limit"); jsonw_uint(&w, cfg->connection_limit);
    jsonw_key(&w, "per_ip_connection_limit"); jsonw_uint(&w, cfg->per_ip_limit);
    jsonw_key(&w, "connection_timeout_s"); jsonw_uint(&w, cfg->timeout_s);
    jsonw_key(&w, "memory_budget"); jsonw_uint(&w, cfg->memory_budget);
    jsonw_key(&w, "max_session_bytes"); jsonw_uint(&w, cfg->max_session_bytes);
    jsonw_key(&w, "max_work"); jsonw_uint(&w, cfg->max_work);
    jsonw_key(&w, "head_timeout_s"); jsonw_uint(&w, cfg->head_timeout_s);
    jsonw_key(&w, "min_body_rate"); jsonw_uint(&w, cfg->min_body_rate);
    /* What the budget holds now, so a client can tell how far it is from a refusal. */
    jsonw_key(&w, "memory_used");
    jsonw_object_begin(&w);
    jsonw_key(&w, "sessions"); jsonw_uint(&w, budget_used(&c->d->budget, BUDGET_SESSIONS));
    jsonw_key(&w, "scenes"); jsonw_uint(&w, budget_used(&c->d->budget, BUDGET_SCENES));
    jsonw_key(&w, "references"); jsonw_uint(&w, budget_used(&c->d->budget, BUDGET_REFERENCES));
    jsonw_key(&w, "uploads"); jsonw_uint(&w, budget_used(&c->d->budget, BUDGET_UPLOADS));
    jsonw_object_end(&w);
    jsonw_object_end(&w);
    api_json(c, 200, &w);
}

static void api_openapi(struct api_call *c)
{
    size_t len = (size_t)(_binary_protocol_openapi_yaml_end - _binary_protocol_openapi_yaml_start);
    char *body = malloc(len ? len : 1);
    if (!body) {
        api_problem(c, 503, "busy", NULL, "out of memory");
        return;
    }
    memcpy(body, _binary_protocol_openapi_yaml_start, len);
    c->resp->status = 200;
    c->resp->content_type = "application/yaml";
    c->resp->body = body;
    c->resp->body_len = len;
}

/* ---- the preview page ---- */

/* If-None-Match against a strong ETag: a list of entity tags or "*", compared weakly as RFC
 * 9110 §13.1.2 asks (a W/ prefix is ignored). */
static bool api_etag_matches(const char *inm, const char *etag)
{
    if (!inm) return false;
    size_t n = strlen(etag);
    for (const char *p = inm; *p;) {
        while (*p == ' ' || *p == '\t' || *p == ',') p++;
        if (*p == '*') return true;
        if (strncmp(p, "W/", 2) == 0) p += 2;
        if (strncmp(p, etag, n) == 0 && (p[n] == '\0' || p[n] == ',' || p[n] == ' ' || p[n] == '\t')) return true;
        while (*p && *p != ',') p++;
    }
    return false;
}

/* The page's files carry stable names, so they are revalidated on every use (no-cache: a
 * cheap 304 by ETag) rather than cached as immutable. The document gets a content security
 * policy that allows only this origin: the page loads nothing from elsewhere. */
static void api_send_web_file(struct api_call *c, const char *name)
{
    const struct webui_file *f = webui_find(name);
    if (!f) {
        api_problem(c, 404, "not-found", NULL, "the web page has no file '%s'", name);
        return;
    }
    http_response_header(c->resp, "ETag", "%s", f->etag);
    http_response_header(c->resp, "Cache-Control", "no-cache");
    http_response_header(c->resp, "X-Content-Type-Options", "nosniff");
    if (strncmp(f->type, "text/html", 9) == 0)
        http_response_header(c->resp, "Content-Security-Policy",
                             "default-src 'self'; img-src 'self' blob: data:; object-src 'none'; base-uri 'none'; "
                             "form-action 'none'; frame-ancestors 'none'");
    if (api_etag_matches(http_header(c->req, "If-None-Match"), f->etag)) {
        c->resp->status = 304;
        return;
    }
    char *body = malloc(f->size ? f->size : 1);
    if (!body) {
        api_problem(c, 503, "busy", NULL, "out of memory");
        return;
    }
    memcpy(body, f->data, f->size);
    c->resp->status = 200;
    c->resp->content_type = f->type;
    c->resp->body = body;
    c->resp->body_len = f->size;
}

static void api_page(struct api_call *c) { api_send_web_file(c, "index.html"); }

static void api_page_file(struct api_call *c) { api_send_web_file(c, c->seg[1]); }

/* ---- scenes ---- */

/* replaced: < 0 leaves the member out (GET); 0/1 for the answer to a PUT. */
static void api_write_scene(struct jsonw *w, const struct registry_info *info, int replaced)
{
    char href[128];
    snprintf(href, sizeof href, "/v1/scenes/%s", info->id);
    jsonw_object_begin(w);
    jsonw_key(w, "id"); jsonw_string(w, info->id);
    jsonw_key(w, "builtin"); jsonw_bool(w, info->builtin);
    jsonw_key(w, "hash"); jsonw_string(w, info->hash);
    jsonw_key(w, "materials"); jsonw_uint(w, info->materials);
    jsonw_key(w, "shapes"); jsonw_uint(w, info->shapes);
    jsonw_key(w, "triangles"); jsonw_uint(w, info->triangles);
    jsonw_key(w, "emitters"); jsonw_uint(w, info->emitters);
    jsonw_key(w, "scene_bytes"); jsonw_uint(w, info->scene_bytes);
    jsonw_key(w, "sessions"); jsonw_uint(w, info->sessions);
    jsonw_key(w, "assets"); jsonw_uint(w, info->assets);
    jsonw_key(w, "href"); jsonw_string(w, href);
    if (replaced >= 0) {
        jsonw_key(w, "replaced");
        jsonw_bool(w, replaced == 1);
    }
    jsonw_object_end(w);
}

static void api_scenes_list(struct api_call *c)
{
    size_t n = registry_list(c->d->registry, NULL, 0);
    struct registry_info *infos = calloc(n ? n : 1, sizeof *infos);
    if (!infos) {
        api_problem(c, 503, "busy", NULL, "out of memory");
        return;
    }
    size_t got = registry_list(c->d->registry, infos, n);
    if (got < n) n = got;  /* a scene may come or go between the two calls */
    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "scenes");
    jsonw_array_begin(&w);
    for (size_t i = 0; i < n; i++) api_write_scene(&w, &infos[i], -1);
    jsonw_array_end(&w);
    jsonw_object_end(&w);
    free(infos);
    api_json(c, 200, &w);
}

static void api_scene_get(struct api_call *c)
{
    struct registry_info info;
    if (!registry_info(c->d->registry, c->seg[2], &info)) {
        api_scene_exists(c, c->seg[2]);
        return;
    }
    struct jsonw w;
    jsonw_init(&w);
    api_write_scene(&w, &info, -1);
    api_json(c, 200, &w);
}

static void api_scene_put(struct api_call *c)
{
    if (!api_require_json(c)) return;
    enum registry_put_result result = REGISTRY_CREATED;  /* set by registry_put_scene; -O3 cannot see it */
    struct err e = {0};
    if (!registry_put_scene(c->d->registry, c->seg[2], c->req->body ? c->req->body : "", c->req->body_len, &result, &e)) {
        if (e.code == ERR_CONFLICT) api_problem(c, 409, "conflict", NULL, "%s", e.message);
        else if (e.code == ERR_PARSE) api_problem(c, 400, "malformed-json", e.where, "%s", e.message);
        else if (e.code == ERR_BUSY) api_budget_error(c, &e);
        else if (e.code == ERR_IO || e.code == ERR_STORAGE || e.code == ERR_INTERNAL || e.code == ERR_NOMEM) api_error(c, &e);
        else api_problem(c, 422, "invalid-scene", e.where, "%s", e.message);
        return;
    }
    struct registry_info info;
    registry_info(c->d->registry, c->seg[2], &info);
    struct jsonw w;
    jsonw_init(&w);
    api_write_scene(&w, &info, result == REGISTRY_REPLACED);
    http_response_header(c->resp, "Location", "/v1/scenes/%s", c->seg[2]);
    api_json(c, result == REGISTRY_CREATED ? 201 : 200, &w);
}

static void api_scene_delete(struct api_call *c)
{
    const char *force = http_query(c->req, "force");
    if (force && strcmp(force, "true") != 0 && strcmp(force, "false") != 0) {
        api_problem(c, 400, "bad-query", "?force", "force must be true or false, got '%s'", force);
        return;
    }
    struct err e = {0};
    if (!registry_delete(c->d->registry, c->seg[2], force && strcmp(force, "true") == 0, &e)) {
        if (e.code == ERR_NOT_FOUND) api_scene_exists(c, c->seg[2]);
        else api_error(c, &e);
        return;
    }
    refstore_drop_scene(c->d->refs, c->seg[2]);
    c->resp->status = 204;
}

static void api_asset_put(struct api_call *c)
{
    const char *ct = http_header(c->req, "Content-Type");
    if (!(api_content_type_is(ct, "application/octet-stream") || api_content_type_is(ct, "model/ply") ||
          api_content_type_is(ct, "model/obj") || api_content_type_is(ct, "text/plain"))) {
        api_problem(c, 415, "unsupported-media-type", NULL,
                    "a mesh asset must be application/octet-stream, model/ply, model/obj or text/plain, got %s",
                    ct ? ct : "no Content-Type");
        return;
    }
    bool created = false;
    struct err e = {0};
    if (!registry_put_asset(c->d->registry, c->seg[2], c->seg[4], c->req->body ? c->req->body : "",
                            c->req->body_len, &created, &e)) {
        if (e.code == ERR_INVALID && strcmp(e.where, "name") == 0) api_problem(c, 400, "bad-id", NULL, "%s", e.message);
        else if (e.code == ERR_CONFLICT) api_problem(c, 409, "conflict", NULL, "%s", e.message);
        else if (e.code == ERR_BUSY) api_budget_error(c, &e);
        else if (e.code == ERR_IO || e.code == ERR_STORAGE || e.code == ERR_INTERNAL || e.code == ERR_NOMEM) api_error(c, &e);
        else if (e.code == ERR_LIMIT) api_problem(c, 422, "limit-exceeded", NULL, "%s: %s", e.where, e.message);
        else api_problem(c, 422, e.where[0] == '/' ? "invalid-scene" : "invalid-asset", e.where[0] == '/' ? e.where : NULL,
                         "%s%s%s", e.where[0] == '/' ? "" : e.where, e.where[0] == '/' || !e.where[0] ? "" : ": ", e.message);
        return;
    }
    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "scene"); jsonw_string(&w, c->seg[2]);
    jsonw_key(&w, "name"); jsonw_string(&w, c->seg[4]);
    jsonw_key(&w, "bytes"); jsonw_uint(&w, c->req->body_len);
    jsonw_object_end(&w);
    api_json(c, created ? 201 : 200, &w);
}

struct api_ref_json { struct ref_image *ref; };

static void api_ref_json(struct api_call *c, struct jsonw *w, void *ctx)
{
    (void)c;
    struct ref_image *r = ((struct api_ref_json *)ctx)->ref;
    double mean[3];
    metrics_image_mean(&r->img, mean);
    jsonw_object_begin(w);
    jsonw_key(w, "name"); jsonw_string(w, r->name);
    jsonw_key(w, "scene"); jsonw_string(w, r->scene);
    jsonw_key(w, "width"); jsonw_uint(w, r->img.width);
    jsonw_key(w, "height"); jsonw_uint(w, r->img.height);
    jsonw_key(w, "spp"); jsonw_uint(w, r->spp);
    jsonw_key(w, "method");
    if (r->method) jsonw_string(w, r->method);
    else jsonw_null(w);
    jsonw_key(w, "mean");
    jsonw_array_begin(w);
    for (int i = 0; i < 3; i++) jsonw_double(w, mean[i]);
    jsonw_array_end(w);
    jsonw_object_end(w);
}

static void api_reference_get(struct api_call *c)
{
    static const char *const types[] = {"image/x-exr", "image/png", "application/json", NULL};
    if (!api_scene_exists(c, c->seg[2])) return;
    const char *type = api_negotiate(c, types);
    if (!type || !api_check_image_query(c)) return;
    struct ref_image *r = refstore_get(c->d->refs, c->seg[2], c->seg[4]);
    if (!r) {
        api_problem(c, 404, "not-found", NULL, "scene '%s' has no reference '%s'", c->seg[2], c->seg[4]);
        return;
    }
    struct api_ref_json ctx = {r};
    api_send_image(c, type, &r->img, NULL, api_ref_json, &ctx);
    ref_image_release(r);
}

static void api_write_ref_info(struct jsonw *w, const char *scene, const struct ref_info *r)
{
    char href[160], created[32];
    snprintf(href, sizeof href, "/v1/scenes/%s/references/%s", scene, r->name);
    struct tm tm;
    gmtime_r(&r->created, &tm);
    strftime(created, sizeof created, "%Y-%m-%dT%H:%M:%SZ", &tm);
    jsonw_object_begin(w);
    jsonw_key(w, "name"); jsonw_string(w, r->name);
    jsonw_key(w, "width"); jsonw_uint(w, r->width);
    jsonw_key(w, "height"); jsonw_uint(w, r->height);
    jsonw_key(w, "spp"); jsonw_uint(w, r->spp);
    jsonw_key(w, "method");
    if (r->method) jsonw_string(w, r->method);
    else jsonw_null(w);
    jsonw_key(w, "bytes"); jsonw_uint(w, r->bytes);
    jsonw_key(w, "created"); jsonw_string(w, created);
    jsonw_key(w, "href"); jsonw_string(w, href);
    jsonw_object_end(w);
}

static void api_references_list(struct api_call *c)
{
    if (!api_scene_exists(c, c->seg[2])) return;
    /* A reference may be stored between counting and copying: ask again with room for it. */
    struct ref_info *list = NULL;
    size_t n = refstore_list(c->d->refs, c->seg[2], NULL, 0), got;
    for (;;) {
        struct ref_info *grown = realloc(list, (n ? n : 1) * sizeof *list);
        if (!grown) {
            free(list);
            api_problem(c, 503, "busy", NULL, "out of memory");
            return;
        }
        list = grown;
        got = refstore_list(c->d->refs, c->seg[2], list, n);
        if (got <= n) break;
        n = got;
    }
    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "references");
    jsonw_array_begin(&w);
    for (size_t i = 0; i < got; i++) api_write_ref_info(&w, c->seg[2], &list[i]);
    jsonw_array_end(&w);
    jsonw_object_end(&w);
    free(list);
    api_json(c, 200, &w);
}

static void api_reference_delete(struct api_call *c)
{
    if (!api_scene_exists(c, c->seg[2])) return;
    if (!refstore_delete(c->d->refs, c->seg[2], c->seg[4])) {
        api_problem(c, 404, "not-found", NULL, "scene '%s' has no reference '%s'", c->seg[2], c->seg[4]);
        return;
    }
    c->resp->status = 204;
}

static void api_reference_put(struct api_call *c)
{
    if (!api_scene_exists(c, c->seg[2])) return;
    const char *ct = http_header(c->req, "Content-Type");
    if (!(api_content_type_is(ct, "image/x-exr") || api_content_type_is(ct, "image/aces"))) {
        api_problem(c, 415, "unsupported-media-type", NULL, "a reference must be image/x-exr or image/aces, got %s",
                    ct ? ct : "no Content-Type");
        return;
    }
    struct image img;
    struct err e = {0};
    /* The decoded image is reserved from the budget, as its header gives its size, before a
     * pixel is decoded: a small compressed file can ask for gigabytes. */
    struct exrio_info info;
    const char *data = c->req->body ? c->req->body : "";
    if (!exrio_probe_mem(data, c->req->body_len, "reference", &info, &e)) {
        api_problem(c, 422, "invalid-reference", NULL, "%s", e.message);
        return;
    }
    uint64_t decoded = info.width > 0 && info.height > 0
                           ? (uint64_t)info.width * (uint64_t)info.height * sizeof(struct vec3) : 0;
    if (!budget_reserve(&c->d->budget, BUDGET_UPLOADS, decoded, &e)) {
        api_budget_error(c, &e);
        return;
    }
    bool read = exrio_read_mem(data, c->req->body_len, "reference", &img, &e);
    budget_release(&c->d->budget, BUDGET_UPLOADS, decoded);  /* refstore_put reserves the image itself */
    if (!read) {
        if (e.code == ERR_NOMEM) api_error(c, &e);
        else api_problem(c, 422, "invalid-reference", NULL, "%s", e.message);
        return;
    }
    uint32_t w_ = img.width, h_ = img.height;
    bool existed;
    if (!refstore_put(c->d->refs, c->seg[2], c->seg[4], &img, 0, NULL, &existed, &e)) {
        api_budget_error(c, &e);
        return;
    }
    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    jsonw_key(&w, "name"); jsonw_string(&w, c->seg[4]);
    jsonw_key(&w, "width"); jsonw_uint(&w, w_);
    jsonw_key(&w, "height"); jsonw_uint(&w, h_);
    jsonw_object_end(&w);
    api_json(c, existed ? 200 : 201, &w);
}

/* ---- routing ---- */

enum api_body { BODY_NONE, BODY_JSON, BODY_ASSET, BODY_REFERENCE };

struct api_route {
    const char *pattern;              /* segments; "*" = an id, "#" = a frame number, "@" = a file name (the handler checks it) */
    const char *methods[3];
    void (*fn[3])(struct api_call *c);
    enum api_body body[3];
    /* The media types every answer of the route has (checked against Accept before the
     * handler runs: 406 without side effects); NULL when the handler negotiates itself. */
    const char *const *produces;
};

static const char *const api_json_only[] = {"application/json", NULL};
static const char *const api_png_only[] = {"image/png", NULL};
static const char *const api_prometheus[] = {"text/plain", NULL};
static const char *const api_yaml[] = {"application/yaml", NULL};

static const struct api_route api_routes[] = {
    {"/", {"GET"}, {api_page}, {0}, NULL},
    {"/ui/@", {"GET"}, {api_page_file}, {0}, NULL},
    {"/healthz", {"GET"}, {api_healthz}, {0}, api_json_only},
    {"/readyz", {"GET"}, {api_readyz}, {0}, api_json_only},
    {"/metrics", {"GET"}, {api_metrics}, {0}, api_prometheus},
    {"/v1/limits", {"GET"}, {api_limits}, {0}, api_json_only},
    {"/v1/methods", {"GET"}, {api_methods}, {0}, api_json_only},
    {"/v1/openapi.yaml", {"GET"}, {api_openapi}, {0}, api_yaml},
    {"/v1/scenes", {"GET"}, {api_scenes_list}, {0}, api_json_only},
    {"/v1/scenes/*", {"GET", "PUT", "DELETE"}, {api_scene_get, api_scene_put, api_scene_delete}, {0, BODY_JSON, 0},
     api_json_only},
    {"/v1/scenes/*/assets/@", {"PUT"}, {api_asset_put}, {BODY_ASSET}, api_json_only},
    {"/v1/scenes/*/references", {"GET"}, {api_references_list}, {0}, api_json_only},
    {"/v1/scenes/*/references/*", {"GET", "PUT", "DELETE"}, {api_reference_get, api_reference_put, api_reference_delete},
     {0, BODY_REFERENCE, 0}, NULL},
    {"/v1/scenes/*/sessions", {"GET", "POST"}, {api_sessions_list, api_sessions_post}, {0, BODY_JSON}, api_json_only},
    {"/v1/scenes/*/sessions/*", {"GET", "DELETE"}, {api_session_get, api_session_delete}, {0}, api_json_only},
    {"/v1/scenes/*/sessions/*/reset", {"POST"}, {api_session_reset}, {BODY_JSON}, api_json_only},
    {"/v1/scenes/*/sessions/*/frames", {"POST"}, {api_frames_post}, {BODY_JSON}, NULL},
    {"/v1/scenes/*/sessions/*/frames/#", {"GET"}, {api_frame_get}, {0}, NULL},
    {"/v1/scenes/*/sessions/*/frames/#/metrics", {"GET"}, {api_frame_metrics}, {0}, api_json_only},
    {"/v1/scenes/*/sessions/*/frames/#/error.png", {"GET"}, {api_frame_error_png}, {0}, api_png_only},
    {"/v1/scenes/*/sessions/*/accumulation", {"GET"}, {api_accumulation_get}, {0}, NULL},
    {"/v1/scenes/*/sessions/*/renders", {"GET", "POST"}, {api_renders_list, api_renders_post}, {0, BODY_JSON},
     api_json_only},
    {"/v1/scenes/*/sessions/*/renders/*", {"GET", "DELETE"}, {api_render_get, api_render_delete}, {0}, api_json_only},
    {"/v1/scenes/*/sessions/*/renders/*/metrics", {"GET"}, {api_render_metrics}, {0}, NULL},
    {"/v1/scenes/*/sessions/*/references/*", {"POST"}, {api_session_reference_post}, {BODY_JSON}, api_json_only},
    {"/v1/scenes/*/sessions/*/events", {"GET"}, {api_events_get}, {0}, NULL},
};
#define API_ROUTE_COUNT (sizeof api_routes / sizeof api_routes[0])

/* Splits the path into segments (in c->buf); false when it has too many or empty ones. "/" has
 * none (the page's route). */
static bool api_split(struct api_call *c, const char *path)
{
    c->nseg = 0;
    if (path[0] != '/' || strlen(path) >= sizeof c->buf) return false;
    if (path[1] == '\0') return true;
    snprintf(c->buf, sizeof c->buf, "%s", path + 1);
    char *p = c->buf;
    for (;;) {
        if (c->nseg == API_MAX_SEGMENTS) return false;
        c->seg[c->nseg++] = p;
        char *slash = strchr(p, '/');
        if (!slash) break;
        *slash = '\0';
        p = slash + 1;
    }
    for (int i = 0; i < c->nseg; i++)
        if (!c->seg[i][0]) return false;
    return true;
}

/* Matches the segment shapes only; ids are validated after the route is known. */
static bool api_match(const char *pattern, const struct api_call *c)
{
    char pat[128];
    snprintf(pat, sizeof pat, "%s", pattern + 1);
    int i = 0;
    char *save = NULL;
    for (char *tok = strtok_r(pat, "/", &save); tok; tok = strtok_r(NULL, "/", &save), i++) {
        if (i >= c->nseg) return false;
        if (strcmp(tok, "*") == 0 || strcmp(tok, "#") == 0 || strcmp(tok, "@") == 0) continue;
        if (strcmp(tok, c->seg[i]) != 0) return false;
    }
    return i == c->nseg;
}

static const struct api_route *api_find(struct api_call *c, const char *path)
{
    if (!api_split(c, path)) return NULL;
    for (size_t r = 0; r < API_ROUTE_COUNT; r++)
        if (api_match(api_routes[r].pattern, c)) return &api_routes[r];
    return NULL;
}

void api_body_policy(void *ctx, const char *method, const char *path, size_t *max_body, bool *required)
{
    struct daemon *d = ctx;
    struct api_call c = {.d = d};
    *max_body = 0;
    *required = false;
    const struct api_route *r = api_find(&c, path);
    if (!r) return;
    for (int i = 0; i < 3 && r->methods[i]; i++) {
        if (strcmp(r->methods[i], method) != 0) continue;
        switch (r->body[i]) {
        case BODY_NONE: break;
        case BODY_JSON: *max_body = d->cfg.max_json_body; break;
        case BODY_ASSET: *max_body = d->cfg.max_asset_body; break;
        case BODY_REFERENCE: *max_body = d->cfg.max_reference_body; break;
        }
        *required = strcmp(method, "PUT") == 0;
    }
}

void api_reject(void *ctx, const struct http_request *req, struct http_response *resp, int status, size_t limit)
{
    struct api_call c = {.d = ctx, .req = req, .resp = resp};
    resp->route = "refused";
    if (status == 411)
        api_problem(&c, 411, "length-required", NULL, "this request needs a Content-Length (chunked bodies are not accepted)");
    else if (status == 503)
        api_problem_limit(&c, 503, "memory-budget", NULL, (double)c.d->cfg.memory_budget,
                          "the memory budget has no room for the rest of this %zu-byte body", limit);
    else if (limit == 0)
        api_problem_limit(&c, 413, "body-too-large", NULL, 0, "%s %s takes no body", req->method, req->path);
    else
        api_problem_limit(&c, 413, "body-too-large", NULL, (double)limit, "the body is over the limit of %zu bytes", limit);
}

void api_cut(void *ctx, bool head)
{
    prom_count_cut(&((struct daemon *)ctx)->prom, head);
}

bool api_body_charge(void *ctx, size_t bytes)
{
    struct daemon *d = ctx;
    return budget_reserve(&d->budget, BUDGET_UPLOADS, bytes, NULL);
}

void api_body_release(void *ctx, size_t bytes)
{
    struct daemon *d = ctx;
    budget_release(&d->budget, BUDGET_UPLOADS, bytes);
}

void api_reject_framing(void *ctx, const struct http_request *req, struct http_response *resp, const char *header,
                        const char *why)
{
    struct api_call c = {.d = ctx, .req = req, .resp = resp};
    resp->route = "refused";
    api_problem(&c, 400, "bad-header", header, "%s", why);
}

static bool api_valid_frame_ref(const char *s)
{
    if (strcmp(s, "latest") == 0) return true;
    size_t n = strlen(s);
    if (n == 0 || n > 10) return false;
    for (size_t i = 0; i < n; i++)
        if (!isdigit((unsigned char)s[i])) return false;
    return strtoull(s, NULL, 10) <= UINT32_MAX;
}

/* ---- who may ask ---- */

/* The host name of a Host header or of an Origin's authority, without the port and the
 * brackets of an IPv6 address, lower-cased into out; false when it is malformed. */
static bool api_host_name(const char *s, size_t len, char *out, size_t size)
{
    const char *end = s + len;
    if (len > 0 && s[0] == '[') {
        const char *close = memchr(s, ']', len);
        if (!close || (close + 1 != end && close[1] != ':')) return false;
        s++;
        end = close;
    } else {
        const char *colon = memchr(s, ':', len);
        if (colon) {
            if (memchr(colon + 1, ':', (size_t)(end - colon - 1))) return false;
            end = colon;
        }
    }
    size_t n = (size_t)(end - s);
    if (n == 0 || n >= size) return false;
    for (size_t i = 0; i < n; i++) {
        unsigned char ch = (unsigned char)s[i];
        if (ch <= ' ' || ch >= 0x7f || ch == '/' || ch == '@') return false;
        out[i] = (char)tolower(ch);
    }
    out[n] = '\0';
    return true;
}

static bool api_host_allowed(const struct daemon_config *cfg, const char *name)
{
    static const char *const loopback[] = {"localhost", "127.0.0.1", "::1"};
    for (size_t i = 0; i < sizeof loopback / sizeof loopback[0]; i++)
        if (strcmp(name, loopback[i]) == 0) return true;
    bool unspecified = strcmp(cfg->host, "0.0.0.0") == 0 || strcmp(cfg->host, "::") == 0;
    if (!unspecified && strcasecmp(name, cfg->host) == 0) return true;
    for (unsigned i = 0; i < cfg->allow_host_count; i++)
        if (strcmp(cfg->allow_hosts[i], "*") == 0 || strcasecmp(name, cfg->allow_hosts[i]) == 0) return true;
    return false;
}

/* Compares without an early exit, so the time taken does not tell how much of a guess was
 * right. */
static bool api_token_equal(const char *given, size_t n, const char *token)
{
    size_t m = strlen(token);
    unsigned diff = (unsigned)(n ^ m);
    for (size_t i = 0; i < n; i++) diff |= (unsigned char)given[i] ^ (unsigned char)token[m ? i % m : 0];
    return diff == 0 && m > 0;
}

/* The checks every request passes before its route runs (docs/deploy.md, "Who can reach the
 * daemon"): a Host this daemon is known by (against DNS rebinding), the bearer token when one
 * is configured, and for a request that changes state, an Origin (when the browser sends one)
 * of this daemon (against cross-site requests). The health checks are always open; the page's
 * own files are open so a browser can load it and be given the token. */
static bool api_guard(struct api_call *c, const char *method, const char *path)
{
    const struct daemon_config *cfg = &c->d->cfg;
    if (strcmp(path, "/healthz") == 0 || strcmp(path, "/readyz") == 0) return true;
    char name[256];
    const char *host = http_header(c->req, "Host");
    if (host && (!api_host_name(host, strlen(host), name, sizeof name) || !api_host_allowed(cfg, name))) {
        c->resp->route = "refused";
        api_problem(c, 403, "forbidden", "Host",
                    "this daemon is not '%s' (it answers to its loopback names and listen address; "
                    "--allow-host adds names)", host);
        return false;
    }
    bool page = strcmp(path, "/") == 0 || strncmp(path, "/ui/", 4) == 0;
    bool open = page || (strcmp(path, "/metrics") == 0 && cfg->metrics_open);
    if (cfg->auth_token[0] && !open) {
        const char *auth = http_header(c->req, "Authorization");
        bool ok = auth && strncasecmp(auth, "Bearer ", 7) == 0;
        if (ok) {
            const char *t = auth + 7;
            while (*t == ' ') t++;
            size_t n = strlen(t);
            while (n > 0 && t[n - 1] == ' ') n--;
            ok = api_token_equal(t, n, cfg->auth_token);
        }
        /* A browser's EventSource cannot send headers: an event stream may carry the token as
         * the access_token query parameter (RFC 6750 §2.3), and nothing else may. */
        size_t pl = strlen(path);
        const char *qt = http_query(c->req, "access_token");
        if (!auth && qt && strcmp(method, "GET") == 0 && pl > 7 && strcmp(path + pl - 7, "/events") == 0)
            ok = api_token_equal(qt, strlen(qt), cfg->auth_token);
        if (!ok) {
            c->resp->route = "refused";
            http_response_header(c->resp, "WWW-Authenticate", "Bearer realm=\"restird\"");
            api_problem(c, 401, "unauthorized", "Authorization", "%s",
                        auth ? "the bearer token is not this daemon's"
                             : "this daemon needs 'Authorization: Bearer TOKEN' (its --auth-token-file or "
                               "RESTIRD_AUTH_TOKEN)");
            return false;
        }
    }
    bool safe = strcmp(method, "GET") == 0 || strcmp(method, "HEAD") == 0 || strcmp(method, "OPTIONS") == 0;
    const char *origin = http_header(c->req, "Origin");
    if (!safe && origin) {
        const char *authority = strstr(origin, "://");
        bool ok = authority && (strncasecmp(origin, "http://", 7) == 0 || strncasecmp(origin, "https://", 8) == 0);
        if (ok) {
            authority += 3;
            size_t n = strcspn(authority, "/");
            ok = authority[n] == '\0' && api_host_name(authority, n, name, sizeof name) && api_host_allowed(cfg, name);
        }
        if (!ok) {
            c->resp->route = "refused";
            api_problem(c, 403, "forbidden", "Origin",
                        "%s %s from the page of another site ('%s') is refused", method, path, origin);
            return false;
        }
    }
    return true;
}

void api_handle(void *ctx, const struct http_request *req, struct http_response *resp)
{
    struct api_call c = {.d = ctx, .req = req, .resp = resp};
    if (!api_guard(&c, req->method, req->path)) return;
    const struct api_route *r = api_find(&c, req->path);
    if (!r) {
        resp->route = "unmatched";
        api_problem(&c, 404, "not-found", NULL, "no resource at %s", req->path);
        return;
    }
    resp->route = r->pattern;
    int m = -1;
    char allow[64] = "";
    /* HEAD is GET without the body (the HTTP layer leaves the body out). */
    const char *method = strcmp(req->method, "HEAD") == 0 ? "GET" : req->method;
    for (int i = 0; i < 3 && r->methods[i]; i++) {
        if (strcmp(r->methods[i], method) == 0) m = i;
        strncat(allow, i ? ", " : "", sizeof allow - strlen(allow) - 1);
        strncat(allow, r->methods[i], sizeof allow - strlen(allow) - 1);
        if (strcmp(r->methods[i], "GET") == 0) strncat(allow, ", HEAD", sizeof allow - strlen(allow) - 1);
    }
    if (m < 0) {
        http_response_header(resp, "Allow", "%s", allow);
        api_problem(&c, 405, "method-not-allowed", NULL, "%s is not allowed here (allowed: %s)", req->method, allow);
        return;
    }
    /* Ids in the path. */
    char pat[128];
    snprintf(pat, sizeof pat, "%s", r->pattern + 1);
    int i = 0;
    char *save = NULL;
    for (char *tok = strtok_r(pat, "/", &save); tok; tok = strtok_r(NULL, "/", &save), i++) {
        if (strcmp(tok, "*") == 0 && !protocol_valid_id(c.seg[i], strlen(c.seg[i]))) {
            api_problem(&c, 400, "bad-id", NULL, "'%s' is not a valid id ([A-Za-z0-9_-]{1,64})", c.seg[i]);
            return;
        }
        if (strcmp(tok, "#") == 0 && !api_valid_frame_ref(c.seg[i])) {
            api_problem(&c, 400, "bad-id", NULL, "'%s' is not a frame number or 'latest'", c.seg[i]);
            return;
        }
    }
    if (r->produces && !api_negotiate(&c, r->produces)) return;
    if (atomic_load(&c.d->draining) && strcmp(method, "GET") != 0) {
        api_problem(&c, 503, "draining", NULL, "the daemon is shutting down");
        return;
    }
    r->fn[m](&c);
}

void api_health_body_policy(void *ctx, const char *method, const char *path, size_t *max_body, bool *required)
{
    (void)ctx;
    (void)method;
    (void)path;
    *max_body = 0;
    *required = false;
}

void api_handle_health(void *ctx, const struct http_request *req, struct http_response *resp)
{
    struct api_call c = {.d = ctx, .req = req, .resp = resp};
    bool get = strcmp(req->method, "GET") == 0 || strcmp(req->method, "HEAD") == 0;
    if (get && strcmp(req->path, "/healthz") == 0) {
        resp->route = "/healthz";
        api_healthz(&c);
    } else if (get && strcmp(req->path, "/readyz") == 0) {
        resp->route = "/readyz";
        api_readyz(&c);
    } else {
        resp->route = "unmatched";
        api_problem(&c, 404, "not-found", NULL, "the health listener answers GET /healthz and GET /readyz only");
    }
}

void api_completed(void *ctx, const char *method, const char *path, const char *route, int status, uint64_t bytes,
                   double ms, const char *request_id)
{
    struct daemon *d = ctx;
    prom_count_request(&d->prom, route, status);
    char stamp[32];
    time_t now = time(NULL);
    struct tm tm;
    gmtime_r(&now, &tm);
    strftime(stamp, sizeof stamp, "%Y-%m-%dT%H:%M:%SZ", &tm);
    /* The path is percent-decoded: a control byte (or a space, or a byte over 0x7e) in it is
     * written %XX again, so that a request cannot forge or split a line of the log. */
    char safe[3 * 512 + 1];
    size_t n = 0;
    for (const unsigned char *p = (const unsigned char *)path; *p && n + 4 < sizeof safe; p++) {
        if (*p <= ' ' || *p >= 0x7f || *p == '%') n += (size_t)snprintf(safe + n, sizeof safe - n, "%%%02X", *p);
        else safe[n++] = (char)*p;
    }
    safe[n] = '\0';
    fprintf(stderr, "%s %s %s %d %llu %.1f %s\n", stamp, method, safe, status, (unsigned long long)bytes, ms,
            request_id);
}
