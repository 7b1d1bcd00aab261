"""``sim2real train``: train textures + translator on simulated scenes and real images.

    sim2real train --preset {paper,small,tiny,cpu,cpu-lines} [--method NAME] --scenes DIR... --real DIR --out RUN
                   [--iterations N] [--max-minutes M] [--checkpoint-every N] [--device {auto,cpu,cuda}]
                   [--set section.field=value ...] [--config YAML] [--resume]
    sim2real train --init-from RUN|shipped --scenes DIR... --real DIR --out RUN [--preset ...] [--set ...]
    sim2real train --out RUN --resume [--iterations N] [--set ...]

``--init-from`` starts a new run from a trained run's translator and discriminators, with fresh
neural textures for the given scenes, and takes over that run's configuration (method section,
losses, optimiser, sizes; for ``shipped`` the YAML beside the shipped weights, the ``cpu-lines``
preset). ``--preset``, ``--config`` or ``--set`` on the same command override it; every key that
then differs from the source's is printed.

``--resume`` continues RUN from its last checkpoint, in one of two ways:

* the command that started the run, with ``--resume`` appended: every flag must agree with
  the checkpoint's configuration and inputs, except ``--iterations``, ``--max-minutes`` and
  ``--checkpoint-every``; a conflict is refused, naming each key with both values;
* ``--out RUN --resume`` alone: the checkpoint's configuration and inputs, changed only by the
  flags given (e.g. ``--set data.workers=4``); each change is printed.

SIGTERM or SIGINT stops the run after the step in progress with a checkpoint; the exit code is
then 128 + the signal's number (143, 130). One process at a time may write to a run folder.
Multi-GPU / multi-node: start it with ``torchrun`` (docs/training.md).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from sim2real.cli.args import positive_float, positive_int
from sim2real.config import differences, override
from sim2real.errors import UserError
from sim2real.presets import PRESETS, config_from_dict, load_config, preset

RESUMABLE = ("iterations", "checkpoint_every")
"""Config fields that a resume may change without notice (so may ``--max-minutes``)."""


def register(sub) -> None:
    p = sub.add_parser("train", help="train neural textures and the translator (docs/training.md)")
    p.add_argument("--preset", help="configuration preset: " + ", ".join(PRESETS) + " (sim2real/presets.py)")
    p.add_argument("--method", help="method or method preset with --preset (default: ours): ours, ours_no_vc, "
                                    "ours_l1_vc, ours_no_tex_vc, ... (sim2real/methods/)")
    p.add_argument("--config", help="YAML configuration (e.g. a run's config.yaml) instead of a preset")
    p.add_argument("--scenes", nargs="+", metavar="DIR",
                   help="scene folders (fresh random views are ray-cast) or views folders (cached G-buffers)")
    p.add_argument("--real", metavar="DIR", help="folder of real images (png/jpg, searched recursively)")
    p.add_argument("--out", required=True, metavar="RUN", help="run folder (new and empty, or the run to resume)")
    p.add_argument("--iterations", type=positive_int, help="total training iterations")
    p.add_argument("--max-minutes", type=positive_float,
                   help="also stop (with a checkpoint) once this wall-clock budget is spent, e.g. a job's time limit")
    p.add_argument("--checkpoint-every", type=positive_int, help="iterations between checkpoints")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), help="where to train (default: config, auto)")
    p.add_argument("--set", dest="overrides", action="append", nargs="+", default=[], metavar="KEY=VALUE",
                   help="override any config field, e.g. --set method.vc=10 data.workers=4")
    p.add_argument("--init-from", metavar="RUN", help="start from a trained run's (or checkpoint's) networks and "
                                                      "configuration, with fresh neural textures for these scenes; "
                                                      "'shipped': the demo model inside the package (preset "
                                                      "cpu-lines)")
    p.add_argument("--resume", action="store_true",
                   help="continue RUN from RUN/checkpoints/last.pt (append it to the run's command, or give --out alone)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def build_config(args: argparse.Namespace, base=None):
    """The effective config: preset / YAML / checkpoint config, then the direct flags, then --set."""
    if args.method and not args.preset:
        raise UserError("--method goes with --preset (a --config file or a resumed run names its own method)")
    if base is not None:
        cfg = base
    elif args.config:
        cfg = load_config(args.config)
    else:
        cfg = preset(args.preset, args.method or "ours")
    sets = [s for group in args.overrides for s in group]
    if args.iterations is not None:
        sets.insert(0, f"iterations={args.iterations}")
    if args.checkpoint_every is not None:
        sets.insert(0, f"checkpoint_every={args.checkpoint_every}")
    if args.device is not None:
        sets.insert(0, f"device={args.device}")
    return override(cfg, sets)


def _show(value) -> str:
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(map(_show, value)) + "]"
    return str(value)


def resume_config(args: argparse.Namespace, state: dict, path) -> tuple[object, list[tuple[str, object, object]]]:
    """The config of a resumed run and the changes it makes to the checkpoint's, as
    ``(key, checkpoint value, new value)``.

    With ``--preset`` or ``--config`` the flags must describe the checkpoint's run: the config
    they build is compared with the checkpoint's field by field (``RESUMABLE`` fields aside),
    and ``--scenes`` / ``--real`` with its inputs; any difference is refused, all of them
    named in one line. Without, the checkpoint's config is changed by the flags given.
    """
    saved = config_from_dict(state["config"])
    given = args.preset or args.config
    cfg = build_config(args, None if given else saved)
    changes = [d for d in differences(saved, cfg) if d[0] not in RESUMABLE]
    inputs = state["inputs"]
    if args.scenes and [str(Path(s).resolve()) for s in args.scenes] != inputs["scenes"]:
        changes.append(("--scenes", inputs["scenes"], [str(Path(s).resolve()) for s in args.scenes]))
    if args.real and str(Path(args.real).resolve()) != inputs["real"]:
        changes.append(("--real", inputs["real"], str(Path(args.real).resolve())))
    if given and changes:
        listed = "; ".join(f"{k}: {_show(a)} in the checkpoint, {_show(b)} here" for k, a, b in changes)
        raise UserError(f"--resume: the flags conflict with checkpoint {path} (step {state['step']}): {listed}. "
                        "Give the run's own values, or change fields on purpose with "
                        "'--out RUN --resume --set KEY=VALUE' (no --preset/--config)")
    return cfg, changes


def init_config(source) -> tuple:
    """The configuration that ``--init-from SOURCE`` takes over, and the loaded checkpoint (None
    when not read): for the shipped model the YAML beside its weights, else the checkpoint's."""
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real import shipped
    from sim2real.engine import checkpoint as ckpt

    if Path(source) == shipped.model_path():
        return load_config(shipped.config_path()), None
    state = ckpt.load_checkpoint(ckpt.find_run_checkpoint(source))
    return config_from_dict(state["config"]), state


