/* restir_bdpt.h — ReSTIR BDPT ([ReSTIR BDPT §4–5]). The lightweight variant ("Lightweight BDPT"):
 * the techniques s = 0 (emitter hits), s = 1 (next-event estimation) and t = 1 (light tracing),
 * no vertex connections, resampled in the extended path space (path, technique) with the target
 * p̂ = lum(w_{s,t} f / p), w the MIS weight among these three techniques only. The full variant
 * adds every vertex connection (s >= 2, t >= 2) as `bdpt` makes them — each camera vertex joined
 * to one vertex drawn uniformly from a light vertex cache (LVC) of this frame's light subpaths —
 * and weighs all techniques with bdpt's recursive MIS (bdpt_mis.h), so its candidates are
 * exactly bdpt's contributions.
 *
 * Per frame: N_L light subpaths start on emitters in proportion to power; every connectable
 * light vertex is connected to the camera (t = 1). The samples that land in a pixel are
 * bucketed per pixel by a counting sort over pixel ids (prefix sum, in light-subpath order,
 * independent of the thread count) and merged into that pixel's reservoir next to its own
 * camera-path candidates, each with resampling weight lum(C) where C already carries the
 * light-tracing estimator's 1/N_L ([ReSTIR BDPT eq. 26]). A t = 1 sample whose secondary hit x_2 is
 * not rough (its light-side scattering lobe was delta) is caustic and goes to the pixel's
 * separate caustic reservoir (§5.1); the image is the sum of both reservoirs' estimates.
 *
 * Caustic reservoirs are reused temporally (Appendix A): each previous caustic sample is
 * replayed with its light subpath's random numbers in the current frame and lands in the pixel
 * its x_1 projects to (a counting sort again), with the generalized balance heuristic of
 * eqs. 51–52 over {previous reservoir, current initial sample}; a reservoir's confidence is 1
 * plus that of the previous caustic reservoir its primary hit maps to (eq. 27), capped at
 * temporal_cap, or at moving_cap in a frame whose shapes or lights moved (restir_bdpt.c).
 *
 * Non-caustic reuse (`reuse`, off by default; both variants): temporal reuse along a
 * G-buffer's motion vectors and spatial reuse through restir.c's passes. Camera-side samples
 * (s = 0, s = 1) shift by the camera-subpath part of [ReSTIR BDPT]'s bidirectional hybrid shift
 * (§6.1): a sample whose path has a reconnectable pair (x_{k-1}, x_k), k >= 2, both vertices
 * with only rough lobes, replays its camera subpath through the target pixel up to x'_{k-1} and
 * joins it to x_k, keeping the rest of the path (struct restir_bdpt_rc), with the Jacobian of
 * Appendix C and the MIS weight recomputed recursively from the suffix's constants (§6.2,
 * restir_bdpt_mis_reconnect); a sample without such a pair shifts by random replay of its camera
 * subpath (Jacobian 1 in primary sample space), its lightweight MIS weight recomputed on the new
 * path, and must stay without one. Russian roulette is decoupled from the primary sample space
 * for these samples ([ReSTIR PT Enhanced §6]): it divides the initial resampling weight, never the
 * contribution, and a shift never rolls it. Between frames whose scenes differ the kept suffix
 * would carry the other scene's light: there the suffix is traced again from x_k along w_k with
 * the sample's own random numbers (as ReSTIR PT does); an s = 1 sample whose light sample
 * leaves x_k itself draws that light sample again from its random numbers. A t = 1 sample's
 * light subpath is replayed and the shift succeeds only when it lands in the target pixel again
 * and is still non-caustic; one whose x_2 has only rough lobes instead shifts by the reverse
 * hybrid shift (§6.1): its light subpath is replayed up to x'_2 and joined to the surface the eye
 * sees through the same sub-pixel position of the target pixel, so it can move to a neighbour.
 *
 * The full variant's connections (s >= 2, t >= 2) shift as [ReSTIR BDPT §5] describes: the light
 * subpath by random replay in the target frame's scene (its random numbers are those of light
 * subpath rc.light_path of the origin frame), the camera subpath by the hybrid shift above or by
 * random replay, joined to the replayed light vertex — at x_k itself when x_k is the connecting
 * camera vertex. Its initial sample's unbiased contribution weight carries 1 / p_L = |LVC| / N_L
 * (eq. 25) in its resampling weight, so the target is the path's own. The full variant's
 * reconnection shifts (connections and camera-side samples alike) keep the suffix and recompute
 * bdpt's MIS weight over all techniques from three constants of it (the recursive reconnection
 * MIS, restir_bdpt_internal.h); a light sample leaving x_k itself is drawn again. A per-pixel cache keeps
 * the light vertex of each pixel's connection in this frame's scene, as it keeps x_2 of
 * light-traced samples.
 *
 * Two biased switches, off by default: `copy_mis` keeps the MIS weight a sample was drawn with
 * through its reconnection shifts (§6.4), and `reject_unshiftable` drops the non-caustic t = 1
 * candidates whose x_2 cannot be joined to the pixel's primary hit (§7.2). The paper needs the
 * rejection because it shifts t = 1 samples to a visibility buffer's hit; here a t = 1 sample
 * shifts to the surface seen through its own sub-pixel position, so an unbiased session needs
 * no rejection and the switch is there to measure what it costs.
 *
 * Method `restir_bdpt` (renderer/session/view.c) renders frames with exactly this. The full variant's
 * caustic reservoirs are reused as the lightweight one's, with the full MIS weight of the
 * replayed t = 1 sample; `copy_mis` is refused with it.
 * Scenes with environment light or translucent materials are refused, as by `bdpt`. */
