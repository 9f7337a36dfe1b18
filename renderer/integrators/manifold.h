/* manifold.h — manifold walks over chains of specular vertices (Jakob & Marschner 2012;
 * Zeltner et al. 2020, the solver of specular manifold sampling, [SMS-SSP §3.1]).
 *
 * A chain connects a fixed start point x1 (a non-specular shading point) through `length`
 * specular vertices on one caster shape, each a reflection or a refraction, to a fixed end
 * point (a point on a light). The walk moves the specular vertices over the caster's surface
 * with Newton's method until each vertex satisfies its specular constraint, re-projecting the
 * vertices onto the surface by ray tracing after every step.
 *
 * Constraint (angle-difference form, Zeltner et al. 2020 §4.3): at every vertex the direction
 * towards the next vertex and the specular scattering of the direction towards the previous
 * vertex are written in spherical coordinates (θ, φ) in a frame attached to the shading normal;
 * C = (Δθ, Δφ) with Δφ wrapped into [−π, π]. The pole of those spherical coordinates is the
 * surface tangent, not the normal: under an overhead light a slab is crossed near normal
 * incidence, where φ about the normal is undefined and its derivative blows up; a pole in the
 * tangent plane only sees grazing directions, which no useful caustic path takes.
 *
 * The Jacobian of C with respect to the vertices' surface parameters is analytic, in double
 * precision, over the exact first-order surface model each vertex carries (position,
 * interpolated normal and their derivatives along the surface parameters): the chain rule
 * through the unit directions to the neighbours, the specular scattering, the frame (which
 * turns with the normal) and the two angles (Zeltner et al. 2020 §4; Jakob & Marschner 2012
 * §4). C_i depends only on vertices i − 1, i, i + 1, so J is block tridiagonal; a walk takes
 * it once per accepted point, and the generalized geometry term takes it with the end point's
 * derivative. The 2k × 2k system (k ≤ MANIFOLD_MAX_CHAIN) is solved directly.
 *
 * Every routine here is deterministic (the Bernoulli trials of SMS depend on that),
 * allocation-free and thread-safe. */
#ifndef RESTIRD_MANIFOLD_H
#define RESTIRD_MANIFOLD_H

#include <stdbool.h>
#include <stdint.h>

#include "scene/accel.h"
#include "core/vec.h"

struct scene;

#define MANIFOLD_MAX_CHAIN 2
#define MANIFOLD_MAX_ITERATIONS 20     /* Zeltner et al. 2020: 20 Newton steps */
#define MANIFOLD_TOLERANCE 1e-5        /* ‖C‖ (radians) at convergence */
#define MANIFOLD_POLISH_TOLERANCE 1e-11 /* after convergence, steps continue towards this... */
#define MANIFOLD_POLISH_STEPS 3         /* ...for at most this many more steps */

enum manifold_event { MANIFOLD_REFLECT, MANIFOLD_REFRACT };

/* What a caster's chain looks like: every vertex on `shape`, events in order from x1. */
struct manifold_chain {
    uint32_t shape;
    uint32_t length;                               /* 1 .. MANIFOLD_MAX_CHAIN */
    enum manifold_event events[MANIFOLD_MAX_CHAIN];
    float ior;                                     /* refraction: the material's inside / outside */
};

/* A specular vertex: the hit it came from (shape = chain.shape) and its surface. */
struct manifold_vertex {
    struct vec3 p, ng, ns;
    uint32_t prim;
    float b1, b2;                                  /* surface_at's point code */
    /* The walk's own double-precision point: ‖C‖ < 1e-5 needs more than the float hit (a float
     * position is off by ~1e-7 of the scene size, which alone gives ~1e-6..1e-5 rad). */
    double pd[3], bd[2];                           /* position; mesh barycentrics (b1, b2) */
};

/* The fixed ends: start point x1 with its geometric normal (for ray origins), end point on
 * a light with the light's geometric normal (for the generalized geometry term). */
struct manifold_ends {
    struct vec3 x1, ng1;
    struct vec3 xe, nge;
};

struct manifold_stats {
    uint32_t iterations;                           /* Newton steps taken (accepted or not) */
};

/* The seed path: a ray from x1 towards `target`, scattered specularly at each hit by the
 * chain's events (shading normals), for `length` hits that must all be on chain->shape.
 * False when a ray misses the caster, hits another shape first, or refraction is impossible. */
bool manifold_seed_path(const struct scene *scene, const struct manifold_chain *chain, const struct manifold_ends *ends,
                        struct vec3 target, struct manifold_vertex *v, struct ray_counters *rc);

/* Walks `v` (chain->length vertices, a path on the caster) to a solution: at most
 * `max_iterations` Newton steps, halving the step when a step fails to re-project onto the
 * caster or does not reduce ‖C‖, doubling it back after a success. True when ‖C‖ <
 * MANIFOLD_TOLERANCE; `v` is then the solution, polished by up to MANIFOLD_POLISH_STEPS more
 * steps (counted in stats, not against max_iterations); on failure it holds the last iterate. */
