"""Training losses and validation metrics between simulated particles and real targets (SPEC §5).

Every distance is in mm and summed, not averaged. A loss returns ``(value_mm, gradient)`` where
``gradient`` (n, 3) is d value / d simulated positions in mm per m, with the correspondences
(nearest neighbours, assignment, height-map cell owners) held fixed during one evaluation.
A simulated set containing NaN/inf gives a NaN value and gradient, so the gradient screening
of :mod:`dpsi.optim` skips that datapoint.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from dpsi.files import check_points
from dpsi.heightmap import height_map, height_map_owners, heightmap_distance_mm, owned_heights

MM_PER_M = 1000.0

LossResult = tuple[float, np.ndarray]
"""(value in mm, gradient (n, 3) in mm/m)."""


def _checked(sim, target) -> tuple[np.ndarray, np.ndarray] | None:
    """Validated (sim, target) arrays, or None if the simulated set is not finite."""
    sim = check_points(sim, "simulated points", finite=False)
    target = check_points(target, "target points")
    return (sim, target) if np.isfinite(sim).all() else None


def _not_finite(sim) -> LossResult:
    return float("nan"), np.full(np.shape(sim), np.nan)


def _pair_gradient(sim: np.ndarray, sim_index: np.ndarray, target_points: np.ndarray) -> np.ndarray:
    """Σ over pairs (sim[sim_index[k]], target_points[k]) of d|x − y|/dx in mm/m, shape of ``sim``.

    A pair at zero distance contributes nothing (a valid subgradient).
    """
    diff = sim[sim_index] - target_points
    norm = np.linalg.norm(diff, axis=1, keepdims=True)
    unit = np.divide(diff, norm, out=np.zeros_like(diff), where=norm > 0)
    gradient = np.zeros_like(sim)
    np.add.at(gradient, sim_index, unit * MM_PER_M)
    return gradient


class LossTerms(NamedTuple):
    """A loss as the sum of its terms: the value (mm), its gradient (n, 3) in mm/m, and the terms (mm), one
    per unit the distance sums over (a point, or a height-map cell), in an order fixed by the simulated and
    target sets' sizes, so that the terms of two simulations of one datapoint pair up unit by unit."""

    value: float
    gradient: np.ndarray
    terms: np.ndarray


def _not_finite_terms(sim, units: int) -> LossTerms:
    return LossTerms(*_not_finite(sim), np.full(units, np.nan))


def chamfer_terms(sim, target) -> LossTerms:
    """:func:`chamfer` with its terms: each simulated point's distance to the target, then each target
    point's distance to the simulation."""
    checked = _checked(sim, target)
    if checked is None:
        return _not_finite_terms(sim, len(sim) + len(target))
    sim, target = checked
    to_target, nearest_target = cKDTree(target).query(sim)
    to_sim, nearest_sim = cKDTree(sim).query(target)
    gradient = (_pair_gradient(sim, np.arange(len(sim)), target[nearest_target])
                + _pair_gradient(sim, nearest_sim, target))
    return LossTerms(float((to_target.sum() + to_sim.sum()) * MM_PER_M), gradient,
                     np.concatenate([to_target, to_sim]) * MM_PER_M)


def chamfer(sim, target) -> LossResult:
    """Chamfer distance Σ_sim min_target |x − y| + Σ_target min_sim |x − y| in mm (SPEC §5)."""
    return chamfer_terms(sim, target)[:2]


def earth_movers_terms(sim, target) -> LossTerms:
    """:func:`earth_movers` with its terms: each target point's distance to its assigned simulated point."""
    checked = _checked(sim, target)
    if checked is None:
        return _not_finite_terms(sim, len(target))
    sim, target = checked
    if len(target) > len(sim):
        raise ValueError(
            f"earth mover's distance needs no more target points than simulated points, "
            f"got {len(target)} target and {len(sim)} simulated"
        )
    cost = cdist(target, sim)
    rows, cols = linear_sum_assignment(cost)
    return LossTerms(float(cost[rows, cols].sum() * MM_PER_M), _pair_gradient(sim, cols, target[rows]),
                     cost[rows, cols] * MM_PER_M)


