"""The stages of ``sim2real evaluate`` (:func:`sim2real.inference.evaluate.evaluate` runs them in
this order): **views** (random views translated, with a_ref, the ceiling and the floor on the same
views), **realism** (:mod:`sim2real.inference.realism`), **segmentation** (Dice), **consistency** (each scene's trajectory: OF error,
ORB-k, revisit) and **report** (samples, report.md/html and, last, metrics.json, which
:mod:`sim2real.inference.metrics_json` assembles). Each stage is a function
of plain inputs, so that each can be run and tested alone.
"""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from tqdm import tqdm

from sim2real.fileio import atomic_write_json
from sim2real.inference.dice import class_dice, dice_of, segmenters  # torch-heavy training code, only with labels
from sim2real.inference.frames import chunked, iter_gbuffers
from sim2real.inference.jobs import Jobs, results
from sim2real.inference.realimages import fit_image
from sim2real.inference.report import write_report
from sim2real.inference.rows import PAPER_KS, sequence_row
from sim2real.inference.samples import safe_name, write_samples
from sim2real.inference.video import write_video
from sim2real.metrics.consistency import orb_settings_for
from sim2real.metrics.odometry import odometry, odometry_orb
from sim2real.render.motion import MotionMeter
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.render.warp import flow as gt_flow
from sim2real.scene.trajectory import make_trajectory, sample_poses

VIEW_INDEX0 = 100_000
"""Anchor frame index (which seeds the sensor noise and picks the floor's appearance) of the first
random view: apart from the sequences' frame indices 0..T-1."""

Say = Callable[[str], None]


def stderr_say(progress: bool) -> Say:
    """``evaluate: MESSAGE`` lines on stderr, or nothing."""
    return (lambda msg: print(f"evaluate: {msg}", file=sys.stderr, flush=True)) if progress else (lambda msg: None)


# --- views ---------------------------------------------------------------------------------------


@dataclass
class ViewSet:
    """The random views of every row: ``shown[row]`` one frame per view (the model's first
    translation), ``scored[row]`` what the realism measures score (the model: every translation
    of every view, variant after variant), ``liver[i]`` view i's simulated liver mask and
    ``labels[i]`` its class label ids (-1: background)."""

    shown: dict[str, list]
    scored: dict[str, list]
    variants: list[str]
    liver: list[np.ndarray] = field(default_factory=list)
    labels: list[np.ndarray] = field(default_factory=list)


