"""Filter section of `abyssal bench`: per-step (predict + update) cost of the Kalman filters on rov4dof, from Python
and from C, beside peers measured in the same run.

Ours:   the EKF, UKF and CKF classes, ``step(u, dt, z)`` through a simulated trajectory (Python over the C runtime
        of runtime/c: one call per step) and ``run(U, Z, dt)`` (one call for the whole trajectory), and the same
        runtime called from a C loop: kalman_loop.c, loaded into this process and run on a filter object Python
        built (the ratios' denominator), and kalman_timing.c, a program linked with the model's and the runtime's
        libraries from abyssal's compile cache (the code Python calls), per step and through abyssal_kalman_run; the
        innovation gate's judgement of one update alone (C); the bytes of each filter object.
Peers:  filterpy's UnscentedKalmanFilter with MerweScaledSigmaPoints(1, 0, 0) (the same CKF) on the independent
        NumPy model of rov4dof (verify/reference_models.py, written from the paper: a model as a user would write
        it).
Floor:  instructions per CKF step from Python (valgrind --tool=callgrind on step_times.py, when valgrind is
        installed; instructions.py: an x86-64-v3 build, valgrind 3.19 decodes no AVX-512), and of them abyssal's C,
        the model's kernels and libmvec, beside the model's own work: 2n evaluations of f through the SIMD
        kernel plus 2n evaluations of h, and the dense algebra of the rule (the step's arithmetic with the
        model's functions counted by their generated instruction counts).
Times:  paired: each pair times the same rows three ways, each on a fresh filter, within a few milliseconds of each
        other (Python's step loop, run(), the in-process C loop; their order rotating pair by pair, the filters'
        pairs interleaved); a ratio is the median over the pairs of that pair's Python time over its C time, so a
        machine whose speed drifts within seconds (a shared host: the same C step measured 4.3-5.6 us minutes apart)
        reaches both sides of a ratio alike; the ratios are what travels between machines, the µs beside them are
        medians. Both sides time the same rows: those after a filter's start-up (step 0, which checks dt's
        stability, and the first updates, which Python's unit watch compares with h(x): units.py), stepped untimed
        on both sides; Python's start-up cost per step is reported beside. Python loops over the rows taken out
        beforehand (``for u, z in rows: f.step(u, dt, z)``), as the C loop walks its arrays. run() is timed twice
        in each pair, each beside a C loop over the same rows: over the 400-row trajectory of the steps and over a
        log of LOG_ROWS rows, whose ratio is the target (run's cost per row; its cost per call, Python's, which a short
        sequence pays in full, is reported beside: run's time over 400 rows beyond the C loop's). The C
        program's times (the minimum over its repetitions) are reported beside, for abyssal_kalman_run and the
        floor.

Targets (issue 34, ratios in one run): CKF.step from Python <= 1.15x the C runtime's step, EKF <= 1.25x; run() <= 1.05x
the C step per row (over a log of LOG_ROWS rows); the CKF >= 300x faster than filterpy.

    python benchmarks/bench_filters.py [--quick]     # this section alone, JSON on stdout
"""
from __future__ import annotations

import ctypes
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from abyssal import generated
from abyssal.generated.build import BuildError, cflags, compiler
from abyssal.runtime.compiled import kalman as kalman_runtime
from abyssal.runtime.compiled.sources import C_DIR
from abyssal.symbolic.codegen import MODEL_HEADER
from abyssal.runtime.filters.kalman import CKF, EKF, UKF
from abyssal.verify import reference_models

import instructions
from bench import json_main, paired_ratio, target
from trajectory import trajectory

MODEL = "rov4dof"
DT = 0.1
LOG_ROWS = 4000  # run()'s rows for its target: a log of 400 s at 10 Hz
HERE = Path(__file__).resolve().parent


