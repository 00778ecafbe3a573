"""The bench sections' own arithmetic and models (benchmarks/, imported by file name as `abyssal bench` does): the
growth fit of bench_scaling, the stochastic-cloning model of bench_sensors against the in-order run,
`abyssal bench DIR` on a folder with several sensors, and the README's block written from a recorded report
(write_readme.py). No timing is asserted here."""
from __future__ import annotations

import copy
import json
import math
import re

import numpy as np
import pytest

import bench_folder  # benchmarks/ ([tool.pytest.ini_options] pythonpath)
import bench_scaling
import bench_sensors


def test_growth_is_the_least_squares_exponent_of_a_power_law():
    assert bench_scaling.growth([(n, 3.0 * n ** 1.7) for n in (6, 12, 18, 24)]) == pytest.approx(1.7, abs=1e-12)
    # a constant factor per point does not change the slope; a missing or non-positive value is left out
    noisy = [(6, 2.0 * 6 ** 2), (12, 2.0 * 12 ** 2), (18, None), (24, 0.0), (30, 2.0 * 30 ** 2)]
    assert bench_scaling.growth(noisy) == pytest.approx(2.0, abs=1e-12)
    assert bench_scaling.growth([(6, 1.0)]) is None and bench_scaling.growth([(6, 1.0), (6, 2.0)]) is None
    # least squares through log-log points (not the end points' slope)
    points = [(1, 1.0), (2, 4.0), (4, 8.0)]
    xs, ys = np.log([1, 2, 4]), np.log([1.0, 4.0, 8.0])
    assert bench_scaling.growth(points) == pytest.approx(np.polyfit(xs, ys, 1)[0], rel=1e-12)


def test_the_chain_family_has_n_states_and_a_sensor_per_angle():
    model = bench_scaling.pendulum_chain(6)
    assert (model.n_x, model.n_u, model.n_w, model.n_y) == (6, 3, 3, 3)
    with pytest.raises(ValueError, match="even number"):
        bench_scaling.pendulum_chain(7)


