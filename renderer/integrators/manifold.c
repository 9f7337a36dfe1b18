/* manifold.c — manifold walks (see manifold.h).
 * Refs: Jakob & Marschner 2012 (manifold exploration, generalized geometry term §4);
 * Zeltner et al. 2020 §4 (angle-difference constraint, step-size control, re-projection);
 * [SMS-SSP §3.1]. */
#include "integrators/manifold.h"

#include <math.h>

#include "core/dvec.h"
#include "material/fresnel.h"
#include "material/microfacet.h"
#include "scene/scene.h"
#include "scene/surface.h"

#define MF_N (2 * MANIFOLD_MAX_CHAIN)


/* A mesh vertex's world position and normal in double. Most shapes sit in world space (identity
 * transform), where the transform is skipped: x * 1 + 0 is x exactly, so nothing changes. */
static inline struct dvec3 mf_world_point(const struct accel *accel, uint32_t shape, struct vec3 p)
{
    return dvec3_from(accel_shape_is_identity(accel, shape) ? p : xform_point(accel_shape_to_world(accel, shape), p));
}
static inline struct dvec3 mf_world_normal(const struct accel *accel, uint32_t shape, struct vec3 n)
{
    return dvec3_from(accel_shape_is_identity(accel, shape) ? n : xform_normal(accel_shape_to_object(accel, shape), n));
}

/* First-order surface model around a vertex, in the vertex's own parameters (u, v):
 * meshes: p(u, v) = p + u dp/du + v dp/dv over the triangle's barycentrics (b1, b2), normal
 * normalize(ñ + u dñ/du + v dñ/dv) with ñ the interpolated vertex normal (exact on the
 * triangle); spheres: n(u, v) = normalize(d + u t1 + v t2), p = c + r n (exact). */
struct mf_geom {
    bool sphere;
    struct dvec3 p, dpdu, dpdv;
    struct dvec3 nt, dntu, dntv;   /* unnormalised normal, on the geometric front side */
    struct dvec3 c;
    double r;
};

static bool mf_geom_of(const struct scene *scene, uint32_t shape, const struct manifold_vertex *v, struct mf_geom *g)
{
    const struct shape *s = &scene->shapes[shape];
    const struct accel *accel = scene->accel;
    const struct xform *xf = accel_shape_to_world(accel, shape);
    struct dvec3 ng = dvec3_from(v->ng);
    if (s->kind == SHAPE_MESH) {
        const uint32_t *tri = &s->indices[3 * v->prim];
        struct dvec3 P0 = mf_world_point(accel, shape, s->positions[tri[0]]);
        struct dvec3 P1 = mf_world_point(accel, shape, s->positions[tri[1]]);
        struct dvec3 P2 = mf_world_point(accel, shape, s->positions[tri[2]]);
        double b1 = v->bd[0], b2 = v->bd[1], b0 = 1.0 - b1 - b2;
        g->sphere = false;
        g->dpdu = dvec3_sub(P1, P0);
        g->dpdv = dvec3_sub(P2, P0);
        g->p = dvec3_madd(dvec3_madd(P0, g->dpdu, b1), g->dpdv, b2);
        g->nt = ng;
        g->dntu = g->dntv = (struct dvec3){0, 0, 0};
        if (s->normals) {
            struct dvec3 N[3];
            for (int i = 0; i < 3; i++) N[i] = mf_world_normal(accel, shape, s->normals[tri[i]]);
            struct dvec3 nt = dvec3_add(dvec3_add(dvec3_scale(N[0], b0), dvec3_scale(N[1], b1)), dvec3_scale(N[2], b2));
            if (dvec3_dot(nt, nt) > 1e-12) {
                /* As surface_from_hit: the shading normal is kept on the geometric front side. */
                double sg = dvec3_dot(nt, ng) < 0.0 ? -1.0 : 1.0;
                g->nt = dvec3_scale(nt, sg);
                g->dntu = dvec3_scale(dvec3_sub(N[1], N[0]), sg);
                g->dntv = dvec3_scale(dvec3_sub(N[2], N[0]), sg);
            }
        }
        struct dvec3 cr = dvec3_cross(g->dpdu, g->dpdv);
        return dvec3_dot(cr, cr) > 0.0;
    }
    /* Sphere under a similarity transform (rotation, uniform scale, translation). */
    struct dvec3 ex = dvec3_from(xform_vector(xf, vec3_make(1, 0, 0))), ey = dvec3_from(xform_vector(xf, vec3_make(0, 1, 0)));
    double sx = dvec3_length(ex), sy = dvec3_length(ey);
    if (!(fabs(sx - sy) <= 1e-5 * sx) || fabs(dvec3_dot(ex, ey)) > 1e-5 * sx * sy) return false;
    g->sphere = true;
    g->c = dvec3_from(xform_point(xf, s->center));
    g->r = (double)s->radius * sx;
    struct dvec3 d = dvec3_normalize(dvec3_sub((struct dvec3){v->pd[0], v->pd[1], v->pd[2]}, g->c));
    struct frame f = frame_from_normal(dvec3_to_float(d));
    g->nt = d;
    g->dntu = dvec3_from(f.s);
    g->dntv = dvec3_from(f.t);
    g->p = dvec3_madd(g->c, d, g->r);
    g->dpdu = dvec3_scale(g->dntu, g->r);
    g->dpdv = dvec3_scale(g->dntv, g->r);
    return true;
}

/* The model at parameter offset (du, dv): position and unit normal. */
static void mf_geom_eval(const struct mf_geom *g, double du, double dvv, struct dvec3 *p, struct dvec3 *n)
{
    struct dvec3 nt = dvec3_madd(dvec3_madd(g->nt, g->dntu, du), g->dntv, dvv);
    *n = dvec3_normalize(nt);
    *p = g->sphere ? dvec3_madd(g->c, *n, g->r) : dvec3_madd(dvec3_madd(g->p, g->dpdu, du), g->dpdv, dvv);
}

