"""Seed 004's experiment: ideal UKF vs GP-UKF on the REMUS 100 helix (Tables 3-4, Figs. 3, 5-8).

    config, prepared = prepare(RemusConfig(), out, say)  # run 1 -> GPs -> generated, compiled GP-UKF predict
    rows = run_one(config, seed)                          # one run: truth, sensors, both filters, metrics
    report(rows, config)                                  # Table 3 and Table 4 beside the paper's (paper.py)

The truth (helix, LOS + PID, sensors) is scenario.py; the GPs are gp_model.py, their generated C gp_codegen.py.

Set-up. Run r (1-based) uses sensor-noise seed r (spec 9); run 1 is also the GPs' training run
(in-sample for the GP-UKF; the other runs differ only in sensor noise, the helix is the same).
Both filters start at the true x0 with P0 below, predict with the logged 5 Hz inputs (held over
0.2 s) and update with every sensor sample; R = the sensors' held noise + LSB^2/12 (both filters).

* Ideal UKF: the true remus100 model (2 RK4 substeps per 0.2 s) with Q = the covariance of the
  true model's one-step residuals on run 1 (x_{k+1} - f(x_k, u_k) with the logged inputs: the
  only "process noise" the truth has is the input held over 0.2 s while the simulator's input
  changes every 0.01 s). "True noise levels" read as: the filter is told the truth's statistics.
* GP-UKF: abyssal.runtime.filters.kalman.GPUKF, Q_k from the GP variance.

Metrics (rows of the campaign table):
* ``rmse_<state>``: RMSE over the run of the filtered (corrected) estimate, angles wrapped (Table 3).
* ``correction``: the mean of the ten measured states' RMSEs (Table 4 "correction"; the paper does
  not define it; this is our reading).
* ``prediction``: horizontal-position RMSE sqrt(mean(e_x^2 + e_y^2)) of the predict-only
  estimate over windows without updates: from the filtered state at t0 = 100, 150, ..., 750 s,
  PREDICTION_HORIZON s of predictions with the logged inputs and no measurements, every
  predicted sample counted (Table 4 "prediction", our definition).
* ``step_ms``: mean wall time of one filter step (timing; not compared across runs).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ...extras import require
from . import paper, scenario

STATE_NAMES = scenario.STATE_NAMES
MEASURED = ("u", "v", "w", "p", "q", "r", "z", "phi", "theta", "psi")
FILTERS = ("UKF", "GP-UKF")
P0_DIAG = (1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6, 1.0, 1.0, 1e-2, 1e-4, 1e-4, 1e-3)
PREDICTION_STARTS = tuple(range(100, 751, 50))  # s
PREDICTION_HORIZON = 10.0                       # s
LOG_DT = 0.2
#: GP regressors per state. The generated predict holds N(N+1)/2 numbers per GP: N = 100 keeps the
#: file under ~2 MB and its compile well under 60 s; N = 200 halves the GP-UKF's position RMSE but
#: writes ~4.7 MB (measured: `abyssal bench`, section remus).
N_TRAIN = 100
N_TRAIN_QUICK = 60
QUICK_DURATION = 300.0

EXTRA_COLUMNS: tuple[str, ...] = ()


@dataclass(frozen=True)
class RemusConfig:
    """What a run needs. The first four fields are the set-up (defaults: `abyssal reproduce remus`); ``prepare``
    fills in the rest from run 1 (paths and numbers, not libraries: the config is pickled to the workers)."""

    duration: float = 800.0             # s per run
    n_train: int = N_TRAIN              # GP regressors per state
    features: str = "paper"             # GP inputs: "paper" or "trig" (gp_model)
    density_at_end: float | None = None  # the 40 % pool's sampling density at the end vs the start (None: gp_model's)
    Q_ukf: tuple | None = None          # (12, 12) nested tuples: the ideal UKF's Q
    predict_library: str | None = None  # the compiled GP-UKF predict
    predict_name: str | None = None
    gp_dt: float | None = None

    def quick(self) -> "RemusConfig":
        """`abyssal reproduce remus --quick`: 300 s runs, 60 regressors per GP."""
        return replace(self, duration=QUICK_DURATION, n_train=N_TRAIN_QUICK)

    @property
    def prepared(self) -> bool:
        return self.predict_library is not None


def _setup(duration: float) -> scenario.HelixSetup:
    return scenario.HelixSetup(duration=duration)


def ukf_process_noise(log: scenario.HelixLog, bundle) -> np.ndarray:
    """Covariance of the true model's one-step residuals over the log (see the module docstring)."""
    X, U = log.x, log.u
    predicted = np.column_stack([bundle.f(X[k], U[k], None, log.dt) for k in range(len(X) - 1)]).T
    residual = X[1:] - predicted
    Q = np.cov(residual.T)
    return 0.5 * (Q + Q.T) + 1e-12 * np.eye(12)


