"""Bathymetry maps (abyssal.runtime.terrain) and the TAN particle filter (filters/particle/terrain.py)."""
import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

import abyssal.generated
from abyssal.runtime.filters.particle.terrain import TerrainParticleFilter
from abyssal.runtime.terrain import BathymetryMap, synthetic_arctic, topobathy_window


@pytest.fixture(scope="module")
def tan():
    return abyssal.generated.load("tan3dof")


@pytest.fixture(scope="module")
def arctic():
    return synthetic_arctic(0)


def small_map():
    rng = np.random.default_rng(1)
    return BathymetryMap(rng.uniform(100, 200, (5, 7)), origin=(-300.0, 50.0), resolution=100.0)


def test_lookup_is_bilinear_with_its_gradient():
    m = small_map()
    xg, yg = m.node_coordinates()
    rng = np.random.default_rng(2)
    x, y = rng.uniform(xg[0], xg[-1], 500), rng.uniform(yg[0], yg[-1], 500)
    depth, gx, gy, inside = m.lookup(x, y)
    np.testing.assert_allclose(depth, RegularGridInterpolator((yg, xg), m.depth)(np.column_stack([y, x])), atol=1e-10)
    assert inside.all()
    # within a cell the blend is bilinear: its gradient is exact for central differences
    h = 1e-4
    np.testing.assert_allclose(gx, (m.depth_at(x + h, y) - m.depth_at(x - h, y)) / (2 * h), atol=1e-5)
    np.testing.assert_allclose(gy, (m.depth_at(x, y + h) - m.depth_at(x, y - h)) / (2 * h), atol=1e-5)
    # nodes and the far corner are reproduced exactly
    assert m.depth_at(xg[-1], yg[-1]) == m.depth[-1, -1] and m.depth_at(xg[2], yg[3]) == m.depth[3, 2]


def test_outside_and_nan_points_are_flagged_never_an_index_error():
    m = small_map()
    x = np.array([-1e9, 1e9, np.nan, -300.0, 300.0001])
    y = np.array([60.0, 1e9, 100.0, np.nan, 250.0])
    depth, gx, gy, inside = m.lookup(x, y)
    assert not inside.any() and np.isfinite(depth).all()
    assert (gx == 0).all() and (gy == 0).all()
    assert depth[0] == m.depth_at(-300.0, 60.0)  # clamped onto the grid's edge


def test_bad_maps_are_refused():
    with pytest.raises(ValueError, match="finite"):
        BathymetryMap(np.array([[1.0, np.nan], [1.0, 2.0]]), (0, 0), 500.0)
    with pytest.raises(ValueError, match="resolution"):
        BathymetryMap(np.ones((3, 3)), (0, 0), 0.0)
    with pytest.raises(ValueError, match="2 x 2"):
        BathymetryMap(np.ones((1, 3)), (0, 0), 1.0)


def test_the_two_maps_have_the_papers_size_and_terrain_types(arctic):
    real = topobathy_window()
    for m in (arctic, real):
        assert m.shape == (121, 281) and m.resolution == 500.0 and m.extent == (0.0, 140e3, 0.0, 60e3)
        assert (m.depth >= 0).all()
    def slope(m, x0, y0):
        return np.median(np.hypot(*m.lookup(x0 + np.arange(0, 15e3, 100.0), np.full(150, y0))[1:3]))

    assert slope(arctic, 20e3, 20e3) > 0.05       # rough: > 5 % median slope along the paper's first track
    assert slope(arctic, 60e3, 10e3) < 0.001      # flat plain: < 0.1 %
    assert synthetic_arctic(0).depth.tobytes() == arctic.depth.tobytes()  # seeded
    assert synthetic_arctic(1).depth.tobytes() != arctic.depth.tobytes()


def straight_track(tan, terrain, n, start=(20e3, 20e3), rng=0):
    """Truth along +x at 0.5 m/s (no current, no body noise) and its measurements."""
    rng = np.random.default_rng(rng)
    x = start[0] + 0.5 * np.arange(1, n + 1)
    y = np.full(n, start[1])
    z = np.column_stack([terrain.depth_at(x, y) + 5.0 * rng.standard_normal(n), np.zeros(n)])
    return np.column_stack([x, y]), z


