"""Device-clean by test: the whole CPU path (a training step, a resume, translate, evaluate) runs
with torch's default device set to ``meta`` (``with torch.device("meta")``, the mode that
``torch.set_default_device`` enters too; that one, reset to None, broke ``torch.get_default_device``
before torch 2.10, and with it every later torchmetrics metric). A tensor that the code creates
without saying where (``torch.zeros(n)``, ``torch.arange(k)``, a module built without a device, ...)
lands on the meta device, and the first operation mixing it with the run's CPU tensors fails, or its
values are missing when they are read: on a GPU such a tensor would sit on the wrong device."""

import functools
import json

import numpy as np
import pytest
import torch
from eval_data import SCENE_SEED
from torch.utils.data import default_collate
from train_data import real_dir, scene_dir, tiny_config

from sim2real.cli.main import main
from sim2real.engine.trainer import Trainer
from sim2real.methods import get_method
from sim2real.presets import METHOD_PRESETS
from sim2real.render.raycast import RayCaster
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory, make_trajectory

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture
def meta_default():
    with torch.device("meta"):
        yield


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 0, err


def test_the_meta_default_device_is_harmful():
    """The trap works: a tensor made without a device is on meta and cannot meet a CPU tensor."""
    with torch.device("meta"):
        stray = torch.zeros(3)
        assert stray.device.type == "meta"
        with pytest.raises((RuntimeError, NotImplementedError)):
            (stray + torch.ones(3, device="cpu")).tolist()
    assert torch.zeros(1).device.type == "cpu"
    assert torch.get_default_device().type == "cpu"  # what torchmetrics asks of every new metric


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

    with torch.device("cpu"):  # a trajectory is set-up, not the code under test
        cams = make_trajectory(RayCaster(Scene.load(scene)), 3, 64, 128, seed=2).cameras
        traj = tmp_path / "traj.txt"
        Trajectory(cams, fps=4.0).save(traj)
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


# --- a fake CUDA device: tensors made on the CPU on purpose (torch.from_numpy, device="cpu") -------
# The meta default above catches a tensor made without a device; one made on the CPU explicitly
# passes it, as the run's device is the CPU. Under torch's FakeTensorMode a model and batch can
# live on a "cuda" device that has no memory and no GPU behind it: every operation checks that its
# tensors share a device, as CUDA would, and computes only shapes. The backward pass cannot run
# there (the autograd engine asks the CUDA driver for the device), nor can anything that reads
# values (.item(), .numpy()), so these tests run the forward passes of a step and of a translation.
# That makes them a check of host syncs too: a value read back from the device (on a GPU the
# host waits for every queued kernel) fails with DataDependentOutputException.


@functools.cache
def _fake_cuda_unavailable() -> str | None:
    """Why this torch cannot fake a CUDA device here, or None. Before torch 2.10 FakeTensorMode
    initialised a "cuda" parameter through the CUDA runtime, which fails where no driver is
    installed ("CUDA driver version is insufficient"; 2.5.1 to 2.9.1 checked); from 2.10 on it
    needs none, and a failure there is the test's own."""
    from torch._subclasses.fake_tensor import FakeTensorMode
    from torch.torch_version import TorchVersion

    if torch.cuda.is_available() or TorchVersion(torch.__version__) >= "2.10":
        return None
    try:
        with FakeTensorMode():
            torch.empty(2, device="cuda").uniform_()
    except RuntimeError as e:  # torch 2.8/2.9 raise its subclass AcceleratorError
        return f"torch {torch.__version__} fakes a CUDA device through the CUDA driver, absent here: {e}".splitlines()[0]
    return None


@pytest.fixture
def fake_cuda():
    """A FakeTensorMode whose "cuda" tensors need no GPU; real CPU tensors (a loader batch) may
    enter it and are turned into fake ones. ``Module.to`` then assigns new parameters instead of
    swapping them in place, which fake tensors do not allow."""
    from torch._subclasses.fake_tensor import FakeTensorMode

    reason = _fake_cuda_unavailable()
    if reason:
        pytest.skip(reason)
    overwrite = torch.__future__.get_overwrite_module_params_on_conversion()
    torch.__future__.set_overwrite_module_params_on_conversion(True)
    try:
        yield FakeTensorMode(allow_non_fake_inputs=True)
    finally:
        torch.__future__.set_overwrite_module_params_on_conversion(overwrite)


WRONG_DEVICE = "same device|two different devices"
"""FakeTensor's error for operands on two devices, as torch 2.14 words it and as torch 2.11 did."""


def test_the_fake_cuda_device_is_harmful(fake_cuda):
    with fake_cuda:
        conv = torch.nn.Conv2d(3, 4, 3, device="cuda")
        y = conv(torch.zeros(1, 3, 8, 8, device="cuda"))
        assert y.device.type == "cuda" and y.shape == (1, 4, 6, 6)
        with pytest.raises(RuntimeError, match=WRONG_DEVICE):
            y * torch.ones(4, 1, 1)  # made without a device: the CPU
        with pytest.raises(RuntimeError, match=WRONG_DEVICE):
            y * torch.from_numpy(np.ones((4, 1, 1), np.float32))


