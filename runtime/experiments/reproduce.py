"""`abyssal reproduce {rov,cn,tan,remus,all}`: rerun the papers' experiments.

rov (seed 000), cn (seed 002), tan (seed 003) and remus (seed 004) each live in
experiments/<name>/; `all` runs the four in turn into one --out folder. Tables put the paper's printed numbers (constants below, labelled as
the paper's) beside ours, which come only from the runs made here. Every experiment runs on the
campaign harness (campaign.py): `--runs M --workers W` (local Dask cluster, W worker processes;
0 = in this process), `--scheduler tcp://HOST:PORT` (an existing cluster), `--resume` (reuse the
runs already in <out>/<experiment>.csv). Exit status 1 when a run failed twice (named with its seed).
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

#: Seed 000, Table 3 (RMSE; the paper's numbers, quoted, not computed here).
PAPER_ROV_TABLE3 = {
    "0": {"PF": (1.8577, 1.2232, 3.8294, 2.5201), "CKF": (1.0618, 0.9602, 0.8827, 1.5164),
          "CPF": (0.8291, 0.7297, 0.6871, 1.5018), "EM-MOGCPF": (0.5633, 0.5290, 0.5140, 0.9196)},
    "1-2": {"PF": (0.8289, 2.6940, 6.9908, 1.6541), "CKF": (1.1010, 1.4307, 3.9050, 1.7259),
            "CPF": (0.6611, 0.8125, 1.0363, 0.8849), "EM-MOGCPF": (0.4392, 0.3738, 0.4771, 0.4083)},
    "3": {"PF": (2.1690, 7.5129, 5.9652, 8.7070), "CKF": (3.5037, 5.0190, 10.9400, 14.6010),
          "CPF": (1.2855, 1.6607, 3.3708, 6.7736), "EM-MOGCPF": (0.5956, 0.3094, 0.6318, 2.1357)},
}
AXES = ("x", "y", "z", "psi")


def paper_rov_rmse() -> dict[str, dict[str, dict[str, float]]]:
    return {sea: {f: dict(zip(AXES, v)) for f, v in row.items()} for sea, row in PAPER_ROV_TABLE3.items()}


def _strict_json(value):
    """NaN and inf (no ESS for a Kalman filter, a diverged filter) as null: strict JSON."""
    if isinstance(value, dict):
        return {k: _strict_json(v) for k, v in value.items()}
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def run_rov(args, config=None) -> int:
    """`abyssal reproduce rov` on the campaign harness; `config` (a RovConfig) overrides the paper's set-up
    (tests use a short one). Rows go to <out>/rov.csv, the summary to <out>/rov.json, figures beside them."""
    from dataclasses import replace

    from . import campaign
    from .rov import experiment

    runs = 10 if args.runs is None else args.runs
    if config is None:
        config = experiment.quick_config() if getattr(args, "quick", False) else experiment.RovConfig()
    if getattr(args, "particles", None) is not None:
        if args.particles < 10:
            raise ValueError("reproduce rov needs --particles >= 10")
        config = replace(config, n_particles=args.particles)
    if runs < 1:
        raise ValueError("reproduce rov needs --runs >= 1")
    out = Path(args.out) if args.out else None
    result = campaign.run_campaign(
        experiment.run_one, config, runs, args.seed, workers=getattr(args, "workers", None),
        scheduler=getattr(args, "scheduler", None), csv_path=out / "rov.csv" if out else None,
        resume=getattr(args, "resume", False), experiment="rov", extra_columns=experiment.EXTRA_COLUMNS)
    rows = result.rows
    print(f"[rov] {result.runs_done} run(s) done, {result.runs_reused} reused from the table, "
          f"{len(result.failures)} failed; {result.wall_seconds:.1f} s on {result.where}", file=sys.stderr)
    figures = experiment.figures(rows, out) if out and rows else []
    summary = {f"{reading}|{sea}|{label}": _strict_json(stats) for (reading, sea, label), stats in experiment.summary(rows).items()}
    document = {"experiment": "rov", "runs": runs, "runs_in_table": len(result.runs), "seed": args.seed,
                "particles": config.n_particles, "config": repr(config), "summary": summary,
                "failures": [f.describe() for f in result.failures], "wall_seconds": result.wall_seconds,
                "where": result.where, "rows_csv": str(out / "rov.csv") if out else None}
    if out:
        (out / "rov.json").write_text(json.dumps(document, indent=1))
    if args.json:
        print(json.dumps(document, indent=1))
    else:
        print(experiment.report(rows))
        print()
        print(experiment.timing_table(rows))
        for path in figures:
            print(f"wrote {path}")
        if out:
            print(f"wrote {out / 'rov.csv'} (one row per run x sea state x filter x metric) and {out / 'rov.json'}")
    if result.failures:
        print(campaign.summarise_failures(result), file=sys.stderr)
        return 1
    return 0


def run_tan(args, config=None) -> int:
    """`abyssal reproduce tan [--quick]` (seed 003) on the campaign harness; `config` (a TanConfig) overrides
    the set-up (tests use a short one). Rows go to <out>/tan.csv, the summary to <out>/tan.json, figures beside."""
    from dataclasses import replace

    from . import campaign
    from .tan import experiment, scenario

    quick = getattr(args, "quick", False)
    config = config or scenario.TanConfig()
    if quick:
        config = config.quick()
    if getattr(args, "particles", None) is not None:
        if args.particles < 10:
            raise ValueError("reproduce tan needs --particles >= 10")
        config = replace(config, n_particles=args.particles)
    runs = (1 if quick else 2) if args.runs is None else args.runs
    if runs < 1:
        raise ValueError("reproduce tan needs --runs >= 1")
    out = Path(args.out) if args.out else None
    result = campaign.run_campaign(
        scenario.run_one, config, runs, args.seed, workers=getattr(args, "workers", None),
        scheduler=getattr(args, "scheduler", None), csv_path=out / "tan.csv" if out else None,
        resume=getattr(args, "resume", False), experiment="tan", extra_columns=experiment.EXTRA_COLUMNS)
    rows = result.rows
    print(f"[tan] {result.runs_done} run(s) done, {result.runs_reused} reused from the table, "
          f"{len(result.failures)} failed; {result.wall_seconds:.1f} s on {result.where}", file=sys.stderr)
    figures = experiment.figures(rows, out, config, args.seed) if out and rows else []
    document = {"experiment": "tan", "runs": runs, "runs_in_table": len(result.runs), "seed": args.seed,
                "config": repr(config), "cases": experiment.json_document(rows),
                "failures": [f.describe() for f in result.failures], "wall_seconds": result.wall_seconds,
                "where": result.where, "rows_csv": str(out / "tan.csv") if out else None}
    return _publish("tan", args, out, result, document, experiment.report(rows, config), figures)


def _publish(name: str, args, out, result, document: dict, report: str, figures) -> int:
    """Write <out>/<name>.json, print the table (or the JSON) and the files written; exit 1 if a run failed twice."""
    from . import campaign

    if out:
        (out / f"{name}.json").write_text(json.dumps(document, indent=1))
    if args.json:
        print(json.dumps(document, indent=1))
    else:
        print(report)
        for path in figures:
            print(f"wrote {path}")
        if out:
            print(f"wrote {out / f'{name}.csv'} (one row per run x case x filter x metric) and {out / f'{name}.json'}")
    if result.failures:
        print(campaign.summarise_failures(result), file=sys.stderr)
        return 1
    return 0


def run_cn(args, config=None) -> int:
    """`abyssal reproduce cn [--runs M] [--quick]` (seed 002, simulated lake trial) on the campaign harness;
    `config` (a CnConfig) overrides the set-up. Rows go to <out>/cn.csv, the summary to <out>/cn.json."""
    from dataclasses import replace

    from . import campaign
    from .cn import experiment

    config = config or experiment.CnConfig()
    if getattr(args, "quick", False):
        config = config.quick()
    if getattr(args, "particles", None) is not None:
        if args.particles < 10:
            raise ValueError("reproduce cn needs --particles >= 10")
        config = replace(config, n_particles=args.particles)
    runs = 10 if args.runs is None else args.runs
    if runs < 1:
        raise ValueError("reproduce cn needs --runs >= 1")
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    result = campaign.run_campaign(
        experiment.run_one, config, runs, args.seed, workers=getattr(args, "workers", None),
        scheduler=getattr(args, "scheduler", None), csv_path=out / "cn.csv" if out else None,
        resume=getattr(args, "resume", False), experiment="cn", extra_columns=experiment.EXTRA_COLUMNS)
    rows = result.rows
    print(f"[cn] {result.runs_done} run(s) done, {result.runs_reused} reused from the table, "
          f"{len(result.failures)} failed; {result.wall_seconds:.1f} s on {result.where}", file=sys.stderr)
    figures = experiment.figures(config, args.seed, out) if out and rows else []
    document = {"experiment": "cn", "data": "simulated lake trial (the paper's data is not public)", "runs": runs,
                "runs_in_table": len(result.runs), "seed": args.seed, "config": repr(config),
                "cases": _strict_json(experiment.json_document(rows)),
                "failures": [f.describe() for f in result.failures], "wall_seconds": result.wall_seconds,
                "where": result.where, "rows_csv": str(out / "cn.csv") if out else None}
    return _publish("cn", args, out, result, document, experiment.report(rows, config), figures)


def _run_remus(args) -> int:
    from .remus.experiment import reproduce

    return reproduce(args)


#: experiment name -> runner; `all` runs them in this order into the same --out folder.
EXPERIMENTS = {"rov": lambda args: run_rov(args), "cn": lambda args: run_cn(args), "tan": lambda args: run_tan(args),
               "remus": _run_remus}


def main(args) -> int:
    if args.experiment != "all":
        return EXPERIMENTS[args.experiment](args)
    status = 0
    for name, run in EXPERIMENTS.items():
        print(f"== abyssal reproduce {name}", file=sys.stderr, flush=True)
        status = max(status, run(args))
    return status
