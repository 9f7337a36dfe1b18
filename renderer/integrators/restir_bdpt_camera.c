/* restir_bdpt_camera.c — ReSTIR BDPT's camera pass (see restir_bdpt_internal.h): each pixel's
 * camera-side candidates and its bucket of light-traced samples resampled into the non-caustic and
 * the caustic reservoir, and the caustic reservoirs' temporal reuse by random replay. */
#include "integrators/restir_bdpt_internal.h"

#include <string.h>

#include "scene/accel.h"

/* ---- camera pass: each pixel's candidates (s = 0, s = 1) and its light-traced bucket -------- */

/* Adds a candidate of contribution C (p̂ = lum(C)) with resampling weight w; `rc` its
 * reconnection (NULL: none). True when it is selected (so far). */
static bool rbdpt_ris_add_rc(struct rbdpt_ris *r, struct vec3 C, double w, uint16_t bits, uint32_t light_path,
                             uint32_t origin_frame, const struct restir_bdpt_rc *rc, struct rng *pick,
                             struct rbdpt_worker *wk)
{
    if (!(w > 0.0)) return false;
    if (!isfinite(w) || !vec3_is_finite(C)) {
        wk->rejected++;
        return false;
    }
    r->wsum += w;
    if ((double)rng_next_float(pick) * r->wsum >= w) return false;
    r->target = vec3_luminance(C);
    r->F = C;
    r->bits = bits;
    r->light_path = light_path;
    r->origin_frame = origin_frame;
    r->lv = NULL;
    if (rc) r->rc = *rc;
    else memset(&r->rc, 0, sizeof r->rc);
    return true;
}

static void rbdpt_ris_add_w(struct rbdpt_ris *r, struct vec3 C, double w, uint16_t bits, uint32_t light_path,
                            uint32_t origin_frame, struct rng *pick, struct rbdpt_worker *wk)
{
    rbdpt_ris_add_rc(r, C, w, bits, light_path, origin_frame, NULL, pick, wk);
}

/* An initial candidate: source pdf 1 in primary sample space, weight p̂ = lum(C). */
static void rbdpt_ris_add(struct rbdpt_ris *r, struct vec3 C, uint16_t bits, uint32_t light_path,
                          uint32_t origin_frame, struct rng *pick, struct rbdpt_worker *wk)
{
    rbdpt_ris_add_w(r, C, vec3_luminance(C), bits, light_path, origin_frame, pick, wk);
}

static void rbdpt_ris_finish(const struct rbdpt_ris *r, uint16_t M, struct restir_bdpt_reservoir *out)
{
    out->head.M = M;
    out->head.bits = r->bits;
    out->head.W = r->target > 0.0f ? (float)(r->wsum / r->target) : 0.0f;
    out->F = r->target > 0.0f ? r->F : vec3_splat(0.0f);
    out->light_path = r->light_path;
    out->origin_frame = r->origin_frame;
}

static void rbdpt_ris_finish_path(const struct rbdpt_ris *r, uint16_t M, struct restir_bdpt_path *out)
{
    rbdpt_ris_finish(r, M, &out->r);
    out->rc = r->rc;
}

/* Offers a camera-side candidate of contribution C and resampling weight w to the reservoir, or
 * hands it to the replay that wants it; true when the replay is settled (found or failed: the
 * path need not be traced further). */
static bool rbdpt_offer(struct rbdpt_ris *r, struct rbdpt_want *want, struct vec3 C, double w, uint16_t bits,
                        const struct restir_bdpt_rc *rc, const struct bdpt_light_vertex *lv, uint32_t pixel,
                        uint32_t frame, struct rng *pick, struct rbdpt_worker *wk)
{
    if (want) {
        if (want->bits != bits) return false;
        want->found = (rc ? rc->k : 0u) == want->k;
        want->C = C;
        if (rc) want->rc = *rc;
        return true;
    }
    wk->candidates++;
    if (rbdpt_ris_add_rc(r, C, w, bits, pixel, frame, rc, pick, wk)) r->lv = lv;
    return false;
}


