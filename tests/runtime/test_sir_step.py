"""The compiled SIR step (runtime/c/abyssal_sir*.c, runtime/compiled/sir.py) against an independent NumPy SIR.

The reference below is written from the textbook SIR and the contract's rules, with NumPy, the NumPy model of
verify/reference_models.py (not the generated C), the runtime's GaussianMixture densities and the Kalman
filters' InnovationGate; it is given the same random draws (the compiled generator's, replayed through
``sir.normals``/``sir.uniforms``).
"""
import math

import numpy as np
import pytest
from scipy import stats

import abyssal.generated
from abyssal.runtime.compiled import sir
from abyssal.runtime.filters.kalman.gate import InnovationGate
from abyssal.runtime.noise import GaussianMixture
from abyssal.verify import reference_models

LOG_UNDERFLOW = math.log(np.finfo(np.float64).tiny)


@pytest.fixture(scope="module")
def rov():
    return abyssal.generated.load("rov4dof")


# ------------------------------------------------------------------------------------------- the generator
def philox_reference(counter, key):
    """Philox4x32-10 written out from Salmon et al. (2011) in Python integers."""
    c, (k0, k1) = list(counter), key
    mask = 0xFFFFFFFF
    for r in range(10):
        if r:
            k0, k1 = (k0 + 0x9E3779B9) & mask, (k1 + 0xBB67AE85) & mask
        p0, p1 = 0xD2511F53 * c[0], 0xCD9E8D57 * c[2]
        c = [((p1 >> 32) ^ c[1] ^ k0) & mask, p1 & mask, ((p0 >> 32) ^ c[3] ^ k1) & mask, p0 & mask]
    return c


