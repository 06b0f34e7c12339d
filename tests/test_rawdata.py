"""The raw dataset layout: a valid dataset loads; every bad input names its file; writers leave no partial output."""

import shutil

import numpy as np
import open3d as o3d
import pytest

from dpsi.motions import MOTIONS, plan, write_waypoints
from dpsi.files import atomic_output
from dpsi.pointclouds import View, write_mesh, write_points
from dpsi.rawdata import RawDataError, load_raw_dataset, write_datapoints_table, write_views

ROWS = [
    dict(id="dp1", motion="poking-1", effector="round", level=1, role="train", material="clay"),
    dict(id="dp2", motion="flattening", effector="cylinder", level=2, role="ood", material="clay"),
]


def pose(x):
    T = np.eye(4)
    T[:3, :3] = o3d.geometry.get_rotation_matrix_from_axis_angle([0.0, 0.3, 0.1])
    T[:3, 3] = [x, 0.0, 0.3]
    return T


@pytest.fixture()
def root(tmp_path):
    root = tmp_path / "raw" / "demo"
    root.mkdir(parents=True)
    (root / "dataset.yaml").write_text("table_z: 0.0\nworkspace: {lo: [-0.6, -0.1, -0.01], hi: [-0.4, 0.1, 0.1]}\n")
    write_datapoints_table(root / "datapoints.csv", ROWS)
    (root / "trajectories").mkdir()
    for name in ("poking-1", "flattening"):
        write_waypoints(root / "trajectories" / f"{name}.csv", plan(MOTIONS[name], seed=0))
    rng = np.random.default_rng(0)
    write_views(root / "dp1" / "before", [View(rng.normal(0, 0.02, (300, 3)) + [0, 0, 0.3], pose(k * 0.1))
                                          for k in range(3)])
    write_points(root / "dp1" / "after_fused.npy", rng.normal(0, 0.02, (500, 3)))
    box = o3d.geometry.TriangleMesh.create_box(0.05, 0.04, 0.03)
    (root / "dp2").mkdir()
    write_mesh(root / "dp2" / "before_mesh.obj", box)
    write_mesh(root / "dp2" / "after_mesh.ply", box)
    return root


def test_valid_dataset_loads(root):
    ds = load_raw_dataset(root)
    assert [d.id for d in ds.datapoints] == ["dp1", "dp2"]
    dp1, dp2 = ds.datapoints
    assert (dp1.before.form, dp1.after.form, dp2.before.form, dp2.after.form) == ("views", "fused", "mesh", "mesh")
    views = dp1.before.load()
    assert len(views) == 3
    np.testing.assert_allclose(views[2].camera_to_base, pose(0.2), atol=1e-12)
    assert dp1.after.load().shape == (500, 3)
    assert dp2.trajectory == root / "trajectories" / "flattening.csv"
    assert ds.workspace[0].tolist() == [-0.6, -0.1, -0.01] and ds.table_z == 0.0


def _edit_table(root, **change):
    rows = [dict(ROWS[0], **change), ROWS[1]]
    write_datapoints_table(root / "datapoints.csv", rows)
    return root / "datapoints.csv"


def _corrupt(path, text):
    path.write_text(text)
    return path


def _truncate(path, keep=0.5):
    """Cut a file to ``keep`` of its size (an interrupted copy)."""
    data = path.read_bytes()
    assert b"binary_little_endian" in data[:200]
    path.write_bytes(data[:int(len(data) * keep)])
    return path


def _nan_vertex(path):
    lines = path.read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("v "))
    lines[first] = "v nan 0 0"
    path.write_text("\n".join(lines) + "\n")
    return path


def _face_out_of_range(path):
    lines = path.read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("f "))
    lines[first] = "f 1 2 100000"  # crashed PyMeshLab (exit 139)
    path.write_text("\n".join(lines) + "\n")
    return path


