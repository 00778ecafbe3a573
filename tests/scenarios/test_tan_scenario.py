"""Seed 003's experiment (runtime/experiments/tan): the tracks and their terrain, the run_one shape, determinism,
the flat-area finding, the statement at 0.1 m/s, and `reproduce tan` end to end."""
import math
from dataclasses import replace

import numpy as np
import pytest

from abyssal.runtime.experiments.campaign import TIMING_METRICS
from abyssal.runtime.experiments.tan import experiment
from abyssal.runtime.experiments.tan.experiment import TanConfig, run_one
from abyssal.runtime.experiments.tan.scenario import TRACKS, characterise, get_map, pick_along_across
from abyssal.runtime.terrain import BathymetryMap

CONFIG = TanConfig(duration_s=400.0, n_particles=200, maps=("arctic",), tracks=("paper_60_10",), currents=("0.15",),
                   sigmas=(2.0,), fuzzy=("fuzzy",))


def plane(slope_x: float, slope_y: float, resolution: float = 500.0) -> BathymetryMap:
    """depth = 1000 m + slope . (x, y) on a 60 x 60 km grid (slopes in m per m)."""
    xs = np.arange(0.0, 60e3 + 1, resolution)
    X, Y = np.meshgrid(xs, xs)
    return BathymetryMap(1000.0 + slope_x * X + slope_y * Y, (0.0, 0.0), resolution)


@pytest.mark.parametrize("gradient, angle", [((0.05, 0.0), 45.0), ((0.05, 0.05), 90.0), ((0.05, -0.05), 0.0)])
def test_terrain_of_a_track_on_a_plane(gradient, angle):
    """On a plane every measure is known in closed form: the slope, the angle between the drift (+x +y) and the
    contours (0 along them, 90 across), no slope in the contours' direction, no relief beyond the trend."""
    terrain = plane(*gradient)
    tt = characterise(terrain, (10e3, 10e3, math.radians(90.0)), (0.1, 0.1), 30000.0, 0.5)
    assert tt.slope_m_per_km == pytest.approx(1e3 * math.hypot(*gradient), rel=1e-9)
    assert tt.drift_contour_angle_deg == pytest.approx(angle, abs=1e-6)
    assert tt.weakest_slope_m_per_km == pytest.approx(0.0, abs=1e-4)
    assert tt.cell_relief_m == pytest.approx(0.0, abs=1e-6)
    assert tt.flat_fraction == 0.0
    assert tt.margin_m == pytest.approx(10e3)      # the path starts 10 km from the west and south edges
    gentle = characterise(plane(0.005, 0.0), (10e3, 10e3, 0.0), (0.0, 0.0), 1000.0, 0.5)
    assert gentle.flat_fraction == 1.0            # 2.5 m across a 500 m cell: below the altimeter's 5 m


def test_terrain_measures_see_crossing_gradients_and_cell_relief():
    """Straight ridges leave one direction without slope; an egg box has slope both ways; noise at the nodes is
    relief at the cell scale."""
    rng = np.random.default_rng(0)
    xs = np.arange(0.0, 60e3 + 1, 500.0)
    X, Y = np.meshgrid(xs, xs)
    start, current = (10e3, 10e3, math.radians(30.0)), (0.1, 0.1)

    def measures(depth):
        return characterise(BathymetryMap(depth, (0.0, 0.0), 500.0), start, current, 30000.0, 0.5)

    ridges = measures(1000.0 + 100.0 * np.sin(2 * np.pi * X / 8e3))
    egg_box = 1000.0 + 50.0 * np.sin(2 * np.pi * X / 8e3) + 50.0 * np.sin(2 * np.pi * Y / 8e3)
    assert ridges.weakest_slope_m_per_km == pytest.approx(0.0, abs=1e-6)
    assert ridges.drift_contour_angle_deg == pytest.approx(45.0)
    assert measures(egg_box).weakest_slope_m_per_km > 5.0
    assert measures(egg_box + 20.0 * rng.standard_normal(X.shape)).cell_relief_m > measures(egg_box).cell_relief_m + 15.0


def test_the_along_and_across_tracks_are_the_rules_picks():
    for map_name in ("arctic", "topobathy"):
        along, across = pick_along_across(get_map(map_name))
        assert TRACKS[map_name]["drift_along"].start == pytest.approx(along)
        assert TRACKS[map_name]["drift_across"].start == pytest.approx(across)
        a = characterise(get_map(map_name), along, (0.1, 0.1), 30000.0, 0.5)
        c = characterise(get_map(map_name), across, (0.1, 0.1), 30000.0, 0.5)
        assert a.drift_contour_angle_deg < 15.0 < 60.0 < c.drift_contour_angle_deg
    shared = {name: t for name, t in TRACKS["arctic"].items() if name != "survey_pick"}
    assert shared == {name: t for name, t in TRACKS["arctic_cells"].items() if name != "survey_pick"}  # the same layout
    for tracks in TRACKS.values():
        assert tracks["paper_20_20"].start == (20e3, 20e3, 0.0) and tracks["paper_60_10"].start == (60e3, 10e3, 0.0)


