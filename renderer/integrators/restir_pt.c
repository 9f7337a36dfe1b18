/* restir_pt.c — ReSTIR PT Enhanced (see restir_pt.h): initial path sampling, the hybrid shift,
 * and the frame driver that runs the shared reuse passes of restir.c.
 *
 * The integrand. A path x_0 (camera) x_1 (the pixel's G-buffer hit) ... x_d is sampled vertex by
 * vertex; at every vertex x_j the lobe and direction come from the random numbers of stream
 * (path seed, j), so a path is its seed plus, past its reconnection vertex, stored geometry.
 * Its contribution in primary sample space ([ReSTIR PT Enhanced eq. 3]) is
 *   F = prod_{j<d-1} f_j |cos_j| / p_j  *  (last step)
 * where the last step is f |cos| Le w_bsdf / p (BSDF sampling hit an emitter) or
 * f |cos| Le w_nee / p_light (NEE), p_light the single-sample light pdf in solid angle and
 * w_nee = M p_light / (M p_light + p_bsdf), w_bsdf = p_bsdf / (M p_light + p_bsdf)
 * ([ReSTIR PT Enhanced] §5, M = RIS candidates; the BSDF pdf is the marginal one, so both weights
 * sum to 1 over the lobes). Emission at x_1 is added by the shade pass, outside the reservoir. The
 * target is p̂ = luminance(F).
 *
 * Initial candidates. Every NEE connection and every emitter hit along one path is a candidate
 * in its own PSS domain (length d, technique); they are resampled by streaming RIS with
 * confidence 1 in total. Their source weight is 1 / prod q_i of the Russian roulette survivals
 * ([ReSTIR PT Enhanced §6]: RR changes the source pdf only, shifts never roll it) times, for NEE,
 * the RIS contribution weight W_ris p_light ([ReSTIR PT Enhanced §5]).
 *
 * Reconnection vertex. x_k is the first vertex (k >= 2) such that x_{k-1} and x_k are both
 * connectable: their lobes are rough (lobe roughness >= alpha_min, or with pdf_connect
 * 1/p(w)^2 >= alpha_min, eq. 26; delta lobes never) and the segment passes the dual footprint
 * threshold (eq. 5) or, without it, a near-field distance. An emitter at the end needs only the
 * first footprint term. The environment is never a reconnection vertex. k <= 63.
 *
 * Hybrid shift to another domain (pixel and frame): replay y_1 .. y_{k-1} with the same random
 * numbers (identity in PSS), reconnect y_{k-1} -> x_k through the stored lobe l_{k-1}, reuse the
 * suffix after x_k (cached radiance; re-traced by replay when the shift changes scenes). Its
 * Jacobian (eq. 4, area form) is
 *   |J| = [p^y_{k-1}(w', l_{k-1}) G(y_{k-1} -> x_k) p^y_k(w_k, l_k)] /
 *         [p^x_{k-1}(w, l_{k-1})  G(x_{k-1} -> x_k) p^x_k(w_k, l_k)]  * dA_to / dA_from,
 * the last factor for a vertex on a shape that moved between the two frames. The shift fails
 * (target 0) unless the offset path would have chosen the same k: no earlier connectable pair,
 * and (y_{k-1}, x_k) connectable. These rules depend only on the path, so T^-1(T(x)) = x
 * (tests/unit/test_restir_pt.c). */
#include "integrators/restir_pt.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "scene/camera.h"
#include "scene/light_ris.h"
#include "scene/light_sampler.h"
#include "core/parallel.h"
#include "reuse/reservoir.h"
#include "core/rng.h"
#include "core/sampling.h"
#include "scene/surface.h"

#define PT_STREAM 0x7270ull                     /* per-path vertex streams */
#define PT_SELECT_STREAM 0x7273656cull          /* initial resampling decisions */
#define PT_PURPOSE_BSDF 1u
#define PT_PURPOSE_NEE 2u
#define PT_PURPOSE_RR 3u
#define PT_MAX_RC 63u                           /* reconnection index fits 6 bits */
#define PT_MAX_LENGTH 127u                      /* path length fits 7 bits */
_Static_assert(PT_MAX_LENGTH - 1 == RESTIR_PT_MAX_DEPTH, "the documented longest path");
#define PT_ENV_PRIM UINT32_MAX                  /* rc_prim of an environment light sample */

/* head.bits: length d (7 bits), reconnection index k (6), NEE technique (1), lobe at x_{k-1}
 * (1), lobe at x_k (1). */
struct pt_sample {
    struct restir_head head;
    float F[3];          /* contribution in the element's own domain (target = luminance) */
    uint32_t seed;       /* random-replay seed */
    uint32_t rc_prim;    /* scene-wide primitive of x_k, or of the NEE light point when k = 0 */
    float rc_b1, rc_b2;  /* its point code (surface_at) */
    float wk_u, wk_v;    /* octahedral w_k leaving x_k; NEE to the environment with k = 0: its direction */
    float rad[3];        /* suffix after x_k's scattering (k <= d-2: with its MIS; k = d-1: Le) */
    float rc_pdf;        /* p_{k-1} G p_k of this path (eq. 4 denominator); NEE end: light pdf_a */
    float light_pdf;     /* k = d-1: light pdf (solid angle at x_k) of the end, for its MIS */
};
_Static_assert(sizeof(struct pt_sample) == RESTIR_PT_RESERVOIR_BYTES, "compact reservoir");

static inline uint32_t pt_length(const struct pt_sample *s) { return s->head.bits & 0x7fu; }
static inline uint32_t pt_rc(const struct pt_sample *s) { return (s->head.bits >> 7) & 0x3fu; }
static inline bool pt_is_nee(const struct pt_sample *s) { return (s->head.bits >> 13) & 1u; }
static inline int pt_lobe_prev(const struct pt_sample *s) { return (s->head.bits >> 14) & 1u; }
static inline int pt_lobe_rc(const struct pt_sample *s) { return (s->head.bits >> 15) & 1u; }
static inline uint16_t pt_bits(uint32_t d, uint32_t k, bool nee, int lobe_prev, int lobe_rc)
{
    return (uint16_t)(d | k << 7 | (uint32_t)nee << 13 | (uint32_t)lobe_prev << 14 | (uint32_t)lobe_rc << 15);
}

/* Russian roulette from the first bounce on (rr_depth 1; pt waits for 3): [ReSTIR PT Enhanced §6]
 * applies it to shorten the initial paths, whose extra noise reuse mostly absorbs. Against rr_depth
 * 3, 13 seeds of 256x256 frames after 32 warm-up frames took 7-17 % less time with a frame's MAPE
 * within -8 % and +3 %: at equal time the error falls (docs/benchmarks.md, "Russian roulette
 * from the first bounce"). */
struct restir_pt_params restir_pt_defaults(void)
{
    return (struct restir_pt_params){
        .max_depth = 64, .candidates = 1, .rr_depth = 1, .rr = true, .nee_candidates = RESTIR_PT_NEE_BY_SCENE, .unify_di = true,
        .temporal = true, .temporal_cap = 20, .history_check = true, .jitter_walk = 0.005f,
        .emission_samples = 16, .spatial_neighbors = 3, .spatial_radius = 0.0f, .spatial_rounds = 1,
        .paired_spatial = true,
        .expected_shading = true,
        .footprint = true, .footprint_c = 0.02f, .near_distance = 0.03f, .pdf_connect = true, .roughness_min = 0.2f,
        .subset = PT_SUBSET_ALL,
    };
}

/* The converge profile: temporal reuse off and a fresh primary ray position every frame, so that
 * a session's frames are independent; the spatial reuse of [ReSTIR BDPT Fig. 12] in its place (3
 * rounds of 6 neighbours); and in a scene with a near-specular surface 8 initial paths a pixel
 * (restir_pt_candidates_by_scene). Measured at equal CPU time on the mean of the frames
 * (docs/benchmarks.md, "restir_pt's converge profile with history" and "Several initial paths a
 * pixel"): a history capped at 1 to 20 frames with the real-time walk correlates the frames more
 * than it lowers each one's error (on cornell-glossy about 3x the RMSE of the same rounds without
 * it, on door-ajar 2.4-4x the relMSE of this profile); fewer rounds or neighbours trade
 * cornell-glossy's relMSE for door-ajar's; and a path that no shift moves is only as good as the
 * pixel's own paths. */
void restir_pt_converge(struct restir_pt_params *p)
{
    p->temporal = false;
    p->jitter_walk = 0.0f;
    p->candidates = RESTIR_PT_CANDIDATES_BY_SCENE;
    p->spatial_rounds = 3;
    p->spatial_neighbors = 6;
}

struct restir_pt_params restir_pt_rest_params(bool independent_frames, uint32_t max_depth)
{
    struct restir_pt_params rp = restir_pt_defaults();
    if (independent_frames) restir_pt_converge(&rp);
    rp.max_depth = max_depth;
    return rp;
}

/* RIS among light candidates ([ReSTIR PT Enhanced §5]) pays where choosing a light by its power
 * alone is poor: several emitters at different distances and orientations from the shading point.
 * With one emitter the candidates differ only in the cosines and distances over it; on cornell-box,
 * cornell-glossy and door-ajar the three extra candidates cost about a fifth of the frame and
 * bought no measurable error reduction (docs/benchmarks.md), so a single-emitter scene gets
 * plain NEE. */
