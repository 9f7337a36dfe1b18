/* bssrdf.c — Burley's normalized diffusion, its radius sampling, the probe-ray construction and
 * the 9-technique MIS pdf of BSSRDF importance sampling (see bssrdf.h for the model).
 * Must not trace rays (callers do, through accel.h) nor allocate.
 * Refs: [ReSTIR SSS §2.1 eqs. 2–4, §3.1 eq. 10, Algorithm 4]; Christensen 2015 (profile, scaling);
 * King et al. 2013 (axis/channel MIS). */
#include "material/bssrdf.h"

#include <math.h>

#include "material/fresnel.h"

float bssrdf_scaling(float albedo)
{
    float t = albedo - 0.8f;
    return 1.9f - albedo + 3.5f * t * t;
}

float bssrdf_fresnel_norm(float eta)
{
    /* c = (1/pi) * integral over the hemisphere of (1 - F(cos)) cos = 1 - 2 int_0^1 F(mu) mu dmu,
     * midpoint rule on 4096 intervals (F is smooth except at mu = 0, where mu F -> 0). */
    const int n = 4096;
    double sum = 0.0;
    for (int i = 0; i < n; i++) {
        double mu = (i + 0.5) / n;
        sum += (double)fresnel_dielectric((float)mu, eta) * mu;
    }
    return (float)(1.0 - 2.0 * sum / n);
}

void bssrdf_prepare(struct material *m)
{
    m->sss_d = vec3_make(m->mfp.x / bssrdf_scaling(m->albedo.x), m->mfp.y / bssrdf_scaling(m->albedo.y),
                         m->mfp.z / bssrdf_scaling(m->albedo.z));
    m->sss_r_max = vec3_make(bssrdf_r_max(m->sss_d.x), bssrdf_r_max(m->sss_d.y), bssrdf_r_max(m->sss_d.z));
    m->sss_c = bssrdf_fresnel_norm(m->ior);
}

/* Both exponentials from one: e^{-r/d} = (e^{-r/3d})^3. The 9-technique pdf evaluates the
 * profile ten times per path, and expf was a third of a ReSTIR SSS shift. */
float bssrdf_profile_pdf(float r, float d)
{
    if (!(r > 0.0f)) return 0.0f;
    float t = expf(-r / (3.0f * d));
    return (t * t * t + t) / (8.0f * PI_F * d * r);
}

float bssrdf_profile_cdf(float r, float d)
{
    if (!(r > 0.0f)) return 0.0f;
    float t = expf(-r / (3.0f * d));
    return 1.0f - 0.25f * t * t * t - 0.75f * t;
}

float bssrdf_profile_sample(float u, float d)
{
    /* With x = e^{-r/3d}: 1 - u = x^3/4 + 3x/4, i.e. x^3 + 3x - 4g = 0 (g = 1 - u), a depressed
     * cubic with one real root. Cardano: x = A - 1/A with A = cbrt(2g + sqrt(4g^2 + 1)) (the two
     * cube roots multiply to -1). In double: for g -> 0, A - 1/A cancels to ~4g/3. */
    double g = 1.0 - (double)u;
    if (!(g > 0.0)) return INFINITY;
    double a = cbrt(2.0 * g + sqrt(4.0 * g * g + 1.0));
    double x = a - 1.0 / a;
    if (!(x > 0.0)) return INFINITY;
    if (x >= 1.0) return 0.0f;
    return (float)(-3.0 * (double)d * log(x));
}

float bssrdf_r_max(float d) { return bssrdf_profile_sample(BSSRDF_CDF_MAX, d); }

struct vec3 bssrdf_profile(const struct material *m, float r)
{
    float out[3];
    for (int k = 0; k < 3; k++) {
        float d = vec3_comp(m->sss_d, k);
        out[k] = r < vec3_comp(m->sss_r_max, k) ? vec3_comp(m->albedo, k) * bssrdf_profile_pdf(r, d) / BSSRDF_CDF_MAX : 0.0f;
    }
    return vec3_make(out[0], out[1], out[2]);
}

