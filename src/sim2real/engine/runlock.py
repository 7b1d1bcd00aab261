"""One writer per run folder: an advisory lock held for as long as a process writes to it.

``RUN/train.lock`` is locked with ``fcntl.flock`` (exclusive, non-blocking) and holds the
holder's ``PID HOST``. A second ``sim2real train`` on the same folder finds the lock taken and
is refused with that PID and host; the file itself is never deleted (deleting a lock file
races with a process that has just opened it). The kernel drops the lock when its holder
dies, even by SIGKILL, so a lock left by a killed run blocks nobody: the PID written in the
file is only read while the lock is held.

Under DDP only rank 0 writes to the run folder, so only rank 0 takes the lock
(:func:`take_run_folder`, called by engine/trainer.py); the others wait for its verdict. A
forked DataLoader worker inherits the descriptor: :func:`close_inherited` closes the child's
copy (never ``LOCK_UN``, which would release the parent's lock). Where ``fcntl`` is missing
(Windows) the lock is a no-op; where the file system refuses locks (some network file systems)
a warning is printed and the run goes on unlocked.
"""

from __future__ import annotations

import errno
import os
import socket
import sys
import weakref
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows: not a target, but keep the package importable
    fcntl = None

from sim2real.data.real import INDEX as REAL_INDEX
from sim2real.engine.checkpoint import stamp
from sim2real.errors import UserError, reason
from sim2real.fileio import prepare_output_dir

LOCK_NAME = "train.lock"
_HELD: "weakref.WeakSet[RunLock]" = weakref.WeakSet()  # locks this process holds (see close_inherited)


def holder_of(path: str | os.PathLike) -> str:
    """``pid N on HOST`` as written by the lock's holder, or a phrase saying it is unknown."""
    try:
        text = Path(path).read_text().split()
    except OSError:
        text = []
    if len(text) >= 2 and text[0].isdigit():
        return f"pid {text[0]} on {text[1]}"
    return "a process that has not written its pid yet"


class RunLock:
    """An exclusive lock on ``folder/train.lock``; :meth:`release` (or process exit) frees it."""

    def __init__(self, folder: str | os.PathLike):
        self.path = Path(folder) / LOCK_NAME
        self._fd: int | None = None
        self._pid = 0  # the process that took it: a forked copy of this object must not unlock

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> "RunLock":
        """Take the lock or raise a UserError naming the process that holds it."""
        if fcntl is None or self._fd is not None:
            return self
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)  # not inherited across exec
        except OSError as e:
            raise UserError(f"cannot open the run lock {self.path}: {reason(e)}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise UserError(f"run folder {self.path.parent} is in use by another sim2real process "
                                f"({holder_of(self.path)}); wait for it to end or stop it") from None
            print(f"sim2real: warning: cannot lock {self.path} ({reason(e)}); this file system does not "
                  "support locks, so nothing stops a second process from writing to the run", file=sys.stderr)
            return self
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()} {socket.gethostname()}\n".encode(), 0)
        self._fd, self._pid = fd, os.getpid()
        _HELD.add(self)
        return self

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is None:
            return
        _HELD.discard(self)
        try:
            if self._pid == os.getpid():  # in a forked child only the copy of the descriptor is closed
                os.ftruncate(fd, 0)  # no stale pid for a reader to show
                fcntl.flock(fd, fcntl.LOCK_UN)
        except OSError:
            pass
        finally:
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> "RunLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()

    def __del__(self) -> None:
        try:
            self.release()
        except Exception:
            pass


def close_inherited() -> None:
    """In a forked child: close the copies of this process's lock descriptors (the parent keeps
    its locks; the child must not keep them alive after the parent dies)."""
    for lock in list(_HELD):
        fd, lock._fd = lock._fd, None
        if fd is not None:
            try:
                os.close(fd)
            except OSError:
                pass
    _HELD.clear()


def remove_if_only_lock(out: Path) -> None:
    """Remove a run folder that holds nothing but its lock file (a fresh run that never started)
    and the index of its real folder."""
    try:
        if {p.name for p in out.iterdir()} <= {LOCK_NAME, REAL_INDEX}:
            (out / REAL_INDEX).unlink(missing_ok=True)
            (out / LOCK_NAME).unlink(missing_ok=True)
            out.rmdir()
    except OSError:
        pass


def take_run_folder(out: Path, lock: RunLock, state: dict | None, resume) -> None:
    """Lock the run folder ``out`` with ``lock`` (rank 0). A fresh run (``state`` None) needs it
    empty (checked before the lock is created in it, and again under the lock); a resumed run
    needs its checkpoint ``resume`` unchanged since ``state`` was read from it (another process
    may have written it in between)."""
    if state is None:
        prepare_output_dir(out)
    else:  # resuming into another folder (Trainer(resume=...) from code) starts it
        out.mkdir(parents=True, exist_ok=True)
    lock.acquire()
    try:
        if state is None:
            prepare_output_dir(out, allowed=(LOCK_NAME,))
        elif resume is not None and stamp(resume) != state.get("stamp"):
            raise UserError(f"checkpoint {resume} was rewritten by another process while this one started; "
                            "run the command again")
    except BaseException:
        lock.release()
        raise
