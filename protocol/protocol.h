/* protocol.h — the wire format: request bodies (JSON) parsed into plain C structs, and the
 * JSON writer responses are built with. Pure functions: no I/O, no global state, thread-safe.
 * Every parser is strict: bodies are byte ranges (not NUL-terminated), lookups are
 * case-sensitive, numbers are checked as doubles (finite, in range, integral where an integer
 * is expected), unknown keys and duplicate keys are errors, and every error carries the RFC 6901
 * JSON pointer of the offending member ("" = the whole body) in err->where.
 * Error codes: ERR_PARSE (not JSON per RFC 8259 — including bytes that are not UTF-8, raw
 * control characters in strings, leading zeros, numbers over 63 characters — or nested deeper
 * than PROTOCOL_MAX_DEPTH; the message gives the byte offset), ERR_INVALID (wrong type,
 * missing or unknown key, a "\u0000" escape, a body that is not an object, 1e999 and other
 * non-finite numbers, out of range), ERR_LIMIT (over a limit from struct protocol_limits; the
 * message names the limit and its value), ERR_NOMEM, ERR_UNSUPPORTED.
 * Every parser reads an empty body (len 0) as {}. A default that is over a configured limit
 * is reported as ERR_LIMIT at the member's pointer, never silently lowered.
 * Refs: protocol/API.md documents every field. */
#ifndef RESTIRD_PROTOCOL_H
#define RESTIRD_PROTOCOL_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "scene/animation.h"
#include "core/err.h"
#include "input/json_read.h"
#include "session/view.h"

#define PROTOCOL_ID_MAX 64          /* ids: [A-Za-z0-9_-]{1,64} */
#define PROTOCOL_MAX_DEPTH 16       /* JSON nesting depth accepted in a request body */
#define PROTOCOL_MAX_SHAPE_CHANGES 64

/* Limits the parsers enforce; the server fills them from its configuration. */
struct protocol_limits {
    uint32_t max_side;              /* width and height */
    uint64_t max_pixels;            /* width * height */
    uint32_t max_spp;               /* samples per pixel per frame (and reference spp) */
    uint32_t max_frames;            /* frames of an animation job */
    uint32_t max_keys;              /* keys per camera track and per shape track */
};

/* The JSON gate every body passes before it is parsed: text[0..len) is one RFC 8259 value,
 * nested at most PROTOCOL_MAX_DEPTH deep. Positions in its errors count from text's first byte,
 * so a value a caller embeds in a larger body (the CLI's --params) can be checked as written. */
bool protocol_check_json(const char *text, size_t len, struct err *err);

/* True when s[0..len) is a valid id. */
bool protocol_valid_id(const char *s, size_t len);

/* POST /v1/scenes/{scene}/sessions:
 * {"method": "pt", "width": W, "height": H, "seed": S, "profile": P, "params": {...}}; method
 * defaults to "pt", width/height to 256, seed to 0, profile to "real_time" ("converge": the
 * method's converge adjustments over its defaults, methods/method.h); params are the method's,
 * read through its descriptor's parameter table (methods/method.h) over the profile's
 * defaults, which absent ones keep.
 * width and height: 1..max_side, reported at "/width" or "/height"; width * height over
 * max_pixels is reported at "" (the product belongs to neither member alone).
 * seed: integer 0..2^53 (checked as a double: 2^53 + 1 reads as 2^53). *out is written only
 * on success. */
bool protocol_parse_session_create(const char *body, size_t len, const struct protocol_limits *limits,
                                   struct view_params *out, struct err *err);

/* A session's "params" object on its own, text[0..len) (the CLI's --params), read exactly as
 * protocol_parse_session_create reads it for vp->method, over the values already in
 * vp->method_params (the defaults of the method and its profile). Bit i of *given is set when
 * the object names vp->method->params[i] (a table has at most 32 parameters, json_check_keys'
 * limit), so a caller can put its own values under the keys left out. Positions in syntax errors count from
 * text's first byte; pointers name /params/<key> as in a session's body. *vp and *given are
 * written only on success. */
bool protocol_parse_method_params(const char *text, size_t len, const struct protocol_limits *limits,
                                  struct view_params *vp, uint32_t *given, struct err *err);

/* A partial camera: only the members present in the request are set. up must be non-zero;
 * position != look_at is checked when both are in the same object, and up not parallel to the
 * view direction when all three are (the server checks the camera it completes). */
