import numpy as np
import pytest

from dpsi.heightmap import interior_cells, height_map, height_map_owners, heightmap_distance_mm

CELL = 0.11 / 32  # m


def cell_centre(i, j, centre=(0.0, 0.0)):
    """Centre (x, y) in m of cell (i, j) of the default map."""
    return (centre[0] - 0.055 + (i + 0.5) * CELL, centre[1] - 0.055 + (j + 0.5) * CELL)


def test_cells_hold_highest_z_and_empty_cells_the_table_height():
    centre = (0.3, -0.1)
    points = np.array([
        [*cell_centre(2, 5, centre), 0.010],
        [*cell_centre(2, 5, centre), 0.030],
        [*cell_centre(2, 5, centre), 0.020],
        [*cell_centre(31, 0, centre), 0.005],
    ])
    hm = height_map(points, centre)
    assert hm.shape == (32, 32)
    assert hm[2, 5] == 0.030  # x indexes the first axis
    assert hm[31, 0] == 0.005
    assert np.count_nonzero(hm) == 2
    assert height_map(points, centre, floor=-1.0)[0, 0] == -1.0


def test_owners_point_at_the_highest_point():
    points = np.array([[*cell_centre(7, 7), 0.02], [*cell_centre(7, 7), 0.04], [*cell_centre(8, 7), 0.01]])
    owners = height_map_owners(points, (0.0, 0.0))
    assert owners[7, 7] == 1 and owners[8, 7] == 2
    assert (owners == -1).sum() == 32 * 32 - 2


def test_points_outside_the_square_are_ignored_and_cells_are_half_open():
    points = np.array([[0.056, 0.0, 0.05], [0.0, -0.0551, 0.05], [-0.055, -0.055, 0.02], [0.055, 0.0, 0.07]])
    hm = height_map(points, (0.0, 0.0))
    assert hm[0, 0] == 0.02  # the low corner belongs to the map
    assert np.count_nonzero(hm) == 1  # the high edge does not


def test_size_and_cells_change_the_grid():
    hm = height_map(np.array([[0.9, 0.0, 0.01]]), (0.0, 0.0), size=2.0, cells=4)
    assert hm.shape == (4, 4) and hm[3, 2] == 0.01


def test_no_points_gives_the_floor():
    assert np.all(height_map(np.zeros((0, 3)), (0.0, 0.0), floor=0.002) == 0.002)


def test_distance_is_summed_in_mm():
    a = np.zeros((32, 32))
    b = np.full((32, 32), 0.001)
    b[0, 0] = -0.002
    assert heightmap_distance_mm(a, b) == pytest.approx(1023 + 2)
    assert heightmap_distance_mm(b, b) == 0.0


@pytest.mark.parametrize("kwargs, message", [
    ({"points": np.zeros((3, 2))}, "points"),
    ({"centre_xy": (0.0, 0.0, 0.0)}, "centre_xy"),
    ({"size": 0.0}, "size"),
    ({"cells": 2.5}, "cells"),
])
def test_bad_input_is_named(kwargs, message):
    args = {"points": np.zeros((3, 3)), "centre_xy": (0.0, 0.0), **kwargs}
    with pytest.raises(ValueError, match=message):
        height_map(**args)


def test_distance_shape_mismatch():
    with pytest.raises(ValueError, match="shape"):
        heightmap_distance_mm(np.zeros((32, 32)), np.zeros((16, 16)))


def box_particles(density, lo=(-0.03, -0.02, 0.0), hi=(0.03, 0.025, 0.03)):
    """A filled box (m) on the table, particles on the fill lattice of ``density`` particles/m³."""
    a = density ** (-1 / 3)
    axes = [np.arange(lo[k] + a / 2, hi[k], a) for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3), a


@pytest.mark.parametrize("density", [1e7, 1.5e7, 4e7])
def test_a_filled_box_has_no_empty_cell_inside_its_outline(density):
    particles, a = box_particles(density)
    hm = height_map(particles, (0.0, 0.0), particle_size=a)
    xs = -0.055 + (np.arange(32) + 0.5) * CELL
    inside_x = (xs > particles[:, 0].min() - a / 2 + CELL / 2) & (xs < particles[:, 0].max() + a / 2 - CELL / 2)
    inside_y = (xs > particles[:, 1].min() - a / 2 + CELL / 2) & (xs < particles[:, 1].max() + a / 2 - CELL / 2)
    interior = hm[np.ix_(inside_x, inside_y)]
    assert interior.size > 100
    top = particles[:, 2].max() + a / 2  # the top of the highest particle cubes: the box's surface
    np.testing.assert_allclose(interior, top)
    # as points, the same particles leave whole rows of empty cells where the lattice is sparser than the map
    if a > CELL:
        assert (height_map(particles, (0.0, 0.0))[np.ix_(inside_x, inside_y)] == 0.0).any()


def test_a_particle_covers_exactly_the_cells_its_footprint_overlaps():
    centre = cell_centre(10, 20)
    hm = height_map(np.array([[centre[0] + 0.4 * CELL, centre[1], 0.01]]), (0.0, 0.0), particle_size=1.5 * CELL)
    # footprint x ∈ [cell 10 + 0.15, cell 11 + 0.65): cells 10, 11; y ∈ [cell 20 − 0.25, cell 20 + 1.25): 19, 20, 21
    assert sorted(map(tuple, np.argwhere(hm > 0))) == [(10, 19), (10, 20), (10, 21), (11, 19), (11, 20), (11, 21)]
    assert hm[10, 20] == pytest.approx(0.01 + 0.75 * CELL)


def test_negative_particle_size_is_named():
    with pytest.raises(ValueError, match="particle size"):
        height_map(np.zeros((1, 3)), (0.0, 0.0), particle_size=-0.001)


def test_interior_cells_are_inside_every_outline_and_one_cell_in():
    particles, a = box_particles(3e7)
    hm = height_map(particles, (0.0, 0.0), particle_size=a)
    shifted = height_map(particles + (2 * CELL, 0.0, 0.0), (0.0, 0.0), particle_size=a)
    inside = interior_cells(hm, floor=0.0)
    both = interior_cells(hm, shifted, floor=0.0)
    covered = hm > 0.0
    along_x, along_y = covered.sum(axis=0).max(), covered.sum(axis=1).max()  # the outline's extent in cells
    assert inside.sum() == (along_x - 2) * (along_y - 2)  # a rectangle one cell in from the outline
    assert not inside[~covered].any() and not both[shifted == 0.0].any()
    assert both.sum() == inside.sum() - 2 * (along_y - 2)  # the shift along x loses two rows of cells
    assert interior_cells(hm, floor=0.0, erosion=0).sum() == covered.sum()
    with pytest.raises(ValueError, match="at least one"):
        interior_cells(floor=0.0)
