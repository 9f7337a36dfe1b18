/* test_restir_sms.c — the manifold shift of restir_sms as round trips (tests/README.md, unit
 * tests; docs/methods.md, restir_sms): for samples drawn by the initial pass (the sms_ssp
 * sampler) on refractive-slab (a two-interface chain through a glass slab) and reflective-plane
 * (one reflection), a shift to a pixel a few pixels away (and to the previous frame's pixel with the
 * camera moved) that succeeds is undone by the shift back: the same chain vertices (within 1e-4
 * of |x1 − x2|), the same light point, the same contribution, and Jacobians whose product is 1
 * within 1e-4. A shift to the sample's own pixel reproduces the stored chain and contribution.
 * Far shifts (beyond what 5 Newton steps reach) must fail rather than land on another chain.
 * Parameters are checked with their expected pointers; the session's bytes planned == allocated. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "integrators/restir_sms.h"
#include "scene/scene.h"
#include "jitter_moves.h"
#include "session_buffers.h"
#include "test.h"
#include "scene_fixture.h"
#include "session/view.h"

struct tally {
    int tried, forward_ok, round_trips, failures, nontrivial_j;
    double worst_j, worst_pos;
};

static bool close_rel(struct vec3 a, struct vec3 b, double tol)
{
    double scale = fmax(fmax(fabs(a.x), fabs(a.y)), fabs(a.z));
    return fabs(a.x - b.x) <= tol * scale && fabs(a.y - b.y) <= tol * scale && fabs(a.z - b.z) <= tol * scale;
}

/* The largest distance between corresponding chain vertices and light points of a and b,
 * relative to the first segment's length of a. */
static double chain_gap(const struct restir_sms_info *a, const struct restir_sms_info *b, struct vec3 x1)
{
    if (a->length != b->length || a->caster != b->caster || a->light_shape != b->light_shape) return INFINITY;
    double d = vec3_length(vec3_sub(a->light_p, b->light_p));
    for (uint32_t i = 0; i < a->length; i++) d = fmax(d, vec3_length(vec3_sub(a->chain[i], b->chain[i])));
    return d / vec3_length(vec3_sub(a->chain[0], x1));
}

static void round_trip(const void *ctx, const uint8_t *elem, struct restir_domain from, struct restir_domain to,
                       struct vec3 x1, struct tally *t)
{
    const struct restir_ops *ops = &restir_sms_ops;
    _Alignas(16) uint8_t y[RESTIR_MAX_STRIDE], x2[RESTIR_MAX_STRIDE];
    struct restir_counters c = {0};
    float t1, j1, t2, j2;
    t->tried++;
    ops->shift(ctx, elem, from, to, y, &t1, &j1, &c);
    if (!(t1 > 0.0f)) return;
    t->forward_ok++;
    ops->shift(ctx, y, to, from, x2, &t2, &j2, &c);
    struct restir_sms_info a, b;
    restir_sms_info(ctx, elem, &a);
    restir_sms_info(ctx, x2, &b);
    double gap = chain_gap(&a, &b, x1);
    double jp = fabs((double)j1 * j2 - 1.0);
    if (t2 > 0.0f && gap > t->worst_pos) t->worst_pos = gap;
    if (t2 > 0.0f && jp > t->worst_j) t->worst_j = jp;
    bool ok = t2 > 0.0f && gap <= 1e-4 && close_rel(a.F, b.F, 1e-3) && jp <= 1e-4;
    if (!ok) {
        if (t->failures++ < 5)
            fprintf(stderr, "  round trip %u -> %u: back target %g, gap %g, F %g -> %g, J %g * %g\n", from.pixel, to.pixel,
                    (double)t2, gap, (double)a.F.x, (double)b.F.x, (double)j1, (double)j2);
        return;
    }
    t->round_trips++;
    if (fabs((double)j1 - 1.0) > 1e-3) t->nontrivial_j++;
}

