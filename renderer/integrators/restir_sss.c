/* restir_sss.c — method `restir_sss` (see restir_sss.h): candidate generation by BSSRDF
 * importance sampling, the reconnection / delayed reconnection / hybrid shifts, and the frame.
 * The reuse passes are restir.c's; the rest of the image is reference_pt_radiance's or restir_pt's.
 * Refs: [ReSTIR SSS §3.1] (eq. 10, Algorithm 3), §3.2 (eq. 11), §4.1, §5.1, §5.3;
 * docs/methods.md (restir_sss). */
#include "integrators/restir_sss.h"

#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "material/bssrdf.h"
#include "scene/camera.h"
#include "scene/light_sampler.h"
#include "core/parallel.h"
#include "integrators/reference_pt.h"
#include "reuse/reservoir.h"
#include "core/rng.h"
#include "core/sampling.h"
#include "scene/surface.h"

#define SSS_STREAM 0x737373ull        /* candidate generation */
#define SSS_PT_STREAM 0x737370ull     /* the pt path of the rest, and the paths of indirect samples */
#define SSS_ENV_SHAPE UINT32_MAX      /* x3 is a direction to the environment */
#define SSS_HIT_UNKNOWN 15u           /* sequential shortcut: the index was not found (§4.3) */
#define SSS_PICK_STREAM 0x737369ull   /* the shortcut's random pick of an unknown index */
#define SSS_LAYER_STREAM 0x73736cull  /* per_channel: the selections of layers 1 and 2 */

/* The reservoir element (Algorithm 3): x2 and x3 as point codes, the technique, the random
 * numbers of the disk point and the intersection index, and the path's contribution F in its own
 * pixel (f times the technique's balance weight, RGB); its target is sss_target_of(F) for its
 * reservoir's channel.
 *
 * x3 is a light point (direct light at the entry point x2) or, for an indirect sample, the first
 * surface the path meets after x2, with L3 the radiance the rest of the path brings from it
 * towards x2 (its own emission left out: that is the direct samples' light). The paper resamples
 * direct light only and names this extension ([ReSTIR SSS §5.3]: a reconnection vertex and its
 * incoming radiance, as ReSTIR PT stores): the reconnection shift keeps x2 and x3, so the
 * direction x2 -> x3 and L3 stay exact; the delayed shift moves x2, and L3 still holds where x3
 * is Lambertian (its outgoing radiance is the same in every direction of the side it leaves).
 * Without it the indirect light at translucent pixels came from one path a frame, which on the
 * scene `translucent` was 3/4 of their error (docs/benchmarks.md, "restir_sss: indirect light
 * in the reservoirs"). */
struct sss_sample {
    /* bits: axis (2) | channel (2) << 2 | hit index (4) << 4 | indirect << 8 | x3 seen from its
     * back << 9 */
    struct restir_head head;
    uint32_t x2_shape, x2_prim;
    float x2_b1, x2_b2;
    uint32_t x3_shape, x3_prim;
    float x3_b1, x3_b2;
    float u_radius, u_angle;
    float F[3];
    float L3[3];   /* indirect samples: the radiance from x3 towards x2; else 0 */
};
_Static_assert(sizeof(struct sss_sample) == RESTIR_SSS_RESERVOIR_BYTES, "reservoir element size");

/* The target p̂ of an RGB contribution F ([ReSTIR SSS §3]: p̂ = f; an RGB f needs a scalar):
 * F_channel for a reservoir of the per_channel target, else the luminance. With one reservoir each
 * channel of the shaded pixel carries F_c / p̂, so a strongly coloured sample is amplified in its
 * channel: luminance weighs blue by 0.0722. The largest channel bounds every F_c / p̂ by 1 and
 * lowered the RMSE on the translucent region (hybrid 0.0695 -> 0.0642 after 16 frames), but the
 * first frame after a camera teleport got worse (MAPE 0.335 against a fresh session's 0.222,
 * tests/test_stability.py::test_camera_teleport; 0.189 with luminance). A likely cause, not
 * measured: the largest channel weighs far entry points, whose F is red only, up to 4.7x more
 * than luminance does, and the old view's history reaches the new one by reconnection from far
 * away. Luminance it stays for one reservoir per pixel; per_channel instead keeps one per channel.
 * (The Euclidean norm, which minimises the summed variance of the channels of one sample, did
 * the same as the largest channel: RMSE 0.0451 -> 0.0399 at max_depth 1, teleport 0.346.) */
static inline float sss_target_of(int channel, struct vec3 F)
{
    return channel < 0 ? vec3_luminance(F) : vec3_comp(F, channel);
}

static inline int sss_axis(const struct sss_sample *s) { return s->head.bits & 3u; }
static inline int sss_channel(const struct sss_sample *s) { return (s->head.bits >> 2) & 3u; }
static inline uint32_t sss_hit(const struct sss_sample *s) { return (s->head.bits >> 4) & 15u; }
static inline bool sss_indirect(const struct sss_sample *s) { return (s->head.bits >> 8) & 1u; }
static inline bool sss_x3_back(const struct sss_sample *s) { return (s->head.bits >> 9) & 1u; }
static inline uint16_t sss_bits(int axis, int channel, uint32_t hit)
{
    return (uint16_t)((unsigned)axis | (unsigned)channel << 2 | hit << 4);
}
/* The technique and hit index replaced, the kind of x3 kept. */
static inline uint16_t sss_bits_of(const struct sss_sample *s, int axis, int channel, uint32_t hit)
{
    return (uint16_t)(sss_bits(axis, channel, hit) | (s->head.bits & 0x300u));
}

struct restir_sss_params restir_sss_defaults(void)
{
    return (struct restir_sss_params){.shift = RESTIR_SSS_HYBRID, .candidates = 1, .temporal = true,
                                      .temporal_cap = 20, .spatial_neighbors = 4, .spatial_radius = 0.0f,
                                      .kappa_orientation = 0.5f, .max_depth = 64, .rr_depth = 3,
                                      .paired_spatial = true, .expected_shading = true,
                                      .rest = RESTIR_SSS_REST_BY_SCENE, .rest_samples = 1};
}

/* by_scene, measured on the scene `translucent` at 256x256 against pt at equal time
 * (docs/benchmarks.md, "restir_sss: indirect light in the reservoirs, and who renders the rest"):
 * in real time (temporal reuse on) restir_pt's rest took the frame's MAPE from 0.71x pt's to
 * 0.36x; converging (temporal off) its converge profile costs 2.3x the pt rest's frame, and the
 * accumulated image's relMSE read 1.73x pt's against the pt rest's 0.93x. */
enum restir_sss_rest restir_sss_rest_of(const struct restir_sss_params *p)
{
    if (p->rest != RESTIR_SSS_REST_BY_SCENE) return p->rest;
    return p->temporal && p->max_depth >= 1 && p->max_depth <= RESTIR_PT_MAX_DEPTH ? RESTIR_SSS_REST_RESTIR_PT
                                                                                    : RESTIR_SSS_REST_PT;
}

