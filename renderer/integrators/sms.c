/* sms.c — specular manifold sampling inside the path tracer (see sms.h).
 * Refs: Zeltner et al. 2020 §4-5 (seeds, Bernoulli trials for 1/P); [SMS-SSP §3.1 eqs. 1-2],
 * §5.2 eqs. 12-13 (the integrand over light points); Booth 2007 (unbiased reciprocal). */
#include "integrators/sms.h"

#include <math.h>
#include <time.h>

#include "scene/light_sampler.h"
#include "material/microfacet.h"
#include "scene/scene.h"

struct sms_params sms_defaults(void)
{
    return (struct sms_params){.bernoulli_cap = 128, .max_iterations = MANIFOLD_MAX_ITERATIONS, .caustics_only = false};
}

bool sms_params_valid(const struct sms_params *p, struct err *err)
{
    if (p->max_iterations < 1 || p->max_iterations > 100)
        return err_set(err, ERR_INVALID, "max_iterations", "max_iterations must be in [1, 100], got %u", p->max_iterations);
    if (p->bernoulli_cap > SMS_HARD_TRIAL_LIMIT)
        return err_set(err, ERR_INVALID, "bernoulli_cap", "bernoulli_cap must be at most %u (0 = uncapped), got %u",
                       SMS_HARD_TRIAL_LIMIT, p->bernoulli_cap);
    return true;
}

bool sms_chain_of(const struct scene *scene, uint32_t shape, struct manifold_chain *out)
{
    const struct shape *s = &scene->shapes[shape];
    if (!s->caustic_caster || s->caustic_interfaces == 0 || s->caustic_interfaces > MANIFOLD_MAX_CHAIN) return false;
    const struct material *m = &scene->materials[s->material];
    if (!microfacet_is_delta(m->roughness)) return false;
    enum manifold_event ev;
    if (m->kind == MATERIAL_CONDUCTOR && s->caustic_interfaces == 1) ev = MANIFOLD_REFLECT;
    else if (m->kind == MATERIAL_DIELECTRIC) ev = MANIFOLD_REFRACT;
    else return false;
    out->shape = shape;
    out->length = s->caustic_interfaces;
    for (uint32_t i = 0; i < MANIFOLD_MAX_CHAIN; i++) out->events[i] = ev;
    out->ior = m->kind == MATERIAL_DIELECTRIC ? m->ior : 1.0f;
    return true;
}

bool sms_scene_init(const struct scene *scene, struct sms_scene *out, struct err *err)
{
    out->count = 0;
    for (uint32_t i = 0; i < scene->shape_count; i++) {
        struct manifold_chain ch;
        if (!sms_chain_of(scene, i, &ch)) continue;
        if (out->count == SMS_MAX_CASTERS)
            return err_set(err, ERR_LIMIT, NULL, "more than %d caustic casters", SMS_MAX_CASTERS);
        struct sms_caster *c = &out->casters[out->count++];
        const struct shape *s = &scene->shapes[i];
        const struct xform *xf = accel_shape_to_world(scene->accel, i);
        c->chain = ch;
        c->sphere = s->kind == SHAPE_SPHERE;
        if (c->sphere) {
            c->centre = xform_point(xf, s->center);
            c->radius = s->radius * vec3_length(xform_vector(xf, vec3_make(1, 0, 0)));
            continue;
        }
        c->lo = vec3_splat(INFINITY);
        c->hi = vec3_splat(-INFINITY);
        for (uint32_t v = 0; v < s->vertex_count; v++) {
            struct vec3 p = xform_point(xf, s->positions[v]);
            c->lo = vec3_make(fminf(c->lo.x, p.x), fminf(c->lo.y, p.y), fminf(c->lo.z, p.z));
            c->hi = vec3_make(fmaxf(c->hi.x, p.x), fmaxf(c->hi.y, p.y), fmaxf(c->hi.z, p.z));
        }
        /* A flat caster still gets a box with volume, so every face has area. */
        struct vec3 ext = vec3_sub(c->hi, c->lo);
        float pad = 1e-3f * fmaxf(ext.x, fmaxf(ext.y, ext.z));
        c->lo = vec3_sub(c->lo, vec3_splat(pad));
        c->hi = vec3_add(c->hi, vec3_splat(pad));
        ext = vec3_sub(c->hi, c->lo);
        float a[3] = {ext.y * ext.z, ext.x * ext.z, ext.x * ext.y}, sum = 2.0f * (a[0] + a[1] + a[2]), acc = 0.0f;
        for (int f = 0; f < 6; f++) {
            acc += a[f / 2];
            c->face_cdf[f] = acc / sum;
        }
        c->face_cdf[5] = 1.0f;
    }
    return true;
}

static void sms_set_comp(struct vec3 *v, int a, float x)
{
    if (a == 0) v->x = x;
    else if (a == 1) v->y = x;
    else v->z = x;
}

