/* test_restir_pt.c — the hybrid shift of restir_pt as round trips (tests/README.md, unit tests):
 * for paths sampled by the initial pass on cornell-glossy and door-ajar, a shift to another
 * domain and back returns the same path and contribution (T^-1(T(x)) = x) and the two Jacobians
 * multiply to 1 (J * J^-1 = 1 to 1e-4), for each kind of shift: pure random replay (no
 * reconnection vertex), reconnection at x_2 (nothing replayed) and hybrid (replay, then
 * reconnection). Domains: a neighbouring pixel of the same frame, and the previous frame's pixel
 * with the camera moved and, in a second case, a shape moved (the suffix is then re-traced).
 * A shift to the sample's own domain reproduces the contribution the initial pass stored. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "integrators/restir_pt.h"
#include "core/rng.h"
#include "scene/scene.h"
#include "jitter_moves.h"
#include "session_buffers.h"
#include "test.h"
#include "scene_fixture.h"
#include "session/view.h"

enum { KIND_REPLAY, KIND_RECONNECT, KIND_HYBRID, KIND_COUNT };
static const char *const kind_names[KIND_COUNT] = {"replay", "reconnection", "hybrid"};

struct tally {
    int tried, forward_ok, round_trips[KIND_COUNT], nontrivial_jacobians, failures;
};

static int kind_of(const struct restir_pt_info *in)
{
    if (in->rc == 0) return KIND_REPLAY;
    return in->rc == 2 ? KIND_RECONNECT : KIND_HYBRID;
}

static bool close_rel(struct vec3 a, struct vec3 b, double tol)
{
    double scale = fmax(fmax(fabs(a.x), fabs(a.y)), fabs(a.z));
    return fabs(a.x - b.x) <= tol * scale && fabs(a.y - b.y) <= tol * scale && fabs(a.z - b.z) <= tol * scale;
}

/* Shifts `elem` from `from` to `to` and back; records the outcome in t. */
static void round_trip(const void *ctx, const uint8_t *elem, struct restir_domain from, struct restir_domain to,
                       struct tally *t)
{
    const struct restir_ops *ops = &restir_pt_ops;
    _Alignas(16) uint8_t x[RESTIR_MAX_STRIDE], y[RESTIR_MAX_STRIDE], x2[RESTIR_MAX_STRIDE];
    struct restir_counters c = {0};
    float t0, j0, t1, j1, t2, j2;
    t->tried++;
    /* x as the shift evaluates it in its own pixel (the initial pass traced the reconnection
     * segment along the sampled ray; test_identity_shift bounds that difference). */
    ops->shift(ctx, elem, from, from, x, &t0, &j0, &c);
    ops->shift(ctx, elem, from, to, y, &t1, &j1, &c);
    if (!(t1 > 0.0f)) return;
    t->forward_ok++;
    ops->shift(ctx, y, to, from, x2, &t2, &j2, &c);
    struct restir_pt_info a, b;
    restir_pt_info(x, &a);
    restir_pt_info(x2, &b);
    bool ok = t0 > 0.0f && t2 > 0.0f && a.length == b.length && a.rc == b.rc && a.nee == b.nee && close_rel(a.F, b.F, 1e-4) &&
              fabs((double)j1 * j2 - 1.0) <= 1e-4;
    if (!ok) {
        if (t->failures++ < 5)
            fprintf(stderr, "  round trip %u -> %u: d %u k %u nee %d, F %g -> %g, J %g * %g = %g, back target %g\n",
                    from.pixel, to.pixel, a.length, a.rc, a.nee, (double)a.F.y, (double)b.F.y, (double)j1, (double)j2,
                    (double)j1 * j2, (double)t2);
        return;
    }
    t->round_trips[kind_of(&a)]++;
    if (fabs((double)j1 - 1.0) > 1e-3) t->nontrivial_jacobians++;
}

