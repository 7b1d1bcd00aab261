"""The trainer on the tiny preset (CPU): learning, observability, the one-translation-per-iteration
schedule, variants, NaN handling and the data stream. Seconds per iteration are measured by
benchmarks/bench_train.py, not asserted here (a timed test fails on a loaded machine)."""

import json
import time

import numpy as np
import pytest
import torch
from PIL import Image
from torch.utils.data import default_collate
from train_data import real_dir, scene_dir, tiny_config, views_dir

from sim2real.data.datasets import PAIR_TRIES, TrainPairs, resolve_scenes
from sim2real.data.real import RealImages, random_resized_crop, to_rgb
from sim2real.engine.trainer import Trainer
from sim2real.errors import UserError
from sim2real.presets import METHOD_PRESETS
from sim2real.render.gbuffer import GBuffer
from sim2real.render.warp import correspondences

EVAL_STEPS = (1000, 1001, 1002)  # held-out samples: never drawn by a 10-iteration run


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    base = tmp_path_factory.getbasetemp()
    return scene_dir(base, 11), real_dir(base)


def _eval(trainer, steps=EVAL_STEPS):
    """Mean generator loss terms on fixed samples, no gradient, L_vc off."""
    sums = {}
    for s in steps:
        batch = trainer._to_device(default_collate([trainer.dataset[s]]))
        with torch.no_grad():
            out = trainer.method.translate(trainer.gen, batch, 0)
            losses = trainer.method.gen_losses(trainer.dis, batch, out, 0)
        for k, v in losses.items():
            sums[k] = sums.get(k, 0.0) + v.item() / len(steps)
    return sums


@pytest.fixture(scope="module")
def ten_steps(tmp_path_factory, inputs):
    scenes, real = inputs
    out = tmp_path_factory.mktemp("ten") / "run"
    cfg = tiny_config(iterations=10, log_every=5, image_every=5, checkpoint_every=5, method__vc_start=5)
    trainer = Trainer(cfg, [scenes], real, out, progress=False)
    before = _eval(trainer)
    losses = {}
    trainer.hooks.append(losses.__setitem__)
    trainer.train()
    return {"trainer": trainer, "out": out, "before": before, "after": _eval(trainer), "losses": losses}


def test_ten_iterations_reduce_reconstruction_losses(ten_steps):
    before, after = ten_steps["before"], ten_steps["after"]
    for k in ("rec_a", "rec_b", "cyc_a", "cyc_b"):
        assert after[k] < 0.97 * before[k], (k, before[k], after[k])


def test_losses_and_schedule(ten_steps):
    losses = ten_steps["losses"]
    assert sorted(losses) == list(range(10))
    for s, v in losses.items():
        assert all(np.isfinite(x) for x in v.values())
        assert ("gen/vc" in v) == (s >= 5)  # lambda_vc = 0 before vc_start (then not even computed)
    for k in ("dis/dis_a", "dis/dis_b", "gen/adv_a", "gen/adv_b", "gen/rec_a", "gen/rec_b", "gen/cyc_a",
              "gen/cyc_b", "gen/content_a", "gen/content_b", "gen/ssim_ab", "gen/ssim_ba"):
        assert k in losses[0]
    # the vc term is logged unweighted: the mean angle (radians) of a barely trained translator
    assert 0 < losses[9]["gen/vc"] < np.pi / 2
    # the totals are the paper's weighted sums (supplementary, "Losses"; lambda_vc = 20 from vc_start)
    paper = {"adv_a": 1, "adv_b": 1, "rec_a": 10, "rec_b": 10, "cyc_a": 10, "cyc_b": 10, "content_a": 1,
             "content_b": 1, "ssim_ab": 5, "ssim_ba": 3, "vc": 20}
    for s in (4, 9):
        v = losses[s]
        want = sum(w * v[f"gen/{k}"] for k, w in paper.items() if f"gen/{k}" in v)
        assert v["gen/total"] == pytest.approx(want, rel=1e-5)
        assert v["dis/total"] == pytest.approx(v["dis/dis_a"] + v["dis/dis_b"], rel=1e-5)


