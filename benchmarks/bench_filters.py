"""Filter timings (EKF, UKF, CKF per step on rov4dof, beside filterpy and a NumPy CKF) as JSON:
a thin wrapper of abyssal.runtime.bench_filters.

    python benchmarks/bench_filters.py [--quick]
"""
import argparse
import json

from abyssal.runtime.checks import bench_filters

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="fewer repetitions (smoke run)")
    args = parser.parse_args()
    print(json.dumps(bench_filters.run(quick=args.quick, verbose=False), indent=1))
