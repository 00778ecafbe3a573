"""Threads section of `abyssal bench`: OpenMP in the ``<name>_batch`` entry points vs the
``concurrent.futures`` split of ``runtime/compiled/batches.py::ParallelBatch``.

The shipped code runs the generated ``<name>_batch`` (a serial C loop over N column-major
slices, one stack work array) in contiguous chunks, one per core, on a process-wide
``ThreadPoolExecutor`` (ctypes releases the GIL; the calling thread runs the first chunk). The
alternative is the parallel loop inside C: this section compiles, at bench time, a small shared
library (OMP_SOURCE, ``-fopenmp`` plus the project's cflags) whose ``omp_batch`` does exactly what
``<name>_batch`` does, inside ``#pragma omp parallel num_threads(T)`` with per-thread arg/res
pointer arrays and iw/w work arrays and ``#pragma omp for schedule(static)`` over the slices. It
calls the generated CasADi function ``<name>(arg, res, iw, w, mem)`` through a function pointer
taken from the loaded generated library: the per-slice call the generated ``_batch`` makes, so it
costs what an OpenMP ``_batch`` would, without touching the committed generated C.

Per batch (µs, ``bench.median_time``), for rov4dof ``ckf_step`` (inputs from a CPF on the seed-000
scenario after 20 steps) and cn2d ``ukf_predict`` / ``ukf_update`` (a particle cloud as in
verify_cn), at N = 64, 300, 1000, 3000 slices (``--quick``: 64 and 300):
  (a) the serial ``_batch`` (one thread, the floor of the work),
  (b) ``ParallelBatch`` (concurrent.futures, min(cores, 4) chunks),
  (c) OpenMP with 2 threads, (d) OpenMP with 1 thread (its own overhead),
with (b)/(a), (c)/(a) and (c)/(b) ("OpenMP time as a fraction of concurrent.futures"). Every
method writes its own outputs, checked bit-identical to (a) before timing.

Whole filter step: the CPF (seed-000 scenario, sea state 3) at N = 300 and 3000 with the shipped
ParallelBatch, and with ParallelBatch's evaluation swapped for the OpenMP call for that run only
(``openmp_parallel_batch``, a bench-only patch of the class, undone afterwards): the median of 3
alternating rounds of ``median_time`` each (1 with ``--quick``), and process CPU time per step;
the two filters must hold bit-identical particles after the same 20 steps.

libgomp's wait policy (full mode only): after a parallel region its idle threads spin
(GOMP_SPINCOUNT, 300000 pause iterations by default) before they sleep, which on 2 cores takes a
core from anything else. libgomp reads OMP_WAIT_POLICY / GOMP_SPINCOUNT once, when it loads, so
each setting of WAIT_POLICIES is measured in a fresh child process: the ParallelBatch peer and
OpenMP x2 on cn2d ukf_predict (N = 300), rov4dof ckf_step (N = 300, 3000) and the CPF step
(N = 300), wall and process CPU time. Two processes at once (PAIR_VARIANTS: as two Dask workers on
the 2 cores), each stepping its own CPF at N = 300 for 2 s after a common start: ms per step.

Fork check: a child process loads the OpenMP library, runs a batch on 2 threads, ``os.fork()``s
(right after the batch, and again after 1 s idle), and the forked child runs the batch on 2
threads (and on 1) under a deadline; a child that does not finish is killed and reported as
hanging. (The OpenMP standard says nothing about fork; GNU libgomp does not rebuild its thread
pool in a forked child.)

Targets (reported, never asserted): OpenMP / concurrent.futures time at N = 300 and 3000 for
rov4dof ckf_step and for the CPF step, <= 1 (met: OpenMP is faster); results bit-identical;
the forked child does not hang. This section loads libgomp into the process: it is the last of
``bench.SECTIONS``.
"""
from __future__ import annotations

import ctypes
import itertools
import json
import os
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..compiled.batches import PARALLEL_MIN_SLICES, ParallelBatch
from .bench import median_time, target

SIZES = (64, 300, 1000, 3000)
QUICK_SIZES = (64, 300)
STEP_SIZES = (300, 3000)
OMP_THREADS = 2
FORK_TIMEOUT = 5.0  # seconds a forked child's batch may take (it takes milliseconds)

