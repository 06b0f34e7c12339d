"""The differentiable MPM simulator checked against physics and against finite differences."""

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import taichi as ti
import taichi.lang.kernel_impl as kernel_impl

from conftest import shared
from dpsi import effectors
from dpsi.motions import Trajectory, trajectory
from dpsi.parameters import HAND_PICKED, NAMES, STIFFEST, Parameters
from dpsi.simulation import Scene, SimulationError, Simulator, SimulatorConfig, memory, mpm
from dpsi.simulation.constitutive import surely_elastic
from dpsi.simulation.mpm import field_bytes, mapped_array

SPACING = 0.004  # m between particles: a coarse object keeps these tests fast
CONFIG = SimulatorConfig(width=0.12, height=0.08, max_particles=1500, max_steps=120)


@pytest.fixture(scope="module")
def sim():
    return Simulator(CONFIG)


def block(size=(0.03, 0.03, 0.02), jitter=0.0, seed=0):
    """Particles filling a box standing on the table z = 0, centred at the origin."""
    axes = [np.arange(-s / 2 + SPACING / 2, s / 2, SPACING) for s in size[:2]]
    axes.append(np.arange(SPACING / 2, size[2], SPACING))
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return points + np.random.default_rng(seed).uniform(-jitter, jitter, points.shape)


def path(steps, dx=0.0, dz=0.0, dyaw=0.0):
    """A straight tip path: per-step increments dx, dz (m) and dyaw (rad)."""
    k = np.arange(steps + 1)[:, None]
    return Trajectory(np.hstack([k * dx, 0 * k, k * dz]), (k * dyaw).ravel())


def scene(particles, traj, effector=effectors.RECTANGLE, depth=0.0):
    """The tip starts ``depth`` below the object's top, above its centre."""
    return Scene(particles, SPACING ** 3, effector, traj, start=[0.0, 0.0, particles[:, 2].max() - depth])


def params(**values):
    return HAND_PICKED.replace(**values)


AWAY = path(30)  # effector parked above the object, never touching it


def far_scene(particles):
    return Scene(particles, SPACING ** 3, effectors.RECTANGLE, AWAY, start=[0.0, 0.0, 0.07])


# ---------------------------------------------------------------- gradients
@pytest.mark.parametrize("effector, tolerance", [(effectors.RECTANGLE, 0.02), (effectors.ROUND, 0.1)])
def test_gradient_matches_finite_differences(sim, effector, tolerance):
    """An effector pressing 2 mm into the top and dragging sideways, with plastic flow and sliding
    on the table: autodiff against central differences for all six parameters. (Curved effectors
    are approximate: the change of the contact normal with particle position is not differentiated.)"""
    particles = block(jitter=5e-4)
    weights = np.random.default_rng(1).normal(size=particles.shape)
    s = scene(particles, path(5, dx=0.0005, dz=-0.0002), effector, depth=0.002)
    theta = params(yield_stress=1100.0, mu_table=0.5, mu_effector=0.5)

    def loss(p):
        return float((sim.forward(s, p) * weights).sum())

    loss(theta)
    grads = sim.backward(weights)
    steps = {"E": 1e-3, "nu": 1e-8, "rho": 1e-5, "yield_stress": 1e-4, "mu_table": 1e-7, "mu_effector": 1e-7}
    for name in NAMES:
        v, h = getattr(theta, name), steps[name]
        fd = (loss(theta.replace(**{name: v + h})) - loss(theta.replace(**{name: v - h}))) / (2 * h)
        assert abs(fd) > 0, f"{name} has no effect in this scene; the check would be empty"
        assert grads[name] == pytest.approx(fd, rel=tolerance), name


