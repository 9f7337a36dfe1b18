/* restir_bdpt_reuse.c — ReSTIR BDPT's reuse of the non-caustic reservoir (see
 * restir_bdpt_internal.h): the shifts restir.c's temporal and spatial passes call, and the per-pixel
 * cache of light-side vertices that spares them replays. */
#include "integrators/restir_bdpt_internal.h"

#include "scene/accel.h"

/* ---- reuse of the non-caustic reservoir (restir.c's passes) ------------------------------- */

/* The x_2 cache (st->x2c): rbdpt_x2_keep stores what the replay of a sample's light subpath
 * gave in this frame's scene, rbdpt_x2_cached gives it back to a shift in that same scene —
 * the same numbers, so an image does not depend on whether a shift found its x_2 here. In a
 * still scene the previous render's entries are as good: a sample of the history (most of a
 * pixel's samples, with temporal reuse) finds its x_2 in st->x2c_prev at rc.x2_pixel, where
 * that render's x_2 pass put it, instead of replaying its light subpath in the temporal pass
 * and again in this render's x_2 pass. */
static void rbdpt_x2_keep(const struct rbdpt_ctx *c, uint32_t pixel, const struct restir_bdpt_path *res,
                          const struct rbdpt_x2 *x2)
{
    struct rbdpt_x2_entry *e = &c->st->x2c[pixel];
    *e = (struct rbdpt_x2_entry){.p = x2->s.p, .ng = x2->s.ng, .ns = x2->s.ns, .shape = x2->s.shape,
                                 .prim = x2->s.prim, .material = x2->s.material, .wo_world = x2->wo_world,
                                 .beta = x2->beta, .rr_beta = x2->rr_beta, .dvcm = x2->mis.dvcm,
                                 .dvc = x2->mis.dvc, .u_rr = x2->u_rr, .depth = x2->depth,
                                 .light_path = res->r.light_path, .origin_frame = res->r.origin_frame,
                                 .tick = c->tick, .depth_key = (uint16_t)(res->r.head.bits >> 8),
                                 .near = (uint8_t)(x2->mis.near | x2->mis.caster << 1), .kind = RBDPT_CACHE_X2};
}

/* Entry e if it holds sample src's x_2, valid in view v. */
static bool rbdpt_x2_entry_of(const struct rbdpt_ctx *c, const struct rbdpt_view *v, const struct rbdpt_x2_entry *e,
                              const struct restir_bdpt_path *src)
{
    return e->kind == RBDPT_CACHE_X2 && e->light_path == src->r.light_path && e->origin_frame == src->r.origin_frame &&
           e->depth_key == (uint16_t)(src->r.head.bits >> 8) && rbdpt_x2_valid(c, v, e);
}

/* The entry holding src's x_2 (a sample of `pixel`, UINT32_MAX: of none in this render): that
 * pixel's in this render's cache, else the one its hint names in the previous render's; NULL
 * when neither holds it. */
static const struct rbdpt_x2_entry *rbdpt_x2_find(const struct rbdpt_ctx *c, const struct rbdpt_view *v,
                                                  uint32_t pixel, const struct restir_bdpt_path *src)
{
    const struct restir_bdpt_state *st = c->st;
    if (!st->x2c) return NULL;
    if (pixel != UINT32_MAX && rbdpt_x2_entry_of(c, v, &st->x2c[pixel], src)) return &st->x2c[pixel];
    const uint32_t h = src->rc.x2_pixel;
    if (st->x2c_prev && h < st->width * st->height && rbdpt_x2_entry_of(c, v, &st->x2c_prev[h], src))
        return &st->x2c_prev[h];
    return NULL;
}

static bool rbdpt_x2_cached(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t pixel,
                            const struct restir_bdpt_path *src, struct rbdpt_x2 *x2)
{
    const struct rbdpt_x2_entry *e = rbdpt_x2_find(c, v, pixel, src);
    if (!e) return false;
    *x2 = (struct rbdpt_x2){.s = {.p = e->p, .ng = e->ng, .ns = e->ns, .frame = frame_from_normal(e->ns),
                                  .shape = e->shape, .prim = e->prim, .material = e->material},
                            .m = &v->scene->materials[e->material], .wo_world = e->wo_world, .beta = e->beta,
                            .rr_beta = e->rr_beta, .mis = {e->dvcm, e->dvc, (e->near & 1) != 0, c->full, (e->near & 2) != 0},
                            .u_rr = e->u_rr, .depth = e->depth};
    return true;
}

