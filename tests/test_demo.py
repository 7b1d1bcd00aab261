"""``sim2real demo`` end to end on the tiny preset: every stage leaves what the README promises,
and the ground truth belongs to the frames of the video."""

import json

import numpy as np
import pytest

from sim2real.cli.main import main
from sim2real.engine import checkpoint as ckpt
from sim2real.inference.gt_dataset import GroundTruthDataset
from sim2real.inference.video import read_video
from sim2real.render.raycast import RayCaster
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory

FRAMES = 6


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "out"
    code = main(["demo", "--out", str(out), "--train", "--minutes", "0.05", "--preset", "tiny", "--scenes", "1",
                 "--real-images", "8", "--frames", str(FRAMES), "--eval-views", "4", "--seg-iterations", "5"])
    return code, out


def test_demo_writes_video_ground_truth_and_report(demo):
    code, out = demo
    assert code == 0
    info = json.loads((out / "demo.json").read_text())
    steps = info["training_steps"]
    assert steps >= 1
    assert ckpt.load_checkpoint(out / "run" / "checkpoints" / ckpt.LAST)["step"] == steps

    traj = Trajectory.load(out / "trajectory.txt")
    h, w = traj.cameras[0].height, traj.cameras[0].width
    assert (h, w) == (64, 128)  # the tiny preset's training size
    assert read_video(out / info["video"]) == (FRAMES, h, w)

    gt = out / info["ground_truth"]
    assert sorted(p.name for p in (gt / "depth_npy").iterdir()) == [f"{i:06d}.npy" for i in range(FRAMES)]
    assert len(list((gt / "flow").glob("*.flo"))) == FRAMES - 1  # forward flow t -> t+1
    # depth of the last frame equals a fresh ray cast of the trajectory's last camera
    caster = RayCaster(Scene.load(out / "scenes" / "sim_0"))
    expected = caster.render(traj.cameras[-1]).depth
    np.testing.assert_allclose(np.load(gt / "depth_npy" / f"{FRAMES - 1:06d}.npy"), expected, atol=1e-3)
    # the README's dataset line: the video folder read back, the last sample that same depth
    data = GroundTruthDataset(out / info["video"].rsplit("/", 1)[0], fields=["image", "depth"])
    last = data[FRAMES - 1]
    assert len(data) == FRAMES and last["image"].shape == (3, h, w)
    np.testing.assert_allclose(last["depth"][0].numpy(), expected, atol=1e-3)

    metrics = json.loads((out / info["metrics"]).read_text())
    assert metrics["run"]["step"] == steps
    for key in ("fid", "kid_mean", "kid_std", "proxy", "dice", "dice_a_ref", "of_error", "orb", "orb_curve",
                "revisit", "per_scene", "reasons", "settings", "inputs"):
        assert key in metrics, key
    assert set(metrics["orb"]) == {"1", "5", "10"} and set(metrics["revisit"]["orb"]) == {"1", "5", "10"}
    assert all({"accuracy", "mean_correct", "pairs"} <= set(v) for v in metrics["orb"].values())
    # the curve k = 1..20; a sequence of T frames has T - k pairs k apart (none beyond T - 1)
    assert [int(k) for k in metrics["orb_curve"]] == list(range(1, 21))
    assert [v["pairs"] for v in metrics["orb_curve"].values()] == [max(0, FRAMES - k) for k in range(1, 21)]
    assert 0.0 <= metrics["dice"] <= 1.0
    assert np.isfinite(metrics["of_error"]) and metrics["of_error"] >= 0
    assert metrics["fid"] is None and "weights" in metrics["reasons"]["fid"]  # said, not invented
    assert (out / info["report"]).stat().st_size > 0
    # the stand-in real domain comes from other scenes than the simulated one
    assert len(list((out / "real" / "images").glob("*.png"))) == 8


def test_demo_refuses_a_used_output_folder(tmp_path, capsys):
    (tmp_path / "old.txt").write_text("keep me")
    code = main(["demo", "--out", str(tmp_path), "--train", "--minutes", "0.05", "--preset", "tiny"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.txt"]


def test_a_demo_stopped_while_training_leaves_nothing(tmp_path, capsys, monkeypatch):
    """Ctrl-C while the demo trains stops the training with a checkpoint (as in train); the demo
    then stops too, with 130, instead of going on with a half-trained model, and removes what it
    wrote, so the same command can run again."""
    import signal

    from sim2real.engine.trainer import Trainer

    def interrupted(self, **kwargs):
        self.stopped_by = signal.SIGINT

    monkeypatch.setattr(Trainer, "train", interrupted)
    out = tmp_path / "out"
    code = main(["demo", "--out", str(out), "--train", "--minutes", "0.05", "--preset", "tiny", "--scenes", "1",
                 "--real-images", "4", "--frames", "4", "--device", "cpu"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 130 and err[-1] == "demo stopped by SIGINT while training; nothing written", err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("extra,words", [
    (["--frames", "1"], "at least 2 frames"),
    (["--fid-weights", "/nonexistent/pt_inception.pth"], "FID Inception weights not found"),
    (["--device", "cuda"], "no CUDA device"),
])
def test_demo_refuses_settings_that_would_fail_after_training(tmp_path, capsys, extra, words, monkeypatch):
    """Settings of the last two stages are checked before the first: nothing is written, no
    minutes of training are spent on them."""
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    code = main(["demo", "--out", str(tmp_path / "out"), "--train", "--minutes", "0.05", "--preset", "tiny", *extra])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and words in err, err
    assert not (tmp_path / "out").exists()