bool manifold_walk(const struct scene *scene, const struct manifold_chain *chain, const struct manifold_ends *ends,
                   struct manifold_vertex *v, uint32_t max_iterations, struct manifold_stats *stats,
                   struct ray_counters *rc);

/* The same walk without the polishing: it stops as soon as ‖C‖ < MANIFOLD_TOLERANCE. For a
 * walk whose end is only compared with a known chain (manifold_same at 1e-4 of the segment,
 * far above what ‖C‖ < 1e-5 leaves loose), or kept as float point codes (~1e-7 of the
 * segment), as a manifold shift keeps its chain: polishing below that buys nothing. Not for
 * the Bernoulli trials, which compare two walks' ends with each other. */
bool manifold_walk_unpolished(const struct scene *scene, const struct manifold_chain *chain,
                              const struct manifold_ends *ends, struct manifold_vertex *v, uint32_t max_iterations,
                              struct manifold_stats *stats, struct ray_counters *rc);

/* The same walk confined to a trust region: `inside(region, x2)` says whether the first vertex
 * is still inside; the walk fails as soon as an accepted step leaves the region (so it fails
 * rather than converge outside). */
typedef bool manifold_region_fn(const void *region, struct vec3 x2);
bool manifold_walk_within(const struct scene *scene, const struct manifold_chain *chain,
                          const struct manifold_ends *ends, struct manifold_vertex *v, uint32_t max_iterations,
                          manifold_region_fn *inside, const void *region, struct manifold_stats *stats,
                          struct ray_counters *rc);

/* ‖C‖ of a path (INFINITY when a constraint is undefined, e.g. total internal reflection). */
double manifold_constraint_norm(const struct scene *scene, const struct manifold_chain *chain,
                                const struct manifold_ends *ends, const struct manifold_vertex *v);

/* Checks a solution against the scene exactly as path tracing would produce it: the ray from
 * x1 towards each vertex in turn first hits that vertex on the caster; each vertex's event type
 * agrees with the sides of the geometric normal the two directions lie on (reflection: same
 * side; refraction: opposite sides); the direction towards the next vertex lies on the same
 * side of the geometric and the shading normal; and the last vertex sees the end point. */
bool manifold_check(const struct scene *scene, const struct manifold_chain *chain, const struct manifold_ends *ends,
                    const struct manifold_vertex *v, struct ray_counters *rc);

/* Generalized geometry term of a solution: |dω1 / dA(xe)|, the solid angle at x1 swept per
 * unit area at the end point with the specular vertices following (implicit function theorem
 * on C, Jakob & Marschner 2012 §4). For an empty chain it would be cos θe / d². 0 when the
 * system is singular. */
double manifold_geometry(const struct scene *scene, const struct manifold_chain *chain,
                         const struct manifold_ends *ends, const struct manifold_vertex *v);

/* Specular throughput of a solution for radiance arriving at x1: the product over the
 * vertices of the conductor's Fresnel reflectance (reflection) or the dielectric's 1 − F times
 * (η_x1-side / η_light-side)² (refraction), as path tracing's delta lobes weigh them in
 * expectation. Zero when a vertex's material cannot produce its event. */
struct vec3 manifold_throughput(const struct scene *scene, const struct manifold_chain *chain,
                                const struct manifold_ends *ends, const struct manifold_vertex *v);

/* Test hooks. The constraint's derivatives at a path: J = dC / d(u_j, v_j) over each vertex's
 * surface model (2k × 2k) and B = dC / d(end point) along the light's tangent frame (2k × 2),
 * analytic as the walks and manifold_geometry take them, or by central differences of C
 * (`central_differences`, step 1e-6 of the adjacent segments). False when C is undefined. */
bool manifold_test_derivatives(const struct scene *scene, const struct manifold_chain *chain,
                               const struct manifold_ends *ends, const struct manifold_vertex *v,
                               bool central_differences, double J[2 * MANIFOLD_MAX_CHAIN][2 * MANIFOLD_MAX_CHAIN],
                               double B[2 * MANIFOLD_MAX_CHAIN][2]);
/* manifold_walk with each Newton step's Jacobian by forward differences (step 1e-7 of the
 * shorter adjacent segment) instead: what the analytic walk's Newton steps are compared with. */
bool manifold_test_walk_forward_differences(const struct scene *scene, const struct manifold_chain *chain,
                                            const struct manifold_ends *ends, struct manifold_vertex *v,
                                            uint32_t max_iterations, struct manifold_stats *stats,
                                            struct ray_counters *rc);

/* Same solution: every vertex within `tol` (world units) of the other's. */
bool manifold_same(const struct manifold_vertex *a, const struct manifold_vertex *b, uint32_t length, float tol);

#endif
