/* bdpt_mis.h — recursive multiple importance sampling for bidirectional path tracing: the
 * partial weights dVCM and dVC that a subpath carries from vertex to vertex, so that the MIS
 * weight of any connection is found from the two endpoints alone, in O(1) (Georgiev 2012,
 * "Implementing Vertex Connection and Merging", technical report; here with vertex
 * merging left out, i.e. plain BDPT; [ReSTIR BDPT §6] uses the same quantities).
 *
 * Notation. A path x_0 .. x_k (x_0 the camera, x_k on an emitter) can be produced by every
 * technique that splits it into a camera subpath of t vertices and a light subpath of s = k+1-t
 * vertices, provided the edge between them joins two non-delta vertices. p_s is that
 * technique's path pdf in the area measure, times its sample count (1 per pixel for the
 * camera-side techniques, N_L for light tracing, t = 1). With Mis(x) = x (balance heuristic)
 * or x^2 (power heuristic), the weight of technique s is
 *     w_s = Mis(p_s) / sum_i Mis(p_i),
 * and the recursive quantities are the sums of Mis(p_i / p_s) over the techniques on either
 * side of s, accumulated along each subpath:
 *   - at a subpath vertex x_i reached from x_{i-1}, after the hit update, dVCM = Mis(p_rev /
 *     p_fwd) for the technique that would end the subpath at x_{i-1} instead, and dVC collects
 *     every technique further back, each divided by the forward area pdfs up to x_i;
 *   - a delta vertex has no connection technique of its own: its dVCM becomes 0, and dVC is
 *     carried through with the ratio of its discrete reverse and forward lobe probabilities.
 * Area conversions use geometric normals. Russian roulette is not folded into the pdfs: the
 * weights only have to sum to 1 over the techniques, which they do whatever positive pdf-like
 * values are used, as long as every technique uses the same ones.
 * Header-only and pure, so the unit test recomputes the weights by brute force against these
 * very functions (tests/unit/test_bdpt.c). */
#ifndef RESTIRD_BDPT_MIS_H
#define RESTIRD_BDPT_MIS_H

#include <math.h>
#include <stdbool.h>

struct bdpt_mis {
    float dvcm, dvc;
};

/* Mis(x): x (balance heuristic) or x^2 (power heuristic, beta = 2). */
static inline float bdpt_mis_f(float x, bool power)
{
    return power ? x * x : x;
}

/* A light subpath leaving a finite area emitter: `direct_pdf_a` is the area pdf with which
 * next-event estimation picks the same point (light choice included), `emission_pdf_w` the pdf
 * of the light subpath's start (point and direction: pdf_a times the direction's solid-angle
 * pdf), `cos_light` the cosine of the emitted direction with the emitter's normal. */
static inline struct bdpt_mis bdpt_mis_light_start(float direct_pdf_a, float emission_pdf_w, float cos_light,
                                                   bool power)
{
    return (struct bdpt_mis){bdpt_mis_f(direct_pdf_a / emission_pdf_w, power),
                             bdpt_mis_f(cos_light / emission_pdf_w, power)};
}

/* A camera subpath: `camera_pdf_w` is the solid-angle pdf of the primary direction when the
 * image plane is sampled with density 1 per pixel, `light_paths` = N_L, the light-tracing
 * technique's sample count against one camera sample per pixel. */
static inline struct bdpt_mis bdpt_mis_camera_start(float light_paths, float camera_pdf_w, bool power)
{
    return (struct bdpt_mis){bdpt_mis_f(light_paths / camera_pdf_w, power), 0.0f};
}

/* The subpath travelled `dist2` (squared length) and hit a surface at cosine `cos_hit`
 * (geometric normal, the incoming direction): the forward solid-angle pdf becomes an area pdf. */
static inline void bdpt_mis_hit(struct bdpt_mis *m, float dist2, float cos_hit, bool power)
{
    float c = bdpt_mis_f(fabsf(cos_hit), power);
    m->dvcm *= bdpt_mis_f(dist2, power) / c;
    m->dvc /= c;
}

