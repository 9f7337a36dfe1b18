/* bdpt.c — method `bdpt` (see bdpt.h): light subpaths into the light vertex cache with light
 * tracing to the camera, then camera subpaths with emitter hits, next-event estimation and one
 * connection per vertex to a uniformly chosen cached light vertex; recursive MIS (bdpt_mis.h).
 *
 * Conventions. Radiance-side BSDF values are material_eval(m, towards the eye, towards the
 * light, TRANSPORT_RADIANCE) at every vertex, on either subpath; light subpaths sample with
 * TRANSPORT_IMPORTANCE, whose refraction lacks radiance's 1/eta^2 (Veach 1997 §5.2). Cosines in
 * contributions use shading normals on the camera side; on the light side the adjoint BSDF
 * carries Veach's shading-normal correction |wo.ns| |wi.ng| / (|wo.ng| |wi.ns|) (Veach 1997
 * eq. 5.19), so that the two directions of transport agree. MIS converts pdfs with geometric
 * normals.
 *
 * The camera: a pinhole with square pixels at distance d = height / (2 tan(fov_y / 2)) pixel
 * units from the eye. Sampling the image plane with density 1 per pixel gives the primary
 * direction the solid-angle pdf d^2 / cos^3(theta_0), and the light-tracing estimate of a pixel
 * from a light vertex y is beta f (d^2 / cos^3 theta_0) |cos theta_y| / |y - eye|^2 / N_L
 * (the box-filtered pixel that `pt` computes). */
#include "integrators/bdpt.h"

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

#define BDPT_TILE 16
#define BDPT_MAX_WORKERS 1024
#define BDPT_NO_PIXEL UINT32_MAX
/* Stream tag of the light subpaths (the camera subpaths use the pixel index, < 2^28). */
#define BDPT_LIGHT_STREAM 0x4c49474854000000ull

/* 52 bytes a cached vertex, 16 its splat (protocol/API.md quotes both). */
_Static_assert(sizeof(struct bdpt_light_vertex) == 52, "bdpt_light_vertex changed size");
_Static_assert(sizeof(struct bdpt_splat) == 16, "bdpt_splat changed size");

struct bdpt_params bdpt_defaults(void)
{
    return (struct bdpt_params){.max_depth = 64, .rr_depth = 3, .light_paths = 0, .lvc_capacity = 8,
                                .heuristic = BDPT_HEURISTIC_POWER};
}

bool bdpt_params_valid(const struct bdpt_params *p, struct err *err)
{
    if (p->max_depth < 1 || p->max_depth > 1024)
        return err_set(err, ERR_INVALID, "/params/max_depth", "max_depth must be in 1..1024");
    if (p->rr_depth > 1024) return err_set(err, ERR_INVALID, "/params/rr_depth", "rr_depth must be in 0..1024");
    if (p->light_paths > (1u << 26))
        return err_set(err, ERR_INVALID, "/params/light_paths", "light_paths must be in 0..%u (0 = the pixel count)",
                       1u << 26);
    if (p->lvc_capacity < 1 || p->lvc_capacity > 64)
        return err_set(err, ERR_INVALID, "/params/lvc_capacity", "lvc_capacity must be in 1..64");
    if (p->heuristic != BDPT_HEURISTIC_POWER && p->heuristic != BDPT_HEURISTIC_BALANCE)
        return err_set(err, ERR_INVALID, "/params/heuristic", "heuristic must be \"power\" or \"balance\"");
    return true;
}

const char *bdpt_heuristic_name(enum bdpt_heuristic h)
{
    switch (h) {
    case BDPT_HEURISTIC_POWER: return "power";
    case BDPT_HEURISTIC_BALANCE: return "balance";
    }
    return NULL;
}

/* ---- sizes -------------------------------------------------------------------------------- */

struct bdpt_blocks bdpt_blocks_of(uint32_t light_paths, uint32_t slots, uint32_t rays_per_block, uint32_t width,
                                  uint32_t height)
{
    struct bdpt_blocks b = {.rays_per_block = rays_per_block};
    b.light_paths = light_paths ? light_paths : (uint32_t)((uint64_t)width * height);
    b.blocks = (b.light_paths + BDPT_BLOCK_PATHS - 1) / BDPT_BLOCK_PATHS;
    b.region = BDPT_BLOCK_PATHS * slots;
    return b;
}

