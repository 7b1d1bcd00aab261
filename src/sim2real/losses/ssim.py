"""Structure loss on grey values: ``1 - MS-SSIM(grey(x), grey(y))`` (supplementary, L_ssim).

Images enter in [-1, 1], are mapped to [0, 1] and reduced to grey
``0.299 R + 0.587 G + 0.114 B`` (ITU-R BT.601), then compared with pytorch-msssim's
``ms_ssim`` (data range 1, Gaussian window ``win`` with sigma 1.5). The paper uses 5 scales
and an 11x11 window. pytorch-msssim requires the short image side to be
> 16 (win - 1) whatever the number of scales (161 px for win 11, 97 for 7, 33 for 3);
``check_ssim_size`` turns that into a clear error. Fewer than 5 scales use the first
standard MS-SSIM weights, renormalised to sum to 1.
"""

from __future__ import annotations

import torch
from pytorch_msssim import ms_ssim

from sim2real.colour import grey as colour_grey

MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)


def grey(x: torch.Tensor) -> torch.Tensor:
    """(B, 3, H, W) in [-1, 1] -> (B, 1, H, W) grey in [0, 1] (:func:`sim2real.colour.grey`)."""
    return colour_grey((x + 1) * 0.5)


def check_ssim_size(height: int, width: int, win: int) -> None:
    """Raise ValueError unless pytorch-msssim accepts ``height x width`` with window ``win``."""
    if win < 1 or win % 2 == 0:
        raise ValueError(f"loss.ssim_win must be an odd positive window size, got {win}")
    need = 16 * (win - 1)
    if min(height, width) <= need:
        raise ValueError(
            f"MS-SSIM with loss.ssim_win={win} needs a short image side > 16*(win-1) = {need} px, "
            f"got {height}x{width} (data.height x data.width); lower loss.ssim_win "
            f"(largest allowed here: {_max_win(height, width)}) "
            f"or enlarge the images"
        )


def _max_win(height: int, width: int) -> int:
    w = (min(height, width) - 1) // 16 + 1  # largest w with 16 (w - 1) < short side
    return w if w % 2 else w - 1


def ms_ssim_loss(x: torch.Tensor, y: torch.Tensor, win: int = 11, scales: int = 5) -> torch.Tensor:
    """``1 - MS-SSIM(grey(x), grey(y))`` averaged over the batch; x, y (B, 3, H, W) in [-1, 1]."""
    if x.shape != y.shape:
        raise ValueError(f"ms_ssim_loss: shapes differ, {tuple(x.shape)} vs {tuple(y.shape)}")
    if not 1 <= scales <= len(MS_SSIM_WEIGHTS):
        raise ValueError(f"loss.ssim_scales must be in 1..{len(MS_SSIM_WEIGHTS)}, got {scales}")
    check_ssim_size(x.shape[-2], x.shape[-1], win)
    w = MS_SSIM_WEIGHTS[:scales]
    weights = [v / sum(w) for v in w]
    # the grey conversion too: a bf16 network output is widened before the weighted sum
    gx, gy = grey(x.float()), grey(y.float())
    # fp32 even under autocast, the window convolutions included: in bf16, sigma^2 = E[x^2] - E[x]^2
    # cancels to <= 0, pytorch-msssim clamps the negative contrast terms to 0, and the loss is a
    # constant 1 without gradient (measured: 1.0 under CPU bf16 autocast vs 0.80 in fp32)
    # pytorch-msssim builds its window without a device: on the images' device from the start
    with torch.autocast(gx.device.type, enabled=False), torch.device(gx.device):
        return 1 - ms_ssim(gx, gy, data_range=1.0, size_average=True, win_size=win, weights=weights)
