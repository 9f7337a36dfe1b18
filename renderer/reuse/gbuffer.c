/* gbuffer.c — primary hits and motion vectors (see gbuffer.h). */
#include "reuse/gbuffer.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scene/camera.h"
#include "scene/light_sampler.h"
#include "core/parallel.h"
#include "core/rng.h"
#include "core/sobol.h"
#include "scene/surface.h"

bool gbuffer_init(struct gbuffer *g, uint32_t width, uint32_t height, struct err *err)
{
    g->width = g->height = 0;
    g->px = NULL;
    g->surf = NULL;
    g->emission = NULL;
    g->edge = NULL;
    g->corner = NULL;
    g->edges = NULL;
    g->owns_emission = false;
    if (width == 0 || height == 0 || width > 16384 || height > 16384)
        return err_set(err, ERR_LIMIT, NULL, "G-buffer size %ux%u outside 1..16384", width, height);
    g->px = calloc((size_t)width * height, sizeof *g->px);
    if (!g->px) return err_set(err, ERR_NOMEM, NULL, "out of memory for a %ux%u G-buffer", width, height);
    g->width = width;
    g->height = height;
    return true;
}

const struct hit *gbuffer_hit(const struct scene *scene, const struct gbuffer_pixel *px, struct hit *out)
{
    if (!isfinite(px->t)) return NULL;
    *out = surface_hit_at(scene, px->shape, px->prim, px->t, px->b1, px->b2);
    return out;
}

bool gbuffer_keep_surfaces(struct gbuffer *g, struct err *err)
{
    if (g->surf) return true;
    g->surf = calloc((size_t)g->width * g->height, sizeof *g->surf);
    if (!g->surf)
        return err_set(err, ERR_NOMEM, NULL, "out of memory for %ux%u primary surfaces", g->width, g->height);
    return true;
}

size_t gbuffer_emission_bytes_planned(uint32_t width, uint32_t height)
{
    const size_t pixels = (size_t)width * height;
    return pixels * (sizeof(struct vec3) + sizeof(uint8_t)) + ((size_t)width + 1) * (height + 1) * sizeof(uint32_t) +
           sizeof(struct gbuffer_edges);
}

/* Frees what gbuffer_keep_emission allocated. */
static void gbuffer_drop_emission(struct gbuffer *g)
{
    if (g->owns_emission) {
        free(g->emission);
        free(g->edge);
        free(g->corner);
        free(g->edges);
    }
    g->emission = NULL;
    g->edge = NULL;
    g->corner = NULL;
    g->edges = NULL;
    g->owns_emission = false;
}

bool gbuffer_keep_emission(struct gbuffer *g, struct err *err)
{
    if (g->emission) return true;
    const size_t pixels = (size_t)g->width * g->height;
    g->owns_emission = true;
    g->emission = calloc(pixels, sizeof *g->emission);
    g->edge = calloc(pixels, sizeof *g->edge);
    g->corner = calloc(((size_t)g->width + 1) * (g->height + 1), sizeof *g->corner);
    g->edges = calloc(1, sizeof *g->edges);   /* serial 0: no scene's */
    if (g->emission && g->edge && g->corner && g->edges) return true;
    gbuffer_drop_emission(g);
    return err_set(err, ERR_NOMEM, NULL, "out of memory for %ux%u pixels' emission", g->width, g->height);
}

void gbuffer_share_emission(struct gbuffer *g, const struct gbuffer *from)
{
    gbuffer_drop_emission(g);
    g->emission = from->emission;
    g->edge = from->edge;
    g->corner = from->corner;
    g->edges = from->edges;
}

void gbuffer_destroy(struct gbuffer *g)
{
    free(g->px);
    free(g->surf);
    gbuffer_drop_emission(g);
    g->px = NULL;
    g->surf = NULL;
    g->width = g->height = 0;
}

size_t gbuffer_bytes(const struct gbuffer *g)
{
    return (size_t)g->width * g->height * sizeof *g->px;
}

size_t gbuffer_surface_bytes(const struct gbuffer *g)
{
    return g->surf ? (size_t)g->width * g->height * sizeof *g->surf : 0;
}

