"""Training variants: what one iteration computes, separate from the loop that runs it.

A :class:`Method` builds the generator side (networks + neural textures) and the
discriminator side as two :class:`Stage` modules, names their optimiser groups, and defines

* ``translate(gen, batch, step)``: every translation of the iteration, computed **once**;
* ``dis_losses(dis, batch, out)``: discriminator terms on the *detached* fakes of ``out``;
* ``gen_losses(dis, batch, out, step)``: generator/texture terms (adversarial terms use the
  discriminators just updated);
* ``image_rows(batch, out)``: what the image grids show.

Losses are dicts of named, already weighted terms; the loop sums them, logs each one and
checks them for NaN/inf. The trainer (engine/trainer.py) owns devices, AMP, DDP,
optimisers, schedules, checkpoints and logging, so the paper's other methods (SSIM-MUNIT,
ReCycle-GAN, OF-UNIT) and further ablations are new subclasses registered in
:data:`METHODS`, not new loops.

Variants now: ``ours`` (the paper), ``ours_no_vc`` (lambda_vc = 0 throughout) and
``ours_no_tex_vc`` (the texture channels are zeros and no textures are learned; no L_vc).
"""

from __future__ import annotations

import re
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable

import torch
from torch import nn

from sim2real.config import TrainConfig
from sim2real.errors import UserError
from sim2real.losses import l1, lsgan_dis_loss, lsgan_gen_loss, ms_ssim_loss, view_consistency, warp_backward
from sim2real.models.translator import build_models
from sim2real.texture.neural_texture import NeuralTexture

Batch = dict[str, torch.Tensor]
Out = dict[str, torch.Tensor]


class Stage(nn.Module):
    """A group of modules trained by one side (generator or discriminator).

    ``stage(fn, *args)`` calls ``fn(stage, *args)``: the method's computation runs inside the
    module's ``forward``, so that a ``DistributedDataParallel`` wrapper around the stage sees
    one forward call per iteration and synchronises the gradients of everything used in it.
    """

    def forward(self, fn: Callable, *args, **kwargs):
        return fn(self, *args, **kwargs)


class GenStage(Stage):
    """Translator (E_A, G_A, E_B, G_B) and one neural texture per scene (keys: :func:`texture_key`)."""

    def __init__(self, translator: nn.Module, textures: nn.ModuleDict, scene_keys: list[str]):
        super().__init__()
        self.translator = translator
        self.textures = textures
        self.scene_keys = list(scene_keys)


class DisStage(Stage):
    def __init__(self, dis_a: nn.Module, dis_b: nn.Module):
        super().__init__()
        self.dis_a = dis_a
        self.dis_b = dis_b


@dataclass
class OptimGroup:
    name: str
    """Log / checkpoint name ('net', 'tex', 'dis')."""
    params: list[nn.Parameter]
    lr: float
    side: str
    """'gen' (stepped after the generator losses) or 'dis'."""


def texture_key(name: str, taken: set[str]) -> str:
    """A ModuleDict-safe, unique key for a scene name."""
    key = "scene_" + re.sub(r"[^0-9A-Za-z_]", "_", name)
    base, k = key, 1
    while key in taken:
        key, k = f"{base}_{k}", k + 1
    return key


class Method(ABC):
    """Base class; see the module docstring. A variant implements the abstract methods."""

    name = "base"
    uses_texture = True

    def __init__(self, cfg: TrainConfig):
        self.cfg = cfg
        self.memory_format = torch.contiguous_format
        """Image layout inside the networks; the trainer sets channels-last on CUDA."""

    # --- construction ----------------------------------------------------------------------------

    @abstractmethod
    def build(self, sources) -> tuple[GenStage, DisStage]:
        """The generator stage (translator + one texture per scene) and the discriminator stage."""

    @abstractmethod
    def optim_groups(self, gen: GenStage, dis: DisStage) -> list[OptimGroup]:
        """Parameter groups, each with its learning rate and side ('gen' or 'dis')."""

    # --- schedules ---------------------------------------------------------------------------------

    def vc_weight(self, step: int) -> float:
        return 0.0

    def schedule_state(self, step: int) -> dict:
        """Loss-schedule state at ``step`` (a pure function of the step, stored for the record)."""
        return {"vc_weight": self.vc_weight(step), "vc_start": self.cfg.loss.vc_start, "vc": self.cfg.loss.vc}

    # --- one iteration -----------------------------------------------------------------------------

    @abstractmethod
    def translate(self, gen: GenStage, batch: Batch, step: int) -> Out:
        """Every translation of one iteration (computed once, shared by both updates)."""

    @abstractmethod
    def dis_losses(self, dis: DisStage, batch: Batch, out: Out) -> dict[str, torch.Tensor]:
        """Discriminator loss terms on the detached translations of ``out``."""

    @abstractmethod
    def gen_losses(self, dis: DisStage, batch: Batch, out: Out, step: int) -> dict[str, torch.Tensor]:
        """Generator/texture loss terms of ``out``."""

    def image_rows(self, batch: Batch, out: Out) -> list[list[torch.Tensor]]:
        return []


