"""One SIR engine for every particle filter, with pluggable proposals (the guided-PF split).

    pf = SIRFilter(model, x0, P0, process_noise, measurement_noise, n_particles, rng,
                   proposal=BootstrapProposal(), policy=ResamplingPolicy())
    pf.step(u, dt, z=None, p=None) -> bool     # the one filter contract (runtime/contract.py)

In the spirit of the particles library's Feynman-Kac models: the engine owns what every SIR
filter does -- particles (n_x, N), log-weights, the exact (mixture) likelihood of the present
entries of z, normalisation, ESS, moments, resampling, input checks, checkpoints -- and a
``Proposal`` owns only where particles move and the importance ratio that move costs:

    class Proposal:
        name: str
        def bind(self, engine) -> None                      # allocate buffers once
        def move(self, engine, u, dt, z, present) -> log_ratio | None
            # write x_k for every particle into engine.proposed (n_x, N) from engine.particles;
            # z is None (prediction only) or (z filled with 0 where missing, present (n_y,) bool);
            # return log p(x_k | x_{k-1}) - log q(x_k | x_{k-1}, z) per particle, or None when q is
            # the transition itself (bootstrap)
        def predict(self, engine, u, dt) -> None             # a move without measurement (default: transition)
        def commit(self, ancestors | None, mode) -> None    # carried per-particle state follows resampling
        _state = (...)                                         # carried state, checkpointed with the filter

The engine then weights w_k = w_{k-1} p(z | x_k) exp(log_ratio), normalised in the log domain.
Nothing the filter reports changes until the step's last line (commit): a refused or failed
step leaves the filter bit-identical (the random generator's state included). Particles live in
two buffers, each bound to its own SIMD f and h (``particles`` and ``proposed``); a step without
resampling commits by swapping them, a resampling step by one gather into the free buffer.
Numerical failures inside a step (LinAlgError, overflow) are refused as ValueError naming the
cause ("out of its finite range").

Process noise: additive on the discrete state, x_k = f(x_{k-1}, u) + w. Given as a
``GaussianMixture`` or as an (n_x, n_x) covariance matrix (zero-mean Gaussian). A matrix may be
singular (e.g. no noise on the pose): the transition then lives on the subspace spanned by the
eigenvectors of Q with positive eigenvalues, particles move only there, and every importance
ratio is computed exactly on that subspace (never by flooring Q). A mixture's components are
positive definite (GaussianMixture checks it).

``predict`` moves the particles by the transition; ``update`` reweights them by the likelihood
(the two make a bootstrap step). ``step`` with a measurement uses the filter's proposal.

dt beyond the model's stable range: the first step with a dt larger than any checked runs the
transition f also in 2 halves (step doubling); if the two disagree by more than 1 % of the
state's scale, f is subdivided into 2, 4, ..., 64 equal substeps until they agree, and that
count is kept for that dt (``pieces``); beyond 64 the step is refused naming dt. The generated
cubature steps of the carried CPF proposal cannot be subdivided: it refuses such a dt.

Reports: ``x``/``P`` are the weighted mean and covariance after the update (before resampling);
``ess`` the effective sample size 1/sum w^2 after the update (before resampling);
``n_particles`` N; ``nis`` NaN (not defined for a particle filter). ``resamples`` counts
resampling steps, ``uninformative`` the updates whose likelihood underflowed at every particle
(the weights are then left as they were: the log domain would otherwise hand all the weight to
whichever particle lies nearest an outlier).
"""
from __future__ import annotations

import math

import numpy as np

from ...compiled.batches import MeasureBatch, ModelBatch
from ...contract import FilterBase, Stateful, as_generator, check_count, check_covariance, check_state
from ...noise.mixtures import LOG_2PI, GaussianMixture, weighted_moments
from ...numerics import angle_indices, gaussian_draws, wrap_to_pi
from ...resampling import ResamplingPolicy, normalise_log_weights

