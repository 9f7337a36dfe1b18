/* restir.c — temporal and spatial reuse passes (see restir.h). */
#include "reuse/restir.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "core/parallel.h"
#include "reuse/reservoir.h"
#include "reuse/reuse_mis.h"
#include "core/rng.h"

#define RESTIR_TEMPORAL_STREAM 0x7274ull
#define RESTIR_SPATIAL_STREAM 0x7273ull
#define RESTIR_ROWS_PER_JOB 2u

/* One pixel of a pass: reads `in` (NULL for the in-place temporal pass), writes `out`. */
struct restir_pass;
typedef void restir_pixel_fn(const struct restir_pass *p, uint32_t pixel, struct restir_counters *c);

struct restir_pass {
    const struct restir_reuse *r;
    restir_pixel_fn *pixel;
    const uint8_t *in;
    uint8_t *out;
    uint32_t matching;  /* paired spatial reuse: which pairing of the round */
    uint64_t pair_key[65];  /* paired spatial reuse: each pairing's hash key (restir_pair_keys) */
    uint32_t pair_log2;     /* and log2 of its block size */
    uint32_t band_groups;   /* a paired pass in bands: jobs per band (restir_band) */
    struct restir_counters counters[RESTIR_MAX_WORKERS];
};

static inline const struct restir_head *restir_elem(const uint8_t *buf, size_t stride, uint32_t pixel)
{
    return (const struct restir_head *)(buf + (size_t)pixel * stride);
}

/* Adds weight * F(elem) to *acc when the term is finite (a weight the reservoir refuses is
 * refused here too). */
static inline void restir_estimate_add(const struct restir_reuse *r, struct vec3 *acc, const void *elem, double weight)
{
    if (!(weight > 0.0) || !isfinite(weight)) return;
    struct vec3 t = vec3_scale(r->ops->value(r->ctx, elem), (float)weight);
    if (vec3_is_finite(t)) *acc = vec3_add(*acc, t);
}

static inline bool restir_estimating(const struct restir_reuse *r) { return r->estimate && r->ops->value; }

/* A pixel the pass leaves as it was: its sample's own F(Y) W. */
static void restir_estimate_unchanged(const struct restir_reuse *r, uint32_t pixel, const struct restir_head *h)
{
    if (!restir_estimating(r) || !(h->W > 0.0f)) return;
    struct vec3 acc = vec3_splat(0.0f);
    restir_estimate_add(r, &acc, h, h->W);
    r->estimate[pixel] = vec3_add(r->estimate[pixel], acc);
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
static void restir_temporal_pixel(const struct restir_pass *p, uint32_t pixel, struct restir_counters *c)
{
    const struct restir_reuse *r = p->r;
    uint8_t *cur = p->out;
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
    /* The history's confidence, capped, times this pixel's share of it (gbuffer.h prev_share). */
    const float M_q = fminf((float)hq->M, (float)r->temporal_cap * M_c) * g->prev_share;
    /* The history's confidence in the MIS weights of one sample: M_q, or for a sample of the low
     * class (ops->capped_low) capped at temporal_cap_low instead; the same for both weights of a
     * sample, since its shift keeps its class. */
    const bool low = r->temporal_cap_low && ops->capped_low;
    const float M_q_low = low ? fminf((float)hq->M, (float)r->temporal_cap_low * M_c) * g->prev_share : M_q;

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
        float pm[2] = {p_c, t_cq * j_cq}, mm[2] = {M_c, low && ops->capped_low(r->ctx, hc) ? M_q_low : M_q};
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
            float pm[2] = {p_q, t_qc * j_qc}, mm[2] = {low && ops->capped_low(r->ctx, hq) ? M_q_low : M_q, M_c};
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

/* Spatial reuse of one pixel with defensive pairwise MIS (Bitterli 2021, GRIS §6.2): the
 * canonical sample keeps weight (1 + sum_n (1 - t_n)) / (k + 1), neighbour n's sample
 * M_n p̂_n / (M_n p̂_n + (M_c / k) p̂_c(T(X_n)) |J|) / (k + 1); k counts the neighbours that
 * can produce samples, chosen before any sample is looked at. */
static void restir_spatial_pixel(const struct restir_pass *p, uint32_t pixel, struct restir_counters *c)
{
    const struct restir_reuse *r = p->r;
    const uint8_t *in = p->in;
    uint8_t *out = p->out;
    const struct restir_ops *ops = r->ops;
    const size_t stride = ops->stride;
    const struct restir_head *hc = restir_elem(in, stride, pixel);
    struct restir_head *ho = (struct restir_head *)(out + (size_t)pixel * stride);
    memcpy(ho, hc, stride);
    const struct restir_domain dc = {pixel, RESTIR_CURRENT};
    if (!ops->domain_valid(r->ctx, dc) || r->neighbors == 0) {
        restir_estimate_unchanged(r, pixel, ho);
        return;
    }

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
        if (!ops->domain_valid(r->ctx, (struct restir_domain){q, RESTIR_CURRENT}) || !restir_neighbours_similar(r, pixel, q))
            continue;
        nb[k++] = q;
    }
    if (k == 0) {
        restir_estimate_unchanged(r, pixel, ho);
        return;
    }

    const float M_c = (float)hc->M;
    const float p_c = hc->W > 0.0f ? ops->target(r->ctx, hc) : 0.0f;
    struct reservoir_stream s;
    reservoir_stream_begin(&s);
    _Alignas(16) uint8_t shifted[RESTIR_MAX_STRIDE];
    float canonical_terms = 0.0f;
    struct vec3 est = vec3_splat(0.0f);
    const bool estimating = restir_estimating(r);
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
                if (estimating) restir_estimate_add(r, &est, shifted, (double)m_n * hn->W * j_nc);
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
        if (estimating) restir_estimate_add(r, &est, hc, (double)m_c * hc->W);
        if (reservoir_stream_offer(&s, (double)m_c * p_c * hc->W, p_c, M_c, u)) memcpy(ho, hc, stride);
    } else {
        reservoir_stream_offer(&s, 0.0, 0.0f, M_c, u);
    }
    c->rejected += s.rejected;
    struct reservoir res = reservoir_stream_finish(&s);
    ho->W = res.W;
    ho->M = restir_clamp_m(res.M);
    if (estimating) r->estimate[pixel] = vec3_add(r->estimate[pixel], est);
}

