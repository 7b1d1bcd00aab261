"""The ``sim2real`` command. Each sub-command lives in its own module with ``register``."""

from __future__ import annotations

import argparse
import gc
import importlib
import os
import re
import signal
import sys

from sim2real.engine.stop import Terminated, exit_code, sigterm_raises
from sim2real.errors import UserError, machine_error

COMMANDS = ("scene", "blend", "render", "realdomain", "realset", "train", "translate", "evaluate", "demo", "benchmark",
            "doctor")
"""Modules of :mod:`sim2real.cli`, each exposing ``register(subparsers)``."""


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # A value that starts with '-' and a digit is a value, not an option: coordinate lists
        # such as "--camera-region -40,60,200,25,25,10" need no '='. (argparse only knows plain
        # negative numbers; Python 3.13 widened its own pattern the same way.) No option of the
        # command line starts with '-' and a digit.
        self._negative_number_matcher = re.compile(r"^-\.?\d")

    def error(self, message: str) -> None:  # one line, exit code 2, no usage dump
        self.exit(2, f"sim2real: error: {message}\n")

    def add_subparsers(self, **kwargs):
        kwargs.setdefault("action", _Commands)
        return super().add_subparsers(**kwargs)


class _Commands(argparse._SubParsersAction):
    """Sub-commands whose own ``--help`` starts with the line the command list shows for them."""

    def add_parser(self, name, **kwargs):
        text = kwargs.get("help")
        if text and "description" not in kwargs:
            kwargs["description"] = f"{text[0].upper()}{text[1:]}."
        return super().add_parser(name, **kwargs)


DESCRIPTION = ("Turn simulated surgical 3D scenes into laparoscopic-looking videos that stay consistent over "
               "the long term, with exact ground truth (depth, optical flow, camera poses, labels).")
EPILOG = ("'sim2real COMMAND --help' lists a command's options; 'sim2real demo --out demo' runs the whole "
          "pipeline on embedded data. Every command: docs/commands.md.")


def build_parser() -> argparse.ArgumentParser:
    from sim2real import __version__

    parser = _Parser(prog="sim2real", description=DESCRIPTION, epilog=EPILOG)
    parser.add_argument("--version", action="version", version=f"sim2real {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name in COMMANDS:
        importlib.import_module(f"sim2real.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run a command. Without ``argv`` (the ``sim2real`` entry point: the process ends next) the
    objects left are frozen out of the garbage collector, whose sweeps at interpreter exit
    otherwise took 0.3 s after trimesh and scipy were imported; nothing is left open by then."""
    args = build_parser().parse_args(argv)
    try:
        with sigterm_raises():
            code = int(args.func(args) or 0)
        if argv is None:
            gc.freeze()
        return code
    except UserError as e:
        print(f"sim2real: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sim2real: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("sim2real: terminated (SIGTERM)", file=sys.stderr)
        return exit_code(signal.SIGTERM)
    except Exception as e:  # an unexpected failure still gets one line; SIM2REAL_DEBUG=1 shows it all
        if os.environ.get("SIM2REAL_DEBUG"):
            raise
        machine = machine_error(e)
        if machine is not None:  # a full disk or a forbidden place: said as such, not as a bug
            print(f"sim2real: error: {machine}", file=sys.stderr)
            return 1
        print(f"sim2real: internal error: {type(e).__name__}: {e} (set SIM2REAL_DEBUG=1 for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
