/* test_exrio.c — EXR write/read round trips, the reader's header gate, and robustness against
 * truncated and corrupted input (run it under ASan: make SAN=1).
 * Independent of exrio internals: headers for gate tests are built byte by byte here from the
 * OpenEXR file layout, and AOV values are checked by parsing uncompressed chunks directly.
 * Refs: OpenEXR "File Layout" document (magic, version flags, attributes, offset tables). */
#include <dirent.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "image/deflate.h"
#include "image/exrio.h"
#include "core/rng.h"
#include "test.h"
#if defined(__SSE2__)
#include <xmmintrin.h>
#endif

/* ---- helpers ----------------------------------------------------------------------------- */

/* The project's own generator (rng.h), one stream for the whole file. */
static struct rng test_rng = {0};
static bool test_rng_seeded = false;
static uint32_t rnd_u32(void)
{
    if (!test_rng_seeded) {
        test_rng = rng_make(0x9e3779b97f4a7c15ull, 0, 0, 0);
        test_rng_seeded = true;
    }
    return rng_next_u32(&test_rng);
}
static double rnd_unit(void) { return (rnd_u32() >> 8) * (1.0 / 16777216.0); }

/* Random finite floats from the whole bit space (any exponent, sign, subnormals, zeros). */
static float rnd_finite_float(void)
{
    for (;;) {
        uint32_t bits = rnd_u32();
        float f;
        memcpy(&f, &bits, sizeof f);
        if (isfinite(f)) return f;
    }
}

static struct image make_image(uint32_t w, uint32_t h, int kind)
{
    struct image img;
    struct err err;
    if (!image_init(&img, w, h, &err)) return img;
    for (size_t i = 0; i < (size_t)w * h; i++) {
        float v[3];
        for (int c = 0; c < 3; c++) {
            if (kind == 0) v[c] = rnd_finite_float();
            else v[c] = (float)(1e-3 * pow(6e4 / 1e-3, rnd_unit())); /* log-uniform [1e-3, 6e4] */
        }
        img.pixels[i] = vec3_make(v[0], v[1], v[2]);
    }
    if (kind == 0 && (size_t)w * h >= 2) {
        /* FLOAT must carry every value bit for bit, non-finite ones included. */
        img.pixels[0] = vec3_make(NAN, INFINITY, -INFINITY);
        img.pixels[1] = vec3_make(-0.0f, 0x1p-149f, -NAN);
    }
    return img;
}

/* Largest relative error between two images' channels; NaN (never <=) makes it NaN, so a
 * decoder that produced NaN fails every `worst <= tol` check. */
static double max_rel_err(const struct image *ref, const struct image *got)
{
    double worst = 0.0;
    for (size_t i = 0; i < (size_t)ref->width * ref->height; i++)
        for (int c = 0; c < 3; c++) {
            double a = vec3_comp(ref->pixels[i], c), b = vec3_comp(got->pixels[i], c);
            double e = fabs(a - b) / fabs(a);
            if (!(e <= worst)) worst = e;
        }
    return worst;
}

static bool same_bits(const struct image *a, const struct image *b)
{
    return a->width == b->width && a->height == b->height &&
           memcmp(a->pixels, b->pixels, sizeof *a->pixels * a->width * a->height) == 0;
}

static void tmp_path(char *buf, size_t size, const char *tag)
{
    snprintf(buf, size, "/tmp/restird_test_exrio_%ld_%s.exr", (long)getpid(), tag);
}

static unsigned char *encode(const struct image *img, struct exrio_write_opts opts, size_t *size)
{
    unsigned char *buf = NULL;
    struct err err = {0};
    bool ok = exrio_write_mem(img, &opts, &buf, size, &err);
    CHECK_MSG(ok, "write: %s", err.message);
    return ok ? buf : NULL;
}

/* ---- byte-level EXR builder (for headers exrio would never write) ------------------------- */

struct bytes {
    unsigned char *p;
    size_t n, cap;
};
static void put(struct bytes *b, const void *src, size_t n)
{
    if (b->n + n > b->cap) {
        size_t cap = b->cap ? b->cap : 256;
        while (cap < b->n + n) cap *= 2;
        b->p = realloc(b->p, cap);
        b->cap = cap;
    }
    memcpy(b->p + b->n, src, n);
    b->n += n;
}
static void put_u8(struct bytes *b, uint8_t v) { put(b, &v, 1); }
static void put_i32(struct bytes *b, int32_t v)  /* little-endian, as EXR stores it */
{
    uint8_t x[4] = {(uint8_t)v, (uint8_t)(v >> 8), (uint8_t)(v >> 16), (uint8_t)((uint32_t)v >> 24)};
    put(b, x, 4);
}
static void put_u64(struct bytes *b, uint64_t v)
{
    for (int i = 0; i < 8; i++) put_u8(b, (uint8_t)(v >> (8 * i)));
}
static void put_f32(struct bytes *b, float f)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    put_i32(b, (int32_t)u);
}
/* Half bits of a small non-negative integer (exact below 2048). */
static uint16_t half_of_int(int v)
{
    if (v == 0) return 0;
    int e = 0;
    while ((v >> (e + 1)) != 0) e++;
    return (uint16_t)(((e + 15) << 10) | (((v << 10) >> e) & 0x3ff));
}
static void put_str(struct bytes *b, const char *s) { put(b, s, strlen(s) + 1); }
static void put_attr(struct bytes *b, const char *name, const char *type, int32_t size)
{
    put_str(b, name);
    put_str(b, type);
    put_i32(b, size);
}

struct craft {
    int32_t width, height;
    int nch;
    const char *names[12];
    int32_t types[12];   /* 0 UINT, 1 HALF, 2 FLOAT */
    int32_t xs, ys;      /* sampling for every channel (0 means 1) */
    uint8_t compression; /* 0 NONE, 4 PIZ, ... */
    bool tiled;
    int parts;           /* 0 or 1: single part; 2: multi-part */
    bool pixels;         /* append uncompressed pixels: FLOAT x + 1000*y + channel/10,
                            HALF x + 8*y + channel (small integers, exact in half) */
};

