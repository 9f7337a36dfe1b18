/* test_gbuffer.c — camera projection and G-buffer motion vectors, as round trips: a position
 * projected back through the camera gives the same ray; a pixel's previous position, traced
 * from the previous camera in the previous scene, hits the same surface point (camera motion,
 * a moved shape, both). The jitter walk keeps positions uniform in the pixel. The history check
 * drops exactly the motion vectors whose previous pixel saw another surface, and the shares of
 * one previous pixel's history add up to about one. And the primary surfaces a G-buffer keeps, and
 * its estimate of the emission seen directly. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scene/accel.h"
#include "scene/camera.h"
#include "scene/light_sampler.h"
#include "reuse/gbuffer.h"
#include "core/rng.h"
#include "scene/scene.h"
#include "scene/surface.h"
#include "test.h"
#include "scene_fixture.h"

static void test_camera_project_round_trip(void)
{
    struct camera_desc d = {{278, 273, -800}, {300, 250, 0}, {0.1f, 1, 0}, 39.3f};
    struct camera cam;
    camera_init(&cam, &d, 64, 48);
    struct rng r = rng_make(1, 2, 3, 4);
    for (int i = 0; i < 1000; i++) {
        float px = -10.0f + 84.0f * rng_next_float(&r), py = -10.0f + 68.0f * rng_next_float(&r);
        struct vec3 dir = camera_ray_dir(&cam, px, py);
        float qx = NAN, qy = NAN;  /* a failed projection fails the comparisons below too */
        CHECK(camera_project(&cam, vec3_madd(cam.position, dir, 10.0f + 900.0f * rng_next_float(&r)), &qx, &qy));
        CHECK_NEAR(qx, px, 1e-3);
        CHECK_NEAR(qy, py, 1e-3);
    }
    float qx = 7.0f, qy = 7.0f;
    CHECK(!camera_project(&cam, vec3_madd(cam.position, cam.forward, -1.0f), &qx, &qy));
    CHECK(qx == 7.0f && qy == 7.0f);
}

/* For every pixel whose point is visible in the previous frame at its previous position, the
 * previous frame's ray through prev_x/prev_y must hit the same object-space point (same shape).
 * Returns the fraction of hit pixels that did; *focus_frac gets the same fraction over the
 * pixels that see shape `focus` (a moved shape: a motion vector that ignored its motion would
 * send those rays past it, so they would not match). */
static double check_motion(const struct gbuffer *g, const struct scene *cur, const struct camera_desc *cur_cam,
                           const struct scene *prev, const struct camera_desc *prev_cam, uint32_t focus,
                           double *focus_frac)
{
    uint32_t focus_hits = 0, focus_matched = 0;
    struct camera cc, pc;
    camera_init(&cc, cur_cam, g->width, g->height);
    camera_init(&pc, prev_cam, g->width, g->height);
    uint32_t hits = 0, matched = 0;
    struct ray_counters rc = {0, 0};
    for (uint32_t y = 0; y < g->height; y++) {
        for (uint32_t x = 0; x < g->width; x++) {
            const struct gbuffer_pixel *gp = &g->px[(size_t)y * g->width + x];
            if (!isfinite(gp->t)) continue;
            hits++;
            focus_hits += gp->shape == focus;
            if (!isfinite(gp->prev_x)) continue;
            struct vec3 d0 = camera_ray_dir(&cc, (float)x + gp->jx, (float)y + gp->jy);
            struct hit h0 = {0}, h1 = {0};
            CHECK(accel_intersect(cur->accel, cc.position, d0, 0, INFINITY, &h0, &rc));
            struct surface s0, s1;
            surface_from_hit(cur, &h0, cc.position, d0, &s0);
            struct vec3 d1 = camera_ray_dir(&pc, gp->prev_x, gp->prev_y);
            if (!accel_intersect(prev->accel, pc.position, d1, 0, INFINITY, &h1, &rc)) continue;
            if (h1.shape != h0.shape) continue;  /* occluded in the previous frame */
            surface_from_hit(prev, &h1, pc.position, d1, &s1);
            /* Compare in object space: the shape may have moved. */
            struct xform inv0, inv1;
            if (!xform_invert(accel_shape_to_world(cur->accel, h0.shape), &inv0) ||
                !xform_invert(accel_shape_to_world(prev->accel, h1.shape), &inv1)) {
                CHECK_MSG(false, "pixel %u,%u: a shape transform is singular", x, y);
                continue;
            }
            struct vec3 o0 = xform_point(&inv0, s0.p), o1 = xform_point(&inv1, s1.p);
            float err = vec3_length(vec3_sub(o0, o1));
            CHECK_MSG(err < 0.05f, "pixel %u,%u: %.4f apart", x, y, (double)err);
            matched++;
            focus_matched += h0.shape == focus;
        }
    }
    if (focus_frac) *focus_frac = focus_hits ? (double)focus_matched / focus_hits : 0.0;
    return hits ? (double)matched / hits : 0.0;
}

