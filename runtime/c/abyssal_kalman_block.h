/* abyssal_kalman_block.h: the sigma-point predict and update of ABYSSAL_BLOCK Gaussians at once, structure-of-arrays
 * across them (the particles of a particle filter's carried proposal). Hand-written C99.
 *
 * The algebra is abyssal_kalman_steps.h's sigma-point predict and update (CKF, UKF, MCUKF, Huber), operation for
 * operation and sum for sum in the same order, with every scalar of one Gaussian replaced by a vector of the block's
 * ABYSSAL_BLOCK lanes: a lane's results are those of abyssal_predict_gaussian / abyssal_update_gaussian on that
 * Gaussian (the runtime compiles without floating-point contraction, so the same order gives the same bits; the
 * model's kernels see the block's points in other vector lanes, where libmvec and libm may differ in the last bit).
 * One call evaluates f (or each sensor's h) once over the block's points: 2n (+1) points times ABYSSAL_BLOCK.
 *
 * Layout: entry e of a lane-vector quantity at v[e * ABYSSAL_BLOCK + lane]; a matrix (column-major, r rows) entry
 * (i, k) is entry e = i + k r. Every lane is computed: a caller with fewer Gaussians fills the other lanes with a
 * valid one. ok[lane] is 1.0 when every Cholesky guard of that lane passed and its results are finite, else 0.0
 * (the caller repairs and redoes that Gaussian alone, e.g. with abyssal_kalman_steps.h). The measurement mask
 * (present) and z, Q, R, u, p, dt are shared by the block. Q and R exactly symmetric, P exactly symmetric per lane.
 */
#ifndef ABYSSAL_KALMAN_BLOCK_H
#define ABYSSAL_KALMAN_BLOCK_H

#include <stddef.h>

#include "abyssal_kalman_steps.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Gaussians per block: one 8-lane vector (AVX-512), two 4-lane ones (AVX2); a block's partial sums stay in registers */
#define ABYSSAL_BLOCK 8

/* Bytes of scratch a predict or an update of one block needs (8-byte aligned memory). */
size_t abyssal_block_scratch_bytes(const abyssal_model* model, abyssal_filter filter);

/* The sigma-point predict of a block: x (n), P (n x n) -> x_pred, P_pred, ok. */
void abyssal_block_predict(const abyssal_model* model, const abyssal_algebra* algebra, const double* wm,
                           const double* wc, const double* x, const double* P, const double* u, const double* p,
                           double dt, const double* Q, double* x_pred, double* P_pred, double* ok, void* scratch);

/* The sigma-point update of a block with the stacked measurement of every sensor: x (n), P (n x n), z (n_y, shared),
 * present (n_y flags, shared), R (n_y x n_y, shared) -> x_post, P_post, innovation (n_y), S (n_y x n_y) in
 * abyssal_update_gaussian's reporting convention, ok. */
void abyssal_block_update(const abyssal_model* model, const abyssal_algebra* algebra, const double* wm,
                          const double* wc, const double* x, const double* P, const double* z,
                          const unsigned char* present, const double* p, const double* R, double* x_post,
                          double* P_post, double* innovation, double* S, double* ok, void* scratch);

/* L L^T = A (r x r lanes, lower; the upper triangle zeroed) as LAPACK's Cholesky factorisation: ok[lane] = 0 (and
 * that lane's L unspecified) where a pivot is not positive or not finite; the others are left as they are. */
void abyssal_block_factor(int r, const double* A, double* L, double* ok);

#ifdef __cplusplus
}
#endif

#endif /* ABYSSAL_KALMAN_BLOCK_H */
