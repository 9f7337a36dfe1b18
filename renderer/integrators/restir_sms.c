/* restir_sms.c — method `restir_sms` (see restir_sms.h): the receivers, candidates from the
 * sms_ssp (or sms) sampler at them, the manifold shift, and the frame. The reuse passes are restir.c's; the rest
 * of the image is reference_pt_radiance_sms's.
 * Refs: [SMS-SSP §5.2] (eqs. 10-13, the manifold shift), §5.3 (5 Newton steps per shift walk);
 * docs/methods.md (restir_sms). */
#include "integrators/restir_sms.h"

#include <math.h>
#include <stddef.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "scene/camera.h"
#include "scene/light_sampler.h"
#include "core/parallel.h"
#include "integrators/reference_pt.h"
#include "core/rng.h"
#include "scene/surface.h"

#define SMS_STREAM 0x736d73ull        /* candidate generation */
#define SMS_PT_STREAM 0x736d70ull     /* the pt path of the rest of the image */
#define SMS_PT_SMS_STREAM 0x736d71ull /* the SMS estimates at that path's later vertices */

/* The reservoir element: the light point x_n and the chain's vertices as point codes (shape-
 * local, so they follow moving shapes between frames), the caster's shape, and the sample's
 * contribution f in its own pixel (RGB) whose luminance is the target. 64 bytes. */
struct sms_sample {
    struct restir_head head;   /* bits: chain length */
    uint32_t light_shape, light_prim;
    float light_b1, light_b2;
    uint32_t caster;
    uint32_t prim[MANIFOLD_MAX_CHAIN];
    float b[MANIFOLD_MAX_CHAIN][2];
    float F[3];
};
_Static_assert(sizeof(struct sms_sample) == RESTIR_SMS_RESERVOIR_BYTES, "reservoir element size");

struct restir_sms_params restir_sms_defaults(void)
{
    struct restir_sms_params p = {.ssp = ssp_defaults(), .shift_iterations = 5, .temporal = true,
                                  .temporal_cap = 20, .spatial_neighbors = 1, .spatial_radius = 30.0f,
                                  .paired_spatial = true, .expected_shading = true, .jitter_walk = 0.1f,
                                  .light_reservoirs = RESTIR_SMS_LIGHT_RESERVOIRS_BY_SCENE, .max_depth = 64, .rr_depth = 3,
                                  .rest = RESTIR_SMS_REST_BY_SCENE};
    return p;
}

enum restir_sms_rest restir_sms_rest_of(const struct restir_sms_params *p, const struct scene *scene)
{
    if (p->ssp.sms.caustics_only) return RESTIR_SMS_REST_PT;   /* no rest at all: the pt path's SMS */
    if (p->rest != RESTIR_SMS_REST_BY_SCENE) return p->rest;
    const bool fits = p->max_depth >= 1 && p->max_depth <= RESTIR_PT_MAX_DEPTH;
    return fits && !scene_has_translucent(scene) ? RESTIR_SMS_REST_RESTIR_PT : RESTIR_SMS_REST_PT;
}

struct restir_pt_params restir_sms_rest_params(const struct restir_sms_params *p)
{
    struct restir_pt_params rp = restir_pt_rest_params(!p->temporal, p->max_depth);
    rp.subset = PT_SUBSET_REST;
    return rp;
}

bool restir_sms_params_valid(const struct restir_sms_params *p, struct err *err)
{
    if ((unsigned)p->sampler > RESTIR_SMS_SAMPLER_SMS)
        return err_set(err, ERR_INVALID, "/params/sampler", "unknown sampler");
    /* ssp names its parameters bare; the session's are under /params. */
    if (!ssp_params_valid(&p->ssp, err)) return err_under(err, "/params");
    if (p->shift_iterations < 1 || p->shift_iterations > MANIFOLD_MAX_ITERATIONS)
        return err_set(err, ERR_INVALID, "/params/shift_iterations", "must be in [1, %d], got %u",
                       MANIFOLD_MAX_ITERATIONS, p->shift_iterations);
    if (p->temporal_cap < 1 || p->temporal_cap > 1000)
        return err_set(err, ERR_INVALID, "/params/temporal_cap", "must be in [1, 1000], got %u", p->temporal_cap);
    if (p->spatial_neighbors > 32)
        return err_set(err, ERR_INVALID, "/params/spatial_neighbors", "must be in [0, 32], got %u", p->spatial_neighbors);
    if (!(p->spatial_radius >= 1.0f && p->spatial_radius <= 256.0f))
        return err_set(err, ERR_INVALID, "/params/spatial_radius", "must be in [1, 256] pixels");
    if (!gbuffer_jitter_walk_valid(p->jitter_walk, err)) return false;
    if (p->light_reservoirs > RESTIR_SMS_MAX_LIGHT_RESERVOIRS)
        return err_set(err, ERR_INVALID, "/params/light_reservoirs", "must be in [0, %u] (0: one per emissive shape), got %u",
                       RESTIR_SMS_MAX_LIGHT_RESERVOIRS, p->light_reservoirs);
    if (p->max_depth > 1024) return err_set(err, ERR_INVALID, "/params/max_depth", "must be at most 1024");
    if ((unsigned)p->rest > RESTIR_SMS_REST_RESTIR_PT) return err_set(err, ERR_INVALID, "/params/rest", "unknown rest");
    if (p->rest == RESTIR_SMS_REST_RESTIR_PT && !p->ssp.sms.caustics_only &&
        (p->max_depth < 1 || p->max_depth > RESTIR_PT_MAX_DEPTH))
        return err_set(err, ERR_INVALID, "/params/max_depth", "must be in 1..%u with rest restir_pt, got %u",
                       RESTIR_PT_MAX_DEPTH, p->max_depth);
    return true;
}

