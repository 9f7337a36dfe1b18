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

#include "exrio.h"
#include "test.h"

/* ---- helpers ----------------------------------------------------------------------------- */

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static uint32_t rnd_u32(void)
{
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return (uint32_t)(rng_state >> 16);
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
    uint64_t saved = rng_state;
    rng_state = 12345;
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
    rng_state = saved;
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
          TEST(test_zip_output_equal_to_raw_size),
          TEST(test_piz_written_but_rejected), TEST(test_too_many_channels),
          TEST(test_crafted_valid_and_grey), TEST(test_half_partial_channels),
          TEST(test_gate_rejections), TEST(test_truncated),
          TEST(test_byte_flips))