def earth_movers(sim, target) -> LossResult:
    """Earth mover's distance Σ_target |t − φ(t)| in mm, φ the optimal one-to-one assignment
    of the target points to simulated points (needs no more target than simulated points)."""
    return earth_movers_terms(sim, target)[:2]


class HeightMapTarget(NamedTuple):
    """A real height map (cells, cells) in m over the default 0.11 m square, the square's centre
    (2,) in m (SPEC §3.5), the height (m) of cells no point falls in (the table), the side (m) of the
    cube each simulated particle stands for (see :mod:`dpsi.heightmap`; 0 treats particles as points),
    and optionally the cells (boolean (cells, cells)) the distance counts; None counts all."""

    heights: np.ndarray
    centre_xy: np.ndarray
    floor: float = 0.0
    particle_size: float = 0.0
    cells: np.ndarray | None = None


def simulated_heightmap(sim, target: HeightMapTarget) -> np.ndarray:
    """Height map (m) of the simulated particles (n, 3) in m over the target's square, drawn as the
    target says (particle cubes, empty cells at its floor)."""
    return height_map(sim, target.centre_xy, cells=np.shape(target.heights)[0], floor=target.floor,
                      particle_size=target.particle_size)


def heightmap_loss_terms(sim, target: HeightMapTarget) -> LossTerms:
    """:func:`heightmap_loss` with its terms: each counted cell's |simulated − target| height in mm, in
    row-major cell order."""
    sim = check_points(sim, "simulated points", finite=False)
    heights = np.asarray(target.heights, dtype=float)
    if heights.ndim != 2 or heights.shape[0] != heights.shape[1]:
        raise ValueError(f"target height map must be square (cells, cells), got {heights.shape}")
    counted = np.ones(heights.shape, bool) if target.cells is None else np.asarray(target.cells, bool)
    if counted.shape != heights.shape:
        raise ValueError(f"height-map cells mask has shape {counted.shape}, the map {heights.shape}")
    if not np.isfinite(sim).all():
        return _not_finite_terms(sim, int(counted.sum()))
    owners = height_map_owners(sim, target.centre_xy, cells=heights.shape[0], particle_size=target.particle_size)
    simulated = owned_heights(sim, owners, target.floor, target.particle_size)
    filled = (owners >= 0) & counted
    gradient = np.zeros_like(sim)
    np.add.at(gradient[:, 2], owners[filled], np.sign(simulated[filled] - heights[filled]) * MM_PER_M)
    return LossTerms(heightmap_distance_mm(simulated[counted], heights[counted]), gradient,
                     np.abs(simulated[counted] - heights[counted]) * MM_PER_M)


def heightmap_loss(sim, target: HeightMapTarget) -> LossResult:
    """Height-map distance (mm) of the particles to a real height map, over the target's ``cells`` (all
    by default); the gradient of each counted cell goes to the z of the particle holding that cell's
    highest z (SPEC §3.5, §7.7), summed over the cells a particle holds."""
    return heightmap_loss_terms(sim, target)[:2]


def neg_heightmap_loss_terms(sim, target: HeightMapTarget) -> LossTerms:
    """:func:`neg_heightmap_loss` with its terms (each cell's negated distance)."""
    value, gradient, terms = heightmap_loss_terms(sim, target)
    return LossTerms(-value, -gradient, -terms)


def neg_heightmap_loss(sim, target: HeightMapTarget) -> LossResult:
    """The negated height-map distance (SPEC appendix A), in mm."""
    return neg_heightmap_loss_terms(sim, target)[:2]


@dataclass(frozen=True)
class Targets:
    """The targets of one datapoint: the PCD target (k, 3) in m (fused after cloud voxel-downsampled
    at 5 mm), the PRT target (k, 3) in m (particles filled in the after mesh), the real height map, and
    the same map restricted to the interior of the object's outlines (``heightmap_interior``)."""

    pcd: np.ndarray | None = None
    prt: np.ndarray | None = None
    heightmap: HeightMapTarget | None = None
    heightmap_interior: HeightMapTarget | None = None