def test_scaling_stiffness_density_and_yield_stress_together_changes_nothing(sim):
    """Dimensional analysis: stresses scale with E and σ_y, inertia and weight with ρ, and the effector moves
    on a prescribed path, so multiplying E, ρ and σ_y by one factor leaves every particle's path unchanged.
    A loss then has no slope along that direction: E ∂L/∂E + ρ ∂L/∂ρ + σ_y ∂L/∂σ_y = 0 (Euler's theorem)."""
    particles = block(jitter=5e-4)
    weights = np.random.default_rng(2).normal(size=particles.shape)
    s = scene(particles, path(5, dx=0.0005, dz=-0.0002), effectors.RECTANGLE, depth=0.002)
    theta = params(yield_stress=1100.0, mu_table=0.5, mu_effector=0.5)
    scaled = theta.replace(E=1.5 * theta.E, rho=1.5 * theta.rho, yield_stress=1.5 * theta.yield_stress)
    np.testing.assert_allclose(sim.forward(s, scaled), sim.forward(s, theta), rtol=0, atol=1e-12)
    assert np.abs(sim.forward(s, theta.replace(E=1.5 * theta.E)) - sim.forward(s, theta)).max() > 1e-6
    sim.forward(s, theta)
    g = sim.backward(weights)
    terms = [theta.E * g["E"], theta.rho * g["rho"], theta.yield_stress * g["yield_stress"]]
    assert abs(sum(terms)) < 1e-6 * sum(abs(t) for t in terms), terms


def test_the_memory_estimate_is_what_the_fields_take(sim):
    from taichi.lang.field import Field
    from taichi.lang.matrix import MatrixField

    def nbytes(field):
        components = field.n * field.m if isinstance(field, MatrixField) else 1
        return np.prod(field.shape) * components * np.dtype(ti.lang.util.to_numpy_type(field.dtype)).itemsize

    allocated = sum(nbytes(v) for v in vars(sim).values() if isinstance(v, Field))
    assert sum(field_bytes(CONFIG).values()) == pytest.approx(allocated, rel=1e-4)


@pytest.mark.parametrize("change, message", [
    ({"cfl": 1e-4}, r"1.54e\+03 GB for its fields: the particle state in 855561 substep slots × 5000 particles.*more "
                    r"than the 24 GB "
                    r"of memory available here; .*raise simulator.cfl \(now 0.0001; it sets the 855560 substeps"),
    ({"max_particles": 10 ** 6}, r"45.5 GB .*124 substep slots × 1000000 particles.*lower simulator.max_particles "
                                 r"\(now 1000000; --max-particles on the command line\)"),
])
def test_a_simulator_that_would_not_fit_in_memory_is_refused_before_it_allocates(monkeypatch, change, message):
    monkeypatch.setattr(memory, "available_memory", lambda: 24e9)
    monkeypatch.setattr(mpm, "ensure_taichi", lambda *args: pytest.fail("Taichi was asked for the fields"))
    with pytest.raises(SimulationError, match=message):
        Simulator(SimulatorConfig(**change))


def test_a_scene_whose_checkpoints_would_not_fit_in_memory_is_refused(sim, monkeypatch):
    particles = block()
    monkeypatch.setattr(memory, "available_memory", lambda: 1e5)
    with pytest.raises(SimulationError, match=rf"for the checkpoints of this scene \(31 steps × {len(particles)} "
                                              r"particles\), more than the 0.0001 GB.*use fewer particles"):
        sim.forward(far_scene(particles), HAND_PICKED)


def test_a_second_arch_in_one_process_is_refused(sim):
    with pytest.raises(RuntimeError, match="Taichi already runs on 'cpu' in this process; cannot switch to 'cuda'"):
        Simulator(replace(CONFIG, arch="cuda"))


def test_cuda_without_a_gpu_is_refused_rather_than_run_on_the_cpu():
    out = subprocess.run([sys.executable, "-c", "from dpsi.simulation.runtime import ensure_taichi; ensure_taichi('cuda')"],
                         capture_output=True, text=True)
    if out.returncode == 0:
        pytest.skip("this machine has a CUDA GPU")
    assert "no usable 'cuda' device" in out.stderr


def test_scattering_loops_run_on_one_cpu_thread_and_in_parallel_on_a_gpu_unless_forced():
    assert SimulatorConfig().serial_loops and not SimulatorConfig(arch="cuda").serial_loops
    assert SimulatorConfig(arch="cuda", serial=True).serial_loops and not SimulatorConfig(serial=False).serial_loops