def prepare(config: RemusConfig, out_dir: Path | None = None, progress=None):
    """Run 1, the GPs and the compiled GP-UKF predict (into out_dir, default ./out): (the prepared config,
    details for the figures and the JSON: {"gp", "compiled", "training"})."""
    from abyssal import generated

    from . import gp_codegen, gp_model

    say = progress or (lambda message: None)
    bundle = generated.load("remus100")
    training = scenario.simulate(1, _setup(config.duration), bundle)
    say(f"fitting 12 GPs on run 1 ({config.n_train} regressors each)")
    density = gp_model.DENSITY_AT_END if config.density_at_end is None else config.density_at_end
    gpm = gp_model.fit(training, n_train=config.n_train, features=config.features, density_at_end=density)
    say(f"GPs fitted in {gpm.train_seconds:.1f} s; generating and compiling the GP-UKF predict")
    compiled = gp_codegen.build_predict(gpm, Path(out_dir) if out_dir else Path("out"))
    say(f"GP-UKF predict: {compiled.c_bytes / 1e6:.2f} MB of C, generated in {compiled.generate_seconds:.1f} s, "
        f"compiled in {compiled.compile_seconds:.1f} s (0 when cached)")
    Q = ukf_process_noise(training, bundle)
    config = replace(config, Q_ukf=tuple(map(tuple, Q)), predict_library=str(compiled.library),
                     predict_name=compiled.name, gp_dt=gpm.dt)
    return config, {"gp": gpm, "compiled": compiled, "training": training}


def _filters(config: RemusConfig, bundle):
    from ...filters.kalman import UKF
    from ...filters.kalman.gp_ukf import GPUKF

    return {
        "UKF": lambda x, P: UKF(bundle, x, P, np.array(config.Q_ukf), scenario.SENSOR_R),
        # the paper's GP-UKF, without the innovation gate: its GP variance is overconfident, so with the gate it
        # gates velocity entries, inflates P and the unobserved position runs away (quick run: x RMSE 0.65 m -> 1.8 km)
        "GP-UKF": lambda x, P: GPUKF(bundle, config.predict_library, config.predict_name, x, P, scenario.SENSOR_R,
                                     gp_dt=config.gp_dt, gate_probability=0.0),
    }


def _errors(estimate: np.ndarray, true: np.ndarray) -> np.ndarray:
    e = estimate - true
    e[..., 9:12] = scenario.wrap(e[..., 9:12])
    return e


def run_one(config: RemusConfig, seed: np.random.SeedSequence) -> list[dict]:
    """One Monte-Carlo run (see the module docstring): the table's run i (0-based) is the spec's run i + 1."""
    return filter_run(config, seed)[0]


def filter_run(config: RemusConfig, seed: np.random.SeedSequence):
    """(rows, log, traces) of one run; traces[filter] = (estimates (T, 12), [(k0, predict-only path)])."""
    from abyssal import generated

    from ..campaign import run_index

    if not config.prepared:
        raise ValueError("RemusConfig is not prepared: call prepare(config, out) first (it trains the GPs)")
    run = run_index(seed)                                   # 0-based row key of the campaign table
    sensor_seed = run + 1 + 100_000 * int(seed.entropy)     # spec 9: run r uses seed r (r = 1..M) for --seed 0
    bundle = generated.load("remus100")
    log = scenario.simulate(sensor_seed, _setup(config.duration), bundle)
    T = len(log.t)
    P0 = np.diag(P0_DIAG)
    rows, traces = [], {}
    for name, make in _filters(config, bundle).items():
        flt = make(log.x[0].copy(), P0)
        X, Ps = np.empty((T, 12)), np.empty((T, 12, 12))
        X[0], Ps[0] = flt.x, flt.P
        result = flt.run(log.u[:-1], log.z[1:], LOG_DT)  # step k: predict with u[k - 1], update with z[k]
        X[1:], Ps[1:] = result.x, result.P
        step_ms = float(np.mean(result.step_time)) * 1e3
        err = _errors(X, log.x)
        rmse = np.sqrt(np.mean(err**2, axis=0))
        for i, state in enumerate(STATE_NAMES):
            rows.append({"run": run, "case": "helix", "filter": name, "metric": f"rmse_{state}", "value": float(rmse[i])})
        rows.append({"run": run, "case": "helix", "filter": name, "metric": "correction",
                     "value": float(np.mean([rmse[STATE_NAMES.index(s)] for s in MEASURED]))})
        # predict-only windows
        horizon = int(round(PREDICTION_HORIZON / LOG_DT))
        sq, count = 0.0, 0
        window_paths = []
        for start in PREDICTION_STARTS:
            k0 = int(round(start / LOG_DT))
            if k0 + horizon >= T:
                continue
            pred = make(X[k0].copy(), Ps[k0])
            path = []
            for k in range(k0 + 1, k0 + horizon + 1):
                pred.predict(log.u[k - 1], LOG_DT)
                xk = pred.x
                sq += (xk[6] - log.x[k, 6]) ** 2 + (xk[7] - log.x[k, 7]) ** 2
                count += 1
                path.append(xk)
            window_paths.append((k0, np.array(path)))
        rows.append({"run": run, "case": "helix", "filter": name, "metric": "prediction",
                     "value": float(np.sqrt(sq / count)) if count else float("nan")})
        rows.append({"run": run, "case": "helix", "filter": name, "metric": "step_ms", "value": step_ms})
        traces[name] = (X, window_paths)
    return rows, log, traces


