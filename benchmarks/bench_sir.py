"""Bench section: one bootstrap SIR step on rov4dof against its peers, ns per particle, N = 10^4 ... 10^6.

The scenario is seed 000's sea state 3 (``runtime/experiments/rov``): 12 states, RK4 with 2 substeps at
dt = 0.1 s, the printed process noise (8 noisy states: the pose has none), a two-component Gaussian-mixture
measurement of the pose (x, y, z, psi; psi's residual wrapped), systematic resampling when ESS < N/2. Every
implementation does the same work per step: draw the process noise, move the particles, weigh them by the
mixture likelihood, normalise, ESS, the weighted mean and covariance (the filter contract reports both every
step), resample when due. Steps cycle through 400 simulated measurements; a step's time is the median of
repeated loops (``bench.median_time``), reported per particle.

Rows:
* ``abyssal, compiled step``: the C step (runtime/compiled/sir.py) on 1 and 2 threads, with the innovation
  gate on (as every SIR filter has it);
* ``abyssal ParticleFilter.step``: the public filter (the SIR engine's bootstrap step, which is the same C call,
  with the contract's checks and the gate's bookkeeping around it);
* peers, each written carefully in its own idiom with the same model equations: a NumPy SIR (vectorised
  RK4 of the independent NumPy model of verify/reference_models.py, preallocated draws, BLAS pinned to one
  thread), a jitted JAX SIR (float64, one thread, the whole step one XLA computation, rov4dof ported to
  jax.numpy and checked against the NumPy model here), and the ``particles`` library (Chopin's SMC with a bootstrap
  Feynman-Kac model; the transition and the mixture likelihood as its ProbDists, moments from its weights).
  A peer that is not installed is reported as "skipped, because ..." (``pip install -e '.[bench]'``).
* the floor: the generated f kernel alone (the arithmetic a step cannot avoid), and the bytes a step moves
  over the measured copy bandwidth of this machine.

Single-threaded rows also report their process CPU time per particle (steadier than wall time on a loaded
machine: what the row would take on an idle core, up to cache sharing), and the compiled step's 2-thread time
over its 1-thread time is measured again with the two alternating (``two_threads_over_one``: steady where the
machine's speed drifts over minutes), as is its 1-thread time over the generated f kernel alone at the same N
(``one_thread_over_f_kernel``). Targets (issue "Generate the model, write the filters once", ratios in one run;
they replace the blocked issue's ns per particle, set on another CPU): the compiled step <= 1.4x the f kernel on
one core; 2 threads <= 0.55x one at N >= 10^5 (on an idle machine); N = 10^6 within 1.3x of N = 10^4 per particle.
Without --quick, and with valgrind installed, the floor also counts instructions per particle of the compiled step
(N = 10^4, one thread) under callgrind, and of them the model's kernels' (benchmarks/instructions.py).
Run alone: ``python benchmarks/bench_sir.py [--quick]``; ``--steps N K`` runs K compiled steps at N particles and
nothing else (for an instruction count under callgrind, benchmarks/README.md).
"""
from __future__ import annotations

import itertools
import math
import os
import time

import numpy as np

from bench import json_main, median_time, target

SIZES = (10_000, 100_000, 1_000_000)
QUICK_SIZES = (1_000, 10_000)
PEER_MAX_N = 100_000  # peers above this take minutes per measurement; their scaling is shown up to here
STEPS = 400


# ------------------------------------------------------------------------------------------- scenario
def scenario():
    from abyssal.generated import load

    from abyssal.runtime.experiments.rov.scenario import SEA_STATES, RovScenario, simulate

    bundle = load("rov4dof")
    scen = RovScenario()
    sea = SEA_STATES["3"]
    truth = simulate(bundle, scen, sea, np.random.default_rng(0), n_steps=STEPS)
    return bundle, scen, sea, truth


