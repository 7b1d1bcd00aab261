"""Ground-truth export: everything written is read back and checked against the G-buffers."""

import json

import numpy as np
import pytest
from PIL import Image

from sim2real.errors import UserError
from sim2real.inference.export import GroundTruthWriter, export_ground_truth
from sim2real.inference.gt_formats import (
    FLO_MAGIC,
    depth_to_png16,
    read_depth_png,
    read_flo,
    read_tum_poses,
    read_tum_poses_with_time,
    write_flo,
)
from sim2real.render.warp import flow as gt_flow
from sim2real.scene.camera import pixel_centres
from sim2real.scene.scene import CLASSES, LABEL_PALETTE

T = 6


@pytest.fixture(scope="module")
def gbuffers(procedural_caster):
    from sim2real.scene.trajectory import make_trajectory

    # The first T frames of a 30-frame sweep: neighbours overlap (a 6-frame sweep jumps ~30 mm).
    traj = make_trajectory(procedural_caster, frames=30, height=48, width=80, seed=3)
    return [procedural_caster.render(c) for c in traj.cameras[:T]]


@pytest.fixture(scope="module")
def export(gbuffers, tmp_path_factory):
    out = tmp_path_factory.mktemp("gt")
    (out / "frames").mkdir()
    rel = []
    for i in range(T):
        Image.fromarray(np.full((48, 80, 3), 10 * i, np.uint8)).save(out / "frames" / f"{i:06d}.png")
        rel.append(f"frames/{i:06d}.png")
    manifest = export_ground_truth(gbuffers, out, fps=5.0, rgb_frames_rel=rel)
    return out, manifest


def _unproject(depth, K, c2w, centres):
    """World points of a z-depth map; ``centres`` (H, W, 2) are the pixel coordinates used with K."""
    h, w = depth.shape
    d_cam = np.concatenate([centres, np.ones((h, w, 1))], axis=-1) @ np.linalg.inv(K).T
    pc = d_cam * depth[..., None].astype(np.float64)
    return pc @ c2w[:3, :3].T + c2w[:3, 3]


def _png16(path) -> np.ndarray:
    """A PNG's pixels, checked to be stored as 16-bit greyscale (IHDR: bit depth 16, colour type 0)
    from the file's header: Pillow 10.0 reads such a file as int32."""
    header = path.read_bytes()[:26]  # 8-byte signature, IHDR length, type, width, height, depth, colour
    assert header[12:16] == b"IHDR" and header[24] == 16 and header[25] == 0
    return np.array(Image.open(path)).astype(np.uint16)


def test_depth_round_trip(export, gbuffers):
    out, _ = export
    for i, g in enumerate(gbuffers):
        png = read_depth_png(out / "depth" / f"{i:06d}.png")
        assert png.shape == g.depth.shape
        assert np.array_equal(png > 0, g.mask)
        assert np.abs(png - g.depth)[g.mask].max() <= 0.05 + 1e-4
        npy = np.load(out / "depth_npy" / f"{i:06d}.npy")
        assert npy.dtype == np.float32 and np.array_equal(npy, np.where(g.mask, g.depth, 0))
        _png16(out / "depth" / f"{i:06d}.png")


def test_depth_png_saturates_and_never_loses_a_surface():
    q = depth_to_png16(np.array([[0.0, 0.01, 1.04, 6553.5, 7000.0, np.nan]]), 10.0)
    assert q.tolist() == [[0, 1, 10, 65535, 65535, 0]]


def test_flow_round_trip_and_masks(export, gbuffers):
    out, manifest = export
    assert sorted(p.name for p in (out / "flow").iterdir()) == [f"{i:06d}.flo" for i in range(T - 1)]
    for i in range(T - 1):
        f, vis = gt_flow(gbuffers[i], gbuffers[i + 1])
        got = read_flo(out / "flow" / f"{i:06d}.flo")
        assert got.dtype == np.float32 and np.array_equal(got, f)
        mask = np.array(Image.open(out / "flow_mask" / f"{i:06d}.png"))
        assert mask.dtype == np.uint8 and set(np.unique(mask)) <= {0, 255}
        assert np.array_equal(mask == 255, vis)
        assert 0.3 < vis.mean()  # a smooth trajectory: most of frame t is seen again in t+1
    raw = (out / "flow" / "000000.flo").read_bytes()
    assert raw[:4] == b"PIEH"  # the Middlebury magic 202021.25 as little-endian float
    assert np.frombuffer(raw[:4], "<f4")[0] == FLO_MAGIC
    assert np.frombuffer(raw[4:12], "<i4").tolist() == [80, 48]


def test_flo_writer_layout(tmp_path):
    f = np.arange(3 * 4 * 2, dtype=np.float32).reshape(3, 4, 2)
    write_flo(tmp_path / "a.flo", f)
    raw = (tmp_path / "a.flo").read_bytes()
    assert len(raw) == 12 + 3 * 4 * 8
    assert np.frombuffer(raw[12:], "<f4")[:4].tolist() == [0, 1, 2, 3]  # u00 v00 u01 v01: row-major, interleaved
    assert np.array_equal(read_flo(tmp_path / "a.flo"), f)
    (tmp_path / "bad.flo").write_bytes(b"\0" * 20)
    with pytest.raises(UserError):
        read_flo(tmp_path / "bad.flo")


