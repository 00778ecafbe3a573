"""Seed 004's experiment: the REMUS 100 helix, UKF readings vs GP-UKF per GP size and training draw (Tables 3-4).

    config, prepared = prepare(RemusConfig(), out, say)  # run 1 -> GP training sets, generated predicts, UKF models
    rows = run_one(config, seed)                          # one run: truth, sensors, every filter, metrics
    report(rows, config)                                  # the case tables beside the paper's (paper.py)

The truth (helix, LOS + PID, sensors) is scenario.py; the GPs are gp_model.py, their generated C gp_codegen.py.

Set-up. Run r (0-based in the table) uses sensor-noise seed r + 1 (spec 9); the GPs are trained on the spec's
run 1 (the table's run 0: in-sample for the GP-UKF; the other runs differ only in sensor noise, the helix
is the same). Every filter starts at the true x0 with P0 below, predicts with the logged 5 Hz inputs (held
over 0.2 s) and updates with every sensor sample; R = the sensors' held noise + LSB^2/12 (every filter).
No filter has an innovation gate (the paper's have none).

Cases: the choices the paper leaves open.
* The controllers' feedback (spec D7): "true" (the default, as the paper's Simulink model runs: its measured-depth
  port is unconnected, so the controllers see the true state) and "measured" (the paper's text: the controllers
  use the corrupted measurements, the sensors' noisy, quantised values of nu, z and the angles). Each UKF reading
  runs on the truths of both, with Q from that feedback's run 1 ("UKF (oracle, measured feedback)": the paper-like
  reading beside the oracle); the GP-UKFs run on the true-feedback truths they were trained on.
* The UKF's reading (case "true model"). "UKF (oracle)": the true remus100 model (2 RK4 substeps per 0.2 s)
  with Q = the covariance of its one-step residuals on run 1 (x_{k+1} - f(x_k, u_k) with the logged inputs:
  the truth's only "process noise" is the input held over 0.2 s while the simulator's changes every 0.01 s).
  It knows the truth's statistics: an ORACLE, not the paper's UKF. "UKF (Euler, 1 step)" and "UKF (RK4,
  1 step)": the same recipe with one explicit Euler or RK4 step per 0.2 s (Q from that model's own
  residuals): paper-like readings of an "ideal UKF" run at the 5 Hz data rate.
* The GP-UKF (abyssal.runtime.filters.kalman.GPUKF, Q_k from the GP variance) per GP size N (regressors per
  GP; the paper's 40 % of 800 s at 5 Hz is 1600) and training draw (case "draw <seed>", gp_model), with
  increment targets ("GP-UKF N=...") and, at ``full_state_sizes``, next-state targets as Deisenroth's
  gpukf.m ("GP-UKF (state) N=..."). Run r uses draw draws[r mod len(draws)] (every draw gets every
  len(draws)-th run: the sensor noise is a small part of the GP-UKF's error, the draw a large one).

Metrics (rows of the campaign table; errors of the filtered estimate at steps 1..T-1, angles wrapped):
* ``rmse_<state>``: RMSE over the run (Table 3).
* ``correction``: the mean of the ten measured states' RMSEs (our reading of Table 4 "correction").
* ``prediction``: horizontal-position RMSE sqrt(mean(e_x^2 + e_y^2)) of the filtered estimate: x and y
  have no sensor, so this is the filter's prediction of the unmeasured position (our reading of Table 4
  "prediction").
* ``predict_10s``: OURS, not the paper's: horizontal-position RMSE over predict-only windows of
  PREDICTION_HORIZON s from the filtered state at t0 = 100, 150, ..., 750 s (logged inputs, no updates);
  ``predict_10s_diverged``: the windows left out because the predict failed (the one-Euler-step model is
  unstable open loop at 0.2 s: its covariance overflows within seconds).
* ``anees``, ``anees_measured``, ``anees_xy``: mean over the run of the NEES of all 12 states, of the 10
  measured ones and of (x, y) (a consistent filter: 12, 10 and 2) from the filter's own P. x and y are never
  measured, so their P is P0 (1 m^2 each, while the start is exact) plus what the predicts add: an ANEES of
  (x, y) far below 2 is P0 speaking, one far above 2 a filter whose predicts add too little.
* ``step_ms``: mean wall time of one filter step (a timing: printed apart, never compared across runs).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from . import paper, scenario
from ..tables import OverRuns, over_runs
from .gp_model import RESTARTS

STATE_NAMES = scenario.STATE_NAMES
MEASURED = ("u", "v", "w", "p", "q", "r", "z", "phi", "theta", "psi")
P0_DIAG = (1e-4, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6, 1.0, 1.0, 1e-2, 1e-4, 1e-4, 1e-3)
PREDICTION_STARTS = tuple(range(100, 751, 50))  # s
PREDICTION_HORIZON = 10.0                       # s
LOG_DT = 0.2
TRUE_MODEL = "true model"
#: UKF readings: key -> (filter name, scheme, substeps per 0.2 s); "oracle" is the committed remus100
READINGS = {"oracle": ("UKF (oracle)", "rk4", 2), "rk4": ("UKF (RK4, 1 step)", "rk4", 1),
            "euler": ("UKF (Euler, 1 step)", "euler", 1)}
QUICK_DURATION = 200.0

EXTRA_COLUMNS: tuple[str, ...] = ()


@dataclass(frozen=True)
class UKFSetup:
    """One UKF reading on one feedback's truths, prepared: its model (a bundle name or generated folder) and Q."""

    name: str
    model: str
    Q: tuple          # (12, 12) nested tuples
    feedback: str = "true"