/* kinds: bit mask of the shift kinds this case must exercise (at least 10 round trips each). */
static void report(const char *what, const struct tally *t, unsigned kinds)
{
    printf("  %s: %d shifts, %d valid, round trips: replay %d, reconnection %d, hybrid %d, |J| != 1: %d\n", what,
           t->tried, t->forward_ok, t->round_trips[KIND_REPLAY], t->round_trips[KIND_RECONNECT],
           t->round_trips[KIND_HYBRID], t->nontrivial_jacobians);
    CHECK_MSG(t->failures == 0, "%s: %d of %d valid shifts did not come back", what, t->failures, t->forward_ok);
    CHECK_MSG(t->forward_ok >= 20, "%s: only %d valid shifts", what, t->forward_ok);
    for (int k = 0; k < KIND_COUNT; k++)
        if (kinds & (1u << k))
            CHECK_MSG(t->round_trips[k] >= 10, "%s: only %d %s round trips", what, t->round_trips[k], kind_names[k]);
    /* Reconnections move x_k's density: their Jacobians are not all 1 (replay's are). */
    if (kinds & (1u << KIND_RECONNECT))
        CHECK_MSG(t->nontrivial_jacobians >= 10, "%s: only %d shifts with a Jacobian other than 1", what,
                  t->nontrivial_jacobians);
}

#define SIZE 48u

/* Spatial round trips: each pixel's initial sample to a random pixel within 20 px. */
#define ALL_KINDS ((1u << KIND_REPLAY) | (1u << KIND_RECONNECT) | (1u << KIND_HYBRID))

static void spatial_case(const char *path, const struct restir_pt_params *p, uint32_t frames, unsigned kinds,
                         const char *what)
{
    struct scene *sc = fixture_load(path);
    if (!sc) return;
    struct err err = {0};
    struct restir_pt_state st;
    CHECK(restir_pt_init(&st, sc, p, SIZE, SIZE, &err));
    struct method_frame f = {.scene = sc, .camera = &sc->camera, .prev_camera = &sc->camera, .seed = 7, .threads = 1};
    struct tally t = {0};
    struct rng r = rng_make(11, 0, 0, 0);
    /* Several frames: more paths per pixel (each frame a fresh initial pass). */
    for (uint32_t frame = 0; frame < frames; frame++) {
        f.frame = frame;
        CHECK(restir_pt_initial_only(&st, p, &f, &err));
        _Alignas(16) uint8_t ctx[RESTIR_PT_CTX_BYTES];
        restir_pt_bind(&st, p, &f, ctx);
        for (uint32_t px = 0; px < SIZE * SIZE; px++) {
            const uint8_t *e = st.rs.res[0] + (size_t)px * restir_pt_ops.stride;
            if (!(((const struct restir_head *)e)->W > 0.0f)) continue;
            int qx = (int)(px % SIZE) + (int)(rng_next_float(&r) * 41.0f) - 20;
            int qy = (int)(px / SIZE) + (int)(rng_next_float(&r) * 41.0f) - 20;
            if (qx < 0 || qy < 0 || qx >= (int)SIZE || qy >= (int)SIZE) continue;
            struct restir_domain a = {px, RESTIR_CURRENT}, b = {(uint32_t)qy * SIZE + (uint32_t)qx, RESTIR_CURRENT};
            if (!restir_pt_ops.domain_valid(ctx, b)) continue;
            round_trip(ctx, e, a, b, &t);
        }
    }
    report(what, &t, kinds);
    restir_pt_destroy(&st);
    scene_release(sc);
}

static void test_spatial_round_trips_enhanced(void)
{
    struct restir_pt_params p = restir_pt_defaults();
    spatial_case("scenes/cornell-glossy/scene.json", &p, 6, (1u << KIND_RECONNECT) | (1u << KIND_HYBRID),
                 "cornell-glossy, footprint + pdf connectability");
    spatial_case("scenes/door-ajar/scene.json", &p, 24, 1u << KIND_RECONNECT, "door-ajar, footprint + pdf connectability");
    /* A footprint threshold no segment passes: every path is shifted by random replay alone. */
    p.footprint_c = 100.0f;
    spatial_case("scenes/cornell-glossy/scene.json", &p, 2, 1u << KIND_REPLAY, "cornell-glossy, replay only");
}

static void test_spatial_round_trips_classic(void)
{
    struct restir_pt_params p = restir_pt_defaults();
    p.footprint = false;
    p.pdf_connect = false;
    p.nee_candidates = 1;
    /* 8 frames: hybrid round trips are the rarest kind here (about 1.4 per frame). */
    spatial_case("scenes/cornell-glossy/scene.json", &p, 8, (1u << KIND_RECONNECT) | (1u << KIND_HYBRID),
                 "cornell-glossy, roughness + distance");
}

