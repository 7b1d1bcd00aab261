"""Checkpoints: complete and atomic; a resumed run reproduces the uninterrupted one exactly
(CPU, deterministic mode), and a run killed with SIGKILL resumes from its last checkpoint."""

import os
import signal
import subprocess
import sys
import time

import pytest
import torch
from train_data import child_env, real_dir, scene_dir, tiny_config

from sim2real.engine.checkpoint import load_checkpoint, mismatch, read_torch_file, save_checkpoint
from sim2real.engine.trainer import Trainer
from sim2real.errors import UserError



@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    base = tmp_path_factory.getbasetemp()
    return scene_dir(base, 11), real_dir(base)


def _run(trainer):
    losses = {}
    trainer.hooks.append(lambda step, values: losses.__setitem__(step, values))
    trainer.train()
    return losses


def _assert_same_state(a: dict, b: dict, where=""):
    assert a.keys() == b.keys(), where
    for k in a:
        if isinstance(a[k], dict):
            _assert_same_state(a[k], b[k], f"{where}/{k}")
        elif isinstance(a[k], torch.Tensor):
            assert torch.equal(a[k], b[k]), f"{where}/{k}"
        elif isinstance(a[k], list):
            assert len(a[k]) == len(b[k])
        else:
            assert a[k] == b[k], f"{where}/{k}"


def test_resume_reproduces_uninterrupted_losses(tmp_path, inputs):
    scenes, real = inputs
    # L_vc switches on at step 4, after the resume point: the release never turned it back on
    cfg = tiny_config(iterations=6, checkpoint_every=3, keep_checkpoints="true", deterministic="true",
                      method__vc_start=4, log_every=1, image_every=100)
    full = _run(Trainer(cfg, [scenes], real, tmp_path / "a", progress=False))
    assert sorted(full) == list(range(6))
    mid = tmp_path / "a" / "checkpoints" / "step_0000003.pt"
    state = load_checkpoint(mid)
    assert state["step"] == 3
    assert state["loss_schedule"]["vc_weight"] == 0.0
    assert {"net", "tex", "dis"} == set(state["optimizers"]) == set(state["schedulers"])
    assert any(k.startswith("textures.") for k in state["gen"])
    assert state["optimizers"]["tex"]["state"], "texture optimiser state must be saved"

    resumed_trainer = Trainer(cfg, None, None, tmp_path / "b", resume=mid, progress=False)
    assert resumed_trainer.step == 3
    resumed = _run(resumed_trainer)
    assert sorted(resumed) == [3, 4, 5]
    for step in (3, 4, 5):
        assert resumed[step] == full[step], step  # bit-exact, every named term
    assert "gen/vc" not in resumed[3] and resumed[4]["gen/vc"] > 0
    end_a = load_checkpoint(tmp_path / "a" / "checkpoints" / "last.pt")
    end_b = load_checkpoint(tmp_path / "b" / "checkpoints" / "last.pt")
    for key in ("gen", "dis", "optimizers", "schedulers"):
        _assert_same_state(end_a[key], end_b[key], key)
    assert end_b["step"] == 6 and end_b["loss_schedule"]["vc_weight"] == 20.0


def test_checkpoint_write_is_atomic(tmp_path):
    path = tmp_path / "ck" / "last.pt"
    state = {"format": "sim2real-train/1", "step": 1, "x": torch.arange(5)}
    save_checkpoint(path, state)
    save_checkpoint(path, {**state, "step": 2})
    assert load_checkpoint(path)["step"] == 2
    assert os.listdir(path.parent) == ["last.pt"]  # no temporary left behind


def _load_error(module: torch.nn.Module, state: dict) -> RuntimeError:
    with pytest.raises(RuntimeError) as e:
        module.load_state_dict(state)
    return e.value