/* Specular scattering of wo (unit, pointing away from the surface) about unit normal n. */
static bool mf_scatter(struct dvec3 wo, struct dvec3 n, enum manifold_event ev, double ior, struct dvec3 *out)
{
    double c = dvec3_dot(wo, n);
    if (ev == MANIFOLD_REFLECT) {
        *out = dvec3_sub(dvec3_scale(n, 2.0 * c), wo);
        return true;
    }
    /* As the smooth dielectric: the side of wo on the shading normal decides inside/outside. */
    bool outside = c > 0.0;
    double eta = outside ? ior : 1.0 / ior;
    struct dvec3 nn = outside ? n : dvec3_scale(n, -1.0);
    double ci = fabs(c);
    double sin2t = (1.0 - ci * ci) / (eta * eta);
    if (!(sin2t < 1.0)) return false;
    double ct = sqrt(1.0 - sin2t);
    *out = dvec3_add(dvec3_scale(wo, -1.0 / eta), dvec3_scale(nn, ci / eta - ct));
    return true;
}

/* A vertex's two directions in spherical coordinates about the pole s (see manifold.h for the
 * choice of pole), each as w = cos θ s + sin θ (cos φ t + sin φ n): a = wi, towards the next
 * vertex, and b = the specular scattering of wo. Kept as cos θ, sin θ and the (t, n) components
 * (x, y), whose length is sin θ = |w × s| (accurate near the pole, where sqrt(1 - cos²) is not):
 * the constraint takes one atan2 per angle from them, and their derivatives none. */
struct mf_dirs { double ca, sa, xa, ya, cb, sb, xb, yb; };

/* Everything of one vertex's constraint that its derivatives reuse: the unit directions wo
 * (towards the previous vertex) and wi (towards the next) with their segment lengths, the unit
 * normal, the frame (s, t) built from the tangent T, |T - n (n·T)| and n·T, the scattered
 * direction, and the spherical coordinates. */
struct mf_vstate {
    struct dvec3 wo, wi, n, s, t, pred, tangent;
    double lo, li, ls, tn;
    struct mf_dirs d;
};

static bool mf_vertex_eval(struct dvec3 prev, struct dvec3 p, struct dvec3 n, struct dvec3 next, struct dvec3 tangent,
                           enum manifold_event ev, double ior, struct mf_vstate *st)
{
    struct dvec3 wo = dvec3_sub(prev, p), wi = dvec3_sub(next, p);
    double lo = dvec3_length(wo), li = dvec3_length(wi);
    if (!(lo > 0.0) || !(li > 0.0)) return false;
    wo = dvec3_scale(wo, 1.0 / lo);
    wi = dvec3_scale(wi, 1.0 / li);
    struct dvec3 pred;
    if (!mf_scatter(wo, n, ev, ior, &pred)) return false;
    double tn = dvec3_dot(n, tangent);
    struct dvec3 s = dvec3_sub(tangent, dvec3_scale(n, tn));
    double ls = dvec3_length(s);
    if (!(ls > 0.0)) return false;
    s = dvec3_scale(s, 1.0 / ls);
    struct dvec3 t = dvec3_cross(n, s);
    struct mf_dirs *d = &st->d;
    d->ca = dvec3_dot(wi, s), d->xa = dvec3_dot(wi, t), d->ya = dvec3_dot(wi, n);
    d->cb = dvec3_dot(pred, s), d->xb = dvec3_dot(pred, t), d->yb = dvec3_dot(pred, n);
    d->sa = sqrt(d->xa * d->xa + d->ya * d->ya);
    d->sb = sqrt(d->xb * d->xb + d->yb * d->yb);
    st->wo = wo, st->wi = wi, st->n = n, st->s = s, st->t = t, st->pred = pred, st->tangent = tangent;
    st->lo = lo, st->li = li, st->ls = ls, st->tn = tn;
    return isfinite(d->ca + d->sa + d->xa + d->ya + d->cb + d->sb + d->xb + d->yb);
}

/* The angle turned from direction (x0, y0) to (x1, y1) of the plane, in [-π, π]. Near a
 * solution (and in a finite difference, ~1e-7 rad) the turn is small, where atan(r) = r - r³/3
 * to 2e-16 (r ≤ 1e-3) and atan2, the costliest call of a walk, is not needed. */
static double mf_turn(double x0, double y0, double x1, double y1)
{
    double sn = x0 * y1 - y0 * x1, cs = x0 * x1 + y0 * y1;
    if (cs > 0.0 && fabs(sn) <= 1e-3 * cs) {
        double r = sn / cs;
        return r * (1.0 - r * r / 3.0);
    }
    return atan2(sn, cs);
}

/* The angle-difference constraint C = (Δθ, Δφ) = (θ_a - θ_b, φ_a - φ_b), Δφ in [-π, π]. */
static void mf_dirs_c(const struct mf_dirs *d, double *c)
{
    c[0] = mf_turn(d->cb, d->sb, d->ca, d->sa);
    c[1] = mf_turn(d->xb, d->yb, d->xa, d->ya);
}

/* C(d1) - C(d0), each angle's turn in [-π, π]. */
static void mf_dirs_dc(const struct mf_dirs *d0, const struct mf_dirs *d1, double *dc)
{
    dc[0] = mf_turn(d0->ca, d0->sa, d1->ca, d1->sa) - mf_turn(d0->cb, d0->sb, d1->cb, d1->sb);
    dc[1] = mf_turn(d0->xa, d0->ya, d1->xa, d1->ya) - mf_turn(d0->xb, d0->yb, d1->xb, d1->yb);
}

/* The constraint's state at every vertex of the chain for positions p[] and unit normals n[]
 * (frames from g[]), ends x1, xe. */
static bool mf_eval_states(const struct manifold_chain *chain, struct dvec3 x1, struct dvec3 xe, const struct dvec3 *p,
                           const struct dvec3 *n, const struct mf_geom *g, struct mf_vstate *S)
{
    uint32_t k = chain->length;
    for (uint32_t i = 0; i < k; i++) {
        struct dvec3 prev = i == 0 ? x1 : p[i - 1], next = i + 1 == k ? xe : p[i + 1];
        if (!mf_vertex_eval(prev, p[i], n[i], next, g[i].dpdu, chain->events[i], chain->ior, &S[i])) return false;
    }
    return true;
}

