"""A Dice that holds still: liver segmenters trained to convergence on a held-out split, over
several seeds, cached per real folder.

Protocol (every number is an :class:`~sim2real.inference.evaluate.EvalSettings` field):

* The labelled real images (the user's own labels, or the stand-in's) are split once (seeded)
  into a training part and a held-out part (``seg_holdout``, at least one image). Each of
  ``seg_seeds`` segmenters (:func:`sim2real.metrics.segmenter.train_segmenter`, flips + random
  resized crops) trains for exactly ``seg_iterations`` steps, **deterministically**: on the CPU,
  with one thread, seeded, no early stopping (a stopping rule moves with the kernels' rounding:
  on a fresh machine the demo's Dice once came out 0.89-0.97 where it had been 0.958). The
  segmenters are small (32x64 inputs), so the CPU costs little even where a GPU is present, and
  the same library versions give the same weights on every machine.
* A set of frames is scored by every segmenter. Its Dice is the mean over the seeds, reported
  with the per-seed values, their spread (max - min) and the standard error of the mean
  (sample standard deviation / sqrt(seeds)). The figure reported is the mean, so it is its
  standard error, not one segmenter's scatter, that says how far another set of seeds could move
  it: above ``seg_max_stderr`` (0.02, about +-0.04 at 95 %) the figure is marked **unstable**;
  the mean is still the value, and the reason beside it gives the seeds' range.
* Trained segmenters are cached under ``$SIM2REAL_CACHE`` (default ``~/.cache/sim2real``) in
  ``segmenters/KEY/``, KEY = SHA-256 of the labelled files' contents, every setting that
  changes training and the versions of torch, numpy and Pillow (which decode, resize and train),
  so that evaluating many methods on one real folder trains them once, and a cache made by other
  library versions is not reused.
* **Classes.** The segmenters learn every class that the real labels and the evaluated scenes
  share (``classes``: name -> label id; the default is the liver alone), one network with a logit
  per class; the Dice of the paper is the liver's, and :func:`class_dice` gives each shared
  class's. A real set's frames and labels are read through their content masks
  (:mod:`sim2real.inference.realimages`), so the segmenters never see the endoscope's surround.
"""

from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path
from typing import Sequence

import numpy as np
import PIL
import torch

from sim2real.fileio import atomic_write_bytes, atomic_write_json, cache_root
from sim2real.inference.jobs import Jobs
from sim2real.inference.realimages import fit_image, load_segmentation_set
from sim2real.metrics.realism import dice as dice_score
from sim2real.metrics.segmenter import LiverUNet, predict, predict_classes, train_segmenter
from sim2real.scene.classes import LABEL_BACKGROUND
from sim2real.threads import one_torch_thread, usable_cores

CACHE_FORMAT = "sim2real-segmenter-cache/3"
LIVER = {"liver": 0}


def library_versions() -> dict:
    """The versions that change a trained segmenter's weights."""
    return {"torch": torch.__version__, "numpy": np.__version__, "pillow": PIL.__version__}


