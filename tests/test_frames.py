"""Frames along a trajectory: the simulator's per-step positions and the real-vs-simulated figure."""

import matplotlib.image as mpimg
import numpy as np
import pytest

from dpsi import effectors
from dpsi.datapoint import Datapoint
from dpsi.motions import Trajectory
from dpsi.parameters import HAND_PICKED
from dpsi.reporting.frames import frame_steps, plot_frames
from dpsi.simulation import Scene, Simulator, SimulatorConfig


def test_frame_steps_span_the_trajectory_evenly():
    assert frame_steps(100).tolist() == [0, 25, 50, 75, 100]
    assert frame_steps(2).tolist() == [0, 1, 2]
    with pytest.raises(ValueError, match="two frames"):
        frame_steps(10, count=1)


def lump(spacing=0.004):
    axes = [np.arange(-0.012, 0.012, spacing)] * 2 + [np.arange(0.002, 0.014, spacing)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def sinking_tip(steps=12):
    k = np.arange(steps + 1)[:, None]
    return Trajectory(np.hstack([0 * k, 0 * k, -0.0005 * k]), np.zeros(steps + 1))


def test_positions_at_steps_are_the_simulated_states():
    """Step 0 is the initial state, the last step the final positions; in between the object is
    being pressed, so the top particles sink monotonically."""
    particles = lump()
    scene = Scene(particles, 0.004 ** 3, effectors.RECTANGLE, sinking_tip(), [0.0, 0.0, particles[:, 2].max()])
    sim = Simulator(SimulatorConfig(width=0.08, height=0.05, max_particles=500, max_steps=20))
    final = sim.forward(scene, HAND_PICKED, keep_substeps=False)
    frames = sim.positions_at([0, 6, 12])
    np.testing.assert_array_equal(frames[0], particles)
    np.testing.assert_array_equal(frames[-1], final)
    top = particles[:, 2] == particles[:, 2].max()
    heights = frames[:, top, 2].mean(axis=1)
    assert heights[0] > heights[1] > heights[2]
    with pytest.raises(ValueError, match="0..12"):
        sim.positions_at([13])


def datapoint(particles):
    return Datapoint(id="d", motion="flattening", effector=effectors.CYLINDER, particles=particles,
                     particle_volume=1e-7, trajectory=sinking_tip(), start=np.array([0.0, 0.0, 0.02]),
                     table_z=0.0, pcd_target=particles, prt_target=particles * (1, 1, 0.5),
                     heightmap=np.zeros((32, 32)), centre_xy=np.zeros(2))


def test_frames_figure_has_a_row_per_parameter_set(tmp_path):
    particles = lump()
    steps = frame_steps(12, count=4)
    frames = np.repeat(particles[None], len(steps), axis=0)
    frames[:, :, 2] *= np.linspace(1.0, 0.5, len(steps))[:, None]  # flattened over time
    simulated = {"hand-picked": frames, "prt_emd / 1-round": frames * 1.01}
    plot_frames(datapoint(particles), simulated, steps, tmp_path / "f.png", tmp_path / "f.pdf")
    image = mpimg.imread(tmp_path / "f.png")
    height, width = image.shape[:2]
    assert width > height  # 4 columns of frames, 3 rows (real, 2 simulated)
    assert (tmp_path / "f.pdf").stat().st_size > 1000
    with pytest.raises(ValueError, match="NaN"):
        plot_frames(datapoint(particles), {"bad": frames * np.nan}, steps, tmp_path / "g.png", tmp_path / "g.pdf")
    with pytest.raises(ValueError, match="shape"):
        plot_frames(datapoint(particles), {"bad": frames[:2]}, steps, tmp_path / "g.png", tmp_path / "g.pdf")
