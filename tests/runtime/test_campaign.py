"""The campaign harness: per-run seeds, order- and worker-independent rows, retries and failures
reported with their seeds, resume/merge from the tidy CSV.

The toy experiments below are module-level (picklable); the module is pickled by value so the
Dask workers need not import this test file.
"""
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

import cloudpickle
import numpy as np
import pytest

from abyssal.runtime.experiments import campaign

cloudpickle.register_pickle_by_value(sys.modules[__name__])


@dataclass(frozen=True)
class Toy:
    """marker_dir: where 'die-once' runs leave a mark; fail_runs raise always; die_runs kill the worker;
    stall_marker: a file a dying run writes first, which STALL_PRELOAD reads (the worker restart then hangs)."""

    marker_dir: str = ""
    fail_runs: tuple = ()
    flaky_runs: tuple = ()
    die_once_runs: tuple = ()
    die_always_runs: tuple = ()
    stall_marker: str = ""


#: a worker preload (run at every worker process's start): a start that finds the marker removes it and hangs, as a
#: worker restart under heavy load did (the campaign then had no live worker and waited forever)
STALL_PRELOAD = """
import os, time  # abyssal test: a worker restart that hangs
MARKER = os.environ.get("ABYSSAL_TEST_STALL_MARKER", "")
if MARKER and os.path.exists(MARKER):
    os.remove(MARKER)
    time.sleep(3600)
"""


def toy_run_one(config: Toy, seed: np.random.SeedSequence) -> list[dict]:
    run = campaign.run_index(seed)
    if run in config.fail_runs:
        raise RuntimeError(f"toy failure in run {run}")
    marker = Path(config.marker_dir) / f"attempted-{run}"
    if run in config.flaky_runs and not marker.exists():
        marker.write_text("1")
        raise RuntimeError("flaky once")
    if run in config.die_once_runs and not marker.exists():
        marker.write_text("1")
        if config.stall_marker:
            Path(config.stall_marker).write_text("1")
        os._exit(3)  # the worker process dies mid-task
    if run in config.die_always_runs:
        os._exit(3)
    (Path(config.marker_dir) / f"ran-{run}-{os.getpid()}-{np.random.default_rng().integers(1 << 60)}").write_text("")
    rows = []
    for case in ("a", "b"):
        rng = np.random.default_rng(campaign.derive(seed, ord(case)))
        draws = rng.standard_normal(1000)
        rows += [{"run": run, "case": case, "filter": "toy", "metric": "mean", "value": float(draws.mean())},
                 {"run": run, "case": case, "filter": "toy", "metric": "var", "value": float(draws.var())}]
    return rows


def bad_run_one(config, seed):
    return [{"run": campaign.run_index(seed) + 1, "case": "a", "filter": "toy", "metric": "m", "value": 0.0}]


def _runs_executed(folder: Path) -> int:
    return len(list(folder.glob("ran-*")))


def test_seeds_do_not_depend_on_the_number_of_runs_and_derive_does_not_mutate():
    few, many = campaign.run_seeds(7, 3), campaign.run_seeds(7, 10)
    for a, b in zip(few, many):
        assert np.array_equal(a.generate_state(4), b.generate_state(4))
    s = few[1]
    first = campaign.derive(s, 2, 0).generate_state(2)
    assert np.array_equal(first, campaign.derive(s, 2, 0).generate_state(2))
    assert not np.array_equal(first, campaign.derive(s, 2, 1).generate_state(2))
    assert s.n_children_spawned == 0 and campaign.run_index(s) == 1


@pytest.mark.timeout(300)
def test_rows_sorted_and_identical_in_process_and_on_two_workers(tmp_path):
    config = Toy(marker_dir=str(tmp_path))
    inline = campaign.run_campaign(toy_run_one, config, 6, seed=3, workers=0)
    cluster = campaign.run_campaign(toy_run_one, config, 6, seed=3, workers=2, csv_path=tmp_path / "toy.csv")
    assert inline.ok and cluster.ok and cluster.where.startswith("local cluster, 2")
    assert inline.rows == cluster.rows  # bit-identical values, same order
    assert [r["run"] for r in cluster.rows] == sorted(r["run"] for r in cluster.rows)
    assert len(cluster.rows) == 6 * 4
    # the CSV reads back bit-identically (floats written in round-trip form)
    assert campaign.read_csv(tmp_path / "toy.csv") == cluster.rows