static void test_motion_vectors(void)
{
    struct scene *s = fixture_load("scenes/cornell-box/scene.json");
    if (!s) return;
    struct gbuffer g;
    struct err err = {0};
    CHECK(gbuffer_init(&g, 48, 40, &err));

    /* No previous frame: no motion. Same camera and scene: prev = the jittered position. */
    struct gbuffer_frame f = {.scene = s, .camera = &s->camera, .seed = 3, .frame = 1, .threads = 2};
    uint64_t rays = 0;
    CHECK(gbuffer_render(&g, &f, &rays, &err));
    CHECK(rays == 48 * 40);
    CHECK(isnan(g.px[0].prev_x));
    f.prev_scene = s;
    f.prev_camera = &s->camera;
    CHECK(gbuffer_render(&g, &f, NULL, &err));
    for (uint32_t i = 0; i < 48 * 40; i++) {
        CHECK_NEAR(g.px[i].prev_x, (float)(i % 48) + g.px[i].jx, 2e-3);
        CHECK_NEAR(g.px[i].prev_y, (float)(i / 48) + g.px[i].jy, 2e-3);
    }

    /* The camera moved: the previous ray through prev_x/prev_y finds the same point. */
    struct camera_desc moved = s->camera;
    moved.position = vec3_add(moved.position, vec3_make(60, -20, 90));
    moved.look_at = vec3_add(moved.look_at, vec3_make(30, 0, 0));
    f.camera = &moved;
    CHECK(gbuffer_render(&g, &f, NULL, &err));
    double frac = check_motion(&g, s, &moved, s, &s->camera, UINT32_MAX, NULL);
    CHECK_MSG(frac > 0.9, "only %.3f of hit pixels found their previous point", frac);

    /* The light moved down and the camera moved: points on the light follow the light. */
    int light = scene_find_shape(s, "ceiling_light");
    CHECK(light >= 0);
    struct scene_shape_override ov = {.shape = (uint32_t)light, .has_to_world = true};
    ov.to_world = xform_identity();
    ov.to_world.m[1][3] = -120.0f;
    ov.to_world.m[0][3] = 40.0f;
    struct scene *d = scene_derive(s, &ov, 1, &err);
    CHECK_MSG(d != NULL, "%s", err.message);
    if (d) {
        f.scene = d;
        CHECK(gbuffer_render(&g, &f, NULL, &err));
        uint32_t on_light = 0;
        for (uint32_t i = 0; i < 48 * 40; i++) on_light += isfinite(g.px[i].t) && g.px[i].shape == (uint32_t)light;
        CHECK(on_light > 0);
        double on = 0.0;
        frac = check_motion(&g, d, &moved, s, &s->camera, (uint32_t)light, &on);
        CHECK_MSG(frac > 0.85, "only %.3f of hit pixels found their previous point", frac);
        CHECK_MSG(on > 0.9, "only %.3f of the moved light's pixels found their previous point", on);
        /* And the other way round (previous frame = the derived scene). */
        f.scene = s;
        f.prev_scene = d;
        CHECK(gbuffer_render(&g, &f, NULL, &err));
        frac = check_motion(&g, s, &moved, d, &s->camera, (uint32_t)light, &on);
        CHECK_MSG(frac > 0.85, "only %.3f of hit pixels found their previous point", frac);
        CHECK_MSG(on > 0.9, "only %.3f of the moved light's pixels found their previous point", on);
        scene_release(d);
    }
    gbuffer_destroy(&g);
    scene_release(s);
}

/* The jitter is the pixel's own stream for the frame: independent of the thread count, and
 * different from one frame to the next. */
static void test_jitter_deterministic(void)
{
    struct scene *s = fixture_load("scenes/cornell-box/scene.json");
    if (!s) return;
    struct gbuffer a, b;
    struct err err = {0};
    CHECK(gbuffer_init(&a, 33, 17, &err) && gbuffer_init(&b, 33, 17, &err));
    struct gbuffer_frame f = {.scene = s, .camera = &s->camera, .seed = 9, .frame = 4, .threads = 1};
    CHECK(gbuffer_render(&a, &f, NULL, &err));
    f.threads = 3;
    CHECK(gbuffer_render(&b, &f, NULL, &err));
    bool same = true;
    for (uint32_t i = 0; i < 33 * 17; i++) same = same && a.px[i].jx == b.px[i].jx && a.px[i].t == b.px[i].t;
    CHECK(same);
    f.frame = 5;
    CHECK(gbuffer_render(&b, &f, NULL, &err));
    uint32_t differ = 0;
    for (uint32_t i = 0; i < 33 * 17; i++) differ += a.px[i].jx != b.px[i].jx;
    CHECK(differ > 33 * 17 * 9 / 10);
    /* Without stratify (a method with temporal reuse) a fresh position is the pixel's random
     * stream's; with it, the frame's point of the pixel's Sobol' sequence. */
    uint32_t streamed = 0, sequenced = 0;
    for (uint32_t i = 0; i < 33 * 17; i++) {
        struct rng r = rng_make(9, 5, i, GBUFFER_STREAM);
        float rx = rng_next_float(&r), ry = rng_next_float(&r);
        streamed += b.px[i].jx == rx && b.px[i].jy == ry;
    }
    f.stratify = true;
    CHECK(gbuffer_render(&b, &f, NULL, &err));
    for (uint32_t i = 0; i < 33 * 17; i++) {
        float sx, sy;
        gbuffer_fresh_position(9, i, 5, &sx, &sy);
        sequenced += b.px[i].jx == sx && b.px[i].jy == sy;
    }
    CHECK_MSG(streamed == 33 * 17 && sequenced == 33 * 17, "%u and %u of %u", streamed, sequenced, 33 * 17);
    gbuffer_destroy(&a);
    gbuffer_destroy(&b);
    scene_release(s);
}

/* Pearson's chi-square of positions in [0, 1)^2 against the uniform distribution, 8 x 8 cells. */
static double jitter_chi2(const float *x, const float *y, uint32_t n)
{
    uint32_t cell[64] = {0};
    for (uint32_t i = 0; i < n; i++) cell[(uint32_t)(x[i] * 8.0f) * 8 + (uint32_t)(y[i] * 8.0f)]++;
    double e = n / 64.0, chi2 = 0.0;
    for (int c = 0; c < 64; c++) chi2 += (cell[c] - e) * (cell[c] - e) / e;
    return chi2;
}

/* The jitter walk (gbuffer.h): each frame's position is the previous one's moved by at most the
 * step per axis, the first frame's and one without a previous G-buffer are drawn afresh, and
 * after many frames the positions are still uniform in the pixel (chi-square over 4096 pixels,
 * 8 x 8 cells, p = 1e-4: 113.7 for 63 degrees of freedom by Wilson-Hilferty). The same steps
 * clamped at the pixel's edges instead of reflected pile up there and fail the same test. */