struct vec3 sms_seed_point(const struct sms_caster *c, float u1, float u2)
{
    if (c->sphere) {
        float z = 1.0f - 2.0f * u1, r = sqrtf(fmaxf(0.0f, 1.0f - z * z)), phi = 2.0f * PI_F * u2;
        return vec3_madd(c->centre, vec3_make(r * cosf(phi), r * sinf(phi), z), c->radius);
    }
    /* u1 picks a face in proportion to its area and, rescaled, is the first face coordinate. */
    int f = 0;
    while (f < 5 && u1 >= c->face_cdf[f]) f++;
    float f0 = f ? c->face_cdf[f - 1] : 0.0f, t = (u1 - f0) / (c->face_cdf[f] - f0);
    t = fminf(fmaxf(t, 0.0f), 1.0f);
    int axis = f / 2, a0 = axis == 0 ? 1 : 0, a1 = axis == 2 ? 1 : 2;
    struct vec3 p;
    sms_set_comp(&p, axis, vec3_comp(f & 1 ? c->hi : c->lo, axis));
    sms_set_comp(&p, a0, vec3_comp(c->lo, a0) + t * (vec3_comp(c->hi, a0) - vec3_comp(c->lo, a0)));
    sms_set_comp(&p, a1, vec3_comp(c->lo, a1) + u2 * (vec3_comp(c->hi, a1) - vec3_comp(c->lo, a1)));
    return p;
}

void sms_track_scatter(const struct scene *scene, struct sms_track *t, const struct surface *s, unsigned flags)
{
    if (!(flags & BSDF_DELTA)) {
        *t = (struct sms_track){true, -1, 0};
        return;
    }
    if (!t->open) return;
    struct manifold_chain ch;
    bool fits = (t->shape < 0 || (uint32_t)t->shape == s->shape) && sms_chain_of(scene, s->shape, &ch) &&
                t->length < ch.length &&
                ((ch.events[t->length] == MANIFOLD_REFLECT) == ((flags & BSDF_REFLECTION) != 0));
    if (!fits) {
        t->open = false;
        return;
    }
    t->shape = (int32_t)s->shape;
    t->length++;
}

bool sms_track_owned(const struct scene *scene, const struct sms_track *t)
{
    if (!t->open || t->shape < 0) return false;
    return t->length == scene->shapes[t->shape].caustic_interfaces;
}

/* One walk from a fresh seed: true when it reaches a solution (not checked against the scene:
 * a Bernoulli trial only asks whether the same solution is reached). */
static bool sms_walk_seed(const struct scene *scene, const struct sms_caster *c, const struct manifold_ends *e,
                          const struct sms_params *p, float u1, float u2, struct manifold_vertex *v,
                          uint64_t *newton, struct ray_counters *rc)
{
    if (!manifold_seed_path(scene, &c->chain, e, sms_seed_point(c, u1, u2), v, rc)) return false;
    struct manifold_stats st = {0};
    bool ok = manifold_walk(scene, &c->chain, e, v, p->max_iterations, &st, rc);
    *newton += st.iterations;
    return ok;
}

struct vec3 sms_solution_value(const struct scene *scene, const struct manifold_chain *chain,
                               const struct manifold_ends *e, const struct manifold_vertex *v, const struct surface *s,
                               const struct material *m, struct vec3 wo, const struct material *light)
{
    const struct vec3 zero = vec3_splat(0.0f);
    /* x1's side of the path, with path tracing's rules (NEE's): same side of both normals. */
    struct vec3 w1 = vec3_normalize(vec3_sub(v[0].p, s->p));
    struct vec3 wi = frame_to_local(&s->frame, w1);
    if (!(vec3_dot(w1, s->ng) * wi.z > 0.0f)) return zero;
    struct vec3 f = material_eval(m, wo, wi, TRANSPORT_RADIANCE);
    const struct manifold_vertex *last = &v[chain->length - 1];
    struct vec3 Le = light_sampler_emitted(light, vec3_dot(vec3_normalize(vec3_sub(last->p, e->xe)), e->nge));
    if (vec3_is_zero(f) || vec3_is_zero(Le)) return zero;
    struct vec3 T = manifold_throughput(scene, chain, e, v);
    double G = manifold_geometry(scene, chain, e, v);
    if (vec3_is_zero(T) || !(G > 0.0)) return zero;
    return vec3_scale(vec3_mul(vec3_mul(f, T), Le), fabsf(wi.z) * (float)G);
}

bool sms_canonical_lobe(const struct material *m, struct vec3 wo, struct bsdf_sample *out)
{
    if (!(material_flags(m) & BSDF_DELTA) || (material_flags(m) & (BSDF_DIFFUSE | BSDF_GLOSSY))) return false;
    /* The largest float below 1: the last lobe in material_sample's order that has any weight. */
    return material_sample(m, wo, 0x1.fffffep-1f, 0.5f, 0.5f, TRANSPORT_RADIANCE, out) && (out->flags & BSDF_DELTA);
}

