"""Triplanar neural texture projection against a naive per-pixel transcription of the paper."""

import math

import numpy as np
import pytest
import torch

from sim2real.config import TextureConfig
from sim2real.texture import NeuralTexture

S = 8


def _scene(seed=0, B=2, H=5, W=7, O=2):
    g = torch.Generator().manual_seed(seed)
    lo = torch.rand(O, 3, generator=g, dtype=torch.float64) * 10 - 5
    hi = lo + 5 + torch.rand(O, 3, generator=g, dtype=torch.float64) * 20
    oid = torch.randint(-1, O, (B, H, W), generator=g)
    oc = oid.clamp_min(0)
    pts = lo[oc] + torch.rand(B, H, W, 3, generator=g, dtype=torch.float64) * (hi - lo)[oc]
    n = torch.randn(B, H, W, 3, generator=g, dtype=torch.float64)
    n = n / n.norm(dim=-1, keepdim=True)
    boxes = torch.stack([lo, hi], 1).float().double()  # the module stores boxes as float32
    return boxes, oid, pts, n


def _texture(boxes, mapping="box", seed=1, N=3):
    tex = NeuralTexture(len(boxes), boxes, cfg=TextureConfig(size=S, features=N, mapping=mapping)).double()
    with torch.no_grad():
        tex.texture.copy_(torch.randn(tex.texture.shape, generator=torch.Generator().manual_seed(seed)))
    return tex


