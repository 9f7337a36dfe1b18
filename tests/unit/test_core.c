/* test_core.c — unit tests for the renderer's base pieces: RNG streams, alias tables, the
 * Embree backend (hit distances, front-face normals, instancing), ray origin offsets, the
 * light sampler's pdfs, the camera, vec.h's four-lane vec3 and Owen-scrambled Sobol' samples.
 * Scenes are built in code so these tests do not depend on the JSON loader. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "scene/accel.h"
#include "scene/camera.h"
#include "core/distrib.h"
#include "scene/light_sampler.h"
#include "core/rng.h"
#include "core/sobol.h"
#include "scene/scene.h"
#include "scene/surface.h"
#include "test.h"

/* χ² statistic critical value for `dof` degrees of freedom at significance 1e-4
 * (Wilson–Hilferty approximation; z = 3.719). */
static double chi2_critical(int dof)
{
    double z = 3.719, k = dof;
    double t = 1.0 - 2.0 / (9.0 * k) + z * sqrt(2.0 / (9.0 * k));
    return k * t * t * t;
}

static void test_rng_uniform_chi2(void)
{
    enum { BINS = 64, N = 640000 };
    int counts[BINS] = {0};
    struct rng r = rng_make(7, 1, 2, 3);
    for (int i = 0; i < N; i++) {
        float u = rng_next_float(&r);
        CHECK(u >= 0.0f && u < 1.0f);
        counts[(int)(u * BINS)]++;
    }
    double chi2 = 0, e = (double)N / BINS;
    for (int i = 0; i < BINS; i++) chi2 += (counts[i] - e) * (counts[i] - e) / e;
    CHECK_MSG(chi2 < chi2_critical(BINS - 1), "chi2 %.2f", chi2);
}

static void test_rng_streams_differ(void)
{
    /* Streams of neighbouring pixels must not be shifted copies of each other. */
    struct rng a = rng_make(0, 0, 0, 0), b = rng_make(0, 0, 1, 0);
    uint32_t xa[16], xb[16];
    for (int i = 0; i < 16; i++) { xa[i] = rng_next_u32(&a); xb[i] = rng_next_u32(&b); }
    int same = 0;
    for (int i = 0; i < 16; i++)
        for (int j = 0; j < 16; j++) same += xa[i] == xb[j];
    CHECK(same == 0);
    struct rng c = rng_make(0, 0, 1, 0);
    CHECK(rng_next_u32(&c) == xb[0]);  /* deterministic */
}

/* Keyed streams are made one per path vertex and purpose and read for a few numbers only: the
 * first numbers of streams with neighbouring keys, and the first two numbers of one stream, must
 * be jointly uniform (16 x 16 bins, chi2). */
static void test_rng_keyed_first_numbers_chi2(void)
{
    enum { B = 16, N = 256000 };
    static int across[B][B], within[B][B];
    memset(across, 0, sizeof across);
    memset(within, 0, sizeof within);
    for (uint64_t i = 0; i < N; i++) {
        /* keys as the path tracer forms them: seed << 32 | vertex << 8 | purpose */
        uint64_t key = (i / 64) << 32 | (i % 64) << 8 | 1u;
        struct rng a = rng_keyed(key), b = rng_keyed(key + 1);
        float a0 = rng_next_float(&a), a1 = rng_next_float(&a), b0 = rng_next_float(&b);
        across[(int)(a0 * B)][(int)(b0 * B)]++;
        within[(int)(a0 * B)][(int)(a1 * B)]++;
    }
    double e = (double)N / (B * B), chi_a = 0, chi_w = 0;
    for (int i = 0; i < B; i++)
        for (int j = 0; j < B; j++) {
            chi_a += (across[i][j] - e) * (across[i][j] - e) / e;
            chi_w += (within[i][j] - e) * (within[i][j] - e) / e;
        }
    CHECK_MSG(chi_a < chi2_critical(B * B - 1), "across keys: chi2 %.2f", chi_a);
    CHECK_MSG(chi_w < chi2_critical(B * B - 1), "within a stream: chi2 %.2f", chi_w);
    struct rng c = rng_keyed(42), d = rng_keyed(42);
    CHECK(rng_next_u32(&c) == rng_next_u32(&d));  /* deterministic */
}

/* A pixel's sample streams (rng_pixel_make once, rng_sample per sample), as the path tracer forms
 * them: the first numbers of neighbouring samples, of the same sample index in neighbouring
 * pixels, and the first two numbers of one sample are jointly uniform (16 x 16 bins, chi2), and a
 * sample's later numbers (its 100th) do not repeat another sample's (no two of the pixel's
 * streams run into each other over 1000 draws). */
static void test_rng_pixel_samples_chi2(void)
{
    enum { B = 16, PIXELS = 4000, SPP = 64 };
    static int samples[B][B], pixels[B][B], within[B][B];
    memset(samples, 0, sizeof samples);
    memset(pixels, 0, sizeof pixels);
    memset(within, 0, sizeof within);
    for (uint64_t px = 0; px < PIXELS; px++) {
        struct rng_pixel p = rng_pixel_make(9, 2, px, 0x7074u), q = rng_pixel_make(9, 2, px + 1, 0x7074u);
        for (uint64_t s = 0; s < SPP; s++) {
            struct rng a = rng_sample(&p, s), b = rng_sample(&p, s + 1), c = rng_sample(&q, s);
            float a0 = rng_next_float(&a), a1 = rng_next_float(&a), b0 = rng_next_float(&b), c0 = rng_next_float(&c);
            samples[(int)(a0 * B)][(int)(b0 * B)]++;
            pixels[(int)(a0 * B)][(int)(c0 * B)]++;
            within[(int)(a0 * B)][(int)(a1 * B)]++;
        }
    }
    double e = (double)PIXELS * SPP / (B * B), chi_s = 0, chi_p = 0, chi_w = 0;
    for (int i = 0; i < B; i++)
        for (int j = 0; j < B; j++) {
            chi_s += (samples[i][j] - e) * (samples[i][j] - e) / e;
            chi_p += (pixels[i][j] - e) * (pixels[i][j] - e) / e;
            chi_w += (within[i][j] - e) * (within[i][j] - e) / e;
        }
    CHECK_MSG(chi_s < chi2_critical(B * B - 1), "neighbouring samples: chi2 %.2f", chi_s);
    CHECK_MSG(chi_p < chi2_critical(B * B - 1), "neighbouring pixels: chi2 %.2f", chi_p);
    CHECK_MSG(chi_w < chi2_critical(B * B - 1), "within a sample: chi2 %.2f", chi_w);
    /* 64 samples of one pixel, 1000 draws each: no stream reaches another's starting state (as
     * it would if the samples' states were consecutive points of their shared sequence). */
    struct rng_pixel p = rng_pixel_make(1, 0, 0, 0x7074u);
    uint64_t start[SPP];
    for (uint32_t s = 0; s < SPP; s++) start[s] = rng_sample(&p, s).state;
    uint32_t runs_into = 0;
    for (uint32_t s = 0; s < SPP; s++) {
        struct rng r = rng_sample(&p, s);
        for (int i = 0; i < 1000; i++) {
            rng_next_u32(&r);
            for (uint32_t t = 0; t < SPP; t++) runs_into += r.state == start[t];
        }
    }
    CHECK_MSG(runs_into == 0, "%u draws reached another sample's starting state", runs_into);
}