def test_run_one_rows_are_tidy_and_deterministic():
    seed = np.random.SeedSequence(5).spawn(1)[0]
    rows = run_one(CONFIG, seed)

    def untimed(rs):
        return [r for r in rs if r["metric"] not in TIMING_METRICS]

    assert untimed(rows) == untimed(run_one(CONFIG, seed))  # wall-clock timings aside, bit-identical
    assert {r["filter"] for r in rows} == {"sigma_2", "fuzzy", "oracle_known_current", "dead_reckoning"}
    assert {r["case"] for r in rows} == {"arctic/paper_60_10/current_0.15"}
    assert set(rows[0]) == {"run", "case", "filter", "metric", "value"}
    summary = experiment.summary(rows)["arctic/paper_60_10/current_0.15"]
    for name in ("sigma_2", "fuzzy"):
        assert {"mean_error_m", "max_error_m", "lost", "mean_std_m", "outside_99", "step_us"} <= set(summary[name])
    assert "mean_std_m" not in summary["dead_reckoning"]  # dead reckoning claims no spread
    # the flat plain has no information: the filters drift with the current like dead reckoning (Fig. 15)
    drift = 0.15 * np.sqrt(2) * CONFIG.duration_s
    for name in ("sigma_2", "fuzzy", "dead_reckoning"):
        assert 0.7 * drift < summary[name]["final_error_m"].mean < 1.3 * drift, name
    assert summary["fuzzy"]["mean_sigma_m"].mean > 6.5
    # the matched-model oracle is given the current: no drift to absorb
    assert summary["oracle_known_current"]["final_error_m"].mean < 0.3 * drift
    assert "arctic/paper_60_10/current_0.15" in experiment.report(rows, CONFIG)


def test_a_cases_draws_do_not_depend_on_the_other_configured_cases_or_filters():
    """A subset of the campaign (one case, one filter) reproduces the full campaign's numbers for that case."""
    seed = np.random.SeedSequence(5).spawn(1)[0]
    full = TanConfig(duration_s=60.0, n_particles=50, maps=("arctic", "topobathy"), tracks=("paper_20_20", "paper_60_10"),
                     currents=("0", "0.1"), sigmas=(2.0, 3.0), fuzzy=("fuzzy",))
    subset = replace(full, maps=("topobathy",), tracks=("paper_60_10",), currents=("0.1",), sigmas=(3.0,), fuzzy=())

    def values(rows):
        return {(r["case"], r["filter"], r["metric"]): r["value"] for r in rows if r["metric"] not in TIMING_METRICS}

    small = values(run_one(subset, seed))
    large = values(run_one(full, seed))
    assert {k[1] for k in small} == {"sigma_3", "oracle_known_current", "dead_reckoning"}
    assert all(large[k] == v for k, v in small.items())


def test_outside_99_counts_the_steps_whose_truth_is_outside_the_filters_own_99_percent_ellipse():
    from scipy.stats import chi2

    rng = np.random.default_rng(4)
    T = 2000
    a, d = rng.uniform(10, 1000, T), rng.uniform(10, 1000, T)
    b = rng.uniform(-0.9, 0.9, T) * np.sqrt(a * d)
    cov = np.column_stack([a, b, d])
    error = rng.normal(0.0, 40.0, (T, 2))
    run = experiment.FilterRun(error.copy(), cov, np.zeros(T))
    run.error_xy, run.errors = error, np.hypot(*error.T)
    nees = np.array([e @ np.linalg.solve([[ai, bi], [bi, di]], e) for e, ai, bi, di in zip(error, a, b, d)])
    assert run.outside_99() == np.mean(nees > chi2.ppf(0.99, 2))
    assert 0.05 < run.outside_99() < 0.95
    metrics = run.metrics(lost_m=100.0, dt=2.0)
    assert metrics["lost"] == 1.0 and metrics["lost_at_s"] == 2.0 * (np.argmax(run.errors > 100.0) + 1)
    assert metrics["mean_std_m"] == pytest.approx(np.mean(np.sqrt(a + d)))


def test_without_a_current_there_is_no_oracle_row():
    config = TanConfig(duration_s=50.0, n_particles=50, maps=("topobathy",), tracks=("paper_60_10",), currents=("0",),
                       sigmas=(3.0,), fuzzy=())
    rows = run_one(config, np.random.SeedSequence(1).spawn(1)[0])
    assert {r["filter"] for r in rows} == {"sigma_3", "dead_reckoning"}


