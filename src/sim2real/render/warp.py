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


def correspondences(gi: GBuffer, gj: GBuffer, eps: float = OCCLUSION_EPS_MM) -> tuple[np.ndarray, np.ndarray]:
    """Positions in view j of view i's pixels, (H_i, W_i, 2) as (u, v) pixel coordinates
    (centre of pixel (c, r) at (c + .5, r + .5)), and a boolean mask of the pixels of i that are
    visible in j. Positions are only meaningful where the mask is True."""
    uv, z = project(gi.points.astype(np.float64), gj.K, gj.world_to_camera)
    uv = np.nan_to_num(uv, nan=-1.0, posinf=-1.0, neginf=-1.0)
    col = np.floor(uv[..., 0]).astype(np.int64)
    row = np.floor(uv[..., 1]).astype(np.int64)
    inside = gi.mask & (z > 1e-6) & (col >= 0) & (col < gj.width) & (row >= 0) & (row < gj.height)
    depth_j = np.zeros(gi.depth.shape, np.float64)
    depth_j[inside] = gj.depth[row[inside], col[inside]]
    ray = gi.points.astype(np.float64) - Camera(gj.K, gj.world_to_camera, gj.height, gj.width).position
    ray /= np.maximum(np.linalg.norm(ray, axis=-1, keepdims=True), 1e-12)
    cos = np.clip(np.abs((ray * gi.normal).sum(-1)), 1e-6, 1.0)
    slope = np.minimum(np.sqrt(1.0 - cos**2) / cos, MAX_SLOPE)
    tol = eps + z / min(gj.K[0, 0], gj.K[1, 1]) * slope
    visible = inside & (depth_j > 0) & ~(z > depth_j + tol)
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
