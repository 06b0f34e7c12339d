"""What a run's data determine (dpsi.uncertainty): intervals from a quadratic model of the loss within its bootstrap
spread, checked on quadratic losses with known answers, on a tiny simulated scene with the scale symmetry of E, ρ
and σ_y, and the coverage count."""

import math

import numpy as np
import pandas as pd
import pytest

from dpsi.identification import uncertainty_at
from dpsi.simulation import Simulator
from dpsi.uncertainty import (DIRECTION_LABEL, Evaluation, UncertaintyError, assess, coverage, curvature,
                              difference_basis, model, resample, true_value)

from test_identification import CONFIG, TRUTH, synthetic

NAMES = ["E", "nu", "yield_stress"]
X0 = np.log([5e4, 0.3, 2500.0])
BOX = (X0 - 6.0, X0 + 6.0)
HESSIAN = np.array([[4.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 0.0]])
"""A loss curved in (E, ν) and flat along σ_y."""
TERMS = np.linspace(0.0, 3.0, 31)
"""The loss's terms at the estimate, whose bootstrap spread is the tolerance."""


def quadratic(hessian, minimum):
    """``evaluate`` of the loss ½(x − minimum)ᵀ H (x − minimum) with the fixed :data:`TERMS`."""
    def evaluate(x):
        d = np.asarray(x) - minimum
        return Evaluation(0.5 * d @ hessian @ d, hessian @ d, (TERMS,))
    return evaluate


def by_quantity(block):
    return {q["quantity"]: q for q in block["quantities"]}


def test_a_quadratic_loss_gives_its_hessian_and_the_known_intervals_and_directions():
    x0 = X0
    block = assess(NAMES, x0, *BOX, quadratic(HESSIAN, x0), samples=4000)
    assert np.array(block["hessian_mm"]) == pytest.approx(HESSIAN, abs=1e-9)
    assert block["evaluations"] == 7  # the estimate and two per free parameter
    # one datapoint: the bootstrap spread of a sum of n terms is √n times their standard deviation
    assert block["tolerance_mm"] == pytest.approx(math.sqrt(len(TERMS)) * TERMS.std(), rel=0.05)
    tolerance, inverse = block["tolerance_mm"], np.linalg.inv(HESSIAN[:2, :2])
    q = by_quantity(block)
    for k, name in enumerate(["E", "nu"]):
        half = math.sqrt(2 * tolerance * inverse[k, k])
        assert q[name]["determined"] and q[name]["factor"] == pytest.approx(math.exp(half))
        assert (q[name]["low"], q[name]["high"]) == pytest.approx(tuple(math.exp(x0[k] + s * half) for s in (-1, 1)))
    assert not q["yield_stress"]["determined"] and not q["yield_stress/E"]["determined"]
    assert (q["yield_stress"]["low"], q["yield_stress"]["high"]) == pytest.approx((2500 * math.exp(-6),
                                                                                    2500 * math.exp(6)))
    # the principal directions: the eigenvectors of H, the stiffest first, the flat one marked
    values, vectors = np.linalg.eigh(HESSIAN[:2, :2])
    stiffest = {"E": 1.0, "nu": round(vectors[1, 1] / vectors[0, 1], 2)}
    assert [d["eigenvalue_mm"] for d in block["directions"]] == pytest.approx([values[1], values[0], 0.0], abs=1e-9)
    assert [d["flat"] for d in block["directions"]] == [False, False, True]
    assert block["directions"][0]["exponents"] == stiffest and block["directions"][2]["exponents"] == {"yield_stress": 1}
    assert q[f"E^1*nu^{stiffest['nu']:.3g}"]["determined"]


def test_an_estimate_off_the_minimum_reaches_over_the_minimum_and_holds_the_estimate():
    """{x: L(x) ≤ L(x0) + Δ} for L = ½ a (x − m)²: m ± √(2 (Δ + L(x0)) / a)."""
    a, m, x0, tolerance = 8.0, 0.5, 0.8, 0.2
    quadratic_model = model([a * (x0 - m)], [[a]], tolerance, [-6.0], [6.0])
    half = math.sqrt(2 * (tolerance + 0.5 * a * (x0 - m) ** 2) / a)
    assert quadratic_model.centre == pytest.approx([m - x0])
    assert quadratic_model.budget * 2 * quadratic_model.inverse[0, 0] == pytest.approx(half**2)
    assert m - half < x0 < m + half


def test_the_difference_step_is_shortened_at_a_bound_and_an_interval_reaching_it_is_not_determined():
    x0 = np.log([1.05e4, 0.3, 2500.0])  # E 5 % above its lower bound 1e4: no room for −10 %
    lower, upper = np.log([1e4, 0.01, 1e3]), np.log([3e5, 0.48, 2e4])
    hessian = np.diag([0.5, 50.0, 50.0])
    measured = curvature(quadratic(hessian, x0), x0, lower, upper)
    assert measured.hessian == pytest.approx(hessian)
    block = assess(NAMES, x0, lower, upper, quadratic(hessian, x0))
    e = by_quantity(block)["E"]
    assert not e["determined"] and e["low"] == pytest.approx(1e4) and e["high"] < 3e5
    assert by_quantity(block)["nu"]["determined"]


