"""A Kalman filter's plain step(u, dt, z) is one C call from Python (runtime/c/abyssal_kalman_python.c, installed as
the filter's own ``step``); every other case goes to the class's step. Against the class's step itself (the checked
path, which holds the contract's rules and messages): the same return values, the same refusals with the same
messages, the same warnings at the caller's line, and every byte of the filter object's state and of its call block
equal after every call of a sequence that mixes plain calls with all the cases the one call hands on."""
from __future__ import annotations

import gc
import sys
import threading
import warnings
import weakref

import numpy as np
import pytest

import abyssal.generated
from abyssal.runtime import CKF, EKF, UKF
from abyssal.runtime.contract import LongStepWarning
from abyssal.runtime.filters.kalman.engine import KalmanFilter


@pytest.fixture(scope="module")
def rov():
    return abyssal.generated.load("rov4dof")


def make(cls, rov):
    n = rov.n_x
    return cls(rov, np.full(n, 0.1), 0.2 * np.eye(n), 1e-3 * np.eye(n), np.diag([0.1, 0.1, 0.05, 0.01]))


def checked(flt):
    """flt with the class's step as its own (the path every case but the plain one takes)."""
    flt.step = KalmanFilter.step.__get__(flt)
    return flt


def outcome(call):
    """What a call did: its value, or its exception's type and message; and the warnings it raised with their line."""
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        try:
            value = ("returned", call())
        except Exception as error:  # noqa: BLE001 - the exception is the outcome compared
            value = ("raised", type(error).__name__, str(error))
    return value, [(w.category.__name__, str(w.message), w.filename, w.lineno) for w in said]


def calls(rov):
    """(label, arguments, keywords) of a sequence: plain steps and predicts, and every case the one call hands on."""
    rng = np.random.default_rng(3)
    tau, n_p = np.array([5.0, 1.0, 2.0, 0.1]), rov.n_p
    z = lambda: 0.5 + 0.05 * rng.normal(size=4)  # noqa: E731
    out = [("watched" if k < 8 else "plain", (tau + rng.normal(size=4), 0.1, z()), {}) for k in range(12)]
    out += [
        ("predict only", (tau, 0.1), {}), ("z None", (tau, 0.1, None), {}), ("p None", (tau, 0.1, z(), None), {}),
        ("missing entries", (tau, 0.1, np.array([0.5, np.nan, 0.5, np.nan])), {}),
        ("numpy dt", (tau, np.float64(0.1), z()), {}), ("int dt", (tau, 1, z()), {}),
        ("list u", (list(tau), 0.1, z()), {}), ("float32 z", (tau, 0.1, z().astype(np.float32)), {}),
        ("strided u", (np.repeat(tau, 2)[::2], 0.1, z()), {}), ("z keyword", (tau, 0.1), {"z": z()}),
        ("own p", (tau, 0.1, z(), np.asarray(rov.p_default, dtype=float)), {}),
        ("after own p", (tau, 0.1, z()), {}),
        ("NaN u", (np.array([np.nan, 0, 0, 0.0]), 0.1, z()), {}), ("negative dt", (tau, -0.1, z()), {}),
        ("zero dt", (tau, 0.0, z()), {}), ("inf z", (tau, 0.1, np.array([np.inf, 0, 0, 0.0])), {}),
        ("NaN p", (tau, 0.1, z(), np.full(n_p, np.nan)), {}), ("short u", (tau[:3], 0.1, z()), {}),
        ("long z", (tau, 0.1, np.zeros(5)), {}), ("string dt", (tau, "0.1", z()), {}),
        ("too many", (tau, 0.1, z(), None, 1), {}), ("unknown keyword", (tau, 0.1), {"y": z()}),
        ("beyond max_dt", (tau, 0.8, z()), {}), ("beyond max_dt again", (tau, 0.8, z()), {}),
    ]
    out += [("plain", (tau + rng.normal(size=4), 0.1, z()), {}) for _ in range(5)]
    return out


def runs_the_classs_step(call) -> bool:
    """Whether call() ran a frame of the class's step (the checked path)."""
    seen = []
    sys.setprofile(lambda frame, event, arg: seen.append(frame.f_code) if event == "call" else None)
    try:
        call()
    except Exception:  # noqa: BLE001,S110 - only the path is asked here
        pass
    finally:
        sys.setprofile(None)
    return KalmanFilter.step.__code__ in seen


