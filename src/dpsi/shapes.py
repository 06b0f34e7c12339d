"""Clay-lump meshes standing on the table, for synthetic data. Units: metres and radians.

A lump is a solid of revolution squeezed into an elliptic footprint: a vertical wall of height ``wall``
topped by a rounded cap reaching ``top`` above the table, with a flat bottom on the plane z = ``table_z``.
The cap's profile is the superellipse |r/R|^p + |(z − wall)/(top − wall)|^p = 1 (p = 2: a half
ellipsoid; larger p: a flatter top with rounder shoulders). A small ``wobble`` (relative amplitudes of the
2nd, 3rd, … harmonics of the footprint radius) makes it less regular while keeping it convex-ish.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

SIZE_RANGE = {
    "semi_major": (0.022, 0.035),    # m: 4.4–7 cm across
    "aspect": (0.7, 1.0),            # minor / major semi-axis
    "top": (0.022, 0.038),           # m above the table
    "wall_fraction": (0.3, 0.6),     # wall height / top
    "roundness": (2.0, 3.0),         # superellipse exponent p of the cap
    "wobble": (0.0, 0.04),           # amplitude of each of the 2nd and 3rd harmonics
}
"""Ranges from which :func:`random_lump` draws its shape, like the published real clay lumps."""


def lump(semi_axes=(0.035, 0.035), wall: float = 0.012, top: float = 0.03, centre=(0.0, 0.0),
         table_z: float = 0.0, yaw: float = 0.0, roundness: float = 2.0, wobble=(), n_around: int = 48,
         n_up: int = 12) -> o3d.geometry.TriangleMesh:
    """Watertight, outward-wound lump mesh (m) standing on z = ``table_z``, centred at ``centre`` (x, y).

    ``semi_axes``: footprint semi-axes (m) along the lump's own x and y, which is yawed by ``yaw`` (rad);
    ``wall``, ``top``: wall height and total height (m) above the table; ``roundness``, ``wobble``: see
    the module docstring; ``n_around``, ``n_up``: vertices around and along the cap."""
    a, b = map(float, semi_axes)
    if not (a > 0 and b > 0 and 0 < wall < top):
        raise ValueError(f"lump needs positive semi-axes and 0 < wall < top, got semi_axes={semi_axes}, "
                         f"wall={wall} m, top={top} m")
    if roundness < 1:
        raise ValueError(f"lump roundness must be at least 1, got {roundness}")
    phi = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    scale = np.ones(n_around) + sum(w * np.cos((k + 2) * phi) for k, w in enumerate(wobble))
    if (scale <= 0.5).any():
        raise ValueError(f"lump wobble {wobble} is too large (the footprint would fold)")
    rim = np.column_stack([a * np.cos(phi), b * np.sin(phi)]) * scale[:, None]
    rim = rim @ np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])

    angles = np.linspace(0, np.pi / 2, n_up + 1)[1:-1]
    e = 2.0 / roundness
    profile = [(1.0, wall * k / 4) for k in range(5)]  # (fraction of the rim radius, height)
    profile += [(np.cos(t) ** e, wall + (top - wall) * np.sin(t) ** e) for t in angles]
    cx, cy = map(float, centre)
    verts = [[cx + f * x, cy + f * y, table_z + z] for f, z in profile for x, y in rim]
    verts += [[cx, cy, table_z + top], [cx, cy, table_z]]
    m, faces = len(profile), []
    for i in range(m - 1):
        for j in range(n_around):
            p, q = i * n_around + j, i * n_around + (j + 1) % n_around
            faces += [[p, q, q + n_around], [p, q + n_around, p + n_around]]
    for j in range(n_around):
        faces.append([(m - 1) * n_around + j, (m - 1) * n_around + (j + 1) % n_around, len(verts) - 2])
        faces.append([(j + 1) % n_around, j, len(verts) - 1])
    return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts), o3d.utility.Vector3iVector(faces))


def random_lump(seed: int, centre=(0.0, 0.0), table_z: float = 0.0) -> o3d.geometry.TriangleMesh:
    """A :func:`lump` with its shape drawn uniformly from :data:`SIZE_RANGE` and a random yaw, centred at
    ``centre`` (m) on the plane z = ``table_z``. Deterministic from ``seed``."""
    rng = np.random.default_rng(seed)
    draw = {k: rng.uniform(*r) for k, r in SIZE_RANGE.items() if k != "wobble"}
    wobble = rng.uniform(*SIZE_RANGE["wobble"], size=2) * rng.choice([-1, 1], size=2)
    a = draw["semi_major"]
    return lump((a, a * draw["aspect"]), wall=draw["top"] * draw["wall_fraction"], top=draw["top"],
                centre=centre, table_z=table_z, yaw=rng.uniform(0, np.pi), roundness=draw["roundness"],
                wobble=tuple(wobble))


__all__ = ["SIZE_RANGE", "lump", "random_lump"]
