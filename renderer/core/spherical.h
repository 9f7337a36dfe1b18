/* spherical.h — uniform sampling of the solid angle a triangle subtends from a point: the
 * spherical triangle that (v0, v1, v2) projects to on the unit sphere around p, its solid angle,
 * its pdf and the inverse of its sampling map; and the same for a rectangle (at the end: sampling
 * and solid angle). Header-only, allocation-free.
 *
 * Sampling is Arvo's two-stage warp of the unit square (J. Arvo, "Stratified Sampling of
 * Spherical Triangles", SIGGRAPH 1995, §2): u1 picks the sub-triangle (A, B, C') that shares
 * the vertex A, the angle alpha there and the side AB with the whole triangle and has area
 * u1 * Omega (C' on the arc AC), and u2 picks a point on the arc BC' with the cosine of its
 * distance to B uniform. The map is continuous and area-preserving, so stratified (u1, u2)
 * stay stratified on the sphere, and the pdf is 1 / Omega everywhere inside.
 *
 * Precision: a small or distant triangle is a spherical triangle of small sides whose angle sum
 * is pi plus a tiny excess, so the textbook forms (Girard's excess, Arvo's cos(A_hat - alpha) -
 * cos(alpha), the sine of a short side from its cosine) cancel catastrophically. Here the
 * geometry is in double, the solid angle comes from van Oosterom & Strackee's formula on the
 * triangle's own edges (no excess), and each difference of nearly equal numbers in the warp is
 * rewritten as a product of sines; only the sine and cosine of the sub-triangle's half area are
 * taken in float (see there). */
#ifndef RESTIRD_SPHERICAL_H
#define RESTIRD_SPHERICAL_H

#include <math.h>
#include <stdbool.h>

#include "core/dvec.h"
#include "core/vec.h"

/* Below this solid angle (steradians) spherical_triangle_init turns a triangle away: p in or
 * next to the triangle's plane, or a triangle of no area, where the solid angle is rounding
 * noise. The warp itself holds far below it: sampling and inverting again comes back to (u1, u2)
 * within 1.1e-7 (the float sine of the first stage) for solid angles from 0.3 sr down to 1e-9 sr,
 * a sliver 500 times longer than wide included (tests/unit/test_spherical.c); with a double
 * sine, within 2e-13 down to 1e-13 sr. */
#define SPHERICAL_MIN_SOLID_ANGLE 1e-10

/* a / |a|, and |a| into *len; the zero vector stays zero. */
static inline struct dvec3 spherical_unit(struct dvec3 a, double *len)
{
    double l = dvec3_length(a);
    if (len) *len = l;
    return l > 0.0 ? dvec3_scale(a, 1.0 / l) : a;
}

#define SPHERICAL_PI 3.14159265358979323846

/* atan2(y, x) for y >= 0, an angle in [0, pi], to 1e-9 relative (libm's atan2 and atan2f cost
 * 126 and 115 instructions a call here, callgrind; this about 35). The argument is folded into [0, 1] (the smaller of
 * |x| and y over the larger, with the quadrant restored at the end), then into [-tan(pi/8),
 * tan(pi/8)] by atan r = pi/4 + atan((r - 1) / (r + 1)), where atan r = r + r^3 P(r^2) with P of
 * degree 4: a least-squares fit of (atan r - r) / r^3 iterated towards equal relative error
 * (Lawson's reweighting), 6.7e-10 at most over that interval. */
static inline double spherical_atan2_upper(double y, double x)
{
    double ax = fabs(x);
    bool steep = y > ax;
    double r = steep ? ax / y : (ax > 0.0 ? y / ax : 0.0);
    double base = 0.0;
    if (r > 0.41421356237309503) {   /* tan(pi/8) */
        base = 0.25 * SPHERICAL_PI;
        r = (r - 1.0) / (r + 1.0);
    }
    double z = r * r;
    double p = -0.333333151889049 +
               z * (0.19998471530162168 + z * (-0.14243533582788628 + z * (0.105938152844006 + z * -0.060782249566231857)));
    double a = base + r + r * z * p;
    if (steep) a = 0.5 * SPHERICAL_PI - a;
    return x < 0.0 ? SPHERICAL_PI - a : a;
}