/* The same, keeping only the spherical coordinates. */
static bool mf_eval_dirs(const struct manifold_chain *chain, struct dvec3 x1, struct dvec3 xe, const struct dvec3 *p,
                         const struct dvec3 *n, const struct mf_geom *g, struct mf_dirs *D)
{
    struct mf_vstate S[MANIFOLD_MAX_CHAIN];
    if (!mf_eval_states(chain, x1, xe, p, n, g, S)) return false;
    for (uint32_t i = 0; i < chain->length; i++) D[i] = S[i].d;
    return true;
}

static double mf_norm(const double *C, uint32_t n)
{
    double s = 0.0;
    for (uint32_t i = 0; i < n; i++) s += C[i] * C[i];
    return sqrt(s);
}

/* C at the chain's surface models' base points, and the vertices' states it came from (S: the
 * derivatives there start from them, analytic or forward differences). */
static bool mf_eval_at(const struct manifold_chain *chain, struct dvec3 x1, struct dvec3 xe, const struct mf_geom *g,
                       double *C, struct mf_vstate *S)
{
    struct dvec3 p[MANIFOLD_MAX_CHAIN] = {0}, n[MANIFOLD_MAX_CHAIN] = {0};
    for (uint32_t i = 0; i < chain->length; i++) mf_geom_eval(&g[i], 0.0, 0.0, &p[i], &n[i]);
    if (!mf_eval_states(chain, x1, xe, p, n, g, S)) return false;
    for (uint32_t i = 0; i < chain->length; i++) mf_dirs_c(&S[i].d, &C[2 * i]);
    return isfinite(mf_norm(C, 2 * chain->length));
}

/* dC / d(u_j, v_j) over the surface model, by finite differences in double: only for the test
 * hooks, which hold the analytic derivatives (mf_derivatives) against them. Forward ones, the
 * Newton step's Jacobian before the analytic one, step 1e-7 of the shorter adjacent segment:
 * truncation ~5e-8 and rounding ~1e-8 relative; they start from S0, the states at the base
 * points (mf_eval_at's, computed with the same numbers). Central ones (`central`, S0 unused),
 * step 1e-6: truncation ~1e-12, rounding ~1e-10. */
static bool mf_jacobian(const struct manifold_chain *chain, struct dvec3 x1, struct dvec3 xe, const struct mf_geom *g,
                        bool central, const struct mf_vstate *S0, double J[MF_N][MF_N])
{
    uint32_t k = chain->length;
    struct dvec3 p[MANIFOLD_MAX_CHAIN], n[MANIFOLD_MAX_CHAIN];
    struct mf_dirs Dp[MANIFOLD_MAX_CHAIN], Dm[MANIFOLD_MAX_CHAIN];
    for (uint32_t i = 0; i < k; i++) mf_geom_eval(&g[i], 0.0, 0.0, &p[i], &n[i]);
    const double rel = central ? 1e-6 : 1e-7;
    for (uint32_t j = 0; j < k; j++) {
        struct dvec3 prev = j == 0 ? x1 : p[j - 1], next = j + 1 == k ? xe : p[j + 1];
        double l0 = dvec3_length(dvec3_sub(prev, p[j])), l1 = dvec3_length(dvec3_sub(next, p[j]));
        double seg = l0 < l1 ? l0 : l1;
        for (int a = 0; a < 2; a++) {
            double lt = dvec3_length(a == 0 ? g[j].dpdu : g[j].dpdv);
            if (!(lt > 0.0) || !(seg > 0.0)) return false;
            double h = rel * seg / lt;
            struct dvec3 pj = p[j], nj = n[j];
            mf_geom_eval(&g[j], a == 0 ? h : 0.0, a == 1 ? h : 0.0, &p[j], &n[j]);
            bool ok = mf_eval_dirs(chain, x1, xe, p, n, g, Dp);
            if (central) {
                mf_geom_eval(&g[j], a == 0 ? -h : 0.0, a == 1 ? -h : 0.0, &p[j], &n[j]);
                ok = ok && mf_eval_dirs(chain, x1, xe, p, n, g, Dm);
            }
            p[j] = pj;
            n[j] = nj;
            if (!ok) return false;
            for (uint32_t i = 0; i < k; i++) {
                double dc[2];
                mf_dirs_dc(central ? &Dm[i] : &S0[i].d, &Dp[i], dc);
                J[2 * i][2 * j + a] = dc[0] / (central ? 2.0 * h : h);
                J[2 * i + 1][2 * j + a] = dc[1] / (central ? 2.0 * h : h);
            }
        }
    }
    return true;
}

/* The part of v orthogonal to the unit vector w, over l. For a unit direction w = (q - p) / l,
 * g·dw = (that of g)·dq: a gradient with respect to w becomes one with respect to q (and its
 * negative one with respect to p). */
static inline struct dvec3 mf_ortho(struct dvec3 w, struct dvec3 v, double l)
{
    return dvec3_scale(dvec3_madd(v, w, -dvec3_dot(w, v)), 1.0 / l);
}

/* A vector given by its components in a vertex's frame (s, t, n). */
static inline struct dvec3 mf_from_frame(const struct mf_vstate *st, double gs, double gt, double gn)
{
    return dvec3_add(dvec3_add(dvec3_scale(st->s, gs), dvec3_scale(st->t, gt)), dvec3_scale(st->n, gn));
}

/* The gradients of a unit direction's spherical coordinates, θ about the pole s (row 0) and φ =
 * atan2(y, x) (row 1), from c = w·s, (x, y) = (w·t, w·n) and sin θ = |(x, y)| as mf_vertex_eval
 * takes them: g with respect to w, in frame components, and f with respect to the normal through
 * the frame, as coefficients of (s·dn, t·dn) (dn ⊥ n, the normal staying a unit vector).
 *   Direction: dθ = (c d sin θ - sin θ dc) / (c² + sin² θ) = -sin θ dc + (c / sin θ) (x dx + y dy)
 * (|w| = 1), dφ = (x dy - y dx) / sin² θ. Both are scale-invariant, so g ⊥ w.
 *   Frame: s = q / |q| with q = T - n (n·T), the tangent T (the model's dp/du) fixed, t = n × s,
 * and with τ = (n·T) / |q|: w·ds = -y s·dn - τ x t·dn, w·dt = (τ c - y) t·dn, w·dn = c s·dn +
 * x t·dn, which the angles take to dθ = (y s·dn + τ x t·dn) / sin θ and dφ = (x c s·dn + (sin² θ
 * - τ c y) t·dn) / sin² θ. Singular only at the pole, which no useful path reaches (manifold.h). */