OMP_SOURCE = r"""
#include <omp.h>
#ifndef _OPENMP
#error "compile with -fopenmp"
#endif

typedef double casadi_real;
typedef long long int casadi_int;
typedef int (*casadi_function)(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);

#define EXPORT __attribute__((visibility("default")))

/* What the generated <name>_batch does (symbolic/codegen.py BATCH_TEMPLATE) over an OpenMP team:
 * fn is <name>; slice j reads arg[k] + j*arg_step[k] and writes res[k] + j*res_step[k] (a step of 0
 * shares the argument). Each thread has its own arg/res pointer arrays and iw/w work arrays (on its
 * stack, where the generated entry point has them) and a contiguous block of slices
 * (schedule(static)). The serial loop stops at the first failing slice; here every slice is
 * evaluated, and the result is still 0 or 1 + j of the first (lowest) failing slice. */
EXPORT int omp_batch(casadi_function fn, casadi_int sz_arg, casadi_int sz_res, casadi_int sz_iw, casadi_int sz_w,
                     casadi_int n_in, casadi_int n_out, casadi_int N,
                     const casadi_real** arg, const casadi_int* arg_step,
                     casadi_real** res, const casadi_int* res_step, int n_threads) {
  casadi_int first = N;
  #pragma omp parallel num_threads(n_threads) reduction(min:first)
  {
    const casadi_real* a[sz_arg > 0 ? sz_arg : 1];
    casadi_real* r[sz_res > 0 ? sz_res : 1];
    casadi_int iw[sz_iw > 0 ? sz_iw : 1];
    casadi_real w[sz_w > 0 ? sz_w : 1];
    casadi_int j, k;
    for (k = 0; k < sz_arg; ++k) a[k] = 0;
    for (k = 0; k < sz_res; ++k) r[k] = 0;
    #pragma omp for schedule(static)
    for (j = 0; j < N; ++j) {
      for (k = 0; k < n_in; ++k) a[k] = arg[k] ? arg[k] + j * arg_step[k] : 0;
      for (k = 0; k < n_out; ++k) r[k] = res[k] ? res[k] + j * res_step[k] : 0;
      if (fn(a, r, iw, w, 0) && j < first) first = j;
    }
  }
  return first < N ? (int)(1 + first) : 0;
}

/* The size of the team a parallel region of n_threads gets (1 if OpenMP did not start threads). */
EXPORT int omp_team_size(int n_threads) {
  int size = 0;
  #pragma omp parallel num_threads(n_threads)
  {
    #pragma omp single
    size = omp_get_num_threads();
  }
  return size;
}

/* For tests of the failure report: a function of CasADi's signature that copies arg[0][0] to
 * res[0][0] and fails (returns 1) when it is negative. */
EXPORT int omp_test_fail_if_negative(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem) {
  (void)iw; (void)w; (void)mem;
  res[0][0] = arg[0][0];
  return arg[0][0] < 0;
}
"""


# ---------------------------------------------------------------------------------------------
# the OpenMP library


class OpenMPUnavailable(RuntimeError):
    """The C compiler does not build OMP_SOURCE with -fopenmp."""


def build_omp_library(folder) -> Path:
    """Compile OMP_SOURCE with the project's compiler and cflags plus -fopenmp into folder/libomp_batch.so."""
    from abyssal.generated.build import cflags, compiler

    folder = Path(folder)
    (folder / "omp_batch.c").write_text(OMP_SOURCE)
    lib = folder / "libomp_batch.so"
    cmd = [compiler(), *cflags(), "-fopenmp", "-shared", str(folder / "omp_batch.c"), "-o", str(lib)]
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise OpenMPUnavailable(f"compiling the OpenMP batch failed: {' '.join(cmd)}\n{res.stderr[-4000:]}")
    return lib


def load_omp_library(path) -> ctypes.CDLL:
    lib = ctypes.CDLL(str(path))
    lib.omp_batch.restype = ctypes.c_int
    lib.omp_team_size.restype = ctypes.c_int
    lib.omp_team_size.argtypes = [ctypes.c_int]
    return lib


def function_pointer(fn) -> int:
    """Address of the generated CasADi function ``fn.name`` in its compiled library (``fn.library``)."""
    return ctypes.cast(ctypes.CDLL(str(fn.library))[fn.name], ctypes.c_void_p).value


class OmpBatch:
    """``omp_batch`` bound to the buffers of a ``fn.bind_batch`` binding: ``batch(N)`` evaluates
    slices 0..N-1 on `n_threads` OpenMP threads, like ``binding(N)`` does serially."""

    def __init__(self, lib: ctypes.CDLL, fn, binding, n_threads: int = OMP_THREADS):
        ext = fn.external
        self._call = lib.omp_batch
        self._name = fn.name
        self.capacity = binding.capacity
        self._binding = binding  # pins the buffers and the pointer arrays
        arg_ptrs, arg_steps, res_ptrs, res_steps = binding._args  # the serial binding's own pointer arrays
        self._head = (ctypes.c_void_p(function_pointer(fn)),
                      *(ctypes.c_longlong(v) for v in (ext.sz_arg(), ext.sz_res(), ext.sz_iw(), ext.sz_w(),
                                                         len(fn.inputs), len(fn.outputs))))
        self._tail = (arg_ptrs, arg_steps, res_ptrs, res_steps)
        self.n_threads = ctypes.c_int(n_threads)

    def __call__(self, n: int) -> None:
        if not 0 <= n <= self.capacity:
            raise ValueError(f"{self._name}: batch size {n} outside 0..{self.capacity} of the bound buffers")
        status = self._call(*self._head, ctypes.c_longlong(n), *self._tail, self.n_threads)
        if status:
            raise FloatingPointError(f"{self._name}: evaluation of slice {status - 1} failed")


