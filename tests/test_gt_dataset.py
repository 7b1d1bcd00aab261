"""GroundTruthDataset reads an export back as tensors, checked against geometry worked out here: a
camera looking straight down at a floor (z = 0) with a box on it (top at z = 30), stepping 6 mm
along the world x axis per frame, so that the floor's depth is the camera's height and its flow
the pinhole formula's -fx * step / depth in every frame."""

import pickle

import numpy as np
import pytest
import torch
from conftest import BOX_HI
from PIL import Image

from sim2real.errors import UserError
from sim2real.inference.export import export_ground_truth
from sim2real.inference.gt_dataset import FIELDS, GroundTruthDataset
from sim2real.render.raycast import RayCaster
from sim2real.render.reference import reference_rendering, to_uint8
from sim2real.scene.camera import Camera, intrinsics_from_fov, look_at

H, W, T, HEIGHT, STEP = 48, 64, 4, 95.0, 6.0


@pytest.fixture(scope="module")
def exported(hiding_scene, tmp_path_factory):
    caster = RayCaster(hiding_scene)
    K = intrinsics_from_fov(W, H, 60)
    cams = [Camera(K, look_at([-9.0 + STEP * i, 0.0, HEIGHT], [-9.0 + STEP * i, 0.0, 0.0], [0, 1, 0]), H, W)
            for i in range(T)]
    gbuffers = [caster.render(c) for c in cams]
    out = tmp_path_factory.mktemp("video")
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (T, H, W, 3), dtype=np.uint8)
    (out / "frames").mkdir()
    (out / "ground_truth").mkdir()  # the frames are named relative to it
    for i, f in enumerate(frames):
        Image.fromarray(f).save(out / "frames" / f"{i:06d}.png")
    export_ground_truth(gbuffers, out / "ground_truth", fps=5.0, rgb_frames_rel=[f"../frames/{i:06d}.png" for i in range(T)])
    return out, cams, gbuffers, frames


def test_samples_hold_the_frames_and_the_geometry(exported):
    out, cams, gbuffers, frames = exported
    data = GroundTruthDataset(out)
    assert len(data) == T and data.size == (H, W) and data.fps == 5.0
    assert data.class_names == {0: "liver", 4: "gallbladder"}
    fx = cams[0].K[0, 0]
    step_cam = cams[0].world_to_camera[:3, :3] @ np.array([STEP, 0.0, 0.0])  # the camera's step in its own axes
    assert abs(abs(step_cam[0]) - STEP) < 1e-9 and abs(step_cam[1]) < 1e-9  # straight down: x along x
    for i in range(T):
        s = data[i]
        assert list(s) == list(FIELDS)
        assert s["image"].shape == (3, H, W) and s["image"].dtype == torch.float32
        assert torch.equal(s["image"], torch.from_numpy(frames[i]).permute(2, 0, 1).float() / 255)
        floor, box = s["labels"] == 0, s["labels"] == 4
        assert s["labels"].dtype == torch.int64 and (floor | box).all() and box.sum() > 20 and floor.sum() > 1000
        assert s["depth"].shape == (1, H, W) and s["depth"].dtype == torch.float32
        depth = s["depth"][0]
        assert torch.allclose(depth[floor], torch.tensor(HEIGHT), atol=1e-3)
        top = box & ((depth - (HEIGHT - BOX_HI[2])).abs() < 1e-3)  # the box's top; its sides lie deeper
        assert top.sum() > 20 and (depth[box] > HEIGHT - BOX_HI[2] - 1e-3).all() and (depth[box] < HEIGHT).all()
        assert torch.allclose(s["K"], torch.tensor(cams[i].K, dtype=torch.float32))
        assert torch.allclose(s["camera_to_world"], torch.tensor(np.linalg.inv(cams[i].world_to_camera),
                                                                 dtype=torch.float32), atol=1e-4)
        assert s["index"].item() == i
        if i + 1 < T:  # a fixed point's x in the camera falls by the step; u by fx * step / depth
            u, v, mask = s["flow"][0], s["flow"][1], s["flow_mask"]
            assert s["flow"].shape == (2, H, W) and mask.dtype == torch.bool
            on_floor = mask & floor
            shift = -fx * step_cam[0] / HEIGHT  # about 3.5 px
            leaving = mask[:, :3] if shift < 0 else mask[:, -3:]  # the columns whose points leave the view
            assert on_floor.sum() > 1000 and not leaving.any()
            assert torch.allclose(u[on_floor], torch.tensor(shift, dtype=torch.float32), atol=1e-3)
            assert torch.allclose(v[mask], torch.tensor(0.0), atol=1e-3)
            top &= mask
            assert top.sum() > 10
            assert torch.allclose(u[top], torch.tensor(-fx * step_cam[0] / (HEIGHT - BOX_HI[2]), dtype=torch.float32), atol=1e-3)
        else:
            assert not s["flow"].any() and not s["flow_mask"].any()
    assert torch.equal(data[-1]["index"], torch.tensor(T - 1))
    with pytest.raises(IndexError):
        data[T]