/* The hybrid shift of a camera-side sample with a reconnection (src->rc.k >= 2) into pixel
 * `pixel` of view v, whose scene is the sample's own ([ReSTIR BDPT §6.1]; the camera-subpath case
 * of its bidirectional hybrid shift): the camera subpath is replayed with the sample's random
 * numbers through the pixel up to x'_{k-1} — no pair before it may be connectable, or the
 * shifted path would reconnect elsewhere and the shift would not be invertible — then joined to
 * x_k, whose suffix is kept. Its contribution, the Jacobian p'_{k-1} G' p'_k / (p_{k-1} G p_k)
 * (Appendix C), and the shifted path's own denominator (*pdf, for its later shifts); false when
 * the shift fails. */
static bool rbdpt_reconnect(const struct rbdpt_ctx *c, const struct rbdpt_view *v, const struct scene *scene_from,
                            const struct restir_bdpt_path *src, const struct bdpt_light_vertex *lv, uint32_t pixel,
                            struct vec3 *C, float *J, struct restir_bdpt_rc *rc_out, struct ray_counters *rays)
{
    const struct scene *scene = v->scene;
    const struct camera *cam = &v->cam;
    const uint32_t k = src->rc.k, e = (uint32_t)(src->r.head.bits >> 8), tech = src->r.head.bits & 0xffu;
    const bool nee = tech == 1u;
    const uint32_t draws = rbdpt_vertex_draws(c);
    struct rng rng = rng_make(c->seed, src->r.origin_frame, RBDPT_CAMERA_STREAM + src->r.light_path, 0);
    float jx, jy;
    rbdpt_jitter(c, src->r.origin_frame, src->r.light_path, &rng, &jx, &jy);
    const uint32_t w = c->st->width;
    struct vec3 dir = camera_ray_dir(cam, (float)(pixel % w) + jx, (float)(pixel / w) + jy);
    float cos0 = vec3_dot(dir, cam->forward);
    if (!(cos0 > 0.0f)) return false;
    struct restir_bdpt_mis mis = restir_bdpt_mis_camera_start(c->n_light, v->plane_dist2 / (cos0 * cos0 * cos0),
                                                                  c->power);
    mis.full = c->full;
    struct vec3 beta = vec3_splat(1.0f), org = cam->position, prev_p = org;
    struct surface s;
    const struct material *m = NULL;
    bool prev_rough = false;
    /* y_1 .. y_{k-1} by random replay, drawing the random numbers as rbdpt_camera_candidates does. */
    for (uint32_t j = 1;; j++) {
        struct hit hit;
        if (!accel_intersect(scene->accel, org, dir, 0.0f, INFINITY, &hit, rays)) return false;
        surface_from_hit(scene, &hit, org, dir, &s);
        restir_bdpt_mis_hit(&mis, vec3_length2(vec3_sub(s.p, prev_p)), vec3_dot(dir, s.ng), c->power);
        m = &scene->materials[s.material];
        const bool rough = rbdpt_rough(m);
        if (j >= 2 && prev_rough && rough) return false;
        rbdpt_mis_vertex(&mis, m);
        if (j + 1 == k) break;
        for (uint32_t n = 0; n < draws - 4u; n++) rng_next_float(&rng);   /* the light sample's (and vertex choice) */
        struct vec3 wo = frame_to_local(&s.frame, vec3_neg(dir));
        struct bsdf_sample bs;
        struct vec3 wi_world;
        float cos_i_ng;
        if (!material_sample_at(m, &s.frame, s.ng, wo, &rng, TRANSPORT_RADIANCE, &bs, &wi_world, &cos_i_ng)) return false;
        beta = vec3_mul(beta, vec3_scale(bs.f, fabsf(bs.wi.z) / bs.pdf_w));
        restir_bdpt_mis_scatter(&mis, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, (bs.flags & BSDF_DELTA) != 0, c->power);
        rng_next_float(&rng);   /* the roulette's: survival is certain in a shift */
        prev_rough = rough;
        org = bdpt_origin(&s, wi_world);
        prev_p = s.p;
        dir = wi_world;
    }
    if (!rbdpt_rough(m)) return false;
    struct surface sk;
    surface_at(scene, src->rc.shape, src->rc.prim, src->rc.b1, src->rc.b2, &sk);
    const struct material *mk = &scene->materials[sk.material];
    if (!rbdpt_rough(mk)) return false;
    /* x_k is rough, and may still be a caustic caster (a narrow glossy lobe). */
    rbdpt_mis_vertex(&mis, mk);
    /* y_{k-1} -> x_k. */
    struct vec3 w1 = vec3_sub(sk.p, s.p);
    float d2 = vec3_length2(w1);
    if (!(d2 > 0.0f)) return false;
    w1 = vec3_scale(w1, 1.0f / sqrtf(d2));
    struct vec3 wo = frame_to_local(&s.frame, vec3_neg(dir)), wi = frame_to_local(&s.frame, w1);
    if (!(vec3_dot(w1, s.ng) * wi.z > 0.0f)) return false;
    struct vec3 f1 = material_eval(m, wo, wi, TRANSPORT_RADIANCE);
    float p1 = material_pdf(m, wo, wi);
    float cos_k = vec3_dot(w1, sk.ng);
    struct vec3 wo_k = frame_to_local(&sk.frame, vec3_neg(w1));
    if (vec3_is_zero(f1) || !(p1 > 0.0f) || !(-cos_k * wo_k.z > 0.0f)) return false;
    restir_bdpt_mis_scatter(&mis, vec3_dot(w1, s.ng), p1, material_pdf(m, wi, wo), false, c->power);
    restir_bdpt_mis_hit(&mis, d2, cos_k, c->power);
    if (tech >= 2u && k + tech == e) {
        /* x_k itself joins the sample's light vertex (replayed in this scene by rbdpt_shift): the
         * direction leaving x_k is the connection's, fixed by the light vertex, so p_k = 1 as for
         * a light sample. */
        bool made;
        const struct bdpt_mis cm = {mis.dvcm, mis.dvc};
        struct vec3 cv = bdpt_connect_light_vertex(scene, c->power, 1.0f, &sk, mk, wo_k, &cm, lv, rays, &made, NULL);
        if (!made || !bdpt_visible(scene->accel, s.p, s.ng, sk.p, &sk.ng, rays)) return false;
        *rc_out = src->rc;
        rc_out->pdf = p1 * fabsf(cos_k) / d2;
        *C = vec3_mul(vec3_mul(beta, vec3_scale(f1, fabsf(wi.z) / p1)), cv);
        *J = rc_out->pdf / src->rc.pdf *
             surface_area_ratio(scene_from, scene, src->rc.shape, src->rc.prim, src->rc.b1, src->rc.b2);
        return isfinite(*J) && *J > 0.0f && vec3_is_finite(*C);
    }
    const bool nee_last = nee && k + 1 == e;   /* the light sample leaves x_k itself */
    /* The full variant draws a light sample that leaves x_k again in every shift (its weight
     * over all techniques has no suffix to keep constants of; the draw is cheap). */
    const bool retrace = (c->full && nee_last) || (scene_from != scene && !c->static_scene) || c->force_retrace;
    /* x_k towards w_k with its new w_o. */
    struct vec3 wk_world = surface_oct_decode(src->rc.wk_u, src->rc.wk_v), L_k = src->rc.L;
    struct light_sample ls = {0};
    float direct_pdf_w = 0.0f, emission_pdf_w = 0.0f, cos_l = 0.0f;
    if (retrace && nee_last) {
        /* The light sample is the other scene's: it is drawn again here from its own random
         * numbers (x_k's, as rbdpt_camera_candidates draws them), its Jacobian 1 in primary
         * sample space, as the suffix of any other reconnected sample is traced again. */
        struct rng r2 = rng_make(c->seed, src->r.origin_frame, RBDPT_CAMERA_STREAM + src->r.light_path, 0);
        const uint32_t skip = RBDPT_CAMERA_JITTER_DRAWS + draws * (k - 1);
        for (uint32_t n = 0; n < skip; n++) rng_next_float(&r2);
        float ul = rng_next_float(&r2), u1 = rng_next_float(&r2), u2 = rng_next_float(&r2);
        struct rbdpt_nee ns;
        if (!rbdpt_nee_sample(scene, sk.p, ul, u1, u2, &ns)) return false;
        ls = ns.ls;
        wk_world = ns.wi_world;
        cos_l = ns.cos_l;
        direct_pdf_w = ns.direct_pdf_w;
        emission_pdf_w = ns.emission_pdf_w;
        L_k = vec3_scale(ns.Le, 1.0f / direct_pdf_w);
    }
    struct vec3 wk = frame_to_local(&sk.frame, wk_world);
    if (!(vec3_dot(wk_world, sk.ng) * wk.z > 0.0f)) return false;
    struct vec3 fk = material_eval(mk, wo_k, wk, TRANSPORT_RADIANCE);
    float fwd = material_pdf(mk, wo_k, wk), rev = material_pdf(mk, wk, wo_k);
    if (vec3_is_zero(fk)) return false;
    struct vec3 factor_k;
    float B, mis_w = 1.0f;
    if (nee_last) {
        /* w_k is the light sample's direction, drawn independently of w_o: p_k = 1. */
        factor_k = vec3_scale(fk, fabsf(wk.z));
        B = 1.0f;
        if (retrace) {
            if (!bdpt_visible(scene->accel, sk.p, sk.ng, ls.p, &ls.n, rays)) return false;
            const float cos_ng = vec3_dot(wk_world, sk.ng);
            mis_w = restir_bdpt_mis_nee(&mis, fwd, rev, direct_pdf_w, emission_pdf_w, cos_ng, cos_l, c->power);
        } else if (!c->p->copy_mis) {
            mis_w = restir_bdpt_mis_reconnect(RBDPT_RC_NEE_LAST, src->rc.mis_a, src->rc.mis_b, &mis, fwd, rev,
                                              c->power);
        }
    } else {
        if (!(fwd > 0.0f)) return false;
        factor_k = vec3_scale(fk, fabsf(wk.z) / fwd);
        B = fwd;
        restir_bdpt_mis_scatter(&mis, vec3_dot(wk_world, sk.ng), fwd, rev, false, c->power);
        if (!retrace && c->full)
            mis_w = rbdpt_full_weight(&src->rc, &mis);
        else if (!retrace && !c->p->copy_mis) {
            /* The kept suffix's vertices are the new path's too. */
            struct restir_bdpt_mis whole = mis;
            whole.caster = whole.caster || src->rc.mis_c != 0.0f;
            mis_w = restir_bdpt_mis_reconnect(k + 1 == e ? RBDPT_RC_EMIT_LAST : RBDPT_RC_AFTER, src->rc.mis_a,
                                              src->rc.mis_b, &whole, fwd, rev, c->power);
        }
    }
    if (!(mis_w > 0.0f) || !isfinite(mis_w)) return false;
    if (!bdpt_visible(scene->accel, s.p, s.ng, sk.p, &sk.ng, rays)) return false;
    *rc_out = src->rc;
    rc_out->pdf = p1 * fabsf(cos_k) / d2 * B;
    struct vec3 head = vec3_mul(beta, vec3_scale(f1, fabsf(wi.z) / p1));
    if (retrace && nee_last) {
        /* The new light sample becomes the sample's (what its later shifts keep). */
        surface_oct_encode(wk_world, &rc_out->wk_u, &rc_out->wk_v);
        restir_bdpt_rc_mis_nee(fwd, rev, direct_pdf_w, emission_pdf_w, vec3_dot(wk_world, sk.ng), cos_l, true, 1.0f,
                               c->power, &rc_out->mis_a, &rc_out->mis_b);
        rc_out->mis_c = 0.0f;   /* no vertex past x_k */
        if (c->p->copy_mis) {
            L_k = vec3_scale(L_k, mis_w);
            mis_w = 1.0f;
        }
        rc_out->L = L_k;
        *C = vec3_scale(vec3_mul(head, vec3_mul(factor_k, L_k)), mis_w);
    } else if (retrace) {
        /* The suffix in this scene: x_k's scattering along w_k, then the rest as the sample's own
         * random numbers trace it (those of vertices 1 .. k skipped). */
        struct rng r2 = rng_make(c->seed, src->r.origin_frame, RBDPT_CAMERA_STREAM + src->r.light_path, 0);
        const uint32_t skip = RBDPT_CAMERA_JITTER_DRAWS + draws * k;
        for (uint32_t n = 0; n < skip; n++) rng_next_float(&r2);
        const struct rbdpt_resume resume = {.org = bdpt_origin(&sk, wk_world), .dir = wk_world, .prev_p = sk.p,
                                            .beta = vec3_mul(head, factor_k), .mis = mis, .rc = *rc_out};
        struct rbdpt_want want = {.bits = src->r.head.bits, .k = k, .lv = lv, .lv_path = src->rc.light_path,
                                  .found = false};
        struct vec3 primary;
        bool has_primary;
        rbdpt_camera_candidates(c, v, wk_world, src->r.light_path, src->r.origin_frame, &r2, NULL, NULL, rays, NULL,
                                &primary, &has_primary, &want, &resume);
        if (!want.found) return false;
        *C = want.C;
        *rc_out = want.rc;
    } else {
        *C = vec3_scale(vec3_mul(head, vec3_mul(factor_k, src->rc.L)), mis_w);
    }
    *J = rc_out->pdf / src->rc.pdf *
         surface_area_ratio(scene_from, scene, src->rc.shape, src->rc.prim, src->rc.b1, src->rc.b2);
    return isfinite(*J) && *J > 0.0f && vec3_is_finite(*C);
}