def compiled_step(bundle, scen, sea, truth, N: int, threads: int, seed: int = 1):
    """The C step bound as the SIR engine binds it (gate on, systematic resampling below N/2)."""
    from scipy.stats import chi2

    from abyssal.runtime.compiled import sir
    from abyssal.runtime.filters.particle.engine import TransitionNoise

    Q = scen.process_covariance(bundle)
    p = np.array(bundle.p_default, dtype=np.float64)
    ctx = sir.SoaMeasure(h=bundle.function("h").soa_address)
    step = sir.CompiledSIR(N, bundle.n_x, bundle.n_u, bundle.n_y, p, f=bundle.function("f").soa_address,
                           measure=(sir.address("abyssal_sir_soa_measure"), ctx),
                           process=sir.ProcessNoise.from_transition(TransitionNoise(Q, bundle.n_x)),
                           measurement=sea.measurement_noise(), angle_outputs=list(bundle.manifest["angle_outputs"]),
                           max_threads=threads)
    rng = np.random.default_rng(seed)
    step.particles[0][...] = np.asarray(scen.x0_hat)[:, None] + math.sqrt(scen.p0_variance) * rng.standard_normal((12, N))
    step.rng[0] = sir.draw_key(rng)
    step.threads = threads  # the thread count asked for, not the one measured
    step.resample_below = 0.5 * N
    step.inputs[sir.IN_MOVE], step.inputs[sir.IN_MEASURE], step.inputs[sir.IN_DT] = sir.MOVE_TRANSITION, 1.0, scen.dt
    step.present[...] = 1.0
    step.thresholds[1:] = chi2.isf(1e-10, np.arange(1, bundle.n_y + 1))

    def one(k):
        step.u[...] = truth.inputs[k]
        step.z[...] = truth.measurements[k]
        status = step()
        if status:
            raise RuntimeError(step.message(status))
        step.commit()

    return one


# ------------------------------------------------------------------------------------------- NumPy peer
class NumpySIR:
    """A careful NumPy SIR: vectorised RK4 of the NumPy model, preallocated draws, per-component whitening of the
    diagonal mixture, BLAS for the moments (pinned to one thread by the caller)."""

    def __init__(self, bundle, scen, sea, N: int, seed: int = 1):
        from abyssal.verify import reference_models

        self.ref, self.step_fn = reference_models.REFERENCES["rov4dof"], reference_models.step
        self.p, self.dt, self.N = np.array(bundle.p_default), scen.dt, N
        self.rng = np.random.default_rng(seed)
        self.X = np.asarray(scen.x0_hat)[:, None] + math.sqrt(scen.p0_variance) * self.rng.standard_normal((12, N))
        self.logw = np.full(N, -math.log(N))
        q = np.diag(scen.process_covariance(bundle))
        self.support = np.flatnonzero(q > 0)
        self.std = np.sqrt(q[self.support])[:, None]
        self.noise = np.empty((self.support.size, N))
        mix = sea.measurement_noise()
        self.inv_std = [1.0 / np.sqrt(np.diag(c))[:, None] for c in mix.covariances]
        self.log_c = [math.log(w) - 0.5 * np.log(np.diag(c)).sum() - 2 * math.log(2 * math.pi)
                      for w, c in zip(mix.weights, mix.covariances)]

    def __call__(self, u, z):
        X = self.step_fn(self.ref, self.X, u[:, None], self.p, self.dt, "rk4", 2)
        self.rng.standard_normal(out=self.noise)
        X[self.support] += self.std * self.noise
        r = z[:, None] - X[:4]
        r[3] = np.pi - np.remainder(np.pi - r[3], 2 * np.pi)
        lk = [c - 0.5 * np.einsum("ij,ij->j", r * s, r * s) for c, s in zip(self.log_c, self.inv_std)]
        lw = self.logw + np.logaddexp(lk[0], lk[1])
        w = np.exp(lw - lw.max())
        total = w.sum()
        w /= total
        ess = 1.0 / (w @ w)
        mean = X @ w
        d = X - mean[:, None]
        cov = (d * w) @ d.T
        if ess < 0.5 * self.N:
            cdf = np.cumsum(w)
            idx = np.searchsorted(cdf / cdf[-1], (np.arange(self.N) + self.rng.random()) / self.N, side="right")
            self.X = X[:, np.minimum(idx, self.N - 1)]
            self.logw = np.full(self.N, -math.log(self.N))
        else:
            self.X, self.logw = X, np.log(w)
        return mean, cov


