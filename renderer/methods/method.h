/* method.h — the method registry: one descriptor per rendering method, read by everything that
 * needs to know about methods (the session driver, the request parser, the daemon's JSON, the
 * CLI, GET /v1/methods). Nothing outside a method's own files and registry.c names a method.
 *
 * A descriptor owns the method's name and summary, its capabilities, its parameter table (name,
 * type, range, help; defaults come from its `defaults` operation), the statistics it reports
 * (a table over its own counters struct) and its operations on its opaque state and parameter
 * structs. docs/architecture.md ("Adding a method") says how to add one. */
#ifndef RESTIRD_METHOD_H
#define RESTIRD_METHOD_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "core/err.h"
#include "core/parallel.h"
#include "image/image.h"
#include "integrators/frame.h"
#include "scene/scene.h"

/* Room for the largest method's parameters and counters; each method checks its own structs
 * against these at compile time (METHOD_FITS). */
#define METHOD_PARAMS_BYTES 256
#define METHOD_COUNTERS_BYTES 256
#define METHOD_FITS(type, room) _Static_assert(sizeof(type) <= (room), #type " does not fit " #room)
/* An enum parameter is read and written as an int (its choice's index). */
#define METHOD_ENUM_IS_INT(type) _Static_assert(sizeof(type) == sizeof(int), #type " is not int-sized")

/* Capabilities (struct method_desc.caps). */
enum {
    METHOD_TAKES_SPP = 1u << 0,        /* a frame holds `spp` samples per pixel (else one path per pixel) */
    METHOD_REUSES_FRAMES = 1u << 1,    /* keeps state that later frames reuse (temporal reuse) */
    METHOD_REUSES_PIXELS = 1u << 2,    /* shares samples between pixels within a frame (spatial reuse) */
    METHOD_MANIFOLD_COUNTERS = 1u << 3, /* fills render_stats.sms */
    METHOD_STILL_CROP = 1u << 4,        /* the CLI may render one still image of a crop window or
                                           a chosen frame index with the reference path tracer */
    METHOD_NO_ENVIRONMENT = 1u << 5,    /* refuses scenes with environment light */
    METHOD_NO_TRANSLUCENT = 1u << 6     /* refuses scenes with translucent materials */
};

enum method_param_kind { METHOD_PARAM_UINT, METHOD_PARAM_BOOL, METHOD_PARAM_FLOAT, METHOD_PARAM_ENUM };

/* A uint parameter whose upper bound is the daemon's max_spp limit rather than `max`. */
#define METHOD_PARAM_SPP_LIMIT 1u
/* A parameter whose default is chosen from the scene when the session is made (the session then
 * reports the value it chose; the registry shows no default). */
#define METHOD_PARAM_SCENE_DEFAULT 2u

/* The bytes a parameter of this kind occupies in its method's parameter struct. */
static inline size_t method_param_size(enum method_param_kind k)
{
    switch (k) {
    case METHOD_PARAM_UINT: return sizeof(uint32_t);
    case METHOD_PARAM_BOOL: return sizeof(bool);
    case METHOD_PARAM_FLOAT: return sizeof(float);
    case METHOD_PARAM_ENUM: return sizeof(int);
    }
    return 0;
}

struct method_param {
    const char *key;                   /* as in a session's "params" object */
    enum method_param_kind kind;       /* UINT: uint32_t; BOOL: bool; FLOAT: float; ENUM: an enum
                                          stored as int, indexing `choices` */
    size_t offset;                     /* into the method's parameter struct */
    double min, max;                   /* UINT and FLOAT: the accepted range (FLOAT: an end is
                                          excluded when min_open / max_open) */
    bool min_open, max_open;
    unsigned flags;                    /* METHOD_PARAM_* */
    const char *const *choices;        /* ENUM: the names, NULL-terminated */
    const char *help;                  /* one line */
};

/* One line of a method's frame statistics: a number, or the start/end of a nested object. The
 * daemon's frame JSON shows every line under `key`; the CLI's --json shows the lines with a
 * `cli_key` ("" hides a line there; the CLI shows no nested object whose start it hides). */
enum method_stat_kind {
    METHOD_STAT_BEGIN,       /* "key": { */
    METHOD_STAT_END,         /* } */
    METHOD_STAT_U64,         /* uint64_t at off */
    METHOD_STAT_MS,          /* double at off, milliseconds */
    METHOD_STAT_MS_SUM,      /* double at off + double at off2 */
    METHOD_STAT_RATIO,       /* uint64_t at off / uint64_t at off2 (0 when off2 holds 0) */
    METHOD_STAT_SUCCESS,     /* 1 - uint64_t at off / uint64_t at off2 (0 when off2 holds 0) */
    METHOD_STAT_SESSION_BYTES,            /* CLI only: the session's bytes (not a counter) */
    METHOD_STAT_RESERVOIR_BYTES_PER_PIXEL /* CLI only: bytes of one pixel's reservoirs */
};
struct method_stat {
    const char *key;                   /* daemon; NULL = CLI only */
    const char *cli_key;               /* CLI; "" = daemon only */
    enum method_stat_kind kind;
    uint16_t off, off2;                /* into the method's counters struct */
};

struct view_buffer_bytes {
    const char *name;                  /* "accumulation", "reservoirs", "gbuffer", ... */
    size_t bytes;
};
#define VIEW_MAX_BUFFERS 16

