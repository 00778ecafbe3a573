"""Seed 000 on the campaign harness: one run = every filter on fresh truths of every case.

``run_one(config, seed)`` is the experiment (``campaign.run_campaign`` maps it over the runs);
``report(rows)`` (the tables, beside the paper's Table 3 of paper.py), ``timing_table(rows)``,
``document(rows, config)`` and ``figures(rows, out)`` are made from its tidy rows only. The truth
(sea states, process-noise readings, the catenary run) is scenario.py.

Rows: ``{"run", "case" (sea state), "filter" (label), "metric", "reading" (the truth's process-noise
reading), "value"}`` with metrics ``mse_x, mse_y, mse_z, mse_psi`` and the body velocities' ``mse_u, mse_v, mse_w,
mse_r`` (mean over the run's steps: a run's RMSE is their square root; the tables print the mean of the per-run
RMSE ± its sample sd over runs, tables.MEAN_SD, and the JSON adds the RMSE pooled over runs, tables.POOLED; psi in rad, the state's unit), ``anees``
(mean over steps of NEES / n_x, the NEES of ``FilterResult.nees``), ``ess_mean`` (mean effective
sample size per step; NaN for a Kalman filter), ``gated_updates`` (updates in which the innovation gate left
out at least one entry: 0 for the ungated filters), ``step_ms`` (wall time, kept out of the compared tables)
and ``refused`` (1 when the filter refused a step of this run, its other metrics then NaN).

Decisions:

* Filters are labelled for what they are: "CKF (matched model)" knows the truth's Q, R and bias
  dynamics (an oracle); "CKF (mismatched Q)" uses the other process-noise reading than the truth
  (with the plain truth: the density reading), which is what a CKF tuned without the simulator's
  noise does. The paper's CKF column is printed beside both. Both run without the innovation gate, as the
  paper's CKF; "CKF (mismatched Q, gated)" is the mismatched CKF with the Kalman filters' default gate
  (gate_probability 1e-10), a labelled variant, not the paper's filter.
* "CPF" is the cubature particle filter with the locally optimal proposal (each particle's
  cubature step from P^i = 0); "CPF (carried P^i)" is the form printed in the paper (van der
  Merwe's UPF), kept to show its weight collapse (mean ESS ~ 1). The paper's CPF column is printed
  beside "CPF".
* EM-MOGCPF variants: "EM-MOGCPF (analytic cov.)" (EM weights and means, Rao-Blackwellised
  component covariances) and the N sweep "EM-MOGCPF N=1000" / "N=3000" (N = 300 is the main row).
* Cases: the paper's three sea states, and sea state "1-2 wide" (the reading of the misprinted sea 1-2 mixture
  with its second component wide, scenario.py; compared with the paper's sea 1-2 column), under each
  process-noise reading of the truth; each filter
  spec names the readings and sea states where it runs, so the costly variants run only where
  they answer a question: the N sweep and the analytic-covariance ablation in sea state 3 (where
  the sample covariances were overconfident), MOGCPF, GS-CKF and the carried CPF under the
  default reading only.
* Seeds: the truth of case c from ``derive(seed, c, 0)`` (c: position in the full reading x sea
  state list), the filter labelled L on it from ``derive(seed, c, 1, crc32(L))``: a filter's
  numbers do not depend on which other filters or cases run.
* A filter whose estimate or covariance becomes non-finite gets inf metrics (shown, not dropped).
  A filter that refuses a step (the contract's ValueError: it left the finite range) gets NaN
  metrics and ``refused = 1`` for that run; the other filters of the run are kept, the tables
  average over the runs where it finished and print how many runs it refused.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..campaign import TIMING_METRICS, derive, run_index, run_seeds
from ..tables import MEAN_SD, over_runs, pooled_rms
from .paper import table3_rmse
from .scenario import POSE_AXES, PROCESS_NOISE_READINGS, SEA_STATES, RovScenario, make_filter, simulate

#: the body velocities (u, v, w in m/s, r in rad/s): the paper's Figs. 6, 8, 10 draw their errors, no table
VELOCITY_AXES = ("u", "v", "w", "r")
METRICS = tuple(f"mse_{a}" for a in POSE_AXES + VELOCITY_AXES) + ("anees", "ess_mean", "gated_updates", "step_ms")
EXTRA_COLUMNS = ("reading",)


@dataclass(frozen=True)
class FilterSpec:
    """One column of the experiment: a filter kind of ``make_filter`` under a label.

    reading: the filter's own process-noise reading (None: the truth's, i.e. a matched model; "other":
    the reading the truth does not use). n_particles None: the config's default. readings / sea_states:
    where it runs (None: every case).
    """

    label: str
    kind: str
    reading: str | None = None
    n_particles: int | None = None
    options: tuple = ()
    readings: tuple[str, ...] | None = None
    sea_states: tuple[str, ...] | None = None

    def runs_on(self, sea: str, reading: str) -> bool:
        return (self.readings is None or reading in self.readings) and (self.sea_states is None or sea in self.sea_states)

    def filter_reading(self, truth_reading: str) -> str:
        if self.reading is None:
            return truth_reading
        if self.reading == "other":
            return next(r for r in PROCESS_NOISE_READINGS if r != truth_reading)
        return self.reading


MAIN_FILTERS = (
    FilterSpec("PF", "PF"),
    FilterSpec("CKF (matched model)", "CKF"),
    FilterSpec("CKF (mismatched Q)", "CKF", reading="other"),
    FilterSpec("CKF (mismatched Q, gated)", "CKF", reading="other", options=(("gate_probability", 1e-10),)),
    FilterSpec("CPF", "CPF", options=(("proposal", "optimal"),)),
    FilterSpec("CPF (carried P^i)", "CPF", options=(("proposal", "carried"),), readings=("plain",)),
    FilterSpec("MOGCPF", "MOGCPF", readings=("plain",)),
    FilterSpec("EM-MOGCPF", "EM-MOGCPF"),
    FilterSpec("GS-CKF", "GS-CKF", readings=("plain",)),
)
N_SWEEP = (
    FilterSpec("EM-MOGCPF (analytic cov.)", "EM-MOGCPF", options=(("covariances", "analytic"),), readings=("plain",),
               sea_states=("3",)),
    FilterSpec("EM-MOGCPF N=1000", "EM-MOGCPF", n_particles=1000, readings=("plain",), sea_states=("3",)),
    FilterSpec("EM-MOGCPF N=3000", "EM-MOGCPF", n_particles=3000, readings=("plain",), sea_states=("3",)),
)
#: the Table 3 sea-state column a case is compared with: its own, or the printed case it is a reading of
PAPER_SEA = {"1-2 wide": "1-2"}


def paper_sea(sea: str) -> str:
    return PAPER_SEA.get(sea, sea)


#: labels whose paper counterpart is the Table 3 column of that name
PAPER_COLUMN = {"PF": "PF", "CKF (matched model)": "CKF", "CKF (mismatched Q)": "CKF", "CPF": "CPF", "EM-MOGCPF": "EM-MOGCPF"}


@dataclass(frozen=True)
class RovConfig:
    """What one run does. The default is `abyssal reproduce rov`."""

    scenario: RovScenario = field(default_factory=RovScenario)
    n_particles: int = 300
    sea_states: tuple[str, ...] = tuple(SEA_STATES)
    readings: tuple[str, ...] = PROCESS_NOISE_READINGS
    filters: tuple[FilterSpec, ...] = MAIN_FILTERS + N_SWEEP

    def quick(self) -> "RovConfig":
        """every sea state under both process-noise readings, the first 20 s of the path (200 steps), the main
        filters (the N sweep and the analytic-covariance ablation left out)"""
        sweep = {spec.label for spec in N_SWEEP}
        return replace(self, scenario=replace(self.scenario, duration=20.0),
                       filters=tuple(f for f in self.filters if f.label not in sweep))

    def cases(self) -> list[tuple[int, str, str]]:
        """(case number, sea state, truth reading); numbers fixed by the full lists, for stable seeds: the paper's
        three sea states keep the numbers they had before "1-2 wide" was added (reading x 3 + sea), the sea states
        after them are numbered after every reading's three."""
        paper_seas, extra = list(SEA_STATES)[:3], list(SEA_STATES)[3:]
        out = []
        for r_index, reading in enumerate(PROCESS_NOISE_READINGS):
            for sea in SEA_STATES:
                if reading in self.readings and sea in self.sea_states:
                    number = (r_index * len(paper_seas) + paper_seas.index(sea) if sea in paper_seas else
                              len(PROCESS_NOISE_READINGS) * len(paper_seas) + r_index * len(extra) + extra.index(sea))
                    out.append((number, sea, reading))
        return out


