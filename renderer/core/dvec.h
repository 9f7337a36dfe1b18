/* dvec.h — 3-vectors in double, for geometry whose float rounding would decide the result: the
 * manifold walks' constraint and derivatives (integrators/manifold.c), spherical triangles seen
 * from far away (core/spherical.h). Header-only. */
#ifndef RESTIRD_DVEC_H
#define RESTIRD_DVEC_H

#include <math.h>

#include "core/vec.h"

struct dvec3 { double x, y, z; };

static inline struct dvec3 dvec3_from(struct vec3 a) { return (struct dvec3){a.x, a.y, a.z}; }
static inline struct vec3 dvec3_to_float(struct dvec3 a) { return vec3_make((float)a.x, (float)a.y, (float)a.z); }
static inline struct dvec3 dvec3_add(struct dvec3 a, struct dvec3 b) { return (struct dvec3){a.x + b.x, a.y + b.y, a.z + b.z}; }
static inline struct dvec3 dvec3_sub(struct dvec3 a, struct dvec3 b) { return (struct dvec3){a.x - b.x, a.y - b.y, a.z - b.z}; }
static inline struct dvec3 dvec3_scale(struct dvec3 a, double s) { return (struct dvec3){a.x * s, a.y * s, a.z * s}; }
static inline struct dvec3 dvec3_madd(struct dvec3 a, struct dvec3 b, double s) { return dvec3_add(a, dvec3_scale(b, s)); }
static inline double dvec3_dot(struct dvec3 a, struct dvec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline struct dvec3 dvec3_cross(struct dvec3 a, struct dvec3 b)
{
    return (struct dvec3){a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
static inline double dvec3_length(struct dvec3 a) { return sqrt(dvec3_dot(a, a)); }
static inline struct dvec3 dvec3_normalize(struct dvec3 a) { return dvec3_scale(a, 1.0 / dvec3_length(a)); }

#endif
