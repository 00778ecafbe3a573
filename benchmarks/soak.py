"""Soak benchmark: every filter through long runs with faults, beside a fault-free twin.

    python benchmarks/soak.py [--quick] [--json] [--only LABEL ...]

Reports per filter the refusals (and those in the last 10 %), non-finite steps, the error over the
last 10 % against the fault-free twin's, and the steps to recover from each fault (bench_soak.py
beside this file, which `abyssal bench` prints as its soak section). Nothing is asserted.
"""
import json
import sys

import bench_soak  # this folder is sys.path[0] when the script runs

if __name__ == "__main__":
    args = sys.argv[1:]
    only = tuple(args[args.index("--only") + 1:]) if "--only" in args else ()
    report = bench_soak.run(quick="--quick" in args, verbose="--json" not in args, only=only)
    if "--json" in args:
        print(json.dumps(report, indent=1, default=str))
