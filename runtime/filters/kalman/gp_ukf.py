"""GP-UKF (Ko et al. 2007; seed 004 Table 2): a UKF whose prediction is learned Gaussian processes.

    gpukf = GPUKF(bundle, predict_library, "remus_gpukf_predict", x0, P0, R, gp_dt=0.2, gp_data=arrays)
    gpukf.step(u, 0.2, z)

Predict (one generated C call, abyssal.symbolic.filters.gp_ukf): sigma points of (x, P) through
the GP means of the state increments; Q_k = diag(GP predictive variance at the prior mean),
including each GP's learned noise; P_pred = points' covariance + Q_k. ``last_Q`` holds Q_k.
The GPs' data (the feature standardisation, then each GP's training matrix, weights, factor: the inputs of
abyssal.symbolic.filters.gp_ukf) are ``gp_data``, bound once: the compiled predict holds no data.

Update: the observation model. Seed 004 and Ko et al. learn an observation GP too; here the
sensors observe states directly (h is remus100's [u v w p q r z phi theta psi]), so the update
is the C runtime's UKF update (``ukf_update``) on the model bundle's h with R from the sensors (held
noise plus quantisation, LSB^2/12). This is a choice: an observation GP would only relearn the
identity plus the same noise.

On the filter contract (abyssal.runtime.contract, FilterBase): checked inputs, NaN entries of z
left out, ``step`` one transaction, refusals leave the filter unchanged; the innovation gate and
the growth limit of every Kalman-type filter (gate.py, numerics.grew_beyond); dt must equal the
step the GPs were trained on (their increments are over that step), anything else is refused.
Parameters: the learned prediction has none (the GPs were trained at fixed parameters), so
``predict(u, dt, p)`` with a p is refused rather than ignored; p is the observation model's, used
by ``update(z, p)`` and by the update of ``step(u, dt, z, p)``.
"""
from __future__ import annotations

import functools
import math

import casadi as ca
import numpy as np

from ...compiled.kalman import BatchStep
from ...contract import FilterBase, check_covariance, check_dt, check_p, check_state, register
from ...numerics import factorable_covariance, grew_beyond
from .gate import InnovationGate

__all__ = ["GPUKF"]


