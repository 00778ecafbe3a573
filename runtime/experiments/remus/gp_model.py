"""The GP process model of seed 004: NARX training data from run 1, one GP per state, several draws and sizes.

Training data (seed 004 section 6): from the 5 Hz log of run 1, the NARX input [eta_k, u_k] and a
target per state, where eta is the paper's 12-vector. The sensors give u v w p q r z phi theta psi;
x and y have no sensor and the paper does not say where its X, Y training values came from: a
simulation has only the true ones, which are used. psi is wrapped in the input.

Targets (TARGETS): "increments", eta_{k+1} - eta_k (Ko et al.; psi's wrapped), or "state", eta_{k+1}
(Deisenroth's gpukf.m, which seed 004 cites) -- except psi, whose GP predicts its increment in both: a
next heading in (-pi, pi] jumps by 2 pi where the helix crosses +-pi (three times per run), which no
smooth GP can follow (abyssal.symbolic.filters.gp_ukf, ``increments``).

A draw (the paper's "40 % of the data taken randomly, more points at the start"): the 40 % pool drawn
without replacement with a density falling linearly to DENSITY_AT_END of its initial value at the end
of the run, then a random order of the pool; the GPs of size N use the first N points of that order
(so one draw's sizes are nested, and N = the pool's size is the paper's 40 %: 1600 points of 800 s).
The draw's seed names it (the seed of numpy's default_rng).

Hyperparameters (ConstantKernel * RBF (ARD, one length scale per input) + WhiteKernel, normalize_y)
maximise the log marginal likelihood (LML; scikit-learn, L-BFGS-B) on the first min(N, hyper_max) points of the
draw, from several starts (``fit_gp``), keeping the fit of the largest LML: the default start (length scales 3,
signal 1, noise 1e-2), the optimum of the next smaller size (a warm start, when there is one) and ``restarts``
random starts drawn log-uniformly inside the bounds (scikit-learn's rule for its n_restarts_optimizer, from a
generator seeded by the draw, the size and the GP). One start is not enough: a GP can stall at the noise-only
optimum (length scales at their upper bound, the targets explained as noise), seen on draw 5's y increments at
N = 400 from the warm start, 3600 nats below the default start's fit on the same points. Every GP's chosen LML and
each start's are kept in the TrainingSet (``lml``, ``start_lml``). A GP of more than hyper_max regressors is then
conditioned on all N with those hyperparameters. This is ours: scikit-learn's gradient holds an N x N x (d + 2)
array (350 MB at N = 1600) and its optimisation of 12 GPs at N = 1600 takes hours.

Features are standardised with the mean/std of the pool (part of the GP's run-time data).

A TrainingSet (the regressors, targets, hyperparameters, standardisation: kilobytes) is saved to an
.npz file that a campaign worker reads; ``runtime_data`` conditions the GPs there (Cholesky with one
BLAS thread, so every process computes the same bits) and returns the filter's data arrays.
"""
from __future__ import annotations

import functools
import hashlib
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...extras import require
from .scenario import HelixLog, wrap

POOL_FRACTION = 0.4
DENSITY_AT_END = 0.25   # sampling density at t = T relative to t = 0
HYPER_MAX = 400         # hyperparameters from at most this many regressors (module docstring)
TARGETS = ("increments", "state")
PSI = 11
#: GP input features: "paper" = [eta, u] (seed 004: 15 inputs, psi wrapped to (-pi, pi]);
#: "trig" = [eta without psi, cos psi, sin psi, u] (16 inputs: no jump where psi wraps).
FEATURES = ("paper", "trig")
#: the kernel's starting hyperparameters and bounds
LENGTH_SCALE, LENGTH_BOUNDS = 3.0, (1e-2, 1e4)
SIGNAL, SIGNAL_BOUNDS = 1.0, (1e-3, 1e3)
NOISE, NOISE_BOUNDS = 1e-2, (1e-8, 1e1)
#: random starts of every hyperparameter fit, besides the default start and the warm start (fit_gp)
RESTARTS = 1
#: the starts' names, in the order of TrainingSet.start_lml's columns (random starts are "random 1", ...)
START_NAMES = ("default", "warm")


def narx_state(log: HelixLog) -> np.ndarray:
    """(T, 12) [u v w p q r x y z phi theta psi]: sensor values, with the true x and y."""
    s = np.empty((len(log.t), 12))
    s[:, 0:6] = log.z[:, 0:6]
    s[:, 6:8] = log.x[:, 6:8]
    s[:, 8:12] = log.z[:, 6:10]
    return s


def feature_rows(eta: np.ndarray, u: np.ndarray, features: str = "paper") -> np.ndarray:
    """GP inputs of states eta (T, 12) and inputs u (T, 3) (the generated feature map does the same)."""
    if features == "paper":
        return np.hstack([eta[:, :11], wrap(eta[:, 11:12]), u])
    if features == "trig":
        return np.hstack([eta[:, :11], np.cos(eta[:, 11:12]), np.sin(eta[:, 11:12]), u])
    raise ValueError(f"features must be one of {FEATURES}, got {features!r}")


