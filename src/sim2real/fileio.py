"""Atomic file writing: write to a temporary name in the same folder, then rename (files, and
whole output folders: :func:`staged_output_dir`); and reading a JSON file with one clear error
line.

A reader never sees a half-written file under the final name, even after kill -9.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import secrets
import shutil
import threading
from pathlib import Path
from typing import Iterator

import numpy as np
from PIL import Image

from sim2real.errors import UserError, reason


def _new_beside(path: Path, infix: str, suffix: str, folder: bool) -> Path:
    """Create a new empty file (or folder) of an unused name ``.NAME.INFIX<random>SUFFIX`` beside
    ``path``, with the permissions the process's umask gives any new file (0644, folders 0755,
    under the usual 022). :mod:`tempfile` would make them private (0600, 0700), and renamed into
    place the outputs would stay so: unreadable to the other users of a shared server, and to the
    host's user when the command ran in a container as another user."""
    for _ in range(100):
        tmp = path.parent / f".{path.name}.{infix}{secrets.token_hex(4)}{suffix}"
        try:
            if folder:
                os.mkdir(tmp, 0o777)  # the kernel applies the umask
            else:
                os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            if not path.parent.is_dir():
                raise
    raise FileExistsError(f"no unused temporary name beside {path}")


def temp_dir_beside(path: str | os.PathLike, infix: str = "") -> Path:
    """A new empty folder beside ``path`` (its parents made), to fill and then rename to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return _new_beside(path, infix, "", folder=True)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is renamed to ``path``."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _new_beside(path, "", suffix or path.suffix + ".tmp", folder=False)
    except (FileExistsError, NotADirectoryError):  # a file where a folder of the path should be
        blocker = next((q for q in path.parents if q.exists() and not q.is_dir()), path.parent)
        raise UserError(f"cannot write {path}: {blocker} is a file, not a folder") from None
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


_deferred: list[str] | None = None
"""Files written under :func:`deferred_fsync`, not yet flushed to disk."""
_deferred_lock = threading.Lock()


@contextlib.contextmanager
def deferred_fsync() -> Iterator[list[str]]:
    """Within this block :func:`atomic_write_bytes` (and the writers built on it) skips its
    per-file fsync and records the file instead; the block yields that list, for one
    :func:`fsync_files` of all of them at its end (or of the folder they are renamed into). For a
    command that writes thousands of small files into a folder it renames into place when
    complete (``sim2real translate``): each file is still atomic under its name, the folder as a
    whole becomes durable at once. Not nested; thread-safe (writer threads may record)."""
    global _deferred
    if _deferred is not None:
        raise RuntimeError("deferred_fsync blocks do not nest")
    _deferred = []
    try:
        yield _deferred
    finally:
        _deferred = None


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            if _deferred is None:
                f.flush()
                os.fsync(f.fileno())
    if _deferred is not None:
        with _deferred_lock:
            _deferred.append(str(path))


def link_or_copy(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Hard-link ``src`` to ``dst`` through a temporary name (an existing ``dst`` is replaced at
    once); copy where a link cannot be made (across file systems)."""
    with atomic_path(dst) as tmp:
        tmp.unlink()
        try:
            os.link(src, tmp)
        except OSError:
            shutil.copyfile(src, tmp)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj) -> None:
    atomic_write_text(path, json.dumps(obj, indent=2) + "\n")