uint32_t restir_pt_nee_by_scene(const struct scene *scene)
{
    uint32_t emitters = !vec3_is_zero(scene->env_radiance);
    for (uint32_t i = 0; i < scene->shape_count && emitters < 2; i++)
        emitters += material_is_emissive(&scene->materials[scene->shapes[i].material]);
    return emitters >= 2 ? 4u : 1u;
}

/* Several initial paths pay where no shift moves a path: one through a near-specular vertex
 * (below the connectability threshold) is random-replayed by every shift, and a neighbour's replay
 * from another primary hit seldom finds the same narrow lobe again, so a pixel's estimate of such
 * light is as good as the paths it traced itself. At pt's CPU time for 64 spp, 8 paths cut the
 * converge profile's relMSE 3x on cornell-glossy, 6x on reflective-plane, 1.7x on door-ajar; on
 * cornell-box, all diffuse, fewer frames at the same time cost 15-20 % relMSE and RMSE
 * (docs/benchmarks.md, "Several initial paths a pixel"). */
uint32_t restir_pt_candidates_by_scene(const struct scene *scene, float roughness_min)
{
    return scene_has_near_specular(scene, roughness_min) ? 8u : 1u;
}

/* The G-buffers estimate the emission seen directly (gbuffer.h) when more than the primary ray's
 * own is asked for and an emitting shape can make edge pixels. */
static bool pt_keeps_emission(const struct restir_pt_params *p, const struct scene *scene)
{
    return p->emission_samples > 1 && scene_has_emitting_shape(scene);
}

bool restir_pt_params_valid(const struct restir_pt_params *p, struct err *err)
{
    if (p->max_depth < 1 || p->max_depth > PT_MAX_LENGTH - 1)
        return err_set(err, ERR_INVALID, "/params/max_depth", "max_depth must be in 1..%u", PT_MAX_LENGTH - 1);
    if (p->candidates > 64)
        return err_set(err, ERR_INVALID, "/params/candidates", "candidates must be in 0..64 (0 = by scene)");
    if (p->nee_candidates > 64 && p->nee_candidates != RESTIR_PT_NEE_BY_SCENE)
        return err_set(err, ERR_INVALID, "/params/nee_candidates", "nee_candidates must be in 0..64");
    if (!gbuffer_jitter_walk_valid(p->jitter_walk, err)) return false;
    if (!gbuffer_emission_samples_valid(p->emission_samples, err)) return false;
    if (p->temporal_cap < 1 || p->temporal_cap > 1000)
        return err_set(err, ERR_INVALID, "/params/temporal_cap", "temporal_cap must be in 1..1000");
    if (p->temporal_cap_replay > 1000)
        return err_set(err, ERR_INVALID, "/params/temporal_cap_replay",
                       "temporal_cap_replay must be in 0..1000 (0 = temporal_cap)");
    if (p->spatial_neighbors > 64)
        return err_set(err, ERR_INVALID, "/params/spatial_neighbors", "spatial_neighbors must be in 0..64");
    if (!(p->spatial_radius == 0.0f || (p->spatial_radius >= 1.0f && p->spatial_radius <= 256.0f)))
        return err_set(err, ERR_INVALID, "/params/spatial_radius",
                       "spatial_radius must be 0 (by resolution) or in 1..256 pixels");
    if (p->spatial_rounds < 1 || p->spatial_rounds > 8)
        return err_set(err, ERR_INVALID, "/params/spatial_rounds", "spatial_rounds must be in 1..8");
    if (!(p->reject_normal_cos >= 0.0f && p->reject_normal_cos <= 1.0f))
        return err_set(err, ERR_INVALID, "/params/reject_normal_cos", "reject_normal_cos must be in [0, 1]");
    if (!(p->reject_depth >= 0.0f && p->reject_depth <= 1.0f))
        return err_set(err, ERR_INVALID, "/params/reject_depth", "reject_depth must be in [0, 1]");
    if (!(p->footprint_c > 0.0f && p->footprint_c <= 100.0f))
        return err_set(err, ERR_INVALID, "/params/footprint_c", "footprint_c must be in (0, 100]");
    if (!(p->near_distance >= 0.0f && p->near_distance <= 1.0f))
        return err_set(err, ERR_INVALID, "/params/near_distance", "near_distance must be in [0, 1]");
    if (!(p->roughness_min > 0.0f && p->roughness_min <= 1.0f))
        return err_set(err, ERR_INVALID, "/params/roughness_min", "roughness_min must be in (0, 1]");
    return true;
}

/* ---- per-frame context ---------------------------------------------------------------------- */

struct pt_ctx {
    const struct restir_pt_params *p;
    const struct restir_pt_state *st;
    const struct scene *scene[2];        /* [RESTIR_CURRENT], [RESTIR_PREVIOUS] */
    struct vec3 eye[2];
    const struct gbuffer *gbuf[2];
    uint64_t seed;
    uint32_t frame;
    uint32_t nee_m;                      /* RIS candidates; 0 = no NEE */
    uint32_t candidates;                 /* initial paths a pixel (>= 1) */
    float near_dist2;                    /* without footprint: squared minimum segment length */
    float pdf_max;                       /* pdf_connect: a lobe is rough when p(w) <= this */
    bool keep_owned, keep_rest;          /* the subset's two halves (sms.h) */
    bool tracked;                        /* a subset: each path's caustic chain is followed */
};
_Static_assert(sizeof(struct pt_ctx) <= RESTIR_PT_CTX_BYTES, "context fits the test buffer");

/* A path vertex on a surface, with w_o in its shading frame. */
struct pt_vertex {
    struct surface s;
    const struct material *m;
    struct vec3 wo;
    float b1, b2;      /* point code (surface_at) */
};

/* The segment entering vertex x_j from x_{j-1}: what connectability and the Jacobian need. */
struct pt_segment {
    float pdf_lobe;    /* p_{j-1}(w_{j-1}, l_{j-1}): the sampling pdf (solid angle) */
    float pdf_marg;    /* the marginal BSDF pdf of w_{j-1} (footprint, eq. 26) */
    bool rough;        /* the lobe used at x_{j-1} is rough */
    int lobe;          /* l_{j-1} */
    float dist2;
    float cos_end;     /* |cos| at x_j (geometric normal) */
    float cos_start;   /* |cos| at x_{j-1} */
};

struct pt_thread {
    const struct pt_ctx *c;
    struct restir_counters *cnt;
    float footprint;   /* the domain's eq. 5 right-hand side */
};

static uint32_t pt_path_seed(uint64_t seed, uint32_t frame, uint32_t pixel)
{
    return (uint32_t)rng_mix64(seed ^ rng_mix64((uint64_t)frame << 32 ^ pixel ^ rng_mix64(PT_STREAM)));
}

static inline struct rng pt_stream(uint32_t path_seed, uint32_t vertex, uint32_t purpose)
{
    /* Distinct (path seed, vertex, purpose) give distinct keys: vertex < 2^24, purpose < 2^8. */
    return rng_keyed((uint64_t)path_seed << 32 | (uint64_t)vertex << 8 | purpose);
}

static uint32_t pt_prim_id(const struct restir_pt_state *st, uint32_t shape, uint32_t prim)
{
    return st->prim_first[shape] + prim;
}

static void pt_prim_decode(const struct restir_pt_state *st, uint32_t id, uint32_t *shape, uint32_t *prim)
{
    /* The last shape whose first primitive is <= id (shapes without primitives share their
     * successor's first id and are skipped). Branch-free: every shift decodes one id, and the
     * comparisons of a search over a few shapes are unpredictable. */
    uint32_t lo = 0, n = st->shape_count;  /* the answer is in [lo, lo + n) */
    while (n > 1) {
        const uint32_t half = n / 2;
        lo = st->prim_first[lo + half] <= id ? lo + half : lo;
        n -= half;
    }
    *shape = lo;
    *prim = id - st->prim_first[lo];
}

static inline float pt_balance(float a, float b)
{
    return a / (a + b);
}

/* The marginal pdf of wi over all lobes, given that of one lobe: the same number for a one-lobe
 * material (diffuse, conductor), where it saves a BSDF evaluation per vertex. */
static inline float pt_marginal(const struct material *m, float lobe_pdf, struct vec3 wo, struct vec3 wi)
{
    return material_lobe_count(m) == 1 ? lobe_pdf : material_pdf(m, wo, wi);
}

/* A stored lobe seen again at a reconnection: its value and pdf for (wo, wi); false when the
 * material there has no such lobe, it is delta (never reconnected) or it gives nothing. */
static bool pt_lobe_at(const struct material *m, int lobe, struct vec3 wo, struct vec3 wi, struct vec3 *f, float *pdf)
{
    if (lobe >= material_lobe_count(m) || (material_lobe_flags(m, lobe) & BSDF_DELTA)) return false;
    *pdf = material_pdf_lobe(m, lobe, wo, wi);
    *f = material_eval_lobe(m, lobe, wo, wi, TRANSPORT_RADIANCE);
    return *pdf > 0.0f && !vec3_is_zero(*f);
}

/* Rough lobe at a vertex: never delta; eq. 26 with pdf_connect, else lobe roughness. */
static bool pt_rough_lobe(const struct pt_ctx *c, const struct material *m, int lobe, float pdf_marg)
{
    unsigned flags = material_lobe_flags(m, lobe);
    if (flags & BSDF_DELTA) return false;
    if (c->p->pdf_connect) return pdf_marg > 0.0f && pdf_marg <= c->pdf_max;
    return (flags & BSDF_DIFFUSE) || material_lobe_roughness(m, lobe) >= c->p->roughness_min;
}