struct restir_pt_params restir_sss_rest_params(const struct restir_sss_params *p)
{
    struct restir_pt_params rp = restir_pt_rest_params(!p->temporal, p->max_depth);
    rp.opaque_primary = true;
    return rp;
}

static const char *const sss_shift_names[] = {"reconnection", "delayed", "hybrid", "sequential"};

const char *restir_sss_shift_name(enum restir_sss_shift s)
{
    return (unsigned)s < 4u ? sss_shift_names[s] : "?";
}

uint32_t restir_sss_layers(const struct restir_sss_params *p)
{
    return p->target == RESTIR_SSS_TARGET_PER_CHANNEL ? 3u : 1u;
}

bool restir_sss_params_valid(const struct restir_sss_params *p, struct err *err)
{
    if ((unsigned)p->shift > RESTIR_SSS_SEQUENTIAL)
        return err_set(err, ERR_INVALID, "/params/shift", "unknown shift");
    if ((unsigned)p->target > RESTIR_SSS_TARGET_PER_CHANNEL)
        return err_set(err, ERR_INVALID, "/params/target", "unknown target");
    if (p->candidates < 1 || p->candidates > 32)
        return err_set(err, ERR_INVALID, "/params/candidates", "must be in [1, 32], got %u", p->candidates);
    if (p->temporal_cap < 1 || p->temporal_cap > 1000)
        return err_set(err, ERR_INVALID, "/params/temporal_cap", "must be in [1, 1000], got %u", p->temporal_cap);
    if (p->spatial_neighbors > 32)
        return err_set(err, ERR_INVALID, "/params/spatial_neighbors", "must be in [0, 32], got %u", p->spatial_neighbors);
    if (!(p->spatial_radius >= 0.0f && p->spatial_radius <= 256.0f))
        return err_set(err, ERR_INVALID, "/params/spatial_radius", "must be in [0, 256] pixels (0 = automatic)");
    if (p->shift == RESTIR_SSS_SEQUENTIAL && p->spatial_neighbors % 2 != 0)
        return err_set(err, ERR_INVALID, "/params/spatial_neighbors",
                       "the sequential shift splits the neighbours over two passes: must be even, got %u",
                       p->spatial_neighbors);
    if (p->index_shortcut && p->shift != RESTIR_SSS_SEQUENTIAL)
        return err_set(err, ERR_INVALID, "/params/index_shortcut", "only the sequential shift has an index shortcut");
    if (!(p->kappa_orientation >= -1.0f && p->kappa_orientation <= 1.0f))
        return err_set(err, ERR_INVALID, "/params/kappa_orientation", "must be in [-1, 1]");
    if (p->max_depth > 1024) return err_set(err, ERR_INVALID, "/params/max_depth", "must be at most 1024");
    if ((unsigned)p->rest > RESTIR_SSS_REST_RESTIR_PT) return err_set(err, ERR_INVALID, "/params/rest", "unknown rest");
    if (p->rest_samples < 1 || p->rest_samples > RESTIR_SSS_MAX_REST_SAMPLES)
        return err_set(err, ERR_INVALID, "/params/rest_samples", "must be in [1, %u], got %u",
                       RESTIR_SSS_MAX_REST_SAMPLES, p->rest_samples);
    if (p->rest == RESTIR_SSS_REST_RESTIR_PT && (p->max_depth < 1 || p->max_depth > RESTIR_PT_MAX_DEPTH))
        return err_set(err, ERR_INVALID, "/params/max_depth", "must be in 1..%u with rest restir_pt, got %u",
                       RESTIR_PT_MAX_DEPTH, p->max_depth);
    return true;
}

/* ---- per-frame context ---------------------------------------------------------------------- */

struct sss_ctx {
    const struct restir_sss_params *p;
    const struct scene *scene[2];   /* [RESTIR_CURRENT], [RESTIR_PREVIOUS] */
    struct vec3 eye[2];
    const struct gbuffer *gbuf[2];
    uint64_t seed;
    uint32_t frame;
    enum restir_sss_shift pass_shift;   /* the shift of the pass running (sequential: per pass) */
    int channel;                        /* the reservoirs' target: -1 luminance, else F_channel */
    bool moved;                         /* the previous frame's scene differs (scene_moved) */
    const struct pt_params *pt;         /* the paths of indirect samples (NULL: none are drawn) */
};
_Static_assert(sizeof(struct sss_ctx) <= RESTIR_SSS_CTX_BYTES, "context fits the test buffer");

/* The primary vertex x1 of a domain: on a translucent material, seen from its front. */
struct sss_x1 {
    struct surface s;
    const struct material *m;
    float cos_o;   /* shading cosine towards the eye */
};

/* The primary vertex x1 of a domain: the surface its frame's G-buffer pass built (read, not
 * rebuilt from the point code, by every shift and validity test of the frame), when it is
 * translucent and seen from its front. */
static bool sss_primary(const struct sss_ctx *c, struct restir_domain d, struct sss_x1 *x)
{
    const struct gbuffer_surface *h = &c->gbuf[d.frame]->surf[d.pixel];
    if (h->material == GBUFFER_NO_HIT) return false;
    const struct scene *scene = c->scene[d.frame];
    const struct material *m = &scene->materials[h->material];
    if (m->kind != MATERIAL_TRANSLUCENT) return false;
    struct vec3 wo = vec3_normalize(vec3_sub(c->eye[d.frame], h->p));
    float cos_o = vec3_dot(wo, h->ns);
    if (!(cos_o > 0.0f && vec3_dot(wo, h->ng) > 0.0f)) return false;
    const struct gbuffer_pixel *g = &c->gbuf[d.frame]->px[d.pixel];
    x->s.p = h->p, x->s.ng = h->ng, x->s.ns = h->ns;
    x->s.frame = frame_from_normal(h->ns);
    x->s.shape = g->shape, x->s.prim = g->prim, x->s.material = h->material;
    x->m = m;
    x->cos_o = cos_o;
    return true;
}

/* The end x3 as rebuilt in a scene: a light point (with normal) or a direction, or an indirect
 * sample's surface point. */
struct sss_x3 {
    bool is_env;
    struct vec3 p, n, dir;
    struct vec3 Le_scale;   /* emitted radiance of the emitter's material (front side); indirect: L3 */
    bool two_sided;
    bool indirect, back;    /* an indirect sample's x3, and L3 leaving it on the side -n */
    bool lambertian;        /* indirect: x3's L3 holds in any direction of its side */
    struct vec3 ns;         /* indirect: x3's shading normal */
};

