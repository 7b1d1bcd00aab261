"""Metric rows of an evaluation: the model, the ceiling, the floor and a_ref, each scored with the
same temporal metrics on the same frames' geometry, and the model's position between floor and
ceiling.

**Position** of a metric: ``(model - floor) / (ceiling - floor)``, so 0 = floor and 1 = ceiling
whatever the metric's direction. It is ``None`` where the ceiling and the floor do not differ by
at least :data:`MIN_GAP` of the larger of the two (such a metric cannot tell them apart on this
path, so a position would be noise). ``position_a_ref`` is the same with a_ref, the untranslated
input, in place of the floor: the meaningful scale for the per-frame realism metrics, which do not
see flicker.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from sim2real.metrics.consistency import (
    PAPER_ORB_KS as PAPER_KS,
    farneback_flow,
    flow_errors,
    orb_curve,
)
from sim2real.metrics.revisit import revisit_of, revisit_orb

ROWS = ("model", "ceiling", "floor", "a_ref")
MIN_GAP = 0.05
CALIBRATION_MARGIN = 0.25
"""A temporal metric (ORB-k, OF, revisit) is calibrated on a path when the ceiling beats the
floor and a_ref by at least this share of the ceiling's value; the per-frame measures keep the
:data:`MIN_GAP` rule of :func:`position`."""
ABOVE = "above the stand-in's level"

HIGHER = "higher"
LOWER = "lower"


def direction(metric: str) -> str | None:
    """Which way a metric of :func:`scalars` is better, or None (``detail``: closest to 1)."""
    if metric in ("dice",) or metric.endswith("_accuracy") or metric.endswith("_correct"):
        return HIGHER
    if metric.startswith("of_") or metric.startswith("revisit_of") or metric in ("proxy", "fid", "kid", "c2st",
                                                                                  "random_kid"):
        return LOWER
    return None


def temporal(metric: str) -> bool:
    return metric.startswith(("orb_", "of_", "revisit_"))


def sequence_row(frames: Sequence[np.ndarray], points, masks, flows, valids, ks, threshold_mm: float, orb,
                 ceiling_flow_est: Sequence[np.ndarray] | None, revisit: bool = True,
                 backward: Sequence[np.ndarray] | None = None) -> tuple[dict, list[np.ndarray]]:
    """Temporal metrics of one video along one path; also returns its Farnebäck flows.

    OF error (paper) and EPE against the ground-truth flow; both also against the ceiling
    video's Farnebäck flow (``*_vs_ceiling``: a blurry video whose Farnebäck flow is near zero
    cannot beat a perfect one there); the ORB-k curve; the revisit protocol on the extended
    sequence ``frames + backward``, where ``backward`` holds the frames of views T..1 as the
    method translated them after the forward half, continuing its state. A time-independent video
    may leave ``backward`` out: its backward half is then the forward frames reversed. With
    ``revisit=False`` (time-independent videos only) the revisit figures are taken from the
    forward ones, which for such a video compare the very same frame pairs (pair (t, 2T-1-t-k) of
    the extended sequence shows frames t and t+k): the anchors' rows skip computing them twice.
    """
    T = len(frames)
    est = [farneback_flow(frames[t], frames[t + 1]) for t in range(T - 1)]
    per = {"of_error": [], "of_epe": [], "of_error_vs_ceiling": [], "of_epe_vs_ceiling": []}
    for t in range(T - 1):
        e, epe = flow_errors(flows[t], est[t], valids[t])
        per["of_error"].append(e)
        per["of_epe"].append(epe)
        if ceiling_flow_est is not None:
            e, epe = flow_errors(ceiling_flow_est[t], est[t], valids[t])
            per["of_error_vs_ceiling"].append(e)
            per["of_epe_vs_ceiling"].append(epe)
    curve = orb_curve(frames, points, masks, ks=ks, threshold_mm=threshold_mm, n_features=orb)
    if backward is not None and len(backward) != T:
        raise ValueError(f"the backward half must have the T = {T} frames of views T..1, got {len(backward)}")
    if revisit or backward is not None:
        ext = list(frames) + (list(backward) if backward is not None else list(frames)[::-1])
        rev_of = revisit_of(ext, flows, valids)
        rev_orb = {str(k): revisit_orb(ext, points, masks, k, threshold_mm, orb) for k in PAPER_KS}
    else:
        rev_of = {"of_error": _mean(per["of_error"]), "per_pair": list(per["of_error"])}
        rev_orb = {str(k): curve[k] for k in PAPER_KS}
    row = {"frames": T, **{k: _mean(v) for k, v in per.items()}, "per_pair": per,
           "orb_curve": {str(k): curve[k] for k in ks},
           "revisit": {"of_error": rev_of["of_error"], "of_error_per_pair": rev_of["per_pair"], "orb": rev_orb}}
    return row, est


def _mean(v):
    v = [x for x in v if x is not None]
    return float(np.mean(v)) if v else None


def pool_orb(entries: Sequence[dict], k: int) -> dict:
    """Pool ORB-k summaries of several sequences: matches summed over all their pairs."""
    correct = sum(e["correct"] for e in entries)
    total = sum(e["total"] for e in entries)
    pairs = sum(e["pairs"] for e in entries)
    return {"k": int(k), "accuracy": correct / total if total else None, "mean_correct": correct / pairs if pairs else None,
            "correct": int(correct), "total": int(total), "pairs": int(pairs),
            "mean_matches": total / pairs if pairs else None}


def pool_rows(per_scene: Sequence[dict], ks) -> dict:
    """One row's sequence metrics pooled over scenes (ORB: matches summed; OF: mean over pairs)."""
    out = {k: _mean([e for r in per_scene for e in r["per_pair"][k]])
           for k in ("of_error", "of_epe", "of_error_vs_ceiling", "of_epe_vs_ceiling")}
    out["orb_curve"] = {str(k): pool_orb([r["orb_curve"][str(k)] for r in per_scene], k) for k in ks}
    out["revisit"] = {"of_error": _mean([e for r in per_scene for e in r["revisit"]["of_error_per_pair"]]),
                      "orb": {str(k): pool_orb([r["revisit"]["orb"][str(k)] for r in per_scene], k) for k in PAPER_KS}}
    return out


