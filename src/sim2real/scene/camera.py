"""Pinhole cameras in the OpenCV convention, poses, random pose sampling and trajectories.

Convention (the one place it is written down; tests check the round trip):

* World units are millimetres. Camera axes: x right, y down, z forward.
* ``K`` is 3x3, ``world_to_camera`` a 4x4 rigid transform ``[R t; 0 1]``.
* A world point X projects to ``[u, v, 1]^T ~ K (R X + t)``. ``u`` runs along columns,
  ``v`` along rows, and pixel (col, row) has its centre at (col + 0.5, row + 0.5).
* ``depth`` is the z coordinate in the camera frame (mm), not the Euclidean distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from sim2real.errors import UserError


@dataclass(frozen=True)
class Camera:
    """Intrinsics, pose and image size of one view."""

    K: np.ndarray  # (3, 3) float64
    world_to_camera: np.ndarray  # (4, 4) float64
    height: int
    width: int

    @property
    def camera_to_world(self) -> np.ndarray:
        return invert_rigid(self.world_to_camera)

    @property
    def position(self) -> np.ndarray:
        """Camera centre in world coordinates (mm)."""
        return self.camera_to_world[:3, 3]


FOV_RANGE_DEG = (1.0, 170.0)
"""Horizontal fields of view that :func:`intrinsics_from_fov` accepts."""


def intrinsics_from_fov(width: int, height: int, fov_x_deg: float) -> np.ndarray:
    """Square-pixel pinhole K with the principal point at the image centre."""
    check_size(height, width)
    check_fov(fov_x_deg)
    f = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def intrinsics_from_values(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Pinhole K of a calibrated camera (pixels of a ``width x height`` image): focal lengths
    ``fx``, ``fy`` and the principal point (``cx``, ``cy``) inside the image, its horizontal
    field of view in :data:`FOV_RANGE_DEG`. Lens distortion is not modelled."""
    check_size(height, width)
    if not all(math.isfinite(v) for v in (fx, fy, cx, cy)) or fx <= 0 or fy <= 0:
        raise UserError(f"intrinsics need positive focal lengths, got fx {fx:g}, fy {fy:g}")
    if not (0 < cx < width and 0 < cy < height):
        raise UserError(f"the principal point ({cx:g}, {cy:g}) lies outside the {width}x{height} image")
    fov = horizontal_fov_deg(np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), width)
    lo, hi = FOV_RANGE_DEG
    if not lo <= fov <= hi:
        raise UserError(f"the intrinsics give a horizontal field of view of {fov:.1f} degrees, outside [{lo:g}, {hi:g}]")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def horizontal_fov_deg(K: np.ndarray, width: int) -> float:
    """The angle (degrees) between the rays through the left and the right image edges, in the
    plane of the principal point's row."""
    fx, cx = float(K[0, 0]), float(K[0, 2])
    return math.degrees(math.atan(cx / fx) + math.atan((width - cx) / fx))


def view_intrinsics(width: int, height: int, fov_x_deg: float, values=None) -> np.ndarray:
    """The K of random views: a calibrated camera's ``values`` (fx, fy, cx, cy in pixels of
    ``width x height``, :func:`intrinsics_from_values`) where given, else the centred square-pixel
    K of ``fov_x_deg`` (:func:`intrinsics_from_fov`)."""
    if values is None:
        return intrinsics_from_fov(width, height, fov_x_deg)
    if len(values) != 4:
        raise UserError(f"intrinsics are four numbers fx, fy, cx, cy, got {len(values)}")
    return intrinsics_from_values(width, height, *(float(v) for v in values))


def check_fov(fov_x_deg: float) -> None:
    """Refuse a horizontal field of view outside :data:`FOV_RANGE_DEG`."""
    lo, hi = FOV_RANGE_DEG
    if not lo <= fov_x_deg <= hi:
        raise UserError(f"field of view must be in [{lo:g}, {hi:g}] degrees, got {fov_x_deg}")


def check_size(height: int, width: int) -> None:
    if int(height) != height or int(width) != width or height < 8 or width < 8 or height > 8192 or width > 8192:
        raise UserError(f"image size must be between 8 and 8192 pixels per side, got {height}x{width}")


def invert_rigid(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """world_to_camera for a camera at ``eye`` looking at ``target``; ``up`` appears upwards
    in the image (i.e. along the camera's -y axis, as far as it is orthogonal to the view)."""
    eye, target, up = (np.asarray(a, dtype=np.float64) for a in (eye, target, up))
    z = target - eye
    n = np.linalg.norm(z)
    if n < 1e-9:
        raise ValueError("look_at: eye and target coincide")
    z /= n
    x = np.cross(-up, z)  # right-handed: x = y cross z, with y = -up before orthogonalising
    if np.linalg.norm(x) < 1e-6:  # looking straight along up: pick any perpendicular
        x = np.cross(z, np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world coordinates
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ eye
    return T


def project(points: np.ndarray, K: np.ndarray, world_to_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (..., 3) -> pixel coordinates (..., 2) as (u, v) and z-depth (...)."""
    pc = points @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    z = pc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uvw = pc @ K.T
        uv = uvw[..., :2] / uvw[..., 2:3]
    return uv, z


def pixel_centres(height: int, width: int) -> np.ndarray:
    """(H, W, 2) array of (u, v) = (col + 0.5, row + 0.5)."""
    v, u = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    return np.stack([u, v], axis=-1)


def pixel_rays(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Origin (3,) and unit world directions (H, W, 3) of the rays through the pixel centres."""
    uv = pixel_centres(camera.height, camera.width)
    ones = np.ones(uv.shape[:2] + (1,))
    d_cam = np.concatenate([uv, ones], axis=-1) @ np.linalg.inv(camera.K).T  # z = 1
    c2w = camera.camera_to_world
    d_world = d_cam @ c2w[:3, :3].T
    d_world /= np.linalg.norm(d_world, axis=-1, keepdims=True)
    return c2w[:3, 3].copy(), d_world


def unproject_depth(depth: np.ndarray, K: np.ndarray, world_to_camera: np.ndarray) -> np.ndarray:
    """Z-depth map (H, W) -> world points (H, W, 3) at the pixel centres."""
    h, w = depth.shape
    uv = pixel_centres(h, w)
    d_cam = np.concatenate([uv, np.ones((h, w, 1))], axis=-1) @ np.linalg.inv(K).T
    pc = d_cam * depth[..., None]
    c2w = invert_rigid(world_to_camera)
    return pc @ c2w[:3, :3].T + c2w[:3, 3]


# --- rotations (for trajectory files in TUM format) -------------------------------------------


def rotation_to_quaternion(R: np.ndarray) -> np.ndarray:
    """3x3 rotation -> unit quaternion (qx, qy, qz, qw) with qw >= 0."""
    q = Rotation.from_matrix(R).as_quat()  # x, y, z, w
    return q if q[3] >= 0 else -q


def quaternion_to_rotation(q: np.ndarray) -> np.ndarray:
    return Rotation.from_quat(np.asarray(q, dtype=np.float64)).as_matrix()
