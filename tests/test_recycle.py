"""ReCycle-GAN (``recycle``, ``ssim_recycle``): the predictor, the loss terms and weights, the
recycle loss by hand, the real-sequence requirement, and train / resume / translate at tiny."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn
from train_data import real_video_dir, resume_run, tiny_config, train_logged, weighted_total

from sim2real.errors import UserError
from sim2real.methods import get_method
from sim2real.validation import validate


@pytest.fixture(autouse=True)
def _one_thread(one_torch_thread):
    yield


def test_the_predictor_maps_two_frames_to_one():
    from sim2real.models.predictor import UNetPredictor

    p = UNetPredictor(3, filters=4, levels=4)
    x0, x1 = torch.rand(2, 3, 32, 48) * 2 - 1, torch.rand(2, 3, 32, 48) * 2 - 1
    y = p(torch.cat((x0, x1), dim=1))
    assert y.shape == (2, 3, 32, 48) and y.abs().max() <= 1
    torch.testing.assert_close(p(x0, x1), y)  # two frames, or the two concatenated along channels
    assert not torch.allclose(p(x1, x0), y)  # the order of the frames matters
    with pytest.raises(ValueError, match="2 x 3 channels"):
        p(x0)
    # the skips reach the output: changing one input pixel changes the output there
    x = torch.cat((x0, x1), dim=1)[:1].clone().requires_grad_(True)
    p(x)[0, :, 10, 20].sum().backward()
    assert x.grad[0, :, 10, 20].abs().sum() > 0


def test_the_resnet_generator_keeps_the_size():
    from sim2real.models.resnet_generator import ResnetGenerator

    g = ResnetGenerator(3, 3, filters=4, downsamplings=2, res_blocks=1)
    assert g(torch.rand(1, 3, 16, 24)).shape == (1, 3, 16, 24)


RECYCLE_WEIGHTS = {"dis_a": 1.0, "dis_b": 1.0, "adv_a": 1.0, "adv_b": 1.0, "recurrent_a": 10.0, "recurrent_b": 10.0,
                   "recycle_a": 10.0, "recycle_b": 10.0, "cyc_a": 10.0, "cyc_b": 10.0, "idt_a": 5.0, "idt_b": 5.0,
                   "ssim_ab": 0.0, "ssim_ba": 0.0}
GEN_TERMS = {"adv_a", "adv_b", "recurrent_a", "recurrent_b", "recycle_a", "recycle_b", "cyc_a", "cyc_b", "idt_a", "idt_b"}


def _triplet(seed: int = 0, size=(64, 128)) -> dict:
    g = torch.Generator().manual_seed(seed)
    return {f"{k}_{t}": torch.rand(1, 3, *size, generator=g) * 2 - 1 for k in ("a_ref", "real") for t in range(3)}


@pytest.mark.parametrize("name,ssim", [("recycle", False), ("ssim_recycle", True)])
def test_every_term_with_its_weight(name, ssim):
    method = get_method(tiny_config(name))
    want = dict(RECYCLE_WEIGHTS, **({"ssim_ab": 5.0, "ssim_ba": 3.0} if ssim else {}))
    assert method.loss_weights(0) == want and method.loss_weights(10**6) == want
    assert method.data == "triplets" and method.time_independent
    gen, dis = method.build([])
    batch = _triplet()
    out = gen(method.translate, batch, 0)
    d, g = method.dis_losses(dis, batch, out), method.gen_losses(dis, batch, out, 0)
    assert set(d) == {"dis_a", "dis_b"}
    assert set(g) == GEN_TERMS | ({"ssim_ab", "ssim_ba"} if ssim else set())
    assert all(torch.isfinite(v) and v.dim() == 0 for v in (*d.values(), *g.values()))
    names = [grp.name for grp in method.optim_groups(gen, dis)]
    assert names == ["net", "dis"] and {grp.lr for grp in method.optim_groups(gen, dis)} == {2e-4}
    # predictors are trained on the generator side, with the generators
    net = {id(p) for p in method.optim_groups(gen, dis)[0].params}
    assert all(id(p) in net for m in (gen.g_ab, gen.g_ba, gen.p_a, gen.p_b) for p in m.parameters())
    # identity off: no identity terms
    off = get_method(tiny_config(name, method__identity=0))
    out = gen(off.translate, batch, 0)
    assert "idt_a" not in off.gen_losses(dis, batch, out, 0)
    rows = method.image_rows(batch, gen(method.translate, batch, 0))
    assert len(rows) == 2 and all(img.shape == (3, 64, 128) for row in rows for img in row)


class _Fn(nn.Module):
    def __init__(self, fn):
        super().__init__()
        self.fn = fn

    def forward(self, x, *rest):
        return self.fn(x)


def test_the_losses_by_hand_for_toy_networks():
    """G_A->B(x) = x / 2, G_B->A(x) = x + 0.1, P_A = the last frame, P_B = the mean of the two,
    D(x) = mean over channels (one scale): every term written out from the definitions."""
    method = get_method(tiny_config("recycle"))
    gen, dis = method.build([])
    gen.g_ab, gen.g_ba = _Fn(lambda x: x / 2), _Fn(lambda x: x + 0.1)
    gen.p_a, gen.p_b = _Fn(lambda x: x[:, 3:]), _Fn(lambda x: (x[:, :3] + x[:, 3:]) / 2)
    D = _Fn(lambda x: [x.mean(1, keepdim=True)])
    dis.dis_a, dis.dis_b = D, D
    batch = _triplet(3)
    a = [batch[f"a_ref_{t}"].numpy().astype(np.float64) for t in range(3)]
    b = [batch[f"real_{t}"].numpy().astype(np.float64) for t in range(3)]
    out = gen(method.translate, batch, 0)
    g, d = method.gen_losses(dis, batch, out, 0), method.dis_losses(dis, batch, out)

    l1 = lambda x, y: np.abs(x - y).mean()
    G, F = (lambda x: x / 2), (lambda x: x + 0.1)
    P_A, P_B = (lambda x0, x1: x1), (lambda x0, x1: (x0 + x1) / 2)
    Dn = lambda x: x.mean(1)
    want = {
        "recycle_a": l1(F(P_B(G(a[0]), G(a[1]))), a[2]),  # = |(a_0 + a_1) / 4 + 0.1 - a_2|
        "recycle_b": l1(G(P_A(F(b[0]), F(b[1]))), b[2]),  # = |(b_1 + 0.1) / 2 - b_2|
        "recurrent_a": l1(a[1], a[2]),
        "recurrent_b": l1((b[0] + b[1]) / 2, b[2]),
        "cyc_a": l1(F(G(a[0])), a[0]) + l1(F(G(a[1])), a[1]),
        "cyc_b": l1(G(F(b[0])), b[0]) + l1(G(F(b[1])), b[1]),
        "idt_b": l1(G(b[0]), b[0]) + l1(G(b[1]), b[1]),
        "idt_a": l1(F(a[0]), a[0]) + l1(F(a[1]), a[1]),
        "adv_b": sum(((Dn(x) - 1) ** 2).mean() for x in (G(a[0]), G(a[1]), P_B(G(a[0]), G(a[1])))),
        "adv_a": sum(((Dn(x) - 1) ** 2).mean() for x in (F(b[0]), F(b[1]), P_A(F(b[0]), F(b[1])))),
    }
    pairs_b = [(G(a[0]), b[0]), (G(a[1]), b[1]), (P_B(G(a[0]), G(a[1])), b[2]), (P_B(b[0], b[1]), b[2])]
    pairs_a = [(F(b[0]), a[0]), (F(b[1]), a[1]), (P_A(F(b[0]), F(b[1])), a[2]), (P_A(a[0], a[1]), a[2])]
    ls_d = lambda pairs: 0.5 * sum((Dn(f) ** 2).mean() + ((Dn(r) - 1) ** 2).mean() for f, r in pairs)
    want_d = {"dis_b": ls_d(pairs_b), "dis_a": ls_d(pairs_a)}
    assert set(g) == set(want)
    for k, v in {**want, **want_d}.items():
        got = (g | d)[k].item()
        assert got == pytest.approx(v, rel=1e-5, abs=1e-6), k
    # the recycle term is not the plain prediction or the cycle: it differs from both here
    assert want["recycle_a"] != pytest.approx(want["recurrent_a"]) and want["recycle_a"] != pytest.approx(want["cyc_a"])
    assert torch.equal(out["b_hat"], batch["a_ref_0"] / 2)  # b_hat: frame 0's translation


@pytest.mark.parametrize("setting,key", [
    ("method__pred_levels=7", "'method.pred_levels'"),  # 64 x 128 images take at most 6 levels
    ("method__pred_levels=1", "'method.pred_levels'"),
    ("method__recycle=-1", "'method.recycle'"),
    ("method__recurrent=nan", "'method.recurrent'"),
    ("method__lr=0", "'method.lr'"),
    ("method__pred_norm=bn", "'method.pred_norm'"),
    ("method__pred_filters=0", "'method.pred_filters'"),
])
def test_bad_settings_name_their_key(setting, key):
    k, v = setting.split("=")
    with pytest.raises(UserError, match=key) as e:
        validate(tiny_config("recycle", **{k: v}))
    assert "\n" not in str(e.value)
    validate(tiny_config("recycle", method__pred_levels=6))


def test_a_real_folder_without_sequences_is_refused_by_the_cli(capsys, tmp_path, train_inputs):
    from sim2real.cli.main import main

    scenes, real = train_inputs  # real: loose images, no sequences/
    code = main(["train", "--preset", "tiny", "--method", "recycle", "--scenes", str(scenes), "--real", str(real),
                 "--out", str(tmp_path / "run"), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "no sequences" in lines[0] and "video methods" in lines[0], lines[0]
    assert not (tmp_path / "run").exists()  # nothing written


@pytest.mark.parametrize("name", ["recycle", "ssim_recycle"])
def test_trains_resumes_and_translates_a_sequence(name, train_inputs, tmp_path, procedural_caster):
    from sim2real.engine.checkpoint import load_checkpoint
    from sim2real.inference.model import load_run
    from sim2real.scene.trajectory import linear_path

    scenes, _ = train_inputs
    real = real_video_dir(tmp_path)
    cfg = tiny_config(name, iterations=2, checkpoint_every=2, image_every=1)
    run = tmp_path / "run"
    trainer, seen = train_logged(cfg, scenes, real, run)
    assert sorted(seen) == [0, 1]
    # the public code's Adam: lr 2e-4, no weight decay (ours' groups keep optim.weight_decay = 1e-4)
    groups = [g for o in trainer.optimizers.values() for g in o.param_groups]
    assert {(g["lr"], g["weight_decay"]) for g in groups} == {(2e-4, 0.0)}
    assert ("gen/ssim_ab" in seen[1]) == (name == "ssim_recycle") and "gen/recycle_a" in seen[1]
    assert seen[1]["gen/total"] == pytest.approx(weighted_total(trainer, seen[1], 1), rel=1e-5)
    assert (run / "samples").is_dir()
    state = load_checkpoint(run / "checkpoints" / "last.pt")
    assert state["step"] == 2 and state["method"] == "recycle"
    assert state["config"]["method"]["ssim"] == (name == "ssim_recycle")
    assert any(k.startswith("p_b.") for k in state["gen"])  # the predictors are checkpointed

    restored, start = resume_run(run, 2)  # nothing left to train: the restored state as it is
    assert start == 2
    torch.testing.assert_close(restored.gen.p_a.state_dict(), trainer.gen.p_a.state_dict())
    resumed, start = resume_run(run, 4)
    assert start == 2 and resumed.step == 4
    assert load_checkpoint(run / "checkpoints" / "last.pt")["step"] == 4

    model = load_run(run, "cpu")
    assert model.time_independent
    cams = linear_path(procedural_caster, 6, 64, 128, 75.0, 1.0, np.random.default_rng(4))
    gbuffers = [procedural_caster.render(c) for c in cams]
    frames = model.sequence(model.scenes[0], batch=4).translate(gbuffers)
    assert len(frames) == 6 and all(f.shape == (64, 128, 3) and f.dtype == np.uint8 for f in frames)
    assert frames[0].std() > 1.0 and not np.array_equal(frames[0], frames[5])
    # stateless: a frame does not depend on the frames before it
    np.testing.assert_array_equal(model.sequence(model.scenes[0], batch=4).translate(gbuffers[3:4])[0], frames[3])
