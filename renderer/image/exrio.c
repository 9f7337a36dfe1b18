/* exrio.c — OpenEXR encode/decode through the OpenEXR Core C API (see exrio.h for contracts).
 * The only file that includes openexr.h. Both directions go through custom streams (a growing
 * memory sink for writes, a pread/memcpy source for reads), so file and memory share one path.
 * Must not decode pixels of a file whose header fails the gate, must not print (library
 * messages are captured into the returned err), must not exit/abort.
 * Refs: OpenEXR "Reading and Writing Image Files with the OpenEXR Core Library" and the
 * headers openexr_{context,part,encode,decode,chunkio}.h of libOpenEXRCore 3.1. */
#include "image/exrio.h"

#include <errno.h>
#include <fcntl.h>
#include <openexr.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
/* F16C code is compiled for that target alone and only called after a run-time check. */
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#include <cpuid.h>
#include <immintrin.h>
#define EXRIO_HAVE_F16C 1
#endif

#include "image/deflate.h"

#define EXRIO_MEM_NAME "<memory>"
/* EXR channel names without the long-name flag; every reader accepts these. */
#define EXRIO_MAX_CHANNEL_NAME 31

/* ---- library messages ------------------------------------------------------------------ */

/* OpenEXR reports details through a callback, often while holding the context's lock, so the
 * callback must not call back into the library. A thread-local slot is enough: every exrio
 * call drives its context on the calling thread only. We keep the first message of an
 * operation because later ones tend to be generic wrappers ("Unable to decompress ..."). */
static _Thread_local char exrio_lib_msg[320];

static void exrio_lib_error(exr_const_context_t ctxt, exr_result_t code, const char *msg)
{
    (void)ctxt;
    if (exrio_lib_msg[0]) return;
    snprintf(exrio_lib_msg, sizeof exrio_lib_msg, "%s (%s)", msg ? msg : "",
             exr_get_error_code_as_string(code));
}

static void exrio_lib_reset(void) { exrio_lib_msg[0] = '\0'; }

/* err_set for a failed library call: the captured message, else the code's default text. */
static bool exrio_lib_fail(struct err *err, enum err_code code, const char *where, exr_result_t rv,
                           const char *what)
{
    if (rv == EXR_ERR_OUT_OF_MEMORY) code = ERR_NOMEM;
    const char *detail = exrio_lib_msg[0] ? exrio_lib_msg : exr_get_default_error_message(rv);
    return err_set(err, code, where, "%s: %s", what, detail);
}

const char *exrio_compression_name(enum exrio_compression c)
{
    switch (c) {
    case EXRIO_NONE: return "NONE";
    case EXRIO_RLE: return "RLE";
    case EXRIO_ZIPS: return "ZIPS";
    case EXRIO_ZIP: return "ZIP";
    case EXRIO_PIZ: return "PIZ";
    case EXRIO_OTHER: return "OTHER";
    }
    return "OTHER";
}

/* Name of a codec as stored in a file, including those exrio_compression lumps as OTHER. */
static const char *exrio_lib_compression_name(exr_compression_t c)
{
    switch (c) {
    case EXR_COMPRESSION_NONE: return "NONE";
    case EXR_COMPRESSION_RLE: return "RLE";
    case EXR_COMPRESSION_ZIPS: return "ZIPS";
    case EXR_COMPRESSION_ZIP: return "ZIP";
    case EXR_COMPRESSION_PIZ: return "PIZ";
    case EXR_COMPRESSION_PXR24: return "PXR24";
    case EXR_COMPRESSION_B44: return "B44";
    case EXR_COMPRESSION_B44A: return "B44A";
    case EXR_COMPRESSION_DWAA: return "DWAA";
    case EXR_COMPRESSION_DWAB: return "DWAB";
    default: return "unknown";
    }
}

static enum exrio_compression exrio_from_lib_compression(exr_compression_t c)
{
    switch (c) {
    case EXR_COMPRESSION_NONE: return EXRIO_NONE;
    case EXR_COMPRESSION_RLE: return EXRIO_RLE;
    case EXR_COMPRESSION_ZIPS: return EXRIO_ZIPS;
    case EXR_COMPRESSION_ZIP: return EXRIO_ZIP;
    case EXR_COMPRESSION_PIZ: return EXRIO_PIZ;
    default: return EXRIO_OTHER;
    }
}

static const char *exrio_pixel_name(exr_pixel_type_t t)
{
    switch (t) {
    case EXR_PIXEL_HALF: return "HALF";
    case EXR_PIXEL_FLOAT: return "FLOAT";
    case EXR_PIXEL_UINT: return "UINT";
    default: return "unknown";
    }
}

/* ---- write side -------------------------------------------------------------------------- */

/* Growing memory sink. The library writes the header, skips the chunk offset table, appends
 * chunks, and fills the table in at exr_finish, so writes may land past the current end. */
struct exrio_sink {
    unsigned char *buf;
    size_t size, cap;
    bool nomem;
};

static int64_t exrio_sink_write(exr_const_context_t ctxt, void *userdata, const void *buffer,
                                uint64_t sz, uint64_t offset, exr_stream_error_func_ptr_t error_cb)
{
    (void)ctxt;
    (void)error_cb;
    struct exrio_sink *s = userdata;
    if (offset > SIZE_MAX / 2 || sz > SIZE_MAX / 2 || sz > (uint64_t)INT64_MAX) {
        s->nomem = true;
        return -1;
    }
    size_t end = (size_t)offset + (size_t)sz;
    if (end > s->cap) {
        size_t cap = s->cap ? s->cap : 65536;
        while (cap < end) cap *= 2;
        unsigned char *nb = realloc(s->buf, cap);
        if (!nb) {
            s->nomem = true;
            return -1;
        }
        s->buf = nb;
        s->cap = cap;
    }
    if (offset > s->size) memset(s->buf + s->size, 0, (size_t)offset - s->size);
    if (sz) memcpy(s->buf + offset, buffer, (size_t)sz);
    if (end > s->size) s->size = end;
    return (int64_t)sz;
}

/* Where the encoder takes one channel's values from: base + y*line_stride + x*pixel_stride. */
struct exrio_src {
    char name[EXRIO_MAX_CHANNEL_NAME + 1];
    exr_pixel_type_t type;
    const unsigned char *base;
    int32_t pixel_stride;
    size_t line_stride;
};

static bool exrio_valid_token(const char *s, size_t max_len)
{
    size_t n = 0;
    for (; s[n]; n++) {
        char c = s[n];
        bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                  c == '_' || c == '-';
        if (!ok || n >= max_len) return false;
    }
    return n > 0;
}

static const float exrio_one = 1.0f;
/* Checks the image and options and lists every channel's source; returns the channel count
 * through *count. */
static bool exrio_plan(const struct image *img, const struct exrio_write_opts *opts,
                       struct exrio_src *srcs, int *count, const char *where, struct err *err)
{
    if (!img || !opts) return err_set(err, ERR_INVALID, where, "image and options are required");
    if (!img->pixels || img->width == 0 || img->height == 0 || img->width > EXRIO_MAX_SIDE ||
        img->height > EXRIO_MAX_SIDE)
        return err_set(err, ERR_INVALID, where, "image %ux%u is empty or larger than %ux%u",
                       img->width, img->height, EXRIO_MAX_SIDE, EXRIO_MAX_SIDE);
    if (opts->pixel != EXRIO_HALF && opts->pixel != EXRIO_FLOAT)
        return err_set(err, ERR_INVALID, where, "pixel type must be HALF or FLOAT");
    switch (opts->compression) {
    case EXRIO_NONE: case EXRIO_RLE: case EXRIO_ZIPS: case EXRIO_ZIP: case EXRIO_PIZ: break;
    default: return err_set(err, ERR_INVALID, where, "compression must be NONE, RLE, ZIPS, ZIP or PIZ");
    }
    if (opts->aov_count < 0 || (opts->aov_count > 0 && !opts->aovs))
        return err_set(err, ERR_INVALID, where, "bad AOV list (count %d)", opts->aov_count);

