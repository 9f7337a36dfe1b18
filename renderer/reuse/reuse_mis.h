/* reuse_mis.h — resampling MIS weights m_i for reuse across pixels and frames: the generalized
 * balance heuristic (temporal reuse, few domains) and defensive pairwise MIS (spatial reuse,
 * O(k) instead of O(k^2) target evaluations). Every p̂ below is the target function of one
 * domain evaluated on a sample expressed in that domain, already multiplied by the Jacobian
 * of the shift that brought it there, so all values of one sum share one measure.
 * Pure functions: no state, thread-safe.
 * Refs: Lin et al. 2022 (GRIS) eq. 9 (generalized balance heuristic) and §6.2 (pairwise MIS,
 * after Bitterli 2021); docs/methods.md, "Reuse shared by the methods". */
#ifndef RESTIRD_REUSE_MIS_H
#define RESTIRD_REUSE_MIS_H

#include <stdint.h>

/* Generalized balance heuristic for the sample of domain `i` among `n` domains:
 * m_i = M_i p̂_i / sum_j M_j p̂_j, where p̂_j is domain j's target evaluated on the sample
 * shifted into domain j (0 when the shift fails or the target is zero there: such a domain
 * could not have produced the sample). Returns 0 when the denominator is 0. */
float reuse_mis_balance(const float *M, const float *p_hat, uint32_t n, uint32_t i);

/* Defensive pairwise MIS over one canonical domain c and k neighbours. Inputs, for neighbour
 * n's sample X_n:
 *   p_n_own       p̂_n(X_n) in its own domain
 *   p_c_shifted   p̂_c(T_{n->c}(X_n)) |J_{n->c}|  (0 if the shift failed)
 * and for the canonical sample Y_c, per neighbour n:
 *   p_c_own       p̂_c(Y_c)
 *   p_n_shifted   p̂_n(T_{c->n}(Y_c)) |J_{c->n}|  (0 if the shift failed)
 * Neighbour n's weight:  (M_n p_n_own / (M_n p_n_own + (M_c/k) p_c_shifted)) / (k + 1).
 * Canonical weight:      (1 + sum_n (1 - t_n)) / (k + 1),
 *                        t_n = M_n p_n_shifted / (M_n p_n_shifted + (M_c/k) p_c_own).
 * For any sample the weights of the domains that can produce it sum to 1, so the GRIS estimate
 * stays unbiased; k >= 1 is the same nominal neighbour count in every term (a neighbour whose
 * shift failed still counts in k; with no neighbour there is nothing to weigh). */
float reuse_mis_pairwise_neighbor(float M_c, float M_n, float p_n_own, float p_c_shifted, uint32_t k);
/* One neighbour's term 1 - t_n of the canonical weight (add them up, then call
 * reuse_mis_pairwise_canonical). */
float reuse_mis_pairwise_canonical_term(float M_c, float M_n, float p_c_own, float p_n_shifted, uint32_t k);
float reuse_mis_pairwise_canonical(float sum_of_terms, uint32_t k);

#endif