# ---------------------------------------------------------------------------------------------
# one run


def pose_errors(bundle, estimates: np.ndarray, states: np.ndarray) -> np.ndarray:
    """estimate - truth, (T, n), the model's angle states wrapped to (-pi, pi]."""
    from ...numerics import angle_indices, wrap_angles

    return wrap_angles(estimates - states, angle_indices(bundle, "states"), axis=1)


def run_case(config: RovConfig, seed: np.random.SeedSequence, case: int, sea_name: str, reading: str,
             specs=None):
    """One case of one run: (truth, {label: FilterResult, or None where the filter refused a step}) for every
    spec of ``specs`` (default: the config's) that runs on this case. What ``run_one`` makes its rows from and
    the figures re-run."""
    from abyssal.generated import load

    bundle = load("rov4dof")
    sea = SEA_STATES[sea_name]
    truth_scenario = config.scenario.with_reading(reading)
    truth = simulate(bundle, truth_scenario, sea, np.random.default_rng(derive(seed, case, 0)))
    results = {}
    for spec in config.filters if specs is None else specs:
        if not spec.runs_on(sea_name, reading):
            continue
        rng = np.random.default_rng(derive(seed, case, 1, zlib.crc32(spec.label.encode())))
        filter_scenario = config.scenario.with_reading(spec.filter_reading(reading))
        filt = make_filter(spec.kind, bundle, filter_scenario, sea, spec.n_particles or config.n_particles, rng,
                           **dict(spec.options))
        try:  # the one contract (runtime/contract.py): estimates, covariances, NEES, ESS, step times
            results[spec.label] = filt.run(truth.inputs, truth.measurements, truth_scenario.dt, truth=truth.states)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            results[spec.label] = None  # the filter refused a step: an outcome of this filter on this truth
    return truth, results