bool bdpt_scene_supported(const struct scene *scene, const char *method, struct err *err)
{
    if (!vec3_is_zero(scene->env_radiance))
        return err_set(err, ERR_INVALID, "/method",
                       "%s does not support environment light (the scene has env_radiance)", method);
    if (scene_has_translucent(scene))
        return err_set(err, ERR_INVALID, "/method",
                       "%s does not sample subsurface scattering (the scene has translucent materials)", method);
    return true;
}

bool bdpt_blocks_alloc(struct bdpt_blocks *b, uint32_t light_paths, uint32_t slots, uint32_t rays_per_block,
                       uint32_t width, uint32_t height, struct err *err)
{
    *b = bdpt_blocks_of(light_paths, slots, rays_per_block, width, height);
    if (b->light_paths == 0) {
        memset(b, 0, sizeof *b);
        return err_set(err, ERR_INVALID, "/params/light_paths", "no light subpaths");
    }
    b->count = calloc(b->blocks, sizeof *b->count);
    b->dropped = calloc(b->blocks, sizeof *b->dropped);
    if (rays_per_block) b->rays = calloc((size_t)rays_per_block * b->blocks, sizeof *b->rays);
    if (!b->count || !b->dropped || (rays_per_block && !b->rays)) {
        uint64_t bytes = bdpt_blocks_bytes(b);
        bdpt_blocks_destroy(b);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for the light subpaths' block counters (%llu bytes)",
                       (unsigned long long)bytes);
    }
    return true;
}

uint64_t bdpt_blocks_bytes(const struct bdpt_blocks *b)
{
    return (uint64_t)b->blocks * (sizeof *b->count + sizeof *b->dropped + b->rays_per_block * sizeof *b->rays);
}

void bdpt_blocks_destroy(struct bdpt_blocks *b)
{
    free(b->count);
    free(b->dropped);
    free(b->rays);
    memset(b, 0, sizeof *b);
}

bool bdpt_frame_valid(const struct method_frame *f, const char *method, const struct image *out, uint32_t width,
                      uint32_t height, struct err *err)
{
    if (!f->scene->accel || !f->scene->lights) return err_set(err, ERR_INVALID, NULL, "scene is not committed");
    if (!vec3_is_zero(f->scene->env_radiance))
        return err_set(err, ERR_INVALID, NULL, "%s does not support environment light", method);
    if (out->width != width || out->height != height || !out->pixels)
        return err_set(err, ERR_INVALID, NULL, "the output image is %ux%u, the state %ux%u", out->width, out->height,
                       width, height);
    return true;
}

/* The blocks of bdpt's light pass: LVC slots, two ray counters per block. */
static struct bdpt_blocks bdpt_blocks_for(const struct bdpt_params *p, uint32_t width, uint32_t height)
{
    return bdpt_blocks_of(p->light_paths, p->lvc_capacity, 2, width, height);
}

/* The LVC with its splats, and the prefix sums of the blocks' counts. */
static uint64_t bdpt_lvc_bytes_of(const struct bdpt_blocks *b)
{
    return (uint64_t)b->blocks * b->region * (sizeof(struct bdpt_light_vertex) + sizeof(struct bdpt_splat));
}

uint64_t bdpt_bytes_planned(const struct bdpt_params *p, uint32_t width, uint32_t height)
{
    struct bdpt_blocks b = bdpt_blocks_for(p, width, height);
    return bdpt_lvc_bytes_of(&b) + bdpt_blocks_bytes(&b) + ((uint64_t)b.blocks + 1) * sizeof(uint64_t);
}

size_t bdpt_lvc_bytes(const struct bdpt_state *st)
{
    return (size_t)bdpt_lvc_bytes_of(&st->lb);
}

size_t bdpt_block_bytes(const struct bdpt_state *st)
{
    return (size_t)bdpt_blocks_bytes(&st->lb) + ((size_t)st->lb.blocks + 1) * sizeof *st->block_first;
}

bool bdpt_init(struct bdpt_state *st, const struct scene *scene, const struct bdpt_params *p, uint32_t width,
               uint32_t height, struct err *err)
{
    memset(st, 0, sizeof *st);
    if (!bdpt_params_valid(p, err) || !bdpt_scene_supported(scene, "bdpt", err) ||
        !bdpt_blocks_alloc(&st->lb, p->light_paths, p->lvc_capacity, 2, width, height, err))
        return false;
    st->width = width;
    st->height = height;
    size_t slots = (size_t)st->lb.blocks * st->lb.region;
    st->lvc = malloc(slots * sizeof *st->lvc);
    st->splat = malloc(slots * sizeof *st->splat);
    st->block_first = calloc((size_t)st->lb.blocks + 1, sizeof *st->block_first);
    if (!st->lvc || !st->splat || !st->block_first) {
        uint64_t bytes = bdpt_lvc_bytes_of(&st->lb);
        bdpt_destroy(st);
        return err_set(err, ERR_NOMEM, NULL, "out of memory for the light vertex cache (%llu bytes)",
                       (unsigned long long)bytes);
    }
    return true;
}

