/* gbuffer.h — the primary hit of every pixel for one frame, and where that point was seen in
 * the previous frame (the motion vector temporal reuse follows). A session keeps two (current
 * and previous) and swaps them; they are allocated once, never per frame.
 * The primary ray goes through a uniformly jittered position in the pixel (the box filter the
 * reference path tracer integrates): the frame's point of the pixel's own stratified sequence
 * (gbuffer_fresh_position) where the method keeps no temporal history, else a draw of the pixel's
 * random stream for the frame. Either way a method that starts its paths at the G-buffer's hits
 * estimates the same pixel integral as `pt`.
 * With a jitter walk the position is instead the previous frame's moved by a uniform step of at
 * most `jitter_walk` pixels per axis, reflected at the pixel's edges: the uniform distribution is
 * stationary under a symmetric step reflected at the edges, so every frame's position is still
 * uniform in the pixel (the first frame's is drawn afresh), while consecutive frames look at
 * nearby points of it, where a method's temporal history was gathered.
 * The previous position accounts for camera motion and for shapes that moved between the two
 * frames' scenes (derived scenes keep shape indices). Visibility in the previous frame is checked
 * only on request (gbuffer_frame.check_history): a temporal shift validates its own vertices, but
 * a method whose history is trusted at many times a frame's confidence loses more to a shift that
 * fails, or that lands on another surface, than it gains (the history check below).
 * Emission seen directly (gbuffer_keep_emission): the light of paths that end on the primary hit
 * is an integral over the pixel's area of its own, apart from everything a method's reservoir
 * carries (those paths have at least one more vertex), so it may be estimated with more primary
 * rays than the one the reservoir's paths start from. Where a pixel's area holds an emitter's edge,
 * one position per frame makes the edge flicker between the emitter's radiance and its
 * surroundings' for many frames of a mean; a method whose frame costs several `pt` samples then
 * loses the edge pixels to `pt` by far (docs/benchmarks.md, "Emission seen directly"). The pass
 * finds those pixels once per camera and scene from rays through the pixel corners that lie in an
 * emitting shape's projection, and spends gbuffer_frame.emission_samples rays on each of them.
 * Only emitting shapes make edge pixels, not the lit environment's horizon (gbuffer.c says why).
 * A frame reads only its own G-buffer's emission, so a session's two G-buffers share one copy
 * (gbuffer_share_emission).
 * Refs: docs/architecture.md (the G-buffer pass); docs/methods.md, "Reuse shared by the methods"
 * (temporal reuse evaluates the previous domain with the previous camera and scene). */
#ifndef RESTIRD_GBUFFER_H
#define RESTIRD_GBUFFER_H

#include <stdint.h>

#include "scene/accel.h"
#include "core/err.h"
#include "scene/scene.h"

struct gbuffer_pixel {
    float t;                /* distance to the primary hit; INFINITY when the ray escaped */
    uint32_t shape, prim;   /* the hit (valid when t is finite) */
    float b1, b2;           /* its point code: surface_at rebuilds the surface */
    float jx, jy;           /* the primary ray's position inside the pixel, in [0, 1) */
    float prev_x, prev_y;   /* image position (pixels) of the same point, or of the same
                               direction for an escaped ray, in the previous frame; NAN when
                               there is no previous frame or the point was behind its camera */
    float prev_share;       /* the share of that pixel's temporal confidence this pixel takes, in
                               (0, 1]: 1 unless gbuffer_frame.check_history (gbuffer.c) */
};

/* A primary hit's surface as the G-buffer pass built it, for a method whose shifts come back to
 * the primary hits of the current and the previous frame several times a frame: reading it costs
 * less than rebuilding the surface from the point code, and every reader sees the same numbers.
 * (The shading frame is frame_from_normal(ns).) */
struct gbuffer_surface {
    struct vec3 p, ng, ns;
    uint32_t material;   /* GBUFFER_NO_HIT: the primary ray escaped */
};
#define GBUFFER_NO_HIT UINT32_MAX

struct gbuffer {
    uint32_t width, height;
    struct gbuffer_pixel *px;      /* width * height, row-major, top row first */
    struct gbuffer_surface *surf;  /* the same pixels' surfaces; NULL unless gbuffer_keep_surfaces */
    struct vec3 *emission;         /* the pixels' directly seen emission this frame (an unbiased
                                      estimate of its mean over the pixel's area: the primary hit's
                                      own, or on an edge pixel the mean of the rays it takes); NULL
                                      unless gbuffer_keep_emission */
    uint8_t *edge;                 /* nonzero where the pixel's area may hold an emitter's edge (2:
                                      its corners see different emitters; 1: beside such a pixel,
                                      or in a small emitter's box) */
    uint32_t *corner;              /* (width + 1) x (height + 1): what each pixel corner's ray sees
                                      (an emitting shape, or none) */
    struct gbuffer_edges *edges;   /* for whom `edge` holds, and its ray count */
    bool owns_emission;            /* false: the arrays above are another G-buffer's */
};

/* The camera and scene (its serial) the edge pixels were found for, and the most rays an edge
 * pixel takes: a power of two, at most the pixels per edge pixel, so that no scene's edges take
 * more rays a frame than the image has pixels. */
struct gbuffer_edges {
    struct camera_desc camera;
    uint64_t serial;
    uint32_t samples;
};

