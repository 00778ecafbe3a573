"""`abyssal reproduce {rov,cn,cn-count,tan,tan-survey,remus,all}`: rerun the papers' experiments.

rov (seed 000), cn (seed 002; cn-count its MCUPF particle-count sweep), tan (seed 003; tan-survey its track
survey) and remus (seed 004) each live in experiments/<name>/ with the same shape: ``paper.py`` (the paper's
printed numbers, quoted and labelled as the paper's), ``scenario.py`` (the truth: the simulated world) and
``experiment.py``, which gives this module

    Config                                    dataclass: Config() is the paper's set-up, .quick() the --quick one
                                              (its docstring is what `reproduce --help` says --quick does)
    EXTRA_COLUMNS                             tidy-table columns beyond run, case, filter, metric, value
    run_one(config, seed) -> rows             one Monte-Carlo run (campaign.py maps it over the runs)
    report(rows, config) -> str               the tables, the paper's numbers beside ours
    figures(rows, out, config, seed, prepared[, settings]) -> [Path]   PNG figures; ``settings`` (when the
                                              function takes it) is the command that made the run, for
                                              plots.stamp_settings
    document(rows, config, prepared) -> dict  the experiment's entries of <out>/<name>.json

and, where its record says so, ``prepare(config, out, say) -> (config, prepared)`` before the campaign.
``EXPERIMENTS`` below is the registry; ``main`` is one loop over it (`all` runs the four in turn into one --out
folder). Ours come only from the runs made here. Every experiment runs on the campaign harness: `--runs M
--workers W` (local Dask cluster, W worker processes; 0 = in this process), `--scheduler tcp://HOST:PORT` (an
existing cluster), `--resume` (reuse the runs already in <out>/<name>.csv). Exit status 1 when a run failed
twice (named with its seed).
"""
from __future__ import annotations

import ast
import importlib
import importlib.util
import inspect
import json
import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path


@dataclass(frozen=True)
class Experiment:
    """One paper's experiment as `abyssal reproduce` runs it, and what it needs."""

    name: str                   # the CLI name; <out>/<name>.csv and <name>.json
    module: str                 # its experiment module, relative to this package
    models: tuple[str, ...]     # generated bundles it loads (compiled once here, before the campaign)
    runs: int                   # default --runs
    quick_runs: int             # default --runs with --quick
    #: optional packages it needs besides the campaign's and the figures' (module -> what needs it)
    needs: dict = field(default_factory=dict)
    particles: bool = True      # --particles sets config.n_particles (else it is ignored)
    prepare: bool = False       # module.prepare(config, out, say) runs before the campaign
    timings_apart: bool = False  # step times printed after the tables (module.timing_table), not in them
    case: str = "case"          # what one case of its tidy table is (the closing line says so)
    page: str = ""              # its docs page, docs/experiments/<page>.md (`abyssal publish`; "": its name)

    def experiment_module(self):
        return importlib.import_module(self.module, __package__)


#: the registry, in the order `all` runs it
EXPERIMENTS: dict[str, Experiment] = {e.name: e for e in (
    Experiment("rov", ".rov.experiment", ("rov4dof",), runs=10, quick_runs=3, timings_apart=True,
               case="sea state"),
    Experiment("cn", ".cn.experiment", ("cn2d",), runs=10, quick_runs=2, timings_apart=True,
               case="geometry x noise case"),
    Experiment("cn-count", ".cn.count_sweep", ("cn2d",), runs=10, quick_runs=1, particles=False,
               case="geometry x noise case", page="cn"),
    Experiment("tan", ".tan.experiment", ("tan3dof",), runs=8, quick_runs=1, case="map x track x current"),
    Experiment("tan-survey", ".tan.survey", ("tan3dof",), runs=3, quick_runs=1, case="map x track", page="tan"),
    Experiment("remus", ".remus.experiment", ("remus100",), runs=20, quick_runs=3,
               needs={"sklearn": "the GP process model"}, particles=False, prepare=True),
)}


