"""Loss landscapes (SPEC §7.1): the grid, every loss from one simulation per grid point and datapoint,
failed simulations as NaN cells, the file round trip, the heat maps, and the workflow's outputs."""

import json

import numpy as np
import pytest
import yaml

from conftest import TINY, snakemake
from dpsi.datapoint import Datapoint
from dpsi.effectors import ROUND
from dpsi.heightmap import height_map
from dpsi.identification import scene
from dpsi.landscape_compute import compute
from dpsi.landscapes import PAIRS, Landscape, axis, load_landscape, pair_by_name, save_landscape
from dpsi.motions import Trajectory
from dpsi.parameters import HAND_PICKED, LOWER, UPPER, Parameters
from dpsi.reconstruction.filling import pcd_target
from dpsi.reporting.landscapes import centred, plot_landscapes
from dpsi.simulation import SimulationError, Simulator, SimulatorConfig

SPACING = 0.004
CONFIG = SimulatorConfig(dx=0.006, width=0.08, height=0.05, max_particles=1000, max_steps=40)
LOSSES = ("prt_cd", "pcd_emd", "heightmap")


def block() -> np.ndarray:
    """A 2 × 2 × 1.2 cm block of particles (75) on the table z = 0."""
    xy = np.arange(-0.008, 0.0081, SPACING)
    z = np.arange(SPACING / 2, 0.012, SPACING)
    return np.stack(np.meshgrid(xy, xy, z, indexing="ij"), -1).reshape(-1, 3)


def datapoint(after: np.ndarray | None = None) -> Datapoint:
    """The block poked 6 mm down in 8 steps and lifted by 3 mm in 4, with targets taken from ``after``
    (default: the block itself; its height map drawn with particle cubes, as a simulated one is)."""
    particles = block()
    after = particles if after is None else after
    z = np.concatenate([np.linspace(0.0, -0.006, 9), np.linspace(-0.006, -0.003, 5)[1:]])
    centre = particles[:, :2].mean(axis=0)
    return Datapoint("poke", "poke", ROUND, particles, SPACING**3,
                     Trajectory(np.column_stack([np.zeros((len(z), 2)), z]), np.zeros(len(z))),
                     np.array([*centre, particles[:, 2].max() + SPACING / 2]), 0.0,
                     pcd_target(after), after, height_map(after, centre, particle_size=SPACING), centre)


class FakeSimulator:
    """Stands in for :class:`Simulator`: stretches the particles in z by E / 5e4 (so the losses are
    lowest at E = 5e4 Pa), counts its simulations, and fails where ``fails(params)`` is true."""

    def __init__(self, fails=lambda params: False):
        self.fails, self.calls = fails, 0

    def forward(self, scene, params: Parameters, keep_substeps: bool = True) -> np.ndarray:
        self.calls += 1
        if self.fails(params):
            raise SimulationError(f"unstable at {params.as_dict()}")
        return scene.particles * [1.0, 1.0, params.E / 5e4]


def test_axes_span_the_full_ranges():
    for name in ("E", "mu_effector"):
        values = axis(name, 30)
        assert values.shape == (30,) and values[0] == LOWER[name] and values[-1] == UPPER[name]
        assert np.all(np.diff(values) > 0)
    with pytest.raises(ValueError, match="at least 2"):
        axis("E", 1)
    with pytest.raises(ValueError, match="unknown parameter"):
        axis("stiffness", 3)
    assert [p.name for p in PAIRS] == ["E-nu", "yield_stress-rho", "mu_table-mu_effector"]
    assert pair_by_name("mu_table-mu_effector").level == 2
    with pytest.raises(ValueError, match="E-nu"):
        pair_by_name("nu-E")


def test_one_simulation_per_grid_point_and_datapoint_serves_every_loss():
    simulator = FakeSimulator()
    datapoints = [datapoint(), datapoint(block() + [0.0, 0.0, 0.001])]
    landscape = compute(simulator, datapoints, pair_by_name("E-nu"), HAND_PICKED, 4, LOSSES)
    assert simulator.calls == 4 * 4 * len(datapoints)
    assert landscape.values.shape == (len(LOSSES), 4, 4) and np.isfinite(landscape.values).all()
    assert landscape.losses == LOSSES and landscape.fixed == HAND_PICKED
    # the fake simulation does not depend on ν: each row of constant E holds one value
    assert np.allclose(landscape.values, landscape.values[:, :, :1])
    assert np.all(landscape.values[:, 0, 0] < landscape.values[:, -1, 0])  # E = 1e4 is nearer 5e4 than 3e5


def test_failed_simulations_become_nan_cells():
    simulator = FakeSimulator(fails=lambda params: params.E > 2e5 and params.nu > 0.4)
    landscape = compute(simulator, [datapoint()], pair_by_name("E-nu"), HAND_PICKED, 3, LOSSES)
    failed = np.zeros((3, 3), bool)
    failed[2, 2] = True
    assert np.isnan(landscape.values[:, failed]).all()
    assert np.isfinite(landscape.values[:, ~failed]).all()


