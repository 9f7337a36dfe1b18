/* restir_bdpt_internal.h — what the parts of ReSTIR BDPT share (see restir_bdpt.h):
 *   restir_bdpt.c         the frame driver, parameters, buffers, the lightweight MIS, test hooks;
 *   restir_bdpt_light.c   light subpaths: the light pass, its t = 1 samples, the light-vertex cache;
 *   restir_bdpt_camera.c  the camera pass: per-pixel candidates, the caustic reservoirs and their
 *                         temporal replay;
 *   restir_bdpt_reuse.c   the non-caustic reservoir's reuse: its shifts and the x_2 cache.
 * Not part of the renderer's interface. The small helpers that the hot loops of more than one
 * part call are `static inline` here. */
#ifndef RESTIR_BDPT_INTERNAL_H
#define RESTIR_BDPT_INTERNAL_H

#include <math.h>
#include <stdatomic.h>

#include "integrators/restir_bdpt.h"
#include "integrators/bdpt_mis.h"
#include "scene/light_sampler.h"
#include "material/material.h"
#include "core/rng.h"
#include "core/sampling.h"
#include "scene/surface.h"
#include "reuse/gbuffer.h"

#define RBDPT_BLOCK_PATHS BDPT_BLOCK_PATHS   /* the light pass's blocks are bdpt's (struct bdpt_blocks) */
#define RBDPT_TILE 16u
#define RBDPT_MAX_WORKERS 1024u
/* Stream tags: light subpaths, camera subpaths (pixel index below 2^28), reservoir choices. */
#define RBDPT_LIGHT_STREAM 0x52424c0000000000ull
#define RBDPT_CAMERA_STREAM 0x5242430000000000ull
#define RBDPT_PICK_STREAM 0x5242500000000000ull
/* A lightweight camera subpath's random numbers (rbdpt_camera_candidates): the jitter's 2, then
 * per vertex the light sample's 3, the BSDF sample's 3 and the roulette's 1; the full variant's
 * draws one more after the light sample's, its choice of a cached light vertex. The shifts that
 * replay part of a subpath (rbdpt_reconnect) draw them in the same order. */
#define RBDPT_CAMERA_JITTER_DRAWS 2u
#define RBDPT_CAMERA_VERTEX_DRAWS 7u

/* A pixel's entry of the light-side cache of its sample, computed in the scene of the render
 * numbered `tick` (struct restir_bdpt_state's x2c_tick), and whose sample it is (light subpath,
 * origin frame, `depth_key`):
 *  - kind RBDPT_CACHE_X2, a t = 1 sample of the reverse hybrid shift's class: what struct
 *    rbdpt_x2 holds, less what follows from the rest (the shading frame is frame_from_normal(ns),
 *    as surface_from_hit builds it); depth_key is x_1's light depth;
 *  - kind RBDPT_CACHE_LV, a connection (s >= 2, full variant): its light vertex as the replay
 *    gives it; depth_key is the vertex's light depth. */
enum { RBDPT_CACHE_NONE, RBDPT_CACHE_X2, RBDPT_CACHE_LV };
struct rbdpt_x2_entry {
    union {
        struct {
            struct vec3 p, ng, ns;
            uint32_t shape, prim, material;
            struct vec3 wo_world, beta, rr_beta;
            float dvcm, dvc, u_rr;
            uint32_t depth;
        };
        struct bdpt_light_vertex lv;
    };
    uint32_t light_path, origin_frame, tick;
    uint16_t depth_key;
    uint8_t near;              /* bit 0: the MIS state's near, bit 1: its caster */
    uint8_t kind;
};

/* ---- per-frame context -------------------------------------------------------------------- */

/* On a cache line of its own, as bdpt.c's: these change with every ray. */
struct rbdpt_worker {
    _Alignas(64) uint64_t rays_intersect;
    uint64_t rays_occluded, candidates, rejected;
    uint64_t shifts, replay_failed, not_caustic, inverse_failed;
    uint64_t connections, unshiftable;
};

/* What a frame sees: its scene and camera (the current frame's, or the previous one's for the
 * caustic shift's inverse). */
struct rbdpt_view {
    const struct scene *scene;
    struct camera cam;
    float plane_dist2;     /* squared image-plane distance in pixel units */
};

