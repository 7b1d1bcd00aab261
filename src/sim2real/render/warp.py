"""Ground-truth correspondences between two views: optical flow, visibility, backward warping.

For every pixel of view i we take its surface point s (G-buffer ``points``), project it into
view j and keep it when it lands inside j, lies in front of j's camera, and is not occluded:

    occluded  <=>  z_j(s) > depth_j[pixel of s in j] + tol,
    tol = eps + (z_j(s) / f_j) * min(tan(theta), tan(85 deg)),     eps = 1 mm

(the authors' release had this comparison reversed and so kept hidden points). The depth
buffer of j is read at the pixel that contains the projection (no interpolation across
silhouettes), up to a pixel away from where s lands. Across one pixel the depth of a surface
seen by j at angle theta from its normal changes by about (z / f) tan(theta), which at grazing
angles is several millimetres: a fixed tolerance then marks visible surface as occluded in
bands (measured: 38 % of a plane seen at 79 degrees). Hence the slope-scaled term, as a
shadow map's slope-scaled depth bias.

Warping an image of view j into view i samples it bilinearly at those positions: the paper's
backward warp w_i(b_j), which leaves no splatting holes.
"""

from __future__ import annotations

import cv2
import numpy as np

from sim2real.render.gbuffer import GBuffer
from sim2real.scene.camera import Camera, pixel_centres, project

OCCLUSION_EPS_MM = 1.0
MAX_SLOPE = float(np.tan(np.radians(85.0)))


def visible_from(points: np.ndarray, normals: np.ndarray, valid: np.ndarray, K: np.ndarray,
                 world_to_camera: np.ndarray, depth: np.ndarray,
                 eps: float = OCCLUSION_EPS_MM) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where surface points (..., 3), with unit normals (..., 3), land in a view with intrinsics
    ``K``, pose ``world_to_camera`` and z-depth buffer ``depth`` (H, W; 0 = no surface), and
    whether the view sees them (the rule above; points where ``valid`` is False are not seen).
    Returns (u, v) pixel positions (..., 2) in float64 (NaN where the projection is undefined),
    the points' z-depth in the view (...), and the visibility mask (...)."""
    height, width = depth.shape
    points = np.asarray(points, dtype=np.float64)
    uv, z = project(points, K, world_to_camera)
    finite = np.nan_to_num(uv, nan=-1.0, posinf=-1.0, neginf=-1.0)
    col = np.floor(finite[..., 0]).astype(np.int64)
    row = np.floor(finite[..., 1]).astype(np.int64)
    inside = valid & (z > 1e-6) & (col >= 0) & (col < width) & (row >= 0) & (row < height)
    depth_here = np.zeros(z.shape, np.float64)
    depth_here[inside] = depth[row[inside], col[inside]]
    ray = points - Camera(K, world_to_camera, height, width).position
    ray /= np.maximum(np.linalg.norm(ray, axis=-1, keepdims=True), 1e-12)
    cos = np.clip(np.abs((ray * normals).sum(-1)), 1e-6, 1.0)
    slope = np.minimum(np.sqrt(1.0 - cos**2) / cos, MAX_SLOPE)
    tol = eps + z / min(K[0, 0], K[1, 1]) * slope
    visible = inside & (depth_here > 0) & ~(z > depth_here + tol)
    return uv, z, visible


def correspondences(gi: GBuffer, gj: GBuffer, eps: float = OCCLUSION_EPS_MM) -> tuple[np.ndarray, np.ndarray]:
    """Positions in view j of view i's pixels, (H_i, W_i, 2) as (u, v) pixel coordinates
    (centre of pixel (c, r) at (c + .5, r + .5)), and a boolean mask of the pixels of i that are
    visible in j. Positions are only meaningful where the mask is True."""
    uv, _, visible = visible_from(gi.points, gi.normal, gi.mask, gj.K, gj.world_to_camera, gj.depth, eps)
    uv = np.nan_to_num(uv, nan=-1.0, posinf=-1.0, neginf=-1.0)
    return uv.astype(np.float32), visible


def flow(gi: GBuffer, gj: GBuffer, eps: float = OCCLUSION_EPS_MM) -> tuple[np.ndarray, np.ndarray]:
    """Optical flow i -> j (H, W, 2) in pixels as (du, dv), 0 where not visible, and the mask."""
    uv, visible = correspondences(gi, gj, eps)
    f = uv - pixel_centres(gi.height, gi.width).astype(np.float32)
    f[~visible] = 0.0
    return f, visible


def warp_image(image_j: np.ndarray, uv: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """w_i(image_j): bilinear samples of ``image_j`` (H_j, W_j[, C]) at ``uv`` (view i's grid);
    zero where not visible. Uses OpenCV's remap, whose integer coordinates are pixel centres."""
    maps = (uv - 0.5).astype(np.float32)
    src = np.ascontiguousarray(image_j.astype(np.float32))
    out = cv2.remap(src, maps[..., 0], maps[..., 1], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out[~visible] = 0
    return out
