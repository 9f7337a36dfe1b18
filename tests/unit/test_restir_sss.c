/* test_restir_sss.c — the shifts of restir_sss as round trips (tests/README.md, unit tests): for
 * samples drawn by the initial pass on the scene `translucent`, a shift to a neighbouring pixel
 * and back returns the same entry point x2 and contribution (T^-1(T(x)) = x) and the Jacobians
 * multiply to 1 (J * J^-1 = 1 to 1e-4), for the reconnection, delayed reconnection and hybrid
 * shifts (on a turned translucent box and a sphere); the previous frame's pixel with the camera
 * moved likewise. A shift to the sample's own pixel reproduces the stored contribution. Delayed
 * reconnection must show non-trivial Jacobians between pixels a few apart (on the box's faces);
 * reconnection's are exactly 1. The sequential shift's reconnection pass also round-trips the
 * inverted disk numbers and the intersection index (Algorithm 4). Parameters are checked with
 * the expected pointers; the session's bytes planned == allocated. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "integrators/restir_sss.h"
#include "scene/scene.h"
#include "session_buffers.h"
#include "test.h"
#include "scene_fixture.h"
#include "session/view.h"

struct tally {
    int tried, forward_ok, round_trips, nontrivial_jacobians, failures, moved_u, indirect_round_trips;
};

static bool close_rel(struct vec3 a, struct vec3 b, double tol)
{
    double scale = fmax(fmax(fabs(a.x), fabs(a.y)), fabs(a.z));
    return fabs(a.x - b.x) <= tol * scale && fabs(a.y - b.y) <= tol * scale && fabs(a.z - b.z) <= tol * scale;
}

static void round_trip(const void *ctx, const uint8_t *elem, struct restir_domain from, struct restir_domain to,
                       struct tally *t)
{
    const struct restir_ops *ops = &restir_sss_ops;
    _Alignas(16) uint8_t x[RESTIR_MAX_STRIDE], y[RESTIR_MAX_STRIDE], x2[RESTIR_MAX_STRIDE];
    struct restir_counters c = {0};
    float t0, j0, t1, j1, t2, j2;
    t->tried++;
    ops->shift(ctx, elem, from, from, x, &t0, &j0, &c);
    ops->shift(ctx, elem, from, to, y, &t1, &j1, &c);
    if (!(t1 > 0.0f)) return;
    t->forward_ok++;
    ops->shift(ctx, y, to, from, x2, &t2, &j2, &c);
    struct restir_sss_info a, b, m;
    restir_sss_info(ctx, x, from.pixel, &a);
    restir_sss_info(ctx, x2, from.pixel, &b);
    restir_sss_info(ctx, y, to.pixel, &m);
    if (fabsf(m.u_radius - a.u_radius) > 1e-3f || fabsf(m.u_angle - a.u_angle) > 1e-3f) t->moved_u++;
    /* The entry point is compared by its code: equal primitive and barycentrics (or sphere
     * direction code) within 1e-4. */
    bool same_x2 = a.x2_shape == b.x2_shape && a.x2_prim == b.x2_prim && fabsf(a.x2_b1 - b.x2_b1) <= 1e-4f &&
                   fabsf(a.x2_b2 - b.x2_b2) <= 1e-4f;
    /* The disk numbers come back too: the sequential shift re-inverts them at every
     * reconnection (Algorithm 4), the others carry them unchanged. */
    bool same_u = fabsf(a.u_radius - b.u_radius) <= 1e-4f &&
                  fminf(fabsf(a.u_angle - b.u_angle), 1.0f - fabsf(a.u_angle - b.u_angle)) <= 1e-4f;
    bool ok = t0 > 0.0f && t2 > 0.0f && same_x2 && same_u && a.axis == b.axis && a.channel == b.channel &&
              a.hit == b.hit && close_rel(a.F, b.F, 1e-4) && fabs((double)j1 * j2 - 1.0) <= 1e-4;
    if (!ok) {
        if (t->failures++ < 5)
            fprintf(stderr, "  round trip %u -> %u: same x2 %d same u %d (%g %g -> %g %g) hit %d -> %d, F %g -> %g, "
                    "J %g * %g = %g, back target %g\n",
                    from.pixel, to.pixel, same_x2, same_u, (double)a.u_radius, (double)a.u_angle, (double)b.u_radius,
                    (double)b.u_angle, a.hit, b.hit, (double)a.F.x, (double)b.F.x, (double)j1, (double)j2,
                    (double)j1 * j2, (double)t2);
        return;
    }
    t->round_trips++;
    t->indirect_round_trips += a.indirect;
    if (fabs((double)j1 - 1.0) > 1e-4) t->nontrivial_jacobians++;
}