void bdpt_destroy(struct bdpt_state *st)
{
    free(st->lvc);
    free(st->splat);
    bdpt_blocks_destroy(&st->lb);
    free(st->block_first);
    memset(st, 0, sizeof *st);
}

/* ---- per-frame context -------------------------------------------------------------------- */

/* A worker's counters, on a cache line of its own: they change with every ray, and two workers'
 * slots on one line would make the cores fight over it. */
struct bdpt_worker {
    _Alignas(64) uint64_t rays_intersect;
    uint64_t rays_occluded, connections, nonfinite;
};

struct bdpt_ctx {
    const struct scene *scene;
    const struct bdpt_params *p;
    struct bdpt_state *st;
    struct camera cam;
    float plane_dist2;     /* squared image-plane distance in pixel units */
    float n_light;         /* N_L */
    struct bdpt_lvc_view lvc;   /* the frame's cache, after the light pass */
    uint64_t seed;
    uint32_t frame;
    bool power;
    struct image *out;
    uint32_t tiles_x;
    struct bdpt_worker worker[BDPT_MAX_WORKERS];
};

/* Solid-angle pdf of an emitted direction at cosine `cos` with the emitting side's normal:
 * cosine-weighted, and a two-sided emitter first picks its side with probability 1/2. */
float bdpt_emit_dir_pdf_w(const struct material *m, float cos)
{
    float pdf = fabsf(cos) * INV_PI_F;
    return m->two_sided_emission ? 0.5f * pdf : pdf;
}

bool bdpt_light_start(const struct scene *scene, const float u[6], struct bdpt_light_start *out)
{
    struct light_sample *ls = &out->ls;
    if (!light_sampler_sample(scene->lights, u[0], u[1], u[2], ls) || ls->is_env) return false;
    const struct material *lm = ls->material;
    out->n = ls->n;
    if (lm->two_sided_emission && u[3] < 0.5f) out->n = vec3_neg(out->n);
    struct vec3 local = sampling_cosine_hemisphere(u[4], u[5]);
    if (!(local.z > 0.0f)) return false;
    struct frame lf = frame_from_normal(out->n);
    out->dir = vec3_normalize(frame_to_world(&lf, local));
    out->cos_l = vec3_dot(out->dir, out->n);
    if (!(out->cos_l > 0.0f)) return false;
    struct vec3 Le = light_sampler_emitted(lm, vec3_dot(out->dir, ls->n));
    if (vec3_is_zero(Le)) return false;
    out->emission_pdf_w = ls->pdf_a * bdpt_emit_dir_pdf_w(lm, out->cos_l);
    if (!(out->emission_pdf_w > 0.0f)) return false;
    out->beta = vec3_scale(Le, out->cos_l / out->emission_pdf_w);
    out->org = surface_offset_along(ls->p, out->n);
    return true;
}

/* Offset origin on the side of ng that `dir` leaves through. */
struct vec3 bdpt_origin(const struct surface *s, struct vec3 dir)
{
    return surface_offset_along(s->p, vec3_dot(dir, s->ng) < 0.0f ? vec3_neg(s->ng) : s->ng);
}

/* Whether nothing blocks the segment from surface point a (geometric normal na) to b (normal
 * nb, or the camera's eye when nb is NULL). Both ends are offset towards each other and the
 * ray spans the offset segment: measuring its length from the unoffset point instead
 * lets the ray reach the far surface itself whenever the origin offset (256 ulps, 0.016 at
 * coordinates near 500) exceeds a relative margin of the distance — short shadow rays from
 * large coordinates would then always be occluded by their own target. */
bool bdpt_visible(const struct accel *accel, struct vec3 a, struct vec3 na, struct vec3 b, const struct vec3 *nb,
                         struct ray_counters *rc)
{
    struct vec3 d = vec3_sub(b, a);
    struct vec3 oa = surface_offset_along(a, vec3_dot(d, na) < 0.0f ? vec3_neg(na) : na);
    struct vec3 ob = nb ? surface_offset_along(b, vec3_dot(d, *nb) > 0.0f ? vec3_neg(*nb) : *nb) : b;
    struct vec3 e = vec3_sub(ob, oa);
    float len = vec3_length(e);
    if (!(len > 0.0f)) return false;
    /* The relative margin on top of the end's offset: near the origin that offset is absolute
     * (1/65536), below the intersection error of a long ray arriving there. */
    return !accel_occluded(accel, oa, vec3_scale(e, 1.0f / len), 0.0f, len * (1.0f - 1e-4f), rc);
}