/* The spherical triangle (a, b, c) seen from a point: unit directions to the vertices, the
 * triple product a . (b x c) of those (its sign is the vertices' winding seen from the point) and
 * the solid angle. */
struct spherical_triangle {
    struct dvec3 a, b, c;
    double triple;
    double solid_angle;
    struct dvec3 to_v0;   /* v0 - p, in double (the light sampler's plane intersection) */
};

/* Solid angle of the triangle at p with edges relative to p: ra = v0 - p, e1 = v1 - v0,
 * e2 = v2 - v0 (van Oosterom & Strackee 1983, "The Solid Angle of a Plane Triangle", IEEE
 * Trans. Biomed. Eng. 30(2)): tan(Omega / 2) = |ra . (rb x rc)| / (|ra||rb||rc| + (ra.rb)|rc|
 * + (ra.rc)|rb| + (rb.rc)|ra|). The triple product is taken as ra . (e1 x e2), which equals it
 * and does not cancel when the three directions are nearly parallel; the denominator is a sum
 * of positive terms for any triangle narrower than a quarter sphere, and atan2 keeps the result
 * right up to 2 pi (denominator <= 0). Both are divided by |ra||rb||rc| first, which makes them
 * the unit directions' triple product (returned in *triple) and 1 + a.b + a.c + b.c. len (may be
 * NULL) receives the vertices' distances. */
static inline double spherical_solid_angle_edges(struct dvec3 ra, struct dvec3 e1,
                                                 struct dvec3 e2, double *triple, double len[3])
{
    struct dvec3 rb = dvec3_add(ra, e1), rc = dvec3_add(ra, e2);
    double la = sqrt(dvec3_dot(ra, ra)), lb = sqrt(dvec3_dot(rb, rb)), lc = sqrt(dvec3_dot(rc, rc));
    double inv = 1.0 / (la * lb * lc);
    double t = dvec3_dot(ra, dvec3_cross(e1, e2)) * inv;
    double den = 1.0 + (dvec3_dot(ra, rb) * lc + dvec3_dot(ra, rc) * lb + dvec3_dot(rb, rc) * la) * inv;
    if (triple) *triple = t;
    if (len) {
        len[0] = la;
        len[1] = lb;
        len[2] = lc;
    }
    return 2.0 * spherical_atan2_upper(fabs(t), den);
}

/* Solid angle of the triangle (v0, v1, v2) seen from p, in steradians. */
static inline double spherical_triangle_solid_angle(struct vec3 p, struct vec3 v0, struct vec3 v1, struct vec3 v2)
{
    struct dvec3 ra = dvec3_sub(dvec3_from(v0), dvec3_from(p));
    struct dvec3 e1 = dvec3_sub(dvec3_from(v1), dvec3_from(v0));
    struct dvec3 e2 = dvec3_sub(dvec3_from(v2), dvec3_from(v0));
    return spherical_solid_angle_edges(ra, e1, e2, NULL, NULL);
}

/* The spherical triangle of the triangle v0 + b1 e1 + b2 e2 seen from p (edges given as the
 * light sampler stores them). False when its solid angle is not above
 * SPHERICAL_MIN_SOLID_ANGLE: use area sampling then. */
static inline bool spherical_triangle_init(struct spherical_triangle *st, struct vec3 p, struct vec3 v0,
                                           struct vec3 e1, struct vec3 e2)
{
    struct dvec3 ra = dvec3_sub(dvec3_from(v0), dvec3_from(p));
    struct dvec3 de1 = dvec3_from(e1), de2 = dvec3_from(e2);
    double len[3];
    st->solid_angle = spherical_solid_angle_edges(ra, de1, de2, &st->triple, len);
    if (!(st->solid_angle > SPHERICAL_MIN_SOLID_ANGLE)) return false;
    st->to_v0 = ra;
    st->a = dvec3_scale(ra, 1.0 / len[0]);
    st->b = dvec3_scale(dvec3_add(ra, de1), 1.0 / len[1]);
    st->c = dvec3_scale(dvec3_add(ra, de2), 1.0 / len[2]);
    return true;
}

