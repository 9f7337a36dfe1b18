/* restir.h — the reuse passes every ReSTIR technique shares: temporal reuse along the G-buffer's
 * motion vectors (generalized balance heuristic over {current, previous}, confidence cap) and
 * spatial reuse over k neighbours (defensive pairwise MIS), over ping-pong reservoir buffers.
 * A technique plugs in through `struct restir_ops`: its reservoir element (a `struct restir_head`
 * then the technique's own sample payload) and its shift mapping between domains. The passes
 * never look inside a payload; a technique's initial and shade passes live in its own file.
 * Deterministic for a seed: every random decision comes from a per-(frame, pixel, pass) stream.
 * Allocation-free per frame (the element scratch of a shift is on the stack).
 * Refs: Lin et al. 2022 (GRIS) eq. 9 and §6.2; docs/architecture.md (pass pipeline);
 * docs/methods.md, "Reuse shared by the methods" (caps, null samples, neighbours that can never
 * produce a sample). */
#ifndef RESTIRD_RESTIR_H
#define RESTIRD_RESTIR_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <time.h>

#include "scene/accel.h"
#include "scene/camera.h"
#include "core/alias.h"
#include "core/err.h"
#include "core/parallel.h"
#include "image/image.h"
#include "integrators/frame.h"
#include "reuse/gbuffer.h"

/* First bytes of every reservoir element. W is the unbiased contribution weight of the sample
 * (0 = none), M its confidence (an integer count of candidates, capped), `bits` belongs to the
 * technique. The sample's target p̂ in its own domain is read through restir_ops.target. */
struct restir_head {
    float W;
    uint16_t M;
    uint16_t bits;
};

#define RESTIR_MAX_STRIDE 256u

/* A domain: one pixel of the current or the previous frame (each with its own camera, scene
 * and G-buffer hit). */
enum { RESTIR_CURRENT = 0, RESTIR_PREVIOUS = 1 };
struct restir_domain {
    uint32_t pixel;
    uint32_t frame;  /* RESTIR_CURRENT or RESTIR_PREVIOUS */
};

/* Per-worker counters of a pass. */
struct restir_counters {
    struct ray_counters rays;
    uint64_t shifts;          /* shift evaluations */
    uint64_t shift_failures;  /* shifts that produced no valid sample (target 0) */
    uint64_t rejected;        /* candidates refused for a non-finite weight */
};

/* *sum += c. A pass counts into a job-local copy and adds it here once per job: the workers'
 * slots of a per-worker array share cache lines, and counting every ray straight into them makes
 * the cores fight over those lines (docs/benchmarks.md, "Two threads that shared a cache line"). */
static inline void restir_counters_add(struct restir_counters *sum, const struct restir_counters *c)
{
    sum->rays.intersect += c->rays.intersect;
    sum->rays.occluded += c->rays.occluded;
    sum->shifts += c->shifts;
    sum->shift_failures += c->shift_failures;
    sum->rejected += c->rejected;
}

struct restir_ops {
    size_t stride;  /* bytes per element, a multiple of 4, <= RESTIR_MAX_STRIDE */
    /* p̂ of the element's sample in the element's own domain. */
    float (*target)(const void *ctx, const void *elem);
    /* Shifts the sample of `src` (valid in domain `from`) into domain `to`: writes the shifted
     * element to `dst` (head copied from src; dst may be NULL when only the numbers are wanted,
     * and is never src), its target in `to` to *target (0 when the shift fails or the sample is
     * worth nothing there) and the Jacobian determinant |d to / d from| to *jacobian. */
    void (*shift)(const void *ctx, const void *src, struct restir_domain from, struct restir_domain to, void *dst,
                  float *target, float *jacobian, struct restir_counters *c);
    /* False when the domain cannot produce any sample (its primary ray escaped): such a pixel
     * is neither a neighbour nor a temporal predecessor, so it counts in neither M nor any MIS
     * denominator. */
    bool (*domain_valid)(const void *ctx, struct restir_domain d);
    /* Optional: the element's contribution vector F in its own domain (the target is a scalar
     * function of it, e.g. its luminance); needed for restir_reuse.estimate. */
    struct vec3 (*value)(const void *ctx, const void *elem);
    /* Optional: whether the element's sample is of the class whose history confidence is capped at
     * restir_reuse.temporal_cap_low instead of temporal_cap. Every shift that succeeds must keep
     * the class (a sample and its shifted copy are of one class), so that both temporal MIS weights
     * of one sample use the same confidences and still sum to one (GRIS's generalized balance
     * heuristic allows confidences that are functions of the sample). */
    bool (*capped_low)(const void *ctx, const void *elem);
};

