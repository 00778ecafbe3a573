"""`abyssal export`: a filter for the vehicle, as a self-contained C99 project that needs no Python.

    abyssal.export("rov4dof", filter="ckf", out="rov4dof_ckf")      # or a model folder written by abyssal.generate
    $ abyssal export gen/cybership --filter ekf --out cybership_ekf

writes into ``out`` (a new or empty folder, or an earlier export):

    CMakeLists.txt           static and shared libraries, run_csv, the tests (ctest)
    README.md                build, link, run; the bare `cc` command
    include/<m>_filter.h     the model: state, input, output and parameter layout with units, sizes, the memory of
                             the filter object; abyssal_exported.h names the exported model and filter
    include/abyssal_*.h      the C runtime's API (abyssal_kalman.h) and abyssal_kalman.hpp, a C++17 wrapper
    src/                     the model's generated C (as committed, hashes checked) and the runtime's C
    examples/run_csv.c       reads dt/u/z rows, writes x/P rows
    tests/                   test vectors recorded from this Python filter (setup.txt, input.csv, expected.csv),
                             compare_csv.c, wrapper_test.cpp

The vectors: ``steps`` (default 10^4) steps of a simulated run of the model inside its operating envelope with
missing entries (NaN), gross outliers (gated), one long dt (subdivided where the model needs it) and three
refused rows (a non-finite u, a negative dt, an infinite z entry: the C must refuse them too, with the same
code, and go on unchanged). Python and the exported C run the same C runtime and the same generated C, so the
recorded rows equal run_csv's bit for bit when compiled with abyssal's own flags. Both builds leave floating-point
contraction off (-ffp-contract=off in abyssal's build and in the CMake project), so another -march or build type
changes nothing but the sin/cos of the structure-of-arrays kernel (abyssal's build vectorises it with the libmvec
variant of its -march; the CMake default calls the scalar libm). Measured against CMake's default Release build:
the Otter-like USV's 1057 and 2013 recorded rows all identical; rov4dof's within 1.9e-13 (steps) and 1.4e-10 (the
time-stamped calls; 2e-9 with GCC's default contraction). ctest compares x and P relative to max(1, |value|), and the
NIS, within tolerances taken from the run itself (NUDGE_ULPS below): the recording is rerun on a twin with x0 and
every input, measurement and R entry moved by a few units in the last place, and ctest allows 100x the largest
difference of the twin, at least 1e-12 (x, P) and 1e-9 (NIS, whose innovation z - h(x) cancels between two large
numbers). rov4dof's CKF: the twin differs by 2.9e-13 (steps) and 5.5e-11 (time-stamped calls), so ctest allows
2.9e-11 and 5.5e-9 against the 1.9e-13 and 1.4e-10 that CMake's default build differs by.
"""
from __future__ import annotations

import json
import platform
import warnings
import shlex
import shutil
from pathlib import Path

import numpy as np

from abyssal import generated
from abyssal.runtime.compiled import kalman as kr
from abyssal.runtime.compiled.sources import EXPORT_TEMPLATES, KALMAN
from abyssal.runtime.compiled.sources import sources as runtime_sources
from abyssal.runtime.contract import LongStepWarning
from abyssal.runtime.filters.kalman import CKF, EKF, MCUKF, UKF, HuberUKF

__all__ = ["FILTERS", "export", "record_vectors"]

#: --filter -> its Python class (every filter runs on any model: the algebra is the C runtime's)
FILTERS = {"ekf": EKF, "ukf": UKF, "ckf": CKF, "mcukf": MCUKF, "huber": HuberUKF}
#: the runtime's files a vehicle needs (abyssal_kalman_binding.c is Python's binding only)
RUNTIME_SOURCES = ("abyssal_kalman.c", "abyssal_kalman_steps.c", "abyssal_linalg.c", "abyssal_kalman_gate.c",
                   "abyssal_kalman_covariance.c")
RUNTIME_HEADERS = ("abyssal_kalman.h", "abyssal_kalman_steps.h", "abyssal_linalg.h", "abyssal_kalman_gate.h",
                   "abyssal_kalman_covariance.h",
                   "abyssal_kalman.hpp")
MARKER = ".abyssal-export.json"
#: the long dt of the recorded run, in steps dt: the shortest of these the filter subdivides
LONG_DT_FACTORS = (50, 100, 200, 400, 800)
#: ctest's tolerances come from the run: the Python filter reruns the recorded calls on a twin whose x0 and every
#: non-zero finite u, z and R entry are moved by up to NUDGE_ULPS units in the last place (what another compiler's
#: or libm's roundings do to the first computations of a step), and ctest allows TOLERANCE_MARGIN x the largest
#: difference between the two runs (relative to max(1, |value|), as compare_csv measures it), kept within
#: [TOLERANCE_FLOORS, TOLERANCE_CAP]: a well-conditioned run keeps today's floors, an ill-conditioned one (P inflated
#: along a stuck sensor, a long subdivided step) gets what its own sensitivity to rounding says.
NUDGE_ULPS = 4
TOLERANCE_MARGIN = 100.0
TOLERANCE_FLOORS = {"x_P": 1e-12, "nis": 1e-9}
TOLERANCE_CAP = 1e-6