/* Sobol' samples (sobol.h). The generator first: bit reversal against a loop over bits, and
 * dimension 1 against its direction numbers built by the textbook recurrence (polynomial x + 1:
 * v_0 = 2^31, v_j = v_(j-1) xor v_(j-1) >> 1; a point is the xor of the v_j of the index's set bits). */
static void test_sobol_generator(void)
{
    uint32_t v[32];
    v[0] = 1u << 31;
    for (int j = 1; j < 32; j++) v[j] = v[j - 1] ^ (v[j - 1] >> 1);
    struct rng r = rng_make(5, 0, 0, 0);
    for (uint32_t n = 0; n < 20000; n++) {
        uint32_t index = n < 4096 ? n : rng_next_u32(&r);
        uint32_t want = 0, reversed = 0;
        for (int j = 0; j < 32; j++) {
            if (index >> j & 1u) want ^= v[j];
            reversed |= (index >> j & 1u) << (31 - j);
        }
        CHECK_MSG(sobol_dimension1(index) == want, "index %u: %08x, want %08x", index, sobol_dimension1(index), want);
        CHECK(sobol_dimension0(index) == reversed && sobol_reverse_bits(index) == reversed);
        uint64_t pair = (uint64_t)index << 32 | (index ^ 0x9e3779b9u);
        CHECK(sobol_reverse_bits64(pair) == ((uint64_t)sobol_reverse_bits(index ^ 0x9e3779b9u) << 32 | reversed));
    }
}

/* The net property, deterministic: for N = 2^k (k = 0..10) consecutive indices of one scrambled
 * dimension pair, starting at 0 or at another multiple of N (a later frame's block), every
 * elementary interval of area 1/N, of every shape 2^-i x 2^-(k-i), holds exactly one point.
 * Fails when the scramble is not nested (a bit flipped by a function of bits below it splits
 * intervals), when the shuffle does not map a block onto a block, or when the generator is wrong. */
static void test_sobol_nets(void)
{
    enum { K = 10, N_MAX = 1 << K };
    static uint32_t pts[N_MAX][2];
    static uint16_t cells[N_MAX];
    uint32_t broken = 0, checked = 0;
    for (uint64_t seed = 0; seed < 3; seed++)
        for (uint32_t dim = 0; dim < 9; dim += 4)
            for (uint32_t k = 0; k <= K; k++) {
                const uint32_t n = 1u << k;
                for (uint32_t block = 0; block < 4; block += 3) {
                    const struct sobol_seeds ks = sobol_dimension_seeds(rng_mix64(seed), dim);
                    for (uint32_t i = 0; i < n; i++) sobol_2d_u32(sobol_reverse_bits(block * n + i), &ks, pts[i]);
                    for (uint32_t i = 0; i <= k; i++) {  /* 2^i columns, 2^(k-i) rows */
                        memset(cells, 0, n * sizeof cells[0]);
                        for (uint32_t p = 0; p < n; p++) {
                            uint32_t col = (uint32_t)((uint64_t)pts[p][0] >> (32 - i));
                            uint32_t row = (uint32_t)((uint64_t)pts[p][1] >> (32 - (k - i)));
                            cells[col << (k - i) | row]++;
                        }
                        for (uint32_t c = 0; c < n; c++) broken += cells[c] != 1;
                        checked++;
                    }
                }
            }
    CHECK_MSG(broken == 0, "%u elementary intervals without exactly one point (%u nets checked)", broken, checked);
}

/* Scrambling randomises: at a fixed sample index, each coordinate over many pixel seeds is
 * uniform (64 bins, chi2), and sobol_1d is sobol_2d's first coordinate. Fails when the seeds
 * ignore the pixel seed (every pixel gets the same number). A coordinate left unscrambled passes
 * here (the shuffle's random high index bits still shift it); test_sobol_convergence catches it. */
static void test_sobol_scrambling_chi2(void)
{
    enum { BINS = 64, SEEDS = 64000 };
    const uint32_t indices[] = {0, 1, 37};
    for (size_t t = 0; t < sizeof indices / sizeof indices[0]; t++) {
        int c0[BINS] = {0}, c1[BINS] = {0};
        uint32_t differ = 0;
        for (uint64_t seed = 0; seed < SEEDS; seed++) {
            const uint64_t pixel_seed = rng_mix64(seed ^ 0x5eedull);
            float u0, u1;
            sobol_sample_2d(pixel_seed, indices[t], 4, &u0, &u1);
            CHECK(u0 >= 0.0f && u0 < 1.0f && u1 >= 0.0f && u1 < 1.0f);
            differ += sobol_sample_1d(pixel_seed, indices[t], 4) != u0;
            c0[(int)(u0 * BINS)]++;
            c1[(int)(u1 * BINS)]++;
        }
        double e = (double)SEEDS / BINS, chi0 = 0, chi1 = 0;
        for (int b = 0; b < BINS; b++) {
            chi0 += (c0[b] - e) * (c0[b] - e) / e;
            chi1 += (c1[b] - e) * (c1[b] - e) / e;
        }
        CHECK_MSG(chi0 < chi2_critical(BINS - 1), "index %u, coordinate 0: chi2 %.2f", indices[t], chi0);
        CHECK_MSG(chi1 < chi2_critical(BINS - 1), "index %u, coordinate 1: chi2 %.2f", indices[t], chi1);
        CHECK_MSG(differ == 0, "index %u: sobol_1d differs from sobol_2d's first coordinate %u times", indices[t],
                  differ);
    }
}

