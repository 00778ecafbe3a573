"""Soak benchmark: every filter over a long run with gross outliers and dropouts.

    python benchmarks/soak.py [--quick] [--json]

Reports steps, updates, refusals, gated, NaN steps, the final error against the truth and the
RSS growth per filter (bench_soak.py beside this file, which `abyssal bench` prints as its soak
section). Nothing is asserted.
"""
import json
import sys

import bench_soak  # this folder is sys.path[0] when the script runs

if __name__ == "__main__":
    report = bench_soak.run(quick="--quick" in sys.argv, verbose="--json" not in sys.argv)
    if "--json" in sys.argv:
        print(json.dumps(report, indent=1))
