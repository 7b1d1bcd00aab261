"""Your own camera path (`scene trajectory --poses`): TUM rows in other units and camera axes,
resampled at a frame rate, checked against poses and rotations worked out by hand, and against a
generated path written out in metres with OpenGL cameras and read back."""

import json

import numpy as np
import pytest

from sim2real.cli.main import main
from sim2real.errors import UserError
from sim2real.scene.camera import intrinsics_from_fov, rotation_to_quaternion
from sim2real.scene.pose_import import resample, trajectory_from_poses
from sim2real.scene.procedural import generate_scene
from sim2real.scene.trajectory import Trajectory

K = intrinsics_from_fov(96, 64, 75.0)


def _rot_z(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])


def _rows(path, times, c2w, scale=1.0):
    path.write_text("".join(f"{t:.6f} " + " ".join(f"{x:.9f}" for x in (*(T[:3, 3] * scale), *rotation_to_quaternion(T[:3, :3])))
                            + "\n" for t, T in zip(times, c2w)))
    return path


def test_resample_interpolates_positions_linearly_and_rotations_along_the_arc():
    a, b = np.eye(4), np.eye(4)
    b[:3, :3], b[:3, 3] = _rot_z(90), [10.0, -4.0, 2.0]
    t, out = resample(np.array([0.0, 1.0]), np.stack([a, b]), fps=4)
    assert np.allclose(t, [0, 0.25, 0.5, 0.75, 1.0])
    for k, frac in enumerate(t):
        assert np.allclose(out[k, :3, 3], frac * np.array([10.0, -4.0, 2.0]))
        assert np.allclose(out[k, :3, :3], _rot_z(90 * frac), atol=1e-9)  # 0, 22.5, 45, 67.5, 90 degrees
    t, _ = resample(np.array([0.0, 0.3, 1.1]), np.stack([a, a, b]), fps=2)
    assert np.allclose(t, [0.0, 0.5, 1.0])  # up to the last row, not past it


def test_units_axes_rate_and_refusals(tmp_path):
    c2w = np.tile(np.eye(4), (3, 1, 1))
    c2w[:, :3, 3] = [[0.1, 0.0, 0.0], [0.2, 0.0, 0.0], [0.3, 0.0, 0.0]]  # metres
    path = _rows(tmp_path / "gl.txt", [10.0, 10.04, 10.08], c2w)
    traj, rows = trajectory_from_poses(path, K, 64, 96, units="m", axes="opengl")
    assert rows == 3 and len(traj.cameras) == 3 and traj.fps == pytest.approx(25.0)
    cam = traj.cameras[1].camera_to_world
    assert np.allclose(cam[:3, 3], [200.0, 0.0, 0.0])  # millimetres
    # an OpenGL camera at identity looks along world -z with world +y up: in OpenCV axes its
    # z (viewing) axis is world -z and its y (down) axis world -y
    assert np.allclose(cam[:3, 2], [0, 0, -1]) and np.allclose(cam[:3, 1], [0, -1, 0]) and np.allclose(cam[:3, 0], [1, 0, 0])
    same, _ = trajectory_from_poses(path, K, 64, 96, units="cm")
    want = np.eye(4)
    want[0, 3] = 3.0  # 0.3 cm, the axes kept
    assert np.allclose(same.cameras[2].camera_to_world, want)
    _rows(tmp_path / "back.txt", [0.0, 0.5, 0.5], c2w)
    with pytest.raises(UserError, match=r"timestamps must increase, but pose 3 \(0.5 s\) does not come after pose 2"):
        trajectory_from_poses(tmp_path / "back.txt", K, 64, 96)
    (tmp_path / "none.txt").write_text("# nothing here\n")
    with pytest.raises(UserError, match="no pose rows"):
        trajectory_from_poses(tmp_path / "none.txt", K, 64, 96)


def test_unevenly_spaced_rows_are_noted_unless_resampled(tmp_path):
    """Rows 0.04 s apart with one 0.12 s gap (a tracker's dropped samples): one note naming the
    gap; the rows within 1.5x of their median, or resampled with fps, give none."""
    c2w = np.tile(np.eye(4), (5, 1, 1))
    gap = _rows(tmp_path / "gap.txt", [0.0, 0.04, 0.08, 0.20, 0.24], c2w)
    notes = []
    traj, _ = trajectory_from_poses(gap, K, 64, 96, note=notes.append)
    assert len(traj.cameras) == 5 and traj.fps == pytest.approx(25.0)
    assert notes == ["1 of 4 pose intervals are more than 1.5x off their median 0.04 s (first after pose 3: 0.12 s), "
                     "yet each row becomes one frame at 25 fps: --fps F resamples the path evenly in time"]
    notes.clear()
    assert len(trajectory_from_poses(gap, K, 64, 96, fps=25.0, note=notes.append)[0].cameras) == 7 and notes == []
    jitter = _rows(tmp_path / "jitter.txt", [0.0, 0.04, 0.09, 0.12, 0.16], c2w)  # 0.03-0.05 s: within 1.5x
    trajectory_from_poses(jitter, K, 64, 96, note=notes.append)
    assert notes == []


