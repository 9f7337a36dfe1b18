/* restir_sss.h — method `restir_sss`: ReSTIR for subsurface scattering ([ReSTIR SSS]).
 * At pixels whose primary hit x1 is on a translucent material, each frame resamples paths
 * x0 -> x1 -> x2 -> x3: an entry point x2 on the same shape from BSSRDF importance sampling
 * (every probe hit is a candidate, eq. 10) and a light point x3, then reuses them temporally and
 * spatially (restir.c) with a shift mapping: `reconnection` (copy x2 and x3, Jacobian 1, no
 * visibility test through the object; §3.2.1), `delayed` (replay the probe from the offset x1,
 * take the same intersection index, reconnect to x3; §3.2.2) or `hybrid` (reconnection when
 * |x2 - x1| >= 2 max d or n1 . n2 <= kappa_orientation, else delayed; the offset path must make
 * the same choice; §4.1) or `sequential` (§4.2–4.3: temporal and a first spatial pass with
 * reconnection, then a second spatial pass with delayed reconnection; each reconnection inverts
 * the sample's disk numbers for its new primary hit and finds the entry point's intersection
 * index by tracing that probe, failing when it is not found — the exact mode; `index_shortcut`
 * traces only for the selected sample and lets a later replay pick a random hit when the index is
 * unknown, which is slightly biased).
 * The technique (axis, channel) is part of the path: the sample lives in the extended space
 * (x2, x3, technique), its integrand is f times the technique's balance-heuristic weight
 * P_t p_t(x2) / sum_t' P_t' p_t'(x2), so a replay's Jacobian is that technique's own pdf ratio
 * p_t,x1(x2) / p_t,y1(y2); summed over techniques the weights give back f.
 * Everything else a pixel receives (emission, the boundary's light at later vertices, light
 * reaching x2 indirectly, pixels not on translucent materials) is the `rest` (below), so the
 * image estimates exactly what `pt` does.
 * The state is allocated once per session; a steady-state frame allocates nothing.
 * Refs: [ReSTIR SSS §3–5]; docs/methods.md (restir_sss). */
#ifndef RESTIRD_RESTIR_SSS_H
#define RESTIRD_RESTIR_SSS_H

#include <stdint.h>

#include "core/alias.h"
#include "reuse/gbuffer.h"
#include "image/image.h"
#include "reuse/restir.h"
#include "integrators/frame.h"
#include "integrators/restir_pt.h"
#include "scene/scene.h"

enum restir_sss_shift {
    RESTIR_SSS_RECONNECTION,
    RESTIR_SSS_DELAYED,
    RESTIR_SSS_HYBRID,
    RESTIR_SSS_SEQUENTIAL,
};

/* The target p̂ of a sample, a scalar function of its RGB contribution F. `luminance`: one
 * reservoir per pixel, p̂ = luminance(F). `per_channel`: three reservoirs per pixel, the c-th with
 * p̂ = F_c, each estimating channel c alone and reused on its own (three times the reservoirs and
 * the shifts): the profile's mean free path differs per channel, so F's colour depends on how far
 * the entry point is, and one luminance-resampled sample per pixel carries one such colour into
 * the image as colour noise (docs/benchmarks.md, restir_sss). */
enum restir_sss_target {
    RESTIR_SSS_TARGET_LUMINANCE,
    RESTIR_SSS_TARGET_PER_CHANNEL,
};

/* Who renders the rest of the light: all but what reaches the entry points x2 of the translucent
 * primary surfaces, which the BSSRDF reservoirs carry (direct and, within max_depth >= 2,
 * indirect). `pt`: rest_samples paths per pixel and frame from the same primary hit at the other
 * pixels (reference_pt_radiance), and the emission seen at the translucent ones. `restir_pt`: a
 * restir_pt session (its `opaque_primary`) for the pixels whose primary surface is not
 * translucent and for the emission seen directly everywhere. Each part estimates its own share of
 * the pixel (each with its own primary ray), so the sum is unbiased. `by_scene` (the default)
 * takes restir_pt with temporal reuse on (the real-time profile) where max_depth is in its
 * 1..RESTIR_PT_MAX_DEPTH, else pt (restir_sss_rest_of says why). */
enum restir_sss_rest { RESTIR_SSS_REST_BY_SCENE, RESTIR_SSS_REST_PT, RESTIR_SSS_REST_RESTIR_PT };