def _naive(T, boxes, oid, pts, n, mapping="box", texel=False):
    """Direct transcription of the supplementary: tri(s), w = (n_s . n_p)^2, floor/ceil bilinear.
    Returns the output and the set of (o, p, x, y) texels with nonzero total weight. ``texel``:
    the release's order, tanh of every texel and no tanh after the interpolation."""
    T = T.detach().numpy()
    T_in = np.tanh(T) if texel else T
    B, H, W = oid.shape
    out = np.zeros((B, T.shape[-1], H, W))
    used = set()
    plane_normals = [np.eye(3)[k // 2] * (1 if k % 2 == 0 else -1) for k in range(6)]
    axes_of_plane = {0: (1, 2), 1: (0, 2), 2: (0, 1)}
    for b in range(B):
        for r in range(H):
            for col in range(W):
                o = int(oid[b, r, col])
                if o < 0:
                    continue
                s = pts[b, r, col].numpy()
                ns = n[b, r, col].numpy()
                lo, hi = boxes[o, 0].numpy(), boxes[o, 1].numpy()
                acc = np.zeros(T.shape[-1])
                for p in range(6):
                    d = float(ns @ plane_normals[p])
                    if d <= 0:
                        continue
                    w = d * d
                    ua, va = axes_of_plane[p // 2]
                    coords = []
                    for ax in (ua, va):
                        if mapping == "box":
                            c = (s[ax] - lo[ax]) / (hi[ax] - lo[ax])
                        else:
                            L = max(hi - lo)
                            c = (s[ax] - (lo[ax] + hi[ax]) / 2) / L + 0.5
                        coords.append(min(max(c * (S - 1), 0.0), S - 1))
                    xp, yp = coords
                    fx, cx, fy, cy = math.floor(xp), math.ceil(xp), math.floor(yp), math.ceil(yp)
                    dx, dy = xp - fx, yp - fy
                    terms = [
                        ((1 - dx) * (1 - dy), fx, fy),
                        ((1 - dx) * dy, fx, cy),
                        (dx * (1 - dy), cx, fy),
                        (dx * dy, cx, cy),
                    ]
                    for wb, i, j in terms:
                        acc += w * wb * T_in[o, p, i, j]
                        if w * wb != 0:
                            used.add((o, p, i, j))
                out[b, :, r, col] = acc if texel else np.tanh(acc)
    return torch.from_numpy(out), used


@pytest.mark.parametrize("mapping", ["box", "cube"])
def test_projection_matches_naive_paper_formula(mapping):
    boxes, oid, pts, n = _scene()
    tex = _texture(boxes, mapping)
    got = tex(oid, pts, n)
    want, _ = _naive(tex.texture, boxes, oid, pts, n, mapping)
    assert got.shape == (2, 3, 5, 7)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)


def test_tanh_per_texel_matches_the_releases_order():
    boxes, oid, pts, n = _scene(seed=5)
    tex = _texture(boxes)
    texel = NeuralTexture(len(boxes), boxes, cfg=TextureConfig(size=S, features=3, tanh="texel")).double()
    texel.load_state_dict(tex.state_dict())
    want, _ = _naive(tex.texture, boxes, oid, pts, n, texel=True)
    torch.testing.assert_close(texel(oid, pts, n), want, rtol=0, atol=1e-12)
    assert not torch.allclose(texel(oid, pts, n), tex(oid, pts, n))  # a different function of the texture


def test_init_noise_is_band_limited_with_the_given_std():
    boxes = torch.tensor([[[0.0, 0, 0], [10, 10, 10]]], dtype=torch.float64)
    cfg = TextureConfig(size=64, features=2, init_noise=0.5, init_noise_sigma=1.5)
    torch.manual_seed(0)
    tex = NeuralTexture(1, boxes, [[0.3, 0.6, 0.9]], cfg)
    flat = NeuralTexture(1, boxes, [[0.3, 0.6, 0.9]], TextureConfig(size=64, features=2))
    d = (tex.texture - flat.texture).detach().double()
    assert d.std().item() == pytest.approx(0.5, rel=1e-3) and abs(d.mean().item()) < 0.05
    # Gaussian-blurred white noise: lag-1 correlation exp(-1 / (4 sigma^2)) = 0.895 at sigma 1.5,
    # along both texel axes (white noise: 0)
    for a, b in ((d[..., 1:, :, :], d[..., :-1, :, :]), (d[..., :, 1:, :], d[..., :, :-1, :])):
        r = torch.corrcoef(torch.stack([a.flatten(), b.flatten()]))[0, 1].item()
        assert r == pytest.approx(math.exp(-1 / 9), abs=0.03)


def test_init_noise_lines_darken_every_feature_alike_along_thin_curves():
    from sim2real.texture.neural_texture import LINE_WIDTH

    boxes = torch.tensor([[[0.0, 0, 0], [10, 10, 10]]], dtype=torch.float64)
    cfg = TextureConfig(size=64, features=3, init_lines=0.8, init_lines_sigma=3)
    torch.manual_seed(0)
    tex = NeuralTexture(1, boxes, [[0.3, 0.6, 0.9]], cfg)
    flat = NeuralTexture(1, boxes, [[0.3, 0.6, 0.9]], TextureConfig(size=64, features=3))
    d = (tex.texture - flat.texture).detach().double()
    # one field per plane, shared by the features: the same darkening in every channel
    # (up to float32 rounding of the sum with each channel's own flat value)
    for c in (1, 2):
        torch.testing.assert_close(d[..., c], d[..., 0], rtol=0, atol=1e-6)
    # -0.8 exp(-n^2 / (2 w^2)) of a unit normal n: in [-0.8, 0], reaching -0.8 near the zero crossings
    assert d.max().item() <= 1e-6 and d.min().item() >= -0.8 - 1e-6 and d.min().item() < -0.79
    # darker than half the amplitude where |n| < w sqrt(2 ln 2): P = erf(w sqrt(ln 2)) = 0.112 at w 0.12
    share = (d[..., 0] < -0.4).double().mean().item()
    assert share == pytest.approx(math.erf(LINE_WIDTH * math.sqrt(math.log(2))), abs=0.02)
    with pytest.raises(ValueError, match="blobs"):
        tex.add_noise(1.0, 2.0, shape="dots")
    # on top of the noise: the blobs' draws come first, then the lines' (one seed, both shapes)
    torch.manual_seed(0)
    both = NeuralTexture(1, boxes, [[0.3, 0.6, 0.9]], TextureConfig(size=64, features=3, init_noise=0.5,
                                                                    init_lines=0.8, init_lines_sigma=3))
    torch.manual_seed(0)
    blobs = NeuralTexture(1, boxes, [[0.3, 0.6, 0.9]], TextureConfig(size=64, features=3, init_noise=0.5))
    lines = (both.texture - blobs.texture).detach().double()
    assert lines.max().item() <= 1e-6 and lines.min().item() < -0.79
    for c in (1, 2):
        torch.testing.assert_close(lines[..., c], lines[..., 0], rtol=0, atol=1e-6)


def test_background_is_zero_and_garbage_there_is_ignored():
    boxes, oid, pts, n = _scene(seed=3)
    bg = oid < 0
    assert bg.any() and (~bg).any()
    pts, n = pts.clone(), n.clone()
    pts[bg] = float("nan")
    n[bg] = float("nan")
    out = _texture(boxes)(oid, pts, n)
    assert torch.isfinite(out).all()
    assert (out.permute(0, 2, 3, 1)[bg] == 0).all()
    assert (out.permute(0, 2, 3, 1)[~bg].abs() > 0).all()


def test_weights_sum_to_one_constant_texture_gives_its_value():
    boxes, oid, pts, n = _scene(seed=4)
    tex = _texture(boxes)
    with torch.no_grad():
        tex.texture.fill_(math.atanh(0.3))
    out = tex(oid, pts, n).permute(0, 2, 3, 1)
    torch.testing.assert_close(out[oid >= 0], torch.full_like(out[oid >= 0], 0.3), rtol=0, atol=1e-12)


def test_colour_init_reproduces_flat_colours_per_object():
    boxes, oid, pts, n = _scene(seed=5)
    colours = np.array([[0.8, 0.2, 0.1], [0.5, 0.999999, 0.0]])
    tex = NeuralTexture.from_colours(boxes, colours, TextureConfig(size=S, features=3)).double()
    out = tex(oid, pts, n).permute(0, 2, 3, 1)
    want = torch.from_numpy(np.clip(2 * colours - 1, -0.99, 0.99))[oid.clamp_min(0)]
    torch.testing.assert_close(out[oid >= 0], want[oid >= 0], rtol=0, atol=1e-6)
    assert torch.isfinite(tex.texture).all()


def test_colours_repeat_cyclically_for_more_features():
    boxes, oid, pts, n = _scene(seed=5)
    tex = NeuralTexture(2, boxes, [[0.75, 0.25], [0.5, 1.0]], TextureConfig(size=4, features=5))
    torch.testing.assert_close(torch.tanh(tex.texture[0, 3, 1, 2]), torch.tensor([0.5, -0.5, 0.5, -0.5, 0.5]))
    torch.testing.assert_close(torch.tanh(tex.texture[1, 0, 0, 0]), torch.tensor([0.0, 0.99, 0.0, 0.99, 0.0]))


def test_gradient_reaches_exactly_the_sampled_texels():
    boxes, oid, pts, n = _scene(seed=6)
    tex = _texture(boxes)
    out = tex(oid, pts, n)
    upstream = torch.rand(out.shape, generator=torch.Generator().manual_seed(7), dtype=torch.float64) + 0.5
    (out * upstream).sum().backward()
    grad = tex.texture.grad
    _, used = _naive(tex.texture, boxes, oid, pts, n)
    got = {tuple(i) for i in (grad.abs().sum(-1) != 0).nonzero().tolist()}
    assert len(used) > 20
    assert got == used
    assert (grad[grad.abs().sum(-1) != 0] != 0).all()  # every feature channel of a used texel


@pytest.mark.parametrize(
    "normal,plane,axes",
    [((1, 0, 0), 0, (1, 2)), ((-1, 0, 0), 1, (1, 2)), ((0, 1, 0), 2, (0, 2)), ((0, -1, 0), 3, (0, 2)),
     ((0, 0, 1), 4, (0, 1)), ((0, 0, -1), 5, (0, 1))],
)
def test_plane_selection_and_texel_coordinates(normal, plane, axes):
    """A linear ramp texture (value = 0.1 x_p in feature 0, 0.1 y_p in feature 1) is reproduced
    exactly by bilinear interpolation, so atanh(output) reads the texel coordinates back."""
    boxes = torch.tensor([[[0.0, 10.0, -4.0], [20.0, 14.0, 36.0]]], dtype=torch.float64)
    tex = NeuralTexture(1, boxes, cfg=TextureConfig(size=S, features=2)).double()
    ramp = torch.arange(S, dtype=torch.float64) * 0.1
    with torch.no_grad():
        tex.texture[0, plane, :, :, 0] = ramp[:, None]
        tex.texture[0, plane, :, :, 1] = ramp[None, :]
    s = torch.tensor([[5.0, 13.0, 26.0], [20.0, 10.0, -4.0], [30.0, 9.0, 0.0]], dtype=torch.float64)
    pts = s.view(1, 1, 3, 3)
    nrm = torch.tensor(normal, dtype=torch.float64).expand(1, 1, 3, 3)
    out = tex(torch.zeros(1, 1, 3, dtype=torch.long), pts, nrm)
    lo, ext = boxes[0, 0], boxes[0, 1] - boxes[0, 0]
    want = ((s - lo) / ext * (S - 1)).clamp(0, S - 1)[:, list(axes)] * 0.1  # (3 points, 2)
    torch.testing.assert_close(torch.atanh(out[0, :, 0]).T, want, rtol=0, atol=1e-12)


def test_cube_mapping_has_square_texels():
    """Moving 1 mm along either in-plane axis moves the same number of texels, (S-1)/L."""
    boxes = torch.tensor([[[0.0, 0.0, 0.0], [10.0, 40.0, 20.0]]], dtype=torch.float64)
    tex = NeuralTexture(1, boxes, cfg=TextureConfig(size=S, features=2, mapping="cube")).double()
    ramp = torch.arange(S, dtype=torch.float64) * 0.1
    with torch.no_grad():
        tex.texture[0, 4, :, :, 0] = ramp[:, None]
        tex.texture[0, 4, :, :, 1] = ramp[None, :]
    s = torch.tensor([[5.0, 20.0, 3.0], [6.0, 20.0, 3.0], [5.0, 21.0, 3.0]], dtype=torch.float64)
    nrm = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(1, 1, 3, 3)
    xy = torch.atanh(tex(torch.zeros(1, 1, 3, dtype=torch.long), s.view(1, 1, 3, 3), nrm)[0, :, 0]).T / 0.1
    step = (S - 1) / 40.0
    torch.testing.assert_close(xy[0], torch.tensor([(S - 1) / 2, (S - 1) / 2], dtype=torch.float64))  # box centre
    torch.testing.assert_close(xy[1] - xy[0], torch.tensor([step, 0.0], dtype=torch.float64))
    torch.testing.assert_close(xy[2] - xy[0], torch.tensor([0.0, step], dtype=torch.float64))


def test_bad_shapes_are_rejected():
    boxes, oid, pts, n = _scene()
    with pytest.raises(ValueError):
        NeuralTexture(3, boxes, cfg=TextureConfig(size=S))
    with pytest.raises(ValueError):
        NeuralTexture(2, boxes, cfg=TextureConfig(size=S, mapping="sphere"))
    with pytest.raises(ValueError):
        _texture(boxes)(oid, pts[..., :2], n)


def test_state_dict_round_trip():
    boxes, oid, pts, n = _scene()
    a = _texture(boxes, seed=1)
    b = _texture(boxes * 0, seed=2)
    b.load_state_dict(a.state_dict())
    assert set(a.state_dict()) == {"texture", "bbox_min", "bbox_max"}
    torch.testing.assert_close(b(oid, pts, n), a(oid, pts, n))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    boxes, oid, pts, n = _scene(seed=8)
    cpu = _texture(boxes).float()
    gpu = _texture(boxes).float().cuda()
    a = cpu(oid, pts.float(), n.float())
    b = gpu(oid.cuda(), pts.float().cuda(), n.float().cuda())
    torch.testing.assert_close(b.cpu(), a, rtol=1e-5, atol=1e-6)
    a.square().sum().backward()
    b.square().sum().backward()
    torch.testing.assert_close(gpu.texture.grad.cpu(), cpu.texture.grad, rtol=1e-4, atol=1e-6)
