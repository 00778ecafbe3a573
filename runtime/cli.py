"""The `abyssal` command: regenerate, verify, reproduce, bench."""
from __future__ import annotations

import argparse
import json
import sys


def _regenerate(args) -> int:
    from abyssal.generated import regenerate

    if args.check:
        problems = regenerate.check(args.models or None)
        if problems:
            print("generated C differs from the equations (run `abyssal regenerate` and commit):", file=sys.stderr)
            for problem in problems:
                print(problem, file=sys.stderr)
            return 1
        print("generated C matches the equations")
        return 0
    written = regenerate.regenerate(args.models or None)
    for path in written:
        print(f"wrote {path}")
    if not written:
        print("generated C already up to date")
    return 0


def _verify(args) -> int:
    from abyssal.runtime.checks import verify

    report = verify.run_all(models=args.models or None)
    if args.json:
        print(json.dumps(report.as_dict(), indent=1))
    else:
        print(report.table())
    return 0 if report.ok else 1


def _bench(args) -> int:
    from abyssal.runtime.checks import bench

    return bench.main(json_output=args.json, out=args.out, quick=args.quick)


def _reproduce(args) -> int:
    from abyssal.runtime.experiments import reproduce

    return reproduce.main(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="abyssal", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("regenerate", help="write generated C from the equations")
    p.add_argument("--check", action="store_true", help="regenerate in memory; exit 1 naming files that differ")
    p.add_argument("models", nargs="*", help="models to regenerate (default: all registered)")
    p.set_defaults(run=_regenerate)

    p = sub.add_parser("verify", help="check every generated function against reference numerics")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("models", nargs="*", help="models to verify (default: all)")
    p.set_defaults(run=_verify)

    p = sub.add_parser("bench", help="per-call and per-step timings, with ratios against peers")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument("--out", default="benchmarks/results", help="folder for the JSON results (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="fewer repetitions (smoke run)")
    p.set_defaults(run=_bench)

    p = sub.add_parser("reproduce", help="rerun the experiments of the four papers")
    p.add_argument("experiment", choices=["rov", "cn", "tan", "remus", "all"])
    p.add_argument("--runs", type=int, default=None, help="Monte-Carlo runs")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--particles", type=int, default=None)
    p.add_argument("--out", default="out", help="folder for figures (default: %(default)s)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_reproduce)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except (KeyError, ValueError, RuntimeError) as exc:
        print(f"abyssal {args.command}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