#ifndef RESTIRD_RESTIR_BDPT_H
#define RESTIRD_RESTIR_BDPT_H

#include <stddef.h>
#include <stdint.h>

#include "core/alias.h"
#include "integrators/bdpt.h"
#include "scene/camera.h"
#include "core/err.h"
#include "reuse/gbuffer.h"
#include "image/image.h"
#include "reuse/restir.h"
#include "integrators/frame.h"
#include "scene/scene.h"

#define RESTIR_BDPT_MAX_DEPTH 250u  /* a sample's vertex count is kept in 8 bits */

enum restir_bdpt_variant { RESTIR_BDPT_LIGHTWEIGHT, RESTIR_BDPT_FULL };
const char *restir_bdpt_variant_name(enum restir_bdpt_variant v);

struct RESTIRD_STORED_IN_BYTES restir_bdpt_params {
    enum restir_bdpt_variant variant;  /* lightweight (default) or full */
    uint32_t max_depth;        /* scattering events of a full path, 1..RESTIR_BDPT_MAX_DEPTH (64, as bdpt) */
    uint32_t rr_depth;         /* Russian roulette after this many bounces of a subpath (3) */
    uint32_t light_paths;      /* N_L per frame; 0 (default) = automatic (restir_bdpt_light_paths) */
    uint32_t lt_capacity;      /* light-traced samples kept per light subpath on average, 1..64 (8) */
    uint32_t lvc_capacity;     /* full variant: light vertices cached per light subpath on average,
                                  1..64 (8, as bdpt) */
    enum bdpt_heuristic heuristic;  /* power (default) or balance */
    bool caustic_temporal;     /* temporal reuse of the caustic reservoirs (true) */
    uint32_t temporal_cap;     /* caustic confidence capped at this absolute value, 1..65535 (20); with
                                  `reuse`, the non-caustic history's at this multiple of the current */
    uint32_t moving_cap;       /* the caustic confidence cap instead in a frame whose shapes or lights
                                  moved or changed since the previous frame, 1..65535 (1: the history
                                  and the new samples weigh alike there; docs/benchmarks.md) */
    bool reuse;                /* temporal and spatial reuse of the non-caustic reservoir (true) */
    bool reuse_temporal;       /* with reuse: the non-caustic reservoirs take the previous frame's as
                                  history (true); false: each frame's reuse is spatial only */
    bool history_check;        /* with reuse_temporal: a pixel whose previous pixel (along the motion
                                  vector) saw another surface takes no history (true; gbuffer.h) */
    uint32_t emission_samples; /* with reuse: rays a frame for the emission seen directly in a pixel
                                  an emitter's edge crosses (gbuffer.h), taken out of the camera
                                  subpaths' candidates; 1 = the camera subpath's own, 1..256 (16) */
    uint32_t spatial_neighbors; /* with reuse: neighbours per pixel and round, 0..32 (2) */
    uint32_t spatial_rounds;   /* with reuse and spatial neighbours: spatial passes in a row, each
                                  reusing the previous one's output, 1..8 (1) */
    float spatial_radius;      /* with reuse: pixels, (0, 256] (30) */
    bool paired_spatial;       /* with reuse: neighbours paired so a pair's shifts serve both (true;
                                  restir.h) */
    bool expected_shading;     /* with reuse and spatial neighbours: the non-caustic reservoirs add the
                                  spatial pass's expected contribution over its selection instead of
                                  the selected sample's F W ([ReSTIR PT Enhanced Fig. 5]; restir.h) */
    bool camera_reconnect;     /* with reuse: camera-side samples reconnect (the hybrid shift); false:
                                  they shift by random replay alone (true) */
    bool copy_mis;             /* with reuse, lightweight variant: a reconnection shift keeps the base
                                  path's MIS weight instead of recomputing it ([ReSTIR BDPT §6.4]; biased,
                                  false) */
    bool reject_unshiftable;   /* drop the non-caustic t = 1 candidates whose x_2 cannot reach the
                                  pixel's primary hit ([ReSTIR BDPT §7.2]; biased, false) */
};

