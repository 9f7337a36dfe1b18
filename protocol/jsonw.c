/* jsonw.c — the JSON text writer responses are built with, and RFC 9457 problem bodies.
 * Owns: separators, string escaping, number formatting, the problem+json shape.
 * Must not: allocate after a failure (every call is then a no-op), emit text that is not JSON
 * (non-finite doubles become null, bytes that are not UTF-8 become U+FFFD, nesting deeper than
 * PROTOCOL_MAX_DEPTH or an unclosed container makes jsonw_finish fail instead of returning
 * half a document).
 * Refs: RFC 8259 §7 (string escapes), RFC 9457 (problem details). */
#include "protocol.h"

#include "input/json_read.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void jsonw_init(struct jsonw *w)
{
    memset(w, 0, sizeof *w);
}

void jsonw_destroy(struct jsonw *w)
{
    free(w->buf);
    jsonw_init(w);
}

static void jsonw_put(struct jsonw *w, const char *s, size_t n)
{
    if (w->failed) return;
    if (w->len + n + 1 > w->cap) {
        size_t cap = w->cap ? w->cap : 256;
        while (cap < w->len + n + 1) {
            if (cap > SIZE_MAX / 2) { w->failed = true; return; }
            cap *= 2;
        }
        char *b = realloc(w->buf, cap);
        if (!b) { w->failed = true; return; }
        w->buf = b;
        w->cap = cap;
    }
    memcpy(w->buf + w->len, s, n);
    w->len += n;
    w->buf[w->len] = '\0';
}

static void jsonw_puts(struct jsonw *w, const char *s)
{
    jsonw_put(w, s, strlen(s));
}

/* Before any value or key: the comma that separates it from the previous member or element.
 * A value right after its key finds need_comma false (jsonw_key cleared it). */
static void jsonw_sep(struct jsonw *w)
{
    if (w->failed) return;
    if (w->need_comma[w->depth]) jsonw_put(w, ",", 1);
}

static void jsonw_after_value(struct jsonw *w)
{
    if (!w->failed) w->need_comma[w->depth] = true;
}

static void jsonw_open(struct jsonw *w, char c)
{
    jsonw_sep(w);
    if (w->failed) return;
    if (w->depth >= PROTOCOL_MAX_DEPTH) { w->failed = true; return; }
    jsonw_put(w, &c, 1);
    if (w->failed) return;
    w->depth++;
    w->need_comma[w->depth] = false;
}

static void jsonw_close(struct jsonw *w, char c)
{
    if (w->failed) return;
    if (w->depth <= 0) { w->failed = true; return; }
    jsonw_put(w, &c, 1);
    w->depth--;
    jsonw_after_value(w);
}

void jsonw_object_begin(struct jsonw *w) { jsonw_open(w, '{'); }
void jsonw_object_end(struct jsonw *w) { jsonw_close(w, '}'); }
void jsonw_array_begin(struct jsonw *w) { jsonw_open(w, '['); }
void jsonw_array_end(struct jsonw *w) { jsonw_close(w, ']'); }

/* Length of the well-formed UTF-8 sequence at s (n bytes left), 0 when ill-formed (RFC 3629:
 * no overlong forms, no surrogates, nothing above U+10FFFF). */

/* A quoted string. Messages quote request text (keys, names), which may hold any byte, so
 * every byte that would not be valid JSON is rewritten rather than trusted. */
static void jsonw_quoted(struct jsonw *w, const char *str)
{
    const unsigned char *s = (const unsigned char *)str;
    size_t n = strlen(str);
    jsonw_put(w, "\"", 1);
    size_t run = 0;  /* start of the pending run of bytes copied as they are */
    for (size_t i = 0; i < n && !w->failed;) {
        unsigned char c = s[i];
        size_t len = c < 0x80 ? 1 : json_utf8_seq(s + i, n - i);
        if (c >= 0x20 && c != '"' && c != '\\' && len > 0) {
            i += len;
            continue;
        }
        jsonw_put(w, str + run, i - run);
        if (len == 0) {
            jsonw_puts(w, "\xef\xbf\xbd");  /* U+FFFD REPLACEMENT CHARACTER */
        } else if (c == '"' || c == '\\') {
            char esc[2] = {'\\', (char)c};
            jsonw_put(w, esc, 2);
        } else {
            char esc[8];
            snprintf(esc, sizeof esc, "\\u%04x", c);
            jsonw_put(w, esc, 6);
        }
        i++;
        run = i;
    }
    jsonw_put(w, str + run, n - run);
    jsonw_put(w, "\"", 1);
}

void jsonw_key(struct jsonw *w, const char *key)
{
    jsonw_sep(w);
    jsonw_quoted(w, key ? key : "");
    jsonw_put(w, ":", 1);
    if (!w->failed) w->need_comma[w->depth] = false;
}

void jsonw_string(struct jsonw *w, const char *s)
{
    if (!s) {
        jsonw_null(w);
        return;
    }
    jsonw_sep(w);
    jsonw_quoted(w, s);
    jsonw_after_value(w);
}

/* The shortest of %.15g, %.16g, %.17g that reads back as the same double (%.17g always does),
 * so 0.1 is written "0.1" and not "0.10000000000000001". */
