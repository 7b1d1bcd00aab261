"""Realism metrics: FID, KID (torchmetrics with our own feature module), Dice, and a proxy.

Paper protocol (Sec. "Metrics"): FID and KID between 10,000 random generated and 10,000 random
real training images; Dice of a liver U-Net (trained on real labelled images) evaluated on the
generated images. The FID/KID numbers are only "standard" with the FID Inception weights
(:mod:`sim2real.metrics.inception`). When they are absent, report ``null`` with a reason
(:func:`fid_unavailable`); :func:`proxy_colour_texture_distance` is a clearly labelled cheap
stand-in that is *not* FID and must never be reported under that name.

Image convention here: ``(N, 3, H, W)`` RGB tensors, float in [0, 1] or uint8 in [0, 255], or an
iterable of such batches. Network-range images in [-1, 1] must be mapped with ``(x + 1) / 2``
first.
"""

from __future__ import annotations

import os
from typing import Iterable, Iterator

import numpy as np
import torch
from torch import Tensor, nn
from torchmetrics.image.fid import FrechetInceptionDistance
from torchmetrics.image.kid import KernelInceptionDistance

from sim2real.colour import grey
from sim2real.metrics.inception import FID_WEIGHTS_ENV, FID_WEIGHTS_FILENAME, resolve_fid_weights

ImageSource = Tensor | Iterable[Tensor]


