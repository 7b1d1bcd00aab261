"""The a -> b structure term: edge recall at a_ref's edges, and the switch between it and MS-SSIM."""

import math

import numpy as np
import pytest
import torch
from scipy import ndimage

from sim2real.config import LossConfig, TrainConfig, override
from sim2real.errors import UserError
from sim2real.losses import edge_recall_loss, ms_ssim_loss, structure_ab_loss
from sim2real.validation import validate


def image(grey_values) -> torch.Tensor:
    """(1, 3, H, W) in [-1, 1] whose grey value (BT.601 weights sum to 1) is ``grey_values``."""
    g = torch.as_tensor(np.asarray(grey_values, dtype=np.float32))
    return (2 * g - 1).expand(1, 3, *g.shape).clone()


def step(cols_from: int, h: int = 12, w: int = 24, lo: float = 0.0, hi: float = 1.0) -> np.ndarray:
    g = np.full((h, w), lo, np.float32)
    g[:, cols_from:] = hi
    return g


def test_a_step_edge_by_hand():
    # a unit step gives the normalised Sobel gradient 1/2 on the two columns beside it, and nothing
    # elsewhere: both columns weigh 1/2. b_hat's step of 0.1 gives 0.05 across, so with c = 0.05
    # L = 1 - tanh(1)
    a = image(step(12))
    x = image(step(12, lo=0.3, hi=0.4))
    assert edge_recall_loss(a, x, contrast=0.05, sigma=0).item() == pytest.approx(1 - math.tanh(1), abs=1e-5)
    # the sign of the contrast does not matter (a wall darker than the liver in one domain only)
    x_inv = image(step(12, lo=0.4, hi=0.3))
    assert edge_recall_loss(a, x_inv, contrast=0.05, sigma=0).item() == pytest.approx(1 - math.tanh(1), abs=1e-5)
    # the same step 3 px away has no gradient on a's edge columns: the full charge
    x_shift = image(step(15, lo=0.3, hi=0.4))
    assert edge_recall_loss(a, x_shift, contrast=0.05, sigma=0).item() == pytest.approx(1.0, abs=1e-6)


def test_edges_where_a_has_none_cost_nothing():
    a = image(step(24, h=40, w=48))
    g = step(24, h=40, w=48, lo=0.3, hi=0.4)
    rng = np.random.default_rng(0)
    textured = g.copy()
    textured[:, :21] += rng.uniform(-0.2, 0.2, (40, 21))  # texture >= 2 px from a's edge columns 23, 24
    textured[:, 27:] += rng.uniform(-0.2, 0.2, (40, 21))
    plain = edge_recall_loss(a, image(g), contrast=0.05, sigma=0).item()
    assert edge_recall_loss(a, image(textured), contrast=0.05, sigma=0).item() == pytest.approx(plain, abs=1e-6)
    # MS-SSIM does charge the same texture
    assert ms_ssim_loss(a, image(textured), win=3) > ms_ssim_loss(a, image(g), win=3) + 0.05


def test_edges_weigh_by_their_strength_by_hand():
    # a: 0 | 1 | 0.5: a step of 1 (gradient 1/2 on two columns) and one of -0.5 (1/4 on two):
    # weights 0.25 / (0.25 + 0.0625) = 0.8 and 0.2. With x = a and c = 0.25 the parts across are
    # 0.5 / 0.25 = 2 and 0.25 / 0.25 = 1.
    g = np.zeros((10, 30), np.float32)
    g[:, 10:20] = 1.0
    g[:, 20:] = 0.5
    a = image(g)
    want = 0.8 * (1 - math.tanh(2)) + 0.2 * (1 - math.tanh(1))
    assert edge_recall_loss(a, a, contrast=0.25, sigma=0).item() == pytest.approx(want, abs=1e-5)
    # without the weak edge in x, its fifth of the weight is charged in full
    x = g.copy()
    x[:, 20:] = 1.0
    want = 0.8 * (1 - math.tanh(2)) + 0.2
    assert edge_recall_loss(a, image(x), contrast=0.25, sigma=0).item() == pytest.approx(want, abs=1e-5)
    # power 2: weights 0.25^2 / (0.25^2 + 0.0625^2) = 16/17 and 1/17
    want = 16 / 17 * (1 - math.tanh(2)) + 1 / 17
    assert edge_recall_loss(a, image(x), contrast=0.25, sigma=0, power=2).item() == pytest.approx(want, abs=1e-5)