struct restir_reuse {
    const struct restir_ops *ops;
    const void *ctx;
    uint32_t width, height;
    uint64_t seed;
    uint32_t frame;
    unsigned threads;                /* 0 = all cores */
    const struct gbuffer *gbuf;      /* the current frame's (motion vectors) */
    /* Temporal: the previous frame's final reservoirs (NULL = no history), and the cap on their
     * confidence as a multiple of the current M (ReSTIR PT: 20). */
    const uint8_t *history;
    uint32_t temporal_cap;
    /* The cap of the samples ops->capped_low names (0: temporal_cap for every sample). The stored
     * M never depends on the sample: it counts the history at temporal_cap. */
    uint32_t temporal_cap_low;
    /* Spatial: neighbours per round, and the radius in pixels of the disk they are drawn from. */
    uint32_t neighbors;
    float radius;
    /* Spatial: a neighbour whose primary hit differs too much from the pixel's is not drawn
     * (restir_neighbours_similar): its shading normal's cosine with the pixel's below min_normal_cos (0 = no
     * normal test; needs the G-buffer's surfaces, skipped without them), or its hit distance off
     * by more than max_depth_rel of the larger of the two (0 = no depth test). The test reads the
     * G-buffer only, never a sample, and is symmetric, so the pairwise MIS weights of both the
     * drawn and the paired neighbours still sum to one ([ReSTIR PT] §7: the geometric rejection
     * of its implementation; there the depth is relative to the centre pixel's, which is not
     * symmetric). */
    float min_normal_cos;
    float max_depth_rel;
    /* Paired spatial reuse (restir.c): the neighbour relation is made symmetric so each pair's
     * two shifts serve both pixels, and neighbours come from B x B blocks, B the largest power of
     * two <= radius. Needs restir_pair_scratch_bytes() of scratch, owned by the technique. */
    bool paired;
    void *pair_scratch;
    /* Spatial: when set (and ops->value is), the pass adds to estimate[pixel] the expectation of
     * F(Y) W over its own final selection, sum_i w_i F(Y_i) / p̂(Y_i) = sum_i m_i W_i |J_i| F(Y_i)
     * over every candidate it resampled: the same unbiased estimate without the selection's noise,
     * which for a luminance target is mostly colour noise ([ReSTIR PT Enhanced Fig. 5]: "the
     * vectorized form of the resampling weight"). For a frame's last spatial pass; the selected
     * sample still goes on as the next frame's history. Pixels the pass leaves as they were add
     * F(Y) W. */
    struct vec3 *estimate;
};

size_t restir_pair_scratch_bytes(uint32_t width, uint32_t height);
/* Whether a technique's spatial reuse needs that scratch: paired, with neighbours. A session
 * allocates it only then. */
/* Whether pixels a and b may be each other's spatial neighbours (restir_reuse.min_normal_cos,
 * max_depth_rel). Two pixels whose primary rays both escaped (a domain for restir_bdpt) are alike;
 * an escaped one is like no hit. Symmetric in a and b, which paired reuse relies on (tests/unit/test_restir.c
 * checks it). */
static inline bool restir_neighbours_similar(const struct restir_reuse *r, uint32_t a, uint32_t b)
{
    if (r->max_depth_rel > 0.0f) {
        const float ta = r->gbuf->px[a].t, tb = r->gbuf->px[b].t;
        if (isinf(ta) || isinf(tb)) return isinf(ta) && isinf(tb);
        if (fabsf(ta - tb) > r->max_depth_rel * fmaxf(ta, tb)) return false;
    }
    if (r->min_normal_cos > 0.0f && r->gbuf->surf) {
        const struct gbuffer_surface *sa = &r->gbuf->surf[a], *sb = &r->gbuf->surf[b];
        if (sa->material == GBUFFER_NO_HIT || sb->material == GBUFFER_NO_HIT)
            return sa->material == sb->material;
        if (vec3_dot(sa->ns, sb->ns) < r->min_normal_cos) return false;
    }
    return true;
}

