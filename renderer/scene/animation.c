/* animation.c — values of keyframe tracks at a time (see animation.h for contracts).
 * Every channel (a vec3, a trs as 9 floats, the fov) is evaluated by one routine over a
 * strided view of the caller's key array, so camera and shape tracks share the search and the
 * interpolation. Must not allocate or fail: an evaluation always produces a value.
 * Catmull-Rom on non-uniform key times is a cubic Hermite spline whose tangent at a key is the
 * finite difference of its neighbours, (p[i+1] - p[i-1]) / (t[i+1] - t[i-1]), one-sided at
 * the ends: it passes through every key, is C1 at interior keys, and is the straight line when
 * a channel has two keys. Refs: Catmull & Rom 1974; cubic Hermite basis, e.g. Farin,
 * "Curves and Surfaces for CAGD", ch. 7. */
#include "scene/animation.h"

#include <math.h>
#include <stddef.h>
#include <string.h>

/* The widest channel: a trs is translate, rotate_deg and scale, 3 floats each. */
#define ANIMATION_MAX_DIM 9

_Static_assert(sizeof(struct vec3) == 3 * sizeof(float), "vec3 must be three packed floats");
_Static_assert(sizeof(struct trs) == 9 * sizeof(float), "trs must be nine packed floats");

/* One channel of a track: `dim` floats at byte `val_off` of each key, present in the keys
 * whose bool at `has_off` is true (in every key when has_off < 0). */
struct animation_channel {
    const unsigned char *keys;
    size_t stride, t_off, val_off;
    ptrdiff_t has_off;
    uint32_t count;
    int dim;
};

/* Where t falls among the keys that set a channel: lo and hi are consecutive setting keys with
 * t in [t_lo, t_hi), prev and next the setting keys around them (-1 where none). Outside the
 * keyed range lo == hi, the end key whose value holds. lo == -1: no key sets the channel. */
struct animation_span {
    int64_t prev, lo, hi, next;
};

static double animation_key_t(const struct animation_channel *ch, int64_t i)
{
    double t;
    memcpy(&t, ch->keys + (size_t)i * ch->stride + ch->t_off, sizeof t);
    return t;
}

static bool animation_key_has(const struct animation_channel *ch, int64_t i)
{
    if (ch->has_off < 0) return true;
    bool has;
    memcpy(&has, ch->keys + (size_t)i * ch->stride + (size_t)ch->has_off, sizeof has);
    return has;
}

/* memcpy, not a float pointer: a trs is read as 9 floats across its three vec3 members. */
static void animation_key_value(const struct animation_channel *ch, int64_t i, double *v)
{
    float f[ANIMATION_MAX_DIM];
    memcpy(f, ch->keys + (size_t)i * ch->stride + ch->val_off, (size_t)ch->dim * sizeof(float));
    for (int c = 0; c < ch->dim; c++) v[c] = f[c];
}

/* Setting key at or before i (downwards), or after i (upwards); -1 when none. */
static int64_t animation_set_below(const struct animation_channel *ch, int64_t i)
{
    while (i >= 0 && !animation_key_has(ch, i)) i--;
    return i;
}

static int64_t animation_set_above(const struct animation_channel *ch, int64_t i)
{
    while (i < (int64_t)ch->count && !animation_key_has(ch, i)) i++;
    return i < (int64_t)ch->count ? i : -1;
}

/* Binary search over all keys (times are sorted whatever channels a key sets), then a walk to
 * the nearest setting keys: O(log n) for dense channels, O(n) at worst for sparse ones. */
static struct animation_span animation_locate(const struct animation_channel *ch, double t)
{
    /* p = last key with t_p <= t, -1 if none. A NaN t compares false and lands before the
     * first key, so it still yields a key's value. */
    int64_t a = 0, b = (int64_t)ch->count;
    while (a < b) {
        int64_t m = a + (b - a) / 2;
        if (animation_key_t(ch, m) <= t) a = m + 1;
        else b = m;
    }
    int64_t p = a - 1;
    struct animation_span s = {-1, -1, -1, -1};
    s.lo = animation_set_below(ch, p);
    s.hi = animation_set_above(ch, p + 1);
    if (s.lo < 0 && s.hi < 0) return s;           /* no key sets the channel */
    if (s.lo < 0) { s.lo = s.hi; return s; }      /* before the first setting key */
    if (s.hi < 0) { s.hi = s.lo; return s; }      /* at or after the last setting key */
    s.prev = animation_set_below(ch, s.lo - 1);
    s.next = animation_set_above(ch, s.hi + 1);
    return s;
}

