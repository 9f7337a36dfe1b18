/* test_tonemap_anim.c — keyframe tracks (values at keys, clamping outside the keyed range,
 * channel independence, Catmull-Rom: linear with two keys, C1 at interior keys, overshoot
 * clamps), deflate.h (CRC-32 check value, round trips, corrupt streams), and the PNG previews
 * and error maps of tonemap.h decoded by an independent reader written here (chunk framing and
 * CRCs, IHDR, all five row filters) down to exact pixel bytes.
 * Expected bytes come from the formulas, evaluated directly (pow, not tonemap.c's tables).
 * Refs: PNG specification (ISO/IEC 15948) §5, §9; IEC 61966-2-1 (sRGB); animation.h. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "scene/animation.h"
#include "image/deflate.h"
#include "image/metrics.h"
#include "core/rng.h"
#include "test.h"
#include "image/tonemap.h"

/* ---- helpers ----------------------------------------------------------------------------- */

/* The project's own generator (rng.h), one stream for the whole file. */
static struct rng test_rng = {0};
static bool test_rng_seeded = false;
static uint32_t rnd_u32(void)
{
    if (!test_rng_seeded) {
        test_rng = rng_make(0x2545f4914f6cdd1dull, 0, 0, 0);
        test_rng_seeded = true;
    }
    return rng_next_u32(&test_rng);
}
static double rnd_unit(void) { return (rnd_u32() >> 8) * (1.0 / 16777216.0); }

static bool vec3_eq(struct vec3 a, struct vec3 b) { return a.x == b.x && a.y == b.y && a.z == b.z; }

static struct image make(uint32_t w, uint32_t h, const struct vec3 *px)
{
    struct image img;
    struct err err;
    if (image_init(&img, w, h, &err) && px) memcpy(img.pixels, px, sizeof *px * w * h);
    return img;
}

/* Reference sRGB code of a display value: round(255 * oetf(v)). */
static int srgb_code(double v)
{
    v = v < 0.0 ? 0.0 : (v > 1.0 ? 1.0 : v);
    double e = v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
    return (int)floor(e * 255.0 + 0.5);
}
static double srgb_decode(double e) { return e <= 0.04045 ? e / 12.92 : pow((e + 0.055) / 1.055, 2.4); }

/* ---- a PNG reader, independent of tonemap.c ---------------------------------------------- */

struct png {
    uint32_t w, h;
    unsigned char *rgb;    /* w * h * 3 */
    int idat_count;
    size_t size;           /* of the whole file */
    unsigned filters_used; /* bit t set when some row used filter type t */
};

static uint32_t get_u32(const unsigned char *p)
{
    return (uint32_t)p[0] << 24 | (uint32_t)p[1] << 16 | (uint32_t)p[2] << 8 | p[3];
}

static int paeth(int a, int b, int c)
{
    int p = a + b - c, pa = abs(p - a), pb = abs(p - b), pc = abs(p - c);
    return (pa <= pb && pa <= pc) ? a : (pb <= pc ? b : c);
}

/* Parses and fully checks an 8-bit RGB, non-interlaced PNG: signature, every chunk's CRC,
 * IHDR first, IDATs consecutive, IEND last with nothing after. CHECK failures mark the test. */
static bool png_decode(const unsigned char *buf, size_t size, struct png *out)
{
    static const unsigned char sig[8] = {0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a};
    memset(out, 0, sizeof *out);
    out->size = size;
    CHECK(size >= 8 && memcmp(buf, sig, 8) == 0);
    if (size < 8 || memcmp(buf, sig, 8) != 0) return false;
    size_t pos = 8, zsize = 0;
    unsigned char *z = malloc(size);
    bool seen_ihdr = false, seen_iend = false, idat_done = false, ok = z != NULL;
    int chunk_no = 0;
    while (ok && pos < size) {
        if (size - pos < 12) { CHECK_MSG(0, "truncated chunk at %zu", pos); ok = false; break; }
        uint32_t len = get_u32(buf + pos);
        const unsigned char *type = buf + pos + 4, *data = buf + pos + 8;
        if (len > size - pos - 12) { CHECK_MSG(0, "chunk length %u overruns", len); ok = false; break; }
        uint32_t crc = get_u32(data + len);
        CHECK_MSG(crc == deflate_crc32(0, type, 4 + (size_t)len), "bad CRC on chunk %d (%.4s)", chunk_no,
                  (const char *)type);
        if (chunk_no == 0) CHECK(memcmp(type, "IHDR", 4) == 0);
        if (memcmp(type, "IHDR", 4) == 0) {
            CHECK(chunk_no == 0 && len == 13);
            if (len != 13) { ok = false; break; }
            out->w = get_u32(data);
            out->h = get_u32(data + 4);
            CHECK(data[8] == 8 && data[9] == 2 && data[10] == 0 && data[11] == 0 && data[12] == 0);
            seen_ihdr = true;
        } else if (memcmp(type, "IDAT", 4) == 0) {
            CHECK_MSG(!idat_done, "IDAT chunks must be consecutive");
            memcpy(z + zsize, data, len);
            zsize += len;
            out->idat_count++;
        } else if (memcmp(type, "IEND", 4) == 0) {
            CHECK(len == 0);
            seen_iend = true;
            pos += 12 + (size_t)len;
            break;
        } else {
            CHECK_MSG(0, "unexpected chunk %.4s", (const char *)type);
        }
        if (out->idat_count && memcmp(type, "IDAT", 4) != 0) idat_done = true;
        pos += 12 + (size_t)len;
        chunk_no++;
    }
    CHECK(seen_ihdr && seen_iend && out->idat_count >= 1);
    CHECK_MSG(pos == size, "%zu bytes after IEND", size - pos);
    ok = ok && seen_ihdr && seen_iend && out->w && out->h;
    size_t stride = 1 + 3 * (size_t)out->w, raw_n = stride * out->h;
    unsigned char *raw = ok ? malloc(raw_n + 1) : NULL;
    size_t got = 0;
    struct err err = {0};
    if (raw) {
        /* One spare byte of capacity: a stream that inflates to too much is caught here. */
        bool inflated = deflate_zlib_decompress(z, zsize, raw, raw_n + 1, &got, &err);
        CHECK_MSG(inflated, "%s", err.message);
        CHECK_MSG(got == raw_n, "inflated %zu bytes, want %zu", got, raw_n);
        ok = inflated && got == raw_n;
    }
    free(z);
    if (!ok) {
        free(raw);
        return false;
    }
    out->rgb = malloc(3 * (size_t)out->w * out->h);
    for (uint32_t y = 0; y < out->h; y++) {
        const unsigned char *f = raw + (size_t)y * stride;
        unsigned char *cur = out->rgb + (size_t)y * 3 * out->w;
        const unsigned char *up = y ? cur - 3 * out->w : NULL;
        int type = f[0];
        CHECK_MSG(type <= 4, "row %u filter %d", y, type);
        out->filters_used |= 1u << (type & 7);
        for (size_t i = 0; i < 3 * (size_t)out->w; i++) {
            int a = i >= 3 ? cur[i - 3] : 0, b = up ? up[i] : 0, c = (up && i >= 3) ? up[i - 3] : 0;
            int pred = type == 1 ? a : type == 2 ? b : type == 3 ? (a + b) / 2 : type == 4 ? paeth(a, b, c) : 0;
            cur[i] = (unsigned char)(f[1 + i] + pred);
        }
    }
    free(raw);
    return true;
}