/* The same for NEE, which evaluates every non-delta lobe. */
static bool pt_rough_nee(const struct pt_ctx *c, const struct material *m, float pdf_marg)
{
    for (int l = 0; l < material_lobe_count(m); l++)
        if (pt_rough_lobe(c, m, l, pdf_marg)) return true;
    return false;
}

/* Whether x_{j-1} and x_j form the reconnection pair: `seg` enters x_j; `end` when x_j is the
 * path's emitter, else the lobe leaving x_j is rough (out_rough) with marginal pdf out_pdf. */
static bool pt_connectable(const struct pt_thread *t, uint32_t j, const struct pt_segment *seg, bool end,
                           bool out_rough, float out_pdf)
{
    if (j < 2 || j > PT_MAX_RC || !seg->rough || !(end || out_rough)) return false;
    const struct pt_ctx *c = t->c;
    if (!c->p->footprint) return seg->dist2 >= c->near_dist2;
    /* Eq. 5: 1 / max(p_{k-1} G(x_{k-1} -> x_k), p_k G(x_k -> x_{k-1})) >= threshold. */
    float a = seg->pdf_marg * seg->cos_end / seg->dist2;
    if (!end) {
        float b = out_pdf * seg->cos_start / seg->dist2;
        if (b > a) a = b;
    }
    return a * t->footprint <= 1.0f;
}

/* Whether opaque_primary leaves the paths of this primary surface to another method (restir_sss,
 * whose BSSRDF samples them); the emission seen there is still ours (pt_initial_pixel). */
static inline bool pt_left_out(const struct pt_ctx *c, const struct scene *scene, const struct gbuffer_surface *h)
{
    return c->p->opaque_primary && scene->materials[h->material].kind == MATERIAL_TRANSLUCENT;
}

/* The primary vertex of a domain and its eq. 5 threshold (c/100) |x0 - x1|^2 / (cos / 4 pi):
 * the G-buffer's surface, the same numbers for the initial pass and every shift into the pixel.
 * x_1 never reconnects (k >= 2), so its primitive and point code are not loaded. */
static bool pt_primary(const struct pt_ctx *c, struct restir_domain d, struct pt_vertex *v, float *footprint)
{
    const struct gbuffer_surface *h = &c->gbuf[d.frame]->surf[d.pixel];
    if (h->material == GBUFFER_NO_HIT) return false;
    const struct scene *scene = c->scene[d.frame];
    if (pt_left_out(c, scene, h)) return false;
    v->s.p = h->p, v->s.ng = h->ng, v->s.ns = h->ns;
    v->s.frame = frame_from_normal(h->ns);
    v->s.material = h->material;
    v->s.shape = v->s.prim = UINT32_MAX;
    v->b1 = v->b2 = 0.0f;
    v->m = &scene->materials[v->s.material];
    struct vec3 to_eye = vec3_sub(c->eye[d.frame], v->s.p);
    float d2 = vec3_length2(to_eye);
    struct vec3 wo_world = vec3_scale(to_eye, 1.0f / sqrtf(d2));
    v->wo = frame_to_local(&v->s.frame, wo_world);
    float cos1 = fabsf(vec3_dot(wo_world, v->s.ng));
    *footprint = c->p->footprint_c * 0.01f * d2 * (4.0f * (float)M_PI) / (cos1 > 1e-6f ? cos1 : 1e-6f);
    return true;
}

/* Traces from vertex v along world direction `dir` (leaving on the side it points to). */
static bool pt_trace(const struct scene *scene, const struct pt_vertex *v, struct vec3 dir, struct hit *hit,
                     struct ray_counters *rc)
{
    struct vec3 org = surface_offset(v->s.p, v->s.ng, dir);
    return accel_intersect(scene->accel, org, dir, 0.0f, INFINITY, hit, rc);
}

/* Whether the environment is seen from v along `dir` (points use pt_visible_points: a segment
 * between two offset ends). */
static bool pt_sees_env(const struct scene *scene, const struct pt_vertex *v, struct vec3 dir, struct ray_counters *rc)
{
    struct vec3 org = surface_offset(v->s.p, v->s.ng, dir);
    return !accel_occluded(scene->accel, org, dir, 0.0f, INFINITY, rc);
}

/* Visibility between two surface points, both ends moved off their surfaces: a reconnection
 * tests a vertex that was found by a ray from elsewhere, and its rebuilt position may sit a float
 * rounding behind its own surface. */
static bool pt_visible_points(const struct scene *scene, struct vec3 a, struct vec3 a_ng, struct vec3 b, struct vec3 b_ng,
                              struct ray_counters *rc)
{
    struct vec3 dir = vec3_sub(b, a);
    struct vec3 org = surface_offset(a, a_ng, dir), end = surface_offset(b, b_ng, vec3_neg(dir));
    struct vec3 seg = vec3_sub(end, org);
    float len = vec3_length(seg);
    if (!(len > 0.0f)) return false;
    return !accel_occluded(scene->accel, org, vec3_scale(seg, 1.0f / len), 0.0f, len * (1.0f - 1e-4f), rc);
}

static void pt_vertex_from_hit(const struct scene *scene, const struct pt_vertex *from, struct vec3 dir,
                               const struct hit *hit, struct pt_vertex *out)
{
    surface_from_hit(scene, hit, from->s.p, dir, &out->s);
    surface_point_code(scene, hit, &out->s, &out->b1, &out->b2);
    out->m = &scene->materials[out->s.material];
    /* w_o points at the previous vertex itself, not back along the ray (whose origin was offset
     * off the surface): a shift that rebuilds this vertex from its code computes the same w_o. */
    out->wo = frame_to_local(&out->s.frame, vec3_normalize(vec3_sub(from->s.p, out->s.p)));
}

/* One BSDF step from v with the replay stream of vertex j: direction, factor f |cos| / p, the
 * marginal pdf and roughness of the lobe. False when the path ends there. */
struct pt_step {
    struct bsdf_sample bs;
    struct vec3 dir;
    struct vec3 factor;
    float pdf_marg;
    bool rough;
};

static bool pt_bsdf_step(const struct pt_ctx *c, const struct pt_vertex *v, uint32_t path_seed, uint32_t j,
                         struct pt_step *out)
{
    struct rng r = pt_stream(path_seed, j, PT_PURPOSE_BSDF);
    float ul = rng_next_float(&r), u1 = rng_next_float(&r), u2 = rng_next_float(&r);
    if (!material_sample(v->m, v->wo, ul, u1, u2, TRANSPORT_RADIANCE, &out->bs)) return false;
    out->dir = frame_to_world(&v->s.frame, out->bs.wi);
    if (!(vec3_dot(out->dir, v->s.ng) * out->bs.wi.z > 0.0f)) return false;
    out->factor = vec3_scale(out->bs.f, fabsf(out->bs.wi.z) / out->bs.pdf_w);
    bool delta = (out->bs.flags & BSDF_DELTA) != 0;
    out->pdf_marg = delta ? 0.0f : pt_marginal(v->m, out->bs.pdf_w, v->wo, out->bs.wi);
    out->rough = !delta && pt_rough_lobe(c, v->m, out->bs.lobe, out->pdf_marg);
    return true;
}

/* The segment from vertex a (leaving through `lobe`, -1 = NEE's all lobes) to the point b, from
 * the two positions: the initial pass and every shift derive connectability and the Jacobian
 * from the same numbers, whichever ray found b. */
static void pt_segment_geo(const struct pt_ctx *c, const struct pt_vertex *a, int lobe, struct vec3 b_p, struct vec3 b_ng,
                           struct pt_segment *seg)
{
    struct vec3 w = vec3_sub(b_p, a->s.p);
    seg->dist2 = vec3_length2(w);
    w = vec3_scale(w, 1.0f / sqrtf(seg->dist2));
    struct vec3 wi = frame_to_local(&a->s.frame, w);
    seg->lobe = lobe < 0 ? 0 : lobe;
    if (lobe < 0) {
        seg->pdf_marg = seg->pdf_lobe = material_pdf(a->m, a->wo, wi);
        seg->rough = pt_rough_nee(c, a->m, seg->pdf_marg);
    } else {
        seg->pdf_lobe = material_pdf_lobe(a->m, lobe, a->wo, wi);
        seg->pdf_marg = pt_marginal(a->m, seg->pdf_lobe, a->wo, wi);
        seg->rough = pt_rough_lobe(c, a->m, lobe, seg->pdf_marg);
    }
    seg->cos_end = fabsf(vec3_dot(w, b_ng));
    seg->cos_start = fabsf(vec3_dot(w, a->s.ng));
}

/* Light pdf (solid angle at the shading point) of an emitter point seen along `dir`. */
static float pt_light_pdf_w(const struct scene *scene, uint32_t shape, uint32_t prim, float dist2, float cos_light)
{
    return sampling_area_to_solid_angle(light_sampler_pdf_a(scene->lights, shape, prim), dist2, cos_light);
}

