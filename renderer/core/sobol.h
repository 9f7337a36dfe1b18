/* sobol.h — Owen-scrambled Sobol' samples with per-dimension index shuffling, after Burley 2020,
 * "Practical Hash-based Owen Scrambling" (JCGT 9(4)). Header-only and allocation-free: a sample
 * is computed from (pixel seed, sample index, dimension) alone, so any thread can draw any sample.
 *
 * What the pieces are for:
 *  - The Sobol' sequence's first two dimensions form a (0,2)-sequence: every aligned block of 2^k
 *    consecutive indices is a (0,k,2)-net, i.e. each elementary interval of area 2^-k (any
 *    2^-i x 2^-(k-i) box on the dyadic grid) holds exactly one point. Dimension 0 is the index
 *    with its bits reversed (van der Corput); dimension 1 multiplies the index by the Pascal
 *    matrix mod 2 (sobol_dimension1_reversed).
 *  - Owen's nested uniform scrambling flips each bit of a coordinate by a random function of the
 *    bits above it (the path down the binary tree of dyadic intervals). It keeps every net a net
 *    and makes each point uniform on [0,1)^2, so estimates stay unbiased while, for smooth
 *    integrands, their error falls like N^-1.5 up to log factors (Owen 1997) instead of random
 *    sampling's N^-0.5.
 *  - Laine and Karras (2011, "Stratified Sampling for Stochastic Transparency") noted that a hash
 *    made of additions, multiplications and xors with multiples of itself changes each bit only
 *    as a function of the bits below it. Burley applies such a hash between two bit reversals:
 *    each bit then depends on the bits above it, which is Owen's tree in a handful of
 *    instructions instead of a table per level (sobol_owen_reversed).
 *  - Burley's shuffling applies the same nested scramble to the sample index. An aligned block
 *    of 2^k indices maps onto an aligned block of 2^k indices (its order permuted), so each
 *    dimension pair still meets the net property over the first 2^k samples, and dimension pairs
 *    given different shuffles are decorrelated. That is padding: a path draws many independent
 *    2D sets, each stratified, instead of one high-dimensional Sobol' point whose higher
 *    dimensions would need generator tables and stratify worse.
 *  - Seeds come from hashing (pixel seed, dimension): each dimension gets its own shuffle and
 *    scrambles (padding), and each pixel its own randomisation (independent pixels, and
 *    independent images for independent seeds).
 *
 * Numbers: floats in [0, 1) from the top 24 bits, as rng_next_float (never 1.0). */
#ifndef RESTIRD_SOBOL_H
#define RESTIRD_SOBOL_H

#include <stddef.h>
#include <stdint.h>

#include "core/rng.h"

/* Bit reversal by a byte swap and then swaps of nibbles, bit pairs and bits within each byte:
 * sixteen operations against a 32-step loop (x86-64 has no bit-reverse instruction). */
static inline uint32_t sobol_reverse_bits(uint32_t x)
{
    x = __builtin_bswap32(x);
    x = ((x >> 4) & 0x0f0f0f0fu) | ((x & 0x0f0f0f0fu) << 4);
    x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
    return ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
}

/* Reverses 64 bits: the high half becomes the low half reversed and the other way round, so two
 * 32-bit values are reversed for the price of one. */
static inline uint64_t sobol_reverse_bits64(uint64_t x)
{
    x = __builtin_bswap64(x);
    x = ((x >> 4) & 0x0f0f0f0f0f0f0f0full) | ((x & 0x0f0f0f0f0f0f0f0full) << 4);
    x = ((x >> 2) & 0x3333333333333333ull) | ((x & 0x3333333333333333ull) << 2);
    return ((x >> 1) & 0x5555555555555555ull) | ((x & 0x5555555555555555ull) << 1);
}

/* Sobol' dimension 1 of `index`, bit-reversed. Its direction numbers (primitive polynomial x + 1)
 * are the columns of the Pascal matrix mod 2: index bit j sets output bit p (counted from the top)
 * when C(j, p) is odd, which by Lucas' theorem is when p's bits are a subset of j's. So output bit
 * p is the xor of the index bits j that are supersets of p, a transform over the five bits of the
 * bit position done one bit at a time; with the output reversed, bit p sits at position p and
 * each step is a shift, a mask and an xor: 14 operations, no table, no loop over set bits. */