static void craft_header(struct bytes *b, const struct craft *c, int part)
{
    int32_t xs = c->xs ? c->xs : 1, ys = c->ys ? c->ys : 1;
    int32_t chsize = 1;
    for (int i = 0; i < c->nch; i++) chsize += (int32_t)strlen(c->names[i]) + 1 + 16;
    put_attr(b, "channels", "chlist", chsize);
    for (int i = 0; i < c->nch; i++) {
        put_str(b, c->names[i]);
        put_i32(b, c->types[i]);
        put_i32(b, 0); /* pLinear + reserved */
        put_i32(b, xs);
        put_i32(b, ys);
    }
    put_u8(b, 0);
    put_attr(b, "compression", "compression", 1);
    put_u8(b, c->compression);
    for (int k = 0; k < 2; k++) {
        put_attr(b, k ? "displayWindow" : "dataWindow", "box2i", 16);
        put_i32(b, 0);
        put_i32(b, 0);
        put_i32(b, c->width - 1);
        put_i32(b, c->height - 1);
    }
    put_attr(b, "lineOrder", "lineOrder", 1);
    put_u8(b, 0);
    put_attr(b, "pixelAspectRatio", "float", 4);
    put_f32(b, 1.0f);
    put_attr(b, "screenWindowCenter", "v2f", 8);
    put_f32(b, 0.0f);
    put_f32(b, 0.0f);
    put_attr(b, "screenWindowWidth", "float", 4);
    put_f32(b, 1.0f);
    if (c->tiled) {
        put_attr(b, "tiles", "tiledesc", 9);
        put_i32(b, 16);
        put_i32(b, 16);
        put_u8(b, 0); /* ONE_LEVEL, round down */
    }
    if (c->parts > 1) {
        char name[16];
        snprintf(name, sizeof name, "part%d", part);
        put_attr(b, "name", "string", (int32_t)strlen(name));
        put(b, name, strlen(name));
        const char *type = "scanlineimage";
        put_attr(b, "type", "string", (int32_t)strlen(type));
        put(b, type, strlen(type));
        put_attr(b, "chunkCount", "int", 4);
        put_i32(b, c->height);
    }
    put_u8(b, 0);
}

/* A complete file for uncompressed scanline headers (one row per chunk), header-only with a
 * zeroed offset table otherwise. Caller frees. */
static unsigned char *craft_file(const struct craft *c, size_t *size)
{
    struct bytes b = {0};
    static const uint8_t magic[4] = {0x76, 0x2f, 0x31, 0x01};
    put(&b, magic, 4);
    int32_t version = 2 | (c->tiled ? 0x200 : 0) | (c->parts > 1 ? 0x1000 : 0);
    put_i32(&b, version);
    int parts = c->parts > 1 ? c->parts : 1;
    for (int p = 0; p < parts; p++) craft_header(&b, c, p);
    if (parts > 1) put_u8(&b, 0);
    int64_t chunks = c->tiled ? ((c->width + 15) / 16) * (int64_t)((c->height + 15) / 16) : c->height;
    size_t table = b.n;
    for (int p = 0; p < parts; p++)
        for (int64_t i = 0; i < chunks; i++) put_u64(&b, 0);
    if (c->pixels && !c->tiled && parts == 1) {
        for (int32_t y = 0; y < c->height; y++) {
            uint64_t off = b.n;
            memcpy(b.p + table + 8 * (size_t)y, &off, 8); /* little-endian host assumed */
            put_i32(&b, y);
            int32_t bytes = 0;
            for (int ch = 0; ch < c->nch; ch++) bytes += c->width * (c->types[ch] == 1 ? 2 : 4);
            put_i32(&b, bytes);
            for (int ch = 0; ch < c->nch; ch++)
                for (int32_t x = 0; x < c->width; x++) {
                    if (c->types[ch] == 1) {
                        uint16_t hb = half_of_int(x + 8 * y + ch);
                        put(&b, &hb, 2);
                    } else {
                        put_f32(&b, (float)x + 1000.0f * y + ch / 10.0f);
                    }
                }
        }
    }
    *size = b.n;
    return b.p;
}

static struct err read_crafted(const struct craft *c, bool expect_ok)
{
    size_t size = 0;
    unsigned char *buf = craft_file(c, &size);
    struct image img = {0};
    struct err err = {0};
    bool ok = exrio_read_mem(buf, size, "crafted.exr", &img, &err);
    CHECK_MSG(ok == expect_ok, "read_mem -> %d (%s: %s)", ok, err_code_name(err.code), err.message);
    if (ok) image_destroy(&img);
    free(buf);
    return err;
}

/* ---- round trips -------------------------------------------------------------------------- */

static void test_float_roundtrip_mem(void)
{
    static const enum exrio_compression comps[] = {EXRIO_NONE, EXRIO_RLE, EXRIO_ZIPS, EXRIO_ZIP};
    struct image img = make_image(37, 41, 0); /* 41 rows: ZIP's last 16-row block is partial */
    for (size_t k = 0; k < sizeof comps / sizeof comps[0]; k++) {
        for (int alpha = 0; alpha < 2; alpha++) {
            struct exrio_write_opts o = {.pixel = EXRIO_FLOAT, .compression = comps[k], .alpha = alpha};
            size_t size = 0;
            unsigned char *buf = encode(&img, o, &size);
            if (!buf) continue;
            struct image back;
            struct err err = {0};
            bool ok = exrio_read_mem(buf, size, "rt.exr", &back, &err);
            CHECK_MSG(ok, "%s alpha=%d: %s", exrio_compression_name(comps[k]), alpha, err.message);
            if (ok) {
                CHECK_MSG(same_bits(&img, &back), "%s alpha=%d not bit-exact",
                          exrio_compression_name(comps[k]), alpha);
                image_destroy(&back);
            }
            struct exrio_info info;
            CHECK(exrio_probe_mem(buf, size, NULL, &info, &err));
            CHECK(info.compression == comps[k]);
            CHECK(info.width == 37 && info.height == 41 && info.parts == 1 && !info.tiled);
            free(buf);
        }
    }
    image_destroy(&img);
}

