"""ssim_munit (Pfeiffer et al. 2019): MUNIT's style path (style encoder, AdaIN, MLP), its loss
terms and weights, the style reconstruction, seeded styles and noise at inference, the realism
views, and 2 tiny iterations that train, checkpoint, resume and translate a sequence."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from train_data import resume_run, tiny_config, train_logged, weighted_total

from sim2real.config import GeneratorConfig
from sim2real.errors import UserError
from sim2real.methods import get_method
from sim2real.models.style import MLP, AdaIN, AdaINDecoder, StyleEncoder
from sim2real.validation import validate


@pytest.fixture(autouse=True)
def _one_thread():
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


def method_of(**changes):
    cfg = tiny_config("ssim_munit", **changes)
    validate(cfg)
    return get_method(cfg)


# --- building blocks -----------------------------------------------------------------------------


def test_style_encoder_gives_an_8_dim_style_from_munits_layers():
    torch.manual_seed(0)
    enc = StyleEncoder(3, GeneratorConfig(filters=4), 8)
    convs = [m for m in enc.modules() if isinstance(m, torch.nn.Conv2d)]
    # conv7, four stride-2 conv4 (the first two double the channels), 1x1 head; no norm anywhere
    assert [(c.kernel_size[0], c.stride[0], c.out_channels) for c in convs] == [
        (7, 1, 4), (4, 2, 8), (4, 2, 16), (4, 2, 16), (4, 2, 16), (1, 1, 8)]
    assert not any(isinstance(m, (torch.nn.InstanceNorm2d, torch.nn.LayerNorm)) for m in enc.modules())
    x = torch.rand(2, 3, 64, 96) * 2 - 1
    s = enc(x)
    assert s.shape == (2, 8)
    assert not torch.allclose(s[0], s[1])  # depends on the image
    assert enc(torch.rand(1, 3, 16, 16)).shape == (1, 8)  # the smallest side it takes


def test_adain_gives_exactly_the_requested_statistics():
    # hand-computed: channel [[1, 3], [1, 3]] has mean 2, variance 1 -> (x - 2) * 2 + 5
    x = torch.tensor([[[[1.0, 3.0], [1.0, 3.0]]]])
    y = AdaIN(1, eps=0.0)(x, torch.tensor([[5.0]]), torch.tensor([[2.0]]))
    assert torch.equal(y, torch.tensor([[[[3.0, 7.0], [3.0, 7.0]]]]))

    torch.manual_seed(1)
    x = torch.randn(2, 4, 6, 7) * 3 + 1
    mean, std = torch.randn(2, 4), torch.rand(2, 4) + 0.5
    y = AdaIN(4, eps=0.0)(x, mean, std)
    var_out, mean_out = torch.var_mean(y, dim=(2, 3), unbiased=False)
    torch.testing.assert_close(mean_out, mean, atol=1e-5, rtol=0)
    torch.testing.assert_close(var_out.sqrt(), std, atol=1e-5, rtol=1e-5)
    # with eps the std shrinks by sqrt(v / (v + eps)), v the input's (biased) variance
    v = torch.var(x, dim=(2, 3), unbiased=False)
    y = AdaIN(4, eps=0.5)(x, mean, std)
    torch.testing.assert_close(torch.std(y, dim=(2, 3), unbiased=False), std * torch.sqrt(v / (v + 0.5)))


def test_the_mlp_maps_the_style_to_exactly_the_adain_parameters_in_order():
    torch.manual_seed(2)
    cfg = GeneratorConfig(filters=4, downsamplings=2, res_blocks=2, content_channels=8)
    dec = AdaINDecoder(3, cfg, style_dim=8, mlp_dim=256, mlp_layers=3)
    w = 4 * 2**2  # residual width 16: 2 blocks x 2 AdaIN layers x (mean, std) x 16 channels
    assert dec.num_adain_params == 2 * 2 * 2 * w == 128
    linears = [m for m in dec.mlp.modules() if isinstance(m, torch.nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linears] == [(8, 256), (256, 256), (256, 128)]
    assert MLP(8, 5, 16, 1)(torch.zeros(3, 8)).shape == (3, 5)
    # the first AdaIN layer gets the first w values as means, the next w as stds
    s = torch.randn(2, 8)
    seen = {}
    dec.res[0].norm1.register_forward_hook(lambda m, i, o: seen.__setitem__("y", o))
    img = dec(torch.rand(2, 8, 8, 12), s)
    assert img.shape == (2, 3, 32, 48) and img.abs().max() <= 1
    p = dec.mlp(s)
    var, mean = torch.var_mean(seen["y"], dim=(2, 3), unbiased=False)
    torch.testing.assert_close(mean, p[:, :w], atol=1e-4, rtol=0)
    torch.testing.assert_close(var.sqrt(), p[:, w : 2 * w].abs(), atol=1e-3, rtol=1e-3)


# --- one iteration ---------------------------------------------------------------------------------


def _batch(h=64, w=128, seed=0):
    g = torch.Generator().manual_seed(seed)
    return {"a_ref_i": torch.rand(1, 3, h, w, generator=g) * 2 - 1, "real": torch.rand(1, 3, h, w, generator=g) * 2 - 1,
            "scene": [0]}


def test_loss_terms_and_munits_weights():
    m = method_of()
    assert m.data == "views" and not m.time_independent
    assert m.loss_weights(0) == {"adv_a": 1.0, "adv_b": 1.0, "dis_a": 1.0, "dis_b": 1.0, "rec_a": 10.0, "rec_b": 10.0,
                                 "style_a": 1.0, "style_b": 1.0, "content_a": 1.0, "content_b": 1.0,
                                 "cyc_a": 10.0, "cyc_b": 10.0, "ssim_ab": 5.0, "ssim_ba": 3.0}
    torch.manual_seed(0)
    gen, dis = m.build([])
    batch = _batch()
    out = m.translate(gen, batch, 0)
    gen_terms = m.gen_losses(dis, batch, out, 0)
    assert set(gen_terms) == set(m.loss_weights(0)) - {"dis_a", "dis_b"}
    assert set(m.dis_losses(dis, batch, out)) == {"dis_a", "dis_b"}
    assert all(torch.isfinite(v) and v >= 0 for v in gen_terms.values())
    # MUNIT skips the explicit cycle when its weight is 0
    m0 = method_of(loss__cyc=0)
    out0 = m0.translate(gen, batch, 0)
    assert "a_cyc" not in out0 and not {"cyc_a", "cyc_b"} & set(m0.gen_losses(dis, batch, out0, 0))


def test_style_reconstruction_ties_the_reencoded_style_to_the_sampled_one():
    m = method_of(method__noise_std=0)
    torch.manual_seed(3)
    gen, dis = m.build([])
    s_a, s_b = torch.randn(1, 8), torch.randn(1, 8)
    batch = {**_batch(), "style_a": s_a, "style_b": s_b}
    out = m.translate(gen, batch, 0)
    assert torch.equal(out["s_b"], s_b) and torch.equal(out["s_a"], s_a)  # the sampled styles decode
    torch.testing.assert_close(out["b_hat"], gen.gen_b.decode(gen.gen_a.enc_content(batch["a_ref_i"]), s_b))
    terms = m.gen_losses(dis, batch, out, 0)
    want = (gen.gen_b.enc_style(out["b_hat"]) - s_b).abs().mean()
    torch.testing.assert_close(terms["style_b"], want)
    torch.testing.assert_close(terms["style_a"], (gen.gen_a.enc_style(out["a_hat"]) - s_a).abs().mean())


def test_style_reconstruction_goes_down_when_trained():
    # fixed draws (the styles to recover and no noise), so that the curve is not dominated by them
    m = method_of(method__noise_std=0)
    torch.manual_seed(4)
    gen, dis = m.build([])
    opt = torch.optim.Adam(gen.parameters(), lr=1e-3)
    batch = {**_batch(64, 64), "style_a": torch.randn(1, 8), "style_b": torch.randn(1, 8)}
    values = []
    for _ in range(10):
        out = m.translate(gen, batch, 0)
        terms = m.gen_losses(dis, batch, out, 0)
        loss = terms["style_a"] + terms["style_b"]
        values.append(loss.item())
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert values[-1] < 0.5 * values[0], values


# --- inference: one style per sequence, seeded noise -------------------------------------------------


def _frames(m, gen, gbuffers, scene=0, chunks=None):
    seq = m.sequence(gen, scene, torch.device("cpu"))
    chunks = chunks or [len(gbuffers)]
    out, i = [], 0
    with torch.no_grad():
        for n in chunks:
            out.append(seq.push(gbuffers[i : i + n]))
            i += n
    return torch.cat(out)


def test_a_fixed_style_gives_identical_frames_without_noise_and_other_styles_differ(procedural_caster):
    from sim2real.scene.trajectory import sample_poses

    g = procedural_caster.render(sample_poses(procedural_caster, 1, 64, 128, 75.0, seed=4)[0])
    m = method_of(method__noise_std=0)
    assert m.time_independent
    torch.manual_seed(5)
    gen, _ = m.build([])
    gen.eval()
    frames = _frames(m, gen, [g] * 4)
    for k in range(1, 4):
        assert torch.equal(frames[k], frames[0])
    other_seed = method_of(method__noise_std=0, method__inference_seed=7)
    assert (_frames(other_seed, gen, [g]) - frames[0]).abs().max() > 1e-3  # another sequence style
    assert (_frames(m, gen, [g], scene=1) - frames[0]).abs().max() > 1e-3  # another scene's style

    # with noise (the default): the same view flickers along the sequence, reproducibly, and
    # the chunking of the sequence does not matter (frame k's noise belongs to index k)
    noisy = method_of()
    f1 = _frames(noisy, gen, [g] * 4)
    assert all((f1[k] - f1[0]).abs().max() > 1e-4 for k in range(1, 4))
    torch.testing.assert_close(_frames(noisy, gen, [g] * 4, chunks=[1, 3]), f1, atol=1e-5, rtol=0)


def test_realism_views_with_a_random_and_a_real_style():
    m = method_of()
    torch.manual_seed(6)
    gen, _ = m.build([])
    gen.eval()
    x = torch.rand(2, 3, 64, 128) * 2 - 1
    real = torch.rand(2, 3, 80, 96) * 2 - 1
    with torch.no_grad():
        views = m.translate_views(gen, {"a_ref_i": x, "scene": [0, 0]}, real, torch.Generator().manual_seed(1))
        again = m.translate_views(gen, {"a_ref_i": x, "scene": [0, 0]}, real, torch.Generator().manual_seed(1))
        no_real = m.translate_views(gen, {"a_ref_i": x, "scene": [0, 0]})
    assert [n for n, _ in views] == ["random_style", "real_style"] and [n for n, _ in no_real] == ["random_style"]
    for (_, v), (_, w) in zip(views, again):
        assert v.shape == (2, 3, 64, 128) and torch.equal(v, w)  # seeded
    assert (views[0][1] - views[1][1]).abs().max() > 1e-3
    # the real style is E^s_B of the real image: without noise, that exact style decodes
    m0 = method_of(method__noise_std=0)
    with torch.no_grad():
        (_, rnd), (_, rs) = m0.translate_views(gen, {"a_ref_i": x}, real[:1])
        want = gen.gen_b.decode(gen.gen_a.enc_content(x), gen.gen_b.enc_style(real[:1]).expand(2, -1))
    torch.testing.assert_close(rs, want)
    with pytest.raises(ValueError, match="real must be"):
        m0.translate_views(gen, {"a_ref_i": x}, torch.zeros(3, 3, 32, 32))


def test_config_errors_name_the_key():
    for changes, key in (({"method__style_dim": 0}, "method.style_dim"), ({"method__mlp_layers": 0}, "method.mlp_layers"),
                         ({"method__noise_std": -0.1}, "method.noise_std"), ({"method__style_rec": "nan"}, "method.style_rec"),
                         ({"generator__res_blocks": 0}, "generator.res_blocks")):
        with pytest.raises(UserError, match=f"'{key}'"):
            validate(tiny_config("ssim_munit", **changes))


# --- the whole path: train 2 iterations, checkpoint, resume, translate a sequence --------------------


def test_trains_checkpoints_resumes_and_translates_a_sequence(train_inputs, tmp_path, procedural_caster):
    from sim2real.engine.checkpoint import load_checkpoint
    from sim2real.inference.model import load_run
    from sim2real.scene.trajectory import sample_poses

    scenes, real = train_inputs
    cfg = tiny_config("ssim_munit", iterations=2, checkpoint_every=2, image_every=1)
    trainer, seen = train_logged(cfg, scenes, real, tmp_path / "run")
    assert sorted(seen) == [0, 1]
    terms = {k[4:] for k in seen[1] if k.startswith("gen/") and k != "gen/total"}
    assert terms == set(trainer.method.loss_weights(1)) - {"dis_a", "dis_b"}
    assert seen[1]["gen/total"] == pytest.approx(weighted_total(trainer, seen[1], 1), rel=1e-5)
    state = load_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt")
    assert state["step"] == 2 and state["method"] == "ssim_munit"
    assert state["config"]["method"]["name"] == "ssim_munit" and state["config"]["method"]["style_dim"] == 8

    _, start = resume_run(tmp_path / "run", 3)
    assert start == 2
    assert load_checkpoint(tmp_path / "run" / "checkpoints" / "last.pt")["step"] == 3

    model = load_run(tmp_path / "run", "cpu")
    assert not model.time_independent
    cams = sample_poses(procedural_caster, 6, 64, 128, 75.0, seed=2)
    gbuffers = [procedural_caster.render(c) for c in cams]
    frames = model.sequence(model.scenes[0], batch=4).translate(gbuffers)
    assert len(frames) == 6 and all(f.shape == (64, 128, 3) and f.dtype == np.uint8 for f in frames)
    # the sequence's frames do not depend on its chunking (chunks of 4 + 2 vs 6 at once)
    again = model.sequence(model.scenes[0], batch=6).translate(gbuffers)
    diff = np.abs(np.stack(frames).astype(int) - np.stack(again).astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3
