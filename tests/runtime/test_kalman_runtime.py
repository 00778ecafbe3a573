"""The C runtime of the Kalman family (runtime/c) against references not produced by it: scipy's chi-square
quantiles, the contract's covariance checks and NumPy's eigen-decomposition repair, NumPy's NIS; and the properties
of its filter object (a refused call changes no byte of the state, the object is a relocatable checkpoint)."""
from __future__ import annotations

import ctypes
import math

import numpy as np
import pytest
from scipy.stats import chi2

import abyssal.generated
from abyssal.runtime.compiled import kalman as kr
from abyssal.runtime import CKF, EKF, UKF, contract
from abyssal.runtime.numerics import factorable_covariance, repair_covariance


@pytest.fixture(scope="module")
def runtime():
    return kr.KalmanRuntime.standalone()


@pytest.fixture(scope="module")
def rov():
    return abyssal.generated.load("rov4dof")


def ptr(a: np.ndarray) -> int:
    return a.ctypes.data


def test_chi_square_quantiles_equal_scipy(runtime):
    worst = 0.0
    for dof in range(1, 41):
        for p in (1e-300, 1e-100, 1e-12, 1e-10, 1e-6, 1e-3, 0.05, 0.5, 0.9, 0.999999):
            worst = max(worst, abs(runtime.chi2_isf(p, dof) / chi2.isf(p, dof) - 1.0))
    assert worst < 1e-12
    assert math.isnan(runtime.chi2_isf(0.0, 3)) and math.isnan(runtime.chi2_isf(1.0, 3))
    assert math.isnan(runtime.chi2_isf(0.5, 0))


def covariance_cases(rng):
    A = rng.normal(size=(6, 6))
    v = rng.normal(size=(6, 1))
    yield "positive definite", A @ A.T + np.eye(6)
    yield "rank one", v @ v.T
    yield "zero", np.zeros((6, 6))
    yield "singular", np.diag([0.0, 0.0, 1.0, 2.0, 3.0, 4.0])
    yield "indefinite", np.diag([1.0, 1.0, 1.0, 1.0, 1.0, -1e-3])
    yield "asymmetric", np.eye(6) + np.triu(np.ones((6, 6)), 1) * 1e-3
    yield "roundoff asymmetry", A @ A.T + np.eye(6) + np.triu(np.full((6, 6), 1e-13), 1)
    yield "scales 1e-10 .. 1e30", np.diag([1e-10, 1.0, 1e30, 5.0, 1e-3, 2.0])
    yield "near 1e308", 1e307 * np.eye(6)
    yield "negative near 1e308", -1e308 * np.eye(6)
    yield "not finite", np.diag([1.0] * 5 + [np.nan])
    yield "infinite", np.diag([1.0] * 5 + [np.inf])


@pytest.mark.parametrize("definite", [False, True])
def test_covariance_checks_agree_with_the_contract(runtime, definite):
    scratch = np.zeros(3 * 36 + 6)
    for name, A in covariance_cases(np.random.default_rng(3)):
        A = np.asfortranarray(A)
        try:
            contract.check_covariance(A, 6, "A", definite=definite)
            python_accepts = True
        except ValueError:
            python_accepts = False
        c_accepts = runtime.covariance_problem(6, ptr(A), int(definite), ptr(scratch)) == 0
        assert c_accepts == python_accepts, name


def test_repair_equals_numpy(runtime):
    rng = np.random.default_rng(5)
    Q = np.asfortranarray(0.3 * np.eye(6))
    scratch, out = np.zeros(3 * 36 + 6), np.zeros((6, 6), order="F")
    for name, A in covariance_cases(rng):
        if not np.all(np.isfinite(A)):
            assert runtime.repair_covariance(6, ptr(np.asfortranarray(A)), ptr(Q), 1e-10, ptr(out), ptr(scratch)) == -1
            continue
        A = np.asfortranarray(A)
        assert runtime.repair_covariance(6, ptr(A), ptr(Q), 1e-10, ptr(out), ptr(scratch)) == 0, name
        with np.errstate(all="ignore"):
            expected = factorable_covariance(A, Q, 1e-10)
        if not np.all(np.isfinite(expected)):  # NumPy's (P + P^T) / 2 overflows near 1e308; the C halves first
            assert np.all(np.isfinite(out)) and np.all(np.linalg.eigvalsh(out) > 0), name
            continue
        scale = np.abs(expected).max()
        assert np.abs(out - expected).max() <= 1e-12 * scale, name
        assert np.array_equal(out, out.T), name
        if np.any(A):
            assert np.abs(out - repair_covariance(A, 1e-10)).max() <= 1e-12 * scale, name


