/* test_metrics.c — MAPE / RMSE / relMSE against values computed by hand on tiny images,
 * size mismatch errors, NaN/Inf exclusion and counting, and the JSON formatting (null for
 * non-finite, never a bare nan).
 * Refs: metrics.h for the definitions; [ReSTIR BDPT footnote 3] for MAPE. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "image/metrics.h"
#include "test.h"

static struct image make(uint32_t w, uint32_t h, const struct vec3 *px)
{
    struct image img;
    struct err err;
    if (image_init(&img, w, h, &err) && px) memcpy(img.pixels, px, sizeof *px * w * h);
    return img;
}

/* ref = (1,2,3),(4,5,6): mean 21/6 = 3.5, so MAPE's offset is 0.035.
 * image differs by +0.5 at ref 1 and +1 at ref 6:
 *   MAPE   = (0.5/1.035 + 1/6.035) / 6
 *   RMSE   = sqrt((0.25 + 1) / 6)
 *   relMSE = (0.25/(1 + 0.01) + 1/(36 + 0.01)) / 6
 * channel means: ref (2.5, 3.5, 4.5), image (2.75, 3.5, 5): relative differences 0.1, 0, 1/9. */
static void test_hand_computed_2x1(void)
{
    struct vec3 r[2] = {{1, 2, 3}, {4, 5, 6}}, a[2] = {{1.5f, 2, 3}, {4, 5, 7}};
    struct image ref = make(2, 1, r), img = make(2, 1, a);
    struct metrics m;
    struct err err = {0};
    CHECK(metrics_compare(&img, &ref, &m, &err));
    CHECK_NEAR(m.mape, (0.5 / 1.035 + 1.0 / 6.035) / 6.0, 1e-15);
    CHECK_NEAR(m.mape, 0.10813197838160916, 1e-15);
    CHECK_NEAR(m.rmse, 0.45643546458763845, 1e-15);
    CHECK_NEAR(m.relmse, 0.04588246939106574, 1e-15);
    CHECK_NEAR(m.ref_mean, 3.5, 0.0);
    CHECK(m.width == 2 && m.height == 1 && m.pixels_used == 2 && m.samples == 6);
    CHECK(m.nan_image == 0 && m.nan_ref == 0 && m.inf_image == 0 && m.inf_ref == 0);
    CHECK(m.mean_ref[0] == 2.5 && m.mean_ref[1] == 3.5 && m.mean_ref[2] == 4.5);
    CHECK(m.mean_image[0] == 2.75 && m.mean_image[1] == 3.5 && m.mean_image[2] == 5.0);
    CHECK_NEAR(m.mean_rel_diff[0], 0.1, 1e-15);
    CHECK(m.mean_rel_diff[1] == 0.0);
    CHECK_NEAR(m.mean_rel_diff[2], 1.0 / 9.0, 1e-15);
    CHECK(m.mean_rel_diff_max == m.mean_rel_diff[2]);

    /* The metric is not symmetric: swapping the roles changes the denominators. */
    struct metrics s;
    CHECK(metrics_compare(&ref, &img, &s, &err));
    CHECK(fabs(s.mape - m.mape) > 1e-3);
    CHECK_NEAR(s.rmse, m.rmse, 1e-15);
    image_destroy(&ref);
    image_destroy(&img);
}

static void test_identical_is_zero(void)
{
    struct vec3 r[3] = {{0.1f, 0.2f, 0.3f}, {0, 0, 0}, {7, 8, 9}};
    struct image ref = make(3, 1, r), img = make(3, 1, r);
    struct metrics m;
    CHECK(metrics_compare(&img, &ref, &m, NULL));
    CHECK(m.mape == 0.0 && m.rmse == 0.0 && m.relmse == 0.0);
    image_destroy(&ref);
    image_destroy(&img);
}