class Ours(Method):
    """The paper: neural texture + reference rendering -> MUNIT without styles, + L_vc."""

    name = "ours"

    def build(self, sources) -> tuple[GenStage, DisStage]:
        from sim2real.render.reference import class_albedo

        cfg = self.cfg
        translator, dis_a, dis_b = build_models(cfg)
        textures, keys = nn.ModuleDict(), []
        for src in sources:
            key = texture_key(src.name, set(keys))
            keys.append(key)
            if self.uses_texture:
                textures[key] = NeuralTexture(len(src.classes), src.bounds, class_albedo(src.classes), cfg.texture)
        return GenStage(translator, textures, keys), DisStage(dis_a, dis_b)

    def optim_groups(self, gen: GenStage, dis: DisStage) -> list[OptimGroup]:
        o = self.cfg.optim
        groups = [OptimGroup("net", list(gen.translator.parameters()), o.lr_net, "gen")]
        if self.uses_texture:
            groups.append(OptimGroup("tex", list(gen.textures.parameters()), o.lr_tex, "gen"))
        groups.append(OptimGroup("dis", list(dis.parameters()), o.lr_net, "dis"))
        return groups

    def vc_weight(self, step: int) -> float:
        return float(self.cfg.loss.vc) if step >= self.cfg.loss.vc_start else 0.0

    def a_tex(self, gen: GenStage, batch: Batch, tag: str) -> torch.Tensor:
        """Projected texture of view ``tag`` (B, N, H, W); each sample uses its scene's texture."""
        oid, pts, nrm = batch[f"object_id_{tag}"], batch[f"points_{tag}"], batch[f"normal_{tag}"]
        if not self.uses_texture:
            B, H, W = oid.shape
            return pts.new_zeros(B, self.cfg.texture.features, H, W)
        scenes = batch["scene"]  # a list (trainer) or a CPU tensor: no device sync
        scenes = scenes.tolist() if torch.is_tensor(scenes) else list(scenes)
        if len(set(scenes)) == 1:
            return gen.textures[gen.scene_keys[scenes[0]]](oid, pts, nrm)
        parts = [gen.textures[gen.scene_keys[s]](oid[b : b + 1], pts[b : b + 1], nrm[b : b + 1]) for b, s in enumerate(scenes)]
        return torch.cat(parts)

    def translate(self, gen: GenStage, batch: Batch, step: int) -> Out:
        t = gen.translator
        x_a = t.join_a(self.a_tex(gen, batch, "i").to(batch["a_ref_i"].dtype), batch["a_ref_i"])
        x_b = batch["real"]
        B = x_a.shape[0]
        x_a = x_a.contiguous(memory_format=self.memory_format)
        c_a, c_b = t.enc_a(x_a), t.enc_b(x_b)
        # Same decoder, two codes: one batched call (exact: the norms are per sample).
        b_hat, b_rec = t.dec_b(torch.cat((c_a, c_b))).split(B)
        a_hat, a_rec = t.dec_a(torch.cat((c_b, c_a))).split(B)
        c_a_rec, c_b_rec = t.enc_b(b_hat), t.enc_a(a_hat)
        a_cyc, b_cyc = t.dec_a(c_a_rec), t.dec_b(c_b_rec)
        out = dict(x_a=x_a, x_b=x_b, c_a=c_a, c_b=c_b, b_hat=b_hat, b_rec=b_rec, a_hat=a_hat, a_rec=a_rec,
                   c_a_rec=c_a_rec, c_b_rec=c_b_rec, a_cyc=a_cyc, b_cyc=b_cyc)
        if self.vc_weight(step) > 0:
            with torch.no_grad():  # view j: translated without gradient, no L_translation
                x_a_j = t.join_a(self.a_tex(gen, batch, "j").to(batch["a_ref_j"].dtype), batch["a_ref_j"])
                b_hat_j = t.dec_b(t.enc_a(x_a_j)).float()
                warped, mask = warp_backward(b_hat_j, batch["uv_ij"], batch["visible_ij"])
            out.update(b_hat_j=b_hat_j, b_hat_j_warped=warped, vc_mask=mask)
        return out

    def dis_losses(self, dis: DisStage, batch: Batch, out: Out) -> dict[str, torch.Tensor]:
        w = self.cfg.loss.adv
        B = out["x_a"].shape[0]
        # real and detached fake in one call per discriminator (its layers are per-sample)
        da = [s.float() for s in dis.dis_a(torch.cat((out["a_hat"].detach(), out["x_a"].detach())))]
        db = [s.float() for s in dis.dis_b(torch.cat((out["b_hat"].detach(), out["x_b"])))]
        return {
            "dis_a": w * lsgan_dis_loss([s[:B] for s in da], [s[B:] for s in da]),
            "dis_b": w * lsgan_dis_loss([s[:B] for s in db], [s[B:] for s in db]),
        }

    def gen_losses(self, dis: DisStage, batch: Batch, out: Out, step: int) -> dict[str, torch.Tensor]:
        L = self.cfg.loss
        f = {k: v.float() for k, v in out.items() if v.is_floating_point()}
        n = self.cfg.texture.features
        losses = {
            "adv_a": L.adv * lsgan_gen_loss([s.float() for s in dis.dis_a(out["a_hat"])]),
            "adv_b": L.adv * lsgan_gen_loss([s.float() for s in dis.dis_b(out["b_hat"])]),
            "rec_a": L.rec * l1(f["a_rec"], f["x_a"]),
            "rec_b": L.rec * l1(f["b_rec"], f["x_b"]),
            "cyc_a": L.cyc * l1(f["a_cyc"], f["x_a"]),
            "cyc_b": L.cyc * l1(f["b_cyc"], f["x_b"]),
            "content_a": L.content * l1(f["c_a_rec"], f["c_a"]),
            "content_b": L.content * l1(f["c_b_rec"], f["c_b"]),
        }
        if L.ssim_ab:
            losses["ssim_ab"] = L.ssim_ab * ms_ssim_loss(f["x_a"][:, n:], f["b_hat"], L.ssim_win, L.ssim_scales)
        if L.ssim_ba:
            losses["ssim_ba"] = L.ssim_ba * ms_ssim_loss(f["x_b"], f["a_hat"][:, n:], L.ssim_win, L.ssim_scales)
        lam = self.vc_weight(step)
        if lam > 0:
            losses["vc"] = lam * view_consistency(L.vc_kind, f["b_hat"], out["b_hat_j_warped"], out["vc_mask"])
        return losses

    def image_rows(self, batch: Batch, out: Out) -> list[list[torch.Tensor]]:
        n = self.cfg.texture.features

        def rgb(x):  # first sample, 3 channels
            x = x[0].detach().float()
            return x[:3] if x.shape[0] >= 3 else x[:1].expand(3, -1, -1)

        rows = [
            [rgb(out["x_a"][:, n:]), rgb(out["x_a"][:, :n]), rgb(out["b_hat"]), rgb(out["a_rec"][:, n:]), rgb(out["a_cyc"][:, n:])],
            [rgb(out["x_b"]), rgb(out["a_hat"][:, n:]), rgb(out["a_hat"][:, :n]), rgb(out["b_rec"]), rgb(out["b_cyc"])],
        ]
        if "b_hat_j" in out:
            mask = out["vc_mask"][0].float()[None].expand(3, -1, -1) * 2 - 1
            rows.append([rgb(batch["a_ref_j"]), rgb(out["b_hat_j"]), rgb(out["b_hat_j_warped"]),
                         rgb(out["b_hat"]) * (mask > 0) - (mask < 0).float(), mask])
        return rows


class OursNoVC(Ours):
    """Ablation: neural texture, but lambda_vc = 0 at every step."""

    name = "ours_no_vc"

    def vc_weight(self, step: int) -> float:
        return 0.0


class OursNoTexVC(OursNoVC):
    """Ablation: no neural texture (its channels are zeros, nothing is learned there), no L_vc."""

    name = "ours_no_tex_vc"
    uses_texture = False


METHODS: dict[str, type[Method]] = {m.name: m for m in (Ours, OursNoVC, OursNoTexVC)}


def get_method(cfg: TrainConfig) -> Method:
    if cfg.method not in METHODS:
        raise UserError(f"unknown method '{cfg.method}' (choose from {', '.join(METHODS)})")
    return METHODS[cfg.method](cfg)