def run_one(config: RovConfig, seed: np.random.SeedSequence) -> list[dict]:
    """Every filter of the config on a fresh truth of every case: tidy rows (see the module docstring)."""
    from abyssal.generated import load

    bundle = load("rov4dof")
    run = run_index(seed)
    kinds = {spec.label: spec.kind for spec in config.filters}
    rows = []
    for case, sea_name, reading in config.cases():
        truth, results = run_case(config, seed, case, sea_name, reading)
        for label, result in results.items():
            if result is None:  # refused: NaN metrics, kept apart from the averages
                metrics = {**{m: math.nan for m in METRICS}, "refused": 1.0}
            else:
                errors = pose_errors(bundle, result.x, truth.states)
                finite = np.all(np.isfinite(errors)) and np.all(np.isfinite(result.P))
                metrics = {f"mse_{axis}": float(np.mean(errors[:, i] ** 2)) if finite else math.inf
                           for i, axis in enumerate(POSE_AXES + VELOCITY_AXES)}  # states 0-3 pose, 4-7 u v w r
                metrics["anees"] = float(np.mean(result.nees) / bundle.n_x) if finite else math.inf
                metrics["ess_mean"] = float(np.mean(np.asarray(result.ess, dtype=np.float64)))
                metrics["gated_updates"] = (float(np.sum(result.nis_dof < bundle.n_y)) if kinds[label] == "CKF"
                                            else math.nan)  # a Kalman filter's NIS counts the entries it used
                metrics["step_ms"] = 1e3 * float(np.mean(result.step_time))
                metrics["refused"] = 0.0
            rows += [{"run": run, "case": sea_name, "filter": label, "metric": m, "reading": reading, "value": v}
                     for m, v in metrics.items()]
    return rows


# ---------------------------------------------------------------------------------------------
# tables and figures, from the rows only


def summary(rows: list[dict]) -> dict:
    """{(reading, sea, filter): {"rmse": {axis: mean of the per-run RMSE}, "rmse_sd": {axis: its sample sd over runs
    (ddof = 1)}, "rmse_ci95": {axis: half-width of its 95 % t interval}, "rmse_pooled": {axis: RMSE pooled over
    every step of every run}, "anees", "anees_sd" (per-run ANEES: mean, sd), "ess_mean", "step_ms", "runs",
    "refused_runs"}} over the runs where the filter ran to the end (psi in rad, as the state)."""
    groups: dict[tuple, dict[str, list[float]]] = {}
    for row in rows:
        groups.setdefault((row["reading"], row["case"], row["filter"]), {}).setdefault(row["metric"], []).append(row["value"])
    out = {}
    for key, metrics in groups.items():
        kept = [i for i, refused in enumerate(metrics.get("refused", [0.0] * len(metrics.get("mse_x", [])))) if not refused]

        def values(m):
            return [metrics[m][i] for i in kept] if m in metrics else []

        rmse = {a: over_runs(math.sqrt(v) for v in values(f"mse_{a}")) for a in POSE_AXES + VELOCITY_AXES}
        anees = over_runs(values("anees"))
        out[key] = {"rmse": {a: r.mean for a, r in rmse.items()}, "rmse_sd": {a: r.sd for a, r in rmse.items()},
                    "rmse_ci95": {a: r.ci95 for a, r in rmse.items()},
                    "rmse_pooled": {a: pooled_rms(values(f"mse_{a}")) for a in POSE_AXES},
                    "anees": anees.mean, "anees_sd": anees.sd, "ess_mean": over_runs(values("ess_mean")).mean,
                    "gated_updates": over_runs(values("gated_updates")).mean,
                    "gated_updates_range": [over_runs(values("gated_updates")).low, over_runs(values("gated_updates")).high],
                    "step_ms": over_runs(values("step_ms")).mean, "runs": len(kept),
                    "refused_runs": len(metrics.get("mse_x", [])) - len(kept)}
    return out