#: the cases the one C call takes itself once the unit watch is done (the rest it hands to the class's step)
ONE_CALL = {"plain", "predict only", "z None", "p None", "missing entries", "numpy dt", "NaN u", "negative dt", "zero dt",
            "inf z", "beyond max_dt", "beyond max_dt again"}


@pytest.mark.parametrize("cls", [EKF, UKF, CKF])
def test_the_one_call_step_equals_the_classs_step_in_every_case(rov, cls):
    fast, slow = make(cls, rov), checked(make(cls, rov))
    assert type(fast.step).__name__ == "StepCall", "Python's headers are here: the plain step must be one C call"
    paths = {}
    for label, args, kwargs in calls(rov):
        twin = make(cls, rov)
        twin._committed[...] = fast._committed
        twin._p[:], twin._p_is_default, twin._unit_watch = fast._p, fast._p_is_default, fast._unit_watch
        paths.setdefault(label, set()).add(runs_the_classs_step(lambda: twin.step(*args, **kwargs)))
        got, want = outcome(lambda: fast.step(*args, **kwargs)), outcome(lambda: slow.step(*args, **kwargs))  # one line
        assert got == want, label
        assert fast._committed.tobytes() == slow._committed.tobytes(), label  # (past it: scratch, with pointers)
        assert fast._io.tobytes() == slow._io.tobytes() and fast.code == slow.code, label
        assert (fast._p_is_default, fast._max_dt) == (slow._p_is_default, slow._max_dt), label
    # (arguments Python cannot bind to the class's step raise its TypeError before any frame runs)
    one_call = {label for label, ran in paths.items() if ran == {False}} - {"too many", "unknown keyword"}
    assert one_call == ONE_CALL, "the plain cases are one C call, the others the class's step"


def test_a_long_step_is_said_once_at_the_callers_line(rov):
    flt = make(CKF, rov)
    for _ in range(9):  # past the unit watch's first updates: the plain case
        flt.step(np.array([5.0, 1.0, 2.0, 0.1]), 0.1, np.full(4, 0.5))
    assert flt._unit_watch is None
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        flt.step(np.array([5.0, 1.0, 2.0, 0.1]), 0.8, np.full(4, 0.5)); line = said and said[0].lineno  # noqa: E702
        flt.step(np.array([5.0, 1.0, 2.0, 0.1]), 0.8, np.full(4, 0.5))
    assert [w.category for w in said] == [LongStepWarning]
    assert said[0].filename == __file__ and line == said[0].lineno


def test_a_step_while_another_thread_holds_the_filter_is_refused_and_changes_nothing(rov):
    flt = make(EKF, rov)
    flt.step(np.array([5.0, 1.0, 2.0, 0.1]), 0.1, np.full(4, 0.5))
    before = flt._committed.tobytes()
    holding, release = threading.Event(), threading.Event()

    def hold():
        with flt._lock:
            holding.set()
            release.wait(10)
    other = threading.Thread(target=hold)
    other.start()
    try:
        assert holding.wait(10)
        with pytest.raises(RuntimeError, match="two threads at once"):
            flt.step(np.array([5.0, 1.0, 2.0, 0.1]), 0.1, np.full(4, 0.5))
    finally:
        release.set()
        other.join(10)
    assert flt._committed.tobytes() == before


def test_a_subclass_keeps_its_own_step_and_a_dropped_filter_is_freed(rov):
    class Counting(CKF):
        def step(self, u, dt, z=None, p=None):
            self.count = getattr(self, "count", 0) + 1
            return super().step(u, dt, z, p)
    flt = make(Counting, rov)
    flt.step(np.array([5.0, 1.0, 2.0, 0.1]), 0.1, np.full(4, 0.5))
    assert flt.count == 1 and "step" not in vars(flt)
    gone = make(CKF, rov)
    memory = weakref.ref(gone._memory.base if gone._memory.base is not None else gone._memory)
    probe = weakref.ref(gone)
    del gone
    gc.collect()
    assert probe() is None and memory() is None
