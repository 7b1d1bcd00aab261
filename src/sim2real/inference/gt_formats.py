"""The file formats of the ground-truth export (:mod:`sim2real.inference.export`), each with its
reader: 16-bit depth PNG, float depth ``.npy``, Middlebury ``.flo`` flow, label colours and TUM
pose rows.
"""

from __future__ import annotations

import io
import os
import struct
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
from PIL import Image

from sim2real.errors import UserError, reason
from sim2real.fileio import atomic_write_bytes
from sim2real.scene.camera import rotation_to_quaternion
from sim2real.scene.classes import ClassTable
from sim2real.scene.tum import read_tum

DEPTH_PNG_SCALE = 10.0
"""``depth/*.png`` value per millimetre (units of 0.1 mm)."""
TUM_DEPTH_SCALE = 5000.0
"""``tum/depth/*.png`` value per metre (the TUM RGB-D convention; units of 0.2 mm)."""
FLO_MAGIC = 202021.25
"""First float of a Middlebury .flo file (the bytes read 'PIEH')."""

# --- depth ---------------------------------------------------------------------------------------


def depth_to_png16(depth_mm: np.ndarray, scale: float) -> np.ndarray:
    """Float depth (mm, 0 = no surface) -> uint16 ``round(depth_mm * scale)``; saturates at 65535,
    surface pixels never become 0."""
    d = np.nan_to_num(np.asarray(depth_mm, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    surface = d > 0
    q = np.clip(np.rint(d * scale), 0, 65535)
    q[surface & (q < 1)] = 1
    q[~surface] = 0
    return q.astype(np.uint16)


def png16_bytes(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image, dtype=np.uint16), [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:  # pragma: no cover
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def read_depth_png(path: str | os.PathLike, scale: float = DEPTH_PNG_SCALE) -> np.ndarray:
    """A 16-bit depth PNG -> float32 z-depth in mm (0 = no surface). ``scale`` is the PNG value per
    millimetre: 10 for ``depth/`` (default), 5 for ``tum/depth/`` (5000 per metre)."""
    try:
        with Image.open(path) as im:
            a = np.array(im)
    except (OSError, ValueError) as e:
        raise UserError(f"cannot read depth image {path}: {reason(e)}") from None
    if a.ndim != 2 or a.dtype not in (np.uint16, np.int32, np.uint8):
        raise UserError(f"{path} is not a single-channel 16-bit depth PNG")
    return (a.astype(np.float64) / scale).astype(np.float32)


def npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=False)
    return buf.getvalue()


# --- Middlebury .flo -----------------------------------------------------------------------------


def write_flo(path: str | os.PathLike, flow: np.ndarray) -> None:
    """Write (H, W, 2) flow (u along columns, v along rows, pixels) as Middlebury .flo:
    float32 202021.25, int32 width, int32 height, then float32 u, v interleaved row by row
    (all little-endian). Written atomically."""
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow must be (H, W, 2), got {flow.shape}")
    h, w = flow.shape[:2]
    header = struct.pack("<fii", FLO_MAGIC, w, h)
    atomic_write_bytes(path, header + np.ascontiguousarray(flow, dtype="<f4").tobytes())


def read_flo(path: str | os.PathLike) -> np.ndarray:
    """Read a Middlebury .flo file -> float32 (H, W, 2)."""
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise UserError(f"cannot read flow file {path}: {reason(e)}") from None
    if len(data) < 12:
        raise UserError(f"{path} is not a .flo file (too short)")
    magic, w, h = struct.unpack("<fii", data[:12])
    if magic != FLO_MAGIC:
        raise UserError(f"{path} is not a .flo file (magic {magic!r}, expected {FLO_MAGIC})")
    if w <= 0 or h <= 0 or len(data) != 12 + 8 * w * h:
        raise UserError(f"{path}: size {w}x{h} does not match the file length {len(data)}")
    return np.frombuffer(data, dtype="<f4", offset=12).reshape(h, w, 2).astype(np.float32)


# --- labels --------------------------------------------------------------------------------------


def labels_to_color(labels: np.ndarray, table: ClassTable | None = None) -> np.ndarray:
    """uint8 labels (255 = background) -> (H, W, 3) uint8 RGB with the palette of ``table``
    (default: the default class table)."""
    return (table if table is not None else ClassTable.defaults()).palette_lut()[labels]


# --- poses ---------------------------------------------------------------------------------------


def pose_rows(c2w: Sequence[np.ndarray], timestamps: Sequence[float], scale: float) -> list[str]:
    rows = []
    for T, ts in zip(c2w, timestamps):
        q = rotation_to_quaternion(T[:3, :3])
        t = T[:3, 3] * scale
        rows.append(f"{ts:.6f} " + " ".join(f"{x:.9f}" for x in (*t, *q)))
    return rows


def read_tum_poses(path: str | os.PathLike) -> list[np.ndarray]:
    """Read TUM trajectory rows ``timestamp tx ty tz qx qy qz qw`` -> list of 4x4 camera_to_world
    (translation in the file's unit: mm for ``poses_tum_mm.txt``, metres for ``tum/groundtruth.txt``).
    Lines starting with '#' are skipped."""
    return [T for _, T in read_tum_poses_with_time(path)]


def read_tum_poses_with_time(path: str | os.PathLike) -> list[tuple[float, np.ndarray]]:
    """Like :func:`read_tum_poses`, with each pose's timestamp."""
    return read_tum(path, "pose file")[1]
