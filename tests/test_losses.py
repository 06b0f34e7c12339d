import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from dpsi.heightmap import height_map, height_map_owners
from dpsi.losses import (
    LOSSES, HeightMapTarget, Targets, bench_emd, bench_sets, chamfer, earth_movers, heightmap_loss, loss_by_name,
    neg_heightmap_loss, validation_metrics,
)

H = 1e-7  # m, finite-difference step


def random_sets(n=20, m=15, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.0, 0.05, (n, 3)), rng.uniform(0.0, 0.05, (m, 3))


def chamfer_pairs(sim, target):
    return tuple(cKDTree(target).query(sim)[1]) + tuple(cKDTree(sim).query(target)[1])


def emd_pairs(sim, target):
    return tuple(linear_sum_assignment(cdist(target, sim))[1])


def finite_difference(loss, sim, target, pairs):
    """Central differences of loss value (mm) per m, checking the correspondences never change."""
    base = pairs(sim, target)
    gradient = np.zeros_like(sim)
    for index in np.ndindex(*sim.shape):
        values = []
        for sign in (1.0, -1.0):
            moved = sim.copy()
            moved[index] += sign * H
            assert pairs(moved, target) == base, "a correspondence flipped; the check would be meaningless"
            values.append(loss(moved, target)[0])
        gradient[index] = (values[0] - values[1]) / (2 * H)
    return gradient


@pytest.mark.parametrize("loss, pairs, m", [(chamfer, chamfer_pairs, 25), (chamfer, chamfer_pairs, 8),
                                            (earth_movers, emd_pairs, 15), (earth_movers, emd_pairs, 20)])
def test_gradient_matches_finite_differences(loss, pairs, m):
    sim, target = random_sets(m=m)
    value, gradient = loss(sim, target)
    assert value > 0 and gradient.shape == sim.shape
    numeric = finite_difference(loss, sim, target, pairs)
    np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-3)
    assert np.abs(gradient).max() > 500  # not trivially zero


def heightmap_setup(seed=1):
    rng = np.random.default_rng(seed)
    sim = np.column_stack([rng.uniform(-0.05, 0.05, (60, 2)), rng.uniform(0.0, 0.04, 60)])
    target = HeightMapTarget(rng.uniform(0.0, 0.04, (4, 4)), np.zeros(2))  # 2.75 cm cells, ~4 points each
    return sim, target


def test_heightmap_gradient_matches_finite_differences():
    sim, target = heightmap_setup()
    owners = lambda points, t: tuple(height_map_owners(points, t.centre_xy, cells=4).ravel())  # noqa: E731
    value, gradient = heightmap_loss(sim, target)
    numeric = finite_difference(heightmap_loss, sim, target, owners)
    np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-3)
    held = height_map_owners(sim, target.centre_xy, cells=4).ravel()
    assert np.count_nonzero(gradient) == 16  # one z per cell, each ±1000 mm/m
    assert set(np.flatnonzero(gradient[:, 2])) == set(held)
    assert np.all(np.abs(gradient[held, 2]) == 1000.0)
    assert value == pytest.approx(1000 * np.abs(height_map(sim, target.centre_xy, cells=4) - target.heights).sum())


def test_neg_heightmap_is_the_negation():
    sim, target = heightmap_setup()
    value, gradient = heightmap_loss(sim, target)
    neg_value, neg_gradient = neg_heightmap_loss(sim, target)
    assert neg_value == -value < 0
    np.testing.assert_array_equal(neg_gradient, -gradient)


def test_identical_sets_give_zero():
    sim, _ = random_sets()
    for loss in (chamfer, earth_movers):
        value, gradient = loss(sim, sim.copy())
        assert value == 0.0 and not gradient.any()
    target = HeightMapTarget(height_map(sim, (0.02, 0.02)), (0.02, 0.02))
    assert heightmap_loss(sim, target)[0] == 0.0


def test_emd_of_a_translation_is_n_times_the_shift():
    sim, _ = random_sets(n=30)
    shift = np.array([0.003, -0.004, 0.012])  # 13 mm, larger than the point spacing
    value, gradient = earth_movers(sim, sim - shift)
    assert value == pytest.approx(30 * 13.0)
    np.testing.assert_allclose(gradient, np.tile(shift / 0.013 * 1000, (30, 1)))


def test_chamfer_of_a_small_translation_of_a_grid():
    grid = np.stack(np.meshgrid(*[np.arange(4) * 0.01] * 3), axis=-1).reshape(-1, 3)
    value, _ = chamfer(grid + [0.001, 0, 0], grid)
    assert value == pytest.approx(2 * 64 * 1.0)


def test_chamfer_hand_example():
    value, gradient = chamfer([[0.0, 0.0, 0.0]], [[0.003, 0.0, 0.0], [0.0, 0.004, 0.0]])
    assert value == pytest.approx(3 + 3 + 4)
    np.testing.assert_allclose(gradient, [[-2000.0, -1000.0, 0.0]])


def test_emd_hand_example_with_fewer_targets():
    value, gradient = earth_movers([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0]], [[0.009, 0.0, 0.0]])
    assert value == pytest.approx(1.0)
    np.testing.assert_allclose(gradient, [[0.0, 0.0, 0.0], [1000.0, 0.0, 0.0]])


def test_emd_needs_no_more_targets_than_particles():
    sim, target = random_sets(n=5, m=6)
    with pytest.raises(ValueError, match="6 target and 5 simulated"):
        earth_movers(sim, target)


def test_non_finite_simulation_gives_nan():
    sim, target = random_sets()
    sim[3, 1] = np.nan
    for loss in (chamfer, earth_movers):
        value, gradient = loss(sim, target)
        assert np.isnan(value) and np.isnan(gradient).all()


