"""Long-range point tracks of the ground-truth export, checked against geometry computed here:
a plane with a box on it, seen by a camera that moves past the box, so that the box hides
different floor points in different frames (a slab test, independent of Embree and of the
export's depth-buffer rule, says which)."""

import json

import numpy as np
import pytest
from PIL import Image
from conftest import BOX_HI, BOX_LO, segment_hits_box

import sim2real.inference.tracks as tracks_module
from sim2real.inference.export import export_ground_truth
from sim2real.inference.gt_formats import read_flo
from sim2real.render.raycast import RayCaster
from sim2real.scene.camera import Camera, intrinsics_from_fov, look_at

H, W, T = 96, 128, 6


@pytest.fixture(scope="module")
def exported(hiding_scene, tmp_path_factory):
    caster = RayCaster(hiding_scene)
    K = intrinsics_from_fov(W, H, 70)
    xs = np.linspace(-70, 70, T)
    cams = [Camera(K, look_at([x, 10.0, 95.0], [0.0, 0.0, 0.0], [0, 1, 0]), H, W) for x in xs]
    gbuffers = [caster.render(c) for c in cams]
    out = tmp_path_factory.mktemp("tracks")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tracks_module, "GRID_STEP", 4)  # 768 grid points a frame, 4,608 in all: thinned to 1,152
        manifest = export_ground_truth(gbuffers, out)
    return out, manifest, cams, gbuffers, dict(np.load(out / "tracks" / "tracks.npz"))


def _project(X, cam):
    pc = X @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3]
    return (pc @ cam.K.T)[:, :2] / pc[:, 2:3], pc[:, 2]


def test_arrays_and_manifest(exported):
    out, manifest, _, _, d = exported
    n = len(d["query_frame"])
    assert n == 1152 and n <= tracks_module.TRACKS_BUDGET  # 4,608 grid points, every fourth kept
    assert d["tracks"].shape == (n, T, 2) and d["tracks"].dtype == np.float32
    assert d["visible"].shape == (n, T) and d["visible"].dtype == bool
    assert d["points_mm"].shape == (n, 3) and d["labels"].shape == (n,) and list(d["size"]) == [W, H]
    assert np.bincount(d["query_frame"], minlength=T).tolist() == [192] * T  # every frame the same share
    assert manifest["files"]["tracks"] == "tracks/tracks.npz"
    assert json.loads((out / "ground_truth.json").read_text())["files"]["tracks"] == "tracks/tracks.npz"
    assert "occluded = ~visible" in (out / "tracks" / "README.txt").read_text()


def test_queries_are_surface_points_at_pixel_centres_with_their_class(exported):
    _, _, _, gbuffers, d = exported
    for n, i in enumerate(d["query_frame"]):
        assert d["visible"][n, i]
        u, v = d["tracks"][n, i]
        col, row = int(np.floor(u)), int(np.floor(v))
        assert abs(u - (col + 0.5)) < 1e-3 and abs(v - (row + 0.5)) < 1e-3
        assert np.abs(d["points_mm"][n] - gbuffers[i].points[row, col]).max() < 1e-3
    on_box = np.all((d["points_mm"] > BOX_LO - 1e-3) & (d["points_mm"] < BOX_HI + 1e-3), axis=1)
    assert on_box.sum() > 20 and (~on_box).sum() > 500
    assert set(d["labels"][on_box]) == {4} and set(d["labels"][~on_box]) == {0}  # gallbladder, liver


def test_positions_are_the_projections_and_visibility_is_the_line_of_sight(exported):
    _, _, cams, gbuffers, d = exported
    X = d["points_mm"].astype(np.float64)
    floor = d["labels"] == 0
    hidden_total = behind_total = 0
    for j, cam in enumerate(cams):
        uv, z = _project(X, cam)
        front = z > 0
        assert np.abs(d["tracks"][front, j] - uv[front]).max() < 1e-3  # hidden or not, inside or not
        assert np.isnan(d["tracks"][~front, j]).all()  # behind the camera
        behind_total += int((~front).sum())
        inside = (z > 0) & (uv[:, 0] >= 1) & (uv[:, 0] < W - 1) & (uv[:, 1] >= 1) & (uv[:, 1] < H - 1)
        hidden = segment_hits_box(X, cam.position, BOX_LO + 0.5, BOX_HI - 0.5)
        clear = ~segment_hits_box(X, cam.position, BOX_LO - 1.5, BOX_HI + 1.5)
        assert not (d["visible"][:, j] & floor & hidden).any()
        assert d["visible"][floor & inside & clear, j].all()
        outside = ~((uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H))
        assert not d["visible"][outside, j].any()
        hidden_total += int((floor & inside & hidden).sum())
        seen = d["visible"][:, j] & floor  # where seen, the frame's own ray-cast surface is that point
        col, row = np.floor(uv[seen]).astype(int).T
        assert np.linalg.norm(gbuffers[j].points[row, col] - X[seen], axis=1).max() < 2 * z[seen].max() / cam.K[0, 0]
    assert hidden_total > 30  # the box really hides floor points, in several frames


def test_next_frame_agrees_with_the_flow(exported):
    out, _, _, gbuffers, d = exported
    for n, i in enumerate(d["query_frame"]):
        if i == T - 1:
            continue
        u, v = d["tracks"][n, i]
        col, row = int(u), int(v)
        mask = np.asarray(Image.open(out / "flow_mask" / f"{i:06d}.png")) > 0
        assert d["visible"][n, i + 1] == mask[row, col]
        if mask[row, col]:
            f = read_flo(out / "flow" / f"{i:06d}.flo")[row, col]
            assert np.abs(d["tracks"][n, i + 1] - (u + f[0], v + f[1])).max() < 1e-3


def test_each_frame_projects_with_its_own_intrinsics(exported, tmp_path):
    import dataclasses

    _, _, cams, gbuffers, _ = exported
    K1 = cams[1].K.copy()
    K1[0, 0] *= 1.5  # frame 1 zooms in horizontally
    export_ground_truth([gbuffers[0], dataclasses.replace(gbuffers[1], K=K1)], tmp_path)
    d = np.load(tmp_path / "tracks" / "tracks.npz")
    X = d["points_mm"].astype(np.float64)
    zoomed = dataclasses.replace(cams[1], K=K1)
    uv, z = _project(X, zoomed)
    assert (z > 0).all() and np.abs(d["tracks"][:, 1] - uv).max() < 1e-3
    assert np.abs(_project(X, cams[1])[0] - uv).max() > 1.0  # frame 1's original K would be pixels off