bool bdpt_eye_link(const struct camera *cam, float plane_dist2, const struct accel *accel, const struct surface *s,
                   const struct material *m, struct vec3 wo_world, struct ray_counters *rc,
                   struct bdpt_eye_link *out)
{
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
    if (accel && !bdpt_visible(accel, s->p, s->ng, cam->position, NULL, rc)) return false;
    out->px = px;
    out->py = py;
    out->ix = ix;
    out->iy = iy;
    out->f = f;
    out->rev_w = material_pdf(m, wc_local, wo_local);
    out->dist2 = dist2;
    out->camera_pdf_w = plane_dist2 / (cos0 * cos0 * cos0);
    out->camera_pdf_a = out->camera_pdf_w * fabsf(cos_c_ng) / dist2;
    out->corr = fabsf(wo_local.z) * fabsf(cos_c_ng) / fabsf(cos_o_ng);
    return true;
}

/* Light tracing (t = 1): the light vertex at `s` (material m, incoming direction wo, throughput
 * beta, MIS state mis) seen by the camera. Fills *pixel and *value, or returns false. */
static bool bdpt_connect_camera(const struct bdpt_ctx *c, const struct surface *s, const struct material *m,
                                struct vec3 wo_world, struct vec3 beta, const struct bdpt_mis *mis,
                                struct ray_counters *rc, uint32_t *pixel, struct vec3 *value)
{
    struct bdpt_eye_link e;
    if (!bdpt_eye_link(&c->cam, c->plane_dist2, c->scene->accel, s, m, wo_world, rc, &e)) return false;
    float w = bdpt_mis_weight_camera(mis, e.camera_pdf_a, c->n_light, e.rev_w, c->power);
    *value = vec3_scale(vec3_mul(beta, e.f), w * e.corr * e.camera_pdf_w / (e.dist2 * c->n_light));
    *pixel = e.iy * c->cam.width + e.ix;
    return true;
}

/* ---- light pass: one job per block of light subpaths ---------------------------------------- */

static void bdpt_light_block(void *ctx, uint32_t block, unsigned worker)
{
    (void)worker;
    struct bdpt_ctx *c = ctx;
    struct bdpt_state *st = c->st;
    const struct scene *scene = c->scene;
    const struct bdpt_params *p = c->p;
    struct ray_counters rc = {0, 0};
    struct bdpt_light_vertex *region = &st->lvc[(size_t)block * st->lb.region];
    struct bdpt_splat *splats = &st->splat[(size_t)block * st->lb.region];
    uint32_t stored = 0, dropped = 0;
    uint32_t first = block * BDPT_BLOCK_PATHS;
    uint32_t last = first + BDPT_BLOCK_PATHS < st->lb.light_paths ? first + BDPT_BLOCK_PATHS : st->lb.light_paths;

    for (uint32_t i = first; i < last; i++) {
        struct rng rng = rng_make(c->seed, c->frame, BDPT_LIGHT_STREAM + i, 1);
        float u[6];
        for (int k = 0; k < 6; k++) u[k] = rng_next_float(&rng);
        struct bdpt_light_start start;
        if (!bdpt_light_start(scene, u, &start)) continue;
        const struct light_sample ls = start.ls;
        struct vec3 dir = start.dir, beta = start.beta;
        struct vec3 rr_beta = vec3_splat(1.0f);   /* beta relative to its start, for Russian roulette */
        struct bdpt_mis mis = bdpt_mis_light_start(ls.pdf_a, start.emission_pdf_w, start.cos_l, c->power);
        struct vec3 org = start.org, prev_p = ls.p;

        for (uint32_t depth = 1; depth <= p->max_depth; depth++) {
            struct hit hit;
            if (!accel_intersect(scene->accel, org, dir, 0.0f, INFINITY, &hit, &rc)) break;
            struct surface s;
            surface_from_hit(scene, &hit, org, dir, &s);
            bdpt_mis_hit(&mis, vec3_length2(vec3_sub(s.p, prev_p)), vec3_dot(dir, s.ng), c->power);
            const struct material *m = &scene->materials[s.material];
            unsigned flags = material_flags(m);
            struct vec3 wo_world = vec3_neg(dir);
            if (flags & (BSDF_DIFFUSE | BSDF_GLOSSY)) {
                /* A connectable vertex: into the cache, and seen by the camera (t = 1). */
                if (stored < st->lb.region) {
                    struct bdpt_splat *sp = &splats[stored];
                    region[stored++] = bdpt_light_vertex_make(scene, &hit, &s, wo_world, beta, &mis, depth);
                    *sp = (struct bdpt_splat){vec3_splat(0.0f), BDPT_NO_PIXEL};
                    uint32_t px;
                    struct vec3 val;
                    if (bdpt_connect_camera(c, &s, m, wo_world, beta, &mis, &rc, &px, &val)) {
                        if (vec3_is_finite(val)) *sp = (struct bdpt_splat){val, px};
                    }
                } else {
                    dropped++;
                }
            }
            if (depth >= p->max_depth) break;
            struct bsdf_sample bs;
            struct vec3 wi_world, weight;
            float cos_i_ng;
            if (!material_sample_importance(m, &s.frame, s.ng, wo_world, &rng, &bs, &wi_world, &cos_i_ng, &weight)) break;
            beta = vec3_mul(beta, weight);
            rr_beta = vec3_mul(rr_beta, weight);
            bdpt_mis_scatter(&mis, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, (bs.flags & BSDF_DELTA) != 0, c->power);
            float u_rr = rng_next_float(&rng);
            if (depth >= p->rr_depth) {
                float mx = vec3_max_comp(rr_beta);
                float q = mx < 0.95f ? mx : 0.95f;
                if (!(q > 0.0f) || u_rr >= q) break;
                beta = vec3_scale(beta, 1.0f / q);
                rr_beta = vec3_scale(rr_beta, 1.0f / q);
            }
            org = bdpt_origin(&s, wi_world);
            prev_p = s.p;
            dir = wi_world;
        }
    }
    st->lb.count[block] = stored;
    st->lb.dropped[block] = dropped;
    st->lb.rays[2 * block] = rc.intersect;
    st->lb.rays[2 * block + 1] = rc.occluded;
}