def test_a_landscape_whose_every_simulation_fails_is_refused():
    with pytest.raises(SimulationError, match="every simulation of the E-nu landscape failed.*unstable"):
        compute(FakeSimulator(fails=lambda params: True), [datapoint()], pair_by_name("E-nu"), HAND_PICKED, 2,
                LOSSES)
    with pytest.raises(ValueError, match="unknown loss"):
        compute(FakeSimulator(), [datapoint()], pair_by_name("E-nu"), HAND_PICKED, 2, ["chamfer"])


def test_centre_of_the_grid_that_made_the_target_is_its_minimum():
    """A real simulation: targets made with σ_y and ρ at the centre of a 3 × 3 grid."""
    pair = pair_by_name("yield_stress-rho")
    truth = HAND_PICKED.replace(**{pair.first: axis(pair.first, 3)[1], pair.second: axis(pair.second, 3)[1]})
    simulator = Simulator(CONFIG)
    target = datapoint(simulator.forward(scene(datapoint()), truth))
    landscape = compute(simulator, [target], pair, HAND_PICKED, 3, LOSSES)
    assert landscape.values.shape == (len(LOSSES), 3, 3) and np.isfinite(landscape.values).all()
    centre = landscape.values[:, 1, 1]
    assert np.allclose(centre[[0, 2]], 0.0, atol=1e-9)  # the PRT target and height map are the simulation's own
    others = np.delete(landscape.values.reshape(len(LOSSES), 9), 4, axis=1)
    assert np.all(others[[0, 2]] > 0.1) and np.all(others[1] > centre[1])


def test_file_round_trip_and_heat_maps(tmp_path):
    pair = pair_by_name("mu_table-mu_effector")
    x, y = axis(pair.first, 5), axis(pair.second, 4)
    values = np.stack([np.add.outer((x - 1.0) ** 2, y), np.add.outer(x, y**2)]) * 100.0
    values[0, 4, 3] = np.nan
    landscape = Landscape(pair, ("prt_cd", "heightmap"), x, y, values, HAND_PICKED)
    save_landscape(tmp_path / "l.npz", landscape)
    loaded = load_landscape(tmp_path / "l.npz")
    assert loaded.pair == pair and loaded.losses == landscape.losses and loaded.fixed == HAND_PICKED
    np.testing.assert_array_equal(loaded.values, values)
    shifted = centred(values[0])
    assert np.isnan(shifted[4, 3]) and abs(np.nanmean(shifted)) < 1e-9
    plot_landscapes([("1-round", loaded), ("6-mix", landscape)], tmp_path / "f.png", tmp_path / "f.pdf")
    assert (tmp_path / "f.png").stat().st_size > 10_000 and (tmp_path / "f.pdf").stat().st_size > 5_000
    other = Landscape(pair, ("prt_cd",), x, y, values[:1], HAND_PICKED)
    with pytest.raises(ValueError, match="differs"):
        plot_landscapes([("1-round", landscape), ("6-mix", other)], tmp_path / "g.png", tmp_path / "g.pdf")
    with pytest.raises(ValueError, match="expected"):
        Landscape(pair, ("prt_cd",), x, y, values, HAND_PICKED)
    with pytest.raises(ValueError, match="not a complete landscape file"):
        load_landscape(tmp_path / "f.png")


def test_workflow_makes_every_landscape_and_its_figure(tiny_run):
    config = yaml.safe_load(TINY.read_text())
    settings, levels = config["analyses"]["landscapes"], config["identification"]["levels"]
    folder = tiny_run / "results" / config["dataset"]
    truth = json.loads((tiny_run / "results" / config["dataset"] / "raw" / "truth.json").read_text())["materials"]["clay"]
    resolution = settings["resolution"]
    pairs = [p for p in PAIRS if p.level in levels]
    assert len(pairs) == 3
    for pair in pairs:
        for dataset in settings["datasets"]:
            landscape = load_landscape(folder / "landscapes" / pair.name / f"{dataset}.npz")
            assert landscape.values.shape == (len(settings["losses"]), resolution, resolution)
            assert np.isfinite(landscape.values).all()
            assert landscape.losses == tuple(settings["losses"]) and landscape.pair == pair
            np.testing.assert_array_equal(landscape.first, axis(pair.first, resolution))
            assert landscape.fixed == Parameters.checked(**truth)
        for suffix in ("png", "pdf"):
            assert (tiny_run / "results" / "twin-tiny" / "figures" / f"landscapes_{pair.name}.{suffix}").stat().st_size > 10_000


def test_a_landscape_dataset_the_datapoints_cannot_form_fails_at_start_up(tmp_path):
    config = yaml.safe_load(TINY.read_text())
    config["analyses"]["landscapes"]["datasets"] = ["1-cylinder"]
    path = tmp_path / "cylinder.yaml"
    path.write_text(yaml.safe_dump(config))
    run = snakemake(tmp_path, "-n", "landscapes", config=path)
    assert run.returncode != 0
    assert "analyses.landscapes" in run.stderr + run.stdout and "cylinder" in run.stderr + run.stdout
