/* restir_bdpt_light.c — ReSTIR BDPT's light subpaths (see restir_bdpt_internal.h): the light
 * pass that traces them and writes their t = 1 samples (and the full variant's light-vertex
 * cache), and the replays of a subpath that the shifts use. */
#include "integrators/restir_bdpt_internal.h"

#include "scene/accel.h"

/* ---- light subpaths ------------------------------------------------------------------------ */

/* t = 1: the light vertex at `s` seen by the eye of view `v` (bdpt_eye_link); lightweight MIS.
 * `eye_sees`: s is known to be visible from the eye, so no shadow ray is traced. */
static bool rbdpt_connect_camera(const struct rbdpt_ctx *c, const struct rbdpt_view *v, const struct surface *s,
                                 const struct material *m, struct vec3 wo_world, struct vec3 beta,
                                 const struct restir_bdpt_mis *mis, bool eye_sees, struct ray_counters *rc,
                                 uint32_t *pixel, struct vec3 *value, float sub[2], float *camera_pdf_a_out,
                                 float *mis_out)
{
    /* A path without a caustic caster has no t = 1 technique (rbdpt_mis_vertex): no shadow ray. */
    if (!rbdpt_mis_keeps_t1(mis)) return false;
    struct bdpt_eye_link e;
    if (!bdpt_eye_link(&v->cam, v->plane_dist2, eye_sees ? NULL : v->scene->accel, s, m, wo_world, rc, &e))
        return false;
    float w = restir_bdpt_mis_camera(mis, e.camera_pdf_a, c->n_light, e.rev_w, c->power);
    *value = vec3_scale(vec3_mul(beta, e.f), w * e.corr * e.camera_pdf_w / (e.dist2 * c->n_light));
    *pixel = e.iy * v->cam.width + e.ix;
    if (sub) sub[0] = e.px - (float)e.ix, sub[1] = e.py - (float)e.iy;
    if (camera_pdf_a_out) *camera_pdf_a_out = e.camera_pdf_a;
    if (mis_out) *mis_out = w;
    return true;
}

/* The t = 1 sample of the light subpath through x2 and the surface x1 (visible from x2), with
 * x_2's scattering taken along the segment between the two positions — the same numbers for
 * the initial sample and for every reverse hybrid shift of it — and the roulette rolled again
 * with x_2's own number (it is part of the light subpath's primary-sample-space integrand).
 * Its pixel, contribution, sub-pixel position and the reverse hybrid shift's Jacobian
 * denominator p_2(w) |cos_1| / d^2 / p_camera,A(x_1) (dw at x_2 per unit of image area).
 * False when it contributes nothing. */
bool rbdpt_t1_eval(const struct rbdpt_ctx *c, const struct rbdpt_view *v, const struct rbdpt_x2 *x2,
                   const struct surface *x1, bool eye_sees, struct ray_counters *rays, uint32_t *pixel,
                   struct vec3 *C, float sub[2], float *pdf, float *mis_w)
{
    const struct material *m1 = &v->scene->materials[x1->material];
    if (!(material_flags(m1) & (BSDF_DIFFUSE | BSDF_GLOSSY))) return false;
    struct restir_bdpt_mis mis = x2->mis;
    rbdpt_mis_vertex(&mis, m1);   /* x_1 joins the path's vertices */
    if (!rbdpt_mis_keeps_t1(&mis)) return false;   /* no t = 1 technique on this path */
    struct vec3 w = vec3_sub(x1->p, x2->s.p);
    float d2 = vec3_length2(w);
    if (!(d2 > 0.0f)) return false;
    w = vec3_scale(w, 1.0f / sqrtf(d2));
    struct vec3 wi = frame_to_local(&x2->s.frame, w), wo = frame_to_local(&x2->s.frame, x2->wo_world);
    float cos_i_ng = vec3_dot(w, x2->s.ng), cos_o_ng = vec3_dot(x2->wo_world, x2->s.ng);
    float cos_1 = vec3_dot(w, x1->ng);
    if (!(cos_i_ng * wi.z > 0.0f) || cos_o_ng == 0.0f || cos_1 == 0.0f) return false;
    struct vec3 f = material_eval(x2->m, wo, wi, TRANSPORT_IMPORTANCE);
    float p2 = material_pdf(x2->m, wo, wi);
    if (vec3_is_zero(f) || !(p2 > 0.0f)) return false;
    struct vec3 weight = vec3_scale(f, fabsf(wo.z) * fabsf(cos_i_ng) / (fabsf(cos_o_ng) * p2));
    struct vec3 beta = vec3_mul(x2->beta, weight);
    if (x2->depth >= c->p->rr_depth) {
        float mx = vec3_max_comp(vec3_mul(x2->rr_beta, weight));
        float q = mx < 0.95f ? mx : 0.95f;
        if (!(q > 0.0f) || x2->u_rr >= q) return false;
        beta = vec3_scale(beta, 1.0f / q);
    }
    restir_bdpt_mis_scatter(&mis, cos_i_ng, p2, material_pdf(x2->m, wi, wo), false, c->power);
    restir_bdpt_mis_hit(&mis, d2, cos_1, c->power);
    float camera_pdf_a;
    if (!rbdpt_connect_camera(c, v, x1, m1, vec3_neg(w), beta, &mis, eye_sees, rays, pixel, C, sub, &camera_pdf_a,
                              mis_w) ||
        !vec3_is_finite(*C) || vec3_is_zero(*C))
        return false;
    *pdf = p2 * fabsf(cos_1) / d2 / camera_pdf_a;
    return *pdf > 0.0f && isfinite(*pdf);
}

