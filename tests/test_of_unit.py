"""OF-UNIT: the warped previous output fed to E_A (hand-computed), zeros at a sequence start, the
L1 consistency of weight 50, training = inference for a given previous frame, train / resume /
translate at the tiny preset, and the revisit protocol (history dependence, unlike ours)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from train_data import tiny_config

from sim2real.config import override
from sim2real.errors import UserError
from sim2real.methods import get_method
from sim2real.presets import preset
from sim2real.validation import validate

H, W = 40, 40  # MS-SSIM at the tiny window needs a side > 32


def _method_and_stages(**changes):
    cfg = tiny_config("of_unit", **changes)
    method = get_method(cfg)
    torch.manual_seed(0)
    gen, dis = method.build([SimpleNamespace(name="s")])
    return method, gen, dis


def _record_enc_a(gen):
    """Every input of E_A, in call order."""
    seen: list[torch.Tensor] = []
    handle = gen.translator.enc_a.register_forward_pre_hook(lambda m, args: seen.append(args[0].detach().clone()))
    return seen, handle


def _centres():
    r, c = np.mgrid[0:H, 0:W].astype(np.float32)
    return c + 0.5, r + 0.5


def _hand_triplet():
    """A triplet whose flows are known: frame 1's pixel (r, c) lies at (r, c + 1) of frame 0
    (u = c + 1.5: exactly on a pixel centre); frame 2's pixel (r, c) lies half a row below its own
    position in frame 1 (v = r + 1: halfway between two pixel centres)."""
    g = torch.Generator().manual_seed(1)
    u, v = _centres()
    uv_10 = np.stack((u + 1.0, v), -1)
    vis_10 = np.ones((H, W), bool)
    vis_10[2, 3] = False  # occluded in frame 0
    uv_21 = np.stack((u, v + 0.5), -1)
    vis_21 = np.ones((H, W), bool)
    batch = {"scene": [0]}
    for t in range(3):
        batch[f"a_ref_{t}"] = torch.rand(1, 3, H, W, generator=g) * 2 - 1
        batch[f"real_{t}"] = torch.rand(1, 3, H, W, generator=g) * 2 - 1
    batch.update(uv_10=torch.from_numpy(uv_10)[None], visible_10=torch.from_numpy(vis_10)[None],
                 uv_21=torch.from_numpy(uv_21)[None], visible_21=torch.from_numpy(vis_21)[None])
    return batch


def _known_outputs(gen):
    """G_B's first two outputs replaced by known images b̂_0, b̂_1 (values c / 10 + r / 100 + k)."""
    r, c = np.mgrid[0:H, 0:W]
    known = [torch.from_numpy(np.stack([c / 10 + r / 100 + k + 0.1 * ch for ch in range(3)]).astype(np.float32))[None]
             for k in (0.0, -0.5)]
    calls = []

    def hook(module, args, out):
        calls.append(1)
        return known[len(calls) - 1] if len(calls) <= 2 else out

    return known, gen.translator.dec_b.register_forward_hook(hook)


def test_config_and_weights():
    cfg = preset("paper", "of_unit")
    m = get_method(cfg)
    assert m.data == "triplets" and not m.time_independent
    assert m.loss_weights(9_999)["vc"] == 0.0 and m.loss_weights(10_000)["vc"] == 50.0
    w = m.loss_weights(10_000)
    assert (w["rec_a"], w["cyc_b"], w["content_a"], w["ssim_ab"], w["ssim_ba"], w["adv_b"]) == (10, 10, 1, 5, 3, 1)
    assert [m.trains_first_frame(s) for s in range(6)] == [True, False, False, True, False, False]
    for key, value in (("vc", "-1"), ("vc_start", "-2"), ("first_frame_every", "-1")):
        with pytest.raises(UserError, match=f"'method.{key}'"):
            validate(override(cfg, [f"method.{key}={value}"]))


