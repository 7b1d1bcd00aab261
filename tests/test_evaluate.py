"""``sim2real evaluate`` on a tiny run: every metrics.json key present, FID with (fake) weights and
null with a reason without them, the report files, and the metric wiring on a 3D-consistent stand-in."""

import json
import math

import numpy as np
import pytest
import torch
from eval_data import SCENE_SEED, fake_fid_weights, labelled_real_dir, tiny_run
from train_data import real_dir, scene_dir

from sim2real.cli.main import main
from sim2real.inference.evaluate import EvalSettings, evaluate, find_real
from sim2real.inference.svg import svg_line_plot
from sim2real.inference.rows import pool_orb

TOP_KEYS = {"format", "run", "settings", "inputs", "fid", "kid_mean", "kid_std", "fid_kid", "proxy", "dice", "dice_a_ref",
            "dice_real_train", "dice_real_held_out", "dice_ceiling", "dice_info", "of_error", "of_epe", "orb", "orb_curve",
            "revisit", "odometry", "rows", "row_curves", "realism", "position", "calibration", "anchors", "warnings", "per_scene", "reasons", "seconds"}
ROW_NAMES = {"model", "ceiling", "floor", "a_ref"}
REASON_KEYS = {"fid", "dice", "of_error", "orb", "revisit"}
ORB_KEYS = {"k", "accuracy", "mean_correct", "correct", "total", "pairs", "mean_matches"}
PROXY_KEYS = {"proxy_colour_distance", "proxy_texture_distance", "proxy_colour_texture_distance",
              "proxy_grad_mean_gen", "proxy_grad_mean_real"}


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    base = tmp_path_factory.getbasetemp()
    tiny_run(base)
    return base


def run_cli(capsys, base, out, real, *extra):
    argv = ["evaluate", base / "eval_tiny_run", "--scenes", scene_dir(base, SCENE_SEED), "--real", real, "--out", out,
            "--views", 4, "--frames", 12, "--seg-iterations", 3, "--seg-size", "32x64", "--device", "cpu",
            "--no-progress", *extra]
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 0, err
    return json.loads((out / "metrics.json").read_text())


def check_keys(m):
    assert set(m) == TOP_KEYS
    assert set(m["reasons"]) == REASON_KEYS
    assert set(m["proxy"]) == PROXY_KEYS and all(math.isfinite(v) for v in m["proxy"].values())
    assert set(m["orb"]) == {"1", "5", "10"} and all(set(e) == ORB_KEYS for e in m["orb"].values())
    assert set(m["orb_curve"]) == {str(k) for k in range(1, 21)}
    assert set(m["revisit"]) == {"of_error", "orb", "backward_frames"} and set(m["revisit"]["orb"]) == {"1", "5", "10"}
    name = f"procedural_{SCENE_SEED:04d}"
    assert list(m["per_scene"]) == [name] and m["per_scene"][name]["frames"] == 12
    for key in ("fid", "dice", "of_error"):
        assert (m[key] is None) == (m["reasons"][key] is not None), key
    assert m["of_error"] is not None and math.isfinite(m["of_error"])
    assert m["orb"]["1"]["pairs"] == 11 and m["orb"]["10"]["pairs"] == 2 and m["orb_curve"]["12"]["pairs"] == 0
    # time-independent model: the revisit protocol equals the forward metric
    assert m["revisit"]["of_error"] == pytest.approx(m["of_error"])
    assert m["revisit"]["orb"]["1"] == m["orb"]["1"]
    assert set(m["rows"]) == ROW_NAMES and set(m["row_curves"]) == ROW_NAMES
    assert set(m["position"]) == set(m["rows"]["model"])
    assert m["settings"]["orb"]["patch_size"] < 31  # 64 px wide frames: ORB settings for the size
    assert m["per_scene"][name]["motion"]["pairs"] == 11


def check_report(out):
    md, page = (out / "report.md").read_text(), (out / "report.html").read_text()
    assert "ORB-1" in md and "FID" in md and "plots/orb_accuracy.svg" in md
    assert page.count("<svg") == 3 and "data:image/png;base64," in page
    assert "<title>sim2real evaluation</title>" in page
    assert "Between floor and ceiling" in page and "overlap 10" in page
    for rel in ("plots/orb_accuracy.svg", "plots/orb_correct.svg", "plots/of_error.svg", "samples/views.png",
                f"videos/procedural_{SCENE_SEED:04d}.mp4"):
        assert (out / rel).is_file(), rel
    return md


