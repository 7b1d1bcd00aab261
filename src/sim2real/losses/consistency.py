"""View consistency: backward warp of view j into view i and the angle / L1 losses (L_vc).

Angle loss (supplementary, L_vc), with RGB mapped from [-1, 1] to [0, 1] first
(``u = (b_i + 1) / 2``, ``v = (w_i(b_j) + 1) / 2``):

    L_vc = 1/|M| sum_{(x,y) in M} angle(u_xy, v_xy),   angle(u, v) = acos(u.v / (|u| |v|)).

It is computed as ``atan2(|u x v|_e, u.v)``: exact where acos is ill-conditioned (near 0
and pi) and with finite gradients for parallel vectors, because the cross-product norm is
smoothed as ``|c|_e = sqrt(|c|^2 + e^2) - e`` (0 with zero gradient at c = 0, differs from |c| by
less than e = 1e-6). Where ``|u|^2 |v|^2 < 1e-12`` (a pure black pixel) the angle is undefined;
it counts as 0 with zero gradient. The loss is invariant to scaling either image's brightness
(in [0, 1] space) and ignores pixels outside the mask; an empty mask gives 0.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

_CROSS_EPS = 1e-6
_DEGENERATE = 1e-12


def _to_unit_range(x: torch.Tensor) -> torch.Tensor:
    return (x.float() + 1) * 0.5


def _masked_mean(per_pixel: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """sum(mask * value) / sum(mask), 0 (with a zero gradient) for an empty mask."""
    if mask.shape != per_pixel.shape:
        raise ValueError(f"mask must have shape {tuple(per_pixel.shape)} (B, H, W), got {tuple(mask.shape)}")
    m = mask.to(per_pixel.dtype)
    return (per_pixel * m).sum() / m.sum().clamp_min(1e-6)


def pixel_angle(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Angle in radians between the channel vectors of u and v (B, 3, H, W) -> (B, H, W)."""
    cross = torch.linalg.cross(u, v, dim=1)
    dot = (u * v).sum(1)
    sin_part = torch.sqrt(cross.square().sum(1) + _CROSS_EPS**2) - _CROSS_EPS
    degenerate = u.square().sum(1) * v.square().sum(1) < _DEGENERATE
    y = torch.where(degenerate, torch.zeros_like(sin_part), sin_part)
    x = torch.where(degenerate, torch.ones_like(dot), dot)
    return torch.atan2(y, x)


def angle_loss(b_i: torch.Tensor, b_j_warped: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean angle (radians) between RGB vectors of ``b_i`` and ``w_i(b_j)`` over ``mask``.

    Args:
        b_i, b_j_warped: (B, 3, H, W) in [-1, 1].
        mask: (B, H, W) bool or float, True/1 where the pixel is matched and not occluded.
    """
    _check_pair(b_i, b_j_warped)
    return _masked_mean(pixel_angle(_to_unit_range(b_i), _to_unit_range(b_j_warped)), mask)


def masked_l1_loss(b_i: torch.Tensor, b_j_warped: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The L1 ablation: mean over matched pixels of the channel-mean ``|b_i - w_i(b_j)|``
    (in the networks' [-1, 1] range, as MUNIT's L1 terms)."""
    _check_pair(b_i, b_j_warped)
    return _masked_mean((b_i.float() - b_j_warped.float()).abs().mean(1), mask)


VC_KINDS = ("angle", "l1")
"""``loss.vc_kind`` options: the lighting-invariant angle (paper) and the L1 ablation."""


def view_consistency(kind: str, b_i: torch.Tensor, b_j_warped: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Dispatch on ``loss.vc_kind``: 'angle' (paper) or 'l1' (ablation)."""
    if kind == "angle":
        return angle_loss(b_i, b_j_warped, mask)
    if kind == "l1":
        return masked_l1_loss(b_i, b_j_warped, mask)
    raise ValueError(f"unknown loss.vc_kind {kind!r} (choose {' or '.join(VC_KINDS)})")


def _check_pair(a: torch.Tensor, b: torch.Tensor) -> None:
    if a.shape != b.shape or a.dim() != 4 or a.shape[1] != 3:
        raise ValueError(f"expected two (B, 3, H, W) images, got {tuple(a.shape)} and {tuple(b.shape)}")


def warp_backward(image_j: torch.Tensor, uv: torch.Tensor, valid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Backward warp ``w_i(image_j)``: sample view j at the pixel coordinates where view i's
    surface points land in view j.

    Args:
        image_j: (B, C, H_j, W_j).
        uv: (B, H, W, 2) continuous pixel coordinates (u = column axis, v = row axis) in view j,
            OpenCV convention: pixel (col, row) has its centre at (col + 0.5, row + 0.5).
        valid: (B, H, W) bool, e.g. "hit a surface in i and not occluded in j".

    Returns:
        warped (B, C, H, W), 0 where not matched; mask (B, H, W) bool = valid, finite and
        inside view j (0 <= u <= W_j, 0 <= v <= H_j).

    Bilinear ``grid_sample(align_corners=False)`` with ``g = uv / (W_j, H_j) * 2 - 1``: with
    align_corners=False, -1 and +1 are the outer edges of the border pixels, so a pixel centre
    col + 0.5 maps exactly onto texel col. Within half a pixel of the border the sample is
    clamped to the border pixel (padding 'border'). Differentiable w.r.t. ``image_j``.
    """
    B, C, Hj, Wj = image_j.shape
    if uv.dim() != 4 or uv.shape[0] != B or uv.shape[-1] != 2 or valid.shape != uv.shape[:-1]:
        raise ValueError(
            f"expected image_j (B,C,H,W), uv (B,H,W,2), valid (B,H,W); got {tuple(image_j.shape)}, "
            f"{tuple(uv.shape)}, {tuple(valid.shape)}"
        )
    u, v = uv[..., 0], uv[..., 1]
    mask = valid.bool() & torch.isfinite(uv).all(-1) & (u >= 0) & (u <= Wj) & (v >= 0) & (v <= Hj)
    safe = torch.where(mask.unsqueeze(-1), uv.to(image_j.dtype), 0.0)
    grid = torch.stack((safe[..., 0] / Wj, safe[..., 1] / Hj), dim=-1) * 2 - 1
    warped = F.grid_sample(image_j, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return warped * mask.unsqueeze(1).to(warped.dtype), mask