# ------------------------------------------------------------------------------------------- JAX peer
def jax_sir(bundle, scen, sea, N: int, seed: int = 1):
    """A jitted JAX SIR step (float64); returns step(u, z) -> (mean, cov) with the state carried inside."""
    import os
    import sys

    if "jax" not in sys.modules:  # one core, as the other single-threaded rows (XLA reads this when it loads)
        os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    from abyssal.verify import reference_models

    names = reference_models.ROV4DOF_PARAMETERS
    prm = dict(zip(names, (float(v) for v in bundle.p_default)))
    m11, m22 = prm["m"] - prm["X_udot"], prm["m"] - prm["Y_vdot"]
    m33, m44 = prm["m"] - prm["Z_wdot"], prm["I_z"] - prm["N_rdot"]

    def xdot(x, u):  # rov4dof_xdot of verify/reference_models.py in jax.numpy (checked against it below)
        psi, vu, vv, vw, vr, bx, by, bz, bp = x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], x[11]
        c, s = jnp.cos(psi), jnp.sin(psi)
        fu = u[0] + m22 * vv * vr + (prm["X_u"] + prm["X_uu"] * jnp.abs(vu)) * vu + c * bx + s * by
        fv = u[1] - m11 * vu * vr + (prm["Y_v"] + prm["Y_vv"] * jnp.abs(vv)) * vv - s * bx + c * by
        fw = u[2] + (prm["Z_w"] + prm["Z_ww"] * jnp.abs(vw)) * vw + (prm["W"] - prm["B"]) + bz
        fr = u[3] - (m22 - m11) * vu * vv + (prm["N_r"] + prm["N_rr"] * jnp.abs(vr)) * vr + bp
        tb = prm["T_b"]
        return jnp.stack([c * vu - s * vv, s * vu + c * vv, vw, vr, fu / m11, fv / m22, fw / m33, fr / m44,
                          -bx / tb, -by / tb, -bz / tb, -bp / tb])

    dt = scen.dt

    def f(x, u):
        h = dt / 2
        for _ in range(2):
            k1 = xdot(x, u)
            k2 = xdot(x + 0.5 * h * k1, u)
            k3 = xdot(x + 0.5 * h * k2, u)
            k4 = xdot(x + h * k3, u)
            x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return x

    # the port is the same model: one RK4 step of both from the same states
    check_x = reference_models.rov4dof_state(np.random.default_rng(5), 50)
    check_u = np.array([20.0, 5.0, 10.0, 0.5])
    expected = reference_models.step(reference_models.REFERENCES["rov4dof"], check_x, check_u[:, None],
                                     np.array(bundle.p_default), dt, "rk4", 2)
    np.testing.assert_allclose(np.asarray(f(jnp.asarray(check_x), jnp.asarray(check_u)[:, None])), expected,
                               rtol=1e-12, atol=1e-12)

    q = np.diag(scen.process_covariance(bundle))
    support = jnp.asarray(np.flatnonzero(q > 0))
    std = jnp.asarray(np.sqrt(q[q > 0]))[:, None]
    mix = sea.measurement_noise()
    inv_std = jnp.asarray(np.stack([1.0 / np.sqrt(np.diag(c)) for c in mix.covariances]))[:, :, None]
    log_c = jnp.asarray([math.log(w) - 0.5 * np.log(np.diag(c)).sum() - 2 * math.log(2 * math.pi)
                         for w, c in zip(mix.weights, mix.covariances)])[:, None]

    @jax.jit
    def step(X, logw, key, u, z):
        key, k_noise, k_res = jax.random.split(key, 3)
        X = f(X, u[:, None])
        X = X.at[support].add(std * jax.random.normal(k_noise, (support.shape[0], N), dtype=jnp.float64))
        r = z[:, None] - X[:4]
        r = r.at[3].set(jnp.pi - jnp.remainder(jnp.pi - r[3], 2 * jnp.pi))
        lk = log_c - 0.5 * jnp.sum((r[None] * inv_std) ** 2, axis=1)
        lw = logw + jax.scipy.special.logsumexp(lk, axis=0)
        w = jnp.exp(lw - lw.max())
        w = w / w.sum()
        ess = 1.0 / (w @ w)
        mean = X @ w
        d = X - mean[:, None]
        cov = (d * w) @ d.T

        def resample(_):
            cdf = jnp.cumsum(w)
            idx = jnp.searchsorted(cdf / cdf[-1], (jnp.arange(N) + jax.random.uniform(k_res)) / N, side="right")
            return X[:, jnp.minimum(idx, N - 1)], jnp.full(N, -math.log(N))

        X, logw = jax.lax.cond(ess < 0.5 * N, resample, lambda _: (X, jnp.log(w)), None)
        return X, logw, key, mean, cov

    rng = np.random.default_rng(seed)
    state = {"X": jnp.asarray(np.asarray(scen.x0_hat)[:, None] + math.sqrt(scen.p0_variance) * rng.standard_normal((12, N))),
             "logw": jnp.full(N, -math.log(N)), "key": jax.random.PRNGKey(seed)}

    def one(u, z):
        X, logw, key, mean, cov = step(state["X"], state["logw"], state["key"], jnp.asarray(u), jnp.asarray(z))
        cov.block_until_ready()
        state.update(X=X, logw=logw, key=key)
        return mean, cov

    return one


