"""The `abyssal` command: regenerate, verify, export, reproduce, publish, replay, bench, cache."""
from __future__ import annotations

import argparse
import json
import sys

from .extras import MissingExtraError


def _regenerate(args) -> int:
    from abyssal.generated import regenerate

    if args.model:
        return _regenerate_user(args, regenerate)
    if args.out:
        raise ValueError("--out needs --model: built-in models are written into the source checkout's generated/")
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


def _regenerate_user(args, regenerate) -> int:
    """`abyssal regenerate --model FILE.py:FUNCTION --out DIR [--check]`."""
    if args.models:
        raise ValueError("give either built-in model names or --model, not both")
    if not args.out:
        raise ValueError("--model needs --out DIR (the folder of your project that receives <DIR>/<model name>/)")
    model, where = _user_model(args.model, regenerate)
    origin = regenerate.cli_origin(args.model, args.out, model.name, where)
    if args.check:
        problems = regenerate.check_folder(model, args.out, origin=origin)
        if problems:
            print(f"{args.out}/{model.name} differs from the equations (run `{origin.command}`):", file=sys.stderr)
            for problem in problems:
                print(problem, file=sys.stderr)
            return 1
        print(f"{args.out}/{model.name} matches the equations")
        return 0
    folder = regenerate.generate(model, args.out, origin=origin)
    print(f"wrote {folder} (load it with abyssal.load({str(folder)!r}); check it with `abyssal verify {folder}`)")
    return 0


def _user_model(spec: str, regenerate):
    """regenerate.load_model_spec(spec); any error raised while importing the user's file or calling its function
    (an ImportError, a SyntaxError, a TypeError in the equations ...) becomes one line naming the spec and the line."""
    import traceback
    from pathlib import Path

    try:
        return regenerate.load_model_spec(spec)
    except (ValueError, FileNotFoundError):
        raise
    except Exception as exc:  # noqa: BLE001 -- the user's code: anything may come out
        ours = [regenerate.SOURCE_ROOT / d for d in ("abyssal", "generated", "runtime", "symbolic")]
        frames = [f for f in traceback.extract_tb(exc.__traceback__) if "site-packages" not in Path(f.filename).parts
                  and not any(Path(f.filename).resolve().is_relative_to(d) for d in ours)]
        where = f" ({frames[-1].filename}, line {frames[-1].lineno})" if frames and not isinstance(exc, SyntaxError) else ""
        raise ValueError(f"--model {spec!r}: loading the model failed: {type(exc).__name__}: {exc}{where}") from exc


def _verify(args) -> int:
    from abyssal.verify import driver as verify  # the product's checks sit above the layers; only the command imports them

    names = [m for m in args.models if not _is_path(m)]
    folders = [m for m in args.models if _is_path(m)]
    if args.model:
        report = _verify_model_spec(args, verify)
    else:
        report = verify.run_all(models=names or None, folders=folders, strict=args.strict)
    if args.json:
        print(json.dumps(report.as_dict(), indent=1))
    else:
        print(report.table())
    return 0 if report.ok else 1


def _is_path(name: str) -> bool:
    from pathlib import Path

    return "/" in name or name.startswith(".") or (Path(name).is_dir() and not _is_builtin(name))


def _is_builtin(name: str) -> bool:
    from abyssal import generated

    return name in generated.available()


def _verify_model_spec(args, verify):
    """`abyssal verify --model SPEC [--out DIR]`: generate (into DIR, or a temporary folder), then verify."""
    import tempfile

    from abyssal.generated import regenerate

    model, where = _user_model(args.model, regenerate)
    out = args.out or tempfile.mkdtemp(prefix="abyssal-verify-")
    origin = regenerate.cli_origin(args.model, out, model.name, where)
    if args.out:
        problems = regenerate.check_folder(model, out, origin=origin)
        if problems:
            raise ValueError(f"{out}/{model.name} is not up to date with {args.model}: run `{origin.command}` first")
    folder = regenerate.generate(model, out, origin=origin) if not args.out else regenerate._user_folder(out, model.name)
    return verify.verify_targets([verify.model_target(model, folder)], strict=args.strict)


def benchmarks_folder():
    """benchmarks/ of the source checkout abyssal runs from (the repository root holds runtime/ and
    benchmarks/); benchmarks/ is never installed, so a non-editable install has none."""
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    folder = root / "benchmarks"
    if not ((root / "pyproject.toml").is_file() and (folder / "bench.py").is_file()):
        raise RuntimeError("the benchmarks ship with the source checkout only (git clone the abyssal repository, "
                           f"pip install -e . in it, and run abyssal bench there); this abyssal is installed at {root}")
    return folder


def _bench(args) -> int:
    import importlib

    folder = str(benchmarks_folder())
    if folder not in sys.path:
        sys.path.insert(0, folder)  # the sections import each other by file name, as when run as scripts
    if args.folders:
        return importlib.import_module("bench_folder").main(args.folders, json_output=args.json, quick=args.quick)
    only = tuple(args.only.split(",")) if args.only else None
    return importlib.import_module("bench").main(json_output=args.json, out=args.out, quick=args.quick, only=only)


