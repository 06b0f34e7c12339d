import json
import math

import pytest

from dpsi.parameters import HAND_PICKED, IDENTIFIED, LOWER, NAMES, STEP_SIZE, UPPER, random_initial
from dpsi.optim import Adam, screen_gradients

OPTIMUM = {"E": 1.2e5, "nu": 0.3, "rho": 1500.0, "yield_stress": 5e3, "mu_table": 0.5, "mu_effector": 1.2}


def quadratic_gradient(values, optimum=OPTIMUM):
    """Gradient of Σ ((x − x*) / range)², a separable quadratic."""
    return {n: 2 * (v - optimum[n]) / (UPPER[n] - LOWER[n]) ** 2 for n, v in values.items()}


def run(adam, iterations, optimum=OPTIMUM):
    for _ in range(iterations):
        adam.step(quadratic_gradient(adam.values, optimum))
    return adam.values


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_adam_converges_on_a_separable_quadratic(seed):
    values = run(Adam.for_level(random_initial(seed, 2), 2), 1000)
    for name in NAMES:
        assert values[name] == pytest.approx(OPTIMUM[name], abs=1e-3 * (UPPER[name] - LOWER[name])), name


def test_adam_stops_at_the_bound_when_the_optimum_is_outside():
    optimum = {**OPTIMUM, "E": 5e5, "nu": -0.2}
    values = run(Adam.for_level(random_initial(0, 1), 1), 300, optimum)
    assert values["E"] == UPPER["E"] and values["nu"] == LOWER["nu"]
    assert values["rho"] == pytest.approx(OPTIMUM["rho"], abs=1.0)


def test_first_step_moves_each_parameter_by_its_step_size():
    adam = Adam.for_level(HAND_PICKED, 1)
    assert set(adam.values) == set(IDENTIFIED[1])
    gradient = {"E": 1e-9, "nu": -3.0, "rho": 2e-4, "yield_stress": -5.0, "mu_table": 7.0}  # extras are ignored
    values = adam.step(gradient)
    for name in IDENTIFIED[1]:
        g = gradient[name]  # first step: lr · g / (|g| + ε), so a gradient below ε shortens it (E)
        expected = getattr(HAND_PICKED, name) - STEP_SIZE[1][name] * g / (abs(g) + 1e-8)
        assert values[name] == pytest.approx(expected, rel=1e-12), name
    assert values["E"] == pytest.approx(HAND_PICKED.E - 4000 / 11)
    assert values["nu"] == pytest.approx(HAND_PICKED.nu + 0.01)


def test_values_are_clipped_to_the_ranges():
    adam = Adam({"nu": 0.475, "rho": 1005.0}, {"nu": 0.01, "rho": 10.0})
    values = adam.step({"nu": -1.0, "rho": 1.0})
    assert values == {"nu": UPPER["nu"], "rho": LOWER["rho"]}


def test_state_round_trips_through_json_and_resumes_bit_for_bit():
    uninterrupted = Adam.for_level(random_initial(1, 2), 2)
    run(uninterrupted, 40)

    first = Adam.for_level(random_initial(1, 2), 2)
    run(first, 17)
    resumed = Adam.from_state(json.loads(json.dumps(first.state())))
    assert resumed.state() == first.state()
    run(resumed, 23)
    assert resumed.state() == uninterrupted.state()  # exact float equality


@pytest.mark.parametrize("build, message", [
    (lambda: Adam({"G": 1.0}, {"G": 1.0}), "unknown: \\['G'\\]"),
    (lambda: Adam({"nu": 0.6}, {"nu": 0.01}), "nu=0.6 is outside"),
    (lambda: Adam({"nu": 0.3}, {}), "step size of nu"),
    (lambda: Adam.for_level(HAND_PICKED, 3), "unknown level 3"),
    (lambda: Adam({"nu": 0.3}, {"nu": 0.01}).step({"rho": 1.0}), "missing .*nu"),
    (lambda: Adam({"nu": 0.3}, {"nu": 0.01}).step({"nu": math.nan}), "not finite"),
    (lambda: Adam.from_state({"values": {}}), "keys"),
])
def test_bad_input_is_named(build, message):
    with pytest.raises(ValueError, match=message):
        build()


def gradient(**overrides):
    return {**{n: 1.0 for n in NAMES}, **overrides}


def test_screening_rules():
    gradients = [
        gradient(E=2.0),                                         # kept
        gradient(E=4.0),                                         # kept
        gradient(nu=math.nan),                                   # NaN gradient
        gradient(rho=-math.inf),                                 # inf gradient
        gradient(),                                              # NaN loss
        gradient(yield_stress=-2e6),                             # too large
        gradient(E=0.0, nu=0.0, rho=0.0, yield_stress=0.0, mu_table=0.0),  # five zeros
    ]
    losses = [1.0, 2.0, 3.0, 4.0, math.nan, 6.0, 7.0]
    screened = screen_gradients(gradients, losses)
    assert screened.skipped == 5
    assert screened.gradient == {**gradient(), "E": 3.0}


def test_screening_boundaries_are_kept():
    kept = gradient(E=1e6, nu=-1e6, rho=0.0, yield_stress=0.0, mu_table=0.0, mu_effector=0.0)  # four zeros
    screened = screen_gradients([kept], [1.0])
    assert screened.skipped == 0 and screened.gradient == kept


def test_screening_everything_skipped():
    assert screen_gradients([gradient(E=math.inf)], [1.0]) == (None, 1)


def test_screening_input_errors():
    with pytest.raises(ValueError, match="1 gradients but 2 losses"):
        screen_gradients([gradient()], [1.0, 2.0])
    with pytest.raises(ValueError, match="datapoint 0"):
        screen_gradients([{"E": 1.0}], [1.0])