/* The camera subpath of `pixel`'s stream (its ids: the pixel and frame whose random numbers
 * drive it) traced along `dir` in view v: its s = 0 and s = 1 candidates, and the full variant's
 * connections. With reuse each candidate also gets its reconnection (struct
 * restir_bdpt_rc), and Russian roulette is decoupled from the primary sample space
 * ([ReSTIR PT Enhanced §6]): C leaves the survival probabilities out and they divide the resampling
 * weight instead, so a shift, which keeps the vertices after x_k, never has to roll the roulette
 * again; a replay never ends by roulette. Without reuse no camera-side sample is ever shifted, and
 * C keeps them (the same estimate; the image is then exactly bdpt's). */
void rbdpt_camera_candidates(const struct rbdpt_ctx *c, const struct rbdpt_view *v, struct vec3 dir,
                             uint32_t pixel, uint32_t frame, struct rng *rng, struct rng *pick,
                             struct rbdpt_ris *r, struct ray_counters *rc, struct rbdpt_worker *wk,
                             struct vec3 *primary, bool *has_primary, struct rbdpt_want *want,
                             const struct rbdpt_resume *resume)
{
    *has_primary = false;
    const struct scene *scene = v->scene;
    const struct restir_bdpt_params *p = c->p;
    const struct light_sampler *lights = scene->lights;
    const struct camera *cam = &v->cam;
    const bool track = p->reuse;
    struct vec3 beta = vec3_splat(1.0f);
    double src = 1.0;   /* track: the product of the roulette's survival probabilities so far */
    /* Undoes refraction's radiance scaling for the roulette (reference_pt.c). A resumed suffix
     * starts it at 1: resuming is a replay, and replays play no roulette. */
    float rr_scale = 1.0f;
    float cos0 = resume ? 1.0f : vec3_dot(dir, cam->forward);
    if (!(cos0 > 0.0f)) return;
    struct restir_bdpt_mis mis = restir_bdpt_mis_camera_start(c->n_light, v->plane_dist2 / (cos0 * cos0 * cos0),
                                                                  c->power);
    mis.full = c->full;
    struct vec3 org = cam->position, prev_p = org;
    /* track: the reconnection found so far (rc_k.k = 0: none), dVC after x_k's scattering, the
     * throughput of the scatterings after x_k, and the previous vertex as it was before its
     * scattering (to redo that scattering along the segment to x_k). */
    struct restir_bdpt_rc rc_k = {0};
    struct restir_bdpt_mis suffix = {0.0f, 1.0f, false, false};   /* dVC's factors past x_k's scattering */
    struct restir_bdpt_mis basis[3];   /* full: the states carried from x_k's scattering (rbdpt_suffix_basis) */
    rbdpt_suffix_basis(basis);
    struct vec3 beta_suf = vec3_splat(1.0f);
    struct surface prev_s = {0};
    const struct material *prev_m = NULL;
    struct vec3 prev_wo = {0, 0, 0}, prev_beta = beta;
    struct restir_bdpt_mis prev_mis = mis;
    bool prev_rough = false;
    uint32_t first = 0;
    if (resume) {
        org = resume->org;
        dir = resume->dir;
        prev_p = resume->prev_p;
        beta = resume->beta;
        mis = resume->mis;
        rc_k = resume->rc;
        first = rc_k.k;
    }

    for (uint32_t depth = first;; depth++) {
        /* A replay is over once past the wanted path's length: every candidate made at this
         * depth has at least depth + 1 vertices after the camera. */
        if (want && depth + 1 > (uint32_t)(want->bits >> 8)) return;
        struct hit hit;
        if (!accel_intersect(scene->accel, org, dir, 0.0f, INFINITY, &hit, rc)) break;
        struct surface s;
        surface_from_hit(scene, &hit, org, dir, &s);
        if (depth == 0) {
            *primary = s.p;
            *has_primary = true;
        }
        float cos_hit = vec3_dot(dir, s.ng);
        float hit_d2 = vec3_length2(vec3_sub(s.p, prev_p));
        restir_bdpt_mis_hit(&mis, hit_d2, cos_hit, c->power);
        if (rc_k.k && rc_k.k <= depth) {
            restir_bdpt_mis_hit(&suffix, hit_d2, cos_hit, c->power);
            for (int j = 0; j < 3; j++) restir_bdpt_mis_hit(&basis[j], hit_d2, cos_hit, c->power);
        }
        const struct material *m = &scene->materials[s.material];
        /* Path vertices after the camera of an emitter hit here: depth + 1. With emission_apart
         * the G-buffer pass estimates the primary hit's (rbdpt_emission_apart). */
        if (material_is_emissive(m) && !(depth == 0 && c->emission_apart)) {
            struct vec3 Le = light_sampler_emitted(m, -cos_hit);
            if (!vec3_is_zero(Le)) {
                float w = 1.0f, direct_pdf_a = 0.0f, emission_pdf_w = 0.0f;
                if (depth > 0) {
                    direct_pdf_a = light_sampler_pdf_a(lights, s.shape, s.prim);
                    emission_pdf_w = direct_pdf_a * bdpt_emit_dir_pdf_w(m, cos_hit);
                    w = restir_bdpt_mis_emission(&mis, direct_pdf_a, emission_pdf_w, c->power);
                }
                struct vec3 C = vec3_scale(vec3_mul(beta, Le), w);
                struct restir_bdpt_rc rce = rc_k;
                if (rce.k) {
                    const bool last = rce.k == depth;   /* x_k scattered straight onto this emitter */
                    rce.L = last ? Le : vec3_mul(beta_suf, Le);
                    if (c->full) {   /* restir_bdpt_mis_emission's K */
                        rbdpt_full_constants(basis, 0.0f, rbdpt_mis_f(direct_pdf_a, c->power),
                                             rbdpt_mis_f(emission_pdf_w, c->power), &rce);
                    } else {
                        restir_bdpt_rc_mis_emission(&mis, direct_pdf_a, emission_pdf_w, hit_d2, cos_hit, last,
                                                    suffix.dvc, c->power, &rce.mis_a, &rce.mis_b);
                        rce.mis_c = suffix.caster ? 1.0f : 0.0f;
                    }
                    if (p->copy_mis) rce.L = vec3_scale(rce.L, w);
                }
                if (rbdpt_offer(r, want, C, vec3_luminance(C) / src, (uint16_t)(((depth + 1) << 8) | 0u),
                                track ? &rce : NULL, NULL, pixel, frame, pick, wk))
                    return;
            }
        }
        if (depth >= p->max_depth) break;
        struct vec3 wo_world = vec3_neg(dir);
        const bool rough = track && p->camera_reconnect && rbdpt_rough(m);
        if (rough && prev_rough && rc_k.k == 0) {
            /* x_{depth+1} is x_k: its predecessor's scattering is redone along the segment between
             * the two positions, as a shift evaluates it (the sampled ray left from an offset
             * origin; at grazing angles the two differ by per cents). */
            struct vec3 w = vec3_sub(s.p, prev_s.p);
            float d2 = vec3_length2(w);
            w = vec3_scale(w, 1.0f / sqrtf(d2));
            struct vec3 wi = frame_to_local(&prev_s.frame, w);
            struct vec3 f = material_eval(prev_m, prev_wo, wi, TRANSPORT_RADIANCE);
            float pdf = material_pdf(prev_m, prev_wo, wi);
            float cos_k = vec3_dot(w, s.ng);
            /* Where the segment and the sampled ray disagree this much the path ends: under the
             * reconnection's integrand it carries nothing. */
            if (!(vec3_dot(w, prev_s.ng) * wi.z > 0.0f) || !(pdf > 0.0f) || vec3_is_zero(f) || cos_k == 0.0f ||
                !(d2 > 0.0f))
                break;
            beta = vec3_mul(prev_beta, vec3_scale(f, fabsf(wi.z) / pdf));
            mis = prev_mis;
            restir_bdpt_mis_scatter(&mis, vec3_dot(w, prev_s.ng), pdf, material_pdf(prev_m, wi, prev_wo), false,
                                    c->power);
            restir_bdpt_mis_hit(&mis, d2, cos_k, c->power);
            rc_k.k = depth + 1;
            rc_k.shape = hit.shape;
            rc_k.prim = hit.prim;
            surface_point_code(scene, &hit, &s, &rc_k.b1, &rc_k.b2);
            rc_k.pdf = pdf * fabsf(cos_k) / d2;
            wo_world = vec3_neg(w);
        }
        /* x_{depth+1} is one of the scattering vertices of every path that continues from here
         * (after the hybrid block above, which may start mis again from the previous vertex). */
        rbdpt_mis_vertex(&mis, m);
        if (rc_k.k && rc_k.k <= depth) rbdpt_mis_vertex(&suffix, m);
        struct vec3 wo = frame_to_local(&s.frame, wo_world);
        bool connectable = (material_flags(m) & (BSDF_DIFFUSE | BSDF_GLOSSY)) != 0;
        float ul = rng_next_float(rng), u1 = rng_next_float(rng), u2 = rng_next_float(rng);
        /* The full variant's choice of a cached light vertex (the lightweight one draws none, so
         * its random streams are as before). */
        float uc = c->full ? rng_next_float(rng) : 0.0f;
        if (connectable) {
            struct rbdpt_nee ns;
            if (rbdpt_nee_sample(scene, s.p, ul, u1, u2, &ns)) {
                const struct vec3 wi_world = ns.wi_world, Le = ns.Le;
                const float cos_l = ns.cos_l, direct_pdf_w = ns.direct_pdf_w, emission_pdf_w = ns.emission_pdf_w;
                struct vec3 wi = frame_to_local(&s.frame, wi_world);
                float cos_ng = vec3_dot(wi_world, s.ng);
                if (cos_ng * wi.z > 0.0f) {
                    struct vec3 f = material_eval(m, wo, wi, TRANSPORT_RADIANCE);
                    if (!vec3_is_zero(f) && bdpt_visible(scene->accel, s.p, s.ng, ns.ls.p, &ns.ls.n, rc)) {
                        float fwd = material_pdf(m, wo, wi), rev = material_pdf(m, wi, wo);
                        float w = restir_bdpt_mis_nee(&mis, fwd, rev, direct_pdf_w, emission_pdf_w, cos_ng, cos_l,
                                                      c->power);
                        struct vec3 end = vec3_scale(vec3_mul(f, Le), fabsf(wi.z) / direct_pdf_w);
                        struct vec3 C = vec3_scale(vec3_mul(beta, end), w);
                        struct restir_bdpt_rc rcn = rc_k;
                        if (rcn.k) {
                            const bool last = rcn.k == depth + 1;   /* the light sample leaves x_k itself */
                            if (last) {
                                rcn.L = vec3_scale(Le, 1.0f / direct_pdf_w);
                                surface_oct_encode(wi_world, &rcn.wk_u, &rcn.wk_v);
                            } else {
                                rcn.L = vec3_mul(beta_suf, end);
                            }
                            if (!c->full) {
                                restir_bdpt_rc_mis_nee(fwd, rev, direct_pdf_w, emission_pdf_w, cos_ng, cos_l, last,
                                                       suffix.dvc, c->power, &rcn.mis_a, &rcn.mis_b);
                                rcn.mis_c = suffix.caster ? 1.0f : 0.0f;
                            } else if (!last) {   /* (a light sample leaving x_k is drawn again by a shift) */
                                /* restir_bdpt_mis_nee's K */
                                const float k_cam = rbdpt_mis_f(emission_pdf_w * fabsf(cos_ng) /
                                                                  (direct_pdf_w * fabsf(cos_l)), c->power);
                                rbdpt_full_constants(basis, rbdpt_mis_f(fwd / direct_pdf_w, c->power), k_cam,
                                                     k_cam * rbdpt_mis_f(rev, c->power), &rcn);
                            }
                            if (p->copy_mis) rcn.L = vec3_scale(rcn.L, w);
                        }
                        if (rbdpt_offer(r, want, C, vec3_luminance(C) / src, (uint16_t)(((depth + 2) << 8) | 1u),
                                        track ? &rcn : NULL, NULL, pixel, frame, pick, wk))
                            return;
                    }
                }
            }
            /* s >= 2, t >= 2 (full variant): a connection to one light vertex drawn uniformly from
             * the cache, as bdpt; paths longer than max_depth are cut. Technique s = the light
             * vertex's surface vertices + the emitter's. |LVC| / N_L = 1 / p_L is the choice's part
             * of the unbiased contribution weight ([ReSTIR BDPT eq. 25]): it scales the resampling
             * weight, and the target C stays a function of the path alone, which a shift can
             * evaluate in another frame whose cache is another. A shift's replay joins the
             * sample's own light vertex instead, replayed (rbdpt_shift). */
            const uint32_t t_c = depth + 1;   /* surface vertices on the camera subpath */
            const struct bdpt_light_vertex *lv = NULL;
            uint32_t lv_path = UINT32_MAX;
            if (want) {
                if (want->lv && (uint32_t)(want->bits & 0xffu) == want->lv->depth + 1 &&
                    t_c + want->lv->depth + 1 == (uint32_t)(want->bits >> 8)) {
                    lv = want->lv;
                    lv_path = want->lv_path;
                }
            } else if (c->full && t_c < p->max_depth) {
                lv = bdpt_lvc_pick(&c->lvc, uc);
                if (lv && c->st->lvc_path) lv_path = c->st->lvc_path[lv - c->st->lvc];
            }
            if (lv && t_c + lv->depth <= p->max_depth) {
                bool made;
                const struct bdpt_mis cm = {mis.dvcm, mis.dvc};
                struct bdpt_connect_pdfs cp;
                struct vec3 cv = bdpt_connect_light_vertex(scene, c->power, 1.0f, &s, m, wo, &cm, lv, rc, &made, &cp);
                if (made) {
                    if (wk) wk->connections++;
                    uint32_t vertices = t_c + lv->depth + 1, tech = lv->depth + 1;
                    struct vec3 C = vec3_mul(beta, cv);
                    struct restir_bdpt_rc rcc = rc_k;
                    rcc.light_path = lv_path;
                    if (rcc.k && rcc.k < t_c && cp.w > 0.0f) {
                        /* Past x_k: what w_k carries back, and the suffix's MIS constants. */
                        rcc.L = vec3_mul(beta_suf, vec3_scale(cv, 1.0f / cp.w));
                        /* bdpt_mis_weight_connect's K */
                        const float lf = rbdpt_mis_f(cp.light_fwd_a, c->power);
                        rbdpt_full_constants(basis,
                                             rbdpt_mis_f(cp.cam_fwd_a, c->power) *
                                                 (lv->dvcm + lv->dvc * rbdpt_mis_f(cp.light_rev_w, c->power)),
                                             lf, lf * rbdpt_mis_f(cp.cam_rev_w, c->power), &rcc);
                    }
                    if (rbdpt_offer(r, want, C, vec3_luminance(C) * c->lvc.scale / src,
                                    (uint16_t)((vertices << 8) | tech), track ? &rcc : NULL, lv, pixel, frame, pick,
                                    wk))
                        return;
                }
            }
        }
        struct bsdf_sample bs;
        struct vec3 wi_world;
        float cos_i_ng;
        if (!material_sample_at(m, &s.frame, s.ng, wo, rng, TRANSPORT_RADIANCE, &bs, &wi_world, &cos_i_ng)) break;
        prev_beta = beta;
        prev_mis = mis;
        if (rc_k.k == depth + 1) {
            /* x_k's own scattering, as a shift evaluates it: the whole BSDF and its pdf. */
            struct vec3 f = material_eval(m, wo, bs.wi, TRANSPORT_RADIANCE);
            float pdf = material_pdf(m, wo, bs.wi);
            if (vec3_is_zero(f) || !(pdf > 0.0f)) break;
            beta = vec3_mul(beta, vec3_scale(f, fabsf(bs.wi.z) / pdf));
            restir_bdpt_mis_scatter(&mis, cos_i_ng, pdf, material_pdf(m, bs.wi, wo), false, c->power);
            rc_k.pdf *= pdf;
            surface_oct_encode(wi_world, &rc_k.wk_u, &rc_k.wk_v);
        } else {
            struct vec3 factor = vec3_scale(bs.f, fabsf(bs.wi.z) / bs.pdf_w);
            beta = vec3_mul(beta, factor);
            const bool delta = (bs.flags & BSDF_DELTA) != 0;
            restir_bdpt_mis_scatter(&mis, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, delta, c->power);
            if (rc_k.k) {
                beta_suf = vec3_mul(beta_suf, factor);
                restir_bdpt_mis_scatter(&suffix, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, delta, c->power);
                rbdpt_suffix_scatter(basis, cos_i_ng, bs.pdf_w, bs.pdf_rev_w, delta, c->power);
            }
        }
        if (bs.flags & BSDF_TRANSMISSION) rr_scale /= material_radiance_scale(m, wo, bs.wi);
        float u_rr = rng_next_float(rng);
        if (depth + 1 >= p->rr_depth && !(track && want)) {
            float mx = vec3_max_comp(beta) * rr_scale / (float)src;
            float q = mx < 0.95f ? mx : 0.95f;
            if (!(q > 0.0f) || u_rr >= q) break;
            if (track) src *= q;
            else beta = vec3_scale(beta, 1.0f / q);
        }
        prev_s = s;
        prev_m = m;
        prev_wo = wo;
        prev_rough = rough;
        org = bdpt_origin(&s, wi_world);
        prev_p = s.p;
        dir = wi_world;
    }
}