static inline uint32_t sobol_dimension1_reversed(uint32_t index)
{
    uint32_t a = index;
    a ^= (a >> 1) & 0x55555555u;   /* positions with bit 0 clear take the one with it set */
    a ^= (a >> 2) & 0x33333333u;   /* ... bit 1 */
    a ^= (a >> 4) & 0x0f0f0f0fu;   /* ... bit 2 */
    a ^= (a >> 8) & 0x00ff00ffu;   /* ... bit 3 */
    return a ^ (a >> 16);          /* ... bit 4 */
}

/* The two coordinates of the Sobol' (0,2)-sequence, as 32-bit fixed point in [0, 1). */
static inline uint32_t sobol_dimension0(uint32_t index)
{
    return sobol_reverse_bits(index);
}

static inline uint32_t sobol_dimension1(uint32_t index)
{
    return sobol_reverse_bits(sobol_dimension1_reversed(index));
}

/* Nested uniform scramble of a bit-reversed value: bit b of the result is bit b of x flipped by a
 * function of the seed and of bits 0..b-1 only, since every step (xor with an even multiple of
 * itself, adding the seed, multiplying by an odd number) carries information upwards only
 * [Laine and Karras 2011; Burley 2020, hash-based Owen scrambling]. Reversed back, bit b counted
 * from the top is flipped by a function of the bits above it: Owen's scrambling tree. The
 * constants are Vegdahl's (2021, "Building a Better LK Hash", psychopath.io), a revision of the
 * Laine-Karras hash that its author measured to come closer to full Owen scrambling. `mul` must
 * be odd (the multiplication is then a bijection that only carries upwards). */
static inline uint32_t sobol_owen_reversed_mul(uint32_t x, uint32_t seed, uint32_t mul)
{
    x ^= x * 0x3d20adeau;
    x += seed;
    x *= mul;
    x ^= x * 0x05526c56u;
    x ^= x * 0x53a22864u;
    return x;
}

/* The multiplier is derived from the seed; sobol_batch stores it beside each seed instead
 * (sobol_owen_reversed_mul), so that a pixel derives it once. */
static inline uint32_t sobol_owen_reversed(uint32_t x, uint32_t seed)
{
    return sobol_owen_reversed_mul(x, seed, (seed >> 16) | 1u);
}

/* Owen scrambling of a value in natural bit order (a coordinate, or a sample index: Burley's
 * shuffling): bit b counted from the top is flipped by a function of the seed and the bits above
 * it, so values sharing their top k bits still share them afterwards (an aligned block of 2^k
 * maps onto an aligned block of 2^k). */
static inline uint32_t sobol_owen_scramble(uint32_t x, uint32_t seed)
{
    return sobol_reverse_bits(sobol_owen_reversed(sobol_reverse_bits(x), seed));
}

/* Top 24 bits to a float in [0, 1), as rng_next_float. */
static inline float sobol_to_float(uint32_t x)
{
    return (float)(x >> 8) * 0x1p-24f;
}

/* A 32-bit integer hash: Wellons' "lowbias32" (2018, "Prospecting for Hash Functions"), two
 * multiply-xorshift rounds found by search for low bias (every input bit flips every output bit
 * with probability close to 1/2). A bijection, so distinct inputs give distinct outputs. */
static inline uint32_t sobol_hash32(uint32_t x)
{
    x ^= x >> 16;
    x *= 0x7feb352du;
    x ^= x >> 15;
    x *= 0x846ca68bu;
    return x ^ (x >> 16);
}

/* A padded dimension's seeds: the index shuffle's, and one scramble per coordinate. They depend
 * on (pixel seed, dimension) only, so a pixel derives them once for all its samples. Seed word w
 * (0: shuffle, 1 and 2: the scrambles) of dimension d is hash(lo ^ hash(hi + d * 0x9e3779b9 +
 * w * 0x85ebca6b)), lo and hi the halves of the pixel seed: the inner hash spreads (d, w) (distinct
 * for every d < 2^16, test_core.c), the outer one mixes in the rest of the pixel seed. Only 32-bit
 * multiplications, so sobol_batch_seed derives eight dimensions' words at once with AVX2 (a
 * SplitMix64 per dimension cost about 200 instructions a pixel for pt's dimensions, some 40 per ray
 * at one sample per pixel). test_core.c checks what the seeds are for: uniform coordinates over
 * pixels, independent dimensions. */
