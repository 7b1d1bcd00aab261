"""``sim2real train ... --resume``: the run's own command with ``--resume`` appended continues
it; flags that conflict with the checkpoint are refused (all named, nothing written);
``--out RUN --resume --set ...`` changes fields and says so. One writer per run folder: a second
process is refused with the holder's pid and host, and a lock left by a killed process
(SIGKILL) blocks nobody."""

import hashlib
import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from train_data import child_env

from sim2real.cli.main import main
from sim2real.engine.checkpoint import load_checkpoint
from sim2real.engine.runlock import LOCK_NAME
from sim2real.presets import preset



def command(scenes, real, out, *extra):
    """The run's command as a person types it (the --set value is not the preset's)."""
    return ["train", "--preset", "tiny", "--scenes", str(scenes), "--real", str(real), "--out", str(out),
            "--device", "cpu", "--set", "method.vc=5", "image_every=1000", "--no-progress", *extra]


@pytest.fixture(scope="module")
def base_run(train_inputs, tmp_path_factory):
    out = tmp_path_factory.mktemp("resume") / "run"
    assert main(command(*train_inputs, out, "--iterations", "2")) == 0
    return out


@pytest.fixture
def run_dir(base_run, tmp_path):
    """A copy of a 2-step run (its checkpoint names the shared inputs by absolute path)."""
    out = tmp_path / "run"
    shutil.copytree(base_run, out)
    return out


def cli(capsys, argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_error_line(err: str) -> str:
    lines = [l for l in err.splitlines() if l.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def snapshot(folder: Path) -> dict:
    """Every file under ``folder``: size, mtime and content hash."""
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns, hashlib.sha256(p.read_bytes()).hexdigest())
            for p in sorted(folder.rglob("*")) if p.is_file()}


def steps_logged(out: Path) -> list[int]:
    return [json.loads(l)["step"] for l in (out / "metrics.jsonl").read_text().splitlines()]


def test_the_runs_own_command_with_resume_continues(capsys, train_inputs, run_dir):
    scenes, real = train_inputs
    code, out, err = cli(capsys, command(scenes, real, run_dir, "--iterations", "4", "--checkpoint-every", "3", "--resume"))
    assert code == 0, err
    assert "changes" not in out and "step 4" in out
    last = run_dir / "checkpoints" / "last.pt"
    state = load_checkpoint(last)
    assert state["step"] == 4 and state["config"]["method"]["vc"] == 5.0 and state["config"]["checkpoint_every"] == 3
    # the run's config.yaml instead of the preset (with --set and --device left out: it holds them)
    code, out, err = cli(capsys, ["train", "--config", run_dir / "config.yaml", "--scenes", scenes, "--real", real,
                                  "--out", run_dir, "--iterations", "5", "--resume", "--no-progress"])
    assert code == 0, err
    assert load_checkpoint(last)["step"] == 5
    assert steps_logged(run_dir) == [2, 4, 5]  # log_every is 5 in tiny: each run logs its last step


def test_conflicting_flags_are_refused_naming_each_key(capsys, train_inputs, run_dir, tmp_path):
    scenes, real = train_inputs
    other_real = shutil.copytree(real, tmp_path / "other_real")
    before = snapshot(run_dir)
    argv = ["train", "--preset", "tiny", "--scenes", scenes, "--real", other_real, "--out", run_dir, "--device", "auto",
            "--set", "method.vc=7", "seed=3", "image_every=1000", "--iterations", "9", "--resume", "--no-progress"]
    code, _, err = cli(capsys, argv)
    assert code == 2
    line = one_error_line(err)
    assert "method.vc: 5.0 in the checkpoint, 7.0 here" in line
    assert "seed: 0 in the checkpoint, 3 here" in line
    assert "device: 'cpu' in the checkpoint, 'auto' here" in line
    assert f"--real: '{Path(real).resolve()}' in the checkpoint, '{other_real.resolve()}' here" in line, line
    assert line.count(" in the checkpoint, ") == 4, line  # iterations may change; nothing else differs
    # the same command without the run's --set: the preset's value would replace it silently
    code, _, err = cli(capsys, ["train", "--preset", "tiny", "--scenes", scenes, "--real", real, "--out", run_dir,
                                "--device", "cpu", "--set", "image_every=1000", "--resume", "--no-progress"])
    assert code == 2
    line = one_error_line(err)
    assert f"method.vc: 5.0 in the checkpoint, {preset('tiny').method.vc} here" in line
    assert line.count(" in the checkpoint, ") == 1
    # another preset
    code, _, err = cli(capsys, ["train", "--preset", "small", "--out", run_dir, "--resume", "--no-progress"])
    assert code == 2
    line = one_error_line(err)
    tiny, small = preset("tiny").generator.filters, preset("small").generator.filters
    assert tiny != small and f"generator.filters: {tiny} in the checkpoint, {small} here" in line
    assert snapshot(run_dir) == before  # nothing in the run folder changed


def test_resume_without_preset_changes_fields_and_says_so(capsys, run_dir):
    code, out, err = cli(capsys, ["train", "--out", run_dir, "--resume", "--iterations", "3", "--set", "log_every=1",
                                  "--no-progress"])
    assert code == 0, err
    assert f"resuming {run_dir} at step 2 with changes: log_every {preset('tiny').log_every} -> 1" in out
    assert yaml.safe_load((run_dir / "config.yaml").read_text())["log_every"] == 1
    state = load_checkpoint(run_dir / "checkpoints" / "last.pt")
    assert state["step"] == 3 and state["config"]["log_every"] == 1 and state["config"]["method"]["vc"] == 5.0


HOLDER = ("import sys, time; from sim2real.engine.runlock import RunLock; lock = RunLock(sys.argv[1]).acquire(); "
          "print('locked', flush=True); time.sleep(600)")


def test_one_writer_per_run_and_a_killed_holder_blocks_nobody(capsys, run_dir):
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(run_dir)], stdout=subprocess.PIPE, text=True,
                              env=child_env())
    try:
        assert holder.stdout.readline().strip() == "locked"
        before = snapshot(run_dir)
        code, _, err = cli(capsys, ["train", "--out", run_dir, "--resume", "--iterations", "3", "--no-progress"])
        assert code == 2
        line = one_error_line(err)
        assert f"pid {holder.pid} on {socket.gethostname()}" in line and str(run_dir) in line
        assert snapshot(run_dir) == before  # the refused process wrote nothing
    finally:
        holder.kill()  # SIGKILL: no chance to unlock; the kernel drops the lock
        holder.wait()
        holder.stdout.close()
    assert holder.returncode == -9
    assert (run_dir / LOCK_NAME).read_text().split()[0] == str(holder.pid)  # the dead holder's pid is still there
    code, out, err = cli(capsys, ["train", "--out", run_dir, "--resume", "--iterations", "3", "--no-progress"])
    assert code == 0, err
    assert load_checkpoint(run_dir / "checkpoints" / "last.pt")["step"] == 3
    assert (run_dir / LOCK_NAME).read_text() == ""  # released at the end


def test_lock_in_one_process(tmp_path):
    from sim2real.engine.runlock import RunLock
    from sim2real.errors import UserError

    with RunLock(tmp_path) as first:
        assert first.held and (tmp_path / LOCK_NAME).read_text().split()[0] == str(os.getpid())
        with pytest.raises(UserError, match=f"pid {os.getpid()} on "):
            RunLock(tmp_path).acquire()  # flock: a second open file description conflicts, even in-process
    assert not first.held
    RunLock(tmp_path).acquire().release()