    exr_pixel_type_t beauty = opts->pixel == EXRIO_HALF ? EXR_PIXEL_HALF : EXR_PIXEL_FLOAT;
    size_t w = img->width;
    int n = 0;
    const unsigned char *px = (const unsigned char *)img->pixels;
    static const char *const rgb[3] = {"R", "G", "B"};
    for (int c = 0; c < 3; c++) {
        struct exrio_src *s = &srcs[n++];
        snprintf(s->name, sizeof s->name, "%s", rgb[c]);
        s->type = beauty;
        s->base = px + (size_t)c * sizeof(float);
        s->pixel_stride = (int32_t)sizeof(struct vec3);
        s->line_stride = w * sizeof(struct vec3);
    }
    if (opts->alpha) {
        /* A constant: stride 0 makes the packer read the same 1.0f for every pixel. */
        struct exrio_src *s = &srcs[n++];
        snprintf(s->name, sizeof s->name, "A");
        s->type = beauty;
        s->base = (const unsigned char *)&exrio_one;
        s->pixel_stride = 0;
        s->line_stride = 0;
    }
    for (int a = 0; a < opts->aov_count; a++) {
        const struct exrio_aov *aov = &opts->aovs[a];
        if (!aov->name || !exrio_valid_token(aov->name, EXRIO_MAX_CHANNEL_NAME))
            return err_set(err, ERR_INVALID, where,
                           "AOV %d: name must be 1..%d characters from [A-Za-z0-9_-]", a,
                           EXRIO_MAX_CHANNEL_NAME);
        if (aov->channels != 1 && aov->channels != 3)
            return err_set(err, ERR_INVALID, where, "AOV '%s': channels must be 1 or 3, not %d",
                           aov->name, aov->channels);
        if (!aov->data) return err_set(err, ERR_INVALID, where, "AOV '%s' has no data", aov->name);
        const char *one = aov->suffix ? aov->suffix : "Y";
        if (aov->channels == 1 && !exrio_valid_token(one, EXRIO_MAX_CHANNEL_NAME))
            return err_set(err, ERR_INVALID, where,
                           "AOV '%s': suffix must be characters from [A-Za-z0-9_-]", aov->name);
        if (n + aov->channels > EXRIO_MAX_WRITE_CHANNELS)
            return err_set(err, ERR_LIMIT, where, "more than %d channels", EXRIO_MAX_WRITE_CHANNELS);
        for (int c = 0; c < aov->channels; c++) {
            struct exrio_src *s = &srcs[n];
            const char *suffix = aov->channels == 3 ? rgb[c] : one;
            size_t ln = strlen(aov->name), ls = strlen(suffix);
            if (ln + 1 + ls > EXRIO_MAX_CHANNEL_NAME)
                return err_set(err, ERR_INVALID, where, "AOV channel '%s.%s' is longer than %d bytes",
                               aov->name, suffix, EXRIO_MAX_CHANNEL_NAME);
            memcpy(s->name, aov->name, ln);
            s->name[ln] = '.';
            memcpy(s->name + ln + 1, suffix, ls + 1);
            for (int k = 0; k < n; k++)
                if (strcmp(srcs[k].name, s->name) == 0)
                    return err_set(err, ERR_INVALID, where, "channel '%s' given twice", s->name);
            s->type = EXR_PIXEL_FLOAT;
            s->base = (const unsigned char *)(aov->data + c);
            s->pixel_stride = (int32_t)(sizeof(float) * (size_t)aov->channels);
            s->line_stride = w * sizeof(float) * (size_t)aov->channels;
            n++;
        }
    }
    *count = n;
    return true;
}

static exr_compression_t exrio_to_lib_compression(enum exrio_compression c)
{
    switch (c) {
    case EXRIO_RLE: return EXR_COMPRESSION_RLE;
    case EXRIO_ZIPS: return EXR_COMPRESSION_ZIPS;
    case EXRIO_ZIP: return EXR_COMPRESSION_ZIP;
    case EXRIO_PIZ: return EXR_COMPRESSION_PIZ;
    default: return EXR_COMPRESSION_NONE;
    }
}

/* ---- float -> half ------------------------------------------------------------------------
 * Every HALF value is converted here (our pack step, exrio_pack), bit for bit as
 * libOpenEXRCore 3.1's own float_to_half (internal_coding.h) does it: round to nearest even,
 * finite magnitudes from 65520 up become Inf, values below 2^-25 become a signed zero, NaN
 * keeps the top 10 bits of its payload (at least one bit set, so it stays NaN).
 * Two implementations, chosen once per encode: F16C's vcvtps2ph (8 values per instruction),
 * used when the CPU and OS support it, with NaN lanes redone by the portable routine (vcvtps2ph
 * also sets the quiet bit of a signalling NaN, OpenEXR does not), and a portable branch-free
 * integer routine. Setting RESTIRD_EXR_HALF=portable in the environment forces the latter
 * (tests compare both). */

static inline uint16_t exrio_float_to_half(uint32_t x)
{
    uint32_t sign = (x >> 16) & 0x8000u, a = x & 0x7fffffffu;
    /* normal half: drop 13 mantissa bits, rounding to nearest even */
    uint32_t nrm = a - 0x38000000u;
    nrm = (nrm + 0x0fffu + ((nrm >> 13) & 1u)) >> 13;
    /* subnormal half (2^-25 < a < 2^-14): the 24-bit significand shifted right by 14..24 */
    uint32_t e = a >> 23, sh = e < 102u ? 24u : e > 112u ? 14u : 126u - e;
    uint32_t sig = 0x800000u | (a & 0x7fffffu), sub = sig >> sh;
    uint32_t rem = sig & ((1u << sh) - 1u), halfway = 1u << (sh - 1u);
    sub += (rem > halfway) | ((rem == halfway) & sub);
    /* NaN: top payload bits, never all zero */
    uint32_t pay = (a & 0x7fffffu) >> 13;
    uint32_t nan = 0x7c00u | pay | (pay == 0u);
    uint32_t r = a > 0x7f800000u   ? nan
                 : a > 0x477fefffu ? 0x7c00u
                 : a >= 0x38800000u ? nrm
                 : a >= 0x33000001u ? sub
                                    : 0u;
    return (uint16_t)(sign | r);
}

static inline void exrio_put16(unsigned char *p, uint16_t v)
{
    p[0] = (unsigned char)v;
    p[1] = (unsigned char)(v >> 8);
}

static inline uint32_t exrio_load_bits(const unsigned char *p)
{
    uint32_t u;
    memcpy(&u, p, sizeof u);
    return u;
}

static inline float exrio_load_float(const unsigned char *p)
{
    float f;
    memcpy(&f, p, sizeof f);
    return f;
}

/* n floats from src (byte stride `stride`, 0 = one repeated value) to little-endian halves. */
typedef void exrio_halves_fn(const unsigned char *src, int32_t stride, int32_t n,
                             unsigned char *dst);