static bool sss_x3_at(const struct scene *scene, const struct sss_sample *s, struct sss_x3 *x3)
{
    if (sss_indirect(s)) {
        struct surface h;
        surface_at(scene, s->x3_shape, s->x3_prim, s->x3_b1, s->x3_b2, &h);
        x3->is_env = false;
        x3->p = h.p, x3->n = h.ng, x3->ns = h.ns;
        x3->Le_scale = vec3_make(s->L3[0], s->L3[1], s->L3[2]);
        x3->two_sided = false;
        x3->indirect = true;
        x3->back = sss_x3_back(s);
        x3->lambertian = material_diffuse_path(&scene->materials[h.material]);
        return true;
    }
    x3->indirect = false;
    if (s->x3_shape == SSS_ENV_SHAPE) {
        if (vec3_is_zero(scene->env_radiance)) return false;
        x3->is_env = true;
        x3->dir = surface_oct_decode(s->x3_b1, s->x3_b2);
        x3->Le_scale = scene->env_radiance;
        return true;
    }
    /* The point and its geometric normal only: the emitter's shading frame is never used. */
    surface_point_at(scene, s->x3_shape, s->x3_prim, s->x3_b1, s->x3_b2, &x3->p, &x3->n);
    const struct material *m = &scene->materials[scene->shapes[s->x3_shape].material];
    x3->is_env = false;
    x3->Le_scale = m->emission;
    x3->two_sided = m->two_sided_emission;
    return material_is_emissive(m);
}

/* The contribution f of x0 -> x1 -> x2 -> x3 times the technique's balance weight, in the
 * measure of the candidates (x2: area; x3: area, or solid angle for the environment), and the
 * part of the path pdf that the candidate's resampling weight divides by. Visibility x2 -> x3 is
 * traced when `visibility` is set. Returns zero when the path carries nothing. */
static struct vec3 sss_eval(const struct scene *scene, const struct sss_x1 *x1, const struct surface *x2,
                            const struct sss_x3 *x3, int axis, int channel, bool visibility, float *pdf_mis,
                            struct ray_counters *rc)
{
    const struct material *m = x1->m;
    struct vec3 zero = vec3_splat(0.0f);
    float r = vec3_length(vec3_sub(x2->p, x1->s.p));
    float p_t = 0.0f;
    float p_mis = bssrdf_pdf_a_and(m, x1->s.p, &x1->s.frame, x2->p, x2->ng, axis, channel, &p_t);
    if (pdf_mis) *pdf_mis = p_mis;
    if (!(p_mis > 0.0f) || !(p_t > 0.0f)) return zero;
    struct vec3 wi, Le;
    float geo;
    if (x3->is_env) {
        wi = x3->dir;
        Le = x3->Le_scale;
        geo = 1.0f;
    } else {
        struct vec3 d = vec3_sub(x3->p, x2->p);
        float d2 = vec3_length2(d);
        if (!(d2 > 0.0f)) return zero;
        wi = vec3_scale(d, 1.0f / sqrtf(d2));
        float cos_l = -vec3_dot(wi, x3->n);
        if (x3->indirect) {
            /* L3 leaves x3 on the side it was found from, by both normals (pt's test at x3). */
            float side = x3->back ? -1.0f : 1.0f;
            if (!(side * cos_l > 0.0f) || !(-side * vec3_dot(wi, x3->ns) > 0.0f)) return zero;
        } else if (!(cos_l > 0.0f) && !(x3->two_sided && cos_l < 0.0f)) {
            return zero;
        }
        Le = x3->Le_scale;
        geo = fabsf(cos_l) / d2;
    }
    float cos_i = vec3_dot(wi, x2->ns);
    if (!(cos_i > 0.0f) || !(vec3_dot(wi, x2->ng) > 0.0f)) return zero;
    struct vec3 R = bssrdf_profile(m, r);
    if (vec3_is_zero(R)) return zero;
    if (visibility) {
        struct vec3 org = surface_offset_along(x2->p, x2->ng);
        float tmax = INFINITY;
        if (!x3->is_env) {
            struct vec3 end = surface_offset(x3->p, x3->n, vec3_neg(wi));
            struct vec3 seg = vec3_sub(end, org);
            tmax = vec3_length(seg);
            if (!(tmax > 0.0f)) return zero;
            wi = vec3_scale(seg, 1.0f / tmax);
            tmax *= 1.0f - 1e-4f;
        }
        if (accel_occluded(scene->accel, org, wi, 0.0f, tmax, rc)) return zero;
    }
    float s = bssrdf_transmittance(m, x1->cos_o) * bssrdf_entry_eval(m, cos_i) * cos_i * geo * (p_t / p_mis);
    return vec3_scale(vec3_mul(R, Le), s);
}

/* Hybrid criterion (§4.1): reconnect iff |x2 - x1| >= 2 max(d) or n1 . n2 <= kappa. */
static bool sss_reconnects(const struct sss_ctx *c, const struct sss_x1 *x1, const struct surface *x2,
                           bool x3_fixed)
{
    switch (c->pass_shift) {
    case RESTIR_SSS_RECONNECTION: return true;
    case RESTIR_SSS_DELAYED: return false;
    default: break;
    }
    /* An indirect sample whose x3 is not Lambertian has no delayed shift (sss_sample). */
    if (x3_fixed) return true;
    float kd = 2.0f * vec3_max_comp(x1->m->sss_d);
    return vec3_length(vec3_sub(x2->p, x1->s.p)) >= kd || vec3_dot(x1->s.ns, x2->ns) <= c->p->kappa_orientation;
}

/* ---- candidates ----------------------------------------------------------------------------- */

/* The selection of one candidate by every layer's reservoir (each with its own target). */
struct sss_offer {
    uint32_t layers;
    struct reservoir_stream *rs;
    struct rng *rng, *rng_layers;
    struct sss_sample *const *out;
    float inv_m;
};

static void sss_offer(const struct sss_offer *o, const struct sss_sample *cand, struct vec3 F, double p)
{
    for (uint32_t l = 0; l < o->layers; l++) {
        float target = sss_target_of(o->layers > 1 ? (int)l : -1, F);
        if (!(target > 0.0f)) continue;
        float u = rng_next_float(l == 0 ? o->rng : o->rng_layers);
        if (reservoir_stream_offer(&o->rs[l], (double)target / p * o->inv_m, target, 0.0f, u)) *o->out[l] = *cand;
    }
}

/* The probe's indirect candidate: one of its n hits picked uniformly (as pt's path continues,
 * [ReSTIR SSS §5.3]), a cosine-sampled direction from it through the entry lobe, and the radiance
 * that pt's path would bring back along it (reference_pt_radiance_after_sss). Its pdf: the
 * technique's, 1/n, and the cosine density in x3's area measure. */