struct protocol_camera {
    bool has_position, has_look_at, has_up, has_fov_deg;
    struct vec3 position, look_at, up;
    float fov_deg;                  /* (0, 180) */
};

/* A change to one named shape in a frame request ("lights": {name: {...}}). name is an id. */
struct protocol_shape_change {
    char name[PROTOCOL_ID_MAX + 1];
    /* position, transform ({"translate","rotate_deg","scale"} as in the scene format) and
     * emission (every component >= 0): the same channels an animation key has */
    struct animation_shape_state state;
};

/* POST …/sessions/{sid}/frames: {"camera": {...}, "lights": {name: {...}}, "time_s": t}, all
 * optional; an empty body (len 0) is the same as {}. A shape change must set at least one of
 * position, transform, emission and must not set both position and transform (both errors at
 * "/lights/<name>"); at most PROTOCOL_MAX_SHAPE_CHANGES (ERR_LIMIT at "/lights"). Shape names
 * are checked against the scene by the caller, which reports "/lights/<name>" (see
 * json_pointer_key). *out is zeroed on failure. */
struct protocol_frame_request {
    struct protocol_camera camera;
    uint32_t shape_count;
    struct protocol_shape_change shapes[PROTOCOL_MAX_SHAPE_CHANGES];
    bool has_time;
    double time_s;                  /* finite, >= 0 */
};
bool protocol_parse_frame_request(const char *body, size_t len, struct protocol_frame_request *out,
                                  struct err *err);

/* A camera key as sent: t plus a partial camera (the server completes it). */
struct protocol_camera_key {
    double t_s;
    struct protocol_camera camera;
};

struct protocol_shape_track {
    char name[PROTOCOL_ID_MAX + 1];
    uint32_t key_count;
    struct animation_shape_key *keys;   /* t_s strictly increasing */
};

/* POST …/sessions/{sid}/renders:
 * {"animation": {"fps": 30, "frames": N, "interpolation": "linear"|"catmull_rom",
 *                "camera_keys": [{"t": 0, "position": [...], "look_at": [...], "up": [...],
 *                                 "fov_deg": 40}, ...],
 *                "light_keys": {name: [{"t": 0, "position"|"transform": ..., "emission": [...]}]}},
 *  "reference": "name"}
 * fps finite > 0 (default 30), frames 1..max_frames (required), interpolation default
 * "linear"; key times finite, >= 0 and strictly increasing within a track (a violation is
 * reported at the later key's ".../t"); every key sets at least one channel besides t, a shape
 * key never both position and transform; camera_keys and light_keys optional (none = static
 * frames). At most max_keys keys per track (ERR_LIMIT at the track's pointer), at most
 * PROTOCOL_MAX_SHAPE_CHANGES shape tracks (ERR_LIMIT at "/animation/light_keys"), and a shape
 * track has at least one key. reference optional: an id. On failure the request is already
 * freed and emptied; protocol_render_request_destroy is idempotent and may still be called. */
struct protocol_render_request {
    double fps;
    uint32_t frames;
    enum animation_interp interp;
    uint32_t camera_key_count;
    struct protocol_camera_key *camera_keys;
    uint32_t shape_track_count;
    struct protocol_shape_track *shape_tracks;
    char reference[PROTOCOL_ID_MAX + 1];    /* "" = none */
};
bool protocol_parse_render_request(const char *body, size_t len, const struct protocol_limits *limits,
                                   struct protocol_render_request *out, struct err *err);
void protocol_render_request_destroy(struct protocol_render_request *req);

/* How a server-rendered reference is estimated: the path tracer, or the path tracer with
 * specular manifold sampling (uncapped Bernoulli trials: unbiased) for the caustic paths it owns,
 * which pt alone finds only by hitting a small light through the caster. */
enum protocol_reference_method { PROTOCOL_REFERENCE_PT, PROTOCOL_REFERENCE_SMS };

struct protocol_reference_request {
    uint32_t spp;
    enum protocol_reference_method method;
};

/* "pt" / "sms" (the names the request and the answers use). */
const char *protocol_reference_method_name(enum protocol_reference_method m);

/* POST …/sessions/{sid}/references/{name}: {"spp": N, "method": "pt" | "sms"} (spp 1..max_spp,
 * default 1024; a default over max_spp is ERR_LIMIT at "/spp"; method default "pt"). *out is
 * written only on success. */
