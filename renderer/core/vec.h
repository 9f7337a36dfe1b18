/* vec.h — small value types for geometry and colour: vec3 (float), affine transforms.
 * Header-only and allocation-free; every renderer file may include it.
 * Colours are linear RGB stored in the same vec3 as positions and directions. */
#ifndef RESTIRD_VEC_H
#define RESTIRD_VEC_H

#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <string.h>

#define PI_F 3.14159265358979323846f
#define INV_PI_F 0.31830988618379067154f

struct vec3 { float x, y, z; };

static inline struct vec3 vec3_make(float x, float y, float z) { return (struct vec3){x, y, z}; }
static inline struct vec3 vec3_splat(float s) { return (struct vec3){s, s, s}; }
static inline struct vec3 vec3_add(struct vec3 a, struct vec3 b) { return (struct vec3){a.x + b.x, a.y + b.y, a.z + b.z}; }
static inline struct vec3 vec3_sub(struct vec3 a, struct vec3 b) { return (struct vec3){a.x - b.x, a.y - b.y, a.z - b.z}; }
static inline struct vec3 vec3_mul(struct vec3 a, struct vec3 b) { return (struct vec3){a.x * b.x, a.y * b.y, a.z * b.z}; }
static inline struct vec3 vec3_div(struct vec3 a, struct vec3 b) { return (struct vec3){a.x / b.x, a.y / b.y, a.z / b.z}; }
static inline struct vec3 vec3_scale(struct vec3 a, float s) { return (struct vec3){a.x * s, a.y * s, a.z * s}; }
static inline struct vec3 vec3_neg(struct vec3 a) { return (struct vec3){-a.x, -a.y, -a.z}; }
static inline float vec3_dot(struct vec3 a, struct vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static inline struct vec3 vec3_cross(struct vec3 a, struct vec3 b)
{
    return (struct vec3){a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
static inline float vec3_length2(struct vec3 a) { return vec3_dot(a, a); }
static inline float vec3_length(struct vec3 a) { return sqrtf(vec3_dot(a, a)); }
static inline struct vec3 vec3_normalize(struct vec3 a)
{
    float l = vec3_length(a);
    return l > 0.0f ? vec3_scale(a, 1.0f / l) : a;
}
static inline struct vec3 vec3_madd(struct vec3 a, struct vec3 b, float s)  /* a + b*s */
{
    return (struct vec3){a.x + b.x * s, a.y + b.y * s, a.z + b.z * s};
}
static inline float vec3_max_comp(struct vec3 a) { return fmaxf(a.x, fmaxf(a.y, a.z)); }
static inline float vec3_min_comp(struct vec3 a) { return fminf(a.x, fminf(a.y, a.z)); }
static inline float vec3_sum(struct vec3 a) { return a.x + a.y + a.z; }
static inline uint32_t vec_float_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}
/* Both tests run several times per path vertex. Written as three `== 0.0f` / isfinite tests
 * they compile to a NaN-aware compare-and-branch chain per component; these forms give the
 * same answers for every input (NaN included) in a few branch-free instructions. */
static inline bool vec3_is_zero(struct vec3 a)  /* all components +0 or -0 */
{
    return ((vec_float_bits(a.x) | vec_float_bits(a.y) | vec_float_bits(a.z)) << 1) == 0;
}
static inline bool vec3_equal(struct vec3 a, struct vec3 b)
{
    return a.x == b.x && a.y == b.y && a.z == b.z;
}
static inline bool vec3_is_finite(struct vec3 a)
{
    /* x - x is +0 for finite x and NaN for inf or NaN, so s is 0 or NaN. Relies on IEEE
     * semantics (no -ffinite-math-only / -ffast-math, which would also break isfinite). */
    float s = (a.x - a.x) + (a.y - a.y) + (a.z - a.z);
    return s == s;
}
static inline float vec3_comp(struct vec3 a, int i) { return i == 0 ? a.x : (i == 1 ? a.y : a.z); }
/* Rec. 709 luminance of a linear RGB colour. */
static inline float vec3_luminance(struct vec3 c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }

/* Orthonormal basis around unit n (Duff et al. 2017, branchless). */
struct frame { struct vec3 s, t, n; };
static inline struct frame frame_from_normal(struct vec3 n)
{
    float sign = copysignf(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float b = n.x * n.y * a;
    struct frame f;
    f.s = (struct vec3){1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x};
    f.t = (struct vec3){b, sign + n.y * n.y * a, -n.y};
    f.n = n;
    return f;
}
static inline struct vec3 frame_to_local(const struct frame *f, struct vec3 v)
{
    return (struct vec3){vec3_dot(v, f->s), vec3_dot(v, f->t), vec3_dot(v, f->n)};
}
static inline struct vec3 frame_to_world(const struct frame *f, struct vec3 v)
{
    return vec3_add(vec3_add(vec3_scale(f->s, v.x), vec3_scale(f->t, v.y)), vec3_scale(f->n, v.z));
}

/* Affine transform: p' = M p + t, with M stored row-major in m[r][c], c = 3 the translation. */
struct xform { float m[3][4]; };

static inline struct xform xform_identity(void)
{
    return (struct xform){{{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}}};
}
static inline struct vec3 xform_point(const struct xform *x, struct vec3 p)
{
    return (struct vec3){
        x->m[0][0] * p.x + x->m[0][1] * p.y + x->m[0][2] * p.z + x->m[0][3],
        x->m[1][0] * p.x + x->m[1][1] * p.y + x->m[1][2] * p.z + x->m[1][3],
        x->m[2][0] * p.x + x->m[2][1] * p.y + x->m[2][2] * p.z + x->m[2][3]};
}
static inline struct vec3 xform_vector(const struct xform *x, struct vec3 v)
{
    return (struct vec3){
        x->m[0][0] * v.x + x->m[0][1] * v.y + x->m[0][2] * v.z,
        x->m[1][0] * v.x + x->m[1][1] * v.y + x->m[1][2] * v.z,
        x->m[2][0] * v.x + x->m[2][1] * v.y + x->m[2][2] * v.z};
}
/* a * b (apply b first). */
static inline struct xform xform_compose(const struct xform *a, const struct xform *b)
{
    struct xform r;
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 4; j++) {
            float s = (j == 3) ? a->m[i][3] : 0.0f;
            for (int k = 0; k < 3; k++) s += a->m[i][k] * b->m[k][j];
            r.m[i][j] = s;
        }
    }
    return r;
}
static inline float xform_det3(const struct xform *x)
{
    const float (*m)[4] = x->m;
    return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
           m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
           m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
}
/* Inverse of an affine transform; false when the linear part is singular. */
static inline bool xform_invert(const struct xform *x, struct xform *out)
{
    const float (*m)[4] = x->m;
    float det = xform_det3(x);
    if (!(fabsf(det) > 1e-30f)) return false;
    float id = 1.0f / det;
    struct xform r;
    r.m[0][0] = (m[1][1] * m[2][2] - m[1][2] * m[2][1]) * id;
    r.m[0][1] = (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * id;
    r.m[0][2] = (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * id;
    r.m[1][0] = (m[1][2] * m[2][0] - m[1][0] * m[2][2]) * id;
    r.m[1][1] = (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * id;
    r.m[1][2] = (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * id;
    r.m[2][0] = (m[1][0] * m[2][1] - m[1][1] * m[2][0]) * id;
    r.m[2][1] = (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * id;
    r.m[2][2] = (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * id;
    for (int i = 0; i < 3; i++)
        r.m[i][3] = -(r.m[i][0] * m[0][3] + r.m[i][1] * m[1][3] + r.m[i][2] * m[2][3]);
    *out = r;
    return true;
}
/* Normal transform: inverse transpose of the linear part (inv = inverse of x). */
static inline struct vec3 xform_normal(const struct xform *inv, struct vec3 n)
{
    return (struct vec3){
        inv->m[0][0] * n.x + inv->m[1][0] * n.y + inv->m[2][0] * n.z,
        inv->m[0][1] * n.x + inv->m[1][1] * n.y + inv->m[2][1] * n.z,
        inv->m[0][2] * n.x + inv->m[1][2] * n.y + inv->m[2][2] * n.z};
}

/* A transform given as its parts, as scenes and animation keys write it: the matrix is
 * translate * Rz * Ry * Rx * scale (scale first, then rotations about X, Y, Z in degrees,
 * right-handed, then the translation). Parts interpolate where matrices do not. */
struct trs { struct vec3 translate, rotate_deg, scale; };

static inline struct trs trs_identity(void)
{
    return (struct trs){{0, 0, 0}, {0, 0, 0}, {1, 1, 1}};
}

/* Composes in double precision; false when an entry leaves the float range. */
static inline bool xform_from_trs(const struct trs *t, struct xform *out)
{
    const double a[3] = {t->rotate_deg.x, t->rotate_deg.y, t->rotate_deg.z};
    const double sc[3] = {t->scale.x, t->scale.y, t->scale.z};
    const double tr[3] = {t->translate.x, t->translate.y, t->translate.z};
    double c[3], sn[3];
    for (int i = 0; i < 3; i++) {
        double rad = fmod(a[i], 360.0) * (3.14159265358979323846 / 180.0);
        c[i] = cos(rad);
        sn[i] = sin(rad);
    }
    /* Rz * Ry * Rx, written out. */
    const double r[3][3] = {
        {c[2] * c[1], c[2] * sn[1] * sn[0] - sn[2] * c[0], c[2] * sn[1] * c[0] + sn[2] * sn[0]},
        {sn[2] * c[1], sn[2] * sn[1] * sn[0] + c[2] * c[0], sn[2] * sn[1] * c[0] - c[2] * sn[0]},
        {-sn[1], c[1] * sn[0], c[1] * c[0]}};
    bool finite = true;
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++) out->m[i][j] = (float)(r[i][j] * sc[j]);
        out->m[i][3] = (float)tr[i];
        for (int j = 0; j < 4; j++) finite = finite && isfinite(out->m[i][j]);
    }
    return finite;
}

/* A vec3 on four SSE lanes (GCC/Clang vector extensions), the fourth 0, for loops that carry a
 * colour across many operations (a path's throughput and radiance): the same IEEE operations
 * lane by lane as vec3's, so the same bits, but one instruction per operation, and one store
 * and one load each when kept across an opaque call (which preserves no SSE register) instead
 * of three. Arithmetic is the extensions' own (+, *, a scalar broadcast). */
typedef float vec3_v4 __attribute__((vector_size(16)));
static inline vec3_v4 vec3_v4_pack(struct vec3 a) { return (vec3_v4){a.x, a.y, a.z, 0.0f}; }
static inline struct vec3 vec3_v4_unpack(vec3_v4 a) { return vec3_make(a[0], a[1], a[2]); }

/* fmaxf without the libm call (in a hot loop the call also costs the reload of every SSE
 * register), with fmaxf's results (tests/unit/test_core.c): a NaN gives the other value, two
 * NaNs a NaN; of equal values (+0, -0) the second, as glibc's maxss-based fmaxf (C leaves that
 * sign open, and GCC may swap fmaxf's operands, so vec3_max_comp can give either). */
static inline float vec_fmaxf(float a, float b) { return a > b || b != b ? a : b; }
/* vec3_max_comp of the first three lanes, the same results. */
static inline float vec3_v4_max_comp(vec3_v4 a) { return vec_fmaxf(a[0], vec_fmaxf(a[1], a[2])); }

#endif