def cache_key(labelled: Sequence[tuple[Path, Path]], spec: dict,
              masks: Sequence[Path | None] | None = None) -> str:
    """SHA-256 over the labelled images', labels' and content masks' bytes (in name order) and ``spec``."""
    h = hashlib.sha256(CACHE_FORMAT.encode())
    h.update(json.dumps(spec, sort_keys=True).encode())
    masks = list(masks) if masks is not None else [None] * len(labelled)
    rows = sorted(((ip, lp, mp) for (ip, lp), mp in zip(labelled, masks)), key=lambda p: (str(p[0].name), str(p[1].name)))
    for ip, lp, mp in rows:
        for p in (ip, lp, mp):
            if p is None:
                continue
            h.update(p.name.encode())
            h.update(hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()[:32]


def split(n: int, holdout: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, held-out) indices of ``n`` items; at least one held out and one for training
    when n >= 2 (n = 1: the one image is both, and the held-out Dice is a fit check)."""
    perm = np.random.default_rng(seed).permutation(n)
    if n < 2:
        return perm, perm
    k = min(n - 1, max(1, int(round(holdout * n))))
    return np.sort(perm[k:]), np.sort(perm[:k])


def segmenters(labelled: Sequence[tuple[Path, Path]], s, device, progress: bool = True, say=print,
               masks: Sequence[Path | None] | None = None, classes: dict[str, int] | None = None) -> tuple[list, dict]:
    """Train (or load from the cache) ``s.seg_seeds`` segmenters of ``classes`` (name -> label id,
    the first is the one ``held_out_dice`` reports; default: the liver) on the ``labelled`` images
    read through their content ``masks``; returns (models, info)."""
    classes = dict(classes or LIVER)
    if not classes:
        raise ValueError("segmenters need at least one class")
    spec = {"height": s.seg_height, "width": s.seg_width, "iterations": s.seg_iterations, "batch": s.seg_batch,
            "holdout": s.seg_holdout, "split_seed": s.seed, "crops": True, "flips": True, "base_channels": 16,
            "depth": 3, "check_every": s.seg_check_every, "early_stop": False, "device": "cpu", "threads": 1,
            "lr": 1e-3, "libraries": library_versions(), "classes": classes}
    x, y = load_segmentation_set(labelled, s.seg_height, s.seg_width, masks, list(classes.values()))
    n_cls = len(classes)
    if n_cls == 1:
        y = y[:, 0]  # one class: the liver network as it always was
    tr, ho = split(len(labelled), s.seg_holdout, s.seed)
    key = cache_key(labelled, spec, masks)
    folder = cache_root() / "segmenters" / key
    loaded: dict[int, tuple] = {}
    for k in range(s.seg_seeds):
        seed = s.seed + k
        f = folder / f"seed_{seed}.pt"
        if f.is_file():
            try:
                blob = torch.load(f, map_location="cpu", weights_only=True)
                model = LiverUNet(16, 3, n_cls)
                model.load_state_dict(blob["state_dict"])
                loaded[seed] = (model.to(device).eval(), {**json.loads(blob["meta"]), "cached": True})
            except Exception:  # a damaged cache entry is retrained, not trusted
                pass
    missing = [s.seed + k for k in range(s.seg_seeds) if s.seed + k not in loaded]
    if missing:
        say(f"Dice: training {len(missing)} U-Nets of {', '.join(classes)} (seeds {', '.join(map(str, missing))}) on "
            f"{len(tr)} labelled real images (held out: {len(ho)}; {s.seg_iterations} steps each)")
        # each on one torch thread (held here for all of them), the seeds in parallel threads: a
        # segmenter's steps run alone on its thread, so its weights are those of a sequential run
        workers = min(len(missing), 2 * usable_cores()) if usable_cores() > 1 else 1
        with one_torch_thread(), Jobs(workers) as jobs:
            trained = {seed: jobs.submit(_train, x, y, tr, ho, s, seed, progress and workers == 1) for seed in missing}
            for seed, job in trained.items():
                model, hist = job.result()
                model = model.to(device)
                meta = {"seed": seed, "history": hist, "steps": s.seg_iterations}
                buf = io.BytesIO()
                torch.save({"state_dict": {k2: v.cpu() for k2, v in model.state_dict().items()},
                            "meta": json.dumps(meta)}, buf)
                atomic_write_bytes(folder / f"seed_{seed}.pt", buf.getvalue())
                atomic_write_json(folder / "spec.json", {"format": CACHE_FORMAT, "spec": spec,
                                                         "images": [str(p[0]) for p in labelled]})
                loaded[seed] = (model, {**meta, "cached": False})
    models, per_seed = [], []
    y0 = y if n_cls == 1 else y[:, 0]
    for k in range(s.seg_seeds):
        model, meta = loaded[s.seed + k]
        meta["held_out_dice"] = dice_score(predict(model, x[ho]), y0[ho])
        meta["train_dice"] = dice_score(predict(model, x[tr]), y0[tr])
        if n_cls > 1:
            pred = predict_classes(model, x[ho])
            meta["held_out_dice_classes"] = {c: dice_score(pred[:, j], y[ho][:, j]) for j, c in enumerate(classes)}
        models.append(model)
        per_seed.append(meta)
    info = {"n_train": int(len(tr)), "n_held_out": int(len(ho)) if len(labelled) > 1 else 0, "seeds": s.seg_seeds,
            "cache": str(folder), "spec": spec, "per_seed": per_seed, "classes": classes,
            "held_out_dice": summarise([m["held_out_dice"] for m in per_seed], s.seg_max_stderr)}
    return models, info


def _train(x, y, tr, ho, s, seed: int, progress: bool):
    """One segmenter, deterministically (module docstring): (model on the CPU, validation history)."""
    hist: list = []
    model = train_segmenter(x[tr], y[tr], s.seg_iterations, device="cpu", seed=seed, batch_size=s.seg_batch,
                            crops=True, val=(x[ho], y[ho]), check_every=s.seg_check_every, history=hist,
                            progress=progress, early_stop=False)
    return model, hist


def summarise(values: Sequence[float], max_stderr: float) -> dict:
    """{"value": the mean over the seeds (None without any), "mean", "per_seed", "spread" (max -
    min), "stderr" (sample standard deviation / sqrt(n); 0 for one seed), "stable" (stderr <=
    ``max_stderr``), "reason": None when stable, else the seeds' range}."""
    v = [float(a) for a in values]
    if not v:
        return {"value": None, "mean": None, "per_seed": [], "spread": None, "stderr": None, "stable": False,
                "reason": "no segmenter"}
    mean, spread = float(np.mean(v)), max(v) - min(v)
    stderr = float(np.std(v, ddof=1) / np.sqrt(len(v))) if len(v) > 1 else 0.0
    stable = stderr <= max_stderr
    reason = None if stable else (f"unstable over segmenter seeds: {min(v):.3f}-{max(v):.3f} (standard error of the "
                                  f"mean {stderr:.3f} > {max_stderr:g}); the mean is shown")
    return {"value": mean, "mean": mean, "per_seed": v, "spread": spread, "stderr": stderr, "stable": stable,
            "reason": reason}


def dice_of(models: list, frames: Sequence[np.ndarray], gt: np.ndarray, s) -> dict:
    """:func:`summarise` of the Dice of every segmenter on ``frames`` (uint8 RGB at any size)
    against ``gt`` (N, h, w) bool at the segmenter's size."""
    x = torch.from_numpy(np.stack([fit_image(f, s.seg_height, s.seg_width) for f in frames])).permute(0, 3, 1, 2)
    return summarise([dice_score(predict(m, x.contiguous()), gt) for m in models], s.seg_max_stderr)


def class_dice(models: list, frames: Sequence[np.ndarray], views: Sequence[np.ndarray], classes: dict[str, int],
               s) -> dict:
    """Each class's :func:`summarise` over the segmenters (trained on ``classes``, in that order) of
    ``frames`` against ``views`` (label id per pixel of each view, repeated over the frames'
    variants like :func:`dice_of`'s ground truth); None for a class absent from every view (its
    Dice would be 1 for an empty prediction, which measures nothing)."""
    x = torch.from_numpy(np.stack([fit_image(f, s.seg_height, s.seg_width) for f in frames])).permute(0, 3, 1, 2)
    lab = np.stack([fit_image(np.where(v < 0, LABEL_BACKGROUND, v).astype(np.uint8), s.seg_height, s.seg_width,
                              nearest=True) for v in views])
    lab = np.concatenate([lab] * (len(frames) // len(lab)))
    preds = [predict_classes(m, x.contiguous()) for m in models]
    out = {}
    for j, (name, label) in enumerate(classes.items()):
        gt = lab == label
        out[name] = summarise([dice_score(p[:, j], gt) for p in preds], s.seg_max_stderr) if gt.any() else None
    return out
