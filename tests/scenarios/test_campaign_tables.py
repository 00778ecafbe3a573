"""Campaign tables are never lost or invented: `resume` adopts a table only when it is, row for row,
the table the campaign wrote (its sidecar), keeps every finished run, and refuses anything else
naming the file, the run and the line.

Each case damages a table the way a disk, an editor or a user does (a value cut mid-number, `nan`,
a duplicated row, a deleted row, a table cut at a line end half-way through a run, a table copied
over another experiment's) and checks that resume refuses it and leaves both files as they were.
The experiments are toys (module-level, in-process: workers=0) so each case takes milliseconds.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from abyssal.runtime.experiments import campaign


@dataclass(frozen=True)
class Toy:
    cases: tuple = ("a", "b", "c")
    label: str = "toy"


def toy_run_one(config: Toy, seed: np.random.SeedSequence) -> list[dict]:
    run = campaign.run_index(seed)
    rng = np.random.default_rng(seed)
    rows = []
    for case in config.cases:
        for metric in ("rmse", "nees", "particles"):
            value = float("nan") if metric == "particles" and case == "c" else float(rng.standard_normal())
            rows.append({"run": run, "case": case, "filter": config.label, "metric": metric, "value": value})
    return rows


ROWS_PER_RUN = 9


def campaign_in(folder, runs, *, resume=False, experiment="cn", config=Toy(), seed=0):
    return campaign.run_campaign(toy_run_one, config, runs, seed, workers=0, csv_path=folder / f"{experiment}.csv",
                                 resume=resume, experiment=experiment, progress=False)


def lines(path):
    return path.read_text().splitlines(keepends=True)


def files(folder, name="cn"):
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.name.startswith(name)}


def refused(folder, runs=3, *, match, experiment="cn", **options):
    """Resume must refuse (TableRefused naming the file and `match`) and leave the folder's files unchanged."""
    before = files(folder, experiment)
    with pytest.raises(campaign.TableRefused, match=match) as error:
        campaign_in(folder, runs, resume=True, experiment=experiment, **options)
    assert str(folder / f"{experiment}.csv") in str(error.value)
    assert files(folder, experiment) == before
    return str(error.value)


@pytest.fixture
def table(tmp_path):
    """A finished 3-run table: (folder, its lines)."""
    result = campaign_in(tmp_path, 3)
    assert result.ok and len(result.rows) == 3 * ROWS_PER_RUN
    return tmp_path, lines(tmp_path / "cn.csv")


def run_lines(all_lines, run):
    """Indices (0-based, in the file) of the lines of one run."""
    return [i for i, line in enumerate(all_lines) if i > 0 and line.split(",")[0] == str(run)]


def test_resume_reuses_an_untouched_table_and_a_smaller_runs_keeps_every_finished_run(table):
    folder, original = table
    again = campaign_in(folder, 3, resume=True)
    assert again.runs_reused == 3 and again.runs_done == 0
    fewer = campaign_in(folder, 1, resume=True)  # reports run 0 only, deletes nothing
    assert fewer.runs == [0] and fewer.runs_done == 0
    assert lines(folder / "cn.csv") == original
    more = campaign_in(folder, 4, resume=True)
    assert more.runs == [0, 1, 2, 3] and more.runs_done == 1
    assert lines(folder / "cn.csv")[: len(original)] == original  # the new run sorts after the old ones


def test_a_value_cut_mid_number_is_refused_naming_the_line_and_run(table):
    folder, original = table
    i = run_lines(original, 1)[0]
    text = original[:]
    text[i] = text[i].rstrip("\n")[:-6] + "\n"  # 0.123456789 -> 0.1234 (still a number)
    (folder / "cn.csv").write_text("".join(text))
    message = refused(folder, match=f"line {i + 1} \\(run 1")
    assert "differs from the row written when run 1 finished" in message


def test_a_nan_value_is_refused(table):
    folder, original = table
    i = run_lines(original, 2)[1]
    text = original[:]
    text[i] = text[i].rsplit(",", 1)[0] + ",nan\n"
    (folder / "cn.csv").write_text("".join(text))
    refused(folder, match=f"line {i + 1} \\(run 2")


def test_a_duplicated_row_is_refused(table):
    folder, original = table
    i = run_lines(original, 0)[4]
    text = original[: i + 1] + [original[i]] + original[i + 1:]
    (folder / "cn.csv").write_text("".join(text))
    refused(folder, match=f"line {i + 2} \\(run 0, .*duplicates line {i + 1}")