/* The reverse hybrid shift of a non-caustic t = 1 sample whose x_2 has only rough lobes
 * ([ReSTIR BDPT §6.1], "light tracing, non-caustic"): its light subpath is replayed with its random
 * numbers in view v up to x'_2, and joined to the new x'_1: the surface the eye sees through the
 * same point of the target pixel (the sample's sub-pixel position, kept in rc.b1 / rc.b2), so the
 * shift maps the paths through one pixel one-to-one onto those through the other. Jacobian:
 * the image-area density of x_1's direction at x_2, p_2(w) |cos_1| / d^2 / p_camera,A(x_1), of
 * the new path over the old (rc.pdf). False when the shift fails. */
static bool rbdpt_reverse(const struct rbdpt_ctx *c, const struct rbdpt_view *v, const struct restir_bdpt_path *src,
                          uint32_t from_pixel, uint32_t pixel, struct vec3 *C, float *J, float *pdf,
                          struct ray_counters *rays)
{
    const uint32_t depth = (uint32_t)(src->r.head.bits >> 8) - 1u;   /* x_1's light depth */
    if (depth < 2 || !(src->rc.pdf > 0.0f)) return false;
    struct rbdpt_x2 x2;
    if (!rbdpt_x2_cached(c, v, from_pixel, src, &x2) &&
        !rbdpt_trace_light(c, v, src->r.origin_frame, src->r.light_path, depth, NULL, 0, NULL, NULL, NULL, NULL, &x2,
                           rays))
        return false;
    if (!rbdpt_rough(x2.m)) return false;
    const struct camera *cam = &v->cam;
    const uint32_t w = c->st->width;
    struct vec3 dir = camera_ray_dir(cam, (float)(pixel % w) + src->rc.b1, (float)(pixel / w) + src->rc.b2);
    struct hit hit;
    if (!accel_intersect(v->scene->accel, cam->position, dir, 0.0f, INFINITY, &hit, rays)) return false;
    struct surface x1;
    surface_from_hit(v->scene, &hit, cam->position, dir, &x1);
    uint32_t px;
    float mis_w;
    /* x'_1 is the eye ray's first hit: the eye sees it, and no shadow ray asks again. */
    if (!rbdpt_t1_eval(c, v, &x2, &x1, true, rays, &px, C, NULL, pdf, &mis_w) || px != pixel) return false;
    if (!bdpt_visible(v->scene->accel, x2.s.p, x2.s.ng, x1.p, &x1.ng, rays)) return false;
    /* copy_mis: the weight the sample was drawn with ([ReSTIR BDPT §6.4]), not the new path's. */
    if (c->p->copy_mis) *C = vec3_scale(*C, src->rc.mis_a / mis_w);
    *J = *pdf / src->rc.pdf;
    return isfinite(*J) && *J > 0.0f;
}