static const struct camera_desc *scene_camera(const struct scene *s) { return &s->camera; }

/* A translucent box turned on two axes beside a translucent sphere, lit from the side: on the
 * box the replayed probe meets faces at other angles than the base path's (a non-trivial
 * delayed-reconnection Jacobian) and crosses edges (shifts that fail); on the sphere it is a
 * rotated copy of the base path (Jacobian 1). */
static const char box_json[] =
    "{\"format\": 1, \"camera\": {\"position\": [0.3, 0.9, 3.2], \"look_at\": [0.3, 0.4, 0], \"up\": [0, 1, 0], "
    "\"fov_deg\": 30},"
    "\"materials\": {\"wax\": {\"type\": \"translucent\", \"albedo\": [0.9, 0.7, 0.5], \"mfp\": [0.08, 0.04, 0.02]},"
    "\"floor\": {\"type\": \"diffuse\", \"albedo\": [0.5, 0.5, 0.5]},"
    "\"lamp\": {\"type\": \"diffuse\", \"albedo\": [0, 0, 0], \"emission\": [20, 20, 20]}},"
    "\"shapes\": [{\"type\": \"quad\", \"material\": \"floor\", \"vertices\": [[-4, 0, -4], [-4, 0, 4], [4, 0, 4], [4, 0, -4]]},"
    "{\"type\": \"box\", \"material\": \"wax\", \"min\": [-0.3, -0.3, -0.3], \"max\": [0.3, 0.3, 0.3],"
    " \"transform\": {\"translate\": [-0.2, 0.5, 0], \"rotate_deg\": [25, 35, 10]}},"
    "{\"type\": \"sphere\", \"material\": \"wax\", \"center\": [0.75, 0.35, 0], \"radius\": 0.35},"
    "{\"type\": \"quad\", \"material\": \"lamp\", \"vertices\": [[2, 0.3, 0.5], [2, 1.3, 0.5], [2, 1.3, -0.5], [2, 0.3, -0.5]]}]}";