def test_filter_tracks_on_rough_terrain_and_fuzzy_sigma_follows_the_terrain(tan, arctic):
    truth, Z = straight_track(tan, arctic, 400)
    P0 = np.diag([50.0 ** 2, 50.0 ** 2, 0.0])
    for sigma in (2.0, "fuzzy"):
        pf = TerrainParticleFilter(tan, [20e3 + 80.0, 20e3 - 60.0, 0.0], P0, sigma, 5.0, 500, 3, terrain=arctic)
        errors = []
        for k in range(400):
            assert pf.step([0.5, 0.0], 1.0, Z[k])
            errors.append(np.hypot(*(pf.x[:2] - truth[k])))
        assert np.mean(errors[-100:]) < 60.0, sigma
        if sigma == "fuzzy":
            assert 4 / 3 - 1e-9 <= pf.sigma <= 20 / 3 + 1e-9
    flat = TerrainParticleFilter(tan, [60e3, 10e3, 0.0], P0, "fuzzy", 5.0, 200, 3, terrain=arctic)
    for k in range(50):
        flat.step([0.5, 0.0], 1.0, [arctic.depth_at(60e3 + 0.5 * k, 10e3), 0.0])
    assert flat.sigma > 6.5  # flat plain: gradient and rate ~ 0 -> LL


def test_refused_inputs_leave_the_filter_bit_identical(tan, arctic):
    pf = TerrainParticleFilter(tan, [20e3, 20e3, 0.0], np.diag([100.0, 100.0, 0.0]), "fuzzy", 5.0, 100, 0, terrain=arctic)
    pf.step([0.5, 0.0], 1.0, [arctic.depth_at(20e3, 20e3), 0.0])
    before = pf.checkpoint()
    for bad in [dict(u=[0.5, 0.0], dt=-1.0, z=None), dict(u=[0.5, np.nan], dt=1.0, z=None),
                dict(u=[0.5, 0.0], dt=1.0, z=[np.inf, 0.0]), dict(u=[0.5], dt=1.0, z=None)]:
        with pytest.raises(ValueError):
            pf.step(**bad)
        after = pf.checkpoint()
        assert before.keys() == after.keys()
        assert all(np.array_equal(before[k], after[k]) if isinstance(before[k], np.ndarray) else before[k] == after[k]
                   for k in before)
    # a missing depth (NaN) is no likelihood, but the compass heading is still used
    assert pf.step([0.5, 0.1], 1.0, [np.nan, 0.25])
    assert np.all(pf.particles[2] == 0.25)


def test_same_seed_same_particles(tan, arctic):
    runs = []
    for _ in range(2):
        pf = TerrainParticleFilter(tan, [20e3, 20e3, 0.0], np.diag([100.0, 100.0, 0.0]), 3.0, 5.0, 50, 7, terrain=arctic)
        for k in range(20):
            pf.step([0.5, 0.0], 1.0, [arctic.depth_at(20e3 + 0.5 * k, 20e3), 0.0])
        runs.append(pf.particles.copy())
    assert np.array_equal(*runs)


def test_gradient_rate_is_the_change_over_the_last_map_cell_travelled(tan, arctic):
    truth, Z = straight_track(tan, arctic, 1500)
    pf = TerrainParticleFilter(tan, [20e3, 20e3, 0.0], np.diag([30.0 ** 2, 30.0 ** 2, 0.0]), "fuzzy", 5.0, 200, 4,
                               terrain=arctic)
    history = [(0.0, pf.gradient)]  # naive reference: keep every entry, search the window
    for k in range(1500):
        pf.step([0.5, 0.0], 1.0, Z[k])
        travelled = 0.5 * (k + 1)
        history.append((travelled, pf.gradient))
        while len(history) > 2 and travelled - history[1][0] >= 500.0:
            history.pop(0)
        assert pf.gradient_rate == pytest.approx((pf.gradient - history[0][1]) / 0.5, rel=1e-12, abs=1e-12)
    assert 499.0 <= travelled - history[0][0] <= 500.5


