/* exr_encode.c — benchmark (not a test): single-thread encode time of a 1920x1080 RGBA HALF
 * frame to memory with ZIP (zlib level 1), PIZ and NONE (baseline), median wall and thread-CPU
 * time of N runs, one JSON line.
 * Usage: exr_encode [-n RUNS] [-o PREFIX]   (-o also writes PREFIX_zip1.exr, PREFIX_piz.exr
 * so the output can be checked with oiiotool --stats / iinfo -v).
 * Content is deterministic: smooth gradients and waves plus per-pixel hash noise, roughly like
 * a low-spp render. Must not be wired into pass/fail tests (timings are machine-dependent). */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "exrio.h"

static double clock_ms(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Integer hash to [0, 1): deterministic per-pixel noise. */
static float hash_unit(uint32_t x)
{
    x ^= x >> 16;
    x *= 0x7feb352dU;
    x ^= x >> 15;
    x *= 0x846ca68bU;
    x ^= x >> 16;
    return (float)(x >> 8) * (1.0f / 16777216.0f);
}

static void fill(struct image *img)
{
    for (uint32_t y = 0; y < img->height; y++)
        for (uint32_t x = 0; x < img->width; x++) {
            float u = (float)x / img->width, v = (float)y / img->height;
            float base = 0.5f + 0.4f * sinf(6.0f * u + 2.0f * v) * cosf(4.0f * v);
            uint32_t i = y * img->width + x;
            float noise = 0.15f * (hash_unit(3 * i) - 0.5f);
            img->pixels[i] = vec3_make(base * (0.8f + u) + noise,
                                       base * (0.6f + v) + 0.7f * noise,
                                       base * 0.9f + 0.5f * hash_unit(3 * i + 1) * 0.2f);
        }
}

static double median(double *t, int n)
{
    qsort(t, (size_t)n, sizeof *t, cmp_double);
    return n % 2 ? t[n / 2] : 0.5 * (t[n / 2 - 1] + t[n / 2]);
}

/* Median wall and thread-CPU encode times in ms over `runs` encodes; *bytes gets the encoded
 * size. CPU time is reported too because shared machines inflate wall time. */
static bool time_encode(const struct image *img, enum exrio_compression comp, int runs,
                        double *wall_ms, double *cpu_ms, size_t *bytes)
{
    double *t = malloc(sizeof *t * 2 * (size_t)runs);
    if (!t) return false;
    double *c = t + runs;
    struct exrio_write_opts o = {.pixel = EXRIO_HALF, .compression = comp, .alpha = true};
    for (int r = 0; r < runs; r++) {
        unsigned char *buf = NULL;
        size_t size = 0;
        struct err err = {0};
        double t0 = clock_ms(CLOCK_MONOTONIC), c0 = clock_ms(CLOCK_THREAD_CPUTIME_ID);
        bool ok = exrio_write_mem(img, &o, &buf, &size, &err);
        t[r] = clock_ms(CLOCK_MONOTONIC) - t0;
        c[r] = clock_ms(CLOCK_THREAD_CPUTIME_ID) - c0;
        free(buf);
        if (!ok) {
            fprintf(stderr, "exr_encode: %s: %s\n", exrio_compression_name(comp), err.message);
            free(t);
            return false;
        }
        *bytes = size;
    }
    *wall_ms = median(t, runs);
    *cpu_ms = median(c, runs);
    free(t);
    return true;
}

int main(int argc, char **argv)
{
    int runs = 20;
    const char *prefix = NULL;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "-n") == 0 && i + 1 < argc) runs = atoi(argv[++i]);
        else if (strcmp(argv[i], "-o") == 0 && i + 1 < argc) prefix = argv[++i];
        else {
            fprintf(stderr, "usage: %s [-n RUNS] [-o PREFIX]\n", argv[0]);
            return 2;
        }
    }
    if (runs < 1) runs = 1;
    struct image img;
    struct err err = {0};
    if (!image_init(&img, 1920, 1080, &err)) {
        fprintf(stderr, "exr_encode: %s\n", err.message);
        return 1;
    }
    fill(&img);
    /* NONE is the baseline: packing (float -> half) and copying without a codec. */
    double zip_ms = 0, piz_ms = 0, none_ms = 0, zip_cpu = 0, piz_cpu = 0, none_cpu = 0;
    size_t zip_bytes = 0, piz_bytes = 0, none_bytes = 0;
    bool ok = time_encode(&img, EXRIO_ZIP, runs, &zip_ms, &zip_cpu, &zip_bytes) &&
              time_encode(&img, EXRIO_PIZ, runs, &piz_ms, &piz_cpu, &piz_bytes) &&
              time_encode(&img, EXRIO_NONE, runs, &none_ms, &none_cpu, &none_bytes);
    if (ok && prefix) {
        char path[1024];
        static const enum exrio_compression comps[2] = {EXRIO_ZIP, EXRIO_PIZ};
        static const char *const tags[2] = {"zip1", "piz"};
        for (int k = 0; ok && k < 2; k++) {
            struct exrio_write_opts o = {.pixel = EXRIO_HALF, .compression = comps[k], .alpha = true};
            snprintf(path, sizeof path, "%s_%s.exr", prefix, tags[k]);
            ok = exrio_write_file(path, &img, &o, &err);
            if (!ok) fprintf(stderr, "exr_encode: %s: %s\n", err.where, err.message);
        }
    }
    if (ok)
        printf("{\"width\":1920,\"height\":1080,\"channels\":\"RGBA\",\"pixel\":\"half\",\"runs\":%d,"
               "\"zip1_ms\":%.2f,\"piz_ms\":%.2f,\"none_ms\":%.2f,"
               "\"zip1_cpu_ms\":%.2f,\"piz_cpu_ms\":%.2f,\"none_cpu_ms\":%.2f,"
               "\"zip1_bytes\":%zu,\"piz_bytes\":%zu,\"none_bytes\":%zu}\n",
               runs, zip_ms, piz_ms, none_ms, zip_cpu, piz_cpu, none_cpu, zip_bytes, piz_bytes,
               none_bytes);
    image_destroy(&img);
    return ok ? 0 : 1;
}