/* The random-replay shift of a caustic sample (light subpath i of frame origin_frame, vertex
 * `depth`) into view v: its pixel and contribution there. It fails when the replayed subpath
 * ends before that vertex or the eye does not see it there, and when x_2 turned rough (the
 * sample left the caustic domain). Its Jacobian in primary sample space is 1. */
enum rbdpt_replay rbdpt_replay_caustic(const struct rbdpt_ctx *c, const struct rbdpt_view *v,
                                       uint32_t origin_frame, uint32_t i, uint32_t depth, uint32_t *pixel,
                                       struct vec3 *F, struct ray_counters *rc)
{
    struct restir_bdpt_lt_sample out;
    uint32_t stored = 0, dropped = 0;
    rbdpt_trace_light(c, v, origin_frame, i, depth, &out, 1, &stored, &dropped, NULL, NULL, NULL, rc);
    if (stored == 0) return RBDPT_REPLAY_FAILED;
    if (!out.caustic) return RBDPT_REPLAY_NOT_CAUSTIC;
    *pixel = out.pixel;
    *F = out.F;
    return RBDPT_REPLAY_OK;
}

/* Whether this render and the previous one have the same view and parameters (struct
 * restir_bdpt_state's still_from). A caustic sample's F and pixel then come from the same
 * computation in both frames: the light pass and a replay run rbdpt_trace_light on the same
 * random numbers in the same scene and camera, and a caustic sample never takes the hybrid
 * evaluation (its x_2 scattered by a delta lobe, so x_2 is not rough). So the replay of the
 * previous frame's sample into this frame lands in the pixel whose reservoir held it, with
 * that reservoir's F, and the inverse replay of this frame's sample gives back its own pixel
 * and F: the shifts of Appendix A are the identity there, taken without the rays. */
