/* restir_sms.h — method `restir_sms`: spatiotemporal resampling (ReSTIR) of specular manifold
 * samples ([SMS-SSP §5]).
 *
 * Domain and integrand (§5.2, eqs. 12-13). A pixel's receiver x1 is the first diffuse or glossy
 * vertex of its camera path when the delta vertices before it all take their canonical lobe
 * (sms.h; the primary hit itself when that is diffuse or glossy, else e.g. the floor seen through
 * a glass slab — §5.2: the prefix before x1 is kept fixed, the shift acts in x1's conditional
 * space). A sample is x̂ = (caster, x_n, x̄*): a caster, a point x_n on an emitter and one admissible
 * specular chain x̄* from x1 through the caster to x_n. The measure is the emitter's area times
 * counting measure over casters and solutions, and the integrand
 *     f(x̂) = T_prefix ρ(x1) |cos θ1| T(x̄*) G(x1 ↔ x̄* ↔ x_n) L_e(x_n)
 * (G the generalized geometry term |dω1/dA(x_n)|, sms_solution_value; T_prefix the prefix's
 * expected throughput). Target p̂ = luminance f.
 *
 * Candidates. One per pixel and frame from the sms_ssp sampler (tiles, trust regions, prior,
 * Bernoulli trials in the conditional space; or plain SMS, `sampler`): its unbiased contribution
 * weight is the Bernoulli estimate W = trials / P(C(u*)) · C / p(x_n) (plain SMS: trials · C /
 * p(x_n)), a random variable with E[W | x̂] = 1 / p(x̂). GRIS
 * (Lin et al. 2022) only needs each input's W to be an unbiased contribution weight
 * (E[f(X) W_X] = ∫ f), so resampling with the estimated inverse pdf stays unbiased — as long as
 * the trials are uncapped (bernoulli_cap 0); with a cap, solutions past it are lost exactly as in
 * `sms` ([SMS-SSP Fig. 7]), a bias the frame counters report (`capped`).
 *
 * The manifold shift (§5.2). T(caster, x_n, x̄*) = (caster, x_n, x̄*'): x_n is kept (rebuilt from
 * its point code in the target frame's scene) and the chain is walked from the base chain x̄* to
 * the target pixel's x1 with at most `shift_iterations` Newton steps (§5.3: 5); the result must
 * pass manifold_check there. Invertibility: the shifted chain is walked back to the base pixel's
 * x1 with the same budget and must reach the base chain again (within 1e-4 of |x1 − x2|, the
 * same-solution threshold of the Bernoulli trials), else the shift fails — so T is a bijection
 * between the sets where it succeeds, and shifting back is its inverse. Jacobian: x_n is the same
 * point of the same emitter and the chain is a discrete choice, so |∂T/∂x| = 1 (footnote 6),
 * times the emitter's area change when its shape was scaled between the two frames
 * (surface_area_ratio; 1 for a static or rigidly moving light).
 *
 * Reuse: restir.c's temporal pass (generalized balance heuristic, confidence cap, default 20)
 * and spatial pass (pairwise MIS; default 1 neighbour in a 30-pixel radius, as [SMS-SSP Fig. 4]),
 * by default with paired neighbours (restir.h, [ReSTIR PT Enhanced]): the neighbour relation is
 * symmetric, so a pair's two manifold shifts serve both of its pixels, one shift per pixel instead
 * of two.
 *
 * Reservoirs per light (`light_reservoirs` n > 1). One selected path carries one light's colour,
 * so under lights of different colours most of a frame's error is that colour (docs/benchmarks.md,
 * "What one reservoir per pixel cannot go below"). With n reservoirs a pixel splits the domain by
 * emitter: reservoir k resamples only the paths whose x_n lies on an emitter of share k
 * (restir_sms_light_reservoir), with target p̂_k = p̂ there and 0 elsewhere, and the pixel's value
 * is the sum of the n estimates, each unbiased for its share of the integral. The pixel's one
 * candidate goes to the reservoir of its light; every other reservoir counts it as a candidate of
 * target 0 (M = 1, W = 0), which is exactly what RIS over p̂_k does with it. The shift keeps x_n,
 * so a reservoir's samples never leave its share. Each reservoir is reused on its own, so the
 * shifts multiply by up to n (reservoirs left empty cost no shift).
 *
 * Everything else a pixel receives comes from one path per pixel and frame from the same
 * primary ray (the G-buffer's jitter), with plain SMS estimates at every other non-delta vertex
 * (reference_pt_radiance_sms, which leaves out exactly the receiver when its path took the
 * canonical prefix, whose expectation T_prefix · SMS the reservoirs carry), and from whatever
 * renders the rest of the light (`rest`, below): that same path, or a restir_pt session restricted
 * to the rest; so the image estimates exactly what `pt` does (or, with caustics_only, pt's
 * caustic subset). Those other vertices take plain SMS with either sampler: the prior describes
 * the receivers only, and partitioning without it draws rare solutions from a 9 / N² share of
 * the seeds, whose weights were most of a frame's error (docs/benchmarks.md).
 * The state is allocated once per session; a steady-state frame allocates nothing.
 * Refs: [SMS-SSP §5, eqs. 10-13]; docs/methods.md (restir_sms). */
