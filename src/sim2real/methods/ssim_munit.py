"""``ssim_munit`` (Pfeiffer et al. 2019): MUNIT **with styles** and input noise, + MS-SSIM losses.

The paper's first baseline (supplementary, "Baselines"): our translator with MUNIT's style path
kept (models/style.py: style encoders, 8-dim styles, AdaIN decoders whose parameters an MLP
computes from the style) and Gaussian noise of std ``noise_std`` added to every generator input,
as the authors' release's ``AdaINGen.encode`` does. Domain A is a_ref alone (3 channels, no
neural texture), domain B is RGB. Data: one simulated view and one real crop per step (batch 1).

One iteration (x_a = a_ref in [-1, 1], x_b = real crop, sigma = ``noise_std``, every n a fresh
N(0, I) image, s_a, s_b fresh N(0, I) styles, ``E^c``/``E^s`` content/style encoders)::

    c_a, s'_a = E^c_A(x_a + sigma n), E^s_A(x_a + sigma n)        (likewise c_b, s'_b from x_b)
    a_rec = G_A(c_a, s'_a)         b_rec = G_B(c_b, s'_b)          within-domain reconstruction
    b_hat = G_B(c_a, s_b)          a_hat = G_A(c_b, s_a)           cross-domain, sampled styles
    c_a_rec, s_b_rec = E_B(b_hat + sigma n)   c_b_rec, s_a_rec = E_A(a_hat + sigma n)
    a_cyc = G_A(c_a_rec, s'_a)     b_cyc = G_B(c_b_rec, s'_b)      (MUNIT's "explicit cycle")

Unweighted terms (L1 = mean absolute difference) and their weights (MUNIT's names in brackets):

    adv_a, adv_b       LSGAN (D(fake) - 1)^2 on a_hat, b_hat, multi-scale D     loss.adv = 1  [gan_w]
    rec_a, rec_b       L1(a_rec, x_a), L1(b_rec, x_b)                          loss.rec = 10 [recon_x_w]
    style_a, style_b   L1(s_a_rec, s_a), L1(s_b_rec, s_b)                      style_rec = 1 [recon_s_w]
    content_a/_b       L1(c_a_rec, c_a), L1(c_b_rec, c_b)                      loss.content = 1 [recon_c_w]
    cyc_a, cyc_b       L1(a_cyc, x_a), L1(b_cyc, x_b)                          loss.cyc = 10 [recon_x_cyc_w]
    ssim_ab            1 - MS-SSIM(grey(a_ref), grey(b_hat))                   loss.ssim_ab = 5
    ssim_ba            1 - MS-SSIM(grey(x_b), grey(a_hat))                     loss.ssim_ba = 3
    dis_a, dis_b       LSGAN D terms on the detached fakes                     loss.adv = 1

MUNIT's edges2* configs switch the explicit cycle off (recon_x_cyc_w 0); its sim-to-real
config (synthia2cityscape) uses 10, and the paper describes its own translator, whose
lambda_cyc is 10, as this model without styles and noise: the paper wins, the shared
``loss.cyc`` (10) applies. MUNIT's perceptual (VGG) term is not part of the paper's losses and
is left out. The discriminators see the same fakes as the generator step (the trainer computes
the translations once), not a second draw of styles as MUNIT's ``dis_update`` does.

**Inference.** A sequence (:class:`StyleSequence`) gets one style, drawn once from N(0, I) with
a generator seeded by ``(inference_seed, scene index)`` and kept for all its frames (the paper:
"a randomly drawn but fixed style"). The input noise **is applied at inference** too, as in the
authors' release (the paper: SSIM-MUNIT "induces flickering since noise is injected into the
generator"): frame k of a sequence gets noise seeded by ``(inference_seed, scene index, k)``.
All inference draws are made on the CPU and moved to the device, so a frame is the same on
every device up to kernel rounding. With ``noise_std > 0`` a frame depends on its index in the
sequence, so the method is **not** time independent (a revisited view is re-noised); with
``noise_std = 0`` it is. The draws travel in the batch (``style_b`` (B, s), ``noise_a``
(B, 3, H, W) unit normal; :meth:`SsimMunit.inference_batch`), and the training forward pass
takes them from there when present, so the same input, weights and draws give the same b_hat.

**Realism evaluation** (:meth:`SsimMunit.translate_views`): each image is translated once with
a style drawn from N(0, I) and once with the style of a real image, E^s_B(real + sigma n).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from sim2real.config import MethodConfig
from sim2real.losses import l1, ms_ssim_loss, structure_ab_loss
from sim2real.methods.base import Batch, Method, OptimGroup, Out, SequenceTranslator, Stage, register_method_config, rgb
from sim2real.methods.common import DisStage, adv_terms, dis_terms, pad_apply, translator_weights
from sim2real.models.discriminator import MsImageDis
from sim2real.models.style import StyleGenerator, style_min_input_side


@register_method_config
@dataclass
class SsimMunitConfig(MethodConfig):
    """SSIM-MUNIT's own settings (the shared ``generator``, ``discriminator`` and ``loss``
    sections give the widths and the weights common with ours)."""

    name = "ssim_munit"
    style_dim: int = 8
    """Length of the style code (MUNIT: 8)."""
    mlp_dim: int = 256
    """Hidden units of the MLP from the style to the AdaIN parameters (MUNIT: 256)."""
    mlp_layers: int = 3
    """Linear layers of that MLP (MUNIT: 3)."""
    noise_std: float = 0.1
    """Std of the Gaussian noise added to every generator input, in training and at inference
    (authors' release: 0.1; 0: none, and the method becomes time independent)."""
    style_rec: float = 1.0
    """Weight of the style reconstruction L1 (MUNIT's recon_s_w: 1)."""
    inference_seed: int = 0
    """Seed of the inference draws: a sequence's style and its frames' noise."""

    def check(self, cfg, need) -> None:
        need(self.style_dim >= 1, "method.style_dim", ">= 1", self.style_dim)
        need(self.mlp_dim >= 1, "method.mlp_dim", ">= 1", self.mlp_dim)
        need(self.mlp_layers >= 1, "method.mlp_layers", ">= 1", self.mlp_layers)
        need(math.isfinite(self.noise_std) and self.noise_std >= 0, "method.noise_std", "finite and >= 0", self.noise_std)
        need(math.isfinite(self.style_rec) and self.style_rec >= 0, "method.style_rec", "a finite weight >= 0",
             self.style_rec)
        need(self.inference_seed >= 0, "method.inference_seed", ">= 0", self.inference_seed)
        need(cfg.generator.res_blocks >= 1, "generator.res_blocks", ">= 1 for ssim_munit (its AdaIN layers are there)",
             cfg.generator.res_blocks)
        side = style_min_input_side()
        short = min(cfg.data.height, cfg.data.width)
        need(short >= side, "data.height", f"with data.width at least {side} px on the short side for the style encoder",
             short)


class MunitGen(Stage):
    """gen_a (domain A: a_ref, 3 channels) and gen_b (domain B: RGB), each a StyleGenerator."""

    def __init__(self, gen_a: torch.nn.Module, gen_b: torch.nn.Module):
        super().__init__()
        self.gen_a = gen_a
        self.gen_b = gen_b


def seeded_normal(shape, *key: int) -> torch.Tensor:
    """N(0, 1) values of ``shape`` on the CPU from a generator seeded by the integers ``key``."""
    seed = int(np.random.SeedSequence([int(k) for k in key]).generate_state(1)[0])
    return torch.randn(shape, generator=torch.Generator().manual_seed(seed))


class StyleSequence(SequenceTranslator):
    """One sequence: its style is drawn at creation (seeded by ``(inference_seed, scene)``) and
    kept; frame k's input noise is seeded by ``(inference_seed, scene, k)``."""

    def __init__(self, method: "SsimMunit", gen: Stage, scene_index: int, device: torch.device):
        super().__init__(method, gen, scene_index, device)
        self.style = method.sequence_style(scene_index)
        self.frame = 0

    def push(self, gbuffers) -> torch.Tensor:
        batch = self.method.inference_batch(gbuffers, self.scene_index, self.device, first_frame=self.frame,
                                            style=self.style)
        self.frame += len(gbuffers)
        return self.method.translate_frames(self.gen, batch)


class SsimMunit(Method):
    """See the module docstring."""

    name = "ssim_munit"
    config_cls = SsimMunitConfig
    image_keys = ("a_ref_i", "real")

    def __init__(self, cfg):
        super().__init__(cfg)
        self.time_independent = self.mc.noise_std == 0

    @property
    def data(self) -> str:
        return "views"

    # --- construction ----------------------------------------------------------------------------

    def _gen(self) -> MunitGen:
        g, m = self.cfg.generator, self.mc
        return MunitGen(StyleGenerator(3, g, m.style_dim, m.mlp_dim, m.mlp_layers),
                        StyleGenerator(3, g, m.style_dim, m.mlp_dim, m.mlp_layers))

    def build(self, sources) -> tuple[MunitGen, DisStage]:
        d = self.cfg.discriminator
        return self._gen(), DisStage(MsImageDis(3, d), MsImageDis(3, d))

    def optim_groups(self, gen: MunitGen, dis: DisStage) -> list[OptimGroup]:
        lr = self.cfg.optim.lr_net
        return [OptimGroup("net", list(gen.parameters()), lr, "gen"), OptimGroup("dis", list(dis.parameters()), lr, "dis")]

    # --- schedules -------------------------------------------------------------------------------

    def loss_weights(self, step: int) -> dict[str, float]:
        w = translator_weights(self.cfg)
        w["style_a"] = w["style_b"] = float(self.mc.style_rec)
        return w

    # --- random draws ----------------------------------------------------------------------------

    def _noisy(self, x: torch.Tensor, unit: torch.Tensor | None = None) -> torch.Tensor:
        """``x + noise_std * n``, n = ``unit`` (given unit-normal draws) or fresh N(0, I)."""
        if self.mc.noise_std == 0:
            return x
        n = torch.randn_like(x) if unit is None else unit.to(device=x.device, dtype=x.dtype)
        return x + self.mc.noise_std * n

    def _style(self, batch: Batch, key: str, like: torch.Tensor) -> torch.Tensor:
        """Style ``batch[key]`` if the batch brings it, else fresh N(0, I) draws (B, style_dim)."""
        if key in batch:
            return batch[key].to(device=like.device, dtype=torch.float32)
        return torch.randn(like.shape[0], self.mc.style_dim, device=like.device)

    def sequence_style(self, scene_index: int) -> torch.Tensor:
        """The fixed style (style_dim,) of every sequence of training scene ``scene_index``."""
        return seeded_normal((self.mc.style_dim,), self.mc.inference_seed, 0, scene_index)

    def frame_noise(self, scene_index: int, frame: int, shape) -> torch.Tensor:
        """Unit-normal input noise (3, H, W) of frame ``frame`` of a sequence of ``scene_index``."""
        return seeded_normal(tuple(shape), self.mc.inference_seed, 1, scene_index, frame)

    # --- one iteration -----------------------------------------------------------------------------

    def translate(self, gen: MunitGen, batch: Batch, step: int) -> Out:
        ga, gb, mf = gen.gen_a, gen.gen_b, self.memory_format
        x_a = batch["a_ref_i"].contiguous(memory_format=mf)
        x_b = batch["real"].contiguous(memory_format=mf)
        B = x_a.shape[0]
        s_a, s_b = self._style(batch, "style_a", x_a), self._style(batch, "style_b", x_a)
        c_a, s_a_enc = ga.encode(self._noisy(x_a, batch.get("noise_a")))
        c_b, s_b_enc = gb.encode(self._noisy(x_b, batch.get("noise_b")))
        # one decoder, two (code, style) pairs: one batched call (exact: norms and AdaIN are per sample)
        b_hat, b_rec = gb.decode(torch.cat((c_a, c_b)), torch.cat((s_b, s_b_enc))).split(B)
        a_hat, a_rec = ga.decode(torch.cat((c_b, c_a)), torch.cat((s_a, s_a_enc))).split(B)
        c_b_rec, s_a_rec = ga.encode(self._noisy(a_hat))
        c_a_rec, s_b_rec = gb.encode(self._noisy(b_hat))
        out = dict(x_a=x_a, x_b=x_b, c_a=c_a, c_b=c_b, s_a=s_a, s_b=s_b, s_a_enc=s_a_enc, s_b_enc=s_b_enc,
                   b_hat=b_hat, b_rec=b_rec, a_hat=a_hat, a_rec=a_rec, c_a_rec=c_a_rec, c_b_rec=c_b_rec,
                   s_a_rec=s_a_rec, s_b_rec=s_b_rec)
        if self.cfg.loss.cyc > 0:  # MUNIT skips the explicit cycle when its weight is 0
            out["a_cyc"] = ga.decode(c_a_rec, s_a_enc)
            out["b_cyc"] = gb.decode(c_b_rec, s_b_enc)
        return out

    def dis_losses(self, dis: DisStage, batch: Batch, out: Out) -> dict[str, torch.Tensor]:
        return dis_terms(dis, out)

    def gen_losses(self, dis: DisStage, batch: Batch, out: Out, step: int) -> dict[str, torch.Tensor]:
        f = {k: v.float() for k, v in out.items() if v.is_floating_point()}
        L = self.cfg.loss
        losses = {
            **adv_terms(dis, out),
            "rec_a": l1(f["a_rec"], f["x_a"]),
            "rec_b": l1(f["b_rec"], f["x_b"]),
            "style_a": l1(f["s_a_rec"], f["s_a"]),
            "style_b": l1(f["s_b_rec"], f["s_b"]),
            "content_a": l1(f["c_a_rec"], f["c_a"]),
            "content_b": l1(f["c_b_rec"], f["c_b"]),
        }
        if "a_cyc" in out:
            losses["cyc_a"] = l1(f["a_cyc"], f["x_a"])
            losses["cyc_b"] = l1(f["b_cyc"], f["x_b"])
        if L.ssim_ab:
            losses["ssim_ab"] = structure_ab_loss(f["x_a"], f["b_hat"], L)
        if L.ssim_ba:
            losses["ssim_ba"] = ms_ssim_loss(f["x_b"], f["a_hat"], L.ssim_win, L.ssim_scales)
        return losses

    def image_rows(self, batch: Batch, out: Out) -> list[list[torch.Tensor]]:
        """Row 1: a_ref, b_hat (sampled style), a_rec, a_cyc; row 2: real, a_hat, b_rec, b_cyc."""
        cyc = lambda k, x: rgb(out[k]) if k in out else rgb(x) * 0 - 1  # noqa: E731  (black without cycle)
        return [[rgb(out["x_a"]), rgb(out["b_hat"]), rgb(out["a_rec"]), cyc("a_cyc", out["x_a"])],
                [rgb(out["x_b"]), rgb(out["a_hat"]), rgb(out["b_rec"]), cyc("b_cyc", out["x_b"])]]

    # --- inference -------------------------------------------------------------------------------

    def inference_stage(self, state: dict, where) -> tuple[MunitGen, list[int | None]]:
        return self._gen(), [None] * len(state["scenes"])

    def inference_batch(self, gbuffers, scene_index: int, device: torch.device, first_frame: int = 0,
                        style: torch.Tensor | None = None) -> Batch:
        """View tensors of ``gbuffers`` as frames ``first_frame, first_frame + 1, ...`` of a
        sequence of scene ``scene_index``, with that sequence's draws: ``style_b`` (B, style_dim),
        every row ``style`` (default: :meth:`sequence_style`), and, when ``noise_std > 0``,
        ``noise_a`` (B, 3, H, W) unit normal, frame k's from :meth:`frame_noise`."""
        batch = super().inference_batch(gbuffers, scene_index, device)
        x = batch["a_ref_i"]
        s = self.sequence_style(scene_index) if style is None else style
        batch["style_b"] = s.to(device).reshape(1, -1).expand(x.shape[0], -1)
        if self.mc.noise_std > 0:
            batch["noise_a"] = torch.stack([self.frame_noise(scene_index, first_frame + k, x.shape[1:])
                                            for k in range(x.shape[0])]).to(device)
        return batch

    def _a_to_b(self, gen: MunitGen, x_a: torch.Tensor, style: torch.Tensor, noise: torch.Tensor | None) -> torch.Tensor:
        """b = G_B(E^c_A(x_a + sigma n), style), padded to the networks' multiple and cropped back."""
        mf = self.memory_format
        x = self._noisy(x_a, noise)
        return pad_apply(lambda t: gen.gen_b.decode(gen.gen_a.enc_content(t.contiguous(memory_format=mf)), style), x,
                         2**self.cfg.generator.downsamplings)

    def inference_networks(self, gen: MunitGen) -> list[nn.Module]:
        return [gen.gen_a.enc_content, gen.gen_b.dec]  # E^c_A and G_B's decoder (_a_to_b)

    def translate_frames(self, gen: MunitGen, batch: Batch) -> torch.Tensor:
        """b_hat of the training forward pass, with the batch's ``style_b`` and ``noise_a`` (fresh
        draws from the global RNG for whichever is absent)."""
        x_a = batch["a_ref_i"]
        return self._a_to_b(gen, x_a, self._style(batch, "style_b", x_a), batch.get("noise_a"))

    def translate_views(self, gen: MunitGen, batch: Batch, real: torch.Tensor | None = None,
                        generator: torch.Generator | None = None) -> list[tuple[str, torch.Tensor]]:
        """Realism evaluation (supplementary): each view of ``batch`` translated once with a style
        drawn from N(0, I) per view (``random_style``) and, given ``real`` (B or 1, 3, h, w) in
        [-1, 1] (any size of at least 16 px), once with the style of its real image,
        E^s_B(real + sigma n) (``real_style``). Both use the same fresh input noise per view.
        Draws come from ``generator`` (a CPU torch.Generator; None: the global RNG)."""
        x_a = batch["a_ref_i"]
        B, dev = x_a.shape[0], x_a.device

        def normal(*shape):
            if generator is None:
                return torch.randn(shape, device=dev)
            return torch.randn(shape, generator=generator).to(dev)

        noise = normal(*x_a.shape) if self.mc.noise_std > 0 else None
        views = [("random_style", self._a_to_b(gen, x_a, normal(B, self.mc.style_dim), noise))]
        if real is not None:
            if real.dim() != 4 or real.shape[1] != 3 or real.shape[0] not in (1, B):
                raise ValueError(f"translate_views: real must be (1 or {B}, 3, h, w), got {tuple(real.shape)}")
            real = real.to(dev)
            r_noise = normal(*real.shape) if self.mc.noise_std > 0 else None
            style = gen.gen_b.enc_style(self._noisy(real, r_noise).contiguous(memory_format=self.memory_format))
            views.append(("real_style", self._a_to_b(gen, x_a, style.float().expand(B, -1), noise)))
        return views

    def sequence(self, gen: Stage, scene_index: int, device: torch.device) -> StyleSequence:
        return StyleSequence(self, gen, scene_index, device)
