"""Trained run -> translated frames: the reusable model API and ``sim2real translate``.

:func:`load_run` restores the generator side of a training run from ``RUN/checkpoints/last.pt``
(or a given checkpoint) through the run's own method (sim2real/methods/) and returns a
:class:`TrainedModel`. :meth:`TrainedModel.sequence` translates the frames of one sequence in
order, chunk after chunk, with the method's :class:`~sim2real.methods.base.SequenceTranslator`
(a time-dependent method carries its state across chunks); :meth:`TrainedModel.translate_gbuffers`
translates unrelated views. For ``ours`` a frame is computed exactly as the training computed
``b_hat`` for view i:

    x_a = cat(a_tex, a_ref)        a_tex = triplanar texture projection, tanh
    b_hat = G_B(E_A(x_a))          a_ref = reference rendering in [-1, 1]

in eval mode under ``torch.inference_mode``; on CUDA with bf16 autocast (when the run's
``amp`` is on) and channels-last images and weights, on the CPU in fp32. Frames are batched;
for a time-independent method each frame depends only on its own view (instance norm is per
sample): the same view always gives the same frame (bit-identical for a given batch size and
device: every network call gets exactly ``batch`` samples, see :class:`FrameSequence`). Sides
that are not multiples of ``2**generator.downsamplings`` are padded (edge replicate) for the
networks and cropped back.

:func:`translate_sequence` is the command: it streams a trajectory (ray-cast in chunks,
in-process or in a process pool) or a views folder through the model and writes
``frames/``, ``video.mp4``, ``ground_truth/`` and ``translate.json`` (docs/formats.md,
"Translate output").
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from tqdm import tqdm

from sim2real.config import to_dict
from sim2real.data.views import list_views
from sim2real.engine import precision as numerics
from sim2real.engine.checkpoint import LAST, load_checkpoint
from sim2real.engine.trainer import resolve_device
from sim2real.errors import UserError
from sim2real.fileio import atomic_write_json, deferred_fsync, fsync_files, prepare_output_dir
from sim2real.inference.compiled import compile_networks
from sim2real.inference.export import GroundTruthWriter
from sim2real.inference.frames import chunked, iter_gbuffers, iter_view_files
from sim2real.inference.realimages import to_nchw
from sim2real.inference.video import BackgroundFrameWriter, _rate
from sim2real.methods import get_method
from sim2real.presets import config_from_dict
from sim2real.render.gbuffer import GBuffer
from sim2real.scene.classes import ClassTable
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import Trajectory

FORMAT = "sim2real-translate/1"
DEFAULT_BATCH = 8


@dataclass
class SceneInfo:
    """A scene the run was trained on."""

    name: str
    key: str
    """Texture key in the generator's ModuleDict."""
    index: int
    """Index into the run's scene sources (``batch['scene']``)."""
    scene_dir: Path | None
    """Where the scene was when the run was trained (None if unknown)."""
    classes: tuple[str, ...] | None
    """Class of each object, from that scene.json when it is still there."""
    num_objects: int | None
    """Objects of the neural texture (None for the no-texture ablation)."""
    class_table: ClassTable | None = None
    """a_ref colours and label ids the run was trained with (a checkpoint from before classes
    were data has none: the defaults then)."""


