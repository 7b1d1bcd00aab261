"""A small U-Net liver segmenter for the Dice realism metric (paper Sec. "Metrics").

The paper trains "a U-Net variant" on 405 labelled real laparoscopic images and reports the Dice
of its liver prediction on the generated images (:func:`sim2real.metrics.realism.dice`). The
exact variant is not given; this one is a plain U-Net:

- ``depth`` levels, each two (conv3x3 -> batch norm -> ReLU) blocks; channels
  ``base, 2*base, 4*base, ...``; 2x2 max-pool down, nearest 2x upsample + conv3x3 up,
  skip connections by concatenation; a 1x1 conv to one logit per pixel.
- Inputs of any size: padded (replicate) to a multiple of ``2**(depth-1)`` and cropped back.

Training (:func:`train_segmenter`): Adam, loss = binary cross-entropy + soft Dice
(1 - 2 sum(p g) / (sum p + sum g + 1)), random horizontal/vertical flips and (``crops``) random
resized crops of 60-100 % of each side, mini-batches drawn with a seeded generator, so a run is
reproducible on a given device. With a validation set it stops once the validation Dice has not
improved by 0.005 for ``patience`` checks and returns the best checked weights (geometric
augmentation only: a colour jitter was measured to make the untranslated a_ref look as good as
real frames to the segmenter, docs/history.md).
Images are (N, 3, H, W) float RGB in [0, 1]; labels (N, H, W) bool (True = liver), or
(N, C, H, W) bool for C classes at once (``out_channels`` = C: one sigmoid logit per class, so
that a real folder labelled with more classes than the liver trains one network for all of them;
the soft Dice is then the mean of the classes' and the first class is the one :func:`predict`
returns and the validation tracks).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from tqdm import tqdm

from sim2real.metrics.realism import dice as dice_score
from sim2real.threads import TORCH_RNG_LOCK


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
        nn.Conv2d(cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
    )


class LiverUNet(nn.Module):
    """U-Net: (N, 3, H, W) in [0, 1] -> (N, out_channels, H, W) logits (the liver's, or one per class)."""

    def __init__(self, base_channels: int = 16, depth: int = 3, out_channels: int = 1) -> None:
        super().__init__()
        if depth < 1 or base_channels < 1:
            raise ValueError("depth and base_channels must be >= 1")
        self.depth = depth
        ch = [base_channels * 2 ** i for i in range(depth)]
        self.down = nn.ModuleList([_block(3 if i == 0 else ch[i - 1], ch[i]) for i in range(depth)])
        self.up_conv = nn.ModuleList([nn.Conv2d(ch[i + 1], ch[i], 3, padding=1) for i in range(depth - 1)])
        self.up = nn.ModuleList([_block(2 * ch[i], ch[i]) for i in range(depth - 1)])
        self.head = nn.Conv2d(ch[0], out_channels, 1)

    def forward(self, x: Tensor) -> Tensor:
        if x.ndim != 4 or x.shape[1] != 3:
            raise ValueError(f"expected (N, 3, H, W), got {tuple(x.shape)}")
        h, w = x.shape[-2:]
        m = 2 ** (self.depth - 1)
        ph, pw = (-h) % m, (-w) % m
        if ph or pw:
            x = F.pad(x, (0, pw, 0, ph), mode="replicate")
        x = 2.0 * x - 1.0
        skips = []
        for i, blk in enumerate(self.down):
            if i > 0:
                x = F.max_pool2d(x, 2)
            x = blk(x)
            skips.append(x)
        for i in reversed(range(self.depth - 1)):
            x = self.up_conv[i](F.interpolate(x, scale_factor=2, mode="nearest"))
            x = self.up[i](torch.cat([x, skips[i]], dim=1))
        return self.head(x)[..., :h, :w]


def _check_images(images: Tensor) -> Tensor:
    if not isinstance(images, Tensor) or images.ndim != 4 or images.shape[1] != 3:
        raise ValueError("images must be a (N, 3, H, W) tensor")
    if images.dtype == torch.uint8:
        return images.float() / 255.0
    if not images.is_floating_point():
        raise TypeError(f"images must be float in [0, 1] or uint8, got {images.dtype}")
    if images.numel() and (images.min() < -1e-3 or images.max() > 1 + 1e-3):
        raise ValueError("float images must lie in [0, 1]")
    return images.float()


def train_segmenter(images: Tensor, labels: Tensor, iterations: int = 500, device: str | torch.device | None = None,
                    seed: int = 0, *, batch_size: int = 8, lr: float = 1e-3, base_channels: int = 16,
                    depth: int = 3, flips: bool = True, crops: bool = False, val: tuple[Tensor, Tensor] | None = None,
                    check_every: int = 100, patience: int = 3, progress: bool = False, history: list | None = None,
                    early_stop: bool = True) -> LiverUNet:
    """Train a :class:`LiverUNet` on (images (N,3,H,W) in [0,1], labels (N,H,W) or (N,C,H,W) bool).

    ``iterations`` Adam steps on random mini-batches of ``batch_size`` (with replacement across
    steps). ``device`` defaults to the images' device. ``progress`` shows a progress bar.
    ``early_stop=False`` trains exactly ``iterations`` steps and keeps the last weights (the
    validation Dice is still recorded in ``history``): the step count then does not depend on
    how the kernels round. Returns the model in eval mode, on ``device``.
    """
    images = _check_images(images)
    if not isinstance(labels, Tensor):
        labels = torch.as_tensor(labels)
    multi = labels.ndim == 4
    if (labels.shape[:1] + labels.shape[-2:] != (images.shape[0],) + tuple(images.shape[-2:])
            or labels.ndim not in (3, 4) or (multi and labels.shape[1] < 1)):
        raise ValueError(f"labels must be (N, H, W) or (N, C, H, W) with N, H, W = "
                         f"{(images.shape[0],) + tuple(images.shape[-2:])}, got {tuple(labels.shape)}")
    out_channels = labels.shape[1] if multi else 1
    if iterations < 0:
        raise ValueError("iterations must be >= 0")
    device = torch.device(device) if device is not None else images.device
    with TORCH_RNG_LOCK, torch.random.fork_rng(devices=[]):  # seeded initialisation, caller's RNG untouched
        torch.manual_seed(seed)
        model = LiverUNet(base_channels=base_channels, depth=depth, out_channels=out_channels)
    model = model.to(device)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    # without early stopping the last weights are kept: the learning rate falls to 0 along a cosine,
    # so that they settle instead of stopping at a random point of Adam's noise
    sched = None if early_stop else torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(iterations, 1))
    gen = torch.Generator(device="cpu").manual_seed(seed)
    x_all = images.to(device)
    y_all = labels.to(device=device, dtype=torch.float32)
    y_all = y_all if multi else y_all[:, None]
    if val is not None and multi:
        val = (val[0], val[1][:, 0])  # the validation tracks the first class
    n = x_all.shape[0]
    best, best_state, since = -1.0, None, 0
    model.train()
    for it in tqdm(range(iterations), desc="liver U-Net", unit="it", disable=not progress):
        if val is not None and it > 0 and it % check_every == 0:
            d = dice_score(predict(model, val[0]), val[1])
            model.train()
            if history is not None:
                history.append((it, d))
            if d > best + 0.005:
                best, since = d, 0
                best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
            else:
                since += 1
                if since >= patience and early_stop:
                    break
        idx = torch.randint(0, n, (min(batch_size, n),), generator=gen).to(device)
        x, y = x_all[idx], y_all[idx]
        if crops:
            x, y = _random_resized_crop(x, y, gen)
        if flips:
            if torch.rand((), generator=gen) < 0.5:
                x, y = x.flip(-1), y.flip(-1)
            if torch.rand((), generator=gen) < 0.5:
                x, y = x.flip(-2), y.flip(-2)
        logits = model(x)
        p = torch.sigmoid(logits)
        if multi:  # each class's soft Dice, averaged: a small class weighs as much as the liver
            dims = (0, 2, 3)
            soft_dice = (1.0 - (2.0 * (p * y).sum(dims) + 1.0) / (p.sum(dims) + y.sum(dims) + 1.0)).mean()
        else:
            soft_dice = 1.0 - (2.0 * (p * y).sum() + 1.0) / (p.sum() + y.sum() + 1.0)
        loss = F.binary_cross_entropy_with_logits(logits, y) + soft_dice
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if sched is not None:
            sched.step()
    if best_state is not None and early_stop:
        d = dice_score(predict(model, val[0]), val[1])
        if history is not None:
            history.append((it + 1, d))
        if d <= best:
            model.load_state_dict(best_state)
    return model.eval()