class OpenMPParallelBatch(ParallelBatch):
    """Bench-only: a ``ParallelBatch`` whose evaluation is one ``omp_batch`` call over the whole
    buffers (made by ``openmp_parallel_batch``). Batches of fewer than ``PARALLEL_MIN_SLICES``
    slices run on the serial ``_batch`` (ParallelBatch keeps those, and any batch that fits its
    first chunk, on the calling thread; the filters timed here evaluate whole buffers);
    ``then(0, count)`` runs after the whole batch, so its NumPy work no longer overlaps."""

    _omp: OmpBatch
    _serial: object

    def __call__(self, count: int, then=None) -> None:
        if not 0 <= count <= self.capacity:
            raise ValueError(f"batch size {count} outside 0..{self.capacity} of the bound buffers")
        (self._omp if count >= PARALLEL_MIN_SLICES else self._serial)(count)
        if then is not None:
            then(0, count)


@contextmanager
def openmp_parallel_batch(lib: ctypes.CDLL, n_threads: int = OMP_THREADS):
    """Bench-only: every ``ParallelBatch`` built inside the block (e.g. by a filter's constructor)
    becomes an ``OpenMPParallelBatch`` on `n_threads` OpenMP threads, for its whole life. The
    class is restored on exit; batches built outside are untouched."""
    init = ParallelBatch.__init__

    def patched_init(self, fn, inputs, batched, outputs, capacity):
        init(self, fn, inputs, batched, outputs, capacity)
        self._omp = OmpBatch(lib, fn, fn.bind_batch(inputs, outputs, capacity), n_threads)
        self._serial = fn.bind_batch(inputs, outputs, capacity)
        self.__class__ = OpenMPParallelBatch

    ParallelBatch.__init__ = patched_init
    try:
        yield
    finally:
        ParallelBatch.__init__ = init


# ---------------------------------------------------------------------------------------------
# inputs


def _f(a) -> np.ndarray:
    return np.asfortranarray(np.array(a, dtype=np.float64))


def rov_step_inputs(n_max: int, steps: int = 20) -> tuple:
    """Inputs of rov4dof ``ckf_step`` over n_max slices, from the buffers of a CPF (seed-000
    scenario, sea state 3, N = n_max) after `steps` steps: (function, inputs, batched flags)."""
    from abyssal.generated import load

    from ..experiments.rov.scenario import SEA_STATES, RovScenario, make_filter, simulate

    bundle = load("rov4dof")
    scenario, sea = RovScenario(), SEA_STATES["3"]
    truth = simulate(bundle, scenario, sea, np.random.default_rng(0), n_steps=steps + 1)
    filt = make_filter("CPF", bundle, scenario, sea, n_max, np.random.default_rng(1))
    for k in range(steps):
        filt.step(truth.inputs[k], scenario.dt, truth.measurements[k])
    fused = filt.proposal._fused
    pb, ub = fused.predict, fused.update
    ins = [_f(a) for a in (pb.mean, pb.cov, pb.u, pb.p, pb.dt, pb.Q, ub.z, ub.R, fused.mask)]
    return bundle.function("ckf_step"), ins, [True, True, False, False, False, True, True, True, True]


def cn_inputs(n_max: int) -> dict:
    """Inputs of cn2d ``ukf_predict`` and ``ukf_update`` over n_max slices (a particle cloud as in
    verify_cn; the update takes the predict's outputs)."""
    from abyssal.generated import load

    bundle = load("cn2d")
    rng = np.random.default_rng(0)
    x = _f(rng.normal([100.0, -50.0], 20.0, (n_max, 2)).T)
    A = rng.normal(0, 3.0, (n_max, 2, 2))
    P = _f(np.moveaxis(A @ np.swapaxes(A, 1, 2) + np.eye(2), 0, -1))
    u, p, dt = np.array([1.5, 0.1, 0.3]), np.array([400.0, 300.0]), np.array([5.0])
    Q, R = np.diag([100.0, 100.0]).reshape(-1, order="F"), np.array([0.1])
    abk, z, mask = np.array([1.0, 0.0, 1.0]), np.array([480.0]), np.ones(1)
    predict = bundle.function("ukf_predict")
    xp, Pp, ok = _zeros_like_outputs(predict, n_max)
    predict.bind_batch([x, P, u, p, dt, Q, abk], [xp, Pp, ok], n_max)(n_max)
    return {
        "cn2d_ukf_predict": (predict, [x, P, u, p, dt, Q, abk], [True, True] + [False] * 5),
        "cn2d_ukf_update": (bundle.function("ukf_update"), [xp, Pp, z, p, R, mask, abk], [True, True] + [False] * 5),
    }


