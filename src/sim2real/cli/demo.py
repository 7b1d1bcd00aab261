"""``sim2real demo``: the whole path on data it makes itself (the embedded defaults).

1. procedural simulated scenes (seeds S, S+1, ...);
2. stand-in real images with labels, from scenes of other seeds (the domains are unpaired);
3. the trained model shipped in the package (``sim2real/shipped``: its scenes' geometry hash is
   checked), or with ``--train`` a training from scratch within a time budget (``--minutes``; on a
   GPU the paper preset);
4. translation of a 100-frame test trajectory to ``video.mp4`` with its ground truth;
5. evaluation (FID/KID when Inception weights are given, proxy distance, Dice, OF, ORB-k,
   revisit) and the report.
"""

from __future__ import annotations

import argparse
import sys
import time

from sim2real.cli.args import (
    add_motion_args,
    add_seg_iterations_arg,
    motion_kwargs,
    non_negative_int,
    positive_float,
    positive_int,
)
from sim2real.errors import UserError
from sim2real.fileio import atomic_write_json, removed_on_failure
from sim2real.presets import PRESETS, budgeted, config_from_dict, default_preset


class _Stopped(Exception):
    """Training was stopped by a signal (its number)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the pipeline end to end on procedural data it makes itself")
    p.add_argument("--out", required=True, help="new output directory")
    p.add_argument("--train", action="store_true",
                   help="train from scratch instead of using the shipped model")
    p.add_argument("--minutes", type=positive_float, default=None, help="with --train: training time budget (default 10)")
    p.add_argument("--preset", choices=tuple(PRESETS), default=None,
                   help="with --train; default: paper on a GPU, cpu on a CPU (sim2real/presets.py)")
    p.add_argument("--scenes", type=positive_int, default=None,
                   help="procedural simulated scenes (default 2; the shipped model's scenes without --train)")
    p.add_argument("--real-images", type=positive_int, default=200, help="stand-in real images")
    p.add_argument("--frames", type=positive_int, default=100, help="frames of the test trajectory")
    p.add_argument("--eval-views", type=positive_int, default=32, help="random views for the realism metrics")
    add_seg_iterations_arg(p)
    add_motion_args(p)
    p.add_argument("--fid-weights", default=None, help="pt_inception-2015-12-05 weights for FID/KID (optional)")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--seed", type=non_negative_int, default=None,
                   help="seed of the scenes and the real domain (default 0; the shipped model's without --train)")
    p.set_defaults(func=run)


def _shipped_settings(args) -> dict:
    """The shipped model's record, with ``args`` checked against it: its scenes are made from its
    seeds, and training flags need ``--train``."""
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real import shipped

    for flag, value in (("--minutes", args.minutes), ("--preset", args.preset)):
        if value is not None:
            raise UserError(f"{flag} sets the training; add --train to train from scratch instead of using the "
                            "shipped model")
    record = shipped.load_record()
    for flag, value, key in (("--seed", args.seed, "scene_seed"), ("--scenes", args.scenes, "scenes")):
        if value is not None and value != record[key]:
            raise UserError(f"the shipped model was trained on the scenes of {key.replace('_', ' ')} {record[key]}, "
                            f"not {flag} {value}; add --train to train on other scenes")
    args.seed, args.scenes = record["scene_seed"], record["scenes"]
    return record


def run(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    import torch

    from sim2real import shipped
    from sim2real.engine.checkpoint import load_checkpoint
    from sim2real.engine.device import resolve_device
    from sim2real.engine.stop import exit_code, signal_name
    from sim2real.inference.evaluate import EvalSettings, check_settings
    from sim2real.metrics.realism import fid_weights_status
    from sim2real.validation import validate

    cuda = args.device == "cuda" or (args.device == "auto" and torch.cuda.is_available())
    if args.train:
        args.minutes = 10.0 if args.minutes is None else args.minutes
        args.seed = 0 if args.seed is None else args.seed
        args.scenes = 2 if args.scenes is None else args.scenes
        args.preset = args.preset or default_preset(cuda)
        cfg = budgeted(args.preset, "ours", args.device)
        record = None
    else:
        record = _shipped_settings(args)
        cfg = config_from_dict(load_checkpoint(shipped.model_path())["config"])
    settings = EvalSettings(views=args.eval_views, frames=args.frames, seg_iterations=args.seg_iterations,
                            seed=args.seed, trajectory=motion_kwargs(args))
    # what would otherwise fail after the training: refused before anything is written
    validate(cfg)
    resolve_device(args.device)
    check_settings(settings)
    fid_weights_status(args.fid_weights)
    try:
        # a demo that fails or is stopped leaves no folder (or the empty one it was given)
        with removed_on_failure(args.out) as out:
            _make_demo(args, out, cfg, record, settings, cuda)
    except _Stopped as e:
        print(f"demo stopped by {signal_name(e.signum)} while training; nothing written", file=sys.stderr)
        return exit_code(e.signum)
    return 0


def _make_demo(args: argparse.Namespace, out, cfg, record: dict | None, settings, cuda: bool) -> None:
    """The five steps into ``out``; ``record``: the shipped model's (None with --train)."""
    from sim2real import shipped
    from sim2real.comparison.figures import side_by_side
    from sim2real.data.embedded import make_embedded_data
    from sim2real.engine.trainer import Trainer
    from sim2real.inference.evaluate import evaluate
    from sim2real.inference.model import load_run
    from sim2real.inference.translate import trajectory_source, translate_sequence
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.camera import view_intrinsics
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import make_trajectory

    h, w = cfg.data.height, cfg.data.width
    t0 = time.perf_counter()

    steps_said = iter(("1/5", "2/5"))
    # the shipped model's scenes are checked before anything is written (a mismatch leaves no demo)
    sim_dirs, _ = make_embedded_data(out, args.seed, args.scenes, args.real_images, h, w,
                                     say=lambda m: print(f"demo: {next(steps_said)} {m}", flush=True),
                                     check=None if args.train else lambda scenes: shipped.check_scenes(record, scenes))

    if args.train:
        print(f"demo: 3/5 training for {args.minutes:g} min ({'GPU' if cuda else 'CPU'})", flush=True)
        trainer = Trainer(cfg, scenes=[str(d) for d in sim_dirs], real=str(out / "real" / "images"), out=out / "run")
        try:
            trainer.train(time_limit_s=60.0 * args.minutes)
        finally:
            trainer.close()
        if trainer.stopped_by:  # Ctrl-C or SIGTERM while training: no demo of a half-trained model
            raise _Stopped(trainer.stopped_by)
        steps = trainer.step
    else:
        shipped.install_run(out / "run")
        steps = shipped.total_steps(record)
        print(f"demo: 3/5 the shipped model ({shipped.record_text(record)}); its scenes' geometry matches", flush=True)

    print("demo: 4/5 translating the test trajectory", flush=True)
    traj_path = out / "trajectory.txt"
    K = view_intrinsics(w, h, cfg.data.fov_x_deg, cfg.data.intrinsics)
    make_trajectory(RayCaster(Scene.load(sim_dirs[0])), args.frames, h, w, seed=args.seed, K=K,
                    **motion_kwargs(args)).save(traj_path)
    model = load_run(out / "run", device=args.device)
    translate_sequence(model, trajectory_source(model, sim_dirs[0], traj_path), out / "video")

    print("demo: 5/5 evaluation", flush=True)
    metrics = evaluate(out / "run", [str(sim_dirs[0])], out / "real", out / "evaluation", trajectories=[traj_path],
                       settings=settings, fid_weights=args.fid_weights, device=args.device)
    side_by_side(out / "side_by_side.png", {"model": out / "run"}, sim_dirs[0], traj_path, out / "real",
                 args.seed, args.device)
    atomic_write_json(out / "demo.json", {
        "model": "trained here" if args.train else "shipped",
        "preset": args.preset if args.train else f"{record.get('preset', shipped.PRESET)} (shipped)",
        "device": "cuda" if cuda else "cpu",
        "training_minutes": args.minutes if args.train else (record.get("trained") or {}).get("minutes"),
        "training_steps": steps,
        "wall_seconds": time.perf_counter() - t0,
        "video": "video/video.mp4",
        "ground_truth": "video/ground_truth",
        "metrics": "evaluation/metrics.json",
        "report": "evaluation/report.html",
        "figure": "side_by_side.png",
    })
    c2st = (metrics.get("realism", {}).get("c2st") or {}).get("rows", {})
    shown = {"Dice": metrics.get("dice"), "OF error (px)": metrics.get("of_error"),
             "C2ST AUC vs real (0.5 = indistinguishable)": c2st.get("model"), "FID": metrics.get("fid")}
    print(f"demo written to {out}: video/video.mp4, video/ground_truth/, evaluation/report.html, "
          f"side_by_side.png "
          f"({steps} training steps; " + ", ".join(f"{k} {'n/a' if v is None else f'{v:.3g}'}" for k, v in shown.items())
          + ")")