static void test_float_roundtrip_file(void)
{
    char path[256];
    tmp_path(path, sizeof path, "float");
    struct image img = make_image(64, 33, 0);
    struct exrio_write_opts o = {.pixel = EXRIO_FLOAT, .compression = EXRIO_ZIP, .alpha = true};
    struct err err = {0};
    CHECK_MSG(exrio_write_file(path, &img, &o, &err), "%s", err.message);
    struct image back;
    bool ok = exrio_read_file(path, &back, &err);
    CHECK_MSG(ok, "%s", err.message);
    if (ok) {
        CHECK(same_bits(&img, &back));
        image_destroy(&back);
    }
    /* The file holds exactly the bytes the memory encoder produces (encoding is deterministic). */
    size_t size = 0;
    unsigned char *buf = encode(&img, o, &size);
    FILE *f = fopen(path, "rb");
    CHECK(f != NULL);
    if (f && buf) {
        unsigned char *disk = malloc(size + 1);
        size_t got = fread(disk, 1, size + 1, f);
        CHECK(got == size && memcmp(disk, buf, size) == 0);
        free(disk);
    }
    if (f) fclose(f);
    free(buf);
    /* Overwriting replaces the file whole (written beside it, then renamed) and leaves no
     * temporary file behind. */
    struct image small = make_image(3, 2, 1);
    CHECK_MSG(exrio_write_file(path, &small, &o, &err), "%s", err.message);
    ok = exrio_read_file(path, &back, &err);
    CHECK(ok && back.width == 3 && back.height == 2);
    if (ok) image_destroy(&back);
    char tmp_prefix[300];
    snprintf(tmp_prefix, sizeof tmp_prefix, "%s.tmp-", strrchr(path, '/') + 1);
    DIR *d = opendir("/tmp");
    int leftovers = 0;
    for (struct dirent *de; d && (de = readdir(d));) leftovers += strncmp(de->d_name, tmp_prefix, strlen(tmp_prefix)) == 0;
    if (d) closedir(d);
    CHECK(leftovers == 0);
    image_destroy(&small);
    remove(path);
    image_destroy(&img);
}

static void test_half_roundtrip(void)
{
    struct image img = make_image(50, 20, 1);
    static const enum exrio_compression comps[] = {EXRIO_NONE, EXRIO_ZIP, EXRIO_RLE};
    for (size_t k = 0; k < 3; k++) {
        struct exrio_write_opts o = {.pixel = EXRIO_HALF, .compression = comps[k], .alpha = true};
        size_t size = 0;
        unsigned char *buf = encode(&img, o, &size);
        if (!buf) continue;
        struct image back;
        struct err err = {0};
        bool ok = exrio_read_mem(buf, size, NULL, &back, &err);
        CHECK_MSG(ok, "%s", err.message);
        if (ok) {
            double worst = max_rel_err(&img, &back);
            CHECK_MSG(worst <= 1e-3, "worst relative error %g", worst);
            CHECK(worst > 0.0); /* it really went through half */
            image_destroy(&back);
        }
        struct exrio_info info;
        CHECK(exrio_probe_mem(buf, size, NULL, &info, &err));
        CHECK(info.channel_count == 4 && info.channels[0].pixel == EXRIO_HALF);
        free(buf);
    }
    image_destroy(&img);
}

/* Byte offset just past the header of a single-part file (start of the offset table). */
static size_t header_end(const unsigned char *p, size_t n)
{
    size_t i = 8;
    while (i < n && p[i] != 0) {
        i += strlen((const char *)p + i) + 1;                 /* name */
        i += strlen((const char *)p + i) + 1;                 /* type */
        int32_t sz;
        memcpy(&sz, p + i, 4);
        i += 4 + (size_t)sz;
    }
    return i + 1;
}

/* HALF keeps NaN and +-Inf and turns finite values beyond 65504 into +-Inf (exrio.h). */
static void test_half_nonfinite(void)
{
    struct err err = {0};
    struct image img;
    CHECK(image_init(&img, 2, 1, &err));
    img.pixels[0] = vec3_make(NAN, INFINITY, -INFINITY);
    img.pixels[1] = vec3_make(70000.0f, -70000.0f, 65504.0f);
    static const enum exrio_compression comps[] = {EXRIO_NONE, EXRIO_ZIP};
    for (int k = 0; k < 2; k++) {
        size_t size = 0;
        unsigned char *buf = encode(&img, (struct exrio_write_opts){.pixel = EXRIO_HALF, .compression = comps[k]}, &size);
        if (!buf) continue;
        struct image back;
        if (exrio_read_mem(buf, size, NULL, &back, &err)) {
            CHECK(isnan(back.pixels[0].x));
            CHECK(back.pixels[0].y == INFINITY && back.pixels[0].z == -INFINITY);
            CHECK(back.pixels[1].x == INFINITY && back.pixels[1].y == -INFINITY);
            CHECK(back.pixels[1].z == 65504.0f);
            image_destroy(&back);
        } else {
            CHECK_MSG(false, "%s", err.message);
        }
        free(buf);
    }
    image_destroy(&img);
}

static void test_aov_channels(void)
{
    const uint32_t w = 9, h = 5;
    struct image img = make_image(w, h, 1);
    float albedo[9 * 5 * 3], depth[9 * 5];
    for (size_t i = 0; i < w * h * 3; i++) albedo[i] = (float)i * 0.25f;
    for (size_t i = 0; i < w * h; i++) depth[i] = 100.0f + (float)i;
    struct exrio_aov aovs[2] = {{.name = "albedo", .channels = 3, .data = albedo},
                                {.name = "depth", .channels = 1, .data = depth, .suffix = "Z"}};
    struct exrio_write_opts o = {.pixel = EXRIO_HALF, .compression = EXRIO_NONE, .alpha = true,
                                 .aovs = aovs, .aov_count = 2};
    size_t size = 0;
    unsigned char *buf = encode(&img, o, &size);
    if (!buf) return;
    struct exrio_info info;
    struct err err = {0};
    CHECK_MSG(exrio_probe_mem(buf, size, "aov.exr", &info, &err), "%s", err.message);
    static const char *const want[] = {"A", "B", "G", "R", "albedo.B", "albedo.G", "albedo.R", "depth.Z"};
    CHECK(info.channel_count == 8);
    for (int c = 0; c < 8 && c < info.channel_count; c++) {
        CHECK_MSG(strcmp(info.channels[c].name, want[c]) == 0, "channel %d is %s", c, info.channels[c].name);
        CHECK(info.channels[c].pixel == (c < 4 ? EXRIO_HALF : EXRIO_FLOAT));
        CHECK(info.channels[c].x_sampling == 1 && info.channels[c].y_sampling == 1);
    }
    /* Parse the uncompressed chunks: rows hold A,B,G,R as half then the AOVs as float. */
    size_t table = header_end(buf, size);
    bool values_ok = table + 8 * h <= size;
    for (uint32_t y = 0; values_ok && y < h; y++) {
        uint64_t off;
        memcpy(&off, buf + table + 8 * y, 8);
        int32_t row, bytes;
        memcpy(&row, buf + off, 4);
        memcpy(&bytes, buf + off + 4, 4);
        values_ok = row == (int32_t)y && bytes == (int32_t)(w * (4 * 2 + 4 * 4)) &&
                    off + 8 + (uint64_t)bytes <= size;
        const unsigned char *floats = buf + off + 8 + w * 4 * 2;
        for (uint32_t x = 0; values_ok && x < w; x++) {
            float ab, ag, ar, z;
            memcpy(&ab, floats + 4 * (0 * w + x), 4);
            memcpy(&ag, floats + 4 * (1 * w + x), 4);
            memcpy(&ar, floats + 4 * (2 * w + x), 4);
            memcpy(&z, floats + 4 * (3 * w + x), 4);
            size_t i = (size_t)y * w + x;
            values_ok = ar == albedo[3 * i] && ag == albedo[3 * i + 1] && ab == albedo[3 * i + 2] &&
                        z == depth[i];
        }
    }
    CHECK(values_ok);
    /* 8 channels is the gate's maximum: still readable, beauty only. */
    struct image back;
    CHECK_MSG(exrio_read_mem(buf, size, NULL, &back, &err), "%s", err.message);
    if (back.pixels) image_destroy(&back);
    free(buf);
    image_destroy(&img);
}

