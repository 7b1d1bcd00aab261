"""Every bad input gets one clear line on stderr and a non-zero exit, never a traceback."""

import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from sim2real.cli.main import main
from sim2real.scene.procedural import generate_scene


def run(capsys, *argv):
    code = main(list(argv))
    err = capsys.readouterr().err.strip()
    return code, err


def assert_one_line_error(code, err, *words):
    assert code != 0
    assert "Traceback" not in err
    lines = [l for l in err.splitlines() if l.strip()]
    assert len(lines) == 1, err
    for w in words:
        assert w in lines[0], lines[0]


@pytest.fixture
def good_mesh(tmp_path):
    path = tmp_path / "liver.stl"
    trimesh.creation.icosphere(subdivisions=2, radius=50).export(path)
    return path


@pytest.fixture
def wall_mesh(tmp_path):
    path = tmp_path / "wall.ply"
    inner = trimesh.creation.icosphere(subdivisions=3, radius=300)
    inner.invert()
    outer = trimesh.creation.icosphere(subdivisions=3, radius=320)
    trimesh.util.concatenate([outer, inner]).export(path)
    return path


def _import(capsys, tmp_path, *meshes, region="0,0,150,20,20,20", out="scene"):
    args = ["scene", "import"]
    for m in meshes:
        args += ["--mesh", str(m)]
    return run(capsys, *args, "--camera-region", region, "--out", str(tmp_path / out))


def test_import_good_scene(capsys, tmp_path, good_mesh, wall_mesh):
    code, err = _import(capsys, tmp_path, f"{good_mesh}=liver", f"{wall_mesh}=abdominal_wall")
    assert code == 0, err
    assert (tmp_path / "scene" / "scene.json").is_file()


def test_missing_mesh_file(capsys, tmp_path):
    assert_one_line_error(*_import(capsys, tmp_path, f"{tmp_path}/nope.obj=liver"), "does not exist")