bool protocol_parse_reference_request(const char *body, size_t len, const struct protocol_limits *limits,
                                      struct protocol_reference_request *out, struct err *err);

/* JSON pointers and UTF-8 sequences: input/json_read.h (json_pointer_key, json_utf8_seq). */

/* ---- responses ---- */

/* A growable JSON text builder. Commas between members and elements are inserted
 * automatically; strings are escaped (quote, backslash, control characters as \u00XX; valid
 * UTF-8 passes through, other bytes become U+FFFD so the text is always JSON; a NULL string is
 * null); non-finite doubles are written as null (JSON has no NaN). After an allocation failure
 * every call is a no-op and jsonw_finish returns NULL; so does nesting deeper than
 * PROTOCOL_MAX_DEPTH, closing a container that is not open, or finishing with a container
 * still open or nothing written. */
struct jsonw {
    char *buf;
    size_t len, cap;
    bool failed;
    int depth;
    bool need_comma[PROTOCOL_MAX_DEPTH + 1];
};
void jsonw_init(struct jsonw *w);
void jsonw_object_begin(struct jsonw *w);
void jsonw_object_end(struct jsonw *w);
void jsonw_array_begin(struct jsonw *w);
void jsonw_array_end(struct jsonw *w);
void jsonw_key(struct jsonw *w, const char *key);       /* inside an object, before a value */
void jsonw_string(struct jsonw *w, const char *s);
void jsonw_double(struct jsonw *w, double v);            /* %.17g round trip; null if non-finite */
void jsonw_uint(struct jsonw *w, uint64_t v);
void jsonw_int(struct jsonw *w, int64_t v);
void jsonw_bool(struct jsonw *w, bool v);
void jsonw_null(struct jsonw *w);
/* Returns the malloc'd NUL-terminated text (caller frees) and its length; NULL (length 0) on
 * failure. Either way the writer is left empty and may be reused after jsonw_init. */
char *jsonw_finish(struct jsonw *w, size_t *len);
void jsonw_destroy(struct jsonw *w);    /* discards an unfinished text */

/* RFC 9457 problem details: {"type","title","status","detail","instance"} plus "field" (when
 * non-NULL; "" is the pointer to the whole body) and "limit" (when has_limit). type is the URN "urn:restird:problem:<slug>": an
 * identifier a client can switch on that never pretends to be a page to fetch ("about:blank"
 * when slug is NULL or empty). A NULL title, detail or instance leaves that member out.
 * Returns malloc'd text (caller frees), NULL when out of memory. */
struct protocol_problem {
    int status;
    const char *slug;                /* e.g. "invalid-field", "scene-not-loaded" */
    const char *title;               /* short, fixed per slug */
    const char *detail;              /* the specific message */
    const char *instance;            /* the request path */
    const char *field;               /* JSON pointer ("" = the whole body), or NULL: none */
    bool has_limit;
    double limit;
};
char *protocol_problem_json(const struct protocol_problem *p, size_t *len);
/* The title of a problem type ("invalid-field" -> "Invalid field"); the slug when unknown. */
const char *protocol_problem_title(const char *slug);
/* Writes the problem's members into an object the caller opened (and closes, after adding
 * members of its own such as "job"): job errors and error events are problems too. */
void protocol_problem_members(struct jsonw *w, const struct protocol_problem *p);

/* Methods as JSON, from their descriptors (method_json.c). A session's params object; the frame's
 * method counters as members of the frame object being written (the daemon's form); the same
 * counters as the CLI's --json prints them, each member preceded by a comma, with the session's
 * bytes and one pixel's reservoir bytes where the method's table places them; one method's
 * descriptor and the whole registry (GET /v1/methods; spp ranges within limits->max_spp). */
void protocol_write_method_params(struct jsonw *w, const struct method_desc *m, const void *params);
void protocol_write_method_counters(struct jsonw *w, const struct method_desc *m, const struct frame_stats *st);
void protocol_print_method_counters(FILE *out, const struct method_desc *m, const struct frame_stats *st,
                                    size_t session_bytes, uint32_t reservoir_bytes_per_pixel);
void protocol_write_method(struct jsonw *w, const struct method_desc *m, const struct protocol_limits *limits);
void protocol_write_methods(struct jsonw *w, const struct protocol_limits *limits);

#endif
