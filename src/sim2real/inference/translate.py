"""``sim2real translate``: a trajectory or a views folder through a trained run.

:func:`translate_sequence` streams a trajectory (ray-cast in chunks, in-process or in a process
pool) or a views folder through a :class:`~sim2real.inference.model.TrainedModel` and writes
``frames/``, ``video.mp4``, ``ground_truth/`` and ``translate.json`` (docs/formats.md,
"Translate output"), and for a stereo pair the right eye's and the disparity.
"""

from __future__ import annotations

import os
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sim2real.config import to_dict
from sim2real.data.views import list_views
from sim2real.errors import UserError
from sim2real.fileio import atomic_write_json, check_free_space, deferred_fsync, staged_output_dir
from sim2real.inference.export import GroundTruthWriter
from sim2real.inference.frames import chunked, iter_gbuffers, iter_view_files
from sim2real.inference.model import TrainedModel, translate_batch
from sim2real.inference.stereo import right_camera, write_stereo_frame, write_stereo_json
from sim2real.inference.video import BackgroundFrameWriter, _rate
from sim2real.render.gbuffer import GBuffer
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory

FORMAT = "sim2real-translate/1"


@dataclass
class TranslateSource:
    """What to translate: a trajectory through a scene folder, or a views folder."""

    scene_name: str
    scene_dir: Path | None
    cameras: list | None = None
    """Trajectory cameras (ray-cast here); None for a views folder."""
    view_files: list[Path] | None = None
    fps: float = 5.0
    description: dict | None = None
    stereo_mm: float | None = None
    """Baseline of a right eye translated beside every camera (a trajectory only); None: one eye."""
    size: tuple[int, int] | None = None
    """(height, width) of the frames."""

    @property
    def frames(self) -> int:
        return len(self.cameras) if self.cameras is not None else len(self.view_files)


def least_bytes(source: TranslateSource) -> int:
    """What the output takes at the least: the ground truth's optical flow (``.flo``: 2 float32
    per pixel, every frame but the last) and depth (``.npy``: 1 float32 per pixel) of each eye,
    and a stereo pair's disparity (1 float32 per pixel). The frames, masks, labels, tracks and the
    COLMAP text come on top: 1.9 MB per frame at 256x512 in all, measured on a 200-frame path."""
    h, w = source.size
    n, eyes = source.frames, 2 if source.stereo_mm else 1
    return h * w * (eyes * (8 * (n - 1) + 4 * n) + (4 * n if source.stereo_mm else 0))


def check_space(source: TranslateSource, out: str | os.PathLike) -> None:
    """Refuse, before anything is translated, an output place with less free space than
    :func:`least_bytes`: else a long translation would fail at its end (a source made without
    its ``size`` is not checked)."""
    if source.size is None:
        return
    h, w = source.size
    eyes = " (both eyes)" if source.stereo_mm else ""
    check_free_space(out, least_bytes(source), f"the ground truth of {source.frames} frames at {w}x{h}{eyes} (its "
                     f"flow and depth maps alone)", "free space, write elsewhere or translate fewer frames")


def trajectory_source(model: TrainedModel, scene: str | os.PathLike, trajectory: str | os.PathLike,
                      stereo_mm: float | None = None) -> TranslateSource:
    """``--scene`` (a scene folder, or the name of one of the run's scenes whose folder still
    exists) and ``--trajectory`` -> a source; every input is checked before anything is written.
    ``stereo_mm``: also a right eye that far along each camera's x axis (:mod:`sim2real.inference.stereo`)."""
    path = Path(scene)
    if not (path / "scene.json").is_file() and str(scene) in model.infos:
        info = model.infos[str(scene)]
        if info.scene_dir is None or not (info.scene_dir / "scene.json").is_file():
            raise UserError(f"scene '{scene}' was trained from {info.scene_dir}, which no longer holds the scene; "
                            f"pass its folder with --scene DIR")
        path = info.scene_dir
    if not path.exists():
        raise UserError(f"scene folder {path} does not exist (the run knows the scenes: {', '.join(model.scenes)})")
    sc = Scene.load(path)
    model.scene(sc.name)
    model.check_classes(sc.name, sc.classes, str(path), sc.class_table)
    traj = Trajectory.load(trajectory)
    if stereo_mm is not None and not (np.isfinite(stereo_mm) and stereo_mm > 0):
        raise UserError(f"the stereo baseline must be a positive number of millimetres, got {stereo_mm}")
    cam = traj.cameras[0]
    return TranslateSource(sc.name, path.resolve(), cameras=traj.cameras, fps=traj.fps, size=(cam.height, cam.width),
                           description={"kind": "trajectory", "trajectory": str(Path(trajectory).resolve()),
                                        "scene_dir": str(path.resolve())}, stereo_mm=stereo_mm)


def views_source(model: TrainedModel, views_dir: str | os.PathLike) -> TranslateSource:
    """A finished views folder (``sim2real render``) -> a source, its views in file order."""
    manifest, files = list_views(views_dir)
    if not files:
        raise UserError(f"views folder {views_dir} holds no views")
    name = str(manifest.get("scene", ""))
    model.scene(name)
    first = GBuffer.load(files[0])
    model.check_classes(name, first.classes, str(views_dir), first.class_table)
    scene_dir = Path(manifest["scene_dir"]) if manifest.get("scene_dir") else None
    return TranslateSource(name, scene_dir, view_files=list(files), fps=5.0, size=first.depth.shape[:2],
                           description={"kind": "views", "views_dir": str(Path(views_dir).resolve())})


