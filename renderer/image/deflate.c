/* deflate.c — zlib streams and CRC-32 on libdeflate, plus our own run-length deflate encoder
 * (see deflate.h for contracts).
 * The only file that includes libdeflate.h: callers see an opaque `struct deflate`, so the
 * library could be swapped for zlib or miniz here alone. Must not print or exit; every failure
 * is returned as a value.
 * The run-length encoder writes, per block, dynamic Huffman codes (RFC 1951 3.2.7) for the
 * literals, the end-of-block code and the length codes, and one distance code (distance 1).
 * Per block it makes two passes over the input: a histogram plus a scan for runs, then the
 * bit output. A block whose coded size would exceed the raw bytes is written stored.
 * Refs: RFC 1950 (zlib format), RFC 1951 (DEFLATE); libdeflate.h of libdeflate 1.14. */
#include "image/deflate.h"

#include <libdeflate.h>
#include <stdlib.h>
#include <string.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

/* A wrapper rather than a cast of libdeflate's pointer, so the type stays ours and can gain
 * fields (statistics, a second codec) without touching callers. */
struct deflate {
    struct libdeflate_compressor *c;  /* NULL: the run-length encoder (which needs no state) */
};

struct deflate *deflate_new(int level, struct err *err)
{
    if (level < 1 || level > 12) {
        err_set(err, ERR_INVALID, NULL, "deflate level %d outside 1..12", level);
        return NULL;
    }
    struct deflate *d = calloc(1, sizeof *d);
    if (d) d->c = libdeflate_alloc_compressor(level);
    if (!d || !d->c) {
        free(d);
        err_set(err, ERR_NOMEM, NULL, "out of memory for a level-%d compressor", level);
        return NULL;
    }
    return d;
}

struct deflate *deflate_new_rle(struct err *err)
{
    struct deflate *d = calloc(1, sizeof *d);
    if (!d) err_set(err, ERR_NOMEM, NULL, "out of memory for a run-length compressor");
    return d;
}

void deflate_free(struct deflate *d)
{
    if (!d) return;
    if (d->c) libdeflate_free_compressor(d->c);
    free(d);
}

/* ---- run-length encoder ------------------------------------------------------------------ */

/* Shorter runs stay literals: a length code costs about as much as several literals of the
 * commonest byte. Measured on EXR ZIP chunks (bench image, Cornell box renders): 4 gives ~1%
 * larger files than 8; 8, 12 and 16 are within 0.3% of each other. */
#ifndef RLE_MIN_RUN
#define RLE_MIN_RUN 8
#endif
/* Blocks shorter than this are merged with the next: a block header costs ~60..100 bytes. */
#define RLE_MIN_BLOCK 1024
/* Without cuts, a new block (fresh Huffman codes) every this many input bytes. */
#define RLE_AUTO_BLOCK (128u * 1024u)
/* Literal/length code lengths are limited to 14 bits (deflate allows 15) so that four codes
 * always fit in the 64-bit bit buffer between flushes; the cost in size is negligible. */
#define RLE_LITLEN_MAX_BITS 14
#define RLE_CL_MAX_BITS 7  /* code-length code limit (RFC 1951) */
#define RLE_STORED_MAX 65535u
#define RLE_KEEP_RUNS 512  /* runs remembered between a block's two passes */

/* Length symbols 257..285: base length and extra bits (RFC 1951 3.2.5). */
static const uint16_t rle_len_base[29] = {3,  4,  5,  6,  7,  8,  9,  10, 11,  13,
                                          15, 17, 19, 23, 27, 31, 35, 43, 51,  59,
                                          67, 83, 99, 115, 131, 163, 195, 227, 258};
static const uint8_t rle_len_extra[29] = {0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2,
                                          2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0};
static const uint8_t rle_cl_order[19] = {16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15};

/* Index (0..28) of the length symbol for a match of `len` (3..258) bytes. */
static int rle_len_index(unsigned len)
{
    int k = 28;
    while (rle_len_base[k] > len) k--;
    return k;
}

/* Next piece of a run's match part: `rem` (>= 3) bytes are left; every piece is 3..258 and
 * none leaves 1 or 2 bytes behind, so a run is all matches after its first literal. */
static unsigned rle_piece(unsigned rem)
{
    if (rem <= 258) return rem;
    return rem - 258 < 3 ? rem - 3 : 258;
}

