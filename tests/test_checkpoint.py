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

from sim2real.engine.checkpoint import load_checkpoint, save_checkpoint
from sim2real.engine.trainer import Trainer



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
