"""``sim2real evaluate``: the paper's metrics (Sec. 4.2) for a trained run, as metrics.json + a report.

Protocol (scaled down by default so that it runs on a CPU; every number is a setting):

* **Realism.** ``views`` random views (:func:`sim2real.scene.trajectory.sample_poses`, the run's
  training size and field of view), spread evenly over the scenes, are translated. FID and KID
  compare them with up to ``max_real`` real images (resized to cover the generated size, centre
  crop) through the FID Inception network (:mod:`sim2real.metrics.inception`); without its
  weights both are ``null`` with the reason, never a number from another network. The labelled
  proxy :func:`sim2real.metrics.realism.proxy_colour_texture_distance` is always reported
  (it is *not* FID). **Dice**: a :class:`~sim2real.metrics.segmenter.LiverUNet` is trained on the
  labelled real images (``labels/NAME.png`` beside ``images/NAME.png``: uint8 class index,
  0 = liver, 255 = background) at ``seg_height x seg_width`` for ``seg_iterations`` steps and
  predicts liver on the translated views; the ground truth is the views' simulated liver pixels
  (``GBuffer.class_index() == 0``). For context the same segmenter is also scored on the
  untranslated reference renderings (``dice_a_ref``) and on its own training images
  (``dice_real_train``, a fit check, not held out).
* **Temporal consistency**, per scene on a trajectory (a given file, or a generated one of
  ``frames`` frames at the training size): OF error between the geometric flow
  (:func:`sim2real.render.warp.flow`, visible pixels only) and Farnebäck flow on consecutive
  translated frames; ORB-k accuracy and correct matches per pair for k = 1..``orb_max_k``
  (ORB-1/5/10 are the paper's); the revisit protocol (1..T, T..1) for ORB-1/5/10 and OF. The
  model is time-independent, so the backward half of the extended sequence reuses the forward
  frames (a method that depends on earlier frames would translate it). Pooled over scenes:
  ORB sums matches over all pairs, OF averages over all pairs.

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

FORMAT = "sim2real-evaluation/1"
PAPER_KS = (1, 5, 10)


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
    seg_iterations: int = 300
    seg_height: int = 128
    seg_width: int = 256
    seg_batch: int = 8
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


# --- real images ---------------------------------------------------------------------------------


@dataclass
class RealSet:
    root: Path
    label_root: Path
    images: list[Path]
    labels: list[Path | None]
    """Label file of each image, or None."""

    @property
    def labelled(self) -> list[tuple[Path, Path]]:
        return [(i, l) for i, l in zip(self.images, self.labels) if l is not None]


def find_real(directory: str | os.PathLike) -> RealSet:
    """Real images and their labels.

    ``DIR/images/`` + ``DIR/labels/`` (the stand-in real domain's layout): every image
    ``images/REL.ext`` may have ``labels/REL.png``. Otherwise every PNG/JPEG under ``DIR`` is an
    image (a ``DIR/labels/`` folder is skipped and read as above).
    """
    from sim2real.data.real import list_images

    root = Path(directory)
    if not root.is_dir():
        raise UserError(f"real image folder {root} does not exist or is not a directory")
    img_root = root / "images" if (root / "images").is_dir() else root
    lab_root = root / "labels"
    images = [p for p in list_images(img_root) if lab_root not in p.parents]
    if not images:
        raise UserError(f"no real images (png/jpg) found under {img_root}")
    labels = []
    for p in images:
        lp = (lab_root / p.relative_to(img_root)).with_suffix(".png")
        labels.append(lp if lab_root.is_dir() and lp.is_file() else None)
    return RealSet(img_root, lab_root, images, labels)


def fit_image(image: np.ndarray, height: int, width: int, nearest: bool = False) -> np.ndarray:
    """Resize so that ``image`` covers ``height x width`` (aspect kept), then crop the centre."""
    from PIL import Image

    h, w = image.shape[:2]
    if (h, w) == (height, width):
        return image
    s = max(height / h, width / w)
    nh, nw = max(height, round(h * s)), max(width, round(w * s))
    resample = Image.NEAREST if nearest else Image.BILINEAR
    im = np.asarray(Image.fromarray(image).resize((nw, nh), resample))
    top, left = (nh - height) // 2, (nw - width) // 2
    return np.ascontiguousarray(im[top:top + height, left:left + width])


def load_label(path: Path) -> np.ndarray:
    from PIL import Image

    try:
        with Image.open(path) as im:
            a = np.asarray(im)
    except Exception as e:
        raise UserError(f"cannot read label image {path}: {e}") from None
    if a.ndim != 2:
        raise UserError(f"label image {path} must be single-channel (uint8 class index, 0 = liver, 255 = background)")
    return a


def load_segmentation_set(labelled: Sequence[tuple[Path, Path]], height: int, width: int):
    """Labelled real images -> (images uint8 (N, 3, h, w), liver masks bool (N, h, w)) at the
    segmenter's size (images bilinear, labels nearest; cover + centre crop)."""
    import torch

    from sim2real.data.real import load_rgb

    xs, ys = [], []
    for ip, lp in labelled:
        img, lab = load_rgb(ip), load_label(lp)
        if lab.shape != img.shape[:2]:
            raise UserError(f"label {lp} is {lab.shape[0]}x{lab.shape[1]} but its image {ip} is "
                            f"{img.shape[0]}x{img.shape[1]}")
        xs.append(fit_image(img, height, width))
        ys.append(fit_image(lab, height, width, nearest=True) == 0)
    return _to_nchw(xs), torch.from_numpy(np.stack(ys))


def _to_nchw(frames: Sequence[np.ndarray]):
    import torch

    return torch.from_numpy(np.stack(frames)).permute(0, 3, 1, 2).contiguous()


# --- pooling -------------------------------------------------------------------------------------


def pool_orb(entries: Sequence[dict], k: int) -> dict:
    """Pool ORB-k summaries of several sequences: matches summed over all their pairs."""
    correct = sum(e["correct"] for e in entries)
    total = sum(e["total"] for e in entries)
    pairs = sum(e["pairs"] for e in entries)
    return {"k": int(k), "accuracy": correct / total if total else None, "mean_correct": correct / pairs if pairs else None,
            "correct": int(correct), "total": int(total), "pairs": int(pairs),
            "mean_matches": total / pairs if pairs else None}


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
    seg_data = load_segmentation_set(labelled, s.seg_height, s.seg_width) if labelled else None
    status = fid_weights_status(fid_weights)
    inception = None
    if status["available"]:
        from sim2real.metrics.inception import load_fid_inception

        inception = load_fid_inception(status["path"], model.device)
    out = prepare_output_dir(out)
    H, W = model.train_size
    fov = model.cfg.data.fov_x_deg
    seconds: dict[str, float] = {}

    # ---- random views: translate ----
    t0 = time.perf_counter()
    counts = [s.views // len(scenes) + (1 if k < s.views % len(scenes) else 0) for k in range(len(scenes))]
    gen, gen_liver, gen_aref = [], [], []
    casters = {}
    bar = tqdm(total=s.views, desc="views", unit="view", disable=not progress)
    for k, ((sc, d), n) in enumerate(zip(scenes, counts)):
        casters[sc.name] = caster = RayCaster(sc)
        if n == 0:
            continue
        cams = sample_poses(caster, n, H, W, fov, seed=s.seed + 1000 * k)
        for chunk in chunked(iter_gbuffers(d, cams, s.workers, s.batch, caster=caster), s.batch):
            gen.extend(model.translate_gbuffers(sc.name, chunk, s.batch))
            for g in chunk:
                gen_liver.append(g.class_index() == 0)
                gen_aref.append(to_uint8(reference_rendering(g)))
            bar.update(len(chunk))
    bar.close()
    seconds["views"] = time.perf_counter() - t0

    # ---- real images for FID/KID and the proxy ----
    rng = np.random.default_rng(s.seed)
    use = real_set.images
    if len(use) > s.max_real:
        use = [use[i] for i in sorted(rng.choice(len(use), s.max_real, replace=False))]
    real_imgs = [fit_image(load_rgb(p), H, W) for p in use]
    gen_t, real_t = _to_nchw(gen), _to_nchw(real_imgs)

    # ---- FID / KID ----
    reasons: dict[str, str | None] = {"fid": None, "dice": None, "of_error": None, "orb": None, "revisit": None}
    fid = {"fid": None, "kid_mean": None, "kid_std": None}
    fid_info = {"n_real": len(real_imgs), "n_gen": len(gen), "kid_subset_size": None, "kid_subsets": s.kid_subsets,
                "weights": status.get("path")}
    t0 = time.perf_counter()
    if inception is None:
        reasons["fid"] = status["reason"]
    elif len(gen) < 2 or len(real_imgs) < 2:
        reasons["fid"] = f"FID/KID need at least 2 images per set (got {len(real_imgs)} real, {len(gen)} generated)"
    else:
        say(f"FID/KID: Inception features of {len(real_imgs)} real and {len(gen)} generated images")
        from sim2real.metrics.realism import fid_kid

        with warnings.catch_warnings():  # torchmetrics warns that KID keeps its features: known, bounded here
            warnings.filterwarnings("ignore", message=".*will save all extracted features in buffer.*")
            r = fid_kid(gen_t, real_t, inception, kid_subset_size=s.kid_subset_size, kid_subsets=s.kid_subsets,
                        batch_size=max(s.batch, 16), seed=s.seed)
        fid = {"fid": r["fid"], "kid_mean": r["kid_mean"], "kid_std": r["kid_std"]}
        fid_info.update(kid_subset_size=r["kid_subset_size"])
        bad = [k for k, v in fid.items() if not np.isfinite(v)]
        if bad:
            reasons["fid"] = f"{', '.join(bad)} not finite (too few images for a {r['num_features']}-d covariance?)"
            fid = {k: (v if np.isfinite(v) else None) for k, v in fid.items()}
    del inception
    seconds["fid_kid"] = time.perf_counter() - t0

    from sim2real.metrics.realism import proxy_colour_texture_distance

    proxy = proxy_colour_texture_distance(gen_t, real_t)
    del gen_t, real_t

    # ---- Dice ----
    t0 = time.perf_counter()
    dice = {"dice": None, "dice_a_ref": None, "dice_real_train": None}
    dice_info = {"n_train": len(labelled), "n_eval": len(gen), "iterations": s.seg_iterations,
                 "height": s.seg_height, "width": s.seg_width}
    if not labelled:
        reasons["dice"] = (f"no labelled real images: expected {real_set.label_root}/NAME.png (uint8 class index, "
                           f"0 = liver, 255 = background) for the images {real_set.root}/NAME.*")
    else:
        say(f"Dice: training the liver U-Net on {len(labelled)} labelled real images for {s.seg_iterations} iterations")
        from sim2real.metrics.realism import dice as dice_score
        from sim2real.metrics.segmenter import predict, train_segmenter

        sh, sw = s.seg_height, s.seg_width
        x_train, y_train = seg_data
        seg = train_segmenter(x_train, y_train, s.seg_iterations, device=model.device, seed=s.seed, batch_size=s.seg_batch,
                              progress=progress)
        gt = np.stack([fit_image(m.astype(np.uint8), sh, sw, nearest=True).astype(bool) for m in gen_liver])
        pred = predict(seg, _to_nchw([fit_image(f, sh, sw) for f in gen]))
        pred_ref = predict(seg, _to_nchw([fit_image(f, sh, sw) for f in gen_aref]))
        dice = {"dice": dice_score(pred, gt), "dice_a_ref": dice_score(pred_ref, gt),
                "dice_real_train": dice_score(predict(seg, x_train), y_train)}
        del seg
    seconds["dice"] = time.perf_counter() - t0

    # ---- temporal consistency per scene ----
    t0 = time.perf_counter()
    per_scene: dict[str, dict] = {}
    seq_samples: dict[str, tuple[list, list]] = {}
    inputs_scenes = []
    ks = sorted(set(range(1, s.orb_max_k + 1)) | set(PAPER_KS))
    for k, (sc, d) in enumerate(scenes):
        if trajs is not None:
            traj = trajs[k]
        else:
            traj = make_trajectory(casters[sc.name], s.frames, H, W, fov, seed=s.seed + k)
        inputs_scenes.append({"name": sc.name, "scene_dir": str(d),
                              "trajectory": str(Path(trajectories[k]).resolve()) if trajectories is not None else None,
                              "frames": len(traj.cameras)})
        res, frames, arefs = _sequence_metrics(model, sc.name, d, traj.cameras, casters[sc.name], s, ks, progress)
        per_scene[sc.name] = res
        seq_samples[sc.name] = (frames, arefs)
        write_video(frames, out / "videos" / f"{_safe(sc.name)}.mp4", fps=traj.fps)
    seconds["consistency"] = time.perf_counter() - t0
    casters.clear()

    scene_list = list(per_scene.values())
    orb = {str(k): pool_orb([r["orb_curve"][str(k)] for r in scene_list], k) for k in ks}
    of_all = [e for r in scene_list for e in r["of_error_per_pair"]]
    of_error = _mean(of_all)
    revisit = {"of_error": _mean([e for r in scene_list for e in r["revisit"]["of_error_per_pair"]]),
               "orb": {str(k): pool_orb([r["revisit"]["orb"][str(k)] for r in scene_list], k) for k in PAPER_KS},
               "backward_frames": scene_list[0]["revisit"]["backward_frames"]}
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

    seconds["total"] = time.perf_counter() - t_start
    metrics = {
        "format": FORMAT,
        "run": {"dir": str(Path(run).resolve()), "checkpoint": str(model.checkpoint.resolve()), "step": model.step,
                "method": model.cfg.method, "device": str(model.device), "amp_bf16": model.amp,
                "train_height": H, "train_width": W},
        "settings": {**dataclasses.asdict(s), "fid_weights": status.get("path")},
        "inputs": {"scenes": inputs_scenes,
                   "real": {"dir": str(Path(real).resolve()), "images": len(real_set.images), "images_used": len(use),
                            "labelled": len(labelled)}},
        **fid,
        "fid_kid": fid_info,
        "proxy": proxy,
        **dice,
        "dice_info": dice_info,
        "of_error": of_error,
        "orb": paper_orb,
        "orb_curve": orb,
        "revisit": revisit,
        "per_scene": per_scene,
        "reasons": reasons,
        "seconds": {k: round(v, 3) for k, v in seconds.items()},
    }
    metrics = _json_safe(metrics)
    say("writing the report")
    samples = _write_samples(out, gen, gen_aref, real_imgs, seq_samples, s)
    write_report(metrics, out, samples)
    atomic_write_json(out / "metrics.json", metrics)  # last: its presence marks a complete evaluation
    return metrics


def check_settings(s: EvalSettings) -> None:
    """Refuse settings outside their range (a :class:`UserError`)."""
    for name in ("views", "frames", "batch", "max_real", "seg_height", "seg_width", "seg_batch", "orb_features",
                 "orb_max_k", "kid_subset_size", "kid_subsets", "samples"):
        if getattr(s, name) < (0 if name == "samples" else 1):
            raise UserError(f"evaluation setting {name} must be positive, got {getattr(s, name)}")
    if s.frames < 2:
        raise UserError(f"a trajectory needs at least 2 frames, got {s.frames}")
    if s.seg_iterations < 0:
        raise UserError(f"seg_iterations must be >= 0, got {s.seg_iterations}")
    if not s.threshold_mm > 0:
        raise UserError(f"threshold_mm must be positive, got {s.threshold_mm}")


def _safe(name: str) -> str:
    import re

    return re.sub(r"[^0-9A-Za-z_.-]", "_", name)


def _sequence_metrics(model, scene: str, scene_dir: Path, cameras, caster, s: EvalSettings, ks, progress: bool):
    """Translate one trajectory and compute OF, the ORB curve and the revisit protocol."""
    from tqdm import tqdm

    from sim2real.inference.frames import chunked, iter_gbuffers
    from sim2real.metrics.consistency import of_error_sequence, orb_curve, revisit_of, revisit_orb
    from sim2real.render.reference import reference_rendering, to_uint8
    from sim2real.render.warp import flow as gt_flow

    T = len(cameras)
    frames, points, masks, flows, valids, arefs = [], [], [], [], [], []
    prev = None
    bar = tqdm(total=T, desc=f"sequence {scene}", unit="frame", disable=not progress)
    for chunk in chunked(iter_gbuffers(scene_dir, cameras, s.workers, s.batch, caster=caster), s.batch):
        for g, f in zip(chunk, model.translate_gbuffers(scene, chunk, s.batch)):
            if prev is not None:
                fl, vis = gt_flow(prev, g)
                flows.append(fl)
                valids.append(vis)
            frames.append(f)
            points.append(np.asarray(g.points, dtype=np.float32))
            masks.append(g.mask)
            arefs.append(to_uint8(reference_rendering(g)) if _is_sample_index(len(frames) - 1, T) else None)
            prev = g
        bar.update(len(chunk))
    bar.close()
    of = of_error_sequence(frames, flows, valids)
    curve = orb_curve(frames, points, masks, ks=ks, threshold_mm=s.threshold_mm, n_features=s.orb_features)
    # Extended sequence 1..T, T..1. Our model is time-independent (TrainedModel.time_independent),
    # so its backward half equals the forward frames reversed; a method conditioned on earlier
    # frames would translate the backward half itself and plug it in here.
    assert model.time_independent
    frames_ext, backward = frames + frames[::-1], "reused: the model is time-independent"
    rev_of = revisit_of(frames_ext, flows, valids)
    rev_orb = {str(k): revisit_orb(frames_ext, points, masks, k, s.threshold_mm, s.orb_features) for k in PAPER_KS}
    result = {
        "frames": T,
        "of_error": of["of_error"],
        "of_error_per_pair": of["per_pair"],
        "orb": {str(k): curve[k] for k in PAPER_KS},
        "orb_curve": {str(k): curve[k] for k in ks},
        "revisit": {"of_error": rev_of["of_error"], "of_error_per_pair": rev_of["per_pair"], "orb": rev_orb,
                    "backward_frames": backward},
    }
    return result, frames, arefs


def _sample_indices(T: int) -> list[int]:
    return sorted({0, T // 3, (2 * T) // 3, T - 1})


def _is_sample_index(i: int, T: int) -> bool:
    return i in _sample_indices(T)


def _grid(rows: list[list[np.ndarray]], gap: int = 2) -> np.ndarray:
    """Tile uint8 RGB images (rows of columns) with white gaps, each fitted to the first one's size."""
    from sim2real.grid import tile

    h, w = rows[0][0].shape[:2]
    return tile([[im if im.shape[:2] == (h, w) else fit_image(im, h, w) for im in row] for row in rows], gap)


def _write_samples(out: Path, gen, gen_aref, real_imgs, seq_samples, s: EvalSettings) -> dict:
    """PNG sample grids under ``out/samples``; returns {title: relative path}."""
    from sim2real.fileio import atomic_write_image

    samples: dict[str, str] = {}
    n = min(s.samples, len(gen))
    if n:
        rng = np.random.default_rng(s.seed)
        idx = sorted(rng.choice(len(gen), n, replace=False))
        atomic_write_image(out / "samples" / "views.png", _grid([[gen_aref[i], gen[i]] for i in idx]))
        samples["Random views: reference rendering a_ref (left), translated (right)"] = "samples/views.png"
    if real_imgs:
        atomic_write_image(out / "samples" / "real.png", _grid([real_imgs[: min(4, len(real_imgs))]]))
        samples["Real images (resized and centre-cropped as for FID)"] = "samples/real.png"
    for name, (frames, arefs) in seq_samples.items():
        idx = _sample_indices(len(frames))
        rel = f"samples/trajectory_{_safe(name)}.png"
        atomic_write_image(out / rel, _grid([[arefs[i] for i in idx], [frames[i] for i in idx]]))
        samples[f"Trajectory of '{name}', frames {', '.join(str(i) for i in idx)}: a_ref (top), translated (bottom)"] = rel
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
