"""The COLMAP model of the ground-truth export, read back with a parser written here from COLMAP's
format description (colmap.github.io/format.html), independent of the writer, and checked against
the ray-cast G-buffers: pose convention, pixel-centre convention, points and colours."""

import dataclasses

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from sim2real.inference.export import export_ground_truth

T = 5


def _rows(path):
    return [l for l in path.read_text().splitlines() if not l.startswith("#")]


def _read(sparse):
    cams = {}
    for l in _rows(sparse / "cameras.txt"):
        cid, model, w, h, *params = l.split()
        assert model == "PINHOLE"
        fx, fy, cx, cy = map(float, params)
        cams[int(cid)] = (int(w), int(h), np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]))
    lines = _rows(sparse / "images.txt")
    images = {}
    for head, obs in zip(lines[0::2], lines[1::2]):
        iid, qw, qx, qy, qz, tx, ty, tz, cid, name = head.split()
        R = Rotation.from_quat([float(qx), float(qy), float(qz), float(qw)]).as_matrix()  # scipy: scalar last
        o = obs.split()
        xy = np.array([[float(o[k]), float(o[k + 1])] for k in range(0, len(o), 3)]).reshape(-1, 2)
        pid = [int(o[k + 2]) for k in range(0, len(o), 3)]
        images[int(iid)] = (R, np.array([float(tx), float(ty), float(tz)]), int(cid), name, xy, pid)
    points = {}
    for l in _rows(sparse / "points3D.txt"):
        v = l.split()
        track = list(zip(map(int, v[8::2]), map(int, v[9::2])))
        points[int(v[0])] = (np.array(v[1:4], float), np.array(v[4:7], int), float(v[7]), track)
    return cams, images, points


@pytest.fixture(scope="module")
def exported(procedural_caster, tmp_path_factory):
    from sim2real.scene.trajectory import make_trajectory

    traj = make_trajectory(procedural_caster, frames=30, height=40, width=64, seed=5)
    gbuffers = [procedural_caster.render(c) for c in traj.cameras[:T]]
    out = tmp_path_factory.mktemp("colmap")
    (out / "frames").mkdir()
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (40, 64, 3), dtype=np.uint8) for _ in range(T)]
    for i, f in enumerate(frames):
        Image.fromarray(f).save(out / "frames" / f"{i:06d}.png")
    export_ground_truth(gbuffers, out, fps=5.0, rgb_frames_rel=[f"frames/{i:06d}.png" for i in range(T)])
    return out / "colmap", gbuffers, frames


def test_cameras_and_poses_are_the_g_buffers(exported):
    folder, gbuffers, frames = exported
    cams, images, _ = _read(folder / "sparse" / "0")
    assert list(cams) == [1] and sorted(images) == list(range(1, T + 1))
    w, h, K = cams[1]
    assert (w, h) == (64, 40) and np.allclose(K, gbuffers[0].K, atol=1e-8)  # pixel centres at +0.5 in both
    for i, g in enumerate(gbuffers):
        R, t, cid, name, _, _ = images[i + 1]
        assert cid == 1 and name == f"{i:06d}.png"
        assert np.allclose(R, g.world_to_camera[:3, :3], atol=1e-9) and np.allclose(t, g.world_to_camera[:3, 3], atol=1e-6)
        assert np.array_equal(np.asarray(Image.open(folder / "images" / name)), frames[i])


def test_points_are_surface_points_seen_where_listed(exported):
    folder, gbuffers, frames = exported
    cams, images, points = _read(folder / "sparse" / "0")
    K = cams[1][2]
    n_obs = 0
    for iid, (R, t, _, _, xy, pid) in images.items():
        g = gbuffers[iid - 1]
        assert len(pid) > 0
        for (x, y), p in zip(xy, pid):
            X, rgb, err, track = points[p]
            assert track == [(iid, pid.index(p))] and err == 0
            col, row = int(x - 0.5), int(y - 0.5)
            assert (x, y) == (col + 0.5, row + 0.5) and g.mask[row, col]
            assert np.abs(X - g.points[row, col]).max() < 1e-3  # mm, the ray-cast hit (4 decimals written)
            uvw = K @ (R @ X + t)  # COLMAP's projection lands on the pixel the point was listed at
            assert np.abs(uvw[:2] / uvw[2] - (x, y)).max() < 1e-3
            assert uvw[2] == pytest.approx(g.depth[row, col], abs=1e-3)
            assert np.array_equal(rgb, frames[iid - 1][row, col])
            n_obs += 1
    assert n_obs == len(points)  # every point is observed exactly once


def test_intrinsics_that_vary_give_a_camera_per_frame_and_points_take_a_ref(exported, tmp_path):
    from sim2real.render.reference import reference_rendering, to_uint8

    _, gbuffers, _ = exported
    g0, g1 = gbuffers[:2]
    K1 = g1.K.copy()
    K1[0, 0] *= 1.5
    export_ground_truth([g0, dataclasses.replace(g1, K=K1)], tmp_path)  # no video frames: a_ref
    cams, images, points = _read(tmp_path / "colmap" / "sparse" / "0")
    assert sorted(cams) == [1, 2] and np.allclose(cams[2][2], K1) and np.allclose(cams[1][2], g0.K)
    assert [images[i][2] for i in (1, 2)] == [1, 2]
    a_ref = to_uint8(reference_rendering(g0))
    R, t, _, _, xy, pid = images[1]
    for (x, y), p in zip(xy, pid):
        assert np.array_equal(points[p][1], a_ref[int(y), int(x)])
    assert "one camera per frame" in (tmp_path / "colmap" / "README.txt").read_text()


def test_pycolmap_reads_the_model(exported):
    import pycolmap  # a test dependency

    folder, gbuffers, _ = exported
    rec = pycolmap.Reconstruction(str(folder / "sparse" / "0"))
    assert rec.num_images() == T and rec.num_cameras() == 1
    _, _, points = _read(folder / "sparse" / "0")
    assert rec.num_points3D() == len(points)
    for image_id, image in rec.images.items():
        w2c = gbuffers[image_id - 1].world_to_camera
        assert np.allclose(image.cam_from_world().matrix(), w2c[:3], atol=1e-6)