/* ---- paired spatial reuse --------------------------------------------------------------------
 * Pairwise MIS needs, for a canonical pixel c and a neighbour n, two shifts: n's sample into c
 * (the candidate) and c's sample into n (c's canonical weight). When n also takes c as a
 * neighbour it needs the very same two shifts, so a symmetric neighbour relation halves the
 * shifts of a round ([ReSTIR PT Enhanced Table 1], "paired spatial reuse"). Each of the round's
 * `neighbors` pairings is an involution on the pixels: the image is cut into B x B blocks (B the
 * largest power of two <= radius, the block grid shifted at random per pairing) and inside a block
 * pixel (x, y) pairs with (x ^ a, y ^ b) for a random non-zero mask (a, b) per block. Partners are
 * therefore within B - 1 pixels on each axis, drawn independently of any sample; the pairing's
 * owner (the smaller pixel index) computes both shifts and updates both reservoirs, which no
 * other pair of the same pairing touches. */

#define RESTIR_PAIR_STREAM 0x7270ull

#define RESTIR_PAIR_CACHED 4u
#define RESTIR_NO_PARTNER UINT32_MAX

/* A pixel's reservoir while a paired round streams into it (the selected payload goes straight
 * into the output buffer). */
struct restir_pair_acc {
    struct reservoir_stream s;
    float canonical_terms;  /* sum over partners of the canonical weight's terms 1 - t_n */
    uint32_t k;             /* partners that can produce samples (pairings whose partner is valid) */
    struct vec3 est;        /* restir_reuse.estimate: sum of m_i W_i |J_i| F(Y_i) so far */
    /* The valid partner of each of the first RESTIR_PAIR_CACHED pairings (RESTIR_NO_PARTNER: off
     * the image or unable to produce samples), found once when the round opens: the later
     * pairings read it instead of hashing the partner's coordinates again. */
    uint32_t partner[RESTIR_PAIR_CACHED];
};

size_t restir_pair_scratch_bytes(uint32_t width, uint32_t height)
{
    return (size_t)width * height * sizeof(struct restir_pair_acc);
}

#define RESTIR_CACHE_LINE 64u

void *restir_buffer_alloc(size_t count, size_t stride)
{
    if (stride && count > (SIZE_MAX - RESTIR_CACHE_LINE) / stride) return NULL;
    size_t bytes = (count * stride + RESTIR_CACHE_LINE - 1) / RESTIR_CACHE_LINE * RESTIR_CACHE_LINE;
    void *buf = aligned_alloc(RESTIR_CACHE_LINE, bytes ? bytes : RESTIR_CACHE_LINE);
    if (buf) memset(buf, 0, bytes);
    return buf;
}

void restir_pass_stats_add(struct restir_pass_stats *s, const struct restir_counters *c)
{
    s->rays_intersect += c->rays.intersect;
    s->rays_occluded += c->rays.occluded;
    s->shifts += c->shifts;
    s->shift_failures += c->shift_failures;
    s->rejected += c->rejected;
}

