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
  index, 0 = liver, 255 = background) less a held-out share, each until its held-out Dice
  converges, and cached per real folder; the Dice of a set of frames is their mean, or ``null``
  ("unstable") when the seeds disagree by more than ``seg_max_spread``. The ground truth is the
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

import dataclasses
import os
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from sim2real.errors import UserError
from sim2real.inference.realimages import find_real, fit_image, to_nchw
from sim2real.inference.rows import PAPER_KS, ROWS, pool_rows, positions, scalars

FORMAT = "sim2real-evaluation/2"
_VIEW_INDEX0 = 100_000
"""Anchor frame index (which seeds the sensor noise and picks the floor's appearance) of the first
random view: apart from the sequences' frame indices 0..T-1."""


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
    seg_iterations: int = 600
    """At most this many steps per segmenter; each stops earlier when its held-out Dice converges."""
    seg_height: int = 32
    seg_width: int = 64
    """The segmenter's input size: the liver is large, and on a 2-core CPU 32x64 trains a U-Net step in
    about 0.07 s (64x128: 0.26 s); raise it on a GPU."""
    seg_batch: int = 8
    seg_seeds: int = 3
    """Segmenters trained with seeds seed, seed+1, ...; Dice is their mean, unstable above seg_max_spread."""
    seg_holdout: float = 0.2
    """Share of the labelled real images held out (stopping criterion and the reported held-out Dice)."""
    seg_check_every: int = 50
    seg_max_spread: float = 0.05
    orb_features: int = 1000
    orb_max_k: int = 20
    """The ORB curve covers k = 1..orb_max_k (and always 1, 5, 10)."""
    threshold_mm: float = 1.0
    """An ORB match is correct when its two 3D points are closer than this (paper: 1 mm)."""
    kid_subset_size: int = 1000
    kid_subsets: int = 100
    workers: int | None = None
    """Ray-casting processes (None: automatic)."""
    samples: int = 4
    """Sample views shown in the report."""
    anchors: bool = True
    """Also score the ceiling and the floor (:mod:`sim2real.inference.anchors`) on the same views."""
    trajectory: dict | None = None
    """Keyword arguments of :func:`~sim2real.scene.trajectory.make_trajectory` for generated paths
    (``flow_budget``, ``max_deg_per_frame``, ``look``); None: its defaults."""


# --- pooling -------------------------------------------------------------------------------------


def _orb_reason(orb: dict[str, dict]) -> str | None:
    bad = []
    for k, e in orb.items():
        if e["pairs"] == 0:
            bad.append(f"ORB-{k}: no frame pair {k} apart (trajectory too short)")
        elif e["accuracy"] is None:
            bad.append(f"ORB-{k}: no ORB match in {e['pairs']} pairs (frames too smooth)")
    return "; ".join(bad) if bad else None


def _mean(values: Sequence[float | None]) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.mean(v)) if v else None


# --- the evaluation ------------------------------------------------------------------------------