/* Padding: two padded dimensions of one pixel are independent (16 x 16 bins of one dimension's
 * coordinate against the other's first coordinate over 65536 consecutive indices, chi2). Each
 * coordinate alone is stratified, so its marginal is exact; what is tested is the pairing. Fails
 * when two dimensions share their seeds (the points coincide) or their shuffle (nested scrambles
 * of the same index tie each interval of one coordinate to a single interval of the other). */
static void test_sobol_padding_independent_chi2(void)
{
    enum { B = 16, N = 65536 };
    static int hist[B][B];
    const struct { uint32_t a, b, coord_a; } pairs[] = {{0, 1, 0}, {0, 1, 1}, {2, 7, 0}, {5, 6, 1}};
    for (uint64_t seed = 1; seed <= 2; seed++)
        for (size_t t = 0; t < sizeof pairs / sizeof pairs[0]; t++) {
            memset(hist, 0, sizeof hist);
            for (uint32_t i = 0; i < N; i++) {
                float a[2], b[2];
                sobol_sample_2d(rng_mix64(seed), i, pairs[t].a, &a[0], &a[1]);
                sobol_sample_2d(rng_mix64(seed), i, pairs[t].b, &b[0], &b[1]);
                hist[(int)(a[pairs[t].coord_a] * B)][(int)(b[0] * B)]++;
            }
            double e = (double)N / (B * B), chi = 0;
            for (int i = 0; i < B; i++)
                for (int j = 0; j < B; j++) chi += (hist[i][j] - e) * (hist[i][j] - e) / e;
            CHECK_MSG(chi < chi2_critical(B * B - 1),
                      "seed %u, dimension %u coordinate %u against dimension %u: chi2 %.2f", (unsigned)seed,
                      pairs[t].a, pairs[t].coord_a, pairs[t].b, chi);
        }
}

/* Least-squares slope of log(rms) against log(n). */
static double loglog_slope(const double *n, const double *rms, int count)
{
    double sx = 0, sy = 0, sxx = 0, sxy = 0;
    for (int i = 0; i < count; i++) {
        double x = log(n[i]), y = log(rms[i]);
        sx += x;
        sy += y;
        sxx += x * x;
        sxy += x * y;
    }
    return (count * sxy - sx * sy) / (count * sxx - sx * sx);
}

/* Stratification pays: the RMS error, over 64 pixel seeds, of the N-point estimate of the
 * integral of exp(-(x^2 + y^2)) over the unit square ((sqrt(pi)/2 erf(1))^2) falls faster than
 * random sampling's 1/sqrt(N). The log-log slope over N = 16..4096 must be below -0.8, and below
 * -1.2, Owen scrambling's rate: its error falls like N^-1.5 up to log factors on smooth integrands
 * (measured -1.44), where a net that is only shifted, not scrambled, in one coordinate falls like
 * 1/N (measured -1.02 with dimension 1 left unscrambled: the shuffle's random high index bits
 * still shift it, so it stays unbiased and uniform, and only this rate gives it away). The same
 * estimate from PCG streams is the control: random sampling's slope is -0.5 (measured -0.506),
 * and it must come out above -0.6, so the fit can tell the rates apart. Fails when the points are
 * not nets (a scramble or shuffle that is not nested), which leaves random sampling's rate. */
static void test_sobol_convergence(void)
{
    enum { SEEDS = 64, STEPS = 9 };
    const double half = 0.5 * sqrt(M_PI) * erf(1.0), exact = half * half;
    double n[STEPS], rms_sobol[STEPS], rms_random[STEPS];
    for (int k = 0; k < STEPS; k++) {
        const uint32_t count = 16u << k;
        double se_sobol = 0, se_random = 0;
        for (uint64_t seed = 0; seed < SEEDS; seed++) {
            struct rng r = rng_make(seed, 77, count, 0);
            double sum_sobol = 0, sum_random = 0;
            for (uint32_t i = 0; i < count; i++) {
                float x, y;
                sobol_sample_2d(rng_mix64(seed + 1000), i, 3, &x, &y);
                sum_sobol += exp(-((double)x * x + (double)y * y));
                float rx = rng_next_float(&r), ry = rng_next_float(&r);
                sum_random += exp(-((double)rx * rx + (double)ry * ry));
            }
            double es = sum_sobol / count - exact, er = sum_random / count - exact;
            se_sobol += es * es;
            se_random += er * er;
        }
        n[k] = count;
        rms_sobol[k] = sqrt(se_sobol / SEEDS);
        rms_random[k] = sqrt(se_random / SEEDS);
    }
    double slope_sobol = loglog_slope(n, rms_sobol, STEPS), slope_random = loglog_slope(n, rms_random, STEPS);
    printf("  RMS error slope over N = 16..4096: sobol %.3f (rms %.3g -> %.3g), random %.3f (rms %.3g -> %.3g)\n",
           slope_sobol, rms_sobol[0], rms_sobol[STEPS - 1], slope_random, rms_random[0], rms_random[STEPS - 1]);
    CHECK_MSG(slope_sobol < -0.8, "sobol slope %.3f: not stratified", slope_sobol);
    CHECK_MSG(slope_sobol < -1.2, "sobol slope %.3f: stratified, but not at Owen scrambling's rate", slope_sobol);
    CHECK_MSG(slope_random > -0.6, "random control slope %.3f: the fit cannot tell random sampling apart",
              slope_random);
}

static int cmp_u32(const void *a, const void *b)
{
    const uint32_t x = *(const uint32_t *)a, y = *(const uint32_t *)b;
    return (x > y) - (x < y);
}

/* Whether this processor runs the batch's code path `path`: 0 the scalar one, 1 the AVX2 one. */
static bool sobol_path_present(int path)
{
#ifdef SOBOL_HAVE_AVX2
    return path == 0 || __builtin_cpu_supports("avx2");
#else
    return path == 0;
#endif
}