static void mf_angles_grad(double c, double sn, double x, double y, double tau, double g[2][3], double f[2][2])
{
    double is = 1.0 / sn, is2 = is * is;
    g[0][0] = -sn, g[0][1] = c * x * is, g[0][2] = c * y * is;
    g[1][0] = 0.0, g[1][1] = -y * is2, g[1][2] = x * is2;
    f[0][0] = y * is, f[0][1] = tau * x * is;
    f[1][0] = x * c * is2, f[1][1] = 1.0 - tau * c * y * is2;
}

/* One vertex's constraint C_i = (θ_a - θ_b, φ_a - φ_b), differentiated (row r for component r):
 * prev[r] and next[r] the gradients with respect to the previous and the next point (x1, a
 * neighbouring vertex or the end point), n[r] with respect to the unit normal (its component
 * along n left out: dn ⊥ n). Moving the vertex itself by dp with its normal by dn changes C_i by
 * n·dn - (prev + next)·dp. */
struct mf_vgrad { struct dvec3 prev[2], next[2], n[2]; };

/* The chain rule through the angles, the frame and the scattering of this constraint (Zeltner
 * et al. 2020 §4; Jakob & Marschner 2012 §4 take the derivatives of their half-vector
 * constraint vertex by vertex the same way), in reverse: one pass per vertex, after which every
 * entry of J is a dot product. */
static void mf_vertex_grad(const struct mf_vstate *st, enum manifold_event ev, double ior, struct mf_vgrad *G)
{
    const struct mf_dirs *d = &st->d;
    const double tau = st->tn / st->ls;
    double ga[2][3], gb[2][3], fa[2][2], fb[2][2];
    mf_angles_grad(d->ca, d->sa, d->xa, d->ya, tau, ga, fa);
    mf_angles_grad(d->cb, d->sb, d->xb, d->yb, tau, gb, fb);
    const double wo[3] = {dvec3_dot(st->wo, st->s), dvec3_dot(st->wo, st->t), dvec3_dot(st->wo, st->n)};
    /* The scattered direction moves as dpred = -dwo / η + μ dn + m n (n·dwo + wo·dn). Reflection
     * (r = 2 (wo·n) n - wo): η = 1, μ = 2 wo·n, m = 2. Refraction (mf_scatter: nn = σ n the normal
     * on wo's side, ci = wo·nn, η the index ratio across it, r = -wo / η + nn (ci / η - ct) with
     * ct = sqrt(1 - (1 - ci²) / η²) = -r·nn, so dct = ci dci / (η² ct)): μ = σ (ci / η - ct),
     * m = 1 / η - ci / (η² ct). */
    double c = wo[2], ie = 1.0, mu = 2.0 * c, m = 2.0;
    if (ev == MANIFOLD_REFRACT) {
        double sg = c > 0.0 ? 1.0 : -1.0, eta = c > 0.0 ? ior : 1.0 / ior;
        double ci = sg * c, ct = -sg * d->yb;
        ie = 1.0 / eta;
        mu = sg * (ci * ie - ct);
        m = ie - ci / (eta * eta * ct);
    }
    for (int r = 0; r < 2; r++) {
        /* θ_b (φ_b) by wo, projected orthogonal to wo; C = a - b. */
        double gwo[3] = {-ie * gb[r][0], -ie * gb[r][1], -ie * gb[r][2] + m * gb[r][2]};
        double pw = wo[0] * gwo[0] + wo[1] * gwo[1] + wo[2] * gwo[2], il = -1.0 / st->lo;
        G->prev[r] = mf_from_frame(st, (gwo[0] - pw * wo[0]) * il, (gwo[1] - pw * wo[1]) * il,
                                   (gwo[2] - pw * wo[2]) * il);
        G->next[r] = dvec3_scale(mf_from_frame(st, ga[r][0], ga[r][1], ga[r][2]), 1.0 / st->li);
        /* By n: the frame under both directions, and the scattering through pred. */
        double ns = fa[r][0] - fb[r][0] - (mu * gb[r][0] + m * gb[r][2] * wo[0]);
        double nt = fa[r][1] - fb[r][1] - (mu * gb[r][1] + m * gb[r][2] * wo[1]);
        G->n[r] = mf_from_frame(st, ns, nt, 0.0);
    }
}

/* Analytic derivatives of the constraint at the chain's surface models' base points, from the
 * vertices' states there (S, which gave C): J = dC / d(u_j, v_j) and, when `e` is given, B =
 * dC / d(end point) along e[0], e[1]. C_i depends only on the vertices i - 1, i, i + 1 (and the
 * end point only through the last vertex's wi), so J is block tridiagonal and B nonzero in the
 * last block row. */