def test_tensorboard_metrics_and_image_grids(ten_steps):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = ten_steps["out"]
    acc = EventAccumulator(str(out / "tb"))
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    for name in ("gen/rec_a", "gen/ssim_ab", "gen/vc", "dis/dis_a", "lr/net", "lr/tex", "lr/dis",
                 "weight/vc", "weight/rec_a", "time/iterations_per_s", "gen/total", "dis/total"):
        assert name in tags, name
    assert [e.step for e in acc.Scalars("gen/rec_a")] == [5, 10]
    assert acc.Scalars("lr/tex")[0].value == pytest.approx(1e-3)
    assert acc.Scalars("weight/vc")[-1].value == 20.0 and acc.Scalars("weight/rec_a")[-1].value == 10.0
    assert "samples" in acc.Tags()["images"]
    lines = [json.loads(l) for l in (out / "metrics.jsonl").read_text().splitlines()]
    assert [l["step"] for l in lines] == [5, 10]
    mean_rec = np.mean([ten_steps["losses"][s]["gen/rec_a"] for s in range(5, 10)])
    assert lines[1]["gen/rec_a"] == pytest.approx(mean_rec, rel=1e-5)  # interval mean
    grids = sorted(p.name for p in (out / "samples").glob("*.png"))
    assert grids == ["step_0000001.png", "step_0000005.png", "step_0000010.png"]
    h, w = 64, 128
    g1 = np.asarray(Image.open(out / "samples" / "step_0000001.png"))
    g10 = np.asarray(Image.open(out / "samples" / "step_0000010.png"))
    assert g1.shape == (2 * h + 2, 5 * w + 8, 3)  # sim row + real row
    assert g10.shape == (3 * h + 4, 5 * w + 8, 3)  # + the view-consistency row once L_vc is on
    assert (out / "config.yaml").is_file()


def test_lr_schedule_halves(inputs, tmp_path):
    scenes, real = inputs
    cfg = tiny_config(iterations=3, optim__lr_halve_every=2, image_every=100)
    trainer = Trainer(cfg, [scenes], real, tmp_path / "r", progress=False)
    trainer.train()
    assert trainer.schedulers["net"].get_last_lr()[0] == pytest.approx(0.5e-4)
    assert trainer.schedulers["tex"].get_last_lr()[0] == pytest.approx(0.5e-3)
    assert trainer.optimizers["dis"].param_groups[0]["lr"] == pytest.approx(0.5e-4)
    assert trainer.optimizers["net"].param_groups[0]["betas"] == (0.5, 0.999)


def test_time_limit_stops_with_a_checkpoint_at_the_step_it_reached(inputs, tmp_path):
    from sim2real.engine import checkpoint as ckpt

    scenes, real = inputs
    cfg = tiny_config(iterations=100_000, checkpoint_every=1000, image_every=1000, log_every=1000)
    trainer = Trainer(cfg, [scenes], real, tmp_path / "r", progress=False)
    ends = []
    trainer.hooks.append(lambda s, v: ends.append(time.perf_counter()))
    t0 = time.perf_counter()
    last = trainer.train(time_limit_s=1.0)
    # it stops after the first step that ends past the budget, not before and not later
    assert 1 <= trainer.step == len(ends) < 100_000
    assert ends[-1] - t0 > 0.9 and (len(ends) == 1 or ends[-2] - t0 <= 1.0 + 0.5)
    assert ckpt.load_checkpoint(last)["step"] == trainer.step


def _count_calls(trainer):
    counts = {}
    t = trainer.gen.translator
    mods = {"enc_a": t.enc_a, "enc_b": t.enc_b, "dec_a": t.dec_a, "dec_b": t.dec_b,
            "dis_a": trainer.dis.dis_a, "dis_b": trainer.dis.dis_b}
    for name, m in mods.items():
        m.register_forward_hook(lambda mod, i, o, n=name: counts.__setitem__(n, counts.get(n, 0) + 1))
    return counts


def test_translations_computed_once_per_iteration(inputs, tmp_path):
    scenes, real = inputs
    trainer = Trainer(tiny_config(method__vc_start=0), [scenes], real, tmp_path / "r", progress=False)
    counts = _count_calls(trainer)
    batch = trainer._to_device(default_collate([trainer.dataset[0]]))
    tex_before = trainer.gen.textures[trainer.gen.scene_keys[0]].texture.detach().clone()
    losses = trainer.train_step(batch, 0)
    # E_A: x_a, a_hat (cycle), view j; E_B: b, b_hat (cycle); G_B: (b_hat, b_rec) batched, b_cyc, view j;
    # G_A: (a_hat, a_rec) batched, a_cyc. D: one call for the dis step, one for the gen step.
    # MUNIT's dis_update would add another E_A, E_B, G_A, G_B pass.
    assert counts == {"enc_a": 3, "enc_b": 2, "dec_a": 2, "dec_b": 3, "dis_a": 2, "dis_b": 2}
    assert "gen/vc" in losses
    # the texture of the sampled scene got a gradient step
    assert not torch.equal(trainer.gen.textures[trainer.gen.scene_keys[0]].texture, tex_before)