float bssrdf_transmittance(const struct material *m, float cos_out)
{
    if (!(cos_out > 0.0f)) return 0.0f;
    return 1.0f - fresnel_dielectric(cos_out, m->ior);
}

float bssrdf_entry_eval(const struct material *m, float cos_in)
{
    return bssrdf_transmittance(m, cos_in) / (m->sss_c * PI_F);
}

static const float bssrdf_axis_prob[BSSRDF_AXES] = {0.5f, 0.25f, 0.25f};

void bssrdf_pick_technique(float u, int *axis, int *channel)
{
    float v;
    if (u < 0.5f) {
        *axis = 0;
        v = u * 2.0f;
    } else if (u < 0.75f) {
        *axis = 1;
        v = (u - 0.5f) * 4.0f;
    } else {
        *axis = 2;
        v = (u - 0.75f) * 4.0f;
    }
    int c = (int)(v * 3.0f);
    *channel = c < 0 ? 0 : (c > 2 ? 2 : c);
}

float bssrdf_technique_prob(int axis, int channel)
{
    (void)channel;
    return bssrdf_axis_prob[axis] * (1.0f / 3.0f);
}

void bssrdf_axis_basis(const struct frame *f, int axis, struct vec3 *a, struct vec3 *du, struct vec3 *dv)
{
    /* Cyclic, so every basis is right-handed: (s, t, n), (t, n, s), (n, s, t). */
    if (axis == 0) {
        *a = f->n, *du = f->s, *dv = f->t;
    } else if (axis == 1) {
        *a = f->s, *du = f->t, *dv = f->n;
    } else {
        *a = f->t, *du = f->n, *dv = f->s;
    }
}

bool bssrdf_probe_make(const struct material *m, struct vec3 p1, const struct frame *f1, int axis, int channel,
                       float u_radius, float u_angle, struct bssrdf_probe *out)
{
    float d = vec3_comp(m->sss_d, channel);
    float r_max = vec3_comp(m->sss_r_max, channel);
    float r = bssrdf_profile_sample(u_radius * BSSRDF_CDF_MAX, d);
    if (!(r < r_max)) return false;
    struct vec3 a, du, dv;
    bssrdf_axis_basis(f1, axis, &a, &du, &dv);
    float phi = 2.0f * PI_F * u_angle;
    struct vec3 q = vec3_add(p1, vec3_add(vec3_scale(du, r * cosf(phi)), vec3_scale(dv, r * sinf(phi))));
    float h = sqrtf(r_max * r_max - r * r);
    if (!(h > 0.0f)) return false;
    out->org = vec3_madd(q, a, h);
    out->dir = vec3_neg(a);
    out->tmax = 2.0f * h;
    out->r = r;
    return true;
}

/* x2 - x1 = l seen along one axis: its radius in the disk plane and |cos| of n2 with the axis. */
static void bssrdf_axis_project(const struct frame *f1, int axis, struct vec3 l, struct vec3 n2, float *r, float *cos_a)
{
    struct vec3 a, du, dv;
    bssrdf_axis_basis(f1, axis, &a, &du, &dv);
    float lu = vec3_dot(l, du), lv = vec3_dot(l, dv);
    *r = sqrtf(lu * lu + lv * lv);
    *cos_a = fabsf(vec3_dot(n2, a));
}

/* One technique's density from the projection (the same operations whichever caller). */
static float bssrdf_technique_density(const struct material *m, int channel, float l2, float r, float cos_a)
{
    float d = vec3_comp(m->sss_d, channel);
    float r_max = vec3_comp(m->sss_r_max, channel);
    if (!(l2 < r_max * r_max)) return 0.0f;
    /* p ~ 1/r at the centre: a hit exactly on the axis has probability 0 but must not give inf. */
    return bssrdf_profile_pdf(fmaxf(r, 1e-6f * d), d) / BSSRDF_CDF_MAX * cos_a;
}