static bool mf_derivatives(const struct manifold_chain *chain, const struct mf_geom *g, const struct mf_vstate *S,
                           double J[MF_N][MF_N], const struct dvec3 *e, double B[MF_N][2])
{
    const uint32_t k = chain->length;
    struct dvec3 dp[MANIFOLD_MAX_CHAIN][2], dn[MANIFOLD_MAX_CHAIN][2];
    for (uint32_t i = 0; i < k; i++) {
        /* n = ñ / |ñ|, dn = (dñ - n (n·dñ)) / |ñ|; a sphere's point follows its normal (p = c + r n),
         * a triangle's is linear in (u, v). */
        double len = dvec3_length(g[i].nt);
        for (int a = 0; a < 2; a++) {
            dn[i][a] = mf_ortho(S[i].n, a == 0 ? g[i].dntu : g[i].dntv, len);
            dp[i][a] = g[i].sphere ? dvec3_scale(dn[i][a], g[i].r) : a == 0 ? g[i].dpdu : g[i].dpdv;
        }
    }
    double sum = 0.0;
    for (uint32_t i = 0; i < k; i++) {
        struct mf_vgrad G;
        mf_vertex_grad(&S[i], chain->events[i], chain->ior, &G);
        for (int r = 0; r < 2; r++) {
            struct dvec3 own = dvec3_add(G.prev[r], G.next[r]);
            for (uint32_t j = 0; j < k; j++)
                for (int a = 0; a < 2; a++) {
                    double v = j == i       ? dvec3_dot(G.n[r], dn[i][a]) - dvec3_dot(own, dp[i][a])
                               : j + 1 == i ? dvec3_dot(G.prev[r], dp[j][a])
                               : j == i + 1 ? dvec3_dot(G.next[r], dp[j][a])
                                            : 0.0;
                    J[2 * i + r][2 * j + a] = v;
                    sum += fabs(v);
                }
            if (e)
                for (int a = 0; a < 2; a++) {
                    B[2 * i + r][a] = i + 1 == k ? dvec3_dot(G.next[r], e[a]) : 0.0;
                    sum += fabs(B[2 * i + r][a]);
                }
        }
    }
    return isfinite(sum);
}

/* dC / d(end point) by central differences, step 1e-6 of the last segment (truncation ~1e-12,
 * rounding ~1e-10): what the analytic B is tested against. */
static bool mf_end_differences(const struct manifold_chain *chain, struct dvec3 x1, struct dvec3 xe,
                               const struct mf_geom *g, const struct dvec3 *e, double B[MF_N][2])
{
    const uint32_t k = chain->length;
    struct dvec3 p[MANIFOLD_MAX_CHAIN], n[MANIFOLD_MAX_CHAIN];
    for (uint32_t i = 0; i < k; i++) mf_geom_eval(&g[i], 0.0, 0.0, &p[i], &n[i]);
    double h = 1e-6 * dvec3_length(dvec3_sub(xe, p[k - 1]));
    for (int a = 0; a < 2; a++) {
        struct mf_dirs Dp[MANIFOLD_MAX_CHAIN], Dm[MANIFOLD_MAX_CHAIN];
        if (!mf_eval_dirs(chain, x1, dvec3_madd(xe, e[a], h), p, n, g, Dp) ||
            !mf_eval_dirs(chain, x1, dvec3_madd(xe, e[a], -h), p, n, g, Dm))
            return false;
        for (uint32_t i = 0; i < k; i++) {
            double dc[2];
            mf_dirs_dc(&Dm[i], &Dp[i], dc);
            B[2 * i][a] = dc[0] / (2.0 * h);
            B[2 * i + 1][a] = dc[1] / (2.0 * h);
        }
    }
    return true;
}

/* The end point's orthonormal tangent basis (area scale 1) of the light. */
static void mf_end_frame(const struct manifold_ends *ends, struct dvec3 e[2])
{
    struct frame fe = frame_from_normal(vec3_normalize(ends->nge));
    e[0] = dvec3_from(fe.s);
    e[1] = dvec3_from(fe.t);
}

/* Solves A X = B in place (n x n, `m` right-hand sides in B's columns); Gaussian elimination
 * with partial pivoting. False when A is (numerically) singular. */
static bool mf_solve(uint32_t n, double A[MF_N][MF_N], double B[MF_N][2], uint32_t m)
{
    double scale = 0.0;
    for (uint32_t r = 0; r < n; r++)
        for (uint32_t c = 0; c < n; c++)
            if (fabs(A[r][c]) > scale) scale = fabs(A[r][c]);
    if (!(scale > 0.0) || !isfinite(scale)) return false;
    for (uint32_t c = 0; c < n; c++) {
        uint32_t piv = c;
        for (uint32_t r = c + 1; r < n; r++)
            if (fabs(A[r][c]) > fabs(A[piv][c])) piv = r;
        if (!(fabs(A[piv][c]) > 1e-12 * scale)) return false;
        if (piv != c) {
            for (uint32_t q = 0; q < n; q++) {
                double t = A[c][q]; A[c][q] = A[piv][q]; A[piv][q] = t;
            }
            for (uint32_t q = 0; q < m; q++) {
                double t = B[c][q]; B[c][q] = B[piv][q]; B[piv][q] = t;
            }
        }
        for (uint32_t r = c + 1; r < n; r++) {
            double f = A[r][c] / A[c][c];
            for (uint32_t q = c; q < n; q++) A[r][q] -= f * A[c][q];
            for (uint32_t q = 0; q < m; q++) B[r][q] -= f * B[c][q];
        }
    }
    for (uint32_t c = n; c-- > 0;) {
        for (uint32_t q = 0; q < m; q++) {
            double s = B[c][q];
            for (uint32_t r = c + 1; r < n; r++) s -= A[c][r] * B[r][q];
            B[c][q] = s / A[c][c];
        }
    }
    return true;
}

static inline struct dvec3 mf_pd(const struct manifold_vertex *v) { return (struct dvec3){v->pd[0], v->pd[1], v->pd[2]}; }

/* The first hit of the ray from `from` along `dir` (double), which must lie on the chain's
 * caster. Embree finds the primitive from the offset float ray; the point is then recomputed
 * in double on that primitive (triangle plane or sphere) from the unoffset double ray. */
