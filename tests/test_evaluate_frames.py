"""``sim2real evaluate --frames DIR --trajectory FILE --scene DIR``: a video made by any tool gets the
full report; the ceiling's own frames, given as such a video, reproduce the ceiling row."""

import json

import pytest
from train_data import real_dir, scene_dir

from sim2real.cli.main import main
from sim2real.fileio import atomic_write_image
from sim2real.inference.anchors import Anchors
from sim2real.render.raycast import RayCaster
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import make_trajectory

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def path(tmp_path_factory):
    base = tmp_path_factory.getbasetemp()
    d = scene_dir(base, 11)
    sc = Scene.load(d)
    caster = RayCaster(sc)
    work = tmp_path_factory.mktemp("frames")
    traj = make_trajectory(caster, 12, 64, 128, 75.0, seed=2)
    traj.save(work / "traj.txt")
    anchors = Anchors(sc, seed=0)  # the evaluation's ceiling: seed 0, the default camera of a non-stand-in folder
    for t, cam in enumerate(traj.cameras):
        atomic_write_image(work / "ceiling" / f"{t:04d}.png", anchors.ceiling(caster.render(cam), t))
    return base, d, work


def test_frames_of_the_ceiling_reproduce_the_ceiling_row(path, capsys):
    base, d, work = path
    out = work / "eval"
    argv = ["evaluate", "--frames", work / "ceiling", "--trajectory", work / "traj.txt", "--scene", d,
            "--real", real_dir(base), "--out", out, "--views", 4, "--orb-max-k", 3, "--device", "cpu", "--no-progress"]
    assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    m = json.loads((out / "metrics.json").read_text())
    model, ceiling = m["rows"]["model"], m["rows"]["ceiling"]
    keys = ["orb_1_correct", "orb_1_accuracy", "orb_5_correct", "of_error", "of_epe", "proxy", "detail"]
    assert ceiling["orb_1_correct"] is not None and ceiling["of_error"] is not None
    assert {k: model[k] for k in keys} == {k: ceiling[k] for k in keys}
    assert model["of_error_vs_ceiling"] == 0.0
    assert m["odometry"]["rows"]["model"] == m["odometry"]["rows"]["ceiling"]
    assert m["run"]["frames"].endswith("ceiling") and m["inputs"]["scenes"][0]["frames"] == 12
    assert m["run"]["compiled"] is False and m["run"]["amp_bf16"] is False  # the keys of a run's evaluation
    assert "made by any tool" in (out / "report.md").read_text()


def test_frames_refused_with_one_line(path, tmp_path, capsys):
    base, d, work = path
    common = ["--scene", d, "--real", real_dir(base), "--device", "cpu", "--no-progress"]
    (tmp_path / "few").mkdir()
    (tmp_path / "empty").mkdir()
    for t in range(3):
        (tmp_path / "few" / f"{t}.png").write_bytes((work / "ceiling" / f"{t:04d}.png").read_bytes())
    cases = [(["--frames", tmp_path / "few", "--trajectory", work / "traj.txt", "--out", tmp_path / "o1"],
              "has 3 frames but the trajectory"),
             (["--frames", work / "ceiling", "--out", tmp_path / "o2"], "exactly one --trajectory"),
             (["--frames", tmp_path / "missing", "--trajectory", work / "traj.txt", "--out", tmp_path / "o3"],
              "neither a folder of frames nor a video"),
             (["--frames", tmp_path / "empty", "--trajectory", work / "traj.txt", "--out", tmp_path / "o6"],
              f"no frames (png/jpg) found under {tmp_path / 'empty'}"),
             (["--frames", work / "ceiling", "--trajectory", work / "traj.txt", "--out", tmp_path / "o4",
               "--precision", "bf16"], "evaluates a video without one"),
             (["--frames", work / "ceiling", "--trajectory", work / "traj.txt", "--out", tmp_path / "o5", "--compile"],
              "--compile compiles a run's networks")]
    for extra, msg in cases:
        assert main([str(a) for a in ["evaluate", *common, *extra]]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and msg in err, err