# ------------------------------------------------------------------------------------------- particles peer
def particles_sir(bundle, scen, sea, N: int, inputs, measurements, seed: int = 1):
    """Chopin's ``particles``: a bootstrap Feynman-Kac model of rov4dof; one ``next()`` per step, then moments."""
    import particles
    from particles import distributions as dists
    from particles import state_space_models as ssm

    from abyssal.verify import reference_models

    ref, rk4 = reference_models.REFERENCES["rov4dof"], reference_models.step
    p, dt = np.array(bundle.p_default), scen.dt
    q = np.diag(scen.process_covariance(bundle))
    support, std = np.flatnonzero(q > 0), np.sqrt(q[q > 0])
    mix = sea.measurement_noise()
    inv_std = [1.0 / np.sqrt(np.diag(c)) for c in mix.covariances]
    log_c = [math.log(w) - 0.5 * np.log(np.diag(c)).sum() - 2 * math.log(2 * math.pi)
             for w, c in zip(mix.weights, mix.covariances)]
    x0, s0 = np.asarray(scen.x0_hat), math.sqrt(scen.p0_variance)

    class Start(dists.ProbDist):
        dim = 12

        def rvs(self, size=None):
            return x0 + s0 * np.random.standard_normal((size, 12))

    class Move(dists.ProbDist):
        dim = 12

        def __init__(self, xp, u):
            self.xp, self.u = xp, u

        def rvs(self, size=None):
            X = rk4(ref, self.xp.T, self.u[:, None], p, dt, "rk4", 2).T
            X[:, support] += std * np.random.standard_normal((X.shape[0], support.size))
            return X

    class Fix(dists.ProbDist):
        dim = 4

        def __init__(self, x):
            self.y = x[:, :4]

        def logpdf(self, z):
            r = z - self.y
            r[:, 3] = np.pi - np.remainder(np.pi - r[:, 3], 2 * np.pi)
            return np.logaddexp(*[c - 0.5 * np.sum((r * s) ** 2, axis=1) for c, s in zip(log_c, inv_std)])

    class Rov(ssm.StateSpaceModel):
        def PX0(self):
            return Start()

        def PX(self, t, xp):
            return Move(xp, inputs[t])

        def PY(self, t, xp, x):
            return Fix(x)

    np.random.seed(seed)
    smc = particles.SMC(fk=ssm.Bootstrap(ssm=Rov(), data=measurements), N=N, resampling="systematic", ESSrmin=0.5)

    def one():
        next(smc)
        W = smc.W
        mean = W @ smc.X
        d = smc.X - mean
        return mean, (d * W[:, None]).T @ d

    return one


# ------------------------------------------------------------------------------------------- the floor
def floor(bundle, N: int, repeat: int, min_time: float) -> dict:
    """The generated f kernel alone, the copy bandwidth, and the bytes a step moves per particle."""
    kernel = f_kernel(bundle, N)
    f_ns = 1e9 * median_time(lambda: kernel(0), repeat, min_time) / N
    f_cpu = 1e9 * median_time(lambda: kernel(0), repeat, min_time, clock=time.process_time) / N
    big = np.ones(2 ** 24)  # 128 MB: beyond the caches
    dst = np.empty_like(big)
    copy_s = median_time(lambda: np.copyto(dst, big), repeat, min_time)
    bandwidth = 2 * big.nbytes / copy_s  # read + write
    # a step without resampling: read x (96 B) and the log-weights (8), write the proposals (96), log-weights and
    # weights (16, read back and written once more when normalised: 32); resampling adds a gather (96 + 96)
    moved, resample = 96 + 8 + 96 + 16 + 32, 192
    return {"f kernel ns/particle": f_ns, "f kernel CPU ns/particle": f_cpu, "copy bandwidth GB/s": bandwidth / 1e9,
            "bytes/particle (no resampling)": moved, "bytes/particle (resampling)": moved + resample,
            "memory floor ns/particle (no resampling)": 1e9 * moved / bandwidth,
            "memory floor ns/particle (resampling)": 1e9 * (moved + resample) / bandwidth}


