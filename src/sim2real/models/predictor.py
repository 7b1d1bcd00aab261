"""Temporal predictor of ReCycle-GAN (Bansal et al. 2018): the next frame from the two before it.

``P(cat(x_{t-2}, x_{t-1}))`` -> ``x_t``, a U-Net (the public code's ``unet_128`` for
``--which_model_netP unet_128``): input (B, 2c, H, W), the two frames concatenated along
channels, output (B, c, H, W) in [-1, 1]. With ``f`` = filters and ``L`` = levels, the width of
level k is ``w_k = f * 2**min(k, 3)`` (``unet_128`` is f = 64, L = 7)::

    down  d_0 = conv4 s2 (2c -> w_0)
          d_k = LeakyReLU(0.2), conv4 s2 (w_{k-1} -> w_k), norm          k = 1 .. L-1
                                                    (no norm at the innermost level k = L-1)
    up    u_{L-1} = ReLU, convT4 s2 (w_{L-1} -> w_{L-2}), norm
          u_k     = ReLU, convT4 s2 (2 w_k -> w_{k-1}), norm             k = L-2 .. 1
          u_0     = ReLU, convT4 s2 (2 w_0 -> c), tanh

    h_0 = d_0(x),  h_k = d_k(h_{k-1}),  y = u_{L-1}(h_{L-1}),  y <- u_k(cat(h_k, y)) for k = L-2 .. 0

Every conv4 / convT4 has stride 2 and zero padding 1, so the sides must be multiples of
``2**L`` (:func:`check_predictor_size`). Norm: instance norm without affine parameters (the
public code's default ``--norm instance``), or none; no dropout (``--no_dropout``). Weights
N(0, 0.02), biases 0 (``--init_type normal``).
"""

from __future__ import annotations

import torch
from torch import nn

from sim2real.models.layers import init_weights

PREDICTOR_NORMS = ("in", "none")


def level_widths(filters: int, levels: int) -> list[int]:
    """``w_k = filters * 2**min(k, 3)`` for k = 0 .. levels-1."""
    return [filters * 2 ** min(k, 3) for k in range(levels)]


def predictor_size_error(height: int, width: int, levels: int) -> str | None:
    """Why a ``levels``-deep U-Net cannot take ``height x width`` images, or None: both sides must
    be multiples of ``2**levels`` (each level halves them and the skips must line up)."""
    step = 2**levels
    if height % step or width % step:
        return f"image sides multiples of {step} (2**levels), got {height}x{width}"
    return None


def _norm(kind: str, channels: int) -> nn.Module:
    return nn.InstanceNorm2d(channels) if kind == "in" else nn.Identity()


class UNetPredictor(nn.Module):
    """``forward(prev2, prev1)`` or ``forward(x)`` with ``x = cat(prev2, prev1)``: the predicted
    next frame (see the module docstring)."""

    def __init__(self, channels: int = 3, filters: int = 64, levels: int = 7, norm: str = "in"):
        super().__init__()
        if levels < 2:
            raise ValueError(f"UNetPredictor needs levels >= 2, got {levels}")
        if norm not in PREDICTOR_NORMS:
            raise ValueError(f"unknown predictor norm {norm!r} (choose {', '.join(PREDICTOR_NORMS)})")
        self.channels, self.levels = channels, levels
        w = level_widths(filters, levels)
        conv = lambda cin, cout: nn.Conv2d(cin, cout, 4, 2, 1)
        up = lambda cin, cout: nn.ConvTranspose2d(cin, cout, 4, 2, 1)
        downs = [conv(2 * channels, w[0])]
        for k in range(1, levels):
            inner = k == levels - 1
            downs.append(nn.Sequential(nn.LeakyReLU(0.2), conv(w[k - 1], w[k]), nn.Identity() if inner else _norm(norm, w[k])))
        ups = [nn.Sequential(nn.ReLU(), up(2 * w[0], channels), nn.Tanh())]
        for k in range(1, levels):
            cin = w[k] if k == levels - 1 else 2 * w[k]
            ups.append(nn.Sequential(nn.ReLU(), up(cin, w[k - 1]), _norm(norm, w[k - 1])))
        self.downs = nn.ModuleList(downs)
        self.ups = nn.ModuleList(ups)
        init_weights(self, "gaussian")
        for m in self.modules():  # init_weights covers Conv2d and Linear; the original also ConvTranspose2d
            if isinstance(m, nn.ConvTranspose2d):
                nn.init.normal_(m.weight, 0.0, 0.02)
                nn.init.zeros_(m.bias)

    def forward(self, x: torch.Tensor, prev1: torch.Tensor | None = None) -> torch.Tensor:
        if prev1 is not None:
            x = torch.cat((x, prev1), dim=1)
        if x.shape[1] != 2 * self.channels:
            raise ValueError(f"UNetPredictor takes 2 x {self.channels} channels, got {x.shape[1]}")
        skips = []
        for d in self.downs:
            x = d(x)
            skips.append(x)
        y = self.ups[-1](skips[-1])
        for k in range(self.levels - 2, -1, -1):
            y = self.ups[k](torch.cat((skips[k], y), dim=1))
        return y