def test_taichi_runs_on_the_threads_asked_for_and_by_default_on_every_cpu_the_process_may_use():
    """A batch system gives a job some CPUs by the process's affinity: by default Taichi uses those."""
    script = ("import os; from taichi.lang import impl; from dpsi.simulation import Simulator, SimulatorConfig; "
              "cpus = sorted(os.sched_getaffinity(0))[:{cpus}]; os.sched_setaffinity(0, cpus); "
              "Simulator(SimulatorConfig(max_particles=100, threads={threads})); "
              "print(impl.current_cfg().cpu_max_num_threads)")
    every = len(os.sched_getaffinity(0))
    for threads, cpus, expected in [(1, every, 1), (None, 1, 1), (None, every, every)]:
        out = subprocess.run([sys.executable, "-c", script.format(cpus=cpus, threads=threads)], capture_output=True,
                             text=True)
        assert out.returncode == 0, out.stderr
        assert int(out.stdout.split()[-1]) == expected


def test_a_kernel_that_does_not_compile_is_named_by_file_line_function_and_source(sim):
    """Taichi's source positions are replaced by a cheaper text (dpsi.simulation.runtime.source_position);
    an error in a kernel must still say where it is."""
    import taichi as ti
    from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext
    from dpsi.simulation.runtime import source_position

    @ti.kernel
    def broken() -> ti.i32:
        return undefined_name + 1  # noqa: F821

    with pytest.raises(ti.TaichiNameError) as raised:
        broken()
    source = Path(__file__).read_text().splitlines()
    line = next(k for k, text in enumerate(source, 1) if text.strip() == "return undefined_name + 1  # noqa: F821")
    assert ASTTransformerContext.get_pos_info is source_position
    assert f'File "{__file__}", line {line}, in broken:' in str(raised.value)
    assert "return undefined_name + 1" in str(raised.value)
    assert 'Name "undefined_name" is not defined' in str(raised.value)


def test_the_thread_count_must_be_positive():
    with pytest.raises(ValueError, match="threads must be at least 1"):
        SimulatorConfig(threads=0)


def test_backward_recomputing_each_step_matches_backward_from_kept_substeps(sim, monkeypatch):
    """With no memory for substep states the backward pass recomputes each step from its checkpoint;
    the gradients must be the same as when the forward pass kept them."""
    particles = block(jitter=5e-4)
    weights = np.random.default_rng(2).normal(size=particles.shape)
    s = scene(particles, path(4, dx=0.0005, dz=-0.0003), effectors.ROUND, depth=0.002)
    sim.forward(s, HAND_PICKED)
    kept = sim.backward(weights)
    monkeypatch.setattr(sim, "config", replace(sim.config, substep_memory_mb=0.0))
    sim.forward(s, HAND_PICKED)
    assert sim._substates is None
    recomputed = sim.backward(weights)
    for name in NAMES:
        assert recomputed[name] == pytest.approx(kept[name], rel=1e-9, abs=1e-12), name


def test_substep_states_beyond_the_memory_available_are_recomputed(sim, monkeypatch):
    """Within the budget but not in the memory there is: the forward pass keeps no substeps (and
    does not fail); checkpoints that fit still do."""
    particles = block(jitter=5e-4)
    s = scene(particles, path(30, dx=0.0002), effectors.ROUND, depth=0.001)
    checkpoints = 31 * len(particles) * mpm.STATE_WIDTH * 8
    monkeypatch.setattr(sim, "_substep_buffer", np.empty(0))
    monkeypatch.setattr(memory, "available_memory", lambda: 2 * checkpoints)
    sim.forward(s, HAND_PICKED)
    assert sim._substates is None and sim._substep_buffer.size == 0
    assert np.isfinite(sim.backward(np.ones_like(particles))["E"])


