"""Multi-scale LSGAN discriminator (MUNIT's ``MsImageDis``, from pix2pixHD).

Scale k sees the input average-pooled k times (3x3, stride 2, padding 1, padding excluded from
the mean). Each scale is ``layers`` conv4 stride-2 LeakyReLU(0.2) blocks (``filters`` channels,
doubling after the first; the first block never normalised, later ones with ``norm``) and a
1x1 conv to one channel. An input side h gives ``floor(h / 2**layers)`` outputs at scale 0
(conv4, stride 2, padding 1 halves and floors); each pooling maps h to ``ceil(h / 2)``.
"""

from __future__ import annotations

import torch
from torch import nn

from sim2real.config import DiscriminatorConfig
from sim2real.models.layers import Conv2dBlock, init_weights


def min_input_side(cfg: DiscriminatorConfig) -> int:
    """Smallest image side the discriminator takes: its coarsest scale (``ceil(s / 2**(scales-1))``)
    must still be ``>= 2**layers``, so that every conv4 stride 2 gets at least 2 pixels (what
    reflect padding by 1 needs) and the last one gives an output, whatever the padding."""
    return (2**cfg.layers - 1) * 2 ** (cfg.scales - 1) + 1


class MsImageDis(nn.Module):
    """``forward(x) -> list`` of ``scales`` raw (B, 1, h_k, w_k) score maps; N(0, 0.02) init."""

    def __init__(self, cin: int, cfg: DiscriminatorConfig):
        super().__init__()
        self.downsample = nn.AvgPool2d(3, stride=2, padding=1, count_include_pad=False)
        self.cnns = nn.ModuleList(self._make_net(cin, cfg) for _ in range(cfg.scales))
        init_weights(self, "gaussian")

    @staticmethod
    def _make_net(cin: int, cfg: DiscriminatorConfig) -> nn.Sequential:
        dim = cfg.filters
        layers: list[nn.Module] = [Conv2dBlock(cin, dim, 4, 2, 1, norm="none", activation="lrelu", pad_type=cfg.pad_type)]
        for _ in range(cfg.layers - 1):
            layers.append(Conv2dBlock(dim, 2 * dim, 4, 2, 1, norm=cfg.norm, activation="lrelu", pad_type=cfg.pad_type))
            dim *= 2
        layers.append(nn.Conv2d(dim, 1, 1, 1, 0))
        return nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        outputs = []
        for i, cnn in enumerate(self.cnns):
            if i:
                x = self.downsample(x)
            outputs.append(cnn(x))
        return outputs