def test_loader_batches_pickles_and_reads_only_the_fields_asked(exported):
    out = exported[0]
    data = GroundTruthDataset(out / "ground_truth", fields=["depth", "labels"])  # the folder itself
    batch = next(iter(torch.utils.data.DataLoader(data, batch_size=3)))
    assert set(batch) == {"depth", "labels"} and batch["depth"].shape == (3, 1, H, W) and batch["labels"].shape == (3, H, W)
    again = pickle.loads(pickle.dumps(data))
    assert torch.equal(again[2]["depth"], data[2]["depth"])
    (out / "broken").mkdir()
    (out / "broken" / "ground_truth.json").write_text((out / "ground_truth" / "ground_truth.json").read_text())
    for name in ("intrinsics.json", "poses_tum_mm.txt"):
        (out / "broken" / name).write_bytes((out / "ground_truth" / name).read_bytes())
    (out / "broken" / "depth_npy").mkdir()
    (out / "broken" / "depth_npy" / "000001.npy").write_bytes((out / "ground_truth" / "depth_npy" / "000001.npy").read_bytes())
    only = GroundTruthDataset(out / "broken", fields=["depth"])[1]  # no frames, labels or flow there
    assert torch.equal(only["depth"], data[1]["depth"])


def test_clips_stack_the_neighbouring_frames_and_their_relative_pose(exported):
    """clip=(0, -1, 1) over 4 frames: 2 clips (centres 1 and 2), each key stacked in the offsets'
    order; the relative pose of neighbours is the camera's 6 mm step, in the camera's axes."""
    out, cams, _, frames = exported
    data = GroundTruthDataset(out, clip=(0, -1, 1))
    assert len(data) == T - 2
    single = GroundTruthDataset(out)
    for k, centre in enumerate((1, 2)):
        s = data[k]
        assert s["index"].tolist() == [centre, centre - 1, centre + 1]
        assert s["image"].shape == (3, 3, H, W) and s["depth"].shape == (3, 1, H, W) and s["K"].shape == (3, 3, 3)
        for t, i in enumerate((centre, centre - 1, centre + 1)):
            assert torch.equal(s["image"][t], torch.from_numpy(frames[i]).permute(2, 0, 1).float() / 255)
            for f in ("depth", "labels", "flow", "flow_mask", "camera_to_world"):
                assert torch.equal(s[f][t], single[i][f]), f
        c2w = s["camera_to_world"].double()
        prev_in_centre = torch.linalg.inv(c2w[0]) @ c2w[1]  # frame centre - 1's camera in the centre's axes
        step = torch.tensor(cams[0].world_to_camera[:3, :3] @ np.array([-STEP, 0.0, 0.0]))
        assert torch.allclose(prev_in_centre[:3, 3], step, atol=1e-3)
        assert torch.allclose(prev_in_centre[:3, :3], torch.eye(3, dtype=torch.float64), atol=1e-5)
    assert torch.equal(data[-1]["index"], torch.tensor([2, 1, 3]))
    with pytest.raises(IndexError):
        data[T - 2]
    pair = GroundTruthDataset(out, fields=["index"], clip=[1, 0])  # (next, this): 3 pairs
    assert len(pair) == T - 1 and pair[0]["index"].tolist() == [1, 0] and pair[2]["index"].tolist() == [3, 2]
    batch = next(iter(torch.utils.data.DataLoader(GroundTruthDataset(out, fields=["depth"], clip=(0, 1)), batch_size=2)))
    assert batch["depth"].shape == (2, 2, 1, H, W)