/* opaque_primary (restir_sss's rest): the translucent scene is refused without it, naming the
 * method; with it, no pixel whose primary surface is translucent holds a path or is a domain a
 * shift may enter, and the paths of the other pixels, which meet the translucent BSDF at later
 * vertices, shift and come back. */
static void test_opaque_primary(void)
{
    struct scene *sc = fixture_load("scenes/translucent/scene.json");
    if (!sc) return;
    struct err err = {0};
    struct restir_pt_params p = restir_pt_defaults();
    struct restir_pt_state st;
    CHECK(!restir_pt_init(&st, sc, &p, SIZE, SIZE, &err) && strcmp(err.where, "/method") == 0);
    p.opaque_primary = true;
    CHECK(restir_pt_init(&st, sc, &p, SIZE, SIZE, &err));
    struct method_frame f = {.scene = sc, .camera = &sc->camera, .seed = 3, .threads = 1};
    CHECK(restir_pt_initial_only(&st, &p, &f, &err));
    _Alignas(16) uint8_t ctx[RESTIR_PT_CTX_BYTES];
    restir_pt_bind(&st, &p, &f, ctx);
    uint32_t translucent = 0, held = 0;
    for (uint32_t px = 0; px < SIZE * SIZE; px++) {
        const struct gbuffer_surface *h = &st.rs.gbuf[st.rs.cur].surf[px];
        const uint8_t *e = st.rs.res[0] + (size_t)px * restir_pt_ops.stride;
        bool has = ((const struct restir_head *)e)->W > 0.0f;
        if (h->material == GBUFFER_NO_HIT || sc->materials[h->material].kind != MATERIAL_TRANSLUCENT) {
            held += has;
            continue;
        }
        translucent++;
        CHECK_MSG(!has, "pixel %u on a translucent surface holds a path", px);
        CHECK(!restir_pt_ops.domain_valid(ctx, (struct restir_domain){px, RESTIR_CURRENT}));
    }
    CHECK_MSG(translucent > SIZE * SIZE / 20 && held > SIZE * SIZE / 10, "translucent pixels %u, with a path %u",
              translucent, held);
    restir_pt_destroy(&st);
    scene_release(sc);
    spatial_case("scenes/translucent/scene.json", &p, 12, 1u << KIND_RECONNECT, "translucent, opaque_primary");
}

/* Temporal round trips: frame 1's samples to frame 0's domains and back, and frame 0's final
 * reservoirs (the history) to frame 1 and back; the camera moves, and with `move_shape` the
 * gold sphere moves too, so paths through it are re-traced in the other frame's scene. */
