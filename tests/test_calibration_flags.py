"""Honest calibration: a count beyond the stand-in's ceiling is not a fraction of it, a path whose
ceiling does not clear the floor and a_ref is uncalibrated, and a real domain has no ceiling."""

import pytest

from sim2real.inference.report import _calibration_blocks
from sim2real.inference.rows import ABOVE, calibration, positions


def rows(model, ceiling, floor, a_ref, of=(0.4, 0.4, 1.3, 0.6)):
    """ORB-10 correct matches per pair and OF error of the four rows (a constructed path)."""
    return {r: {"orb_10_correct": v, "of_error": o, "dice": 0.9}
            for r, v, o in zip(("model", "ceiling", "floor", "a_ref"), (model, ceiling, floor, a_ref), of)}


def test_path_whose_ceiling_does_not_clear_a_ref_is_uncalibrated():
    # the 60-frame path of the demo scene: ceiling 0.98, floor 0.66, a_ref 4.52, model 9.18
    t = rows(9.18, 0.98, 0.66, 4.52)
    cal = calibration(t, stand_in=True)
    assert cal["status"] == "uncalibrated" and cal["uncalibrated"] == ["orb_10_correct"]
    assert "a_ref (4.52)" in cal["metrics"]["orb_10_correct"]["reason"]
    # OF: ceiling 0.4 vs floor 1.3 and a_ref 0.6: gaps 0.9 and 0.2 >= 25 % of 0.4
    assert cal["metrics"]["of_error"]["calibrated"]
    pos = positions(t, cal["metrics"])
    assert pos["orb_10_correct"]["position"] is None and pos["orb_10_correct"]["position_a_ref"] is None
    assert pos["orb_10_correct"]["reason"].startswith("uncalibrated")
    blocks = _calibration_blocks({"rows": t, "position": pos, "calibration": cal, "per_scene": {}})
    assert "Uncalibrated path" in str(blocks)
    table = next(b for b in blocks if b[0] == "table")
    orb10 = next(r for r in table[2] if r[0].startswith("ORB-10 correct"))
    assert orb10[5] == "uncalibrated" and orb10[6] == "uncalibrated"


def test_above_the_ceiling_is_not_a_fraction():
    # ceiling 2.28 clears floor 0.20 and a_ref 0.20; the model finds 8x the ceiling's count
    t = rows(18.3, 2.28, 0.20, 0.20)
    cal = calibration(t, stand_in=True)
    assert cal["status"] == "calibrated"
    p = positions(t, cal["metrics"])["orb_10_correct"]
    assert p["position"] is None and p["reason"] == ABOVE
    below = positions(rows(1.24, 2.28, 0.20, 0.20), cal["metrics"])["orb_10_correct"]
    assert below["position"] == pytest.approx((1.24 - 0.20) / (2.28 - 0.20))
    blocks = _calibration_blocks({"rows": t, "position": positions(t, cal["metrics"]), "calibration": cal,
                                  "per_scene": {}})
    table = next(b for b in blocks if b[0] == "table")
    orb10 = next(r for r in table[2] if r[0].startswith("ORB-10 correct"))
    assert orb10[5] == "above the stand-in's level"


def test_real_domain_has_no_ceiling():
    t = rows(1.0, 2.28, 0.20, 0.20)
    cal = calibration(t, stand_in=False)
    assert cal["status"] == "no ceiling" and not any(m["calibrated"] for m in cal["metrics"].values())
    pos = positions(t, cal["metrics"])
    assert all(p["position"] is None for p in pos.values())
    text = str(_calibration_blocks({"rows": t, "position": pos, "calibration": cal, "per_scene": {}}))
    assert "No ceiling exists for this real domain" in text and "'no ceiling'" in text
