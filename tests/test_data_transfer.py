"""The loader's transfer format and limits: compact dtypes that widen back within stated errors,
the shared-memory check, and the one worker rule."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sim2real import threads
from sim2real.data.shm import loader_workers_for_shm
from sim2real.data.tensors import FP16_POINTS_MAX_MM, compact, widen
from sim2real.errors import UserError

MiB = 2**20


def _sample(max_mm: float) -> dict:
    g = torch.Generator().manual_seed(0)
    pix = torch.randint(0, 256, (3, 16, 32), generator=g, dtype=torch.uint8)
    normal = torch.nn.functional.normalize(torch.randn(16, 32, 3, generator=g), dim=-1)
    return {
        "step": torch.tensor(3), "scene": torch.tensor(0),
        "real": pix.to(torch.float32) / 127.5 - 1.0,  # as data.real.to_network maps an 8-bit crop
        "a_ref_i": torch.rand(3, 16, 32, generator=g) * 2 - 1,
        "object_id_i": torch.randint(-1, 5, (16, 32), generator=g),
        "points_i": (torch.rand(16, 32, 3, generator=g) * 2 - 1) * max_mm,
        "normal_i": normal,
        "uv_ij": torch.rand(16, 32, 2, generator=g) * 512,
        "visible_ij": torch.rand(16, 32, generator=g) > 0.5,
    }, pix


def test_compact_widens_back_within_the_stated_errors():
    s, pix = _sample(FP16_POINTS_MAX_MM * 0.999)
    c = compact(s)
    assert c["real"].dtype == torch.uint8 and torch.equal(c["real"], pix)
    assert c["object_id_i"].dtype == torch.int16 and c["points_i"].dtype == torch.float16
    w = widen(c)
    assert torch.equal(w["real"], s["real"])  # bit for bit: the 8-bit crop is the source
    assert torch.equal(w["object_id_i"], s["object_id_i"]) and w["object_id_i"].dtype == torch.int64
    # the 1 mm rule: fp16 points under 1024 mm are within 0.25 mm (half a unit in the last place)
    assert (w["points_i"] - s["points_i"]).abs().max() <= 0.25
    assert (w["normal_i"] - s["normal_i"]).abs().max() <= 2**-11
    assert (w["a_ref_i"] - s["a_ref_i"]).abs().max() <= 2**-11
    assert torch.equal(w["uv_ij"], s["uv_ij"]) and torch.equal(w["visible_ij"], s["visible_ij"])
    before = sum(v.numel() * v.element_size() for v in s.values())
    after = sum(v.numel() * v.element_size() for v in c.values())
    assert after < 0.5 * before


def test_points_of_a_large_scene_stay_fp32():
    s, _ = _sample(3000.0)
    c = compact(s)
    assert c["points_i"].dtype == torch.float32 and torch.equal(widen(c)["points_i"], s["points_i"])


def test_shared_memory_check():
    per = 2 * 8 * MiB  # prefetch 2 of 8 MiB samples
    assert loader_workers_for_shm(3, 2, 8 * MiB, automatic=False, free=64 * MiB) == 3  # 48 MiB <= 0.8 * 64
    assert loader_workers_for_shm(7, 2, 8 * MiB, automatic=True, free=64 * MiB) == 3  # fewer, automatically
    with pytest.raises(UserError) as e:
        loader_workers_for_shm(7, 2, 8 * MiB, automatic=False, free=64 * MiB)
    msg = str(e.value)
    assert "\n" not in msg and "--shm-size" in msg and "data.workers=3" in msg and f"{7 * per // MiB} MiB" in msg
    with pytest.raises(UserError, match="data.workers=0"):
        loader_workers_for_shm(1, 2, 8 * MiB, automatic=True, free=8 * MiB)  # not even one worker fits
    assert loader_workers_for_shm(0, 2, 8 * MiB, automatic=False, free=0) == 0  # in-process loading


@pytest.mark.parametrize("cores,ranks,jobs,reserve,expected", [
    (16, None, None, 0, 16), (16, None, None, 1, 15), (96, None, None, 0, 96), (16, "8", None, 1, 1),
    (64, "8", None, 1, 7), (16, None, 5, 0, 5), (1, None, None, 1, 1)])
def test_worker_rule(monkeypatch, cores, ranks, jobs, reserve, expected):
    monkeypatch.setattr(threads, "usable_cores", lambda: cores)
    if ranks is None:
        monkeypatch.delenv("LOCAL_WORLD_SIZE", raising=False)
    else:
        monkeypatch.setenv("LOCAL_WORLD_SIZE", ranks)
    assert threads.worker_count(jobs=jobs, reserve=reserve) == expected


def test_translate_ray_casting_uses_every_core(monkeypatch):
    from sim2real.inference import frames

    monkeypatch.setattr(threads, "usable_cores", lambda: 32)
    monkeypatch.setattr(frames, "usable_cores", lambda: 32)
    monkeypatch.delenv("LOCAL_WORLD_SIZE", raising=False)

    class Cam:
        height, width = 256, 512

    assert frames.auto_workers([Cam()] * 100) == 32  # was capped at 4
    assert frames.auto_workers([Cam()] * 2) == 1  # too few rays for a pool


def test_a_ref_on_the_device_equals_the_reference_rendering(procedural_caster):
    """a_ref rendered from the transferred inputs (torch) against render/reference.py (numpy),
    on two ray-cast views: the same formula to float rounding, and within fp16's rounding of its
    inputs when they travel compact."""
    from sim2real.data.tensors import complete_on_device, view_inputs
    from sim2real.render.reference import reference_rendering
    from sim2real.scene.trajectory import sample_poses

    gbuffers = [procedural_caster.render(c) for c in sample_poses(procedural_caster, 2, 48, 96, 75.0, seed=4)]
    want = torch.from_numpy(np.stack([reference_rendering(g).transpose(2, 0, 1) for g in gbuffers]) * 2 - 1)
    inputs = view_inputs(gbuffers, "i", max_objects=len(gbuffers[0].classes) + 2)  # padded class list
    exact = complete_on_device(inputs)
    assert set(exact) == {"a_ref_i", "object_id_i", "points_i", "normal_i"}
    assert (exact["a_ref_i"] - want).abs().max() <= 1e-5
    assert want.std() > 0.1  # a rendered view, not an empty one
    via_compact = complete_on_device(widen(compact(inputs)))
    assert (via_compact["a_ref_i"] - want).abs().max() <= 4e-3  # about one 8-bit level