def test_the_window_ring_grows_while_the_vehicle_holds_still_and_checkpoints_across_it(tan, arctic, monkeypatch):
    """The fuzzy stage's ring of (travelled, G) starts at 4 entries here: holding still adds one per step, so it
    doubles several times; the rate still equals the naive reference's, a checkpoint taken before the growth
    restores a filter that repeats the same steps exactly, and a step refused when the ring is full keeps it."""
    import abyssal.runtime.filters.particle.terrain as terrain_module

    monkeypatch.setattr(terrain_module, "HISTORY_CAPACITY", 4)
    truth, Z = straight_track(tan, arctic, 80)
    pf = TerrainParticleFilter(tan, [20e3, 20e3, 0.0], np.diag([30.0 ** 2, 30.0 ** 2, 0.0]), "fuzzy", 5.0, 100, 4,
                               terrain=arctic, rate_window_m=5.0)
    history, travelled = [(0.0, pf.gradient)], 0.0
    saved, replay, refused_when_full = None, [], 0
    for k in range(80):
        v = 0.0 if 10 <= k < 40 else 0.5  # 30 steps holding still: 30 entries within one window
        if k == 12:
            saved = pf.checkpoint()
        count = pf._fuzzy_state[pf._sir.side][terrain_module.TerrainFuzzy.COUNT]
        if count == pf._history.shape[0]:  # a step refused while the ring is full (a current beyond the finite
            before = pf.checkpoint()       # range): the ring and the fields stay as they were
            with pytest.raises(ValueError):
                pf.step(np.array([v, 0.0]), 1.0, Z[k], p=np.array([1e308, 1e308]))
            after = pf.checkpoint()
            assert after["_history"].shape == before["_history"].shape
            np.testing.assert_array_equal(after["_history"], before["_history"])
            np.testing.assert_array_equal(after["_fuzzy_state"], before["_fuzzy_state"])
            refused_when_full += 1
        pf.step(np.array([v, 0.0]), 1.0, Z[k])
        travelled += v
        history.append((travelled, pf.gradient))
        while len(history) > 2 and travelled - history[1][0] >= 5.0:
            history.pop(0)
        assert pf.gradient_rate == pytest.approx((pf.gradient - history[0][1]) / 0.005, rel=1e-12, abs=1e-12)
        if k >= 12:
            replay.append((pf.sigma, pf.gradient_rate, pf.x.copy()))
    assert pf._history.shape[0] >= 32 and refused_when_full >= 2  # grown from 4, at 8 and 16 entries at least
    pf.restore(saved)
    assert pf._history.shape == saved["_history"].shape and pf._history.shape[0] < 32  # the ring the checkpoint holds
    for k in range(12, 80):
        v = 0.0 if 10 <= k < 40 else 0.5
        pf.step(np.array([v, 0.0]), 1.0, Z[k])
        sigma, rate, x = replay[k - 12]
        assert (pf.sigma, pf.gradient_rate) == (sigma, rate) and np.array_equal(pf.x, x), k