def evaluate(run: str | os.PathLike, scene_dirs: Sequence[str | os.PathLike], real: str | os.PathLike,
             out: str | os.PathLike, trajectories: Sequence[str | os.PathLike] | None = None,
             settings: EvalSettings | None = None, fid_weights: str | os.PathLike | None = None,
             device: str = "auto", checkpoint: str | os.PathLike | None = None, progress: bool = True) -> dict:
    """Evaluate a run; writes ``out/metrics.json``, ``report.md``, ``report.html``, ``samples/``
    and ``videos/``. Returns the metrics. Inputs are all checked before the long work starts."""
    from tqdm import tqdm

    from sim2real.data.real import load_rgb
    from sim2real.fileio import atomic_write_json, prepare_output_dir
    from sim2real.inference.frames import chunked, iter_gbuffers
    from sim2real.inference.report import write_report
    from sim2real.inference.translate import load_run
    from sim2real.inference.video import write_video
    from sim2real.metrics.consistency import orb_settings_for
    from sim2real.metrics.realism import fid_weights_status
    from sim2real.render.raycast import RayCaster
    from sim2real.render.reference import reference_rendering, to_uint8
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import Trajectory, make_trajectory, sample_poses

    s = settings or EvalSettings()
    check_settings(s)
    t_start = time.perf_counter()
    say = (lambda msg: print(f"evaluate: {msg}", file=sys.stderr, flush=True)) if progress else (lambda msg: None)

    # ---- inputs (fail fast) ----
    if not scene_dirs:
        raise UserError("no scenes given (--scenes SCENE_DIR...)")
    if trajectories is not None and len(trajectories) != len(scene_dirs):
        raise UserError(f"give one trajectory per scene: {len(scene_dirs)} scenes, {len(trajectories)} trajectories")
    model = load_run(run, device, checkpoint)
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
    real_set = find_real(real)
    labelled = real_set.labelled
    status = fid_weights_status(fid_weights)
    inception = None
    if status["available"]:
        from sim2real.metrics.inception import load_fid_inception

        inception = load_fid_inception(status["path"], model.device)
    out = prepare_output_dir(out)
    H, W = model.train_size
    fov = model.cfg.data.fov_x_deg
    seconds: dict[str, float] = {}

    # ---- anchors: the ceiling and the floor of every metric ----
    from sim2real.inference.anchors import Anchors, stand_in_options

    anchor_opts, real_is_stand_in = stand_in_options(real_set.root)
    anchors = {sc.name: Anchors(sc, seed=s.seed, pool=s.orb_max_k + 1, options=anchor_opts) for sc, _ in scenes} \
        if s.anchors else {}
    rows_shown = [r for r in ROWS if s.anchors or r in ("model", "a_ref")]

    # ---- real images for FID/KID, the proxy and style sources ----
    rng = np.random.default_rng(s.seed)
    use = real_set.images
    if len(use) > s.max_real:
        use = [use[i] for i in sorted(rng.choice(len(use), s.max_real, replace=False))]
    real_imgs = [fit_image(load_rgb(p), H, W) for p in use]
    real_t = to_nchw(real_imgs)

    # ---- random views: translate, reference rendering, ceiling, floor ----
    t0 = time.perf_counter()
    variants: dict[str, list] = {}
    style_rng = np.random.default_rng((s.seed, 1))
    counts = [s.views // len(scenes) + (1 if k < s.views % len(scenes) else 0) for k in range(len(scenes))]
    views: dict[str, list] = {r: [] for r in rows_shown}
    gen_liver = []
    casters = {}
    bar = tqdm(total=s.views, desc="views", unit="view", disable=not progress)
    for k, ((sc, d), n) in enumerate(zip(scenes, counts)):
        casters[sc.name] = caster = RayCaster(sc)
        if n == 0:
            continue
        cams = sample_poses(caster, n, H, W, fov, seed=s.seed + 1000 * k)
        for chunk in chunked(iter_gbuffers(d, cams, s.workers, s.batch, caster=caster), s.batch):
            styles = [real_imgs[int(i)] for i in style_rng.integers(0, len(real_imgs), len(chunk))]
            for name, frames in model.translate_views(sc.name, chunk, styles, s.seed + len(gen_liver), s.batch).items():
                variants.setdefault(name, []).extend(frames)
            for g in chunk:
                i = len(gen_liver)
                gen_liver.append(g.class_index() == 0)
                views["a_ref"].append(to_uint8(reference_rendering(g)))
                if s.anchors:
                    views["ceiling"].append(anchors[sc.name].ceiling(g, _VIEW_INDEX0 + i))
                    views["floor"].append(anchors[sc.name].floor(g, _VIEW_INDEX0 + i))
            bar.update(len(chunk))
    bar.close()
    # a method with several translations per view (styles) is scored on all of them; the first is
    # the one shown beside the other rows
    views["model"] = next(iter(variants.values()))
    scored = {**views, "model": [f for frames in variants.values() for f in frames]}
    gen = scored["model"]
    seconds["views"] = time.perf_counter() - t0

    realism: dict[str, dict] = {r: {} for r in rows_shown}

    # ---- FID / KID ----
    reasons: dict[str, str | None] = {"fid": None, "dice": None, "of_error": None, "orb": None, "revisit": None}
    fid = {"fid": None, "kid_mean": None, "kid_std": None}
    fid_info = {"n_real": len(real_imgs), "n_gen": len(gen), "kid_subset_size": None, "kid_subsets": s.kid_subsets,
                "weights": status.get("path"), "variants": [v or "default" for v in variants]}
    t0 = time.perf_counter()
    if inception is None:
        reasons["fid"] = status["reason"]
    elif len(gen) < 2 or len(real_imgs) < 2:
        reasons["fid"] = f"FID/KID need at least 2 images per set (got {len(real_imgs)} real, {len(gen)} generated)"
    else:
        say(f"FID/KID: Inception features of {len(real_imgs)} real and {len(gen)} images per row")
        from sim2real.metrics.realism import fid_kid

        for row in rows_shown:
            with warnings.catch_warnings():  # torchmetrics warns that KID keeps its features: known, bounded here
                warnings.filterwarnings("ignore", message=".*will save all extracted features in buffer.*")
                r = fid_kid(to_nchw(scored[row]), real_t, inception, kid_subset_size=s.kid_subset_size,
                            kid_subsets=s.kid_subsets, batch_size=max(s.batch, 16), seed=s.seed)
            vals = {"fid": r["fid"], "kid_mean": r["kid_mean"], "kid_std": r["kid_std"]}
            vals = {k: (v if np.isfinite(v) else None) for k, v in vals.items()}
            realism[row].update(fid=vals["fid"], kid=vals["kid_mean"])
            if row == "model":
                fid = vals
                fid_info.update(kid_subset_size=r["kid_subset_size"])
                bad = [k for k, v in vals.items() if v is None]
                if bad:
                    reasons["fid"] = f"{', '.join(bad)} not finite (too few images for a {r['num_features']}-d covariance?)"
    del inception
    seconds["fid_kid"] = time.perf_counter() - t0

    from sim2real.metrics.realism import proxy_colour_texture_distance

    proxy = proxy_colour_texture_distance(to_nchw(gen), real_t)
    for row in rows_shown:
        p = proxy if row == "model" else proxy_colour_texture_distance(to_nchw(scored[row]), real_t)
        realism[row]["proxy"] = p["proxy_colour_texture_distance"]
        # detail: the row's mean grey gradient as a share of the real images' (1 = as detailed)
        g_real = p["proxy_grad_mean_real"]
        realism[row]["detail"] = p["proxy_grad_mean_gen"] / g_real if g_real > 0 else None
    del real_t

    # ---- Dice ----
    t0 = time.perf_counter()
    dice = {"dice": None, "dice_a_ref": None, "dice_real_train": None, "dice_real_held_out": None, "dice_ceiling": None}
    dice_info = {"n_train": len(labelled), "n_eval": len(gen), "iterations": s.seg_iterations,
                 "height": s.seg_height, "width": s.seg_width, "rows": {}}
    if not labelled:
        reasons["dice"] = (f"no labelled real images: expected {real_set.label_root}/NAME.png (uint8 class index, "
                           f"0 = liver, 255 = background) for the images {real_set.root}/NAME.*")
    else:
        from sim2real.inference.dice import dice_of, segmenters

        segs, info = segmenters(labelled, s, model.device, progress=progress, say=say)
        dice_info.update(info)
        gt = np.stack([fit_image(m.astype(np.uint8), s.seg_height, s.seg_width, nearest=True).astype(bool) for m in gen_liver])
        for row in rows_shown:
            dice_info["rows"][row] = d = dice_of(segs, scored[row], np.concatenate([gt] * (len(scored[row]) // len(gt))), s)
            realism[row]["dice"] = d["value"]
        dice.update(dice=dice_info["rows"]["model"]["value"], dice_a_ref=dice_info["rows"]["a_ref"]["value"],
                    dice_real_held_out=info["held_out_dice"]["value"],
                    dice_real_train=float(np.mean([m["train_dice"] for m in info["per_seed"]])),
                    dice_ceiling=dice_info["rows"].get("ceiling", {}).get("value"))
        if dice["dice"] is None:
            reasons["dice"] = dice_info["rows"]["model"]["reason"]
        del segs
    seconds["dice"] = time.perf_counter() - t0

    # ---- temporal consistency per scene ----
    t0 = time.perf_counter()
    per_scene: dict[str, dict] = {}
    seq_samples: dict[str, dict] = {}
    inputs_scenes = []
    orb_settings = orb_settings_for(W, s.orb_features)
    ks = sorted(set(range(1, s.orb_max_k + 1)) | set(PAPER_KS))
    for k, (sc, d) in enumerate(scenes):
        if trajs is not None:
            traj = trajs[k]
        else:
            traj = make_trajectory(casters[sc.name], s.frames, H, W, fov, seed=s.seed + k, **(s.trajectory or {}))
        res, frames = _sequence_metrics(model, sc.name, d, traj.cameras, casters[sc.name], anchors.get(sc.name), s, ks,
                                        orb_settings, rows_shown, progress)
        res["trajectory"] = {"file": str(Path(trajectories[k]).resolve()) if trajectories is not None else None,
                             "motion_budget": (traj.motion or {}).get("budget")}
        inputs_scenes.append({"name": sc.name, "scene_dir": str(d), "trajectory": res["trajectory"]["file"],
                              "frames": len(traj.cameras)})
        per_scene[sc.name] = res
        seq_samples[sc.name] = frames
        for row in rows_shown:
            if row != "a_ref":
                write_video(frames[row], out / "videos" / (f"{_safe(sc.name)}.mp4" if row == "model"
                                                           else f"{_safe(sc.name)}_{row}.mp4"), fps=traj.fps)
        if "model_backward" in frames:  # the extended sequence 1..T, T..1 as the method translated it
            write_video(frames["model"] + frames["model_backward"], out / "videos" / f"{_safe(sc.name)}_revisit.mp4",
                        fps=traj.fps)
    seconds["consistency"] = time.perf_counter() - t0
    casters.clear()

    scene_list = list(per_scene.values())
    pooled = {row: pool_rows([r["rows"][row] for r in scene_list], ks) for row in rows_shown}
    m_row = pooled["model"]
    orb = m_row["orb_curve"]
    of_error = m_row["of_error"]
    revisit = {"of_error": m_row["revisit"]["of_error"], "orb": m_row["revisit"]["orb"],
               "backward_frames": "reused: the method is time-independent" if model.time_independent
               else "translated by the method, continuing its state after frame T"}
    if of_error is None:
        reasons["of_error"] = "no frame pair with visible ground-truth flow (trajectories of 1 frame, or nothing visible)"
    paper_orb = {str(k): orb[str(k)] for k in PAPER_KS}
    reasons["orb"] = _orb_reason(paper_orb)
    rv = []
    if revisit["of_error"] is None:
        rv.append("OF: no pair with visible ground-truth flow")
    if _orb_reason(revisit["orb"]):
        rv.append(_orb_reason(revisit["orb"]))
    reasons["revisit"] = "; ".join(rv) if rv else None
    table = {row: scalars(pooled[row], realism[row]) for row in rows_shown}
    pos = positions(table) if s.anchors else {}
    warnings_ = []
    if s.anchors and of_error is not None and pooled["ceiling"]["of_error"] is not None \
            and of_error < pooled["ceiling"]["of_error"]:
        warnings_.append(f"the model's OF error ({of_error:.3g} px) is below the ceiling's "
                         f"({pooled['ceiling']['of_error']:.3g} px): Farnebäck returns near-zero flow on smooth frames, "
                         "so this OF error rewards blur here; see of_error_vs_ceiling "
                         f"({m_row['of_error_vs_ceiling']:.3g} px, ceiling 0)")
    if s.anchors and not real_is_stand_in:
        warnings_.append("the real folder is not the stand-in real domain (no sim2real-realdomain manifest): the ceiling "
                         "and the floor describe the stand-in, not your domain")

    seconds["total"] = time.perf_counter() - t_start
    metrics = {
        "format": FORMAT,
        "run": {"dir": str(Path(run).resolve()), "checkpoint": str(model.checkpoint.resolve()), "step": model.step,
                "method": model.method.name, "device": str(model.device), "amp_bf16": model.amp,
                "train_height": H, "train_width": W},
        "settings": {**dataclasses.asdict(s), "fid_weights": status.get("path"), "orb": orb_settings.to_json()},
        "inputs": {"scenes": inputs_scenes,
                   "real": {"dir": str(Path(real).resolve()), "images": len(real_set.images), "images_used": len(use),
                            "labelled": len(labelled), "stand_in": real_is_stand_in}},
        **fid,
        "fid_kid": fid_info,
        "proxy": proxy,
        **dice,
        "dice_info": dice_info,
        "of_error": of_error,
        "of_epe": m_row["of_epe"],
        "orb": paper_orb,
        "orb_curve": orb,
        "revisit": revisit,
        "rows": table,
        "row_curves": {row: pooled[row]["orb_curve"] for row in rows_shown},
        "position": pos,
        "anchors": {"ceiling": "the stand-in real domain rendered on the evaluated views with one appearance",
                    "floor": f"the stand-in with a new appearance every frame (a pool of {s.orb_max_k + 1}, frame t "
                             f"takes t mod {s.orb_max_k + 1})", "a_ref": "the untranslated reference rendering",
                    "enabled": s.anchors, "render_options": anchor_opts.to_json()},
        "warnings": warnings_,
        "per_scene": per_scene,
        "reasons": reasons,
        "seconds": {k: round(v, 3) for k, v in seconds.items()},
    }
    metrics = _json_safe(metrics)
    say("writing the report")
    samples = _write_samples(out, views, real_imgs, seq_samples, s)
    write_report(metrics, out, samples)
    atomic_write_json(out / "metrics.json", metrics)  # last: its presence marks a complete evaluation
    return metrics


def check_settings(s: EvalSettings) -> None:
    """Refuse settings outside their range (a :class:`UserError`)."""
    for name in ("views", "frames", "batch", "max_real", "seg_height", "seg_width", "seg_batch", "orb_features",
                 "orb_max_k", "kid_subset_size", "kid_subsets", "samples", "seg_seeds", "seg_check_every"):
        if getattr(s, name) < (0 if name == "samples" else 1):
            raise UserError(f"evaluation setting {name} must be positive, got {getattr(s, name)}")
    if s.frames < 2:
        raise UserError(f"a trajectory needs at least 2 frames, got {s.frames}")
    if s.seg_iterations < 0:
        raise UserError(f"seg_iterations must be >= 0, got {s.seg_iterations}")
    if not s.threshold_mm > 0:
        raise UserError(f"threshold_mm must be positive, got {s.threshold_mm}")
    if not 0 < s.seg_holdout < 1:
        raise UserError(f"seg_holdout must be between 0 and 1, got {s.seg_holdout}")
    if not s.seg_max_spread >= 0:
        raise UserError(f"seg_max_spread must be >= 0, got {s.seg_max_spread}")


def _safe(name: str) -> str:
    import re

    return re.sub(r"[^0-9A-Za-z_.-]", "_", name)


def _sequence_metrics(model, scene: str, scene_dir: Path, cameras, caster, anchors, s: EvalSettings, ks, orb,
                      rows_shown, progress: bool):
    """Translate one trajectory, render its ceiling, floor and a_ref, and score every row."""
    from tqdm import tqdm

    from sim2real.inference.frames import chunked, iter_gbuffers
    from sim2real.inference.rows import sequence_row
    from sim2real.render.motion import MotionMeter
    from sim2real.render.reference import reference_rendering, to_uint8
    from sim2real.render.warp import flow as gt_flow

    T = len(cameras)
    frames: dict[str, list] = {r: [] for r in rows_shown}
    points, masks, flows, valids = [], [], [], []
    meter = MotionMeter()
    prev = None
    bar = tqdm(total=T, desc=f"sequence {scene}", unit="frame", disable=not progress)
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
                frames["ceiling"].append(anchors.ceiling(g, t))
                frames["floor"].append(anchors.floor(g, t))
            points.append(np.asarray(g.points, dtype=np.float32))
            masks.append(g.mask)
            prev = g
        bar.update(len(chunk))
    bar.close()
    backward = None
    if not model.time_independent:  # the revisit half T..1, continuing the sequence's state
        backward = []
        for chunk in chunked(iter_gbuffers(scene_dir, cameras[::-1], s.workers, s.batch, caster=caster), s.batch):
            backward.extend(seq.translate(chunk))
        frames["model_backward"] = backward
    rows, ceiling_est = {}, None
    for row in ("ceiling",) + tuple(r for r in rows_shown if r != "ceiling"):
        if row in frames:
            rows[row], est = sequence_row(frames[row], points, masks, flows, valids, ks, s.threshold_mm, orb, ceiling_est,
                                          revisit=row == "model",  # the anchors reuse their forward pairs
                                          backward=backward if row == "model" else None)
            if row == "ceiling":  # against its own flow the ceiling scores 0 by definition
                ceiling_est = est
                r = rows["ceiling"]
                for key in ("of_error", "of_epe"):
                    r["per_pair"][f"{key}_vs_ceiling"] = [None if e is None else 0.0 for e in r["per_pair"][key]]
                    r[f"{key}_vs_ceiling"] = None if r[key] is None else 0.0
    return {"frames": T, "motion": meter.summary(), "rows": rows}, frames


def _sample_indices(T: int) -> list[int]:
    return sorted({0, T // 3, (2 * T) // 3, T - 1})


def _grid(rows: list[list[np.ndarray]], gap: int = 2) -> np.ndarray:
    """Tile uint8 RGB images (rows of columns) with white gaps, each fitted to the first one's size."""
    from sim2real.grid import tile

    h, w = rows[0][0].shape[:2]
    return tile([[im if im.shape[:2] == (h, w) else fit_image(im, h, w) for im in row] for row in rows], gap)


def _write_samples(out: Path, views: dict, real_imgs, seq_samples: dict, s: EvalSettings) -> dict:
    """PNG sample grids under ``out/samples``; returns {title: relative path}."""
    from sim2real.fileio import atomic_write_image

    samples: dict[str, str] = {}
    order = [r for r in ("a_ref", "model", "ceiling", "floor") if r in views]
    gen = views["model"]
    n = min(s.samples, len(gen))
    if n:
        rng = np.random.default_rng(s.seed)
        idx = sorted(rng.choice(len(gen), n, replace=False))
        atomic_write_image(out / "samples" / "views.png", _grid([[views[r][i] for r in order] for i in idx]))
        samples[f"Random views, one per row; columns: {', '.join(order)}"] = "samples/views.png"
    if real_imgs:
        atomic_write_image(out / "samples" / "real.png", _grid([real_imgs[: min(4, len(real_imgs))]]))
        samples["Real images (resized and centre-cropped as for FID)"] = "samples/real.png"
    for name, frames in seq_samples.items():
        idx = _sample_indices(len(frames["model"]))
        rel = f"samples/trajectory_{_safe(name)}.png"
        atomic_write_image(out / rel, _grid([[frames[r][i] for i in idx] for r in order]))
        samples[f"Trajectory of '{name}', frames {', '.join(str(i) for i in idx)}; rows: {', '.join(order)}"] = rel
    return samples


def _json_safe(x):
    """numpy scalars -> Python numbers, NaN/inf -> None (metrics.json is strict JSON)."""
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x