static void shift_case(const char *scene_path, bool temporal, int offset, bool expect_success, bool scale_light)
{
    struct scene *base = fixture_load(scene_path);
    if (!base) return;
    struct scene *sc = base;
    if (scale_light) {
        /* The current frame's warm light 1.3x wider about its centre (x = -0.3): the emitter's area
         * element changes between the frames, so the light point's Jacobian is 1.3 / 1 / 1.3. */
        int li = scene_find_shape(base, "warm_light");
        CHECK(li >= 0);
        struct scene_shape_override ov = {.shape = (uint32_t)li, .has_to_world = true,
                                          .to_world = base->shapes[li].to_world};
        ov.to_world.m[0][0] *= 1.3f;
        ov.to_world.m[0][3] = ov.to_world.m[0][3] * 1.3f + 0.09f;
        struct err derr = {0};
        sc = scene_derive(base, &ov, 1, &derr);
        CHECK_MSG(sc != NULL, "%s", derr.message);
        if (!sc) {
            scene_release(base);
            return;
        }
    }
    const uint32_t W = 48, H = 36;
    struct restir_sms_params p = restir_sms_defaults();
    struct restir_sms_state st;
    struct err err = {0};
    CHECK(restir_sms_init(&st, sc, &p, W, H, &err));
    struct camera_desc cam0 = sc->camera, cam1 = cam0;
    cam1.position.x += 0.03f;
    cam1.look_at.x += 0.02f;
    _Alignas(16) static uint8_t ctx[RESTIR_SMS_CTX_BYTES];
    struct method_frame f = {.scene = base, .camera = &cam0, .seed = 7, .frame = 0, .threads = 2};
    CHECK(restir_sms_initial_only(&st, &p, &f, ctx, &err));
    /* The initial pass alone leaves no history: its res[1] is not a finished frame's. */
    CHECK(!st.rs.has_history);
    if (temporal) {
        /* The history must exist for the previous G-buffer to be kept. */
        st.rs.has_history = true;
        f = (struct method_frame){.scene = sc, .camera = &cam1, .prev_scene = base, .prev_camera = &cam0, .seed = 7,
                                      .frame = 1, .threads = 2};
        CHECK(restir_sms_initial_only(&st, &p, &f, ctx, &err));
    }
    const struct restir_sms_receiver *recv = st.recv[st.rs.cur];
    int through_glass = 0;
    struct tally t = {0};
    int identity_ok = 0, identity_tried = 0;
    const size_t stride = restir_sms_ops.stride;
    /* Every reservoir layer's rows in turn (one per light on the slab). */
    for (uint32_t row = 0; row < H * st.rs.layers; row++) {
        const uint32_t y = row % H, layer = row / H;
        for (uint32_t x = 0; x < W; x++) {
            uint32_t pixel = y * W + x;
            const uint8_t *elem = st.rs.res[0] + ((size_t)layer * W * H + pixel) * stride;
            if (!(((const struct restir_head *)elem)->W > 0.0f)) continue;
            struct restir_sms_info li;
            restir_sms_info(ctx, elem, &li);
            CHECK(restir_sms_light_reservoir(temporal ? sc : base, li.light_shape, st.rs.layers) == layer);
            struct restir_domain from = {pixel, RESTIR_CURRENT};
            struct surface s1;
            surface_at(sc, recv[pixel].shape, recv[pixel].prim, recv[pixel].b1, recv[pixel].b2, &s1);
            if (recv[pixel].depth > 0) through_glass++;
            /* Identity: the stored chain and contribution come back. */
            _Alignas(16) uint8_t same[RESTIR_MAX_STRIDE];
            float ts, js;
            struct restir_counters c = {0};
            restir_sms_ops.shift(ctx, elem, from, from, same, &ts, &js, &c);
            struct restir_sms_info a, b;
            restir_sms_info(ctx, elem, &a);
            restir_sms_info(ctx, same, &b);
            identity_tried++;
            if (ts > 0.0f && chain_gap(&a, &b, s1.p) <= 1e-4 && close_rel(a.F, b.F, 1e-3) && fabsf(js - 1.0f) < 1e-4f)
                identity_ok++;
            if (temporal) {
                round_trip(ctx, elem, from, (struct restir_domain){pixel, RESTIR_PREVIOUS}, s1.p, &t);
            } else {
                round_trip(ctx, elem, from, (struct restir_domain){y * W + (x + (uint32_t)offset) % W, RESTIR_CURRENT},
                           s1.p, &t);
                round_trip(ctx, elem, from, (struct restir_domain){((y + (uint32_t)offset) % H) * W + x, RESTIR_CURRENT},
                           s1.p, &t);
            }
        }
    }
    printf("     %s%s offset %d: %d samples (%d at receivers behind delta vertices, identity %d), %d shifts tried, %d succeeded, %d round trips "
           "(worst gap %.2g, worst |J J' - 1| %.2g, %d with J != 1), %llu Newton steps\n",
           scene_path, temporal ? " temporal" : "", offset, identity_tried, through_glass, identity_ok, t.tried, t.forward_ok,
           t.round_trips, t.worst_pos, t.worst_j, t.nontrivial_j, (unsigned long long)restir_sms_shift_newton(ctx));
    CHECK(identity_tried > 30);
    CHECK(identity_ok >= identity_tried * 98 / 100);
    if (expect_success) CHECK(t.forward_ok > t.tried / 4);
    /* Every shift that succeeds is undone by the shift back. */
    CHECK_MSG(t.round_trips >= t.forward_ok * 99 / 100, "%d of %d", t.round_trips, t.forward_ok);
    if (scale_light) CHECK(t.nontrivial_j > 10);
    else CHECK(t.nontrivial_j == 0);
    restir_sms_destroy(&st);
    if (sc != base) scene_release(sc);
    scene_release(base);
}