@pytest.mark.parametrize("transfers", ["gather", "atomic scatter"])
def test_every_loop_in_parallel_matches_the_serial_scatters(sim, monkeypatch, transfers):
    """``serial: false`` gives the positions and gradients of the default CPU loops to rounding, both as
    the CPU runs it (the transfers gather at the nodes) and as a GPU does (the particles scatter with
    atomic adds: the one check of that path on a machine without a GPU)."""
    particles = block(jitter=5e-4)
    weights = np.random.default_rng(3).normal(size=particles.shape)
    s = scene(particles, path(4, dx=0.0005, dz=-0.0003), effectors.ROUND, depth=0.002)
    assert sim.serial
    final, grads = sim.forward(s, HAND_PICKED), sim.backward(weights)
    parallel = sim
    if transfers == "atomic scatter":
        parallel = Simulator(CONFIG)
        monkeypatch.setattr(parallel, "gathers", lambda serial: False)
    monkeypatch.setattr(parallel, "serial", False)
    parallel_final, parallel_grads = parallel.forward(s, HAND_PICKED), parallel.backward(weights)
    assert np.abs(parallel_final - final).max() < 1e-12
    assert np.abs(parallel_final - particles).max() > 1e-4  # the effector did move particles
    for name in NAMES:
        assert parallel_grads[name] == pytest.approx(grads[name], rel=1e-8, abs=1e-12), name


# ---------------------------------------------------------------- physics
def test_block_at_rest_stays_put_and_keeps_its_mass(sim):
    particles = block()
    final = sim.forward(far_scene(particles), params(yield_stress=2e4))
    assert np.abs(final - particles).max() < 3e-4  # elastic sag under gravity only
    assert np.abs(final.mean(axis=0) - particles.mean(axis=0))[:2].max() < 1e-6  # no drift
    assert sim.grid_mass() == pytest.approx(len(particles) * SPACING ** 3 * HAND_PICKED.rho, rel=1e-12)


def test_softer_material_sags_more(sim):
    particles = block(size=(0.03, 0.03, 0.03))
    top = [sim.forward(far_scene(particles), params(E=E, yield_stress=2e4))[:, 2].max() for E in (1e4, 1e5)]
    drop_soft, drop_stiff = particles[:, 2].max() - top[0], particles[:, 2].max() - top[1]
    assert drop_soft > 2 * drop_stiff > 0


def test_lower_yield_stress_leaves_deeper_permanent_dent(sim):
    """Poke 6 mm down, pull back up and let the block relax: the dent under the tip stays deeper when
    the material yields earlier."""
    particles = block()
    poke = Trajectory(np.vstack([path(20, dz=-0.0003).positions, path(20, dz=0.0003).positions[1:] - [0, 0, 0.006]]),
                      np.zeros(41))
    centre = np.linalg.norm(particles[:, :2], axis=1) < 0.006
    top = particles[:, 2] > particles[:, 2].max() - SPACING / 2
    depth = {}
    for ys in (1e3, 1e4):
        final = sim.forward(scene(particles, poke, effectors.ROUND), params(yield_stress=ys))
        depth[ys] = particles[centre & top, 2].mean() - final[centre & top, 2].mean()
    assert depth[1e3] > depth[1e4] + 1e-3
    assert depth[1e3] > 2e-3


def shifted_distance(sim, **values):
    """How far the block's centre of mass moves when the rectangle presses 3 mm in and moves 15 mm in +x."""
    particles = block()
    press_and_shift = Trajectory(np.vstack([path(10, dz=-0.0003).positions,
                                            path(30, dx=0.0005).positions[1:] + [0, 0, -0.003]]), np.zeros(41))
    final = sim.forward(scene(particles, press_and_shift), params(**values))
    return final[:, 0].mean() - particles[:, 0].mean()


def test_higher_effector_friction_drags_further(sim):
    assert shifted_distance(sim, mu_effector=2.0, mu_table=0.5) > shifted_distance(sim, mu_effector=0.05, mu_table=0.5) + 1e-3


def test_higher_table_friction_moves_less(sim):
    assert shifted_distance(sim, mu_table=2.0, mu_effector=1.0) < shifted_distance(sim, mu_table=0.05, mu_effector=1.0) - 1e-3


def test_rotation_turns_the_object_its_way(sim):
    """The rectangle pressed 4 mm into the top and turned by +180° about z (counter-clockwise) turns the
    top of the block counter-clockwise."""
    particles = block(size=(0.036, 0.036, 0.02))
    turn = Trajectory(np.vstack([path(10, dz=-0.0004).positions, np.tile([0, 0, -0.004], (40, 1))]),
                      np.concatenate([np.zeros(11), np.linspace(0, np.pi, 41)[1:]]))
    final = sim.forward(scene(particles, turn), params(mu_effector=2.0))
    top = particles[:, 2] > particles[:, 2].max() - 2 * SPACING
    before = np.arctan2(particles[top, 1], particles[top, 0])
    after = np.arctan2(final[top, 1], final[top, 0])
    turned = np.angle(np.exp(1j * (after - before)))
    assert np.median(turned) > 0.1


