"""``sim2real benchmark``: the paper's Table 1 in one command.

Every method (a preset of :data:`sim2real.presets.METHOD_PRESETS`) is trained on the same data
with the same seed for the same budget (wall-clock minutes or iterations; both are recorded),
translates the same test trajectories, and is scored by the one evaluator
(:func:`sim2real.inference.evaluate.evaluate`: FID/KID with weights, else the named proxy; Dice;
OF error; ORB-1/5/10; the revisit protocol). The ceiling and the floor are scored once, with the
first method, on the very same views and paths: every method's temporal figures stand beside them.

Layout of ``OUT``::

    benchmark.json            the settings (a resume must match them)
    data/                     the embedded scenes and stand-in real domain (without data flags)
    trajectories/             the generated test paths, one per evaluated scene
    runs/METHOD/              training runs; done.json once the budget is spent
    runs/METHOD.seedS/        further seeds of a method (``--seeds``), evaluated on the same views
    translations/METHOD/      frames, video.mp4 and ground truth of the first test path
    evaluations/METHOD/       metrics.json, report.html
    videos/METHOD.mp4         one video per method
    table.md, table.json      Table 1 (comparison/table.py)
    report.html               bar charts and the side-by-side views (comparison/figures.py)

A killed benchmark continues with ``--resume``: finished trainings, translations and evaluations
are kept (their marker files say so), an interrupted training resumes from its checkpoint with
what is left of its budget, and unfinished outputs are redone.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

from sim2real.comparison.figures import side_by_side, write_report
from sim2real.comparison.table import build_table, write_table
from sim2real.config import override, to_dict
from sim2real.data.embedded import make_embedded_data
from sim2real.data.real import RealImages, RealSequences
from sim2real.engine.device import resolve_device
from sim2real.engine.trainer import Trainer
from sim2real.errors import UserError
from sim2real.fileio import atomic_write_json, atomic_write_json as write, prepare_output_dir
from sim2real.inference.evaluate import EvalSettings, check_settings, evaluate
from sim2real.inference.model import load_run
from sim2real.inference.translate import trajectory_source, translate_sequence
from sim2real.methods import get_method
from sim2real.metrics.realism import fid_weights_status
from sim2real.presets import METHOD_PRESETS, budgeted, config_from_dict, default_preset
from sim2real.render.raycast import RayCaster
from sim2real.scene.camera import view_intrinsics
from sim2real.scene.scene import Scene
from sim2real.scene.trajectory import make_trajectory
from sim2real.threads import usable_cores
from sim2real.validation import validate

FORMAT = "sim2real-benchmark/1"


@dataclass
class BenchmarkSettings:
    """What ``sim2real benchmark`` compares, and how long each method trains."""

    methods: list[str]
    minutes: float | None = None
    """Wall-clock training budget per method (exclusive with ``iterations``)."""
    iterations: int | None = None
    """Iteration budget per method."""
    preset: str | None = None
    """Preset name (sim2real/presets.py); None: paper on a GPU, cpu on a CPU."""
    seed: int = 0
    device: str = "auto"
    scenes: int = 2
    """Embedded simulated scenes (without --scenes)."""
    real_images: int = 200
    sequences: int = 4
    """Stand-in real sequences (for the video methods) without --real."""
    sequence_frames: int = 30
    frames: int = 100
    eval_views: int = 32
    seg_iterations: int = EvalSettings.seg_iterations
    trajectory: dict = field(default_factory=dict)
    """Motion budget of the generated test paths (make_trajectory keywords)."""
    seeds: int = 1
    """Trainings of each method in ``seeds_for``, with the seeds ``seed``, ``seed + 1``, ...; the
    data, the test paths and the evaluation's views stay those of ``seed``."""
    seeds_for: list[str] | None = None
    """The methods trained ``seeds`` times (None: every method); the others train once."""
    parallel: int = 1
    """Methods trained at once, each in its own process on ``cores // parallel`` threads (every
    method then trains under the same conditions; on a 2-core CPU two single-thread trainings
    make more steps in all than one two-thread training after the other)."""


def _say(msg: str) -> None:
    print(f"benchmark: {msg}", file=sys.stderr, flush=True)