bool restir_session_init(struct restir_session *s, uint32_t width, uint32_t height, uint32_t layers,
                         size_t sample_bytes, bool keep_surfaces, bool pairs, struct err *err)
{
    memset(s, 0, sizeof *s);
    s->width = width;
    s->height = height;
    s->layers = layers;
    s->sample_bytes = sample_bytes;
    bool ok = true;
    for (int i = 0; ok && i < 2; i++)
        ok = gbuffer_init(&s->gbuf[i], width, height, err) && (!keep_surfaces || gbuffer_keep_surfaces(&s->gbuf[i], err));
    for (int i = 0; ok && i < 2; i++)
        if (!(s->res[i] = restir_buffer_alloc((size_t)width * height * layers, sample_bytes)))
            ok = err_set(err, ERR_NOMEM, NULL, "out of memory for %ux%u reservoirs", width, height);
    if (ok && pairs && !(s->pair_scratch = restir_buffer_alloc(1, restir_pair_scratch_bytes(width, height))))
        ok = err_set(err, ERR_NOMEM, NULL, "out of memory for %ux%u spatial pairs", width, height);
    if (!ok) restir_session_destroy(s);
    return ok;
}

void restir_session_destroy(struct restir_session *s)
{
    for (int i = 0; i < 2; i++) {
        gbuffer_destroy(&s->gbuf[i]);
        free(s->res[i]);
    }
    free(s->pair_scratch);
    memset(s, 0, sizeof *s);
}

size_t restir_session_reservoir_bytes(const struct restir_session *s)
{
    return 2 * (size_t)s->width * s->height * s->layers * s->sample_bytes;
}

size_t restir_session_gbuffer_bytes(const struct restir_session *s)
{
    return gbuffer_bytes(&s->gbuf[0]) + gbuffer_bytes(&s->gbuf[1]);
}

size_t restir_session_hit_bytes(const struct restir_session *s)
{
    return gbuffer_surface_bytes(&s->gbuf[0]) + gbuffer_surface_bytes(&s->gbuf[1]);
}

bool restir_session_keep_emission(struct restir_session *s, struct err *err)
{
    if (!gbuffer_keep_emission(&s->gbuf[0], err)) return false;
    gbuffer_share_emission(&s->gbuf[1], &s->gbuf[0]);
    return true;
}

size_t restir_session_emission_bytes(const struct restir_session *s)
{
    return gbuffer_emission_bytes(&s->gbuf[0]) + gbuffer_emission_bytes(&s->gbuf[1]);
}

size_t restir_session_pair_bytes(const struct restir_session *s)
{
    return s->pair_scratch ? restir_pair_scratch_bytes(s->width, s->height) : 0;
}

/* log2 of the block size B: the largest power of two <= radius (at least 2, at most 256). */
static uint32_t restir_pair_log2(float radius)
{
    uint32_t l = 1;
    while ((float)(2u << l) <= radius && l < 8) l++;
    return l;
}

/* 32-bit integer hash (the "lowbias32" constants): per-block masks and per-pixel decisions are
 * hashed from a per-pairing key, which costs a handful of instructions instead of a stream. */
static inline uint32_t restir_hash32(uint32_t x)
{
    x ^= x >> 16;
    x *= 0x7feb352du;
    x ^= x >> 15;
    x *= 0x846ca68bu;
    x ^= x >> 16;
    return x;
}

/* One key per pairing of the round (and one more for the canonical candidate's decision). */
static void restir_pair_keys(const struct restir_reuse *r, uint64_t keys[65])
{
    for (uint32_t m = 0; m <= 64; m++)
        keys[m] = rng_mix64(r->seed ^ rng_mix64(((uint64_t)r->frame << 8 | m) ^ RESTIR_PAIR_STREAM));
}

/* The partner of pixel (x, y) under the pairing with key h and blocks of 2^L pixels (false: off
 * the image). */
static bool restir_partner_of(const struct restir_reuse *r, uint64_t h, uint32_t L, uint32_t x, uint32_t y,
                              uint32_t *partner)
{
    const uint32_t mask = (1u << L) - 1;
    const uint32_t ox = (uint32_t)h & mask, oy = (uint32_t)(h >> 20) & mask;
    const uint32_t gx = x + ox, gy = y + oy;
    const uint32_t t = restir_hash32((uint32_t)(h >> 32) ^ restir_hash32((gx >> L) << 16 ^ (gy >> L)));
    uint32_t a = t & mask, b = (t >> 16) & mask;
    if (a == 0 && b == 0) a = 1;
    const int64_t qx = (int64_t)((gx & ~mask) | ((gx & mask) ^ a)) - ox;
    const int64_t qy = (int64_t)((gy & ~mask) | ((gy & mask) ^ b)) - oy;
    if (qx < 0 || qy < 0 || qx >= r->width || qy >= r->height) return false;
    *partner = (uint32_t)qy * r->width + (uint32_t)qx;
    return true;
}

static inline bool restir_partner(const struct restir_pass *p, uint32_t m, uint32_t x, uint32_t y, uint32_t *partner)
{
    return restir_partner_of(p->r, p->pair_key[m], p->pair_log2, x, y, partner);
}

