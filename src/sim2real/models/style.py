"""MUNIT's style path (Huang et al. 2018), as SSIM-MUNIT (Pfeiffer et al. 2019) keeps it.

Style encoder (``f`` = ``generator.filters``, ``s`` = style dimension, no normalisation)::

    conv7(cin -> f) ReLU
    conv4 stride 2 (f -> 2f) ReLU,  conv4 stride 2 (2f -> 4f) ReLU      (the first two double)
    conv4 stride 2 (4f -> 4f) ReLU, conv4 stride 2 (4f -> 4f) ReLU
    global average pooling, conv1x1(4f -> s)                             -> style (B, s)

AdaIN (adaptive instance norm), per sample b and channel c with the statistics of x over (H, W)
(biased variance)::

    y[b, c] = (x[b, c] - mean_hw(x[b, c])) / sqrt(var_hw(x[b, c]) + eps) * std[b, c] + mean[b, c]

so that y[b, c] has exactly the mean ``mean[b, c]`` and the standard deviation
``std[b, c] * sqrt(v / (v + eps))`` (v = var_hw(x[b, c])). MUNIT passes the parameters as
(mean, std), the "std" unconstrained (no +1, no softplus); so do we.

MLP (``layers`` linear layers, ``width`` hidden units, ReLU between, none after the last):
style (B, s) -> all AdaIN parameters (B, P), P = sum over AdaIN layers of 2 x channels, ordered
layer by layer, each layer's means then its stds (as MUNIT's ``assign_adain_params``).

AdaIN decoder (same as :class:`sim2real.models.translator.Decoder` with AdaIN in the residual
blocks instead of instance norm; the upsampling convs keep ``generator.upsample_norm``, layer
norm by default)::

    if c > 0: conv3(c -> w) ReLU                         (content code width, authors' release)
    res_blocks x [x + AdaIN(conv3(ReLU(AdaIN(conv3(x)))))]     params from MLP(style)
    d x [nearest upsample x2, conv5 (halve channels) norm ReLU]
    conv7(f -> cout) tanh

:class:`StyleGenerator` is one domain's MUNIT ``AdaINGen``: content encoder
(:class:`~sim2real.models.translator.Encoder`, as ours), style encoder, AdaIN decoder;
Kaiming-initialised as MUNIT. Input noise (the release's ``encode``) is the method's business
(sim2real/methods/ssim_munit.py), so that it owns every random draw.
"""

from __future__ import annotations

import torch
from torch import nn

from sim2real.config import GeneratorConfig
from sim2real.models.layers import Conv2dBlock, UpConv2dBlock, init_weights
from sim2real.models.translator import Encoder, content_width

STYLE_DOWNSAMPLINGS = 4
"""Stride-2 convs of MUNIT's style encoder (``n_downsample = 4``)."""


def style_min_input_side() -> int:
    """Smallest image side the style encoder takes: every conv4 stride 2 with padding 1 needs at
    least 2 input pixels (reflect padding), so the side before the last one must be >= 2."""
    return 2**STYLE_DOWNSAMPLINGS


class StyleEncoder(nn.Module):
    """Image (B, cin, H, W) -> style code (B, style_dim); see the module docstring."""

    def __init__(self, cin: int, cfg: GeneratorConfig, style_dim: int):
        super().__init__()
        pad, dim = cfg.pad_type, cfg.filters
        layers: list[nn.Module] = [Conv2dBlock(cin, dim, 7, 1, 3, norm="none", activation="relu", pad_type=pad)]
        for k in range(STYLE_DOWNSAMPLINGS):
            out = 2 * dim if k < 2 else dim
            layers.append(Conv2dBlock(dim, out, 4, 2, 1, norm="none", activation="relu", pad_type=pad))
            dim = out
        self.model = nn.Sequential(*layers)
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.head = nn.Conv2d(dim, style_dim, 1, 1, 0)
        self.style_dim = style_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.pool(self.model(x))).flatten(1)


class AdaIN(nn.Module):
    """Adaptive instance norm without parameters of its own: ``forward(x, mean, std)`` with
    ``mean``, ``std`` (B, C); statistics in fp32 (also under autocast)."""

    def __init__(self, num_features: int, eps: float = 1e-5):
        super().__init__()
        self.num_features = num_features
        self.eps = eps

    def forward(self, x: torch.Tensor, mean: torch.Tensor, std: torch.Tensor) -> torch.Tensor:
        B, C = x.shape[:2]
        if mean.shape != (B, C) or std.shape != (B, C):
            raise ValueError(f"AdaIN: x {tuple(x.shape)} needs mean and std of shape {(B, C)}, "
                             f"got {tuple(mean.shape)} and {tuple(std.shape)}")
        xf = x.float()
        var, mu = torch.var_mean(xf, dim=(2, 3), keepdim=True, unbiased=False)
        scale = std.float()[:, :, None, None] * torch.rsqrt(var + self.eps)
        shift = mean.float()[:, :, None, None] - mu * scale
        return torch.addcmul(shift, xf, scale).to(x.dtype)

    def extra_repr(self) -> str:
        return f"{self.num_features}, eps={self.eps}"