static void sss_indirect_candidate(const struct sss_ctx *c, const struct sss_x1 *x1, const struct hit *hits, uint32_t n,
                                   const struct bssrdf_probe *probe, int axis, int channel, float ur, float ua,
                                   float upick, float ud1, float ud2, struct rng *rng_pt, const struct sss_offer *o,
                                   struct ray_counters *rc)
{
    const struct scene *scene = c->scene[RESTIR_CURRENT];
    uint32_t pick = (uint32_t)(upick * (float)n);
    if (pick >= n) pick = n - 1;
    struct surface x2;
    float b1, b2;
    surface_from_hit(scene, &hits[pick], probe->org, probe->dir, &x2);
    surface_point_code(scene, &hits[pick], &x2, &b1, &b2);
    surface_at(scene, hits[pick].shape, hits[pick].prim, b1, b2, &x2);
    struct vec3 wl = sampling_cosine_hemisphere(ud1, ud2);
    if (!(wl.z > 0.0f)) return;
    struct vec3 wi = frame_to_world(&x2.frame, wl);
    if (!(vec3_dot(wi, x2.ng) > 0.0f)) return;
    struct vec3 org = surface_offset_along(x2.p, x2.ng);
    struct hit h3;
    if (!accel_intersect(scene->accel, org, wi, 0.0f, INFINITY, &h3, rc)) return;  /* the environment: direct */
    struct vec3 L3 = reference_pt_radiance_after_sss(scene, c->pt, org, wi, &h3, rng_pt, rc);
    if (vec3_is_zero(L3) || !isfinite(L3.x + L3.y + L3.z)) return;
    struct sss_sample cand;
    memset(&cand, 0, sizeof cand);
    struct surface s3;
    surface_from_hit(scene, &h3, org, wi, &s3);
    cand.x3_shape = h3.shape;
    cand.x3_prim = h3.prim;
    surface_point_code(scene, &h3, &s3, &cand.x3_b1, &cand.x3_b2);
    surface_at(scene, h3.shape, h3.prim, cand.x3_b1, cand.x3_b2, &s3);
    const bool back = vec3_dot(vec3_sub(x2.p, s3.p), s3.ng) < 0.0f;
    cand.head.bits = (uint16_t)(sss_bits(axis, channel, pick) | 1u << 8 | (unsigned)back << 9);
    cand.x2_shape = hits[pick].shape;
    cand.x2_prim = hits[pick].prim;
    cand.x2_b1 = b1;
    cand.x2_b2 = b2;
    cand.u_radius = ur;
    cand.u_angle = ua;
    cand.L3[0] = L3.x, cand.L3[1] = L3.y, cand.L3[2] = L3.z;
    struct sss_x3 x3;
    if (!sss_x3_at(scene, &cand, &x3)) return;
    /* x3 is the ray's first hit: visible (not traced again from the rebuilt points). */
    struct vec3 F = sss_eval(scene, x1, &x2, &x3, axis, channel, false, NULL, rc);
    if (vec3_is_zero(F)) return;
    struct vec3 d = vec3_sub(x3.p, x2.p);
    float d2 = vec3_length2(d);
    struct vec3 w3 = vec3_scale(d, 1.0f / sqrtf(d2));
    double p = (double)(bssrdf_technique_prob(axis, channel) *
                        bssrdf_pdf_technique(x1->m, x1->s.p, &x1->s.frame, axis, channel, x2.p, x2.ng)) /
               (double)n * (double)(vec3_dot(w3, x2.ns) / PI_F) * (double)(fabsf(vec3_dot(w3, x3.n)) / d2);
    if (!(p > 0.0)) return;
    cand.F[0] = F.x, cand.F[1] = F.y, cand.F[2] = F.z;
    sss_offer(o, &cand, F, p);
}

/* The pixel's initial reservoirs, one per layer (out[l]): every layer resamples the same
 * candidates with its own target and its own selection numbers. */
static void sss_initial_pixel(const struct sss_ctx *c, uint32_t pixel, uint32_t layers, struct sss_sample *const *out,
                              struct ray_counters *rc)
{
    for (uint32_t l = 0; l < layers; l++) memset(out[l], 0, sizeof *out[l]);
    struct sss_x1 x1;
    if (!sss_primary(c, (struct restir_domain){pixel, RESTIR_CURRENT}, &x1)) return;
    const struct scene *scene = c->scene[RESTIR_CURRENT];
    struct rng rng = rng_make(c->seed, c->frame, pixel, SSS_STREAM);
    struct rng rng_pt = rng_make(c->seed, c->frame, pixel, SSS_PT_STREAM);
    /* Layers 1 and 2 (per_channel) draw their selections from a stream of their own, so layer 0
     * and a luminance reservoir see the same numbers. */
    struct rng rng_layers = {0, 0};
    if (layers > 1) rng_layers = rng_make(c->seed, c->frame, pixel, SSS_LAYER_STREAM);
    struct reservoir_stream rs[3];
    for (uint32_t l = 0; l < layers; l++) reservoir_stream_begin(&rs[l]);
    const struct sss_offer offer = {.layers = layers, .rs = rs, .rng = &rng, .rng_layers = &rng_layers, .out = out,
                                    .inv_m = 1.0f / (float)c->p->candidates};
    for (uint32_t i = 0; i < c->p->candidates; i++) {
        float ut = rng_next_float(&rng), ur = rng_next_float(&rng), ua = rng_next_float(&rng);
        float ul = rng_next_float(&rng), u1 = rng_next_float(&rng), u2 = rng_next_float(&rng);
        float upick = rng_next_float(&rng), ud1 = rng_next_float(&rng), ud2 = rng_next_float(&rng);
        /* A probe is one candidate (confidence 1) whether or not it finds anything (§3.1). */
        for (uint32_t l = 0; l < layers; l++) reservoir_stream_offer(&rs[l], 0.0, 0.0f, 1.0f, 0.0f);
        int axis, channel;
        bssrdf_pick_technique(ut, &axis, &channel);
        struct bssrdf_probe probe;
        if (!bssrdf_probe_make(x1.m, x1.s.p, &x1.s.frame, axis, channel, ur, ua, &probe)) continue;
        struct hit hits[BSSRDF_MAX_HITS];
        uint32_t n = accel_intersect_shape_all(scene->accel, x1.s.shape, probe.org, probe.dir, 0.0f, probe.tmax, hits,
                                               BSSRDF_MAX_HITS, rc);
        if (n == 0) continue;
        if (c->pt)
            sss_indirect_candidate(c, &x1, hits, n, &probe, axis, channel, ur, ua, upick, ud1, ud2, &rng_pt, &offer,
                                   rc);
        /* One light sample shared by all the probe's hits (§5.2). */
        struct light_sample ls;
        if (!light_sampler_sample(scene->lights, ul, u1, u2, &ls)) continue;
        struct sss_sample cand;
        memset(&cand, 0, sizeof cand);
        cand.u_radius = ur;
        cand.u_angle = ua;
        float pdf_light;
        if (ls.is_env) {
            cand.x3_shape = SSS_ENV_SHAPE;
            surface_oct_encode(ls.dir, &cand.x3_b1, &cand.x3_b2);
            pdf_light = ls.pdf_w;
        } else {
            cand.x3_shape = ls.shape;
            cand.x3_prim = ls.prim;
            if (scene->shapes[ls.shape].kind == SHAPE_MESH) {
                cand.x3_b1 = ls.b1;
                cand.x3_b2 = ls.b2;
            } else {
                const struct shape *sh = &scene->shapes[ls.shape];
                struct vec3 dd = vec3_normalize(
                    vec3_sub(xform_point(accel_shape_to_object(scene->accel, ls.shape), ls.p), sh->center));
                surface_oct_encode(dd, &cand.x3_b1, &cand.x3_b2);
            }
            pdf_light = ls.pdf_a;
        }
        struct sss_x3 x3;
        if (!(pdf_light > 0.0f) || !sss_x3_at(scene, &cand, &x3)) continue;
        for (uint32_t j = 0; j < n; j++) {
            struct surface x2;
            float b1, b2;
            surface_from_hit(scene, &hits[j], probe.org, probe.dir, &x2);
            /* Evaluated at the point its code rebuilds, exactly as every shift will see it. */
            surface_point_code(scene, &hits[j], &x2, &b1, &b2);
            surface_at(scene, hits[j].shape, hits[j].prim, b1, b2, &x2);
            float p_mis;
            struct vec3 F = sss_eval(scene, &x1, &x2, &x3, axis, channel, true, &p_mis, rc);
            if (vec3_is_zero(F)) continue;
            /* w = p̂ / p with p̂ = f w_t and p = P_t p_t p_light: f / (p_mis p_light) (eq. 10). */
            double p = (double)(bssrdf_technique_prob(axis, channel) *
                                bssrdf_pdf_technique(x1.m, x1.s.p, &x1.s.frame, axis, channel, x2.p, x2.ng)) *
                       pdf_light;
            cand.head.bits = sss_bits(axis, channel, j);
            cand.x2_shape = hits[j].shape;
            cand.x2_prim = hits[j].prim;
            cand.x2_b1 = b1;
            cand.x2_b2 = b2;
            cand.F[0] = F.x, cand.F[1] = F.y, cand.F[2] = F.z;
            sss_offer(&offer, &cand, F, p);
        }
    }
    for (uint32_t l = 0; l < layers; l++) {
        struct reservoir res = reservoir_stream_finish(&rs[l]);
        out[l]->head.W = res.W;
        out[l]->head.M = (uint16_t)res.M;
    }
}

