/* restir_pt.h — method `restir_pt`: ReSTIR path tracing with the Enhanced improvements.
 * Each pixel keeps one resampled path (from its G-buffer primary hit on) in a 64-byte reservoir;
 * a frame runs G-buffer -> initial path sampling -> temporal reuse -> spatial reuse -> shade.
 * Paths live in lobe-indexed primary sample space (PSS) and move between pixels and frames by the
 * hybrid shift: random replay until the first two consecutive connectable vertices, then
 * reconnection to the base path's vertex x_k (Jacobian: [ReSTIR PT Enhanced eq. 4]).
 * Options (each a session parameter, defaults as [ReSTIR PT Enhanced]): dual ray-footprint
 * threshold (eq. 5, c = 0.02) instead of a near-field distance; PDF-based connectability (eq. 26)
 * instead of lobe roughness; Russian roulette that changes only the initial source pdf (§6);
 * RIS-based NEE with M candidates and the M-sample MIS weight (§5); direct light in the same
 * reservoir as indirect (DI/GI unification, §7).
 * The state is allocated once per session; a steady-state frame allocates nothing.
 * Refs: [ReSTIR PT Enhanced §1–8]; Lin et al. 2022 (ReSTIR PT, GRIS);
 * docs/methods.md (restir_pt). */
#ifndef RESTIRD_RESTIR_PT_H
#define RESTIRD_RESTIR_PT_H

#include <stdint.h>

#include "core/alias.h"
#include "reuse/gbuffer.h"
#include "image/image.h"
#include "reuse/restir.h"
#include "integrators/frame.h"
#include "scene/scene.h"
#include "integrators/sms.h"

struct RESTIRD_STORED_IN_BYTES restir_pt_params {
    uint32_t max_depth;          /* as `pt`: scattering events before the path stops (64) */
    uint32_t candidates;         /* initial paths per pixel and frame, resampled into its
                                    reservoir (1; RESTIR_PT_CANDIDATES_BY_SCENE:
                                    restir_pt_candidates_by_scene) */
    uint32_t rr_depth;           /* Russian roulette from this vertex on (1) */
    bool rr;                     /* Russian roulette on initial paths (decoupled from PSS) */
    uint32_t nee_candidates;     /* RIS NEE candidates; 1 = plain NEE, 0 = no NEE
                                    (RESTIR_PT_NEE_BY_SCENE: restir_pt_nee_by_scene) */
    bool unify_di;               /* direct light resampled with indirect (true) */
    bool temporal;               /* temporal reuse (true) */
    uint32_t temporal_cap;       /* previous M capped at this multiple of the current M (20) */
    uint32_t temporal_cap_replay; /* the cap instead in the MIS weights of a sample without a
                                    reconnection vertex (k = 0: every shift of it is random replay,
                                    which keeps k); 0 = temporal_cap (0) */
    bool history_check;          /* the G-buffer's history check of the motion vectors in frames
                                    where something moved (gbuffer.h; true) */
    float jitter_walk;           /* the primary ray's position in the pixel moves by at most this
                                    many pixels per axis and frame (gbuffer.h); 0 = a fresh
                                    position every frame (0.005) */
    uint32_t emission_samples;   /* rays per frame for the emission seen directly in a pixel whose
                                    area holds an emitter's edge (gbuffer.h); 1 = the primary
                                    ray's own (16) */
    uint32_t spatial_neighbors;  /* per round (3); 0 = no spatial reuse */
    float spatial_radius;        /* pixels; 0 = by resolution (restir_radius_auto; 0) */
    uint32_t spatial_rounds;     /* (1) */
    float reject_normal_cos;     /* a neighbour whose normal's cosine with the pixel's is below
                                    this is not reused; 0 = no normal test (0) */
    float reject_depth;          /* nor one whose hit distance differs by more than this fraction
                                    of the larger; 0 = no depth test (0; restir_neighbours_similar) */
    bool paired_spatial;         /* neighbours paired so a pair's shifts serve both (true; restir.h) */
    bool expected_shading;       /* shade with the last spatial pass's expected contribution over
                                    its selection instead of the selected sample's F W: colour
                                    noise reduction, [ReSTIR PT Enhanced Fig. 5] (true; restir.h) */
    bool footprint;              /* dual footprint threshold (eq. 5) vs near-field distance */
    float footprint_c;           /* c of eq. 5 (0.02) */
    float near_distance;         /* without footprint: minimum segment length, fraction of the
                                    scene's bounding radius (0.03) */
    bool pdf_connect;            /* PDF-based connectability (eq. 26) vs lobe roughness */
    float roughness_min;         /* alpha_min of both tests (0.2) */
    enum pt_subset subset;       /* the light transport the image holds, split as pt's (sms.h):
                                    all, the caustic paths specular manifold sampling owns, or the
                                    rest (all) */
    bool opaque_primary;         /* only the pixels whose primary surface is not translucent: the
                                    share of the image restir_sss's `rest` takes from restir_pt,
                                    whose BSSRDF paths at translucent primary surfaces it leaves
                                    to restir_sss; translucent surfaces further along a path are
                                    the translucent BSDF, as for `pt` (false: a scene with
                                    translucent materials is refused) */
};