/* Sorts keys ascending: Shell sort with Ciura's gaps, inline (qsort's callback costs more
 * than the whole construction for the <= 288 keys of a block). */
static void rle_sort(uint64_t *key, int m)
{
    static const int gaps[] = {132, 57, 23, 10, 4, 1};
    for (int g = 0; g < 6; g++) {
        int gap = gaps[g];
        for (int i = gap; i < m; i++) {
            uint64_t k = key[i];
            int j = i;
            for (; j >= gap && key[j - gap] > k; j -= gap) key[j] = key[j - gap];
            key[j] = k;
        }
    }
}

/* Code lengths (at most maxbits) of a Huffman code for freq[0..n): unused symbols get 0. With
 * fewer than two used symbols, symbols 0 and 1 are added, so the code is always complete,
 * which every inflater accepts. */
static void rle_huff_lengths(const uint32_t *freq, int n, int maxbits, uint8_t *len)
{
    uint64_t key[288];       /* freq << 16 | symbol, ascending */
    uint32_t weight[2 * 288];
    uint16_t parent[2 * 288];
    int m = 0;
    for (int s = 0; s < n; s++) {
        len[s] = 0;
        if (freq[s]) key[m++] = (uint64_t)freq[s] << 16 | (uint64_t)s;
    }
    for (int s = 0; m < 2 && s < 2; s++)
        if (!freq[s]) key[m++] = (uint64_t)1 << 16 | (uint64_t)s;  /* pretend it occurs */
    if (m < 2) return;  /* unreachable: n >= 2 */
    rle_sort(key, m);
    /* Two-queue Huffman construction: leaves 0..m-1 in ascending weight, internal nodes m..
     * created in ascending weight too, so the two lightest are always at a queue's head. */
    for (int i = 0; i < m; i++) weight[i] = (uint32_t)(key[i] >> 16);
    int leaf = 0, inner = m, made = m;
    for (int k = 0; k < m - 1; k++) {
        int pick[2];
        for (int t = 0; t < 2; t++) {
            if (leaf < m && (inner >= made || weight[leaf] <= weight[inner])) pick[t] = leaf++;
            else pick[t] = inner++;
        }
        uint64_t w = (uint64_t)weight[pick[0]] + weight[pick[1]];
        weight[made] = w > UINT32_MAX ? UINT32_MAX : (uint32_t)w;
        parent[pick[0]] = parent[pick[1]] = (uint16_t)made;
        made++;
    }
    /* Depths: the root (made - 1) is 0; parents are created after their children. */
    uint8_t depth[2 * 288];
    depth[made - 1] = 0;
    for (int i = made - 2; i >= 0; i--) {
        int dd = depth[parent[i]] + 1;
        depth[i] = (uint8_t)(dd > 255 ? 255 : dd);
    }
    /* Limit to maxbits: count codes per length (clamping), then repair the Kraft sum by moving
     * codes one level deeper until it is exactly 1, and hand the lengths out again, longest
     * to the rarest symbols. */
    unsigned count[RLE_LITLEN_MAX_BITS + 2] = {0};
    for (int i = 0; i < m; i++) count[depth[i] > maxbits ? maxbits : depth[i]]++;
    uint64_t kraft = 0;
    for (int l = 1; l <= maxbits; l++) kraft += (uint64_t)count[l] << (maxbits - l);
    while (kraft > (uint64_t)1 << maxbits) {
        count[maxbits]--;
        for (int l = maxbits - 1; l > 0; l--)
            if (count[l]) {
                count[l]--;
                count[l + 1] += 2;
                break;
            }
        kraft--;
    }
    int i = 0;
    for (int l = maxbits; l > 0; l--)
        for (unsigned c = 0; c < count[l]; c++) len[key[i++] & 0xffff] = (uint8_t)l;
}

/* Canonical codes (RFC 1951 3.2.2), bit-reversed for LSB-first output, packed as
 * code | length << 16. */