/* ---- shifts --------------------------------------------------------------------------------- */

/* After a reconnection to y1 (sequential shift, §4.2–4.3): the disk numbers that make the kept
 * technique's probe from y1 pass through y2 (Algorithm 4 lines 2–9; the technique is part of the
 * sample, so line 1's choice is the sample's own) and y2's index among that probe's hits. Exact
 * mode: the probe is traced for every evaluation and the shift fails when y2 is not among its
 * hits, so the mapping is the same whether or not the shifted sample is kept. Shortcut: traced
 * only for a sample that is kept (`dst_wanted`); a miss leaves the index unknown. */
static bool sss_invert(const struct sss_ctx *c, const struct scene *scene, const struct sss_x1 *y1,
                       const struct surface *y2, int axis, int channel, struct sss_sample *y, bool dst_wanted,
                       struct ray_counters *rc)
{
    float ur, ua;
    if (!bssrdf_invert(y1->m, y1->s.p, &y1->s.frame, axis, channel, y2->p, &ur, &ua)) return false;
    y->u_radius = ur;
    y->u_angle = ua;
    if (c->p->index_shortcut && !dst_wanted) return true;
    struct bssrdf_probe probe;
    uint32_t found = SSS_HIT_UNKNOWN;
    if (bssrdf_probe_make(y1->m, y1->s.p, &y1->s.frame, axis, channel, ur, ua, &probe)) {
        struct hit hits[BSSRDF_MAX_HITS];
        uint32_t n = accel_intersect_shape_all(scene->accel, y1->s.shape, probe.org, probe.dir, 0.0f, probe.tmax, hits,
                                               BSSRDF_MAX_HITS, rc);
        /* The hit on y2's primitive nearest to y2, within a small fraction of the reach. */
        float best = 1e-3f * vec3_comp(y1->m->sss_r_max, channel);
        best *= best;
        for (uint32_t j = 0; j < n && j < SSS_HIT_UNKNOWN; j++) {
            if (hits[j].shape != y->x2_shape || hits[j].prim != y->x2_prim) continue;
            struct surface h;
            surface_from_hit(scene, &hits[j], probe.org, probe.dir, &h);
            float d2 = vec3_length2(vec3_sub(h.p, y2->p));
            if (d2 < best) best = d2, found = j;
        }
    }
    if (found == SSS_HIT_UNKNOWN && !c->p->index_shortcut) return false;
    y->head.bits = sss_bits_of(y, axis, channel, found);
    return true;
}

