/* abyssal_proposal.h: the carried Gaussian proposal of the particle filters (the CPF's carried cubature proposal,
 * the UPF's, HRUPF's and MCUPF's unscented ones): one call moves every particle, on the Kalman runtime's algebra
 * (abyssal_kalman_steps.h) and the model's descriptor (abyssal_model.h). Hand-written C99.
 *
 * Every particle i carries a covariance P^i. One step (ABYSSAL_PROPOSAL_STEP), for the n particles x^i_{k-1}:
 *
 *   means    f^i = f(x^i_{k-1}, u) of every particle, one call of the model's structure-of-arrays f;
 *   predict  (x^i_{k-1}, P^i) -> (m^i_-, P^i_-) by the filter's rule (CKF, or the scaled unscented rule), as the
 *            runtime's batched steps compute it (abyssal_steps_batch: P, Q and R symmetrised); a particle whose
 *            Cholesky guard fails is predicted again from its repaired covariance (abyssal_repair_covariance);
 *   update   (m^i_-, P^i_-) with the present entries of z - E[v] -> (m^i, P^i_+, nu^i, S^i) (CKF, UKF, MCUKF or
 *            Huber), repaired as the predict; with guard_sigma finite, entries beyond guard_sigma standard
 *            deviations of a particle's S^i are left out of that particle's update (the cloud gate is then off);
 *   gate     the innovation gate on the cloud's predicted measurement (the SIR engine's screen, engine.py):
 *            nu = sum_i w_i nu^i, S = sum_i w_i S^i + sum_i w_i (nu^i - nu)(nu^i - nu)^T, w the prior weights
 *            (uniform when the committed weights are not them), tested by the filter's gate (abyssal_gate_judge,
 *            settled at once when nu^T R^-1 nu passes); the entries it leaves out are left out of every update,
 *            which is redone from the kept predictions (the predict is not redone); admitted entries (the gate's
 *            re-acquisition) are used while they fail;
 *   draw     x^i_k = f^i + V y^i, y^i = V^T (m^i - f^i) + L^i xi^i with L^i L^i^T = V^T P^i_+ V (repaired when it is
 *            not positive definite), xi^i the caller's standard normals and V the basis of the process noise's
 *            positive-definite subspace (its support rows, or a dense basis); the log importance ratio
 *            log N(V^T (x^i_k - f^i); 0, Lambda) - log N(xi^i; 0, I) + log det L^i on that subspace. A particle whose
 *            update failed its guards on a repaired covariance proposes from its prediction (m^i_-, P^i_-).
 *            When the gate leaves every entry out, the particles move by the transition, x^i_k = f^i + V sqrt(Lambda)
 *            xi^i, and P^i becomes P^i_-.
 *
 * ABYSSAL_PROPOSAL_PREDICT is the step without a measurement (means, predict, the transition's draw) and
 * ABYSSAL_PROPOSAL_SCREEN an update alone's gate (the particles do not move: residuals z - E[v] - h(x^i), S^i = R).
 * The weights, moments and resampling of the moved particles are the SIR step's (abyssal_sir.h, its proposals'
 * move), whose buffers this call shares: it reads the committed particles and weights and writes the proposals and
 * their log ratios there, and writes the next carried covariances into the other one of its two buffers. It writes
 * nothing a caller has committed, so a step the caller refuses has nothing to undo. No allocation, no global state.
 *
 * Layouts: particles as the SIR step's, row r of particle j at r * ld + j; carried covariances n_x * n_x per
 * particle, column-major, particle j at j * n_x * n_x; Q, R column-major; the normals row-major (rank, n).
 */
#ifndef ABYSSAL_PROPOSAL_H
#define ABYSSAL_PROPOSAL_H

#include "abyssal_model.h"