static void test_jitter_walk(void)
{
    struct scene *s = fixture_load("scenes/cornell-box/scene.json");
    if (!s) return;
    enum { W = 64, H = 64, N = W * H, FRAMES = 64 };
    /* Larger than restir_sms's 0.1: the walk mixes in fewer frames and the clamped control piles
     * up more at the edges (chi-square ~450 against 55-90 for the walk over seeds 5-9). */
    const float step = 0.25f;
    struct gbuffer g[2], fresh;
    struct err err = {0};
    CHECK(gbuffer_init(&g[0], W, H, &err) && gbuffer_init(&g[1], W, H, &err) && gbuffer_init(&fresh, W, H, &err));
    static float cx[N], cy[N];
    float worst = 0.0f;
    uint32_t cur = 0;
    struct gbuffer_frame f = {.scene = s, .camera = &s->camera, .seed = 5, .frame = 0, .threads = 2, .jitter_walk = step};
    CHECK(gbuffer_render(&g[cur], &f, NULL, &err));
    CHECK(gbuffer_render(&fresh, &(struct gbuffer_frame){.scene = s, .camera = &s->camera, .seed = 5, .threads = 2},
                         NULL, &err));
    CHECK(memcmp(g[cur].px, fresh.px, N * sizeof *fresh.px) == 0);  /* no previous G-buffer: afresh */
    for (uint32_t i = 0; i < N; i++) cx[i] = g[cur].px[i].jx, cy[i] = g[cur].px[i].jy;
    for (uint32_t t = 1; t <= FRAMES; t++) {
        f.frame = t;
        f.prev_gbuffer = &g[cur];
        cur ^= 1u;
        CHECK(gbuffer_render(&g[cur], &f, NULL, &err));
        for (uint32_t i = 0; i < N; i++) {
            const struct gbuffer_pixel *a = &g[cur ^ 1u].px[i], *b = &g[cur].px[i];
            worst = fmaxf(worst, fmaxf(fabsf(b->jx - a->jx), fabsf(b->jy - a->jy)));
            CHECK(b->jx >= 0.0f && b->jx < 1.0f && b->jy >= 0.0f && b->jy < 1.0f);
            /* The control: the walk's own steps, clamped at the edges. */
            struct rng rng = rng_make(f.seed, t, i, GBUFFER_STREAM);
            float ux = rng_next_float(&rng), uy = rng_next_float(&rng);
            cx[i] = fminf(fmaxf(cx[i] + (2.0f * ux - 1.0f) * step, 0.0f), 0x1.fffffep-1f);
            cy[i] = fminf(fmaxf(cy[i] + (2.0f * uy - 1.0f) * step, 0.0f), 0x1.fffffep-1f);
        }
    }
    CHECK_MSG(worst <= step * (1.0f + 1e-6f) && worst > 0.5f * step, "largest move %g for a step of %g", worst, step);
    static float jx[N], jy[N];
    for (uint32_t i = 0; i < N; i++) jx[i] = g[cur].px[i].jx, jy[i] = g[cur].px[i].jy;
    const double walk = jitter_chi2(jx, jy, N), clamped = jitter_chi2(cx, cy, N);
    printf("    jitter walk: chi-square %.1f after %d frames, clamped control %.1f (threshold 113.7), largest move %g\n",
           walk, FRAMES, clamped, worst);
    CHECK_MSG(walk < 113.7, "positions after %d frames of the walk: chi-square %.1f (63 dof)", FRAMES, walk);
    CHECK_MSG(clamped > 113.7, "the clamped control passes: chi-square %.1f", clamped);
    /* A walk of 0 draws every frame afresh, whatever the previous G-buffer. */
    f.jitter_walk = 0.0f;
    f.frame = 0;
    f.prev_gbuffer = &g[cur];
    CHECK(gbuffer_render(&g[cur ^ 1u], &f, NULL, &err));
    CHECK(memcmp(g[cur ^ 1u].px, fresh.px, N * sizeof *fresh.px) == 0);
    gbuffer_destroy(&g[0]);
    gbuffer_destroy(&g[1]);
    gbuffer_destroy(&fresh);
    scene_release(s);
}

/* Fresh positions (gbuffer_fresh_position) are stratified over a pixel's consecutive frames: the
 * 16 frames of an aligned block hold one point in each elementary interval of area 1/16 (all five
 * shapes), so the mean of a smooth function over 2^k frames errs far less than over independent
 * positions; and one frame's positions over many pixels are uniform. Independent positions (the
 * pixel's random stream, as before) are the control: they fail the net test, and their error
 * falls as 1/sqrt(frames). */
static bool net16(const float *x, const float *y)
{
    for (int a = 0; a <= 4; a++) {  /* intervals of 2^-a by 2^-(4-a) */
        int nx = 1 << a, ny = 1 << (4 - a), cell[16] = {0};
        for (int i = 0; i < 16; i++) cell[(int)(x[i] * nx) * ny + (int)(y[i] * ny)]++;
        for (int c = 0; c < 16; c++)
            if (cell[c] != 1) return false;
    }
    return true;
}

static void random_position(uint64_t seed, uint64_t pixel, uint32_t frame, float *jx, float *jy)
{
    struct rng r = rng_make(seed, frame, pixel, GBUFFER_STREAM);
    *jx = rng_next_float(&r);
    *jy = rng_next_float(&r);
}

/* RMS over pixels of the error of the mean of x*y over frames [0, n) (exact mean 1/4). */
static double smooth_mean_rms(void (*pos)(uint64_t, uint64_t, uint32_t, float *, float *), uint32_t n)
{
    double sq = 0.0;
    for (uint64_t px = 0; px < 1024; px++) {
        double sum = 0.0;
        for (uint32_t f = 0; f < n; f++) {
            float x, y;
            pos(11, px, f, &x, &y);
            sum += (double)x * y;
        }
        sq += (sum / n - 0.25) * (sum / n - 0.25);
    }
    return sqrt(sq / 1024);
}

