"""``sim2real translate`` and the TrainedModel API on a tiny run trained for 2 iterations (CPU)."""

import json
import shutil

import numpy as np
import pytest
import torch
from conftest import private_outputs
from eval_data import SCENE_SEED, tiny_run
from PIL import Image
from train_data import scene_dir, views_dir

from sim2real.cli.main import main
from sim2real.inference.gt_dataset import GroundTruthDataset
from sim2real.inference.model import load_run
from sim2real.inference.video import read_video
from sim2real.render.raycast import RayCaster
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory, make_trajectory

H, W = 64, 128


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    base = tmp_path_factory.getbasetemp()
    run = tiny_run(base)
    scene = scene_dir(base, SCENE_SEED)
    caster = RayCaster(Scene.load(scene))
    cams = make_trajectory(caster, 4, H, W, seed=2).cameras
    traj = tmp_path_factory.mktemp("traj") / "revisit.txt"
    Trajectory(cams + [cams[1]], fps=4.0).save(traj)  # frame 4 revisits frame 1's view
    return {"base": base, "run": run, "scene": scene, "traj": traj, "caster": caster, "cams": cams}


def cli(capsys, *argv):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.strip()


def one_line(err):
    lines = [l for l in err.splitlines() if l.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def png(path):
    return np.asarray(Image.open(path))


def test_translate_trajectory(inputs, tmp_path, capsys):
    out = tmp_path / "out"
    code, err = cli(capsys, "translate", inputs["run"], "--scene", inputs["scene"], "--trajectory", inputs["traj"],
                    "--out", out, "--batch", 3, "--device", "cpu", "--no-progress")
    assert code == 0 and "bf16" not in err, err
    names = sorted(p.name for p in (out / "frames").iterdir())
    assert names == [f"{i:06d}.png" for i in range(5)]
    frames = [png(out / "frames" / n) for n in names]
    assert all(f.shape == (H, W, 3) and f.dtype == np.uint8 for f in frames)
    assert read_video(out / "video.mp4") == (5, H, W)
    gt = json.loads((out / "ground_truth" / "ground_truth.json").read_text())
    assert gt["frames"] == 5 and gt["fps"] == 4.0 and (gt["height"], gt["width"]) == (H, W)
    assert len(list((out / "ground_truth" / "flow").glob("*.flo"))) == 4
    # tum/rgb holds the translated frames, not a_ref
    assert np.array_equal(png(out / "ground_truth" / "tum" / "rgb" / "000003.png"), frames[3])
    # time independence: the revisited view (other batch, other position) gives the same pixels
    assert np.array_equal(frames[4], frames[1])
    assert not np.array_equal(frames[0], frames[1])
    manifest = json.loads((out / "translate.json").read_text())
    assert manifest["frames"] == 5 and manifest["scene"] == f"procedural_{SCENE_SEED:04d}"
    assert manifest["batch"] == 3  # as given
    assert not (out / ".gbuffers").exists()  # scratch removed
    assert not list(tmp_path.glob(".out.partial-*"))  # written beside it, then renamed into place
    assert private_outputs(out, tmp_path) == []  # readable as any new file is, not 0600 / 0700


def test_translate_stereo_pair(inputs, tmp_path, capsys):
    """--stereo: each eye's frames are the model's translation of that eye's view (a time-independent
    method gives the same pixels wherever a view appears), each eye has its ground truth, and the
    disparity is fx * baseline / depth of the left view."""
    from sim2real.inference.gt_formats import read_tum_poses
    from sim2real.inference.stereo import right_camera

    out = tmp_path / "stereo"
    code, err = cli(capsys, "translate", inputs["run"], "--scene", inputs["scene"], "--trajectory", inputs["traj"],
                    "--out", out, "--batch", 3, "--device", "cpu", "--no-progress", "--stereo", 4)
    assert code == 0, err
    cams = Trajectory.load(inputs["traj"]).cameras  # as translate reads them
    model = load_run(inputs["run"], "cpu")
    name = f"procedural_{SCENE_SEED:04d}"
    left_g = [inputs["caster"].render(c) for c in cams]
    right_g = [inputs["caster"].render(right_camera(c, 4.0)) for c in cams]
    for eye, g in ((out, left_g), (out / "right", right_g)):
        want = model.translate_gbuffers(name, g, batch=3)
        assert all(np.array_equal(png(eye / "frames" / f"{i:06d}.png"), want[i]) for i in range(5))
        assert read_video(eye / "video.mp4") == (5, H, W)
        assert json.loads((eye / "ground_truth" / "ground_truth.json").read_text())["frames"] == 5
    assert not np.array_equal(png(out / "frames" / "000000.png"), png(out / "right" / "frames" / "000000.png"))
    for pl, pr in zip(read_tum_poses(out / "ground_truth" / "poses_tum_mm.txt"),
                      read_tum_poses(out / "right" / "ground_truth" / "poses_tum_mm.txt")):
        assert np.allclose(pr[:3, 3], pl[:3, 3] + 4.0 * pl[:3, 0], atol=1e-4) and np.allclose(pr[:3, :3], pl[:3, :3], atol=1e-6)
    st = json.loads((out / "stereo" / "stereo.json").read_text())
    assert st["baseline_mm"] == 4.0 and st["frames"] == 5 and np.allclose(st["K"], cams[0].K)
    for i in range(5):
        depth = np.load(out / "ground_truth" / "depth_npy" / f"{i:06d}.npy")
        d = np.load(out / "stereo" / "disparity" / f"{i:06d}.npy")
        assert np.allclose(d[depth > 0], cams[i].K[0, 0] * 4.0 / depth[depth > 0], rtol=1e-6) and (d[depth == 0] == 0).all()
        mask = png(out / "stereo" / "disparity_mask" / f"{i:06d}.png")
        assert 0.5 < (mask[depth > 0] == 255).mean() and not mask[depth == 0].any()
    manifest = json.loads((out / "translate.json").read_text())
    assert manifest["stereo"] == {"baseline_mm": 4.0, "right": "right/", "stereo": "stereo/"}
    pair = GroundTruthDataset(out, fields=["image", "depth", "right_image", "disparity", "disparity_mask"], stereo=True)
    s = pair[3]
    assert torch.equal(s["right_image"], torch.tensor(png(out / "right" / "frames" / "000003.png")).permute(2, 0, 1) / 255)
    assert torch.equal(s["image"], torch.tensor(png(out / "frames" / "000003.png")).permute(2, 0, 1) / 255)
    surface = s["depth"] > 0
    assert pair.baseline_mm == 4.0 and (s["disparity"][~surface] == 0).all() and not s["disparity_mask"][~surface[0]].any()
    assert torch.allclose(s["disparity"][surface], float(cams[3].K[0, 0]) * 4.0 / s["depth"][surface], rtol=1e-5)

    code, err = cli(capsys, "translate", inputs["run"], "--views", out, "--stereo", 4, "--out", tmp_path / "x")
    assert code == 2 and one_line(err) == ("sim2real: error: --stereo needs --scene SCENE --trajectory FILE: "
                                           "a views folder has one camera per view")


def test_default_batch_by_device():
    from sim2real.inference.model import translate_batch

    assert translate_batch(torch.device("cuda")) == 8 and translate_batch(torch.device("cpu")) == 2


def test_model_api_is_time_independent(inputs):
    model = load_run(inputs["run"], "cpu")
    name = f"procedural_{SCENE_SEED:04d}"
    assert model.scenes == [name] and model.train_size == (H, W)
    g = [inputs["caster"].render(c) for c in inputs["cams"][:3]]
    a = model.translate_gbuffers(name, g, batch=2)
    b = model.translate_gbuffers(name, [g[2], g[0], g[2], g[1]], batch=2)
    c = model.translate_gbuffers(name, [g[2]], batch=2)
    assert np.array_equal(a[2], b[0]) and np.array_equal(a[2], b[2]) and np.array_equal(a[2], c[0])
    assert np.array_equal(a[0], b[1]) and np.array_equal(a[1], b[3])
    # a size that is not a multiple of 4 is padded for the networks and cropped back
    from sim2real.scene.camera import Camera, intrinsics_from_fov

    cam = inputs["cams"][0]
    odd = inputs["caster"].render(Camera(intrinsics_from_fov(77, 45, 75.0), cam.world_to_camera, 45, 77))
    assert model.translate_gbuffers(name, [odd])[0].shape == (45, 77, 3)


def test_translate_views_folder(inputs, tmp_path, capsys):
    views = views_dir(inputs["base"], inputs["scene"], n=3, height=H, width=W, name="views_translate")
    out = tmp_path / "from_views"
    code, err = cli(capsys, "translate", inputs["run"], "--views", views, "--out", out, "--device", "cpu", "--no-progress")
    assert code == 0, err
    assert len(list((out / "frames").glob("*.png"))) == 3
    assert read_video(out / "video.mp4") == (3, H, W)
    assert (out / "ground_truth" / "ground_truth.json").is_file()


def test_run_without_checkpoint(inputs, tmp_path, capsys):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    shutil.copy(inputs["run"] / "config.yaml", run / "config.yaml")
    code, err = cli(capsys, "translate", run, "--scene", inputs["scene"], "--trajectory", inputs["traj"], "--out", tmp_path / "o")
    assert code == 2
    assert "no checkpoint" in one_line(err)


def test_bad_trajectory_rows(inputs, tmp_path, capsys):
    bad = tmp_path / "bad.txt"
    lines = inputs["traj"].read_text().splitlines()
    bad.write_text("\n".join(lines[:-1] + ["0.8 1 2 3 nan 0 0 1"]) + "\n")
    code, err = cli(capsys, "translate", inputs["run"], "--scene", inputs["scene"], "--trajectory", bad, "--out", tmp_path / "o")
    assert code == 2
    line = one_line(err)
    assert f"bad.txt:{len(lines)}" in line and "8 numbers" in line
    assert not (tmp_path / "o").exists()


def test_unknown_scene_names_the_known_ones(inputs, tmp_path, capsys):
    other = tmp_path / "other_scene"
    shutil.copytree(inputs["scene"], other)
    spec = json.loads((other / "scene.json").read_text())
    spec["name"] = "somewhere_else"
    (other / "scene.json").write_text(json.dumps(spec))
    code, err = cli(capsys, "translate", inputs["run"], "--scene", other, "--trajectory", inputs["traj"], "--out", tmp_path / "o")
    assert code == 2
    line = one_line(err)
    assert "somewhere_else" in line and f"procedural_{SCENE_SEED:04d}" in line


def test_output_dir_with_other_data(inputs, tmp_path, capsys):
    out = tmp_path / "busy"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    code, err = cli(capsys, "translate", inputs["run"], "--scene", inputs["scene"], "--trajectory", inputs["traj"],
                    "--out", out, "--device", "cpu")
    assert code == 2
    assert "already holds other data" in one_line(err)
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_a_failed_translation_leaves_no_output_folder(inputs, tmp_path, capsys, monkeypatch):
    """The disk fills while the ground truth is closed (after the frames): one line, exit 1, no
    --out folder (not even an empty one) and nothing hidden beside it; an --out folder the user
    made beforehand stays, empty."""
    import errno
    import os

    from sim2real.inference import export

    def full(self):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(export.GroundTruthWriter, "close", full)
    made = tmp_path / "made"
    made.mkdir()
    for out in (tmp_path / "out", made):
        code, err = cli(capsys, "translate", inputs["run"], "--scene", inputs["scene"], "--trajectory", inputs["traj"],
                        "--out", out, "--device", "cpu", "--no-progress")
        assert code == 1 and one_line(err).endswith("No space left on device: free space on that disk or write elsewhere")
    assert [p.name for p in tmp_path.iterdir()] == ["made"] and list(made.iterdir()) == []


def test_too_little_free_space_is_refused_before_translating(inputs, tmp_path, capsys, monkeypatch):
    """The flow (2 float32 per pixel, all frames but the last) and depth (1 float32) of 5 frames at
    64x128: 8192 * (8 * 4 + 4 * 5) = 425,984 bytes; a right eye doubles them and adds a disparity
    per frame: 8192 * (2 * 52 + 4 * 5) = 1,015,808. One byte less free: refused, nothing written."""
    import collections

    from sim2real.inference import translate

    model = load_run(inputs["run"], device="cpu")
    mono = translate.trajectory_source(model, inputs["scene"], inputs["traj"])
    assert translate.least_bytes(mono) == 425_984
    assert translate.least_bytes(translate.trajectory_source(model, inputs["scene"], inputs["traj"], 5.0)) == 1_015_808
    usage = collections.namedtuple("usage", "total used free")
    for free, code in ((425_983, 2), (425_984, 0)):
        monkeypatch.setattr(shutil, "disk_usage", lambda p, f=free: usage(0, 0, f))
        out = tmp_path / f"out{free}"
        got, err = cli(capsys, "translate", inputs["run"], "--scene", inputs["scene"], "--trajectory", inputs["traj"],
                       "--out", out, "--device", "cpu", "--no-progress")
        assert got == code, err
        if code:
            assert one_line(err).endswith(f"the ground truth of 5 frames at {W}x{H} (its flow and depth maps alone) "
                                          f"needs at least 0.4 MiB but {tmp_path} has 0.4 MiB free; free space, write "
                                          f"elsewhere or translate fewer frames")
            assert not out.exists()
        else:
            assert (out / "translate.json").is_file()


def test_mixed_precision_path_on_cpu(inputs, monkeypatch):
    """The CUDA path (bf16 autocast, channels-last), run on the CPU: frames within bf16 rounding
    of the fp32 ones, and still independent of what shares their batch."""
    from sim2real.engine import precision

    name = f"procedural_{SCENE_SEED:04d}"
    g = [inputs["caster"].render(c) for c in inputs["cams"][:3]]
    fp32 = load_run(inputs["run"], "cpu").translate_gbuffers(name, g, batch=2)
    monkeypatch.setattr(precision, "mixed_precision", lambda device: True)
    model = load_run(inputs["run"], "cpu")
    assert model.amp and model.method.memory_format == torch.channels_last
    bf16 = model.translate_gbuffers(name, g, batch=2)
    for a, b in zip(bf16, fp32):
        d = np.abs(a.astype(int) - b.astype(int))
        assert d.mean() < 3.0 and d.max() <= 32, (d.mean(), d.max())  # measured: mean ~1, max 10-14 levels
    assert any(not np.array_equal(a, b) for a, b in zip(bf16, fp32))  # it did run in bf16
    assert np.array_equal(model.translate_gbuffers(name, [g[2], g[0]], batch=2)[0], bf16[2])


def test_precision_choice_on_cpu(inputs, tmp_path, capsys, monkeypatch):
    """'auto' and 'fp32' are the same exact fp32 frames on the CPU; 'bf16' runs bf16 autocast
    in the default layout (channels-last is CUDA-only), frames within bf16 rounding of fp32 and
    still independent of what shares their batch; the choice is recorded and checked."""
    from sim2real.errors import UserError

    name = f"procedural_{SCENE_SEED:04d}"
    g = [inputs["caster"].render(c) for c in inputs["cams"][:3]]
    auto = load_run(inputs["run"], "cpu")
    fp32 = load_run(inputs["run"], "cpu", precision="fp32")
    bf16 = load_run(inputs["run"], "cpu", precision="bf16")
    assert not auto.amp and not fp32.amp and bf16.amp
    assert bf16.method.memory_format == torch.contiguous_format
    want = auto.translate_gbuffers(name, g, batch=2)
    assert all(np.array_equal(a, b) for a, b in zip(fp32.translate_gbuffers(name, g, batch=2), want))
    got = bf16.translate_gbuffers(name, g, batch=2)
    for a, b in zip(got, want):
        d = np.abs(a.astype(int) - b.astype(int))
        assert d.mean() < 3.0 and d.max() <= 32, (d.mean(), d.max())
    assert any(not np.array_equal(a, b) for a, b in zip(got, want))  # it did run in bf16
    assert np.array_equal(bf16.translate_gbuffers(name, [g[2], g[0]], batch=2)[0], got[2])
    with pytest.raises(UserError, match="precision must be one of auto, fp32, bf16"):
        load_run(inputs["run"], "cpu", precision="fp16")

    out = tmp_path / "bf16"
    monkeypatch.setattr("sim2real.engine.precision.cpu_has_bf16", lambda: False)  # emulated: a note says so
    code, err = cli(capsys, "translate", inputs["run"], "--scene", inputs["scene"], "--trajectory", inputs["traj"],
                    "--out", out, "--device", "cpu", "--precision", "bf16", "--no-progress")
    assert code == 0 and one_line(err).startswith("note: this CPU has no bf16 instructions"), err
    manifest = json.loads((out / "translate.json").read_text())
    assert manifest["amp_bf16"] is True and manifest["batch"] == 2  # no --batch: the CPU's default
    with pytest.raises(SystemExit) as e:  # argparse refuses it before anything loads
        main([str(a) for a in ("translate", inputs["run"], "--scene", inputs["scene"], "--trajectory", inputs["traj"],
                               "--out", tmp_path / "fp16", "--precision", "fp16")])
    assert e.value.code == 2 and "invalid choice: 'fp16'" in one_line(capsys.readouterr().err)
    assert not (tmp_path / "fp16").exists()


def test_compiled_translation_equals_eager(inputs, tmp_path, capsys):
    """--compile (TorchInductor with frozen weights) gives the eager frames to within one 8-bit
    level on few pixels, through the command; the networks were compiled, and it is recorded."""
    import torch._dynamo

    torch._dynamo.reset()
    graphs = torch._dynamo.utils.counters["stats"]["unique_graphs"]
    frames = {}
    for flag in ((), ("--compile",)):
        out = tmp_path / f"out{len(flag)}"
        code, err = cli(capsys, "translate", inputs["run"], "--scene", inputs["scene"], "--trajectory", inputs["traj"],
                        "--out", out, "--batch", 2, "--device", "cpu", "--no-progress", *flag)
        assert code == 0, err
        assert json.loads((out / "translate.json").read_text())["compiled"] is bool(flag)
        frames[bool(flag)] = np.stack([png(p) for p in sorted((out / "frames").iterdir())]).astype(int)
    assert torch._dynamo.utils.counters["stats"]["unique_graphs"] - graphs >= 2  # the encoder and the decoder
    d = np.abs(frames[True] - frames[False])
    assert d.max() <= 1 and (d > 0).mean() < 1e-2, (d.max(), (d > 0).mean())
    assert np.array_equal(frames[True][4], frames[True][1])  # still time-independent (padded batches)


def test_compile_without_a_compiler_is_one_line(inputs, tmp_path):
    """A machine without a C++ compiler (CXX names none): one line, a non-zero exit, no output.
    In a fresh process, so that inductor's memory of the missing compiler stays there."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "CXX": str(tmp_path / "no-such-c++"), "TORCHINDUCTOR_CACHE_DIR": str(tmp_path / "inductor"),
           "SIM2REAL_CACHE": str(tmp_path / "cache")}
    r = subprocess.run([sys.executable, "-m", "sim2real.cli.main", "translate", str(inputs["run"]), "--scene",
                        str(inputs["scene"]), "--trajectory", str(inputs["traj"]), "--out", str(tmp_path / "out"),
                        "--device", "cpu", "--no-progress", "--compile"], capture_output=True, text=True, env=env,
                       timeout=300)
    assert r.returncode != 0
    line = one_line(r.stderr)
    assert "--compile: TorchInductor cannot compile for cpu" in line and "run without --compile" in line, line
    assert not (tmp_path / "out").exists()


def test_compiled_cuda_numerics_on_cpu(inputs, monkeypatch):
    """--compile under the CUDA path's numerics (bf16 autocast, channels-last images and weights),
    run on the CPU: frames within bf16 rounding of the uncompiled ones of the same path, and still
    independent of what shares their batch."""
    import torch._dynamo

    from sim2real.engine import precision

    torch._dynamo.reset()
    monkeypatch.setattr(precision, "mixed_precision", lambda device: True)
    name = f"procedural_{SCENE_SEED:04d}"
    g = [inputs["caster"].render(c) for c in inputs["cams"][:3]]
    eager = load_run(inputs["run"], "cpu").translate_gbuffers(name, g, batch=2)
    model = load_run(inputs["run"], "cpu", compile=True)
    assert model.compiled and model.amp and model.method.memory_format == torch.channels_last
    got = model.translate_gbuffers(name, g, batch=2)
    for a, b in zip(got, eager):
        d = np.abs(a.astype(int) - b.astype(int))
        assert d.mean() < 3.0 and d.max() <= 32, (d.mean(), d.max())
    assert np.array_equal(model.translate_gbuffers(name, [g[2], g[0]], batch=2)[0], got[2])
    torch._dynamo.reset()
