/* restir_bdpt.c — ReSTIR BDPT, lightweight and full variants: initial resampling (see restir_bdpt.h).
 *
 * Conventions as bdpt.c (radiance-side BSDF values on both subpaths, Veach's adjoint
 * shading-normal correction on the light side, pinhole camera sampled with density 1 per pixel).
 *
 * Lightweight MIS. A path x_0 .. x_k (x_0 the camera, x_k on an emitter) is produced here by at
 * most three techniques: s = 0 (the camera subpath hits x_k), s = 1 (NEE from x_{k-1}) and
 * t = 1 (a light subpath reaches x_1 and connects to the eye), with the power or balance
 * heuristic over exactly these three. The quantities are SmallVCM's dVCM / dVC (bdpt_mis.h)
 * with every term of a vertex-connection technique left out: on either subpath, dVCM before
 * the first scattering names the far end's nearest technique that we keep (t = 1 on the
 * camera side; s = 1 on the light side, whose dVC at the start is s = 0), and after it dVCM
 * names a connection technique (dropped from dVC's accumulation and from every weight), while
 * dVC carries only the kept far-end techniques. The emitter-hit weight's dVCM term is s = 1
 * itself and stays. Keeping dVCM after the first scattering as well (`full`) restores exactly
 * the terms left out, and these functions then compute bdpt_mis.h's weights over all techniques
 * (tests/unit/test_restir_bdpt.c compares the two): the full variant's MIS.
 *
 * Resampling. In primary sample space every candidate X_i has source pdf 1 and target
 * p̂(X_i) = lum(C_i), C_i = w_i f / p the MIS-weighted contribution: its resampling weight is
 * lum(C_i), W = sum / p̂(Y) and the pixel estimate C_Y W. Candidates from distinct techniques
 * (and path lengths) live in disjoint parts of the extended path space, each with one candidate
 * per pixel from the camera side; the t = 1 part gets N_L candidates per pixel — one per light
 * subpath, most of them null for this pixel — each with the MIS weight 1/N_L (seed 000 eq. 26),
 * which C already carries. So the merge is unbiased whatever lands where. */
#include "integrators/restir_bdpt.h"

#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "scene/accel.h"
#include "integrators/bdpt_mis.h"
#include "scene/light_sampler.h"
#include "material/material.h"
#include "core/parallel.h"
#include "core/rng.h"
#include "core/sampling.h"
#include "scene/surface.h"

#define RBDPT_BLOCK_PATHS 256u
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

_Static_assert(sizeof(struct restir_bdpt_reservoir) == RESTIR_BDPT_RESERVOIR_BYTES, "restir_bdpt_reservoir changed size");
_Static_assert(sizeof(struct restir_bdpt_shifted) == 32, "restir_bdpt_shifted changed size");
_Static_assert(sizeof(struct restir_bdpt_path) == RESTIR_BDPT_PATH_BYTES, "restir_bdpt_path changed size");

/* ---- lightweight MIS ---------------------------------------------------------------------- */

static inline float rbdpt_mis_f(float x, bool power) { return power ? x * x : x; }

struct restir_bdpt_mis restir_bdpt_mis_camera_start(float light_paths, float camera_pdf_w, bool power)
{
    return (struct restir_bdpt_mis){rbdpt_mis_f(light_paths / camera_pdf_w, power), 0.0f, true, false};
}

struct restir_bdpt_mis restir_bdpt_mis_light_start(float direct_pdf_a, float emission_pdf_w, float cos_light,
                                                   bool power)
{
    return (struct restir_bdpt_mis){rbdpt_mis_f(direct_pdf_a / emission_pdf_w, power),
                                    rbdpt_mis_f(cos_light / emission_pdf_w, power), true, false};
}

void restir_bdpt_mis_hit(struct restir_bdpt_mis *m, float dist2, float cos_hit, bool power)
{
    float c = rbdpt_mis_f(fabsf(cos_hit), power);
    m->dvcm *= rbdpt_mis_f(dist2, power) / c;
    m->dvc /= c;
}

void restir_bdpt_mis_scatter(struct restir_bdpt_mis *m, float cos_out, float pdf_fwd_w, float pdf_rev_w, bool delta,
                             bool power)
{
    float c = fabsf(cos_out);
    if (delta) {
        m->dvcm = 0.0f;
        m->dvc *= rbdpt_mis_f(c * pdf_rev_w / pdf_fwd_w, power);
    } else {
        m->dvc = rbdpt_mis_f(c / pdf_fwd_w, power) * (m->dvc * rbdpt_mis_f(pdf_rev_w, power) + (m->near ? m->dvcm : 0.0f));
        m->dvcm = rbdpt_mis_f(1.0f / pdf_fwd_w, power);
    }
    m->near = m->full;
}

float restir_bdpt_mis_emission(const struct restir_bdpt_mis *cam, float direct_pdf_a, float emission_pdf_w, bool power)
{
    return 1.0f / (1.0f + rbdpt_mis_f(direct_pdf_a, power) * cam->dvcm + rbdpt_mis_f(emission_pdf_w, power) * cam->dvc);
}

float restir_bdpt_mis_nee(const struct restir_bdpt_mis *cam, float bsdf_fwd_w, float bsdf_rev_w, float direct_pdf_w,
                          float emission_pdf_w, float cos_camera, float cos_light, bool power)
{
    float w_light = rbdpt_mis_f(bsdf_fwd_w / direct_pdf_w, power);
    float w_camera = rbdpt_mis_f(emission_pdf_w * fabsf(cos_camera) / (direct_pdf_w * fabsf(cos_light)), power) *
                     ((cam->near ? cam->dvcm : 0.0f) + cam->dvc * rbdpt_mis_f(bsdf_rev_w, power));
    return 1.0f / (w_light + 1.0f + w_camera);
}

float restir_bdpt_mis_camera(const struct restir_bdpt_mis *light, float camera_pdf_a, float light_paths,
                             float light_rev_w, bool power)
{
    float w_light = rbdpt_mis_f(camera_pdf_a / light_paths, power) *
                    ((light->near ? light->dvcm : 0.0f) + light->dvc * rbdpt_mis_f(light_rev_w, power));
    return 1.0f / (w_light + 1.0f);
}

void restir_bdpt_rc_mis_emission(const struct restir_bdpt_mis *cam, float direct_pdf_a, float emission_pdf_w,
                                 float dist2, float cos_end, bool last, float suffix, bool power, float *a, float *b)
{
    float c = rbdpt_mis_f(fabsf(cos_end), power);
    if (last) {
        /* dVCM at the emitter is Mis(1 / p_fwd(x_k)) Mis(d^2) / Mis(|cos|), dVC = dVC_k / Mis(|cos|). */
        *a = rbdpt_mis_f(direct_pdf_a, power) * rbdpt_mis_f(dist2, power) / c;
        *b = rbdpt_mis_f(emission_pdf_w, power) / c;
    } else {
        *a = 1.0f + rbdpt_mis_f(direct_pdf_a, power) * cam->dvcm;
        *b = rbdpt_mis_f(emission_pdf_w, power) * suffix;
    }
}

void restir_bdpt_rc_mis_nee(float bsdf_fwd_w, float bsdf_rev_w, float direct_pdf_w,
                            float emission_pdf_w, float cos_camera, float cos_light, bool last, float suffix,
                            bool power, float *a, float *b)
{
    /* k >= 2: the NEE vertex has scattered before, so dVCM names no kept technique (near is false). */
    float K = rbdpt_mis_f(emission_pdf_w * fabsf(cos_camera) / (direct_pdf_w * fabsf(cos_light)), power);
    if (last) {
        *a = 1.0f / direct_pdf_w;
        *b = K;
    } else {
        *a = rbdpt_mis_f(bsdf_fwd_w / direct_pdf_w, power) + 1.0f;
        *b = K * rbdpt_mis_f(bsdf_rev_w, power) * suffix;
    }
}

float restir_bdpt_mis_reconnect(enum restir_bdpt_rc_kind kind, float a, float b, const struct restir_bdpt_mis *m,
                                float pdf_fwd, float pdf_rev, bool power)
{
    switch (kind) {
    case RBDPT_RC_AFTER: return 1.0f / (a + b * m->dvc);
    case RBDPT_RC_EMIT_LAST: return 1.0f / (1.0f + a * rbdpt_mis_f(1.0f / pdf_fwd, power) + b * m->dvc);
    case RBDPT_RC_NEE_LAST:
        return 1.0f / (rbdpt_mis_f(pdf_fwd * a, power) + 1.0f + b * m->dvc * rbdpt_mis_f(pdf_rev, power));
    }
    return 0.0f;
}

/* ---- parameters and sizes ----------------------------------------------------------------- */

struct restir_bdpt_params restir_bdpt_defaults(void)
{
    return (struct restir_bdpt_params){.variant = RESTIR_BDPT_LIGHTWEIGHT, .max_depth = 64, .rr_depth = 3,
                                       .light_paths = 0, .lt_capacity = 8, .lvc_capacity = 8,
                                       .heuristic = BDPT_HEURISTIC_POWER,
                                       .caustic_temporal = true, .temporal_cap = 20, .moving_cap = 1, .reuse = false,
                                       .spatial_neighbors = 2, .spatial_radius = 30.0f, .paired_spatial = true,
                                       .camera_reconnect = true, .copy_mis = false,
                                       .reject_unshiftable = false};
}

bool restir_bdpt_params_valid(const struct restir_bdpt_params *p, struct err *err)
{
    if (p->variant != RESTIR_BDPT_LIGHTWEIGHT && p->variant != RESTIR_BDPT_FULL)
        return err_set(err, ERR_INVALID, "/params/variant", "variant must be \"lightweight\" or \"full\"");
    if (p->copy_mis && !p->reuse)
        return err_set(err, ERR_INVALID, "/params/copy_mis",
                       "copy_mis changes the shifts of the non-caustic reuse: it needs \"reuse\": true");
    if (p->copy_mis && p->variant == RESTIR_BDPT_FULL)
        return err_set(err, ERR_INVALID, "/params/copy_mis",
                       "copy_mis is a shortcut of the lightweight variant's reconnection shift; the full variant "
                       "recomputes the MIS weight of every shifted path");
    /* A sample keeps its vertex count (depth + 2) in 8 bits of head.bits. */
    if (p->max_depth < 1 || p->max_depth > RESTIR_BDPT_MAX_DEPTH)
        return err_set(err, ERR_INVALID, "/params/max_depth", "max_depth must be in 1..%u", RESTIR_BDPT_MAX_DEPTH);
    if (p->rr_depth > 1024) return err_set(err, ERR_INVALID, "/params/rr_depth", "rr_depth must be in 0..1024");
    if (p->light_paths > (1u << 26))
        return err_set(err, ERR_INVALID, "/params/light_paths", "light_paths must be in 0..%u (0 = the pixel count)",
                       1u << 26);
    if (p->lt_capacity < 1 || p->lt_capacity > 64)
        return err_set(err, ERR_INVALID, "/params/lt_capacity", "lt_capacity must be in 1..64");
    if (p->lvc_capacity < 1 || p->lvc_capacity > 64)
        return err_set(err, ERR_INVALID, "/params/lvc_capacity", "lvc_capacity must be in 1..64");
    if (p->heuristic != BDPT_HEURISTIC_POWER && p->heuristic != BDPT_HEURISTIC_BALANCE)
        return err_set(err, ERR_INVALID, "/params/heuristic", "heuristic must be \"power\" or \"balance\"");
    if (p->temporal_cap < 1 || p->temporal_cap > 65535)
        return err_set(err, ERR_INVALID, "/params/temporal_cap", "temporal_cap must be in 1..65535");
    if (p->moving_cap < 1 || p->moving_cap > 65535)
        return err_set(err, ERR_INVALID, "/params/moving_cap", "moving_cap must be in 1..65535");
    if (p->spatial_neighbors > 32)
        return err_set(err, ERR_INVALID, "/params/spatial_neighbors", "spatial_neighbors must be in 0..32");
    if (!(p->spatial_radius > 0.0f && p->spatial_radius <= 256.0f))
        return err_set(err, ERR_INVALID, "/params/spatial_radius", "spatial_radius must be in (0, 256]");
    return true;
}

const char *restir_bdpt_variant_name(enum restir_bdpt_variant v)
{
    return v == RESTIR_BDPT_FULL ? "full" : "lightweight";
}

bool restir_bdpt_variant_parse(const char *name, enum restir_bdpt_variant *out)
{
    if (strcmp(name, "lightweight") == 0) *out = RESTIR_BDPT_LIGHTWEIGHT;
    else if (strcmp(name, "full") == 0) *out = RESTIR_BDPT_FULL;
    else return false;
    return true;
}

struct rbdpt_sizes {
    uint32_t light_paths, blocks, region, lvc_region;
    uint64_t lt, pixels, blocks_b, res, lvc, pairs, x2c;
};

/* A pixel's entry of the light-side cache of its sample, computed in frame `frame`'s scene, and
 * whose sample it is (light subpath, origin frame, `depth_key`):
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
    uint32_t light_path, origin_frame, frame;
    uint16_t depth_key;
    uint8_t near, kind;
};

static struct rbdpt_sizes rbdpt_sizes_of(const struct restir_bdpt_params *p, uint32_t width, uint32_t height)
{
    struct rbdpt_sizes z;
    uint64_t n = (uint64_t)width * height;
    z.light_paths = p->light_paths ? p->light_paths : (uint32_t)n;
    z.blocks = (z.light_paths + RBDPT_BLOCK_PATHS - 1) / RBDPT_BLOCK_PATHS;
    z.region = RBDPT_BLOCK_PATHS * p->lt_capacity;
    z.lt = 2 * (uint64_t)z.blocks * z.region * sizeof(struct restir_bdpt_lt_sample);
    z.pixels = (n + 1) * sizeof(uint32_t);
    z.blocks_b = (uint64_t)z.blocks * (2 * sizeof(uint32_t) + 3 * sizeof(uint64_t));
    z.res = (p->reuse ? 3 : 1) * n * sizeof(struct restir_bdpt_path) + 2 * n * sizeof(struct restir_bdpt_reservoir) +
            2 * n * sizeof(struct restir_bdpt_shifted) +
            (n + 1) * sizeof(uint32_t) + (p->reuse ? n * sizeof(struct gbuffer_pixel) : 0);
    /* The full variant's LVC: the vertices, per block its count, its dropped count and its
     * prefix sum (one more). */
    z.pairs = p->reuse && p->paired_spatial ? restir_pair_scratch_bytes(width, height) : 0;
    z.x2c = p->reuse ? n * sizeof(struct rbdpt_x2_entry) : 0;
    bool full = p->variant == RESTIR_BDPT_FULL;
    z.lvc_region = full ? RBDPT_BLOCK_PATHS * p->lvc_capacity : 0;
    z.lvc = full ? (uint64_t)z.blocks * z.lvc_region *
                           (sizeof(struct bdpt_light_vertex) + (p->reuse ? sizeof(uint32_t) : 0)) +
                       (uint64_t)z.blocks * 2 * sizeof(uint32_t) + ((uint64_t)z.blocks + 1) * sizeof(uint64_t)
                 : 0;
    return z;
}

