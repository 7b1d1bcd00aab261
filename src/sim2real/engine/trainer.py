"""The training loop: one loop for every method (sim2real/methods/), which it runs without
knowing which it is.

One iteration (``step`` counts from 0):

1. **Translate once.** ``out = method.translate(gen, batch, step)`` inside the generator
   stage's forward (so DDP sees it): every translation the method's losses need (for ``ours``:
   texture projection of view i, every translation, reconstruction and cycle of the paper,
   and view j under ``torch.no_grad``).
2. **Discriminator step** on the *detached* fakes of ``out`` and the real inputs. The
   translations are not recomputed for it (the authors' MUNIT-based code computed them
   twice). The fakes come from the same generator weights and inputs that MUNIT's
   ``dis_update`` would use, so the schedule is unchanged.
3. **Generator step**: ``method.gen_losses`` with the discriminators just updated (as MUNIT's
   ``gen_update`` after ``dis_update``), their parameters frozen meanwhile; Adam on each of the
   method's generator-side groups (for ``ours``: networks at lr_net, textures at lr_tex).
4. The method returns **unweighted** terms; the trainer sums ``weight * term`` with the weights
   of :meth:`Method.loss_weights` at this step (a pure function of the step, so it is right
   after any resume) and logs terms (``gen/<name>``, ``dis/<name>``), weights
   (``weight/<name>``) and the weighted totals (``gen/total``, ``dis/total``) apart.
   Learning rates follow StepLR (halved every ``optim.lr_halve_every``).

The loader's samples arrive in compact dtypes and are widened on the device (data/tensors.py);
the time the loop waits for them is logged per interval (``time/data_wait_s`` per step and
``time/data_wait_share`` of the wall time, metrics.jsonl): a share well above 0 means the loader,
not the device, sets the pace (docs/gpu.md).

Every loss term is checked for NaN/inf before its optimiser steps; a non-finite loss stops the
run with a UserError naming the last good checkpoint. On CUDA the forward passes run under
bf16 autocast with channels-last images and networks (no loss scaling is needed for bf16);
on the CPU everything is fp32 (engine/precision.py). The device is chosen at run time.

SIGTERM / SIGINT stop the loop after the step in progress, with a checkpoint of that step
(engine/stop.py); the ranks agree on it, and on the time limit, at every step boundary. Rank 0
holds the run folder's lock (engine/runlock.py) from construction to :meth:`Trainer.close`.
"""

from __future__ import annotations

import math
import os
import random
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from sim2real.config import TrainConfig, save_yaml, to_dict
from sim2real.data.datasets import StepSampler, make_dataset, resolve_scenes
from sim2real.data.real import INDEX as REAL_INDEX, RealImages
from sim2real.data.tensors import complete_on_device, widen
from sim2real.data.viewpool import attach_view_pools
from sim2real.engine import checkpoint as ckpt, distributed, precision
from sim2real.engine.device import resolve_device
from sim2real.engine.loader import make_loader, worker_message
from sim2real.engine.observe import Observer
from sim2real.engine.optim import optimizers_for
from sim2real.engine.runlock import RunLock, remove_if_only_lock, take_run_folder
from sim2real.engine.stop import StopSignals
from sim2real.errors import UserError
from sim2real.methods import get_method
from sim2real.validation import validate