static void test_write_rejects_bad_input(void)
{
    struct image img = make_image(4, 4, 1);
    float d[16] = {0};
    unsigned char *buf = (unsigned char *)1;
    size_t size = 1;
    struct err err = {0};
    struct exrio_aov bad[] = {{.name = "al.bedo", .channels = 3, .data = d},
                              {.name = "x", .channels = 2, .data = d},
                              {.name = "x", .channels = 1, .data = NULL},
                              {.name = "averyveryveryverylongname_abcdefgh", .channels = 1, .data = d}};
    for (int k = 0; k < 4; k++) {
        struct exrio_write_opts o = {.pixel = EXRIO_FLOAT, .aovs = &bad[k], .aov_count = 1};
        CHECK(!exrio_write_mem(&img, &o, &buf, &size, &err));
        CHECK(err.code == ERR_INVALID && buf == NULL && size == 0);
    }
    struct exrio_aov dup[] = {{.name = "n", .channels = 1, .data = d}, {.name = "n", .channels = 1, .data = d}};
    struct exrio_write_opts o = {.pixel = EXRIO_FLOAT, .aovs = dup, .aov_count = 2};
    CHECK(!exrio_write_mem(&img, &o, &buf, &size, &err) && err.code == ERR_INVALID);
    o = (struct exrio_write_opts){.pixel = EXRIO_UINT};
    CHECK(!exrio_write_mem(&img, &o, &buf, &size, &err) && err.code == ERR_INVALID);
    o = (struct exrio_write_opts){.pixel = EXRIO_FLOAT, .compression = EXRIO_OTHER};
    CHECK(!exrio_write_mem(&img, &o, &buf, &size, &err) && err.code == ERR_INVALID);
    o = (struct exrio_write_opts){.pixel = EXRIO_FLOAT};
    CHECK(!exrio_write_file("/nonexistent-dir/x.exr", &img, &o, &err));
    CHECK(err.code == ERR_NOT_FOUND && strcmp(err.where, "/nonexistent-dir/x.exr") == 0);
    image_destroy(&img);
}

/* Regression: rows of graded compressibility make some ZIPS chunks deflate to exactly their raw
 * size; libOpenEXRCore 3.1.5 then stored zlib bytes that every reader takes as raw. */
static void test_zip_output_equal_to_raw_size(void)
{
    const uint32_t w = 64, h = 4096;
    struct image img;
    struct err err = {0};
    if (!image_init(&img, w, h, &err)) { CHECK(0); return; }
    rnd_u32();  /* seeds the file's stream if needed */
    struct rng saved = test_rng;
    test_rng = rng_make(12345, 0, 0, 0);
    for (uint32_t y = 0; y < h; y++)
        for (uint32_t x = 0; x < w; x++) {
            float v[3];
            for (uint32_t c = 0; c < 3; c++) {
                /* Row y: the first y/4096 of its floats random, the rest 1.0f. */
                uint32_t bits = (x * 3 + c) * 4096 < y * w * 3 ? (rnd_u32() & 0x3fffffffu) : 0x3f800000u;
                memcpy(&v[c], &bits, sizeof bits);
            }
            img.pixels[(size_t)y * w + x] = vec3_make(v[0], v[1], v[2]);
        }
    test_rng = saved;
    struct exrio_write_opts o = {.pixel = EXRIO_FLOAT, .compression = EXRIO_ZIPS};
    size_t size = 0;
    unsigned char *buf = encode(&img, o, &size);
    struct image back;
    if (buf) {
        CHECK_MSG(exrio_read_mem(buf, size, NULL, &back, &err), "%s", err.message);
        if (back.pixels) {
            CHECK(same_bits(&img, &back));
            image_destroy(&back);
        }
        free(buf);
    }
    image_destroy(&img);
}

/* ---- float -> half exactness and the ZIP path ----------------------------------------------
 * exrio converts HALF itself (F16C when the CPU has it, else a portable routine; the
 * environment variable RESTIRD_EXR_HALF=portable forces the latter) and must give exactly
 * libOpenEXRCore's float_to_half: round to nearest even, >= 65520 -> Inf, NaN keeps its top 10
 * payload bits (at least one set, no quiet bit added). The reference below computes the same
 * thing a different way, in double arithmetic. */

static uint16_t ref_half(uint32_t bits)
{
    uint16_t sign = (uint16_t)((bits >> 16) & 0x8000u);
    uint32_t a = bits & 0x7fffffffu;
    if (a > 0x7f800000u) {
        uint32_t pay = (a & 0x7fffffu) >> 13;
        return (uint16_t)(sign | 0x7c00u | (pay ? pay : 1u));
    }
    float f;
    memcpy(&f, &a, sizeof f);
    double v = f;
    if (v >= 65520.0) return (uint16_t)(sign | 0x7c00u); /* Inf included */
    if (v < 0x1p-14) return (uint16_t)(sign | (uint16_t)nearbyint(v * 0x1p24)); /* 1024 = 0x400 */
    int e;
    double m = nearbyint(frexp(v, &e) * 2048.0); /* 11 significant bits, [1024, 2048] */
    if (m == 2048.0) {
        m = 1024.0;
        e++;
    }
    return (uint16_t)(sign | (uint16_t)((e + 14) << 10) | (uint16_t)((unsigned)m - 1024u));
}