static void shift_case(enum restir_sss_shift shift, bool temporal)
{
    struct err lerr = {0};
    struct scene *sc = scene_load_json(box_json, strlen(box_json), ".", &lerr);
    CHECK_MSG(sc != NULL, "%s: %s", lerr.where, lerr.message);
    if (!sc) return;
    if (!scene_commit(sc, &lerr)) {
        CHECK_MSG(false, "%s", lerr.message);
        scene_release(sc);
        return;
    }
    const uint32_t W = 64, H = 48;
    struct restir_sss_params p = restir_sss_defaults();
    p.shift = shift;
    p.candidates = 4;  /* more pixels with a sample */
    struct restir_sss_state st;
    struct err err = {0};
    CHECK(restir_sss_init(&st, sc, &p, W, H, &err));
    /* Temporal: frame 0 with the scene's camera, frame 1 with the camera moved a little; the
     * previous frame's pixels are the domains shifted to. */
    struct camera_desc cam0 = *scene_camera(sc), cam1 = cam0;
    cam1.position.x += 0.02f;
    cam1.look_at.x += 0.02f;
    struct method_frame f0 = {.scene = sc, .camera = &cam0, .seed = 5, .frame = 0, .threads = 2};
    CHECK(restir_sss_initial_only(&st, &p, &f0, &err));
    struct method_frame f = f0;
    if (temporal) {
        /* The history must exist for the previous G-buffer to be kept. */
        st.rs.has_history = true;
        f = (struct method_frame){.scene = sc, .camera = &cam1, .prev_scene = sc, .prev_camera = &cam0,
                                      .seed = 5, .frame = 1, .threads = 2};
        CHECK(restir_sss_initial_only(&st, &p, &f, &err));
    }
    _Alignas(16) uint8_t ctx[RESTIR_SSS_CTX_BYTES];
    restir_sss_bind(&st, &p, &f, ctx);
    struct tally t = {0};
    int identity_ok = 0, identity_tried = 0, indirect = 0, fixed = 0, fixed_failed = 0;
    const size_t stride = restir_sss_ops.stride;
    for (uint32_t y = 0; y < H; y++) {
        for (uint32_t x = 0; x < W; x++) {
            uint32_t pixel = y * W + x;
            const uint8_t *elem = st.rs.res[0] + (size_t)pixel * stride;
            if (!(((const struct restir_head *)elem)->W > 0.0f)) continue;
            struct restir_domain from = {pixel, RESTIR_CURRENT};
            /* Identity: the stored contribution comes back. */
            _Alignas(16) uint8_t same[RESTIR_MAX_STRIDE];
            float ts, js;
            struct restir_counters c = {0};
            restir_sss_ops.shift(ctx, elem, from, from, same, &ts, &js, &c);
            struct restir_sss_info a, b;
            restir_sss_info(ctx, elem, pixel, &a);
            restir_sss_info(ctx, same, pixel, &b);
            indirect += a.indirect;
            if (a.x3_fixed && shift == RESTIR_SSS_DELAYED) {
                /* No delayed shift for an indirect sample whose x3 is not Lambertian. */
                fixed++;
                fixed_failed += !(ts > 0.0f);
                continue;
            }
            identity_tried++;
            if (ts > 0.0f && close_rel(a.F, b.F, 1e-4) && fabsf(js - 1.0f) < 1e-4f) identity_ok++;
            else if (getenv("SSS_DEBUG"))
                fprintf(stderr, "  identity %u: t %g F %g %g %g -> %g %g %g J %g hit %d axis %d ch %d indirect %d\n", pixel, (double)ts,
                        (double)a.F.x, (double)a.F.y, (double)a.F.z, (double)b.F.x, (double)b.F.y, (double)b.F.z,
                        (double)js, a.hit, a.axis, a.channel, a.indirect);
            if (temporal) {
                round_trip(ctx, elem, from, (struct restir_domain){pixel, RESTIR_PREVIOUS}, &t);
            } else {
                /* A few pixels away, so the replayed entry point moves measurably. */
                round_trip(ctx, elem, from, (struct restir_domain){y * W + (x + 4) % W, RESTIR_CURRENT}, &t);
                round_trip(ctx, elem, from, (struct restir_domain){((y + 3) % H) * W + x, RESTIR_CURRENT}, &t);
            }
        }
    }
    printf("     %s%s: %d samples (identity %d; %d indirect), %d shifts tried, %d succeeded, %d round trips (%d "
           "indirect), %d non-trivial J\n",
           restir_sss_shift_name(shift), temporal ? " temporal" : "", identity_tried, identity_ok, indirect, t.tried,
           t.forward_ok, t.round_trips, t.indirect_round_trips, t.nontrivial_jacobians);
    /* Indirect samples (x3 the surface after the entry point) are drawn and shift like the
     * others; under the delayed shift those whose x3 is not Lambertian fail, and only they. */
    CHECK(indirect > 20);
    CHECK(t.indirect_round_trips > 10);
    CHECK(fixed_failed == fixed);
    CHECK(identity_tried > 200);
    CHECK(identity_ok >= identity_tried * 99 / 100);
    CHECK(t.forward_ok > 100);
    CHECK_MSG(t.round_trips >= t.forward_ok * 99 / 100, "%d of %d", t.round_trips, t.forward_ok);
    if (shift == RESTIR_SSS_RECONNECTION || shift == RESTIR_SSS_SEQUENTIAL) CHECK(t.nontrivial_jacobians == 0);
    /* Only the sequential shift re-inverts the numbers: they must really change. */
    if (shift == RESTIR_SSS_SEQUENTIAL) CHECK(t.moved_u > t.forward_ok / 2);
    if (shift == RESTIR_SSS_RECONNECTION) CHECK(t.moved_u == 0);
    if (shift == RESTIR_SSS_DELAYED && !temporal) CHECK(t.nontrivial_jacobians > t.round_trips / 20);
    restir_sss_destroy(&st);
    scene_release(sc);
}

