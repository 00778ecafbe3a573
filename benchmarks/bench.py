"""`abyssal bench`: timings measured as ratios against peers in the same run.

Sections (modules of this folder exposing ``run(quick: bool) -> dict``) each return
``{"results": {...}, "targets": [{"name", "value", "limit", "unit", "met"}...]}``; this module
prints them, and writes ``<out>/bench.json``. Targets are reported, never asserted in tests.

The folder is not installed: `abyssal bench` puts it on sys.path (from a source checkout) and
imports the sections by their file names, as `python benchmarks/bench_models.py` does.
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import subprocess
import time
from pathlib import Path

import numpy as np

SECTIONS = ("bench_models", "bench_filters", "bench_particles", "bench_sir", "bench_soak", "bench_campaign", "bench_remus",
            "bench_tan", "bench_cn", "bench_scaling", "bench_sensors")


def median_time(fn, repeat: int = 7, min_time: float = 0.05, clock=time.perf_counter) -> float:
    """Median seconds per call of fn(), timing loops of at least `min_time` seconds (of `clock`: wall time, or
    time.process_time for the CPU time of a single-threaded fn, steadier on a loaded machine)."""
    fn()
    n = 1
    while True:
        t0 = clock()
        for _ in range(n):
            fn()
        elapsed = clock() - t0
        if elapsed >= min_time:
            break
        n *= 2 if elapsed == 0 else max(2, int(min_time / elapsed * 1.2))
    samples = []
    for _ in range(repeat):
        t0 = clock()
        for _ in range(n):
            fn()
        samples.append((clock() - t0) / n)
    samples.sort()
    return samples[len(samples) // 2]


def paired_ratio(tops, bottoms) -> float:
    """The median of the pairs' own ratios top / bottom, each pair's two sides measured adjacent in time (a host whose
    speed drifts reaches both sides of a pair alike, which a ratio of two minima taken apart does not)."""
    return float(np.median(np.asarray(tops, dtype=float) / np.asarray(bottoms, dtype=float)))


def target(name: str, value: float, limit: float, unit: str, higher_is_better: bool = False) -> dict:
    met = value >= limit if higher_is_better else value <= limit
    return {"name": name, "value": value, "limit": limit, "unit": unit,
            "direction": ">=" if higher_is_better else "<=", "met": bool(met)}


def _load_average() -> list[float] | None:
    return list(os.getloadavg()) if hasattr(os, "getloadavg") else None


def _now() -> str:
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _commit() -> str:
    """The checkout's commit (short), with "+changes" when its tracked files differ from it."""
    root = Path(__file__).resolve().parent.parent
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+changes" if dirty else "")


def machine(quick: bool = False, only: tuple[str, ...] | None = None) -> dict:
    """Where and when the run happened: the README's block prints it beside the targets."""
    return {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
            "cpu_model": _cpu_model(), "cores": os.cpu_count(), "load_start": _load_average(), "date_start": _now(),
            "commit": _commit(), "command": "abyssal bench" + (" --quick" if quick else "")
            + (f" --only {','.join(only)}" if only else "")}


def main(json_output: bool = False, out: str | None = "benchmarks/results", quick: bool = False,
         only: tuple[str, ...] | None = None) -> int:
    """Every section (or those named in `only`, without the bench_ prefix) in SECTIONS' order."""
    unknown = set(only or ()) - {s.removeprefix("bench_") for s in SECTIONS}
    if unknown:
        raise SystemExit(f"abyssal bench --only: no section {', '.join(sorted(unknown))} (sections: "
                         f"{', '.join(s.removeprefix('bench_') for s in SECTIONS)})")
    report = {"machine": machine(quick, only), "sections": {}}
    for section in SECTIONS:
        if only and section.removeprefix("bench_") not in only:
            continue
        module = importlib.import_module(section)  # a missing or renamed section is an error, never skipped
        key = section.removeprefix("bench_")
        if not json_output:
            print(f"== {key}", flush=True)
        result = module.run(quick=quick, verbose=not json_output)
        report["sections"][key] = result
    report["machine"]["load_end"] = _load_average()
    report["machine"]["date_end"] = _now()
    targets = [t for s in report["sections"].values() for t in s.get("targets", [])]
    if out:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "bench.json").write_text(json.dumps(report, indent=1))
    if json_output:
        print(json.dumps(report, indent=1))
    else:
        print("\ntargets:")
        for t in targets:
            print(f"  {'met ' if t['met'] else 'MISS'}  {t['name']}: {t['value']:.4g} {t['unit']} (target {t['direction']} {t['limit']:g})")
        if out:
            print(f"\nsaved {Path(out) / 'bench.json'}")
    return 0


def json_main(run, description: str) -> None:
    """`python benchmarks/<section>.py [--quick]`: one section alone, its report as JSON on stdout."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (smoke run)")
    args = parser.parse_args()
    print(json.dumps(run(quick=args.quick, verbose=False), indent=1))