bool restir_pair_partner(const struct restir_reuse *r, uint32_t m, uint32_t pixel, uint32_t *partner)
{
    uint64_t keys[65];
    restir_pair_keys(r, keys);
    return m < 64 &&
           restir_partner_of(r, keys[m], restir_pair_log2(r->radius), pixel % r->width, pixel / r->width, partner);
}

/* The partner of pixel (x, y) in pairing m, when it is on the image, can produce samples and is
 * similar (restir_neighbours_similar, symmetric: the pair is valid from both sides, as the pairing is). */
static bool restir_pair_valid(const struct restir_pass *p, uint32_t m, uint32_t x, uint32_t y, uint32_t *partner)
{
    return restir_partner(p, m, x, y, partner) &&
           p->r->ops->domain_valid(p->r->ctx, (struct restir_domain){*partner, RESTIR_CURRENT}) &&
           restir_neighbours_similar(p->r, y * p->r->width + x, *partner);
}

/* The uniform number of pixel's candidate from pairing m (m = neighbors: the canonical one). */
static float restir_pair_u(const struct restir_pass *p, uint32_t pixel, uint32_t m)
{
    const uint64_t h = p->pair_key[m];
    return (float)(restir_hash32((uint32_t)h ^ restir_hash32(pixel ^ (uint32_t)(h >> 32))) >> 8) * 0x1p-24f;
}

/* Opens the round for a pixel: k counts the valid partners, the first ones are kept. The output
 * is written only when a candidate is selected, and when the round closes if the canonical sample
 * stays. The first pairing, which opens the round, has already found the pixel's partner there
 * (`first`, RESTIR_NO_PARTNER when none) and whether the pixel can produce samples (`valid`). */
static void restir_pair_open(const struct restir_pass *p, uint32_t pixel, bool valid, uint32_t first)
{
    const struct restir_reuse *r = p->r;
    struct restir_pair_acc *a = (struct restir_pair_acc *)r->pair_scratch + pixel;
    memset(a, 0, sizeof *a);
    reservoir_stream_begin(&a->s);
    for (uint32_t m = 0; m < RESTIR_PAIR_CACHED; m++) a->partner[m] = RESTIR_NO_PARTNER;
    if (!valid) return;
    a->partner[0] = first;
    a->k = first != RESTIR_NO_PARTNER;
    const uint32_t x = pixel % r->width, y = pixel / r->width;
    for (uint32_t m = 1; m < r->neighbors; m++) {
        uint32_t q;
        if (!restir_pair_valid(p, m, x, y, &q)) continue;
        a->k++;
        if (m < RESTIR_PAIR_CACHED) a->partner[m] = q;
    }
}

/* The half of a pair's work that lands in pixel c: its canonical term from the shift of its own
 * sample into n, and n's sample shifted into c as a candidate. */
static void restir_pair_side(const struct restir_pass *p, struct restir_domain dc, struct restir_domain dn,
                             float p_c, float t_cn_j, float p_n, float t_nc, float j_nc, const void *shifted,
                             struct restir_counters *c)
{
    const struct restir_reuse *r = p->r;
    const size_t stride = r->ops->stride;
    const struct restir_head *hc = restir_elem(p->in, stride, dc.pixel), *hn = restir_elem(p->in, stride, dn.pixel);
    struct restir_pair_acc *a = (struct restir_pair_acc *)r->pair_scratch + dc.pixel;
    const float M_c = (float)hc->M, M_n = (float)hn->M;
    if (p_c > 0.0f) a->canonical_terms += reuse_mis_pairwise_canonical_term(M_c, M_n, p_c, t_cn_j, a->k);
    const float u = restir_pair_u(p, dc.pixel, p->matching);
    const unsigned before = a->s.rejected;
    if (p_n > 0.0f && t_nc > 0.0f) {
        float m_n = reuse_mis_pairwise_neighbor(M_c, M_n, p_n, t_nc * j_nc, a->k);
        if (restir_estimating(r)) restir_estimate_add(r, &a->est, shifted, (double)m_n * hn->W * j_nc);
        if (reservoir_stream_offer(&a->s, (double)m_n * t_nc * hn->W * j_nc, t_nc, M_n, u))
            memcpy(p->out + (size_t)dc.pixel * stride, shifted, stride);
    } else {
        reservoir_stream_offer(&a->s, 0.0, 0.0f, M_n, u);
    }
    c->rejected += a->s.rejected - before;
}

/* The valid partner of a pixel that can produce samples, under pairing p->matching: as the round's
 * opening stored it, or found afresh (in the first pairing, which opens the round, and past the
 * stored ones). *valid: whether the pixel itself can produce samples (set when found afresh). */
static bool restir_pair_of_round(const struct restir_pass *p, uint32_t pixel, bool *valid, uint32_t *q)
{
    const struct restir_reuse *r = p->r;
    if (p->matching > 0 && p->matching < RESTIR_PAIR_CACHED) {
        *q = ((const struct restir_pair_acc *)r->pair_scratch)[pixel].partner[p->matching];
        return *q != RESTIR_NO_PARTNER;
    }
    *valid = r->ops->domain_valid(r->ctx, (struct restir_domain){pixel, RESTIR_CURRENT});
    return *valid && restir_pair_valid(p, p->matching, pixel % r->width, pixel / r->width, q);
}

