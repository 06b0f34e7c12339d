"""The six physical parameters θ of the clay model, their ranges and optimiser step sizes.

All values are SI: Young's modulus and yield stress in Pa, density in kg/m³, the rest
dimensionless (SPEC §1).
"""

from __future__ import annotations

from dataclasses import dataclass, asdict

import numpy as np

NAMES = ("E", "nu", "rho", "yield_stress", "mu_table", "mu_effector")
"""Parameter names in their canonical order."""

LOWER = {"E": 1e4, "nu": 0.01, "rho": 1000.0, "yield_stress": 1e3, "mu_table": 0.01, "mu_effector": 0.01}
UPPER = {"E": 3e5, "nu": 0.48, "rho": 2000.0, "yield_stress": 2e4, "mu_table": 2.0, "mu_effector": 2.0}

STEP_SIZE = {
    1: {"E": 4000.0, "nu": 0.01, "rho": 10.0, "yield_stress": 500.0, "mu_table": 0.01, "mu_effector": 0.01},
    2: {"E": 4000.0, "nu": 0.001, "rho": 10.0, "yield_stress": 100.0, "mu_table": 0.05, "mu_effector": 0.1},
}
"""Adam step size per contact-complexity level and parameter."""

IDENTIFIED = {1: ("E", "nu", "rho", "yield_stress"), 2: NAMES}
"""Which parameters each level identifies; the others stay at :data:`LEVEL1_FIXED`."""

LEVEL1_FIXED = {"mu_table": 2.0, "mu_effector": 0.3}

SCALE_FREE = ("E/rho", "yield_stress/E")
"""What a motion can determine of E, ρ and σ_y. Stresses scale with E and σ_y, inertia and weight with ρ, and
the effector follows a prescribed path, so multiplying all three by one factor leaves every particle's path
unchanged (tested in tests/test_simulation.py): data fix E/ρ (m²/s², a squared wave speed) and σ_y/E (the
yield strain), not the common factor. Knowing ρ (weigh the sample) fixes it."""


def scale_free(values) -> dict[str, float]:
    """The :data:`SCALE_FREE` combinations of a mapping (or :class:`Parameters`) holding E, rho and
    yield_stress."""
    v = asdict(values) if isinstance(values, Parameters) else values
    return {"E/rho": v["E"] / v["rho"], "yield_stress/E": v["yield_stress"] / v["E"]}

UNITS = {"E": "Pa", "nu": "-", "rho": "kg/m^3", "yield_stress": "Pa", "mu_table": "-", "mu_effector": "-"}


@dataclass(frozen=True)
class Parameters:
    """One value of θ. Construct with :meth:`checked` to validate the ranges."""

    E: float
    nu: float
    rho: float
    yield_stress: float
    mu_table: float
    mu_effector: float

    @classmethod
    def checked(cls, **values: float) -> "Parameters":
        """Build from keyword values, raising ``ValueError`` naming any unknown or out-of-range one."""
        unknown = sorted(set(values) - set(NAMES))
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown}; known parameters are {list(NAMES)}")
        missing = [n for n in NAMES if n not in values]
        if missing:
            raise ValueError(f"missing parameter(s) {missing}")
        out = cls(**{n: float(values[n]) for n in NAMES})
        out.check_range()
        return out

    def check_range(self) -> None:
        """Raise ``ValueError`` if any value is not finite or lies outside its range."""
        for name in NAMES:
            value = getattr(self, name)
            if not np.isfinite(value) or not LOWER[name] <= value <= UPPER[name]:
                raise ValueError(
                    f"parameter {name}={value} {UNITS[name]} is outside its range "
                    f"[{LOWER[name]}, {UPPER[name]}]"
                )

    def replace(self, **values: float) -> "Parameters":
        """A copy with some values changed (validated)."""
        return Parameters.checked(**{**asdict(self), **values})

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    def as_array(self) -> np.ndarray:
        return np.array([getattr(self, n) for n in NAMES], dtype=float)

    @classmethod
    def from_array(cls, values) -> "Parameters":
        return cls.checked(**dict(zip(NAMES, map(float, values))))

    def lame(self) -> tuple[float, float]:
        """Lamé parameters (μ, λ) in Pa (SPEC §4, with the paper's swap fixed)."""
        return lame(self.E, self.nu)

    def p_wave_speed(self) -> float:
        """Speed of compression waves sqrt((λ + 2μ)/ρ) in m/s, which limits the explicit time step."""
        mu, lam = self.lame()
        return float(np.sqrt((lam + 2.0 * mu) / self.rho))