static const unsigned char *png_px(const struct png *p, uint32_t x, uint32_t y)
{
    return p->rgb + ((size_t)y * p->w + x) * 3;
}

static bool px_is(const unsigned char *p, int r, int g, int b) { return p[0] == r && p[1] == g && p[2] == b; }

/* Tone-maps img and decodes the result; false (test marked failed) when either step fails. */
static bool preview(const struct image *img, float ev, enum tonemap_curve curve, struct png *out)
{
    struct tonemap_opts o = {ev, curve};
    unsigned char *buf = NULL;
    size_t n = 0;
    struct err err = {0};
    bool ok = tonemap_png(img, &o, &buf, &n, &err);
    CHECK_MSG(ok, "%s", err.message);
    if (ok) ok = png_decode(buf, n, out);
    free(buf);
    return ok;
}

static bool error_map(const struct image *img, const struct image *ref, float scale_max, float *used,
                      struct png *out)
{
    unsigned char *buf = NULL;
    size_t n = 0;
    struct err err = {0};
    bool ok = tonemap_error_png(img, ref, scale_max, used, &buf, &n, &err);
    CHECK_MSG(ok, "%s", err.message);
    if (ok) ok = png_decode(buf, n, out);
    free(buf);
    return ok;
}

/* ---- deflate ----------------------------------------------------------------------------- */

static void test_deflate_crc_and_round_trip(void)
{
    /* The CRC-32 check value of the ISO 3309 polynomial, and continuation across pieces. */
    CHECK(deflate_crc32(0, "123456789", 9) == 0xcbf43926u);
    CHECK(deflate_crc32(deflate_crc32(0, "1234", 4), "56789", 5) == 0xcbf43926u);
    CHECK(deflate_crc32(0, "", 0) == 0);

    struct err err = {0};
    CHECK(!deflate_new(0, &err) && err.code == ERR_INVALID);
    CHECK(!deflate_new(13, &err) && err.code == ERR_INVALID);
    struct deflate *d = deflate_new(6, &err);
    CHECK(d != NULL);
    if (!d) return;
    size_t n = 100000;
    unsigned char *in = malloc(n), *back = malloc(n + 16);
    for (size_t i = 0; i < n; i++) in[i] = i < n / 2 ? (unsigned char)(i % 251) : (unsigned char)rnd_u32();
    size_t bound = deflate_zlib_bound(d, n);
    unsigned char *z = malloc(bound + 1);
    size_t zn = deflate_zlib(d, in, n, z, bound);
    CHECK(zn > 2 && zn <= bound);
    CHECK((z[0] & 0x0f) == 8 && ((z[0] << 8) | z[1]) % 31 == 0);  /* zlib header: deflate, FCHECK */
    size_t got = 0;
    CHECK(deflate_zlib_decompress(z, zn, back, n + 16, &got, &err));
    CHECK(got == n && memcmp(in, back, n) == 0);
    unsigned char *small = malloc(zn / 2);
    CHECK(deflate_zlib(d, in, n, small, zn / 2) == 0);  /* too small: 0, not a cut stream */
    free(small);

    /* Too little room, a corrupted Adler-32, trailing bytes, a cut stream. */
    CHECK(!deflate_zlib_decompress(z, zn, back, n - 1, &got, &err) && err.code == ERR_LIMIT);
    z[zn - 1] ^= 0x01;
    CHECK(!deflate_zlib_decompress(z, zn, back, n + 16, &got, &err) && err.code == ERR_PARSE);
    z[zn - 1] ^= 0x01;
    z[zn] = 0;
    CHECK(!deflate_zlib_decompress(z, zn + 1, back, n + 16, &got, &err) && err.code == ERR_PARSE);
    CHECK(!deflate_zlib_decompress(z, zn / 2, back, n + 16, &got, &err) && err.code == ERR_PARSE);
    CHECK(deflate_zlib_decompress(z, zn, back, n, NULL, &err));
    deflate_free(d);
    deflate_free(NULL);
    free(in);
    free(back);
    free(z);
}

/* ---- animation --------------------------------------------------------------------------- */

static struct animation_camera_key cam_key(double t, struct vec3 pos, struct vec3 look, struct vec3 up, float fov)
{
    struct animation_camera_key k;
    memset(&k, 0, sizeof k);
    k.t_s = t;
    k.camera.position = pos;
    k.camera.look_at = look;
    k.camera.up = up;
    k.camera.fov_deg = fov;
    return k;
}