/* The reconnection record of a pixel's selected t = 1 sample of the reverse hybrid shift's
 * class, found once it is selected rather than kept for every light-traced sample: the light
 * subpath is replayed to x_2, x_1 found along the direction x_2 sampled, and the sub-pixel
 * position and Jacobian denominator taken from rbdpt_t1_eval, which made the sample. False (the
 * sample then never shifts) if the replay does not give it back. */
bool rbdpt_reverse_record(const struct rbdpt_ctx *c, uint32_t pixel, struct restir_bdpt_path *res,
                          struct ray_counters *rays)
{
    const struct rbdpt_view *v = &c->view[0];
    const uint32_t depth = (uint32_t)(res->r.head.bits >> 8) - 1u;
    struct rbdpt_x2 x2;
    if (!rbdpt_trace_light(c, v, res->r.origin_frame, res->r.light_path, depth, NULL, 0, NULL, NULL, NULL, NULL, &x2,
                           rays))
        return false;
    struct hit hit;
    struct vec3 org = bdpt_origin(&x2.s, x2.dir);
    if (!accel_intersect(v->scene->accel, org, x2.dir, 0.0f, INFINITY, &hit, rays)) return false;
    struct surface x1;
    surface_from_hit(v->scene, &hit, org, x2.dir, &x1);
    uint32_t px;
    struct vec3 C;
    float sub[2], pdf, mis_w;
    /* The light pass made this very sample (the replay is exact): the eye saw x_1 then. */
    if (!rbdpt_t1_eval(c, v, &x2, &x1, true, rays, &px, &C, sub, &pdf, &mis_w)) return false;
    res->rc.b1 = sub[0];
    res->rc.b2 = sub[1];
    res->rc.pdf = pdf;
    res->rc.mis_a = mis_w;
    if (c->st->x2c) {
        rbdpt_x2_keep(c, pixel, res, &x2);
        res->rc.x2_pixel = pixel;
    }
    return true;
}

