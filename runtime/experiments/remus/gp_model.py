"""The GP process model of seed 004: NARX training data from run 1, one GP per state increment.

Training data (seed 004 section 6): from the 5 Hz log of run 1, the NARX input [eta_k, u_k]
and the target eta_{k+1} - eta_k (increments: see symbolic/filters/gp_ukf.py), where eta is
the paper's 12-vector. The sensors give u v w p q r z phi theta psi; x and y have no sensor
and the paper does not say where its X, Y training values came from: a simulation has only
the true ones, which are used. psi is wrapped, its increment too.

Subsampling: the paper takes "40 % of the data randomly, more points at the start". Here the
40 % pool is drawn without replacement with a density falling linearly to a quarter of its
initial value at the end of the run; the GP's regressors are ``n_train`` points drawn from that
pool (a subset of regressors: the generated C holds N(N+1)/2 numbers per GP; the measured
size/accuracy trade-off is at experiment.N_TRAIN). ``density_at_end=1`` samples uniformly instead.

Features are standardised (mean/std of the pool) before the GP, so one length-scale range
suits every input; the standardisation is part of the generated feature map. Kernel:
ConstantKernel * RBF (ARD, one length scale per input) + WhiteKernel, normalize_y=True,
hyperparameters by maximising the log marginal likelihood (scikit-learn, L-BFGS-B, no restarts).
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from ...extras import require
from .scenario import HelixLog, wrap

POOL_FRACTION = 0.4
DENSITY_AT_END = 0.25   # sampling density at t = T relative to t = 0


@dataclass
class GPProcessModel:
    """Fitted GPs of the 12 state increments and the feature standardisation."""

    gprs: list                 # 12 fitted sklearn GaussianProcessRegressor
    feature_mean: np.ndarray   # (15,)
    feature_std: np.ndarray    # (15,)
    dt: float                  # the step the increments are over (s)
    n_train: int
    train_seconds: float
    train_times: np.ndarray    # log times of the regressors (for Fig. 3)
    pool_times: np.ndarray
    features: str = "paper"    # see FEATURES


def narx_state(log: HelixLog) -> np.ndarray:
    """(T, 12) [u v w p q r x y z phi theta psi]: sensor values, with the true x and y."""
    s = np.empty((len(log.t), 12))
    s[:, 0:6] = log.z[:, 0:6]
    s[:, 6:8] = log.x[:, 6:8]
    s[:, 8:12] = log.z[:, 6:10]
    return s


#: GP input features: "paper" = [eta, u] (seed 004: 15 inputs, psi wrapped to (-pi, pi]);
#: "trig" = [eta without psi, cos psi, sin psi, u] (16 inputs: no jump where psi wraps).
FEATURES = ("paper", "trig")


def feature_rows(eta: np.ndarray, u: np.ndarray, features: str = "paper") -> np.ndarray:
    """GP inputs of states eta (T, 12) and inputs u (T, 3) (the generated feature map does the same)."""
    if features == "paper":
        return np.hstack([eta[:, :11], wrap(eta[:, 11:12]), u])
    if features == "trig":
        return np.hstack([eta[:, :11], np.cos(eta[:, 11:12]), np.sin(eta[:, 11:12]), u])
    raise ValueError(f"features must be one of {FEATURES}, got {features!r}")


def narx_data(log: HelixLog, features: str = "paper") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(inputs (T-1, d) = features of [eta_k, u_k], increments (T-1, 12), times (T-1,))."""
    s = narx_state(log)
    d = s[1:] - s[:-1]
    d[:, 9:12] = wrap(d[:, 9:12])
    return feature_rows(s[:-1], log.u[:-1], features), d, log.t[:-1]


def training_subset(times: np.ndarray, n_train: int, seed: int = 4,
                    density_at_end: float = DENSITY_AT_END) -> tuple[np.ndarray, np.ndarray]:
    """(pool indices, regressor indices): the 40 % pool, denser at the start, then n_train of it."""
    rng = np.random.default_rng(seed)
    T = times[-1] if times[-1] > 0 else 1.0
    density = 1.0 - (1.0 - density_at_end) * times / T
    n_pool = int(round(POOL_FRACTION * len(times)))
    pool = np.sort(rng.choice(len(times), size=n_pool, replace=False, p=density / density.sum()))
    regressors = np.sort(rng.choice(pool, size=min(n_train, n_pool), replace=False))
    return pool, regressors


def fit(log: HelixLog, n_train: int = 100, seed: int = 4, features: str = "paper",
        density_at_end: float = DENSITY_AT_END) -> GPProcessModel:
    """Fit the 12 GPs on run `log` (run 1 in the paper)."""
    ConvergenceWarning = require("sklearn.exceptions", "the GP process model").ConvergenceWarning
    GaussianProcessRegressor = require("sklearn.gaussian_process", "the GP process model").GaussianProcessRegressor
    kernels = require("sklearn.gaussian_process.kernels", "the GP process model")
    RBF, ConstantKernel, WhiteKernel = kernels.RBF, kernels.ConstantKernel, kernels.WhiteKernel

    inputs, targets, times = narx_data(log, features)
    pool, idx = training_subset(times, n_train, seed, density_at_end)
    mu, sd = inputs[pool].mean(axis=0), inputs[pool].std(axis=0)
    sd[sd == 0] = 1.0
    X = (inputs[idx] - mu) / sd
    t0 = time.perf_counter()
    gprs = []
    for i in range(targets.shape[1]):
        kernel = (ConstantKernel(1.0, (1e-3, 1e3)) * RBF(np.full(X.shape[1], 3.0), (1e-2, 1e4))
                  + WhiteKernel(1e-2, (1e-8, 1e1)))
        with warnings.catch_warnings():  # noise-only increments (u..r) drive length scales to their bounds
            warnings.simplefilter("ignore", ConvergenceWarning)
            gprs.append(GaussianProcessRegressor(kernel, normalize_y=True, random_state=seed).fit(X, targets[idx, i]))
    return GPProcessModel(gprs, mu, sd, log.dt, len(idx), time.perf_counter() - t0, times[idx], times[pool], features)
