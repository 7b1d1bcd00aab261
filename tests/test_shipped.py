"""The trained demo model shipped in the package (sim2real/shipped): its size, its scenes, its
frames against the values stored beside it, and the demo that uses it."""

import json

import numpy as np
import pytest
import torch
import yaml

from sim2real import shipped
from sim2real.cli.main import main
from sim2real.config import differences, override, to_dict
from sim2real.engine import checkpoint as ckpt
from sim2real.errors import UserError
from sim2real.inference.model import load_run
from sim2real.presets import config_from_dict, load_config, preset
from sim2real.scene.procedural import generate_scene


@pytest.fixture(scope="module")
def record():
    return shipped.load_record()


@pytest.fixture(scope="module")
def scene_dirs(record, tmp_path_factory):
    root = tmp_path_factory.mktemp("shipped_scenes")
    return [generate_scene(record["scene_seed"] + k).save(root / f"sim_{k}") for k in range(record["scenes"])]


def test_shipped_checkpoint_is_small_and_loads_as_fp32(record):
    path = shipped.model_path()
    assert path.stat().st_size <= 40 * 2**20
    raw = torch.load(path, weights_only=True)
    assert raw["step"] == record["steps"] > 0
    assert "optimizers" not in raw and "rng" not in raw  # an inference checkpoint
    big = [v for v in raw["gen"].values() if v.numel() >= shipped.HALF_MIN]
    assert big and all(v.dtype == torch.float16 for v in big)
    state = ckpt.load_checkpoint(path)
    assert all(v.dtype != torch.float16 for part in ("gen", "dis") for v in state[part].values())
    # the fp32 values are the stored fp16 values, exactly
    k = next(k for k, v in raw["gen"].items() if v.numel() >= shipped.HALF_MIN)
    assert torch.equal(state["gen"][k], raw["gen"][k].float())


def test_generated_scenes_match_the_recorded_geometry_hash(record, scene_dirs):
    shipped.check_scenes(record, scene_dirs)  # raises on a mismatch
    assert shipped.scene_hashes(scene_dirs) == record["scene_hashes"]


def test_a_scene_hashes_the_same_in_memory_and_after_save_and_load(record, scene_dirs):
    """The demo checks the scenes it generates before writing them; the record was made from
    saved folders (float32 vertices)."""
    fresh = [generate_scene(record["scene_seed"] + k) for k in range(record["scenes"])]
    assert shipped.scene_hashes(fresh) == shipped.scene_hashes(scene_dirs) == record["scene_hashes"]


def test_a_changed_scene_is_refused_with_one_clear_line(record, scene_dirs, tmp_path):
    from sim2real.scene.scene import Scene

    scene = Scene.load(scene_dirs[1])
    scene.objects[0].mesh.vertices[0] += [0.05, 0.0, 0.0]  # 0.05 mm: above the hash's 0.01 mm rounding
    moved = scene.save(tmp_path / "moved")
    with pytest.raises(UserError) as e:
        shipped.check_scenes(record, [scene_dirs[0], moved])
    assert "geometry hash" in str(e.value) and str(moved) in str(e.value) and "\n" not in str(e.value)


def test_shipped_model_translates_the_demo_path_like_the_stored_values(record, scene_dirs):
    model = load_run(shipped.HERE, device="cpu", checkpoint=shipped.model_path())
    frames = shipped.reference_frames(model, scene_dirs[0], shipped.HERE / shipped.CHECK_TRAJECTORY)
    assert len(frames) == 2 == len(record["reference"]["frames"])
    for frame, stored in zip(frames, record["reference"]["frames"]):
        assert frame.shape == (record["height"], record["width"], 3)
        diff = np.abs(shipped.thumbnail(frame) - np.asarray(stored))  # 0..255 block means
        assert diff.max() <= 2.0 and diff.mean() <= 0.5, (diff.max(), diff.mean())
    # the two frames differ (the camera moved): the check can tell frames apart
    assert np.abs(np.asarray(record["reference"]["frames"][0]) - np.asarray(record["reference"]["frames"][1])).max() > 2.0


def test_demo_uses_the_shipped_model_end_to_end(tmp_path):
    out = tmp_path / "demo"
    code = main(["demo", "--out", str(out), "--frames", "3", "--real-images", "8", "--eval-views", "4",
                 "--seg-iterations", "5", "--device", "cpu"])
    assert code == 0
    info = json.loads((out / "demo.json").read_text())
    rec = shipped.load_record()
    # a model trained in stages counts the steps of all of them; its checkpoint, those of the last
    assert info["model"] == "shipped" and info["training_steps"] == (rec.get("trained") or {}).get("steps", rec["steps"])
    # the demo's run folder holds the shipped checkpoint, byte for byte
    assert (out / "run" / "checkpoints" / ckpt.LAST).read_bytes() == shipped.model_path().read_bytes()
    metrics = json.loads((out / info["metrics"]).read_text())
    assert metrics["run"]["step"] == rec["steps"]
    assert len(list((out / "video" / "frames").glob("*.png"))) == 3
    # the figure: rows a_ref, ceiling, the model; a label column and views 0, T/2, T-1, 0 revisited
    from PIL import Image

    w, h = Image.open(out / info["figure"]).size
    assert 5 * rec["width"] <= w < 5 * rec["width"] + 40 and 3 * rec["height"] <= h < 3 * rec["height"] + 40


