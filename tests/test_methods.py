"""Methods as plug-ins: the tagged config section, presets, the format-1 migration, a foreign
method run by the unchanged trainer and inference, and inference equal to the training forward
pass for every method preset."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch
import yaml
from toy_methods import ToyConfig, toy_methods  # noqa: F401  (fixture)
from train_data import resume_run, tiny_config, train_logged

from sim2real.config import override, save_yaml, to_dict
from sim2real.errors import UserError
from sim2real.methods import get_method
from sim2real.presets import METHOD_PRESETS, config_from_dict, load_config, method_config, preset


@pytest.mark.parametrize("name", sorted(METHOD_PRESETS))
def test_every_preset_round_trips_through_plain_yaml(tmp_path, name):
    cfg = preset("tiny", name)
    save_yaml(cfg, tmp_path / "c.yaml")
    raw = yaml.safe_load((tmp_path / "c.yaml").read_text())  # plain YAML: no Python tags
    assert raw["method"]["name"] == METHOD_PRESETS[name][0]
    back = load_config(tmp_path / "c.yaml")
    assert back == cfg and type(back.method) is type(cfg.method)


def test_presets_are_values_of_the_method_section():
    base = method_config("ours", "small")
    assert base.texture.size == 256 and base.vc_start == 2_000 and base.vc == 20.0  # size-dependent defaults
    assert dataclasses.replace(base, vc=0.0) == method_config("ours_no_vc", "small")
    assert dataclasses.replace(base, vc_kind="l1") == method_config("ours_l1_vc", "small")
    no_tex = method_config("ours_no_tex_vc", "small")
    assert no_tex.texture.features == 0 and no_tex.vc == 0.0 and no_tex.texture.size == 256


def test_format_1_configs_are_migrated():
    old = to_dict(preset("tiny"))
    section = old.pop("method")
    old["method"] = "ours_no_vc"  # the layout before methods had a section
    old["texture"] = section["texture"]
    old["loss"].update(vc=20.0, vc_start=5, vc_kind="l1")
    cfg = config_from_dict(old)
    assert type(cfg.method).name == "ours"
    assert (cfg.method.vc, cfg.method.vc_start, cfg.method.vc_kind) == (0.0, 5, "l1")
    assert cfg.method.texture.size == 64
    old["method"] = "ours_no_tex_vc"
    with pytest.raises(UserError, match="former method 'ours_no_tex_vc'"):
        config_from_dict(old)
    with pytest.raises(UserError, match="unknown method 'cyclegan'"):
        config_from_dict({**to_dict(preset("tiny")), "method": {"name": "cyclegan"}})


def test_the_former_noise_shape_key_is_migrated():
    d = to_dict(preset("tiny"))
    d["method"]["texture"].update(init_noise=0.7, init_noise_sigma=4.0, init_noise_shape="lines")
    t = config_from_dict(d).method.texture
    assert (t.init_noise, t.init_lines, t.init_lines_sigma) == (0.0, 0.7, 4.0)
    d["method"]["texture"].update(init_noise=0.7, init_noise_sigma=4.0, init_noise_shape="blobs")
    t = config_from_dict(d).method.texture
    assert (t.init_noise, t.init_noise_sigma, t.init_lines) == (0.7, 4.0, 0.0)
    d["method"]["texture"]["init_noise_shape"] = "dots"
    with pytest.raises(UserError, match="blobs or lines, got 'dots'"):
        config_from_dict(d)


# --- a method the project does not know: the trainer and inference must run it unchanged ---------


def test_a_foreign_method_trains_resumes_and_translates(toy_methods, train_inputs, tmp_path, procedural_caster):
    from sim2real.engine.checkpoint import load_checkpoint
    from sim2real.inference.model import load_run
    from sim2real.scene.trajectory import sample_poses

    scenes, real = train_inputs
    cfg = preset("tiny")
    cfg.method = ToyConfig(gain=3.0)
    cfg.iterations, cfg.checkpoint_every = 3, 3
    trainer, seen = train_logged(cfg, scenes, real, tmp_path / "run")
    assert sorted(seen) == [0, 1, 2]
    assert seen[2]["gen/total"] == pytest.approx(3.0 * seen[2]["gen/fit"], rel=1e-6)  # weighted by the method
    state = load_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt")
    assert state["method"] == "toy_plugin" and state["config"]["method"] == {"name": "toy_plugin", "gain": 3.0}
    # resume from the saved YAML-able config, two more steps
    resumed, start = resume_run(tmp_path / "run", 5)
    assert start == 3 and resumed.step == 5
    model = load_run(tmp_path / "run", "cpu")
    g = procedural_caster.render(sample_poses(procedural_caster, 1, 64, 128, 75.0, seed=3)[0])
    frame = model.translate_gbuffers(model.scenes[0], [g])[0]
    with torch.no_grad():
        want = model.method.translate_frames(model.gen, model.method.inference_batch([g], 0, torch.device("cpu")))
    want = ((want[0].clamp(-1, 1) + 1) * 127.5).round().to(torch.uint8).permute(1, 2, 0).numpy()
    np.testing.assert_array_equal(frame, want)


# --- inference equals the training forward pass, for every method preset -------------------------


@pytest.mark.parametrize("name", sorted(METHOD_PRESETS))
def test_inference_equals_the_training_forward_pass(name, request, tmp_path, procedural_caster):
    from sim2real.data.tensors import view_tensors
    from sim2real.engine.trainer import Trainer
    from sim2real.inference.model import load_run
    from sim2real.scene.trajectory import sample_poses

    cfg = tiny_config(name, iterations=2, checkpoint_every=2, image_every=100)
    # video methods train on real sequences
    video = get_method(cfg).data == "triplets"
    scenes, real = request.getfixturevalue("video_train_inputs" if video else "train_inputs")
    trainer = Trainer(cfg, [scenes], real, tmp_path / "run", progress=False)
    trainer.train()  # two real steps, so that the textures and networks are no longer at their init
    trainer.close()
    cams = sample_poses(procedural_caster, 2, 64, 128, 75.0, seed=9)
    gbuffers = [procedural_caster.render(c) for c in cams]
    # single frames; translate_gbuffers translates each view as a sequence start, so a
    # time-dependent method's training forward pass gets no previous frame here either
    batch = {**view_tensors(gbuffers, "i"), "real": torch.zeros(2, 3, 64, 128), "scene": [0, 0]}
    # A stochastic method's random draws (styles, noise) travel in its inference batch: the
    # training pass takes the draws that inference makes for each view (as the first frame of a
    # sequence, as translate_gbuffers translates unrelated views of a time-dependent method).
    parts = [trainer.method.inference_batch([g], 0, torch.device("cpu")) for g in gbuffers]
    batch.update({k: torch.cat([p[k] for p in parts]) for k in parts[0]
                  if torch.is_tensor(parts[0][k]) and k not in batch})
    if video and trainer.method.time_independent:
        # ReCycle trains on triplets only: b_hat is frame 0's translation (frames 1, 2 are other
        # views). A time-dependent method (OF-UNIT) takes single frames with no previous frame.
        batch = {**view_tensors(gbuffers, "0"), **view_tensors(gbuffers[::-1], "1"), **view_tensors(gbuffers[::-1], "2"),
                 **{f"real_{t}": torch.zeros(2, 3, 64, 128) for t in range(3)}, "scene": [0, 0]}
    with torch.no_grad():
        b_hat = trainer.method.translate(trainer.gen, batch, 0)["b_hat"]
    want = ((b_hat.clamp(-1, 1) + 1) * 127.5).round().to(torch.uint8).permute(0, 2, 3, 1).numpy()
    model = load_run(tmp_path / "run", "cpu")
    # the networks that --compile compiles are the ones translation runs, each as a whole module
    nets = model.method.inference_networks(model.gen)
    assert nets and all(any(n is m for m in model.gen.modules()) for n in nets)
    calls = [0] * len(nets)
    hooks = [n.register_forward_hook(lambda *a, k=k: calls.__setitem__(k, calls[k] + 1)) for k, n in enumerate(nets)]
    got = np.stack(model.translate_gbuffers(model.scenes[0], gbuffers, batch=2))
    for h in hooks:
        h.remove()
    assert all(c >= 1 for c in calls), calls
    # oneDNN may pick other kernels in eval/inference mode: at most one 8-bit level, on few pixels
    diff = np.abs(got.astype(int) - want.astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3, (diff.max(), (diff > 0).mean())
    assert got.std() > 1.0  # not a constant image


def test_init_from_carries_the_networks_to_new_scenes(train_inputs, tmp_path, capsys, monkeypatch):
    """``--init-from``: a trained run's translator and discriminators, fresh textures for other scenes."""
    import torch
    from train_data import scene_dir

    from sim2real.cli.main import main
    from sim2real.engine.checkpoint import load_checkpoint

    scenes, real = train_inputs
    trainer, _ = train_logged(tiny_config(iterations=2, checkpoint_every=2, image_every=100), scenes, real,
                              tmp_path / "src")
    other = scene_dir(tmp_path, 12)
    argv = ["train", "--scenes", str(other), "--real", str(real), "--device", "cpu", "--no-progress",
            "--iterations", "1", "--init-from", str(tmp_path / "src")]
    from sim2real.engine import checkpoint

    reads = []
    monkeypatch.setattr(checkpoint, "load_checkpoint",
                        lambda path, *a, _load=load_checkpoint, **k: reads.append(path) or _load(path, *a, **k))
    assert main([*argv, "--out", str(tmp_path / "new")]) == 0, capsys.readouterr().err
    assert len(reads) == 1  # the source checkpoint is read once, for its configuration and its weights
    monkeypatch.undo()
    # the source run's configuration, changed only by this command's flags, each printed
    assert f"--init-from {tmp_path / 'src'}: its configuration, overridden: iterations 2 -> 1, " \
           "device 'auto' -> 'cpu'" in capsys.readouterr().out
    assert to_dict(load_config(tmp_path / "new" / "config.yaml")) == to_dict(
        override(trainer.cfg, ["iterations=1", "device=cpu"]))
    src = load_checkpoint(tmp_path / "src" / "checkpoints" / "last.pt")
    step0 = load_checkpoint(tmp_path / "new" / "checkpoints" / "step_0000000.pt")
    assert step0["step"] == 0 and step0["inputs"]["init_from"].endswith("last.pt")
    for part in ("gen", "dis"):
        moved = [k for k in src[part] if not k.startswith("textures.")]
        assert moved and all(torch.equal(step0[part][k], src[part][k]) for k in moved), part
    # the new scene's texture starts fresh: flat per-class colours, as any new run's
    (new_tex,) = [v for k, v in step0["gen"].items() if k.startswith("textures.") and k.endswith(".texture")]
    assert new_tex.shape[0] == len(json.loads((other / "scene.json").read_text())["objects"])
    assert torch.equal(new_tex, new_tex[:, :1, :1, :1].expand_as(new_tex))
    # another architecture is refused in one line, naming a weight, and leaves no run folder
    code = main([*argv, "--out", str(tmp_path / "bad"), "--set", "generator.filters=16"])
    err = capsys.readouterr().err
    assert code == 2 and "does not fit this configuration" in err and "weight '" in err
    assert not (tmp_path / "bad").exists()
    code = main([*argv, "--out", str(tmp_path / "bad"), "--preset", "tiny", "--method", "ours_no_tex_vc"])
    assert code == 2 and "does not fit" in capsys.readouterr().err