/* MIS weight of BSDF sampling against M-candidate NEE for a BSDF-sampled end. */
static float pt_mis_bsdf(const struct pt_ctx *c, bool delta, float pdf_marg, float light_pdf_w)
{
    if (delta || c->nee_m == 0 || !(light_pdf_w > 0.0f)) return 1.0f;
    return pt_balance(pdf_marg, (float)c->nee_m * light_pdf_w);
}

static float pt_env_pdf_w(const struct scene *scene)
{
    return vec3_is_zero(scene->env_radiance) ? 0.0f : light_sampler_env_pdf_w(scene->lights);
}

/* Point code of a light sample (triangles: its barycentrics; spheres: the object-space direction). */
static void pt_light_code(const struct scene *scene, const struct light_sample *ls, float *b1, float *b2)
{
    if (scene->shapes[ls->shape].kind == SHAPE_MESH) {
        *b1 = ls->b1;
        *b2 = ls->b2;
        return;
    }
    const struct shape *sh = &scene->shapes[ls->shape];
    struct vec3 d = vec3_normalize(vec3_sub(xform_point(accel_shape_to_object(scene->accel, ls->shape), ls->p), sh->center));
    surface_oct_encode(d, b1, b2);
}


/* A light point from its code: emissive triangles from the light sampler's table (what NEE
 * sampled, bit for bit, at the cost of a lookup), spheres rebuilt from the surface. */
static void pt_light_point(const struct scene *scene, uint32_t shape, uint32_t prim, float b1, float b2, struct vec3 *p,
                           struct vec3 *ng)
{
    if (!light_sampler_triangle_point(scene->lights, shape, prim, b1, b2, p, ng))
        surface_point_at(scene, shape, prim, b1, b2, p, ng);
}

/* ---- initial path sampling ------------------------------------------------------------------ */

/* Where a path reconnects, as stored with it. */
struct pt_rc_record {
    uint32_t k;          /* 0 = none */
    uint32_t prim;       /* scene-wide primitive of x_k (or of the light point; PT_ENV_PRIM) */
    float b1, b2;
    struct vec3 wk;      /* world direction leaving x_k (NEE to the environment: its direction) */
    int lobe_prev, lobe_rc;
    float rc_pdf;
};

/* The subset (restir_pt_params.subset; sms.h): whether the emission that a BSDF-sampled path meets
 * after the scattering events in `track` belongs to it. Emission reached by next-event estimation,
 * the environment and the emission seen directly always belong to the rest. A shift keeps the
 * class of what it reconnects: x_k scatters through a rough lobe, which restarts the track, so a
 * suffix it copies ends as it did in the base path; what a shift replays or re-traces is tracked
 * afresh. */
static inline void pt_track(const struct pt_ctx *c, const struct scene *scene, struct sms_track *track,
                            const struct surface *s, unsigned flags)
{
    if (c->tracked) sms_track_scatter(scene, track, s, flags);
}

static inline bool pt_keeps_hit(const struct pt_ctx *c, const struct scene *scene, const struct sms_track *track)
{
    if (!c->tracked) return true;
    return sms_track_owned(scene, track) ? c->keep_owned : c->keep_rest;
}

static void pt_store(struct pt_sample *out, uint32_t seed, uint32_t d, bool nee, struct vec3 F,
                     const struct pt_rc_record *rc, struct vec3 rad, float light_pdf)
{
    out->F[0] = F.x, out->F[1] = F.y, out->F[2] = F.z;
    out->seed = seed;
    out->head.bits = pt_bits(d, rc->k, nee, rc->lobe_prev, rc->lobe_rc);
    out->rc_prim = rc->prim;
    out->rc_b1 = rc->b1, out->rc_b2 = rc->b2;
    surface_oct_encode(rc->wk, &out->wk_u, &out->wk_v);
    out->rad[0] = rad.x, out->rad[1] = rad.y, out->rad[2] = rad.z;
    out->rc_pdf = rc->rc_pdf;
    out->light_pdf = light_pdf;
}

static struct pt_rc_record pt_rc_at(const struct pt_ctx *c, const struct pt_vertex *v, struct vec3 wk, int lobe_prev,
                                    int lobe_rc, float rc_pdf, uint32_t k)
{
    return (struct pt_rc_record){.k = k, .prim = pt_prim_id(c->st, v->s.shape, v->s.prim), .b1 = v->b1, .b2 = v->b2,
                                 .wk = wk, .lobe_prev = lobe_prev, .lobe_rc = lobe_rc, .rc_pdf = rc_pdf};
}

/* The path throughput up to a reconnection vertex x_k as a shift evaluates it: x_{k-1}'s factor
 * f |cos| / p of lobe `lobe` taken along the segment between the two positions rather than along
 * the sampled ray, whose origin was moved off the surface. At grazing angles the two differ by
 * several per cent; with this the initial sample and its shift to its own pixel compute one
 * integrand ([ReSTIR PT Enhanced eq. 4] is written on vertex positions). `beta_before` is the
 * throughput up to x_{k-2}; false (beta untouched) when the lobe gives nothing along the
 * segment. */
static bool pt_rc_beta(const struct pt_vertex *prev, int lobe, struct vec3 xk_p, struct vec3 beta_before,
                       struct vec3 *beta)
{
    struct vec3 w = vec3_normalize(vec3_sub(xk_p, prev->s.p));
    struct vec3 wi = frame_to_local(&prev->s.frame, w);
    struct vec3 f;
    float pdf;
    if (!(vec3_dot(w, prev->s.ng) * wi.z > 0.0f) || !pt_lobe_at(prev->m, lobe, prev->wo, wi, &f, &pdf)) return false;
    *beta = vec3_mul(beta_before, vec3_scale(f, fabsf(wi.z) / pdf));
    return true;
}

/* One candidate path from the primary hit x_1 (v), its candidates offered to `rs` at weights
 * scaled by inv_m (each path is one of M draws from the same source, so their resampling MIS
 * weights are the uniform 1/M: Lin et al. 2022), the direct light it finds outside the reservoir
 * added to *direct at the same scale. */
static void pt_initial_path(const struct pt_thread *t, struct pt_vertex v, uint32_t seed, float inv_m,
                            struct reservoir_stream *rs_out, struct rng *sel_io, struct pt_sample *out,
                            struct vec3 *direct)
{
    const struct pt_ctx *c = t->c;
    const struct restir_pt_params *p = c->p;
    const struct scene *scene = c->scene[RESTIR_CURRENT];
    struct ray_counters *rays = &t->cnt->rays;
    const struct pt_thread th = *t;
    struct reservoir_stream rs = *rs_out;
    struct rng sel = *sel_io;
    struct vec3 beta = vec3_splat(1.0f);      /* prod f |cos| / p over x_1 .. x_{j-1} */
    struct vec3 beta_suf = vec3_splat(1.0f);  /* the same over the vertices after x_k */
    struct pt_vertex prev = v;                /* x_{j-1} (j >= 2) */
    struct vec3 beta_prev = beta;             /* prod over x_1 .. x_{j-2} */
    int prev_lobe = 0;                        /* the lobe sampled at x_{j-1} */
    double src = 1.0;                         /* prod of Russian roulette survival probabilities */
    float rr_scale = 1.0f;                    /* undoes refraction's radiance scaling for the
                                                 roulette (reference_pt.c) */
    struct pt_segment seg = {0};              /* enters x_j (j >= 2) */
    struct pt_rc_record rc = {0};             /* the first connectable pair of the continuation */
    const bool nee_on = c->nee_m > 0 && light_sampler_count(scene->lights) > 0 && c->keep_rest;
    struct sms_track track = sms_track_start();   /* from the camera on (pt_keeps_hit) */

