"""An asynchronous extended Kalman filter in NumPy, written from the textbook equations: the reference that abyssal's
EKF (C runtime, generated C) is checked against on the dive's asynchronous and delayed stream.

Nothing of abyssal's filters or generated C is used: the model's xdot = f(x, u, p, w) and each sensor's h_k(x, p) come
from the symbolic Model through CasADi's own Functions (CasADi's virtual machine evaluates them), and everything else
is here.

Discretisation (the model's: classic RK4 in `substeps` equal steps, u and the noise w held over the step). The state
Jacobian F = dx+/dx and the noise Jacobian G = dx+/dw of the step are the exact derivatives of the RK4 formulas by the
chain rule (stage by stage, with A = df/dx and B = df/dw at each stage's point):

    k1 = f(x)              dk1 = A1 [I | 0] + [0 | B1]
    k2 = f(x + h/2 k1)     dk2 = A2 ([I | 0] + h/2 dk1) + [0 | B2]         (likewise k3, and k4 with h)
    x+ = x + h/6 (k1 + 2 k2 + 2 k3 + k4),   [F | G] = [I | 0] + h/6 (dk1 + 2 dk2 + 2 dk3 + dk4)

and substeps chain: F = F_2 F_1, G = F_2 G_1 + G_2.

Predict over dt with noise inputs of power spectral density Qc (w held over the step, covariance Qc / dt):
    x- = f_d(x),  P- = F P F^T + G (Qc / dt) G^T
Update of sensor k with z, R:   nu = z - h_k(x) (angle outputs wrapped to (-pi, pi]), S = H P H^T + R,
    K = P H^T S^-1,  x+ = x + K nu,  P+ = (I - K H) P (I - K H)^T + K R K^T   (Joseph form)

Time. The filter is a list of events -- predicts to a time with the input held since the previous one, and sensor
updates at a time -- with the state after each. Inputs are piecewise constant between the predicts' times. A
measurement stamped before the filter's time is inserted at its stamp: after the last event at or before the stamp,
splitting the predict that spans it into two predicts with that predict's input; every later event is then run again
from the state before the insertion. (No innovation gate: a check compares runs in which the gate never acts.)
"""
from __future__ import annotations

import casadi as ca
import numpy as np


def wrap(angle):
    """Angles to (-pi, pi]."""
    return np.pi - np.mod(np.pi - angle, 2 * np.pi)


class CasadiModel:
    """The Model's f, df/dx, df/dw and each sensor's h_k, dh_k/dx as CasADi Functions (evaluated by CasADi)."""

    def __init__(self, model):
        self.n, self.n_w = model.x.numel(), model.w.numel()
        self.substeps = model.substeps
        if model.discretisation != "rk4":
            raise ValueError("this reference integrates with RK4 only")
        self.dynamics = ca.Function("dynamics", [model.x, model.u, model.p, model.w],
                                    [model.xdot, ca.jacobian(model.xdot, model.x), ca.jacobian(model.xdot, model.w)])
        self.sensors = {s.name: (ca.Function(f"h_{s.name}", [model.x, model.p], [s.y, ca.jacobian(s.y, model.x)]),
                                 np.array([i in s.angle_outputs for i in range(s.n_y)]))
                        for s in model.sensors}
        self.p = np.array([q.default for q in model.parameters], dtype=float)

    def stage(self, x, u):
        """f, A = df/dx, B = df/dw at (x, u, p, w = 0)."""
        f, A, B = self.dynamics(x, u, self.p, np.zeros(self.n_w))
        return np.asarray(f).ravel(), np.asarray(A), np.asarray(B)

    def step(self, x, u, dt):
        """x+, F = dx+/dx and G = dx+/dw of RK4 over dt in `substeps` steps (module docstring)."""
        n, h = self.n, dt / self.substeps
        identity = np.eye(n)
        F, G = np.eye(n), np.zeros((n, self.n_w))
        for _ in range(self.substeps):
            k1, A1, B1 = self.stage(x, u)
            dk1x, dk1w = A1, B1
            k2, A2, B2 = self.stage(x + h / 2 * k1, u)
            dk2x, dk2w = A2 @ (identity + h / 2 * dk1x), A2 @ (h / 2 * dk1w) + B2
            k3, A3, B3 = self.stage(x + h / 2 * k2, u)
            dk3x, dk3w = A3 @ (identity + h / 2 * dk2x), A3 @ (h / 2 * dk2w) + B3
            k4, A4, B4 = self.stage(x + h * k3, u)
            dk4x, dk4w = A4 @ (identity + h * dk3x), A4 @ (h * dk3w) + B4
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            F_s = identity + h / 6 * (dk1x + 2 * dk2x + 2 * dk3x + dk4x)
            G_s = h / 6 * (dk1w + 2 * dk2w + 2 * dk3w + dk4w)
            F, G = F_s @ F, F_s @ G + G_s
        return x, F, G

    def measure(self, sensor, x):
        h, H = self.sensors[sensor][0](x, self.p)
        return np.asarray(h).ravel(), np.asarray(H)