static bool rbdpt_caustic_still(const struct rbdpt_ctx *c)
{
    return c->tick > c->still_from;
}

/* The caustic reservoir's confidence (eq. 27): 1 for this frame's initial samples plus the
 * confidence of the previous caustic reservoir that the primary hit maps to with the previous
 * camera — independent of where caustic samples happen to land. */
static uint16_t rbdpt_caustic_confidence(const struct rbdpt_ctx *c, struct vec3 primary, bool has_primary)
{
    uint32_t M = 1;
    if (c->p->caustic_temporal && c->has_prev && c->st->has_history && has_primary) {
        float px, py;
        const struct camera *pc = &c->view[1].cam;
        if (camera_project(pc, primary, &px, &py) && px >= 0.0f && py >= 0.0f && px < (float)pc->width &&
            py < (float)pc->height) {
            uint32_t v = (uint32_t)py * pc->width + (uint32_t)px;
            if (v < pc->width * pc->height) M += c->st->caustic_prev[v].head.M;
        }
    }
    if (M > c->caustic_cap) M = c->caustic_cap;
    return (uint16_t)M;
}

void rbdpt_camera_tile(void *ctx, uint32_t tile, unsigned worker)
{
    struct rbdpt_ctx *c = ctx;
    struct restir_bdpt_state *st = c->st;
    struct rbdpt_worker *wk = &c->worker[worker];
    struct ray_counters rc = {0, 0};
    uint32_t w = st->width, h = st->height;
    uint32_t x0 = (tile % c->tiles_x) * RBDPT_TILE, y0 = (tile / c->tiles_x) * RBDPT_TILE;
    uint32_t x1 = x0 + RBDPT_TILE < w ? x0 + RBDPT_TILE : w, y1 = y0 + RBDPT_TILE < h ? y0 + RBDPT_TILE : h;
    bool temporal = c->p->caustic_temporal && c->has_prev && st->has_history;
    for (uint32_t y = y0; y < y1; y++) {
        for (uint32_t x = x0; x < x1; x++) {
            uint32_t pixel = y * w + x;
            struct rng rng = rng_make(c->seed, c->frame, RBDPT_CAMERA_STREAM + pixel, 0);
            struct rng pick = rng_make(c->seed, c->frame, RBDPT_PICK_STREAM + pixel, 0);
            float jx, jy;
            rbdpt_jitter(c, c->frame, pixel, &rng, &jx, &jy);
            struct vec3 dir = camera_ray_dir(&c->view[0].cam, (float)x + jx, (float)y + jy);
            struct rbdpt_ris r = {0.0, 0.0f, {0, 0, 0}, 0, UINT32_MAX, 0};
            struct rbdpt_ris rcau = r;
            struct vec3 primary = {0, 0, 0};
            bool has_primary;
            rbdpt_camera_candidates(c, &c->view[0], dir, pixel, c->frame, &rng, &pick, &r, &rc, wk, &primary,
                                    &has_primary, NULL, NULL);
            /* The pixel's bucket of light-traced samples (eq. 26: C carries 1/N_L). */
            struct surface xg;
            int xg_state = 0;   /* reject_unshiftable: the primary hit, traced when first needed (1: hit, -1: none) */
            for (uint32_t k = st->pixel_first[pixel]; k < st->pixel_first[pixel + 1]; k++) {
                const struct restir_bdpt_lt_sample *ls = &st->lt_sorted[k];
                uint16_t bits = (uint16_t)(((uint32_t)(ls->depth + 1) << 8) | RESTIR_BDPT_TECH_LT);
                if (c->p->reject_unshiftable && !ls->caustic) {
                    if (xg_state == 0) {
                        struct hit hit;
                        xg_state = -1;
                        if (accel_intersect(c->view[0].scene->accel, c->view[0].cam.position, dir, 0.0f, INFINITY,
                                            &hit, &rc)) {
                            surface_from_hit(c->view[0].scene, &hit, c->view[0].cam.position, dir, &xg);
                            xg_state = 1;
                        }
                    }
                    if (xg_state < 0 || !rbdpt_reaches_primary(c, &c->view[0], c->frame, ls->light_path, ls->depth,
                                                               &xg, &rc)) {
                        wk->unshiftable++;
                        continue;
                    }
                }
                if (ls->hybrid && !ls->caustic) {
                    /* Marks the reverse hybrid shift's class; the record is filled in once selected. */
                    const struct restir_bdpt_rc mark = {.k = 1};
                    rbdpt_ris_add_rc(&r, ls->F, vec3_luminance(ls->F), bits, ls->light_path, c->frame, &mark, &pick,
                                     wk);
                } else {
                    rbdpt_ris_add(ls->caustic ? &rcau : &r, ls->F, bits, ls->light_path, c->frame, &pick, wk);
                }
            }
            rbdpt_ris_finish_path(&r, 1, &st->res[pixel]);
            if (st->res[pixel].rc.k == 1 && st->res[pixel].r.head.W > 0.0f &&
                !rbdpt_reverse_record(c, pixel, &st->res[pixel], &rc))
                st->res[pixel].rc.pdf = 0.0f;
            /* A connection drawn in this frame joins a vertex of this frame's cache: the one its
             * replay gives back. */
            if (st->x2c && r.lv && rbdpt_is_connection(&st->res[pixel]) && st->res[pixel].r.head.W > 0.0f)
                rbdpt_light_vertex_keep(c, pixel, &st->res[pixel], r.lv);
            uint16_t M = rbdpt_caustic_confidence(c, primary, has_primary);
            if (temporal) {
                /* Appendix A: the initial caustic reservoir (confidence 1) against the previous
                 * frame's reservoirs whose replayed samples landed here. */
                struct rbdpt_ris merged = {0.0, 0.0f, {0, 0, 0}, 0, UINT32_MAX, 0};
                if (rcau.target > 0.0f) {
                    /* eq. 52: the inverse shift of the initial sample into the previous frame. */
                    uint32_t v;
                    struct vec3 Fp;
                    double denom = rcau.target;
                    wk->shifts++;
                    if (rbdpt_caustic_still(c)) {
                        v = pixel;
                        Fp = rcau.F;
                    }
                    if (rbdpt_caustic_still(c) ||
                        rbdpt_replay_caustic(c, &c->view[1], rcau.origin_frame, rcau.light_path,
                                             (uint32_t)(rcau.bits >> 8) - 1u, &v, &Fp, &rc) == RBDPT_REPLAY_OK) {
                        denom += (double)st->caustic_prev[v].head.M * vec3_luminance(Fp);
                    } else {
                        wk->inverse_failed++;
                    }
                    double m = rcau.target / denom;
                    rbdpt_ris_add_w(&merged, rcau.F, m * rcau.wsum, rcau.bits, rcau.light_path, rcau.origin_frame,
                                    &pick, wk);
                }
                for (uint32_t k = st->shift_first[pixel]; k < st->shift_first[pixel + 1]; k++) {
                    const struct restir_bdpt_shifted *sh = &st->shifted_sorted[k];
                    uint16_t bits = (uint16_t)(((uint32_t)(sh->depth + 1) << 8) | RESTIR_BDPT_TECH_LT);
                    rbdpt_ris_add_w(&merged, sh->F, sh->w, bits, sh->light_path, sh->origin_frame, &pick, wk);
                }
                rbdpt_ris_finish(&merged, M, &st->caustic[pixel]);
            } else {
                rbdpt_ris_finish(&rcau, M, &st->caustic[pixel]);
            }
            /* With reuse the non-caustic estimate is added after the reuse passes. */
            struct vec3 L = vec3_scale(st->caustic[pixel].F, st->caustic[pixel].head.W);
            if (!c->p->reuse) L = vec3_add(L, vec3_scale(st->res[pixel].r.F, st->res[pixel].r.head.W));
            c->out->pixels[pixel] = L;
        }
    }
    wk->rays_intersect += rc.intersect;
    wk->rays_occluded += rc.occluded;
}

