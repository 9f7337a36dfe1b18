/* bdpt.h — method `bdpt`: bidirectional path tracing with a light vertex cache ([ReSTIR BDPT §3]
 * and docs/methods.md (bdpt); Davidovič et al. 2014 for the cache). Each frame traces N_L light
 * subpaths, starting on emitters in proportion to their power; every non-delta light vertex is
 * kept in the light vertex cache (LVC) and connected to the camera (light tracing, t = 1).
 * Then one camera subpath per pixel collects emission it hits (s = 0), next-event estimation
 * (s = 1) and, at each non-delta vertex, a connection to one vertex drawn uniformly from the
 * LVC (weighted |LVC| / N_L, so in expectation it equals connecting to every vertex of one
 * light subpath). All techniques are weighted with recursive MIS (bdpt_mis.h).
 *
 * Determinism: light subpath i draws from its own random stream and light subpaths are traced
 * in fixed blocks; each block writes its vertices into its own fixed region of the LVC, and the
 * light-tracing contributions are added to the image block by block, vertex by vertex, in one
 * thread: frames are bit-identical whatever the thread count.
 *
 * Limits (said, not hidden): constant environment light is not supported (bdpt_init refuses
 * such scenes); a block whose light subpaths store more vertices than its region holds drops
 * the excess vertices (and their light-tracing contributions) and counts them in
 * bdpt_stats.lvc_dropped — a bias, so the region size is a parameter and the statistical tests
 * assert that nothing was dropped. Paths longer than max_depth bounces are cut, as in `pt`. */
#ifndef RESTIRD_BDPT_H
#define RESTIRD_BDPT_H

#include <stddef.h>
#include <stdint.h>

#include "core/alias.h"
#include "scene/camera.h"
#include "core/err.h"
#include "image/image.h"
#include "scene/light_sampler.h"
#include "integrators/frame.h"
#include "scene/scene.h"

enum bdpt_heuristic { BDPT_HEURISTIC_POWER, BDPT_HEURISTIC_BALANCE };

struct RESTIRD_STORED_IN_BYTES bdpt_params {
    uint32_t max_depth;        /* maximum scattering events of a full path, 1..1024 (default 64) */
    uint32_t rr_depth;         /* Russian roulette after this many bounces of a subpath (default 3) */
    uint32_t light_paths;      /* N_L per frame; 0 = the pixel count (default) */
    uint32_t lvc_capacity;     /* LVC vertices kept per light subpath on average, 1..64 (default 8) */
    enum bdpt_heuristic heuristic;  /* power (beta = 2, default) or balance */
};

/* Light subpaths per LVC block (the unit of parallel work and of the LVC's fixed regions). */
#define BDPT_BLOCK_PATHS 256u

/* One light subpath vertex in the cache. The surface is rebuilt from its point code. */
struct bdpt_light_vertex {
    struct vec3 wo;            /* unit direction towards the previous light vertex */
    struct vec3 beta;          /* light subpath throughput up to this vertex */
    float dvcm, dvc;           /* recursive MIS quantities (bdpt_mis.h) */
    float b1, b2;              /* point code (surface_at) */
    uint32_t shape, prim;
    uint32_t depth;            /* number of surface vertices on the light subpath up to this one */
};

/* bdpt's light-tracing contribution (t = 1) of the cached vertex in the same slot, added to the
 * image after the light pass in block order (restir_bdpt buckets its own instead). */
struct bdpt_splat {
    struct vec3 value;         /* already / N_L; 0 when none */
    uint32_t pixel;            /* UINT32_MAX when none */
};

/* A frame's light subpaths in blocks of BDPT_BLOCK_PATHS (a block is one job and fills its own
 * region of `region` slots of the method's per-block cache), with each block's counters: the
 * layout bdpt and restir_bdpt share. */
struct bdpt_blocks {
    uint32_t light_paths;      /* N_L resolved */
    uint32_t blocks;           /* ceil(N_L / BDPT_BLOCK_PATHS) */
    uint32_t region;           /* cache slots per block */
    uint32_t rays_per_block;   /* counters per block in `rays` */
    uint32_t *count;           /* slots stored per block */
    uint32_t *dropped;         /* entries dropped per block (region full) */
    uint64_t *rays;            /* per block: rays traced (intersect, occluded), then the method's own */
};
/* The layout of light_paths subpaths (0: one per pixel) with `slots` cache slots each; no
 * allocation. */
