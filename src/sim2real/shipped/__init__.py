"""The trained demo model shipped inside the package (``sim2real demo`` without ``--train``).

This folder holds, beside this module:

* ``demo_model.pt``: an inference checkpoint (``sim2real-train/1`` without optimiser, scheduler or
  random states) of the CPU preset trained on the demo's embedded data. Tensors of at least
  :data:`HALF_MIN` elements are stored in fp16 and read back as fp32 (``load_checkpoint``); small
  ones (biases, norms, texture bounding boxes) stay fp32.
* ``demo_model.json``: the record: the scene seeds and count, the stand-in real domain's seed, a
  hash of every scene's geometry (:meth:`sim2real.scene.scene.Scene.geometry_hash`), how it was
  trained, what it scored, and reference values of two translated frames of the demo's test path.
* ``demo_model_check.txt``: those two frames' cameras (a trajectory file).
* ``demo_model.yaml``: the model's training configuration, readable: the named preset it was
  trained with (:data:`PRESET`). It differs from the configuration inside the checkpoint at most
  in :data:`RUN_KEYS`, where and how long a run goes, not what it learns
  (``tests/test_shipped.py`` checks both). ``sim2real train --init-from shipped`` takes it over.

:func:`pack` makes the three files from a finished run; ``python -m sim2real.shipped`` is its
command.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import torch

from sim2real.config import differences, save_yaml, to_dict
from sim2real.engine.checkpoint import (
    FORMAT as CKPT_FORMAT,
    LAST,
    find_run_checkpoint,
    load_checkpoint,
    save_checkpoint,
)
from sim2real.errors import UserError
from sim2real.fileio import atomic_path, atomic_write_json, read_json
from sim2real.inference.model import load_run
from sim2real.presets import config_from_dict, preset
from sim2real.render.raycast import RayCaster
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory, make_trajectory

HERE = Path(__file__).resolve().parent
MODEL = "demo_model.pt"
RECORD = "demo_model.json"
CHECK_TRAJECTORY = "demo_model_check.txt"
CONFIG = "demo_model.yaml"
PRESET = "cpu-lines"
"""The named preset (:mod:`sim2real.presets`) of the shipped model's training."""
RUN_KEYS = ("device", "iterations")
"""Config keys that say where and how long a run goes; a packed run may differ from its preset there."""
FORMAT = "sim2real-shipped/1"
HALF_MIN = 1024
"""Tensors with at least this many elements are stored in fp16."""
THUMB = (16, 32)
"""Reference values of a translated frame: its mean RGB over 16 x 32 blocks (area average)."""


def model_path(root: Path = HERE) -> Path:
    return root / MODEL


def config_path(root: Path = HERE) -> Path:
    return root / CONFIG


def write_config(run_config: dict, preset_name: str, out: Path = HERE) -> None:
    """Write ``demo_model.yaml``: preset ``preset_name``, after checking that the run's config (a
    plain dict) equals it outside :data:`RUN_KEYS`; a run trained otherwise is refused, naming the
    keys (make a preset of its recipe first)."""
    want = preset(preset_name, type(config_from_dict(run_config).method).name)
    diff = [k for k, _, _ in differences(config_from_dict(run_config), want) if k not in RUN_KEYS]
    if diff:
        raise UserError(f"the run was not trained with preset '{preset_name}': it differs in {', '.join(diff)}")
    save_yaml(want, out / CONFIG)


def init_source(value: str | os.PathLike) -> str | os.PathLike:
    """What ``--init-from VALUE`` names: the shipped checkpoint for ``shipped`` (unless a path of
    that name exists), else ``value`` itself (a run folder or a checkpoint)."""
    if str(value) != "shipped" or Path(value).exists():
        return value
    load_record()  # one clear line when this installation has none
    return model_path()


def load_record(root: Path = HERE) -> dict:
    """The shipped model's record; one clear error when this installation has none."""
    if not (root / MODEL).is_file() or not (root / RECORD).is_file():
        raise UserError(f"no shipped demo model in {root}; run 'sim2real demo --train' to train one")
    record = read_json(root / RECORD, "shipped model record")
    if record.get("format") != FORMAT:
        raise UserError(f"{root / RECORD} is not a {FORMAT} record")
    return record


def scene_hashes(scenes) -> list[str]:
    """Geometry hashes of ``scenes`` (:class:`Scene` objects or scene folders)."""
    return [(s if isinstance(s, Scene) else Scene.load(s)).geometry_hash() for s in scenes]


def check_scenes(record: dict, scenes) -> None:
    """Refuse scenes (objects or folders) whose geometry is not the geometry the shipped textures
    were trained on."""
    want = record["scene_hashes"]
    got = scene_hashes(scenes)
    if len(got) != len(want):
        raise UserError(f"the shipped model was trained on {len(want)} scenes, not {len(got)}")
    for s, g, w in zip(scenes, got, want):
        if g != w:
            name = f"'{s.name}'" if isinstance(s, Scene) else str(s)
            raise UserError(f"scene {name} does not match the shipped model's scene (geometry hash {g[:12]} != "
                            f"{w[:12]}): the procedural generator changed since the model was trained; "
                            "use 'sim2real demo --train' or re-pack the model")