struct rbdpt_ctx {
    const struct restir_bdpt_params *p;
    struct restir_bdpt_state *st;
    struct rbdpt_view view[2];   /* [0] current, [1] previous (valid when has_prev) */
    bool has_prev;
    uint32_t caustic_cap;        /* temporal_cap, or moving_cap when the scene moved (scene_moved) */
    float n_light;
    uint64_t seed;
    uint32_t frame;
    /* The x_2 cache's validity: entries made at renders tick_from .. tick (this render) were made
     * in this render's scene with these random streams, so they equal a replay here (rbdpt_x2_valid). */
    uint32_t tick, tick_from;
    uint32_t still_from;         /* renders after it had the view and parameters of the one before */
    bool power;
    bool full;                   /* the full variant: all techniques, an LVC */
    bool emission_apart;         /* the G-buffer's estimate of the emission seen directly stands for
                                    the camera subpaths' candidates that end on the primary hit */
    bool static_scene;           /* the previous frame's scene equals this one (scene_moved) */
    bool force_retrace;          /* tests: reconnection shifts trace every suffix again */
    _Atomic uint64_t *reconnections;  /* with reuse: hybrid shifts attempted (rbdpt_reconnect) */
    struct bdpt_lvc_view lvc;    /* full: this frame's cache, after the light pass */
    struct image *out;
    uint32_t tiles_x;
    struct rbdpt_worker worker[RBDPT_MAX_WORKERS];
};

/* Streaming RIS over candidates in primary sample space (p̂ = lum(C)). */
struct rbdpt_ris {
    double wsum;
    float target;
    struct vec3 F;
    uint16_t bits;
    uint32_t light_path, origin_frame;
    struct restir_bdpt_rc rc;   /* camera-side candidates with reuse: the selected one's reconnection */
    const struct bdpt_light_vertex *lv;   /* a selected connection's cached light vertex */
};

/* ---- shared by the parts -------------------------------------------------------------------- */

/* Whether cache entry e holds what a replay in view v would give: v is this render's scene and
 * e was made in it (this render or an earlier one since which scene, seed and the parameters
 * the light subpaths depend on are unchanged: a light subpath's vertices are a function of
 * these alone, so the entry and the replay agree to the bit). */
static inline bool rbdpt_x2_valid(const struct rbdpt_ctx *c, const struct rbdpt_view *v,
                                  const struct rbdpt_x2_entry *e)
{
    return v->scene == c->view[0].scene && e->tick >= c->tick_from && e->tick <= c->tick;
}

static inline float rbdpt_mis_f(float x, bool power) { return power ? x * x : x; }

/* The primary ray's position in the pixel of the camera subpath of (origin_frame, origin pixel):
 * the G-buffer's stratified point for that frame (gbuffer_fresh_position), the same wherever the
 * subpath is replayed. The stream's jitter draws are still consumed, so that the numbers after
 * them (RBDPT_CAMERA_JITTER_DRAWS) stay where every replay skips to. */
static inline void rbdpt_jitter(const struct rbdpt_ctx *c, uint32_t origin_frame, uint32_t origin_pixel,
                                struct rng *rng, float *jx, float *jy)
{
    for (uint32_t n = 0; n < RBDPT_CAMERA_JITTER_DRAWS; n++) (void)rng_next_u32(rng);
    gbuffer_fresh_position(c->seed, origin_pixel, origin_frame, jx, jy);
}

/* The full variant's light vertex cache of one block: `region` vertices, `count` used, the
 * excess counted in `dropped`. */
struct rbdpt_lvc_block {
    struct bdpt_light_vertex *v;
    uint32_t *path;            /* with reuse: each vertex's light subpath; NULL otherwise */
    uint32_t region, count, dropped;
};

/* A vertex the hybrid shift may reconnect at or from: every lobe of its material is rough (the
 * reconnection evaluates the whole BSDF, so a delta lobe beside a rough one would be lost). */
static inline bool rbdpt_rough(const struct material *m)
{
    unsigned f = material_flags(m);
    return (f & (BSDF_DIFFUSE | BSDF_GLOSSY)) && !(f & BSDF_DELTA);
}