def _export(args) -> int:
    """`abyssal export NAME|DIR --filter F --out DIR`: a self-contained C project of the filter (abyssal/export.py)."""
    import importlib

    export = importlib.import_module("abyssal.export")  # the module (the package exports a function `export`)
    folder = export.export(args.target, filter=args.filter, out=args.out, steps=args.steps, seed=args.seed,
                           history_seconds=args.history, force=args.force)
    print(f"wrote {folder}: cmake -S {folder} -B {folder}/build && cmake --build {folder}/build --parallel && "
          f"(cd {folder}/build && ctest)")
    return 0


def _reproduce(args) -> int:
    from abyssal.runtime.experiments import reproduce

    return reproduce.main(args)


def _publish(args) -> int:
    from abyssal.runtime.experiments import publish

    return publish.main(args)


def _replay(args) -> int:
    """`abyssal replay LOG --model NAME|DIR --filter F --sensors MAP.toml --out DIR [--smooth]` (runtime/replay)."""
    from abyssal.runtime.replay import replay

    result = replay(args.log, args.model, filter=args.filter, sensors=args.sensors, out=args.out, smooth=args.smooth,
                    progress=not args.no_progress)
    counts = ", ".join(f"{name} {c['used']}/{c['received']} used" for name, c in result.counts.items())
    smoothed = " and smoothed.csv" if result.smoothed is not None else ""
    print(f"replayed {args.log} through {result.filter_name} ({len(result.track.t)} events; {counts}): wrote "
          f"{args.out}/track.csv{smoothed}, measurements.csv, report.md, figures/"
          + (", odometry/ (nav_msgs/Odometry, ENU)" if result.log.kind == "bag" else ""))
    return 0


def _size_text(n: int) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} B"


