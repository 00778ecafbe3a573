"""Symbolic filter algebra that is generated: the GP-UKF's learned predict.

Every filter's algebra on a model (EKF, UKF, CKF, the robust updates, the per-particle proposals,
smoothing) is written once in the C runtime (runtime/c/abyssal_kalman_steps.c), generic over the
dimensions, and reaches a model only through its generated f, F, G, each sensor's h and H and the
structure-of-arrays kernels. The one exception lives here: seed 004's GP-UKF predict
(``gp_ukf.py``), whose "model" is a learned Gaussian process with its training data as run-time
inputs, on the sigma-point rules of ``sigma_points.py`` and the guarded Cholesky of ``linalg.py``.
"""
