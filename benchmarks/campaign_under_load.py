"""A campaign test repeated under CPU load: does a dead Dask worker ever hang the campaign?

    python benchmarks/campaign_under_load.py [--repeat 20] [--burners 8] [--timeout 240] [--json] [NODEID ...]

Starts BURNERS busy processes (each spins on one core, at this script's priority), then runs the pytest
node(s) (default: tests/runtime/test_campaign.py::test_a_dead_worker_loses_only_its_task) REPEAT times, one
pytest process each, killed with its process group after TIMEOUT seconds (a hang). Prints per run its outcome,
seconds and the 1-minute load average, then the counts (passed, failed, hung). The burners and every child are
stopped before it exits. Nothing is asserted (a measurement: run it from a source checkout, see
benchmarks/README.md).
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TEST = "tests/runtime/test_campaign.py::test_a_dead_worker_loses_only_its_task"


def _burn() -> None:
    while True:
        pass


def run_once(nodeids: list[str], timeout: float) -> tuple[str, float]:
    """('passed' | 'failed' | 'hung', seconds) of one pytest process over the node ids."""
    started = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *nodeids], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        output, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # pytest, its Dask scheduler and workers: one process group
        proc.wait()
        return "hung", time.monotonic() - started
    outcome = "passed" if proc.returncode == 0 else "failed"
    if outcome == "failed":
        sys.stderr.write(output.decode(errors="replace")[-3000:] + "\n")
    return outcome, time.monotonic() - started


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("nodeids", nargs="*", default=[DEFAULT_TEST])
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--burners", type=int, default=8)
    parser.add_argument("--timeout", type=float, default=240.0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    burners = [multiprocessing.Process(target=_burn, daemon=True) for _ in range(args.burners)]
    for burner in burners:
        burner.start()
    runs = []
    try:
        time.sleep(5.0)  # let the load average rise
        for i in range(args.repeat):
            outcome, seconds = run_once(args.nodeids, args.timeout)
            load = os.getloadavg()[0]
            runs.append({"run": i, "outcome": outcome, "seconds": round(seconds, 1), "load": round(load, 1)})
            if not args.json:
                print(f"run {i + 1}/{args.repeat}: {outcome} in {seconds:.1f} s at load {load:.1f}", flush=True)
    finally:
        for burner in burners:
            burner.terminate()
        for burner in burners:
            burner.join()
    counts = {k: sum(r["outcome"] == k for r in runs) for k in ("passed", "failed", "hung")}
    loads = [r["load"] for r in runs]
    report = {"tests": args.nodeids, "burners": args.burners, "timeout": args.timeout, "runs": runs, **counts,
              "load_min": min(loads, default=None), "load_max": max(loads, default=None)}
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        print(f"{counts['passed']} passed, {counts['failed']} failed, {counts['hung']} hung (killed after "
              f"{args.timeout:g} s) of {len(runs)}; load {report['load_min']}-{report['load_max']} with "
              f"{args.burners} burners")
    return report


if __name__ == "__main__":
    main()