def test_view_j_gets_no_gradient(inputs, tmp_path):
    scenes, real = inputs
    trainer = Trainer(tiny_config(method__vc_start=0), [scenes], real, tmp_path / "r", progress=False)
    batch = trainer._to_device(default_collate([trainer.dataset[0]]))
    out = trainer.method.translate(trainer.gen, batch, 0)
    assert out["b_hat"].requires_grad
    assert not out["b_hat_j"].requires_grad and not out["b_hat_j_warped"].requires_grad


def test_reconstruction_targets_carry_gradient_into_the_texture_only_if_asked(inputs, tmp_path):
    """rec_a = mean |a_rec - x_a|: through its target x_a it sends d/dx_a = -sign(a_rec - x_a) / numel
    into the texture (the release); with ``method.target_grad=false`` only through a_rec."""
    scenes, real = inputs
    for flag in (True, False):
        trainer = Trainer(tiny_config(method__target_grad=flag), [scenes], real, tmp_path / f"r{flag}", progress=False)
        batch = trainer._to_device(default_collate([trainer.dataset[0]]))
        out = trainer.method.translate(trainer.gen, batch, 0)
        out["a_rec"] = out["a_rec"].detach()  # the prediction path off: what is left is the target's
        x_a = out["x_a"]
        x_a.retain_grad()
        rec_a = trainer.method.gen_losses(trainer.dis, batch, out, 0)["rec_a"]
        torch.testing.assert_close(rec_a, (out["a_rec"] - x_a).abs().mean())  # same value either way
        if flag:
            rec_a.backward()
            torch.testing.assert_close(x_a.grad, -torch.sign(out["a_rec"] - x_a.detach()) / x_a.numel())
            assert trainer.gen.textures[trainer.gen.scene_keys[0]].texture.grad.abs().sum() > 0
        else:
            assert not rec_a.requires_grad  # no path into x_a: the texture learns only through the outputs


def test_texture_edge_term_asks_the_frame_for_the_texture_edges(inputs, tmp_path):
    """``method.tex_edges``: edge recall of b_hat at a_tex's edges. A flat frame recalls no edge
    (1 - tanh 0 = 1 exactly); the texture shown as the frame recalls every one; a_ref's channels
    play no part; the texture enters as a target without gradient; off by default."""
    scenes, real = inputs
    off = Trainer(tiny_config(method__vc_start=0, method__texture__init_noise=1.0), [scenes], real, tmp_path / "off",
                  progress=False)
    assert off.method.loss_weights(0)["tex_edges"] == 0.0
    batch = off._to_device(default_collate([off.dataset[0]]))
    assert "tex_edges" not in off.method.gen_losses(off.dis, batch, off.method.translate(off.gen, batch, 0), 0)

    trainer = Trainer(tiny_config(method__vc_start=0, method__texture__init_noise=1.0, method__tex_edges=2.0), [scenes],
                      real, tmp_path / "on", progress=False)
    m = trainer.method
    assert m.loss_weights(0)["tex_edges"] == 2.0
    out = m.translate(trainer.gen, batch, 0)
    n = m.features
    assert n == 3
    tex = out["x_a"][:, :n].detach()

    def term(b_hat, a_ref=None):
        o = dict(out, b_hat=b_hat)
        if a_ref is not None:
            o["x_a"] = torch.cat((out["x_a"][:, :n], a_ref), 1)
        return m.gen_losses(trainer.dis, batch, o, 0)["tex_edges"]

    assert term(torch.zeros_like(out["b_hat"])).item() == pytest.approx(1.0, abs=1e-6)
    shown = term(tex.clone()).item()
    assert shown < 0.05  # c = 0.02 against the noise's edges: tanh of many c's is ~1
    assert term(tex.clone(), a_ref=torch.zeros_like(out["x_a"][:, n:])).item() == pytest.approx(shown, abs=1e-6)
    # the texture as the target carries no gradient: with b_hat detached nothing is left to train
    assert not term(out["b_hat"].detach()).requires_grad
    term(out["b_hat"]).backward()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in trainer.gen.translator.dec_b.parameters())


