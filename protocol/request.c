/* request.c — request bodies (JSON byte ranges) -> the plain structs of protocol.h.
 * Owns the request schemas (protocol.h documents each body), the strict JSON gate that runs
 * before cJSON sees a byte, and the JSON pointers in every error. The cJSON tree never leaves
 * this file: callers get plain structs.
 * Must not: touch the network or the file system, keep state between calls, resolve names
 * against a scene (the server does), or invent a value the request did not give beyond the
 * defaults protocol.h documents.
 * Refs: RFC 8259 (JSON), RFC 3629 (UTF-8), RFC 6901 (JSON pointer); protocol/API.md. */
#include "protocol.h"

#include "input/json_read.h"

#include <cjson/cJSON.h>
#include <float.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define REQUEST_PTR 256              /* same size as err.where: longer pointers are truncated */
#define REQUEST_MAX_NUMBER_CHARS 63  /* cJSON copies a number into a 64-byte buffer */
#define REQUEST_MAX_SEED 9007199254740992.0  /* 2^53: every integer up to here is exact in a double */
#define REQUEST_DEFAULT_SIDE 256u
#define REQUEST_DEFAULT_FPS 30.0
#define REQUEST_DEFAULT_REFERENCE_SPP 1024u

/* ---- JSON pointers ---- */

/* Appends whole characters only, so a truncated pointer never ends inside an escape or a
 * UTF-8 sequence (it goes into JSON error bodies). Bytes that are not UTF-8 are copied one by
 * one; the JSON writer replaces them. */

static void request_ptr_index(char out[REQUEST_PTR], const char *base, size_t i)
{
    char idx[24];
    snprintf(idx, sizeof idx, "%zu", i);
    json_pointer_key(out, REQUEST_PTR, base, idx);
}

/* ---- ids ---- */

bool protocol_valid_id(const char *s, size_t len)
{
    if (!s || len == 0 || len > PROTOCOL_ID_MAX) return false;
    for (size_t i = 0; i < len; i++) {
        char c = s[i];
        if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' || c == '-'))
            return false;
    }
    return true;
}

/* ---- the JSON gate ---- */

/* RFC 8259 is checked here, byte by byte and without recursion, before cJSON parses: cJSON
 * recurses once per nesting level (1000 levels by default), accepts raw control characters in
 * strings and leading zeros in numbers, does not check UTF-8, turns "\u0000" into a C string
 * cut short (so "a\u0000b" would become the key "a"), and cuts numbers at 63 characters. After
 * this gate cJSON only builds the tree. */

struct request_scan {
    const unsigned char *s;
    size_t len, i;
    struct err *err;
};

static bool request_scan_fail(const struct request_scan *sc, size_t at, const char *what)
{
    unsigned line = 1, col = 1;
    for (size_t k = 0; k < at && k < sc->len; k++) {
        if (sc->s[k] == '\n') { line++; col = 1; }
        else col++;
    }
    if (at >= sc->len)
        return err_set(sc->err, ERR_PARSE, "", "JSON syntax error at byte %zu (line %u, column %u): unexpected end of input, %s",
                       at, line, col, what);
    unsigned char c = sc->s[at];
    if (c >= 0x20 && c < 0x7f)
        return err_set(sc->err, ERR_PARSE, "", "JSON syntax error at byte %zu (line %u, column %u): unexpected '%c', %s", at,
                       line, col, c, what);
    return err_set(sc->err, ERR_PARSE, "", "JSON syntax error at byte %zu (line %u, column %u): unexpected byte 0x%02x, %s",
                   at, line, col, c, what);
}

static void request_scan_ws(struct request_scan *sc)
{
    while (sc->i < sc->len) {
        unsigned char c = sc->s[sc->i];
        if (c != ' ' && c != '\t' && c != '\n' && c != '\r') break;
        sc->i++;
    }
}