def export(target, filter: str = "ckf", out=None, *, steps: int = 10_000, seed: int = 0,
           history_seconds: float | None = None, force: bool = False, command: str | None = None) -> Path:
    """Write the C project of `filter` on the model `target` (a built-in name or a model folder) into `out`;
    returns the folder. history_seconds: the fixed lag of the filter's history for late measurements (None: twice
    the longest latency a sensor declares, at least 2 s). force: replace an earlier export in `out` (a non-empty
    folder is refused without it). See the module docstring."""
    if filter not in FILTERS:
        raise ValueError(f"--filter {filter!r}: choose one of {sorted(FILTERS)}")
    if out is None:
        raise ValueError("out: the folder to write the project into is required")
    if not (isinstance(steps, int) and steps >= 100):
        raise ValueError(f"steps must be an integer >= 100, got {steps!r}")
    folder = generated.model_folder(target)
    manifest, sources = generated.read_folder(folder)
    model, cls = manifest["model"], FILTERS[filter]
    if f"{model}_descriptor.c" not in sources:
        raise ValueError(f"{folder} was generated before the C runtime of the Kalman family (no {model}_descriptor.c): "
                         "regenerate it, then export")
    if history_seconds is None:
        latencies = [s["latency"][1] for s in manifest.get("sensors", []) if s.get("latency")]
        history_seconds = max([2.0, *(2.0 * v for v in latencies)])
    if not (isinstance(history_seconds, (int, float)) and 0 < history_seconds < float("inf")):
        raise ValueError(f"--history must be a positive number of seconds, got {history_seconds!r}")
    # the history's entries: its seconds at the recorded run's rate of calls (a predict per tick, each sensor at
    # its rate), with half again as margin; the filter object's bytes grow with them
    envelope = manifest.get("envelope") or {}
    dt = float(min(0.1, envelope.get("max_dt") or 0.1))
    rate = 1.0 / dt + sum(s["rate"] if s.get("rate") else 1.0 / (dt * (k + 1))
                          for k, s in enumerate(manifest.get("sensors", [])))
    history_entries = int(np.ceil(1.5 * history_seconds * rate)) + 4
    out_given = Path(out).expanduser()
    out = _prepare(out_given, force)
    # the command as a colleague would retype it: no path of this machine (an absolute path keeps its last part)
    command = command or (f"abyssal export {shlex.quote(_portable(target))} --filter {filter} "
                          f"--out {shlex.quote(_portable(out_given))}")
    bundle = generated.load(folder)
    options = {"history_seconds": float(history_seconds), "history_entries": history_entries}
    setup, rows, expected, summary = record_vectors(bundle, filter, steps=steps, seed=seed, options=options)
    events, events_expected, events_summary = record_events(bundle, filter, steps=steps, seed=seed, options=options)
    flips = summary["twin"]["rows_whose_code_differs"] + events_summary["twin"]["rows_whose_code_differs"]
    if flips:
        warnings.warn(f"export: {flips} recorded row(s) changed their outcome (a gate or refusal at its threshold) when "
                      "the run was repeated with rounding-level changes, so another compiler's build may fail ctest on "
                      "them: export again with another seed", RuntimeWarning, stacklevel=2)

    runtime = runtime_sources([*KALMAN, "abyssal_kalman.hpp"])
    for sub in ("include", "src", "examples", "tests/vectors"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    for name, text in sorted(sources.items()):  # the model's C, and its copy of the descriptor's type (abyssal_model.h)
        (out / ("include" if name.endswith(".h") else "src") / name).write_text(text)
    for name in RUNTIME_SOURCES:
        (out / "src" / name).write_text(runtime[name])
    for name in RUNTIME_HEADERS:
        (out / "include" / name).write_text(runtime[name])
    flt = cls(bundle, np.zeros(bundle.n_x), np.eye(bundle.n_x), np.eye(bundle.n_x), np.eye(bundle.n_y), **options)
    bytes_ = int(flt._memory.nbytes)
    (out / "include" / f"{model}_filter.h").write_text(_model_header(manifest, filter, bytes_, command, flt.options))
    (out / "include" / "abyssal_exported.h").write_text(_exported_header(manifest, filter))
    shutil.copyfile(EXPORT_TEMPLATES / "run_csv.c", out / "examples" / "run_csv.c")
    for name in ("compare_csv.c", "wrapper_test.cpp"):
        shutil.copyfile(EXPORT_TEMPLATES / name, out / "tests" / name)
    model_sources = " ".join(f"src/{name}" for name in sorted(sources) if name.endswith(".c"))
    cmake = (EXPORT_TEMPLATES / "CMakeLists.txt.in").read_text()
    runtime_list = " ".join(f"src/{name}" for name in RUNTIME_SOURCES)
    (out / "CMakeLists.txt").write_text(cmake.replace("@MODEL@", model).replace("@SOURCES@", model_sources)
                                        .replace("@RUNTIME_SOURCES@", runtime_list)
                                        .replace("@COMMAND@", command)
                                        .replace("@TOLERANCE@", _tolerance_text(summary["tolerance"]["x_P"]))
                                        .replace("@NIS_TOLERANCE@", _tolerance_text(summary["tolerance"]["nis"]))
                                        .replace("@EVENTS_TOLERANCE@",
                                                 _tolerance_text(events_summary["tolerance"]["x_P"]))
                                        .replace("@EVENTS_NIS_TOLERANCE@",
                                                 _tolerance_text(events_summary["tolerance"]["nis"])))
    (out / "tests" / "vectors" / "setup.txt").write_text(setup)
    (out / "tests" / "vectors" / "input.csv").write_text(rows)
    (out / "tests" / "vectors" / "expected.csv").write_text(expected)
    (out / "tests" / "vectors" / "events.csv").write_text(events)
    (out / "tests" / "vectors" / "events_expected.csv").write_text(events_expected)
    (out / "README.md").write_text(_readme(manifest, filter, bytes_, command, summary, events_summary, flt.options))
    (out / MARKER).write_text(json.dumps({"model": model, "filter": filter, "command": command, "steps": steps,
                                          "seed": seed, "history_seconds": float(history_seconds), "vectors": summary,
                                          "events": events_summary}, indent=1) + "\n")
    return out


def _portable(path) -> str:
    """A target or folder as the export's files quote it: as given when relative, its last part when absolute."""
    text = str(path)
    return Path(text).name if Path(text).expanduser().is_absolute() else text


def _prepare(out: Path, force: bool) -> Path:
    """`out` created; a non-empty folder refused, unless it is an earlier export and force is given (then emptied,
    but for its build folder); a folder holding files abyssal did not write is never touched."""
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"--out {out} is a file")
    if out.is_dir() and any(out.iterdir()):
        if not (out / MARKER).is_file():
            raise FileExistsError(f"--out {out} exists and holds files abyssal export did not write: choose an empty or "
                                  "new folder")
        if not force:
            raise FileExistsError(f"--out {out} holds an earlier export: give --force (force=True) to replace it, or "
                                  "choose another folder")
        for child in out.iterdir():
            if child.name != "build":
                shutil.rmtree(child) if child.is_dir() else child.unlink()
    out.mkdir(parents=True, exist_ok=True)
    return out.resolve()