static const struct animation_camera_key cam_keys[5] = {
    {0.0, {{0, 1, 5}, {0, 0, 0}, {0, 1, 0}, 40}},
    {0.5, {{2, 1.5f, 4}, {0.5f, 0, 0}, {0, 1, 0}, 45}},
    {2.0, {{3, 3, -1}, {0, 1, 0}, {0, 1, 0}, 60}},
    {2.3, {{-1, 2, -2}, {0, 0.5f, 0.25f}, {0, 1, 0}, 35}},
    {4.0, {{-4, 0.5f, 1}, {1, 0, 0}, {0, 1, 0}, 50}},
};

static void test_anim_values_at_keys_exact(void)
{
    for (int interp = 0; interp < 2; interp++) {
        for (int i = 0; i < 5; i++) {
            struct camera_desc c;
            animation_camera_at(cam_keys, 5, (enum animation_interp)interp, cam_keys[i].t_s, &c);
            CHECK_MSG(vec3_eq(c.position, cam_keys[i].camera.position) && vec3_eq(c.look_at, cam_keys[i].camera.look_at) &&
                          vec3_eq(c.up, cam_keys[i].camera.up) && c.fov_deg == cam_keys[i].camera.fov_deg,
                      "interp %d key %d", interp, i);
        }
    }
    struct animation_shape_key sk[3] = {
        {.t_s = 1, .has_emission = true, .emission = {1, 2, 3}, .has_transform = true,
         .transform = {{1, 2, 3}, {10, 20, 30}, {1, 1, 1}}},
        {.t_s = 2, .has_emission = true, .emission = {0.5f, 0, 7}, .has_transform = true,
         .transform = {{-1, 0, 3}, {0, 90, 0}, {2, 2, 0.5f}}},
        {.t_s = 3.5, .has_emission = true, .emission = {4, 4, 4}, .has_transform = true,
         .transform = {{0, 5, 0}, {45, 0, -30}, {1, 3, 1}}},
    };
    for (int interp = 0; interp < 2; interp++) {
        for (int i = 0; i < 3; i++) {
            struct animation_shape_state s;
            animation_shape_at(sk, 3, (enum animation_interp)interp, sk[i].t_s, &s);
            CHECK(s.has_emission && s.has_transform && !s.has_position);
            CHECK(vec3_eq(s.emission, sk[i].emission));
            CHECK(vec3_eq(s.transform.translate, sk[i].transform.translate) &&
                  vec3_eq(s.transform.rotate_deg, sk[i].transform.rotate_deg) &&
                  vec3_eq(s.transform.scale, sk[i].transform.scale));
        }
    }
}

static void test_anim_two_keys_catmull_rom_is_linear(void)
{
    struct animation_camera_key k[2] = {
        cam_key(1.0, vec3_make(0, 0, 10), vec3_make(1, 2, 3), vec3_make(0, 1, 0), 30),
        cam_key(3.5, vec3_make(5, -2, 4), vec3_make(-1, 0, 7), vec3_make(0, 1, 0), 70),
    };
    for (int i = 0; i <= 100; i++) {
        double t = 1.0 + 2.5 * i / 100.0;
        struct camera_desc a, b;
        animation_camera_at(k, 2, ANIMATION_LINEAR, t, &a);
        animation_camera_at(k, 2, ANIMATION_CATMULL_ROM, t, &b);
        CHECK_MSG(vec3_eq(a.position, b.position) && vec3_eq(a.look_at, b.look_at) && a.fov_deg == b.fov_deg,
                  "t = %g", t);
        double u = (t - 1.0) / 2.5;
        CHECK_NEAR(a.position.x, 5 * u, 1e-5);
        CHECK_NEAR(a.position.z, 10 - 6 * u, 1e-5);
        CHECK_NEAR(a.fov_deg, 30 + 40 * u, 1e-4);
    }
    /* The same holds for a shape channel with two setting keys among others that do not. */
    struct animation_shape_key s[3] = {
        {.t_s = 0, .has_position = true, .position = {0, 0, 0}},
        {.t_s = 1, .has_emission = true, .emission = {1, 1, 1}},
        {.t_s = 4, .has_position = true, .position = {8, -4, 2}},
    };
    for (int i = 0; i <= 40; i++) {
        double t = 0.1 * i;
        struct animation_shape_state a, b;
        animation_shape_at(s, 3, ANIMATION_LINEAR, t, &a);
        animation_shape_at(s, 3, ANIMATION_CATMULL_ROM, t, &b);
        CHECK_MSG(vec3_eq(a.position, b.position), "t = %g", t);
        CHECK_NEAR(b.position.x, 2 * t, 1e-5);
    }
}

static void test_anim_clamps_outside_keys(void)
{
    for (int interp = 0; interp < 2; interp++) {
        double ts[4] = {-100.0, -1e-9, 4.0 + 1e-9, 1e9};
        for (int i = 0; i < 4; i++) {
            const struct camera_desc *want = ts[i] < 0 ? &cam_keys[0].camera : &cam_keys[4].camera;
            struct camera_desc c;
            animation_camera_at(cam_keys, 5, (enum animation_interp)interp, ts[i], &c);
            CHECK_MSG(vec3_eq(c.position, want->position) && vec3_eq(c.look_at, want->look_at) &&
                          c.fov_deg == want->fov_deg, "interp %d t %g", interp, ts[i]);
        }
        /* One key: constant everywhere. */
        struct camera_desc c;
        animation_camera_at(&cam_keys[2], 1, (enum animation_interp)interp, -5.0, &c);
        CHECK(vec3_eq(c.position, cam_keys[2].camera.position) && c.fov_deg == 60);
        animation_camera_at(&cam_keys[2], 1, (enum animation_interp)interp, 7.0, &c);
        CHECK(vec3_eq(c.position, cam_keys[2].camera.position) && c.fov_deg == 60);
    }
}

/* Position at keys 0, 2, 4; emission at keys 1, 3; transform at key 3 only. Each channel must
 * see only its own keys: the unset fields of the other keys (zeros) must never leak in. */