/* Solid-angle pdf of spherical_triangle_sample: 1 / Omega for every direction inside. */
static inline double spherical_triangle_pdf_w(const struct spherical_triangle *st)
{
    return 1.0 / st->solid_angle;
}

/* The interior angle alpha at vertex a, as cos and sin: the angle between the planes (a, b)
 * and (a, c). With a unit, |(a x b) x (a x c)| = |a . (b x c)|, so sin alpha comes from the
 * triple product without a difference of nearly equal cosines. Also the unit tangent at a
 * towards c (c with its a component removed, the unit normal of (a, c) crossed with a), which
 * the first stage builds C' from. */
static inline void spherical_angle_at_a(const struct spherical_triangle *st, double *cos_alpha, double *sin_alpha,
                                        struct dvec3 *c_tangent)
{
    double lab, lac;
    struct dvec3 nab = dvec3_cross(st->a, st->b);
    struct dvec3 nac = spherical_unit(dvec3_cross(st->a, st->c), &lac);
    lab = sqrt(dvec3_dot(nab, nab));
    *cos_alpha = dvec3_dot(nab, nac) / lab;
    *sin_alpha = fabs(st->triple) / (lab * lac);
    *c_tangent = dvec3_cross(nac, st->a);
}

/* A unit direction uniformly distributed over the spherical triangle (pdf 1 / Omega) for
 * (u1, u2) in [0, 1]^2, Arvo 1995 §2, in double: the light sampler intersects it with the
 * triangle's plane in double too, so that a small triangle's point keeps its place. */
static inline struct dvec3 spherical_triangle_sample_d(const struct spherical_triangle *st, float u1, float u2)
{
    double cos_alpha, sin_alpha;
    struct dvec3 c_tangent;
    spherical_angle_at_a(st, &cos_alpha, &sin_alpha, &c_tangent);
    /* First stage: the sub-triangle of area A_hat = u1 Omega. Arvo's closed form gives the
     * cosine q of its side AC' as q = ((v t - u s) cos alpha - v) / ((v s + u t) sin alpha), with
     * s = sin(A_hat - alpha), t = cos(A_hat - alpha), u = t - cos alpha and v = s + sin alpha
     * cos c (c the side AB). C' needs sin of that side too, and sqrt(1 - q^2) from q is lost to
     * rounding for a short side (1 - q below 1e-10 keeps fewer than six digits). So the
     * complement is formed directly: by the angle-sum formulas the denominator minus the
     * numerator is v (1 - cos A_hat) + u sin A_hat, and the denominator is sin alpha (1 - cos
     * A_hat + sin alpha sin(alpha - A_hat) (1 - cos c)). With h = A_hat / 2 and g = alpha - h
     * every difference of nearly equal numbers becomes a product: 1 - cos A_hat = 2 sin^2 h,
     * u = 2 sin h sin g, v = 2 sin h cos g - sin alpha (1 - cos c), 1 - cos c = |a - b|^2 / 2.
     * Only h needs a sine and cosine: g's follow from alpha's by the difference formulas
     * (g > 0, as A_hat <= Omega < 2 alpha). */
    double h = 0.5 * (double)u1 * st->solid_angle;
    /* In float: its 1e-7 relative error is far below what the warp needs (a sub-triangle's area
     * off by that share), and GCC makes one sincosf call of the pair, a quarter of sincos. */
    double sin_h = sinf((float)h), cos_h = cosf((float)h);
    double sin_g = sin_alpha * cos_h - cos_alpha * sin_h, cos_g = cos_alpha * cos_h + sin_alpha * sin_h;
    double one_minus_cos_hat = 2.0 * sin_h * sin_h, sin_hat = 2.0 * sin_h * cos_h;
    double sin_alpha_minus_hat = sin_g * cos_h - cos_g * sin_h;   /* sin(g - h) */
    struct dvec3 ab = dvec3_sub(st->a, st->b);
    double one_minus_cos_c = 0.5 * dvec3_dot(ab, ab);
    double u = 2.0 * sin_h * sin_g;
    double v = 2.0 * sin_h * cos_g - sin_alpha * one_minus_cos_c;
    double den = sin_alpha * (one_minus_cos_hat + sin_alpha * sin_alpha_minus_hat * one_minus_cos_c);
    double one_minus_q = den != 0.0 ? (v * one_minus_cos_hat + u * sin_hat) / den : 0.0;
    /* [0, 2] but for rounding; NaN (a degenerate angle) gives the vertex a itself. */
    one_minus_q = one_minus_q > 0.0 ? (one_minus_q < 2.0 ? one_minus_q : 2.0) : 0.0;
    double q = 1.0 - one_minus_q, sin_q = sqrt(one_minus_q * (2.0 - one_minus_q));
    struct dvec3 c_hat = dvec3_add(dvec3_scale(st->a, q), dvec3_scale(c_tangent, sin_q));
    /* Second stage: on the arc from b to C', the cosine z of the distance to b uniform between
     * 1 and b . C' (the strip of the sub-triangle at distance theta from b is as wide as
     * sin theta). 1 - z = u2 (1 - b . C') with 1 - b . C' = |C' - b|^2 / 2, and sin = sqrt((1 - z)
     * (1 + z)): no cancellation when C' is close to b. */
    struct dvec3 cb = dvec3_sub(c_hat, st->b);
    double one_minus_z = (double)u2 * 0.5 * dvec3_dot(cb, cb);
    double z = 1.0 - one_minus_z;
    double sin_z2 = one_minus_z * (2.0 - one_minus_z);   /* >= 0 but for rounding (fmax is a libm call) */
    double sin_z = sqrt(sin_z2 > 0.0 ? sin_z2 : 0.0);
    struct dvec3 c_off_b = dvec3_sub(c_hat, dvec3_scale(st->b, dvec3_dot(c_hat, st->b)));
    struct dvec3 tangent = spherical_unit(c_off_b, NULL);
    return dvec3_add(dvec3_scale(st->b, z), dvec3_scale(tangent, sin_z));
}