static void sss_shift_impl(const struct sss_ctx *c, const struct sss_sample *x, struct restir_domain from,
                           struct restir_domain to, struct sss_sample *y, bool dst_wanted, float *target,
                           float *jacobian, struct restir_counters *cnt)
{
    *target = 0.0f;
    *jacobian = 0.0f;
    *y = *x;
    struct sss_x1 x1, y1;
    if (!sss_primary(c, from, &x1) || !sss_primary(c, to, &y1)) return;
    /* Never across objects (§2.1): x2 lies on x1's shape, so y1 must be on it too. */
    if (y1.s.shape != x->x2_shape || x1.s.shape != x->x2_shape) return;
    const struct scene *sf = c->scene[from.frame], *st = c->scene[to.frame];
    struct surface x2;
    surface_at(sf, x->x2_shape, x->x2_prim, x->x2_b1, x->x2_b2, &x2);
    const int axis = sss_axis(x), channel = sss_channel(x);
    struct sss_x3 x3;
    if (!sss_x3_at(st, x, &x3)) return;
    const bool x3_fixed = x3.indirect && !x3.lambertian;
    const bool reconnect = sss_reconnects(c, &x1, &x2, x3_fixed);
    /* An indirect sample's L3 was found in its own frame's scene: it holds in another frame only
     * while nothing in the scene moved. */
    if (x3.indirect && from.frame != to.frame && c->moved) return;
    float jac = 1.0f;
    if (x->x3_shape != SSS_ENV_SHAPE) jac *= surface_area_ratio(sf, st, x->x3_shape, x->x3_prim, x->x3_b1, x->x3_b2);
    struct surface y2;
    bool visibility;
    if (reconnect) {
        /* Reconnection (§3.2.1): y2 = x2 (its point code, so a moving object carries it). */
        surface_at(st, x->x2_shape, x->x2_prim, x->x2_b1, x->x2_b2, &y2);
        jac *= surface_area_ratio(sf, st, x->x2_shape, x->x2_prim, x->x2_b1, x->x2_b2);
        /* x2 -> x3 is unchanged within a frame (and was visible: the sample's target is > 0). */
        visibility = from.frame != to.frame;
        if (c->p->shift == RESTIR_SSS_SEQUENTIAL &&
            !sss_invert(c, st, &y1, &y2, axis, channel, y, dst_wanted, &cnt->rays))
            return;
    } else {
        /* Delayed reconnection (§3.2.2): replay the probe from y1, take the same hit index. An
         * indirect sample's L3 holds towards y2 only from a Lambertian x3. */
        if (x3_fixed) return;
        struct bssrdf_probe probe;
        if (!bssrdf_probe_make(y1.m, y1.s.p, &y1.s.frame, axis, channel, x->u_radius, x->u_angle, &probe)) return;
        struct hit hits[BSSRDF_MAX_HITS];
        uint32_t n = accel_intersect_shape_all(st->accel, y1.s.shape, probe.org, probe.dir, 0.0f, probe.tmax, hits,
                                               BSSRDF_MAX_HITS, &cnt->rays);
        uint32_t j = sss_hit(x);
        if (j == SSS_HIT_UNKNOWN && n > 0) {
            /* The shortcut's unknown index: a random hit, from a stream of the two domains
             * (deterministic, but not invertible: the slight bias §4.3 accepts). */
            struct rng pick = rng_make(c->seed, c->frame, (uint64_t)from.pixel << 32 | to.pixel, SSS_PICK_STREAM);
            j = (uint32_t)(rng_next_float(&pick) * (float)n);
            if (j >= n) j = n - 1;
            y->head.bits = sss_bits_of(y, axis, channel, j);
        }
        if (j >= n) return;
        surface_from_hit(st, &hits[j], probe.org, probe.dir, &y2);
        surface_point_code(st, &hits[j], &y2, &y->x2_b1, &y->x2_b2);
        y->x2_prim = hits[j].prim;
        /* The stored point is its code: rebuild y2 from it, as the inverse shift will rebuild it
         * (the pdf ~ 1/r near x1 turns a float difference into a visible Jacobian error). */
        surface_at(st, y->x2_shape, y->x2_prim, y->x2_b1, y->x2_b2, &y2);
        /* Jacobian of the replay in area measure, per technique: p_t,x1(x2) / p_t,y1(y2). */
        float px = bssrdf_pdf_technique(x1.m, x1.s.p, &x1.s.frame, axis, channel, x2.p, x2.ng);
        float py = bssrdf_pdf_technique(y1.m, y1.s.p, &y1.s.frame, axis, channel, y2.p, y2.ng);
        if (!(px > 0.0f) || !(py > 0.0f)) return;
        jac *= px / py;
        visibility = true;
    }
    /* The offset path must make the same choice (§4.1), so the shift stays invertible. */
    if (c->pass_shift == RESTIR_SSS_HYBRID && sss_reconnects(c, &y1, &y2, x3_fixed) != reconnect) return;
    struct vec3 F = sss_eval(st, &y1, &y2, &x3, axis, channel, visibility, NULL, &cnt->rays);
    float t = sss_target_of(c->channel, F);
    if (!(t > 0.0f) || !(jac > 0.0f) || !isfinite(jac)) return;
    y->F[0] = F.x, y->F[1] = F.y, y->F[2] = F.z;
    *target = t;
    *jacobian = jac;
}

/* F of the sample in the channels its reservoir estimates: all, or its target's channel. */
static struct vec3 sss_value_of(int channel, const struct sss_sample *s)
{
    if (channel < 0) return vec3_make(s->F[0], s->F[1], s->F[2]);
    struct vec3 v = vec3_splat(0.0f);
    if (channel == 0) v.x = s->F[0];
    else if (channel == 1) v.y = s->F[1];
    else v.z = s->F[2];
    return v;
}

static struct vec3 sss_value(const void *ctx, const void *elem)
{
    const struct sss_ctx *c = ctx;
    return sss_value_of(c->channel, elem);
}

static float sss_target(const void *ctx, const void *elem)
{
    const struct sss_ctx *c = ctx;
    const struct sss_sample *s = elem;
    return sss_target_of(c->channel, vec3_make(s->F[0], s->F[1], s->F[2]));
}

static void sss_shift(const void *ctx, const void *src, struct restir_domain from, struct restir_domain to, void *dst,
                      float *target, float *jacobian, struct restir_counters *cnt)
{
    struct sss_sample y;
    sss_shift_impl(ctx, src, from, to, &y, dst != NULL, target, jacobian, cnt);
    if (dst) memcpy(dst, &y, sizeof y);
}

static bool sss_domain_valid(const void *ctx, struct restir_domain d)
{
    struct sss_x1 x1;
    return sss_primary(ctx, d, &x1);
}

const struct restir_ops restir_sss_ops = {
    .stride = sizeof(struct sss_sample),
    .target = sss_target,
    .shift = sss_shift,
    .domain_valid = sss_domain_valid,
    .value = sss_value,
};

void restir_sss_info(const void *ctx, const void *elem, uint32_t pixel, struct restir_sss_info *out)
{
    const struct sss_ctx *c = ctx;
    const struct sss_sample *s = elem;
    memset(out, 0, sizeof *out);
    out->x2_shape = s->x2_shape, out->x2_prim = s->x2_prim, out->x2_b1 = s->x2_b1, out->x2_b2 = s->x2_b2;
    out->axis = sss_axis(s), out->channel = sss_channel(s), out->hit = (int)sss_hit(s);
    out->u_radius = s->u_radius, out->u_angle = s->u_angle;
    out->F = vec3_make(s->F[0], s->F[1], s->F[2]);
    out->indirect = sss_indirect(s);
    struct sss_x1 x1;
    if (s->head.W > 0.0f && sss_primary(c, (struct restir_domain){pixel, RESTIR_CURRENT}, &x1)) {
        struct surface x2;
        surface_at(c->scene[RESTIR_CURRENT], s->x2_shape, s->x2_prim, s->x2_b1, s->x2_b2, &x2);
        struct sss_ctx ch = *c;
        ch.pass_shift = RESTIR_SSS_HYBRID;
        struct sss_x3 x3;
        const bool x3_fixed = sss_x3_at(c->scene[RESTIR_CURRENT], s, &x3) && x3.indirect && !x3.lambertian;
        out->reconnect = sss_reconnects(&ch, &x1, &x2, x3_fixed);
        out->x3_fixed = x3_fixed;
    }
}

/* ---- the frame ------------------------------------------------------------------------------ */

static bool sss_uses_pairs(const struct restir_sss_params *p)
{
    return restir_pairs_needed(p->paired_spatial, p->spatial_neighbors);
}

