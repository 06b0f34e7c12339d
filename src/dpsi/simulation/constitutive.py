"""The material model in principal stretches, as Taichi functions with hand-written reverse modes.

Von Mises plasticity in Hencky strain and the fixed-corotated Kirchhoff stress (SPEC §4). Each
``*_adjoint`` recomputes what it needs of its forward function and returns the gradients of a scalar
loss with respect to the inputs, given the gradient ``*_bar`` with respect to the output. Stretches are
dimensionless, stresses and moduli in Pa.
"""

import taichi as ti

MIN_STRETCH = 1e-8
"""Smallest singular value taken into the logarithmic strain."""

TINY = 1e-30
"""Added under square roots so that they and their derivatives stay finite at zero."""

ELASTIC_MARGIN = 0.9
""":func:`surely_elastic` answers yes only below this fraction of the yield strain, leaving room for
round-off between its bound and the exact test."""


@ti.func
def surely_elastic(stretch, yield_stress, shear):
    """Whether stretches (each ≥ MIN_STRETCH) lie inside the von Mises surface, decided by a bound that
    takes no logarithm: |log σ_i − log σ_j| ≤ |σ_i − σ_j| / min σ, and ‖dev ε‖² = Σ_{i<j} (ε_i − ε_j)² / 3.
    False means "maybe not": the exact test must decide."""
    low = stretch.min()
    spread = 0.0
    for i, j in ti.static(((0, 1), (0, 2), (1, 2))):
        spread += (stretch[i] - stretch[j]) ** 2
    limit = ELASTIC_MARGIN * yield_stress / (2.0 * shear) * low
    return spread / 3.0 + TINY * low * low < limit * limit


@ti.func
def plastic_flow(sigma, yield_stress, shear):
    """Singular values after projecting the trial Hencky strain log σ onto the von Mises surface
    ‖dev ε‖ ≤ σ_y / (2μ) (inside it, σ itself)."""
    stretch = ti.max(sigma, MIN_STRETCH)
    if not surely_elastic(stretch, yield_stress, shear):
        eps = ti.log(stretch)
        eps_dev = eps - eps.sum() / 3.0
        dev_norm = ti.sqrt(eps_dev.dot(eps_dev) + TINY)
        plastic = dev_norm - yield_stress / (2.0 * shear)
        if plastic > 0.0:
            stretch = ti.exp(eps - plastic / dev_norm * eps_dev)
    return stretch


@ti.func
def plastic_flow_adjoint(sigma, elastic, yield_stress, shear, out_bar):
    """Gradients (σ̄, σ̄_y, μ̄) of :func:`plastic_flow` given its output ``elastic`` (not recomputed: it
    holds the function's exponentials) and the gradient of that output."""
    eps_bar = out_bar * elastic  # of ε = log σ, through exp
    ys_bar, shear_bar = 0.0, 0.0
    if not surely_elastic(ti.max(sigma, MIN_STRETCH), yield_stress, shear):
        eps = ti.log(ti.max(sigma, MIN_STRETCH))
        eps_dev = eps - eps.sum() / 3.0
        dev_norm = ti.sqrt(eps_dev.dot(eps_dev) + TINY)
        excess = dev_norm - yield_stress / (2.0 * shear)
        plastic = ti.max(excess, 0.0)
        ratio = plastic / dev_norm
        z_bar = eps_bar
        dev_bar = -ratio * z_bar
        if excess > 0.0:
            ratio_bar = -z_bar.dot(eps_dev)
            plastic_bar = ratio_bar / dev_norm
            norm_bar = plastic_bar - ratio_bar * plastic / (dev_norm * dev_norm)
            ys_bar = -plastic_bar / (2.0 * shear)
            shear_bar = plastic_bar * yield_stress / (2.0 * shear * shear)
            dev_bar += norm_bar * eps_dev / dev_norm
        eps_bar += dev_bar - dev_bar.sum() / 3.0
    sigma_bar = ti.select(sigma > MIN_STRETCH, eps_bar / sigma, 0.0)
    return sigma_bar, ys_bar, shear_bar


@ti.func
def principal_stress(s, shear, lam):
    """Principal Kirchhoff stresses 2μ(σ − 1)σ + λ(J − 1)J of the fixed-corotated model, J = σ₀σ₁σ₂."""
    J = s[0] * s[1] * s[2]
    return 2.0 * shear * (s - 1.0) * s + lam * (J - 1.0) * J


@ti.func
def principal_stress_adjoint(s, shear, lam, stress_bar):
    """Gradients (σ̄, μ̄, λ̄) of :func:`principal_stress` given the gradient of its output."""
    J = s[0] * s[1] * s[2]
    others = ti.Vector([s[1] * s[2], s[0] * s[2], s[0] * s[1]])  # ∂J/∂σ
    total = stress_bar.sum()
    s_bar = 2.0 * shear * (2.0 * s - 1.0) * stress_bar + lam * (2.0 * J - 1.0) * total * others
    return s_bar, 2.0 * ((s - 1.0) * s).dot(stress_bar), (J - 1.0) * J * total


@ti.func
def column(m, a: ti.template()):
    return ti.Vector([m[0, a], m[1, a], m[2, a]])


@ti.func
def compose(u, s, v):
    """U diag(s) Vᵀ as a sum of outer products of the columns."""
    out = ti.Matrix.zero(float, 3, 3)
    for a in ti.static(range(3)):
        out += s[a] * column(u, a).outer_product(column(v, a))
    return out


@ti.func
def compose_adjoint(u, s, v, out_bar):
    """Gradients (Ū, s̄, V̄) of :func:`compose` given the gradient of its output."""
    scaled_u = ti.Matrix.zero(float, 3, 3)
    scaled_v = ti.Matrix.zero(float, 3, 3)
    for i, a in ti.static(ti.ndrange(3, 3)):
        scaled_u[i, a], scaled_v[i, a] = u[i, a] * s[a], v[i, a] * s[a]
    s_bar = ti.Vector([column(u, a).dot(out_bar @ column(v, a)) for a in ti.static(range(3))])
    return out_bar @ scaled_v, s_bar, out_bar.transpose() @ scaled_u


def lame_parameters(E: float, nu: float) -> tuple[float, float]:
    """Shear modulus μ and Lamé's λ (Pa) from Young's modulus E (Pa) and Poisson's ratio ν."""
    return E / (2.0 * (1.0 + nu)), E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))


def lame_gradient(E: float, nu: float, shear_bar: float, lam_bar: float) -> tuple[float, float]:
    """Gradients (Ē, ν̄) of :func:`lame_parameters` given those of μ and λ."""
    denominator = (1.0 + nu) * (1.0 - 2.0 * nu)
    E_bar = shear_bar / (2.0 * (1.0 + nu)) + lam_bar * nu / denominator
    nu_bar = -shear_bar * E / (2.0 * (1.0 + nu) ** 2) + lam_bar * E * (1.0 + 2.0 * nu * nu) / denominator ** 2
    return E_bar, nu_bar