# ------------------------------------------------------------------ the compiled step (an instance of the SIR step)
def numpy_sir_step(particles, log_w, u, dt, noise, uniform, sigma, z, terrain, body=(0.1, 0.1, 0.001, 0.1),
                   altimeter_sigma=5.0, out_of_map_ll=-12.5, resample_below=0.0):
    """Fig. 5 written out in NumPy, independent of the compiled step (exact arc in the v/omega form)."""
    v, om = u
    a1, a2, a3, a4 = body
    vv = v + np.sqrt(a1 * v * v + a2 * om * om) * noise[0]
    ww = om + np.sqrt(a3 * v * v + a4 * om * om) * noise[1]
    th = particles[2]
    turned = np.abs(ww) > 1e-9
    wsafe = np.where(turned, ww, 1.0)
    dx = np.where(turned, vv / wsafe * (np.sin(th + ww * dt) - np.sin(th)), vv * dt * np.cos(th))
    dy = np.where(turned, vv / wsafe * (np.cos(th) - np.cos(th + ww * dt)), vv * dt * np.sin(th))
    proposed = np.vstack([particles[0] + dx + sigma * noise[2], particles[1] + dy + sigma * noise[3], th + ww * dt])
    proposed[2] = z[1]  # compass
    interp = RegularGridInterpolator((terrain.origin[1] + terrain.resolution * np.arange(terrain.shape[0]),
                                      terrain.origin[0] + terrain.resolution * np.arange(terrain.shape[1])),
                                     terrain.depth, bounds_error=False, fill_value=None)
    depth = interp(np.column_stack([proposed[1], proposed[0]]))
    x_max, y_max = terrain.extent[1], terrain.extent[3]
    inside = ((proposed[0] >= terrain.origin[0]) & (proposed[0] <= x_max) & (proposed[1] >= terrain.origin[1])
              & (proposed[1] <= y_max))
    log_w = log_w + np.where(inside, -0.5 * ((z[0] - depth) / altimeter_sigma) ** 2, out_of_map_ll)
    w = np.exp(log_w - log_w.max())
    w /= w.sum()
    ess = 1.0 / np.sum(w * w)
    mean = proposed @ w
    centred = proposed - mean[:, None]
    cov = (centred * w) @ centred.T
    resampled = proposed
    if ess < resample_below:
        cdf = np.cumsum(w)
        resampled = proposed[:, np.searchsorted(cdf / cdf[-1], (np.arange(w.size) + uniform) / w.size, side="right")]
    return proposed, w, ess, mean, cov, resampled