def test_stiffest_corner_of_the_range_is_stable(sim):
    particles = block()
    final = sim.forward(scene(particles, path(10, dz=-0.0003), effectors.ROUND), STIFFEST)
    assert sim.substeps == CONFIG.max_substeps
    assert np.isfinite(final).all() and np.abs(final - particles).max() < 0.01


# ---------------------------------------------------------------- shortcuts that must not change results
def test_contact_tested_only_within_the_effector_reach_changes_nothing(sim, monkeypatch):
    """The rectangle pressed into a long block, then moved 30 mm along it while turning by 90°: testing
    contact only within each step's reach box gives the same trajectory, to the bit, as testing it at
    every particle and node."""
    particles = block(size=(0.07, 0.036, 0.02))
    sweep = Trajectory(np.vstack([path(10, dz=-0.0004).positions, path(40, dx=0.00075).positions[1:] + [0, 0, -0.004]]),
                       np.concatenate([np.zeros(11), np.linspace(0, np.pi / 2, 41)[1:]]))
    s = Scene(particles, SPACING ** 3, effectors.RECTANGLE, sweep, start=[-0.015, 0.0, particles[:, 2].max()])
    limited = sim.forward(s, params(mu_effector=2.0))
    everywhere = lambda step: (sim._origin - 1.0, sim._origin + 1.0)  # noqa: E731 (metres beyond the box)
    monkeypatch.setattr(sim, "_effector_reach", everywhere)
    assert np.array_equal(sim.forward(s, params(mu_effector=2.0)), limited)


@ti.kernel
def elastic_bound(sigma: ti.types.ndarray(), yield_strain: float, out: ti.types.ndarray()):
    for i in range(sigma.shape[0]):
        stretch = ti.Vector([sigma[i, 0], sigma[i, 1], sigma[i, 2]])
        out[i] = ti.select(surely_elastic(stretch, 2.0 * yield_strain, 1.0), 1, 0)


def test_logarithm_free_elastic_bound_never_claims_a_yielding_stretch(sim):
    """Stretches around the von Mises surface: whatever the bound calls elastic lies inside it by the
    exact Hencky-strain test, and it settles most of those well inside (so the shortcut is taken)."""
    rng = np.random.default_rng(3)
    yield_strain = 0.05
    direction = rng.normal(size=(20000, 3))
    direction -= direction.mean(axis=1, keepdims=True)
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    dev_norm = yield_strain * rng.uniform(0.0, 1.5, size=(20000, 1))
    sigma = np.exp(dev_norm * direction + rng.normal(0.0, 0.1, size=(20000, 1)))  # plus volume change
    out = np.zeros(len(sigma), dtype=np.int32)
    elastic_bound(sigma, yield_strain, out)
    claimed = out.astype(bool)
    assert (dev_norm[claimed, 0] <= yield_strain).all()
    assert claimed[dev_norm[:, 0] < 0.7 * yield_strain].mean() > 0.9


# ---------------------------------------------------------------- reuse without recompiling
def test_second_datapoint_with_other_particle_count_does_not_compile(sim, monkeypatch):
    traj = trajectory("poking-1")
    short = Trajectory(traj.positions[:6], traj.yaw[:6])
    first = block()
    sim.forward(scene(first, short, effectors.CYLINDER), HAND_PICKED)
    sim.backward(np.ones_like(first))
    compiled = []
    original = kernel_impl.Kernel.materialize

    def materialize(kernel, key=None, *args, **kwargs):
        if key not in kernel.compiled_kernels and hasattr(Simulator, kernel.func.__name__):
            compiled.append(kernel.func.__name__)
        return original(kernel, key, *args, **kwargs)

    monkeypatch.setattr(kernel_impl.Kernel, "materialize", materialize)
    second = block(size=(0.04, 0.02, 0.016))
    assert len(second) != len(first)
    final = sim.forward(scene(second, path(8, dz=-0.0003), effectors.ROUND), params(E=8e4))
    grads = sim.backward(np.ones_like(final))
    assert final.shape == second.shape and all(np.isfinite(list(grads.values())))
    assert compiled == []