# ------------------------------------------------------------------------------------------ tables
def summary(rows) -> dict:
    """{filter: {metric: (mean, std over runs)}} of the comparable metrics."""
    out: dict = {}
    for name in FILTERS:
        metrics = sorted({r["metric"] for r in rows if r["filter"] == name})
        out[name] = {}
        for metric in metrics:
            values = np.array([r["value"] for r in rows if r["filter"] == name and r["metric"] == metric])
            out[name][metric] = (float(np.mean(values)), float(np.std(values, ddof=1)) if len(values) > 1 else 0.0)
    return out


def report(rows, config: RemusConfig | None = None) -> str:
    """Table 3 and Table 4, ours (mean ± std over the runs) beside the paper's (paper.py)."""
    s = summary(rows)
    runs = len({r["run"] for r in rows})
    lines = [f"REMUS 100 helix (seed 004): ideal UKF vs GP-UKF, {runs} run(s); OURS = mean ± std over runs, "
             "THEIRS = the paper's Table 3/4 (quoted; '-' where illegible in the seed text)", "",
             "Table 3: RMSE per state", f"{'state':<7}{'UKF ours':>22}{'UKF theirs':>20}{'GP-UKF ours':>22}{'GP-UKF theirs':>20}"]
    for state in STATE_NAMES:
        cells = []
        for name, sigma in (("UKF", "sigma-UKF"), ("GP-UKF", "sigma-GP-UKF")):
            mean, std = s[name][f"rmse_{state}"]
            cells.append(f"{mean:>11.4g} ± {std:<8.2g}")
            theirs = paper.TABLE3[name].get(state)
            tsig = paper.TABLE3[sigma].get(state)
            cells.append(f"{(f'{theirs:.4g}' if theirs is not None else '-'):>11} ± {(f'{tsig:.2g}' if tsig is not None else '-'):<6}")
        lines.append(f"{state:<7}" + "".join(f"{c:>21}" for c in cells))
    lines += ["", "Table 4", f"{'':<28}{'ours':>20}{'theirs':>10}"]
    for name in FILTERS:
        for metric in ("correction", "prediction"):
            mean, std = s[name][metric]
            lines.append(f"RMSE-{name} {metric:<16}{mean:>11.4g} ± {std:<7.2g}{paper.TABLE4[(name, metric)]:>10}")
    lines += ["", "correction: mean of the 10 measured states' RMSE; prediction: horizontal-position RMSE (m) of "
              f"predict-only windows of {PREDICTION_HORIZON:g} s from t0 = {PREDICTION_STARTS[0]}, "
              f"{PREDICTION_STARTS[1]}, ..., {PREDICTION_STARTS[-1]} s (our definitions: the paper gives none).",
              "step ms: " + ", ".join(f"{n} {s[n]['step_ms'][0]:.3f}" for n in FILTERS) + " (mean wall time per predict+update)"]
    return "\n".join(lines)


def per_state_json(rows) -> dict:
    s = summary(rows)
    return {name: {"rmse": {st: s[name][f"rmse_{st}"][0] for st in STATE_NAMES},
                   "rmse_std": {st: s[name][f"rmse_{st}"][1] for st in STATE_NAMES},
                   "correction": s[name]["correction"][0], "prediction": s[name]["prediction"][0],
                   "step_ms": s[name]["step_ms"][0]} for name in FILTERS}