struct RESTIRD_STORED_IN_BYTES restir_sss_params {
    enum restir_sss_shift shift;  /* (hybrid) */
    uint32_t candidates;          /* BSSRDF probes per pixel and frame, each with one light sample
                                     shared by all its hits (1) */
    bool temporal;                /* (true) */
    uint32_t temporal_cap;        /* previous M capped at this multiple of the current M (20) */
    uint32_t spatial_neighbors;   /* (4); 0 = no spatial reuse; sequential: half in each of its
                                     two spatial passes (4 = 2 + 2, §5.1), so it must be even */
    float spatial_radius;         /* pixels; 0 = from 2 max(d) projected at the translucent
                                     pixels' mean distance, clamped to [5, 30] (0) */
    float kappa_orientation;      /* hybrid: reconnect when n1 . n2 <= this (0.5) */
    uint32_t max_depth, rr_depth; /* of the paths of indirect samples (from x1 on, as pt counts)
                                     and of the pt rest (64, 3) */
    bool index_shortcut;          /* sequential only: the slightly biased intersection-index
                                     shortcut of §4.3 instead of the exact mode (false) */
    bool paired_spatial;          /* symmetric neighbour pairs whose two shifts serve both pixels
                                     (restir.h, [ReSTIR PT Enhanced Table 1]), half the shifts (true) */
    bool expected_shading;        /* shade with the last spatial pass's expected contribution over
                                     its selection (restir.h; [ReSTIR PT Enhanced Fig. 5]) (true) */
    enum restir_sss_target target; /* (luminance) */
    enum restir_sss_rest rest;    /* (by_scene) */
    uint32_t rest_samples;        /* rest pt: paths a pixel and frame at the pixels whose primary
                                     surface is not translucent, continuations of the same primary
                                     hit, averaged (1; the converge profile: 2) */
};

struct restir_sss_params restir_sss_defaults(void);
/* ERR_INVALID naming the parameter (where = "/params/<name>"). */
bool restir_sss_params_valid(const struct restir_sss_params *p, struct err *err);
const char *restir_sss_shift_name(enum restir_sss_shift s);
/* Reservoirs per pixel and buffer: 1, or 3 for the per_channel target. */
uint32_t restir_sss_layers(const struct restir_sss_params *p);
/* p->rest with by_scene resolved. */
enum restir_sss_rest restir_sss_rest_of(const struct restir_sss_params *p);
/* The rest's restir_pt parameters: restir_pt's defaults (its converge profile when temporal reuse
 * is off, restir_sss's own), opaque_primary and restir_sss's max_depth. */
struct restir_pt_params restir_sss_rest_params(const struct restir_sss_params *p);

struct RESTIRD_STORED_IN_BYTES restir_sss_stats {
    struct restir_pass_stats pass;
    float spatial_radius;          /* the radius used (pixels) */
    double rest_ms;                /* the rest's restir_pt frame (rest restir_pt) */
};

struct restir_sss_state {
    struct restir_session rs;  /* G-buffers with their primary surfaces, restir_sss_layers reservoirs */
    bool has_rest;                 /* rest restir_pt: */
    struct restir_pt_state rest;   /*   its session, */
    struct image rest_image;       /*   and its frame, to which the initial pass adds the rest */
};

#define RESTIR_SSS_MAX_REST_SAMPLES 64u   /* rest_samples's bound */
#define RESTIR_SSS_RESERVOIR_BYTES 72u   /* per reservoir; a pixel has restir_sss_layers of them */

/* Sized for params' target and rest, which a session keeps; the pair scratch only for paired
 * spatial reuse (a render asking for another target or rest, or for pairs the session lacks, is
 * refused). */
bool restir_sss_init(struct restir_sss_state *st, const struct scene *scene, const struct restir_sss_params *params,
                     uint32_t width, uint32_t height, struct err *err);
void restir_sss_destroy(struct restir_sss_state *st);
/* Both sessions' history forgotten. */
void restir_sss_reset(struct restir_sss_state *st);
uint64_t restir_sss_bytes_planned(const struct restir_sss_params *params, const struct scene *scene, uint32_t width,
                                  uint32_t height);


bool restir_sss_render(struct restir_sss_state *st, const struct restir_sss_params *params,
                       const struct method_frame *f, struct image *out, struct restir_sss_stats *stats,
                       struct err *err);

/* For tests: G-buffers and initial reservoirs only, a bound context (RESTIR_SSS_CTX_BYTES) for
 * calling restir_sss_ops directly, and the decoded sample. */
#define RESTIR_SSS_CTX_BYTES 256u
bool restir_sss_initial_only(struct restir_sss_state *st, const struct restir_sss_params *params,
                             const struct method_frame *f, struct err *err);
void restir_sss_bind(struct restir_sss_state *st, const struct restir_sss_params *params,
                     const struct method_frame *f, void *ctx);
extern const struct restir_ops restir_sss_ops;
struct restir_sss_info {
    uint32_t x2_shape, x2_prim;
    float x2_b1, x2_b2;
    int axis, channel, hit;   /* hit 15 = unknown (sequential shortcut) */
    float u_radius, u_angle;
    bool reconnect;   /* the hybrid criterion on the sample's own path */
    bool indirect;    /* x3 is the surface after the entry point, not a light point */
    bool x3_fixed;    /* ... and not Lambertian: the delayed shift fails, the hybrid reconnects */
    struct vec3 F;
};
/* `ctx` bound, `pixel` the element's own (current-frame) pixel. */
void restir_sss_info(const void *ctx, const void *elem, uint32_t pixel, struct restir_sss_info *out);

#endif
