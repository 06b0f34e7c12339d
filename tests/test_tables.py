"""The main table (best_params) on made-up run summaries: a parameter that ends on its bound is flagged."""

from dpsi.parameters import HAND_PICKED, LEVEL1_FIXED
from dpsi.reporting.tables import best_params_table

BASELINES = {(level, "v0"): {"hand_picked": {"heightmap_mm": 2500.0}, "no_motion": {"heightmap_mm": 3000.0}}
             for level in (1, 2)}
"""The baselines of the one validation datapoint ``v0`` of each level."""


def _run(level, dataset, known=(), **values):
    inside = HAND_PICKED.replace(yield_stress=2e3)  # the hand-picked σ_y lies on its lower bound
    parameters = inside.replace(**(LEVEL1_FIXED if level == 1 else {}), **values).as_dict()
    return {"level": level, "loss": "prt_cd", "dataset": dataset, "seed": 0, "known": sorted(known),
            "validation": [["v0", 500, 94]],
            "best": {"iteration": 3, "parameters": parameters, "validation": {"heightmap_mm": 2000.0}}}


def test_identified_parameters_on_a_bound_are_flagged():
    """At level 1 μ_t = 2 is fixed (not identified) and a known ρ is held: neither is flagged, though both lie
    on a bound; at level 2 μ_t is identified and flagged."""
    table = best_params_table([_run(1, "1-round", E=3e5, nu=0.01), _run(1, "1-cylinder", known=["rho"], rho=1000.0),
                               _run(2, "1-round", mu_table=2.0), _run(2, "6-mix")], BASELINES)
    flags = table.set_index(["level", "loss", "dataset"]).at_bound
    assert flags[(1, "prt_cd", "1-round")] == "E=upper; nu=lower"
    assert flags[(1, "prt_cd", "1-cylinder")] == ""
    assert flags[(2, "prt_cd", "1-round")] == "mu_table=upper"
    assert flags[(2, "prt_cd", "6-mix")] == ""
    assert (table[table.dataset.isin(["average", ""])].at_bound == "").all()
    assert list(table.columns)[-1] == "at_bound"