struct sobol_seeds { uint32_t shuffle, scramble0, scramble1; };

#define SOBOL_SEED_DIM_STEP 0x9e3779b9u
#define SOBOL_SEED_WORD_STEP 0x85ebca6bu

static inline uint32_t sobol_seed_word(uint64_t pixel_seed, uint32_t dim, uint32_t word)
{
    const uint32_t lo = (uint32_t)pixel_seed, hi = (uint32_t)(pixel_seed >> 32);
    return sobol_hash32(lo ^ sobol_hash32(hi + dim * SOBOL_SEED_DIM_STEP + word * SOBOL_SEED_WORD_STEP));
}

static inline struct sobol_seeds sobol_dimension_seeds(uint64_t pixel_seed, uint32_t dim)
{
    return (struct sobol_seeds){sobol_seed_word(pixel_seed, dim, 0), sobol_seed_word(pixel_seed, dim, 1),
                                sobol_seed_word(pixel_seed, dim, 2)};
}

/* A sample's index shuffled by one dimension's seed (Burley's shuffling: sobol_owen_scramble of
 * the index), in natural bit order, from the index bit-reversed (a pixel's sample reverses its
 * index once for all its dimensions). */
static inline uint32_t sobol_shuffled_index(uint32_t index_reversed, uint32_t seed)
{
    return sobol_reverse_bits(sobol_owen_reversed(index_reversed, seed));
}

/* A padded dimension of one sample as two 32-bit fixed-point coordinates in [0, 1): Sobol'
 * dimensions 0 and 1 of the shuffled index, each Owen-scrambled with its own seed. Over the first
 * 2^k indices of one (pixel, dimension) the points form a (0,k,2)-net. Dimension 0 of an index,
 * reversed, is the index itself and dimension 1 reversed is sobol_dimension1_reversed, so both
 * are scrambled without leaving the reversed domain, and their two reversals back are one
 * 64-bit reversal. */
static inline void sobol_2d_u32(uint32_t index_reversed, const struct sobol_seeds *k, uint32_t out[2])
{
    uint32_t index = sobol_shuffled_index(index_reversed, k->shuffle);
    uint32_t r0 = sobol_owen_reversed(index, k->scramble0);
    uint32_t r1 = sobol_owen_reversed(sobol_dimension1_reversed(index), k->scramble1);
    uint64_t both = sobol_reverse_bits64((uint64_t)r0 << 32 | r1);
    out[0] = (uint32_t)both;
    out[1] = (uint32_t)(both >> 32);
}

static inline void sobol_2d(uint32_t index_reversed, const struct sobol_seeds *k, float *u0, float *u1)
{
    uint32_t u[2];
    sobol_2d_u32(index_reversed, k, u);
    *u0 = sobol_to_float(u[0]);
    *u1 = sobol_to_float(u[1]);
}

/* Coordinate 0 of a padded dimension alone (the number sobol_2d gives as *u0), for a
 * one-dimensional decision: over the first 2^k indices it is stratified by itself. */
static inline float sobol_1d(uint32_t index_reversed, const struct sobol_seeds *k)
{
    uint32_t index = sobol_shuffled_index(index_reversed, k->shuffle);
    return sobol_to_float(sobol_reverse_bits(sobol_owen_reversed(index, k->scramble0)));
}

/* Padded dimension `dim` of sample `index` of the pixel with seed `pixel_seed`, all in one call
 * (a caller drawing many samples of one pixel keeps the seeds and the reversed index instead). */
static inline void sobol_sample_2d(uint64_t pixel_seed, uint32_t index, uint32_t dim, float *u0, float *u1)
{
    const struct sobol_seeds k = sobol_dimension_seeds(pixel_seed, dim);
    sobol_2d(sobol_reverse_bits(index), &k, u0, u1);
}

