/* deflate.h — zlib-format (RFC 1950/1951) compression and decompression and CRC-32, for the
 * EXR ZIP codecs (exrio.c) and PNG (tonemap.c). deflate.c is the only includer of libdeflate,
 * so a change of compression library touches one file.
 * Thread-safety: a `struct deflate` is used by one thread at a time (keep one per thread);
 * every other function here is safe to call from any thread. */
#ifndef RESTIRD_DEFLATE_H
#define RESTIRD_DEFLATE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "core/err.h"

struct deflate;

/* A compressor at zlib level `level` (1..12; libdeflate's scale, where 1..9 are comparable to
 * zlib's and 10..12 trade much more time for slightly smaller output). NULL on ERR_INVALID
 * (level out of range) or ERR_NOMEM. Free with deflate_free (NULL is accepted). */
struct deflate *deflate_new(int level, struct err *err);
/* A run-length compressor: Huffman coding of the bytes plus back-references at distance 1 for
 * runs of one repeated byte, and no other string matching (zlib's Z_RLE strategy; our own
 * encoder, not libdeflate's). Several times faster than level 1. On data that has been through
 * a byte-wise predictor (EXR ZIP chunks, filtered PNG rows) its output is about as small as
 * level 1's, on text much larger. Every zlib decoder reads its streams. NULL on ERR_NOMEM. */
struct deflate *deflate_new_rle(struct err *err);
void deflate_free(struct deflate *d);
/* Upper bound of the zlib stream size for `n` input bytes: an output buffer of this size
 * always suffices for deflate_zlib and deflate_zlib_blocks. */
size_t deflate_zlib_bound(struct deflate *d, size_t n);
/* Compresses `n` bytes into out (capacity `cap`); returns the stream size, 0 if it did not
 * fit (out's contents are then unspecified; the run-length compressor also returns 0 for
 * n >= 4 GiB). Deterministic: the same level (or kind) and input give the same bytes. The
 * run-length compressor starts new Huffman codes every 128 KiB. */
size_t deflate_zlib(struct deflate *d, const void *in, size_t n, void *out, size_t cap);
/* deflate_zlib where the caller knows where the statistics of the input change: the
 * run-length compressor starts a new deflate block (new Huffman codes) at each offset in
 * cuts[0..ncuts) (ascending, each inside (0, n); a cut closer than 1 KiB to the previous block
 * start is ignored). A level compressor chooses its own blocks and ignores the cuts. */
size_t deflate_zlib_blocks(struct deflate *d, const void *in, size_t n, const size_t *cuts,
                           int ncuts, void *out, size_t cap);
/* Inflates the zlib stream of exactly `n` bytes into out (capacity `cap`); *out_n (may be
 * NULL) receives the decompressed size. Errors: ERR_PARSE (corrupt stream, bad Adler-32, or
 * bytes left after the stream's end), ERR_LIMIT (the data needs more than `cap` bytes),
 * ERR_NOMEM. Allocates and frees its decompressor per call: meant for tests and cold paths. */
bool deflate_zlib_decompress(const void *in, size_t n, void *out, size_t cap, size_t *out_n,
                             struct err *err);
/* CRC-32 (ISO 3309 / ITU-T V.42, as PNG and gzip use) continuing from `crc` (start with 0). */
uint32_t deflate_crc32(uint32_t crc, const void *data, size_t n);

#endif
