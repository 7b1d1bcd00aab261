"""Training checkpoints: complete, atomic, loadable with ``torch.load(weights_only=True)``.

A checkpoint is one ``torch.save`` dict:

=================  =================================================================
key                content
=================  =================================================================
``format``         ``"sim2real-train/1"``
``step``           iterations completed; a resumed run continues with this step
``config``         the effective TrainConfig as a plain dict
``method``         the method name (sim2real/methods/); its settings are ``config.method``
``inputs``         ``{"scenes": [...], "real": ...}`` as given on the command line
``scenes``         per scene: name, key (e.g. of its neural texture), scene_dir, cached
                   view files or None
``gen``, ``dis``   state dicts of the method's generator stage (for ``ours``: translator
                   + all neural textures) and discriminator stage
``optimizers``     Adam state dicts by group name (for ``ours``: 'net', 'tex', 'dis')
``schedulers``     StepLR state dicts by group name
``rng``            per rank: python, numpy, torch CPU (and CUDA) generator states
``loss_schedule``  the loss weights at ``step`` (a function of the step), and for ``ours``
                   the current view-consistency weight
``world_size``     ranks that trained it
=================  =================================================================

The data stream is derived from (seed, rank, step) (data/datasets.py), so no loader state
is needed. Files are written to a temporary name, flushed, fsynced and renamed over
``last.pt``: a reader (or a run killed by SIGKILL at any moment) sees either the previous
complete checkpoint or the new one.
"""

from __future__ import annotations

import os
import pickle
import random
import re
import warnings
from pathlib import Path
from typing import BinaryIO

import numpy as np
import torch

from sim2real.errors import UserError, reason
from sim2real.fileio import atomic_path, link_or_copy

FORMAT = "sim2real-train/1"
LAST = "last.pt"


def mismatch(e: Exception, shown: int = 3) -> str:
    """One short line from the error of ``Module.load_state_dict`` (or of any other exception, its
    first line): which keys are missing or unexpected (the first ``shown`` of each, and how many)
    and which tensors differ in shape. torch's own message lists every key, one paragraph each."""
    lines = [ln.strip() for ln in str(e).strip().splitlines()]
    parts = []
    for ln in lines[1:]:
        m = re.match(r"(Missing|Unexpected) key\(s\) in state_dict: (.*)", ln)
        if m:
            keys = re.findall(r'"([^"]+)"', m.group(2))
            more = f", ... ({len(keys)} in all)" if len(keys) > shown else ""
            parts.append(f"{m.group(1).lower()} {', '.join(keys[:shown])}{more}")
        m = re.match(r"size mismatch for (\S+): copying a param with shape torch\.Size\((\[.*?\])\) from checkpoint, "
                     r"the shape in current model is torch\.Size\((\[.*?\])\)", ln)
        if m:
            parts.append(f"{m.group(1)} has shape {m.group(2)} in the file, {m.group(3)} here")
    if not parts:
        return lines[0] if lines and lines[0] else type(e).__name__
    more = f"; ... ({len(parts)} differences in all)" if len(parts) > shown else ""
    return "; ".join(parts[:shown]) + more


_LEGACY_MAGIC = pickle.dumps(0x1950A86A20F9469CFC6C, protocol=2)
"""How a file of torch.save's format before the zip archive (torch < 1.6) begins."""


def _torch_file(path) -> bool:
    """Whether ``path`` begins as torch.save's output does: a zip archive (whole or cut short), or
    the older pickle format."""
    try:
        with open(path, "rb") as f:
            head = f.read(len(_LEGACY_MAGIC))
    except OSError:
        return False
    return head.startswith(b"PK\x03\x04") or head == _LEGACY_MAGIC


def read_torch_file(source: str | os.PathLike | BinaryIO, path, what: str, map_location="cpu"):
    """``torch.load(source, weights_only=True)`` with any failure turned into one
    :class:`UserError` line ``cannot read {what} {path}: <why>``: a damaged zip archive (a
    truncated copy), a file that ``torch.save`` did not write, or one holding objects other than
    tensors and plain containers (which ``weights_only`` refuses, for safety). torch's own
    messages for these run to several sentences or, for a file of another kind, name a stray key."""
    try:
        with warnings.catch_warnings():  # its unpickler warns about pickle protocols it may not read
            warnings.simplefilter("ignore")
            return torch.load(source, map_location=map_location, weights_only=True)
    except Exception as e:  # noqa: BLE001 - whatever torch.load raises becomes one line
        first = (str(e).strip().splitlines() or [type(e).__name__])[0]
        if not _torch_file(path):
            why = "not a file written by torch.save"
        elif isinstance(e, pickle.UnpicklingError) and "weights only" in first.lower():
            why = "it holds objects other than tensors and plain containers, which are not loaded (for safety)"
        elif "PytorchStreamReader" in first:
            why = "a damaged or incomplete archive (a truncated copy?)"
        else:
            why = f"{type(e).__name__}: {first[:160]}"
        raise UserError(f"cannot read {what} {path}: {why}") from None