@register("kalman")
class GPUKF(FilterBase):
    """GP-UKF on a compiled GP predict step and a model bundle's UKF update (see module docstring).

    alpha, beta, kappa: the scaled unscented rule of both predict and update (default 1, 2, 0, as UKF).
    gate_probability, gate_patience, gate_inflation, gate_max_inflations: the innovation gate of every Kalman-type
    filter (gate.py); growth_limit: a predict whose covariance grows more than this (numerics.grew_beyond) is refused.
    """

    _state = ("_x", "_P", "nis", "nis_dof", "last_Q", "gate")

    @classmethod
    def contract_example(cls, model, *, x0=None, P0=None, n_particles=None, rng=0):
        """For the contract test: GPs of `model`'s own one-step increments (a small, quickly compiled predict)."""
        library, name, dt, data = _example_predict(model.name)
        n = model.n_x
        return cls(model, library, name, np.zeros(n) if x0 is None else x0, np.eye(n) if P0 is None else P0,
                   0.5 * np.eye(model.n_y), gp_dt=dt, gp_data=data)

    def __init__(self, model, predict_library, predict_name: str, x0, P0, R, *, gp_dt: float, gp_data=(),
                 alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0, gate_probability: float = 1e-10,
                 gate_patience: int = 5, gate_inflation: float = 4.0, gate_max_inflations: int = 10,
                 growth_limit: float = 1e3):
        if not hasattr(model, "functions") or not hasattr(model, "library"):
            raise TypeError(f"GPUKF needs a model bundle from abyssal.generated.load() (its observation model); got {model!r}")
        n, m = model.n_x, model.n_y
        if not all(math.isfinite(v) for v in (alpha, beta, kappa)) or not alpha**2 * (n + kappa) > 0:
            raise ValueError(f"sigma points need finite alpha, beta, kappa with alpha^2 (n + kappa) > 0 (n = {n})")
        if not growth_limit > 1.0:
            raise ValueError(f"growth_limit must be > 1, got {growth_limit!r}")
        self._init_contract(model)
        self.gp_dt = check_dt(gp_dt)
        self._x = check_state(x0, n, "x0")
        self._P = check_covariance(P0, n, "P0")
        self._R = check_covariance(R, m, "R", definite=True)
        self._abk = np.array([alpha, beta, kappa], dtype=float)
        # the whole P is inflated (gate.py): the learned predict forgets P grown along one entry
        self.gate = InnovationGate(self._R, probability=gate_probability, patience=gate_patience, inflation=gate_inflation,
                                   max_inflations=gate_max_inflations, along=False)
        self.growth_limit = float(growth_limit)
        self.nis, self.nis_dof = math.nan, 0
        self.last_Q = np.zeros((n, n))
        # predict: casadi.external on preallocated buffers
        self._pin = [np.zeros(n), np.zeros((n, n), order="F"), np.zeros(model.n_u), self._abk]
        self._pout = [np.zeros(n), np.zeros((n, n), order="F"), np.zeros((n, n), order="F"), np.zeros(1)]
        self._external = ca.external(predict_name, str(predict_library))
        self._gp_data = [np.asfortranarray(a, dtype=float) for a in gp_data]   # kept alive: bound below
        if self._external.n_in() != 4 + len(self._gp_data):
            raise ValueError(f"gp_data: {predict_name} takes {self._external.n_in() - 4} data arrays, got {len(self._gp_data)}")
        for i, a in enumerate(self._gp_data, start=4):
            if a.size != self._external.nnz_in(i) or not np.all(np.isfinite(a)):
                raise ValueError(f"gp_data[{i - 4}] ({self._external.name_in(i)}) must hold {self._external.nnz_in(i)} "
                                 f"finite numbers, got {a.size}{'' if np.all(np.isfinite(a)) else ' (not all finite)'}")
        self._pin += self._gp_data
        self._buffer, self._eval = self._external.buffer()
        for i, a in enumerate(self._pin):
            self._buffer.set_arg(i, memoryview(a.reshape(-1, order="F")))
        for i, a in enumerate(self._pout):
            self._buffer.set_res(i, memoryview(a.reshape(-1, order="F")))
        self._update_fn = BatchStep(model, "ukf_update")

    @property
    def gated(self) -> int:
        """Measurement entries left out by the innovation gate so far."""
        return self.gate.gated

    # ------------------------------------------------------------------ the contract's hooks (FilterBase)
    def _predict_call(self, u, dt, p) -> None:
        if p is not None:  # a malformed p is named as such first
            check_p(p, self.model)
            raise ValueError("GPUKF.predict: p is not used by a prediction (the GPs learned the dynamics at fixed "
                             "parameters); p is the observation model's: give it to update() or step(). State unchanged")
        super()._predict_call(u, dt, None)

    def _predict(self, u, dt) -> None:
        if abs(dt - self.gp_dt) > 1e-9 * self.gp_dt:
            raise ValueError(f"dt must be the GPs' training step {self.gp_dt} s (their increments are over it), got {dt}")
        self._pin[0][:] = self._x
        self._pin[1][:] = self._P
        self._pin[2][:] = u
        self._eval()
        if self._pout[3][0] != 1.0 and np.all(np.isfinite(self._P)):  # a singular P (P0 = 0): its nearest factorable
            self._pin[1][:] = factorable_covariance(self._P, self._R)
            self._eval()
        if self._pout[3][0] != 1.0:
            raise ValueError("GPUKF.predict: the generated step failed (covariance not positive definite or "
                             "non-finite outputs); state left unchanged")
        if grew_beyond(self.growth_limit, self._P, self._pout[1], self._pout[2]):
            raise ValueError(f"GPUKF.predict: the covariance grew more than {self.growth_limit:g}x in one predict (the GPs "
                             "extrapolate far outside their training data); state left unchanged")
        self._x = self._pout[0].copy()
        self._P = np.array(self._pout[1], order="F")
        self.last_Q = self._pout[2].copy()

    def _update(self, z, present) -> bool:
        result = {}

        def evaluate(entries):
            x_post, P_post, innovation, S, ok = self._update_fn(self._x, self._P, np.where(entries, z, 0.0), self._p, self._R,
                                                                 entries.astype(float), self._abk)
            if float(np.asarray(ok).reshape(-1)[0]) != 1.0:
                raise ValueError("GPUKF.update: the generated update failed; state left unchanged")
            result.update(x=np.asarray(x_post, dtype=float).reshape(-1), P=np.array(P_post, order="F"),
                          nu=np.asarray(innovation, dtype=float).reshape(-1), S=np.atleast_2d(np.asarray(S, dtype=float)))
            return result["nu"], result["S"]

        accepted, gated = self.gate.select(evaluate, present)
        if accepted is not None:
            self._x, self._P = result["x"], result["P"]
            self.nis, self.nis_dof = float(result["nu"] @ np.linalg.solve(result["S"], result["nu"])), int(accepted.sum())
        self._P = self.gate.inflated(self._P, gated, present, accepted, None)  # (whole P: no reduction asked)
        return accepted is not None


@functools.lru_cache(maxsize=None)
def _example_predict(model_name: str, dt: float = 0.5, n_train: int = 12):
    """(library, function name, dt, data) of a GP-UKF predict learned from `model_name`'s f: one GP
    (ConstantKernel x RBF + White) per state increment on n_train random (x, u) points."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    import abyssal.generated
    from abyssal.generated.build import build
    from abyssal.symbolic import gp
    from abyssal.symbolic.filters.gp_ukf import gp_ukf_predict_function

    bundle = abyssal.generated.load(model_name)
    rng = np.random.default_rng(0)
    X = rng.normal(size=(n_train, bundle.n_x))
    U = rng.normal(size=(n_train, bundle.n_u))
    increments = np.array([bundle.f(x, u, None, dt) - x for x, u in zip(X, U)])
    features = np.hstack([X, U])
    gprs = [GaussianProcessRegressor(ConstantKernel() * RBF() + WhiteKernel(1e-3, (1e-12, 1.0)), random_state=0).fit(features, y)
            for y in increments.T]
    name = f"{model_name}_contract_gpukf_predict"
    layout, data = gp.gp_data(gprs)
    fn = gp_ukf_predict_function(name, layout, bundle.n_u)
    d = layout.n_inputs
    data = (np.zeros(d), np.ones(d), *data)  # features [x; u] as they are
    return build(name, {f"{name}.c": gp.c_source([fn])}, symbols=(name,)), name, dt, data