def test_a_deleted_row_is_refused(table):
    folder, original = table
    i = run_lines(original, 1)[3]
    (folder / "cn.csv").write_text("".join(original[:i] + original[i + 1:]))
    message = refused(folder, match="run 1")
    assert f"line {i + 1}" in message and "missing" in message and f"8 of its {ROWS_PER_RUN} rows" in message


def test_a_table_cut_at_a_line_end_half_way_through_a_run_is_refused(table):
    folder, original = table
    cut = run_lines(original, 1)[4]
    (folder / "cn.csv").write_text("".join(original[:cut]))  # runs 0 whole, run 1 with 4 of its 9 rows
    message = refused(folder, match=f"run 1 has 4 of its {ROWS_PER_RUN} rows")
    assert f"after line {cut}" in message


def test_a_line_cut_mid_row_and_a_garbled_value_are_refused_naming_the_line(table):
    folder, original = table
    (folder / "cn.csv").write_text("".join(original[:-1]) + original[-1][:7])
    refused(folder, match=f"line {len(original)}: .*fields")
    text = original[:]
    text[5] = text[5].rsplit(",", 1)[0] + ",0.1x3\n"
    (folder / "cn.csv").write_text("".join(text))
    refused(folder, match="line 6 \\(run 0, .*'0.1x3' is not a number")


def test_a_table_of_another_experiment_is_never_adopted(tmp_path):
    cn = campaign_in(tmp_path, 2, experiment="cn", config=Toy(label="cn filters"))
    campaign_in(tmp_path, 1, experiment="tan", config=Toy(cases=("map",), label="tan filters"))
    # cn.csv copied over tan.csv, without its sidecar: tan's sidecar does not describe those rows
    (tmp_path / "tan.csv").write_bytes((tmp_path / "cn.csv").read_bytes())
    message = refused(tmp_path, 2, experiment="tan", config=Toy(cases=("map",), label="tan filters"), match="line 2")
    assert "not the table abyssal wrote" in message
    # ... with its sidecar too: made by another experiment and configuration
    (tmp_path / "tan.csv.meta.json").write_bytes((tmp_path / "cn.csv.meta.json").read_bytes())
    refused(tmp_path, 2, experiment="tan", config=Toy(cases=("map",), label="tan filters"),
            match="different experiment, config")
    # a table without any sidecar (copied into a new folder) is refused, not adopted
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    (fresh / "cn.csv").write_bytes((tmp_path / "cn.csv").read_bytes())
    refused(fresh, 2, config=Toy(label="cn filters"), match="has no sidecar")
    assert cn.ok


def test_a_damaged_or_older_sidecar_gives_a_clear_error(table):
    folder, _ = table
    sidecar = folder / "cn.csv.meta.json"
    good = sidecar.read_text()
    sidecar.write_text(good[: len(good) // 2])
    refused(folder, match="sidecar .* is damaged")
    old = json.loads(good)
    for key in ("format", "table_sha256", "previous_table_sha256", "runs"):  # the sidecar of an older abyssal
        del old[key]
    sidecar.write_text(json.dumps(old))
    refused(folder, match="written by an older abyssal")
    record = json.loads(good)
    record["runs"]["1"]["rows"] = "nine"
    sidecar.write_text(json.dumps(record))
    refused(folder, match="malformed run records")


def test_an_interrupted_write_between_sidecar_and_table_still_resumes(table):
    """Every write puts the sidecar first: a table one write behind its sidecar is the table written before."""
    folder, original = table
    previous_table = (folder / "cn.csv").read_bytes()
    campaign_in(folder, 4, resume=True)  # adds run 3
    (folder / "cn.csv").write_bytes(previous_table)  # as if interrupted before the table's rename
    resumed = campaign_in(folder, 4, resume=True)
    assert resumed.runs_reused == 3 and resumed.runs_done == 1 and resumed.runs == [0, 1, 2, 3]


def test_run_one_returning_a_key_twice_is_a_failed_run(tmp_path):
    def twice(config, seed):
        row = {"run": campaign.run_index(seed), "case": "a", "filter": "f", "metric": "m", "value": 1.0}
        return [row, dict(row)]

    result = campaign.run_campaign(twice, None, 1, workers=0, progress=False)
    assert not result.ok and "two rows with the key" in result.failures[0].error