def method_config(s: BenchmarkSettings, method: str, cuda: bool, seed: int | None = None):
    """The training configuration of ``method`` in this benchmark: its preset (default: ``paper`` on
    a GPU, ``cpu`` on a CPU) for a run that the budget ends, trained with ``seed`` (default ``s.seed``)."""
    cfg = budgeted(s.preset or default_preset(cuda), method, s.device)
    sets = [f"seed={s.seed if seed is None else seed}"]
    if s.iterations is not None:
        sets.append(f"iterations={s.iterations}")
        sets.append(f"checkpoint_every={min(cfg.checkpoint_every, s.iterations)}")
    return override(cfg, sets)


def run_names(s: BenchmarkSettings) -> dict[str, tuple[str, int]]:
    """Every training run of the benchmark: ``{run name: (method, seed)}``, a method's first seed
    under its own name, its further seeds as ``METHOD.seedS``."""
    runs = {}
    for m in s.methods:
        runs[m] = (m, s.seed)
        if s.seeds_for is None or m in s.seeds_for:
            runs.update({f"{m}.seed{s.seed + i}": (m, s.seed + i) for i in range(1, s.seeds)})
    return runs


def _uses_sequences(cfg) -> bool:
    return get_method(cfg).data == "triplets"


def check(s: BenchmarkSettings, out: Path, scenes, real, trajectories, resume: bool, fid_weights) -> dict:
    """Every input checked before anything is written or trained; returns the method configs."""
    if not s.methods:
        raise UserError("no methods to compare (--methods NAME...)")
    unknown = [m for m in s.methods if m not in METHOD_PRESETS]
    if unknown:
        raise UserError(f"unknown method '{unknown[0]}' (choose from {', '.join(METHOD_PRESETS)})")
    if len(set(s.methods)) != len(s.methods):
        raise UserError("a method is named twice in --methods")
    if s.seeds_for is not None and set(s.seeds_for) - set(s.methods):
        raise UserError(f"--seeds-for names '{sorted(set(s.seeds_for) - set(s.methods))[0]}', which is not compared "
                        "(--methods)")
    if (s.minutes is None) == (s.iterations is None):
        raise UserError("give one budget: --minutes-per-method M or --iterations N")
    if (scenes is None) != (real is None):
        raise UserError("give --scenes and --real together, or neither (the embedded data)")
    if trajectories is not None and scenes is None:
        raise UserError("--trajectory needs --scenes (one trajectory per scene)")
    if trajectories is not None and len(trajectories) != len(scenes):
        raise UserError(f"give one trajectory per scene: {len(scenes)} scenes, {len(trajectories)} trajectories")
    resolve_device(s.device)
    cuda = s.device == "cuda" or (s.device == "auto" and torch.cuda.is_available())
    configs = {n: method_config(s, m, cuda, seed) for n, (m, seed) in run_names(s).items()}
    for cfg in configs.values():
        validate(cfg)
    check_settings(EvalSettings(views=s.eval_views, frames=s.frames, seg_iterations=s.seg_iterations, seed=s.seed))
    fid_weights_status(fid_weights)
    video = [m for m, cfg in configs.items() if _uses_sequences(cfg)]
    if real is not None:

        RealImages(real)
        if video:
            try:
                RealSequences(real)
            except UserError as e:
                raise UserError(f"{', '.join(video)} train on consecutive real frames: {e}") from None
        for d in scenes:
            if not (Path(d) / "scene.json").is_file():
                raise UserError(f"{d} is not a scene folder (no scene.json)")
    elif video and s.sequences < 1:
        raise UserError(f"{', '.join(video)} train on consecutive real frames: give --real-sequences >= 1")
    if resume:
        manifest = out / "benchmark.json"
        if not manifest.is_file():
            raise UserError(f"nothing to resume: {manifest} does not exist")
        saved = json.loads(manifest.read_text())
        if _what(saved.get("settings") or {}) != _what(_settings_json(s, scenes, real, trajectories)):
            raise UserError(f"--resume: the flags differ from the benchmark's own ({manifest}); give the same flags")
    else:

        prepare_output_dir(out)
    return configs


ADDITIVE = ("seeds", "seeds_for")
"""Settings a resume may change: further seeds add runs and leave the finished ones as they are."""


def _what(settings: dict) -> dict:
    """The settings a resume must match."""
    return {k: v for k, v in settings.items() if k not in ADDITIVE}


