"""Long-range point tracks: where surface points of the video are in every frame and whether
they are seen there, the ground truth of "tracking any point" (TAP-Vid's task) and of
long-term correspondence, beyond the flow's one frame::

    tracks/
      tracks.npz   tracks (N, T, 2), visible (N, T), query_frame (N,), points_mm (N, 3),
                   labels (N,), size (2,)
      README.txt

Query points are ray-cast surface points on a ``GRID_STEP`` pixel grid of every frame, thinned
alike over all frames to at most ``TRACKS_BUDGET`` (:class:`PointSampler`). The scene is rigid,
so a point's world position is fixed: its track is its exact projection into each frame, and it
is visible where :func:`sim2real.render.warp.visible_from` says so, the rule of the flow masks
(in front of the camera, inside the image, not behind the frame's depth buffer beyond a
slope-scaled tolerance). Positions are given in every frame, also where the point is hidden or
outside the image (NaN only where it is behind the camera). The cost is 9 bytes per point and
frame: 1.8 MB for 2,048 points over 100 frames.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from sim2real.fileio import atomic_write_bytes, atomic_write_text
from sim2real.inference.surface_points import PointSampler
from sim2real.render.warp import visible_from

GRID_STEP = 16
"""Pixel step of the grid each frame's query points are taken from before thinning."""
TRACKS_BUDGET = 2048
"""Most query points kept; a long video's frames are thinned evenly to stay under it."""


def tracks_sampler() -> PointSampler:
    """The sampler of the query points; each frame adds its ``points`` (H, W, 3), ``normal``
    (H, W, 3) and ``labels`` (H, W)."""
    return PointSampler(TRACKS_BUDGET, GRID_STEP)


def point_tracks(Ks: Sequence[np.ndarray], world_to_camera: Sequence[np.ndarray],
                 depth_of: Callable[[int], np.ndarray], queries: PointSampler) -> dict[str, np.ndarray]:
    """The tracks of ``queries`` through the frames with intrinsics ``Ks``, poses ``world_to_camera``
    and z-depth buffers ``depth_of(j)`` (mm, 0 = no surface), as the arrays of ``tracks.npz``."""
    n = len(Ks)
    kept = [(i, f) for i in range(n) for rows, _, f in [queries.frame(i)] if len(rows)]

    def joined(name: str, empty: np.ndarray) -> np.ndarray:
        return np.concatenate([f[name] for _, f in kept] or [empty])

    query_frame = np.concatenate([np.full(len(f["points"]), i, np.int32) for i, f in kept] or [np.zeros(0, np.int32)])
    points = joined("points", np.zeros((0, 3))).astype(np.float64)
    normals = joined("normal", np.zeros((0, 3))).astype(np.float64)
    labels = joined("labels", np.zeros(0, np.uint8)).astype(np.uint8)
    tracks = np.full((len(points), n, 2), np.nan, np.float32)
    visible = np.zeros((len(points), n), bool)
    valid = np.ones(len(points), bool)
    for j in range(n):
        uv, z, seen = visible_from(points, normals, valid, Ks[j], world_to_camera[j], depth_of(j))
        tracks[:, j] = np.where((z > 1e-6)[:, None], uv, np.nan)
        visible[:, j] = seen
    return {"tracks": tracks, "visible": visible, "query_frame": query_frame,
            "points_mm": points.astype(np.float32), "labels": labels}


def write_tracks(folder: Path, arrays: dict[str, np.ndarray], width: int, height: int) -> None:
    """``folder`` (``tracks/``): ``tracks.npz`` with ``arrays`` (:func:`point_tracks`) and the
    image size, and its README."""
    buf = io.BytesIO()
    np.savez(buf, **arrays, size=np.array([width, height], np.int32))
    atomic_write_bytes(folder / "tracks.npz", buf.getvalue())
    n, t = arrays["visible"].shape
    seen = arrays["visible"].sum(1)
    atomic_write_text(folder / "README.txt", "\n".join([
        "Point tracks exported by sim2real: exact, from the scene's geometry",
        "",
        f"{n} surface points over {t} frames of {width}x{height} pixels"
        + (f"; each point is seen in {np.median(seen):g} frames (median)" if n else ""),
        "tracks.npz (numpy.load):",
        "  tracks (N, T, 2) float32   (x, y) pixel position of point n in frame t, the centre of the",
        "                             top-left pixel at (0.5, 0.5); given where hidden or outside the",
        "                             image too, NaN where the point is behind the camera",
        "  visible (N, T) bool        the frame sees the point (inside, in front, not occluded)",
        "  query_frame (N,) int32     the frame the point was sampled from (visible there)",
        "  points_mm (N, 3) float32   its world position, millimetres",
        "  labels (N,) uint8          its class label id, as in ../labels/",
        "  size (2,) int32            width, height",
        "",
        "As TAP-Vid's points and occlusions (x, y scaled to [0, 1] by the image size):",
        "  points = tracks / size;  occluded = ~visible",
    ]) + "\n")
