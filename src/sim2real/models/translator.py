"""MUNIT encoders/decoders without styles (AdaIN -> instance norm) and the two-domain translator.

Encoder (``f`` = filters, ``d`` = downsamplings, ``c`` = content channels)::

    conv7(cin -> f) IN ReLU
    d x conv4 stride 2 (double channels) IN ReLU              -> width w = f 2^d, size H/2^d
    res_blocks x ResBlock(w, IN)
    if c > 0: conv3(w -> c) ReLU                              (authors' release: c = 8)

Decoder::

    if c > 0: conv3(c -> w) ReLU                              (release)
    res_blocks x ResBlock(w, IN)
    d x [nearest upsample x2, conv5 (halve channels) norm ReLU]   (norm: MUNIT layer norm;
                                                                 computed sub-pixel: UpConv2dBlock)
    conv7(f -> cout) tanh

All padding is ``pad_type`` (reflect). Domain A is ``cat(a_tex, a_ref)`` with
``n_features + 3`` channels (tex first); domain B is RGB. Images are in [-1, 1].
"""

from __future__ import annotations

import torch
from torch import nn

from sim2real.config import GeneratorConfig
from sim2real.models.layers import Conv2dBlock, ResBlock, UpConv2dBlock, init_weights


def content_width(cfg: GeneratorConfig) -> int:
    """Channels after the downsamplings, ``filters * 2**downsamplings``."""
    return cfg.filters * 2**cfg.downsamplings


def min_input_side(cfg: GeneratorConfig) -> int:
    """Smallest image side the encoders and decoders take. Reflect padding needs more pixels
    than it pads: 4 for the conv7 layers, and 2 at the content resolution (side / 2^d) for the
    residual and content conv3 layers; zero and replicate padding only need side / 2^d >= 1."""
    if cfg.pad_type == "reflect":
        return max(4, 2 ** (cfg.downsamplings + 1))
    return 2**cfg.downsamplings


class Encoder(nn.Module):
    """Image (B, cin, H, W) -> content code (B, c or w, H / 2^d, W / 2^d)."""

    def __init__(self, cin: int, cfg: GeneratorConfig):
        super().__init__()
        pad, dim = cfg.pad_type, cfg.filters
        layers: list[nn.Module] = [Conv2dBlock(cin, dim, 7, 1, 3, norm="in", activation="relu", pad_type=pad)]
        for _ in range(cfg.downsamplings):
            layers.append(Conv2dBlock(dim, 2 * dim, 4, 2, 1, norm="in", activation="relu", pad_type=pad))
            dim *= 2
        layers += [ResBlock(dim, "in", pad) for _ in range(cfg.res_blocks)]
        if cfg.content_channels > 0:
            layers.append(Conv2dBlock(dim, cfg.content_channels, 3, 1, 1, norm="none", activation="relu", pad_type=pad))
        self.model = nn.Sequential(*layers)
        self.out_channels = cfg.content_channels if cfg.content_channels > 0 else dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)


class Decoder(nn.Module):
    """Content code -> image (B, cout, H, W) in [-1, 1]."""

    def __init__(self, cout: int, cfg: GeneratorConfig):
        super().__init__()
        pad, dim = cfg.pad_type, content_width(cfg)
        layers: list[nn.Module] = []
        if cfg.content_channels > 0:
            layers.append(Conv2dBlock(cfg.content_channels, dim, 3, 1, 1, norm="none", activation="relu", pad_type=pad))
        layers += [ResBlock(dim, "in", pad) for _ in range(cfg.res_blocks)]
        for _ in range(cfg.downsamplings):
            layers.append(UpConv2dBlock(dim, dim // 2, 5, norm=cfg.upsample_norm, activation="relu", pad_type=pad))
            dim //= 2
        layers.append(Conv2dBlock(dim, cout, 7, 1, 3, norm="none", activation="tanh", pad_type=pad))
        self.model = nn.Sequential(*layers)

    def forward(self, c: torch.Tensor) -> torch.Tensor:
        return self.model(c)


class Translator(nn.Module):
    """E_A, G_A (domain A: a_tex + a_ref) and E_B, G_B (domain B: RGB); Kaiming-initialised.

    Image sides must be multiples of ``2**downsamplings`` for decoded sizes to match inputs.
    """

    def __init__(self, n_features: int, cfg: GeneratorConfig, b_channels: int = 3):
        super().__init__()
        self.n_features = n_features
        self.a_channels = n_features + 3
        self.b_channels = b_channels
        self.enc_a = Encoder(self.a_channels, cfg)
        self.dec_a = Decoder(self.a_channels, cfg)
        self.enc_b = Encoder(b_channels, cfg)
        self.dec_b = Decoder(b_channels, cfg)
        init_weights(self, "kaiming")

    def join_a(self, a_tex: torch.Tensor, a_ref: torch.Tensor) -> torch.Tensor:
        """Domain-A image ``cat(a_tex, a_ref)`` along channels."""
        return torch.cat((a_tex, a_ref), dim=1)

    def split_a(self, x_a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(a_tex, a_ref) of a domain-A image."""
        return x_a[:, : self.n_features], x_a[:, self.n_features :]

    def a_to_b(self, x_a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x_a -> (b_hat = G_B(E_A(x_a)), content code E_A(x_a))."""
        c = self.enc_a(x_a)
        return self.dec_b(c), c

    def b_to_a(self, x_b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x_b -> (a_hat = G_A(E_B(x_b)), content code E_B(x_b)); a_hat holds tex and ref."""
        c = self.enc_b(x_b)
        return self.dec_a(c), c
