"""Adam over the named physical parameters, and the screening of per-datapoint gradients (SPEC §6).

Values, step sizes and gradients are keyed by the names of :data:`dpsi.parameters.NAMES`, each in
its parameter's own unit (gradients in loss mm per parameter unit).
"""

from __future__ import annotations

import math
from typing import Mapping, NamedTuple, Sequence

from dpsi.parameters import IDENTIFIED, LOWER, NAMES, STEP_SIZE, UPPER, Parameters, clip

BETA1 = 0.9
BETA2 = 0.999
EPSILON = 1e-8

MAX_GRADIENT = 1e6
"""A datapoint with any |gradient| above this is skipped."""

MAX_ZERO_GRADIENTS = 4
"""A datapoint with more zero gradients than this (among the six) is skipped."""

_STATE_KEYS = {"values", "step_size", "first_moment", "second_moment", "iteration"}


class Adam:
    """Adam on a subset of the parameters, each with its own step size (in its own unit),
    clipped to its range after every update."""

    def __init__(self, values: Mapping[str, float], step_size: Mapping[str, float]):
        unknown = sorted(set(values) - set(NAMES))
        if unknown or not values:
            raise ValueError(f"Adam needs one or more known parameters, got {list(values)} "
                             f"(unknown: {unknown}); known parameters are {list(NAMES)}")
        for name, value in values.items():
            if not (math.isfinite(value) and LOWER[name] <= value <= UPPER[name]):
                raise ValueError(f"initial {name}={value} is outside its range [{LOWER[name]}, {UPPER[name]}]")
            if not step_size.get(name, 0.0) > 0.0:
                raise ValueError(f"step size of {name} must be positive, got {step_size.get(name)}")
        self.values = {n: float(v) for n, v in values.items()}
        self.step_size = {n: float(step_size[n]) for n in self.values}
        self.first_moment = {n: 0.0 for n in self.values}
        self.second_moment = {n: 0.0 for n in self.values}
        self.iteration = 0

    @classmethod
    def for_level(cls, initial: Parameters, level: int, held: Sequence[str] = ()) -> "Adam":
        """Adam over the parameters identified at ``level`` (1 or 2), less those ``held`` at their initial
        value (known, e.g. a measured density), with that level's step sizes."""
        if level not in IDENTIFIED:
            raise ValueError(f"unknown level {level}; known levels are {sorted(IDENTIFIED)}")
        return cls({n: getattr(initial, n) for n in IDENTIFIED[level] if n not in held}, STEP_SIZE[level])

    def step(self, gradient: Mapping[str, float]) -> dict[str, float]:
        """One update from ``gradient`` (needs every optimised name; other names are ignored);
        returns the new, clipped values."""
        missing = [n for n in self.values if n not in gradient]
        if missing:
            raise ValueError(f"gradient is missing the optimised parameter(s) {missing}")
        bad = {n: gradient[n] for n in self.values if not math.isfinite(gradient[n])}
        if bad:
            raise ValueError(f"gradient is not finite: {bad}")
        self.iteration += 1
        first_correction = 1.0 - BETA1 ** self.iteration
        second_correction = 1.0 - BETA2 ** self.iteration
        for name in self.values:
            g = float(gradient[name])
            self.first_moment[name] = BETA1 * self.first_moment[name] + (1.0 - BETA1) * g
            self.second_moment[name] = BETA2 * self.second_moment[name] + (1.0 - BETA2) * g * g
            first = self.first_moment[name] / first_correction
            second = self.second_moment[name] / second_correction
            self.values[name] -= self.step_size[name] * first / (math.sqrt(second) + EPSILON)
        self.values = clip(self.values)
        return dict(self.values)

    def state(self) -> dict:
        """The full optimiser state as plain, JSON-serialisable data."""
        return {"values": dict(self.values), "step_size": dict(self.step_size),
                "first_moment": dict(self.first_moment), "second_moment": dict(self.second_moment),
                "iteration": self.iteration}

    @classmethod
    def from_state(cls, state: Mapping) -> "Adam":
        """Rebuild an optimiser from :meth:`state` (e.g. after a JSON round trip)."""
        if set(state) != _STATE_KEYS:
            raise ValueError(f"Adam state must have the keys {sorted(_STATE_KEYS)}, got {sorted(state)}")
        adam = cls(state["values"], state["step_size"])
        for key in ("first_moment", "second_moment"):
            if set(state[key]) != set(adam.values):
                raise ValueError(f"Adam state {key} has names {sorted(state[key])}, "
                                 f"expected {sorted(adam.values)}")
        adam.first_moment = {n: float(state["first_moment"][n]) for n in adam.values}
        adam.second_moment = {n: float(state["second_moment"][n]) for n in adam.values}
        adam.iteration = int(state["iteration"])
        return adam


class Screened(NamedTuple):
    """Mean gradient of the kept datapoints (None if every one was skipped) and the skipped count."""

    gradient: dict[str, float] | None
    skipped: int


def unusable(gradient: Mapping[str, float], loss: float) -> str | None:
    """Why one datapoint fails the SPEC §6 rules (None if it passes)."""
    values = {n: float(gradient[n]) for n in NAMES}
    if not math.isfinite(loss):
        return f"its loss is {loss}"
    bad = {n: g for n, g in values.items() if not (math.isfinite(g) and abs(g) <= MAX_GRADIENT)}
    if bad:
        return f"its gradient is not finite or above {MAX_GRADIENT:g} in magnitude: {bad}"
    zeros = [n for n, g in values.items() if g == 0.0]
    if len(zeros) > MAX_ZERO_GRADIENTS:
        return f"its gradient is zero for {zeros} (at most {MAX_ZERO_GRADIENTS} may be)"
    return None


def screen_gradients(gradients: Sequence[Mapping[str, float]], losses: Sequence[float]) -> Screened:
    """Drop datapoints whose loss or gradient has NaN/inf, any |gradient| > 1e6 or more than four
    zero gradients among the six; average the gradients of the rest."""
    if len(gradients) != len(losses):
        raise ValueError(f"got {len(gradients)} gradients but {len(losses)} losses")
    for index, gradient in enumerate(gradients):
        if set(gradient) != set(NAMES):
            raise ValueError(f"gradient of datapoint {index} has names {sorted(gradient)}, "
                             f"expected all six {list(NAMES)}")
    kept = [g for g, loss in zip(gradients, losses) if unusable(g, loss) is None]
    skipped = len(gradients) - len(kept)
    if not kept:
        return Screened(None, skipped)
    return Screened({n: sum(float(g[n]) for g in kept) / len(kept) for n in NAMES}, skipped)


__all__ = ["BETA1", "BETA2", "EPSILON", "MAX_GRADIENT", "MAX_ZERO_GRADIENTS", "Adam", "Screened",
           "unusable", "screen_gradients"]