static inline float sobol_sample_1d(uint64_t pixel_seed, uint32_t index, uint32_t dim)
{
    const struct sobol_seeds k = sobol_dimension_seeds(pixel_seed, dim);
    return sobol_1d(sobol_reverse_bits(index), &k);
}

/* Many padded dimensions of one pixel drawn at once (a path's dimensions, all at the start of its
 * sample): the seeds of up to SOBOL_BATCH_DIMS dimensions as lanes, and one call that draws every
 * lane's 2D point for one sample index. The numbers are exactly sobol_2d's for the same seeds
 * (test_core.c compares them lane by lane on both code paths), computed eight lanes at a time with
 * AVX2 where the processor has it (chosen at run time; the build targets plain x86-64), else one
 * by one: a 32-bit multiply is one instruction for eight lanes, and a bit reversal is two 16-entry
 * nibble lookups and a byte swap (pshufb). Eight lanes cost about what one sobol_2d costs in
 * scalar code (`bash bench/sobol_instr.sh`). The multiplier (seed >> 16) | 1 of
 * sobol_owen_reversed is stored beside each seed, so it is derived once per pixel. Lane counts
 * are at most SOBOL_BATCH_DIMS; multiples of SOBOL_BATCH_LANES take the vector code throughout. */
#define SOBOL_BATCH_LANES 8
#define SOBOL_BATCH_DIMS 16
struct sobol_batch {
    uint32_t shuffle[SOBOL_BATCH_DIMS], shuffle_mul[SOBOL_BATCH_DIMS];
    uint32_t scramble0[SOBOL_BATCH_DIMS], scramble0_mul[SOBOL_BATCH_DIMS];
    uint32_t scramble1[SOBOL_BATCH_DIMS], scramble1_mul[SOBOL_BATCH_DIMS];
};

/* Lane d takes dimension d of the pixel. */
static inline void sobol_batch_seed_lane(struct sobol_batch *b, uint64_t pixel_seed, uint32_t d)
{
    const struct sobol_seeds k = sobol_dimension_seeds(pixel_seed, d);
    b->shuffle[d] = k.shuffle;
    b->shuffle_mul[d] = (k.shuffle >> 16) | 1u;
    b->scramble0[d] = k.scramble0;
    b->scramble0_mul[d] = (k.scramble0 >> 16) | 1u;
    b->scramble1[d] = k.scramble1;
    b->scramble1_mul[d] = (k.scramble1 >> 16) | 1u;
}

/* Lane i's 2D point: sobol_2d with the lane's seeds. */
static inline void sobol_batch_draw_lane(const struct sobol_batch *b, uint32_t index_reversed, uint32_t i, float *u0,
                                         float *u1)
{
    uint32_t index = sobol_reverse_bits(sobol_owen_reversed_mul(index_reversed, b->shuffle[i], b->shuffle_mul[i]));
    uint32_t r0 = sobol_owen_reversed_mul(index, b->scramble0[i], b->scramble0_mul[i]);
    uint32_t r1 = sobol_owen_reversed_mul(sobol_dimension1_reversed(index), b->scramble1[i], b->scramble1_mul[i]);
    u0[i] = sobol_to_float(sobol_reverse_bits(r0));
    u1[i] = sobol_to_float(sobol_reverse_bits(r1));
}

/* Lanes [first, lanes) one by one: the scalar path, and the vector paths' tails (kept out of
 * line there, so that the eight-lane loop does not carry their code). */
__attribute__((noinline, unused)) static void sobol_batch_seed_from(struct sobol_batch *b, uint64_t pixel_seed,
                                                                  uint32_t first, uint32_t lanes)
{
    for (uint32_t d = first; d < lanes; d++) sobol_batch_seed_lane(b, pixel_seed, d);
}

__attribute__((noinline, unused)) static void sobol_batch_draw_from(const struct sobol_batch *b,
                                                                  uint32_t index_reversed, uint32_t first,
                                                                  uint32_t lanes, float *u0, float *u1)
{
    for (uint32_t i = first; i < lanes; i++) sobol_batch_draw_lane(b, index_reversed, i, u0, u1);
}

/* Samples first .. first + count - 1 (natural order, first + count <= 2^32), sample i's lanes at
 * u0 + i * stride and u1 + i * stride. */
