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
    # two trainings at a time; ours with a second seed
    assert main(["benchmark", "--out", str(out), *TINY, "--parallel", "2", "--seeds", "2", "--seeds-for", "ours"]) == 0
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
    assert {"ceiling", "floor", "a_ref", "real_held_out"} <= set(table["anchors"])
    first = json.loads((everything / "evaluations" / next(iter(table["methods"])) / "metrics.json").read_text())
    assert table["anchors"]["real_held_out"]["proxy"] == first["realism"]["proxy"]["rows"]["real_held_out"] > 0
    # ours: two runs with their own seeds; its row is their mean, its range their min and max
    runs = table["methods"]["ours"]["runs"]
    assert {n: r["seed"] for n, r in runs.items()} == {"ours": 0, "ours.seed1": 1}
    a, b = (r["metrics"]["orb_1_correct"] for r in runs.values())
    assert table["methods"]["ours"]["metrics"]["orb_1_correct"] == pytest.approx((a + b) / 2)
    assert table["methods"]["ours"]["range"]["orb_1_correct"] == [min(a, b), max(a, b)]
    assert list(table["methods"]["of_unit"]["runs"]) == ["of_unit"]
    for name, e in table["methods"].items():  # the weight-free realism and odometry beside consistency
        assert 0.0 <= e["metrics"]["c2st"] <= 1.0 and "odometry_10_success" in e["metrics"], name
    assert table["calibration"]["status"] in ("calibrated", "uncalibrated")
    assert table["methods"]["ssim_munit"]["type"] == "img" and table["methods"]["recycle"]["type"] == "vid"
    assert table["methods"]["ours"]["type"] == table["methods"]["ours_no_vc"]["type"] == "ours"
    md = (everything / "table.md").read_text()
    for name in METHOD_PRESETS:
        assert f"| {name} |" in md
    assert "| of_unit (revisit) |" in md and "| *ceiling* |" in md and "| *floor* |" in md and "| *a ref* |" in md
    assert "| ours ×2 |" in md and "C2ST AUC" in md and "| *real held out* |" in md
    page = (everything / "report.html").read_text()
    assert page.count("<svg") >= 8 and "data:image/png;base64," in page
    assert "<title>sim2real benchmark</title>" in page
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


def test_a_resume_may_add_seeds(everything, tmp_path, capsys):
    out = tmp_path / "more"
    shutil.copytree(everything, out)
    code, err = bench(capsys, out, "--resume", "--seeds", "2", "--seeds-for", "ours", "of_unit")
    assert code == 0, err
    assert "of_unit.seed1: training" in err and "ours.seed1: training" not in err and "ours: training" not in err
    table = json.loads((out / "table.json").read_text())
    assert list(table["methods"]["of_unit"]["runs"]) == ["of_unit", "of_unit.seed1"]
    code, err = bench(capsys, out, "--resume", "--seed", "3")  # what is compared may not change
    assert code == 2 and "the flags differ" in err


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
    code, err = bench(capsys, tmp_path / "e", "--methods", "ours", "--seeds", "2", "--seeds-for", "recycle")
    assert code == 2 and "--seeds-for names 'recycle', which is not compared" in err and not (tmp_path / "e").exists()


def test_counts_above_the_ceilings_are_marked_not_ranked():
    """A hand-made table: ORB counts 3.0 and 0.5 against a ceiling's 2.0 -> only the first has the mark."""
    from sim2real.comparison.table import markdown

    def row(correct):
        m = {"c2st": 0.9, "proxy": 0.1, "dice": 0.9, "of_error": 0.5}
        for k in (1, 5, 10):
            m[f"orb_{k}_accuracy"], m[f"orb_{k}_correct"] = 0.5, correct
        return m

    method = {"type": "ours", "time_independent": True, "train": {"iterations": 7, "seconds": 9.0}}
    table = {"realism": "proxy", "realism_reason": "no weights", "calibration": {},
             "methods": {"high": {**method, "metrics": row(3.0)}, "low": {**method, "metrics": row(0.5)}},
             "anchors": {"ceiling": row(2.0)}}
    lines = {l.split(" | ")[0]: l for l in markdown(table).splitlines() if l.startswith("| ")}
    assert lines["| high"].count("(3⁺)") == 3 and "⁺" not in lines["| low"] and "⁺" not in lines["| *ceiling*"]


@pytest.mark.parametrize("stop", [KeyboardInterrupt, "a training fails"])
def test_a_stopped_parallel_benchmark_stops_its_running_trainings(tmp_path, monkeypatch, stop):
    """Ctrl-C or SIGTERM to the benchmark (here at its first poll), or one training failing, stops
    the trainings still running (SIGTERM: each stops after its step with a checkpoint, resumable)
    and waits for them, instead of leaving them to train on without it."""
    from sim2real.comparison import run
    from sim2real.errors import UserError
    from sim2real.presets import budgeted

    procs = []

    class Training:  # a training process that is still running, unless it is the failing one
        def __init__(self, argv, **kwargs):
            self.calls, self.failed = [], stop != KeyboardInterrupt and not procs
            procs.append(self)

        def poll(self):
            return 1 if self.failed else None

        returncode = property(lambda self: 1 if self.failed else None)

        def terminate(self):
            self.calls.append("terminate")

        def wait(self):
            self.calls.append("wait")
            return -15

    def first_poll(seconds):
        if stop == KeyboardInterrupt:
            raise KeyboardInterrupt

    monkeypatch.setattr(run.subprocess, "Popen", Training)
    monkeypatch.setattr(run.time, "sleep", first_poll)
    cfg = budgeted("tiny", "ours", "cpu")
    settings = run.BenchmarkSettings(methods=["a", "b", "c"], iterations=2, parallel=2)
    with pytest.raises(KeyboardInterrupt if stop == KeyboardInterrupt else UserError):
        run._train_all({"a": cfg, "b": cfg, "c": cfg}, settings, [tmp_path], tmp_path, tmp_path)
    assert len(procs) == 2  # the third never started
    running = procs if stop == KeyboardInterrupt else procs[1:]
    assert all(p.calls == ["terminate", "wait"] for p in running) and all(not p.calls for p in procs if p not in running)