static bool mf_trace(const struct scene *scene, uint32_t shape, struct dvec3 from, struct vec3 from_ng, struct dvec3 dir,
                     struct manifold_vertex *v, struct ray_counters *rc)
{
    struct vec3 dirf = vec3_normalize(dvec3_to_float(dir));
    struct vec3 org = surface_offset(dvec3_to_float(from), from_ng, dirf);
    struct hit h;
    if (!accel_intersect(scene->accel, org, dirf, 0.0f, INFINITY, &h, rc) || h.shape != shape) return false;
    struct surface s;
    surface_from_hit(scene, &h, org, dirf, &s);
    v->p = s.p;
    v->ng = s.ng;
    v->ns = s.ns;
    v->prim = h.prim;
    surface_point_code(scene, &h, &s, &v->b1, &v->b2);
    const struct shape *sh = &scene->shapes[shape];
    const struct xform *xf = accel_shape_to_world(scene->accel, shape);
    dir = dvec3_normalize(dir);
    if (sh->kind == SHAPE_MESH) {
        const uint32_t *tri = &sh->indices[3 * h.prim];
        struct dvec3 P0 = mf_world_point(scene->accel, shape, sh->positions[tri[0]]);
        struct dvec3 e1 = dvec3_sub(mf_world_point(scene->accel, shape, sh->positions[tri[1]]), P0);
        struct dvec3 e2 = dvec3_sub(mf_world_point(scene->accel, shape, sh->positions[tri[2]]), P0);
        /* Möller-Trumbore in double (the hit may sit a rounding error outside the triangle). */
        struct dvec3 pv = dvec3_cross(dir, e2);
        double det = dvec3_dot(e1, pv);
        if (!(fabs(det) > 0.0)) return false;
        struct dvec3 tv = dvec3_sub(from, P0), qv = dvec3_cross(tv, e1);
        double b1 = dvec3_dot(tv, pv) / det, b2 = dvec3_dot(dir, qv) / det, t = dvec3_dot(e2, qv) / det;
        if (!(t > 0.0)) return false;
        struct dvec3 p = dvec3_madd(from, dir, t);
        v->bd[0] = b1;
        v->bd[1] = b2;
        v->pd[0] = p.x, v->pd[1] = p.y, v->pd[2] = p.z;
        return true;
    }
    struct dvec3 c = dvec3_from(xform_point(xf, sh->center));
    double r = (double)sh->radius * dvec3_length(dvec3_from(xform_vector(xf, vec3_make(1, 0, 0))));
    struct dvec3 oc = dvec3_sub(from, c);
    double b = dvec3_dot(oc, dir), q = dvec3_dot(oc, oc) - r * r, disc = b * b - q;
    if (!(disc >= 0.0)) disc = 0.0;
    double sq = sqrt(disc), t0 = -b - sq, t1 = -b + sq;
    /* The root Embree found (its distance from the float origin is within rounding of ours). */
    double th = dvec3_length(dvec3_sub(dvec3_from(s.p), from));
    double t = fabs(t0 - th) < fabs(t1 - th) ? t0 : t1;
    if (!(t > 0.0)) return false;
    struct dvec3 p = dvec3_madd(from, dir, t);
    v->pd[0] = p.x, v->pd[1] = p.y, v->pd[2] = p.z;
    v->bd[0] = v->b1, v->bd[1] = v->b2;
    return true;
}

bool manifold_seed_path(const struct scene *scene, const struct manifold_chain *chain, const struct manifold_ends *ends,
                        struct vec3 target, struct manifold_vertex *v, struct ray_counters *rc)
{
    struct dvec3 from = dvec3_from(ends->x1);
    struct vec3 from_ng = ends->ng1;
    struct dvec3 dir = dvec3_sub(dvec3_from(target), from);
    if (!(dvec3_length(dir) > 0.0)) return false;
    dir = dvec3_normalize(dir);
    for (uint32_t i = 0; i < chain->length; i++) {
        if (!mf_trace(scene, chain->shape, from, from_ng, dir, &v[i], rc)) return false;
        if (i + 1 < chain->length) {
            struct mf_geom g;
            struct dvec3 p, n, out;
            if (!mf_geom_of(scene, chain->shape, &v[i], &g)) return false;
            mf_geom_eval(&g, 0.0, 0.0, &p, &n);
            if (!mf_scatter(dvec3_scale(dir, -1.0), n, chain->events[i], chain->ior, &out)) return false;
            dir = dvec3_normalize(out);
        }
        from = mf_pd(&v[i]);
        from_ng = v[i].ng;
    }
    return true;
}

double manifold_constraint_norm(const struct scene *scene, const struct manifold_chain *chain,
                                const struct manifold_ends *ends, const struct manifold_vertex *v)
{
    struct mf_geom g[MANIFOLD_MAX_CHAIN];
    struct mf_vstate S[MANIFOLD_MAX_CHAIN];
    double C[MF_N];
    for (uint32_t i = 0; i < chain->length; i++)
        if (!mf_geom_of(scene, chain->shape, &v[i], &g[i])) return INFINITY;
    if (!mf_eval_at(chain, dvec3_from(ends->x1), dvec3_from(ends->xe), g, C, S)) return INFINITY;
    return mf_norm(C, 2 * chain->length);
}


/* The walk. Every point takes C with the vertices' states (mf_eval_at); an accepted one also
 * takes the Jacobian from those states, analytic (mf_derivatives), or by forward differences for
 * manifold_test_walk_forward_differences. */