@pytest.fixture(scope="module")
def scene_and_path(tmp_path_factory):
    root = tmp_path_factory.mktemp("poses")
    generate_scene(2).save(root / "scene")
    assert main(["scene", "trajectory", str(root / "scene"), "--frames", "12", "--height", "64", "--width", "96",
                 "--out", str(root / "made.txt")]) == 0
    return root, Trajectory.load(root / "made.txt")


def test_a_path_in_metres_with_opengl_cameras_comes_back_as_it_was(scene_and_path, tmp_path, capsys):
    root, made = scene_and_path
    gl = [c.camera_to_world @ np.diag([1.0, -1.0, -1.0, 1.0]) for c in made.cameras]  # Blender's camera axes
    poses = _rows(tmp_path / "robot.txt", 100.0 + np.arange(12) / 25.0, gl, scale=1e-3)
    out = tmp_path / "own.txt"
    code = main(["scene", "trajectory", str(root / "scene"), "--poses", str(poses), "--units", "m", "--axes", "opengl",
                 "--height", "64", "--width", "96", "--out", str(out)])
    io = capsys.readouterr()
    assert code == 0 and io.err == "", io.err
    assert io.out.startswith(f"12 poses written to {out} (from 12 pose rows of {poses}, median flow ")
    back = Trajectory.load(out)
    assert back.fps == pytest.approx(25.0) and len(back.cameras) == 12
    for a, b in zip(back.cameras, made.cameras):
        assert np.allclose(a.camera_to_world, b.camera_to_world, atol=1e-5) and np.allclose(a.K, b.K)
    side = json.loads(out.with_name("own.txt.json").read_text())
    assert side["motion"]["source"] == {"poses": str(poses), "rows": 12, "units": "m", "axes": "opengl",
                                        "resampled_fps": None}
    assert side["motion"]["flow_px_per_frame_median"] > 0 and side["motion"]["overlap"]["10"] > 0.5

    code = main(["scene", "trajectory", str(root / "scene"), "--poses", str(poses), "--units", "m", "--axes", "opengl",
                 "--fps", "10", "--height", "64", "--width", "96", "--out", str(tmp_path / "ten.txt")])
    assert code == 0
    ten = Trajectory.load(tmp_path / "ten.txt")
    assert ten.fps == 10 and len(ten.cameras) == 5  # 0.44 s of rows: 0, 0.1, ..., 0.4
    assert np.allclose(ten.cameras[2].camera_to_world[:3, 3],  # 0.2 s = row 5
                       made.cameras[5].camera_to_world[:3, 3], atol=1e-5)


def test_poses_in_the_wrong_frame_and_flags_of_generated_paths_are_one_line(scene_and_path, tmp_path, capsys):
    root, made = scene_and_path
    far = [c.camera_to_world + np.pad(np.array([[0, 0, 0, 5000.0]]), ((0, 3), (0, 0))) for c in made.cameras]
    poses = _rows(tmp_path / "far.txt", np.arange(12) / 5.0, far)
    cases = [
        (["--poses", str(poses)], "12 of 12 cameras lie inside an organ or outside the abdominal wall (frame 0: "
                                  "outside the abdominal wall): are the poses in the scene's frame, in --units mm "
                                  "with --axes opencv?"),
        (["--poses", str(poses), "--seed", "3"], "--seed shapes a generated path; with --poses the path is the file's"),
        (["--poses", str(poses), "--frames", "3"], "--frames shapes a generated path"),
        (["--axes", "opengl"], "--units, --axes and --camera describe --poses: give them with --poses FILE"),
        (["--poses", str(poses), "--camera", "Cam"], "--camera names a camera of a .blend file"),
        (["--poses", str(tmp_path / "none.blend")], f"pose file {tmp_path / 'none.blend'} does not exist"),
    ]
    for extra, message in cases:
        code = main(["scene", "trajectory", str(root / "scene"), *extra, "--out", str(tmp_path / "x.txt")])
        err = capsys.readouterr().err.strip()
        assert code == 2 and err.startswith(f"sim2real: error: {message}") and "\n" not in err, err
    assert not (tmp_path / "x.txt").exists()
    # a few stray cameras (an endoscope entering through its trocar) are named, not refused
    some = [c.camera_to_world for c in made.cameras]
    some[0] = far[0]
    code = main(["scene", "trajectory", str(root / "scene"), "--poses", str(_rows(tmp_path / "some.txt", np.arange(12) / 5.0, some)),
                 "--height", "64", "--width", "96", "--out", str(tmp_path / "some_out.txt")])
    io = capsys.readouterr()
    assert code == 0 and io.err.strip() == ("sim2real: note: 1 of 12 cameras lies inside an organ or outside the abdominal "
                                             "wall (first: frame 0)")
