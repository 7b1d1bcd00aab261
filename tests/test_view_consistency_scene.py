"""L_vc on real G-buffers of a procedural scene: a texture-only "translator" (b_hat = the
projected neural texture) is view-consistent by construction, so its loss between two views
is ~0; scaling one view's brightness keeps the angle loss ~0 but not the L1 loss."""

import numpy as np
import pytest
import torch

from sim2real.config import TextureConfig
from sim2real.losses import view_consistency, warp_backward
from sim2real.render.warp import correspondences
from sim2real.scene.trajectory import make_trajectory
from sim2real.texture.neural_texture import NeuralTexture


@pytest.fixture(scope="module")
def two_views(procedural_scene, procedural_caster):
    traj = make_trajectory(procedural_caster, frames=30, height=96, width=160, seed=2)
    gi, gj = procedural_caster.render(traj.cameras[10]), procedural_caster.render(traj.cameras[14])
    uv, visible = correspondences(gi, gj)
    assert visible.mean() > 0.3  # the views overlap
    # a random texture (coarse texels, so bilinear resampling barely blurs it)
    tex = NeuralTexture(len(procedural_scene.objects), procedural_scene.bounds(), None, TextureConfig(size=16))
    with torch.no_grad():
        tex.texture.normal_(0.0, 1.0, generator=torch.Generator().manual_seed(0))

    def project(g):
        t = lambda a: torch.from_numpy(np.ascontiguousarray(a))[None]
        with torch.no_grad():
            return tex(t(g.object_id.astype(np.int64)), t(g.points), t(g.normal))

    return project(gi), project(gj), torch.from_numpy(uv)[None], torch.from_numpy(visible)[None]


def _vc(kind, b_i, b_j, uv, visible):
    warped, mask = warp_backward(b_j, uv, visible)
    assert mask.sum() > 1000
    return view_consistency(kind, b_i, warped, mask).item()


def test_texture_only_translation_is_view_consistent(two_views):
    b_i, b_j, uv, visible = two_views
    assert b_i.std() > 0.2  # a textured image, not a flat one
    angle, l1 = _vc("angle", b_i, b_j, uv, visible), _vc("l1", b_i, b_j, uv, visible)
    assert angle < 0.01 and l1 < 0.01  # radians; [-1, 1] units
    # control: correspondences off by a few pixels give a clearly larger loss
    shifted = uv + torch.tensor([5.0, 0.0])
    assert _vc("angle", b_i, b_j, shifted, visible) > 20 * angle
    assert _vc("l1", b_i, b_j, shifted, visible) > 20 * l1


def test_brightness_change_keeps_angle_loss_but_not_l1(two_views):
    b_i, b_j, uv, visible = two_views
    darker = 0.6 * (b_j + 1) - 1  # 60 % brightness in [0, 1] space, still in [-1, 1]
    angle, angle_dark = _vc("angle", b_i, b_j, uv, visible), _vc("angle", b_i, darker, uv, visible)
    l1, l1_dark = _vc("l1", b_i, b_j, uv, visible), _vc("l1", b_i, darker, uv, visible)
    assert angle_dark < 0.01 and abs(angle_dark - angle) < 1e-4
    # mean |b_i - darker| ~ 0.4 * mean(b + 1) over the matched pixels: far from 0
    expected = (0.4 * (b_i + 1)).abs().mean(1)[visible].mean().item()
    assert l1_dark > 20 * l1 and l1_dark == pytest.approx(expected, rel=0.1)