struct restir_bdpt_params restir_bdpt_defaults(void);
/* Ranges; errors name /params/<key>; `copy_mis` needs `reuse` and the lightweight variant. */
bool restir_bdpt_params_valid(const struct restir_bdpt_params *p, struct err *err);

/* A light-traced (t = 1) sample: its pixel, its contribution C (MIS weight and 1/N_L included). */
struct restir_bdpt_lt_sample {
    struct vec3 F;
    uint32_t pixel;
    uint32_t light_path;       /* index of its light subpath in the frame */
    uint16_t depth;            /* light vertices up to x_1 */
    uint8_t caustic;           /* 1 when x_2 is not rough */
    uint8_t hybrid;            /* with reuse: x_2 is a surface with only rough lobes (depth >= 2), so
                                  the sample shifts by the reverse hybrid shift (restir_bdpt_reuse.c) */
};

/* A reservoir: the shared head (W, M, technique in `bits`), the selected sample's contribution
 * C in its own pixel (primary sample space, so p̂ = lum(C)). */
struct restir_bdpt_reservoir {
    struct restir_head head;
    struct vec3 F;
    uint32_t light_path;       /* t = 1: its light subpath; else UINT32_MAX */
    uint32_t origin_frame;     /* t = 1: the frame whose random numbers trace that subpath */
};

/* Where a camera-side sample (s = 0, s = 1) reconnects under the hybrid shift ([ReSTIR BDPT §6.1],
 * after Lin et al. 2022): x_k is the first vertex with k >= 2 whose predecessor and itself have
 * only rough (non-delta) lobes, k <= the last camera vertex that scatters or connects to the light;
 * k = 0 when the path has no such pair (it shifts by random replay alone). A shift replays the
 * camera subpath up to x'_{k-1} and joins it to this x_k; everything past x_k is kept:
 *   - `L`: what x_k's outgoing direction w_k carries back, Russian roulette and the MIS weight
 *     left out: the suffix throughput times the emission (s = 0), or times f |cos| Le / p_light of
 *     the last vertex's light sample (s = 1), or, when x_k itself is that last vertex, Le (s = 0:
 *     w_k hits the emitter) or Le / p_light (s = 1: w_k is the light sample's direction);
 *   - `mis_a`, `mis_b`, `mis_c`: the suffix's part of the MIS weight, so that the shifted path's
 *     weight follows from its new prefix alone (the recursive reconnection MIS of
 *     [ReSTIR BDPT §6.2]; lightweight: restir_bdpt_mis_reconnect's two constants, and mis_c 1
 *     when a vertex past x_k is a caustic caster, else 0 (the path keeps the t = 1 technique whatever
 *     its new prefix: rbdpt_mis_vertex); full: the weight is
 *     1 / (1 + a dVCM + b dVC + c) with dVCM, dVC those after x_k's scattering, which the suffix
 *     maps affinely onto the last vertex's — see restir_bdpt_internal.h);
 *   - `pdf`: p_{k-1}(w_{k-1}) |cos_k| / d^2 p_k(w_k) (p_k = 1 for a light sample's direction), the
 *     reconnection's Jacobian denominator ([ReSTIR BDPT Appendix C]).
 * With `copy_mis` `L` carries the MIS weight of the path the sample was drawn as, which its
 * shifts keep (mis_a and mis_b are then unused).
 * A light-traced sample (t = 1) of the reverse hybrid shift's class (non-caustic, x_2 a surface
 * with only rough lobes) has k = 1, its sub-pixel position in b1, b2 and in `pdf` the density
 * p_2(w) |cos_1| / d^2 / p_camera,A(x_1) of its x_1 per unit of image area (with `copy_mis`, the
 * MIS weight its shifts keep in mis_a); other t = 1 samples k = 0.
 * A connection (s >= 2, full variant) has its camera subpath's x_k (k <= the connecting vertex;
 * when equal, `pdf` leaves p_k out as for a light sample: the connection fixes w_k, and `L` is
 * unused) and its light subpath in `light_path`; `L` is what w_k carries back: the suffix
 * throughput times the connection's contribution, MIS weight left out. */
