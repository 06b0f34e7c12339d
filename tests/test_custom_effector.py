"""An effector defined by a mesh in dataset.yaml (docs/raw-format.md) works end to end: validated with
the raw dataset, carried by the prepared datapoint (also through its file) and simulated by
identification."""

import io

import numpy as np
import open3d as o3d
import pytest
import yaml

from dpsi.datapoint import load_datapoint, save_datapoint
from dpsi.effectors import GRID, SDF_GRID_RESOLUTION
from dpsi.identification import identify, scene
from dpsi.motions import MOTIONS, plan, write_waypoints
from dpsi.parameters import HAND_PICKED
from dpsi.pointclouds import write_mesh
from dpsi.prepare import prepare_datapoint
from dpsi.rawdata import load_raw_dataset, write_datapoints_table
from dpsi.shapes import lump
from dpsi.simulation import Simulator, SimulatorConfig

CENTRE = (-0.52, 0.01)
BEFORE = lump((0.03, 0.025), wall=0.012, top=0.03, centre=CENTRE)
PRESSED = lump((0.032, 0.026), wall=0.012, top=0.022, centre=CENTRE)
DENSITY = 2e7
PLATE = (0.02, 0.04, 0.05)
"""The custom effector: a 20 × 40 mm plate, 50 mm tall, tip (its bottom face) at the origin (m)."""


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("custom") / "raw"
    (root / "effectors").mkdir(parents=True)
    plate = o3d.geometry.TriangleMesh.create_box(*PLATE).translate((-PLATE[0] / 2, -PLATE[1] / 2, 0.0))
    write_mesh(root / "effectors" / "plate.obj", plate)
    (root / "dataset.yaml").write_text(yaml.safe_dump({"table_z": 0.0,
                                                       "effectors": {"plate": {"obj": "effectors/plate.obj"}}}))
    write_datapoints_table(root / "datapoints.csv", [
        dict(id="train", motion="poking-2", effector="plate", level=1, role="train", material="clay"),
        dict(id="val", motion="poking-2", effector="plate", level=1, role="validation", material="clay")])
    (root / "trajectories").mkdir()
    write_waypoints(root / "trajectories" / "poking-2.csv", plan(MOTIONS["poking-2"], seed=1, start_xyz=(*CENTRE, 0.03)))
    for folder in ("train", "val"):
        (root / folder).mkdir()
        write_mesh(root / folder / "before_mesh.obj", BEFORE)
        write_mesh(root / folder / "after_mesh.obj", PRESSED)
    return load_raw_dataset(root)


def test_mesh_effector_from_validation_to_an_identification_iteration(dataset, tmp_path):
    assert dataset.effectors["plate"].obj is not None
    train, val = (prepare_datapoint(dataset, i, DENSITY) for i in ("train", "val"))
    effector = train.effector
    assert (effector.name, effector.kind) == ("plate", GRID)
    assert effector.sdf.shape == (SDF_GRID_RESOLUTION,) * 3
    # the signed distance at the middle of the plate's bottom face is 0, 1 cm below it +1 cm
    lower, spacing = np.asarray(effector.sdf_lower), effector.sdf_spacing
    assert effector.sdf.min() < 0 < effector.sdf.max()
    assert np.all(lower <= [-PLATE[0] / 2, -PLATE[1] / 2, 0.0]) and lower[2] + spacing * 39 >= PLATE[2]

    save_datapoint(tmp_path / "train.npz", train)
    again = load_datapoint(tmp_path / "train.npz")
    assert again.effector == effector  # name, kind, size, yaw, grid placement
    np.testing.assert_array_equal(again.effector.sdf, effector.sdf)

    simulator = Simulator(SimulatorConfig(max_particles=2000))
    final = simulator.forward(scene(again), HAND_PICKED, keep_substeps=False)
    pressed = again.particles[:, 2].max() - final[:, 2].max()
    assert pressed > 0.001  # the plate went down into the clay and pushed its top down (1.3 mm seen)

    summary = identify(tmp_path / "run", 1, "prt_cd", [again], [val], iterations=1, simulator=simulator,
                       progress=io.StringIO())
    assert summary["completed_iterations"] == 1 and summary["skipped_total"] == 0
    assert np.isfinite(summary["best"]["validation"]["heightmap_mm"])