    for (uint32_t j = 1; j <= p->max_depth; j++) {
        const uint32_t d = j + 1;  /* length of the paths that end after x_j */
        const bool offer = p->unify_di || j >= 2;
        /* The throughput up to x_j when x_j reconnects (pt_rc_beta; beta itself when the lobe gives
         * nothing along the segment): NEE and the BSDF step may both want it, it is computed once. */
        struct vec3 beta_rc = beta;
        bool beta_rc_done = false;

        /* NEE candidate: x_1 .. x_j -> light. */
        if (nee_on && (material_flags(v.m) & (BSDF_DIFFUSE | BSDF_GLOSSY))) {
            struct rng nr = pt_stream(seed, j, PT_PURPOSE_NEE);
            struct light_ris_sample ls = {0};
            unsigned rejected = 0;
            if (light_ris_sample(scene, &v.s, v.m, v.wo, c->nee_m, &nr, &ls, &rejected) &&
                (ls.light.is_env ? pt_sees_env(scene, &v, ls.wi_world, rays)
                                 : pt_visible_points(scene, v.s.p, v.s.ng, ls.light.p, ls.light.n, rays))) {
                struct vec3 wi = frame_to_local(&v.s.frame, ls.wi_world);
                float p1 = ls.pdf_light_w, p2 = material_pdf(v.m, v.wo, wi);
                struct vec3 end = vec3_scale(vec3_mul(ls.f_cos, ls.Le), pt_balance((float)c->nee_m * p1, p2) / p1);
                bool rough = pt_rough_nee(c, v.m, p2);
                /* x_j reconnects when no earlier pair did and (x_{j-1}, x_j) is connectable. */
                const bool rc_here = offer && rc.k == 0 && pt_connectable(&th, j, &seg, false, rough, p2);
                if (rc_here && !beta_rc_done) {
                    pt_rc_beta(&prev, prev_lobe, v.s.p, beta_prev, &beta_rc);
                    beta_rc_done = true;
                }
                struct vec3 F = vec3_mul(rc_here ? beta_rc : beta, end);
                double W_u = (double)ls.W * p1 * inv_m / src;  /* [ReSTIR PT Enhanced §5]: W_ris p_light */
                float target = vec3_luminance(F);
                if (!offer) {
                    *direct = vec3_add(*direct, vec3_scale(F, (float)W_u));
                } else if (reservoir_stream_offer(&rs, target * W_u, target, 0.0f, rng_next_float(&sel))) {
                    struct pt_rc_record r = rc;
                    struct vec3 rad = vec3_mul(beta_suf, end);
                    float light_pdf = 0.0f;
                    if (rc_here) {
                        /* x_j reconnects; the NEE direction leaves it (its pdf ignores w_o: B = 1). */
                        r = pt_rc_at(c, &v, ls.wi_world, seg.lobe, 0, seg.pdf_lobe * seg.cos_end / seg.dist2, j);
                        rad = ls.Le;
                        light_pdf = p1;
                    } else if (rc.k == 0) {
                        /* The light point itself is stored: reconnected (k = d) or replayed (k = 0).
                         * Its connectability is judged on the point rebuilt from its code, as a
                         * shift sees it. */
                        r = (struct pt_rc_record){.k = 0, .wk = ls.wi_world};
                        if (ls.light.is_env) {
                            r.prim = PT_ENV_PRIM;
                            r.rc_pdf = ls.light.pdf_w;
                        } else {
                            r.prim = pt_prim_id(c->st, ls.light.shape, ls.light.prim);
                            pt_light_code(scene, &ls.light, &r.b1, &r.b2);
                            r.rc_pdf = ls.light.pdf_a;
                            struct vec3 lp, lng;
                            pt_light_point(scene, ls.light.shape, ls.light.prim, r.b1, r.b2, &lp, &lng);
                            struct pt_segment lseg;
                            pt_segment_geo(c, &v, -1, lp, lng, &lseg);
                            if (pt_connectable(&th, d, &lseg, true, false, 0.0f)) r.k = d;
                        }
                    }
                    pt_store(out, seed, d, true, F, &r, rad, light_pdf);
                }
            }
            t->cnt->rejected += rejected;
        }

        /* BSDF sampling continues the path. */
        struct pt_step stp;
        if (!pt_bsdf_step(c, &v, seed, j, &stp)) break;
        pt_track(c, scene, &track, &v.s, stp.bs.flags);
        bool found_here = false;
        if (rc.k == 0 && pt_connectable(&th, j, &seg, false, stp.rough, stp.pdf_marg)) {
            rc = pt_rc_at(c, &v, stp.dir, seg.lobe, stp.bs.lobe, seg.pdf_lobe * seg.cos_end / seg.dist2 * stp.bs.pdf_w, j);
            found_here = true;
            if (!beta_rc_done) {
                pt_rc_beta(&prev, prev_lobe, v.s.p, beta_prev, &beta_rc);
                beta_rc_done = true;
            }
            beta = beta_rc;
        }
        const struct vec3 beta_in = beta;  /* prod over x_1 .. x_{j-1} */
        beta = vec3_mul(beta, stp.factor);
        if (rc.k && !found_here) beta_suf = vec3_mul(beta_suf, stp.factor);
        if (stp.bs.flags & BSDF_TRANSMISSION) rr_scale /= material_radiance_scale(v.m, v.wo, stp.bs.wi);
        if (p->rr && j >= p->rr_depth) {
            /* Decoupled RR ([ReSTIR PT Enhanced §6]): survival changes the source pdf, never the
             * integrand. */
            struct rng rr = pt_stream(seed, j, PT_PURPOSE_RR);
            float q = (float)(vec3_max_comp(beta) * rr_scale / src);
            q = q < 0.95f ? q : 0.95f;
            if (!(q > 0.0f) || rng_next_float(&rr) >= q) break;
            src *= q;
        }

        const bool delta = (stp.bs.flags & BSDF_DELTA) != 0;
        struct hit hit;
        if (!pt_trace(scene, &v, stp.dir, &hit, rays)) {
            const bool env = c->keep_rest && !vec3_is_zero(scene->env_radiance);
            if (env && offer) {
                float lp = pt_env_pdf_w(scene);
                struct vec3 end = vec3_scale(scene->env_radiance, pt_mis_bsdf(c, delta, stp.pdf_marg, lp));
                struct vec3 F = vec3_mul(beta, end);
                float target = vec3_luminance(F);
                if (reservoir_stream_offer(&rs, target * inv_m / src, target, 0.0f, rng_next_float(&sel))) {
                    struct pt_rc_record r = rc;
                    struct vec3 rad = found_here ? scene->env_radiance : vec3_mul(beta_suf, end);
                    pt_store(out, seed, d, false, F, &r, rad, found_here ? lp : 0.0f);
                }
            } else if (env) {
                float lp = pt_env_pdf_w(scene);
                *direct = vec3_add(*direct, vec3_scale(vec3_mul(beta, scene->env_radiance),
                                                       pt_mis_bsdf(c, delta, stp.pdf_marg, lp) * inv_m / (float)src));
            }
            break;
        }
        struct pt_vertex nv;
        pt_vertex_from_hit(scene, &v, stp.dir, &hit, &nv);
        float dist2 = vec3_length2(vec3_sub(nv.s.p, v.s.p));
        /* The segment's connectability numbers matter only until the reconnection pair is found. */
        struct pt_segment nseg = {0};
        if (rc.k == 0) pt_segment_geo(c, &v, stp.bs.lobe, nv.s.p, nv.s.ng, &nseg);

        if (material_is_emissive(nv.m) && pt_keeps_hit(c, scene, &track)) {
            struct vec3 Le = light_sampler_emitted(nv.m, -vec3_dot(stp.dir, nv.s.ng));
            if (!vec3_is_zero(Le)) {
                float lp = pt_light_pdf_w(scene, nv.s.shape, nv.s.prim, dist2, vec3_dot(stp.dir, nv.s.ng));
                struct vec3 end = vec3_scale(Le, pt_mis_bsdf(c, delta, stp.pdf_marg, lp));
                struct vec3 beta_end = beta;
                /* The emitter x_d itself reconnects: its segment's numbers come from the positions. */
                const bool rc_end = offer && !found_here && rc.k == 0 && pt_connectable(&th, d, &nseg, true, false, 0.0f);
                if (rc_end && pt_rc_beta(&v, stp.bs.lobe, nv.s.p, beta_in, &beta_end))
                    end = vec3_scale(Le, pt_mis_bsdf(c, false, nseg.pdf_marg,
                                                     pt_light_pdf_w(scene, nv.s.shape, nv.s.prim, nseg.dist2, nseg.cos_end)));
                struct vec3 F = vec3_mul(beta_end, end);
                float target = vec3_luminance(F);
                if (!offer) {
                    *direct = vec3_add(*direct, vec3_scale(F, (float)(inv_m / src)));
                } else if (reservoir_stream_offer(&rs, target * inv_m / src, target, 0.0f, rng_next_float(&sel))) {
                    struct pt_rc_record r = rc;
                    struct vec3 rad = vec3_mul(beta_suf, end);
                    float light_pdf = 0.0f;
                    if (found_here) {
                        rad = Le;
                        light_pdf = lp;
                    } else if (rc_end) {
                        r = pt_rc_at(c, &nv, stp.dir, stp.bs.lobe, 0, nseg.pdf_lobe * nseg.cos_end / nseg.dist2, d);
                    }
                    pt_store(out, seed, d, false, F, &r, rad, light_pdf);
                }
            }
        }
        prev = v;
        prev_lobe = stp.bs.lobe;
        beta_prev = beta_in;
        v = nv;
        seg = nseg;
    }
    *rs_out = rs;
    *sel_io = sel;
}

/* Samples the pixel's `candidates` paths from its primary hit and resamples their candidates into
 * `out`; light that reaches the pixel outside the reservoir — emission seen directly (the
 * environment for an escaped primary ray; the G-buffer's estimate when it keeps one, gbuffer.h),
 * and direct light when it is not unified — goes to *direct. */