static int request_hex(unsigned char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* Four hex digits at i; -1 when they are not. */
static long request_scan_u16(const struct request_scan *sc, size_t i)
{
    if (i + 4 > sc->len) return -1;
    long v = 0;
    for (size_t k = 0; k < 4; k++) {
        int h = request_hex(sc->s[i + k]);
        if (h < 0) return -1;
        v = v * 16 + h;
    }
    return v;
}

static bool request_scan_string(struct request_scan *sc)
{
    sc->i++;  /* the opening quote */
    while (sc->i < sc->len) {
        unsigned char c = sc->s[sc->i];
        if (c == '"') { sc->i++; return true; }
        if (c < 0x20) return request_scan_fail(sc, sc->i, "control characters in a string must be escaped");
        if (c >= 0x80) {
            size_t n = json_utf8_seq(sc->s + sc->i, sc->len - sc->i);
            if (!n) return request_scan_fail(sc, sc->i, "strings must be UTF-8");
            sc->i += n;
            continue;
        }
        if (c != '\\') { sc->i++; continue; }
        size_t at = sc->i;
        if (at + 1 >= sc->len) { sc->i = sc->len; break; }
        unsigned char e = sc->s[at + 1];
        if (e != 'u') {
            if (!strchr("\"\\/bfnrt", e) || e == '\0')
                return request_scan_fail(sc, at + 1, "expected an escape (\\\" \\\\ \\/ \\b \\f \\n \\r \\t \\uXXXX)");
            sc->i += 2;
            continue;
        }
        long u = request_scan_u16(sc, at + 2);
        if (u < 0) return request_scan_fail(sc, at + 2 < sc->len ? at + 2 : sc->len, "expected 4 hex digits after \\u");
        if (u == 0) {
            /* Well-formed JSON, but a C string cannot hold it: refused rather than cut short. */
            unsigned line = 1, col = 1;
            for (size_t k = 0; k < at; k++) {
                if (sc->s[k] == '\n') { line++; col = 1; }
                else col++;
            }
            return err_set(sc->err, ERR_INVALID, "", "\\u0000 in a string at byte %zu (line %u, column %u) is not allowed",
                           at, line, col);
        }
        if (u >= 0xdc00 && u <= 0xdfff)
            return request_scan_fail(sc, at, "a low surrogate \\uDC00-\\uDFFF without a high one before it");
        if (u >= 0xd800 && u <= 0xdbff) {
            long lo = at + 7 < sc->len && sc->s[at + 6] == '\\' && sc->s[at + 7] == 'u' ? request_scan_u16(sc, at + 8) : -1;
            if (!(lo >= 0xdc00 && lo <= 0xdfff))
                return request_scan_fail(sc, at, "a high surrogate \\uD800-\\uDBFF must be followed by a low one");
            sc->i += 12;
        } else {
            sc->i += 6;
        }
    }
    return request_scan_fail(sc, sc->len, "expected '\"' closing the string");
}

static bool request_scan_digits(struct request_scan *sc, const char *what)
{
    if (sc->i >= sc->len || sc->s[sc->i] < '0' || sc->s[sc->i] > '9') return request_scan_fail(sc, sc->i, what);
    while (sc->i < sc->len && sc->s[sc->i] >= '0' && sc->s[sc->i] <= '9') sc->i++;
    return true;
}

static bool request_scan_number(struct request_scan *sc)
{
    size_t start = sc->i;
    if (sc->s[sc->i] == '-') sc->i++;
    if (sc->i < sc->len && sc->s[sc->i] == '0') {
        sc->i++;
        if (sc->i < sc->len && sc->s[sc->i] >= '0' && sc->s[sc->i] <= '9')
            return request_scan_fail(sc, sc->i, "numbers have no leading zeros");
    } else if (!request_scan_digits(sc, "expected a digit")) {
        return false;
    }
    if (sc->i < sc->len && sc->s[sc->i] == '.') {
        sc->i++;
        if (!request_scan_digits(sc, "expected a digit after '.'")) return false;
    }
    if (sc->i < sc->len && (sc->s[sc->i] == 'e' || sc->s[sc->i] == 'E')) {
        sc->i++;
        if (sc->i < sc->len && (sc->s[sc->i] == '+' || sc->s[sc->i] == '-')) sc->i++;
        if (!request_scan_digits(sc, "expected a digit in the exponent")) return false;
    }
    if (sc->i - start > REQUEST_MAX_NUMBER_CHARS)
        return err_set(sc->err, ERR_PARSE, "", "JSON number at byte %zu has %zu characters, more than the limit of %d",
                       start, sc->i - start, REQUEST_MAX_NUMBER_CHARS);
    return true;
}

static bool request_scan_literal(struct request_scan *sc, const char *word)
{
    size_t n = strlen(word);
    for (size_t k = 0; k < n; k++)
        if (sc->i + k >= sc->len || sc->s[sc->i + k] != (unsigned char)word[k])
            return request_scan_fail(sc, sc->i + k, "expected a value (object, array, string, number, true, false or null)");
    sc->i += n;
    return true;
}

/* The whole text is one JSON value, nested at most PROTOCOL_MAX_DEPTH deep. */
static bool request_scan_all(const char *text, size_t len, struct err *err)
{
    struct request_scan sc = {(const unsigned char *)text, len, 0, err};
    char stack[PROTOCOL_MAX_DEPTH];  /* '{' or '[' per open container */
    int depth = 0;
    enum { VALUE, AFTER_VALUE, KEY } want = VALUE;

    request_scan_ws(&sc);
    for (;;) {
        if (want == KEY) {
            /* After '{' or ',' in an object: a key, ':', then a value. */
            if (sc.i >= len || sc.s[sc.i] != '"') return request_scan_fail(&sc, sc.i, "expected '\"' starting a key");
            if (!request_scan_string(&sc)) return false;
            request_scan_ws(&sc);
            if (sc.i >= len || sc.s[sc.i] != ':') return request_scan_fail(&sc, sc.i, "expected ':' after a key");
            sc.i++;
            request_scan_ws(&sc);
            want = VALUE;
            continue;
        }
        if (want == VALUE) {
            if (sc.i >= len) return request_scan_fail(&sc, sc.i, "expected a value");
            unsigned char c = sc.s[sc.i];
            if (c == '{' || c == '[') {
                if (depth == PROTOCOL_MAX_DEPTH)
                    return err_set(err, ERR_PARSE, "", "JSON nested deeper than %d levels at byte %zu", PROTOCOL_MAX_DEPTH, sc.i);
                stack[depth++] = (char)c;
                sc.i++;
                request_scan_ws(&sc);
                if (sc.i < len && sc.s[sc.i] == (c == '{' ? '}' : ']')) {
                    sc.i++;
                    depth--;
                    want = AFTER_VALUE;
                } else {
                    want = c == '{' ? KEY : VALUE;
                }
                continue;
            }
            bool ok;
            if (c == '"') ok = request_scan_string(&sc);
            else if (c == '-' || (c >= '0' && c <= '9')) ok = request_scan_number(&sc);
            else if (c == 't') ok = request_scan_literal(&sc, "true");
            else if (c == 'f') ok = request_scan_literal(&sc, "false");
            else if (c == 'n') ok = request_scan_literal(&sc, "null");
            else ok = request_scan_fail(&sc, sc.i, "expected a value (object, array, string, number, true, false or null)");
            if (!ok) return false;
            want = AFTER_VALUE;
            continue;
        }
        /* AFTER_VALUE */
        request_scan_ws(&sc);
        if (depth == 0) {
            if (sc.i < len) return request_scan_fail(&sc, sc.i, "expected the end of input after the JSON value");
            return true;
        }
        char open = stack[depth - 1];
        if (sc.i < len && sc.s[sc.i] == ',') {
            sc.i++;
            request_scan_ws(&sc);
            want = open == '{' ? KEY : VALUE;
        } else if (sc.i < len && sc.s[sc.i] == (open == '{' ? '}' : ']')) {
            sc.i++;
            depth--;
        } else {
            return request_scan_fail(&sc, sc.i, open == '{' ? "expected ',' or '}'" : "expected ',' or ']'");
        }
    }
}

bool protocol_check_json(const char *text, size_t len, struct err *err)
{
    return request_scan_all(text, len, err);
}

/* Parses one JSON value (any type) past the gate into *root. */
static bool request_parse_value(const char *text, size_t len, cJSON **root, struct err *err)
{
    *root = NULL;
    if (!text && len) return err_set(err, ERR_INVALID, "", "no body text");
    if (!request_scan_all(text, len, err)) return false;
    const char *end = NULL;
    *root = cJSON_ParseWithLengthOpts(text, len, &end, false);
    /* The gate accepted the text, so a failure here is cJSON running out of memory. */
    return *root ? true : err_set(err, ERR_NOMEM, "", "out of memory parsing the body");
}

/* Parses a request body into *root (an object). An empty body is {} (every request's members
 * are optional or reported missing by name). */
static bool request_parse(const char *body, size_t len, cJSON **root, struct err *err)
{
    *root = NULL;
    if (len == 0) {
        *root = cJSON_CreateObject();
        return *root ? true : err_set(err, ERR_NOMEM, "", "out of memory parsing the body");
    }
    if (!request_parse_value(body, len, root, err)) return false;
    if (!cJSON_IsObject(*root)) {
        const char *what = cJSON_IsArray(*root) ? "an array" : cJSON_IsString(*root) ? "a string"
                         : cJSON_IsNumber(*root) ? "a number" : cJSON_IsBool(*root) ? "a boolean" : "null";
        cJSON_Delete(*root);
        *root = NULL;
        return err_set(err, ERR_INVALID, "", "expected the body to be a JSON object, got %s", what);
    }
    return true;
}

/* ---- typed, strict accessors ---- */


/* Every key of `obj` must be in the NULL-terminated `allowed` list (at most 32), at most once.
 * The first offending key in document order is reported, by its pointer. */

/* Members of a name-keyed object (shape names): each a valid id, each once. O(n^2) in the
 * member count, which the caller bounds first. */
static bool request_check_names(const cJSON *obj, const char *ptr, struct err *err)
{
    char p[REQUEST_PTR];
    for (const cJSON *c = obj->child; c; c = c->next) {
        json_pointer_key(p, sizeof p, ptr, c->string);
        if (!protocol_valid_id(c->string, strlen(c->string)))
            return err_set(err, ERR_INVALID, p, "invalid name \"%.64s\": names must match [A-Za-z0-9_-]{1,%d}", c->string,
                           PROTOCOL_ID_MAX);
        for (const cJSON *d = obj->child; d != c; d = d->next)
            if (strcmp(d->string, c->string) == 0) return err_set(err, ERR_INVALID, p, "duplicate key \"%s\"", c->string);
    }
    return true;
}


/* The member `key` of obj and its pointer; NULL when absent. */
static const cJSON *request_member(const cJSON *obj, const char *ptr, const char *key, char p[REQUEST_PTR])
{
    json_pointer_key(p, REQUEST_PTR, ptr, key);
    return cJSON_GetObjectItemCaseSensitive(obj, key);
}

/* A finite number. cJSON turns 1e999 into inf, which is refused here. */
static bool request_double(const cJSON *v, const char *ptr, double *out, struct err *err)
{
    if (!cJSON_IsNumber(v)) return err_set(err, ERR_INVALID, ptr, "expected a number, got %s", json_type_name(v));
    if (!isfinite(v->valuedouble))
        return err_set(err, ERR_INVALID, ptr, "expected a finite number (the value overflows to infinity)");
    *out = v->valuedouble;
    return true;
}

/* A finite number that is also finite as a 32-bit float (the renderer's precision). */
static bool request_float(const cJSON *v, const char *ptr, float *out, struct err *err)
{
    double d = 0.0;
    if (!request_double(v, ptr, &d, err)) return false;
    if (fabs(d) > (double)FLT_MAX)
        return err_set(err, ERR_INVALID, ptr, "%g is not finite as a 32-bit float (|x| <= 3.4e38)", d);
    *out = (float)d;
    return true;
}

/* An integer in [lo, hi], checked as a double (never cJSON's saturating valueint). Above hi is
 * ERR_LIMIT naming `limit_name` when the bound is a configured limit, ERR_INVALID otherwise. */
static bool request_integer(const cJSON *v, const char *ptr, double lo, double hi, const char *limit_name, double *out,
                            struct err *err)
{
    double d = 0.0;
    if (!request_double(v, ptr, &d, err)) return false;
    if (d != floor(d)) return err_set(err, ERR_INVALID, ptr, "expected an integer, got %.17g", d);
    if (d < lo) return err_set(err, ERR_INVALID, ptr, "must be >= %.17g, got %.17g", lo, d);
    if (!limit_name && d > hi) return err_set(err, ERR_INVALID, ptr, "must be <= %.17g, got %.17g", hi, d);
    if (d > hi) return err_set(err, ERR_LIMIT, ptr, "%.17g is over the limit %s = %.17g", d, limit_name, hi);
    *out = d;
    return true;
}

static bool request_uint32(const cJSON *v, const char *ptr, uint32_t lo, uint32_t hi, const char *limit_name,
                           uint32_t *out, struct err *err)
{
    double d = 0.0;
    if (!request_integer(v, ptr, lo, hi, limit_name, &d, err)) return false;
    *out = (uint32_t)d;
    return true;
}



/* An id member copied into out[PROTOCOL_ID_MAX + 1]. */
static bool request_id(const cJSON *v, const char *ptr, char *out, struct err *err)
{
    const char *s = json_string(v, ptr, err);
    if (!s) return false;
    size_t n = strlen(s);
    if (!protocol_valid_id(s, n))
        return err_set(err, ERR_INVALID, ptr, "invalid id \"%.64s\": ids must match [A-Za-z0-9_-]{1,%d}", s, PROTOCOL_ID_MAX);
    memcpy(out, s, n + 1);
    return true;
}

enum request_range { RANGE_ANY, RANGE_NONNEG };

/* Exactly 3 finite numbers; with RANGE_NONNEG each >= 0 (reported at its element). */
static bool request_vec3(const cJSON *v, const char *ptr, enum request_range r, struct vec3 *out, struct err *err)
{
    if (!cJSON_IsArray(v))
        return err_set(err, ERR_INVALID, ptr, "expected an array of 3 numbers, got %s", json_type_name(v));
    int n = cJSON_GetArraySize(v);
    if (n != 3) return err_set(err, ERR_INVALID, ptr, "expected an array of 3 numbers, got %d elements", n);
    float f[3];
    char p[REQUEST_PTR];
    int i = 0;
    for (const cJSON *c = v->child; c; c = c->next, i++) {
        request_ptr_index(p, ptr, (size_t)i);
        if (!request_float(c, p, &f[i], err)) return false;
        if (r == RANGE_NONNEG && !(f[i] >= 0.0f)) return err_set(err, ERR_INVALID, p, "must be >= 0, got %g", (double)f[i]);
    }
    *out = vec3_make(f[0], f[1], f[2]);
    return true;
}

static bool request_key_vec3(const cJSON *obj, const char *ptr, const char *key, enum request_range r, bool *has,
                             struct vec3 *out, struct err *err)
{
    char p[REQUEST_PTR];
    const cJSON *v = request_member(obj, ptr, key, p);
    if (!v) return true;
    *has = true;
    return request_vec3(v, p, r, out, err);
}

/* ---- parts shared by the requests ---- */

/* {"translate": [3], "rotate_deg": [3], "scale": number or [3]} as in docs/scene-format.md
 * "Transform": absent parts are the identity's, every scale factor > 0 (mirroring would flip
 * the front face of instanced geometry), and the composed matrix must stay in float range. */
static bool request_trs(const cJSON *t, const char *ptr, struct trs *out, struct err *err)
{
    static const char *const keys[] = {"translate", "rotate_deg", "scale", NULL};
    bool has_t = false, has_r = false;
    char p[REQUEST_PTR], q[REQUEST_PTR];

    *out = trs_identity();
    if (!json_object(t, ptr, "a transform", err) || !json_check_keys(t, ptr, keys, " in a transform", err) ||
        !request_key_vec3(t, ptr, "translate", RANGE_ANY, &has_t, &out->translate, err) ||
        !request_key_vec3(t, ptr, "rotate_deg", RANGE_ANY, &has_r, &out->rotate_deg, err))
        return false;
    const cJSON *sv = request_member(t, ptr, "scale", p);
    if (sv) {
        bool array = cJSON_IsArray(sv);
        if (cJSON_IsNumber(sv)) {
            float s = 0.0f;
            if (!request_float(sv, p, &s, err)) return false;
            out->scale = vec3_splat(s);
        } else if (array) {
            if (!request_vec3(sv, p, RANGE_ANY, &out->scale, err)) return false;
        } else {
            return err_set(err, ERR_INVALID, p, "expected a number or an array of 3 numbers, got %s", json_type_name(sv));
        }
        for (int i = 0; i < 3; i++) {
            float s = vec3_comp(out->scale, i);
            const char *where = p;
            if (array) {
                request_ptr_index(q, p, (size_t)i);
                where = q;
            }
            if (s == 0.0f) return err_set(err, ERR_INVALID, where, "scale must be > 0, got 0 (a zero scale is singular)");
            if (s < 0.0f)
                return err_set(err, ERR_INVALID, where, "negative scale (mirroring) is not supported, got %g", (double)s);
        }
    }
    struct xform x;
    if (!xform_from_trs(out, &x)) return err_set(err, ERR_INVALID, ptr, "the transform overflows the 32-bit float range");
    return true;
}

/* The members of a partial camera present in obj (the caller has checked the keys). up must
 * be non-zero; position and look_at, when both are given here, must differ; when position,
 * look_at and up are all given, up must not be parallel to the view direction. Members the
 * request leaves out are completed by the server, which checks the completed camera. */
static bool request_camera(const cJSON *obj, const char *ptr, struct protocol_camera *out, struct err *err)
{
    char p[REQUEST_PTR];
    memset(out, 0, sizeof *out);
    if (!request_key_vec3(obj, ptr, "position", RANGE_ANY, &out->has_position, &out->position, err) ||
        !request_key_vec3(obj, ptr, "look_at", RANGE_ANY, &out->has_look_at, &out->look_at, err) ||
        !request_key_vec3(obj, ptr, "up", RANGE_ANY, &out->has_up, &out->up, err))
        return false;
    const cJSON *fv = request_member(obj, ptr, "fov_deg", p);
    if (fv) {
        if (!request_float(fv, p, &out->fov_deg, err)) return false;
        if (!(out->fov_deg > 0.0f && out->fov_deg < 180.0f))
            return err_set(err, ERR_INVALID, p, "must be in (0, 180) degrees, got %g", (double)out->fov_deg);
        out->has_fov_deg = true;
    }
    if (out->has_up && vec3_is_zero(out->up)) {
        json_pointer_key(p, sizeof p, ptr, "up");
        return err_set(err, ERR_INVALID, p, "up must be non-zero");
    }
    if (out->has_position && out->has_look_at) {
        struct vec3 dir = vec3_sub(out->look_at, out->position);
        if (!vec3_is_finite(dir) || vec3_is_zero(dir)) {
            json_pointer_key(p, sizeof p, ptr, "look_at");
            return err_set(err, ERR_INVALID, p, "look_at must differ from position (and the difference be finite)");
        }
        if (out->has_up) {
            /* Same test as the scene loader: |dir x up| against |dir| |up|, in double. */
            const struct vec3 u = out->up;
            double cx = (double)dir.y * u.z - (double)dir.z * u.y;
            double cy = (double)dir.z * u.x - (double)dir.x * u.z;
            double cz = (double)dir.x * u.y - (double)dir.y * u.x;
            double lens = sqrt(((double)dir.x * dir.x + (double)dir.y * dir.y + (double)dir.z * dir.z) *
                               ((double)u.x * u.x + (double)u.y * u.y + (double)u.z * u.z));
            if (!(sqrt(cx * cx + cy * cy + cz * cz) > 1e-6 * lens)) {
                json_pointer_key(p, sizeof p, ptr, "up");
                return err_set(err, ERR_INVALID, p, "up must not be parallel to the view direction");
            }
        }
    }
    return true;
}

/* Channels of a shape change or shape key: position | transform, emission. The caller has
 * checked the keys. At least one channel, never both position and transform (position replaces
 * the translation of a transform the other would replace whole). Reported at ptr. */
static bool request_shape_channels(const cJSON *obj, const char *ptr, struct animation_shape_state *out,
                                   struct err *err)
{
    char p[REQUEST_PTR];
    memset(out, 0, sizeof *out);
    const cJSON *pos = cJSON_GetObjectItemCaseSensitive(obj, "position");
    const cJSON *tr = cJSON_GetObjectItemCaseSensitive(obj, "transform");
    const cJSON *em = cJSON_GetObjectItemCaseSensitive(obj, "emission");
    if (pos && tr)
        return err_set(err, ERR_INVALID, ptr, "set either position or transform, not both (position replaces the "
                                              "translation of the transform)");
    if (!pos && !tr && !em) return err_set(err, ERR_INVALID, ptr, "no channel: set position, transform or emission");
    if (!request_key_vec3(obj, ptr, "position", RANGE_ANY, &out->has_position, &out->position, err)) return false;
    if (tr) {
        json_pointer_key(p, sizeof p, ptr, "transform");
        if (!request_trs(tr, p, &out->transform, err)) return false;
        out->has_transform = true;
    }
    return request_key_vec3(obj, ptr, "emission", RANGE_NONNEG, &out->has_emission, &out->emission, err);
}

/* A key time: finite, >= 0, after the previous key's (prev < 0: first key). */
static bool request_key_time(const cJSON *key, const char *ptr, double prev, double *t, struct err *err)
{
    char p[REQUEST_PTR];
    const cJSON *tv = request_member(key, ptr, "t", p);
    if (!tv) return err_set(err, ERR_INVALID, p, "missing required key");
    if (!request_double(tv, p, t, err)) return false;
    if (*t < 0.0) return err_set(err, ERR_INVALID, p, "must be >= 0, got %.17g", *t);
    if (prev >= 0.0 && !(*t > prev))
        return err_set(err, ERR_INVALID, p, "key times must be strictly increasing: %.17g is not after the previous key's %.17g",
                       *t, prev);
    return true;
}

/* ---- session create ---- */

/* A string naming one of `choices` (NULL-terminated): its index, else an error at p that
 * lists them ("unknown <what> "x" (a, b or c)"). */
static bool request_choice(const cJSON *v, const char *p, const char *what, const char *const *choices, int *out,
                           struct err *err)
{
    const char *name = json_string(v, p, err);
    if (!name) return false;
    int found = -1;
    char list[160];
    size_t n = 0;
    list[0] = '\0';
    for (int k = 0; choices[k]; k++) {
        if (strcmp(name, choices[k]) == 0) found = k;
        const char *sep = k == 0 ? "" : choices[k + 1] ? ", " : " or ";
        if (n < sizeof list) n += (size_t)snprintf(list + n, sizeof list - n, "%s%s", sep, choices[k]);
    }
    if (found < 0) return err_set(err, ERR_INVALID, p, "unknown %s \"%.64s\" (%s)", what, name, list);
    *out = found;
    return true;
}

/* A method's "params" object, read through its descriptor's parameter table (method.h): every
 * key must be one of the table's, each value of the key's kind and within its range (spp within
 * max_spp too); then the method's own validation checks what the table cannot (its pointers name
 * /params/<key>). */
static bool request_method_params(const cJSON *pv, const char *ptr, const struct method_desc *m,
                                  const struct protocol_limits *limits, void *params, uint32_t *given,
                                  struct err *err)
{
    char context[64];
    snprintf(context, sizeof context, " in %s params", m->name);
    const char *keys[m->param_count + 1];
    for (uint32_t i = 0; i < m->param_count; i++) keys[i] = m->params[i].key;
    keys[m->param_count] = NULL;
    if (!json_object(pv, ptr, "a params", err) || !json_check_keys(pv, ptr, keys, context, err)) return false;
    char p[REQUEST_PTR];
    for (uint32_t i = 0; i < m->param_count; i++) {
        const struct method_param *mp = &m->params[i];
        const cJSON *v = request_member(pv, ptr, mp->key, p);
        if (!v) continue;
        *given |= 1u << i;
        unsigned char *at = (unsigned char *)params + mp->offset;
        switch (mp->kind) {
        case METHOD_PARAM_UINT: {
            bool spp = mp->flags & METHOD_PARAM_SPP_LIMIT;
            double hi = spp && limits->max_spp < mp->max ? limits->max_spp : mp->max;
            uint32_t u = 0;
            if (!request_uint32(v, p, (uint32_t)mp->min, (uint32_t)hi, spp ? "max_spp" : NULL, &u, err)) return false;
            memcpy(at, &u, sizeof u);
            break;
        }
        case METHOD_PARAM_BOOL: {
            bool b = false;
            if (!json_bool(v, p, &b, err)) return false;
            memcpy(at, &b, sizeof b);
            break;
        }
        case METHOD_PARAM_FLOAT: {
            float x;
            if (!request_float(v, p, &x, err)) return false;
            bool low = mp->min_open ? !(x > mp->min) : !(x >= mp->min);
            bool high = mp->max_open ? !(x < mp->max) : !(x <= mp->max);
            if (low || high)
                return err_set(err, ERR_INVALID, p, "%s must be in %c%g, %g%c, got %g", mp->key,
                               mp->min_open ? '(' : '[', mp->min, mp->max, mp->max_open ? ')' : ']', (double)x);
            memcpy(at, &x, sizeof x);
            break;
        }
        case METHOD_PARAM_ENUM: {
            int found = 0;
            if (!request_choice(v, p, mp->key, mp->choices, &found, err)) return false;
            memcpy(at, &found, sizeof found);
            break;
        }
        }
    }
    return m->validate(params, err);
}

/* A default within a parameter's range may still be over a configured limit. */
static bool request_defaults_within_limits(const struct view_params *vp, const struct protocol_limits *limits,
                                           struct err *err)
{
    const struct method_desc *method = vp->method;
    for (uint32_t i = 0; i < method->param_count; i++) {
        const struct method_param *mp = &method->params[i];
        uint32_t value;
        if (!(mp->flags & METHOD_PARAM_SPP_LIMIT)) continue;
        memcpy(&value, vp->method_params + mp->offset, sizeof value);
        if (value > limits->max_spp) {
            char at[REQUEST_PTR];
            json_pointer_key(at, sizeof at, "/params", mp->key);
            return err_set(err, ERR_LIMIT, at, "the default %s %u is over the limit max_spp = %u (send params.%s)",
                           mp->key, value, limits->max_spp, mp->key);
        }
    }
    return true;
}

/* A side: given (1..max_side) or the default, which must be within the limit too. */
static bool request_side(const cJSON *root, const char *key, const struct protocol_limits *limits, uint32_t *out,
                         struct err *err)
{
    char p[REQUEST_PTR];
    const cJSON *v = request_member(root, "", key, p);
    *out = REQUEST_DEFAULT_SIDE;
    if (v) return request_uint32(v, p, 1, limits->max_side, "max_side", out, err);
    if (*out > limits->max_side)
        return err_set(err, ERR_LIMIT, p, "the default %s %u is over the limit max_side = %u (send %s)", key, *out,
                       limits->max_side, key);
    return true;
}

bool protocol_parse_session_create(const char *body, size_t len, const struct protocol_limits *limits,
                                   struct view_params *out, struct err *err)
{
    static const char *const keys[] = {"method", "width", "height", "seed", "profile", "params", NULL};
    if (!out || !limits) return err_set(err, ERR_INVALID, "", "no output or limits given");
    cJSON *root;
    if (!request_parse(body, len, &root, err)) return false;

    bool ok = json_check_keys(root, "", keys, " at the top level", err);
    const struct method_desc *method = method_default();
    char p[REQUEST_PTR];
    const cJSON *mv = request_member(root, "", "method", p);
    if (ok && mv) {
        const char *name = json_string(mv, p, err);
        ok = name != NULL;
        if (ok && !(method = method_find(name))) {
            char known[256];
            method_names(known, sizeof known, ", ");
            ok = err_set(err, ERR_INVALID, p, "unknown method \"%.64s\" (known methods: %s)", name, known);
        }
    }
    uint32_t w = 0, h = 0;
    ok = ok && request_side(root, "width", limits, &w, err) && request_side(root, "height", limits, &h, err);
    /* The pixel count belongs to neither side alone, so it is reported on the whole body. */
    if (ok && (uint64_t)w * h > limits->max_pixels)
        ok = err_set(err, ERR_LIMIT, "", "%ux%u is %llu pixels, over the limit max_pixels = %llu", w, h,
                     (unsigned long long)w * h, (unsigned long long)limits->max_pixels);
    /* An unknown method has failed above (ok is false) and has no defaults. */
    struct view_params vp = view_params_defaults(method ? method : method_default(), w, h);
    /* The profile chooses the defaults that the params below are read over: a parameter the
     * user sends wins over the profile's value. */
    const cJSON *fv = request_member(root, "", "profile", p);
    int profile = METHOD_PROFILE_REAL_TIME;
    if (ok && fv) ok = request_choice(fv, p, "profile", method_profile_names, &profile, err);
    if (ok) view_params_set_profile(&vp, (enum method_profile)profile);
    const cJSON *sv = request_member(root, "", "seed", p);
    if (ok && sv) {
        double seed = 0.0;
        ok = request_integer(sv, p, 0.0, REQUEST_MAX_SEED, NULL, &seed, err);
        vp.seed = ok ? (uint64_t)seed : 0;
    }
    const cJSON *pv = request_member(root, "", "params", p);
    uint32_t given = 0;
    if (ok && pv) ok = request_method_params(pv, p, method, limits, vp.method_params, &given, err);
    ok = ok && request_defaults_within_limits(&vp, limits, err);
    cJSON_Delete(root);
    if (ok) *out = vp;
    return ok;
}

bool protocol_parse_method_params(const char *text, size_t len, const struct protocol_limits *limits,
                                  struct view_params *vp, uint32_t *given, struct err *err)
{
    if (!vp || !vp->method || !limits || !given) return err_set(err, ERR_INVALID, "", "no parameters or limits given");
    cJSON *root;
    if (!request_parse_value(text, len, &root, err)) return false;
    struct view_params parsed = *vp;
    uint32_t set = 0;
    bool ok = request_method_params(root, "/params", vp->method, limits, parsed.method_params, &set, err) &&
              request_defaults_within_limits(&parsed, limits, err);
    cJSON_Delete(root);
    if (ok) *vp = parsed, *given = set;
    return ok;
}

/* ---- frame request ---- */

bool protocol_parse_frame_request(const char *body, size_t len, struct protocol_frame_request *out, struct err *err)
{
    static const char *const keys[] = {"camera", "lights", "time_s", NULL};
    static const char *const camera_keys[] = {"position", "look_at", "up", "fov_deg", NULL};
    static const char *const shape_keys[] = {"position", "transform", "emission", NULL};
    if (!out) return err_set(err, ERR_INVALID, "", "no output given");
    memset(out, 0, sizeof *out);
    cJSON *root;
    if (!request_parse(body, len, &root, err)) return false;

    char p[REQUEST_PTR];
    bool ok = json_check_keys(root, "", keys, " at the top level", err);
    const cJSON *cv = request_member(root, "", "camera", p);
    if (ok && cv)
        ok = json_object(cv, p, "a camera", err) && json_check_keys(cv, p, camera_keys, " in the camera", err) &&
             request_camera(cv, p, &out->camera, err);

    const cJSON *lv = request_member(root, "", "lights", p);
    if (ok && lv) {
        ok = json_object(lv, p, "a lights", err);
        int n = ok ? cJSON_GetArraySize(lv) : 0;
        if (ok && n > PROTOCOL_MAX_SHAPE_CHANGES)
            ok = err_set(err, ERR_LIMIT, p, "%d shape changes, over the limit of %d per frame", n, PROTOCOL_MAX_SHAPE_CHANGES);
        ok = ok && request_check_names(lv, p, err);
        char q[REQUEST_PTR];
        for (const cJSON *c = ok ? lv->child : NULL; c && ok; c = c->next) {
            struct protocol_shape_change *sc = &out->shapes[out->shape_count];
            struct animation_shape_state st;
            json_pointer_key(q, sizeof q, p, c->string);
            ok = json_object(c, q, "a shape change", err) && json_check_keys(c, q, shape_keys, " in a shape change", err) &&
                 request_shape_channels(c, q, &st, err);
            if (!ok) break;
            snprintf(sc->name, sizeof sc->name, "%s", c->string);
            sc->state = st;
            out->shape_count++;
        }
    }

    const cJSON *tv = request_member(root, "", "time_s", p);
    if (ok && tv) {
        ok = request_double(tv, p, &out->time_s, err);
        if (ok && out->time_s < 0.0) ok = err_set(err, ERR_INVALID, p, "must be >= 0, got %.17g", out->time_s);
        out->has_time = ok;
    }
    cJSON_Delete(root);
    if (!ok) memset(out, 0, sizeof *out);
    return ok;
}

/* ---- render request ---- */

void protocol_render_request_destroy(struct protocol_render_request *req)
{
    if (!req) return;
    free(req->camera_keys);
    for (uint32_t i = 0; req->shape_tracks && i < req->shape_track_count; i++) free(req->shape_tracks[i].keys);
    free(req->shape_tracks);
    req->camera_keys = NULL;
    req->camera_key_count = 0;
    req->shape_tracks = NULL;
    req->shape_track_count = 0;
}

/* The number of elements of an array or members of an object, against a limit. */
static bool request_count(const cJSON *v, const char *ptr, uint32_t limit, const char *limit_name, const char *what,
                          uint32_t *n, struct err *err)
{
    int k = cJSON_GetArraySize(v);
    if (k < 0 || (uint32_t)k > limit)
        return err_set(err, ERR_LIMIT, ptr, "%d %s, over the limit %s = %u", k, what, limit_name, limit);
    *n = (uint32_t)k;
    return true;
}

static bool request_camera_keys(const cJSON *v, const char *ptr, const struct protocol_limits *limits,
                                struct protocol_render_request *out, struct err *err)
{
    static const char *const keys[] = {"t", "position", "look_at", "up", "fov_deg", NULL};
    uint32_t n = 0;
    if (!cJSON_IsArray(v)) return err_set(err, ERR_INVALID, ptr, "expected an array of camera keys, got %s", json_type_name(v));
    if (!request_count(v, ptr, limits->max_keys, "max_keys", "camera keys", &n, err)) return false;
    if (n == 0) return true;
    out->camera_keys = calloc(n, sizeof *out->camera_keys);
    if (!out->camera_keys) return err_set(err, ERR_NOMEM, ptr, "out of memory");
    char p[REQUEST_PTR];
    double prev = -1.0;
    for (const cJSON *k = v->child; k; k = k->next) {
        struct protocol_camera_key *ck = &out->camera_keys[out->camera_key_count];
        request_ptr_index(p, ptr, out->camera_key_count);
        if (!json_object(k, p, "a camera key", err) || !json_check_keys(k, p, keys, " in a camera key", err) ||
            !request_key_time(k, p, prev, &ck->t_s, err) || !request_camera(k, p, &ck->camera, err))
            return false;
        const struct protocol_camera *c = &ck->camera;
        if (!c->has_position && !c->has_look_at && !c->has_up && !c->has_fov_deg)
            return err_set(err, ERR_INVALID, p, "no channel: set position, look_at, up or fov_deg");
        prev = ck->t_s;
        out->camera_key_count++;
    }
    return true;
}

static bool request_shape_track(const cJSON *v, const char *ptr, const struct protocol_limits *limits,
                                struct protocol_shape_track *track, struct err *err)
{
    static const char *const keys[] = {"t", "position", "transform", "emission", NULL};
    uint32_t n = 0;
    if (!cJSON_IsArray(v)) return err_set(err, ERR_INVALID, ptr, "expected an array of shape keys, got %s", json_type_name(v));
    if (!request_count(v, ptr, limits->max_keys, "max_keys", "keys", &n, err)) return false;
    if (n == 0) return err_set(err, ERR_INVALID, ptr, "a shape track needs at least one key");
    track->keys = calloc(n, sizeof *track->keys);
    if (!track->keys) return err_set(err, ERR_NOMEM, ptr, "out of memory");
    char p[REQUEST_PTR];
    double prev = -1.0;
    for (const cJSON *k = v->child; k; k = k->next) {
        struct animation_shape_key *sk = &track->keys[track->key_count];
        struct animation_shape_state st;
        request_ptr_index(p, ptr, track->key_count);
        if (!json_object(k, p, "a shape key", err) || !json_check_keys(k, p, keys, " in a shape key", err) ||
            !request_key_time(k, p, prev, &sk->t_s, err) || !request_shape_channels(k, p, &st, err))
            return false;
        sk->has_position = st.has_position;
        sk->has_transform = st.has_transform;
        sk->has_emission = st.has_emission;
        sk->position = st.position;
        sk->transform = st.transform;
        sk->emission = st.emission;
        prev = sk->t_s;
        track->key_count++;
    }
    return true;
}

static bool request_animation(const cJSON *a, const char *ptr, const struct protocol_limits *limits,
                              struct protocol_render_request *out, struct err *err)
{
    static const char *const keys[] = {"fps", "frames", "interpolation", "camera_keys", "light_keys", NULL};
    char p[REQUEST_PTR];
    const cJSON *v;
    if (!json_object(a, ptr, "an animation", err) || !json_check_keys(a, ptr, keys, " in the animation", err))
        return false;
    if ((v = request_member(a, ptr, "fps", p))) {
        if (!request_double(v, p, &out->fps, err)) return false;
        if (!(out->fps > 0.0)) return err_set(err, ERR_INVALID, p, "must be > 0, got %.17g", out->fps);
    }
    v = request_member(a, ptr, "frames", p);
    if (!v) return err_set(err, ERR_INVALID, p, "missing required key");
    if (!request_uint32(v, p, 1, limits->max_frames, "max_frames", &out->frames, err)) return false;
    if ((v = request_member(a, ptr, "interpolation", p))) {
        const char *s = json_string(v, p, err);
        if (!s) return false;
        if (strcmp(s, "linear") == 0) out->interp = ANIMATION_LINEAR;
        else if (strcmp(s, "catmull_rom") == 0) out->interp = ANIMATION_CATMULL_ROM;
        else return err_set(err, ERR_INVALID, p, "unknown interpolation \"%.64s\" (expected linear or catmull_rom)", s);
    }
    if ((v = request_member(a, ptr, "camera_keys", p)) && !request_camera_keys(v, p, limits, out, err)) return false;
    if ((v = request_member(a, ptr, "light_keys", p))) {
        uint32_t n = 0;
        if (!json_object(v, p, "a light_keys", err) ||
            !request_count(v, p, PROTOCOL_MAX_SHAPE_CHANGES, "PROTOCOL_MAX_SHAPE_CHANGES", "shape tracks", &n, err) ||
            !request_check_names(v, p, err))
            return false;
        if (n == 0) return true;
        out->shape_tracks = calloc(n, sizeof *out->shape_tracks);
        if (!out->shape_tracks) return err_set(err, ERR_NOMEM, p, "out of memory");
        char q[REQUEST_PTR];
        for (const cJSON *c = v->child; c; c = c->next) {
            struct protocol_shape_track *track = &out->shape_tracks[out->shape_track_count++];
            snprintf(track->name, sizeof track->name, "%s", c->string);
            json_pointer_key(q, sizeof q, p, c->string);
            if (!request_shape_track(c, q, limits, track, err)) return false;
        }
    }
    return true;
}

bool protocol_parse_render_request(const char *body, size_t len, const struct protocol_limits *limits,
                                   struct protocol_render_request *out, struct err *err)
{
    static const char *const keys[] = {"animation", "reference", NULL};
    if (!out) return err_set(err, ERR_INVALID, "", "no output given");
    memset(out, 0, sizeof *out);
    out->fps = REQUEST_DEFAULT_FPS;
    out->interp = ANIMATION_LINEAR;
    if (!limits) return err_set(err, ERR_INVALID, "", "no limits given");
    cJSON *root;
    if (!request_parse(body, len, &root, err)) return false;

    char p[REQUEST_PTR];
    bool ok = json_check_keys(root, "", keys, " at the top level", err);
    const cJSON *av = request_member(root, "", "animation", p);
    if (ok && !av) ok = err_set(err, ERR_INVALID, p, "missing required key");
    ok = ok && request_animation(av, p, limits, out, err);
    const cJSON *rv = request_member(root, "", "reference", p);
    if (ok && rv) ok = request_id(rv, p, out->reference, err);
    cJSON_Delete(root);
    if (!ok) protocol_render_request_destroy(out);  /* the caller's destroy is then a no-op */
    return ok;
}

/* ---- reference request ---- */

const char *protocol_reference_method_name(enum protocol_reference_method m)
{
    return m == PROTOCOL_REFERENCE_SMS ? "sms" : "pt";
}

bool protocol_parse_reference_request(const char *body, size_t len, const struct protocol_limits *limits,
                                      struct protocol_reference_request *out, struct err *err)
{
    static const char *const keys[] = {"spp", "method", NULL};
    if (!out || !limits) return err_set(err, ERR_INVALID, "", "no output or limits given");
    cJSON *root;
    if (!request_parse(body, len, &root, err)) return false;
    char p[REQUEST_PTR];
    uint32_t n = REQUEST_DEFAULT_REFERENCE_SPP;
    bool ok = json_check_keys(root, "", keys, " at the top level", err);
    const cJSON *v = request_member(root, "", "spp", p);
    if (ok && v) ok = request_uint32(v, p, 1, limits->max_spp, "max_spp", &n, err);
    else if (ok && n > limits->max_spp)
        ok = err_set(err, ERR_LIMIT, p, "the default spp %u is over the limit max_spp = %u (send spp)", n, limits->max_spp);
    enum protocol_reference_method method = PROTOCOL_REFERENCE_PT;
    const cJSON *mv = request_member(root, "", "method", p);
    if (ok && mv) {
        const char *name = json_string(mv, p, err);
        ok = name != NULL;
        if (ok && strcmp(name, "sms") == 0) method = PROTOCOL_REFERENCE_SMS;
        else if (ok && strcmp(name, "pt") != 0)
            ok = err_set(err, ERR_INVALID, p, "unknown reference method \"%.64s\" (known: pt, sms)", name);
    }
    cJSON_Delete(root);
    if (ok) *out = (struct protocol_reference_request){.spp = n, .method = method};
    return ok;
}
