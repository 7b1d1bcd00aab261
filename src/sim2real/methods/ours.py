"""``ours`` (the paper): neural texture + reference rendering -> MUNIT without styles, + L_vc.

Its named presets (:data:`sim2real.presets.METHOD_PRESETS`) are the paper's ablations, each a
value of this section, not a separate code path:

* ``ours_no_vc``: ``vc = 0`` (no view j is even rendered: the data are single views);
* ``ours_l1_vc``: ``vc_kind = 'l1'`` (L1 instead of the angle, paper Fig. 7);
* ``ours_no_tex_vc``: ``texture.features = 0, vc = 0``: domain A is a_ref alone (3 channels),
  which is SSIM-MUNIT without styles or noise, as the paper defines the ablation.

One iteration (``step``): view i's texture is projected (``a_tex = tanh(T(s))``), domain A is
``x_a = cat(a_tex, a_ref)``; every translation of MUNIT's ``gen_update`` is computed once;
view j is translated without gradient and warped into view i for L_vc once its weight is on.
Beyond the paper, ``tex_edges`` (the CPU preset's, with a noisy texture start) asks b_hat for an
edge wherever a_tex has one, so that the frames' detail stays on the surface (docs/detail_study.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import nn

from sim2real.config import MethodConfig, TextureConfig
from sim2real.errors import UserError
from sim2real.losses import edge_recall_loss, l1, ms_ssim_loss, structure_ab_loss, view_consistency, warp_backward
from sim2real.losses.consistency import VC_KINDS
from sim2real.methods.base import Batch, Method, OptimGroup, Out, Stage, register_method_config, rgb
from sim2real.methods.common import DisStage, adv_terms, dis_terms, pad_apply, translator_terms, translator_weights
from sim2real.models.discriminator import MsImageDis
from sim2real.models.translator import Translator
from sim2real.render.reference import class_albedo
from sim2real.texture.neural_texture import MAPPINGS, TANH_MODES, NeuralTexture


@register_method_config
@dataclass
class OursConfig(MethodConfig):
    """The paper's method."""

    name = "ours"
    texture: TextureConfig = field(default_factory=TextureConfig)
    vc: float = 20.0
    """View-consistency weight once switched on (0: no view consistency, no view j)."""
    vc_start: int = 10_000
    """Iteration from which the view-consistency weight is ``vc`` (0 before)."""
    vc_kind: str = "angle"
    """'angle' (lighting invariant, paper) or 'l1' (the ablation)."""
    target_grad: bool = True
    """Whether x_a as the target of rec_a and cyc_a carries gradient into the texture (the authors'
    release: it does, so the texture is also pulled towards what the translator reconstructs of it).
    False detaches the targets: the texture learns only through the translator's outputs."""
    tex_edges: float = 0.0
    """Weight of the edge recall of b_hat at the edges of the projected texture a_tex (detached; the
    ``loss.edge_*`` settings): wherever the texture has an edge, its own pattern fixed to the surface,
    the frame must have one too. Not in the paper: a lever of the detail study, because nothing else
    asks the frames' grey detail to stay put (the view-consistency angle ignores brightness). 0: off."""

    @classmethod
    def for_size(cls, size: str) -> "OursConfig":
        if size == "small":
            return cls(texture=TextureConfig(size=256), vc_start=2_000)
        if size == "tiny":
            return cls(texture=TextureConfig(size=64), vc_start=5)
        return cls()

    def check(self, cfg, need) -> None:
        t = self.texture
        need(t.size >= 1, "method.texture.size", ">= 1", t.size)
        need(t.features >= 0, "method.texture.features", ">= 0 (0: no texture)", t.features)
        need(t.mapping in MAPPINGS, "method.texture.mapping", "one of " + ", ".join(MAPPINGS), t.mapping)
        need(t.tanh in TANH_MODES, "method.texture.tanh", "one of " + ", ".join(TANH_MODES), t.tanh)
        need(math.isfinite(t.init_noise) and t.init_noise >= 0, "method.texture.init_noise", "finite and >= 0",
             t.init_noise)
        need(math.isfinite(t.init_noise_sigma) and t.init_noise_sigma > 0, "method.texture.init_noise_sigma", "> 0",
             t.init_noise_sigma)
        need(math.isfinite(t.init_lines) and t.init_lines >= 0, "method.texture.init_lines", "finite and >= 0",
             t.init_lines)
        need(math.isfinite(t.init_lines_sigma) and t.init_lines_sigma > 0, "method.texture.init_lines_sigma", "> 0",
             t.init_lines_sigma)
        need(math.isfinite(self.vc) and self.vc >= 0, "method.vc", "a finite weight >= 0", self.vc)
        need(self.vc_start >= 0, "method.vc_start", ">= 0", self.vc_start)
        need(math.isfinite(self.tex_edges) and self.tex_edges >= 0, "method.tex_edges", "a finite weight >= 0",
             self.tex_edges)
        need(self.vc_kind in VC_KINDS, "method.vc_kind", "one of " + ", ".join(VC_KINDS), self.vc_kind)