def _order(items, key=lambda x: x):
    return list(dict.fromkeys(key(i) for i in items))


#: the order of filter labels in tables: the default config's, then any others alphabetically
LABEL_ORDER = tuple(f.label for f in MAIN_FILTERS + N_SWEEP)


def _labels(rows) -> list[str]:
    present = set(_order(rows, lambda r: r["filter"]))
    return [label for label in LABEL_ORDER if label in present] + sorted(present - set(LABEL_ORDER))


def _fmt(value: float, width: int, spec: str = ".4f") -> str:
    return f"{'-':>{width}}" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:>{width}{spec}}"


def _cell(stats: dict | None, axis: str, width: int) -> str:
    """"mean ± sd" of the per-run RMSE of one axis (the mean alone from one run, "inf" for a diverged filter, "-"
    without a value)."""
    mean = stats["rmse"].get(axis, math.nan) if stats else math.nan
    if not math.isfinite(mean):
        return f"{'-' if math.isnan(mean) else 'inf':>{width}}"
    sd = stats["rmse_sd"][axis]
    text = f"{mean:.3f}" + (f" ± {sd:.3f}" if math.isfinite(sd) else "")
    return f"{text:>{width}}"


#: the unit of each pose axis in our tables (psi as the state: rad)
UNITS = {"x": "m", "y": "m", "z": "m", "psi": "rad"}
#: how the paper's psi column is read (it prints no unit)
PSI_READING = ("psi: ours in rad, the error wrapped to (-pi, pi]. The paper prints no unit for psi; we read it as rad, "
               "the unit of its SI model (its R and Q), its errors then not wrapped (its values reach 14.6, more than "
               "pi). A reading in deg cannot be ruled out: its psi cells are this reading, not a printed unit.")


def table3(rows: list[dict], reading: str = "plain") -> str:
    """Our RMSE beside the paper's Table 3, for the filters the paper has (truth under `reading`)."""
    paper = table3_rmse()
    stats = summary(rows)
    seas = [s for s in SEA_STATES if any(k[:2] == (reading, s) for k in stats)]
    labels = [f for f in _labels(rows) if f in PAPER_COLUMN and any(k == (reading, s, f) for s in seas for k in stats)]
    runs = max((v["runs"] for v in stats.values()), default=0)
    lines = [f"Table 3 (seed 000): RMSE, truth under the '{reading}' process-noise reading, {runs} run(s)",
             f"ours: {MEAN_SD}; paper: Table 3 as printed (how many runs it averages is not stated; its CKF is one "
             f"column: compare both of ours). {PSI_READING}", ""]
    head = f"{'sea':<10}{'axis':<8}" + "".join(f"{label[:27]:>28}" for label in labels)
    lines += [head, f"{'':<18}" + "".join(f"{'ours':>19}{'paper':>9}" for _ in labels), "-" * len(head)]
    for sea in seas:
        for i, axis in enumerate(POSE_AXES):
            cells = []
            for label in labels:
                theirs = paper.get(paper_sea(sea), {}).get(PAPER_COLUMN[label], {}).get(axis)
                cells.append(_cell(stats.get((reading, sea, label)), axis, 19) + _fmt(theirs, 9))
            lines.append(f"{(sea if i == 0 else ''):<10}{axis + ' ' + UNITS[axis]:<8}" + "".join(cells))
        for metric, spec in (("anees", ".3g"), ("ess_mean", ".1f")):
            cells = [_fmt(stats.get((reading, sea, label), {}).get(metric), 19, spec) + f"{'':>9}" for label in labels]
            lines.append(f"{'':<10}{('ANEES' if metric == 'anees' else 'ESS'):<8}" + "".join(cells))
        lines.append("")
    return "\n".join(lines)


