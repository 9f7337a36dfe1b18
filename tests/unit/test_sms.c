/* test_sms.c — the pieces of specular manifold sampling that need no statistics: the sessions'
 * planned bytes equal what they allocate (sms: nothing beyond pt; sms_ssp: its prior), the path
 * tracer's chain tracking (which emission SMS owns), the seed maps' reach, and the parameter
 * checks. */
#include <math.h>
#include <string.h>

#include "scene/scene.h"
#include "integrators/sms.h"
#include "integrators/sms_ssp.h"
#include "session/view.h"
#include "test.h"
#include "session_buffers.h"

static struct scene *slab(void)
{
    struct err err = {0};
    struct scene *s = scene_load_file("scenes/refractive-slab/scene.json", &err);
    CHECK_MSG(s && scene_commit(s, &err), "%s", err.message);
    return s;
}

/* The slab scene and its one caster (the slab). */
static struct scene *slab_caster(struct sms_scene *ss)
{
    struct err err = {0};
    struct scene *s = slab();
    CHECK_MSG(!s || (sms_scene_init(s, ss, &err) && ss->count == 1), "%s", err.message);
    return s;
}

static void test_planned_bytes_match(void)
{
    struct scene *s = slab();
    if (!s) return;
    static const uint32_t sizes[][2] = {{1, 1}, {16, 16}, {17, 33}, {64, 48}};
    for (int m = 0; m < 2; m++) {
        const struct method_desc *method = m ? method_find("sms_ssp") : method_find("sms");
        for (size_t i = 0; i < sizeof sizes / sizeof sizes[0]; i++) {
            struct view_params p = view_params_defaults(method, sizes[i][0], sizes[i][1]);
            struct view v;
            struct err err = {0};
            CHECK_MSG(view_init(&v, s, &p, 1, &err), "%s", err.message);
            struct session_buffers sb;
            CHECK(session_buffers_agree(&v, &p, s, &sb));
            CHECK((session_buffer(&sb, "prior") > 0) == (method == method_find("sms_ssp")));
            view_destroy(&v);
        }
    }
    scene_release(s);
}

static void test_track_owns_exactly_the_chain(void)
{
    struct scene *s = slab();
    if (!s) return;
    uint32_t slab_i = (uint32_t)scene_find_shape(s, "slab"), floor_i = (uint32_t)scene_find_shape(s, "floor");
    struct surface on_slab = {.shape = slab_i}, on_floor = {.shape = floor_i};
    const unsigned T = BSDF_DELTA | BSDF_TRANSMISSION, R = BSDF_DELTA | BSDF_REFLECTION, D = BSDF_DIFFUSE | BSDF_REFLECTION;
    /* x1 (diffuse) -> T -> T -> emitter: owned. */
    struct sms_track t = sms_track_start();
    sms_track_scatter(s, &t, &on_floor, D);
    CHECK(!sms_track_owned(s, &t));
    sms_track_scatter(s, &t, &on_slab, T);
    CHECK(!sms_track_owned(s, &t));
    sms_track_scatter(s, &t, &on_slab, T);
    CHECK(sms_track_owned(s, &t));
    /* A third crossing, a reflection, or no diffuse vertex first: not owned. */
    struct sms_track u = t;
    sms_track_scatter(s, &u, &on_slab, T);
    CHECK(!sms_track_owned(s, &u));
    u = sms_track_start();
    sms_track_scatter(s, &u, &on_floor, D);
    sms_track_scatter(s, &u, &on_slab, R);
    sms_track_scatter(s, &u, &on_slab, T);
    CHECK(!sms_track_owned(s, &u));
    u = sms_track_start();
    sms_track_scatter(s, &u, &on_slab, T);
    sms_track_scatter(s, &u, &on_slab, T);
    CHECK(!sms_track_owned(s, &u));
    /* A new diffuse vertex restarts the chain. */
    sms_track_scatter(s, &u, &on_floor, D);
    sms_track_scatter(s, &u, &on_slab, T);
    sms_track_scatter(s, &u, &on_slab, T);
    CHECK(sms_track_owned(s, &u));
    scene_release(s);
}