static float float_of_bits(uint32_t u)
{
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

/* An image whose first values are the edge cases, the rest floats of every exponent with random
 * mantissas, two sevenths of them exactly halfway between two (normal or subnormal) halves. */
static struct image edge_image(uint32_t w, uint32_t h)
{
    static const uint32_t special[] = {
        0x477fe000u /* 65504 */, 0x477ff000u /* 65520 -> Inf */, 0x477fefffu, 0x477ff001u,
        0xc77ff000u, 0x47800000u /* 65536 */, 0x33800000u /* 2^-24 */, 0x33000000u /* 2^-25 -> 0 */,
        0x33000001u, 0x33c00000u /* 1.5 * 2^-24 -> 2^-23 (even) */, 0x34200000u /* 2.5 * 2^-24 */,
        0x387fc000u, 0x387fe000u /* largest subnormal half + 1/2 ulp -> 2^-14 */, 0x38800000u,
        0x80000000u /* -0 */, 0x00000000u, 0x00000001u, 0x807fffffu /* float subnormals */,
        0x7f800000u, 0xff800000u, 0x7fc00000u, 0xffc00000u, 0x7f800001u /* signalling NaN */,
        0x7f802000u, 0xffa00000u, 0x7fbfffffu, 0x7f801fffu, 0x3f800000u, 0x3f801000u, 0x3f803000u,
        0x3f801001u, 0xbf800fffu};
    struct image img;
    struct err err;
    if (!image_init(&img, w, h, &err)) return img;
    float *f = (float *)img.pixels;
    size_t n = (size_t)w * h * 3, ns = sizeof special / sizeof special[0];
    rnd_u32();
    struct rng saved = test_rng;
    test_rng = rng_make(777, 0, 0, 0);
    for (size_t i = 0; i < n; i++) {
        uint32_t bits = (rnd_u32() & 0x807fffffu) | (uint32_t)((i / 7) % 256) << 23;
        if (i % 7 == 3) bits = (bits & 0xffffe000u) | 0x1000u; /* a tie between normal halves */
        f[i] = float_of_bits(i < ns ? special[i] : bits);
        if (i >= ns && i % 7 == 5) /* a tie between subnormal halves: (k + 1/2) * 2^-24 */
            f[i] = ((float)(rnd_u32() % 1024) + 0.5f) * 0x1p-24f * (rnd_u32() % 2 ? -1.0f : 1.0f);
    }
    test_rng = saved;
    return img;
}

/* Encodes img as HALF without compression (with flush-to-zero and denormals-are-zero set
 * during the encode when `ftz`: render threads may set them) and checks every stored half
 * against ref_half. */
static void check_halves_exact(const struct image *img, bool ftz, const char *label)
{
    size_t size = 0;
#if defined(__SSE2__)
    unsigned csr = _mm_getcsr();
    if (ftz) _mm_setcsr(csr | 0x8040u);
#else
    (void)ftz;
#endif
    unsigned char *buf = encode(img, (struct exrio_write_opts){.pixel = EXRIO_HALF, .alpha = true}, &size);
#if defined(__SSE2__)
    _mm_setcsr(csr);
#endif
    if (!buf) return;
    uint32_t w = img->width;
    size_t table = header_end(buf, size), bad = 0, checked = 0;
    bool layout_ok = table + 8 * (size_t)img->height <= size;
    for (uint32_t y = 0; layout_ok && y < img->height; y++) {
        uint64_t off;
        memcpy(&off, buf + table + 8 * (size_t)y, 8);
        int32_t row, bytes;
        layout_ok = off + 8 <= size;
        if (!layout_ok) break;
        memcpy(&row, buf + off, 4);
        memcpy(&bytes, buf + off + 4, 4);
        layout_ok = row == (int32_t)y && bytes == (int32_t)(8 * w) && off + 8 + (uint64_t)bytes <= size;
        const unsigned char *p = buf + off + 8; /* channels A, B, G, R */
        for (uint32_t c = 0; layout_ok && c < 4; c++)
            for (uint32_t x = 0; x < w; x++) {
                uint16_t got = (uint16_t)(p[2 * (c * w + x)] | p[2 * (c * w + x) + 1] << 8);
                uint32_t src = 0x3f800000u; /* A = 1 */
                if (c > 0) memcpy(&src, (const float *)&img->pixels[(size_t)y * w + x] + (3 - c), 4);
                uint16_t want = ref_half(src);
                if (got != want && bad++ < 5)
                    fprintf(stderr, "  %s: float 0x%08x -> half 0x%04x, want 0x%04x\n", label, src, got, want);
                checked++;
            }
    }
    CHECK_MSG(layout_ok, "%s: unexpected chunk layout", label);
    CHECK_MSG(bad == 0, "%s: %zu of %zu halves differ from OpenEXR's rounding", label, bad, checked);
    free(buf);
}

static void test_half_conversion_exact(void)
{
    struct image img = edge_image(509, 200); /* odd width: SIMD tails */
    if (!img.pixels) { CHECK(0); return; }
    const char *saved = getenv("RESTIRD_EXR_HALF");
    unsetenv("RESTIRD_EXR_HALF");
    check_halves_exact(&img, false, "default (F16C if present)");
    check_halves_exact(&img, true, "default, FTZ+DAZ");
    setenv("RESTIRD_EXR_HALF", "portable", 1);
    check_halves_exact(&img, false, "portable");
    check_halves_exact(&img, true, "portable, FTZ+DAZ");
    if (saved) setenv("RESTIRD_EXR_HALF", saved, 1);
    else unsetenv("RESTIRD_EXR_HALF");
    image_destroy(&img);
}

/* ZIP and ZIPS (our transform + run-length or level-1 deflate) decode to exactly the values
 * the uncompressed file holds, for noisy, smooth (the level-1 retry), constant, smooth-then-
 * noisy and NaN/Inf-laden images and widths that are not multiples of the SIMD widths. */
static void test_zip_matches_uncompressed(void)
{
    static const uint32_t widths[] = {1, 7, 37, 300};
    for (int kind = 0; kind < 5; kind++)
        for (size_t wi = 0; wi < sizeof widths / sizeof widths[0]; wi++) {
            uint32_t w = widths[wi], h = kind == 4 ? 96 : 37;
            struct image img;
            if (kind == 3) {
                img = edge_image(w, h);
            } else {
                struct err err;
                if (!image_init(&img, w, h, &err)) continue;
                for (uint32_t y = 0; y < h; y++)
                    for (uint32_t x = 0; x < w; x++) {
                        float s = 0.5f + 0.3f * sinf(0.05f * (float)x + 0.1f * (float)y);
                        bool noisy = kind == 0 || (kind == 4 && y >= h / 2);
                        float noise = noisy ? (float)rnd_unit() * 0.2f : 0.0f;
                        if (kind == 2) s = 0.25f;
                        img.pixels[(size_t)y * w + x] = vec3_make(s + noise, s * 0.5f, s - noise);
                    }
            }
            if (!img.pixels) { CHECK(0); continue; }
            struct image ref = {0};
            struct err err = {0};
            size_t size = 0;
            unsigned char *raw = encode(&img, (struct exrio_write_opts){.pixel = EXRIO_HALF, .alpha = true}, &size);
            bool ok = raw && exrio_read_mem(raw, size, NULL, &ref, &err);
            CHECK_MSG(ok, "NONE: %s", err.message);
            free(raw);
            for (int z = 0; ok && z < 2; z++)
                for (int a = 0; a < 2; a++) {
                    struct exrio_write_opts o = {.pixel = EXRIO_HALF, .compression = z ? EXRIO_ZIPS : EXRIO_ZIP,
                                                 .alpha = a == 1};
                    unsigned char *buf = encode(&img, o, &size);
                    struct image back;
                    if (!buf) continue;
                    bool read = exrio_read_mem(buf, size, NULL, &back, &err);
                    CHECK_MSG(read, "kind %d width %u %s: %s", kind, w, z ? "ZIPS" : "ZIP", err.message);
                    if (read) {
                        CHECK_MSG(same_bits(&ref, &back), "kind %d width %u %s alpha %d: values differ", kind,
                                  w, z ? "ZIPS" : "ZIP", a);
                        image_destroy(&back);
                    }
                    free(buf);
                }
            if (ref.pixels) image_destroy(&ref);
            image_destroy(&img);
        }
}

/* deflate.h's run-length compressor (written for EXR ZIP chunks): round trips through
 * libdeflate's inflater on inputs that exercise each block type and code-length corner. */
static void check_rle_round_trip(struct deflate *d, const unsigned char *in, size_t n,
                                 const size_t *cuts, int ncuts, const char *label)
{
    size_t bound = deflate_zlib_bound(d, n);
    unsigned char *z = malloc(bound), *back = malloc(n + 1);
    if (!z || !back) { CHECK(0); free(z); free(back); return; }
    size_t zn = deflate_zlib_blocks(d, in, n, cuts, ncuts, z, bound);
    CHECK_MSG(zn > 0 && zn <= bound, "%s: %zu bytes for bound %zu", label, zn, bound);
    if (zn > 0) {
        CHECK(((z[0] << 8) | z[1]) % 31 == 0 && (z[0] & 0x0f) == 8);
        size_t got = 0;
        struct err err = {0};
        bool ok = deflate_zlib_decompress(z, zn, back, n + 1, &got, &err);
        CHECK_MSG(ok && got == n && (n == 0 || memcmp(back, in, n) == 0), "%s: %s", label,
                  ok ? "different bytes" : err.message);
        /* deterministic, and 0 (not a cut stream) when the output does not fit */
        unsigned char *z2 = malloc(bound);
        if (z2) {
            CHECK(deflate_zlib_blocks(d, in, n, cuts, ncuts, z2, bound) == zn && memcmp(z, z2, zn) == 0);
            if (zn > 8) CHECK(deflate_zlib_blocks(d, in, n, cuts, ncuts, z2, zn - 1) == 0);
            free(z2);
        }
    }
    free(z);
    free(back);
}

static void test_deflate_rle(void)
{
    struct err err = {0};
    struct deflate *d = deflate_new_rle(&err);
    CHECK(d != NULL);
    if (!d) return;
    size_t n = 600000;
    unsigned char *buf = calloc(n, 1);
    if (!buf) { CHECK(0); deflate_free(d); return; }
    check_rle_round_trip(d, buf, 0, NULL, 0, "empty");
    buf[0] = 42;
    check_rle_round_trip(d, buf, 1, NULL, 0, "one byte");
    memset(buf, 7, n);
    check_rle_round_trip(d, buf, 5, NULL, 0, "one symbol, no run");
    /* runs whose match part is 258k + 1 or + 2 bytes long (no 1- or 2-byte leftovers) */
    for (size_t len = 255; len < 520; len += 1) check_rle_round_trip(d, buf, len, NULL, 0, "one run");
    check_rle_round_trip(d, buf, n, NULL, 0, "600 KB run (automatic blocks)");
    for (size_t i = 0; i < n; i++) buf[i] = (unsigned char)rnd_u32();
    check_rle_round_trip(d, buf, n, NULL, 0, "random: stored blocks");
    for (size_t i = 0; i < n; i++) /* predictor-like: peaked, with runs and a few wild bytes */
        buf[i] = (i / 5000) % 3 == 0 ? 128 : (unsigned char)(128 + (int)(rnd_u32() % 7) - 3 + (rnd_u32() % 97 == 0) * 90);
    size_t cuts[] = {100, 5000, 5100, 300000, 599999};
    check_rle_round_trip(d, buf, n, cuts, 5, "peaked with cuts");
    check_rle_round_trip(d, buf, 70000, cuts + 1, 1, "peaked, one cut");
    for (size_t i = 0; i < n; i++) buf[i] = (unsigned char)(i % 251 < 3 ? i : 200 + i % 2);
    check_rle_round_trip(d, buf, 4096, NULL, 0, "two symbols");
    for (size_t i = 0; i < n; i++) /* skewed counts: literal codes at the 14-bit limit */
        buf[i] = (unsigned char)(__builtin_ctz((unsigned)rnd_u32() | 0x80000000u) * 8 + (i % 3));
    check_rle_round_trip(d, buf, n, NULL, 0, "geometric");
    deflate_free(d);
    free(buf);
}

/* ---- the header gate ---------------------------------------------------------------------- */

static void test_piz_written_but_rejected(void)
{
    struct image img = make_image(40, 40, 1);
    struct exrio_write_opts o = {.pixel = EXRIO_HALF, .compression = EXRIO_PIZ, .alpha = true};
    size_t size = 0;
    unsigned char *buf = encode(&img, o, &size);
    if (!buf) return;
    struct exrio_info info;
    struct err err = {0};
    CHECK(exrio_probe_mem(buf, size, NULL, &info, &err));
    CHECK(info.compression == EXRIO_PIZ && strcmp(info.compression_name, "PIZ") == 0);
    struct image back;
    CHECK(!exrio_read_mem(buf, size, "frame.exr", &back, &err));
    CHECK(err.code == ERR_UNSUPPORTED && strstr(err.message, "PIZ") != NULL);
    CHECK(strcmp(err.where, "frame.exr") == 0);
    CHECK(back.pixels == NULL);
    free(buf);
    image_destroy(&img);
}

static void test_too_many_channels(void)
{
    struct image img = make_image(8, 8, 1);
    float d[8 * 8 * 3] = {0};
    struct exrio_aov aovs[2] = {{.name = "albedo", .channels = 3, .data = d},
                                {.name = "normal", .channels = 3, .data = d}};
    struct exrio_write_opts o = {.pixel = EXRIO_HALF, .compression = EXRIO_ZIP, .alpha = true,
                                 .aovs = aovs, .aov_count = 2};
    size_t size = 0;
    unsigned char *buf = encode(&img, o, &size);
    if (!buf) return;
    struct image back;
    struct err err = {0};
    CHECK(!exrio_read_mem(buf, size, "aovs.exr", &back, &err));
    CHECK_MSG(err.code == ERR_LIMIT && strstr(err.message, "10 channels"), "%s", err.message);
    free(buf);
    image_destroy(&img);
}

static void test_crafted_valid_and_grey(void)
{
    /* Sanity check of the builder: a plain RGB FLOAT file it makes must read back. */
    struct craft rgb = {.width = 6, .height = 3, .nch = 3, .names = {"B", "G", "R"},
                        .types = {2, 2, 2}, .pixels = true};
    size_t size = 0;
    unsigned char *buf = craft_file(&rgb, &size);
    struct image img = {0};
    struct err err = {0};
    CHECK_MSG(exrio_read_mem(buf, size, NULL, &img, &err), "%s", err.message);
    if (img.pixels) {
        struct vec3 p = img.pixels[2 * 6 + 5]; /* x=5, y=2: B is channel 0 in the file */
        CHECK(p.x == 2005.2f && p.y == 2005.1f && p.z == 2005.0f);
        image_destroy(&img);
    }
    free(buf);

    struct craft grey = {.width = 5, .height = 4, .nch = 1, .names = {"Y"}, .types = {2}, .pixels = true};
    buf = craft_file(&grey, &size);
    CHECK_MSG(exrio_read_mem(buf, size, NULL, &img, &err), "%s", err.message);
    if (img.pixels) {
        CHECK(img.width == 5 && img.height == 4);
        struct vec3 p = img.pixels[3 * 5 + 4];
        CHECK(p.x == 3004.0f && p.y == 3004.0f && p.z == 3004.0f);
        image_destroy(&img);
    }
    free(buf);
}

/* Regression: a 3-channel HALF file of which we decode one channel (B, G, Y: grey mode)
 * made libOpenEXRCore 3.1.5's interleaved unpacker write through a NULL pointer. Also covers
 * HALF RGB without alpha, whose channel pointers look interleaved in reverse. */
static void test_half_partial_channels(void)
{
    struct craft bgy = {.width = 7, .height = 3, .nch = 3, .names = {"B", "G", "Y"},
                        .types = {1, 1, 1}, .pixels = true};
    size_t size = 0;
    unsigned char *buf = craft_file(&bgy, &size);
    struct image img = {0};
    struct err err = {0};
    CHECK_MSG(exrio_read_mem(buf, size, NULL, &img, &err), "%s", err.message);
    if (img.pixels) {
        struct vec3 p = img.pixels[2 * 7 + 6]; /* Y is channel 2: 6 + 16 + 2 */
        CHECK(p.x == 24.0f && p.y == 24.0f && p.z == 24.0f);
        image_destroy(&img);
    }
    free(buf);

    struct image src = make_image(31, 19, 1);
    struct exrio_write_opts o = {.pixel = EXRIO_HALF, .compression = EXRIO_ZIP};
    buf = encode(&src, o, &size);
    if (buf) {
        CHECK_MSG(exrio_read_mem(buf, size, NULL, &img, &err), "%s", err.message);
        if (img.pixels) {
            double worst = max_rel_err(&src, &img);
            CHECK_MSG(worst <= 1e-3, "worst relative error %g", worst);
            image_destroy(&img);
        }
        free(buf);
    }
    image_destroy(&src);
}

static void test_gate_rejections(void)
{
    struct err e;
    struct craft tiled = {.width = 32, .height = 32, .nch = 3, .names = {"B", "G", "R"},
                          .types = {1, 1, 1}, .tiled = true};
    e = read_crafted(&tiled, false);
    CHECK_MSG(e.code == ERR_UNSUPPORTED && strstr(e.message, "tiled"), "%s", e.message);
    CHECK(strcmp(e.where, "crafted.exr") == 0);

    struct craft wide = {.width = 20000, .height = 2, .nch = 3, .names = {"B", "G", "R"}, .types = {1, 1, 1}};
    e = read_crafted(&wide, false);
    CHECK_MSG(e.code == ERR_LIMIT && strstr(e.message, "20000x2"), "%s", e.message);

    struct craft area = {.width = 16384, .height = 4097, .nch = 3, .names = {"B", "G", "R"}, .types = {1, 1, 1}};
    e = read_crafted(&area, false);
    CHECK_MSG(e.code == ERR_LIMIT && strstr(e.message, "pixels"), "%s", e.message);

    struct craft uint_ch = {.width = 4, .height = 4, .nch = 3, .names = {"B", "G", "R"}, .types = {1, 0, 1}};
    e = read_crafted(&uint_ch, false);
    CHECK_MSG(e.code == ERR_UNSUPPORTED && strstr(e.message, "UINT"), "%s", e.message);

    struct craft sub = {.width = 4, .height = 4, .nch = 3, .names = {"B", "G", "R"}, .types = {1, 1, 1},
                        .xs = 2, .ys = 2};
    e = read_crafted(&sub, false);
    CHECK_MSG(e.code == ERR_UNSUPPORTED && strstr(e.message, "subsampled"), "%s", e.message);

    struct craft b44 = {.width = 4, .height = 4, .nch = 3, .names = {"B", "G", "R"}, .types = {1, 1, 1},
                        .compression = 6};
    e = read_crafted(&b44, false);
    CHECK_MSG(e.code == ERR_UNSUPPORTED && strstr(e.message, "B44"), "%s", e.message);

    struct craft nine = {.width = 4, .height = 4, .nch = 9,
                         .names = {"A", "B", "G", "R", "a", "b", "c", "d", "e"},
                         .types = {1, 1, 1, 1, 1, 1, 1, 1, 1}};
    e = read_crafted(&nine, false);
    CHECK_MSG(e.code == ERR_LIMIT && strstr(e.message, "9 channels"), "%s", e.message);

    struct craft no_rgb = {.width = 4, .height = 4, .nch = 1, .names = {"Z"}, .types = {2}};
    e = read_crafted(&no_rgb, false);
    CHECK_MSG(e.code == ERR_UNSUPPORTED && strstr(e.message, "no R, G, B or Y"), "%s", e.message);

    struct craft multi = {.width = 4, .height = 4, .nch = 3, .names = {"B", "G", "R"}, .types = {1, 1, 1},
                          .parts = 2};
    e = read_crafted(&multi, false);
    CHECK_MSG(e.code == ERR_UNSUPPORTED && strstr(e.message, "multi-part"), "%s", e.message);

    /* Not EXR at all, and empty input. */
    struct image img;
    struct err err = {0};
    CHECK(!exrio_read_mem("P6\n1 1\n255\n\0\0\0", 14, "x.ppm", &img, &err) && err.code == ERR_PARSE);
    CHECK(!exrio_read_mem(NULL, 0, NULL, &img, &err) && err.code == ERR_PARSE);
    CHECK(strcmp(err.where, "<memory>") == 0);
    CHECK(!exrio_read_file("/nonexistent/file.exr", &img, &err) && err.code == ERR_NOT_FOUND);
    CHECK(strcmp(err.where, "/nonexistent/file.exr") == 0);
    CHECK(!exrio_read_file("/tmp", &img, &err) && err.code == ERR_IO);
}

/* ---- damaged input ------------------------------------------------------------------------ */

static void test_truncated(void)
{
    struct image src = make_image(64, 40, 1);
    static const enum exrio_compression comps[] = {EXRIO_ZIP, EXRIO_NONE};
    for (int k = 0; k < 2; k++) {
        struct exrio_write_opts o = {.pixel = EXRIO_HALF, .compression = comps[k], .alpha = true};
        size_t size = 0;
        unsigned char *buf = encode(&src, o, &size);
        if (!buf) continue;
        size_t cuts[10] = {0, 3, 8, 40, header_end(buf, size) - 1, header_end(buf, size) + 20,
                           size / 3, size / 2, size - 100, size - 1};
        for (int i = 0; i < 10; i++) {
            unsigned char *part = malloc(cuts[i] ? cuts[i] : 1); /* exact size: ASan sees overreads */
            memcpy(part, buf, cuts[i]);
            struct image img;
            struct err err = {0};
            bool ok = exrio_read_mem(part, cuts[i], "cut.exr", &img, &err);
            CHECK_MSG(!ok, "%s truncated at %zu of %zu was accepted", exrio_compression_name(comps[k]),
                      cuts[i], size);
            CHECK(ok || (err.code == ERR_PARSE && err.message[0] && strcmp(err.where, "cut.exr") == 0));
            if (ok) image_destroy(&img);
            free(part);
        }
        /* And through the file path. */
        char path[256];
        tmp_path(path, sizeof path, "cut");
        FILE *f = fopen(path, "wb");
        if (f) {
            fwrite(buf, 1, size / 2, f);
            fclose(f);
            struct image img;
            struct err err = {0};
            CHECK(!exrio_read_file(path, &img, &err) && err.code == ERR_PARSE);
            remove(path);
        }
        free(buf);
    }
    image_destroy(&src);
}

static void test_byte_flips(void)
{
    struct image src = make_image(48, 35, 1);
    static const enum exrio_compression comps[] = {EXRIO_ZIP, EXRIO_NONE, EXRIO_RLE, EXRIO_ZIPS};
    int accepted = 0, rejected = 0;
    for (int k = 0; k < 4; k++) {
        struct exrio_write_opts o = {.pixel = k & 1 ? EXRIO_FLOAT : EXRIO_HALF, .compression = comps[k],
                                     .alpha = true};
        size_t size = 0;
        unsigned char *buf = encode(&src, o, &size);
        if (!buf) continue;
        size_t hdr = header_end(buf, size);
        unsigned char *mut = malloc(size);
        for (int trial = 0; trial < 400; trial++) {
            memcpy(mut, buf, size);
            int flips = 1 + (int)(rnd_u32() % 8);
            for (int f = 0; f < flips; f++) {
                /* Half the trials aim at the header and offset table, where damage is most
                 * interesting; the rest anywhere. */
                size_t span = (trial & 1) ? size : (hdr + 8 * 40 < size ? hdr + 8 * 40 : size);
                size_t at = rnd_u32() % span;
                mut[at] ^= (unsigned char)(1u << (rnd_u32() % 8));
            }
            struct image img;
            struct err err = {0};
            if (exrio_read_mem(mut, size, "flip.exr", &img, &err)) {
                accepted++;
                CHECK(img.width >= 1 && img.width <= EXRIO_MAX_SIDE && img.pixels);
                image_destroy(&img);
            } else {
                rejected++;
                CHECK(err.code != ERR_NONE && err.message[0] != '\0');
            }
        }
        free(mut);
        free(buf);
    }
    CHECK(rejected > 0);
    printf("     byte flips: %d accepted, %d rejected\n", accepted, rejected);
    image_destroy(&src);
}

TEST_MAIN(TEST(test_half_nonfinite), TEST(test_float_roundtrip_mem), TEST(test_float_roundtrip_file), TEST(test_half_roundtrip),
          TEST(test_aov_channels), TEST(test_write_rejects_bad_input),
          TEST(test_zip_output_equal_to_raw_size), TEST(test_half_conversion_exact),
          TEST(test_zip_matches_uncompressed), TEST(test_deflate_rle),
          TEST(test_piz_written_but_rejected), TEST(test_too_many_channels),
          TEST(test_crafted_valid_and_grey), TEST(test_half_partial_channels),
          TEST(test_gate_rejections), TEST(test_truncated),
          TEST(test_byte_flips))