struct restir_bdpt_rc {
    uint32_t k;
    union {
        uint32_t shape;
        /* t = 1 of the reverse hybrid shift's class (k = 1): the pixel whose x_2 cache entry (of
         * the render that placed the sample there) holds its x_2 — a hint, checked against the
         * entry's key (restir_bdpt_reuse.c). */
        uint32_t x2_pixel;
    };
    uint32_t prim;
    float b1, b2;              /* x_k's point code (surface_at) */
    float wk_u, wk_v;          /* octahedral w_k (world) */
    struct vec3 L;
    float pdf;
    float mis_a, mis_b, mis_c; /* the suffix's MIS constants (lightweight: a and b, and in c its caster
                                  flag; full: all three) */
    union {
        uint32_t light_path;   /* full variant, s >= 2: the light subpath the connection joins (frame
                                  r.origin_frame) */
        /* Any other sample: the render (x2c_tick) whose shift into the pixel the sample sits in
         * computed its F and rc there; 0 for an initial candidate (restir_bdpt_reuse.c). */
        uint32_t eval_tick;
    };
};

/* A non-caustic reservoir: the reservoir and its sample's reconnection. */
struct restir_bdpt_path {
    struct restir_bdpt_reservoir r;
    struct restir_bdpt_rc rc;
};

/* A previous frame's caustic reservoir shifted into the current frame by random replay: the
 * pixel it lands in, its contribution there and its resampling weight ([ReSTIR BDPT eq. 51]). */
struct restir_bdpt_shifted {
    struct vec3 F;
    float w;
    uint32_t pixel;
    uint32_t light_path, origin_frame;
    uint16_t depth, valid;
};

/* Bytes of one reservoir: a pixel has a non-caustic one (with its reconnection: 88 bytes) and
 * two caustic ones (the current and the previous frame's, 28 bytes each); with `reuse` two more
 * non-caustic ones (history and spatial output). */
#define RESTIR_BDPT_RESERVOIR_BYTES 28u
#define RESTIR_BDPT_PATH_BYTES 88u

/* head.bits: technique s in the low byte (0, 1, or 0xff for t = 1), path vertices above. */
#define RESTIR_BDPT_TECH_LT 0xffu