def _zeros_like_outputs(fn, n: int) -> list[np.ndarray]:
    return [np.zeros((s.shape[0], n) if s.shape[1] == 1 else (*s.shape, n), order="F") for s in fn.outputs]


def _head(inputs, batched, n: int) -> list[np.ndarray]:
    """The first n slices of each batched input (Fortran copies), shared inputs as they are."""
    return [_f(a[..., :n]) if b else a for a, b in zip(inputs, batched)]


# ---------------------------------------------------------------------------------------------
# measurements


def _timer(quick: bool):
    return (lambda fn: median_time(fn, repeat=3, min_time=0.01)) if quick else (lambda fn: median_time(fn))


def _cpu_per_call(fn, seconds: float) -> float:
    """Process CPU seconds per call of fn(), over a loop of about `seconds` of wall time."""
    t0 = time.perf_counter()
    fn()
    once = max(time.perf_counter() - t0, 1e-7)
    n = max(3, int(seconds / once))
    c0 = time.process_time()
    for _ in range(n):
        fn()
    return (time.process_time() - c0) / n


def compare_batches(lib, fn, inputs, batched, n: int, timer=None, cpu_seconds: float = 0.0) -> dict:
    """µs per batch of n slices through (a) serial _batch, (b) ParallelBatch, (c) OpenMP on
    OMP_THREADS threads, (d) OpenMP on 1; raises AssertionError unless all outputs are bit-identical."""
    ins = _head(inputs, batched, n)
    outs = {key: _zeros_like_outputs(fn, n) for key in ("serial", "futures", "omp2", "omp1")}
    calls = {
        "serial": fn.bind_batch(ins, outs["serial"], n),
        "futures": ParallelBatch(fn, ins, batched, outs["futures"], n),
        "omp2": OmpBatch(lib, fn, fn.bind_batch(ins, outs["omp2"], n), OMP_THREADS),
        "omp1": OmpBatch(lib, fn, fn.bind_batch(ins, outs["omp1"], n), 1),
    }
    for call in calls.values():
        call(n)
    for key in ("futures", "omp2", "omp1"):
        for s, a, b in zip(fn.outputs, outs["serial"], outs[key]):
            if not np.array_equal(a, b):  # exact (and NaN-free: the outputs are finite)
                raise AssertionError(f"{fn.name} output {s.name!r}: {key} differs from the serial _batch at N = {n}")
    row = {"identical": True}
    if timer is not None:
        for key, call in calls.items():
            row[f"{key}_us"] = timer(lambda: call(n)) * 1e6
        row["futures_speedup"] = row["serial_us"] / row["futures_us"]
        row["omp2_speedup"] = row["serial_us"] / row["omp2_us"]
        row["omp1_over_serial"] = row["omp1_us"] / row["serial_us"]
        row["omp_over_futures"] = row["omp2_us"] / row["futures_us"]
    if cpu_seconds:
        for key in ("futures", "omp2"):
            row[f"{key}_cpu_us"] = _cpu_per_call(lambda: calls[key](n), cpu_seconds) * 1e6
    return row


def _stepper(filt, truth, dt):
    steps = itertools.cycle(range(truth.states.shape[0]))

    def step():
        k = next(steps)
        filt.step(truth.inputs[k], dt, truth.measurements[k])

    return step