/* `reject_unshiftable` ([ReSTIR BDPT §7.2], "stable but biased temporal reuse of light traced
 * samples"): whether the non-caustic t = 1 sample of light subpath `light_path` (frame
 * `origin_frame`, x_1 at light depth `depth`) could be joined to the pixel's primary hit `xg`
 * instead of its own x_1 — x_2 scatters (or, at depth 1, emits) towards xg, xg scatters towards
 * the eye, and the two see each other. A sample the eye sees at x_1 through another surface than
 * the primary hit fails (Fig. 6); dropping it darkens penumbrae a little. */
bool rbdpt_reaches_primary(const struct rbdpt_ctx *c, const struct rbdpt_view *v, uint32_t origin_frame,
                           uint32_t light_path, uint32_t depth, const struct surface *xg,
                           struct ray_counters *rays)
{
    const struct material *mg = &v->scene->materials[xg->material];
    if (!(material_flags(mg) & (BSDF_DIFFUSE | BSDF_GLOSSY))) return false;
    struct vec3 p2, n2;
    struct rbdpt_x2 x2;
    if (depth == 1) {
        struct rng rng;
        struct bdpt_light_start start;
        if (!rbdpt_light_stream(c, v->scene, origin_frame, light_path, &rng, &start)) return false;
        p2 = start.ls.p;
        n2 = start.n;
        if (!(vec3_dot(vec3_sub(xg->p, p2), n2) > 0.0f)) return false;
    } else {
        if (!rbdpt_trace_light(c, v, origin_frame, light_path, depth, NULL, 0, NULL, NULL, NULL, NULL, &x2, rays))
            return false;
        p2 = x2.s.p;
        n2 = x2.s.ng;
        struct vec3 w = vec3_normalize(vec3_sub(xg->p, p2));
        struct vec3 wi = frame_to_local(&x2.s.frame, w), wo = frame_to_local(&x2.s.frame, x2.wo_world);
        if (!(vec3_dot(w, n2) * wi.z > 0.0f) ||
            vec3_is_zero(material_eval(x2.m, wo, wi, TRANSPORT_IMPORTANCE)))
            return false;
    }
    struct vec3 to2 = vec3_normalize(vec3_sub(p2, xg->p));
    struct vec3 toeye = vec3_normalize(vec3_sub(v->cam.position, xg->p));
    struct vec3 wi = frame_to_local(&xg->frame, to2), wo = frame_to_local(&xg->frame, toeye);
    if (!(vec3_dot(to2, xg->ng) * wi.z > 0.0f) || !(vec3_dot(toeye, xg->ng) * wo.z > 0.0f) ||
        vec3_is_zero(material_eval(mg, wo, wi, TRANSPORT_RADIANCE)))
        return false;
    return bdpt_visible(v->scene->accel, p2, n2, xg->p, &xg->ng, rays);
}

