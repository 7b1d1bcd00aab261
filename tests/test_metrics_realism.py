"""Realism metrics: FID/KID against an independent NumPy/SciPy reference, Dice, proxy, U-Net."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import torch
from torch import nn

from sim2real.errors import UserError
from sim2real.metrics.inception import FID_WEIGHTS_ENV
from sim2real.metrics.realism import (
    clamp_kid_subset_size,
    dice,
    dice_per_image,
    fid_kid,
    fid_unavailable,
    fid_weights_status,
    proxy_colour_texture_distance,
)
from sim2real.metrics.segmenter import LiverUNet, predict, train_segmenter

D_IN = 3 * 6 * 6  # tiny 6x6 RGB images
D_FEAT = 8


class RandomProjection(nn.Module):
    """Fixed random linear map of the flattened image: a stand-in feature extractor."""

    def __init__(self, weight: np.ndarray) -> None:
        super().__init__()
        self.register_buffer("weight", torch.as_tensor(weight, dtype=torch.float32))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.flatten(1) @ self.weight.T


def _data(seed=0, n_real=60, n_gen=40):
    rng = np.random.default_rng(seed)
    w = rng.normal(size=(D_FEAT, D_IN)) / np.sqrt(D_IN)
    real = rng.random((n_real, 3, 6, 6))
    gen = np.clip(0.6 * rng.random((n_gen, 3, 6, 6)) + 0.3 * rng.random((n_gen, 1, 1, 1)), 0, 1)
    return w, real, gen


def _np_fid(f1: np.ndarray, f2: np.ndarray) -> float:
    mu1, mu2 = f1.mean(0), f2.mean(0)
    s1, s2 = np.cov(f1, rowvar=False), np.cov(f2, rowvar=False)
    covmean = scipy.linalg.sqrtm(s1 @ s2).real
    return float(((mu1 - mu2) ** 2).sum() + np.trace(s1 + s2 - 2.0 * covmean))


def _np_mmd2_unbiased(x: np.ndarray, y: np.ndarray) -> float:
    d = x.shape[1]
    k = lambda a, b: (a @ b.T / d + 1.0) ** 3  # noqa: E731
    m = x.shape[0]
    kxx, kyy, kxy = k(x, x), k(y, y), k(x, y)
    return float((kxx.sum() - np.trace(kxx) + kyy.sum() - np.trace(kyy)) / (m * (m - 1)) - 2.0 * kxy.mean())


def test_fid_matches_numpy_scipy_reference():
    w, real, gen = _data()
    module = RandomProjection(w)
    out = fid_kid(torch.tensor(gen, dtype=torch.float32), torch.tensor(real, dtype=torch.float32), module,
                  kid_subset_size=1000, kid_subsets=3, batch_size=7)
    f_real = real.reshape(len(real), -1) @ w.T
    f_gen = gen.reshape(len(gen), -1) @ w.T
    expected = _np_fid(f_real, f_gen)
    assert expected > 0.05  # the two sets really differ
    assert out["fid"] == pytest.approx(expected, rel=1e-3)
    assert out["n_real"] == 60 and out["n_gen"] == 40 and out["num_features"] == D_FEAT
    assert out["kid_subset_size"] == 40  # clamped from 1000 to the smaller set


def test_fid_of_a_set_with_itself_is_zero_and_batches_can_be_iterables():
    w, real, _ = _data(1)
    x = torch.tensor(real, dtype=torch.float32)
    out = fid_kid(iter([x[:25], x[25:]]), x, RandomProjection(w), kid_subset_size=10, kid_subsets=2)
    assert abs(out["fid"]) < 1e-3


def test_kid_equals_unbiased_mmd_when_subset_is_whole_set():
    # With n_real == n_gen == m every subset is the full set (a permutation), so KID is exact.
    w, real, gen = _data(2, n_real=12, n_gen=12)
    out = fid_kid(torch.tensor(gen, dtype=torch.float32), torch.tensor(real, dtype=torch.float32),
                  RandomProjection(w), kid_subset_size=1000, kid_subsets=4)
    f_real = real.reshape(12, -1) @ w.T
    f_gen = gen.reshape(12, -1) @ w.T
    assert out["kid_subset_size"] == 12
    assert out["kid_mean"] == pytest.approx(_np_mmd2_unbiased(f_real, f_gen), rel=1e-3, abs=1e-6)
    assert out["kid_std"] == pytest.approx(0.0, abs=1e-5)


def test_kid_subset_clamp_and_seeded_reproducibility():
    assert clamp_kid_subset_size(1000, 50, 30) == 30
    assert clamp_kid_subset_size(10, 50, 30) == 10
    with pytest.raises(ValueError):
        clamp_kid_subset_size(1000, 1, 30)
    with pytest.raises(ValueError):
        clamp_kid_subset_size(0, 10, 10)
    w, real, gen = _data(3, n_real=30, n_gen=30)
    args = (torch.tensor(gen, dtype=torch.float32), torch.tensor(real, dtype=torch.float32), RandomProjection(w))
    torch.manual_seed(123)
    before = torch.rand(1)
    a = fid_kid(*args, kid_subset_size=10, kid_subsets=5, seed=7)
    torch.manual_seed(123)
    torch.rand(1)
    b = fid_kid(*args, kid_subset_size=10, kid_subsets=5, seed=7)
    assert a["kid_mean"] == b["kid_mean"] and a["kid_std"] == b["kid_std"]
    assert a["kid_std"] > 0  # subsets really are random
    torch.manual_seed(123)
    assert torch.equal(torch.rand(1), before)  # the caller's RNG stream is untouched


def test_fid_kid_input_checks():
    w, real, gen = _data()
    m = RandomProjection(w)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        fid_kid(torch.tensor(gen, dtype=torch.float32) * 2 - 1, torch.tensor(real, dtype=torch.float32), m)
    with pytest.raises(ValueError, match="at least 2"):
        fid_kid(torch.tensor(gen[:1], dtype=torch.float32), torch.tensor(real, dtype=torch.float32), m)
    with pytest.raises(ValueError):
        fid_kid(torch.rand(4, 1, 6, 6), torch.rand(4, 1, 6, 6), m)


def test_weights_status_reports_absence_never_substitutes(monkeypatch, tmp_path):
    monkeypatch.delenv(FID_WEIGHTS_ENV, raising=False)
    st = fid_weights_status()
    assert st["available"] is False and FID_WEIGHTS_ENV in st["reason"]
    entry = fid_unavailable(st["reason"])
    assert entry["fid"] is None and entry["kid_mean"] is None and entry["reason"] == st["reason"]
    f = tmp_path / "w.pth"
    f.write_bytes(b"x")
    monkeypatch.setenv(FID_WEIGHTS_ENV, str(f))
    assert fid_weights_status() == {"available": True, "path": str(f)}
    with pytest.raises(UserError):
        fid_weights_status(tmp_path / "missing.pth")


def test_proxy_colour_texture_distance():
    rng = np.random.default_rng(0)
    x = torch.tensor(0.2 + 0.5 * rng.random((6, 3, 16, 16)), dtype=torch.float32)
    same = proxy_colour_texture_distance(x, x.clone())
    assert same["proxy_colour_texture_distance"] == pytest.approx(0.0, abs=1e-9)
    shifted = proxy_colour_texture_distance(x + 0.1, x)
    # every channel mean moves by 0.1, stds and gradients are unchanged
    assert shifted["proxy_colour_distance"] == pytest.approx(0.1, abs=1e-5)
    assert shifted["proxy_texture_distance"] == pytest.approx(0.0, abs=1e-9)
    flat = x.mean(dim=(2, 3), keepdim=True).expand_as(x).contiguous()
    d = proxy_colour_texture_distance(flat, x)
    assert d["proxy_grad_mean_gen"] == pytest.approx(0.0, abs=1e-7)
    assert d["proxy_texture_distance"] > 0.5  # all gradient mass in bin 0 vs spread out
    assert all(k.startswith("proxy_") for k in d)


def test_dice_hand_cases():
    p = np.array([[1, 1], [0, 0]])
    g = np.array([[1, 0], [0, 0]])
    assert dice_per_image(p, g) == pytest.approx([2 * 1 / (2 + 1)])
    empty = np.zeros((2, 2), bool)
    assert dice_per_image(empty, empty) == pytest.approx([1.0])  # empty/empty convention
    assert dice_per_image(empty, g) == pytest.approx([0.0])
    assert dice_per_image(g, empty) == pytest.approx([0.0])
    full = np.ones((2, 2), bool)
    batch_p = np.stack([p, empty, full]).astype(bool)
    batch_g = np.stack([g, empty, g]).astype(bool)
    per = dice_per_image(torch.from_numpy(batch_p), torch.from_numpy(batch_g))
    assert per == pytest.approx([2 / 3, 1.0, 2 * 1 / (4 + 1)])
    assert dice(batch_p, batch_g) == pytest.approx((2 / 3 + 1.0 + 0.4) / 3)
    with pytest.raises(ValueError):
        dice(p, np.zeros((3, 3)))
    with pytest.raises(ValueError):
        dice(np.full((2, 2), 0.5), g)


def _discs(n, seed, h=48, w=64):
    rng = np.random.default_rng(seed)
    rr, cc = np.mgrid[0:h, 0:w]
    imgs = np.zeros((n, 3, h, w), np.float32)
    labels = np.zeros((n, h, w), bool)
    for i in range(n):
        r0, c0, rad = rng.uniform(10, h - 10), rng.uniform(10, w - 10), rng.uniform(5, 14)
        m = (rr - r0) ** 2 + (cc - c0) ** 2 < rad ** 2
        labels[i] = m
        imgs[i, 0] = np.where(m, 0.8, 0.2)
        imgs[i, 1] = np.where(m, 0.2, 0.7)
        imgs[i, 2] = 0.3
    imgs = np.clip(imgs + 0.05 * rng.normal(size=imgs.shape), 0, 1).astype(np.float32)
    return torch.from_numpy(imgs), torch.from_numpy(labels)


def test_unet_learns_separable_segmentation_quickly():
    x, y = _discs(24, 0)
    xt, yt = _discs(8, 1, h=50, w=70)  # other size: the net pads to a multiple of 4 and crops back
    # 40 Adam steps of batch 4 at 48x64: about 1.5 s on 2 idle CPU cores
    model = train_segmenter(x, y, iterations=40, device="cpu", seed=0, batch_size=4)
    pred = predict(model, xt)
    assert pred.shape == yt.shape and pred.dtype == torch.bool
    assert dice(pred, yt) > 0.9
    untrained = predict(LiverUNet(), xt)
    assert untrained.shape == yt.shape
