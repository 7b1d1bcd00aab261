"""``recycle`` (and ``ssim_recycle``): ReCycle-GAN, Bansal et al. 2018, as the paper compares to it.

The paper's baseline is "Bansal et al.'s approach ... the variant with additional non-temporal
cycles" of github.com/aayushbansal/Recycle-GAN (its ``reCycle_gan`` model, trained with
``scripts/run_reCycle_gan.sh``), trained on triplets of consecutive frames, batch 1. Domain A is
the reference rendering ``a_t = a_ref_t`` (3 channels) of three consecutive simulated frames along
a random linear camera path (data kind ``triplets``); domain B is three consecutive real frames
``b_t = real_t``. t = 0, 1, 2 (the paper's t-2, t-1, t).

Networks (what the paper implies by comparing to Bansal et al.'s approach: their networks, not
ours):

* generators ``G = G_A->B`` and ``F = G_B->A``: the public code's ResNet generator
  (``resnet_6blocks``, :class:`~sim2real.models.resnet_generator.ResnetGenerator`), with
  ``generator.filters`` / ``generator.downsamplings`` / ``generator.pad_type`` of the size
  preset and ``method.gen_res_blocks`` residual blocks (6 at the paper and small presets);
* temporal predictors ``P_A``, ``P_B``: the public code's U-Net (``unet_128``,
  :class:`~sim2real.models.predictor.UNetPredictor`) on the two previous frames concatenated
  along channels; ``method.pred_levels`` deep (7 as ``unet_128``; fewer for tiny images);
* discriminators ``D_A``, ``D_B``: this project's multi-scale LSGAN discriminator
  (:class:`~sim2real.models.discriminator.MsImageDis`, ``discriminator.*``) instead of the
  original's single-scale PatchGAN: every method of the comparison then has the same critic,
  whose scale 0 is a PatchGAN of ``discriminator.layers`` stride-2 layers; the loss form (LSGAN)
  is the original's.

Losses (L1 = mean absolute error, LS_G(x) = sum over scales of mean((D(x) - 1)^2), LS_D(f, r) =
sum over scales of mean(D(f)^2) + mean((D(r) - 1)^2)); per-frame terms are summed over frames as
the public code sums them::

    adv_b       = sum_{x in G(a_0), G(a_1), P_B(G(a_0), G(a_1))} LS_G(D_B(x))       (adv_a: mirror)
    recurrent_a = L1(P_A(a_0, a_1), a_2)                                         (recurrent_b: mirror)
    recycle_a   = L1(F(P_B(G(a_0), G(a_1))), a_2)                               (recycle_b: mirror)
    cyc_a       = sum_{t=0,1} L1(F(G(a_t)), a_t)                                     (cyc_b: mirror)
    idt_b       = sum_{t=0,1} L1(G(b_t), b_t),  idt_a = sum_{t=0,1} L1(F(a_t), a_t)
    ssim_ab     = sum_{t=0,1} 1 - MS-SSIM(grey a_t, grey G(a_t))       (ssim_recycle only)
    ssim_ba     = sum_{t=0,1} 1 - MS-SSIM(grey b_t, grey F(b_t))       (ssim_recycle only)
    dis_b       = 1/2 sum over (fake, real) in (G(a_0), b_0), (G(a_1), b_1),
                  (P_B(G(a_0), G(a_1)), b_2), (P_B(b_0, b_1), b_2) of LS_D(fake, real)   (dis_a: mirror)

Weights (the public code's): adversarial ``loss.adv`` = 1; recurrent, recycle and cycle L1
terms 10 (``method.recurrent``, ``method.recycle``, ``loss.cyc``); identity
``method.identity`` = 5, i.e. the public code's default ``--identity 0.5`` times lambda = 10,
which its ``run_reCycle_gan.sh`` leaves on (0 switches it off); MS-SSIM ``loss.ssim_ab`` = 5 and
``loss.ssim_ba`` = 3 when ``method.ssim`` is true (the preset ``ssim_recycle``, the paper's
"variant with MS-SSIM loss for label preservation"), else 0. The predictors get no adversarial
loss (``--adversarial_loss_p`` off) and no image pool (``--pool_size 0``).

Optimisation: Adam, beta1 0.5 (``optim.beta1``), one learning rate ``method.lr`` = 2e-4 for
generators + predictors ('gen' side) and discriminators ('dis'). The paper gives no learning rate
for its baselines; it trains them for the suggested 40 epochs with the public code, whose
learning rate is 2e-4, constant for the first 100 epochs, so 2e-4 is what the paper ran. (The
trainer's shared ``optim.lr_halve_every`` and ``optim.weight_decay`` still apply.) Batch 1,
triplets from random linear camera paths: the paper's setting.

Inference: the generator translates each frame on its own (the predictors are a training device),
``b_hat = G(a_ref)``: the default stateless sequence translator, :attr:`time_independent`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from sim2real.config import MethodConfig
from sim2real.losses import l1, lsgan_dis_loss, lsgan_gen_loss, ms_ssim_loss, structure_ab_loss
from sim2real.methods.base import Batch, Method, OptimGroup, Out, Stage, register_method_config, rgb
from sim2real.methods.common import DisStage, pad_apply
from sim2real.models.discriminator import MsImageDis
from sim2real.models.predictor import PREDICTOR_NORMS, UNetPredictor, predictor_size_error
from sim2real.models.resnet_generator import ResnetGenerator

FRAMES = 3


@register_method_config
@dataclass
class RecycleConfig(MethodConfig):
    """ReCycle-GAN (with the non-temporal cycles); ``ssim = true`` is SSIM-ReCycle."""

    name = "recycle"
    recurrent: float = 10.0
    """Weight of the recurrent loss L1(P_X(x_0, x_1), x_2) (public code: lambda = 10)."""
    recycle: float = 10.0
    """Weight of the recycle loss L1(G_Y->X(P_Y(G_X->Y(x_0), G_X->Y(x_1))), x_2) (lambda = 10)."""
    identity: float = 5.0
    """Weight of the identity loss L1(G_X->Y(y_t), y_t) (public code default: 0.5 x lambda)."""
    ssim: bool = False
    """Add the MS-SSIM losses (weights ``loss.ssim_ab`` / ``loss.ssim_ba``): SSIM-ReCycle."""
    lr: float = 2e-4
    """Adam learning rate of every network (public code; what the paper ran)."""
    gen_res_blocks: int = 6
    """Residual blocks of each ResNet generator (``resnet_6blocks``)."""
    pred_filters: int = 64
    """Channels of the predictors' first level (the public code builds its U-Net with ngf = 64)."""
    pred_levels: int = 7
    """U-Net levels (``unet_128``: 7); image sides must be multiples of 2**pred_levels."""
    pred_norm: str = "in"
    """Predictor normalisation: 'in' (instance norm, the original) or 'none'."""

    @classmethod
    def for_size(cls, size: str) -> "RecycleConfig":
        if size == "small":
            return cls(pred_filters=32)
        if size == "tiny":
            return cls(gen_res_blocks=2, pred_filters=8, pred_levels=6)
        return cls()

    def check(self, cfg, need) -> None:
        for key in ("recurrent", "recycle", "identity"):
            v = getattr(self, key)
            need(math.isfinite(v) and v >= 0, f"method.{key}", "a finite weight >= 0", v)
        need(math.isfinite(self.lr) and self.lr > 0, "method.lr", "a finite learning rate > 0", self.lr)
        need(self.gen_res_blocks >= 0, "method.gen_res_blocks", ">= 0", self.gen_res_blocks)
        need(self.pred_filters >= 1, "method.pred_filters", ">= 1", self.pred_filters)
        need(self.pred_levels >= 2, "method.pred_levels", ">= 2", self.pred_levels)
        need(self.pred_norm in PREDICTOR_NORMS, "method.pred_norm", "one of " + ", ".join(PREDICTOR_NORMS),
             self.pred_norm)
        h, w = cfg.data.height, cfg.data.width
        if predictor_size_error(h, w, self.pred_levels):
            top = max((k for k in range(2, 16) if not predictor_size_error(h, w, k)), default=None)
            fit = f"at most {top}" if top else "impossible: the sides are not multiples of 4"
            need(False, "method.pred_levels", f"such that data.height x data.width ({h}x{w}) are multiples of "
                 f"2**pred_levels ({fit})", self.pred_levels)


