r"""Downstream odometry: how well a two-view visual odometry recovers the camera's motion from a
video, the use the method is for (realistic video with ground truth to evaluate SLAM on).

For frame pairs ``(t, t + k)``: ORB features (the evaluation's ORB settings, as for ORB-k),
cross-checked Hamming matches, OpenCV's ``findEssentialMat`` (RANSAC, 0.999 confidence, 1 px
threshold) with the scene's true intrinsics ``K``, then ``recoverPose``. Its rotation
:math:`\hat R` and unit translation :math:`\hat t` (the scale is not observable from two views)
are compared with the ground truth :math:`R, t` from the poses, ``X_b = R X_a + t`` for
world-to-camera poses :math:`W_a, W_b` (OpenCV convention): :math:`[R\,|\,t] = W_b W_a^{-1}`.

* rotation error :math:`e_R = \arccos\bigl((\operatorname{tr}(\hat R^\top R) - 1) / 2\bigr)` in degrees;
* translation direction error :math:`e_t = \arccos(\hat t \cdot t / \lVert t \rVert)` in degrees
  (pairs whose camera did not move, :math:`\lVert t \rVert <` 1e-6 mm, have none);
* a pair is a **success** when a pose was found with at least :data:`MIN_INLIERS` inlier matches
  and :math:`e_R <` :data:`SUCCESS_DEG`. A pair where no pose was found counts as a failure and,
  for the medians, as the worst error (180°), so a row that mostly fails has a large median.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import cv2
import numpy as np

from sim2real.metrics.consistency import OrbFeatures, OrbSettings, match_features

SUCCESS_DEG = 5.0
MIN_INLIERS = 15
WORST_DEG = 180.0
FAST_THRESHOLD = 2
"""FAST threshold of the odometry's ORB (the ORB-k metric keeps OpenCV's 20): on the stand-in's
ceiling of a demo-scene path at 128x256, thresholds 20 and 7 (ORB-SLAM's fallback) found 3 and
18 keypoints per frame, too few for an essential matrix; 2 found about 470, and the ceiling's
pairs 1 frame apart then succeeded at 80 % with a median rotation error of 0.5 degrees."""


def odometry_orb(settings: OrbSettings) -> OrbSettings:
    """The odometry's ORB: ``settings`` with the FAST threshold :data:`FAST_THRESHOLD`."""
    return replace(settings, fast_threshold=FAST_THRESHOLD)


def ground_truth_motion(w2c_a: np.ndarray, w2c_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) with ``X_b = R X_a + t`` from two world-to-camera 4x4 poses."""
    T = np.asarray(w2c_b, np.float64) @ np.linalg.inv(np.asarray(w2c_a, np.float64))
    return T[:3, :3], T[:3, 3]


def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> float:
    c = (np.trace(R_est.T @ R_gt) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def direction_error_deg(t_est: np.ndarray, t_gt: np.ndarray) -> float | None:
    n = np.linalg.norm(t_gt)
    if n < 1e-6:
        return None
    e = np.asarray(t_est, np.float64).ravel()
    c = float(e @ t_gt) / (np.linalg.norm(e) * n + 1e-300)
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def relative_pose(fa: OrbFeatures, fb: OrbFeatures, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, int] | None:
    """(R, t, inliers) from two frames' ORB features, or None when no pose is found. Keypoints
    are moved by +0.5 px into the project's pixel convention (centres at col + 0.5, as ``K``)."""
    pa, pb = match_features(fa, fb)
    if len(pa) < 5:
        return None
    pa, pb = pa + 0.5, pb + 0.5
    try:
        E, mask = cv2.findEssentialMat(pa, pb, K, method=cv2.RANSAC, prob=0.999, threshold=1.0)
        if E is None or E.shape != (3, 3):  # several stacked solutions (degenerate): no single pose
            return None
        inl, R, t, _ = cv2.recoverPose(E, pa, pb, K, mask=mask)
    except cv2.error:  # degenerate matches (e.g. all on a line): the five-point solver's polynomial vanishes
        return None
    return R, t.ravel(), int(inl)


def pair_starts(n_frames: int, k: int, max_pairs: int | None) -> list[int]:
    """Start frames of the pairs ``(t, t + k)``: all of them, or ``max_pairs`` evenly spaced."""
    n = max(0, n_frames - k)
    if max_pairs is None or n <= max_pairs:
        return list(range(n))
    return sorted({int(round(x)) for x in np.linspace(0, n - 1, max_pairs)})


def odometry(frames: Sequence[np.ndarray], world_to_camera: Sequence[np.ndarray], K: np.ndarray,
             ks: Sequence[int] = (1, 5, 10), orb: OrbSettings | int = 1000, max_pairs: int | None = None) -> dict:
    """Two-view odometry of a video along known poses (module docstring), per k: the per-pair
    figures ``{"k", "rotation_deg", "translation_deg", "inliers", "success"}`` (see
    :func:`summarise` for the summary). ``max_pairs`` limits the pairs per k (evenly spaced)."""
    if len(frames) != len(world_to_camera):
        raise ValueError(f"{len(frames)} frames but {len(world_to_camera)} poses")
    K = np.asarray(K, np.float64)
    feats: dict[int, OrbFeatures] = {}

    def feat(t: int) -> OrbFeatures:
        if t not in feats:
            feats[t] = OrbFeatures(frames[t], orb)
        return feats[t]

    out = {}
    for k in ks:
        rec = {"k": int(k), "rotation_deg": [], "translation_deg": [], "inliers": [], "success": []}
        for t in pair_starts(len(frames), k, max_pairs):
            R_gt, t_gt = ground_truth_motion(world_to_camera[t], world_to_camera[t + k])
            est = relative_pose(feat(t), feat(t + k), K)
            if est is None:
                rec["rotation_deg"].append(WORST_DEG)
                rec["translation_deg"].append(WORST_DEG if np.linalg.norm(t_gt) >= 1e-6 else None)
                rec["inliers"].append(0)
                rec["success"].append(False)
                continue
            R, tt, n_in = est
            e_r = rotation_error_deg(R, R_gt)
            rec["rotation_deg"].append(e_r)
            rec["translation_deg"].append(direction_error_deg(tt, t_gt))
            rec["inliers"].append(n_in)
            rec["success"].append(bool(n_in >= MIN_INLIERS and e_r < SUCCESS_DEG))
        out[str(k)] = rec
    return out


def summarise(records: Sequence[dict]) -> dict:
    """One k's per-pair records (of one or several videos) pooled: ``{"k", "pairs", "successes",
    "success_rate", "median_rotation_error_deg", "median_translation_error_deg",
    "median_inliers"}`` (rates and medians None without pairs)."""
    rot = [v for r in records for v in r["rotation_deg"]]
    trans = [v for r in records for v in r["translation_deg"] if v is not None]
    inl = [v for r in records for v in r["inliers"]]
    ok = sum(v for r in records for v in r["success"])
    n = len(rot)
    return {"k": records[0]["k"] if records else None, "pairs": n, "successes": int(ok),
            "success_rate": ok / n if n else None,
            "median_rotation_error_deg": float(np.median(rot)) if n else None,
            "median_translation_error_deg": float(np.median(trans)) if trans else None,
            "median_inliers": float(np.median(inl)) if n else None}
