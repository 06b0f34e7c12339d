"""Motion offsets registered from the dent (dpsi.motion_offsets): the shift of a drawn dent, and an offset
injected into a simulated poke recovered from its after state."""

import numpy as np
import pytest

from dpsi.datapoint import Datapoint
from dpsi.effectors import by_name
from dpsi.heightmap import height_map
from dpsi.identification import scene
from dpsi.motion_offsets import CELL, imprint_shift, register, shifted
from dpsi.motions import Trajectory
from dpsi.parameters import HAND_PICKED, LEVEL1_FIXED
from dpsi.simulation import Simulator, SimulatorConfig

TRUTH = HAND_PICKED.replace(E=5e4, yield_stress=3e3, **LEVEL1_FIXED)
SPACING = 0.003


def _dent(centre_mm, depth_mm):
    """A 40 mm tall flat top (110 × 110 cells of 1 mm) with a round dent of 8 mm radius."""
    x = (np.arange(110) + 0.5) * CELL * 1e3
    r = np.hypot(*np.meshgrid(x - centre_mm[0], x - centre_mm[1], indexing="ij"))
    return 0.04 - 1e-3 * depth_mm * np.clip(1 - (r / 8.0) ** 2, 0, None)


def test_the_shift_of_a_drawn_dent_is_found():
    before = np.full((110, 110), 0.04)
    planned, made = _dent((55, 55), 6.0), _dent((57, 53.5), 5.0)
    dx, dy, dz = imprint_shift(before, planned, made)
    assert (dx, dy) == pytest.approx((0.002, -0.0015), abs=2.5e-4)
    assert dz == pytest.approx(0.0005, abs=4e-4)  # a shallower dent: the tool stayed higher


def test_an_injected_offset_is_recovered_within_a_millimetre():
    """A 5 cm lump poked 10 mm deep by the round effector, its tool path 2, −1.5 and 1.5 mm off the planned
    one: registered at the true parameters, the offset comes back within 1 mm on each axis."""
    xy = np.arange(-0.025, 0.0251, SPACING)
    particles = np.stack(np.meshgrid(xy, xy, np.arange(SPACING / 2, 0.024, SPACING), indexing="ij"), -1).reshape(-1, 3)
    z = np.concatenate([np.linspace(0.0, -0.01, 11), -0.01 + np.linspace(0.0, 0.005, 6)[1:]])
    poke = Trajectory(np.column_stack([np.zeros((len(z), 2)), z]), np.zeros(len(z)))
    centre = particles[:, :2].mean(axis=0)
    start = np.array([*centre, particles[:, 2].max() + SPACING / 2])
    dp = Datapoint("lump", "poke", by_name("round"), particles, SPACING**3, poke, start, 0.0, particles, particles,
                   np.zeros((32, 32)), centre)
    simulator = Simulator(SimulatorConfig(max_particles=3000))
    true = np.array([0.002, -0.0015, 0.0015])
    dp.prt_target = simulator.forward(scene(shifted(dp, true)), TRUTH, keep_substeps=False)
    dp.heightmap = height_map(dp.prt_target, centre)
    registration = register(simulator, dp, TRUTH)
    assert np.abs(registration.offset - true).max() < 0.001
    (planned, planned_mm), (first, first_mm) = registration.tried[:2]
    assert planned == (0.0, 0.0, 0.0) and first_mm < planned_mm  # most of the way in the first round
    assert np.abs(np.asarray(first) - true).max() < 0.002
