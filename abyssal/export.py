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
recorded rows equal run_csv's bit for bit when compiled with the same compiler and flags (abyssal's own build), and
to rounding otherwise (other contractions into FMAs, another sin/cos); ctest compares x and P at 1e-12 of
max(1, |value|) and the NIS at 1e-9 (the innovation z - h(x) cancels between two large numbers).
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


def export(target, filter: str = "ckf", out=None, *, steps: int = 10_000, seed: int = 0, command: str | None = None) -> Path:
    """Write the C project of `filter` on the model `target` (a built-in name or a model folder) into `out`;
    returns the folder. See the module docstring."""
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
    out = _prepare(Path(out).expanduser())
    command = command or f"abyssal export {shlex.quote(str(target))} --filter {filter} --out {shlex.quote(str(out))}"
    bundle = generated.load(folder)
    setup, rows, expected, summary = record_vectors(bundle, filter, steps=steps, seed=seed)

    runtime = runtime_sources([*KALMAN, "abyssal_kalman.hpp"])
    for sub in ("include", "src", "examples", "tests/vectors"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    for name, text in sorted(sources.items()):  # the model's C, and its copy of the descriptor's type (abyssal_model.h)
        (out / ("include" if name.endswith(".h") else "src") / name).write_text(text)
    for name in RUNTIME_SOURCES:
        (out / "src" / name).write_text(runtime[name])
    for name in RUNTIME_HEADERS:
        (out / "include" / name).write_text(runtime[name])
    flt = cls(bundle, np.zeros(bundle.n_x), np.eye(bundle.n_x), np.eye(bundle.n_x), np.eye(bundle.n_y))
    bytes_ = int(flt._memory.nbytes)
    (out / "include" / f"{model}_filter.h").write_text(_model_header(manifest, filter, bytes_, command))
    (out / "include" / "abyssal_exported.h").write_text(_exported_header(manifest, filter))
    shutil.copyfile(EXPORT_TEMPLATES / "run_csv.c", out / "examples" / "run_csv.c")
    for name in ("compare_csv.c", "wrapper_test.cpp"):
        shutil.copyfile(EXPORT_TEMPLATES / name, out / "tests" / name)
    model_sources = " ".join(f"src/{name}" for name in sorted(sources) if name.endswith(".c"))
    cmake = (EXPORT_TEMPLATES / "CMakeLists.txt.in").read_text()
    runtime_list = " ".join(f"src/{name}" for name in RUNTIME_SOURCES)
    (out / "CMakeLists.txt").write_text(cmake.replace("@MODEL@", model).replace("@SOURCES@", model_sources)
                                        .replace("@RUNTIME_SOURCES@", runtime_list)
                                        .replace("@COMMAND@", command))
    (out / "tests" / "vectors" / "setup.txt").write_text(setup)
    (out / "tests" / "vectors" / "input.csv").write_text(rows)
    (out / "tests" / "vectors" / "expected.csv").write_text(expected)
    (out / "README.md").write_text(_readme(manifest, filter, bytes_, command, summary))
    (out / MARKER).write_text(json.dumps({"model": model, "filter": filter, "command": command, "steps": steps,
                                          "seed": seed, "vectors": summary}, indent=1) + "\n")
    return out


def _prepare(out: Path) -> Path:
    """`out` created, or emptied of an earlier export; refused when it holds files abyssal did not write."""
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"--out {out} is a file")
    if out.is_dir() and any(out.iterdir()):
        if not (out / MARKER).is_file():
            raise FileExistsError(f"--out {out} exists and holds files abyssal export did not write: choose an empty or "
                                  "new folder")
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
    return np.array([table.get(name, default) for name in names], dtype=float)


def record_vectors(bundle, filter: str, *, steps: int = 10_000, seed: int = 0):
    """(setup.txt, input.csv, expected.csv texts, a summary dict) of a run of the Python `filter` on `bundle`.

    The truth moves inside the model's envelope (inputs slowly swept around the centre of their ranges, additive
    process noise Q), the measurements are h plus noise R (R from the spread of the outputs over a pilot run); 5 %
    of the entries and every 97th row are missing, one entry in every 1000 steps is off by 10^3 standard
    deviations, steps T/4, T/2, 3T/4 are refused (NaN u, negative dt, infinite z), and step 0.6 T has the
    shortest of LONG_DT_FACTORS x dt that the filter subdivides there (tried on a checkpoint; the first factor
    when none is). expected.csv holds every 10th step, every step near an event and the last one."""
    with warnings.catch_warnings():  # the recording runs a long dt on purpose (beyond a declared max_dt)
        warnings.simplefilter("ignore", RuntimeWarning)
        return _record(bundle, filter, steps, seed)