def _settings_json(s: BenchmarkSettings, scenes, real, trajectories) -> dict:
    res = lambda p: str(Path(p).resolve())  # noqa: E731
    kept = {k: v for k, v in dataclasses.asdict(s).items() if k != "parallel"}  # how, not what: may change
    return {**kept, "scenes": None if scenes is None else [res(d) for d in scenes],
            "real": None if real is None else res(real),
            "trajectories": None if trajectories is None else [res(t) for t in trajectories]}


def _fresh(path: Path) -> Path:
    """An output folder of a step that did not finish: removed, to be redone."""
    if path.exists():
        shutil.rmtree(path)
    return path


def _data(s: BenchmarkSettings, out: Path, configs: dict, scenes, real) -> tuple[list[Path], Path]:
    if scenes is not None:
        return [Path(d) for d in scenes], Path(real)
    data = out / "data"
    done = data / "done.json"
    video = any(_uses_sequences(c) for c in configs.values())
    cfg = next(iter(configs.values()))
    if not done.is_file():
        _fresh(data)
        sim, _ = make_embedded_data(data, s.seed, s.scenes, s.real_images, cfg.data.height, cfg.data.width,
                                    sequences=s.sequences if video else 0, sequence_frames=s.sequence_frames, say=_say)
        atomic_write_json(done, {"scenes": [str(d) for d in sim]})
    sim = [Path(d) for d in json.loads(done.read_text())["scenes"]]
    return sim, data / "real"


def _train(name: str, cfg, s: BenchmarkSettings, scenes: list[Path], real: Path, out: Path) -> dict:
    """Train one method for its budget (resuming an interrupted run); returns its done record."""
    run = out / "runs" / name
    done, progress = run / "done.json", run / "progress.json"
    if done.is_file():
        return json.loads(done.read_text())
    _say(f"{name}: training ({'%g min' % s.minutes if s.minutes is not None else '%d iterations' % s.iterations})")
    last = run / "checkpoints" / "last.pt"
    spent = json.loads(progress.read_text())["seconds"] if progress.is_file() and last.is_file() else 0.0
    if not last.is_file():
        _fresh(run)
    # the real folder's images: a stand-in root trains on its images/ (its labels are not photographs)
    real_images = real / "images" if (real / "images").is_dir() else real
    trainer = Trainer(cfg, [str(d) for d in scenes], str(real_images), run, resume=last if last.is_file() else None,
                      progress=True)
    t0 = time.perf_counter()

    def record(step, values):
        if (step + 1) % 25 == 0:
            write(progress, {"seconds": spent + time.perf_counter() - t0, "step": step + 1})

    trainer.hooks.append(record)
    try:
        left = None if s.minutes is None else max(1.0, 60.0 * s.minutes - spent)
        trainer.train(time_limit_s=left)
    finally:
        trainer.close()
    if trainer.stopped_by:
        raise UserError(f"training of {name} was stopped; continue with --resume")

    rec = {"method": name, "iterations": trainer.step, "seconds": round(spent + time.perf_counter() - t0, 1),
           "budget": {"minutes": s.minutes} if s.minutes is not None else {"iterations": s.iterations},
           "threads": torch.get_num_threads(), "parallel": s.parallel}
    write(done, rec)
    return rec


def train_job(job_file: str) -> None:
    """Entry point of one training process of a parallel benchmark (see :func:`_train_all`)."""
    job = json.loads(Path(job_file).read_text())

    torch.set_num_threads(job["threads"])
    s = BenchmarkSettings(**job["settings"])
    _train(job["name"], config_from_dict(job["config"]), s, [Path(d) for d in job["scenes"]], Path(job["real"]),
           Path(job["out"]))


def _stop(running: list) -> None:
    """SIGTERM to each running training process: it stops after its step with a checkpoint."""
    for _, proc, _ in running:
        proc.terminate()
    for _, proc, _ in running:
        proc.wait()
    running.clear()