@dataclass(frozen=True)
class GPSetup:
    """One GP-UKF case, prepared: its training set (gp_model.TrainingSet file) and compiled predict."""

    targets: str
    n_train: int
    draw: int
    data: str          # .npz path
    digest: str        # its sha256 (the workers' cache key)
    library: str
    function: str
    lml: tuple = ()        # per GP (12): the chosen hyperparameters' log marginal likelihood on the fitted points
    start_lml: tuple = ()  # per GP: each start's optimum (gp_model.START_NAMES, then the random starts)

    @property
    def name(self) -> str:
        return gp_filter_name(self.targets, self.n_train)


def gp_filter_name(targets: str, n_train: int) -> str:
    return f"GP-UKF N={n_train}" if targets == "increments" else f"GP-UKF (state) N={n_train}"


def draw_case(draw: int) -> str:
    return f"draw {draw}"


#: the controllers' feedback (spec D7): the Simulink model's (the default) and the paper's text
FEEDBACKS = ("true", "measured")


def ukf_name(reading: str, feedback: str = "true") -> str:
    """"UKF (oracle)" on the true-feedback truths; "UKF (oracle, measured feedback)" on the measured-feedback ones."""
    name = READINGS[reading][0]
    return name if feedback == "true" else f"{name[:-1]}, measured feedback)"


def ukf_case(feedback: str) -> str:
    return TRUE_MODEL if feedback == "true" else f"{TRUE_MODEL}, measured feedback"


@dataclass(frozen=True)
class RemusConfig:
    """What a run needs. The fields up to ``readings`` are the set-up (defaults: `abyssal reproduce remus`);
    ``prepare`` fills in the rest from run 1 (paths and numbers, not libraries: the config is pickled to the
    workers)."""

    duration: float = 800.0                    # s per run
    sizes: tuple[int, ...] = (100, 400, 1600)  # GP regressors per state (1600: the paper's 40 %)
    draws: tuple[int, ...] = (4, 5, 6)         # training draws (gp_model.draw_order seeds)
    full_state_sizes: tuple[int, ...] = (100, 400)  # sizes also run with next-state targets (gpukf.m)
    hyper_max: int = 400                       # hyperparameters from at most this many regressors (gp_model)
    readings: tuple[str, ...] = tuple(READINGS)  # UKF readings (READINGS)
    feedbacks: tuple[str, ...] = FEEDBACKS     # the truths' controller feedback the UKF readings run on (D7)
    restarts: int = RESTARTS                   # random starts of every GP hyperparameter fit (gp_model.fit_gp)
    features: str = "paper"                    # GP inputs: "paper" or "trig" (gp_model)
    density_at_end: float | None = None        # the pool's sampling density at the end vs the start (None: gp_model's)
    ukfs: tuple = ()                           # UKFSetup per reading (prepare)
    gps: tuple = ()                            # GPSetup per target x size x draw (prepare)

    def quick(self) -> "RemusConfig":
        """`abyssal reproduce remus --quick` (3 runs): 200 s runs; GP-UKFs with increment targets of 40 and 160
        regressors from 2 training draws, hyperparameters from 40 points (no next-state targets); the three UKF
        readings. A smoke version, not the paper's set-up (its GPs hold 1600 points of 800 s)."""
        return replace(self, duration=QUICK_DURATION, sizes=(40, 160), draws=(4, 5), full_state_sizes=(),
                       hyper_max=40)

    @property
    def prepared(self) -> bool:
        return bool(self.ukfs)

    def draw_of_run(self, run: int) -> int:
        return self.draws[run % len(self.draws)]


def _setup(duration: float, feedback: str = "true") -> scenario.HelixSetup:
    return scenario.HelixSetup(duration=duration, feedback=feedback)


# ------------------------------------------------------------------------------------------ preparation
def process_noise(log: scenario.HelixLog, bundle) -> np.ndarray:
    """Covariance of `bundle`'s one-step residuals over the log (see the module docstring)."""
    X, U = log.x, log.u
    predicted = np.column_stack([bundle.f(X[k], U[k], None, log.dt) for k in range(len(X) - 1)]).T
    residual = X[1:] - predicted
    Q = np.cov(residual.T)
    return 0.5 * (Q + Q.T) + 1e-12 * np.eye(12)


