/* restir.c — temporal and spatial reuse passes (see restir.h). */
#include "restir.h"

#include <math.h>
#include <string.h>

#include "parallel.h"
#include "reservoir.h"
#include "reuse_mis.h"
#include "rng.h"

#define RESTIR_TEMPORAL_STREAM 0x7274ull
#define RESTIR_SPATIAL_STREAM 0x7273ull
#define RESTIR_ROWS_PER_JOB 2u

/* One pixel of a pass: reads `in` (NULL for the in-place temporal pass), writes `out`. */
typedef void restir_pixel_fn(const struct restir_reuse *r, const uint8_t *in, uint8_t *out, uint32_t pixel,
                             struct restir_counters *c);

struct restir_pass {
    const struct restir_reuse *r;
    restir_pixel_fn *pixel;
    const uint8_t *in;
    uint8_t *out;
    struct restir_counters counters[RESTIR_MAX_WORKERS];
};

static inline const struct restir_head *restir_elem(const uint8_t *buf, size_t stride, uint32_t pixel)
{
    return (const struct restir_head *)(buf + (size_t)pixel * stride);
}

/* A shift, counted: returns the target in `to` (0 when it fails) and sets *jacobian. */
static float restir_shift(const struct restir_reuse *r, const void *src, struct restir_domain from,
                          struct restir_domain to, void *dst, float *jacobian, struct restir_counters *c)
{
    float t = 0.0f;
    *jacobian = 0.0f;
    r->ops->shift(r->ctx, src, from, to, dst, &t, jacobian, c);
    c->shifts++;
    if (t > 0.0f) return t;
    c->shift_failures++;
    return 0.0f;
}

static inline uint16_t restir_clamp_m(float m)
{
    return m >= 65535.0f ? 65535u : (uint16_t)m;
}

/* Temporal reuse of one pixel: the generalized balance heuristic over the current domain c and
 * the previous domain q the motion vector lands in (GRIS eq. 9), both weights evaluated in c's
 * measure:
 *   m_c = M_c p̂_c(Y_c) / (M_c p̂_c(Y_c) + M_q p̂_q(T_cq(Y_c)) |J_cq|)
 *   m_q = M_q p̂_q(Y_q) / (M_q p̂_q(Y_q) + M_c p̂_c(T_qc(Y_q)) |J_qc|)
 * with resampling weights w = m p̂_c(shifted) W |J|. */
static void restir_temporal_pixel(const struct restir_reuse *r, const uint8_t *in, uint8_t *cur, uint32_t pixel,
                                  struct restir_counters *c)
{
    (void)in;
    const struct restir_ops *ops = r->ops;
    const size_t stride = ops->stride;
    struct restir_head *hc = (struct restir_head *)(cur + (size_t)pixel * stride);
    const struct restir_domain dc = {pixel, RESTIR_CURRENT};
    if (!ops->domain_valid(r->ctx, dc)) return;
    const struct gbuffer_pixel *g = &r->gbuf->px[pixel];
    if (!(g->prev_x >= 0.0f) || !(g->prev_y >= 0.0f) || g->prev_x >= (float)r->width || g->prev_y >= (float)r->height)
        return;  /* no previous frame, NaN, or off screen */
    const struct restir_domain dq = {(uint32_t)g->prev_y * r->width + (uint32_t)g->prev_x, RESTIR_PREVIOUS};
    if (!ops->domain_valid(r->ctx, dq)) return;

    const struct restir_head *hq = restir_elem(r->history, stride, dq.pixel);
    const float M_c = (float)hc->M;
    float M_q = (float)hq->M;
    if (M_q > (float)r->temporal_cap * M_c) M_q = (float)r->temporal_cap * M_c;

    struct rng rng = rng_make(r->seed, r->frame, pixel, RESTIR_TEMPORAL_STREAM);
    struct reservoir_stream s;
    reservoir_stream_begin(&s);
    _Alignas(16) uint8_t shifted[RESTIR_MAX_STRIDE];
    bool take_prev = false;