static void rle_codes(const uint8_t *len, int n, uint32_t *code)
{
    unsigned count[16] = {0}, next[16];
    for (int s = 0; s < n; s++) count[len[s]]++;
    count[0] = 0;
    unsigned c = 0;
    for (int l = 1; l < 16; l++) {
        c = (c + count[l - 1]) << 1;
        next[l] = c;
    }
    for (int s = 0; s < n; s++) {
        unsigned l = len[s];
        if (!l) {
            code[s] = 0;
            continue;
        }
        unsigned v = next[l]++;  /* reverse the 16-bit value, keep its top l bits */
        v = ((v & 0x5555u) << 1) | ((v >> 1) & 0x5555u);
        v = ((v & 0x3333u) << 2) | ((v >> 2) & 0x3333u);
        v = ((v & 0x0f0fu) << 4) | ((v >> 4) & 0x0f0fu);
        v = ((v & 0x00ffu) << 8) | ((v >> 8) & 0x00ffu);
        code[s] = v >> (16 - l) | l << 16;
    }
}

/* LSB-first bit writer. Invariant between calls: n <= 7 after bw_flush, and callers put at
 * most 56 bits between flushes. The caller checks the capacity for a whole block first, so
 * writes never pass `end`. */
struct bitw {
    uint64_t buf;
    unsigned n;
    unsigned char *p, *end;
};

static inline void bw_put(struct bitw *w, uint64_t v, unsigned nbits)
{
    w->buf |= v << w->n;
    w->n += nbits;
}

static inline void bw_store64(unsigned char *p, uint64_t v)
{
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    memcpy(p, &v, 8);
#else
    for (int i = 0; i < 8; i++) p[i] = (unsigned char)(v >> (8 * i));
#endif
}

static inline void bw_flush(struct bitw *w)
{
    if (w->end - w->p >= 8) {
        bw_store64(w->p, w->buf);
        unsigned bytes = w->n >> 3;
        w->p += bytes;
        w->buf >>= 8 * bytes;
        w->n &= 7;
    } else {
        while (w->n >= 8) {
            *w->p++ = (unsigned char)w->buf;
            w->buf >>= 8;
            w->n -= 8;
        }
    }
}

/* Pads to a byte boundary and writes out every whole byte (n becomes 0). */
static void bw_align(struct bitw *w)
{
    w->n = (w->n + 7) & ~7u;
    bw_flush(w);
}

/* Start of the first run of >= RLE_MIN_RUN equal bytes in s[i..end), or `end` if none. */
static size_t rle_next_run(const unsigned char *s, size_t i, size_t end)
{
    if (end - i < RLE_MIN_RUN) return end;
#if defined(__SSE2__)
    /* 32 neighbour comparisons at a time: bit k of m is s[i+k] == s[i+k+1]; a run of
     * RLE_MIN_RUN starts at i+k when bits k..k+RLE_MIN_RUN-2 are all set. */
    while (end - i >= 33) {
        __m128i a0 = _mm_loadu_si128((const __m128i *)(s + i));
        __m128i b0 = _mm_loadu_si128((const __m128i *)(s + i + 1));
        __m128i a1 = _mm_loadu_si128((const __m128i *)(s + i + 16));
        __m128i b1 = _mm_loadu_si128((const __m128i *)(s + i + 17));
        uint32_t m = (uint32_t)_mm_movemask_epi8(_mm_cmpeq_epi8(a0, b0)) |
                     (uint32_t)_mm_movemask_epi8(_mm_cmpeq_epi8(a1, b1)) << 16;
        uint32_t t = m;  /* bit k: `have` equal neighbour pairs in a row start at k */
        for (unsigned have = 1; have < RLE_MIN_RUN - 1;) {
            unsigned sh = have < RLE_MIN_RUN - 1 - have ? have : RLE_MIN_RUN - 1 - have;
            t &= t >> sh;
            have += sh;
        }
        if (t) return i + (size_t)__builtin_ctz(t);
        i += 32 - (RLE_MIN_RUN - 2);
    }
#endif
    for (; end - i >= RLE_MIN_RUN; i++) {
        int k = 1;
        while (k < RLE_MIN_RUN && s[i + k] == s[i]) k++;
        if (k == RLE_MIN_RUN) return i;
        i += (size_t)k - 1;
    }
    return end;
}

_Static_assert(RLE_MIN_RUN >= 4 && RLE_MIN_RUN <= 26, "rle_next_run scans 32 pairs at a time");