#ifndef RESTIRD_RESTIR_SMS_H
#define RESTIRD_RESTIR_SMS_H

#include <stdint.h>

#include "core/alias.h"
#include "reuse/gbuffer.h"
#include "image/image.h"
#include "reuse/restir.h"
#include "integrators/frame.h"
#include "scene/scene.h"
#include "integrators/sms_ssp.h"
#include "integrators/restir_pt.h"

/* The candidates' sampler: [SMS-SSP]'s sample-space partitioning with the per-frame prior (`ssp`,
 * the paper's), or plain SMS (`sms`, Zeltner et al. 2020: seeds over the caster's bounding box,
 * no prior), whose estimates have a lighter tail on our scenes (docs/benchmarks.md). The SMS
 * estimates at the pt path's later vertices use the same sampler. */
enum restir_sms_sampler { RESTIR_SMS_SAMPLER_SSP, RESTIR_SMS_SAMPLER_SMS };

/* Who renders the light manifold sampling does not own (sms.h's rest: all but the caustic chains).
 * `pt`: one path-traced sample a pixel and frame from the G-buffer's primary ray, which bounds the
 * frame's error from below whatever the caustics' reuse achieves (docs/benchmarks.md, "What one
 * reservoir per pixel cannot go below"). `restir_pt`: a restir_pt session restricted to that
 * subset (its `subset` "rest"), its reservoirs beside the caustic ones, as ReSTIR BDPT keeps
 * reservoirs for both kinds of path; the pt path then adds only the SMS estimates at its later
 * vertices. Both halves are unbiased, so is their sum. `by_scene` (the default) takes restir_pt
 * unless the scene has translucent materials (restir_pt does not sample subsurface scattering) or
 * max_depth is outside restir_pt's 1..RESTIR_PT_MAX_DEPTH. */
enum restir_sms_rest { RESTIR_SMS_REST_BY_SCENE, RESTIR_SMS_REST_PT, RESTIR_SMS_REST_RESTIR_PT };

struct RESTIRD_STORED_IN_BYTES restir_sms_params {
    enum restir_sms_sampler sampler; /* (ssp) */
    struct ssp_params ssp;        /* the candidate sampler (sms_ssp's params: bernoulli_cap,
                                     max_iterations, caustics_only, tiles, prior, prior_samples,
                                     alpha); ssp.sms also the plain SMS at other vertices */
    uint32_t shift_iterations;    /* Newton steps of each walk of a shift (5, §5.3) */
    bool temporal;                /* (true) */
    uint32_t temporal_cap;        /* previous M capped at this multiple of the current M (20) */
    uint32_t spatial_neighbors;   /* (1); 0 = no spatial reuse */
    float spatial_radius;         /* pixels (30) */
    bool paired_spatial;          /* symmetric neighbour pairs whose two shifts serve both pixels
                                     (true; restir.h); else neighbours uniform in the radius */
    bool expected_shading;        /* shade with the spatial pass's expected contribution over its
                                     candidates instead of the selected sample's F W (true) */
    float jitter_walk;            /* the primary ray's position in the pixel moves by at most this
                                     per axis and frame (0.1 pixels; gbuffer.h), so that the history
                                     was gathered near where the frame looks: a sharp caustic varies
                                     within a pixel; 0 = a fresh position every frame */
    uint32_t light_reservoirs;    /* reservoirs per pixel, each resampling only the paths to its
                                     share of the emitters (restir_sms_light_reservoir); BY_SCENE
                                     (the default): one per emissive shape, at most MAX */
    uint32_t max_depth, rr_depth; /* of the pt path that supplies the rest of the image (64, 3;
                                     max_depth also the rest's restir_pt paths') */
    enum restir_sms_rest rest;    /* (by_scene) */
};

#define RESTIR_SMS_MAX_LIGHT_RESERVOIRS 8u
#define RESTIR_SMS_LIGHT_RESERVOIRS_BY_SCENE 0u

struct restir_sms_params restir_sms_defaults(void);
/* p->rest on the scene, by_scene resolved; pt with caustics_only (the pt path adds only its SMS
 * estimates then). */
enum restir_sms_rest restir_sms_rest_of(const struct restir_sms_params *p, const struct scene *scene);
/* The parameters of the rest's restir_pt session: restir_pt's defaults with subset "rest" and
 * restir_sms's max_depth; without temporal reuse (restir_sms's converge profile), restir_pt's
 * converge profile, so that the frames stay independent. */