/* Every seed of the bounding-box map lies on the box's surface, and every face gets seeds. */
static void test_seed_map_covers_the_box(void)
{
    struct sms_scene ss;
    struct scene *s = slab_caster(&ss);
    if (!s) return;
    const struct sms_caster *c = &ss.casters[0];
    int faces[6] = {0};
    for (int i = 0; i < 64; i++)
        for (int j = 0; j < 64; j++) {
            struct vec3 p = sms_seed_point(c, (i + 0.5f) / 64.0f, (j + 0.5f) / 64.0f);
            const float e = 1e-5f;
            bool on = false;
            for (int a = 0; a < 3; a++) {
                float lo = vec3_comp(c->lo, a), hi = vec3_comp(c->hi, a), x = vec3_comp(p, a);
                CHECK(x >= lo - e && x <= hi + e);
                if (fabsf(x - lo) <= e) { faces[2 * a]++; on = true; }
                if (fabsf(x - hi) <= e) { faces[2 * a + 1]++; on = true; }
            }
            CHECK(on);
        }
    for (int f = 0; f < 6; f++) CHECK_MSG(faces[f] > 0, "face %d", f);
    scene_release(s);
}

/* The prior's walks start at the block's shading points ([SMS-SSP §4.1]): a pixel seen through
 * the slab shades the floor behind it, so a block whose every primary hit is glass still gets a
 * prior, built from the floor points it sees (before, primary hits alone gave it none). Every
 * walk that finds a solution marks a tile of its (light, caster) pair. */
static void test_prior_built_behind_the_slab(void)
{
    struct sms_scene ss;
    struct scene *s = slab_caster(&ss);
    if (!s) return;
    struct err err = {0};
    /* Straight down through the slab's middle: at y = 0.7 the view is 0.23 wide, inside the slab. */
    struct camera cam;
    camera_init(&cam, &(struct camera_desc){vec3_make(0, 2, 0), vec3_make(0, 0, 0), vec3_make(0, 0, -1), 20.0f},
                SSP_BLOCK, SSP_BLOCK);
    struct hit h;
    struct ray_counters rc = {0};
    for (uint32_t y = 0; y < SSP_BLOCK; y += 5)
        for (uint32_t x = 0; x < SSP_BLOCK; x += 5)
            CHECK(accel_intersect(s->accel, cam.position, camera_ray_dir(&cam, x + 0.5f, y + 0.5f), 0.0f, INFINITY, &h,
                                  &rc) &&
                  (int)h.shape == scene_find_shape(s, "slab"));
    struct ssp_prior pr;
    struct ssp_params p = ssp_defaults();
    CHECK(ssp_prior_init(&pr, SSP_BLOCK, SSP_BLOCK, 1, &err));
    struct ssp_prior_counters c = {0};
    CHECK(ssp_prior_build(&pr, s, &ss, &p, &cam, 7, 0, false, 2, &c, &rc, &err));
    CHECK_MSG(c.samples == p.prior_samples, "%llu walks of %u", (unsigned long long)c.samples, p.prior_samples);
    CHECK_MSG(c.solutions > 0, "no solution in %llu walks", (unsigned long long)c.samples);
    uint32_t pairs = 0, tiles = 0;
    for (int i = 0; i < SSP_PRIOR_ENTRIES; i++)
        if (pr.entries[i].light_shape >= 0) {
            pairs++;
            tiles += pr.entries[i].count;
            CHECK(pr.entries[i].caster == 0 && pr.entries[i].count > 0);
        }
    /* Both lights' caustics fall on the floor under the slab. */
    CHECK_MSG(pairs == 2 && tiles <= c.solutions, "%u pairs, %u tiles, %llu solutions", pairs, tiles,
              (unsigned long long)c.solutions);
    /* The block's middle pixel's receiver draws seeds from the prior; a floor point far from the
     * block's receivers (the floor's corner) falls back, though it asks with the same pixel. */
    struct hit rh;
    struct surface x1;
    struct vec3 wo, T;
    uint32_t depth;
    const uint32_t mid = SSP_BLOCK / 2;
    CHECK(accel_intersect(s->accel, cam.position, camera_ray_dir(&cam, mid, mid), 0.0f, INFINITY, &h, &rc) &&
          sms_receiver_trace(s, 64, cam.position, camera_ray_dir(&cam, mid, mid), &h, &rh, &x1, &wo, &T, &depth, &rc) &&
          depth == 2);
    struct vec3 far_org = vec3_make(1.8f, 1.0f, 1.8f), down = vec3_make(0.0f, -1.0f, 0.0f);
    struct hit fh;
    struct surface far;
    CHECK(accel_intersect(s->accel, far_org, down, 0.0f, INFINITY, &fh, &rc));
    surface_from_hit(s, &fh, far_org, down, &far);
    for (int k = 0; k < 2; k++) {
        const struct surface *at = k ? &far : &x1;
        struct sms_counters sc = {0};
        struct sms_solution sol;
        struct rng rng = rng_make(3, 0, 0, 0);
        ssp_sample(s, &ss, &p, &pr, mid, mid, at, &s->materials[at->material], frame_to_local(&at->frame, vec3_make(0, 1, 0)),
                   8, &rng, &sol, &sc, &rc);
        CHECK_MSG(sc.samples == 1 && sc.with_prior == (k ? 0u : 1u), "%s: %llu of %llu samples with the prior",
                  k ? "far" : "receiver", (unsigned long long)sc.with_prior, (unsigned long long)sc.samples);
    }
    ssp_prior_destroy(&pr);
    scene_release(s);
}

