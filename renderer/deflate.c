/* deflate.c — zlib streams and CRC-32 on libdeflate (see deflate.h for contracts).
 * The only file that includes libdeflate.h: callers see an opaque `struct deflate`, so the
 * library could be swapped for zlib or miniz here alone. Must not print or exit; every failure
 * is returned as a value.
 * Refs: RFC 1950 (zlib format), RFC 1951 (DEFLATE); libdeflate.h of libdeflate 1.14. */
#include "deflate.h"

#include <libdeflate.h>
#include <stdlib.h>

/* A wrapper rather than a cast of libdeflate's pointer, so the type stays ours and can gain
 * fields (statistics, a second codec) without touching callers. */
struct deflate {
    struct libdeflate_compressor *c;
};

struct deflate *deflate_new(int level, struct err *err)
{
    if (level < 1 || level > 12) {
        err_set(err, ERR_INVALID, NULL, "deflate level %d outside 1..12", level);
        return NULL;
    }
    struct deflate *d = malloc(sizeof *d);
    if (d) d->c = libdeflate_alloc_compressor(level);
    if (!d || !d->c) {
        free(d);
        err_set(err, ERR_NOMEM, NULL, "out of memory for a level-%d compressor", level);
        return NULL;
    }
    return d;
}

void deflate_free(struct deflate *d)
{
    if (!d) return;
    libdeflate_free_compressor(d->c);
    free(d);
}

size_t deflate_zlib_bound(struct deflate *d, size_t n)
{
    return libdeflate_zlib_compress_bound(d->c, n);
}

size_t deflate_zlib(struct deflate *d, const void *in, size_t n, void *out, size_t cap)
{
    return libdeflate_zlib_compress(d->c, in, n, out, cap);
}

bool deflate_zlib_decompress(const void *in, size_t n, void *out, size_t cap, size_t *out_n,
                             struct err *err)
{
    if (out_n) *out_n = 0;
    if (!in && n) return err_set(err, ERR_INVALID, NULL, "no input buffer");
    struct libdeflate_decompressor *dec = libdeflate_alloc_decompressor();
    if (!dec) return err_set(err, ERR_NOMEM, NULL, "out of memory for a decompressor");
    size_t used_in = 0, got = 0;
    enum libdeflate_result r = libdeflate_zlib_decompress_ex(dec, in, n, out, cap, &used_in, &got);
    libdeflate_free_decompressor(dec);
    switch (r) {
    case LIBDEFLATE_SUCCESS: break;
    case LIBDEFLATE_INSUFFICIENT_SPACE:
        return err_set(err, ERR_LIMIT, NULL, "zlib stream inflates to more than %zu bytes", cap);
    default:
        return err_set(err, ERR_PARSE, NULL, "corrupt zlib stream (%zu bytes)", n);
    }
    /* libdeflate stops at the stream's end; anything after it means the caller framed the
     * data wrongly (e.g. a PNG with garbage after the last IDAT's stream). */
    if (used_in != n)
        return err_set(err, ERR_PARSE, NULL, "%zu bytes after the end of the zlib stream", n - used_in);
    if (out_n) *out_n = got;
    return true;
}

uint32_t deflate_crc32(uint32_t crc, const void *data, size_t n)
{
    return libdeflate_crc32(crc, data, n);
}
