/* test_reservoir.c — GRIS reservoirs and resampling MIS weights on 1-D toy integrals with known
 * values: streaming selection frequencies (chi-square), unbiased initial RIS, unbiased spatial
 * reuse with pairwise MIS and temporal reuse with the generalized balance heuristic when the
 * neighbours' targets differ from the pixel's and even miss part of its support; and a
 * negative control (constant 1/(k+1) weights) that the same z-test must reject as biased. */
#include <math.h>
#include <stdint.h>

#include "reuse/reservoir.h"
#include "reuse/reuse_mis.h"
#include "core/rng.h"
#include "test.h"

/* Streaming resampling picks candidate i with probability w_i / sum w (chi-square over 6
 * fixed weights, one of them zero, 60 000 draws). */
static void test_stream_selection_frequencies(void)
{
    const double w[6] = {0.5, 2.0, 0.0, 1.0, 3.5, 1.0};
    const double sum = 8.0;
    unsigned count[6] = {0};
    const unsigned trials = 60000;
    for (unsigned t = 0; t < trials; t++) {
        struct rng r = rng_make(11, t, 0, 0);
        struct reservoir_stream s;
        reservoir_stream_begin(&s);
        int pick = -1;
        for (int i = 0; i < 6; i++)
            if (reservoir_stream_offer(&s, w[i], (float)(i + 1), 1.0f, rng_next_float(&r))) pick = i;
        CHECK(pick >= 0);
        if (pick >= 0) count[pick]++;
        struct reservoir res = reservoir_stream_finish(&s);
        CHECK(res.M == 6.0f);
        CHECK(fabs(res.W - sum / (pick + 1)) < 1e-5 * res.W);
    }
    CHECK(count[2] == 0);
    double chi2 = 0.0;
    for (int i = 0; i < 6; i++) {
        if (w[i] == 0.0) continue;
        double e = trials * w[i] / sum;
        chi2 += (count[i] - e) * (count[i] - e) / e;
    }
    /* 4 degrees of freedom: P(chi2 > 23.5) ~ 1e-4. */
    CHECK_MSG(chi2 < 23.5, "chi2 %.2f", chi2);
}

static void test_stream_rejects_bad_weights(void)
{
    struct reservoir_stream s;
    reservoir_stream_begin(&s);
    CHECK(!reservoir_stream_offer(&s, NAN, 1.0f, 1.0f, 0.0f));
    CHECK(!reservoir_stream_offer(&s, INFINITY, 1.0f, 1.0f, 0.0f));
    CHECK(!reservoir_stream_offer(&s, -1.0, 1.0f, 1.0f, 0.0f));
    CHECK(!reservoir_stream_offer(&s, 1.0, NAN, 1.0f, 0.0f));
    CHECK(s.rejected == 4 && s.M == 0.0f && s.w_sum == 0.0);
    CHECK(!reservoir_stream_offer(&s, 0.0, 0.0f, 1.0f, 0.5f));  /* a null candidate still counts */
    CHECK(s.M == 1.0f);
    struct reservoir r = reservoir_stream_finish(&s);
    CHECK(r.W == 0.0f && r.M == 1.0f);
    struct reservoir c = {1.0f, 1.0f, 500.0f};
    reservoir_cap_m(&c, 20.0f);
    CHECK(c.M == 20.0f);
}

/* ---- toy integrals on [0, 1) ---- */

enum { DOMAINS = 4 };

/* The canonical pixel's integrand (integral 2) and three neighbours: one similar, one with a
 * different shape, one that is zero on [0.6, 1) (it cannot produce samples there). */
static double toy_f(int d, double x)
{
    switch (d) {
    case 0: return 1.0 + 2.0 * x;
    case 1: return 1.2 + 1.5 * x;
    case 2: return 0.3 + 4.0 * x * x;
    default: return x < 0.6 ? 2.0 - x : 0.0;
    }
}

struct toy_res { double x; struct reservoir r; };

/* Initial RIS: M0 uniform candidates (source pdf 1), target = the domain's integrand. */
static struct toy_res toy_initial(int d, struct rng *r, unsigned M0)
{
    struct reservoir_stream s;
    reservoir_stream_begin(&s);
    struct toy_res out = {0.0, {0}};
    for (unsigned i = 0; i < M0; i++) {
        double x = rng_next_double(r);
        double p = toy_f(d, x);
        if (reservoir_stream_offer(&s, p / M0, (float)p, 1.0f, rng_next_float(r))) out.x = x;
    }
    out.r = reservoir_stream_finish(&s);
    return out;
}

enum toy_mode { TOY_PAIRWISE, TOY_BALANCE, TOY_NAIVE };

/* One spatial (or, with TOY_BALANCE, generalized-balance) reuse at domain 0 from domains
 * 1..3 with the identity shift (|J| = 1); returns the estimate f_0(Y) W. */