/* The scene as loaded: a derived scene (moved shapes, changed emission) holds its base. The
 * reservoirs' lights are ranked there, so a light switched off or on during a session moves no
 * other light's paths to another reservoir: a reservoir whose history held one light's paths and
 * whose candidates came from another's would count a light twice. */
static const struct scene *sms_loaded_scene(const struct scene *scene)
{
    while (scene->base) scene = scene->base;
    return scene;
}

/* Emissive shapes among the first `end` shapes of the scene as loaded. Once per candidate that
 * found a solution: scenes with caustic casters have few shapes, and the walk cost far more. */
static uint32_t sms_emitters_before(const struct scene *scene, uint32_t end)
{
    scene = sms_loaded_scene(scene);
    uint32_t n = 0;
    for (uint32_t i = 0; i < end && i < scene->shape_count; i++)
        n += material_is_emissive(&scene->materials[scene->shapes[i].material]);
    return n;
}

uint32_t restir_sms_layers(const struct restir_sms_params *p, const struct scene *scene)
{
    if (p->light_reservoirs != RESTIR_SMS_LIGHT_RESERVOIRS_BY_SCENE) return p->light_reservoirs;
    uint32_t emitters = sms_emitters_before(scene, UINT32_MAX);
    return emitters < 1 ? 1 : emitters > RESTIR_SMS_MAX_LIGHT_RESERVOIRS ? RESTIR_SMS_MAX_LIGHT_RESERVOIRS : emitters;
}

uint32_t restir_sms_light_reservoir(const struct scene *scene, uint32_t light_shape, uint32_t layers)
{
    return layers <= 1 ? 0 : sms_emitters_before(scene, light_shape) % layers;
}

/* ---- per-frame context ---------------------------------------------------------------------- */

struct sms_shared {
    _Atomic uint64_t newton, not_invertible;
};

struct sms_ctx {
    const struct restir_sms_params *p;
    const struct scene *scene[2];   /* [RESTIR_CURRENT], [RESTIR_PREVIOUS] */
    const struct gbuffer *gbuf[2];
    const struct restir_sms_receiver *recv[2];
    const struct ssp_prior *prior;
    uint64_t seed;
    uint32_t frame, width;
    uint32_t max_depth;             /* of the path: a chain from x1 at depth d has max_depth - d - 1 */
    struct sms_shared *shared;
    struct sms_shared shared_storage;
    struct sms_scene ss;            /* the current frame's casters (candidates) */
};
_Static_assert(sizeof(struct sms_ctx) <= RESTIR_SMS_CTX_BYTES, "context fits the test buffer");

/* The receiver x1 of a domain (restir_sms.h), where path tracing would make the SMS estimate
 * the reservoirs take over. */
struct sms_x1 {
    struct surface s;
    const struct material *m;
    struct vec3 wo;   /* back along the path, in s's local frame */
    struct vec3 T;    /* the delta prefix's expected throughput */
    uint32_t room;    /* the longest chain the path's depth limit leaves after x1 */
};

static bool sms_receiver(const struct sms_ctx *c, struct restir_domain d, struct sms_x1 *x)
{
    const struct restir_sms_receiver *r = &c->recv[d.frame][d.pixel];
    if (!r->valid) return false;
    const struct scene *scene = c->scene[d.frame];
    surface_at(scene, r->shape, r->prim, r->b1, r->b2, &x->s);
    x->m = &scene->materials[x->s.material];
    x->wo = frame_to_local(&x->s.frame, vec3_make(r->wo[0], r->wo[1], r->wo[2]));
    x->T = vec3_make(r->T[0], r->T[1], r->T[2]);
    x->room = c->max_depth > r->depth + 1u ? c->max_depth - r->depth - 1u : 0;
    return true;
}