/* The subpath sampled its next direction at the current vertex with solid-angle pdf
 * `pdf_fwd_w`; `pdf_rev_w` is the pdf of sampling the previous direction from the new one,
 * `cos_out` the cosine of the new direction (geometric normal). Delta lobes pass their
 * discrete lobe probabilities. */
static inline void bdpt_mis_scatter(struct bdpt_mis *m, float cos_out, float pdf_fwd_w, float pdf_rev_w, bool delta,
                                    bool power)
{
    float c = fabsf(cos_out);
    if (delta) {
        m->dvcm = 0.0f;
        m->dvc *= bdpt_mis_f(c * pdf_rev_w / pdf_fwd_w, power);
        return;
    }
    m->dvc = bdpt_mis_f(c / pdf_fwd_w, power) * (m->dvc * bdpt_mis_f(pdf_rev_w, power) + m->dvcm);
    m->dvcm = bdpt_mis_f(1.0f / pdf_fwd_w, power);
}

/* s = 0: the camera subpath hit an emitter (after at least one bounce). `direct_pdf_a` and
 * `emission_pdf_w` as in bdpt_mis_light_start, for the point hit. */
static inline float bdpt_mis_weight_emission(const struct bdpt_mis *cam, float direct_pdf_a, float emission_pdf_w,
                                             bool power)
{
    float w_camera = bdpt_mis_f(direct_pdf_a, power) * cam->dvcm + bdpt_mis_f(emission_pdf_w, power) * cam->dvc;
    return 1.0f / (1.0f + w_camera);
}

/* s = 1: next-event estimation from a camera vertex. `bsdf_fwd_w` / `bsdf_rev_w`: the camera
 * vertex's BSDF pdfs towards the light and back; `direct_pdf_w`: the light sample's solid-angle
 * pdf at the camera vertex; `emission_pdf_w`: the pdf that a light subpath starts at the point
 * in this direction; `cos_camera`: cosine at the camera vertex, `cos_light` at the emitter (both
 * geometric). */
static inline float bdpt_mis_weight_nee(const struct bdpt_mis *cam, float bsdf_fwd_w, float bsdf_rev_w,
                                        float direct_pdf_w, float emission_pdf_w, float cos_camera, float cos_light,
                                        bool power)
{
    float w_light = bdpt_mis_f(bsdf_fwd_w / direct_pdf_w, power);
    float w_camera = bdpt_mis_f(emission_pdf_w * fabsf(cos_camera) / (direct_pdf_w * fabsf(cos_light)), power) *
                     (cam->dvcm + cam->dvc * bdpt_mis_f(bsdf_rev_w, power));
    return 1.0f / (w_light + 1.0f + w_camera);
}

/* s >= 2, t >= 2: a camera vertex joined to a light vertex. `cam_fwd_a`: the camera vertex's
 * BSDF pdf towards the light vertex as an area pdf there; `cam_rev_w`: the camera vertex's pdf
 * of its own incoming direction given the connection; the light side likewise. */
static inline float bdpt_mis_weight_connect(const struct bdpt_mis *cam, const struct bdpt_mis *light, float cam_fwd_a,
                                            float cam_rev_w, float light_fwd_a, float light_rev_w, bool power)
{
    float w_light = bdpt_mis_f(cam_fwd_a, power) * (light->dvcm + light->dvc * bdpt_mis_f(light_rev_w, power));
    float w_camera = bdpt_mis_f(light_fwd_a, power) * (cam->dvcm + cam->dvc * bdpt_mis_f(cam_rev_w, power));
    return 1.0f / (w_light + 1.0f + w_camera);
}

/* t = 1: a light vertex seen by the camera (light tracing). `camera_pdf_a`: the area pdf at the
 * light vertex of a camera ray sampled with density 1 per pixel; `light_rev_w`: the light
 * vertex's pdf of its incoming direction given the direction to the camera. */
static inline float bdpt_mis_weight_camera(const struct bdpt_mis *light, float camera_pdf_a, float light_paths,
                                           float light_rev_w, bool power)
{
    float w_light = bdpt_mis_f(camera_pdf_a / light_paths, power) *
                    (light->dvcm + light->dvc * bdpt_mis_f(light_rev_w, power));
    return 1.0f / (w_light + 1.0f);
}

#endif