static void test_fresh_positions_stratified(void)
{
    uint32_t nets = 0, random_nets = 0;
    for (uint64_t px = 0; px < 256; px++) {
        for (uint32_t block = 0; block < 4; block++) {
            float x[16], y[16], rx[16], ry[16];
            for (uint32_t i = 0; i < 16; i++) {
                gbuffer_fresh_position(3, px, 16 * block + i, &x[i], &y[i]);
                random_position(3, px, 16 * block + i, &rx[i], &ry[i]);
            }
            nets += net16(x, y);
            random_nets += net16(rx, ry);
        }
    }
    printf("    aligned 16-frame blocks that are (0,4,2)-nets: %u of 1024 (independent positions: %u)\n", nets,
           random_nets);
    CHECK_MSG(nets == 1024, "%u of 1024 blocks are nets", nets);
    CHECK_MSG(random_nets == 0, "the control: %u blocks of independent positions are nets", random_nets);

    /* One frame over 4096 pixels: uniform (chi-square, 63 dof, threshold at p = 0.0005). */
    enum { N = 4096 };
    static float jx[N], jy[N];
    for (uint32_t i = 0; i < N; i++) gbuffer_fresh_position(3, i, 7, &jx[i], &jy[i]);
    double chi2 = jitter_chi2(jx, jy, N);
    CHECK_MSG(chi2 < 113.7, "frame 7's positions over %d pixels: chi-square %.1f", N, chi2);

    /* The mean over 64 frames against over 4: 1/4 of the error for independent positions
     * (1/sqrt(16)); far less stratified. */
    double s4 = smooth_mean_rms(gbuffer_fresh_position, 4), s64 = smooth_mean_rms(gbuffer_fresh_position, 64);
    double r4 = smooth_mean_rms(random_position, 4), r64 = smooth_mean_rms(random_position, 64);
    printf("    mean of x*y: RMS error 4 frames %.2e, 64 frames %.2e (ratio %.4f); independent %.2e, %.2e (%.3f)\n",
           s4, s64, s64 / s4, r4, r64, r64 / r4);
    CHECK_MSG(s64 / s4 < 0.05, "stratified error ratio %.4f", s64 / s4);
    CHECK_MSG(r64 / r4 > 0.18 && r64 / r4 < 0.33, "independent positions' ratio %.3f, expected about 0.25", r64 / r4);
}

/* Checks the kept surfaces of one rendered G-buffer; returns the pixels whose ray escaped. */
static uint32_t check_kept_surfaces(const struct gbuffer *g, const struct scene *s)
{
    uint32_t escaped = 0, bad_hit = 0, bad_point = 0, bad_light_point = 0;
    for (uint32_t i = 0; i < g->width * g->height; i++) {
        const struct gbuffer_pixel *px = &g->px[i];
        const struct gbuffer_surface *k = &g->surf[i];
        if (!isfinite(px->t)) {
            escaped++;
            bad_hit += k->material != GBUFFER_NO_HIT;
            continue;
        }
        bad_hit += k->material != s->shapes[px->shape].material;
        struct surface at;
        surface_at(s, px->shape, px->prim, px->b1, px->b2, &at);
        bad_point += vec3_length(vec3_sub(at.p, k->p)) > 1e-2f || vec3_dot(at.ng, k->ng) < 0.9999f ||
                     vec3_dot(at.ns, k->ns) < 0.9999f;
        struct vec3 p, ng;
        surface_point_at(s, px->shape, px->prim, px->b1, px->b2, &p, &ng);
        bad_light_point += memcmp(&p, &at.p, sizeof p) != 0 || memcmp(&ng, &at.ng, sizeof ng) != 0;
    }
    CHECK_MSG(bad_hit == 0, "%u pixels keep the wrong material or hit mark", bad_hit);
    CHECK_MSG(bad_point == 0, "%u kept surfaces differ from the point their code rebuilds", bad_point);
    CHECK_MSG(bad_light_point == 0, "surface_point_at differs from surface_at at %u points", bad_light_point);
    return escaped;
}

/* The surfaces a G-buffer keeps (gbuffer_keep_surfaces): the no-hit mark exactly where the ray
 * escaped, else the shape's material and the point the pixel's code rebuilds; and
 * surface_point_at gives surface_at's position and normal bit for bit, on shapes in world
 * coordinates and on a moved one. */
static void test_kept_surfaces(void)
{
    struct scene *s = fixture_load("scenes/cornell-box/scene.json");
    if (!s) return;
    struct gbuffer g;
    struct err err = {0};
    CHECK(gbuffer_init(&g, 40, 32, &err));
    CHECK(g.surf == NULL && gbuffer_surface_bytes(&g) == 0);
    CHECK(gbuffer_keep_surfaces(&g, &err));
    CHECK(gbuffer_surface_bytes(&g) == 40 * 32 * sizeof(struct gbuffer_surface));
    struct gbuffer_frame f = {.scene = s, .camera = &s->camera, .seed = 5, .frame = 2, .threads = 2};
    CHECK(gbuffer_render(&g, &f, NULL, &err));
    CHECK(check_kept_surfaces(&g, s) < 40 * 32);

    int light = scene_find_shape(s, "ceiling_light");
    CHECK(light >= 0);
    struct scene_shape_override ov = {.shape = (uint32_t)light, .has_to_world = true};
    ov.to_world = xform_identity();
    ov.to_world.m[1][3] = -120.0f;
    ov.to_world.m[0][2] = 0.3f;  /* sheared, so the normal goes through the inverse transpose */
    struct scene *d = light >= 0 ? scene_derive(s, &ov, 1, &err) : NULL;
    CHECK_MSG(d != NULL, "%s", err.message);
    if (d) {
        f.scene = d;
        CHECK(gbuffer_render(&g, &f, NULL, &err));
        uint32_t on_light = 0;
        for (uint32_t i = 0; i < 40 * 32; i++) on_light += isfinite(g.px[i].t) && g.px[i].shape == (uint32_t)light;
        CHECK(on_light > 0);
        check_kept_surfaces(&g, d);
        scene_release(d);
    }

    /* Looking away from the box: every ray escapes, every pixel is marked. */
    struct camera_desc away = s->camera;
    away.look_at = vec3_sub(away.position, vec3_sub(away.look_at, away.position));
    f.scene = s;
    f.camera = &away;
    CHECK(gbuffer_render(&g, &f, NULL, &err));
    CHECK(check_kept_surfaces(&g, s) == 40 * 32);
    gbuffer_destroy(&g);
    scene_release(s);
}