/* The same direction in float (unit length to float rounding). */
static inline struct vec3 spherical_triangle_sample(const struct spherical_triangle *st, float u1, float u2)
{
    struct dvec3 d = spherical_triangle_sample_d(st, u1, u2);
    return vec3_make((float)d.x, (float)d.y, (float)d.z);
}

/* Whether the unit direction `dir` lies inside the spherical triangle (on the inner side of its
 * three great circles; the edges count as inside). */
static inline bool spherical_triangle_contains(const struct spherical_triangle *st, struct vec3 dir)
{
    struct dvec3 d = dvec3_from(dir);
    double w = st->triple < 0.0 ? -1.0 : 1.0;
    return w * dvec3_dot(d, dvec3_cross(st->a, st->b)) >= 0.0 &&
           w * dvec3_dot(d, dvec3_cross(st->b, st->c)) >= 0.0 &&
           w * dvec3_dot(d, dvec3_cross(st->c, st->a)) >= 0.0;
}

/* The pdf of spherical_triangle_sample towards `dir`: 1 / Omega inside, 0 outside. */
static inline double spherical_triangle_pdf_w_toward(const struct spherical_triangle *st, struct vec3 dir)
{
    return spherical_triangle_contains(st, dir) ? spherical_triangle_pdf_w(st) : 0.0;
}

/* The inverse of spherical_triangle_sample: the (u1, u2) that map to the unit direction `dir`
 * inside the triangle. C' is where the great circle through b and dir meets the arc a-c (of
 * the two antipodal crossings, the one on the side of a + c); u1 is the sub-triangle (a, b, C')'s
 * share of the solid angle and u2 = (1 - b . dir) / (1 - b . C'), both differences of cosines
 * again taken as squared chords. */
