/* accel.h — ray queries against a committed scene (the Embree home is accel.c).
 * Only shapes declared movable get an instance of their own (moving one re-commits just the
 * top level); everything else is baked into world space, in one flat BVH when nothing moves,
 * since a second traversal level costs every ray. Queries are thread-safe, allocation-free. */
#ifndef RESTIRD_ACCEL_H
#define RESTIRD_ACCEL_H

#include <stdint.h>

#include "core/err.h"
#include "core/vec.h"

struct scene;
struct accel;

struct hit {
    float t;          /* distance along the (unit) ray direction */
    uint32_t shape;   /* index into scene->shapes */
    uint32_t prim;    /* triangle index within the shape (0 for spheres) */
    float b1, b2;     /* barycentrics of triangle vertices 1 and 2 */
    struct vec3 ng;   /* geometric normal in world space, unit length, front-face side */
};

/* Per-thread query counters; callers sum them after a pass (rays/s in frame stats). */
struct ray_counters { uint64_t intersect, occluded; };

/* movable: NULL, or one flag per shape; a flagged shape can be moved with
 * accel_set_transform. The scene must outlive the accel. */
struct accel *accel_new(const struct scene *scene, const bool *movable, struct err *err);
void accel_free(struct accel *accel);
/* Closest hit with t in (tmin, tmax); `dir` must be unit length. */
bool accel_intersect(const struct accel *accel, struct vec3 org, struct vec3 dir, float tmin, float tmax,
                     struct hit *hit, struct ray_counters *counters);
/* accel_intersect with tmin 0 and tmax infinity for n <= ACCEL_BUNDLE rays from one origin,
 * traced together (cheaper than one by one when their directions are close, as a pixel's camera
 * rays are). found[i] tells whether ray i hit, hits[i] is its hit then. Counts n intersect
 * queries; returns how many rays hit. */
#define ACCEL_BUNDLE 8u
uint32_t accel_intersect_bundle(const struct accel *accel, struct vec3 org, const struct vec3 *dirs, uint32_t n,
                                struct hit *hits, bool *found, struct ray_counters *counters);
/* Every intersection with the one shape `shape` along org + t dir, t in (tmin, tmax), other
 * shapes ignored, in increasing t (so an index into the list names a hit deterministically: the
 * probe rays of bssrdf.h). Writes at most max_hits and returns how many; hits beyond max_hits are
 * not reported. Hits of the shape less than one float step apart in t count once (a ray through
 * a shared edge: see accel.c). One traversal, counted as one intersect query. `dir` must be unit
 * length. */
uint32_t accel_intersect_shape_all(const struct accel *accel, uint32_t shape, struct vec3 org, struct vec3 dir,
                                   float tmin, float tmax, struct hit *hits, uint32_t max_hits,
                                   struct ray_counters *counters);
/* True when anything blocks (tmin, tmax), t in units of |dir| (any length but zero): a segment
 * can be passed as it is, with tmax 1. */
bool accel_occluded(const struct accel *accel, struct vec3 org, struct vec3 dir, float tmin, float tmax,
                    struct ray_counters *counters);
/* Embree's query structs, kept by a caller that sends many rays from one thread (pt's tile
 * loop): the fields that are the same for every ray (the intersection context, tmin 0, the ray's
 * time, mask, id and flags) are written once by accel_query_init instead of once per ray, which
 * is about seven stores of every query (Embree writes only tfar and the hit record; it restores
 * whatever it changes for an instance's traversal). The layout is accel.c's; a query may be used
 * by one thread at a time only. */
struct accel_query {
    _Alignas(16) unsigned char opaque[160];
};
void accel_query_init(struct accel_query *q);
/* accel_intersect and accel_occluded with tmin 0, through q (set up by accel_query_init). */
bool accel_query_intersect(const struct accel *accel, struct accel_query *q, struct vec3 org, struct vec3 dir,
                           float tmax, struct hit *hit, struct ray_counters *counters);
bool accel_query_occluded(const struct accel *accel, struct accel_query *q, struct vec3 org, struct vec3 dir,
                          float tmax, struct ray_counters *counters);
/* Moves a shape that was declared movable; false otherwise. Takes effect after
 * accel_commit_top. Not thread-safe against concurrent queries. */
bool accel_set_transform(struct accel *accel, uint32_t shape, const struct xform *to_world);
void accel_commit_top(struct accel *accel);
/* Current object-to-world transform of a shape (baked shapes: their scene transform). */
const struct xform *accel_shape_to_world(const struct accel *accel, uint32_t shape);
/* Its inverse, kept beside it (computed once per transform with xform_invert, never singular:
 * accel_new and accel_set_transform reject singular transforms). */
const struct xform *accel_shape_to_object(const struct accel *accel, uint32_t shape);
/* True when that transform is exactly the identity (shapes given in world coordinates, as
 * most scene files write them), so hit reconstruction can skip applying it. */
bool accel_shape_is_identity(const struct accel *accel, uint32_t shape);

#endif