static void exrio_halves_portable(const unsigned char *src, int32_t stride, int32_t n,
                                  unsigned char *dst)
{
    for (int32_t x = 0; x < n; x++)
        exrio_put16(dst + 2 * (size_t)x, exrio_float_to_half(exrio_load_bits(src + (ptrdiff_t)x * stride)));
}

#ifdef EXRIO_HAVE_F16C
__attribute__((target("avx,f16c"))) static void exrio_halves_f16c(const unsigned char *src,
                                                                  int32_t stride, int32_t n,
                                                                  unsigned char *dst)
{
    int32_t x = 0;
    for (; x + 8 <= n; x += 8) {
        const unsigned char *p = src + (ptrdiff_t)x * stride;
        __m256 v;
        if (stride == 4) {
            v = _mm256_loadu_ps((const float *)(const void *)p);
        } else {  /* eight scalar loads into lanes (an array + vector load would stall) */
            ptrdiff_t s = stride;
            v = _mm256_setr_ps(exrio_load_float(p), exrio_load_float(p + s), exrio_load_float(p + 2 * s),
                               exrio_load_float(p + 3 * s), exrio_load_float(p + 4 * s),
                               exrio_load_float(p + 5 * s), exrio_load_float(p + 6 * s),
                               exrio_load_float(p + 7 * s));
        }
        __m128i h = _mm256_cvtps_ph(v, _MM_FROUND_TO_NEAREST_INT);
        _mm_storeu_si128((__m128i *)(void *)(dst + 2 * (size_t)x), h);
        if (_mm256_movemask_ps(_mm256_cmp_ps(v, v, _CMP_UNORD_Q)))
            exrio_halves_portable(p, stride, 8, dst + 2 * (size_t)x);
    }
    if (x < n) exrio_halves_portable(src + (ptrdiff_t)x * stride, stride, n - x, dst + 2 * (size_t)x);
}
#endif

static exrio_halves_fn *exrio_pick_halves(void)
{
    const char *force = getenv("RESTIRD_EXR_HALF");
    if (force && strcmp(force, "portable") == 0) return exrio_halves_portable;
#ifdef EXRIO_HAVE_F16C
    /* libgcc fills the CPU model in a constructor, so no __builtin_cpu_init (not thread-safe).
     * F16C is read from CPUID leaf 1 because clang's __builtin_cpu_supports does not know it
     * (the fuzz targets are built with clang); "avx" also checks that the OS saves YMM state. */
    unsigned a, b, c, d;
    if (__builtin_cpu_supports("avx") && __get_cpuid(1, &a, &b, &c, &d) && (c & bit_F16C)) return exrio_halves_f16c;
#endif
    return exrio_halves_portable;
}

/* What exrio_encode hands the pipeline's hooks (encoding_user_data). */
struct exrio_hooks {
    exrio_halves_fn *halves;
    /* ZIP, ZIPS only (exrio_zip_compress): */
    struct deflate *rle;       /* run-length compressor, made on first use */
    struct deflate *level1;    /* libdeflate level 1, made on first use */
    unsigned char *scratch;    /* the reordered and predicted chunk */
    size_t scratch_size;
    unsigned char *alt;        /* level 1's output when both are tried */
    size_t alt_size;
    bool smooth;               /* level 1 won the last HALF chunk: try it first */
};

/* Our convert_and_pack_fn, replacing the library's generic packer (4x more instructions for
 * HALF): per scanline of the chunk, each channel's `width` values in channel-list order,
 * little-endian. Sources are always FLOAT (exrio_encode sets user_data_type). */
static exr_result_t exrio_pack(exr_encode_pipeline_t *enc)
{
    const struct exrio_hooks *hooks = enc->encoding_user_data;
    uint64_t want = 0;
    for (int c = 0; c < enc->channel_count; c++) {
        const exr_coding_channel_info_t *ch = &enc->channels[c];
        if (ch->user_data_type != EXR_PIXEL_FLOAT || ch->height != enc->chunk.height ||
            ch->width < 0 || (ch->data_type != EXR_PIXEL_HALF && ch->data_type != EXR_PIXEL_FLOAT))
            return EXR_ERR_INVALID_ARGUMENT;
        want += (uint64_t)ch->height * (uint64_t)ch->width * (uint64_t)ch->bytes_per_element;
    }
    if (want > enc->packed_alloc_size) return EXR_ERR_INVALID_ARGUMENT;
    unsigned char *out = enc->packed_buffer;
    for (int32_t y = 0; y < enc->chunk.height; y++) {
        for (int c = 0; c < enc->channel_count; c++) {
            const exr_coding_channel_info_t *ch = &enc->channels[c];
            const unsigned char *src = (const unsigned char *)ch->encode_from_ptr +
                                       (ptrdiff_t)y * ch->user_line_stride;
            int32_t w = ch->width, stride = ch->user_pixel_stride;
            if (ch->data_type == EXR_PIXEL_HALF) {
                if (stride == 0) {  /* a constant channel (A): one value, then doubling copies */
                    size_t row = 2 * (size_t)w, done = 2;
                    if (w > 0) exrio_put16(out, exrio_float_to_half(exrio_load_bits(src)));
                    for (; done < row; done *= 2)
                        memcpy(out + done, out, done < row - done ? done : row - done);
                } else {
                    hooks->halves(src, stride, w, out);
                }
                out += 2 * (size_t)w;
            } else {
                for (int32_t x = 0; x < w; x++, out += 4) {
                    uint32_t u = exrio_load_bits(src + (ptrdiff_t)x * stride);
                    out[0] = (unsigned char)u;
                    out[1] = (unsigned char)(u >> 8);
                    out[2] = (unsigned char)(u >> 16);
                    out[3] = (unsigned char)(u >> 24);
                }
            }
        }
    }
    enc->packed_bytes = want;
    return EXR_ERR_SUCCESS;
}

/* ---- ZIP / ZIPS ---------------------------------------------------------------------------- */

/* The file format's transform before deflate, in one pass: t[0..half) gets the bytes of `in`
 * at even offsets, t[half..n) those at odd offsets, and every byte after the first becomes its
 * difference to the byte before it in t, plus 128 (mod 256). For HALF channels the low bytes
 * (mantissa noise) and the high bytes (sign, exponent: mostly constant) land in different
 * halves, which exrio_zip_compress deflates as separate blocks. */