# ---------------------------------------------------------------- errors
def test_particles_outside_the_box_are_refused(sim):
    particles = block()
    particles[0] = [0.2, 0.0, 0.01]
    with pytest.raises(SimulationError, match="outside the simulated box"):
        sim.forward(far_scene(particles), HAND_PICKED)


def test_trajectory_leaving_the_box_is_refused(sim):
    with pytest.raises(SimulationError, match="leaves the simulated box at step"):
        sim.forward(scene(block(), path(30, dx=0.005)), HAND_PICKED)


def test_parameters_out_of_range_are_refused(sim):
    with pytest.raises(ValueError, match="E=500000.0 Pa is outside its range"):
        sim.forward(far_scene(block()), Parameters(5e5, 0.3, 1300, 2e3, 0.5, 0.5))


def test_too_many_particles_are_refused(sim):
    particles = block(size=(0.06, 0.06, 0.04))
    assert len(particles) > CONFIG.max_particles
    with pytest.raises(SimulationError, match="capacity"):
        sim.forward(far_scene(particles), HAND_PICKED)


def test_instability_names_the_step_and_parameters():
    """A time step beyond the stability limit (Courant number 1) blows up; the error says where."""
    unstable = Simulator(SimulatorConfig(width=0.12, height=0.08, max_particles=400, max_steps=20, cfl=1.0,
                                         min_substeps=1))
    with pytest.raises(SimulationError, match=r"step \d+ of 10 .*'E': 300000.0"):
        unstable.forward(scene(block(), path(10, dz=-0.0003), effectors.ROUND), STIFFEST)


def test_a_forward_that_fails_leaves_no_earlier_run_to_differentiate():
    """A forward pass lets the last run's checkpoints go before it starts (so that two runs' checkpoints never
    share the peak memory): after a failed run, backward refuses rather than differentiate the run before it."""
    unstable = Simulator(SimulatorConfig(width=0.12, height=0.08, max_particles=400, max_steps=20, cfl=1.0,
                                         min_substeps=1))
    poke = scene(block(), path(10, dz=-0.0003), effectors.ROUND)
    unstable.forward(poke, HAND_PICKED)
    with pytest.raises(SimulationError, match="step"):
        unstable.forward(poke, STIFFEST)
    with pytest.raises(SimulationError, match="needs a forward"):
        unstable.backward(np.zeros((len(block()), 3)))


def test_backward_needs_forward():
    with pytest.raises(SimulationError, match="forward"):
        Simulator(CONFIG).backward(np.zeros((1, 3)))


def test_mesh_effector_matches_the_parametric_rectangle(sim, tmp_path):
    """The measured rectangle effector mesh, as a signed-distance grid, agrees with the parametric box."""
    mesh = shared("real-clay/effectors/meshes/raw/RectangleEEF.obj")
    grid = effectors.effector_from_mesh(mesh, initial_yaw=effectors.RECTANGLE.initial_yaw)
    particles = block()
    box, sampled_box = scene(particles, AWAY, effectors.RECTANGLE), scene(particles, AWAY, grid)
    points = np.random.default_rng(2).uniform([-0.03, -0.03, -0.01], [0.03, 0.03, 0.07], (400, 3)) + box.start
    parametric = sim.effector_signed_distance(box, points)
    sampled = sim.effector_signed_distance(sampled_box, points)
    near = np.abs(parametric) < 0.02
    assert np.abs(parametric[near] - sampled[near]).max() < 2 * grid.sdf_spacing  # trilinear error at edges
    assert (np.sign(parametric[np.abs(parametric) > 2e-3]) == np.sign(sampled[np.abs(parametric) > 2e-3])).all()


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_mapped_array_is_a_zeroed_writable_array_of_its_own(dtype):
    a, b = mapped_array(1000, dtype), mapped_array(1000, dtype)
    assert a.shape == (1000,) and a.dtype == dtype and a.flags.writeable and a.flags.c_contiguous
    assert not a.any()
    a[:] = 1.5
    assert (a == 1.5).all() and not b.any()  # each call maps its own memory
    assert mapped_array(0, dtype).shape == (0,)