def _record(bundle, filter: str, steps: int, seed: int) -> tuple[str, str, str, dict]:
    cls = FILTERS[filter]
    rng = np.random.default_rng(seed)
    n, m, n_u = bundle.n_x, bundle.n_y, bundle.n_u
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
    sd = np.sqrt(np.diag(R))

    long_step, outliers = (6 * steps) // 10, set(range(700, steps, 1000))
    linear = [i for i in range(m) if i not in bundle.angle_outputs] or list(range(m))
    refused = {steps // 4: "u", steps // 2: "dt", (3 * steps) // 4: "z"}
    P0 = np.diag((0.01 * x_half) ** 2)
    x0 = x_centre + rng.normal(size=n) * np.sqrt(np.diag(P0))
    flt = cls(bundle, x0, P0, Q, R)
    events = {long_step, *refused, *outliers}
    kept = set(range(0, steps, 10)) | {j + d for j in events for d in range(-2, 3) if 0 <= j + d < steps} | {steps - 1}
    upper = np.triu_indices(n)
    header = ",".join(["dt", *bundle.input_names, *(f"z_{name}" for name in bundle.output_names)])
    inputs = [header]
    expected = ["k,code,nis," + ",".join(f"x_{s}" for s in bundle.state_names) + ","
                + ",".join(f"P_{i}_{j}" for i in range(n) for j in range(i, n))]
    codes: dict[int, int] = {}
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
        try:
            code = int(flt.step(u, dt_j, None if np.isnan(z).all() else z))
        except ValueError:
            code = flt.code
        codes[code] = codes.get(code, 0) + 1
        inputs.append(",".join(repr(float(v)) for v in (dt_j, *u, *z)))
        if j in kept:
            row = [code, flt.nis if code == kr.UPDATED else np.nan, *flt.x, *flt.P[upper]]
            expected.append(f"{j}," + ",".join(str(v) if i == 0 else repr(float(v)) for i, v in enumerate(row)))
    setup = [f"# abyssal export: {bundle.name}, {filter}; x0, P0, Q and R (column-major), then the filter's options"]
    setup += [f"{name} {' '.join(map(repr, A.ravel(order='F').tolist()))}" for name, A in
              (("x0", x0), ("P0", P0), ("Q", Q), ("R", R))]
    setup += [f"{name} {float(kr.NOISE[value] if name == 'noise' else value)!r}" for name, value in flt.options.items()]
    summary = {"steps": steps, "dt": dt, "long_dt_step": long_step, "long_dt": float(long_dt),
               "refused_steps": {str(j): what for j, what in refused.items()},
               "codes": {str(c): v for c, v in sorted(codes.items())}, "missing_entries": missing,
               "outlier_steps": len(outliers), "gated": flt.gated, "inflations": flt.inflations, "repairs": flt.repairs,
               "substeps": flt.substeps, "expected_rows": len(expected) - 1}
    return "\n".join(setup) + "\n", "\n".join(inputs) + "\n", "\n".join(expected) + "\n", summary


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


def _model_header(manifest: dict, filter: str, bytes_: int, command: str) -> str:
    m = manifest["model"]
    M = m.upper()
    kind = f"ABYSSAL_{'HUBER_UKF' if filter == 'huber' else filter.upper()}"
    angles = [manifest["outputs"][i]["name"] for i in manifest.get("angle_outputs", [])]
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
             f"({platform.machine()}, 8-byte pointers); abyssal_kalman_work_size() gives it on any target.",
             " * Matrices (P0, Q, P, R, S) are column-major; the measurement's angle entries"
             + (f" ({', '.join(angles)}) have their innovations wrapped to (-pi, pi]." if angles else ": none."),
             " *"]
    lines += _table(manifest["states"], f"State x ({len(manifest['states'])})")
    lines += _table(manifest["inputs"], f"Input u ({len(manifest['inputs'])})")
    lines += _table(manifest["outputs"], f"Measurement z ({len(manifest['outputs'])}); NaN: a missing entry")
    lines += _table(manifest["parameters"], f"Parameters p ({len(manifest['parameters'])}); NULL: the defaults")
    notes = manifest.get("notes") or []
    if notes:
        lines += [" *", " * Notes of the model:"] + [f" *   - {_c_comment(note)}" for note in notes]
    lines += [" *",
              " * Use (see abyssal_kalman.h for every call and return code):",
              " *",
              f" *     static double memory[{M}_{filter.upper()}_BYTES / sizeof(double)];",
              f" *     abyssal_kalman_options options = abyssal_kalman_default_options({kind});",
              " *     abyssal_kalman* filter;",
              f" *     int code = abyssal_kalman_init(memory, sizeof memory, &{m}_descriptor, &options, x0, P0, Q, R, "
              "t0, &filter);",
              f" *     code = abyssal_kalman_step(filter, &{m}_descriptor, u, dt, z, NULL, NULL);   (1: updated, 0: "
              "predicted, < 0: refused)",
              " *     const double* x = abyssal_kalman_x(filter);",
              " */",
              f"#ifndef {M}_FILTER_H", f"#define {M}_FILTER_H", "", '#include "abyssal_kalman.h"', "",
              f"#define {M}_N_X {len(manifest['states'])}", f"#define {M}_N_U {len(manifest['inputs'])}",
              f"#define {M}_N_Y {len(manifest['outputs'])}", f"#define {M}_N_P {len(manifest['parameters'])}",
              "/* bytes of the exported filter object on a 64-bit target (an upper bound on 32-bit ones) */",
              f"#define {M}_{filter.upper()}_BYTES {bytes_}", f"#define {M}_FILTER {kind}", "",
              "#ifdef __cplusplus", 'extern "C" {', "#endif", "",
              "/* the model: sizes, default parameters, names, units and its generated functions */",
              f"extern const abyssal_model {m}_descriptor;", "", "#ifdef __cplusplus", "}", "#endif", "",
              f"#endif /* {M}_FILTER_H */", ""]
    return "\n".join(lines)