static void pt_initial_pixel(const struct pt_thread *t, uint32_t pixel, struct pt_sample *out, struct vec3 *direct)
{
    const struct pt_ctx *c = t->c;
    const struct scene *scene = c->scene[RESTIR_CURRENT];
    memset(out, 0, sizeof *out);
    const struct vec3 *seen = c->gbuf[RESTIR_CURRENT]->emission;
    /* Emission seen directly belongs to the rest (pt_keeps_hit). */
    *direct = !c->keep_rest ? vec3_splat(0.0f) : seen ? seen[pixel] : scene->env_radiance;
    struct pt_thread th = *t;
    struct pt_vertex v;
    const struct gbuffer_surface *h = &c->gbuf[RESTIR_CURRENT]->surf[pixel];
    if (h->material != GBUFFER_NO_HIT && pt_left_out(c, scene, h)) {
        /* Its paths are restir_sss's; the emission seen there stays ours, as everywhere (the
         * G-buffer's estimate counts every emitter in the pixel's area, whatever surface the
         * primary ray found). */
        if (!seen && c->keep_rest)
            *direct = light_sampler_emitted(&scene->materials[h->material],
                                            vec3_dot(vec3_sub(c->eye[RESTIR_CURRENT], h->p), h->ng));
        return;
    }
    if (!pt_primary(c, (struct restir_domain){pixel, RESTIR_CURRENT}, &v, &th.footprint)) return;
    if (!seen && c->keep_rest)
        *direct = light_sampler_emitted(v.m, vec3_dot(vec3_sub(c->eye[RESTIR_CURRENT], v.s.p), v.s.ng));

    const uint32_t m = c->candidates;
    const float inv_m = 1.0f / (float)m;
    const uint32_t seed0 = pt_path_seed(c->seed, c->frame, pixel);
    struct rng sel = rng_make(c->seed, c->frame, pixel, PT_SELECT_STREAM);
    struct reservoir_stream rs;
    reservoir_stream_begin(&rs);
    for (uint32_t i = 0; i < m; i++) {
        /* The first path keeps the seed of a one-candidate frame; the others get seeds of their
         * own (a replay needs only the selected path's seed, stored with the sample). */
        const uint32_t seed = i == 0 ? seed0 : (uint32_t)rng_mix64((uint64_t)seed0 << 32 | i);
        pt_initial_path(&th, v, seed, inv_m, &rs, &sel, out, direct);
    }
    t->cnt->rejected += rs.rejected;
    struct reservoir r = reservoir_stream_finish(&rs);
    out->head.W = r.W;
    out->head.M = 1;  /* one pixel's draw: all its paths' candidates together have confidence 1 */
}

/* ---- the hybrid shift ----------------------------------------------------------------------- */

/* Re-traces the suffix of a BSDF-sampled path from x_k along w_k by replay in `scene` (a shift
 * between frames whose scenes differ): the cached radiance of x_k's suffix, and for k = d-1 the
 * light pdf of the end. False when the replayed suffix does not end on an emitter at x_d. */
static bool pt_suffix(const struct pt_thread *t, const struct scene *scene, const struct pt_vertex *xk, struct vec3 wk,
                      uint32_t seed, uint32_t k, uint32_t d, struct vec3 *rad, float *light_pdf)
{
    const struct pt_ctx *c = t->c;
    struct pt_vertex v = *xk;
    struct vec3 dir = wk, beta = vec3_splat(1.0f);
    bool delta = false;
    float pdf_marg = 0.0f;
    struct sms_track track = sms_track_start();
    pt_track(c, scene, &track, &xk->s, 0);   /* x_k's lobe is rough: the chain starts here */
    for (uint32_t j = k;; j++) {
        struct hit hit;
        bool found = pt_trace(scene, &v, dir, &hit, &t->cnt->rays);
        if (j + 1 == d) {
            struct vec3 Le;
            float lp;
            if (!found) {
                if (!c->keep_rest) return false;
                Le = scene->env_radiance;
                lp = pt_env_pdf_w(scene);
            } else {
                struct pt_vertex nv;
                pt_vertex_from_hit(scene, &v, dir, &hit, &nv);
                if (!pt_keeps_hit(c, scene, &track)) return false;
                float dist2 = vec3_length2(vec3_sub(nv.s.p, v.s.p));
                float cosl = vec3_dot(dir, nv.s.ng);
                Le = light_sampler_emitted(nv.m, -cosl);
                lp = pt_light_pdf_w(scene, nv.s.shape, nv.s.prim, dist2, cosl);
            }
            if (vec3_is_zero(Le)) return false;
            if (j == k) {
                *rad = Le;
                *light_pdf = lp;
            } else {
                *rad = vec3_mul(beta, vec3_scale(Le, pt_mis_bsdf(c, delta, pdf_marg, lp)));
                *light_pdf = 0.0f;
            }
            return true;
        }
        if (!found) return false;
        struct pt_vertex nv;
        pt_vertex_from_hit(scene, &v, dir, &hit, &nv);
        struct pt_step stp;
        if (!pt_bsdf_step(c, &nv, seed, j + 1, &stp)) return false;
        pt_track(c, scene, &track, &nv.s, stp.bs.flags);
        beta = vec3_mul(beta, stp.factor);
        delta = (stp.bs.flags & BSDF_DELTA) != 0;
        pdf_marg = stp.pdf_marg;
        dir = stp.dir;
        v = nv;
    }
}