def test_evaluate_with_weights_and_labels(base, tmp_path, capsys):
    out = tmp_path / "eval"
    m = run_cli(capsys, base, out, labelled_real_dir(base), "--fid-weights", fake_fid_weights(base))
    check_keys(m)
    assert math.isfinite(m["fid"]) and math.isfinite(m["kid_mean"]) and m["reasons"]["fid"] is None
    assert m["run"]["compiled"] is False and m["run"]["amp_bf16"] is False
    # detail = mean grey gradient as a share of the real images'; the stand-in's mottling and noise
    # make the ceiling's views more detailed than the smooth, flat-coloured a_ref
    p = m["proxy"]
    assert m["rows"]["model"]["detail"] == pytest.approx(p["proxy_grad_mean_gen"] / p["proxy_grad_mean_real"])
    assert m["rows"]["ceiling"]["detail"] > m["rows"]["a_ref"]["detail"] > 0
    assert m["fid_kid"]["n_gen"] == 4 and m["fid_kid"]["n_real"] == 6 and m["fid_kid"]["kid_subset_size"] == 4
    # FID, KID and the proxy have a real row too: three real images against the other three
    real_row = {k: m["realism"][k]["rows"]["real_held_out"] for k in ("fid", "kid", "proxy")}
    assert all(v is not None and math.isfinite(v) for v in real_row.values()), real_row
    assert real_row["proxy"] < m["realism"]["proxy"]["rows"]["a_ref"]
    for key in ("dice_real_train", "dice_real_held_out"):  # 3 steps of training: unstable figures are None
        assert m[key] is None or 0.0 <= m[key] <= 1.0
    assert m["dice_info"]["n_held_out"] == 1 and len(m["dice_info"]["per_seed"]) == 5  # the default seeds
    assert m["dice_info"]["n_train"] == 5 and m["dice_info"]["n_eval"] == 4
    check_report(out)


def test_evaluate_without_weights_or_labels(base, tmp_path, capsys, monkeypatch):
    """Also the wiring of --compile: the run's inference networks reach the compiler, for the
    evaluation's device, and metrics.json records it (the compile itself: tests/test_translate.py)."""
    from sim2real.inference import model

    compiled = []
    monkeypatch.setattr(model, "compile_networks", lambda nets, dev: compiled.append((nets, dev)) or len(nets))
    monkeypatch.delenv("SIM2REAL_FID_WEIGHTS", raising=False)
    out = tmp_path / "eval"
    m = run_cli(capsys, base, out, real_dir(base), "--compile")
    check_keys(m)
    assert len(compiled) == 1 and str(compiled[0][1]) == "cpu"
    assert compiled[0][0] and all(isinstance(n, torch.nn.Module) for n in compiled[0][0])
    assert m["run"]["compiled"] is True
    assert m["fid"] is None and m["kid_mean"] is None and m["kid_std"] is None
    assert "SIM2REAL_FID_WEIGHTS" in m["reasons"]["fid"]
    assert m["dice"] is None and m["dice_a_ref"] is None and "labels" in m["reasons"]["dice"]
    md = check_report(out)
    assert "FID and KID are not reported" in md