size_t gbuffer_emission_bytes(const struct gbuffer *g)
{
    return g->emission && g->owns_emission ? gbuffer_emission_bytes_planned(g->width, g->height) : 0;
}

#define GBUFFER_ROWS_PER_JOB 4u
#define GBUFFER_MAX_WORKERS 1024u

struct gbuffer_job {
    struct gbuffer *g;
    const struct gbuffer_frame *f;
    struct camera cam, prev_cam;
    bool check;  /* the history check applies (gbuffer_render) */
    uint64_t rays[GBUFFER_MAX_WORKERS];
};

/* The point's position in the previous frame's world: unchanged unless its shape moved. */
static struct vec3 gbuffer_prev_point(const struct gbuffer_frame *f, uint32_t shape, struct vec3 p)
{
    const struct xform *cur = accel_shape_to_world(f->scene->accel, shape);
    const struct xform *prev = accel_shape_to_world(f->prev_scene->accel, shape);
    if (memcmp(cur, prev, sizeof *cur) == 0) return p;
    struct xform inv;
    if (!xform_invert(cur, &inv)) return p;
    return xform_point(prev, xform_point(&inv, p));
}

/* A position moved by a step of at most 0.5, reflected back into [0, 1). */
static float gbuffer_reflect(float z)
{
    if (z < 0.0f) z = -z;
    if (z >= 1.0f) z = 2.0f - z;
    return z < 1.0f ? z : 0x1.fffffep-1f;
}

/* The pixel of g under image position (px, py), or UINT32_MAX off screen (or NaN). */
static uint32_t gbuffer_pixel_at(const struct gbuffer *g, float px, float py)
{
    if (!(px >= 0.0f && py >= 0.0f && px < (float)g->width && py < (float)g->height)) return UINT32_MAX;
    return (uint32_t)py * g->width + (uint32_t)px;
}

/* The area a pixel of camera `cam` covers on a surface at distance d along unit direction w,
 * whose geometric normal is ng: the pixel's solid angle (s^2 cos^3 of the angle off the axis,
 * s the pixel's side at unit distance) times d^2 / |cos| at the surface. */
static float gbuffer_footprint(const struct camera *cam, struct vec3 w, float d, struct vec3 ng)
{
    const float side = 2.0f * cam->tan_half_fov_y / (float)cam->height;
    const float c = vec3_dot(w, cam->forward);
    return side * side * c * c * c * d * d / fmaxf(fabsf(vec3_dot(ng, w)), 1e-3f);
}

/* The history check of a pixel whose primary hit (on `shape`, normal ng, distance t along unit
 * direction dir) reprojects to q at image position (px, py) of the previous frame. Returns 0 when
 * the previous pixel under (px, py) saw another surface: no hit, another shape, or a tangent plane
 * farther from q than GBUFFER_HISTORY_PLANE_TOL of q's distance from the previous camera (the
 * plane rather than the hit distance, which on a surface seen at a grazing angle changes by more
 * than any fixed tolerance across the pixel). A disoccluded point, or one seen across a
 * silhouette, fails. Otherwise the pixel's share of that history's confidence, min(1, A / A'),
 * A and A' the areas the current and the previous pixel cover on the surface (A carried to the
 * previous frame's surface where the shape changed size: surface_area_ratio): a previous pixel
 * that covered k times this one's area is the history of about k current pixels (after the camera
 * came closer, or turned to see the surface less obliquely), each of which would otherwise take
 * its few samples at their full confidence and repeat them over k pixels. Any positive
 * confidence keeps the temporal pass's MIS weights a partition of unity, so the share biases
 * nothing. Off screen: 1 (the temporal pass drops it anyway). */
