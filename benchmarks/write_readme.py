"""The summary block of benchmarks/README.md, written from one `abyssal bench --json` report (never typed by hand).

    abyssal bench --json > /dev/null                     # writes benchmarks/results/bench.json as well
    python benchmarks/write_readme.py benchmarks/results/bench.json [MORE.json ...] [--readme benchmarks/README.md]

The block sits between the markers ``<!-- bench:begin -->`` and ``<!-- bench:end -->`` (added below the README's
first paragraph when absent); everything outside them is left as it is. It holds: the command and the commit of the
run (of each run, when several reports are given: a section is taken from the first report that holds it), the
machine (CPU model, cores, load average at start and end, date), every target of every section with its value,
limit and met/missed, and the floors the sections counted beside the ratios: bytes and instructions per particle
(the SIR step and its f kernel) and per Kalman step.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

BEGIN, END = "<!-- bench:begin -->", "<!-- bench:end -->"
README = Path(__file__).resolve().parent / "README.md"


def _number(value, unit: str = "") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    if isinstance(value, (int, float)):
        text = f"{value:,.0f}" if abs(value) >= 1000 else f"{value:.4g}"
    else:
        text = str(value)
    return f"{text} {unit}".strip()


def _cell(text: str) -> str:
    return text.replace("|", "\\|")  # (a target's name such as max |dx|)


def _load(machine: dict, key: str) -> str:
    value = machine.get(key)
    return "n/a" if not value else " / ".join(f"{v:.2f}" for v in value)


def floors(report: dict) -> list[tuple[str, str, str]]:
    """(floor, value, where it was counted) rows from the sections' results: whatever the run counted, nothing typed."""
    rows: list[tuple[str, str, str]] = []
    sections = report.get("sections", {})
    sir = sections.get("sir", {}).get("results", {})
    for name, value in (sir.get("floor") or {}).items():
        unit = "B" if name.startswith("bytes") else ""
        rows.append((f"SIR step: {name}", _number(value, unit), "bench_sir floor (rov4dof, N = 10^5)"))
    for name, value in (sir.get("instructions_per_particle") or {}).items():
        rows.append((f"SIR step: instructions per particle, {name}", _number(value),
                     "bench_sir under callgrind (x86-64-v3 build)"))
    cpu, kernel = sir.get("cpu_ns_per_particle") or {}, (sir.get("floor") or {}).get("f kernel CPU ns/particle")
    for N in ("100000", "10000"):  # (JSON's keys are strings; --quick stops at 10^4)
        step = (cpu.get(N) or {}).get("abyssal compiled step, 1 thread")
        if step and kernel:
            rows.append((f"SIR step over its f kernel (CPU ns/particle, 1 thread, step at N = {N})",
                         _number(step / kernel, "x"), "bench_sir (the step's CPU time / the floor's f kernel at 10^5)"))
            break
    filters = sections.get("filters", {}).get("results", {})
    for name, value in (filters.get("instructions_per_step_callgrind") or {}).items():
        rows.append((f"CKF step from Python: instructions, {name}", _number(value),
                     "bench_filters under callgrind (x86-64-v3 build)"))
    for name, value in (filters.get("floor") or {}).items():
        rows.append((f"CKF step: {name}", _number(value), "bench_filters floor (rov4dof, manifest counts)"))
    for name, value in (filters.get("filter_object_bytes") or {}).items():
        rows.append((f"{name} filter object", _number(value, "B"), "bench_filters"))
    particles = sections.get("particles", {}).get("results", {})
    for row, counts in (particles.get("instructions_per_step") or {}).items():
        for name, value in (counts or {}).items():
            rows.append((f"{row} step from Python: instructions, {name}", _number(value),
                         "bench_particles under callgrind (x86-64-v3 build)"))
    return rows


