"""Translator (MUNIT without styles) and multi-scale discriminator: shapes, sizes, init, layer norm."""

import math

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from sim2real.config import DiscriminatorConfig, GeneratorConfig, TrainConfig
from sim2real.models import MsImageDis, Translator
from sim2real.models.layers import LayerNorm, UpConv2dBlock
from sim2real.presets import preset


def _tiny(content_channels):
    return GeneratorConfig(filters=4, downsamplings=2, res_blocks=1, content_channels=content_channels)


@pytest.mark.parametrize("cc", [0, 8])
def test_translator_shapes_and_range(cc):
    torch.manual_seed(0)
    tr = Translator(3, _tiny(cc))
    x_a = torch.rand(2, 6, 16, 24) * 2 - 1
    x_b = torch.rand(2, 3, 16, 24) * 2 - 1
    b_hat, c_a = tr.a_to_b(x_a)
    a_hat, c_b = tr.b_to_a(x_b)
    width = cc if cc else 4 * 4
    assert c_a.shape == c_b.shape == (2, width, 4, 6)
    assert b_hat.shape == (2, 3, 16, 24) and a_hat.shape == (2, 6, 16, 24)
    for y in (b_hat, a_hat):
        assert y.abs().max() <= 1 and y.std() > 0
    if cc:
        assert (c_a >= 0).all()  # the release's content squeeze ends with a ReLU
    tex, ref = tr.split_a(a_hat)
    assert tex.shape[1] == 3 and ref.shape[1] == 3
    assert torch.equal(tr.join_a(tex, ref), a_hat)


def test_texture_features_set_domain_a_channels():
    tr = Translator(5, _tiny(8))
    assert tr.enc_a.model[0].conv.in_channels == 8
    a_hat, _ = tr.b_to_a(torch.zeros(1, 3, 8, 8))
    assert a_hat.shape == (1, 8, 8, 8)


def _conv(cin, cout, k):
    return cin * cout * k * k + cout


def test_paper_generator_widths_and_parameter_count():
    cfg = preset("paper")
    tr = Translator(3, cfg.generator)
    convs = [m for m in tr.enc_a.modules() if isinstance(m, nn.Conv2d)]
    widths = [(c.in_channels, c.out_channels, c.kernel_size[0], c.stride[0]) for c in convs]
    assert widths[:3] == [(6, 64, 7, 1), (64, 128, 4, 2), (128, 256, 4, 2)]
    assert widths[3:11] == [(256, 256, 3, 1)] * 8
    assert widths[11:] == [(256, 8, 3, 1)]
    # hand count: encoder A, decoder A (6 out), encoder B, decoder B (3 out); LN: gamma + beta
    res = 8 * _conv(256, 256, 3)
    enc = lambda cin: _conv(cin, 64, 7) + _conv(64, 128, 4) + _conv(128, 256, 4) + res + _conv(256, 8, 3)
    dec = lambda cout: (_conv(8, 256, 3) + res + _conv(256, 128, 5) + 2 * 128 + _conv(128, 64, 5) + 2 * 64
                        + _conv(64, cout, 7))
    want = enc(6) + dec(6) + enc(3) + dec(3)
    assert sum(p.numel() for p in tr.parameters()) == want
    assert 20e6 < want < 25e6  # four halves (two encoders, two decoders) of ~5.6 M each