BAD = {
    "missing transform": (lambda r: (r / "dp1/before/view_1.transform.txt").unlink() or r / "dp1/before/view_1.ply",
                          "transform"),
    "empty cloud": (lambda r: _corrupt(r / "dp1/before/view_2.ply", ""), "empty"),
    "malformed cloud": (lambda r: _corrupt(r / "dp1/before/view_0.ply", "ply\nformat nonsense\n"), "end_header"),
    "truncated binary cloud": (lambda r: _truncate(r / "dp1/before/view_1.ply"), "truncated PLY file"),
    "truncated ASCII cloud": (lambda r: _corrupt(r / "dp1/before/view_0.ply", "ply\nformat ascii 1.0\n"
                                                 "element vertex 3\nproperty float x\nproperty float y\n"
                                                 "property float z\nend_header\n0 0 0\n1 0 0\n"), "declares 3 rows"),
    "truncated binary mesh": (lambda r: _truncate(r / "dp2/after_mesh.ply", keep=0.9), "truncated PLY file"),
    "NaN vertex in an OBJ mesh": (lambda r: _nan_vertex(r / "dp2/before_mesh.obj"), r"line \d+: vertex 'nan"),
    "face index out of range": (lambda r: _face_out_of_range(r / "dp2/before_mesh.obj"),
                                "face refers to vertex 100000"),
    "pickled npy": (lambda r: np.save(r / "dp1/after_fused.npy", np.array([{}], dtype=object), allow_pickle=True)
                    or r / "dp1/after_fused.npy", "not a numeric .npy array"),
    "malformed npy": (lambda r: _corrupt(r / "dp1/after_fused.npy", "not an array"), "not a numeric .npy array"),
    "non-rigid transform": (lambda r: _corrupt(r / "dp1/before/view_1.transform.txt",
                                               "2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n"), "not rigid"),
    "reflection": (lambda r: _corrupt(r / "dp1/before/view_1.transform.txt",
                                      "-1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n"), "determinant"),
    "bad last row": (lambda r: _corrupt(r / "dp1/before/view_1.transform.txt",
                                        "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n"), "last row"),
    "gap in views": (lambda r: [(r / "dp1/before" / f).unlink() for f in ("view_0.ply", "view_0.transform.txt")]
                     and r / "dp1/before", "without gaps"),
    "unknown motion": (lambda r: _edit_table(r, motion="poking-9"), "unknown motion 'poking-9'"),
    "unknown effector": (lambda r: _edit_table(r, effector="spoon"), "unknown effector 'spoon'"),
    "wrong level": (lambda r: _edit_table(r, level=2), "level 1"),
    "bad role": (lambda r: _edit_table(r, role="test"), "role"),
    "missing trajectory": (lambda r: (r / "trajectories/poking-1.csv").unlink() or r / "trajectories/poking-1.csv",
                           "not found"),
    "non-monotone trajectory": (lambda r: _corrupt(r / "trajectories/flattening.csv",
                                                   "t,x,y,z,yaw\n0,0,0,0,0\n0.5,0,0,0,0\n0.4,0,0,0,0\n"),
                                "increase strictly"),
    "two forms": (lambda r: write_points(r / "dp1/after_fused.ply", np.ones((5, 3))) or r / "dp1", "exactly one form"),
    "no form": (lambda r: (r / "dp1/after_fused.npy").unlink() or r / "dp1", "exactly one form"),
    "open mesh": (lambda r: _corrupt(r / "dp2/after_mesh.ply", "ply\nformat ascii 1.0\nelement vertex 3\n"
                                     "property float x\nproperty float y\nproperty float z\nelement face 1\n"
                                     "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
                                     "3 0 1 2\n"), "not watertight"),
    "missing datapoint folder": (lambda r: shutil.rmtree(r / "dp2") or r / "dp2", "not found"),
    "bad effector kind": (lambda r: _corrupt(r / "dataset.yaml", "effectors: {spoon: {kind: ladle}}\n"), "ladle"),
    "views without workspace": (lambda r: _corrupt(r / "dataset.yaml", "table_z: 0.0\n"), "workspace"),
    "id too long for a file name": (lambda r: _edit_table(r, id="d" * 240), r"id 'd{39}… \(240 characters\) must be"),
    "YAML syntax error": (lambda r: _corrupt(r / "dataset.yaml", "table_z: [0.0\n"), "not valid YAML"),
    "python tag in YAML": (lambda r: _corrupt(r / "dataset.yaml", "table_z: !!python/object/apply:os.getpid []\n"),
                           r"\(line 1\): tags such as .*python/object/apply:os.getpid.* are not allowed"),
    "effectors of the wrong type": (lambda r: _corrupt(r / "dataset.yaml", "effectors: [round]\n"),
                                    "effectors must be a mapping"),
    "workspace corner of the wrong type": (
        lambda r: _corrupt(r / "dataset.yaml", "workspace: {lo: 0, hi: [1, 1, 1]}\n"),
        r"workspace.lo must be three numbers \[x, y, z\] in m, not 0"),
    "absolute effector path": (
        lambda r: _corrupt(r / "dataset.yaml", f"effectors: {{mine: {{obj: {r / 'dp2/before_mesh.obj'}}}}}\n"),
        "effectors.mine.obj is the absolute path .*; paths in dataset.yaml must be relative"),
    "effector path leaving the dataset": (
        lambda r: _corrupt(r / "dataset.yaml", "effectors: {mine: {obj: ../tool.obj}}\n"),
        "effectors.mine.obj '../tool.obj' leads outside the dataset folder"),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_input_names_the_file(root, case):
    damage, problem = BAD[case]
    bad_path = damage(root)
    with pytest.raises(RawDataError, match=problem) as err:
        load_raw_dataset(root)
    assert str(bad_path) in str(err.value)


def test_spaces_around_csv_names_and_values_are_dropped(root):
    """"id, motion, …" once gave "missing column(s) ['motion', …]"."""
    table = root / "datapoints.csv"
    table.write_text("\n".join(", ".join(line.split(",")) for line in table.read_text().splitlines()) + "\n")
    trajectory = root / "trajectories" / "poking-1.csv"
    lines = trajectory.read_text().splitlines()
    trajectory.write_text("\n".join([" t , x , y , z , yaw", *lines[1:]]) + "\n")
    ds = load_raw_dataset(root)
    assert [(d.id, d.motion, d.effector, d.role) for d in ds.datapoints] == [
        ("dp1", "poking-1", "round", "train"), ("dp2", "flattening", "cylinder", "ood")]


def test_ood_motion_with_the_wrong_effector(root):
    write_datapoints_table(root / "datapoints.csv", [ROWS[0], dict(ROWS[1], effector="round")])
    with pytest.raises(RawDataError, match="cylinder effector") as err:
        load_raw_dataset(root)
    assert "datapoints.csv" in str(err.value)


def test_write_views_validates_before_writing(tmp_path):
    bad = pose(0.0)
    bad[:3, :3] *= 1.01  # a scaled, non-rigid transform in the last view
    views = [View(np.ones((4, 3)), pose(0.0)), View(np.ones((4, 3)), bad)]
    with pytest.raises(RawDataError, match="view_1.transform.txt"):
        write_views(tmp_path / "state", views)
    assert not (tmp_path / "state").exists()


def test_failed_write_leaves_no_partial_file(tmp_path):
    target = tmp_path / "cloud.ply"
    write_points(target, np.zeros((3, 3)))
    before = target.read_bytes()
    with pytest.raises(ValueError, match="non-finite"):
        write_points(target, np.array([[0.0, 0.0, np.nan]]))
    with pytest.raises(RuntimeError):
        with atomic_output(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("interrupted")
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["cloud.ply"]