static double toy_reuse(struct rng *r, enum toy_mode mode, unsigned M0)
{
    struct toy_res res[DOMAINS];
    for (int d = 0; d < DOMAINS; d++) res[d] = toy_initial(d, r, M0);
    const uint32_t k = DOMAINS - 1;
    struct reservoir_stream s;
    reservoir_stream_begin(&s);
    double y = 0.0;
    float Ms[DOMAINS], ph[DOMAINS];
    for (int d = 0; d < DOMAINS; d++) Ms[d] = res[d].r.M;

    /* canonical */
    double xc = res[0].x, pc = toy_f(0, xc), mc;
    if (mode == TOY_PAIRWISE) {
        float sum = 0.0f;
        for (uint32_t n = 1; n <= k; n++)
            sum += reuse_mis_pairwise_canonical_term(res[0].r.M, res[n].r.M, (float)pc, (float)toy_f((int)n, xc), k);
        mc = reuse_mis_pairwise_canonical(sum, k);
    } else if (mode == TOY_BALANCE) {
        for (int d = 0; d < DOMAINS; d++) ph[d] = (float)toy_f(d, xc);
        mc = reuse_mis_balance(Ms, ph, DOMAINS, 0);
    } else {
        mc = 1.0 / (k + 1);
    }
    if (reservoir_stream_offer(&s, mc * pc * res[0].r.W, (float)pc, res[0].r.M, rng_next_float(r))) y = xc;

    for (uint32_t n = 1; n <= k; n++) {
        double xn = res[n].x, p_at_c = toy_f(0, xn), m;
        if (mode == TOY_PAIRWISE) {
            m = reuse_mis_pairwise_neighbor(res[0].r.M, res[n].r.M, (float)toy_f((int)n, xn), (float)p_at_c, k);
        } else if (mode == TOY_BALANCE) {
            for (int d = 0; d < DOMAINS; d++) ph[d] = (float)toy_f(d, xn);
            m = reuse_mis_balance(Ms, ph, DOMAINS, n);
        } else {
            m = 1.0 / (k + 1);
        }
        if (reservoir_stream_offer(&s, m * p_at_c * res[n].r.W, (float)p_at_c, res[n].r.M, rng_next_float(r))) y = xn;
    }
    struct reservoir out = reservoir_stream_finish(&s);
    return out.W > 0.0f ? toy_f(0, y) * out.W : 0.0;
}

/* z-score of the mean of `trials` estimates against the exact integral 2. */
static double toy_z(enum toy_mode mode, unsigned M0, unsigned trials, int seed, int initial_only)
{
    double sum = 0.0, sum2 = 0.0;
    for (unsigned t = 0; t < trials; t++) {
        struct rng r = rng_make((uint64_t)seed, t, mode, M0);
        double e;
        if (initial_only) {
            struct toy_res res = toy_initial(0, &r, M0);
            e = res.r.W > 0.0f ? toy_f(0, res.x) * res.r.W : 0.0;
        } else {
            e = toy_reuse(&r, mode, M0);
        }
        sum += e;
        sum2 += e * e;
    }
    double mean = sum / trials, var = (sum2 / trials - mean * mean) / (trials - 1);
    return (mean - 2.0) / sqrt(var);
}

static void test_initial_ris_unbiased(void)
{
    for (unsigned M0 = 1; M0 <= 8; M0 *= 2) {
        double z = toy_z(TOY_PAIRWISE, M0, 100000, 3, 1);
        CHECK_MSG(fabs(z) < 4.5, "M0=%u z=%.2f", M0, z);
    }
}

static void test_pairwise_reuse_unbiased(void)
{
    for (unsigned M0 = 1; M0 <= 4; M0 *= 2) {
        double z = toy_z(TOY_PAIRWISE, M0, 100000, 5, 0);
        CHECK_MSG(fabs(z) < 4.5, "M0=%u z=%.2f", M0, z);
    }
}

static void test_balance_reuse_unbiased(void)
{
    for (unsigned M0 = 1; M0 <= 4; M0 *= 2) {
        double z = toy_z(TOY_BALANCE, M0, 100000, 7, 0);
        CHECK_MSG(fabs(z) < 4.5, "M0=%u z=%.2f", M0, z);
    }
}

/* Constant 1/(k+1) weights give domain 3's share of [0.6, 1) to nobody: the estimate darkens,
 * and the same test must see it (this is what makes the two tests above meaningful). */
static void test_naive_weights_detected_as_biased(void)
{
    double z = toy_z(TOY_NAIVE, 2, 100000, 9, 0);
    CHECK_MSG(z < -8.0, "z=%.2f", z);
}

/* Pairwise weights of one sample over the domains that can produce it sum to 1. */
static void test_pairwise_weights_partition_unity(void)
{
    const uint32_t k = 3;
    const float M[4] = {1.0f, 3.0f, 2.0f, 5.0f};
    for (int i = 0; i < 50; i++) {
        double x = (i + 0.5) / 50.0;
        /* Treat x as the canonical sample and as each neighbour's sample in turn: the weight a
         * domain gives x must be the same function of x whichever domain's reservoir holds it. */
        float sum_terms = 0.0f;
        for (uint32_t n = 1; n <= k; n++)
            sum_terms += reuse_mis_pairwise_canonical_term(M[0], M[n], (float)toy_f(0, x), (float)toy_f((int)n, x), k);
        double total = reuse_mis_pairwise_canonical(sum_terms, k);
        for (uint32_t n = 1; n <= k; n++)
            total += reuse_mis_pairwise_neighbor(M[0], M[n], (float)toy_f((int)n, x), (float)toy_f(0, x), k);
        CHECK_NEAR(total, 1.0, 1e-5);
    }
}

TEST_MAIN(TEST(test_stream_selection_frequencies), TEST(test_stream_rejects_bad_weights), TEST(test_initial_ris_unbiased),
          TEST(test_pairwise_reuse_unbiased), TEST(test_balance_reuse_unbiased),
          TEST(test_naive_weights_detected_as_biased), TEST(test_pairwise_weights_partition_unity))