static void temporal_case(bool move_shape)
{
    struct scene *sc = fixture_load("scenes/cornell-glossy/scene.json");
    if (!sc) return;
    struct err err = {0};
    struct scene *moved = sc;
    if (move_shape) {
        int sphere = scene_find_shape(sc, "gold_sphere");
        CHECK(sphere >= 0);
        struct scene_shape_override ov = {.shape = (uint32_t)sphere, .has_to_world = true,
                                          .to_world = sc->shapes[sphere].to_world};
        ov.to_world.m[0][3] += 12.0f;
        ov.to_world.m[2][3] -= 7.0f;
        moved = scene_derive(sc, &ov, 1, &err);
        CHECK_MSG(moved != NULL, "%s", err.message);
        if (!moved) {
            scene_release(sc);
            return;
        }
    }
    struct restir_pt_params p = restir_pt_defaults();
    struct restir_pt_state st;
    CHECK(restir_pt_init(&st, sc, &p, SIZE, SIZE, &err));
    struct image img;
    CHECK(image_init(&img, SIZE, SIZE, &err));
    struct camera_desc cam0 = sc->camera, cam1 = sc->camera;
    cam1.position.x += 15.0f;
    cam1.look_at.y += 6.0f;
    struct method_frame f0 = {.scene = sc, .camera = &cam0, .prev_camera = &cam0, .seed = 3, .frame = 0, .threads = 1};
    CHECK(restir_pt_render(&st, &p, &f0, &img, NULL, &err));
    struct method_frame f1 = {.scene = moved, .camera = &cam1, .prev_scene = sc, .prev_camera = &cam0, .seed = 3,
                                 .frame = 1, .threads = 1};
    CHECK(restir_pt_initial_only(&st, &p, &f1, &err));
    /* The full frame before left a history; the initial pass alone ends it (its res[1] is the
     * frame before's, under another G-buffer). */
    CHECK(!st.rs.has_history);
    _Alignas(16) uint8_t ctx[RESTIR_PT_CTX_BYTES];
    restir_pt_bind(&st, &p, &f1, ctx);
    struct tally t = {0};
    const struct gbuffer *g = &st.rs.gbuf[st.rs.cur];
    for (uint32_t px = 0; px < SIZE * SIZE; px++) {
        const struct gbuffer_pixel *gp = &g->px[px];
        if (!(gp->prev_x >= 0.0f && gp->prev_y >= 0.0f && gp->prev_x < SIZE && gp->prev_y < SIZE)) continue;
        uint32_t q = (uint32_t)gp->prev_y * SIZE + (uint32_t)gp->prev_x;
        struct restir_domain cur = {px, RESTIR_CURRENT}, prev = {q, RESTIR_PREVIOUS};
        if (!restir_pt_ops.domain_valid(ctx, prev) || !restir_pt_ops.domain_valid(ctx, cur)) continue;
        const uint8_t *e = st.rs.res[0] + (size_t)px * restir_pt_ops.stride;
        if (((const struct restir_head *)e)->W > 0.0f) round_trip(ctx, e, cur, prev, &t);
        const uint8_t *h = st.rs.res[1] + (size_t)q * restir_pt_ops.stride;
        if (((const struct restir_head *)h)->W > 0.0f) round_trip(ctx, h, prev, cur, &t);
    }
    /* With the sphere moved, paths re-traced past x_k (and NEE ends inside them) mostly fail:
     * what survives is direct light and x_k on the moved sphere (a Jacobian of 1 for a rigid move). */
    report(move_shape ? "temporal, camera and sphere moved" : "temporal, camera moved", &t,
           move_shape ? 0u : (1u << KIND_RECONNECT) | (1u << KIND_HYBRID));
    image_destroy(&img);
    restir_pt_destroy(&st);
    if (moved != sc) scene_release(moved);
    scene_release(sc);
}

static void test_temporal_round_trips_camera(void) { temporal_case(false); }
static void test_temporal_round_trips_moving_shape(void) { temporal_case(true); }

/* The shift to a sample's own domain re-evaluates the path: it must give the contribution the
 * initial pass stored, with |J| = 1 — the initial pass and the shift compute one integrand. Both
 * evaluate the segment into the reconnection vertex between the two positions (pt_rc_beta), not
 * along the sampled ray, whose origin was moved off the surface: at grazing angles those differ
 * by several per cent (7 % on one sample here before). What remains is float rounding. */
/* Each pixel's initial sample shifted to its own pixel gives back its contribution, with one
 * initial path a pixel and with four (`candidates`: a sample from any of them replays from the
 * seed of its own path). */
static void test_identity_shift_reproduces_initial_contribution(void)
{
    struct scene *sc = fixture_load("scenes/cornell-glossy/scene.json");
    if (!sc) return;
    for (uint32_t candidates = 1; candidates <= 4; candidates += 3) {
        struct err err = {0};
        struct restir_pt_params p = restir_pt_defaults();
        p.candidates = candidates;
        struct restir_pt_state st;
        CHECK(restir_pt_init(&st, sc, &p, SIZE, SIZE, &err));
        struct method_frame f = {.scene = sc, .camera = &sc->camera, .prev_camera = &sc->camera, .seed = 5, .threads = 1};
        CHECK(restir_pt_initial_only(&st, &p, &f, &err));
        _Alignas(16) uint8_t ctx[RESTIR_PT_CTX_BYTES];
        restir_pt_bind(&st, &p, &f, ctx);
        int checked = 0, bad = 0, replayed = 0;
        double worst = 0.0;
        for (uint32_t px = 0; px < SIZE * SIZE; px++) {
            const uint8_t *e = st.rs.res[0] + (size_t)px * restir_pt_ops.stride;
            if (!(((const struct restir_head *)e)->W > 0.0f)) continue;
            _Alignas(16) uint8_t y[RESTIR_MAX_STRIDE];
            float tgt, jac;
            struct restir_counters c = {0};
            struct restir_domain d = {px, RESTIR_CURRENT};
            restir_pt_ops.shift(ctx, e, d, d, y, &tgt, &jac, &c);
            struct restir_pt_info a, b;
            restir_pt_info(e, &a);
            restir_pt_info(y, &b);
            checked++;
            /* A sample whose first bounce direction comes from its seed (no reconnection at x_2). */
            replayed += a.rc != 2;
            double rel = fabs((double)vec3_luminance(a.F) - vec3_luminance(b.F)) / vec3_luminance(a.F);
            if (rel > worst) worst = rel;
            if (!(tgt > 0.0f) || !close_rel(a.F, b.F, 1e-3) || fabs((double)jac - 1.0) > 1e-4) {
                if (bad++ < 5)
                    fprintf(stderr, "  pixel %u: d %u k %u nee %d stored F %g, re-evaluated %g (target %g), J %g\n", px,
                            a.length, a.rc, a.nee, (double)a.F.y, (double)b.F.y, (double)tgt, (double)jac);
            }
        }
        printf("  %u candidates: %d samples re-evaluated in their own pixel (%d replayed past x_1), %d differ by more "
               "than 0.1 %%, largest difference %.2g\n", candidates, checked, replayed, bad, worst);
        CHECK(checked > 500 && replayed > 100);
        CHECK(bad == 0);
        restir_pt_destroy(&st);
    }
    scene_release(sc);
}

