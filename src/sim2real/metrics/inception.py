"""The FID Inception-v3 network (pool3, 2048-d features), in plain torch.

This is the network behind the standard FID/KID numbers: the TensorFlow graph
``inception-2015-12-05`` as ported to PyTorch by pytorch-fid (weights file
``pt_inception-2015-12-05-6726825d.pth``; torch-fidelity ships the same weights as
``weights-inception-2015-12-05-6726825d.pth``). It differs from torchvision's Inception-v3 in

- the classifier has 1008 outputs and there is no auxiliary classifier;
- every average pool inside the Inception blocks ignores the zero padding
  (``count_include_pad=False``, as TensorFlow does);
- the last block (``Mixed_7c``) uses a 3x3 *max* pool in its pool branch.

Pre-processing (pytorch-fid's): images in [0, 1] are resized to 299x299 by bilinear
interpolation (``align_corners=False``) and mapped to [-1, 1] by ``2x - 1``. The feature
is the global average of ``Mixed_7c``'s output, a 2048-vector per image. torch-fidelity (and
torchmetrics' default extractor) resizes uint8 images with a TF1-style bilinear kernel and maps
them by ``(x - 128) / 128``, so numbers follow pytorch-fid and differ slightly from
torch-fidelity's.

Module and parameter names follow torchvision/pytorch-fid (``Conv2d_1a_3x3.conv.weight``,
``Conv2d_1a_3x3.bn.running_mean``, ``Mixed_5b.branch1x1.conv.weight``, ..., ``fc.weight``),
so the published state dict loads with ``strict=True``.

Weights cannot be downloaded at run time. They come from a local path: the ``path``
argument, else the environment variable ``SIM2REAL_FID_WEIGHTS``; when neither is given
:func:`resolve_fid_weights` returns ``None`` and the caller must report FID/KID as absent
(see :func:`sim2real.metrics.realism.fid_unavailable`), never substitute another network.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from sim2real.engine.checkpoint import mismatch, read_torch_file
from sim2real.errors import UserError

FID_WEIGHTS_ENV = "SIM2REAL_FID_WEIGHTS"
FID_WEIGHTS_FILENAME = "pt_inception-2015-12-05-6726825d.pth"
FID_INPUT_SIZE = 299
FID_NUM_FEATURES = 2048
FID_NUM_CLASSES = 1008


class BasicConv2d(nn.Module):
    """conv (no bias) -> batch norm (eps 1e-3) -> ReLU; keys ``conv.*`` and ``bn.*``."""

    def __init__(self, in_ch: int, out_ch: int, kernel_size, stride=1, padding=0) -> None:
        super().__init__()
        self.conv = nn.Conv2d(in_ch, out_ch, kernel_size, stride=stride, padding=padding, bias=False)
        self.bn = nn.BatchNorm2d(out_ch, eps=0.001)

    def forward(self, x: Tensor) -> Tensor:
        return F.relu(self.bn(self.conv(x)))


def _avg3(x: Tensor) -> Tensor:
    """3x3 stride-1 average pool that ignores the zero padding (TensorFlow semantics)."""
    return F.avg_pool2d(x, kernel_size=3, stride=1, padding=1, count_include_pad=False)


class FIDInceptionA(nn.Module):
    """Mixed_5b/5c/5d: 1x1 | 1x1->5x5 | 1x1->3x3->3x3 | avgpool->1x1 (64+64+96+pool_features)."""

    def __init__(self, in_ch: int, pool_features: int) -> None:
        super().__init__()
        self.branch1x1 = BasicConv2d(in_ch, 64, 1)
        self.branch5x5_1 = BasicConv2d(in_ch, 48, 1)
        self.branch5x5_2 = BasicConv2d(48, 64, 5, padding=2)
        self.branch3x3dbl_1 = BasicConv2d(in_ch, 64, 1)
        self.branch3x3dbl_2 = BasicConv2d(64, 96, 3, padding=1)
        self.branch3x3dbl_3 = BasicConv2d(96, 96, 3, padding=1)
        self.branch_pool = BasicConv2d(in_ch, pool_features, 1)

    def forward(self, x: Tensor) -> Tensor:
        b1 = self.branch1x1(x)
        b5 = self.branch5x5_2(self.branch5x5_1(x))
        b3 = self.branch3x3dbl_3(self.branch3x3dbl_2(self.branch3x3dbl_1(x)))
        bp = self.branch_pool(_avg3(x))
        return torch.cat([b1, b5, b3, bp], dim=1)


class InceptionB(nn.Module):
    """Mixed_6a (grid reduction 35->17): 3x3/2 | 1x1->3x3->3x3/2 | maxpool/2 (384+96+in)."""

    def __init__(self, in_ch: int) -> None:
        super().__init__()
        self.branch3x3 = BasicConv2d(in_ch, 384, 3, stride=2)
        self.branch3x3dbl_1 = BasicConv2d(in_ch, 64, 1)
        self.branch3x3dbl_2 = BasicConv2d(64, 96, 3, padding=1)
        self.branch3x3dbl_3 = BasicConv2d(96, 96, 3, stride=2)

    def forward(self, x: Tensor) -> Tensor:
        b3 = self.branch3x3(x)
        bd = self.branch3x3dbl_3(self.branch3x3dbl_2(self.branch3x3dbl_1(x)))
        bp = F.max_pool2d(x, kernel_size=3, stride=2)
        return torch.cat([b3, bd, bp], dim=1)


class FIDInceptionC(nn.Module):
    """Mixed_6b..6e: factorised 7x7 branches with ``c7`` inner channels (4 x 192 = 768 out)."""

    def __init__(self, in_ch: int, channels_7x7: int) -> None:
        super().__init__()
        c7 = channels_7x7
        self.branch1x1 = BasicConv2d(in_ch, 192, 1)
        self.branch7x7_1 = BasicConv2d(in_ch, c7, 1)
        self.branch7x7_2 = BasicConv2d(c7, c7, (1, 7), padding=(0, 3))
        self.branch7x7_3 = BasicConv2d(c7, 192, (7, 1), padding=(3, 0))
        self.branch7x7dbl_1 = BasicConv2d(in_ch, c7, 1)
        self.branch7x7dbl_2 = BasicConv2d(c7, c7, (7, 1), padding=(3, 0))
        self.branch7x7dbl_3 = BasicConv2d(c7, c7, (1, 7), padding=(0, 3))
        self.branch7x7dbl_4 = BasicConv2d(c7, c7, (7, 1), padding=(3, 0))
        self.branch7x7dbl_5 = BasicConv2d(c7, 192, (1, 7), padding=(0, 3))
        self.branch_pool = BasicConv2d(in_ch, 192, 1)

    def forward(self, x: Tensor) -> Tensor:
        b1 = self.branch1x1(x)
        b7 = self.branch7x7_3(self.branch7x7_2(self.branch7x7_1(x)))
        bd = x
        for layer in (self.branch7x7dbl_1, self.branch7x7dbl_2, self.branch7x7dbl_3,
                      self.branch7x7dbl_4, self.branch7x7dbl_5):
            bd = layer(bd)
        bp = self.branch_pool(_avg3(x))
        return torch.cat([b1, b7, bd, bp], dim=1)


class InceptionD(nn.Module):
    """Mixed_7a (grid reduction 17->8): 1x1->3x3/2 | 1x1->1x7->7x1->3x3/2 | maxpool/2."""

    def __init__(self, in_ch: int) -> None:
        super().__init__()
        self.branch3x3_1 = BasicConv2d(in_ch, 192, 1)
        self.branch3x3_2 = BasicConv2d(192, 320, 3, stride=2)
        self.branch7x7x3_1 = BasicConv2d(in_ch, 192, 1)
        self.branch7x7x3_2 = BasicConv2d(192, 192, (1, 7), padding=(0, 3))
        self.branch7x7x3_3 = BasicConv2d(192, 192, (7, 1), padding=(3, 0))
        self.branch7x7x3_4 = BasicConv2d(192, 192, 3, stride=2)

    def forward(self, x: Tensor) -> Tensor:
        b3 = self.branch3x3_2(self.branch3x3_1(x))
        b7 = self.branch7x7x3_4(self.branch7x7x3_3(self.branch7x7x3_2(self.branch7x7x3_1(x))))
        bp = F.max_pool2d(x, kernel_size=3, stride=2)
        return torch.cat([b3, b7, bp], dim=1)


class FIDInceptionE(nn.Module):
    """Mixed_7b / Mixed_7c (320 + 768 + 768 + 192 = 2048 out).

    ``pool="avg"`` (Mixed_7b): padding-excluding 3x3 average pool in the pool branch;
    ``pool="max"`` (Mixed_7c): 3x3 max pool, as in the TensorFlow FID graph.
    """

    def __init__(self, in_ch: int, pool: str) -> None:
        super().__init__()
        if pool not in ("avg", "max"):
            raise ValueError(f"pool must be 'avg' or 'max', got {pool!r}")
        self.pool = pool
        self.branch1x1 = BasicConv2d(in_ch, 320, 1)
        self.branch3x3_1 = BasicConv2d(in_ch, 384, 1)
        self.branch3x3_2a = BasicConv2d(384, 384, (1, 3), padding=(0, 1))
        self.branch3x3_2b = BasicConv2d(384, 384, (3, 1), padding=(1, 0))
        self.branch3x3dbl_1 = BasicConv2d(in_ch, 448, 1)
        self.branch3x3dbl_2 = BasicConv2d(448, 384, 3, padding=1)
        self.branch3x3dbl_3a = BasicConv2d(384, 384, (1, 3), padding=(0, 1))
        self.branch3x3dbl_3b = BasicConv2d(384, 384, (3, 1), padding=(1, 0))
        self.branch_pool = BasicConv2d(in_ch, 192, 1)

    def forward(self, x: Tensor) -> Tensor:
        b1 = self.branch1x1(x)
        t = self.branch3x3_1(x)
        b3 = torch.cat([self.branch3x3_2a(t), self.branch3x3_2b(t)], dim=1)
        t = self.branch3x3dbl_2(self.branch3x3dbl_1(x))
        bd = torch.cat([self.branch3x3dbl_3a(t), self.branch3x3dbl_3b(t)], dim=1)
        if self.pool == "avg":
            p = _avg3(x)
        else:
            p = F.max_pool2d(x, kernel_size=3, stride=1, padding=1)
        bp = self.branch_pool(p)
        return torch.cat([b1, b3, bd, bp], dim=1)


class FIDInceptionV3(nn.Module):
    """FID Inception-v3 feature extractor, usable as torchmetrics' ``feature=`` module.

    Input: ``(N, 3, H, W)`` RGB, either ``uint8`` in [0, 255] (torchmetrics' ``normalize=False``)
    or floating point in [0, 1] (``normalize=True``). Any H, W: the image is resized to 299x299.
    Output: ``(N, 2048)`` float32 pool3 features. ``num_features = 2048`` is an attribute, so
    torchmetrics does not run a dummy forward pass to find it.

    The module always stays in eval mode (``train()`` is a no-op), so batch norm uses the
    stored statistics. It runs on whatever device its parameters are on; inputs are moved there.
    ``fc`` (2048 -> 1008 logits) exists for state-dict compatibility and is not used by
    :meth:`forward`; :meth:`logits` exposes it.
    """

    num_features: int = FID_NUM_FEATURES

    def __init__(self) -> None:
        super().__init__()
        self.Conv2d_1a_3x3 = BasicConv2d(3, 32, 3, stride=2)
        self.Conv2d_2a_3x3 = BasicConv2d(32, 32, 3)
        self.Conv2d_2b_3x3 = BasicConv2d(32, 64, 3, padding=1)
        self.Conv2d_3b_1x1 = BasicConv2d(64, 80, 1)
        self.Conv2d_4a_3x3 = BasicConv2d(80, 192, 3)
        self.Mixed_5b = FIDInceptionA(192, pool_features=32)
        self.Mixed_5c = FIDInceptionA(256, pool_features=64)
        self.Mixed_5d = FIDInceptionA(288, pool_features=64)
        self.Mixed_6a = InceptionB(288)
        self.Mixed_6b = FIDInceptionC(768, channels_7x7=128)
        self.Mixed_6c = FIDInceptionC(768, channels_7x7=160)
        self.Mixed_6d = FIDInceptionC(768, channels_7x7=160)
        self.Mixed_6e = FIDInceptionC(768, channels_7x7=192)
        self.Mixed_7a = InceptionD(768)
        self.Mixed_7b = FIDInceptionE(1280, pool="avg")
        self.Mixed_7c = FIDInceptionE(2048, pool="max")
        self.fc = nn.Linear(FID_NUM_FEATURES, FID_NUM_CLASSES)
        self.requires_grad_(False)
        super().train(False)

    def train(self, mode: bool = True) -> "FIDInceptionV3":  # noqa: D102 - always eval
        return super().train(False)

    def preprocess(self, images: Tensor) -> Tensor:
        """uint8 [0,255] or float [0,1] (N,3,H,W) -> float32 (N,3,299,299) in [-1,1]."""
        if not isinstance(images, Tensor):
            raise TypeError(f"images must be a torch.Tensor, got {type(images).__name__}")
        if images.ndim != 4 or images.shape[1] != 3:
            raise ValueError(f"images must have shape (N, 3, H, W), got {tuple(images.shape)}")
        device = self.fc.weight.device
        if images.dtype == torch.uint8:
            x = images.to(device=device, dtype=torch.float32) / 255.0
        elif images.is_floating_point():
            x = images.to(device=device, dtype=torch.float32)
        else:
            raise TypeError(f"images must be uint8 or floating point, got {images.dtype}")
        if x.shape[-2:] != (FID_INPUT_SIZE, FID_INPUT_SIZE):
            x = F.interpolate(x, size=(FID_INPUT_SIZE, FID_INPUT_SIZE), mode="bilinear", align_corners=False)
        return 2.0 * x - 1.0

    def features(self, x: Tensor) -> Tensor:
        """Pre-processed (N,3,299,299) in [-1,1] -> (N, 2048) pool3 features."""
        x = self.Conv2d_1a_3x3(x)  # 149
        x = self.Conv2d_2a_3x3(x)  # 147
        x = self.Conv2d_2b_3x3(x)  # 147
        x = F.max_pool2d(x, kernel_size=3, stride=2)  # 73
        x = self.Conv2d_3b_1x1(x)
        x = self.Conv2d_4a_3x3(x)  # 71
        x = F.max_pool2d(x, kernel_size=3, stride=2)  # 35
        for block in (self.Mixed_5b, self.Mixed_5c, self.Mixed_5d, self.Mixed_6a,  # -> 17
                      self.Mixed_6b, self.Mixed_6c, self.Mixed_6d, self.Mixed_6e,
                      self.Mixed_7a, self.Mixed_7b, self.Mixed_7c):  # -> 8
            x = block(x)
        return torch.flatten(F.adaptive_avg_pool2d(x, 1), 1)

    def forward(self, images: Tensor) -> Tensor:
        return self.features(self.preprocess(images))

    def logits(self, images: Tensor) -> Tensor:
        """(N, 1008) classifier logits (not used by FID)."""
        return self.fc(self.forward(images))


def resolve_fid_weights(path: str | os.PathLike | None = None) -> Path | None:
    """Where the FID Inception weights are: ``path``, else ``$SIM2REAL_FID_WEIGHTS``, else None.

    A path that is given (by argument or environment) but does not exist is a user error
    (:class:`~sim2real.errors.UserError`); ``None`` means nobody gave one, and the caller
    must report FID/KID as unavailable.
    """
    source = "argument"
    if path is None or str(path) == "":
        path = os.environ.get(FID_WEIGHTS_ENV) or None
        source = f"${FID_WEIGHTS_ENV}"
    if path is None:
        return None
    p = Path(path).expanduser()
    if not p.is_file():
        raise UserError(f"FID Inception weights not found at {p} (from {source}); "
                        f"expected pytorch-fid's {FID_WEIGHTS_FILENAME}")
    return p


def load_fid_inception(path: str | os.PathLike | None = None,
                       device: str | torch.device | None = None) -> FIDInceptionV3 | None:
    """Build :class:`FIDInceptionV3` and load the weights from a local file (``strict=True``).

    ``path`` is resolved by :func:`resolve_fid_weights`; returns ``None`` when no path was given
    anywhere. The file is a plain state dict (pytorch-fid's ``pt_inception-2015-12-05-6726825d.pth``)
    or a dict holding one under ``"state_dict"``. The only leniency: batch-norm
    ``num_batches_tracked`` counters (unused in eval) may be absent from the file. Any other
    missing or unexpected key, or a shape mismatch, raises a :class:`UserError`.
    """
    p = resolve_fid_weights(path)
    if p is None:
        return None
    state = read_torch_file(p, p, "FID Inception weights")
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise UserError(f"{p} does not hold a state dict")
    net = FIDInceptionV3()
    own = net.state_dict()
    state = dict(state)
    for key, value in own.items():
        if key.endswith("num_batches_tracked") and key not in state:
            state[key] = value.clone()
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise UserError(f"{p} is not an FID Inception-v3 state dict ({mismatch(exc)})") from None
    if device is not None:
        net = net.to(device)
    return net