def translate_sequence(model: TrainedModel, source: TranslateSource, out: str | os.PathLike, batch: int | None = None,
                       fps: float | None = None, workers: int | None = None, progress: bool = True) -> dict:
    """Translate every frame of ``source`` into ``out`` (new or empty) and export its ground truth.

    Writes ``frames/000000.png ...``, ``video.mp4`` (H.264 at ``fps``, default the trajectory's),
    ``ground_truth/`` (:func:`sim2real.inference.export.export_ground_truth`, with ``tum/rgb`` =
    the translated frames) and, last, ``translate.json``. G-buffers are streamed: a chunk of
    frames is ray-cast (or read; by every core, :func:`sim2real.inference.frames.iter_gbuffers`),
    translated, and handed to a writer thread that writes the PNG frames and encodes the video
    (:class:`~sim2real.inference.video.BackgroundFrameWriter`) and to threads that write its
    ground truth (:class:`~sim2real.inference.export.GroundTruthWriter`) while the next chunk is
    translated; no G-buffer outlives its chunk by more than a few frames, so neither memory nor
    disk grows with the trajectory beyond its output. A source with ``stereo_mm`` also writes
    the right eye's ``right/frames/``, ``right/video.mp4``, ``right/ground_truth/`` and the
    pair's ``stereo/`` (:mod:`sim2real.inference.stereo`).

    Everything is written into a hidden sibling folder without a flush per file; when complete,
    all its files are flushed to disk at once and the folder is renamed to ``out``: a reader sees
    no ``out`` content or all of it. Returns the manifest. ``batch``: frames per network call
    (default :func:`~sim2real.inference.model.translate_batch`, by the model's device).
    """
    batch = translate_batch(model.device) if batch is None else batch
    if batch < 1:
        raise UserError(f"--batch must be >= 1, got {batch}")
    fps = float(source.fps if fps is None else fps)
    _rate(fps)
    check_space(source, out)
    with staged_output_dir(out) as staged, deferred_fsync():
        return _translate_into(model, source, staged, batch, fps, workers, progress)


def _translate_into(model: TrainedModel, source: TranslateSource, out: Path, batch: int, fps: float,
                    workers: int | None, progress: bool) -> dict:
    n = source.frames
    stereo = source.stereo_mm
    eyes = [out, out / "right"] if stereo else [out]
    for eye in eyes:
        (eye / "frames").mkdir(parents=True)
    t0 = time.perf_counter()
    size: list[tuple[int, int]] = []
    if source.cameras is not None:
        # A stereo pair is cast side by side (left, right, left, ...): one pool, one stream.
        cams = [c for cam in source.cameras for c in ((cam, right_camera(cam, stereo)) if stereo else (cam,))]
        gbuffers = iter_gbuffers(source.scene_dir, cams, workers=workers, chunk=batch * len(eyes))
    else:
        gbuffers = iter_view_files(source.view_files)
    i = 0
    # One sequence per eye: a stateful method continues each; the frames are named relative to
    # ground_truth/ (../frames/...).
    seqs = [model.sequence(source.scene_name, batch) for _ in eyes]
    with tqdm(total=n, desc="translate", unit="frame", disable=not progress) as bar, ExitStack() as truths:
        gts = [truths.enter_context(GroundTruthWriter(eye / "ground_truth", fps, [f"../frames/{k:06d}.png" for k in range(n)]))
               for eye in eyes]
        with ExitStack() as videos:
            writers = [videos.enter_context(BackgroundFrameWriter(eye / "frames", eye / "video.mp4", fps, depth=2 * batch))
                       for eye in eyes]
            if model.compiled:  # the first chunk compiles the networks: say why the bar waits
                bar.set_description("translate (compiling the networks)")
            for chunk in chunked(gbuffers, batch * len(eyes)):
                views = [chunk[e::len(eyes)] for e in range(len(eyes))]
                outputs = [seq.translate(v) for seq, v in zip(seqs, views)]
                bar.set_description("translate")
                for k, frames in enumerate(zip(*outputs)):
                    for f in frames:
                        if not size:
                            size.append(f.shape[:2])
                        elif f.shape[:2] != size[0]:
                            raise UserError(f"frame {i} is {f.shape[0]}x{f.shape[1]}, frame 0 is {size[0][0]}x{size[0][1]}; "
                                            f"a video has one size")
                    for writer, f in zip(writers, frames):
                        writer.put(f)
                    if stereo:
                        write_stereo_frame(out / "stereo", i, views[0][k], views[1][k], stereo)
                    i += 1
                    bar.update()
                for gt, v in zip(gts, views):
                    for g in v:
                        gt.add(g)
        count = writers[0].count
        translate_s = time.perf_counter() - t0
        for gt in gts:
            gt.close()
    if stereo:
        write_stereo_json(out / "stereo", stereo, source.cameras[0].K, count)
    h, w = size[0]
    manifest = {
        "format": FORMAT,
        "run_checkpoint": str(model.checkpoint.resolve()),
        "step": model.step,
        "method": model.method.name,
        "method_config": to_dict(model.cfg.method),
        "scene": source.scene_name,
        "source": source.description,
        "frames": count,
        "batch": batch,
        "fps": fps,
        "height": h,
        "width": w,
        "device": str(model.device),
        "amp_bf16": model.amp,
        "compiled": model.compiled,
        "files": {"frames": "frames/%06d.png", "video": "video.mp4", "ground_truth": "ground_truth/"},
        "stereo": None if stereo is None else {"baseline_mm": stereo, "right": "right/", "stereo": "stereo/"},
        "seconds": {"translate": round(translate_s, 3), "total": round(time.perf_counter() - t0, 3)},
    }
    atomic_write_json(out / "translate.json", manifest)
    return manifest