/* A pixel with a history: counts it in *kept, its previous pixel in *landed the first time one
 * lands there (landed_on marks them, w wide), checks its share is in (0, 1] and returns it. */
static double share_landed(const struct gbuffer_pixel *gp, uint32_t w, uint8_t *landed_on, uint32_t *kept,
                           uint32_t *landed)
{
    CHECK_MSG(gp->prev_share > 0.0f && gp->prev_share <= 1.0f, "share %g", (double)gp->prev_share);
    (*kept)++;
    const size_t q = (size_t)(uint32_t)gp->prev_y * w + (uint32_t)gp->prev_x;
    *landed += !landed_on[q];
    landed_on[q] = 1;
    return gp->prev_share;
}

/* Renders `cur` after `prev` (same scene), with the history check or without; returns the sum of the kept
 * pixels' shares and sets *landed to the number of distinct previous pixels they point into, and
 * counts over the hit pixels whose point projects into the previous image: *onscreen all of them,
 * *kept those kept, *occluded those kept although the previous camera's ray towards the point
 * hits another shape (the check must drop every one), *dropped_visible those dropped although
 * that ray reaches the point. */
static double history_run(const struct scene *s, const struct camera_desc *prev, const struct camera_desc *cur,
                          bool check, uint32_t w, uint32_t h, uint32_t *landed, uint32_t *onscreen, uint32_t *kept,
                          uint32_t *occluded, uint32_t *dropped_visible)
{
    struct gbuffer g[2];
    struct err err = {0};
    CHECK(gbuffer_init(&g[0], w, h, &err) && gbuffer_init(&g[1], w, h, &err));
    struct gbuffer_frame f = {.scene = s, .camera = prev, .seed = 7, .frame = 1, .threads = 2};
    CHECK(gbuffer_render(&g[0], &f, NULL, &err));
    f = (struct gbuffer_frame){.scene = s, .camera = cur, .prev_scene = s, .prev_camera = prev, .seed = 7,
                               .frame = 2, .threads = 2, .prev_gbuffer = &g[0], .check_history = check};
    CHECK(gbuffer_render(&g[1], &f, NULL, &err));
    struct camera cc, pc;
    camera_init(&cc, cur, w, h);
    camera_init(&pc, prev, w, h);
    uint8_t *hit_prev = calloc((size_t)w * h, 1);
    double share = 0.0;
    *landed = *onscreen = *kept = *occluded = *dropped_visible = 0;
    struct ray_counters rc = {0, 0};
    for (uint32_t i = 0; hit_prev && i < w * h; i++) {
        const struct gbuffer_pixel *gp = &g[1].px[i];
        if (!isfinite(gp->t)) continue;
        /* The reprojected point, traced from the previous camera without the check. */
        struct vec3 d = camera_ray_dir(&cc, (float)(i % w) + gp->jx, (float)(i / w) + gp->jy);
        struct vec3 p = vec3_madd(cc.position, d, gp->t);
        float px, py;
        if (!camera_project(&pc, p, &px, &py) || !(px >= 0 && py >= 0 && px < (float)w && py < (float)h)) continue;
        (*onscreen)++;
        struct vec3 to = vec3_sub(p, pc.position);
        struct hit h1;
        bool seen = accel_intersect(s->accel, pc.position, vec3_normalize(to), 0, INFINITY, &h1, &rc) &&
                    h1.shape == gp->shape && fabsf(h1.t - vec3_length(to)) < 1e-3f * vec3_length(to);
        if (isfinite(gp->prev_x)) {
            share += share_landed(gp, w, hit_prev, kept, landed);
            *occluded += !seen && h1.shape != gp->shape;
        } else {
            *dropped_visible += seen;
        }
    }
    free(hit_prev);
    gbuffer_destroy(&g[0]);
    gbuffer_destroy(&g[1]);
    return share;
}

static void test_history_check(void)
{
    struct scene *s = fixture_load("scenes/cornell-box/scene.json");
    if (!s) return;
    uint32_t landed, on, kept, occluded, dropped;
    /* The same camera and scene: the check does not apply (gbuffer_render), every pixel keeps all
     * of its history. */
    double sum = history_run(s, &s->camera, &s->camera, true, 64, 48, &landed, &on, &kept, &occluded, &dropped);
    CHECK_MSG(kept == on && sum == (double)kept, "kept %u of %u, shares sum to %.1f", kept, on, sum);
    /* The camera halfway to the box: each previous pixel is the history of about 2-4 current ones
     * (their areas on the walls), and their shares add up to about one per previous pixel. */
    struct camera_desc near = s->camera;
    near.position = vec3_madd(near.position, vec3_normalize(vec3_sub(near.look_at, near.position)), 450.0f);
    sum = history_run(s, &s->camera, &near, true, 96, 80, &landed, &on, &kept, &occluded, &dropped);
    CHECK_MSG(kept > on * 9 / 10, "kept %u of %u", kept, on);
    CHECK_MSG(landed < kept / 2 && fabs(sum / landed - 1.0) < 0.15,
              "shares sum to %.1f over %u previous pixels (%u kept)", sum, landed, kept);
    /* The camera moved sideways and up: the tall box uncovers wall and floor. Without the check
     * many pixels point into a previous pixel that saw the box; with it almost none (a previous
     * pixel astride the box's silhouette whose own ray hit the wall keeps its history, rightly),
     * and of the points seen then, few are dropped (edges between walls). */
    struct camera_desc side = s->camera;
    side.position = vec3_add(side.position, vec3_make(-260, 120, 100));
    uint32_t occluded_unchecked;
    history_run(s, &s->camera, &side, false, 96, 80, &landed, &on, &kept, &occluded_unchecked, &dropped);
    sum = history_run(s, &s->camera, &side, true, 96, 80, &landed, &on, &kept, &occluded, &dropped);
    printf("    history check after a side step: %u of %u kept, %u of them occluded then (%u unchecked), "
           "%u seen then dropped\n", kept, on, occluded, occluded_unchecked, dropped);
    CHECK_MSG(occluded_unchecked > 20 * occluded + 100 && dropped < kept / 20,
              "%u occluded kept (%u unchecked), %u visible dropped of %u kept", occluded, occluded_unchecked, dropped,
              kept);
    scene_release(s);
}