    /* The current sample, and how likely the previous domain was to produce it. */
    const float p_c = hc->W > 0.0f ? ops->target(r->ctx, hc) : 0.0f;
    if (p_c > 0.0f) {
        float j_cq;
        float t_cq = restir_shift(r, hc, dc, dq, NULL, &j_cq, c);
        float pm[2] = {p_c, t_cq * j_cq}, mm[2] = {M_c, M_q};
        float m_c = reuse_mis_balance(mm, pm, 2, 0);
        reservoir_stream_offer(&s, (double)m_c * p_c * hc->W, p_c, M_c, rng_next_float(&rng));
    } else {
        reservoir_stream_offer(&s, 0.0, 0.0f, M_c, rng_next_float(&rng));
    }
    /* The previous sample shifted into this pixel. */
    float u = rng_next_float(&rng);
    const float p_q = hq->W > 0.0f ? ops->target(r->ctx, hq) : 0.0f;
    if (p_q > 0.0f) {
        float j_qc;
        float t_qc = restir_shift(r, hq, dq, dc, shifted, &j_qc, c);
        if (t_qc > 0.0f) {
            float pm[2] = {p_q, t_qc * j_qc}, mm[2] = {M_q, M_c};
            float m_q = reuse_mis_balance(mm, pm, 2, 0);
            take_prev = reservoir_stream_offer(&s, (double)m_q * t_qc * hq->W * j_qc, t_qc, M_q, u);
        } else {
            reservoir_stream_offer(&s, 0.0, 0.0f, M_q, u);
        }
    } else {
        reservoir_stream_offer(&s, 0.0, 0.0f, M_q, u);
    }
    c->rejected += s.rejected;

    struct reservoir res = reservoir_stream_finish(&s);
    if (take_prev) memcpy(hc, shifted, stride);
    hc->W = res.W;
    hc->M = restir_clamp_m(res.M);
}

/* Spatial reuse of one pixel with defensive pairwise MIS (Bitterli 2022, GRIS §6.2): the
 * canonical sample keeps weight (1 + sum_n (1 - t_n)) / (k + 1), neighbour n's sample
 * M_n p̂_n / (M_n p̂_n + (M_c / k) p̂_c(T(X_n)) |J|) / (k + 1); k counts the neighbours that
 * can produce samples, chosen before any sample is looked at. */
static void restir_spatial_pixel(const struct restir_reuse *r, const uint8_t *in, uint8_t *out, uint32_t pixel,
                                 struct restir_counters *c)
{
    const struct restir_ops *ops = r->ops;
    const size_t stride = ops->stride;
    const struct restir_head *hc = restir_elem(in, stride, pixel);
    struct restir_head *ho = (struct restir_head *)(out + (size_t)pixel * stride);
    memcpy(ho, hc, stride);
    const struct restir_domain dc = {pixel, RESTIR_CURRENT};
    if (!ops->domain_valid(r->ctx, dc) || r->neighbors == 0) return;

    struct rng rng = rng_make(r->seed, r->frame, pixel, RESTIR_SPATIAL_STREAM);
    uint32_t nb[64];
    uint32_t k = 0;
    const int px = (int)(pixel % r->width), py = (int)(pixel / r->width);
    for (uint32_t i = 0; i < r->neighbors && i < 64; i++) {
        /* Uniform in the disk of the radius (by its area), rounded to a pixel. */
        float rad = r->radius * sqrtf(rng_next_float(&rng)), phi = 6.2831853f * rng_next_float(&rng);
        int qx = px + (int)lrintf(rad * cosf(phi)), qy = py + (int)lrintf(rad * sinf(phi));
        if (qx < 0 || qy < 0 || qx >= (int)r->width || qy >= (int)r->height || (qx == px && qy == py)) continue;
        uint32_t q = (uint32_t)qy * r->width + (uint32_t)qx;
        if (!ops->domain_valid(r->ctx, (struct restir_domain){q, RESTIR_CURRENT})) continue;
        nb[k++] = q;
    }
    if (k == 0) return;

