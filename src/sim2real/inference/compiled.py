"""Inference networks compiled by TorchInductor (``sim2real translate --compile``).

:func:`compile_networks` compiles, in place (``nn.Module.compile``, inductor's defaults), the
networks a method's translation runs (:meth:`~sim2real.methods.base.Method.inference_networks`);
the modules keep their names and state dicts. Inductor's ``freezing`` (weights as constants,
batch norm folded into the convolutions) was measured and left off: on a 2-core AMD EPYC, small
preset at 256x512, fp32, 48 frames, it ran 2.50 frames/s against 2.53 without it (eager 2.10).
Every network call of a time-independent method has the same shape
(:class:`~sim2real.inference.model.FrameSequence` pads the last chunk), so each network is
compiled once, on its first call (a time-dependent method's shorter last chunk compiles once
more); that first call is slow (about 20 s on a 2-core CPU, see docs/gpu.md), the later ones
faster. The compiled code is cached on disk under
``$SIM2REAL_CACHE/inductor/`` (unless ``TORCHINDUCTOR_CACHE_DIR`` is set), so a later
translation with the same model shape starts sooner.

Compiling needs a C++ compiler on the CPU and Triton on CUDA; :func:`compile_networks` first
compiles a one-line function on the device and turns a failure into one clear error.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import logging
import os
import sys

import torch
from torch import nn

from sim2real.errors import UserError
from sim2real.fileio import cache_root


def _probe(x: torch.Tensor) -> torch.Tensor:
    return torch.relu(x * 2.0 - 1.0)


def _load_compiler_stack_quietly() -> None:
    """Import torch's C++ extension module without its one message that a CUDA toolkit
    (CUDA_HOME) was found but no CUDA runtime: it says nothing about a compile for the CPU. It is
    printed as the module loads, by a logger in newer torch releases and by print in older ones."""
    if "torch.utils.cpp_extension" in sys.modules:
        return
    log = logging.getLogger("torch.utils.cpp_extension")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            importlib.import_module("torch.utils.cpp_extension")
    finally:
        log.setLevel(level)


def check_compiler(device: torch.device) -> None:
    """Raise a one-line :class:`UserError` when TorchInductor cannot compile for ``device``
    (no C++ compiler for the CPU, no Triton for CUDA, ...). Compiled code is cached under
    ``$SIM2REAL_CACHE/inductor/`` unless ``TORCHINDUCTOR_CACHE_DIR`` says otherwise."""
    os.environ.setdefault("TORCHINDUCTOR_CACHE_DIR", str(cache_root() / "inductor"))
    try:
        _load_compiler_stack_quietly()
        with torch.inference_mode():
            torch.compile(_probe)(torch.zeros(4, device=device))
    except Exception as e:  # noqa: BLE001 - whatever the compiler stack raises becomes one line
        lines = [s.strip() for s in str(e).strip().splitlines() if s.strip()]
        why = lines[0] if lines else type(e).__name__
        raise UserError(f"--compile: TorchInductor cannot compile for {device} ({type(e).__name__}: {why[:200]}); "
                        f"run without --compile") from None


def compile_networks(networks: list[nn.Module], device: torch.device) -> int:
    """Compile ``networks`` in place for inference on ``device`` (see the module docstring);
    returns how many were compiled. Refuses (:class:`UserError`) an empty list: the method does
    not say which networks it runs."""
    if not networks:
        raise UserError("--compile: this method does not list the networks its translation runs")
    check_compiler(device)
    for net in networks:
        net.compile()
    return len(networks)