__all__ = ["LOG_UNDERFLOW", "BootstrapProposal", "MeasurementNoise", "Proposal", "SIRFilter", "TransitionNoise",
           "check_noises", "informative", "measurement_residuals"]

#: log of the smallest normal double: a likelihood below it at every particle underflows to zero
LOG_UNDERFLOW = float(np.log(np.finfo(np.float64).tiny))


def informative(log_likelihoods: np.ndarray) -> np.ndarray | None:
    """The log-likelihoods, or None when every one underflows (the measurement carries no usable
    information: all-zero likelihoods would give 0/0 weights, so the weights are left as they were)."""
    if not log_likelihoods.max() >= LOG_UNDERFLOW:
        return None
    return log_likelihoods


def measurement_residuals(z: np.ndarray, y: np.ndarray, angle_rows) -> np.ndarray:
    """z - y for each column of y (m, N), the rows in angle_rows wrapped to (-pi, pi]."""
    r = z[:, None] - y
    for i in angle_rows:
        if np.abs(r[i]).max() > np.pi:
            r[i] = wrap_to_pi(r[i])
    return r


# ---------------------------------------------------------------------------------------------
# noises


class TransitionNoise:
    """The additive process noise w of x_k = f(x_{k-1}) + w, with its positive-definite subspace.

    ``basis`` V (n, r) holds the eigenvectors of the (moment-matched) covariance with eigenvalues
    above 1e-12 of the largest (the columns of I for a diagonal covariance), ``variances`` the r
    eigenvalues. ``log_density(y)`` is the exact log-density of the subspace coordinates y = V^T w
    (r, N); for a mixture (always positive definite) r = n and the full mixture density is used.
    """

    def __init__(self, noise, n: int):
        if isinstance(noise, GaussianMixture):
            if noise.dim != n:
                raise ValueError(f"process_noise must be {n}-dimensional (additive on the discrete state), got {noise.dim}")
            self.mixture = noise if noise.n_components > 1 else None
            self.mean, cov = noise.mean(), noise.covariance()
        else:
            cov = check_covariance(noise, n, "process_noise")
            self.mixture, self.mean = None, np.zeros(n)
        self.covariance = np.ascontiguousarray(cov)
        diagonal = not np.any(cov - np.diag(np.diag(cov)))
        if diagonal:
            values = np.diag(cov).copy()
            keep = values > 1e-12 * max(values.max(), 1e-300)
            self.basis = np.eye(n)[:, keep]
            self.support = np.flatnonzero(keep)  # V = I[:, support]: y = w[support]
        else:
            values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
            keep = values > 1e-12 * max(values.max(), 1e-300)
            self.basis, self.support = np.ascontiguousarray(vectors[:, keep]), None
            values = values
        self.variances = values[keep]
        self.rank = int(keep.sum())
        self.full = self.rank == n and self.support is not None  # V = I
        self._std = np.sqrt(self.variances)[:, None]
        self._log_norm = -0.5 * (float(np.log(self.variances).sum()) + self.rank * LOG_2PI)

    def coordinates(self, w: np.ndarray) -> np.ndarray:
        """y = V^T w (r, N)."""
        if self.support is not None:
            return w if self.full else w[self.support]
        return self.basis.T @ w

    def embed(self, y: np.ndarray) -> np.ndarray:
        """w = V y (n, N)."""
        if self.support is not None:
            if self.full:
                return y
            out = np.zeros((self.basis.shape[0], y.shape[1]))
            out[self.support] = y
            return out
        return self.basis @ y

    def sample(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """count draws of w (n, count) (the mixture's exact draws when it has several components)."""
        if self.mixture is not None:
            return self.mixture.sample(rng, count)[0]
        y = rng.standard_normal((self.rank, count))
        y *= self._std
        w = self.embed(y)
        if self.mean.any():
            w = w + self.mean[:, None]
        return w

    def log_density(self, w_centred: np.ndarray) -> np.ndarray:
        """log p(w) of the noise at w (n, N) given minus its mean, on the subspace (exact there)."""
        if self.mixture is not None:
            return self.mixture.log_density(w_centred + self.mean[:, None])
        y = self.coordinates(w_centred)
        return -0.5 * np.einsum("rn,rn->n", y, y / self.variances[:, None]) + self._log_norm


class MeasurementNoise:
    """The measurement noise mixture and its marginals on the present entries (cached by pattern)."""

    def __init__(self, noise, m: int):
        if not isinstance(noise, GaussianMixture):
            raise TypeError(f"measurement_noise must be a GaussianMixture, got {type(noise).__name__}")
        if noise.dim != m:
            raise ValueError(f"measurement_noise must be {m}-dimensional, got {noise.dim}")
        self.mixture = noise
        self.mean, self.covariance = noise.mean(), noise.covariance()
        self._marginals: dict[bytes, GaussianMixture] = {}

    def marginal(self, present: np.ndarray) -> GaussianMixture:
        if present.all():
            return self.mixture
        key = present.tobytes()
        if key not in self._marginals:
            mix = self.mixture
            self._marginals[key] = GaussianMixture(mix.weights, mix.means[:, present],
                                                   mix.covariances[:, present][:, :, present])
        return self._marginals[key]


def check_noises(model, process_noise, measurement_noise) -> tuple[TransitionNoise, MeasurementNoise]:
    return TransitionNoise(process_noise, model.n_x), MeasurementNoise(measurement_noise, model.n_y)


def check_model(model, who: str) -> None:
    if not hasattr(model, "functions") or "f" not in model.functions or "h" not in model.functions:
        raise TypeError(f"{who} needs a model bundle from abyssal.generated.load(); got {model!r}")


# ---------------------------------------------------------------------------------------------
# proposals


class Proposal(Stateful):
    """Base of the proposals: the move and its importance ratio (see the module docstring). Carried
    per-particle state is declared in ``_state`` (checkpointed with the filter)."""

    name = "proposal"

    def bind(self, engine: "SIRFilter") -> None:
        pass

    def move(self, engine: "SIRFilter", u, dt, z, present) -> np.ndarray | None:
        raise NotImplementedError

    def predict(self, engine: "SIRFilter", u, dt) -> None:
        """A move without a measurement: the transition (proposals with carried state update it too)."""
        engine.transition_draw(u, dt)

    def commit(self, ancestors: np.ndarray | None, mode: str) -> None:
        """The step is accepted (mode "predict", "update" or "step"): carried state follows ancestors."""


class BootstrapProposal(Proposal):
    """q = p(x_k | x_{k-1}): draw from the transition; the weights are the likelihood alone."""

    name = "bootstrap"

    def move(self, engine, u, dt, z, present):
        engine.transition_draw(u, dt)
        return None


# ---------------------------------------------------------------------------------------------
# the engine


class SIRFilter(FilterBase):
    """Sequential importance resampling on generated C, with a pluggable proposal (module docstring)."""

    name = "SIR"
    _state = ("particles", "log_weights", "weights", "ess", "_x", "_P", "resamples", "uninformative", "rng", "proposal")
    #: a step writes only the free particle buffer and scratch before its commit (a proposal's carried state too):
    #: a refusal restores the generator
    _touched = ("rng",)

    def __init__(self, model, x0, P0, process_noise, measurement_noise, n_particles, rng, *,
                 proposal: Proposal | None = None, policy: ResamplingPolicy = ResamplingPolicy()):
        check_model(model, type(self).__name__)
        N = check_count(n_particles, "n_particles")
        rng = as_generator(rng)
        x0 = check_state(x0, model.n_x, "x0")
        P0 = check_covariance(P0, model.n_x, "P0")
        self.transition, self.noise = check_noises(model, process_noise, measurement_noise)
        if not isinstance(policy, ResamplingPolicy):
            raise TypeError(f"policy must be a ResamplingPolicy, got {type(policy).__name__}")
        self._init_contract(model)  # self._p: the model parameters of the current step, shared by every batch
        self.rng, self.policy = rng, policy
        self.process_noise, self.measurement_noise = process_noise, measurement_noise
        self.N = N
        self.n_particles = float(N)
        self.angle_outputs = angle_indices(model, "outputs")
        # Two particle buffers, each bound to its own f and h: ``particles`` (x_{k-1}) and ``proposed``
        # (x_k, written by the proposal). A step without resampling commits by swapping them.
        self._batches = [ModelBatch(model, N, self._p), ModelBatch(model, N, self._p)]
        self._measures = [MeasureBatch(model, b.x, self._p) for b in self._batches]
        self._cur = 0
        self.particles[...] = gaussian_draws(x0, P0, rng, N)
        self.log_weights = np.full(N, -math.log(N))
        self.weights = np.full(N, 1.0 / N)
        self.ess = float(N)
        self.resamples = 0
        self.uninformative = 0
        self._x, self._P = x0, np.array(P0)
        self._resample_always = policy.threshold >= 1.0
        self._checked_dt = 0.0  # f in one piece was checked stable up to this dt (see pieces())
        self._dt_pieces: dict[float, int] = {}
        self._sub = None  # scratch batch for substeps
        self.proposal = BootstrapProposal() if proposal is None else proposal
        if not isinstance(self.proposal, Proposal):
            raise TypeError(f"proposal must be a Proposal, got {type(self.proposal).__name__}")
        self.proposal.bind(self)

    # ---------------------------------------------------------------- contract: state
    @property
    def particles(self) -> np.ndarray:
        """The particles x_{k} (n_x, N) after the last step (the filter's buffer: do not write)."""
        return self._batches[self._cur].x

    @property
    def proposed(self) -> np.ndarray:
        """The buffer a proposal writes the moved particles into (n_x, N)."""
        return self._batches[1 - self._cur].x

    # ---------------------------------------------------------------- the step
    def transition_draw(self, u, dt) -> None:
        """proposed = f(particles, u) + w (the bootstrap move; also used by other proposals)."""
        x_next = self.propagate(u, dt)
        np.add(x_next, self.transition.sample(self.rng, self.N), out=self.proposed)

    def propagate(self, u, dt) -> np.ndarray:
        """f(x^i_{k-1}, u) + E[w] of every particle (n, N), a buffer valid until the next call.

        A dt larger than any checked so far is checked first by step doubling (see ``pieces``)."""
        pieces = 1 if dt <= self._checked_dt else self.pieces(u, dt)
        if pieces == 1:
            x_next = self._batches[self._cur].propagate(u, dt)  # reads self.particles (its input buffer)
        else:
            x_next = self._substeps(self.particles, u, dt, pieces)
        if self.transition.mean.any():
            x_next += self.transition.mean[:, None]
        return x_next

    #: step-doubling tolerance: |f in k pieces - f in 2k pieces| <= tol (1 + max |x|)
    substep_tolerance = 1e-2
    max_substeps = 64

    def pieces(self, u, dt) -> int:
        """How many equal substeps f needs at this dt from the current particles: the smallest k
        (1, 2, 4, ..., max_substeps) whose result agrees with 2k substeps within substep_tolerance
        (step doubling: an unresolved or unstable explicit integration disagrees with its halves).
        k = 1 raises the checked dt; larger k are remembered for that dt. Beyond max_substeps the
        step is refused, naming the limit."""
        if dt in self._dt_pieces:
            return self._dt_pieces[dt]
        k = 1
        coarse = self._substeps(self.particles, u, dt, 1).copy()
        with np.errstate(all="ignore"):
            while k <= self.max_substeps:
                fine = self._substeps(self.particles, u, dt, 2 * k).copy()
                scale = 1.0 + float(np.max(np.abs(fine))) if np.isfinite(fine).all() else math.inf
                if np.isfinite(coarse).all() and float(np.max(np.abs(coarse - fine))) <= self.substep_tolerance * scale:
                    break
                coarse, k = fine, 2 * k
        if k > self.max_substeps:
            raise ValueError(f"{type(self).__name__}: dt = {dt!r} s is beyond the model's stable range at this state: "
                             f"even {self.max_substeps} substeps of {dt / self.max_substeps:.3g} s disagree with their "
                             "halves (step doubling); state left unchanged")
        if k == 1:
            self._checked_dt = dt
        elif len(self._dt_pieces) < 64:
            self._dt_pieces[dt] = k
        return k

    def _substeps(self, x, u, dt, pieces: int) -> np.ndarray:
        """f applied `pieces` times with dt / pieces, from x (n, N), in the scratch batch."""
        sub = self._sub
        if sub is None:
            sub = self._sub = ModelBatch(self.model, self.N, self._p)
        sub.x[...] = x
        for _ in range(pieces):
            sub.x[...] = sub.propagate(u, dt / pieces)
        return sub.x

    def log_likelihoods(self, z: np.ndarray, present: np.ndarray) -> np.ndarray:
        """log p(z_present | x) at every proposed particle (exact mixture on the present entries)."""
        y = self._measures[1 - self._cur](self.N)  # h at the proposed particles
        if present.all():
            residuals = measurement_residuals(z, y, self.angle_outputs)
        else:
            rows = np.flatnonzero(present)
            angle_rows = [i for i, r in enumerate(rows) if r in self.angle_outputs]
            residuals = measurement_residuals(z[rows], y[rows], angle_rows)
        return self.noise.marginal(present).log_density(residuals)

    def _advance(self, u, dt, measurement) -> bool:
        """The contract's move (FilterBase) on checked inputs: a predict moves every particle by the transition
        (weights unchanged), an update alone reweights them by the likelihood of the present entries of z, a
        step moves by the proposal and weights; commits only at its end (FilterBase restores the rest)."""
        mode = "update" if u is None else "predict" if measurement is None else "step"
        z, present = measurement if measurement is not None else (None, None)
        log_w = None
        if mode == "step":
            log_w = self.proposal.move(self, u, dt, z, present)
        elif mode == "predict":
            self.proposal.predict(self, u, dt)
        else:
            self.proposed[...] = self.particles
        informative_step = True
        if measurement is not None:
            log_lik = informative(self.log_likelihoods(z, present))
            if log_lik is None:
                informative_step = False
            else:
                log_w = log_lik if log_w is None else log_w + log_lik
        if log_w is None:
            log_w = self.log_weights.copy()
        else:
            log_w += self.log_weights
        if not np.isfinite(self.proposed).all():
            raise ValueError(f"{type(self).__name__}: a particle left the finite range (the model's integration "
                             f"overflowed): dt = {dt!r} s may be beyond the model's stable range; state left unchanged")
        weights, log_mean = normalise_log_weights(log_w)
        ess = 1.0 / float(weights @ weights)
        x, P = weighted_moments(self.proposed, weights)
        ancestors = None
        if self._resample_always or ess < self.policy.threshold * self.N:
            ancestors = self.policy.ancestors(weights, self.rng)
        # commit: nothing below can fail on finite numbers
        if ancestors is None:
            self._cur = 1 - self._cur  # the proposed buffer becomes the particles
            if math.isfinite(log_mean):
                log_w -= log_mean + math.log(self.N)  # normalised, in the log domain
                self.log_weights = log_w
            else:
                self.log_weights = np.full(self.N, -math.log(self.N))
        else:
            np.take(self.proposed, ancestors, axis=1, out=self.particles)
            self.log_weights = np.full(self.N, -math.log(self.N))
            self.resamples += 1
        self.weights, self.ess, self._x, self._P = weights, ess, x, P
        self.uninformative += not informative_step
        self.proposal.commit(ancestors, mode)
        return measurement is not None