def test_nis_equals_numpy_and_is_infinite_when_S_is_not_definite(runtime):
    rng = np.random.default_rng(1)
    scratch = np.zeros(4 * 4 + 4)
    for _ in range(20):
        B = rng.normal(size=(4, 4))
        S, nu = np.asfortranarray(B @ B.T + 0.1 * np.eye(4)), rng.normal(size=4)
        assert runtime.nis(4, ptr(nu), ptr(S), ptr(scratch)) == pytest.approx(nu @ np.linalg.solve(S, nu), rel=1e-12)
    S = np.asfortranarray(np.diag([1.0, 1.0, -1.0, 1.0]))
    assert runtime.nis(4, ptr(np.ones(4)), ptr(S), ptr(scratch)) == math.inf
    assert runtime.nis(4, ptr(np.full(4, 1e200)), ptr(np.asfortranarray(np.eye(4))), ptr(scratch)) == math.inf


def test_the_option_struct_mirrors_the_c_one(runtime):
    ckf = runtime.kalman_default_options(kr.FILTERS["ckf"])
    assert (ckf.filter, ckf.alpha, ckf.beta, ckf.kappa, ckf.sigma, ckf.gamma) == (3, 1.0, 2.0, 0.0, 15.0, 1.345)
    assert (ckf.gate_probability, ckf.gate_patience, ckf.gate_inflation) == (1e-10, 5, 4.0)
    assert (ckf.growth_limit, ckf.max_substeps, ckf.repair_floor) == (1e3, 64, 1e-10)
    assert (ckf.huber_iterations, ckf.gate_max_inflations, ckf.noise, ckf.history_entries, ckf.history_seconds,
            ckf.smoothing) == (3, 10, kr.NOISE["step"], 0, 2.0, 0)
    header = kr.GateHeader()
    assert ctypes.sizeof(header) == 80  # abyssal_gate: 1 + 2 * 4 / 8 + 8 eight-byte fields


@pytest.mark.parametrize("code, words", [
    (kr.E_U, "u has non-finite"), (kr.E_DT, "dt must be"), (kr.E_Z, "use NaN"), (kr.E_P, "parameters) has non-finite"),
    (kr.E_DIVERGED, "diverged"), (kr.E_UNSTABLE, "max_substeps"), (kr.E_UNSTABLE_INPUT, "u or p: the predict blew up"),
    (kr.E_SIGMA_POINTS, "alpha"), (kr.E_GATE, "gate_"),
    (kr.E_SUBSTEPS, "growth_limit"), (kr.E_MODEL, "model"), (kr.E_R, "R:"), (kr.E_MEMORY, "memory"),
    (kr.E_SENSOR, "sensor"), (kr.E_TIME, "t: not finite"), (kr.E_TOO_LATE, "older than the filter's history"),
    (kr.E_LIVE, "initialised filter"), (kr.E_UNSTABLE_STATE, "x or P"), (kr.E_OPTIONS, "history_entries"),
])
def test_the_python_codes_mirror_the_c_messages(runtime, code, words):
    assert words in runtime.message(code)


