"""``sim2real benchmark`` end to end at the tiny preset: every method, a few iterations each, on the
embedded data; table.json holds every method and every metric; bad input is refused before anything
is trained; a killed benchmark resumes without retraining finished methods."""

from __future__ import annotations

import json
import shutil

import pytest
from train_data import real_dir, scene_dir

from sim2real.cli.main import main
from sim2real.presets import METHOD_PRESETS

pytestmark = pytest.mark.usefixtures("one_torch_thread")

TINY = ["--preset", "tiny", "--iterations", "2", "--frames", "12", "--eval-views", "4", "--seg-iterations", "3",
        "--real-images", "12", "--real-sequences", "1", "--sequence-frames", "4", "--device", "cpu"]
METRICS = {"proxy", "dice", "of_error", "of_epe", *(f"{p}orb_{k}_{q}" for p in ("", "revisit_") for k in (1, 5, 10)
                                                    for q in ("accuracy", "correct")), "revisit_of_error", "fid", "kid"}


def bench(capsys, out, *extra) -> tuple[int, str]:
    code = main(["benchmark", "--out", str(out), *TINY, *map(str, extra)])
    return code, capsys.readouterr().err


@pytest.fixture(scope="module")
def everything(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "all"
    assert main(["benchmark", "--out", str(out), *TINY, "--parallel", "2"]) == 0  # two trainings at a time
    return out


def test_every_method_and_metric_in_the_table(everything):
    table = json.loads((everything / "table.json").read_text())
    assert list(table["methods"]) == list(METHOD_PRESETS)
    for name, e in table["methods"].items():
        assert METRICS <= set(e["metrics"]), (name, METRICS - set(e["metrics"]))
        assert e["train"]["iterations"] == 2 and e["train"]["budget"] == {"iterations": 2} and e["train"]["seconds"] > 0
        assert e["train"]["parallel"] == 2 and e["train"]["threads"] >= 1
        assert (everything / "videos" / f"{name}.mp4").stat().st_size > 0
        # a time-independent method's revisit equals its forward figures; OF-UNIT's are its own
        same = e["metrics"]["revisit_orb_1_accuracy"] == e["metrics"]["orb_1_accuracy"]
        assert same or not e["time_independent"], name
    assert table["methods"]["of_unit"]["time_independent"] is False
    assert {"ceiling", "floor"} <= set(table["anchors"])
    assert table["methods"]["ssim_munit"]["type"] == "img" and table["methods"]["recycle"]["type"] == "vid"
    assert table["methods"]["ours"]["type"] == table["methods"]["ours_no_vc"]["type"] == "ours"
    md = (everything / "table.md").read_text()
    for name in METHOD_PRESETS:
        assert f"| {name} |" in md
    assert "| of_unit (revisit) |" in md and "| *ceiling* |" in md and "| *floor* |" in md
    page = (everything / "report.html").read_text()
    assert page.count("<svg") >= 8 and "data:image/png;base64," in page
    assert (everything / "side_by_side.png").is_file()


def test_a_killed_benchmark_resumes_without_retraining(everything, tmp_path, capsys):
    out = tmp_path / "copy"
    shutil.copytree(everything, out)
    # as if killed at the end of ours_no_vc's training (its done marker not yet written) and so
    # before its evaluation: its metrics and the table are not there yet
    (out / "runs" / "ours_no_vc" / "done.json").unlink()
    shutil.rmtree(out / "evaluations" / "ours_no_vc")
    (out / "evaluations" / "ours_no_vc").mkdir()  # a half-written folder
    (out / "table.json").unlink()
    ckpt = out / "runs" / "ours" / "checkpoints" / "last.pt"
    before = ckpt.stat().st_mtime_ns
    code, err = bench(capsys, out, "--resume")
    assert code == 0, err
    assert ckpt.stat().st_mtime_ns == before  # not retrained
    assert "ours: training" not in err and "ours: evaluation" not in err
    assert "ours_no_vc: training" in err and "ours_no_vc: evaluation" in err
    assert json.loads((out / "runs" / "ours_no_vc" / "done.json").read_text())["iterations"] == 2  # resumed at 2
    assert list(json.loads((out / "table.json").read_text())["methods"]) == list(METHOD_PRESETS)


def test_bad_input_is_refused_before_anything_is_trained(capsys, tmp_path):
    base = tmp_path / "inputs"
    code, err = bench(capsys, tmp_path / "a", "--methods", "ours", "cyclegan")
    assert code == 2 and "unknown method 'cyclegan'" in err and not (tmp_path / "a").exists()
    code, err = bench(capsys, tmp_path / "b", "--methods", "ours", "recycle", "--scenes", scene_dir(base, 11),
                      "--real", real_dir(base))
    assert code == 2 and "recycle train on consecutive real frames" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "b").exists()
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "x.txt").write_text("occupied")
    code, err = bench(capsys, tmp_path / "c", "--methods", "ours")
    assert code == 2 and "already holds other data" in err and not (tmp_path / "c" / "runs").exists()
    code, err = bench(capsys, tmp_path / "d", "--methods", "ours", "--resume")
    assert code == 2 and "nothing to resume" in err