def test_philox_matches_the_published_known_answers_and_a_python_reference():
    # Random123's kat_vectors: counter, key -> output
    known = [((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
             ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
             ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
              (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1))]
    for counter, key, out in known:
        assert tuple(sir.philox(counter, key)) == out
        assert tuple(philox_reference(counter, key)) == out
    rng = np.random.default_rng(0)
    for _ in range(20):
        counter, key = rng.integers(0, 2 ** 32, 4), rng.integers(0, 2 ** 32, 2)
        assert list(sir.philox(counter, key)) == philox_reference([int(v) for v in counter], [int(v) for v in key])


def test_the_step_normals_are_the_box_muller_transform_of_philox():
    # 37 particles: the vectorised Philox (four counters at a time where the CPU has AVX2) and its scalar tail
    key, counter = 0x0123456789ABCDEF, 77
    n = 37
    z = sir.normals(key, counter, 6, n, i0=10)
    for i in range(n):
        for g in range(2):
            bits = philox_reference([10 + i, g, counter & 0xFFFFFFFF, counter >> 32], [key & 0xFFFFFFFF, key >> 32])
            for pair in range(2):
                row = 4 * g + 2 * pair
                if row >= 6:
                    continue
                r = math.sqrt(-2 * math.log(bits[2 * pair] * 2.0 ** -32 + 2.0 ** -33))
                angle = bits[2 * pair + 1] * 2.0 ** -32 * 2 * math.pi
                assert z[row, i] == pytest.approx(r * math.cos(angle), rel=2e-6, abs=2e-6)
                assert z[row + 1, i] == pytest.approx(r * math.sin(angle), rel=2e-6, abs=2e-6)
    u = sir.uniforms(key, counter, sir.TAG_RESAMPLING, n)
    for i in range(n):
        bits = philox_reference([i, 2 << 16, counter, 0], [key & 0xFFFFFFFF, key >> 32])[0]
        assert u[i] == (bits + 0.5) * 2.0 ** -32


def test_the_box_muller_transform_is_the_double_precision_one_to_single_precision():
    # the step's transform (its own log, sin and cos series in single precision) against numpy's in double of the
    # same u = (a + 1/2) 2^-32 rounded to single precision, at random words and at the edges: u at 2^-33, at 1 and
    # around sqrt(1/2) (the split of u into 2^e m), the angle at and beside every eighth of a turn (the quadrants'
    # and their series' ends)
    rng = np.random.default_rng(7)
    edges_a = np.array([0, 1, 2, 3, 1000, 2 ** 16 - 1, 2 ** 16, 2 ** 24, 2 ** 31, 0xB504F333, 0xB504F334, 2 ** 32 - 2 ** 9,
                        2 ** 32 - 2, 2 ** 32 - 1], dtype=np.uint64)
    eighths = np.arange(0, 2 ** 32, 2 ** 29, dtype=np.uint64)
    edges_b = np.concatenate([eighths, (eighths + 1) % 2 ** 32, (eighths - 1) % 2 ** 32])
    a = np.concatenate([rng.integers(0, 2 ** 32, 200_000, dtype=np.uint64), np.repeat(edges_a, edges_b.size)])
    b = np.concatenate([rng.integers(0, 2 ** 32, 200_000, dtype=np.uint64), np.tile(edges_b, edges_a.size)])
    cos_z, sin_z = sir.box_muller(a.astype(np.uint32), b.astype(np.uint32))
    u = ((a + 0.5) * 2.0 ** -32).astype(np.float32).astype(np.float64)
    r, t = np.sqrt(-2.0 * np.log(u)), 2.0 * np.pi * b * 2.0 ** -32
    scale = np.maximum(1.0, r)
    assert np.all(np.abs(cos_z - r * np.cos(t)) <= 4e-7 * scale)
    assert np.all(np.abs(sin_z - r * np.sin(t)) <= 4e-7 * scale)
    assert np.abs(cos_z).max() == np.abs(sin_z).max() == pytest.approx(math.sqrt(-2.0 * math.log(2.0 ** -33)), rel=1e-6)


def test_the_wrap_of_angle_residuals_has_the_bits_of_numpys_wrap():
    # the step wraps residuals beyond +-pi (vectorised with a fused multiply-add where the CPU has one); numpy's
    # pi - remainder(pi - r, 2 pi) is the reference, bit for bit, at the quotients' edges and far out
    from abyssal.runtime.numerics import wrap_to_pi

    two_pi = 2 * math.pi
    k = np.arange(-40.0, 41.0)
    edges = np.concatenate([k * two_pi + math.pi, k * two_pi - math.pi, k * two_pi])
    edges = np.concatenate([edges, np.nextafter(edges, np.inf), np.nextafter(edges, -np.inf)])
    rng = np.random.default_rng(3)
    values = np.concatenate([edges, rng.uniform(-1e3, 1e3, 5000), rng.uniform(-1e9, 1e9, 500) * rng.random(500),
                             [2.0 ** 49, np.nextafter(math.pi, 4), -np.nextafter(math.pi, 4)]])
    far = np.array([2.0 ** 51, -(2.0 ** 51), 1e300, -1e300, 4.0])  # a block reaching beyond 2^50: the scalar path
    for part in (values, values[:37], far):  # vector body, vector tail, scalar
        wrapped = sir.wrap_residuals(part)
        beyond = np.abs(part) > math.pi
        assert np.array_equal(wrapped[beyond], wrap_to_pi(part[beyond]))
        assert np.array_equal(wrapped[~beyond], part[~beyond])
        assert np.all(np.abs(wrapped) <= math.pi)


def test_the_step_normals_are_standard_normal_and_independent():
    z = sir.normals(2024, 3, 8, 250_000)
    flat = z.ravel()
    assert abs(flat.mean()) < 4 / math.sqrt(flat.size)
    assert abs(flat.var() - 1.0) < 4 * math.sqrt(2.0 / flat.size)
    for row in z:
        assert stats.kstest(row, "norm").pvalue > 1e-4
    corr = np.corrcoef(z)
    assert np.abs(corr - np.eye(8)).max() < 5 / math.sqrt(z.shape[1])  # rows (pairs, groups) uncorrelated
    assert abs(np.corrcoef(z[0, :-1], z[0, 1:])[0, 1]) < 5 / math.sqrt(z.shape[1])  # neighbouring particles
    other = sir.normals(2024, 4, 8, 250_000)  # the next step
    assert abs(np.corrcoef(z[0], other[0])[0, 1]) < 5 / math.sqrt(z.shape[1])
    np.testing.assert_array_equal(sir.normals(2024, 3, 8, 1000, i0=5000), z[:, 5000:6000])  # a pure function


# ------------------------------------------------------------------------------------------- the NumPy SIR
def process_noise_draws(process: sir.ProcessNoise, n_x, Y, components_u):
    w = np.zeros((n_x, Y.shape[1]))
    if process.cumulative is not None:
        comp = np.searchsorted(process.cumulative, components_u, side="right").clip(max=len(process.cumulative) - 1)
        for k in range(len(process.cumulative)):
            sel = comp == k
            w[:, sel] = process.means[k][:, None] + process.factors[k] @ Y[:, sel]
        return w
    if process.support is not None:
        w[process.support] = process.factor[:, None] * Y
    else:
        w = process.factor @ Y
    if process.mean is not None:
        w += process.mean[:, None]
    return w


def wrap(a):
    return np.pi - np.remainder(np.pi - a, 2 * np.pi)


def numpy_sir_step(model, X, log_w, u, dt, p, process, mixture, z, present, angles, key, counter, *, move=True,
                   gate_probability=0.0, resample_below=0.0, scheme="systematic", pins=()):
    """One SIR step in NumPy: returns a dict of what the compiled step reports."""
    ref = reference_models.REFERENCES[model.name]
    n_x, N = X.shape
    if move:
        Y = sir.normals(key, counter, process.rank, N)
        comp_u = sir.uniforms(key, counter, sir.TAG_COMPONENTS, N)
        Xn = reference_models.step(ref, X, u[:, None], p, dt, model.manifest["discretisation"],
                                   model.manifest["substeps"]) + process_noise_draws(process, n_x, Y, comp_u)
    else:
        Xn = X.copy()
    for row, value in pins:
        Xn[row] = value
    out = {"proposed": Xn, "gated": np.zeros(model.n_y, bool), "uninformative": False}
    log_post = log_w.copy()
    if z is not None and present.any():
        y = ref.h(Xn, p)
        prior = np.exp(log_w - log_w.max())
        prior /= prior.sum()
        residuals = z[:, None] - y  # the gate's statistics: of the residuals, angle entries wrapped
        for a in angles:
            big = np.abs(residuals[a]) > np.pi
            residuals[a, big] = wrap(residuals[a, big])
        with np.errstate(over="ignore", invalid="ignore"):  # a residual of 1e300: S overflows, the gate judges it
            centre = residuals @ prior
            dr = residuals - centre[:, None]
            Cyy = (dr * prior) @ dr.T
        R, v_mean = mixture.covariance(), mixture.mean()
        nu_full = centre - v_mean
        gate = InnovationGate(R, probability=gate_probability)

        def evaluate(entries):
            nu = np.where(entries, nu_full, 0.0)
            S = np.where(np.outer(entries, entries), Cyy + R, np.eye(len(z)))
            return nu, S

        used, gated = gate.select(evaluate, present) if gate_probability else (present, np.zeros_like(present))
        out["gated"] = gated
        used = present & ~gated if used is None else used
        if used is not None and used.any():
            rows = np.flatnonzero(used)
            r = z[rows, None] - y[rows]
            for i, row in enumerate(rows):
                if row in angles:
                    big = np.abs(r[i]) > np.pi
                    r[i, big] = wrap(r[i, big])
            marginal = GaussianMixture(mixture.weights, mixture.means[:, rows], mixture.covariances[:, rows][:, :, rows])
            ll = marginal.log_density(r)
            out["max_ll"] = ll.max()
            if ll.max() >= LOG_UNDERFLOW:
                log_post = log_post + ll
            else:
                out["uninformative"] = True
    w = np.exp(log_post - log_post.max())
    w /= w.sum()
    out["w"], out["log_w"] = w, np.log(w)
    out["ess"] = 1.0 / (w @ w)
    out["mean"] = Xn @ w
    d = Xn - out["mean"][:, None]
    out["cov"] = (d * w) @ d.T
    out["resampled"] = out["ess"] < resample_below or resample_below == np.inf
    if out["resampled"]:
        if scheme == "systematic":
            targets = (np.arange(N) + sir.uniforms(key, counter, sir.TAG_RESAMPLING, 1)[0]) / N
        else:
            targets = (np.arange(N) + sir.uniforms(key, counter, sir.TAG_RESAMPLING, N)) / N
        cdf = np.cumsum(w)
        out["ancestors"] = np.minimum(np.searchsorted(cdf / cdf[-1], targets, side="right"), N - 1)
        out["particles"] = Xn[:, out["ancestors"]]
    else:
        out["particles"] = Xn
    return out


def ref_innovation(model, X, lw, u, dt, p, process, z, key, counter):
    """nu = sum_i w_i (z - h(x_i)) - E[v] of the proposed cloud with the prior weights, the heading's residuals
    wrapped (NumPy)."""
    ref = reference_models.REFERENCES[model.name]
    Y = sir.normals(key, counter, process.rank, X.shape[1])
    Xn = reference_models.step(ref, X, u[:, None], p, dt, model.manifest["discretisation"], model.manifest["substeps"])
    Xn = Xn + process_noise_draws(process, X.shape[0], Y, sir.uniforms(key, counter, sir.TAG_COMPONENTS, X.shape[1]))
    w = np.exp(lw - lw.max())
    r = z[:, None] - ref.h(Xn, p)
    r[3] = wrap(r[3])
    return r @ (w / w.sum()) - sea_mixture().mean()


# ------------------------------------------------------------------------------------------- set-ups
def rov_noise(kind):
    """Process noises of rov4dof: the seed-000 'plain' Q (singular on the pose), a dense singular Q, a mixture."""
    from abyssal.runtime.filters.particle.engine import TransitionNoise

    if kind == "support":
        return TransitionNoise(np.diag([0.0] * 4 + [1e-2] * 4 + [1e-4] * 4), 12)
    if kind == "dense":
        A = np.random.default_rng(3).normal(size=(12, 6)) * 0.05
        return TransitionNoise(A @ A.T, 12)  # rank 6, not diagonal
    if kind == "mixture":
        rng = np.random.default_rng(4)
        covs = np.stack([np.diag(rng.uniform(1e-4, 1e-2, 12)) for _ in range(2)])
        return TransitionNoise(GaussianMixture(np.array([0.7, 0.3]), rng.normal(size=(2, 12)) * 0.01, covs), 12)
    raise KeyError(kind)


def sea_mixture(two_components=True):
    R = np.diag([0.05, 0.05, 0.02, 0.01])
    if not two_components:
        return GaussianMixture.gaussian(np.zeros(4), R)
    return GaussianMixture(np.array([0.8, 0.2]), np.array([[0.0] * 4, [0.1, -0.1, 0.05, 0.0]]), np.stack([R, 9 * R]))


def make_step(model, N, process_kind="support", mixture=None, threads=1, seed=0, spread=0.3):
    transition = rov_noise(process_kind)
    process = sir.ProcessNoise.from_transition(transition)
    mixture = sea_mixture() if mixture is None else mixture
    p = np.array(model.p_default, dtype=np.float64)
    ctx = sir.SoaMeasure(h=model.function("h").soa_address)
    step = sir.CompiledSIR(N, model.n_x, model.n_u, model.n_y, p, f=model.function("f").soa_address,
                           measure=(sir.address("abyssal_sir_soa_measure"), ctx), process=process, measurement=mixture,
                           angle_outputs=list(model.manifest["angle_outputs"]), max_threads=threads)
    rng = np.random.default_rng(seed)
    step.particles[0][...] = rng.normal(size=(model.n_x, N)) * spread
    step.particles[0][3] += np.pi * 0.9  # headings near +-pi: the angle residuals wrap
    lw = rng.normal(size=N) * 0.5
    lw -= np.log(np.exp(lw).sum())
    step.log_w[0][...] = lw
    step.rng[0], step.rng[1] = 0xC0FFEE1234, 41
    step.weights_match = False  # log_w above are not log(w)
    return step, process, mixture, p


def set_inputs(step, u, dt, z, threshold=0.0, scheme="systematic", gate=0.0, move=sir.MOVE_TRANSITION):
    step.u[...] = u
    step.inputs[sir.IN_DT], step.inputs[sir.IN_MOVE] = dt, move
    step.resample_below = threshold
    step.scheme = sir.SCHEMES[scheme]
    if z is None:
        step.inputs[sir.IN_MEASURE] = 0.0
    else:
        present = np.isfinite(z)
        step.inputs[sir.IN_MEASURE] = 1.0
        step.z[...] = np.where(present, z, 0.0)
        step.present[...] = present
    m = step.n_y
    step.thresholds[...] = math.inf
    if gate:
        step.thresholds[1:] = stats.chi2.isf(gate, np.arange(1, m + 1))


def compare(step, ref, side=1, rtol=1e-9):
    cur_next = (step.cur + (2 if ref["resampled"] else 1)) % 3
    assert step.report[side][sir.R_RESAMPLED] == ref["resampled"]
    np.testing.assert_allclose(step.particles[(step.cur + 1) % 3], ref["proposed"], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(step.w[side], ref["w"], rtol=rtol, atol=1e-300)
    assert step.report[side][sir.R_ESS] == pytest.approx(ref["ess"], rel=1e-10)
    np.testing.assert_allclose(step.mean(side), ref["mean"], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(step.cov(side), ref["cov"], rtol=1e-8, atol=1e-14)
    np.testing.assert_array_equal(step.gated(side) != 0, ref["gated"])
    assert bool(step.report[side][sir.R_UNINFORMATIVE]) == ref["uninformative"]
    if ref["resampled"]:
        np.testing.assert_allclose(step.particles[cur_next], ref["particles"], rtol=1e-10, atol=1e-10)
        np.testing.assert_array_equal(step.log_w[side], -np.log(step.n))
    else:
        np.testing.assert_allclose(step.log_w[side], ref["log_w"], rtol=1e-9, atol=1e-9)


# ------------------------------------------------------------------------------------------- the step vs NumPy
@pytest.mark.parametrize("process_kind", ["support", "dense", "mixture"])
@pytest.mark.parametrize("resample", [False, True])
def test_compiled_step_matches_an_independent_numpy_sir(rov, process_kind, resample):
    N = 1500  # three blocks, the last one partial
    step, process, mixture, p = make_step(rov, N, process_kind)
    u, dt = np.array([20.0, 5.0, 10.0, 0.5]), 0.1
    z = np.array([0.2, -0.1, 0.05, -np.pi + 0.05])
    set_inputs(step, u, dt, z, threshold=np.inf if resample else 0.0)
    X, lw = step.particles[0].copy(), step.log_w[0].copy()
    assert step() == 0
    ref = numpy_sir_step(rov, X, lw, u, dt, p, process, mixture, z, np.isfinite(z), [3], *step.rng,
                         resample_below=np.inf if resample else 0.0)
    compare(step, ref)


@pytest.mark.parametrize("components", [1, 2, 3])
@pytest.mark.parametrize("z", [[0.2, -0.1, 0.05, -np.pi + 0.05], [0.2, np.nan, 0.05, np.nan], [np.nan, -0.1, np.nan, 3.0]],
                         ids=["four entries", "two entries", "two with the heading"])
def test_a_correlated_measurement_noise_weighs_as_numpys_mixture_density(rov, components, z):
    """A measurement noise whose covariances are not diagonal (every entry correlated with the others, the means not
    zero): the particles' weights are the mixture density of scipy-checked GaussianMixture.log_density, with all of
    the entries and with two of them (the step's likelihood of up to four entries in registers, full L^-1)."""
    rng = np.random.default_rng(components)
    scale = np.sqrt([0.05, 0.05, 0.02, 0.01])
    C = np.array([[1.0, 0.3, -0.2, 0.1], [0.3, 1.0, 0.25, 0.05], [-0.2, 0.25, 1.0, 0.15], [0.1, 0.05, 0.15, 1.0]])
    covs = np.stack([C * np.outer(scale, scale) * (1 + 4 * k) for k in range(components)])
    weights = np.arange(1.0, components + 1)
    mixture = GaussianMixture(weights / weights.sum(), rng.normal(size=(components, 4)) * 0.05, covs)
    step, process, mixture, p = make_step(rov, 1500, mixture=mixture)
    u, dt, z = np.array([20.0, 5.0, 10.0, 0.5]), 0.1, np.array(z)
    set_inputs(step, u, dt, z)
    X, lw = step.particles[0].copy(), step.log_w[0].copy()
    assert step() == 0
    ref = numpy_sir_step(rov, X, lw, u, dt, p, process, mixture, z, np.isfinite(z), [3], *step.rng)
    compare(step, ref)
    assert step.report[1][sir.R_USED] == np.isfinite(z).sum()


def test_missing_entries_stratified_resampling_and_one_gaussian(rov):
    step, process, mixture, p = make_step(rov, 700, mixture=sea_mixture(two_components=False))
    u, dt = np.array([10.0, 0.0, -5.0, 0.1]), 0.2
    z = np.array([0.1, np.nan, np.nan, 3.0])
    set_inputs(step, u, dt, z, threshold=np.inf, scheme="stratified")
    X, lw = step.particles[0].copy(), step.log_w[0].copy()
    assert step() == 0
    ref = numpy_sir_step(rov, X, lw, u, dt, p, process, mixture, z, np.isfinite(z), [3], *step.rng,
                         resample_below=np.inf, scheme="stratified")
    compare(step, ref)
    assert step.report[1][sir.R_USED] == 2


def test_one_gaussian_entry_and_the_committed_weights_as_the_gates_prior(rov):
    """One present entry of a Gaussian noise (the step's one-pass likelihood), the gate on; the gate's prior weights
    read from the committed weights (weights_match) or recomputed from the log-weights give the same step."""
    mixture = sea_mixture(two_components=False)
    runs = []
    for match in (False, True):
        step, process, _, p = make_step(rov, 1300, mixture=mixture)
        step.w[0][...] = np.exp(step.log_w[0])  # the committed weights are exp(log w) ...
        step.weights_match = match             # ... and the step may read them (or recompute them)
        u, dt = np.array([20.0, 5.0, 10.0, 0.5]), 0.1
        z = np.array([np.nan, 0.3, np.nan, np.nan])
        set_inputs(step, u, dt, z, threshold=np.inf, gate=1e-10)
        X, lw = step.particles[0].copy(), step.log_w[0].copy()
        assert step() == 0
        ref = numpy_sir_step(rov, X, lw, u, dt, p, process, mixture, z, np.isfinite(z), [3], *step.rng,
                             gate_probability=1e-10, resample_below=np.inf)
        compare(step, ref)
        runs.append(step.w[1].copy())
    np.testing.assert_allclose(runs[0], runs[1], rtol=1e-12)


def test_the_gate_leaves_an_outlier_entry_out_like_the_kalman_gate(rov):
    step, process, mixture, p = make_step(rov, 1200)
    u, dt = np.array([20.0, 5.0, 10.0, 0.5]), 0.1
    z = np.array([0.2, 40.0, 0.05, -np.pi + 0.05])  # y: 40 m off
    set_inputs(step, u, dt, z, gate=1e-10)
    X, lw = step.particles[0].copy(), step.log_w[0].copy()
    assert step() == 0
    ref = numpy_sir_step(rov, X, lw, u, dt, p, process, mixture, z, np.isfinite(z), [3], *step.rng, gate_probability=1e-10)
    assert list(ref["gated"]) == [False, True, False, False]
    compare(step, ref)
    # three passes: the first, one forming S (the bound nu^T R^-1 nu did not settle it), one without the entry
    assert step.report[1][sir.R_GATED] == 1 and step.report[1][sir.R_USED] == 3 and step.report[1][sir.R_PASSES] == 3
    nu, S = step.innovation(1)
    assert nu[1] == pytest.approx(ref_innovation(rov, X, lw, u, 0.1, p, process, z, *step.rng)[1], rel=1e-9)
    assert S[1, 1] > mixture.covariance()[1, 1]
    # an ordinary measurement: the bound settles the gate in the first pass, and nothing is left out
    ordinary, *_ = make_step(rov, 1200)
    set_inputs(ordinary, u, dt, np.array([0.2, -0.1, 0.05, -np.pi + 0.05]), gate=1e-10)
    assert ordinary() == 0
    assert ordinary.report[1][sir.R_PASSES] == 1 and ordinary.report[1][sir.R_GATED] == 0
    # every present entry an outlier: nothing is used, the weights stay
    step2, *_ = make_step(rov, 1200)
    set_inputs(step2, u, dt, np.array([1e3, 1e3, 1e3, np.nan]), gate=1e-10)
    assert step2() == 0
    assert step2.report[1][sir.R_USED] == 0 and step2.report[1][sir.R_GATED] == 3
    np.testing.assert_allclose(step2.log_w[1], lw, rtol=1e-12, atol=1e-12)


def test_a_measurement_every_likelihood_underflows_keeps_the_weights(rov):
    step, process, mixture, p = make_step(rov, 900)
    u, dt = np.array([20.0, 5.0, 10.0, 0.5]), 0.1
    X, lw = step.particles[0].copy(), step.log_w[0].copy()
    for z in (np.array([1e4, 0.0, 0.0, 0.0]), np.array([1e300, 0.0, 0.0, 0.0])):
        set_inputs(step, u, dt, z)  # no gate: the underflow rule alone
        assert step() == 0
        ref = numpy_sir_step(rov, X, lw, u, dt, p, process, mixture, z, np.isfinite(z), [3], *step.rng)
        assert ref["uninformative"]
        compare(step, ref)
        assert step.report[1][sir.R_ESS] < 900  # the prior weights: not uniform, not collapsed to 1


def test_prediction_only_update_only_and_pins(rov):
    step, process, mixture, p = make_step(rov, 600)
    u, dt = np.array([5.0, 1.0, 0.0, 0.0]), 0.5
    set_inputs(step, u, dt, None)
    X, lw = step.particles[0].copy(), step.log_w[0].copy()
    assert step() == 0
    ref = numpy_sir_step(rov, X, lw, u, dt, p, process, mixture, None, None, [3], *step.rng)
    compare(step, ref)
    np.testing.assert_allclose(step.w[1], np.exp(lw), rtol=1e-12)  # weights unchanged
    # an update alone, with a pinned row (state 2 := 1.5)
    step.commit()
    X, lw = step.particles[step.cur].copy(), step.log_w[step.side].copy()
    z = np.array([0.0, 0.1, np.nan, 0.0])
    set_inputs(step, u, dt, z, move=sir.MOVE_NONE)
    step.inputs[sir.IN_PINS], step.pin_rows[0], step.pin_values[0] = 1, 2, 1.5
    assert step() == 0
    ref = numpy_sir_step(rov, X, lw, u, dt, p, process, mixture, z, np.isfinite(z), [3], *step.rng, move=False,
                         pins=[(2, 1.5)])
    compare(step, ref, side=0)


def test_a_proposal_moves_and_its_log_ratios_weigh(rov):
    step, process, mixture, p = make_step(rov, 800)
    lw = step.log_w[0].copy()
    rng = np.random.default_rng(9)
    moved = step.particles[0] + 0.01 * rng.normal(size=step.particles[0].shape)
    step.next_particles[...] = moved
    step.log_ratio[...] = rng.normal(size=800)
    z = np.array([0.1, 0.2, 0.0, 2.9])
    set_inputs(step, np.zeros(4), 0.1, z, move=sir.MOVE_GIVEN)
    step.use_log_ratio = True
    assert step() == 0
    ref = numpy_sir_step(rov, moved, lw + step.log_ratio, None, 0.1, p, process, mixture, z, np.isfinite(z), [3],
                         *step.rng, move=False)
    compare(step, ref)


@pytest.mark.parametrize("n_x", [1, 3, 4, 5, 6, 7, 9, 12, 13])
def test_the_weighted_moments_of_any_dimension(n_x):
    """Mean and covariance of given particles (no move, no measurement) for every tiling of the moments: up to
    four rows in one pass, beyond that tiles of two rows by four columns (an odd last row and a partial last group
    clamped inside); over three blocks, the last partial."""
    N = 1234
    rng = np.random.default_rng(n_x)
    step = sir.CompiledSIR(N, n_x, 0, 0, np.zeros(1), f=None, measure=None,
                           process=sir.ProcessNoise(rank=0, factor=np.zeros(1)), measurement=None)
    X = 1e3 + rng.normal(size=(n_x, N)) * rng.uniform(0.1, 10.0, (n_x, 1))  # far from 0: the shift matters
    step.next_particles[...] = X
    lw = rng.normal(size=N)
    step.log_w[0][...] = lw
    step.inputs[sir.IN_MOVE], step.inputs[sir.IN_MEASURE] = sir.MOVE_GIVEN, 0.0
    step.weights_match = False
    assert step() == 0
    w = np.exp(lw - lw.max())
    w /= w.sum()
    mean = X @ w
    d = X - mean[:, None]
    np.testing.assert_allclose(step.means[1], mean, rtol=1e-13)
    np.testing.assert_allclose(step.covs[1], (d * w) @ d.T, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(step.w[1], w, rtol=1e-12)


# ------------------------------------------------------------------------------------------- threads
@pytest.mark.parametrize("scheme", ["systematic", "stratified"])
def test_results_do_not_depend_on_the_thread_count(rov, scheme):
    N = 20_000 + 77
    results = []
    for threads in (1, 2, 3, None):  # None: chosen by timing (probing 1 and 2 threads in its first steps)
        step, *_ = make_step(rov, N, "mixture", threads=threads or 2)
        step.threads = threads
        for k in range(8):
            z = np.array([0.1 * k, -0.1, np.nan if k == 1 else 0.0, 3.0])
            set_inputs(step, np.array([20.0, 5.0, 10.0, 0.5]), 0.1, z, threshold=0.9 * N, scheme=scheme, gate=1e-10)
            assert step() == 0
            step.commit()
        results.append((step.particles[step.cur].copy(), step.log_w[step.side].copy(), step.w[step.side].copy(),
                        step.report[step.side].copy()))
    for other in results[1:]:
        for a, b in zip(results[0], other):
            assert a.tobytes() == b.tobytes()


def test_the_thread_count_is_timed_again_after_doubling_gaps():
    """The timing of 1 thread against every core runs at the first step, again FIRST_RETIME_STEPS later, then
    after gaps doubling up to RETIME_STEPS (a process's first split steps are slow; benchmarks/README.md)."""
    step = sir.CompiledSIR(sir.BLOCK + 1, 3, 0, 0, np.zeros(1), f=None, measure=None,
                           process=sir.ProcessNoise(rank=0, factor=np.zeros(1)), measurement=None, max_threads=2)
    starts, timed = [], step._probed_call

    def probed_call():
        if step._probes == 0:
            starts.append(k)
        return timed()

    step._probed_call, step._fn = probed_call, lambda arg: 0  # a step too short to split: timed on 1 thread only
    for k in range(9000):
        step._go()
    gaps = [b - a + sir.PROBE_STEPS for a, b in zip(starts, starts[1:])]
    expected = [min(sir.FIRST_RETIME_STEPS * 2 ** i, sir.RETIME_STEPS) for i in range(len(gaps))]
    assert starts[0] == 0 and gaps == expected and gaps[-1] == sir.RETIME_STEPS


def test_a_non_finite_particle_is_refused_and_the_committed_side_untouched(rov):
    step, *_ = make_step(rov, 600)
    set_inputs(step, np.array([1e308, 0.0, 0.0, 0.0]), 0.1, np.array([0.0, 0.0, 0.0, 0.0]))
    before = [a.copy() for a in (step.particles[0], step.log_w[0], step.w[0], step.report[0])]
    status = step()
    assert status == 1, sir.message(status)
    for a, b in zip(before, (step.particles[0], step.log_w[0], step.w[0], step.report[0])):
        assert a.tobytes() == b.tobytes()
    step.inputs[sir.IN_PIECES] = 0.5  # out of range: refused before anything is written
    assert step() == 5


def test_moments_out_of_the_finite_range_are_refused_and_the_committed_side_untouched():
    """Finite particles whose covariance overflows (spread 1e160: squares of 1e320): the step refuses with
    NONFINITE_MOMENTS and writes nothing committed; the same particles scaled to 1e150 pass."""
    N, n_x = 700, 3
    step = sir.CompiledSIR(N, n_x, 0, 0, np.zeros(1), f=None, measure=None,
                           process=sir.ProcessNoise(rank=0, factor=np.zeros(1)), measurement=None)
    X = np.random.default_rng(5).normal(size=(n_x, N))
    step.inputs[sir.IN_MOVE], step.inputs[sir.IN_MEASURE] = sir.MOVE_GIVEN, 0.0
    before = [a.copy() for a in (step.particles[0], step.log_w[0], step.w[0], step.report[0])]
    step.next_particles[...] = 1e160 * X
    status = step()
    assert status == sir.NONFINITE_MOMENTS, sir.message(status)
    assert "not finite" in step.message(status)
    for a, b in zip(before, (step.particles[0], step.log_w[0], step.w[0], step.report[0])):
        assert a.tobytes() == b.tobytes()
    step.next_particles[...] = 1e150 * X
    assert step() == 0
    assert np.isfinite(step.covs[1]).all() and np.isfinite(step.means[1]).all()
