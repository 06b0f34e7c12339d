"""Differentiable 3D MLS-MPM (Hu et al. 2018) of an elastoplastic object on a table, pressed by a
kinematic rigid effector (SPEC §4).

One substep (state slot s → s + 1), each a kernel of its own:

1. ``contact_geometry`` – clear the grid; effector distance, normal and velocity at the nodes and
   particles (geometry only: not differentiated).
2. ``trial_deformation`` – F_tr = (I + Δt C) F.
3. ``decompose`` – F_tr = U Σ Vᵀ (its derivative is :func:`svd.svd_backward`).
4. ``return_mapping`` – von Mises return mapping in Hencky strain.
5. ``elastic_deformation`` – the new F from the projected singular values.
6. ``elastic_stress`` – the Kirchhoff stress of fixed-corotated elasticity, as APIC affine momentum.
7. ``particle_to_grid`` – APIC/MLS transfer of mass and momentum (quadratic B-splines).
8. ``grid_update`` – velocities, gravity, frictional contact with table and effector, walls.
9. ``grid_to_particle`` – velocities and affine matrices back to particles.
10. ``particle_contact_and_advect`` – contact again at the particles, then advection.

Gradients run backwards through all substeps of all steps. Memory: the particle state is kept at
the start of every step (a checkpoint) and for every substep of the one step being differentiated;
grid and stress are recomputed for each substep during the backward pass.
"""


import numpy as np
import taichi as ti

from ..effectors import GRID, SDF_GRID_RESOLUTION, Effector
from ..parameters import NAMES, Parameters
from .config import Scene, SimulationError, SimulatorConfig
from .contact import effector_normal, effector_sdf, frictional_contact, rotation_z
from .runtime import ensure_taichi
from .svd import svd_backward

GRAVITY = -9.81
"""Acceleration of gravity along z (m/s²)."""

WALL_CELLS = 3
"""Nodes this close to the box's faces stop outward motion (the box walls)."""

STATE_WIDTH = 24
"""Floats per particle in a checkpoint: x (3), v (3), C (9), F (9)."""