class Trainer:
    """Build everything for a run (or restore it from a checkpoint) and train.

    Args:
        cfg: the effective configuration.
        scenes: ``--scenes`` entries (scene or views folders); None on resume takes the
            checkpoint's.
        real: folder of real images; None on resume takes the checkpoint's.
        out: run folder (``config.yaml``, ``checkpoints/``, ``tb/``, ``samples/``, ``metrics.jsonl``).
            A fresh run needs it empty or absent.
        resume: checkpoint to continue from (``out/checkpoints/last.pt`` for ``--resume``).
        progress: show the progress bar.
        resume_state: the already loaded checkpoint ``resume`` (saves reading it twice).
        init_from: a run (or checkpoint) whose networks start this new run (``--init-from``).
        init_state: the already loaded checkpoint of ``init_from``.
    """

    def __init__(self, cfg: TrainConfig, scenes=None, real=None, out=None, resume=None, progress: bool = True,
                 resume_state: dict | None = None, init_from=None, init_state: dict | None = None):
        validate(cfg)
        if init_from is not None and (resume is not None or resume_state is not None):
            raise UserError("--init-from starts a new run; it cannot be combined with --resume")
        self.cfg = cfg
        self.init_from = None if init_from is None else ckpt.find_run_checkpoint(init_from)
        if self.init_from is not None and init_state is None:
            init_state = ckpt.load_checkpoint(self.init_from)
        self.method = get_method(cfg)
        state = resume_state if resume_state is not None else (ckpt.load_checkpoint(resume) if resume is not None else None)
        if state is not None:
            if "optimizers" not in state:
                raise UserError(f"{resume} is an inference checkpoint (the shipped model: no optimiser state); "
                                "start a new run from it with --init-from")
            trained = ckpt.trained_method(state)
            if trained != self.method.name:
                raise UserError(f"checkpoint {resume} was trained with method '{trained}', not '{self.method.name}'")
            scenes = scenes if scenes else state["inputs"]["scenes"]
            real = real if real else state["inputs"]["real"]
        if not scenes:
            raise UserError("no simulated scenes given (--scenes DIR...)")
        if not real:
            raise UserError("no real image folder given (--real DIR)")
        self.inputs = {"scenes": [str(Path(s).resolve()) for s in scenes], "real": str(Path(real).resolve())}
        if state is None and self.init_from is not None:
            self.inputs["init_from"] = str(self.init_from.resolve())
        elif state is not None and state["inputs"].get("init_from"):
            self.inputs["init_from"] = state["inputs"]["init_from"]

        probe = torch.device("cuda") if cfg.device == "cuda" or (cfg.device == "auto" and torch.cuda.is_available()) else torch.device("cpu")
        self.dist = distributed.setup(probe.type)
        self.device = resolve_device(cfg.device, self.dist.local_rank)
        self.cuda = self.device.type == "cuda"
        self.channels_last = precision.mixed_precision(self.device)
        self.amp = self.channels_last and cfg.amp
        if self.channels_last:
            self.method.memory_format = torch.channels_last
        if self.cuda:  # every step has the same sizes: let cuDNN time its kernels once and keep the fastest
            torch.backends.cudnn.benchmark = not cfg.deterministic

        self.sources = resolve_scenes(scenes, cfg.data.height, cfg.data.width)
        self.real = RealImages(real, index=Path(out) / REAL_INDEX)  # a plain folder is checked once per run
        # the method's training data (a real folder without what it needs is refused here, before
        # the run folder is touched)
        self.dataset = make_dataset(self.method.data, self.sources, self.real, cfg.data, cfg.seed, self.dist.rank)
        self.dataset.a_ref_in_worker = not self.cuda  # a GPU renders it from the sample (data/tensors.py)
        self.out = Path(out)
        self.ckpt_dir = self.out / "checkpoints"
        self.lock = RunLock(self.out)
        # rank 0 takes the run folder; a refusal there is raised on every rank, before any trains
        distributed.on_main(self.dist, lambda: take_run_folder(self.out, self.lock, state, resume))
        try:
            if self.dist.is_main:
                self.real.save_index()
            # the view pools, once the run folder is taken (a refused run builds none); the video
            # methods' paths are not single views: they ray-cast them (data/triplets.py)
            if self.method.data != "triplets":
                attach_view_pools(self.sources, cfg.data, cfg.seed, progress=progress and self.dist.is_main)
            self._build(state, resume, progress, init_state)
        except BaseException:
            self.lock.release()
            if state is None and self.dist.is_main:  # a refused fresh run leaves no folder behind
                remove_if_only_lock(self.out)
            raise

    def _build(self, state: dict | None, resume, progress: bool, init_state: dict | None = None) -> None:
        cfg = self.cfg
        # networks, textures, optimisers (same seed on every rank; DDP also broadcasts rank 0's)
        random.seed(cfg.seed)
        np.random.seed(cfg.seed)
        torch.manual_seed(cfg.seed)
        with torch.device("cpu"):  # built on the host (the same initial weights on every device), then moved
            self.gen, self.dis = self.method.build(self.sources)
        if state is not None:
            self.method.check_resume(state, self.sources, resume)
        if init_state is not None:
            ckpt.transfer_weights(self.method, {"gen": self.gen, "dis": self.dis}, init_state, self.init_from)
        self.gen.to(self.device)
        self.dis.to(self.device)
        if self.channels_last:  # conv weights channels-last (4-D tensors only: the 5-D textures stay as they are)
            for m in (*self.gen.children(), self.dis):
                if not isinstance(m, torch.nn.ModuleDict):
                    m.to(memory_format=torch.channels_last)
        self.groups = self.method.optim_groups(self.gen, self.dis)
        self.optimizers, self.schedulers = optimizers_for(self.groups, cfg)
        self.step = 0
        self.last_checkpoint: Path | None = None
        if state is not None:
            self._restore(state, resume)
        if self.dist.is_main:
            save_yaml(cfg, self.out / "config.yaml")

        self.gen_ddp = distributed.wrap(self.gen, self.dist, self.device, find_unused=self.method.ddp_find_unused(self.gen))
        self.dis_ddp = distributed.wrap(self.dis, self.dist, self.device, find_unused=False)
        self.progress = progress
        self.last_out: dict | None = None
        """The translations of the latest step (for image grids)."""
        self.hooks: list[Callable[[int, dict[str, float]], None]] = []
        """Called after every step with ``(step, {name: value})``; costs one sync per step."""
        self.stopped_by = 0
        """The signal (SIGTERM, SIGINT) that stopped the latest :meth:`train`, 0 for none."""

    # --- checkpoints -----------------------------------------------------------------------------

    def _restore(self, state: dict, path) -> None:
        try:
            self.gen.load_state_dict(state["gen"])
            self.dis.load_state_dict(state["dis"])
            for name, opt in self.optimizers.items():
                opt.load_state_dict(state["optimizers"][name])
            for name, sch in self.schedulers.items():
                sch.load_state_dict(state["schedulers"][name])
        except (RuntimeError, KeyError, ValueError) as e:
            raise UserError(f"checkpoint {path} does not match this configuration ({ckpt.mismatch(e)})") from None
        self.step = int(state["step"])
        rngs = state["rng"]
        ckpt.set_rng_state(rngs[self.dist.rank] if self.dist.rank < len(rngs) else rngs[0])
        self.last_checkpoint = Path(path)

    def state_dict(self, rngs: list[dict]) -> dict:
        return {
            "format": ckpt.FORMAT,
            "step": self.step,
            "config": to_dict(self.cfg),
            "method": self.method.name,
            "inputs": self.inputs,
            "scenes": self.method.scenes_record(self.gen, self.sources),
            "gen": self.gen.state_dict(),
            "dis": self.dis.state_dict(),
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "schedulers": {k: s.state_dict() for k, s in self.schedulers.items()},
            "rng": rngs,
            "loss_schedule": self.method.schedule_state(self.step),
            "world_size": self.dist.world_size,
            "torch": str(torch.__version__),
        }

    def save_checkpoint(self) -> Path:
        """Write ``checkpoints/last.pt`` (rank 0; all ranks take part in gathering RNG states)."""
        rngs = distributed.gather_objects(self.dist, ckpt.rng_state())
        path = self.ckpt_dir / ckpt.LAST
        if self.dist.is_main:
            ckpt.save_checkpoint(path, self.state_dict(rngs))
            if self.cfg.keep_checkpoints or self.step == 0:
                ckpt.keep_copy(path, self.step)
        distributed.barrier(self.dist)
        self.last_checkpoint = path
        return path

    # --- the loop --------------------------------------------------------------------------------

    def _autocast(self):
        return precision.autocast(self.device, self.amp)

    def _to_device(self, batch: dict) -> dict:
        """A loader batch on the device: copied in its compact dtypes, widened and its a_ref
        rendered there (data/tensors.py); channels-last images where the device runs them."""
        moved, host = {}, {}
        for k, v in batch.items():
            if k in self.method.host_keys:  # Python lists: read on the host, never moved (not even by DDP)
                host[k] = v.tolist()
            else:
                moved[k] = v.to(self.device, non_blocking=True)
        out = complete_on_device(widen(moved))
        if self.channels_last:
            for k in self.method.image_keys:
                if k in out:
                    out[k] = out[k].contiguous(memory_format=torch.channels_last)
        return {**out, **host}

    def _update(self, losses: dict[str, torch.Tensor], weights: dict[str, float], optimizers: list) -> torch.Tensor:
        """One optimiser step on ``sum(weights[k] * losses[k])``; returns that sum, detached."""
        missing = [k for k in losses if k not in weights]
        if missing:
            raise KeyError(f"method '{self.method.name}' gives no weight for its loss terms {missing}")
        total = sum(weights[k] * v for k, v in losses.items())
        for o in optimizers:
            o.zero_grad(set_to_none=True)
        total.backward()
        for o in optimizers:
            o.step()
        return total.detach()

    def _check_finite(self, losses: dict[str, torch.Tensor], totals: tuple[torch.Tensor, ...], step: int) -> None:
        """Stop on a non-finite loss. Checked once per step, after both updates: one host sync (and
        one all-reduce under DDP) instead of one before each backward, so a GPU step is not drained
        twice. The bad step's update is then applied in memory, but no checkpoint follows it."""
        if not distributed.any_true(self.dist, ~torch.isfinite(torch.stack(totals)).all()):
            return
        bad = [(k, v.item()) for k, v in losses.items() if not math.isfinite(v.item())]
        where = f"loss {bad[0][0]} became {bad[0][1]}" if bad else "a loss became non-finite on another rank"
        last = str(self.last_checkpoint) if self.last_checkpoint else "none"
        raise UserError(f"{where} at step {step}; stopping. Last good checkpoint: {last}")

    def _set_dis_grad(self, flag: bool) -> None:
        for p in self.dis.parameters():
            p.requires_grad_(flag)

    def train_step(self, batch: dict, step: int) -> dict[str, torch.Tensor]:
        """One iteration; returns the named, unweighted loss terms (``dis/...``, ``gen/...``) and
        the weighted totals (``dis/total``, ``gen/total``)."""
        gen_opts = [self.optimizers[g.name] for g in self.groups if g.side == "gen"]
        dis_opts = [self.optimizers[g.name] for g in self.groups if g.side == "dis"]
        weights = self.method.loss_weights(step)
        with self._autocast():
            out = self.gen_ddp(self.method.translate, batch, step)
            d_losses = self.dis_ddp(self.method.dis_losses, batch, out)
        d_total = self._update(d_losses, weights, dis_opts)

        self._set_dis_grad(False)
        try:
            with self._autocast():
                g_losses = self.method.gen_losses(self.dis, batch, out, step)
            g_total = self._update(g_losses, weights, gen_opts)
        finally:
            self._set_dis_grad(True)
        for s in self.schedulers.values():
            s.step()
        self.last_out = out
        losses = {**{f"dis/{k}": v.detach() for k, v in d_losses.items()}, **{f"gen/{k}": v.detach() for k, v in g_losses.items()}}
        self._check_finite(losses, (d_total, g_total), step)
        losses.update({"dis/total": d_total, "gen/total": g_total})
        return losses

    def _loader(self):
        return make_loader(self.dataset, StepSampler(self.step, self.cfg.iterations), self.cfg.data.workers,
                           pin_memory=self.cuda, announce=self.dist.is_main)

    def train(self, time_limit_s: float | None = None) -> Path:
        """Run from ``self.step`` to ``cfg.iterations``; returns the last checkpoint.

        ``time_limit_s``: also stop (with a final checkpoint) after the first step that ends past
        this many wall-clock seconds; the progress bar then counts steps without a total.
        SIGTERM / SIGINT (engine/stop.py) also stop it after the step in progress, with a
        checkpoint; :attr:`stopped_by` is then that signal's number (0 otherwise). Under DDP all
        ranks agree on both at every step boundary, so they stop at the same step.
        """
        cfg = self.cfg
        deadline = None if time_limit_s is None else time.perf_counter() + time_limit_s
        prev_det = torch.are_deterministic_algorithms_enabled()
        if cfg.deterministic:
            os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
            # CUDA has no deterministic backward for reflection/replication padding: warn there
            torch.use_deterministic_algorithms(True, warn_only=self.cuda)
        self.stopped_by = 0
        obs = Observer(self.out, cfg.iterations if deadline is None else None, self.step, self.dist.is_main,
                       self.progress)
        try:
            with StopSignals(announce=self.dist.is_main) as signals:
                if self.last_checkpoint is None:
                    self.save_checkpoint()  # step 0: a run killed at once can still --resume
                first = self.step
                stop = self.step if self._stop_requested(None, signals) else cfg.iterations
                host = torch.device("cpu")  # the loader is host code (torch's own seeds and collation included)
                with host:
                    it = iter(self._loader()) if self.step < stop else None
                wait_s, wait_steps, interval_t0 = 0.0, 0, time.perf_counter()
                while self.step < stop:
                    t_wait = time.perf_counter()
                    try:
                        with host:
                            batch = next(it)
                    except UserError as e:
                        raise UserError(worker_message(e)) from None
                    wait_s, wait_steps = wait_s + time.perf_counter() - t_wait, wait_steps + 1
                    step = self.step
                    batch = self._to_device(batch)
                    losses = self.train_step(batch, step)
                    self.step = step + 1
                    obs.accumulate(losses)
                    obs.step_done()
                    if self.hooks:
                        values = dict(zip(losses, torch.stack(list(losses.values())).tolist()))
                        for hook in self.hooks:
                            hook(step, values)
                    if self._stop_requested(deadline, signals):
                        stop = self.step
                    if self.step % cfg.log_every == 0 or self.step == stop:
                        lrs = {k: s.get_last_lr()[0] for k, s in self.schedulers.items()}
                        now = time.perf_counter()
                        timing = {"time/data_wait_s": wait_s / max(wait_steps, 1),
                                  "time/data_wait_share": wait_s / max(now - interval_t0, 1e-9)}
                        wait_s, wait_steps, interval_t0 = 0.0, 0, now
                        obs.log(self.step, lrs, {**timing, **{f"weight/{k}": v for k, v in
                                                              self.method.loss_weights(step).items()}})
                    if step == first or self.step % cfg.image_every == 0:
                        obs.images(self.step, self.method.image_rows(batch, self.last_out))
                    self.last_out = None
                    if self.step % cfg.checkpoint_every == 0 or self.step == stop:
                        self.save_checkpoint()  # a signal meanwhile is only recorded: the write completes
                del it  # shuts the loader workers down while the signals are still deferred
                # a signal that came during the last checkpoint counts too (agreed by all ranks)
                self.stopped_by = self._agree(False, signals.signum)[1]
            return self.last_checkpoint
        finally:
            obs.close()
            self.last_out = None
            if cfg.deterministic:
                torch.use_deterministic_algorithms(prev_det)

    def _stop_requested(self, deadline: float | None, signals: StopSignals) -> bool:
        """Whether any rank's clock is past ``deadline`` or any rank got a stop signal."""
        past = deadline is not None and time.perf_counter() > deadline
        past, signum = self._agree(past, signals.signum)
        return past or bool(signum)

    def _agree(self, past: bool, signum: int) -> tuple[bool, int]:
        """The maximum over the ranks of (past the deadline, signal number): one all-reduce of two
        integers at every step boundary under DDP (the run's only other per-step collective is the
        NaN check's); nothing in one process."""
        past, signum = distributed.max_ints(self.dist, [int(past), int(signum)], self.device)
        return bool(past), signum

    def close(self) -> None:
        """Release the run folder's lock and leave the process group."""
        self.lock.release()
        distributed.teardown(self.dist)


