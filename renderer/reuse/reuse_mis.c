/* reuse_mis.c — resampling MIS weights (see reuse_mis.h). */
#include "reuse/reuse_mis.h"

#include <math.h>

float reuse_mis_balance(const float *M, const float *p_hat, uint32_t n, uint32_t i)
{
    double den = 0.0;
    for (uint32_t j = 0; j < n; j++) den += (double)M[j] * (double)p_hat[j];
    if (!(den > 0.0) || !isfinite(den)) return 0.0f;
    return (float)((double)M[i] * (double)p_hat[i] / den);
}

float reuse_mis_pairwise_neighbor(float M_c, float M_n, float p_n_own, float p_c_shifted, uint32_t k)
{
    /* a / (a + b) / (k + 1) with a = M_n p_n, b = (M_c / k) p_c, both terms multiplied by k: one
     * division instead of three (the weights of a spatial pass are its commonest arithmetic). */
    double a = (double)M_n * (double)p_n_own * (double)k;
    double b = (double)M_c * (double)p_c_shifted;
    if (!(a > 0.0) || !isfinite(a + b)) return 0.0f;
    return (float)(a / ((a + b) * (double)(k + 1)));
}

float reuse_mis_pairwise_canonical_term(float M_c, float M_n, float p_c_own, float p_n_shifted, uint32_t k)
{
    /* 1 - a / (a + b) = b / (a + b) with a = M_n p_n, b = (M_c / k) p_c, both times k. */
    double a = (double)M_n * (double)p_n_shifted * (double)k;
    double b = (double)M_c * (double)p_c_own;
    /* The neighbour cannot produce the canonical sample: the canonical domain keeps it all. */
    if (!(a > 0.0)) return 1.0f;
    if (!isfinite(a + b)) return 0.0f;
    return (float)(b / (a + b));
}

float reuse_mis_pairwise_canonical(float sum_of_terms, uint32_t k)
{
    return (1.0f + sum_of_terms) / (float)(k + 1);
}
