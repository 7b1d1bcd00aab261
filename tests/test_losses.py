"""Losses: LSGAN, L1, grey MS-SSIM, view-consistency angle/L1 and the backward warp."""

import math

import numpy as np
import pytest
import torch

from sim2real.losses import (
    angle_loss,
    check_ssim_size,
    grey,
    l1,
    lsgan_dis_loss,
    lsgan_gen_loss,
    masked_l1_loss,
    ms_ssim_loss,
    view_consistency,
    warp_backward,
)


def _rgb(*c):
    """One-pixel image from an RGB colour in [0, 1], returned in the networks' [-1, 1] range."""
    return (torch.tensor(c, dtype=torch.float32).view(1, 3, 1, 1) * 2 - 1)


def _ones(h=1, w=1):
    return torch.ones(1, h, w, dtype=torch.bool)


# ---------------------------------------------------------------- GAN / L1


def test_lsgan_losses_on_constant_outputs():
    fake = [torch.full((2, 1, 4, 4), 0.5), torch.full((2, 1, 2, 2), 0.25)]
    real = [torch.full((2, 1, 4, 4), 1.0), torch.full((2, 1, 2, 2), 0.0)]
    # dis: (0.5^2 + 0) + (0.25^2 + 1^2) ; gen: (0.5-1)^2 + (0.25-1)^2
    assert lsgan_dis_loss(fake, real).item() == pytest.approx(0.25 + 0.0625 + 1.0)
    assert lsgan_gen_loss(fake).item() == pytest.approx(0.25 + 0.5625)
    assert lsgan_dis_loss([torch.zeros(1, 1, 3, 3)], [torch.ones(1, 1, 3, 3)]).item() == 0
    with pytest.raises(ValueError):
        lsgan_dis_loss(fake, real[:1])


def test_lsgan_mean_is_per_scale_not_per_element_total():
    """A scale with 4x the elements but the same error contributes the same amount."""
    loss = lsgan_gen_loss([torch.zeros(1, 1, 8, 8), torch.zeros(1, 1, 2, 2)])
    assert loss.item() == pytest.approx(2.0)


def test_l1_is_elementwise_mean():
    x = torch.tensor([[1.0, -1.0], [0.5, 0.0]])
    assert l1(x, torch.zeros(2, 2)).item() == pytest.approx(2.5 / 4)
    with pytest.raises(ValueError):
        l1(x, torch.zeros(4))


# ---------------------------------------------------------------- MS-SSIM


def test_grey_weights():
    g = grey(torch.cat([_rgb(1, 0, 0), _rgb(0, 1, 0), _rgb(0, 0, 1), _rgb(1, 1, 1)]))
    torch.testing.assert_close(g.flatten(), torch.tensor([0.299, 0.587, 0.114, 1.0]))


def test_ms_ssim_zero_for_identical_and_positive_for_different():
    torch.manual_seed(0)
    x = torch.rand(2, 3, 40, 48) * 2 - 1
    assert ms_ssim_loss(x, x.clone(), win=3, scales=5).item() == pytest.approx(0.0, abs=1e-5)
    y = (x + 0.5 * torch.randn_like(x)).clamp(-1, 1)
    assert ms_ssim_loss(x, y, win=3).item() > 0.05


def test_ms_ssim_only_sees_grey_values():
    """Adding a colour offset orthogonal to the grey weights changes RGB, not grey: loss ~ 0."""
    torch.manual_seed(1)
    x01 = torch.rand(1, 3, 40, 40) * 0.5 + 0.25
    d = torch.tensor([0.587, -0.299, 0.0]).view(1, 3, 1, 1) * 0.3  # 0.299*0.587 - 0.587*0.299 = 0
    x, y = x01 * 2 - 1, (x01 + d) * 2 - 1
    assert (x - y).abs().max() > 0.1
    assert ms_ssim_loss(x, y, win=3).item() == pytest.approx(0.0, abs=1e-5)


def test_ms_ssim_gradient_is_finite():
    torch.manual_seed(2)
    x = (torch.rand(1, 3, 40, 40) * 2 - 1).requires_grad_()
    ms_ssim_loss(x, torch.rand(1, 3, 40, 40) * 2 - 1, win=3).backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0


def test_ms_ssim_is_computed_in_fp32_under_autocast():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(1, 3, 64, 128, generator=g) * 2 - 1
    y = (x + 0.3 * torch.randn(1, 3, 64, 128, generator=g)).clamp(-1, 1)
    want = ms_ssim_loss(x, y, win=3).item()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = ms_ssim_loss(x.bfloat16(), y.bfloat16(), win=3).item()
    assert 0.05 < want < 0.95 and got == pytest.approx(want, abs=1e-2)


