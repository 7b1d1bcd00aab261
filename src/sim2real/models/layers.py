"""Building blocks shared by the generators and discriminators (MUNIT's, minus the styles).

``Conv2dBlock`` is ``pad -> conv (bias) -> norm -> activation``; the padding is explicit so that
'reflect' works for any kernel. Norms: 'in' instance norm (no affine, as MUNIT), 'ln' MUNIT's
layer norm, 'none'. Activations: 'relu', 'lrelu' (slope 0.2), 'tanh', 'none'.
"""

from __future__ import annotations

import torch
from torch import nn

PADS = {"reflect": nn.ReflectionPad2d, "replicate": nn.ReplicationPad2d, "zero": nn.ZeroPad2d}


class LayerNorm(nn.Module):
    """MUNIT's layer norm: per sample over (C, H, W), then a per-channel affine map,

        y = (x - mean) / (std + eps) * gamma_c + beta_c,

    with the unbiased standard deviation and ``eps`` added to the std (not the variance), as in
    MUNIT. ``gamma`` starts uniform in [0, 1) like MUNIT's ``Tensor.uniform_()``, ``beta`` at 0.
    """

    def __init__(self, num_features: int, eps: float = 1e-5, affine: bool = True):
        super().__init__()
        self.num_features = num_features
        self.eps = eps
        self.affine = affine
        if affine:
            self.gamma = nn.Parameter(torch.rand(num_features))
            self.beta = nn.Parameter(torch.zeros(num_features))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        flat = x.reshape(x.shape[0], -1)
        shape = (-1,) + (1,) * (x.dim() - 1)
        mean = flat.mean(1).view(shape)
        std = flat.std(1).view(shape)
        x = (x - mean) / (std + self.eps)
        if self.affine:
            cshape = (1, -1) + (1,) * (x.dim() - 2)
            x = x * self.gamma.view(cshape) + self.beta.view(cshape)
        return x

    def extra_repr(self) -> str:
        return f"{self.num_features}, eps={self.eps}, affine={self.affine}"


def make_norm(kind: str, channels: int) -> nn.Module | None:
    if kind == "in":
        return nn.InstanceNorm2d(channels)
    if kind == "ln":
        return LayerNorm(channels)
    if kind == "none":
        return None
    raise ValueError(f"unknown norm {kind!r} (choose 'in', 'ln' or 'none')")


def make_activation(kind: str) -> nn.Module | None:
    acts = {"relu": lambda: nn.ReLU(), "lrelu": lambda: nn.LeakyReLU(0.2), "tanh": nn.Tanh, "none": lambda: None}
    if kind not in acts:
        raise ValueError(f"unknown activation {kind!r} (choose {', '.join(acts)})")
    return acts[kind]()


class Conv2dBlock(nn.Module):
    """pad -> Conv2d(k, stride) -> norm -> activation."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int = 1, padding: int = 0,
                 norm: str = "none", activation: str = "relu", pad_type: str = "reflect"):
        super().__init__()
        if pad_type not in PADS:
            raise ValueError(f"unknown pad_type {pad_type!r} (choose {', '.join(PADS)})")
        self.pad = PADS[pad_type](padding)
        self.conv = nn.Conv2d(cin, cout, kernel, stride, bias=True)
        self.norm = make_norm(norm, cout)
        self.activation = make_activation(activation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.conv(self.pad(x))
        if self.norm is not None:
            x = self.norm(x)
        if self.activation is not None:
            x = self.activation(x)
        return x


class ResBlock(nn.Module):
    """x + [conv3 -> norm -> ReLU -> conv3 -> norm](x)."""

    def __init__(self, dim: int, norm: str = "in", pad_type: str = "reflect"):
        super().__init__()
        self.body = nn.Sequential(
            Conv2dBlock(dim, dim, 3, 1, 1, norm=norm, activation="relu", pad_type=pad_type),
            Conv2dBlock(dim, dim, 3, 1, 1, norm=norm, activation="none", pad_type=pad_type),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


def init_weights(module: nn.Module, kind: str) -> nn.Module:
    """Initialise every Conv/Linear weight in ``module`` as MUNIT's ``weights_init``:
    'kaiming' = ``kaiming_normal_(a=0, mode='fan_in')`` (std sqrt(2 / fan_in)),
    'gaussian' = N(0, 0.02); biases 0. Norm parameters are left alone."""
    for m in module.modules():
        if isinstance(m, (nn.Conv2d, nn.Linear)):
            if kind == "kaiming":
                nn.init.kaiming_normal_(m.weight, a=0, mode="fan_in")
            elif kind == "gaussian":
                nn.init.normal_(m.weight, 0.0, 0.02)
            else:
                raise ValueError(f"unknown init {kind!r} (choose 'kaiming' or 'gaussian')")
            if m.bias is not None:
                nn.init.zeros_(m.bias)
    return module