/* The receiver of a camera ray whose first hit the caller has (`primary`; NULL: it escaped). */
static void sms_find_receiver(const struct scene *scene, uint32_t max_depth, struct vec3 org, struct vec3 dir,
                              const struct hit *primary, struct restir_sms_receiver *out, struct ray_counters *rc)
{
    memset(out, 0, sizeof *out);
    struct hit hit;
    struct surface s;
    struct vec3 wo_world, T;
    uint32_t depth;
    if (!primary || !sms_receiver_trace(scene, max_depth, org, dir, primary, &hit, &s, &wo_world, &T, &depth, rc))
        return;
    out->shape = hit.shape;
    out->prim = hit.prim;
    surface_point_code(scene, &hit, &s, &out->b1, &out->b2);
    out->wo[0] = wo_world.x, out->wo[1] = wo_world.y, out->wo[2] = wo_world.z;
    out->T[0] = T.x, out->T[1] = T.y, out->T[2] = T.z;
    out->depth = (uint16_t)depth;
    out->valid = 1;
}

static inline uint32_t sms_length(const struct sms_sample *x) { return x->head.bits; }

/* A chain vertex rebuilt from its code: the walk's starting point (it re-projects by tracing). */
static void sms_vertex_at(const struct scene *scene, uint32_t shape, uint32_t prim, const float b[2],
                          struct manifold_vertex *v)
{
    struct surface s;
    surface_at(scene, shape, prim, b[0], b[1], &s);
    memset(v, 0, sizeof *v);
    v->p = s.p;
    v->ng = s.ng;
    v->ns = s.ns;
    v->prim = prim;
    v->b1 = b[0];
    v->b2 = b[1];
    v->pd[0] = s.p.x, v->pd[1] = s.p.y, v->pd[2] = s.p.z;
    v->bd[0] = b[0], v->bd[1] = b[1];
}

static void sms_chain_at(const struct scene *scene, const struct sms_sample *x, struct manifold_vertex *v)
{
    for (uint32_t i = 0; i < sms_length(x); i++) sms_vertex_at(scene, x->caster, x->prim[i], x->b[i], &v[i]);
}

/* The code of a walked vertex: meshes keep the walk's double barycentrics (more precise than
 * the float hit's), spheres their octahedral code. */
static void sms_code_of(const struct scene *scene, uint32_t shape, const struct manifold_vertex *v, uint32_t *prim,
                        float b[2])
{
    *prim = v->prim;
    if (scene->shapes[shape].kind == SHAPE_MESH) {
        b[0] = (float)v->bd[0];
        b[1] = (float)v->bd[1];
    } else {
        b[0] = v->b1;
        b[1] = v->b2;
    }
}

/* The light point of a sample in a scene: its ends with x1, and its material. */
static bool sms_ends_at(const struct scene *scene, const struct sms_sample *x, const struct sms_x1 *x1,
                        struct manifold_ends *e, const struct material **lm)
{
    struct surface ls;
    surface_at(scene, x->light_shape, x->light_prim, x->light_b1, x->light_b2, &ls);
    *lm = &scene->materials[ls.material];
    *e = (struct manifold_ends){.x1 = x1->s.p, .ng1 = x1->s.ng, .xe = ls.p, .nge = ls.ng};
    return material_is_emissive(*lm);
}

/* ---- candidates ----------------------------------------------------------------------------- */

static void sms_initial_candidate(const struct sms_ctx *c, uint32_t pixel, struct sms_sample *out,
                                  struct sms_counters *sc, struct ray_counters *rc)
{
    memset(out, 0, sizeof *out);
    struct sms_x1 x1;
    if (!sms_receiver(c, (struct restir_domain){pixel, RESTIR_CURRENT}, &x1)) return;
    /* One candidate, counted whether or not it finds a solution (null samples count). */
    out->head.M = 1;
    const struct scene *scene = c->scene[RESTIR_CURRENT];
    struct rng rng = rng_make(c->seed, c->frame, pixel, SMS_STREAM);
    struct sms_solution sol;
    bool found = c->p->sampler == RESTIR_SMS_SAMPLER_SMS
                     ? sms_sample(scene, &c->ss, &c->p->ssp.sms, &x1.s, x1.m, x1.wo, x1.room, &rng, &sol, sc, rc)
                     : ssp_sample(scene, &c->ss, &c->p->ssp, c->prior, pixel % c->width, pixel / c->width, &x1.s, x1.m,
                                  x1.wo, x1.room, &rng, &sol, sc, rc);
    if (!found) return;
    sol.value = vec3_mul(sol.value, x1.T);
    float target = vec3_luminance(sol.value);
    if (!(target > 0.0f) || !isfinite(target) || !(sol.W > 0.0) || !isfinite(sol.W)) return;
    const struct sms_caster *cs = &c->ss.casters[sol.caster];
    out->head.bits = (uint16_t)cs->chain.length;
    out->caster = cs->chain.shape;
    out->light_shape = sol.light.shape;
    out->light_prim = sol.light.prim;
    if (scene->shapes[sol.light.shape].kind == SHAPE_MESH) {
        out->light_b1 = sol.light.b1;
        out->light_b2 = sol.light.b2;
    } else {
        const struct shape *sh = &scene->shapes[sol.light.shape];
        struct vec3 d = vec3_normalize(
            vec3_sub(xform_point(accel_shape_to_object(scene->accel, sol.light.shape), sol.light.p), sh->center));
        surface_oct_encode(d, &out->light_b1, &out->light_b2);
    }
    for (uint32_t i = 0; i < cs->chain.length; i++) sms_code_of(scene, cs->chain.shape, &sol.v[i], &out->prim[i], out->b[i]);
    out->F[0] = sol.value.x, out->F[1] = sol.value.y, out->F[2] = sol.value.z;
    /* A single candidate: W = w / p̂ = the sampler's estimated inverse pdf (eq. 11). */
    out->head.W = (float)sol.W;
}