def run(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real import shipped
    from sim2real.data.real import enlargement_note, field_of_view_note
    from sim2real.scene.camera import horizontal_fov_deg, view_intrinsics
    from sim2real.engine import checkpoint as ckpt
    from sim2real.engine.stop import exit_code, signal_name
    from sim2real.engine.trainer import Trainer

    state = path = init_state = None
    changes = []
    if args.init_from and args.resume:
        raise UserError("--init-from starts a new run; it cannot be combined with --resume")
    if args.preset and args.config:
        raise UserError("give either --preset or --config, not both")
    if args.resume:
        path = Path(args.out) / "checkpoints" / ckpt.LAST
        if not path.is_file():
            raise UserError(f"nothing to resume: no checkpoint at {path}")
        state = ckpt.load_checkpoint(path)
        cfg, changes = resume_config(args, state, path)
    else:
        if not args.preset and not args.config and not args.init_from:
            raise UserError("give --preset (" + ", ".join(PRESETS) + "), --config or --init-from, or --resume a run")
        if not args.scenes:
            raise UserError("no simulated scenes given (--scenes DIR...)")
        if not args.real:
            raise UserError("no real image folder given (--real DIR)")
        if args.init_from:
            given_source, args.init_from = args.init_from, shipped.init_source(args.init_from)
            source, init_state = init_config(args.init_from)
            cfg = build_config(args, None if args.preset or args.config else source)
            overrides = differences(source, cfg)
            listed = ", ".join(f"{k} {_show(a)} -> {_show(b)}" for k, a, b in overrides) or "none"
            if os.environ.get("RANK", "0") == "0":  # once under torchrun
                print(f"--init-from {given_source}: its configuration, overridden: {listed}", flush=True)
        else:
            cfg = build_config(args)
    trainer = Trainer(cfg, scenes=args.scenes, real=args.real, out=args.out, resume=path,
                      progress=not args.no_progress, resume_state=state, init_from=args.init_from,
                      init_state=init_state)
    try:
        if state is None and trainer.dist.is_main:  # once per run, on its first start
            factors = trainer.real.enlargements(cfg.data.height, cfg.data.width)
            note = enlargement_note(factors, cfg.data.height, cfg.data.width) if factors else None
            if note:
                print(note, flush=True)
            d = cfg.data
            sim_deg = horizontal_fov_deg(view_intrinsics(d.width, d.height, d.fov_x_deg, d.intrinsics), d.width)
            note = field_of_view_note(trainer.real.crop_fields_of_view(d.height, d.width), sim_deg,
                                      d.real_scale_min, d.real_scale_max)
            if note:
                print(note, flush=True)
        if changes and trainer.dist.is_main:
            listed = ", ".join(f"{k} {_show(a)} -> {_show(b)}" for k, a, b in changes)
            print(f"resuming {args.out} at step {trainer.step} with changes: {listed}", flush=True)
        last = trainer.train(time_limit_s=None if args.max_minutes is None else 60.0 * args.max_minutes)
    finally:
        trainer.close()
    if trainer.stopped_by:
        if trainer.dist.is_main:
            print(f"training stopped by {signal_name(trainer.stopped_by)} at step {trainer.step}; checkpoint {last} "
                  "(continue with --resume)")
        return exit_code(trainer.stopped_by)
    if trainer.dist.is_main:
        print(f"training finished at step {trainer.step}; checkpoint {last}")
    return 0