uint64_t restir_bdpt_bytes_planned(const struct restir_bdpt_params *p, uint32_t width, uint32_t height)
{
    struct rbdpt_sizes z = rbdpt_sizes_of(p, width, height);
    return z.lt + z.pixels + z.blocks_b + z.res + z.lvc + z.pairs + z.x2c;
}

size_t restir_bdpt_x2_bytes(const struct restir_bdpt_state *st)
{
    return st->x2c ? (size_t)st->width * st->height * sizeof *st->x2c : 0;
}

size_t restir_bdpt_pair_bytes(const struct restir_bdpt_state *st)
{
    return st->pair_scratch ? restir_pair_scratch_bytes(st->width, st->height) : 0;
}

size_t restir_bdpt_lvc_bytes(const struct restir_bdpt_state *st)
{
    if (!st->lvc) return 0;
    return (size_t)st->blocks * st->lvc_region * (sizeof *st->lvc + (st->lvc_path ? sizeof *st->lvc_path : 0)) +
           (size_t)st->blocks * (sizeof *st->lvc_count + sizeof *st->lvc_dropped) +
           ((size_t)st->blocks + 1) * sizeof *st->lvc_first;
}

size_t restir_bdpt_reservoir_bytes(const struct restir_bdpt_state *st)
{
    size_t n = (size_t)st->width * st->height;
    return (st->res_prev ? 3 : 1) * n * sizeof *st->res + 2 * n * sizeof *st->caustic;
}

size_t restir_bdpt_lt_bytes(const struct restir_bdpt_state *st)
{
    return 2 * (size_t)st->blocks * st->region * sizeof *st->lt;
}

size_t restir_bdpt_shift_bytes(const struct restir_bdpt_state *st)
{
    return 2 * (size_t)st->width * st->height * sizeof *st->shifted;
}

size_t restir_bdpt_bucket_bytes(const struct restir_bdpt_state *st)
{
    size_t n = (size_t)st->width * st->height;
    return (n + 1) * sizeof *st->pixel_first + (n + 1) * sizeof *st->shift_first;
}

size_t restir_bdpt_block_bytes(const struct restir_bdpt_state *st)
{
    return (size_t)st->blocks * (sizeof *st->block_count + sizeof *st->block_dropped + 3 * sizeof *st->block_rays);
}

size_t restir_bdpt_bytes(const struct restir_bdpt_state *st)
{
    return restir_bdpt_reservoir_bytes(st) + restir_bdpt_lt_bytes(st) + restir_bdpt_shift_bytes(st) +
           restir_bdpt_bucket_bytes(st) + restir_bdpt_block_bytes(st) + gbuffer_bytes(&st->gbuf) +
           restir_bdpt_lvc_bytes(st) + restir_bdpt_pair_bytes(st) + restir_bdpt_x2_bytes(st);
}

bool restir_bdpt_init(struct restir_bdpt_state *st, const struct scene *scene, const struct restir_bdpt_params *p,
                      uint32_t width, uint32_t height, struct err *err)
{
    memset(st, 0, sizeof *st);
    if (!restir_bdpt_params_valid(p, err)) return false;
    if (!vec3_is_zero(scene->env_radiance))
        return err_set(err, ERR_INVALID, "/method",
                       "restir_bdpt does not support environment light (the scene has env_radiance)");
    if (scene_has_translucent(scene))
        return err_set(err, ERR_INVALID, "/method",
                       "restir_bdpt does not sample subsurface scattering (the scene has translucent materials)");
    struct rbdpt_sizes z = rbdpt_sizes_of(p, width, height);
    if (z.light_paths == 0) return err_set(err, ERR_INVALID, "/params/light_paths", "no light subpaths");
    size_t n = (size_t)width * height;
    st->width = width;
    st->height = height;
    st->light_paths = z.light_paths;
    st->blocks = z.blocks;
    st->region = z.region;
    size_t lt_n = (size_t)z.blocks * z.region;
    st->lt = malloc(lt_n * sizeof *st->lt);
    st->lt_sorted = malloc(lt_n * sizeof *st->lt_sorted);
    st->pixel_first = calloc(n + 1, sizeof *st->pixel_first);
    st->block_count = calloc(z.blocks, sizeof *st->block_count);
    st->block_dropped = calloc(z.blocks, sizeof *st->block_dropped);
    st->block_rays = calloc(3 * (size_t)z.blocks, sizeof *st->block_rays);
    st->res = calloc(n, sizeof *st->res);
    st->caustic = calloc(n, sizeof *st->caustic);
    st->caustic_prev = calloc(n, sizeof *st->caustic_prev);
    st->shifted = calloc(n, sizeof *st->shifted);
    st->shifted_sorted = calloc(n, sizeof *st->shifted_sorted);
    st->shift_first = calloc(n + 1, sizeof *st->shift_first);
    if (p->reuse) {
        st->res_prev = calloc(n, sizeof *st->res_prev);
        st->res_spatial = calloc(n, sizeof *st->res_spatial);
        if (p->paired_spatial) st->pair_scratch = restir_buffer_alloc(1, z.pairs);
        st->x2c = calloc(n, sizeof *st->x2c);
        if (st->res_prev && st->res_spatial && !gbuffer_init(&st->gbuf, width, height, err)) {
            restir_bdpt_destroy(st);
            return false;
        }
    }
    if (p->variant == RESTIR_BDPT_FULL) {
        st->lvc_region = z.lvc_region;
        st->lvc = malloc((size_t)z.blocks * z.lvc_region * sizeof *st->lvc);
        st->lvc_count = calloc(z.blocks, sizeof *st->lvc_count);
        st->lvc_dropped = calloc(z.blocks, sizeof *st->lvc_dropped);
        st->lvc_first = calloc((size_t)z.blocks + 1, sizeof *st->lvc_first);
        if (p->reuse) st->lvc_path = malloc((size_t)z.blocks * z.lvc_region * sizeof *st->lvc_path);
    }
    if (!st->lt || !st->lt_sorted || !st->pixel_first || !st->block_count || !st->block_dropped || !st->block_rays ||
        !st->res || !st->caustic || !st->caustic_prev || !st->shifted || !st->shifted_sorted || !st->shift_first ||
        (p->reuse && (!st->res_prev || !st->res_spatial || !st->x2c || (p->paired_spatial && !st->pair_scratch))) ||
        (p->variant == RESTIR_BDPT_FULL && (!st->lvc || !st->lvc_count || !st->lvc_dropped || !st->lvc_first ||
                                             (p->reuse && !st->lvc_path)))) {
        restir_bdpt_destroy(st);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for restir_bdpt (%llu bytes)",
                       (unsigned long long)restir_bdpt_bytes_planned(p, width, height));
    }
    return true;
}

void restir_bdpt_destroy(struct restir_bdpt_state *st)
{
    free(st->lt);
    free(st->lt_sorted);
    free(st->pixel_first);
    free(st->block_count);
    free(st->block_dropped);
    free(st->block_rays);
    free(st->res);
    free(st->caustic);
    free(st->caustic_prev);
    free(st->shifted);
    free(st->shifted_sorted);
    free(st->shift_first);
    free(st->res_prev);
    free(st->res_spatial);
    free(st->pair_scratch);
    free(st->x2c);
    free(st->lvc);
    free(st->lvc_path);
    free(st->lvc_count);
    free(st->lvc_dropped);
    free(st->lvc_first);
    gbuffer_destroy(&st->gbuf);
    memset(st, 0, sizeof *st);
}

void restir_bdpt_reset(struct restir_bdpt_state *st)
{
    st->has_history = false;
}

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
    bool power;
    bool full;                   /* the full variant: all techniques, an LVC */
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

/* Adds a candidate of contribution C (p̂ = lum(C)) with resampling weight w; `rc` its
 * reconnection (NULL: none). True when it is selected (so far). */
static bool rbdpt_ris_add_rc(struct rbdpt_ris *r, struct vec3 C, double w, uint16_t bits, uint32_t light_path,
                             uint32_t origin_frame, const struct restir_bdpt_rc *rc, struct rng *pick,
                             struct rbdpt_worker *wk)
{
    if (!(w > 0.0)) return false;
    if (!isfinite(w) || !vec3_is_finite(C)) {
        wk->rejected++;
        return false;
    }
    r->wsum += w;
    if ((double)rng_next_float(pick) * r->wsum >= w) return false;
    r->target = vec3_luminance(C);
    r->F = C;
    r->bits = bits;
    r->light_path = light_path;
    r->origin_frame = origin_frame;
    r->lv = NULL;
    if (rc) r->rc = *rc;
    else memset(&r->rc, 0, sizeof r->rc);
    return true;
}

static void rbdpt_ris_add_w(struct rbdpt_ris *r, struct vec3 C, double w, uint16_t bits, uint32_t light_path,
                            uint32_t origin_frame, struct rng *pick, struct rbdpt_worker *wk)
{
    rbdpt_ris_add_rc(r, C, w, bits, light_path, origin_frame, NULL, pick, wk);
}

/* An initial candidate: source pdf 1 in primary sample space, weight p̂ = lum(C). */
static void rbdpt_ris_add(struct rbdpt_ris *r, struct vec3 C, uint16_t bits, uint32_t light_path,
                          uint32_t origin_frame, struct rng *pick, struct rbdpt_worker *wk)
{
    rbdpt_ris_add_w(r, C, vec3_luminance(C), bits, light_path, origin_frame, pick, wk);
}

static void rbdpt_ris_finish(const struct rbdpt_ris *r, uint16_t M, struct restir_bdpt_reservoir *out)
{
    out->head.M = M;
    out->head.bits = r->bits;
    out->head.W = r->target > 0.0f ? (float)(r->wsum / r->target) : 0.0f;
    out->F = r->target > 0.0f ? r->F : vec3_splat(0.0f);
    out->light_path = r->light_path;
    out->origin_frame = r->origin_frame;
}

static void rbdpt_ris_finish_path(const struct rbdpt_ris *r, uint16_t M, struct restir_bdpt_path *out)
{
    rbdpt_ris_finish(r, M, &out->r);
    out->rc = r->rc;
}

/* t = 1: the light vertex at `s` seen by the eye of view `v`; lightweight MIS. */
static bool rbdpt_connect_camera(const struct rbdpt_ctx *c, const struct rbdpt_view *v, const struct surface *s,
                                 const struct material *m, struct vec3 wo_world, struct vec3 beta,
                                 const struct restir_bdpt_mis *mis, struct ray_counters *rc, uint32_t *pixel,
                                 struct vec3 *value, float sub[2], float *camera_pdf_a_out, float *mis_out)
{
    const struct camera *cam = &v->cam;
    struct vec3 d = vec3_sub(cam->position, s->p);
    float dist2 = vec3_length2(d);
    if (!(dist2 > 0.0f)) return false;
    struct vec3 wc = vec3_scale(d, 1.0f / sqrtf(dist2));
    float cos0 = -vec3_dot(wc, cam->forward);
    if (!(cos0 > 0.0f)) return false;
    float px, py;
    if (!camera_project(cam, s->p, &px, &py)) return false;
    if (!(px >= 0.0f && py >= 0.0f && px < (float)cam->width && py < (float)cam->height)) return false;
    uint32_t ix = (uint32_t)px, iy = (uint32_t)py;
    if (ix >= cam->width || iy >= cam->height) return false;
    struct vec3 wc_local = frame_to_local(&s->frame, wc), wo_local = frame_to_local(&s->frame, wo_world);
    float cos_c_ng = vec3_dot(wc, s->ng), cos_o_ng = vec3_dot(wo_world, s->ng);
    if (!(cos_c_ng * wc_local.z > 0.0f) || cos_o_ng == 0.0f) return false;
    struct vec3 f = material_eval(m, wc_local, wo_local, TRANSPORT_RADIANCE);
    if (vec3_is_zero(f)) return false;
    if (!bdpt_visible(v->scene->accel, s->p, s->ng, cam->position, NULL, rc)) return false;
    float camera_pdf_w = v->plane_dist2 / (cos0 * cos0 * cos0);
    float camera_pdf_a = camera_pdf_w * fabsf(cos_c_ng) / dist2;
    float w = restir_bdpt_mis_camera(mis, camera_pdf_a, c->n_light, material_pdf(m, wc_local, wo_local), c->power);
    float corr = fabsf(wo_local.z) * fabsf(cos_c_ng) / fabsf(cos_o_ng);
    *value = vec3_scale(vec3_mul(beta, f), w * corr * camera_pdf_w / (dist2 * c->n_light));
    *pixel = iy * cam->width + ix;
    if (sub) sub[0] = px - (float)ix, sub[1] = py - (float)iy;
    if (camera_pdf_a_out) *camera_pdf_a_out = camera_pdf_a;
    if (mis_out) *mis_out = w;
    return true;
}

/* ---- light subpaths ------------------------------------------------------------------------ */

/* The full variant's light vertex cache of one block: `region` vertices, `count` used, the
 * excess counted in `dropped`. */
struct rbdpt_lvc_block {
    struct bdpt_light_vertex *v;
    uint32_t *path;            /* with reuse: each vertex's light subpath; NULL otherwise */
    uint32_t region, count, dropped;
};

/* A vertex the hybrid shift may reconnect at or from: every lobe of its material is rough (the
 * reconnection evaluates the whole BSDF, so a delta lobe beside a rough one would be lost). */
