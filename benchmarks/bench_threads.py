"""OpenMP in the `_batch` entry points vs ParallelBatch's concurrent.futures split (µs per batch, CPF step,
wait policy, fork check): `python benchmarks/bench_threads.py [--quick] [--json]`."""
import json
import sys

from abyssal.runtime.checks import bench_threads

if __name__ == "__main__":
    report = bench_threads.run(quick="--quick" in sys.argv, verbose=True)
    for t in report["targets"]:
        print(f"{'met ' if t['met'] else 'MISS'}  {t['name']}: {t['value']:.3f} {t['unit']} (target {t['direction']} {t['limit']:g})")
    if "--json" in sys.argv:
        print(json.dumps(report, indent=1))