/* sobol_batch_draw_run gives every sample of a run what sobol_batch_draw gives it alone, on
 * every code path this processor has (the scalar one, and the AVX2 one where present), for run
 * lengths around the eight samples the vector path reverses at once and a stride with room
 * between samples, which must stay untouched. Fails when a sample takes another's index, a step
 * of the run's vector path differs from the per-sample one, or a run writes past its samples. */
static void test_sobol_batch_run_matches(void)
{
    struct rng r = rng_make(13, 0, 0, 0);
    enum { MAX_RUN = 21, STRIDE = 20 };  /* 20 floats a sample: 8 lanes of u0, gap, 8 of u1, gap */
    uint32_t mismatched = 0, paths = 0;
    for (int path = 0; path < 2; path++) {
        if (!sobol_path_present(path)) continue;
        paths++;
        for (int trial = 0; trial < 400; trial++) {
            const uint64_t pixel_seed = (uint64_t)rng_next_u32(&r) << 32 | rng_next_u32(&r);
            const uint32_t count = 1 + (uint32_t)trial % MAX_RUN;
            /* Near the top of the index range too: first + count stays within 2^32. */
            const uint32_t first = trial % 5 == 4 ? 0xffffffffu - count : rng_next_u32(&r) >> 1;
            struct sobol_batch b;
            sobol_batch_seed_scalar(&b, pixel_seed, SOBOL_BATCH_LANES);
            float out[MAX_RUN * STRIDE + 8];
            for (size_t i = 0; i < sizeof out / sizeof out[0]; i++) out[i] = -1.0f;
            if (path == 0)
                sobol_batch_draw_run_scalar(&b, first, count, SOBOL_BATCH_LANES, out, out + 10, STRIDE);
#ifdef SOBOL_HAVE_AVX2
            if (path == 1) sobol_batch_draw_run8_avx2(&b, first, count, out, out + 10, STRIDE);
#endif
            for (uint32_t i = 0; i < count; i++) {
                float w0[SOBOL_BATCH_DIMS], w1[SOBOL_BATCH_DIMS];
                sobol_batch_draw_scalar(&b, sobol_reverse_bits(first + i), SOBOL_BATCH_LANES, w0, w1);
                const float *u0 = out + i * STRIDE, *u1 = u0 + 10;
                for (uint32_t l = 0; l < SOBOL_BATCH_LANES; l++) mismatched += u0[l] != w0[l] || u1[l] != w1[l];
                mismatched += u0[8] != -1.0f || u0[9] != -1.0f || u1[8] != -1.0f || u1[9] != -1.0f;
            }
            for (size_t i = (size_t)count * STRIDE; i < sizeof out / sizeof out[0]; i++) mismatched += out[i] != -1.0f;
        }
    }
    printf("  Sobol' runs checked on %u code path(s)\n", paths);
    CHECK_MSG(mismatched == 0, "%u numbers of a run differ from sobol_batch_draw's or were written outside it",
              mismatched);
}

/* The batch functions compute what the one-dimension functions do, on every code path this
 * processor has (scalar, and AVX2 where present): seeds equal to sobol_dimension_seeds lane by lane
 * (with the multiplier beside each), and every lane's point equal to sobol_2d's, over random pixel
 * seeds and indices, for 5, 8, 13 and 16 lanes (the vector code with and without a scalar tail),
 * and nothing written past the last lane. Fails when a lane takes another lane's seeds, a vector
 * step differs from the scalar one, or a group of eight is written where fewer lanes were asked. Also: the inner inputs (dim, word) of the seed hash are
 * distinct for every dimension below 2^16, so no two seed words of a pixel coincide by
 * construction. */
static void test_sobol_batch_matches_scalar(void)
{
    struct rng r = rng_make(11, 0, 0, 0);
    uint32_t mismatched = 0, paths = 0;
    for (int path = 0; path < 2; path++) {
        if (!sobol_path_present(path)) continue;
        paths++;
        for (int trial = 0; trial < 2000; trial++) {
            const uint64_t pixel_seed = (uint64_t)rng_next_u32(&r) << 32 | rng_next_u32(&r);
            static const uint32_t lane_counts[] = {5, 8, 13, 16};
            const uint32_t lanes = lane_counts[trial % 4], index_reversed = rng_next_u32(&r);
            struct sobol_batch b;
            float u0[SOBOL_BATCH_DIMS], u1[SOBOL_BATCH_DIMS];
            memset(&b, 0xab, sizeof b);
            for (uint32_t d = 0; d < SOBOL_BATCH_DIMS; d++) u0[d] = u1[d] = -1.0f;
            if (path == 0) {
                sobol_batch_seed_scalar(&b, pixel_seed, lanes);
                sobol_batch_draw_scalar(&b, index_reversed, lanes, u0, u1);
            }
#ifdef SOBOL_HAVE_AVX2
            if (path == 1) {
                sobol_batch_seed_avx2(&b, pixel_seed, lanes);
                sobol_batch_draw_avx2(&b, index_reversed, lanes, u0, u1);
            }
#endif
            for (uint32_t d = 0; d < lanes; d++) {
                const struct sobol_seeds k = sobol_dimension_seeds(pixel_seed, d);
                float w0, w1;
                sobol_2d(index_reversed, &k, &w0, &w1);
                mismatched += b.shuffle[d] != k.shuffle || b.scramble0[d] != k.scramble0 ||
                              b.scramble1[d] != k.scramble1 || b.shuffle_mul[d] != ((k.shuffle >> 16) | 1u) ||
                              b.scramble0_mul[d] != ((k.scramble0 >> 16) | 1u) ||
                              b.scramble1_mul[d] != ((k.scramble1 >> 16) | 1u) || u0[d] != w0 || u1[d] != w1;
            }
            for (uint32_t d = lanes; d < SOBOL_BATCH_DIMS; d++) mismatched += u0[d] != -1.0f || u1[d] != -1.0f;
        }
    }
    printf("  batch Sobol' checked on %u code path(s)\n", paths);
    CHECK_MSG(mismatched == 0, "%u lanes differ from sobol_dimension_seeds / sobol_2d", mismatched);
    /* Distinct inner inputs: d * step + w * step2 over d < 2^16, w < 3, sorted. */
    enum { DIMS = 1 << 16 };
    static uint32_t inner[3 * DIMS];
    for (uint32_t d = 0; d < DIMS; d++)
        for (uint32_t w = 0; w < 3; w++) inner[3 * d + w] = d * SOBOL_SEED_DIM_STEP + w * SOBOL_SEED_WORD_STEP;
    qsort(inner, 3 * DIMS, sizeof inner[0], cmp_u32);
    uint32_t repeats = 0;
    for (uint32_t i = 1; i < 3 * DIMS; i++) repeats += inner[i] == inner[i - 1];
    CHECK_MSG(repeats == 0, "%u repeated (dimension, word) inputs of the seed hash", repeats);
}