/* ---- camera pass -------------------------------------------------------------------------- */

const struct bdpt_light_vertex *bdpt_lvc_pick(const struct bdpt_lvc_view *lvc, float u)
{
    if (lvc->total == 0) return NULL;
    uint64_t k = (uint64_t)((double)u * (double)lvc->total);
    if (k >= lvc->total) k = lvc->total - 1;
    uint32_t lo = 0, hi = lvc->blocks;  /* first[lo] <= k < first[hi] */
    while (hi - lo > 1) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (lvc->first[mid] <= k) lo = mid; else hi = mid;
    }
    return &lvc->v[(size_t)lo * lvc->region + (k - lvc->first[lo])];
}

struct bdpt_light_vertex bdpt_light_vertex_make(const struct scene *scene, const struct hit *hit,
                                                const struct surface *s, struct vec3 wo, struct vec3 beta,
                                                const struct bdpt_mis *mis, uint32_t depth)
{
    struct bdpt_light_vertex v = {.wo = wo, .beta = beta, .dvcm = mis->dvcm, .dvc = mis->dvc, .shape = s->shape,
                                  .prim = s->prim, .depth = depth};
    surface_point_code(scene, hit, s, &v.b1, &v.b2);
    return v;
}

struct vec3 bdpt_connect_light_vertex(const struct scene *scene, bool power, float lvc_scale, const struct surface *s,
                                      const struct material *m, struct vec3 wo, const struct bdpt_mis *cam_mis,
                                      const struct bdpt_light_vertex *v, struct ray_counters *rc, bool *made,
                                      struct bdpt_connect_pdfs *pdfs)
{
    struct vec3 zero = vec3_splat(0.0f);
    *made = false;
    struct surface sl;
    surface_at(scene, v->shape, v->prim, v->b1, v->b2, &sl);
    const struct material *ml = &scene->materials[sl.material];
    struct vec3 d = vec3_sub(sl.p, s->p);
    float dist2 = vec3_length2(d);
    if (!(dist2 > 0.0f)) return zero;
    float dist = sqrtf(dist2);
    struct vec3 dc = vec3_scale(d, 1.0f / dist);           /* camera vertex -> light vertex */
    struct vec3 dl = vec3_neg(dc);
    struct vec3 wi = frame_to_local(&s->frame, dc);
    struct vec3 wl = frame_to_local(&sl.frame, dl), wol = frame_to_local(&sl.frame, v->wo);
    float cos_c_ng = vec3_dot(dc, s->ng), cos_l_ng = vec3_dot(dl, sl.ng), cos_lo_ng = vec3_dot(v->wo, sl.ng);
    if (!(cos_c_ng * wi.z > 0.0f) || !(cos_l_ng * wl.z > 0.0f) || cos_lo_ng == 0.0f) return zero;
    struct vec3 fc = material_eval(m, wo, wi, TRANSPORT_RADIANCE);
    if (vec3_is_zero(fc)) return zero;
    struct vec3 fl = material_eval(ml, wl, wol, TRANSPORT_RADIANCE);
    if (vec3_is_zero(fl)) return zero;
    if (!bdpt_visible(scene->accel, s->p, s->ng, sl.p, &sl.ng, rc)) return zero;
    float cam_fwd_a = material_pdf(m, wo, wi) * fabsf(cos_l_ng) / dist2;
    float cam_rev_w = material_pdf(m, wi, wo);
    float light_fwd_a = material_pdf(ml, wol, wl) * fabsf(cos_c_ng) / dist2;
    float light_rev_w = material_pdf(ml, wl, wol);
    struct bdpt_mis lm = {v->dvcm, v->dvc};
    float w = bdpt_mis_weight_connect(cam_mis, &lm, cam_fwd_a, cam_rev_w, light_fwd_a, light_rev_w, power);
    if (pdfs) *pdfs = (struct bdpt_connect_pdfs){cam_fwd_a, cam_rev_w, light_fwd_a, light_rev_w, w};
    float corr = fabsf(wol.z) * fabsf(cos_l_ng) / fabsf(cos_lo_ng);
    *made = true;
    return vec3_scale(vec3_mul(vec3_mul(fc, fl), v->beta), fabsf(wi.z) * corr * w * lvc_scale / dist2);
}