struct restir_bdpt_state {
    uint32_t width, height;
    uint32_t auto_light_paths;               /* what light_paths 0 means in this session (0: none) */
    struct bdpt_blocks lb;                   /* region: light tracing samples per block; rays: 3 per
                                              * block (intersect, occluded rays, light vertices) */
    struct restir_bdpt_lt_sample *lt;        /* lb.blocks * lb.region, per-block regions */
    struct restir_bdpt_lt_sample *lt_sorted; /* lb.blocks * lb.region, by pixel */
    uint32_t *pixel_first;                   /* width * height + 1 (prefix sums) */
    struct restir_bdpt_path *res;            /* width * height, non-caustic */
    struct restir_bdpt_reservoir *caustic;   /* width * height, caustic (this frame's) */
    struct restir_bdpt_reservoir *caustic_prev; /* width * height, the previous frame's */
    bool has_history;
    struct restir_bdpt_shifted *shifted;        /* width * height, by source pixel */
    struct restir_bdpt_shifted *shifted_sorted; /* width * height, by landing pixel */
    uint32_t *shift_first;                      /* width * height + 1 */
    /* With reuse: the previous frame's final non-caustic reservoirs, the spatial pass's output,
     * and the G-buffers whose motion vectors temporal reuse follows (gbuf[gcur] this frame's, the
     * other the previous frame's, which the history check reads). */
    struct restir_bdpt_path *res_prev, *res_spatial;
    struct gbuffer gbuf[2];
    uint32_t gcur;
    bool gbuf_history;
    void *pair_scratch;                         /* with reuse and paired_spatial: restir.c's pairs */
    /* With reuse: per pixel the x_2 of its sample of the reverse hybrid shift's class in this
     * frame's scene, so that the shifts of one sample replay its light subpath once (restir_bdpt_reuse.c).
     * x2c_prev is the previous render's, read-only during a render (its samples, now the history,
     * find their x_2 there through rc.x2_pixel), or from the second spatial round on the previous
     * round's (the samples it moved find theirs there likewise); the two halves of one allocation
     * (x2c_base) swap at each render and each spatial round after the first. x2c_tick numbers the
     * renders; entries made since render x2c_tick_from were made in the scene x2c_scene with seed
     * x2c_seed and the light-subpath parameters x2c_params, and stay valid while these do not
     * change. */
    struct rbdpt_x2_entry *x2c, *x2c_prev, *x2c_base;
    uint32_t x2c_tick, x2c_tick_from;
    const struct scene *x2c_scene;
    uint64_t x2c_seed;
    uint32_t x2c_params[4];
    /* Renders after still_from saw the same scene object, camera, seed and parameters as the
     * render before them (last_camera, last_params: the previous render's). */
    uint32_t still_from;
    /* Set, no render counts as still: every shift and caustic replay is computed in full. The
     * shortcuts must not change an image, and tests/unit/test_restir_bdpt.c renders with them and
     * without them to show it. false after init. */
    bool still_withheld;
    struct camera_desc last_camera;
    struct restir_bdpt_params last_params;
    /* The full variant's light vertex cache, in bdpt's layout: per block a region of lvb.region
     * vertices, lvb.count of them used (lvb has no ray counters), lvc_first the prefix sums
     * (blocks + 1). NULL and empty otherwise. */
    struct bdpt_light_vertex *lvc;
    uint32_t *lvc_path;        /* with reuse: per slot, the light subpath of the vertex (a connection's
                                  shift replays it) */
    struct bdpt_blocks lvb;
    uint64_t *lvc_first;
};

struct RESTIRD_STORED_IN_BYTES restir_bdpt_stats {
    double light_ms, sort_ms, camera_ms;
    uint64_t light_subpaths;    /* N_L */
    uint64_t light_vertices;    /* connectable light vertices reached, each connected to the eye (t = 1):
                                   what the full variant's light vertex cache holds */
    uint64_t lvc_dropped;       /* full: vertices that found their block's LVC region full (a bias) */
    uint64_t connections;       /* full: camera-to-LVC connections made (visible, non-zero) */
    uint64_t light_traced;      /* t = 1 samples that reached a pixel */
    uint64_t caustic_samples;   /* of which caustic */
    uint64_t lt_dropped;        /* samples that found their block's region full (a bias; see bdpt.h) */
    uint64_t lt_unshiftable;    /* reject_unshiftable: non-caustic t = 1 candidates dropped (a bias) */
    uint64_t camera_candidates; /* s = 0 and s = 1 candidates with a non-zero contribution */
    uint64_t rejected;          /* candidates refused for a non-finite weight */
    uint64_t caustic_shifts;            /* random-replay shifts: previous caustic samples into this
                                           frame, and this frame's selected ones back (eq. 52) */
    uint64_t caustic_replay_failed;     /* forward shifts whose replay ended, missed the eye or lost
                                           its vertex */
    uint64_t caustic_not_caustic;       /* forward shifts whose replayed x_2 turned rough */
    uint64_t caustic_inverse_failed;    /* backward shifts that failed (no predecessor) */
    double reuse_ms;            /* with reuse: G-buffer, temporal and spatial passes */
    uint64_t reuse_shifts;      /* with reuse: shifts of non-caustic samples, and those that failed */
    uint64_t reuse_shift_failures;
    uint64_t reuse_reconnections; /* with reuse: shifts of camera-side samples that joined the
                                     replayed prefix to the sample's x_k (the hybrid shift) */
    uint64_t reservoir_bytes;
    uint64_t rays_intersect, rays_occluded;
};