/* A caustic caster: a material with a delta lobe, or a glossy lobe smoother than GGX alpha
 * RBDPT_CASTER_ROUGHNESS (restir_pt's default roughness_min for reconnection, below which a lobe
 * counts as near-specular). The light a diffuse surface receives off one is found by the camera's
 * techniques only through a narrow lobe, by light tracing easily. */
#define RBDPT_CASTER_ROUGHNESS 0.2f
static inline bool rbdpt_caster(const struct material *m)
{
    return material_near_specular(m, RBDPT_CASTER_ROUGHNESS);
}
/* The lightweight variant's techniques of a path: s = 0 and s = 1 always, t = 1 only if one of
 * its scattering vertices x_1 .. x_{k-1} is a caustic caster. A path without one is one the
 * camera's techniques sample well, and a light-traced sample of it lands in a pixel by chance: it
 * adds variance to the reservoirs and, spread by the spatial passes, to the neighbours
 * (docs/benchmarks.md, "Light subpaths where nothing is specular"). Both subpaths call this at
 * every scattering vertex, so the choice is a function of the path and the weights stay a
 * partition of unity on each. */
static inline void rbdpt_mis_vertex(struct restir_bdpt_mis *mis, const struct material *m)
{
    if (rbdpt_caster(m)) mis->caster = true;
}

/* Whether the t = 1 technique's terms count in the weights of the path `mis` has seen. */
static inline bool rbdpt_mis_keeps_t1(const struct restir_bdpt_mis *mis)
{
    return mis->full || mis->caster;
}

/* A light subpath's vertex x_2 (light depth `depth` >= 1) as it was before it scattered towards
 * x_1: what the reverse hybrid shift keeps of a t = 1 sample and joins to a new x_1. */
struct rbdpt_x2 {
    struct surface s;
    const struct material *m;
    struct vec3 wo_world;        /* towards the previous light vertex */
    struct vec3 beta, rr_beta;   /* before its scattering */
    struct restir_bdpt_mis mis;  /* after its hit */
    struct vec3 dir;             /* the direction it sampled (the base path's x_1 lies along it) */
    float u_rr;                  /* the roulette's number after its scattering */
    uint32_t depth;
};

/* Light subpath i of frame `origin_frame`: its random stream, and its start on an emitter drawn
 * from the stream's first six numbers (the rest of the stream scatters the subpath). */
static inline bool rbdpt_light_stream(const struct rbdpt_ctx *c, const struct scene *scene, uint32_t origin_frame,
                                      uint32_t i, struct rng *rng, struct bdpt_light_start *start)
{
    *rng = rng_make(c->seed, origin_frame, RBDPT_LIGHT_STREAM + i, 1);
    float u[6];
    for (int k = 0; k < 6; k++) u[k] = rng_next_float(rng);
    return bdpt_light_start(scene, u, start);
}

/* Next-event estimation's light sample for a vertex at p from three random numbers: the
 * direction to it, its emitted radiance towards p, its solid-angle density at p and its emission
 * density (the MIS weight's). False when there is none or it carries nothing. */
struct rbdpt_nee {
    struct light_sample ls;
    struct vec3 wi_world, Le;
    float cos_l, direct_pdf_w, emission_pdf_w;
};

static inline bool rbdpt_nee_sample(const struct scene *scene, struct vec3 p, float ul, float u1, float u2,
                                    struct rbdpt_nee *out)
{
    if (!light_sampler_sample(scene->lights, ul, u1, u2, &out->ls) || out->ls.is_env) return false;
    struct vec3 d = vec3_sub(out->ls.p, p);
    float d2 = vec3_length2(d);
    if (!(d2 > 0.0f)) return false;
    out->wi_world = vec3_scale(d, 1.0f / sqrtf(d2));
    out->cos_l = -vec3_dot(out->wi_world, out->ls.n);
    const struct material *lm = out->ls.material;
    out->Le = light_sampler_emitted(lm, out->cos_l);
    out->direct_pdf_w = sampling_area_to_solid_angle(out->ls.pdf_a, d2, out->cos_l);
    if (!(out->direct_pdf_w > 0.0f) || vec3_is_zero(out->Le)) return false;
    out->emission_pdf_w = out->ls.pdf_a * bdpt_emit_dir_pdf_w(lm, out->cos_l);
    return true;
}

