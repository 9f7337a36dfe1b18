/* light_ris.c — RIS next-event estimation (see light_ris.h). */
#include "scene/light_ris.h"

#include <math.h>

#include "reuse/reservoir.h"
#include "core/sampling.h"

/* One light candidate evaluated at the shading point; false when it cannot contribute. */
static bool light_ris_candidate(const struct scene *scene, const struct surface *s, const struct material *m,
                                struct vec3 wo, struct rng *rng, struct light_ris_sample *c)
{
    float ul = rng_next_float(rng), u1 = rng_next_float(rng), u2 = rng_next_float(rng);
    struct light_sample ls;
    if (!light_sampler_sample(scene->lights, ul, u1, u2, &ls)) return false;
    c->light = ls;
    if (ls.is_env) {
        c->wi_world = ls.dir;
        c->dist = INFINITY;
        c->pdf_light_w = ls.pdf_w;
        c->Le = scene->env_radiance;
    } else {
        struct vec3 d = vec3_sub(ls.p, s->p);
        float d2 = vec3_length2(d);
        if (!(d2 > 0.0f)) return false;
        c->dist = sqrtf(d2);
        c->wi_world = vec3_scale(d, 1.0f / c->dist);
        float cos_l = -vec3_dot(c->wi_world, ls.n);
        c->Le = light_sampler_emitted(ls.material, cos_l);
        c->pdf_light_w = sampling_area_to_solid_angle(ls.pdf_a, d2, cos_l);
    }
    if (!(c->pdf_light_w > 0.0f) || vec3_is_zero(c->Le)) return false;
    struct vec3 wi = frame_to_local(&s->frame, c->wi_world);
    /* Same side of the geometric and the shading normal, as in reference_pt.c. */
    if (!(vec3_dot(c->wi_world, s->ng) * wi.z > 0.0f)) return false;
    c->f_cos = vec3_scale(material_eval(m, wo, wi, TRANSPORT_RADIANCE), fabsf(wi.z));
    return !vec3_is_zero(c->f_cos);
}

bool light_ris_sample(const struct scene *scene, const struct surface *s, const struct material *m, struct vec3 wo,
                      uint32_t M, struct rng *rng, struct light_ris_sample *out, unsigned *rejected)
{
    if (M == 0 || light_sampler_count(scene->lights) == 0) return false;
    struct reservoir_stream rs;
    reservoir_stream_begin(&rs);
    const double inv_m = 1.0 / (double)M;
    for (uint32_t i = 0; i < M; i++) {
        struct light_ris_sample c;
        /* A candidate that cannot contribute is a null sample: it still counts in M (through
         * the 1/M in every weight), it just cannot be selected. */
        if (!light_ris_candidate(scene, s, m, wo, rng, &c)) {
            rng_next_float(rng);  /* keep the stream aligned: every candidate uses 4 numbers */
            continue;
        }
        float target = vec3_luminance(vec3_mul(c.f_cos, c.Le));
        double w = inv_m * (double)target / (double)c.pdf_light_w;
        if (reservoir_stream_offer(&rs, w, target, 1.0f, rng_next_float(rng))) *out = c;
    }
    if (rejected) *rejected += rs.rejected;
    struct reservoir r = reservoir_stream_finish(&rs);
    if (!(r.W > 0.0f)) return false;
    out->W = r.W;
    return true;
}