@pytest.mark.parametrize("options, code", [
    ({"alpha": 1e200}, kr.E_SIGMA_POINTS), ({"alpha": 0.0}, kr.E_SIGMA_POINTS), ({"kappa": -12.0}, kr.E_SIGMA_POINTS),
    ({"gate_probability": 1.0}, kr.E_GATE), ({"gate_patience": 0}, kr.E_GATE), ({"gate_inflation": 0.5}, kr.E_GATE),
    ({"growth_limit": 1.0}, kr.E_SUBSTEPS), ({"max_substeps": 0}, kr.E_SUBSTEPS), ({"repair_floor": 0.0}, kr.E_SUBSTEPS),
])
def test_options_are_checked_in_c(rov, options, code):
    runtime = kr.KalmanRuntime.of(rov)
    o = runtime.options("ukf", **options)
    assert runtime.kalman_check_options(runtime.descriptor, o) == code
    assert runtime.kalman_work_size(runtime.descriptor, o) == 0


def state_bytes(flt) -> bytes:
    """The bytes of the filter object that are its state: everything up to the end of the committed region but
    the two spare buffer sets of x and P and the spare innovation/S buffer (scratch of the next call)."""
    memory = flt._memory
    spare = [flt._x[k] for k in range(kr.SETS) if k != flt._cur] + [flt._P[k] for k in range(kr.SETS) if k != flt._cur]
    if flt._reported[0] >= 0:
        spare += [flt._innovation[1 - flt._reported[0]], flt._S[1 - flt._reported[0]]]
    mask = np.ones(flt._committed.nbytes, dtype=bool)
    base = memory.ctypes.data
    for a in spare:
        start = a.ctypes.data - base
        mask[start:start + a.nbytes] = False
    return np.frombuffer(flt._committed.tobytes(), np.uint8)[mask].tobytes()


def test_a_refused_call_changes_no_byte_of_the_state(rov):
    n = rov.n_x
    flt = CKF(rov, np.full(n, 0.5), 0.2 * np.eye(n), 1e-3 * np.eye(n), np.diag([0.1, 0.1, 0.05, 0.01]))
    tau, z = np.array([5.0, 1.0, 2.0, 0.1]), np.array([0.5, 0.5, 0.5, 0.5])
    for _ in range(3):
        flt.step(tau, 0.1, z)
    before = state_bytes(flt)
    for call in (lambda: flt.step(np.array([np.nan, 0, 0, 0]), 0.1, z), lambda: flt.step(tau, -1.0, z),
                 lambda: flt.step(tau, 0.1, np.array([np.inf, 0, 0, 0])),
                 lambda: flt.step(tau, 0.1, z, np.full(rov.n_p, np.nan))):
        with pytest.raises(ValueError):
            call()
        assert state_bytes(flt) == before
    diverging = CKF(rov, np.full(n, 1e150), 1e290 * np.eye(n), np.eye(n), np.eye(4))
    before = state_bytes(diverging)
    with pytest.raises(ValueError, match="state given to the filter"):
        diverging.predict(tau, 0.1)
    assert state_bytes(diverging) == before


def c_step(runtime):
    fn = runtime.cdll.abyssal_kalman_step
    fn.restype = ctypes.c_int
    fn.argtypes = [ctypes.c_void_p] * 3 + [ctypes.c_double] + [ctypes.c_void_p] * 3
    return fn


@pytest.mark.parametrize("cls", [EKF, CKF, UKF])
def test_the_filter_object_is_a_relocatable_checkpoint(rov, cls):
    """The object holds no pointer at all: its memory copied to another buffer is a working filter."""
    n = rov.n_x
    tau = np.array([5.0, 1.0, 2.0, 0.1])
    flt = cls(rov, np.full(n, 0.5), 0.2 * np.eye(n), 1e-3 * np.eye(n), np.diag([0.1, 0.1, 0.05, 0.01]),
              history_seconds=1.0)
    flt.step(tau, 0.1, np.array([0.5, 0.5, 0.5, 0.5]))
    runtime = flt._runtime
    step = c_step(runtime)
    copy = flt._memory.copy()
    z = np.array([0.6, np.nan, 0.55, 0.5])
    for _ in range(5):
        flt.step(tau, 0.1, z)
        assert step(ptr(copy), runtime.descriptor, ptr(tau), 0.1, ptr(z), None, None) == kr.UPDATED
    assert copy.tobytes()[: flt._committed.nbytes] == flt._memory.tobytes()[: flt._committed.nbytes]