def variants_table(rows: list[dict], reading: str = "plain") -> str:
    """Every filter (including the extra baselines and the EM-MOGCPF variants): RMSE, ANEES, ESS per case."""
    stats = summary(rows)
    labels = _labels(rows)
    lines = [f"All filters, truth under the '{reading}' reading: RMSE of x, y, z (m) and psi (rad), {MEAN_SD}; ANEES "
             "and ESS: mean over runs; over the runs where the filter ran to the end (refused: runs where it refused "
             "a step, left out of its averages)", ""]
    head = (f"{'sea':<10}{'filter':<26}" + "".join(f"{a + ' ' + UNITS[a]:>17}" for a in POSE_AXES)
            + f"{'ANEES':>10}{'ESS':>8}{'refused':>9}")
    lines += [head, "-" * len(head)]
    for sea in SEA_STATES:
        for label in labels:
            s = stats.get((reading, sea, label))
            if s is None:
                continue
            lines.append(f"{sea:<10}{label[:25]:<26}" + "".join(_cell(s, a, 17) for a in POSE_AXES)
                         + _fmt(s["anees"], 10, ".3g") + _fmt(s["ess_mean"], 8, ".1f") + f"{s['refused_runs']:>9d}")
        lines.append("")
    return "\n".join(lines)


def sensitivity_table(rows: list[dict]) -> str:
    """reading x filter x sea state: x RMSE, ANEES, mean ESS (filters that ran under every reading)."""
    stats = summary(rows)
    readings = _order(rows, lambda r: r["reading"])
    labels = [f for f in _labels(rows)
              if all(any(k[0] == rd and k[2] == f for k in stats) for rd in readings)]
    seas = [s for s in SEA_STATES if any(k[1] == s for k in stats)]
    lines = ["Sensitivity to the process-noise reading of the truth (filters matched unless labelled):",
             "x RMSE (m, mean of the per-run RMSE) / ANEES / ESS (means over runs) per sea state", ""]
    head = f"{'reading':<9}{'filter':<27}" + "".join(f"{'sea ' + s:>26}" for s in seas)
    lines += [head, "-" * len(head)]
    for reading in readings:
        for label in labels:
            cells = []
            for sea in seas:
                s = stats.get((reading, sea, label))
                cells.append(f"{'-':>26}" if s is None else
                             f"{_fmt(s['rmse']['x'], 9, '.3f')} /{_fmt(s['anees'], 7, '.3g')} /{_fmt(s['ess_mean'], 6, '.0f')}")
            lines.append(f"{reading:<9}{label[:26]:<27}" + "".join(cells))
        lines.append("")
    return "\n".join(lines)


def kurtosis_table() -> str:
    """Each sea state's measurement noise: its mixture and the excess kurtosis per axis (0: Gaussian)."""
    lines = ["Measurement noise per sea state: excess kurtosis E[v^4] / E[v^2]^2 - 3 per axis (0 for a Gaussian; "
             "exact, from the mixture)", f"{'sea':<10}{'x':>7}{'y':>7}{'z':>7}{'psi':>7}   mixture (weights renormalised)"]
    for name, sea in SEA_STATES.items():
        k = sea.excess_kurtosis()
        lines.append(f"{name:<10}" + "".join(f"{v:>7.3f}" for v in k) + f"   {sea.description}")
    return "\n".join(lines)


def velocity_table(rows: list[dict], reading: str = "plain") -> str:
    """The body velocities' RMSE (the paper draws their errors, Figs. 6, 8, 10, and prints no number)."""
    stats = summary(rows)
    lines = [f"Body velocities, truth '{reading}': RMSE of u, v, w (m/s) and r (rad/s), {MEAN_SD} (the paper prints "
             "no velocity table; its Figs. 6, 8, 10 draw the errors over time)", ""]
    head = f"{'sea':<10}{'filter':<26}" + "".join(f"{a + (' rad/s' if a == 'r' else ' m/s'):>17}" for a in VELOCITY_AXES)
    lines += [head, "-" * len(head)]
    for sea in SEA_STATES:
        for label in _labels(rows):
            st = stats.get((reading, sea, label))
            if st is not None:
                lines.append(f"{sea:<10}{label[:25]:<26}" + "".join(_cell(st, a, 17) for a in VELOCITY_AXES))
    return "\n".join(lines)