/* The same pair's entry in a block's table, or NULL. */
static const struct ssp_entry *pair_in(const struct ssp_entry *tab, const struct ssp_entry *e)
{
    for (int i = 0; i < SSP_PRIOR_ENTRIES; i++)
        if (tab[i].light_shape == e->light_shape && tab[i].caster == e->caster) return &tab[i];
    return NULL;
}

/* A still view's prior is the union of its kept frames' walks (sms_ssp.h): with prior_frames 4,
 * frame 1's table holds every tile and the box of frame 0's and frame 1's own priors, per pair,
 * and nothing else; a frame that is not still starts again from its own walks alone. */
static void test_prior_unites_still_frames(void)
{
    struct sms_scene ss;
    struct scene *s = slab_caster(&ss);
    if (!s) return;
    struct err err = {0};
    struct camera cam;
    camera_init(&cam, &s->camera, 2 * SSP_BLOCK, 2 * SSP_BLOCK);
    struct ssp_params p = ssp_defaults();
    struct ray_counters rc = {0};
    struct ssp_prior own[3], kept;
    for (uint32_t f = 0; f < 3; f++) {
        struct ssp_prior_counters c = {0};
        CHECK(ssp_prior_init(&own[f], cam.width, cam.height, 1, &err) &&
              ssp_prior_build(&own[f], s, &ss, &p, &cam, 5, f, false, 2, &c, &rc, &err));
    }
    CHECK(ssp_prior_init(&kept, cam.width, cam.height, 4, &err));
    const size_t n = 4 * SSP_PRIOR_ENTRIES;
    for (uint32_t f = 0; f < 3; f++) {
        struct ssp_prior_counters c = {0};
        CHECK(ssp_prior_build(&kept, s, &ss, &p, &cam, 5, f, f == 1, 2, &c, &rc, &err));
        if (f == 0 || f == 2) {
            CHECK_MSG(memcmp(kept.entries, own[f].entries, n * sizeof *kept.entries) == 0, "frame %u", f);
            continue;
        }
        uint32_t united = 0, single = 0;
        for (uint32_t b = 0; b < 4; b++) {
            const struct ssp_entry *u = &kept.entries[b * SSP_PRIOR_ENTRIES];
            for (int i = 0; i < SSP_PRIOR_ENTRIES && u[i].light_shape >= 0; i++) {
                const struct ssp_entry *a = pair_in(&own[0].entries[b * SSP_PRIOR_ENTRIES], &u[i]);
                const struct ssp_entry *z = pair_in(&own[1].entries[b * SSP_PRIOR_ENTRIES], &u[i]);
                CHECK(a || z);
                uint32_t bits = 0;
                for (int w = 0; w < SSP_MAX_TILES * SSP_MAX_TILES / 64; w++) {
                    uint64_t want = (a ? a->bits[w] : 0) | (z ? z->bits[w] : 0);
                    CHECK_MSG(u[i].bits[w] == want, "block %u pair %d word %d", b, i, w);
                    bits += (uint32_t)__builtin_popcountll(u[i].bits[w]);
                }
                CHECK(u[i].count == bits);
                for (int k = 0; k < 3; k++)
                    CHECK(u[i].lo[k] == fminf(a ? a->lo[k] : INFINITY, z ? z->lo[k] : INFINITY) &&
                          u[i].hi[k] == fmaxf(a ? a->hi[k] : -INFINITY, z ? z->hi[k] : -INFINITY));
                united += u[i].count;
                single += z ? z->count : 0;
            }
            for (int i = 0; i < SSP_PRIOR_ENTRIES; i++)
                for (int k = 0; k < 2; k++) {
                    const struct ssp_entry *e = &own[k].entries[b * SSP_PRIOR_ENTRIES + i];
                    CHECK(e->light_shape < 0 || pair_in(u, e));
                }
        }
        CHECK_MSG(united > single && single > 0, "%u tiles united, %u in frame 1's own", united, single);
    }
    for (int f = 0; f < 3; f++) ssp_prior_destroy(&own[f]);
    ssp_prior_destroy(&kept);
    scene_release(s);
}