static void test_slab_round_trips(void)
{
    shift_case("scenes/refractive-slab/scene.json", false, 1, true, false);
    shift_case("scenes/refractive-slab/scene.json", false, 3, true, false);
}
static void test_plane_round_trips(void) { shift_case("scenes/reflective-plane/scene.json", false, 2, true, false); }
static void test_temporal_round_trips(void)
{
    shift_case("scenes/refractive-slab/scene.json", true, 0, true, false);
    shift_case("scenes/reflective-plane/scene.json", true, 0, true, false);
}
/* Temporal with the light scaled between the frames: non-trivial Jacobians that still multiply
 * to 1 over a round trip. */
static void test_scaled_light_jacobians(void) { shift_case("scenes/refractive-slab/scene.json", true, 0, true, true); }
/* 17 pixels apart many walks need more than 5 Newton steps or land on another solution: those
 * shifts must fail, never return a chain that does not walk back. */
static void test_far_shifts_fail_cleanly(void)
{
    shift_case("scenes/refractive-slab/scene.json", false, 17, false, false);
}

static void test_params(void)
{
    struct restir_sms_params p = restir_sms_defaults();
    struct err err = {0};
    CHECK(restir_sms_params_valid(&p, &err));
    CHECK(p.shift_iterations == 5 && p.spatial_neighbors == 1 && p.spatial_radius == 30.0f && p.temporal_cap == 20 &&
          p.temporal && p.ssp.tiles == 16 && p.ssp.alpha == 0.8f);
    p.shift_iterations = 0;
    CHECK(!restir_sms_params_valid(&p, &err) && strcmp(err.where, "/params/shift_iterations") == 0);
    p = restir_sms_defaults();
    p.ssp.tiles = 2;
    CHECK(!restir_sms_params_valid(&p, &err) && strcmp(err.where, "/params/tiles") == 0);
    p = restir_sms_defaults();
    p.spatial_radius = 0.0f;
    CHECK(!restir_sms_params_valid(&p, &err) && strcmp(err.where, "/params/spatial_radius") == 0);
    p = restir_sms_defaults();
    CHECK(p.jitter_walk == 0.1f);
    p.jitter_walk = 0.5f;
    CHECK(restir_sms_params_valid(&p, &err));
    p.jitter_walk = 0.6f;
    CHECK(!restir_sms_params_valid(&p, &err) && strcmp(err.where, "/params/jitter_walk") == 0);
    p.jitter_walk = NAN;
    CHECK(!restir_sms_params_valid(&p, &err) && strcmp(err.where, "/params/jitter_walk") == 0);
    p = restir_sms_defaults();
    CHECK(p.light_reservoirs == RESTIR_SMS_LIGHT_RESERVOIRS_BY_SCENE);
    p.light_reservoirs = RESTIR_SMS_MAX_LIGHT_RESERVOIRS;
    CHECK(restir_sms_params_valid(&p, &err));
    p.light_reservoirs = RESTIR_SMS_MAX_LIGHT_RESERVOIRS + 1;
    CHECK(!restir_sms_params_valid(&p, &err) && strcmp(err.where, "/params/light_reservoirs") == 0);
}

