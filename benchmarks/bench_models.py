"""Model timings (f, F, h per call; f per particle) as JSON: a thin wrapper of abyssal.runtime.bench_models.

    python benchmarks/bench_models.py [--quick]
"""
import argparse
import json

from abyssal.runtime.checks import bench_models

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (smoke run)")
    args = parser.parse_args()
    print(json.dumps(bench_models.run(quick=args.quick, verbose=False), indent=1))
