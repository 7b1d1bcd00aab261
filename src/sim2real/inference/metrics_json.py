"""metrics.json of ``sim2real evaluate`` (docs/formats.md, "Evaluation") from the results of the
stages (:mod:`sim2real.inference.stages`): the realism table with its reference rows, the pooled
consistency and odometry figures, the calibration, the reasons a figure is missing and the
warnings, as strict JSON."""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from sim2real.inference.rows import PAPER_KS, calibration, pool_rows, positions, scalars
from sim2real.metrics.odometry import MIN_INLIERS, SUCCESS_DEG, summarise as odo_summarise


def _orb_reason(orb: dict[str, dict]) -> str | None:
    bad = []
    for k, e in orb.items():
        if e["pairs"] == 0:
            bad.append(f"ORB-{k}: no frame pair {k} apart (trajectory too short)")
        elif e["accuracy"] is None:
            bad.append(f"ORB-{k}: no ORB match in {e['pairs']} pairs (frames too smooth)")
    return "; ".join(bad) if bad else None


def assemble_metrics(*, header: dict, s, rows_shown: Sequence[str], realism: dict, seg: dict, cons: dict,
                     time_independent: bool, real_is_stand_in: bool, anchor_options: dict, seconds: dict) -> dict:
    """metrics.json (docs/formats.md, "Evaluation") from the stages' results; ``header`` holds
    ``format``, ``run`` and ``inputs`` (whose ``scenes`` the consistency stage fills)."""
    realism_rows = {r: {**realism["rows"][r]} for r in rows_shown}
    for r, v in seg["rows"].items():
        realism_rows[r]["dice"] = v
    pooled = {row: pool_rows([sc["rows"][row] for sc in cons["per_scene"].values()], cons["ks"]) for row in rows_shown}
    m_row = pooled["model"]
    orb = m_row["orb_curve"]
    of_error = m_row["of_error"]
    revisit = {"of_error": m_row["revisit"]["of_error"], "orb": m_row["revisit"]["orb"],
               "backward_frames": "reused: the method is time-independent" if time_independent
               else "translated by the method, continuing its state after frame T"}
    reasons: dict[str, str | None] = {"fid": realism["reason"], "dice": seg["reason"], "of_error": None, "orb": None,
                                      "revisit": None}
    if of_error is None:
        reasons["of_error"] = "no frame pair with visible ground-truth flow (trajectories of 1 frame, or nothing visible)"
    paper_orb = {str(k): orb[str(k)] for k in PAPER_KS}
    reasons["orb"] = _orb_reason(paper_orb)
    rv = []
    if revisit["of_error"] is None:
        rv.append("OF: no pair with visible ground-truth flow")
    if _orb_reason(revisit["orb"]):
        rv.append(_orb_reason(revisit["orb"]))
    reasons["revisit"] = "; ".join(rv) if rv else None
    table = {row: scalars(pooled[row], realism_rows[row]) for row in rows_shown}
    calib = calibration(table, real_is_stand_in) if s.anchors else {"status": "no anchors", "metrics": {}}
    pos = positions(table, calib["metrics"]) if s.anchors else {}
    warnings_ = []
    if s.anchors and of_error is not None and pooled["ceiling"]["of_error"] is not None \
            and of_error < pooled["ceiling"]["of_error"]:
        warnings_.append(f"the model's OF error ({of_error:.3g} px) is below the ceiling's "
                         f"({pooled['ceiling']['of_error']:.3g} px): Farnebäck returns near-zero flow on smooth frames, "
                         "so this OF error rewards blur here; see of_error_vs_ceiling "
                         f"({m_row['of_error_vs_ceiling']:.3g} px, ceiling 0)")
    if s.anchors and not real_is_stand_in:
        warnings_.append("the real folder is not the stand-in real domain (no sim2real-realdomain manifest): the ceiling "
                         "and the floor describe the stand-in, not your domain")
    inputs = {**header["inputs"], "scenes": cons["inputs"]}
    realism_json = realism_section(realism, seg, rows_shown)
    metrics = {
        "format": header["format"],
        "run": header["run"],
        "settings": {**dataclasses.asdict(s), "fid_weights": realism["fid_info"]["weights"],
                     "orb": cons["orb_settings"].to_json()},
        "inputs": inputs,
        **realism["fid"],
        "fid_kid": realism["fid_info"],
        "proxy": realism["proxy"],
        "realism": realism_json,
        **seg["dice"],
        "dice_info": seg["info"],
        "of_error": of_error,
        "of_epe": m_row["of_epe"],
        "orb": paper_orb,
        "orb_curve": orb,
        "revisit": revisit,
        "odometry": odometry_section(cons["per_scene"], rows_shown, s),
        "rows": table,
        "row_curves": {row: pooled[row]["orb_curve"] for row in rows_shown},
        "position": pos,
        "calibration": calib,
        "anchors": {"ceiling": "the stand-in real domain rendered on the evaluated views with one appearance",
                    "floor": f"the stand-in with a new appearance every frame (a pool of {s.orb_max_k + 1}, frame t "
                             f"takes t mod {s.orb_max_k + 1})", "a_ref": "the untranslated reference rendering",
                    "enabled": s.anchors, "render_options": anchor_options},
        "warnings": warnings_,
        "per_scene": cons["per_scene"],
        "reasons": reasons,
        "seconds": {k: round(v, 3) for k, v in seconds.items()},
    }
    return json_safe(metrics)


