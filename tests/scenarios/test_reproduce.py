"""`abyssal reproduce`: the registry of the four experiments, their common shape, and the one loop over them."""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import itertools
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
    # names no table lists skip the colours the listed filters of the figure already have
    other = ("fuzzy", "filter A", "filter B", "filter C")
    other_colours = [plots.filter_style(n, other)["color"] for n in other]
    assert len(set(other_colours)) == len(other_colours)
    # a swept parameter (TAN's fixed sigma) is an ordered ramp: darker to lighter, one colour per value
    ramp = [plots.filter_style(f"sigma = {v} m")["color"] for v in range(1, 7)]
    lightness = [_lab(c, "normal")[0] for c in ramp]
    assert len(set(ramp)) == 6 and lightness == sorted(lightness)


# colour vision: sRGB -> CIELAB, dichromat simulation (Machado, Oliveira & Fernandes 2009, severity 1), CIEDE2000
_DICHROMATS = {
    "normal": np.eye(3),
    "protan": np.array([[0.152286, 1.052583, -0.204868], [0.114503, 0.786281, 0.099216], [-0.003882, -0.048116, 1.051998]]),
    "deutan": np.array([[0.367322, 0.860646, -0.227968], [0.280085, 0.672501, 0.047413], [-0.011820, 0.042940, 0.968881]]),
    "tritan": np.array([[1.255528, -0.076749, -0.178779], [-0.078411, 0.930809, 0.147602], [0.004733, 0.691367, 0.303900]]),
}


def _lab(colour: str, vision: str) -> np.ndarray:
    from matplotlib.colors import to_rgb

    c = np.array(to_rgb(colour))
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    linear = np.clip(_DICHROMATS[vision] @ linear, 0.0, 1.0)
    xyz = np.array([[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750],
                    [0.0193339, 0.1191920, 0.9503041]]) @ linear / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def _delta_e2000(lab1: np.ndarray, lab2: np.ndarray) -> float:
    (L1, a1, b1), (L2, a2, b2) = lab1, lab2
    c_bar = (np.hypot(a1, b1) + np.hypot(a2, b2)) / 2
    g = 0.5 * (1 - np.sqrt(c_bar**7 / (c_bar**7 + 25**7)))
    a1, a2 = (1 + g) * a1, (1 + g) * a2
    c1, c2 = np.hypot(a1, b1), np.hypot(a2, b2)
    h1, h2 = np.degrees(np.arctan2(b1, a1)) % 360, np.degrees(np.arctan2(b2, a2)) % 360
    dh = 0.0 if c1 * c2 == 0 else (h2 - h1 + 180) % 360 - 180
    dH = 2 * np.sqrt(c1 * c2) * np.sin(np.radians(dh / 2))
    L_bar, C_bar = (L1 + L2) / 2, (c1 + c2) / 2
    h_bar = h1 + h2 if c1 * c2 == 0 else ((h1 + h2) / 2 if abs(h1 - h2) <= 180 else (h1 + h2 + 360 * (1 if h1 + h2 < 360 else -1)) / 2)
    t = (1 - 0.17 * np.cos(np.radians(h_bar - 30)) + 0.24 * np.cos(np.radians(2 * h_bar))
         + 0.32 * np.cos(np.radians(3 * h_bar + 6)) - 0.20 * np.cos(np.radians(4 * h_bar - 63)))
    sl = 1 + 0.015 * (L_bar - 50) ** 2 / np.sqrt(20 + (L_bar - 50) ** 2)
    sc, sh = 1 + 0.045 * C_bar, 1 + 0.015 * C_bar * t
    rt = -np.sin(np.radians(60 * np.exp(-(((h_bar - 275) / 25) ** 2)))) * 2 * np.sqrt(C_bar**7 / (C_bar**7 + 25**7))
    return float(np.sqrt(((L2 - L1) / sl) ** 2 + ((c2 - c1) / sc) ** 2 + (dH / sh) ** 2 + rt * ((c2 - c1) / sc) * (dH / sh)))


def test_the_palette_is_colour_blind_safe_inside_every_experiment_and_one_colour_per_filter_across_them():
    """Every two filters of one experiment differ by a CIEDE2000 distance of at least 15 in normal vision and 10 as a
    protanope, deuteranope and tritanope sees them (dichromacy, the severest case); no two filters of the four
    experiments share a colour (one colour per filter everywhere); a reference value pair checks the formula."""
    from abyssal.runtime import plots

    # Sharma, Wu & Dalal (2005), Table 1, pair 1: Delta E00 = 2.0425
    assert _delta_e2000(np.array([50.0, 2.6772, -79.7751]), np.array([50.0, 0.0, -82.7485])) == pytest.approx(2.0425, abs=1e-4)
    colours = {}
    for experiment, families in plots.FAMILIES_BY_EXPERIMENT.items():
        looks = {f: plots.filter_style(f)["color"] for f in families}
        for (f1, c1), (f2, c2) in itertools.combinations(looks.items(), 2):
            for vision in _DICHROMATS:
                distance = _delta_e2000(_lab(c1, vision), _lab(c2, vision))
                assert distance >= (15.0 if vision == "normal" else 10.0), (experiment, f1, f2, vision, round(distance, 1))
        colours.update(looks)
    methods = {f: c for f, c in colours.items() if f not in ("DR", "oracle")}
    assert len(set(methods.values())) == len(methods)


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
    assert set(document["summary"]) == {"UKF (oracle)", "UKF (Euler, 1 step)", "GP-UKF N=20", "GP-UKF (state) N=20",
                                        "UKF (oracle, measured feedback)", "UKF (Euler, 1 step, measured feedback)"}
    assert set(document["gp_per_draw"]["GP-UKF N=20"]["prediction"]) == {"draw 4", "draw 5"}   # run r: draw r mod 2
    assert np.isfinite(document["summary"]["GP-UKF N=20"]["prediction"]["mean"])
    assert document["paper"]["table4"]["GP-UKF|prediction"] == 2.86
    assert {p.name for p in tmp_path.glob("remus_*.png")} == {
        "remus_training_data.png", "remus_position_error.png", "remus_surge_error.png", "remus_rmse_vs_size.png",
        "remus_state_rmse.png"}
