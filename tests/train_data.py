"""Small inputs for the training tests, built once per pytest session (under its base temp)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def scene_dir(base: Path, seed: int) -> Path:
    """A procedural scene saved as a folder (scene.json + meshes), cached in ``base``."""
    from sim2real.scene.procedural import generate_scene

    path = Path(base) / f"scene_{seed}"
    if not (path / "scene.json").is_file():
        generate_scene(seed).save(path)
    return path


def real_dir(base: Path, n: int = 4, name: str = "real", modes=("RGB",)) -> Path:
    """``n`` smooth colour images of varying sizes and the given PIL modes."""
    from PIL import Image

    path = Path(base) / name
    if path.is_dir():
        return path
    path.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for k in range(n):
        h, w = int(rng.integers(70, 140)), int(rng.integers(130, 300))
        yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
        f = rng.uniform(2, 6, 3)
        rgb = np.stack([0.5 + 0.4 * np.sin(f[c] * (xx + c * yy) * np.pi) for c in range(3)], -1)
        img = Image.fromarray((rgb * 255).astype(np.uint8))
        mode = modes[k % len(modes)]
        if mode != "RGB":
            img = img.convert(mode)
        img.save(path / f"img_{k:02d}.png")
    return path


def real_video_dir(base: Path, frames: int = 6, name: str = "real_video") -> Path:
    """A real folder whose only images are one sequence (``sequences/000/images``) of ``frames``
    consecutive frames of a slowly moving smooth pattern (the video methods need sequences)."""
    from PIL import Image

    path = Path(base) / name
    seq = path / "sequences" / "000" / "images"
    if seq.is_dir():
        return path
    seq.mkdir(parents=True)
    yy, xx = np.mgrid[0:96, 0:192] / 192.0
    for k in range(frames):
        rgb = np.stack([0.5 + 0.4 * np.sin((3 + c) * (xx + 0.02 * k + c * yy) * np.pi) for c in range(3)], -1)
        Image.fromarray((rgb * 255).astype(np.uint8)).save(seq / f"{k:04d}.png")
    return path


def tiny_config(method: str = "ours", **changes):
    """The tiny preset of ``method`` with ``section.field=value`` changes (as ``--method`` and
    ``--set`` would apply them)."""
    from sim2real.config import override
    from sim2real.presets import preset

    return override(preset("tiny", method), [f"{k.replace('__', '.')}={v}" for k, v in changes.items()])


def views_dir(base: Path, scene_path: Path, n: int = 4, height: int = 64, width: int = 128, name: str | None = None) -> Path:
    """A views folder (cached G-buffers + views.json) of ``n`` random views of a scene folder."""
    from sim2real.data.views import write_views_manifest
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import sample_poses

    path = Path(base) / (name or f"views_{Path(scene_path).name}_{n}")
    if (path / "views.json").is_file():
        return path
    scene = Scene.load(scene_path)
    caster = RayCaster(scene)
    for k, cam in enumerate(sample_poses(caster, n, height, width, 75.0, seed=5)):
        caster.render(cam).save(path / f"view_{k:05d}.npz")
    write_views_manifest(path, scene.name, scene_path, n)
    return path


def train_logged(cfg, scenes, real, run):
    """Train ``cfg`` on one scene folder into ``run``; returns (trainer, {step: logged values})."""
    from sim2real.engine.trainer import Trainer

    trainer = Trainer(cfg, [scenes], real, run, progress=False)
    seen: dict = {}
    trainer.hooks.append(lambda s, v: seen.__setitem__(s, v))
    try:
        trainer.train()
    finally:
        trainer.close()
    return trainer, seen


def weighted_total(trainer, values: dict, step: int) -> float:
    """sum(weight * term) of the generator terms logged at ``step``, by the method's weights."""
    w = trainer.method.loss_weights(step)
    return sum(w[k[4:]] * v for k, v in values.items() if k.startswith("gen/") and k != "gen/total")


def resume_run(run, iterations: int):
    """Resume ``run`` from its last checkpoint with its own saved configuration until ``iterations``;
    returns the trainer (``.step`` is where it ended) and the step it resumed at."""
    from sim2real.engine.checkpoint import load_checkpoint
    from sim2real.engine.trainer import Trainer
    from sim2real.presets import config_from_dict

    last = Path(run) / "checkpoints" / "last.pt"
    cfg = config_from_dict(load_checkpoint(last)["config"])
    cfg.iterations = iterations
    trainer = Trainer(cfg, None, None, run, resume=last, progress=False)
    start = trainer.step
    try:
        trainer.train()
    finally:
        trainer.close()
    return trainer, start


def child_env(**extra: str) -> dict[str, str]:
    """The environment of a child Python process: this checkout's ``src`` first on PYTHONPATH,
    then whatever the parent's PYTHONPATH held (packages installed by PYTHONPATH stay visible),
    and ``extra``."""
    import os

    src = str(Path(__file__).resolve().parents[1] / "src")
    path = os.pathsep.join(p for p in (src, os.environ.get("PYTHONPATH")) if p)
    return {**os.environ, "PYTHONPATH": path, **extra}
