"""The revisit protocol (paper Sec. "Metrics"): a sequence 1..T is extended to 1, ..., T, T, ..., 1,
and each forward frame is compared with the frame that shows its view (OF) or the view k later
(ORB-k) on the way back, so a method is scored on views it sees again after a long gap. Frames,
flows, 3D points and keypoints follow the conventions of :mod:`sim2real.metrics.consistency`.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from sim2real.metrics.consistency import (
    OrbFeatures,
    OrbSettings,
    match_correctness,
    match_features,
    of_error,
    pairs_summary,
)


def view_of_extended(e: int, T: int) -> int:
    """0-based view shown at 0-based position ``e`` of the extended sequence 1..T, T..1."""
    if not 0 <= e < 2 * T:
        raise ValueError(f"extended index {e} outside [0, {2 * T})")
    return e if e < T else 2 * T - 1 - e


def revisit_pairs(T: int, k: int) -> list[tuple[int, int]]:
    """Pairs (i, j) of 0-based positions in the extended sequence compared by the revisit protocol.

    The paper extends 1..T to 1, ..., T, T, ..., 1 (1-based positions s = 1..2T; position s > T
    shows view 2T + 1 - s) and compares forward frame t with position 2T - t (ORB-1 and OF),
    2T - t - 4 (ORB-5) and 2T - t - 9 (ORB-10): in general 2T - t - (k - 1), which shows view
    t + k on the way back. In 0-based terms (i = t - 1):

        i = 0, ..., T - 1 - k   and   j = 2T - 1 - i - k,   with view_of_extended(j) = i + k.

    Returns an empty list when k >= T.
    """
    if T < 1 or k < 1:
        raise ValueError(f"need T >= 1 and k >= 1, got T={T}, k={k}")
    return [(i, 2 * T - 1 - i - k) for i in range(max(T - k, 0))]


def _per_view(seq, T: int, name: str):
    """Index function: ``seq`` given per view (length T) or per extended frame (length 2T)."""
    n = len(seq)
    if n == T:
        return lambda e: seq[view_of_extended(e, T)]
    if n == 2 * T:
        return lambda e: seq[e]
    raise ValueError(f"{name} must have length T={T} (per view) or 2T={2 * T} (per extended frame), got {n}")


def revisit_orb(frames_ext: Sequence, points: Sequence, valids: Sequence, k: int, threshold_mm: float = 1.0,
                n_features: "int | OrbSettings" = 1000) -> dict:
    """ORB-k under the revisit protocol ("OF-UNIT (revisit)").

    ``frames_ext``: the 2T translated frames of the extended sequence (forward then backward).
    ``points``/``valids``: per view (length T) or per extended frame (length 2T). Compares
    ``frames_ext[i]`` with ``frames_ext[j]`` for (i, j) in :func:`revisit_pairs` ``(T, k)``; the
    3D points are those of views i and i + k. Same summary as one entry of :func:`orb_curve`.
    """
    n = len(frames_ext)
    if n % 2 or n == 0:
        raise ValueError(f"frames_ext must have an even, positive length 2T, got {n}")
    T = n // 2
    P = _per_view(points, T, "points")
    V = _per_view(valids, T, "valids")
    feats: dict[int, OrbFeatures] = {}

    def f(e: int) -> OrbFeatures:
        if e not in feats:
            feats[e] = OrbFeatures(frames_ext[e], n_features)
        return feats[e]

    per = []
    for i, j in revisit_pairs(T, k):
        pa, pb = match_features(f(i), f(j))
        ok = match_correctness(pa, pb, P(i), P(j), V(i), V(j), threshold_mm)
        per.append((int(ok.sum()), len(ok)))
    return pairs_summary(k, per)


def revisit_of(frames_ext: Sequence, flows_gt: Sequence, valids: Sequence | None = None) -> dict:
    """OF error under the revisit protocol.

    ``frames_ext``: 2T frames; ``flows_gt[i]``: ground-truth flow from view i to view i + 1
    (T - 1 arrays), ``valids[i]`` its mask. Pair i compares ``frames_ext[i]`` (view i) with
    ``frames_ext[2T - 2 - i]`` (view i + 1 on the way back), see :func:`revisit_pairs` with k = 1.
    Returns ``{"of_error": mean over pairs, "per_pair": [...], "pairs": n}``.
    """
    n = len(frames_ext)
    if n % 2 or n == 0:
        raise ValueError(f"frames_ext must have an even, positive length 2T, got {n}")
    T = n // 2
    if len(flows_gt) != T - 1 or (valids is not None and len(valids) != T - 1):
        raise ValueError(f"need T - 1 = {T - 1} flows (and valids), got {len(flows_gt)}")
    per = [of_error(flows_gt[i], frames_ext[i], frames_ext[j], None if valids is None else valids[i])
           for i, j in revisit_pairs(T, 1)]
    vals = [e for e in per if e is not None]
    return {"of_error": float(np.mean(vals)) if vals else None, "per_pair": per, "pairs": len(vals)}
