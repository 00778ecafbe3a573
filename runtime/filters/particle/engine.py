"""One SIR engine for every SIR filter, with pluggable proposals and resampling policies.

    pf = SIRFilter(model, x0, P0, process_noise, measurement_noise, n_particles, rng,
                   proposal=BootstrapProposal(), policy=ResamplingPolicy(),
                   gate_probability=1e-10, gate_patience=5, gate_inflation=4.0)
    pf.step(u, dt, z=None, p=None) -> bool     # the one filter contract (runtime/contract.py)

In the spirit of the particles library's Feynman-Kac models: the engine owns what every SIR
filter does -- particles, log-weights, the innovation gate, the exact (mixture) likelihood of the
kept entries of z, normalisation, ESS, moments, resampling, checks, checkpoints; a ``Proposal``
owns only where particles move and the importance ratio that move costs; a resampling policy
(``ResamplingPolicy``, ``KLDResampling``) owns when to resample and how many particles the next
step runs with. PF and CPF (sir.py) and UPF / HRUPF / MCUPF (unscented.py) are this engine with
a proposal and a policy.

One step (``_advance``), in one place and in this order (for the bootstrap proposal steps 1-6 are one
compiled call, ``compiled.py``: the same rule, the process noise and resampling uniforms from the C
step's own generator):

    1. move        proposal.move (a step), proposal.predict (a predict), or none (an update alone)
                   writes x_k of every particle into ``proposed`` and returns its log importance ratio
    2. gate        ``screen``: the innovation gate on the cloud's predicted measurement (below);
                   entries that fail are left out of the proposal and the likelihood
    3. likelihood  log p(z_kept | x_k) at every moved particle (exact mixture); when it underflows
                   at every particle the weights are kept (``uninformative``)
    4. weights     w_k = w_{k-1} p(z | x_k) exp(log_ratio), normalised in the log domain; ESS
    5. moments     x, P (reported; before resampling)
       re-acquire  the gate's counters (restored with the generator if the step fails); an entry left
                   out gate_patience times in a row widens the moved cloud or is admitted (below)
    6. resampling  policy.due(ess, N), policy.ancestors(w, rng, x_k): the next active count
    7. commit      the only writes to the filter's state: particle buffers swapped or gathered, N,
                   weights, reports, the proposal's carried state (commit)

The hooks a proposal implements (``Proposal``):

        def bind(self, engine) -> None                      # allocate buffers once (engine.capacity columns)
        def move(self, engine, u, dt, z, present) -> log_ratio | None
            # write x_k of the engine.N particles into engine.proposed from engine.particles;
            # return log p(x_k | x_{k-1}) - log q(x_k | x_{k-1}, z) per particle, or None when q is
            # the transition itself. A proposal that uses z calls engine.screen(...) first with its
            # per-particle predicted measurements and uses only the entries it returns.
        def predict(self, engine, u, dt) -> None             # a move without measurement (default: transition)
        reacquire = "widen" | "admit"                         # the gate's re-acquisition (module docstring)
        def commit(self, ancestors, mode, count) -> None     # carried state follows resampling
        _state = (...)                                         # carried state, checkpointed with the filter

Nothing the filter reports changes before the commit: a refused or failed step leaves the filter
bit-identical (the random generator's state included). Particles live in two buffers, each bound
to its own SIMD f and h (``particles`` and ``proposed``); a step without resampling commits by
swapping them, a resampling step by one gather into the free buffer. Numerical failures inside a
step are refused as ValueError naming the cause.

Particle number: a ``capacity`` (the most the policy can ask for: N for a fixed N, max(N, n_max)
for KLD-resampling) and an active count ``N``. Every buffer is sized to the capacity once; every
batch call is given N. ``n_particles`` reports the number the last step ran with (before its
resampling).

Process noise: additive on the discrete state, x_k = f(x_{k-1}, u) + w. Given as a
``GaussianMixture`` or as an (n_x, n_x) covariance matrix (zero-mean Gaussian). A matrix may be
singular (e.g. no noise on the pose): the transition then lives on the subspace spanned by the
eigenvectors of Q with positive eigenvalues, particles move only there, and every importance
ratio is computed exactly on that subspace (never by flooring Q). A mixture's components are
positive definite (GaussianMixture checks it).

Innovation gate (every SIR filter; options as the Kalman filters': ``gate_probability``, 1e-10 by
default, 0 turns it off; ``gate_patience`` 5; ``gate_inflation`` 4). One outlier far beyond every
particle either underflows every likelihood, or hands all the weight to the particle nearest it,
and a proposal that uses z (CPF, UPF) moves every particle towards it. So before z is used, the
cloud's predicted measurement is tested entry by entry with the Kalman filters' gate
(filters/kalman/gate.py): with w_i the weights before the step and (zhat_i, S_i) each particle's
predicted measurement and its covariance,

    nu = z - E[v] - sum_i w_i zhat_i,    S = sum_i w_i S_i + sum_i w_i (zhat_i - zbar)(zhat_i - zbar)^T

(the moment-matched predictive of the mixture sum_i w_i N(zhat_i, S_i)). zhat_i = h(x_i) and S_i = R
(the moment-matched covariance of the measurement noise) for the bootstrap proposal and an update
alone; the carried proposals use their generated update's innovation and S (cubature or unscented:
Pzz^i + R; the robust updates Pzz^i + their R~, which is >= R); the locally optimal proposal its
cubature moments. Entries that fail are left out of the proposal and the likelihood and counted
(``gated``). S >= R, so nu^T R^-1 nu bounds the NIS from above: a measurement within that bound
costs one weighted sum.

Re-acquisition. An entry left out in ``gate_patience`` consecutive updates (gated, or its update's
likelihood underflowed at every particle: the cloud cannot represent it either way) means the
cloud, not the sensor, is probably wrong (a jump it cannot follow); each update that leaves it out
again after that counts in ``inflations`` and
  * "widen" (the bootstrap proposal, which cannot move particles towards z): the moved particles
    are widened about their weighted mean along the regression of the state on the gated entries'
    predicted measurements, so the cloud's spread of those entries grows by sqrt(gate_inflation)
    and what they do not see stays (``_widen``), until z lies within ``reach`` (2) standard
    deviations of that spread. This is the Kalman filters' inflation of P restricted to the
    measured directions;
  * "admit" (the proposals that use z: carried CPF, UPF family, locally optimal CPF): the entry is
    used by the next updates while it keeps failing the gate; the proposal moves every particle
    towards z, as an ungated Kalman filter would.
Measured on a permanent jump of 47 m (56 sigma of R) of linear_cv's position
(tests/runtime/test_sir_reliability.py): the PF re-acquires by widening in 29 of 30 runs and in 12
of 30 without it (using the entry instead, the gate off, in 17 of 30: its likelihood underflows at
every particle and the weights stay as they were); the carried proposals, 6 runs: widening the carried proposals' particles or
covariances instead made them run away (the carried CPF on rov4dof at sea state 3: unmeasured
velocities widened until the dynamics overflowed), while admitting the entry brings the carried
CPF and the UPF back in 4-5 steps, the HRUPF in 4-36, the locally optimal CPF in 21-66 (its moves
are bounded by Q), the MCUPF in 4 of 6 (its correntropy kernel discounts the jump as an outlier).

The last line of defence stays: a likelihood that underflows at every particle (below the
smallest normal double) leaves the weights as they were and is counted in ``uninformative`` (the
log domain would otherwise hand all the weight to whichever particle lies nearest an outlier).

Two rules of this engine are not in the papers it implements; each is an option, so a paper's own rules can be
run beside them (seed 002's MCUPF, experiments/cn/count_sweep.py):
  * ``underflow``: "keep" (default, the rule above) or "normalise" (the weights are normalised whatever the
    likelihoods, as eq. 21 prints it: in the log domain, so an update whose likelihood underflows at every
    particle hands the weight to those nearest the measurement; still counted in ``uninformative``);
  * ``estimate``: "before" (default: x, P are the weighted moments before resampling) or "after" (the moments of
    the resampled, equally weighted particles, as seed 002's eqs. 23-24 and its Table 3 step 4 print them; a step
    without resampling reports the weighted moments either way).
A filter with a rule other than the default runs the Python step (the compiled bootstrap step has the defaults).

``predict`` moves the particles by the transition; ``update`` reweights them by the likelihood
(the two make a bootstrap step). ``step`` with a measurement uses the filter's proposal.

dt beyond the model's stable range: the first step with a dt larger than any checked runs the
transition f also in 2 halves (step doubling); if the two disagree by more than 1 % of the
state's scale, f is subdivided into 2, 4, ..., 64 equal substeps until they agree, and that
count is kept for that dt (``pieces``); beyond 64 the step is refused naming dt. The generated
steps of the carried proposals cannot be subdivided: they refuse such a dt.

Finite in, finite out: a step whose particles leave |x| <= MAX_STATE (1e153: beyond, their
covariance overflows or their spread is lost to rounding), or whose weights are not finite, is
refused with a ValueError (state unchanged); inside that range the mean and covariance are finite.
A start whose particles leave it is refused (x0 near 1e153 or beyond; P0 = 1e300 I is accepted).

Reports: ``x``/``P`` are the weighted mean and covariance after the update (before resampling);
``ess`` the effective sample size 1/sum w^2 after the update (before resampling);
``n_particles`` N; ``nis`` NaN (not defined for a particle filter). ``resamples`` counts
resampling steps, ``uninformative`` the updates whose likelihood underflowed at every particle,
``gated`` the measurement entries left out by the gate, ``inflations`` the widenings.
"""
from __future__ import annotations

