/* view.h — the persistent state of one rendering session: the method and its parameters, the
 * image size and seed, the current and previous camera and scene (the previous pair is what
 * temporal reuse evaluates the previous domain with), the frame counter, and the buffers the
 * method needs — allocated once when the view is created, never during a frame.
 * A method allocates only what it uses (its descriptor's init): `pt` keeps an accumulation buffer
 * and no reservoirs or G-buffers; `restir_pt` adds its two reservoir buffers and two G-buffers.
 * view_bytes() reports every buffer by name.
 * Not thread-safe: one frame at a time per view (the caller serialises). */
#ifndef RESTIRD_VIEW_H
#define RESTIRD_VIEW_H

#include <stddef.h>
#include <stdint.h>

#include "scene/animation.h"
#include "image/image.h"
#include "core/parallel.h"
#include "methods/method.h"
#include "scene/scene.h"

/* A session's method and parameters. The method's own parameters live in `method_params`, as
 * its parameter struct (VIEW_METHOD_PARAMS); the method's descriptor documents them. */
struct view_params {
    const struct method_desc *method;
    enum method_profile profile;          /* how method_params' defaults were chosen */
    uint32_t width, height;
    uint64_t seed;
    _Alignas(8) unsigned char method_params[METHOD_PARAMS_BYTES];
};
#define VIEW_METHOD_PARAMS(vp, type) ((type *)(void *)(vp)->method_params)

/* The method's defaults for a width x height session, seed 0, real_time profile. */
struct view_params view_params_defaults(const struct method_desc *method, uint32_t width, uint32_t height);
/* The defaults of p's method under `profile` in place of its parameters: called before the
 * user's parameters are read over them. */
void view_params_set_profile(struct view_params *p, enum method_profile profile);
/* A parameter of the session's method by name (method.h's table): false when the method has no
 * such parameter of that kind (nothing is written then). */
bool view_params_get_uint(const struct view_params *p, const char *key, uint32_t *out);
bool view_params_set_uint(struct view_params *p, const char *key, uint32_t value);
bool view_params_set_bool(struct view_params *p, const char *key, bool value);

/* A change applied to one named shape before a frame (absent channels keep their value). */
struct view_shape_change {
    uint32_t shape;                       /* index into scene->shapes */
    bool has_position, has_transform, has_emission;
    struct vec3 position;                 /* replaces the translation of the shape's transform */
    struct xform transform;               /* replaces the whole transform */
    struct vec3 emission;                 /* radiance of the shape's own copy of its material */
};

/* One frame's changes; absent members keep the previous frame's value. */
struct view_frame_change {
    bool has_camera;
    struct camera_desc camera;            /* complete (the caller merged partial changes) */
    uint32_t shape_count;
    const struct view_shape_change *shapes;
    bool has_time;
    double time_s;
};

/* Keyframed camera and shape tracks (an animation job, or the CLI's --animation), resolved
 * against a scene: cameras complete, shapes by index. The arrays belong to the owner. */
struct view_track {
    uint32_t shape;
    uint32_t key_count;
    struct animation_shape_key *keys;
};
struct view_animation {
    enum animation_interp interp;
    uint32_t camera_key_count;             /* 0 = the camera does not move */
    struct animation_camera_key *camera_keys;
    uint32_t track_count;
    struct view_track *tracks;
};

/* The frame change at time t: the interpolated camera (when keyed) and one shape change per
 * track, written to `shapes` (room for a->track_count). ERR_INVALID when an interpolated
 * transform leaves the float range. */
bool view_animation_change(const struct view_animation *a, double t_s, struct view_frame_change *out,
                           struct view_shape_change *shapes, struct err *err);

struct view {
    struct view_params params;
    unsigned threads;                     /* 0 = all cores */
    struct scene *base;                   /* the scene as loaded (retained) */
    struct scene *scene, *prev_scene;     /* current and previous frame's scene (retained;
                                             == base until a shape changes) */
    struct camera_desc camera, prev_camera;
    double time_s;
    uint32_t frame;                       /* frames rendered since creation or reset */
    struct image output;                  /* the frame last rendered (view_render's output) */
    struct image accum;                   /* running sum since the last change */
    uint32_t accum_count;
    void *state;                          /* the method's (its descriptor's state_bytes) */
    struct view_shape_change *changes;    /* the shape changes in force, one per changed shape */
    uint32_t change_count;
};

/* Validates params against the scene and allocates every buffer. Retains `scene`.
 * Errors: ERR_INVALID (params), ERR_LIMIT, ERR_NOMEM. */
bool view_init(struct view *v, struct scene *scene, const struct view_params *params, unsigned threads,
               struct err *err);
void view_destroy(struct view *v);
/* Forgets the history: frame counter, accumulation, previous camera/scene; keeps the current
 * camera and shape changes. */
void view_reset(struct view *v);

/* Renders the next frame into v->output (allocated with the view: a steady-state frame
 * allocates nothing unless a shape change derives a new scene). Applies `change` first
 * (NULL = none): a camera change or a shape change restarts the accumulation. Errors:
 * ERR_INVALID (a change names a shape out of range or gives a non-finite value), ERR_NOMEM;
 * on error the view's state (camera, scene, changes, counters) is unchanged. */
bool view_render(struct view *v, const struct view_frame_change *change, struct frame_stats *stats,
                 parallel_progress_fn *progress, void *progress_ctx, struct err *err);

/* The mean of the accumulated frames into `out` (initialised here); ERR_INVALID when none. */
bool view_accumulated(const struct view *v, struct image *out, uint32_t *count, struct err *err);

/* Bytes of the buffers view_init would allocate for `params` on `scene` (equal to view_bytes'
 * total right after view_init), so a caller can refuse a view before allocating it. */
uint64_t view_bytes_planned(const struct view_params *params, const struct scene *scene);

/* Bytes of one pixel's reservoirs in one of the method's reservoir buffers (0 without reuse):
 * restir_sss and restir_sms have one per layer (their target; light_reservoirs). `scene`: the
 * scene the params are for, which resolves a light_reservoirs left to the scene (0); NULL for
 * a view's own params, which view_init resolved (the view's scene changes while it renders, so
 * a reader of a busy view must not touch it). */
uint32_t view_reservoir_bytes_per_pixel(const struct view_params *params, const struct scene *scene);

/* Buffers by name; returns the count (<= VIEW_MAX_BUFFERS). *total gets the sum. */
uint32_t view_bytes(const struct view *v, struct view_buffer_bytes out[VIEW_MAX_BUFFERS], size_t *total);

#endif