@pytest.mark.parametrize("h,w", [(64, 96), (50, 70)])
def test_discriminator_scales_and_sizes(h, w):
    cfg = DiscriminatorConfig(filters=4, layers=3, scales=3)
    dis = MsImageDis(6, cfg)
    outs = dis(torch.randn(2, 6, h, w))
    assert len(outs) == 3
    sizes = []
    for _ in range(3):
        sizes.append((h // 8, w // 8))  # three conv4 s2 p1 layers: floor halving each
        h, w = math.ceil(h / 2), math.ceil(w / 2)  # avgpool 3, s2, p1
    assert [tuple(o.shape) for o in outs] == [(2, 1, a, b) for a, b in sizes]


@pytest.mark.parametrize("scales,layers,pad", [(3, 4, "reflect"), (2, 4, "reflect"), (2, 2, "zero"), (1, 3, "reflect"),
                                               (3, 1, "replicate")])
def test_discriminator_min_input_side_is_the_smallest_that_runs(scales, layers, pad):
    """The formula against torch itself: the side it names runs, one pixel less does not."""
    from sim2real.models.discriminator import min_input_side

    cfg = DiscriminatorConfig(filters=2, layers=layers, scales=scales, pad_type=pad)
    side = min_input_side(cfg)
    dis = MsImageDis(3, cfg)
    outs = dis(torch.randn(1, 3, side, side + 7))
    assert min(o.shape[-2] for o in outs) == 1  # the coarsest scale is down to one row
    with pytest.raises(RuntimeError):
        dis(torch.randn(1, 3, side - 1, side + 7))


@pytest.mark.parametrize("d,pad", [(2, "reflect"), (3, "reflect"), (0, "reflect"), (2, "zero")])
def test_generator_min_input_side_is_the_smallest_that_runs(d, pad):
    from sim2real.models.translator import min_input_side

    cfg = GeneratorConfig(filters=2, downsamplings=d, res_blocks=1, pad_type=pad)
    side = min_input_side(cfg)
    assert side % 2**d == 0
    tr = Translator(3, cfg)
    b_hat, _ = tr.a_to_b(torch.randn(1, 6, side, 2 * side))
    assert b_hat.shape == (1, 3, side, 2 * side)
    smaller = side - 2**d  # the next size the multiple-of-2^d rule admits
    if smaller >= 1:
        with pytest.raises(RuntimeError):
            tr.a_to_b(torch.randn(1, 6, smaller, 2 * side))


def test_discriminator_first_scale_sees_full_resolution_input():
    """Scale 0 is applied to the input itself, scale 1 to its 3x3/s2 average pool."""
    dis = MsImageDis(3, DiscriminatorConfig(filters=4, layers=2, scales=2))
    x = torch.randn(1, 3, 16, 16)
    outs = dis(x)
    torch.testing.assert_close(outs[0], dis.cnns[0](x))
    pooled = nn.functional.avg_pool2d(x, 3, 2, 1, count_include_pad=False)
    torch.testing.assert_close(outs[1], dis.cnns[1](pooled))


def build_models(cfg: TrainConfig):
    """The translator and D_A, D_B of ``cfg``'s ``ours`` section, as the method builds them."""
    n = cfg.method.texture.features
    return Translator(n, cfg.generator), MsImageDis(n + 3, cfg.discriminator), MsImageDis(3, cfg.discriminator)


def test_initialisation_follows_release():
    torch.manual_seed(0)
    translator, dis_a, dis_b = build_models(preset("paper"))
    conv = translator.enc_a.model[3].body[0].conv  # 256 -> 256, 3x3
    assert abs(conv.weight.std().item() - math.sqrt(2 / (256 * 9))) < 0.02 * math.sqrt(2 / (256 * 9))
    assert conv.bias.abs().max() == 0
    dconv = dis_b.cnns[0][2].conv  # 128 -> 256, 4x4
    assert abs(dconv.weight.std().item() - 0.02) < 0.001 and abs(dconv.weight.mean().item()) < 0.001
    assert dis_a.cnns[0][0].conv.in_channels == preset("paper").method.texture.features + 3
    assert len(dis_a.cnns) == 3


def test_munit_layer_norm_formula():
    torch.manual_seed(0)
    ln = LayerNorm(3)
    with torch.no_grad():
        ln.gamma.copy_(torch.tensor([1.0, 2.0, 0.5]))
        ln.beta.copy_(torch.tensor([0.0, -1.0, 3.0]))
    x = torch.randn(2, 3, 4, 5, dtype=torch.float64)
    y = ln.double()(x)
    for b in range(2):
        v = x[b].flatten()
        mean, std = v.mean(), math.sqrt(((v - v.mean()) ** 2).sum().item() / (v.numel() - 1))
        for c, (g, be) in enumerate([(1.0, 0.0), (2.0, -1.0), (0.5, 3.0)]):
            torch.testing.assert_close(y[b, c], (x[b, c] - mean) / (std + 1e-5) * g + be)


def test_unknown_norm_or_padding_is_rejected():
    with pytest.raises(ValueError, match="norm"):
        Translator(3, GeneratorConfig(filters=4, res_blocks=1, upsample_norm="bn"))
    with pytest.raises(ValueError, match="pad_type"):
        Translator(3, GeneratorConfig(filters=4, res_blocks=1, pad_type="circular"))


def _upsample_then_conv(x, weight, bias, pad_type):
    """MUNIT's up-step written out: nearest x2, pad the upsampled image, convolve."""
    u = F.interpolate(x, scale_factor=2, mode="nearest")
    p = weight.shape[-1] // 2
    mode = {"reflect": "reflect", "replicate": "replicate", "zero": "constant"}[pad_type]
    return F.conv2d(F.pad(u, (p, p, p, p), mode=mode), weight, bias)


@pytest.mark.parametrize("pad_type", ["reflect", "replicate", "zero"])
@pytest.mark.parametrize("kernel", [3, 5, 7])
@pytest.mark.parametrize("hw", [(5, 7), (9, 4), (2, 3)])
def test_subpixel_up_step_equals_upsample_then_conv(pad_type, kernel, hw):
    """Values and gradients (input, weight, bias) of the sub-pixel form equal the direct form
    in float64, at every border, for odd sizes and for inputs too small for the sub-pixel form."""
    torch.manual_seed(kernel)
    layer = UpConv2dBlock(4, 3, kernel, norm="none", activation="none", pad_type=pad_type).double()
    layer.subpixel = True
    x = torch.randn(2, 4, *hw, dtype=torch.float64, requires_grad=True)
    w_out = torch.randn(2, 3, 2 * hw[0], 2 * hw[1], dtype=torch.float64)
    conv = layer.block.conv
    got = layer(x)
    g_got = torch.autograd.grad((got * w_out).sum(), (x, conv.weight, conv.bias))
    want = _upsample_then_conv(x, conv.weight, conv.bias, pad_type)
    g_want = torch.autograd.grad((want * w_out).sum(), (x, conv.weight, conv.bias))
    assert got.shape == want.shape == w_out.shape
    torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
    for a, b in zip(g_got, g_want):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)


def test_subpixel_up_step_compiles(tmp_path, monkeypatch):
    """TorchInductor compiles the sub-pixel form (``translate --compile``) to the eager values.
    Its per-phase bias is a tensor of its own: inductor 2.11 could not lower a convolution whose
    bias was a view (``repeat_interleave``)."""
    import torch._dynamo

    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path / "inductor"))
    torch._dynamo.reset()
    torch.manual_seed(0)
    layer = UpConv2dBlock(8, 4, 5, norm="none", activation="relu", pad_type="reflect").eval()
    layer.subpixel = True
    x = torch.randn(2, 8, 8, 12)
    with torch.inference_mode():
        want = layer(x)
        got = torch.compile(layer)(x)
    torch._dynamo.reset()
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)