static inline void spherical_triangle_invert_d(const struct spherical_triangle *st, struct dvec3 dir,
                                               double *u1, double *u2)
{
    struct dvec3 d = spherical_unit(dir, NULL);
    struct dvec3 c_hat = dvec3_cross(dvec3_cross(st->b, d), dvec3_cross(st->a, st->c));
    double len;
    c_hat = spherical_unit(c_hat, &len);
    if (!(len > 0.0)) {   /* dir is b (or the sub-triangle is the whole one's edge ab) */
        *u1 = *u2 = 0.0;
        return;
    }
    if (dvec3_dot(c_hat, dvec3_add(st->a, st->c)) < 0.0) c_hat = dvec3_scale(c_hat, -1.0);
    struct dvec3 e1 = dvec3_sub(st->b, st->a), e2 = dvec3_sub(c_hat, st->a);
    double sub = spherical_solid_angle_edges(st->a, e1, e2, NULL, NULL);
    struct dvec3 db = dvec3_sub(d, st->b), cb = dvec3_sub(c_hat, st->b);
    double chord2 = dvec3_dot(cb, cb);
    double x1 = sub / st->solid_angle, x2 = chord2 > 0.0 ? dvec3_dot(db, db) / chord2 : 0.0;
    *u1 = x1 < 0.0 ? 0.0 : (x1 > 1.0 ? 1.0 : x1);
    *u2 = x2 < 0.0 ? 0.0 : (x2 > 1.0 ? 1.0 : x2);
}

/* The same for a float direction. */
static inline void spherical_triangle_invert(const struct spherical_triangle *st, struct vec3 dir, float *u1, float *u2)
{
    double x1, x2;
    spherical_triangle_invert_d(st, dvec3_from(dir), &x1, &x2);
    *u1 = (float)x1;
    *u2 = (float)x2;
}

/* ---------------------------------------------------------------- spherical rectangles
 *
 * A rectangle (corner c, orthonormal edge directions x and y, side lengths lx and ly) seen from
 * p is a spherical quadrilateral, sampled uniformly in its solid angle by the area-preserving map
 * of C. Ureña, M. Fajardo and A. King, "An Area-Preserving Parametrization for Spherical
 * Rectangles", EGSR 2013 (§3): u1 gives the solid angle up to a line of constant x, u1 Omega,
 * from which that x follows in closed form, and u2 picks y along it with the height h = y /
 * sqrt(x^2 + y^2 + z^2) uniform. One warp covers the whole quad, where a pair of spherical
 * triangles needs two solid angles and a choice between them.
 *
 * In the rectangle's frame with p at the origin, the corners are (x0|x1, y0|y1, z0), z0 < 0 (the
 * frame's z is flipped to face away from p). The quadrilateral's interior angles g at its four
 * corners give the solid angle by Girard's theorem, Omega = g0 + g1 + g2 + g3 - 2 pi. The paper
 * takes each angle as the arc cosine of the dot product of two edge-plane normals; those normals
 * are axis-aligned in this frame, so the cosine and sine of each angle are short products of the
 * coordinates (at the corner (x1, y0), cos g = y0 x1 / (|(0, z0, -y0)| |(-z0, 0, x1)|) and sin g
 * = |z0| |(x1, y0, z0)| over the same denominator), and the angles are arc tangents of those
 * numerators, with no arc cosine near +-1 losing digits. Against the sum of the two triangles'
 * van Oosterom & Strackee solid angles Omega agrees to 5e-9 (relative) or better, from a
 * rectangle about as far as it is large to one 30 times farther (7e-4 sr) and one seen at a
 * grazing angle (tests/unit/test_spherical.c). */

/* The sum of two angles in [0, pi] given as (cosine, sine) up to a positive factor each (sines
 * >= 0): the argument of the product of the two as complex numbers, in [0, 2 pi). */
static inline double spherical_angle_sum(double ca, double sa, double cb, double sb)
{
    const double re = ca * cb - sa * sb, im = ca * sb + sa * cb;
    return im >= 0.0 ? spherical_atan2_upper(im, re) : 2.0 * SPHERICAL_PI - spherical_atan2_upper(-im, re);
}

/* Below this solid angle spherical_rect_init turns a rectangle away: the point is in or next to
 * its plane, where Omega would be mostly the rounding of the angle sum. */
#define SPHERICAL_RECT_MIN_SOLID_ANGLE 1e-6

struct spherical_rect {
    struct dvec3 x, y, z;           /* the frame: edge directions, and z = +-(x cross y) away from p */
    double x0, x1, y0, y1, z0;      /* the corners' coordinates from p */
    double b0, b1, k;               /* the paper's n0.z, n2.z and 2 pi - g2 - g3 */
    double solid_angle;
};

/* The spherical rectangle of the rectangle corner + s x + t y (s in [0, lx], t in [0, ly]) seen
 * from p, with to_corner = corner - p and z = x cross y. False when its solid angle is not above
 * SPHERICAL_RECT_MIN_SOLID_ANGLE. */
