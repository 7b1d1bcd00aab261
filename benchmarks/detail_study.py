"""The detail study ("Detail that stays", docs/detail_study.md): one lever setting, trained from scratch for a fixed
wall-clock budget on the demo's data, scored on the demo's test path; prints one JSON row and
appends it to ``--rows`` (JSON lines). ``--table ROWS`` prints the markdown table of a rows file.

Every run uses the same embedded data (``make_embedded_data``: seed 0, 2 scenes, the stand-in real
domain at the training size), the same test trajectory (``make_trajectory`` of the first scene,
seed 0, the evaluation's default motion budget: no training view lies on it) and the same seeds;
only the lever's ``--set`` assignments differ from the preset (``--preset``, default ``cpu``: the
demo's CPU configuration). ``--data-seed N``
makes the data of other scenes (seeds N, N + 1) in another ``--data`` folder; ``--init-from``
starts from a trained run or the shipped model instead of from scratch. Give every run
the same minutes on an otherwise idle machine (the runs are equal in wall-clock, not in steps).
Two rows may run at once, each pinned to its own core (``taskset -c 0`` / ``-c 1``); the row
records the cores and threads it had, so rows are compared only with rows of the same share.

Scores (from ``sim2real evaluate``, with the ceiling and the floor on the same path):
ORB-1/5/10 correct matches per pair as a fraction of the ceiling's, and their accuracy; the detail
statistic (mean grey gradient as a share of the real images'); Dice and a_ref's Dice.

Usage:
  python benchmarks/detail_study.py --data D --out RUNS --lever init_noise --minutes 30 \\
      --set method.texture.init_noise=1.0 --rows docs/detail_study.jsonl
  python benchmarks/detail_study.py --data D --out RUNS --lever longer --name init_noise --resume --minutes 40 ...
  python benchmarks/detail_study.py --table docs/detail_study.jsonl
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path


def data(root: Path, height: int, width: int, frames: int, seed: int = 0) -> tuple[list[Path], Path, Path]:
    """The shared inputs, made once under ``root``: scenes and real folder of ``seed``, test
    trajectory (seed 0 of the first scene)."""
    from sim2real.data.embedded import make_embedded_data
    from sim2real.render.raycast import RayCaster
    from sim2real.scene.scene import Scene
    from sim2real.scene.trajectory import make_trajectory

    done = root / "done.json"
    if not done.is_file():
        sim, real = make_embedded_data(root, seed, 2, 200, height, width, say=lambda m: print(m, file=sys.stderr))
        make_trajectory(RayCaster(Scene.load(sim[0])), frames, height, width, 75.0, seed=0).save(root / "trajectory.txt")
        done.write_text(json.dumps({"scenes": [str(s) for s in sim], "real": str(real)}))
    info = json.loads(done.read_text())
    return [Path(s) for s in info["scenes"]], Path(info["real"]), root / "trajectory.txt"


def _fraction(c, c_ceiling):
    return None if c is None or not c_ceiling else round(c / c_ceiling, 3)


def _cpu_name() -> str:
    """The CPU model (rows of different machines differ in steps per minute)."""
    import platform

    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _setting(args) -> str:
    parts = ([] if args.preset == "cpu" else [f"--preset {args.preset}"]) + list(args.set)
    if args.init_from:
        parts.append(f"--init-from {args.init_from}")
    if args.data_seed:
        parts.append(f"--data-seed {args.data_seed}")
    return " ".join(parts) or "(demo defaults)"


def run(args) -> dict:
    import torch

    from sim2real.config import override
    from sim2real.engine.trainer import Trainer
    from sim2real.inference.evaluate import EvalSettings, evaluate
    from sim2real.presets import budgeted
    from sim2real.threads import usable_cores

    cfg = override(budgeted(args.preset, args.method, "cpu"), args.set)
    scenes, real, traj = data(Path(args.data), cfg.data.height, cfg.data.width, args.frames, args.data_seed)
    out = Path(args.out) / args.name
    torch.set_num_threads(usable_cores())
    record = out / "study.json"  # the run's minutes so far (a resumed row reports the total)
    before = json.loads(record.read_text())["minutes"] if args.resume else 0.0
    if args.resume:
        from sim2real.engine.checkpoint import load_checkpoint
        from sim2real.presets import config_from_dict

        last = out / "run" / "checkpoints" / "last.pt"
        cfg = config_from_dict(load_checkpoint(last)["config"])
        trainer = Trainer(cfg, None, None, out / "run", resume=last, progress=False)
    else:
        from sim2real import shipped

        trainer = Trainer(cfg, [str(s) for s in scenes], str(real / "images"), out / "run", progress=False,
                          init_from=shipped.init_source(args.init_from) if args.init_from else None)
    t0 = time.perf_counter()
    try:
        trainer.train(time_limit_s=60.0 * args.minutes)
    finally:
        trainer.close()
    minutes = before + (time.perf_counter() - t0) / 60
    record.write_text(json.dumps({"minutes": minutes, "steps": trainer.step}))
    m = evaluate(out / "run", [str(scenes[0])], real, out / f"evaluation_{trainer.step:07d}", trajectories=[str(traj)],
                 settings=EvalSettings(views=32, frames=args.frames, seed=0), device="cpu", progress=False)
    rows = m["rows"]
    row = {"lever": args.lever, "setting": f"{args.name}, continued" if args.resume else _setting(args), "method": args.method,
           "minutes": round(minutes, 1), "steps": trainer.step, "cores": usable_cores(),
           "threads": torch.get_num_threads(), "machine": _cpu_name(), "command": " ".join(map(shlex.quote, sys.argv))}
    for k in (1, 5, 10):
        c, c_ceiling = rows["model"][f"orb_{k}_correct"], rows["ceiling"][f"orb_{k}_correct"]
        row[f"orb_{k}_of_ceiling"] = _fraction(c, c_ceiling)
        row[f"orb_{k}_accuracy"] = rows["model"][f"orb_{k}_accuracy"]
        row[f"orb_{k}_ceiling_correct"] = c_ceiling
        row[f"floor_orb_{k}_of_ceiling"] = _fraction(rows["floor"][f"orb_{k}_correct"], c_ceiling)
    row.update(detail=rows["model"].get("detail"), detail_ceiling=rows["ceiling"].get("detail"),
               dice=m["dice"], dice_a_ref=m["dice_a_ref"],
               # a Dice is withheld when the segmenter seeds disagree; the row keeps the means
               dice_a_ref_mean=m["dice_info"]["rows"].get("a_ref", {}).get("mean"),
               dice_mean=m["dice_info"]["rows"].get("model", {}).get("mean"),
               a_ref_orb_1_of_ceiling=_fraction(rows["a_ref"]["orb_1_correct"], rows["ceiling"]["orb_1_correct"]))
    return row


def table(rows_file: Path) -> str:
    def f(v, pct=False):
        return "–" if v is None else (f"{100 * v:.0f} %" if pct else f"{v:.3g}")

    head = "| lever | setting | min (cores) | steps | ORB-1 of ceiling (acc.) | ORB-5 | ORB-10 | detail | Dice (a_ref) |"
    lines = [head, "|" + "---|" * 9]
    for line in rows_file.read_text().splitlines():
        r = json.loads(line)
        orb = [f"{f(r[f'orb_{k}_of_ceiling'], True)} ({f(r[f'orb_{k}_accuracy'], True)})" for k in (1, 5, 10)]
        setting = r["setting"] if r["method"] == "ours" else f"--method {r['method']} {r['setting']}".replace(" (demo defaults)", "")
        lines.append(f"| {r['lever']} | `{setting}` | {r['minutes']} ({r.get('cores', '?')}) | {r['steps']} | " + " | ".join(orb)
                     + f" | {f(r['detail'])} | {f(r['dice'] or r.get('dice_mean'))} ({f(r['dice_a_ref'] or r.get('dice_a_ref_mean'))}) |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", type=Path, help="print the markdown table of a rows file and stop")
    ap.add_argument("--data", default="study_data", help="shared inputs (made once)")
    ap.add_argument("--out", default="study_runs")
    ap.add_argument("--lever", default="baseline")
    ap.add_argument("--name", help="run folder name (default: the lever)")
    ap.add_argument("--method", default="ours")
    ap.add_argument("--preset", default="cpu", help="the configuration the lever's --set list changes")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--resume", action="store_true",
                    help="continue the row's run (--name) for --minutes more, then score it (the row gives the total)")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--data-seed", type=int, default=0,
                    help="seed of the scenes and real domain made under --data (0: the demo's)")
    ap.add_argument("--init-from", help="start from a trained run's translator and discriminators "
                    "(a run folder, a checkpoint, or 'shipped'), fresh textures")
    ap.add_argument("--rows", type=Path, help="append the row to this JSON-lines file")
    args = ap.parse_args()
    if args.table:
        print(table(args.table))
        return
    args.name = args.name or args.lever
    row = run(args)
    print(json.dumps(row, indent=2))
    if args.rows:
        with open(args.rows, "a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
