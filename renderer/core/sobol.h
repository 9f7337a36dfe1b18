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
 * Laine-Karras hash that its author measured to come closer to full Owen scrambling. */
static inline uint32_t sobol_owen_reversed(uint32_t x, uint32_t seed)
{
    x ^= x * 0x3d20adeau;
    x += seed;
    x *= (seed >> 16) | 1u;
    x ^= x * 0x05526c56u;
    x ^= x * 0x53a22864u;
    return x;
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

/* A padded dimension's seeds: the index shuffle's, and one scramble per coordinate. They depend
 * on (pixel seed, dimension) only, so a pixel can derive them once for all its samples. One
 * SplitMix64 of (pixel seed, dimension) gives the first two; the third mixes both halves of that
 * hash through one more multiplication, cheaper than a second SplitMix64 (test_core.c checks
 * what the seeds are for: uniform coordinates over pixels, independent dimensions). */
struct sobol_seeds { uint32_t shuffle, scramble0, scramble1; };

static inline struct sobol_seeds sobol_dimension_seeds(uint64_t pixel_seed, uint32_t dim)
{
    uint64_t key = rng_mix64(pixel_seed + (uint64_t)dim * 0x9e3779b97f4a7c15ull);
    uint32_t third = (uint32_t)(((key ^ (key >> 32)) * 0xd6e8feb86659fd93ull) >> 32);
    return (struct sobol_seeds){(uint32_t)key, (uint32_t)(key >> 32), third};
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

#endif