static void test_anim_channels_independent(void)
{
    struct animation_shape_key k[5] = {
        {.t_s = 0, .has_position = true, .position = {0, 0, 0}},
        {.t_s = 1, .has_emission = true, .emission = {2, 4, 6}},
        {.t_s = 2, .has_position = true, .position = {4, 2, 0}},
        {.t_s = 3, .has_emission = true, .emission = {4, 0, 6}, .has_transform = true,
         .transform = {{1, 1, 1}, {0, 0, 90}, {2, 2, 2}}},
        {.t_s = 4, .has_position = true, .position = {4, 2, 8}},
    };
    struct animation_shape_state s;
    animation_shape_at(k, 5, ANIMATION_LINEAR, 1.0, &s);
    CHECK(s.has_position && s.has_emission && s.has_transform);
    CHECK(vec3_eq(s.position, vec3_make(2, 1, 0)));     /* halfway between keys 0 and 2 */
    CHECK(vec3_eq(s.emission, vec3_make(2, 4, 6)));     /* key 1 itself */
    CHECK(vec3_eq(s.transform.scale, vec3_make(2, 2, 2)) && vec3_eq(s.transform.translate, vec3_make(1, 1, 1)));
    animation_shape_at(k, 5, ANIMATION_LINEAR, 0.5, &s);
    CHECK(vec3_eq(s.emission, vec3_make(2, 4, 6)));     /* before the first emission key */
    animation_shape_at(k, 5, ANIMATION_LINEAR, 2.0, &s);
    CHECK(vec3_eq(s.position, vec3_make(4, 2, 0)));
    CHECK(vec3_eq(s.emission, vec3_make(3, 2, 6)));     /* halfway between keys 1 and 3 */
    animation_shape_at(k, 5, ANIMATION_LINEAR, 3.5, &s);
    CHECK(vec3_eq(s.position, vec3_make(4, 2, 6)));
    CHECK(vec3_eq(s.emission, vec3_make(4, 0, 6)));     /* after the last emission key */

    /* With Catmull-Rom the emission channel has two keys, so it is linear too, while position
     * (three keys) bends: at t = 1 it leaves the chord of keys 0 and 2. */
    animation_shape_at(k, 5, ANIMATION_CATMULL_ROM, 2.0, &s);
    CHECK(vec3_eq(s.emission, vec3_make(3, 2, 6)));
    animation_shape_at(k, 5, ANIMATION_CATMULL_ROM, 1.0, &s);
    CHECK(!vec3_eq(s.position, vec3_make(2, 1, 0)));
    CHECK(s.position.z < 0.0f);  /* the tangent at key 2 points to +z: the curve dips first */

    /* A channel no key sets is absent, with neutral values. */
    struct animation_shape_key only_em[1] = {{.t_s = 0, .has_emission = true, .emission = {1, 1, 1}}};
    animation_shape_at(only_em, 1, ANIMATION_CATMULL_ROM, 0.0, &s);
    CHECK(s.has_emission && !s.has_position && !s.has_transform);
    CHECK(vec3_eq(s.transform.scale, vec3_make(1, 1, 1)) && vec3_eq(s.position, vec3_make(0, 0, 0)));
}

/* One-sided second-order difference quotients of the camera's position.x around t. */
static double cam_x(const struct animation_camera_key *k, uint32_t n, enum animation_interp in, double t)
{
    struct camera_desc c;
    animation_camera_at(k, n, in, t, &c);
    return c.position.x;
}

static void test_anim_catmull_rom_c1(void)
{
    const double h = 1e-3;
    for (int i = 1; i < 4; i++) {
        double t = cam_keys[i].t_s;
        double left = (3 * cam_x(cam_keys, 5, ANIMATION_CATMULL_ROM, t) - 4 * cam_x(cam_keys, 5, ANIMATION_CATMULL_ROM, t - h) +
                       cam_x(cam_keys, 5, ANIMATION_CATMULL_ROM, t - 2 * h)) / (2 * h);
        double right = (-3 * cam_x(cam_keys, 5, ANIMATION_CATMULL_ROM, t) + 4 * cam_x(cam_keys, 5, ANIMATION_CATMULL_ROM, t + h) -
                        cam_x(cam_keys, 5, ANIMATION_CATMULL_ROM, t + 2 * h)) / (2 * h);
        double want = (cam_keys[i + 1].camera.position.x - cam_keys[i - 1].camera.position.x) /
                      (cam_keys[i + 1].t_s - cam_keys[i - 1].t_s);
        CHECK_MSG(fabs(left - right) < 2e-3, "key %d: left %g right %g", i, left, right);
        CHECK_MSG(fabs(left - want) < 2e-3 && fabs(right - want) < 2e-3, "key %d: %g %g want %g", i, left, right, want);
        /* The same probe sees linear interpolation's kink, so it can tell. */
        double l_lin = (cam_x(cam_keys, 5, ANIMATION_LINEAR, t) - cam_x(cam_keys, 5, ANIMATION_LINEAR, t - h)) / h;
        double r_lin = (cam_x(cam_keys, 5, ANIMATION_LINEAR, t + h) - cam_x(cam_keys, 5, ANIMATION_LINEAR, t)) / h;
        CHECK_MSG(fabs(l_lin - r_lin) > 0.5, "key %d: linear %g %g", i, l_lin, r_lin);
    }
}