static void pt_shift_impl(const struct pt_ctx *c, struct restir_counters *cnt, const struct pt_sample *x,
                          struct restir_domain from, struct restir_domain to, struct pt_sample *y, float *target,
                          float *jacobian)
{
    *target = 0.0f;
    *jacobian = 0.0f;
    *y = *x;
    const uint32_t d = pt_length(x), k = pt_rc(x);
    const bool nee = pt_is_nee(x);
    const struct scene *scene = c->scene[to.frame], *scene_from = c->scene[from.frame];
    const bool retrace = scene != scene_from;
    /* A shift between scenes re-traces a cached suffix; an NEE end inside it has no stored point
     * (in both directions alike, so the mapping stays a bijection on what it accepts). */
    if (retrace && nee && k > 0 && k < d) return;
    struct ray_counters *rays = &cnt->rays;
    struct pt_thread t = {.c = c, .cnt = cnt};
    struct pt_vertex v;
    if (!pt_primary(c, to, &v, &t.footprint)) return;
    const uint32_t seed = x->seed;
    const uint32_t last = k ? k - 1 : d - 1;  /* the last vertex random replay reaches */
    struct vec3 beta = vec3_splat(1.0f);
    struct pt_segment seg = {0};
    struct sms_track track = sms_track_start();

    /* Random replay of y_1 .. y_last: none of its pairs may be connectable (invertibility). */
    for (uint32_t j = 1; j < last; j++) {
        struct pt_step stp;
        if (!pt_bsdf_step(c, &v, seed, j, &stp)) return;
        pt_track(c, scene, &track, &v.s, stp.bs.flags);
        if (pt_connectable(&t, j, &seg, false, stp.rough, stp.pdf_marg)) return;
        beta = vec3_mul(beta, stp.factor);
        struct hit hit;
        if (!pt_trace(scene, &v, stp.dir, &hit, rays)) return;
        struct pt_vertex nv;
        pt_vertex_from_hit(scene, &v, stp.dir, &hit, &nv);
        pt_segment_geo(c, &v, stp.bs.lobe, nv.s.p, nv.s.ng, &seg);
        v = nv;
    }

    struct vec3 F;
    float J = 1.0f;
    if (k == 0 && !nee) {
        /* Pure replay to an emitter. */
        struct pt_step stp;
        if (!pt_bsdf_step(c, &v, seed, last, &stp)) return;
        if (pt_connectable(&t, last, &seg, false, stp.rough, stp.pdf_marg)) return;
        pt_track(c, scene, &track, &v.s, stp.bs.flags);
        const bool delta = (stp.bs.flags & BSDF_DELTA) != 0;
        struct hit hit;
        struct vec3 end;
        if (!pt_trace(scene, &v, stp.dir, &hit, rays)) {
            if (!c->keep_rest) return;
            end = vec3_scale(scene->env_radiance, pt_mis_bsdf(c, delta, stp.pdf_marg, pt_env_pdf_w(scene)));
        } else {
            struct pt_vertex nv;
            pt_vertex_from_hit(scene, &v, stp.dir, &hit, &nv);
            float dist2 = vec3_length2(vec3_sub(nv.s.p, v.s.p));
            struct pt_segment nseg;
            pt_segment_geo(c, &v, stp.bs.lobe, nv.s.p, nv.s.ng, &nseg);
            if (pt_connectable(&t, d, &nseg, true, false, 0.0f)) return;
            if (!pt_keeps_hit(c, scene, &track)) return;
            struct vec3 Le = light_sampler_emitted(nv.m, -vec3_dot(stp.dir, nv.s.ng));
            float lp = pt_light_pdf_w(scene, nv.s.shape, nv.s.prim, dist2, vec3_dot(stp.dir, nv.s.ng));
            end = vec3_scale(Le, pt_mis_bsdf(c, delta, stp.pdf_marg, lp));
        }
        F = vec3_mul(beta, vec3_mul(stp.factor, end));
    } else if (nee && (k == 0 || k == d)) {
        /* NEE from y_{d-1} to the stored light point: reconnection (k = d) or, with k = 0, the
         * replay of the light sample's coordinates (the same point on the same emitter). */
        if (!(material_flags(v.m) & (BSDF_DIFFUSE | BSDF_GLOSSY)) || c->nee_m == 0) return;
        struct vec3 wi_world, Le, light_p = {0}, light_ng = {0};
        float dist, p1, pdf_a = 0.0f;
        struct pt_segment lseg = {0};
        if (x->rc_prim == PT_ENV_PRIM) {
            wi_world = surface_oct_decode(x->wk_u, x->wk_v);
            dist = INFINITY;
            p1 = pt_env_pdf_w(scene);
            Le = scene->env_radiance;
            J = p1 / x->rc_pdf;
            y->rc_pdf = p1;
        } else {
            uint32_t shape, prim;
            pt_prim_decode(c->st, x->rc_prim, &shape, &prim);
            pt_light_point(scene, shape, prim, x->rc_b1, x->rc_b2, &light_p, &light_ng);
            struct vec3 dv = vec3_sub(light_p, v.s.p);
            float d2 = vec3_length2(dv);
            if (!(d2 > 0.0f)) return;
            dist = sqrtf(d2);
            wi_world = vec3_scale(dv, 1.0f / dist);
            float cosl = vec3_dot(wi_world, light_ng);
            Le = light_sampler_emitted(&scene->materials[scene->shapes[shape].material], -cosl);
            pdf_a = light_sampler_pdf_a(scene->lights, shape, prim);
            p1 = sampling_area_to_solid_angle(pdf_a, d2, cosl);
            lseg.dist2 = d2;
            lseg.cos_end = fabsf(cosl);
            J = pdf_a * surface_area_ratio(scene_from, scene, shape, prim, x->rc_b1, x->rc_b2) / x->rc_pdf;
            y->rc_pdf = pdf_a;
        }
        if (vec3_is_zero(Le) || !(p1 > 0.0f)) return;
        struct vec3 wi = frame_to_local(&v.s.frame, wi_world);
        if (!(vec3_dot(wi_world, v.s.ng) * wi.z > 0.0f)) return;
        float p2 = material_pdf(v.m, v.wo, wi);
        bool rough = pt_rough_nee(c, v.m, p2);
        if (pt_connectable(&t, d - 1, &seg, false, rough, p2)) return;
        lseg.pdf_marg = p2;
        lseg.rough = rough;
        bool end_connectable = x->rc_prim != PT_ENV_PRIM && pt_connectable(&t, d, &lseg, true, false, 0.0f);
        if (end_connectable != (k == d)) return;
        if (x->rc_prim == PT_ENV_PRIM ? !pt_sees_env(scene, &v, wi_world, rays)
                                      : !pt_visible_points(scene, v.s.p, v.s.ng, light_p, light_ng, rays))
            return;
        struct vec3 f_cos = vec3_scale(material_eval(v.m, v.wo, wi, TRANSPORT_RADIANCE), fabsf(wi.z));
        F = vec3_mul(beta, vec3_scale(vec3_mul(f_cos, Le), pt_balance((float)c->nee_m * p1, p2) / p1));
    } else {
        /* Reconnection y_{k-1} -> x_k through the stored lobe l_{k-1}. */
        uint32_t shape, prim;
        pt_prim_decode(c->st, x->rc_prim, &shape, &prim);
        struct pt_vertex xk;
        surface_at(scene, shape, prim, x->rc_b1, x->rc_b2, &xk.s);
        xk.m = &scene->materials[xk.s.material];
        xk.b1 = x->rc_b1, xk.b2 = x->rc_b2;
        struct vec3 dv = vec3_sub(xk.s.p, v.s.p);
        float d2 = vec3_length2(dv);
        if (!(d2 > 0.0f)) return;
        float dist = sqrtf(d2);
        struct vec3 w1 = vec3_scale(dv, 1.0f / dist);
        struct vec3 wi = frame_to_local(&v.s.frame, w1);
        if (!(vec3_dot(w1, v.s.ng) * wi.z > 0.0f)) return;
        const int l1 = pt_lobe_prev(x);
        struct vec3 f1;
        float p_l1;
        if (!pt_lobe_at(v.m, l1, v.wo, wi, &f1, &p_l1)) return;
        float marg1 = pt_marginal(v.m, p_l1, v.wo, wi);
        bool rough1 = pt_rough_lobe(c, v.m, l1, marg1);
        if (pt_connectable(&t, k - 1, &seg, false, rough1, marg1)) return;
        struct pt_segment kseg = {.pdf_lobe = p_l1, .pdf_marg = marg1, .rough = rough1, .lobe = l1, .dist2 = d2,
                                  .cos_end = fabsf(vec3_dot(w1, xk.s.ng)), .cos_start = fabsf(vec3_dot(w1, v.s.ng))};
        const float A = p_l1 * kseg.cos_end / d2;   /* area density of x_k from y_{k-1} */
        struct vec3 first = vec3_scale(f1, fabsf(wi.z) / p_l1);
        struct vec3 end;
        float B = 1.0f;
        if (k == d) {
            /* x_k is the emitter a BSDF sample hit. */
            if (!pt_connectable(&t, k, &kseg, true, false, 0.0f)) return;
            struct vec3 Le = light_sampler_emitted(xk.m, -vec3_dot(w1, xk.s.ng));
            if (vec3_is_zero(Le)) return;
            float lp = pt_light_pdf_w(scene, shape, prim, d2, kseg.cos_end);
            end = vec3_scale(Le, pt_mis_bsdf(c, false, marg1, lp));
        } else {
            /* x_k scatters towards w_k with new w_o. */
            xk.wo = frame_to_local(&xk.s.frame, vec3_neg(w1));
            struct vec3 wk_world = surface_oct_decode(x->wk_u, x->wk_v);
            struct vec3 wk = frame_to_local(&xk.s.frame, wk_world);
            if (!(vec3_dot(wk_world, xk.s.ng) * wk.z > 0.0f)) return;
            struct vec3 rad = vec3_make(x->rad[0], x->rad[1], x->rad[2]);
            float light_pdf = x->light_pdf;
            if (nee && k == d - 1) {
                float p2 = material_pdf(xk.m, xk.wo, wk);
                if (!pt_connectable(&t, k, &kseg, false, pt_rough_nee(c, xk.m, p2), p2)) return;
                struct vec3 f = material_eval(xk.m, xk.wo, wk, TRANSPORT_RADIANCE);
                end = vec3_scale(vec3_mul(f, rad), fabsf(wk.z) * pt_balance((float)c->nee_m * light_pdf, p2) / light_pdf);
            } else {
                const int lk = pt_lobe_rc(x);
                struct vec3 fk;
                float p_lk;
                if (!pt_lobe_at(xk.m, lk, xk.wo, wk, &fk, &p_lk)) return;
                float marg_k = pt_marginal(xk.m, p_lk, xk.wo, wk);
                if (!pt_connectable(&t, k, &kseg, false, pt_rough_lobe(c, xk.m, lk, marg_k), marg_k)) return;
                if (retrace && !pt_suffix(&t, scene, &xk, wk_world, seed, k, d, &rad, &light_pdf)) return;
                struct vec3 fac = vec3_scale(fk, fabsf(wk.z) / p_lk);
                end = vec3_mul(fac, k == d - 1 ? vec3_scale(rad, pt_mis_bsdf(c, false, marg_k, light_pdf)) : rad);
                B = p_lk;
            }
            y->rad[0] = rad.x, y->rad[1] = rad.y, y->rad[2] = rad.z;
            y->light_pdf = light_pdf;
        }
        if (!pt_visible_points(scene, v.s.p, v.s.ng, xk.s.p, xk.s.ng, rays)) return;
        F = vec3_mul(beta, vec3_mul(first, end));
        y->rc_pdf = A * B;
        J = A * B * surface_area_ratio(scene_from, scene, shape, prim, x->rc_b1, x->rc_b2) / x->rc_pdf;
    }

    float tgt = vec3_luminance(F);
    if (!(tgt > 0.0f) || !isfinite(tgt) || !(J > 0.0f) || !isfinite(J)) return;
    y->F[0] = F.x, y->F[1] = F.y, y->F[2] = F.z;
    *target = tgt;
    *jacobian = J;
}

static struct vec3 pt_value(const void *ctx, const void *elem)
{
    (void)ctx;
    const struct pt_sample *s = elem;
    return vec3_make(s->F[0], s->F[1], s->F[2]);
}

static float pt_target(const void *ctx, const void *elem)
{
    (void)ctx;
    const struct pt_sample *s = elem;
    return vec3_luminance(vec3_make(s->F[0], s->F[1], s->F[2]));
}

static void pt_shift(const void *ctx, const void *src, struct restir_domain from, struct restir_domain to, void *dst,
                     float *target, float *jacobian, struct restir_counters *cnt)
{
    struct pt_sample y;
    pt_shift_impl(ctx, cnt, src, from, to, dst ? (struct pt_sample *)dst : &y, target, jacobian);
}

/* From the G-buffer surface, which a shift into the domain reads next. */
static bool pt_domain_valid(const void *ctx, struct restir_domain d)
{
    const struct pt_ctx *c = ctx;
    const struct gbuffer_surface *h = &c->gbuf[d.frame]->surf[d.pixel];
    return h->material != GBUFFER_NO_HIT && !pt_left_out(c, c->scene[d.frame], h);
}

/* The samples whose history confidence restir_pt_params.temporal_cap_replay caps: those without a
 * reconnection vertex. The shift keeps k (pt_shift_impl copies it), so this class is what
 * restir_ops.capped_low asks for. */
static bool pt_replay_only(const void *ctx, const void *elem)
{
    (void)ctx;
    return pt_rc(elem) == 0;
}

const struct restir_ops restir_pt_ops = {
    .stride = sizeof(struct pt_sample),
    .target = pt_target,
    .shift = pt_shift,
    .domain_valid = pt_domain_valid,
    .value = pt_value,
    .capped_low = pt_replay_only,
};

void restir_pt_info(const void *elem, struct restir_pt_info *out)
{
    const struct pt_sample *s = elem;
    out->length = pt_length(s);
    out->rc = pt_rc(s);
    out->nee = pt_is_nee(s);
    out->F = vec3_make(s->F[0], s->F[1], s->F[2]);
}

/* ---- the frame ------------------------------------------------------------------------------ */

static bool pt_uses_pairs(const struct restir_pt_params *p)
{
    return restir_pairs_needed(p->paired_spatial, p->spatial_neighbors);
}