/* The spatial radius of a method whose spatial_radius is 0 (auto): a fixed share of the image,
 * RESTIR_RADIUS_AT_1080 pixels on an image whose shorter side has 1080 (the radius of the ReSTIR
 * PT code, Lin et al. 2022, at 1920 x 1080), scaled with the shorter side so that the neighbours
 * stay as alike on a small image as on a large one, and never below RESTIR_RADIUS_MIN pixels (too
 * few distinct neighbours). docs/benchmarks.md has the measurements behind the two numbers. */
#define RESTIR_RADIUS_AT_1080 20.0f
#define RESTIR_RADIUS_MIN 3.0f
static inline float restir_radius_auto(uint32_t width, uint32_t height)
{
    const float r = RESTIR_RADIUS_AT_1080 * (float)(width < height ? width : height) / 1080.0f;
    return r > RESTIR_RADIUS_MIN ? r : RESTIR_RADIUS_MIN;
}

static inline bool restir_pairs_needed(bool paired, uint32_t neighbors) { return paired && neighbors > 0; }

/* A zeroed array of `count` elements of `stride` bytes that starts on a cache line (NULL when out
 * of memory; free() it). The reuse passes reach their neighbours' elements in no order a
 * prefetcher follows: a 64-byte element of an aligned array is one cache line, of an unaligned
 * one it straddles two. */
void *restir_buffer_alloc(size_t count, size_t stride);

/* The per-pass times and the reuse counters every ReSTIR method reports for a frame (as the
 * per-pass tables of [ReSTIR PT Enhanced Table 1]); a method's own counters struct starts with
 * one. */
struct RESTIRD_STORED_IN_BYTES restir_pass_stats {
    double gbuffer_ms, initial_ms, temporal_ms, spatial_ms, shade_ms;
    uint64_t rays_intersect, rays_occluded;   /* G-buffer included */
    uint64_t shifts, shift_failures, rejected;
    uint64_t nonfinite;   /* pixels whose shaded value was not finite (written as 0) */
};
/* Adds a reuse pass's (or a worker's) rays and shift counters. */
void restir_pass_stats_add(struct restir_pass_stats *s, const struct restir_counters *c);

/* What every ReSTIR method keeps between the frames of a session: two G-buffers (the current
 * one is gbuf[cur], the other the previous frame's), two reservoir buffers of `layers`
 * reservoirs per pixel, the paired spatial reuse's scratch, and whether a history exists. A
 * method's state embeds one. */
struct restir_session {
    uint32_t width, height;
    struct gbuffer gbuf[2];
    uint32_t cur;                /* index of the current G-buffer */
    uint32_t layers;             /* reservoirs per pixel; layer l's at l * width * height */
    size_t sample_bytes;         /* one reservoir */
    uint8_t *res[2];             /* [0] working (initial + temporal), [1] history (final) */
    void *pair_scratch;          /* paired spatial reuse: restir_pair_scratch_bytes(); else NULL */
    bool has_history;
};

/* Allocates the buffers (keep_surfaces: the G-buffers keep their primary hit points too, for
 * methods that rebuild them in another frame's scene; pairs: the paired spatial reuse's scratch).
 * On failure everything is freed and *s zeroed. */
bool restir_session_init(struct restir_session *s, uint32_t width, uint32_t height, uint32_t layers,
                         size_t sample_bytes, bool keep_surfaces, bool pairs, struct err *err);
void restir_session_destroy(struct restir_session *s);
/* Forgets the history (the next frame has no temporal predecessor). */
static inline void restir_session_reset(struct restir_session *s) { s->has_history = false; }
/* Bytes of the reservoir buffers, the G-buffers, their kept hit points, the pair scratch. */
size_t restir_session_reservoir_bytes(const struct restir_session *s);
size_t restir_session_gbuffer_bytes(const struct restir_session *s);
size_t restir_session_hit_bytes(const struct restir_session *s);
size_t restir_session_pair_bytes(const struct restir_session *s);
/* Both G-buffers estimate each pixel's directly seen emission, into one copy (gbuffer_keep_emission,
 * gbuffer_share_emission), and its bytes. */
bool restir_session_keep_emission(struct restir_session *s, struct err *err);
size_t restir_session_emission_bytes(const struct restir_session *s);

/* The partner of `pixel` in pairing m (< 64) of the round r->frame names (false: off the image);
 * for tests: the pairing is an involution. */
bool restir_pair_partner(const struct restir_reuse *r, uint32_t m, uint32_t pixel, uint32_t *partner);