/* nee_candidates of the defaults: chosen from the session's scene at restir_pt_init. */
#define RESTIR_PT_NEE_BY_SCENE UINT32_MAX
/* candidates 0 (the converge profile's): chosen from the session's scene at restir_pt_init. */
#define RESTIR_PT_CANDIDATES_BY_SCENE 0u

/* The longest paths a reservoir holds (its length field). */
#define RESTIR_PT_MAX_DEPTH 126u

struct restir_pt_params restir_pt_defaults(void);
/* The converge profile over p (the method's `--profile converge`, and the rest of restir_sss and
 * restir_sms when their frames are independent: restir_pt_rest_params): frames that are
 * independent draws. */
void restir_pt_converge(struct restir_pt_params *p);
/* The parameters of a restir_pt session that renders the light another method leaves (restir_sss's
 * and restir_sms's `rest`): the defaults, or the converge profile when that method's frames are to
 * be independent (its temporal reuse off), and the method's max_depth. The caller says which light
 * (subset, opaque_primary). */
struct restir_pt_params restir_pt_rest_params(bool independent_frames, uint32_t max_depth);
/* The RIS NEE candidates a scene gets by default: 4 with two or more emitters (emissive
 * shapes; a lit environment counts as one), 1 (plain NEE) with a single one. */
uint32_t restir_pt_nee_by_scene(const struct scene *scene);
/* The initial paths a scene gets for candidates 0: 8 where a shape's material is near-specular
 * below roughness_min (scene_has_near_specular: paths through it are replayed by every shift, so
 * a pixel has only the paths it traced itself), else 1. */
uint32_t restir_pt_candidates_by_scene(const struct scene *scene, float roughness_min);
/* ERR_INVALID naming the parameter (where = "/params/<name>") when out of range. */
bool restir_pt_params_valid(const struct restir_pt_params *p, struct err *err);

/* Per-session state: two G-buffers (current, previous), each keeping its primary surfaces
 * (gbuffer_keep_surfaces: the initial pass and every shift read x_1 from there), and two
 * reservoir buffers (the frame's working buffer and the history the next frame reuses). */
struct restir_pt_state {
    struct restir_session rs;  /* G-buffers with hit points, one reservoir per pixel, pairs */
    uint32_t shape_count;
    uint32_t *prim_first;      /* shape -> first scene-wide primitive id (shape_count + 1) */
    uint32_t nee_by_scene;     /* restir_pt_nee_by_scene of the scene at init: fixed for the session,
                                  as the integrand's MIS weights must not change between frames */
    uint32_t candidates_by_scene; /* restir_pt_candidates_by_scene at init */
};

/* Bytes of one reservoir (the payload included). */
#define RESTIR_PT_RESERVOIR_BYTES 64u

/* The buffers the parameters use: the pair scratch only for paired spatial reuse (a render that
 * asks for it from a session made without is refused). */
bool restir_pt_init(struct restir_pt_state *st, const struct scene *scene, const struct restir_pt_params *params,
                    uint32_t width, uint32_t height, struct err *err);
void restir_pt_destroy(struct restir_pt_state *st);
/* What restir_pt_init allocates for these parameters, size and scene (before allocating it). */
uint64_t restir_pt_bytes_planned(const struct restir_pt_params *params, uint32_t width, uint32_t height,
                                 const struct scene *scene);


/* Renders one frame into `out` (width x height) and makes it the history of the next. */
bool restir_pt_render(struct restir_pt_state *st, const struct restir_pt_params *params,
                      const struct method_frame *f, struct image *out, struct restir_pass_stats *stats,
                      struct err *err);
/* The same as another method's rest (restir_sms, restir_sss): the frame's rays and non-finite
 * pixels added to `into`, the caller's counters. */
bool restir_pt_render_rest(struct restir_pt_state *st, const struct restir_pt_params *params,
                           const struct method_frame *f, struct image *out, struct restir_pass_stats *into,
                           struct err *err);

/* For tests of the shift: the G-buffers and initial reservoirs of a frame (no reuse), then the
 * shift of one reservoir element between domains. restir_pt_bind fills an opaque context of
 * RESTIR_PT_CTX_BYTES bytes valid while st, params and f live. */
#define RESTIR_PT_CTX_BYTES 512u
bool restir_pt_initial_only(struct restir_pt_state *st, const struct restir_pt_params *params,
                            const struct method_frame *f, struct err *err);
void restir_pt_bind(struct restir_pt_state *st, const struct restir_pt_params *params, const struct method_frame *f,
                    void *ctx);
extern const struct restir_ops restir_pt_ops;
/* Decoded fields of a reservoir element (tests and stats). */
struct restir_pt_info {
    uint32_t length;      /* path vertices after the camera (x_1 .. x_d) */
    uint32_t rc;          /* reconnection vertex index k, 0 = none (random replay only) */
    bool nee;             /* the last vertex was sampled by NEE */
    struct vec3 F;        /* the path's contribution in its own pixel */
};
void restir_pt_info(const void *elem, struct restir_pt_info *out);

#endif