/* End of the run of s[p] starting at p (p < end). */
static size_t rle_run_end(const unsigned char *s, size_t p, size_t end)
{
    unsigned char b = s[p];
    size_t q = p + 1;
#if defined(__SSE2__)
    __m128i v = _mm_set1_epi8((char)b);
    while (end - q >= 16) {
        unsigned m = (unsigned)_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_loadu_si128((const __m128i *)(s + q)), v));
        if (m != 0xffffu) return q + (size_t)__builtin_ctz(~m);
        q += 16;
    }
#endif
    while (q < end && s[q] == b) q++;
    return q;
}

/* Literal codes of s[i..j) into the bit writer, four per flush. */
static void rle_put_literals(struct bitw *w, const uint32_t *code, const unsigned char *s, size_t i,
                             size_t j)
{
    uint64_t buf = w->buf;
    unsigned n = w->n;
    unsigned char *p = w->p, *end = w->end;
    for (; j - i >= 4 && end - p >= 8; i += 4) {
        uint32_t c0 = code[s[i]], c1 = code[s[i + 1]], c2 = code[s[i + 2]], c3 = code[s[i + 3]];
        buf |= (uint64_t)(c0 & 0xffffu) << n;
        n += c0 >> 16;
        buf |= (uint64_t)(c1 & 0xffffu) << n;
        n += c1 >> 16;
        buf |= (uint64_t)(c2 & 0xffffu) << n;
        n += c2 >> 16;
        buf |= (uint64_t)(c3 & 0xffffu) << n;
        n += c3 >> 16;
        bw_store64(p, buf);
        unsigned bytes = n >> 3;
        p += bytes;
        buf >>= 8 * bytes;
        n &= 7;
    }
    w->buf = buf;
    w->n = n;
    w->p = p;
    for (; i < j; i++) {
        bw_put(w, code[s[i]] & 0xffffu, code[s[i]] >> 16);
        bw_flush(w);
    }
}

/* Code-length sequence of a dynamic header, run-length coded with symbols 16/17/18
 * (RFC 1951 3.2.7). Returns the number of items; sym[] and extra[] receive them. */
static int rle_cl_items(const uint8_t *lens, int n, uint8_t *sym, uint8_t *extra)
{
    int k = 0;
    for (int i = 0; i < n;) {
        uint8_t v = lens[i];
        int run = 1;
        while (i + run < n && lens[i + run] == v) run++;
        i += run;
        if (v == 0) {
            while (run >= 11) {
                int t = run > 138 ? 138 : run;
                sym[k] = 18, extra[k++] = (uint8_t)(t - 11);
                run -= t;
            }
            if (run >= 3) {
                sym[k] = 17, extra[k++] = (uint8_t)(run - 3);
                run = 0;
            }
        } else {
            sym[k] = v, extra[k++] = 0;
            run--;
            while (run >= 3) {
                int t = run > 6 ? 6 : run;
                sym[k] = 16, extra[k++] = (uint8_t)(t - 3);
                run -= t;
            }
        }
        while (run-- > 0) sym[k] = v, extra[k++] = 0;
    }
    return k;
}

static const uint8_t rle_cl_extra_bits[19] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
                                              0, 0, 0, 0, 0, 0, 2, 3, 7};

/* Stored blocks for s[a..b); the last one final when `final`. */
static void rle_put_stored(struct bitw *w, const unsigned char *s, size_t a, size_t b, bool final)
{
    do {
        size_t len = b - a > RLE_STORED_MAX ? RLE_STORED_MAX : b - a;
        bool last = a + len == b;
        bw_put(w, (final && last) ? 1u : 0u, 3);  /* BFINAL, BTYPE 00 */
        bw_align(w);
        bw_put(w, (uint64_t)len | (uint64_t)(~len & 0xffffu) << 16, 32);
        bw_flush(w);
        memcpy(w->p, s + a, len);
        w->p += len;
        a += len;
    } while (a < b);
}

static size_t rle_stored_bytes(size_t len)
{
    size_t blocks = len ? (len + RLE_STORED_MAX - 1) / RLE_STORED_MAX : 1;
    return len + 5 * blocks + 1;  /* LEN/NLEN per block, header bits + padding */
}

