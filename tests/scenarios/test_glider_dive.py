"""A real dive no one here wrote: examples/glider_dive over the Slocum dive dbdreader ships (read in place).

The glider's own numbers are the references: its dead-reckoning error at surfacing (m_dr_x_ini_err, m_dr_y_ini_err,
GPS minus DR in its local mission frame) must equal its DR position (m_lat/m_lon) against the fix converted by our
geodesy (pymap3d about the pre-dive fix); its depth-averaged current (m_water_vx/vy, computed from the same fixes)
must agree with the smoothed current within two of the smoother's standard deviations; the filter's miss (when the
glider surfaced, and predicted on to the fix) must lie within three of its own standard deviations per axis; and the
README's number is this run's.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

try:
    import dbdreader  # noqa: F401
except ImportError:
    pytest.skip("skipped, because dbdreader is not installed (GPL-3, in abyssal's test extra only: pip install "
                "'abyssal[test]'); it ships the real Slocum dive this test replays", allow_module_level=True)
pytest.importorskip("pymap3d", reason="pymap3d (the replay extra) is not installed")

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "examples" / "glider_dive"))
import run as glider_dive  # noqa: E402


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    return glider_dive.main(["--out", str(tmp_path_factory.mktemp("glider")), "--no-figures"])


def test_the_log_holds_one_deep_dive_between_two_fixes(dive):
    times = dive["times"]
    assert 5000 < times["end"] - times["start"] < 6500
    assert times["fix_before"] < times["start"] < times["end"] < times["fix_after"]
    depth = dive["result"].track.x[:, 2]
    assert 550 < depth.max() < 650
    counts = dive["result"].counts
    assert counts["gps"]["used"] == 2 and counts["gps"]["skipped"] == {"before t0": counts["gps"]["received"] - 2}
    assert counts["depth"]["used"] > 1300


def test_the_glider_dead_reckoning_error_agrees_with_our_geodesy(dive):
    own = dive["glider"]
    assert 400 < own["own_error_m"] < 500
    assert abs(own["dr_error_m"] - own["own_error_m"]) < 2.0


def test_the_filter_misses_the_surfacing_fix_within_its_own_uncertainty(dive):
    at = dive["surfacing"]
    assert at["fix_status"] == "used"
    for when in ("at_surface", "at_fix"):
        assert np.all(np.abs(at[when]["predicted_minus_fix_ne"]) < 3 * np.array(at[when]["sigma_ne"]))
    readme = (ROOT / "README.md").read_text()
    assert f"{at['at_surface']['error_m']:.0f} m" in readme, "the README's glider number is not this run's: update it"


def test_the_smoothed_current_agrees_with_the_glider_own_estimate(dive):
    current, own = dive["current"], dive["glider"]
    difference = np.array(current["current_ne"]) - np.array(own["water_velocity_ne"])
    assert np.all(np.abs(difference) < 2 * np.array(current["sigma_ne"]))