def _scene_classes(scene_dir: Path | None) -> tuple[str, ...] | None:
    if scene_dir is None:
        return None
    try:
        spec = json.loads((scene_dir / "scene.json").read_text())
        return tuple(str(o["class"]) for o in spec["objects"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


class TrainedModel:
    """The generator side of a trained run, ready for inference (see the module docstring)."""

    def __init__(self, cfg, method, gen, device: torch.device, scenes: list[SceneInfo], checkpoint: Path, step: int,
                 amp: bool, compiled: bool = False):
        self.cfg = cfg
        self.method = method
        self.gen = gen
        self.device = device
        self.amp = amp
        """Whether the networks run under bf16 autocast (:func:`sim2real.engine.precision.inference_bf16`)."""
        self.compiled = compiled
        """Whether the method's inference networks are compiled (:mod:`sim2real.inference.compiled`)."""
        self.infos = {s.name: s for s in scenes}
        self.checkpoint = checkpoint
        self.step = step

    @property
    def time_independent(self) -> bool:
        """Each frame depends only on its own view (the method's property)."""
        return self.method.time_independent

    @property
    def scenes(self) -> list[str]:
        """Names of the scenes the run was trained on (and has textures for)."""
        return list(self.infos)

    @property
    def train_size(self) -> tuple[int, int]:
        """(height, width) the run was trained at."""
        return self.cfg.data.height, self.cfg.data.width

    def scene(self, name: str) -> SceneInfo:
        if name not in self.infos:
            raise UserError(f"the run was not trained on scene '{name}'; it knows: {', '.join(self.scenes)}")
        return self.infos[name]

    def check_classes(self, name: str, classes: Sequence[str], where: str = "", table: ClassTable | None = None) -> None:
        """Refuse G-buffers whose objects do not match the scene's texture, or whose classes have
        a_ref colours (``table``) other than those the run was trained with."""
        info = self.scene(name)
        classes = tuple(classes)
        src = f" ({where})" if where else ""
        if table is not None:
            known = info.class_table if info.class_table is not None else ClassTable.defaults()
            for c in dict.fromkeys(classes):
                if c not in known:
                    raise UserError(f"scene '{name}'{src} has class '{c}', for which the run has no texture or a_ref "
                                    f"colour (it knows: {', '.join(known)})")
                if table[c].a_ref != known[c].a_ref:
                    raise UserError(f"scene '{name}'{src} gives class '{c}' the a_ref colour {list(table[c].a_ref)}, "
                                    f"the run was trained with {list(known[c].a_ref)}")
        if info.classes is not None and classes != info.classes:
            raise UserError(f"scene '{name}'{src} has objects of classes {list(classes)}, but the run was trained on "
                            f"a scene '{name}' with {list(info.classes)}")
        if info.num_objects is not None and len(classes) != info.num_objects:
            raise UserError(f"scene '{name}'{src} has {len(classes)} objects, but the run's texture of '{name}' "
                            f"has {info.num_objects}")

    def check_gbuffers(self, name: str, gbuffers: Sequence[GBuffer]) -> None:
        """:meth:`check_classes` for each distinct class list and table of ``gbuffers``."""
        seen = set()
        for g in gbuffers:
            key = (tuple(g.classes), id(g.class_table))
            if key not in seen:
                seen.add(key)
                self.check_classes(name, g.classes, table=g.class_table)

    @torch.inference_mode()
    def translate_views(self, scene_name: str, gbuffers: Sequence[GBuffer], real: Sequence[np.ndarray] | None = None,
                        seed: int = 0, batch: int = DEFAULT_BATCH) -> dict[str, list[np.ndarray]]:
        """Unrelated views as a realism evaluation scores them (:meth:`Method.translate_views`):
        {variant name: uint8 (H, W, 3) frames}, one frame per view in each variant. ``real``: one
        uint8 real image per view, a style source for methods with styles (``ssim_munit`` then
        adds a 'real_style' variant); ``seed`` seeds every random draw."""
        info = self.scene(scene_name)
        gbuffers = list(gbuffers)
        gen = torch.Generator().manual_seed(int(seed))
        out: dict[str, list[np.ndarray]] = {}
        for i in range(0, len(gbuffers), batch):
            chunk = gbuffers[i : i + batch]
            self.check_gbuffers(scene_name, chunk)
            b = self.method.inference_batch(chunk, info.index, self.device)
            r = None
            if real is not None:

                r = (to_nchw([np.asarray(x) for x in real[i : i + batch]]).to(self.device) / 127.5) - 1.0
            with numerics.autocast(self.device, self.amp):
                variants = self.method.translate_views(self.gen, b, r, gen)
            for name, frames in variants:
                out.setdefault(name, []).extend(_to_uint8(frames))
        return out

    def sequence(self, scene_name: str, batch: int = DEFAULT_BATCH) -> "FrameSequence":
        """A translator for one sequence of ``scene_name``: feed it consecutive chunks of G-buffers
        (:meth:`FrameSequence.translate`); a time-dependent method carries its state across chunks."""
        return FrameSequence(self, self.scene(scene_name), batch)

    def translate_gbuffers(self, scene_name: str, gbuffers: Sequence[GBuffer], batch: int = DEFAULT_BATCH) -> list[np.ndarray]:
        """Translate unrelated views of scene ``scene_name`` -> uint8 (H, W, 3) RGB frames, in order;
        each view on its own (for a time-dependent method, as the first frame of a sequence).

        Frames of one size go through the networks ``batch`` at a time; a shorter last batch is
        padded to ``batch`` so that, for a given ``batch`` and device, a view always gives
        bit-identical pixels wherever it appears (time independence)."""
        if self.time_independent:
            return self.sequence(scene_name, batch).translate(gbuffers)
        return [self.sequence(scene_name, batch).translate([g])[0] for g in gbuffers]


def _to_uint8(images: torch.Tensor) -> list[np.ndarray]:
    """(B, 3, H, W) in [-1, 1] -> B uint8 (H, W, 3) arrays."""
    u8 = ((images.float().clamp(-1.0, 1.0) + 1.0) * 127.5).round().to(torch.uint8)
    return [np.ascontiguousarray(f) for f in u8.permute(0, 2, 3, 1).cpu().numpy()]


class FrameSequence:
    """One sequence through a :class:`TrainedModel` (the method's
    :class:`~sim2real.methods.base.SequenceTranslator` in eval mode, inference mode and autocast)."""

    def __init__(self, model: TrainedModel, info: SceneInfo, batch: int):
        if batch < 1:
            raise UserError(f"batch must be >= 1, got {batch}")
        self.model = model
        self.info = info
        self.batch = batch
        self.translator = model.method.sequence(model.gen, info.index, model.device)

    @torch.inference_mode()
    def _chunk(self, gbuffers: list[GBuffer]) -> list[np.ndarray]:
        m = self.model
        n = len(gbuffers)
        # Every call of a stateless method sees exactly `batch` samples (the last frame repeated):
        # on the CPU oneDNN picks its convolution kernels by batch size, which moved single pixels
        # by one 8-bit level; with one shape a view's frame never depends on what shares its
        # batch. A time-dependent method sees only the real frames (a repeat would be a new frame).
        pad_to = self.batch if m.method.time_independent else n
        with numerics.autocast(m.device, m.amp):
            b_hat = self.translator.push(gbuffers + [gbuffers[-1]] * (pad_to - n))
        return _to_uint8(b_hat[:n])

    def translate(self, gbuffers: Sequence[GBuffer]) -> list[np.ndarray]:
        """The next frames of the sequence -> uint8 (H, W, 3) RGB frames, in order."""
        gbuffers = list(gbuffers)
        self.model.check_gbuffers(self.info.name, gbuffers)
        out: list[np.ndarray] = []
        i = 0
        while i < len(gbuffers):
            size = (gbuffers[i].height, gbuffers[i].width)
            j = i
            while j < len(gbuffers) and j - i < self.batch and (gbuffers[j].height, gbuffers[j].width) == size:
                j += 1
            out.extend(self._chunk(gbuffers[i:j]))
            i = j
        return out


def find_checkpoint(run_dir: str | os.PathLike, checkpoint: str | os.PathLike | None = None) -> Path:
    """The checkpoint to load: ``checkpoint`` if given, else ``RUN/checkpoints/last.pt``."""
    if checkpoint is not None:
        path = Path(checkpoint)
        if not path.is_file():
            raise UserError(f"no checkpoint at {path}")
        return path
    run = Path(run_dir)
    if not run.is_dir():
        raise UserError(f"run directory {run} does not exist")
    path = run / "checkpoints" / LAST
    if not path.is_file():
        raise UserError(f"{run} holds no checkpoint (expected {path}); train it with 'sim2real train' "
                        f"or pass --checkpoint PATH")
    return path


def load_run(run_dir: str | os.PathLike, device: str | torch.device = "auto",
             checkpoint: str | os.PathLike | None = None, precision: str = "auto",
             compile: bool = False) -> TrainedModel:
    """Restore the translator and the neural textures of a run for inference.

    ``device``: 'auto' (CUDA when available), 'cpu', 'cuda' or a torch.device. The configuration,
    method and scene list come from the checkpoint itself; the scene folders are not needed
    (the textures hold their objects' bounding boxes). ``precision``: 'auto', 'fp32' or
    'bf16' (:func:`sim2real.engine.precision.inference_bf16`). ``compile``: compile the method's
    inference networks with TorchInductor (:mod:`sim2real.inference.compiled`): the first network
    call is slow, the later ones faster.
    """
    if precision not in numerics.INFERENCE_PRECISIONS:
        raise UserError(f"precision must be one of {', '.join(numerics.INFERENCE_PRECISIONS)}, got '{precision}'")
    path = find_checkpoint(run_dir, checkpoint)
    state = load_checkpoint(path)
    try:
        cfg = config_from_dict(state["config"])
        scenes_raw = list(state["scenes"])
        gen_state = state["gen"]
    except KeyError as e:
        raise UserError(f"checkpoint {path} lacks '{e.args[0]}'") from None
    method = get_method(cfg)
    dev = device if isinstance(device, torch.device) else resolve_device(str(device))
    with torch.device("cpu"):  # built on the host from the checkpoint's tensors, then moved
        gen, objects = method.inference_stage(state, path)
    infos = []
    for k, (s, n_obj) in enumerate(zip(scenes_raw, objects)):
        scene_dir = Path(s["scene_dir"]) if s.get("scene_dir") else None
        table = ClassTable.from_json(s["class_table"], f"checkpoint {path}") if "class_table" in s else None
        classes = tuple(s["classes"]) if "classes" in s else _scene_classes(scene_dir)
        infos.append(SceneInfo(str(s["name"]), s["key"], k, scene_dir, classes, n_obj, table))
    try:
        gen.load_state_dict(gen_state)
    except RuntimeError as e:
        first = str(e).strip().splitlines()[0]
        raise UserError(f"checkpoint {path} does not match its own configuration ({first})") from None
    gen.to(dev)
    if numerics.mixed_precision(dev):
        method.memory_format = torch.channels_last
        for m in gen.children():
            if not isinstance(m, torch.nn.ModuleDict):
                m.to(memory_format=torch.channels_last)
    gen.eval()
    gen.requires_grad_(False)
    amp = numerics.inference_bf16(dev, precision, cfg.amp)
    if compile:
        compile_networks(method.inference_networks(gen), dev)
    return TrainedModel(cfg, method, gen, dev, infos, path, int(state.get("step", 0)), amp, compile)


# --- the command -----------------------------------------------------------------------------------


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

    @property
    def frames(self) -> int:
        return len(self.cameras) if self.cameras is not None else len(self.view_files)


def trajectory_source(model: TrainedModel, scene: str | os.PathLike, trajectory: str | os.PathLike) -> TranslateSource:
    """``--scene`` (a scene folder, or the name of one of the run's scenes whose folder still
    exists) and ``--trajectory`` -> a source; every input is checked before anything is written."""
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
    return TranslateSource(sc.name, path.resolve(), cameras=traj.cameras, fps=traj.fps,
                           description={"kind": "trajectory", "trajectory": str(Path(trajectory).resolve()),
                                        "scene_dir": str(path.resolve())})


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
    return TranslateSource(name, scene_dir, view_files=list(files), fps=5.0,
                           description={"kind": "views", "views_dir": str(Path(views_dir).resolve())})


def translate_sequence(model: TrainedModel, source: TranslateSource, out: str | os.PathLike, batch: int = DEFAULT_BATCH,
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
    disk grows with the trajectory beyond its output.

    Everything is written into a hidden sibling folder without a flush per file; when complete,
    all its files are flushed to disk at once and the folder is renamed to ``out``: a reader sees
    no ``out`` content or all of it. Returns the manifest.
    """
    if batch < 1:
        raise UserError(f"--batch must be >= 1, got {batch}")
    fps = float(source.fps if fps is None else fps)
    _rate(fps)
    final = prepare_output_dir(out)
    out = Path(tempfile.mkdtemp(prefix=f".{final.name}.partial-", dir=final.parent))
    try:
        with deferred_fsync():
            manifest = _translate_into(model, source, out, batch, fps, workers, progress)
        fsync_files([p for p in out.rglob("*") if p.is_file() and not p.is_symlink()])
        os.replace(out, final)  # onto the empty folder prepare_output_dir accepted
        fsync_files([final.parent])
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise
    return manifest


def _translate_into(model: TrainedModel, source: TranslateSource, out: Path, batch: int, fps: float,
                    workers: int | None, progress: bool) -> dict:
    n = source.frames
    frames_dir = out / "frames"
    frames_dir.mkdir()
    t0 = time.perf_counter()
    size: list[tuple[int, int]] = []
    if source.cameras is not None:
        gbuffers = iter_gbuffers(source.scene_dir, source.cameras, workers=workers, chunk=batch)
    else:
        gbuffers = iter_view_files(source.view_files)
    i = 0
    seq = model.sequence(source.scene_name, batch)  # one sequence: a stateful method continues
    # the frames are named relative to ground_truth/ (../frames/...)
    with tqdm(total=n, desc="translate", unit="frame", disable=not progress) as bar, \
            GroundTruthWriter(out / "ground_truth", fps, [f"../frames/{k:06d}.png" for k in range(n)]) as gt:
        with BackgroundFrameWriter(frames_dir, out / "video.mp4", fps, depth=2 * batch) as writer:
            if model.compiled:  # the first chunk compiles the networks: say why the bar waits
                bar.set_description("translate (compiling the networks)")
            for chunk in chunked(gbuffers, batch):
                frames = seq.translate(chunk)
                bar.set_description("translate")
                for f in frames:
                    if not size:
                        size.append(f.shape[:2])
                    elif f.shape[:2] != size[0]:
                        raise UserError(f"frame {i} is {f.shape[0]}x{f.shape[1]}, frame 0 is {size[0][0]}x{size[0][1]}; "
                                        f"a video has one size")
                    writer.put(f)
                    i += 1
                    bar.update()
                for g in chunk:
                    gt.add(g)
        count = writer.count
        translate_s = time.perf_counter() - t0
        gt.close()
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
        "fps": fps,
        "height": h,
        "width": w,
        "device": str(model.device),
        "amp_bf16": model.amp,
        "compiled": model.compiled,
        "files": {"frames": "frames/%06d.png", "video": "video.mp4", "ground_truth": "ground_truth/"},
        "seconds": {"translate": round(translate_s, 3), "total": round(time.perf_counter() - t0, 3)},
    }
    atomic_write_json(out / "translate.json", manifest)
    return manifest