static void test_distrib_chi2(void)
{
    double w[5] = {1.0, 0.0, 3.0, 0.5, 10.0};
    struct distrib d;
    struct err err;
    CHECK(distrib_init(&d, w, 5, &err));
    double total = 14.5;
    int counts[5] = {0};
    struct rng r = rng_make(1, 0, 0, 0);
    enum { N = 400000 };
    for (int i = 0; i < N; i++) {
        float pmf;
        uint32_t k = distrib_sample(&d, rng_next_float(&r), &pmf);
        CHECK(k < 5);
        CHECK_NEAR(pmf, w[k] / total, 1e-6);
        counts[k]++;
    }
    CHECK(counts[1] == 0);
    double chi2 = 0;
    for (int k = 0; k < 5; k++) {
        if (w[k] == 0) continue;
        double e = N * w[k] / total;
        chi2 += (counts[k] - e) * (counts[k] - e) / e;
    }
    CHECK_MSG(chi2 < chi2_critical(3), "chi2 %.2f", chi2);
    distrib_destroy(&d);
    double bad[2] = {1.0, NAN};
    CHECK(!distrib_init(&d, bad, 2, &err) && err.code == ERR_INVALID);
}

/* A scene with a floor quad (y = 0, front +y, 10 x 10 around the origin, named or not) and an
 * emissive quad facing down at y = 5. */
static struct scene *make_scene(bool named_floor)
{
    struct scene *s = calloc(1, sizeof *s);
    s->refcount = 1;
    s->camera = (struct camera_desc){{0, 2, -10}, {0, 2, 0}, {0, 1, 0}, 40.0f};
    s->material_count = 2;
    s->materials = calloc(2, sizeof *s->materials);
    s->material_names = calloc(2, sizeof *s->material_names);
    s->materials[0] = (struct material){.kind = MATERIAL_DIFFUSE, .albedo = {0.5f, 0.5f, 0.5f}};
    s->materials[1] = (struct material){.kind = MATERIAL_DIFFUSE, .emission = {4, 4, 4}};
    strcpy(s->material_names[0], "grey");
    strcpy(s->material_names[1], "lamp");
    s->shape_count = 3;
    s->shapes = calloc(3, sizeof *s->shapes);
    for (int i = 0; i < 2; i++) {
        struct shape *sh = &s->shapes[i];
        float y = i == 0 ? 0.0f : 5.0f, e = i == 0 ? 5.0f : 1.0f;
        sh->kind = SHAPE_MESH;
        sh->material = (uint32_t)i;
        sh->to_world = xform_identity();
        sh->vertex_count = 4;
        sh->triangle_count = 2;
        sh->positions = malloc(4 * sizeof *sh->positions);
        sh->indices = malloc(6 * sizeof *sh->indices);
        /* Counter-clockwise seen from +y for the floor; from -y for the lamp. */
        struct vec3 up[4] = {{-e, y, -e}, {-e, y, e}, {e, y, e}, {e, y, -e}};
        for (int v = 0; v < 4; v++) sh->positions[i == 0 ? v : 3 - v] = up[v];
        uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
        memcpy(sh->indices, idx, sizeof idx);
    }
    if (named_floor) strcpy(s->shapes[0].name, "floor");
    /* A sphere of radius 1 at (3, 1, 0), scaled non-uniformly into an ellipsoid (instanced). */
    struct shape *sp = &s->shapes[2];
    sp->kind = SHAPE_SPHERE;
    sp->material = 0;
    sp->center = vec3_make(0, 0, 0);
    sp->radius = 1.0f;
    sp->to_world = xform_identity();
    sp->to_world.m[0][0] = 2.0f;  /* x semi-axis 2 */
    sp->to_world.m[0][3] = 3.0f;
    sp->to_world.m[1][3] = 1.0f;
    return s;
}

static void check_floor_hits(struct scene *s)
{
    struct ray_counters rc = {0, 0};
    struct hit h;
    /* From above: hits the floor at t = 2 with normal +y. */
    CHECK(accel_intersect(s->accel, vec3_make(-2, 2, 0), vec3_make(0, -1, 0), 0, INFINITY, &h, &rc));
    CHECK_NEAR(h.t, 2.0f, 1e-5);
    CHECK(h.shape == 0);
    CHECK_NEAR(h.ng.y, 1.0f, 1e-6);
    /* Up to the lamp: front face points down. */
    CHECK(accel_intersect(s->accel, vec3_make(0, 2, 0), vec3_make(0, 1, 0), 0, INFINITY, &h, &rc));
    CHECK(h.shape == 1);
    CHECK_NEAR(h.ng.y, -1.0f, 1e-6);
    /* The ellipsoid: along -x from x = 10 at y = 1 hits x = 3 + 2 = 5, normal +x. */
    CHECK(accel_intersect(s->accel, vec3_make(10, 1, 0), vec3_make(-1, 0, 0), 0, INFINITY, &h, &rc));
    CHECK(h.shape == 2);
    CHECK_NEAR(h.t, 5.0f, 1e-4);
    CHECK_NEAR(h.ng.x, 1.0f, 1e-5);
    struct surface su;
    surface_from_hit(s, &h, vec3_make(10, 1, 0), vec3_make(-1, 0, 0), &su);
    CHECK_NEAR(su.p.x, 5.0f, 1e-5);
    /* From the top of the ellipsoid (y = 2 at x = 3): the normal is +y. */
    CHECK(accel_intersect(s->accel, vec3_make(3, 4, 0), vec3_make(0, -1, 0), 0, INFINITY, &h, &rc));
    CHECK(h.shape == 2);
    CHECK_NEAR(h.ng.y, 1.0f, 1e-5);
    /* Occlusion of a segment that ends before the lamp, and one that crosses it. */
    CHECK(!accel_occluded(s->accel, vec3_make(0.5f, 1, 0), vec3_make(0, 1, 0), 0, 3.0f, &rc));
    CHECK(accel_occluded(s->accel, vec3_make(0.5f, 1, 0), vec3_make(0, 1, 0), 0, 5.0f, &rc));
    CHECK(rc.intersect == 4 && rc.occluded == 2);
}