static void exrio_zip_predict(const unsigned char *in, size_t n, unsigned char *t)
{
    if (n == 0) return;
    size_t half = (n + 1) / 2, pairs = n / 2, i = 0;
    unsigned char *lo = t, *hi = t + half;
    unsigned plo = 128u, phi = in[2 * (half - 1)];  /* t[0] stays as it is */
#if defined(__SSE2__)
    const __m128i even = _mm_set1_epi16(0x00ff), bias = _mm_set1_epi8((char)0x80);
    __m128i last_lo = _mm_set1_epi8((char)plo), last_hi = _mm_set1_epi8((char)phi);
    for (; i + 16 <= pairs; i += 16) {
        __m128i a = _mm_loadu_si128((const __m128i *)(const void *)(in + 2 * i));
        __m128i b = _mm_loadu_si128((const __m128i *)(const void *)(in + 2 * i + 16));
        __m128i l = _mm_packus_epi16(_mm_and_si128(a, even), _mm_and_si128(b, even));
        __m128i h = _mm_packus_epi16(_mm_srli_epi16(a, 8), _mm_srli_epi16(b, 8));
        /* each byte's predecessor: this vector moved up one byte, last vector's top byte in */
        __m128i pl = _mm_or_si128(_mm_slli_si128(l, 1), _mm_srli_si128(last_lo, 15));
        __m128i ph = _mm_or_si128(_mm_slli_si128(h, 1), _mm_srli_si128(last_hi, 15));
        _mm_storeu_si128((__m128i *)(void *)(lo + i), _mm_add_epi8(_mm_sub_epi8(l, pl), bias));
        _mm_storeu_si128((__m128i *)(void *)(hi + i), _mm_add_epi8(_mm_sub_epi8(h, ph), bias));
        last_lo = l;
        last_hi = h;
    }
    if (i) {
        plo = in[2 * i - 2];
        phi = in[2 * i - 1];
    }
#endif
    for (; i < pairs; i++) {
        unsigned l = in[2 * i], h = in[2 * i + 1];
        lo[i] = (unsigned char)(l - plo + 128u);
        hi[i] = (unsigned char)(h - phi + 128u);
        plo = l;
        phi = h;
    }
    if (n & 1) lo[half - 1] = (unsigned char)(in[n - 1] - plo + 128u);
}

/* The encode pipeline's buffers come from these, so exrio_zip_compress may replace the
 * compressed buffer with malloc and know the pipeline frees it with free (the context's
 * default allocator is a process-wide setting we must not rely on). */
static void *exrio_pipeline_alloc(exr_transcoding_pipeline_buffer_id_t id, size_t size)
{
    (void)id;
    return malloc(size);
}
static void exrio_pipeline_free(exr_transcoding_pipeline_buffer_id_t id, void *p)
{
    (void)id;
    free(p);
}

/* ZIP and ZIPS chunks: the format's transform (exrio_zip_predict), then deflate by
 * deflate.c instead of the library's zlib; either way a standard zlib stream that every reader
 * inflates. Which compressor (measured in docs/benchmarks.md):
 * - A chunk of HALF channels only goes to our run-length encoder (deflate_new_rle), with a
 *   block boundary between the low-byte and high-byte halves: on noisy renders 3x faster than
 *   libdeflate's level 1 and 2-10% smaller.
 * - If that output is under 1/EXRIO_ZIP_RETRY of the chunk, the chunk is smooth (few noise
 *   bits), where string matching finds what runs do not (a noise-free gradient: 2.2x smaller
 *   with level 1); level 1 is then tried too and the smaller stream kept. Noisy chunks
 *   (renders at any spp we measured: 26-46%) never pay for the second try. Once level 1 has
 *   won, the next chunks try level 1 first and keep it while it stays under that ratio
 *   (smooth images are usually smooth throughout), so they pay for one encoder, not two.
 * - A chunk with a FLOAT channel goes to level 1: there the run-length encoder's output is
 *   ~15% larger, because the four bytes of a float interleave in each half.
 * A chunk that does not shrink is stored raw, as the format requires. That rule also avoids a
 * bug of libOpenEXRCore 3.1.5's own ZIP encoder (upstream openexr issue 2306): it stored zlib
 * bytes exactly as long as the raw chunk, which every reader then decodes as raw
 * (tests/unit/test_exrio.c: test_zip_output_equal_to_raw_size). */
#define EXRIO_ZIP_RETRY 5

/* The hook's compressor of that kind, made on first use; NULL when out of memory. */
static struct deflate *exrio_deflater(struct exrio_hooks *hooks, bool rle)
{
    struct deflate **slot = rle ? &hooks->rle : &hooks->level1;
    if (!*slot) *slot = rle ? deflate_new_rle(NULL) : deflate_new(1, NULL);
    return *slot;
}

/* Makes *buf hold at least `need` bytes (contents not kept). */
static bool exrio_reserve(unsigned char **buf, size_t *size, size_t need)
{
    if (*size >= need) return true;
    free(*buf);
    *buf = malloc(need);
    *size = *buf ? need : 0;
    return *buf != NULL;
}

/* Level 1 of the predicted chunk (hooks->scratch, n bytes) into hooks->alt; *size gets the
 * stream size (0: did not fit). False when out of memory. */
static bool exrio_level1_alt(struct exrio_hooks *hooks, size_t n, size_t *size)
{
    struct deflate *l1 = exrio_deflater(hooks, false);
    if (!l1 || !exrio_reserve(&hooks->alt, &hooks->alt_size, deflate_zlib_bound(l1, n)))
        return false;
    *size = deflate_zlib(l1, hooks->scratch, n, hooks->alt, hooks->alt_size);
    return true;
}

static exr_result_t exrio_zip_compress(exr_encode_pipeline_t *enc)
{
    struct exrio_hooks *hooks = enc->encoding_user_data;
    size_t n = enc->packed_bytes;
    const unsigned char *in = enc->packed_buffer;
    bool all_half = true;
    for (int c = 0; c < enc->channel_count; c++)
        all_half &= enc->channels[c].data_type == EXR_PIXEL_HALF;
    struct deflate *d = exrio_deflater(hooks, all_half);
    if (!d) return EXR_ERR_OUT_OF_MEMORY;
    size_t bound = deflate_zlib_bound(d, n);
    size_t need = bound > n ? bound : n;
    if (enc->compressed_alloc_size < need) {
        /* A buffer of size 0 may alias packed_buffer: never ours to free. */
        if (enc->compressed_alloc_size > 0) free(enc->compressed_buffer);
        enc->compressed_buffer = malloc(need);
        enc->compressed_alloc_size = enc->compressed_buffer ? need : 0;
        if (!enc->compressed_buffer) return EXR_ERR_OUT_OF_MEMORY;
    }
    if (!exrio_reserve(&hooks->scratch, &hooks->scratch_size, n)) return EXR_ERR_OUT_OF_MEMORY;
    exrio_zip_predict(in, n, hooks->scratch);
    size_t got = 0, alt = 0;  /* alt: level 1's size in hooks->alt once tried */
    bool tried = false;
    if (all_half && hooks->smooth) {
        if (!exrio_level1_alt(hooks, n, &alt)) return EXR_ERR_OUT_OF_MEMORY;
        tried = true;
        if (alt > 0 && alt < n / EXRIO_ZIP_RETRY) {
            memcpy(enc->compressed_buffer, hooks->alt, alt);
            got = alt;
        } else {
            hooks->smooth = false;
        }
    }
    if (got == 0) {
        size_t cut = (n + 1) / 2;
        got = deflate_zlib_blocks(d, hooks->scratch, n, &cut, 1, enc->compressed_buffer,
                                  enc->compressed_alloc_size);
        if (all_half && got > 0 && got < n / EXRIO_ZIP_RETRY) {
            if (!tried && !exrio_level1_alt(hooks, n, &alt)) return EXR_ERR_OUT_OF_MEMORY;
            if (alt > 0 && alt < got) {
                memcpy(enc->compressed_buffer, hooks->alt, alt);
                got = alt;
                hooks->smooth = true;
            }
        }
    }
    if (got == 0 || got >= n) {
        memcpy(enc->compressed_buffer, in, n);
        got = n;
    }
    enc->compressed_bytes = got;
    return EXR_ERR_SUCCESS;
}