def _train_all(configs: dict, s: BenchmarkSettings, scenes: list[Path], real: Path, out: Path) -> dict:
    """Train every method for its budget: one after the other, or ``s.parallel`` at a time, each
    in its own process with an equal share of the cores."""
    pending = [n for n in configs if not (out / "runs" / n / "done.json").is_file()]
    if s.parallel > 1 and len(pending) > 1:
        threads = max(1, usable_cores() // s.parallel)
        _say(f"training {len(pending)} methods, {s.parallel} at a time on {threads} thread(s) each")
        running: list[tuple[str, subprocess.Popen, Path]] = []
        try:
            queue = list(pending)
            while queue or running:
                while queue and len(running) < s.parallel:
                    name = queue.pop(0)
                    (out / "jobs").mkdir(exist_ok=True)
                    job = out / "jobs" / f"{name}.json"
                    atomic_write_json(job, {"name": name, "config": to_dict(configs[name]),
                                            "settings": dataclasses.asdict(s), "scenes": [str(d) for d in scenes],
                                            "real": str(real), "out": str(out), "threads": threads})
                    log = out / "jobs" / f"{name}.log"
                    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
                    with open(log, "w") as f:
                        proc = subprocess.Popen([sys.executable, "-c", "import sys; from sim2real.comparison.run import "
                                                 "train_job; train_job(sys.argv[1])", str(job)], stdout=f, stderr=f, env=env)
                    running.append((name, proc, log))
                time.sleep(1.0)
                for item in list(running):
                    name, proc, log = item
                    if proc.poll() is None:
                        continue
                    running.remove(item)
                    if proc.returncode != 0:
                        tail = [ln for ln in log.read_text().splitlines() if ln.strip()][-1:] or ["(no output)"]
                        raise UserError(f"training of {name} failed ({tail[0]}); log {log}; continue with --resume")
        except BaseException:  # Ctrl-C, SIGTERM or a failure here: the others stop with a checkpoint too
            _stop(running)
            raise
    return {n: _train(n, cfg, s, scenes, real, out) for n, cfg in configs.items()}


def run_benchmark(out, s: BenchmarkSettings, scenes=None, real=None, trajectories=None, resume: bool = False,
                  fid_weights=None) -> dict:
    """Train, translate, evaluate every method and write the table and the report (module docstring)."""
    out = Path(out)
    configs = check(s, out, scenes, real, trajectories, resume, fid_weights)
    atomic_write_json(out / "benchmark.json", {"format": FORMAT, "settings": _settings_json(s, scenes, real, trajectories)})
    sim, real_dir = _data(s, out, configs, scenes, real)
    cfg0 = next(iter(configs.values()))
    if trajectories is None:
        trajectories = []
        for k, d in enumerate(sim[:1] if scenes is None else sim):
            path = out / "trajectories" / f"scene_{k}.txt"
            if not path.is_file():
                _say(f"test trajectory of {Scene.load(d).name}")
                dat = cfg0.data
                make_trajectory(RayCaster(Scene.load(d)), s.frames, dat.height, dat.width, seed=s.seed + k,
                                K=view_intrinsics(dat.width, dat.height, dat.fov_x_deg, dat.intrinsics),
                                **s.trajectory).save(path)
            trajectories.append(path)
    eval_scenes = sim[: len(trajectories)]
    metrics = {}
    trained = _train_all(configs, s, sim, real_dir, out)
    for k, name in enumerate(configs):
        tdir = out / "translations" / name
        if not (tdir / "translate.json").is_file():
            _say(f"{name}: translating the test trajectory")
            model = load_run(out / "runs" / name, device=s.device)
            translate_sequence(model, trajectory_source(model, eval_scenes[0], trajectories[0]), _fresh(tdir))
            video = out / "videos" / f"{name}.mp4"
            video.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(tdir / "video.mp4", video.with_suffix(".mp4.tmp"))
            video.with_suffix(".mp4.tmp").replace(video)
        edir = out / "evaluations" / name
        if not (edir / "metrics.json").is_file():
            _say(f"{name}: evaluation" + (" (with the ceiling and the floor)" if k == 0 else ""))
            settings = EvalSettings(views=s.eval_views, frames=s.frames, seg_iterations=s.seg_iterations, seed=s.seed,
                                    anchors=k == 0, trajectory=s.trajectory or None)
            evaluate(out / "runs" / name, [str(d) for d in eval_scenes], real_dir, _fresh(edir),
                     trajectories=[str(t) for t in trajectories], settings=settings, fid_weights=fid_weights,
                     device=s.device, progress=True)
        metrics[name] = json.loads((edir / "metrics.json").read_text())
    table = build_table(metrics, trained, configs, {n: m for n, (m, _) in run_names(s).items()})
    write_table(table, out)
    _say("the side-by-side figure")
    figure = side_by_side(out / "side_by_side.png", {m: out / "runs" / m for m in s.methods}, eval_scenes[0],
                          trajectories[0], real_dir, s.seed, s.device)
    write_report(table, out, figure)
    _say(f"written: {out / 'table.md'}, {out / 'report.html'}")
    return table