def test_mismatch_names_the_first_keys_and_the_shapes_in_one_line():
    lin = torch.nn.Linear(3, 2)  # weight (2, 3), bias (2,)
    e = _load_error(lin, {"weight": torch.zeros(3, 3), "bias": torch.zeros(2), "extra": torch.zeros(1)})
    assert mismatch(e) == "unexpected extra; weight has shape [3, 3] in the file, [2, 3] here"
    seq = torch.nn.Sequential(*[torch.nn.Linear(1, 1) for _ in range(3)])  # 6 keys: 0.weight ... 2.bias
    e = _load_error(seq, {"0.weight": torch.zeros(1, 1)})
    assert mismatch(e) == "missing 0.bias, 1.weight, 1.bias, ... (5 in all)"
    assert mismatch(KeyError("gen")) == "'gen'"  # any other error: its first line


def test_read_torch_file_says_in_one_line_why_a_file_cannot_be_read(tmp_path):
    good = {"w": torch.arange(3)}
    torch.save(good, tmp_path / "zip.pt")
    torch.save(good, tmp_path / "legacy.pt", _use_new_zipfile_serialization=False)  # torch < 1.6's format
    for name in ("zip.pt", "legacy.pt"):
        assert torch.equal(read_torch_file(tmp_path / name, name, "weights")["w"], good["w"])
    blob = (tmp_path / "zip.pt").read_bytes()
    (tmp_path / "cut.pt").write_bytes(blob[: len(blob) // 2])
    (tmp_path / "text.pt").write_text("not a checkpoint\n")
    torch.save({"w": torch.arange(3), "when": __import__("datetime").date(2026, 1, 1)}, tmp_path / "object.pt")
    expected = {"cut.pt": "a damaged or incomplete archive (a truncated copy?)",
                "text.pt": "not a file written by torch.save",
                "object.pt": "it holds objects other than tensors and plain containers, which are not loaded (for safety)"}
    for name, why in expected.items():
        with pytest.raises(UserError) as e:
            read_torch_file(tmp_path / name, tmp_path / name, "weights")
        assert str(e.value) == f"cannot read weights {tmp_path / name}: {why}"
    with pytest.raises(UserError) as e:
        load_checkpoint(tmp_path / "text.pt")
    assert str(e.value) == f"cannot read checkpoint {tmp_path / 'text.pt'}: not a file written by torch.save"


@pytest.mark.parametrize("method", ["ours", "ssim_munit"])  # the paper's method and a baseline
def test_kill_9_then_resume(tmp_path, inputs, method):
    scenes, real = inputs
    out = tmp_path / "run"
    env = child_env()
    cmd = [sys.executable, "-m", "sim2real.cli.main", "train", "--preset", "tiny", "--method", method, "--scenes",
           str(scenes), "--real", str(real), "--out", str(out), "--device", "cpu", "--no-progress"]
    proc = subprocess.Popen(cmd + ["--iterations", "100000", "--checkpoint-every", "4"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    last, metrics = out / "checkpoints" / "last.pt", out / "metrics.jsonl"
    try:
        # kill once the step-4 checkpoint exists and step 5 (past it) has been logged (log_every 5)
        deadline = time.time() + 90
        while time.time() < deadline and not (metrics.is_file() and '"step": 5' in metrics.read_text()):
            assert proc.poll() is None, proc.stderr.read().decode()
            time.sleep(0.02)
        assert last.is_file() and load_checkpoint(last)["step"] >= 4  # readable: replaced atomically
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    state = load_checkpoint(last)
    assert state["step"] >= 4 and state["step"] % 4 == 0
    target = state["step"] + 2
    done = subprocess.run(cmd[:4] + ["--out", str(out), "--resume", "--iterations", str(target), "--no-progress"],
                          env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert load_checkpoint(last)["step"] == target and load_checkpoint(last)["method"] == method
    assert f"step {target}" in done.stdout
    # what the killed run logged beyond its checkpoint was dropped on resume: no repeated steps
    import json

    steps = [json.loads(l)["step"] for l in (out / "metrics.jsonl").read_text().splitlines()]
    assert steps == sorted(set(steps)) and steps[-1] == target
