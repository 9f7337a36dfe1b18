/* exrio.h — OpenEXR encode (file or memory) and gated decode of `struct image`.
 * Owns every contact with OpenEXR: no other file may include openexr.h, so nothing else needs
 * to know about EXR channel lists, chunks or compression codecs.
 * Must not trust input files: the reader checks the whole header against fixed limits before
 * it decodes a single pixel, and a truncated or corrupt file is an error, never a crash.
 * Refs: OpenEXR file layout and C API (openexr.h, libOpenEXRCore 3.1); docs/architecture.md. */
#ifndef RESTIRD_EXRIO_H
#define RESTIRD_EXRIO_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "core/err.h"
#include "image/image.h"

/* Per-channel storage type. UINT appears only in exrio_probe results: we never write it and
 * the reader rejects it. */
enum exrio_pixel { EXRIO_HALF, EXRIO_FLOAT, EXRIO_UINT };

/* Compression codecs. ZIP = zlib over 16-scanline blocks, ZIPS = zlib per scanline. HALF
 * chunks are deflated by deflate.c's run-length encoder (Huffman codes plus repeats of the
 * previous byte: ~3x faster than zlib level 1 on noisy renders and no larger); smooth chunks
 * and chunks with FLOAT channels use zlib level 1. Any zlib reader decodes both. The reader accepts NONE, RLE, ZIPS and ZIP only; EXRIO_OTHER stands for any
 * codec this enum does not name (PXR24, B44, B44A, DWAA, DWAB, unknown). */
enum exrio_compression { EXRIO_NONE, EXRIO_RLE, EXRIO_ZIPS, EXRIO_ZIP, EXRIO_PIZ, EXRIO_OTHER };

/* Reader limits (the header gate). */
#define EXRIO_MAX_SIDE 16384u                      /* data window width and height */
#define EXRIO_MAX_PIXELS (64u * 1024u * 1024u)     /* width * height */
#define EXRIO_MAX_READ_CHANNELS 8
/* Writer limit on the total channel count (RGB[A] plus every AOV channel). */
#define EXRIO_MAX_WRITE_CHANNELS 64

/* An extra image plane written next to the beauty image, as channels "<name>.<suffix>".
 * channels == 3: suffixes R, G, B (e.g. "albedo.R", "albedo.G", "albedo.B").
 * channels == 1: the suffix is `suffix` ("Z" gives "depth.Z"); NULL means "Y".
 * name and suffix: non-empty, characters from [A-Za-z0-9_-] (no '.', the layer separator),
 * and the whole channel name at most 31 bytes (EXR's short-name limit that every reader takes).
 * data: interleaved floats, width * height * channels, same row order as the image.
 * AOV channels are always stored as FLOAT whatever the beauty pixel type: depth and
 * normals need more than half precision. */
struct exrio_aov {
    const char *name;
    int channels;
    const float *data;
    const char *suffix;
};

struct exrio_write_opts {
    enum exrio_pixel pixel;              /* HALF or FLOAT for R, G, B (and A); HALF turns
                                            |v| > 65504 into +-Inf and keeps NaN */
    enum exrio_compression compression;  /* NONE, RLE, ZIPS, ZIP or PIZ */
    bool alpha;                          /* also write A = 1 */
    const struct exrio_aov *aovs;        /* may be NULL when aov_count == 0 */
    int aov_count;
};

/* Encodes img (single part, scanline, increasing Y, data and display window
 * 0..width-1 x 0..height-1) into a malloc'd buffer; on success *out / *out_size hold it and the
 * caller frees *out. On failure *out is NULL and *out_size 0. Errors: ERR_INVALID (bad
 * options, image or AOV), ERR_LIMIT (too many channels), ERR_NOMEM, ERR_INTERNAL (OpenEXR). */
bool exrio_write_mem(const struct image *img, const struct exrio_write_opts *opts,
                     unsigned char **out, size_t *out_size, struct err *err);

/* Same encoding written to `path` (created or truncated). A failed write removes the partial
 * file. Errors as exrio_write_mem plus ERR_IO naming the path. */
bool exrio_write_file(const char *path, const struct image *img,
                      const struct exrio_write_opts *opts, struct err *err);

/* Decodes a scanline EXR into *out (initialised by this function; the caller calls
 * image_destroy on success, nothing to free on failure). The image is the data window; RGB
 * come from channels R, G, B, or a lone Y is replicated to all three; A and any other channel
 * are ignored. Before any pixel is decoded the header must pass the gate: single part,
 * scanline (not tiled or deep), at most EXRIO_MAX_READ_CHANNELS channels, data window sides in
 * 1..EXRIO_MAX_SIDE and area <= EXRIO_MAX_PIXELS, every channel HALF or FLOAT with 1x1
 * sampling, compression NONE, RLE, ZIPS or ZIP, and R,G,B or Y present.
 * Errors (err->where = the path, or `name` for memory input): ERR_NOT_FOUND / ERR_IO (file),
 * ERR_PARSE (not EXR, corrupt or truncated), ERR_UNSUPPORTED (a valid feature we refuse, the
 * message names it, e.g. "compression PIZ is not accepted"), ERR_LIMIT, ERR_NOMEM. */
bool exrio_read_file(const char *path, struct image *out, struct err *err);
/* name labels the buffer in errors; NULL gives "<memory>". The buffer is only read. */
bool exrio_read_mem(const void *data, size_t size, const char *name, struct image *out,
                    struct err *err);

/* Header facts, read without the gate and without decoding pixels (the header parse itself
 * is still bounded by OpenEXR's checks against the input size). Channel entries beyond
 * EXRIO_PROBE_MAX_CHANNELS are counted in channel_count but not listed. Channels are listed
 * in file order, which OpenEXR keeps sorted by name. */
#define EXRIO_PROBE_MAX_CHANNELS 32
struct exrio_channel {
    char name[256];
    enum exrio_pixel pixel;
    int x_sampling, y_sampling;
};
struct exrio_info {
    int parts;
    bool tiled, deep;                    /* of part 0 */
    int64_t width, height;               /* of part 0's data window */
    enum exrio_compression compression;  /* of part 0 */
    const char *compression_name;        /* static string, e.g. "ZIP", "PIZ", "DWAA" */
    int channel_count;
    struct exrio_channel channels[EXRIO_PROBE_MAX_CHANNELS];
};
bool exrio_probe_file(const char *path, struct exrio_info *info, struct err *err);
bool exrio_probe_mem(const void *data, size_t size, const char *name, struct exrio_info *info,
                     struct err *err);

/* "NONE", "RLE", "ZIPS", "ZIP", "PIZ" or "OTHER". */
const char *exrio_compression_name(enum exrio_compression c);

#endif