/* Defines the part, writes the header and every scanline chunk. The caller finishes ctxt. */
static bool exrio_encode(exr_context_t ctxt, const struct image *img,
                         const struct exrio_write_opts *opts, const struct exrio_src *srcs,
                         int nsrc, const char *where, struct err *err)
{
    int part = 0;
    exr_result_t rv = exr_add_part(ctxt, "", EXR_STORAGE_SCANLINE, &part);
    if (rv == EXR_ERR_SUCCESS)
        rv = exr_initialize_required_attr_simple(ctxt, part, (int32_t)img->width,
                                                 (int32_t)img->height,
                                                 exrio_to_lib_compression(opts->compression));
    /* exr_add_channel keeps the list sorted by name, as the file format requires, so the
     * order we add in does not matter; the encoder's channel array follows the sorted list. */
    for (int c = 0; rv == EXR_ERR_SUCCESS && c < nsrc; c++)
        rv = exr_add_channel(ctxt, part, srcs[c].name, srcs[c].type, EXR_PERCEPTUALLY_LOGARITHMIC,
                             1, 1);
    if (rv == EXR_ERR_SUCCESS) rv = exr_write_header(ctxt);
    if (rv != EXR_ERR_SUCCESS) return exrio_lib_fail(err, ERR_INTERNAL, where, rv, "EXR header");

    int32_t lines = 0;
    rv = exr_get_scanlines_per_chunk(ctxt, part, &lines);
    if (rv != EXR_ERR_SUCCESS || lines < 1)
        return exrio_lib_fail(err, ERR_INTERNAL, where, rv, "EXR chunk layout");

    exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
    struct exrio_hooks hooks = {exrio_pick_halves(), NULL, NULL, NULL, 0, NULL, 0, false};
    bool zip = opts->compression == EXRIO_ZIP || opts->compression == EXRIO_ZIPS;
    bool started = false, ok = true;
    for (int32_t y = 0; ok && y < (int32_t)img->height; y += lines) {
        exr_chunk_info_t ci;
        rv = exr_write_scanline_chunk_info(ctxt, part, y, &ci);
        if (rv == EXR_ERR_SUCCESS)
            rv = started ? exr_encoding_update(ctxt, part, &ci, &enc)
                         : exr_encoding_initialize(ctxt, part, &ci, &enc);
        if (rv != EXR_ERR_SUCCESS) {
            ok = exrio_lib_fail(err, ERR_INTERNAL, where, rv, "EXR encode setup");
            break;
        }
        for (int c = 0; ok && c < enc.channel_count; c++) {
            exr_coding_channel_info_t *ch = &enc.channels[c];
            const struct exrio_src *s = NULL;
            for (int k = 0; k < nsrc; k++)
                if (strcmp(srcs[k].name, ch->channel_name) == 0) s = &srcs[k];
            if (!s) {
                ok = err_set(err, ERR_INTERNAL, where, "EXR encoder lists unknown channel '%s'",
                             ch->channel_name);
                break;
            }
            ch->user_data_type = EXR_PIXEL_FLOAT;
            ch->user_bytes_per_element = (int16_t)sizeof(float);
            ch->user_pixel_stride = s->pixel_stride;
            ch->user_line_stride = (int32_t)s->line_stride;
            ch->encode_from_ptr = s->base + (size_t)ci.start_y * s->line_stride;
        }
        if (!ok) break;
        if (!started) {
            rv = exr_encoding_choose_default_routines(ctxt, part, &enc);
            started = true;
            enc.alloc_fn = exrio_pipeline_alloc;
            enc.free_fn = exrio_pipeline_free;
            enc.encoding_user_data = &hooks;
            enc.convert_and_pack_fn = exrio_pack;
            if (zip) enc.compress_fn = exrio_zip_compress;
        }
        if (rv == EXR_ERR_SUCCESS) rv = exr_encoding_run(ctxt, part, &enc);
        if (rv != EXR_ERR_SUCCESS) ok = exrio_lib_fail(err, ERR_INTERNAL, where, rv, "EXR encode");
    }
    if (started) exr_encoding_destroy(ctxt, &enc);
    deflate_free(hooks.rle);
    deflate_free(hooks.level1);
    free(hooks.scratch);
    free(hooks.alt);
    return ok;
}

bool exrio_write_mem(const struct image *img, const struct exrio_write_opts *opts,
                     unsigned char **out, size_t *out_size, struct err *err)
{
    const char *where = EXRIO_MEM_NAME;
    if (!out || !out_size) return err_set(err, ERR_INVALID, where, "no output buffer pointer");
    *out = NULL;
    *out_size = 0;
    struct exrio_src srcs[EXRIO_MAX_WRITE_CHANNELS];
    int nsrc = 0;
    if (!exrio_plan(img, opts, srcs, &nsrc, where, err)) return false;

    exrio_lib_reset();
    struct exrio_sink sink = {0};
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = exrio_lib_error;
    init.user_data = &sink;
    init.write_fn = exrio_sink_write;
    exr_context_t ctxt = NULL;
    exr_result_t rv = exr_start_write(&ctxt, where, EXR_WRITE_FILE_DIRECTLY, &init);
    if (rv != EXR_ERR_SUCCESS) {
        exr_finish(&ctxt);
        free(sink.buf);
        return exrio_lib_fail(err, ERR_INTERNAL, where, rv, "EXR writer");
    }
    bool ok = exrio_encode(ctxt, img, opts, srcs, nsrc, where, err);
    /* exr_finish writes the chunk offset table, so its result matters on success. */
    rv = exr_finish(&ctxt);
    if (ok && rv != EXR_ERR_SUCCESS) ok = exrio_lib_fail(err, ERR_INTERNAL, where, rv, "EXR finish");
    if (ok && sink.nomem) ok = err_set(err, ERR_NOMEM, where, "out of memory for the EXR buffer");
    if (!ok) {
        if (sink.nomem && err) err->code = ERR_NOMEM;
        free(sink.buf);
        return false;
    }
    *out = sink.buf;
    *out_size = sink.size;
    return true;
}

bool exrio_write_file(const char *path, const struct image *img,
                      const struct exrio_write_opts *opts, struct err *err)
{
    if (!path || !path[0]) return err_set(err, ERR_INVALID, NULL, "no output path");
    unsigned char *buf = NULL;
    size_t size = 0;
    if (!exrio_write_mem(img, opts, &buf, &size, err)) {
        if (err) snprintf(err->where, sizeof err->where, "%s", path);
        return false;
    }
    /* Written beside the target and renamed over it: readers see the old file or the whole
     * new one, never a partial frame, and a failed write leaves the old file in place. */
    static unsigned exrio_tmp_counter;
    char tmp[4096];
    int n = snprintf(tmp, sizeof tmp, "%s.tmp-%ld-%u", path, (long)getpid(),
                     __atomic_fetch_add(&exrio_tmp_counter, 1u, __ATOMIC_RELAXED));
    if (n < 0 || (size_t)n >= sizeof tmp) {
        free(buf);
        return err_set(err, ERR_INVALID, path, "output path is too long");
    }
    int fd = open(tmp, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    if (fd < 0) {
        int e = errno;
        free(buf);
        return err_set(err, e == ENOENT ? ERR_NOT_FOUND : ERR_IO, path, "cannot create: %s", strerror(e));
    }
    size_t done = 0;
    int e = 0;
    while (done < size) {
        ssize_t w = write(fd, buf + done, size - done);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) {
            e = w < 0 ? errno : EIO;
            break;
        }
        done += (size_t)w;
    }
    free(buf);
    if (close(fd) != 0 && !e) e = errno;
    if (!e && rename(tmp, path) != 0) e = errno;
    if (e) {
        unlink(tmp);
        return err_set(err, ERR_IO, path, "write failed: %s", strerror(e));
    }
    return true;
}