def gate_table(rows: list[dict], reading: str = "plain") -> str:
    """The CKFs' innovation gate: updates with an entry left out per run (0 for the paper's ungated CKF)."""
    stats = summary(rows)
    labels = [label for label in _labels(rows) if any(k[0] == reading and k[2] == label and
                                                      math.isfinite(v["gated_updates"]) for k, v in stats.items())]
    lines = [f"Innovation gate of the CKFs, truth '{reading}': updates (of {RovScenario().n_steps} per run at the "
             "default duration) in which the gate left out an entry, mean over runs (min-max)"]
    for label in labels:
        cells = []
        for sea in SEA_STATES:
            st = stats.get((reading, sea, label))
            if st is not None and math.isfinite(st["gated_updates"]):
                low, high = st["gated_updates_range"]
                cells.append(f"sea {sea} {st['gated_updates']:.0f} ({low:.0f}-{high:.0f})")
        lines.append(f"  {label:<26}" + "; ".join(cells))
    return "\n".join(lines)


def timing_table(rows: list[dict]) -> str:
    """Mean wall time per step (machine- and load-dependent: not part of the reproducible tables)."""
    stats = summary(rows)
    labels = _labels(rows)
    parts = []
    for label in labels:
        values = [v["step_ms"] for k, v in stats.items() if k[2] == label and not math.isnan(v["step_ms"])]
        if values:
            parts.append(f"{label} {math.fsum(values) / len(values):.3f}")
    return "Wall time per filter step, ms (varies with the machine and load; not compared across runs):\n  " + "; ".join(parts)


def rankings(rows: list[dict], reading: str = "plain") -> str:
    """The paper's pairwise orderings (by mean pose RMSE over x, y, z, psi per sea state), and in how many of
    our runs each holds (a consistency measure: an ordering that holds in 5 of 10 runs is not a finding).
    The paper's CKF is compared as both of ours: the matched-model oracle and the mismatched-Q CKF."""
    lines = [f"The paper's orderings (mean RMSE over x, y, z, psi; truth '{reading}'): do ours agree, and in how many runs?"]
    for sea, better, worse, la, lb, k, n in ordering_rows(rows, reading):
        verdict = "holds" if k == n else ("reversed" if k == 0 else "mixed")
        lines.append(f"  sea {sea:<9} paper: {better} < {worse}; ours: {la} < {lb}: {verdict} ({k}/{n} runs)")
    return "\n".join(lines)


def ordering_rows(rows: list[dict], reading: str = "plain") -> list[tuple[str, str, str, str, str, int, int]]:
    """The paper's pairwise orderings and ours: (sea, the paper's better, worse, our better label, our worse label,
    runs where ours agrees, runs) -- rankings() as data."""
    paper = table3_rmse()
    per_run: dict[tuple, dict[str, float]] = {}
    for row in rows:
        if row["reading"] == reading and row["metric"] in {f"mse_{a}" for a in POSE_AXES} and row["filter"] in PAPER_COLUMN:
            per_run.setdefault((row["case"], row["filter"], row["run"]), {})[row["metric"]] = row["value"]

    def pose_rmse(metrics):
        return np.mean([math.sqrt(metrics[f"mse_{x}"]) for x in POSE_AXES])

    out = []
    for sea in SEA_STATES:
        cols = [c for c in ("PF", "CKF", "CPF", "EM-MOGCPF") if c in paper.get(paper_sea(sea), {})]
        score = {c: np.mean(list(paper[paper_sea(sea)][c].values())) for c in cols}
        for i, a in enumerate(cols):
            for b in cols[i + 1:]:
                better, worse = (a, b) if score[a] < score[b] else (b, a)
                for la in [k for k, v in PAPER_COLUMN.items() if v == better]:
                    for lb in [k for k, v in PAPER_COLUMN.items() if v == worse]:
                        runs = sorted({k[2] for k in per_run if k[0] == sea and k[1] in (la, lb)})
                        pairs = [(per_run.get((sea, la, r)), per_run.get((sea, lb, r))) for r in runs]
                        wins = [pose_rmse(ma) < pose_rmse(mb) for ma, mb in pairs if ma and mb]
                        if wins:
                            out.append((sea, better, worse, la, lb, sum(wins), len(wins)))
    return out