def _machine_line(machine: dict) -> str:
    return (f"{machine.get('cpu_model') or machine.get('cpu', 'unknown CPU')}, {machine.get('cores', '?')} cores; "
            f"load average (1, 5, 15 min) at start {_load(machine, 'load_start')}, at end {_load(machine, 'load_end')}; "
            f"{machine.get('date_start', '?')} to {machine.get('date_end', '?')}; Python {machine.get('python', '?')}")


def block(runs: list[tuple[dict, str]]) -> str:
    """The block from one or more reports [(report, its path)]: a section is taken from the first report holding it."""
    merged: dict = {"sections": {}}
    origin: dict[str, int] = {}
    for k, (report, _) in enumerate(runs):
        for key, section in report.get("sections", {}).items():
            if key not in merged["sections"]:
                merged["sections"][key], origin[key] = section, k
    machines = [report.get("machine", {}) for report, _ in runs]
    commands = [m.get("command") or "abyssal bench --json" for m in machines]
    sources = " ".join(source for _, source in runs)
    lines = [BEGIN, f"<!-- written by `python benchmarks/write_readme.py {sources}` from "
             + ", ".join(f"`{c}`" for c in commands) + "; do not edit by hand -->", ""]
    if len(runs) == 1:
        lines += [f"## Latest run: every target, met or missed (`{commands[0]}`, commit "
                  f"{machines[0].get('commit', 'unknown')})", "", f"Machine: {_machine_line(machines[0])}. "
                  "Targets are ratios measured in the same run unless their unit says otherwise; compare ratios, not "
                  "times, across machines."]
    else:
        lines += ["## Latest runs: every target, met or missed", ""]
        lines += [f"{k + 1}. `{c}`, commit {m.get('commit', 'unknown')}: sections "
                  f"{', '.join(key for key, o in origin.items() if o == k) or '(none used)'}; {_machine_line(m)}."
                  for k, (c, m) in enumerate(zip(commands, machines))]
        lines += ["", "Targets are ratios measured in the same run unless their unit says otherwise; compare ratios, "
                  "not times, across machines."]
    lines += ["", "| section | target | value | limit | |", "|---|---|---|---|---|"]
    met = total = 0
    for key, section in merged["sections"].items():
        label = key if len(runs) == 1 else f"{key} (run {origin[key] + 1})"
        for t in section.get("targets", []):
            total += 1
            met += bool(t.get("met"))
            note = f" ({t['note']})" if t.get("note") else ""
            lines.append(f"| {label} | {_cell(t['name'] + note)} | {_number(t.get('value'), t.get('unit', ''))} | "
                         f"{t.get('direction', '<=')} {_number(t.get('limit'), t.get('unit', ''))} | "
                         f"{'met' if t.get('met') else '**missed**'} |")
    lines += ["", f"{met} of {total} targets met.", "", "Floors (counted in the same run as their section):", "",
              "| floor | value | counted by |", "|---|---|---|"]
    rows = floors(merged)
    lines += [f"| {_cell(a)} | {b} | {c} |" for a, b, c in rows] or ["| (none counted in this run) | | |"]
    lines += ["", END]
    return "\n".join(lines)


def write(readme: Path, text: str) -> str:
    """The README with its block replaced by `text` (or inserted after the first paragraph)."""
    old = readme.read_text()
    if BEGIN in old and END in old:
        head, rest = old.split(BEGIN, 1)
        tail = rest.split(END, 1)[1]
        return head + text + tail
    title, _, body = old.partition("\n\n")
    first, _, others = body.partition("\n\n")
    return f"{title}\n\n{first}\n\n{text}\n\n{others}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reports", nargs="+", help="bench.json written by `abyssal bench` (or its --json output); "
                        "with several (e.g. `abyssal bench --only ...` runs), a section from the first that holds it")
    parser.add_argument("--readme", default=str(README))
    args = parser.parse_args(argv)
    runs = [(json.loads(Path(path).read_text()), path) for path in args.reports]
    readme = Path(args.readme)
    readme.write_text(write(readme, block(runs)))
    print(f"wrote the bench block of {readme}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