import math

import numpy as np

from ...compiled.batches import MeasureBatch, ModelBatch
from ...contract import FilterBase, Stateful, as_generator, check_count, check_covariance, check_state
from ...noise.mixtures import LOG_2PI, GaussianMixture, weighted_moments
from ...numerics import angle_indices, gaussian_draws, wrap_to_pi
from ...resampling import KLDResampling, ResamplingPolicy, normalise_log_weights
from ..kalman.gate import InnovationGate
from .carried import CompiledCarried
from .compiled import CompiledBootstrap

__all__ = ["LOG_UNDERFLOW", "BootstrapProposal", "MeasurementNoise", "Proposal", "SIRFilter", "TransitionNoise",
           "check_noises", "informative", "measurement_residuals"]

#: the engine's rule, then the printed alternative, for an update whose likelihood underflows at every particle
UNDERFLOW_RULES = ("keep", "normalise")
#: where the reported estimate is taken: the engine's rule (before resampling), then the printed alternative
ESTIMATE_RULES = ("before", "after")
#: log of the smallest normal double: a likelihood below it at every particle underflows to zero
LOG_UNDERFLOW = float(np.log(np.finfo(np.float64).tiny))
#: the particles' finite range: inside it every entry of their covariance is at most (2 MAX_STATE)^2 = 4e306; beyond
#: it the covariance overflows, or the spread is lost to rounding (a cloud of spread 1 moved to 1e200 is one double)
MAX_STATE = 1e153


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


