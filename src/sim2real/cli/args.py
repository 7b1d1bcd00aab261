"""Argument types shared by the sub-commands: they turn bad values into one-line errors."""

from __future__ import annotations

import argparse

from sim2real.scene.conventions import DEFAULT_FLOW_BUDGET, DEFAULT_MAX_DEG_PER_FRAME, LOOKS


def int_range(low: int, high: int | None = None):
    """An argparse type: an integer from ``low`` to ``high`` (no upper bound without ``high``)."""
    what = (f"an integer from {low} to {high}" if high is not None
            else "a positive integer" if low == 1 else f"an integer >= {low}")

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got '{text}'") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"expected {what}, got '{text}'")
        return value

    return parse


positive_int = int_range(1)
non_negative_int = int_range(0)


def counted(n: int, noun: str) -> str:
    """``n`` and ``noun``, plural unless ``n`` is 1: "1 object", "3 objects"."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got '{text}'") from None
    if not value > 0 or value != value or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number, got '{text}'")
    return value


def non_negative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got '{text}'") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got '{text}'")
    return value


def add_motion_args(p) -> None:
    """The motion budget of generated test paths (:func:`sim2real.scene.trajectory.make_trajectory`)."""
    p.add_argument("--flow-budget", type=non_negative_float, default=DEFAULT_FLOW_BUDGET, metavar="F",
                   help=f"median ground-truth flow per frame, fraction of the width (default {DEFAULT_FLOW_BUDGET:g}; "
                        "0 = unbounded)")
    p.add_argument("--max-deg-per-frame", type=non_negative_float, default=DEFAULT_MAX_DEG_PER_FRAME, metavar="D",
                   help=f"camera rotation per frame, degrees (default {DEFAULT_MAX_DEG_PER_FRAME:g}; 0 = unbounded)")
    p.add_argument("--look", choices=LOOKS, default="smooth",
                   help="smooth look-at (default) or 'swing' between random liver points; "
                        "'--look swing --flow-budget 0 --max-deg-per-frame 0' is the old, fast stress-test path")


def motion_kwargs(args) -> dict:
    return {"flow_budget": args.flow_budget or None, "max_deg_per_frame": args.max_deg_per_frame or None,
            "look": args.look}


SEG_ITERATIONS = 200
"""Default training steps of each Dice segmenter (``EvalSettings.seg_iterations``, repeated here
because this module imports no torch; tests/test_cli_errors.py holds them equal)."""


def add_seg_iterations_arg(p) -> None:
    """``--seg-iterations`` of the commands that evaluate (0: no Dice segmenter is trained)."""
    p.add_argument("--seg-iterations", type=non_negative_int, default=SEG_ITERATIONS,
                   help=f"training steps of each Dice segmenter, exactly (deterministic; default {SEG_ITERATIONS})")


PRECISIONS = ("auto", "fp32", "bf16")
"""The choices of ``--precision`` (:data:`sim2real.engine.precision.INFERENCE_PRECISIONS`,
repeated here because this module imports no torch)."""


def add_precision_arg(p) -> None:
    """``--precision`` of the commands that run a trained network."""
    p.add_argument("--precision", choices=PRECISIONS, default="auto",
                   help="network arithmetic: auto (default: the run's bf16 on CUDA, fp32 on the CPU), fp32, or bf16 "
                        "(also on a CPU: 1.3-1.6x faster networks where the CPU has AVX512-BF16 or AMX, frames "
                        "within a few levels of fp32; elsewhere bf16 is emulated and many times slower: "
                        "'sim2real doctor' says which)")


EMULATED_BF16 = ("note: this CPU has no bf16 instructions (AVX512-BF16 or AMX on x86, BF16 on Arm), so --precision "
                 "bf16 is emulated, many times slower than fp32; leave it out for speed")
"""What translate and evaluate print (to stderr) before running emulated bf16."""


def add_compile_arg(p) -> None:
    """``--compile`` of the commands that run a trained network."""
    p.add_argument("--compile", action="store_true",
                   help="compile the networks (TorchInductor; needs a C++ compiler on the CPU): the first frames wait "
                        "for the compiler (15-20 s on a 2-core CPU, a few once cached), the rest run faster; "
                        "for long trajectories")


def add_camera_args(p: argparse.ArgumentParser) -> None:
    """``--fov`` or ``--intrinsics``: the pinhole camera of generated views (:func:`camera_matrix`)."""
    p.add_argument("--fov", type=positive_float, default=None, help="horizontal field of view, degrees (default 75)")
    p.add_argument("--intrinsics", default=None, metavar="FX,FY,CX,CY",
                   help="a calibrated endoscope's pinhole intrinsics in pixels of --width x --height, "
                        "instead of --fov (lens distortion is not modelled)")


def camera_matrix(args: argparse.Namespace):
    """The 3x3 K of :func:`add_camera_args`' flags at ``args.width`` x ``args.height``; a bad value
    or both flags: :class:`~sim2real.errors.UserError`."""
    from sim2real.errors import UserError
    from sim2real.scene.camera import view_intrinsics
    from sim2real.scene.io import parse_vector

    values = None
    if args.intrinsics is not None:
        if args.fov is not None:
            raise UserError("give --fov or --intrinsics, not both")
        values = parse_vector(args.intrinsics, 4, "--intrinsics")
    return view_intrinsics(args.width, args.height, 75.0 if args.fov is None else args.fov, values)