/* ---- read side --------------------------------------------------------------------------- */

/* A read-only byte source: memory, or a file read with pread so the library can ask for any
 * offset. A short count at the end is how the library learns the input is truncated. */
struct exrio_source {
    const unsigned char *mem;
    int fd;
    uint64_t size;
    int io_errno;
};

static int64_t exrio_source_read(exr_const_context_t ctxt, void *userdata, void *buffer,
                                 uint64_t sz, uint64_t offset, exr_stream_error_func_ptr_t error_cb)
{
    (void)ctxt;
    (void)error_cb;
    struct exrio_source *src = userdata;
    if (offset >= src->size || sz == 0) return 0;
    uint64_t n = src->size - offset < sz ? src->size - offset : sz;
    if (n > (uint64_t)INT64_MAX || n > SIZE_MAX) return -1;
    if (src->mem) {
        memcpy(buffer, src->mem + offset, (size_t)n);
        return (int64_t)n;
    }
    uint64_t got = 0;
    while (got < n) {
        ssize_t r = pread(src->fd, (unsigned char *)buffer + got, (size_t)(n - got),
                          (off_t)(offset + got));
        if (r < 0) {
            if (errno == EINTR) continue;
            src->io_errno = errno;
            return -1;
        }
        if (r == 0) break;
        got += (uint64_t)r;
    }
    return (int64_t)got;
}

static int64_t exrio_source_size(exr_const_context_t ctxt, void *userdata)
{
    (void)ctxt;
    const struct exrio_source *src = userdata;
    return src->size > (uint64_t)INT64_MAX ? -1 : (int64_t)src->size;
}

/* Error code for a failed read-side library call: truncation and garbage are ERR_PARSE, an
 * operating-system read failure is ERR_IO. */
static bool exrio_read_fail(struct err *err, const struct exrio_source *src, const char *where,
                            exr_result_t rv, const char *what)
{
    if (src->io_errno)
        return err_set(err, ERR_IO, where, "%s: read failed: %s", what, strerror(src->io_errno));
    return exrio_lib_fail(err, ERR_PARSE, where, rv, what);
}

/* Parses the header (only) into *ctxt. The library's own size limits stay above ours so the
 * gate, not the parser, reports ordinary oversize images with a precise message; the parser
 * limits only keep absurd headers from reaching allocation code. */
static bool exrio_open(struct exrio_source *src, const char *where, exr_context_t *ctxt,
                       struct err *err)
{
    static const unsigned char magic[4] = {0x76, 0x2f, 0x31, 0x01};
    unsigned char head[4];
    if (src->size < 8 || exrio_source_read(NULL, src, head, 4, 0, NULL) != 4 ||
        memcmp(head, magic, 4) != 0) {
        if (src->io_errno)
            return err_set(err, ERR_IO, where, "read failed: %s", strerror(src->io_errno));
        return err_set(err, ERR_PARSE, where, "not an OpenEXR file (bad magic number or too short)");
    }
    exrio_lib_reset();
    exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
    init.error_handler_fn = exrio_lib_error;
    init.user_data = src;
    init.read_fn = exrio_source_read;
    init.size_fn = exrio_source_size;
    init.max_image_width = (int)EXRIO_MAX_SIDE * 4;
    init.max_image_height = (int)EXRIO_MAX_SIDE * 4;
    init.max_tile_width = (int)EXRIO_MAX_SIDE;
    init.max_tile_height = (int)EXRIO_MAX_SIDE;
    /* Reconstructing a damaged chunk table is guesswork over untrusted bytes; we would rather
     * report the damage. */
    init.flags = EXR_CONTEXT_FLAG_DISABLE_CHUNK_RECONSTRUCTION;
    *ctxt = NULL;
    exr_result_t rv = exr_start_read(ctxt, where, &init);
    if (rv != EXR_ERR_SUCCESS) {
        exr_finish(ctxt);
        *ctxt = NULL;
        return exrio_read_fail(err, src, where, rv, "bad EXR header");
    }
    return true;
}

/* What the gate found: the data window and which channels carry R, G, B (or Y). */
struct exrio_layout {
    exr_attr_box2i_t window;
    uint32_t width, height;
    bool grey;  /* only Y: replicate it */
};

static bool exrio_gate(exr_context_t ctxt, const char *where, struct exrio_layout *lay,
                       struct err *err)
{
    int parts = 0;
    exr_result_t rv = exr_get_count(ctxt, &parts);
    if (rv != EXR_ERR_SUCCESS) return exrio_lib_fail(err, ERR_PARSE, where, rv, "EXR part count");
    if (parts != 1)
        return err_set(err, ERR_UNSUPPORTED, where, "multi-part EXR (%d parts) is not accepted",
                       parts);
    exr_storage_t storage;
    rv = exr_get_storage(ctxt, 0, &storage);
    if (rv != EXR_ERR_SUCCESS) return exrio_lib_fail(err, ERR_PARSE, where, rv, "EXR storage");
    if (storage != EXR_STORAGE_SCANLINE)
        return err_set(err, ERR_UNSUPPORTED, where, "%s EXR is not accepted (scanline only)",
                       storage == EXR_STORAGE_TILED           ? "tiled"
                       : storage == EXR_STORAGE_DEEP_SCANLINE ? "deep scanline"
                       : storage == EXR_STORAGE_DEEP_TILED    ? "deep tiled"
                                                              : "unknown-storage");

    const exr_attr_chlist_t *chl = NULL;
    rv = exr_get_channels(ctxt, 0, &chl);
    if (rv != EXR_ERR_SUCCESS || !chl) return exrio_lib_fail(err, ERR_PARSE, where, rv, "EXR channels");
    if (chl->num_channels < 1 || chl->num_channels > EXRIO_MAX_READ_CHANNELS)
        return err_set(err, ERR_LIMIT, where, "%d channels (accepted: 1..%d)", chl->num_channels,
                       EXRIO_MAX_READ_CHANNELS);
    bool has_r = false, has_g = false, has_b = false, has_y = false;
    for (int c = 0; c < chl->num_channels; c++) {
        const exr_attr_chlist_entry_t *e = &chl->entries[c];
        const char *nm = e->name.str ? e->name.str : "";
        if (e->pixel_type != EXR_PIXEL_HALF && e->pixel_type != EXR_PIXEL_FLOAT)
            return err_set(err, ERR_UNSUPPORTED, where,
                           "channel '%.64s' has pixel type %s (accepted: HALF, FLOAT)", nm,
                           exrio_pixel_name(e->pixel_type));
        if (e->x_sampling != 1 || e->y_sampling != 1)
            return err_set(err, ERR_UNSUPPORTED, where,
                           "channel '%.64s' is subsampled %dx%d (accepted: 1x1)", nm,
                           e->x_sampling, e->y_sampling);
        has_r |= strcmp(nm, "R") == 0;
        has_g |= strcmp(nm, "G") == 0;
        has_b |= strcmp(nm, "B") == 0;
        has_y |= strcmp(nm, "Y") == 0;
    }

    exr_compression_t comp;
    rv = exr_get_compression(ctxt, 0, &comp);
    if (rv != EXR_ERR_SUCCESS) return exrio_lib_fail(err, ERR_PARSE, where, rv, "EXR compression");
    if (comp != EXR_COMPRESSION_NONE && comp != EXR_COMPRESSION_RLE &&
        comp != EXR_COMPRESSION_ZIPS && comp != EXR_COMPRESSION_ZIP)
        return err_set(err, ERR_UNSUPPORTED, where,
                       "compression %s is not accepted (accepted: NONE, RLE, ZIPS, ZIP)",
                       exrio_lib_compression_name(comp));

