"""``sim2real train``: bad inputs get one clear line and exit code 2; grey/RGBA images are fine."""

import shutil

import pytest
import torch
import yaml
from PIL import Image
from train_data import real_dir, scene_dir, views_dir

from sim2real.cli.main import main


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    base = tmp_path_factory.getbasetemp()
    return scene_dir(base, 11), real_dir(base)


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.err.strip(), captured.out


def assert_error(result, *words):
    code, err, _ = result
    assert code == 2, err
    assert "Traceback" not in err
    lines = [l for l in err.splitlines() if l.strip()]
    assert len(lines) == 1, err
    for w in words:
        assert w in lines[0], lines[0]


def train(capsys, tmp_path, scenes, real, *extra, preset="tiny"):
    return run(capsys, "train", "--preset", preset, "--scenes", *scenes, "--real", real,
               "--out", tmp_path / "run", "--no-progress", *extra)


def test_unknown_preset(capsys, tmp_path, inputs):
    assert_error(train(capsys, tmp_path, [inputs[0]], inputs[1], preset="huge"), "unknown preset 'huge'", "tiny")


def test_unknown_and_malformed_keys(capsys, tmp_path, inputs):
    assert_error(train(capsys, tmp_path, [inputs[0]], inputs[1], "--set", "loss.nope=1"), "unknown config key 'loss.nope'")
    assert_error(train(capsys, tmp_path, [inputs[0]], inputs[1], "--set", "method.vc=abc"), "method.vc", "expects float")
    assert_error(train(capsys, tmp_path, [inputs[0]], inputs[1], "--method", "cyclegan"), "unknown method 'cyclegan'",
                 "ours_no_vc")
    assert_error(train(capsys, tmp_path, [inputs[0]], inputs[1], "--set", "method=ours"), "'method' is a section",
                 "--method NAME")
    # a key of another method's section is unknown in this one
    assert_error(train(capsys, tmp_path, [inputs[0]], inputs[1], "--set", "loss.vc=1"), "unknown config key 'loss.vc'")
    assert_error(train(capsys, tmp_path, [inputs[0]], inputs[1], "--set", "data.height=66"), "multiples of 4")
    assert not (tmp_path / "run").exists()  # nothing written for a refused run


@pytest.mark.parametrize("setting,words", [
    ("method.texture.size=0", ["'method.texture.size'", ">= 1"]),
    ("method.texture.features=-1", ["'method.texture.features'", ">= 0"]),
    ("method.texture.mapping=sphere", ["'method.texture.mapping'", "box, cube"]),
    ("method.texture.tanh=before", ["'method.texture.tanh'", "interpolated, texel"]),
    ("method.texture.init_noise=-0.5", ["'method.texture.init_noise'", ">= 0"]),
    ("method.texture.init_noise_sigma=0", ["'method.texture.init_noise_sigma'", "> 0"]),
    ("method.texture.init_lines=-1", ["'method.texture.init_lines'", ">= 0"]),
    ("method.texture.init_lines_sigma=0", ["'method.texture.init_lines_sigma'", "> 0"]),
    ("method.vc=-1", ["'method.vc'", ">= 0"]),
    ("method.vc_start=-1", ["'method.vc_start'", ">= 0"]),
    ("generator.filters=0", ["'generator.filters'"]),
    ("generator.content_channels=-1", ["'generator.content_channels'", ">= 0"]),
    ("generator.upsample_norm=bn", ["'generator.upsample_norm'", "in, ln, none"]),
    ("discriminator.pad_type=circular", ["'discriminator.pad_type'", "reflect"]),
    ("discriminator.scales=0", ["'discriminator.scales'"]),
    ("loss.ssim_scales=6", ["'loss.ssim_scales'", "1..5"]),
    ("loss.cyc=-10", ["'loss.cyc'", ">= 0"]),
    ("method.vc_kind=cosine", ["'method.vc_kind'", "angle, l1"]),
    ("optim.lr_tex=.nan", ["'optim.lr_tex'", "nan"]),
    ("optim.lr_net=0", ["'optim.lr_net'", "> 0"]),
    ("optim.beta1=1.5", ["'optim.beta1'", "[0, 1)"]),
    ("optim.weight_decay=-1e-4", ["'optim.weight_decay'"]),
    ("data.min_overlap=1.5", ["'data.min_overlap'", "[0, 1]"]),
    ("data.fov_x_deg=180", ["'data.fov_x_deg'", "170"]),
    ("data.workers=-2", ["'data.workers'", ">= -1"]),
    ("seed=-1", ["'seed'", ">= 0"]),
    ("device=tpu", ["'device'", "auto, cpu, cuda"]),
    # tiny: 2 scales; 6 layers need the coarse scale ceil(s / 2) >= 2^6, i.e. s >= 127 > 64
    ("discriminator.layers=6", ["discriminator.layers=6", "at least 127 px", "64x128"]),
    ("generator.downsamplings=6", ["generator.downsamplings=6", "at least 128 px"]),  # 64 / 2^6 = 1 row at the res blocks
])
def test_bad_config_values_are_refused_before_anything_is_written(capsys, tmp_path, inputs, setting, words):
    assert_error(train(capsys, tmp_path, [inputs[0]], inputs[1], "--set", setting), *words)
    assert not (tmp_path / "run").exists()


