"""Differentiable 3D MLS-MPM (Hu et al. 2018) of an elastoplastic object on a table, pressed by a
kinematic rigid effector (SPEC §4).

One substep (state slot s → s + 1):

1. ``contact_geometry`` – clear the grid; effector distance, normal and velocity at the nodes and
   particles (geometry only: not differentiated).
2. ``constitutive`` – trial deformation F_tr = (I + Δt C) F, its SVD, von Mises return mapping in
   Hencky strain, the new F, and the fixed-corotated Kirchhoff stress as APIC affine momentum.
3. ``particle_to_grid`` – APIC/MLS transfer of mass and momentum (quadratic B-splines).
4. ``grid_update`` – velocities, gravity, frictional contact with table and effector, walls.
5. ``grid_to_particle`` – velocities and affine matrices back to particles.
6. ``particle_contact_and_advect`` – contact again at the particles, then advection.

Reverse mode runs through small kernels, one per physical operation (``trial_deformation``,
``return_mapping``, ``elastic_deformation``, ``elastic_stress``, ``grid_update``,
``particle_contact_and_advect``), because Taichi's LLVM back end compiles a large reverse-mode kernel
very slowly; the SVD and the two transfers have hand-written adjoints (``decompose_backward``,
``particle_to_grid_adjoint``, ``grid_to_particle_adjoint``).

Gradients run backwards through all substeps of all steps. Memory: the particle state is kept at
the start of every step (a checkpoint) and for every substep of the one step being differentiated;
grid and stress are recomputed for each substep during the backward pass. When the whole trajectory's
substep states (and SVDs) fit in ``SimulatorConfig.substep_memory_mb``, the forward pass keeps them
all and the backward pass reloads each step instead of simulating it again.
"""


import numpy as np
import taichi as ti

from ..effectors import GRID, SDF_GRID_RESOLUTION, Effector
from ..parameters import NAMES, Parameters
from .config import Scene, SimulationError, SimulatorConfig
from .contact import effector_normal, effector_sdf, frictional_contact, rotation_z
from .runtime import ensure_taichi
from .svd import svd_backward, warm_started_svd

GRAVITY = -9.81
"""Acceleration of gravity along z (m/s²)."""

WALL_CELLS = 3
"""Nodes this close to the box's faces stop outward motion (the box walls)."""

REGION_MARGIN = 5
"""Cells around the particles' bounding box that a step's grid work covers: the 3-node stencil reaches
1.5 cells out, leaving 3.5 cells (≈ 2 cm) for motion within one 0.01 s step."""

STATE_WIDTH = 33
"""Floats per particle in a checkpoint: x (3), v (3), C (9), F (9), and the right singular vectors V (9)
that warm-start the next step's first SVD."""


SUBSTEP_WIDTH = 45
"""Floats per particle and substep kept for the backward pass: x, v, C, F (24) and the substep's SVD
U (9), σ (3), V (9)."""