def lame(E: float, nu: float) -> tuple[float, float]:
    """Shear modulus μ = E/(2(1+ν)) and first Lamé parameter λ = Eν/((1+ν)(1−2ν)), in Pa."""
    return E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))


HAND_PICKED = Parameters(E=3e4, nu=0.4, rho=1330.0, yield_stress=1e3, mu_table=0.7, mu_effector=0.7)
"""Literature values used as the baseline and as the good initial guess (SPEC §1)."""


def at_level(params: Parameters, level: int) -> Parameters:
    """``params`` as a run of ``level`` holds them: level 1 keeps the frictions at :data:`LEVEL1_FIXED`."""
    return params.replace(**LEVEL1_FIXED) if level == 1 else params


def hand_picked(level: int) -> Parameters:
    """The literature values as a run of ``level`` starts from them."""
    return at_level(HAND_PICKED, level)


STIFFEST = Parameters(E=UPPER["E"], nu=UPPER["nu"], rho=LOWER["rho"], yield_stress=UPPER["yield_stress"],
                      mu_table=UPPER["mu_table"], mu_effector=UPPER["mu_effector"])
"""The corner of the range with the fastest waves: it sets the worst-case time step."""


def clip(values: dict[str, float]) -> dict[str, float]:
    """Clip each named value into its range."""
    return {k: float(np.clip(v, LOWER[k], UPPER[k])) for k, v in values.items()}


def at_bound(values, names=NAMES) -> dict[str, str]:
    """The parameters among ``names`` whose value in ``values`` (a mapping name → value) lies exactly on a
    bound of its range (where clipping after an update leaves it), mapped to "lower" or "upper"."""
    return {n: "lower" if values[n] == LOWER[n] else "upper" for n in names if values[n] in (LOWER[n], UPPER[n])}


def check_known(known, level: int) -> None:
    """``ValueError`` unless the parameters of ``known`` (names → values) are all identified at ``level`` (the
    others are fixed anyway) and leave at least one to identify."""
    wrong = sorted(set(known) - set(IDENTIFIED[level]))
    if wrong:
        fixed = f" (level 1 holds the frictions at {LEVEL1_FIXED})" if level == 1 else ""
        raise ValueError(f"known parameter(s) {wrong} are not identified at level {level}{fixed}; known values may "
                         f"be given for {list(IDENTIFIED[level])}")
    if set(known) == set(IDENTIFIED[level]):
        raise ValueError(f"every parameter of level {level} is known: nothing left to identify")


def random_initial(seed: int, level: int) -> Parameters:
    """Uniform random values in the ranges for the identified parameters of ``level``;
    the level-1 frictions stay at :data:`LEVEL1_FIXED`."""
    rng = np.random.default_rng(seed)
    values = {n: float(rng.uniform(LOWER[n], UPPER[n])) for n in NAMES}
    if level == 1:
        values.update(LEVEL1_FIXED)
    return Parameters.checked(**values)


__all__ = [
    "NAMES", "LOWER", "UPPER", "STEP_SIZE", "IDENTIFIED", "LEVEL1_FIXED", "SCALE_FREE", "scale_free", "UNITS",
    "Parameters", "lame", "HAND_PICKED", "at_level", "hand_picked", "STIFFEST", "clip", "at_bound", "check_known",
    "random_initial",
]