static float gbuffer_history_share(const struct gbuffer_job *gj, const struct gbuffer_pixel *gp, struct vec3 ng,
                                   struct vec3 dir, struct vec3 q, float px, float py)
{
    const uint32_t shape = gp->shape;
    const struct gbuffer_frame *f = gj->f;
    const struct gbuffer *pg = f->prev_gbuffer;
    const uint32_t at = gbuffer_pixel_at(pg, px, py);
    if (at == UINT32_MAX) return 1.0f;
    const struct gbuffer_pixel *pp = &pg->px[at];
    if (!isfinite(pp->t) || pp->shape != shape) return 0.0f;
    struct vec3 pp_p, pp_ng;
    if (pg->surf) {
        pp_p = pg->surf[at].p;
        pp_ng = pg->surf[at].ng;
    } else {
        struct vec3 pdir =
            camera_ray_dir(&gj->prev_cam, (float)(at % pg->width) + pp->jx, (float)(at / pg->width) + pp->jy);
        struct hit h = surface_hit_at(f->prev_scene, pp->shape, pp->prim, pp->t, pp->b1, pp->b2);
        struct surface s;
        surface_from_hit(f->prev_scene, &h, gj->prev_cam.position, pdir, &s);
        pp_p = s.p;
        pp_ng = s.ng;
    }
    const struct vec3 to_q = vec3_sub(q, gj->prev_cam.position);
    const float dist = vec3_length(to_q);
    if (!(fabsf(vec3_dot(pp_ng, vec3_sub(q, pp_p))) <= GBUFFER_HISTORY_PLANE_TOL * dist)) return 0.0f;
    const float a = gbuffer_footprint(&gj->cam, dir, gp->t, ng) *
                    surface_area_ratio(f->scene, f->prev_scene, shape, gp->prim, gp->b1, gp->b2);
    const float a_prev = gbuffer_footprint(&gj->prev_cam, vec3_scale(to_q, 1.0f / dist), dist, pp_ng);
    return a_prev > a ? a / a_prev : 1.0f;
}

/* An escaped ray's history: the previous pixel's ray escaped too. */
static bool gbuffer_same_sky(const struct gbuffer *pg, float px, float py)
{
    const uint32_t at = gbuffer_pixel_at(pg, px, py);
    return at == UINT32_MAX || !isfinite(pg->px[at].t);
}

void gbuffer_emission_position(uint64_t seed, uint64_t pixel, uint32_t frame, uint32_t k, uint32_t samples, float *jx,
                               float *jy)
{
    /* Past 2^32 points the sequence starts again under another scramble. */
    const uint64_t index = (uint64_t)frame * samples + k;
    const uint64_t pixel_seed =
        rng_mix64(seed ^ rng_mix64(pixel ^ rng_mix64(GBUFFER_EMISSION_STREAM ^ (index >> 32))));
    sobol_sample_2d(pixel_seed, (uint32_t)index, 0, jx, jy);
}

/* What a ray from the camera sees first, as far as the edge pixels go: an emitting shape (its
 * index), or nothing (a surface that does not emit towards the camera, or the environment).
 * The environment's edges are left out on purpose: estimated apart, the emission seen directly
 * loses the one position's agreement between it and the rest of the pixel's light, which a lit
 * environment and the surfaces it lights usually have (scenes/furnace: relMSE 2x at equal time),
 * and which an emitting shape, many times brighter than what surrounds it, does not
 * (docs/benchmarks.md, "Emission seen directly"). */
#define GBUFFER_SEES_NOTHING UINT32_MAX

/* The emission a camera ray along `dir` meets first (*sees: what it is), its hit already traced
 * (found: whether it hit). */
static struct vec3 gbuffer_emitted(const struct scene *scene, bool found, const struct hit *hit, struct vec3 dir,
                                   uint32_t *sees)
{
    if (!found) {
        *sees = GBUFFER_SEES_NOTHING;
        return scene->env_radiance;
    }
    const struct material *m = &scene->materials[scene->shapes[hit->shape].material];
    struct vec3 Le = material_is_emissive(m) ? light_sampler_emitted(m, -vec3_dot(dir, hit->ng)) : vec3_splat(0.0f);
    *sees = vec3_is_zero(Le) ? GBUFFER_SEES_NOTHING : hit->shape;
    return Le;
}

/* A corner whose ray gbuffer_corner_rows must trace: it lies in an emitting shape's projection. */
#define GBUFFER_CORNER_TRACE (UINT32_MAX - 1u)