def _config(name: str, **changes):
    """The tiny preset on the CPU (the fake device replaces it), without view pool or workers."""
    return tiny_config(name, device="cpu", data__view_pool=0, data__workers=0, **changes)


def _cuda_step(cfg, scenes, real, out, fake_cuda, gbuffers):
    """The forward passes of one training step (the trainer's own batch transfer and step, without
    its backward and its host sync) and of a translation, with the model and batch on the fake
    CUDA device; returns every loss term and translated image."""
    trainer = Trainer(cfg, [scenes], real, out, progress=False)
    try:
        trainer.dataset.a_ref_in_worker = False  # as on CUDA: a_ref rendered from the sample on the device
        batch = default_collate([trainer.dataset[0]])
        cuda = torch.device("cuda")
        trainer.device, trainer.channels_last = cuda, True
        trainer.method.memory_format = torch.channels_last
        trainer._update = lambda losses, weights, opts: sum(weights[k] * v for k, v in losses.items())
        trainer._check_finite = lambda losses, totals, step: None
        method = trainer.method
        with fake_cuda:
            trainer.gen.to(cuda)
            trainer.dis.to(cuda)
            results = dict(trainer.train_step(trainer._to_device(batch), 0))
            seq = method.sequence(trainer.gen, 0, cuda)
            for k in range(2):  # two chunks: a time-dependent method carries state from the first
                results[f"push_{k}"] = seq.push(gbuffers[2 * k: 2 * k + 2])
            views = method.inference_batch(gbuffers[:2], 0, cuda)
            real_img = torch.zeros(1, 3, 40, 72, device=cuda)
            for name, img in method.translate_views(trainer.gen, views, real_img, torch.Generator().manual_seed(0)):
                results[f"views{name}"] = img
    finally:
        trainer.close()
    return results


@pytest.fixture(scope="module")
def four_views(procedural_caster):
    from sim2real.scene.trajectory import make_trajectory

    cams = make_trajectory(procedural_caster, 4, 32, 64, seed=3).cameras
    return [procedural_caster.render(c) for c in cams]


@pytest.mark.filterwarnings("ignore:Detected call of `lr_scheduler.step\\(\\)` before")  # no optimiser step here
@pytest.mark.parametrize("name,structure", [(n, "ms_ssim") for n in sorted(METHOD_PRESETS)] + [("ours", "edges")])
def test_a_step_and_a_translation_on_a_fake_cuda_device(name, structure, request, tmp_path, fake_cuda, four_views):
    cfg = _config(name, loss__ab_structure=structure)
    if hasattr(cfg.method, "vc_start"):
        cfg.method.vc_start = 0  # the view-consistency term in the step too
    video = get_method(cfg).data == "triplets"
    scenes, real = request.getfixturevalue("video_train_inputs" if video else "train_inputs")
    results = _cuda_step(cfg, scenes, real, tmp_path / "run", fake_cuda, four_views)
    assert {"dis/total", "gen/total", "push_0", "push_1"} <= results.keys()
    assert any(k.startswith("views") for k in results)
    for k, v in results.items():
        assert v.device.type == "cuda", k
    for k in ("push_0", "push_1"):
        assert results[k].shape == (2, 3, 32, 64), k


def test_a_cpu_tensor_in_the_step_fails_on_the_fake_cuda_device(train_inputs, tmp_path, fake_cuda, four_views,
                                                                monkeypatch):
    """The check catches what the meta default cannot: a_ref drawn with a weight made from numpy."""
    import sim2real.data.tensors as tensors

    real_reference = tensors.reference_on_device

    def cpu_weighted(*args):
        return real_reference(*args) * torch.from_numpy(np.ones((3, 1, 1), np.float32))

    monkeypatch.setattr(tensors, "reference_on_device", cpu_weighted)
    scenes, real = train_inputs
    with pytest.raises(RuntimeError, match=WRONG_DEVICE):
        _cuda_step(_config("ours"), scenes, real, tmp_path / "run", fake_cuda, four_views)


def test_a_host_sync_in_the_step_fails_on_the_fake_cuda_device(train_inputs, tmp_path, fake_cuda, four_views,
                                                               monkeypatch):
    """A value read back from the device inside the step (on a GPU, a host sync) fails it. The read
    back is the one kornia 0.9's gaussian_blur2d makes inside a device context, written out here
    because other kornia releases check sigma differently (0.8.2 reads nothing back): sigma put in a
    tensor made without a device, so on the device, and read to check it is positive. The edge-recall
    term's own blur (losses/structure.py) reads nothing back."""
    from torch._subclasses.fake_tensor import DataDependentOutputException

    import sim2real.losses.structure as structure

    own_blur = structure.gaussian_blur

    def blur_reading_sigma_back(x, sigma):
        with torch.device(x.device):
            if not bool((torch.tensor([sigma, sigma]) > 0).all()):
                raise ValueError("sigma must be positive")
        return own_blur(x, sigma)

    monkeypatch.setattr(structure, "gaussian_blur", blur_reading_sigma_back)
    scenes, real = train_inputs
    cfg = _config("ours", loss__ab_structure="edges")
    with pytest.raises(DataDependentOutputException):
        _cuda_step(cfg, scenes, real, tmp_path / "run", fake_cuda, four_views)
