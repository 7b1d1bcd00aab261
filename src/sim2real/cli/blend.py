"""``sim2real blend setup``: Blender's Python module in its own environment, for .blend import."""

from __future__ import annotations

import argparse


def register(sub) -> None:
    p = sub.add_parser("blend", help="set up reading Blender .blend files (bpy in its own environment)")
    ss = p.add_subparsers(dest="blend_command", required=True, parser_class=type(p))
    s = ss.add_parser("setup", help="install bpy into its own virtual environment (about 1 GB, a few minutes)")
    s.set_defaults(func=_setup)


def _setup(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real.scene.blend import BPY_REQUIREMENT, setup, venv_dir

    print(f"installing {BPY_REQUIREMENT} into {venv_dir()} (set SIM2REAL_BLEND_VENV for another place)")
    path = setup()
    print(f"Blender's Python module is ready in {path}; 'sim2real scene import --mesh FILE.blend' reads .blend files")
    return 0