enum rbdpt_replay { RBDPT_REPLAY_OK, RBDPT_REPLAY_FAILED, RBDPT_REPLAY_NOT_CAUSTIC };

/* Whether a non-caustic sample is a connection (s >= 2, the full variant's). */
static inline bool rbdpt_is_connection(const struct restir_bdpt_path *x)
{
    const uint32_t tech = x->r.head.bits & 0xffu;
    return tech >= 2u && tech != RESTIR_BDPT_TECH_LT;
}

/* The full variant's recursive reconnection MIS ([ReSTIR BDPT §6.2–6.3], in dVCM / dVC form). Past
 * x_k's scattering every update of a camera subpath's MIS state is affine in that state: a hit
 * scales both quantities, a rough scattering sets dVCM to a constant and makes dVC a linear
 * combination of the two, a delta one zeroes dVCM and scales dVC. So the state where a
 * candidate is made is M (dVCM_k, dVC_k) + o, (dVCM_k, dVC_k) the state right after x_k's
 * scattering; M's columns are carried along the suffix from (1, 0) and (0, 1) by the linear
 * part of the updates, o from (0, 0) by the updates themselves (rbdpt_suffix_basis,
 * rbdpt_suffix_scatter). Every technique's weight is 1 / (1 + K0 + K1 dVCM + K2 dVC) in that
 * state, with K >= 0 fixed by the candidate, so 1 / w = 1 + a dVCM_k + b dVC_k + c, a, b, c sums
 * of non-negative terms (no cancellation). The shift recomputes the weight from its new prefix
 * alone: eqs. 42–47's content, in three constants. */
static inline void rbdpt_suffix_basis(struct restir_bdpt_mis basis[3])
{
    basis[0] = (struct restir_bdpt_mis){0.0f, 0.0f, true, true};
    basis[1] = (struct restir_bdpt_mis){1.0f, 0.0f, true, true};
    basis[2] = (struct restir_bdpt_mis){0.0f, 1.0f, true, true};
}

static inline void rbdpt_suffix_scatter(struct restir_bdpt_mis basis[3], float cos_out, float pdf_fwd_w,
                                        float pdf_rev_w, bool delta, bool power)
{
    for (int j = 0; j < 3; j++) restir_bdpt_mis_scatter(&basis[j], cos_out, pdf_fwd_w, pdf_rev_w, delta, power);
    basis[1].dvcm = basis[2].dvcm = 0.0f;   /* the constant a rough scattering sets belongs to o */
}

/* a, b, c from the carried states and the candidate's K. */
static inline void rbdpt_full_constants(const struct restir_bdpt_mis basis[3], float K0, float K1, float K2,
                                        struct restir_bdpt_rc *rc)
{
    rc->mis_a = K1 * basis[1].dvcm + K2 * basis[1].dvc;
    rc->mis_b = K1 * basis[2].dvcm + K2 * basis[2].dvc;
    rc->mis_c = K0 + K1 * basis[0].dvcm + K2 * basis[0].dvc;
}

/* The weight from those constants and the state after x_k's scattering on the shifted path. */
static inline float rbdpt_full_weight(const struct restir_bdpt_rc *rc, const struct restir_bdpt_mis *at_k)
{
    return 1.0f / (1.0f + rc->mis_a * at_k->dvcm + rc->mis_b * at_k->dvc + rc->mis_c);
}

/* Random numbers a camera subpath draws per vertex (RBDPT_CAMERA_VERTEX_DRAWS). */
static inline uint32_t rbdpt_vertex_draws(const struct rbdpt_ctx *c)
{
    return RBDPT_CAMERA_VERTEX_DRAWS + (c->full ? 1u : 0u);
}

/* With `want` set, the camera subpath is a random replay (the shift of a camera-path sample
 * without a reconnection, or the re-traced suffix of one with): no candidate is resampled, and
 * the contribution of the one whose technique and length are want->bits is returned in want->C
 * (want->found), its reconnection record in want->rc. Its reconnection must be at want->k (0:
 * none): the hybrid shift's classes map onto themselves, or the shift would not be
 * invertible. */
struct rbdpt_want {
    uint16_t bits;
    uint32_t k;
    const struct bdpt_light_vertex *lv;   /* s >= 2: the sample's light vertex, replayed, and */
    uint32_t lv_path;                     /* its light subpath */
    bool found;
    struct vec3 C;
    struct restir_bdpt_rc rc;
};

