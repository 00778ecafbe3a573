"""How generated code grows with the model: C bytes, seconds to generate, seconds to the
first loaded bundle and µs per filter step, against the number of states n.

    python benchmarks/bench_scaling.py                     # n = 6, 12, 18, 24, 30, 36, CKF family
    python benchmarks/bench_scaling.py --quick             # n = 6, 12: a smoke run
    python benchmarks/bench_scaling.py --families all      # every family (ekf, ukf, ckf, robust): EKF step too
    python benchmarks/bench_scaling.py --bluerov2          # also examples/bluerov2 (12 states, 8 inputs)
    python benchmarks/bench_scaling.py --timeout 600 --json scaling.json

The family of models: a chain of n/2 damped pendulums, neighbours coupled by torsion springs
(free ends), a torque input and a torque-noise input per pendulum, the angles measured, RK4 with
2 substeps. Every generated function of it is dense in the state (the springs couple every
pendulum to every other through the RK4 stages), as a real vehicle's are.

Each model runs in a child process of its own, with a fresh empty compile cache (ABYSSAL_CACHE_DIR
in a temporary folder), so "build" is a first build on this machine: generate (abyssal.generate
into a temporary folder), then abyssal.load of that folder (the compiler and the smoke test), then
per step: the runtime's CKF.step (and EKF.step when the "ekf" family is generated) over a
simulated run, and the generated ckf_step (ekf_step) alone through the bundle's fast path
(``bundle.function("ckf_step").bind(...)``, the same number of calls on fixed buffers); medians
over rounds that alternate between them, so a machine that gets busier slows all alike. A child that
exceeds --timeout seconds (generate, build and the timed steps together) is killed with its
compiler processes and its row says where it stopped ("did not build in S s"); what it measured
before stays.

The growth exponent is the slope of a least-squares line through log(value) against log(n) over
the chain sizes that finished (the BlueROV2 row is reported beside them, not fitted).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
BLUEROV2 = HERE.parent / "examples" / "bluerov2" / "bluerov2.py"
SIZES, QUICK_SIZES = (6, 12, 18, 24, 30, 36), (6, 12)
ALL_FAMILIES = ("ekf", "ukf", "ckf", "robust")
DT = 0.1
SUBSTEPS = 2


# --------------------------------------------------------------------------- the model family
def pendulum_chain(n: int):
    """n/2 damped pendulums in a row, neighbours coupled by torsion springs (n states).

        theta_i_dot = omega_i
        omega_i_dot = -(g/l) sin(theta_i) - c omega_i + k (theta_{i-1} - 2 theta_i + theta_{i+1}) + tau_i + w_i

    with free ends (a missing neighbour contributes no spring); torques per unit inertia.
    """
    import casadi as ca

    from abyssal import Model, Parameter, Quantity, symbols

    if n < 2 or n % 2:
        raise ValueError(f"n must be an even number >= 2 (n/2 pendulums), got {n}")
    k_count = n // 2
    states = tuple(Quantity(f"theta_{i}", "rad", f"angle of pendulum {i}") for i in range(k_count)) + tuple(
        Quantity(f"omega_{i}", "rad/s", f"rate of pendulum {i}") for i in range(k_count))
    inputs = tuple(Quantity(f"tau_{i}", "rad/s^2", f"torque on pendulum {i} per unit inertia") for i in range(k_count))
    noises = tuple(Quantity(f"w_{i}", "rad/s^2", f"torque noise on pendulum {i}") for i in range(k_count))
    outputs = tuple(Quantity(f"theta_{i}", "rad", f"encoder of pendulum {i}") for i in range(k_count))
    parameters = (Parameter("g_over_l", "1/s^2", 9.81, "gravity over pendulum length"),
                  Parameter("c", "1/s", 0.5, "damping per unit inertia"),
                  Parameter("k", "1/s^2", 2.0, "spring between neighbours per unit inertia"))
    x, u, p, w = symbols("x", states), symbols("u", inputs), symbols("p", parameters), symbols("w", noises)
    theta, omega = x[:k_count], x[k_count:]
    g_over_l, c, k = p[0], p[1], p[2]
    springs = []
    for i in range(k_count):
        left = theta[i - 1] - theta[i] if i > 0 else 0
        right = theta[i + 1] - theta[i] if i < k_count - 1 else 0
        springs.append(k * (left + right))
    omega_dot = -g_over_l * ca.sin(theta) - c * omega + ca.vertcat(*springs) + u + w
    return Model(name=f"chain{n}", states=states, inputs=inputs, parameters=parameters, noises=noises,
                 outputs=outputs, x=x, u=u, p=p, w=w, xdot=ca.vertcat(omega, omega_dot), y=theta,
                 discretisation="rk4", substeps=SUBSTEPS)


# --------------------------------------------------------------------------- one model, in a child
def _families(text: str) -> tuple[str, ...]:
    return ALL_FAMILIES if text == "all" else tuple(f for f in text.split(",") if f)


def _progress(path: Path, **record) -> None:
    with open(path, "a") as out:
        out.write(json.dumps(record) + "\n")


def _noise(bundle):
    """Q (additive on the discrete state) and R of the simulated run: torque or force noise through G."""
    import numpy as np

    n, m = bundle.n_x, bundle.n_y
    G = bundle.G(np.zeros(n), np.zeros(bundle.n_u), None, DT)
    Q = G @ G.T * 0.05 + 1e-8 * np.eye(n)
    R = np.eye(m) * 1e-4
    return Q, R


def _trajectory(bundle, steps: int, rng):
    """x0, P0, Q, R, U (steps, n_u), Z (steps, n_y) of a simulated run on the compiled model."""
    import numpy as np

    n = bundle.n_x
    Q, R = _noise(bundle)
    t = DT * np.arange(steps)
    phase = np.linspace(0.0, np.pi, bundle.n_u)
    U = 0.5 * np.sin(0.3 * t[:, None] + phase[None, :]) + 0.1 * rng.standard_normal((steps, bundle.n_u))
    x = 0.05 * rng.standard_normal(n)
    x0 = x.copy()
    Z = np.empty((steps, bundle.n_y))
    for k in range(steps):
        x = bundle.f(x, U[k], None, DT) + rng.multivariate_normal(np.zeros(n), Q)
        Z[k] = bundle.h(x) + rng.multivariate_normal(np.zeros(bundle.n_y), R)
    return x0, 0.01 * np.eye(n), Q, R, U, Z


def _pass_us(flt, U, Z, x0, P0) -> float:
    """Mean µs per flt.step over one pass of the run (from x0, P0)."""
    flt.reset(x0, P0)
    t0 = time.perf_counter()
    for k in range(len(U)):
        flt.step(U[k], DT, Z[k])
    return 1e6 * (time.perf_counter() - t0) / len(U)


def _bound_call(bundle, name: str, x0, P0, Q, R, u, z):
    """The generated `name` (ckf_step / ekf_step) bound to fixed buffers through the fast path: a no-argument call."""
    import numpy as np

    fn = bundle.function(name)
    values = {"x": x0, "P": P0, "u": u, "p": bundle.p_default, "dt": np.array([DT]), "Q": Q, "z": z, "R": R,
              "mask": np.ones(bundle.n_y)}
    inputs = [np.asfortranarray(np.array(values[s.name], dtype=np.float64).reshape(s.shape, order="F"))
              for s in fn.inputs]
    outputs = [np.zeros(s.shape, order="F") for s in fn.outputs]
    return fn.bind(inputs, outputs).eval


def _calls_us(call, calls: int) -> float:
    t0 = time.perf_counter()
    for _ in range(calls):
        call()
    return 1e6 * (time.perf_counter() - t0) / calls


def _median(samples) -> float:
    samples = sorted(samples)
    return samples[len(samples) // 2]


def child(spec: str, families: tuple[str, ...], folder: Path, progress: Path, steps: int, repeat: int) -> None:
    """Generate, load and time one model, appending one JSON line per finished phase to `progress`."""
    import numpy as np

    import abyssal
    from abyssal.generated.regenerate import load_model_spec

    t0 = time.perf_counter()
    model = pendulum_chain(int(spec.removeprefix("chain:"))) if spec.startswith("chain:") else load_model_spec(spec)[0]
    out = abyssal.generate(model, folder, families)
    generate_s = time.perf_counter() - t0
    manifest = json.loads((out / "manifest.json").read_text())
    files = {p.name: p.stat().st_size for p in sorted(out.glob("*.c"))}
    instructions = {name.removeprefix(model.name + "_"): spec_.get("instructions")
                    for name, spec_ in manifest["functions"].items()}
    _progress(progress, phase="generated", model=model.name, n_x=model.n_x, n_u=model.n_u, n_p=model.n_p,
              n_y=model.n_y, generate_s=generate_s, files=files, c_bytes=sum(files.values()), instructions=instructions)

    t0 = time.perf_counter()
    bundle = abyssal.load(out)
    _progress(progress, phase="loaded", load_s=time.perf_counter() - t0)

    rng = np.random.default_rng(0)
    x0, P0, Q, R, U, Z = _trajectory(bundle, steps, rng)
    # what is timed: the runtime's step() over the run, and the bare generated call on fixed buffers;
    # rounds alternate between them so a machine that gets busier mid-way slows both alike
    timed = {}
    for label, cls, fused in (("CKF.step", abyssal.CKF, "ckf_step"), ("EKF.step", abyssal.EKF, "ekf_step")):
        if fused.removesuffix("_step") + "_predict" not in bundle.functions:
            continue
        flt = cls(bundle, x0, P0, Q, R)
        timed[label] = lambda flt=flt: _pass_us(flt, U, Z, x0, P0)
        if fused in bundle.functions:
            call = _bound_call(bundle, fused, x0, P0, Q, R, U[0], Z[0])
            timed[f"{fused} bound"] = lambda call=call: _calls_us(call, len(U))
    samples = {label: [] for label in timed}
    for round_ in range(repeat + 1):  # round 0 warms caches (a step's code can be megabytes) and is dropped
        for label, measure_once in timed.items():
            value = measure_once()
            if round_:
                samples[label].append(value)
    step_us = {label: _median(values) for label, values in samples.items()}
    _progress(progress, phase="timed", steps=steps, step_us=step_us)


# --------------------------------------------------------------------------- the parent
def measure(label: str, spec: str, families, timeout: float, steps: int, repeat: int, verbose: bool) -> dict:
    """Run the child for one model under a deadline; the row of what it measured."""
    with tempfile.TemporaryDirectory(prefix="abyssal-scaling-") as tmp:
        tmp = Path(tmp)
        (tmp / "cache").mkdir()
        progress = tmp / "progress.jsonl"
        env = dict(os.environ, ABYSSAL_CACHE_DIR=str(tmp / "cache"),
                   ABYSSAL_BUILD_TIMEOUT=str(timeout + 60))  # the deadline below governs, not the cache's
        command = [sys.executable, str(Path(__file__).resolve()), "--child", spec, "--families", ",".join(families),
                   "--folder", str(tmp / "gen"), "--progress", str(progress), "--steps", str(steps),
                   "--repeat", str(repeat)]
        load_before = os.getloadavg()[0]
        t0 = time.perf_counter()
        proc = subprocess.Popen(command, env=env, cwd=tmp, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, start_new_session=True)  # own process group: the compilers die with it
        try:
            output, _ = proc.communicate(timeout=timeout)
            status = "ok" if proc.returncode == 0 else f"failed (exit {proc.returncode})"
        except subprocess.TimeoutExpired:
            # SIGTERM first: the child exits through Python, and the cache's build kills the compilers it
            # runs in process groups of their own on the way out; SIGKILL if it does not stop in time
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                output, _ = proc.communicate(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                output, _ = proc.communicate()
            status = None
        wall = time.perf_counter() - t0
        row = {"label": label, "spec": spec, "families": list(families), "wall_s": wall,
               "load_average": [load_before, os.getloadavg()[0]]}  # 1-min load before / after: was the machine idle?
        if spec.startswith("chain:"):
            row["n_x"] = int(spec.removeprefix("chain:"))  # known before the child reports it
        phases = [json.loads(line) for line in progress.read_text().splitlines()] if progress.exists() else []
        for record in phases:
            row.update({k: v for k, v in record.items() if k != "phase"})
        done = [r["phase"] for r in phases]
        if status is None:
            where = "generate" if "generated" not in done else "build" if "loaded" not in done else "time the steps"
            status = f"did not {where} in {timeout:g} s"
        row["status"] = status
        if status.startswith("failed"):
            row["output_tail"] = output[-2000:]
        if verbose:
            tail = f"\n{output[-2000:]}" if status.startswith("failed") else ""
            print(f"  {label}: {status} ({wall:.1f} s, load average {load_before:.1f} -> {row['load_average'][1]:.1f})"
                  + tail, flush=True)
        return row


def growth(rows: list[dict], key) -> float | None:
    """Least-squares slope of log(value) against log(n) over the rows that have the value."""
    points = [(r["n_x"], key(r)) for r in rows if r.get("n_x") and key(r)]
    if len(points) < 2:
        return None
    xs = [math.log(n) for n, _ in points]
    ys = [math.log(v) for _, v in points]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    sxx = sum((x - mx) ** 2 for x in xs)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx if sxx else None


COLUMNS = (  # header, value of a row, format
    ("C bytes", lambda r: r.get("c_bytes"), lambda v: f"{v / 1e6:.2f} MB"),
    ("generate s", lambda r: r.get("generate_s"), lambda v: f"{v:.1f}"),
    ("build + load s", lambda r: r.get("load_s"), lambda v: f"{v:.1f}"),
    ("CKF.step µs", lambda r: r.get("step_us", {}).get("CKF.step"), lambda v: f"{v:.1f}"),
    ("ckf_step bound µs", lambda r: r.get("step_us", {}).get("ckf_step bound"), lambda v: f"{v:.2f}"),
    ("EKF.step µs", lambda r: r.get("step_us", {}).get("EKF.step"), lambda v: f"{v:.1f}"),
    ("ekf_step bound µs", lambda r: r.get("step_us", {}).get("ekf_step bound"), lambda v: f"{v:.2f}"),
)


def table(rows: list[dict], fitted: list[dict]) -> str:
    lines = ["| model | n | " + " | ".join(h for h, _, _ in COLUMNS) + " | status |",
             "|---|---|" + "---|" * len(COLUMNS) + "---|"]
    for r in rows:
        cells = [fmt(key(r)) if key(r) is not None else "–" for _, key, fmt in COLUMNS]
        load = "load {:.1f} / {:.1f}".format(*r["load_average"])
        lines.append(f"| {r.get('model', r['label'])} | {r.get('n_x', '?')} | " + " | ".join(cells)
                     + f" | {r['status']} ({load}) |")
    exponents = [growth(fitted, key) for _, key, _ in COLUMNS]
    lines.append("| growth exponent (chain) | | " + " | ".join("–" if e is None else f"n^{e:.2f}" for e in exponents)
                 + " | |")
    return "\n".join(lines)


def file_table(rows: list[dict]) -> str:
    """Bytes per generated file (by its suffix after the model name), one column per model."""
    measured = [r for r in rows if r.get("files")]
    if not measured:
        return ""
    suffix = {}
    for r in measured:
        for fname, size in r["files"].items():
            suffix.setdefault(fname.removeprefix(r["model"] + "_"), {})[r["model"]] = size
    lines = ["| file | " + " | ".join(r["model"] for r in measured) + " |", "|---|" + "---|" * len(measured)]
    for name in sorted(suffix):
        sizes = suffix[name]
        lines.append(f"| {name} | " + " | ".join(f"{sizes[r['model']] / 1e3:.0f} kB" if r["model"] in sizes else "–"
                                                  for r in measured) + " |")
    return "\n".join(lines)


def run(sizes, families, timeout: float, bluerov2: bool, quick: bool, verbose: bool = True) -> dict:
    steps, repeat = (100, 3) if quick else (300, 7)
    rows = []
    for n in sizes:
        rows.append(measure(f"chain{n}", f"chain:{n}", families, timeout, steps, repeat, verbose))
    if bluerov2:
        rows.append(measure("bluerov2", f"{BLUEROV2}:bluerov2", families, timeout, steps, repeat, verbose))
    chain = [r for r in rows if r["spec"].startswith("chain:")]
    exponents = {header: growth(chain, key) for header, key, _ in COLUMNS}
    return {"families": list(families), "timeout_s": timeout, "steps": steps, "repeat": repeat,
            "rows": rows, "growth_exponents": exponents}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="n = 6, 12 only, fewer timed steps")
    parser.add_argument("--sizes", help="comma-separated state counts (even), instead of 6..36 ('' for none)")
    parser.add_argument("--families", default="ckf", help="filter families to generate: ckf (default: the CKF "
                        "alone), a comma list (ekf,ckf), or all")
    parser.add_argument("--bluerov2", action="store_true", help="also measure examples/bluerov2/bluerov2.py")
    parser.add_argument("--timeout", type=float, default=300.0,
                        help="seconds per model: generate, build and timing (default 300)")
    parser.add_argument("--json", metavar="FILE", help="write the results as JSON")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--folder", help=argparse.SUPPRESS)
    parser.add_argument("--progress", help=argparse.SUPPRESS)
    parser.add_argument("--steps", type=int, default=300, help=argparse.SUPPRESS)
    parser.add_argument("--repeat", type=int, default=7, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    families = _families(args.families)
    if args.child:
        signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGTERM))  # unwind: compilers are stopped
        child(args.child, families, Path(args.folder), Path(args.progress), args.steps, args.repeat)
        return 0
    if args.sizes is not None:
        sizes = tuple(int(s) for s in args.sizes.split(",") if s.strip())
    else:
        sizes = QUICK_SIZES if args.quick else SIZES
    print(f"families {','.join(families)}, timeout {args.timeout:g} s per model, fresh compile cache per model",
          flush=True)
    report = run(sizes, families, args.timeout, args.bluerov2, args.quick)
    rows = report["rows"]
    print()
    print(table(rows, [r for r in rows if r["spec"].startswith("chain:")]))
    files = file_table(rows)
    if files:
        print()
        print(files)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))
        print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