/* The pixel's initial reservoirs, layer l's at res[l * n]: the candidate in its light's, and in
 * every other one the same candidate seen with target 0 (restir_sms.h). */
static void sms_initial_pixel(const struct sms_ctx *c, uint32_t pixel, uint32_t layers, size_t n, struct sms_sample *res,
                              struct sms_counters *sc, struct ray_counters *rc)
{
    struct sms_sample cand;
    sms_initial_candidate(c, pixel, &cand, sc, rc);
    uint32_t own = cand.head.W > 0.0f ? restir_sms_light_reservoir(c->scene[RESTIR_CURRENT], cand.light_shape, layers) : 0;
    for (uint32_t l = 0; l < layers; l++) {
        struct sms_sample *out = &res[l * n + pixel];
        if (l == own) {
            *out = cand;
        } else {
            memset(out, 0, sizeof *out);
            out->head.M = cand.head.M;
        }
    }
}

/* ---- the manifold shift --------------------------------------------------------------------- */

static void sms_shift_impl(const struct sms_ctx *c, const struct sms_sample *x, struct restir_domain from,
                           struct restir_domain to, struct sms_sample *y, float *target, float *jacobian,
                           struct restir_counters *cnt)
{
    *target = 0.0f;
    *jacobian = 0.0f;
    *y = *x;
    const uint32_t k = sms_length(x);
    if (!(x->head.W > 0.0f) || k == 0 || k > MANIFOLD_MAX_CHAIN) return;
    struct sms_x1 a, b;
    if (!sms_receiver(c, from, &a) || !sms_receiver(c, to, &b)) return;
    const struct scene *sa = c->scene[from.frame], *sb = c->scene[to.frame];
    struct manifold_chain chain;
    if (!sms_chain_of(sb, x->caster, &chain) || chain.length != k || k > b.room) return;
    struct manifold_ends ea, eb;
    const struct material *la, *lb;
    if (!sms_ends_at(sa, x, &a, &ea, &la) || !sms_ends_at(sb, x, &b, &eb, &lb)) return;
    struct ray_counters *rc = &cnt->rays;
    struct manifold_stats st = {0};
    /* Forward: from the base chain to the target pixel's x1, x_n fixed (§5.2), <= 5 steps (§5.3).
     * Unpolished: the shifted chain is kept as float point codes, and polishing it to the double
     * floor cost 23 % of the shifts' Newton steps. */
    struct manifold_vertex v[MANIFOLD_MAX_CHAIN], w[MANIFOLD_MAX_CHAIN], base[MANIFOLD_MAX_CHAIN];
    sms_chain_at(sb, x, v);
    bool ok = manifold_walk_unpolished(sb, &chain, &eb, v, c->p->shift_iterations, &st, rc) &&
              manifold_check(sb, &chain, &eb, v, rc);
    struct vec3 F = vec3_splat(0.0f);
    if (ok) F = vec3_mul(sms_solution_value(sb, &chain, &eb, v, &b.s, b.m, b.wo, lb), b.T);
    ok = ok && !vec3_is_zero(F) && vec3_is_finite(F);
    if (ok) {
        for (uint32_t i = 0; i < k; i++) sms_code_of(sb, x->caster, &v[i], &y->prim[i], y->b[i]);
        /* Invertibility: walking the shifted chain back to the base pixel's x1 must reach the
         * base chain again; otherwise two base chains could share an image and T would not be a
         * bijection. The walk back starts from the shifted chain's codes exactly as the reverse
         * shift (B -> A) would. */
        sms_chain_at(sa, y, w);
        sms_chain_at(sa, x, base);
        float tol = 1e-4f * vec3_length(vec3_sub(base[0].p, a.s.p));
        ok = manifold_walk_unpolished(sa, &chain, &ea, w, c->p->shift_iterations, &st, rc) &&
             manifold_same(w, base, k, tol);
        if (!ok) atomic_fetch_add_explicit(&c->shared->not_invertible, 1, memory_order_relaxed);
    }
    atomic_fetch_add_explicit(&c->shared->newton, st.iterations, memory_order_relaxed);
    if (!ok) return;
    float t = vec3_luminance(F);
    /* |∂T/∂x| = 1 for a fixed light point (footnote 6), times its area change when the emitter's
     * shape was scaled between the two frames' scenes. */
    float J = surface_area_ratio(sa, sb, x->light_shape, x->light_prim, x->light_b1, x->light_b2);
    if (!(t > 0.0f) || !isfinite(t) || !(J > 0.0f) || !isfinite(J)) return;
    y->F[0] = F.x, y->F[1] = F.y, y->F[2] = F.z;
    *target = t;
    *jacobian = J;
}

