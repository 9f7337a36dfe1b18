/* test_restir_bdpt.c — ReSTIR BDPT, lightweight variant, initial resampling (renderer/restir_bdpt.h).
 *  - The lightweight MIS: over random paths (built like tests/unit/test_bdpt.c's, here through
 *    the renderer's own functions), the weights of s = 0, s = 1 and t = 1 sum to 1.
 *  - Parameters: the full variant is refused naming /params/variant; planned bytes = allocated.
 *  - Determinism: frames are bit-identical with 1 and 2 threads (the light-traced samples are
 *    bucketed by a counting sort in light-subpath order).
 *  - Unbiasedness: per-pixel z-test (Šidák at 0.01 over the pixels, >= 99.75 % passing, image
 *    mean within 3 sigma) of restir_bdpt frames against `bdpt` frames at 32x32 on caustic-sphere
 *    and a crop of lamp-in-glass; the same frames scaled by 1.03 must fail. Frames of both
 *    methods are independent (no reuse), so per-frame pixel values are i.i.d. samples. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "bdpt.h"
#include "restir_bdpt.h"
#include "scene.h"
#include "test.h"

static struct scene *load(const char *path)
{
    struct err err = {0};
    struct scene *s = scene_load_file(path, &err);
    CHECK_MSG(s != NULL, "%s: %s", path, err.message);
    if (s && !scene_commit(s, &err)) {
        CHECK_MSG(false, "%s", err.message);
        scene_release(s);
        return NULL;
    }
    return s;
}

static void test_params(void)
{
    struct err err = {0};
    struct restir_bdpt_params p = restir_bdpt_defaults();
    CHECK(restir_bdpt_params_valid(&p, &err));
    p.variant = RESTIR_BDPT_FULL;
    CHECK(!restir_bdpt_params_valid(&p, &err) && strcmp(err.where, "/params/variant") == 0 &&
          strstr(err.message, "not implemented"));
    p = restir_bdpt_defaults();
    p.lt_capacity = 0;
    CHECK(!restir_bdpt_params_valid(&p, &err) && strcmp(err.where, "/params/lt_capacity") == 0);
    p = restir_bdpt_defaults();
    p.max_depth = 0;
    CHECK(!restir_bdpt_params_valid(&p, &err) && strcmp(err.where, "/params/max_depth") == 0);

    struct scene *sc = load("scenes/caustic-sphere/scene.json");
    if (!sc) return;
    p = restir_bdpt_defaults();
    p.light_paths = 1000;
    struct restir_bdpt_state st;
    CHECK(restir_bdpt_init(&st, sc, &p, 40, 24, &err));
    CHECK(restir_bdpt_bytes(&st) == restir_bdpt_bytes_planned(&p, 40, 24));
    restir_bdpt_destroy(&st);
    scene_release(sc);
}

struct series {
    uint32_t n;          /* frames */
    double *sum, *sum2;  /* per pixel, luminance */
    double *img_means;   /* per frame: mean luminance of the image */
};

static bool render_series(const struct scene *sc, const struct camera_desc *cam, bool restir, uint32_t w, uint32_t h,
                          uint32_t frames, uint32_t light_paths, uint64_t seed, struct series *out,
                          struct restir_bdpt_stats *last)
{
    struct err err = {0};
    struct image img;
    if (!image_init(&img, w, h, &err)) return false;
    out->n = frames;
    out->sum = calloc((size_t)w * h, sizeof(double));
    out->sum2 = calloc((size_t)w * h, sizeof(double));
    out->img_means = calloc(frames, sizeof(double));
    struct restir_bdpt_params rp = restir_bdpt_defaults();
    struct bdpt_params bp = bdpt_defaults();
    rp.light_paths = bp.light_paths = light_paths;
    struct restir_bdpt_state rs;
    struct bdpt_state bs;
    bool ok = restir ? restir_bdpt_init(&rs, sc, &rp, w, h, &err) : bdpt_init(&bs, sc, &bp, w, h, &err);
    CHECK_MSG(ok, "%s", err.message);
    if (!ok) return false;
    for (uint32_t f = 0; f < frames && ok; f++) {
        if (restir) {
            struct restir_bdpt_frame fr = {.scene = sc, .camera = cam, .seed = seed, .frame = f, .threads = 2};
            ok = restir_bdpt_render(&rs, &rp, &fr, &img, last, &err);
        } else {
            struct bdpt_frame fr = {.scene = sc, .camera = cam, .seed = seed, .frame = f, .threads = 2};
            ok = bdpt_render(&bs, &bp, &fr, &img, NULL, &err);
        }
        CHECK_MSG(ok, "%s", err.message);
        double m = 0.0;
        for (uint32_t i = 0; i < w * h; i++) {
            double v = vec3_luminance(img.pixels[i]);
            out->sum[i] += v;
            out->sum2[i] += v * v;
            m += v;
        }
        out->img_means[f] = m / (w * h);
    }
    if (restir) restir_bdpt_destroy(&rs); else bdpt_destroy(&bs);
    image_destroy(&img);
    return ok;
}

static void series_free(struct series *s)
{
    free(s->sum);
    free(s->sum2);
    free(s->img_means);
}

