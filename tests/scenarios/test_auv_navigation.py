"""examples/auv_navigation: the evidence of "Sensors and time" (delayed fixes fused at their stamp) and of smoothing.

The example's folder is copied into a temporary project (its gen/ is written there, never into the checkout) and run
as a user runs it. What is asserted was looked at first over many seeds (40 dives of the quick mission, 20 of the full
one: docs/sensors-and-time.md): fusing the USBL fixes at their stamp beat fusing them at arrival in every dive (by
0.12 m of horizontal RMSE at least on the quick mission), the smoothed track beat the filtered one in every dive, and
fixes fused at arrival were overconfident (horizontal ANEES 5.4 against 0.8). The quick run's four dives are asked
for a majority only.

The independent NumPy EKF (examples/auv_navigation/reference_ekf.py: RK4 and its exact derivatives written out, the
model's f and h through CasADi's own Functions) must agree with abyssal's EKF to 1e-9 on the asynchronous, delayed
stream; that the comparison can fail is shown by the two handlings, which differ by centimetres, and by a mutant of
the reference that fuses a late fix at the end of the predict spanning its stamp (10-40 ms late) instead of splitting
that predict.
"""
from __future__ import annotations

import csv
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "auv_navigation"
MODULES = ("auv", "simulate", "navigate", "scoring", "reference_ekf", "run", "figure")


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    folder = tmp_path_factory.mktemp("auv_navigation")
    for source in EXAMPLE.glob("*.py"):
        shutil.copy(source, folder / source.name)
    return folder


