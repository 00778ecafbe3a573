"""Model section of `abyssal bench`: per-call cost of the generated model functions beside peers
measured in the same run.

Per call (f, F, h):   fast path (``fn.bind(...)`` then ``binding.eval``), the convenience call
                      (``bundle.f(x, u, p, dt)``), CasADi's symbolic Function called from Python,
                      and the same generated C in a pure-C loop (a small timing driver compiled
                      here with the compiler and flags of abyssal.generated.build).
Per particle (f):     the ``_batch`` entry point bound to (n, N) Fortran buffers (serial C loop),
                      the SIMD structure-of-arrays kernel (``bind_soa``, what ``f_batch`` calls),
                      and a vectorised NumPy RK4 of the reference model, at N = 1000 and 100000.

Targets (rov4dof): fast-path overhead over pure C <= 0.5 us; f batch <= 100 ns per particle;
f batch >= 10x faster than NumPy.
"""
from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

import numpy as np

from abyssal import generated
from abyssal.generated.build import BuildError, cflags, compiler
from abyssal.verify import reference_models

from bench import json_main, median_time, target

PER_CALL = ("f", "F", "h")
BATCH_SIZES = (1000, 100_000)

# A pure-C timing loop around generated functions; {declarations} and {timings} are filled per model.
C_DRIVER = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>

typedef double casadi_real;
typedef long long int casadi_int;
{declarations}

static double now_ns(void) {{
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return 1e9 * (double)ts.tv_sec + (double)ts.tv_nsec;
}}

static volatile casadi_real sink;

/* Median over `repeat` loops of `calls` calls, in ns per call. */
#define TIME_CALLS(label, call, out)                                   \
  do {{                                                                 \
    double samples[{repeat}];                                          \
    int rep, k, i, j;                                                  \
    for (rep = 0; rep < {repeat}; ++rep) {{                             \
      double t0 = now_ns();                                            \
      for (k = 0; k < {calls}; ++k) {{ call; sink = (out)[0]; }}        \
      samples[rep] = (now_ns() - t0) / {calls};                        \
    }}                                                                 \
    for (i = 1; i < {repeat}; ++i)                                     \
      for (j = i; j > 0 && samples[j - 1] > samples[j]; --j) {{         \
        double t = samples[j]; samples[j] = samples[j - 1]; samples[j - 1] = t; \
      }}                                                               \
    printf("%s %.3f\n", label, samples[{repeat} / 2]);                 \
  }} while (0)

