/* exr_encode.c — benchmark (not a test): single-thread encode time of a 1920x1080 RGBA HALF
 * frame to memory with ZIP, PIZ and NONE (baseline), median wall and thread-CPU time of N runs,
 * one JSON line. (The key "zip1" is kept from when ZIP meant zlib level 1; exrio.c says which
 * deflate encoder a ZIP chunk gets now.)
 * Usage: exr_encode [-n RUNS] [-o PREFIX] [-c LIST] [-s | -i FILE.exr]
 *   -o  also writes PREFIX_zip1.exr, PREFIX_piz.exr, to check with oiiotool --stats / iinfo -v
 *   -c  runs only the listed codecs of zip1,piz,none (e.g. one codec under callgrind)
 *   -s  the built-in image without its noise (smooth, very compressible content)
 *   -i  encodes this EXR's RGB (e.g. a render) instead of the built-in image
 * Built-in content is deterministic: smooth gradients and waves plus per-pixel hash noise,
 * roughly like a low-spp render. Must not be wired into pass/fail tests (timings are
 * machine-dependent). */
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "image/exrio.h"

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

static void fill(struct image *img, bool smooth)
{
    for (uint32_t y = 0; y < img->height; y++)
        for (uint32_t x = 0; x < img->width; x++) {
            float u = (float)x / img->width, v = (float)y / img->height;
            float base = 0.5f + 0.4f * sinf(6.0f * u + 2.0f * v) * cosf(4.0f * v);
            uint32_t i = y * img->width + x;
            float noise = smooth ? 0.0f : 0.15f * (hash_unit(3 * i) - 0.5f);
            float blue_noise = smooth ? 0.0f : 0.5f * hash_unit(3 * i + 1) * 0.2f;
            img->pixels[i] = vec3_make(base * (0.8f + u) + noise,
                                       base * (0.6f + v) + 0.7f * noise,
                                       base * 0.9f + blue_noise);
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

/* The codecs, in the order they run and print; -c picks a subset (e.g. for callgrind). */
static const struct {
    const char *tag;
    enum exrio_compression comp;
} codecs[] = {{"zip1", EXRIO_ZIP}, {"piz", EXRIO_PIZ}, {"none", EXRIO_NONE}};
#define NCODECS (int)(sizeof codecs / sizeof codecs[0])

int main(int argc, char **argv)
{
    int runs = 20;
    const char *prefix = NULL, *only = NULL, *input = NULL;
    bool smooth = false;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "-n") == 0 && i + 1 < argc) runs = atoi(argv[++i]);
        else if (strcmp(argv[i], "-o") == 0 && i + 1 < argc) prefix = argv[++i];
        else if (strcmp(argv[i], "-c") == 0 && i + 1 < argc) only = argv[++i];
        else if (strcmp(argv[i], "-i") == 0 && i + 1 < argc) input = argv[++i];
        else if (strcmp(argv[i], "-s") == 0) smooth = true;
        else {
            fprintf(stderr, "usage: %s [-n RUNS] [-o PREFIX] [-c zip1,piz,none] [-s | -i FILE.exr]\n",
                    argv[0]);
            return 2;
        }
    }
    if (runs < 1) runs = 1;
    bool run[NCODECS];
    for (int k = 0; k < NCODECS; k++) {
        run[k] = true;
        if (only) {
            /* the tag as a whole comma-separated item of the list */
            size_t len = strlen(codecs[k].tag);
            const char *p = only;
            run[k] = false;
            while ((p = strstr(p, codecs[k].tag)) != NULL) {
                if ((p == only || p[-1] == ',') && (p[len] == ',' || p[len] == '\0')) run[k] = true;
                p += len;
            }
        }
    }
    struct image img;
    struct err err = {0};
    if (input ? !exrio_read_file(input, &img, &err) : !image_init(&img, 1920, 1080, &err)) {
        fprintf(stderr, "exr_encode: %s\n", err.message);
        return 1;
    }
    if (!input) fill(&img, smooth);
    /* NONE is the baseline: packing (float -> half) and copying without a codec. */
    double ms[NCODECS] = {0}, cpu[NCODECS] = {0};
    size_t bytes[NCODECS] = {0};
    bool ok = true;
    for (int k = 0; ok && k < NCODECS; k++)
        if (run[k]) ok = time_encode(&img, codecs[k].comp, runs, &ms[k], &cpu[k], &bytes[k]);
    if (ok && prefix) {
        char path[1024];
        for (int k = 0; ok && k < NCODECS; k++) {
            if (!run[k] || codecs[k].comp == EXRIO_NONE) continue;
            struct exrio_write_opts o = {.pixel = EXRIO_HALF, .compression = codecs[k].comp, .alpha = true};
            snprintf(path, sizeof path, "%s_%s.exr", prefix, codecs[k].tag);
            ok = exrio_write_file(path, &img, &o, &err);
            if (!ok) fprintf(stderr, "exr_encode: %s: %s\n", err.where, err.message);
        }
    }
    if (ok) {
        printf("{\"width\":%u,\"height\":%u,\"channels\":\"RGBA\",\"pixel\":\"half\",\"runs\":%d",
               img.width, img.height, runs);
        if (input) {
            printf(",\"content\":\"");
            for (const char *c = input; *c; c++) printf(*c == '"' || *c == '\\' ? "\\%c" : "%c", *c);
            printf("\"");
        } else if (smooth) {
            printf(",\"content\":\"smooth\"");
        }
        for (int k = 0; k < NCODECS; k++)
            if (run[k]) printf(",\"%s_ms\":%.2f", codecs[k].tag, ms[k]);
        for (int k = 0; k < NCODECS; k++)
            if (run[k]) printf(",\"%s_cpu_ms\":%.2f", codecs[k].tag, cpu[k]);
        for (int k = 0; k < NCODECS; k++)
            if (run[k]) printf(",\"%s_bytes\":%zu", codecs[k].tag, bytes[k]);
        printf("}\n");
    }
    image_destroy(&img);
    return ok ? 0 : 1;
}