    exr_attr_box2i_t dw;
    rv = exr_get_data_window(ctxt, 0, &dw);
    if (rv != EXR_ERR_SUCCESS) return exrio_lib_fail(err, ERR_PARSE, where, rv, "EXR data window");
    int64_t w = (int64_t)dw.max.x - (int64_t)dw.min.x + 1;
    int64_t h = (int64_t)dw.max.y - (int64_t)dw.min.y + 1;
    if (w < 1 || h < 1 || w > EXRIO_MAX_SIDE || h > EXRIO_MAX_SIDE)
        return err_set(err, ERR_LIMIT, where,
                       "data window %lldx%lld outside 1..%u per side", (long long)w,
                       (long long)h, EXRIO_MAX_SIDE);
    if (w * h > (int64_t)EXRIO_MAX_PIXELS)
        return err_set(err, ERR_LIMIT, where, "data window %lldx%lld has more than %u pixels",
                       (long long)w, (long long)h, EXRIO_MAX_PIXELS);

    if (!(has_r && has_g && has_b) && !has_y)
        return err_set(err, ERR_UNSUPPORTED, where, "no R, G, B or Y channels");
    lay->window = dw;
    lay->width = (uint32_t)w;
    lay->height = (uint32_t)h;
    lay->grey = !(has_r && has_g && has_b);
    return true;
}

/* Component of struct vec3 a channel fills (0..2), or -1 when we do not decode it. */
static int exrio_channel_slot(const char *name, bool grey)
{
    if (grey) return strcmp(name, "Y") == 0 ? 0 : -1;
    if (strcmp(name, "R") == 0) return 0;
    if (strcmp(name, "G") == 0) return 1;
    if (strcmp(name, "B") == 0) return 2;
    return -1;
}

/* Exact IEEE half -> float (every half is representable as a float). */
static float exrio_half_to_float(uint16_t h)
{
    uint32_t sign = (uint32_t)(h & 0x8000u) << 16;
    uint32_t exp = (h >> 10) & 0x1fu, man = h & 0x3ffu, bits;
    float f;
    if (exp == 0) {
        f = (float)man * 0x1p-24f;  /* zero or subnormal: man * 2^-24 */
        memcpy(&bits, &f, sizeof bits);
        bits |= sign;
    } else if (exp == 31) {
        bits = sign | 0x7f800000u | (man << 13);  /* Inf, NaN keeps its payload */
    } else {
        bits = sign | ((exp + 112u) << 23) | (man << 13);
    }
    memcpy(&f, &bits, sizeof f);
    return f;
}

static inline void exrio_set(struct vec3 *p, int slot, float v)
{
    if (slot == 0) p->x = v;
    else if (slot == 1) p->y = v;
    else p->z = v;
}

/* Scatters one decompressed chunk (per row: each channel's `width` little-endian values, in
 * channel-list order) into the image rows it covers. The caller has checked the buffer size. */