/* The pair (pixel, q) of pairing p->matching: both shifts, and each side's candidate. */
static void restir_pair_work(const struct restir_pass *p, uint32_t pixel, uint32_t q, struct restir_counters *c)
{
    const struct restir_reuse *r = p->r;
    const struct restir_ops *ops = r->ops;
    const size_t stride = ops->stride;
    const struct restir_domain dp = {pixel, RESTIR_CURRENT}, dq = {q, RESTIR_CURRENT};
    const struct restir_head *hp = restir_elem(p->in, stride, pixel), *hq = restir_elem(p->in, stride, q);
    const float p_p = hp->W > 0.0f ? ops->target(r->ctx, hp) : 0.0f;
    const float p_q = hq->W > 0.0f ? ops->target(r->ctx, hq) : 0.0f;
    _Alignas(16) uint8_t to_q[RESTIR_MAX_STRIDE], to_p[RESTIR_MAX_STRIDE];
    float t_pq = 0.0f, j_pq = 0.0f, t_qp = 0.0f, j_qp = 0.0f;
    if (p_p > 0.0f) t_pq = restir_shift(r, hp, dp, dq, to_q, &j_pq, c);
    if (p_q > 0.0f) t_qp = restir_shift(r, hq, dq, dp, to_p, &j_qp, c);
    restir_pair_side(p, dp, dq, p_p, t_pq * j_pq, p_q, t_qp, j_qp, to_p, c);
    restir_pair_side(p, dq, dp, p_q, t_qp * j_qp, p_p, t_pq, j_pq, to_q, c);
}

/* Closes the round for a pixel: the canonical sample is the last candidate. */
static void restir_pair_close(const struct restir_pass *p, uint32_t pixel, struct restir_counters *c)
{
    const struct restir_reuse *r = p->r;
    const size_t stride = r->ops->stride;
    struct restir_pair_acc *a = (struct restir_pair_acc *)r->pair_scratch + pixel;
    const struct restir_head *hc = restir_elem(p->in, stride, pixel);
    struct restir_head *ho = (struct restir_head *)(p->out + (size_t)pixel * stride);
    if (a->k == 0) {  /* the canonical reservoir goes on as it was */
        memcpy(ho, hc, stride);
        restir_estimate_unchanged(r, pixel, hc);
        return;
    }
    const float M_c = (float)hc->M;
    const float p_c = hc->W > 0.0f ? r->ops->target(r->ctx, hc) : 0.0f;
    const float u = restir_pair_u(p, pixel, r->neighbors);
    const unsigned before = a->s.rejected;
    /* The output holds the selected partner's sample, if any was; else the canonical one stays
     * (with W = 0 when it is worth nothing either). */
    bool canonical = !a->s.selected;
    if (p_c > 0.0f) {
        float m_c = reuse_mis_pairwise_canonical(a->canonical_terms, a->k);
        if (restir_estimating(r)) restir_estimate_add(r, &a->est, hc, (double)m_c * hc->W);
        if (reservoir_stream_offer(&a->s, (double)m_c * p_c * hc->W, p_c, M_c, u)) canonical = true;
    } else {
        reservoir_stream_offer(&a->s, 0.0, 0.0f, M_c, u);
    }
    if (canonical) memcpy(ho, hc, stride);
    c->rejected += a->s.rejected - before;
    struct reservoir res = reservoir_stream_finish(&a->s);
    ho->W = res.W;
    ho->M = restir_clamp_m(res.M);
    if (restir_estimating(r)) r->estimate[pixel] = vec3_add(r->estimate[pixel], a->est);
}

/* One pixel's part in pairing p->matching. The owner of a pair (its smaller pixel) does the pair;
 * a pixel without a valid partner does only its own bookkeeping. The first pairing also opens the
 * round and the last one closes it, for both pixels of each pair, while their elements are in
 * cache: the partner relation is symmetric, so every pixel is opened once before any candidate
 * reaches it and closed once after all of them, without passes of their own. */
static void restir_pair_pixel(const struct restir_pass *p, uint32_t pixel, struct restir_counters *c)
{
    const bool opens = p->matching == 0, closes = p->matching + 1 == p->r->neighbors;
    uint32_t q;
    bool valid = true;
    const bool paired = restir_pair_of_round(p, pixel, &valid, &q);
    if (paired && q < pixel) return;  /* q owns the pair */
    if (opens) {
        /* Pairing 0 is an involution: q's partner there is this pixel, and both can produce samples. */
        restir_pair_open(p, pixel, valid, paired ? q : RESTIR_NO_PARTNER);
        if (paired) restir_pair_open(p, q, true, pixel);
    }
    if (paired) restir_pair_work(p, pixel, q, c);
    if (closes) {
        restir_pair_close(p, pixel, c);
        if (paired) restir_pair_close(p, q, c);
    }
}