class RecycleGen(Stage):
    """G_A->B (``g_ab``), G_B->A (``g_ba``), P_A (``p_a``), P_B (``p_b``)."""

    def __init__(self, g_ab: nn.Module, g_ba: nn.Module, p_a: nn.Module, p_b: nn.Module):
        super().__init__()
        self.g_ab, self.g_ba, self.p_a, self.p_b = g_ab, g_ba, p_a, p_b


class Recycle(Method):
    """See the module docstring."""

    name = "recycle"
    config_cls = RecycleConfig
    image_keys = tuple(f"{k}_{t}" for k in ("a_ref", "real") for t in range(FRAMES))

    @property
    def data(self) -> str:
        return "triplets"

    # --- construction ----------------------------------------------------------------------------

    def _stage(self) -> RecycleGen:
        g, m = self.cfg.generator, self.mc
        gen = lambda: ResnetGenerator(3, 3, g.filters, g.downsamplings, m.gen_res_blocks, g.pad_type)
        pred = lambda: UNetPredictor(3, m.pred_filters, m.pred_levels, m.pred_norm)
        return RecycleGen(gen(), gen(), pred(), pred())

    def build(self, sources) -> tuple[RecycleGen, DisStage]:
        d = self.cfg.discriminator
        return self._stage(), DisStage(MsImageDis(3, d), MsImageDis(3, d))

    def optim_groups(self, gen: RecycleGen, dis: DisStage) -> list[OptimGroup]:
        # the public ReCycle-GAN code: Adam without weight decay
        return [OptimGroup("net", list(gen.parameters()), self.mc.lr, "gen", weight_decay=0.0),
                OptimGroup("dis", list(dis.parameters()), self.mc.lr, "dis", weight_decay=0.0)]

    # --- schedules -------------------------------------------------------------------------------

    def loss_weights(self, step: int) -> dict[str, float]:
        L, m = self.cfg.loss, self.mc
        return {"dis_a": L.adv, "dis_b": L.adv, "adv_a": L.adv, "adv_b": L.adv,
                "recurrent_a": m.recurrent, "recurrent_b": m.recurrent, "recycle_a": m.recycle, "recycle_b": m.recycle,
                "cyc_a": L.cyc, "cyc_b": L.cyc, "idt_a": m.identity, "idt_b": m.identity,
                "ssim_ab": L.ssim_ab if m.ssim else 0.0, "ssim_ba": L.ssim_ba if m.ssim else 0.0}

    # --- one iteration -----------------------------------------------------------------------------

    def translate(self, gen: RecycleGen, batch: Batch, step: int) -> Out:
        """Every network output of one iteration, in three batched rounds (instance norm is per
        sample, so batching is exact): the generators on frames 0, 1 (and on the other domain for
        the identity loss), the predictors, and the generators back."""
        mf = self.memory_format
        a = [batch[f"a_ref_{t}"] for t in range(FRAMES)]
        b = [batch[f"real_{t}"] for t in range(FRAMES)]
        B, idt = a[0].shape[0], self.mc.identity > 0
        a01, b01 = torch.cat(a[:2]), torch.cat(b[:2])
        ga = gen.g_ab((torch.cat((a01, b01)) if idt else a01).contiguous(memory_format=mf))
        gb = gen.g_ba((torch.cat((b01, a01)) if idt else b01).contiguous(memory_format=mf))
        b_hat01, a_hat01 = ga[: 2 * B], gb[: 2 * B]
        pair = lambda x0, x1: torch.cat((x0, x1), dim=1)  # two frames along channels
        pb = gen.p_b(torch.cat((pair(b_hat01[:B], b_hat01[B:]), pair(b[0], b[1]))))
        pa = gen.p_a(torch.cat((pair(a_hat01[:B], a_hat01[B:]), pair(a[0], a[1]))))
        b_next, pred_b2 = pb[:B], pb[B:]
        a_next, pred_a2 = pa[:B], pa[B:]
        back_a = gen.g_ba(torch.cat((b_hat01, b_next)))  # cycles of a_0, a_1 and the recycle of a_2
        back_b = gen.g_ab(torch.cat((a_hat01, a_next)))
        out = dict(b_hat=b_hat01[:B], a_hat=a_hat01[:B], b_hat01=b_hat01, a_hat01=a_hat01, b_next=b_next,
                   a_next=a_next, pred_a2=pred_a2, pred_b2=pred_b2, a_cyc01=back_a[: 2 * B], b_cyc01=back_b[: 2 * B],
                   a_recycle=back_a[2 * B :], b_recycle=back_b[2 * B :])
        if idt:
            out.update(idt_b01=ga[2 * B :], idt_a01=gb[2 * B :])
        return out

    def dis_losses(self, dis: DisStage, batch: Batch, out: Out) -> dict[str, torch.Tensor]:
        a = [batch[f"a_ref_{t}"] for t in range(FRAMES)]
        b = [batch[f"real_{t}"] for t in range(FRAMES)]

        def term(d, fakes, reals):
            n = fakes.shape[0] // 4  # 4 (fake, real) pairs, one call
            s = [x.float() for x in d(torch.cat((fakes.detach(), reals)))]
            k = lambda i: [x[i * n : (i + 1) * n] for x in s]
            return 0.5 * sum(lsgan_dis_loss(k(i), k(4 + i)) for i in range(4))

        return {"dis_b": term(dis.dis_b, torch.cat((out["b_hat01"], out["b_next"], out["pred_b2"])),
                              torch.cat((b[0], b[1], b[2], b[2]))),
                "dis_a": term(dis.dis_a, torch.cat((out["a_hat01"], out["a_next"], out["pred_a2"])),
                              torch.cat((a[0], a[1], a[2], a[2])))}

    def gen_losses(self, dis: DisStage, batch: Batch, out: Out, step: int) -> dict[str, torch.Tensor]:
        f = {k: v.float() for k, v in out.items()}
        a = [batch[f"a_ref_{t}"].float() for t in range(FRAMES)]
        b = [batch[f"real_{t}"].float() for t in range(FRAMES)]
        B = a[0].shape[0]
        two = lambda x: (x[:B], x[B:])  # frames 0 and 1 of a (2B, ...) tensor

        def adv(d, fakes):
            s = [x.float() for x in d(fakes)]
            return sum(lsgan_gen_loss([x[i * B : (i + 1) * B] for x in s]) for i in range(3))

        def per_frame(fn, x01, y):
            return sum(fn(x, t) for x, t in zip(two(x01), y))

        losses = {
            "adv_b": adv(dis.dis_b, torch.cat((out["b_hat01"], out["b_next"]))),
            "adv_a": adv(dis.dis_a, torch.cat((out["a_hat01"], out["a_next"]))),
            "recurrent_a": l1(f["pred_a2"], a[2]),
            "recurrent_b": l1(f["pred_b2"], b[2]),
            "recycle_a": l1(f["a_recycle"], a[2]),
            "recycle_b": l1(f["b_recycle"], b[2]),
            "cyc_a": per_frame(l1, f["a_cyc01"], a),
            "cyc_b": per_frame(l1, f["b_cyc01"], b),
        }
        if "idt_b01" in out:
            losses["idt_b"] = per_frame(l1, f["idt_b01"], b)
            losses["idt_a"] = per_frame(l1, f["idt_a01"], a)
        if self.mc.ssim:
            L = self.cfg.loss
            losses["ssim_ab"] = per_frame(lambda b_hat, a_t: structure_ab_loss(a_t, b_hat, L), f["b_hat01"], a)
            losses["ssim_ba"] = per_frame(lambda a_hat, b_t: ms_ssim_loss(b_t, a_hat, L.ssim_win, L.ssim_scales),
                                          f["a_hat01"], b)
        return losses

    def image_rows(self, batch: Batch, out: Out) -> list[list[torch.Tensor]]:
        """Per domain: x_0, its translation, its cycle | x_2, P_X(x_0, x_1), P_Y of the two
        translations, and that prediction translated back (the recycle)."""
        return [
            [rgb(batch["a_ref_0"]), rgb(out["b_hat"]), rgb(out["a_cyc01"]), rgb(batch["a_ref_2"]), rgb(out["pred_a2"]),
             rgb(out["b_next"]), rgb(out["a_recycle"])],
            [rgb(batch["real_0"]), rgb(out["a_hat"]), rgb(out["b_cyc01"]), rgb(batch["real_2"]), rgb(out["pred_b2"]),
             rgb(out["a_next"]), rgb(out["b_recycle"])],
        ]

    # --- inference -------------------------------------------------------------------------------

    def inference_stage(self, state: dict, where) -> tuple[RecycleGen, list[int | None]]:
        return self._stage(), [None] * len(state["scenes"])

    def inference_networks(self, gen: RecycleGen) -> list[nn.Module]:
        return [gen.g_ab]

    def translate_frames(self, gen: RecycleGen, batch: Batch) -> torch.Tensor:
        return pad_apply(lambda x: gen.g_ab(x.contiguous(memory_format=self.memory_format)), batch["a_ref_i"],
                         2**self.cfg.generator.downsamplings)