static float sms_target(const void *ctx, const void *elem)
{
    (void)ctx;
    const struct sms_sample *s = elem;
    return vec3_luminance(vec3_make(s->F[0], s->F[1], s->F[2]));
}

static struct vec3 sms_value(const void *ctx, const void *elem)
{
    (void)ctx;
    const struct sms_sample *s = elem;
    return vec3_make(s->F[0], s->F[1], s->F[2]);
}

static void sms_shift(const void *ctx, const void *src, struct restir_domain from, struct restir_domain to, void *dst,
                      float *target, float *jacobian, struct restir_counters *cnt)
{
    struct sms_sample y;
    sms_shift_impl(ctx, src, from, to, &y, target, jacobian, cnt);
    if (dst) memcpy(dst, &y, sizeof y);
}

/* Whether the pixel has a receiver, without rebuilding its surface (sms_receiver does that for a
 * shift): the reuse passes ask this of every neighbour and predecessor they consider. */
static bool sms_domain_valid(const void *ctx, struct restir_domain d)
{
    const struct sms_ctx *c = ctx;
    return c->recv[d.frame][d.pixel].valid;
}

const struct restir_ops restir_sms_ops = {
    .stride = sizeof(struct sms_sample),
    .target = sms_target,
    .shift = sms_shift,
    .domain_valid = sms_domain_valid,
    .value = sms_value,
};

void restir_sms_info(const void *ctx, const void *elem, struct restir_sms_info *out)
{
    const struct sms_ctx *c = ctx;
    const struct sms_sample *s = elem;
    memset(out, 0, sizeof *out);
    out->F = vec3_make(s->F[0], s->F[1], s->F[2]);
    out->length = sms_length(s);
    if (!(s->head.W > 0.0f) || out->length == 0 || out->length > MANIFOLD_MAX_CHAIN) return;
    const struct scene *scene = c->scene[RESTIR_CURRENT];
    out->caster = s->caster;
    out->light_shape = s->light_shape;
    struct surface ls;
    surface_at(scene, s->light_shape, s->light_prim, s->light_b1, s->light_b2, &ls);
    out->light_p = ls.p;
    struct manifold_vertex v[MANIFOLD_MAX_CHAIN];
    sms_chain_at(scene, s, v);
    for (uint32_t i = 0; i < out->length; i++) out->chain[i] = v[i].p;
}

uint64_t restir_sms_shift_newton(const void *ctx)
{
    const struct sms_ctx *c = ctx;
    return atomic_load(&c->shared->newton);
}

/* ---- the frame ------------------------------------------------------------------------------ */

static bool sms_uses_prior(const struct restir_sms_params *p) { return p->sampler == RESTIR_SMS_SAMPLER_SSP; }
static bool sms_uses_pairs(const struct restir_sms_params *p)
{
    return restir_pairs_needed(p->paired_spatial, p->spatial_neighbors);
}