static inline void sobol_batch_draw_run_scalar(const struct sobol_batch *b, uint32_t first, uint32_t count,
                                               uint32_t lanes, float *u0, float *u1, uint32_t stride)
{
    for (uint32_t i = 0; i < count; i++)
        sobol_batch_draw_from(b, sobol_reverse_bits(first + i), 0, lanes, u0 + (size_t)i * stride,
                              u1 + (size_t)i * stride);
}

static inline void sobol_batch_seed_scalar(struct sobol_batch *b, uint64_t pixel_seed, uint32_t lanes)
{
    sobol_batch_seed_from(b, pixel_seed, 0, lanes);
}

static inline void sobol_batch_draw_scalar(const struct sobol_batch *b, uint32_t index_reversed, uint32_t lanes,
                                           float *u0, float *u1)
{
    sobol_batch_draw_from(b, index_reversed, 0, lanes, u0, u1);
}

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define SOBOL_HAVE_AVX2 1

/* The scalar steps above, eight lanes at a time. The scramble's first step, which depends on x
 * alone, is a function of its own (sobol_batch_draw_run takes it for eight samples at once). */
__attribute__((target("avx2"))) static inline __m256i sobol_owen_reversed_pre_x8(__m256i x)
{
    return _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32(0x3d20adea)));
}

__attribute__((target("avx2"))) static inline __m256i sobol_owen_reversed_post_x8(__m256i x, __m256i seed, __m256i mul)
{
    x = _mm256_add_epi32(x, seed);
    x = _mm256_mullo_epi32(x, mul);
    x = _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32(0x05526c56)));
    return _mm256_xor_si256(x, _mm256_mullo_epi32(x, _mm256_set1_epi32(0x53a22864)));
}

__attribute__((target("avx2"))) static inline __m256i sobol_owen_reversed_x8(__m256i x, __m256i seed, __m256i mul)
{
    return sobol_owen_reversed_post_x8(sobol_owen_reversed_pre_x8(x), seed, mul);
}

/* Each byte's nibbles reversed by table lookup and swapped, then each lane's bytes swapped (the
 * shuffles work within each 128-bit half, so the tables are repeated in both). */
__attribute__((target("avx2"))) static inline __m256i sobol_reverse_bits_x8(__m256i x)
{
    const __m256i nibble_reversed = _mm256_set_epi8(15, 7, 11, 3, 13, 5, 9, 1, 14, 6, 10, 2, 12, 4, 8, 0, 15, 7, 11, 3,
                                                    13, 5, 9, 1, 14, 6, 10, 2, 12, 4, 8, 0);
    const __m256i low = _mm256_set1_epi8(0x0f);
    const __m256i byte_swap = _mm256_set_epi8(12, 13, 14, 15, 8, 9, 10, 11, 4, 5, 6, 7, 0, 1, 2, 3, 12, 13, 14, 15, 8,
                                              9, 10, 11, 4, 5, 6, 7, 0, 1, 2, 3);
    __m256i lo = _mm256_shuffle_epi8(nibble_reversed, _mm256_and_si256(x, low));
    __m256i hi = _mm256_shuffle_epi8(nibble_reversed, _mm256_and_si256(_mm256_srli_epi16(x, 4), low));
    return _mm256_shuffle_epi8(_mm256_or_si256(_mm256_slli_epi16(lo, 4), hi), byte_swap);
}

__attribute__((target("avx2"))) static inline __m256i sobol_dimension1_reversed_x8(__m256i a)
{
    a = _mm256_xor_si256(a, _mm256_and_si256(_mm256_srli_epi32(a, 1), _mm256_set1_epi32(0x55555555)));
    a = _mm256_xor_si256(a, _mm256_and_si256(_mm256_srli_epi32(a, 2), _mm256_set1_epi32(0x33333333)));
    a = _mm256_xor_si256(a, _mm256_and_si256(_mm256_srli_epi32(a, 4), _mm256_set1_epi32(0x0f0f0f0f)));
    a = _mm256_xor_si256(a, _mm256_and_si256(_mm256_srli_epi32(a, 8), _mm256_set1_epi32(0x00ff00ff)));
    return _mm256_xor_si256(a, _mm256_srli_epi32(a, 16));
}