def test_a_real_folder_without_sequences_is_refused(train_inputs, tmp_path):
    from sim2real.engine.trainer import Trainer

    scenes, real = train_inputs
    with pytest.raises(UserError, match="has no sequences"):
        Trainer(tiny_config("of_unit"), [scenes], real, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_e_a_gets_the_previous_output_warped_by_the_flow():
    method, gen, _ = _method_and_stages(method__first_frame_every=0)
    batch = _hand_triplet()
    known, h_dec = _known_outputs(gen)
    seen, h_enc = _record_enc_a(gen)
    out = method.translate(gen, batch, 7)
    h_dec.remove()
    h_enc.remove()
    x0, x1, x2 = seen[:3]
    # frame 0: a sequence start, zeros
    assert torch.equal(x0[:, :3], torch.zeros(1, 3, H, W)) and torch.equal(x0[:, 3:], batch["a_ref_0"])
    # frame 1: b̂_0 one pixel to the left; the last column falls outside frame 0, (2, 3) is occluded
    b0 = known[0][0].numpy()
    want1 = np.zeros((3, H, W), np.float32)
    want1[:, :, :-1] = b0[:, :, 1:]
    want1[:, 2, 3] = 0.0
    np.testing.assert_allclose(x1[0, :3].numpy(), want1, atol=1e-6)
    assert want1[0, 5, 4] == pytest.approx(0.5 + 0.05)  # column 5 of b̂_0 at row 5
    assert torch.equal(x1[:, 3:], batch["a_ref_1"])
    # frame 2: the mean of rows r and r + 1 of b̂_1 (the last row at the border: that row)
    b1 = known[1][0].numpy()
    want2 = b1.copy()
    want2[:, :-1] = (b1[:, :-1] + b1[:, 1:]) / 2
    np.testing.assert_allclose(x2[0, :3].numpy(), want2, atol=1e-6)
    assert torch.equal(x2[:, 3:], batch["a_ref_2"])
    # the trained frame is frame 2, translated from x2 against real frame 2
    assert int(out["frame"]) == 2 and torch.equal(out["x_a"], x2) and torch.equal(out["x_b"], batch["real_2"])
    assert torch.equal(out["prev_warped"], x2[:, :3]) and out["vc_mask"].all()
    assert out["b_hat"].requires_grad and not out["prev_warped"].requires_grad


def test_first_frame_steps_start_from_zeros():
    method, gen, dis = _method_and_stages()  # first_frame_every = 3
    batch = _hand_triplet()
    seen, h = _record_enc_a(gen)
    out = method.translate(gen, batch, 3)
    h.remove()
    assert int(out["frame"]) == 0 and "b_hat_prev" not in out
    assert torch.equal(seen[0][:, :3], torch.zeros(1, 3, H, W)) and torch.equal(seen[0][:, 3:], batch["a_ref_0"])
    assert torch.equal(out["x_b"], batch["real_0"]) and not out["vc_mask"].any()
    assert method.gen_losses(dis, batch, out, 3)["vc"].item() == 0.0
    assert int(method.translate(gen, batch, 4)["frame"]) == 2


def test_vc_is_the_masked_l1_to_the_warped_previous_frame():
    method, gen, dis = _method_and_stages(method__first_frame_every=0)
    batch = _hand_triplet()
    batch["visible_21"][0, :4] = False  # rows 0..3 not visible in frame 1
    out = method.translate(gen, batch, 9)
    losses = method.gen_losses(dis, batch, out, 9)
    assert method.loss_weights(9)["vc"] == 50.0 and method.loss_weights(4)["vc"] == 0.0  # tiny: from step 5
    b = out["b_hat"].detach().numpy()[0]
    p = out["prev_warped"].numpy()[0]
    assert np.abs(p[:, :4]).max() == 0.0  # not visible: zeros
    per_pixel = np.abs(b - p).mean(0)  # mean over the 3 channels, in [-1, 1] units
    assert losses["vc"].item() == pytest.approx(per_pixel[4:].mean(), rel=1e-5)
    losses["vc"].backward()  # the gradient reaches the translator through b̂_2 only
    assert any(q.grad is not None and q.grad.abs().sum() > 0 for q in gen.translator.enc_a.parameters())


def _path(caster, n, seed, step_mm=2.0):
    from sim2real.scene.trajectory import linear_path

    cams = linear_path(caster, n, 64, 128, 75.0, step_mm, np.random.default_rng(seed))
    return [caster.render(c) for c in cams]


def test_inference_equals_the_training_chain(procedural_caster):
    """The stateful inference of frames 0, 1, 2 equals the training forward pass of a triplet made
    of the same frames: the no-gradient chain and the trained frame 2, for the same weights."""
    from sim2real.data.tensors import view_tensors
    from sim2real.losses import warp_backward
    from sim2real.render.warp import correspondences

    method, gen, _ = _method_and_stages(method__first_frame_every=0)
    frames = _path(procedural_caster, 3, seed=4)
    batch = {"scene": [0]}
    for t, g in enumerate(frames):
        batch.update(view_tensors([g], str(t)))
        batch[f"real_{t}"] = torch.zeros(1, 3, 64, 128)
        if t:
            uv, vis = correspondences(g, frames[t - 1])
            batch[f"uv_{t}{t - 1}"] = torch.from_numpy(uv)[None]
            batch[f"visible_{t}{t - 1}"] = torch.from_numpy(vis)[None]
    assert batch["visible_10"].float().mean() > 0.5
    with torch.no_grad():
        trained = method.translate(gen, batch, 1)
    gen.eval()
    seq = method.sequence(gen, 0, torch.device("cpu"))
    seen, h = _record_enc_a(gen)
    with torch.inference_mode():
        first = seq.push(frames[:1])  # chunks: the state carries over
        rest = seq.push(frames[1:])
    h.remove()
    assert torch.equal(seen[0][:, :3], torch.zeros(1, 3, 64, 128))  # the sequence start
    want1, _ = warp_backward(first.float(), *(torch.from_numpy(a)[None] for a in correspondences(frames[1], frames[0])))
    torch.testing.assert_close(seen[1][:, :3], want1, atol=1e-6, rtol=0)
    torch.testing.assert_close(seen[2], trained["x_a"], atol=1e-5, rtol=0)
    torch.testing.assert_close(rest[1:], trained["b_hat"], atol=1e-5, rtol=0)
    # the stateless form with that previous frame gives the same frame
    single = {**view_tensors(frames[1:2], "i"), "prev_i": want1, "scene": [0]}
    with torch.inference_mode():
        torch.testing.assert_close(method.translate_frames(gen, single), rest[:1], atol=1e-5, rtol=0)


def _train(tmp_path, name, inputs, iterations, **changes):
    from sim2real.engine.trainer import Trainer

    scenes, real = inputs
    cfg = tiny_config(name, iterations=iterations, checkpoint_every=iterations, image_every=1, **changes)
    trainer = Trainer(cfg, [scenes], real, tmp_path / name, progress=False)
    seen = {}
    trainer.hooks.append(lambda s, v: seen.__setitem__(s, v))
    trainer.train()
    trainer.close()
    return tmp_path / name, seen


def test_trains_resumes_and_translates_a_six_frame_sequence(video_train_inputs, tmp_path, procedural_caster):
    from sim2real.engine.checkpoint import load_checkpoint
    from sim2real.engine.trainer import Trainer
    from sim2real.inference.model import load_run
    from sim2real.presets import config_from_dict

    run, seen = _train(tmp_path, "of_unit", video_train_inputs, 2, method__vc_start=0)
    assert seen[0]["gen/vc"] == 0.0 and seen[1]["gen/vc"] > 0.0  # step 0: a first frame; step 1: the chain
    terms = {k[4:]: v for k, v in seen[1].items() if k.startswith("gen/") and k != "gen/total"}
    state = load_checkpoint(run / "checkpoints" / "last.pt")
    weights = state["loss_schedule"]["weights"]
    assert weights["vc"] == 50.0
    assert seen[1]["gen/total"] == pytest.approx(sum(weights[k] * v for k, v in terms.items()), rel=1e-5)
    assert state["method"] == "of_unit" and state["step"] == 2
    assert not any(k.startswith("textures.") for k in state["gen"])
    assert len(list((run / "samples").glob("*.png"))) == 2
    cfg = config_from_dict(state["config"])
    cfg.iterations = 4
    resumed = Trainer(cfg, None, None, run, resume=run / "checkpoints" / "last.pt", progress=False)
    assert resumed.step == 2
    resumed.train()
    resumed.close()
    model = load_run(run, "cpu")
    assert model.step == 4 and not model.time_independent
    frames = _path(procedural_caster, 6, seed=2)
    chunked = model.sequence(model.scenes[0], batch=4).translate(frames)  # chunks of 4 and 2
    whole = model.sequence(model.scenes[0], batch=8).translate(frames)
    assert len(chunked) == 6 and chunked[0].shape == (64, 128, 3) and chunked[0].dtype == np.uint8
    for a, b in zip(chunked, whole):
        np.testing.assert_array_equal(a, b)  # the state carries across chunks
    assert np.std(np.stack(chunked)) > 1.0


def test_revisit_continues_the_state(video_train_inputs, train_inputs, tmp_path, procedural_caster):
    """1..T, T..1 through one sequence: OF-UNIT's second visit of a view differs from its first
    (history dependence); ours' is identical."""
    from sim2real.inference.model import load_run

    views = _path(procedural_caster, 4, seed=6)
    revisit = views + views[::-1]
    T = len(views)
    for name, inputs in (("of_unit", video_train_inputs), ("ours", train_inputs)):
        run, _ = _train(tmp_path, name, inputs, 1)
        model = load_run(run, "cpu")
        out = model.sequence(model.scenes[0]).translate(revisit)
        diffs = [np.abs(out[t].astype(int) - out[2 * T - 1 - t].astype(int)).max() for t in range(T)]
        if name == "of_unit":
            assert min(diffs) > 0, diffs
            # a new sequence starts from zeros again: the first view alone is the first frame
            np.testing.assert_array_equal(model.translate_gbuffers(model.scenes[0], views[:1])[0], out[0])
        else:
            assert max(diffs) == 0, diffs