/* Traces light subpath i with the random numbers of frame `origin_frame` in view `v` and writes
 * its t = 1 samples to out[0 .. cap) (*stored, the excess counted in *dropped), and with `lvc`
 * (the full variant's light pass) every connectable vertex into the cache as bdpt does. With
 * only_depth > 0 it is the random-replay shift of [ReSTIR BDPT Appendix A]: the subpath is replayed
 * up to that vertex and only the sample there is written (nothing when the replayed path ends
 * earlier, the vertex is not connectable or the eye does not see it). With `x2` (and
 * only_depth >= 2) the replay stops at light depth only_depth - 1 instead and returns that
 * vertex (true when it got there). With `out` NULL and only_depth > 0 it only caches the vertex at
 * that depth into `lvc` (a connection's shift, rbdpt_replay_light_vertex). With reuse a sample
 * whose x_2 has only rough lobes is evaluated by rbdpt_t1_eval. */
bool rbdpt_trace_light(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t origin_frame,
                       uint32_t i, uint32_t only_depth, struct restir_bdpt_lt_sample *out, uint32_t cap,
                       uint32_t *stored, uint32_t *dropped, uint64_t *vertices, struct rbdpt_lvc_block *lvc,
                       struct rbdpt_x2 *x2_out, struct ray_counters *rc)
{
    const struct scene *scene = v->scene;
    const struct restir_bdpt_params *p = c->p;
    const bool track = p->reuse;
    struct rng rng;
    struct bdpt_light_start start;
    if (!rbdpt_light_stream(c, scene, origin_frame, i, &rng, &start)) return false;
    const struct light_sample ls = start.ls;
    struct vec3 dir = start.dir, beta = start.beta;
    struct vec3 rr_beta = vec3_splat(1.0f);
    struct restir_bdpt_mis mis = restir_bdpt_mis_light_start(ls.pdf_a, start.emission_pdf_w, start.cos_l, c->power);
    mis.full = c->full;
    struct vec3 org = start.org, prev_p = ls.p;
    bool prev_rough = true;   /* the emitter itself is rough: x_2 of a depth-1 sample */
    uint32_t last = only_depth ? only_depth : p->max_depth;
    if (last > p->max_depth) return false;
    if (x2_out) last = only_depth - 1;
    struct rbdpt_x2 x2 = {0};
    bool x2_rough = false;    /* track: the previous vertex is a surface with only rough lobes */