/* A large image with a constant error: double accumulation keeps the means exact enough. */
static void test_large_constant_error(void)
{
    struct image ref = make(1000, 1000, NULL), img = make(1000, 1000, NULL);
    if (!ref.pixels || !img.pixels) { CHECK(0); return; }
    for (size_t i = 0; i < 1000000; i++) {
        ref.pixels[i] = vec3_splat(1.0f);
        img.pixels[i] = vec3_splat(1.25f);
    }
    struct metrics m;
    CHECK(metrics_compare(&img, &ref, &m, NULL));
    CHECK_NEAR(m.mape, 0.25 / 1.01, 1e-12);
    CHECK_NEAR(m.rmse, 0.25, 1e-12);
    CHECK_NEAR(m.relmse, 0.0625 / 1.01, 1e-12);
    CHECK(m.samples == 3000000);
    image_destroy(&ref);
    image_destroy(&img);
}

static void test_size_mismatch(void)
{
    struct vec3 p[2] = {{1, 1, 1}, {1, 1, 1}};
    struct image a = make(2, 1, p), b = make(1, 2, p);
    struct metrics m;
    struct err err = {0};
    CHECK(!metrics_compare(&a, &b, &m, &err));
    CHECK(err.code == ERR_INVALID);
    CHECK_MSG(strstr(err.message, "2x1") && strstr(err.message, "1x2"), "%s", err.message);
    struct image empty = {0};
    CHECK(!metrics_compare(&a, &empty, &m, &err) && err.code == ERR_INVALID);
    image_destroy(&a);
    image_destroy(&b);
}

/* Pixel 1 has a NaN in the image, pixel 2 an Inf in the reference, pixel 3 both a NaN and an
 * Inf in the image: only pixel 0 enters the sums, and its values alone decide the metrics. */
static void test_nonfinite_excluded(void)
{
    struct vec3 r[4] = {{2, 2, 2}, {1, 1, 1}, {INFINITY, 1, 1}, {1, 1, 1}};
    struct vec3 a[4] = {{3, 2, 2}, {1, NAN, 1}, {1, 1, 1}, {NAN, -INFINITY, 1}};
    struct image ref = make(4, 1, r), img = make(4, 1, a);
    struct metrics m;
    CHECK(metrics_compare(&img, &ref, &m, NULL));
    CHECK(m.pixels_used == 1 && m.samples == 3);
    CHECK(m.nan_image == 2 && m.inf_image == 1 && m.nan_ref == 0 && m.inf_ref == 1);
    /* Pixel 3 is in both counts above but is one non-finite pixel. */
    CHECK(m.nonfinite_image == 2 && m.nonfinite_ref == 1);
    CHECK_NEAR(m.ref_mean, 2.0, 0.0);
    CHECK_NEAR(m.mape, (1.0 / 2.02) / 3.0, 1e-15);
    CHECK_NEAR(m.rmse, sqrt(1.0 / 3.0), 1e-15);
    CHECK_NEAR(m.relmse, (1.0 / 4.01) / 3.0, 1e-15);
    CHECK(isfinite(m.mape) && isfinite(m.rmse) && isfinite(m.relmse));
    image_destroy(&ref);
    image_destroy(&img);
}