static void test_accel_flat_and_two_level(void)
{
    for (int layout = 0; layout < 2; layout++) {
        struct scene *s = make_scene(layout);
        struct err err = {0};
        CHECK_MSG(scene_commit(s, &err), "%s", err.message);
        if (layout == 1) {
            /* Same queries with the floor movable (two-level layout). */
            bool movable[3] = {true, false, false};
            accel_free(s->accel);
            s->accel = accel_new(s, movable, &err);
            CHECK(s->accel != NULL);
        }
        check_floor_hits(s);
        scene_release(s);
    }
}

static void test_accel_move_instance(void)
{
    struct scene *s = make_scene(true);
    struct err err = {0};
    CHECK(scene_commit(s, &err));
    bool movable[3] = {true, false, false};
    accel_free(s->accel);
    s->accel = accel_new(s, movable, &err);
    CHECK(s->accel != NULL);
    struct xform up = xform_identity();
    up.m[1][3] = 1.0f;  /* lift the floor to y = 1 */
    CHECK(accel_set_transform(s->accel, 0, &up));
    CHECK(!accel_set_transform(s->accel, 1, &up));  /* not movable: baked */
    accel_commit_top(s->accel);
    struct ray_counters rc = {0, 0};
    struct hit h;
    CHECK(accel_intersect(s->accel, vec3_make(-2, 3, 0), vec3_make(0, -1, 0), 0, INFINITY, &h, &rc));
    CHECK_NEAR(h.t, 2.0f, 1e-5);
    struct surface su;
    surface_from_hit(s, &h, vec3_make(-2, 3, 0), vec3_make(0, -1, 0), &su);
    CHECK_NEAR(su.p.y, 1.0f, 1e-6);
    scene_release(s);
}

/* make_scene committed in one of three accel layouts: 0 flat (nothing movable, one BVH), 1 the
 * first shape movable (two levels), 2 every shape movable. */
static struct scene *make_scene_layout(int layout)
{
    struct scene *s = make_scene(false);
    struct err err = {0};
    CHECK_MSG(scene_commit(s, &err), "%s", err.message);
    if (layout > 0) {
        bool movable[3] = {true, layout == 2, layout == 2};
        accel_free(s->accel);
        s->accel = accel_new(s, movable, &err);
        CHECK(s->accel != NULL);
    }
    return s;
}

/* accel_query_intersect and accel_query_occluded answer as accel_intersect and accel_occluded do,
 * hit for hit, over one query reused for a mixed run of rays (hits, misses, blocked and free
 * segments, in the flat and both two-level layouts): fails when a field that the query functions
 * leave to accel_query_init is changed by a query (a miss after a hit would then see the hit's
 * shortened tfar, or a hit record would survive into the next query). */
static void test_accel_query_matches(void)
{
    for (int layout = 0; layout < 3; layout++) {
        struct scene *s = make_scene_layout(layout);
        struct accel_query q;
        accel_query_init(&q);
        struct rng r = rng_make(17, (uint64_t)layout, 0, 0);
        struct ray_counters rc = {0, 0}, rq = {0, 0};
        uint32_t mismatched = 0, hits = 0, blocked = 0;
        for (int i = 0; i < 4000; i++) {
            struct vec3 o = vec3_make(12.0f * rng_next_float(&r) - 6.0f, 6.0f * rng_next_float(&r) - 1.0f,
                                      12.0f * rng_next_float(&r) - 6.0f);
            struct vec3 d = vec3_normalize(vec3_make(2.0f * rng_next_float(&r) - 1.0f,
                                                     2.0f * rng_next_float(&r) - 1.0f,
                                                     2.0f * rng_next_float(&r) - 1.0f));
            float tmax = i % 3 == 0 ? INFINITY : 10.0f * rng_next_float(&r);
            struct hit a, b;
            memset(&a, 0, sizeof a);
            memset(&b, 0, sizeof b);
            bool ha = accel_intersect(s->accel, o, d, 0.0f, tmax, &a, &rc);
            bool hb = accel_query_intersect(s->accel, &q, o, d, tmax, &b, &rq);
            mismatched += ha != hb || memcmp(&a, &b, sizeof a) != 0;
            hits += ha;
            bool oa = accel_occluded(s->accel, o, d, 0.0f, tmax, &rc);
            bool ob = accel_query_occluded(s->accel, &q, o, d, tmax, &rq);
            mismatched += oa != ob;
            blocked += oa;
        }
        CHECK_MSG(mismatched == 0, "layout %d: %u query answers differ", layout, mismatched);
        CHECK(hits > 500 && hits < 3500 && blocked > 500 && blocked < 3500);  /* both answers exercised */
        CHECK(rc.intersect == rq.intersect && rc.occluded == rq.occluded);
        scene_release(s);
    }
}

/* accel_intersect_bundle gives each ray accel_intersect's answer: bundles of 1 to 8 rays from one
 * origin, close together (a pixel's camera rays) and spread out, in the three layouts. Triangles
 * must match to the bit; the ellipsoid (shape 2) within a few float steps, since Embree's packet
 * sphere kernel rounds differently from its single-ray one. */
