"""A rectified stereo pair along a trajectory, as a stereo laparoscope sees it: the right eye is
the left camera moved ``baseline_mm`` along its own x axis (same intrinsics, same orientation),
so that a surface point at z-depth z in the left view appears in the right view on the same row,
``disparity = fx * baseline_mm / z`` pixels to the left::

    stereo/
      disparity/000000.npy       float32 (H, W): the left view's disparity in pixels, 0 = no surface
      disparity_mask/000000.png  uint8: 255 = the left pixel's surface point is seen by the right eye
      stereo.json                baseline, K, the convention

The mask follows the flow masks' rule (:func:`sim2real.render.warp.correspondences`): inside
the right image and not hidden there. Each eye has its own frames, video and ground truth.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from sim2real.fileio import atomic_write_bytes, atomic_write_image, atomic_write_json
from sim2real.inference.gt_formats import npy_bytes
from sim2real.render.gbuffer import GBuffer
from sim2real.render.warp import correspondences
from sim2real.scene.camera import Camera

FORMAT = "sim2real-stereo/1"


def right_camera(left: Camera, baseline_mm: float) -> Camera:
    """The right eye of ``left``: its centre ``baseline_mm`` along the left camera's x axis."""
    w2c = np.array(left.world_to_camera, dtype=np.float64)
    w2c[0, 3] -= baseline_mm  # x_right = x_left - baseline in camera coordinates, no rotation
    return dataclasses.replace(left, world_to_camera=w2c)


def disparity(left: GBuffer, baseline_mm: float) -> np.ndarray:
    """(H, W) float32 disparity of the left view in pixels, ``fx * baseline / z``; 0 = no surface."""
    with np.errstate(divide="ignore"):
        d = left.K[0, 0] * baseline_mm / left.depth.astype(np.float64)
    return np.where(left.mask & (left.depth > 0), d, 0.0).astype(np.float32)


def write_stereo_frame(folder: Path, i: int, left: GBuffer, right: GBuffer, baseline_mm: float) -> None:
    """Frame ``i``'s disparity and its mask into ``folder`` (``stereo/``)."""
    _, seen = correspondences(left, right)
    atomic_write_bytes(folder / "disparity" / f"{i:06d}.npy", npy_bytes(disparity(left, baseline_mm)))
    atomic_write_image(folder / "disparity_mask" / f"{i:06d}.png", np.where(seen, 255, 0).astype(np.uint8))


def write_stereo_json(folder: Path, baseline_mm: float, K: np.ndarray, frames: int) -> dict:
    """``stereo.json``: the pair's calibration (frame 0's K; every frame's is in ``intrinsics.json``)."""
    entry = {
        "format": FORMAT,
        "frames": frames,
        "baseline_mm": float(baseline_mm),
        "K": np.asarray(K, dtype=np.float64).tolist(),
        "rectified": True,
        "convention": "right eye = left camera translated by baseline_mm along its x axis, same K and "
                      "orientation; a left pixel (u, v) with disparity d shows the point the right eye "
                      "sees at (u - d, v); d = fx * baseline_mm / depth_mm",
        "files": {"disparity": "disparity/%06d.npy", "disparity_mask": "disparity_mask/%06d.png"},
    }
    atomic_write_json(folder / "stereo.json", entry)
    return entry