def quick_description(experiment: Experiment) -> str:
    """What `--quick` runs for one experiment: its quick run count and the docstring of its ``Config.quick``,
    read from the module's source (nothing is imported, so `abyssal --help` stays fast and an experiment whose
    optional packages are missing still gets its line)."""
    runs = f"{experiment.quick_runs} run{'s' if experiment.quick_runs != 1 else ''}"
    try:
        spec = importlib.util.find_spec(experiment.module, __package__)
        tree = ast.parse(Path(spec.origin).read_text())
        aliases = {node.targets[0].id: node.value.id for node in tree.body if isinstance(node, ast.Assign)
                   and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name) and isinstance(node.value, ast.Name)}
        name = aliases.get("Config", "Config")
        cls = next(node for node in tree.body if isinstance(node, ast.ClassDef) and node.name == name)
        quick = next(node for node in cls.body if isinstance(node, ast.FunctionDef) and node.name == "quick")
        doc = ast.get_docstring(quick)
    except (AttributeError, OSError, StopIteration, SyntaxError, ImportError, TypeError):
        doc = None
    text = " ".join(doc.split()) if doc else "(its Config.quick has no docstring)"
    for prefix in ("`abyssal reproduce", "abyssal reproduce"):  # a docstring that opens with the command itself
        if text.startswith(prefix):
            text = text.split(":", 1)[-1].strip()
    return f"{runs}; {text}"


def quick_help() -> str:
    """The `reproduce --help` epilog: one line per experiment saying what its --quick version is."""
    import textwrap

    lines = ["--quick, per experiment (derived from each experiment's Config.quick):"]
    width = max(len(name) for name in EXPERIMENTS) + 1
    lines += [textwrap.fill(quick_description(e), width=100, initial_indent=f"  {e.name:<{width}}",
                            subsequent_indent=" " * (width + 2), break_on_hyphens=False) for e in EXPERIMENTS.values()]
    return "\n".join(lines)