def test_mixed_precision_path_on_cpu(inputs, tmp_path, monkeypatch):
    """The CUDA path (bf16 autocast, channels-last images and weights), run on the CPU: losses
    finite and within bf16 rounding of the fp32 step, the networks computing in bf16, the
    texture and every parameter updated in fp32."""
    from sim2real.engine import precision

    scenes, real = inputs
    cfg = tiny_config(method__vc_start=0)
    fp32 = Trainer(cfg, [scenes], real, tmp_path / "fp32", progress=False)
    monkeypatch.setattr(precision, "mixed_precision", lambda device: True)
    bf16 = Trainer(cfg, [scenes], real, tmp_path / "bf16", progress=False)
    assert bf16.amp and not fp32.amp
    conv = bf16.gen.translator.enc_a.model[0].conv
    assert conv.weight.is_contiguous(memory_format=torch.channels_last)
    batch = default_collate([fp32.dataset[0]])
    b32, b16 = fp32._to_device(batch), bf16._to_device(batch)
    assert b16["real"].is_contiguous(memory_format=torch.channels_last)
    with bf16._autocast():
        out = bf16.method.translate(bf16.gen, b16, 0)
    assert out["b_hat"].dtype == torch.bfloat16 and out["b_hat_j_warped"].dtype == torch.float32
    tex16 = bf16.gen.textures[bf16.gen.scene_keys[0]].texture
    tex32 = fp32.gen.textures[fp32.gen.scene_keys[0]].texture
    init = tex32.detach().clone()
    assert torch.equal(tex16, init)
    l32, l16 = fp32.train_step(b32, 0), bf16.train_step(b16, 0)
    assert l16.keys() == l32.keys() and "gen/vc" in l16
    for k in l32:
        assert torch.isfinite(l16[k]) and l16[k].dtype == torch.float32, k
        assert l16[k].item() == pytest.approx(l32[k].item(), rel=0.05, abs=0.02), k
    for p in (*bf16.gen.parameters(), *bf16.dis.parameters()):
        assert p.dtype == torch.float32
    # the texture gradient through the bf16 networks points where the fp32 one does (cosine
    # 0.747 measured on this sample, 0.757 before the structure terms' grey conversion moved to
    # fp32 and the samples to compact dtypes; unrelated gradients would give ~0)
    g16, g32 = tex16.grad.flatten(), tex32.grad.flatten()
    assert torch.nn.functional.cosine_similarity(g16, g32, dim=0) > 0.7
    assert (tex16 - init).abs().max() <= cfg.optim.lr_tex * 1.001  # Adam's first step: at most lr


def test_ablations_are_presets_of_ours(inputs, tmp_path):
    from sim2real.losses import angle_loss

    scenes, real = inputs
    assert {"ours", "ours_no_vc", "ours_l1_vc", "ours_no_tex_vc"} <= set(METHOD_PRESETS)
    with pytest.raises(UserError, match="unknown method 'cyclegan'"):
        tiny_config(method="cyclegan")
    # no texture: domain A is a_ref alone (3 channels, D_A too), no texture group, single views
    no_tex = Trainer(tiny_config(method="ours_no_tex_vc"), [scenes], real, tmp_path / "a", progress=False)
    assert type(no_tex.method).name == "ours" and len(no_tex.gen.textures) == 0 and "tex" not in no_tex.optimizers
    assert no_tex.gen.translator.enc_a.model[0].conv.in_channels == 3
    assert no_tex.dis.dis_a.cnns[0][0].conv.in_channels == 3
    sample = no_tex.dataset[0]
    assert "points_j" not in sample and "uv_ij" not in sample  # view j is not even ray-cast
    batch = no_tex._to_device(default_collate([sample]))
    out = no_tex.method.translate(no_tex.gen, batch, 10)
    assert torch.equal(out["x_a"], batch["a_ref_i"])
    assert "gen/vc" not in no_tex.train_step(batch, 10)
    # no view consistency: the texture is learned, lambda_vc is 0 at every step
    no_vc = Trainer(tiny_config(method="ours_no_vc"), [scenes], real, tmp_path / "b", progress=False)
    assert "tex" in no_vc.optimizers and no_vc.method.loss_weights(10**6)["vc"] == 0.0
    assert "points_j" not in no_vc.dataset[0]
    assert "gen/vc" not in no_vc.train_step(no_vc._to_device(default_collate([no_vc.dataset[0]])), 10)
    # L1 view consistency: channel-mean |b_i - w(b_j)| over matched pixels (by hand), not the angle
    l1 = Trainer(tiny_config(method="ours_l1_vc", method__vc_start=0), [scenes], real, tmp_path / "c", progress=False)
    batch = l1._to_device(default_collate([l1.dataset[0]]))
    with torch.no_grad():
        out = l1.method.translate(l1.gen, batch, 0)
        vc = l1.method.gen_losses(l1.dis, batch, out, 0)["vc"]
    m = out["vc_mask"][0].numpy()
    diff = np.abs(out["b_hat"][0].numpy() - out["b_hat_j_warped"][0].numpy()).mean(0)
    assert m.sum() > 0 and vc.item() == pytest.approx(float(diff[m].mean()), rel=1e-5)
    assert vc.item() != pytest.approx(angle_loss(out["b_hat"], out["b_hat_j_warped"], out["vc_mask"]).item(), rel=1e-3)