/* A camera subpath resumed past its reconnection vertex x_k (k >= 2): the hybrid shift between
 * frames whose scenes differ re-traces the suffix in the target scene from x_k along w_k with the
 * sample's own random numbers (the rng given is advanced to vertex k + 1), as ReSTIR PT does.
 * The state after x_k's scattering on the shifted path, and x_k's record (k, point code, w_k,
 * Jacobian denominator); L and the MIS constants are found anew. */
struct rbdpt_resume {
    struct vec3 org, dir, prev_p, beta;
    struct restir_bdpt_mis mis;
    struct restir_bdpt_rc rc;
};

/* ---- restir_bdpt_light.c ------------------------------------------------------------------ */

/* The light pass (rbdpt_light_block, one parallel_run job per block of light subpaths) and the
 * replays of one light subpath that the camera pass and the shifts ask for. */
bool rbdpt_t1_eval(const struct rbdpt_ctx *c, const struct rbdpt_view *v, const struct rbdpt_x2 *x2,
                   const struct surface *x1, bool eye_sees, struct ray_counters *rays, uint32_t *pixel,
                   struct vec3 *C, float sub[2], float *pdf, float *mis_w);
bool rbdpt_trace_light(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t origin_frame,
                       uint32_t i, uint32_t only_depth, struct restir_bdpt_lt_sample *out, uint32_t cap,
                       uint32_t *stored, uint32_t *dropped, uint64_t *vertices, struct rbdpt_lvc_block *lvc,
                       struct rbdpt_x2 *x2_out, struct ray_counters *rc);
void rbdpt_light_block(void *ctx, uint32_t block, unsigned worker);
void rbdpt_light_vertex_keep(const struct rbdpt_ctx *c, uint32_t pixel, const struct restir_bdpt_path *src,
                             const struct bdpt_light_vertex *lv);
bool rbdpt_light_vertex_of(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t pixel,
                           const struct restir_bdpt_path *src, bool keep, struct bdpt_light_vertex *lv,
                           struct ray_counters *rays);

/* ---- restir_bdpt_camera.c ----------------------------------------------------------------- */

/* The camera pass (rbdpt_camera_tile) and the caustic history's replay (rbdpt_history_row), both
 * parallel_run jobs; rbdpt_camera_candidates also replays a camera subpath for the shifts. */
void rbdpt_camera_candidates(const struct rbdpt_ctx *c, const struct rbdpt_view *v, struct vec3 dir,
                             uint32_t pixel, uint32_t frame, struct rng *rng, struct rng *pick,
                             struct rbdpt_ris *r, struct ray_counters *rc, struct rbdpt_worker *wk,
                             struct vec3 *primary, bool *has_primary, struct rbdpt_want *want,
                             const struct rbdpt_resume *resume);
enum rbdpt_replay rbdpt_replay_caustic(const struct rbdpt_ctx *c, const struct rbdpt_view *v,
                                       uint32_t origin_frame, uint32_t i, uint32_t depth, uint32_t *pixel,
                                       struct vec3 *F, struct ray_counters *rc);
void rbdpt_camera_tile(void *ctx, uint32_t tile, unsigned worker);
void rbdpt_history_row(void *ctx, uint32_t row, unsigned worker);

/* ---- restir_bdpt_reuse.c ------------------------------------------------------------------ */

/* The non-caustic reservoir's shifts (rbdpt_ops, for restir.c's passes), the cache fill before
 * the spatial pass (rbdpt_x2_row, a parallel_run job), and what the camera pass asks of them. */
bool rbdpt_reverse_record(const struct rbdpt_ctx *c, uint32_t pixel, struct restir_bdpt_path *res,
                          struct ray_counters *rays);
bool rbdpt_reaches_primary(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t origin_frame,
                           uint32_t light_path, uint32_t depth, const struct surface *xg,
                           struct ray_counters *rays);
void rbdpt_shift(const void *ctx, const void *src_v, struct restir_domain from, struct restir_domain to,
                 void *dst_v, float *target, float *jacobian, struct restir_counters *cnt);
void rbdpt_x2_row(void *ctx, uint32_t row, unsigned worker);
extern const struct restir_ops rbdpt_ops;

#endif
