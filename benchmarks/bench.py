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
import platform
import time
from pathlib import Path

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


def target(name: str, value: float, limit: float, unit: str, higher_is_better: bool = False) -> dict:
    met = value >= limit if higher_is_better else value <= limit
    return {"name": name, "value": value, "limit": limit, "unit": unit,
            "direction": ">=" if higher_is_better else "<=", "met": bool(met)}


def main(json_output: bool = False, out: str | None = "benchmarks/results", quick: bool = False) -> int:
    report = {"machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
              "sections": {}}
    for section in SECTIONS:
        module = importlib.import_module(section)  # a missing or renamed section is an error, never skipped
        key = section.removeprefix("bench_")
        if not json_output:
            print(f"== {key}", flush=True)
        result = module.run(quick=quick, verbose=not json_output)
        report["sections"][key] = result
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