def test_nan_loss_stops_with_last_good_checkpoint(inputs, tmp_path):
    from sim2real.engine.checkpoint import load_checkpoint

    scenes, real = inputs
    cfg = tiny_config(iterations=6, checkpoint_every=2, image_every=100)
    trainer = Trainer(cfg, [scenes], real, tmp_path / "r", progress=False)

    def corrupt(step, values):
        if step == 2:  # after the checkpoint at step 2 was written
            with torch.no_grad():
                trainer.gen.translator.enc_a.model[0].conv.weight[0, 0, 0, 0] = float("nan")

    trainer.hooks.append(corrupt)
    last = tmp_path / "r" / "checkpoints" / "last.pt"
    with pytest.raises(UserError) as e:
        trainer.train()
    msg = str(e.value)
    assert "became nan at step 3" in msg and str(last) in msg, msg
    state = load_checkpoint(last)
    assert state["step"] == 2
    assert all(torch.isfinite(v).all() for v in state["gen"].values() if v.is_floating_point())


# --- data ------------------------------------------------------------------------------------


def test_real_image_modes_are_converted():
    rgb = np.random.default_rng(0).integers(0, 256, (6, 9, 3), dtype=np.uint8)
    im = Image.fromarray(rgb)
    assert np.array_equal(to_rgb(im), rgb)
    assert np.array_equal(to_rgb(im.convert("RGBA")), rgb)  # alpha dropped, colours kept
    grey = np.asarray(im.convert("L"))
    for mode in ("L", "LA"):
        out = to_rgb(im.convert(mode))
        assert out.shape == (6, 9, 3) and all(np.array_equal(out[..., c], grey) for c in range(3))
    pal = im.convert("P")
    assert np.array_equal(to_rgb(pal), np.asarray(pal.convert("RGB")))
    g16 = Image.fromarray((grey.astype(np.uint16) * 257))
    assert np.array_equal(to_rgb(g16)[..., 1], grey)


def test_random_resized_crop_covers_and_scales():
    rng = np.random.default_rng(1)
    img = np.zeros((100, 100, 3), np.uint8)
    img[:, 50:] = 255  # left half black, right half white
    for _ in range(20):
        crop = random_resized_crop(img, 32, 64, 1.0, 1.0, rng)
        assert crop.shape == (32, 64, 3)
    # factor 1 on a 100x100 image for 32x64: width 64 covers it exactly -> the full width is seen
    crop = random_resized_crop(img, 32, 64, 1.0, 1.0, rng)
    assert crop[:, :20].max() < 10 and crop[:, -20:].min() > 245
    small = random_resized_crop(np.full((10, 20, 3), 7, np.uint8), 32, 64, 1.0, 1.2, rng)
    assert small.shape == (32, 64, 3) and (small == 7).all()  # upscaled to cover


