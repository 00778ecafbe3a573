"""The campaign harness: per-run seeds, order- and worker-independent rows, retries and failures
reported with their seeds, resume/merge from the tidy CSV.

The toy experiments below are module-level (picklable); the module is pickled by value so the
Dask workers need not import this test file.
"""
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import cloudpickle
import numpy as np
import pytest

from abyssal.runtime.experiments import campaign

cloudpickle.register_pickle_by_value(sys.modules[__name__])


@dataclass(frozen=True)
class Toy:
    """marker_dir: where 'die-once' runs leave a mark; fail_runs raise always; die_runs kill the worker."""

    marker_dir: str = ""
    fail_runs: tuple = ()
    flaky_runs: tuple = ()
    die_once_runs: tuple = ()
    die_always_runs: tuple = ()


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