def markdown(rows: list[dict], config: RovConfig | None = None, document: dict | None = None) -> dict[str, str]:
    """The tables of docs/experiments/rov.md (`abyssal publish rov`, publish.py), from the rows (truth 'plain')."""
    from ..publish import markdown_table, number

    stats = summary(rows)
    paper = table3_rmse()
    reading = "plain"
    labels = _labels(rows)
    seas = [s for s in SEA_STATES if any(k[:2] == (reading, s) for k in stats)]
    out = {"kurtosis": markdown_table(
        ["sea state", "mixture (weights renormalised)", "x", "y", "z", "psi"],
        [[name, sea.description, *(f"{v:.3f}" for v in sea.excess_kurtosis())] for name, sea in SEA_STATES.items()],
        align="llrrrr")}

    def cell(st, axis):
        if st is None:
            return "-"
        mean, sd = st["rmse"][axis], st["rmse_sd"][axis]
        return number(mean, ".2f") + (f" ± {sd:.2f}" if math.isfinite(mean) and math.isfinite(sd) else "")

    shown = [label for label in labels if label in PAPER_COLUMN or label == "CKF (mismatched Q, gated)"]
    header = ["sea", "axis", *shown]
    body = []
    for sea in seas:
        for axis in POSE_AXES:
            row = [sea, f"{axis} ({UNITS[axis]})"]
            for label in shown:
                theirs = paper.get(paper_sea(sea), {}).get(PAPER_COLUMN.get(label), {}).get(axis)
                row.append(cell(stats.get((reading, sea, label)), axis) + (f" / {theirs:.2f}" if theirs is not None else ""))
            body.append(row)
    out["table3"] = markdown_table(header, body, align="ll" + "r" * len(shown))
    body = [[sea, f"{b} < {w}", f"{la} < {lb}", "holds" if k == n else ("reversed" if k == 0 else "mixed"), f"{k}/{n}"]
            for sea, b, w, la, lb, k, n in ordering_rows(rows, reading)]
    out["orderings"] = markdown_table(["sea", "the paper", "ours", "verdict", "runs"], body, align="llllr")
    body = []
    for label in labels:
        row = [label]
        for sea in seas:
            st = stats.get((reading, sea, label))
            row.append("-" if st is None else f"{number(st['anees'], '.3g')} / {number(st['ess_mean'], '.0f')}")
        body.append(row)
    out["consistency"] = markdown_table(["filter", *(f"sea {s}: ANEES / ESS" for s in seas)], body)
    body = [[label, *(cell(stats.get((reading, sea, label)), "x") for sea in seas)] for label in labels]
    out["all-x"] = markdown_table(["filter", *(f"sea {s}" for s in seas)], body)
    body = []
    for sea in seas:
        for label in [x for x in labels if x.startswith("CKF (mismatched Q")]:
            st = stats.get((reading, sea, label))
            if st:
                low, high = st["gated_updates_range"]
                body.append([sea, label, cell(st, "x"), cell(st, "psi"),
                             f"{number(st['gated_updates'], '.0f')} ({number(low, '.0f')}-{number(high, '.0f')})"])
    out["gate"] = markdown_table(["sea", "filter", "x RMSE (m)", "psi RMSE (rad)", "updates with an entry gated, mean "
                                  "(min-max) of 2000"], body, align="llrrr")
    body = [[sea, label, *(cell(stats.get((reading, sea, label)), a) for a in VELOCITY_AXES)]
            for sea in seas for label in labels if label in PAPER_COLUMN and (reading, sea, label) in stats]
    out["velocity"] = markdown_table(["sea", "filter", "u (m/s)", "v (m/s)", "w (m/s)", "r (rad/s)"], body, align="llrrrr")
    readings = _order(rows, lambda r: r["reading"])
    if "density" in readings:
        body = [[label, *(cell(stats.get(("density", sea, label)), "x") for sea in seas)]
                for label in labels if any(("density", sea, label) in stats for sea in seas)]
        out["density-x"] = markdown_table(["filter (truth 'density')", *(f"sea {s}" for s in seas)], body)
    return out


def report(rows: list[dict], config: RovConfig | None = None) -> str:
    """Every reproducible table (no timings: ``timing_table``)."""
    readings = _order(rows, lambda r: r["reading"])
    if not rows:
        return "no rows: every run failed"
    parts = []
    main = "plain" if "plain" in readings else readings[0]
    parts += [kurtosis_table(), table3(rows, main), variants_table(rows, main), velocity_table(rows, main),
              gate_table(rows, main)]
    if len(readings) > 1:
        parts.append(sensitivity_table(rows))
    parts.append(rankings(rows, main))
    return "\n\n".join(parts)


def document(rows: list[dict], config: RovConfig, prepared=None) -> dict:
    """The JSON summary's entries: {"particles", "summary": {"reading|sea|filter": summary(rows) entry}}."""
    return {"particles": config.n_particles,
            "summary": {f"{reading}|{sea}|{label}": stats for (reading, sea, label), stats in summary(rows).items()}}