def best_per_step(make, step, steps: int, repeats: int) -> float:
    """Seconds per step: the minimum over `repeats` runs of steps 1..steps-1, each on a fresh object from make()
    (step 0, the one that checks dt's stability, untimed)."""
    best = float("inf")
    for _ in range(repeats):
        obj = make()
        step(obj, 0)
        t0 = time.perf_counter()
        for k in range(1, steps):
            step(obj, k)
        best = min(best, (time.perf_counter() - t0) / (steps - 1))
    return best


def start_up_rows(make, U, Z) -> int:
    """Rows a filter takes to leave its start-up: step 0 (which checks dt's stability) and the updates its unit watch
    observes (units.py: the first values of every sensor output, compared with h(x) in Python)."""
    flt = make()
    for k in range(len(U)):
        flt.step(U[k], DT, Z[k])
        if flt._unit_watch is None:
            return k + 1
    return len(U)


def _compile(source: Path, libraries: list[Path], output: Path, *flags: str) -> None:
    """source built with the cache's compiler and flags against the runtime's headers, linked with `libraries` (found
    again at run time where they are: rpath), into `output`."""
    cmd = [compiler(), *cflags(), *flags, f"-I{C_DIR}", f"-I{MODEL_HEADER.parent}", str(source),
           *map(str, libraries), *(f"-Wl,-rpath,{lib.parent}" for lib in libraries), "-o", str(output), "-lm"]
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise BuildError(f"compiling {source.name} failed: {' '.join(cmd)}\n{res.stderr[-4000:]}")


class CLoop:
    """kalman_loop.c built as a shared library against the runtime's library from abyssal's compile cache (the one
    Python loaded) and loaded into this process; close() removes it."""

    def __init__(self, bundle):
        self.tmp = tempfile.TemporaryDirectory(prefix="abyssal-bench-loop-")
        library = Path(self.tmp.name) / "kalman_loop.so"
        try:
            _compile(HERE / "kalman_loop.c", [Path(kalman_runtime.KalmanRuntime.of(bundle).library)], library, "-shared")
        except BuildError:
            self.tmp.cleanup()
            raise
        self._steps = ctypes.CDLL(str(library)).abyssal_bench_steps
        self._steps.restype = ctypes.c_double
        self._steps.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_longlong, ctypes.c_void_p, ctypes.c_int,
                                ctypes.c_void_p, ctypes.c_int, ctypes.c_double]

    def seconds(self, flt, U: np.ndarray, Z: np.ndarray) -> float:
        """Seconds of abyssal_kalman_step over the rows of U, Z (C-contiguous) on the filter object flt holds."""
        ns = self._steps(flt._memory.ctypes.data, flt._runtime.descriptor, U.shape[0], U.ctypes.data, U.shape[1],
                         Z.ctypes.data, Z.shape[1], DT)
        if ns < 0:
            raise RuntimeError("a step of the C loop was refused")
        return ns / 1e9

    def close(self) -> None:
        self.tmp.cleanup()