static void test_reconnection_round_trips(void) { shift_case(RESTIR_SSS_RECONNECTION, false); }
static void test_delayed_round_trips(void) { shift_case(RESTIR_SSS_DELAYED, false); }
static void test_hybrid_round_trips(void) { shift_case(RESTIR_SSS_HYBRID, false); }
/* The sequential shift's reconnection passes (the context starts in that pass): the shifted
 * sample carries the inverted disk numbers and the intersection index found for the offset
 * primary hit, and shifting back restores the original ones. */
static void test_sequential_round_trips(void) { shift_case(RESTIR_SSS_SEQUENTIAL, false); }
static void test_temporal_round_trips(void)
{
    shift_case(RESTIR_SSS_RECONNECTION, true);
    shift_case(RESTIR_SSS_DELAYED, true);
    shift_case(RESTIR_SSS_HYBRID, true);
    shift_case(RESTIR_SSS_SEQUENTIAL, true);
}

static void test_params(void)
{
    struct restir_sss_params p = restir_sss_defaults();
    struct err err = {0};
    CHECK(restir_sss_params_valid(&p, &err));
    CHECK(p.shift == RESTIR_SSS_HYBRID && p.candidates == 1 && p.spatial_neighbors == 4 && p.temporal_cap == 20 &&
          p.kappa_orientation == 0.5f && p.spatial_radius == 0.0f);
    p.shift = RESTIR_SSS_SEQUENTIAL;
    CHECK(restir_sss_params_valid(&p, &err));
    p.spatial_neighbors = 3;
    CHECK(!restir_sss_params_valid(&p, &err) && strcmp(err.where, "/params/spatial_neighbors") == 0);
    p = restir_sss_defaults();
    p.index_shortcut = true;
    CHECK(!restir_sss_params_valid(&p, &err) && strcmp(err.where, "/params/index_shortcut") == 0);
    p = restir_sss_defaults();
    p.candidates = 0;
    CHECK(!restir_sss_params_valid(&p, &err) && strcmp(err.where, "/params/candidates") == 0);
    p = restir_sss_defaults();
    p.target = (enum restir_sss_target)7;
    CHECK(!restir_sss_params_valid(&p, &err) && strcmp(err.where, "/params/target") == 0);
    p = restir_sss_defaults();
    p.rest = (enum restir_sss_rest)3;
    CHECK(!restir_sss_params_valid(&p, &err) && strcmp(err.where, "/params/rest") == 0);
    /* restir_pt holds paths of at most RESTIR_PT_MAX_DEPTH events: asked for, it bounds max_depth;
     * by default the rest falls back to pt outside that range. */
    p = restir_sss_defaults();
    p.rest = RESTIR_SSS_REST_RESTIR_PT;
    p.max_depth = 0;
    CHECK(!restir_sss_params_valid(&p, &err) && strcmp(err.where, "/params/max_depth") == 0);
    p.max_depth = RESTIR_PT_MAX_DEPTH;
    CHECK(restir_sss_params_valid(&p, &err));
    p = restir_sss_defaults();
    CHECK(restir_sss_rest_of(&p) == RESTIR_SSS_REST_RESTIR_PT);
    p.max_depth = 0;
    CHECK(restir_sss_params_valid(&p, &err) && restir_sss_rest_of(&p) == RESTIR_SSS_REST_PT);
    p.max_depth = RESTIR_PT_MAX_DEPTH + 1;
    CHECK(restir_sss_params_valid(&p, &err) && restir_sss_rest_of(&p) == RESTIR_SSS_REST_PT);
    /* Converging (temporal reuse off) the default rest is pt: it measured better there. */
    p = restir_sss_defaults();
    p.temporal = false;
    CHECK(restir_sss_rest_of(&p) == RESTIR_SSS_REST_PT);
}