bool restir_sms_init(struct restir_sms_state *st, const struct scene *scene, const struct restir_sms_params *params,
                     uint32_t width, uint32_t height, struct err *err)
{
    memset(st, 0, sizeof *st);
    size_t n = (size_t)width * height;
    bool ok = restir_session_init(&st->rs, width, height, restir_sms_layers(params, scene), sizeof(struct sms_sample),
                                  false, sms_uses_pairs(params), err);
    for (int i = 0; ok && i < 2; i++)
        if (!(st->recv[i] = calloc(n, sizeof(struct restir_sms_receiver))))
            ok = err_set(err, ERR_NOMEM, NULL, "out of memory for %ux%u receivers", width, height);
    ok = ok && (!sms_uses_prior(params) || ssp_prior_init(&st->prior, width, height, params->ssp.prior_frames, err));
    if (ok && restir_sms_rest_of(params, scene) == RESTIR_SMS_REST_RESTIR_PT) {
        if (scene_has_translucent(scene)) {
            ok = err_set(err, ERR_INVALID, "/params/rest",
                         "restir_pt does not sample subsurface scattering (the scene has translucent materials): "
                         "give \"pt\"");
        } else {
            struct restir_pt_params rp = restir_sms_rest_params(params);
            st->has_rest = true;
            ok = restir_pt_init(&st->rest, scene, &rp, width, height, err) &&
                 image_init(&st->rest_image, width, height, err);
        }
    }
    if (!ok) restir_sms_destroy(st);
    return ok;
}

void restir_sms_destroy(struct restir_sms_state *st)
{
    restir_session_destroy(&st->rs);
    for (int i = 0; i < 2; i++) free(st->recv[i]);
    ssp_prior_destroy(&st->prior);
    if (st->has_rest) {
        restir_pt_destroy(&st->rest);
        image_destroy(&st->rest_image);
    }
    memset(st, 0, sizeof *st);
}

size_t restir_sms_receiver_bytes(const struct restir_sms_state *st)
{
    return 2 * (size_t)st->rs.width * st->rs.height * sizeof(struct restir_sms_receiver);
}

size_t restir_sms_prior_bytes(const struct restir_sms_state *st)
{
    return st->prior.entries ? ssp_prior_bytes(st->rs.width, st->rs.height, st->prior.frames) : 0;
}

/* The rest's restir_pt session and its frame, when rest is restir_pt. */
static uint64_t sms_rest_bytes(const struct restir_sms_params *params, const struct scene *scene, uint32_t width,
                               uint32_t height)
{
    if (restir_sms_rest_of(params, scene) != RESTIR_SMS_REST_RESTIR_PT) return 0;
    struct restir_pt_params rp = restir_sms_rest_params(params);
    return restir_pt_bytes_planned(&rp, width, height, scene) + (uint64_t)width * height * sizeof(struct vec3);
}

uint64_t restir_sms_bytes_planned(const struct restir_sms_params *params, const struct scene *scene, uint32_t width,
                                  uint32_t height)
{
    uint64_t layers = restir_sms_layers(params, scene);
    return 2 * (uint64_t)width * height *
               (layers * sizeof(struct sms_sample) + sizeof(struct gbuffer_pixel) + sizeof(struct restir_sms_receiver)) +
           (sms_uses_prior(params) ? ssp_prior_bytes(width, height, params->ssp.prior_frames) : 0) +
           (sms_uses_pairs(params) ? restir_pair_scratch_bytes(width, height) : 0) + sms_rest_bytes(params, scene, width, height);
}

struct sms_pass {
    struct restir_frame fr;   /* first: the driver's rows reach it through the pass */
    const struct sms_ctx *c;
    struct restir_sms_receiver *recv;   /* this frame's, which the initial pass finds */
    struct pt_params pt;
    const struct vec3 *rest;   /* the rest's restir_pt frame, or NULL: the pt path renders the rest */
    struct sms_counters sms[RESTIR_MAX_WORKERS];
    struct restir_sms_stats local;   /* the counters of a frame whose caller keeps none */
};
RESTIR_FRAME_FIRST(struct sms_pass);
/* The frame's stats pointer is this struct's `pass`. */
_Static_assert(offsetof(struct restir_sms_stats, pass) == 0, "restir_sms_stats must begin with its pass stats");
/* One reuse per light reservoir, in the frame's fixed array. */
_Static_assert(RESTIR_SMS_MAX_LIGHT_RESERVOIRS <= RESTIR_MAX_LAYERS, "more light reservoirs than a frame reuses");

/* Initial pass: the candidate into the working buffer, and the sms_ssp path for the rest of the
 * image from the same primary ray (the G-buffer's jitter). */
