"""Geometry and frictional contact, as Taichi functions used inside the simulator's kernels.

Signed distances are in metres, negative inside. Effector shapes are given in the effector frame
(tip at the origin, z up); see :mod:`dpsi.effectors` for the kinds and sizes.
"""

import taichi as ti

from ..effectors import BOX, BULLET, GRID, ROLLER

TINY = 1e-30
"""Added under the square root of a norm so that it and its derivative stay finite at zero."""

NORMAL_STEP = 1e-4
"""Central-difference step (m) for effector normals."""


@ti.func
def box_sdf(p, size):
    """Box of size (x, y, z) standing on the origin, its bottom face centred there."""
    q = ti.abs(p - ti.Vector([0.0, 0.0, 0.5 * size[2]])) - 0.5 * size
    outside = ti.max(q, 0.0).norm()
    inside = ti.min(ti.max(q[0], ti.max(q[1], q[2])), 0.0)
    return outside + inside


@ti.func
def capped_cylinder_sdf(radial, axial, radius, half_length):
    """Cylinder of ``radius`` and axial extent ±half_length, given a point's radial and axial offsets."""
    d = ti.Vector([radial - radius, ti.abs(axial) - half_length])
    return ti.min(ti.max(d[0], d[1]), 0.0) + ti.max(d, 0.0).norm()


@ti.func
def bullet_sdf(p, size):
    """Vertical cylinder of radius size[0] reaching z = size[1], with a hemispherical tip at the origin."""
    r = size[0]
    tip = (p - ti.Vector([0.0, 0.0, r])).norm() - r
    shaft_half = 0.5 * (size[1] - r)
    shaft = capped_cylinder_sdf(ti.Vector([p[0], p[1]]).norm(), p[2] - r - shaft_half, r, shaft_half)
    return ti.min(tip, shaft)


@ti.func
def roller_sdf(p, size):
    """Horizontal cylinder along y (radius size[0], length size[1]) touching the origin from above,
    on a vertical shaft of the same radius up to z = size[2]."""
    r = size[0]
    roller = capped_cylinder_sdf(ti.Vector([p[0], p[2] - r]).norm(), p[1], r, 0.5 * size[1])
    shaft_half = 0.5 * (size[2] - r)
    shaft = capped_cylinder_sdf(ti.Vector([p[0], p[1]]).norm(), p[2] - r - shaft_half, r, shaft_half)
    return ti.min(roller, shaft)


@ti.func
def grid_sdf(p, sdf: ti.template(), lower, spacing):
    """Trilinear interpolation in a sampled signed-distance grid; outside it, the clamped value plus
    the distance to the grid's box (an upper bound, exact enough to say "no contact")."""
    res = sdf.shape[0]
    upper = lower + spacing * (res - 1)
    q = ti.min(ti.max(p, lower), upper)
    g = (q - lower) / spacing
    base = ti.min(ti.cast(ti.floor(g), ti.i32), res - 2)
    f = g - base
    value = 0.0
    for i, j, k in ti.static(ti.ndrange(2, 2, 2)):
        w = (f[0] if i else 1.0 - f[0]) * (f[1] if j else 1.0 - f[1]) * (f[2] if k else 1.0 - f[2])
        value += w * sdf[base[0] + i, base[1] + j, base[2] + k]
    return value + (p - q).norm()


@ti.func
def effector_sdf(p, kind: ti.i32, size, sdf: ti.template(), lower, spacing):
    """Signed distance of point ``p`` (effector frame) to the effector of the given kind."""
    d = 0.0
    if kind == BOX:
        d = box_sdf(p, size)
    elif kind == BULLET:
        d = bullet_sdf(p, size)
    elif kind == ROLLER:
        d = roller_sdf(p, size)
    elif kind == GRID:
        d = grid_sdf(p, sdf, lower, spacing)
    return d


@ti.func
def effector_normal(p, kind: ti.i32, size, sdf: ti.template(), lower, spacing):
    """Outward unit normal ∇φ/‖∇φ‖ by central differences (effector frame). The six evaluations run in
    a loop, so that the signed distance is compiled once."""
    n = ti.Vector.zero(float, 3)
    for q in range(6):
        a, sign = q // 2, 1.0 - 2.0 * (q % 2)
        e = ti.Vector([ti.select(a == b, sign * NORMAL_STEP, 0.0) for b in ti.static(range(3))])
        n[a] += sign * effector_sdf(p + e, kind, size, sdf, lower, spacing)
    return n / ti.max(n.norm(), 1e-12)


@ti.func
def rotation_z(angle):
    c, s = ti.cos(angle), ti.sin(angle)
    return ti.Matrix([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@ti.func
def frictional_contact(v, v_obj, n, mu):
    """Velocity after contact with a rigid body moving at ``v_obj`` with outward normal ``n`` (SPEC §4):
    nothing when separating; sticky inside the friction cone; otherwise the tangential slip is
    reduced by μ times the normal approach speed."""
    v_rel = v - v_obj
    vn = v_rel.dot(n)
    result = v
    if vn < 0.0:
        vt = v_rel - vn * n
        vt_norm = ti.sqrt(vt.dot(vt) + TINY)
        if vt_norm <= -mu * vn:
            result = v_obj
        else:
            result = vt * (1.0 + mu * vn / vt_norm) + v_obj
    return result


@ti.func
def frictional_contact_adjoint(v, v_obj, n, mu, result_bar):
    """Gradients (v̄, μ̄) of :func:`frictional_contact` given the gradient of its result (the body's
    velocity and normal are not differentiated)."""
    v_rel = v - v_obj
    vn = v_rel.dot(n)
    v_bar = result_bar
    mu_bar = 0.0
    if vn < 0.0:
        vt = v_rel - vn * n
        vt_norm = ti.sqrt(vt.dot(vt) + TINY)
        if vt_norm <= -mu * vn:
            v_bar = ti.Vector.zero(float, 3)
        else:
            scale_bar = vt.dot(result_bar)
            mu_bar = scale_bar * vn / vt_norm
            vn_bar = scale_bar * mu / vt_norm
            norm_bar = -scale_bar * mu * vn / (vt_norm * vt_norm)
            vt_bar = (1.0 + mu * vn / vt_norm) * result_bar + norm_bar * vt / vt_norm
            v_bar = vt_bar + (vn_bar - n.dot(vt_bar)) * n
    return v_bar, mu_bar
