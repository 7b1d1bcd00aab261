"""Two methods the project does not know, for the plug-in and revisit tests.

* ``toy_plugin``: b_hat = tanh(0.1 conv(a_ref) + 2 pattern(s)), with ``pattern`` fixed value noise
  on the surface point s (mm), so the video is 3D-consistent and ORB finds features;
  time-independent.
* ``toy_drift``: the same, but the pattern slides along the surface by ``drift_mm`` for every frame
  the sequence has translated before: a history-dependent method whose consecutive frames agree
  closely while a view revisited many frames later does not (the failure the paper's revisit
  protocol exposes).
"""

from __future__ import annotations

from dataclasses import dataclass

import pytest
import torch
from torch import nn

from sim2real.config import MethodConfig
from sim2real.methods import METHODS
from sim2real.methods.base import METHOD_CONFIGS, Method, OptimGroup, SequenceTranslator, Stage, register_method_config

_VOLUME = torch.rand(1, 1, 32, 32, 32, generator=torch.Generator().manual_seed(0)) * 2 - 1


def pattern(points: torch.Tensor, shift_mm: float = 0.0) -> torch.Tensor:
    """(B, H, W, 3) surface points -> (B, 1, H, W) in [-1, 1]: value noise fixed to the surface
    (a seeded 32^3 random volume of 2 mm cells, trilinear, repeating every 64 mm), slid along x
    by ``shift_mm``."""
    p = points.float() + torch.tensor([shift_mm, 0.0, 0.0])
    grid = torch.remainder(p / 64.0, 1.0) * 2 - 1  # (B, H, W, 3) in [-1, 1)
    vol = _VOLUME.to(points.device).expand(p.shape[0], -1, -1, -1, -1)
    return torch.nn.functional.grid_sample(vol, grid[:, None], mode="bilinear", align_corners=False)[:, :, 0]


@dataclass
class ToyConfig(MethodConfig):
    name = "toy_plugin"
    gain: float = 2.0
    """Weight of the toy's only generator term."""


@dataclass
class DriftConfig(ToyConfig):
    name = "toy_drift"
    drift_mm: float = 0.3
    """How far the pattern slides per frame translated before."""


class ToyGen(Stage):
    def __init__(self):
        super().__init__()
        self.conv = nn.Conv2d(3, 3, 3, padding=1)


class ToyDis(Stage):
    def __init__(self):
        super().__init__()
        self.conv = nn.Conv2d(3, 1, 3, padding=1)


class Toy(Method):
    name = "toy_plugin"
    config_cls = ToyConfig
    image_keys = ("a_ref_i", "real")

    @property
    def data(self):
        return "views"

    def build(self, sources):
        return ToyGen(), ToyDis()

    def optim_groups(self, gen, dis):
        return [OptimGroup("g", list(gen.parameters()), 1e-2, "gen"), OptimGroup("d", list(dis.parameters()), 1e-2, "dis")]

    def loss_weights(self, step):
        return {"fit": self.mc.gain, "d": 1.0}

    def translate(self, gen, batch, step):
        return {"b_hat": self.translate_frames(gen, batch)}

    def dis_losses(self, dis, batch, out):
        return {"d": ((dis.conv(out["b_hat"].detach()) ** 2).mean() + ((dis.conv(batch["real"]) - 1) ** 2).mean())}

    def gen_losses(self, dis, batch, out, step):
        return {"fit": (out["b_hat"] - batch["real"]).abs().mean()}

    def inference_stage(self, state, where):
        return ToyGen(), [None] * len(state["scenes"])

    def translate_frames(self, gen, batch, shift_mm: float = 0.0):
        return torch.tanh(0.1 * gen.conv(batch["a_ref_i"]) + 2.0 * pattern(batch["points_i"], shift_mm))


class DriftSequence(SequenceTranslator):
    def __init__(self, *args):
        super().__init__(*args)
        self.seen = 0

    def push(self, gbuffers):
        out = []
        for g in gbuffers:  # frame by frame: each one shifted by the frames before it
            batch = self.method.inference_batch([g], self.scene_index, self.device)
            out.append(self.method.translate_frames(self.gen, batch, self.seen * self.method.mc.drift_mm))
            self.seen += 1
        return torch.cat(out)


class Drift(Toy):
    name = "toy_drift"
    config_cls = DriftConfig
    time_independent = False

    def sequence(self, gen, scene_index, device):
        return DriftSequence(self, gen, scene_index, device)


@pytest.fixture
def toy_methods():
    """Register both toys for one test."""
    for cfg, method in ((ToyConfig, Toy), (DriftConfig, Drift)):
        register_method_config(cfg)
        METHODS[method.name] = method
    yield
    for name in ("toy_plugin", "toy_drift"):
        METHODS.pop(name)
        METHOD_CONFIGS.pop(name)