def test_ms_ssim_size_limit_error_names_the_fields():
    with pytest.raises(ValueError, match=r"loss\.ssim_win=11.*160 px.*64x128.*data\.height.*largest allowed here: 3"):
        ms_ssim_loss(torch.zeros(1, 3, 64, 128), torch.zeros(1, 3, 64, 128), win=11)
    check_ssim_size(161, 300, 11)  # the paper's smallest size for win 11
    with pytest.raises(ValueError):
        check_ssim_size(160, 300, 11)
    check_ssim_size(128, 256, 7)
    with pytest.raises(ValueError, match="odd"):
        check_ssim_size(256, 512, 4)


# ---------------------------------------------------------------- view consistency


def test_angle_zero_for_identical_and_brightness_scaled():
    torch.manual_seed(3)
    b = torch.rand(2, 3, 5, 6) * 2 - 1
    m = torch.ones(2, 5, 6, dtype=torch.bool)
    assert angle_loss(b, b.clone(), m).item() == pytest.approx(0.0, abs=1e-6)
    darker = ((b + 1) / 2 * 0.5) * 2 - 1  # x0.5 in [0, 1] space
    assert angle_loss(b, darker, m).item() == pytest.approx(0.0, abs=1e-4)
    assert angle_loss(darker, b, m).item() == pytest.approx(0.0, abs=1e-4)
    assert masked_l1_loss(b, darker, m).item() > 0.1  # L1 is not lighting invariant


def test_angle_known_values():
    m = _ones()
    assert angle_loss(_rgb(1, 0, 0), _rgb(0, 1, 0), m).item() == pytest.approx(math.pi / 2, abs=1e-6)
    assert angle_loss(_rgb(1, 0, 0), _rgb(1, 1, 0), m).item() == pytest.approx(math.pi / 4, abs=1e-6)
    assert angle_loss(_rgb(1, 1, 1), _rgb(0.2, 0.2, 0.2), m).item() == pytest.approx(0.0, abs=1e-6)


def test_angle_matches_acos_formula_over_mask_and_is_scale_invariant():
    g = torch.Generator().manual_seed(4)
    bi = torch.rand(2, 3, 4, 5, generator=g) * 2 - 1
    bj = torch.rand(2, 3, 4, 5, generator=g) * 2 - 1
    mask = torch.rand(2, 4, 5, generator=g) > 0.4
    u, v = ((bi + 1) / 2).double().numpy(), ((bj + 1) / 2).double().numpy()
    cos = (u * v).sum(1) / (np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1))
    want = np.arccos(np.clip(cos, -1, 1))[mask.numpy()].mean()
    assert angle_loss(bi, bj, mask).item() == pytest.approx(want, abs=1e-5)
    scaled = ((bj + 1) / 2 * 0.7) * 2 - 1
    assert angle_loss(bi, scaled, mask).item() == pytest.approx(want, abs=1e-5)


def test_masked_pixels_are_ignored_and_empty_mask_is_zero():
    torch.manual_seed(5)
    bi = torch.rand(1, 3, 3, 4) * 2 - 1
    bj = bi.clone()
    mask = torch.ones(1, 3, 4, dtype=torch.bool)
    mask[0, 1, 2] = False
    bj[0, :, 1, 2] = torch.tensor([1.0, -1.0, -1.0])  # a wildly different colour, masked out
    for fn in (angle_loss, masked_l1_loss):
        assert fn(bi, bj, mask).item() == pytest.approx(0.0, abs=1e-6)
        assert fn(bi, bj, mask.float()).item() == pytest.approx(0.0, abs=1e-6)
        x = bi.clone().requires_grad_()
        loss = fn(x, bj, torch.zeros_like(mask))
        loss.backward()
        assert loss.item() == 0 and torch.isfinite(x.grad).all() and (x.grad == 0).all()


def test_angle_gradients_finite_for_parallel_and_zero_vectors():
    black = torch.full((1, 3, 2, 2), -1.0)  # zero vectors in [0, 1] space
    grey_img = torch.zeros(1, 3, 2, 2)
    m = torch.ones(1, 2, 2, dtype=torch.bool)
    for a, b in [(black, black), (black, grey_img), (grey_img, grey_img), (grey_img, grey_img * 0.5 - 0.5)]:
        x = a.clone().requires_grad_()
        y = b.clone().requires_grad_()
        loss = angle_loss(x, y, m)
        loss.backward()
        assert torch.isfinite(loss) and torch.isfinite(x.grad).all() and torch.isfinite(y.grad).all()
    # away from degenerate cases the gradient is the analytic one: d angle / d v for u = e_x, v = (1, t, 0)
    x = _rgb(1, 0, 0)
    y = _rgb(1, 0.5, 0).requires_grad_()
    angle_loss(x, y, _ones()).backward()
    # angle = atan(v_g / v_r); in [-1,1] space v = (y+1)/2, so dv/dy = 1/2
    torch.testing.assert_close(y.grad.flatten(), torch.tensor([-0.5 / 1.25, 1 / 1.25, 0.0]) * 0.5)