float bssrdf_pdf_technique(const struct material *m, struct vec3 p1, const struct frame *f1, int axis, int channel,
                           struct vec3 p2, struct vec3 n2)
{
    struct vec3 l = vec3_sub(p2, p1);
    float r, cos_a;
    bssrdf_axis_project(f1, axis, l, n2, &r, &cos_a);
    return bssrdf_technique_density(m, channel, vec3_length2(l), r, cos_a);
}

float bssrdf_pdf_a_and(const struct material *m, struct vec3 p1, const struct frame *f1, struct vec3 p2, struct vec3 n2,
                       int axis, int channel, float *pdf_t)
{
    /* The three channels of an axis share its projection. */
    struct vec3 l = vec3_sub(p2, p1);
    const float l2 = vec3_length2(l);
    float sum = 0.0f;
    for (int a = 0; a < BSSRDF_AXES; a++) {
        float r, cos_a;
        bssrdf_axis_project(f1, a, l, n2, &r, &cos_a);
        for (int ch = 0; ch < BSSRDF_CHANNELS; ch++) {
            float p = bssrdf_technique_prob(a, ch) * bssrdf_technique_density(m, ch, l2, r, cos_a);
            if (a == axis && ch == channel) *pdf_t = p;
            sum += p;
        }
    }
    return sum;
}

float bssrdf_pdf_a(const struct material *m, struct vec3 p1, const struct frame *f1, struct vec3 p2, struct vec3 n2)
{
    return bssrdf_pdf_a_and(m, p1, f1, p2, n2, -1, -1, NULL);
}

bool bssrdf_invert(const struct material *m, struct vec3 p1, const struct frame *f1, int axis, int channel,
                   struct vec3 p2, float *u_radius, float *u_angle)
{
    float d = vec3_comp(m->sss_d, channel);
    float r_max = vec3_comp(m->sss_r_max, channel);
    struct vec3 l = vec3_sub(p2, p1);
    if (!(vec3_length2(l) < r_max * r_max)) return false;
    struct vec3 a, du, dv;
    bssrdf_axis_basis(f1, axis, &a, &du, &dv);
    float lu = vec3_dot(l, du), lv = vec3_dot(l, dv);
    float r = sqrtf(lu * lu + lv * lv);
    if (!(r > 0.0f)) return false;
    float ur = bssrdf_profile_cdf(r, d) / BSSRDF_CDF_MAX;
    float phi = atan2f(lv, lu);
    if (phi < 0.0f) phi += 2.0f * PI_F;
    float ua = phi / (2.0f * PI_F);
    if (!(ur < 1.0f) || !(ua < 1.0f)) return false;
    *u_radius = ur;
    *u_angle = ua;
    return true;
}

bool bssrdf_invert_technique(const struct material *m, struct vec3 p1, const struct frame *f1, struct vec3 p2,
                             struct vec3 n2, float gamma, int *axis, int *channel)
{
    float w[BSSRDF_TECHNIQUES], sum = 0.0f;
    for (int t = 0; t < BSSRDF_TECHNIQUES; t++) {
        int a = t / BSSRDF_CHANNELS, c = t % BSSRDF_CHANNELS;
        w[t] = bssrdf_technique_prob(a, c) * bssrdf_pdf_technique(m, p1, f1, a, c, p2, n2);
        sum += w[t];
    }
    if (!(sum > 0.0f) || !isfinite(sum)) return false;
    float target = gamma * sum, acc = 0.0f;
    int pick = -1;
    for (int t = 0; t < BSSRDF_TECHNIQUES; t++) {
        if (!(w[t] > 0.0f)) continue;
        pick = t;
        acc += w[t];
        if (target < acc) break;
    }
    *axis = pick / BSSRDF_CHANNELS;
    *channel = pick % BSSRDF_CHANNELS;
    return true;
}
