"""A training step that works the way the authors' release does, for benchmarks/bench_train.py.

Same networks, losses and data as ``sim2real``'s trainer, but organised like the MUNIT-based
release:

* ``dis_update`` then ``gen_update`` (MUNIT's trainer): the discriminator step computes its
  own translations a->b and b->a (with autograd on, as MUNIT does), and the generator step
  computes them again;
* the neural texture enters as ``tanh(texture)`` of the **whole** texture every step, and the
  projection is a gather with index lists precomputed per view (12 corner texels and weights
  per foreground pixel, computed outside the timed region, as an offline cache would) followed
  by a scatter of the foreground pixels into the image;
* the decoders upsample and then convolve (MUNIT's ``nn.Upsample`` + 5x5 conv; sim2real
  computes the same function sub-pixel, see ``UpConv2dBlock``);
* fp32 everywhere, also on CUDA (no autocast, no channels-last);
* plain Adam (``torch.optim.Adam`` defaults: no fused kernel), the discriminators keep
  ``requires_grad`` during the generator step, and every decoder call is separate.

Deliberately favourable to the reference: its discriminator sees the real domain-A image
detached (no backward into the texture from the real term).
"""

from __future__ import annotations

import torch
from torch import nn

from sim2real.losses import l1, lsgan_dis_loss, lsgan_gen_loss, ms_ssim_loss, view_consistency, warp_backward
from sim2real.models.layers import UpConv2dBlock
from sim2real.models.discriminator import MsImageDis
from sim2real.models.translator import Translator
from sim2real.render.reference import class_albedo
from sim2real.texture.neural_texture import NeuralTexture


class GatherScatterTexture(nn.Module):
    """Texture (O, 6, S, S, N); forward = tanh(whole texture) -> gather -> scatter."""

    def __init__(self, src, cfg):
        super().__init__()
        init = NeuralTexture(len(src.classes), src.bounds, class_albedo(src.classes), cfg)
        self.texture = nn.Parameter(init.texture.detach().clone())
        init.texture.data = torch.empty(0)
        self.__dict__["_coords"] = init  # not a submodule: only its boxes, for the index lists

    @torch.no_grad()
    def precompute(self, object_id, points, normals):
        """Per view: flat foreground pixel indices, 12 flat texel indices and weights per pixel."""
        t = self._coords.to(points.device)
        S = t.size
        oid = object_id.reshape(-1).long()
        fg = torch.nonzero(oid >= 0).squeeze(1)
        o = oid[fg]
        pts, nrm = points.reshape(-1, 3)[fg].float(), normals.reshape(-1, 3)[fg].float()
        c = t.plane_coords(o, pts)
        tt = (c * (S - 1)).clamp(0, S - 1)
        t0 = tt.floor().long()
        fr = tt - t0
        t1 = (t0 + 1).clamp_max(S - 1)
        n2 = nrm * nrm
        w_axis = n2 / n2.sum(1, keepdim=True).clamp_min(1e-12)
        idx, wts = [], []
        for a, (u, v) in enumerate(((1, 2), (0, 2), (0, 1))):
            base = (o * 6 + 2 * a + (nrm[:, a] < 0).long()) * S * S
            for iu, du in ((t0[:, u], 1 - fr[:, u]), (t1[:, u], fr[:, u])):
                for iv, dv in ((t0[:, v], 1 - fr[:, v]), (t1[:, v], fr[:, v])):
                    idx.append(base + iu * S + iv)
                    wts.append(du * dv * w_axis[:, a])
        return fg, torch.stack(idx), torch.stack(wts)

    def forward(self, lists, shape):
        fg, idx, wts = lists
        B, H, W = shape
        N = self.texture.shape[-1]
        flat = torch.tanh(self.texture).reshape(-1, N)  # O(texels) every step
        vals = (flat[idx] * wts.unsqueeze(-1)).sum(0)  # advanced-index gather; backward = index_put(accumulate)
        img = torch.zeros(B * H * W, N, dtype=vals.dtype, device=vals.device)
        img = img.index_put((fg,), vals)  # scatter into the image
        return img.reshape(B, H, W, N).permute(0, 3, 1, 2)