def test_decoder_up_step_is_the_release_layer_sequence():
    """Same state dict into MUNIT's [Upsample, Conv2dBlock(k5, LN, ReLU)]: same output, in both forms."""
    from sim2real.models.layers import Conv2dBlock

    torch.manual_seed(0)
    layer = UpConv2dBlock(64, 32, 5, norm="ln", activation="relu", pad_type="reflect")
    release = nn.Sequential(nn.Upsample(scale_factor=2, mode="nearest"),
                            Conv2dBlock(64, 32, 5, 1, 2, norm="ln", activation="relu", pad_type="reflect"))
    release[1].load_state_dict(layer.block.state_dict())
    x = torch.randn(1, 64, 32, 64)  # 64 * 32 * 64 = 2^17 input values: the automatic rule picks sub-pixel
    want = release(x)
    for form in (None, True, False):
        layer.subpixel = form
        torch.testing.assert_close(layer(x), want, rtol=1e-4, atol=1e-4)


def test_tiny_preset_models_build_and_run():
    cfg = preset("tiny")
    translator, _, dis_b = build_models(cfg)
    x_a = torch.rand(1, cfg.method.texture.features + 3, cfg.data.height, cfg.data.width) * 2 - 1
    b_hat, _ = translator.a_to_b(x_a)
    outs = dis_b(b_hat)
    assert len(outs) == cfg.discriminator.scales
    assert isinstance(cfg, TrainConfig)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_forward_backward():
    translator, _, dis_b = build_models(preset("tiny"))
    tr, dis = translator.cuda(), dis_b.cuda()
    x = torch.rand(1, 6, 32, 64, device="cuda") * 2 - 1
    with torch.autocast("cuda", dtype=torch.bfloat16):
        b_hat, _ = tr.a_to_b(x)
        loss = sum(o.float().square().mean() for o in dis(b_hat))
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in tr.enc_a.parameters() if p.grad is not None)