/* Value of the channel at t over span s (s.lo >= 0). lo_out/hi_out (may be NULL) receive the
 * per-component range of the keys the value was made from, for callers that must keep a
 * Catmull-Rom overshoot inside the keyed range. */
static void animation_eval(const struct animation_channel *ch, const struct animation_span *s,
                           enum animation_interp interp, double t, float *out, double *lo_out,
                           double *hi_out)
{
    double p0[ANIMATION_MAX_DIM], p1[ANIMATION_MAX_DIM];
    animation_key_value(ch, s->lo, p0);
    if (s->hi == s->lo) {
        for (int c = 0; c < ch->dim; c++) {
            out[c] = (float)p0[c];
            if (lo_out) lo_out[c] = hi_out[c] = p0[c];
        }
        return;
    }
    animation_key_value(ch, s->hi, p1);
    double t0 = animation_key_t(ch, s->lo), t1 = animation_key_t(ch, s->hi);
    double h = t1 - t0;
    double u = (t - t0) / h;  /* in [0, 1): t0 <= t < t1 by construction */

    bool cubic = interp == ANIMATION_CATMULL_ROM;
    double pp[ANIMATION_MAX_DIM] = {0}, pn[ANIMATION_MAX_DIM] = {0};  /* read only where set; -O3 cannot see it */
    double tp = 0.0, tn = 0.0;
    if (cubic && s->prev >= 0) {
        animation_key_value(ch, s->prev, pp);
        tp = animation_key_t(ch, s->prev);
    }
    if (cubic && s->next >= 0) {
        animation_key_value(ch, s->next, pn);
        tn = animation_key_t(ch, s->next);
    }
    /* Hermite basis for the deviation from the chord: h10 = u^3 - 2u^2 + u, h11 = u^3 - u^2. */
    double h10 = u * (u - 1.0) * (u - 1.0), h11 = u * u * (u - 1.0);
    for (int c = 0; c < ch->dim; c++) {
        double delta = p1[c] - p0[c];
        double v = p0[c] + u * delta;
        double lo = fmin(p0[c], p1[c]), hi = fmax(p0[c], p1[c]);
        if (cubic) {
            /* The Hermite cubic written as chord + h*(h10*(m0 - d) + h11*(m1 - d)), d the chord
             * slope: algebraically the usual h00*p0 + h10*h*m0 + h01*p1 + h11*h*m1, but an end
             * tangent computed as the same one-sided difference as d cancels to exactly 0, so
             * a 2-key channel gives the linear value bit for bit. */
            double d = delta / h;
            double m0 = s->prev >= 0 ? (p1[c] - pp[c]) / (t1 - tp) : d;
            double m1 = s->next >= 0 ? (pn[c] - p0[c]) / (tn - t0) : d;
            v += h * (h10 * (m0 - d) + h11 * (m1 - d));
            if (s->prev >= 0) { lo = fmin(lo, pp[c]); hi = fmax(hi, pp[c]); }
            if (s->next >= 0) { lo = fmin(lo, pn[c]); hi = fmax(hi, pn[c]); }
        }
        out[c] = (float)v;
        if (lo_out) { lo_out[c] = lo; hi_out[c] = hi; }
    }
}

static float animation_clampf(float v, double lo, double hi)
{
    return (float)fmin(fmax((double)v, lo), hi);
}

/* The channel of `member` in an array of `type` keys (has_off: see struct animation_channel). */
#define ANIMATION_CHANNEL(key_array, n, type, has_off_, member, dim_)                            \
    ((struct animation_channel){.keys = (const unsigned char *)(key_array), .stride = sizeof(type), \
                                .t_off = offsetof(type, t_s), .val_off = offsetof(type, member),  \
                                .has_off = (has_off_), .count = (n), .dim = (dim_)})