@pytest.fixture(scope="module")
def linear(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bench-sensors")
    bundle = bench_sensors.load(bench_sensors.linear_cv_sensors, folder)
    aug = bench_sensors.load(lambda: bench_sensors.cloned(bench_sensors.linear_cv_sensors(), "usbl"), folder)
    return bundle, aug


def test_the_cloned_model_holds_the_clone_and_measures_it(linear):
    bundle, aug = linear
    n = bundle.n_x
    assert aug.n_x == 2 * n and aug.n_w == bundle.n_w
    assert aug.sensor_names == bundle.sensor_names + ("usbl_clone",)
    rng = np.random.default_rng(0)
    x, u = rng.normal(size=2 * n), rng.normal(size=bundle.n_u)
    x_next = aug.f(x, u, None, 0.05)
    np.testing.assert_array_equal(x_next[n:], x[n:])  # f_aug = [f(x); x_c]: the clone is held exactly
    np.testing.assert_allclose(x_next[:n], bundle.f(x[:n], u, None, 0.05), rtol=0, atol=1e-15)
    G = aug.G(x, u, None, 0.05)
    assert np.all(G[n:] == 0) and np.allclose(G[:n], bundle.G(x[:n], u, None, 0.05), rtol=0, atol=1e-15)
    y = aug.h(x)
    usbl, clone = bench_sensors.rows_of(aug, "usbl"), bench_sensors.rows_of(aug, "usbl_clone")
    np.testing.assert_array_equal(y[clone], bundle.h(x[n:])[bench_sensors.rows_of(bundle, "usbl")])
    np.testing.assert_array_equal(y[usbl], bundle.h(x[:n])[bench_sensors.rows_of(bundle, "usbl")])


def test_cloning_and_replay_equal_the_in_order_run_on_the_linear_model(linear):
    """Delayed USBL fixes (1 s late at 20 Hz): fused by stochastic cloning with the EKF on the cloned model, and from
    the filter's history, both give the in-order run's state and covariance (the Kalman filter is exact here)."""
    bundle, aug = linear
    sc = bench_sensors.scenario(bundle, ("dvl",), "usbl", 8.0, seed=3)
    assert len(sc.fixes) == 3
    runs = bench_sensors.delayed_fix_runs(bundle, aug, sc)
    assert runs["late"] == len(sc.fixes)
    assert runs["replay_vs_in_order"]["x_rel"] <= 1e-12 and runs["replay_vs_in_order"]["P_rel"] <= 1e-12
    assert runs["cloning_vs_in_order"]["x_rel"] <= 1e-10 and runs["cloning_vs_in_order"]["P_rel"] <= 1e-10
    # the comparison means something: before a fix arrives, the late runs differ from the in-order one
    (x_ref, _), (x_late, _) = runs["in_order"][:2], runs["replay"][:2]
    _, j, k_arrival, _ = sc.fixes[0]
    assert np.abs(x_late[j + 1] - x_ref[j + 1]).max() > 1e-6
    assert math.isfinite(runs["cloning_vs_in_order"]["x_rel"])


def test_bench_folder_times_every_kalman_filter_and_each_sensor(linear, capsys, monkeypatch):
    """`abyssal bench DIR` on a folder with two sensors: every Kalman filter's step, each sensor's h and update."""
    bundle, _ = linear
    monkeypatch.setattr(bench_folder, "PARTICLES", (100,))
    assert bench_folder.main([str(bundle.folder)], json_output=True, quick=True) == 0
    (result,) = json.loads(capsys.readouterr().out)
    assert set(result["per_step"]) == {"EKF", "UKF", "CKF", "MCUKF", "HuberUKF"}
    assert set(result["per_sensor"]) == {"dvl", "usbl"} and {"dvl_h", "usbl_h"} <= set(result["per_call"])
    assert all(math.isfinite(row["step_us"]) and row["step_us"] > 0 for row in result["per_step"].values())


# ------------------------------------------------------------------------------------------- the README's block
RECORDED = {
    "machine": {"python": "3.11.2", "cpu": "x86_64", "cpu_model": "AMD EPYC 9R14", "cores": 2,
                "load_start": [1.5, 2.0, 2.5], "load_end": [3.0, 2.5, 2.25], "date_start": "2026-12-04 06:40 UTC",
                "date_end": "2026-12-04 07:20 UTC", "commit": "abc1234", "command": "abyssal bench"},
    "sections": {
        "particles": {"results": {"instructions_per_step": {"CPF N=100": {"total": 4928306.75, "libmvec": 395447.0}}},
                      "targets": [{"name": "CPF N=100 step over 1dd3f6b's", "value": 0.61, "limit": 0.7, "unit": "x",
                                   "direction": "<=", "met": True},
                                  {"name": "MCUPF cn step over 1dd3f6b's", "value": 0.85, "limit": 0.7, "unit": "x",
                                   "direction": "<=", "met": False, "note": "load 9"}]},
        "filters": {"results": {"instructions_per_step_callgrind": {"total": 12345.0},
                                "filter_object_bytes": {"CKF": 4096}},
                    "targets": [{"name": "CKF speed-up over filterpy", "value": 512.0, "limit": 300.0, "unit": "x",
                                 "direction": ">=", "met": True}]},
        "sir": {"results": {"floor": {"bytes/particle (no resampling)": 248},
                            "instructions_per_particle": {"step": 812.5, "f kernel (and h)": 402.25}},
                "targets": []},
    },
}


def test_the_readme_block_is_written_from_a_recorded_report(tmp_path):
    import write_readme

    recorded = copy.deepcopy(RECORDED)
    report = tmp_path / "bench.json"
    report.write_text(json.dumps(recorded))
    readme = tmp_path / "README.md"
    readme.write_text("# benchmarks\n\nThe intro.\n\n## An older run\n\nits numbers\n")
    assert write_readme.main([str(report), "--readme", str(readme)]) == 0
    text = readme.read_text()
    assert text.startswith("# benchmarks\n\nThe intro.\n\n" + write_readme.BEGIN)
    assert text.rstrip().endswith("## An older run\n\nits numbers")  # the history stays below the block
    inside = text.split(write_readme.BEGIN)[1].split(write_readme.END)[0]
    # the command that wrote it, the run's command and commit, the machine
    assert f"python benchmarks/write_readme.py {report}" in inside
    assert "`abyssal bench`" in inside and "commit abc1234" in inside
    assert "AMD EPYC 9R14, 2 cores" in inside and "1.50 / 2.00 / 2.50" in inside and "2026-12-04 07:20 UTC" in inside
    # every target with its value, limit and verdict
    assert "| particles | CPF N=100 step over 1dd3f6b's | 0.61 x | <= 0.7 x | met |" in inside
    assert "| particles | MCUPF cn step over 1dd3f6b's (load 9) | 0.85 x | <= 0.7 x | **missed** |" in inside
    assert "| filters | CKF speed-up over filterpy | 512 x | >= 300 x | met |" in inside
    assert "2 of 3 targets met." in inside
    # the floors as counted: per particle (SIR) and per Kalman step
    assert "| SIR step: bytes/particle (no resampling) | 248 B |" in inside
    assert "| SIR step: instructions per particle, step | 812.5 |" in inside
    assert "| CKF step from Python: instructions, total | 12,345 |" in inside
    assert "| CPF N=100 step from Python: instructions, total | 4,928,307 |" in inside
    # written again from another report: the block is replaced, the rest untouched
    recorded["machine"]["commit"] = "def5678"
    report.write_text(json.dumps(recorded))
    write_readme.main([str(report), "--readme", str(readme)])
    again = readme.read_text()
    assert again.count(write_readme.BEGIN) == 1 and "commit def5678" in again and "commit abc1234" not in again
    assert again.replace("def5678", "abc1234") == text


def test_several_reports_take_each_section_from_the_first_that_holds_it(tmp_path):
    import write_readme

    main_run = copy.deepcopy(RECORDED)
    main_run["machine"]["command"] = "abyssal bench --only particles,sir"
    del main_run["sections"]["filters"]
    quick = copy.deepcopy(RECORDED)
    quick["machine"].update(command="abyssal bench --quick", commit="0123abc")
    quick["sections"]["particles"]["targets"][0]["value"] = 0.99  # (shadowed by the first report's)
    paths = []
    for name, report in (("main.json", main_run), ("quick.json", quick)):
        paths.append(tmp_path / name)
        paths[-1].write_text(json.dumps(report))
    readme = tmp_path / "README.md"
    readme.write_text("# benchmarks\n\nThe intro.\n")
    write_readme.main([str(p) for p in paths] + ["--readme", str(readme)])
    inside = readme.read_text().split(write_readme.BEGIN)[1].split(write_readme.END)[0]
    assert "1. `abyssal bench --only particles,sir`, commit abc1234: sections particles, sir;" in inside
    assert "2. `abyssal bench --quick`, commit 0123abc: sections filters;" in inside
    assert "| particles (run 1) | CPF N=100 step over 1dd3f6b's | 0.61 x |" in inside and "0.99" not in inside
    assert "| filters (run 2) | CKF speed-up over filterpy | 512 x |" in inside
    assert "| CKF step from Python: instructions, total | 12,345 |" in inside

def test_the_committed_readme_block_names_its_command_and_commit():
    import write_readme

    text = write_readme.README.read_text()
    assert text.count(write_readme.BEGIN) == 1 and text.count(write_readme.END) == 1
    inside = text.split(write_readme.BEGIN)[1].split(write_readme.END)[0]
    assert "python benchmarks/write_readme.py " in inside and "`abyssal bench" in inside
    assert re.search(r"commit [0-9a-f]{7}", inside) and "targets met." in inside
    assert text.index(write_readme.END) < text.index("## Generated code")  # the history stays below it