def _exported_header(manifest: dict, filter: str) -> str:
    m, M = manifest["model"], manifest["model"].upper()
    return "\n".join([
        "/* abyssal_exported.h: which model and filter this project exports (for run_csv and the tests). DO NOT EDIT. */",
        "#ifndef ABYSSAL_EXPORTED_H", "#define ABYSSAL_EXPORTED_H", f'#include "{m}_filter.h"',
        f"#define ABYSSAL_EXPORTED_MODEL (&{m}_descriptor)", f"#define ABYSSAL_EXPORTED_FILTER {M}_FILTER",
        f"#define ABYSSAL_EXPORTED_BYTES {M}_{filter.upper()}_BYTES", f"#define ABYSSAL_EXPORTED_N_X {M}_N_X",
        f"#define ABYSSAL_EXPORTED_N_U {M}_N_U", f"#define ABYSSAL_EXPORTED_N_Y {M}_N_Y", f"#define ABYSSAL_EXPORTED_N_P {M}_N_P",
        "#endif", ""])


def _readme(manifest: dict, filter: str, bytes_: int, command: str, summary: dict) -> str:
    m = manifest["model"]
    return f"""# {m}: {filter.upper()} filter in C

Written by `{command}`. Needs a C99 compiler (and CMake >= 3.13 for the project; a C++17 compiler for the
wrapper's test); no Python, NumPy or CasADi.

```bash
cmake -S . -B build && cmake --build build && (cd build && ctest --output-on-failure)
build/run_csv tests/vectors/setup.txt tests/vectors/input.csv out.csv      # the example: dt/u/z rows in, x/P rows out
cc -std=c99 -Wall -Wextra -Werror -pedantic -O2 -Iinclude src/*.c examples/run_csv.c -o run_csv -lm   # no CMake
```

`-DABYSSAL_SIMD=ON` vectorises the model's structure-of-arrays kernel (GCC/Clang; the sigma points of one predict
go through it in one call). Link `{m}_filter` (static, with the runtime `abyssal_kalman`) or
`lib{m}_filter.so` (shared, both in one).

- `include/{m}_filter.h`: the state, input, measurement and parameter layout with units, the sizes, and the
  memory of the filter object ({bytes_} bytes for this {filter.upper()} on a 64-bit target).
- `include/abyssal_kalman.h`: the API (init, step/predict/update, reports, return codes and their messages);
  `include/abyssal_kalman.hpp`: a header-only C++17 wrapper (RAII; `std::array` arguments).
- `tests/vectors`: {summary['steps']} steps recorded from abyssal's Python filter (same C runtime, same generated
  C): {summary['missing_entries']} missing entries, {summary['outlier_steps']} gross outliers ({summary['gated']}
  entries gated), dt = {summary['long_dt']:g} s at step {summary['long_dt_step']} ({summary['substeps']} subdivided
  predicts), refused rows {', '.join(f"{k} ({v})" for k, v in summary['refused_steps'].items())}; ctest compares
  {summary['expected_rows']} recorded rows with run_csv's and the C++ wrapper's output: x and P within 1e-12 of
  max(1, |value|), the NIS within 1e-9 (the innovation z - h(x) cancels between two large numbers).

The abyssal README's "On the vehicle" section describes the calls, what is checked at init, per-step parameters
and how the Python and C results relate.
"""