void jsonw_double(struct jsonw *w, double v)
{
    if (!isfinite(v)) {
        jsonw_null(w);
        return;
    }
    char buf[40];
    for (int prec = 15; prec <= 17; prec++) {
        snprintf(buf, sizeof buf, "%.*g", prec, v);
        if (strtod(buf, NULL) == v) break;
    }
    /* A locale with a decimal comma would make strtod and snprintf agree on text that is not
     * JSON; the daemon runs in the C locale, this keeps the output JSON regardless. */
    for (char *c = buf; *c; c++)
        if (*c == ',') *c = '.';
    jsonw_sep(w);
    jsonw_puts(w, buf);
    jsonw_after_value(w);
}

void jsonw_uint(struct jsonw *w, uint64_t v)
{
    char buf[24];
    snprintf(buf, sizeof buf, "%llu", (unsigned long long)v);
    jsonw_sep(w);
    jsonw_puts(w, buf);
    jsonw_after_value(w);
}

void jsonw_int(struct jsonw *w, int64_t v)
{
    char buf[24];
    snprintf(buf, sizeof buf, "%lld", (long long)v);
    jsonw_sep(w);
    jsonw_puts(w, buf);
    jsonw_after_value(w);
}

void jsonw_bool(struct jsonw *w, bool v)
{
    jsonw_sep(w);
    jsonw_puts(w, v ? "true" : "false");
    jsonw_after_value(w);
}

void jsonw_null(struct jsonw *w)
{
    jsonw_sep(w);
    jsonw_puts(w, "null");
    jsonw_after_value(w);
}

char *jsonw_finish(struct jsonw *w, size_t *len)
{
    if (len) *len = 0;
    if (w->failed || w->depth != 0 || w->len == 0) {
        jsonw_destroy(w);
        return NULL;
    }
    char *text = w->buf;
    if (len) *len = w->len;
    jsonw_init(w);  /* the text now belongs to the caller */
    return text;
}

void protocol_problem_members(struct jsonw *w, const struct protocol_problem *p)
{
    /* RFC 9457 §4.2.1: "about:blank" is the type of a problem with no more specific one. */
    jsonw_key(w, "type");
    if (p->slug && p->slug[0]) {
        char type[96];
        snprintf(type, sizeof type, "urn:restird:problem:%s", p->slug);
        jsonw_string(w, type);
    } else {
        jsonw_string(w, "about:blank");
    }
    if (p->title) {
        jsonw_key(w, "title");
        jsonw_string(w, p->title);
    }
    jsonw_key(w, "status");
    jsonw_int(w, p->status);
    if (p->detail) {
        jsonw_key(w, "detail");
        jsonw_string(w, p->detail);
    }
    if (p->instance) {
        jsonw_key(w, "instance");
        jsonw_string(w, p->instance);
    }
    if (p->field) {
        jsonw_key(w, "field");
        jsonw_string(w, p->field);
    }
    if (p->has_limit) {
        jsonw_key(w, "limit");
        jsonw_double(w, p->limit);
    }
}

char *protocol_problem_json(const struct protocol_problem *p, size_t *len)
{
    if (len) *len = 0;
    if (!p) return NULL;
    struct jsonw w;
    jsonw_init(&w);
    jsonw_object_begin(&w);
    protocol_problem_members(&w, p);
    jsonw_object_end(&w);
    return jsonw_finish(&w, len);
}

/* The fixed title of each problem type (protocol/API.md lists them). */
static const struct { const char *slug, *title; } protocol_titles[] = {
    {"malformed-json", "Malformed JSON"},
    {"bad-query", "Bad query parameter"},
    {"bad-id", "Bad identifier"},
    {"bad-header", "Bad header"},
    {"unauthorized", "Unauthorized"},
    {"forbidden", "Forbidden"},
    {"not-found", "Not found"},
    {"scene-not-loaded", "Scene not loaded on this daemon"},
    {"method-not-allowed", "Method not allowed"},
    {"not-acceptable", "Not acceptable"},
    {"conflict", "Conflict"},
    {"frame-evicted", "Frame no longer kept"},
    {"length-required", "Length required"},
    {"body-too-large", "Body too large"},
    {"unsupported-media-type", "Unsupported media type"},
    {"invalid-field", "Invalid field"},
    {"limit-exceeded", "Limit exceeded"},
    {"invalid-scene", "Invalid scene"},
    {"invalid-asset", "Invalid asset"},
    {"invalid-reference", "Invalid reference image"},
    {"reference-mismatch", "Reference does not match"},
    {"too-many-sessions", "Too many sessions"},
    {"queue-full", "Queue full"},
    {"memory-budget", "Memory budget full"},
    {"insufficient-storage", "Insufficient storage"},
    {"busy", "Busy"},
    {"draining", "Shutting down"},
    {"loading", "Loading stored scenes"},
    {"internal", "Internal error"},
};

const char *protocol_problem_title(const char *slug)
{
    for (size_t i = 0; i < sizeof protocol_titles / sizeof protocol_titles[0]; i++)
        if (strcmp(protocol_titles[i].slug, slug) == 0) return protocol_titles[i].title;
    return slug;
}