/* A wall that was half its size in the previous frame (scaled about its centre, camera still):
 * every previous pixel is the history of about four current ones, so their shares must add up
 * to about one per previous pixel — which the areas alone (the same world area under the same
 * camera) would not give; the area ratio of the shape's change does. */
static void test_history_share_of_a_scaled_shape(void)
{
    struct scene *s = fixture_load_json(
        "{\"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], \"fov_deg\": 40},"
        " \"materials\": {\"grey\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]},"
        "   \"light\": {\"type\": \"diffuse\", \"albedo\": [0, 0, 0], \"emission\": [1, 1, 1]}},"
        " \"shapes\": [{\"type\": \"quad\", \"name\": \"wall\", \"material\": \"grey\","
        "   \"vertices\": [[-4, -4, 0], [4, -4, 0], [4, 4, 0], [-4, 4, 0]]},"
        "  {\"type\": \"quad\", \"material\": \"light\","
        "   \"vertices\": [[-1, 5, -3], [1, 5, -3], [1, 5, -1], [-1, 5, -1]]}]}",
        NULL);
    if (!s) return;
    struct err err = {0};
    struct scene_shape_override ov = {.shape = (uint32_t)scene_find_shape(s, "wall"), .has_to_world = true};
    ov.to_world = xform_identity();
    ov.to_world.m[0][0] = ov.to_world.m[1][1] = 0.5f;
    struct scene *small = scene_derive(s, &ov, 1, &err);
    CHECK_MSG(small != NULL, "%s", err.message);
    enum { W = 64 };
    struct gbuffer g[2];
    CHECK(small && gbuffer_init(&g[0], W, W, &err) && gbuffer_init(&g[1], W, W, &err));
    if (small && g[0].px && g[1].px) {
        struct gbuffer_frame f = {.scene = small, .camera = &s->camera, .seed = 3, .frame = 1, .threads = 2};
        CHECK(gbuffer_render(&g[0], &f, NULL, &err));
        f = (struct gbuffer_frame){.scene = s, .camera = &s->camera, .prev_scene = small, .prev_camera = &s->camera,
                                   .seed = 3, .frame = 2, .threads = 2, .prev_gbuffer = &g[0], .check_history = true};
        CHECK(gbuffer_render(&g[1], &f, NULL, &err));
        uint32_t kept = 0, landed = 0;
        static uint8_t landed_on[W * W];
        memset(landed_on, 0, sizeof landed_on);
        double sum = 0.0;
        for (uint32_t i = 0; i < W * W; i++)
            if (isfinite(g[1].px[i].t) && isfinite(g[1].px[i].prev_x))
                sum += share_landed(&g[1].px[i], W, landed_on, &kept, &landed);
        printf("    wall half its size before: %u pixels kept, into %u previous ones, shares sum to %.1f\n", kept,
               landed, sum);
        CHECK_MSG(kept > W * W / 2 && landed < kept / 3, "%u kept into %u", kept, landed);
        CHECK_MSG(fabs(sum / landed - 1.0) < 0.15, "shares sum to %.1f over %u previous pixels", sum, landed);
    }
    gbuffer_destroy(&g[0]);
    gbuffer_destroy(&g[1]);
    if (small) scene_release(small);
    scene_release(s);
}

/* The emission a camera ray through image position (px, py) meets first. */
static struct vec3 seen_emission(const struct scene *s, const struct camera *cam, float px, float py)
{
    struct vec3 dir = camera_ray_dir(cam, px, py);
    struct hit h;
    struct ray_counters rc = {0, 0};
    if (!accel_intersect(s->accel, cam->position, dir, 0.0f, INFINITY, &h, &rc)) return s->env_radiance;
    const struct material *m = &s->materials[s->shapes[h.shape].material];
    return material_is_emissive(m) ? light_sampler_emitted(m, -vec3_dot(dir, h.ng)) : vec3_splat(0.0f);
}

/* Each pixel's mean emission over a dense grid of positions (n x n), and whether the grid saw
 * more than one value (the pixel's area holds an emitter's edge). */
static void emission_truth(const struct scene *s, const struct camera *cam, uint32_t w, uint32_t h, uint32_t n,
                           double *truth, bool *mixed)
{
    for (uint32_t y = 0; y < h; y++) {
        for (uint32_t x = 0; x < w; x++) {
            double sum = 0.0;
            float first = -1.0f;
            bool mix = false;
            for (uint32_t j = 0; j < n; j++) {
                for (uint32_t i = 0; i < n; i++) {
                    float v = seen_emission(s, cam, x + (i + 0.5f) / n, y + (j + 0.5f) / n).x;
                    if (first < 0.0f) first = v;
                    mix |= v != first;
                    sum += v;
                }
            }
            truth[y * w + x] = sum / ((double)n * n);
            mixed[y * w + x] = mix;
        }
    }
}