static void test_anim_up_renormalised(void)
{
    struct animation_camera_key k[2] = {
        cam_key(0, vec3_make(0, 0, 5), vec3_make(0, 0, 0), vec3_make(0, 2, 0), 40),
        cam_key(1, vec3_make(0, 0, 5), vec3_make(0, 0, 0), vec3_make(3, 0, 0), 40),
    };
    for (int interp = 0; interp < 2; interp++) {
        for (int i = 0; i <= 10; i++) {
            struct camera_desc c;
            animation_camera_at(k, 2, (enum animation_interp)interp, 0.1 * i, &c);
            CHECK_NEAR(vec3_length(c.up), 1.0, 1e-6);
            /* Direction of the interpolated (unnormalised) up (2(1-u), 3u, 0) / |.|. */
            double u = 0.1 * i, ux = 3 * u, uy = 2 * (1 - u), l = sqrt(ux * ux + uy * uy);
            CHECK_NEAR(c.up.x, ux / l, 1e-6);
            CHECK_NEAR(c.up.y, uy / l, 1e-6);
        }
    }
    /* Opposite ups cancel at the midpoint: the nearer key's up stands in. */
    k[0].camera.up = vec3_make(0, 1, 0);
    k[1].camera.up = vec3_make(0, -1, 0);
    struct camera_desc c;
    animation_camera_at(k, 2, ANIMATION_LINEAR, 0.5, &c);
    CHECK_MSG(vec3_eq(c.up, vec3_make(0, 1, 0)) || vec3_eq(c.up, vec3_make(0, -1, 0)), "%g %g %g", (double)c.up.x,
              (double)c.up.y, (double)c.up.z);
    /* Off the midpoint the short interpolated up is simply renormalised. */
    animation_camera_at(k, 2, ANIMATION_LINEAR, 0.45, &c);
    CHECK(vec3_eq(c.up, vec3_make(0, 1, 0)));
    animation_camera_at(k, 2, ANIMATION_LINEAR, 0.55, &c);
    CHECK(vec3_eq(c.up, vec3_make(0, -1, 0)));
}

/* Keys 0, 0, 10: the Catmull-Rom segment between the two zeros dips below 0 (its end tangent
 * is 5). Position shows the dip; emission is clamped at 0; fov and scale stay within their
 * keys' range. */
static void test_anim_overshoot_clamps(void)
{
    struct animation_shape_key k[3] = {
        {.t_s = 0, .has_position = true, .has_emission = true},
        {.t_s = 1, .has_position = true, .has_emission = true},
        {.t_s = 2, .has_position = true, .position = {10, 10, 10}, .has_emission = true, .emission = {10, 10, 10}},
    };
    struct animation_shape_state s;
    animation_shape_at(k, 3, ANIMATION_CATMULL_ROM, 0.5, &s);
    CHECK_MSG(s.position.x < -0.1f, "%g", (double)s.position.x);
    CHECK(s.emission.x == 0.0f && s.emission.y == 0.0f && s.emission.z == 0.0f);

    struct animation_shape_key tk[3] = {
        {.t_s = 0, .has_transform = true, .transform = {{0, 0, 0}, {0, 0, 0}, {1, 1, 1}}},
        {.t_s = 1, .has_transform = true, .transform = {{0, 0, 0}, {0, 0, 0}, {1, 1, 1}}},
        {.t_s = 2, .has_transform = true, .transform = {{10, 0, 0}, {90, 0, 0}, {20, 1, 1}}},
    };
    animation_shape_at(tk, 3, ANIMATION_CATMULL_ROM, 0.5, &s);
    CHECK(s.transform.translate.x < -0.1f && s.transform.rotate_deg.x < -0.1f);  /* free to overshoot */
    CHECK(s.transform.scale.x == 1.0f);                                            /* clamped */

    struct animation_camera_key ck[3] = {
        cam_key(0, vec3_make(0, 0, 5), vec3_make(0, 0, 0), vec3_make(0, 1, 0), 30),
        cam_key(1, vec3_make(0, 0, 5), vec3_make(0, 0, 0), vec3_make(0, 1, 0), 30),
        cam_key(2, vec3_make(0, 0, 5), vec3_make(0, 0, 0), vec3_make(0, 1, 0), 170),
    };
    for (int i = 0; i <= 20; i++) {
        struct camera_desc c;
        animation_camera_at(ck, 3, ANIMATION_CATMULL_ROM, 0.1 * i, &c);
        CHECK_MSG(c.fov_deg >= 30.0f && c.fov_deg <= 170.0f, "t %g fov %g", 0.1 * i, (double)c.fov_deg);
    }
}

/* ---- tone-mapped previews ---------------------------------------------------------------- */

static void test_curve_names(void)
{
    enum tonemap_curve c;
    const enum tonemap_curve all[3] = {TONEMAP_CLAMP, TONEMAP_REINHARD, TONEMAP_ACES};
    for (int i = 0; i < 3; i++) {
        CHECK(tonemap_curve_parse(tonemap_curve_name(all[i]), &c) && c == all[i]);
    }
    CHECK(strcmp(tonemap_curve_name(TONEMAP_ACES), "aces") == 0);
    CHECK(!tonemap_curve_parse("ACES", &c) && !tonemap_curve_parse("", &c) && !tonemap_curve_parse(NULL, &c));
    CHECK(tonemap_curve_name((enum tonemap_curve)17) == NULL);
}

