"""Building blocks shared by the generators and discriminators (MUNIT's, minus the styles).

``Conv2dBlock`` is ``pad -> conv (bias) -> norm -> activation``; the padding is explicit so that
'reflect' works for any kernel. ``UpConv2dBlock`` is MUNIT's decoder up-step (nearest x2
upsample, then a ``Conv2dBlock``) computed as a sub-pixel convolution. Norms: 'in' instance
norm (no affine, as MUNIT), 'ln' MUNIT's layer norm, 'none'. Activations: 'relu', 'lrelu'
(slope 0.2), 'tanh', 'none'.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

PADS = {"reflect": nn.ReflectionPad2d, "replicate": nn.ReplicationPad2d, "zero": nn.ZeroPad2d}
NORMS = ("in", "ln", "none")


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
        # As one scale-and-shift per (sample, channel): a single pass over x forward and
        # backward (measured 1.4-1.6x faster than subtract, divide, multiply, add at 128^2 x 128).
        B, C = x.shape[:2]
        std, mean = torch.std_mean(x.reshape(B, -1), dim=1)
        scale = (1.0 / (std + self.eps))[:, None].expand(B, C)
        if self.affine:
            scale = scale * self.gamma[None, :]
        shift = -mean[:, None] * scale
        if self.affine:
            shift = shift + self.beta[None, :]
        view = (B, C) + (1,) * (x.dim() - 2)
        return torch.addcmul(shift.view(view), x, scale.reshape(view))

    def extra_repr(self) -> str:
        return f"{self.num_features}, eps={self.eps}, affine={self.affine}"


def make_norm(kind: str, channels: int) -> nn.Module | None:
    if kind == "in":
        return nn.InstanceNorm2d(channels)
    if kind == "ln":
        return LayerNorm(channels)
    if kind == "none":
        return None
    raise ValueError(f"unknown norm {kind!r} (choose {', '.join(NORMS)})")


def make_activation(kind: str) -> nn.Module | None:
    # in place (as MUNIT): they follow a conv or a norm, whose backward does not need its output
    acts = {"relu": lambda: nn.ReLU(inplace=True), "lrelu": lambda: nn.LeakyReLU(0.2, inplace=True), "tanh": nn.Tanh,
            "none": lambda: None}
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


class UpConv2dBlock(nn.Module):
    """Nearest x2 upsample -> pad -> Conv2d(k, stride 1, padding k // 2) -> norm -> activation.

    Same parameters and same function as ``nn.Upsample(2) + Conv2dBlock``, computed without
    the upsampled image. An output pixel of phase (py, px) (its position mod 2) sees each input
    pixel through the sum of the k x k taps that land on that pixel's 2 x 2 copy, so the four
    phases are four (2r+1) x (2r+1) convolutions of the *input* (r = ceil(p / 2)), run as one
    convolution with 4 * cout channels and interleaved by ``pixel_shuffle``. For MUNIT's k = 5
    that is 9 instead of 25 taps per output, at a quarter of the pixels: 36 % of the
    multiply-adds. The phase kernels are derived from the k x k weight at every call, so
    gradients, optimiser state and checkpoints are those of the direct form.

    Zero and replicate padding of the upsampled image equal zero and replicate padding of the
    input. Reflect padding does not (row -2 of the upsampled image is input row 1), so with
    'reflect' the outer p output rows and columns are recomputed the direct way from the p
    input rows (columns) they see: exact, for the cost of p rows and columns.

    Measured, forward + backward (LN, ReLU) on the 2-core CPU, torch 2.13, fp32, batch 1,
    direct -> sub-pixel: 256 -> 128 channels from 64x128: 929 -> 403 ms; 128 -> 64 from
    128x256: 1135 -> 608 ms; 64 -> 32 from 64x128: 66 -> 36 ms; 16 -> 8 from 64x128: 14.0 ->
    6.5 ms. Small inputs lose to the extra calls: 128 -> 64 from 8x16: 4.8 -> 7.6 ms; 16 -> 8
    from 32x64: 3.0 -> 3.1 ms. The measured break-even is an input of about 2^16 values per
    sample (cin * h * w), ``MIN_INPUT``. ``subpixel``: None decides per call by that rule;
    True or False forces a form (False is the authors' way, for benchmarks and tests).
    """

    MIN_INPUT = 2**16
    """cin * h * w per sample from which the sub-pixel form runs (measured break-even)."""

    def __init__(self, cin: int, cout: int, kernel: int, norm: str = "none", activation: str = "relu",
                 pad_type: str = "reflect"):
        super().__init__()
        if kernel % 2 != 1:
            raise ValueError(f"UpConv2dBlock needs an odd kernel, got {kernel}")
        self.block = Conv2dBlock(cin, cout, kernel, 1, kernel // 2, norm=norm, activation=activation, pad_type=pad_type)
        self.pad_type = pad_type
        self.subpixel: bool | None = None
        self.p = p = kernel // 2
        self.r = (p + 1) // 2
        # phase_map[phase, j, t] = 1 where tap t of an output of that phase reads input offset j - r
        m = torch.zeros(2, 2 * self.r + 1, kernel)
        for phase in range(2):
            for t in range(kernel):
                m[phase, (phase + t - p) // 2 + self.r, t] = 1.0
        self.register_buffer("phase_map", m, persistent=False)

    def _direct(self, x: torch.Tensor) -> torch.Tensor:
        return self.block.conv(self.block.pad(F.interpolate(x, scale_factor=2, mode="nearest")))

    def _subpixel(self, x: torch.Tensor) -> torch.Tensor:
        conv, r, p = self.block.conv, self.r, self.p
        m = self.phase_map.to(conv.weight.dtype)
        w = torch.einsum("pak,qbl,oikl->opqiab", m, m, conv.weight)
        w = w.reshape(-1, conv.in_channels, 2 * r + 1, 2 * r + 1)
        mode = "constant" if self.pad_type == "zero" else "replicate"
        # each output channel's bias for its four phases, gathered into a tensor of its own: TorchInductor
        # 2.11 cannot lower a convolution whose bias is a view (repeat_interleave(4) is one there)
        bias = conv.bias.index_select(0, torch.arange(4 * conv.out_channels, device=conv.bias.device) // 4)
        y = F.pixel_shuffle(F.conv2d(F.pad(x, (r, r, r, r), mode=mode), w, bias), 2)
        if self.pad_type == "reflect":  # outer p output rows / columns, the direct way
            B = x.shape[0]
            up = lambda t: F.interpolate(t, scale_factor=2, mode="nearest")
            rows = F.conv2d(torch.cat((F.pad(up(x[:, :, :p]), (p, p, p, 0), mode="reflect"),
                                       F.pad(up(x[:, :, -p:]), (p, p, 0, p), mode="reflect"))), conv.weight, conv.bias)
            cols = F.conv2d(torch.cat((F.pad(up(x[..., :p]), (p, 0, p, p), mode="reflect"),
                                       F.pad(up(x[..., -p:]), (0, p, p, p), mode="reflect"))), conv.weight, conv.bias)
            y[:, :, :p], y[:, :, -p:] = rows[:B], rows[B:]
            y[..., :p], y[..., -p:] = cols[:B], cols[B:]
        return y

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        use = self.subpixel
        if use is None:
            use = self.block.conv.in_channels * x.shape[-2] * x.shape[-1] >= self.MIN_INPUT
        use = use and self.p > 0 and min(x.shape[-2:]) > self.p
        x = self._subpixel(x) if use else self._direct(x)
        if self.block.norm is not None:
            x = self.block.norm(x)
        if self.block.activation is not None:
            x = self.block.activation(x)
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