/* Rows of pixel corners: what each corner marked GBUFFER_CORNER_TRACE sees (gbuffer_find_edges). */
static void gbuffer_corner_rows(void *ctx, uint32_t job, unsigned worker)
{
    struct gbuffer_job *gj = ctx;
    struct gbuffer *g = gj->g;
    struct ray_counters rc = {0, 0};
    const uint32_t w1 = g->width + 1, h1 = g->height + 1;
    const uint32_t y1 = (job + 1) * GBUFFER_ROWS_PER_JOB < h1 ? (job + 1) * GBUFFER_ROWS_PER_JOB : h1;
    for (uint32_t y = job * GBUFFER_ROWS_PER_JOB; y < y1; y++) {
        for (uint32_t x = 0; x < w1; x++) {
            uint32_t *corner = &g->corner[(size_t)y * w1 + x];
            if (*corner != GBUFFER_CORNER_TRACE) continue;
            struct vec3 dir = camera_ray_dir(&gj->cam, (float)x, (float)y);
            struct hit hit;
            bool found = accel_intersect(gj->f->scene->accel, gj->cam.position, dir, 0.0f, INFINITY, &hit, &rc);
            gbuffer_emitted(gj->f->scene, found, &hit, dir, corner);
        }
    }
    gj->rays[worker] += rc.intersect + rc.occluded;
}

/* The image box (pixels) an emitting shape's world bounding box projects onto; false when a
 * corner of that box is not in front of the camera (the shape may then cover any pixel). */
static bool gbuffer_emitter_box(const struct camera *cam, const struct scene *scene, uint32_t i, float box[4])
{
    const struct shape *sh = &scene->shapes[i];
    struct vec3 lo = vec3_splat(INFINITY), hi = vec3_splat(-INFINITY);
    const struct xform *to_world = accel_shape_to_world(scene->accel, i);
    const uint32_t n = sh->kind == SHAPE_MESH ? sh->vertex_count : 8u;
    if (n == 0) return false;
    for (uint32_t v = 0; v < n; v++) {
        struct vec3 p = sh->kind == SHAPE_MESH ? sh->positions[v]
                                               : vec3_add(sh->center, vec3_make(v & 1u ? sh->radius : -sh->radius,
                                                                                v & 2u ? sh->radius : -sh->radius,
                                                                                v & 4u ? sh->radius : -sh->radius));
        p = xform_point(to_world, p);
        lo = vec3_make(fminf(lo.x, p.x), fminf(lo.y, p.y), fminf(lo.z, p.z));
        hi = vec3_make(fmaxf(hi.x, p.x), fmaxf(hi.y, p.y), fmaxf(hi.z, p.z));
    }
    box[0] = box[1] = INFINITY;
    box[2] = box[3] = -INFINITY;
    for (uint32_t c = 0; c < 8u; c++) {
        struct vec3 q = vec3_make(c & 1u ? hi.x : lo.x, c & 2u ? hi.y : lo.y, c & 4u ? hi.z : lo.z);
        float px, py;
        if (!camera_project(cam, q, &px, &py) || !isfinite(px) || !isfinite(py)) return false;
        box[0] = fminf(box[0], px), box[1] = fminf(box[1], py), box[2] = fmaxf(box[2], px), box[3] = fmaxf(box[3], py);
    }
    return true;
}

/* Integer range [*a, *b] of lo - 1 .. hi + 1 within 0 .. last; false when it is empty. */
static bool gbuffer_range(float lo, float hi, uint32_t last, uint32_t *a, uint32_t *b)
{
    if (hi + 1.0f < 0.0f || lo - 1.0f > (float)last) return false;
    *a = lo - 1.0f > 0.0f ? (uint32_t)(lo - 1.0f) : 0u;
    *b = hi + 1.0f < (float)last ? (uint32_t)(hi + 1.0f) : last;
    return true;
}

/* An emitter that covers less than a pixel may fall between the corners: the pixels of every
 * emitting shape whose bounding box projects onto at most GBUFFER_SMALL_EMITTER_PX pixels a side
 * (and one pixel around) are edge pixels too. */
#define GBUFFER_SMALL_EMITTER_PX 8.0f