/* An indirect sample's L3 was traced in its own frame's scene: a temporal shift of one must fail
 * when the scene moved between the frames (here the lamp, by 5 cm), and only then; direct
 * samples still shift. Without the rule, a moving light's old indirect light stays in the
 * reservoirs for as long as their history. */
static void test_indirect_not_across_moved_scene(void)
{
    static const char lamp[] = "[2, 0.3, -0.5]]}";
    static const char moved_lamp[] = "[2, 0.3, -0.5]], \"transform\": {\"translate\": [0, 0.05, 0]}}";
    const char *at = strstr(box_json, lamp);
    CHECK(at != NULL);
    if (!at) return;
    char json[sizeof box_json + sizeof moved_lamp];
    size_t head = (size_t)(at - box_json);
    memcpy(json, box_json, head);
    snprintf(json + head, sizeof json - head, "%s%s", moved_lamp, at + strlen(lamp));
    struct err err = {0};
    struct scene *sc0 = scene_load_json(box_json, strlen(box_json), ".", &err);
    struct scene *sc1 = scene_load_json(json, strlen(json), ".", &err);
    CHECK_MSG(sc0 && sc1, "%s: %s", err.where, err.message);
    if (!sc0 || !sc1 || !scene_commit(sc0, &err) || !scene_commit(sc1, &err)) {
        CHECK_MSG(false, "%s", err.message);
        if (sc0) scene_release(sc0);
        if (sc1) scene_release(sc1);
        return;
    }
    CHECK(scene_moved(sc0, sc1));
    const uint32_t W = 64, H = 48;
    for (int moved = 0; moved < 2; moved++) {
        struct restir_sss_params p = restir_sss_defaults();
        p.rest = RESTIR_SSS_REST_PT;
        p.candidates = 4;
        struct restir_sss_state st;
        CHECK(restir_sss_init(&st, sc0, &p, W, H, &err));
        struct method_frame f0 = {.scene = sc0, .camera = &sc0->camera, .seed = 5, .frame = 0, .threads = 2};
        CHECK(restir_sss_initial_only(&st, &p, &f0, &err));
        st.rs.has_history = true;
        struct scene *now = moved ? sc1 : sc0;
        struct method_frame f1 = {.scene = now, .camera = &now->camera, .prev_scene = sc0,
                                  .prev_camera = &sc0->camera, .seed = 5, .frame = 1, .threads = 2};
        CHECK(restir_sss_initial_only(&st, &p, &f1, &err));
        _Alignas(16) uint8_t ctx[RESTIR_SSS_CTX_BYTES];
        restir_sss_bind(&st, &p, &f1, ctx);
        int indirect = 0, indirect_shifted = 0, direct = 0, direct_shifted = 0;
        for (uint32_t pixel = 0; pixel < W * H; pixel++) {
            const uint8_t *elem = st.rs.res[0] + (size_t)pixel * restir_sss_ops.stride;
            if (!(((const struct restir_head *)elem)->W > 0.0f)) continue;
            struct restir_sss_info a;
            restir_sss_info(ctx, elem, pixel, &a);
            _Alignas(16) uint8_t y[RESTIR_MAX_STRIDE];
            float t, j;
            struct restir_counters c = {0};
            restir_sss_ops.shift(ctx, elem, (struct restir_domain){pixel, RESTIR_CURRENT},
                                 (struct restir_domain){pixel, RESTIR_PREVIOUS}, y, &t, &j, &c);
            if (a.indirect) indirect++, indirect_shifted += t > 0.0f;
            else direct++, direct_shifted += t > 0.0f;
        }
        printf("     scene %s: %d of %d indirect and %d of %d direct samples shift to the previous frame\n",
               moved ? "moved" : "still", indirect_shifted, indirect, direct_shifted, direct);
        CHECK(indirect > 20 && direct > 100);
        CHECK(direct_shifted > direct / 2);
        if (moved) CHECK(indirect_shifted == 0);
        else CHECK(indirect_shifted > indirect / 2);
        restir_sss_destroy(&st);
    }
    scene_release(sc0);
    scene_release(sc1);
}