static void test_json(void)
{
    struct vec3 r[2] = {{1, 2, 3}, {4, 5, 6}};
    struct image ref = make(2, 1, r), img = make(2, 1, r);
    struct metrics m;
    CHECK(metrics_compare(&img, &ref, &m, NULL));
    char buf[METRICS_JSON_MAX];
    struct err err = {0};
    CHECK(metrics_format_json(&m, buf, sizeof buf, &err));
    CHECK_MSG(strcmp(buf, "{\"width\":2,\"height\":1,\"pixels_used\":2,\"samples\":6,\"mape\":0,"
                          "\"rmse\":0,\"relmse\":0,\"ref_mean\":3.5,\"nan\":{\"a\":0,\"b\":0},"
                          "\"inf\":{\"a\":0,\"b\":0},\"nonfinite\":{\"a\":0,\"b\":0},"
                          "\"mean\":{\"a\":[2.5,3.5,4.5],\"b\":[2.5,3.5,4.5]},\"mean_rel_diff\":[0,0,0],"
                          "\"mean_rel_diff_max\":0}") == 0, "%s", buf);

    /* %.9g for real values. */
    struct vec3 a[2] = {{1.5f, 2, 3}, {4, 5, 7}};
    struct image img2 = make(2, 1, a);
    CHECK(metrics_compare(&img2, &ref, &m, NULL));
    CHECK(metrics_format_json(&m, buf, sizeof buf, &err));
    CHECK_MSG(strstr(buf, "\"mape\":0.108131978,\"rmse\":0.456435465,\"relmse\":0.0458824694,"), "%s", buf);

    /* Black reference: MAPE undefined -> null; all pixels non-finite -> every metric null. */
    struct vec3 z[2] = {{0, 0, 0}, {0, 0, 0}};
    struct image black = make(2, 1, z);
    CHECK(metrics_compare(&img, &black, &m, NULL));
    CHECK(isnan(m.mape) && isfinite(m.rmse));
    CHECK(metrics_format_json(&m, buf, sizeof buf, &err));
    CHECK_MSG(strstr(buf, "\"mape\":null,\"rmse\":") && !strstr(buf, ":nan") && !strstr(buf, ":-nan") &&
                  !strstr(buf, ":inf"),
              "%s", buf);
    /* Means of 0 in the reference: an image mean above it is infinitely off (null), 0 is not. */
    CHECK(isinf(m.mean_rel_diff_max));
    CHECK_MSG(strstr(buf, "\"mean_rel_diff\":[null,null,null],\"mean_rel_diff_max\":null}"), "%s", buf);
    struct metrics mb;
    CHECK(metrics_compare(&black, &black, &mb, NULL) && mb.mean_rel_diff_max == 0.0);
    struct vec3 n[2] = {{NAN, 0, 0}, {0, INFINITY, 0}};
    struct image bad = make(2, 1, n);
    CHECK(metrics_compare(&bad, &ref, &m, NULL));
    CHECK(m.pixels_used == 0);
    CHECK(metrics_format_json(&m, buf, sizeof buf, &err));
    CHECK_MSG(strstr(buf, "\"mape\":null,\"rmse\":null,\"relmse\":null,\"ref_mean\":null,"
                          "\"nan\":{\"a\":1,\"b\":0},\"inf\":{\"a\":1,\"b\":0},\"nonfinite\":{\"a\":2,\"b\":0},"
                          "\"mean\":{\"a\":[null,null,null],\"b\":[null,null,null]},"
                          "\"mean_rel_diff\":[null,null,null],\"mean_rel_diff_max\":null}"),
              "%s", buf);

    /* Too small a buffer is an error, not a silently cut object. */
    char tiny[40];
    CHECK(!metrics_format_json(&m, tiny, sizeof tiny, &err) && err.code == ERR_LIMIT);
    image_destroy(&ref);
    image_destroy(&img);
    image_destroy(&img2);
    image_destroy(&black);
    image_destroy(&bad);
}

static void test_image_mean(void)
{
    struct image img;
    struct err err;
    CHECK(image_init(&img, 2, 1, &err));
    img.pixels[0] = vec3_make(1.0f, 2.0f, 0.0f);
    img.pixels[1] = vec3_make(3.0f, 0.5f, -1.0f);
    double mean[3];
    CHECK(metrics_image_mean(&img, mean) == 0);
    CHECK(mean[0] == 2.0 && mean[1] == 1.25 && mean[2] == -0.5);
    image_destroy(&img);
    /* A NaN or Inf pixel is left out and counted, never summed. */
    CHECK(image_init(&img, 3, 1, &err));
    img.pixels[0] = vec3_make(1.0f, 1.0f, 1.0f);
    img.pixels[1] = vec3_make(NAN, 0.0f, 0.0f);
    img.pixels[2] = vec3_make(3.0f, INFINITY, 3.0f);
    CHECK(metrics_image_mean(&img, mean) == 2);
    CHECK(mean[0] == 1.0 && mean[1] == 1.0 && mean[2] == 1.0);
    image_destroy(&img);
}

/* The error image holds MAPE's per-pixel terms: on the 2x1 pair above, pixel 0 is
 * (0.5/1.035)/3 and pixel 1 (1/6.035)/3, their mean is MAPE. A third pixel with a NaN in the
 * image has an infinite error, above every threshold; a fourth with an Inf in the reference
 * has nothing to be compared with: NaN, left out of the fraction. */