class MLP(nn.Module):
    """style (B, s) -> (B, out): ``layers`` linear layers of ``width`` units, ReLU between them."""

    def __init__(self, cin: int, cout: int, width: int, layers: int):
        super().__init__()
        if layers < 1:
            raise ValueError(f"MLP needs at least 1 layer, got {layers}")
        dims = [cin] + [width] * (layers - 1) + [cout]
        mods: list[nn.Module] = []
        for k in range(layers):
            mods.append(nn.Linear(dims[k], dims[k + 1]))
            if k < layers - 1:
                mods.append(nn.ReLU(inplace=True))
        self.model = nn.Sequential(*mods)

    def forward(self, s: torch.Tensor) -> torch.Tensor:
        return self.model(s)


class AdaINResBlock(nn.Module):
    """x + AdaIN_2(conv3(ReLU(AdaIN_1(conv3(x))))); ``params`` = (mean_1, std_1, mean_2, std_2)."""

    def __init__(self, dim: int, pad_type: str = "reflect"):
        super().__init__()
        self.conv1 = Conv2dBlock(dim, dim, 3, 1, 1, norm="none", activation="none", pad_type=pad_type)
        self.norm1 = AdaIN(dim)
        self.conv2 = Conv2dBlock(dim, dim, 3, 1, 1, norm="none", activation="none", pad_type=pad_type)
        self.norm2 = AdaIN(dim)

    @property
    def num_params(self) -> int:
        return 2 * (self.norm1.num_features + self.norm2.num_features)

    def forward(self, x: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        m1, s1, m2, s2 = params.split([self.norm1.num_features] * 2 + [self.norm2.num_features] * 2, dim=1)
        y = torch.relu(self.norm1(self.conv1(x), m1, s1))
        return x + self.norm2(self.conv2(y), m2, s2)


class AdaINDecoder(nn.Module):
    """``forward(c, s)``: content code (B, c or w, h, w') and style (B, s) -> image (B, cout, H, W)
    in [-1, 1]; see the module docstring."""

    def __init__(self, cout: int, cfg: GeneratorConfig, style_dim: int, mlp_dim: int, mlp_layers: int):
        super().__init__()
        pad, dim = cfg.pad_type, content_width(cfg)
        self.lift = (Conv2dBlock(cfg.content_channels, dim, 3, 1, 1, norm="none", activation="relu", pad_type=pad)
                     if cfg.content_channels > 0 else nn.Identity())
        self.res = nn.ModuleList(AdaINResBlock(dim, pad) for _ in range(cfg.res_blocks))
        up: list[nn.Module] = []
        for _ in range(cfg.downsamplings):
            up.append(UpConv2dBlock(dim, dim // 2, 5, norm=cfg.upsample_norm, activation="relu", pad_type=pad))
            dim //= 2
        up.append(Conv2dBlock(dim, cout, 7, 1, 3, norm="none", activation="tanh", pad_type=pad))
        self.up = nn.Sequential(*up)
        self.num_adain_params = sum(b.num_params for b in self.res)
        self.mlp = MLP(style_dim, self.num_adain_params, mlp_dim, mlp_layers)

    def forward(self, c: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        params = self.mlp(s)
        x = self.lift(c)
        for block, p in zip(self.res, params.split([b.num_params for b in self.res], dim=1)):
            x = block(x, p)
        return self.up(x)


class StyleGenerator(nn.Module):
    """One domain's MUNIT ``AdaINGen``: ``encode(x) -> (content, style)``, ``decode(c, s) -> image``."""

    def __init__(self, channels: int, cfg: GeneratorConfig, style_dim: int, mlp_dim: int, mlp_layers: int):
        super().__init__()
        self.channels = channels
        self.style_dim = style_dim
        self.enc_content = Encoder(channels, cfg)
        self.enc_style = StyleEncoder(channels, cfg, style_dim)
        self.dec = AdaINDecoder(channels, cfg, style_dim, mlp_dim, mlp_layers)
        init_weights(self, "kaiming")

    def encode(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.enc_content(x), self.enc_style(x)

    def decode(self, c: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        return self.dec(c, s)