def atomic_save_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray], compressed: bool = False,
                    durable: bool = True) -> None:
    """Write ``arrays`` as an ``.npz`` (numpy's zip of ``.npy`` files, every dtype kept bit for
    bit), straight into the temporary file. Uncompressed by default: deflate took 250 ms for a
    256x512 G-buffer (three times its ray casting) and saved 12 % of the bytes, because float32
    surface data barely compresses. ``durable`` flushes the file to disk (fsync) before the
    rename; scratch files can skip that."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            (np.savez_compressed if compressed else np.savez)(f, **arrays)
            if durable:
                f.flush()
                os.fsync(f.fileno())


def fsync_files(paths) -> None:
    """Flush files already written (and renamed) to disk, then their folders' entries: many files
    made durable at once, instead of one blocking fsync per file while it is written (a 4 MB view
    file's fsync took about as long as ray casting the view on the dev machine)."""
    paths = [os.path.abspath(p) for p in paths]
    for p in [*paths, *sorted({os.path.dirname(p) for p in paths})]:
        fd = os.open(p, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def atomic_write_image(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an 8- or 16-bit image (H x W, H x W x 3 RGB or H x W x 4 RGBA) as PNG."""
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    atomic_write_bytes(path, buf.getvalue())


def check_output_dir(path: str | os.PathLike, allowed: tuple[str, ...] = ()) -> Path:
    """``path`` as a Path, if it does not exist or is an empty folder (or one holding only
    ``allowed`` names); otherwise a one-line :class:`UserError`, so that no command silently
    mixes its files with an earlier one's."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UserError(f"output path {path} exists and is not a directory")
    if path.is_dir():
        other = sorted(p.name for p in path.iterdir() if p.name not in allowed)
        if other:
            raise UserError(f"output directory {path} already holds other data ({other[0]}, ...); choose an empty one")
    return path


def prepare_output_dir(path: str | os.PathLike, allowed: tuple[str, ...] = ()) -> Path:
    """Create ``path`` or accept it when empty (or holding only ``allowed`` names), to write into
    in place: for a folder that is filled over time and continued (a training run). An output
    made at once is written with :func:`staged_output_dir` instead."""
    path = check_output_dir(path, allowed)
    path.mkdir(parents=True, exist_ok=True)
    return path


@contextlib.contextmanager
def removed_on_failure(path: str | os.PathLike) -> Iterator[Path]:
    """:func:`prepare_output_dir` for an output filled in place whose files name one another by
    absolute path (the demo's scenes, real set, run and evaluation), which a renamed folder
    (:func:`staged_output_dir`) would break. When the block raises, what it wrote is removed, and
    the folder too if this made it: a rerun into the same name is accepted."""
    made = not Path(path).exists()
    path = prepare_output_dir(path)
    try:
        yield path
    except BaseException:
        if made:
            shutil.rmtree(path, ignore_errors=True)
        else:  # the user's empty folder: emptied again
            for child in path.iterdir():
                if child.is_dir() and not child.is_symlink():
                    shutil.rmtree(child, ignore_errors=True)
                else:
                    child.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def staged_output_dir(path: str | os.PathLike) -> Iterator[Path]:
    """A new output folder that appears complete or not at all.

    ``path`` must not exist or be an empty folder (:func:`check_output_dir`, checked before the
    block). The block fills the empty hidden sibling folder this yields
    (``.NAME.partial-<random>``). When the block ends, every file in it is flushed to disk and
    the sibling is renamed to ``path``. When the block raises (an error, Ctrl-C, a full disk), the
    sibling is removed and ``path`` is left as it was, so neither a reader nor a rerun finds a
    half-written output, nor an empty folder the failed command made; only a kill -9 leaves the
    hidden sibling behind. A ``path`` that is a symbolic link (to a folder on a larger disk, say)
    is followed: the folder is made and renamed where the link points."""
    final = Path(os.path.realpath(check_output_dir(path)))
    tmp = temp_dir_beside(final, "partial-")
    try:
        yield tmp
        fsync_files([p for p in tmp.rglob("*") if p.is_file() and not p.is_symlink()])
        try:
            os.replace(tmp, final)  # onto the empty folder, or a new name
        except OSError as e:
            if e.errno in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
                raise UserError(f"output directory {final} was filled by something else while this command ran; "
                                f"choose an empty one") from None
            raise
        fsync_files([final.parent])
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def check_free_space(place: str | os.PathLike, need: int, what: str, fixes: str) -> None:
    """Refuse, in one line, a ``place`` (or its nearest existing parent) whose file system has
    fewer than ``need`` bytes free: ``WHAT needs at least N but PLACE has M free; FIXES``. For a
    command that would otherwise fail near its end, after minutes or hours."""
    place = Path(place).absolute()
    place = next(p for p in (place, *place.parents) if p.exists())
    free = shutil.disk_usage(place).free
    if free < need:
        raise UserError(f"{what} needs at least {_bytes(need)} but {place} has {_bytes(free)} free; {fixes}")


def _bytes(n: int) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**30 else f"{n / 2**20:.1f} MiB"


def read_json(path: str | os.PathLike, what: str = "JSON file") -> dict:
    """The JSON object in ``path``, or a one-line :class:`UserError` naming ``what``, the file and
    the problem: missing or unreadable, not UTF-8, not JSON, or not an object at the top level
    (every JSON file of this project holds one object)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise UserError(f"cannot read {what} {path}: {reason(e)}") from None
    except UnicodeDecodeError:
        raise UserError(f"cannot read {what} {path}: not a UTF-8 text file") from None
    try:
        data = json.loads(text)
    except ValueError as e:
        raise UserError(f"cannot read {what} {path}: not valid JSON ({e})") from None
    if not isinstance(data, dict):
        raise UserError(f"cannot read {what} {path}: expected a JSON object, found {type(data).__name__}")
    return data


def cache_root() -> Path:
    """The folder of sim2real's caches (trained segmenters, view pools, compiled networks): ``$SIM2REAL_CACHE``, by
    default ``~/.cache/sim2real``."""
    return Path(os.environ.get("SIM2REAL_CACHE") or Path.home() / ".cache" / "sim2real")


def read_json_or_none(path: str | os.PathLike) -> dict | None:
    """:func:`read_json` for optional files: None where it would raise."""
    try:
        return read_json(path)
    except UserError:
        return None