MIB = 2.0 ** 20


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
        self.region_lo = ti.Vector.field(3, ti.i32, shape=())
        self.region_hi = ti.Vector.field(3, ti.i32, shape=())

        self.effector_kind = ti.field(ti.i32, shape=())
        self.effector_size = ti.Vector.field(3, f64, shape=())
        self.effector_lower = ti.Vector.field(3, f64, shape=())
        self.effector_upper = ti.Vector.field(3, f64, shape=())
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
        self.U = ti.Matrix.field(3, 3, f64, shape=slots, needs_grad=True)
        self.sigma = ti.Vector.field(3, f64, shape=slots, needs_grad=True)
        self.sigma_elastic = ti.Vector.field(3, f64, shape=n, needs_grad=True)
        self.V_start = ti.Matrix.field(3, 3, f64, shape=n)
        self.V = ti.Matrix.field(3, 3, f64, shape=slots, needs_grad=True)
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

        self._params = None
        self._checkpoints = None
        self._substates = None
        self._substep_buffer = np.empty(0)
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
        local = rotation_z(-yaw) @ rel
        margin = 2.0 * self.dx
        if (local > self.effector_lower[None] - margin).all() and (local < self.effector_upper[None] + margin).all():
            kind, size = self.effector_kind[None], self.effector_size[None]
            lower, spacing = self.sdf_lower[None], self.sdf_spacing[None]
            phi = effector_sdf(local, kind, size, self.sdf, lower, spacing)
            if phi <= 0.0:
                normal = rotation_z(yaw) @ effector_normal(local, kind, size, self.sdf, lower, spacing)
                vel = lin + ang * ti.Vector([-rel[1], rel[0], 0.0])
        return phi, normal, vel

    # ------------------------------------------------------------------ substep: per-particle physics
    # Each step of the constitutive update is a ti.func. The forward pass runs them fused in one kernel
    # (fast); reverse mode differentiates them one small kernel at a time (fast to compile).
    @ti.func
    def trial(self, s, p):
        return (ti.Matrix.identity(ti.f64, 3) + self.dt[None] * self.C[s, p]) @ self.F[s, p]

    @ti.func
    def plastic_flow(self, sigma):
        """Singular values after projecting the trial Hencky strain onto the von Mises surface."""
        eps = ti.log(ti.max(sigma, 1e-8))
        eps_dev = eps - eps.sum() / 3.0
        dev_norm = ti.sqrt(eps_dev.dot(eps_dev) + 1e-30)
        plastic = ti.max(dev_norm - self.yield_stress[None] / (2.0 * self.shear[None]), 0.0)
        return ti.exp(eps - plastic / dev_norm * eps_dev)

    @ti.func
    def rebuild(self, u, sig, v):
        """U diag(sig) Vᵀ as a sum of outer products of the columns."""
        out = ti.Matrix.zero(ti.f64, 3, 3)
        for a in ti.static(range(3)):
            out += sig[a] * ti.Vector([u[0, a], u[1, a], u[2, a]]).outer_product(ti.Vector([v[0, a], v[1, a], v[2, a]]))
        return out

    @ti.func
    def affine_momentum(self, s, p, u, sig):
        """APIC affine momentum m C − (4Δt/Δx²) V_p τ with the fixed-corotated Kirchhoff stress
        τ = 2μ(F − R)Fᵀ + λ(J − 1)J I = U diag(2μ(σ − 1)σ + λ(J − 1)J) Uᵀ."""
        J = sig[0] * sig[1] * sig[2]
        principal = 2.0 * self.shear[None] * (sig - 1.0) * sig + self.lam[None] * (J - 1.0) * J
        tau = self.rebuild(u, principal, u)
        scale = 4.0 * self.dt[None] * self.inv_dx * self.inv_dx * self.particle_volume[None]
        return self.particle_mass[None] * self.C[s, p] - scale * tau

    @ti.kernel
    def constitutive(self, s: ti.i32):
        """Forward pass of the whole constitutive update: F_tr, its SVD (kept per substep for the
        backward pass; warm-started from the previous substep's V), plastic flow, the new F and the
        affine momentum. The SVD makes this the one kernel heavy enough to be worth starting threads for,
        whatever ``serial`` says."""
        for p in range(self.n_particles[None]):
            previous = self.V_start[p]
            if s > 0:
                previous = self.V[s - 1, p]
            u, sigma, v = warm_started_svd(self.trial(s, p), previous)
            self.U[s, p], self.V[s, p], self.sigma[s, p] = u, v, sigma
            elastic = self.plastic_flow(sigma)
            self.sigma_elastic[p] = elastic
            self.F[s + 1, p] = self.rebuild(u, elastic, v)
            self.affine[p] = self.affine_momentum(s, p, u, elastic)

    @ti.kernel
    def trial_deformation(self, s: ti.i32):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.F_trial[p] = self.trial(s, p)

    @ti.kernel
    def decompose_backward(self, s: ti.i32):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.F_trial.grad[p] += svd_backward(self.U[s, p], self.sigma[s, p], self.V[s, p],
                                                 self.U.grad[s, p], self.sigma.grad[s, p], self.V.grad[s, p])

    @ti.kernel
    def return_mapping(self, s: ti.i32):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.sigma_elastic[p] = self.plastic_flow(self.sigma[s, p])

    @ti.kernel
    def elastic_deformation(self, s: ti.i32):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.F[s + 1, p] = self.rebuild(self.U[s, p], self.sigma_elastic[p], self.V[s, p])

    @ti.kernel
    def elastic_stress(self, s: ti.i32):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.affine[p] = self.affine_momentum(s, p, self.U[s, p], self.sigma_elastic[p])

    # ------------------------------------------------------------------ substep: transfers
    # Particle-grid transfers have hand-written adjoints: Taichi's reverse mode of the unrolled
    # 27-node loop takes minutes to compile, and that of a rolled loop runs 13 times slower.
    @ti.func
    def stencil(self, x):
        """The 3×3×3 stencil of position ``x``: its base node, the particle's offset fx from it (cells),
        and per node offset o (rows) and axis (columns) the quadratic B-spline weight of d = o − fx and
        its derivative with respect to d. Computed once per particle, used for all 27 nodes."""
        X = (x - self.origin[None]) * self.inv_dx
        base = ti.min(ti.max(ti.cast(X - 0.5, ti.i32), 0), ti.Vector(self.grid_shape) - 3)
        fx = X - base.cast(ti.f64)
        W = ti.Matrix.zero(ti.f64, 3, 3)
        D = ti.Matrix.zero(ti.f64, 3, 3)
        for o, a in ti.static(ti.ndrange(3, 3)):
            d = o - fx[a]
            if ti.static(o == 1):
                W[o, a], D[o, a] = 0.75 - d ** 2, -2.0 * d
            else:
                W[o, a], D[o, a] = 0.5 * (1.5 - ti.abs(d)) ** 2, -(1.5 - ti.abs(d)) * ti.math.sign(d)
        return base, fx, W, D

    @ti.func
    def stencil_node(self, base, fx, W, D, i: ti.template(), j: ti.template(), k: ti.template()):
        """Node (i, j, k) of a :meth:`stencil`: its index, weight, offset from the particle (m), and the
        weight's gradient with respect to the particle position (1/m)."""
        w = W[i, 0] * W[j, 1] * W[k, 2]
        grad_w = -self.inv_dx * ti.Vector([D[i, 0] * W[j, 1] * W[k, 2], W[i, 0] * D[j, 1] * W[k, 2],
                                           W[i, 0] * W[j, 1] * D[k, 2]])
        offset = ti.Vector([i, j, k])
        return base + offset, w, (offset.cast(ti.f64) - fx) * self.dx, grad_w

    @ti.kernel
    def particle_to_grid(self, s: ti.i32):
        """grid momentum += w (m v + A (x_i − x_p)), grid mass += w m, A the affine momentum."""
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            mass, v, A = self.particle_mass[None], self.v[s, p], self.affine[p]
            base, fx, W, D = self.stencil(self.x[s, p])
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                node, w, dpos, _ = self.stencil_node(base, fx, W, D, i, j, k)
                self.grid_p[node] += w * (mass * v + A @ dpos)
                self.grid_m[node] += w * mass

    @ti.kernel
    def particle_to_grid_adjoint(self, s: ti.i32):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            mass, v, A = self.particle_mass[None], self.v[s, p], self.affine[p]
            x_bar, v_bar, m_bar = ti.Vector.zero(ti.f64, 3), ti.Vector.zero(ti.f64, 3), 0.0
            A_bar = ti.Matrix.zero(ti.f64, 3, 3)
            base, fx, W, D = self.stencil(self.x[s, p])
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                node, w, dpos, grad_w = self.stencil_node(base, fx, W, D, i, j, k)
                p_bar, m_node_bar = self.grid_p.grad[node], self.grid_m.grad[node]
                v_bar += w * mass * p_bar
                A_bar += w * p_bar.outer_product(dpos)
                m_bar += w * (v.dot(p_bar) + m_node_bar)
                x_bar += (p_bar.dot(mass * v + A @ dpos) + m_node_bar * mass) * grad_w - w * (A.transpose() @ p_bar)
            self.x.grad[s, p] += x_bar
            self.v.grad[s, p] += v_bar
            self.affine.grad[p] += A_bar
            self.particle_mass.grad[None] += m_bar

    @ti.kernel
    def grid_to_particle(self, s: ti.i32):
        """v = Σ w v_i and C = (4/Δx²) Σ w v_i (x_i − x_p)ᵀ."""
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            v = ti.Vector.zero(ti.f64, 3)
            C = ti.Matrix.zero(ti.f64, 3, 3)
            base, fx, W, D = self.stencil(self.x[s, p])
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                node, w, dpos, _ = self.stencil_node(base, fx, W, D, i, j, k)
                v += w * self.grid_v[node]
                C += (4.0 * self.inv_dx * self.inv_dx * w) * self.grid_v[node].outer_product(dpos)
            self.v_grid[p] = v
            self.C[s + 1, p] = C

    @ti.kernel
    def grid_to_particle_adjoint(self, s: ti.i32):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            v_bar, C_bar = self.v_grid.grad[p], self.C.grad[s + 1, p]
            x_bar = ti.Vector.zero(ti.f64, 3)
            base, fx, W, D = self.stencil(self.x[s, p])
            for i, j, k in ti.static(ti.ndrange(3, 3, 3)):
                node, w, dpos, grad_w = self.stencil_node(base, fx, W, D, i, j, k)
                g_v = self.grid_v[node]
                scale = 4.0 * self.inv_dx * self.inv_dx
                self.grid_v.grad[node] += w * v_bar + scale * w * (C_bar @ dpos)
                x_bar += (g_v.dot(v_bar) + scale * g_v.dot(C_bar @ dpos)) * grad_w - scale * w * (C_bar.transpose() @ g_v)
            self.x.grad[s, p] += x_bar

    # ------------------------------------------------------------------ substep: grid and contact
    @ti.kernel
    def contact_geometry(self, s: ti.i32, step: ti.i32, fraction: ti.f64):
        """Clear the grid and tabulate effector contact at nodes and particles (not differentiated)."""
        ti.loop_config(serialize=self.serial)
        for i, j, k in ti.ndrange(*[(self.region_lo[None][a], self.region_hi[None][a]) for a in range(3)]):
            I = ti.Vector([i, j, k])
            self.grid_m[I] = 0.0
            self.grid_p[I] = ti.Vector.zero(ti.f64, 3)
            node = self.origin[None] + I.cast(ti.f64) * self.dx
            self.g_phi[I], self.g_normal[I], self.g_v_effector[I] = self.effector_contact(node, step, fraction)
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.p_phi[p], self.p_normal[p], self.p_v_effector[p] = self.effector_contact(self.x[s, p], step, fraction)

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
        for i, j, k in ti.ndrange(*[(self.region_lo[None][a], self.region_hi[None][a]) for a in range(3)]):
            I = ti.Vector([i, j, k])
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
                self.V_start[p][a, b] = state[p, 24 + 3 * a + b]

    @ti.kernel
    def store_state(self, last: ti.i32, state: ti.types.ndarray()) -> ti.i32:
        """Copy slot ``last`` (and the last SVD's V) into slot 0 and into ``state``; return 1 if a value
        is not finite, 2 if a particle left the box, else 0."""
        status = 0
        lower = 2.0
        upper = ti.Vector(self.grid_shape).cast(ti.f64) - 2.0
        for p in range(self.n_particles[None]):
            x, v, C, F = self.x[last, p], self.v[last, p], self.C[last, p], self.F[last, p]
            self.x[0, p], self.v[0, p], self.C[0, p], self.F[0, p] = x, v, C, F
            V = self.V[last - 1, p]
            self.V_start[p] = V
            for a in ti.static(range(3)):
                state[p, a] = x[a]
                state[p, 3 + a] = v[a]
            for a, b in ti.static(ti.ndrange(3, 3)):
                state[p, 6 + 3 * a + b] = C[a, b]
                state[p, 15 + 3 * a + b] = F[a, b]
                state[p, 24 + 3 * a + b] = V[a, b]
            total = x.sum() + v.sum() + C.sum() + F.sum()
            if not (total == total and ti.abs(total) < 1e30):
                ti.atomic_max(status, 1)
            X = (x - self.origin[None]) * self.inv_dx
            if (X < lower).any() or (X > upper).any():
                ti.atomic_max(status, 2)
        return status

    @ti.kernel
    def save_substeps(self, states: ti.types.ndarray()):
        """Copy every substep slot of the step just simulated into ``states`` (substeps + 1, n, 45)."""
        for s, p in ti.ndrange(states.shape[0], self.n_particles[None]):
            self.substep_state(s, p, states, True)

    @ti.kernel
    def load_substeps(self, states: ti.types.ndarray()):
        """Inverse of :meth:`save_substeps`."""
        for s, p in ti.ndrange(states.shape[0], self.n_particles[None]):
            self.substep_state(s, p, states, False)

    @ti.func
    def substep_state(self, s, p, states: ti.template(), save: ti.template()):
        """Copy slot s of particle p to (``save``) or from row (s, p) of ``states``."""
        for a in ti.static(range(3)):
            if ti.static(save):
                states[s, p, a], states[s, p, 3 + a], states[s, p, 42 + a] = self.x[s, p][a], self.v[s, p][a], self.sigma[s, p][a]
            else:
                self.x[s, p][a], self.v[s, p][a], self.sigma[s, p][a] = states[s, p, a], states[s, p, 3 + a], states[s, p, 42 + a]
        for a, b in ti.static(ti.ndrange(3, 3)):
            i = 3 * a + b
            if ti.static(save):
                states[s, p, 6 + i], states[s, p, 15 + i] = self.C[s, p][a, b], self.F[s, p][a, b]
                states[s, p, 24 + i], states[s, p, 33 + i] = self.U[s, p][a, b], self.V[s, p][a, b]
            else:
                self.C[s, p][a, b], self.F[s, p][a, b] = states[s, p, 6 + i], states[s, p, 15 + i]
                self.U[s, p][a, b], self.V[s, p][a, b] = states[s, p, 24 + i], states[s, p, 33 + i]

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
    def clear_substep_gradients(self, s: ti.i32):
        ti.loop_config(serialize=self.serial)
        for p in range(self.n_particles[None]):
            self.F_trial.grad[p] = ti.Matrix.zero(ti.f64, 3, 3)
            self.U.grad[s, p] = ti.Matrix.zero(ti.f64, 3, 3)
            self.V.grad[s, p] = ti.Matrix.zero(ti.f64, 3, 3)
            self.sigma.grad[s, p] = ti.Vector.zero(ti.f64, 3)
            self.affine.grad[p] = ti.Matrix.zero(ti.f64, 3, 3)
            self.v_grid.grad[p] = ti.Vector.zero(ti.f64, 3)
            self.sigma_elastic.grad[p] = ti.Vector.zero(ti.f64, 3)
        ti.loop_config(serialize=self.serial)
        for i, j, k in ti.ndrange(*[(self.region_lo[None][a], self.region_hi[None][a]) for a in range(3)]):
            I = ti.Vector([i, j, k])
            self.grid_m.grad[I] = 0.0
            self.grid_p.grad[I] = ti.Vector.zero(ti.f64, 3)
            self.grid_v.grad[I] = ti.Vector.zero(ti.f64, 3)

    @ti.kernel
    def grid_mass(self) -> ti.f64:
        """Total mass on the grid after the last substep (kg)."""
        total = 0.0
        for I in ti.grouped(self.grid_m):
            total += self.grid_m[I]
        return total

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
        self.effector_lower[None], self.effector_upper[None] = effector.bounds
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

    def _set_active_region(self, state: np.ndarray) -> None:
        """Limit grid work during a step to the particles' bounding box plus REGION_MARGIN cells."""
        cells = (state[:, :3] - self.origin.to_numpy()) * self.inv_dx
        lo = np.floor(cells.min(axis=0)).astype(int) - REGION_MARGIN
        hi = np.ceil(cells.max(axis=0)).astype(int) + REGION_MARGIN
        self.region_lo[None] = np.maximum(lo, 0)
        self.region_hi[None] = np.minimum(hi, self.grid_shape)

    def _substep(self, step: int, s: int) -> None:
        self.contact_geometry(s, step, (s + 1) / self.substeps)
        self.constitutive(s)
        self.particle_to_grid(s)
        self.grid_update()
        self.grid_to_particle(s)
        self.particle_contact_and_advect(s)

    def _restore_substep_temporaries(self, step: int, s: int) -> None:
        """Recompute what substep s keeps in single-copy fields (grid, contact, stress), reusing the
        SVD stored for the substep."""
        self.contact_geometry(s, step, (s + 1) / self.substeps)
        self.return_mapping(s)
        self.elastic_stress(s)
        self.particle_to_grid(s)
        self.grid_update()
        self.grid_to_particle(s)

    def _substep_backward(self, s: int) -> None:
        self.clear_substep_gradients(s)
        self.particle_contact_and_advect.grad(s)
        self.grid_to_particle_adjoint(s)
        self.grid_update.grad()
        self.particle_to_grid_adjoint(s)
        self.elastic_stress.grad(s)
        self.elastic_deformation.grad(s)
        self.return_mapping.grad(s)
        self.decompose_backward(s)
        self.trial_deformation.grad(s)

    def forward(self, scene: Scene, params: Parameters, keep_substeps: bool = True) -> np.ndarray:
        """Simulate the scene with parameters θ and return the final particle positions (n, 3) in m.

        Keeps a checkpoint of every step for :meth:`backward` and, if ``keep_substeps`` and they fit in
        the memory budget, every substep's state too (which makes the backward pass about a third
        faster; pass False when no backward pass follows)."""
        self._set_scene(scene)
        self._set_params(params)
        n, steps = len(scene.particles), scene.trajectory.n_steps
        checkpoints = np.empty((steps + 1, n, STATE_WIDTH))
        checkpoints[0] = 0.0
        checkpoints[0, :, :3] = scene.particles
        checkpoints[0, :, 15:24] = np.eye(3).reshape(1, 9)
        checkpoints[0, :, 24:33] = np.eye(3).reshape(1, 9)
        self.load_state(checkpoints[0])
        substates = self._substep_storage(n, steps) if keep_substeps else None
        for step in range(steps):
            self._set_active_region(checkpoints[step])
            for s in range(self.substeps):
                self._substep(step, s)
            if substates is not None:
                self.save_substeps(substates[step])
            status = self.store_state(self.substeps, checkpoints[step + 1])
            if status:
                problem = "produced NaN or inf" if status == 1 else "pushed particles out of the simulated box"
                raise SimulationError(f"step {step + 1} of {steps} {problem} "
                                      f"(substeps={self.substeps}, parameters {params.as_dict()})")
        self._params, self._checkpoints, self._substates = params, checkpoints, substates
        return self.final_positions()

    def _substep_storage(self, n: int, steps: int) -> "np.ndarray | None":
        """Room for every substep state of the trajectory, or None if it exceeds the memory budget.
        The buffer is kept and reused by later calls (fresh memory costs a page fault per 4 KiB)."""
        shape = (steps, self.substeps + 1, n, SUBSTEP_WIDTH)
        size = int(np.prod(shape))
        if size * 8 > self.config.substep_memory_mb * MIB:
            return None
        if self._substep_buffer.size < size:
            self._substep_buffer = np.empty(0)
            self._substep_buffer = np.empty(size)
        return self._substep_buffer[:size].reshape(shape)

    def final_positions(self) -> np.ndarray:
        """Particle positions (n, 3) in m at the end of the last :meth:`forward`."""
        if self._checkpoints is None:
            raise SimulationError("no simulation has run yet")
        return self._checkpoints[-1, :, :3].copy()

    def positions_at(self, steps) -> np.ndarray:
        """Particle positions (len(steps), n, 3) in m at the start of the given steps of the last
        :meth:`forward` (step n_steps is the end of the trajectory)."""
        if self._checkpoints is None:
            raise SimulationError("no simulation has run yet")
        steps = np.asarray(steps, dtype=int)
        if steps.min() < 0 or steps.max() >= len(self._checkpoints):
            raise ValueError(f"steps must lie in 0..{len(self._checkpoints) - 1}, got {steps.tolist()}")
        return self._checkpoints[steps, :, :3].copy()

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
            self._set_active_region(checkpoints[step])
            if self._substates is not None:
                self.load_substeps(self._substates[step])
            else:
                self.load_state(checkpoints[step])
                for s in range(self.substeps):
                    self._substep(step, s)
            for s in reversed(range(self.substeps)):
                self._restore_substep_temporaries(step, s)
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