def test_blurred_random_images_match_an_independent_scipy_computation():
    rng = np.random.default_rng(3)
    ga, gx = rng.uniform(0, 1, (2, 20, 28)).astype(np.float32)
    sigma, c = 1.0, 0.05

    def grad(g):  # torch's 'reflect' pad is scipy's 'mirror'; kornia's Sobel pads 'replicate' = 'nearest'
        b = ndimage.gaussian_filter(g.astype(np.float64), sigma, mode="mirror", truncate=3.0)
        return ndimage.sobel(b, 1, mode="nearest") / 8, ndimage.sobel(b, 0, mode="nearest") / 8

    (ax, ay), (xx, xy) = grad(ga), grad(gx)
    m2 = ax**2 + ay**2
    for power in (1.0, 2.0):
        w = m2**power / (m2**power).sum()
        want = (w * (1 - np.tanh(np.abs(ax * xx + ay * xy) / (np.sqrt(m2) * c)))).sum()
        got = edge_recall_loss(image(ga), image(gx), contrast=c, sigma=sigma, power=power).item()
        assert got == pytest.approx(want, abs=1e-5)


@pytest.mark.parametrize("sigma", [0.6, 1.0, 2.3])
def test_the_gaussian_blur_is_kornias_and_scipys(sigma):
    """The blur made without kornia's host sync gives kornia's gaussian_blur2d values, and scipy's
    Gaussian filter (mirror borders, radius int(3 sigma + 0.5), equal to ceil(3 sigma) here)."""
    import kornia

    from sim2real.losses.structure import gaussian_blur

    g = torch.from_numpy(np.random.default_rng(5).uniform(0, 1, (2, 1, 24, 31)).astype(np.float32))
    k = 2 * math.ceil(3 * sigma) + 1
    got = gaussian_blur(g, sigma)
    assert torch.allclose(got, kornia.filters.gaussian_blur2d(g, (k, k), (sigma, sigma)), atol=1e-6)
    want = np.stack([ndimage.gaussian_filter(c[0].astype(np.float64), sigma, mode="mirror", truncate=3.0)
                     for c in g.numpy()])
    assert np.abs(got[:, 0].numpy() - want).max() < 1e-5


def test_an_edgeless_a_gives_zero_and_the_gradient_reaches_the_missing_edge():
    flat = image(np.full((8, 16), 0.5, np.float32))
    assert edge_recall_loss(flat, image(step(8, h=8, w=16)), sigma=0).item() == 0.0
    a = image(step(12))
    x = image(step(12, lo=0.3, hi=0.31)).requires_grad_(True)  # a faint edge: L near 1
    edge_recall_loss(a, x, contrast=0.05, sigma=0).backward()
    g = x.grad[0].sum(0)  # (H, W)
    # strengthening the edge lowers the loss: darker left of it, lighter right of it
    assert (g[:, 10:12] > 0).all() and (g[:, 12:14] < 0).all()
    assert torch.count_nonzero(g[:, :9]) == 0 and torch.count_nonzero(g[:, 16:]) == 0


def test_structure_ab_loss_switches_on_the_config():
    rng = np.random.default_rng(1)
    a, x = (image(v) for v in rng.uniform(0, 1, (2, 40, 40)).astype(np.float32))
    L = LossConfig(ssim_win=3)
    assert structure_ab_loss(a, x, L).item() == pytest.approx(ms_ssim_loss(a, x, win=3).item(), abs=1e-7)
    L = LossConfig(ab_structure="edges", edge_contrast=0.1, edge_sigma=0.5, edge_power=2)
    assert structure_ab_loss(a, x, L).item() == pytest.approx(
        edge_recall_loss(a, x, contrast=0.1, sigma=0.5, power=2).item(), abs=1e-7)


@pytest.mark.parametrize("key, value", [("loss.ab_structure", "sobel"), ("loss.edge_contrast", "0"),
                                        ("loss.edge_sigma", "-1"), ("loss.edge_power", "0")])
def test_bad_structure_settings_name_the_key(key, value):
    with pytest.raises(UserError, match=key.replace(".", r"\.")):
        validate(override(TrainConfig(), [f"{key}={value}"]))
