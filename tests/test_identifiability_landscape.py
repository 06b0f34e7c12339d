"""The identifiability ladder's landscapes around the truth: which parameters fit the data as well as the
truth does, on a made-up landscape, on R0 of the tiny poked block, and drawn."""

import numpy as np
import pytest

from dpsi.identifiability import SCAN_FACTORS, scan_values
from dpsi.identifiability_landscape import COLUMNS, PAIR, as_good_as_truth, truth_landscape
from dpsi.landscapes import Landscape, fixed_cell
from dpsi.parameters import LEVEL1_FIXED
from dpsi.reporting.landscapes import plot_truth_landscapes
from test_identifiability import rung0  # noqa: F401  (the fixture)
from test_identification import TRUTH


def valley(truth=TRUTH) -> Landscape:
    """A landscape over (E, σ_y) around ``truth``: loss 1 mm at the truth, rising steeply along σ_y and gently
    along E; one cell (2 E, 1.4 σ_y) fits better than the truth, one (4 E, 4 σ_y) failed."""
    e, s = scan_values("E", truth.E), scan_values("yield_stress", truth.yield_stress)
    f_e, f_s = np.log(e / truth.E), np.log(s / truth.yield_stress)
    values = 1.0 + 0.2 * np.abs(f_e)[:, None] + 10.0 * np.abs(f_s)[None, :]
    values[list(e).index(2 * truth.E), list(s).index(1.4 * truth.yield_stress)] = 0.9
    values[-1, -1] = np.nan
    return Landscape(PAIR, ("prt_cd", "heightmap_interior"), e, s, np.stack([values, values + 5.0]), truth)


def test_the_cells_as_good_as_the_truth_reach_as_far_as_the_better_cell():
    table = as_good_as_truth(valley()).set_index(["loss", "parameter"])
    assert list(table.reset_index().columns) == list(COLUMNS)
    e, s = table.loc[("prt_cd", "E")], table.loc[("prt_cd", "yield_stress")]
    assert (e.as_good_from, e.as_good_to) == pytest.approx((1.0, 2.0))
    assert (s.as_good_from, s.as_good_to) == pytest.approx((1.0, 1.4))
    assert e["argmin"] == pytest.approx(2 * TRUTH.E) and s["argmin"] == pytest.approx(1.4 * TRUTH.yield_stress)
    assert e.loss_at_truth_mm == pytest.approx(1.0) and e.loss_min_mm == pytest.approx(0.9)
    assert e.as_good_cells == 2 and e.cells == len(SCAN_FACTORS) ** 2 - 1
    strain = table.loc[("prt_cd", "yield_stress/E")]  # the better cell's yield strain is 0.7 × the truth's
    assert (strain.as_good_from, strain.as_good_to) == pytest.approx((0.7, 1.0))
    assert strain.truth == pytest.approx(TRUTH.yield_stress / TRUTH.E)
    assert table.loc[("heightmap_interior", "E"), "loss_at_truth_mm"] == pytest.approx(6.0)


def test_a_landscape_without_the_truth_on_its_grid_is_refused():
    landscape = valley()
    with pytest.raises(ValueError, match="E axis does not hold"):
        as_good_as_truth(Landscape(PAIR, landscape.losses, landscape.first * 1.01, landscape.second,
                                   landscape.values, TRUTH))
    assert fixed_cell(landscape) == (SCAN_FACTORS.index(1.0), SCAN_FACTORS.index(1.0))


def test_on_rung_0_only_the_truth_fits_as_well_as_the_truth(rung0):
    simulator, training, _ = rung0
    landscape = truth_landscape(simulator, training[:1], TRUTH, ["prt_cd", "heightmap_interior"])
    assert landscape.fixed == TRUTH.replace(**LEVEL1_FIXED)
    np.testing.assert_allclose(landscape.first / TRUTH.E, SCAN_FACTORS)
    assert np.isfinite(landscape.values).all()
    table = as_good_as_truth(landscape)
    assert len(table) == 2 * 3 and (table.loss_at_truth_mm < 1e-9).all() and (table.as_good_cells == 1).all()
    assert (table.as_good_from == 1.0).all() and (table.as_good_to == 1.0).all()
    assert np.allclose(table.argmin, table.truth)


def test_ladder_landscapes_are_drawn_relative_to_the_truth(tmp_path):
    landscape = valley()
    plot_truth_landscapes([("R0, 1-round", landscape), ("R1, 1-round", landscape)], tmp_path / "f.png",
                          tmp_path / "f.pdf")
    assert (tmp_path / "f.png").stat().st_size > 10_000 and (tmp_path / "f.pdf").stat().st_size > 5_000