def test_the_tolerance_is_the_bootstrap_spread_of_the_mean_loss_over_datapoints_and_their_terms():
    rng = np.random.default_rng(1)
    one = rng.exponential(2.0, 200)
    within = resample([one], samples=4000).tolerance_mm
    assert within == pytest.approx(math.sqrt(200) * one.std(), rel=0.05)
    # two datapoints whose losses differ by 200 mm: drawing both datapoints from the two adds (L2 − L1) / (2√2)
    both = resample([one, one + 1.0], samples=4000).tolerance_mm
    assert both == pytest.approx(math.hypot(within / math.sqrt(2), 200 / (2 * math.sqrt(2))), rel=0.05)
    with pytest.raises(UncertaintyError, match="not finite"):
        resample([np.array([1.0, np.nan])])


def test_a_symmetry_is_a_difference_direction_and_its_quantities_are_orthogonal_to_it():
    names = ["E", "nu", "rho", "yield_stress"]
    basis = difference_basis(names)
    assert basis.T @ basis == pytest.approx(np.eye(4))
    assert abs(basis[:, 0]) == pytest.approx(np.array([1, 0, 1, 1]) / math.sqrt(3))
    assert difference_basis(["E", "nu", "yield_stress"]) == pytest.approx(np.eye(3))  # ρ held: no symmetry


def test_coverage_counts_the_truths_inside_the_determined_intervals():
    truth = 2.0
    rows = []
    for rung, intervals in {"R0": [(1.9, 2.1, True), (1.5, 2.5, True), (2.1, 2.4, True), (0.1, 40.0, False)],
                            "R1": [(1.0, 4.0, True), (2.2, 3.0, False)]}.items():
        for seed, (low, high, determined) in enumerate(intervals):
            for quantity in ("E", "yield_stress^1*E^-0.9"):
                rows.append(dict(rung=rung, level=1, loss="prt_emd", dataset="1-round", seed=seed, quantity=quantity,
                                 estimate=math.sqrt(low * high), low=low, high=high, determined=determined, truth=truth))
    rows.append({**rows[0], "loss": "pcd_emd"})  # the same run under another name counts once
    rows.append({**rows[0], "seed": 9, "truth": math.nan})  # no truth: left out
    table = coverage(pd.DataFrame(rows)).set_index(["rung", "quantity"])
    r0 = table.loc[("R0", "E")]
    assert (r0.runs, r0.determined, r0.covered) == (4, 3, 2) and r0.coverage == pytest.approx(2 / 3)
    assert r0.median_factor == pytest.approx(math.sqrt(2.4 / 2.1))  # of 1.05, 1.29 and 1.07
    assert table.loc[("R0", DIRECTION_LABEL)].covered == 2
    assert table.loc[("R0", "all")].runs == 8 and table.loc[("R0", "all")].coverage == pytest.approx(2 / 3)
    r1 = table.loc[("R1", "E")]
    assert (r1.determined, r1.covered, r1.coverage, r1.median_factor) == (1, 1, 1.0, pytest.approx(2.0))


def test_a_quantity_s_truth_is_the_product_of_powers():
    assert true_value({"yield_stress": 1.0, "E": -1.0}, {"E": 5e4, "yield_stress": 2.5e3}) == pytest.approx(0.05)


def test_on_a_tiny_scene_the_common_scale_of_e_rho_and_yield_stress_is_flat_and_the_ratios_are_determined():
    """Two pokes of a 245-particle block with targets simulated at the truth; the estimate a few per cent off it."""
    simulator = Simulator(CONFIG)
    training = [synthetic(simulator, "round", 0.008), synthetic(simulator, "rectangle", 0.008)]
    estimate = TRUTH.replace(E=1.06 * TRUTH.E, nu=0.95 * TRUTH.nu, rho=1.03 * TRUTH.rho,
                             yield_stress=1.04 * TRUTH.yield_stress)
    names = ["E", "nu", "rho", "yield_stress"]
    block = uncertainty_at(simulator, training, estimate, "prt_emd", names)
    assert block["evaluations"] == 9 and block["tolerance_mm"] > 0
    hessian, scale = np.array(block["hessian_mm"]), np.array([1.0, 0.0, 1.0, 1.0]) / math.sqrt(3)
    largest = np.abs(np.linalg.eigvalsh(hessian)).max()
    assert abs(scale @ hessian @ scale) < 1e-9 * largest and np.abs(hessian @ scale).max() < 1e-9 * largest
    flat = [d for d in block["directions"] if d["flat"]]
    assert [d["exponents"] for d in flat] == [{"E": 1.0, "rho": 1.0, "yield_stress": 1.0}]
    q = by_quantity(block)
    assert not any(q[n]["determined"] for n in ("E", "rho", "yield_stress"))
    for ratio in ("E/rho", "yield_stress/E"):
        assert q[ratio]["determined"] and q[ratio]["factor"] < 2.5, q[ratio]
        assert q[ratio]["low"] < true_value(q[ratio]["exponents"], TRUTH.as_dict()) < q[ratio]["high"]