class Pairs:
    """The paired timings of one filter class (module docstring, Times): add() times one pair."""

    WAYS = ("step", "run", "C loop")
    LOG_WAYS = ("run (log)", "C loop (log)")

    def __init__(self, make, rows, U, Z, first: int, steps: int, log_rows: int, loop: CLoop):
        self.make, self.rows, self.first, self.loop = make, rows, first, loop
        self.steady = rows[first:steps]
        self.U, self.Z = np.ascontiguousarray(U[first:steps]), np.ascontiguousarray(Z[first:steps])
        self.U_log = np.ascontiguousarray(U[first:first + log_rows])
        self.Z_log = np.ascontiguousarray(Z[first:first + log_rows])
        self.seconds: dict[str, list[float]] = {way: [] for way in self.WAYS + self.LOG_WAYS}
        self.start_up: list[float] = []
        #: per run() way, its one C call's time per row (FilterResult.step_time)
        self.run_c: dict[str, list[float]] = {"run": [], "run (log)": []}

    def _started(self):
        flt = self.make()
        u, z = self.rows[0]
        flt.step(u, DT, z)
        t0 = time.perf_counter()
        for u, z in self.rows[1:self.first]:
            flt.step(u, DT, z)
        self.start_up.append((time.perf_counter() - t0) / max(self.first - 1, 1))
        return flt

    def add(self, turn: int, ways=WAYS) -> None:
        """One pair: each of `ways` (WAYS, or LOG_WAYS: run() and the C loop over the log) on a fresh filter."""
        started = [self._started() for _ in ways]
        for j, flt in enumerate(started):
            way = ways[(turn + j) % len(ways)]
            U, Z = (self.U_log, self.Z_log) if way.endswith("(log)") else (self.U, self.Z)
            if way == "step":
                step = flt.step
                t0 = time.perf_counter()
                for u, z in self.steady:
                    step(u, DT, z)
                elapsed = time.perf_counter() - t0
            elif way.startswith("run"):  # (the result is kept past the timer: freeing it is the caller's, later)
                t0 = time.perf_counter()
                result = flt.run(U, Z, DT)
                elapsed = time.perf_counter() - t0
                self.run_c[way].append(float(result.step_time[0]))
                del result
            else:
                elapsed = self.loop.seconds(flt, U, Z)
            self.seconds[way].append(elapsed / len(U))

    def summary(self) -> dict[str, float]:
        """Medians in µs per step, the paired ratios' medians, the start-up rows' cost (minimum)."""
        step, run, c, run_log, c_log = (np.array(self.seconds[way]) for way in self.WAYS + self.LOG_WAYS)
        return {"step_us": 1e6 * float(np.median(step)), "run_us": 1e6 * float(np.median(run)),
                "c_loop_us": 1e6 * float(np.median(c)), "step_over_c": paired_ratio(step, c),
                "run_over_c": paired_ratio(run, c), "run_c_call_over_c": paired_ratio(self.run_c["run"], c),
                "run_log_over_c": paired_ratio(run_log, c_log),
                "run_log_c_call_over_c": paired_ratio(self.run_c["run (log)"], c_log),
                "run_beyond_c_us": 1e6 * len(self.U) * float(np.median(run - c)),
                "start_up_us": 1e6 * min(self.start_up), "pairs": len(c)}


class CTiming:
    """The C timing driver (kalman_timing.c) built once against the model's and the runtime's libraries from
    abyssal's compile cache (the code Python calls), run on a trajectory file; close() removes both."""

    def __init__(self, bundle, U, Z):
        self.tmp = tempfile.TemporaryDirectory(prefix="abyssal-bench-")
        tmp = Path(self.tmp.name)
        self.data = tmp / "trajectory.txt"
        with open(self.data, "w") as fh:
            fh.write(f"{len(U)} {bundle.n_u} {bundle.n_y}\n")
            np.savetxt(fh, np.hstack([U, Z]), fmt="%.17g")
        self.exe = tmp / "kalman_timing"
        try:
            _compile(HERE / "kalman_timing.c", [Path(bundle.library), Path(kalman_runtime.KalmanRuntime.of(bundle).library)],
                     self.exe, f"-DDESCRIPTOR={bundle.name}_descriptor")
        except BuildError:
            self.tmp.cleanup()
            raise

    def times(self, repeats: int, first: int) -> dict[str, float]:
        """ns per step of each filter from a C loop over rows first.. and through abyssal_kalman_run over them, the
        gate's ns, the objects' bytes: one run of the driver (the minimum over its `repeats`)."""
        out = subprocess.run([str(self.exe), str(self.data), str(repeats), str(first)], capture_output=True, text=True,
                             check=True, timeout=600).stdout
        return {label: float(value) for label, value in (line.split() for line in out.splitlines())}

    def close(self) -> None:
        self.tmp.cleanup()