def test_no_real_images(capsys, tmp_path, inputs):
    empty = tmp_path / "empty"
    (empty / "sub").mkdir(parents=True)
    (empty / "notes.txt").write_text("no images here")
    assert_error(train(capsys, tmp_path, [inputs[0]], empty), "no real images", str(empty))
    assert_error(train(capsys, tmp_path, [inputs[0]], tmp_path / "missing"), "does not exist")


def test_unreadable_real_image(capsys, tmp_path, inputs):
    folder = tmp_path / "real"
    shutil.copytree(inputs[1], folder)
    bad = folder / "nested" / "broken.png"
    bad.parent.mkdir()
    bad.write_bytes(b"\x89PNG\r\n\x1a\n this is not a png")
    assert_error(train(capsys, tmp_path, [inputs[0]], folder), "cannot read real image", str(bad))


def test_views_of_a_scene_missing(capsys, tmp_path, tmp_path_factory, inputs):
    views = tmp_path / "views"
    shutil.copytree(views_dir(tmp_path_factory.getbasetemp(), inputs[0]), views)
    (views / "view_00002.npz").unlink()
    assert_error(train(capsys, tmp_path, [views], inputs[1]), "lists 4 views but 3 view files exist")


def test_views_folder_problems(capsys, tmp_path, tmp_path_factory, inputs):
    src = views_dir(tmp_path_factory.getbasetemp(), inputs[0])
    # views at 64x128 for a run at 96x128
    assert_error(train(capsys, tmp_path, [src], inputs[1], "--set", "data.height=96"), "are 64x128", "96x128")
    # its scene folder is gone
    views, scene = tmp_path / "views", tmp_path / "scene"
    shutil.copytree(inputs[0], scene)
    shutil.copytree(views_dir(tmp_path, scene, name="v"), views)
    shutil.rmtree(scene)
    assert_error(train(capsys, tmp_path, [views], inputs[1]), "names scene_dir", "not a scene folder")
    # a scene given twice, and a path that is neither
    assert_error(train(capsys, tmp_path, [inputs[0], inputs[0]], inputs[1]), "given twice")
    assert_error(train(capsys, tmp_path, [tmp_path / "nowhere"], inputs[1]), "does not exist")
    assert_error(train(capsys, tmp_path, [inputs[1]], inputs[1]), "neither a scene folder")


def test_run_folder_and_resume_errors(capsys, tmp_path, inputs):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "old.txt").write_text("x")
    assert_error(train(capsys, tmp_path, [inputs[0]], inputs[1]), "already holds other data")
    assert_error(run(capsys, "train", "--out", tmp_path / "fresh", "--resume"), "nothing to resume")
    assert_error(run(capsys, "train", "--out", tmp_path / "fresh", "--scenes", inputs[0], "--real", inputs[1]), "--preset")
    assert_error(run(capsys, "train", "--preset", "tiny", "--out", tmp_path / "fresh", "--real", inputs[1]), "no simulated scenes")


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_cuda_requested_without_cuda(capsys, tmp_path, inputs):
    assert_error(train(capsys, tmp_path, [inputs[0]], inputs[1], "--device", "cuda"), "no CUDA device")


def test_grey_and_rgba_images_train(capsys, tmp_path, inputs):
    real = real_dir(tmp_path, n=4, name="odd_modes", modes=("L", "LA", "RGBA", "P"))
    # and one frame smaller than the tiny preset's 64x128 crop: enlarged max(64/32, 128/48) = 2.67x
    Image.new("RGB", (48, 32), (120, 60, 50)).save(real / "small.png")
    code, err, out = train(capsys, tmp_path, [inputs[0]], real, "--iterations", "1", "--set", "method.vc=5",
                           "log_every=1", "--device", "cpu")
    assert code == 0, err
    assert "step 1" in out
    assert out.splitlines()[0].startswith("note: 1 of 5 real frames hold less than the 64x128 training crop "
                                          "and are enlarged (up to 2.7x)")
    saved = yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())
    assert saved["iterations"] == 1 and saved["method"] == {**saved["method"], "name": "ours", "vc": 5.0} and saved["device"] == "cpu"
    assert saved["generator"]["filters"] == 8  # the tiny preset