class GenStage(Stage):
    """Translator (E_A, G_A, E_B, G_B) and one neural texture per scene (keys: scene keys)."""

    def __init__(self, translator: nn.Module, textures: nn.ModuleDict, scene_keys: list[str]):
        super().__init__()
        self.translator = translator
        self.textures = textures
        self.scene_keys = list(scene_keys)


class Ours(Method):
    """See the module docstring."""

    name = "ours"
    config_cls = OursConfig
    image_keys = ("a_ref_i", "a_ref_j", "real")

    @property
    def features(self) -> int:
        return self.mc.texture.features

    @property
    def target_grad(self) -> bool:
        """Whether rec_a's and cyc_a's target x_a carries gradient (``method.target_grad``)."""
        return self.mc.target_grad

    @property
    def tex_edges(self) -> float:
        """Weight of the texture's edge recall (``method.tex_edges``); 0 without a texture."""
        return self.mc.tex_edges if self.features else 0.0

    @property
    def data(self) -> str:
        return "view_pairs" if self.mc.vc > 0 else "views"

    # --- construction ----------------------------------------------------------------------------

    def _stage(self, keys: list[str], textures: nn.ModuleDict) -> GenStage:
        return GenStage(Translator(self.features, self.cfg.generator), textures, keys)

    def build(self, sources) -> tuple[GenStage, DisStage]:
        keys, textures = self.scene_keys(sources), nn.ModuleDict()
        if self.features:
            for key, src in zip(keys, sources):
                textures[key] = NeuralTexture(len(src.classes), src.bounds, class_albedo(src.classes, src.class_table),
                                              self.mc.texture)
        gen = self._stage(keys, textures)
        d = self.cfg.discriminator
        return gen, DisStage(MsImageDis(self.features + 3, d), MsImageDis(3, d))

    def optim_groups(self, gen: GenStage, dis: DisStage) -> list[OptimGroup]:
        o = self.cfg.optim
        groups = [OptimGroup("net", list(gen.translator.parameters()), o.lr_net, "gen")]
        if self.features:
            groups.append(OptimGroup("tex", list(gen.textures.parameters()), o.lr_tex, "gen"))
        groups.append(OptimGroup("dis", list(dis.parameters()), o.lr_net, "dis"))
        return groups

    def transferable(self, key: str) -> bool:
        return not key.startswith("textures.")  # a scene's texture stays with its scene

    def ddp_find_unused(self, gen: GenStage) -> bool:
        # with several textures, those of scenes that no rank sampled in a step get no gradient
        return len(gen.textures) > 1

    # --- schedules -------------------------------------------------------------------------------

    def vc_weight(self, step: int) -> float:
        return float(self.mc.vc) if step >= self.mc.vc_start else 0.0

    def loss_weights(self, step: int) -> dict[str, float]:
        w = translator_weights(self.cfg)
        w["vc"] = self.vc_weight(step)
        w["tex_edges"] = self.tex_edges
        return w

    def schedule_state(self, step: int) -> dict:
        return {**super().schedule_state(step), "vc_weight": self.vc_weight(step), "vc_start": self.mc.vc_start,
                "vc": self.mc.vc}

    # --- one iteration -----------------------------------------------------------------------------

    def a_tex(self, gen: GenStage, batch: Batch, tag: str) -> torch.Tensor | None:
        """Projected texture of view ``tag`` (B, N, H, W), None without texture; each sample uses
        its scene's texture."""
        if not self.features:
            return None
        oid, pts, nrm = batch[f"object_id_{tag}"], batch[f"points_{tag}"], batch[f"normal_{tag}"]
        scenes = batch["scene"]  # a host list: no device sync
        scenes = scenes.tolist() if torch.is_tensor(scenes) else list(scenes)
        if len(set(scenes)) == 1:
            return gen.textures[gen.scene_keys[scenes[0]]](oid, pts, nrm)
        parts = [gen.textures[gen.scene_keys[s]](oid[b : b + 1], pts[b : b + 1], nrm[b : b + 1]) for b, s in enumerate(scenes)]
        return torch.cat(parts)

    def x_a(self, gen: GenStage, batch: Batch, tag: str) -> torch.Tensor:
        """Domain-A image of view ``tag``: ``cat(a_tex, a_ref)``, or a_ref alone without texture."""
        a_ref = batch[f"a_ref_{tag}"]
        tex = self.a_tex(gen, batch, tag)
        return a_ref if tex is None else gen.translator.join_a(tex.to(a_ref.dtype), a_ref)

    def translate(self, gen: GenStage, batch: Batch, step: int) -> Out:
        t = gen.translator
        x_a = self.x_a(gen, batch, "i").contiguous(memory_format=self.memory_format)
        out = translator_terms(t, x_a, batch["real"])
        if self.vc_weight(step) > 0:
            with torch.no_grad():  # view j: translated without gradient, no L_translation
                b_hat_j = t.dec_b(t.enc_a(self.x_a(gen, batch, "j"))).float()
                warped, mask = warp_backward(b_hat_j, batch["uv_ij"], batch["visible_ij"])
            out.update(b_hat_j=b_hat_j, b_hat_j_warped=warped, vc_mask=mask)
        return out

    def dis_losses(self, dis: DisStage, batch: Batch, out: Out) -> dict[str, torch.Tensor]:
        return dis_terms(dis, out)

    def gen_losses(self, dis: DisStage, batch: Batch, out: Out, step: int) -> dict[str, torch.Tensor]:
        f = {k: v.float() for k, v in out.items() if v.is_floating_point()}
        L, n = self.cfg.loss, self.features
        target_a = f["x_a"] if self.target_grad else f["x_a"].detach()
        losses = {
            **adv_terms(dis, out),
            "rec_a": l1(f["a_rec"], target_a),
            "rec_b": l1(f["b_rec"], f["x_b"]),
            "cyc_a": l1(f["a_cyc"], target_a),
            "cyc_b": l1(f["b_cyc"], f["x_b"]),
            "content_a": l1(f["c_a_rec"], f["c_a"]),
            "content_b": l1(f["c_b_rec"], f["c_b"]),
        }
        if L.ssim_ab:
            losses["ssim_ab"] = structure_ab_loss(f["x_a"][:, n:], f["b_hat"], L)
        if L.ssim_ba:
            losses["ssim_ba"] = ms_ssim_loss(f["x_b"], f["a_hat"][:, n:], L.ssim_win, L.ssim_scales)
        if self.tex_edges:
            tex = f["x_a"][:, :n].detach()
            tex = tex if n == 3 else tex.mean(1, keepdim=True).expand(-1, 3, -1, -1)  # grey() of equal channels: the mean
            losses["tex_edges"] = edge_recall_loss(tex, f["b_hat"], L.edge_contrast, L.edge_sigma, L.edge_power)
        if "b_hat_j_warped" in out:
            losses["vc"] = view_consistency(self.mc.vc_kind, f["b_hat"], out["b_hat_j_warped"], out["vc_mask"])
        return losses

    def image_rows(self, batch: Batch, out: Out) -> list[list[torch.Tensor]]:
        n = self.features
        ref, tex = (lambda x: rgb(x[:, n:])), (lambda x: rgb(x[:, :n]) if n else rgb(x[:, n:]))
        rows = [
            [ref(out["x_a"]), tex(out["x_a"]), rgb(out["b_hat"]), ref(out["a_rec"]), ref(out["a_cyc"])],
            [rgb(out["x_b"]), ref(out["a_hat"]), tex(out["a_hat"]), rgb(out["b_rec"]), rgb(out["b_cyc"])],
        ]
        if "b_hat_j" in out:
            mask = out["vc_mask"][0].float()[None].expand(3, -1, -1) * 2 - 1
            rows.append([rgb(batch["a_ref_j"]), rgb(out["b_hat_j"]), rgb(out["b_hat_j_warped"]),
                         rgb(out["b_hat"]) * (mask > 0) - (mask < 0).float(), mask])
        return rows

    # --- inference -------------------------------------------------------------------------------

    def inference_stage(self, state: dict, where) -> tuple[GenStage, list[int | None]]:
        gen_state = state["gen"]
        shell = replace(self.mc.texture, init_noise=0.0, init_lines=0.0)  # its texels come from the checkpoint
        keys, textures, objects = [], nn.ModuleDict(), []
        for s in state["scenes"]:
            keys.append(s["key"])
            n_obj = None
            if self.features:
                tex = gen_state.get(f"textures.{s['key']}.texture")
                if tex is None:
                    raise UserError(f"checkpoint {where} has no texture for scene '{s['name']}'")
                n_obj = int(tex.shape[0])
                textures[s["key"]] = NeuralTexture(n_obj, np.zeros((n_obj, 2, 3), np.float32), None, shell)
            objects.append(n_obj)
        return self._stage(keys, textures), objects

    def inference_networks(self, gen: GenStage) -> list[nn.Module]:
        return [gen.translator.enc_a, gen.translator.dec_b]

    def translate_frames(self, gen: GenStage, batch: Batch) -> torch.Tensor:
        t = gen.translator
        x_a = self.x_a(gen, batch, "i")
        return pad_apply(lambda x: t.dec_b(t.enc_a(x.contiguous(memory_format=self.memory_format))), x_a,
                         2**self.cfg.generator.downsamplings)