/* Reservoirs per light: by default one per emissive shape (the slab's two lights, the plane's
 * one), each light's paths in the reservoir of its rank; an explicit count is kept. */
static void test_light_reservoirs(void)
{
    struct scene *slab = fixture_load("scenes/refractive-slab/scene.json");
    struct scene *plane = fixture_load("scenes/reflective-plane/scene.json");
    if (!slab || !plane) {
        if (slab) scene_release(slab);
        if (plane) scene_release(plane);
        return;
    }
    struct restir_sms_params p = restir_sms_defaults();
    CHECK(restir_sms_layers(&p, slab) == 2 && restir_sms_layers(&p, plane) == 1);
    p.light_reservoirs = 3;
    CHECK(restir_sms_layers(&p, slab) == 3 && restir_sms_layers(&p, plane) == 3);
    int warm = scene_find_shape(slab, "warm_light"), cool = scene_find_shape(slab, "cool_light");
    CHECK(warm >= 0 && cool >= 0);
    if (warm >= 0 && cool >= 0) {
        CHECK(restir_sms_light_reservoir(slab, (uint32_t)warm, 2) == 0 && restir_sms_light_reservoir(slab, (uint32_t)cool, 2) == 1);
        CHECK(restir_sms_light_reservoir(slab, (uint32_t)cool, 1) == 0);
        /* The warm light switched off in a frame's scene: the cool light's paths stay in the
         * second reservoir and the count stays 2 (ranked in the scene as loaded), so no reservoir
         * mixes one light's history with another's candidates. */
        struct scene_shape_override off = {.shape = (uint32_t)warm, .has_emission = true};
        struct err derr = {0};
        struct scene *dark = scene_derive(slab, &off, 1, &derr);
        CHECK_MSG(dark != NULL, "%s", derr.message);
        if (dark) {
            CHECK(!material_is_emissive(&dark->materials[dark->shapes[warm].material]));
            CHECK(restir_sms_light_reservoir(dark, (uint32_t)cool, 2) == 1);
            CHECK(restir_sms_layers(&(struct restir_sms_params){0}, dark) == 2);
            scene_release(dark);
        }
    }
    /* On the plane's one light a second reservoir stays empty: the frames are bit for bit those
     * of one reservoir (it adds nothing, and its passes draw from no stream the other uses). */
    enum { W = 24, H = 24 };
    struct image img[2];
    for (int k = 0; k < 2; k++) {
        struct restir_sms_params q = restir_sms_defaults();
        q.sampler = RESTIR_SMS_SAMPLER_SMS;
        q.light_reservoirs = (uint32_t)k + 1;
        struct restir_sms_state st;
        struct err err = {0};
        CHECK(restir_sms_init(&st, plane, &q, W, H, &err) && image_init(&img[k], W, H, &err));
        for (uint32_t t = 0; t < 3; t++) {
            struct method_frame f = {.scene = plane, .camera = &plane->camera, .prev_scene = t ? plane : NULL,
                                         .prev_camera = &plane->camera, .seed = 5, .frame = t, .threads = 2};
            CHECK_MSG(restir_sms_render(&st, &q, &f, &img[k], NULL, &err), "%s", err.message);
        }
        restir_sms_destroy(&st);
    }
    double lit = 0.0;
    bool same = true;
    for (uint32_t i = 0; i < W * H; i++) {
        same = same && memcmp(&img[0].pixels[i], &img[1].pixels[i], sizeof img[0].pixels[i]) == 0;
        lit += img[0].pixels[i].x;
    }
    CHECK(same);
    CHECK(lit > 0.0);
    image_destroy(&img[0]);
    image_destroy(&img[1]);
    scene_release(slab);
    scene_release(plane);
}

