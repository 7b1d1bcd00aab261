"""Stop a training run cleanly on SIGTERM or SIGINT.

Cluster schedulers send SIGTERM some time before they kill a job (SLURM pre-emption,
``scancel``), torchrun forwards it to its workers, and people press Ctrl-C (SIGINT). While
:class:`StopSignals` is active (the whole of ``Trainer.train``), either signal only records
its number: the step in progress finishes, all ranks agree at the step boundary to stop there
(engine/trainer.py), a checkpoint is written atomically and ``sim2real train`` exits with
``128 + signum`` (143 for SIGTERM, 130 for SIGINT) after printing the checkpoint's path.

Further signals are ignored (a note is printed): a worker of torchrun can get the same SIGTERM
twice, from the scheduler and from torchrun, and a second signal must not cut the checkpoint
write short. The handler never raises, so no signal can interrupt a write half way; the write
itself is a temporary file renamed over ``last.pt`` (engine/checkpoint.py), so even SIGKILL
leaves the previous complete checkpoint. A signal that the process inherited as ignored
(``SIG_IGN``, e.g. SIGINT of a shell's background job) stays ignored. DataLoader workers ignore
both signals (:func:`ignore_in_worker`): Ctrl-C reaches the whole process group, and a worker
that died of it would make the main process fail instead of stopping cleanly; the main process
shuts its workers down itself.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from typing import Iterator

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


def signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def exit_code(signum: int) -> int:
    """The shell's convention for a process ended by signal ``signum``."""
    return 128 + signum


class StopSignals:
    """Context manager: SIGTERM / SIGINT set :attr:`signum` (the first one received) instead of
    ending the process. Handlers are installed only in the main thread (where Python runs them)
    and the previous ones are restored on exit.

    Args:
        announce: write a one-line note to stderr when a signal arrives (rank 0 only).
    """

    def __init__(self, announce: bool = True):
        self.announce = announce
        self.signum = 0
        """The first stop signal received, 0 for none."""
        self._previous: dict[int, object] = {}

    def __enter__(self) -> "StopSignals":
        if threading.current_thread() is threading.main_thread():
            for s in STOP_SIGNALS:
                if signal.getsignal(s) is not signal.SIG_IGN:
                    self._previous[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        self._previous.clear()

    def _handle(self, signum, frame) -> None:
        if not self.signum:
            self.signum = signum
            note = f"sim2real: {signal_name(signum)} received: stopping after this step with a checkpoint\n"
        else:
            note = f"sim2real: {signal_name(signum)} received again: ignored, already stopping with a checkpoint\n"
        if self.announce:
            try:  # os.write, not print: a handler may run while the main thread is inside print
                os.write(2, note.encode())
            except OSError:
                pass


class Terminated(BaseException):
    """SIGTERM, raised in the main thread while :func:`sigterm_raises` is active."""


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """Within this block SIGTERM raises :class:`Terminated` in the main thread, as Ctrl-C raises
    KeyboardInterrupt, instead of ending the process where it stands: a command stopped by a
    scheduler or ``kill`` unwinds and removes its temporary outputs (a translation's hidden
    folder of gigabytes) on the way out. :class:`StopSignals` takes over while a run trains and
    restores this after. An inherited ``SIG_IGN`` stays; off the main thread nothing changes."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGTERM) is signal.SIG_IGN:
        yield
        return

    def terminate(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a second one must not cut the clean-up short
        raise Terminated

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def ignore_in_worker() -> None:
    """For DataLoader workers: leave stopping to the main process."""
    for s in STOP_SIGNALS:
        signal.signal(s, signal.SIG_IGN)