def f_kernel(bundle, N: int):
    """The generated f kernel alone over N particles spread as a step's are (the floor of a step), as a callable of
    the row index (ignored) for interleaved_ratio."""
    rng = np.random.default_rng(0)
    x = 0.3 * rng.normal(size=(12, N))
    u, p, dt, out = np.tile([[20.0], [5.0], [10.0], [0.5]], (1, N)), np.array(bundle.p_default), np.array([0.1]), np.empty((12, N))
    bound = bundle.function("f").bind_soa([x, u, p, dt], [out])
    return lambda k: bound(N)


def interleaved_ratio(a, b, N: int, repeat: int) -> float:
    """Median over `repeat` alternations of (seconds of a loop of a's steps) / (the same loop of b's), each loop
    ~0.3 s: the two in the same seconds, so a machine whose speed drifts over minutes does not bias the ratio."""
    loop = max(3, int(2e6 / N))
    ratios, k = [], 0
    for _ in range(repeat):
        seconds = []
        for fn in (a, b):
            t0 = time.perf_counter()
            for i in range(loop):
                fn((k + i) % STEPS)
            seconds.append(time.perf_counter() - t0)
        k += loop
        ratios.append(seconds[0] / seconds[1])
    return sorted(ratios)[len(ratios) // 2]


# ------------------------------------------------------------------------------------------- the section
def run(quick: bool = False, verbose: bool = True) -> dict:
    bundle, scen, sea, truth = scenario()
    repeat, min_time = (3, 0.05) if quick else (7, 0.2)
    sizes = QUICK_SIZES if quick else SIZES
    results: dict = {"scenario": "rov4dof, seed 000 sea state 3, bootstrap SIR, systematic resampling at ESS < N/2",
                     "ns_per_particle": {}, "skipped": {}}

    def say(text):
        if verbose:
            print(text, flush=True)

    cpu = results["cpu_ns_per_particle"] = {}

    def per_particle(fn, N, name=None):
        """Wall ns per particle; for a single-threaded row (name given) also its process CPU time per particle."""
        rows = itertools.cycle(range(STEPS))

        def step():
            fn(next(rows))

        for _ in range(5):  # warm-up (a jitted function compiles here)
            step()
        if name is not None:
            cpu.setdefault(N, {})[name] = 1e9 * median_time(step, repeat, min_time, clock=time.process_time) / N
        return 1e9 * median_time(step, repeat, min_time) / N

    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl comes with scikit-learn ([experiments])
        threadpool_limits = None
    table = results["ns_per_particle"]
    ratios = results["two_threads_over_one"] = {}
    over_f = results["one_thread_over_f_kernel"] = {}
    for N in sizes:
        row = table.setdefault(N, {})
        steps = {}
        for threads in (1, 2):
            name = f"abyssal compiled step, {threads} thread{'s' if threads > 1 else ''}"
            steps[threads] = compiled_step(bundle, scen, sea, truth, N, threads)
            row[name] = per_particle(steps[threads], N, name if threads == 1 else None)
        ratios[N] = interleaved_ratio(steps[2], steps[1], N, repeat)
        over_f[N] = interleaved_ratio(steps[1], f_kernel(bundle, N), N, repeat)
        if N <= PEER_MAX_N:
            from abyssal.runtime.experiments.rov.scenario import make_filter

            pf = make_filter("PF", bundle, scen, sea, N, np.random.default_rng(1))
            name = "abyssal ParticleFilter.step"
            row[name] = per_particle(lambda k: pf.step(truth.inputs[k], scen.dt, truth.measurements[k]), N, name)
            numpy_sir = NumpySIR(bundle, scen, sea, N)
            if threadpool_limits is not None:
                with threadpool_limits(limits=1):
                    name = "NumPy SIR (BLAS 1 thread)"
                    row[name] = per_particle(lambda k: numpy_sir(truth.inputs[k], truth.measurements[k]), N, name)
            else:
                name = "NumPy SIR"
                row[name] = per_particle(lambda k: numpy_sir(truth.inputs[k], truth.measurements[k]), N, name)
            try:
                jax_step = jax_sir(bundle, scen, sea, N)
                name = "JAX SIR (jit, float64, 1 thread)"
                row[name] = per_particle(lambda k: jax_step(truth.inputs[k], truth.measurements[k]), N, name)
            except ImportError as exc:
                results["skipped"]["JAX"] = f"skipped, because jax is not installed ({exc}); pip install -e '.[bench]'"
            try:
                smc_step = particles_sir(bundle, scen, sea, N, truth.inputs, truth.measurements)
                rows = itertools.count()
                for _ in range(5):
                    smc_step()
                seconds, cpu_seconds = [], []
                for _ in range(repeat):  # the SMC iterator runs through the data once: a few steps per sample
                    t0, c0 = time.perf_counter(), time.process_time()
                    for _ in range(4):
                        smc_step()
                        next(rows)
                    seconds.append((time.perf_counter() - t0) / 4)
                    cpu_seconds.append((time.process_time() - c0) / 4)
                name = "particles (Chopin), bootstrap SMC"
                row[name] = 1e9 * sorted(seconds)[len(seconds) // 2] / N
                cpu.setdefault(N, {})[name] = 1e9 * sorted(cpu_seconds)[len(cpu_seconds) // 2] / N
            except ImportError as exc:
                results["skipped"]["particles"] = (f"skipped, because the particles library is not installed ({exc}); "
                                                   "pip install -e '.[bench]'")
        for name, value in row.items():
            extra = f"   (CPU {cpu[N][name]:7.1f})" if name in cpu.get(N, {}) else ""
            say(f"  N = {N:>8}  {name:<40} {value:9.1f} ns/particle{extra}")
        say(f"  N = {N:>8}  {'compiled step, 2 threads / 1, interleaved':<40} {ratios[N]:9.3f}")
        say(f"  N = {N:>8}  {'compiled step (1 thread) / f kernel, interl.':<40} {over_f[N]:9.3f}")
    results["floor"] = fl = floor(bundle, 100_000, repeat, min_time)
    if not quick:
        results["instructions_per_particle"] = counted = instructions_per_particle(10_000, 4)
        for name, value in (counted or {}).items():
            say(f"  floor: instructions per particle, {name:<22} {value:9.1f}")
    results["load_average"] = os.getloadavg() if hasattr(os, "getloadavg") else None
    for name, value in fl.items():
        say(f"  floor: {name:<44} {value:9.2f}")
    for name, why in results["skipped"].items():
        say(f"  {name}: {why}")
    one_core = [table[N]["abyssal compiled step, 1 thread"] for N in sizes]
    # issue 34's ratios (they replace the blocked issue's ns per particle, set on another CPU)
    targets = [target(f"compiled SIR step (1 thread) / the f kernel alone, rov4dof, N = {N}", over_f[N], 1.4, "x")
               for N in sizes]
    targets += [target(f"compiled SIR step, 2 threads / 1 thread, rov4dof, N = {N}", ratios[N], 0.55, "x")
                for N in sizes if N >= 100_000]
    if 1_000_000 in table and 10_000 in table:
        targets.append(target("compiled SIR step ns/particle, N = 10^6 / N = 10^4 (1 core)",
                              one_core[sizes.index(1_000_000)] / one_core[sizes.index(10_000)], 1.3, "x"))
    return {"results": results, "targets": targets}


def instructions_per_particle(N: int, steps: int) -> dict | None:
    """Instructions per particle of a compiled step on one thread under callgrind (benchmarks/instructions.py: the
    difference of `steps` and 2 `steps` steps at N particles), and of them the f kernel's and libmvec's; None without
    valgrind."""
    import sys
    from pathlib import Path

    import instructions

    counts = instructions.per_step([sys.executable, str(Path(__file__).resolve()), "--steps", str(N)], steps)
    if counts is None:
        return None
    names = {"total": "step", "model kernels": "f kernel (and h)"}  # (the others by their own names)
    return {names.get(k, k): v / N for k, v in counts.items()}


def steps_only(N: int, steps: int) -> None:
    """`steps` compiled steps at N particles on one thread and nothing else (for an instruction count under
    callgrind: benchmarks/README.md)."""
    bundle, scen, sea, truth = scenario()
    one = compiled_step(bundle, scen, sea, truth, N, 1)
    for k in range(steps):
        one(k)


if __name__ == "__main__":  # python benchmarks/bench_sir.py [--quick] | --steps N K
    import sys

    if len(sys.argv) == 4 and sys.argv[1] == "--steps":
        steps_only(int(sys.argv[2]), int(sys.argv[3]))
    else:
        json_main(run, __doc__.splitlines()[0])