/* Planned = allocated, and the buffers follow the parameters: the prior only for the ssp
 * sampler, the pair scratch only for paired spatial reuse. */
static void test_session_bytes_planned_match_allocated(void)
{
    struct scene *sc = fixture_load("scenes/refractive-slab/scene.json");
    if (!sc) return;
    for (int variant = 0; variant < 4; variant++) {
        struct view_params vp = view_params_defaults(method_find("restir_sms"), 37, 23);
        if (variant == 1) VIEW_METHOD_PARAMS(&vp, struct restir_sms_params)->sampler = RESTIR_SMS_SAMPLER_SMS;
        if (variant == 2) VIEW_METHOD_PARAMS(&vp, struct restir_sms_params)->paired_spatial = false;
        if (variant == 3) VIEW_METHOD_PARAMS(&vp, struct restir_sms_params)->light_reservoirs = 1;
        struct view v;
        struct err err = {0};
        CHECK(view_init(&v, sc, &vp, 1, &err));
        struct session_buffers sb;
        CHECK(session_buffers_agree(&v, &vp, sc, &sb));
        /* One reservoir per light by default: the slab has two. */
        CHECK(session_buffer(&sb, "reservoirs") == 2u * 37 * 23 * RESTIR_SMS_RESERVOIR_BYTES * (variant == 3 ? 1 : 2));
        CHECK(VIEW_METHOD_PARAMS(&v.params, struct restir_sms_params)->light_reservoirs == (variant == 3 ? 1u : 2u));  /* what the session reports */
        CHECK((session_buffer(&sb, "prior") > 0) == (variant != 1));
        CHECK(session_buffer(&sb, "spatial_pairs") == (variant != 2 ? restir_pair_scratch_bytes(37, 23) : 0));
        struct frame_stats fs = {0};
        CHECK(view_render(&v, NULL, &fs, NULL, NULL, &err));
        CHECK(view_render(&v, NULL, &fs, NULL, NULL, &err));
        const struct restir_sms_stats *ms = (const struct restir_sms_stats *)(const void *)fs.counters;
        CHECK(ms->pass.shifts > 0 && ms->shift_newton > 0 && fs.render.sms.samples > 0);
        view_destroy(&v);
    }
    /* A render asking for what the session was not made for is refused, naming the parameter. */
    struct restir_sms_params made = restir_sms_defaults(), asked = made;
    made.sampler = RESTIR_SMS_SAMPLER_SMS;
    made.paired_spatial = false;
    struct restir_sms_state st;
    struct err err = {0};
    CHECK(restir_sms_init(&st, sc, &made, 8, 8, &err));
    struct image out;
    CHECK(image_init(&out, 8, 8, &err));
    struct method_frame f = {.scene = sc, .camera = &sc->camera, .seed = 1, .threads = 1};
    CHECK(!restir_sms_render(&st, &asked, &f, &out, NULL, &err) && strcmp(err.where, "/params/sampler") == 0);
    asked.sampler = RESTIR_SMS_SAMPLER_SMS;
    CHECK(!restir_sms_render(&st, &asked, &f, &out, NULL, &err) && strcmp(err.where, "/params/paired_spatial") == 0);
    asked.paired_spatial = false;
    asked.light_reservoirs = 1;
    CHECK(!restir_sms_render(&st, &asked, &f, &out, NULL, &err) && strcmp(err.where, "/params/light_reservoirs") == 0);
    asked.light_reservoirs = RESTIR_SMS_LIGHT_RESERVOIRS_BY_SCENE;
    /* The session keeps a restir_pt rest (by_scene on the slab): a render asking for pt's is refused. */
    asked.rest = RESTIR_SMS_REST_PT;
    CHECK(!restir_sms_render(&st, &asked, &f, &out, NULL, &err) && strcmp(err.where, "/params/rest") == 0);
    asked.rest = RESTIR_SMS_REST_BY_SCENE;
    CHECK(restir_sms_render(&st, &asked, &f, &out, NULL, &err));
    image_destroy(&out);
    restir_sms_destroy(&st);
    scene_release(sc);
}