static void test_error_image(void)
{
    struct vec3 r[4] = {{1, 2, 3}, {4, 5, 6}, {1, 1, 1}, {INFINITY, 1, 1}};
    struct vec3 a[4] = {{1.5f, 2, 3}, {4, 5, 7}, {NAN, 1, 1}, {1, 1, 1}};
    struct image ref = make(4, 1, r), img = make(4, 1, a), out = make(4, 1, NULL), small = make(2, 1, NULL);
    struct metrics m;
    struct err err = {0};
    CHECK(metrics_compare(&img, &ref, &m, &err));
    CHECK(metrics_error_image(&img, &ref, &m, &out, &err));
    /* ref_mean over the used pixels is 3.5 as above: the non-finite pixels are out of every sum. */
    CHECK_NEAR(m.ref_mean, 3.5, 0.0);
    CHECK_NEAR(out.pixels[0].x, 0.5 / 1.035 / 3.0, 1e-7);
    CHECK_NEAR(out.pixels[1].x, 1.0 / 6.035 / 3.0, 1e-7);
    CHECK(out.pixels[0].y == out.pixels[0].x && out.pixels[1].z == out.pixels[1].x);
    CHECK(out.pixels[2].x == INFINITY && isnan(out.pixels[3].x));
    CHECK_NEAR((out.pixels[0].x + out.pixels[1].x) / 2.0, m.mape, 1e-7);
    /* Pixel 0's error is 0.161, pixel 1's 0.055, pixel 2's infinite: the fraction is over those
     * three. */
    CHECK(metrics_fraction_above(&out, 0.1) == 2.0 / 3.0);
    CHECK(metrics_fraction_above(&out, 0.01) == 1.0);
    CHECK(metrics_fraction_above(&out, 0.2) == 1.0 / 3.0);
    CHECK(metrics_fraction_above(&out, 1e30) == 1.0 / 3.0);
    /* Strictly above: an error equal to the threshold passes. */
    CHECK(metrics_fraction_above(&out, out.pixels[0].x) == 1.0 / 3.0);
    CHECK(!metrics_error_image(&img, &ref, &m, &small, &err) && err.code == ERR_INVALID);
    CHECK_MSG(strstr(err.message, "4x1") && strstr(err.message, "2x1"), "%s", err.message);
    /* An all-black reference leaves MAPE undefined: every pixel is NaN, and so is the fraction. */
    struct vec3 z[4] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
    struct image black = make(4, 1, z);
    CHECK(metrics_compare(&ref, &black, &m, &err) && isnan(m.mape));
    CHECK(metrics_error_image(&ref, &black, &m, &out, &err));
    CHECK(isnan(out.pixels[0].x) && isnan(metrics_fraction_above(&out, 0.1)));
    image_destroy(&ref);
    image_destroy(&img);
    image_destroy(&out);
    image_destroy(&small);
    image_destroy(&black);
}

/* A negative reference sample counts as 0 in MAPE's denominator, in MAPE and in the error
 * image alike: ref (-0.5, 1, 1), (1, 1, 1) has mean 0.75, offset 0.0075, and an image off by 1
 * in that sample has the term 1 / 0.0075 there, never the negative 1 / (-0.5 + 0.0075). */
static void test_negative_reference(void)
{
    struct vec3 r[2] = {{-0.5f, 1, 1}, {1, 1, 1}}, a[2] = {{0.5f, 1, 1}, {1, 1, 1}};
    struct image ref = make(2, 1, r), img = make(2, 1, a), out = make(2, 1, NULL);
    struct metrics m;
    struct err err = {0};
    CHECK(metrics_compare(&img, &ref, &m, &err) && metrics_error_image(&img, &ref, &m, &out, &err));
    CHECK_NEAR(m.ref_mean, 0.75, 0.0);
    CHECK_NEAR(m.mape, 1.0 / 0.0075 / 6.0, 1e-9);
    CHECK_NEAR(out.pixels[0].x, 1.0 / 0.0075 / 3.0, 1e-4);
    CHECK(out.pixels[1].x == 0.0f);
    image_destroy(&ref);
    image_destroy(&img);
    image_destroy(&out);
}

TEST_MAIN(TEST(test_image_mean), TEST(test_error_image), TEST(test_negative_reference), TEST(test_hand_computed_2x1), TEST(test_identical_is_zero), TEST(test_large_constant_error),
          TEST(test_size_mismatch), TEST(test_nonfinite_excluded), TEST(test_json))