# --------------------------------------------------------------------------- input handling
def _check_batch(x: Tensor, name: str) -> Tensor:
    if not isinstance(x, Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor batch, got {type(x).__name__}")
    if x.ndim != 4 or x.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (N, 3, H, W), got {tuple(x.shape)}")
    if x.dtype == torch.uint8:
        return x.float() / 255.0
    if not x.is_floating_point():
        raise TypeError(f"{name}: expected uint8 or floating point, got {x.dtype}")
    if x.numel() and (x.min() < -1e-3 or x.max() > 1 + 1e-3):
        raise ValueError(f"{name}: float images must lie in [0, 1] (got range "
                         f"[{float(x.min()):.3f}, {float(x.max()):.3f}]); map [-1, 1] with (x + 1) / 2")
    return x.float().clamp(0.0, 1.0)


def _batches(images: ImageSource, name: str, batch_size: int) -> Iterator[Tensor]:
    """Yield float [0, 1] (n, 3, H, W) batches from a tensor or an iterable of tensors."""
    if isinstance(images, Tensor):
        images = _check_batch(images, name)
        for i in range(0, images.shape[0], batch_size):
            yield images[i:i + batch_size]
    else:
        for b in images:
            b = _check_batch(b, name)
            for i in range(0, b.shape[0], batch_size):
                yield b[i:i + batch_size]


def _module_device(module: nn.Module) -> torch.device:
    for t in list(module.parameters()) + list(module.buffers()):
        return t.device
    return torch.device("cpu")


# --------------------------------------------------------------------------- FID / KID
def clamp_kid_subset_size(subset_size: int, n_real: int, n_gen: int) -> int:
    """KID subset size actually used: ``min(subset_size, n_real, n_gen)``.

    torchmetrics draws ``subsets`` random subsets of ``subset_size`` features from each set
    *without replacement*, so it needs ``subset_size <= n`` for both sets (it raises
    otherwise); the unbiased MMD estimate needs at least 2 samples. The standard choice is
    1000 (for 10,000 images); smaller evaluations get the whole set per subset.
    """
    if subset_size < 1:
        raise ValueError(f"kid_subset_size must be >= 1, got {subset_size}")
    m = min(int(subset_size), int(n_real), int(n_gen))
    if m < 2:
        raise ValueError(f"KID needs at least 2 real and 2 generated images (got {n_real} real, {n_gen} generated)")
    return m


@torch.no_grad()
def fid_kid(gen_images: ImageSource, real_images: ImageSource, feature_module: nn.Module, *,
            kid_subset_size: int = 1000, kid_subsets: int = 100, batch_size: int = 32,
            seed: int = 0) -> dict:
    r"""FID and KID between generated and real images with a given feature extractor.

    With features :math:`f` of the real (r) and generated (g) sets, means :math:`\mu` and
    unbiased covariances :math:`\Sigma`:

    .. math::
        \mathrm{FID} = \lVert \mu_r - \mu_g \rVert^2
            + \operatorname{tr}\bigl(\Sigma_r + \Sigma_g - 2 (\Sigma_r \Sigma_g)^{1/2}\bigr)

    KID is the unbiased squared MMD with the cubic polynomial kernel
    :math:`k(x, y) = (x^\top y / d + 1)^3` (``d`` = feature dim), averaged over ``kid_subsets``
    random subsets of ``m`` samples from each set, ``m`` = :func:`clamp_kid_subset_size`
    ``(kid_subset_size, n_real, n_gen)``. The subset draw uses torch's RNG forked and seeded with
    ``seed``, so the result is reproducible and the caller's RNG state is untouched.

    ``feature_module`` maps float (n, 3, H, W) in [0, 1] to (n, d) features (torchmetrics'
    ``normalize=True`` convention), e.g. :class:`~sim2real.metrics.inception.FIDInceptionV3`.
    Images are moved to the module's device. It runs once per batch; torchmetrics'
    ``FrechetInceptionDistance`` / ``KernelInceptionDistance`` accumulate and compute the
    statistics from those features (their ``feature=`` is an identity over them). Returns
    ``{"fid", "kid_mean", "kid_std", "kid_subset_size", "kid_subsets", "n_real", "n_gen", "num_features"}``.
    """
    if not isinstance(feature_module, nn.Module):
        raise TypeError("feature_module must be a torch.nn.Module")
    device = _module_device(feature_module)
    fid = kid = None
    counts = {True: 0, False: 0}
    for real, source, name in ((True, real_images, "real_images"), (False, gen_images, "gen_images")):
        for b in _batches(source, name, batch_size):
            feats = feature_module(b.to(device))
            if feats.ndim != 2 or feats.shape[0] != b.shape[0]:
                raise ValueError(f"feature_module must return (n, d), got {tuple(feats.shape)}")
            if fid is None:
                ident = _Precomputed(feats.shape[1])
                fid = FrechetInceptionDistance(feature=ident, normalize=True).to(feats.device)
                # subset_size is a placeholder until the counts are known (see below).
                kid = KernelInceptionDistance(feature=ident, normalize=True, subsets=kid_subsets,
                                              subset_size=1).to(feats.device)
            fid.update(feats, real=real)
            kid.update(feats, real=real)
            counts[real] += b.shape[0]
    n_real, n_gen = counts[True], counts[False]
    if n_real < 2 or n_gen < 2:
        raise ValueError(f"FID/KID need at least 2 images per set (got {n_real} real, {n_gen} generated)")
    m = clamp_kid_subset_size(kid_subset_size, n_real, n_gen)
    kid.subset_size = m
    fid_value = float(fid.compute())
    with torch.random.fork_rng(devices=[]):  # torchmetrics draws the subsets with the CPU RNG
        torch.manual_seed(seed)
        kid_mean, kid_std = kid.compute()
    return {"fid": fid_value, "kid_mean": float(kid_mean), "kid_std": float(kid_std),
            "kid_subset_size": m, "kid_subsets": int(kid_subsets),
            "n_real": n_real, "n_gen": n_gen, "num_features": fid.inception.num_features}


class _Precomputed(nn.Module):
    """Identity "feature extractor" handed to torchmetrics.

    :func:`fid_kid` runs the real extractor once per batch and feeds its features to both
    torchmetrics metrics, which then only accumulate statistics (the extractor would otherwise
    run twice, once per metric).
    """

    def __init__(self, num_features: int) -> None:
        super().__init__()
        self.num_features = int(num_features)

    def forward(self, feats: Tensor) -> Tensor:
        return feats


def fid_weights_status(path: str | os.PathLike | None = None) -> dict:
    """Whether the FID Inception weights are available, as a JSON-ready dict.

    ``{"available": True, "path": "..."}`` or ``{"available": False, "path": None, "reason": "..."}``.
    A path that is given but missing raises :class:`~sim2real.errors.UserError` (via
    :func:`~sim2real.metrics.inception.resolve_fid_weights`).
    """
    p = resolve_fid_weights(path)
    if p is None:
        return {"available": False, "path": None,
                "reason": (f"FID Inception weights not given: pass a path or set ${FID_WEIGHTS_ENV} "
                           f"to pytorch-fid's {FID_WEIGHTS_FILENAME} (no download at run time)")}
    return {"available": True, "path": str(p)}


def fid_unavailable(reason: str) -> dict:
    """The metrics.json entry when FID/KID cannot be computed: nulls plus the reason.

    ``{"fid": None, "kid_mean": None, "kid_std": None, "reason": reason}`` - never a number from a
    substitute network.
    """
    return {"fid": None, "kid_mean": None, "kid_std": None, "reason": str(reason)}


# --------------------------------------------------------------------------- proxy (not FID)
def _gradient_magnitude(x: Tensor) -> Tensor:
    """Central-difference gradient magnitude of the grey image, (n, H-2, W-2)."""
    g = grey(x)[:, 0]
    gx = (g[:, 1:-1, 2:] - g[:, 1:-1, :-2]) / 2.0
    gy = (g[:, 2:, 1:-1] - g[:, :-2, 1:-1]) / 2.0
    return torch.sqrt(gx * gx + gy * gy)


@torch.no_grad()
def _proxy_stats(images: ImageSource, name: str, bins: int, grad_max: float, batch_size: int) -> dict:
    n_pix = 0.0
    s = torch.zeros(3, dtype=torch.float64, device="cpu")
    s2 = torch.zeros(3, dtype=torch.float64, device="cpu")
    hist = torch.zeros(bins, dtype=torch.float64, device="cpu")
    grad_sum = 0.0
    n_grad = 0
    for b in _batches(images, name, batch_size):
        b = b.to("cpu", torch.float64)
        if b.shape[-1] < 3 or b.shape[-2] < 3:
            raise ValueError(f"{name}: images must be at least 3x3")
        flat = b.permute(1, 0, 2, 3).reshape(3, -1)
        s += flat.sum(1)
        s2 += (flat * flat).sum(1)
        n_pix += flat.shape[1]
        gm = _gradient_magnitude(b).reshape(-1)
        grad_sum += float(gm.sum())
        n_grad += gm.numel()
        hist += torch.histc(gm.clamp(max=grad_max), bins=bins, min=0.0, max=grad_max)
    if n_pix == 0:
        raise ValueError(f"{name}: no images")
    mean = s / n_pix
    std = torch.sqrt(torch.clamp(s2 / n_pix - mean * mean, min=0.0))
    return {"mean": mean, "std": std, "hist": hist / hist.sum(), "grad_mean": grad_sum / n_grad}


def proxy_stats(real_images: ImageSource, bins: int = 32, grad_max: float = 0.25, batch_size: int = 64) -> dict:
    """The statistics of one set that :func:`proxy_colour_texture_distance` compares."""
    return _proxy_stats(real_images, "real_images", bins, grad_max, batch_size)


def proxy_colour_texture_distance(gen_images: ImageSource, real_images: ImageSource, *,
                                  bins: int = 32, grad_max: float = 0.25, batch_size: int = 64,
                                  real_stats: dict | None = None) -> dict:
    r"""A cheap realism *proxy* (NOT FID): colour-statistics and texture-statistics distances.

    Over all pixels of each set (RGB in [0, 1]): per-channel mean :math:`\mu_c` and standard
    deviation :math:`\sigma_c`; grey :math:`Y = 0.299R + 0.587G + 0.114B`; central-difference
    gradient magnitude :math:`|\nabla Y|` with its histogram :math:`h` (``bins`` bins on
    [0, ``grad_max``], larger values in the last bin, normalised to sum 1).

    .. math::
        d_{colour} = \tfrac{1}{3}\sum_c |\mu^g_c - \mu^r_c| + |\sigma^g_c - \sigma^r_c|, \qquad
        d_{texture} = \tfrac12 \sum_i |h^g_i - h^r_i| \in [0, 1]

    Returns ``{"proxy_colour_distance", "proxy_texture_distance", "proxy_colour_texture_distance"
    (their sum), "proxy_grad_mean_gen", "proxy_grad_mean_real"}``. Zero for identical sets.
    ``real_stats`` (:func:`proxy_stats` of ``real_images`` with the same ``bins`` and
    ``grad_max``) saves recomputing them when several sets are compared with one real set.
    """
    g = _proxy_stats(gen_images, "gen_images", bins, grad_max, batch_size)
    r = real_stats if real_stats is not None else _proxy_stats(real_images, "real_images", bins, grad_max, batch_size)
    d_col = float(((g["mean"] - r["mean"]).abs() + (g["std"] - r["std"]).abs()).sum() / 3.0)
    d_tex = float(0.5 * (g["hist"] - r["hist"]).abs().sum())
    return {"proxy_colour_distance": d_col, "proxy_texture_distance": d_tex,
            "proxy_colour_texture_distance": d_col + d_tex,
            "proxy_grad_mean_gen": g["grad_mean"], "proxy_grad_mean_real": r["grad_mean"]}


# --------------------------------------------------------------------------- Dice
def _as_bool_masks(x, name: str) -> np.ndarray:
    if isinstance(x, Tensor):
        x = x.detach().cpu().numpy()
    x = np.asarray(x)
    if x.ndim == 2:
        x = x[None]
    if x.ndim != 3:
        raise ValueError(f"{name}: expected (H, W) or (N, H, W), got shape {x.shape}")
    if x.dtype != bool:
        if not np.all((x == 0) | (x == 1)):
            raise ValueError(f"{name}: masks must be boolean or 0/1 valued")
        x = x.astype(bool)
    return x


def dice_per_image(pred_mask, gt_mask) -> np.ndarray:
    r"""Per-image Dice coefficient of binary masks, shape (N,) float64.

    .. math:: \mathrm{Dice}(P, G) = \frac{2 |P \cap G|}{|P| + |G|}

    Convention: when both masks are empty (:math:`|P| + |G| = 0`) the Dice is **1** (the
    prediction "no liver" is exactly right); an empty prediction against a non-empty ground
    truth, or vice versa, gives 0. Inputs: (H, W) or (N, H, W), bool or 0/1, numpy or torch.
    """
    p = _as_bool_masks(pred_mask, "pred_mask")
    g = _as_bool_masks(gt_mask, "gt_mask")
    if p.shape != g.shape:
        raise ValueError(f"pred_mask {p.shape} and gt_mask {g.shape} differ in shape")
    inter = np.logical_and(p, g).sum(axis=(1, 2)).astype(np.float64)
    total = p.sum(axis=(1, 2)).astype(np.float64) + g.sum(axis=(1, 2))
    out = np.ones(p.shape[0], dtype=np.float64)
    nz = total > 0
    out[nz] = 2.0 * inter[nz] / total[nz]
    return out


def dice(pred_mask, gt_mask) -> float:
    """Mean over images of :func:`dice_per_image` (each image weighs the same)."""
    return float(dice_per_image(pred_mask, gt_mask).mean())