static inline bool spherical_rect_init(struct spherical_rect *sr, struct dvec3 to_corner, struct dvec3 x,
                                       struct dvec3 y, struct dvec3 z, double lx, double ly)
{
    double z0 = dvec3_dot(to_corner, z);
    if (z0 > 0.0) {
        z = dvec3_scale(z, -1.0);
        z0 = -z0;
    }
    const double x0 = dvec3_dot(to_corner, x), y0 = dvec3_dot(to_corner, y);
    const double x1 = x0 + lx, y1 = y0 + ly, zz = z0 * z0, az = -z0;
    /* The interior angles at (x1, y0), (x1, y1), (x0, y1) and (x0, y0), g0..g3 in the paper, as
     * (cosine, sine) pairs up to a common positive factor each. Only the sums g0 + g1 and g2 + g3
     * are needed: each is the argument of the product of its two pairs as complex numbers, one
     * arc tangent instead of two. */
    const double c0 = y0 * x1, s0 = az * sqrt(x1 * x1 + y0 * y0 + zz);
    const double c1 = -x1 * y1, s1 = az * sqrt(x1 * x1 + y1 * y1 + zz);
    const double c2 = x0 * y1, s2 = az * sqrt(x0 * x0 + y1 * y1 + zz);
    const double c3 = -x0 * y0, s3 = az * sqrt(x0 * x0 + y0 * y0 + zz);
    const double g01 = spherical_angle_sum(c0, s0, c1, s1), g23 = spherical_angle_sum(c2, s2, c3, s3);
    sr->x = x;
    sr->y = y;
    sr->z = z;
    sr->x0 = x0;
    sr->x1 = x1;
    sr->y0 = y0;
    sr->y1 = y1;
    sr->z0 = z0;
    sr->b0 = -y0 / sqrt(zz + y0 * y0);
    sr->b1 = y1 / sqrt(zz + y1 * y1);
    sr->k = 2.0 * SPHERICAL_PI - g23;
    sr->solid_angle = g01 - sr->k;
    return sr->solid_angle > SPHERICAL_RECT_MIN_SOLID_ANGLE;
}

/* The point corner + s x + t y of the rectangle whose direction from p is uniformly distributed
 * over the spherical rectangle (pdf 1 / Omega) for (u1, u2) in [0, 1]^2 (the paper's Algorithm 1),
 * as (s, t): the light sampler maps those to its triangles' barycentrics directly. */
static inline void spherical_rect_sample_st(const struct spherical_rect *sr, float u1, float u2, double *s, double *t)
{
    /* The angle au runs over [k, k + Omega]; its sine and cosine in float, as in the triangle's
     * warp: an error of 1e-7 in au moves the point by that fraction of the distance. */
    const double au = (double)u1 * sr->solid_angle + sr->k;
    const double sin_au = sinf((float)au), cos_au = cosf((float)au);
    const double fu = (cos_au * sr->b0 - sr->b1) / sin_au;
    double cu = 1.0 / sqrt(fu * fu + sr->b0 * sr->b0);
    if (!(fu > 0.0)) cu = -cu;
    cu = cu > -1.0 ? (cu < 1.0 ? cu : 1.0) : -1.0;   /* NaN (0 / 0 at au = pi) to -1, clamped to x0 below */
    double xu = -(cu * sr->z0) / sqrt(1.0 - cu * cu);
    xu = xu > sr->x0 ? (xu < sr->x1 ? xu : sr->x1) : sr->x0;
    const double dd = xu * xu + sr->z0 * sr->z0, d = sqrt(dd);
    const double h0 = sr->y0 / sqrt(dd + sr->y0 * sr->y0), h1 = sr->y1 / sqrt(dd + sr->y1 * sr->y1);
    const double hv = h0 + (double)u2 * (h1 - h0), hv2 = hv * hv;
    double yv = hv2 < 1.0 - 1e-12 ? hv * d / sqrt(1.0 - hv2) : sr->y1;
    yv = yv > sr->y0 ? (yv < sr->y1 ? yv : sr->y1) : sr->y0;
    *s = xu - sr->x0;
    *t = yv - sr->y0;
}

#endif