def narx_data(log: HelixLog, features: str = "paper", targets: str = "increments"):
    """(inputs (T-1, d) = features of [eta_k, u_k], targets (T-1, 12), times (T-1,)) (module docstring)."""
    if targets not in TARGETS:
        raise ValueError(f"targets must be one of {TARGETS}, got {targets!r}")
    s = narx_state(log)
    if targets == "increments":
        y = s[1:] - s[:-1]
        y[:, 9:12] = wrap(y[:, 9:12])
    else:
        y = s[1:].copy()
        y[:, PSI] = wrap(s[1:, PSI] - s[:-1, PSI])
    return feature_rows(s[:-1], log.u[:-1], features), y, log.t[:-1]


def increments_of(targets: str) -> tuple[int, ...]:
    """The states whose GP predicts an increment (abyssal.symbolic.filters.gp_ukf)."""
    return tuple(range(12)) if targets == "increments" else (PSI,)


def draw_order(times: np.ndarray, seed: int, density_at_end: float = DENSITY_AT_END) -> tuple[np.ndarray, np.ndarray]:
    """(pool indices (sorted), the pool in a random order) of one draw (module docstring)."""
    rng = np.random.default_rng(seed)
    T = times[-1] if times[-1] > 0 else 1.0
    density = 1.0 - (1.0 - density_at_end) * times / T
    n_pool = int(round(POOL_FRACTION * len(times)))
    pool = np.sort(rng.choice(len(times), size=n_pool, replace=False, p=density / density.sum()))
    return pool, rng.permutation(pool)


def pool_size(duration: float, dt: float = 0.2) -> int:
    """Points in the 40 % pool of a run of `duration` s logged every dt."""
    return int(round(POOL_FRACTION * round(duration / dt)))


@dataclass
class TrainingSet:
    """One draw's GPs of one size and target kind: what ``runtime_data`` conditions (module docstring)."""

    X: np.ndarray              # (N, d) standardised inputs of the regressors
    Y: np.ndarray              # (N, 12) targets
    theta: np.ndarray          # (12, d + 2) log hyperparameters (scikit-learn's kernel.theta) per GP
    feature_mean: np.ndarray   # (d,)
    feature_std: np.ndarray    # (d,)
    times: np.ndarray          # (N,) log times of the regressors (figures)
    pool_times: np.ndarray
    dt: float                  # s, the step the targets are over
    train_seconds: float       # hyperparameter optimisation of this set (0: reused a smaller size's)
    targets: str = "increments"
    features: str = "paper"
    draw: int = 0
    lml: np.ndarray | None = None        # (12,) the chosen fit's log marginal likelihood per GP (on the fit's points)
    start_lml: np.ndarray | None = None  # (12, starts) each start's optimum (NaN: no warm start), START_NAMES order

    @property
    def n_train(self) -> int:
        return self.X.shape[0]

    def save(self, path: Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.stem + ".tmp.npz")
        np.savez(tmp, X=self.X, Y=self.Y, theta=self.theta, feature_mean=self.feature_mean,
                 feature_std=self.feature_std, times=self.times, pool_times=self.pool_times,
                 scalars=np.array([self.dt, self.train_seconds, self.draw]), labels=np.array([self.targets, self.features]),
                 lml=np.full(12, np.nan) if self.lml is None else self.lml,
                 start_lml=np.full((12, 0), np.nan) if self.start_lml is None else self.start_lml)
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: Path) -> "TrainingSet":
        with np.load(path) as f:
            dt, seconds, draw = f["scalars"]
            targets, features = (str(v) for v in f["labels"])
            return cls(f["X"], f["Y"], f["theta"], f["feature_mean"], f["feature_std"], f["times"], f["pool_times"],
                       float(dt), float(seconds), targets, features, int(draw),
                       f["lml"] if "lml" in f else None, f["start_lml"] if "start_lml" in f else None)


def kernel(d: int):
    """ConstantKernel * RBF (ARD over d inputs) + WhiteKernel with this module's start values and bounds."""
    kernels = require("sklearn.gaussian_process.kernels", "the GP process model")
    return (kernels.ConstantKernel(SIGNAL, SIGNAL_BOUNDS) * kernels.RBF(np.full(d, LENGTH_SCALE), LENGTH_BOUNDS)
            + kernels.WhiteKernel(NOISE, NOISE_BOUNDS))


def _regressor(theta: np.ndarray | None, d: int, optimise: bool, seed: int):
    GaussianProcessRegressor = require("sklearn.gaussian_process", "the GP process model").GaussianProcessRegressor
    k = kernel(d) if theta is None else kernel(d).clone_with_theta(theta)
    return GaussianProcessRegressor(k, normalize_y=True, random_state=seed, optimizer="fmin_l_bfgs_b" if optimise else None)