def test_samples_depend_on_seed_rank_step_only(inputs, tmp_path_factory):
    scenes, real = inputs
    views = views_dir(tmp_path_factory.getbasetemp(), scene_dir(tmp_path_factory.getbasetemp(), 12))
    cfg = tiny_config()
    sources = resolve_scenes([scenes, views], 64, 128)
    assert [s.cached for s in sources] == [False, True] and len(sources[1].view_files) == 4
    pool = RealImages(real)
    a, b = TrainPairs(sources, pool, cfg.data, seed=0), TrainPairs(sources, pool, cfg.data, seed=0)
    s7 = a[7]
    _ = b[3]  # another history: the same step still gives the same sample
    assert all(torch.equal(s7[k], b[7][k]) for k in s7)
    other_rank = TrainPairs(sources, pool, cfg.data, seed=0, rank=1)[7]
    assert not torch.equal(s7["real"], other_rank["real"]) or not torch.equal(s7["points_i"], other_rank["points_i"])
    # every sample: two different views of one scene with matching correspondences
    scenes_seen = set()
    for step in range(12):
        s = a[step]
        scenes_seen.add(int(s["scene"]))
        assert not torch.equal(s["points_i"], s["points_j"])
        assert s["visible_ij"].float().mean() >= cfg.data.min_overlap
        assert s["real"].shape == (3, 64, 128) and s["real"].dtype == torch.uint8  # widened on the device
        assert s["distance_i"].shape == (64, 128)  # a_ref is rendered on the device, from this
    assert scenes_seen == {0, 1}


def test_loader_workers_do_not_change_the_data(inputs, tmp_path):
    scenes, real = inputs
    streams = []
    for w in (0, 2):
        trainer = Trainer(tiny_config(iterations=3, data__workers=w), [scenes], real, tmp_path / f"w{w}", progress=False)
        trainer.step = 1  # as after a resume: the stream starts at the resumed step
        streams.append(list(trainer._loader()))
    assert [int(b["step"]) for b in streams[0]] == [1, 2]
    for b0, b2 in zip(*streams):
        assert all(torch.equal(b0[k], b2[k]) for k in b0)


@pytest.mark.parametrize("cores,local_world,expected", [(16, None, 15), (128, None, 127), (16, "4", 3), (64, "8", 7),
                                                         (2, None, 1), (1, None, 1), (3, "2", 1)])
def test_automatic_loader_workers(monkeypatch, cores, local_world, expected):
    """data.workers = -1: the node's usable cores split among its ranks, less one for training,
    at least 1 and no fixed cap (sim2real.threads.worker_count); an explicit count is kept."""
    from sim2real import threads
    from sim2real.engine import loader

    monkeypatch.setattr(threads, "usable_cores", lambda: cores)
    if local_world is None:
        monkeypatch.delenv("LOCAL_WORLD_SIZE", raising=False)
    else:
        monkeypatch.setenv("LOCAL_WORLD_SIZE", local_world)
    assert loader.loader_workers(-1) == expected
    assert loader.loader_workers(0) == 0 and loader.loader_workers(5) == 5


def test_low_overlap_redraws_view_j_only(inputs, tmp_path_factory):
    """A pair below data.min_overlap keeps view i and draws a new j: with an unreachable
    threshold every try is made, i is the first draw of the step, and the best j is kept."""
    scenes, real = inputs
    views = views_dir(tmp_path_factory.getbasetemp(), scene_dir(tmp_path_factory.getbasetemp(), 12))
    cfg = tiny_config()
    cfg.data.min_overlap = 1.0  # never reached: all PAIR_TRIES draws of j happen
    sources = resolve_scenes([views], 64, 128)
    ds = TrainPairs(sources, RealImages(real), cfg.data, seed=0)
    calls = []
    original = ds._view

    def spy(src, rng, avoid=None):
        k, g = original(src, rng, avoid)
        calls.append((k, avoid))
        return k, g

    ds._view = spy
    s = ds[3]
    assert len(calls) == 1 + PAIR_TRIES
    ki = calls[0][0]
    assert calls[0][1] is None and all(avoid == ki and k != ki for k, avoid in calls[1:])
    gi = GBuffer.load(sources[0].view_files[ki])
    assert torch.equal(s["points_i"], torch.from_numpy(gi.points).to(torch.float16))  # in transit: fp16
    overlaps = [float(correspondences(gi, GBuffer.load(sources[0].view_files[k]))[1].mean()) for k, _ in calls[1:]]
    assert s["visible_ij"].float().mean().item() == pytest.approx(max(overlaps))