static void restir_rows(void *ctx, uint32_t job, unsigned worker)
{
    struct restir_pass *p = ctx;
    const struct restir_reuse *r = p->r;
    uint32_t y1 = (job + 1) * RESTIR_ROWS_PER_JOB < r->height ? (job + 1) * RESTIR_ROWS_PER_JOB : r->height;
    struct restir_counters c = {0};
    for (uint32_t y = job * RESTIR_ROWS_PER_JOB; y < y1; y++)
        for (uint32_t x = 0; x < r->width; x++) p->pixel(p, y * r->width + x, &c);
    restir_counters_add(&p->counters[worker], &c);
}

/* A paired pass's pixels block by block. Pairing m pairs each pixel with one in its own block of
 * the grid of B x B blocks shifted by the pairing's offset (restir_partner_of), so a block holds
 * every pair it starts and the elements they touch. Taken row by row, a pass reaches B - 1 rows
 * ahead for its partners: at 256x256 and B = 16 that band of reservoirs, G-buffer surfaces and
 * pair accumulators is about 1 MB, past the second-level cache; a block's is 64 kB. A job is one
 * band of blocks, taken left to right, so that two threads work B rows apart rather than on the
 * two sides of a block's edge, which share cache lines in each row (jobs of one block each were
 * 12 % slower than rows with two threads, and 7 % faster with one). Where there are few bands for
 * the threads a band is split into groups of columns (RESTIR_JOBS_PER_THREAD jobs a thread), and
 * where the whole image holds fewer blocks than that (a radius near the image's size: blocks
 * then save nothing either) the pass keeps to rows. Each pixel still takes part in each pairing
 * exactly once and its candidates arrive in pairing order, so the order of the pixels within a
 * pass changes nothing in the result. */
#define RESTIR_JOBS_PER_THREAD 4u

struct restir_blocks {
    uint32_t log2, ox, oy;    /* B = 1 << log2; the grid's offset, as restir_partner_of takes it */
    uint32_t bands, columns;  /* the grid's rows and columns that meet the image */
};

static struct restir_blocks restir_blocks_of(const struct restir_pass *p)
{
    const uint32_t mask = (1u << p->pair_log2) - 1;
    const uint64_t h = p->pair_key[p->matching];
    struct restir_blocks b = {p->pair_log2, (uint32_t)h & mask, (uint32_t)(h >> 20) & mask, 0, 0};
    b.bands = (p->r->height + b.oy + mask) >> b.log2;
    b.columns = (p->r->width + b.ox + mask) >> b.log2;
    return b;
}

/* The pixels [*lo, *hi) of the image's `extent` that lie in block `index` of a grid offset by `offset`. */
static void restir_block_span(uint32_t index, uint32_t log2, uint32_t offset, uint32_t extent, uint32_t *lo,
                              uint32_t *hi)
{
    const uint64_t g0 = (uint64_t)index << log2, g1 = g0 + (1u << log2);
    *lo = g0 > offset ? (uint32_t)(g0 - offset) : 0;
    *hi = g1 - offset < extent ? (uint32_t)(g1 - offset) : extent;
}

static void restir_band(void *ctx, uint32_t job, unsigned worker)
{
    struct restir_pass *p = ctx;
    const struct restir_reuse *r = p->r;
    const struct restir_blocks b = restir_blocks_of(p);
    const uint32_t band = job / p->band_groups, group = job % p->band_groups;
    uint32_t y0, y1;
    restir_block_span(band, b.log2, b.oy, r->height, &y0, &y1);
    struct restir_counters c = {0};
    const uint32_t col1 = (uint32_t)((uint64_t)(group + 1) * b.columns / p->band_groups);
    for (uint32_t col = (uint32_t)((uint64_t)group * b.columns / p->band_groups); col < col1; col++) {
        uint32_t x0, x1;
        restir_block_span(col, b.log2, b.ox, r->width, &x0, &x1);
        for (uint32_t y = y0; y < y1; y++)
            for (uint32_t x = x0; x < x1; x++) p->pixel(p, y * r->width + x, &c);
    }
    restir_counters_add(&p->counters[worker], &c);
}