def scalars(seq: dict | None, realism: dict | None) -> dict:
    """The flat metric -> value map of one row (the numbers the table and the positions use)."""
    out: dict = {}
    if realism:
        out.update(realism)
    if seq:
        for k in ("of_error", "of_epe", "of_error_vs_ceiling", "of_epe_vs_ceiling"):
            out[k] = seq[k]
        for k in PAPER_KS:
            e = seq["orb_curve"][str(k)]
            out[f"orb_{k}_accuracy"], out[f"orb_{k}_correct"] = e["accuracy"], e["mean_correct"]
            r = seq["revisit"]["orb"][str(k)]
            out[f"revisit_orb_{k}_accuracy"], out[f"revisit_orb_{k}_correct"] = r["accuracy"], r["mean_correct"]
        out["revisit_of_error"] = seq["revisit"]["of_error"]
    return out


def position(model, ceiling, low, low_name: str = "floor", min_gap: float = MIN_GAP) -> tuple[float | None, str | None]:
    """``(model - low) / (ceiling - low)`` and None, or None and why (see the module docstring)."""
    if model is None or ceiling is None or low is None:
        return None, "a value is missing"
    gap = ceiling - low
    if abs(gap) < min_gap * max(abs(ceiling), abs(low)) or gap == 0:
        return None, f"ceiling {ceiling:.4g} and {low_name} {low:.4g} differ by less than {min_gap:.0%}"
    return float((model - low) / gap), None


def positions(rows: dict[str, dict], calibrated: dict | None = None) -> dict:
    """{metric: {"position", "position_a_ref", "reason"}} for every metric of the model row.

    A position above 1 (the model beyond the ceiling) is withheld with the reason :data:`ABOVE`:
    the ceiling is the stand-in's level, not an upper bound of what a video can score. With
    ``calibrated`` (:func:`calibration`'s ``metrics``), an uncalibrated metric's positions are
    withheld too."""
    out = {}
    for name, v in rows["model"].items():
        p, why = position(v, rows["ceiling"].get(name), rows["floor"].get(name), "floor")
        pa, why_a = position(v, rows["ceiling"].get(name), rows["a_ref"].get(name), "a_ref")
        if calibrated is not None and name in calibrated and not calibrated[name]["calibrated"]:
            why = why_a = f"uncalibrated: {calibrated[name]['reason']}"
            p = pa = None
        if p is not None and p > 1 + 1e-9:
            p, why = None, ABOVE
        if pa is not None and pa > 1 + 1e-9:
            pa, why_a = None, ABOVE
        out[name] = {"position": p, "position_a_ref": pa, "reason": why, "reason_a_ref": why_a}
    return out


def calibrated_metric(metric: str, rows: dict[str, dict],
                      margin: float = CALIBRATION_MARGIN) -> tuple[bool, str | None]:
    """(True, None) when the ceiling clears the rows it must beat by ``margin`` of its value on
    this metric (module docstring of :data:`CALIBRATION_MARGIN`), else (False, why)."""
    d = direction(metric)
    c = rows["ceiling"].get(metric)
    if d is None or not temporal(metric):  # per-frame measures: the 5 % rule of position() only
        return True, None
    if c is None:
        return False, "the ceiling has no value"
    for low in ("floor", "a_ref"):
        v = rows.get(low, {}).get(metric)
        if v is None:
            continue
        gap = (c - v) if d == HIGHER else (v - c)
        if gap < margin * abs(c):
            return False, (f"the ceiling ({c:.4g}) does not clear {low} ({v:.4g}) by {margin:.0%} of its value")
    return True, None


def calibration(rows: dict[str, dict], stand_in: bool, margin: float = CALIBRATION_MARGIN) -> dict:
    """Whether this path's ceiling can calibrate each metric.

    ``status``: "no ceiling" when the real images are not the stand-in domain (the ceiling and
    floor rows then describe the stand-in, and only a_ref, the floor and the realism measures
    speak for the user's domain); else "uncalibrated" when any ORB-1/5/10 count or the OF error
    is uncalibrated (:func:`calibrated_metric`), else "calibrated". ``metrics``: per metric."""
    metrics = {}
    for name in rows["model"]:
        ok, why = (calibrated_metric(name, rows, margin) if stand_in
                   else (False, "no ceiling exists for this real domain"))
        metrics[name] = {"calibrated": ok, "reason": why}
    key = [f"orb_{k}_correct" for k in PAPER_KS] + ["of_error"]
    bad = [k for k in key if k in metrics and not metrics[k]["calibrated"]]
    status = "no ceiling" if not stand_in else ("uncalibrated" if bad else "calibrated")
    return {"status": status, "margin": margin, "uncalibrated": bad if stand_in else [], "metrics": metrics}