def reading_model(reading: str, out: Path) -> str:
    """The model of a UKF reading: "remus100" (the oracle's), or remus100 with another integrator generated into
    <out>/generated/ (UKF functions only; compiled once, cached by source hash)."""
    _, scheme, substeps = READINGS[reading]
    if (scheme, substeps) == ("rk4", 2):
        return "remus100"
    from abyssal.generated.regenerate import generate
    from abyssal.symbolic.models.remus100 import remus100

    model = replace(remus100(name=f"remus100_{scheme}{substeps}"), discretisation=scheme, substeps=substeps)
    return str(generate(model, out / "generated"))


def prepare(config: RemusConfig, out_dir: Path | None = None, progress=None):
    """Run 1, the UKF readings' models and Q, the GP training sets and their compiled predicts (into out_dir,
    default ./out): (the prepared config, details for the figures and the JSON)."""
    from abyssal import generated

    from . import gp_codegen, gp_model

    say = progress or (lambda message: None)
    out = Path(out_dir) if out_dir else Path("out")
    bundle = generated.load("remus100")
    training = scenario.simulate(1, _setup(config.duration), bundle)
    runs1 = {f: training if f == "true" else scenario.simulate(1, _setup(config.duration, f), bundle)
             for f in config.feedbacks}
    ukfs = []
    for reading in config.readings:
        model = reading_model(reading, out)
        for feedback, log in runs1.items():
            Q = process_noise(log, bundle if model == "remus100" else generated.load(model))
            ukfs.append(UKFSetup(ukf_name(reading, feedback), model, tuple(map(tuple, Q)), feedback))
    pool = gp_model.pool_size(config.duration, LOG_DT)
    gps, sets, compiled = [], {}, {}
    density = gp_model.DENSITY_AT_END if config.density_at_end is None else config.density_at_end
    for targets, sizes in (("increments", config.sizes), ("state", config.full_state_sizes)):
        if not sizes:
            continue
        sizes = tuple(sorted({min(int(n), pool) for n in sizes}))
        for draw in config.draws:
            found = _cached_sets(out, training, targets, draw, sizes, config, density)
            if found is None:
                found = gp_model.fit_draw(training, draw, sizes, targets=targets, features=config.features,
                                          hyper_max=config.hyper_max, density_at_end=density,
                                          restarts=config.restarts, say=say)
                _save_sets(out, training, targets, draw, sizes, config, density, found)
            else:
                say(f"draw {draw}, {targets}: training sets read from {_gp_folder(out)} (fitted earlier)")
            for n, training_set in found.items():
                sets[(targets, n, draw)] = training_set
        for n in sizes:
            c = gp_codegen.build_predict(n, out, features=config.features, targets=targets)
            compiled[(targets, n)] = c
            say(f"GP-UKF predict ({targets}, N = {n}): {c.c_bytes / 1e3:.0f} kB of C, generated in "
                f"{c.generate_seconds:.1f} s, compiled in {c.compile_seconds:.1f} s (0 when cached)")
        for n in sizes:
            for draw in config.draws:
                path = _set_path(out, targets, draw, n)
                c = compiled[(targets, n)]
                fitted = sets[(targets, n, draw)]
                gps.append(GPSetup(targets, n, draw, str(path), gp_model.file_digest(path), str(c.library), c.name,
                                   tuple(map(float, fitted.lml)), tuple(map(tuple, fitted.start_lml.tolist()))))
    config = replace(config, ukfs=tuple(ukfs), gps=tuple(gps))
    return config, {"training": training, "sets": sets, "compiled": compiled}


def _gp_folder(out: Path) -> Path:
    return Path(out) / "remus_gp"


def _set_path(out: Path, targets: str, draw: int, n: int) -> Path:
    return _gp_folder(out) / f"{targets}_draw{draw}_n{n}.npz"


def _fit_key(training: scenario.HelixLog, targets, draw, sizes, config: RemusConfig, density) -> str:
    """What a draw's training sets depend on: run 1's data and every setting of gp_model.fit_draw."""
    import hashlib

    import sklearn

    from . import gp_model

    h = hashlib.sha256()
    for array in (training.x, training.u, training.z):
        h.update(np.ascontiguousarray(array).tobytes())
    h.update(repr((targets, draw, sizes, config.features, config.hyper_max, density, gp_model.POOL_FRACTION,
                   gp_model.LENGTH_SCALE, gp_model.LENGTH_BOUNDS, gp_model.SIGNAL, gp_model.SIGNAL_BOUNDS, gp_model.NOISE,
                   gp_model.NOISE_BOUNDS, config.restarts, gp_model.START_NAMES, sklearn.__version__)).encode())
    return h.hexdigest()


def _cached_sets(out, training, targets, draw, sizes, config, density):
    import json

    from .gp_model import TrainingSet

    key_path = _gp_folder(out) / f"{targets}_draw{draw}.json"
    if not key_path.exists() or json.loads(key_path.read_text()).get("key") != _fit_key(training, targets, draw, sizes,
                                                                                          config, density):
        return None
    if not all(_set_path(out, targets, draw, n).exists() for n in sizes):
        return None
    return {n: TrainingSet.load(_set_path(out, targets, draw, n)) for n in sizes}