static bool restir_run(const struct restir_reuse *r, restir_pixel_fn *fn, const uint8_t *in, uint8_t *out,
                       uint32_t matching, struct restir_counters *c, struct err *err)
{
    /* On the stack (40 KiB of counters): a frame allocates nothing. */
    struct restir_pass pass;
    memset(&pass, 0, sizeof pass);
    pass.r = r;
    pass.pixel = fn;
    pass.in = in;
    pass.out = out;
    pass.matching = matching;
    if (r->paired) {
        restir_pair_keys(r, pass.pair_key);  /* 65 hashes: nothing beside a pass */
        pass.pair_log2 = restir_pair_log2(r->radius);
    }
    unsigned threads = r->threads ? r->threads : parallel_default_threads();
    if (threads > RESTIR_MAX_WORKERS) threads = RESTIR_MAX_WORKERS;
    uint32_t jobs = (r->height + RESTIR_ROWS_PER_JOB - 1) / RESTIR_ROWS_PER_JOB;
    const uint32_t want = RESTIR_JOBS_PER_THREAD * threads;
    bool bands = false;
    if (fn == restir_pair_pixel) {
        const struct restir_blocks b = restir_blocks_of(&pass);
        if ((uint64_t)b.bands * b.columns >= want) {
            bands = true;
            pass.band_groups = (want + b.bands - 1) / b.bands;
            if (pass.band_groups > b.columns) pass.band_groups = b.columns;
            jobs = b.bands * pass.band_groups;
        }
    }
    if (!parallel_run(threads, jobs, bands ? restir_band : restir_rows, &pass, NULL, NULL, err)) return false;
    for (unsigned i = 0; i < threads; i++) restir_counters_add(c, &pass.counters[i]);
    return true;
}

bool restir_temporal_pass(const struct restir_reuse *r, uint8_t *cur, struct restir_counters *c, struct err *err)
{
    if (!r->history) return true;
    return restir_run(r, restir_temporal_pixel, NULL, cur, 0, c, err);
}

bool restir_spatial_pass(const struct restir_reuse *r, const uint8_t *in, uint8_t *out, struct restir_counters *c,
                         struct err *err)
{
    if (!r->paired || r->neighbors == 0) return restir_run(r, restir_spatial_pixel, in, out, 0, c, err);
    if (!r->pair_scratch) return err_set(err, ERR_INTERNAL, NULL, "paired spatial reuse without its scratch buffer");
    for (uint32_t m = 0; m < r->neighbors; m++)
        if (!restir_run(r, restir_pair_pixel, in, out, m, c, err)) return false;
    return true;
}

bool restir_gbuffer_next(struct gbuffer gbuf[2], uint32_t *cur, bool *has_history, struct gbuffer_frame gf,
                         uint64_t *rays, struct err *err)
{
    const bool history = *has_history && gf.prev_scene;
    if (history) *cur ^= 1u;
    else gf.prev_scene = NULL;
    gf.prev_gbuffer = history ? &gbuf[*cur ^ 1u] : NULL;
    if (!gbuffer_render(&gbuf[*cur], &gf, rays, err)) return false;
    if (!history) *has_history = false;
    return true;
}

void *restir_frame_open(struct restir_frame *fr, size_t pass_bytes, struct restir_session *s,
                        const struct method_frame *f, struct image *out, bool temporal, void *stats, void *local,
                        size_t stats_bytes, struct err *err)
{
    memset(fr, 0, pass_bytes);
    if (out && (out->width != s->width || out->height != s->height)) {
        err_set(err, ERR_INVALID, NULL, "the output image is %ux%u, the session %ux%u", out->width, out->height,
                s->width, s->height);
        return NULL;
    }
    if (s->layers > RESTIR_MAX_LAYERS) {
        err_set(err, ERR_INTERNAL, NULL, "%u reservoirs per pixel, at most %u", s->layers, RESTIR_MAX_LAYERS);
        return NULL;
    }
    if (!stats) stats = local;
    memset(stats, 0, stats_bytes);
    fr->s = s;
    fr->f = f;
    fr->out = out;
    fr->stats = stats;
    camera_init(&fr->camera, f->camera, s->width, s->height);
    fr->threads = restir_threads(f->threads);
    /* Before the G-buffer pass, which drops a history the frame cannot use. */
    fr->history = s->has_history && f->prev_scene && temporal;
    fr->temporal = temporal;
    return stats;
}

bool restir_frame_gbuffer(struct restir_frame *fr, float jitter_walk, bool pairs, bool check_history,
                          uint32_t emission_samples, struct err *err)
{
    struct restir_session *s = fr->s;
    const struct method_frame *f = fr->f;
    if (pairs && !s->pair_scratch)
        return err_set(err, ERR_INVALID, "/params/paired_spatial", "the session was made without paired spatial reuse");
    clock_gettime(CLOCK_MONOTONIC, &fr->t0);
    struct gbuffer_frame gf = {.scene = f->scene, .camera = f->camera, .prev_scene = f->prev_scene,
                               .prev_camera = f->prev_camera, .seed = f->seed, .frame = f->frame,
                               .threads = fr->threads, .jitter_walk = jitter_walk, .check_history = check_history,
                               .stratify = !fr->temporal, .emission_samples = emission_samples};
    uint64_t grays = 0;
    if (!restir_gbuffer_next(s->gbuf, &s->cur, &s->has_history, gf, &grays, err)) return false;
    fr->stats->gbuffer_ms = parallel_lap_ms(&fr->t0);
    fr->stats->rays_intersect += grays;
    return true;
}