/* One block of s[a..b) (b > a). False if it would not fit in the writer. */
static bool rle_block(struct bitw *w, const unsigned char *s, size_t a, size_t b,
                      bool final)
{
    /* Pass 1: runs and symbol frequencies. */
    uint32_t freq[288] = {0};
    {
        uint32_t h[4][256];
        memset(h, 0, sizeof h);
        size_t i = a;
        for (; b - i >= 4; i += 4) {
            h[0][s[i]]++;
            h[1][s[i + 1]]++;
            h[2][s[i + 2]]++;
            h[3][s[i + 3]]++;
        }
        for (; i < b; i++) h[0][s[i]]++;
        for (int v = 0; v < 256; v++) freq[v] = h[0][v] + h[1][v] + h[2][v] + h[3][v];
    }
    /* The first RLE_KEEP_RUNS runs are kept for pass 2, which finds any others again
     * (rle_next_run is deterministic). */
    uint32_t kept_p[RLE_KEEP_RUNS], kept_q[RLE_KEEP_RUNS];  /* offsets from a */
    int kept = 0;
    uint64_t matches = 0;
    for (size_t i = a; i < b;) {
        size_t p = rle_next_run(s, i, b);
        if (p == b) break;
        size_t q = rle_run_end(s, p, b);
        if (kept < RLE_KEEP_RUNS) {
            kept_p[kept] = (uint32_t)(p - a);
            kept_q[kept++] = (uint32_t)(q - a);
        }
        freq[s[p]] -= (uint32_t)(q - p - 1);
        for (unsigned rem = (unsigned)(q - p - 1); rem;) {
            unsigned t = rle_piece(rem);
            freq[257 + rle_len_index(t)]++;
            matches++;
            rem -= t;
        }
        i = q;
    }
    freq[256] = 1;

    /* Codes: literal/length from the counts, distance fixed (codes 0 and 1, one bit each:
     * only distance 1 = code 0 is used; the second keeps the code complete). */
    uint8_t lens[286];
    rle_huff_lengths(freq, 286, RLE_LITLEN_MAX_BITS, lens);
    int hlit = 286;
    while (hlit > 257 && lens[hlit - 1] == 0) hlit--;
    uint8_t seq[286 + 2];  /* the lengths the header sends: literal/length, then distance */
    memcpy(seq, lens, (size_t)hlit);
    seq[hlit] = seq[hlit + 1] = 1;
    uint8_t cl_sym[286 + 2], cl_extra[286 + 2];
    int ncl = rle_cl_items(seq, hlit + 2, cl_sym, cl_extra);
    uint32_t cl_freq[19] = {0};
    for (int k = 0; k < ncl; k++) cl_freq[cl_sym[k]]++;
    uint8_t cl_len[19];
    rle_huff_lengths(cl_freq, 19, RLE_CL_MAX_BITS, cl_len);
    int hclen = 19;
    while (hclen > 4 && cl_len[rle_cl_order[hclen - 1]] == 0) hclen--;

    /* Exact size of the dynamic block in bits, against stored. */
    uint64_t bits = 3 + 5 + 5 + 4 + 3 * (uint64_t)hclen;
    for (int k = 0; k < ncl; k++) bits += cl_len[cl_sym[k]] + rle_cl_extra_bits[cl_sym[k]];
    for (int v = 0; v < 286; v++)
        bits += (uint64_t)freq[v] * (lens[v] + (v >= 257 ? rle_len_extra[v - 257] : 0));
    bits += matches;  /* the distance code */
    size_t room = (size_t)(w->end - w->p);
    if (bits / 8 + 2 >= rle_stored_bytes(b - a)) {
        if (rle_stored_bytes(b - a) + 1 > room) return false;
        rle_put_stored(w, s, a, b, final);
        return true;
    }
    if (bits / 8 + 2 > room) return false;

    /* Pass 2: header, then literals and run matches. */
    uint32_t code[286], cl_code[19];
    rle_codes(lens, 286, code);
    rle_codes(cl_len, 19, cl_code);
    bw_put(w, final ? 5u : 4u, 3);  /* BFINAL, BTYPE 10 (dynamic) */
    bw_put(w, (uint64_t)(hlit - 257) | 1u << 5 | (uint64_t)(hclen - 4) << 10, 14);
    bw_flush(w);
    for (int k = 0; k < hclen; k++) {
        bw_put(w, cl_len[rle_cl_order[k]], 3);
        if (k % 8 == 7) bw_flush(w);
    }
    bw_flush(w);
    for (int k = 0; k < ncl; k++) {
        uint32_t c = cl_code[cl_sym[k]];
        bw_put(w, c & 0xffffu, c >> 16);
        bw_put(w, cl_extra[k], rle_cl_extra_bits[cl_sym[k]]);
        bw_flush(w);
    }
    size_t i = a;
    for (int r = 0;; r++) {
        size_t p, q;
        if (r < kept) {
            p = a + kept_p[r];
            q = a + kept_q[r];
        } else {
            if (kept < RLE_KEEP_RUNS || (p = rle_next_run(s, i, b)) == b) break;
            q = rle_run_end(s, p, b);
        }
        rle_put_literals(w, code, s, i, p + 1);  /* up to and including the run's first byte */
        for (unsigned rem = (unsigned)(q - p - 1); rem;) {
            unsigned t = rle_piece(rem);
            int k = rle_len_index(t);
            uint32_t c = code[257 + k];
            bw_put(w, c & 0xffffu, c >> 16);
            bw_put(w, t - rle_len_base[k], rle_len_extra[k]);
            bw_put(w, 0u, 1);  /* distance code 0 (distance 1), one bit */
            bw_flush(w);
            rem -= t;
        }
        i = q;
    }
    rle_put_literals(w, code, s, i, b);
    bw_put(w, code[256] & 0xffffu, code[256] >> 16);
    bw_flush(w);
    return true;
}

