"""A trained run as a model: the reusable API behind ``sim2real translate`` and ``evaluate``.

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
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from sim2real.engine import precision as numerics
from sim2real.engine.checkpoint import LAST, load_checkpoint, mismatch
from sim2real.engine.device import resolve_device
from sim2real.errors import UserError
from sim2real.inference.compiled import compile_networks
from sim2real.inference.realimages import to_nchw
from sim2real.methods import get_method
from sim2real.presets import config_from_dict
from sim2real.render.gbuffer import GBuffer
from sim2real.scene.classes import ClassTable

DEFAULT_BATCH = 8
"""Frames per network call where none is given (the evaluation's; translate's on CUDA)."""
CPU_TRANSLATE_BATCH = 2
"""Translate's frames per network call on a CPU: there a small batch keeps the activations nearer
the caches. Measured on an idle 2-core AMD EPYC (32 MiB L3), small preset at 256x512, fp32,
16 frames, medians of three passes (``bench_translate.py --batch B``): networks 1.75, 1.80,
1.57 and 1.32 frames/s at batches 1, 2, 4 and 8."""


def translate_batch(device: torch.device) -> int:
    """``sim2real translate``'s default ``--batch`` on ``device``: 8 on CUDA, 2 on a CPU."""
    return DEFAULT_BATCH if device.type == "cuda" else CPU_TRANSLATE_BATCH


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
        raise UserError(f"checkpoint {path} does not match its own configuration ({mismatch(e)})") from None
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