/* candidates 0 (the converge profile's) resolves from the scene at init: 8 where a material is
 * near-specular below roughness_min, 1 in an all-diffuse scene. */
static void test_candidates_by_scene(void)
{
    struct scene *box = fixture_load("scenes/cornell-box/scene.json");
    struct scene *glossy = fixture_load("scenes/cornell-glossy/scene.json");
    if (box && glossy) {
        CHECK(restir_pt_candidates_by_scene(box, 0.2f) == 1);
        CHECK(restir_pt_candidates_by_scene(glossy, 0.2f) == 8);
        /* cornell-glossy's glass sphere is a delta lobe whatever the threshold. */
        CHECK(restir_pt_candidates_by_scene(glossy, 1e-4f) == 8);
        /* The glossy branch of the test, material by material: copper (GGX 0.1) is near-specular
         * below 0.2 and not below 0.05, aluminium (0.3) not below 0.2, the white wall never. */
        const int copper = scene_find_shape(glossy, "copper_sphere"), alu = scene_find_shape(glossy, "aluminium_sphere");
        CHECK(copper >= 0 && alu >= 0);
        if (copper >= 0 && alu >= 0) {
            const struct material *cu = &glossy->materials[glossy->shapes[copper].material];
            const struct material *al = &glossy->materials[glossy->shapes[alu].material];
            CHECK(material_near_specular(cu, 0.2f) && !material_near_specular(cu, 0.05f));
            CHECK(!material_near_specular(al, 0.2f) && material_near_specular(al, 0.35f));
            CHECK(!material_near_specular(&glossy->materials[glossy->shapes[0].material], 1.0f));
        }
        struct err err = {0};
        struct restir_pt_params p = restir_pt_defaults();
        p.candidates = RESTIR_PT_CANDIDATES_BY_SCENE;
        CHECK(restir_pt_params_valid(&p, &err));
        struct restir_pt_state st;
        CHECK(restir_pt_init(&st, glossy, &p, SIZE, SIZE, &err) && st.candidates_by_scene == 8);
        restir_pt_destroy(&st);
        CHECK(restir_pt_init(&st, box, &p, SIZE, SIZE, &err) && st.candidates_by_scene == 1);
        restir_pt_destroy(&st);
        p.candidates = 65;
        CHECK(!restir_pt_params_valid(&p, &err) && strcmp(err.where, "/params/candidates") == 0);
    }
    if (box) scene_release(box);
    if (glossy) scene_release(glossy);
}

static void test_reservoir_is_compact(void)
{
    CHECK(restir_pt_ops.stride == RESTIR_PT_RESERVOIR_BYTES);
    CHECK(RESTIR_PT_RESERVOIR_BYTES <= 64);
}

/* The memory budget reserves what a session will allocate: planned bytes = allocated bytes, with
 * the pair scratch only for paired spatial reuse; a render asking for pairs the session was made
 * without is refused naming the parameter. */
