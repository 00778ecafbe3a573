"""Seed 003's experiment (runtime/experiments/tan): the run_one shape, determinism, the flat-area finding."""
import numpy as np

from abyssal.runtime.experiments.campaign import TIMING_METRICS
from abyssal.runtime.experiments.tan import experiment
from abyssal.runtime.experiments.tan.experiment import TanConfig, run_one

CONFIG = TanConfig(duration_s=400.0, n_particles=200, maps=("arctic",), starts=("flat",), currents=("0.15",),
                   sigmas=(2.0,), fuzzy=("fuzzy",))


def test_run_one_rows_are_tidy_and_deterministic():
    seed = np.random.SeedSequence(5).spawn(1)[0]
    rows = run_one(CONFIG, seed)
    def untimed(rs):
        return [r for r in rs if r["metric"] not in TIMING_METRICS]

    assert untimed(rows) == untimed(run_one(CONFIG, seed))  # wall-clock timings aside, bit-identical
    assert {r["filter"] for r in rows} == {"sigma_2", "fuzzy", "oracle_known_current", "dead_reckoning"}
    assert {r["case"] for r in rows} == {"arctic/flat/current_0.15"}
    assert set(rows[0]) == {"run", "case", "filter", "metric", "value"}
    summary = experiment.summary(rows)["arctic/flat/current_0.15"]
    for name in ("sigma_2", "fuzzy", "dead_reckoning"):
        assert {"mean_error_m", "max_error_m", "lost_fraction", "step_us"} <= set(summary[name])
    # the flat plain has no information: the filters drift with the current like dead reckoning (Fig. 15)
    drift = 0.15 * np.sqrt(2) * CONFIG.duration_s
    for name in ("sigma_2", "fuzzy", "dead_reckoning"):
        assert 0.7 * drift < summary[name]["final_error_m"] < 1.3 * drift, name
    assert summary["fuzzy"]["mean_sigma_m"] > 6.5
    # the matched-model oracle is given the current: no drift to absorb
    assert summary["oracle_known_current"]["final_error_m"] < 0.3 * drift
    assert "arctic/flat/current_0.15" in experiment.report(rows, CONFIG)


def test_reproduce_tan_writes_table_json_csv_and_figures(tmp_path, capsys):
    import argparse
    import json

    from abyssal.runtime.experiments import reproduce

    config = TanConfig(duration_s=200.0, n_particles=100, maps=("arctic",), starts=("rough", "flat"), currents=("0.1",),
                       sigmas=(2.0,), fuzzy=("fuzzy",))
    args = argparse.Namespace(runs=1, seed=0, particles=None, workers=0, scheduler=None, resume=False,
                              out=str(tmp_path), json=False, quick=False)
    assert reproduce.run("tan", args, config) == 0
    printed = capsys.readouterr().out
    assert "arctic/rough/current_0.1" in printed and "THE PAPER" in printed
    document = json.loads((tmp_path / "tan.json").read_text())
    entry = document["cases"]["arctic/flat/current_0.1"]["fuzzy"]
    assert {"mean_error_m", "max_error_m", "lost_fraction", "step_us"} <= set(entry)
    assert (tmp_path / "tan.csv").is_file()
    assert (tmp_path / "tan_arctic_rough_current_0.1_paths.png").is_file()
    assert (tmp_path / "tan_arctic_rough_current_0.1_fuzzy_inputs.png").is_file()