/* The light subpaths a frame traces: light_paths when set; otherwise the pixel count, except in a
 * lightweight session whose scene has no caustic caster (no delta or near-specular lobe), which
 * traces none: its MIS leaves the t = 1 technique out on every path. */
uint32_t restir_bdpt_light_paths(const struct restir_bdpt_params *p, const struct scene *scene, uint32_t width,
                                 uint32_t height);
uint64_t restir_bdpt_bytes_planned(const struct restir_bdpt_params *p, const struct scene *scene, uint32_t width,
                                   uint32_t height);
bool restir_bdpt_init(struct restir_bdpt_state *st, const struct scene *scene, const struct restir_bdpt_params *p,
                      uint32_t width, uint32_t height, struct err *err);
void restir_bdpt_destroy(struct restir_bdpt_state *st);
/* Forgets the history. */
void restir_bdpt_reset(struct restir_bdpt_state *st);
size_t restir_bdpt_bytes(const struct restir_bdpt_state *st);
/* The buffers by name (their sum is restir_bdpt_bytes): the three reservoir buffers (non-caustic,
 * caustic, previous caustic), the light-traced samples (per block, and sorted by pixel), the
 * caustic shifts (by source and by landing pixel), the two per-pixel bucket tables, the
 * per-block counters. */
size_t restir_bdpt_reservoir_bytes(const struct restir_bdpt_state *st);
size_t restir_bdpt_x2_bytes(const struct restir_bdpt_state *st);
size_t restir_bdpt_lt_bytes(const struct restir_bdpt_state *st);
size_t restir_bdpt_shift_bytes(const struct restir_bdpt_state *st);
size_t restir_bdpt_bucket_bytes(const struct restir_bdpt_state *st);
size_t restir_bdpt_block_bytes(const struct restir_bdpt_state *st);
size_t restir_bdpt_lvc_bytes(const struct restir_bdpt_state *st);   /* 0 for the lightweight variant */
size_t restir_bdpt_pair_bytes(const struct restir_bdpt_state *st);  /* 0 without paired spatial reuse */

bool restir_bdpt_render(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                        const struct method_frame *f, struct image *out, struct restir_bdpt_stats *stats,
                        struct err *err);

/* For tests: the random-replay shift of a caustic sample (light subpath `light_path` traced with
 * the random numbers of frame `origin_frame`, its vertex `depth`) into the view of f->scene and
 * f->camera: the pixel it lands in and its contribution there; false when the shift fails. */
bool restir_bdpt_caustic_replay(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                                const struct method_frame *f, uint32_t origin_frame, uint32_t light_path,
                                uint32_t depth, uint32_t *pixel, struct vec3 *F);

/* For tests, with reuse: the non-caustic sample that the frame just rendered left in `pixel`
 * shifted into pixel `to` of the same frame (f's scene and camera), or with f_to of a frame of
 * f_to's scene and camera (as the previous frame: a scene that differs makes a reconnected
 * sample's suffix be traced again there), and back. target[0..2]: its
 * target, the shifted one's, the one shifted back (0 where a shift failed); *jj: the product of
 * the two Jacobians. Returns the shift kind: 2 the hybrid shift (camera side), 1 the reverse
 * hybrid shift (t = 1), 0 random replay, 3 a connection (s >= 2) by random replay of both
 * subpaths, 4 a connection by the hybrid shift; -1 when the pixel holds no sample. */
int restir_bdpt_shift_round_trip(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                                 const struct method_frame *f, const struct method_frame *f_to,
                                 uint32_t pixel, uint32_t to, float target[3], float *jj);
/* For tests, with reuse: the reconnected sample (rc.k >= 2) the frame just rendered left in
 * `pixel` shifted into pixel `to` of the same frame twice — with its suffix's constants (L and
 * the recursive reconnection MIS) and with the suffix traced again from x_k — giving target[0],
 * jacobian[0] and target[1], jacobian[1]. Returns the shift kind (2 or 4, as
 * restir_bdpt_shift_round_trip), -1 when the pixel holds no such sample. */
int restir_bdpt_shift_retrace_pair(struct restir_bdpt_state *st, const struct restir_bdpt_params *p,
                                   const struct method_frame *f, uint32_t pixel, uint32_t to, float target[2],
                                   float jacobian[2]);