bool sms_receiver_trace(const struct scene *scene, uint32_t max_depth, struct vec3 org, struct vec3 dir,
                        const struct hit *primary, struct hit *hit, struct surface *s, struct vec3 *wo,
                        struct vec3 *T, uint32_t *depth, struct ray_counters *rc)
{
    *T = vec3_splat(1.0f);
    for (uint32_t d = 0; d < max_depth && d <= SMS_RECEIVER_MAX_PREFIX; d++) {
        if (d == 0)
            *hit = *primary;
        else if (!accel_intersect(scene->accel, org, dir, 0.0f, INFINITY, hit, rc))
            return false;
        surface_from_hit(scene, hit, org, dir, s);
        const struct material *m = &scene->materials[s->material];
        struct vec3 wo_world = vec3_neg(dir);
        if (material_flags(m) & (BSDF_DIFFUSE | BSDF_GLOSSY)) {
            *wo = wo_world;
            *depth = d;
            return m->kind != MATERIAL_TRANSLUCENT;
        }
        struct bsdf_sample bs;
        if (!sms_canonical_lobe(m, frame_to_local(&s->frame, wo_world), &bs)) return false;
        struct vec3 wi_world = frame_to_world(&s->frame, bs.wi);
        float cos_ng = vec3_dot(wi_world, s->ng);
        if (cos_ng * bs.wi.z <= 0.0f) return false;
        /* Path tracing's weight f |cos| / pdf times the probability pdf of taking this lobe. */
        *T = vec3_scale(vec3_mul(*T, bs.f), fabsf(bs.wi.z));
        org = surface_offset_along(s->p, cos_ng < 0.0f ? vec3_neg(s->ng) : s->ng);
        dir = wi_world;
    }
    return false;
}

double sms_now_ms(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec * 1e3 + (double)t.tv_nsec * 1e-6;
}

/* A Bernoulli trial of sms_sample: a uniform seed of the caster's seed map, walked. */
struct sms_trial {
    const struct scene *scene;
    const struct sms_caster *cs;
    const struct manifold_ends *e;
    const struct sms_params *p;
};

static bool sms_trial(const void *ctx, struct rng *rng, struct manifold_vertex *w, struct sms_counters *c,
                      struct ray_counters *rc)
{
    const struct sms_trial *t = ctx;
    float a = rng_next_float(rng), b = rng_next_float(rng);
    return sms_walk_seed(t->scene, t->cs, t->e, t->p, a, b, w, &c->newton_trials, rc);
}

bool sms_draw_begin(const struct scene *scene, const struct sms_scene *ss, float uc, float ul, float l1, float l2,
                    uint32_t max_chain, const struct surface *s, struct sms_counters *c, struct sms_draw *d)
{
    d->t0 = sms_now_ms();
    c->samples++;
    const bool picked = sms_pick(scene, ss, uc, ul, l1, l2, max_chain, &d->ci, &d->ls);
    d->cs = &ss->casters[d->ci];
    if (!picked) return false;
    d->e = (struct manifold_ends){.x1 = s->p, .ng1 = s->ng, .xe = d->ls.p, .nge = d->ls.n};
    return true;
}

bool sms_sample(const struct scene *scene, const struct sms_scene *ss, const struct sms_params *p,
                const struct surface *s, const struct material *m, struct vec3 wo, uint32_t max_chain,
                struct rng *rng, struct sms_solution *out, struct sms_counters *c, struct ray_counters *rc)
{
    out->W = 0.0;
    float uc = rng_next_float(rng), ul = rng_next_float(rng), l1 = rng_next_float(rng), l2 = rng_next_float(rng);
    float s1 = rng_next_float(rng), s2 = rng_next_float(rng);
    if (ss->count == 0) return false;
    struct sms_draw d;
    if (!sms_draw_begin(scene, ss, uc, ul, l1, l2, max_chain, s, c, &d)) goto out;
    struct manifold_vertex *v = out->v;
    if (!sms_walk_seed(scene, d.cs, &d.e, p, s1, s2, v, &c->newton_sample, rc) ||
        !manifold_check(scene, &d.cs->chain, &d.e, v, rc))
        goto out;
    struct vec3 value = sms_solution_value(scene, &d.cs->chain, &d.e, v, s, m, wo, d.ls.material);
    if (vec3_is_zero(value)) goto out;
    /* Bernoulli trials: the number of fresh seeds until one walks to this solution again has
     * expectation 1 / P(x̄*) ([SMS-SSP §3.1]). */
    const struct sms_trial trial = {scene, d.cs, &d.e, p};
    uint32_t trials = sms_bernoulli(p, v, d.cs->chain.length, s->p, sms_trial, &trial, rng, c, rc);
    if (!trials) goto out;
    sms_draw_keep(&d, value, out);
    /* The float product the estimate has always used (its images stay bit-identical). */
    out->W = (double)((float)trials * (float)ss->count / d.ls.pdf_a);
out:
    return sms_draw_end(&d, out, c);
}

struct vec3 sms_estimate(const struct scene *scene, const struct sms_scene *ss, const struct sms_params *p,
                         const struct surface *s, const struct material *m, struct vec3 wo, uint32_t max_chain,
                         struct rng *rng, struct sms_counters *c, struct ray_counters *rc)
{
    struct sms_solution sol;
    if (!sms_sample(scene, ss, p, s, m, wo, max_chain, rng, &sol, c, rc)) return vec3_splat(0.0f);
    return vec3_scale(sol.value, (float)sol.W);
}