def _strict_json(value):
    """NaN and inf (no ESS for a Kalman filter, a diverged filter, one run's sd) as null: strict JSON."""
    if isinstance(value, dict):
        return {k: _strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_strict_json(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _check_needs(experiment: Experiment, args) -> None:
    """Fail before anything runs when a package or a generated model it needs is missing."""
    from abyssal.generated import load

    from ..extras import require

    for module, purpose in experiment.needs.items():
        require(module, purpose)
    if args.out:
        require("matplotlib", "the experiment figures")
    for model in experiment.models:
        load(model)


def run(name: str, args, config=None) -> int:
    """`abyssal reproduce NAME` on the campaign harness; `config` overrides the paper's set-up (tests use a
    short one). Rows go to <out>/NAME.csv, the summary to <out>/NAME.json (with its provenance: the command, commit,
    CPU, load and wall time, provenance.py), the figures beside them."""
    from . import campaign, provenance

    experiment = EXPERIMENTS[name]
    module = experiment.experiment_module()
    quick = bool(getattr(args, "quick", False))
    config = config or module.Config()
    if quick:
        config = config.quick()
    if experiment.particles and getattr(args, "particles", None) is not None:
        if args.particles < 10:
            raise ValueError(f"reproduce {name} needs --particles >= 10")
        config = replace(config, n_particles=args.particles)
    runs = (experiment.quick_runs if quick else experiment.runs) if args.runs is None else args.runs
    if runs < 1:
        raise ValueError(f"reproduce {name} needs --runs >= 1")
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    say = lambda message: print(f"[{name}] {message}", file=sys.stderr, flush=True)  # noqa: E731
    record = provenance.started(
        provenance.reproduce_command(name, runs=runs, seed=args.seed, quick=quick,
                                     particles=getattr(args, "particles", None) if experiment.particles else None),
        getattr(args, "workers", None), getattr(args, "scheduler", None))
    t0 = time.perf_counter()
    earlier = _earlier_provenance(out / f"{name}.json") if out and getattr(args, "resume", False) else None
    prepared = None
    if experiment.prepare:
        if getattr(args, "resume", False) and out:  # a table resume would refuse, refused before the preparation
            campaign.check_resume(out / f"{name}.csv", name, args.seed, module.EXTRA_COLUMNS)
        config, prepared = module.prepare(config, out, say)
    result = campaign.run_campaign(
        module.run_one, config, runs, args.seed, workers=getattr(args, "workers", None),
        scheduler=getattr(args, "scheduler", None), csv_path=out / f"{name}.csv" if out else None,
        resume=getattr(args, "resume", False), experiment=name, extra_columns=module.EXTRA_COLUMNS)
    rows = result.rows
    say(f"{result.runs_done} run(s) done, {result.runs_reused} reused from the table, {len(result.failures)} failed; "
        f"{result.wall_seconds:.1f} s on {result.where}")
    figures = _figures(module, rows, out, config, args.seed, prepared, name, quick, runs) if out and rows else []
    document = {"experiment": name, "runs": runs, "runs_in_table": len(result.runs),
                "seed": args.seed, "quick": quick, "config": repr(config), **module.document(rows, config, prepared),
                "failures": [f.describe() for f in result.failures], "wall_seconds": result.wall_seconds,
                "where": result.where, "rows_csv": str(out / f"{name}.csv") if out else None,
                "provenance": provenance.resumed(provenance.finished(record, time.perf_counter() - t0),
                                                 earlier if result.runs_reused else None)}
    report = module.report(rows, config) if rows else f"{name}: no rows (every run failed)"
    if experiment.timings_apart and rows:
        report += "\n\n" + module.timing_table(rows)
    return _publish(experiment, args, out, result, _strict_json(document), report, figures)


def _earlier_provenance(path: Path) -> dict | None:
    """The provenance of the session that wrote <out>/NAME.json before a --resume (None: none readable)."""
    try:
        return json.loads(path.read_text()).get("provenance")
    except (OSError, ValueError, AttributeError):
        return None


def _figures(module, rows, out, config, seed, prepared, name: str, quick: bool, runs: int) -> list:
    """The experiment's figures; an experiment whose ``figures`` takes ``settings`` gets the command that made the
    run, to stamp into every figure (plots.stamp_settings)."""
    if "settings" in inspect.signature(module.figures).parameters:
        settings = f"abyssal reproduce {name}{' --quick' if quick else ''} --runs {runs} --seed {seed}"
        return module.figures(rows, out, config, seed, prepared, settings=settings)
    return module.figures(rows, out, config, seed, prepared)


def _publish(experiment: Experiment, args, out, result, document: dict, report: str, figures) -> int:
    """Write <out>/<name>.json, print the tables (or the JSON) and the files written; 1 if a run failed twice."""
    from . import campaign

    name = experiment.name
    if out:
        (out / f"{name}.json").write_text(json.dumps(document, indent=1))
    if args.json:
        print(json.dumps(document, indent=1))
    else:
        print(report)
        for path in figures:
            print(f"wrote {path}")
        if out:
            print(f"wrote {out / f'{name}.csv'} (one row per run x {experiment.case} x filter x metric) and "
                  f"{out / f'{name}.json'}")
    if result.failures:
        print(campaign.summarise_failures(result), file=sys.stderr)
        return 1
    return 0


def main(args) -> int:
    names = list(EXPERIMENTS) if args.experiment == "all" else [args.experiment]
    for name in names:
        _check_needs(EXPERIMENTS[name], args)
    status = 0
    for name in names:
        if len(names) > 1:
            print(f"== abyssal reproduce {name}", file=sys.stderr, flush=True)
        status = max(status, run(name, args))
    return status