@pytest.fixture(scope="module")
def quick(project):
    """`python run.py --quick --out out` in the copied project: its output and its tidy rows."""
    done = subprocess.run([sys.executable, "run.py", "--quick", "--out", "out"], cwd=project, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    with open(project / "out" / "runs.csv") as f:
        rows = list(csv.DictReader(f))
    return done.stdout, rows


@pytest.fixture(scope="module")
def example(project):
    """The example's modules imported from the copied project (removed from sys.modules afterwards)."""
    sys.path.insert(0, str(project))
    for name in MODULES:  # another example's module of the same name (examples/replay_log/auv.py) may be cached
        sys.modules.pop(name, None)
    try:
        import importlib

        modules = {name: importlib.import_module(name) for name in MODULES if name not in ("run", "figure")}
        yield modules
    finally:
        sys.path.remove(str(project))
        for name in MODULES:
            sys.modules.pop(name, None)


def per_seed(rows, filter_name, track, key="rmse_xy") -> dict:
    return {int(r["seed"]): float(r[key]) for r in rows if r["filter"] == filter_name and r["track"] == track}


def test_the_quick_run_prints_its_tables_and_writes_its_figure(quick, project):
    stdout, rows = quick
    assert "Oracles: none" in stdout and "Delayed USBL fixes" in stdout and "Smoothed (RTS" in stdout
    for name in ("EKF", "UKF", "CKF"):
        for label in ("at stamp", "at arrival", "dropped"):
            assert any(line.startswith(f"{name:6} {label}") for line in stdout.splitlines()), (name, label)
    assert len(rows) == 4 * 3 * 4  # seeds x filters x (stamp, arrival, dropped, smoothed)
    assert (project / "out" / "auv_navigation.png").stat().st_size > 50_000
    # every sensor reported in the fused runs, and the USBL only where it is fused
    for row in rows:
        if row["track"] in ("stamp", "arrival", "dropped"):
            assert all(int(row[f"n_{s}"]) > 0 for s in ("dvl", "depth", "ahrs", "gnss"))
            assert (int(row["n_usbl"]) > 0) == (row["track"] != "dropped")


@pytest.mark.parametrize("filter_name", ["EKF", "UKF", "CKF"])
def test_fixes_fused_at_their_stamp_beat_fixes_fused_at_arrival(quick, filter_name):
    _, rows = quick
    stamp, arrival = per_seed(rows, filter_name, "stamp"), per_seed(rows, filter_name, "arrival")
    assert sum(stamp[s] < arrival[s] for s in stamp) >= 3  # most of the 4 dives (40 of 40 seen)
    assert np.mean(list(stamp.values())) < np.mean(list(arrival.values()))
    # at arrival the filter believes fixes that are 0.3-1.4 m stale: overconfident in position
    assert np.mean(list(per_seed(rows, filter_name, "arrival", "nees_xy").values())) > \
        2 * np.mean(list(per_seed(rows, filter_name, "stamp", "nees_xy").values()))


@pytest.mark.parametrize("filter_name", ["EKF", "UKF", "CKF"])
def test_the_smoothed_track_beats_the_filtered_one(quick, filter_name):
    _, rows = quick
    filtered, smoothed = per_seed(rows, filter_name, "stamp"), per_seed(rows, filter_name, "smoothed")
    assert sum(smoothed[s] < filtered[s] for s in filtered) >= 3
    assert np.mean(list(smoothed.values())) < np.mean(list(filtered.values()))


def test_an_independent_numpy_ekf_equals_ours_on_the_asynchronous_delayed_stream(example):
    """A 60 s dive (surface with GNSS, 15 late USBL fixes, a DVL gap), fed to both filters as it arrives; x and P
    compared at every second. The fixes fused at arrival give another stream: both handlings must agree with the
    reference, and differ from each other (the check can fail)."""
    import abyssal

    simulate, navigate, auv = example["simulate"], example["navigate"], example["auv"]
    bundle = abyssal.load(abyssal.generate(auv.auv_navigation, Path(simulate.__file__).parent / "gen"))
    mission = simulate.Mission(duration=60.0, surface_time=15.0, max_depth=2.0, lock_loss=(30.0, 40.0))
    dive = simulate.simulate(bundle, 3, mission)
    x0, P0 = navigate.start(dive, 3)
    clock = dive.t[::simulate.CLOCK]
    final = {}
    for handling in ("stamp", "arrival"):
        ours = abyssal.EKF(bundle, x0, P0, np.diag(simulate.FORCE_PSD), None, noise="inputs",
                           history_seconds=navigate.HISTORY_SECONDS)
        reference = example["reference_ekf"].AsyncEKF(auv.auv_navigation(), x0, P0, np.diag(simulate.FORCE_PSD))
        for _ in zip(navigate.feed(ours, dive, handling, clock), navigate.feed(reference, dive, handling, clock)):
            assert ours.t == reference.t
            x, P = reference.x, reference.P
            assert np.abs(ours.x - x).max() <= 1e-9 * max(1.0, np.abs(x).max())
            assert np.abs(ours.P - P).max() <= 1e-9 * np.abs(P).max()
        # the comparison covered what it claims: late fixes from the history, the GNSS, no gate, no subdivided step
        assert ours.late == (ours.sensor_report("usbl")["used"] if handling == "stamp" else 0)
        assert ours.sensor_report("usbl")["used"] >= 13 and ours.sensor_report("gnss")["used"] >= 10
        assert ours.gated == ours.substeps == ours.repairs == 0
        final[handling] = ours.x
    assert np.hypot(*(final["stamp"] - final["arrival"])[6:8]) > 1e-2

    class FusedAtTheSpanningPredictsEnd(example["reference_ekf"].AsyncEKF):
        """A mutant: a late fix fused at the end of the predict that spans its stamp (10-40 ms after it)."""

        def update(self, sensor, z, t, R=None):
            if t >= self.t:
                return super().update(sensor, z, t, R)
            at = sum(1 for e in self.events if e[1] <= t)
            self.events.insert(at + 1, ("update", self.events[at][1], sensor, np.array(z, float), np.asarray(R)))
            self._run_from(at + 1)

    ours = abyssal.EKF(bundle, x0, P0, np.diag(simulate.FORCE_PSD), None, noise="inputs",
                       history_seconds=navigate.HISTORY_SECONDS)
    mutant = FusedAtTheSpanningPredictsEnd(auv.auv_navigation(), x0, P0, np.diag(simulate.FORCE_PSD))
    worst = 0.0
    for _ in zip(navigate.feed(ours, dive, "stamp", clock), navigate.feed(mutant, dive, "stamp", clock)):
        worst = max(worst, np.abs(ours.x - mutant.x).max() / max(1.0, np.abs(mutant.x).max()))
    assert worst > 1e-6  # seen: 3e-4, five orders of magnitude above the tolerance
