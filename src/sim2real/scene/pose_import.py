"""A camera path from the user's own poses: TUM rows ``timestamp tx ty tz qx qy qz qw`` (camera
to world, seconds) such as a tracked endoscope's, a surgical robot's kinematics, a SLAM run's or
a Blender camera's, given in the scene's world frame, made into a :class:`Trajectory` that
``translate`` and ``render`` take: translations to millimetres, camera axes to OpenCV's (x right,
y down, z forward), and on request resampled at a fixed frame rate.
"""

from __future__ import annotations

import os
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from sim2real.errors import UserError
from sim2real.scene.camera import Camera, invert_rigid
from sim2real.scene.conventions import CAMERA_AXES, UNITS
from sim2real.scene.trajectory import Trajectory
from sim2real.scene.tum import read_tum

AXES = {"opencv": np.eye(4), "opengl": np.diag([1.0, -1.0, -1.0, 1.0])}
"""Camera axes of the poses: ``opencv`` (TUM's, COLMAP's: x right, y down, looking along +z) or
``opengl`` (Blender's, OpenGL's, Unity's: x right, y up, looking along -z);
``camera_to_world_opencv = camera_to_world @ AXES[axes]``."""
assert tuple(AXES) == CAMERA_AXES


def resample(times: np.ndarray, c2w: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """The poses at ``fps`` from the first timestamp to the last: positions interpolated linearly,
    rotations spherically (slerp) between the two rows around each new time."""
    n = int(np.floor((times[-1] - times[0]) * fps + 1e-9)) + 1
    t = times[0] + np.arange(n) / fps
    out = np.tile(np.eye(4), (n, 1, 1))
    out[:, :3, :3] = Slerp(times, Rotation.from_matrix(c2w[:, :3, :3]))(t).as_matrix()
    for k in range(3):
        out[:, k, 3] = np.interp(t, times, c2w[:, k, 3])
    return t, out


UNEVEN = 1.5
"""Row intervals beyond this factor of their median (either way) are noted as uneven."""


def trajectory_from_poses(path: str | os.PathLike, K: np.ndarray, height: int, width: int, units: str = "mm",
                          axes: str = "opencv", fps: float | None = None,
                          note: Callable[[str], None] | None = None) -> tuple[Trajectory, int]:
    """The trajectory of the poses in ``path`` seen through ``K`` at ``width`` x ``height``, and
    the number of rows read. ``units`` of the translations (mm, cm, m); ``axes`` of the cameras
    (:data:`AXES`); ``fps``: resample at this rate (:func:`resample`), None: one frame per row at
    the rows' median rate, where ``note`` is told when the rows are unevenly spaced in time
    (dropped samples of a tracker: the video's motion per frame would jump there). Timestamps
    must increase."""
    if units not in UNITS:
        raise UserError(f"units must be one of {', '.join(UNITS)}, not {units}")
    if axes not in AXES:
        raise UserError(f"camera axes must be one of {', '.join(AXES)}, not {axes}")
    rows = read_tum(path, "pose file")[1]
    if not rows:
        raise UserError(f"{path}: no pose rows ('timestamp tx ty tz qx qy qz qw')")
    times = np.array([t for t, _ in rows], dtype=np.float64)
    c2w = np.stack([T for _, T in rows])
    steps = np.diff(times)
    if (steps <= 0).any():
        k = int(np.argmax(steps <= 0))
        raise UserError(f"{path}: timestamps must increase, but pose {k + 2} ({times[k + 1]:g} s) does not come "
                        f"after pose {k + 1} ({times[k]:g} s)")
    c2w[:, :3, 3] *= UNITS[units]
    c2w = c2w @ AXES[axes]
    if fps is not None and len(rows) > 1:
        _, c2w = resample(times, c2w, fps)
    rate = fps if fps is not None else (1.0 / float(np.median(steps)) if len(rows) > 1 else 5.0)
    if fps is None and note is not None and len(steps) > 1:
        uneven = (steps > UNEVEN / rate) | (steps < 1.0 / (UNEVEN * rate))
        if uneven.any():
            k = int(np.argmax(uneven))
            note(f"{int(uneven.sum())} of {len(steps)} pose intervals are more than {UNEVEN:g}x off their median "
                 f"{1.0 / rate:.3g} s (first after pose {k + 1}: {steps[k]:.3g} s), "
                 f"yet each row becomes one frame at {rate:.3g} fps: --fps F resamples the path evenly in time")
    cams = [Camera(np.asarray(K, dtype=np.float64), invert_rigid(T), height, width) for T in c2w]
    return Trajectory(cams, fps=rate), len(rows)


def blender_intrinsics(path: str | os.PathLike, width: int, height: int) -> tuple[np.ndarray, str | None]:
    """The pinhole K at ``width`` x ``height`` of the Blender camera described in the comment line
    that :func:`sim2real.scene.blend.blend_camera_path` writes, and a note when its pixels are
    not square there (another aspect than Blender's render size: the field of view is kept).

    Blender fits its sensor to one side of the render (``sensor_fit``; AUTO: the longer side, with
    ``sensor_width``), so that side's focal length in pixels is ``side_px * lens / sensor``; its
    shifts move the principal point by a share of that side, x to the right and y up:
    ``cx = W / 2 - shift_x * side_px``, ``cy = H / 2 + shift_y * side_px`` (pixel centres at +0.5)."""
    comments = read_tum(path, "camera file")[0]
    line = next((text for _, text in comments if text.startswith("# blender-camera ")), None)
    if line is None:
        raise UserError(f"{path} holds no Blender camera description")
    words = line.split()[2:]
    cam = dict(zip(words[0::2], words[1::2]))
    wb, hb = int(cam["width"]), int(cam["height"])
    lens, fit = float(cam["lens_mm"]), cam["sensor_fit"]
    if abs(float(cam["pixel_aspect"]) - 1.0) > 1e-9:
        raise UserError(f"the Blender camera renders pixels of aspect {float(cam['pixel_aspect']):g}, not square ones: "
                        f"give --intrinsics")
    side = "x" if fit == "HORIZONTAL" or (fit == "AUTO" and wb >= hb) else "y"
    sensor = float(cam["sensor_height_mm"] if fit == "VERTICAL" else cam["sensor_width_mm"])
    side_px = wb if side == "x" else hb
    f = side_px * lens / sensor
    sx, sy = width / wb, height / hb
    K = np.array([[f * sx, 0.0, (wb / 2 - float(cam["shift_x"]) * side_px) * sx],
                  [0.0, f * sy, (hb / 2 + float(cam["shift_y"]) * side_px) * sy],
                  [0.0, 0.0, 1.0]])
    note = None
    if abs(sx / sy - 1.0) > 1e-6:
        note = (f"the Blender camera renders {wb}x{hb}: at {width}x{height} its pixels are not square "
                f"(fx/fy {sx / sy:.3f}); give --width and --height of its aspect for square ones")
    return K, note