    for (uint32_t depth = 1; depth <= last; depth++) {
        struct hit hit;
        if (!accel_intersect(scene->accel, org, dir, 0.0f, INFINITY, &hit, rc)) return false;
        struct surface s;
        surface_from_hit(scene, &hit, org, dir, &s);
        restir_bdpt_mis_hit(&mis, vec3_length2(vec3_sub(s.p, prev_p)), vec3_dot(dir, s.ng), c->power);
        const struct material *m = &scene->materials[s.material];
        rbdpt_mis_vertex(&mis, m);
        struct vec3 wo_world = vec3_neg(dir);
        if (!x2_out && (!only_depth || depth == only_depth) && (material_flags(m) & (BSDF_DIFFUSE | BSDF_GLOSSY))) {
            if (vertices) (*vertices)++;
            if (lvc && lvc->count < lvc->region) {
                const struct bdpt_mis lm = {mis.dvcm, mis.dvc};
                if (lvc->path) lvc->path[lvc->count] = i;
                lvc->v[lvc->count++] = bdpt_light_vertex_make(scene, &hit, &s, wo_world, beta, &lm, depth);
            } else if (lvc) {
                lvc->dropped++;
            }
            uint32_t px;
            struct vec3 val;
            const bool hybrid = track && depth >= 2 && x2_rough;
            float sub[2], pdf;
            bool made = out && (hybrid ? rbdpt_t1_eval(c, v, &x2, &s, false, rc, &px, &val, sub, &pdf, NULL)
                                       : rbdpt_connect_camera(c, v, &s, m, wo_world, beta, &mis, false, rc, &px, &val,
                                                              NULL, NULL, NULL) &&
                                             vec3_is_finite(val) && !vec3_is_zero(val));
            if (made) {
                if (*stored < cap) {
                    out[(*stored)++] = (struct restir_bdpt_lt_sample){
                        .F = val, .pixel = px, .light_path = i, .depth = (uint16_t)depth,
                        .caustic = (uint8_t)(prev_rough ? 0 : 1), .hybrid = (uint8_t)hybrid};
                } else {
                    (*dropped)++;
                }
            }
        }
        if (depth >= last && !x2_out) return true;
        struct bsdf_sample bs;
        struct vec3 wi_world, weight;
        float cos_i_ng;
        if (!material_sample_importance(m, &s.frame, s.ng, wo_world, &rng, &bs, &wi_world, &cos_i_ng, &weight))
            return false;
        if (track || x2_out) {
            x2 = (struct rbdpt_x2){.s = s, .m = m, .wo_world = wo_world, .beta = beta, .rr_beta = rr_beta,
                                   .mis = mis, .dir = wi_world, .depth = depth};
            x2_rough = rbdpt_rough(m);
        }
        beta = vec3_mul(beta, weight);
        rr_beta = vec3_mul(rr_beta, weight);
        bool delta = (bs.flags & BSDF_DELTA) != 0;
        restir_bdpt_mis_scatter(&mis, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, delta, c->power);
        /* Roughness of x_2 for the next vertex's sample: the lobe this vertex scattered by. */
        prev_rough = !delta;
        float u_rr = rng_next_float(&rng);
        x2.u_rr = u_rr;
        if (x2_out && depth == last) {
            *x2_out = x2;
            return true;
        }
        if (depth >= p->rr_depth) {
            /* Russian roulette is part of the primary-sample-space integrand, so a replay that
             * the roulette ends fails the shift (C = 0 there). */
            float mx = vec3_max_comp(rr_beta);
            float q = mx < 0.95f ? mx : 0.95f;
            if (!(q > 0.0f) || u_rr >= q) return false;
            beta = vec3_scale(beta, 1.0f / q);
            rr_beta = vec3_scale(rr_beta, 1.0f / q);
        }
        org = bdpt_origin(&s, wi_world);
        prev_p = s.p;
        dir = wi_world;
    }
    return !x2_out;
}

/* The light pass: one job per block of light subpaths, each block into its own region. */
void rbdpt_light_block(void *ctx, uint32_t block, unsigned worker)
{
    (void)worker;
    struct rbdpt_ctx *c = ctx;
    struct restir_bdpt_state *st = c->st;
    struct ray_counters rc = {0, 0};
    struct restir_bdpt_lt_sample *region = &st->lt[(size_t)block * st->lb.region];
    uint32_t stored = 0, dropped = 0;
    uint64_t vertices = 0;
    uint32_t first = block * RBDPT_BLOCK_PATHS;
    uint32_t last = first + RBDPT_BLOCK_PATHS < st->lb.light_paths ? first + RBDPT_BLOCK_PATHS : st->lb.light_paths;
    const size_t lvc_at = (size_t)block * st->lvb.region;
    struct rbdpt_lvc_block lvc = {st->lvc ? &st->lvc[lvc_at] : NULL, st->lvc_path ? &st->lvc_path[lvc_at] : NULL,
                                  st->lvb.region, 0, 0};
    for (uint32_t i = first; i < last; i++)
        rbdpt_trace_light(c, &c->view[0], c->frame, i, 0, region, st->lb.region, &stored, &dropped, &vertices,
                          st->lvc ? &lvc : NULL, NULL, &rc);
    if (st->lvc) {
        st->lvb.count[block] = lvc.count;
        st->lvb.dropped[block] = lvc.dropped;
    }
    st->lb.count[block] = stored;
    st->lb.dropped[block] = dropped;
    st->lb.rays[3 * block] = rc.intersect;
    st->lb.rays[3 * block + 1] = rc.occluded;
    st->lb.rays[3 * block + 2] = vertices;
}