/* The lightweight MIS state a subpath carries (SmallVCM's dVCM / dVC restricted to the
 * techniques s = 0, s = 1, t = 1; see restir_bdpt.c). Exposed for the unit test. With `full`
 * set (the full variant) nothing is left out and the same functions compute bdpt_mis.h's
 * weights over all techniques: dVCM keeps naming a technique after the first scattering. */
struct restir_bdpt_mis {
    float dvcm, dvc;
    bool near;                 /* no scattering yet (or `full`): dvcm still names a wanted technique */
    bool full;
    /* Lightweight: a vertex so far is a caustic caster (rbdpt_mis_vertex). Only such a path
     * keeps the t = 1 technique; the others are weighed over s = 0 and s = 1 alone. */
    bool caster;
};
struct restir_bdpt_mis restir_bdpt_mis_camera_start(float light_paths, float camera_pdf_w, bool power);
struct restir_bdpt_mis restir_bdpt_mis_light_start(float direct_pdf_a, float emission_pdf_w, float cos_light,
                                                   bool power);
void restir_bdpt_mis_hit(struct restir_bdpt_mis *m, float dist2, float cos_hit, bool power);
void restir_bdpt_mis_scatter(struct restir_bdpt_mis *m, float cos_out, float pdf_fwd_w, float pdf_rev_w, bool delta,
                             bool power);
float restir_bdpt_mis_emission(const struct restir_bdpt_mis *cam, float direct_pdf_a, float emission_pdf_w,
                               bool power);
float restir_bdpt_mis_nee(const struct restir_bdpt_mis *cam, float bsdf_fwd_w, float bsdf_rev_w, float direct_pdf_w,
                          float emission_pdf_w, float cos_camera, float cos_light, bool power);
float restir_bdpt_mis_camera(const struct restir_bdpt_mis *light, float camera_pdf_a, float light_paths,
                             float light_rev_w, bool power);

/* The recursive reconnection MIS ([ReSTIR BDPT §6.2]; its eqs. 42–47 written in dVCM / dVC form,
 * for the lightweight techniques). After x_1's scattering a camera subpath's dVC only gains factors
 * of its own vertices (each hit divides by Mis(|cos|), each scattering multiplies by
 * Mis(|cos| p_rev / p_fwd)), and those past x_k do not depend on x_{k-1}: the weight of a path
 * whose prefix is replaced up to x_k is found from two constants of its suffix and the new
 * state at x_k. Three cases, by where the path ends (e: its last vertex, x_e the emitter or, for
 * s = 1, the light sample):
 *   RBDPT_RC_AFTER: k < e - 1; 1 / w = a + b dVC, dVC after x_k's scattering;
 *   RBDPT_RC_EMIT_LAST: s = 0, k = e - 1; 1 / w = 1 + a Mis(1 / p_fwd) + b dVC, dVC likewise and
 *     p_fwd x_k's pdf of w_k;
 *   RBDPT_RC_NEE_LAST: s = 1, k = e - 1; 1 / w = Mis(p_fwd a) + 1 + b dVC Mis(p_rev), dVC after
 *     x_k's hit, p_fwd / p_rev x_k's BSDF pdfs towards the light and back.
 * The make functions take the base path's state where its weight is computed (as
 * restir_bdpt_mis_emission / _nee) and, for RBDPT_RC_AFTER, `suffix`: the factor its dVC gained
 * since x_k's scattering (the same updates applied to dVC = 1 there; kept as a product rather
 * than a quotient of the two states, which would be 0 / 0 when x_1 is delta and dVC is 0).
 * tests/unit/test_restir_bdpt.c checks the weights against a recomputation along the whole new
 * path. */
enum restir_bdpt_rc_kind { RBDPT_RC_AFTER, RBDPT_RC_EMIT_LAST, RBDPT_RC_NEE_LAST };
void restir_bdpt_rc_mis_emission(const struct restir_bdpt_mis *cam, float direct_pdf_a, float emission_pdf_w,
                                 float dist2, float cos_end, bool last, float suffix, bool power, float *a, float *b);
void restir_bdpt_rc_mis_nee(float bsdf_fwd_w, float bsdf_rev_w, float direct_pdf_w,
                            float emission_pdf_w, float cos_camera, float cos_light, bool last, float suffix,
                            bool power, float *a, float *b);
float restir_bdpt_mis_reconnect(enum restir_bdpt_rc_kind kind, float a, float b, const struct restir_bdpt_mis *m,
                                float pdf_fwd, float pdf_rev, bool power);

#endif
