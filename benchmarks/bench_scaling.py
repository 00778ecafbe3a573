"""Scaling section of `abyssal bench`: how the generated code and its first build grow with the model.

    python benchmarks/bench_scaling.py                  # chains n = 6, 12, 18, 24, 30, 36 and examples/bluerov2
    python benchmarks/bench_scaling.py --quick          # n = 6, 12 only (a smoke run: no BlueROV2)
    python benchmarks/bench_scaling.py --sizes 6,24 --no-bluerov2 --timeout 600 --json scaling.json

Generate the model, write the filters once: a model folder holds only the model's own functions (f with its RK4
substeps, the variational Jacobian F, G, each sensor's h and H, the SoA kernels and the descriptor); every Kalman
filter's algebra is the C runtime of runtime/c, compiled once per machine. So the generated C should grow with the
model's own work, not with a filter's (the former fused and per-family filter steps grew as ~n^2.2).

The family of models: a chain of n/2 damped pendulums, neighbours coupled by torsion springs (free ends), a torque
input and a torque-noise input per pendulum, the angles measured, RK4 with 2 substeps. Every generated function of
it is dense in the state (the springs couple every pendulum to every other through the RK4 stages), as a real
vehicle's are. Beside it (not fitted), a user's 12-state model: examples/bluerov2/bluerov2.py (8 inputs), loaded as
`abyssal regenerate --model FILE.py:FUNCTION` does (generated.regenerate.load_model_spec).

Each model runs in a child process of its own with a fresh, empty compile cache (ABYSSAL_CACHE_DIR in a temporary
folder), so everything is a first build on this machine, as a user's first run is:

* generate: abyssal.generate into a temporary folder; wall seconds and CPU seconds (the process's own and any
  children's); the bytes of each generated .c file and their total; the model's own op count, the manifest's
  per-function "instructions" of f and F (CasADi's count of the SX operations each evaluation runs);
* build: abyssal.load of that folder (gcc on the model's files, the smoke test): wall seconds, and gcc's CPU
  seconds as the child's resource.getrusage(RUSAGE_CHILDREN) user + system delta around the call (the compilers
  run as the child's children and are waited for, so their whole CPU time lands there, whatever the load);
* the Kalman runtime's own one-time compile, which a cold cache pays once per machine too
  (abyssal.runtime.compiled.kalman.KalmanRuntime.of(bundle), and the extension that makes a filter's plain step one
  C call from Python, abyssal_kalman_python.c): measured the same way, separately;
* per step: EKF.step and CKF.step from Python over a simulated 300-step run (each pass from the same x0, P0 after
  reset), rounds alternating EKF / CKF, the minimum per filter of the process CPU time per step (and of the wall
  time, reported beside it): a load that comes and goes reaches both alike, and a minimum leaves it out.

A child that exceeds --timeout seconds (generate, build and the timed steps together) is killed with its compiler
processes (its own process group) and its row says where it stopped ("did not build in S s"); what it measured
before stays. Every row records the 1/5/15-minute load averages before and after and the CPU model.

Growth exponents: the slope of a least-squares line through log(value) against log(n) over the chain sizes that
finished (``growth``), for the generated C bytes, the model's gcc CPU (the runtime's compile is a constant and is
left out of the fit) and the f + F op count.

Targets (issue 34, deliverable 4):
* the generated C of the chain grows no faster than the model's own f + F op count: C-bytes exponent <= op-count
  exponent + 0.1 (the tolerance: two fits over six points of the same family differ by a few hundredths from the
  constant files alone -- the descriptor and the SoA kernels' fixed parts);
* n = 36: C <= 2 MB, and <= 30 s of gcc CPU for a cold cache (the model's build plus the Kalman runtime's);
* rov4dof's generated folder <= 40 % of its size at commit 708d1a3 (the last commit with the generated filter
  families; the sum of `git ls-tree -r -l 708d1a3 generated/rov4dof` against the files of generated/rov4dof now;
  skipped with a note when git or that commit is not available);
* a 12-state user model (BlueROV2) from generate to loaded <= 15 s of CPU with a cold cache: generate CPU + all
  gcc CPU of the build and of the runtime's compile (the child's own CPU during load is reported beside it); built
  twice, each in its own child with an empty cache, and the smaller taken (gcc's CPU time on this shared machine
  varies by ~20 % from one build to the next).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench import target

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
BLUEROV2 = REPO / "examples" / "bluerov2" / "bluerov2.py"
SIZES, QUICK_SIZES = (6, 12, 18, 24, 30, 36), (6, 12)
DT = 0.1
SUBSTEPS = 2
BASELINE_COMMIT = "708d1a3"  # the last commit with the generated filter families (ekf, sigma_points, fused steps)
GROWTH_TOLERANCE = 0.1
BUILDS = 2  # cold builds of BlueROV2 (each in its own child with its own empty cache)


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


# --------------------------------------------------------------------------- the machine
def machine() -> dict:
    """The CPU model and the 1/5/15-minute load averages now (the machine is shared: every number is read beside
    them)."""
    cpu, info = None, {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            info.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    if "model name" in info:  # a KVM guest may say only "AMD EPYC": the family and model tell Zen 2 from Zen 4
        simd = next((s for s in ("avx512f", "avx2") if s in info.get("flags", "").split()), "no avx2")
        cpu = f"{info['model name']} (family {info.get('cpu family')}, model {info.get('model')}, {simd})"
    import platform

    return {"cpu": cpu or platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "load_average": [round(v, 2) for v in os.getloadavg()] if hasattr(os, "getloadavg") else None}


# --------------------------------------------------------------------------- one model, in a child
def _progress(path: Path, **record) -> None:
    with open(path, "a") as out:
        out.write(json.dumps(record) + "\n")


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _self_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _trajectory(bundle, steps: int, rng):
    """x0, P0, Q, R, U (steps, n_u), Z (steps, n_y) of a simulated run on the compiled model (Q: the noise inputs
    through G, additive on the discrete state)."""
    import numpy as np

    n, m = bundle.n_x, bundle.n_y
    G = bundle.G(np.zeros(n), np.zeros(bundle.n_u), None, DT)
    Q = G @ G.T * 0.05 + 1e-8 * np.eye(n)
    R = np.eye(m) * 1e-4
    t = DT * np.arange(steps)
    phase = np.linspace(0.0, np.pi, bundle.n_u)
    U = 0.5 * np.sin(0.3 * t[:, None] + phase[None, :]) + 0.1 * rng.standard_normal((steps, bundle.n_u))
    x = 0.05 * rng.standard_normal(n)
    x0 = x.copy()
    Z = np.empty((steps, m))
    for k in range(steps):
        x = bundle.f(x, U[k], None, DT) + rng.multivariate_normal(np.zeros(n), Q)
        Z[k] = bundle.h(x) + rng.multivariate_normal(np.zeros(m), R)
    return x0, 0.01 * np.eye(n), Q, R, U, Z


def _pass(flt, U, Z, x0, P0) -> tuple[float, float]:
    """(CPU, wall) seconds per flt.step over one pass of the run (from x0, P0)."""
    flt.reset(x0, P0)
    c0, t0 = time.process_time(), time.perf_counter()
    for k in range(len(U)):
        flt.step(U[k], DT, Z[k])
    return (time.process_time() - c0) / len(U), (time.perf_counter() - t0) / len(U)


def child(spec: str, folder: Path, progress: Path, steps: int, rounds: int) -> None:
    """Generate, load and time one model, appending one JSON line per finished phase to `progress`."""
    import numpy as np

    import abyssal
    from abyssal.generated.regenerate import load_model_spec
    from abyssal.runtime.compiled.kalman import KalmanRuntime, _python_module

    cpu0, kids0, t0 = _self_cpu(), _children_cpu(), time.perf_counter()
    model = pendulum_chain(int(spec.removeprefix("chain:"))) if spec.startswith("chain:") else load_model_spec(spec)[0]
    out = abyssal.generate(model, folder)
    generate_s = time.perf_counter() - t0
    generate_cpu = (_self_cpu() - cpu0) + (_children_cpu() - kids0)
    manifest = json.loads((out / "manifest.json").read_text())
    files = {p.name: p.stat().st_size for p in sorted(out.iterdir()) if p.is_file()}
    c_files = {name: size for name, size in files.items() if name.endswith(".c")}
    instructions = {name.removeprefix(model.name + "_"): spec_.get("instructions")
                    for name, spec_ in manifest["functions"].items()}
    _progress(progress, phase="generated", model=model.name, n_x=model.n_x, n_u=model.n_u, n_p=model.n_p,
              n_y=model.n_y, generate_s=generate_s, generate_cpu_s=generate_cpu, files=files,
              c_bytes=sum(c_files.values()), folder_bytes=sum(files.values()), instructions=instructions,
              ops_f_F=(instructions.get("f") or 0) + (instructions.get("F") or 0))

    cpu0, kids0, t0 = _self_cpu(), _children_cpu(), time.perf_counter()
    bundle = abyssal.load(out)
    _progress(progress, phase="loaded", load_s=time.perf_counter() - t0, gcc_cpu_s=_children_cpu() - kids0,
              load_self_cpu_s=_self_cpu() - cpu0)

    cpu0, kids0, t0 = _self_cpu(), _children_cpu(), time.perf_counter()
    KalmanRuntime.of(bundle)
    _python_module()  # the plain step's one-call extension (abyssal_kalman_python.c), built with the runtime when cold
    _progress(progress, phase="runtime", runtime_s=time.perf_counter() - t0, runtime_gcc_cpu_s=_children_cpu() - kids0,
              runtime_self_cpu_s=_self_cpu() - cpu0)

    x0, P0, Q, R, U, Z = _trajectory(bundle, steps, np.random.default_rng(0))
    filters = {"EKF.step": abyssal.EKF(bundle, x0, P0, Q, R), "CKF.step": abyssal.CKF(bundle, x0, P0, Q, R)}
    cpu = {label: math.inf for label in filters}
    wall = dict(cpu)
    for round_ in range(rounds + 1):  # round 0 warms the caches and is dropped; the order alternates per round
        order = list(filters) if round_ % 2 else list(filters)[::-1]
        for label in order:
            c, w = _pass(filters[label], U, Z, x0, P0)
            if round_:
                cpu[label], wall[label] = min(cpu[label], c), min(wall[label], w)
    _progress(progress, phase="timed", steps=steps, rounds=rounds, step_cpu_us={k: 1e6 * v for k, v in cpu.items()},
              step_wall_us={k: 1e6 * v for k, v in wall.items()})


# --------------------------------------------------------------------------- the parent
def measure(label: str, spec: str, timeout: float, steps: int, rounds: int, verbose: bool) -> dict:
    """Run the child for one model under a deadline; the row of what it measured."""
    with tempfile.TemporaryDirectory(prefix="abyssal-scaling-") as tmp:
        tmp = Path(tmp)
        (tmp / "cache").mkdir()
        progress = tmp / "progress.jsonl"
        env = dict(os.environ, ABYSSAL_CACHE_DIR=str(tmp / "cache"),
                   ABYSSAL_BUILD_TIMEOUT=str(timeout + 60))  # the deadline below governs, not the cache's
        command = [sys.executable, str(Path(__file__).resolve()), "--child", spec, "--folder", str(tmp / "gen"),
                   "--progress", str(progress), "--steps", str(steps), "--rounds", str(rounds)]
        before = machine()
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
        after = machine()
        row = {"label": label, "spec": spec, "wall_s": wall, "cpu": before["cpu"],
               "load_average": {"before": before["load_average"], "after": after["load_average"]}}
        if spec.startswith("chain:"):
            row["n_x"] = int(spec.removeprefix("chain:"))  # known before the child reports it
        phases = [json.loads(line) for line in progress.read_text().splitlines()] if progress.exists() else []
        for record in phases:
            row.update({k: v for k, v in record.items() if k != "phase"})
        done = [r["phase"] for r in phases]
        if status is None:
            where = ("generate" if "generated" not in done else "build" if "loaded" not in done
                     else "compile the runtime" if "runtime" not in done else "time the steps")
            status = f"did not {where} in {timeout:g} s"
        row["status"] = status
        if "runtime_gcc_cpu_s" in row:
            row["cold_gcc_cpu_s"] = row["gcc_cpu_s"] + row["runtime_gcc_cpu_s"]
            # the brief's measure: generate CPU + every gcc CPU second a cold cache pays
            row["cold_cpu_s"] = row["generate_cpu_s"] + row["cold_gcc_cpu_s"]
            row["cold_cpu_with_python_s"] = row["cold_cpu_s"] + row["load_self_cpu_s"] + row["runtime_self_cpu_s"]
        if status.startswith("failed"):
            row["output_tail"] = output[-2000:]
        if verbose:
            tail = f"\n{output[-2000:]}" if status.startswith("failed") else ""
            print(f"  {label}: {status} ({wall:.1f} s, load average {before['load_average']} -> "
                  f"{after['load_average']})" + tail, flush=True)
        return row


def growth(points) -> float | None:
    """Least-squares slope of log(value) against log(n) over (n, value) pairs with a positive value (None with
    fewer than two distinct n): value ~ n^slope."""
    points = [(n, v) for n, v in points if n and v is not None and v > 0]
    if len({n for n, _ in points}) < 2:
        return None
    xs = [math.log(n) for n, _ in points]
    ys = [math.log(v) for _, v in points]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    sxx = sum((x - mx) ** 2 for x in xs)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx


COLUMNS = (  # key, header, value of a row, format; the fitted ones are FITTED
    ("c_bytes", "C", lambda r: r.get("c_bytes"), lambda v: f"{v / 1e3:.0f} kB"),
    ("ops_f_F", "f+F ops", lambda r: r.get("ops_f_F"), lambda v: f"{v:.0f}"),
    ("generate_cpu_s", "generate CPU s", lambda r: r.get("generate_cpu_s"), lambda v: f"{v:.2f}"),
    ("gcc_cpu_s", "gcc CPU s (model)", lambda r: r.get("gcc_cpu_s"), lambda v: f"{v:.2f}"),
    ("runtime_gcc_cpu_s", "gcc CPU s (runtime)", lambda r: r.get("runtime_gcc_cpu_s"), lambda v: f"{v:.2f}"),
    ("load_s", "load wall s", lambda r: r.get("load_s"), lambda v: f"{v:.2f}"),
    ("cold_cpu_s", "cold CPU s", lambda r: r.get("cold_cpu_s"), lambda v: f"{v:.2f}"),
    ("ekf_us", "EKF.step µs", lambda r: r.get("step_cpu_us", {}).get("EKF.step"), lambda v: f"{v:.2f}"),
    ("ckf_us", "CKF.step µs", lambda r: r.get("step_cpu_us", {}).get("CKF.step"), lambda v: f"{v:.2f}"),
)
FITTED = ("c_bytes", "ops_f_F", "gcc_cpu_s", "generate_cpu_s", "ekf_us", "ckf_us")


def exponents(chain: list[dict]) -> dict:
    return {key: growth([(r["n_x"], value(r)) for r in chain]) for key, _, value, _ in COLUMNS if key in FITTED}


def table(rows: list[dict], fitted: dict) -> str:
    lines = ["| model | n | " + " | ".join(h for _, h, _, _ in COLUMNS) + " | status, load before/after |",
             "|---|---|" + "---|" * len(COLUMNS) + "---|"]
    for r in rows:
        cells = [fmt(value(r)) if value(r) is not None else "–" for _, _, value, fmt in COLUMNS]
        load = "{} / {}".format(*(",".join(f"{v:.1f}" for v in r["load_average"][k] or []) for k in ("before", "after")))
        lines.append(f"| {r.get('model', r['label'])} | {r.get('n_x', '?')} | " + " | ".join(cells)
                     + f" | {r['status']} ({load}) |")
    cells = ["–" if fitted.get(key) is None else f"n^{fitted[key]:.2f}" for key, _, _, _ in COLUMNS]
    lines.append("| growth exponent (chain) | | " + " | ".join(cells) + " | |")
    return "\n".join(lines)


def file_table(rows: list[dict]) -> str:
    """Bytes per generated file (by its suffix after the model name), one column per model."""
    measured = list({r["model"]: r for r in rows[::-1] if r.get("files")}.values())[::-1]  # one column per model
    if not measured:
        return ""
    suffix: dict = {}
    for r in measured:
        for fname, size in r["files"].items():
            suffix.setdefault(fname.removeprefix(r["model"] + "_"), {})[r["model"]] = size
    lines = ["| file | " + " | ".join(r["model"] for r in measured) + " |", "|---|" + "---|" * len(measured)]
    for name in sorted(suffix):
        sizes = suffix[name]
        lines.append(f"| {name} | " + " | ".join(f"{sizes[r['model']] / 1e3:.1f} kB" if r["model"] in sizes else "–"
                                                  for r in measured) + " |")
    return "\n".join(lines)


def rov4dof_folder(commit: str = BASELINE_COMMIT) -> dict:
    """Bytes of generated/rov4dof now (its files) and at `commit` (git ls-tree), or a note saying why not."""
    folder = REPO / "generated" / "rov4dof"
    now = sum(p.stat().st_size for p in folder.iterdir() if p.is_file())
    try:
        listing = subprocess.run(["git", "-C", str(REPO), "ls-tree", "-r", "-l", commit, "generated/rov4dof"],
                                 capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return {"now_bytes": now, "note": f"skipped: git is not available ({exc})"}
    if listing.returncode != 0 or not listing.stdout.strip():
        return {"now_bytes": now, "note": f"skipped: commit {commit} is not in this checkout "
                                          f"({listing.stderr.strip() or 'no generated/rov4dof there'})"}
    before = sum(int(line.split()[3]) for line in listing.stdout.splitlines() if line.split()[3].isdigit())
    return {"now_bytes": now, "commit": commit, "commit_bytes": before, "ratio": now / before}


def run(quick: bool = False, verbose: bool = True, sizes=None, bluerov2: bool | None = None,
        timeout: float = 300.0) -> dict:
    """The section: every chain size (QUICK_SIZES when quick) and BlueROV2 (unless bluerov2=False), each in its
    own child with a fresh compile cache; {"results", "targets"}."""
    sizes = (QUICK_SIZES if quick else SIZES) if sizes is None else tuple(sizes)
    bluerov2 = not quick if bluerov2 is None else bluerov2  # ~15 s of CPU: not a smoke run's
    steps, rounds = (100, 3) if quick else (300, 9)
    say = print if verbose else (lambda *a, **k: None)
    say(f"scaling: fresh compile cache per model, timeout {timeout:g} s per model, {machine()}", flush=True)
    rows = [measure(f"chain{n}", f"chain:{n}", timeout, steps, rounds, verbose) for n in sizes]
    if bluerov2:  # twice: the target is the smaller (gcc's CPU time on a shared machine varies by ~20 % run to run)
        rows += [measure("bluerov2", f"{BLUEROV2}:bluerov2", timeout, steps, rounds, verbose) for _ in range(BUILDS)]
    chain = [r for r in rows if r["spec"].startswith("chain:")]
    fitted = exponents(chain)
    folder = rov4dof_folder()
    results = {"machine": machine(), "timeout_s": timeout, "steps": steps, "rounds": rounds, "rows": rows,
               "growth_exponents": fitted, "rov4dof_folder": folder}
    say(table(rows, fitted))
    say(file_table(rows))
    if "ratio" in folder:
        say(f"rov4dof folder: {folder['now_bytes']} B now, {folder['commit_bytes']} B at {folder['commit']}: "
            f"{100 * folder['ratio']:.1f} %")
    else:
        say(f"rov4dof folder: {folder['note']}")

    targets = []
    c_exp, ops_exp = fitted.get("c_bytes"), fitted.get("ops_f_F")
    if c_exp is not None and ops_exp is not None:
        span = f"n = {min(r['n_x'] for r in chain)}..{max(r['n_x'] for r in chain)}"
        targets.append(target(f"chain ({span}): growth exponent of the generated C <= f+F op-count exponent "
                              f"(n^{ops_exp:.2f}) + {GROWTH_TOLERANCE}", c_exp, ops_exp + GROWTH_TOLERANCE, ""))
    big = next((r for r in chain if r.get("n_x") == 36), None)
    if big is not None:
        targets.append(target("chain36: generated C", big.get("c_bytes", math.inf) / 1e6, 2.0, "MB"))
        targets.append(target("chain36: gcc CPU of a cold cache (model + Kalman runtime)",
                              big.get("cold_gcc_cpu_s", math.inf), 30.0, "s"))
    if "ratio" in folder:
        targets.append(target(f"rov4dof generated folder / its size at {folder['commit']}", 100 * folder["ratio"],
                              40.0, "%"))
    blue = [r.get("cold_cpu_s", math.inf) for r in rows if r["label"] == "bluerov2"]
    if blue:
        targets.append(target(f"BlueROV2 (12 states), generate to loaded with a cold cache: generate + gcc CPU "
                              f"(model + runtime), the smaller of {len(blue)}", min(blue), 15.0, "s CPU"))
    return {"results": results, "targets": targets}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="n = 6, 12 only, fewer timed steps")
    parser.add_argument("--sizes", help="comma-separated state counts (even), instead of 6..36 ('' for none)")
    parser.add_argument("--bluerov2", dest="bluerov2", action="store_true", default=None,
                        help="measure examples/bluerov2/bluerov2.py (the default unless --quick)")
    parser.add_argument("--no-bluerov2", dest="bluerov2", action="store_false",
                        help="leave out examples/bluerov2/bluerov2.py")
    parser.add_argument("--timeout", type=float, default=300.0,
                        help="seconds per model: generate, build and timing (default 300)")
    parser.add_argument("--json", metavar="FILE", help="write the results as JSON")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--folder", help=argparse.SUPPRESS)
    parser.add_argument("--progress", help=argparse.SUPPRESS)
    parser.add_argument("--steps", type=int, default=300, help=argparse.SUPPRESS)
    parser.add_argument("--rounds", type=int, default=9, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGTERM))  # unwind: compilers are stopped
        child(args.child, Path(args.folder), Path(args.progress), args.steps, args.rounds)
        return 0
    sizes = None if args.sizes is None else tuple(int(s) for s in args.sizes.split(",") if s.strip())
    report = run(quick=args.quick, verbose=True, sizes=sizes, bluerov2=args.bluerov2, timeout=args.timeout)
    print("\ntargets:")
    for t in report["targets"]:
        print(f"  {'met ' if t['met'] else 'MISS'}  {t['name']}: {t['value']:.4g} {t['unit']} "
              f"(target {t['direction']} {t['limit']:.4g})")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))
        print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