# ------------------------------------------------------------------ the test vectors
def _ranges(bundle, kind: str, names) -> np.ndarray:
    envelope = bundle.envelope or {}
    default = envelope.get("default_range", [-1.0, 1.0])
    table = envelope.get(kind) or {}
    return np.array([table.get(name, default) for name in names], dtype=float).reshape(len(names), 2)


def record_vectors(bundle, filter: str, *, steps: int = 10_000, seed: int = 0, options: dict | None = None):
    """(setup.txt, input.csv, expected.csv texts, a summary dict) of a run of the Python `filter` on `bundle`.

    The truth moves inside the model's envelope (inputs slowly swept around the centre of their ranges, additive
    process noise Q), the measurements are h plus noise R (R from the spread of the outputs over a pilot run); 5 %
    of the entries and every 97th row are missing, one entry in every 1000 steps is off by 10^3 standard
    deviations, steps T/4, T/2, 3T/4 are refused (NaN u, negative dt, infinite z), and step 0.6 T has the
    shortest of LONG_DT_FACTORS x dt that the filter subdivides there (tried on a checkpoint; the first factor
    when none is). expected.csv holds every 10th step, every step near an event and the last one."""
    with warnings.catch_warnings():  # the recording runs a long dt on purpose (beyond a declared max_dt)
        warnings.simplefilter("ignore", RuntimeWarning)
        warnings.simplefilter("ignore", LongStepWarning)
        return _record(bundle, filter, steps, seed, options or {})


def _truth(bundle, steps: int, rng):
    """The simulated run's pieces: dt, inputs U (steps, n_u), Q and its factor, R (from the spread of the outputs
    over a pilot run), x_centre and the state's half ranges, and advance(x, u, pieces, rng)."""
    n, n_u = bundle.n_x, bundle.n_u
    xr, ur = _ranges(bundle, "states", bundle.state_names), _ranges(bundle, "inputs", bundle.input_names)
    x_centre, x_half = xr.mean(axis=1), np.maximum((xr[:, 1] - xr[:, 0]) / 2, 1e-6)
    u_centre, u_half = ur.mean(axis=1), (ur[:, 1] - ur[:, 0]) / 2
    envelope = bundle.envelope or {}
    dt = float(min(0.1, envelope.get("max_dt") or 0.1))
    k = np.arange(steps)
    U = u_centre + 0.3 * u_half * np.sin(2 * np.pi * k[:, None] / (300.0 + 37.0 * np.arange(n_u)) + np.arange(n_u))
    Q = np.diag((1e-3 * x_half) ** 2)
    noise = np.linalg.cholesky(Q)

    def advance(x, u, pieces):
        for _ in range(pieces):
            x = bundle.f(x, u, None, dt) + noise @ rng.standard_normal(n)
        return x

    pilot, x = np.empty((min(steps, 2000), n)), x_centre.copy()
    for j in range(len(pilot)):
        x = pilot[j] = advance(x, U[j], 1)
    Y = bundle.h_batch(pilot.T).T
    spread = np.maximum(Y.std(axis=0), 1e-3 * np.maximum(np.abs(Y).max(axis=0), 1.0))
    R = np.diag((0.01 * spread) ** 2)
    return dt, U, Q, R, x_centre, x_half, advance


def _initial(x_centre, x_half, rng):
    """The filter's x0 (drawn about the centre of the envelope) and P0."""
    P0 = np.diag((0.01 * x_half) ** 2)
    return x_centre + rng.normal(size=len(x_centre)) * np.sqrt(np.diag(P0)), P0


def _setup_text(bundle, filter: str, flt, x0, P0, Q, R) -> str:
    setup = [f"# abyssal export: {bundle.name}, {filter}; x0, P0, Q and R (column-major), then the filter's options"]
    setup += [f"{name} {' '.join(map(repr, A.ravel(order='F').tolist()))}" for name, A in
              (("x0", x0), ("P0", P0), ("Q", Q), ("R", R))]
    setup += [f"{name} {float(kr.NOISE[value] if name == 'noise' else value)!r}" for name, value in flt.options.items()]
    return "\n".join(setup) + "\n"