def _save_sets(out, training, targets, draw, sizes, config, density, sets) -> None:
    import json

    for n, training_set in sets.items():
        training_set.save(_set_path(out, targets, draw, n))
    (_gp_folder(out) / f"{targets}_draw{draw}.json").write_text(
        json.dumps({"key": _fit_key(training, targets, draw, sizes, config, density)}))


# ------------------------------------------------------------------------------------------ one run
def _filters(config: RemusConfig, run: int):
    """{filter name: (case, feedback of the truths it runs on, factory (x0, P0) -> filter)} of one run."""
    from abyssal import generated

    from ...filters.kalman import UKF
    from ...filters.kalman.gp_ukf import GPUKF
    from . import gp_model

    bundle = generated.load("remus100")
    out = {}
    for u in config.ukfs:
        model = bundle if u.model == "remus100" else generated.load(u.model)
        out[u.name] = (ukf_case(u.feedback), u.feedback, lambda x, P, model=model, Q=np.array(u.Q):
                       UKF(model, x, P, Q, scenario.SENSOR_R, gate_probability=0.0))
    draw = config.draw_of_run(run)
    for g in config.gps:
        if g.draw != draw:
            continue
        _, data = gp_model.runtime_data(g.data, g.digest)
        out[g.name] = (draw_case(draw), "true", lambda x, P, g=g, data=data:
                       GPUKF(bundle, g.library, g.function, x, P, scenario.SENSOR_R, gp_dt=LOG_DT, gp_data=data,
                             gate_probability=0.0))
    return out


def _errors(estimate: np.ndarray, true: np.ndarray) -> np.ndarray:
    e = estimate - true
    e[..., 9:12] = scenario.wrap(e[..., 9:12])
    return e


def run_one(config: RemusConfig, seed: np.random.SeedSequence) -> list[dict]:
    """One Monte-Carlo run (see the module docstring): the table's run i (0-based) is the spec's run i + 1."""
    return filter_run(config, seed)[0]


def filter_run(config: RemusConfig, seed: np.random.SeedSequence):
    """(rows, log, traces) of one run; traces[filter] = (estimates (T, 12), covariances (T, 12, 12)) of the filters
    on the true-feedback truth ``log`` (the measured-feedback UKFs run on their own truth: rows only)."""
    from abyssal import generated

    from ...numerics import nees
    from ..campaign import run_index

    if not config.prepared:
        raise ValueError("RemusConfig is not prepared: call prepare(config, out) first (it trains the GPs)")
    run = run_index(seed)                                   # 0-based row key of the campaign table
    sensor_seed = run + 1 + 100_000 * int(seed.entropy)     # spec 9: run r uses seed r (r = 1..M) for --seed 0
    filters = _filters(config, run)
    logs = {f: scenario.simulate(sensor_seed, _setup(config.duration, f), generated.load("remus100"))
            for f in dict.fromkeys(feedback for _, feedback, _ in filters.values())}
    T = len(next(iter(logs.values())).t)
    P0 = np.diag(P0_DIAG)
    horizon = int(round(PREDICTION_HORIZON / LOG_DT))
    measured = [STATE_NAMES.index(s) for s in MEASURED]
    rows, traces = [], {}
    for name, (case, feedback, make) in filters.items():
        log = logs[feedback]
        flt = make(log.x[0].copy(), P0)
        X, Ps = np.empty((T, 12)), np.empty((T, 12, 12))
        X[0], Ps[0] = flt.x, flt.P
        result = flt.run(log.u[:-1], log.z[1:], LOG_DT)  # step k: predict with u[k - 1], update with z[k]
        X[1:], Ps[1:] = result.x, result.P
        err = _errors(X[1:], log.x[1:])
        rmse = np.sqrt(np.mean(err**2, axis=0))
        values = {f"rmse_{s}": rmse[i] for i, s in enumerate(STATE_NAMES)}
        values["correction"] = np.mean(rmse[measured])
        values["prediction"] = np.sqrt(np.mean(err[:, 6] ** 2 + err[:, 7] ** 2))
        values["anees"] = np.mean(nees(err, Ps[1:]))
        values["anees_measured"] = np.mean(nees(err[:, measured], Ps[1:][:, measured][:, :, measured]))
        values["anees_xy"] = np.mean(nees(err[:, 6:8], Ps[1:, 6:8, 6:8]))
        sq, diverged = [], 0
        for start in PREDICTION_STARTS:                      # predict-only windows (ours)
            k0 = int(round(start / LOG_DT))
            if k0 + horizon >= T:
                continue
            pred, window = make(X[k0].copy(), Ps[k0]), []
            try:
                for k in range(k0 + 1, k0 + horizon + 1):
                    pred.predict(log.u[k - 1], LOG_DT)
                    window.append((pred.x[6] - log.x[k, 6]) ** 2 + (pred.x[7] - log.x[k, 7]) ** 2)
                sq += window
            except ValueError:                               # the model's open-loop prediction blew up
                diverged += 1
        values["predict_10s"] = math.sqrt(np.mean(sq)) if sq else math.nan
        values["predict_10s_diverged"] = diverged
        values["step_ms"] = float(np.mean(result.step_time)) * 1e3
        rows += [{"run": run, "case": case, "filter": name, "metric": m, "value": float(v)} for m, v in values.items()]
        if feedback == "true":
            traces[name] = (X, Ps)
    return rows, logs.get("true", log), traces


