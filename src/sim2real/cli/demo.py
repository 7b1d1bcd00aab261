"""``sim2real demo``: the whole path on data it makes itself (the embedded defaults).

1. procedural simulated scenes (seeds S, S+1, ...);
2. stand-in real images with labels, from scenes of other seeds (the domains are unpaired);
3. training within a time budget (``--minutes``); on a GPU it picks the paper preset;
4. translation of a 100-frame test trajectory to ``video.mp4`` with its ground truth;
5. evaluation (FID/KID when Inception weights are given, proxy distance, Dice, OF, ORB-k,
   revisit) and the report.
"""

from __future__ import annotations

import argparse
import time

from sim2real.cli.args import add_motion_args, motion_kwargs, non_negative_int, positive_float, positive_int

def register(sub) -> None:
    p = sub.add_parser("demo", help="run the pipeline end to end on procedural data it makes itself")
    p.add_argument("--out", required=True, help="new output directory")
    p.add_argument("--minutes", type=positive_float, default=10.0, help="training time budget")
    p.add_argument("--preset", choices=("paper", "small", "tiny"), default=None,
                   help="default: paper on a GPU, a lighter 'small' (16 filters) on a CPU")
    p.add_argument("--scenes", type=positive_int, default=2, help="procedural simulated scenes")
    p.add_argument("--real-images", type=positive_int, default=200, help="stand-in real images")
    p.add_argument("--frames", type=positive_int, default=100, help="frames of the test trajectory")
    p.add_argument("--eval-views", type=positive_int, default=32, help="random views for the realism metrics")
    p.add_argument("--seg-iterations", type=positive_int, default=600,
                   help="training steps of each Dice segmenter at most (each stops when its held-out Dice converges)")
    add_motion_args(p)
    p.add_argument("--fid-weights", default=None, help="pt_inception-2015-12-05 weights for FID/KID (optional)")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--seed", type=non_negative_int, default=0)
    p.set_defaults(func=run)


def demo_config(preset_name: str | None, cuda: bool, device: str, method: str = "ours"):
    """The demo's training configuration of ``method``: the paper preset on a GPU, on a CPU the
    'small' preset with 16 filters (and, for ``ours``, view consistency from step 300)."""
    from sim2real.config import override, preset

    name = preset_name or ("paper" if cuda else "small")
    cfg = preset(name, method)
    sets = [f"device={device}", "iterations=10000000", "deterministic=false"]
    if name == "small" and preset_name is None:
        # ~0.7 s per iteration on a 2-core CPU (DESIGN.md); switch view consistency on early.
        sets += ["generator.filters=16", "discriminator.filters=16", "checkpoint_every=100", "image_every=100",
                 "log_every=20"]
        if hasattr(cfg.method, "vc_start"):
            sets.append("method.vc_start=300")
    elif name == "tiny":
        sets += ["checkpoint_every=5", "image_every=5", "log_every=5"]
    return override(cfg, sets)


def run(args: argparse.Namespace) -> int:
    import torch

    from sim2real.config import validate
    from sim2real.engine.trainer import Trainer, resolve_device
    from sim2real.fileio import atomic_write_json, prepare_output_dir
    from sim2real.inference.evaluate import EvalSettings, check_settings, evaluate
    from sim2real.inference.translate import load_run, trajectory_source, translate_sequence
    from sim2real.metrics.realism import fid_weights_status
    from sim2real.render.raycast import RayCaster
    from sim2real.data.embedded import make_embedded_data
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import make_trajectory

    cuda = args.device == "cuda" or (args.device == "auto" and torch.cuda.is_available())
    cfg = demo_config(args.preset, cuda, args.device)
    h, w = cfg.data.height, cfg.data.width
    settings = EvalSettings(views=args.eval_views, frames=args.frames, seg_iterations=args.seg_iterations,
                            seed=args.seed, trajectory=motion_kwargs(args))
    # what would otherwise fail after the training: refused before anything is written
    validate(cfg)
    resolve_device(args.device)
    check_settings(settings)
    fid_weights_status(args.fid_weights)
    out = prepare_output_dir(args.out)
    t0 = time.perf_counter()

    steps_said = iter(("1/5", "2/5"))
    sim_dirs, _ = make_embedded_data(out, args.seed, args.scenes, args.real_images, h, w,
                                     say=lambda m: print(f"demo: {next(steps_said)} {m}", flush=True))

    print(f"demo: 3/5 training for {args.minutes:g} min ({'GPU' if cuda else 'CPU'})", flush=True)
    trainer = Trainer(cfg, scenes=[str(d) for d in sim_dirs], real=str(out / "real" / "images"), out=out / "run")
    try:
        trainer.train(time_limit_s=60.0 * args.minutes)
    finally:
        trainer.close()
    steps = trainer.step

    print("demo: 4/5 translating the test trajectory", flush=True)
    traj_path = out / "trajectory.txt"
    make_trajectory(RayCaster(Scene.load(sim_dirs[0])), args.frames, h, w, cfg.data.fov_x_deg,
                    seed=args.seed, **motion_kwargs(args)).save(traj_path)
    model = load_run(out / "run", device=args.device)
    translate_sequence(model, trajectory_source(model, sim_dirs[0], traj_path), out / "video")

    print("demo: 5/5 evaluation", flush=True)
    metrics = evaluate(out / "run", [str(sim_dirs[0])], out / "real", out / "evaluation", trajectories=[traj_path],
                       settings=settings, fid_weights=args.fid_weights, device=args.device)
    atomic_write_json(out / "demo.json", {
        "preset": args.preset or ("paper" if cuda else "small-16"),
        "device": "cuda" if cuda else "cpu",
        "training_minutes": args.minutes,
        "training_steps": steps,
        "wall_seconds": time.perf_counter() - t0,
        "video": "video/video.mp4",
        "ground_truth": "video/ground_truth",
        "metrics": "evaluation/metrics.json",
        "report": "evaluation/report.html",
    })
    shown = {"Dice": metrics.get("dice"), "OF error (px)": metrics.get("of_error"), "FID": metrics.get("fid")}
    print(f"demo written to {out}: video/video.mp4, video/ground_truth/, evaluation/report.html "
          f"({steps} training steps; " + ", ".join(f"{k} {'n/a' if v is None else f'{v:.3g}'}" for k, v in shown.items())
          + ")")
    return 0