def test_track_fields_follow_the_floor_by_the_pinhole_step(exported, tmp_path):
    """A tracked floor point seen in two neighbouring frames moves by -fx * step / depth along x
    and not along y; in its own frame it lies on the floor's depth; tracks are loaded by each
    process, not pickled."""
    out, cams, _, _ = exported
    data = GroundTruthDataset(out, fields=["depth", "tracks", "track_visible", "index"], clip=(0, 1))
    raw = np.load(out / "ground_truth" / "tracks" / "tracks.npz")
    fx = cams[0].K[0, 0]
    step_cam = cams[0].world_to_camera[:3, :3] @ np.array([STEP, 0.0, 0.0])
    shift = -fx * step_cam[0] / HEIGHT
    on_floor_total = 0
    for k in range(len(data)):
        s = data[k]
        xy, seen, depth = s["tracks"], s["track_visible"], s["depth"][0, 0]
        for t, i in enumerate(s["index"].tolist()):  # the file's columns of the sample's frames
            assert np.array_equal(xy[t].numpy(), raw["tracks"][:, i], equal_nan=True)
            assert np.array_equal(seen[t].numpy(), raw["visible"][:, i])
        assert xy.shape[0] == 2 and xy.shape[2] == 2 and xy.dtype == torch.float32 and seen.dtype == torch.bool
        both = seen[0] & seen[1]
        col = xy[0, :, 0].floor().long().clamp(0, W - 1)
        row = xy[0, :, 1].floor().long().clamp(0, H - 1)
        # the floor less a pixel around the box: a point there is the floor's, not the box's edge
        floor_px = ((depth - HEIGHT).abs() < 1e-3).float()[None, None]
        inner = -torch.nn.functional.max_pool2d(-floor_px, 3, stride=1, padding=1)[0, 0] > 0.5
        floor = both & inner[row, col]
        on_floor_total += int(floor.sum())
        d = xy[1, floor] - xy[0, floor]
        assert torch.allclose(d[:, 0], torch.tensor(shift, dtype=torch.float32), atol=1e-3)
        assert torch.allclose(d[:, 1], torch.tensor(0.0), atol=1e-3)
    assert on_floor_total > 20
    assert pickle.loads(pickle.dumps(data))._tracks is None and data._tracks is not None
    bare = tmp_path / "no_tracks"
    bare.mkdir()
    for name in ("ground_truth.json", "intrinsics.json", "poses_tum_mm.txt"):
        (bare / name).write_bytes((out / "ground_truth" / name).read_bytes())
    assert len(GroundTruthDataset(bare, fields=["K"])) == T
    with pytest.raises(UserError, match=f"{bare} holds no point tracks"):
        GroundTruthDataset(bare, fields=["K", "tracks"])


def test_without_frames_the_image_is_the_reference_rendering(exported, tmp_path):
    gbuffers = exported[2]
    export_ground_truth(gbuffers[:2], tmp_path / "gt")
    s = GroundTruthDataset(tmp_path / "gt", fields=["image"])[1]
    want = to_uint8(reference_rendering(gbuffers[1]))
    assert torch.equal(s["image"], torch.from_numpy(want).permute(2, 0, 1).float() / 255)


def test_bad_input_is_one_line(exported, tmp_path):
    out = exported[0]
    cases = [
        (lambda: GroundTruthDataset(tmp_path), f"{tmp_path} is neither a translate output nor a ground-truth export"),
        (lambda: GroundTruthDataset(out, fields=["depth", "normals"]), "unknown field 'normals'; choose from image,"),
        (lambda: GroundTruthDataset(out, stereo=True), f"{out} holds no stereo pair (no stereo/stereo.json)"),
        (lambda: GroundTruthDataset(out, clip=(0, 0)), "clip takes distinct frame offsets such as (0, -1, 1), not (0, 0)"),
        (lambda: GroundTruthDataset(out, clip=()), "clip takes distinct frame offsets"),
        (lambda: GroundTruthDataset(out, clip=(0, 0.5)), "clip takes integer frame offsets such as (0, -1, 1), not (0, 0.5)"),
        (lambda: GroundTruthDataset(out, clip=(-2, 2)), f"a clip spanning 5 frames needs a video of at least that many; this one has {T}"),
    ]
    for make, start in cases:
        with pytest.raises(UserError) as e:
            make()
        assert str(e.value).startswith(start) and "\n" not in str(e.value), str(e.value)
    (tmp_path / "ground_truth.json").write_text('{"format": "something-else/1"}')
    with pytest.raises(UserError, match="is not a sim2real ground-truth manifest"):
        GroundTruthDataset(tmp_path)
