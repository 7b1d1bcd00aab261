"""Device-clean by test: the whole CPU path (a training step, a resume, translate, evaluate) runs
with torch's default device set to ``meta``. A tensor that the code creates without saying where
(``torch.zeros(n)``, ``torch.arange(k)``, a module built without a device, ...) lands on the meta
device, and the first operation mixing it with the run's CPU tensors fails, or its values are
missing when they are read: on a GPU such a tensor would sit on the wrong device."""

import json

import pytest
import torch
from eval_data import SCENE_SEED
from train_data import real_dir, scene_dir

from sim2real.cli.main import main
from sim2real.render.raycast import RayCaster
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory, make_trajectory

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture
def meta_default():
    torch.set_default_device("meta")
    try:
        yield
    finally:
        torch.set_default_device(None)


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 0, err


def test_the_meta_default_device_is_harmful():
    """The trap works: a tensor made without a device is on meta and cannot meet a CPU tensor."""
    torch.set_default_device("meta")
    try:
        stray = torch.zeros(3)
        assert stray.device.type == "meta"
        with pytest.raises((RuntimeError, NotImplementedError)):
            (stray + torch.ones(3, device="cpu")).tolist()
    finally:
        torch.set_default_device(None)
    assert torch.zeros(1).device.type == "cpu"


def test_train_resume_translate_evaluate_with_a_meta_default_device(tmp_path_factory, tmp_path, capsys, meta_default):
    base = tmp_path_factory.getbasetemp()
    scene, real = scene_dir(base, SCENE_SEED), real_dir(base)
    run = tmp_path / "run"
    common = ["--preset", "tiny", "--device", "cpu", "--no-progress", "--set", "data.workers=0"]
    _cli(capsys, "train", "--scenes", scene, "--real", real, "--out", run, "--iterations", 1, *common)
    _cli(capsys, "train", "--out", run, "--resume", "--iterations", 2, "--device", "cpu", "--no-progress")
    metrics = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert [m["step"] for m in metrics] == [1, 2]
    assert all(0 <= m["time/data_wait_share"] <= 1 for m in metrics)

    torch.set_default_device(None)  # a trajectory is set-up, not the code under test
    cams = make_trajectory(RayCaster(Scene.load(scene)), 3, 64, 128, seed=2).cameras
    traj = tmp_path / "traj.txt"
    Trajectory(cams, fps=4.0).save(traj)
    torch.set_default_device("meta")
    out = tmp_path / "translated"
    _cli(capsys, "translate", run, "--scene", scene, "--trajectory", traj, "--out", out, "--batch", 2, "--device",
         "cpu", "--no-progress")
    assert len(list((out / "frames").glob("*.png"))) == 3
    ev = tmp_path / "eval"
    _cli(capsys, "evaluate", run, "--scenes", scene, "--real", real, "--out", ev, "--views", 2, "--frames", 4,
         "--seg-iterations", 2, "--seg-size", "32x64", "--device", "cpu", "--no-progress")
    assert (ev / "metrics.json").is_file()


def test_a_ref_rendered_from_the_sample_with_a_meta_default_device(procedural_caster, meta_default):
    """The GPU path's a_ref (data/tensors.py): every tensor it makes is on its inputs' device."""
    from sim2real.data.tensors import compact, complete_on_device, view_inputs, widen
    from sim2real.scene.trajectory import sample_poses

    g = procedural_caster.render(sample_poses(procedural_caster, 1, 32, 64, 75.0, seed=1)[0])
    batch = complete_on_device(widen(compact(view_inputs([g], "i", len(g.classes)))))
    assert batch["a_ref_i"].device.type == "cpu" and batch["a_ref_i"].shape == (1, 3, 32, 64)
    assert batch["a_ref_i"].abs().sum().item() > 0
