"""Temporal consistency: OF error, ORB accuracy / ORB-k, revisit protocol."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sim2real.metrics.consistency import (
    farneback_flow,
    keypoint_pixels,
    match_correctness,
    of_error,
    of_error_sequence,
    orb_accuracy,
    orb_curve,
    orb_matches,
)
from sim2real.metrics.revisit import revisit_of, revisit_orb, revisit_pairs, view_of_extended

H, W = 128, 192
S = 0.5  # mm per pixel of the synthetic fronto-parallel plane


def _texture(h, w, sigma, seed):
    """Random RGB texture in [0, 1], blurred with a Gaussian of ``sigma`` pixels."""
    t = np.random.default_rng(seed).random((h, w, 3)).astype(np.float32)
    if sigma > 0:
        t = cv2.GaussianBlur(t, (0, 0), sigma)
    return (t - t.min()) / (t.max() - t.min())


def _plane_points(h, w, col_offset=0.0):
    """points[r, c] = ((c + col_offset) * S, r * S, 100) mm: a plane at z = 100 mm."""
    r, c = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.stack([(c + col_offset) * S, r * S, np.full((h, w), 100.0)], axis=-1)


def _view(big, v, step):
    """View v of a camera translating ``step`` px per view: content moves left by v * step."""
    return big[:, v * step: v * step + W]


# --------------------------------------------------------------------------- OF error
def test_of_error_known_shift_follows_definition():
    big = _texture(H, W + 20, 2.0, 1)
    a = big[:, 10:10 + W]
    b = big[:, 7:7 + W]  # b[:, x] = a[:, x - 3]: content moves 3 px right, flow (u, v) = (3, 0)
    valid = np.zeros((H, W), bool)
    valid[20:-20, 20:-20] = True  # away from the borders where content enters/leaves
    true_flow = np.zeros((H, W, 2))
    true_flow[..., 0] = 3.0
    assert of_error(true_flow, a, b, valid) < 0.1
    # mean over pixels and BOTH components: a 3 px error in u alone is 3 / 2, not 3 (EPE would be 3)
    assert of_error(np.zeros((H, W, 2)), a, b, valid) == pytest.approx(1.5, abs=0.1)
    wrong_v = true_flow.copy()
    wrong_v[..., 1] = -3.0
    assert of_error(wrong_v, a, b, valid) == pytest.approx(1.5, abs=0.1)
    both = np.full((H, W, 2), 0.0)
    both[..., 1] = 2.0  # |3 - 0| + |0 - 2| = 5 -> 2.5
    assert of_error(both, a, b, valid) == pytest.approx(2.5, abs=0.1)
    # the error equals the formula applied to the Farnebäck flow directly
    est = farneback_flow(a, b)
    assert of_error(both, a, b, valid) == pytest.approx(np.abs(both[valid] - est[valid]).mean(), rel=1e-9)


def test_of_error_ignores_invalid_pixels_and_nan_flow():
    big = _texture(H, W + 20, 2.0, 2)
    a, b = big[:, 10:10 + W], big[:, 7:7 + W]
    valid = np.zeros((H, W), bool)
    valid[20:-20, 20:-20] = True
    flow = np.zeros((H, W, 2))
    flow[..., 0] = 3.0
    garbage = flow.copy()
    garbage[~valid] = 1000.0
    assert of_error(garbage, a, b, valid) == pytest.approx(of_error(flow, a, b, valid))
    nan_flow = flow.copy()
    nan_flow[~valid] = np.nan
    assert of_error(nan_flow, a, b) == pytest.approx(of_error(flow, a, b, valid))  # default: finite flow
    assert of_error(flow, a, b, np.zeros((H, W), bool)) is None
    u8a = np.rint(a * 255).astype(np.uint8)
    u8b = np.rint(b * 255).astype(np.uint8)
    assert of_error(flow, u8a, u8b, valid) == pytest.approx(of_error(flow, a, b, valid))
    with pytest.raises(ValueError):
        of_error(flow[:-1], a, b)
    with pytest.raises(ValueError):
        of_error(flow, a * 2 - 1, b)


def test_of_error_sequence_averages_pairs():
    big = _texture(H, W + 40, 2.0, 3)
    frames = [_view(big, v, 2) for v in range(4)]  # content moves 2 px left per frame
    flows = [np.dstack([np.full((H, W), -2.0), np.zeros((H, W))]) for _ in range(3)]
    valids = [np.pad(np.ones((H - 40, W - 40), bool), 20) for _ in range(3)]
    res = of_error_sequence(frames, flows, valids)
    assert res["pairs"] == 3 and res["of_error"] < 0.1
    assert res["of_error"] == pytest.approx(np.mean(res["per_pair"]))
    with pytest.raises(ValueError):
        of_error_sequence(frames, flows[:2])


# --------------------------------------------------------------------------- ORB
def test_keypoint_pixel_convention():
    # OpenCV puts pixel centres at integer coordinates: pixel c covers [c - 0.5, c + 0.5)
    pts = np.array([[2.0, 3.0], [2.49, 3.5], [2.5, 3.49], [-0.4, 0.0], [10.7, 8.6]])
    rows, cols = keypoint_pixels(pts, (9, 11))
    assert cols.tolist() == [2, 2, 3, 0, 10]
    assert rows.tolist() == [3, 4, 3, 0, 8]


def test_match_correctness_hand_cases():
    pts_a = _plane_points(4, 5)
    pts_b = _plane_points(4, 5)
    pts_b[1, 1, 2] += 0.9  # 0.9 mm away: still correct
    pts_b[2, 2, 2] += 1.0  # exactly 1 mm: not < 1 mm
    va = np.ones((4, 5), bool)
    vb = va.copy()
    vb[3, 4] = False  # background
    ka = np.array([[0, 0], [1, 1], [2, 2], [4, 3], [1, 0]], float)  # (x, y)
    kb = np.array([[0, 0], [1, 1], [2, 2], [4, 3], [3, 0]], float)  # last: 2 px * 0.5 mm = 1 mm off
    ok = match_correctness(ka, kb, pts_a, pts_b, va, vb, threshold_mm=1.0)
    assert ok.tolist() == [True, True, False, False, False]
    assert match_correctness(ka[-1:], kb[-1:], pts_a, pts_b, va, vb, threshold_mm=1.01).tolist() == [True]


def test_orb_identical_frames_are_all_correct():
    frame = _texture(H, W, 1.0, 4)
    pts = _plane_points(H, W)
    valid = np.ones((H, W), bool)
    res = orb_accuracy(frame, frame, pts, pts, valid, valid)
    assert res["total"] > 200
    assert res["accuracy"] > 0.95 and res["correct"] <= res["total"]


def test_orb_shift_correct_only_if_geometry_moves_with_the_image():
    big = _texture(H, W + 20, 1.0, 5)
    a = big[:, 10:10 + W]
    b = big[:, 5:5 + W]  # content moves 5 px right
    va = np.ones((H, W), bool)
    pa = _plane_points(H, W)
    pb = _plane_points(H, W, col_offset=-5.0)  # the surface moved with the image: pb[r, c] = pa[r, c - 5]
    moving = orb_accuracy(a, b, pa, pb, va, va)
    assert moving["total"] > 200 and moving["accuracy"] > 0.85
    # same matches, but the geometry claims nothing moved: every match is 5 px * 0.5 mm = 2.5 mm off
    static = orb_accuracy(a, b, pa, pa, va, va)
    assert static["total"] == moving["total"] and static["accuracy"] < 0.05
    # matches landing on background never count
    nothing_valid = orb_accuracy(a, b, pa, pb, np.zeros((H, W), bool), va)
    assert nothing_valid["correct"] == 0 and nothing_valid["total"] == moving["total"]


def test_orb_smooth_frame_gives_zero_matches_without_crashing():
    smooth = np.full((H, W, 3), 0.5, np.float32)
    textured = _texture(H, W, 1.0, 6)
    pa, pb = orb_matches(smooth, textured)
    assert pa.shape == (0, 2) and pb.shape == (0, 2)
    pts = _plane_points(H, W)
    v = np.ones((H, W), bool)
    assert orb_accuracy(smooth, smooth, pts, pts, v, v) == {"correct": 0, "total": 0, "accuracy": None}
    curve = orb_curve([smooth, smooth], [pts, pts], [v, v], ks=(1,))
    assert curve[1]["total"] == 0 and curve[1]["accuracy"] is None and curve[1]["mean_correct"] == 0


def _sequence(T, step, seed):
    big = _texture(H, W + step * T, 1.0, seed)
    frames = [_view(big, v, step) for v in range(T)]
    points = [_plane_points(H, W, col_offset=v * step) for v in range(T)]  # world-fixed plane
    valids = [np.ones((H, W), bool) for _ in range(T)]
    return frames, points, valids


def test_orb_curve_pools_pairs_per_k():
    T = 5
    frames, points, valids = _sequence(T, 2, 7)
    curve = orb_curve(frames, points, valids, ks=(1, 3, 5))
    assert set(curve) == {1, 3, 5}
    assert curve[1]["pairs"] == 4 and curve[3]["pairs"] == 2 and curve[5]["pairs"] == 0
    assert curve[5]["accuracy"] is None
    for k in (1, 3):
        pair_results = [orb_accuracy(frames[t], frames[t + k], points[t], points[t + k], valids[t], valids[t + k])
                        for t in range(T - k)]
        correct = sum(r["correct"] for r in pair_results)
        total = sum(r["total"] for r in pair_results)
        assert curve[k]["correct"] == correct and curve[k]["total"] == total
        assert curve[k]["accuracy"] == pytest.approx(correct / total)
        assert curve[k]["mean_correct"] == pytest.approx(correct / (T - k))
        assert curve[k]["accuracy"] > 0.85


# --------------------------------------------------------------------------- revisit protocol
def test_revisit_pairs_follow_the_paper_indices():
    # T = 4, extended (1-based views): 1 2 3 4 4 3 2 1. Paper: frame t vs position 2T - t (ORB-1).
    assert revisit_pairs(4, 1) == [(0, 6), (1, 5), (2, 4)]
    # ORB-5 with T = 7: frame t vs position 2T - t - 4; t = 1 -> position 9 (0-based 8), t = 2 -> 7
    assert revisit_pairs(7, 5) == [(0, 8), (1, 7)]
    # ORB-10 with T = 12: 2T - t - 9; t = 1 -> 14 (0-based 13), t = 2 -> 12 (0-based 11)
    assert revisit_pairs(12, 10) == [(0, 13), (1, 12)]
    assert revisit_pairs(3, 3) == []
    for T in (1, 2, 5, 13):
        ext_views = list(range(1, T + 1)) + list(range(T, 0, -1))  # the paper's 1..T, T..1
        for k in (1, 5, 10):
            pairs = revisit_pairs(T, k)
            assert len(pairs) == max(T - k, 0)
            for i, j in pairs:
                assert i < T <= j < 2 * T  # forward-pass frame vs backward-pass frame
                assert ext_views[i] == i + 1  # view t = i + 1
                assert ext_views[j] == ext_views[i] + k  # the backward occurrence of view t + k
                assert view_of_extended(j, T) == i + k
                # 1-based: position j + 1 == 2T - t - (k - 1)
                assert j + 1 == 2 * T - (i + 1) - (k - 1)


def test_revisit_orb_time_independent_equals_forward_metric_and_detects_drift():
    T, k = 6, 2
    frames, points, valids = _sequence(T, 3, 8)
    ext = [frames[view_of_extended(e, T)] for e in range(2 * T)]
    forward = orb_curve(frames, points, valids, ks=(k,))[k]
    revisit = revisit_orb(ext, points, valids, k)
    for key in ("correct", "total", "pairs", "accuracy", "mean_correct"):
        assert revisit[key] == forward[key]
    assert revisit["accuracy"] > 0.85
    # points given per extended frame give the same answer
    ext_points = [points[view_of_extended(e, T)] for e in range(2 * T)]
    ext_valids = [valids[view_of_extended(e, T)] for e in range(2 * T)]
    assert revisit_orb(ext, ext_points, ext_valids, k) == revisit
    # a method whose details drift over time: the backward pass renders the same views with
    # other texture details -> revisit matches are (almost) never on the same 3D point
    other, _, _ = _sequence(T, 3, 9)
    drift = ext[:T] + [other[view_of_extended(e, T)] for e in range(T, 2 * T)]
    res = revisit_orb(drift, points, valids, k)
    assert res["total"] > 0 and res["accuracy"] < 0.2
    with pytest.raises(ValueError):
        revisit_orb(ext[:-1], points, valids, k)
    with pytest.raises(ValueError):
        revisit_orb(ext, points[:-1], valids, k)


def test_revisit_of_equals_forward_of_when_time_independent():
    T = 4
    frames, _, _ = _sequence(T, 2, 10)
    flows = [np.dstack([np.full((H, W), -2.0), np.zeros((H, W))]) for _ in range(T - 1)]
    valids = [np.pad(np.ones((H - 40, W - 40), bool), 20) for _ in range(T - 1)]
    ext = [frames[view_of_extended(e, T)] for e in range(2 * T)]
    rev = revisit_of(ext, flows, valids)
    fwd = of_error_sequence(frames, flows, valids)
    assert rev["per_pair"] == pytest.approx(fwd["per_pair"])
    assert rev["of_error"] < 0.1
