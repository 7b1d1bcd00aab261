"""Stopping cleanly: SIGTERM / SIGINT to a real training process finish the step in progress,
write a checkpoint of exactly that step, print its path and exit with 128 + signum; the run
resumes from there. A second signal while that checkpoint is written changes nothing."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from train_data import child_env, tiny_config

from sim2real.cli.main import main
from sim2real.engine import checkpoint as ckpt
from sim2real.engine.trainer import Trainer

# the CLI with default dispositions of both signals (a shell's background job inherits SIGINT ignored)
CHILD = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
         "signal.signal(signal.SIGTERM, signal.SIG_DFL); from sim2real.cli.main import main; sys.exit(main(sys.argv[1:]))")
TIMEOUT = 180  # seconds; generous for a loaded 2-core machine


def train_args(scenes, real, out, *extra):
    return ["train", "--preset", "tiny", "--scenes", str(scenes), "--real", str(real), "--out", str(out),
            "--device", "cpu", "--iterations", "100000", "--checkpoint-every", "1000", "--no-progress",
            "--set", "log_every=1", "image_every=100000", "keep_checkpoints=true", *extra]


def logged_steps(out: Path) -> list[int]:
    path = out / "metrics.jsonl"
    if not path.is_file():
        return []
    steps = []
    for line in path.read_text().splitlines():
        try:
            steps.append(json.loads(line)["step"])
        except ValueError:  # a line being written
            pass
    return steps


class Child:
    """The CLI in a child process, its stdout and stderr in files."""

    def __init__(self, folder: Path, argv: list[str], **popen):
        folder.mkdir(parents=True, exist_ok=True)
        self.folder, self.argv = folder, argv
        self.out = Path(argv[argv.index("--out") + 1])
        with open(folder / "stdout.txt", "w") as o, open(folder / "stderr.txt", "w") as e:
            env = child_env(OMP_NUM_THREADS="1")  # two children share 2 cores
            self.proc = subprocess.Popen([sys.executable, "-c", CHILD, *argv], env=env, stdout=o, stderr=e, **popen)

    def stderr(self) -> str:
        return (self.folder / "stderr.txt").read_text()

    def wait_for_step(self, min_step: int) -> int:
        """Poll the child's log until it has completed ``min_step``; returns the last step logged."""
        deadline = time.monotonic() + TIMEOUT
        while not any(s >= min_step for s in logged_steps(self.out)):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"the child never reached step {min_step}: {self.stderr()}")
            time.sleep(0.05)
        return max(logged_steps(self.out))

    def finish(self) -> tuple[str, str]:
        try:
            self.proc.wait(timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            pytest.fail("the child did not stop after the signal")
        return (self.folder / "stdout.txt").read_text(), self.stderr()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()


def assert_stopped_with_checkpoint(out: Path, stdout: str, seen: int, name: str) -> int:
    """The checkpoint holds the last completed step (the last one logged), which is at least the
    step seen before the signal and past the last periodic checkpoint (step 0 here)."""
    last = out / "checkpoints" / ckpt.LAST
    state = ckpt.load_checkpoint(last)
    done = logged_steps(out)[-1]
    assert state["step"] == done >= seen > 0
    assert f"training stopped by {name} at step {done}; checkpoint {last}" in stdout, stdout
    # keep_checkpoints: a copy of every checkpoint written, so none other than step 0 and the stop
    assert sorted(p.name for p in last.parent.iterdir()) == [ckpt.LAST, ckpt.step_name(0), ckpt.step_name(done)]
    return done


def test_sigterm_and_ctrl_c_stop_after_the_step_with_a_checkpoint(capsys, train_inputs, tmp_path, one_torch_thread):
    """Two training children at once (their start-up, mostly imports, overlaps): SIGTERM to one;
    SIGINT to the other's whole process group, as a terminal's Ctrl-C, with a DataLoader worker
    that must leave the stop to the main process. Then the SIGTERM run resumes."""
    scenes, real = train_inputs
    term = Child(tmp_path / "term", train_args(scenes, real, tmp_path / "term" / "run"))
    ctrl_c = Child(tmp_path / "int", train_args(scenes, real, tmp_path / "int" / "run", "data.workers=1"),
                   start_new_session=True)
    try:
        seen_int = ctrl_c.wait_for_step(3)
        os.killpg(ctrl_c.proc.pid, signal.SIGINT)
        term.wait_for_step(3)
        # a second writer on a running run is refused, naming the child
        code = main(["train", "--out", str(term.out), "--resume", "--no-progress"])
        err = capsys.readouterr().err
        assert code == 2 and f"in use by another sim2real process (pid {term.proc.pid} on {socket.gethostname()})" in err
        seen_term = max(logged_steps(term.out))
        term.proc.send_signal(signal.SIGTERM)
        (out_term, err_term), (out_int, err_int) = term.finish(), ctrl_c.finish()
    finally:
        term.kill()
        ctrl_c.kill()
    assert term.proc.returncode == 128 + signal.SIGTERM, err_term
    assert "SIGTERM received: stopping after this step" in err_term
    done = assert_stopped_with_checkpoint(term.out, out_term, seen_term, "SIGTERM")
    assert ctrl_c.proc.returncode == 128 + signal.SIGINT, err_int
    assert "Traceback" not in err_int and "error" not in err_int, err_int
    assert_stopped_with_checkpoint(ctrl_c.out, out_int, seen_int, "SIGINT")

    # the same command with --resume appended (and a new --iterations) continues from that step
    argv = list(term.argv)
    argv[argv.index("--iterations") + 1] = str(done + 2)
    assert main(argv + ["--resume"]) == 0, capsys.readouterr().err
    assert ckpt.load_checkpoint(term.out / "checkpoints" / ckpt.LAST)["step"] == done + 2
    assert logged_steps(term.out) == list(range(1, done + 3))  # every step once: nothing lost, nothing repeated


def test_a_second_signal_during_the_checkpoint_write_is_ignored(train_inputs, tmp_path, monkeypatch):
    scenes, real = train_inputs
    cfg = tiny_config(iterations=50, checkpoint_every=1000, image_every=1000, log_every=1000)
    trainer = Trainer(cfg, [scenes], real, tmp_path / "run", progress=False)
    received = []
    recorder = lambda signum, frame: received.append(signum)  # noqa: E731 (in place of the trainer's, were it missing)
    previous = signal.signal(signal.SIGINT, recorder)
    real_fsync, during_write = os.fsync, []

    def fsync_with_signal(fd):
        if trainer.step == 3:  # the stop checkpoint: its temporary file is written, not yet renamed
            during_write.append(fd)
            os.kill(os.getpid(), signal.SIGINT)
        return real_fsync(fd)

    def first_signal(step, values):
        if step == 2:
            os.kill(os.getpid(), signal.SIGINT)

    trainer.hooks.append(first_signal)
    monkeypatch.setattr(os, "fsync", fsync_with_signal)
    try:
        last = trainer.train()
        restored = signal.getsignal(signal.SIGINT)
    finally:
        monkeypatch.undo()
        signal.signal(signal.SIGINT, previous)
        trainer.close()
    assert received == [] and restored is recorder  # the trainer took every SIGINT, then put the handler back
    assert during_write, "the second signal was not sent during the write"
    assert trainer.stopped_by == signal.SIGINT and trainer.step == 3
    assert ckpt.load_checkpoint(last)["step"] == 3
    assert sorted(p.name for p in last.parent.iterdir()) == [ckpt.LAST, ckpt.step_name(0)]  # no temporary left