def views_stage(model, scenes: Sequence[tuple], casters: dict, anchors: dict, real_imgs: Sequence[np.ndarray], s,
                rows_shown: Sequence[str], size: tuple, progress: bool = True,
                cameras: dict | None = None, view_index: Sequence[int] | None = None) -> ViewSet:
    """Translate ``s.views`` random views (spread evenly over ``scenes``, pairs ``(Scene, dir)``),
    with a_ref and, when ``anchors`` has the scene, the ceiling and the floor of each view.
    ``size`` = (H, W, K: the views' 3x3 intrinsics); real images are the style sources.
    ``cameras`` (scene name -> cameras) gives the views instead of random ones, and
    ``view_index`` the anchor frame index of each (default: :data:`VIEW_INDEX0` + i)."""
    H, W, K = size
    variants: dict[str, list] = {}
    style_rng = np.random.default_rng((s.seed, 1))
    if cameras is not None:
        counts = [len(cameras.get(sc.name, [])) for sc, _ in scenes]
    else:
        counts = [s.views // len(scenes) + (1 if k < s.views % len(scenes) else 0) for k in range(len(scenes))]
    views: dict[str, list] = {r: [] for r in rows_shown}
    liver: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    bar = tqdm(total=sum(counts), desc="views", unit="view", disable=not progress)
    jobs = Jobs()  # the ceiling and the floor shade in threads while the model translates
    for k, ((sc, d), n) in enumerate(zip(scenes, counts)):
        if n == 0:
            continue
        caster = casters[sc.name]
        cams = cameras[sc.name] if cameras is not None else sample_poses(caster, n, H, W, None, seed=s.seed + 1000 * k, K=K)
        for chunk in chunked(iter_gbuffers(d, cams, s.workers, s.batch, caster=caster), s.batch):
            styles = [real_imgs[int(i)] for i in style_rng.integers(0, len(real_imgs), len(chunk))]
            for name, frames in model.translate_views(sc.name, chunk, styles, s.seed + len(liver), s.batch).items():
                variants.setdefault(name, []).extend(frames)
            for g in chunk:
                i = VIEW_INDEX0 + len(liver) if view_index is None else view_index[len(liver)]
                labels.append(g.class_index())
                liver.append(labels[-1] == 0)
                views["a_ref"].append(to_uint8(reference_rendering(g)))
                if sc.name in anchors:
                    views["ceiling"].append(jobs.submit(anchors[sc.name].ceiling, g, i))
                    views["floor"].append(jobs.submit(anchors[sc.name].floor, g, i))
            bar.update(len(chunk))
    for row in ("ceiling", "floor"):
        if row in views:
            views[row] = results(views[row])
    jobs.close()
    bar.close()
    # a method with several translations per view (styles) is scored on all of them; the first is
    # the one shown beside the other rows
    views["model"] = next(iter(variants.values()))
    scored = {**views, "model": [f for frames in variants.values() for f in frames]}
    return ViewSet(views, scored, [v or "default" for v in variants], liver, labels)


# --- segmentation --------------------------------------------------------------------------------


def segmentation_stage(real_set, vs: ViewSet, s, device, rows_shown: Sequence[str], progress: bool = True,
                       say: Say = lambda m: None, classes: dict[str, int] | None = None) -> dict:
    """Dice of every row (:mod:`sim2real.inference.dice`) against the views' simulated liver, and
    with ``classes`` (name -> label id: those the real labels and the scenes share, the liver
    first) each class's under ``info["class_dice"]`` (class -> row -> value).
    Returns ``{"dice": {...}, "info": {...}, "rows": {row: value}, "reason"}``."""
    labelled = real_set.labelled
    dice = {"dice": None, "dice_a_ref": None, "dice_real_train": None, "dice_real_held_out": None, "dice_ceiling": None}
    info = {"n_train": len(labelled), "n_eval": len(vs.scored["model"]), "iterations": s.seg_iterations,
            "height": s.seg_height, "width": s.seg_width, "rows": {}}
    values: dict[str, float | None] = {}
    if not labelled:
        reason = (f"no labelled real images: expected {real_set.label_root}/NAME.png (uint8 class index, "
                  f"0 = liver, 255 = background) for the images {real_set.root}/NAME.*")
        return {"dice": dice, "info": info, "rows": values, "reason": reason}
    if classes is not None and "liver" not in classes:
        return {"dice": dice, "info": info, "rows": values,
                "reason": "the real labels and the scenes share no liver class (the paper's Dice is the liver's)"}
    segs, seg_info = segmenters(labelled, s, device, progress=progress, say=say,
                                masks=[real_set.mask_of(p) for p, _ in labelled], classes=classes)
    info.update(seg_info)
    gt = np.stack([fit_image(m.astype(np.uint8), s.seg_height, s.seg_width, nearest=True).astype(bool)
                   for m in vs.liver])
    for row in rows_shown:
        frames = vs.scored[row]
        info["rows"][row] = d = dice_of(segs, frames, np.concatenate([gt] * (len(frames) // len(gt))), s)
        values[row] = d["value"]
    dice.update(dice=info["rows"]["model"]["value"], dice_a_ref=info["rows"]["a_ref"]["value"],
                dice_real_held_out=seg_info["held_out_dice"]["value"],
                dice_real_train=float(np.mean([m["train_dice"] for m in seg_info["per_seed"]])),
                dice_ceiling=info["rows"].get("ceiling", {}).get("value"))
    if classes is not None and len(classes) > 1:
        per_row = {row: class_dice(segs, vs.scored[row], vs.labels, classes, s) for row in rows_shown}
        info["class_dice"] = {c: {row: (per_row[row][c] or {}).get("value") for row in rows_shown} for c in classes}
    reason = info["rows"]["model"]["reason"]  # None when the seeds agree; else their range beside the mean
    return {"dice": dice, "info": info, "rows": values, "reason": reason}


# --- consistency ---------------------------------------------------------------------------------


def consistency_stage(model, scenes: Sequence[tuple], casters: dict, anchors: dict, s, rows_shown: Sequence[str],
                      out: Path, size: tuple, trajs=None, trajectory_files=None,
                      progress: bool = True) -> dict:
    """Each scene's trajectory (given, or generated with ``s.frames`` frames) translated and
    scored for every row; the videos are written under ``out/videos``. Returns
    ``{"per_scene", "samples" (scene -> row -> frames), "inputs" (per scene), "orb_settings", "ks"}``."""
    H, W, K = size
    per_scene: dict[str, dict] = {}
    seq_samples: dict[str, dict] = {}
    inputs_scenes = []
    orb = orb_settings_for(W, s.orb_features)
    ks = sorted(set(range(1, s.orb_max_k + 1)) | set(PAPER_KS))
    for k, (sc, d) in enumerate(scenes):
        if trajs is not None:
            traj = trajs[k]
        else:
            traj = make_trajectory(casters[sc.name], s.frames, H, W, seed=s.seed + k, K=K, **(s.trajectory or {}))
        res, frames = sequence_metrics(model, sc.name, d, traj.cameras, casters[sc.name], anchors.get(sc.name), s, ks,
                                       orb, rows_shown, progress)
        res["trajectory"] = {"file": str(Path(trajectory_files[k]).resolve()) if trajectory_files is not None else None,
                             "motion_budget": (traj.motion or {}).get("budget")}
        inputs_scenes.append({"name": sc.name, "scene_dir": str(d), "trajectory": res["trajectory"]["file"],
                              "frames": len(traj.cameras)})
        per_scene[sc.name] = res
        seq_samples[sc.name] = frames
        for row in rows_shown:
            if row != "a_ref":
                write_video(frames[row], out / "videos" / (f"{safe_name(sc.name)}.mp4" if row == "model"
                                                           else f"{safe_name(sc.name)}_{row}.mp4"), fps=traj.fps)
        if "model_backward" in frames:  # the extended sequence 1..T, T..1 as the method translated it
            write_video(frames["model"] + frames["model_backward"],
                        out / "videos" / f"{safe_name(sc.name)}_revisit.mp4", fps=traj.fps)
    return {"per_scene": per_scene, "samples": seq_samples, "inputs": inputs_scenes, "orb_settings": orb, "ks": ks}


def sequence_metrics(model, scene: str, scene_dir: Path, cameras, caster, anchors, s, ks, orb, rows_shown,
                     progress: bool):
    """Translate one trajectory, render its ceiling, floor and a_ref, and score every row."""
    T = len(cameras)
    frames: dict[str, list] = {r: [] for r in rows_shown}
    points, masks, flows, valids, poses = [], [], [], [], []
    K = None
    meter = MotionMeter()
    prev = None
    bar = tqdm(total=T, desc=f"sequence {scene}", unit="frame", disable=not progress)
    jobs = Jobs()  # the ceiling and the floor shade in threads while the model translates
    seq = model.sequence(scene, s.batch)
    for chunk in chunked(iter_gbuffers(scene_dir, cameras, s.workers, s.batch, caster=caster), s.batch):
        for g, f in zip(chunk, seq.translate(chunk)):
            t = len(points)
            if prev is not None:
                fl, vis = gt_flow(prev, g)
                flows.append(fl)
                valids.append(vis)
            meter.add(g)
            frames["model"].append(f)
            frames["a_ref"].append(to_uint8(reference_rendering(g)))
            if anchors is not None:
                frames["ceiling"].append(jobs.submit(anchors.ceiling, g, t))
                frames["floor"].append(jobs.submit(anchors.floor, g, t))
            points.append(np.asarray(g.points, dtype=np.float32))
            masks.append(g.mask)
            poses.append(g.world_to_camera)
            K = g.K
            prev = g
        bar.update(len(chunk))
    bar.close()
    backward = None
    if not model.time_independent:  # the revisit half T..1, continuing the sequence's state
        backward = []
        for chunk in chunked(iter_gbuffers(scene_dir, cameras[::-1], s.workers, s.batch, caster=caster), s.batch):
            backward.extend(seq.translate(chunk))
        frames["model_backward"] = backward
    for row in ("ceiling", "floor"):
        if row in frames:
            frames[row] = results(frames[row])
    rows, odo = score_rows(jobs, frames, rows_shown, points, masks, flows, valids, poses, K, ks, orb, s, backward)
    jobs.close()
    return {"frames": T, "motion": meter.summary(), "rows": rows, "odometry": odo}, frames


def score_rows(jobs: Jobs, frames: dict, rows_shown, points, masks, flows, valids, poses, K, ks, orb, s, backward):
    """The temporal metrics (:func:`sequence_row`) and the odometry of every row, as jobs: the
    ceiling's first (the others' flows are compared with its Farnebäck flow), with the odometry
    beside it, then the other rows. Returns (rows, odometry)."""
    def row_job(row, ceiling_est):
        # a time-independent video's revisit pairs are its forward pairs (sequence_row): only a
        # time-dependent method's backward half is scored again
        return sequence_row(frames[row], points, masks, flows, valids, ks, s.threshold_mm, orb, ceiling_est,
                            revisit=False, backward=backward if row == "model" else None)

    order = [r for r in ("ceiling",) + tuple(r for r in rows_shown if r != "ceiling") if r in frames]
    ceiling = jobs.submit(row_job, "ceiling", None) if "ceiling" in frames else None
    odo_jobs = {}
    if s.odometry_pairs > 0:
        odo_orb = odometry_orb(orb)
        odo_jobs = {row: jobs.submit(odometry, frames[row], poses, K, PAPER_KS, odo_orb, s.odometry_pairs)
                    for row in rows_shown}
    rows, ceiling_est = {}, None
    if ceiling is not None:
        rows["ceiling"], ceiling_est = ceiling.result()
        r = rows["ceiling"]  # against its own flow the ceiling scores 0 by definition
        for key in ("of_error", "of_epe"):
            r["per_pair"][f"{key}_vs_ceiling"] = [None if e is None else 0.0 for e in r["per_pair"][key]]
            r[f"{key}_vs_ceiling"] = None if r[key] is None else 0.0
    others = {row: jobs.submit(row_job, row, ceiling_est) for row in order if row != "ceiling"}
    for row, f in others.items():
        rows[row] = f.result()[0]
    rows = {row: rows[row] for row in order}
    return rows, {row: f.result() for row, f in odo_jobs.items()}


# --- report --------------------------------------------------------------------------------------


def report_stage(metrics: dict, out: Path, vs: ViewSet, real_imgs, seq_samples: dict, s) -> dict:
    """Write the samples, report.md/html and, last, metrics.json (its presence marks a complete
    evaluation). Returns ``metrics``."""
    samples = write_samples(out, vs.shown, real_imgs, seq_samples, s)
    write_report(metrics, out, samples)
    atomic_write_json(out / "metrics.json", metrics)
    return metrics


@contextlib.contextmanager
def timed(seconds: dict, name: str):
    """Add the wall time of the ``with`` block to ``seconds[name]``."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - t0