def _random_resized_crop(x: Tensor, y: Tensor, gen: torch.Generator) -> tuple[Tensor, Tensor]:
    """One random crop of 60-100 % of each side for the whole batch, resized back (images
    bilinear, labels nearest)."""
    h, w = x.shape[-2:]
    s = 0.6 + 0.4 * float(torch.rand((), generator=gen))
    ch, cw = max(2, round(h * s)), max(2, round(w * s))
    top = int(torch.randint(0, h - ch + 1, (), generator=gen))
    left = int(torch.randint(0, w - cw + 1, (), generator=gen))
    xc = F.interpolate(x[..., top:top + ch, left:left + cw], size=(h, w), mode="bilinear", align_corners=False)
    yc = F.interpolate(y[..., top:top + ch, left:left + cw], size=(h, w), mode="nearest")
    return xc, yc


@torch.no_grad()
def predict_classes(model: nn.Module, images: Tensor, *, batch_size: int = 16, threshold: float = 0.5) -> Tensor:
    """Class masks (N, C, H, W) bool: sigmoid(logit) > ``threshold`` per class; runs on the
    model's device, returns on the images' device. The model is put in eval mode."""
    images = _check_images(images)
    model.eval()
    dev = next(model.parameters()).device
    out = []
    for i in range(0, images.shape[0], batch_size):
        logits = model(images[i:i + batch_size].to(dev))
        out.append((torch.sigmoid(logits) > threshold).to(images.device))
    if not out:
        return torch.zeros((0, model.head.out_channels) + tuple(images.shape[-2:]), dtype=torch.bool,
                           device=images.device)
    return torch.cat(out)


def predict(model: nn.Module, images: Tensor, *, batch_size: int = 16, threshold: float = 0.5) -> Tensor:
    """Liver masks (N, H, W) bool (the first class of a many-class model): see :func:`predict_classes`."""
    return predict_classes(model, images, batch_size=batch_size, threshold=threshold)[:, 0]
