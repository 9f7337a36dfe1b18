/* rng.h — PCG32 random streams with stateless seeding.
 * A stream is derived by hashing (session seed, frame, pixel, pass, sample), never from a
 * thread id, so images do not depend on the thread count. Refs: O'Neill 2014 (PCG). */
#ifndef RESTIRD_RNG_H
#define RESTIRD_RNG_H

#include <stdint.h>

struct rng { uint64_t state, inc; };

/* 64-bit finaliser (SplitMix64) used to spread seed words. */
static inline uint64_t rng_mix64(uint64_t z)
{
    z += 0x9e3779b97f4a7c15ull;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

/* Advances the stream by one number without computing it: a draw whose value is not needed
 * (a lobe choice at a one-lobe material), so that later draws stay where they were. */
static inline void rng_skip(struct rng *r)
{
    r->state = r->state * 6364136223846793005ull + r->inc;
}

static inline uint32_t rng_next_u32(struct rng *r)
{
    uint64_t old = r->state;
    rng_skip(r);
    uint32_t xorshifted = (uint32_t)(((old >> 18u) ^ old) >> 27u);
    uint32_t rot = (uint32_t)(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((-rot) & 31));
}

/* Stream for (seed, a, b, c): distinct tuples give independent-looking streams. */
static inline struct rng rng_make(uint64_t seed, uint64_t a, uint64_t b, uint64_t c)
{
    uint64_t h = rng_mix64(seed ^ rng_mix64(a ^ rng_mix64(b ^ rng_mix64(c))));
    struct rng r = {0, (rng_mix64(h + 1) << 1u) | 1u};
    rng_next_u32(&r);
    r.state += h;
    rng_next_u32(&r);
    return r;
}

/* The streams of one pixel's samples: rng_make's hash of (seed, a, b, c) once per pixel gives the
 * increment, shared by the pixel's samples, and rng_sample hashes the sample index into a starting
 * state (one SplitMix64 where rng_make costs five and two steps), so that a path tracer pays the
 * full derivation once per pixel, not once per sample. A pixel's samples start at unrelated points
 * of its own sequence: two of a thousand samples drawing a thousand numbers each overlap with a
 * probability near 1e-10; other pixels use other sequences. */
struct rng_pixel { uint64_t hash, inc; };

static inline struct rng_pixel rng_pixel_make(uint64_t seed, uint64_t a, uint64_t b, uint64_t c)
{
    uint64_t h = rng_mix64(seed ^ rng_mix64(a ^ rng_mix64(b ^ rng_mix64(c))));
    return (struct rng_pixel){h, (rng_mix64(h + 1) << 1u) | 1u};
}

static inline struct rng rng_sample(const struct rng_pixel *p, uint64_t sample)
{
    return (struct rng){rng_mix64(p->hash ^ sample), p->inc};
}

/* Stream for one 64-bit key, for streams made by the million (a path vertex's numbers): one
 * SplitMix64 hash spreads the key over PCG32's state and every such stream shares one increment,
 * so distinct keys start at unrelated points of one 2^64 sequence — a few numbers each never
 * overlap in practice. About a tenth of rng_make's cost. */
static inline struct rng rng_keyed(uint64_t key)
{
    struct rng r = {rng_mix64(key), 0xda3e39cb94b95bdbull};
    return r;
}

/* Uniform float in [0, 1): 24 random mantissa bits, never returns 1. */
static inline float rng_next_float(struct rng *r)
{
    return (float)(rng_next_u32(r) >> 8) * 0x1p-24f;
}

static inline double rng_next_double(struct rng *r)
{
    uint64_t hi = rng_next_u32(r), lo = rng_next_u32(r);
    return (double)(((hi << 32) | lo) >> 11) * 0x1p-53;
}

#endif
