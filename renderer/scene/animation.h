/* animation.h — keyframe tracks for cameras and named shapes (lights and objects): the value of
 * a track at a time, by linear or Catmull-Rom interpolation. Pure functions over caller-owned
 * arrays: no allocation, no I/O, thread-safe.
 * Keys are sorted by strictly increasing time `t_s` (the protocol layer validates this).
 * Before the first key a track holds the first key's value, after the last the last's; at a
 * key's time the value is exactly that key's.
 * Catmull-Rom here is the cubic Hermite spline through the keys with tangents from the
 * neighbours' finite differences, (p[i+1] - p[i-1]) / (t[i+1] - t[i-1]), one-sided at the
 * ends: C1 for any key spacing, and exactly linear for a channel with two keys. */
#ifndef RESTIRD_ANIMATION_H
#define RESTIRD_ANIMATION_H

#include <stdbool.h>
#include <stdint.h>

#include "scene/scene.h"
#include "core/vec.h"

enum animation_interp { ANIMATION_LINEAR, ANIMATION_CATMULL_ROM };

/* A camera key: every field set (the server fills fields a request left out from the camera the
 * session had when the job started). */
struct animation_camera_key {
    double t_s;
    struct camera_desc camera;
};

/* A key of a named shape. Each channel is optional; a channel interpolates over only the keys
 * that set it, so a track may key position at some times and emission at others.
 * `position` replaces the translation of the shape's transform; `transform` replaces the whole
 * transform (given as parts so that it interpolates component-wise: angles in degrees, no
 * wrapping, so 350 -> 10 turns back through 180; key 370 to turn forwards); a key must not set
 * both. */
struct animation_shape_key {
    double t_s;
    bool has_position, has_transform, has_emission;
    struct vec3 position;
    struct trs transform;
    struct vec3 emission;   /* linear RGB radiance, every component >= 0 */
};

/* The state of a shape at one time: which channels any key set, and their values. */
struct animation_shape_state {
    bool has_position, has_transform, has_emission;
    struct vec3 position;
    struct trs transform;
    struct vec3 emission;
};

/* Camera at time t. Position, look_at and fov_deg interpolate component-wise; fov_deg stays
 * within the range of the keys it is made from (so inside (0, 180) when they are). up
 * interpolates and is renormalised; where it degenerates (zero, or parallel to the view
 * direction) the nearer key's up is used. `count` >= 1 (with 0, *out is left unchanged). */
void animation_camera_at(const struct animation_camera_key *keys, uint32_t count, enum animation_interp interp,
                         double t_s, struct camera_desc *out);

/* Shape state at time t. Interpolated emission is clamped at 0 and each transform scale
 * component to the range of the keys it is made from (Catmull-Rom overshoots). Channels no key
 * sets are reported absent, with zero position and emission and the identity transform.
 * `count` >= 1. */
void animation_shape_at(const struct animation_shape_key *keys, uint32_t count, enum animation_interp interp,
                        double t_s, struct animation_shape_state *out);

#endif