/* The shift of a non-caustic sample into domain `to`:
 *  - s = 0 and s = 1 with a reconnection: the hybrid shift (rbdpt_reconnect; between frames
 *    whose scenes differ with its suffix traced again);
 *  - s = 0 and s = 1 otherwise: random replay, whose Jacobian in primary sample space is 1 (the
 *    identity on the random numbers): the camera subpath of the sample's own random stream (the
 *    pixel and frame it was drawn in) is traced again through the target pixel (its jitter from
 *    that stream) in the target frame's scene and camera, and the candidate of the same
 *    technique and length is the shifted sample, its lightweight MIS weight and reconnection
 *    recomputed on the new path. Between frames whose scenes agree a sample without a
 *    reconnection must shift to one without (the hybrid shift's replay-only class);
 *  - t = 1 of the reverse hybrid shift's class (rc.k = 1): rbdpt_reverse;
 *  - other t = 1: the light subpath is replayed in the target frame; the shift succeeds only when
 *    the replayed sample lands in the target pixel and is still non-caustic and outside that
 *    class (such a sample belongs to the pixel it lands in: it cannot move to a neighbour).
 * A replay that ends early, misses the technique or changes class fails (target 0). */
void rbdpt_shift(const void *ctx, const void *src_v, struct restir_domain from, struct restir_domain to,
                 void *dst_v, float *target, float *jacobian, struct restir_counters *cnt)
{
    const struct rbdpt_ctx *c = ctx;
    const struct restir_bdpt_path *src = src_v;
    const struct rbdpt_view *v = &c->view[to.frame == RESTIR_PREVIOUS ? 1 : 0];
    const uint32_t w = c->st->width;
    *target = 0.0f;
    *jacobian = 1.0f;
    struct vec3 C = {0, 0, 0};
    struct restir_bdpt_rc rc = src->rc;
    const struct scene *scene_from = c->view[from.frame == RESTIR_PREVIOUS ? 1 : 0].scene;
    const bool connection = rbdpt_is_connection(src);
    /* A sample of the history shifted into the pixel it sat in, when the previous render computed
     * its F there by a shift and nothing has changed since (two still renders in a row: the
     * previous one's shift saw the same scene on both sides, so it did not trace its suffix
     * again): this shift is the identity and would repeat that computation on the same inputs
     * (the same replays, cache entries and rays), giving the same F and rc and a Jacobian of
     * exactly 1 (rc.pdf over itself; surface_area_ratio of one scene is 1). Its answer is taken
     * as it is, without the rays. */
    if (from.frame == RESTIR_PREVIOUS && to.frame == RESTIR_CURRENT && from.pixel == to.pixel && !connection &&
        src->rc.eval_tick == c->tick - 1u && src->rc.eval_tick > c->still_from) {
        const uint32_t tech = src->r.head.bits & 0xffu;
        if ((tech == RESTIR_BDPT_TECH_LT && src->rc.k) || (tech != RESTIR_BDPT_TECH_LT && src->rc.k >= 2))
            atomic_fetch_add_explicit(c->reconnections, 1, memory_order_relaxed);
        *target = vec3_luminance(src->r.F);
        if (dst_v && *target > 0.0f) {
            struct restir_bdpt_path *dst = dst_v;
            *dst = *src;
            dst->rc.eval_tick = c->tick;
        }
        return;
    }
    /* s >= 2: the sample's light vertex in the target scene, needed unless the hybrid shift keeps
     * it (reconnected before the connecting vertex, in a scene where the light subpath replays
     * to the same vertices). */
    struct bdpt_light_vertex lv = {0};
    const struct bdpt_light_vertex *lvp = NULL;
    if (connection) {
        const uint32_t tech = src->r.head.bits & 0xffu, e = (uint32_t)(src->r.head.bits >> 8);
        const bool moved = (scene_from != v->scene && !c->static_scene) || c->force_retrace;
        if (src->rc.k < 2 || src->rc.k + tech == e || moved) lvp = &lv;
    }
    bool ok = false;
    if ((src->r.head.bits & 0xffu) == RESTIR_BDPT_TECH_LT && src->rc.k) {
        float pdf;
        ok = rbdpt_reverse(c, v, src, from.frame == RESTIR_CURRENT ? from.pixel : UINT32_MAX, to.pixel, &C, jacobian,
                           &pdf, &cnt->rays);
        if (ok) rc.pdf = pdf;
        atomic_fetch_add_explicit(c->reconnections, 1, memory_order_relaxed);
    } else if ((src->r.head.bits & 0xffu) == RESTIR_BDPT_TECH_LT) {
        struct restir_bdpt_lt_sample out;
        uint32_t stored = 0, dropped = 0;
        rbdpt_trace_light(c, v, src->r.origin_frame, src->r.light_path, (uint32_t)(src->r.head.bits >> 8) - 1u, &out,
                          1, &stored, &dropped, NULL, NULL, NULL, &cnt->rays);
        /* It stays in its class: a replayed sample of the reverse hybrid shift's would not shift back. */
        ok = stored == 1 && !out.caustic && !out.hybrid && out.pixel == to.pixel;
        if (ok) C = out.F;
    } else if (lvp && !rbdpt_light_vertex_of(c, v, from.frame == RESTIR_CURRENT ? from.pixel : UINT32_MAX, src,
                                             false, &lv, &cnt->rays)) {
        ok = false;
    } else if (src->rc.k >= 2) {
        ok = rbdpt_reconnect(c, v, scene_from, src, lvp, to.pixel, &C, jacobian, &rc, &cnt->rays);
        atomic_fetch_add_explicit(c->reconnections, 1, memory_order_relaxed);
    } else {
        struct rng rng = rng_make(c->seed, src->r.origin_frame, RBDPT_CAMERA_STREAM + src->r.light_path, 0);
        float jx, jy;
        rbdpt_jitter(c, src->r.origin_frame, src->r.light_path, &rng, &jx, &jy);
        struct vec3 dir = camera_ray_dir(&v->cam, (float)(to.pixel % w) + jx, (float)(to.pixel / w) + jy);
        struct rbdpt_want want = {.bits = src->r.head.bits, .k = 0, .lv = lvp, .lv_path = src->rc.light_path,
                                  .found = false};
        struct vec3 primary;
        bool has_primary;
        rbdpt_camera_candidates(c, v, dir, src->r.light_path, src->r.origin_frame, &rng, NULL, NULL, &cnt->rays,
                                NULL, &primary, &has_primary, &want, NULL);
        ok = want.found;
        C = want.C;
    }
    if (!ok || !vec3_is_finite(C)) {
        *jacobian = 1.0f;
        return;
    }
    *target = vec3_luminance(C);
    if (dst_v && *target > 0.0f) {
        struct restir_bdpt_path *dst = dst_v;
        *dst = *src;
        dst->r.F = C;
        dst->rc = rc;
        if (!connection) dst->rc.eval_tick = c->tick;
    }
}