def test_bad_shapes_and_targets_are_named():
    with pytest.raises(ValueError, match="simulated points"):
        chamfer(np.zeros((4, 2)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="target points: contains non-finite"):
        chamfer(np.zeros((4, 3)), np.full((4, 3), np.inf))


def test_registry_maps_names_to_distance_and_target():
    sim, pcd = random_sets(seed=2)
    _, prt = random_sets(seed=3)
    targets = Targets(pcd=pcd, prt=prt, heightmap=HeightMapTarget(np.zeros((32, 32)), (0.0, 0.0)))
    assert set(LOSSES) == {"pcd_cd", "prt_cd", "pcd_emd", "prt_emd", "heightmap", "neg_heightmap", "heightmap_interior"}
    assert loss_by_name("pcd_cd")(sim, targets)[0] == chamfer(sim, pcd)[0]
    assert loss_by_name("prt_cd")(sim, targets)[0] == chamfer(sim, prt)[0]
    assert loss_by_name("pcd_emd")(sim, targets)[0] == earth_movers(sim, pcd)[0]
    assert loss_by_name("prt_emd")(sim, targets)[0] == earth_movers(sim, prt)[0]
    assert loss_by_name("heightmap")(sim, targets)[0] == -loss_by_name("neg_heightmap")(sim, targets)[0] > 0


def test_unknown_loss_and_missing_target():
    with pytest.raises(ValueError, match="unknown loss 'l2'.*prt_emd"):
        loss_by_name("l2")
    with pytest.raises(ValueError, match="'prt'"):
        loss_by_name("prt_emd")(np.zeros((3, 3)), Targets(pcd=np.zeros((3, 3))))


def test_validation_metrics():
    sim, _ = random_sets(n=30)
    shift = np.array([0.0, 0.0, 0.002])
    real_map = height_map(sim, (0.0, 0.0))
    metrics = validation_metrics(sim, sim[:10], sim - shift, real_map, (0.0, 0.0))
    assert set(metrics) == {"pcd_cd", "prt_cd", "pcd_emd", "prt_emd", "heightmap_mm"}
    assert metrics["pcd_emd"] == 0.0 and metrics["heightmap_mm"] == 0.0
    assert metrics["prt_emd"] == pytest.approx(30 * 2.0)
    assert metrics["pcd_cd"] > 0  # the 20 particles not in the PCD target are away from it


def test_benchmark_sets_and_their_distances():
    """The benchmarked sets are a 6 cm cube and its 3 mm jitter; on them the optimal assignment costs
    no more than the jitter itself (the identity assignment), and each Chamfer term no more than it."""
    sim, target = bench_sets(n=200)
    assert sim.min() >= 0.0 and sim.max() <= 0.06
    assert np.std(target - sim) == pytest.approx(0.003, rel=0.1)
    jitter_mm = 1000.0 * np.linalg.norm(target - sim, axis=1).sum()
    emd = earth_movers(sim, target)[0]
    assert 0.5 * jitter_mm < emd <= jitter_mm + 1e-9
    assert 0 < chamfer(sim, target)[0] <= 2 * emd
    result = bench_emd(n=50)
    assert result["n"] == 50 and result["emd_s"] > 0 and result["chamfer_s"] > 0


def test_heightmap_gradient_with_particle_cubes_matches_finite_differences():
    sim, target = heightmap_setup()
    target = target._replace(particle_size=0.03)  # each particle covers up to 2 × 2 of the 2.75 cm cells
    owners = lambda points, t: tuple(height_map_owners(points, t.centre_xy, cells=4, particle_size=0.03).ravel())  # noqa: E731
    value, gradient = heightmap_loss(sim, target)
    numeric = finite_difference(heightmap_loss, sim, target, owners)
    np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-3)
    assert np.abs(gradient[:, 2]).max() >= 2000  # some particle holds more than one cell
    held = height_map_owners(sim, target.centre_xy, cells=4, particle_size=0.03)
    assert value == pytest.approx(1000 * np.abs(sim[held, 2] + 0.015 - target.heights).sum())


def test_heightmap_counted_on_some_cells_sums_and_differentiates_only_those():
    sim, target = heightmap_setup()
    cells = np.zeros((4, 4), bool)
    cells[1:3, 1:3] = True
    masked = target._replace(cells=cells)
    value, gradient = heightmap_loss(sim, masked)
    full = np.abs(height_map(sim, target.centre_xy, cells=4) - target.heights)
    assert value == pytest.approx(1000 * full[cells].sum())
    assert value < heightmap_loss(sim, target)[0]
    held = height_map_owners(sim, target.centre_xy, cells=4)
    assert set(np.flatnonzero(gradient[:, 2])) == set(held[cells])
    owners = lambda points, t: tuple(height_map_owners(points, t.centre_xy, cells=4).ravel())  # noqa: E731
    np.testing.assert_allclose(gradient, finite_difference(heightmap_loss, sim, masked, owners), rtol=1e-5, atol=1e-3)
    with pytest.raises(ValueError, match="mask has shape"):
        heightmap_loss(sim, target._replace(cells=np.ones((3, 3), bool)))


def test_interior_loss_uses_the_interior_target():
    sim, target = heightmap_setup()
    cells = np.eye(4, dtype=bool)
    targets = Targets(heightmap=target, heightmap_interior=target._replace(cells=cells))
    expected = 1000 * np.abs(height_map(sim, target.centre_xy, cells=4) - target.heights)[cells].sum()
    assert loss_by_name("heightmap_interior")(sim, targets)[0] == pytest.approx(expected)
