"""``sim2real evaluate``: the paper's metrics (Sec. 4.2) for a trained run, as metrics.json + a report.

Protocol (scaled down by default so that it runs on a CPU; every number is a setting):

* **Realism.** ``views`` random views (:func:`sim2real.scene.trajectory.sample_poses`, the run's
  training size and field of view), spread evenly over the scenes, are translated. FID and KID
  compare them with up to ``max_real`` real images (resized to cover the generated size, centre
  crop) through the FID Inception network (:mod:`sim2real.metrics.inception`); without its
  weights both are ``null`` with the reason, never a number from another network. The labelled
  proxy :func:`sim2real.metrics.realism.proxy_colour_texture_distance` is always reported
  (it is *not* FID). **Dice** (:mod:`sim2real.inference.dice`): ``seg_seeds`` liver U-Nets,
  trained on the labelled real images (``labels/NAME.png`` beside ``images/NAME.png``: uint8 class
  index, 0 = liver, 255 = background) less a held-out share, each for exactly ``seg_iterations``
  steps, and cached per real folder; the Dice of a set of frames is their mean, marked
  "unstable" when its standard error over the seeds exceeds ``seg_max_stderr``. The ground truth is the
  views' simulated liver pixels (``GBuffer.class_index() == 0``).
* **Temporal consistency**, per scene on a trajectory (a given file, or a generated one of
  ``frames`` frames at the training size, within the motion budget of
  :func:`~sim2real.scene.trajectory.make_trajectory`; its measured motion is reported): OF error
  (paper) and end-point error between the geometric flow (:func:`sim2real.render.warp.flow`,
  visible pixels only) and Farnebäck flow of consecutive frames, both also against the ceiling's
  Farnebäck flow; ORB-k accuracy and correct matches per pair for k = 1..``orb_max_k`` with ORB
  settings for the frame size (:func:`~sim2real.metrics.consistency.orb_settings_for`); the
  revisit protocol (1..T, T..1) for ORB-1/5/10 and OF: a time-dependent method translates the
  backward half T..1 itself, continuing the state it reached at frame T; a time-independent one
  (``Method.time_independent``) opts into reusing its forward frames, which are the very frames
  it would translate again. Pooled over scenes: ORB sums matches over all pairs, OF averages
  over all pairs.
* **Rows** (:mod:`sim2real.inference.rows`): every metric is computed for the model, the
  **ceiling**, the **floor** (:mod:`sim2real.inference.anchors`) and a_ref on the very same views
  and paths, with the model's position between floor (0) and ceiling (1).

Every key of ``metrics.json`` is always present; a value that cannot be computed is ``null``
and ``reasons`` says why (docs/formats.md, "Evaluation").
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from sim2real.errors import UserError
from sim2real.fileio import staged_output_dir
from sim2real.inference.anchors import Anchors, stand_in_options
from sim2real.inference.realimages import find_real, shared_classes
from sim2real.inference.rows import ROWS
from sim2real.inference.metrics_json import assemble_metrics
from sim2real.inference.realism import realism_stage
from sim2real.inference.stages import (
    consistency_stage,
    report_stage,
    segmentation_stage,
    stderr_say,
    timed,
    views_stage,
)
from sim2real.inference.model import load_run
from sim2real.metrics.inception import load_fid_inception
from sim2real.metrics.realism import fid_weights_status
from sim2real.render.raycast import RayCaster
from sim2real.scene.camera import view_intrinsics
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory

FORMAT = "sim2real-evaluation/2"


@dataclass
class EvalSettings:
    """Sizes of the evaluation (defaults: affordable on a 2-core CPU; the paper used 10,000 images)."""

    views: int = 64
    """Random translated views for FID/KID, the proxy and Dice (spread over the scenes)."""
    frames: int = 100
    """Frames of each generated trajectory (when no trajectory file is given)."""
    batch: int = 8
    """Frames per network call."""
    seed: int = 0
    max_real: int = 500
    """Real images used for FID/KID and the proxy (a seeded random subset when there are more)."""
    seg_iterations: int = 200
    """Steps of each segmenter, exactly (deterministic; the learning rate falls to 0 along a cosine)."""
    seg_height: int = 32
    seg_width: int = 64
    """The segmenter's input size: the liver is large, and on a 2-core CPU 32x64 trains a U-Net step in
    about 0.07 s (64x128: 0.26 s); raise it on a GPU."""
    seg_batch: int = 8
    seg_seeds: int = 5
    """Segmenters trained with seeds seed, seed+1, ...; Dice is their mean, unstable when its
    standard error exceeds seg_max_stderr (five seeds: one segmenter's scatter on a model's frames,
    about 0.04, gives a mean within about 0.02)."""
    seg_holdout: float = 0.2
    """Share of the labelled real images held out (the reported held-out Dice on real frames)."""
    seg_check_every: int = 50
    seg_max_stderr: float = 0.02
    orb_features: int = 1000
    orb_max_k: int = 20
    """The ORB curve covers k = 1..orb_max_k (and always 1, 5, 10)."""
    threshold_mm: float = 1.0
    """An ORB match is correct when its two 3D points are closer than this (paper: 1 mm)."""
    kid_subset_size: int = 1000
    kid_subsets: int = 100
    odometry_pairs: int = 30
    """Frame pairs per k (evenly spaced) of the downstream odometry (:mod:`sim2real.metrics.odometry`; 0: off)."""
    c2st_steps: int = 150
    """Training steps of the classifier two-sample test (0: not computed)."""
    realism_kid: bool = False
    """Also compute the KID in a fixed random network's features. Off by default: on the stand-in and
    on real footage it did not rank a blurred video below real frames (docs/evaluation.md)."""
    workers: int | None = None
    """Ray-casting processes (None: automatic)."""
    samples: int = 4
    """Sample views shown in the report."""
    anchors: bool = True
    """Also score the ceiling and the floor (:mod:`sim2real.inference.anchors`) on the same views."""
    trajectory: dict | None = None
    """Keyword arguments of :func:`~sim2real.scene.trajectory.make_trajectory` for generated paths
    (``flow_budget``, ``max_deg_per_frame``, ``look``); None: its defaults."""


# --- the evaluation ------------------------------------------------------------------------------


def evaluate(run: str | os.PathLike, scene_dirs: Sequence[str | os.PathLike], real: str | os.PathLike,
             out: str | os.PathLike, trajectories: Sequence[str | os.PathLike] | None = None,
             settings: EvalSettings | None = None, fid_weights: str | os.PathLike | None = None,
             device: str = "auto", checkpoint: str | os.PathLike | None = None, progress: bool = True,
             precision: str = "auto", compile: bool = False) -> dict:
    """Evaluate a run; writes ``out/metrics.json``, ``report.md``, ``report.html``, ``samples/``
    and ``videos/``. Returns the metrics. ``precision`` and ``compile``: the networks' arithmetic
    and whether they are compiled (:func:`sim2real.inference.model.load_run`). Inputs are all
    checked before the long work starts; the work is the stages of
    :mod:`sim2real.inference.stages`, in order."""
    s = settings or EvalSettings()
    check_settings(s)
    t_start = time.perf_counter()

    # ---- inputs (fail fast) ----
    if not scene_dirs:
        raise UserError("no scenes given (--scenes SCENE_DIR...)")
    if trajectories is not None and len(trajectories) != len(scene_dirs):
        raise UserError(f"give one trajectory per scene: {len(scene_dirs)} scenes, {len(trajectories)} trajectories")
    model = load_run(run, device, checkpoint, precision, compile=compile)
    scenes = []
    for d in scene_dirs:
        if not (Path(d) / "scene.json").is_file():
            raise UserError(f"{d} is not a scene folder (no scene.json)")
        sc = Scene.load(d)
        model.scene(sc.name)
        model.check_classes(sc.name, sc.classes, str(d))
        if any(sc.name == other.name for other, _ in scenes):
            raise UserError(f"scene '{sc.name}' is given twice")
        scenes.append((sc, Path(d).resolve()))
    trajs = [Trajectory.load(t) for t in trajectories] if trajectories is not None else None
    H, W = model.train_size
    run_info = {"dir": str(Path(run).resolve()), "checkpoint": str(model.checkpoint.resolve()), "step": model.step,
                "method": model.method.name, "device": str(model.device), "amp_bf16": model.amp,
                "compiled": model.compiled, "train_height": H, "train_width": W}
    d = model.cfg.data
    K = view_intrinsics(W, H, d.fov_x_deg, d.intrinsics)
    return run_stages(model, scenes, trajs, trajectories, real, out, s, fid_weights, (H, W, K), run_info, progress,
                      t_start)


def run_stages(model, scenes: list, trajs, trajectory_files, real, out, s: EvalSettings, fid_weights,
               size: tuple, run_info: dict, progress: bool, t_start: float,
               view_cameras: dict | None = None, view_index: list[int] | None = None) -> dict:
    """The evaluation of ``model`` (a trained run, or any object with its ``translate_views``,
    ``sequence``, ``time_independent`` and ``device``) on checked inputs: the stages, in order.
    ``size``: (H, W, K), the views' size and 3x3 intrinsics.
    ``view_cameras`` (scene name -> cameras) replaces the random views, ``view_index`` their anchor
    frame indices."""
    with staged_output_dir(out) as out:  # the folder appears complete, or not at all
        say = stderr_say(progress)
        real_set = find_real(real)
        status = fid_weights_status(fid_weights)
        inception = load_fid_inception(status["path"], model.device) if status["available"] else None
        H, W, _ = size
        seconds: dict[str, float] = {}

        # ---- anchors: the ceiling and the floor of every metric ----
        anchor_opts, real_is_stand_in = stand_in_options(real_set.root)
        anchors = {sc.name: Anchors(sc, seed=s.seed, pool=s.orb_max_k + 1, options=anchor_opts) for sc, _ in scenes} \
            if s.anchors else {}
        rows_shown = [r for r in ROWS if s.anchors or r in ("model", "a_ref")]
        casters = {sc.name: RayCaster(sc) for sc, _ in scenes}

        # ---- real images for FID/KID, the proxy and style sources ----
        rng = np.random.default_rng(s.seed)
        use = real_set.images
        if len(use) > s.max_real:
            use = [use[i] for i in sorted(rng.choice(len(use), s.max_real, replace=False))]
        real_imgs = real_set.frames(use, H, W)  # each real set frame's content window (realimages)

        with timed(seconds, "views"):
            vs = views_stage(model, scenes, casters, anchors, real_imgs, s, rows_shown, size, progress,
                             cameras=view_cameras, view_index=view_index)
        with timed(seconds, "realism"):
            realism = realism_stage(vs, real_imgs, inception, status, s, rows_shown, say, model.device)
        del inception
        with timed(seconds, "dice"):
            seg = segmentation_stage(real_set, vs, s, model.device, rows_shown, progress, say,
                                     classes=shared_classes(real_set, [sc.class_table for sc, _ in scenes]))
        with timed(seconds, "consistency"):
            cons = consistency_stage(model, scenes, casters, anchors, s, rows_shown, out, size, trajs, trajectory_files,
                                     progress)
        casters.clear()
        seconds["total"] = time.perf_counter() - t_start

        header = {"format": FORMAT, "run": run_info,
                  "inputs": {"real": {"dir": str(Path(real).resolve()), "images": len(real_set.images), "images_used": len(use),
                                      "labelled": len(real_set.labelled), "stand_in": real_is_stand_in}}}
        metrics = assemble_metrics(header=header, s=s, rows_shown=rows_shown, realism=realism, seg=seg, cons=cons,
                                   time_independent=model.time_independent, real_is_stand_in=real_is_stand_in,
                                   anchor_options=anchor_opts.to_json(), seconds=seconds)
        say("writing the report")
        return report_stage(metrics, out, vs, real_imgs, cons["samples"], s)


def check_settings(s: EvalSettings) -> None:
    """Refuse settings outside their range (a :class:`UserError`)."""
    for name in ("views", "frames", "batch", "max_real", "seg_height", "seg_width", "seg_batch", "orb_features",
                 "orb_max_k", "kid_subset_size", "kid_subsets", "samples", "seg_seeds", "seg_check_every"):
        if getattr(s, name) < (0 if name == "samples" else 1):
            raise UserError(f"evaluation setting {name} must be positive, got {getattr(s, name)}")
    if s.frames < 2:
        raise UserError(f"a trajectory needs at least 2 frames, got {s.frames}")
    for name in ("seg_iterations", "c2st_steps", "odometry_pairs"):
        if getattr(s, name) < 0:
            raise UserError(f"evaluation setting {name} must be >= 0, got {getattr(s, name)}")
    if not s.threshold_mm > 0:
        raise UserError(f"threshold_mm must be positive, got {s.threshold_mm}")
    if not 0 < s.seg_holdout < 1:
        raise UserError(f"seg_holdout must be between 0 and 1, got {s.seg_holdout}")
    if not s.seg_max_stderr >= 0:
        raise UserError(f"seg_max_stderr must be >= 0, got {s.seg_max_stderr}")