/* Planned and allocated bytes agree; the per_channel target allocates three reservoirs per pixel
 * and buffer, luminance one; the pair scratch comes with paired spatial reuse only; the rest's
 * restir_pt session and frame with rest restir_pt only; a render asking for pairs or a rest the
 * session lacks is refused naming the parameter. */
static void test_session_bytes_planned_match_allocated(void)
{
    struct scene *sc = fixture_load("scenes/translucent/scene.json");
    if (!sc) return;
    struct err err = {0};
    for (int variant = 0; variant < 4; variant++) {
        const uint32_t layers = variant == 1 ? 3 : 1;
        struct view_params vp = view_params_defaults(method_find("restir_sss"), 37, 23);
        struct restir_sss_params *vsp = VIEW_METHOD_PARAMS(&vp, struct restir_sss_params);
        vsp->target = layers == 3 ? RESTIR_SSS_TARGET_PER_CHANNEL : RESTIR_SSS_TARGET_LUMINANCE;
        vsp->paired_spatial = variant != 2;
        if (variant == 3) vsp->rest = RESTIR_SSS_REST_PT;
        struct view v;
        CHECK(view_init(&v, sc, &vp, 1, &err));
        struct session_buffers sb;
        CHECK(session_buffers_agree(&v, &vp, sc, &sb));
        CHECK(session_buffer(&sb, "reservoirs") == 2u * 37 * 23 * layers * RESTIR_SSS_RESERVOIR_BYTES);
        CHECK(session_buffer(&sb, "spatial_pairs") == (variant != 2 ? restir_pair_scratch_bytes(37, 23) : 0));
        CHECK(session_buffer(&sb, "rest_reservoirs") == (variant != 3 ? 2u * 37 * 23 * RESTIR_PT_RESERVOIR_BYTES : 0));
        CHECK(session_buffer(&sb, "rest_frame") == (variant != 3 ? 37u * 23 * sizeof(struct vec3) : 0));
        view_destroy(&v);
    }
    struct restir_sss_params made = restir_sss_defaults(), asked = made;
    made.paired_spatial = false;
    struct restir_sss_state st;
    CHECK(restir_sss_init(&st, sc, &made, 8, 8, &err));
    struct image out;
    CHECK(image_init(&out, 8, 8, &err));
    struct method_frame f = {.scene = sc, .camera = &sc->camera, .seed = 1, .threads = 1};
    CHECK(!restir_sss_render(&st, &asked, &f, &out, NULL, &err) && strcmp(err.where, "/params/paired_spatial") == 0);
    asked = made;
    asked.rest = RESTIR_SSS_REST_PT;
    CHECK(!restir_sss_render(&st, &asked, &f, &out, NULL, &err) && strcmp(err.where, "/params/rest") == 0);
    CHECK(restir_sss_render(&st, &made, &f, &out, NULL, &err));
    image_destroy(&out);
    restir_sss_destroy(&st);
    scene_release(sc);
}

TEST_MAIN(TEST(test_reconnection_round_trips), TEST(test_delayed_round_trips), TEST(test_hybrid_round_trips),
          TEST(test_sequential_round_trips),
          TEST(test_temporal_round_trips), TEST(test_indirect_not_across_moved_scene), TEST(test_params),
          TEST(test_session_bytes_planned_match_allocated))