def cpf_steps(lib, sizes, quick: bool, cpu_seconds: float = 0.0, rounds: int = 1) -> dict:
    """ms per CPF step (seed-000 scenario, sea state 3) with ParallelBatch and with OpenMP: the
    median over `rounds` alternating ``median_time`` measurements of each (the two filters start
    alike and must hold bit-identical particles after the same 20 steps)."""
    from abyssal.generated import load

    from ..experiments.rov.scenario import SEA_STATES, RovScenario, make_filter, simulate

    bundle = load("rov4dof")
    scenario, sea = RovScenario(), SEA_STATES["3"]
    truth = simulate(bundle, scenario, sea, np.random.default_rng(0), n_steps=400)
    repeat, min_time = (3, 0.02) if quick else (7, 0.1)
    results = {}
    for n in sizes:
        steps, particles = {}, {}
        for key in ("futures", "omp2"):
            if key == "omp2":
                with openmp_parallel_batch(lib):
                    filt = make_filter("CPF", bundle, scenario, sea, n, np.random.default_rng(1))
            else:
                filt = make_filter("CPF", bundle, scenario, sea, n, np.random.default_rng(1))
            steps[key] = _stepper(filt, truth, scenario.dt)
            for _ in range(20):  # leave the initial transient; the same 20 steps for both
                steps[key]()
            if isinstance(filt.proposal._fused._eval, OpenMPParallelBatch) != (key == "omp2"):
                raise AssertionError(f"the {key} filter does not evaluate through {key}")
            particles[key] = (filt.particles.copy(), filt.x.copy())
        samples = {key: [] for key in steps}
        for _ in range(rounds):
            for key, step in steps.items():
                samples[key].append(1e3 * median_time(step, repeat=repeat, min_time=min_time))
        row = {f"{key}_ms": float(np.median(v)) for key, v in samples.items()}
        row.update({f"{key}_ms_rounds": v for key, v in samples.items()})
        if cpu_seconds:
            for key, step in steps.items():
                row[f"{key}_cpu_ms"] = 1e3 * _cpu_per_call(step, cpu_seconds)
        row["omp_over_futures"] = row["omp2_ms"] / row["futures_ms"]
        row["identical_particles"] = all(np.array_equal(a, b) for a, b in zip(particles["futures"], particles["omp2"]))
        results[f"N={n}"] = row
    return results


# ---------------------------------------------------------------------------------------------
# wait policy and fork (child processes)


def _child_env(**overrides) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    env.update(overrides)
    return env


def _child(mode: str, lib_path, *args: str, env: dict, timeout: float = 600) -> dict:
    cmd = [sys.executable, "-m", "abyssal.runtime.checks.bench_threads", mode, str(lib_path), *args]
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, check=False)
    if res.returncode != 0:
        return {"error": res.stderr[-2000:]}
    return json.loads(res.stdout.strip().splitlines()[-1])


#: libgomp settings compared in fresh processes (label -> environment overrides)
WAIT_POLICIES = {"default": {}, "PASSIVE": {"OMP_WAIT_POLICY": "PASSIVE"}, "ACTIVE": {"OMP_WAIT_POLICY": "ACTIVE"},
                 "GOMP_SPINCOUNT=10000": {"GOMP_SPINCOUNT": "10000"}}


def wait_policies(lib_path, quick: bool) -> dict:
    """cn2d ukf_predict and rov4dof ckf_step batches at N = 300 (ckf_step also 3000) and the CPF
    step at N = 300 under each of WAIT_POLICIES, each in a fresh process (libgomp reads them when it
    loads): wall and process CPU time."""
    return {label: _child("--policy-child", lib_path, *(["--quick"] if quick else []), env=_child_env(**overrides))
            for label, overrides in WAIT_POLICIES.items()}


def _policy_child(lib_path: str, quick: bool) -> dict:
    lib = load_omp_library(lib_path)
    timer = _timer(quick)
    fn, inputs, batched = cn_inputs(300)["cn2d_ukf_predict"]
    out = {"ukf_predict": {"300": compare_batches(lib, fn, inputs, batched, 300, timer, cpu_seconds=0.3)}}
    fn, inputs, batched = rov_step_inputs(3000)
    out["ckf_step"] = {str(n): compare_batches(lib, fn, inputs, batched, n, timer, cpu_seconds=0.3) for n in (300, 3000)}
    out["cpf_step"] = cpf_steps(lib, (300,), quick, cpu_seconds=0.5)
    return out


#: (label, evaluation of the ParallelBatch objects, libgomp environment) of the two-process runs
PAIR_VARIANTS = (("ParallelBatch", "futures", {}), ("OpenMP x2, default", "omp2", {}),
                 ("OpenMP x2, PASSIVE", "omp2", {"OMP_WAIT_POLICY": "PASSIVE"}),
                 ("OpenMP x2, GOMP_SPINCOUNT=10000", "omp2", {"GOMP_SPINCOUNT": "10000"}),
                 ("serial (OpenMP x1)", "omp1", {}))