class AuthorsStyleTrainer:
    def __init__(self, cfg, sources, device="cpu"):
        torch.manual_seed(cfg.seed)
        self.cfg = cfg
        n = cfg.method.texture.features  # the networks as the 'ours' method builds them
        self.tr = Translator(n, cfg.generator).to(device)
        self.dis_a, self.dis_b = MsImageDis(n + 3, cfg.discriminator).to(device), MsImageDis(3, cfg.discriminator).to(device)
        for m in self.tr.modules():
            if isinstance(m, UpConv2dBlock):
                m.subpixel = False  # upsample, then convolve
        self.textures = nn.ModuleList(GatherScatterTexture(s, cfg.method.texture) for s in sources).to(device)
        o = cfg.optim
        kw = dict(betas=(o.beta1, o.beta2), weight_decay=o.weight_decay)
        self.opt_gen = torch.optim.Adam(self.tr.parameters(), lr=o.lr_net, **kw)
        self.opt_tex = torch.optim.Adam(self.textures.parameters(), lr=o.lr_tex, **kw)
        self.opt_dis = torch.optim.Adam(list(self.dis_a.parameters()) + list(self.dis_b.parameters()), lr=o.lr_net, **kw)

    def precompute(self, batch):
        tex = self.textures[int(batch["scene"][0])]
        return {tag: tex.precompute(batch[f"object_id_{tag}"], batch[f"points_{tag}"], batch[f"normal_{tag}"]) for tag in "ij"}

    def _x_a(self, batch, lists, tag):
        tex = self.textures[int(batch["scene"][0])]
        return self.tr.join_a(tex(lists[tag], batch[f"object_id_{tag}"].shape), batch[f"a_ref_{tag}"])

    def dis_update(self, x_a, x_b):
        t, L = self.tr, self.cfg.loss
        self.opt_dis.zero_grad()
        c_a, c_b = t.enc_a(x_a), t.enc_b(x_b)
        x_ba, x_ab = t.dec_a(c_b), t.dec_b(c_a)
        loss = L.adv * (lsgan_dis_loss(self.dis_a(x_ba.detach()), self.dis_a(x_a.detach()))
                        + lsgan_dis_loss(self.dis_b(x_ab.detach()), self.dis_b(x_b)))
        loss.backward()
        self.opt_dis.step()
        return loss

    def gen_update(self, x_a, x_b, batch, lists, step):
        t, L, n = self.tr, self.cfg.loss, self.cfg.method.texture.features
        self.opt_gen.zero_grad()
        self.opt_tex.zero_grad()
        c_a, c_b = t.enc_a(x_a), t.enc_b(x_b)
        x_a_recon, x_b_recon = t.dec_a(c_a), t.dec_b(c_b)
        x_ba, x_ab = t.dec_a(c_b), t.dec_b(c_a)
        c_b_recon, c_a_recon = t.enc_a(x_ba), t.enc_b(x_ab)
        x_aba, x_bab = t.dec_a(c_a_recon), t.dec_b(c_b_recon)
        loss = (L.adv * (lsgan_gen_loss(self.dis_a(x_ba)) + lsgan_gen_loss(self.dis_b(x_ab)))
                + L.rec * (l1(x_a_recon, x_a) + l1(x_b_recon, x_b))
                + L.cyc * (l1(x_aba, x_a) + l1(x_bab, x_b))
                + L.content * (l1(c_a_recon, c_a) + l1(c_b_recon, c_b))
                + L.ssim_ab * ms_ssim_loss(x_a[:, n:], x_ab, L.ssim_win, L.ssim_scales)
                + L.ssim_ba * ms_ssim_loss(x_b, x_ba[:, n:], L.ssim_win, L.ssim_scales))
        m = self.cfg.method
        if step >= m.vc_start:
            with torch.no_grad():
                b_j = t.dec_b(t.enc_a(self._x_a(batch, lists, "j")))
                warped, mask = warp_backward(b_j, batch["uv_ij"], batch["visible_ij"])
            loss = loss + m.vc * view_consistency(m.vc_kind, x_ab, warped, mask)
        loss.backward()
        self.opt_gen.step()
        self.opt_tex.step()
        return loss

    def train_step(self, batch, lists, step):
        x_a = self._x_a(batch, lists, "i")
        x_b = batch["real"]
        self.dis_update(x_a, x_b)
        return self.gen_update(x_a, x_b, batch, lists, step)
