"""Synthetic depth-camera capture of a watertight object standing on a table (the real setup's six views).

Units: metres and radians. Frames: the robot base frame (z up, the table is the plane z = ``table_z``)
and camera frames in the OpenCV convention (x right, y down, z along the optical axis).

Each view ray-casts a pinhole camera against the object and a square of table around it, so it sees
only the visible surface (never the bottom, with self-occlusion) plus the table. Depth gets Gaussian
noise along each ray. The camera pose used to make the points is the *true* one; the transform returned
with the view is the *believed* one, off by a random rigid error of a few millimetres and a fraction of
a degree, as a calibrated arm-mounted camera would be.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from dpsi.pointclouds import View, check_rigid


@dataclass(frozen=True)
class Camera:
    """Pinhole depth camera: image ``width`` × ``height`` pixels, horizontal field of view ``fov`` (rad),
    usable range [``near``, ``far``] (m) and depth noise standard deviation ``depth_noise`` (m)."""

    width: int = 200
    height: int = 150
    fov: float = np.radians(60.0)
    near: float = 0.05
    far: float = 1.0
    depth_noise: float = 0.0005


def look_at(eye, target) -> np.ndarray:
    """Camera-to-base transform of a camera at ``eye`` (m) whose optical axis points at ``target``
    (m), image x axis kept horizontal."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: the optical axis must not be vertical")
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = eye
    return T


def view_poses(target, n_views: int = 6, distance: float = 0.3, elevation: float = np.radians(55.0),
               first_azimuth: float = 0.0) -> list[np.ndarray]:
    """Camera-to-base transforms of ``n_views`` cameras evenly spaced in azimuth around ``target`` (m),
    ``distance`` (m) away and ``elevation`` (rad) above the horizontal, all looking at ``target``."""
    target = np.asarray(target, float)
    poses = []
    for k in range(n_views):
        a = first_azimuth + 2 * np.pi * k / n_views
        offset = distance * np.array([np.cos(elevation) * np.cos(a), np.cos(elevation) * np.sin(a),
                                      np.sin(elevation)])
        poses.append(look_at(target + offset, target))
    return poses


def perturb(transform, rng: np.random.Generator, translation_std: float = 0.002,
            rotation_std: float = np.radians(0.2)) -> np.ndarray:
    """``transform`` (camera-to-base) composed with a random rigid error in the camera frame: a translation
    with per-axis std ``translation_std`` (m) and a rotation about a random axis by an angle with std
    ``rotation_std`` (rad)."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    R = o3d.geometry.get_rotation_matrix_from_axis_angle(axis * rng.normal(0.0, rotation_std))
    error = np.eye(4)
    error[:3, :3] = R
    error[:3, 3] = rng.normal(0.0, translation_std, 3)
    return check_rigid(np.asarray(transform, float) @ error, "perturbed camera transform")


def _scene(mesh: o3d.geometry.TriangleMesh, table_z: float, table_half: float):
    lo = np.asarray(mesh.get_min_bound())
    hi = np.asarray(mesh.get_max_bound())
    cx, cy = (lo[:2] + hi[:2]) / 2
    table = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector([[cx - table_half, cy - table_half, table_z],
                                    [cx + table_half, cy - table_half, table_z],
                                    [cx + table_half, cy + table_half, table_z],
                                    [cx - table_half, cy + table_half, table_z]]),
        o3d.utility.Vector3iVector([[0, 1, 2], [0, 2, 3]]))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(table))
    return scene


def render(scene: o3d.t.geometry.RaycastingScene, camera_to_base, camera: Camera,
           rng: np.random.Generator) -> np.ndarray:
    """Noisy points (n, 3) in the camera frame that a camera at ``camera_to_base`` sees in ``scene``."""
    T = np.asarray(camera_to_base, float)
    f = camera.width / (2 * np.tan(camera.fov / 2))
    u, v = np.meshgrid(np.arange(camera.width) + 0.5, np.arange(camera.height) + 0.5)
    d_cam = np.column_stack([(u.ravel() - camera.width / 2) / f, (v.ravel() - camera.height / 2) / f,
                             np.ones(u.size)])  # rays with unit depth
    d_base = d_cam @ T[:3, :3].T
    rays = np.hstack([np.broadcast_to(T[:3, 3], d_base.shape), d_base]).astype(np.float32)
    depth = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(float)
    seen = np.isfinite(depth) & (depth >= camera.near) & (depth <= camera.far)
    depth = depth[seen] + rng.normal(0.0, camera.depth_noise, seen.sum())
    return d_cam[seen] * depth[:, None]


def capture(mesh: o3d.geometry.TriangleMesh, table_z: float = 0.0, seed: int = 0, n_views: int = 6,
            camera: Camera = Camera(), distance: float = 0.3, elevation: float = np.radians(55.0),
            translation_error: float = 0.002, rotation_error: float = np.radians(0.2),
            table_half: float = 0.15) -> list[View]:
    """Capture ``mesh`` (m, base frame, standing on the plane z = ``table_z``) from ``n_views`` cameras
    around its bounding-box centre, with a table square of half-side ``table_half`` (m) around it.
    Deterministic from ``seed``. See :func:`view_poses`, :func:`perturb` and :class:`Camera`."""
    if len(mesh.triangles) == 0:
        raise ValueError("capture: the mesh has no triangles")
    if mesh.get_min_bound()[2] < table_z - 1e-3:
        raise ValueError(f"capture: the mesh reaches z = {mesh.get_min_bound()[2]:.4f} m, "
                         f"below the table z = {table_z} m")
    rng = np.random.default_rng(seed)
    scene = _scene(mesh, table_z, table_half)
    target = mesh.get_axis_aligned_bounding_box().get_center()
    views = []
    for true in view_poses(target, n_views, distance, elevation, first_azimuth=rng.uniform(0, 2 * np.pi)):
        points = render(scene, true, camera, rng)
        views.append(View(points, perturb(true, rng, translation_error, rotation_error)))
    return views


__all__ = ["Camera", "look_at", "view_poses", "perturb", "render", "capture"]