/* The edge pixels of this camera and scene: a pixel is one when its four corners do not all see
 * the same emitting shape or none (an emitter's edge crosses it), and so is every pixel beside
 * one; and the pixels of emitters too small for the corners to see. Only corners inside an
 * emitting shape's projected box (one pixel around) are traced: the others cannot see an
 * emitter. The edges depend on the camera and the scene alone, never on a frame's random numbers,
 * so which estimate a pixel's emission takes biases nothing. Kept until the camera or the scene
 * changes (by its serial, not its address, which a later scene may reuse). */
static bool gbuffer_find_edges(struct gbuffer_job *gj, unsigned threads, struct err *err)
{
    struct gbuffer *g = gj->g;
    const struct gbuffer_frame *f = gj->f;
    const uint32_t w = g->width, h = g->height, w1 = w + 1;
    const size_t pixels = (size_t)w * h;
    struct gbuffer_edges *key = g->edges;
    if (key->serial == f->scene->serial && memcmp(&key->camera, f->camera, sizeof *f->camera) == 0) return true;
    const struct scene *scene = f->scene;
    const size_t corners = (size_t)w1 * (h + 1);
    for (size_t i = 0; i < corners; i++) g->corner[i] = GBUFFER_SEES_NOTHING;
    memset(g->edge, 0, pixels * sizeof *g->edge);
    bool trace_all = false;
    for (uint32_t i = 0; i < scene->shape_count; i++) {
        if (!material_is_emissive(&scene->materials[scene->shapes[i].material])) continue;
        float box[4];
        uint32_t xa, xb, ya, yb;
        if (!gbuffer_emitter_box(&gj->cam, scene, i, box)) {
            trace_all = true;
        } else if (gbuffer_range(box[0], box[2], w, &xa, &xb) && gbuffer_range(box[1], box[3], h, &ya, &yb)) {
            for (uint32_t y = ya; y <= yb; y++)
                for (uint32_t x = xa; x <= xb; x++) g->corner[(size_t)y * w1 + x] = GBUFFER_CORNER_TRACE;
            /* Small: its pixels (and one around) are edge pixels whatever the corners see. */
            if (box[2] - box[0] <= GBUFFER_SMALL_EMITTER_PX && box[3] - box[1] <= GBUFFER_SMALL_EMITTER_PX &&
                gbuffer_range(box[0], box[2], w - 1, &xa, &xb) && gbuffer_range(box[1], box[3], h - 1, &ya, &yb))
                for (uint32_t y = ya; y <= yb; y++)
                    for (uint32_t x = xa; x <= xb; x++) g->edge[(size_t)y * w + x] = 1u;
        }
    }
    if (trace_all)
        for (size_t c = 0; c < corners; c++) g->corner[c] = GBUFFER_CORNER_TRACE;
    if (!parallel_run(threads, (h + 1 + GBUFFER_ROWS_PER_JOB - 1) / GBUFFER_ROWS_PER_JOB, gbuffer_corner_rows, gj,
                      NULL, NULL, err))
        return false;
    /* edge = 2: the pixel's own corners differ; 1: beside such a pixel, or a small emitter's. */
    for (uint32_t y = 0; y < h; y++) {
        for (uint32_t x = 0; x < w; x++) {
            const uint32_t *c = &g->corner[(size_t)y * w1 + x];
            if (c[0] != c[1] || c[0] != c[w1] || c[0] != c[w1 + 1]) g->edge[(size_t)y * w + x] = 2u;
        }
    }
    for (uint32_t y = 0; y < h; y++) {
        for (uint32_t x = 0; x < w; x++) {
            uint8_t *e = &g->edge[(size_t)y * w + x];
            if (*e) continue;
            for (uint32_t yy = y ? y - 1 : 0; yy <= y + 1 && yy < h && !*e; yy++)
                for (uint32_t xx = x ? x - 1 : 0; xx <= x + 1 && xx < w && !*e; xx++)
                    if (g->edge[(size_t)yy * w + xx] == 2u) *e = 1u;
        }
    }
    size_t edges = 0;
    for (size_t i = 0; i < pixels; i++) edges += g->edge[i] != 0;
    /* At most as many edge rays as pixels, and a power of two: a frame's rays are then a whole
     * block of the pixel's Sobol' sequence (gbuffer_emission_position). */
    const size_t share = edges ? pixels / edges : GBUFFER_EMISSION_SAMPLES_MAX;
    uint32_t cap = 1u;
    while ((size_t)cap * 2u <= share && cap * 2u <= GBUFFER_EMISSION_SAMPLES_MAX) cap *= 2u;
    key->samples = cap;
    key->camera = *f->camera;
    key->serial = scene->serial;
    return true;
}

