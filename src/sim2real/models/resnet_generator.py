"""The ResNet generator of CycleGAN / ReCycle-GAN (``resnet_6blocks`` in their public code).

One network maps one domain to the other (no shared content space, no styles). With ``f`` =
filters, ``d`` = downsamplings, ``n`` = residual blocks::

    conv7 (cin -> f) IN ReLU                                         reflect pad 3
    d x conv3 stride 2 (double channels) IN ReLU                     zero pad 1
    n x ResBlock(f 2^d, IN)                                          x + [conv3 IN ReLU conv3 IN](x)
    d x convT3 stride 2, output padding 1 (halve channels) IN ReLU
    conv7 (f -> cout) tanh                                           reflect pad 3

Instance norm has no affine parameters; weights N(0, 0.02), biases 0 (``--init_type normal``);
no dropout (``--no_dropout``). Image sides must be multiples of ``2**d`` for the output to have
the input's size. The residual blocks' padding is ``pad_type`` (reflect in the original).
"""

from __future__ import annotations

import torch
from torch import nn

from sim2real.models.layers import Conv2dBlock, ResBlock, init_weights


class ResnetGenerator(nn.Module):
    """Image (B, cin, H, W) -> image (B, cout, H, W) in [-1, 1] (see the module docstring)."""

    def __init__(self, cin: int, cout: int, filters: int = 64, downsamplings: int = 2, res_blocks: int = 6,
                 pad_type: str = "reflect"):
        super().__init__()
        dim = filters
        layers: list[nn.Module] = [Conv2dBlock(cin, dim, 7, 1, 3, norm="in", activation="relu", pad_type="reflect")]
        for _ in range(downsamplings):
            layers.append(Conv2dBlock(dim, 2 * dim, 3, 2, 1, norm="in", activation="relu", pad_type="zero"))
            dim *= 2
        layers += [ResBlock(dim, "in", pad_type) for _ in range(res_blocks)]
        for _ in range(downsamplings):
            layers += [nn.ConvTranspose2d(dim, dim // 2, 3, 2, 1, output_padding=1), nn.InstanceNorm2d(dim // 2),
                       nn.ReLU(inplace=True)]
            dim //= 2
        layers.append(Conv2dBlock(dim, cout, 7, 1, 3, norm="none", activation="tanh", pad_type="reflect"))
        self.model = nn.Sequential(*layers)
        self.downsamplings = downsamplings
        init_weights(self, "gaussian")
        for m in self.modules():  # init_weights covers Conv2d and Linear; the original also ConvTranspose2d
            if isinstance(m, nn.ConvTranspose2d):
                nn.init.normal_(m.weight, 0.0, 0.02)
                nn.init.zeros_(m.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.model(x)