@pytest.mark.parametrize("resample", [False, True])
def test_compiled_step_matches_an_independent_numpy_step(tan, arctic, resample):
    from abyssal.runtime.compiled import sir
    from abyssal.runtime.resampling import ResamplingPolicy

    n = 1400  # three blocks of the compiled step, the last one partial
    pf = TerrainParticleFilter(tan, [20e3, 20e3, 0.3], np.diag([200.0 ** 2, 200.0 ** 2, 0.0]), 3.0, 5.0, n, 5,
                               terrain=arctic, policy=ResamplingPolicy("systematic", 1.0 if resample else 0.0))
    pf.step([0.5, 0.02], 1.0, [arctic.depth_at(20e3, 20e3), 0.3])  # non-uniform weights to start from
    particles, log_w = pf.particles.copy(), pf.log_weights.copy()
    key, counter = (int(v) for v in pf.streams)
    noise = sir.normals(key, counter, 4, n)  # the step's draws: body noise (v, omega), then environment (x, y)
    uniform = sir.uniforms(key, counter, sir.TAG_RESAMPLING, 1)[0]
    z = [arctic.depth_at(20e3 + 0.5, 20e3 + 0.2) + 3.0, 0.31]
    pf.step([0.6, 0.05], 2.0, z)
    proposed, w, ess, mean, cov, resampled = numpy_sir_step(particles, log_w, (0.6, 0.05), 2.0, noise, uniform, 3.0,
                                                            z, arctic, resample_below=np.inf if resample else 0.0)
    assert pf.resamples == (2 if resample else 0)
    np.testing.assert_allclose(pf.weights, w, rtol=1e-9, atol=1e-15)
    assert pf.ess == pytest.approx(ess, rel=1e-12)
    np.testing.assert_allclose(pf.x, mean, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(pf.P, cov, rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(pf.particles, resampled, rtol=1e-12, atol=1e-9)
    if resample:
        assert len(np.unique(pf.particles[0])) < n  # copies of the heavy particles
        np.testing.assert_array_equal(pf.log_weights, -np.log(n))


def test_the_compiled_step_resamples_systematically_or_stratified_only(tan, arctic):
    from abyssal.runtime.resampling import ResamplingPolicy

    with pytest.raises(ValueError, match="policy"):
        TerrainParticleFilter(tan, [20e3, 20e3, 0.0], np.eye(3), 3.0, 5.0, 10, 0, terrain=arctic,
                              policy=ResamplingPolicy("multinomial", 0.5))
    TerrainParticleFilter(tan, [20e3, 20e3, 0.0], np.eye(3), 3.0, 5.0, 10, 0, terrain=arctic,
                          policy=ResamplingPolicy("stratified", 0.5))


# ------------------------------------------------------------------ one depth value cannot end the filter
def faulty_track(arctic, T, fault, every=100, seed=100):
    rng = np.random.default_rng(seed)
    x, y = 20e3 + 0.5 * np.arange(1, T + 1), np.full(T, 20e3)
    Z = np.column_stack([arctic.depth_at(x, y) + 5.0 * rng.standard_normal(T), np.zeros(T)])
    faults = np.arange(every - 1, T, every)
    Z[faults, 0] += fault
    return Z, faults


@pytest.mark.parametrize("fault", [100.0, 1e4, 1e300])
def test_a_gated_depth_outlier_is_a_missing_depth(tan, arctic, fault):
    """60 particles, a depth fault every 100 s: each fault is gated (counted), the ESS does not collapse, and
    the run is bit-identical to one where those depths are missing (NaN)."""
    Z, faults = faulty_track(arctic, 500, fault)
    missing = Z.copy()
    missing[faults, 0] = np.nan
    P0 = np.diag([30.0 ** 2, 30.0 ** 2, 0.0])
    pf, twin = (TerrainParticleFilter(tan, [20e3 + 30, 20e3 - 20, 0.0], P0, 2.0, 5.0, 60, 0, terrain=arctic)
                for _ in range(2))
    for k in range(500):
        pf.step([0.5, 0.0], 1.0, Z[k])
        twin.step([0.5, 0.0], 1.0, missing[k])
        if k in faults:
            assert pf.ess > 1.5
    assert pf.gated == len(faults) and twin.gated == 0
    assert pf.particles.tobytes() == twin.particles.tobytes() and pf.x.tobytes() == twin.x.tobytes()


def test_without_the_gate_a_depth_no_particle_explains_keeps_the_weights(tan, arctic):
    pf = TerrainParticleFilter(tan, [20e3, 20e3, 0.0], np.diag([30.0 ** 2, 30.0 ** 2, 0.0]), 2.0, 5.0, 60, 1,
                               terrain=arctic, gate_probability=0.0)
    for k in range(20):
        pf.step([0.5, 0.0], 1.0, [arctic.depth_at(20e3 + 0.5 * k, 20e3), 0.0])
    log_weights, resamples = pf.log_weights.copy(), pf.resamples
    pf.update([arctic.depth_at(20e3 + 10.0, 20e3) + 1e4, 0.0])  # every likelihood underflows
    assert pf.uninformative == 1 and pf.gated == 0 and pf.resamples == resamples
    np.testing.assert_allclose(pf.log_weights, log_weights, rtol=1e-12, atol=1e-12)  # the weights stay
    assert pf.ess > 1.5


def test_a_gated_streak_ends_after_the_patience(tan, arctic):
    """A depth offset that lasts (a map bias, or a lost filter) is used again after gate_patience gated depths."""
    pf = TerrainParticleFilter(tan, [20e3, 20e3, 0.0], np.diag([10.0 ** 2, 10.0 ** 2, 0.0]), 2.0, 5.0, 100, 2,
                               terrain=arctic, gate_patience=3)
    for k in range(8):
        pf.step([0.5, 0.0], 1.0, [arctic.depth_at(20e3 + 0.5 * k, 20e3) + 500.0, 0.0])
    assert pf.gated == 6  # gated, gated, gated, used, then the same again


def test_refusals_are_value_errors_that_leave_the_filter_unchanged(tan, arctic):
    pf = TerrainParticleFilter(tan, [20e3, 20e3, 0.0], np.diag([100.0, 100.0, 0.0]), "fuzzy", 5.0, 50, 0, terrain=arctic)
    pf.step([0.5, 0.0], 1.0, [arctic.depth_at(20e3, 20e3), 0.0])
    before = pf.checkpoint()
    with pytest.raises(ValueError, match="finite range"):
        pf.step([1e308, 1e308], 1e300, [100.0, 0.0])
    after = pf.checkpoint()
    for k in before:
        a, b = before[k], after[k]
        assert (np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b), k
    twin = TerrainParticleFilter(tan, [20e3, 20e3, 0.0], np.diag([100.0, 100.0, 0.0]), "fuzzy", 5.0, 50, 0, terrain=arctic)
    twin.step([0.5, 0.0], 1.0, [arctic.depth_at(20e3, 20e3), 0.0])
    pf.step([0.5, 0.0], 1.0, [arctic.depth_at(20e3 + 0.5, 20e3), 0.0])
    twin.step([0.5, 0.0], 1.0, [arctic.depth_at(20e3 + 0.5, 20e3), 0.0])
    assert pf.particles.tobytes() == twin.particles.tobytes()


def test_a_compass_heading_is_wrapped_and_an_absurd_one_refused(tan, arctic):
    """A heading of 2 pi + 0.25 is the heading 0.25 (bit-identical run); one of 1e300 rad, and a current p that
    moves every particle past the covariance's finite range, are refused naming the argument, state unchanged."""
    P0 = np.diag([100.0, 100.0, 0.0])
    pf, twin = (TerrainParticleFilter(tan, [20e3, 20e3, 0.0], P0, 3.0, 5.0, 50, 4, terrain=arctic) for _ in range(2))
    depth = arctic.depth_at(20e3, 20e3)
    pf.step([0.5, 0.0], 1.0, [depth, 0.25 + 2.0 * np.pi])
    twin.step([0.5, 0.0], 1.0, [depth, 0.25])
    assert np.all(np.abs(pf.particles[2] - 0.25) < 1e-15)
    assert np.allclose(pf.x, twin.x, rtol=0, atol=1e-9)
    before = pf.checkpoint()
    for z, p, match in (([depth, 1e300], None, r"z\[1\], the compass heading"),
                        ([depth, 0.0], [1e308, 1e308], "not finite")):
        with pytest.raises(ValueError, match=match):
            pf.step([0.5, 0.0], 1.0, z, p)
        after = pf.checkpoint()
        for k in before:
            a, b = before[k], after[k]
            assert (np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b), k
    pf.step([0.5, 0.0], 1.0, [depth, -0.25 - 4.0 * np.pi])
    assert np.all(np.abs(pf.particles[2] + 0.25) < 1e-14) and np.isfinite(pf.P).all()


def test_the_one_frame_step_equals_the_contracts_step_in_every_case(tan, arctic):
    """TerrainParticleFilter.step takes its plain case (float64 arrays, a float dt, every value finite, the model's
    p) in one frame; against the contract's own step (FilterBase.step: checks, transaction, _advance) on a twin, the
    same return values and refusals, and the same state after every call."""
    from abyssal.runtime.contract import FilterBase

    truth, Z = straight_track(tan, arctic, 120)
    P0 = np.diag([50.0 ** 2, 50.0 ** 2, 0.0])
    for sigma in (2.0, "fuzzy"):
        one, contract = (TerrainParticleFilter(tan, [20e3 + 80.0, 20e3 - 60.0, 0.0], P0, sigma, 5.0, 300, 3,
                                               terrain=arctic) for _ in range(2))
        for k in range(120):
            u, z = np.array([0.5, 0.01 * (k % 3)]), Z[k].copy()
            args = [(u, 1.0, z), (u, 1.0, np.array([z[0], 7.0])), (list(u), 1.0, z), (u, 1.0, np.array([np.nan, 0.1])),
                    (u, 1.0, None), (u, 1.0, np.array([z[0], 1e300])), (u, np.float64(0.5), z)][k % 7]
            outcomes = []
            for flt, step in ((one, one.step), (contract, lambda *a, f=contract: FilterBase.step(f, *a))):
                try:
                    outcomes.append(step(*args))
                except ValueError as error:
                    outcomes.append(str(error))
            assert outcomes[0] == outcomes[1], k
            a, b = one.checkpoint(), contract.checkpoint()
            assert all(np.array_equal(a[key], b[key]) if isinstance(a[key], np.ndarray) else a[key] == b[key]
                       for key in a), k
            assert (one.sigma, one.gated, one.resamples) == (contract.sigma, contract.gated, contract.resamples), k
