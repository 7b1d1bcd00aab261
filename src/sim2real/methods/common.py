"""Pieces that every MUNIT-style translator method shares: the translations of one iteration,
the discriminator terms, the shared loss weights, and padding for inference."""

from __future__ import annotations

from typing import Callable

import torch
import torch.nn.functional as F

from sim2real.losses import lsgan_dis_loss, lsgan_gen_loss
from sim2real.methods.base import Stage


class DisStage(Stage):
    """The two discriminators of a two-domain method: D_A and D_B."""

    def __init__(self, dis_a: torch.nn.Module, dis_b: torch.nn.Module):
        super().__init__()
        self.dis_a = dis_a
        self.dis_b = dis_b


def translator_terms(t, x_a: torch.Tensor, x_b: torch.Tensor) -> dict[str, torch.Tensor]:
    """Every translation of MUNIT's ``gen_update`` (without styles), computed once: codes
    ``c_a, c_b``, translations ``b_hat, a_hat``, reconstructions ``a_rec, b_rec``, re-encoded
    codes ``c_a_rec, c_b_rec`` and cycles ``a_cyc, b_cyc``."""
    B = x_a.shape[0]
    c_a, c_b = t.enc_a(x_a), t.enc_b(x_b)
    # Same decoder, two codes: one batched call (exact: the norms are per sample).
    b_hat, b_rec = t.dec_b(torch.cat((c_a, c_b))).split(B)
    a_hat, a_rec = t.dec_a(torch.cat((c_b, c_a))).split(B)
    c_a_rec, c_b_rec = t.enc_b(b_hat), t.enc_a(a_hat)
    a_cyc, b_cyc = t.dec_a(c_a_rec), t.dec_b(c_b_rec)
    return dict(x_a=x_a, x_b=x_b, c_a=c_a, c_b=c_b, b_hat=b_hat, b_rec=b_rec, a_hat=a_hat, a_rec=a_rec,
                c_a_rec=c_a_rec, c_b_rec=c_b_rec, a_cyc=a_cyc, b_cyc=b_cyc)


def dis_terms(dis, out: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Unweighted LSGAN terms of D_A (fake ``a_hat`` vs ``x_a``) and D_B (``b_hat`` vs ``x_b``) on
    the detached fakes; real and fake go through each discriminator in one call (its layers are
    per sample)."""
    B = out["x_a"].shape[0]
    da = [s.float() for s in dis.dis_a(torch.cat((out["a_hat"].detach(), out["x_a"].detach())))]
    db = [s.float() for s in dis.dis_b(torch.cat((out["b_hat"].detach(), out["x_b"].detach())))]
    return {"dis_a": lsgan_dis_loss([s[:B] for s in da], [s[B:] for s in da]),
            "dis_b": lsgan_dis_loss([s[:B] for s in db], [s[B:] for s in db])}


def adv_terms(dis, out: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Unweighted LSGAN generator terms: D_A on ``a_hat``, D_B on ``b_hat`` (gradient flows to the
    generators; the trainer freezes the discriminators meanwhile)."""
    return {"adv_a": lsgan_gen_loss([s.float() for s in dis.dis_a(out["a_hat"])]),
            "adv_b": lsgan_gen_loss([s.float() for s in dis.dis_b(out["b_hat"])])}


def translator_weights(cfg) -> dict[str, float]:
    """Weights of the shared translator terms (``cfg.loss``), by term name."""
    L = cfg.loss
    return {"dis_a": L.adv, "dis_b": L.adv, "adv_a": L.adv, "adv_b": L.adv, "rec_a": L.rec, "rec_b": L.rec,
            "cyc_a": L.cyc, "cyc_b": L.cyc, "content_a": L.content, "content_b": L.content,
            "ssim_ab": L.ssim_ab, "ssim_ba": L.ssim_ba}


def pad_apply(fn: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor, multiple: int) -> torch.Tensor:
    """``fn(x)`` for an image whose sides need not be multiples of ``multiple``: padded (edge
    replicate) for ``fn`` and cropped back."""
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph or pw:
        x = F.pad(x, (0, pw, 0, ph), mode="replicate")
    return fn(x)[..., :h, :w]