struct bdpt_blocks bdpt_blocks_of(uint32_t light_paths, uint32_t slots, uint32_t rays_per_block, uint32_t width,
                                  uint32_t height);
/* The start of both methods' init once their parameters are valid: refuses environment light and
 * translucent materials (the messages name `method`). */
bool bdpt_scene_supported(const struct scene *scene, const char *method, struct err *err);
/* Lays out *b (bdpt_blocks_of) and allocates its counters (no `rays` when rays_per_block is 0).
 * False, with *b empty, for a frame without light subpaths or when an allocation fails. */
bool bdpt_blocks_alloc(struct bdpt_blocks *b, uint32_t light_paths, uint32_t slots, uint32_t rays_per_block,
                       uint32_t width, uint32_t height, struct err *err);
/* Whether the parameters of a frame still lay out the session's blocks. */
static inline bool bdpt_blocks_same(const struct bdpt_blocks *b, struct bdpt_blocks want)
{
    return want.light_paths == b->light_paths && want.region == b->region;
}
/* The checks both methods' render start with once their parameters are valid: a committed scene
 * without environment light (the message names `method`) and an output of the session's size. */
bool bdpt_frame_valid(const struct method_frame *f, const char *method, const struct image *out, uint32_t width,
                      uint32_t height, struct err *err);
/* Bytes of the counters. */
uint64_t bdpt_blocks_bytes(const struct bdpt_blocks *b);
void bdpt_blocks_destroy(struct bdpt_blocks *b);

struct bdpt_state {
    uint32_t width, height;
    struct bdpt_blocks lb;           /* region: LVC vertices per block */
    struct bdpt_light_vertex *lvc;   /* lb.blocks * lb.region */
    struct bdpt_splat *splat;        /* lb.blocks * lb.region, the same slots */
    uint64_t *block_first;     /* prefix sums of lb.count (lb.blocks + 1) */
};

struct RESTIRD_STORED_IN_BYTES bdpt_stats {
    double light_ms, splat_ms, camera_ms;
    uint64_t light_subpaths;   /* N_L */
    uint64_t lvc_vertices;     /* |LVC| */
    uint64_t lvc_dropped;      /* vertices that found their block's region full (see above) */
    uint64_t light_traced;     /* light-tracing samples that reached a pixel (t = 1) */
    uint64_t connections;      /* camera-to-LVC connections made (visible, non-zero) */
    uint64_t rays_intersect, rays_occluded;
    uint64_t nonfinite;
};


/* Defaults: max_depth 64, rr_depth 3, N_L = pixel count, 8 LVC vertices per path, power. */
struct bdpt_params bdpt_defaults(void);
/* Ranges; errors name /params/<key>. */
bool bdpt_params_valid(const struct bdpt_params *p, struct err *err);
const char *bdpt_heuristic_name(enum bdpt_heuristic h);

/* Allocates the LVC for width x height and the parameters' N_L; ERR_INVALID for a scene with
 * environment light (not supported). */
bool bdpt_init(struct bdpt_state *st, const struct scene *scene, const struct bdpt_params *p, uint32_t width,
               uint32_t height, struct err *err);
void bdpt_destroy(struct bdpt_state *st);
/* Bytes bdpt_init allocates (equal to bdpt_bytes after it). */
uint64_t bdpt_bytes_planned(const struct bdpt_params *p, uint32_t width, uint32_t height);
size_t bdpt_lvc_bytes(const struct bdpt_state *st);
size_t bdpt_block_bytes(const struct bdpt_state *st);

/* Renders one frame into `out` (width x height, allocated by the caller). Allocates nothing. */
bool bdpt_render(struct bdpt_state *st, const struct bdpt_params *p, const struct method_frame *f, struct image *out,
                 struct bdpt_stats *stats, struct err *err);

/* Geometry helpers shared with restir_bdpt_*.c (the same conventions on both). */
struct accel;
struct material;
struct ray_counters;
struct surface;
/* Solid-angle pdf of an emitted direction at cosine `cos` with the emitting side's normal. */
float bdpt_emit_dir_pdf_w(const struct material *m, float cos);
/* The start of a light subpath: an emitter point by power (numbers ul, u1, u2), its side for a
 * two-sided emitter (us), a cosine-distributed direction (ud1, ud2), the throughput Le cos / p
 * and the pdfs MIS needs. False when the sample carries nothing (environment light, zero pdf or
 * emission). */