/* Adds a buffer to a method's list of `room` entries (method_desc.buffers); past the room the
 * entry is counted but not written, and the caller sees the count exceed the room. */
static inline void method_buffer(struct view_buffer_bytes *out, uint32_t room, uint32_t *n, const char *name,
                                 size_t bytes)
{
    if (*n < room) out[*n] = (struct view_buffer_bytes){name, bytes};
    (*n)++;
}

/* The statistics of one frame: what every method counts, and the method's own counters (its
 * descriptor's `stats` table describes them). */
struct frame_stats {
    uint32_t frame;                       /* index of this frame in the session's sequence */
    double time_s;
    struct render_stats render;           /* rays, samples, nonfinite, threads, render_ms */
    double scene_update_ms;               /* rebuilding the scene for moved or re-lit shapes */
    uint32_t accumulated;                 /* frames in the accumulation buffer after this one */
    _Alignas(8) unsigned char counters[METHOD_COUNTERS_BYTES];
};

/* A session's profile: real_time (the defaults, for a user who watches every frame) or
 * converge (a method's `converge` adjustments over them, for one image averaged over the
 * session's frames). */
enum method_profile { METHOD_PROFILE_REAL_TIME, METHOD_PROFILE_CONVERGE };
/* The profiles' names as the protocol spells them, by enum value, NULL-terminated. */
extern const char *const method_profile_names[];

struct method_desc {
    const char *name;
    const char *summary;                  /* one line */
    unsigned caps;                        /* METHOD_* capabilities */
    const char *refuses;                  /* scene features it refuses, and why (NULL: none) */
    const struct method_param *params;
    uint32_t param_count;
    const struct method_stat *stats;
    uint32_t stat_count;

    /* The defaults (params has METHOD_PARAMS_BYTES of room, zeroed). */
    void (*defaults)(void *params);
    /* The converge profile (enum method_profile): changes the defaults in params so that a
     * session's frames are independent draws, whose mean converges to the image. It runs
     * before the user's params, which override it. NULL: the method's frames are independent
     * under its defaults already, and the profile changes nothing. */
    void (*converge)(void *params);
    /* Ranges and combinations the table cannot express; the pointer names /params/<key>. */
    bool (*validate)(const void *params, struct err *err);
    /* Allocates the state for a width x height session on `scene` (state: state_bytes, zeroed,
     * owned by the session). May resolve scene-dependent defaults in params (what the session
     * then reports). On failure it frees what it allocated itself: the caller then frees the
     * state's memory without calling destroy. */
    size_t state_bytes;
    bool (*init)(void *state, const struct scene *scene, void *params, uint32_t width, uint32_t height,
                 struct err *err);
    void (*reset)(void *state);           /* forgets the history; NULL: nothing to forget */
    void (*destroy)(void *state);
    /* Renders one frame into out (allocated by the caller) and sets stats->render and the
     * method's counters in stats->counters. */
    bool (*render)(void *state, const void *params, const struct method_frame *f, struct image *out,
                   struct frame_stats *stats, parallel_progress_fn *progress, void *progress_ctx, struct err *err);
    /* Bytes init would allocate; bytes of one pixel's reservoirs (NULL: none); the buffers by
     * name, at most `room` of them (method_buffer; returns how many the method has). */
    uint64_t (*bytes_planned)(const void *params, const struct scene *scene, uint32_t width, uint32_t height);
    uint32_t (*reservoir_bytes_per_pixel)(const void *params, const struct scene *scene);
    uint32_t (*buffers)(const void *state, const void *params, struct view_buffer_bytes *out, uint32_t room);
    /* Appends to a "session too large" error how to ask for a smaller one, where the method's
     * buffers grow with the scene ("; ..."; NULL or nothing written: no hint). */
    void (*size_hint)(const void *params, const struct scene *scene, char *out, size_t size);
};

/* The method's defaults under a profile into params (METHOD_PARAMS_BYTES, zeroed). */
void method_profile_defaults(const struct method_desc *m, enum method_profile profile, void *params);

/* The registry, in a fixed order (the order of GET /v1/methods and of error messages). */
uint32_t method_count(void);
const struct method_desc *method_at(uint32_t i);
const struct method_desc *method_find(const char *name);   /* NULL when unknown */
/* The method a session or a render gets when none is named: the registry's first, the reference
 * path tracer. */
const struct method_desc *method_default(void);
/* "a, b, c" of every method's name, for messages. */
void method_names(char *out, size_t size, const char *separator);
const struct method_param *method_param_find(const struct method_desc *m, const char *key);

/* The render_stats of a frame rendered in one go: one sample per pixel, the method's own ray and
 * non-finite counts and pass times. */
struct render_stats method_frame_render_stats(const struct image *out, unsigned threads, uint64_t rays_intersect,
                                              uint64_t rays_occluded, uint64_t nonfinite, double ms);

#define METHOD_PARAM(type, key_, kind_, min_, max_, help_) \
    {.key = #key_, .kind = (kind_), .offset = offsetof(type, key_), .min = (min_), .max = (max_), .help = (help_)}
#define METHOD_PARAM_AT(key_, type, member, kind_, min_, max_, help_) \
    {.key = (key_), .kind = (kind_), .offset = offsetof(type, member), .min = (min_), .max = (max_), .help = (help_)}
#define METHOD_ENUM(type, key_, choices_, help_) \
    {.key = #key_, .kind = METHOD_PARAM_ENUM, .offset = offsetof(type, key_), .choices = (choices_), .help = (help_)}

#endif
