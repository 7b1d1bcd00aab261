"""The package's one grey conversion, and its two users agreeing with it."""

import cv2
import numpy as np
import torch

from sim2real.colour import grey
from sim2real.losses.ssim import grey as ssim_grey
from sim2real.metrics.realism import _gradient_magnitude


def test_grey_matches_opencv_and_its_users():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    x = torch.from_numpy(img).permute(2, 0, 1)[None].double() / 255
    ref = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float64) / 255  # OpenCV rounds to uint8
    assert np.abs(grey(x)[0, 0].numpy() - ref).max() <= 0.5 / 255 + 1e-9
    assert torch.allclose(ssim_grey(2 * x - 1), grey(x))
    # the realism proxy's gradient is that of the same grey image: for a pure-green ramp along x
    # the central difference is 0.587 * (step of the ramp)
    ramp = torch.zeros(1, 3, 4, 6, dtype=torch.float64)
    ramp[:, 1] = torch.arange(6, dtype=torch.float64) * 0.1
    assert torch.allclose(_gradient_magnitude(ramp), torch.full((1, 2, 4), 0.0587, dtype=torch.float64))
    assert abs(grey(np.ones((1, 3, 2, 2)))[0, 0, 0, 0] - 1.0) < 1e-12  # numpy arrays too; white stays white