def test_a_run_failing_twice_is_reported_with_its_seed_and_the_rest_kept(tmp_path):
    config = Toy(marker_dir=str(tmp_path), fail_runs=(2,), flaky_runs=(1,))
    result = campaign.run_campaign(toy_run_one, config, 4, seed=11, workers=0, csv_path=tmp_path / "t.csv")
    assert not result.ok
    assert [f.run for f in result.failures] == [2]
    failure = result.failures[0]
    assert failure.entropy == 11 and failure.spawn_key == (2,)
    assert "toy failure in run 2" in failure.describe() and "SeedSequence(11, spawn_key=(2,))" in failure.describe()
    assert np.array_equal(failure.seed_sequence().generate_state(3), campaign.run_seeds(11, 4)[2].generate_state(3))
    assert sorted({r["run"] for r in result.rows}) == [0, 1, 3]  # the flaky run succeeded on its retry
    assert sorted({r["run"] for r in campaign.read_csv(tmp_path / "t.csv")}) == [0, 1, 3]


def test_malformed_rows_are_a_failure_not_silently_kept():
    result = campaign.run_campaign(bad_run_one, None, 1, workers=0)
    assert not result.ok and "names run 1, but its seed is run 0" in result.failures[0].error


@pytest.mark.timeout(300)
def test_a_dead_worker_loses_only_its_task(tmp_path):
    config = Toy(marker_dir=str(tmp_path), die_once_runs=(1,), die_always_runs=(2,))
    result = campaign.run_campaign(toy_run_one, config, 4, seed=5, workers=1)
    assert [f.run for f in result.failures] == [2]
    assert "KilledWorker" in result.failures[0].error or "died" in result.failures[0].error
    assert sorted({r["run"] for r in result.rows}) == [0, 1, 3]
    reference = campaign.run_campaign(toy_run_one, Toy(marker_dir=str(tmp_path)), 4, seed=5, workers=0)
    assert [r for r in reference.rows if r["run"] != 2] == result.rows


def test_resume_runs_only_the_missing_runs_and_merges_to_the_fresh_table(tmp_path):
    csv_path = tmp_path / "out" / "toy.csv"
    config = Toy(marker_dir=str(tmp_path))
    first = campaign.run_campaign(toy_run_one, config, 3, seed=9, workers=0, csv_path=csv_path)
    assert _runs_executed(tmp_path) == 3
    more = campaign.run_campaign(toy_run_one, config, 5, seed=9, workers=0, csv_path=csv_path, resume=True)
    assert _runs_executed(tmp_path) == 5 and more.runs_reused == 3 and more.runs_done == 2
    fresh = campaign.run_campaign(toy_run_one, config, 5, seed=9, workers=0)
    assert more.rows == fresh.rows and first.rows == [r for r in fresh.rows if r["run"] < 3]
    executed = _runs_executed(tmp_path)
    again = campaign.run_campaign(toy_run_one, config, 5, seed=9, workers=0, csv_path=csv_path, resume=True)
    assert again.runs_done == 0 and again.rows == fresh.rows and _runs_executed(tmp_path) == executed
    with pytest.raises(ValueError, match="different seed"):
        campaign.run_campaign(toy_run_one, config, 5, seed=10, workers=0, csv_path=csv_path, resume=True)


def test_resume_with_fewer_runs_keeps_the_finished_ones_on_disk(tmp_path):
    csv_path = tmp_path / "out" / "toy.csv"
    config = Toy(marker_dir=str(tmp_path))
    both = campaign.run_campaign(toy_run_one, config, 2, seed=9, workers=0, csv_path=csv_path)
    one = campaign.run_campaign(toy_run_one, config, 1, seed=9, workers=0, csv_path=csv_path, resume=True)
    assert one.runs_done == 0 and {r["run"] for r in one.rows} == {0}  # the result: the runs asked for
    on_disk = campaign.read_csv(csv_path, tuple(campaign.TIDY_COLUMNS))
    assert sorted(map(tuple, (r.values() for r in on_disk))) == sorted(map(tuple, (r.values() for r in both.rows)))
    executed = _runs_executed(tmp_path)
    again = campaign.run_campaign(toy_run_one, config, 2, seed=9, workers=0, csv_path=csv_path, resume=True)
    assert again.runs_done == 0 and again.rows == both.rows and _runs_executed(tmp_path) == executed


