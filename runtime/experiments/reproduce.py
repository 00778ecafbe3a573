"""`abyssal reproduce {rov,cn,tan,remus,all}`: rerun the papers' experiments.

Only `rov` (seed 000) exists so far; `cn`, `tan` and `remus` exit with status 2 and say so;
`all` runs what exists. Tables put the paper's printed numbers (constants below, labelled as
the paper's) beside ours, which come only from the runs made here.
"""
from __future__ import annotations

import json
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
NOT_YET = ("cn", "tan", "remus")


def paper_rov_rmse() -> dict[str, dict[str, dict[str, float]]]:
    return {sea: {f: dict(zip(AXES, v)) for f, v in row.items()} for sea, row in PAPER_ROV_TABLE3.items()}


def _progress(message: str) -> None:
    """One updating line on a terminal; plain lines in a log."""
    if sys.stderr.isatty():
        print(f"\r\033[K[rov] {message}", end="", file=sys.stderr, flush=True)
    else:
        print(f"[rov] {message}", file=sys.stderr, flush=True)


def rov_table(results: dict, runs: int, n_particles: int) -> str:
    """Table 3 layout: per sea state and axis, ours vs THEIRS for each filter; then step time and ANEES."""
    paper = paper_rov_rmse()
    filters = list(next(iter(results.values()))["metrics"])
    lines = [f"ROV sea-state experiment (seed 000): RMSE over {runs} Monte-Carlo run(s), N = {n_particles} particles",
             "OURS = this run; THEIRS = the paper's Table 3 (quoted; '-' where the paper has no such filter)", ""]
    header = f"{'sea state':<10}{'axis':<6}" + "".join(f"{name:>20}" for name in filters)
    sub = f"{'':<16}" + "".join(f"{'ours':>11}{'theirs':>9}" for _ in filters)
    lines += [header, sub, "-" * len(header)]
    for sea, block in results.items():
        for i, axis in enumerate(AXES):
            cells = []
            for name in filters:
                ours = block["metrics"][name]["rmse"][axis]
                theirs = paper.get(sea, {}).get(name, {}).get(axis)
                cells.append(f"{ours:>11.4f}{(f'{theirs:.4f}' if theirs is not None else '-'):>9}")
            lines.append(f"{(sea if i == 0 else ''):<10}{axis:<6}" + "".join(cells))
        lines.append(f"{'':<10}{'ms':<6}" + "".join(f"{block['metrics'][n]['step_ms']:>11.3f}{'':>9}" for n in filters))
        lines.append(f"{'':<10}{'ANEES':<6}" + "".join(f"{block['metrics'][n]['anees']:>11.3g}{'':>9}" for n in filters))
        lines.append("")
    lines.append("ms: mean wall time of one filter step (predict + update) in this run; ANEES: mean of "
                 "e^T P^-1 e / 12 over steps and runs (1 = consistent).")
    return "\n".join(lines)


def rov_figures(results: dict, out: Path) -> list[Path]:
    from .. import plots

    out.mkdir(parents=True, exist_ok=True)
    paper = paper_rov_rmse()
    written = []
    for sea, block in results.items():
        slug = sea.replace("-", "_")
        if block.get("first_run"):
            truth, runs = block["first_run"]
            errors = {name: r.errors(truth) for name, r in runs.items()}
            written.append(plots.error_vs_time(
                truth.times, {n: e[:, 0:4] for n, e in errors.items()}, ("x error (m)", "y error (m)", "z error (m)", "yaw error (rad)"),
                f"Position and yaw error, sea state {sea} (run 1; cf. the paper's Figs. 5, 7, 9)", out / f"rov_pose_error_sea_{slug}.png",
                wrapped_panels=(3,)))
            written.append(plots.error_vs_time(
                truth.times, {n: e[:, 4:8] for n, e in errors.items()}, ("u error (m/s)", "v error (m/s)", "w error (m/s)", "r error (rad/s)"),
                f"Velocity error, sea state {sea} (run 1; cf. the paper's Figs. 6, 8, 10)", out / f"rov_velocity_error_sea_{slug}.png"))
        written.append(plots.rmse_bars(block["metrics"], paper.get(sea), f"RMSE, sea state {sea} (cf. the paper's Figs. 11-12)",
                                       out / f"rov_rmse_sea_{slug}.png"))
    return written


def run_rov(args, scenario=None) -> int:
    """Run the experiment; `scenario` (a RovScenario) overrides the paper's set-up (tests use a short one)."""
    from .rov import scenario as rov_sea_state

    runs = 3 if args.runs is None else args.runs
    n_particles = 300 if args.particles is None else args.particles
    if runs < 1 or n_particles < 10:
        raise ValueError("reproduce rov needs --runs >= 1 and --particles >= 10")
    results = rov_sea_state.run_experiment(runs, args.seed, n_particles, progress=_progress,
                                           scenario=scenario or rov_sea_state.RovScenario())
    if sys.stderr.isatty():
        print("\r\033[K", end="", file=sys.stderr)
    figures = rov_figures(results, Path(args.out)) if args.out else []
    if args.json:
        print(json.dumps({"experiment": "rov", "runs": runs, "seed": args.seed, "particles": n_particles,
                          "sea_states": {sea: block["metrics"] for sea, block in results.items()}}, indent=1))
    else:
        print(rov_table(results, runs, n_particles))
        for path in figures:
            print(f"wrote {path}")
    return 0


def main(args) -> int:
    if args.experiment in NOT_YET:
        print(f"abyssal reproduce {args.experiment}: not implemented yet (only `rov` exists so far)", file=sys.stderr)
        return 2
    if args.experiment == "all":
        for name in NOT_YET:
            print(f"abyssal reproduce all: skipping {name} (not implemented yet)", file=sys.stderr)
    return run_rov(args)
