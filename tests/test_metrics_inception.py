"""FID Inception-v3: architecture, pytorch-fid key names, strict loading, torchmetrics use."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from sim2real.errors import UserError
from sim2real.metrics.inception import FID_WEIGHTS_ENV, FIDInceptionV3, _avg3, load_fid_inception, resolve_fid_weights


def _randomised_net(seed: int) -> FIDInceptionV3:
    """A net whose activations stay O(1) (He init) and whose BN statistics are not the identity."""
    g = torch.Generator().manual_seed(seed)
    net = FIDInceptionV3()
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, nn.Conv2d):
                fan_in = m.weight[0].numel()
                m.weight.copy_(torch.randn(m.weight.shape, generator=g) * (2.0 / fan_in) ** 0.5)
            elif isinstance(m, nn.BatchNorm2d):
                n = m.num_features
                m.weight.copy_(1.0 + 0.1 * torch.randn(n, generator=g))
                m.bias.copy_(0.1 * torch.randn(n, generator=g))
                m.running_mean.copy_(0.1 * torch.randn(n, generator=g))
                m.running_var.copy_(1.0 + 0.5 * torch.rand(n, generator=g))
            elif isinstance(m, nn.Linear):
                m.weight.copy_(0.01 * torch.randn(m.weight.shape, generator=g))
                m.bias.copy_(0.01 * torch.randn(m.bias.shape, generator=g))
    return net


@pytest.fixture(scope="module")
def net_and_file(tmp_path_factory):
    net = _randomised_net(0)
    path = tmp_path_factory.mktemp("w") / "pt_inception-2015-12-05-6726825d.pth"
    torch.save(net.state_dict(), path)
    return net, path


def test_architecture_matches_pytorch_fid_naming_and_size():
    net = FIDInceptionV3()
    sd = net.state_dict()
    # torchvision Inception-v3: 27,161,264 parameters with AuxLogits (3,326,696) and a 1000-way fc;
    # the FID variant has no AuxLogits and a 1008-way fc (+16,392): 23,850,960.
    assert sum(p.numel() for p in net.parameters()) == 27_161_264 - 3_326_696 + 8 * 2048 + 8
    # 94 conv+BN units x (conv.weight + 5 BN tensors) + fc weight/bias
    assert len(sd) == 94 * 6 + 2
    expected_shapes = {
        "Conv2d_1a_3x3.conv.weight": (32, 3, 3, 3),
        "Conv2d_1a_3x3.bn.running_var": (32,),
        "Conv2d_4a_3x3.conv.weight": (192, 80, 3, 3),
        "Mixed_5b.branch1x1.conv.weight": (64, 192, 1, 1),
        "Mixed_5b.branch_pool.conv.weight": (32, 192, 1, 1),
        "Mixed_5d.branch5x5_2.conv.weight": (64, 48, 5, 5),
        "Mixed_6a.branch3x3.conv.weight": (384, 288, 3, 3),
        "Mixed_6b.branch7x7_2.conv.weight": (128, 128, 1, 7),
        "Mixed_6e.branch7x7dbl_5.conv.weight": (192, 192, 1, 7),
        "Mixed_7a.branch7x7x3_4.conv.weight": (192, 192, 3, 3),
        "Mixed_7b.branch3x3dbl_3b.conv.weight": (384, 384, 3, 1),
        "Mixed_7c.branch_pool.conv.weight": (192, 2048, 1, 1),
        "fc.weight": (1008, 2048),
        "fc.bias": (1008,),
    }
    for key, shape in expected_shapes.items():
        assert tuple(sd[key].shape) == shape, key
    assert not any(k.startswith("AuxLogits") for k in sd)
    assert all(m.eps == 1e-3 for m in net.modules() if isinstance(m, nn.BatchNorm2d))


def test_avg_pool_ignores_padding_like_tensorflow():
    x = torch.ones(1, 1, 4, 4)
    assert torch.allclose(_avg3(x), x)  # zero padding counted would give 4/9 in the corners
    x = torch.arange(16.0).reshape(1, 1, 4, 4)
    assert _avg3(x)[0, 0, 0, 0].item() == pytest.approx((0 + 1 + 4 + 5) / 4)


def test_strict_roundtrip_identical_outputs_and_feature_sizes(net_and_file):
    net, path = net_and_file
    loaded = load_fid_inception(path)
    assert isinstance(loaded, FIDInceptionV3)
    assert all(not p.requires_grad for p in loaded.parameters())
    sizes = {}
    for name in ("Mixed_5d", "Mixed_6e", "Mixed_7c"):
        getattr(loaded, name).register_forward_hook(lambda m, i, o, name=name: sizes.__setitem__(name, tuple(o.shape[1:])))
    torch.manual_seed(1)
    x = torch.rand(2, 3, 299, 299)
    with torch.no_grad():
        ref = net(x)
        out = loaded(x)
    assert out.shape == (2, 2048)
    assert torch.isfinite(out).all() and out.abs().mean() > 1e-3
    assert torch.equal(out, ref)
    assert sizes == {"Mixed_5d": (288, 35, 35), "Mixed_6e": (768, 17, 17), "Mixed_7c": (2048, 8, 8)}
    assert not torch.allclose(out[0], out[1])  # features depend on the image


def test_loader_tolerates_missing_bn_counters_only(net_and_file, tmp_path):
    net, _ = net_and_file
    sd = {k: v for k, v in net.state_dict().items() if not k.endswith("num_batches_tracked")}
    p = tmp_path / "no_counters.pth"
    torch.save(sd, p)
    x = torch.rand(1, 3, 64, 64)
    with torch.no_grad():
        assert torch.equal(load_fid_inception(p)(x), net(x))
    # everything else is strict: one unexpected key (torchvision's aux classifier) ...
    sd["AuxLogits.fc.weight"] = torch.zeros(1)
    torch.save(sd, tmp_path / "extra.pth")
    del sd
    with pytest.raises(UserError, match="AuxLogits"):
        load_fid_inception(tmp_path / "extra.pth")
    # ... or missing ones
    torch.save({"Conv2d_1a_3x3.conv.weight": torch.zeros(32, 3, 3, 3)}, tmp_path / "partial.pth")
    with pytest.raises(UserError) as e:
        load_fid_inception(tmp_path / "partial.pth")
    n = sum(not k.endswith("num_batches_tracked") for k in net.state_dict()) - 1  # the counters are filled in
    assert str(e.value) == (f"{tmp_path / 'partial.pth'} is not an FID Inception-v3 state dict (missing "
                            f"Conv2d_1a_3x3.bn.weight, Conv2d_1a_3x3.bn.bias, Conv2d_1a_3x3.bn.running_mean, ... "
                            f"({n} in all))")
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(UserError, match="cannot read"):
        load_fid_inception(tmp_path / "junk.pth")


def test_weights_path_resolution(monkeypatch, net_and_file, tmp_path):
    _, path = net_and_file
    monkeypatch.delenv(FID_WEIGHTS_ENV, raising=False)
    assert resolve_fid_weights(None) is None
    assert load_fid_inception(None) is None
    monkeypatch.setenv(FID_WEIGHTS_ENV, str(path))
    assert resolve_fid_weights(None) == path
    assert resolve_fid_weights(str(path)) == path
    with pytest.raises(UserError, match="not found"):
        resolve_fid_weights(tmp_path / "absent.pth")  # argument wins over the environment
    monkeypatch.setenv(FID_WEIGHTS_ENV, str(tmp_path / "absent.pth"))
    with pytest.raises(UserError, match="SIM2REAL_FID_WEIGHTS"):
        resolve_fid_weights(None)


def test_input_conventions(net_and_file):
    net, _ = net_and_file
    net.train()
    assert not net.training  # always eval: batch norm uses the stored statistics
    u8 = torch.randint(0, 256, (1, 3, 40, 56), dtype=torch.uint8)
    with torch.no_grad():
        a = net(u8)
        b = net(u8.float() / 255.0)
    assert torch.allclose(a, b, atol=1e-6)
    x = torch.rand(1, 3, 299, 299)
    assert torch.equal(net.preprocess(x), 2 * x - 1)  # 299 input: no resampling
    with pytest.raises(ValueError):
        net(torch.rand(1, 4, 32, 32))
    with pytest.raises(TypeError):
        net(torch.zeros(1, 3, 32, 32, dtype=torch.int32))


def test_usable_as_torchmetrics_feature_module(net_and_file):
    from torchmetrics.image.fid import FrechetInceptionDistance

    net, _ = net_and_file
    calls = []
    hook = net.register_forward_hook(lambda m, i, o: calls.append(o.shape))
    try:
        fid = FrechetInceptionDistance(feature=net, normalize=True)
        assert calls == []  # num_features is an attribute: no dummy forward pass
        torch.manual_seed(2)
        x = torch.rand(2, 3, 32, 32)
        with torch.no_grad():
            expected = net(x).double()
        fid.update(x, real=False)
        assert fid.fake_features_sum.shape == (2048,)
        assert torch.allclose(fid.fake_features_sum, expected.sum(0))
        assert torch.allclose(fid.fake_features_cov_sum, expected.T @ expected)
        # normalize=False: torchmetrics hands uint8 images through unchanged; the module scales them
        fid_u8 = FrechetInceptionDistance(feature=net, normalize=False)
        fid_u8.update(torch.randint(0, 256, (1, 3, 32, 32), dtype=torch.uint8), real=True)
        assert fid_u8.real_features_num_samples == 1
        # (compute() on 2048-d features costs seconds on CPU; the FID/KID arithmetic is tested in
        # test_metrics_realism.py with a small feature module)
    finally:
        hook.remove()