class AsyncEKF:
    """predict_to(t, u), update(sensor, z, t, R), x, P, t: the equations of the module docstring."""

    def __init__(self, model, x0, P0, Qc, t0=0.0):
        self.m = CasadiModel(model)
        self.Qc = np.asarray(Qc, float)
        self.R_declared = {s.name: np.array(s.noise, float) for s in model.sensors}
        self.events = []                      # ("predict", t, u) or ("update", t, sensor, z, R)
        self.states = [(t0, np.array(x0, float), np.array(P0, float))]  # after each event (the first: the start)

    @property
    def t(self):
        return self.states[-1][0]

    @property
    def x(self):
        return self.states[-1][1].copy()

    @property
    def P(self):
        return self.states[-1][2].copy()

    def _apply(self, event, state):
        t0, x, P = state
        if event[0] == "predict":
            _, t, u = event
            dt = t - t0
            x1, F, G = self.m.step(x, u, dt)
            return t, x1, F @ P @ F.T + G @ (self.Qc / dt) @ G.T
        _, t, sensor, z, R = event
        h, H = self.m.measure(sensor, x)
        nu = z - h
        angles = self.m.sensors[sensor][1]
        nu[angles] = wrap(nu[angles])
        S = H @ P @ H.T + R
        K = np.linalg.solve(S, H @ P).T
        IKH = np.eye(x.size) - K @ H
        return t, x + K @ nu, IKH @ P @ IKH.T + K @ R @ K.T

    def _run_from(self, index):
        """Recompute the states after events[index:] from the state before them."""
        del self.states[index + 1:]
        for event in self.events[index:]:
            self.states.append(self._apply(event, self.states[-1]))

    def predict_to(self, t, u):
        if t > self.t:
            self.events.append(("predict", t, np.array(u, float)))
            self._run_from(len(self.events) - 1)

    def update(self, sensor, z, t, R=None):
        R = self.R_declared[sensor] if R is None else np.asarray(R, float)
        if t >= self.t:
            first = len(self.events)
            if t > self.t:  # predicted to t with the input held since the last predict
                held = next(e[2] for e in reversed(self.events) if e[0] == "predict")
                self.events.append(("predict", t, held))
            self.events.append(("update", t, sensor, np.array(z, float), R))
            self._run_from(first)
            return
        # late: after the last event at or before t; the predict spanning t is split there with its own input
        at = sum(1 for e in self.events if e[1] <= t)  # the events are in time order
        if t < self.states[0][0] or self.events[at][0] != "predict":
            raise ValueError(f"t = {t} is before the start")
        _, end, u = self.events[at]
        inserted = [("update", t, sensor, np.array(z, float), R), ("predict", end, u)]
        if t > self.states[at][0]:
            inserted.insert(0, ("predict", t, u))
        self.events[at:at + 1] = inserted
        self._run_from(at)
