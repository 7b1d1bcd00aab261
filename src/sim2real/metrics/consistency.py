"""Temporal-consistency metrics (paper Sec. "Metrics"): OF error and ORB-k accuracy (the revisit
protocol: :mod:`sim2real.metrics.revisit`).

Conventions
-----------
Frames
    numpy arrays (H, W, 3) RGB or (H, W) grey, ``uint8`` in [0, 255] or float in [0, 1]
    (torch tensors with the same layout are accepted and copied to the CPU). Both OpenCV methods
    run on 8-bit grey images (``cv2.COLOR_RGB2GRAY``; floats are scaled by 255 and rounded).
Optical flow
    (H, W, 2) float, forward from frame a to frame b: the surface point seen at pixel
    (col, row) of a is seen at (col + flow[row, col, 0], row + flow[row, col, 1]) in b, so
    ``[..., 0]`` is the horizontal (u, column) and ``[..., 1]`` the vertical (v, row)
    displacement in pixels. This is the convention of ``cv2.calcOpticalFlowFarneback(a, b)``.
    Displacements do not depend on where a pixel's centre is put.
3D points
    (H, W, 3) world-space surface point per pixel in mm (the G-buffer's ``points``), with a
    (H, W) bool ``valid`` mask (the G-buffer's ``mask``; background = False).
Keypoints
    OpenCV keypoint coordinates ``pt = (x, y)`` put pixel centres at integers (pixel (col, row)
    covers [col - 0.5, col + 0.5) in x). The project convention puts the centre at
    (col + 0.5, row + 0.5), i.e. ``u = x + 0.5``; both give the pixel index
    ``col = floor(x + 0.5)``, ``row = floor(y + 0.5)`` (clipped to the image).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Iterable, Sequence

import cv2
import numpy as np

#: Gunnar-Farnebäck parameters (OpenCV's documented example values; the paper gives none).
FARNEBACK_PARAMS = dict(pyr_scale=0.5, levels=3, winsize=15, iterations=3, poly_n=5, poly_sigma=1.2, flags=0)

#: ORB-k offsets reported by the paper (1 and 5/10 frames = 1/2 s apart).
PAPER_ORB_KS = (1, 5, 10)


@dataclass(frozen=True)
class OrbSettings:
    """Parameters of ``cv2.ORB_create``; the defaults are OpenCV's (the paper's ORB at 256x512)."""

    n_features: int = 1000
    patch_size: int = 31
    edge_threshold: int = 31
    n_levels: int = 8
    scale_factor: float = 1.2
    fast_threshold: int = 20

    def create(self):
        return cv2.ORB_create(nfeatures=int(self.n_features), scaleFactor=float(self.scale_factor),
                              nlevels=int(self.n_levels), edgeThreshold=int(self.edge_threshold),
                              patchSize=int(self.patch_size), fastThreshold=int(self.fast_threshold))

    def to_json(self) -> dict:
        return asdict(self)


PAPER_ORB_WIDTH = 512
"""Image width at which :func:`orb_settings_for` gives the paper's (OpenCV's default) ORB."""


def orb_settings_for(width: int, n_features: int = 1000) -> OrbSettings:
    """ORB settings for frames ``width`` pixels wide.

    At :data:`PAPER_ORB_WIDTH` and above: OpenCV's defaults with ``n_features`` (the paper's ORB,
    so figures there compare with its Table 1). Narrower frames shrink the 31-px patch and border
    to ``round(31 (width / 512)^0.2)`` px (27 at 256 px): the default patch leaves little image at
    128x256, and a patch scaled with the width (15 px) finds more matches but loses accuracy at
    ORB-10. Measured on the ceiling of the default test path at 128x256 (docs/evaluation.md,
    "ORB at the training size"): patch 31 / 27 / 23 / 19 gave ORB-10 73 / 66 / 63 / 62 %
    accuracy with 24 / 23 / 25 / 30 correct matches per pair on demo scene 0, and
    94 / 92 / 91 / 88 % with 17 / 24 / 33 / 41 on scene 1.
    """
    if width >= PAPER_ORB_WIDTH:
        return OrbSettings(n_features=int(n_features))
    patch = max(11, int(round(31 * (width / PAPER_ORB_WIDTH) ** 0.2)))
    return OrbSettings(n_features=int(n_features), patch_size=patch, edge_threshold=patch)


# --------------------------------------------------------------------------- input handling
def _to_numpy(x) -> np.ndarray:
    if hasattr(x, "detach") and hasattr(x, "cpu"):  # torch tensor, without importing torch
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def to_grey_u8(frame) -> np.ndarray:
    """(H, W[, 3]) RGB/grey, uint8 or float in [0, 1] -> (H, W) uint8 grey (contiguous)."""
    f = _to_numpy(frame)
    if f.ndim == 3 and f.shape[2] == 1:
        f = f[..., 0]
    if not (f.ndim == 2 or (f.ndim == 3 and f.shape[2] == 3)):
        raise ValueError(f"frame must be (H, W) or (H, W, 3), got shape {f.shape}")
    if f.dtype == np.uint8:
        u8 = f
    elif np.issubdtype(f.dtype, np.floating):
        if f.size and (np.nanmin(f) < -1e-3 or np.nanmax(f) > 1 + 1e-3):
            raise ValueError("float frames must lie in [0, 1]")
        u8 = np.clip(np.rint(f * 255.0), 0, 255).astype(np.uint8)
    else:
        raise TypeError(f"frame must be uint8 or float, got {f.dtype}")
    if u8.ndim == 3:
        u8 = cv2.cvtColor(np.ascontiguousarray(u8), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(u8)


def _check_points(points, valid, shape: tuple[int, int], name: str) -> tuple[np.ndarray, np.ndarray]:
    p = _to_numpy(points)
    v = _to_numpy(valid)
    if p.shape != shape + (3,):
        raise ValueError(f"points_{name} must be (H, W, 3) = {shape + (3,)}, got {p.shape}")
    if v.shape != shape:
        raise ValueError(f"valid_{name} must be (H, W) = {shape}, got {v.shape}")
    return p, v.astype(bool)


# --------------------------------------------------------------------------- optical flow
def farneback_flow(frame_a, frame_b) -> np.ndarray:
    """Gunnar-Farnebäck flow a -> b, (H, W, 2) float32, with :data:`FARNEBACK_PARAMS`."""
    a, b = to_grey_u8(frame_a), to_grey_u8(frame_b)
    if a.shape != b.shape:
        raise ValueError(f"frames differ in shape: {a.shape} vs {b.shape}")
    return cv2.calcOpticalFlowFarneback(a, b, None, **FARNEBACK_PARAMS)


def of_error(flow_gt, frame_a, frame_b, valid=None) -> float | None:
    r"""Optical-flow error of a frame pair (paper: :math:`mean(|OF(a^{ref}_t, a^{ref}_{t+1}) - OF_{GF}(\hat b_t, \hat b_{t+1})|)`).

    With :math:`F` the ground-truth flow, :math:`\hat F` the Farnebäck flow of the (translated)
    frames (:func:`farneback_flow`) and :math:`V` the valid pixels,

    .. math::
        \mathrm{OF} = \frac{1}{2|V|} \sum_{p \in V} \bigl(|F_u(p) - \hat F_u(p)| + |F_v(p) - \hat F_v(p)|\bigr)

    i.e. the mean absolute difference over valid pixels *and* both flow components, in pixels
    (not the end-point error). ``valid`` (H, W) bool marks pixels whose ground-truth flow is
    defined (surface visible in both frames); by default, pixels whose flow is finite. Returns
    ``None`` when no pixel is valid.
    """
    gt = _to_numpy(flow_gt).astype(np.float64)
    a = to_grey_u8(frame_a)
    if gt.shape != a.shape + (2,):
        raise ValueError(f"flow_gt must be (H, W, 2) = {a.shape + (2,)}, got {gt.shape}")
    if valid is None:
        v = np.isfinite(gt).all(axis=-1)
    else:
        v = _to_numpy(valid).astype(bool)
        if v.shape != a.shape:
            raise ValueError(f"valid must be (H, W) = {a.shape}, got {v.shape}")
        v = v & np.isfinite(gt).all(axis=-1)
    if not v.any():
        return None
    est = farneback_flow(a, frame_b).astype(np.float64)
    return float(np.abs(gt[v] - est[v]).mean())


def flow_errors(flow_ref, flow_est, valid=None) -> tuple[float, float] | tuple[None, None]:
    r"""Mean absolute component difference and mean end-point error between two flows.

    With :math:`F` the reference flow (ground truth, or the ceiling video's Farnebäck flow),
    :math:`\hat F` the estimate and :math:`V` the valid pixels (default: where both are finite),

    .. math::
        \mathrm{OF} = \frac{1}{2|V|} \sum_{p \in V} \bigl(|F_u - \hat F_u| + |F_v - \hat F_v|\bigr), \qquad
        \mathrm{EPE} = \frac{1}{|V|} \sum_{p \in V} \lVert F(p) - \hat F(p) \rVert_2

    (the first is the paper's OF error when :math:`F` is the ground truth). ``(None, None)``
    when no pixel is valid.
    """
    a = _to_numpy(flow_ref).astype(np.float64)
    b = _to_numpy(flow_est).astype(np.float64)
    if a.shape != b.shape or a.ndim != 3 or a.shape[-1] != 2:
        raise ValueError(f"flows must both be (H, W, 2), got {a.shape} and {b.shape}")
    v = np.isfinite(a).all(-1) & np.isfinite(b).all(-1)
    if valid is not None:
        v &= _to_numpy(valid).astype(bool)
    if not v.any():
        return None, None
    d = a[v] - b[v]
    return float(np.abs(d).mean()), float(np.linalg.norm(d, axis=-1).mean())


def of_error_sequence(frames: Sequence, flows_gt: Sequence, valids: Sequence | None = None) -> dict:
    """:func:`of_error` over consecutive pairs (t, t+1); ``flows_gt[t]`` is the flow t -> t+1.

    Returns ``{"of_error": mean over pairs with a value (None if none), "per_pair": [...], "pairs": n}``;
    every pair weighs the same.
    """
    T = len(frames)
    if len(flows_gt) != T - 1:
        raise ValueError(f"need len(flows_gt) == len(frames) - 1 = {T - 1}, got {len(flows_gt)}")
    if valids is not None and len(valids) != T - 1:
        raise ValueError(f"need len(valids) == len(frames) - 1 = {T - 1}, got {len(valids)}")
    per = [of_error(flows_gt[t], frames[t], frames[t + 1], None if valids is None else valids[t])
           for t in range(T - 1)]
    vals = [e for e in per if e is not None]
    return {"of_error": float(np.mean(vals)) if vals else None, "per_pair": per, "pairs": len(vals)}


# --------------------------------------------------------------------------- ORB
class OrbFeatures:
    """Keypoints (M, 2) float64 in OpenCV coordinates and descriptors (or None) of one frame."""

    __slots__ = ("pts", "des", "shape")

    def __init__(self, frame, n_features: int | OrbSettings) -> None:
        grey = to_grey_u8(frame)
        self.shape = grey.shape
        orb = (n_features if isinstance(n_features, OrbSettings) else OrbSettings(n_features=int(n_features))).create()
        kps, des = orb.detectAndCompute(grey, None)
        self.pts = np.array([kp.pt for kp in kps], dtype=np.float64).reshape(-1, 2)
        self.des = des if des is not None and len(des) else None


def match_features(fa: OrbFeatures, fb: OrbFeatures) -> tuple[np.ndarray, np.ndarray]:
    """Cross-checked brute-force Hamming matches of two frames' features -> (pts_a, pts_b), each
    (M, 2) in OpenCV keypoint coordinates (M = 0 when either frame has no descriptors)."""
    if fa.des is None or fb.des is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    matches = matcher.match(fa.des, fb.des)
    if not matches:
        return np.zeros((0, 2)), np.zeros((0, 2))
    ia = np.array([m.queryIdx for m in matches])
    ib = np.array([m.trainIdx for m in matches])
    return fa.pts[ia], fb.pts[ib]


def orb_matches(frame_a, frame_b, n_features: "int | OrbSettings" = 1000) -> tuple[np.ndarray, np.ndarray]:
    """Cross-checked ORB matches between two frames.

    ORB (``cv2.ORB_create(nfeatures=n_features)``, other parameters OpenCV's defaults; or the
    parameters of an :class:`OrbSettings` passed as ``n_features``, as in every ORB function
    here) on the 8-bit grey frames, brute-force Hamming matching with cross-check (a match is kept only if
    each descriptor is the other's nearest neighbour). Returns ``(pts_a, pts_b)``, each (M, 2)
    float64 ``(x, y)`` in OpenCV keypoint coordinates (pixel centres at integers). A frame
    without descriptors (e.g. a smooth image) gives M = 0.
    """
    return match_features(OrbFeatures(frame_a, n_features), OrbFeatures(frame_b, n_features))


def keypoint_pixels(pts: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV keypoint coordinates (M, 2) -> (rows, cols) int arrays: ``floor(pt + 0.5)``, clipped."""
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    cols = np.clip(np.floor(pts[:, 0] + 0.5).astype(np.int64), 0, shape[1] - 1)
    rows = np.clip(np.floor(pts[:, 1] + 0.5).astype(np.int64), 0, shape[0] - 1)
    return rows, cols


def match_correctness(pts_a, pts_b, points_a, points_b, valid_a, valid_b, threshold_mm: float = 1.0) -> np.ndarray:
    """(M,) bool: is each match (pts_a[i] <-> pts_b[i]) on the same 3D location?

    Correct iff both keypoints' pixels (:func:`keypoint_pixels`) are valid and
    ``|| points_a[pixel_a] - points_b[pixel_b] ||_2 < threshold_mm``. A keypoint on background
    (invalid) makes the match incorrect.
    """
    shape = _to_numpy(valid_a).shape
    pa, va = _check_points(points_a, valid_a, shape, "a")
    pb, vb = _check_points(points_b, valid_b, shape, "b")
    ra, ca = keypoint_pixels(pts_a, shape)
    rb, cb = keypoint_pixels(pts_b, shape)
    ok = va[ra, ca] & vb[rb, cb]
    dist = np.linalg.norm(pa[ra, ca].astype(np.float64) - pb[rb, cb].astype(np.float64), axis=-1)
    return ok & (dist < threshold_mm)


def _summary(correct: int, total: int) -> dict:
    return {"correct": int(correct), "total": int(total),
            "accuracy": (correct / total) if total > 0 else None}


def orb_accuracy(frame_a, frame_b, points_a, points_b, valid_a, valid_b, threshold_mm: float = 1.0,
                 n_features: "int | OrbSettings" = 1000) -> dict:
    """ORB match accuracy of one frame pair: ``{"correct", "total", "accuracy"}``.

    ``total`` = number of cross-checked ORB matches (:func:`orb_matches`), ``correct`` = those
    whose two 3D points are < ``threshold_mm`` apart (:func:`match_correctness`, paper: 1 mm),
    ``accuracy`` = correct / total, or ``None`` when there is no match.
    """
    pts_a, pts_b = orb_matches(frame_a, frame_b, n_features)
    ok = match_correctness(pts_a, pts_b, points_a, points_b, valid_a, valid_b, threshold_mm)
    return _summary(int(ok.sum()), len(ok))


def pairs_summary(k: int, per_pair: list[tuple[int, int]]) -> dict:
    correct = sum(c for c, _ in per_pair)
    total = sum(t for _, t in per_pair)
    n = len(per_pair)
    out = _summary(correct, total)
    out.update(k=int(k), pairs=n, mean_correct=(correct / n) if n else None,
               mean_matches=(total / n) if n else None)
    return out


def _seq_len_check(frames, points, valids) -> int:
    T = len(frames)
    if len(points) != T or len(valids) != T:
        raise ValueError(f"frames, points and valids need the same length (got {T}, {len(points)}, {len(valids)})")
    return T


def orb_curve(frames: Sequence, points: Sequence, valids: Sequence, ks: Iterable[int] = range(1, 21),
              threshold_mm: float = 1.0, n_features: "int | OrbSettings" = 1000) -> dict[int, dict]:
    """ORB-k for each k in ``ks`` over all pairs (t, t+k), t = 0..T-1-k.

    ``frames``: T frames; ``points``: T arrays (H, W, 3) mm; ``valids``: T masks (H, W).
    For each k: ``accuracy`` = sum of correct / sum of matches over the pairs (pooled, so pairs
    with many matches weigh more; None if no match at all), ``mean_correct`` = mean number of
    correct matches per pair (the paper's "average number of correct matches per image pair"),
    plus ``correct``, ``total``, ``pairs``, ``mean_matches``. A k >= T has 0 pairs and None values.
    ORB-1/5/10 of the paper are ``ks = (1, 5, 10)``. Returns ``{k: {...}}``.
    """
    T = _seq_len_check(frames, points, valids)
    ks = [int(k) for k in ks]
    if any(k < 1 for k in ks):
        raise ValueError(f"ks must be >= 1, got {ks}")
    feats = [OrbFeatures(f, n_features) for f in frames]
    out = {}
    for k in ks:
        per = []
        for t in range(T - k):
            pa, pb = match_features(feats[t], feats[t + k])
            ok = match_correctness(pa, pb, points[t], points[t + k], valids[t], valids[t + k], threshold_mm)
            per.append((int(ok.sum()), len(ok)))
        out[k] = pairs_summary(k, per)
    return out