def thumbnail(frame: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 -> (16, 32, 3) float block means in 0..255 (H, W multiples of 16, 32)."""
    h, w, c = frame.shape
    bh, bw = h // THUMB[0], w // THUMB[1]
    return frame.astype(np.float64).reshape(THUMB[0], bh, THUMB[1], bw, c).mean(axis=(1, 3))


def reference_frames(model, scene_dir: Path, trajectory: Path) -> list[np.ndarray]:
    """The translated frames of the check trajectory (ray-cast here, translated as unrelated views)."""
    scene = Scene.load(scene_dir)
    caster = RayCaster(scene)
    gbuffers = [caster.render(cam) for cam in Trajectory.load(trajectory).cameras]
    return model.translate_gbuffers(scene.name, gbuffers)


def _halved(state: dict) -> dict:
    return {k: v.half() if v.is_floating_point() and v.numel() >= HALF_MIN else v for k, v in state.items()}


def pack(run_dir: Path, seed: int, scores: dict, out: Path = HERE, frames: int = 100,
         preset_name: str = PRESET) -> dict:
    """Make the shipped files in ``out`` from the finished run ``run_dir``, trained on the embedded
    data of seed ``seed`` (its scene folders must still exist) with preset ``preset_name``.
    ``scores``: what the run scored and, under ``trained``, how it was trained (kept in the
    record). Returns the record."""
    src = find_run_checkpoint(run_dir)
    state = load_checkpoint(src)
    scene_dirs = [Path(s["scene_dir"]) for s in state["scenes"]]
    cfg = to_dict(config_from_dict(state["config"]))  # in today's keys (an older run migrates)
    h, w = cfg["data"]["height"], cfg["data"]["width"]
    shipped = {"format": CKPT_FORMAT, "step": state["step"], "config": cfg, "method": state["method"],
               "inputs": {"scenes": [s["name"] for s in state["scenes"]], "real": "stand-in real domain"},
               "scenes": [{**s, "scene_dir": None, "views": None} for s in state["scenes"]],
               "gen": _halved(state["gen"]), "dis": _halved(state["dis"]), "world_size": state.get("world_size", 1)}
    out.mkdir(parents=True, exist_ok=True)
    write_config(cfg, preset_name, out)
    tmp = out / (MODEL + ".new")
    save_checkpoint(tmp, shipped)
    # the reference values come from the packed (fp16-rounded) model on the CPU
    traj = make_trajectory(RayCaster(Scene.load(scene_dirs[0])), frames, h, w, cfg["data"]["fov_x_deg"], seed=seed)
    check = Trajectory(traj.cameras[:2], fps=traj.fps)
    check.save(out / CHECK_TRAJECTORY)
    model = load_run(out, device="cpu", checkpoint=tmp)
    thumbs = [thumbnail(f).round(3).tolist() for f in reference_frames(model, scene_dirs[0], out / CHECK_TRAJECTORY)]
    os.replace(tmp, out / MODEL)
    record = {
        "format": FORMAT,
        "scene_seed": seed, "scenes": len(scene_dirs), "scene_names": [s["name"] for s in state["scenes"]],
        "scene_hashes": scene_hashes(scene_dirs), "real_seed": seed,
        "height": h, "width": w, "steps": int(state["step"]), "method": state["method"],
        "preset": preset_name, "trained": scores.pop("trained", None), "scores": scores,
        "reference": {"frames": thumbs, "thumbnail": list(THUMB), "device": "cpu", "torch": torch.__version__},
    }
    atomic_write_json(out / RECORD, record)
    return record


def install_run(run_dir: Path, root: Path = HERE) -> Path:
    """Copy the shipped checkpoint to ``run_dir/checkpoints/last.pt``, so that the demo's output
    holds a run folder that ``translate``, ``evaluate`` and ``train --init-from`` accept."""
    dst = Path(run_dir) / "checkpoints" / LAST
    dst.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(dst) as tmp:
        shutil.copyfile(model_path(root), tmp)
    return dst


def total_steps(record: dict) -> int:
    """Training steps of the shipped model over all its stages (its checkpoint counts the last)."""
    return (record.get("trained") or {}).get("steps", record["steps"])


def record_text(record: dict) -> str:
    """One line on what the shipped model is."""
    t = record.get("trained") or {}
    how = f", {t['minutes']:g} min on {t['machine']}" if t.get("minutes") and t.get("machine") else ""
    total = total_steps(record)
    stages = f" in all ({record['steps']} in its last stage)" if total != record["steps"] else ""
    return f"{record['method']} at {record['height']}x{record['width']}, {total} training steps{stages}{how}"