static float rbdpt_target(const void *ctx, const void *elem)
{
    (void)ctx;
    return vec3_luminance(((const struct restir_bdpt_path *)elem)->r.F);
}

/* Every pixel can produce samples: its camera subpaths are jittered over the whole pixel, and
 * light-traced samples land anywhere (a G-buffer ray that escaped says nothing about them). */
static bool rbdpt_domain_valid(const void *ctx, struct restir_domain d)
{
    (void)ctx;
    (void)d;
    return true;
}

/* A sample's contribution F: its luminance is the target (rbdpt_target). */
static struct vec3 rbdpt_value(const void *ctx, const void *elem)
{
    (void)ctx;
    return ((const struct restir_bdpt_path *)elem)->r.F;
}

const struct restir_ops rbdpt_ops = {.stride = sizeof(struct restir_bdpt_path), .target = rbdpt_target,
                                     .shift = rbdpt_shift, .domain_valid = rbdpt_domain_valid, .value = rbdpt_value};

/* Before each spatial round: every pixel's sample of the reverse hybrid shift's class gets its x_2
 * in this frame's scene into the cache, and every connection its light vertex, so that its
 * shifts to the neighbours (and theirs) do not each replay its light subpath; most were kept
 * when the sample was drawn, the rest came from the history, or in a later round from the
 * previous round's entries (st->x2c_prev: the pixel a moved sample came from). One job per row,
 * each writing its own pixels. */
