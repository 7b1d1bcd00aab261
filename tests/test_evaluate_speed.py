"""The evaluation's faster paths give the very figures of the plain ones: a time-independent video's
revisit taken from its forward pairs, the rows and the odometry scored in threads, the C2ST of
several rows and the segmenters of several seeds trained in threads, the ceiling and the floor
shaded in threads. Each is compared for equality with the sequential path on tiny inputs."""

import json
from types import SimpleNamespace

import cv2
import numpy as np
import torch
from eval_data import labelled_real_dir

from sim2real.inference import dice as dice_mod, stages
from sim2real.inference.anchors import Anchors
from sim2real.inference.evaluate import EvalSettings
from sim2real.inference.jobs import Jobs, results
from sim2real.inference.realimages import find_real
from sim2real.inference.rows import sequence_row
from sim2real.metrics.consistency import orb_settings_for
from sim2real.metrics.twosample import c2st
from sim2real.threads import one_torch_thread

H, W, T = 64, 128, 12


def _video(seed: int, step: float = 1.0):
    """A textured plane seen by a camera sliding ``step`` px per frame to the left: frames, the 3D
    points (0.5 mm per pixel, 100 mm away), masks, the true flows (+step px in x) and poses."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.random((H, W + 40, 3)).astype(np.float32), (0, 0), 1.2)
    tex = (255 * (tex - tex.min()) / (tex.max() - tex.min())).astype(np.uint8)
    frames, points, masks, poses = [], [], [], []
    r, c = np.mgrid[0:H, 0:W].astype(np.float64)
    for t in range(T):
        x0 = int(round(20 - step * t))
        frames.append(np.ascontiguousarray(tex[:, x0:x0 + W]))
        points.append(np.stack([(c + x0) * 0.5, r * 0.5, np.full((H, W), 100.0)], -1).astype(np.float32))
        masks.append(np.ones((H, W), bool))
        pose = np.eye(4)
        pose[0, 3] = -0.5 * x0  # world x = camera x + 0.5 x0
        poses.append(pose)
    flows = [np.dstack([np.full((H, W), step, np.float32), np.zeros((H, W), np.float32)]) for _ in range(T - 1)]
    valids = [np.ones((H, W), bool) for _ in range(T - 1)]
    return frames, points, masks, flows, valids, poses


def test_time_independent_revisit_taken_from_the_forward_pairs_is_exact():
    frames, points, masks, flows, valids, _ = _video(0)
    orb = orb_settings_for(W)
    computed, _ = sequence_row(frames, points, masks, flows, valids, (1, 5, 10), 1.0, orb, None, revisit=True)
    reused, _ = sequence_row(frames, points, masks, flows, valids, (1, 5, 10), 1.0, orb, None, revisit=False)
    assert computed["revisit"]["orb"]["1"]["total"] > 0  # the pairs found matches: a real comparison
    assert reused["revisit"] == computed["revisit"]  # bit-identical, not approximately


def test_rows_and_odometry_in_threads_equal_one_thread():
    video = _video(1)
    frames, points, masks, flows, valids, poses = video
    rows = {"ceiling": frames, "model": [cv2.GaussianBlur(f, (0, 0), 0.8) for f in frames],
            "floor": _video(2)[0], "a_ref": [f // 2 for f in frames]}
    K = np.array([[100.0, 0, W / 2], [0, 100.0, H / 2], [0, 0, 1]])
    s = SimpleNamespace(threshold_mm=1.0, odometry_pairs=4)
    args = (list(rows), points, masks, flows, valids, poses, K, (1, 2, 5, 10), orb_settings_for(W), s, None)
    with Jobs(1) as one:
        a = stages.score_rows(one, rows, *args)
    with Jobs(3) as three:
        b = stages.score_rows(three, rows, *args)
    assert list(a[0]) == ["ceiling", "model", "floor", "a_ref"] == list(b[0])
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    assert a[0]["ceiling"]["of_error_vs_ceiling"] == 0.0 and a[0]["model"]["of_error_vs_ceiling"] > 0
    assert [len(a[1][r]["5"]["rotation_deg"]) for r in rows] == [4] * 4  # every row went through the odometry


def test_c2st_of_several_rows_in_threads_equals_sequential():
    rng = np.random.default_rng(0)
    real = [rng.integers(0, 255, (32, 48, 3), dtype=np.uint8) for _ in range(12)]
    sets = {k: [np.clip(f.astype(int) + 40 * k, 0, 255).astype(np.uint8) for f in real[:10]] for k in range(3)}
    state = torch.random.get_rng_state()
    seq = {k: c2st(v, real, seed=0, steps=6, crop=16) for k, v in sets.items()}
    with one_torch_thread(), Jobs(3) as jobs:
        par = {k: f.result() for k, f in {k: jobs.submit(c2st, v, real, seed=0, steps=6, crop=16)
                                           for k, v in sets.items()}.items()}
    assert par == seq
    assert torch.equal(torch.random.get_rng_state(), state)  # the caller's generator is untouched


def test_segmenters_trained_in_threads_equal_sequential(tmp_path_factory, monkeypatch):
    labelled = find_real(labelled_real_dir(tmp_path_factory.getbasetemp())).labelled
    s = EvalSettings(seg_iterations=6, seg_seeds=3, seg_check_every=3)
    weights = []
    for cores in (1, 2):
        monkeypatch.setenv("SIM2REAL_CACHE", str(tmp_path_factory.mktemp(f"cache_{cores}")))
        monkeypatch.setattr(dice_mod, "usable_cores", lambda c=cores: c)
        models, info = dice_mod.segmenters(labelled, s, "cpu", progress=False, say=lambda m: None)
        assert [m["seed"] for m in info["per_seed"]] == [0, 1, 2] and not any(m["cached"] for m in info["per_seed"])
        weights.append([{k: v.clone() for k, v in m.state_dict().items()} for m in models])
        if cores == 2:  # the cache written by the threads loads back as the same weights
            again, info2 = dice_mod.segmenters(labelled, s, "cpu", progress=False, say=lambda m: None)
            assert all(m["cached"] for m in info2["per_seed"])
            assert info2["held_out_dice"] == info["held_out_dice"]
    for a, b in zip(*weights):
        assert all(torch.equal(a[k], b[k]) for k in a)
    assert not torch.equal(weights[0][0]["head.weight"], weights[0][1]["head.weight"])  # the seeds differ


def test_anchors_shaded_in_threads_equal_sequential():
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.procedural import generate_scene
    from sim2real.scene.trajectory import make_trajectory

    scene = generate_scene(0)
    caster = RayCaster(scene)
    gbs = [caster.render(c) for c in make_trajectory(caster, 4, 32, 64, 75.0, seed=0).cameras]
    plain = Anchors(scene, seed=0, pool=2)
    seq = [plain.ceiling(g, t) for t, g in enumerate(gbs)] + [plain.floor(g, t) for t, g in enumerate(gbs)]
    threaded = Anchors(scene, seed=0, pool=2)
    with Jobs(4) as jobs:
        par = results([jobs.submit(threaded.ceiling, g, t) for t, g in enumerate(gbs)]
                      + [jobs.submit(threaded.floor, g, t) for t, g in enumerate(gbs)])
    assert all(np.array_equal(a, b) for a, b in zip(seq, par))
    assert not np.array_equal(seq[4], seq[5])  # floor frames 0 and 1: two appearances