_REGISTRY: dict[str, tuple[Callable[..., LossTerms], str]] = {
    # name: (distance with its terms, Targets field it is measured against)
    "pcd_cd": (chamfer_terms, "pcd"),
    "prt_cd": (chamfer_terms, "prt"),
    "pcd_emd": (earth_movers_terms, "pcd"),
    "prt_emd": (earth_movers_terms, "prt"),
    "heightmap": (heightmap_loss_terms, "heightmap"),
    "neg_heightmap": (neg_heightmap_loss_terms, "heightmap"),
    "heightmap_interior": (heightmap_loss_terms, "heightmap_interior"),
}

LOSSES = _REGISTRY.keys()
"""Names of the training losses: a set-like view in the order above."""


def loss_terms_by_name(name: str) -> Callable[[np.ndarray, Targets], LossTerms]:
    """The loss ``name`` as a function ``(sim_points (n, 3) in m, targets) -> LossTerms`` (value in mm,
    gradient in mm/m and the terms it sums)."""
    if name not in _REGISTRY:
        raise ValueError(f"unknown loss {name!r}; known losses are {list(LOSSES)}")
    distance, field = _REGISTRY[name]

    def loss(sim_points, targets: Targets) -> LossTerms:
        target = getattr(targets, field)
        if target is None:
            raise ValueError(f"loss {name!r} needs the {field!r} target, which is missing")
        return distance(sim_points, target)

    loss.__name__ = name
    return loss


def loss_by_name(name: str) -> Callable[[np.ndarray, Targets], LossResult]:
    """The loss ``name`` as a function ``(sim_points (n, 3) in m, targets) -> (mm, gradient mm/m)``."""
    with_terms = loss_terms_by_name(name)

    def loss(sim_points, targets: Targets) -> LossResult:
        return with_terms(sim_points, targets)[:2]

    loss.__name__ = name
    return loss


VALIDATION_METRICS = {"pcd_cd": "pcd_cd", "prt_cd": "prt_cd", "pcd_emd": "pcd_emd", "prt_emd": "prt_emd",
                      "heightmap_mm": "heightmap"}
"""The validation metrics (SPEC §6) and the loss each one is the value of."""


def validation_metrics(sim_points, pcd_target, prt_target, real_heightmap, centre_xy,
                       floor: float = 0.0, particle_size: float = 0.0) -> dict[str, float]:
    """The five validation metrics in mm: pcd_cd, prt_cd, pcd_emd, prt_emd and heightmap_mm
    (the height map of the particles, cubes of side ``particle_size`` m, against ``real_heightmap``
    (cells, cells) in m centred at ``centre_xy`` (2,) in m, empty cells at ``floor``, the table height
    in m); all point sets are (k, 3) in m."""
    targets = Targets(pcd=pcd_target, prt=prt_target,
                      heightmap=HeightMapTarget(real_heightmap, centre_xy, floor, particle_size))
    return {metric: loss_by_name(loss)(sim_points, targets)[0] for metric, loss in VALIDATION_METRICS.items()}


def bench_sets(n: int = 3000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The point sets the loss benchmark times, (n, 3) each in m: a random 6 cm clay-sized cube and a
    copy of it jittered by 3 mm (standard deviation per axis)."""
    rng = np.random.default_rng(seed)
    sim = rng.uniform(0.0, 0.06, (n, 3))
    return sim, sim + rng.normal(0.0, 0.003, (n, 3))


def bench_emd(n: int = 3000, seed: int = 0) -> dict[str, float]:
    """Wall time (s) of one earth mover's and one Chamfer evaluation with gradient between the two
    :func:`bench_sets` of ``n`` points."""
    sim, target = bench_sets(n, seed)
    out: dict[str, float] = {"n": n}
    for name, distance in (("emd_s", earth_movers), ("chamfer_s", chamfer)):
        start = time.perf_counter()
        distance(sim, target)
        out[name] = time.perf_counter() - start
    return out


__all__ = [
    "LossResult", "LossTerms", "chamfer", "chamfer_terms", "earth_movers", "earth_movers_terms", "HeightMapTarget",
    "simulated_heightmap", "heightmap_loss", "heightmap_loss_terms", "neg_heightmap_loss", "neg_heightmap_loss_terms",
    "Targets", "LOSSES", "loss_terms_by_name", "loss_by_name", "VALIDATION_METRICS", "validation_metrics",
    "bench_sets", "bench_emd",
]