struct bdpt_light_start {
    struct light_sample ls;
    struct vec3 n;              /* the emitting side's normal */
    struct vec3 dir, org;       /* the first direction and its ray origin */
    struct vec3 beta;           /* Le cos / (pdf_a pdf_w) */
    float cos_l, emission_pdf_w;
};
bool bdpt_light_start(const struct scene *scene, const float u[6], struct bdpt_light_start *out);
/* Ray origin on the side of the geometric normal that `dir` leaves through. */
struct vec3 bdpt_origin(const struct surface *s, struct vec3 dir);
/* Whether nothing blocks the segment from a (normal na) to b (normal nb, NULL for the eye). */
bool bdpt_visible(const struct accel *accel, struct vec3 a, struct vec3 na, struct vec3 b, const struct vec3 *nb,
                  struct ray_counters *rc);
/* Light tracing (t = 1): the eye's side of joining the surface vertex s (material m, the light
 * arriving along -wo_world) to the pinhole camera, whose image plane lies at squared distance
 * plane_dist2 in pixel units. The MIS weight is the caller's: its contribution is
 * beta f · w · corr · camera_pdf_w / (dist2 N_L) in pixel (ix, iy). False when the vertex is
 * behind the camera or off the image, faces away from the eye, sends nothing towards it or is
 * hidden from it; `accel` NULL: s is known to be visible from the eye (no ray is traced). */
struct bdpt_eye_link {
    float px, py;               /* the image-plane position in pixels */
    uint32_t ix, iy;            /* its pixel */
    struct vec3 f;              /* the BSDF towards the eye (radiance side) */
    float rev_w;                /* the BSDF's pdf of wo from the eye's direction (the MIS weight's) */
    float dist2;                /* squared distance to the eye */
    float camera_pdf_w, camera_pdf_a;  /* the camera's density of the direction, and per area at s */
    float corr;                 /* Veach's adjoint shading-normal correction |wo.ns| |wc.ng| / |wo.ng| */
};
bool bdpt_eye_link(const struct camera *cam, float plane_dist2, const struct accel *accel, const struct surface *s,
                   const struct material *m, struct vec3 wo_world, struct ray_counters *rc,
                   struct bdpt_eye_link *out);
/* A light vertex cache kept in fixed per-block regions of `region` slots, in its canonical order
 * (blocks in order, each block's vertices in order): first = the prefix sums of the blocks'
 * counts (blocks + 1), total = first[blocks], scale = total / N_L. */
struct bdpt_lvc_view {
    const struct bdpt_light_vertex *v;
    const uint64_t *first;
    uint32_t blocks, region;
    uint64_t total;
    float scale;
};
/* The cached vertex drawn uniformly by u in [0, 1); NULL when the cache is empty. */
const struct bdpt_light_vertex *bdpt_lvc_pick(const struct bdpt_lvc_view *lvc, float u);
/* A connectable light vertex as the cache keeps it: the subpath's hit (its surface s), the
 * direction back along the subpath, its throughput, MIS state and surface vertex count. */
struct bdpt_mis;
struct hit;
struct bdpt_light_vertex bdpt_light_vertex_make(const struct scene *scene, const struct hit *hit,
                                                const struct surface *s, struct vec3 wo, struct vec3 beta,
                                                const struct bdpt_mis *mis, uint32_t depth);
/* What a connection's MIS weight was made of (bdpt_mis_weight_connect's arguments besides the
 * two MIS states), and the weight. */
struct bdpt_connect_pdfs {
    float cam_fwd_a, cam_rev_w, light_fwd_a, light_rev_w, w;
};
/* A vertex connection (s >= 2, t >= 2): camera vertex s (material m, incoming direction wo in its
 * shading frame, MIS state cam_mis after its hit) joined to cached light vertex v, with recursive
 * MIS over all techniques. The contribution before the camera subpath's throughput, times
 * lvc_scale = |LVC| / N_L (the vertex was drawn uniformly from the cache); *made is false when
 * the connection carries nothing. With `pdfs` (may be NULL) what its MIS weight was made of. */
struct vec3 bdpt_connect_light_vertex(const struct scene *scene, bool power, float lvc_scale, const struct surface *s,
                                      const struct material *m, struct vec3 wo, const struct bdpt_mis *cam_mis,
                                      const struct bdpt_light_vertex *v, struct ray_counters *rc, bool *made,
                                      struct bdpt_connect_pdfs *pdfs);

#endif
