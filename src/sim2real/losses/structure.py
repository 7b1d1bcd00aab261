"""The a -> b structure term, and the edge-recall variant of it (issue "Detail that stays").

The paper's term, ``1 - MS-SSIM(grey a_ref, grey b_hat)`` (:mod:`sim2real.losses.ssim`), keeps
the labels of a translation in place, but it also charges everything a real image has and a_ref
has not: the real domain's shading, vignette, highlights and texture. ``benchmarks/loss_probe.py``
measured it on the demo's path: a perfect video pays 0.21, the smooth frames of the shipped model
0.025, and a perfect video shifted by 4 px only 0.24 (docs/detail_study.md).

Edge recall asks only whether b_hat has an edge wherever a_ref has one. On grey images g_a, g_x
(BT.601, in [0, 1]), both blurred by a Gaussian of ``sigma`` px (none for 0), with ``∇`` the
normalised Sobel gradient (kornia's ``spatial_gradient``: the kernel divided by 8, so a unit step
gives 1/2 on the two pixels beside it)::

    w_p = |∇g_a(p)|^(2k) / sum_q |∇g_a(q)|^(2k)
    L   = sum_p w_p * (1 - tanh(|<∇g_a(p), ∇g_x(p)>| / (|∇g_a(p)| * c)))

that is, at every edge pixel of a_ref (weighted by its edge strength to the power ``2k``,
``power``), the part of b_hat's gradient across a_ref's edge, against ``c``, the contrast (grey
per pixel) that counts as an edge. With k = 1 a_ref's soft shading gradients, wide and weak, hold
a good part of the weight; k = 2 leaves it almost all to the outlines. L is in
[0, 1]: 0 for strong edges in the same place, 1 for none there. It does not depend on the edges'
sign (a wall darker than the liver in the real domain and lighter in a_ref is no charge), and
edges b_hat has where a_ref has none, such as texture and highlights, cost nothing. An a_ref without
edges gives 0. On the demo's path (``c`` 0.02, ``sigma`` 1, ``benchmarks/loss_probe.py``) it charges
a perfect video 0.028 and the shipped model's frames 0.025, but the perfect video shifted by 4 px
0.60 and another view's 0.76; with k = 2, 0.007, 0.012, 0.63 and 0.76. ``c`` is per pixel: it was
chosen at 128x256, and larger frames have weaker gradients per pixel for the same outline.
"""

from __future__ import annotations

import math

import kornia
import torch

from sim2real.losses.ssim import grey, ms_ssim_loss

STRUCTURES = ("ms_ssim", "edges")
"""What ``loss.ab_structure`` may name."""


def gaussian_blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """``kornia.filters.gaussian_blur2d(x, (k, k), (sigma, sigma))`` with k = 2 ceil(3 sigma) + 1
    (reflected borders), the same values (tested) without a host sync: kornia 0.9 checks that sigma
    is positive by reading back a tensor it makes without a device, which inside a device context
    (on a GPU) is a copy to the device and a read back on every call. Here the kernel is made from a
    sigma on x's device."""
    k = 2 * math.ceil(3 * sigma) + 1
    kernel = kornia.filters.get_gaussian_kernel1d(k, torch.full((1, 1), float(sigma), device=x.device, dtype=x.dtype))
    return kornia.filters.filter2d_separable(x, kernel, kernel, border_type="reflect")


def edge_recall_loss(a: torch.Tensor, x: torch.Tensor, contrast: float = 0.02, sigma: float = 1.0,
                     power: float = 1.0) -> torch.Tensor:
    """Edge recall of ``x`` at the edges of ``a`` (module docstring), averaged over the batch;
    a, x (B, 3, H, W) in [-1, 1]. Computed in fp32 even under autocast: ``contrast`` (0.02-0.08
    grey per pixel) is within a few steps of bf16's resolution (2**-8 relative), and the
    blurred gradients of a bf16 convolution would move edges in and out of it."""
    if a.shape != x.shape:
        raise ValueError(f"edge_recall_loss: shapes differ, {tuple(a.shape)} vs {tuple(x.shape)}")
    if not contrast > 0 or not sigma >= 0 or not power > 0:
        raise ValueError(f"edge_recall_loss: needs contrast > 0, sigma >= 0 and power > 0, got {contrast}, {sigma}, "
                         f"{power}")
    with torch.autocast(a.device.type, enabled=False):
        ga, gx = grey(a.float()), grey(x.float())
        if sigma > 0:
            ga, gx = gaussian_blur(ga, sigma), gaussian_blur(gx, sigma)
        da = kornia.filters.spatial_gradient(ga)[:, 0]  # (B, 2, H, W): d/dx, d/dy
        dx = kornia.filters.spatial_gradient(gx)[:, 0]
        m2 = (da**2).sum(1)
        across = (da * dx).sum(1).abs() / (m2.sqrt() * contrast + 1e-12)
        w = m2**power
        w = w / (w.sum((1, 2), keepdim=True) + 1e-30)
        return (w * (1 - torch.tanh(across))).sum((1, 2)).mean()


def structure_ab_loss(a: torch.Tensor, b_hat: torch.Tensor, L) -> torch.Tensor:
    """The a -> b structure term that the loss config ``L.ab_structure`` names (weight
    ``loss.ssim_ab``): the paper's ``1 - MS-SSIM`` of grey images, or the edge recall of b_hat at
    a_ref's edges."""
    if L.ab_structure == "edges":
        return edge_recall_loss(a, b_hat, L.edge_contrast, L.edge_sigma, L.edge_power)
    return ms_ssim_loss(a, b_hat, L.ssim_win, L.ssim_scales)