static void test_params_checked(void)
{
    struct err err = {0};
    struct ssp_params p = ssp_defaults();
    CHECK(ssp_params_valid(&p, &err));
    p.tiles = 2;
    CHECK(!ssp_params_valid(&p, &err) && strcmp(err.where, "tiles") == 0);
    p = ssp_defaults();
    p.alpha = 1.0f;
    CHECK(!ssp_params_valid(&p, &err) && strcmp(err.where, "alpha") == 0);
    p = ssp_defaults();
    CHECK(p.prior_frames == 4);
    p.prior_frames = 0;
    CHECK(!ssp_params_valid(&p, &err) && strcmp(err.where, "prior_frames") == 0);
    p.prior_frames = SSP_MAX_PRIOR_FRAMES + 1;
    CHECK(!ssp_params_valid(&p, &err) && strcmp(err.where, "prior_frames") == 0);
    struct sms_params q = sms_defaults();
    CHECK(q.bernoulli_cap == 128 && q.max_iterations == MANIFOLD_MAX_ITERATIONS);
    q.max_iterations = 0;
    CHECK(!sms_params_valid(&q, &err) && strcmp(err.where, "max_iterations") == 0);
    /* 16 x 16 blocks of 8 pair entries. */
    CHECK(ssp_prior_bytes(17, 16, 1) == 2 * SSP_PRIOR_ENTRIES * sizeof(struct ssp_entry));
    CHECK(ssp_prior_bytes(17, 16, 4) == 5 * 2 * SSP_PRIOR_ENTRIES * sizeof(struct ssp_entry));
}

TEST_MAIN(TEST(test_planned_bytes_match), TEST(test_track_owns_exactly_the_chain), TEST(test_seed_map_covers_the_box),
          TEST(test_prior_built_behind_the_slab), TEST(test_prior_unites_still_frames), TEST(test_params_checked))
