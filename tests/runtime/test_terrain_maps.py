"""The synthetic map with relief at the 500 m cell (runtime/terrain/maps.py, MAPS["arctic_cells"])."""
import numpy as np
import pytest

from abyssal.runtime.terrain import MAPS, synthetic_arctic
from abyssal.runtime.terrain.maps import _smoothed, _von_karman


@pytest.fixture(scope="module")
def maps():
    return synthetic_arctic(0), MAPS["arctic_cells"](0)


def second_difference_rms(depth: np.ndarray) -> float:
    """rms of the depth's second difference between neighbouring nodes along x (m): relief at the cell scale."""
    return float(np.sqrt(np.mean(np.diff(depth, 2, axis=1) ** 2)))


def test_the_cell_relief_map_is_the_arctic_layout_with_relief_down_to_the_cell(maps):
    smooth, cells = maps
    assert cells.name == "arctic_cells" and "von Karman" in cells.notes[0]
    assert cells.shape == smooth.shape == (121, 281) and cells.resolution == 500.0 and cells.extent == smooth.extent
    assert MAPS["arctic_cells"](0).depth.tobytes() == cells.depth.tobytes()  # seeded
    assert MAPS["arctic_cells"](1).depth.tobytes() != cells.depth.tobytes()
    # the same layout: the plain east of the slope is the same map, the slope's relief differs
    east, west = slice(130, None), slice(0, 80)
    np.testing.assert_allclose(cells.depth[:, east], smooth.depth[:, east], atol=0.05)
    assert np.abs(cells.depth[:, west] - smooth.depth[:, west]).std() > 20.0
    # relief at the cell scale: neighbouring nodes' second difference several times the smooth map's
    assert second_difference_rms(cells.depth[:, west]) > 2.0 * second_difference_rms(smooth.depth[:, west])
    # the bank on the slope keeps its flat top (1250 m, 1 m of relief) on both maps (cf. the paper's Fig. 12)
    top = (np.abs(smooth.depth - 1250.0) < 3.0) & (np.abs(cells.depth - 1250.0) < 3.0)
    assert top.sum() > 100


def _structure_exponent(field: np.ndarray, lags=(1, 2, 4, 8)) -> float:
    lags = np.asarray(lags)
    structure = [np.mean((field[:, lag:] - field[:, :-lag]) ** 2) for lag in lags]
    return float(np.polyfit(np.log(lags), np.log(structure), 1)[0])


@pytest.mark.parametrize("hurst", [0.5, 0.8])
def test_von_karman_relief_has_the_power_law_structure_function(hurst):
    """Well below the corner wavelength the field's structure function grows as lag^(2 H) (a rough, fractal
    surface); the smooth map's Gaussian-correlated field grows as lag^2 (a differentiable one)."""
    white = np.random.default_rng(3).standard_normal((512, 512))
    field = _von_karman(white, 256.0, hurst)
    assert field.std() == pytest.approx(1.0)
    assert _structure_exponent(field) == pytest.approx(2 * hurst, abs=0.2)
    assert _structure_exponent(_smoothed(white, 2.5), lags=(1, 2)) > 1.8