# ------------------------------------------------------------------------------------------ statistics
def _values(rows, name: str, metric: str, case: str | None = None) -> list[float]:
    return [r["value"] for r in rows if r["filter"] == name and r["metric"] == metric and (case is None or r["case"] == case)]


def filter_names(rows) -> list[str]:
    """UKF readings first (in READINGS order, the true-feedback truths, then the measured ones), then the GP-UKFs by
    targets and size."""
    names = sorted({r["filter"] for r in rows})
    ukfs = [ukf_name(k, f) for f in FEEDBACKS for k in READINGS if ukf_name(k, f) in names]
    gps = sorted((n for n in names if n.startswith("GP-UKF")), key=lambda n: ("(state)" in n, int(n.split("N=")[1])))
    return ukfs + gps + [n for n in names if n not in ukfs and n not in gps]


def is_gp(name: str) -> bool:
    return name.startswith("GP-UKF")


def draws_of(rows, name: str) -> list[str]:
    return sorted({r["case"] for r in rows if r["filter"] == name}, key=lambda c: int(c.split()[-1]))


def over_draws(per_draw: dict[str, OverRuns]) -> OverRuns:
    """Between training draws: over_runs of the per-draw means (per_draw: {draw: over_runs of its runs})."""
    return over_runs([s.mean for s in per_draw.values()])


def cell(s: OverRuns) -> str:
    """"mean ± sd" (3 and 2 significant digits), the mean alone for one value or when a run diverged (inf), "-" for
    none."""
    if s.n == 0:
        return "-"
    if not math.isfinite(s.mean):
        return f"{s.mean}"
    if s.n < 2 or not math.isfinite(s.sd):
        return f"{s.mean:.3g}"
    return f"{s.mean:.3g} ± {s.sd:.2g}"


def per_draw(rows, name: str, metric: str) -> dict[str, OverRuns]:
    return {case: over_runs(_values(rows, name, metric, case)) for case in draws_of(rows, name)}


def statistic(rows, name: str, metric: str) -> OverRuns:
    """A UKF reading: over its runs. A GP-UKF: between its training draws (of the per-draw means over runs)."""
    if is_gp(name):
        return over_draws(per_draw(rows, name, metric))
    return over_runs(_values(rows, name, metric))


def ratio_to_paper(rows, name: str) -> dict[str, float]:
    """Our mean RMSE over the paper's (Table 3, UKF row) per state."""
    return {s: statistic(rows, name, f"rmse_{s}").mean / paper.TABLE3["UKF"][s] for s in STATE_NAMES}


def closest_reading(rows) -> tuple[str, dict]:
    """(the UKF reading nearest the paper's UKF row, {reading: (median |log10 ratio|, max |log10 ratio|, states
    within a factor 2)}): distance = median over the 12 states of |log10(ours / paper)|."""
    scores = {}
    for name in filter_names(rows):
        if is_gp(name):
            continue
        logs = np.abs(np.log10(np.array(list(ratio_to_paper(rows, name).values()))))
        scores[name] = (float(np.median(logs)), float(np.max(logs)), int(np.sum(logs <= math.log10(2))))
    return min(scores, key=lambda n: scores[n][0]), scores


def paper_sigma_check() -> list[str]:
    """The paper's sigma of x and y against sqrt(20) x its mean (paper.py)."""
    bound = math.sqrt(paper.RUNS)
    lines = []
    for s in ("x", "y"):
        mean, sigma = paper.TABLE3["UKF"][s], paper.TABLE3["sigma-UKF"][s]
        verdict = "exceeds" if sigma > bound * mean else "is within"
        lines.append(f"  {s}: sigma {sigma:g} m {verdict} sqrt({paper.RUNS}) x mean = {bound * mean:.3g} m "
                     f"(ratio sigma/mean {sigma / mean:.2f} vs {bound:.2f})")
    return lines


# ------------------------------------------------------------------------------------------ tables
def _conditions(rows, config: RemusConfig | None) -> str:
    runs = len({r["run"] for r in rows})
    if config is None:
        return f"{runs} run(s)"
    return (f"{runs} run(s) x {config.duration:g} s at 5 Hz; GPs trained on run 0 (spec run 1), {len(config.draws)} "
            f"training draw(s) {', '.join(map(str, config.draws))} (run r uses draw r mod {len(config.draws)}), "
            f"hyperparameters from <= {config.hyper_max} regressors")