/* The session's jitter_walk reaches its G-buffer: with the default each pixel's primary ray moves
 * by at most 0.1 pixels per axis between consecutive frames; with 0 most move further (a fresh
 * position every frame); after a reset the walk starts afresh. */
static void test_jitter_walk_reaches_the_gbuffer(void)
{
    struct scene *sc = fixture_load("scenes/reflective-plane/scene.json");
    if (!sc) return;
    enum { W = 16, H = 16, N = W * H };
    for (int walk = 0; walk < 2; walk++) {
        struct restir_sms_params p = restir_sms_defaults();
        p.sampler = RESTIR_SMS_SAMPLER_SMS;
        p.ssp.sms.caustics_only = true;
        if (!walk) p.jitter_walk = 0.0f;
        struct restir_sms_state st;
        struct err err = {0};
        struct image out;
        CHECK(restir_sms_init(&st, sc, &p, W, H, &err) && image_init(&out, W, H, &err));
        float jx[N], jy[N], worst = 0.0f;
        for (uint32_t t = 0; t < 3; t++) {
            struct method_frame f = {.scene = sc, .camera = &sc->camera, .prev_scene = t ? sc : NULL,
                                         .prev_camera = &sc->camera, .seed = 4, .frame = t, .threads = 1};
            CHECK_MSG(restir_sms_render(&st, &p, &f, &out, NULL, &err), "%s", err.message);
            worst = fmaxf(worst, jitter_largest_move(st.rs.gbuf[st.rs.cur].px, N, jx, jy, t == 0));
        }
        if (walk) CHECK_MSG(worst <= 0.1f * (1.0f + 1e-6f), "walk 0.1: largest move %g", worst);
        else CHECK_MSG(worst > 0.5f, "no walk: largest move only %g", worst);
        /* After a reset the first frame has no history: its positions are drawn afresh. */
        restir_session_reset(&st.rs);
        struct method_frame f = {.scene = sc, .camera = &sc->camera, .prev_scene = sc, .prev_camera = &sc->camera,
                                     .seed = 4, .frame = 3, .threads = 1};
        CHECK(restir_sms_render(&st, &p, &f, &out, NULL, &err));
        float moved = 0.0f;
        for (uint32_t i = 0; i < N; i++) moved = fmaxf(moved, fabsf(st.rs.gbuf[st.rs.cur].px[i].jx - jx[i]));
        CHECK_MSG(moved > 0.5f, "after a reset: largest move only %g", moved);
        image_destroy(&out);
        restir_sms_destroy(&st);
    }
    scene_release(sc);
}

TEST_MAIN(TEST(test_slab_round_trips), TEST(test_plane_round_trips), TEST(test_temporal_round_trips), TEST(test_scaled_light_jacobians),
          TEST(test_far_shifts_fail_cleanly), TEST(test_params),
          TEST(test_session_bytes_planned_match_allocated), TEST(test_jitter_walk_reaches_the_gbuffer),
          TEST(test_light_reservoirs))
