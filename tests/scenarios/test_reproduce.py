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
    assert ran == checked == ["rov", "cn", "cn-count", "tan", "tan-survey", "remus"]
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

    quick = experiment.CnConfig().quick()
    config = replace(quick, scenario=replace(quick.scenario, duration=200.0), n_particles=100, kld_n_max=100,
                     cases=("gaussian",), geometries=("collinear", "crossing60"), filters=("DR", "CKF", "MCUPF"),
                     tuned=("CKF",))
    assert reproduce.run("cn", _args(out=str(tmp_path)), config) == 0
    printed = capsys.readouterr().out
    assert "SIMULATED lake trial" in printed and "152.0" in printed  # the paper's CKF APE beside ours
    assert "geometry crossing60" in printed and "Wall time per filter step" in printed
    document = json.loads((tmp_path / "cn.json").read_text())
    assert document["experiment"] == "cn" and document["runs"] == 1 and document["config"] == repr(config)
    assert document["data"].startswith("simulated") and set(document["geometries"]) == {"collinear", "crossing60"}
    assert set(document["cases"]["crossing60"]["gaussian"]) == {"DR", "CKF", "MCUPF", "CKF tuned"}
    assert document["cases"]["collinear"]["gaussian"]["CKF"]["paper_ape_m"] == 152.0
    assert document["geometries"]["crossing60"]["crossing_median_deg"] > 45
    assert (tmp_path / "cn.csv").is_file()
    assert {p.name for p in tmp_path.glob("cn_*.png")} == {"cn_geometry.png", "cn_errors.png", "cn_ape.png", "cn_kld.png"}


def test_help_says_what_each_quick_version_is_from_the_experiment_itself(capsys):
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["reproduce", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for name, record in reproduce.EXPERIMENTS.items():
        doc = record.experiment_module().Config.quick.__doc__
        line = reproduce.quick_description(record)
        assert line.startswith(f"{record.quick_runs} run")
        if doc:  # the docstring's words, not a copy kept here
            assert " ".join(doc.split()).split(":")[-1].strip()[:40] in line, name
        assert f"{name} {line}" in text


def test_figures_that_take_settings_get_the_command_that_made_the_run(monkeypatch, tmp_path):
    seen = {}

    class Module:
        @staticmethod
        def figures(rows, out, config, seed, prepared, settings=None):
            seen["settings"] = settings
            return []

    class Old:
        @staticmethod
        def figures(rows, out, config, seed, prepared):
            seen["old"] = True
            return []

    reproduce._figures(Module, [{}], tmp_path, None, 4, None, "cn", True, 2)
    assert seen["settings"] == "abyssal reproduce cn --quick --runs 2 --seed 4"
    reproduce._figures(Old, [{}], tmp_path, None, 4, None, "tan", False, 2)
    assert seen["old"]


def test_tables_helper_gives_sample_sd_and_t_interval_and_keeps_inf():
    from scipy import stats

    from abyssal.runtime.experiments import tables

    values = [3.0, 5.0, 4.0, 8.0]
    r = tables.over_runs(values + [float("nan")])
    assert (r.n, r.missing) == (4, 1)
    assert r.mean == pytest.approx(5.0) and r.sd == pytest.approx(np.std(values, ddof=1))
    low, high = stats.t.interval(0.95, 3, loc=5.0, scale=stats.sem(values))
    assert r.ci95 == pytest.approx((high - low) / 2) and r.cell(".1f") == f"5.0 ± {r.sd:.1f}"
    one = tables.over_runs([2.0])
    assert one.n == 1 and np.isnan(one.sd) and one.cell(".1f") == "2.0"
    diverged = tables.over_runs([1.0, float("inf")])
    assert diverged.mean == float("inf") and np.isnan(diverged.sd)
    assert tables.over_runs([]).cell() == "-"
    mse = [0.04, 0.25]
    assert tables.pooled_rms(mse) == pytest.approx(np.sqrt(0.145)) and tables.pooled_rms(mse) > np.mean(np.sqrt(mse))
    assert tables.fraction([True, False, True]) == (2, 3)


def test_every_filter_of_an_experiment_has_its_own_colour_and_variants_keep_their_family_s():
    from abyssal.runtime import plots
    from abyssal.runtime.experiments.cn import experiment as cn
    from abyssal.runtime.experiments.rov import experiment as rov

    cn_names = tuple(cn.filter_names(cn.CnConfig()))
    families = [n for n in cn_names if not n.endswith(" tuned")]
    colours = [plots.filter_style(n, cn_names)["color"] for n in families]
    assert len(set(colours)) == len(colours)  # DR, CKF, ..., MCC-UPF: no two alike
    for name in cn_names:
        if name.endswith(" tuned"):
            base, variant = plots.filter_style(name.removesuffix(" tuned"), cn_names), plots.filter_style(name, cn_names)
            assert variant["color"] == base["color"] and variant["linestyle"] != base["linestyle"]
    rov_names = tuple(f.label for f in rov.MAIN_FILTERS + rov.N_SWEEP)
    rov_colours = {plots._family(n): plots.filter_style(n, rov_names)["color"] for n in rov_names}
    assert len(set(rov_colours.values())) == len(rov_colours)  # one colour per family, variants hatched
    # names no table lists (a fixed-sigma family) skip the colours the listed filters of the figure already have
    tan = ("fuzzy", "sigma=1 m", "sigma=2 m", "sigma=3 m")
    tan_colours = [plots.filter_style(n, tan)["color"] for n in tan]
    assert len(set(tan_colours)) == len(tan_colours)


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