def report(rows, config: RemusConfig | None = None) -> str:
    """The case tables (module docstring) beside the paper's numbers (paper.py)."""
    names = filter_names(rows)
    ukfs = [n for n in names if not is_gp(n)]
    gps = [n for n in names if is_gp(n)]
    L = [f"REMUS 100 helix (seed 004): {_conditions(rows, config)}.",
         "OURS: a UKF reading = mean ± sample sd (ddof 1) over its runs; a GP-UKF = mean ± sample sd (ddof 1) BETWEEN "
         "training draws of the per-draw means over runs. THEIRS: the paper's tables, quoted ('-' where illegible).", ""]

    w = max([24] + [len(n) + 2 for n in names])  # the width of a column or row named by a filter
    L += ["Table 3, UKF readings: RMSE per state (UKF (oracle) knows the true model and the truth's residual "
          "covariance: an ORACLE; 'measured feedback': the controllers see the sensors, spec D7, the paper-like "
          "reading)", f"{'state':<6}{'unit':<6}{'paper UKF':>11}" + "".join(f"{n:>{w}}" for n in ukfs)]
    for s in STATE_NAMES:
        L.append(f"{s:<6}{paper.UNITS[s]:<6}{paper.TABLE3['UKF'][s]:>11.4g}"
                 + "".join(f"{cell(statistic(rows, n, f'rmse_{s}')):>{w}}" for n in ukfs))
    if ukfs:
        best, scores = closest_reading(rows)
        L += ["distance to the paper's UKF row: median |log10(ours/paper)| over the 12 states [max]; states within "
              "a factor 2"]
        for n in ukfs:
            med, worst, within = scores[n]
            ratio = ratio_to_paper(rows, n)
            L.append(f"  {n:<{w}} {med:.2f} [{worst:.2f}]  {within:>2}/12   x: {ratio['x']:.3g}x the paper's, "
                     f"y: {ratio['y']:.3g}x")
        L.append(f"  closest: {best}" + ("" if scores[best][2] == 12 else
                                         "; no reading is within a factor 2 of the paper in every state"))
    if gps:
        L += ["", "Table 3, GP-UKF: RMSE per state (mean ± sd between training draws)",
              f"{'state':<6}{'unit':<6}{'paper':>9}" + "".join(f"{n:>22}" for n in gps)]
        for s in STATE_NAMES:
            theirs = paper.TABLE3["GP-UKF"].get(s)
            L.append(f"{s:<6}{paper.UNITS[s]:<6}{(f'{theirs:.4g}' if theirs is not None else '-'):>9}"
                     + "".join(f"{cell(statistic(rows, n, f'rmse_{s}')):>22}" for n in gps))

    duration = config.duration if config else max(PREDICTION_STARTS) + PREDICTION_HORIZON + LOG_DT
    windows = sum(1 for t in PREDICTION_STARTS if t + PREDICTION_HORIZON < duration)
    L += ["", "Table 4: correction (mean of the 10 measured states' RMSEs, mixed units) and prediction (horizontal "
          "position RMSE of the filtered estimate, m: x, y are never measured); predict_10s (m) is OURS "
          "(predict-only windows; 'diverged': windows whose predict failed, of all), the paper has no such number",
          f"{'filter':<{w}}{'correction':>20}{'paper':>8}{'prediction (m)':>20}{'paper (m)':>10}{'predict_10s (m)':>20}"
          f"{'diverged':>10}"]
    for n in names:
        kind = "GP-UKF" if is_gp(n) else "UKF"
        diverged = f"{sum(_values(rows, n, 'predict_10s_diverged')):g}/{windows * len(_values(rows, n, 'prediction'))}"
        L.append(f"{n:<{w}}{cell(statistic(rows, n, 'correction')):>20}{paper.TABLE4[(kind, 'correction')]:>8}"
                 f"{cell(statistic(rows, n, 'prediction')):>20}{paper.TABLE4[(kind, 'prediction')]:>10}"
                 f"{cell(statistic(rows, n, 'predict_10s')):>20}{diverged:>10}")

    if gps:
        cases = sorted({c for n in gps for c in draws_of(rows, n)}, key=lambda c: int(c.split()[-1]))
        L += ["", "GP-UKF per training draw: prediction (horizontal position RMSE, m), mean ± sd (ddof 1) over that "
              "draw's runs [runs]; between draws: mean, sd (ddof 1), min-max of the per-draw means",
              f"{'filter':<{w}}" + "".join(f"{c:>22}" for c in cases) + f"{'between draws':>30}"]
        for n in gps:
            d = per_draw(rows, n, "prediction")
            cells = "".join(f"{(cell(d[c]) + f' [{d[c].n}]') if c in d else '-':>22}" for c in cases)
            b = over_draws(d)
            L.append(f"{n:<{w}}{cells}{f'{cell(b)}, {b.low:.3g}-{b.high:.3g}':>30}")

    L += ["", "Consistency: ANEES from the filter's own P of the 12 states, the 10 measured ones and (x, y) (a consistent "
          "filter: 12, 10, 2; x, y start exact with P0 = 1 m^2 and are never measured); statistic as above",
          f"{'filter':<{w}}{'ANEES (12)':>20}{'measured (10)':>20}{'x, y (2)':>20}"]
    for n in names:
        L.append(f"{n:<{w}}" + "".join(f"{cell(statistic(rows, n, m)):>20}" for m in ("anees", "anees_measured", "anees_xy")))
    if config is not None and any(g.lml for g in config.gps):
        L += ["", *fit_table(config)]

    L += ["", f"The paper's Table 3 sigma of the UKF (quoted; paper.py) cannot be a standard deviation over its "
          f"{paper.RUNS} runs: the sample sd of n values >= 0 is at most sqrt(n) x their mean.", *paper_sigma_check(),
          "  It is printed here and never paired with our sd over runs (a different statistic).", "",
          "step ms (mean wall time of one predict + update, this machine and its load; not compared across runs): "
          + ", ".join(f"{n} {statistic(rows, n, 'step_ms').mean:.3g}" for n in names)]
    return "\n".join(L)


