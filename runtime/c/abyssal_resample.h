/* abyssal_resample.h: resampling of weighted particles from the caller's uniforms, in C (C99).
 *
 * The schemes of runtime/resampling (schemes.py, kld.py) take their uniforms from the filter's numpy Generator;
 * these functions take the same uniforms and return the same ancestors, bit for bit, without the Python around
 * them. The SIR step's own systematic and stratified resampling (abyssal_sir.h) draws its uniforms itself.
 *
 *   inverse CDF  cdf = the cumulative sums of w in order, divided by the last; the ancestor of a uniform u is the
 *                first i with cdf[i] > u (numpy's searchsorted, side "right"), and for a u at or beyond the last
 *                (1.0 after rounding) the last particle of positive weight;
 *   systematic   the inverse CDF of (k + u0) / m, k = 0 .. m - 1;
 *   multinomial  the inverse CDF of the m uniforms sorted (ancestors in increasing order);
 *   KLD          Fox's KLD-sampling (kld.py): categorical draws (the first i with cdf[i] > u, at most n - 1) until the
 *                number of draws reaches the clamped bound of the bins they occupy, limit[k]. A particle's bin is the
 *                tuple of floor(clip(x_d / width_d, +-1e300)) along the binned rows, relative to the cloud's lowest
 *                one along each row; only the drawn particles are binned, into a hash set of the occupied bins (no
 *                renumbering of all particles). The uniforms come in chunks: a draw stops within a chunk.
 *
 * Gathers copy the ancestors' columns of particle rows, or their per-particle blocks (a carried covariance).
 */
#ifndef ABYSSAL_RESAMPLE_H
#define ABYSSAL_RESAMPLE_H

#include <stddef.h>

typedef long long abyssal_count;

/* ancestors (m) of sorted uniforms u (m) in [0, 1] by the inverse CDF of the normalised weights w (n); cdf: n doubles
 * of scratch */
void abyssal_resample_inverse_cdf(abyssal_count n, const double* w, abyssal_count m, const double* u,
                                  abyssal_count* ancestors, double* cdf);
/* m systematic ancestors from the one uniform u0 */
void abyssal_resample_systematic(abyssal_count n, const double* w, abyssal_count m, double u0, abyssal_count* ancestors,
                                 double* cdf);
/* m multinomial ancestors from m uniforms in [0, 1) (sorted in place); cdf: n doubles, order: m + 1 counts of
 * scratch */
void abyssal_resample_multinomial(abyssal_count n, const double* w, abyssal_count m, double* u, abyssal_count* ancestors,
                                  double* cdf, abyssal_count* order);

/* KLD-sampling's state, in caller memory of abyssal_kld_bytes(n, n_max, dims) bytes (8-byte aligned), reused from
 * draw to draw (zeroed once, when first allocated). */
size_t abyssal_kld_bytes(abyssal_count n, abyssal_count n_max, int dims);
/* Start a resampling of n particles with weights w: the binned rows (dims of them) of the states at states[d * ld + j],
 * their bin widths, the clamp (n_min <= draws <= n_max) and limit (n_max + 1 entries: limit[k] for k occupied bins).
 * Returns 0, -1 when a binned state is not finite, -2 for a bad argument. */
int abyssal_kld_start(void* memory, size_t bytes, abyssal_count n, const double* w, const double* states,
                      abyssal_count ld, int dims, const double* widths, abyssal_count n_max, const long long* limit);
/* Draw count more ancestors from the uniforms u (count) into ancestors (at the draws so far): the number of
 * ancestors when the draws stopped (the bound is reached, or n_max), 0 when more uniforms are needed. */
abyssal_count abyssal_kld_draw(void* memory, const double* u, abyssal_count count, abyssal_count* ancestors);

/* dst[r * ld_dst + k] = src[r * ld_src + ancestors[k]] for rows r < rows, k < m */
void abyssal_gather_rows(int rows, abyssal_count m, const abyssal_count* ancestors, const double* src,
                         abyssal_count ld_src, double* dst, abyssal_count ld_dst);
/* dst[k * size .. + size] = src[ancestors[k] * size .. + size] for k < m (dst may not overlap src) */
void abyssal_gather_items(abyssal_count m, const abyssal_count* ancestors, abyssal_count size, const double* src,
                          double* dst);

#endif /* ABYSSAL_RESAMPLE_H */
