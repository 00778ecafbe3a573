"""Seed 003's track survey (runtime/experiments/tan/survey.py): the tracks it surveys, its rows, its pick, and its
independence of the other configured tracks."""
from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace

import numpy as np

from abyssal.runtime.experiments.tan import survey
from abyssal.runtime.experiments.tan.scenario import TRACKS, admissible_starts, characterise, get_map
from abyssal.runtime.experiments.tan.survey import SurveyConfig, run_one

SHORT = SurveyConfig(duration_s=120.0, n_particles=100, grid_km=40.0, maps=("arctic",))


def test_the_surveyed_tracks_are_the_admissible_ones_inside_the_map_and_sloped():
    config = replace(SHORT, duration_s=30000.0, grid_km=20.0)
    tracks = config.tracks("arctic")
    terrain = get_map("arctic")
    assert [t[1] for t in tracks] == [s for s, _ in admissible_starts(terrain, 30000.0, 0.5, (0.1, 0.15), 20.0)]
    assert 0 < len(tracks) < 4 * 6 * 2  # some of the 6 x 2 grid starts x 4 headings leave the map or are flat
    for label, start, measures in tracks:
        assert label == survey.track_label(start)
        assert characterise(terrain, start, (0.15, 0.15), 30000.0, 0.5).margin_m >= 2000.0
        assert measures["flat_fraction"] <= 0.1


def test_a_run_stops_once_lost_and_its_rows_say_so():
    seed = np.random.SeedSequence(3).spawn(1)[0]
    rows = run_one(replace(SHORT, lost_m=30.0), seed)  # 30 m: the 50 m initial spread loses some runs at once
    by_key = {(r["case"], r["filter"], r["metric"]): r["value"] for r in rows}
    cases = {r["case"] for r in rows}
    assert cases == {f"arctic/{label}" for label, _, _ in SHORT.tracks("arctic")}
    lost = [(c, f) for (c, f, m), v in by_key.items() if m == "lost" and v == 1.0]
    kept = [(c, f) for (c, f, m), v in by_key.items() if m == "lost" and v == 0.0]
    assert lost, "a 30 m lost line must lose some run"
    for c, f in lost:
        assert by_key[(c, f, "max_error_m")] > 30.0 and 1.0 <= by_key[(c, f, "lost_at_s")] <= 120.0
        assert (c, f, "mean_error_m") not in by_key  # a truncated run has no mean error
    for c, f in kept:
        assert by_key[(c, f, "max_error_m")] <= 30.0 and (c, f, "lost_at_s") not in by_key
    assert rows == run_one(replace(SHORT, lost_m=30.0), seed)  # deterministic (no timings in its rows)


def test_a_tracks_draws_do_not_depend_on_the_other_tracks_or_maps():
    seed = np.random.SeedSequence(4).spawn(1)[0]
    one = run_one(SHORT, seed)
    both = run_one(replace(SHORT, maps=("topobathy", "arctic")), seed)
    assert all(r in both for r in one)


def test_the_pick_is_the_kept_track_with_the_largest_margin():
    entries = [{"label": "a", "start": (0, 0, 0), "terrain": {}, "worst": {"sigma_2": 400.0, "sigma_3": 2000.0},
                "kept": ["sigma_2"]},
               {"label": "b", "start": (1, 0, 0), "terrain": {}, "worst": {"sigma_2": 3000.0, "sigma_3": 250.0},
                "kept": ["sigma_3"]},
               {"label": "c", "start": (2, 0, 0), "terrain": {}, "worst": {"sigma_2": 100.0, "sigma_3": 90.0},
                "kept": []}]
    assert survey.pick(entries)["label"] == "b" and survey.pick(entries)["filter"] == "sigma_3"
    assert survey.pick([entries[2]]) is None


def test_each_maps_survey_pick_is_an_admissible_track_of_the_default_survey():
    config = SurveyConfig()
    for m in config.maps:
        pick = TRACKS[m]["survey_pick"]
        starts = [start for _, start, _ in config.tracks(m)]
        assert any(math.isclose(pick.x, s[0]) and math.isclose(pick.y, s[1]) and math.isclose(pick.heading, s[2])
                   for s in starts), m


def test_reproduce_tan_survey_writes_its_table_json_csv_and_figure(tmp_path, capsys):
    from abyssal.runtime.experiments import reproduce

    args = argparse.Namespace(runs=1, seed=0, particles=None, workers=0, scheduler=None, resume=False,
                              out=str(tmp_path), json=False, quick=False)
    assert reproduce.run("tan-survey", args, SHORT) == 0
    printed = capsys.readouterr().out
    assert "track survey" in printed and "THE SURVEY'S PICK" in printed
    document = json.loads((tmp_path / "tan-survey.json").read_text())
    assert len(document["survey"]["arctic"]) == len(SHORT.tracks("arctic"))
    assert (tmp_path / "tan-survey.csv").is_file() and (tmp_path / "tan_survey_tracks.png").is_file()