static void test_accel_bundle_matches(void)
{
    for (int layout = 0; layout < 3; layout++) {
        struct scene *s = make_scene_layout(layout);
        struct rng r = rng_make(23, (uint64_t)layout, 0, 0);
        struct ray_counters rc = {0, 0}, rb = {0, 0};
        uint32_t mismatched = 0, hits = 0, misses = 0, spheres = 0, counted_wrong = 0;
        for (int b = 0; b < 1500; b++) {
            uint32_t n = 1 + (uint32_t)b % ACCEL_BUNDLE;
            float spread = b % 2 ? 0.002f : 1.0f;
            struct vec3 o = vec3_make(12.0f * rng_next_float(&r) - 6.0f, 6.0f * rng_next_float(&r) - 1.0f,
                                      12.0f * rng_next_float(&r) - 6.0f);
            struct vec3 c = vec3_make(2.0f * rng_next_float(&r) - 1.0f, 2.0f * rng_next_float(&r) - 1.0f,
                                      2.0f * rng_next_float(&r) - 1.0f);
            struct vec3 dirs[ACCEL_BUNDLE];
            for (uint32_t i = 0; i < n; i++)
                dirs[i] = vec3_normalize(vec3_make(c.x + spread * (2.0f * rng_next_float(&r) - 1.0f),
                                                   c.y + spread * (2.0f * rng_next_float(&r) - 1.0f),
                                                   c.z + spread * (2.0f * rng_next_float(&r) - 1.0f)));
            struct hit got[ACCEL_BUNDLE];
            bool found[ACCEL_BUNDLE];
            memset(got, 0, sizeof got);
            uint32_t count = accel_intersect_bundle(s->accel, o, dirs, n, got, found, &rb);
            uint32_t want_count = 0;
            for (uint32_t i = 0; i < n; i++) {
                struct hit want;
                memset(&want, 0, sizeof want);
                bool h = accel_intersect(s->accel, o, dirs[i], 0.0f, INFINITY, &want, &rc);
                want_count += h;
                if (h != found[i]) {
                    mismatched++;
                    continue;
                }
                if (!h) {
                    misses++;
                    continue;
                }
                hits++;
                if (want.shape == 2 && got[i].shape == 2) {
                    spheres++;
                    float tol = 4e-6f * fmaxf(want.t, 1.0f);
                    mismatched += got[i].prim != want.prim || fabsf(got[i].t - want.t) > tol ||
                                  vec3_length(vec3_sub(got[i].ng, want.ng)) > 4e-6f;
                } else {
                    mismatched += memcmp(&got[i], &want, sizeof want) != 0;
                }
            }
            counted_wrong += count != want_count;
        }
        CHECK_MSG(mismatched == 0, "layout %d: %u bundle answers differ", layout, mismatched);
        CHECK_MSG(counted_wrong == 0, "layout %d: %u bundles returned a wrong hit count", layout, counted_wrong);
        CHECK(hits > 500 && misses > 500 && spheres > 100);  /* hits, misses and the ellipsoid exercised */
        CHECK(rc.intersect == rb.intersect && rb.occluded == 0);
        scene_release(s);
    }
}

static void test_offset_avoids_self_hit(void)
{
    struct scene *s = make_scene(false);
    struct err err = {0};
    CHECK(scene_commit(s, &err));
    struct rng r = rng_make(3, 0, 0, 0);
    struct ray_counters rc = {0, 0};
    int self = 0;
    for (int i = 0; i < 20000; i++) {
        /* Points on the floor far from the origin (large ULPs) leaving at grazing angles. */
        struct vec3 p = vec3_make(4.9f * (2 * rng_next_float(&r) - 1), 0.0f, 4.9f * (2 * rng_next_float(&r) - 1));
        float a = 1e-3f + 0.5f * rng_next_float(&r);
        struct vec3 d = vec3_normalize(vec3_make(cosf(6.28f * a), a * 0.01f, sinf(6.28f * a)));
        struct hit h;
        struct vec3 o = surface_offset(p, vec3_make(0, 1, 0), d);
        if (accel_intersect(s->accel, o, d, 0, INFINITY, &h, &rc) && h.shape == 0) self++;
    }
    CHECK_MSG(self == 0, "%d self-intersections", self);
    scene_release(s);
}

static void test_light_sampler_pdfs(void)
{
    struct scene *s = make_scene(false);
    struct err err = {0};
    CHECK(scene_commit(s, &err));
    const struct light_sampler *ls = s->lights;
    CHECK(light_sampler_count(ls) == 2);  /* the lamp's two triangles */
    struct rng r = rng_make(5, 0, 0, 0);
    double mean_x = 0, mean_z = 0;
    uint32_t last_shape = 0;
    enum { N = 100000 };
    for (int i = 0; i < N; i++) {
        struct light_sample smp;
        if (!light_sampler_sample(ls, rng_next_float(&r), rng_next_float(&r), rng_next_float(&r), &smp)) {
            CHECK_MSG(false, "light sample %d failed", i);
            break;
        }
        CHECK_NEAR(smp.p.y, 5.0f, 1e-6);
        CHECK(fabsf(smp.p.x) <= 1.0f && fabsf(smp.p.z) <= 1.0f);
        CHECK_NEAR(smp.n.y, -1.0f, 1e-6);
        /* Uniform over the 2 x 2 lamp: pdf_a = 1/4 everywhere, and pdf_a() agrees. */
        CHECK_NEAR(smp.pdf_a, 0.25f, 1e-6);
        CHECK_NEAR(light_sampler_pdf_a(ls, smp.shape, smp.prim), smp.pdf_a, 1e-7);
        /* The point rebuilt from its code is the sampled one, bit for bit (restir_pt's shifts rely
         * on it), and the surface's reconstruction of that code within rounding. */
        struct vec3 tp, tn, sp, sn;
        CHECK(light_sampler_triangle_point(ls, smp.shape, smp.prim, smp.b1, smp.b2, &tp, &tn));
        CHECK(memcmp(&tp, &smp.p, sizeof tp) == 0 && memcmp(&tn, &smp.n, sizeof tn) == 0);
        surface_point_at(s, smp.shape, smp.prim, smp.b1, smp.b2, &sp, &sn);
        CHECK(vec3_length(vec3_sub(sp, tp)) < 1e-5f && vec3_length(vec3_sub(sn, tn)) < 1e-5f);
        last_shape = smp.shape;
        mean_x += smp.p.x;
        mean_z += smp.p.z;
    }
    /* Uniform over [-1,1]^2: means 0 with standard error 1/sqrt(3N). */
    CHECK(fabs(mean_x / N) < 4.0 / sqrt(3.0 * N));
    CHECK(fabs(mean_z / N) < 4.0 / sqrt(3.0 * N));
    CHECK(light_sampler_pdf_a(ls, 0, 0) == 0.0f);  /* the floor is no emitter */
    struct vec3 tp = {0}, tn = {0};
    CHECK(!light_sampler_triangle_point(ls, 0, 0, 0.25f, 0.25f, &tp, &tn));            /* not an emitter */
    CHECK(!light_sampler_triangle_point(ls, last_shape, 2, 0.25f, 0.25f, &tp, &tn));   /* no third triangle */
    CHECK(!light_sampler_triangle_point(ls, s->shape_count, 0, 0.25f, 0.25f, &tp, &tn));  /* no such shape */
    CHECK(light_sampler_emitted(&s->materials[1], 0.5f).x == 4.0f);
    CHECK(light_sampler_emitted(&s->materials[1], -0.5f).x == 0.0f);  /* one-sided */
    scene_release(s);
}