#define RESTIR_MAX_WORKERS 1024u
/* Runs fn(ctx, job) over an image's rows in jobs of rows_per_job rows on `threads` workers. */
static inline bool restir_run_rows(uint32_t height, uint32_t rows_per_job, unsigned threads, parallel_job_fn *fn,
                                   void *ctx, struct err *err)
{
    return parallel_run(threads, (height + rows_per_job - 1) / rows_per_job, fn, ctx, NULL, NULL, err);
}
/* The worker threads of a frame's passes for a session's thread setting (0 = all cores). */
static inline unsigned restir_threads(unsigned threads) { return parallel_threads(threads, RESTIR_MAX_WORKERS); }

/* Temporal reuse in place: `cur` holds each pixel's initial reservoir and receives the merge
 * with the history's reservoir at the pixel the motion vector points to. Counters are summed
 * into *c. */
bool restir_temporal_pass(const struct restir_reuse *r, uint8_t *cur, struct restir_counters *c, struct err *err);
/* One round of spatial reuse from `in` to `out` (distinct buffers of width*height elements). */
bool restir_spatial_pass(const struct restir_reuse *r, const uint8_t *in, uint8_t *out, struct restir_counters *c,
                         struct err *err);

/* The G-buffer pass of a frame for a method that keeps two (gbuf[*cur] current, the other the
 * previous frame's): when the previous frame is history (*has_history and gf.prev_scene) they
 * swap, the motion vectors point into it and a jitter walk (gf.jitter_walk) starts from its
 * positions; otherwise the history is dropped and the positions are drawn afresh. */
bool restir_gbuffer_next(struct gbuffer gbuf[2], uint32_t *cur, bool *has_history, struct gbuffer_frame gf,
                         uint64_t *rays, struct err *err);

/* ---- the frame driver ----------------------------------------------------------------------
 * Every ReSTIR method's frame runs the same passes: the G-buffer, the method's initial pass
 * (candidates into the working reservoirs res[0], and the light they do not carry straight into
 * the image), temporal reuse of every reservoir layer, spatial rounds that end in res[1] (next
 * frame's history), and the shade pass that adds F(Y) W of the final reservoirs. The driver owns
 * the order, the clocks, the counters and the buffer swaps; a method supplies its checks, its
 * context and two row functions (initial, shade), each called once per job of
 * RESTIR_FRAME_ROWS rows. A method's pass struct starts with a `struct restir_frame`
 * (RESTIR_FRAME_FIRST), so the frame is the row functions' job context and they reach the pass
 * struct from it. The pass struct is on the stack, so a frame allocates nothing: sizeof(struct
 * restir_frame) is 50,016 bytes with the per-worker counters, restir_pt's and restir_sss's pass
 * structs about as much, restir_sms's 115,888 with its per-worker SMS counters (x86-64, GCC 12:
 * `gdb -batch -ex 'p sizeof(struct restir_frame)' -ex 'p sizeof(struct sms_pass)' build/restir`). */
#define RESTIR_FRAME_ROWS 2u
/* A method's pass struct must begin with its `struct restir_frame fr`: restir_frame_open zeroes
 * pass_bytes from &fr, and the row functions cast the frame they are given to the pass struct. */