def _cache(args) -> int:
    """`abyssal cache info [--json]` and `abyssal cache clear` (the compile cache, generated/build.py)."""
    import importlib

    build = importlib.import_module("abyssal.generated.build")  # the module (the package exports a function `build`)
    if args.action == "clear":
        removed, kept = build.clear()
        note = f"; kept {kept} in use by running processes" if kept else ""
        print(f"removed {removed} entr{'y' if removed == 1 else 'ies'} from {build.cache_dir()}{note}")
        return 0
    info = build.info()
    if args.json:
        print(json.dumps(info, indent=1))
        return 0
    n = len(info["entries"])
    print(f"cache folder: {info['folder']} (ABYSSAL_CACHE_DIR chooses it)")
    print(f"{n} entr{'y' if n == 1 else 'ies'}, {_size_text(info['total_bytes'])} of {_size_text(info['max_bytes'])} "
          f"(ABYSSAL_CACHE_MAX_BYTES; least recently used evicted first); build timeout {info['build_timeout_s']:g} s "
          "(ABYSSAL_BUILD_TIMEOUT)")
    for e in reversed(info["entries"]):
        status = e["compiler"] if e["valid"] else "not valid: rebuilt on next use"
        print(f"  {e['last_used']}  {_size_text(e['bytes']):>10}  {e['name']}  ({status})")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="abyssal", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("regenerate", help="write generated C from the equations",
                       description="Built-ins: `abyssal regenerate [NAME...]` writes into the source checkout. "
                                   "Your own model: `abyssal regenerate --model FILE.py:FUNCTION --out DIR` writes "
                                   "DIR/<model name>/.")
    p.add_argument("--check", action="store_true", help="regenerate in memory; exit 1 naming files that differ")
    p.add_argument("--model", metavar="FILE.py:FUNCTION", help="your model: a file path or MODULE:FUNCTION returning a Model")
    p.add_argument("--out", metavar="DIR", help="with --model: the folder receiving DIR/<model name>/")
    p.add_argument("models", nargs="*", help="built-in models to regenerate (default: all registered)")
    p.set_defaults(run=_regenerate)

    p = sub.add_parser("verify", help="check every generated function against reference numerics",
                       description="Verify built-in models by name, model folders written by abyssal.generate (DIR), "
                                   "or a model function (--model FILE.py:FUNCTION [--out DIR]).")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--model", metavar="FILE.py:FUNCTION", help="verify this model (generated into --out, or a temporary folder)")
    p.add_argument("--out", metavar="DIR", help="with --model: the folder it was generated into")
    p.add_argument("--strict", action="store_true", help="a skipped check fails the verification")
    p.add_argument("models", nargs="*", help="built-in model names or model folders (default: all built-ins)")
    p.set_defaults(run=_verify)

    p = sub.add_parser("bench", help="per-call and per-step timings, with ratios against peers",
                       description="Runs the sections of benchmarks/ (or times model folders, DIR); the benchmarks "
                                   "ship with the source checkout only.")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument("--out", default="benchmarks/results", help="folder for the JSON results (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="fewer repetitions (smoke run)")
    p.add_argument("--only", metavar="SECTION,...", help="these sections only (models, filters, particles, ...)")
    p.add_argument("folders", nargs="*", metavar="DIR", help="model folders to time (default: the built-in benchmarks)")
    p.set_defaults(run=_bench)

    p = sub.add_parser("export", help="a self-contained C99 project of a filter for the vehicle (no Python needed)",
                       description="Writes the model's generated C, the C runtime of the Kalman family, a header with "
                                   "the model's layout and units, CMakeLists.txt, the example run_csv, a C++17 wrapper "
                                   "and test vectors recorded from the Python filter (ctest runs them).")
    p.add_argument("target", metavar="NAME|DIR", help="a built-in model name or a model folder written by abyssal.generate")
    p.add_argument("--filter", required=True, choices=["ekf", "ukf", "ckf", "mcukf", "huber"])
    p.add_argument("--out", required=True, metavar="DIR", help="a new or empty folder")
    p.add_argument("--force", action="store_true", help="replace an earlier export in --out")
    p.add_argument("--history", type=float, default=None, metavar="SECONDS",
                   help="the filter's history for late measurements (default: twice the longest latency a sensor "
                        "declares, at least 2 s)")
    p.add_argument("--steps", type=int, default=10_000, help="steps of the recorded test vectors (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the recorded run (default: %(default)s)")
    p.set_defaults(run=_export)

    p = sub.add_parser("replay", help="a recorded log (CSV tables, rosbag2/MCAP) through a filter: track, report, figures",
                       description="Reads LOG (a folder of CSV tables or a rosbag2/MCAP bag) as MAP.toml maps its "
                                   "streams to the model's input and sensors, runs the filter over it in the order the "
                                   "measurements arrived, and writes track.csv, measurements.csv, report.md/json, "
                                   "figures/ (and for a bag an Odometry bag in ENU) into DIR, all or nothing.")
    p.add_argument("log", metavar="LOG", help="a folder of CSV tables, a rosbag2 folder or an .mcap file")
    p.add_argument("--model", required=True, metavar="NAME|DIR", help="a built-in model or a generated model folder")
    p.add_argument("--filter", required=True, choices=["ekf", "ukf", "ckf", "pf"])
    p.add_argument("--sensors", required=True, metavar="MAP.toml", help="the sensor map (streams, filter settings)")
    p.add_argument("--out", required=True, metavar="DIR", help="a new or empty folder (or an earlier replay's)")
    p.add_argument("--smooth", action="store_true", help="also write the Rauch-Tung-Striebel smoothed track")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(run=_replay)

    from .experiments.reproduce import EXPERIMENTS, quick_help  # the registry (light: the experiments load when run)

    p = sub.add_parser("reproduce", help="rerun the experiments of the four papers", epilog=quick_help(),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("experiment", choices=[*EXPERIMENTS, "all"])
    runs = ", ".join(f"{e.name} {e.runs} ({e.quick_runs} with --quick)" for e in EXPERIMENTS.values())
    p.add_argument("--runs", type=int, default=None, help=f"Monte-Carlo runs (default: {runs})")
    p.add_argument("--seed", type=int, default=0, help="campaign seed: run i uses SeedSequence(seed).spawn(runs)[i]")
    p.add_argument("--particles", type=int, default=None)
    p.add_argument("--workers", type=int, default=None,
                   help="local Dask worker processes, one thread each (default: the cores; 0 = in this process)")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="run on an existing Dask scheduler instead of a local cluster")
    p.add_argument("--resume", action="store_true", help="keep the runs already in <out>/<experiment>.csv; run the rest")
    p.add_argument("--quick", action="store_true", help="a short version of the experiment (each one's is listed below)")
    p.add_argument("--out", default="out", help="folder for the tidy CSV, JSON and figures (default: %(default)s)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_reproduce)

    p = sub.add_parser("publish", help="write a campaign's tables into the generated blocks of its docs page",
                       description="Rewrites the blocks '<!-- BEGIN GENERATED: NAME/... -->' of FILE (default: "
                                   "docs/experiments/<page>.md of the experiment) from DIR/NAME.csv and DIR/NAME.json, "
                                   "each naming the command, commit, CPU and load that made the campaign.")
    p.add_argument("experiment", choices=list(EXPERIMENTS))
    p.add_argument("--from", dest="source", required=True, metavar="DIR", help="the campaign's --out folder")
    p.add_argument("--into", default=None, metavar="FILE", help="the Markdown page (default: the experiment's)")
    p.set_defaults(run=_publish)

    p = sub.add_parser("cache", help="the compile cache: where it is, what it holds; clear it",
                       description="info: folder, entries (most recently used first), total size and cap. "
                                   "clear: remove every entry not in use by a running process.")
    p.add_argument("action", choices=["info", "clear"])
    p.add_argument("--json", action="store_true", help="with info: print JSON")
    p.set_defaults(run=_cache)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except (KeyError, ValueError, RuntimeError, OSError, MissingExtraError) as exc:
        print(f"abyssal {args.command}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C: one line (a campaign says what it kept), no traceback
        print(f"abyssal {args.command}: {exc or 'interrupted'}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