void animation_camera_at(const struct animation_camera_key *keys, uint32_t count, enum animation_interp interp,
                         double t_s, struct camera_desc *out)
{
#define ANIMATION_CAMERA(member, dim) \
    ANIMATION_CHANNEL(keys, count, struct animation_camera_key, -1, camera.member, dim)
    const struct animation_channel pos = ANIMATION_CAMERA(position, 3);
    const struct animation_channel look = ANIMATION_CAMERA(look_at, 3);
    const struct animation_channel up = ANIMATION_CAMERA(up, 3);
    const struct animation_channel fov = ANIMATION_CAMERA(fov_deg, 1);
#undef ANIMATION_CAMERA
    /* Every camera key sets every field: one search serves all four channels. */
    struct animation_span s = animation_locate(&pos, t_s);
    if (s.lo < 0) return;  /* count == 0 breaks the contract; leave *out as it was */
    float v[3];
    animation_eval(&pos, &s, interp, t_s, v, NULL, NULL);
    out->position = vec3_make(v[0], v[1], v[2]);
    animation_eval(&look, &s, interp, t_s, v, NULL, NULL);
    out->look_at = vec3_make(v[0], v[1], v[2]);

    /* fov is validated into (0, 180) at every key; an overshoot must not leave that range,
     * so the value stays within the keys it was interpolated from. */
    double lo, hi;
    animation_eval(&fov, &s, interp, t_s, v, &lo, &hi);
    out->fov_deg = animation_clampf(v[0], lo, hi);

    /* up is a direction: interpolated, then renormalised. If it degenerates (a key pair with
     * opposite ups crosses zero, or it turns parallel to the view direction) the nearer
     * key's up stands in, which was valid for a nearby view. */
    animation_eval(&up, &s, interp, t_s, v, NULL, NULL);
    struct vec3 u = vec3_make(v[0], v[1], v[2]);
    struct vec3 fwd = vec3_normalize(vec3_sub(out->look_at, out->position));
    float len = vec3_length(u);
    bool bad = !(len > 1e-6f) || !isfinite(len) || vec3_length(vec3_cross(fwd, vec3_scale(u, 1.0f / len))) < 1e-6f;
    if (bad) {
        int64_t near = s.lo;
        if (s.hi != s.lo && t_s - animation_key_t(&pos, s.lo) > animation_key_t(&pos, s.hi) - t_s) near = s.hi;
        u = keys[near].camera.up;
    }
    out->up = vec3_normalize(u);
}

void animation_shape_at(const struct animation_shape_key *keys, uint32_t count, enum animation_interp interp,
                        double t_s, struct animation_shape_state *out)
{
#define ANIMATION_SHAPE(has, member, dim)                                                          \
    ANIMATION_CHANNEL(keys, count, struct animation_shape_key,                                     \
                      (ptrdiff_t)offsetof(struct animation_shape_key, has), member, dim)
    const struct animation_channel pos = ANIMATION_SHAPE(has_position, position, 3);
    const struct animation_channel xf = ANIMATION_SHAPE(has_transform, transform, 9);
    const struct animation_channel em = ANIMATION_SHAPE(has_emission, emission, 3);
#undef ANIMATION_SHAPE
    memset(out, 0, sizeof *out);
    out->transform = trs_identity();

    float v[ANIMATION_MAX_DIM];
    double lo[ANIMATION_MAX_DIM], hi[ANIMATION_MAX_DIM];
    struct animation_span s = animation_locate(&pos, t_s);
    if ((out->has_position = s.lo >= 0)) {
        animation_eval(&pos, &s, interp, t_s, v, NULL, NULL);
        out->position = vec3_make(v[0], v[1], v[2]);
    }
    s = animation_locate(&xf, t_s);
    if ((out->has_transform = s.lo >= 0)) {
        animation_eval(&xf, &s, interp, t_s, v, lo, hi);
        /* Scale stays within its keys' range: an overshoot through 0 would flatten or mirror
         * a shape whose keys never do. Translation and angles may overshoot, as a spline does. */
        for (int c = 6; c < 9; c++) v[c] = animation_clampf(v[c], lo[c], hi[c]);
        out->transform.translate = vec3_make(v[0], v[1], v[2]);
        out->transform.rotate_deg = vec3_make(v[3], v[4], v[5]);
        out->transform.scale = vec3_make(v[6], v[7], v[8]);
    }
    s = animation_locate(&em, t_s);
    if ((out->has_emission = s.lo >= 0)) {
        animation_eval(&em, &s, interp, t_s, v, NULL, NULL);
        out->emission = vec3_make(fmaxf(v[0], 0.0f), fmaxf(v[1], 0.0f), fmaxf(v[2], 0.0f));
    }
}