static struct vec3 bdpt_camera_path(struct bdpt_ctx *c, struct vec3 dir, struct rng *rng, struct ray_counters *rc,
                                    struct bdpt_worker *wk)
{
    const struct scene *scene = c->scene;
    const struct bdpt_params *p = c->p;
    const struct light_sampler *lights = scene->lights;
    const struct camera *cam = &c->cam;
    struct vec3 L = vec3_splat(0.0f), beta = vec3_splat(1.0f);
    float rr_scale = 1.0f;  /* undoes refraction's radiance scaling for the roulette (reference_pt.c) */
    float cos0 = vec3_dot(dir, cam->forward);
    if (!(cos0 > 0.0f)) return L;
    struct bdpt_mis mis = bdpt_mis_camera_start(c->n_light, c->plane_dist2 / (cos0 * cos0 * cos0), c->power);
    struct vec3 org = cam->position, prev_p = org;

    for (uint32_t depth = 0;; depth++) {
        struct hit hit;
        if (!accel_intersect(scene->accel, org, dir, 0.0f, INFINITY, &hit, rc)) break;
        struct surface s;
        surface_from_hit(scene, &hit, org, dir, &s);
        float cos_hit = vec3_dot(dir, s.ng);
        bdpt_mis_hit(&mis, vec3_length2(vec3_sub(s.p, prev_p)), cos_hit, c->power);
        const struct material *m = &scene->materials[s.material];

        if (material_is_emissive(m)) {
            /* s = 0. A primary hit has no other technique: the emitter's own vertex is never
             * connected to the camera, and the eye cannot be sampled by NEE. */
            struct vec3 Le = light_sampler_emitted(m, -cos_hit);
            if (!vec3_is_zero(Le)) {
                float w = 1.0f;
                if (depth > 0) {
                    float direct_pdf_a = light_sampler_pdf_a(lights, s.shape, s.prim);
                    float emission_pdf_w = direct_pdf_a * bdpt_emit_dir_pdf_w(m, cos_hit);
                    w = bdpt_mis_weight_emission(&mis, direct_pdf_a, emission_pdf_w, c->power);
                }
                L = vec3_add(L, vec3_scale(vec3_mul(beta, Le), w));
            }
        }
        if (depth >= p->max_depth) break;
        uint32_t t_c = depth + 1;   /* surface vertices on the camera subpath, this one included */

        struct vec3 wo_world = vec3_neg(dir);
        struct vec3 wo = frame_to_local(&s.frame, wo_world);
        bool connectable = (material_flags(m) & (BSDF_DIFFUSE | BSDF_GLOSSY)) != 0;
        float ul = rng_next_float(rng), u1 = rng_next_float(rng), u2 = rng_next_float(rng);
        float uc = rng_next_float(rng);
        if (connectable) {
            /* s = 1: next-event estimation. */
            struct light_sample ls;
            if (light_sampler_sample(lights, ul, u1, u2, &ls) && !ls.is_env) {
                struct vec3 d = vec3_sub(ls.p, s.p);
                float d2 = vec3_length2(d);
                float dist = sqrtf(d2);
                struct vec3 wi_world = vec3_scale(d, 1.0f / dist);
                float cos_l = -vec3_dot(wi_world, ls.n);
                const struct material *lm = ls.material;
                struct vec3 Le = light_sampler_emitted(lm, cos_l);
                float direct_pdf_w = sampling_area_to_solid_angle(ls.pdf_a, d2, cos_l);
                struct vec3 wi = frame_to_local(&s.frame, wi_world);
                float cos_ng = vec3_dot(wi_world, s.ng);
                if (d2 > 0.0f && direct_pdf_w > 0.0f && !vec3_is_zero(Le) && cos_ng * wi.z > 0.0f) {
                    struct vec3 f = material_eval(m, wo, wi, TRANSPORT_RADIANCE);
                    if (!vec3_is_zero(f) && bdpt_visible(scene->accel, s.p, s.ng, ls.p, &ls.n, rc)) {
                        float emission_pdf_w = ls.pdf_a * bdpt_emit_dir_pdf_w(lm, cos_l);
                        float w = bdpt_mis_weight_nee(&mis, material_pdf(m, wo, wi), material_pdf(m, wi, wo),
                                                      direct_pdf_w, emission_pdf_w, cos_ng, cos_l, c->power);
                        L = vec3_add(L, vec3_mul(beta, vec3_scale(vec3_mul(f, Le), fabsf(wi.z) * w / direct_pdf_w)));
                    }
                }
            }
            /* s >= 2: one cached light vertex, uniformly; paths longer than max_depth are cut. */
            const struct bdpt_light_vertex *v = t_c < p->max_depth ? bdpt_lvc_pick(&c->lvc, uc) : NULL;
            if (v) {
                if (t_c + v->depth <= p->max_depth) {
                    bool made;
                    struct vec3 cv = bdpt_connect_light_vertex(scene, c->power, c->lvc.scale, &s, m, wo, &mis, v, rc,
                                                               &made, NULL);
                    if (made) {
                        wk->connections++;
                        L = vec3_add(L, vec3_mul(beta, cv));
                    }
                }
            }
        }

        /* Continue by BSDF sampling. */
        struct bsdf_sample bs;
        struct vec3 wi_world;
        float cos_i_ng;
        if (!material_sample_at(m, &s.frame, s.ng, wo, rng, TRANSPORT_RADIANCE, &bs, &wi_world, &cos_i_ng)) break;
        beta = vec3_mul(beta, vec3_scale(bs.f, fabsf(bs.wi.z) / bs.pdf_w));
        if (bs.flags & BSDF_TRANSMISSION) rr_scale /= material_radiance_scale(m, wo, bs.wi);
        bdpt_mis_scatter(&mis, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, (bs.flags & BSDF_DELTA) != 0, c->power);
        float u_rr = rng_next_float(rng);
        if (depth + 1 >= p->rr_depth) {
            float mx = vec3_max_comp(beta) * rr_scale;
            float q = mx < 0.95f ? mx : 0.95f;
            if (!(q > 0.0f) || u_rr >= q) break;
            beta = vec3_scale(beta, 1.0f / q);
        }
        org = bdpt_origin(&s, wi_world);
        prev_p = s.p;
        dir = wi_world;
    }
    return L;
}

