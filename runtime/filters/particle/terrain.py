"""Terrain-aided navigation SIR with fixed or fuzzy process noise (seed 003, Fig. 5 and section 3).

    pf = TerrainParticleFilter(load("tan3dof"), x0, P0, sigma="fuzzy" | 3.0, altimeter_sigma=5.0,
                               n_particles=1000, rng=seed, terrain=BathymetryMap(...))
    pf.step(u=[v, omega], dt, z=[depth, heading]) -> bool      # the one filter contract

Decisions (the paper's Fig. 5 fixes the SIR loop, not these):

* Measurement z = [seabed depth (altimeter at operating depth 0 m), compass heading]. Either
  entry may be NaN (left out). The depth likelihood is Gaussian, N(z_depth; map(x, y),
  altimeter_sigma^2), with the map bilinearly interpolated (eq. 4) by the compiled lookup.
* Heading: the paper's filter estimates position only (Fig. 5: the process noise Sigma_m acts
  in x and y). A measured heading, wrapped to (-pi, pi] (a heading beyond +-1e6 rad is refused
  naming z), is copied into every particle after the move; the arc of
  the step still uses each particle's noisy turn rate (eq. 2). Without a heading entry the
  particles keep their own propagated headings.
* Out-of-map particles: their likelihood is that of a residual of ``out_of_map_sigmas`` (5)
  altimeter standard deviations -- unlikely but never impossible, so a cloud straddling the
  map edge is not wiped out; the kernel clamps the lookup onto the grid (no index error).
* Process noise (the move): every particle draws its own body noise (eq. 2: n_v ~ N(0, a1 v^2
  + a2 omega^2), n_omega ~ N(0, a3 v^2 + a4 omega^2), with the commanded v, omega), is moved by
  the generated exact-arc step ``tan3dof_f`` (its SIMD kernel, per-particle inputs), then gets the
  environment noise of eq. 3, N(0, sigma^2) in x and y (sigma in m per step). The current is
  unknown to the filter (p = [0, 0] unless given).
* One compiled call per step: the terrain filter is an instance of the SIR step of every particle
  filter (``abyssal.runtime.compiled.sir``, C in ``runtime/c/abyssal_sir*``): the body noise is its
  per-particle input noise, the environment noise its process noise on the (x, y) subspace, the compass
  its pinned heading, the altimeter its measurement (the map lookup, ``abyssal_sir_terrain_measure``)
  with the out-of-map particles its invalid ones; draws, move, lookup, weights, moments and resampling
  happen in that call, and with a fuzzy sigma eq. 3's stage (``abyssal_sir_terrain_step``: the gradient, its
  rate over the window of travel, the generated controller; abyssal_sir_terrain.h). Python keeps the contract's
  checks. The draws are the step's
  own counter-based generator (Philox4x32-10), keyed once from ``rng`` at construction (the numpy
  Generator is not advanced by steps); ``checkpoint()`` includes its key and step counter.
* One depth value cannot end the filter (the robust rule of every SIR filter): a depth whose innovation
  against the cloud's predicted depth fails the chi-square gate (``gate_probability``, 1e-10 by default,
  0: no gate; S = the cloud's depth spread + altimeter_sigma^2) is left out, the weights stay and it is
  counted in ``gated``; after ``gate_patience`` (5) consecutive gated depths the next one is used
  ungated (the filter, not the altimeter, is then probably wrong, as the Kalman gate's patience says),
  and a depth under which every particle's likelihood underflows keeps the weights (``uninformative``).
* sigma: a fixed number (the paper's 1..6 m), or "fuzzy": the generated Mamdani system
  ``tan3dof_fuzzy_sigma(gradient, gradient_rate)`` evaluated once per step on:
    - gradient G_k: the posterior mean of the map's slope along each particle's heading, in
      percent (m of depth per 100 m): 100 * sum_i w_i grad d(x_i) . (cos theta_i, sin theta_i);
    - gradient rate R_k: the change of G along the track over the last ``rate_window_m`` (500 m, one
      map cell) of commanded travel, per km: (G_k - G_{k-W}) / 0.5 km, W = the steps of that window.
      Early in a run, when less than a window has been travelled, the difference to the first G is
      still divided by the whole window (dividing by the short distance actually travelled made the
      first steps' rates explode to thousands of %/km while the cloud's weights settled).
  Both are clipped to [-20, 20] inside the fuzzy system. The units are this module's choice (the paper
  defines none): ``gradient_scale`` = 100 (percent) and ``rate_length_m`` = 1000 (per km) by default;
  ``gradient_scale`` = 500, ``rate_length_m`` = 500 reads them per 500 m map cell instead (5x the
  gradient, 2.5x the rate), the experiment's "fuzzy_per_cell" sensitivity row. The sigma computed after step k's
  update is the one used by step k+1's move (the first move uses G at x0 and R = 0). The window's entries are a
  ring of (travelled, G) in the filter's checkpoint that doubles when full (a vehicle holding still adds one
  entry per step until it has travelled a window).
* Resampling: systematic, when N_eff = 1/sum w^2 < N_th = ``threshold`` N (default 0.5: the paper
  does not state N_th). The estimate and covariance are the weighted moments after the update,
  before resampling.
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from scipy.stats import chi2

from ...compiled import sir
from ...contract import (_FLOAT64, NUMERICAL_FAILURES, FilterBase, as_generator, check_count, check_covariance,
                         check_state, register)
from ...noise import GaussianMixture
from ...numerics import gaussian_draws
from ...resampling import ResamplingPolicy
from ...terrain.kernel import TerrainFuzzy, TerrainMeasure

_MOVE_NONE, _MOVE_TRANSITION, _NONFINITE_MOMENTS = sir.MOVE_NONE, sir.MOVE_TRANSITION, sir.NONFINITE_MOMENTS
_REPORT_TO_GATED = sir.R_GATED + 1  # the report's head up to R_GATED: ess, resampled, ..., gated
_HISTORY_FULL = TerrainFuzzy.HISTORY_FULL

#: entries of the ring of (travelled, gradient) a filter starts with (it doubles when full: a vehicle that holds still
#: adds one per step until it has travelled a window)
HISTORY_CAPACITY = 1024
#: seed 003, Table 2: (a1, a2, a3, a4) of eq. 2
BODY_NOISE = (0.1, 0.1, 0.001, 0.1)
LOG_2PI = math.log(2.0 * math.pi)
#: the largest |compass heading| (rad) a step wraps; beyond it the step is refused (TerrainParticleFilter._wrapped_heading)
MAX_HEADING = 1e6


@register("particle")
class TerrainParticleFilter(FilterBase):
    """SIR for terrain-aided navigation on a bathymetry map, fixed or fuzzy sigma (module docstring)."""

    name = "TAN-SIR"
    _state = ("particles", "log_weights", "weights", "streams", "ess", "_x", "_P", "resamples", "gated",
              "uninformative", "_gate_streak", "_fuzzy_state", "_history")
    #: a step writes the uncommitted side of the compiled step's buffers and its inputs only
    _touched = ()

    @classmethod
    def contract_example(cls, model, *, x0=None, P0=None, n_particles=None, rng=0):
        """For the contract test: fuzzy sigma on a small random map (tan3dof's own bundle; its u, z and p
        have the shapes of the test model's: [v, omega], [depth, heading], current [d_x, d_y])."""
        import abyssal.generated
        from ...terrain import BathymetryMap

        depths = np.random.default_rng(0).uniform(100.0, 200.0, (41, 41))
        terrain = BathymetryMap(depths, origin=(-2000.0, -2000.0), resolution=100.0)
        return cls(abyssal.generated.load("tan3dof"), np.zeros(3) if x0 is None else x0,
                   np.diag([100.0, 100.0, 0.01]) if P0 is None else P0, "fuzzy", 5.0, 40 if n_particles is None else n_particles,
                   rng, terrain=terrain)

    def __init__(self, model, x0, P0, sigma, altimeter_sigma: float, n_particles: int, rng, *, terrain,
                 body_noise=BODY_NOISE, policy: ResamplingPolicy = ResamplingPolicy("systematic", 0.5),
                 out_of_map_sigmas: float = 5.0, rate_window_m: float = 500.0, gradient_scale: float = 100.0,
                 rate_length_m: float = 1000.0, gate_probability: float = 1e-10, gate_patience: int = 5):
        if "fuzzy_sigma" not in model.functions:
            raise TypeError("model must be the tan3dof bundle (abyssal.load('tan3dof')): it has no fuzzy_sigma")
        N = check_count(n_particles, "n_particles")
        self.rng = as_generator(rng)
        x0 = check_state(x0, model.n_x, "x0")
        P0 = check_covariance(P0, model.n_x, "P0")
        self.fuzzy = isinstance(sigma, str)
        if self.fuzzy and sigma != "fuzzy":
            raise ValueError(f"sigma must be a positive number of metres or 'fuzzy', got {sigma!r}")
        if not self.fuzzy and not (np.isfinite(float(sigma)) and float(sigma) >= 0):
            raise ValueError(f"sigma must be a non-negative finite number of metres or 'fuzzy', got {sigma!r}")
        if not (np.isfinite(altimeter_sigma) and altimeter_sigma > 0):
            raise ValueError(f"altimeter_sigma must be positive, got {altimeter_sigma}")
        if len(body_noise) != 4 or not all(np.isfinite(a) and a >= 0 for a in body_noise):
            raise ValueError("body_noise must be four non-negative coefficients (a1, a2, a3, a4)")
        if not (np.isfinite(rate_window_m) and rate_window_m > 0 and np.isfinite(rate_length_m) and rate_length_m > 0):
            raise ValueError(f"rate_window_m and rate_length_m must be positive metres, got {rate_window_m}, {rate_length_m}")
        if not isinstance(policy, ResamplingPolicy) or policy.scheme not in sir.SCHEMES:
            raise ValueError(f"policy must be a systematic or stratified ResamplingPolicy (the compiled step resamples "
                             f"itself), got {policy!r}")
        if not 0.0 <= gate_probability < 1.0:
            raise ValueError(f"gate_probability must be in [0, 1) (0: no gate), got {gate_probability!r}")
        if isinstance(gate_patience, bool) or not isinstance(gate_patience, (int, np.integer)) or gate_patience < 1:
            raise ValueError(f"gate_patience must be an integer >= 1, got {gate_patience!r}")
        if not (np.isfinite(out_of_map_sigmas) and out_of_map_sigmas >= 0):
            raise ValueError(f"out_of_map_sigmas must be a non-negative number, got {out_of_map_sigmas!r}")
        self.bundle, self.terrain, self.policy = model, terrain, policy
        # run() checks shapes against this view: z has two entries (depth, heading)
        self.model = SimpleNamespace(n_x=model.n_x, n_u=model.n_u, n_p=model.n_p, n_y=2, p_default=model.p_default,
                                     manifest=model.manifest, angle_states=(2,), angle_outputs=(1,),
                                     params=model.params, name=model.name)
        self.N, self.n_particles = N, float(N)
        self.altimeter_sigma = float(altimeter_sigma)
        self.body_noise = tuple(float(a) for a in body_noise)
        self.rate_window_m = float(rate_window_m)
        self.gradient_scale, self.rate_length_m = float(gradient_scale), float(rate_length_m)
        self.gate_probability, self.gate_patience = float(gate_probability), int(gate_patience)
        f = model.function("f")
        if f.soa_batched_inputs != ("x", "u"):
            raise TypeError("model's f has no structure-of-arrays kernel over x and u: regenerate tan3dof")
        # the compiled SIR step: body noise = input noise, environment noise = process noise on (x, y), the
        # compass = a pinned heading, the altimeter = the map lookup with out-of-map particles invalid
        p = np.zeros(model.n_p)
        self._init_contract(self.model, p_buffer=p)
        log_norm = -math.log(self.altimeter_sigma) - 0.5 * LOG_2PI
        self._measure = TerrainMeasure.bind(terrain, slope=self.fuzzy)
        self._sir = sir.CompiledSIR(
            N, model.n_x, model.n_u, 1, p, f=f.soa_address, measure=(TerrainMeasure.function(), self._measure),
            entry="abyssal_sir_terrain_step" if self.fuzzy else "abyssal_sir_step",
            process=sir.ProcessNoise(rank=2, factor=np.zeros(2), support=np.array([0, 1], dtype=np.int32)),
            measurement=GaussianMixture.gaussian(np.zeros(1), np.array([[self.altimeter_sigma ** 2]])),
            input_noise=True, n_extra=1 if self.fuzzy else 0, has_valid=True,
            invalid_log_lik=log_norm - 0.5 * out_of_map_sigmas ** 2)
        step, inputs = self._sir, self._sir.inputs
        # the lookup reads [pins, first pinned value]: whether every particle has the compass heading, and which
        self._measure.read_heading_from(inputs[sir.IN_PINS:sir.IN_PINS + 2])
        step.scheme = sir.SCHEMES[policy.scheme]
        step.resample_below = math.inf if policy.threshold >= 1.0 else policy.threshold * N
        # what a step changes is the inputs MOVE .. the thresholds (CompiledSIR.run), and the environment sigma:
        # [MOVE, MEASURE, DT, PIECES, PINS, heading, 0, 0, pin rows 2, 0, 0, v, omega, sd_v, sd_omega, depth,
        #  present, gate thresholds (2)]
        gate = chi2.isf(gate_probability, 1) if gate_probability > 0 else math.inf
        self._values = [0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, math.inf,
                        gate]
        self._gate = gate
        if len(self._values) != step.io.settings - sir.IN_MOVE or step.io.u - sir.IN_MOVE != 11:
            raise RuntimeError("the compiled SIR step's input layout changed: update TerrainParticleFilter._values")
        step.particles[0][...] = gaussian_draws(x0, P0, self.rng, N)
        step.rng[0] = sir.draw_key(self.rng)
        self._x, self._P = step.mean(0), step.cov(0)
        self._x[...], self._P[...] = x0, P0
        self.ess = float(N)
        self.resamples = 0
        #: depths left out by the gate, and depths whose likelihood underflowed at every particle (weights kept)
        self.gated = 0
        self.uninformative = 0
        self._gate_streak = 0
        # the fuzzy inputs and sigma of the step's two sides (TerrainFuzzy's fields; the committed one is the step's
        # side) and the ring of (travelled, gradient) along the track: the first move uses G at x0 and R = 0
        gradient = self._gradient_at(x0)
        sigma0 = float(model.function("fuzzy_sigma")(gradient, 0.0)[0]) if self.fuzzy else float(sigma)
        self._fuzzy_state = np.zeros((2, TerrainFuzzy.FIELDS))
        self._fuzzy_state[:] = [0.0, gradient, 0.0, sigma0, 0.0, 1.0]
        self._history = np.zeros((HISTORY_CAPACITY if self.fuzzy else 1, 2))  # (a fixed sigma keeps none)
        self._history[0] = 0.0, gradient
        step.factor[...] = sigma0  # (a fixed sigma stays; the fuzzy stage writes the committed one before each move)
        if self.fuzzy:
            self._stage = TerrainFuzzy.bind(model.function("fuzzy_sigma").batch_address, self.gradient_scale,
                                            self.rate_window_m, self.rate_window_m / self.rate_length_m,
                                            self._fuzzy_state, self._history, step.factor)
            self._measure.use_fuzzy(self._stage)

    # ---------------------------------------------------------------- state (the step's committed side)
    @property
    def particles(self) -> np.ndarray:
        """(3, N) particles after the last step's resampling (a view: copy before keeping it)."""
        return self._sir.particles[self._sir.cur]

    @property
    def log_weights(self) -> np.ndarray:
        return self._sir.log_w[self._sir.side]

    @property
    def weights(self) -> np.ndarray:
        """(N,) normalised weights of the last update, before resampling."""
        return self._sir.w[self._sir.side]

    @property
    def streams(self) -> np.ndarray:
        """The compiled step's generator state: [Philox key, step counter]."""
        return self._sir.rng

    def checkpoint(self) -> dict:
        state = super().checkpoint()
        state["sides"] = (self._sir.cur, self._sir.side, self._sir.weights_match)
        return state

    def restore(self, checkpoint: dict) -> None:
        self._check_checkpoint(checkpoint)  # before anything is put back: a refused checkpoint changes nothing
        self._sir.cur, self._sir.side, self._sir.weights_match = checkpoint["sides"]
        self._x, self._P = self._sir.mean(self._sir.side), self._sir.cov(self._sir.side)
        super().restore(checkpoint)  # into the buffers of the restored sides
        if self.fuzzy:  # (a ring of another capacity is a new array)
            self._stage.bind_history(self._history)

    # ---------------------------------------------------------------- eq. 3's inputs and sigma (the committed side)
    @property
    def sigma(self) -> float:
        """The environment noise's standard deviation (m per step) of the next move: the fixed one, or the fuzzy
        controller's after the last update."""
        return self._fuzzy_state.item(self._sir.side, TerrainFuzzy.SIGMA)

    @property
    def gradient(self) -> float:
        """G: the posterior mean of the map's slope along the particles' headings after the last update (x0's at
        the start), in gradient_scale units (percent by default)."""
        return self._fuzzy_state.item(self._sir.side, TerrainFuzzy.GRADIENT)

    @property
    def gradient_rate(self) -> float:
        """R: the change of G over the last rate_window_m of commanded travel, per rate_length_m (0 at the start)."""
        return self._fuzzy_state.item(self._sir.side, TerrainFuzzy.RATE)

    # ---------------------------------------------------------------- the step
    def _gradient_at(self, x: np.ndarray) -> float:
        _, gx, gy, _ = self.terrain.lookup(x[0:1], x[1:2])
        return float(self.gradient_scale * (gx[0] * math.cos(x[2]) + gy[0] * math.sin(x[2])))

    @staticmethod
    def _wrapped_heading(heading: float) -> float:
        """A compass heading wrapped to (-pi, pi] (the particles' heading is an angle), or a ValueError naming z
        beyond +-MAX_HEADING rad (there the wrap would be off by more than 1e-10 rad: 2 pi is not a double)."""
        if not abs(heading) <= MAX_HEADING:
            raise ValueError(f"TerrainParticleFilter: z[1], the compass heading, must be within +-{MAX_HEADING:g} rad, "
                             f"got {heading!r}; state left unchanged")
        if -math.pi < heading <= math.pi:
            return heading
        wrapped = math.remainder(heading, 2.0 * math.pi)
        return math.pi if wrapped == -math.pi else wrapped

    def step(self, u, dt, z=None, p=None) -> bool:
        """predict(u, dt, p) then update(z, p) as one transaction; returns whether an update happened. (The
        contract's step; its plain case, every value finite and p the model's, in this one frame: the compiled step
        writes only its uncommitted side and _move commits last, so there is nothing to snapshot.)"""
        if (p is None and type(dt) is float and 0.0 < dt < math.inf and type(u) is np.ndarray and u.dtype is _FLOAT64
                and u.shape == (2,) and type(z) is np.ndarray and z.dtype is _FLOAT64 and z.shape == (2,)
                and self._p_is_default):
            v, omega = u.tolist()
            z_depth, z_heading = z.tolist()
            if math.isfinite(v + omega) and math.isfinite(z_depth + z_heading):  # (a finite sum: both finite)
                if not self._lock.acquire(False):
                    raise self._busy()
                try:
                    self._move(True, v, omega, dt, True, z_depth, True, z_heading)
                except NUMERICAL_FAILURES as error:
                    raise self._numerical_failure(error) from error
                finally:
                    self._lock.release()
                if dt > self._max_dt:  # (as FilterBase.step says it, from the same depth)
                    self._warn_long_step(dt)
                return True
        return super().step(u, dt, z, p)

    def _advance(self, u, dt, measurement) -> bool:
        """The contract's move (FilterBase), one predict/update/step on checked inputs (_move)."""
        depth_present = heading_present = False
        z_depth = z_heading = 0.0
        if measurement is not None:
            z, present = measurement
            depth_present, heading_present = present.tolist()
            z_depth, z_heading = z.tolist()
        v, omega = u.tolist() if u is not None else (0.0, 0.0)
        self._move(u is not None, v, omega, dt, depth_present, z_depth, heading_present, z_heading)
        return measurement is not None

    def _move(self, move: bool, v: float, omega: float, dt, depth_present: bool, z_depth: float, heading_present: bool,
              z_heading: float) -> None:
        """One compiled call writing the uncommitted side, then the fuzzy inputs, then the commit; only the step's
        inputs are written before it (a refusal leaves the filter as it was)."""
        a1, a2, a3, a4 = self.body_noise
        step = self._sir
        values = self._values  # see __init__: the step's inputs MOVE .. the thresholds
        values[0], values[1], values[2] = (_MOVE_TRANSITION if move else _MOVE_NONE), depth_present, (dt if move else 1.0)
        if heading_present and not -math.pi < z_heading <= math.pi:
            z_heading = self._wrapped_heading(z_heading)
        values[4], values[5] = heading_present, z_heading                                      # the compass, pinned
        values[11], values[12] = v, omega
        values[13] = math.sqrt(a1 * v * v + a2 * omega * omega)                                # eq. 2
        values[14] = math.sqrt(a3 * v * v + a4 * omega * omega)
        values[15] = z_depth
        values[18] = math.inf if self._gate_streak >= self.gate_patience else self._gate    # patience: ungated
        status = step.run(values)  # (with a fuzzy sigma, eq. 3's stage too: abyssal_sir_terrain_step)
        if status == _HISTORY_FULL:  # (rare: the window's ring grows)
            status = self._run_with_a_larger_history(values)
        nxt = 1 - step.side
        if status:
            if status == _NONFINITE_MOMENTS:  # finite in, finite out (e.g. a current p of 1e308 moves every particle
                self._check_finite(step.means[nxt], step.covs[nxt], () if move else None, dt,  # past the covariance's
                                   () if depth_present or heading_present else None)  # range; its message names the call)
            raise ValueError(f"TerrainParticleFilter: {step.message(status)} (u, dt, z or p out of the model's "
                             "finite range); state left unchanged")
        ess, resampled, _, uninformative, _, gated = step.head(nxt)[:_REPORT_TO_GATED]
        # commit: nothing below can fail
        step.commit(resampled != 0.0)
        if depth_present:
            self._gate_streak = self._gate_streak + 1 if gated else 0
        self.gated += int(gated)
        self.uninformative += uninformative > 0.0
        self.resamples += resampled > 0.0
        self.ess = ess
        self._x, self._P = step.means[nxt], step.covs[nxt]

    def _run_with_a_larger_history(self, values) -> int:
        """The step again with the ring of (travelled, gradient) twice as long (its entries where they were, modulo
        the new length: the committed fields stay as they are); a refused step keeps the old ring."""
        old = self._history
        capacity = old.shape[0]
        committed = self._fuzzy_state[self._sir.side]
        at = int(committed[TerrainFuzzy.FIRST]) + np.arange(int(committed[TerrainFuzzy.COUNT]))
        grown = np.zeros((2 * capacity, 2))
        grown[at % (2 * capacity)] = old[at % capacity]
        self._history = grown
        self._stage.bind_history(grown)
        status = self._sir.run(values)
        if status:
            self._history = old
            self._stage.bind_history(old)
        return status