void rbdpt_x2_row(void *ctx, uint32_t row, unsigned worker)
{
    struct rbdpt_ctx *c = ctx;
    struct restir_bdpt_state *st = c->st;
    struct rbdpt_worker *wk = &c->worker[worker];
    struct ray_counters rc = {0, 0};
    for (uint32_t x = 0; x < st->width; x++) {
        uint32_t pixel = row * st->width + x;
        struct restir_bdpt_path *res = &st->res[pixel];
        struct rbdpt_x2 x2;
        if (rbdpt_is_connection(res) && res->r.head.W > 0.0f) {
            struct bdpt_light_vertex lv;
            rbdpt_light_vertex_of(c, &c->view[0], pixel, res, true, &lv, &rc);
            continue;
        }
        if ((res->r.head.bits & 0xffu) != RESTIR_BDPT_TECH_LT || res->rc.k != 1 || !(res->r.head.W > 0.0f)) continue;
        /* Found in this pixel's entry, copied from the previous render's (a sample of the
         * history), or replayed; the spatial pass's outputs carry the hint along. */
        const struct rbdpt_x2_entry *e = rbdpt_x2_find(c, &c->view[0], pixel, res);
        if (e && e != &st->x2c[pixel]) {
            st->x2c[pixel] = *e;
            st->x2c[pixel].tick = c->tick;
        } else if (!e && rbdpt_trace_light(c, &c->view[0], res->r.origin_frame, res->r.light_path,
                                           (uint32_t)(res->r.head.bits >> 8) - 1u, NULL, 0, NULL, NULL, NULL, NULL, &x2,
                                           &rc)) {
            rbdpt_x2_keep(c, pixel, res, &x2);
        } else if (!e) {
            continue;
        }
        res->rc.x2_pixel = pixel;
    }
    wk->rays_intersect += rc.intersect;
    wk->rays_occluded += rc.occluded;
}