def test_unreadable_mesh_file(capsys, tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat garbage\n\x00\x01\x02")
    assert_one_line_error(*_import(capsys, tmp_path, f"{bad}=liver"), "bad.ply")


def test_empty_mesh(capsys, tmp_path):
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\nv 0 0 0\nv 1 0 0\n")
    code, err = _import(capsys, tmp_path, f"{empty}=liver")
    assert_one_line_error(code, err)
    assert "empty" in err or "not a triangle mesh" in err


def test_non_triangle_mesh(capsys, tmp_path):
    cloud = tmp_path / "cloud.ply"
    trimesh.PointCloud(np.random.default_rng(0).normal(size=(50, 3))).export(cloud)
    assert_one_line_error(*_import(capsys, tmp_path, f"{cloud}=liver"), "not a triangle mesh")


def test_nan_vertices(capsys, tmp_path):
    path = tmp_path / "nan.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    assert_one_line_error(*_import(capsys, tmp_path, f"{path}=liver"), "NaN")


def test_unknown_class(capsys, tmp_path, good_mesh):
    # spleen is a default class now; a class no table names is refused
    assert_one_line_error(*_import(capsys, tmp_path, f"{good_mesh}=tumour"), "unknown class 'tumour'", "--class-table")


def test_camera_region_inside_organ(capsys, tmp_path, good_mesh, wall_mesh):
    code, err = _import(capsys, tmp_path, f"{good_mesh}=liver", f"{wall_mesh}=abdominal_wall", region="0,0,0,10,10,10")
    assert_one_line_error(code, err, "inside organ", "liver")


def test_camera_region_outside_wall(capsys, tmp_path, good_mesh, wall_mesh):
    code, err = _import(capsys, tmp_path, f"{good_mesh}=liver", f"{wall_mesh}=abdominal_wall", region="0,0,600,10,10,10")
    assert_one_line_error(code, err, "outside the abdominal wall")


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("s") / "scene"
    generate_scene(2).save(d)
    return d


def test_output_dir_with_other_data(capsys, tmp_path, scene_dir):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    code, err = run(capsys, "render", str(scene_dir), "--views", "1", "--height", "16", "--width", "16", "--out", str(out))
    assert_one_line_error(code, err, "already holds other data")
    code, err = run(capsys, "scene", "generate", "--seed", "1", "--out", str(out))
    assert_one_line_error(code, err, "already holds other data")
    assert (out / "keep.txt").read_text() == "mine"


@pytest.mark.parametrize("flags,word", [
    (["--views", "0"], "--views"),
    (["--views", "two"], "--views"),
    (["--views", "1", "--height", "-5"], "--height"),
    (["--views", "1", "--height", "4"], "image size"),
    (["--views", "1", "--width", "100000"], "image size"),
])
def test_invalid_size_or_count(capsys, tmp_path, scene_dir, flags, word):
    code, err = 0, ""
    try:
        code, err = run(capsys, "render", str(scene_dir), *flags, "--out", str(tmp_path / "o"))
    except SystemExit as e:  # argparse rejects before main's handler
        code, err = e.code, capsys.readouterr().err.strip()
    assert_one_line_error(code, err, word)
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_bad_trajectory_rows(capsys, tmp_path, scene_dir):
    traj = tmp_path / "t.txt"
    traj.write_text("# width 32\n# height 16\n# K 20 0 16 0 20 8 0 0 1\n0 1 2 3 0 0 0 1\n0.2 1 2 oops\n")
    code, err = run(capsys, "render", str(scene_dir), "--trajectory", str(traj), "--out", str(tmp_path / "o"))
    assert_one_line_error(code, err, "t.txt:5")


def test_entry_point_has_no_traceback(tmp_path):
    r = subprocess.run([sys.executable, "-m", "sim2real.cli.main", "render", str(tmp_path / "none"), "--views", "1",
                        "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().startswith("sim2real: error:") and len(r.stderr.strip().splitlines()) == 1


def test_seg_iterations_default_and_range(capsys):
    """Every evaluating command defaults to the library's segmenter steps and refuses a negative
    count in one line."""
    from sim2real.cli.main import build_parser
    from sim2real.inference.evaluate import EvalSettings

    parser = build_parser()
    want = EvalSettings().seg_iterations
    for argv in (["evaluate", "RUN", "--scenes", "S", "--real", "R", "--out", "O"], ["demo", "--out", "O"],
                 ["benchmark", "--out", "O"]):
        args = parser.parse_args(argv)
        assert args.seg_iterations == want, argv
        assert parser.parse_args(argv + ["--seg-iterations", "7"]).seg_iterations == 7
    with pytest.raises(SystemExit) as e:  # argparse rejects before main's handler
        main(["demo", "--out", "O", "--seg-iterations", "-1"])
    code, err = e.value.code, capsys.readouterr().err.strip()
    assert_one_line_error(code, err, "--seg-iterations", "-1")


@pytest.mark.parametrize("frames", [5, 12])
def test_scene_trajectory_summarises_what_it_measured(capsys, tmp_path, scene_dir, frames):
    """A path of 5 frames has overlaps after 1 frame only (after 5 needs a 6th); 12 frames reach 10."""
    out = tmp_path / "path.txt"
    code = main(["scene", "trajectory", str(scene_dir), "--frames", str(frames), "--height", "64", "--width", "96",
                 "--out", str(out)])
    io = capsys.readouterr()
    assert code == 0, io.err
    motion = json.loads(out.with_name("path.txt.json").read_text())["motion"]
    k = {5: "1", 12: "10"}[frames]
    assert motion["overlap"]["10"] is None if frames == 5 else motion["overlap"]["10"] is not None
    assert f"overlap after {k} frame{'s' if k != '1' else ''} {motion['overlap'][k]:.0%}" in io.out
    assert io.out.startswith(f"{frames} poses written to {out} (median flow ")


def test_scene_trajectory_takes_a_calibrated_cameras_intrinsics(capsys, tmp_path, scene_dir):
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import Trajectory

    out = tmp_path / "path.txt"
    code = main(["scene", "trajectory", str(scene_dir), "--frames", "5", "--height", "64", "--width", "96",
                 "--intrinsics", "60,64,40,30", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    cams = Trajectory.load(out).cameras
    for cam in cams:
        np.testing.assert_array_equal(cam.K, [[60, 0, 40], [0, 64, 30], [0, 0, 1]])
    # the ray caster sees through that K: a pixel's point, in the camera frame, lies at
    # ((col + 0.5 - cx) / fx, (row + 0.5 - cy) / fy, 1) times its depth
    g = RayCaster(Scene.load(scene_dir)).render(cams[0])
    rows, cols = np.nonzero(g.object_id >= 0)
    z = g.depth[rows, cols]
    hand = np.stack([(cols + 0.5 - 40) / 60 * z, (rows + 0.5 - 30) / 64 * z, z], axis=1)
    R, t = cams[0].world_to_camera[:3, :3], cams[0].world_to_camera[:3, 3]
    np.testing.assert_allclose(g.points[rows, cols] @ R.T + t, hand, atol=1e-3)
    for extra, words in ((["--intrinsics", "60,64,100,30"], "principal point (100, 30) lies outside the 96x64"),
                         (["--intrinsics", "60,64,40"], "--intrinsics must be 4"),
                         (["--intrinsics", "60,64,40,30", "--fov", "70"], "give --fov or --intrinsics"),
                         (["--intrinsics", "0,64,40,30"], "positive focal lengths"),
                         (["--intrinsics", "1,64,40,30"], "field of view of 177.5 degrees")):  # atan(40) + atan(56)
        code = main(["scene", "trajectory", str(scene_dir), "--frames", "5", "--height", "64", "--width", "96",
                     *extra, "--out", str(tmp_path / "bad.txt")])
        assert_one_line_error(code, capsys.readouterr().err.strip(), words)


def test_render_draws_random_views_through_the_given_intrinsics(capsys, tmp_path, scene_dir):
    from sim2real.render.gbuffer import GBuffer

    out = tmp_path / "views"
    code = main(["render", str(scene_dir), "--views", "2", "--height", "64", "--width", "96", "--workers", "1",
                 "--intrinsics", "60,64,40,30", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    for k in range(2):
        np.testing.assert_array_equal(GBuffer.load(out / f"view_{k:05d}.npz").K, [[60, 0, 40], [0, 64, 30], [0, 0, 1]])
    code = main(["render", str(scene_dir), "--views", "2", "--height", "64", "--width", "96", "--fov", "70",
                 "--intrinsics", "60,64,40,30", "--out", str(tmp_path / "both")])
    assert_one_line_error(code, capsys.readouterr().err.strip(), "give --fov or --intrinsics")
    assert not (tmp_path / "both").exists()



def test_counts_are_written_with_their_noun_in_the_right_number():
    from sim2real.cli.args import counted

    assert [counted(n, "frame") for n in (0, 1, 2)] == ["0 frames", "1 frame", "2 frames"]


def test_machine_failures_are_named_with_what_to_do():
    """A full disk, a quota, a read-only or forbidden place is the machine's failure: found in the
    exception or those it was raised from (torch.save wraps the OSError in a RuntimeError);
    anything else is not one."""
    import errno
    import os

    from sim2real.errors import machine_error

    full = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert machine_error(full) == "No space left on device: free space on that disk or write elsewhere"
    denied = PermissionError(errno.EACCES, os.strerror(errno.EACCES), "/data/run")
    assert machine_error(denied) == "Permission denied (/data/run): check its permissions"
    try:
        try:
            raise full
        except OSError:
            raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 57761792 vs 57761684")
    except RuntimeError as wrapped:
        assert machine_error(wrapped) == machine_error(full)
    assert machine_error(RuntimeError("a bug")) is None
    assert machine_error(FileNotFoundError(errno.ENOENT, "No such file or directory", "x")) is None


def test_a_full_disk_is_one_line_and_leaves_nothing_behind(capsys, tmp_path, monkeypatch):
    import errno
    import os

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "replace", full)  # the rename of the finished scene folder fails
    code, err = run(capsys, "scene", "generate", "--seed", "0", "--out", str(tmp_path / "scene"))
    assert code == 1 and err == "sim2real: error: No space left on device: free space on that disk or write elsewhere"
    assert list(tmp_path.iterdir()) == []  # no scene folder, no temporary one


def test_version_and_help_speak_of_the_product(capsys):
    """--version gives the installed package's version (the one pip recorded from pyproject.toml);
    --help says what the tool does and where to go next, not how its code is arranged."""
    from importlib.metadata import version

    from sim2real.cli.main import main

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out == f"sim2real {version('sim2real')}\n"
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert e.value.code == 0
    assert "laparoscopic-looking videos" in text and "'sim2real COMMAND --help' lists a command's options" in text
    assert "register" not in text and "module" not in text
    for argv, first in ((["train", "--help"], "Train neural textures and the translator"),
                        (["scene", "trajectory", "--help"], "A smooth camera path through a scene"),
                        (["realset", "--help"], "sim2real realset: make a real set")):
        with pytest.raises(SystemExit):
            main(argv)
        text = capsys.readouterr().out
        assert first in text and "``" not in text, argv  # each command's help opens with what it does


def test_sigterm_unwinds_a_command_and_leaves_no_output(tmp_path):
    """SIGTERM (a scheduler's pre-emption, 'kill') while a command writes its output: the command
    unwinds as on Ctrl-C, says so in one line, exits with 143 (128 + SIGTERM) and leaves neither
    its output folder nor the hidden one it was filling (Python's default would end the process
    where it stands, leaving the hidden folder)."""
    import signal
    import time

    generate_scene(0).save(tmp_path / "scene")
    out = tmp_path / "real"
    proc = subprocess.Popen([sys.executable, "-m", "sim2real.cli.main", "realdomain", "--scenes", str(tmp_path / "scene"),
                             "--images", "1000", "--height", "32", "--width", "64", "--workers", "1", "--quiet",
                             "--out", str(out)], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not list(tmp_path.glob(".real.partial-*/images/*.png")) and time.monotonic() < deadline:
        time.sleep(0.05)  # until frames are being written into the hidden folder
    assert proc.poll() is None, proc.stderr.read()
    proc.send_signal(signal.SIGTERM)
    try:
        code = proc.wait(timeout=60)
    finally:
        proc.kill()
    err = proc.stderr.read().strip().splitlines()
    assert code == 143 and err[-1] == "sim2real: terminated (SIGTERM)", (code, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]


def test_render_refuses_too_little_free_space_before_rendering(tmp_path, capsys, monkeypatch):
    """The need is the views' arrays: at most each file's size, so free space equal to what the
    files take passes, and one byte under the arrays alone is refused before anything is written."""
    import collections
    import shutil

    from sim2real.render.gbuffer import GBuffer

    generate_scene(0).save(tmp_path / "scene")
    argv = ["render", str(tmp_path / "scene"), "--views", "2", "--height", "32", "--width", "64", "--seed", "0"]
    assert main([*argv, "--out", str(tmp_path / "views")]) == 0
    files = sorted((tmp_path / "views").glob("view_*.npz"))
    arrays = GBuffer.load(files[0]).nbytes
    assert 0.9 * files[0].stat().st_size < arrays <= files[0].stat().st_size  # headers and class table on top
    usage = collections.namedtuple("usage", "total used free")
    for free, code in ((sum(f.stat().st_size for f in files), 0), (2 * arrays - 1, 2)):
        monkeypatch.setattr(shutil, "disk_usage", lambda p, f=free: usage(0, 0, f))
        out = tmp_path / f"views{free}"
        assert main([*argv, "--out", str(out)]) == code
        err = capsys.readouterr().err.strip()
        if code:
            assert err.startswith("sim2real: error: rendering 2 views at 64x32 needs at least") and "\n" not in err
            assert not out.exists()