# ------------------------------------------------------------------------------------------ figures
def document(rows, config: RemusConfig, prepared: dict) -> dict:
    """The JSON summary's entries: the GPs, their generated predict, per-state RMSE and the paper's tables."""
    gpm, compiled = prepared["gp"], prepared["compiled"]
    return {"duration_s": config.duration, "gp_regressors": gpm.n_train, "gp_train_seconds": gpm.train_seconds,
            "gp_predict_c_bytes": compiled.c_bytes, "gp_predict_compile_seconds": compiled.compile_seconds,
            "per_state_rmse": per_state_json(rows),
            "paper": {"table3": paper.TABLE3, "table4": {f"{k[0]}|{k[1]}": v for k, v in paper.TABLE4.items()}}}


def figures(rows, out: Path, config: RemusConfig, seed: int, prepared: dict) -> list[Path]:
    """Figs. 3, 5-8 of the paper from run 1 (training/evaluation data, surge, x(t), y(t), 3-D path), run again
    here from the campaign's seed for run 1 (the same numbers as the table's)."""
    require("matplotlib", "the experiment figures").use("Agg")
    plt = require("matplotlib.pyplot", "the experiment figures")

    from ..campaign import run_seeds

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    _, log, traces = filter_run(config, run_seeds(seed, 1)[0])
    details = prepared
    written = []

    def save(fig, name):
        path = out / name
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)

    gpm, training = details["gp"], details["training"]
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(training.t, training.z[:, 0], color="0.7", lw=0.8, label="run 1, measured u (evaluation data)")
    sel = np.isin(training.t, gpm.train_times)
    pool = np.isin(training.t, gpm.pool_times)
    ax.plot(training.t[pool], training.z[pool, 0], ".", ms=2, color="C0", label="40 % pool (denser at the start)")
    ax.plot(training.t[sel], training.z[sel, 0], "o", ms=3, color="C3", label=f"GP regressors (N = {gpm.n_train})")
    ax.set(xlabel="t (s)", ylabel="u (m/s)", title="Training vs evaluation data (cf. Fig. 3)")
    ax.legend(fontsize=7)
    save(fig, "remus_fig3_training_data.png")

    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(log.t, log.z[:, 0], color="0.6", lw=0.6, label="measured")
    ax.plot(log.t, log.x[:, 0], "k", lw=1, label="true")
    for name, (X, _) in traces.items():
        ax.plot(log.t, X[:, 0], lw=0.9, label=name)
    ax.set(xlabel="t (s)", ylabel="u (m/s)", title="Surge speed (cf. Fig. 5)")
    ax.legend(fontsize=7)
    save(fig, "remus_fig5_surge.png")

    for i, axis, fig_no in ((6, "x", 6), (7, "y", 7)):
        fig, ax = plt.subplots(figsize=(8, 3.5))
        ax.plot(log.t, log.x[:, i], "k", lw=1, label="true")
        for j, (name, (X, windows)) in enumerate(traces.items()):
            ax.plot(log.t, X[:, i], lw=0.8, color=f"C{j}", label=f"{name} (corrected)")
            for n_w, (k0, path) in enumerate(windows):
                tt = log.t[k0 + 1:k0 + 1 + len(path)]
                ax.plot(tt, path[:, i], lw=2, color=f"C{j}", alpha=0.6,
                        label=f"{name} predict-only windows" if n_w == 0 else None)
        ax.set(xlabel="t (s)", ylabel=f"{axis} (m)", title=f"Position {axis}: corrected and predicted (cf. Fig. {fig_no})")
        ax.legend(fontsize=7)
        save(fig, f"remus_fig{fig_no}_{axis}.png")

    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    ax.plot(log.x[:, 6], log.x[:, 7], log.x[:, 8], "k", lw=1, label="true")
    for name, (X, _) in traces.items():
        ax.plot(X[:, 6], X[:, 7], X[:, 8], lw=0.8, label=name)
    ax.invert_zaxis()
    ax.set(xlabel="x (m)", ylabel="y (m)", zlabel="z (m)", title="Helix: true and estimated (cf. Fig. 8)")
    ax.legend(fontsize=7)
    save(fig, "remus_fig8_path3d.png")
    return written


#: the name `abyssal reproduce` looks up (reproduce.py)
Config = RemusConfig