bool restir_sss_init(struct restir_sss_state *st, const struct scene *scene, const struct restir_sss_params *params,
                     uint32_t width, uint32_t height, struct err *err)
{
    memset(st, 0, sizeof *st);
    bool ok = restir_session_init(&st->rs, width, height, restir_sss_layers(params), sizeof(struct sss_sample), true,
                                  sss_uses_pairs(params), err);
    if (ok && restir_sss_rest_of(params) == RESTIR_SSS_REST_RESTIR_PT) {
        struct restir_pt_params rp = restir_sss_rest_params(params);
        st->has_rest = true;
        ok = restir_pt_init(&st->rest, scene, &rp, width, height, err) && image_init(&st->rest_image, width, height, err);
    }
    if (!ok) restir_sss_destroy(st);
    return ok;
}

void restir_sss_destroy(struct restir_sss_state *st)
{
    restir_session_destroy(&st->rs);
    if (st->has_rest) {
        restir_pt_destroy(&st->rest);
        image_destroy(&st->rest_image);
    }
    memset(st, 0, sizeof *st);
}

void restir_sss_reset(struct restir_sss_state *st)
{
    restir_session_reset(&st->rs);
    if (st->has_rest) restir_session_reset(&st->rest.rs);
}

uint64_t restir_sss_bytes_planned(const struct restir_sss_params *params, const struct scene *scene, uint32_t width,
                                  uint32_t height)
{
    uint64_t rest = 0;
    if (restir_sss_rest_of(params) == RESTIR_SSS_REST_RESTIR_PT) {
        struct restir_pt_params rp = restir_sss_rest_params(params);
        rest = restir_pt_bytes_planned(&rp, width, height, scene) + (uint64_t)width * height * sizeof(struct vec3);
    }
    return 2 * (uint64_t)width * height *
               (restir_sss_layers(params) * sizeof(struct sss_sample) + sizeof(struct gbuffer_pixel) +
                sizeof(struct gbuffer_surface)) +
           (sss_uses_pairs(params) ? restir_pair_scratch_bytes(width, height) : 0) + rest;
}

struct sss_pass {
    struct restir_frame fr;   /* first: the driver's rows reach it through the pass */
    const struct sss_ctx *c;
    struct pt_params pt;
    const struct vec3 *rest;   /* the rest's restir_pt frame, or NULL: the pt path renders the rest */
    uint32_t rest_samples;     /* pt paths a pixel for the rest (params->rest_samples) */
    struct restir_sss_stats local;   /* the counters of a frame whose caller keeps none */
};
RESTIR_FRAME_FIRST(struct sss_pass);
/* The frame's stats pointer is this struct's `pass`. */
_Static_assert(offsetof(struct restir_sss_stats, pass) == 0, "restir_sss_stats must begin with its pass stats");

/* Initial pass: candidates into the working buffer, and the rest of the image: restir_pt's
 * frame, or the pt path from the same primary ray (the G-buffer's jitter). Where the primary
 * surface is translucent the reservoirs carry all the light pt's path would bring (it has no
 * surface reflection: pt_sss_primary) but the emission seen there, which restir_pt's frame holds
 * at every pixel, or which is added here. */
static void sss_initial_rows(void *ctx, uint32_t job, unsigned worker)
{
    struct sss_pass *pp = ctx;
    const struct sss_ctx *c = pp->c;
    uint32_t w = pp->fr.s->width, y0, y1;
    restir_frame_rows(&pp->fr, job, &y0, &y1);
    struct sss_sample *res = (struct sss_sample *)pp->fr.s->res[0];
    const uint32_t layers = pp->fr.s->layers;
    const size_t n = (size_t)w * pp->fr.s->height;
    struct ray_counters rays = {0, 0};  /* job-local (see restir_counters_add) */
    struct ray_counters *rc = &rays;
    for (uint32_t y = y0; y < y1; y++) {
        for (uint32_t x = 0; x < w; x++) {
            uint32_t pixel = y * w + x;
            struct sss_sample *out[3];
            for (uint32_t l = 0; l < layers; l++) out[l] = &res[l * n + pixel];
            sss_initial_pixel(c, pixel, layers, out, rc);
            if (!pp->fr.out) continue;
            const struct gbuffer_pixel *g = &c->gbuf[RESTIR_CURRENT]->px[pixel];
            const struct gbuffer_surface *h = &c->gbuf[RESTIR_CURRENT]->surf[pixel];
            const struct scene *scene = c->scene[RESTIR_CURRENT];
            const struct material *m = h->material == GBUFFER_NO_HIT ? NULL : &scene->materials[h->material];
            const bool translucent = m && m->kind == MATERIAL_TRANSLUCENT;
            if (pp->rest) {
                pp->fr.out->pixels[pixel] = pp->rest[pixel];
                continue;
            }
            struct vec3 dir = camera_ray_dir(&pp->fr.camera, (float)x + g->jx, (float)y + g->jy);
            if (translucent) {
                pp->fr.out->pixels[pixel] = light_sampler_emitted(m, -vec3_dot(dir, h->ng));
                continue;
            }
            struct rng rng = rng_make(c->seed, c->frame, pixel, SSS_PT_STREAM);
            /* The G-buffer pass traced this ray already: its hit starts the paths. How many a
             * pixel gets is fixed once its primary hit is known, so their mean estimates what one
             * path from that hit does. */
            struct hit first;
            const struct hit *primary = gbuffer_hit(scene, g, &first);
            struct vec3 L = {0.0f, 0.0f, 0.0f};
            for (uint32_t i = 0; i < pp->rest_samples; i++)
                L = vec3_add(L, reference_pt_radiance(scene, &pp->pt, pp->fr.camera.position, dir, primary, &rng, rc));
            pp->fr.out->pixels[pixel] = vec3_scale(L, 1.0f / (float)pp->rest_samples);
        }
    }
    pp->fr.counters[worker].rays.intersect += rays.intersect;
    pp->fr.counters[worker].rays.occluded += rays.occluded;
}

static void sss_shade_rows(void *ctx, uint32_t job, unsigned worker)
{
    struct sss_pass *pp = ctx;
    uint32_t w = pp->fr.s->width, y0, y1;
    restir_frame_rows(&pp->fr, job, &y0, &y1);
    const struct sss_sample *res = (const struct sss_sample *)pp->fr.s->res[1];
    const uint32_t layers = pp->fr.s->layers;
    const size_t n = (size_t)w * pp->fr.s->height;
    for (uint32_t y = y0; y < y1; y++) {
        for (uint32_t x = 0; x < w; x++) {
            uint32_t pixel = y * w + x;
            struct vec3 L = pp->fr.out->pixels[pixel];
            /* Unless the last spatial pass already added its expected contribution. */
            for (uint32_t l = 0; l < layers && !pp->fr.estimated; l++) {
                const struct sss_sample *s = &res[l * n + pixel];
                if (s->head.W > 0.0f)
                    L = vec3_add(L, vec3_scale(sss_value_of(layers > 1 ? (int)l : -1, s), s->head.W));
            }
            restir_frame_store(&pp->fr, worker, pixel, L);
        }
    }
}