/* The light side of a connection's shift (s >= 2; [ReSTIR BDPT §5]: the light subpath shifts by
 * random replay): light subpath i of frame origin_frame replayed in view v to its vertex at light
 * depth `depth`, as the light pass would have cached it. False when the replay ends earlier or the
 * vertex is not connectable there (a changed classification fails the shift). */
static bool rbdpt_replay_light_vertex(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t origin_frame,
                                      uint32_t i, uint32_t depth, struct bdpt_light_vertex *out,
                                      struct ray_counters *rays)
{
    struct rbdpt_lvc_block one = {out, NULL, 1, 0, 0};
    rbdpt_trace_light(c, v, origin_frame, i, depth, NULL, 0, NULL, NULL, NULL, &one, NULL, rays);
    return one.count == 1;
}

/* Keeps a connection's light vertex in this frame's scene in the cache entry of `pixel`, whose
 * sample src is. */
void rbdpt_light_vertex_keep(const struct rbdpt_ctx *c, uint32_t pixel, const struct restir_bdpt_path *src,
                             const struct bdpt_light_vertex *lv)
{
    c->st->x2c[pixel] = (struct rbdpt_x2_entry){.lv = *lv, .light_path = src->rc.light_path,
                                                .origin_frame = src->r.origin_frame, .tick = c->tick,
                                                .depth_key = (uint16_t)lv->depth, .kind = RBDPT_CACHE_LV};
}

/* Whether cache entry e holds the light vertex at light depth `depth` of connection src's light
 * subpath, valid in view v. */
static bool rbdpt_lv_entry_of(const struct rbdpt_ctx *c, const struct rbdpt_view *v, const struct rbdpt_x2_entry *e,
                              const struct restir_bdpt_path *src, uint32_t depth)
{
    return e->kind == RBDPT_CACHE_LV && rbdpt_x2_valid(c, v, e) && e->light_path == src->rc.light_path &&
           e->origin_frame == src->r.origin_frame && e->depth_key == depth;
}

/* A connection's light vertex (rbdpt_replay_light_vertex) through the cache entries of `pixel`,
 * whose sample src is (UINT32_MAX: none; st->x2c, see rbdpt_x2_keep): found in this render's
 * entry, or in the same pixel's entry of st->x2c_prev (the previous render's, or from the second
 * spatial round on the previous round's) when it was kept in this frame's scene, else replayed;
 * with `keep` (only the job that owns the pixel) kept in this render's entry. The entries hold what
 * the replay gave, so an image does not depend on them. */
bool rbdpt_light_vertex_of(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t pixel,
                           const struct restir_bdpt_path *src, bool keep, struct bdpt_light_vertex *lv,
                           struct ray_counters *rays)
{
    const uint32_t depth = (src->r.head.bits & 0xffu) - 1u;
    const struct restir_bdpt_state *st = c->st;
    const bool cached = st->x2c && pixel != UINT32_MAX && v->scene == c->view[0].scene;
    if (cached && rbdpt_lv_entry_of(c, v, &st->x2c[pixel], src, depth)) {
        *lv = st->x2c[pixel].lv;
        return true;
    }
    if (cached && st->x2c_prev && rbdpt_lv_entry_of(c, v, &st->x2c_prev[pixel], src, depth)) {
        *lv = st->x2c_prev[pixel].lv;
    } else if (!rbdpt_replay_light_vertex(c, v, src->r.origin_frame, src->rc.light_path, depth, lv, rays)) {
        return false;
    }
    if (cached && keep) rbdpt_light_vertex_keep(c, pixel, src, lv);
    return true;
}