def _finite(a: np.ndarray) -> bool:
    """Every entry finite (one reduction: a NaN or inf anywhere makes the sum non-finite)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return math.isfinite(float(a.sum()))


# ---------------------------------------------------------------------------------------------
# noises


class TransitionNoise:
    """The additive process noise w of x_k = f(x_{k-1}) + w, with its positive-definite subspace.

    ``basis`` V (n, r) holds the eigenvectors of the (moment-matched) covariance with eigenvalues
    above 1e-12 of the largest (the columns of I for a diagonal covariance), ``variances`` the r
    eigenvalues. ``log_density(y)`` is the exact log-density of the subspace coordinates y = V^T w
    (r, N); for a mixture (always positive definite) r = n and the full mixture density is used.
    """

    def __init__(self, noise, n: int, name: str = "process_noise"):
        if isinstance(noise, GaussianMixture):
            if noise.dim != n:
                raise ValueError(f"{name} must be {n}-dimensional (additive on the discrete state), got {noise.dim}")
            self.mixture = noise if noise.n_components > 1 else None
            self.mean, cov = noise.mean(), noise.covariance()
        else:
            cov = check_covariance(noise, n, name)
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
        self._inverses: dict[bytes, np.ndarray] = {}
        #: 1 / the smallest eigenvalue of the covariance
        self.inverse_norm = 1.0 / float(np.linalg.eigvalsh(self.covariance)[0])

    def marginal(self, present: np.ndarray) -> GaussianMixture:
        if present.all():
            return self.mixture
        key = present.tobytes()
        if key not in self._marginals:
            mix = self.mixture
            self._marginals[key] = GaussianMixture(mix.weights, mix.means[:, present],
                                                   mix.covariances[:, present][:, :, present])
        return self._marginals[key]

    def inverse(self, present: np.ndarray) -> np.ndarray:
        """(m, m): the inverse of the covariance's block on the present entries, zero elsewhere (cached)."""
        key = present.tobytes()
        if key not in self._inverses:
            out = np.zeros_like(self.covariance)
            out[np.ix_(present, present)] = np.linalg.inv(self.covariance[np.ix_(present, present)])
            self._inverses[key] = out
        return self._inverses[key]


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
    #: how the filter re-acquires an entry gated gate_patience times in a row (module docstring): "widen" the
    #: cloud along it, or "admit" it to the next update (a proposal whose particles carry covariances)
    reacquire = "widen"

    def bind(self, engine: "SIRFilter") -> None:
        pass

    def move(self, engine: "SIRFilter", u, dt, z, present) -> np.ndarray | None:
        raise NotImplementedError

    def predict(self, engine: "SIRFilter", u, dt) -> None:
        """A move without a measurement: the transition (proposals with carried state update it too)."""
        engine.transition_draw(u, dt)

    def commit(self, ancestors: np.ndarray | None, mode: str, count: int) -> None:
        """The step is accepted (mode "predict", "update" or "step", run with `count` particles): carried state
        follows ancestors (the next particles, or None: no resampling)."""


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
    _state = ("N", "particles", "log_weights", "weights", "_prior", "ess", "_x", "_P", "resamples", "uninformative",
              "n_particles", "_admit", "rng", "gate", "proposal")
    #: a step writes only the free particle buffer and scratch before its commit (a proposal's carried state
    #: too); the generator and the gate's streaks change before it: a refusal restores them
    _touched = ("rng", "gate")

    def __init__(self, model, x0, P0, process_noise, measurement_noise, n_particles, rng, *,
                 proposal: Proposal | None = None, policy=ResamplingPolicy(), gate_probability: float = 1e-10,
                 gate_patience: int = 5, gate_inflation: float = 4.0, process_noise_name: str = "process_noise",
                 underflow: str = "keep", estimate: str = "before"):
        check_model(model, type(self).__name__)
        if underflow not in UNDERFLOW_RULES or estimate not in ESTIMATE_RULES:
            raise ValueError(f"{type(self).__name__}: underflow must be one of {UNDERFLOW_RULES} and estimate one of "
                             f"{ESTIMATE_RULES}, got underflow={underflow!r}, estimate={estimate!r}")
        self.underflow, self.estimate = underflow, estimate
        N = check_count(n_particles, "n_particles")
        rng = as_generator(rng)
        x0 = check_state(x0, model.n_x, "x0")
        P0 = check_covariance(P0, model.n_x, "P0")
        self.transition = TransitionNoise(process_noise, model.n_x, process_noise_name)
        self.noise = MeasurementNoise(measurement_noise, model.n_y)
        if not isinstance(policy, (ResamplingPolicy, KLDResampling)):
            raise TypeError(f"policy must be a ResamplingPolicy or KLDResampling, got {type(policy).__name__}")
        policy.check(model.n_x)
        self.proposal = BootstrapProposal() if proposal is None else proposal
        if not isinstance(self.proposal, Proposal):
            raise TypeError(f"proposal must be a Proposal, got {type(self.proposal).__name__}")
        self.gate = InnovationGate(self.noise.covariance, probability=gate_probability, patience=gate_patience,
                                   inflation=gate_inflation)
        self._init_contract(model)  # self._p: the model parameters of the current step, shared by every batch
        self.rng, self.policy = rng, policy
        self.process_noise, self.measurement_noise = process_noise, measurement_noise
        #: the most particles the policy can ask for: every buffer has this many columns
        self.capacity = max(N, int(policy.capacity(N)))
        self.N = N
        self.n_particles = float(N)
        self.angle_outputs = angle_indices(model, "outputs")
        # The bootstrap proposal's step is one compiled call (compiled.py) over the buffers of its C step;
        # otherwise two particle buffers, each bound to its own f and h: ``particles`` (x_{k-1}) and ``proposed``
        # (x_k, written by the proposal). A step without resampling commits by swapping them.
        defaults = (underflow, estimate) == (UNDERFLOW_RULES[0], ESTIMATE_RULES[0])  # the compiled steps' rules
        self._compiled = None if not defaults else (
            CompiledBootstrap(self, self.capacity) if CompiledBootstrap.fits(self)
            else CompiledCarried(self, self.capacity) if CompiledCarried.fits(self) else None)
        if self._compiled is None:
            self._batches = [ModelBatch(model, self.capacity, self._p), ModelBatch(model, self.capacity, self._p)]
            self._measures = [MeasureBatch(model, b.x, self._p) for b in self._batches]
        self._cur = 0
        self._ones = np.ones(self.capacity)
        self.particles[...] = gaussian_draws(x0, P0, rng, N)
        if not -MAX_STATE <= self.particles.min() <= self.particles.max() <= MAX_STATE:
            raise ValueError(f"{type(self).__name__}: x0 and P0 give particles beyond the finite range |x| <= {MAX_STATE:g}; "
                             f"max |x0| = {np.abs(x0).max():.3g}, max |P0| = {np.abs(P0).max():.3g}")
        self.ess = float(N)
        self.resamples = 0
        self.uninformative = 0
        if self._compiled is None:
            self.log_weights = np.full(N, -math.log(N))
            self.weights = np.full(N, 1.0 / N)
            self._prior = None  # the normalised weights of the particles, None when uniform
            self._x, self._P = x0, np.array(P0)
        else:
            self._compiled.start(self, x0, P0)
        self._checked_dt = 0.0  # f in one piece was checked stable up to this dt (see pieces())
        self._dt_pieces: dict[float, int] = {}
        self._sub = None  # scratch batch for substeps
        self._screened = None  # the gate's decision of the step under way (screen)
        self._admit = None  # entries the next update uses without gating (the re-acquisition)
        self.proposal.bind(self)

    # ---------------------------------------------------------------- contract: state
    @property
    def particles(self) -> np.ndarray:
        """The N particles x_k (n_x, N) after the last step (a view of the filter's buffer: do not write)."""
        if self._compiled is not None:
            return self._compiled.particles(self.N)
        x = self._batches[self._cur].x
        return x if self.N == self.capacity else x[:, :self.N]

    @property
    def proposed(self) -> np.ndarray:
        """The buffer a proposal writes the N moved particles into (n_x, N)."""
        if self._compiled is not None:
            return self._compiled.proposed(self.N)
        x = self._batches[1 - self._cur].x
        return x if self.N == self.capacity else x[:, :self.N]

    @property
    def streams(self) -> np.ndarray | None:
        """The compiled step's generator state [Philox key, step counter] (None: the step is not compiled)."""
        return None if self._compiled is None else self._compiled.streams

    def checkpoint(self) -> dict:
        state = super().checkpoint()
        if self._compiled is not None:
            state["compiled"] = self._compiled.checkpoint()
        return state

    def restore(self, checkpoint: dict) -> None:
        self._check_checkpoint(checkpoint)  # before anything is put back: a refused checkpoint changes nothing
        if self._compiled is not None:  # the sides first: the arrays are restored into their views
            self.N = checkpoint["N"]
            self._compiled.restore(self, checkpoint["compiled"], checkpoint["weights"], checkpoint["_prior"])
        super().restore(checkpoint)

    def _checkpoint_sizes(self) -> dict:
        return {"capacity": int(self.capacity)}

    def _checkpoint_options(self) -> dict:
        return {"proposal": type(self.proposal).__name__, "policy": repr(self.policy),
                "compiled step": self._compiled is not None}

    def _check_checkpoint(self, checkpoint) -> None:
        """FilterBase's identity check, then the cloud: N particles (1 <= N <= the capacity), finite, with finite
        non-negative weights summing to 1 (within 1e-9) and finite (or -inf) log-weights; each refusal names the
        entry, and the filter is unchanged."""
        super()._check_checkpoint(checkpoint)
        name = f"{type(self).__name__}.restore: refused"
        N = checkpoint["N"]
        if isinstance(N, bool) or not isinstance(N, (int, np.integer)) or not 1 <= N <= self.capacity:
            raise ValueError(f"{name}, N = {N!r} is not a particle count in [1, {self.capacity}] (this filter's capacity); "
                             "the filter is unchanged")
        particles, weights, logs = (np.asarray(checkpoint[k], dtype=float) for k in ("particles", "weights", "log_weights"))
        if particles.shape != (self.model.n_x, N) or weights.shape != (N,) or logs.shape != (N,):
            raise ValueError(f"{name}, the shapes of particles {particles.shape}, weights {weights.shape} and log_weights "
                             f"{logs.shape} are not ({self.model.n_x}, {N}), ({N},), ({N},) for N = {N}; the filter is "
                             "unchanged")
        if not np.all(np.isfinite(particles)):
            column = int(np.argwhere(~np.isfinite(particles))[0][1])
            raise ValueError(f"{name}, particle {column} is not finite ({particles[:, column]}); the filter is unchanged")
        total = float(np.sum(weights)) if np.all(np.isfinite(weights)) else math.nan
        if not (np.all(weights >= 0) and abs(total - 1.0) <= 1e-9):
            raise ValueError(f"{name}, the weights must be finite, non-negative and sum to 1 (sum {total!r}, smallest "
                             f"{float(np.min(weights))!r}); the filter is unchanged")
        if np.any(np.isnan(logs)) or np.any(logs == np.inf):
            raise ValueError(f"{name}, log_weights must be finite or -inf; the filter is unchanged")

    @property
    def gated(self) -> int:
        """Measurement entries left out by the innovation gate so far."""
        return self.gate.gated

    @property
    def inflations(self) -> int:
        """Widenings of the cloud after gate_patience consecutive gated updates of an entry."""
        return self.gate.inflations

    # ---------------------------------------------------------------- moves (used by the proposals)
    def transition_draw(self, u, dt) -> None:
        """proposed = f(particles, u) + w (the bootstrap move; also used by other proposals)."""
        self.add_transition_noise(self.propagate(u, dt))

    def add_transition_noise(self, f: np.ndarray) -> None:
        """proposed = f + w, w drawn from the process noise (f: the transition means, (n, N))."""
        np.add(f, self.transition.sample(self.rng, self.N), out=self.proposed)

    def propagate(self, u, dt) -> np.ndarray:
        """f(x^i_{k-1}, u) + E[w] of every particle (n, N), a buffer valid until the next call.

        A dt larger than any checked so far is checked first by step doubling (see ``pieces``)."""
        pieces = 1 if dt <= self._checked_dt else self.pieces(u, dt)
        if pieces == 1:
            x_next = self._batches[self._cur].propagate(u, dt, self.N)  # reads self.particles (its input buffer)
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
            sub = self._sub = ModelBatch(self.model, self.capacity, self._p)
        N = x.shape[1]
        sub.x[:, :N] = x
        for _ in range(pieces):
            sub.x[:, :N] = sub.propagate(u, dt / pieces, N)
        return sub.x[:, :N]

    # ---------------------------------------------------------------- the gate and the likelihood
    #: the re-acquisition widens the cloud along a gated entry until z lies within this many standard deviations
    #: of the cloud's spread of that entry (then a fair share of the particles lies near z)
    reach = 2.0

    def screen(self, residuals: np.ndarray, present: np.ndarray, S: np.ndarray | None = None,
               offset: np.ndarray | None = None) -> np.ndarray | None:
        """The innovation gate on the cloud's predicted measurement (module docstring): the entries of z to use
        (a bool mask), or None when every entry is gated. residuals (m, N): z - zhat_i per particle (rows of
        absent entries ignored), minus ``offset`` (m,) if given (the noise mean E[v]); S (m, m, N): each
        particle's predicted measurement covariance, None when it is R for every particle. The decision is
        remembered for the step's commit (the gate's counters and the re-acquisition)."""
        gate = self.gate
        gated = np.zeros_like(present)
        if gate.probability == 0.0:
            self._screened = (present, gated, present)
            return present
        N = residuals.shape[1]
        w = self._prior
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow gives inf, which fails the bounds below
            # (ndarray.dot calls BLAS: several times faster than @ for a matrix times a vector)
            centre = residuals.dot(self._ones[:N]) * (1.0 / N) if w is None else residuals.dot(w)
            nu = centre - offset if offset is not None else centre
            if present.all():
                dof = nu.size
            else:
                nu, dof = np.where(present, nu, 0.0), int(present.sum())
            # the NIS is at most nu^T R^-1 nu (S >= R), which is at most |nu|^2 / lambda_min(R): cheap bounds first
            threshold = gate.thresholds[dof]
            if (nu.dot(nu) * self.noise.inverse_norm <= threshold
                    or nu.dot(self.noise.inverse(present)).dot(nu) <= threshold):
                self._screened = (present, gated, present)
                return present
            if w is None:
                w = self._ones[:N] * (1.0 / N)
            S_cloud = (residuals * w).dot(residuals.T)  # the weighted second moment, minus the centre's outer product:
            S_cloud -= np.outer(centre, centre)        # the spread of the predicted measurements
            S_cloud += self.noise.covariance if S is None else S.dot(w)
            if present.all() and gate.passes(nu, S_cloud, dof):  # the exact NIS of the whole measurement
                self._screened = (present, gated, present)
                return present

        def evaluate(entries):
            S_e = np.where(np.outer(entries, entries), S_cloud, np.eye(nu.size))
            return np.where(entries, nu, 0.0), S_e

        judged = np.isfinite(nu) & np.isfinite(S_cloud).all(axis=1)  # an overflowing entry is gated outright
        accepted, gated = gate.select(evaluate, present & judged) if (present & judged).any() else (None, gated)
        gated = gated | (present & ~judged)
        if self._admit is not None and (gated & self._admit).any():  # the re-acquisition: used while they fail
            accepted = (gated & self._admit) | (False if accepted is None else accepted)
        self._screened = (accepted, gated, present)
        return accepted

    def _residuals(self, z: np.ndarray, present: np.ndarray) -> np.ndarray:
        """z - h(x) at every moved particle (m, N), angle rows wrapped (absent rows: z there is 0)."""
        y = self._measures[1 - self._cur](self.N)  # h at the proposed particles
        return measurement_residuals(z, y, [i for i in self.angle_outputs if present[i]])

    def _widen(self, proposed: np.ndarray, weights: np.ndarray, x: np.ndarray, residuals: np.ndarray) -> None:
        """The re-acquisition (module docstring): the moved particles widened about their weighted mean x along
        the directions the gated entries see, so that the cloud's spread of those entries grows by
        sqrt(gate_inflation) (exactly for a linear h) and what they do not see stays: x_i += (sqrt(inflation) - 1)
        C_xy C_yy^+ (y_i - ybar), the weighted regression of the state on the predicted measurements y_i of the
        gated entries whose innovation lies beyond ``reach`` standard deviations of the cloud's own spread
        (|nu_j| > reach sqrt(C_yy,jj): a cloud that already spans z is not widened further, so widening never
        runs away). residuals (g, N): z - y_i of the gated entries. A cloud
        without spread in those entries is not widened (the transition noise gives it some again); nor is one
        whose widening would leave the finite range."""
        with np.errstate(over="ignore", invalid="ignore"):
            nu = residuals @ weights
            d_y = residuals - nu[:, None]
            C_yy = (d_y * weights) @ d_y.T
            beyond = nu * nu > self.reach**2 * np.diag(C_yy)
            if not beyond.any():
                return
            d_y, C_yy = d_y[beyond], C_yy[np.ix_(beyond, beyond)]
            C_xy = ((proposed - x[:, None]) * weights) @ d_y.T
            if not (_finite(C_yy) and _finite(C_xy)):
                return
            shift = C_xy @ np.linalg.pinv(C_yy, rcond=1e-12, hermitian=True) @ d_y
            shift *= math.sqrt(self.gate.inflation) - 1.0
            shift += proposed
        if _finite(shift):
            proposed[...] = shift

    # ---------------------------------------------------------------- the step
    def _advance(self, u, dt, measurement) -> bool:
        """The contract's move (FilterBase) on checked inputs: a predict moves every particle by the transition
        (weights unchanged), an update alone reweights them by the likelihood of the kept entries of z, a
        step moves by the proposal and weights (module docstring, steps 1-7); commits only at its end
        (FilterBase restores the rest)."""
        if self._compiled is not None:
            return self._compiled.advance(self, u, dt, measurement)
        mode = "update" if u is None else "predict" if measurement is None else "step"
        z, present = measurement if measurement is not None else (None, None)
        N = self.N
        # 1. move
        self._screened = None
        log_w = None
        if mode == "step":
            log_w = self.proposal.move(self, u, dt, z, present)
        elif mode == "predict":
            self.proposal.predict(self, u, dt)
        else:
            self.proposed[...] = self.particles
        proposed = self.proposed
        if not -MAX_STATE <= proposed.min() <= proposed.max() <= MAX_STATE:  # (NaN fails too)
            raise ValueError(f"{self.name}: a particle left the finite range |x| <= {MAX_STATE:g} (u, p or dt drive the "
                             f"model's integration beyond it: dt = {dt!r} s may be beyond the model's stable range); "
                             "state left unchanged")
        # 2. gate, 3. likelihood
        kept, informative_step = None, True
        if measurement is not None:
            residuals = self._residuals(z, present)
            kept = self._screened[0] if self._screened is not None else self.screen(residuals, present,
                                                                                    offset=self.noise.mean)
            if kept is not None:
                log_lik = self.noise.marginal(kept).log_density(residuals if kept.all() else residuals[kept])
                if informative(log_lik) is None:
                    informative_step = False
                if informative_step or self.underflow == "normalise":
                    log_w = log_lik if log_w is None else log_w + log_lik
        # 4. weights, ESS
        log_w = self.log_weights.copy() if log_w is None else log_w + self.log_weights
        try:
            weights, log_mean = normalise_log_weights(log_w)
        except ValueError as error:
            raise ValueError(f"{self.name}: the step's importance weights are not finite ({error}); u, z or p drive the "
                             "particles out of the finite range; state left unchanged") from None
        ess = 1.0 / float(weights.dot(weights))
        # 5. moments (finite: |x| <= MAX_STATE and normalised weights bound every entry of P by (2 MAX_STATE)^2)
        x, P = weighted_moments(proposed, weights)
        admit = None
        # the gate's counters, and the re-acquisition after gate_patience gated updates of an entry (an update whose
        # likelihood underflowed at every particle left its entries out too: the cloud cannot represent them)
        if self._screened is not None and self.gate.probability > 0.0:
            accepted, gated, screened = self._screened
            if not informative_step:
                gated = screened
            if (gated.any() or self.gate.streaking) and self.gate.note(gated, screened):
                if self.proposal.reacquire == "admit":
                    admit = gated
                else:
                    self._widen(proposed, weights, x, residuals[gated])
        # 6. resampling
        ancestors = self.policy.ancestors(weights, self.rng, proposed) if self.policy.due(ess, N) else None
        if ancestors is not None and self.estimate == "after":  # the moments of the resampled particles
            x, P = weighted_moments(proposed[:, ancestors], np.full(ancestors.size, 1.0 / ancestors.size))
        # 7. commit: nothing below can fail on finite numbers
        if ancestors is None:
            self._cur = 1 - self._cur  # the proposed buffer becomes the particles
            if math.isfinite(log_mean):
                log_w -= log_mean + math.log(N)  # normalised, in the log domain
            else:
                log_w = np.log(weights)
            self.log_weights, self._prior = log_w, weights
        else:
            n_next = ancestors.size
            target = self._batches[self._cur].x  # the particles' buffer is free: gather into it
            if n_next == self.capacity:
                np.take(proposed, ancestors, axis=1, out=target)
            else:
                target[:, :n_next] = proposed[:, ancestors]
            self.N = n_next
            self.log_weights, self._prior = np.full(n_next, -math.log(n_next)), None
            self.resamples += 1
        self.weights, self.ess, self._x, self._P = weights, ess, x, P
        self.n_particles = float(N)
        self.uninformative += not informative_step
        if measurement is not None:
            self._admit = admit
        self.proposal.commit(ancestors, mode, N)
        return kept is not None