def find_run_checkpoint(path: str | os.PathLike) -> Path:
    """A checkpoint file, or a run folder's ``checkpoints/last.pt``."""
    path = Path(path)
    if path.is_file():
        return path
    if (path / "checkpoints" / LAST).is_file():
        return path / "checkpoints" / LAST
    raise UserError(f"{path} is neither a checkpoint file nor a run folder with checkpoints/{LAST}")


def step_name(step: int) -> str:
    return f"step_{step:07d}.pt"


def save_checkpoint(path: str | os.PathLike, state: dict) -> Path:
    """Atomically write ``state`` to ``path``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            torch.save(state, f)
            f.flush()
            os.fsync(f.fileno())
    try:  # make the rename itself durable
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError:
        pass
    return path


def keep_copy(path: Path, step: int) -> Path:
    """Also keep the checkpoint at ``path`` as ``step_NNNNNNN.pt`` (a hard link when possible)."""
    dst = path.parent / step_name(step)
    link_or_copy(path, dst)
    return dst


def stamp(path: str | os.PathLike) -> list[int] | None:
    """(inode, mtime in ns, size) of ``path``, None when it is missing: every atomic rewrite
    changes the inode."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return [st.st_ino, st.st_mtime_ns, st.st_size]


def load_checkpoint(path: str | os.PathLike, map_location="cpu") -> dict:
    """Read a checkpoint. The dict also holds ``stamp``, the :func:`stamp` of the file that was
    read (the trainer checks it under the run lock: the file must not have been rewritten since)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"no checkpoint at {path}")
    try:
        with open(path, "rb") as f:  # the stamp of the very file read, even if it is replaced meanwhile
            st = os.fstat(f.fileno())
            state = read_torch_file(f, path, "checkpoint", map_location)
    except OSError as e:
        raise UserError(f"cannot read checkpoint {path}: {reason(e)}") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise UserError(f"{path} is not a sim2real training checkpoint")
    state["stamp"] = [st.st_ino, st.st_mtime_ns, st.st_size]
    for part in ("gen", "dis"):  # the shipped model stores its large tensors in fp16 (sim2real/shipped)
        if isinstance(state.get(part), dict):
            state[part] = {k: v.float() if torch.is_tensor(v) and v.dtype == torch.float16 else v
                           for k, v in state[part].items()}
    return state


def rng_state() -> dict:
    """Python, numpy and torch generator states as weights_only-loadable values."""
    py = random.getstate()
    kind, keys, pos, has_gauss, gauss = np.random.get_state()
    state = {
        "python": [py[0], list(py[1]), py[2]],
        "numpy": {"kind": kind, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                  "has_gauss": int(has_gauss), "gauss": float(gauss)},
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict) -> None:
    py = state["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))
    n = state["numpy"]
    np.random.set_state((n["kind"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["gauss"]))
    torch.set_rng_state(state["torch"].cpu())
    if "cuda" in state and torch.cuda.is_available():
        cuda = [s.cpu() for s in state["cuda"]]
        if len(cuda) == torch.cuda.device_count():
            torch.cuda.set_rng_state_all(cuda)


def trained_method(state: dict) -> str:
    """The method a checkpoint was trained with (its config section's tag; format-1 checkpoints
    named the variant, whose method is 'ours')."""
    section = state.get("config", {}).get("method")
    return section.get("name", "?") if isinstance(section, dict) else "ours"


def transfer_weights(method, modules: dict[str, torch.nn.Module], state: dict, path: Path) -> None:
    """``--init-from``: load into ``modules`` ({'gen': ..., 'dis': ...}) the weights of the
    trained run ``state`` (read from ``path``) that ``method`` calls transferable (e.g. not the
    neural textures of its scenes). Refused (:class:`UserError`) when the run was trained with
    another method or a transferable weight is absent or shaped otherwise on either side."""
    trained = trained_method(state)
    if trained != method.name:
        raise UserError(f"--init-from {path} was trained with method '{trained}', not '{method.name}'")
    for part, module in modules.items():
        own = {k: v for k, v in module.state_dict().items() if method.transferable(k)}
        theirs = {k: v for k, v in state[part].items() if method.transferable(k)}
        for k in sorted(set(own) | set(theirs)):
            if k not in own or k not in theirs or own[k].shape != theirs[k].shape:
                shapes = [tuple(d[k].shape) if k in d else "absent" for d in (theirs, own)]
                raise UserError(f"--init-from {path} does not fit this configuration: {part} weight '{k}' is "
                                f"{shapes[0]} there and {shapes[1]} here (use the same generator and "
                                "discriminator settings)")
        module.load_state_dict(theirs, strict=False)