def _rows(lost: dict[tuple[str, str], list[bool]]) -> list[dict]:
    rows = []
    for (case, name), flags in lost.items():
        for run, flag in enumerate(flags):
            rows += [{"run": run, "case": case, "filter": name, "metric": "lost", "value": float(flag)},
                     {"run": run, "case": case, "filter": name, "metric": "mean_error_m", "value": 2000.0 if flag else 200.0}]
    return rows


def test_the_statement_at_0_1_names_the_tracks_where_a_fixed_sigma_kept_every_run_and_where_none_did():
    config = TanConfig(maps=("arctic",), tracks=("start_10_40", "drift_along"), currents=("0.1",), sigmas=(2.0, 3.0))
    rows = _rows({("arctic/start_10_40/current_0.1", "sigma_2"): [False] * 8,
                  ("arctic/start_10_40/current_0.1", "sigma_3"): [False] * 7 + [True],
                  ("arctic/drift_along/current_0.1", "sigma_2"): [True] + [False] * 7,
                  ("arctic/drift_along/current_0.1", "sigma_3"): [True] * 8})
    assert experiment.verdict(experiment.summary(rows), config) == {
        "arctic": {"tracking": {"start_10_40": ["sigma_2"]}, "none": ["drift_along"]}}
    assert experiment.lost_count(experiment.summary(rows)["arctic/start_10_40/current_0.1"]["sigma_3"]) == (1, 8)


def test_quick_is_a_shorter_smaller_campaign_that_says_so():
    default, quick = TanConfig(), TanConfig().quick()
    assert quick.duration_s < default.duration_s and quick.currents == (experiment.MAIN_CURRENT,)
    assert quick.maps == default.maps and len(quick.cases()) < len(default.cases())
    for m in quick.maps:
        assert quick.tracks_of(m) == list(experiment.QUICK_TRACKS)
    assert "--quick" in quick.settings(1, 0) and "--quick" not in default.settings(8, 0)
    # figures: the best track of each map only (the default also draws the worst and the flat-area track)
    rows = _rows({(f"{m}/{t}/current_0.1", "sigma_2"): [t == "drift_along"] for m in quick.maps
                  for t in experiment.QUICK_TRACKS})
    assert experiment.figure_cases(rows, quick) == [(m, "drift_across", "0.1") for m in quick.maps]
    assert len(experiment.figure_cases(rows, replace(quick, quick_run=False))) == 2 * len(quick.maps)


def test_the_papers_short_verdicts_are_its_quoted_claims():
    from abyssal.runtime.experiments.tan import paper

    assert set(paper.VERDICTS) <= set(paper.CLAIMS)
    for key, words in paper.VERDICTS.items():
        claim = paper.CLAIMS[key]
        first = words.split(",")[0].split("\n")[0].strip()
        assert first in claim or (first == "lost" and "exceeds 1000 m" in claim), (key, words)


def test_reproduce_tan_writes_table_json_csv_and_figures(tmp_path, capsys):
    import argparse
    import json

    from abyssal.runtime.experiments import reproduce

    config = TanConfig(duration_s=200.0, n_particles=100, maps=("arctic",), tracks=("paper_20_20", "paper_60_10"),
                       currents=("0.1",), sigmas=(2.0,), fuzzy=("fuzzy",))
    args = argparse.Namespace(runs=1, seed=0, particles=None, workers=0, scheduler=None, resume=False,
                              out=str(tmp_path), json=False, quick=False)
    assert reproduce.run("tan", args, config) == 0
    printed = capsys.readouterr().out
    assert "arctic/paper_20_20/current_0.1" in printed and "THE PAPER" in printed
    assert "AT 0.1 m/s, fixed sigma that kept every run within 1000 m" in printed
    document = json.loads((tmp_path / "tan.json").read_text())
    entry = document["cases"]["arctic/paper_60_10/current_0.1"]["fuzzy"]
    assert {"mean_error_m", "max_error_m", "lost", "step_us"} <= set(entry)
    assert entry["mean_error_m"]["n"] == 1
    assert document["tracks"]["arctic"]["paper_20_20"]["start_km"] == [20.0, 20.0]
    assert "fixed_sigma_within_lost_m_at_0.1" in document
    assert (tmp_path / "tan.csv").is_file()
    for name in ("tan_tracks.png", "tan_lost_current_0.1.png", "tan_arctic_error_spread_vs_sigma.png",
                 "tan_terrain_vs_lost.png", "tan_arctic_paper_60_10_current_0.1.png"):
        assert (tmp_path / name).is_file(), name
