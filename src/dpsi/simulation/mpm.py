"""Differentiable 3D MLS-MPM (Hu et al. 2018) of an elastoplastic object on a table, pressed by a
kinematic rigid effector (SPEC §4).

One substep (state slot s → s + 1) is two kernels, :meth:`Simulator.tabulate_contact` (loop 1) and
:meth:`Simulator.advance` (loops 2–5):

1. particles and grid: effector distance, normal and velocity at the particles and at the nodes within
   the effector's reach in this step; the substep's grid region (the nodes the particles' stencils
   reach: all grid work of the substep stays in it), cleared;
2. particles: trial deformation F_tr = (I + Δt C) F, its SVD, von Mises
   return mapping in Hencky strain, the new F, and the fixed-corotated Kirchhoff stress as APIC affine
   momentum;
3. particles: APIC/MLS transfer of mass and momentum to the grid (quadratic B-splines);
4. grid: velocities, gravity, frictional contact with table and effector, walls;
5. particles: velocities and affine matrices back from the grid, contact with table and effector
   again, advection.

Loop 3 scatters: each particle adds to its 27 stencil nodes, and so does the reverse of loop 5. On one
CPU thread Taichi makes those adds plain ones, and that is the CPU's default (the heavy loops without
atomics still use every thread). On several CPU threads the adds must be atomic, which costs more than
the threads gain (17 000 particles, two threads: 2.5 × the time of one). So with ``serial`` False on the
CPU the transfers gather instead: each substep the particles are sorted into bins by their stencil's base
node (a counting sort in one serial loop) and store, in bin order, their weights and what they transfer;
each node then sums over the 27 bins whose stencils reach it. Those are the same sums without atomics,
and loops 3 and 4 become one loop over the nodes. On a GPU, where atomic adds are fast and one thread is
slow, the particles scatter atomically.

The reverse mode is written by hand (Taichi's automatic one compiles slowly and adds every particle's
contribution to a parameter into one shared number): per substep, :meth:`Simulator.tabulate_contact`
and :meth:`Simulator.restore` recompute the grid of the forward pass from the substep's state and SVD,
and :meth:`Simulator.adjoint` runs loops 2–5 backwards in three. Gradients of the state live in two
slots (of the substep being differentiated and of the one after it). Gradients of the material
parameters are summed per particle and those of the friction coefficients per grid node, and reduced
once per backward pass.

Memory: the particle state is kept at the start of every step (a checkpoint) and for every substep of
the one step being differentiated. When the whole trajectory's substep states (and SVDs) fit in
``SimulatorConfig.substep_memory_mb``, the forward pass keeps them all and the backward pass reloads each
step instead of simulating it again.
"""

import mmap

import numpy as np
import taichi as ti

from ..effectors import GRID, SDF_GRID_RESOLUTION, Effector
from ..parameters import Parameters
from .config import WALL_CELLS, Scene, SimulationError, SimulatorConfig
from .constitutive import (compose, compose_adjoint, lame_gradient, lame_parameters, plastic_flow,
                           plastic_flow_adjoint, principal_stress, principal_stress_adjoint)
from .contact import effector_normal, effector_sdf, frictional_contact, frictional_contact_adjoint, rotation_z
from . import memory
from .runtime import ensure_taichi
from .svd import svd_backward, warm_started_svd

GRAVITY = -9.81
"""Acceleration of gravity along z (m/s²)."""

CONTACT_MARGIN_CELLS = 2
"""Points this many cells outside the effector's bounding box are tested for contact (its signed distance
evaluated); beyond, they are known to be clear of it."""

STATE_WIDTH = 33
"""Floats per particle in a checkpoint: x (3), v (3), C (9), F (9), and the right singular vectors V (9)
that warm-start the next step's first SVD."""

SUBSTEP_WIDTH = 45
"""Floats per particle and substep kept for the backward pass: x, v, C, F (24) and the substep's SVD
U (9), σ (3), V (9)."""

MATERIAL_GRADIENTS = ("shear", "lam", "particle_mass", "yield_stress", "mu_table", "mu_effector")
"""Order of the per-particle parameter gradients (the friction ones also per grid node, last two)."""

PARTICLE_FLOATS = 109
"""Floats per particle outside the substep slots: V at the step's start, the affine momentum and elastic
stretches (21), contact (7), the state gradients in two slots (48) and the others (9), and the sorted
transfer buffers (24); plus one 32-bit integer (its rank in bin order)."""

NODE_FLOATS = 23
"""Floats per grid node: mass, momentum, velocity (7), contact (7) and their gradients with the friction
sums (9); plus two 32-bit integers (its bin's count and first index)."""

MIB = 2.0 ** 20


def field_bytes(config: SimulatorConfig) -> dict[str, float]:
    """Bytes of the Taichi fields of a simulator of ``config``, by what they hold: "slots" the particle
    state in each of the max_substeps + 1 substep slots of a step, "particles" the rest per particle,
    "grid" the grid nodes, "effector" its distance grid and the trajectory."""
    size = np.dtype(np.float64).itemsize
    n = config.max_particles
    return {"slots": (config.max_substeps + 1) * n * SUBSTEP_WIDTH * size,
            "particles": n * (PARTICLE_FLOATS * size + 4),
            "grid": float(np.prod(config.grid_shape)) * (NODE_FLOATS * size + 2 * 4),
            "effector": (SDF_GRID_RESOLUTION ** 3 + 4 * (config.max_steps + 1)) * size}


def check_capacity(config: SimulatorConfig) -> None:
    """Raise :class:`SimulationError`, naming the settings to change, if the fields of a simulator of
    ``config`` do not fit in the memory available (Taichi touches all of them when a kernel first runs)."""
    need = {what: size / memory.GB for what, size in field_bytes(config).items()}
    slots, (nx, ny, nz) = config.max_substeps + 1, config.grid_shape
    memory.check_fits(sum(need.values()) * memory.GB,
                      f"its fields: the particle state in {slots} substep slots × {config.max_particles} "
                      f"particles ({need['slots']:.3g} GB), the rest of the particles ({need['particles']:.3g} GB) "
                      f"and the grid {nx}×{ny}×{nz} ({need['grid']:.3g} GB)",
                      f"lower simulator.max_particles (now {config.max_particles}; --max-particles on the command "
                      f"line), or raise simulator.cfl (now {config.cfl:g}; it sets the {config.max_substeps} substeps "
                      f"per step at the stiffest parameters) or simulator.dx (now {config.dx:g} m)")