void restir_sss_bind(struct restir_sss_state *st, const struct restir_sss_params *params,
                     const struct method_frame *f, void *ctx)
{
    struct sss_ctx *c = ctx;
    memset(c, 0, sizeof *c);
    c->p = params;
    restir_frame_domains(&st->rs, f, c->scene, c->eye, c->gbuf);
    c->seed = f->seed;
    c->frame = f->frame;
    /* The sequential shift starts with reconnection (temporal and first spatial pass). */
    c->pass_shift = params->shift == RESTIR_SSS_SEQUENTIAL ? RESTIR_SSS_RECONNECTION : params->shift;
    c->channel = -1;   /* the luminance target, or layer 0's channel: restir_sss_render sets it per layer */
    if (restir_sss_layers(params) > 1) c->channel = 0;
    c->moved = f->prev_scene && scene_moved(f->prev_scene, f->scene);
    c->pt = NULL;      /* restir_sss_render points it at the frame's path parameters */
}

/* The automatic spatial radius (§5.1): 2 max(d) of the translucent materials seen, projected at
 * the mean distance of the translucent primary hits, clamped to [5, 30] pixels. */
static float sss_auto_radius(const struct sss_ctx *c, const struct camera_desc *cam, uint32_t width, uint32_t height)
{
    double dist = 0.0, dmax = 0.0;
    uint64_t n = 0;
    const struct scene *scene = c->scene[RESTIR_CURRENT];
    for (uint32_t i = 0; i < width * height; i++) {
        const struct gbuffer_pixel *g = &c->gbuf[RESTIR_CURRENT]->px[i];
        if (!isfinite(g->t)) continue;
        const struct material *m = &scene->materials[scene->shapes[g->shape].material];
        if (m->kind != MATERIAL_TRANSLUCENT) continue;
        dist += g->t;
        n++;
        if (vec3_max_comp(m->sss_d) > dmax) dmax = vec3_max_comp(m->sss_d);
    }
    if (n == 0) return 5.0f;
    double mean = dist / (double)n;
    double px = 2.0 * dmax / (2.0 * mean * tan(cam->fov_deg * M_PI / 360.0)) * height;
    return (float)fmin(30.0, fmax(5.0, px));
}

bool restir_sss_render(struct restir_sss_state *st, const struct restir_sss_params *params,
                       const struct method_frame *f, struct image *out, struct restir_sss_stats *stats,
                       struct err *err)
{
    struct sss_ctx c;
    struct sss_pass pp;   /* on the stack (restir_frame): a frame allocates nothing */
    if (!(stats = restir_frame_open(&pp.fr, sizeof pp, &st->rs, f, out, params->temporal, stats, &pp.local,
                                    sizeof pp.local, err)) ||
        !restir_sss_params_valid(params, err))
        return false;
    if (restir_sss_layers(params) != st->rs.layers)
        return err_set(err, ERR_INVALID, "/params/target", "the session's reservoirs were made for the other target");
    if ((restir_sss_rest_of(params) == RESTIR_SSS_REST_RESTIR_PT) != st->has_rest)
        return err_set(err, ERR_INVALID, "/params/rest", "the session was made for the rest by %s",
                       st->has_rest ? "restir_pt" : "pt");
    /* The rest's frame first, with its own G-buffer (restir_pt's jitter walk) and passes. */
    pp.rest = NULL;
    if (st->has_rest && out) {
        clock_gettime(CLOCK_MONOTONIC, &pp.fr.t0);   /* restir_frame_gbuffer starts it after the rest */
        struct restir_pt_params rp = restir_sss_rest_params(params);
        if (!restir_pt_render_rest(&st->rest, &rp, f, &st->rest_image, &stats->pass, err)) return false;
        stats->rest_ms = parallel_lap_ms(&pp.fr.t0);
        pp.rest = st->rest_image.pixels;
    }
    if (!restir_frame_gbuffer(&pp.fr, 0.0f, sss_uses_pairs(params), false, 1, err)) return false;
    restir_sss_bind(st, params, f, &c);
    pp.c = &c;
    pp.pt = reference_pt_rest(st->rs.width, st->rs.height, params->max_depth, params->rr_depth);
    pp.rest_samples = params->rest_samples;
    /* Indirect samples start at the path's second vertex: none within max_depth 1. */
    c.pt = params->max_depth >= 2 ? &pp.pt : NULL;
    if (!restir_frame_initial(&pp.fr, sss_initial_rows, err)) return false;
    if (!out) return true;   /* restir_sss_initial_only */
    float radius = params->spatial_radius > 0.0f ? params->spatial_radius
                                                 : sss_auto_radius(&c, f->camera, st->rs.width, st->rs.height);
    stats->spatial_radius = radius;
    /* One reuse per layer, each with its own target (the ctx's channel) and reservoirs; they share
     * the G-buffers, the pair scratch (one pass at a time) and the neighbour pairings. */
    const uint32_t layers = st->rs.layers;
    struct sss_ctx lc[3];
    for (uint32_t l = 0; l < layers; l++) {
        lc[l] = c;
        lc[l].channel = layers > 1 ? (int)l : -1;
    }
    struct restir_reuse *r = restir_frame_reuse(&pp.fr, &restir_sss_ops, lc, sizeof lc[0], params->temporal_cap,
                                                params->spatial_neighbors, radius, params->paired_spatial);
    if (!restir_frame_temporal(&pp.fr, err)) return false;
    if (params->spatial_neighbors > 0 && params->shift == RESTIR_SSS_SEQUENTIAL) {
        /* §4.3, §5.1: half the neighbours with reconnection, then half with delayed
         * reconnection (its own neighbour stream), ending in res[1]. */
        for (uint32_t l = 0; l < layers; l++) r[l].neighbors = params->spatial_neighbors / 2;
        if (!restir_frame_spatial(&pp.fr, false, false, err)) return false;
        for (uint32_t l = 0; l < layers; l++) {
            lc[l].pass_shift = RESTIR_SSS_DELAYED;
            r[l].frame = f->frame * 8u + 1u;
        }
        if (!restir_frame_spatial(&pp.fr, params->expected_shading, true, err)) return false;
    } else if (params->spatial_neighbors > 0) {
        if (!restir_frame_spatial(&pp.fr, params->expected_shading, true, err)) return false;
    } else {
        restir_session_swap(&st->rs);
    }
    restir_frame_reused(&pp.fr);
    return restir_frame_shade(&pp.fr, sss_shade_rows, err);
}

bool restir_sss_initial_only(struct restir_sss_state *st, const struct restir_sss_params *params,
                             const struct method_frame *f, struct err *err)
{
    return restir_sss_render(st, params, f, NULL, NULL, err);
}
