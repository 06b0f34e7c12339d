"""What a run's data determine: intervals for the identified parameters and their combinations.

Everything is in natural-log parameters x = ln θ (one unit: a factor e), over the run's free parameters.
At the selected estimate x̂ the training loss L (mm, the mean over the training datapoints) is modelled by
its quadratic

    L(x̂ + δ) ≈ L(x̂) + gᵀδ + ½ δᵀHδ,

g its exact gradient (the simulator's adjoint) and H its Hessian from central differences of the exact
gradient, two gradient evaluations per free parameter (:func:`curvature`). The loss tolerance Δ is the loss's
own sampling spread: the standard deviation of the loss at x̂ over bootstrap resamples of the training
datapoints and, within each, of the units the loss sums over (target points, or height-map cells), with no
further simulation (:func:`resample`). The interval of a quantity c·x (a parameter, a ratio such as σ_y/E, a
principal direction) is the range of c·x over the parameters whose modelled loss is at most L(x̂) + Δ — they
fit the data within the loss's own noise of the estimate — clipped to the range that the parameter bounds
allow (:func:`interval`). A direction along which the loss rises by less than Δ across the whole parameter
box is flat: the model carries no information along it, so it is given the curvature that would reach the box's
diagonal, which sends every quantity with a part along it to the bounds. A quantity whose interval reaches a
bound of its range is *not determined* by these data.

A known symmetry (multiplying E, ρ and σ_y by one factor changes no motion) is a direction of exactly zero
curvature; :func:`difference_basis` puts it among the difference directions, so that its column of H is the
difference of two equal gradients and the common scale always comes out flat.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

import numpy as np
import pandas as pd

LOG_STEP = 0.1
"""Central-difference step (natural-log units: ±10 %) of the gradient; the loss of a height map is a staircase
at the scale of a particle's move, so the step averages its curvature over ±10 % of each parameter."""

SAMPLES = 400
"""Bootstrap resamples of the loss at the estimate."""

SCALE_SYMMETRY = {"E": 1.0, "rho": 1.0, "yield_stress": 1.0}
"""E, ρ and σ_y times one factor: no motion changes (dpsi.parameters.SCALE_FREE)."""

RATIOS = {"E/rho": {"E": 1.0, "rho": -1.0}, "yield_stress/E": {"yield_stress": 1.0, "E": -1.0}}
"""The scale-free combinations, as exponents of the parameters; reported when all their parameters are free."""


class UncertaintyError(ValueError):
    """The curvature or the loss's spread could not be measured (a simulation or gradient failed)."""


class Evaluation(NamedTuple):
    """The training loss at one point x: its value (mm), exact gradient dL/dx (k,) in mm per log unit, and
    each training datapoint's loss terms (mm; the loss is the mean over datapoints of their sums)."""

    loss_mm: float
    gradient: np.ndarray
    terms: tuple[np.ndarray, ...]


class Curvature(NamedTuple):
    """The loss at the estimate (:class:`Evaluation`), its symmetrised Hessian H (k, k) in mm per log unit²,
    the slopes (units, k) in mm per log unit of each datapoint's terms, and the number of gradient evaluations."""

    centre: Evaluation
    hessian: np.ndarray
    term_slopes: tuple[np.ndarray, ...]
    evaluations: int


def difference_basis(names: Sequence[str], symmetries: Sequence[Mapping[str, float]] = (SCALE_SYMMETRY,)) -> np.ndarray:
    """Orthonormal directions (k, k) in the log space of ``names`` (one per column) whose first columns span
    the ``symmetries`` lying wholly within ``names`` (exponents by name); the identity if there are none."""
    k = len(names)
    inside = [np.array([s.get(n, 0.0) for n in names]) for s in symmetries if set(s) <= set(names)]
    if not inside:
        return np.eye(k)
    q, _ = np.linalg.qr(np.column_stack([*inside, np.eye(k)]))
    return q[:, :k]