static void test_png_known_pixels(void)
{
    struct vec3 px[8] = {
        {0, 0, 0}, {1, 1, 1}, {0.5f, 0.5f, 0.5f}, {NAN, 0, 0},
        {0, 0.5f, 1}, {0.25f, 2, -1}, {INFINITY, 1, 1}, {0.001f, 0.1f, 0.7f},
    };
    struct image img = make(4, 2, px);
    struct png p;
    if (preview(&img, 0.0f, TONEMAP_CLAMP, &p)) {
        CHECK(p.w == 4 && p.h == 2);
        CHECK(px_is(png_px(&p, 0, 0), 0, 0, 0));
        CHECK(px_is(png_px(&p, 1, 0), 255, 255, 255));
        CHECK(px_is(png_px(&p, 2, 0), 188, 188, 188));
        CHECK(px_is(png_px(&p, 3, 0), 255, 0, 255));  /* NaN */
        CHECK(px_is(png_px(&p, 0, 1), 0, 188, 255));  /* channels independent */
        CHECK(px_is(png_px(&p, 1, 1), srgb_code(0.25), 255, 0));  /* 2 clips, -1 is black */
        CHECK(px_is(png_px(&p, 2, 1), 255, 0, 255));  /* Inf */
        CHECK(px_is(png_px(&p, 3, 1), srgb_code(0.001), srgb_code(0.1), srgb_code(0.7)));
        free(p.rgb);
    }
    /* +1 EV doubles: 0.25 -> 0.5 -> 188, 0.5 -> 1 -> 255. */
    if (preview(&img, 1.0f, TONEMAP_CLAMP, &p)) {
        CHECK(px_is(png_px(&p, 2, 0), 255, 255, 255));
        CHECK(px_is(png_px(&p, 1, 1), 188, 255, 0));
        CHECK(px_is(png_px(&p, 3, 1), srgb_code(0.002), srgb_code(0.2), 255));
        CHECK(px_is(png_px(&p, 3, 0), 255, 0, 255));
        free(p.rgb);
    }
    /* A huge exposure keeps black black and NaN magenta; a tiny one makes everything black. */
    if (preview(&img, 3000.0f, TONEMAP_REINHARD, &p)) {
        CHECK(px_is(png_px(&p, 0, 0), 0, 0, 0));
        CHECK(px_is(png_px(&p, 1, 0), 255, 255, 255));
        CHECK(px_is(png_px(&p, 3, 0), 255, 0, 255));
        free(p.rgb);
    }
    if (preview(&img, -3000.0f, TONEMAP_ACES, &p)) {
        CHECK(px_is(png_px(&p, 1, 0), 0, 0, 0));
        free(p.rgb);
    }
    /* Reinhard maps 1 to 0.5; ACES (Narkowicz 2016) maps 1 to 2.54 / 3.16. */
    if (preview(&img, 0.0f, TONEMAP_REINHARD, &p)) {
        CHECK(px_is(png_px(&p, 1, 0), 188, 188, 188));
        free(p.rgb);
    }
    if (preview(&img, 0.0f, TONEMAP_ACES, &p)) {
        int want = srgb_code(2.54 / 3.16);
        CHECK_MSG(px_is(png_px(&p, 1, 0), want, want, want), "%d vs %d", png_px(&p, 1, 0)[0], want);
        CHECK(want > 220 && want < 240);
        free(p.rgb);
    }
    image_destroy(&img);
}

/* Every curve against the formula evaluated directly, over a dense sweep of values. */
static void test_png_curves_match_formulas(void)
{
    uint32_t w = 509, h = 31;
    struct image img = make(w, h, NULL);
    if (!img.pixels) { CHECK(0); return; }
    for (size_t i = 0; i < (size_t)w * h; i++) {
        double v = (double)i / (w * h) * 12.0;
        v = v * v / 12.0;  /* dense near 0, where sRGB is steepest */
        img.pixels[i] = vec3_make((float)v, (float)(v * 0.37), (float)rnd_unit());
    }
    for (int curve = 0; curve < 3; curve++) {
        struct png p;
        if (!preview(&img, 0.5f, (enum tonemap_curve)curve, &p)) continue;
        int bad = 0;
        for (size_t i = 0; i < (size_t)w * h && bad < 5; i++) {
            for (int c = 0; c < 3; c++) {
                double x = vec3_comp(img.pixels[i], c) * exp2(0.5);
                double y = curve == 0 ? fmin(x, 1.0)
                           : curve == 1 ? x / (1.0 + x)
                                        : fmin(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 1.0);
                int want = srgb_code(y), got = p.rgb[3 * i + (size_t)c];
                if (want != got) {
                    CHECK_MSG(0, "curve %d pixel %zu channel %d: x %.9g got %d want %d", curve, i, c, x, got, want);
                    bad++;
                }
            }
        }
        free(p.rgb);
    }
    image_destroy(&img);
}

/* Noise that does not compress spans several IDAT chunks; every byte code comes back exactly
 * (values at the centre of each code's interval), through whichever filters rows chose. */
static void test_png_large_multi_idat(void)
{
    uint32_t w = 1000, h = 800;
    struct image img = make(w, h, NULL);
    if (!img.pixels) { CHECK(0); return; }
    unsigned char *codes = malloc((size_t)w * h * 3);
    for (size_t i = 0; i < (size_t)w * h * 3; i++) {
        size_t x = (i / 3) % w, y = (i / 3) / w;
        /* Left half: noise; right half: smooth ramps (where Sub/Up/Paeth pay off). */
        codes[i] = x < w / 2 ? (unsigned char)rnd_u32() : (unsigned char)((x + 2 * y + 40 * (i % 3)) & 255);
    }
    for (size_t i = 0; i < (size_t)w * h; i++) {
        float v[3];
        for (int c = 0; c < 3; c++) v[c] = (float)srgb_decode(codes[3 * i + (size_t)c] / 255.0);
        img.pixels[i] = vec3_make(v[0], v[1], v[2]);
    }
    struct png p;
    if (preview(&img, 0.0f, TONEMAP_CLAMP, &p)) {
        CHECK(p.w == w && p.h == h);
        CHECK_MSG(p.idat_count >= 2, "%d IDAT chunks, %zu bytes", p.idat_count, p.size);
        CHECK_MSG(p.filters_used != 1u, "only filter type 0 was used");
        CHECK(memcmp(p.rgb, codes, (size_t)w * h * 3) == 0);
        free(p.rgb);
    }
    free(codes);
    image_destroy(&img);
}

static void test_png_errors(void)
{
    struct vec3 px[1] = {{1, 1, 1}};
    struct image img = make(1, 1, px);
    unsigned char *buf = (unsigned char *)&img;  /* must be reset to NULL on failure */
    size_t n = 7;
    struct err err = {0};
    struct tonemap_opts o = {NAN, TONEMAP_CLAMP};
    CHECK(!tonemap_png(&img, &o, &buf, &n, &err) && err.code == ERR_INVALID && !buf && n == 0);
    o.exposure_ev = INFINITY;
    CHECK(!tonemap_png(&img, &o, &buf, &n, &err) && err.code == ERR_INVALID);
    o.exposure_ev = 0;
    o.curve = (enum tonemap_curve)9;
    CHECK(!tonemap_png(&img, &o, &buf, &n, &err) && err.code == ERR_INVALID);
    o.curve = TONEMAP_CLAMP;
    CHECK(!tonemap_png(NULL, &o, &buf, &n, &err) && err.code == ERR_INVALID);
    CHECK(!tonemap_png(&img, NULL, &buf, &n, &err) && err.code == ERR_INVALID);
    struct image empty = {0};
    CHECK(!tonemap_png(&empty, &o, &buf, &n, &err) && err.code == ERR_INVALID);
    struct image huge = {20000, 1, img.pixels};
    CHECK(!tonemap_png(&huge, &o, &buf, &n, &err) && err.code == ERR_LIMIT);
    /* A 1x1 image is the smallest valid PNG. */
    struct png p;
    if (preview(&img, 0.0f, TONEMAP_CLAMP, &p)) {
        CHECK(p.w == 1 && p.h == 1 && px_is(p.rgb, 255, 255, 255));
        free(p.rgb);
    }
    image_destroy(&img);
}

