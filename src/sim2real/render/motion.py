"""How fast a camera path moves, measured on the path itself: ground-truth flow per frame,
rotation per frame and the share of a frame still in view k frames later.

Definitions (for a sequence of G-buffers g_0..g_{T-1} of width W):

* **flow per frame** of pair (t, t+1): the median over the pixels of t visible in t+1
  (:func:`sim2real.render.warp.correspondences`) of the ground-truth flow's length
  ``||flow||_2`` in pixels; also as a fraction of W. A pair with no such pixel counts as W
  (the view left the scene entirely).
* **rotation per frame**: the angle of ``R_{t+1} R_t^T`` in degrees.
* **overlap k**: the mean over pairs (t, t+k) of the share of t's surface pixels that are
  visible in t+k. The paper's ORB-10 compares frames 2 s apart; the overlap at k = 10 says how
  much of a frame there is still to match.

The path statistic that trajectories are budgeted on is the median over pairs of the flow per
frame (as a fraction of W) and the maximum over pairs of the rotation per frame.
"""

from __future__ import annotations

from collections import deque
from typing import Iterable, Sequence

import numpy as np

from sim2real.metrics.consistency import PAPER_ORB_KS as OVERLAP_KS  # overlaps at the ORB-k offsets
from sim2real.render.gbuffer import GBuffer
from sim2real.render.warp import correspondences
from sim2real.scene.camera import pixel_centres


def pair_flow_px(gi: GBuffer, gj: GBuffer) -> tuple[float, float]:
    """(median ground-truth flow length in pixels over the pixels of i visible in j, share of i's
    surface pixels visible in j). The flow is ``width`` when nothing of i is visible in j."""
    uv, vis = correspondences(gi, gj)
    surf = int(gi.mask.sum())
    if not vis.any():
        return float(gi.width), 0.0
    d = uv[vis] - pixel_centres(gi.height, gi.width)[vis]
    return float(np.median(np.linalg.norm(d, axis=-1))), float(vis.sum()) / max(surf, 1)


def rotation_deg(world_to_camera_a: np.ndarray, world_to_camera_b: np.ndarray) -> float:
    """Angle of the relative rotation between two camera orientations, degrees."""
    R = world_to_camera_b[:3, :3] @ world_to_camera_a[:3, :3].T
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(c)))


class MotionMeter:
    """Streams G-buffers of a sequence and accumulates :func:`summary` figures (keeps only the
    last ``max(ks)`` G-buffers)."""

    def __init__(self, ks: Sequence[int] = OVERLAP_KS):
        self.ks = tuple(sorted({1, *(int(k) for k in ks)}))  # k = 1 gives the flow per frame
        self.window: deque[GBuffer] = deque(maxlen=max(self.ks))
        self.flow_px: list[float] = []
        self.deg: list[float] = []
        self.overlaps: dict[int, list[float]] = {k: [] for k in self.ks}
        self.width = None

    def add(self, g: GBuffer) -> None:
        self.width = g.width
        n = len(self.window)
        for k in self.ks:
            if k <= n:
                fl, ov = pair_flow_px(self.window[n - k], g)
                self.overlaps[k].append(ov)
                if k == 1:
                    self.flow_px.append(fl)
                    self.deg.append(rotation_deg(self.window[-1].world_to_camera, g.world_to_camera))
        self.window.append(g)

    def summary(self) -> dict:
        W = self.width or 1
        fl = np.asarray(self.flow_px, dtype=np.float64)
        return {
            "width": self.width,
            "pairs": len(fl),
            "flow_px_per_frame_median": float(np.median(fl)) if len(fl) else None,
            "flow_frac_per_frame_median": float(np.median(fl) / W) if len(fl) else None,
            "flow_frac_per_frame_max": float(fl.max() / W) if len(fl) else None,
            "deg_per_frame_max": float(max(self.deg)) if self.deg else None,
            "overlap": {str(k): (float(np.mean(v)) if v else None) for k, v in self.overlaps.items()},
            "flow_px_per_frame": [round(x, 3) for x in fl.tolist()],
        }


def measure(gbuffers: Iterable[GBuffer], ks: Sequence[int] = OVERLAP_KS) -> dict:
    """Motion summary of a sequence of G-buffers (see the module docstring):
    ``flow_px_per_frame`` (per pair), its median in px and as a fraction of the width, its
    maximum fraction, ``deg_per_frame_max`` and ``overlap`` {k: mean share}."""
    m = MotionMeter(ks)
    for g in gbuffers:
        m.add(g)
    return m.summary()