def test_arguments_are_checked():
    with pytest.raises(ValueError, match="runs"):
        campaign.run_campaign(toy_run_one, Toy(), 0, workers=0)
    with pytest.raises(ValueError, match="workers"):
        campaign.run_campaign(toy_run_one, Toy(), 1, workers=-1)
    with pytest.raises(ValueError, match="csv_path"):
        campaign.run_campaign(toy_run_one, Toy(), 1, workers=0, resume=True)


@pytest.mark.timeout(300)
def test_a_worker_whose_restart_hangs_does_not_hang_the_campaign(tmp_path, monkeypatch):
    """Run 1 kills its worker and the restarted worker hangs at its start (STALL_PRELOAD): no live worker is left,
    which hung the campaign at load 8-23. The watchdog replaces the local cluster after NO_WORKER_SECONDS and submits
    the unfinished runs again: every run finishes, with the rows of an undisturbed campaign."""
    import dask

    stall = tmp_path / "stall"
    monkeypatch.setenv("ABYSSAL_TEST_STALL_MARKER", str(stall))
    monkeypatch.setattr(campaign, "NO_WORKER_SECONDS", 3.0)
    config = Toy(marker_dir=str(tmp_path), die_once_runs=(1,), stall_marker=str(stall))
    with dask.config.set({"distributed.worker.preload": [STALL_PRELOAD]}):
        result = campaign.run_campaign(toy_run_one, config, 4, seed=5, workers=1, run_timeout=120)
    assert result.ok, campaign.summarise_failures(result)
    reference = campaign.run_campaign(toy_run_one, Toy(marker_dir=str(tmp_path)), 4, seed=5, workers=0)
    assert result.rows == reference.rows
    assert not stall.exists()  # the hung start happened (it removed the marker)


@pytest.mark.timeout(300)
def test_runs_that_never_finish_are_recorded_as_failed_with_their_seeds(tmp_path, monkeypatch):
    """A worker that keeps hanging at its restart and a scheduler with no worker: after run_timeout seconds without a
    finished run, the unfinished runs are failures with their seeds, the finished ones kept; the call returns."""
    import dask

    stall = tmp_path / "stall"
    monkeypatch.setenv("ABYSSAL_TEST_STALL_MARKER", str(stall))
    monkeypatch.setattr(campaign, "NO_WORKER_SECONDS", 1e9)  # never replaced: only run_timeout ends the wait
    config = Toy(marker_dir=str(tmp_path), die_once_runs=(2,), stall_marker=str(stall))
    with dask.config.set({"distributed.worker.preload": [STALL_PRELOAD]}):
        result = campaign.run_campaign(toy_run_one, config, 4, seed=5, workers=1, run_timeout=8,
                                       csv_path=tmp_path / "t.csv")
    assert 2 in [f.run for f in result.failures] and "run_timeout = 8 s" in result.failures[-1].error
    assert all(f.entropy == 5 and f.spawn_key == (f.run,) for f in result.failures)
    assert {r["run"] for r in campaign.read_csv(tmp_path / "t.csv")} == {r["run"] for r in result.rows}


TOY_EXPERIMENT = """
import time
from dataclasses import dataclass

EXTRA_COLUMNS = ()


@dataclass(frozen=True)
class Config:
    def quick(self):
        return self


def run_one(config, seed):
    time.sleep(0.2)
    run = int(seed.spawn_key[-1])
    return [{"run": run, "case": "a", "filter": "toy", "metric": "m", "value": float(run)}]


def report(rows, config):
    return "toy"


def figures(rows, out, config, seed, prepared):
    return []


def document(rows, config, prepared):
    return {}
"""