def mapped_array(size: int, dtype) -> np.ndarray:
    """A zeroed 1-D array of ``size`` elements in an anonymous memory map of its own.

    For a large array NumPy asks the kernel for transparent huge pages, and where the kernel then
    compacts memory to find them (``/sys/kernel/mm/transparent_hugepage/defrag`` = ``madvise``, a common
    default) the first write of a 1 GiB buffer took 1.5–2.5 s instead of 0.5–0.8 s on the 2-core
    development machine. A plain anonymous map asks for nothing; the array keeps the map alive."""
    if size == 0:
        return np.empty(0, dtype=dtype)
    return np.frombuffer(mmap.mmap(-1, size * np.dtype(dtype).itemsize), dtype=dtype)


@ti.data_oriented
class Simulator:
    """A simulator compiled once per process and reused for any scene that fits its capacity.

    >>> sim = Simulator(SimulatorConfig())
    >>> final = sim.forward(scene, params)          # (n, 3) final positions (m)
    >>> grads = sim.backward(dloss_dfinal)          # {"E": dL/dE, ...}
    """

    def __init__(self, config: "SimulatorConfig | None" = None):
        self.config = config or SimulatorConfig()
        check_capacity(self.config)
        ensure_taichi(self.config.arch, self.config.threads)
        c = self.config
        self.dx = c.dx
        self.inv_dx = 1.0 / c.dx
        self.grid_shape = c.grid_shape
        self.slots = c.max_substeps + 1
        n = c.max_particles

        scalar = lambda: ti.field(float, shape=())  # noqa: E731
        self.yield_stress, self.mu_table, self.mu_effector = scalar(), scalar(), scalar()
        self.shear, self.lam, self.particle_mass = scalar(), scalar(), scalar()
        self.dt, self.particle_volume, self.table_z = scalar(), scalar(), scalar()
        self.n_particles = ti.field(ti.i32, shape=())
        self.n_substeps = ti.field(ti.i32, shape=())
        self.step = ti.field(ti.i32, shape=())
        self.origin = ti.Vector.field(3, float, shape=())
        self.region_lo = ti.Vector.field(3, ti.i32, shape=())  # nodes the particles' stencils reach in a substep
        self.region_hi = ti.Vector.field(3, ti.i32, shape=())
        self.reach_lo = ti.Vector.field(3, float, shape=())
        self.reach_hi = ti.Vector.field(3, float, shape=())
        self.reach_node_lo = ti.Vector.field(3, ti.i32, shape=())
        self.reach_node_hi = ti.Vector.field(3, ti.i32, shape=())

        self.effector_kind = ti.field(ti.i32, shape=())
        self.effector_size = ti.Vector.field(3, float, shape=())
        self.effector_lower = ti.Vector.field(3, float, shape=())
        self.effector_upper = ti.Vector.field(3, float, shape=())
        self.sdf = ti.field(float, shape=(SDF_GRID_RESOLUTION,) * 3)
        self.sdf_lower = ti.Vector.field(3, float, shape=())
        self.sdf_spacing = scalar()
        self.tip = ti.Vector.field(3, float, shape=c.max_steps + 1)
        self.yaw = ti.field(float, shape=c.max_steps + 1)

        slots = (self.slots, n)
        self.x = ti.Vector.field(3, float, shape=slots)
        self.v = ti.Vector.field(3, float, shape=slots)
        self.C = ti.Matrix.field(3, 3, float, shape=slots)
        self.F = ti.Matrix.field(3, 3, float, shape=slots)
        self.U = ti.Matrix.field(3, 3, float, shape=slots)
        self.sigma = ti.Vector.field(3, float, shape=slots)
        self.V = ti.Matrix.field(3, 3, float, shape=slots)
        self.V_start = ti.Matrix.field(3, 3, float, shape=n)
        self.affine = ti.Matrix.field(3, 3, float, shape=n)
        self.elastic = ti.Vector.field(3, float, shape=n)
        self.p_phi = ti.field(float, shape=n)
        self.p_normal = ti.Vector.field(3, float, shape=n)
        self.p_v_effector = ti.Vector.field(3, float, shape=n)

        # gradients: of the state in two slots (substep s in slot s % 2), of the parameters per particle
        self.x_bar = ti.Vector.field(3, float, shape=(2, n))
        self.v_bar = ti.Vector.field(3, float, shape=(2, n))
        self.C_bar = ti.Matrix.field(3, 3, float, shape=(2, n))
        self.F_bar = ti.Matrix.field(3, 3, float, shape=(2, n))
        self.velocity_bar = ti.Vector.field(3, float, shape=n)  # of the velocity before particle contact
        self.material_bar = ti.Vector.field(len(MATERIAL_GRADIENTS), float, shape=n)
        self.gradient_total = ti.Vector.field(len(MATERIAL_GRADIENTS), float, shape=())

        g = self.grid_shape
        self.grid_m = ti.field(float, shape=g)
        self.grid_p = ti.Vector.field(3, float, shape=g)
        self.grid_v = ti.Vector.field(3, float, shape=g)
        self.g_phi = ti.field(float, shape=g)
        self.g_normal = ti.Vector.field(3, float, shape=g)
        self.g_v_effector = ti.Vector.field(3, float, shape=g)
        self.grid_m_bar = ti.field(float, shape=g)
        self.grid_p_bar = ti.Vector.field(3, float, shape=g)
        self.grid_v_bar = ti.Vector.field(3, float, shape=g)
        self.friction_bar = ti.Vector.field(2, float, shape=g)
        # gathering transfers: particles binned by the base node of their stencil (count and first index
        # of each bin, each particle's index in bin order), and per particle in bin order its offset from
        # the base node (cells), B-spline weights per node offset and axis, and what it transfers (m v and
        # the affine momentum, or v̄ and (4/Δx²) C̄)
        self.bin_count = ti.field(ti.i32, shape=g)
        self.bin_first = ti.field(ti.i32, shape=g)
        self.bin_rank = ti.field(ti.i32, shape=n)
        self.sorted_fx = ti.Vector.field(3, float, shape=n)
        self.sorted_W = ti.field(float, shape=(n, 3, 3))
        self.sorted_a = ti.Vector.field(3, float, shape=n)
        self.sorted_A = ti.Matrix.field(3, 3, float, shape=n)

        self._params = None
        self._origin = self._tips = self._effector_bounds = None  # of the current scene, for _begin_step
        self._checkpoints = None
        self._substates = None
        self._substep_buffer = np.empty(0, dtype=np.float64)
        self.substeps = 0
        self.serial = c.serial_loops

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
        vel = ti.Vector.zero(float, 3)
        local = rotation_z(-yaw) @ rel
        margin = ti.static(CONTACT_MARGIN_CELLS * self.dx)
        if (local > self.effector_lower[None] - margin).all() and (local < self.effector_upper[None] + margin).all():
            kind, size = self.effector_kind[None], self.effector_size[None]
            lower, spacing = self.sdf_lower[None], self.sdf_spacing[None]
            phi = effector_sdf(local, kind, size, self.sdf, lower, spacing)
            if phi <= 0.0:
                normal = rotation_z(yaw) @ effector_normal(local, kind, size, self.sdf, lower, spacing)
                vel = lin + ang * ti.Vector([-rel[1], rel[0], 0.0])
        return phi, normal, vel

    @ti.func
    def substep_fraction(self, s):
        """How far through the step the end of substep s lies."""
        return (s + 1) / self.n_substeps[None]

    @ti.func
    def tabulate_point_contact(self, q, s, lo, extent):
        """Store the effector's distance, normal and velocity at point q of substep s: particle q, or for
        q ≥ n_particles a node of the box ``lo`` + [0, ``extent``) of nodes within the effector's reach.
        Particles out of its reach get distance 1 m. One call site of :meth:`effector_contact` for
        both, which halves the kernel's compile time."""
        n = self.n_particles[None]
        point = ti.Vector.zero(float, 3)
        I = ti.Vector.zero(ti.i32, 3)
        if q < n:
            point = self.x[s, q]
        else:
            flat = q - n
            I = lo + ti.Vector([flat // (extent[1] * extent[2]), (flat // extent[2]) % extent[1], flat % extent[2]])
            point = self.origin[None] + I.cast(float) * self.dx
        phi, normal, velocity = 1.0, ti.Vector([0.0, 0.0, 1.0]), ti.Vector.zero(float, 3)
        if (point >= self.reach_lo[None]).all() and (point <= self.reach_hi[None]).all():
            phi, normal, velocity = self.effector_contact(point, self.step[None], self.substep_fraction(s))
        if q < n:
            self.p_phi[q], self.p_normal[q], self.p_v_effector[q] = phi, normal, velocity
        else:
            self.g_phi[I], self.g_normal[I], self.g_v_effector[I] = phi, normal, velocity

    @ti.func
    def effector_touches(self, I):
        """Whether grid node I lies on or inside the effector (tabulated by :meth:`tabulate_contact`)."""
        return (I >= self.reach_node_lo[None]).all() and (I < self.reach_node_hi[None]).all() and self.g_phi[I] <= 0.0

    # ------------------------------------------------------------------ per-particle physics
    @ti.func
    def trial(self, s, p):
        return (ti.Matrix.identity(float, 3) + self.dt[None] * self.C[s, p]) @ self.F[s, p]

    @ti.func
    def stress_scale(self):
        """4 Δt V_p / Δx², the factor of the Kirchhoff stress in the APIC affine momentum (m³ s / m²)."""
        return 4.0 * self.dt[None] * self.inv_dx * self.inv_dx * self.particle_volume[None]

    @ti.func
    def affine_momentum(self, s, p, u, elastic):
        """APIC affine momentum m C − (4Δt/Δx²) V_p τ with the fixed-corotated Kirchhoff stress
        τ = 2μ(F − R)Fᵀ + λ(J − 1)J I = U diag(2μ(σ − 1)σ + λ(J − 1)J) Uᵀ."""
        tau = compose(u, principal_stress(elastic, self.shear[None], self.lam[None]), u)
        return self.particle_mass[None] * self.C[s, p] - self.stress_scale() * tau

    @ti.func
    def constitutive_adjoint(self, s, p, affine_bar):
        """Gradients of everything the constitutive update of substep s reads (C, F at slot s and the
        material parameters), given those of the affine momentum and of F at slot s + 1. Adds the
        parameter gradients to particle p's sums; returns (C̄, F̄) at slot s."""
        u, sigma, v, elastic = self.U[s, p], self.sigma[s, p], self.V[s, p], self.elastic[p]
        shear, lam, ys = self.shear[None], self.lam[None], self.yield_stress[None]
        principal = principal_stress(elastic, shear, lam)
        tau_bar = -self.stress_scale() * affine_bar
        u_bar, principal_bar, u_bar_transposed = compose_adjoint(u, principal, u, tau_bar)  # τ = U P Uᵀ
        elastic_bar, shear_bar, lam_bar = principal_stress_adjoint(elastic, shear, lam, principal_bar)
        next_u_bar, next_elastic_bar, v_bar = compose_adjoint(u, elastic, v, self.F_bar[(s + 1) % 2, p])
        sigma_bar, ys_bar, flow_shear_bar = plastic_flow_adjoint(sigma, elastic, ys, shear, elastic_bar + next_elastic_bar)
        trial_bar = svd_backward(u, sigma, v, u_bar + u_bar_transposed + next_u_bar, sigma_bar, v_bar)
        mass_bar = (self.C[s, p] * affine_bar).sum()
        self.add_material_bar(p, ti.Vector([shear_bar + flow_shear_bar, lam_bar, mass_bar, ys_bar, 0.0, 0.0]))
        C_bar = self.particle_mass[None] * affine_bar + self.dt[None] * trial_bar @ self.F[s, p].transpose()
        F_bar = (ti.Matrix.identity(float, 3) + self.dt[None] * self.C[s, p]).transpose() @ trial_bar
        return C_bar, F_bar

    @ti.func
    def add_material_bar(self, p, bar):
        """Add to particle p's parameter gradients (p is one thread's own: no atomic add needed)."""
        self.material_bar[p] = self.material_bar[p] + bar

    # ------------------------------------------------------------------ particle–grid transfers
    # Loops over the 27 stencil nodes: unrolled, the adjoint kernel alone took 65 s to compile (CPU time,
    # development machine), rolled 4.4 s. The forward transfers, the hot serial loops, unroll 9 of the
    # 27 nodes: 2.4 s to compile advance (7.1 s unrolled, 1.1 s rolled), 0.26 ms a substep at 2038
    # particles (0.21 ms unrolled, 0.40 ms rolled).
    @ti.func
    def stencil(self, x):
        """The 3×3×3 stencil of position ``x``: its base node, the particle's offset fx from it (cells),
        and per node offset o (rows) and axis (columns) the quadratic B-spline weight of d = o − fx and
        its derivative with respect to d. Computed once per particle, used for all 27 nodes."""
        base = self.stencil_base(x)
        fx = (x - self.origin[None]) * self.inv_dx - base.cast(float)
        W = ti.Matrix.zero(float, 3, 3)
        D = ti.Matrix.zero(float, 3, 3)
        for o, a in ti.static(ti.ndrange(3, 3)):
            d = o - fx[a]
            if ti.static(o == 1):
                W[o, a], D[o, a] = 0.75 - d ** 2, -2.0 * d
            else:
                W[o, a], D[o, a] = 0.5 * (1.5 - ti.abs(d)) ** 2, -(1.5 - ti.abs(d)) * ti.math.sign(d)
        return base, fx, W, D

    @ti.func
    def stencil_base(self, x):
        """The lowest node of the 3×3×3 stencil of position ``x``."""
        X = (x - self.origin[None]) * self.inv_dx
        return ti.min(ti.max(ti.cast(X - 0.5, ti.i32), 0), ti.Vector(self.grid_shape) - 3)

    @ti.func
    def stencil_node(self, base, fx, W, D, i, j, k):
        """Node (i, j, k) of a :meth:`stencil`: its index, weight, offset from the particle (m), and the
        weight's gradient with respect to the particle position (1/m)."""
        w = W[i, 0] * W[j, 1] * W[k, 2]
        grad_w = -self.inv_dx * ti.Vector([D[i, 0] * W[j, 1] * W[k, 2], W[i, 0] * D[j, 1] * W[k, 2],
                                           W[i, 0] * W[j, 1] * D[k, 2]])
        offset = ti.Vector([i, j, k])
        return base + offset, w, (offset.cast(float) - fx) * self.dx, grad_w

    @ti.func
    def particle_to_grid(self, s, p):
        """grid momentum += w (m v + A (x_i − x_p)), grid mass += w m, A the affine momentum."""
        mass, v, A = self.particle_mass[None], self.v[s, p], self.affine[p]
        base, fx, W, D = self.stencil(self.x[s, p])
        for i in range(3):
            for j, k in ti.static(ti.ndrange(3, 3)):
                node, w, dpos, _ = self.stencil_node(base, fx, W, D, i, j, k)
                self.grid_p[node] += w * (mass * v + A @ dpos)
                self.grid_m[node] += w * mass

    @ti.func
    def grid_to_particle(self, s, p):
        """v = Σ w v_i and C = (4/Δx²) Σ w v_i (x_i − x_p)ᵀ."""
        v = ti.Vector.zero(float, 3)
        C = ti.Matrix.zero(float, 3, 3)
        base, fx, W, D = self.stencil(self.x[s, p])
        for i in range(3):
            for j, k in ti.static(ti.ndrange(3, 3)):
                node, w, dpos, _ = self.stencil_node(base, fx, W, D, i, j, k)
                v += w * self.grid_v[node]
                C += (4.0 * self.inv_dx * self.inv_dx * w) * self.grid_v[node].outer_product(dpos)
        return v, C

    @ti.func
    def grid_to_particle_scatter_adjoint(self, s, p, v_bar, C_bar):
        """Adds the gradients of :meth:`grid_to_particle` with respect to the grid velocities, given those
        of v and C, to the nodes' (the position's gradient is gathered by :meth:`transfers_adjoint`)."""
        C_bar_scaled = 4.0 * self.inv_dx * self.inv_dx * C_bar
        base, fx, W, D = self.stencil(self.x[s, p])
        for i in range(3):
            for j, k in ti.static(ti.ndrange(3, 3)):
                node, w, dpos, _ = self.stencil_node(base, fx, W, D, i, j, k)
                self.grid_v_bar[node] += w * (v_bar + C_bar_scaled @ dpos)

    @ti.func
    def transfers_adjoint(self, s, p, velocity_bar, C_bar):
        """What particle p gathers from the grid in the reverse of substep s's two transfers: the gradient
        of its position through :meth:`grid_to_particle` (given those of its v and C, ``velocity_bar`` and
        ``C_bar``) and through :meth:`particle_to_grid` (given those of grid momentum and mass), and the
        gradients of its velocity, affine momentum and mass through the latter. Returns (x̄, v̄, Ā, m̄)."""
        mass, v, A = self.particle_mass[None], self.v[s, p], self.affine[p]
        C_bar_scaled = 4.0 * self.inv_dx * self.inv_dx * C_bar
        x_bar, weighted_v, weighted_p_bar = ti.Vector.zero(float, 3), ti.Vector.zero(float, 3), ti.Vector.zero(float, 3)
        A_bar = ti.Matrix.zero(float, 3, 3)
        weighted_m_bar = 0.0
        base, fx, W, D = self.stencil(self.x[s, p])
        for i, j, k in ti.ndrange(3, 3, 3):
            node, w, dpos, grad_w = self.stencil_node(base, fx, W, D, i, j, k)
            g_v, p_bar, m_bar = self.grid_v[node], self.grid_p_bar[node], self.grid_m_bar[node]
            weighted_v += w * g_v
            weighted_p_bar += w * p_bar
            weighted_m_bar += w * m_bar
            A_bar += w * p_bar.outer_product(dpos)
            x_bar += (g_v.dot(velocity_bar + C_bar_scaled @ dpos) + p_bar.dot(mass * v + A @ dpos) + m_bar * mass) * grad_w
        x_bar -= C_bar_scaled.transpose() @ weighted_v + A.transpose() @ weighted_p_bar
        return x_bar, mass * weighted_p_bar, A_bar, v.dot(weighted_p_bar) + weighted_m_bar

    @ti.func
    def grid_velocity(self, s, p):
        """Σ w v_i: the particle's velocity interpolated from the grid."""
        v = ti.Vector.zero(float, 3)
        base, fx, W, D = self.stencil(self.x[s, p])
        for i, j, k in ti.ndrange(3, 3, 3):
            node, w, _, _ = self.stencil_node(base, fx, W, D, i, j, k)
            v += w * self.grid_v[node]
        return v

    @ti.func
    def bin_particles(self, s):
        """Sort the particles of slot s into bins by their stencil's base node (a counting sort in one
        serial loop: about 0.2 ms a substep at 17 000 particles), for :meth:`gathered`. Bases lie in the
        grid region less its last two nodes per axis."""
        lo, hi = self.region_lo[None], self.region_hi[None] - 2
        for _ in range(1):  # one thread: the counts, their running sum and the order depend on each other
            for I in ti.grouped(ti.ndrange((lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2]))):
                self.bin_count[I] = 0
            for p in range(self.n_particles[None]):
                self.bin_count[self.stencil_base(self.x[s, p])] += 1
            end = 0
            for I in ti.grouped(ti.ndrange((lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2]))):
                end += self.bin_count[I]
                self.bin_first[I] = end
            for p in range(self.n_particles[None]):
                base = self.stencil_base(self.x[s, p])
                self.bin_first[base] -= 1
                self.bin_rank[p] = self.bin_first[base]

    @ti.func
    def sort_transfer(self, s, p, a, A, with_weights: ti.template()):
        """Store particle p's transfer (vector ``a``, matrix ``A``) in bin order, and with ``with_weights``
        its stencil offset and weights at slot s."""
        q = self.bin_rank[p]
        self.sorted_a[q], self.sorted_A[q] = a, A
        if ti.static(with_weights):
            _, fx, W, _D = self.stencil(self.x[s, p])
            self.sorted_fx[q] = fx
            for o, axis in ti.static(ti.ndrange(3, 3)):
                self.sorted_W[q, o, axis] = W[o, axis]

    @ti.func
    def gathered(self, I):
        """Node I's sums over the particles (binned by :meth:`bin_particles`, transfers stored by
        :meth:`sort_transfer`) whose stencils reach it: Σ w and Σ w (a + A (x_i − x_p)). Forward (a, A) =
        (m v, affine momentum): the mass over m and the momentum that :meth:`particle_to_grid` scatters;
        backward (v̄, (4/Δx²) C̄): the velocity gradient that :meth:`grid_to_particle_scatter_adjoint` scatters."""
        lo, hi = self.region_lo[None], self.region_hi[None] - 3
        weight, total = 0.0, ti.Vector.zero(float, 3)
        for o in ti.grouped(ti.ndrange(3, 3, 3)):
            base = I - o
            if (base >= lo).all() and (base <= hi).all():
                first = self.bin_first[base]
                for q in range(first, first + self.bin_count[base]):
                    w = self.sorted_W[q, o[0], 0] * self.sorted_W[q, o[1], 1] * self.sorted_W[q, o[2], 2]
                    dpos = (o.cast(float) - self.sorted_fx[q]) * self.dx
                    total += w * (self.sorted_a[q] + self.sorted_A[q] @ dpos)
                    weight += w
        return weight, total

    # ------------------------------------------------------------------ contact
    @ti.func
    def walled(self, I, v, w):
        """``w`` with the components zeroed in which velocity ``v`` at node I points out of the box near
        its faces (the walls: applied to v itself, and to its gradient)."""
        return ti.Vector([
            ti.select(((I[d] < WALL_CELLS) & (v[d] < 0.0))
                      | ((I[d] >= ti.static(self.grid_shape[d] - WALL_CELLS)) & (v[d] > 0.0)), 0.0, w[d])
            for d in ti.static(range(3))])

    @ti.func
    def node_contact(self, I):
        """Node I's velocity before contact (from momentum, mass and gravity), after the table, and after
        the effector."""
        free = self.grid_p[I] / self.grid_m[I] + self.dt[None] * ti.Vector([0.0, 0.0, GRAVITY])
        on_table = self.origin[None][2] + I[2] * self.dx <= self.table_z[None]
        after_table = free
        if on_table:
            after_table = frictional_contact(free, ti.Vector.zero(float, 3), ti.Vector([0.0, 0.0, 1.0]), self.mu_table[None])
        after_effector = after_table
        if self.effector_touches(I):
            after_effector = frictional_contact(after_table, self.g_v_effector[I], self.g_normal[I], self.mu_effector[None])
        return free, on_table, after_table, after_effector

    @ti.func
    def update_node(self, I):
        if self.grid_m[I] > 0.0:
            _, _, _, after_effector = self.node_contact(I)
            self.grid_v[I] = self.walled(I, after_effector, after_effector)

    @ti.func
    def update_node_adjoint(self, I):
        """Gradients of node I's momentum and mass from that of its velocity, which it then clears; adds
        the friction coefficients' gradients to the node's sums."""
        p_bar, m_bar = ti.Vector.zero(float, 3), 0.0
        if self.grid_m[I] > 0.0:
            free, on_table, after_table, after_effector = self.node_contact(I)
            bar = self.walled(I, after_effector, self.grid_v_bar[I])
            mu_effector_bar, mu_table_bar = 0.0, 0.0
            if self.effector_touches(I):
                bar, mu_effector_bar = frictional_contact_adjoint(after_table, self.g_v_effector[I], self.g_normal[I],
                                                                  self.mu_effector[None], bar)
            if on_table:
                bar, mu_table_bar = frictional_contact_adjoint(free, ti.Vector.zero(float, 3),
                                                               ti.Vector([0.0, 0.0, 1.0]), self.mu_table[None], bar)
            p_bar = bar / self.grid_m[I]
            m_bar = -bar.dot(self.grid_p[I]) / (self.grid_m[I] * self.grid_m[I])
            self.friction_bar[I] = self.friction_bar[I] + ti.Vector([mu_table_bar, mu_effector_bar])
        self.grid_p_bar[I], self.grid_m_bar[I] = p_bar, m_bar
        self.grid_v_bar[I] = ti.Vector.zero(float, 3)  # consumed: zero again for the next substep

    @ti.func
    def on_table(self, s, p):
        return self.x[s, p][2] <= self.table_z[None]

    @ti.func
    def in_contact(self, s, p):
        """Whether particle p touches the table or the effector in substep s."""
        return self.on_table(s, p) or self.p_phi[p] <= 0.0

    @ti.func
    def particle_contact(self, s, p, v):
        """Particle velocity ``v`` after the table and after the effector."""
        after_table = v
        if self.on_table(s, p):
            after_table = frictional_contact(v, ti.Vector.zero(float, 3), ti.Vector([0.0, 0.0, 1.0]), self.mu_table[None])
        after_effector = after_table
        if self.p_phi[p] <= 0.0:
            after_effector = frictional_contact(after_table, self.p_v_effector[p], self.p_normal[p], self.mu_effector[None])
        return after_table, after_effector

    @ti.func
    def particle_contact_adjoint(self, s, p, v, bar):
        """Gradient of the velocity ``v`` before :meth:`particle_contact` from that after it; adds the
        friction coefficients' gradients to the particle's sums."""
        after_table, _ = self.particle_contact(s, p, v)
        v_bar = bar
        mu_effector_bar, mu_table_bar = 0.0, 0.0
        if self.p_phi[p] <= 0.0:
            v_bar, mu_effector_bar = frictional_contact_adjoint(after_table, self.p_v_effector[p], self.p_normal[p],
                                                                self.mu_effector[None], v_bar)
        if self.on_table(s, p):
            v_bar, mu_table_bar = frictional_contact_adjoint(v, ti.Vector.zero(float, 3), ti.Vector([0.0, 0.0, 1.0]),
                                                             self.mu_table[None], v_bar)
        self.add_material_bar(p, ti.Vector([0.0, 0.0, 0.0, 0.0, mu_table_bar, mu_effector_bar]))
        return v_bar

    def gathers(self, serial: bool) -> bool:
        """Whether the transfers gather at the nodes (loops on several CPU threads) rather than scatter
        from the particles (one thread, or a GPU): see the module docstring."""
        return not serial and self.config.arch == "cpu"

    @ti.func
    def update_grid(self, serial: ti.template()):
        """Loop 4 over the grid region (where the transfers gather, their loop 3 first, node by node)."""
        ti.loop_config(serialize=serial)
        for I in ti.grouped(ti.ndrange(*[(self.region_lo[None][a], self.region_hi[None][a]) for a in range(3)])):
            if ti.static(self.gathers(serial)):
                weight, self.grid_p[I] = self.gathered(I)
                self.grid_m[I] = weight * self.particle_mass[None]
            self.update_node(I)

    # ------------------------------------------------------------------ substep kernels
    @ti.kernel
    def tabulate_contact(self, s: ti.i32, serial: ti.template()):
        """Start substep s: find the region of grid nodes the particles' stencils reach (where the
        substep's grid work happens), clear it, and tabulate the effector's contact geometry at the
        particles and at the region's nodes within the effector's reach (a kernel of its own, shared by
        :meth:`advance` and :meth:`restore`: the effector's shapes are most of the compile time)."""
        self.region_lo[None] = ti.Vector(self.grid_shape)
        self.region_hi[None] = ti.Vector.zero(ti.i32, 3)
        ti.loop_config(serialize=ti.static(serial or self.gathers(serial)))  # contended atomics: worse than one thread
        for p in range(self.n_particles[None]):
            base = self.stencil_base(self.x[s, p])
            for a in ti.static(range(3)):
                ti.atomic_min(self.region_lo[None][a], base[a])
                ti.atomic_max(self.region_hi[None][a], base[a] + 3)
        if ti.static(self.gathers(serial)):
            self.bin_particles(s)
        if ti.static(not self.gathers(serial)):  # gathering sets every node of the region
            ti.loop_config(serialize=serial)
            for I in ti.grouped(ti.ndrange(*[(self.region_lo[None][a], self.region_hi[None][a]) for a in range(3)])):
                self.grid_m[I] = 0.0
                self.grid_p[I] = ti.Vector.zero(float, 3)
        lo = ti.max(self.reach_node_lo[None], self.region_lo[None])
        extent = ti.max(ti.min(self.reach_node_hi[None], self.region_hi[None]) - lo, 0)
        ti.loop_config(serialize=serial)
        for q in range(self.n_particles[None] + extent[0] * extent[1] * extent[2]):
            self.tabulate_point_contact(q, s, lo, extent)

    @ti.kernel
    def advance(self, s: ti.i32, serial: ti.template()):
        """Substep s after :meth:`tabulate_contact`: state slot s → s + 1 (loops 2–5 of the module
        docstring). The SVD makes the constitutive loop heavy enough to be worth starting threads for,
        whatever ``serial`` says."""
        for p in range(self.n_particles[None]):
            previous = self.V_start[p]
            if s > 0:
                previous = self.V[s - 1, p]
            u, sigma, v = warm_started_svd(self.trial(s, p), previous)
            self.U[s, p], self.V[s, p], self.sigma[s, p] = u, v, sigma
            elastic = plastic_flow(sigma, self.yield_stress[None], self.shear[None])
            self.F[s + 1, p] = compose(u, elastic, v)
            self.affine[p] = self.affine_momentum(s, p, u, elastic)
            if ti.static(self.gathers(serial)):
                self.sort_transfer(s, p, self.particle_mass[None] * self.v[s, p], self.affine[p], True)
        if ti.static(not self.gathers(serial)):
            ti.loop_config(serialize=serial)
            for p in range(self.n_particles[None]):
                self.particle_to_grid(s, p)
        self.update_grid(serial)
        ti.loop_config(serialize=serial)
        for p in range(self.n_particles[None]):
            v, self.C[s + 1, p] = self.grid_to_particle(s, p)
            _, after = self.particle_contact(s, p, v)
            self.v[s + 1, p] = after
            self.x[s + 1, p] = self.x[s, p] + self.dt[None] * after

    @ti.kernel
    def restore(self, s: ti.i32, serial: ti.template()):
        """After :meth:`tabulate_contact`, recompute the grid of substep s (and the affine momenta the
        adjoint reads) from the state at slot s and the substep's SVD."""
        ti.loop_config(serialize=serial)
        for p in range(self.n_particles[None]):
            elastic = plastic_flow(self.sigma[s, p], self.yield_stress[None], self.shear[None])
            self.elastic[p] = elastic
            self.affine[p] = self.affine_momentum(s, p, self.U[s, p], elastic)
            if ti.static(self.gathers(serial)):
                self.sort_transfer(s, p, self.particle_mass[None] * self.v[s, p], self.affine[p], True)
            else:
                self.particle_to_grid(s, p)
        self.update_grid(serial)

    @ti.kernel
    def adjoint(self, s: ti.i32, serial: ti.template()):
        """Gradients of the state at slot s from those at slot s + 1, through substep s (after
        :meth:`restore`): advection and particle contact, scattering the grid velocities' gradients; the
        grid update; then each particle gathers from the grid its gradients through both transfers and
        goes back through the constitutive update. Like the SVD of :meth:`advance`, that last loop has no
        atomics and is heavy enough to be worth starting threads for, whatever ``serial`` says."""
        now, later = s % 2, (s + 1) % 2
        ti.loop_config(serialize=serial)
        for p in range(self.n_particles[None]):
            velocity_bar = self.v_bar[later, p] + self.dt[None] * self.x_bar[later, p]
            if self.in_contact(s, p):  # only then does the velocity before contact matter
                velocity_bar = self.particle_contact_adjoint(s, p, self.grid_velocity(s, p), velocity_bar)
            self.velocity_bar[p] = velocity_bar
            if ti.static(self.gathers(serial)):
                self.sort_transfer(s, p, velocity_bar, 4.0 * self.inv_dx * self.inv_dx * self.C_bar[later, p], False)
            else:
                self.grid_to_particle_scatter_adjoint(s, p, velocity_bar, self.C_bar[later, p])
        ti.loop_config(serialize=serial)
        for I in ti.grouped(ti.ndrange(*[(self.region_lo[None][a], self.region_hi[None][a]) for a in range(3)])):
            if ti.static(self.gathers(serial)):
                _, self.grid_v_bar[I] = self.gathered(I)
            self.update_node_adjoint(I)
        for p in range(self.n_particles[None]):  # no atomics, heavy (SVD adjoint): always worth threads
            x_bar, v_bar, affine_bar, mass_bar = self.transfers_adjoint(s, p, self.velocity_bar[p], self.C_bar[later, p])
            self.add_material_bar(p, ti.Vector([0.0, 0.0, mass_bar, 0.0, 0.0, 0.0]))
            C_bar, F_bar = self.constitutive_adjoint(s, p, affine_bar)
            self.x_bar[now, p] = self.x_bar[later, p] + x_bar
            self.v_bar[now, p] = v_bar
            self.C_bar[now, p] = C_bar
            self.F_bar[now, p] = F_bar

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
        upper = ti.Vector(self.grid_shape).cast(float) - 2.0
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
        """Copy the slots that the substeps of the step just simulated start from into ``states``
        (substeps, n, 45): what the backward pass reads (the last slot, the step's end, is not)."""
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
    def seed_gradient(self, grad_x: ti.types.ndarray(), slot: ti.i32):
        """Start a backward pass: the gradient of the final positions in state-gradient ``slot``, zero
        for the rest of the final state and for the parameters' sums."""
        for p in range(self.n_particles[None]):
            for a in ti.static(range(3)):
                self.x_bar[slot, p][a] = grad_x[p, a]
            self.v_bar[slot, p] = ti.Vector.zero(float, 3)
            self.C_bar[slot, p] = ti.Matrix.zero(float, 3, 3)
            self.F_bar[slot, p] = ti.Matrix.zero(float, 3, 3)
            self.material_bar[p] = ti.Vector.zero(float, ti.static(len(MATERIAL_GRADIENTS)))
        for I in ti.grouped(self.friction_bar):
            self.friction_bar[I] = ti.Vector.zero(float, 2)

    @ti.kernel
    def carry_gradient(self):
        """Move the state gradient from slot 0 (the start of the later step) to slot 1 (the end of this
        step, when its substep count is odd)."""
        for p in range(self.n_particles[None]):
            self.x_bar[1, p], self.v_bar[1, p] = self.x_bar[0, p], self.v_bar[0, p]
            self.C_bar[1, p], self.F_bar[1, p] = self.C_bar[0, p], self.F_bar[0, p]

    @ti.kernel
    def sum_parameter_gradients(self):
        """Reduce the per-particle and per-node parameter gradients into ``gradient_total`` (once per
        backward pass)."""
        self.gradient_total[None] = ti.Vector.zero(float, ti.static(len(MATERIAL_GRADIENTS)))
        for p in range(self.n_particles[None]):
            self.gradient_total[None] += self.material_bar[p]
        for I in ti.grouped(self.friction_bar):
            bar = self.friction_bar[I]
            self.gradient_total[None] += ti.Vector([0.0, 0.0, 0.0, 0.0, bar[0], bar[1]])

    @ti.kernel
    def grid_mass(self) -> float:
        """Total mass on the grid after the last substep (kg): in its region (the rest is stale)."""
        total = 0.0
        for I in ti.grouped(ti.ndrange(*[(self.region_lo[None][a], self.region_hi[None][a]) for a in range(3)])):
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
        self._effector_bounds = effector.bounds
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
        origin = c.check_box(scene)
        tips, yaws = scene.tip_poses()
        self.n_particles[None] = n
        self.origin[None] = origin
        self._origin = origin
        self.table_z[None] = scene.table_z
        self.particle_volume[None] = scene.particle_volume
        self._set_effector(scene.effector)
        padded = np.zeros((c.max_steps + 1, 3), dtype=np.float64)
        padded[: steps + 1] = tips
        self.tip.from_numpy(padded)
        self._tips = tips
        padded_yaw = np.zeros(c.max_steps + 1, dtype=np.float64)
        padded_yaw[: steps + 1] = yaws
        self.yaw.from_numpy(padded_yaw)

    def _set_params(self, params: Parameters) -> None:
        params.check_range()
        for name in ("yield_stress", "mu_table", "mu_effector"):
            getattr(self, name)[None] = getattr(params, name)
        self.shear[None], self.lam[None] = lame_parameters(params.E, params.nu)
        self.particle_mass[None] = params.rho * self.particle_volume[None]
        self.substeps = self.config.substeps(params)
        self.n_substeps[None] = self.substeps
        self.dt[None] = self.config.step_dt / self.substeps

    def _begin_step(self, step: int) -> None:
        """Set the step whose substeps run next, and limit their contact tests to the effector's reach in
        this step."""
        self.step[None] = step
        reach_lo, reach_hi = self._effector_reach(step)
        node_lo = np.clip(np.floor((reach_lo - self._origin) * self.inv_dx).astype(int), 0, self.grid_shape)
        node_hi = np.clip(np.ceil((reach_hi - self._origin) * self.inv_dx).astype(int) + 1, node_lo, self.grid_shape)
        self.reach_lo[None], self.reach_hi[None] = reach_lo, reach_hi
        self.reach_node_lo[None], self.reach_node_hi[None] = node_lo, node_hi

    def _effector_reach(self, step: int) -> tuple[np.ndarray, np.ndarray]:
        """World box (m) holding every point that :meth:`effector_contact` tests during ``step``: the
        effector's bounds plus CONTACT_MARGIN_CELLS, turned by any yaw (a circle in x, y), swept from the
        step's first tip position to its last, plus one cell for round-off."""
        margin = CONTACT_MARGIN_CELLS * self.dx
        lower, upper = np.asarray(self._effector_bounds[0]) - margin, np.asarray(self._effector_bounds[1]) + margin
        radius = np.hypot(max(abs(lower[0]), abs(upper[0])), max(abs(lower[1]), abs(upper[1])))
        tips = self._tips[step:step + 2]
        low = tips.min(axis=0) + np.array([-radius, -radius, lower[2]]) - self.dx
        high = tips.max(axis=0) + np.array([radius, radius, upper[2]]) + self.dx
        return low, high

    def forward(self, scene: Scene, params: Parameters, keep_substeps: bool = True) -> np.ndarray:
        """Simulate the scene with parameters θ and return the final particle positions (n, 3) in m.

        Keeps a checkpoint of every step for :meth:`backward` and, if ``keep_substeps`` and they fit in
        the memory budget, every substep's state too (which makes the backward pass about a third
        faster; pass False when no backward pass follows)."""
        self._set_scene(scene)
        self._set_params(params)
        # let the last run's checkpoints go before this run's exist: both at once set the peak memory
        self._params = self._checkpoints = self._substates = None
        n, steps = len(scene.particles), scene.trajectory.n_steps
        memory.check_fits((steps + 1) * n * STATE_WIDTH * np.dtype(np.float64).itemsize,
                   f"the checkpoints of this scene ({steps + 1} steps × {n} particles)",
                   "use fewer particles (a lower particle density) or a shorter trajectory")
        checkpoints = np.empty((steps + 1, n, STATE_WIDTH), dtype=np.float64)
        checkpoints[0] = 0.0
        checkpoints[0, :, :3] = scene.particles
        checkpoints[0, :, 15:24] = np.eye(3).reshape(1, 9)
        checkpoints[0, :, 24:33] = np.eye(3).reshape(1, 9)
        self.load_state(checkpoints[0])
        substates = self._substep_storage(n, steps) if keep_substeps else None
        for step in range(steps):
            self._begin_step(step)
            for s in range(self.substeps):
                self.tabulate_contact(s, self.serial)
                self.advance(s, self.serial)
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
        """Room for every substep state of the trajectory, or None if it exceeds the memory budget or the
        memory available (the backward pass then recomputes them). The buffer is kept and reused by later
        calls (fresh memory costs a page fault per 4 KiB)."""
        shape = (steps, self.substeps, n, SUBSTEP_WIDTH)
        size = int(np.prod(shape))
        if size * self._substep_buffer.itemsize > self.config.substep_memory_mb * MIB:
            return None
        if self._substep_buffer.size < size:
            self._substep_buffer = np.empty(0, dtype=np.float64)
            available = memory.available_memory()
            if available is not None and size * self._substep_buffer.itemsize > available:
                return None
            self._substep_buffer = mapped_array(size, np.float64)
        return self._substep_buffer[:size].reshape(shape)

    def final_positions(self) -> np.ndarray:
        """Particle positions (n, 3) in m at the end of the last :meth:`forward`."""
        if self._checkpoints is None:
            raise SimulationError("no simulation has run yet")
        return self._checkpoints[-1, :, :3].astype(np.float64)

    def positions_at(self, steps) -> np.ndarray:
        """Particle positions (len(steps), n, 3) in m at the start of the given steps of the last
        :meth:`forward` (step n_steps is the end of the trajectory)."""
        if self._checkpoints is None:
            raise SimulationError("no simulation has run yet")
        steps = np.asarray(steps, dtype=int)
        if steps.min() < 0 or steps.max() >= len(self._checkpoints):
            raise ValueError(f"steps must lie in 0..{len(self._checkpoints) - 1}, got {steps.tolist()}")
        return self._checkpoints[steps, :, :3].astype(np.float64)

    def backward(self, grad_positions: np.ndarray) -> dict[str, float]:
        """Gradient of a scalar loss L with respect to θ, given dL/d(final positions) (n, 3) in 1/m
        times the loss unit. Requires a preceding :meth:`forward`."""
        if self._checkpoints is None:
            raise SimulationError("backward() needs a forward() first")
        checkpoints = self._checkpoints
        grad_positions = np.ascontiguousarray(grad_positions, dtype=np.float64)
        if grad_positions.shape != checkpoints.shape[1:2] + (3,):
            raise ValueError(f"gradient has shape {grad_positions.shape}, expected {(checkpoints.shape[1], 3)}")
        odd = self.substeps % 2
        self.seed_gradient(grad_positions, odd)
        for step in reversed(range(len(checkpoints) - 1)):
            if odd and step < len(checkpoints) - 2:
                self.carry_gradient()
            self._begin_step(step)
            if self._substates is not None:
                self.load_substeps(self._substates[step])
            else:
                self.load_state(checkpoints[step])
                for s in range(self.substeps):
                    self.tabulate_contact(s, self.serial)
                    self.advance(s, self.serial)
            for s in reversed(range(self.substeps)):
                self.tabulate_contact(s, self.serial)
                self.restore(s, self.serial)
                self.adjoint(s, self.serial)
        grads = self._parameter_gradients()
        bad = [k for k, g in grads.items() if not np.isfinite(g)]
        if bad:
            raise SimulationError(f"gradient of {bad} is not finite (parameters {self._params.as_dict()})")
        return grads

    def _parameter_gradients(self) -> dict[str, float]:
        """dL/dθ from the per-particle and per-node sums of a finished backward pass."""
        self.sum_parameter_gradients()
        bar = dict(zip(MATERIAL_GRADIENTS, map(float, self.gradient_total[None].to_numpy())))
        params = self._params
        E_bar, nu_bar = lame_gradient(params.E, params.nu, bar["shear"], bar["lam"])
        return {"E": E_bar, "nu": nu_bar, "rho": bar["particle_mass"] * float(self.particle_volume[None]),
                "yield_stress": bar["yield_stress"], "mu_table": bar["mu_table"], "mu_effector": bar["mu_effector"]}

    def effector_signed_distance(self, scene: Scene, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) of world points to the scene's effector at its start pose."""
        self._set_scene(scene)
        points = np.ascontiguousarray(points, dtype=np.float64)
        out = np.empty(len(points))
        self.effector_distance(points, out)
        return out