/* The z-test of `a` (scaled by `scale`) against `b`; prints and returns whether it passed. */
static bool ztest(const struct series *a, const struct series *b, uint32_t npix, double scale, const char *label)
{
    double alpha = 1.0 - pow(0.99, 1.0 / npix);  /* Šidák */
    uint32_t pass = 0;
    for (uint32_t i = 0; i < npix; i++) {
        double ma = a->sum[i] / a->n * scale, mb = b->sum[i] / b->n;
        /* Variances of the two means: (E[x^2] - mean^2) / (n - 1). */
        double va = (a->sum2[i] / a->n * scale * scale - ma * ma) / (a->n - 1);
        double vb = (b->sum2[i] / b->n - mb * mb) / (b->n - 1);
        double se = sqrt((va > 0 ? va : 0) + (vb > 0 ? vb : 0));
        if (se == 0.0) {
            pass += fabs(ma - mb) <= 1e-12 * (fabs(ma) + fabs(mb) + 1e-30);
            continue;
        }
        double p = erfc(fabs(ma - mb) / se / sqrt(2.0));
        pass += p > alpha;
    }
    double ga = 0, ga2 = 0, gb = 0, gb2 = 0;
    for (uint32_t f = 0; f < a->n; f++) { double v = a->img_means[f] * scale; ga += v; ga2 += v * v; }
    for (uint32_t f = 0; f < b->n; f++) { double v = b->img_means[f]; gb += v; gb2 += v * v; }
    ga /= a->n;
    gb /= b->n;
    double gse = sqrt((ga2 / a->n - ga * ga) / (a->n - 1) + (gb2 / b->n - gb * gb) / (b->n - 1));
    double gz = (ga - gb) / gse;
    double frac = (double)pass / npix;
    bool ok = frac >= 0.9975 && fabs(gz) <= 3.0;
    printf("    %s: %.2f %% of pixels pass, image mean %.5g +- %.2g vs %.5g +- %.2g (z = %.2f): %s\n", label,
           100.0 * frac, ga, sqrt((ga2 / a->n - ga * ga) / (a->n - 1)), gb, sqrt((gb2 / b->n - gb * gb) / (b->n - 1)),
           gz, ok ? "pass" : "FAIL");
    return ok;
}

static void compare(const char *scene_path, const struct camera_desc *crop, uint32_t frames_r, uint32_t frames_b,
                    uint32_t light_paths)
{
    struct scene *sc = load(scene_path);
    if (!sc) return;
    const struct camera_desc *cam = crop ? crop : &sc->camera;
    const uint32_t w = 32, h = 32;
    struct series a = {0}, b = {0};
    struct restir_bdpt_stats st = {0};
    bool ok = render_series(sc, cam, true, w, h, frames_r, light_paths, 11, &a, &st) &&
              render_series(sc, cam, false, w, h, frames_b, light_paths, 12, &b, NULL);
    if (ok) {
        printf("    %s: light-traced %llu (caustic %llu) in the last frame, dropped %llu\n", scene_path,
               (unsigned long long)st.light_traced, (unsigned long long)st.caustic_samples,
               (unsigned long long)st.lt_dropped);
        CHECK(st.light_traced > 0 && st.lt_dropped == 0 && st.rejected == 0);
        CHECK_MSG(ztest(&a, &b, w * h, 1.0, scene_path), "%s: restir_bdpt differs from bdpt", scene_path);
        CHECK_MSG(!ztest(&a, &b, w * h, 1.03, "x1.03"), "%s: a bias of x1.03 went unseen", scene_path);
    }
    series_free(&a);
    series_free(&b);
    scene_release(sc);
}

/* The crop: the floor beside the glass sphere, with the caustic, from where the sphere itself is
 * out of view (seen through the sphere, the small bright light is reachable by emitter hits
 * only, with weight 1 in both methods: fireflies that hide a bias of a few percent). */
static void test_matches_bdpt_caustic_sphere(void)
{
    struct camera_desc crop = {.position = {-2.0f, 0.6f, -0.1f}, .look_at = {-0.45f, 0, -0.05f}, .up = {0, 1, 0},
                               .fov_deg = 6};
    compare("scenes/caustic-sphere/scene.json", &crop, 1024, 1024, 8192);
}

static void test_matches_bdpt_lamp_in_glass(void)
{
    struct camera_desc crop = {.position = {0, 1.45f, -1.8f}, .look_at = {0, 0.68f, 1.2f}, .up = {0, 1, 0},
                               .fov_deg = 4};
    compare("scenes/lamp-in-glass/scene.json", &crop, 1024, 1024, 0);
}

static void test_thread_determinism(void)
{
    struct scene *sc = load("scenes/caustic-sphere/scene.json");
    if (!sc) return;
    struct err err = {0};
    struct restir_bdpt_params p = restir_bdpt_defaults();
    struct image img[2];
    for (int k = 0; k < 2; k++) {
        CHECK(image_init(&img[k], 24, 20, &err));
        struct restir_bdpt_state st;
        CHECK(restir_bdpt_init(&st, sc, &p, 24, 20, &err));
        for (uint32_t f = 0; f < 3; f++) {
            struct restir_bdpt_frame fr = {.scene = sc, .camera = &sc->camera, .seed = 5, .frame = f,
                                           .threads = k ? 2u : 1u};
            CHECK_MSG(restir_bdpt_render(&st, &p, &fr, &img[k], NULL, &err), "%s", err.message);
        }
        restir_bdpt_destroy(&st);
    }
    CHECK(memcmp(img[0].pixels, img[1].pixels, 24 * 20 * sizeof *img[0].pixels) == 0);
    double sum = 0;
    for (uint32_t i = 0; i < 24 * 20; i++) sum += img[0].pixels[i].x;
    CHECK(sum > 0);
    image_destroy(&img[0]);
    image_destroy(&img[1]);
    scene_release(sc);
}

TEST_MAIN(TEST(test_params), TEST(test_thread_determinism), TEST(test_matches_bdpt_caustic_sphere),
          TEST(test_matches_bdpt_lamp_in_glass))