/* The emission seen directly (gbuffer_keep_emission), on cornell-box's ceiling light and on a
 * light smaller than a pixel that falls between the pixel corners:
 * - every pixel whose area holds the edge (a dense grid sees two values) is an edge pixel, and a
 *   pixel that is not one gets exactly its primary ray's own emission;
 * - over 64 frames an edge pixel's estimate averages to the dense grid's mean (both are within
 *   1-2 % of the light's radiance of the exact coverage);
 * - with 16 rays a frame the frames scatter about the truth at most 0.15x as much as with the
 *   primary ray's own (1 ray: its square error is the coverage's Bernoulli variance). */
static void check_emission(const struct scene *s, uint32_t W, uint32_t H, const char *what)
{
    enum { FRAMES = 64, K = 16, GRID = 96 };
    struct err err = {0};
    struct gbuffer g, one;
    CHECK(gbuffer_init(&g, W, H, &err) && gbuffer_init(&one, W, H, &err));
    CHECK(g.emission == NULL && gbuffer_emission_bytes(&g) == 0);
    CHECK(gbuffer_keep_emission(&g, &err) && gbuffer_keep_emission(&one, &err));
    CHECK(gbuffer_emission_bytes(&g) == gbuffer_emission_bytes_planned(W, H));
    struct camera cam;
    camera_init(&cam, &s->camera, W, H);
    double *truth = calloc((size_t)W * H, sizeof *truth), *mean = calloc((size_t)W * H, sizeof *mean);
    bool *mixed = calloc((size_t)W * H, sizeof *mixed);
    CHECK(truth && mean && mixed);
    if (!truth || !mean || !mixed) goto out;
    emission_truth(s, &cam, W, H, GRID, truth, mixed);
    double le = 0.0;
    for (uint32_t i = 0; i < s->material_count; i++) le = fmax(le, s->materials[i].emission.x);
    double sq_k = 0.0, sq_1 = 0.0;
    uint32_t edges = 0, mixed_n = 0, missed = 0, own_wrong = 0;
    for (uint32_t t = 0; t < FRAMES; t++) {
        struct gbuffer_frame f = {.scene = s, .camera = &s->camera, .seed = 11, .frame = t, .threads = 2,
                                  .stratify = true, .emission_samples = K};
        CHECK(gbuffer_render(&g, &f, NULL, &err));
        f.emission_samples = 1;
        CHECK(gbuffer_render(&one, &f, NULL, &err));
        for (uint32_t i = 0; i < W * H; i++) {
            mean[i] += g.emission[i].x / FRAMES;
            if (!g.edge[i]) {
                /* Not an edge pixel: the primary ray's own emission, the same as with one ray. */
                own_wrong += g.emission[i].x != one.emission[i].x ||
                             g.emission[i].x != seen_emission(s, &cam, (float)(i % W) + g.px[i].jx,
                                                              (float)(i / W) + g.px[i].jy).x;
                continue;
            }
            sq_k += (g.emission[i].x - truth[i]) * (g.emission[i].x - truth[i]);
            sq_1 += (one.emission[i].x - truth[i]) * (one.emission[i].x - truth[i]);
        }
    }
    double worst = 0.0;
    for (uint32_t i = 0; i < W * H; i++) {
        edges += g.edge[i] != 0;
        mixed_n += mixed[i];
        missed += mixed[i] && !g.edge[i];
        if (g.edge[i]) worst = fmax(worst, fabs(mean[i] - truth[i]) / le);
    }
    printf("    %s: %u edge pixels, %u with an edge inside; largest error of the %d-frame mean %.4f of Le; "
           "square error a frame %.3g with %d rays, %.3g with one (ratio %.4f)\n",
           what, edges, mixed_n, FRAMES, worst, sq_k, K, sq_1, sq_1 > 0.0 ? sq_k / sq_1 : NAN);
    CHECK_MSG(mixed_n > 0 && missed == 0, "%s: %u of %u pixels with an edge inside are not edge pixels", what, missed,
              mixed_n);
    CHECK_MSG(own_wrong == 0, "%s: %u values of pixels without an edge differ from their primary ray's", what,
              own_wrong);
    CHECK_MSG(worst < 0.02, "%s: an edge pixel's mean is %.4f of Le off the dense grid's", what, worst);
    CHECK_MSG(sq_k < 0.15 * sq_1, "%s: %d rays a frame leave %.3g of one ray's square error %.3g", what, K, sq_k,
              sq_1);
out:
    free(truth);
    free(mean);
    free(mixed);
    gbuffer_destroy(&g);
    gbuffer_destroy(&one);
}

static void test_emission_seen_directly(void)
{
    struct scene *s = fixture_load("scenes/cornell-box/scene.json");
    if (s) check_emission(s, 32, 32, "cornell-box");
    if (s) scene_release(s);
    /* A light 0.4 pixels across, between the corners of the image's centre pixel. */
    struct scene *tiny = fixture_load_json(
        "{\"format\": 1, \"camera\": {\"position\": [0, 0, -5], \"look_at\": [0, 0, 0], \"up\": [0, 1, 0], "
        "\"fov_deg\": 40}, \"materials\": {\"grey\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]}, "
        "\"lamp\": {\"type\": \"diffuse\", \"albedo\": [0, 0, 0], \"emission\": [50, 50, 50]}}, "
        "\"shapes\": [{\"type\": \"quad\", \"material\": \"grey\", \"vertices\": [[-9, -9, 2], [-9, 9, 2], "
        "[9, 9, 2], [9, -9, 2]]}, {\"type\": \"sphere\", \"material\": \"lamp\", \"center\": [0.03, 0.012, 0], "
        "\"radius\": 0.022}]}",
        ".");
    if (tiny) check_emission(tiny, 31, 31, "a light smaller than a pixel");
    if (tiny) scene_release(tiny);
}