@ti.data_oriented
class Simulator:
    """A simulator compiled once per process and reused for any scene that fits its capacity.

    >>> sim = Simulator(SimulatorConfig())
    >>> final = sim.forward(scene, params)          # (n, 3) final positions (m)
    >>> grads = sim.backward(dloss_dfinal)          # {"E": dL/dE, ...}
    """

    def __init__(self, config: "SimulatorConfig | None" = None):
        self.config = config or SimulatorConfig()
        ensure_taichi(self.config.arch)
        c = self.config
        self.serial = c.serial
        self.dx = c.dx
        self.inv_dx = 1.0 / c.dx
        self.grid_shape = c.grid_shape
        self.slots = c.max_substeps + 1
        n, f64 = c.max_particles, ti.f64

        scalar = lambda grad=False: ti.field(f64, shape=(), needs_grad=grad)  # noqa: E731
        self.E, self.nu, self.rho = scalar(True), scalar(True), scalar(True)
        self.yield_stress, self.mu_table, self.mu_effector = scalar(True), scalar(True), scalar(True)
        self.shear, self.lam, self.particle_mass = scalar(True), scalar(True), scalar(True)
        self.dt, self.particle_volume, self.table_z = scalar(), scalar(), scalar()
        self.n_particles = ti.field(ti.i32, shape=())
        self.origin = ti.Vector.field(3, f64, shape=())

        self.effector_kind = ti.field(ti.i32, shape=())
        self.effector_size = ti.Vector.field(3, f64, shape=())
        self.effector_radius = scalar()
        self.sdf = ti.field(f64, shape=(SDF_GRID_RESOLUTION,) * 3)
        self.sdf_lower = ti.Vector.field(3, f64, shape=())
        self.sdf_spacing = scalar()
        self.tip = ti.Vector.field(3, f64, shape=c.max_steps + 1)
        self.yaw = ti.field(f64, shape=c.max_steps + 1)

        slots = (self.slots, n)
        self.x = ti.Vector.field(3, f64, shape=slots, needs_grad=True)
        self.v = ti.Vector.field(3, f64, shape=slots, needs_grad=True)
        self.C = ti.Matrix.field(3, 3, f64, shape=slots, needs_grad=True)
        self.F = ti.Matrix.field(3, 3, f64, shape=slots, needs_grad=True)

        self.F_trial = ti.Matrix.field(3, 3, f64, shape=n, needs_grad=True)
        self.U = ti.Matrix.field(3, 3, f64, shape=n, needs_grad=True)
        self.sigma = ti.Vector.field(3, f64, shape=n, needs_grad=True)
        self.sigma_elastic = ti.Vector.field(3, f64, shape=n, needs_grad=True)
        self.V = ti.Matrix.field(3, 3, f64, shape=n, needs_grad=True)
        self.affine = ti.Matrix.field(3, 3, f64, shape=n, needs_grad=True)
        self.v_grid = ti.Vector.field(3, f64, shape=n, needs_grad=True)
        self.p_phi = ti.field(f64, shape=n)
        self.p_normal = ti.Vector.field(3, f64, shape=n)
        self.p_v_effector = ti.Vector.field(3, f64, shape=n)

        g = self.grid_shape
        self.grid_m = ti.field(f64, shape=g, needs_grad=True)
        self.grid_p = ti.Vector.field(3, f64, shape=g, needs_grad=True)
        self.grid_v = ti.Vector.field(3, f64, shape=g, needs_grad=True)
        self.g_phi = ti.field(f64, shape=g)
        self.g_normal = ti.Vector.field(3, f64, shape=g)
        self.g_v_effector = ti.Vector.field(3, f64, shape=g)

        self._scene = None
        self._params = None
        self._checkpoints = None
        self.substeps = 0

    # ------------------------------------------------------------------ parameters
    @ti.kernel
    def material(self):
        """Lamé parameters from Young's modulus and Poisson's ratio (SPEC §4, fixed), particle mass."""
        self.shear[None] = self.E[None] / (2.0 * (1.0 + self.nu[None]))
        self.lam[None] = self.E[None] * self.nu[None] / ((1.0 + self.nu[None]) * (1.0 - 2.0 * self.nu[None]))
        self.particle_mass[None] = self.rho[None] * self.particle_volume[None]

    # ------------------------------------------------------------------ effector pose
    @ti.func
    def effector_pose(self, step, fraction):
        """Tip position, yaw, linear and angular (about z) velocity a ``fraction`` into ``step``."""
        a, b = self.tip[step], self.tip[step + 1]
        ya, yb = self.yaw[step], self.yaw[step + 1]
        duration = ti.static(self.config.step_dt)
        return a + fraction * (b - a), ya + fraction * (yb - ya), (b - a) / duration, (yb - ya) / duration

    @ti.func
    def effector_contact(self, point, step, fraction):
        """Signed distance, outward normal and effector velocity at a world ``point``."""
        tip, yaw, lin, ang = self.effector_pose(step, fraction)
        rel = point - tip
        phi = 1.0
        normal = ti.Vector([0.0, 0.0, 1.0])
        vel = ti.Vector.zero(ti.f64, 3)
        if rel.norm() < self.effector_radius[None] + 2.0 * self.dx:
            to_local = rotation_z(-yaw)
            local = to_local @ rel
            kind, size = self.effector_kind[None], self.effector_size[None]
            lower, spacing = self.sdf_lower[None], self.sdf_spacing[None]
            phi = effector_sdf(local, kind, size, self.sdf, lower, spacing)
            if phi <= 0.0:
                normal = rotation_z(yaw) @ effector_normal(local, kind, size, self.sdf, lower, spacing)
                vel = lin + ang * ti.Vector([-rel[1], rel[0], 0.0])
        return phi, normal, vel

    # ------------------------------------------------------------------ substep kernels
    @ti.kernel
    def contact_geometry(self, s: ti.i32, step: ti.i32, fraction: ti.f64):
        """Clear the grid and tabulate effector contact at nodes and particles (not differentiated)."""
        ti.loop_config(serialize=self.serial)
        for I in ti.grouped(ti.ndrange(*self.grid_shape)):
            self.grid_m[I] = 0.0
            self.grid_p[I] = ti.Vector.zero(ti.f64, 3)
            node = self.origin[None] + I.cast(ti.f64) * self.dx
            self.g_phi[I], self.g_normal[I], self.g_v_effector[I] = self.effector_contact(node, step, fraction)
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.p_phi[p], self.p_normal[p], self.p_v_effector[p] = self.effector_contact(self.x[s, p], step, fraction)
            self.v_grid[p] = ti.Vector.zero(ti.f64, 3)
            self.C[s + 1, p] = ti.Matrix.zero(ti.f64, 3, 3)

    @ti.kernel
    def trial_deformation(self, s: ti.i32):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.F_trial[p] = (ti.Matrix.identity(ti.f64, 3) + self.dt[None] * self.C[s, p]) @ self.F[s, p]

    @ti.kernel
    def decompose(self):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            u, sig, v = ti.svd(self.F_trial[p], ti.f64)
            self.U[p], self.V[p] = u, v
            self.sigma[p] = ti.Vector([sig[0, 0], sig[1, 1], sig[2, 2]])

    @ti.kernel
    def decompose_backward(self):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.F_trial.grad[p] += svd_backward(self.U[p], self.sigma[p], self.V[p],
                                                 self.U.grad[p], self.sigma.grad[p], self.V.grad[p])

    @ti.kernel
    def return_mapping(self):
        """Project the trial Hencky strain onto the von Mises yield surface: singular values after
        plastic flow."""
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            eps = ti.log(ti.max(self.sigma[p], 1e-8))
            eps_dev = eps - eps.sum() / 3.0
            dev_norm = ti.sqrt(eps_dev.dot(eps_dev) + 1e-30)
            plastic = ti.max(dev_norm - self.yield_stress[None] / (2.0 * self.shear[None]), 0.0)
            self.sigma_elastic[p] = ti.exp(eps - plastic / dev_norm * eps_dev)

    @ti.func
    def rebuild(self, u, sig, v):
        """U diag(sig) Vᵀ as a sum of outer products of the columns."""
        out = ti.Matrix.zero(ti.f64, 3, 3)
        for a in ti.static(range(3)):
            out += sig[a] * ti.Vector([u[0, a], u[1, a], u[2, a]]).outer_product(ti.Vector([v[0, a], v[1, a], v[2, a]]))
        return out

    @ti.kernel
    def elastic_deformation(self, s: ti.i32):
        """Deformation gradient after plastic flow, F = U Σ Vᵀ."""
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.F[s + 1, p] = self.rebuild(self.U[p], self.sigma_elastic[p], self.V[p])

    @ti.kernel
    def elastic_stress(self, s: ti.i32):
        """APIC affine momentum m C − (4Δt/Δx²) V_p τ, with the fixed-corotated Kirchhoff stress
        τ = 2μ(F − R)Fᵀ + λ(J − 1)J I, which in the principal frame is
        U diag(2μ(σ − 1)σ + λ(J − 1)J) Uᵀ."""
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            sig = self.sigma_elastic[p]
            J = sig[0] * sig[1] * sig[2]
            principal = 2.0 * self.shear[None] * (sig - 1.0) * sig + self.lam[None] * (J - 1.0) * J
            tau = self.rebuild(self.U[p], principal, self.U[p])
            scale = 4.0 * self.dt[None] * self.inv_dx * self.inv_dx * self.particle_volume[None]
            self.affine[p] = self.particle_mass[None] * self.C[s, p] - scale * tau

    @ti.func
    def stencil(self, x):
        """Lower corner node index and fractional offset (in cells) of a position's 3×3×3 stencil."""
        X = (x - self.origin[None]) * self.inv_dx
        base = ti.cast(X - 0.5, ti.i32)
        return base, X - base.cast(ti.f64)

    @ti.func
    def weight(self, fx, offset):
        """Quadratic B-spline weight of the node at ``offset`` (0, 1, 2 per axis) and its offset
        from the particle (m)."""
        d = offset.cast(ti.f64) - fx
        w = ti.Vector([0.0, 0.0, 0.0])
        for a in ti.static(range(3)):
            w[a] = ti.select(offset[a] == 1, 0.75 - d[a] ** 2, 0.5 * (1.5 - ti.abs(d[a])) ** 2)
        return w[0] * w[1] * w[2], d * self.dx

    @ti.kernel
    def particle_to_grid(self, s: ti.i32):
        """Scatter mass and momentum. The stencil is recomputed in the loop body so that reverse mode
        needs no per-iteration stack."""
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            for i, j, k in ti.ndrange(3, 3, 3):
                offset = ti.Vector([i, j, k])
                base, fx = self.stencil(self.x[s, p])
                weight, dpos = self.weight(fx, offset)
                mass = self.particle_mass[None]
                self.grid_p[base + offset] += weight * (mass * self.v[s, p] + self.affine[p] @ dpos)
                self.grid_m[base + offset] += weight * mass

    @ti.func
    def wall(self, I, v):
        """Zero the velocity components that point out of the box at nodes near its faces."""
        return ti.Vector([
            ti.select(((I[d] < WALL_CELLS) & (v[d] < 0.0))
                      | ((I[d] >= ti.static(self.grid_shape[d] - WALL_CELLS)) & (v[d] > 0.0)), 0.0, v[d])
            for d in ti.static(range(3))])

    @ti.kernel
    def grid_update(self):
        ti.loop_config(serialize=self.serial)
        for I in ti.grouped(ti.ndrange(*self.grid_shape)):
            if self.grid_m[I] > 0.0:
                up = ti.Vector([0.0, 0.0, 1.0])
                still = ti.Vector.zero(ti.f64, 3)
                free = self.grid_p[I] / self.grid_m[I] + self.dt[None] * ti.Vector([0.0, 0.0, GRAVITY])
                on_table = self.origin[None][2] + I[2] * self.dx <= self.table_z[None]
                after_table = ti.select(on_table, frictional_contact(free, still, up, self.mu_table[None]), free)
                after_effector = ti.select(
                    self.g_phi[I] <= 0.0,
                    frictional_contact(after_table, self.g_v_effector[I], self.g_normal[I], self.mu_effector[None]),
                    after_table)
                self.grid_v[I] = self.wall(I, after_effector)

    @ti.kernel
    def grid_to_particle(self, s: ti.i32):
        """Gather velocity and the affine matrix C = (4/Δx²) Σ w v (x_i − x_p)ᵀ from the grid
        (into fields cleared by ``contact_geometry``)."""
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            for i, j, k in ti.ndrange(3, 3, 3):
                offset = ti.Vector([i, j, k])
                base, fx = self.stencil(self.x[s, p])
                weight, dpos = self.weight(fx, offset)
                g_v = self.grid_v[base + offset]
                self.v_grid[p] += weight * g_v
                self.C[s + 1, p] += (4.0 * self.inv_dx * self.inv_dx * weight) * g_v.outer_product(dpos)

    @ti.kernel
    def particle_contact_and_advect(self, s: ti.i32):
        """Collide particles with the table and the effector again, then move them."""
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            up = ti.Vector([0.0, 0.0, 1.0])
            still = ti.Vector.zero(ti.f64, 3)
            x, v = self.x[s, p], self.v_grid[p]
            after_table = ti.select(x[2] <= self.table_z[None], frictional_contact(v, still, up, self.mu_table[None]), v)
            after_effector = ti.select(
                self.p_phi[p] <= 0.0,
                frictional_contact(after_table, self.p_v_effector[p], self.p_normal[p], self.mu_effector[None]),
                after_table)
            self.v[s + 1, p] = after_effector
            self.x[s + 1, p] = x + self.dt[None] * after_effector

    # ------------------------------------------------------------------ bookkeeping kernels
    @ti.kernel
    def load_state(self, state: ti.types.ndarray()):
        for p in range(self.n_particles[None]):
            for a in ti.static(range(3)):
                self.x[0, p][a] = state[p, a]
                self.v[0, p][a] = state[p, 3 + a]
            for a, b in ti.static(ti.ndrange(3, 3)):
                self.C[0, p][a, b] = state[p, 6 + 3 * a + b]
                self.F[0, p][a, b] = state[p, 15 + 3 * a + b]

    @ti.kernel
    def store_state(self, last: ti.i32, state: ti.types.ndarray()) -> ti.i32:
        """Copy slot ``last`` into slot 0 and into ``state``; return 1 if a value is not finite,
        2 if a particle left the box, else 0."""
        status = 0
        lower = 2.0
        upper = ti.Vector(self.grid_shape).cast(ti.f64) - 2.0
        for p in range(self.n_particles[None]):
            x, v, C, F = self.x[last, p], self.v[last, p], self.C[last, p], self.F[last, p]
            self.x[0, p], self.v[0, p], self.C[0, p], self.F[0, p] = x, v, C, F
            for a in ti.static(range(3)):
                state[p, a] = x[a]
                state[p, 3 + a] = v[a]
            for a, b in ti.static(ti.ndrange(3, 3)):
                state[p, 6 + 3 * a + b] = C[a, b]
                state[p, 15 + 3 * a + b] = F[a, b]
            total = x.sum() + v.sum() + C.sum() + F.sum()
            if not (total == total and ti.abs(total) < 1e30):
                ti.atomic_max(status, 1)
            X = (x - self.origin[None]) * self.inv_dx
            if (X < lower).any() or (X > upper).any():
                ti.atomic_max(status, 2)
        return status

    @ti.kernel
    def seed_gradient(self, grad_x: ti.types.ndarray()):
        for p in range(self.n_particles[None]):
            for a in ti.static(range(3)):
                self.x.grad[0, p][a] = grad_x[p, a]
            self.v.grad[0, p] = ti.Vector.zero(ti.f64, 3)
            self.C.grad[0, p] = ti.Matrix.zero(ti.f64, 3, 3)
            self.F.grad[0, p] = ti.Matrix.zero(ti.f64, 3, 3)

    @ti.kernel
    def carry_gradient(self, last: ti.i32):
        """Move the gradient of the state at slot 0 (the start of the later step) to slot ``last``
        (the end of this step) and clear the others."""
        for p in range(self.n_particles[None]):
            self.x.grad[last, p] = self.x.grad[0, p]
            self.v.grad[last, p] = self.v.grad[0, p]
            self.C.grad[last, p] = self.C.grad[0, p]
            self.F.grad[last, p] = self.F.grad[0, p]
            for s in range(last):
                self.x.grad[s, p] = ti.Vector.zero(ti.f64, 3)
                self.v.grad[s, p] = ti.Vector.zero(ti.f64, 3)
                self.C.grad[s, p] = ti.Matrix.zero(ti.f64, 3, 3)
                self.F.grad[s, p] = ti.Matrix.zero(ti.f64, 3, 3)

    @ti.kernel
    def clear_substep_gradients(self):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.F_trial.grad[p] = ti.Matrix.zero(ti.f64, 3, 3)
            self.U.grad[p] = ti.Matrix.zero(ti.f64, 3, 3)
            self.V.grad[p] = ti.Matrix.zero(ti.f64, 3, 3)
            self.affine.grad[p] = ti.Matrix.zero(ti.f64, 3, 3)
            self.v_grid.grad[p] = ti.Vector.zero(ti.f64, 3)
            self.sigma.grad[p] = ti.Vector.zero(ti.f64, 3)
            self.sigma_elastic.grad[p] = ti.Vector.zero(ti.f64, 3)
        ti.loop_config(serialize=self.serial)
        for I in ti.grouped(ti.ndrange(*self.grid_shape)):
            self.grid_m.grad[I] = 0.0
            self.grid_p.grad[I] = ti.Vector.zero(ti.f64, 3)
            self.grid_v.grad[I] = ti.Vector.zero(ti.f64, 3)

    @ti.kernel
    def effector_distance(self, points: ti.types.ndarray(), out: ti.types.ndarray()):
        """Signed distance (m) of world points to the effector at the start of the trajectory."""
        for i in range(points.shape[0]):
            point = ti.Vector([points[i, 0], points[i, 1], points[i, 2]])
            tip, yaw, _, _ = self.effector_pose(0, 0.0)
            local = rotation_z(-yaw) @ (point - tip)
            out[i] = effector_sdf(local, self.effector_kind[None], self.effector_size[None], self.sdf,
                                  self.sdf_lower[None], self.sdf_spacing[None])

    # ------------------------------------------------------------------ driver
    def _set_effector(self, effector: Effector) -> None:
        self.effector_kind[None] = effector.kind
        self.effector_size[None] = effector.size
        self.effector_radius[None] = effector.bounding_radius
        if effector.kind == GRID:
            self.sdf.from_numpy(effector.sdf)
            self.sdf_lower[None] = effector.sdf_lower
            self.sdf_spacing[None] = effector.sdf_spacing

    def _set_scene(self, scene: Scene) -> None:
        c = self.config
        n, steps = len(scene.particles), scene.trajectory.n_steps
        if n > c.max_particles:
            raise SimulationError(f"scene has {n} particles, more than this simulator's capacity "
                                  f"max_particles={c.max_particles}; lower the particle density or raise the capacity")
        if steps > c.max_steps:
            raise SimulationError(f"trajectory has {steps} steps, more than max_steps={c.max_steps}")
        origin = np.array([*(scene.centre_xy - 0.5 * self.grid_shape[0] * c.dx), scene.table_z - WALL_CELLS * c.dx])
        upper = origin + (np.array(self.grid_shape) - 2) * c.dx
        lower = origin + 2 * c.dx
        outside = np.any((scene.particles < lower) | (scene.particles > upper), axis=1)
        if outside.any():
            first = scene.particles[outside][0]
            raise SimulationError(f"{outside.sum()} particles lie outside the simulated box "
                                  f"[{lower.round(4)}, {upper.round(4)}] m (e.g. {first.round(4)}); the object is "
                                  f"larger than SimulatorConfig.width/height allow or lies below the table")
        tips, yaws = scene.tip_poses()
        margin = np.array([2 * c.dx, 2 * c.dx, 0.0])
        bad = np.any((tips[:, :2] < lower[:2] + margin[:2]) | (tips[:, :2] > upper[:2] - margin[:2]), axis=1)
        bad |= (tips[:, 2] < scene.table_z - c.dx) | (tips[:, 2] > upper[2])
        if bad.any():
            k = int(np.argmax(bad))
            raise SimulationError(f"the effector trajectory leaves the simulated box at step {k} "
                                  f"(tip at {tips[k].round(4)} m, box [{lower.round(4)}, {upper.round(4)}] m)")
        self.n_particles[None] = n
        self.origin[None] = origin
        self.table_z[None] = scene.table_z
        self.particle_volume[None] = scene.particle_volume
        self._set_effector(scene.effector)
        padded = np.zeros((c.max_steps + 1, 3))
        padded[: steps + 1] = tips
        self.tip.from_numpy(padded)
        padded_yaw = np.zeros(c.max_steps + 1)
        padded_yaw[: steps + 1] = yaws
        self.yaw.from_numpy(padded_yaw)

    def _set_params(self, params: Parameters) -> None:
        params.check_range()
        for name, value in params.as_dict().items():
            getattr(self, name)[None] = value
        self.substeps = self.config.substeps(params)
        self.dt[None] = self.config.step_dt / self.substeps
        self.material()

    def _substep(self, step: int, s: int) -> None:
        self.contact_geometry(s, step, (s + 1) / self.substeps)
        self.trial_deformation(s)
        self.decompose()
        self.return_mapping()
        self.elastic_deformation(s)
        self.elastic_stress(s)
        self.particle_to_grid(s)
        self.grid_update()
        self.grid_to_particle(s)
        self.particle_contact_and_advect(s)

    def _substep_backward(self, s: int) -> None:
        self.clear_substep_gradients()
        self.particle_contact_and_advect.grad(s)
        self.grid_to_particle.grad(s)
        self.grid_update.grad()
        self.particle_to_grid.grad(s)
        self.elastic_stress.grad(s)
        self.elastic_deformation.grad(s)
        self.return_mapping.grad()
        self.decompose_backward()
        self.trial_deformation.grad(s)

    def forward(self, scene: Scene, params: Parameters) -> np.ndarray:
        """Simulate the scene with parameters θ and return the final particle positions (n, 3) in m.

        Keeps a checkpoint of every step for :meth:`backward`."""
        self._set_scene(scene)
        self._set_params(params)
        n, steps = len(scene.particles), scene.trajectory.n_steps
        checkpoints = np.empty((steps + 1, n, STATE_WIDTH))
        checkpoints[0] = 0.0
        checkpoints[0, :, :3] = scene.particles
        checkpoints[0, :, 15:] = np.eye(3).reshape(1, 9)
        self.load_state(checkpoints[0])
        for step in range(steps):
            for s in range(self.substeps):
                self._substep(step, s)
            status = self.store_state(self.substeps, checkpoints[step + 1])
            if status:
                problem = "produced NaN or inf" if status == 1 else "pushed particles out of the simulated box"
                raise SimulationError(f"step {step + 1} of {steps} {problem} "
                                      f"(substeps={self.substeps}, parameters {params.as_dict()})")
        self._scene, self._params, self._checkpoints = scene, params, checkpoints
        return checkpoints[-1, :, :3].copy()

    def backward(self, grad_positions: np.ndarray) -> dict[str, float]:
        """Gradient of a scalar loss L with respect to θ, given dL/d(final positions) (n, 3) in 1/m
        times the loss unit. Requires a preceding :meth:`forward`."""
        if self._checkpoints is None:
            raise SimulationError("backward() needs a forward() first")
        checkpoints = self._checkpoints
        grad_positions = np.ascontiguousarray(grad_positions, dtype=np.float64)
        if grad_positions.shape != checkpoints.shape[1:2] + (3,):
            raise ValueError(f"gradient has shape {grad_positions.shape}, expected {(checkpoints.shape[1], 3)}")
        for name in (*NAMES, "shear", "lam", "particle_mass"):
            getattr(self, name).grad[None] = 0.0
        self.seed_gradient(grad_positions)
        for step in reversed(range(len(checkpoints) - 1)):
            self.carry_gradient(self.substeps)
            self.load_state(checkpoints[step])
            for s in range(self.substeps):
                self._substep(step, s)
            for s in reversed(range(self.substeps)):
                self._substep(step, s)  # restores the substep's grid and temporaries
                self._substep_backward(s)
        self.material.grad()
        grads = {name: float(getattr(self, name).grad[None]) for name in NAMES}
        bad = [k for k, g in grads.items() if not np.isfinite(g)]
        if bad:
            raise SimulationError(f"gradient of {bad} is not finite (parameters {self._params.as_dict()})")
        return grads

    def effector_signed_distance(self, scene: Scene, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) of world points to the scene's effector at its start pose."""
        self._set_scene(scene)
        points = np.ascontiguousarray(points, dtype=np.float64)
        out = np.empty(len(points))
        self.effector_distance(points, out)
        return out