    const float M_c = (float)hc->M;
    const float p_c = hc->W > 0.0f ? ops->target(r->ctx, hc) : 0.0f;
    struct reservoir_stream s;
    reservoir_stream_begin(&s);
    _Alignas(16) uint8_t shifted[RESTIR_MAX_STRIDE];
    float canonical_terms = 0.0f;
    for (uint32_t i = 0; i < k; i++) {
        const struct restir_domain dn = {nb[i], RESTIR_CURRENT};
        const struct restir_head *hn = restir_elem(in, stride, dn.pixel);
        const float M_n = (float)hn->M;
        /* The canonical sample seen from the neighbour. */
        if (p_c > 0.0f) {
            float j_cn;
            float t_cn = restir_shift(r, hc, dc, dn, NULL, &j_cn, c);
            canonical_terms += reuse_mis_pairwise_canonical_term(M_c, M_n, p_c, t_cn * j_cn, k);
        }
        /* The neighbour's sample shifted here. */
        float u = rng_next_float(&rng);
        const float p_n = hn->W > 0.0f ? ops->target(r->ctx, hn) : 0.0f;
        if (p_n > 0.0f) {
            float j_nc;
            float t_nc = restir_shift(r, hn, dn, dc, shifted, &j_nc, c);
            if (t_nc > 0.0f) {
                float m_n = reuse_mis_pairwise_neighbor(M_c, M_n, p_n, t_nc * j_nc, k);
                if (reservoir_stream_offer(&s, (double)m_n * t_nc * hn->W * j_nc, t_nc, M_n, u))
                    memcpy(ho, shifted, stride);
                continue;
            }
        }
        reservoir_stream_offer(&s, 0.0, 0.0f, M_n, u);
    }
    float u = rng_next_float(&rng);
    if (p_c > 0.0f) {
        float m_c = reuse_mis_pairwise_canonical(canonical_terms, k);
        if (reservoir_stream_offer(&s, (double)m_c * p_c * hc->W, p_c, M_c, u)) memcpy(ho, hc, stride);
    } else {
        reservoir_stream_offer(&s, 0.0, 0.0f, M_c, u);
    }
    c->rejected += s.rejected;
    struct reservoir res = reservoir_stream_finish(&s);
    ho->W = res.W;
    ho->M = restir_clamp_m(res.M);
}

static void restir_rows(void *ctx, uint32_t job, unsigned worker)
{
    struct restir_pass *p = ctx;
    const struct restir_reuse *r = p->r;
    uint32_t y1 = (job + 1) * RESTIR_ROWS_PER_JOB < r->height ? (job + 1) * RESTIR_ROWS_PER_JOB : r->height;
    for (uint32_t y = job * RESTIR_ROWS_PER_JOB; y < y1; y++)
        for (uint32_t x = 0; x < r->width; x++) p->pixel(r, p->in, p->out, y * r->width + x, &p->counters[worker]);
}

static bool restir_run(const struct restir_reuse *r, restir_pixel_fn *fn, const uint8_t *in, uint8_t *out,
                       struct restir_counters *c, struct err *err)
{
    /* On the stack (40 KiB of counters): a frame allocates nothing. */
    struct restir_pass pass;
    memset(&pass, 0, sizeof pass);
    pass.r = r;
    pass.pixel = fn;
    pass.in = in;
    pass.out = out;
    unsigned threads = r->threads ? r->threads : parallel_default_threads();
    if (threads > RESTIR_MAX_WORKERS) threads = RESTIR_MAX_WORKERS;
    uint32_t jobs = (r->height + RESTIR_ROWS_PER_JOB - 1) / RESTIR_ROWS_PER_JOB;
    if (!parallel_run(threads, jobs, restir_rows, &pass, NULL, NULL, err)) return false;
    for (unsigned i = 0; i < threads; i++) {
        c->rays.intersect += pass.counters[i].rays.intersect;
        c->rays.occluded += pass.counters[i].rays.occluded;
        c->shifts += pass.counters[i].shifts;
        c->shift_failures += pass.counters[i].shift_failures;
        c->rejected += pass.counters[i].rejected;
    }
    return true;
}

bool restir_temporal_pass(const struct restir_reuse *r, uint8_t *cur, struct restir_counters *c, struct err *err)
{
    if (!r->history) return true;
    return restir_run(r, restir_temporal_pixel, NULL, cur, c, err);
}

bool restir_spatial_pass(const struct restir_reuse *r, const uint8_t *in, uint8_t *out, struct restir_counters *c,
                         struct err *err)
{
    return restir_run(r, restir_spatial_pixel, in, out, c, err);
}