def test_an_interrupted_evaluation_leaves_no_output_folder(base, tmp_path, capsys, monkeypatch):
    """Ctrl-C while the report is written, after the videos: no --out folder (a rerun into the
    same name is accepted) and nothing hidden beside it."""
    from sim2real.inference import evaluate

    written = []

    def interrupt(metrics, out, *args):
        written.extend(sorted(p.name for p in (out / "videos").iterdir()))
        raise KeyboardInterrupt

    monkeypatch.setattr(evaluate, "report_stage", interrupt)
    argv = ["evaluate", base / "eval_tiny_run", "--scenes", scene_dir(base, SCENE_SEED), "--real", real_dir(base),
            "--out", tmp_path / "eval", "--views", 4, "--frames", 4, "--seg-iterations", 1, "--seg-size", "32x64",
            "--device", "cpu", "--no-progress"]
    assert main([str(a) for a in argv]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == "sim2real: interrupted"
    assert f"procedural_{SCENE_SEED:04d}.mp4" in written
    assert list(tmp_path.iterdir()) == []


def test_bad_inputs_one_line(base, tmp_path, capsys):
    argv = ["evaluate", base / "eval_tiny_run", "--scenes", scene_dir(base, SCENE_SEED), "--real", real_dir(base),
            "--out", tmp_path / "o", "--trajectory", "a.txt", "b.txt"]
    assert main([str(a) for a in argv]) == 2
    assert "one trajectory per scene" in capsys.readouterr().err
    argv[-3:] = ["--fid-weights", tmp_path / "missing.pth"]
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "FID Inception weights not found" in err


def test_emulated_bf16_is_noted_before_the_evaluation(base, tmp_path, capsys, monkeypatch):
    """On a CPU without bf16 instructions, --precision bf16 is noted in one line before the
    evaluation starts (here stopped at once); with them, or in fp32, nothing is noted."""
    from sim2real.errors import UserError
    from sim2real.inference import evaluate

    def stop(*args, **kwargs):
        raise UserError(f"stopped here ({kwargs['precision']})")

    monkeypatch.setattr(evaluate, "evaluate", stop)
    argv = ["evaluate", base / "eval_tiny_run", "--scenes", scene_dir(base, SCENE_SEED), "--real", real_dir(base),
            "--out", tmp_path / "o", "--device", "cpu"]
    for has, extra, noted in ((False, ["--precision", "bf16"], True), (True, ["--precision", "bf16"], False),
                              (False, [], False)):
        monkeypatch.setattr("sim2real.engine.precision.cpu_has_bf16", lambda: has)
        assert main([str(a) for a in argv + extra]) == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert lines[-1].endswith(f"stopped here ({'bf16' if extra else 'auto'})")
        assert len(lines) == 1 + noted and (not noted or lines[0].startswith("note: this CPU has no bf16")), lines


def test_metric_wiring_on_a_consistent_texture(base, tmp_path, monkeypatch):
    """A stand-in 'translator' that paints a fixed 3D pattern on the surfaces is consistent by
    construction: its ORB matches must mostly land on the same 3D points, unlike shuffled frames."""
    from sim2real.inference import model

    def painted(gbuffers):
        out = []
        for g in gbuffers:
            p = g.points
            v = np.sin(p[..., 0] * 0.9) * np.sin(p[..., 1] * 0.7 + 1) * np.sin(p[..., 2] * 1.1 + 2)
            v = 0.5 + 0.5 * np.sign(v) * np.sqrt(np.abs(v))
            rgb = np.stack([v, 0.6 * v, 1 - v], -1) * g.mask[..., None]
            out.append((rgb * 255).astype(np.uint8))
        return out

    monkeypatch.setattr(model.TrainedModel, "translate_gbuffers", lambda self, name, gbuffers, batch=8: painted(gbuffers))
    monkeypatch.setattr(model.FrameSequence, "translate", lambda self, gbuffers: painted(gbuffers))
    monkeypatch.setattr(model.TrainedModel, "train_size", property(lambda self: (128, 256)))
    s = EvalSettings(views=2, frames=40, seg_iterations=0, orb_max_k=3, orb_features=500, samples=1, anchors=False,
                     trajectory={"flow_budget": None, "max_deg_per_frame": None, "look": "swing"})  # the fast path
    m = evaluate(base / "eval_tiny_run", [scene_dir(base, SCENE_SEED)], real_dir(base), tmp_path / "w", settings=s,
                 device="cpu", progress=False)
    orb1 = m["orb"]["1"]
    assert orb1["pairs"] == 39 and orb1["accuracy"] > 0.15 and orb1["mean_correct"] > 10
    assert m["orb"]["10"]["accuracy"] < orb1["accuracy"] / 3  # the sweep moves far in 10 frames
    assert m["of_error"] < 10.0
    assert m["revisit"]["orb"]["5"] == m["orb"]["5"]


def test_find_real_layouts_and_pooling(tmp_path):
    root = labelled_real_dir(tmp_path)
    rs = find_real(root)
    assert len(rs.images) == 6 and len(rs.labelled) == 6 and rs.root == root / "images"
    flat = find_real(real_dir(tmp_path))
    assert flat.labelled == []
    e1 = {"correct": 3, "total": 4, "pairs": 2}
    e2 = {"correct": 1, "total": 4, "pairs": 1}
    p = pool_orb([e1, e2], 1)
    assert p["accuracy"] == 0.5 and p["mean_correct"] == pytest.approx(4 / 3) and p["pairs"] == 3
    assert pool_orb([{"correct": 0, "total": 0, "pairs": 0}], 5)["accuracy"] is None
    svg = svg_line_plot({"a": [(1, 0.5), (2, None), (3, 0.7)], "b": []}, "t", "x", "y")
    assert svg.startswith("<svg") and svg.count("<circle") == 2
    assert "no data" in svg_line_plot({"a": [(1, None)]}, "t", "x", "y")