static bool mf_walk(const struct scene *scene, const struct manifold_chain *chain, const struct manifold_ends *ends,
                    struct manifold_vertex *v, uint32_t max_iterations, manifold_region_fn *inside, const void *region,
                    uint32_t polish_steps, bool forward_differences, struct manifold_stats *stats,
                    struct ray_counters *rc)
{
    const uint32_t k = chain->length, n2 = 2 * k;
    const struct dvec3 x1 = dvec3_from(ends->x1), xe = dvec3_from(ends->xe);
    struct mf_geom g[MANIFOLD_MAX_CHAIN] = {0};
    struct mf_vstate S[MANIFOLD_MAX_CHAIN];   /* the states C at g came from */
    double C[MF_N], step[MF_N][2];
    uint32_t it = 0;
    bool ok = false, have_step = false;
    double beta = 1.0;
    if (k == 0 || k > MANIFOLD_MAX_CHAIN) goto done;
    for (uint32_t i = 0; i < k; i++)
        if (!mf_geom_of(scene, chain->shape, &v[i], &g[i])) goto done;
    if (!mf_eval_at(chain, x1, xe, g, C, S)) goto done;
    double norm = mf_norm(C, n2);
    uint32_t polish = 0;
    for (;;) {
        if (norm < MANIFOLD_TOLERANCE) {
            /* Converged. A few more full steps (quadratic convergence: usually one) take C to
             * the double-precision floor, so that two walks that reach the same solution agree
             * on it to far better than the 1e-4 same-solution threshold of the Bernoulli trials,
             * even near a caustic fold where ‖C‖ < 1e-5 alone leaves the position loose. */
            ok = true;
            if (norm < MANIFOLD_POLISH_TOLERANCE || polish >= polish_steps) break;
            polish++;
        } else if (it >= max_iterations) {
            break;
        }
        if (!have_step) {
            double J[MF_N][MF_N];
            if (!(forward_differences ? mf_jacobian(chain, x1, xe, g, false, S, J)
                                      : mf_derivatives(chain, g, S, J, NULL, NULL)))
                break;
            for (uint32_t r = 0; r < n2; r++) step[r][0] = -C[r];
            if (!mf_solve(n2, J, step, 1)) break;
            have_step = true;
        }
        it++;
        /* Propose the step in each vertex's tangent plane, then re-project by tracing from the
         * (new) previous vertex towards the proposed point. */
        /* Written vertex by vertex below and read only when every vertex was (zeroing them
         * every step cost 1 % of a restir_sms frame's instructions). */
        struct manifold_vertex nv[MANIFOLD_MAX_CHAIN];
        struct mf_geom ng_[MANIFOLD_MAX_CHAIN];
        struct mf_vstate Sn[MANIFOLD_MAX_CHAIN];
        double Cn[MF_N];
        bool moved = true;
        struct dvec3 from = x1;
        struct vec3 from_ng = ends->ng1;
        for (uint32_t j = 0; j < k && moved; j++) {
            struct dvec3 target = dvec3_madd(dvec3_madd(g[j].p, g[j].dpdu, beta * step[2 * j][0]), g[j].dpdv,
                                        beta * step[2 * j + 1][0]);
            struct dvec3 dir = dvec3_sub(target, from);
            moved = dvec3_length(dir) > 0.0 && mf_trace(scene, chain->shape, from, from_ng, dir, &nv[j], rc) &&
                    mf_geom_of(scene, chain->shape, &nv[j], &ng_[j]);
            from = mf_pd(&nv[j]);
            from_ng = nv[j].ng;
        }
        double nn = INFINITY;
        if (moved && mf_eval_at(chain, x1, xe, ng_, Cn, Sn)) nn = mf_norm(Cn, n2);
        if (nn < norm) {
            /* A trust region ends the walk as soon as an accepted step leaves it
             * ([SMS-SSP §3.3]). */
            if (inside && !inside(region, nv[0].p)) {
                ok = false;
                break;
            }
            for (uint32_t j = 0; j < k; j++) {
                v[j] = nv[j];
                g[j] = ng_[j];
                S[j] = Sn[j];
            }
            for (uint32_t r = 0; r < n2; r++) C[r] = Cn[r];
            norm = nn;
            beta = fmin(1.0, 2.0 * beta);
            have_step = false;
        } else {
            if (ok) break;  /* polishing stalled at the rounding floor */
            beta *= 0.5;
        }
    }
done:
    if (stats) stats->iterations += it;
    return ok;
}

bool manifold_walk(const struct scene *scene, const struct manifold_chain *chain, const struct manifold_ends *ends,
                   struct manifold_vertex *v, uint32_t max_iterations, struct manifold_stats *stats,
                   struct ray_counters *rc)
{
    return mf_walk(scene, chain, ends, v, max_iterations, NULL, NULL, MANIFOLD_POLISH_STEPS, false, stats, rc);
}

bool manifold_walk_unpolished(const struct scene *scene, const struct manifold_chain *chain,
                              const struct manifold_ends *ends, struct manifold_vertex *v, uint32_t max_iterations,
                              struct manifold_stats *stats, struct ray_counters *rc)
{
    return mf_walk(scene, chain, ends, v, max_iterations, NULL, NULL, 0, false, stats, rc);
}

bool manifold_walk_within(const struct scene *scene, const struct manifold_chain *chain,
                          const struct manifold_ends *ends, struct manifold_vertex *v, uint32_t max_iterations,
                          manifold_region_fn *inside, const void *region, struct manifold_stats *stats,
                          struct ray_counters *rc)
{
    return mf_walk(scene, chain, ends, v, max_iterations, inside, region, MANIFOLD_POLISH_STEPS, false, stats, rc);
}

bool manifold_test_walk_forward_differences(const struct scene *scene, const struct manifold_chain *chain,
                                            const struct manifold_ends *ends, struct manifold_vertex *v,
                                            uint32_t max_iterations, struct manifold_stats *stats,
                                            struct ray_counters *rc)
{
    return mf_walk(scene, chain, ends, v, max_iterations, NULL, NULL, MANIFOLD_POLISH_STEPS, true, stats, rc);
}

bool manifold_check(const struct scene *scene, const struct manifold_chain *chain, const struct manifold_ends *ends,
                    const struct manifold_vertex *v, struct ray_counters *rc)
{
    struct vec3 from = ends->x1, from_ng = ends->ng1;
    for (uint32_t i = 0; i < chain->length; i++) {
        struct vec3 d = vec3_sub(v[i].p, from);
        float dist = vec3_length(d);
        if (!(dist > 0.0f)) return false;
        struct manifold_vertex h;
        if (!mf_trace(scene, chain->shape, dvec3_from(from), from_ng, dvec3_from(d), &h, rc)) return false;
        if (vec3_length(vec3_sub(h.p, v[i].p)) > 1e-4f * dist + 1e-6f) return false;
        struct vec3 next = i + 1 == chain->length ? ends->xe : v[i + 1].p;
        struct vec3 wo = vec3_normalize(vec3_sub(from, v[i].p)), wi = vec3_normalize(vec3_sub(next, v[i].p));
        float so = vec3_dot(wo, v[i].ng), si = vec3_dot(wi, v[i].ng);
        if (chain->events[i] == MANIFOLD_REFLECT ? !(so * si > 0.0f) : !(so * si < 0.0f)) return false;
        /* Path tracing's own rule for a scattered direction: same side of both normals. */
        if (!(si * vec3_dot(wi, v[i].ns) > 0.0f) || vec3_dot(wo, v[i].ns) == 0.0f) return false;
        from = v[i].p;
        from_ng = v[i].ng;
    }
    struct vec3 d = vec3_sub(ends->xe, from);
    float dist = vec3_length(d);
    if (!(dist > 0.0f)) return false;
    d = vec3_scale(d, 1.0f / dist);
    return !accel_occluded(scene->accel, surface_offset(from, from_ng, d), d, 0.0f, dist * (1.0f - 1e-4f), rc);
}