REPRODUCE_TOY = """
import signal, sys
# Ctrl-C as a terminal delivers it: SIGINT unblocked, Python's own handler (a test runner's disposition or signal
# mask, inherited through fork and exec, must not decide what this test sees)
signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])
signal.signal(signal.SIGINT, signal.default_int_handler)
sys.path.insert(0, {folder!r})
from abyssal.runtime import cli
from abyssal.runtime.experiments import reproduce
reproduce.EXPERIMENTS["toy"] = reproduce.Experiment("toy", "toy_experiment", (), runs=400, quick_runs=400)
sys.exit(cli.main(["reproduce", "toy", "--workers", {workers!r}, "--out", {out!r}]))
"""


@pytest.mark.timeout(300)
@pytest.mark.parametrize("workers", ["0", "1"])
def test_ctrl_c_ends_abyssal_reproduce_with_one_line_and_keeps_the_finished_runs(tmp_path, workers):
    """SIGINT of `abyssal reproduce` (a toy experiment in the registry, 400 runs of 0.2 s) once a few runs are in
    the table: exit 130, one line on stderr besides the progress lines (no traceback), and the finished runs in the
    CSV, which --resume accepts."""
    (tmp_path / "toy_experiment.py").write_text(textwrap.dedent(TOY_EXPERIMENT))
    out = tmp_path / "out"
    script = REPRODUCE_TOY.format(folder=str(tmp_path), workers=workers, out=str(out))
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(tmp_path)})
    try:
        deadline, seen = time.monotonic() + 200, False
        while time.monotonic() < deadline and proc.poll() is None:
            sidecar = out / "toy.csv.meta.json"
            if sidecar.exists() and '"runs": {}' not in sidecar.read_text():
                seen = True
                break
            time.sleep(0.2)
        assert seen, "no finished run reached the table before the campaign ended"
        time.sleep(1.0)
        os.kill(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("[toy] run ")]
    assert len(lines) == 1 and "Traceback" not in err, err
    kept = campaign.read_csv(out / "toy.csv")
    assert lines[0] == (f"abyssal reproduce: interrupted: {len(kept)} finished run(s) of 400 kept in {out / 'toy.csv'}; "
                        "--resume runs the others")
    assert 0 < len(kept) < 400 and [r["value"] for r in kept] == [float(r["run"]) for r in kept]
    campaign.check_resume(out / "toy.csv", "toy", 0)  # the table is one --resume adopts


@pytest.mark.timeout(300)
def test_a_resumed_campaign_names_every_session_behind_its_table(tmp_path, monkeypatch):
    """--resume keeps the provenance of the session whose runs it adopts beside its own, so that a generated block
    names every commit, load and wall time behind the table (not only the resume's)."""
    from abyssal.runtime import cli
    from abyssal.runtime.experiments import provenance, reproduce

    (tmp_path / "toy_experiment.py").write_text(textwrap.dedent(TOY_EXPERIMENT))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(reproduce.EXPERIMENTS, "toy", reproduce.Experiment("toy", "toy_experiment", (), runs=3,
                                                                           quick_runs=3))
    out = tmp_path / "out"
    assert cli.main(["reproduce", "toy", "--runs", "2", "--workers", "0", "--out", str(out)]) == 0
    first = json.loads((out / "toy.json").read_text())["provenance"]
    assert "earlier_sessions" not in first and "sessions" not in provenance.describe(first)
    assert cli.main(["reproduce", "toy", "--runs", "3", "--workers", "0", "--resume", "--out", str(out)]) == 0
    second = json.loads((out / "toy.json").read_text())["provenance"]
    assert second["earlier_sessions"] == [first]
    line = provenance.describe(second)
    assert "--runs 3" in line and "in 2 sessions (--resume)" in line
    loads = [v for r in (first, second) for v in (r["load_start"], r["load_end"]) if v is not None]
    assert f"load {min(loads):.1f}-{max(loads):.1f}" in line
    other = {**second, "earlier_sessions": [{**first, "commit": "f" * 40}]}  # an earlier session at another commit
    assert "commits " in provenance.describe(other) and "ffffffffff" in provenance.describe(other)