/* Allocates (ERR_LIMIT / ERR_NOMEM). */
bool gbuffer_init(struct gbuffer *g, uint32_t width, uint32_t height, struct err *err);
/* From now on gbuffer_render also writes g->surf (ERR_NOMEM). */
bool gbuffer_keep_surfaces(struct gbuffer *g, struct err *err);
/* From now on gbuffer_render also writes g->emission (ERR_NOMEM). */
bool gbuffer_keep_emission(struct gbuffer *g, struct err *err);
/* From now on gbuffer_render writes g's emission into `from`'s arrays (which gbuffer_keep_emission
 * made, and which must outlive g's use of them): for a session's other G-buffer, of the same size. */
void gbuffer_share_emission(struct gbuffer *g, const struct gbuffer *from);
/* What gbuffer_keep_emission allocates for a width x height G-buffer. */
size_t gbuffer_emission_bytes_planned(uint32_t width, uint32_t height);
void gbuffer_destroy(struct gbuffer *g);
size_t gbuffer_bytes(const struct gbuffer *g);          /* the pixels, surfaces not included */
size_t gbuffer_surface_bytes(const struct gbuffer *g);  /* 0 without surfaces */
size_t gbuffer_emission_bytes(const struct gbuffer *g); /* 0 without emission or when shared */

/* Random stream id of the independent fresh positions and the jitter walk's steps, rng_make(seed,
 * frame, pixel, GBUFFER_STREAM), and the key of the stratified positions' Sobol' seeds. Methods
 * use other ids for their own random numbers. */
#define GBUFFER_STREAM 0x6762ull
/* The key of the directly seen emission's positions (gbuffer_emission_position). */
#define GBUFFER_EMISSION_STREAM 0x67656dull

struct gbuffer_frame {
    const struct scene *scene;            /* this frame */
    const struct camera_desc *camera;
    const struct scene *prev_scene;       /* the previous frame; NULL = none (first frame) */
    const struct camera_desc *prev_camera;
    uint64_t seed;
    uint32_t frame;
    unsigned threads;                     /* 0 = all cores */
    bool stratify;                        /* a fresh position is the frame's point of the pixel's
                                             stratified sequence (gbuffer_fresh_position: frames
                                             without temporal history); else a draw of the pixel's
                                             random stream, independent of the previous frame's */
    float jitter_walk;                    /* 0: a fresh position every frame; in (0, 0.5]: the
                                             largest step per axis from prev_gbuffer's, pixels */
    const struct gbuffer *prev_gbuffer;   /* the previous frame's (same size); NULL = fresh */
    bool check_history;                   /* with prev_gbuffer, in a frame whose camera or shapes
                                             moved: a motion vector whose previous pixel saw another
                                             surface is dropped (prev_x = NAN), and prev_share set
                                             (gbuffer_history_share) */
    uint32_t emission_samples;            /* with g->emission: the rays an edge pixel's directly
                                             seen emission takes (1: the primary ray's own only),
                                             rounded down to a power of two and at most
                                             g->edges->samples */
};

/* The most rays a method may spend on a pixel's directly seen emission per frame. */
#define GBUFFER_EMISSION_SAMPLES_MAX 256u

/* Whether a method's `emission_samples` parameter is in 1..GBUFFER_EMISSION_SAMPLES_MAX; the error
 * names /params/emission_samples. */
bool gbuffer_emission_samples_valid(uint32_t samples, struct err *err);

/* Position k of the K an edge pixel's directly seen emission takes in `frame`: point frame K + k
 * of a Sobol' sequence of the pixel's own (gbuffer_fresh_position's, another key), so the
 * positions of every frame are stratified in the pixel and those of consecutive frames fill in
 * each other's gaps. */
void gbuffer_emission_position(uint64_t seed, uint64_t pixel, uint32_t frame, uint32_t k, uint32_t samples, float *jx,
                               float *jy);

/* The primary ray's position in the pixel in a frame without a jitter walk or temporal history
 * (gbuffer_frame.stratify): point `frame` of the
 * pixel's own Owen-scrambled Sobol' sequence (core/sobol.h; Burley 2020), randomised by (seed,
 * pixel). Each frame's position is uniform in the pixel, so every frame is unbiased on its own,
 * and the positions of any 2^k consecutive frames from a multiple of 2^k form a (0,k,2)-net: a
 * mean of frames (the converge profiles') samples the pixel's area stratified, as pt's samples
 * do, where independent positions leave edges and small bright features noisier. A method that
 * draws its own primary rays (restir_bdpt, whose shifts replay them) takes its positions here too. */
void gbuffer_fresh_position(uint64_t seed, uint64_t pixel, uint32_t frame, float *jx, float *jy);

/* Whether a method's `jitter_walk` parameter is a step gbuffer_render takes: 0 (a fresh
 * position every frame) up to half a pixel, a step that already spreads the next position over
 * the whole pixel (a larger one would keep no more of the history's place than a fresh draw).
 * The error names /params/jitter_walk. */
bool gbuffer_jitter_walk_valid(float jitter_walk, struct err *err);

/* Relative tolerance of the history check: the reprojected point must lie within this fraction
 * of its distance to the previous camera from the tangent plane of the previous pixel's hit. */
#define GBUFFER_HISTORY_PLANE_TOL 0.02f

/* Traces one primary ray per pixel. *rays gets the number of ray queries. */
bool gbuffer_render(struct gbuffer *g, const struct gbuffer_frame *f, uint64_t *rays, struct err *err);

/* The pixel's primary hit for a path that follows the same camera ray (surface_hit_at), written
 * to *out; NULL when the ray escaped. A method that continues the ray need not trace it again. */
const struct hit *gbuffer_hit(const struct scene *scene, const struct gbuffer_pixel *px, struct hit *out);

#endif