static void sms_initial_rows(void *ctx, uint32_t job, unsigned worker)
{
    struct sms_pass *pp = ctx;
    const struct sms_ctx *c = pp->c;
    const struct restir_session *rs = pp->fr.s;
    const struct camera *cam = &pp->fr.camera;
    uint32_t w = rs->width, y0, y1;
    restir_frame_rows(&pp->fr, job, &y0, &y1);
    struct sms_sample *res = (struct sms_sample *)rs->res[0];
    struct ray_counters rays = {0, 0};  /* job-local (see sms_counters_add) */
    struct sms_counters sms = {0};
    struct ray_counters *rc = &rays;
    struct sms_counters *sc = &sms;
    struct restir_sms_receiver *recv = pp->recv;
    for (uint32_t y = y0; y < y1; y++) {
        for (uint32_t x = 0; x < w; x++) {
            uint32_t pixel = y * w + x;
            const struct gbuffer_pixel *g = &c->gbuf[RESTIR_CURRENT]->px[pixel];
            struct vec3 dir = camera_ray_dir(cam, (float)x + g->jx, (float)y + g->jy);
            /* The G-buffer pass traced this ray already: its hit starts both walks along it. */
            struct hit first;
            const struct hit *primary = gbuffer_hit(c->scene[RESTIR_CURRENT], g, &first);
            sms_find_receiver(c->scene[RESTIR_CURRENT], c->max_depth, cam->position, dir, primary, &recv[pixel], rc);
            sms_initial_pixel(c, pixel, rs->layers, (size_t)w * rs->height, res, sc, rc);
            if (!pp->fr.out) continue;
            struct rng rng = rng_make(c->seed, c->frame, pixel, SMS_PT_STREAM);
            struct rng srng = rng_make(c->seed, c->frame, pixel, SMS_PT_SMS_STREAM);
            struct vec3 L = reference_pt_radiance_sms(c->scene[RESTIR_CURRENT], &pp->pt, &c->ss, x, y,
                                                      cam->position, dir, primary, &rng, &srng, sc, rc);
            pp->fr.out->pixels[pixel] = pp->rest ? vec3_add(L, pp->rest[pixel]) : L;
        }
    }
    pp->fr.counters[worker].rays.intersect += rays.intersect;
    pp->fr.counters[worker].rays.occluded += rays.occluded;
    sms_counters_add(&pp->sms[worker], &sms);
}

static void sms_shade_rows(void *ctx, uint32_t job, unsigned worker)
{
    struct sms_pass *pp = ctx;
    const struct restir_session *rs = pp->fr.s;
    uint32_t w = rs->width, y0, y1;
    restir_frame_rows(&pp->fr, job, &y0, &y1);
    const struct sms_sample *res = (const struct sms_sample *)rs->res[1];
    const size_t n = (size_t)w * rs->height;
    for (uint32_t y = y0; y < y1; y++) {
        for (uint32_t x = 0; x < w; x++) {
            uint32_t pixel = y * w + x;
            struct vec3 L = pp->fr.out->pixels[pixel];
            for (uint32_t l = 0; l < rs->layers && !pp->fr.estimated; l++) {
                const struct sms_sample *s = &res[l * n + pixel];
                if (s->head.W > 0.0f) L = vec3_add(L, vec3_scale(vec3_make(s->F[0], s->F[1], s->F[2]), s->head.W));
            }
            restir_frame_store(&pp->fr, worker, pixel, L);
        }
    }
}

static bool sms_bind(struct restir_sms_state *st, const struct restir_sms_params *params,
                     const struct method_frame *f, struct sms_ctx *c, struct err *err)
{
    memset(c, 0, sizeof *c);
    c->p = params;
    restir_frame_domains(&st->rs, f, c->scene, NULL, c->gbuf);
    c->recv[RESTIR_CURRENT] = st->recv[st->rs.cur];
    c->recv[RESTIR_PREVIOUS] = st->recv[st->rs.cur ^ 1u];
    c->prior = &st->prior;
    c->seed = f->seed;
    c->frame = f->frame;
    c->width = st->rs.width;
    c->max_depth = params->max_depth;
    c->shared = &c->shared_storage;
    return sms_scene_init(f->scene, &c->ss, err);
}

/* A frame with the context in `c`; without an output, its G-buffer, prior and initial passes only
 * (restir_sms_initial_only). */