def _room(x0: np.ndarray, direction: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> float:
    """How far (log units) one can go from ``x0`` along ``direction`` and stay in the box."""
    with np.errstate(divide="ignore"):
        limits = np.where(direction > 0, (upper - x0) / direction,
                          np.where(direction < 0, (lower - x0) / direction, np.inf))
    return float(max(0.0, limits.min()))


def curvature(evaluate: Callable[[np.ndarray], Evaluation], x0, lower, upper, step: float = LOG_STEP,
              basis: np.ndarray | None = None) -> Curvature:
    """The loss at ``x0`` and its Hessian from central differences of the exact gradient along each column v
    of ``basis`` (default the parameter axes): (g(x0 + a v) − g(x0 − b v)) / (a + b), a and b the ``step``
    shortened where the box [``lower``, ``upper``] (log bounds) ends, the centre's gradient taking the place of a
    point with no room; then H = M Vᵀ, symmetrised. The same differences of each datapoint's loss terms give
    their slopes. ``evaluate(x)`` returns an :class:`Evaluation`."""
    x0, lower, upper = (np.asarray(a, dtype=float) for a in (x0, lower, upper))
    k = len(x0)
    basis = np.eye(k) if basis is None else np.asarray(basis, dtype=float)
    if basis.shape != (k, k) or not np.allclose(basis.T @ basis, np.eye(k), atol=1e-9):
        raise ValueError(f"the difference basis must be an orthonormal ({k}, {k}) matrix")
    if not step > 0:
        raise ValueError(f"the difference step must be positive, got {step}")
    centre = evaluate(x0)
    columns, slopes, evaluations = [], [[] for _ in centre.terms], 1
    for v in basis.T:
        a, b = min(step, _room(x0, v, lower, upper)), min(step, _room(x0, -v, lower, upper))
        if a + b <= 0:
            raise UncertaintyError("the box of the free parameters has no room around the estimate")
        ends = []
        for distance in (a, -b):
            ends.append(evaluate(x0 + distance * v) if distance else centre)
            evaluations += bool(distance)
        forward, backward = ends
        columns.append((forward.gradient - backward.gradient) / (a + b))
        for d, (tf, tb) in enumerate(zip(forward.terms, backward.terms)):
            slopes[d].append((tf - tb) / (a + b))
    hessian = np.column_stack(columns) @ basis.T
    return Curvature(centre, 0.5 * (hessian + hessian.T),
                     tuple(np.column_stack(s) @ basis.T for s in slopes), evaluations)


class Spread(NamedTuple):
    """Bootstrap of the loss at the estimate: its standard deviation (mm) — the tolerance Δ — and the
    covariance (k, k) of the resampled loss's gradient (mm² per log unit², the spread that a resample moves the
    minimum by; for the record)."""

    tolerance_mm: float
    gradient_covariance: np.ndarray


def resample(terms: Sequence[np.ndarray], term_slopes: Sequence[np.ndarray] | None = None,
             samples: int = SAMPLES, seed: int = 0) -> Spread:
    """Bootstrap the mean over datapoints of each one's summed ``terms``: each resample draws the datapoints
    with replacement and, for each drawn copy, as many of its terms as it has, with replacement.
    ``term_slopes``: each datapoint's (units, k) slopes of its terms, resampled alike for the gradient's
    covariance (zero (0, 0) if not given)."""
    if not terms or any(len(t) == 0 for t in terms):
        raise UncertaintyError("every training datapoint needs at least one loss term to resample")
    if not all(np.isfinite(t).all() for t in terms):
        raise UncertaintyError("a loss term at the estimate is not finite")
    rng = np.random.default_rng(seed)
    m = len(terms)
    copies = np.stack([np.bincount(rng.integers(0, m, m), minlength=m) for _ in range(samples)])
    losses = np.zeros(samples)
    k = 0 if term_slopes is None else term_slopes[0].shape[1]
    gradients = np.zeros((samples, k))
    for d, t in enumerate(terms):
        n = len(t)
        weights = np.stack([rng.multinomial(c * n, np.full(n, 1.0 / n)) if c else np.zeros(n) for c in copies[:, d]])
        losses += weights @ t / m
        if term_slopes is not None:
            gradients += weights @ term_slopes[d] / m
    covariance = np.cov(gradients, rowvar=False).reshape(k, k) if k else np.zeros((0, 0))
    return Spread(float(np.std(losses, ddof=1)), covariance)


class Interval(NamedTuple):
    """A quantity exp(c·x) (c: ``exponents`` by name): estimate, interval [low, high] clipped to the range
    [``lowest``, ``highest``] the bounds allow (SI units of the product), whether it is determined (its
    interval reaches neither end of the range), and its half-width as a factor: the interval, unclipped,
    is the estimate's ×/÷ ``factor`` when centred on it (at most the range's own width)."""

    quantity: str
    exponents: dict[str, float]
    estimate: float
    low: float
    high: float
    determined: bool
    factor: float
    lowest: float
    highest: float


class Model(NamedTuple):
    """The quadratic model's confidence set {δ: ½(δ − centre)ᵀ H̃ (δ − centre) ≤ budget}, H̃ the Hessian with each
    flat eigenvalue raised to ``floor``; eigenvalues (ascending) and directions (k, k), columns, with the
    flat ones marked."""

    centre: np.ndarray
    budget: float
    inverse: np.ndarray
    eigenvalues: np.ndarray
    directions: np.ndarray
    flat: np.ndarray
    floor: float


def model(gradient, hessian, tolerance: float, lower, upper) -> Model:
    """The set of δ whose modelled loss rise gᵀδ + ½δᵀHδ is at most ``tolerance`` (mm), with the eigenvalues of
    H below 2 Δ / D² — the loss rises by less than Δ over the box's diagonal D (log bounds ``lower``, ``upper``)
    — raised to that floor, and the gradient's part along them dropped: along a flat direction the model knows
    nothing, so it neither rises nor falls."""
    gradient, hessian = np.asarray(gradient, dtype=float), np.asarray(hessian, dtype=float)
    if not tolerance > 0:
        raise UncertaintyError(f"the loss tolerance must be positive, got {tolerance} mm")
    if not (np.isfinite(gradient).all() and np.isfinite(hessian).all()):
        raise UncertaintyError("the gradient or the Hessian at the estimate is not finite")
    diagonal = float(np.linalg.norm(np.asarray(upper, dtype=float) - np.asarray(lower, dtype=float)))
    floor = 2.0 * tolerance / diagonal**2
    eigenvalues, directions = np.linalg.eigh(0.5 * (hessian + hessian.T))
    flat = eigenvalues < floor
    curvatures = np.where(flat, floor, eigenvalues)
    along = np.where(flat, 0.0, directions.T @ gradient)
    centre = -directions @ (along / curvatures)
    budget = tolerance + 0.5 * float(np.sum(along**2 / curvatures))
    return Model(centre, budget, directions @ np.diag(1.0 / curvatures) @ directions.T, eigenvalues, directions,
                 flat, floor)


def interval(name: str, exponents: Mapping[str, float], names: Sequence[str], x0, lower, upper,
             quadratic: Model) -> Interval:
    """The :class:`Interval` of the quantity ``exponents`` (by name, over the free ``names``) at log values
    ``x0`` within log bounds [``lower``, ``upper``]."""
    unknown = sorted(set(exponents) - set(names))
    if unknown:
        raise ValueError(f"quantity {name!r} uses {unknown}, which are not among the free parameters {list(names)}")
    c = np.array([exponents.get(n, 0.0) for n in names])
    x0, lower, upper = (np.asarray(a, dtype=float) for a in (x0, lower, upper))
    lowest, highest = float(np.minimum(c * lower, c * upper).sum()), float(np.maximum(c * lower, c * upper).sum())
    half = math.sqrt(2.0 * quadratic.budget * float(c @ quadratic.inverse @ c))
    middle = float(c @ (x0 + quadratic.centre))
    low, high = middle - half, middle + half
    estimate = float(c @ x0)
    return Interval(name, {n: float(exponents[n]) for n in names if exponents.get(n)}, math.exp(estimate),
                    math.exp(max(low, lowest)), math.exp(min(high, highest)), bool(low > lowest and high < highest),
                    math.exp(min(half, highest - lowest)), math.exp(lowest), math.exp(highest))


def direction_name(exponents: Mapping[str, float]) -> str:
    """A product of powers, largest exponent first: ``yield_stress^1*E^-0.93``."""
    return "*".join(f"{n}^{a:.3g}" for n, a in sorted(exponents.items(), key=lambda kv: -abs(kv[1])) if a)


def principal_exponents(direction: np.ndarray, names: Sequence[str]) -> dict[str, float]:
    """A principal direction as exponents rounded to two decimals, the largest +1 (so that its name defines it)."""
    largest = direction[np.argmax(np.abs(direction))]
    return {n: round(float(a / largest), 2) for n, a in zip(names, direction)}


def quantities(names: Sequence[str], quadratic: Model) -> dict[str, dict[str, float]]:
    """What to report, name → exponents: each free parameter, each of :data:`RATIOS` whose parameters are all
    free, and the stiffest principal direction (the combination the data determine best) when there are two
    or more free parameters and it is none of those."""
    out = {n: {n: 1.0} for n in names}
    out.update({r: e for r, e in RATIOS.items() if set(e) <= set(names)})
    if len(names) >= 2:
        stiffest = principal_exponents(quadratic.directions[:, -1], names)
        stiffest = {n: a for n, a in stiffest.items() if a}
        if len(stiffest) >= 2 and stiffest not in out.values():
            out[direction_name(stiffest)] = stiffest
    return out


def assess(names: Sequence[str], x0, lower, upper, evaluate: Callable[[np.ndarray], Evaluation],
           step: float = LOG_STEP, samples: int = SAMPLES, seed: int = 0,
           symmetries: Sequence[Mapping[str, float]] = (SCALE_SYMMETRY,)) -> dict:
    """The uncertainty of an estimate at log values ``x0`` of the free parameters ``names`` (log bounds
    ``lower``, ``upper``; ``evaluate``: the training loss, see :class:`Evaluation`), as a JSON-ready block: the
    loss, tolerance, gradient and Hessian, the principal directions and an interval per :func:`quantities`."""
    names = list(names)
    measured = curvature(evaluate, x0, lower, upper, step, difference_basis(names, symmetries))
    spread = resample(measured.centre.terms, measured.term_slopes, samples, seed)
    quadratic = model(measured.centre.gradient, measured.hessian, spread.tolerance_mm, lower, upper)
    asked = quantities(names, quadratic)
    results = [interval(q, e, names, x0, lower, upper, quadratic) for q, e in asked.items()]
    directions = []
    for value, flat, vector in zip(quadratic.eigenvalues[::-1], quadratic.flat[::-1], quadratic.directions.T[::-1]):
        exponents = principal_exponents(vector, names)
        directions.append({"eigenvalue_mm": float(value), "flat": bool(flat),
                           **_interval_record(interval(direction_name(exponents), exponents, names, x0, lower, upper,
                                                       quadratic))})
    return {"method": "quadratic model of the training loss in log-parameters within its bootstrap spread",
            "free": names, "log_step": step, "evaluations": measured.evaluations,
            "loss_mm": measured.centre.loss_mm, "tolerance_mm": spread.tolerance_mm,
            "bootstrap": {"samples": samples, "seed": seed, "units": [len(t) for t in measured.centre.terms]},
            "gradient_mm": measured.centre.gradient.tolist(), "hessian_mm": measured.hessian.tolist(),
            "gradient_covariance_mm2": spread.gradient_covariance.tolist(),
            "flat_floor_mm": quadratic.floor, "directions": directions,
            "quantities": [_interval_record(r) for r in results]}


def _interval_record(result: Interval) -> dict:
    return {"quantity": result.quantity, "exponents": result.exponents, "estimate": result.estimate,
            "low": result.low, "high": result.high, "determined": result.determined, "factor": result.factor,
            "lowest": result.lowest, "highest": result.highest}


def true_value(exponents: Mapping[str, float], truth: Mapping[str, float]) -> float:
    """The quantity ``exponents`` (by name) of the parameters ``truth`` (SI)."""
    return math.exp(sum(a * math.log(truth[n]) for n, a in exponents.items()))


def describe(record: Mapping) -> str:
    """One line for a person: ``yield_stress/E = 0.0589 within ×/÷1.2 (0.0497–0.0704)``, or ``E not determined
    (its interval 1.2e+04–3e+05 reaches the upper bound 3e+05)``."""
    q, low, high = record["quantity"], record["low"], record["high"]
    if record["determined"]:
        return f"{q} = {record['estimate']:.3g} within ×/÷{record['factor']:.2g} ({low:.3g}–{high:.3g})"
    ends = [f"{end} bound {value:.3g}" for end, value, reached in
            (("lower", record["lowest"], low <= record["lowest"] * (1 + 1e-9)),
             ("upper", record["highest"], high >= record["highest"] * (1 - 1e-9))) if reached]
    return f"{q} not determined (its interval {low:.3g}–{high:.3g} reaches the {' and the '.join(ends)})"


DIRECTION_LABEL = "stiffest direction"
"""How :func:`coverage` groups the principal directions, whose names differ from run to run."""

COVERAGE_COLUMNS = ("rung", "quantity", "runs", "determined", "covered", "coverage", "median_factor")


def coverage(table: pd.DataFrame) -> pd.DataFrame:
    """Calibration on a known truth: per rung and quantity (principal directions as :data:`DIRECTION_LABEL`),
    and per rung over all quantities (quantity "all"), the runs, how many marked the quantity determined, how
    many of those intervals hold the truth, that fraction, and the median ×/÷ factor √(high/low) of the
    determined intervals. ``table``: rows with the columns of uncertainty.csv (rung, level, dataset, seed,
    quantity, estimate, low, high, determined, truth); rows without a truth are left out, and a run that
    stands for another (the same numbers under another loss name) is counted once."""
    rows = table[table["truth"].notna()].copy()
    rows["quantity"] = [DIRECTION_LABEL if "^" in q else q for q in rows["quantity"]]
    rows = rows.drop_duplicates(["rung", "level", "dataset", "seed", "quantity", "estimate", "low", "high"])
    rows["determined"] = rows["determined"].astype(bool)
    rows["covered"] = rows["determined"] & (rows["low"] <= rows["truth"]) & (rows["truth"] <= rows["high"])
    rows["factor"] = np.sqrt(rows["high"] / rows["low"])
    out = []
    for rung, mine in rows.groupby("rung", sort=True):
        for quantity, group in [*mine.groupby("quantity", sort=False), ("all", mine)]:
            determined = group[group["determined"]]
            out.append(dict(rung=rung, quantity=quantity, runs=len(group), determined=len(determined),
                            covered=int(group["covered"].sum()),
                            coverage=group["covered"].sum() / len(determined) if len(determined) else math.nan,
                            median_factor=determined["factor"].median() if len(determined) else math.nan))
    return pd.DataFrame(out, columns=list(COVERAGE_COLUMNS))


__all__ = ["LOG_STEP", "SAMPLES", "SCALE_SYMMETRY", "RATIOS", "UncertaintyError", "Evaluation", "Curvature",
           "difference_basis", "curvature", "Spread", "resample", "Interval", "Model", "model", "interval",
           "direction_name", "principal_exponents", "quantities", "assess", "true_value", "describe", "DIRECTION_LABEL",
           "COVERAGE_COLUMNS", "coverage"]
