"""TUM RGB-D pose files: one row ``timestamp tx ty tz qx qy qz qw`` per pose (camera to world,
quaternion x y z w), '#' comment lines. The one reader of them (trajectories, exported poses)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from sim2real.errors import UserError, reason
from sim2real.scene.camera import quaternion_to_rotation


def read_tum(path: str | os.PathLike, what: str = "pose file") -> tuple[list[tuple[int, str]], list[tuple[float, np.ndarray]]]:
    """``(comments, poses)`` of a TUM file: the comment lines as (line number, stripped text), and
    each row as (timestamp, 4x4 camera_to_world; translation in the file's unit). A row with
    anything but 8 finite numbers, or a quaternion off unit length by more than 1e-3, is refused
    with its line number; ``what`` names the file in the error of an unreadable one."""
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise UserError(f"cannot read {what} {path}: {reason(e)}") from None
    comments: list[tuple[int, str]] = []
    poses: list[tuple[float, np.ndarray]] = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        if line.startswith("#"):
            comments.append((lineno, line))
            continue
        try:
            vals = [float(x) for x in line.split()]
        except ValueError:
            vals = []
        if len(vals) != 8 or not np.all(np.isfinite(vals)):
            raise UserError(f"{path}:{lineno}: expected 8 numbers 'timestamp tx ty tz qx qy qz qw', got '{line}'")
        if abs(np.linalg.norm(vals[4:]) - 1.0) > 1e-3:
            raise UserError(f"{path}:{lineno}: quaternion is not of unit length")
        T = np.eye(4)
        T[:3, :3] = quaternion_to_rotation(vals[4:])
        T[:3, 3] = vals[1:4]
        poses.append((vals[0], T))
    return comments, poses