def test_view_consistency_dispatch():
    bi, bj, m = _rgb(1, 0, 0), _rgb(0, 1, 0), _ones()
    assert view_consistency("angle", bi, bj, m).item() == pytest.approx(math.pi / 2, abs=1e-6)
    assert view_consistency("l1", bi, bj, m).item() == pytest.approx(4 / 3)
    with pytest.raises(ValueError, match="vc_kind"):
        view_consistency("l2", bi, bj, m)


# ---------------------------------------------------------------- warp


def _pixel_centres(B, H, W):
    rows, cols = torch.meshgrid(torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32),
                                indexing="ij")
    return torch.stack((cols + 0.5, rows + 0.5), -1).expand(B, H, W, 2).clone()


def test_warp_integer_shift():
    torch.manual_seed(6)
    B, C, H, W = 2, 3, 5, 7
    img = torch.randn(B, C, H, W)
    dx, dy = 2, -1
    uv = _pixel_centres(B, H, W) + torch.tensor([dx, dy], dtype=torch.float32)
    warped, mask = warp_backward(img, uv, torch.ones(B, H, W, dtype=torch.bool))
    want = torch.zeros_like(img)
    want_mask = torch.zeros(B, H, W, dtype=torch.bool)
    for r in range(H):
        for c in range(W):
            if 0 <= r + dy < H and 0 <= c + dx < W:
                want[:, :, r, c] = img[:, :, r + dy, c + dx]
                want_mask[:, r, c] = True
    assert torch.equal(mask, want_mask)
    torch.testing.assert_close(warped, want, rtol=0, atol=1e-6)


def test_warp_half_pixel_is_bilinear_and_invalid_inputs_are_masked():
    img = torch.arange(12, dtype=torch.float32).view(1, 1, 3, 4)
    uv = torch.tensor([[[[1.0, 0.5], [2.0, 2.0], [float("nan"), 1.0], [2.5, 1.5], [-0.1, 1.0]]]])
    valid = torch.tensor([[[True, True, True, False, True]]])
    warped, mask = warp_backward(img, uv, valid)
    # (u=1, v=0.5): halfway between cols 0 and 1 on row 0 -> 0.5; (2, 2): mean of rows 1-2, cols 1-2
    torch.testing.assert_close(warped[0, 0, 0], torch.tensor([0.5, (5 + 6 + 9 + 10) / 4, 0.0, 0.0, 0.0]))
    assert mask.tolist() == [[[True, True, False, False, False]]]


def test_warp_gradient_reaches_source_pixels():
    img = torch.zeros(1, 1, 3, 4, requires_grad=True)
    uv = torch.tensor([[[[2.5, 1.5]]]])  # centre of pixel (col 2, row 1)
    warped, _ = warp_backward(img, uv, torch.ones(1, 1, 1, dtype=torch.bool))
    warped.sum().backward()
    expect = torch.zeros(1, 1, 3, 4)
    expect[0, 0, 1, 2] = 1
    torch.testing.assert_close(img.grad, expect)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_losses_match_cpu():
    torch.manual_seed(7)
    bi, bj = torch.rand(1, 3, 40, 40) * 2 - 1, torch.rand(1, 3, 40, 40) * 2 - 1
    m = torch.rand(1, 40, 40) > 0.3
    uv = _pixel_centres(1, 40, 40) + 0.3
    for f in (lambda *a: angle_loss(*a), lambda *a: masked_l1_loss(*a)):
        assert f(bi.cuda(), bj.cuda(), m.cuda()).item() == pytest.approx(f(bi, bj, m).item(), abs=1e-5)
    assert ms_ssim_loss(bi.cuda(), bj.cuda(), win=3).item() == pytest.approx(ms_ssim_loss(bi, bj, win=3).item(), abs=1e-4)
    w_gpu, _ = warp_backward(bj.cuda(), uv.cuda(), m.cuda())
    w_cpu, _ = warp_backward(bj, uv, m)
    torch.testing.assert_close(w_gpu.cpu(), w_cpu, rtol=1e-5, atol=1e-5)
