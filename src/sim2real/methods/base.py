"""What a method is: everything specific to one way of training and running a translator.

The trainer (engine/trainer.py) and inference (inference/model.py) run any :class:`Method`
without knowing which it is. A method

* has its own typed config section, a :class:`~sim2real.config.MethodConfig` subclass
  registered under the method's name (``cfg.method``; YAML ``method: {name: ..., ...}``);
* declares the data it trains on (:attr:`Method.data`, a kind of
  :func:`sim2real.data.datasets.make_dataset`) and which batch entries stay on the host and
  which are images (:attr:`Method.host_keys`, :attr:`Method.image_keys`);
* builds its generator and discriminator :class:`Stage` modules and names their optimiser
  groups (:meth:`Method.build`, :meth:`Method.optim_groups`);
* computes one iteration: ``translate`` once, then ``dis_losses`` on the detached fakes and
  ``gen_losses``, each a dict of **unweighted** terms; :meth:`Method.loss_weights` gives the
  weight of every term at a step (the trainer sums ``weight * term`` and logs terms and
  weights apart, so curves compare across runs);
* says what the image grids show (:meth:`Method.image_rows`);
* restores its generator stage from a checkpoint for inference and translates sequences
  (:meth:`Method.inference_stage`, :meth:`Method.sequence`): the default translates each frame
  on its own, batched; a method whose output depends on earlier frames returns a stateful
  :class:`SequenceTranslator` and sets :attr:`Method.time_independent` to False;
* says which translations a realism evaluation scores (:meth:`Method.translate_views`: one by
  default, one per kind of style for a method with styles).
"""

from __future__ import annotations

import re
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable, ClassVar

import torch
from torch import nn

from sim2real.config import MethodConfig, TrainConfig
from sim2real.data.tensors import view_tensors
from sim2real.errors import UserError

Batch = dict[str, torch.Tensor]
Out = dict[str, torch.Tensor]

METHOD_CONFIGS: dict[str, type[MethodConfig]] = {}
"""Registered method config sections by method name: what a tagged ``method`` section of a config
dict or YAML file is built as (:func:`sim2real.presets.config_from_dict`)."""


def register_method_config(cls: type[MethodConfig]) -> type[MethodConfig]:
    """Class decorator: register a method's config section under its ``name``."""
    METHOD_CONFIGS[cls.name] = cls
    return cls


class Stage(nn.Module):
    """A group of modules trained by one side (generator or discriminator).

    ``stage(fn, *args)`` calls ``fn(stage, *args)``: the method's computation runs inside the
    module's ``forward``, so that a ``DistributedDataParallel`` wrapper around the stage sees
    one forward call per iteration and synchronises the gradients of everything used in it.
    """

    def forward(self, fn: Callable, *args, **kwargs):
        return fn(self, *args, **kwargs)


@dataclass
class OptimGroup:
    name: str
    """Log / checkpoint name ('net', 'tex', 'dis', ...)."""
    params: list[nn.Parameter]
    lr: float
    side: str
    """'gen' (stepped after the generator losses) or 'dis'."""
    weight_decay: float | None = None
    """Adam's weight decay for this group; None: ``optim.weight_decay`` (the authors' release: 1e-4)."""


def scene_key(name: str, taken: set[str]) -> str:
    """A ModuleDict-safe, unique key for a scene name."""
    key = "scene_" + re.sub(r"[^0-9A-Za-z_]", "_", name)
    base, k = key, 1
    while key in taken:
        key, k = f"{base}_{k}", k + 1
    return key


class SequenceTranslator:
    """Translates the frames of one sequence of one training scene, in order, chunk after chunk.

    ``push(gbuffers)`` takes the next frames' G-buffers and returns their translations
    (B, 3, H, W) in [-1, 1]. This default is stateless: every frame depends only on its own view
    (:meth:`Method.translate_frames` of :meth:`Method.inference_batch`), so chunks may have any
    size and may repeat frames. A time-dependent method subclasses it and keeps its state here
    between calls (the previous output and G-buffer, a style drawn for the sequence, ...)."""

    def __init__(self, method: "Method", gen: Stage, scene_index: int, device: torch.device):
        self.method = method
        self.gen = gen
        self.scene_index = scene_index
        self.device = device

    def push(self, gbuffers) -> torch.Tensor:
        batch = self.method.inference_batch(gbuffers, self.scene_index, self.device)
        return self.method.translate_frames(self.gen, batch)