@dataclass(frozen=True)
class GPFit:
    """One GP's hyperparameter fit from several starts: the chosen theta (the largest LML) and every start's LML."""

    theta: np.ndarray        # (d + 2,) log hyperparameters (scikit-learn's kernel.theta)
    lml: float               # its log marginal likelihood
    start_lml: np.ndarray    # (starts,) each start's optimum, in the order of the starts given
    chosen: int              # the index of the start whose optimum was kept


def random_starts(d: int, count: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``count`` log-hyperparameter vectors drawn uniformly in the log of the kernel's bounds (scikit-learn's rule)."""
    bounds = kernel(d).bounds  # (d + 2, 2), log
    return [rng.uniform(bounds[:, 0], bounds[:, 1]) for _ in range(count)]


def fit_gp(X: np.ndarray, y: np.ndarray, starts, seed: int = 0) -> GPFit:
    """Maximise the LML from each start (None: skipped, its LML NaN) and keep the best (module docstring)."""
    ConvergenceWarning = require("sklearn.exceptions", "the GP process model").ConvergenceWarning
    d = X.shape[1]
    lmls, thetas = [], []
    for start in starts:
        if start is None:
            lmls.append(np.nan), thetas.append(None)
            continue
        with warnings.catch_warnings():  # noise-only targets (u..r) drive length scales to their bounds
            warnings.simplefilter("ignore", ConvergenceWarning)
            gp = _regressor(np.asarray(start, dtype=float), d, True, seed).fit(X, y)
        lmls.append(float(gp.log_marginal_likelihood_value_)), thetas.append(gp.kernel_.theta)
    lml = np.array(lmls)
    chosen = int(np.nanargmax(lml))
    return GPFit(thetas[chosen], float(lml[chosen]), lml, chosen)


def fit_draw(log: HelixLog, draw: int, sizes, *, targets: str = "increments", features: str = "paper",
             hyper_max: int = HYPER_MAX, density_at_end: float = DENSITY_AT_END, restarts: int = RESTARTS,
             say=None) -> dict[int, TrainingSet]:
    """The TrainingSets of one draw at each size in `sizes` (each at most the pool's size), run 1 = `log`."""
    say = say or (lambda message: None)
    inputs, outputs, times = narx_data(log, features, targets)
    pool, order = draw_order(times, draw, density_at_end)
    mu, sd = inputs[pool].mean(axis=0), inputs[pool].std(axis=0)
    sd[sd == 0] = 1.0
    standardised = (inputs - mu) / sd
    sizes = sorted({min(int(n), len(pool)) for n in sizes})
    d = inputs.shape[1]
    default = kernel(d).theta
    fits, seconds, theta = {}, {}, None
    for n in sorted({min(n, hyper_max) for n in sizes}):
        idx = order[:n]
        t0 = time.perf_counter()
        fitted = []
        for i in range(12):
            rng = np.random.default_rng([draw, n, i, TARGETS.index(targets)])
            starts = [default, None if theta is None else theta[i], *random_starts(d, restarts, rng)]
            fitted.append(fit_gp(standardised[idx], outputs[idx, i], starts, draw))
        theta = np.array([f.theta for f in fitted])
        fits[n], seconds[n] = fitted, time.perf_counter() - t0
        won = [START_NAMES[f.chosen] if f.chosen < len(START_NAMES) else "random" for f in fitted]
        say(f"draw {draw}, {targets}: hyperparameters of 12 GPs on {n} regressors, {2 + restarts} starts each, in "
            f"{seconds[n]:.1f} s (the chosen start: {', '.join(f'{w} {won.count(w)}' for w in dict.fromkeys(won))})")
    out = {}
    for n in sizes:
        m = min(n, hyper_max)
        idx = np.sort(order[:n])
        out[n] = TrainingSet(standardised[idx], outputs[idx], np.array([f.theta for f in fits[m]]), mu, sd, times[idx],
                             times[pool], log.dt, seconds[m] if n == m else 0.0, targets, features, draw,
                             np.array([f.lml for f in fits[m]]), np.array([f.start_lml for f in fits[m]]))
    return out


def regressors(training: TrainingSet) -> list:
    """The 12 fitted scikit-learn GPs of a TrainingSet (conditioned, hyperparameters fixed; one BLAS thread)."""
    threadpoolctl = require("threadpoolctl", "the GP process model")
    out = []
    with threadpoolctl.threadpool_limits(1), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i in range(12):
            out.append(_regressor(training.theta[i], training.X.shape[1], False, training.draw)
                       .fit(training.X, training.Y[:, i]))
    return out


@functools.lru_cache(maxsize=8)
def runtime_data(path: str, digest: str) -> tuple:
    """(GPLayout, the GP-UKF predict's data arrays: feature shift, scale, then gp.gp_data's) of the TrainingSet at `path`;
    cached per process by (path, its sha256), so a worker conditions each set once."""
    from abyssal.symbolic import gp

    training = TrainingSet.load(Path(path))
    layout, data = gp.gp_data(regressors(training))
    shift, scale = training.feature_mean.copy(), training.feature_std.copy()
    return layout, (shift, scale, *data)


def file_digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
