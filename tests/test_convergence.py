"""Resolution study (dpsi.convergence): the table-making code on two coarse grid cells, its small parts on
hand-made inputs, and (slow) the convergence of the poking dent between the chosen dx and the next finer."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from dpsi import convergence
from dpsi.heightmap import CELLS, SIZE
from dpsi.motions import get_motion
from dpsi.simulation import SimulatorConfig
from dpsi.twin_plan import MATERIALS


def test_density_keeps_two_particles_per_cell_per_axis():
    for dx in (0.008, 0.005, 0.003):
        spacing = convergence.density_for(dx) ** (-1 / 3)
        assert spacing == pytest.approx(dx / 2)
    with pytest.raises(ValueError, match="dx"):
        convergence.density_for(0.0)


def test_poke_point_is_where_the_tip_first_reaches_its_lowest_height():
    setup = convergence.Setup.make()
    for motion in convergence.MOTIONS:
        point = convergence.poke_point(setup.trajectories[motion], setup.start)
        # both motions go straight down first: the poke is under the start, 20 mm below the top
        assert point == pytest.approx(setup.start[:2], abs=1e-9)
        depth = -setup.trajectories[motion].positions[:, 2].min()
        assert depth == pytest.approx(-get_motion(motion).segments[0].amount)


def test_dent_depth_averages_the_drop_near_the_poke_only():
    centre = np.array([0.1, -0.2])
    cell = SIZE / CELLS
    axis = (np.arange(CELLS) + 0.5) * cell - SIZE / 2
    x, y = np.meshgrid(centre[0] + axis, centre[1] + axis, indexing="ij")
    poke = centre + [0.02, 0.0]
    initial = np.full((CELLS, CELLS), 0.030)
    final = initial - np.where(np.hypot(x - poke[0], y - poke[1]) <= 0.006, 0.012, 0.0)  # a 12 mm pit
    final[0, 0] = 0.08  # a bulge far away does not count
    assert convergence.dent_depth_mm(initial, final, centre, poke) == pytest.approx(12.0)
    assert convergence.dent_depth_mm(initial, initial, centre, poke) == 0.0
    with pytest.raises(ValueError, match="poke point"):
        convergence.dent_depth_mm(initial, final, centre, centre + 1.0)


def test_recommended_dx_is_the_coarsest_within_tolerance_with_every_finer_one():
    worst = {8: 900.0, 6: 250.0, 5: 350.0, 4: 120.0, 3: 0.0}
    table = pd.DataFrame([dict(motion=m, dx_mm=dx, heightmap_to_finest_mm=d * (1 if m == "a" else 0.5))
                          for m in "ab" for dx, d in worst.items()])
    assert convergence.recommended_dx_mm(table, 300.0) == 4.0  # 6 mm is within, but 5 mm is not
    assert convergence.recommended_dx_mm(table, 400.0) == 6.0
    assert convergence.recommended_dx_mm(table, 10.0) == 3.0


def test_table_of_two_coarse_resolutions(tmp_path):
    table = convergence.resolution_study([8, 10], simulator={"arch": "cpu"})
    assert list(table.columns) == convergence.COLUMNS
    assert list(zip(table.motion, table.dx_mm)) == [(m, dx) for m in convergence.MOTIONS for dx in (10.0, 8.0)]
    clay = MATERIALS["clay"]
    for dx in (10.0, 8.0):
        rows = table[table.dx_mm == dx]
        assert rows.density.tolist() == pytest.approx([(2 / (dx / 1000)) ** 3] * 2)
        assert rows.substeps.tolist() == [SimulatorConfig(dx=dx / 1000).substeps(clay)] * 2
        assert (rows.forward_s > 0).all() and (rows.peak_mem_mib > 0).all()
    coarse, fine = table[table.dx_mm == 10.0], table[table.dx_mm == 8.0]
    assert (fine.particles.to_numpy() > 1.5 * coarse.particles.to_numpy()).all()  # (10/8)³ ≈ 1.95 × as many
    distances = ["heightmap_to_finest_mm", "initial_heightmap_to_finest_mm"]
    assert (fine[distances] == 0).all().all() and (coarse[distances] > 0).all().all()
    # with two resolutions the next finer is the finest; the finest has none
    assert coarse.heightmap_to_next_finer_mm.tolist() == coarse.heightmap_to_finest_mm.tolist()
    assert fine.heightmap_to_next_finer_mm.isna().all()
    # the round effector pokes 20 mm down from the top; the clay springs back a little and the cells
    # around the poke point lie on the dent's slope, so the dent is deep but not deeper than the poke
    poking = table[table.motion == "poking-2"]
    assert ((poking.dent_depth_mm > 10) & (poking.dent_depth_mm < 21)).all()



CHOSEN_DX_MM = 1000 * yaml.safe_load((Path(__file__).parents[1] / "config" / "paper.yaml").read_text())["simulator"]["dx"]
"""The dx the resolution study recommends (docs/benchmarks.md, "Resolution study"): the paper-scale config's;
the quick default trades it for time."""

DENT_TOLERANCE_MM = 1.5
"""How much a dent may change between the chosen dx and the next finer one (see the test)."""


@pytest.mark.slow
def test_dents_converge_between_the_chosen_dx_and_the_next_finer():
    """The dent of each motion (poking-2 about 16 mm, poking-shifting-2 about 14 mm deep) changes by
    less than 1.5 mm from the chosen dx to the next finer dx of the study. The dent is read from height
    maps of particle cubes whose tops lie up to one lattice spacing (dx / 2: 2–2.5 mm here) below the true
    surface, so each dent carries about ±1 mm of lattice noise whatever the physics; 1.5 mm (~10 % of
    the dents) sits above that noise and well below the 6 mm by which the poking-shifting dent deepens
    from 6 mm to 5 mm cells."""
    finer = max(dx for dx in convergence.DX_MM if dx < CHOSEN_DX_MM)
    table = convergence.resolution_study([CHOSEN_DX_MM, finer])
    dents = table.pivot(index="motion", columns="dx_mm", values="dent_depth_mm")
    assert (dents > 3).all().all(), dents  # real dents (a height-map cell deep), not two flat maps agreeing
    change = (dents[CHOSEN_DX_MM] - dents[finer]).abs()
    assert (change < DENT_TOLERANCE_MM).all(), dents


@pytest.mark.parametrize("args, message", [
    (["--motions", "poking-9"], "argument --motions: invalid choice: 'poking-9'"),
    (["--dx", "6", "0"], "argument --dx: must be a positive number, got '0'"),
    (["--dx", "6"], "argument --dx: needs at least two different grid cells, got [6.0]"),
    (["--seed", "-1"], "argument --seed: must be an integer ≥ 0, got '-1'"),
    (["--simulator", "{cfl: 0.5}"], "argument --simulator: must be a JSON object, got '{cfl: 0.5}'"),
    (["--simulator", '{"dx": 0.004}'], "argument --simulator: unknown or fixed setting(s) ['dx']"),
    (["--simulator", '{"cfl": 2}'], "argument --simulator: cfl must lie in (0, 1], got 2"),
    (["--out", "."], "argument --out: . is a folder; give the CSV file to write"),
])
def test_bad_arguments_are_named_without_a_traceback(capsys, monkeypatch, args, message):
    monkeypatch.setattr(convergence, "resolution_study", lambda *a, **k: pytest.fail("the study started"))
    with pytest.raises(SystemExit) as exit_:
        convergence.main(args)
    error = capsys.readouterr().err
    assert exit_.value.code == 2 and message in error and "Traceback" not in error