class Method(ABC):
    """Base class; see the module docstring."""

    name: ClassVar[str] = "base"
    config_cls: ClassVar[type[MethodConfig]] = MethodConfig
    host_keys: ClassVar[tuple[str, ...]] = ("scene", "step")
    """Batch entries read by Python on the host (lists), never moved to the device."""
    image_keys: ClassVar[tuple[str, ...]] = ()
    """Batch entries that are (B, C, H, W) images (channels-last on CUDA)."""
    time_independent: ClassVar[bool] = True
    """Each frame depends only on its own view: a revisited view is translated identically, so an
    evaluation may reuse forward frames for the revisit protocol."""

    def __init__(self, cfg: TrainConfig):
        if not isinstance(cfg.method, self.config_cls):
            raise UserError(f"method '{self.name}' needs a '{self.name}' config section, got '{type(cfg.method).name}'")
        self.cfg = cfg
        self.mc = cfg.method
        self.memory_format = torch.contiguous_format
        """Image layout inside the networks; the trainer sets channels-last on CUDA."""

    # --- data --------------------------------------------------------------------------------------

    @property
    def data(self) -> str:
        """The kind of training samples (:func:`sim2real.data.datasets.make_dataset`)."""
        return "view_pairs"

    # --- construction ------------------------------------------------------------------------------

    @abstractmethod
    def build(self, sources) -> tuple[Stage, Stage]:
        """The generator stage and the discriminator stage for the training scenes ``sources``."""

    @abstractmethod
    def optim_groups(self, gen: Stage, dis: Stage) -> list[OptimGroup]:
        """Parameter groups, each with its learning rate and side ('gen' or 'dis')."""

    def scenes_record(self, gen: Stage, sources) -> list[dict]:
        """What the checkpoint stores per training scene (``state['scenes']``)."""
        return [{**s.to_json(), "key": k} for s, k in zip(sources, self.scene_keys(sources))]

    @staticmethod
    def scene_keys(sources) -> list[str]:
        keys: list[str] = []
        for s in sources:
            keys.append(scene_key(s.name, set(keys)))
        return keys

    def check_resume(self, state: dict, sources, where) -> None:
        """Refuse a checkpoint that was trained on other scenes."""
        if [s["key"] for s in state["scenes"]] != self.scene_keys(sources):
            raise UserError(f"checkpoint {where} was trained on scenes {[s['name'] for s in state['scenes']]}, "
                            f"not {[s.name for s in sources]}")

    def transferable(self, key: str) -> bool:
        """Whether state-dict entry ``key`` of the stages carries over to a run on other scenes
        (``sim2real train --init-from``); a method marks its per-scene weights False."""
        return True

    def ddp_find_unused(self, gen: Stage) -> bool:
        """Whether some generator parameters may get no gradient in a step (DDP must look for them)."""
        return False

    # --- schedules ---------------------------------------------------------------------------------

    @abstractmethod
    def loss_weights(self, step: int) -> dict[str, float]:
        """The weight of every loss term at ``step`` (a term of weight 0 need not be computed)."""

    def schedule_state(self, step: int) -> dict:
        """Loss-schedule state at ``step`` (stored in checkpoints for the record)."""
        return {"weights": self.loss_weights(step)}

    # --- one iteration -----------------------------------------------------------------------------

    @abstractmethod
    def translate(self, gen: Stage, batch: Batch, step: int) -> Out:
        """Every translation of one iteration (computed once, shared by both updates)."""

    @abstractmethod
    def dis_losses(self, dis: Stage, batch: Batch, out: Out) -> dict[str, torch.Tensor]:
        """Unweighted discriminator loss terms on the detached translations of ``out``."""

    @abstractmethod
    def gen_losses(self, dis: Stage, batch: Batch, out: Out, step: int) -> dict[str, torch.Tensor]:
        """Unweighted generator loss terms of ``out``."""

    def image_rows(self, batch: Batch, out: Out) -> list[list[torch.Tensor]]:
        return []

    # --- inference ---------------------------------------------------------------------------------

    @abstractmethod
    def inference_stage(self, state: dict, where) -> tuple[Stage, list[int | None]]:
        """The generator stage of checkpoint ``state`` (weights loaded) and, per training scene, the
        number of objects its weights are made for (None: any)."""

    def inference_batch(self, gbuffers, scene_index: int, device: torch.device) -> Batch:
        """The batch of view tensors that :meth:`translate_frames` takes for ``gbuffers``."""
        batch = {k: v.to(device) for k, v in view_tensors(gbuffers, "i").items()}
        batch["scene"] = [scene_index] * len(gbuffers)
        return batch

    @abstractmethod
    def translate_frames(self, gen: Stage, batch: Batch) -> torch.Tensor:
        """Domain A -> B for the frames of ``batch`` on their own: (B, 3, H, W) in [-1, 1]. Equals
        the training forward pass's translation of view i for the same input and weights."""

    def inference_networks(self, gen: Stage) -> list[nn.Module]:
        """The networks that carry the cost of :meth:`translate_frames`, each as the module whose
        ``forward`` it calls (``sim2real translate --compile`` compiles these in place). Default:
        none listed, so such a method cannot be compiled."""
        return []

    def translate_views(self, gen: Stage, batch: Batch, real: torch.Tensor | None = None,
                        generator: torch.Generator | None = None) -> list[tuple[str, torch.Tensor]]:
        """The translations of the views of ``batch`` that a realism evaluation scores, each
        (name, (B, 3, H, W) in [-1, 1]); names are suffixes of the result keys. ``real``: real
        images (B or 1, 3, h, w) in [-1, 1] that a method may take a style from; ``generator``:
        a CPU generator for any random draw (None: the global RNG). Default: one unnamed
        translation, :meth:`translate_frames`. A method with styles returns one per kind of style
        (ssim_munit: 'random_style' and, given ``real``, 'real_style')."""
        return [("", self.translate_frames(gen, batch))]

    def sequence(self, gen: Stage, scene_index: int, device: torch.device) -> SequenceTranslator:
        """A translator for one sequence of training scene ``scene_index`` (stateless by default)."""
        return SequenceTranslator(self, gen, scene_index, device)


def rgb(x: torch.Tensor) -> torch.Tensor:
    """First sample of a batch as a 3-channel image for the grids (1 channel is repeated)."""
    x = x[0].detach().float()
    return x[:3] if x.shape[0] >= 3 else x[:1].expand(3, -1, -1)