static bool sms_frame(struct restir_sms_state *st, const struct restir_sms_params *params,
                      const struct method_frame *f, struct sms_ctx *c, struct image *out,
                      struct restir_sms_stats *stats, struct err *err)
{
    /* The pass's per-worker counters on the heap would be a per-frame malloc; the stack is fine. */
    struct sms_pass pp;
    if (!(stats = restir_frame_open(&pp.fr, sizeof pp, &st->rs, f, out, params->temporal, stats, &pp.local,
                                    sizeof pp.local, err)) ||
        !restir_sms_params_valid(params, err))
        return false;
    if (restir_sms_layers(params, f->scene) != st->rs.layers)
        return err_set(err, ERR_INVALID, "/params/light_reservoirs", "the session has %u reservoirs per pixel, not %u",
                       st->rs.layers, restir_sms_layers(params, f->scene));
    if (sms_uses_prior(params) && !st->prior.entries)
        return err_set(err, ERR_INVALID, "/params/sampler", "the session was made for the sms sampler (no prior)");
    if (sms_uses_prior(params) && st->prior.frames != params->ssp.prior_frames)
        return err_set(err, ERR_INVALID, "/params/prior_frames", "the session keeps %u frames of prior walks, not %u",
                       st->prior.frames, params->ssp.prior_frames);
    if (!restir_frame_gbuffer(&pp.fr, params->jitter_walk, sms_uses_pairs(params), false, 1, err)) return false;
    if ((restir_sms_rest_of(params, f->scene) == RESTIR_SMS_REST_RESTIR_PT) != st->has_rest)
        return err_set(err, ERR_INVALID, "/params/rest", "the session was made for the rest by %s",
                       st->has_rest ? "restir_pt" : "pt");
    /* The rest's frame first, with its own G-buffer (restir_pt's jitter walk) and passes. */
    pp.rest = NULL;
    struct sms_params pt_sms = params->ssp.sms;
    if (st->has_rest && out) {
        struct restir_pt_params rp = restir_sms_rest_params(params);
        if (!restir_pt_render_rest(&st->rest, &rp, f, &st->rest_image, &stats->pass, err)) return false;
        stats->rest_ms = parallel_lap_ms(&pp.fr.t0);
        pp.rest = st->rest_image.pixels;
        pt_sms.caustics_only = true;   /* the pt path's SMS estimates at later vertices only */
    }

    if (!sms_bind(st, params, f, c, err)) return false;
    pp.c = c;
    pp.recv = st->recv[st->rs.cur];
    /* The prior pass ([SMS-SSP §4.1]) under this frame's scene and camera. */
    struct ray_counters prc = {0, 0};
    const bool ssp = params->sampler == RESTIR_SMS_SAMPLER_SSP;
    /* The walks kept from earlier frames describe this one while nothing moved (sms_ssp.h). */
    const bool still = st->rs.has_history && f->prev_scene && f->prev_camera &&
                       memcmp(f->camera, f->prev_camera, sizeof *f->camera) == 0 && !scene_moved(f->prev_scene, f->scene);
    if (ssp && !ssp_prior_build(&st->prior, f->scene, &c->ss, &params->ssp, &pp.fr.camera, f->seed, f->frame, still,
                                pp.fr.threads, &stats->prior, &prc, err))
        return false;
    stats->pass.rays_intersect += prc.intersect;
    stats->pass.rays_occluded += prc.occluded;
    stats->prior_ms = parallel_lap_ms(&pp.fr.t0);
    pp.pt = reference_pt_rest(st->rs.width, st->rs.height, params->max_depth, params->rr_depth);
    /* The rest's SMS estimates, at every non-delta vertex but the receiver, are plain SMS with
     * either sampler: the prior describes receivers only, and without it partitioning has more
     * variance than SMS's seeds over the whole caster (restir_sms.h). */
    pp.pt.sms = &pt_sms;
    if (!restir_frame_initial(&pp.fr, sms_initial_rows, err)) return false;
    for (unsigned i = 0; i < pp.fr.threads; i++) sms_counters_add(&stats->sms, &pp.sms[i]);
    if (!out) return true;

    /* One reuse per reservoir layer, each over its own share of the lights; they share the
     * context, the G-buffers, the receivers, the pair scratch (one pass at a time) and the
     * neighbour pairings. */
    restir_frame_reuse(&pp.fr, &restir_sms_ops, c, 0, params->temporal_cap, params->spatial_neighbors,
                       params->spatial_radius, params->paired_spatial);
    if (!restir_frame_temporal(&pp.fr, err)) return false;
    if (params->spatial_neighbors > 0) {
        /* The target is a luminance, so one selected sample per pixel carries one sample's colour:
         * under lights of different colours most of its noise is colour, which the expectation
         * over the pass's candidates leaves out ([ReSTIR PT Enhanced Fig. 5]). */
        if (!restir_frame_spatial(&pp.fr, params->expected_shading, true, err)) return false;
    } else {
        restir_session_swap(&st->rs);
    }
    restir_frame_reused(&pp.fr);
    stats->shift_newton = atomic_load(&c->shared->newton);
    stats->shift_not_invertible = atomic_load(&c->shared->not_invertible);
    return restir_frame_shade(&pp.fr, sms_shade_rows, err);
}

bool restir_sms_initial_only(struct restir_sms_state *st, const struct restir_sms_params *params,
                             const struct method_frame *f, void *ctx, struct err *err)
{
    return sms_frame(st, params, f, ctx, NULL, NULL, err);
}

bool restir_sms_render(struct restir_sms_state *st, const struct restir_sms_params *params,
                       const struct method_frame *f, struct image *out, struct restir_sms_stats *stats,
                       struct err *err)
{
    struct sms_ctx c;   /* the frame's casters (~7 KiB): on the stack, as the pass */
    return sms_frame(st, params, f, &c, out, stats, err);
}