/* The previous frame's caustic reservoirs, each replayed into the current frame (eq. 51): one
 * job per row of source pixels, each writing only its own slots. */
void rbdpt_history_row(void *ctx, uint32_t row, unsigned worker)
{
    struct rbdpt_ctx *c = ctx;
    struct restir_bdpt_state *st = c->st;
    struct rbdpt_worker *wk = &c->worker[worker];
    struct ray_counters rc = {0, 0};
    for (uint32_t x = 0; x < st->width; x++) {
        uint32_t v = row * st->width + x;
        const struct restir_bdpt_reservoir *prev = &st->caustic_prev[v];
        struct restir_bdpt_shifted *sh = &st->shifted[v];
        sh->valid = 0;
        float p_prev = vec3_luminance(prev->F);
        if (!(prev->head.W > 0.0f) || !(p_prev > 0.0f)) continue;
        wk->shifts++;
        uint32_t depth = (uint32_t)(prev->head.bits >> 8) - 1u;
        uint32_t q = v;
        struct vec3 F = prev->F;
        enum rbdpt_replay res = rbdpt_caustic_still(c) ? RBDPT_REPLAY_OK
                                                       : rbdpt_replay_caustic(c, &c->view[0], prev->origin_frame,
                                                                              prev->light_path, depth, &q, &F, &rc);
        if (res != RBDPT_REPLAY_OK) {
            if (res == RBDPT_REPLAY_FAILED) wk->replay_failed++; else wk->not_caustic++;
            continue;
        }
        float p_cur = vec3_luminance(F);
        if (!(p_cur > 0.0f)) {
            wk->replay_failed++;
            continue;
        }
        /* eq. 51 with |dT/dX| = 1 (random replay) and the initial sample's confidence 1. */
        double mp = (double)prev->head.M * p_prev;
        double m = mp / (mp + p_cur);
        *sh = (struct restir_bdpt_shifted){.F = F, .w = (float)(m * p_cur * prev->head.W), .pixel = q,
                                           .light_path = prev->light_path, .origin_frame = prev->origin_frame,
                                           .depth = (uint16_t)depth, .valid = 1};
    }
    wk->rays_intersect += rc.intersect;
    wk->rays_occluded += rc.occluded;
}