/* ---- error maps -------------------------------------------------------------------------- */

/* The ramp's documented anchors (tonemap.c): first, middle, last. */
static const unsigned char ramp_first[3] = {12, 14, 48}, ramp_mid[3] = {22, 134, 150}, ramp_last[3] = {252, 240, 134};

static double lstar(const unsigned char *rgb)
{
    double y = 0.2126 * srgb_decode(rgb[0] / 255.0) + 0.7152 * srgb_decode(rgb[1] / 255.0) +
               0.0722 * srgb_decode(rgb[2] / 255.0);
    double f = y > 216.0 / 24389.0 ? cbrt(y) : (24389.0 / 27.0 * y + 16.0) / 116.0;
    return 116.0 * f - 16.0;
}

static void test_error_map_identical(void)
{
    uint32_t w = 37, h = 11;
    struct image a = make(w, h, NULL), b = make(w, h, NULL);
    if (!a.pixels || !b.pixels) { CHECK(0); return; }
    for (size_t i = 0; i < (size_t)w * h; i++) a.pixels[i] = b.pixels[i] = vec3_make((float)rnd_unit(), 3.0f, 0.0f);
    struct png p;
    float used = 0;
    if (error_map(&a, &b, 0.0f, &used, &p)) {
        CHECK(used == 1e-6f);
        int off = 0;
        for (size_t i = 0; i < (size_t)w * h; i++) off += memcmp(p.rgb + 3 * i, ramp_first, 3) != 0;
        CHECK_MSG(off == 0, "%d pixels not the first ramp colour", off);
        free(p.rgb);
    }
    image_destroy(&a);
    image_destroy(&b);
}

static void test_error_map_errors(void)
{
    struct image a = make(3, 2, NULL), b = make(2, 3, NULL);
    unsigned char *buf = NULL;
    size_t n = 0;
    struct err err = {0};
    float used = 0;
    CHECK(!tonemap_error_png(&a, &b, 0.0f, &used, &buf, &n, &err) && err.code == ERR_INVALID && !buf);
    CHECK_MSG(strstr(err.message, "3x2") && strstr(err.message, "2x3"), "%s", err.message);
    CHECK(!tonemap_error_png(&a, NULL, 0.0f, &used, &buf, &n, &err) && err.code == ERR_INVALID);
    CHECK(!tonemap_error_png(&a, &a, NAN, &used, &buf, &n, &err) && err.code == ERR_INVALID);
    image_destroy(&a);
    image_destroy(&b);
}

/* The error of img value v against a reference of ones (mean 1), exactly as the header
 * defines it: |v - 1| / (1 + 0.01 * 1) per channel, in double, rounded to float as the map
 * stores it. */
static float err_vs_ones(float v)
{
    double s = 0.0;
    for (int c = 0; c < 3; c++) s += fabs((double)v - 1.0) / (1.0 + 0.01);
    return (float)(s / 3.0);
}

static void fill_ones(struct image *img)
{
    for (size_t i = 0; i < (size_t)img->width * img->height; i++) img->pixels[i] = vec3_splat(1.0f);
}

static int cmp_float(const void *a, const void *b)
{
    float x = *(const float *)a, y = *(const float *)b;
    return (x > y) - (x < y);
}

static void test_error_map_percentile_and_colours(void)
{
    /* 1050 pixels, 50 of them non-finite (every 21st, in the image or the reference): 1000
     * finite errors, so 0.99 * 1000 is a whole rank and an off-by-one choice of rank shows. */
    uint32_t w = 50, h = 21;
    struct image img = make(w, h, NULL), ref = make(w, h, NULL);
    if (!img.pixels || !ref.pixels) { CHECK(0); return; }
    fill_ones(&ref);
    float *errs = malloc(sizeof(float) * w * h);
    size_t m = 0;
    for (size_t i = 0; i < (size_t)w * h; i++) {
        float v = 1.0f + (float)(rnd_unit() * rnd_unit() * 3.0);  /* skewed: a long tail */
        img.pixels[i] = vec3_splat(v);
        if (i % 21 != 5) {
            errs[m++] = err_vs_ones(v);
            continue;
        }
        switch ((i / 21) % 3) {
        case 0: img.pixels[i].y = NAN; break;
        case 1: ref.pixels[i].z = INFINITY; break;
        default: img.pixels[i].x = -INFINITY; break;
        }
    }
    qsort(errs, m, sizeof *errs, cmp_float);
    size_t rank = (99 * m + 99) / 100;  /* nearest rank ceil(0.99 m), 1-based */
    CHECK(m == 1000 && rank == 990);
    struct png p;
    float used = 0;
    if (error_map(&img, &ref, 0.0f, &used, &p)) {
        CHECK_MSG(used == errs[rank - 1], "used %.9g want %.9g (neighbours %.9g %.9g)", (double)used,
                  (double)errs[rank - 1], (double)errs[rank - 2], (double)errs[rank]);
        int magenta = 0, off = 0;
        for (size_t i = 0; i < (size_t)w * h; i++) {
            bool is_m = px_is(p.rgb + 3 * i, 255, 0, 255);
            magenta += is_m;
            off += is_m != (i % 21 == 5);
        }
        CHECK_MSG(magenta == 50 && off == 0, "%d magenta, %d misplaced", magenta, off);
        /* Pixels at or over the scale are the last colour; there are m - rank + 1 of them at
         * least (ties included). */
        int last = 0;
        for (size_t i = 0; i < (size_t)w * h; i++) last += memcmp(p.rgb + 3 * i, ramp_last, 3) == 0;
        CHECK_MSG(last >= (int)(m - rank + 1) && last < 50, "%d pixels at the top", last);
        free(p.rgb);
    }
    free(errs);

    /* A given scale: error 0 -> first anchor, scale / 2 -> middle anchor, >= scale -> last
     * (errors 0, 2, 4 and 7 against ones, to float rounding, which the 8-bit colours hide). */
    struct vec3 px[4] = {{1, 1, 1}, {3.02f, 3.02f, 3.02f}, {5.04f, 5.04f, 5.04f}, {8.07f, 8.07f, 8.07f}};
    struct image a = make(4, 1, px), z = make(4, 1, NULL);
    fill_ones(&z);
    CHECK(fabsf(err_vs_ones(3.02f) - 2.0f) < 1e-6f && fabsf(err_vs_ones(5.04f) - 4.0f) < 1e-6f);
    if (error_map(&a, &z, 4.0f, &used, &p)) {
        CHECK(used == 4.0f);
        CHECK(memcmp(png_px(&p, 0, 0), ramp_first, 3) == 0);
        CHECK(memcmp(png_px(&p, 1, 0), ramp_mid, 3) == 0);
        CHECK(memcmp(png_px(&p, 2, 0), ramp_last, 3) == 0);
        CHECK(memcmp(png_px(&p, 3, 0), ramp_last, 3) == 0);
        free(p.rgb);
    }
    image_destroy(&a);
    image_destroy(&z);
    image_destroy(&img);
    image_destroy(&ref);
}

