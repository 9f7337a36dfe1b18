/* reservoir.h — generalized resampled importance sampling (GRIS) reservoirs, the state every
 * ReSTIR method keeps per pixel. The sample itself is the technique's own payload (a path, a
 * light vertex, a manifold solution): a reservoir records only the numbers resampling needs,
 * and reservoir_stream_offer tells the caller when to copy the candidate's payload.
 * Fields keep one meaning each (docs/architecture.md): `w_sum` exists only while streaming,
 * `W` is the unbiased contribution weight of the selected sample, `M` the confidence,
 * `target` the target function p̂ of the selected sample in the pixel it belongs to.
 * Header-only, allocation-free, thread-safe (no shared state).
 * Refs: Lin et al. 2022 (GRIS, §4–5: resampling weights m_i p̂(T(X_i)) W_i |J_i|, W = w_sum / p̂(Y));
 * docs/methods.md, "Reuse shared by the methods" (double w_sum, non-finite weights rejected
 * and counted). */
#ifndef RESTIRD_RESERVOIR_H
#define RESTIRD_RESERVOIR_H

#include <math.h>
#include <stdbool.h>

/* A finished reservoir, as stored per pixel (the technique stores its payload beside it). */
struct reservoir {
    float W;       /* unbiased contribution weight of the selected sample; 0 = no sample */
    float target;  /* p̂(Y) in the reservoir's own pixel */
    float M;       /* confidence (number of candidates it stands for, possibly capped) */
};

/* A reservoir being filled by streaming resampling. */
struct reservoir_stream {
    double w_sum;     /* sum of the resampling weights offered so far (double: many small terms) */
    float target;     /* p̂ of the selected candidate */
    float M;          /* sum of the confidences offered */
    bool selected;    /* a candidate with w > 0 was selected */
    unsigned rejected;/* offers refused for a non-finite or negative weight or target */
};

static inline void reservoir_stream_begin(struct reservoir_stream *s)
{
    *s = (struct reservoir_stream){0};
}

/* Offers a candidate with resampling weight `w` (for GRIS: m_i * p̂(T(X_i)) * W_i * |J_i|), its
 * target value in this pixel and its confidence M. `u` is uniform in [0, 1) from the pixel's
 * own random stream. Returns true when the candidate replaces the current selection (the
 * caller copies its payload then). A candidate with w = 0 still adds its confidence: null
 * samples count as candidates. Non-finite or negative weights are refused and counted: they add
 * neither weight nor confidence (a NaN must never reach w_sum). */
static inline bool reservoir_stream_offer(struct reservoir_stream *s, double w, float target, float M, float u)
{
    if (!(w >= 0.0) || !isfinite(w) || !(target >= 0.0f) || !isfinite(target) || !(M >= 0.0f)) {
        s->rejected++;
        return false;
    }
    s->M += M;
    if (w == 0.0) return false;
    s->w_sum += w;
    /* Select with probability w / w_sum; u < 1 so the first positive weight always wins. */
    if ((double)u * s->w_sum < w) {
        s->target = target;
        s->selected = true;
        return true;
    }
    return false;
}

/* W = w_sum / p̂(Y); no sample (or p̂(Y) = 0) gives W = 0. */
static inline struct reservoir reservoir_stream_finish(const struct reservoir_stream *s)
{
    struct reservoir r = {0.0f, 0.0f, s->M};
    if (s->selected && s->target > 0.0f) {
        r.W = (float)(s->w_sum / (double)s->target);
        r.target = s->target;
    }
    return r;
}

/* Caps the confidence of a reused reservoir (temporal history: 20x the current M by default). */
static inline void reservoir_cap_m(struct reservoir *r, float cap)
{
    if (r->M > cap) r->M = cap;
}

#endif