struct restir_pt_params restir_sms_rest_params(const struct restir_sms_params *p);
/* ERR_INVALID naming the parameter (where = "/params/<name>"). */
bool restir_sms_params_valid(const struct restir_sms_params *p, struct err *err);

struct RESTIRD_STORED_IN_BYTES restir_sms_stats {
    struct restir_pass_stats pass;
    double prior_ms;                /* the prior pass (the ssp sampler's), before the candidates */
    uint64_t shift_newton;          /* Newton steps of the shifts' walks (forward and back) */
    uint64_t shift_not_invertible;  /* shifts whose walk back missed the base chain */
    struct sms_counters sms;        /* the candidates and the SMS estimates at later vertices */
    double rest_ms;                 /* the rest's restir_pt frame (rest = restir_pt), before the prior */
    struct ssp_prior_counters prior;
};

/* A pixel's receiver x1 in one frame (sms.h): the camera ray (the G-buffer's jitter) followed
 * through canonical delta lobes to the first diffuse or glossy vertex. */
struct restir_sms_receiver {
    uint32_t shape, prim;
    float b1, b2;        /* x1's point code */
    float wo[3];         /* world direction from x1 back along the path */
    float T[3];          /* the delta prefix's expected throughput: the product of f |cos| over its
                            canonical lobes (what path tracing carries there, averaged over its
                            lobe choices) */
    uint16_t valid, depth;   /* depth: delta vertices before x1 */
};

struct restir_sms_state {
    struct restir_session rs;              /* restir_sms_layers reservoirs per pixel */
    struct restir_sms_receiver *recv[2];   /* with rs.gbuf[rs.cur] and rs.gbuf[rs.cur ^ 1] */
    struct ssp_prior prior;   /* the ssp sampler's; no entries with the sms sampler */
    bool has_rest;                 /* rest = restir_pt: */
    struct restir_pt_state rest;   /*   its session, */
    struct image rest_image;       /*   and its frame, to which the initial pass adds the caustics */
};

#define RESTIR_SMS_RESERVOIR_BYTES 64u   /* per reservoir; a pixel has light_reservoirs of them */

/* The reservoir a path to an emissive shape belongs to, of `layers`: the shape's rank among the
 * emissive shapes (in scene order) of the scene as loaded (a derived scene's base), modulo
 * `layers`; the same in every frame of a session whatever its lights' emission. */
uint32_t restir_sms_light_reservoir(const struct scene *scene, uint32_t light_shape, uint32_t layers);

/* The reservoirs per pixel the parameters give on a scene: light_reservoirs, or BY_SCENE's count
 * (of the scene as loaded, like restir_sms_light_reservoir's ranks). */
uint32_t restir_sms_layers(const struct restir_sms_params *p, const struct scene *scene);

/* The buffers the parameters use on the scene: restir_sms_layers reservoirs per pixel, the prior
 * only for the ssp sampler, the pair scratch only for paired spatial reuse (a render with other
 * parameters is refused). */
bool restir_sms_init(struct restir_sms_state *st, const struct scene *scene, const struct restir_sms_params *params,
                     uint32_t width, uint32_t height, struct err *err);
void restir_sms_destroy(struct restir_sms_state *st);
size_t restir_sms_receiver_bytes(const struct restir_sms_state *st);
size_t restir_sms_prior_bytes(const struct restir_sms_state *st);  /* 0 with the sms sampler */
uint64_t restir_sms_bytes_planned(const struct restir_sms_params *params, const struct scene *scene, uint32_t width,
                                  uint32_t height);


bool restir_sms_render(struct restir_sms_state *st, const struct restir_sms_params *params,
                       const struct method_frame *f, struct image *out, struct restir_sms_stats *stats,
                       struct err *err);

/* For tests: the shift on its own. A context bound to a frame whose G-buffers were rendered
 * (restir_sms_initial_only renders them and the initial reservoirs), an element built from a
 * solution at a domain, and the shift through restir_sms_ops. */
#define RESTIR_SMS_CTX_BYTES 8192u
bool restir_sms_initial_only(struct restir_sms_state *st, const struct restir_sms_params *params,
                             const struct method_frame *f, void *ctx, struct err *err);
extern const struct restir_ops restir_sms_ops;
struct restir_sms_info {
    uint32_t caster, length, light_shape;
    struct vec3 light_p;
    struct vec3 chain[MANIFOLD_MAX_CHAIN];  /* the chain's vertices rebuilt in the current scene */
    struct vec3 F;
};
/* The element's sample decoded in the current frame's scene. */
void restir_sms_info(const void *ctx, const void *elem, struct restir_sms_info *out);
/* The number of Newton steps the bound context's shifts have taken so far. */
uint64_t restir_sms_shift_newton(const void *ctx);

#endif