def figures(rows: list[dict], out: Path, config: RovConfig | None = None, seed: int = 0, prepared=None,
            settings: str | None = None) -> list[Path]:
    """Per sea state: ``rov_rmse_sea_<s>.png``, RMSE bars (the paper's Figs. 11-12) from the rows, x, y, z (m) and
    psi (rad) in panels of their own, the paper's Table 3 values as markers (its psi read as rad: PSI_READING);
    ``rov_errors_sea_<s>.png``, the pose error over time of the paper's filters in run 0 (its Figs. 5, 7,
    9), re-run here from the same seed, so it shows a run that is in the table; ``rov_velocity_errors_sea_<s>.png``,
    the body velocities' error (u, v, w, r) of the same run (its Figs. 6, 8, 10: it says "XYZ-axis velocity"; our
    states are the body-frame velocities, drawn as such)."""
    from abyssal.generated import load

    from ... import plots

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    config = config or RovConfig()
    paper = table3_rmse()
    stats = summary(rows)
    readings = _order(rows, lambda r: r["reading"])
    main = "plain" if "plain" in readings else readings[0]
    labels = tuple(_labels(rows))
    runs = len({r["run"] for r in rows})
    stamp = (f"{settings}: " if settings else "") + (f"{runs} run(s), seed {seed}, {config.scenario.duration:g} s of the "
                                                      f"path, N = {config.n_particles}")
    note = {1: "paper's psi: no unit printed, read as rad\n(its SI model; 14.6 > pi: errors not wrapped)"}
    written = []
    for sea in SEA_STATES:
        metrics = {k[2]: v for k, v in stats.items() if k[0] == main and k[1] == sea}
        if not metrics:
            continue
        metrics = {label: metrics[label] for label in labels if label in metrics}
        theirs = {label: paper[paper_sea(sea)][col] for label, col in PAPER_COLUMN.items()
                  if label in metrics and col in paper.get(paper_sea(sea), {})}
        written.append(plots.rmse_bars(
            metrics, theirs, f"RMSE, sea state {sea}, '{main}' reading: mean of the per-run RMSE ± sd over runs "
            "(cf. the paper's Figs. 11-12)", out / f"rov_rmse_sea_{sea.replace('-', '_').replace(' ', '_')}.png",
            paper_label="paper, Table 3 (quoted)", notes=note, ordered=labels, settings=stamp))
    shown = tuple(spec for spec in config.filters if spec.label in PAPER_COLUMN)
    seed0 = run_seeds(seed, 1)[0]
    for case, sea, reading in config.cases():
        if reading != main or not shown:
            continue
        truth, results = run_case(config, seed0, case, sea, reading, shown)
        bundle = load("rov4dof")
        errors = {label: pose_errors(bundle, r.x, truth.states) for label, r in results.items() if r is not None}
        name = sea.replace("-", "_").replace(" ", "_")
        written.append(plots.error_vs_time(
            truth.times, {label: e[:, :4] for label, e in errors.items()},
            ("x error (m)", "y error (m)", "z error (m)", "psi error (rad)"),
            f"Pose error, sea state {sea}, '{main}' reading, run 0 (cf. the paper's Figs. 5, 7, 9)",
            out / f"rov_errors_sea_{name}.png", wrapped_panels=(3,), ordered=labels, settings=stamp))
        written.append(plots.error_vs_time(
            truth.times, {label: e[:, 4:8] for label, e in errors.items()},
            ("u error (m/s)", "v error (m/s)", "w error (m/s)", "r error (rad/s)"),
            f"Body-velocity error, sea state {sea}, '{main}' reading, run 0 (cf. the paper's Figs. 6, 8, 10)",
            out / f"rov_velocity_errors_sea_{name}.png", ordered=labels, settings=stamp))
    return written


def short_config(duration: float = 3.0, n_particles: int = 20, **changes) -> RovConfig:
    """A seconds-long configuration for tests and quick benches (same filters, fewer steps and particles)."""
    filters = tuple(replace(f, n_particles=None if f.n_particles is None else 2 * n_particles) for f in MAIN_FILTERS + N_SWEEP)
    base = RovConfig(scenario=RovScenario(duration=duration), n_particles=n_particles, filters=filters)
    return replace(base, **changes)


#: the name `abyssal reproduce` looks up (reproduce.py)
Config = RovConfig

__all__ = ["EXTRA_COLUMNS", "Config", "FilterSpec", "RovConfig", "TIMING_METRICS", "document", "figures", "report", "run_one",
           "short_config", "summary", "timing_table"]