/* Point `frame` of the pixel's Sobol' sequence (gbuffer.h). */
void gbuffer_fresh_position(uint64_t seed, uint64_t pixel, uint32_t frame, float *jx, float *jy)
{
    const uint64_t pixel_seed = rng_mix64(seed ^ rng_mix64(pixel ^ rng_mix64(GBUFFER_STREAM)));
    sobol_sample_2d(pixel_seed, frame, 0, jx, jy);
}

static void gbuffer_rows(void *ctx, uint32_t job, unsigned worker)
{
    struct gbuffer_job *gj = ctx;
    struct gbuffer *g = gj->g;
    const struct gbuffer_frame *f = gj->f;
    struct ray_counters rc = {0, 0};
    const bool check = gj->check;
    uint32_t y1 = (job + 1) * GBUFFER_ROWS_PER_JOB < g->height ? (job + 1) * GBUFFER_ROWS_PER_JOB : g->height;
    for (uint32_t y = job * GBUFFER_ROWS_PER_JOB; y < y1; y++) {
        for (uint32_t x = 0; x < g->width; x++) {
            uint64_t pixel = (uint64_t)y * g->width + x;
            struct gbuffer_pixel *gp = &g->px[pixel];
            const bool walk = f->prev_gbuffer && f->jitter_walk > 0.0f;
            if (f->stratify && !walk) {
                gbuffer_fresh_position(f->seed, pixel, f->frame, &gp->jx, &gp->jy);
            } else {
                struct rng rng = rng_make(f->seed, f->frame, pixel, GBUFFER_STREAM);
                gp->jx = rng_next_float(&rng);
                gp->jy = rng_next_float(&rng);
                if (walk) {
                    const struct gbuffer_pixel *pp = &f->prev_gbuffer->px[pixel];
                    gp->jx = gbuffer_reflect(pp->jx + (2.0f * gp->jx - 1.0f) * f->jitter_walk);
                    gp->jy = gbuffer_reflect(pp->jy + (2.0f * gp->jy - 1.0f) * f->jitter_walk);
                }
            }
            struct vec3 dir = camera_ray_dir(&gj->cam, (float)x + gp->jx, (float)y + gp->jy);
            struct hit hit;
            gp->prev_x = gp->prev_y = NAN;
            gp->prev_share = 1.0f;
            bool found = accel_intersect(f->scene->accel, gj->cam.position, dir, 0.0f, INFINITY, &hit, &rc);
            if (g->emission) {
                uint32_t sees;
                struct vec3 Le = gbuffer_emitted(f->scene, found, &hit, dir, &sees);
                uint32_t k_count = 1u;   /* the largest power of two within both bounds */
                while (k_count * 2u <= f->emission_samples && k_count * 2u <= g->edges->samples) k_count *= 2u;
                if (k_count > 1 && g->edge[pixel]) {
                    /* The primary ray's own emission stays with the reservoir's path position
                     * only when the pixel is not an edge pixel: here K rays of their own. */
                    Le = vec3_splat(0.0f);
                    for (uint32_t k = 0; k < k_count; k++) {
                        float ex, ey;
                        gbuffer_emission_position(f->seed, pixel, f->frame, k, k_count, &ex, &ey);
                        struct vec3 edir = camera_ray_dir(&gj->cam, (float)x + ex, (float)y + ey);
                        struct hit eh;
                        bool ef = accel_intersect(f->scene->accel, gj->cam.position, edir, 0.0f, INFINITY, &eh, &rc);
                        Le = vec3_add(Le, gbuffer_emitted(f->scene, ef, &eh, edir, &sees));
                    }
                    Le = vec3_scale(Le, 1.0f / (float)k_count);
                }
                g->emission[pixel] = Le;
            }
            if (!found) {
                gp->t = INFINITY;
                gp->shape = gp->prim = 0;
                gp->b1 = gp->b2 = 0.0f;
                if (g->surf) g->surf[pixel] = (struct gbuffer_surface){.material = GBUFFER_NO_HIT};
                if (f->prev_scene) camera_project_dir(&gj->prev_cam, dir, &gp->prev_x, &gp->prev_y);
                if (check && !gbuffer_same_sky(f->prev_gbuffer, gp->prev_x, gp->prev_y)) gp->prev_x = gp->prev_y = NAN;
                continue;
            }
            gp->t = hit.t;
            gp->shape = hit.shape;
            gp->prim = hit.prim;
            struct surface s;
            surface_from_hit(f->scene, &hit, gj->cam.position, dir, &s);
            surface_point_code(f->scene, &hit, &s, &gp->b1, &gp->b2);
            if (g->surf) g->surf[pixel] = (struct gbuffer_surface){s.p, s.ng, s.ns, s.material};
            if (f->prev_scene) {
                struct vec3 q = gbuffer_prev_point(f, hit.shape, s.p);
                camera_project(&gj->prev_cam, q, &gp->prev_x, &gp->prev_y);
                if (check) {
                    gp->prev_share = gbuffer_history_share(gj, gp, s.ng, dir, q, gp->prev_x, gp->prev_y);
                    if (!(gp->prev_share > 0.0f)) gp->prev_x = gp->prev_y = NAN;
                }
            }
        }
    }
    gj->rays[worker] += rc.intersect + rc.occluded;
}