#define RESTIR_FRAME_FIRST(pass_type) \
    _Static_assert(offsetof(pass_type, fr) == 0, #pass_type " must begin with its struct restir_frame fr")
#define RESTIR_MAX_LAYERS 8u   /* reservoirs per pixel a frame reuses (restir_sms: one per light group) */

struct restir_frame {
    struct restir_session *s;
    const struct method_frame *f;
    struct image *out;                 /* NULL: the initial pass alone (a method's initial_only) */
    struct restir_pass_stats *stats;   /* the method's counters, which start with these (each method
                                        * asserts its stats' `pass` at offset 0) */
    struct camera camera;              /* f->camera at the session's size */
    unsigned threads;
    bool temporal;                     /* the method reuses its previous frames (its parameter): the
                                        * G-buffer then draws fresh positions independently, since a
                                        * stratified sequence's consecutive points lie apart, farther
                                        * from where the history was gathered (gbuffer_frame.stratify) */
    bool history;                      /* temporal reuse has the previous frame's reservoirs */
    bool estimated;                    /* the last spatial round added its expected contribution to out */
    struct timespec t0;                /* the clock of the pass that runs */
    struct restir_reuse reuse[RESTIR_MAX_LAYERS];  /* one per reservoir layer (restir_frame_reuse) */
    struct restir_counters reuse_counters;          /* the temporal and spatial passes' */
    struct restir_counters counters[RESTIR_MAX_WORKERS];  /* the initial pass's, one per worker */
    uint64_t nonfinite[RESTIR_MAX_WORKERS];              /* the shade pass's, one per worker */
};

/* Opens a frame in *fr, the start of the method's pass struct of pass_bytes (all zeroed here):
 * the output, when there is one, must have the session's size; the method's counters start at
 * zero (`stats` may be NULL, then `local` is used and returned; NULL on failure). `temporal`: the
 * method's parameters ask for temporal reuse. */
void *restir_frame_open(struct restir_frame *fr, size_t pass_bytes, struct restir_session *s,
                        const struct method_frame *f, struct image *out, bool temporal, void *stats, void *local,
                        size_t stats_bytes, struct err *err);
/* After the method's own checks: refuses paired spatial reuse (pairs) in a session made without
 * its scratch, starts the clock and renders the G-buffer pass (restir_gbuffer_next; jitter_walk,
 * check_history and emission_samples as gbuffer_frame's), whose time and rays go to the stats. */
bool restir_frame_gbuffer(struct restir_frame *fr, float jitter_walk, bool pairs, bool check_history,
                          uint32_t emission_samples, struct err *err);
/* The initial pass: fn(fr, job) over the rows (fr is the start of the pass struct); then its time
 * and the workers' `counters` go to the stats, and the clock restarts for the reuse passes. A frame
 * without an output ends here and leaves the session without a history. */
bool restir_frame_initial(struct restir_frame *fr, parallel_job_fn *fn, struct err *err);
/* The reuse of every layer: the same ops and parameters, layer l's context at ctx + l * ctx_stride
 * bytes (0: one context for all). Returns fr->reuse, for a method that changes a round's fields. */
struct restir_reuse *restir_frame_reuse(struct restir_frame *fr, const struct restir_ops *ops, const void *ctx,
                                        size_t ctx_stride, uint32_t temporal_cap, uint32_t neighbors, float radius,
                                        bool paired);
/* Temporal reuse of every layer in res[0], from res[1] when there is history. */
bool restir_frame_temporal(struct restir_frame *fr, struct err *err);
/* One spatial round of every layer from res[0] into res[1]; `estimate`: the round adds its
 * expected contribution to the image (restir_reuse.estimate), which the shade pass then leaves
 * out; `last`: else the buffers swap, so the next round reads this one's output. */
bool restir_frame_spatial(struct restir_frame *fr, bool estimate, bool last, struct err *err);
/* The working reservoirs become the history (a frame without spatial reuse). */
static inline void restir_session_swap(struct restir_session *s)
{
    uint8_t *tmp = s->res[0];
    s->res[0] = s->res[1];
    s->res[1] = tmp;
}
/* Closes the reuse: the spatial rounds' time and the reuse counters go to the stats. */
void restir_frame_reused(struct restir_frame *fr);
/* The shade pass: fn(fr, job) over the rows (restir_frame_store per pixel); then the
 * non-finite count and its time go to the stats, and the session has a history. */
bool restir_frame_shade(struct restir_frame *fr, parallel_job_fn *fn, struct err *err);

/* What a method's shift context holds of the frame's two domains (RESTIR_CURRENT,
 * RESTIR_PREVIOUS): their scenes and G-buffers and, where eye is not NULL, their camera positions;
 * a frame without a previous scene or camera uses the current one in its place. */
void restir_frame_domains(const struct restir_session *s, const struct method_frame *f, const struct scene *scene[2],
                          struct vec3 eye[2], const struct gbuffer *gbuf[2]);

/* The rows [*y0, *y1) of a job. */
static inline void restir_frame_rows(const struct restir_frame *fr, uint32_t job, uint32_t *y0, uint32_t *y1)
{
    const uint32_t h = fr->s->height;
    *y0 = job * RESTIR_FRAME_ROWS;
    *y1 = (job + 1) * RESTIR_FRAME_ROWS < h ? (job + 1) * RESTIR_FRAME_ROWS : h;
}
/* The shade pass's write of a pixel: a value that is not finite is counted and written as 0. */
static inline void restir_frame_store(struct restir_frame *fr, unsigned worker, uint32_t pixel, struct vec3 L)
{
    if (!vec3_is_finite(L)) {
        fr->nonfinite[worker]++;
        L = vec3_splat(0.0f);
    }
    fr->out->pixels[pixel] = L;
}

#endif