static void bdpt_camera_tile(void *ctx, uint32_t tile, unsigned worker)
{
    struct bdpt_ctx *c = ctx;
    struct bdpt_worker *wk = &c->worker[worker];
    struct ray_counters rc = {0, 0};
    uint32_t w = c->st->width, h = c->st->height;
    uint32_t x0 = (tile % c->tiles_x) * BDPT_TILE, y0 = (tile / c->tiles_x) * BDPT_TILE;
    uint32_t x1 = x0 + BDPT_TILE < w ? x0 + BDPT_TILE : w, y1 = y0 + BDPT_TILE < h ? y0 + BDPT_TILE : h;
    for (uint32_t y = y0; y < y1; y++) {
        for (uint32_t x = x0; x < x1; x++) {
            uint32_t pixel = y * w + x;
            struct rng rng = rng_make(c->seed, c->frame, pixel, 0);
            float jx = rng_next_float(&rng), jy = rng_next_float(&rng);
            struct vec3 dir = camera_ray_dir(&c->cam, (float)x + jx, (float)y + jy);
            struct vec3 L = bdpt_camera_path(c, dir, &rng, &rc, wk);
            if (!vec3_is_finite(L)) {
                wk->nonfinite++;
                continue;
            }
            c->out->pixels[pixel] = vec3_add(c->out->pixels[pixel], L);
        }
    }
    wk->rays_intersect += rc.intersect;
    wk->rays_occluded += rc.occluded;
}