CHILD = """
import sys, numpy as np, ctypes, abyssal.generated
from abyssal.runtime.compiled import kalman as kr
rov = abyssal.generated.load("rov4dof")
runtime = kr.KalmanRuntime.of(rov)
memory = np.load(sys.argv[1])
step = runtime.cdll.abyssal_kalman_step
step.restype, step.argtypes = ctypes.c_int, [ctypes.c_void_p] * 3 + [ctypes.c_double] + [ctypes.c_void_p] * 3
tau, z = np.array([5.0, 1.0, 2.0, 0.1]), np.array([0.6, np.nan, 0.55, 0.5])
codes = [step(memory.ctypes.data, runtime.descriptor, tau.ctypes.data, 0.1, z.ctypes.data, None, None) for _ in range(5)]
np.save(sys.argv[2], memory)
print(codes)
"""


def test_a_filter_object_saved_in_one_process_runs_in_another(rov, tmp_path):
    """The memory of a filter written to a file and read back by another process (another address space, the
    model's descriptor elsewhere) steps exactly as the original does (issue 33: it used to hold a pointer)."""
    import subprocess
    import sys
    n = rov.n_x
    tau, z = np.array([5.0, 1.0, 2.0, 0.1]), np.array([0.6, np.nan, 0.55, 0.5])
    flt = CKF(rov, np.full(n, 0.5), 0.2 * np.eye(n), 1e-3 * np.eye(n), np.diag([0.1, 0.1, 0.05, 0.01]))
    flt.step(tau, 0.1, z)
    np.save(tmp_path / "saved.npy", flt._memory)
    done = subprocess.run([sys.executable, "-c", CHILD, str(tmp_path / "saved.npy"), str(tmp_path / "after.npy")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    for _ in range(5):
        flt.step(tau, 0.1, z)
    after = np.load(tmp_path / "after.npy")
    assert after.tobytes()[: flt._committed.nbytes] == flt._memory.tobytes()[: flt._committed.nbytes]


def test_another_models_descriptor_is_refused_and_changes_nothing(rov):
    cv = abyssal.generated.load("linear_cv")
    flt = CKF(rov, np.zeros(12), np.eye(12), 1e-3 * np.eye(12), np.eye(4))
    before = flt._memory.copy()
    tau, z = np.array([5.0, 1.0, 2.0, 0.1]), np.zeros(4)
    assert c_step(flt._runtime)(ptr(flt._memory), kr.KalmanRuntime.of(cv).descriptor, ptr(tau), 0.1, ptr(z), None,
                                None) == kr.E_MODEL
    assert flt._memory.tobytes() == before.tobytes()


def test_init_on_a_live_filter_is_refused_and_changes_nothing(rov):
    runtime = kr.KalmanRuntime.of(rov)
    flt = CKF(rov, np.zeros(12), np.eye(12), 1e-3 * np.eye(12), np.eye(4))
    before = flt._memory.copy()
    o = runtime.options("ckf")
    bad_x0 = np.full(12, np.nan)
    eye, R = np.eye(12), np.eye(4)
    code = runtime.kalman_init(ptr(flt._memory), flt._memory.nbytes, runtime.descriptor, o, ptr(bad_x0), ptr(eye), ptr(eye),
                               ptr(R), 0.0, None)
    assert code == kr.E_LIVE and flt._memory.tobytes() == before.tobytes()
    runtime.kalman_release(ptr(before))  # released memory may be built again
    assert runtime.kalman_init(ptr(before), before.nbytes, runtime.descriptor, o, ptr(np.zeros(12)), ptr(eye), ptr(eye),
                               ptr(R), 0.0, None) == kr.OK


def test_get_report_accepts_null(rov):
    flt = CKF(rov, np.zeros(12), np.eye(12), 1e-3 * np.eye(12), np.eye(4))
    fn = flt._runtime.cdll.abyssal_kalman_get_report
    fn.restype, fn.argtypes = None, [ctypes.c_void_p, ctypes.c_void_p]
    fn(ptr(flt._memory), None)  # no crash: nothing is written
    fn(None, None)