def test_labels(export, gbuffers):
    out, _ = export
    for i, g in enumerate(gbuffers):
        lab = np.array(Image.open(out / "labels" / f"{i:06d}.png"))
        assert lab.dtype == np.uint8
        ci = g.class_index()
        assert np.array_equal(lab, np.where(ci >= 0, ci, 255))
        col = np.array(Image.open(out / "labels_color" / f"{i:06d}.png").convert("RGB"))
        for k, c in enumerate(CLASSES):
            if (lab == k).any():
                assert (col[lab == k] == LABEL_PALETTE[c]).all()
    assert CLASSES.index("liver") == 0 and CLASSES.index("gallbladder") == 4


def test_intrinsics(export, gbuffers):
    out, _ = export
    intr = json.loads((out / "intrinsics.json").read_text())
    K = gbuffers[0].K
    assert np.array_equal(np.array(intr["K"]), K)
    assert (intr["fx"], intr["fy"], intr["cx"], intr["cy"]) == (K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    assert (intr["width"], intr["height"]) == (80, 48) and intr["constant"] and "per_frame" not in intr
    assert np.allclose(np.array(intr["K_integer_centres"])[:2, 2], K[:2, 2] - 0.5)


def test_poses_and_depth_reproduce_surface_points(export, gbuffers):
    out, _ = export
    intr = json.loads((out / "intrinsics.json").read_text())
    K = np.array(intr["K"])
    poses = read_tum_poses(out / "poses_tum_mm.txt")
    assert len(poses) == T
    centres = pixel_centres(48, 80)
    ray_len = np.linalg.norm(np.concatenate([centres, np.ones((48, 80, 1))], -1) @ np.linalg.inv(K).T, axis=-1)
    for i, g in enumerate(gbuffers):
        m = g.mask
        pts = _unproject(read_depth_png(out / "depth" / f"{i:06d}.png"), K, poses[i], centres)
        err = np.linalg.norm(pts - g.points, axis=-1)
        # 0.05 mm of depth quantisation along the ray (longer than z by ray_len), plus float32 noise.
        assert (err[m] <= 0.05 * ray_len[m] + 2e-3).all(), err[m].max()
        pts = _unproject(np.load(out / "depth_npy" / f"{i:06d}.npy"), K, poses[i], centres)
        assert np.linalg.norm(pts - g.points, axis=-1)[m].max() < 2e-3
    # The pose file is also a sim2real trajectory file.
    from sim2real.scene.trajectory import Trajectory

    traj = Trajectory.load(out / "poses_tum_mm.txt")
    assert traj.fps == 5.0 and np.allclose(traj.cameras[2].world_to_camera, gbuffers[2].world_to_camera, atol=1e-6)


def test_tum_folder(export, gbuffers):
    out, _ = export
    tum = out / "tum"
    rows = [l.split() for l in (tum / "associations.txt").read_text().splitlines() if l and not l.startswith("#")]
    assert len(rows) == T
    gt = read_tum_poses_with_time(tum / "groundtruth.txt")
    calib = [l for l in (tum / "calibration.txt").read_text().splitlines() if not l.startswith("#")]
    fx, fy, cx, cy = map(float, calib[0].split())
    K_tum = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    # TUM tools put pixel centres at integer coordinates: u = column.
    v, u = np.meshgrid(np.arange(48.0), np.arange(80.0), indexing="ij")
    integer_centres = np.stack([u, v], -1)
    for i, (t_rgb, rgb, t_d, dep) in enumerate(rows):
        assert float(t_rgb) == float(t_d) == pytest.approx(i / 5.0)
        assert (tum / rgb).is_file() and (tum / dep).is_file()
        assert (tum / rgb).read_bytes() == (out / "frames" / f"{i:06d}.png").read_bytes()
        g = gbuffers[i]
        raw = _png16(tum / dep)
        depth_m = raw / 5000.0
        assert np.abs(depth_m * 1000 - g.depth)[g.mask].max() <= 0.1 + 1e-4  # 0.2 mm steps
        assert np.array_equal(raw > 0, g.mask)
        ts, c2w_m = gt[i]
        assert ts == pytest.approx(i / 5.0)
        c2w = np.linalg.inv(g.world_to_camera)
        assert np.allclose(c2w_m[:3, 3], c2w[:3, 3] / 1000.0, atol=1e-8)
        assert np.allclose(c2w_m[:3, :3], c2w[:3, :3], atol=1e-7)
        # A TUM reader (metres, integer pixel centres) reconstructs the surface.
        pts_m = _unproject(depth_m, K_tum, c2w_m, integer_centres)
        assert np.abs(pts_m * 1000 - g.points)[g.mask].max() < 0.2
    for name in ("rgb.txt", "depth.txt"):
        lines = [l for l in (tum / name).read_text().splitlines() if not l.startswith("#")]
        assert len(lines) == T and all((tum / l.split()[1]).is_file() for l in lines)
    assert (out / "ground_truth.json").is_file()


def test_export_refuses_to_mix_and_without_rgb_writes_reference(gbuffers, export, tmp_path):
    out, _ = export
    with pytest.raises(UserError, match="already holds"):
        export_ground_truth(gbuffers, out)
    m = export_ground_truth(gbuffers[:2], tmp_path / "new")
    assert m["frames"] == 2 and m["rgb_frames"] is None
    img = np.array(Image.open(tmp_path / "new" / "tum" / "rgb" / "000000.png"))
    assert img.shape == (48, 80, 3) and img.dtype == np.uint8 and img.max() > 0
    with pytest.raises(UserError, match="does not exist"):
        export_ground_truth(gbuffers[:2], tmp_path / "other", rgb_frames_rel=["a.png", "b.png"])


def _trajectory_cameras(caster, frames, height=48, width=80):
    from sim2real.scene.trajectory import make_trajectory

    return make_trajectory(caster, frames=30, height=height, width=width, seed=3).cameras[:frames]


def test_streaming_writer_writes_as_frames_arrive_and_keeps_few(procedural_caster, tmp_path):
    """With one thread at most two frames are in flight: after 8 of 12 frames, frames 0-4 are on
    disk (the manifest is not), and of the 12 G-buffers made on the fly at most four are alive."""
    import gc
    import weakref

    out = tmp_path / "gt"
    alive = []
    with GroundTruthWriter(out, fps=5.0, threads=1) as writer:
        for i, cam in enumerate(_trajectory_cameras(procedural_caster, 12)):
            g = procedural_caster.render(cam)
            alive.append(weakref.ref(g))
            writer.add(g)
            del g
            if i == 7:  # frames 0..6 submitted, at most two of them still pending
                assert all((out / "depth" / f"{k:06d}.png").is_file() for k in range(5))
                assert not (out / "ground_truth.json").exists()
        gc.collect()
        assert sum(r() is not None for r in alive) <= 4
        manifest = writer.close()
    assert manifest["frames"] == 12 and manifest["flow_frames"] == 11
    assert len(list((out / "flow").glob("*.flo"))) == 11 and len(list((out / "tum" / "rgb").glob("*.png"))) == 12


def test_streaming_writer_matches_the_views_it_was_given(procedural_caster, tmp_path):
    """Frame by frame, in several threads, each file belongs to its own frame: depth and flow read
    back equal what the G-buffers give directly."""
    gb = [procedural_caster.render(c) for c in _trajectory_cameras(procedural_caster, 7)]
    with GroundTruthWriter(tmp_path / "gt", fps=2.0, threads=3) as writer:
        for g in gb:
            writer.add(g)
        writer.close()
    for i, g in enumerate(gb):
        depth = np.load(tmp_path / "gt" / "depth_npy" / f"{i:06d}.npy")
        assert np.array_equal(depth, np.where(g.mask, g.depth, 0).astype(np.float32))
        if i + 1 < len(gb):
            assert np.allclose(read_flo(tmp_path / "gt" / "flow" / f"{i:06d}.flo"), gt_flow(g, gb[i + 1])[0])


def test_streaming_writer_errors(procedural_caster, tmp_path, monkeypatch):
    import sim2real.inference.export as export_mod

    cams = _trajectory_cameras(procedural_caster, 5)
    gb = [procedural_caster.render(c) for c in cams]
    with pytest.raises(UserError, match="nothing to export"):
        GroundTruthWriter(tmp_path / "empty").close()
    with GroundTruthWriter(tmp_path / "size") as writer:
        writer.add(gb[0])
        with pytest.raises(UserError, match="frame 1 is 24x40, frame 0 is 48x80; a video has one size"):
            writer.add(procedural_caster.render(_trajectory_cameras(procedural_caster, 1, 24, 40)[0]))
    # The video's RGB frames must exist when the export closes; no manifest otherwise.
    with pytest.raises(UserError, match="does not exist"):
        with GroundTruthWriter(tmp_path / "rgb", rgb_frames_rel=["a.png", "b.png"]) as writer:
            writer.add(gb[0])
            writer.add(gb[1])
            writer.close()
    assert not (tmp_path / "rgb" / "ground_truth.json").exists()
    # A failed write in a thread reaches the caller; no manifest.
    calls = []

    def failing_write_flo(path, flow):
        calls.append(path)
        if len(calls) == 2:
            raise OSError("No space left on device")
        write_flo(path, flow)

    monkeypatch.setattr(export_mod, "write_flo", failing_write_flo)
    with pytest.raises(OSError, match="No space left"):
        with GroundTruthWriter(tmp_path / "full", threads=1) as writer:
            for g in gb:
                writer.add(g)
            writer.close()
    assert not (tmp_path / "full" / "ground_truth.json").exists()