/* The edge pixels of a G-buffer that has seen camera A, then B, then a scene whose light moved
 * (another scene, maybe at the same address) equal those of a fresh G-buffer for each; the
 * session's other G-buffer, which shares them (gbuffer_share_emission), uses them without a corner
 * ray; and an edge pixel takes the largest power of two of rays within emission_samples
 * and the pixels per edge pixel (a 6 x 6 image, where edges are a third of the pixels, takes 2). */
static uint64_t edge_frame(struct gbuffer *g, const struct scene *s, const struct camera_desc *cam,
                           const struct gbuffer *other, uint32_t k)
{
    struct err err = {0};
    uint64_t rays = 0;
    struct gbuffer_frame f = {.scene = s, .camera = cam, .seed = 2, .frame = 3, .threads = 2, .stratify = true,
                              .emission_samples = k, .prev_gbuffer = other, .prev_scene = other ? s : NULL,
                              .prev_camera = other ? cam : NULL};
    CHECK_MSG(gbuffer_render(g, &f, &rays, &err), "%s", err.message);
    return rays;
}

static uint32_t edge_count(const struct gbuffer *g)
{
    uint32_t n = 0;
    for (uint32_t i = 0; i < g->width * g->height; i++) n += g->edge[i] != 0;
    return n;
}

static void test_emission_edges_follow_the_camera(void)
{
    struct scene *s = fixture_load("scenes/cornell-box/scene.json");
    if (!s) return;
    enum { W = 48, H = 40 };
    struct err err = {0};
    struct gbuffer g, fresh, other;
    CHECK(gbuffer_init(&g, W, H, &err) && gbuffer_init(&fresh, W, H, &err) && gbuffer_init(&other, W, H, &err));
    CHECK(gbuffer_keep_emission(&g, &err) && gbuffer_keep_emission(&fresh, &err));
    gbuffer_share_emission(&other, &g);   /* a session's other G-buffer */
    CHECK(gbuffer_emission_bytes(&other) == 0 && other.emission == g.emission);
    struct camera_desc a = s->camera, b = s->camera;
    b.position.x += 60.0f;
    b.look_at.y += 40.0f;
    edge_frame(&g, s, &a, NULL, 16);
    static uint8_t edges_a[W * H];
    memcpy(edges_a, g.edge, sizeof edges_a);
    CHECK(edge_count(&g) > 0);
    edge_frame(&g, s, &b, NULL, 16);
    edge_frame(&fresh, s, &b, NULL, 16);
    CHECK_MSG(memcmp(g.edge, fresh.edge, W * H) == 0 && memcmp(g.edge, edges_a, W * H) != 0,
              "camera B: %u edge pixels, a fresh G-buffer %u", edge_count(&g), edge_count(&fresh));
    edge_frame(&g, s, &a, NULL, 16);
    CHECK(memcmp(g.edge, edges_a, W * H) == 0);

    /* The other G-buffer shares the edges: the primary rays and the edge pixels' own, no corner ray. */
    const uint64_t copied = edge_frame(&other, s, &a, &g, 16);
    CHECK(memcmp(other.edge, edges_a, W * H) == 0);
    CHECK_MSG(copied == (uint64_t)W * H + 16u * edge_count(&g), "%llu rays, expected %u + 16 x %u",
              (unsigned long long)copied, W * H, edge_count(&g));
    const uint64_t own = edge_frame(&fresh, s, &a, NULL, 16);
    CHECK_MSG(own > copied, "a G-buffer that finds its edges traced %llu rays, one that copies them %llu",
              (unsigned long long)own, (unsigned long long)copied);

    /* The light moved: another scene, so the edges are found again. */
    int light = scene_find_shape(s, "ceiling_light");
    CHECK(light >= 0);
    struct scene_shape_override ov = {.shape = (uint32_t)light, .has_to_world = true};
    ov.to_world = xform_identity();
    ov.to_world.m[0][3] = 120.0f;
    struct scene *d = light >= 0 ? scene_derive(s, &ov, 1, &err) : NULL;
    CHECK_MSG(d != NULL, "%s", err.message);
    if (d) {
        CHECK(d->serial != s->serial);
        edge_frame(&g, d, &a, NULL, 16);
        edge_frame(&fresh, d, &a, NULL, 16);
        CHECK(memcmp(g.edge, fresh.edge, W * H) == 0 && memcmp(g.edge, edges_a, W * H) != 0);
        scene_release(d);
    }

    /* The cap: at 6 x 6 about a third of the pixels are edge pixels. */
    struct gbuffer tiny;
    CHECK(gbuffer_init(&tiny, 6, 6, &err) && gbuffer_keep_emission(&tiny, &err));
    edge_frame(&tiny, s, &a, NULL, 16);
    const uint32_t e = edge_count(&tiny);
    uint32_t cap = 1;
    while (cap * 2 <= 36 / e) cap *= 2;
    CHECK_MSG(e > 4 && tiny.edges->samples == cap && cap < 16, "%u edge pixels of 36: cap %u, expected %u", e,
              tiny.edges->samples, cap);
    const uint64_t rays = edge_frame(&tiny, s, &a, NULL, 16);
    CHECK_MSG(rays == 36u + (uint64_t)cap * e, "%llu rays for %u edge pixels at %u", (unsigned long long)rays, e, cap);
    gbuffer_destroy(&tiny);
    gbuffer_destroy(&g);
    gbuffer_destroy(&fresh);
    gbuffer_destroy(&other);
    scene_release(s);
}

TEST_MAIN(TEST(test_camera_project_round_trip), TEST(test_motion_vectors), TEST(test_jitter_deterministic),
          TEST(test_jitter_walk), TEST(test_fresh_positions_stratified), TEST(test_kept_surfaces), TEST(test_history_check),
          TEST(test_history_share_of_a_scaled_shape), TEST(test_emission_seen_directly),
          TEST(test_emission_edges_follow_the_camera))