/* With several emitters the sampler's table holds them back to back: a primitive past one
 * emissive mesh's last triangle is no emitter, though the table has an entry at that index. */
static void test_light_sampler_triangle_point_per_shape(void)
{
    struct err err = {0};
    struct scene *s = scene_load_file("scenes/refractive-slab/scene.json", &err);
    CHECK_MSG(s != NULL, "%s", err.message);
    if (!s) return;
    CHECK_MSG(scene_commit(s, &err), "%s", err.message);
    uint32_t emissive = 0;
    for (uint32_t i = 0; i < s->shape_count; i++) {
        const struct shape *sh = &s->shapes[i];
        if (sh->kind != SHAPE_MESH || !material_is_emissive(&s->materials[sh->material])) continue;
        struct vec3 p, n;
        CHECK(light_sampler_triangle_point(s->lights, i, sh->triangle_count - 1, 0.2f, 0.3f, &p, &n));
        CHECK(!light_sampler_triangle_point(s->lights, i, sh->triangle_count, 0.2f, 0.3f, &p, &n));
        emissive++;
    }
    CHECK(emissive >= 2);  /* not vacuous: the first emitter's past-the-end index is the next's first */
    scene_release(s);
}

static void test_camera_rays(void)
{
    struct camera_desc d = {{278, 273, -800}, {278, 273, 0}, {0, 1, 0}, 39.3077f};
    struct camera c;
    camera_init(&c, &d, 200, 100);
    struct vec3 mid = camera_ray_dir(&c, 100, 50);
    CHECK_NEAR(mid.z, 1.0f, 1e-6);
    /* The top edge centre is fov/2 above the axis. */
    struct vec3 top = camera_ray_dir(&c, 100, 0);
    CHECK_NEAR(atan2f(top.y, top.z) * 180.0f / PI_F, 39.3077f / 2, 1e-3);
    /* Image right is -x for a camera looking down +z with +y up (right-handed). */
    struct vec3 right = camera_ray_dir(&c, 200, 50);
    CHECK(right.x < 0.0f);
}

/* vec_fmaxf and vec3_v4_max_comp give fmaxf's and vec3_max_comp's results over every pair and
 * triple of special values: NaN in any lane (the other value; NaN only when all are), ±0 in
 * either order, ±Inf, and the pack/unpack round trip keeps the bits. The sign of a zero maximum
 * is left out of the comparison: C leaves fmaxf(+0, -0) to the implementation, and GCC, taking
 * fmaxf as commutative, may swap the operands of glibc's call (which returns the second), so
 * vec3_max_comp's sign there depends on the compiler. Equal non-zero floats have equal bits. */
static bool same_float(float a, float b) { return (a != a && b != b) || a == b; }
static void test_vec3_v4_max(void)
{
    volatile float nan = NAN;  /* not folded: the comparisons run as they do at run time */
    const float v[] = {nan, -nan, 0.0f, -0.0f, 1.0f, -1.0f, 0.5f, INFINITY, -INFINITY, 1e-45f};
    const size_t n = sizeof v / sizeof v[0];
    uint32_t checked = 0;
    for (size_t i = 0; i < n; i++)
        for (size_t j = 0; j < n; j++) {
            CHECK_MSG(same_float(vec_fmaxf(v[i], v[j]), fmaxf(v[i], v[j])), "vec_fmaxf(%g, %g) = %g, fmaxf %g", v[i],
                      v[j], vec_fmaxf(v[i], v[j]), fmaxf(v[i], v[j]));
            for (size_t k = 0; k < n; k++) {
                const struct vec3 a = vec3_make(v[i], v[j], v[k]);
                const vec3_v4 p = vec3_v4_pack(a);
                const struct vec3 back = vec3_v4_unpack(p);
                CHECK(memcmp(&back, &a, sizeof a) == 0 && vec_float_bits(p[3]) == 0);
                const float got = vec3_v4_max_comp(p), want = vec3_max_comp(a);
                CHECK_MSG(same_float(got, want), "max of (%g, %g, %g): %g, vec3_max_comp %g", a.x, a.y, a.z, got, want);
                checked++;
            }
        }
    /* Spelled out: a zero maximum is the second operand, as glibc's maxss-based fmaxf called in
     * that order; the path loop's Russian roulette only asks whether it is > 0. */
    CHECK(vec_float_bits(vec_fmaxf(0.0f, -0.0f)) == vec_float_bits(-0.0f));
    CHECK(vec_float_bits(vec_fmaxf(-0.0f, 0.0f)) == vec_float_bits(0.0f));
    CHECK(vec_fmaxf(nan, 2.0f) == 2.0f && vec_fmaxf(2.0f, nan) == 2.0f && isnan(vec_fmaxf(nan, nan)));
    CHECK(vec3_v4_max_comp(vec3_v4_pack(vec3_make(nan, nan, 0.25f))) == 0.25f);
    printf("  %u triples alike\n", checked);
}

TEST_MAIN(TEST(test_vec3_v4_max), TEST(test_rng_uniform_chi2), TEST(test_rng_streams_differ),
          TEST(test_rng_keyed_first_numbers_chi2), TEST(test_rng_pixel_samples_chi2), TEST(test_sobol_generator),
          TEST(test_sobol_nets), TEST(test_sobol_scrambling_chi2), TEST(test_sobol_padding_independent_chi2),
          TEST(test_sobol_convergence), TEST(test_sobol_batch_matches_scalar), TEST(test_sobol_batch_run_matches),
          TEST(test_distrib_chi2), TEST(test_accel_flat_and_two_level), TEST(test_accel_move_instance),
          TEST(test_accel_query_matches), TEST(test_accel_bundle_matches), TEST(test_offset_avoids_self_hit), TEST(test_light_sampler_pdfs),
          TEST(test_light_sampler_triangle_point_per_shape), TEST(test_camera_rays))