static void rle_put_be32(unsigned char *p, uint32_t v)
{
    p[0] = (unsigned char)(v >> 24);
    p[1] = (unsigned char)(v >> 16);
    p[2] = (unsigned char)(v >> 8);
    p[3] = (unsigned char)v;
}

static size_t rle_zlib(const unsigned char *in, size_t n, const size_t *cuts,
                       int ncuts, unsigned char *out, size_t cap)
{
    if (cap < 2 + 2 + 4 || n > UINT32_MAX) return 0;
    out[0] = 0x78;  /* deflate, 32 KiB window */
    out[1] = 0x01;  /* FLEVEL 0 (fastest), no dictionary, FCHECK */
    struct bitw w = {0, 0, out + 2, out + cap - 4};
    if (n == 0) {
        bw_put(&w, 3u, 3);  /* final fixed-Huffman block holding only end-of-block */
        bw_put(&w, 0u, 7);
    } else {
        size_t start = 0;
        int c = 0;
        while (start < n) {
            size_t stop = n;
            if (ncuts > 0) {
                while (c < ncuts && (cuts[c] <= start || cuts[c] - start < RLE_MIN_BLOCK)) c++;
                if (c < ncuts && cuts[c] < n) stop = cuts[c];
            } else if (n - start > RLE_AUTO_BLOCK + RLE_AUTO_BLOCK / 2) {
                stop = start + RLE_AUTO_BLOCK;
            }
            if (n - stop < RLE_MIN_BLOCK) stop = n;
            if (!rle_block(&w, in, start, stop, stop == n)) return 0;
            start = stop;
        }
    }
    bw_align(&w);
    rle_put_be32(w.p, libdeflate_adler32(1, in, n));
    return (size_t)(w.p + 4 - out);
}

/* ---- public ------------------------------------------------------------------------------ */

size_t deflate_zlib_bound(struct deflate *d, size_t n)
{
    if (d->c) return libdeflate_zlib_compress_bound(d->c, n);
    /* Worst case: every block stored; blocks are at least RLE_MIN_BLOCK long except the
     * last, so at most n / RLE_MIN_BLOCK + 1 of them. */
    size_t blocks = n / RLE_MIN_BLOCK + 1;
    return 2 + 4 + n + 5 * (n / RLE_STORED_MAX + 1) + 8 * blocks + 32;
}

size_t deflate_zlib(struct deflate *d, const void *in, size_t n, void *out, size_t cap)
{
    return deflate_zlib_blocks(d, in, n, NULL, 0, out, cap);
}

size_t deflate_zlib_blocks(struct deflate *d, const void *in, size_t n, const size_t *cuts,
                           int ncuts, void *out, size_t cap)
{
    if (d->c) return libdeflate_zlib_compress(d->c, in, n, out, cap);
    return rle_zlib(in, n, cuts, ncuts, out, cap);
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