def test_the_record_line_counts_the_steps_of_every_stage():
    rec = {"method": "ours", "height": 128, "width": 256, "steps": 2917}
    assert shipped.record_text(rec) == "ours at 128x256, 2917 training steps"
    rec["trained"] = {"steps": 8079, "minutes": 213.8, "machine": "one core"}
    assert shipped.record_text(rec) == ("ours at 128x256, 8079 training steps in all (2917 in its last stage), "
                                        "213.8 min on one core")


def test_demo_with_other_scenes_stops_before_writing_anything(tmp_path, capsys, monkeypatch):
    """A generator that no longer makes the shipped model's scenes: one line, exit 2, and no
    scenes or real images left behind in the output folder."""
    rec = dict(shipped.load_record())
    rec["scene_hashes"] = ["0" * 64] + rec["scene_hashes"][1:]
    monkeypatch.setattr(shipped, "load_record", lambda: rec)
    out = tmp_path / "demo"
    code = main(["demo", "--out", str(out), "--frames", "3", "--device", "cpu"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "geometry hash" in err and "procedural_0000" in err, err
    assert not any(out.rglob("*"))


@pytest.mark.parametrize("extra,words", [
    (["--seed", "5"], "add --train"),
    (["--minutes", "3"], "add --train"),
    (["--preset", "tiny"], "add --train"),
    (["--scenes", "1"], "add --train"),
])
def test_demo_without_train_refuses_training_flags_and_other_scenes(tmp_path, capsys, extra, words):
    code = main(["demo", "--out", str(tmp_path / "out"), *extra])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and words in err, err
    assert not (tmp_path / "out").exists()


def test_the_shipped_config_is_the_cpu_lines_preset_and_the_checkpoints():
    """``demo_model.yaml`` equals ``--preset cpu-lines`` key by key, and the configuration inside
    the checkpoint differs from it only where and how long the run went (``RUN_KEYS``)."""
    yaml_cfg = yaml.safe_load(shipped.config_path().read_text())
    assert yaml_cfg == to_dict(preset("cpu-lines"))
    inside = ckpt.load_checkpoint(shipped.model_path())["config"]
    differ = differences(config_from_dict(inside), config_from_dict(yaml_cfg))
    assert {k for k, _, _ in differ} <= set(shipped.RUN_KEYS), differ
    # the recipe keys that make it the line-net stage, read from the checkpoint itself
    assert inside["method"]["texture"]["init_lines"] == 1.0 and inside["method"]["tex_edges"] == 3.0
    assert inside["loss"]["edge_contrast"] == 0.08 and inside["generator"]["filters"] == 16
    assert shipped.load_record()["preset"] == "cpu-lines"


def test_packing_a_run_of_another_recipe_is_refused(tmp_path):
    """``pack`` writes the preset's YAML only for a run trained with it."""
    other = to_dict(override(preset("cpu-lines"), ["loss.edge_contrast=0.02", "device=cpu"]))
    with pytest.raises(UserError, match="differs in loss.edge_contrast$"):
        shipped.write_config(other, "cpu-lines", tmp_path)
    assert not (tmp_path / shipped.CONFIG).exists()
    shipped.write_config(to_dict(override(preset("cpu-lines"), ["device=cpu", "iterations=7"])), "cpu-lines", tmp_path)
    assert yaml.safe_load((tmp_path / shipped.CONFIG).read_text()) == to_dict(preset("cpu-lines"))


def test_resuming_the_shipped_checkpoint_is_refused(tmp_path, capsys):
    run = tmp_path / "run"
    shipped.install_run(run)
    code = main(["train", "--out", str(run), "--resume"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--init-from" in err and "Traceback" not in err, err


def test_init_from_shipped_starts_a_new_scene_from_the_shipped_networks(train_inputs, tmp_path, capsys):
    """``sim2real train --init-from shipped``: the shipped translator and discriminators (fp32),
    fresh textures for the user's own scene, and the shipped configuration (preset cpu-lines)
    except the keys the command overrides, each printed."""
    scene, real = train_inputs
    code = main(["train", "--set", "data.workers=0", "--scenes", str(scene), "--real", str(real), "--device", "cpu",
                 "--no-progress", "--iterations", "1", "--init-from", "shipped", "--out", str(tmp_path / "new")])
    out, err = capsys.readouterr()
    assert code == 0, err
    (line,) = [s for s in out.splitlines() if s.startswith("--init-from")]
    assert line == "--init-from shipped: its configuration, overridden: iterations 20000 -> 1, device 'auto' -> 'cpu', " \
                   "data.workers -1 -> 0", line
    written = load_config(tmp_path / "new" / "config.yaml")
    assert {k for k, _, _ in differences(preset("cpu-lines"), written)} == {"device", "iterations", "data.workers"}
    src = ckpt.load_checkpoint(shipped.model_path())
    step0 = ckpt.load_checkpoint(tmp_path / "new" / "checkpoints" / ckpt.step_name(0))
    assert step0["inputs"]["init_from"] == str(shipped.model_path())
    for part in ("gen", "dis"):
        moved = [k for k in src[part] if not k.startswith("textures.")]
        assert moved and all(torch.equal(step0[part][k], src[part][k]) for k in moved), part
    assert not any(k.startswith("textures.scene_procedural_0000") for k in step0["gen"])