bool gbuffer_emission_samples_valid(uint32_t samples, struct err *err)
{
    if (samples >= 1 && samples <= GBUFFER_EMISSION_SAMPLES_MAX) return true;
    return err_set(err, ERR_INVALID, "/params/emission_samples", "emission_samples must be in 1..%u",
                   GBUFFER_EMISSION_SAMPLES_MAX);
}

bool gbuffer_jitter_walk_valid(float jitter_walk, struct err *err)
{
    if (jitter_walk >= 0.0f && jitter_walk <= 0.5f) return true;
    return err_set(err, ERR_INVALID, "/params/jitter_walk", "must be in [0, 0.5] pixels");
}

bool gbuffer_render(struct gbuffer *g, const struct gbuffer_frame *f, uint64_t *rays, struct err *err)
{
    /* On the stack (8 KiB of counters): a steady-state frame allocates nothing. */
    struct gbuffer_job job_storage;
    struct gbuffer_job *gj = &job_storage;
    memset(gj, 0, sizeof *gj);
    gj->g = g;
    gj->f = f;
    camera_init(&gj->cam, f->camera, g->width, g->height);
    if (f->prev_scene) camera_init(&gj->prev_cam, f->prev_camera, g->width, g->height);
    /* With a still camera and scene the previous pixel is this pixel (up to its jitter) and covers
     * the same area: the check would only drop pixels astride an edge between two shapes, whose
     * history is as good as any, so it applies only when something moved. */
    gj->check = f->check_history && f->prev_gbuffer && f->prev_scene &&
                (memcmp(f->camera, f->prev_camera, sizeof *f->camera) != 0 || scene_moved(f->prev_scene, f->scene));
    unsigned threads = f->threads ? f->threads : parallel_default_threads();
    if (threads > GBUFFER_MAX_WORKERS) threads = GBUFFER_MAX_WORKERS;
    uint32_t jobs = (g->height + GBUFFER_ROWS_PER_JOB - 1) / GBUFFER_ROWS_PER_JOB;
    bool ok = !(g->emission && f->emission_samples > 1) || gbuffer_find_edges(gj, threads, err);
    ok = ok && parallel_run(threads, jobs, gbuffer_rows, gj, NULL, NULL, err);
    if (rays) {
        *rays = 0;
        for (unsigned i = 0; i < threads; i++) *rays += gj->rays[i];
    }
    return ok;
}