__attribute__((target("avx2"))) static inline __m256 sobol_to_float_x8(__m256i x)
{
    return _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_srli_epi32(x, 8)), _mm256_set1_ps(0x1p-24f));
}

__attribute__((target("avx2"))) static inline __m256i sobol_hash32_x8(__m256i x)
{
    x = _mm256_xor_si256(x, _mm256_srli_epi32(x, 16));
    x = _mm256_mullo_epi32(x, _mm256_set1_epi32(0x7feb352d));
    x = _mm256_xor_si256(x, _mm256_srli_epi32(x, 15));
    x = _mm256_mullo_epi32(x, _mm256_set1_epi32((int)0x846ca68bu));
    return _mm256_xor_si256(x, _mm256_srli_epi32(x, 16));
}

/* Eight lanes at a time, the rest (a lane count that is no multiple of 8) one by one. */
__attribute__((target("avx2"))) static inline void sobol_batch_seed_avx2(struct sobol_batch *b, uint64_t pixel_seed,
                                                                        uint32_t lanes)
{
    const __m256i lo = _mm256_set1_epi32((int)(uint32_t)pixel_seed);
    const __m256i hi = _mm256_set1_epi32((int)(uint32_t)(pixel_seed >> 32));
    const __m256i one = _mm256_set1_epi32(1);
    uint32_t i = 0;
    for (; i + 8 <= lanes; i += 8) {
        __m256i dims = _mm256_add_epi32(_mm256_set1_epi32((int)i), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
        __m256i base = _mm256_add_epi32(hi, _mm256_mullo_epi32(dims, _mm256_set1_epi32((int)SOBOL_SEED_DIM_STEP)));
        uint32_t *words[3] = {b->shuffle + i, b->scramble0 + i, b->scramble1 + i};
        uint32_t *muls[3] = {b->shuffle_mul + i, b->scramble0_mul + i, b->scramble1_mul + i};
        for (int w = 0; w < 3; w++) {
            __m256i seed = sobol_hash32_x8(_mm256_xor_si256(lo, sobol_hash32_x8(base)));
            _mm256_storeu_si256((__m256i *)words[w], seed);
            _mm256_storeu_si256((__m256i *)muls[w], _mm256_or_si256(_mm256_srli_epi32(seed, 16), one));
            base = _mm256_add_epi32(base, _mm256_set1_epi32((int)SOBOL_SEED_WORD_STEP));
        }
    }
    if (i < lanes) sobol_batch_seed_from(b, pixel_seed, i, lanes);
}

__attribute__((target("avx2"))) static inline void sobol_batch_draw_avx2(const struct sobol_batch *b,
                                                                        uint32_t index_reversed, uint32_t lanes,
                                                                        float *u0, float *u1)
{
    const __m256i ir = _mm256_set1_epi32((int)index_reversed);
    uint32_t i = 0;
    for (; i + 8 <= lanes; i += 8) {
#define SOBOL_LOAD(field) _mm256_loadu_si256((const __m256i *)(b->field + i))
        __m256i index = sobol_reverse_bits_x8(sobol_owen_reversed_x8(ir, SOBOL_LOAD(shuffle), SOBOL_LOAD(shuffle_mul)));
        __m256i r0 = sobol_owen_reversed_x8(index, SOBOL_LOAD(scramble0), SOBOL_LOAD(scramble0_mul));
        __m256i r1 = sobol_owen_reversed_x8(sobol_dimension1_reversed_x8(index), SOBOL_LOAD(scramble1),
                                            SOBOL_LOAD(scramble1_mul));
#undef SOBOL_LOAD
        _mm256_storeu_ps(u0 + i, sobol_to_float_x8(sobol_reverse_bits_x8(r0)));
        _mm256_storeu_ps(u1 + i, sobol_to_float_x8(sobol_reverse_bits_x8(r1)));
    }
    if (i < lanes) sobol_batch_draw_from(b, index_reversed, i, lanes, u0, u1);
}

/* The eight lanes of sobol_batch_draw_avx2 after the shuffle's first step (pre: that step of the
 * reversed index, in every lane). */
__attribute__((target("avx2"))) static inline void sobol_batch_draw8_pre_avx2(const struct sobol_batch *b, __m256i pre,
                                                                             float *u0, float *u1)
{
#define SOBOL_LOAD(field) _mm256_loadu_si256((const __m256i *)b->field)
    __m256i index =
        sobol_reverse_bits_x8(sobol_owen_reversed_post_x8(pre, SOBOL_LOAD(shuffle), SOBOL_LOAD(shuffle_mul)));
    __m256i r0 = sobol_owen_reversed_x8(index, SOBOL_LOAD(scramble0), SOBOL_LOAD(scramble0_mul));
    __m256i r1 = sobol_owen_reversed_x8(sobol_dimension1_reversed_x8(index), SOBOL_LOAD(scramble1),
                                        SOBOL_LOAD(scramble1_mul));
#undef SOBOL_LOAD
    _mm256_storeu_ps(u0, sobol_to_float_x8(sobol_reverse_bits_x8(r0)));
    _mm256_storeu_ps(u1, sobol_to_float_x8(sobol_reverse_bits_x8(r1)));
}

/* A run of samples with eight lanes each, in one call: the constants stay in registers across the
 * run, and the samples' indices are reversed, and put through the shuffle's first step, eight at a
 * time. */
__attribute__((target("avx2"))) static inline void sobol_batch_draw_run8_avx2(const struct sobol_batch *b,
                                                                             uint32_t first, uint32_t count,
                                                                             float *u0, float *u1, uint32_t stride)
{
    const __m256i step = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    for (uint32_t i = 0; i < count; i += 8) {
        uint32_t pre[8];
        _mm256_storeu_si256((__m256i *)pre, sobol_owen_reversed_pre_x8(sobol_reverse_bits_x8(
                                                 _mm256_add_epi32(_mm256_set1_epi32((int)(first + i)), step))));
        const uint32_t n = count - i < 8 ? count - i : 8;
        for (uint32_t j = 0; j < n; j++)
            sobol_batch_draw8_pre_avx2(b, _mm256_set1_epi32((int)pre[j]), u0 + (size_t)(i + j) * stride,
                                       u1 + (size_t)(i + j) * stride);
    }
}
#endif

/* Lanes [0, lanes) take the seeds of the pixel's dimensions 0 .. lanes - 1: sobol_dimension_seeds
 * of each, with its multipliers. */
static inline void sobol_batch_seed(struct sobol_batch *b, uint64_t pixel_seed, uint32_t lanes)
{
#ifdef SOBOL_HAVE_AVX2
    if (__builtin_cpu_supports("avx2")) {
        sobol_batch_seed_avx2(b, pixel_seed, lanes);
        return;
    }
#endif
    sobol_batch_seed_scalar(b, pixel_seed, lanes);
}

/* Every lane's 2D point for one sample index (reversed, as sobol_2d takes it): u0[i], u1[i] for
 * lane i < lanes. */
static inline void sobol_batch_draw(const struct sobol_batch *b, uint32_t index_reversed, uint32_t lanes, float *u0,
                                    float *u1)
{
#ifdef SOBOL_HAVE_AVX2
    if (__builtin_cpu_supports("avx2")) {
        sobol_batch_draw_avx2(b, index_reversed, lanes, u0, u1);
        return;
    }
#endif
    sobol_batch_draw_scalar(b, index_reversed, lanes, u0, u1);
}

/* sobol_batch_draw for samples first .. first + count - 1 (natural order; first + count <= 2^32):
 * sample i's lanes at u0 + i * stride and u1 + i * stride. A pixel's samples drawn as one run
 * instead of one call each: with AVX2 and eight lanes, the constants are set up and the processor
 * checked once per run, and the indices reversed eight at a time. */
static inline void sobol_batch_draw_run(const struct sobol_batch *b, uint32_t first, uint32_t count, uint32_t lanes,
                                        float *u0, float *u1, uint32_t stride)
{
#ifdef SOBOL_HAVE_AVX2
    if (lanes == SOBOL_BATCH_LANES && __builtin_cpu_supports("avx2")) {
        sobol_batch_draw_run8_avx2(b, first, count, u0, u1, stride);
        return;
    }
#endif
    sobol_batch_draw_run_scalar(b, first, count, lanes, u0, u1, stride);
}

#endif
