"""``sim2real evaluate --frames DIR|VIDEO --trajectory FILE --scene DIR``: the full evaluation of a
video made by any tool along a trajectory of a scene.

The video's frame t is taken as the view of the trajectory's camera t; every row (the ceiling, the
floor, a_ref) is rendered on the same cameras, so the consistency metrics, the odometry and the
ORB ground truth are exactly those of a sim2real run on that path. The realism measures and Dice
score the video's own frames (``views`` of them, evenly spaced) against the real images, beside
the other rows on the same cameras. A video has no second pass, so the revisit protocol reuses
its forward frames (as for a time-independent method).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from sim2real.data.real import list_images, load_rgb
from sim2real.engine.device import resolve_device
from sim2real.errors import UserError
from sim2real.inference.evaluate import EvalSettings, check_settings, run_stages
from sim2real.inference.video import read_video_frames
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory


def load_frames(source: str | os.PathLike) -> list[np.ndarray]:
    """uint8 RGB frames of a folder of images (in name order) or of a video file."""
    p = Path(source)
    if p.is_dir():
        return [load_rgb(f) for f in list_images(p, "frame")]
    if p.is_file():
        frames = read_video_frames(p)
        if len(frames) == 0:
            raise UserError(f"no frames decoded from {p}")
        return list(frames)
    raise UserError(f"{p} is neither a folder of frames nor a video file")


def fit_to_cameras(frames: Sequence[np.ndarray], height: int, width: int) -> list[np.ndarray]:
    """Frames resized to the cameras' size; the aspect ratio must match (a crop would move the
    pixels away from the ground truth)."""
    out = []
    for f in frames:
        h, w = f.shape[:2]
        if (h, w) == (height, width):
            out.append(f)
            continue
        if abs(w / h - width / height) > 0.01 * width / height:
            raise UserError(f"the frames are {w}x{h} but the trajectory's cameras are {width}x{height}: "
                            "the aspect ratios differ (resize the video to the trajectory's size)")
        out.append(cv2.resize(f, (width, height), interpolation=cv2.INTER_AREA if h > height else cv2.INTER_LINEAR))
    return out


class VideoAsModel:
    """A given video in the place of a trained model: the trajectory's frames in order, and the
    chosen views' frames for the realism stage."""

    time_independent = True

    def __init__(self, frames: list[np.ndarray], view_frames: list[np.ndarray], device):
        self.frames = frames
        self.view_frames = view_frames
        self.device = device
        self._views_given = 0

    def translate_views(self, scene_name, gbuffers, styles, seed, batch) -> dict:
        n = len(gbuffers)
        out = self.view_frames[self._views_given:self._views_given + n]
        self._views_given += n
        return {"": out}

    def sequence(self, scene_name, batch):
        frames = self.frames

        class _Seq:
            t = 0

            def translate(self, gbuffers):
                out = frames[self.t:self.t + len(gbuffers)]
                self.t += len(gbuffers)
                return out
        return _Seq()


def evaluate_frames(frames: str | os.PathLike, scene_dir: str | os.PathLike, trajectory: str | os.PathLike,
                    real: str | os.PathLike, out: str | os.PathLike, settings: EvalSettings | None = None,
                    fid_weights: str | os.PathLike | None = None, device: str = "auto", progress: bool = True) -> dict:
    """Evaluate the video ``frames`` (a folder of images or a video file) made along ``trajectory``
    of the scene ``scene_dir``; writes the same outputs as :func:`~sim2real.inference.evaluate.evaluate`."""
    s = settings or EvalSettings()
    check_settings(s)
    t_start = time.perf_counter()
    if not (Path(scene_dir) / "scene.json").is_file():
        raise UserError(f"{scene_dir} is not a scene folder (no scene.json)")
    traj = Trajectory.load(trajectory)
    cams = traj.cameras
    video = load_frames(frames)
    if len(video) != len(cams):
        raise UserError(f"{frames} has {len(video)} frames but the trajectory {trajectory} has {len(cams)} cameras")
    H, W = cams[0].height, cams[0].width
    video = fit_to_cameras(video, H, W)
    sc = Scene.load(scene_dir)
    idx = sorted({int(round(x)) for x in np.linspace(0, len(cams) - 1, min(s.views, len(cams)))})
    model = VideoAsModel(video, [video[i] for i in idx], resolve_device(device))
    run_info = {"dir": None, "frames": str(Path(frames).resolve()), "checkpoint": None, "step": None,
                "method": "a given video", "device": str(model.device), "amp_bf16": False, "compiled": False,
                "train_height": H, "train_width": W}
    return run_stages(model, [(sc, Path(scene_dir).resolve())], [traj], [trajectory], real, out, s, fid_weights,
                      (H, W, cams[0].K), run_info, progress, t_start, view_cameras={sc.name: [cams[i] for i in idx]},
                      view_index=idx)