def fit_rows(fits: dict, hyper_max: int) -> list[list[str]]:
    """[targets, N, draw, LML of x's GP, of y's, the kept starts (of 12 GPs), the warm start's largest shortfall]
    per fitted training set; fits: {(targets, N, draw): (lml (12,), start_lml (12, starts))}."""
    from .gp_model import START_NAMES

    out = []
    for (targets, n, draw), (lml, start) in sorted(fits.items()):
        if n > hyper_max or lml is None:
            continue
        lml, start = np.asarray(lml, dtype=float), np.asarray(start, dtype=float)
        kept = [START_NAMES[i] if i < len(START_NAMES) else "random" for i in np.nanargmax(start, axis=1)]
        counts = ", ".join(f"{name} {kept.count(name)}" for name in dict.fromkeys(kept))
        warm = start[:, 1] if start.shape[1] > 1 else np.full(12, np.nan)
        gap = float(np.nanmax(lml - warm)) if np.isfinite(warm).any() else math.nan
        out.append([targets, str(n), str(draw), f"{lml[6]:.1f}", f"{lml[7]:.1f}", counts,
                    "-" if math.isnan(gap) else f"{gap:.1f}"])
    return out


def markdown(rows, config: RemusConfig, document: dict | None = None) -> dict[str, str]:
    """The tables of docs/experiments/remus.md (`abyssal publish remus`, publish.py): from the rows, the GP fits
    from the JSON document (its "gp" entries)."""
    from ..publish import markdown_table

    names = filter_names(rows)
    ukfs = [n for n in names if not is_gp(n)]
    gps = [n for n in names if is_gp(n)]
    out = {}
    out["ukf"] = markdown_table(
        ["state", "unit", "paper UKF (Table 3)", *ukfs],
        [[st, paper.UNITS[st], f"{paper.TABLE3['UKF'][st]:.4g}", *(cell(statistic(rows, n, f"rmse_{st}")) for n in ukfs)]
         for st in STATE_NAMES], align="ll" + "r" * (1 + len(ukfs)))
    if ukfs:
        best, scores = closest_reading(rows)
        body = []
        for n in ukfs:
            med, worst, within = scores[n]
            ratio = ratio_to_paper(rows, n)
            body.append([n + (" (closest)" if n == best else ""), f"{med:.2f}", f"{worst:.2f}", f"{within}/12",
                         f"{ratio['x']:.3g}", f"{ratio['y']:.3g}"])
        out["distance"] = markdown_table(["UKF reading", "median abs log10(ours / paper), 12 states", "max",
                                          "states within a factor 2", "x: ours / paper", "y: ours / paper"], body)
    cases = sorted({c for n in gps for c in draws_of(rows, n)}, key=lambda c: int(c.split()[-1]))
    body = []
    for n in gps:
        d = per_draw(rows, n, "prediction")
        b = over_draws(d)
        body.append([n, *((cell(d[c]) + f" [{d[c].n}]") if c in d else "-" for c in cases),
                     f"{cell(b)}; {b.low:.3g}-{b.high:.3g}"])
    out["gp-sweep"] = markdown_table(["GP-UKF", *(f"{c}: m [runs]" for c in cases), "between draws: mean ± sd; range"],
                                     body)
    fits = {}
    for key, entry in ((document or {}).get("gp") or {}).items():
        parts = key.split("|")
        if len(parts) == 3 and parts[2].startswith("draw") and entry.get("lml") is not None:
            fits[(parts[0], int(parts[1].removeprefix("N=")), int(parts[2].split()[-1]))] = (
                [np.nan if v is None else v for v in entry["lml"]],
                [[np.nan if v is None else v for v in row] for row in entry["start_lml"]])
    if fits:
        out["gp-fits"] = markdown_table(["targets", "N", "draw", "LML x (nats)", "LML y (nats)", "kept start (of 12 GPs)",
                                         "warm start alone short by (nats, max)"],
                                        fit_rows(fits, config.hyper_max), align="lrrrrlr")
    body = []
    windows = sum(1 for t in PREDICTION_STARTS if t + PREDICTION_HORIZON < config.duration)
    for n in names:
        kind = "GP-UKF" if is_gp(n) else "UKF"
        diverged = f"{sum(_values(rows, n, 'predict_10s_diverged')):g}/{windows * len(_values(rows, n, 'prediction'))}"
        body.append([n, cell(statistic(rows, n, "correction")), f"{paper.TABLE4[(kind, 'correction')]}",
                     cell(statistic(rows, n, "prediction")), f"{paper.TABLE4[(kind, 'prediction')]}",
                     cell(statistic(rows, n, "predict_10s")), diverged])
    out["table4"] = markdown_table(["filter", "correction (mixed units)", "paper", "prediction (m)", "paper (m)",
                                    "predict_10s (m, ours)", "windows diverged"], body)
    body = [[n, *(cell(statistic(rows, n, m)) for m in ("anees", "anees_measured", "anees_xy"))] for n in names]
    out["consistency"] = markdown_table(["filter", "ANEES, 12 states (12)", "10 measured (10)", "x, y (2)"], body)
    if gps:
        out["gp-states"] = markdown_table(
            ["state", "unit", "paper GP-UKF (Table 3)", *gps],
            [[st, paper.UNITS[st], (f"{paper.TABLE3['GP-UKF'][st]:.4g}" if st in paper.TABLE3["GP-UKF"] else "-"),
              *(cell(statistic(rows, n, f"rmse_{st}")) for n in gps)] for st in STATE_NAMES],
            align="ll" + "r" * (1 + len(gps)))
    return out