static void exrio_unpack(const unsigned char *p, const exr_decode_pipeline_t *dec, int32_t rows,
                         uint32_t width, const int *slots, struct vec3 *first_row)
{
    for (int32_t r = 0; r < rows; r++) {
        struct vec3 *row = first_row + (size_t)r * width;
        for (int c = 0; c < dec->channel_count; c++) {
            const exr_coding_channel_info_t *ch = &dec->channels[c];
            size_t bytes = (size_t)width * (size_t)ch->bytes_per_element;
            int slot = slots[c];
            if (slot >= 0) {
                if (ch->data_type == EXR_PIXEL_HALF) {
                    for (uint32_t x = 0; x < width; x++, p += 2)
                        exrio_set(&row[x], slot, exrio_half_to_float((uint16_t)(p[0] | (p[1] << 8))));
                } else {
                    for (uint32_t x = 0; x < width; x++, p += 4) {
                        uint32_t u = (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 |
                                     (uint32_t)p[3] << 24;
                        float f;
                        memcpy(&f, &u, sizeof f);
                        exrio_set(&row[x], slot, f);
                    }
                }
            } else {
                p += bytes;
            }
        }
    }
}

/* Reads and decompresses chunk by chunk with the library, but unpacks with exrio_unpack:
 * libOpenEXRCore 3.1's specialised unpackers can write through the NULL pointer of a skipped
 * channel (its 3-channel interleave test ignores skipped channels), so we never hand the
 * library an output pointer. */
static bool exrio_decode(exr_context_t ctxt, const struct exrio_source *src, const char *where,
                         const struct exrio_layout *lay, struct image *img, struct err *err)
{
    int32_t lines = 0;
    exr_result_t rv = exr_get_scanlines_per_chunk(ctxt, 0, &lines);
    if (rv != EXR_ERR_SUCCESS || lines < 1 || lines > 256)
        return exrio_lib_fail(err, ERR_PARSE, where, rv, "EXR chunk layout");
    exr_compression_t comp = EXR_COMPRESSION_NONE;
    exr_get_compression(ctxt, 0, &comp);
    exr_decode_pipeline_t dec = EXR_DECODE_PIPELINE_INITIALIZER;
    int slots[EXRIO_MAX_READ_CHANNELS];
    uint64_t row_bytes = 0;
    bool started = false, ok = true;
    for (int64_t y = lay->window.min.y; ok && y <= lay->window.max.y; y += lines) {
        exr_chunk_info_t ci;
        rv = exr_read_scanline_chunk_info(ctxt, 0, (int)y, &ci);
        if (rv != EXR_ERR_SUCCESS) {
            ok = exrio_read_fail(err, src, where, rv, "EXR chunk table");
            break;
        }
        /* The chunk must cover rows inside the window, starting where we asked, full width,
         * or the rows we scatter into would leave the image. */
        if (ci.start_y != y || ci.height < 1 || ci.height > lines ||
            (int64_t)ci.start_y + ci.height - 1 > lay->window.max.y ||
            ci.width != (int32_t)lay->width) {
            ok = err_set(err, ERR_PARSE, where, "EXR chunk at row %lld has an inconsistent shape",
                         (long long)y);
            break;
        }
        rv = started ? exr_decoding_update(ctxt, 0, &ci, &dec)
                     : exr_decoding_initialize(ctxt, 0, &ci, &dec);
        if (rv == EXR_ERR_SUCCESS && !started) {
            started = true;
            if (dec.channel_count < 1 || dec.channel_count > EXRIO_MAX_READ_CHANNELS) {
                ok = err_set(err, ERR_PARSE, where, "EXR decoder sees %d channels",
                             dec.channel_count);
                break;
            }
            for (int c = 0; c < dec.channel_count; c++) {
                const exr_coding_channel_info_t *ch = &dec.channels[c];
                slots[c] = exrio_channel_slot(ch->channel_name ? ch->channel_name : "", lay->grey);
                row_bytes += (uint64_t)lay->width * (uint64_t)ch->bytes_per_element;
            }
            /* Read and decompress only: with no unpack step the decoded bytes stay in
             * dec.unpacked_buffer for exrio_unpack. */
            rv = exr_decoding_choose_default_routines(ctxt, 0, &dec);
            dec.unpack_and_convert_fn = NULL;
        }
        /* An uncompressed chunk whose size field disagrees would leave the unpacked buffer
         * unfilled; every codec's output must be exactly rows * row_bytes. */
        uint64_t want = (uint64_t)ci.height * row_bytes;
        if (rv == EXR_ERR_SUCCESS &&
            (ci.unpacked_size != want ||
             (comp == EXR_COMPRESSION_NONE && ci.packed_size != ci.unpacked_size))) {
            ok = err_set(err, ERR_PARSE, where, "EXR chunk at row %lld has a bad size",
                         (long long)y);
            break;
        }
        if (rv == EXR_ERR_SUCCESS) rv = exr_decoding_run(ctxt, 0, &dec);
        if (rv != EXR_ERR_SUCCESS) {
            ok = exrio_read_fail(err, src, where, rv, "EXR pixel data");
            break;
        }
        if (!dec.unpacked_buffer) {
            ok = err_set(err, ERR_PARSE, where, "EXR chunk at row %lld decoded to nothing",
                         (long long)y);
            break;
        }
        exrio_unpack(dec.unpacked_buffer, &dec, ci.height, lay->width, slots,
                     img->pixels + (size_t)(ci.start_y - lay->window.min.y) * lay->width);
    }
    if (started) exr_decoding_destroy(ctxt, &dec);
    if (ok && lay->grey) {
        size_t n = (size_t)img->width * img->height;
        for (size_t i = 0; i < n; i++) img->pixels[i].y = img->pixels[i].z = img->pixels[i].x;
    }
    return ok;
}

static bool exrio_read_source(struct exrio_source *src, const char *where, struct image *out,
                              struct err *err)
{
    exr_context_t ctxt = NULL;
    if (!exrio_open(src, where, &ctxt, err)) return false;
    struct exrio_layout lay = {0};
    bool ok = exrio_gate(ctxt, where, &lay, err);
    if (ok) {
        ok = image_init(out, lay.width, lay.height, err);
        if (!ok && err) snprintf(err->where, sizeof err->where, "%s", where);
    }
    if (ok) {
        ok = exrio_decode(ctxt, src, where, &lay, out, err);
        if (!ok) image_destroy(out);
    }
    exr_finish(&ctxt);
    return ok;
}

/* Opens a regular file for exrio_source; directories and devices are refused up front. */
static bool exrio_source_open_file(const char *path, struct exrio_source *src, struct err *err)
{
    memset(src, 0, sizeof *src);
    src->fd = open(path, O_RDONLY | O_CLOEXEC);
    if (src->fd < 0) {
        int e = errno;
        return err_set(err, e == ENOENT ? ERR_NOT_FOUND : ERR_IO, path, "cannot open: %s",
                       strerror(e));
    }
    struct stat st;
    if (fstat(src->fd, &st) != 0 || !S_ISREG(st.st_mode)) {
        close(src->fd);
        src->fd = -1;
        return err_set(err, ERR_IO, path, "not a regular file");
    }
    src->size = (uint64_t)st.st_size;
    return true;
}

bool exrio_read_file(const char *path, struct image *out, struct err *err)
{
    if (!out) return err_set(err, ERR_INVALID, path, "no output image");
    out->width = out->height = 0;
    out->pixels = NULL;
    if (!path || !path[0]) return err_set(err, ERR_INVALID, NULL, "no input path");
    struct exrio_source src;
    if (!exrio_source_open_file(path, &src, err)) return false;
    bool ok = exrio_read_source(&src, path, out, err);
    close(src.fd);
    return ok;
}

bool exrio_read_mem(const void *data, size_t size, const char *name, struct image *out,
                    struct err *err)
{
    const char *where = name ? name : EXRIO_MEM_NAME;
    if (!out) return err_set(err, ERR_INVALID, where, "no output image");
    out->width = out->height = 0;
    out->pixels = NULL;
    if (!data && size) return err_set(err, ERR_INVALID, where, "no input buffer");
    struct exrio_source src = {.mem = data, .fd = -1, .size = size};
    if (!data) src.size = 0;
    return exrio_read_source(&src, where, out, err);
}

/* ---- probe ------------------------------------------------------------------------------- */

static bool exrio_probe_source(struct exrio_source *src, const char *where,
                               struct exrio_info *info, struct err *err)
{
    memset(info, 0, sizeof *info);
    exr_context_t ctxt = NULL;
    if (!exrio_open(src, where, &ctxt, err)) return false;
    bool ok = true;
    exr_result_t rv = exr_get_count(ctxt, &info->parts);
    exr_storage_t storage = EXR_STORAGE_SCANLINE;
    if (rv == EXR_ERR_SUCCESS) rv = exr_get_storage(ctxt, 0, &storage);
    exr_compression_t comp = EXR_COMPRESSION_NONE;
    if (rv == EXR_ERR_SUCCESS) rv = exr_get_compression(ctxt, 0, &comp);
    exr_attr_box2i_t dw;
    memset(&dw, 0, sizeof dw);
    if (rv == EXR_ERR_SUCCESS) rv = exr_get_data_window(ctxt, 0, &dw);
    const exr_attr_chlist_t *chl = NULL;
    if (rv == EXR_ERR_SUCCESS) rv = exr_get_channels(ctxt, 0, &chl);
    if (rv != EXR_ERR_SUCCESS || !chl) {
        ok = exrio_lib_fail(err, ERR_PARSE, where, rv, "EXR header");
    } else {
        info->tiled = storage == EXR_STORAGE_TILED || storage == EXR_STORAGE_DEEP_TILED;
        info->deep = storage == EXR_STORAGE_DEEP_SCANLINE || storage == EXR_STORAGE_DEEP_TILED;
        info->width = (int64_t)dw.max.x - dw.min.x + 1;
        info->height = (int64_t)dw.max.y - dw.min.y + 1;
        info->compression = exrio_from_lib_compression(comp);
        info->compression_name = exrio_lib_compression_name(comp);
        info->channel_count = chl->num_channels;
        for (int c = 0; c < chl->num_channels && c < EXRIO_PROBE_MAX_CHANNELS; c++) {
            const exr_attr_chlist_entry_t *e = &chl->entries[c];
            struct exrio_channel *d = &info->channels[c];
            snprintf(d->name, sizeof d->name, "%s", e->name.str ? e->name.str : "");
            d->pixel = e->pixel_type == EXR_PIXEL_HALF    ? EXRIO_HALF
                       : e->pixel_type == EXR_PIXEL_FLOAT ? EXRIO_FLOAT
                                                          : EXRIO_UINT;
            d->x_sampling = e->x_sampling;
            d->y_sampling = e->y_sampling;
        }
    }
    exr_finish(&ctxt);
    return ok;
}

bool exrio_probe_file(const char *path, struct exrio_info *info, struct err *err)
{
    if (!info) return err_set(err, ERR_INVALID, path, "no output info");
    if (!path || !path[0]) return err_set(err, ERR_INVALID, NULL, "no input path");
    struct exrio_source src;
    if (!exrio_source_open_file(path, &src, err)) return false;
    bool ok = exrio_probe_source(&src, path, info, err);
    close(src.fd);
    return ok;
}

bool exrio_probe_mem(const void *data, size_t size, const char *name, struct exrio_info *info,
                     struct err *err)
{
    const char *where = name ? name : EXRIO_MEM_NAME;
    if (!info) return err_set(err, ERR_INVALID, where, "no output info");
    if (!data && size) return err_set(err, ERR_INVALID, where, "no input buffer");
    struct exrio_source src = {.mem = data, .fd = -1, .size = data ? size : 0};
    return exrio_probe_source(&src, where, info, err);
}
