"""Soak benchmark: every filter over a long run with gross outliers and dropouts.

    python benchmarks/soak.py [--quick] [--json]

Reports steps, updates, refusals, gated, NaN steps, the final error against the truth and the
RSS growth per filter (see abyssal.runtime.checks.bench_soak); `abyssal bench` prints the same
section. Nothing is asserted.
"""
import json
import sys

from abyssal.runtime.checks import bench_soak

if __name__ == "__main__":
    report = bench_soak.run(quick="--quick" in sys.argv, verbose="--json" not in sys.argv)
    if "--json" in sys.argv:
        print(json.dumps(report, indent=1))