def fit_table(config: RemusConfig) -> list[str]:
    """The GPs' hyperparameter fits (gp_model.fit_gp): per targets, size and draw, the log marginal likelihood (LML,
    nats, on the fitted points) of the x- and y-targets' GPs, which start each of the 12 GPs kept, and the largest
    shortfall of the warm start alone (the fit without restarts before this was added) below the kept fit."""
    lines = [f"GP hyperparameter fits ({2 + config.restarts} starts per GP: the default, the next smaller size's optimum "
             f"(warm), {config.restarts} random; the fit with the largest LML is kept; sizes above {config.hyper_max} "
             "reuse that size's hyperparameters)",
             f"{'targets':<12}{'N':>6}{'draw':>6}{'LML x':>11}{'LML y':>11}   {'kept start (of 12 GPs)':<34}"
             f"{'warm start short by (nats, max)':>32}"]
    fits = {(g.targets, g.n_train, g.draw): (g.lml, g.start_lml) for g in config.gps if g.lml}
    for targets, n, draw, x, y, counts, gap in fit_rows(fits, config.hyper_max):
        lines.append(f"{targets:<12}{n:>6}{draw:>6}{x:>11}{y:>11}   {counts:<34}{gap:>32}")
    return lines


def document(rows, config: RemusConfig, prepared: dict) -> dict:
    """The JSON summary's entries: per filter and metric the statistic; the GPs' training and C; the paper's tables."""
    names = filter_names(rows)
    metrics = sorted({r["metric"] for r in rows})
    summary = {n: {m: vars(statistic(rows, n, m)) for m in metrics} for n in names}
    draws = {n: {m: {c: vars(s) for c, s in per_draw(rows, n, m).items()} for m in ("prediction", "rmse_x", "rmse_y")}
             for n in names if is_gp(n)}
    gp = {}
    if prepared:
        for (targets, n, draw), s in prepared["sets"].items():
            gp[f"{targets}|N={n}|draw {draw}"] = {
                "regressors": s.n_train, "hyperparameter_seconds": s.train_seconds,
                "lml": None if s.lml is None else s.lml.tolist(),
                "start_lml": None if s.start_lml is None else s.start_lml.tolist()}
        for (targets, n), c in prepared["compiled"].items():
            gp[f"{targets}|N={n}|predict"] = {"c_bytes": c.c_bytes, "generate_seconds": c.generate_seconds,
                                               "compile_seconds": c.compile_seconds}
    best = closest_reading(rows)[0] if any(not is_gp(n) for n in names) else None
    return {"duration_s": config.duration, "statistic": "UKF: mean and sd (ddof 1) over runs; GP-UKF: between training "
            "draws of per-draw means", "summary": summary, "gp_per_draw": draws, "gp": gp,
            "closest_reading_to_paper_ukf": best,
            "paper": {"table3": paper.TABLE3, "table4": {f"{k[0]}|{k[1]}": v for k, v in paper.TABLE4.items()}}}


# ------------------------------------------------------------------------------------------ figures
def figures(rows, out: Path, config: RemusConfig, seed: int, prepared: dict, settings: str | None = None) -> list[Path]:
    """The figures (figures.py of this folder), from the rows and a rerun of run 0 (the same numbers as the table's);
    settings: the command that made the run (stamped into every figure)."""
    from . import figures as remus_figures

    return remus_figures.all_figures(rows, Path(out), config, seed, prepared, settings)


#: the name `abyssal reproduce` looks up (reproduce.py)
Config = RemusConfig