/* The ramp is perceptually ordered: CIE L* rises strictly along 64 steps from 0 to the scale,
 * and no step is magenta-like (the non-finite marker). */
static void test_error_map_ramp_lightness(void)
{
    uint32_t n = 65;
    struct image img = make(n, 1, NULL), ref = make(n, 1, NULL);
    if (!img.pixels || !ref.pixels) { CHECK(0); return; }
    fill_ones(&ref);
    for (uint32_t i = 0; i < n; i++) img.pixels[i] = vec3_splat(1.0f + 0.01f * (float)i / (float)(n - 1));
    float scale = err_vs_ones(1.01f);
    struct png p;
    if (error_map(&img, &ref, scale, NULL, &p)) {
        CHECK(memcmp(p.rgb, ramp_first, 3) == 0 && memcmp(png_px(&p, n - 1, 0), ramp_last, 3) == 0);
        for (uint32_t i = 1; i < n; i++) {
            double l0 = lstar(png_px(&p, i - 1, 0)), l1 = lstar(png_px(&p, i, 0));
            CHECK_MSG(l1 > l0, "step %u: L* %.3f -> %.3f", i, l0, l1);
            const unsigned char *c = png_px(&p, i, 0);
            CHECK(!(c[0] > 200 && c[1] < 80 && c[2] > 200));
        }
        free(p.rgb);
    }
    image_destroy(&img);
    image_destroy(&ref);
}

/* The map shows metrics_error_image's values, MAPE's per-pixel terms: on a reference whose
 * mean is 15 the denominator is r + 0.15, so an image 0.15 above a black reference pixel has
 * error 1 (r + 0.01 would make it 15). With one error of 1 and one of 0, the 99th percentile
 * the map picks as its scale is that error, bit for bit; an all-black reference leaves MAPE
 * undefined and the whole map magenta. */
static void test_error_map_is_mapes_term(void)
{
    struct vec3 r[2] = {{0, 0, 0}, {30, 30, 30}}, a[2] = {{0.15f, 0.15f, 0.15f}, {30, 30, 30}};
    struct image ref = make(2, 1, r), img = make(2, 1, a), errs = make(2, 1, NULL);
    struct metrics m = {0};
    struct err err = {0};
    CHECK(metrics_compare(&img, &ref, &m, &err) && metrics_error_image(&img, &ref, &m, &errs, &err));
    CHECK_NEAR(errs.pixels[0].x, 1.0, 1e-6);
    struct png p;
    float used = 0;
    if (error_map(&img, &ref, 0.0f, &used, &p)) {
        CHECK_MSG(used == errs.pixels[0].x, "scale %.9g, error %.9g", (double)used, (double)errs.pixels[0].x);
        CHECK(memcmp(png_px(&p, 0, 0), ramp_last, 3) == 0 && memcmp(png_px(&p, 1, 0), ramp_first, 3) == 0);
        free(p.rgb);
    }
    struct image black = make(2, 1, NULL);
    if (error_map(&img, &black, 1.0f, NULL, &p)) {
        CHECK(px_is(png_px(&p, 0, 0), 255, 0, 255) && px_is(png_px(&p, 1, 0), 255, 0, 255));
        free(p.rgb);
    }
    image_destroy(&ref);
    image_destroy(&img);
    image_destroy(&errs);
    image_destroy(&black);
}

TEST_MAIN(TEST(test_deflate_crc_and_round_trip), TEST(test_anim_values_at_keys_exact),
          TEST(test_anim_two_keys_catmull_rom_is_linear), TEST(test_anim_clamps_outside_keys),
          TEST(test_anim_channels_independent), TEST(test_anim_catmull_rom_c1), TEST(test_anim_up_renormalised),
          TEST(test_anim_overshoot_clamps), TEST(test_curve_names), TEST(test_png_known_pixels),
          TEST(test_png_curves_match_formulas), TEST(test_png_large_multi_idat), TEST(test_png_errors),
          TEST(test_error_map_identical), TEST(test_error_map_errors), TEST(test_error_map_percentile_and_colours),
          TEST(test_error_map_ramp_lightness), TEST(test_error_map_is_mapes_term))