static void test_session_bytes_planned_match_allocated(void)
{
    struct scene *sc = fixture_load("scenes/cornell-glossy/scene.json");
    if (!sc) return;
    struct err err = {0};
    for (int paired = 0; paired < 2; paired++) {
        struct view_params vp = view_params_defaults(method_find("restir_pt"), 40, 24);
        VIEW_METHOD_PARAMS(&vp, struct restir_pt_params)->paired_spatial = paired;
        struct view v;
        CHECK(view_init(&v, sc, &vp, 1, &err));
        struct session_buffers sb;
        CHECK(session_buffers_agree(&v, &vp, sc, &sb));
        CHECK(session_buffer(&sb, "spatial_pairs") == (paired ? restir_pair_scratch_bytes(40, 24) : 0));
        view_destroy(&v);
    }
    struct restir_pt_params made = restir_pt_defaults(), asked = made;
    made.paired_spatial = false;
    struct restir_pt_state st;
    CHECK(restir_pt_init(&st, sc, &made, 8, 8, &err));
    struct image out;
    CHECK(image_init(&out, 8, 8, &err));
    struct method_frame f = {.scene = sc, .camera = &sc->camera, .seed = 1, .threads = 1};
    CHECK(!restir_pt_render(&st, &asked, &f, &out, NULL, &err) && strcmp(err.where, "/params/paired_spatial") == 0);
    CHECK(restir_pt_render(&st, &made, &f, &out, NULL, &err));
    image_destroy(&out);
    restir_pt_destroy(&st);
    scene_release(sc);
}

/* The session's jitter_walk reaches its G-buffer: with the default each pixel's primary ray moves
 * by at most the default step per axis between consecutive frames; with 0 most move further (a
 * fresh position every frame). Out of [0, 0.5] it is refused naming the parameter. */
static void test_jitter_walk_reaches_the_gbuffer(void)
{
    struct scene *sc = fixture_load("scenes/cornell-glossy/scene.json");
    if (!sc) return;
    enum { W = 16, H = 16, N = W * H };
    const float step = restir_pt_defaults().jitter_walk;
    CHECK(step > 0.0f && step <= 0.5f);
    struct err err = {0};
    for (int walk = 0; walk < 2; walk++) {
        struct restir_pt_params p = restir_pt_defaults();
        if (!walk) p.jitter_walk = 0.0f;
        struct restir_pt_state st;
        struct image out;
        CHECK(restir_pt_init(&st, sc, &p, W, H, &err) && image_init(&out, W, H, &err));
        float jx[N], jy[N], worst = 0.0f;
        for (uint32_t t = 0; t < 3; t++) {
            struct method_frame f = {.scene = sc, .camera = &sc->camera, .prev_scene = t ? sc : NULL,
                                     .prev_camera = &sc->camera, .seed = 4, .frame = t, .threads = 1};
            CHECK_MSG(restir_pt_render(&st, &p, &f, &out, NULL, &err), "%s", err.message);
            worst = fmaxf(worst, jitter_largest_move(st.rs.gbuf[st.rs.cur].px, N, jx, jy, t == 0));
        }
        if (walk) CHECK_MSG(worst <= step * (1.0f + 1e-6f), "walk %g: largest move %g", step, worst);
        else CHECK_MSG(worst > 0.5f, "no walk: largest move only %g", worst);
        image_destroy(&out);
        restir_pt_destroy(&st);
    }
    struct restir_pt_params bad = restir_pt_defaults();
    bad.jitter_walk = 0.51f;
    CHECK(!restir_pt_params_valid(&bad, &err) && strcmp(err.where, "/params/jitter_walk") == 0);
    bad.jitter_walk = NAN;
    CHECK(!restir_pt_params_valid(&bad, &err) && strcmp(err.where, "/params/jitter_walk") == 0);
    scene_release(sc);
}

TEST_MAIN(TEST(test_reservoir_is_compact), TEST(test_candidates_by_scene), TEST(test_jitter_walk_reaches_the_gbuffer), TEST(test_session_bytes_planned_match_allocated), TEST(test_identity_shift_reproduces_initial_contribution),
          TEST(test_spatial_round_trips_enhanced), TEST(test_spatial_round_trips_classic),
          TEST(test_temporal_round_trips_camera), TEST(test_temporal_round_trips_moving_shape), TEST(test_opaque_primary))