#ifdef __cplusplus
extern "C" {
#endif

enum { ABYSSAL_PROPOSAL_STEP = 0, ABYSSAL_PROPOSAL_PREDICT = 1, ABYSSAL_PROPOSAL_SCREEN = 2 };

/* return codes */
enum {
  ABYSSAL_PROPOSAL_OK = 0,
  ABYSSAL_PROPOSAL_BAD_ARGUMENT = 1,        /* sizes, pointers or the mode out of range */
  ABYSSAL_PROPOSAL_NONFINITE_PREDICTION = 2 /* a predicted covariance is not finite (a predict without update) */
};

/* The step's inputs, in[]: these scalars, then u (n_u), z (n_y), present (n_y) and admit (n_y) (flags 1 / 0). */
enum {
  ABYSSAL_PROPOSAL_IN_MODE,    /* ABYSSAL_PROPOSAL_STEP, _PREDICT or _SCREEN */
  ABYSSAL_PROPOSAL_IN_COUNT,   /* particles this step (1 .. capacity) */
  ABYSSAL_PROPOSAL_IN_CUR,     /* the committed particle buffer (0 .. 2); the proposals go to cur + 1 (mod 3) */
  ABYSSAL_PROPOSAL_IN_SIDE,    /* the committed side of the weights (0, 1) */
  ABYSSAL_PROPOSAL_IN_PRIOR,   /* 1: the committed weights are the prior weights; 0: the prior is uniform */
  ABYSSAL_PROPOSAL_IN_CARRIED, /* the committed carried covariances (0, 1); the next ones go to the other */
  ABYSSAL_PROPOSAL_IN_DT,
  ABYSSAL_PROPOSAL_IN_HEAD
};

/* The step's results, out[]: these scalars, then kept (n_y) and gated (n_y) (flags 1 / 0). */
enum {
  ABYSSAL_PROPOSAL_OUT_KEPT,   /* entries of z the proposal (and so the weights) used; 0: every one was left out */
  ABYSSAL_PROPOSAL_OUT_FAILED, /* particles that proposed from their prediction (update failed even when repaired) */
  ABYSSAL_PROPOSAL_OUT_HEAD
};

typedef struct {
  const abyssal_model* model;
  int filter;                  /* abyssal_filter (abyssal_kalman_steps.h): CKF, UKF, MCUKF or Huber */
  double alpha, beta, kappa;   /* the scaled unscented rule (not read for the CKF) */
  double sigma, gamma;         /* the MCC kernel's bandwidth, Huber's threshold */
  long long capacity;          /* particles the buffers hold */
  long long ld;                /* row stride of the particle buffers (>= capacity) */
  const double* p;             /* (n_p) the model's parameters */
  /* process noise: Q (n_x x n_x) and its positive-definite subspace V: rank columns, either the state rows
   * `support` (V = I[:, support]) or the dense `basis` (n_x x rank, column-major); variances: its eigenvalues */
  const double* Q;
  int rank;
  const int* support;
  const double* basis;
  const double* variances;
  double log_norm;             /* -(sum log variances + rank log 2 pi) / 2: the normalisation of N(0, Lambda) */
  /* measurement noise (its moment-matched covariance and mean) */
  const double* R;             /* (n_y x n_y) */
  const double* r_mean;        /* (n_y) */
  double guard_sigma;          /* a particle's own outlier guard (inf: none) */
  void* gate;                  /* the filter's abyssal_gate (abyssal_kalman_gate.h) */
  /* buffers */
  double* particles[3];        /* the SIR step's (n_x rows of stride ld each) */
  const double* w[2];          /* the SIR step's normalised weights, per side */
  double* log_ratio;           /* (capacity) the SIR step's proposal log ratios */
  double* carried[2];          /* (capacity * n_x * n_x) each */
  const double* normals;       /* (rank * count) the step's standard normals, row-major */
  const double* in;            /* ABYSSAL_PROPOSAL_IN_HEAD + n_u + 3 n_y */
  double* out;                 /* ABYSSAL_PROPOSAL_OUT_HEAD + 2 n_y */
  double* work;                /* abyssal_proposal_work_size() doubles */
  long long work_size;
} abyssal_proposal;

/* Doubles of work for a model, a filter, capacity particles and rows of stride ld. */
long long abyssal_proposal_work_size(const abyssal_model* model, int filter, long long capacity, long long ld);

/* One step (the top of this file); ABYSSAL_PROPOSAL_OK or an error code. */
int abyssal_proposal_step(const abyssal_proposal* s);

#ifdef __cplusplus
}
#endif

#endif /* ABYSSAL_PROPOSAL_H */
