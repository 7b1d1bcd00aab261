"""``of_unit`` (paper, "Baselines" and supplementary "OF-UNIT"): ours' translator conditioned on
its own previous frame, warped by ground-truth optical flow, instead of a neural texture.

Domain A of frame t is

    x_a(t) = cat(w_t(b̂_{t-1}), a_ref(t))          (6 channels: 3 warped previous output + 3 a_ref)

where ``w_t`` is the perfect backward warp (:func:`~sim2real.losses.consistency.warp_backward`
with the ground-truth correspondences of frame t in frame t-1): ``w_t(b̂_{t-1})`` is b̂_{t-1}
sampled where frame t's pixels lie in frame t-1, and **0** (mid-grey in [-1, 1]) where a pixel
of frame t is not visible in frame t-1. The first frame of a sequence has no previous frame:
its 3 channels are all 0. Otherwise this is ``ours`` with 3 "texture" channels: E_A, G_A (which
predicts all 6 channels), E_B, G_B, a 6-channel D_A, and every translation loss of ours (LSGAN,
reconstruction, cycle, content, MS-SSIM on the a_ref channels; shared ``loss`` section). View
consistency is the supplementary's **L1 with weight 50** between consecutive frames,

    L_vc = sum_p M_p mean_c |b̂_t - w_t(b̂_{t-1})|_{c,p} / sum_p M_p,    M = visible in t-1,

switched on at ``vc_start`` like ours' lambda (paper: lambda = 0 for the first 10^4 steps). The
paper trains 1 M iterations (``--set iterations=1000000``); the sizes are ours'.

Training on a triplet (data kind ``triplets``: simulated frames 0, 1, 2 along a random linear
camera path with ground-truth flow, and 3 consecutive real frames). The paper does not say how
b̂_prev is made during training; here the model is conditioned on **its own** previous outputs,
as at inference, by unrolling the triplet without gradient (as ours' view j; no
back-propagation through time):

    b̂_0 = G_B(E_A(cat(0, a_ref(0))))                         no gradient
    b̂_1 = G_B(E_A(cat(w_1(b̂_0), a_ref(1))))                  no gradient
    x_a  = cat(w_2(b̂_1), a_ref(2)),  x_b = real_2             every translation of MUNIT,
                                                               L_vc(b̂_2, w_2(b̂_1)) with gradient

The real side takes one real frame per step (the trained frame's index). Every
``first_frame_every``-th step (step % first_frame_every == 0; 0 = never) trains frame 0 instead,
with the zero previous frame of a sequence start (``x_a = cat(0, a_ref(0))``, x_b = real_0; L_vc
is then 0: no pixel is visible): otherwise the first frame of every inference sequence (and
every view translated on its own) would be an input the model never trained on. Default 3:
one first frame per triplet.

Inference (:class:`OfUnitSequence`) translates frame by frame: the same x_a with the previous
*translated* frame and the previous G-buffer (``correspondences(g_t, g_{t-1})``), so the output
depends on the history (``time_independent = False``; the revisit protocol translates 1..T,T..1
through one sequence). The stateless :meth:`OfUnit.translate_frames` takes the already warped
previous frame from the batch key ``prev_i`` (zeros when absent); :meth:`OfUnit.translate` takes
either a triplet (training) or such single frames (``a_ref_i``, optional ``prev_i``, ``real``),
so that the training forward pass of a frame with a given previous frame can be compared with
inference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from sim2real.config import MethodConfig
from sim2real.losses import warp_backward
from sim2real.losses.consistency import masked_l1_loss
from sim2real.methods.base import Batch, OptimGroup, Out, SequenceTranslator, register_method_config, rgb
from sim2real.methods.common import DisStage, translator_terms
from sim2real.methods.ours import GenStage, Ours
from sim2real.models.discriminator import MsImageDis
from sim2real.render.warp import correspondences

PREV_CHANNELS = 3
"""Channels of the warped previous output in domain A (in place of ours' texture features)."""
FRAMES = 3
"""Frames of a training triplet (data/triplets.py)."""


@register_method_config
@dataclass
class OfUnitConfig(MethodConfig):
    """OF-UNIT: ours' translator fed the flow-warped previous output instead of a neural texture."""

    name = "of_unit"
    vc: float = 50.0
    """Weight of the L1 consistency between consecutive frames once switched on (supplementary: 50)."""
    vc_start: int = 10_000
    """Iteration from which the consistency weight is ``vc`` (0 before), as ours' lambda."""
    first_frame_every: int = 3
    """Every this many steps (step % n == 0) train a triplet's first frame, with a zero previous
    frame, instead of its last after the no-gradient chain; 0: never."""

    @classmethod
    def for_size(cls, size: str) -> "OfUnitConfig":
        if size == "small":
            return cls(vc_start=2_000)
        if size == "tiny":
            return cls(vc_start=5)
        return cls()

    def check(self, cfg, need) -> None:
        need(math.isfinite(self.vc) and self.vc >= 0, "method.vc", "a finite weight >= 0", self.vc)
        need(self.vc_start >= 0, "method.vc_start", ">= 0", self.vc_start)
        need(self.first_frame_every >= 0, "method.first_frame_every", ">= 0 (0: never)", self.first_frame_every)


class OfUnit(Ours):
    """See the module docstring. Ours with 3 "texture" channels that hold w(b̂_prev); its
    schedule (``vc``, ``vc_start``), discriminator terms and translation losses are ours'."""

    name = "of_unit"
    config_cls = OfUnitConfig
    image_keys = ("a_ref_0", "a_ref_1", "a_ref_2", "real_0", "real_1", "real_2", "a_ref_i", "prev_i", "real")
    time_independent = False

    @property
    def features(self) -> int:
        return PREV_CHANNELS

    @property
    def data(self) -> str:
        return "triplets"

    # --- construction ----------------------------------------------------------------------------

    def build(self, sources) -> tuple[GenStage, DisStage]:
        d = self.cfg.discriminator
        gen = self._stage(self.scene_keys(sources), nn.ModuleDict())  # no neural texture
        return gen, DisStage(MsImageDis(PREV_CHANNELS + 3, d), MsImageDis(3, d))

    def optim_groups(self, gen: GenStage, dis: DisStage) -> list[OptimGroup]:
        lr = self.cfg.optim.lr_net
        return [OptimGroup("net", list(gen.translator.parameters()), lr, "gen"),
                OptimGroup("dis", list(dis.parameters()), lr, "dis")]

    def inference_stage(self, state: dict, where) -> tuple[GenStage, list[int | None]]:
        scenes = state["scenes"]
        return self._stage([s["key"] for s in scenes], nn.ModuleDict()), [None] * len(scenes)

    # --- one iteration -----------------------------------------------------------------------------

    def trains_first_frame(self, step: int) -> bool:
        """Whether ``step`` trains a triplet's first frame (zero previous frame)."""
        n = self.mc.first_frame_every
        return n > 0 and step % n == 0

    def join(self, gen: GenStage, prev: torch.Tensor | None, a_ref: torch.Tensor) -> torch.Tensor:
        """``x_a = cat(prev, a_ref)`` with ``prev`` the warped previous output (zeros if None)."""
        prev = torch.zeros_like(a_ref) if prev is None else prev.to(a_ref.dtype)
        return gen.translator.join_a(prev, a_ref).contiguous(memory_format=self.memory_format)

    def x_a(self, gen: GenStage, batch: Batch, tag: str) -> torch.Tensor:
        """Domain A of single frames: ``cat(prev_{tag}, a_ref_{tag})``, ``prev`` zeros when absent
        (ours' :meth:`translate_frames` builds its input with this)."""
        return self.join(gen, batch.get(f"prev_{tag}"), batch[f"a_ref_{tag}"])

    def translate(self, gen: GenStage, batch: Batch, step: int) -> Out:
        """A triplet: the no-gradient chain, then every translation of the trained frame (module
        docstring). Single frames (``a_ref_i``, optional ``prev_i``, ``real``): their translations."""
        if "a_ref_0" not in batch:
            return translator_terms(gen.translator, self.x_a(gen, batch, "i"), batch["real"])
        t = gen.translator
        last = 0 if self.trains_first_frame(step) else FRAMES - 1
        prev = b_prev = mask = None
        with torch.no_grad():
            for k in range(last):
                b_prev = t.dec_b(t.enc_a(self.join(gen, prev, batch[f"a_ref_{k}"]))).float()
                prev, mask = warp_backward(b_prev, batch[f"uv_{k + 1}{k}"], batch[f"visible_{k + 1}{k}"])
        a_ref = batch[f"a_ref_{last}"]
        out = translator_terms(t, self.join(gen, prev, a_ref), batch[f"real_{last}"])
        if prev is None:  # a sequence start: nothing of a previous frame is visible
            prev = torch.zeros(a_ref.shape, device=a_ref.device)
            mask = torch.zeros((a_ref.shape[0], *a_ref.shape[2:]), dtype=torch.bool, device=a_ref.device)
        else:
            out["b_hat_prev"] = b_prev
        out.update(prev_warped=prev, vc_mask=mask, frame=torch.tensor(last, device=a_ref.device))
        return out

    target_grad = True  # x_a's extra channels are w(b_hat_prev), computed without gradient: nothing to detach
    tex_edges = 0.0  # no texture whose edges the frames could keep

    def gen_losses(self, dis: DisStage, batch: Batch, out: Out, step: int) -> dict[str, torch.Tensor]:
        """Ours' translation terms and ``vc`` = masked L1(b̂_t, w_t(b̂_{t-1})) (module docstring)."""
        losses = super().gen_losses(dis, batch, out, step)
        if "prev_warped" in out:  # a triplet step (single frames carry no flow)
            losses["vc"] = masked_l1_loss(out["b_hat"].float(), out["prev_warped"], out["vc_mask"])
        return losses

    def image_rows(self, batch: Batch, out: Out) -> list[list[torch.Tensor]]:
        """Ours' rows (a_ref, w(b̂_prev), b̂, a_rec, a_cyc / b, â_ref, â_prev, b_rec, b_cyc) and, after
        a chain, (a_ref of the previous frame, b̂_prev, w(b̂_prev), b̂ on the visible pixels, mask)."""
        rows = super().image_rows(batch, out)
        if "b_hat_prev" in out:
            k = int(out["frame"]) - 1
            mask = out["vc_mask"][0].float()[None].expand(3, -1, -1) * 2 - 1
            rows.append([rgb(batch[f"a_ref_{k}"]), rgb(out["b_hat_prev"]), rgb(out["prev_warped"]),
                         rgb(out["b_hat"]) * (mask > 0) - (mask < 0).float(), mask])
        return rows

    # --- inference -------------------------------------------------------------------------------

    def sequence(self, gen: GenStage, scene_index: int, device: torch.device) -> "OfUnitSequence":
        return OfUnitSequence(self, gen, scene_index, device)


class OfUnitSequence(SequenceTranslator):
    """Frame-by-frame OF-UNIT inference for one sequence: keeps the previous translated frame
    (float, [-1, 1]) and its G-buffer; each pushed frame is translated with
    ``prev_i = w_t(b̂_{t-1})`` from ``correspondences(g_t, g_{t-1})`` (zeros for the first frame
    and where not visible), then becomes the previous frame."""

    def __init__(self, method: OfUnit, gen: GenStage, scene_index: int, device: torch.device):
        super().__init__(method, gen, scene_index, device)
        self.prev: torch.Tensor | None = None
        self.prev_gbuffer = None

    def warped_prev(self, gbuffer) -> torch.Tensor | None:
        """``w_t(b̂_{t-1})`` (1, 3, H, W) for frame ``gbuffer``; None at the start of the sequence."""
        if self.prev is None:
            return None
        uv, visible = correspondences(gbuffer, self.prev_gbuffer)
        uv_t = torch.from_numpy(uv)[None].to(self.device)
        vis_t = torch.from_numpy(visible)[None].to(self.device)
        return warp_backward(self.prev, uv_t, vis_t)[0]

    def push(self, gbuffers) -> torch.Tensor:
        frames = []
        for g in gbuffers:  # sequential: each frame needs the previous one's output
            batch = self.method.inference_batch([g], self.scene_index, self.device)
            prev = self.warped_prev(g)
            if prev is not None:
                batch["prev_i"] = prev
            b_hat = self.method.translate_frames(self.gen, batch)
            self.prev, self.prev_gbuffer = b_hat.float(), g
            frames.append(b_hat)
        return torch.cat(frames)
