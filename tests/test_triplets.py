"""Training triplets of the video methods: linear camera paths, real sequences, the sample."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from PIL import Image

from sim2real.config import DataConfig
from sim2real.data.real import RealImages, RealSequences
from sim2real.errors import UserError


def test_linear_path_translates_the_camera_by_equal_steps(procedural_caster):
    from sim2real.scene.trajectory import linear_path

    cams = linear_path(procedural_caster, 4, 64, 128, 75.0, 0.8, np.random.default_rng(3))
    eyes = np.array([c.position for c in cams])
    steps = np.diff(eyes, axis=0)
    np.testing.assert_allclose(np.linalg.norm(steps, axis=1), 0.8, rtol=1e-9)
    np.testing.assert_allclose(steps, steps[:1].repeat(3, 0), atol=1e-9)  # one direction
    for c in cams[1:]:  # the view pans without turning
        np.testing.assert_allclose(c.world_to_camera[:3, :3], cams[0].world_to_camera[:3, :3], atol=1e-9)
    assert procedural_caster.free_space(eyes).all()


def _sequence_folder(root, name, frames, h=16, w=64):
    d = root / "sequences" / name / "images"
    d.mkdir(parents=True)
    ramp = np.tile(np.arange(w, dtype=np.uint8)[None, :, None], (h, 1, 3))
    for k in range(frames):
        Image.fromarray(ramp + np.uint8(10 * k)).save(d / f"{k:04d}.png")


def test_real_sequences_give_consecutive_frames_with_one_crop(tmp_path):
    with pytest.raises(UserError, match="no sequences of 3 or more frames"):
        RealSequences(tmp_path)
    _sequence_folder(tmp_path, "short", 2)  # too short for a triplet: ignored
    with pytest.raises(UserError, match="sequences/NAME/images"):
        RealSequences(tmp_path)
    _sequence_folder(tmp_path, "long", 6)
    seq = RealSequences(tmp_path)
    assert len(seq.sequences) == 1
    rng = np.random.default_rng(0)
    lefts = set()
    for _ in range(20):
        # 16x64 frames into 16x32 crops at scale 1: no resize, a random window of 33 lefts
        f = seq.sample(rng, 16, 32, 1.0, 1.0)
        u8 = [np.round((x + 1) * 127.5).astype(int) for x in f]
        # frame t+1 = frame t + 10 everywhere: consecutive frames, one crop window for all three
        for t in (1, 2):
            assert (u8[t] - u8[t - 1] == 10).all()
        row = u8[0][0, 0, :]  # channel 0, row 0
        assert (np.diff(row) == 1).all()  # a window of the ramp, not resized
        lefts.add(int(row[0]))  # = window left + 10 * start frame
    assert len(lefts) > 3  # random windows and start frames


def test_a_triplet_sample(procedural_scene, tmp_path):
    from torch.utils.data import default_collate

    from sim2real.data.datasets import SceneSource, make_dataset
    from sim2real.data.tensors import complete_on_device, widen

    _sequence_folder(tmp_path / "real", "a", 5, h=80, w=160)
    scene_dir = tmp_path / "scene"
    procedural_scene.save(scene_dir)
    src = SceneSource(procedural_scene.name, scene_dir, procedural_scene.classes, procedural_scene.bounds())
    ds = make_dataset("triplets", [src], RealImages(tmp_path / "real"), DataConfig(height=64, width=128, path_step_mm=1.0),
                      seed=0)
    # in transit a_ref is left to the device: widen and render it as the trainer does
    s = {k: v[0] for k, v in complete_on_device(widen(default_collate([ds[7]]))).items()}
    for t in range(3):
        assert s[f"a_ref_{t}"].shape == (3, 64, 128) and s[f"real_{t}"].shape == (3, 64, 128)
    for key in ("uv_10", "uv_21"):
        assert s[key].shape == (64, 128, 2)
    # uv_10 is where frame 1's pixels lie in frame 0: frame 0's surface point there is frame 1's point
    vis = s["visible_10"].numpy()
    assert vis.mean() > 0.5
    uv = s["uv_10"].numpy()[vis]
    col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    p0 = s["points_0"].numpy()[row, col]
    p1 = s["points_1"].numpy()[vis]
    assert np.median(np.linalg.norm(p0 - p1, axis=1)) < 0.5  # mm: within a pixel's footprint
    # the camera moved: frame 0 and frame 1 differ
    assert not np.array_equal(s["points_0"].numpy(), s["points_1"].numpy())
    # the same step gives the same sample (step-indexed data)
    first, again = ds[7], ds[7]
    assert first.keys() == again.keys() and all(torch.equal(again[k], first[k]) for k in first)
