"""``sim2real doctor``: what this machine offers sim2real (GPU, CPU, loader workers, shared
memory, cache disk, compiler, video, FID weights, Blender), each with the fix where one is needed.

    sim2real doctor [--compile] [--json]

Exit status 0, or 1 when a check warns (a setting that will slow or stop a run).
"""

from __future__ import annotations

import argparse
import json


def register(sub) -> None:
    p = sub.add_parser("doctor", help="check what this machine offers sim2real (GPU, workers, shared memory, disk)")
    p.add_argument("--compile", action="store_true",
                   help="also compile a one-line function, as --compile of translate and evaluate would (seconds to a minute)")
    p.add_argument("--json", action="store_true", help="print the checks and their figures as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # imported here, not at the top: 'sim2real --help' starts without torch and trimesh
    from sim2real.doctor import as_json, run_checks

    checks = run_checks(compile_probe=args.compile)
    if args.json:
        print(json.dumps(as_json(checks), indent=2))
    else:
        for c in checks:
            print(f"{c.status:<5} {c.name:<8} {c.text}")
    return 1 if any(c.status == "warn" for c in checks) else 0