def filterpy_ckf(bundle, Q, R):
    """filterpy's UKF with cubature points (Merwe 1, 0, 0) on the NumPy reference model of the bundle."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    ref = reference_models.REFERENCES[bundle.name]
    p, disc, substeps = bundle.params(), bundle.manifest["discretisation"], bundle.manifest["substeps"]
    points = MerweScaledSigmaPoints(bundle.n_x, alpha=1.0, beta=0.0, kappa=0.0)

    def make():
        ukf = UnscentedKalmanFilter(bundle.n_x, bundle.n_y, DT, hx=lambda s: ref.h(s, p), fx=None, points=points)
        ukf.Q, ukf.R = Q, R
        ukf.x, ukf.P = np.zeros(bundle.n_x), 0.3 * np.eye(bundle.n_x)
        return ukf
    return make, lambda s, u, dt: reference_models.step(ref, s, u, p, dt, disc, substeps)


def run(quick: bool = False, verbose: bool = True) -> dict:
    bundle = generated.load(MODEL)
    steps, log_rows = (200, 1000) if quick else (400, LOG_ROWS)
    pairs, repeats = (8, 2) if quick else (40, 3)
    x0, P0, Q, R, U, Z = trajectory(bundle, steps + log_rows)
    results: dict = {"model": MODEL, "steps": steps, "log rows": log_rows, "pairs": pairs, "per_step_us": {},
                     "from_c_us": {}, "paired": {}}
    py, c = results["per_step_us"], results["from_c_us"]

    # both sides time the rows after the start-up (step 0 and the unit watch's first updates, which Python alone
    # runs: its cost per step is reported beside), over the same rows, in pairs (module docstring, Times)
    first = max(start_up_rows(lambda: CKF(bundle, x0, P0, Q, R), U, Z),
                start_up_rows(lambda: EKF(bundle, x0, P0, Q, R), U, Z), start_up_rows(lambda: UKF(bundle, x0, P0, Q, R), U, Z))
    results["untimed start-up rows"] = first
    rows = list(zip(U, Z))
    loop, timing = CLoop(bundle), CTiming(bundle, U[:steps], Z[:steps])
    try:
        paired = {cls.__name__: Pairs(lambda cls=cls: cls(bundle, x0, P0, Q, R), rows, U, Z, first, steps, log_rows, loop)
                  for cls in (EKF, UKF, CKF)}
        for ways in (Pairs.WAYS, Pairs.LOG_WAYS):  # (the log's pairs after the others': its 2 MB of results pass through the caches)
            for turn in range(pairs):
                for timed in paired.values():
                    timed.add(turn, ways)
        timings = timing.times(repeats, first)
    finally:
        timing.close()
        loop.close()
    for name, timed in paired.items():
        summary = results["paired"][name] = timed.summary()
        py[name], py[f"{name} start-up"], py[f"{name}.run per row"] = (summary["step_us"], summary["start_up_us"],
                                                                        summary["run_us"])
        py[f"{name}.run over {steps - first} rows beyond the C loop's time"] = summary["run_beyond_c_us"]
        c[f"{name} (C loop in this process)"] = summary["c_loop_us"]
    for name in ("EKF", "UKF", "CKF"):
        c[f"{name} (C program, minimum of {repeats})"] = timings[name] / 1e3
        c[f"{name} abyssal_kalman_run per row (C program)"] = timings[f"{name}_run"] / 1e3
    results["gate_us"] = timings["gate"] / 1e3
    results["filter_object_bytes"] = {name: int(timings[f"{name}_bytes"]) for name in ("EKF", "UKF", "CKF")}
    if not quick and instructions.available():  # (the CKF's steps from Python under callgrind: ~1.5 min)
        results["instructions_per_step_callgrind"] = instructions.per_step(
            [sys.executable, str(HERE / "step_times.py"), "--steps", "CKF"], 200)
    results["floor"] = floor(bundle)

    fp_steps = 20 if quick else 60
    try:
        make, fx = filterpy_ckf(bundle, Q, R)
    except ImportError:
        results["filterpy"] = "not installed (pip install 'abyssal[test]')"
    else:
        def filterpy_step(ukf, k):
            ukf.predict(fx=lambda s, dt: fx(s, U[k], dt))
            ukf.update(Z[k])
        py["filterpy UKF (cubature points), NumPy model"] = 1e6 * best_per_step(make, filterpy_step, fp_steps,
                                                                                 2 if quick else 5)

    summaries = results["paired"]
    ratios = {f"{name}.step from Python / C step": summaries[name]["step_over_c"] for name in ("CKF", "EKF", "UKF")}
    for name in ("CKF", "EKF"):
        ratios[f"{name}.run per row / C step, {log_rows} rows (a log)"] = summaries[name]["run_log_over_c"]
        ratios[f"{name}.run's C call (abyssal_kalman_run: the outputs copied) per row / C step, {log_rows} rows"] = \
            summaries[name]["run_log_c_call_over_c"]
        ratios[f"{name}.run per row / C step, {steps - first} rows"] = summaries[name]["run_over_c"]
        ratios[f"{name}.run's C call per row / C step, {steps - first} rows"] = summaries[name]["run_c_call_over_c"]
    filterpy_us = py.get("filterpy UKF (cubature points), NumPy model")
    if filterpy_us is not None:
        ratios["filterpy / CKF"] = filterpy_us / py["CKF"]
    results["ratios"] = ratios

    if verbose:
        print(f"per step (predict + update) on {MODEL}, {steps - first} rows after {first} start-up rows, medians of "
              f"{pairs} pairs (ratios: the median of the pairs' ratios):")
        for name, us in py.items():
            print(f"  from Python  {name:<58} {us:9.3f} us")
        for name, us in c.items():
            print(f"  from C       {name:<58} {us:9.3f} us")
        print(f"  the gate's judgement of one update (C)                                   {results['gate_us']:9.3f} us")
        for name, b in results["filter_object_bytes"].items():
            print(f"  {name} filter object: {b} bytes")
        for name, value in results["floor"].items():
            print(f"  floor: {name:<58} {value:10.0f}")
        if "instructions_per_step_callgrind" in results:
            print("  CKF.step from Python, instructions per step (callgrind, x86-64-v3 build): " + ", ".join(
                f"{k} {v:,.0f}" for k, v in results["instructions_per_step_callgrind"].items()))
        for name, ratio in ratios.items():
            print(f"  {name:<58} {ratio:10.2f} x")

    targets = [
        target("CKF.step from Python / its C runtime step (rov4dof)", ratios["CKF.step from Python / C step"], 1.15, "x"),
        target("EKF.step from Python / its C runtime step (rov4dof)", ratios["EKF.step from Python / C step"], 1.25, "x"),
        target(f"CKF.run per row over a log of {log_rows} rows / the C runtime step (rov4dof)",
               ratios[f"CKF.run per row / C step, {log_rows} rows (a log)"], 1.05, "x"),
    ]
    if "filterpy / CKF" in ratios:
        targets.append(target("CKF speed-up over filterpy", ratios["filterpy / CKF"], 300.0, "x", higher_is_better=True))
    return {"results": results, "targets": targets}


def floor(bundle) -> dict[str, float]:
    """The model's own work in one step, by the generated instruction counts (manifest): f over the 2n cubature
    points, h over them, and the CKF's dense algebra (the Cholesky factor n^3/6, the moments 2n (n + n(n+1)/2), the
    update's cross-covariance and gain ~ n m (2n + m), all as multiply-adds)."""
    spec = bundle.manifest["functions"]
    n, m = bundle.n_x, bundle.n_y
    f, h = spec[f"{bundle.name}_f"]["instructions"], spec[f"{bundle.name}_h"]["instructions"]
    points = 2 * n
    algebra = 2 * n ** 3 / 6 + points * (n + n * (n + 1) / 2) + points * (m + m * (m + 1) / 2) + n * m * (2 * n + m) + n * n * m
    return {"f over the points (generated instructions)": points * f, "h over the points": points * h,
            "CKF algebra (multiply-adds)": algebra}


if __name__ == "__main__":
    json_main(run, __doc__.splitlines()[0])