def two_processes(lib_path, folder, n: int = 300, seconds: float = 2.0) -> dict:
    """Two processes at once (as two Dask workers on 2 cores), each stepping its own CPF at N = n for
    `seconds` after a common start: ms per step and CPU ms per step in each, per variant."""
    results = {}
    for label, variant, overrides in PAIR_VARIANTS:
        barrier = Path(tempfile.mkdtemp(prefix="barrier-", dir=folder))
        env = _child_env(**overrides)
        cmd = [sys.executable, "-m", "abyssal.runtime.checks.bench_threads", "--pair-child", str(lib_path), variant,
               str(barrier), str(n), str(seconds)]
        procs = [subprocess.Popen([*cmd, str(i)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
                 for i in range(2)]
        outs = []
        for proc in procs:
            try:
                stdout, stderr = proc.communicate(timeout=300)
            except subprocess.TimeoutExpired:
                proc.kill()
                stdout, stderr = proc.communicate()
            outs.append(json.loads(stdout.strip().splitlines()[-1]) if proc.returncode == 0 else {"error": stderr[-2000:]})
        results[label] = outs
    return results


def _pair_child(lib_path: str, variant: str, barrier: str, n: int, seconds: float, index: int) -> dict:
    from abyssal.generated import load

    from ..experiments.rov.scenario import SEA_STATES, RovScenario, make_filter, simulate

    lib = load_omp_library(lib_path)
    bundle = load("rov4dof")
    scenario, sea = RovScenario(), SEA_STATES["3"]
    truth = simulate(bundle, scenario, sea, np.random.default_rng(0), n_steps=400)
    if variant in ("omp2", "omp1"):
        with openmp_parallel_batch(lib, n_threads=OMP_THREADS if variant == "omp2" else 1):
            filt = make_filter("CPF", bundle, scenario, sea, n, np.random.default_rng(1))
    else:
        filt = make_filter("CPF", bundle, scenario, sea, n, np.random.default_rng(1))
    steps = itertools.cycle(range(truth.states.shape[0]))

    def step():
        k = next(steps)
        filt.step(truth.inputs[k], scenario.dt, truth.measurements[k])

    for _ in range(20):
        step()
    if isinstance(filt.proposal._fused._eval, OpenMPParallelBatch) != (variant != "futures"):
        raise AssertionError(f"the {variant} filter does not evaluate as it should")
    Path(barrier, f"ready{index}").touch()
    deadline = time.perf_counter() + 60
    while len(list(Path(barrier).glob("ready*"))) < 2 and time.perf_counter() < deadline:
        time.sleep(0.001)
    count, w0, c0 = 0, time.perf_counter(), time.process_time()
    while time.perf_counter() - w0 < seconds:
        step()
        count += 1
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    return {"ms_per_step": 1e3 * wall / count, "cpu_ms_per_step": 1e3 * cpu / count, "steps": count}


FORK_SCRIPT = r"""
import ctypes, json, os, signal, sys, time
import numpy as np

omp_path, gen_path, name, data_path, timeout = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], float(sys.argv[5])
spec = json.loads(open(data_path + ".json").read())
data = np.load(data_path + ".npz")
lib = ctypes.CDLL(omp_path)
fn = ctypes.cast(ctypes.CDLL(gen_path)[name], ctypes.c_void_p)
ins = [np.ascontiguousarray(data[f"in{k}"]) for k in range(spec["n_in"])]
outs = [np.zeros(size) for size in spec["out_sizes"]]
arg = (ctypes.c_void_p * len(ins))(*[a.ctypes.data for a in ins])
arg_step = (ctypes.c_longlong * len(ins))(*spec["arg_steps"])
res = (ctypes.c_void_p * len(outs))(*[a.ctypes.data for a in outs])
res_step = (ctypes.c_longlong * len(outs))(*spec["res_steps"])
sizes = [ctypes.c_longlong(v) for v in spec["sizes"]]


def run(threads):
    for a in outs:
        a[...] = 0.0
    status = lib.omp_batch(fn, *sizes, ctypes.c_longlong(spec["N"]), arg, arg_step, res, res_step, ctypes.c_int(threads))
    return status, [a.copy() for a in outs]


status, reference = run(2)
assert status == 0
report = {}
for case, threads, idle in (("child_2_threads", 2, 0.0), ("child_2_threads_parent_idle_1s", 2, 1.0),
                            ("child_1_thread", 1, 0.0)):
    run(2)  # the parent's team has run: its threads are spinning (idle = 0) or asleep (after idle seconds)
    time.sleep(idle)
    t0 = time.perf_counter()
    pid = os.fork()
    if pid == 0:
        signal.alarm(int(timeout) + 5)  # a last resort: the parent kills us first
        st, got = run(threads)
        os._exit(0 if st == 0 and all(np.array_equal(a, b) for a, b in zip(got, reference)) else 3)
    while True:
        done, code = os.waitpid(pid, os.WNOHANG)
        if done:
            report[case] = {"result": "ok" if os.waitstatus_to_exitcode(code) == 0 else
                            f"failed (exit {os.waitstatus_to_exitcode(code)})",
                            "seconds": round(time.perf_counter() - t0, 4)}
            break
        if time.perf_counter() - t0 > timeout:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            report[case] = {"result": f"hang (killed after {timeout:g} s)", "seconds": timeout}
            break
        time.sleep(0.005)
status, again = run(2)
report["parent_after_fork"] = "ok" if status == 0 and all(np.array_equal(a, b) for a, b in zip(again, reference)) else "failed"
print(json.dumps(report))
"""


def fork_check(lib_path, folder, fn, inputs, batched, n: int = 300, timeout: float = FORK_TIMEOUT) -> dict:
    """Run FORK_SCRIPT in a fresh process on `fn` over n slices: does a forked child's OpenMP call
    finish (with the results of the parent), after the parent has used its OpenMP team?"""
    folder = Path(folder)
    ins = _head(inputs, batched, n)
    outs = _zeros_like_outputs(fn, n)
    binding = fn.bind_batch(ins, outs, n)
    _, arg_steps, _, res_steps = binding._args
    ext = fn.external
    spec = {"n_in": len(ins), "N": n, "out_sizes": [o.size for o in outs],
            "arg_steps": list(arg_steps), "res_steps": list(res_steps),
            "sizes": [ext.sz_arg(), ext.sz_res(), ext.sz_iw(), ext.sz_w(), len(fn.inputs), len(fn.outputs)]}
    data = folder / "fork_inputs"
    np.savez(data.with_suffix(".npz"), **{f"in{k}": a.reshape(-1, order="F") for k, a in enumerate(ins)})
    data.with_suffix(".json").write_text(json.dumps(spec))
    (folder / "fork_check.py").write_text(FORK_SCRIPT)
    cmd = [sys.executable, str(folder / "fork_check.py"), str(lib_path), str(fn.library), fn.name, str(data),
           str(timeout)]
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=4 * timeout + 30, check=False,
                             env=_child_env())
    except subprocess.TimeoutExpired:
        return {"error": "the fork-check process itself did not finish"}
    if res.returncode != 0:
        return {"error": res.stderr[-2000:]}
    report = json.loads(res.stdout.strip().splitlines()[-1])
    report["function"], report["N"] = fn.name, n
    return report


# ---------------------------------------------------------------------------------------------
# section


def run(quick: bool = False, verbose: bool = True) -> dict:
    sizes = QUICK_SIZES if quick else SIZES
    timer = _timer(quick)
    results: dict = {"omp_threads": OMP_THREADS, "cores": os.cpu_count(),
                     "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", "default"),
                     "load_average": list(os.getloadavg())}
    targets = []
    with tempfile.TemporaryDirectory(prefix="abyssal-bench-threads-") as tmp:
        try:
            lib_path = build_omp_library(tmp)
        except OpenMPUnavailable as exc:
            if verbose:
                print(f"  skipped: {exc}")
            return {"results": {"skipped": str(exc)}, "targets": []}
        lib = load_omp_library(lib_path)
        results["team_size"] = lib.omp_team_size(OMP_THREADS)
        cases = {"rov4dof_ckf_step": rov_step_inputs(max(sizes))}
        cn = cn_inputs(max(sizes))
        cases["cn2d_ukf_predict"] = cn["cn2d_ukf_predict"]
        if not quick:
            cases["cn2d_ukf_update"] = cn["cn2d_ukf_update"]
        batches = {}
        for name, (fn, inputs, batched) in cases.items():
            batches[name] = {}
            if verbose:
                print(f"{name}: µs per batch (a) serial _batch, (b) ParallelBatch, (c) OpenMP x{OMP_THREADS}, (d) OpenMP x1")
                print(f"  {'N':>5} {'(a)':>9} {'(b)':>9} {'(c)':>9} {'(d)':>9} {'(b)/(a)':>8} {'(c)/(a)':>8} "
                      f"{'(d)/(a)':>8} {'(c)/(b)':>8}", flush=True)
            for n in sizes:
                row = batches[name][str(n)] = compare_batches(lib, fn, inputs, batched, n, timer)
                if verbose:
                    print(f"  {n:5d} {row['serial_us']:9.1f} {row['futures_us']:9.1f} {row['omp2_us']:9.1f} "
                          f"{row['omp1_us']:9.1f} {row['futures_speedup']:7.2f}x {row['omp2_speedup']:7.2f}x "
                          f"{row['omp1_over_serial']:7.3f}x {row['omp_over_futures']:8.3f}", flush=True)
        results["batches"] = batches
        step_sizes = STEP_SIZES[:1] if quick else STEP_SIZES
        results["cpf_step"] = cpf_steps(lib, step_sizes, quick, cpu_seconds=0.0 if quick else 0.5,
                                        rounds=1 if quick else 3)
        if verbose:
            print("CPF step (seed-000, sea state 3): ms per step, ParallelBatch vs OpenMP x2 (median of alternating rounds)")
            for key, row in results["cpf_step"].items():
                cpu = (f"  (CPU {row['futures_cpu_ms']:.3f} vs {row['omp2_cpu_ms']:.3f} ms)"
                       if "futures_cpu_ms" in row else "")
                print(f"  {key:>7}  ParallelBatch {row['futures_ms']:8.3f}  OpenMP {row['omp2_ms']:8.3f}  "
                      f"OpenMP/futures {row['omp_over_futures']:.3f}  identical particles: "
                      f"{row['identical_particles']}{cpu}", flush=True)
        if not quick:
            results["wait_policy"] = wait_policies(lib_path, quick)
            if verbose:
                print("OMP_WAIT_POLICY (a fresh process each): wall / process CPU time, ParallelBatch vs OpenMP x2")
                for policy, res in results["wait_policy"].items():
                    if "error" in res:
                        print(f"  {policy:<20} error: {res['error'][-300:]}")
                        continue
                    rows = [(f"cn2d ukf_predict N = {n}", row, "us") for n, row in res["ukf_predict"].items()]
                    rows += [(f"rov4dof ckf_step N = {n}", row, "us") for n, row in res["ckf_step"].items()]
                    rows += [(f"CPF step {key.replace('=', ' = ')}", row, "ms") for key, row in res["cpf_step"].items()]
                    for label, row, unit in rows:
                        w = f"_{unit}"
                        print(f"  {policy:<20} {label:<26} futures {row['futures' + w]:9.3f} / {row['futures_cpu' + w]:9.3f} {unit}"
                              f"   OpenMP {row['omp2' + w]:9.3f} / {row['omp2_cpu' + w]:9.3f} {unit}"
                              f"   OpenMP/futures {row['omp2' + w] / row['futures' + w]:.3f}", flush=True)
            results["two_processes"] = two_processes(lib_path, tmp)
            if verbose:
                print("two processes at once, each stepping a CPF at N = 300: ms per step (CPU ms per step)")
                for label, outs in results["two_processes"].items():
                    cells = [f"{o['ms_per_step']:.3f} ({o['cpu_ms_per_step']:.3f})" if "error" not in o
                             else f"error: {o['error'][-200:]}" for o in outs]
                    print(f"  {label:<32} " + "   ".join(cells), flush=True)
        fn, inputs, batched = cases["rov4dof_ckf_step"]
        results["fork"] = fork_check(lib_path, tmp, fn, inputs, batched, timeout=1.0 if quick else FORK_TIMEOUT)
        if verbose:
            print("fork check (OpenMP on 2 threads in the parent, os.fork(), OpenMP in the child):")
            for case, res in results["fork"].items():
                if isinstance(res, dict):
                    print(f"  {case:<32} {res['result']} ({res['seconds']:.3f} s)")
                elif case not in ("function", "N"):
                    print(f"  {case:<32} {res}")
    results["load_average_after"] = list(os.getloadavg())
    rov = results["batches"]["rov4dof_ckf_step"]
    for n in (300, 3000):
        if str(n) in rov:
            targets.append(target(f"OpenMP / concurrent.futures at N = {n} (rov4dof ckf_step)",
                                  rov[str(n)]["omp_over_futures"], 1.0, "x"))
    for key, row in results["cpf_step"].items():
        targets.append(target(f"OpenMP / concurrent.futures, CPF step at {key.replace('=', ' = ')}",
                              row["omp_over_futures"], 1.0, "x"))
    pair = results.get("two_processes", {})
    if all("error" not in o for outs in pair.values() for o in outs) and pair:
        futures = np.mean([o["ms_per_step"] for o in pair["ParallelBatch"]])
        for label in ("OpenMP x2, default", "OpenMP x2, PASSIVE"):
            value = np.mean([o["ms_per_step"] for o in pair[label]]) / futures
            targets.append(target(f"{label.replace('x2, ', '(')}) / concurrent.futures, CPF step N = 300, "
                                  "two processes at once", float(value), 1.0, "x"))
    identical = all(r["identical"] for rows in results["batches"].values() for r in rows.values()) and all(
        r["identical_particles"] for r in results["cpf_step"].values())
    targets.append(target("OpenMP results bit-identical to the serial _batch and ParallelBatch", float(identical), 1.0,
                          "bool", higher_is_better=True))
    fork = results["fork"]
    fork_ok = all(isinstance(v, dict) and v.get("result") == "ok" for k, v in fork.items() if k.startswith("child_")) \
        and fork.get("parent_after_fork") == "ok"
    targets.append(target("forked child's OpenMP calls finish (no hang)", float(fork_ok), 1.0, "bool", higher_is_better=True))
    return {"results": results, "targets": targets}


if __name__ == "__main__":
    if len(sys.argv) >= 3 and sys.argv[1] == "--policy-child":
        print(json.dumps(_policy_child(sys.argv[2], "--quick" in sys.argv)))
    elif len(sys.argv) == 8 and sys.argv[1] == "--pair-child":
        _, _, lib_arg, variant_arg, barrier_arg, n_arg, seconds_arg, index_arg = sys.argv
        print(json.dumps(_pair_child(lib_arg, variant_arg, barrier_arg, int(n_arg), float(seconds_arg), int(index_arg))))