void restir_frame_domains(const struct restir_session *s, const struct method_frame *f, const struct scene *scene[2],
                          struct vec3 eye[2], const struct gbuffer *gbuf[2])
{
    scene[RESTIR_CURRENT] = f->scene;
    scene[RESTIR_PREVIOUS] = f->prev_scene ? f->prev_scene : f->scene;
    if (eye) {
        eye[RESTIR_CURRENT] = f->camera->position;
        eye[RESTIR_PREVIOUS] = f->prev_camera ? f->prev_camera->position : f->camera->position;
    }
    gbuf[RESTIR_CURRENT] = &s->gbuf[s->cur];
    gbuf[RESTIR_PREVIOUS] = &s->gbuf[s->cur ^ 1u];
}

static bool restir_frame_run(struct restir_frame *fr, parallel_job_fn *fn, struct err *err)
{
    return restir_run_rows(fr->s->height, RESTIR_FRAME_ROWS, fr->threads, fn, fr, err);
}

bool restir_frame_initial(struct restir_frame *fr, parallel_job_fn *fn, struct err *err)
{
    if (!restir_frame_run(fr, fn, err)) return false;
    /* The initial pass alone (no output) stops here: res[1] is not this frame's, nor under its
     * G-buffer, so a following frame must not take it as history. */
    if (!fr->out) fr->s->has_history = false;
    fr->stats->initial_ms = parallel_lap_ms(&fr->t0);
    for (unsigned i = 0; i < fr->threads; i++) restir_pass_stats_add(fr->stats, &fr->counters[i]);
    clock_gettime(CLOCK_MONOTONIC, &fr->t0);
    return true;
}

struct restir_reuse *restir_frame_reuse(struct restir_frame *fr, const struct restir_ops *ops, const void *ctx,
                                        size_t ctx_stride, uint32_t temporal_cap, uint32_t neighbors, float radius,
                                        bool paired)
{
    const struct restir_session *s = fr->s;
    for (uint32_t l = 0; l < s->layers; l++)
        fr->reuse[l] = (struct restir_reuse){.ops = ops, .ctx = (const uint8_t *)ctx + l * ctx_stride,
                                             .width = s->width, .height = s->height, .seed = fr->f->seed,
                                             .frame = fr->f->frame, .threads = fr->threads,
                                             .gbuf = &s->gbuf[s->cur], .temporal_cap = temporal_cap,
                                             .neighbors = neighbors, .radius = radius, .paired = paired,
                                             .pair_scratch = s->pair_scratch};
    return fr->reuse;
}

/* The bytes of one layer of a reservoir buffer. */
static size_t restir_layer_bytes(const struct restir_session *s)
{
    return (size_t)s->width * s->height * s->sample_bytes;
}

bool restir_frame_temporal(struct restir_frame *fr, struct err *err)
{
    const struct restir_session *s = fr->s;
    const size_t layer_bytes = restir_layer_bytes(s);
    for (uint32_t l = 0; l < s->layers; l++) {
        fr->reuse[l].history = fr->history ? s->res[1] + l * layer_bytes : NULL;
        if (!restir_temporal_pass(&fr->reuse[l], s->res[0] + l * layer_bytes, &fr->reuse_counters, err))
            return false;
    }
    fr->stats->temporal_ms = parallel_lap_ms(&fr->t0);
    return true;
}

bool restir_frame_spatial(struct restir_frame *fr, bool estimate, bool last, struct err *err)
{
    struct restir_session *s = fr->s;
    const size_t layer_bytes = restir_layer_bytes(s);
    fr->estimated = estimate;
    for (uint32_t l = 0; l < s->layers; l++) {
        fr->reuse[l].estimate = estimate ? fr->out->pixels : NULL;  /* adds to the light outside the reservoirs */
        if (!restir_spatial_pass(&fr->reuse[l], s->res[0] + l * layer_bytes, s->res[1] + l * layer_bytes,
                                 &fr->reuse_counters, err))
            return false;
    }
    if (!last) restir_session_swap(s);
    return true;
}

void restir_frame_reused(struct restir_frame *fr)
{
    fr->stats->spatial_ms = parallel_lap_ms(&fr->t0);
    restir_pass_stats_add(fr->stats, &fr->reuse_counters);
}

bool restir_frame_shade(struct restir_frame *fr, parallel_job_fn *fn, struct err *err)
{
    memset(fr->nonfinite, 0, sizeof fr->nonfinite);
    if (!restir_frame_run(fr, fn, err)) return false;
    for (unsigned i = 0; i < fr->threads; i++) fr->stats->nonfinite += fr->nonfinite[i];
    fr->stats->shade_ms = parallel_lap_ms(&fr->t0);
    fr->s->has_history = true;
    return true;
}