int main(void) {{
{buffers}
{timings}
  return 0;
}}
"""


def _c_array(name: str, values) -> str:
    values = np.atleast_1d(np.asarray(values, dtype=float)).ravel(order="F")
    return f"  static casadi_real {name}[{max(1, values.size)}] = {{{', '.join(repr(float(v)) for v in values) or '0'}}};"


def pure_c_times(bundle, args: dict[str, np.ndarray], names=PER_CALL, quick: bool = False) -> dict[str, float]:
    """ns per call of <model>_<name> for each name, from a C loop linked with the generated C files that
    define them (the manifest says which: F lives in the EKF's file when that family is generated)."""
    manifest, sources = generated.read_sources(bundle.name)
    fns = [bundle.functions[n] for n in names if n in bundle.functions]
    files = sorted({manifest["functions"][fn.name]["file"] for fn in fns})
    declarations, buffers, timings = [], [], []
    buffers += [_c_array(f"in_{k}", v) for k, v in args.items()]
    for fn in fns:
        spec = fn.spec
        declarations.append(f"int {fn.name}(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem);")
        tag = fn.name
        outs = ", ".join(f"out_{tag}_{i}" for i in range(len(fn.outputs)))
        buffers += [f"  static casadi_real out_{tag}_{i}[{s.size}];" for i, s in enumerate(fn.outputs)]
        buffers += [
            f"  const casadi_real* arg_{tag}[{max(1, spec['sz_arg'])}] = {{{', '.join(f'in_{s.name}' for s in fn.inputs)}}};",
            f"  casadi_real* res_{tag}[{max(1, spec['sz_res'])}] = {{{outs}}};",
            f"  static casadi_int iw_{tag}[{max(1, spec['sz_iw'])}];",
            f"  static casadi_real w_{tag}[{max(1, spec['sz_w'])}];",
        ]
        timings.append(f'  TIME_CALLS("{fn.name}", {fn.name}(arg_{tag}, res_{tag}, iw_{tag}, w_{tag}, 0), out_{tag}_0);')
    driver = C_DRIVER.format(declarations="\n".join(declarations), buffers="\n".join(buffers),
                             timings="\n".join(timings), repeat=5 if quick else 11, calls=20_000 if quick else 200_000)
    with tempfile.TemporaryDirectory(prefix="abyssal-bench-") as tmp:
        tmp = Path(tmp)
        (tmp / "driver.c").write_text(driver)
        for name in files:
            (tmp / name).write_text(sources[name])
        exe = tmp / "driver"
        cmd = [compiler(), *cflags(), str(tmp / "driver.c"), *(str(tmp / name) for name in files), "-o", str(exe), "-lm"]
        res = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if res.returncode != 0:
            raise BuildError(f"compiling the timing driver failed: {' '.join(cmd)}\n{res.stderr[-4000:]}")
        out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout
    times = {}
    for line in out.splitlines():
        label, ns = line.split()
        times[label[len(bundle.name) + 1:]] = float(ns)
    return times


def _timer(quick: bool):
    return (lambda fn: median_time(fn, repeat=3, min_time=0.01)) if quick else (lambda fn: median_time(fn))


def per_call(bundle, quick: bool) -> dict:
    """Seconds -> ns per call of f, F, h through each path."""
    from abyssal.verify.models import symbolic_functions

    timer = _timer(quick)
    ref = reference_models.REFERENCES.get(bundle.name)
    rng = np.random.default_rng(1)
    x = ref.cruise[0] if ref and ref.cruise else (ref.sample_state(rng) if ref else np.zeros(bundle.n_x))
    u = ref.cruise[1] if ref and ref.cruise else (ref.sample_input(rng) if ref else np.zeros(bundle.n_u))
    args = {"x": np.array(x, dtype=float), "u": np.array(u, dtype=float), "p": bundle.params(), "dt": np.array([0.1])}
    symbolic = symbolic_functions(bundle.name)
    pure_c = pure_c_times(bundle, args, quick=quick)
    results = {}
    for name in PER_CALL:
        fn = bundle.functions[name]
        ins = [args[s.name] for s in fn.inputs]
        outs = [np.zeros(s.shape, order="F") for s in fn.outputs]
        binding = fn.bind(ins, outs)
        fast = binding.eval
        row = {
            "pure_c_ns": pure_c[name],
            "fast_path_ns": timer(fast) * 1e9,
            "convenience_ns": timer(lambda: fn(*ins)) * 1e9,
        }
        if name in symbolic:
            casadi_fn = symbolic[name]
            row["casadi_python_ns"] = timer(lambda: casadi_fn(*ins)) * 1e9
            row["casadi_over_fast_path"] = row["casadi_python_ns"] / row["fast_path_ns"]
        row["fast_path_overhead_ns"] = row["fast_path_ns"] - row["pure_c_ns"]
        results[name] = row
    return results


def numpy_rk4_batch(bundle, ref):
    """Vectorised NumPy step of the reference model over columns (the NumPy peer of f_batch)."""
    disc, substeps = bundle.manifest["discretisation"], bundle.manifest["substeps"]
    return lambda X, U, p, dt: reference_models.step(ref, X, U, p, dt, disc, substeps)


def per_particle(bundle, quick: bool) -> dict:
    """ns per particle of one f step over N columns, per path."""
    timer = _timer(quick)
    ref = reference_models.REFERENCES[bundle.name]
    rng = np.random.default_rng(2)
    p, dt = bundle.params(), np.array([0.1])
    fn = bundle.functions["f"]
    results = {}
    for n in BATCH_SIZES:
        X = np.asfortranarray(ref.sample_state(rng, n))
        u = np.ascontiguousarray(ref.sample_input(rng))
        Y = np.zeros((bundle.n_x, n), order="F")
        serial = fn.bind_batch([X, u, p, dt], [Y], capacity=n)
        Xc, Uc, Yc = np.ascontiguousarray(X), np.ascontiguousarray(np.repeat(u[:, None], n, axis=1)), np.zeros((bundle.n_x, n))
        simd = fn.bind_soa([Xc, Uc, p, dt], [Yc])
        numpy_step = numpy_rk4_batch(bundle, ref)
        Xn = np.ascontiguousarray(X)
        row = {
            "batch_entry_ns": timer(lambda: serial(n)) * 1e9 / n,
            "soa_simd_ns": timer(lambda: simd(n)) * 1e9 / n,
            "f_batch_convenience_ns": timer(lambda: bundle.f_batch(Xc, u, p, 0.1)) * 1e9 / n,
            "numpy_vectorised_ns": timer(lambda: numpy_step(Xn, u, p, 0.1)) * 1e9 / n,
        }
        row["numpy_over_batch_entry"] = row["numpy_vectorised_ns"] / row["batch_entry_ns"]
        row["numpy_over_soa_simd"] = row["numpy_vectorised_ns"] / row["soa_simd_ns"]
        results[str(n)] = row
    return results


def run(quick: bool = False, verbose: bool = True) -> dict:
    results, targets = {}, []
    for name in ("rov4dof", "cn2d"):
        bundle = generated.load(name)
        results[name] = {"per_call": per_call(bundle, quick), "per_particle": per_particle(bundle, quick)}
        if verbose:
            _print(name, results[name])
    rov = results["rov4dof"]
    # Targets apply to f_batch (the SIMD kernel); the serial `_batch` entry point is a peer in the results.
    targets.append(
        target("rov4dof f fast-path overhead over pure C", rov["per_call"]["f"]["fast_path_overhead_ns"] / 1e3, 0.5, "us"))
    for n in BATCH_SIZES:
        row = rov["per_particle"][str(n)]
        targets += [
            target(f"rov4dof f_batch (SIMD kernel) per particle, N = {n}", row["soa_simd_ns"], 100.0, "ns"),
            target(f"rov4dof f_batch (SIMD kernel) speed-up over NumPy, N = {n}", row["numpy_over_soa_simd"], 10.0, "x",
                   higher_is_better=True),
        ]
    return {"results": results, "targets": targets}


def _print(name: str, res: dict) -> None:
    print(f"{name}: ns per call")
    print(f"  {'fn':<4} {'pure C':>9} {'fast path':>10} {'convenience':>12} {'CasADi/Python':>14} {'CasADi/fast':>12}")
    for fn, row in res["per_call"].items():
        print(f"  {fn:<4} {row['pure_c_ns']:9.1f} {row['fast_path_ns']:10.1f} {row['convenience_ns']:12.1f} "
              f"{row.get('casadi_python_ns', float('nan')):14.1f} {row.get('casadi_over_fast_path', float('nan')):11.0f}x")
    print(f"{name}: f, ns per particle")
    print(f"  {'N':>7} {'_batch (C loop)':>16} {'SIMD kernel':>12} {'f_batch()':>10} {'NumPy':>8} {'NumPy/C loop':>13} {'NumPy/SIMD':>11}")
    for n, row in res["per_particle"].items():
        print(f"  {n:>7} {row['batch_entry_ns']:16.1f} {row['soa_simd_ns']:12.1f} {row['f_batch_convenience_ns']:10.1f} "
              f"{row['numpy_vectorised_ns']:8.1f} {row['numpy_over_batch_entry']:12.1f}x {row['numpy_over_soa_simd']:10.1f}x")


if __name__ == "__main__":  # python benchmarks/bench_models.py [--quick]: this section alone, as JSON
    json_main(run, __doc__)
