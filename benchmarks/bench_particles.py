"""Per-step time of the particle filters on rov4dof (N = 300 and 3000): `python benchmarks/bench_particles.py [--quick]`."""
import json
import sys

from abyssal.runtime.checks import bench_particles

if __name__ == "__main__":
    report = bench_particles.run(quick="--quick" in sys.argv, verbose=True)
    for t in report["targets"]:
        print(f"{'met ' if t['met'] else 'MISS'}  {t['name']}: {t['value']:.3f} {t['unit']} (target <= {t['limit']:g})")
    if "--json" in sys.argv:
        print(json.dumps(report, indent=1))