static bool rbdpt_rough(const struct material *m)
{
    unsigned f = material_flags(m);
    return (f & (BSDF_DIFFUSE | BSDF_GLOSSY)) && !(f & BSDF_DELTA);
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

/* The t = 1 sample of the light subpath through x2 and the surface x1 (visible from x2), with
 * x_2's scattering taken along the segment between the two positions — the same numbers for
 * the initial sample and for every reverse hybrid shift of it — and the roulette rolled again
 * with x_2's own number (it is part of the light subpath's primary-sample-space integrand).
 * Its pixel, contribution, sub-pixel position and the reverse hybrid shift's Jacobian
 * denominator p_2(w) |cos_1| / d^2 / p_camera,A(x_1) (dw at x_2 per unit of image area).
 * False when it contributes nothing. */
static bool rbdpt_t1_eval(const struct rbdpt_ctx *c, const struct rbdpt_view *v, const struct rbdpt_x2 *x2,
                          const struct surface *x1, struct ray_counters *rays, uint32_t *pixel, struct vec3 *C,
                          float sub[2], float *pdf, float *mis_w)
{
    const struct material *m1 = &v->scene->materials[x1->material];
    if (!(material_flags(m1) & (BSDF_DIFFUSE | BSDF_GLOSSY))) return false;
    struct vec3 w = vec3_sub(x1->p, x2->s.p);
    float d2 = vec3_length2(w);
    if (!(d2 > 0.0f)) return false;
    w = vec3_scale(w, 1.0f / sqrtf(d2));
    struct vec3 wi = frame_to_local(&x2->s.frame, w), wo = frame_to_local(&x2->s.frame, x2->wo_world);
    float cos_i_ng = vec3_dot(w, x2->s.ng), cos_o_ng = vec3_dot(x2->wo_world, x2->s.ng);
    float cos_1 = vec3_dot(w, x1->ng);
    if (!(cos_i_ng * wi.z > 0.0f) || cos_o_ng == 0.0f || cos_1 == 0.0f) return false;
    struct vec3 f = material_eval(x2->m, wo, wi, TRANSPORT_IMPORTANCE);
    float p2 = material_pdf(x2->m, wo, wi);
    if (vec3_is_zero(f) || !(p2 > 0.0f)) return false;
    struct vec3 weight = vec3_scale(f, fabsf(wo.z) * fabsf(cos_i_ng) / (fabsf(cos_o_ng) * p2));
    struct vec3 beta = vec3_mul(x2->beta, weight);
    if (x2->depth >= c->p->rr_depth) {
        float mx = vec3_max_comp(vec3_mul(x2->rr_beta, weight));
        float q = mx < 0.95f ? mx : 0.95f;
        if (!(q > 0.0f) || x2->u_rr >= q) return false;
        beta = vec3_scale(beta, 1.0f / q);
    }
    struct restir_bdpt_mis mis = x2->mis;
    restir_bdpt_mis_scatter(&mis, cos_i_ng, p2, material_pdf(x2->m, wi, wo), false, c->power);
    restir_bdpt_mis_hit(&mis, d2, cos_1, c->power);
    float camera_pdf_a;
    if (!rbdpt_connect_camera(c, v, x1, m1, vec3_neg(w), beta, &mis, rays, pixel, C, sub, &camera_pdf_a, mis_w) ||
        !vec3_is_finite(*C) || vec3_is_zero(*C))
        return false;
    *pdf = p2 * fabsf(cos_1) / d2 / camera_pdf_a;
    return *pdf > 0.0f && isfinite(*pdf);
}

/* Light subpath i of frame `origin_frame`: its random stream, and its start on an emitter drawn
 * from the stream's first six numbers (the rest of the stream scatters the subpath). */
static bool rbdpt_light_stream(const struct rbdpt_ctx *c, const struct scene *scene, uint32_t origin_frame,
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

static bool rbdpt_nee_sample(const struct scene *scene, struct vec3 p, float ul, float u1, float u2,
                             struct rbdpt_nee *out)
{
    if (!light_sampler_sample(scene->lights, ul, u1, u2, &out->ls) || out->ls.is_env) return false;
    struct vec3 d = vec3_sub(out->ls.p, p);
    float d2 = vec3_length2(d);
    if (!(d2 > 0.0f)) return false;
    out->wi_world = vec3_scale(d, 1.0f / sqrtf(d2));
    out->cos_l = -vec3_dot(out->wi_world, out->ls.n);
    const struct material *lm = &scene->materials[scene->shapes[out->ls.shape].material];
    out->Le = light_sampler_emitted(lm, out->cos_l);
    out->direct_pdf_w = sampling_area_to_solid_angle(out->ls.pdf_a, d2, out->cos_l);
    if (!(out->direct_pdf_w > 0.0f) || vec3_is_zero(out->Le)) return false;
    out->emission_pdf_w = out->ls.pdf_a * bdpt_emit_dir_pdf_w(lm, out->cos_l);
    return true;
}

/* Traces light subpath i with the random numbers of frame `origin_frame` in view `v` and writes
 * its t = 1 samples to out[0 .. cap) (*stored, the excess counted in *dropped), and with `lvc`
 * (the full variant's light pass) every connectable vertex into the cache as bdpt does. With
 * only_depth > 0 it is the random-replay shift of seed 000 Appendix A: the subpath is replayed
 * up to that vertex and only the sample there is written (nothing when the replayed path ends
 * earlier, the vertex is not connectable or the eye does not see it). With `x2` (and
 * only_depth >= 2) the replay stops at light depth only_depth - 1 instead and returns that
 * vertex (true when it got there). With `out` NULL and only_depth > 0 it only caches the vertex at
 * that depth into `lvc` (a connection's shift, rbdpt_replay_light_vertex). With reuse a sample
 * whose x_2 has only rough lobes is evaluated by rbdpt_t1_eval. */
static bool rbdpt_trace_light(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t origin_frame,
                              uint32_t i, uint32_t only_depth, struct restir_bdpt_lt_sample *out, uint32_t cap,
                              uint32_t *stored, uint32_t *dropped, uint64_t *vertices, struct rbdpt_lvc_block *lvc,
                              struct rbdpt_x2 *x2_out, struct ray_counters *rc)
{
    const struct scene *scene = v->scene;
    const struct restir_bdpt_params *p = c->p;
    const bool track = p->reuse;
    struct rng rng;
    struct bdpt_light_start start;
    if (!rbdpt_light_stream(c, scene, origin_frame, i, &rng, &start)) return false;
    const struct light_sample ls = start.ls;
    struct vec3 dir = start.dir, beta = start.beta;
    struct vec3 rr_beta = vec3_splat(1.0f);
    struct restir_bdpt_mis mis = restir_bdpt_mis_light_start(ls.pdf_a, start.emission_pdf_w, start.cos_l, c->power);
    mis.full = c->full;
    struct vec3 org = start.org, prev_p = ls.p;
    bool prev_rough = true;   /* the emitter itself is rough: x_2 of a depth-1 sample */
    uint32_t last = only_depth ? only_depth : p->max_depth;
    if (last > p->max_depth) return false;
    if (x2_out) last = only_depth - 1;
    struct rbdpt_x2 x2 = {0};
    bool x2_rough = false;    /* track: the previous vertex is a surface with only rough lobes */

    for (uint32_t depth = 1; depth <= last; depth++) {
        struct hit hit;
        if (!accel_intersect(scene->accel, org, dir, 0.0f, INFINITY, &hit, rc)) return false;
        struct surface s;
        surface_from_hit(scene, &hit, org, dir, &s);
        restir_bdpt_mis_hit(&mis, vec3_length2(vec3_sub(s.p, prev_p)), vec3_dot(dir, s.ng), c->power);
        const struct material *m = &scene->materials[s.material];
        struct vec3 wo_world = vec3_neg(dir);
        if (!x2_out && (!only_depth || depth == only_depth) && (material_flags(m) & (BSDF_DIFFUSE | BSDF_GLOSSY))) {
            if (vertices) (*vertices)++;
            if (lvc && lvc->count < lvc->region) {
                const struct bdpt_mis lm = {mis.dvcm, mis.dvc};
                if (lvc->path) lvc->path[lvc->count] = i;
                lvc->v[lvc->count++] = bdpt_light_vertex_make(scene, &hit, &s, wo_world, beta, &lm, depth);
            } else if (lvc) {
                lvc->dropped++;
            }
            uint32_t px;
            struct vec3 val;
            const bool hybrid = track && depth >= 2 && x2_rough;
            float sub[2], pdf;
            bool made = out && (hybrid ? rbdpt_t1_eval(c, v, &x2, &s, rc, &px, &val, sub, &pdf, NULL)
                                       : rbdpt_connect_camera(c, v, &s, m, wo_world, beta, &mis, rc, &px, &val, NULL,
                                                              NULL, NULL) &&
                                             vec3_is_finite(val) && !vec3_is_zero(val));
            if (made) {
                if (*stored < cap) {
                    out[(*stored)++] = (struct restir_bdpt_lt_sample){
                        .F = val, .pixel = px, .light_path = i, .depth = (uint16_t)depth,
                        .caustic = (uint8_t)(prev_rough ? 0 : 1), .hybrid = (uint8_t)hybrid};
                } else {
                    (*dropped)++;
                }
            }
        }
        if (depth >= last && !x2_out) return true;
        struct vec3 wo = frame_to_local(&s.frame, wo_world);
        float ulobe = rng_next_float(&rng), v1 = rng_next_float(&rng), v2 = rng_next_float(&rng);
        struct bsdf_sample bs;
        if (!material_sample(m, wo, ulobe, v1, v2, TRANSPORT_IMPORTANCE, &bs)) return false;
        struct vec3 wi_world = frame_to_world(&s.frame, bs.wi);
        float cos_i_ng = vec3_dot(wi_world, s.ng), cos_o_ng = vec3_dot(wo_world, s.ng);
        if (cos_i_ng * bs.wi.z <= 0.0f || cos_o_ng == 0.0f) return false;
        if (track || x2_out) {
            x2 = (struct rbdpt_x2){.s = s, .m = m, .wo_world = wo_world, .beta = beta, .rr_beta = rr_beta,
                                   .mis = mis, .dir = wi_world, .depth = depth};
            x2_rough = rbdpt_rough(m);
        }
        struct vec3 weight = vec3_scale(bs.f, fabsf(wo.z) * fabsf(cos_i_ng) / (fabsf(cos_o_ng) * bs.pdf_w));
        beta = vec3_mul(beta, weight);
        rr_beta = vec3_mul(rr_beta, weight);
        bool delta = (bs.flags & BSDF_DELTA) != 0;
        restir_bdpt_mis_scatter(&mis, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, delta, c->power);
        /* Roughness of x_2 for the next vertex's sample: the lobe this vertex scattered by. */
        prev_rough = !delta;
        float u_rr = rng_next_float(&rng);
        x2.u_rr = u_rr;
        if (x2_out && depth == last) {
            *x2_out = x2;
            return true;
        }
        if (depth >= p->rr_depth) {
            /* Russian roulette is part of the primary-sample-space integrand, so a replay that
             * the roulette ends fails the shift (C = 0 there). */
            float mx = vec3_max_comp(rr_beta);
            float q = mx < 0.95f ? mx : 0.95f;
            if (!(q > 0.0f) || u_rr >= q) return false;
            beta = vec3_scale(beta, 1.0f / q);
            rr_beta = vec3_scale(rr_beta, 1.0f / q);
        }
        org = bdpt_origin(&s, wi_world);
        prev_p = s.p;
        dir = wi_world;
    }
    return !x2_out;
}

/* The x_2 cache (st->x2c): rbdpt_x2_keep stores what the replay of a sample's light subpath
 * gave in this frame's scene, rbdpt_x2_cached gives it back to a shift in that same scene —
 * the same numbers, so an image does not depend on whether a shift found its x_2 here. */
static void rbdpt_x2_keep(const struct rbdpt_ctx *c, uint32_t pixel, const struct restir_bdpt_path *res,
                          const struct rbdpt_x2 *x2)
{
    struct rbdpt_x2_entry *e = &c->st->x2c[pixel];
    *e = (struct rbdpt_x2_entry){.p = x2->s.p, .ng = x2->s.ng, .ns = x2->s.ns, .shape = x2->s.shape,
                                 .prim = x2->s.prim, .material = x2->s.material, .wo_world = x2->wo_world,
                                 .beta = x2->beta, .rr_beta = x2->rr_beta, .dvcm = x2->mis.dvcm,
                                 .dvc = x2->mis.dvc, .u_rr = x2->u_rr, .depth = x2->depth,
                                 .light_path = res->r.light_path, .origin_frame = res->r.origin_frame,
                                 .frame = c->frame, .depth_key = (uint16_t)(res->r.head.bits >> 8),
                                 .near = x2->mis.near, .kind = RBDPT_CACHE_X2};
}

static bool rbdpt_x2_cached(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t pixel,
                            const struct restir_bdpt_path *src, struct rbdpt_x2 *x2)
{
    if (!c->st->x2c || pixel == UINT32_MAX || v->scene != c->view[0].scene) return false;
    const struct rbdpt_x2_entry *e = &c->st->x2c[pixel];
    if (e->kind != RBDPT_CACHE_X2 || e->frame != c->frame || e->light_path != src->r.light_path ||
        e->origin_frame != src->r.origin_frame || e->depth_key != (uint16_t)(src->r.head.bits >> 8))
        return false;
    *x2 = (struct rbdpt_x2){.s = {.p = e->p, .ng = e->ng, .ns = e->ns, .frame = frame_from_normal(e->ns),
                                  .shape = e->shape, .prim = e->prim, .material = e->material},
                            .m = &v->scene->materials[e->material], .wo_world = e->wo_world, .beta = e->beta,
                            .rr_beta = e->rr_beta, .mis = {e->dvcm, e->dvc, e->near != 0, c->full},
                            .u_rr = e->u_rr, .depth = e->depth};
    return true;
}

/* The light pass: one job per block of light subpaths, each block into its own region. */
static void rbdpt_light_block(void *ctx, uint32_t block, unsigned worker)
{
    (void)worker;
    struct rbdpt_ctx *c = ctx;
    struct restir_bdpt_state *st = c->st;
    struct ray_counters rc = {0, 0};
    struct restir_bdpt_lt_sample *region = &st->lt[(size_t)block * st->region];
    uint32_t stored = 0, dropped = 0;
    uint64_t vertices = 0;
    uint32_t first = block * RBDPT_BLOCK_PATHS;
    uint32_t last = first + RBDPT_BLOCK_PATHS < st->light_paths ? first + RBDPT_BLOCK_PATHS : st->light_paths;
    const size_t lvc_at = (size_t)block * st->lvc_region;
    struct rbdpt_lvc_block lvc = {st->lvc ? &st->lvc[lvc_at] : NULL, st->lvc_path ? &st->lvc_path[lvc_at] : NULL,
                                  st->lvc_region, 0, 0};
    for (uint32_t i = first; i < last; i++)
        rbdpt_trace_light(c, &c->view[0], c->frame, i, 0, region, st->region, &stored, &dropped, &vertices,
                          st->lvc ? &lvc : NULL, NULL, &rc);
    if (st->lvc) {
        st->lvc_count[block] = lvc.count;
        st->lvc_dropped[block] = lvc.dropped;
    }
    st->block_count[block] = stored;
    st->block_dropped[block] = dropped;
    st->block_rays[3 * block] = rc.intersect;
    st->block_rays[3 * block + 1] = rc.occluded;
    st->block_rays[3 * block + 2] = vertices;
}

enum rbdpt_replay { RBDPT_REPLAY_OK, RBDPT_REPLAY_FAILED, RBDPT_REPLAY_NOT_CAUSTIC };

/* The random-replay shift of a caustic sample (light subpath i of frame origin_frame, vertex
 * `depth`) into view v: its pixel and contribution there. It fails when the replayed subpath
 * ends before that vertex or the eye does not see it there, and when x_2 turned rough (the
 * sample left the caustic domain). Its Jacobian in primary sample space is 1. */
static enum rbdpt_replay rbdpt_replay_caustic(const struct rbdpt_ctx *c, const struct rbdpt_view *v,
                                              uint32_t origin_frame, uint32_t i, uint32_t depth, uint32_t *pixel,
                                              struct vec3 *F, struct ray_counters *rc)
{
    struct restir_bdpt_lt_sample out;
    uint32_t stored = 0, dropped = 0;
    rbdpt_trace_light(c, v, origin_frame, i, depth, &out, 1, &stored, &dropped, NULL, NULL, NULL, rc);
    if (stored == 0) return RBDPT_REPLAY_FAILED;
    if (!out.caustic) return RBDPT_REPLAY_NOT_CAUSTIC;
    *pixel = out.pixel;
    *F = out.F;
    return RBDPT_REPLAY_OK;
}

/* The light side of a connection's shift (s >= 2; seed 000 §5: the light subpath shifts by random
 * replay): light subpath i of frame origin_frame replayed in view v to its vertex at light depth
 * `depth`, as the light pass would have cached it. False when the replay ends earlier or the
 * vertex is not connectable there (a changed classification fails the shift). */
static bool rbdpt_replay_light_vertex(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t origin_frame,
                                      uint32_t i, uint32_t depth, struct bdpt_light_vertex *out,
                                      struct ray_counters *rays)
{
    struct rbdpt_lvc_block one = {out, NULL, 1, 0, 0};
    rbdpt_trace_light(c, v, origin_frame, i, depth, NULL, 0, NULL, NULL, NULL, &one, NULL, rays);
    return one.count == 1;
}

/* Keeps a connection's light vertex in this frame's scene in the cache entry of `pixel`, whose
 * sample src is. */
static void rbdpt_light_vertex_keep(const struct rbdpt_ctx *c, uint32_t pixel, const struct restir_bdpt_path *src,
                                    const struct bdpt_light_vertex *lv)
{
    c->st->x2c[pixel] = (struct rbdpt_x2_entry){.lv = *lv, .light_path = src->rc.light_path,
                                                .origin_frame = src->r.origin_frame, .frame = c->frame,
                                                .depth_key = (uint16_t)lv->depth, .kind = RBDPT_CACHE_LV};
}

/* A connection's light vertex (rbdpt_replay_light_vertex) through the cache entry of `pixel`,
 * whose sample src is (UINT32_MAX: none; st->x2c, see rbdpt_x2_keep): found there when it was
 * kept in this frame's scene, else replayed, and with `keep` (only the job that owns the pixel)
 * kept there. The entry holds what the replay gave, so an image does not depend on it. */
static bool rbdpt_light_vertex_of(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t pixel,
                                  const struct restir_bdpt_path *src, bool keep, struct bdpt_light_vertex *lv,
                                  struct ray_counters *rays)
{
    const uint32_t depth = (src->r.head.bits & 0xffu) - 1u;
    struct rbdpt_x2_entry *e =
        c->st->x2c && pixel != UINT32_MAX && v->scene == c->view[0].scene ? &c->st->x2c[pixel] : NULL;
    if (e && e->kind == RBDPT_CACHE_LV && e->frame == c->frame && e->light_path == src->rc.light_path &&
        e->origin_frame == src->r.origin_frame && e->depth_key == depth) {
        *lv = e->lv;
        return true;
    }
    if (!rbdpt_replay_light_vertex(c, v, src->r.origin_frame, src->rc.light_path, depth, lv, rays)) return false;
    if (e && keep) rbdpt_light_vertex_keep(c, pixel, src, lv);
    return true;
}

/* Whether a non-caustic sample is a connection (s >= 2, the full variant's). */
static bool rbdpt_is_connection(const struct restir_bdpt_path *x)
{
    const uint32_t tech = x->r.head.bits & 0xffu;
    return tech >= 2u && tech != RESTIR_BDPT_TECH_LT;
}

/* The full variant's recursive reconnection MIS (seed 000 §6.2–6.3, in dVCM / dVC form). Past
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
static void rbdpt_suffix_basis(struct restir_bdpt_mis basis[3])
{
    basis[0] = (struct restir_bdpt_mis){0.0f, 0.0f, true, true};
    basis[1] = (struct restir_bdpt_mis){1.0f, 0.0f, true, true};
    basis[2] = (struct restir_bdpt_mis){0.0f, 1.0f, true, true};
}

static void rbdpt_suffix_scatter(struct restir_bdpt_mis basis[3], float cos_out, float pdf_fwd_w, float pdf_rev_w,
                                 bool delta, bool power)
{
    for (int j = 0; j < 3; j++) restir_bdpt_mis_scatter(&basis[j], cos_out, pdf_fwd_w, pdf_rev_w, delta, power);
    basis[1].dvcm = basis[2].dvcm = 0.0f;   /* the constant a rough scattering sets belongs to o */
}

/* a, b, c from the carried states and the candidate's K. */
static void rbdpt_full_constants(const struct restir_bdpt_mis basis[3], float K0, float K1, float K2,
                                 struct restir_bdpt_rc *rc)
{
    rc->mis_a = K1 * basis[1].dvcm + K2 * basis[1].dvc;
    rc->mis_b = K1 * basis[2].dvcm + K2 * basis[2].dvc;
    rc->mis_c = K0 + K1 * basis[0].dvcm + K2 * basis[0].dvc;
}

/* The weight from those constants and the state after x_k's scattering on the shifted path. */
static float rbdpt_full_weight(const struct restir_bdpt_rc *rc, const struct restir_bdpt_mis *at_k)
{
    return 1.0f / (1.0f + rc->mis_a * at_k->dvcm + rc->mis_b * at_k->dvc + rc->mis_c);
}

/* Random numbers a camera subpath draws per vertex (RBDPT_CAMERA_VERTEX_DRAWS). */
static uint32_t rbdpt_vertex_draws(const struct rbdpt_ctx *c)
{
    return RBDPT_CAMERA_VERTEX_DRAWS + (c->full ? 1u : 0u);
}

/* ---- camera pass: each pixel's candidates (s = 0, s = 1) and its light-traced bucket -------- */

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

/* Offers a camera-side candidate of contribution C and resampling weight w to the reservoir, or
 * hands it to the replay that wants it; true when the replay is settled (found or failed: the
 * path need not be traced further). */
static bool rbdpt_offer(struct rbdpt_ris *r, struct rbdpt_want *want, struct vec3 C, double w, uint16_t bits,
                        const struct restir_bdpt_rc *rc, const struct bdpt_light_vertex *lv, uint32_t pixel,
                        uint32_t frame, struct rng *pick, struct rbdpt_worker *wk)
{
    if (want) {
        if (want->bits != bits) return false;
        want->found = (rc ? rc->k : 0u) == want->k;
        want->C = C;
        if (rc) want->rc = *rc;
        return true;
    }
    wk->candidates++;
    if (rbdpt_ris_add_rc(r, C, w, bits, pixel, frame, rc, pick, wk)) r->lv = lv;
    return false;
}


/* The camera subpath of `pixel`'s stream (its ids: the pixel and frame whose random numbers
 * drive it) traced along `dir` in view v: its s = 0 and s = 1 candidates, and the full variant's
 * connections. With reuse each candidate also gets its reconnection (struct
 * restir_bdpt_rc), and Russian roulette is decoupled from the primary sample space (seed 001 §6):
 * C leaves the survival probabilities out and they divide the resampling weight instead, so a
 * shift, which keeps the vertices after x_k, never has to roll the roulette again; a replay
 * never ends by roulette. Without reuse no camera-side sample is ever shifted, and C keeps them
 * (the same estimate; the image is then exactly bdpt's). */
static void rbdpt_camera_candidates(const struct rbdpt_ctx *c, const struct rbdpt_view *v, struct vec3 dir,
                                    uint32_t pixel, uint32_t frame, struct rng *rng, struct rng *pick,
                                    struct rbdpt_ris *r, struct ray_counters *rc, struct rbdpt_worker *wk,
                                    struct vec3 *primary, bool *has_primary, struct rbdpt_want *want,
                                    const struct rbdpt_resume *resume)
{
    *has_primary = false;
    const struct scene *scene = v->scene;
    const struct restir_bdpt_params *p = c->p;
    const struct light_sampler *lights = scene->lights;
    const struct camera *cam = &v->cam;
    const bool track = p->reuse;
    struct vec3 beta = vec3_splat(1.0f);
    double src = 1.0;   /* track: the product of the roulette's survival probabilities so far */
    /* Undoes refraction's radiance scaling for the roulette (reference_pt.c). A resumed suffix
     * starts it at 1: resuming is a replay, and replays play no roulette. */
    float rr_scale = 1.0f;
    float cos0 = resume ? 1.0f : vec3_dot(dir, cam->forward);
    if (!(cos0 > 0.0f)) return;
    struct restir_bdpt_mis mis = restir_bdpt_mis_camera_start(c->n_light, v->plane_dist2 / (cos0 * cos0 * cos0),
                                                                  c->power);
    mis.full = c->full;
    struct vec3 org = cam->position, prev_p = org;
    /* track: the reconnection found so far (rc_k.k = 0: none), dVC after x_k's scattering, the
     * throughput of the scatterings after x_k, and the previous vertex as it was before its
     * scattering (to redo that scattering along the segment to x_k). */
    struct restir_bdpt_rc rc_k = {0};
    struct restir_bdpt_mis suffix = {0.0f, 1.0f, false, false};   /* dVC's factors past x_k's scattering */
    struct restir_bdpt_mis basis[3];   /* full: the states carried from x_k's scattering (rbdpt_suffix_basis) */
    rbdpt_suffix_basis(basis);
    struct vec3 beta_suf = vec3_splat(1.0f);
    struct surface prev_s = {0};
    const struct material *prev_m = NULL;
    struct vec3 prev_wo = {0, 0, 0}, prev_beta = beta;
    struct restir_bdpt_mis prev_mis = mis;
    bool prev_rough = false;
    uint32_t first = 0;
    if (resume) {
        org = resume->org;
        dir = resume->dir;
        prev_p = resume->prev_p;
        beta = resume->beta;
        mis = resume->mis;
        rc_k = resume->rc;
        first = rc_k.k;
    }

    for (uint32_t depth = first;; depth++) {
        /* A replay is over once past the wanted path's length: every candidate made at this
         * depth has at least depth + 1 vertices after the camera. */
        if (want && depth + 1 > (uint32_t)(want->bits >> 8)) return;
        struct hit hit;
        if (!accel_intersect(scene->accel, org, dir, 0.0f, INFINITY, &hit, rc)) break;
        struct surface s;
        surface_from_hit(scene, &hit, org, dir, &s);
        if (depth == 0) {
            *primary = s.p;
            *has_primary = true;
        }
        float cos_hit = vec3_dot(dir, s.ng);
        float hit_d2 = vec3_length2(vec3_sub(s.p, prev_p));
        restir_bdpt_mis_hit(&mis, hit_d2, cos_hit, c->power);
        if (rc_k.k && rc_k.k <= depth) {
            restir_bdpt_mis_hit(&suffix, hit_d2, cos_hit, c->power);
            for (int j = 0; j < 3; j++) restir_bdpt_mis_hit(&basis[j], hit_d2, cos_hit, c->power);
        }
        const struct material *m = &scene->materials[s.material];
        /* Path vertices after the camera of an emitter hit here: depth + 1. */
        if (material_is_emissive(m)) {
            struct vec3 Le = light_sampler_emitted(m, -cos_hit);
            if (!vec3_is_zero(Le)) {
                float w = 1.0f, direct_pdf_a = 0.0f, emission_pdf_w = 0.0f;
                if (depth > 0) {
                    direct_pdf_a = light_sampler_pdf_a(lights, s.shape, s.prim);
                    emission_pdf_w = direct_pdf_a * bdpt_emit_dir_pdf_w(m, cos_hit);
                    w = restir_bdpt_mis_emission(&mis, direct_pdf_a, emission_pdf_w, c->power);
                }
                struct vec3 C = vec3_scale(vec3_mul(beta, Le), w);
                struct restir_bdpt_rc rce = rc_k;
                if (rce.k) {
                    const bool last = rce.k == depth;   /* x_k scattered straight onto this emitter */
                    rce.L = last ? Le : vec3_mul(beta_suf, Le);
                    if (c->full) {   /* restir_bdpt_mis_emission's K */
                        rbdpt_full_constants(basis, 0.0f, rbdpt_mis_f(direct_pdf_a, c->power),
                                             rbdpt_mis_f(emission_pdf_w, c->power), &rce);
                    } else {
                        restir_bdpt_rc_mis_emission(&mis, direct_pdf_a, emission_pdf_w, hit_d2, cos_hit, last,
                                                    suffix.dvc, c->power, &rce.mis_a, &rce.mis_b);
                    }
                    if (p->copy_mis) rce.L = vec3_scale(rce.L, w);
                }
                if (rbdpt_offer(r, want, C, vec3_luminance(C) / src, (uint16_t)(((depth + 1) << 8) | 0u),
                                track ? &rce : NULL, NULL, pixel, frame, pick, wk))
                    return;
            }
        }
        if (depth >= p->max_depth) break;
        struct vec3 wo_world = vec3_neg(dir);
        const bool rough = track && p->camera_reconnect && rbdpt_rough(m);
        if (rough && prev_rough && rc_k.k == 0) {
            /* x_{depth+1} is x_k: its predecessor's scattering is redone along the segment between
             * the two positions, as a shift evaluates it (the sampled ray left from an offset
             * origin; at grazing angles the two differ by per cents). */
            struct vec3 w = vec3_sub(s.p, prev_s.p);
            float d2 = vec3_length2(w);
            w = vec3_scale(w, 1.0f / sqrtf(d2));
            struct vec3 wi = frame_to_local(&prev_s.frame, w);
            struct vec3 f = material_eval(prev_m, prev_wo, wi, TRANSPORT_RADIANCE);
            float pdf = material_pdf(prev_m, prev_wo, wi);
            float cos_k = vec3_dot(w, s.ng);
            /* Where the segment and the sampled ray disagree this much the path ends: under the
             * reconnection's integrand it carries nothing. */
            if (!(vec3_dot(w, prev_s.ng) * wi.z > 0.0f) || !(pdf > 0.0f) || vec3_is_zero(f) || cos_k == 0.0f ||
                !(d2 > 0.0f))
                break;
            beta = vec3_mul(prev_beta, vec3_scale(f, fabsf(wi.z) / pdf));
            mis = prev_mis;
            restir_bdpt_mis_scatter(&mis, vec3_dot(w, prev_s.ng), pdf, material_pdf(prev_m, wi, prev_wo), false,
                                    c->power);
            restir_bdpt_mis_hit(&mis, d2, cos_k, c->power);
            rc_k.k = depth + 1;
            rc_k.shape = hit.shape;
            rc_k.prim = hit.prim;
            surface_point_code(scene, &hit, &s, &rc_k.b1, &rc_k.b2);
            rc_k.pdf = pdf * fabsf(cos_k) / d2;
            wo_world = vec3_neg(w);
        }
        struct vec3 wo = frame_to_local(&s.frame, wo_world);
        bool connectable = (material_flags(m) & (BSDF_DIFFUSE | BSDF_GLOSSY)) != 0;
        float ul = rng_next_float(rng), u1 = rng_next_float(rng), u2 = rng_next_float(rng);
        /* The full variant's choice of a cached light vertex (the lightweight one draws none, so
         * its random streams are as before). */
        float uc = c->full ? rng_next_float(rng) : 0.0f;
        if (connectable) {
            struct rbdpt_nee ns;
            if (rbdpt_nee_sample(scene, s.p, ul, u1, u2, &ns)) {
                const struct vec3 wi_world = ns.wi_world, Le = ns.Le;
                const float cos_l = ns.cos_l, direct_pdf_w = ns.direct_pdf_w, emission_pdf_w = ns.emission_pdf_w;
                struct vec3 wi = frame_to_local(&s.frame, wi_world);
                float cos_ng = vec3_dot(wi_world, s.ng);
                if (cos_ng * wi.z > 0.0f) {
                    struct vec3 f = material_eval(m, wo, wi, TRANSPORT_RADIANCE);
                    if (!vec3_is_zero(f) && bdpt_visible(scene->accel, s.p, s.ng, ns.ls.p, &ns.ls.n, rc)) {
                        float fwd = material_pdf(m, wo, wi), rev = material_pdf(m, wi, wo);
                        float w = restir_bdpt_mis_nee(&mis, fwd, rev, direct_pdf_w, emission_pdf_w, cos_ng, cos_l,
                                                      c->power);
                        struct vec3 end = vec3_scale(vec3_mul(f, Le), fabsf(wi.z) / direct_pdf_w);
                        struct vec3 C = vec3_scale(vec3_mul(beta, end), w);
                        struct restir_bdpt_rc rcn = rc_k;
                        if (rcn.k) {
                            const bool last = rcn.k == depth + 1;   /* the light sample leaves x_k itself */
                            if (last) {
                                rcn.L = vec3_scale(Le, 1.0f / direct_pdf_w);
                                surface_oct_encode(wi_world, &rcn.wk_u, &rcn.wk_v);
                            } else {
                                rcn.L = vec3_mul(beta_suf, end);
                            }
                            if (!c->full) {
                                restir_bdpt_rc_mis_nee(fwd, rev, direct_pdf_w, emission_pdf_w, cos_ng, cos_l, last,
                                                       suffix.dvc, c->power, &rcn.mis_a, &rcn.mis_b);
                            } else if (!last) {   /* (a light sample leaving x_k is drawn again by a shift) */
                                /* restir_bdpt_mis_nee's K */
                                const float k_cam = rbdpt_mis_f(emission_pdf_w * fabsf(cos_ng) /
                                                                  (direct_pdf_w * fabsf(cos_l)), c->power);
                                rbdpt_full_constants(basis, rbdpt_mis_f(fwd / direct_pdf_w, c->power), k_cam,
                                                     k_cam * rbdpt_mis_f(rev, c->power), &rcn);
                            }
                            if (p->copy_mis) rcn.L = vec3_scale(rcn.L, w);
                        }
                        if (rbdpt_offer(r, want, C, vec3_luminance(C) / src, (uint16_t)(((depth + 2) << 8) | 1u),
                                        track ? &rcn : NULL, NULL, pixel, frame, pick, wk))
                            return;
                    }
                }
            }
            /* s >= 2, t >= 2 (full variant): a connection to one light vertex drawn uniformly from
             * the cache, as bdpt; paths longer than max_depth are cut. Technique s = the light
             * vertex's surface vertices + the emitter's. |LVC| / N_L = 1 / p_L is the choice's part
             * of the unbiased contribution weight (seed 000 eq. 25): it scales the resampling
             * weight, and the target C stays a function of the path alone, which a shift can
             * evaluate in another frame whose cache is another. A shift's replay joins the
             * sample's own light vertex instead, replayed (rbdpt_shift). */
            const uint32_t t_c = depth + 1;   /* surface vertices on the camera subpath */
            const struct bdpt_light_vertex *lv = NULL;
            uint32_t lv_path = UINT32_MAX;
            if (want) {
                if (want->lv && (uint32_t)(want->bits & 0xffu) == want->lv->depth + 1 &&
                    t_c + want->lv->depth + 1 == (uint32_t)(want->bits >> 8)) {
                    lv = want->lv;
                    lv_path = want->lv_path;
                }
            } else if (c->full && t_c < p->max_depth) {
                lv = bdpt_lvc_pick(&c->lvc, uc);
                if (lv && c->st->lvc_path) lv_path = c->st->lvc_path[lv - c->st->lvc];
            }
            if (lv && t_c + lv->depth <= p->max_depth) {
                bool made;
                const struct bdpt_mis cm = {mis.dvcm, mis.dvc};
                struct bdpt_connect_pdfs cp;
                struct vec3 cv = bdpt_connect_light_vertex(scene, c->power, 1.0f, &s, m, wo, &cm, lv, rc, &made, &cp);
                if (made) {
                    if (wk) wk->connections++;
                    uint32_t vertices = t_c + lv->depth + 1, tech = lv->depth + 1;
                    struct vec3 C = vec3_mul(beta, cv);
                    struct restir_bdpt_rc rcc = rc_k;
                    rcc.light_path = lv_path;
                    if (rcc.k && rcc.k < t_c && cp.w > 0.0f) {
                        /* Past x_k: what w_k carries back, and the suffix's MIS constants. */
                        rcc.L = vec3_mul(beta_suf, vec3_scale(cv, 1.0f / cp.w));
                        /* bdpt_mis_weight_connect's K */
                        const float lf = rbdpt_mis_f(cp.light_fwd_a, c->power);
                        rbdpt_full_constants(basis,
                                             rbdpt_mis_f(cp.cam_fwd_a, c->power) *
                                                 (lv->dvcm + lv->dvc * rbdpt_mis_f(cp.light_rev_w, c->power)),
                                             lf, lf * rbdpt_mis_f(cp.cam_rev_w, c->power), &rcc);
                    }
                    if (rbdpt_offer(r, want, C, vec3_luminance(C) * c->lvc.scale / src,
                                    (uint16_t)((vertices << 8) | tech), track ? &rcc : NULL, lv, pixel, frame, pick,
                                    wk))
                        return;
                }
            }
        }
        float ulobe = rng_next_float(rng), v1 = rng_next_float(rng), v2 = rng_next_float(rng);
        struct bsdf_sample bs;
        if (!material_sample(m, wo, ulobe, v1, v2, TRANSPORT_RADIANCE, &bs)) break;
        struct vec3 wi_world = frame_to_world(&s.frame, bs.wi);
        float cos_i_ng = vec3_dot(wi_world, s.ng);
        if (cos_i_ng * bs.wi.z <= 0.0f) break;
        prev_beta = beta;
        prev_mis = mis;
        if (rc_k.k == depth + 1) {
            /* x_k's own scattering, as a shift evaluates it: the whole BSDF and its pdf. */
            struct vec3 f = material_eval(m, wo, bs.wi, TRANSPORT_RADIANCE);
            float pdf = material_pdf(m, wo, bs.wi);
            if (vec3_is_zero(f) || !(pdf > 0.0f)) break;
            beta = vec3_mul(beta, vec3_scale(f, fabsf(bs.wi.z) / pdf));
            restir_bdpt_mis_scatter(&mis, cos_i_ng, pdf, material_pdf(m, bs.wi, wo), false, c->power);
            rc_k.pdf *= pdf;
            surface_oct_encode(wi_world, &rc_k.wk_u, &rc_k.wk_v);
        } else {
            struct vec3 factor = vec3_scale(bs.f, fabsf(bs.wi.z) / bs.pdf_w);
            beta = vec3_mul(beta, factor);
            const bool delta = (bs.flags & BSDF_DELTA) != 0;
            restir_bdpt_mis_scatter(&mis, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, delta, c->power);
            if (rc_k.k) {
                beta_suf = vec3_mul(beta_suf, factor);
                restir_bdpt_mis_scatter(&suffix, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, delta, c->power);
                rbdpt_suffix_scatter(basis, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, delta, c->power);
            }
        }
        if (bs.flags & BSDF_TRANSMISSION) rr_scale /= material_radiance_scale(m, wo, bs.wi);
        float u_rr = rng_next_float(rng);
        if (depth + 1 >= p->rr_depth && !(track && want)) {
            float mx = vec3_max_comp(beta) * rr_scale / (float)src;
            float q = mx < 0.95f ? mx : 0.95f;
            if (!(q > 0.0f) || u_rr >= q) break;
            if (track) src *= q;
            else beta = vec3_scale(beta, 1.0f / q);
        }
        prev_s = s;
        prev_m = m;
        prev_wo = wo;
        prev_rough = rough;
        org = bdpt_origin(&s, wi_world);
        prev_p = s.p;
        dir = wi_world;
    }
}

/* ---- reuse of the non-caustic reservoir (restir.c's passes) ------------------------------- */

/* The hybrid shift of a camera-side sample with a reconnection (src->rc.k >= 2) into pixel
 * `pixel` of view v, whose scene is the sample's own (seed 000 §6.1; the camera-subpath case of
 * its bidirectional hybrid shift): the camera subpath is replayed with the sample's random
 * numbers through the pixel up to x'_{k-1} — no pair before it may be connectable, or the
 * shifted path would reconnect elsewhere and the shift would not be invertible — then joined to
 * x_k, whose suffix is kept. Its contribution, the Jacobian p'_{k-1} G' p'_k / (p_{k-1} G p_k)
 * (Appendix C), and the shifted path's own denominator (*pdf, for its later shifts); false when
 * the shift fails. */
static bool rbdpt_reconnect(const struct rbdpt_ctx *c, const struct rbdpt_view *v, const struct scene *scene_from,
                            const struct restir_bdpt_path *src, const struct bdpt_light_vertex *lv, uint32_t pixel,
                            struct vec3 *C, float *J, struct restir_bdpt_rc *rc_out, struct ray_counters *rays)
{
    const struct scene *scene = v->scene;
    const struct camera *cam = &v->cam;
    const uint32_t k = src->rc.k, e = (uint32_t)(src->r.head.bits >> 8), tech = src->r.head.bits & 0xffu;
    const bool nee = tech == 1u;
    const uint32_t draws = rbdpt_vertex_draws(c);
    struct rng rng = rng_make(c->seed, src->r.origin_frame, RBDPT_CAMERA_STREAM + src->r.light_path, 0);
    float jx = rng_next_float(&rng), jy = rng_next_float(&rng);
    const uint32_t w = c->st->width;
    struct vec3 dir = camera_ray_dir(cam, (float)(pixel % w) + jx, (float)(pixel / w) + jy);
    float cos0 = vec3_dot(dir, cam->forward);
    if (!(cos0 > 0.0f)) return false;
    struct restir_bdpt_mis mis = restir_bdpt_mis_camera_start(c->n_light, v->plane_dist2 / (cos0 * cos0 * cos0),
                                                                  c->power);
    mis.full = c->full;
    struct vec3 beta = vec3_splat(1.0f), org = cam->position, prev_p = org;
    struct surface s;
    const struct material *m = NULL;
    bool prev_rough = false;
    /* y_1 .. y_{k-1} by random replay, drawing the random numbers as rbdpt_camera_candidates does. */
    for (uint32_t j = 1;; j++) {
        struct hit hit;
        if (!accel_intersect(scene->accel, org, dir, 0.0f, INFINITY, &hit, rays)) return false;
        surface_from_hit(scene, &hit, org, dir, &s);
        restir_bdpt_mis_hit(&mis, vec3_length2(vec3_sub(s.p, prev_p)), vec3_dot(dir, s.ng), c->power);
        m = &scene->materials[s.material];
        const bool rough = rbdpt_rough(m);
        if (j >= 2 && prev_rough && rough) return false;
        if (j + 1 == k) break;
        for (uint32_t n = 0; n < draws - 4u; n++) rng_next_float(&rng);   /* the light sample's (and vertex choice) */
        struct vec3 wo = frame_to_local(&s.frame, vec3_neg(dir));
        float ulobe = rng_next_float(&rng), v1 = rng_next_float(&rng), v2 = rng_next_float(&rng);
        struct bsdf_sample bs;
        if (!material_sample(m, wo, ulobe, v1, v2, TRANSPORT_RADIANCE, &bs)) return false;
        struct vec3 wi_world = frame_to_world(&s.frame, bs.wi);
        float cos_i_ng = vec3_dot(wi_world, s.ng);
        if (cos_i_ng * bs.wi.z <= 0.0f) return false;
        beta = vec3_mul(beta, vec3_scale(bs.f, fabsf(bs.wi.z) / bs.pdf_w));
        restir_bdpt_mis_scatter(&mis, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, (bs.flags & BSDF_DELTA) != 0, c->power);
        rng_next_float(&rng);   /* the roulette's: survival is certain in a shift */
        prev_rough = rough;
        org = bdpt_origin(&s, wi_world);
        prev_p = s.p;
        dir = wi_world;
    }
    if (!rbdpt_rough(m)) return false;
    struct surface sk;
    surface_at(scene, src->rc.shape, src->rc.prim, src->rc.b1, src->rc.b2, &sk);
    const struct material *mk = &scene->materials[sk.material];
    if (!rbdpt_rough(mk)) return false;
    /* y_{k-1} -> x_k. */
    struct vec3 w1 = vec3_sub(sk.p, s.p);
    float d2 = vec3_length2(w1);
    if (!(d2 > 0.0f)) return false;
    w1 = vec3_scale(w1, 1.0f / sqrtf(d2));
    struct vec3 wo = frame_to_local(&s.frame, vec3_neg(dir)), wi = frame_to_local(&s.frame, w1);
    if (!(vec3_dot(w1, s.ng) * wi.z > 0.0f)) return false;
    struct vec3 f1 = material_eval(m, wo, wi, TRANSPORT_RADIANCE);
    float p1 = material_pdf(m, wo, wi);
    float cos_k = vec3_dot(w1, sk.ng);
    struct vec3 wo_k = frame_to_local(&sk.frame, vec3_neg(w1));
    if (vec3_is_zero(f1) || !(p1 > 0.0f) || !(-cos_k * wo_k.z > 0.0f)) return false;
    restir_bdpt_mis_scatter(&mis, vec3_dot(w1, s.ng), p1, material_pdf(m, wi, wo), false, c->power);
    restir_bdpt_mis_hit(&mis, d2, cos_k, c->power);
    if (tech >= 2u && k + tech == e) {
        /* x_k itself joins the sample's light vertex (replayed in this scene by rbdpt_shift): the
         * direction leaving x_k is the connection's, fixed by the light vertex, so p_k = 1 as for
         * a light sample. */
        bool made;
        const struct bdpt_mis cm = {mis.dvcm, mis.dvc};
        struct vec3 cv = bdpt_connect_light_vertex(scene, c->power, 1.0f, &sk, mk, wo_k, &cm, lv, rays, &made, NULL);
        if (!made || !bdpt_visible(scene->accel, s.p, s.ng, sk.p, &sk.ng, rays)) return false;
        *rc_out = src->rc;
        rc_out->pdf = p1 * fabsf(cos_k) / d2;
        *C = vec3_mul(vec3_mul(beta, vec3_scale(f1, fabsf(wi.z) / p1)), cv);
        *J = rc_out->pdf / src->rc.pdf *
             surface_area_ratio(scene_from, scene, src->rc.shape, src->rc.prim, src->rc.b1, src->rc.b2);
        return isfinite(*J) && *J > 0.0f && vec3_is_finite(*C);
    }
    const bool nee_last = nee && k + 1 == e;   /* the light sample leaves x_k itself */
    /* The full variant draws a light sample that leaves x_k again in every shift (its weight
     * over all techniques has no suffix to keep constants of; the draw is cheap). */
    const bool retrace = (c->full && nee_last) || (scene_from != scene && !c->static_scene) || c->force_retrace;
    /* x_k towards w_k with its new w_o. */
    struct vec3 wk_world = surface_oct_decode(src->rc.wk_u, src->rc.wk_v), L_k = src->rc.L;
    struct light_sample ls = {0};
    float direct_pdf_w = 0.0f, emission_pdf_w = 0.0f, cos_l = 0.0f;
    if (retrace && nee_last) {
        /* The light sample is the other scene's: it is drawn again here from its own random
         * numbers (x_k's, as rbdpt_camera_candidates draws them), its Jacobian 1 in primary
         * sample space, as the suffix of any other reconnected sample is traced again. */
        struct rng r2 = rng_make(c->seed, src->r.origin_frame, RBDPT_CAMERA_STREAM + src->r.light_path, 0);
        const uint32_t skip = RBDPT_CAMERA_JITTER_DRAWS + draws * (k - 1);
        for (uint32_t n = 0; n < skip; n++) rng_next_float(&r2);
        float ul = rng_next_float(&r2), u1 = rng_next_float(&r2), u2 = rng_next_float(&r2);
        struct rbdpt_nee ns;
        if (!rbdpt_nee_sample(scene, sk.p, ul, u1, u2, &ns)) return false;
        ls = ns.ls;
        wk_world = ns.wi_world;
        cos_l = ns.cos_l;
        direct_pdf_w = ns.direct_pdf_w;
        emission_pdf_w = ns.emission_pdf_w;
        L_k = vec3_scale(ns.Le, 1.0f / direct_pdf_w);
    }
    struct vec3 wk = frame_to_local(&sk.frame, wk_world);
    if (!(vec3_dot(wk_world, sk.ng) * wk.z > 0.0f)) return false;
    struct vec3 fk = material_eval(mk, wo_k, wk, TRANSPORT_RADIANCE);
    float fwd = material_pdf(mk, wo_k, wk), rev = material_pdf(mk, wk, wo_k);
    if (vec3_is_zero(fk)) return false;
    struct vec3 factor_k;
    float B, mis_w = 1.0f;
    if (nee_last) {
        /* w_k is the light sample's direction, drawn independently of w_o: p_k = 1. */
        factor_k = vec3_scale(fk, fabsf(wk.z));
        B = 1.0f;
        if (retrace) {
            if (!bdpt_visible(scene->accel, sk.p, sk.ng, ls.p, &ls.n, rays)) return false;
            const float cos_ng = vec3_dot(wk_world, sk.ng);
            mis_w = restir_bdpt_mis_nee(&mis, fwd, rev, direct_pdf_w, emission_pdf_w, cos_ng, cos_l, c->power);
        } else if (!c->p->copy_mis) {
            mis_w = restir_bdpt_mis_reconnect(RBDPT_RC_NEE_LAST, src->rc.mis_a, src->rc.mis_b, &mis, fwd, rev,
                                              c->power);
        }
    } else {
        if (!(fwd > 0.0f)) return false;
        factor_k = vec3_scale(fk, fabsf(wk.z) / fwd);
        B = fwd;
        restir_bdpt_mis_scatter(&mis, vec3_dot(wk_world, sk.ng), fwd, rev, false, c->power);
        if (!retrace && c->full)
            mis_w = rbdpt_full_weight(&src->rc, &mis);
        else if (!retrace && !c->p->copy_mis)
            mis_w = restir_bdpt_mis_reconnect(k + 1 == e ? RBDPT_RC_EMIT_LAST : RBDPT_RC_AFTER, src->rc.mis_a,
                                              src->rc.mis_b, &mis, fwd, rev, c->power);
    }
    if (!(mis_w > 0.0f) || !isfinite(mis_w)) return false;
    if (!bdpt_visible(scene->accel, s.p, s.ng, sk.p, &sk.ng, rays)) return false;
    *rc_out = src->rc;
    rc_out->pdf = p1 * fabsf(cos_k) / d2 * B;
    struct vec3 head = vec3_mul(beta, vec3_scale(f1, fabsf(wi.z) / p1));
    if (retrace && nee_last) {
        /* The new light sample becomes the sample's (what its later shifts keep). */
        surface_oct_encode(wk_world, &rc_out->wk_u, &rc_out->wk_v);
        restir_bdpt_rc_mis_nee(fwd, rev, direct_pdf_w, emission_pdf_w, vec3_dot(wk_world, sk.ng), cos_l, true, 1.0f,
                               c->power, &rc_out->mis_a, &rc_out->mis_b);
        if (c->p->copy_mis) {
            L_k = vec3_scale(L_k, mis_w);
            mis_w = 1.0f;
        }
        rc_out->L = L_k;
        *C = vec3_scale(vec3_mul(head, vec3_mul(factor_k, L_k)), mis_w);
    } else if (retrace) {
        /* The suffix in this scene: x_k's scattering along w_k, then the rest as the sample's own
         * random numbers trace it (those of vertices 1 .. k skipped). */
        struct rng r2 = rng_make(c->seed, src->r.origin_frame, RBDPT_CAMERA_STREAM + src->r.light_path, 0);
        const uint32_t skip = RBDPT_CAMERA_JITTER_DRAWS + draws * k;
        for (uint32_t n = 0; n < skip; n++) rng_next_float(&r2);
        const struct rbdpt_resume resume = {.org = bdpt_origin(&sk, wk_world), .dir = wk_world, .prev_p = sk.p,
                                            .beta = vec3_mul(head, factor_k), .mis = mis, .rc = *rc_out};
        struct rbdpt_want want = {.bits = src->r.head.bits, .k = k, .lv = lv, .lv_path = src->rc.light_path,
                                  .found = false};
        struct vec3 primary;
        bool has_primary;
        rbdpt_camera_candidates(c, v, wk_world, src->r.light_path, src->r.origin_frame, &r2, NULL, NULL, rays, NULL,
                                &primary, &has_primary, &want, &resume);
        if (!want.found) return false;
        *C = want.C;
        *rc_out = want.rc;
    } else {
        *C = vec3_scale(vec3_mul(head, vec3_mul(factor_k, src->rc.L)), mis_w);
    }
    *J = rc_out->pdf / src->rc.pdf *
         surface_area_ratio(scene_from, scene, src->rc.shape, src->rc.prim, src->rc.b1, src->rc.b2);
    return isfinite(*J) && *J > 0.0f && vec3_is_finite(*C);
}

/* The reverse hybrid shift of a non-caustic t = 1 sample whose x_2 has only rough lobes (seed
 * 000 §6.1, "light tracing, non-caustic"): its light subpath is replayed with its random numbers
 * in view v up to x'_2, and joined to the new x'_1: the surface the eye sees through the same
 * point of the target pixel (the sample's sub-pixel position, kept in rc.b1 / rc.b2), so the
 * shift maps the paths through one pixel one-to-one onto those through the other. Jacobian:
 * the image-area density of x_1's direction at x_2, p_2(w) |cos_1| / d^2 / p_camera,A(x_1), of
 * the new path over the old (rc.pdf). False when the shift fails. */
static bool rbdpt_reverse(const struct rbdpt_ctx *c, const struct rbdpt_view *v, const struct restir_bdpt_path *src,
                          uint32_t from_pixel, uint32_t pixel, struct vec3 *C, float *J, float *pdf,
                          struct ray_counters *rays)
{
    const uint32_t depth = (uint32_t)(src->r.head.bits >> 8) - 1u;   /* x_1's light depth */
    if (depth < 2 || !(src->rc.pdf > 0.0f)) return false;
    struct rbdpt_x2 x2;
    if (!rbdpt_x2_cached(c, v, from_pixel, src, &x2) &&
        !rbdpt_trace_light(c, v, src->r.origin_frame, src->r.light_path, depth, NULL, 0, NULL, NULL, NULL, NULL, &x2,
                           rays))
        return false;
    if (!rbdpt_rough(x2.m)) return false;
    const struct camera *cam = &v->cam;
    const uint32_t w = c->st->width;
    struct vec3 dir = camera_ray_dir(cam, (float)(pixel % w) + src->rc.b1, (float)(pixel / w) + src->rc.b2);
    struct hit hit;
    if (!accel_intersect(v->scene->accel, cam->position, dir, 0.0f, INFINITY, &hit, rays)) return false;
    struct surface x1;
    surface_from_hit(v->scene, &hit, cam->position, dir, &x1);
    uint32_t px;
    float mis_w;
    if (!rbdpt_t1_eval(c, v, &x2, &x1, rays, &px, C, NULL, pdf, &mis_w) || px != pixel) return false;
    if (!bdpt_visible(v->scene->accel, x2.s.p, x2.s.ng, x1.p, &x1.ng, rays)) return false;
    /* copy_mis: the weight the sample was drawn with (seed 000 §6.4), not the new path's. */
    if (c->p->copy_mis) *C = vec3_scale(*C, src->rc.mis_a / mis_w);
    *J = *pdf / src->rc.pdf;
    return isfinite(*J) && *J > 0.0f;
}

/* The reconnection record of a pixel's selected t = 1 sample of the reverse hybrid shift's
 * class, found once it is selected rather than kept for every light-traced sample: the light
 * subpath is replayed to x_2, x_1 found along the direction x_2 sampled, and the sub-pixel
 * position and Jacobian denominator taken from rbdpt_t1_eval, which made the sample. False (the
 * sample then never shifts) if the replay does not give it back. */
static bool rbdpt_reverse_record(const struct rbdpt_ctx *c, uint32_t pixel, struct restir_bdpt_path *res,
                                 struct ray_counters *rays)
{
    const struct rbdpt_view *v = &c->view[0];
    const uint32_t depth = (uint32_t)(res->r.head.bits >> 8) - 1u;
    struct rbdpt_x2 x2;
    if (!rbdpt_trace_light(c, v, res->r.origin_frame, res->r.light_path, depth, NULL, 0, NULL, NULL, NULL, NULL, &x2,
                           rays))
        return false;
    struct hit hit;
    struct vec3 org = bdpt_origin(&x2.s, x2.dir);
    if (!accel_intersect(v->scene->accel, org, x2.dir, 0.0f, INFINITY, &hit, rays)) return false;
    struct surface x1;
    surface_from_hit(v->scene, &hit, org, x2.dir, &x1);
    uint32_t px;
    struct vec3 C;
    float sub[2], pdf, mis_w;
    if (!rbdpt_t1_eval(c, v, &x2, &x1, rays, &px, &C, sub, &pdf, &mis_w)) return false;
    res->rc.b1 = sub[0];
    res->rc.b2 = sub[1];
    res->rc.pdf = pdf;
    res->rc.mis_a = mis_w;
    if (c->st->x2c) rbdpt_x2_keep(c, pixel, res, &x2);
    return true;
}

/* `reject_unshiftable` (seed 000 §7.2, "stable but biased temporal reuse of light traced
 * samples"): whether the non-caustic t = 1 sample of light subpath `light_path` (frame
 * `origin_frame`, x_1 at light depth `depth`) could be joined to the pixel's primary hit `xg`
 * instead of its own x_1 — x_2 scatters (or, at depth 1, emits) towards xg, xg scatters towards
 * the eye, and the two see each other. A sample the eye sees at x_1 through another surface than
 * the primary hit fails (Fig. 6); dropping it darkens penumbrae a little. */
static bool rbdpt_reaches_primary(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t origin_frame,
                                  uint32_t light_path, uint32_t depth, const struct surface *xg,
                                  struct ray_counters *rays)
{
    const struct material *mg = &v->scene->materials[xg->material];
    if (!(material_flags(mg) & (BSDF_DIFFUSE | BSDF_GLOSSY))) return false;
    struct vec3 p2, n2;
    struct rbdpt_x2 x2;
    if (depth == 1) {
        struct rng rng;
        struct bdpt_light_start start;
        if (!rbdpt_light_stream(c, v->scene, origin_frame, light_path, &rng, &start)) return false;
        p2 = start.ls.p;
        n2 = start.n;
        if (!(vec3_dot(vec3_sub(xg->p, p2), n2) > 0.0f)) return false;
    } else {
        if (!rbdpt_trace_light(c, v, origin_frame, light_path, depth, NULL, 0, NULL, NULL, NULL, NULL, &x2, rays))
            return false;
        p2 = x2.s.p;
        n2 = x2.s.ng;
        struct vec3 w = vec3_normalize(vec3_sub(xg->p, p2));
        struct vec3 wi = frame_to_local(&x2.s.frame, w), wo = frame_to_local(&x2.s.frame, x2.wo_world);
        if (!(vec3_dot(w, n2) * wi.z > 0.0f) ||
            vec3_is_zero(material_eval(x2.m, wo, wi, TRANSPORT_IMPORTANCE)))
            return false;
    }
    struct vec3 to2 = vec3_normalize(vec3_sub(p2, xg->p));
    struct vec3 toeye = vec3_normalize(vec3_sub(v->cam.position, xg->p));
    struct vec3 wi = frame_to_local(&xg->frame, to2), wo = frame_to_local(&xg->frame, toeye);
    if (!(vec3_dot(to2, xg->ng) * wi.z > 0.0f) || !(vec3_dot(toeye, xg->ng) * wo.z > 0.0f) ||
        vec3_is_zero(material_eval(mg, wo, wi, TRANSPORT_RADIANCE)))
        return false;
    return bdpt_visible(v->scene->accel, p2, n2, xg->p, &xg->ng, rays);
}

/* The shift of a non-caustic sample into domain `to`:
 *  - s = 0 and s = 1 with a reconnection: the hybrid shift (rbdpt_reconnect; between frames
 *    whose scenes differ with its suffix traced again);
 *  - s = 0 and s = 1 otherwise: random replay, whose Jacobian in primary sample space is 1 (the
 *    identity on the random numbers): the camera subpath of the sample's own random stream (the
 *    pixel and frame it was drawn in) is traced again through the target pixel (its jitter from
 *    that stream) in the target frame's scene and camera, and the candidate of the same
 *    technique and length is the shifted sample, its lightweight MIS weight and reconnection
 *    recomputed on the new path. Between frames whose scenes agree a sample without a
 *    reconnection must shift to one without (the hybrid shift's replay-only class);
 *  - t = 1 of the reverse hybrid shift's class (rc.k = 1): rbdpt_reverse;
 *  - other t = 1: the light subpath is replayed in the target frame; the shift succeeds only when
 *    the replayed sample lands in the target pixel and is still non-caustic and outside that
 *    class (such a sample belongs to the pixel it lands in: it cannot move to a neighbour).
 * A replay that ends early, misses the technique or changes class fails (target 0). */
static void rbdpt_shift(const void *ctx, const void *src_v, struct restir_domain from, struct restir_domain to,
                        void *dst_v, float *target, float *jacobian, struct restir_counters *cnt)
{
    const struct rbdpt_ctx *c = ctx;
    const struct restir_bdpt_path *src = src_v;
    const struct rbdpt_view *v = &c->view[to.frame == RESTIR_PREVIOUS ? 1 : 0];
    const uint32_t w = c->st->width;
    *target = 0.0f;
    *jacobian = 1.0f;
    struct vec3 C = {0, 0, 0};
    struct restir_bdpt_rc rc = src->rc;
    const struct scene *scene_from = c->view[from.frame == RESTIR_PREVIOUS ? 1 : 0].scene;
    /* s >= 2: the sample's light vertex in the target scene, needed unless the hybrid shift keeps
     * it (reconnected before the connecting vertex, in a scene where the light subpath replays
     * to the same vertices). */
    struct bdpt_light_vertex lv = {0};
    const struct bdpt_light_vertex *lvp = NULL;
    if (rbdpt_is_connection(src)) {
        const uint32_t tech = src->r.head.bits & 0xffu, e = (uint32_t)(src->r.head.bits >> 8);
        const bool moved = (scene_from != v->scene && !c->static_scene) || c->force_retrace;
        if (src->rc.k < 2 || src->rc.k + tech == e || moved) lvp = &lv;
    }
    bool ok = false;
    if ((src->r.head.bits & 0xffu) == RESTIR_BDPT_TECH_LT && src->rc.k) {
        float pdf;
        ok = rbdpt_reverse(c, v, src, from.frame == RESTIR_CURRENT ? from.pixel : UINT32_MAX, to.pixel, &C, jacobian,
                           &pdf, &cnt->rays);
        if (ok) rc.pdf = pdf;
        atomic_fetch_add_explicit(c->reconnections, 1, memory_order_relaxed);
    } else if ((src->r.head.bits & 0xffu) == RESTIR_BDPT_TECH_LT) {
        struct restir_bdpt_lt_sample out;
        uint32_t stored = 0, dropped = 0;
        rbdpt_trace_light(c, v, src->r.origin_frame, src->r.light_path, (uint32_t)(src->r.head.bits >> 8) - 1u, &out,
                          1, &stored, &dropped, NULL, NULL, NULL, &cnt->rays);
        /* It stays in its class: a replayed sample of the reverse hybrid shift's would not shift back. */
        ok = stored == 1 && !out.caustic && !out.hybrid && out.pixel == to.pixel;
        if (ok) C = out.F;
    } else if (lvp && !rbdpt_light_vertex_of(c, v, from.frame == RESTIR_CURRENT ? from.pixel : UINT32_MAX, src,
                                             false, &lv, &cnt->rays)) {
        ok = false;
    } else if (src->rc.k >= 2) {
        ok = rbdpt_reconnect(c, v, scene_from, src, lvp, to.pixel, &C, jacobian, &rc, &cnt->rays);
        atomic_fetch_add_explicit(c->reconnections, 1, memory_order_relaxed);
    } else {
        struct rng rng = rng_make(c->seed, src->r.origin_frame, RBDPT_CAMERA_STREAM + src->r.light_path, 0);
        float jx = rng_next_float(&rng), jy = rng_next_float(&rng);
        struct vec3 dir = camera_ray_dir(&v->cam, (float)(to.pixel % w) + jx, (float)(to.pixel / w) + jy);
        struct rbdpt_want want = {.bits = src->r.head.bits, .k = 0, .lv = lvp, .lv_path = src->rc.light_path,
                                  .found = false};
        struct vec3 primary;
        bool has_primary;
        rbdpt_camera_candidates(c, v, dir, src->r.light_path, src->r.origin_frame, &rng, NULL, NULL, &cnt->rays,
                                NULL, &primary, &has_primary, &want, NULL);
        ok = want.found;
        C = want.C;
    }
    if (!ok || !vec3_is_finite(C)) {
        *jacobian = 1.0f;
        return;
    }
    *target = vec3_luminance(C);
    if (dst_v && *target > 0.0f) {
        struct restir_bdpt_path *dst = dst_v;
        *dst = *src;
        dst->r.F = C;
        dst->rc = rc;
    }
}

static float rbdpt_target(const void *ctx, const void *elem)
{
    (void)ctx;
    return vec3_luminance(((const struct restir_bdpt_path *)elem)->r.F);
}

/* Every pixel can produce samples: its camera subpaths are jittered over the whole pixel, and
 * light-traced samples land anywhere (a G-buffer ray that escaped says nothing about them). */
static bool rbdpt_domain_valid(const void *ctx, struct restir_domain d)
{
    (void)ctx;
    (void)d;
    return true;
}

static const struct restir_ops rbdpt_ops = {.stride = sizeof(struct restir_bdpt_path), .target = rbdpt_target,
                                            .shift = rbdpt_shift, .domain_valid = rbdpt_domain_valid};

/* The caustic reservoir's confidence (eq. 27): 1 for this frame's initial samples plus the
 * confidence of the previous caustic reservoir that the primary hit maps to with the previous
 * camera — independent of where caustic samples happen to land. */
static uint16_t rbdpt_caustic_confidence(const struct rbdpt_ctx *c, struct vec3 primary, bool has_primary)
{
    uint32_t M = 1;
    if (c->p->caustic_temporal && c->has_prev && c->st->has_history && has_primary) {
        float px, py;
        const struct camera *pc = &c->view[1].cam;
        if (camera_project(pc, primary, &px, &py) && px >= 0.0f && py >= 0.0f && px < (float)pc->width &&
            py < (float)pc->height) {
            uint32_t v = (uint32_t)py * pc->width + (uint32_t)px;
            if (v < pc->width * pc->height) M += c->st->caustic_prev[v].head.M;
        }
    }
    if (M > c->caustic_cap) M = c->caustic_cap;
    return (uint16_t)M;
}

static void rbdpt_camera_tile(void *ctx, uint32_t tile, unsigned worker)
{
    struct rbdpt_ctx *c = ctx;
    struct restir_bdpt_state *st = c->st;
    struct rbdpt_worker *wk = &c->worker[worker];
    struct ray_counters rc = {0, 0};
    uint32_t w = st->width, h = st->height;
    uint32_t x0 = (tile % c->tiles_x) * RBDPT_TILE, y0 = (tile / c->tiles_x) * RBDPT_TILE;
    uint32_t x1 = x0 + RBDPT_TILE < w ? x0 + RBDPT_TILE : w, y1 = y0 + RBDPT_TILE < h ? y0 + RBDPT_TILE : h;
    bool temporal = c->p->caustic_temporal && c->has_prev && st->has_history;
    for (uint32_t y = y0; y < y1; y++) {
        for (uint32_t x = x0; x < x1; x++) {
            uint32_t pixel = y * w + x;
            struct rng rng = rng_make(c->seed, c->frame, RBDPT_CAMERA_STREAM + pixel, 0);
            struct rng pick = rng_make(c->seed, c->frame, RBDPT_PICK_STREAM + pixel, 0);
            float jx = rng_next_float(&rng), jy = rng_next_float(&rng);
            struct vec3 dir = camera_ray_dir(&c->view[0].cam, (float)x + jx, (float)y + jy);
            struct rbdpt_ris r = {0.0, 0.0f, {0, 0, 0}, 0, UINT32_MAX, 0};
            struct rbdpt_ris rcau = r;
            struct vec3 primary = {0, 0, 0};
            bool has_primary;
            rbdpt_camera_candidates(c, &c->view[0], dir, pixel, c->frame, &rng, &pick, &r, &rc, wk, &primary,
                                    &has_primary, NULL, NULL);
            /* The pixel's bucket of light-traced samples (eq. 26: C carries 1/N_L). */
            struct surface xg;
            int xg_state = 0;   /* reject_unshiftable: the primary hit, traced when first needed (1: hit, -1: none) */
            for (uint32_t k = st->pixel_first[pixel]; k < st->pixel_first[pixel + 1]; k++) {
                const struct restir_bdpt_lt_sample *ls = &st->lt_sorted[k];
                uint16_t bits = (uint16_t)(((uint32_t)(ls->depth + 1) << 8) | RESTIR_BDPT_TECH_LT);
                if (c->p->reject_unshiftable && !ls->caustic) {
                    if (xg_state == 0) {
                        struct hit hit;
                        xg_state = -1;
                        if (accel_intersect(c->view[0].scene->accel, c->view[0].cam.position, dir, 0.0f, INFINITY,
                                            &hit, &rc)) {
                            surface_from_hit(c->view[0].scene, &hit, c->view[0].cam.position, dir, &xg);
                            xg_state = 1;
                        }
                    }
                    if (xg_state < 0 || !rbdpt_reaches_primary(c, &c->view[0], c->frame, ls->light_path, ls->depth,
                                                               &xg, &rc)) {
                        wk->unshiftable++;
                        continue;
                    }
                }
                if (ls->hybrid && !ls->caustic) {
                    /* Marks the reverse hybrid shift's class; the record is filled in once selected. */
                    const struct restir_bdpt_rc mark = {.k = 1};
                    rbdpt_ris_add_rc(&r, ls->F, vec3_luminance(ls->F), bits, ls->light_path, c->frame, &mark, &pick,
                                     wk);
                } else {
                    rbdpt_ris_add(ls->caustic ? &rcau : &r, ls->F, bits, ls->light_path, c->frame, &pick, wk);
                }
            }
            rbdpt_ris_finish_path(&r, 1, &st->res[pixel]);
            if (st->res[pixel].rc.k == 1 && st->res[pixel].r.head.W > 0.0f &&
                !rbdpt_reverse_record(c, pixel, &st->res[pixel], &rc))
                st->res[pixel].rc.pdf = 0.0f;
            /* A connection drawn in this frame joins a vertex of this frame's cache: the one its
             * replay gives back. */
            if (st->x2c && r.lv && rbdpt_is_connection(&st->res[pixel]) && st->res[pixel].r.head.W > 0.0f)
                rbdpt_light_vertex_keep(c, pixel, &st->res[pixel], r.lv);
            uint16_t M = rbdpt_caustic_confidence(c, primary, has_primary);
            if (temporal) {
                /* Appendix A: the initial caustic reservoir (confidence 1) against the previous
                 * frame's reservoirs whose replayed samples landed here. */
                struct rbdpt_ris merged = {0.0, 0.0f, {0, 0, 0}, 0, UINT32_MAX, 0};
                if (rcau.target > 0.0f) {
                    /* eq. 52: the inverse shift of the initial sample into the previous frame. */
                    uint32_t v;
                    struct vec3 Fp;
                    double denom = rcau.target;
                    wk->shifts++;
                    if (rbdpt_replay_caustic(c, &c->view[1], rcau.origin_frame, rcau.light_path,
                                             (uint32_t)(rcau.bits >> 8) - 1u, &v, &Fp, &rc) == RBDPT_REPLAY_OK) {
                        denom += (double)st->caustic_prev[v].head.M * vec3_luminance(Fp);
                    } else {
                        wk->inverse_failed++;
                    }
                    double m = rcau.target / denom;
                    rbdpt_ris_add_w(&merged, rcau.F, m * rcau.wsum, rcau.bits, rcau.light_path, rcau.origin_frame,
                                    &pick, wk);
                }
                for (uint32_t k = st->shift_first[pixel]; k < st->shift_first[pixel + 1]; k++) {
                    const struct restir_bdpt_shifted *sh = &st->shifted_sorted[k];
                    uint16_t bits = (uint16_t)(((uint32_t)(sh->depth + 1) << 8) | RESTIR_BDPT_TECH_LT);
                    rbdpt_ris_add_w(&merged, sh->F, sh->w, bits, sh->light_path, sh->origin_frame, &pick, wk);
                }
                rbdpt_ris_finish(&merged, M, &st->caustic[pixel]);
            } else {
                rbdpt_ris_finish(&rcau, M, &st->caustic[pixel]);
            }
            /* With reuse the non-caustic estimate is added after the reuse passes. */
            struct vec3 L = vec3_scale(st->caustic[pixel].F, st->caustic[pixel].head.W);
            if (!c->p->reuse) L = vec3_add(L, vec3_scale(st->res[pixel].r.F, st->res[pixel].r.head.W));
            c->out->pixels[pixel] = L;
        }
    }
    wk->rays_intersect += rc.intersect;
    wk->rays_occluded += rc.occluded;
}

/* The previous frame's caustic reservoirs, each replayed into the current frame (eq. 51): one
 * job per row of source pixels, each writing only its own slots. */
static void rbdpt_history_row(void *ctx, uint32_t row, unsigned worker)
{
    struct rbdpt_ctx *c = ctx;
    struct restir_bdpt_state *st = c->st;
    struct rbdpt_worker *wk = &c->worker[worker];
    struct ray_counters rc = {0, 0};
    for (uint32_t x = 0; x < st->width; x++) {
        uint32_t v = row * st->width + x;
        const struct restir_bdpt_reservoir *prev = &st->caustic_prev[v];
        struct restir_bdpt_shifted *sh = &st->shifted[v];
        sh->valid = 0;
        float p_prev = vec3_luminance(prev->F);
        if (!(prev->head.W > 0.0f) || !(p_prev > 0.0f)) continue;
        wk->shifts++;
        uint32_t depth = (uint32_t)(prev->head.bits >> 8) - 1u;
        uint32_t q;
        struct vec3 F;
        enum rbdpt_replay res = rbdpt_replay_caustic(c, &c->view[0], prev->origin_frame, prev->light_path, depth, &q,
                                                     &F, &rc);
        if (res != RBDPT_REPLAY_OK) {
            if (res == RBDPT_REPLAY_FAILED) wk->replay_failed++; else wk->not_caustic++;
            continue;
        }
        float p_cur = vec3_luminance(F);
        if (!(p_cur > 0.0f)) {
            wk->replay_failed++;
            continue;
        }
        /* eq. 51 with |dT/dX| = 1 (random replay) and the initial sample's confidence 1. */
        double mp = (double)prev->head.M * p_prev;
        double m = mp / (mp + p_cur);
        *sh = (struct restir_bdpt_shifted){.F = F, .w = (float)(m * p_cur * prev->head.W), .pixel = q,
                                           .light_path = prev->light_path, .origin_frame = prev->origin_frame,
                                           .depth = (uint16_t)depth, .valid = 1};
    }
    wk->rays_intersect += rc.intersect;
    wk->rays_occluded += rc.occluded;
}

/* Before the spatial pass: every pixel's sample of the reverse hybrid shift's class gets its x_2
 * in this frame's scene into the cache, and every connection its light vertex, so that its
 * shifts to the neighbours (and theirs) do not each replay its light subpath; most were kept
 * when the sample was drawn, the rest came from the history. One job per row, each writing its
 * own pixels. */
static void rbdpt_x2_row(void *ctx, uint32_t row, unsigned worker)
{
    struct rbdpt_ctx *c = ctx;
    struct restir_bdpt_state *st = c->st;
    struct rbdpt_worker *wk = &c->worker[worker];
    struct ray_counters rc = {0, 0};
    for (uint32_t x = 0; x < st->width; x++) {
        uint32_t pixel = row * st->width + x;
        const struct restir_bdpt_path *res = &st->res[pixel];
        struct rbdpt_x2 x2;
        if (rbdpt_is_connection(res) && res->r.head.W > 0.0f) {
            struct bdpt_light_vertex lv;
            rbdpt_light_vertex_of(c, &c->view[0], pixel, res, true, &lv, &rc);
            continue;
        }
        if ((res->r.head.bits & 0xffu) != RESTIR_BDPT_TECH_LT || res->rc.k != 1 || !(res->r.head.W > 0.0f) ||
            rbdpt_x2_cached(c, &c->view[0], pixel, res, &x2))
            continue;
        if (rbdpt_trace_light(c, &c->view[0], res->r.origin_frame, res->r.light_path,
                              (uint32_t)(res->r.head.bits >> 8) - 1u, NULL, 0, NULL, NULL, NULL, NULL, &x2, &rc))
            rbdpt_x2_keep(c, pixel, res, &x2);
    }
    wk->rays_intersect += rc.intersect;
    wk->rays_occluded += rc.occluded;
}

static double rbdpt_ms_since(const struct timespec *t0)
{
    struct timespec t1;
    clock_gettime(CLOCK_MONOTONIC, &t1);
    return (double)(t1.tv_sec - t0->tv_sec) * 1e3 + (double)(t1.tv_nsec - t0->tv_nsec) * 1e-6;
}

bool restir_bdpt_render(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                        const struct method_frame *f, struct image *out, struct restir_bdpt_stats *stats,
                        struct err *err)
{
    if (!restir_bdpt_params_valid(p, err)) return false;
    if (!f->scene->accel || !f->scene->lights) return err_set(err, ERR_INVALID, NULL, "scene is not committed");
    if (!vec3_is_zero(f->scene->env_radiance))
        return err_set(err, ERR_INVALID, NULL, "restir_bdpt does not support environment light");
    if (out->width != st->width || out->height != st->height || !out->pixels)
        return err_set(err, ERR_INVALID, NULL, "the output image is %ux%u, the state %ux%u", out->width, out->height,
                       st->width, st->height);
    struct rbdpt_sizes z = rbdpt_sizes_of(p, st->width, st->height);
    if (z.light_paths != st->light_paths || z.region != st->region || z.lvc_region != st->lvc_region)
        return err_set(err, ERR_INVALID, NULL, "the parameters changed the buffers' sizes since init");
    unsigned threads = f->threads ? f->threads : parallel_default_threads();
    if (threads > RBDPT_MAX_WORKERS) threads = RBDPT_MAX_WORKERS;

    struct rbdpt_ctx ctx_storage;
    struct rbdpt_ctx *c = &ctx_storage;
    memset(c, 0, sizeof *c);
    c->p = p;
    c->st = st;
    for (int k = 0; k < 2; k++) {
        const struct scene *sc = k ? f->prev_scene : f->scene;
        const struct camera_desc *cd = k ? f->prev_camera : f->camera;
        if (!sc || !cd) continue;
        c->view[k].scene = sc;
        camera_init(&c->view[k].cam, cd, st->width, st->height);
        float plane = (float)st->height / (2.0f * c->view[k].cam.tan_half_fov_y);
        c->view[k].plane_dist2 = plane * plane;
    }
    c->has_prev = f->prev_scene && f->prev_camera && f->prev_scene->accel && f->prev_scene->lights;
    if (!c->has_prev) st->has_history = false;
    /* Eq. 27 takes a caustic reservoir's confidence from the pixel the camera's motion maps it
     * to, but caustics move with their lights and casters, not with the camera (seed 000 §9.1):
     * in a frame whose scene moved the reservoirs under the caustic hold history that no longer
     * lies where they are, and with the cap of a still scene (20) a moving caustic's error grows
     * over the frames. A lower cap there bounds that history. The test reads only the scenes,
     * never the samples, so the weights stay a valid MIS whatever it decides. */
    const bool moved = c->has_prev && scene_moved(f->prev_scene, f->scene);
    c->caustic_cap = moved ? p->moving_cap : p->temporal_cap;
    c->static_scene = c->has_prev && !moved;
    _Atomic uint64_t reconnections = 0;
    c->reconnections = &reconnections;
    c->n_light = (float)st->light_paths;
    c->seed = f->seed;
    c->frame = f->frame;
    c->power = p->heuristic == BDPT_HEURISTIC_POWER;
    c->full = p->variant == RESTIR_BDPT_FULL;
    c->out = out;

    struct restir_bdpt_stats s = {0};
    struct timespec t0;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    if (!parallel_run(threads, st->blocks, rbdpt_light_block, c, NULL, NULL, err)) return false;
    if (c->full) {
        /* The cache's canonical order: blocks in order, each block's vertices in order. */
        st->lvc_first[0] = 0;
        for (uint32_t b = 0; b < st->blocks; b++) {
            st->lvc_first[b + 1] = st->lvc_first[b] + st->lvc_count[b];
            s.lvc_dropped += st->lvc_dropped[b];
        }
        c->lvc = (struct bdpt_lvc_view){st->lvc, st->lvc_first, st->blocks, st->lvc_region, st->lvc_first[st->blocks],
                                        (float)((double)st->lvc_first[st->blocks] / (double)st->light_paths)};
    }
    s.light_ms = rbdpt_ms_since(&t0);

    /* Counting sort of the light-traced samples by pixel: counts, exclusive prefix sum, then a
     * stable scatter in block order — the buckets' contents and order depend only on the seed. */
    clock_gettime(CLOCK_MONOTONIC, &t0);
    uint32_t npix = st->width * st->height;
    memset(st->pixel_first, 0, ((size_t)npix + 1) * sizeof *st->pixel_first);
    for (uint32_t b = 0; b < st->blocks; b++) {
        const struct restir_bdpt_lt_sample *v = &st->lt[(size_t)b * st->region];
        for (uint32_t j = 0; j < st->block_count[b]; j++) st->pixel_first[v[j].pixel + 1]++;
        s.lt_dropped += st->block_dropped[b];
        s.rays_intersect += st->block_rays[3 * b];
        s.rays_occluded += st->block_rays[3 * b + 1];
        s.light_vertices += st->block_rays[3 * b + 2];
    }
    for (uint32_t i = 0; i < npix; i++) st->pixel_first[i + 1] += st->pixel_first[i];
    for (uint32_t b = 0; b < st->blocks; b++) {
        const struct restir_bdpt_lt_sample *v = &st->lt[(size_t)b * st->region];
        for (uint32_t j = 0; j < st->block_count[b]; j++) {
            /* pixel_first[pixel] is advanced as a cursor and restored below. */
            st->lt_sorted[st->pixel_first[v[j].pixel]++] = v[j];
            s.light_traced++;
            s.caustic_samples += v[j].caustic;
        }
    }
    for (uint32_t i = npix; i > 0; i--) st->pixel_first[i] = st->pixel_first[i - 1];
    st->pixel_first[0] = 0;
    s.sort_ms = rbdpt_ms_since(&t0);

    /* Caustic temporal reuse: replay the previous caustic samples, then sort them by the pixel
     * they land in (the same counting sort, in source-pixel order). */
    uint32_t *sf = st->shift_first;
    memset(sf, 0, ((size_t)npix + 1) * sizeof *sf);
    if (p->caustic_temporal && c->has_prev && st->has_history) {
        clock_gettime(CLOCK_MONOTONIC, &t0);
        if (!parallel_run(threads, st->height, rbdpt_history_row, c, NULL, NULL, err)) return false;
        for (uint32_t v = 0; v < npix; v++)
            if (st->shifted[v].valid) sf[st->shifted[v].pixel + 1]++;
        for (uint32_t i = 0; i < npix; i++) sf[i + 1] += sf[i];
        for (uint32_t v = 0; v < npix; v++)
            if (st->shifted[v].valid) st->shifted_sorted[sf[st->shifted[v].pixel]++] = st->shifted[v];
        for (uint32_t i = npix; i > 0; i--) sf[i] = sf[i - 1];
        sf[0] = 0;
        s.sort_ms += rbdpt_ms_since(&t0);
    }

    clock_gettime(CLOCK_MONOTONIC, &t0);
    c->tiles_x = (st->width + RBDPT_TILE - 1) / RBDPT_TILE;
    uint32_t tiles_y = (st->height + RBDPT_TILE - 1) / RBDPT_TILE;
    if (!parallel_run(threads, c->tiles_x * tiles_y, rbdpt_camera_tile, c, NULL, NULL, err)) return false;
    s.camera_ms = rbdpt_ms_since(&t0);

    if (p->reuse) {
        /* Temporal reuse of the non-caustic reservoirs along the G-buffer's motion vectors, then
         * spatial reuse (restir.c: generalized balance heuristic, defensive pairwise MIS), with
         * the random-replay shift above; the final reservoirs become the next frame's history. */
        clock_gettime(CLOCK_MONOTONIC, &t0);
        uint64_t grays = 0;
        struct gbuffer_frame gf = {.scene = f->scene, .camera = f->camera, .prev_scene = c->has_prev ? f->prev_scene : NULL,
                                   .prev_camera = c->has_prev ? f->prev_camera : NULL, .seed = f->seed,
                                   .frame = f->frame, .threads = f->threads};
        if (!gbuffer_render(&st->gbuf, &gf, &grays, err)) return false;
        s.rays_intersect += grays;
        struct restir_reuse rr = {.ops = &rbdpt_ops, .ctx = c, .width = st->width, .height = st->height,
                                  .seed = f->seed, .frame = f->frame, .threads = f->threads, .gbuf = &st->gbuf,
                                  .history = c->has_prev && st->has_history ? (const uint8_t *)st->res_prev : NULL,
                                  .temporal_cap = p->temporal_cap, .neighbors = p->spatial_neighbors,
                                  .radius = p->spatial_radius, .paired = p->paired_spatial,
                                  .pair_scratch = st->pair_scratch};
        struct restir_counters rc = {{0, 0}, 0, 0, 0};
        if (rr.history && !restir_temporal_pass(&rr, (uint8_t *)st->res, &rc, err)) return false;
        struct restir_bdpt_path *final = st->res;
        if (p->spatial_neighbors) {
            if (st->x2c && !parallel_run(threads, st->height, rbdpt_x2_row, c, NULL, NULL, err)) return false;
            if (!restir_spatial_pass(&rr, (const uint8_t *)st->res, (uint8_t *)st->res_spatial, &rc, err)) return false;
            final = st->res_spatial;
        }
        for (uint32_t i = 0; i < npix; i++)
            out->pixels[i] = vec3_add(out->pixels[i], vec3_scale(final[i].r.F, final[i].r.head.W));
        /* The final buffer becomes the history; the old history is the next frame's scratch. */
        struct restir_bdpt_path *old = st->res_prev;
        st->res_prev = final;
        if (final == st->res) st->res = old; else st->res_spatial = old;
        s.rays_intersect += rc.rays.intersect;
        s.rays_occluded += rc.rays.occluded;
        s.reuse_shifts = rc.shifts;
        s.reuse_shift_failures = rc.shift_failures;
        s.reuse_reconnections = atomic_load(&reconnections);
        s.rejected += rc.rejected;
        s.reuse_ms = rbdpt_ms_since(&t0);
    }

    for (unsigned i = 0; i < threads; i++) {
        s.rays_intersect += c->worker[i].rays_intersect;
        s.rays_occluded += c->worker[i].rays_occluded;
        s.camera_candidates += c->worker[i].candidates;
        s.rejected += c->worker[i].rejected;
        s.caustic_shifts += c->worker[i].shifts;
        s.caustic_replay_failed += c->worker[i].replay_failed;
        s.caustic_not_caustic += c->worker[i].not_caustic;
        s.caustic_inverse_failed += c->worker[i].inverse_failed;
        s.connections += c->worker[i].connections;
        s.lt_unshiftable += c->worker[i].unshiftable;
    }
    /* This frame's caustic reservoirs become the history of the next. */
    struct restir_bdpt_reservoir *tmp = st->caustic_prev;
    st->caustic_prev = st->caustic;
    st->caustic = tmp;
    st->has_history = true;
    s.light_subpaths = st->light_paths;
    s.reservoir_bytes = restir_bdpt_reservoir_bytes(st);
    if (stats) *stats = s;
    return true;
}

/* Tests only: a context for one view (its worker array on the heap rather than the stack). */
static struct rbdpt_ctx *rbdpt_test_ctx(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                                        const struct method_frame *f, _Atomic uint64_t *reconnections)
{
    struct rbdpt_ctx *c = calloc(1, sizeof *c);
    if (!c) return NULL;
    c->p = p;
    c->st = st;
    c->view[0].scene = f->scene;
    camera_init(&c->view[0].cam, f->camera, st->width, st->height);
    float plane = (float)st->height / (2.0f * c->view[0].cam.tan_half_fov_y);
    c->view[0].plane_dist2 = plane * plane;
    c->n_light = (float)st->light_paths;
    c->seed = f->seed;
    c->frame = f->frame;
    c->power = p->heuristic == BDPT_HEURISTIC_POWER;
    c->full = p->variant == RESTIR_BDPT_FULL;
    c->reconnections = reconnections;
    return c;
}

int restir_bdpt_shift_round_trip(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                                 const struct method_frame *f, const struct method_frame *f_to,
                                 uint32_t pixel, uint32_t to, float target[3], float *jj)
{
    if (!st->res_prev) return -1;
    const struct restir_bdpt_path *x = &st->res_prev[pixel];   /* the frame just rendered */
    if (!(x->r.head.W > 0.0f)) return -1;
    _Atomic uint64_t reconnections = 0;
    struct rbdpt_ctx *c = rbdpt_test_ctx(st, p, f, &reconnections);
    if (!c) return -1;
    const bool lt = (x->r.head.bits & 0xffu) == RESTIR_BDPT_TECH_LT;
    const int kind = lt ? (x->rc.k ? 1 : 0) : rbdpt_is_connection(x) ? (x->rc.k >= 2 ? 4 : 3) : (x->rc.k >= 2 ? 2 : 0);
    struct restir_counters cnt = {{0, 0}, 0, 0, 0};
    if (f_to) {
        c->view[1].scene = f_to->scene;
        camera_init(&c->view[1].cam, f_to->camera, st->width, st->height);
        c->view[1].plane_dist2 = c->view[0].plane_dist2;
        c->static_scene = f_to->scene == f->scene;
    }
    const struct restir_domain dp = {pixel, RESTIR_CURRENT}, dq = {to, f_to ? RESTIR_PREVIOUS : RESTIR_CURRENT};
    struct restir_bdpt_path y, z;
    float j1 = 0.0f, j2 = 0.0f;
    target[0] = vec3_luminance(x->r.F);
    target[1] = target[2] = 0.0f;
    rbdpt_shift(c, x, dp, dq, &y, &target[1], &j1, &cnt);
    if (target[1] > 0.0f) rbdpt_shift(c, &y, dq, dp, &z, &target[2], &j2, &cnt);
    *jj = j1 * j2;
    free(c);
    return kind;
}

int restir_bdpt_shift_retrace_pair(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                                   const struct method_frame *f, uint32_t pixel, uint32_t to, float target[2],
                                   float jacobian[2])
{
    if (!st->res_prev) return -1;
    const struct restir_bdpt_path *x = &st->res_prev[pixel];
    if (!(x->r.head.W > 0.0f) || (x->r.head.bits & 0xffu) == RESTIR_BDPT_TECH_LT || x->rc.k < 2) return -1;
    _Atomic uint64_t reconnections = 0;
    struct rbdpt_ctx *c = rbdpt_test_ctx(st, p, f, &reconnections);
    if (!c) return -1;
    struct restir_counters cnt = {{0, 0}, 0, 0, 0};
    const struct restir_domain dp = {pixel, RESTIR_CURRENT}, dq = {to, RESTIR_CURRENT};
    for (int k = 0; k < 2; k++) {
        c->force_retrace = k == 1;
        rbdpt_shift(c, x, dp, dq, NULL, &target[k], &jacobian[k], &cnt);
    }
    free(c);
    return rbdpt_is_connection(x) ? 4 : 2;
}

bool restir_bdpt_caustic_replay(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                                const struct method_frame *f, uint32_t origin_frame, uint32_t light_path,
                                uint32_t depth, uint32_t *pixel, struct vec3 *F)
{
    struct rbdpt_ctx *c = rbdpt_test_ctx(st, p, f, NULL);
    if (!c) return false;
    struct ray_counters rc = {0, 0};
    bool ok = rbdpt_replay_caustic(c, &c->view[0], origin_frame, light_path, depth, pixel, F, &rc) == RBDPT_REPLAY_OK;
    free(c);
    return ok;
}