double manifold_geometry(const struct scene *scene, const struct manifold_chain *chain,
                         const struct manifold_ends *ends, const struct manifold_vertex *v)
{
    const uint32_t k = chain->length, n2 = 2 * k;
    struct mf_geom g[MANIFOLD_MAX_CHAIN];
    for (uint32_t i = 0; i < k; i++)
        if (!mf_geom_of(scene, chain->shape, &v[i], &g[i])) return 0.0;
    const struct dvec3 x1 = dvec3_from(ends->x1), xe = dvec3_from(ends->xe);
    double C[MF_N], J[MF_N][MF_N], B[MF_N][2];
    struct mf_vstate S[MANIFOLD_MAX_CHAIN];
    struct dvec3 e[2];
    mf_end_frame(ends, e);
    if (!mf_eval_at(chain, x1, xe, g, C, S) || !mf_derivatives(chain, g, S, J, e, B)) return 0.0;
    struct dvec3 p[MANIFOLD_MAX_CHAIN], n[MANIFOLD_MAX_CHAIN];
    for (uint32_t i = 0; i < k; i++) mf_geom_eval(&g[i], 0.0, 0.0, &p[i], &n[i]);
    /* Implicit function theorem: d(u, v) / d(end) = -J^-1 dC/d(end); only x2's block matters,
     * and only through |det|, so the sign is left out. */
    if (!mf_solve(n2, J, B, 2)) return 0.0;
    double det = fabs(B[0][0] * B[1][1] - B[0][1] * B[1][0]);
    struct dvec3 w = dvec3_sub(p[0], x1);
    double d2 = dvec3_dot(w, w);
    w = dvec3_scale(w, 1.0 / sqrt(d2));
    /* Solid angle at x1 per parameter area at x2: |cos| dA / d² with dA = |dp/du × dp/dv| du dv
     * (geometric normal of the surface patch). */
    struct dvec3 cr = dvec3_cross(g[0].dpdu, g[0].dpdv);
    double area = dvec3_length(cr);
    double cosg = fabs(dvec3_dot(w, cr)) / area;
    double G = cosg / d2 * area * det;
    return isfinite(G) ? G : 0.0;
}

struct vec3 manifold_throughput(const struct scene *scene, const struct manifold_chain *chain,
                                const struct manifold_ends *ends, const struct manifold_vertex *v)
{
    const struct material *m = &scene->materials[scene->shapes[chain->shape].material];
    struct vec3 T = vec3_splat(1.0f);
    struct vec3 prev = ends->x1;
    for (uint32_t i = 0; i < chain->length; i++) {
        struct vec3 next = i + 1 == chain->length ? ends->xe : v[i + 1].p;
        struct vec3 wo = vec3_normalize(vec3_sub(prev, v[i].p)), wi = vec3_normalize(vec3_sub(next, v[i].p));
        float co = vec3_dot(wo, v[i].ns), ci = vec3_dot(wi, v[i].ns);
        if (chain->events[i] == MANIFOLD_REFLECT) {
            if (m->kind == MATERIAL_CONDUCTOR && microfacet_is_delta(m->roughness))
                T = vec3_mul(T, fresnel_conductor_rgb(fabsf(co), m->eta, m->k));
            else if (m->kind == MATERIAL_DIELECTRIC && microfacet_is_delta(m->roughness))
                T = vec3_scale(T, fresnel_dielectric(fabsf(co), co > 0.0f ? m->ior : 1.0f / m->ior));
            else
                return vec3_splat(0.0f);
        } else {
            if (m->kind != MATERIAL_DIELECTRIC || !microfacet_is_delta(m->roughness)) return vec3_splat(0.0f);
            bool outside = co > 0.0f;
            float eta_o = outside ? 1.0f : m->ior, eta_i = outside ? m->ior : 1.0f;
            float tr = fresnel_dielectric_transmittance(fabsf(co), fabsf(ci), eta_o, eta_i);
            /* Radiance transport: (eta_wo / eta_wi)^2, the smooth dielectric's refraction weight. */
            T = vec3_scale(T, tr * (eta_o / eta_i) * (eta_o / eta_i));
        }
        prev = v[i].p;
    }
    return T;
}

bool manifold_same(const struct manifold_vertex *a, const struct manifold_vertex *b, uint32_t length, float tol)
{
    for (uint32_t i = 0; i < length; i++)
        if (!(dvec3_length(dvec3_sub(mf_pd(&a[i]), mf_pd(&b[i]))) <= tol)) return false;
    return true;
}

bool manifold_test_derivatives(const struct scene *scene, const struct manifold_chain *chain,
                               const struct manifold_ends *ends, const struct manifold_vertex *v,
                               bool central_differences, double J[2 * MANIFOLD_MAX_CHAIN][2 * MANIFOLD_MAX_CHAIN],
                               double B[2 * MANIFOLD_MAX_CHAIN][2])
{
    const uint32_t k = chain->length;
    struct mf_geom g[MANIFOLD_MAX_CHAIN];
    if (k == 0 || k > MANIFOLD_MAX_CHAIN) return false;
    for (uint32_t i = 0; i < k; i++)
        if (!mf_geom_of(scene, chain->shape, &v[i], &g[i])) return false;
    const struct dvec3 x1 = dvec3_from(ends->x1), xe = dvec3_from(ends->xe);
    struct dvec3 e[2];
    mf_end_frame(ends, e);
    if (central_differences)
        return mf_jacobian(chain, x1, xe, g, true, NULL, J) && mf_end_differences(chain, x1, xe, g, e, B);
    double C[MF_N];
    struct mf_vstate S[MANIFOLD_MAX_CHAIN];
    return mf_eval_at(chain, x1, xe, g, C, S) && mf_derivatives(chain, g, S, J, e, B);
}