def _record(bundle, filter: str, steps: int, seed: int, options: dict) -> tuple[str, str, str, dict]:
    cls = FILTERS[filter]
    rng = np.random.default_rng(seed)
    n, m = bundle.n_x, bundle.n_y
    dt, U, Q, R, x_centre, x_half, advance = _truth(bundle, steps, rng)
    x0, P0 = _initial(x_centre, x_half, rng)
    sd = np.sqrt(np.diag(R))

    long_step, outliers = (6 * steps) // 10, set(range(700, steps, 1000))
    linear = [i for i in range(m) if i not in bundle.angle_outputs] or list(range(m))
    refused = {steps // 4: "u", steps // 2: "dt", (3 * steps) // 4: "z"}
    if bundle.n_u == 0:  # no input to make non-finite
        del refused[steps // 4]
    flt = cls(bundle, x0, P0, Q, R, **options)
    events = {long_step, *refused, *outliers}
    kept = set(range(0, steps, 10)) | {j + d for j in events for d in range(-2, 3) if 0 <= j + d < steps} | {steps - 1}
    upper = np.triu_indices(n)
    header = ",".join(["dt", *bundle.input_names, *(f"z_{name}" for name in bundle.output_names)])
    inputs = [header]
    expected = ["k,code,nis," + ",".join(f"x_{s}" for s in bundle.state_names) + ","
                + ",".join(f"P_{i}_{j}" for i in range(n) for j in range(i, n))]
    codes: dict[int, int] = {}
    calls, results = [], {}  # each row's (u, dt, z); the kept rows' (code, nis, x, P's upper triangle)
    missing, long_dt, x = 0, LONG_DT_FACTORS[0] * dt, x_centre.copy()
    for j in range(steps):
        u, dt_j = U[j].copy(), dt
        if j == long_step:
            dt_j = long_dt = _subdivided_dt(flt, u, dt)
        x = advance(x, u, int(round(dt_j / dt)))
        z = bundle.h(x) + rng.normal(size=m) * sd
        z[rng.random(m) < 0.05] = np.nan
        if j % 97 == 0:
            z[:] = np.nan
        if j in outliers:  # on an entry that is not an angle (an angle's innovation is wrapped)
            entry = linear[(j // 1000) % len(linear)]
            z[entry] = bundle.h(x)[entry] + 1e3 * sd[entry]
        what = refused.get(j)
        if what == "u":
            u[0] = np.nan
        elif what == "dt":
            dt_j = -dt
        elif what == "z":
            z[0] = np.inf
        missing += int(np.isnan(z).sum())
        code = _apply_row(flt, (u, dt_j, z))
        codes[code] = codes.get(code, 0) + 1
        inputs.append(",".join(repr(float(v)) for v in (dt_j, *u, *z)))
        calls.append((u, dt_j, z))
        if j in kept:
            results[j] = _result(flt, code, upper)
            row = [code, results[j][1], *results[j][2], *results[j][3]]
            expected.append(f"{j}," + ",".join(str(v) if i == 0 else repr(float(v)) for i, v in enumerate(row)))
    twin = _twin_deviation(cls(bundle, _nudged(x0, np.random.default_rng(seed + 2)), P0, Q, R, **options), calls,
                           _apply_row, results, upper, np.random.default_rng(seed + 3))
    setup = _setup_text(bundle, filter, flt, x0, P0, Q, R)
    summary = {"steps": steps, "dt": dt, "long_dt_step": long_step, "long_dt": float(long_dt),
               "refused_steps": {str(j): what for j, what in refused.items()},
               "codes": {str(c): v for c, v in sorted(codes.items())}, "missing_entries": missing,
               "outlier_steps": len(outliers), "gated": flt.gated, "inflations": flt.inflations, "repairs": flt.repairs,
               "substeps": flt.substeps, "expected_rows": len(expected) - 1, **twin}
    return setup, "\n".join(inputs) + "\n", "\n".join(expected) + "\n", summary


def _apply_row(flt, row) -> int:
    """One recorded row (u, dt, z) as a step of `flt` (z all NaN: no measurement); its return code."""
    u, dt, z = row
    try:
        return int(flt.step(u, dt, None if np.isnan(z).all() else z))
    except ValueError:
        return flt.code


def _apply_event(flt, event) -> int:
    """One recorded time-stamped call (t, sensor k or -1 for predict_to, values, its own R or None); its code."""
    t, k, values, R_k = event
    try:
        if k < 0:
            flt.predict_to(t, values)
            return flt.code
        return int(flt.update(flt.model.sensors[k]["name"], values, t, R=R_k))
    except ValueError:
        return flt.code


def _result(flt, code: int, upper) -> tuple:
    """What a recorded row holds after a call: (code, nis or NaN, x, P's upper triangle)."""
    return code, flt.nis if code == kr.UPDATED else np.nan, flt.x, flt.P[upper]


def _nudged(values: np.ndarray, rng) -> np.ndarray:
    """A copy of `values` with every non-zero finite entry moved by up to NUDGE_ULPS units in the last place; NaN,
    inf and zeros kept (a missing entry stays missing, a refusal a refusal, an R's zero off-diagonal zero, so that
    it stays symmetric)."""
    v = np.array(values, dtype=float)
    movable = np.isfinite(v) & (v != 0.0)
    v[movable] += rng.integers(-NUDGE_ULPS, NUDGE_ULPS + 1, size=int(movable.sum())) * np.spacing(v[movable])
    return v


def _twin_deviation(twin, calls, apply, results: dict, upper, rng) -> dict:
    """Rerun `calls` through apply(twin, call) with every array argument _nudged, and compare the rows `results`
    kept (row -> (code, nis, x, P upper)) as compare_csv does: {"twin": the largest relative differences of x and P
    and of the NIS, rows whose return code differs; "tolerance": ctest's, from them}."""
    worst = {"x_P": 0.0, "nis": 0.0}
    codes_differ = 0
    for j, call in enumerate(calls):
        code = apply(twin, tuple(_nudged(v, rng) if isinstance(v, np.ndarray) else v for v in call))
        if j not in results:
            continue
        expected, actual = results[j], _result(twin, code, upper)
        if code != expected[0]:
            codes_differ += 1
            continue
        for key, e, a in (("nis", [expected[1]], [actual[1]]), ("x_P", [*expected[2], *expected[3]],
                                                                   [*actual[2], *actual[3]])):
            e, a = np.asarray(e, dtype=float), np.asarray(a, dtype=float)
            both_nan = np.isnan(e) & np.isnan(a)
            with np.errstate(invalid="ignore"):
                difference = np.where(both_nan, 0.0, np.abs(a - e) / np.maximum(1.0, np.abs(e)))
            worst[key] = max(worst[key], float(np.nanmax(np.where(np.isnan(difference), np.inf, difference))))
    tolerance = {key: float(min(TOLERANCE_CAP, max(TOLERANCE_FLOORS[key], TOLERANCE_MARGIN * worst[key])))
                 for key in worst}
    return {"twin": {"nudge_ulps": NUDGE_ULPS, "largest_difference": worst, "rows_whose_code_differs": codes_differ},
            "tolerance": tolerance}


def _tolerance_text(value: float) -> str:
    """A tolerance as CMakeLists.txt passes it to compare_csv (rounded up to two significant digits)."""
    exponent = int(np.floor(np.log10(value)))
    mantissa = np.ceil(value / 10.0 ** exponent * 10.0 - 1e-9) / 10.0
    if mantissa >= 10.0:
        mantissa, exponent = mantissa / 10.0, exponent + 1
    return f"{mantissa:g}e{exponent}"



def _subdivided_dt(flt, u, dt: float) -> float:
    """The shortest of LONG_DT_FACTORS x dt that the filter subdivides (and does not refuse) now, tried on a
    checkpoint; the first factor when none is."""
    saved = flt.checkpoint()
    try:
        for factor in LONG_DT_FACTORS:
            before = flt.substeps
            try:
                flt.predict(u, factor * dt)
            except ValueError:
                continue
            finally:
                subdivided = flt.substeps > before
                flt.restore(saved)
            if subdivided:
                return factor * dt
    finally:
        flt.restore(saved)
    return LONG_DT_FACTORS[0] * dt


def record_events(bundle, filter: str, *, steps: int = 10_000, seed: int = 0, options: dict | None = None):
    """(events.csv, events_expected.csv texts, a summary dict) of the time-stamped calls on the Python `filter`.

    Each row is one call: "t,-1,u..." is predict_to(t, u) (u held over the interval that ends at t), "t,k,z..." is
    update_sensor(k, t, z) and "t,k,z...,R..." the same with the fix's own covariance (column-major). The truth is
    the stacked run's (_truth), over steps // 2 ticks; sensor k measures every max(1, round(1 / (rate_k dt))) ticks
    (k + 1 without a declared rate), and its measurements arrive after their declared latency (uniform in it), the
    last sensor's every 5th also 0.3-1.0 s late when it declares none: asynchronous rows, and late ones fused from
    the history at their stamp. Also: 5 % of the entries missing (NaN); the first sensor silent for a tenth of the
    run (dropped) and then stuck for another tenth (its value frozen 10^3 standard deviations off: gated, inflated
    along, held as rejected); every 3rd fix of the last sensor with its own R; refused rows: a fix older than the
    history (too late), a predict_to back in time, a non-finite u. events_expected.csv holds every 5th call, the
    calls around the refused ones and the last, as expected.csv does."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        warnings.simplefilter("ignore", LongStepWarning)
        return _record_events(bundle, filter, steps, seed, options or {})


def _record_events(bundle, filter: str, steps: int, seed: int, options: dict) -> tuple[str, str, dict]:
    cls = FILTERS[filter]
    rng = np.random.default_rng(seed)  # the stacked run's setup (x0, P0, Q, R: one setup.txt for both), then its own
    n, n_u = bundle.n_x, bundle.n_u
    ticks = max(steps // 2, 100)
    dt, U, Q, R, x_centre, x_half, advance = _truth(bundle, steps, rng)
    x0, P0 = _initial(x_centre, x_half, rng)
    rng = np.random.default_rng(seed + 1)
    sd = np.sqrt(np.diag(R))
    sensors = bundle.sensors
    history = float(options.get("history_seconds", 2.0))
    every = [max(1, int(round(1.0 / (s["rate"] * dt)))) if s.get("rate") else k + 1 for k, s in enumerate(sensors)]
    last = len(sensors) - 1
    outage = min(ticks // 10, int(round(3.0 / dt)))  # 3 s (or a tenth of the run): a short drop-out, then stuck
    dropped = range(ticks // 10, ticks // 10 + outage)
    stuck = range(ticks // 5, ticks // 5 + 2 * outage)
    too_late_tick, backwards_tick, bad_u_tick = (7 * ticks) // 10, (8 * ticks) // 10, (9 * ticks) // 10
    flt = cls(bundle, x0, P0, Q, R, **options)
    x, pending, calls = x_centre.copy(), [], []  # pending: (arrival, stamp, sensor, z, R or None)
    frozen, last_arrival = None, {}
    # the first sensor's entries that stick: all of them when other sensors carry the filter meanwhile, else its
    # first entry that is not an angle (a one-sensor model keeps the rest of its measurement)
    first = sensors[0]
    linear = [i for i in range(len(first["outputs"])) if i not in first.get("angle_outputs", [])] or [0]
    stuck_entries = list(range(len(first["outputs"]))) if len(sensors) > 1 else linear[:1]
    late = own_R = too_late = 0
    for j in range(ticks):
        t = (j + 1) * dt
        x = advance(x, U[j], 1)
        u = U[j].copy()
        if j == bad_u_tick and n_u:
            u[0] = np.nan
        calls.append((t, -1, u, None))
        if j == backwards_tick:
            calls.append((t - 0.5 * dt, -1, U[j].copy(), None))  # back in time: refused
        y = bundle.h(x)
        for k, s in enumerate(sensors):
            if (j + 1) % every[k] or (k == 0 and j in dropped):
                continue
            rows = slice(s["offset"], s["offset"] + len(s["outputs"]))
            z = y[rows] + rng.normal(size=len(s["outputs"])) * sd[rows]
            z[rng.random(len(z)) < 0.05] = np.nan
            if k == 0 and j in stuck:  # stuck 10^4 standard deviations off: never re-acquired within the cap
                if frozen is None:
                    frozen = y[rows] + 1e4 * sd[rows]
                z[stuck_entries] = frozen[stuck_entries]
            latency = 0.0
            if s.get("latency"):
                latency = float(rng.uniform(*s["latency"]))
            elif k == last and ((j + 1) // every[k]) % 5 == 0:
                latency = float(rng.uniform(0.3, 1.0))
            if j == too_late_tick and k == last:
                latency = history + 1.0
            R_k = None
            if k == last and ((j + 1) // every[k]) % 3 == 0:
                R_k = np.diag((sd[rows] * rng.uniform(0.5, 2.0, size=len(z))) ** 2)
            # a sensor's own stream stays in order (its stamps must increase): a late fix holds back the later ones
            arrival = max(t + latency, last_arrival.get(k, -np.inf))
            last_arrival[k] = arrival
            pending.append((arrival, t, k, z, R_k))
        arrived = sorted((p for p in pending if p[0] <= t + 1e-12), key=lambda p: (p[0], p[1], p[2]))
        pending = [p for p in pending if p[0] > t + 1e-12]
        for arrival, stamp, k, z, R_k in arrived:
            calls.append((stamp, k, z, R_k))
    upper = np.triu_indices(n)
    width = max([n_u, *(len(s["outputs"]) * (1 + len(s["outputs"])) for s in sensors)])
    lines = ["t,event," + ",".join(f"v_{i}" for i in range(width))]
    expected = ["k,code,nis," + ",".join(f"x_{s}" for s in bundle.state_names) + ","
                + ",".join(f"P_{i}_{j}" for i in range(n) for j in range(i, n))]
    codes: dict[int, int] = {}
    refused_calls = []
    results = []
    for e, (t, k, values, R_k) in enumerate(calls):
        if k >= 0:
            late += t < flt.t
        code = _apply_event(flt, (t, k, values, R_k))
        if code < 0:
            refused_calls.append(e)
            too_late += code == kr.E_TOO_LATE
        else:
            own_R += k >= 0 and R_k is not None
        codes[code] = codes.get(code, 0) + 1
        row = [t, k, *values] + ([] if R_k is None else list(R_k.ravel(order="F")))
        lines.append(",".join(repr(float(v)) for v in row))
        results.append(_result(flt, code, upper))
    kept = set(range(0, len(calls), 5)) | {e + d for e in refused_calls for d in range(-2, 3)} | {len(calls) - 1}
    kept = sorted(k for k in kept if 0 <= k < len(calls))
    for e in kept:
        code, nis, xe, Pe = results[e]
        expected.append(f"{e},{code}," + ",".join(repr(float(v)) for v in (nis, *xe, *Pe)))
    twin = _twin_deviation(cls(bundle, _nudged(x0, np.random.default_rng(seed + 4)), P0, Q, R, **options), calls,
                           _apply_event, {e: results[e] for e in kept}, upper, np.random.default_rng(seed + 5))
    report = [flt.sensor_report(s["name"]) for s in sensors]
    summary = {"calls": len(calls), "ticks": ticks, "dt": dt, "history_seconds": history,
               "codes": {str(c): v for c, v in sorted(codes.items())}, "late": int(flt.late), "late_calls": late,
               "too_late": too_late, "own_R": own_R, "dropped_ticks": [dropped.start, dropped.stop],
               "stuck_ticks": [stuck.start, stuck.stop], "sensor_every_ticks": every,
               "sensors": {s["name"]: {key: report[k][key] for key in ("used", "gated", "inflations", "late")}
                           for k, s in enumerate(sensors)},
               "expected_rows": len(expected) - 1, **twin}
    return "\n".join(lines) + "\n", "\n".join(expected) + "\n", summary


# ------------------------------------------------------------------ the headers and the README
def _c_comment(text: str) -> str:
    return text.replace("*/", "* /")


def _table(rows, title: str) -> list[str]:
    if not rows:
        return [f" * {title}: none"]
    width = max(len(q["name"]) for q in rows)
    unit = max(len(q.get("unit", "")) for q in rows)
    out = [f" * {title}:"]
    for i, q in enumerate(rows):
        default = f"  default {q['default']!r}" if "default" in q else ""
        out.append(f" *   [{i:2d}] {q['name']:<{width}}  {q.get('unit', ''):<{unit}}  {_c_comment(q.get('description', ''))}"
                   f"{default}")
    return out


def _model_header(manifest: dict, filter: str, bytes_: int, command: str, options: dict) -> str:
    m = manifest["model"]
    M = m.upper()
    kind = f"ABYSSAL_{'HUBER_UKF' if filter == 'huber' else filter.upper()}"
    angles = [manifest["outputs"][i]["name"] for i in manifest.get("angle_outputs", [])]
    first_sensor = _c_name(manifest["sensors"][0]["name"])
    lines = [f"/* {m}_filter.h: the model {m} for the exported {filter.upper()} (abyssal_kalman.h).",
             " *",
             f" * DO NOT EDIT: written by `{_c_comment(command)}` from the generated C of {m}",
             f" * (equations sha256 {manifest['equations_sha256'][:16]}..., CasADi {manifest['casadi']}); "
             "regenerate the model and export again.",
             " *",
             f" * Discretisation: {manifest['discretisation']}"
             + (f", {manifest['substeps']} substeps per step" if manifest.get("substeps") else "")
             + "; dt is a runtime input (seconds).",
             f" * Memory: the {filter.upper()} filter object of this model takes {bytes_} bytes "
             f"({platform.machine()}, 8-byte pointers) with a history of {options['history_seconds']:g} s "
             f"(at most {options['history_entries']} events)",
             " * for late measurements; abyssal_kalman_work_size() gives it on any target and for other options.",
             " * Matrices (P0, Q, P, R, S) are column-major; the measurement's angle entries"
             + (f" ({', '.join(angles)}) have their innovations wrapped to (-pi, pi]." if angles else ": none."),
             " *"]
    lines += _table(manifest["states"], f"State x ({len(manifest['states'])})")
    lines += _table(manifest["inputs"], f"Input u ({len(manifest['inputs'])})")
    lines += _table(manifest["outputs"], f"Measurement z ({len(manifest['outputs'])}); NaN: a missing entry")
    lines += _table(manifest["parameters"], f"Parameters p ({len(manifest['parameters'])}); NULL: the defaults")
    lines += _sensor_table(manifest)
    notes = manifest.get("notes") or []
    if notes:
        lines += [" *", " * Notes of the model:"] + [f" *   - {_c_comment(note)}" for note in notes]
    lines += [" *",
              " * Use (see abyssal_kalman.h for every call and return code):",
              " *",
              f" *     static double memory[{M}_{filter.upper()}_BYTES / sizeof(double)];",
              f" *     abyssal_kalman_options options = abyssal_kalman_default_options({kind});",
              f" *     options.history_seconds = {M}_HISTORY_SECONDS;   (late measurements: both, or none is kept)",
              f" *     options.history_entries = {M}_HISTORY_ENTRIES;   ({M}_{filter.upper()}_BYTES counts this history)",
              " *     abyssal_kalman* filter;",
              f" *     int code = abyssal_kalman_init(memory, sizeof memory, &{m}_descriptor, &options, x0, P0, Q, R, "
              "t0, &filter);",
              f" *     code = abyssal_kalman_step(filter, &{m}_descriptor, u, dt, z, NULL, NULL);   (1: updated, 0: "
              "predicted, < 0: refused)",
              " *   or, time-stamped (each sensor at its own rate; a late measurement is fused at its stamp):",
              f" *     code = abyssal_kalman_predict_to(filter, &{m}_descriptor, t, u, NULL);",
              f" *     code = abyssal_kalman_update_sensor(filter, &{m}_descriptor, {M}_SENSOR_{first_sensor}, t_z, z_k, "
              "NULL, R_k or NULL, NULL);",
              " *     const double* x = abyssal_kalman_x(filter);",
              " */",
              f"#ifndef {M}_FILTER_H", f"#define {M}_FILTER_H", "", '#include "abyssal_kalman.h"', "",
              f"#define {M}_N_X {len(manifest['states'])}", f"#define {M}_N_U {len(manifest['inputs'])}",
              f"#define {M}_N_Y {len(manifest['outputs'])}", f"#define {M}_N_P {len(manifest['parameters'])}",
              "/* bytes of the exported filter object on a 64-bit target (an upper bound on 32-bit ones) */",
              f"#define {M}_{filter.upper()}_BYTES {bytes_}", f"#define {M}_FILTER {kind}",
              "/* the history for late measurements that the byte count above includes (abyssal_kalman_options) */",
              f"#define {M}_HISTORY_SECONDS {options['history_seconds']!r}",
              f"#define {M}_HISTORY_ENTRIES {options['history_entries']}",
              f"#define {M}_N_SENSORS {len(manifest['sensors'])}",
              "/* each sensor's index (abyssal_kalman_update_sensor), its outputs, and its first entry in z and p */",
              *[line for k, sensor in enumerate(manifest["sensors"]) for line in (
                  f"#define {M}_SENSOR_{_c_name(sensor['name'])} {k}",
                  f"#define {M}_SENSOR_{_c_name(sensor['name'])}_N_Y {len(sensor['outputs'])}",
                  f"#define {M}_SENSOR_{_c_name(sensor['name'])}_OFFSET {sensor['offset']}",
                  f"#define {M}_SENSOR_{_c_name(sensor['name'])}_P_OFFSET {sensor['p_offset']}")], "",
              "#ifdef __cplusplus", 'extern "C" {', "#endif", "",
              "/* the model: sizes, default parameters, names, units and its generated functions */",
              f"extern const abyssal_model {m}_descriptor;", "", "#ifdef __cplusplus", "}", "#endif", "",
              f"#endif /* {M}_FILTER_H */", ""]
    return "\n".join(lines)


def _c_name(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name).upper()


def _sensor_table(manifest: dict) -> list[str]:
    """Each sensor: its index, outputs (entries of the stacked z, units), own parameters (entries of p), declared
    noise, rate and latency."""
    sensors = manifest.get("sensors") or []
    out = [" *", f" * Sensors ({len(sensors)}), each its own measurement z_k for abyssal_kalman_update_sensor (stacked in "
           "this order for abyssal_kalman_step):"]
    for k, s in enumerate(sensors):
        first, count = s["offset"], len(s["outputs"])
        noise = ("noise " + " ".join(f"{np.sqrt(row[i]):.4g}" for i, row in enumerate(s["noise"])) + " (std)"
                 if s.get("noise") else "no declared noise (R given at init)")
        timing = ", ".join(filter(None, (f"{s['rate']:g} Hz" if s.get("rate") else "",
                                         f"latency {s['latency'][0]:g}-{s['latency'][1]:g} s" if s.get("latency") else "")))
        out.append(f" *   [{k}] {s['name']}: z entries {first}..{first + count - 1}; {noise}" + (f"; {timing}" if timing else ""))
        for i, q in enumerate(s["outputs"]):
            angle = "  (angle: wrapped)" if i in s.get("angle_outputs", []) else ""
            out.append(f" *       {q['name']}  {q.get('unit', '')}  {_c_comment(q.get('description', ''))}{angle}")
        if s["parameters"]:
            out.append(f" *       own parameters: p entries {s['p_offset']}..{s['p_offset'] + len(s['parameters']) - 1} "
                       f"({', '.join(q['name'] + ' ' + q.get('unit', '') for q in s['parameters'])}); per call: q")
    return out


def _exported_header(manifest: dict, filter: str) -> str:
    m, M = manifest["model"], manifest["model"].upper()
    return "\n".join([
        "/* abyssal_exported.h: which model and filter this project exports (for run_csv and the tests). DO NOT EDIT. */",
        "#ifndef ABYSSAL_EXPORTED_H", "#define ABYSSAL_EXPORTED_H", f'#include "{m}_filter.h"',
        f"#define ABYSSAL_EXPORTED_MODEL (&{m}_descriptor)", f"#define ABYSSAL_EXPORTED_FILTER {M}_FILTER",
        f"#define ABYSSAL_EXPORTED_BYTES {M}_{filter.upper()}_BYTES", f"#define ABYSSAL_EXPORTED_N_X {M}_N_X",
        f"#define ABYSSAL_EXPORTED_N_U {M}_N_U", f"#define ABYSSAL_EXPORTED_N_Y {M}_N_Y", f"#define ABYSSAL_EXPORTED_N_P {M}_N_P",
        f"#define ABYSSAL_EXPORTED_N_SENSORS {M}_N_SENSORS",
        "#endif", ""])


def _readme(manifest: dict, filter: str, bytes_: int, command: str, summary: dict, events: dict, options: dict) -> str:
    m = manifest["model"]
    return f"""# {m}: {filter.upper()} filter in C

Written by `{command}`. Needs a C99 compiler (and CMake >= 3.13 for the project; a C++17 compiler for the
wrapper's test); no Python, NumPy or CasADi.

```bash
cmake -S . -B build && cmake --build build --parallel && (cd build && ctest --output-on-failure)   # --parallel: every core, a line per file
build/run_csv tests/vectors/setup.txt tests/vectors/input.csv out.csv      # the example: dt/u/z rows in, x/P rows out
build/run_csv tests/vectors/setup.txt tests/vectors/events.csv out.csv     # time-stamped rows: t, sensor, values
cc -std=c99 -Wall -Wextra -Werror -pedantic -O2 -ffp-contract=off -Iinclude src/*.c examples/run_csv.c -o run_csv -lm  # no CMake
```

`-DABYSSAL_SIMD=ON` vectorises the model's structure-of-arrays kernel (GCC/Clang; the sigma points of one predict
go through it in one call). Link `{m}_filter` (static, with the runtime `abyssal_kalman`) or
`lib{m}_filter.so` (shared, both in one).

- `include/{m}_filter.h`: the state, input, measurement and parameter layout with units, each sensor's outputs,
  units, parameters, noise, rate and latency (and its index, `{m.upper()}_SENSOR_<NAME>`), the sizes, and the
  memory of the filter object ({bytes_} bytes for this {filter.upper()} on a 64-bit target, with a history of
  {options['history_seconds']:g} s for late measurements).
- `include/abyssal_kalman.h`: the API (init, step/predict/update, reports, return codes and their messages);
  `include/abyssal_kalman.hpp`: a header-only C++17 wrapper (RAII; `std::array` arguments).
- `tests/vectors`: {summary['steps']} steps recorded from abyssal's Python filter (same C runtime, same generated
  C): {summary['missing_entries']} missing entries, {summary['outlier_steps']} gross outliers ({summary['gated']}
  entries gated), dt = {summary['long_dt']:g} s at step {summary['long_dt_step']} ({summary['substeps']} subdivided
  predicts), refused rows {', '.join(f"{k} ({v})" for k, v in summary['refused_steps'].items())}; ctest compares
  {summary['expected_rows']} recorded rows with run_csv's and the C++ wrapper's output: x and P within
  {_tolerance_text(summary['tolerance']['x_P'])} of max(1, |value|), the NIS within
  {_tolerance_text(summary['tolerance']['nis'])}. The tolerances come from this run: it was rerun on a twin with x0
  and every u, z and R entry moved by up to {NUDGE_ULPS} units in the last place (what another compiler's roundings
  do), which differed by {summary['twin']['largest_difference']['x_P']:.2g} (x, P) and
  {summary['twin']['largest_difference']['nis']:.2g} (NIS); ctest allows {TOLERANCE_MARGIN:g}x that, at least
  {TOLERANCE_FLOORS['x_P']:g} and {TOLERANCE_FLOORS['nis']:g} (the NIS's innovation z - h(x) cancels between two large
  numbers), at most {TOLERANCE_CAP:g}.
- `tests/vectors/events.csv`: {events['calls']} time-stamped calls of the same filter (`predict_to`,
  `update_sensor`; rows "t,-1,u" and "t,k,z[,R]"): sensors at their own rates, {events['late_calls']} measurements
  late (fused from the history at their stamp), {events['own_R']} with their own R, a sensor dropped and then
  stuck, and refused calls (a fix older than the history, a time stamp going back, a non-finite u); ctest compares
  {events['expected_rows']} recorded rows within {_tolerance_text(events['tolerance']['x_P'])} (x, P) and
  {_tolerance_text(events['tolerance']['nis'])} (NIS), derived the same way (the twin differed by
  {events['twin']['largest_difference']['x_P']:.2g} and {events['twin']['largest_difference']['nis']:.2g}: the stuck
  sensor's inflation leaves P ill-conditioned, which amplifies roundings, and each late fix re-runs the history).

The abyssal README's "On the vehicle" section describes the calls, what is checked at init, per-step parameters
and how the Python and C results relate.
"""
