"""`abyssal reproduce`: the registry of the four experiments, their common shape, and the one loop over them."""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import warnings
from dataclasses import replace

import numpy as np
import pytest

from abyssal.runtime import cli
from abyssal.runtime.experiments import reproduce
from abyssal.runtime.extras import MissingExtraError


def _args(**changes) -> argparse.Namespace:
    base = dict(experiment="cn", runs=1, seed=0, particles=None, workers=0, scheduler=None, resume=False, quick=False,
                out=None, json=False)
    return argparse.Namespace(**{**base, **changes})


@pytest.mark.parametrize("name", list(reproduce.EXPERIMENTS))
def test_every_experiment_has_paper_scenario_and_experiment_modules_of_one_shape(name):
    record = reproduce.EXPERIMENTS[name]
    module = record.experiment_module()
    package = module.__name__.rsplit(".", 1)[0]
    for part in ("paper", "scenario"):
        importlib.import_module(f"{package}.{part}")
    assert dataclasses.is_dataclass(module.Config)
    default = module.Config()
    quick = default.quick()
    assert isinstance(quick, module.Config) and quick != default  # --quick changes something
    for function in ("run_one", "report", "figures", "document"):
        assert callable(getattr(module, function)), function
    assert isinstance(module.EXTRA_COLUMNS, tuple)
    assert callable(getattr(module, "prepare", None)) == record.prepare
    if record.timings_apart:
        assert callable(module.timing_table)
    if record.particles:
        assert "n_particles" in {f.name for f in dataclasses.fields(module.Config)}


def test_the_cli_takes_every_registered_experiment_and_all(capsys):
    parser = cli.build_parser()
    for name in [*reproduce.EXPERIMENTS, "all"]:
        assert parser.parse_args(["reproduce", name]).experiment == name
    with pytest.raises(SystemExit):
        parser.parse_args(["reproduce", "nope"])
    assert "{" + ",".join([*reproduce.EXPERIMENTS, "all"]) + "}" in capsys.readouterr().err  # and offers no other


def test_all_runs_the_registry_in_order_and_exits_with_the_worst_status(monkeypatch):
    ran, checked = [], []
    monkeypatch.setattr(reproduce, "_check_needs", lambda experiment, args: checked.append(experiment.name))
    monkeypatch.setattr(reproduce, "run", lambda name, args: ran.append(name) or (1 if name == "tan" else 0))
    assert reproduce.main(_args(experiment="all")) == 1
    assert ran == checked == ["rov", "cn", "tan", "remus"]
    ran.clear()
    assert reproduce.main(_args(experiment="cn")) == 0 and ran == ["cn"]


def test_a_missing_package_stops_all_before_the_first_run(monkeypatch):
    import abyssal.runtime.extras as extras

    real = extras.importlib.import_module

    def without_sklearn(name, *a):
        if name.split(".")[0] == "sklearn":
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return real(name, *a)

    monkeypatch.setattr(extras.importlib, "import_module", without_sklearn)
    ran = []
    monkeypatch.setattr(reproduce, "run", lambda name, args: ran.append(name) or 0)
    with pytest.raises(MissingExtraError, match="scikit-learn"):
        reproduce.main(_args(experiment="all"))
    assert ran == []  # rov, cn and tan did not run for hours first


@pytest.mark.parametrize("changes,message", [({"particles": 5}, "--particles >= 10"), ({"runs": 0}, "--runs >= 1")])
def test_flags_are_checked_before_the_campaign(changes, message):
    with pytest.raises(ValueError, match=message):
        reproduce.run("cn", _args(**changes))


def test_reproduce_cn_writes_its_table_json_csv_and_figures(tmp_path, capsys):
    from abyssal.runtime.experiments.cn import experiment

    config = replace(experiment.CnConfig().quick(), n_particles=100, kld_n_max=100, cases=("gaussian",),
                     filters=("DR", "CKF", "MCUPF"), tuned=("CKF",))
    assert reproduce.run("cn", _args(out=str(tmp_path)), config) == 0
    printed = capsys.readouterr().out
    assert "SIMULATED lake trial" in printed and "152.0" in printed  # the paper's CKF APE beside ours
    document = json.loads((tmp_path / "cn.json").read_text())
    assert document["experiment"] == "cn" and document["runs"] == 1 and document["config"] == repr(config)
    assert document["data"].startswith("simulated") and set(document["cases"]["gaussian"]) == {"DR", "CKF", "MCUPF", "CKF tuned"}
    assert document["cases"]["gaussian"]["CKF"]["paper_ape_m"] == 152.0
    assert (tmp_path / "cn.csv").is_file() and (tmp_path / "cn_gaussian.png").is_file()


def test_reproduce_remus_prepares_the_gps_then_runs_the_campaign(tmp_path, capsys, monkeypatch):
    pytest.importorskip("sklearn")
    from abyssal.runtime.experiments.remus import experiment

    monkeypatch.setattr(experiment, "PREDICTION_STARTS", (20, 30))
    config = experiment.RemusConfig(duration=60.0, sizes=(20,), draws=(4, 5), full_state_sizes=(20,), hyper_max=20,
                                    readings=("oracle", "euler"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # scikit-learn's convergence warnings on 20 points
        assert reproduce.run("remus", _args(out=str(tmp_path), particles=500, runs=2), config) == 0  # --particles: ignored
    printed = capsys.readouterr().out
    assert "Table 3, UKF readings" in printed and "2.424" in printed  # the paper's UKF x RMSE, quoted
    assert "ORACLE" in printed and "BETWEEN training draws" in printed
    document = json.loads((tmp_path / "remus.json").read_text())
    assert document["duration_s"] == 60.0 and document["runs"] == 2
    assert set(document["summary"]) == {"UKF (oracle)", "UKF (Euler, 1 step)", "GP-UKF N=20", "GP-UKF (state) N=20"}
    assert set(document["gp_per_draw"]["GP-UKF N=20"]["prediction"]) == {"draw 4", "draw 5"}   # run r: draw r mod 2
    assert np.isfinite(document["summary"]["GP-UKF N=20"]["prediction"]["mean"])
    assert document["paper"]["table4"]["GP-UKF|prediction"] == 2.86
    assert {p.name for p in tmp_path.glob("remus_*.png")} == {
        "remus_training_data.png", "remus_position_error.png", "remus_surge_error.png", "remus_rmse_vs_size.png",
        "remus_state_rmse.png"}