def odometry_section(per_scene: dict, rows_shown: Sequence[str], s) -> dict:
    """metrics.json's ``odometry``: per row and k (1, 5, 10), pooled over the scenes' paths
    (:func:`sim2real.metrics.odometry.summarise`), with the definition of a success."""
    rows = {}
    if s.odometry_pairs > 0:
        for row in rows_shown:
            rows[row] = {str(k): odo_summarise([sc["odometry"][row][str(k)] for sc in per_scene.values()])
                         for k in PAPER_KS}
    return {"success": f"a pose found with >= {MIN_INLIERS} inlier matches and a rotation error < {SUCCESS_DEG:g} deg",
            "method": "ORB (FAST threshold 2) + cross-checked matches + findEssentialMat (RANSAC) + recoverPose "
                      "with the true intrinsics; errors against the ground-truth poses",
            "pairs_per_k": s.odometry_pairs, "rows": rows,
            "reason": None if rows else "switched off in the settings (odometry_pairs 0)"}


def realism_section(realism: dict, seg: dict, rows_shown: Sequence[str]) -> dict:
    """metrics.json's ``realism``: every realism measure with its value per row (``model``,
    ``ceiling``, ``floor``, ``a_ref``, ``real_held_out``: real images not used as the reference;
    for FID, KID and the proxy, whose rows compare with all the real images, one half of them
    against the other)
    and ``better`` ("lower" or "higher"), so that a reader ranks rows without knowing the measure."""
    rows_all = list(rows_shown) + ["real_held_out"]
    out: dict[str, dict] = {}
    for name, m in realism.get("measures", {}).items():
        out[name] = {"better": m["better"], "null": m["null"], "rows": {r: m["rows"].get(r) for r in rows_all},
                     "details": m["details"], "seconds": round(m["seconds"], 3), "reason": m["reason"]}
    per_row = realism["rows"]
    fid_reason = realism["reason"]
    for name, key, better, why in (
            ("fid", "fid", "lower", fid_reason), ("kid", "kid", "lower", fid_reason),
            ("proxy", "proxy", "lower", None)):
        out[name] = {"better": better, "rows": {r: per_row.get(r, {}).get(key) for r in rows_shown},
                     "reason": why}
        # the rows compare with all the real images; the real row is one half of them against
        # the other (the C2ST's halves)
        out[name]["rows"]["real_held_out"] = realism.get("real_held_out", {}).get(key)
    out["dice"] = {"better": "higher", "rows": {r: seg["rows"].get(r) for r in rows_shown}, "reason": seg["reason"]}
    out["dice"]["rows"]["real_held_out"] = seg["dice"]["dice_real_held_out"]
    return out


def json_safe(x):
    """numpy scalars -> Python numbers, NaN/inf -> None (metrics.json is strict JSON)."""
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x