static double bdpt_ms_since(const struct timespec *t0)
{
    struct timespec t1;
    clock_gettime(CLOCK_MONOTONIC, &t1);
    return (double)(t1.tv_sec - t0->tv_sec) * 1e3 + (double)(t1.tv_nsec - t0->tv_nsec) * 1e-6;
}

bool bdpt_render(struct bdpt_state *st, const struct bdpt_params *p, const struct method_frame *f, struct image *out,
                 struct bdpt_stats *stats, struct err *err)
{
    if (!bdpt_params_valid(p, err) || !bdpt_frame_valid(f, "bdpt", out, st->width, st->height, err)) return false;
    if (!bdpt_blocks_same(&st->lb, bdpt_blocks_for(p, st->width, st->height)))
        return err_set(err, ERR_INVALID, NULL, "the parameters changed the light vertex cache's size since init");
    unsigned threads = f->threads ? f->threads : parallel_default_threads();
    if (threads > BDPT_MAX_WORKERS) threads = BDPT_MAX_WORKERS;

    /* On the stack (per-worker counters, about 65 KiB): a frame allocates nothing. */
    struct bdpt_ctx ctx_storage;
    struct bdpt_ctx *c = &ctx_storage;
    memset(c, 0, sizeof *c);
    c->scene = f->scene;
    c->p = p;
    c->st = st;
    camera_init(&c->cam, f->camera, st->width, st->height);
    float plane = (float)st->height / (2.0f * c->cam.tan_half_fov_y);
    c->plane_dist2 = plane * plane;
    c->n_light = (float)st->lb.light_paths;
    c->seed = f->seed;
    c->frame = f->frame;
    c->power = p->heuristic == BDPT_HEURISTIC_POWER;
    c->out = out;
    memset(out->pixels, 0, (size_t)out->width * out->height * sizeof *out->pixels);

    struct bdpt_stats s = {0};
    struct timespec t0;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    if (!parallel_run(threads, st->lb.blocks, bdpt_light_block, c, NULL, NULL, err)) return false;
    s.light_ms = bdpt_ms_since(&t0);

    /* Canonical LVC order and the light-tracing contributions, in one thread in block order so
     * that the sums do not depend on the thread count. */
    clock_gettime(CLOCK_MONOTONIC, &t0);
    st->block_first[0] = 0;
    for (uint32_t b = 0; b < st->lb.blocks; b++) {
        st->block_first[b + 1] = st->block_first[b] + st->lb.count[b];
        s.lvc_dropped += st->lb.dropped[b];
        s.rays_intersect += st->lb.rays[2 * b];
        s.rays_occluded += st->lb.rays[2 * b + 1];
        const struct bdpt_splat *sp = &st->splat[(size_t)b * st->lb.region];
        for (uint32_t j = 0; j < st->lb.count[b]; j++) {
            if (sp[j].pixel == BDPT_NO_PIXEL) continue;
            out->pixels[sp[j].pixel] = vec3_add(out->pixels[sp[j].pixel], sp[j].value);
            s.light_traced++;
        }
    }
    c->lvc = (struct bdpt_lvc_view){st->lvc, st->block_first, st->lb.blocks, st->lb.region, st->block_first[st->lb.blocks],
                                    (float)((double)st->block_first[st->lb.blocks] / (double)st->lb.light_paths)};
    s.splat_ms = bdpt_ms_since(&t0);

    clock_gettime(CLOCK_MONOTONIC, &t0);
    c->tiles_x = (st->width + BDPT_TILE - 1) / BDPT_TILE;
    uint32_t tiles_y = (st->height + BDPT_TILE - 1) / BDPT_TILE;
    if (!parallel_run(threads, c->tiles_x * tiles_y, bdpt_camera_tile, c, NULL, NULL, err)) return false;
    s.camera_ms = bdpt_ms_since(&t0);

    for (unsigned i = 0; i < threads; i++) {
        s.rays_intersect += c->worker[i].rays_intersect;
        s.rays_occluded += c->worker[i].rays_occluded;
        s.connections += c->worker[i].connections;
        s.nonfinite += c->worker[i].nonfinite;
    }
    s.light_subpaths = st->lb.light_paths;
    s.lvc_vertices = c->lvc.total;
    if (stats) *stats = s;
    return true;
}