bool restir_pt_init(struct restir_pt_state *st, const struct scene *scene, const struct restir_pt_params *params,
                    uint32_t width, uint32_t height, struct err *err)
{
    memset(st, 0, sizeof *st);
    if (scene_has_translucent(scene) && !params->opaque_primary)
        return err_set(err, ERR_INVALID, "/method",
                       "restir_pt does not sample subsurface scattering (the scene has translucent materials)");
    st->nee_by_scene = restir_pt_nee_by_scene(scene);
    st->candidates_by_scene = restir_pt_candidates_by_scene(scene, params->roughness_min);
    st->shape_count = scene->shape_count;
    st->prim_first = malloc(((size_t)scene->shape_count + 1) * sizeof *st->prim_first);
    if (!st->prim_first) return err_set(err, ERR_NOMEM, NULL, "out of memory for a restir_pt session");
    uint64_t total = 0;
    for (uint32_t i = 0; i < scene->shape_count; i++) {
        st->prim_first[i] = (uint32_t)total;
        total += scene->shapes[i].kind == SHAPE_MESH ? scene->shapes[i].triangle_count : 1;
    }
    st->prim_first[scene->shape_count] = (uint32_t)total;
    if (total >= PT_ENV_PRIM) {
        restir_pt_destroy(st);
        return err_set(err, ERR_LIMIT, NULL, "the scene has %llu primitives; restir_pt stores at most 2^32 - 1",
                       (unsigned long long)total);
    }
    if (!restir_session_init(&st->rs, width, height, 1, sizeof(struct pt_sample), true, pt_uses_pairs(params), err) ||
        (pt_keeps_emission(params, scene) && !restir_session_keep_emission(&st->rs, err))) {
        restir_pt_destroy(st);
        return false;
    }
    return true;
}

void restir_pt_destroy(struct restir_pt_state *st)
{
    restir_session_destroy(&st->rs);
    free(st->prim_first);
    memset(st, 0, sizeof *st);
}

uint64_t restir_pt_bytes_planned(const struct restir_pt_params *params, uint32_t width, uint32_t height,
                                 const struct scene *scene)
{
    const uint32_t shape_count = scene->shape_count;
    uint64_t pixels = (uint64_t)width * height;
    return 2 * pixels * (sizeof(struct pt_sample) + sizeof(struct gbuffer_pixel) + sizeof(struct gbuffer_surface)) +
           ((uint64_t)shape_count + 1) * sizeof(uint32_t) +
           (pt_uses_pairs(params) ? restir_pair_scratch_bytes(width, height) : 0) +
           (pt_keeps_emission(params, scene) ? (uint64_t)gbuffer_emission_bytes_planned(width, height) : 0);
}

struct pt_pass {
    struct restir_frame fr;   /* first: the driver's rows reach it through the pass */
    const struct pt_ctx *c;
    struct restir_pass_stats local;   /* the counters of a frame whose caller keeps none */
};
RESTIR_FRAME_FIRST(struct pt_pass);

/* Initial pass: one path per pixel into the working buffer; the image gets what the reservoir
 * does not carry. */
static void pt_initial_rows(void *ctx, uint32_t job, unsigned worker)
{
    struct pt_pass *pp = ctx;
    const struct pt_ctx *c = pp->c;
    struct restir_counters cnt = {0};  /* job-local: see restir_counters_add */
    struct pt_thread t = {.c = c, .cnt = &cnt};
    uint32_t w = pp->fr.s->width, y0, y1;
    restir_frame_rows(&pp->fr, job, &y0, &y1);
    struct pt_sample *res = (struct pt_sample *)pp->fr.s->res[0];
    for (uint32_t y = y0; y < y1; y++) {
        for (uint32_t x = 0; x < w; x++) {
            uint32_t pixel = y * w + x;
            struct vec3 direct;
            pt_initial_pixel(&t, pixel, &res[pixel], &direct);
            if (pp->fr.out) pp->fr.out->pixels[pixel] = direct;
        }
    }
    restir_counters_add(&pp->fr.counters[worker], &cnt);
}

/* Shade pass: F(Y) W of the final reservoir added to the image. */
static void pt_shade_rows(void *ctx, uint32_t job, unsigned worker)
{
    struct pt_pass *pp = ctx;
    uint32_t w = pp->fr.s->width, y0, y1;
    restir_frame_rows(&pp->fr, job, &y0, &y1);
    const struct pt_sample *res = (const struct pt_sample *)pp->fr.s->res[1];
    for (uint32_t y = y0; y < y1; y++) {
        for (uint32_t x = 0; x < w; x++) {
            uint32_t pixel = y * w + x;
            const struct pt_sample *s = &res[pixel];
            struct vec3 L = pp->fr.out->pixels[pixel];
            /* Unless the last spatial pass already added its expected contribution. */
            if (!pp->fr.estimated && s->head.W > 0.0f)
                L = vec3_add(L, vec3_scale(vec3_make(s->F[0], s->F[1], s->F[2]), s->head.W));
            restir_frame_store(&pp->fr, worker, pixel, L);
        }
    }
}

void restir_pt_bind(struct restir_pt_state *st, const struct restir_pt_params *params, const struct method_frame *f,
                    void *ctx)
{
    struct pt_ctx *c = ctx;
    memset(c, 0, sizeof *c);
    c->p = params;
    c->st = st;
    restir_frame_domains(&st->rs, f, c->scene, c->eye, c->gbuf);
    c->seed = f->seed;
    c->frame = f->frame;
    c->nee_m = params->nee_candidates == RESTIR_PT_NEE_BY_SCENE ? st->nee_by_scene : params->nee_candidates;
    c->candidates = params->candidates == RESTIR_PT_CANDIDATES_BY_SCENE ? st->candidates_by_scene : params->candidates;
    struct vec3 ext = vec3_sub(f->scene->bounds_max, f->scene->bounds_min);
    float radius = 0.5f * vec3_length(ext);
    c->near_dist2 = (params->near_distance * radius) * (params->near_distance * radius);
    c->pdf_max = 1.0f / sqrtf(params->roughness_min);
    c->keep_owned = params->subset != PT_SUBSET_REST;
    c->keep_rest = params->subset != PT_SUBSET_CAUSTIC;
    c->tracked = params->subset != PT_SUBSET_ALL;
}

bool restir_pt_render(struct restir_pt_state *st, const struct restir_pt_params *params,
                      const struct method_frame *f, struct image *out, struct restir_pass_stats *stats,
                      struct err *err)
{
    struct pt_ctx c;
    struct pt_pass pp;   /* on the stack (restir_frame): a frame allocates nothing */
    if (!restir_frame_open(&pp.fr, sizeof pp, &st->rs, f, out, params->temporal, stats, &pp.local, sizeof pp.local,
                           err) ||
        !restir_pt_params_valid(params, err))
        return false;
    if (f->scene->shape_count != st->shape_count)
        return err_set(err, ERR_INVALID, NULL, "the scene has %u shapes, the session %u", f->scene->shape_count,
                       st->shape_count);
    if (!restir_frame_gbuffer(&pp.fr, params->jitter_walk, pt_uses_pairs(params), params->history_check,
                              params->emission_samples, err)) return false;
    restir_pt_bind(st, params, f, &c);
    pp.c = &c;
    if (!restir_frame_initial(&pp.fr, pt_initial_rows, err)) return false;
    if (!out) return true;   /* restir_pt_initial_only */
    struct restir_reuse *r = restir_frame_reuse(&pp.fr, &restir_pt_ops, &c, 0, params->temporal_cap,
                                                params->spatial_neighbors,
                                                params->spatial_radius > 0.0f ? params->spatial_radius
                                                                              : restir_radius_auto(st->rs.width, st->rs.height),
                                                params->paired_spatial);
    r->temporal_cap_low = params->temporal_cap_replay;
    r->min_normal_cos = params->reject_normal_cos;
    r->max_depth_rel = params->reject_depth;
    if (!restir_frame_temporal(&pp.fr, err)) return false;
    /* Spatial rounds ping-pong between the two buffers and end in res[1], the history. */
    const uint32_t rounds = params->spatial_neighbors > 0 ? params->spatial_rounds : 0;
    for (uint32_t round = 0; round < rounds; round++) {
        r->frame = f->frame * 8u + round;  /* a distinct neighbour stream per round */
        const bool last = round + 1 == rounds;
        if (!restir_frame_spatial(&pp.fr, params->expected_shading && last, last, err)) return false;
    }
    if (params->spatial_neighbors == 0) restir_session_swap(&st->rs);
    restir_frame_reused(&pp.fr);
    return restir_frame_shade(&pp.fr, pt_shade_rows, err);
}

bool restir_pt_render_rest(struct restir_pt_state *st, const struct restir_pt_params *params,
                           const struct method_frame *f, struct image *out, struct restir_pass_stats *into,
                           struct err *err)
{
    struct restir_pass_stats s = {0};
    if (!restir_pt_render(st, params, f, out, &s, err)) return false;
    into->rays_intersect += s.rays_intersect;
    into->rays_occluded += s.rays_occluded;
    into->nonfinite += s.nonfinite;
    return true;
}

bool restir_pt_initial_only(struct restir_pt_state *st, const struct restir_pt_params *params,
                            const struct method_frame *f, struct err *err)
{
    return restir_pt_render(st, params, f, NULL, NULL, err);
}
