"""``sim2real doctor``: what this machine offers sim2real, checked before a long run.

Each check is one :class:`Check` (name, status, one line of text, its figures): ``ok``, ``note``
(a capability that is absent and has a fallback) or ``warn`` (a setting that will slow or stop a
run, with the fix). The figures for training are those of the paper preset at its size
(256x512), by the same rules the trainer applies: the loader workers of the worker rule
(:func:`sim2real.engine.loader.loader_workers`), the shared memory their samples take
(:mod:`sim2real.data.shm`), and the disk a view pool takes (:mod:`sim2real.data.viewpool`).
"""

from __future__ import annotations

import os
import platform
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from sim2real.data.pairs import sample_transfer_bytes
from sim2real.data.shm import HEADROOM, MiB, free_shared_memory, loader_workers_for_shm
from sim2real.data.viewpool import bytes_per_view
from sim2real.engine.device import resolve_device
from sim2real.engine.loader import PREFETCH, loader_workers
from sim2real.engine.precision import cpu_has_bf16
from sim2real.errors import UserError
from sim2real.fileio import cache_root
from sim2real.metrics.realism import fid_weights_status
from sim2real.presets import preset
from sim2real.threads import local_ranks, usable_cores

GiB = 2**30
INSTALL_HINT = "install a CUDA build of torch first (docs/gpu.md, Install)"


@dataclass
class Check:
    name: str
    status: str
    """'ok', 'note' (absent, with a fallback) or 'warn' (will slow or stop a run; the text says the fix)."""
    text: str
    figures: dict = field(default_factory=dict)


def _nvidia_driver() -> bool:
    """Whether the machine has an NVIDIA driver (whatever this torch build can use)."""
    return os.path.exists("/proc/driver/nvidia/version") or shutil.which("nvidia-smi") is not None


def check_torch() -> Check:
    cuda = torch.version.cuda
    text = f"torch {torch.__version__} ({'CUDA ' + cuda if cuda else 'CPU build'}), Python {platform.python_version()}"
    return Check("torch", "ok", text, {"torch": torch.__version__, "cuda_build": cuda,
                                       "python": platform.python_version()})


def check_gpu() -> Check:
    """The CUDA devices torch sees, with their memory and bf16 (the GPU presets train under bf16
    autocast); a CPU build of torch on a machine with an NVIDIA driver is the usual mistake."""
    if torch.cuda.is_available():
        devices = []
        for k in range(torch.cuda.device_count()):
            p = torch.cuda.get_device_properties(k)
            devices.append({"name": p.name, "memory_gib": round(p.total_memory / GiB, 1)})
        bf16 = bool(torch.cuda.is_bf16_supported())
        text = ", ".join(f"{d['name']} ({d['memory_gib']:g} GiB)" for d in devices)
        if not bf16:
            return Check("gpu", "warn", f"{text}: no bf16, which the GPU presets train with; "
                         "use a GPU of compute capability 8.0 or newer, or --set amp=false", {"devices": devices, "bf16": bf16})
        return Check("gpu", "ok", f"{text}, bf16", {"devices": devices, "bf16": bf16})
    if _nvidia_driver():  # a GPU torch cannot use
        why = (f"this torch is a CPU build: {INSTALL_HINT}" if torch.version.cuda is None else
               f"this torch (CUDA {torch.version.cuda}) sees no device: a driver older than its CUDA, or "
               "CUDA_VISIBLE_DEVICES hides them")
        return Check("gpu", "warn", f"the machine has an NVIDIA driver but {why}; commands run on the CPU", {"devices": []})
    return Check("gpu", "note", "no GPU: every command runs on the CPU (training at paper size is slow there)",
                 {"devices": []})


def check_cpu() -> Check:
    """The cores of this process's share, the loader workers the worker rule starts per training
    process, and bf16 instructions (``--precision bf16`` on the CPU pays only with them)."""
    cores, ranks, workers, bf16 = usable_cores(), local_ranks(), loader_workers(-1), cpu_has_bf16()
    text = (f"{cores} usable cores, {ranks} training process(es) on this node: {workers} loader worker(s) each; "
            f"bf16 instructions: {'yes' if bf16 else 'no (--precision bf16 would be emulated)'}")
    return Check("cpu", "ok", text, {"cores": cores, "local_ranks": ranks, "loader_workers": workers, "bf16": bf16})


def check_shared_memory(free: int | None = None) -> Check:
    """Whether ``/dev/shm`` holds the paper preset's loader workers (``free``: its free bytes,
    default measured)."""
    free = free_shared_memory() if free is None else free
    workers = loader_workers(-1)
    cfg = preset("paper").data
    sample = sample_transfer_bytes(cfg.height, cfg.width)
    per_worker = PREFETCH * sample
    if free is None:
        return Check("shm", "ok", "no /dev/shm on this system (the loader uses the platform's own shared memory)",
                     {"free_mib": None})
    try:  # the trainer's own rule: as many of the automatic workers as fit
        started = loader_workers_for_shm(workers, PREFETCH, sample, automatic=True, free=free)
    except UserError:  # not even one fits: training stops with this advice
        started = 0
    figures = {"free_mib": round(free / MiB), "per_worker_mib": round(per_worker / MiB, 1), "workers_wanted": workers,
               "workers_started": started}
    if started >= workers:
        return Check("shm", "ok", f"/dev/shm {free / MiB:.0f} MiB free: holds the {workers} loader worker(s) "
                     f"({per_worker / MiB:.1f} MiB each at paper size)", figures)
    need = workers * per_worker / HEADROOM
    then = f"training starts {started}" if started else "training stops"
    return Check("shm", "warn", f"/dev/shm {free / MiB:.0f} MiB free holds {started} of {workers} loader workers at "
                 f"paper size: {then}; give the container about {need / MiB:.0f} MiB (docker run --shm-size=1g)",
                 figures)


def check_cache(root: Path | None = None) -> Check:
    """The cache folder and whether its disk holds one paper-size view pool (3,000 views a scene)."""
    root = cache_root() if root is None else root
    cfg = preset("paper").data
    pool = cfg.view_pool * bytes_per_view(cfg.height, cfg.width)
    probe = root
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        free = shutil.disk_usage(probe).free
    except OSError:
        return Check("cache", "warn", f"cache {root}: its disk cannot be read", {"dir": str(root)})
    figures = {"dir": str(root), "free_gib": round(free / GiB, 1), "view_pool_gib": round(pool / GiB, 2),
               "pools_fit": int(free // pool)}
    text = (f"cache {root}: {free / GiB:.1f} GiB free, {int(free // pool)} paper-size view pool(s) of "
            f"{pool / GiB:.1f} GiB (one per scene)")
    if free < pool:
        return Check("cache", "warn", text + "; point SIM2REAL_CACHE at a larger disk or train with "
                     "--set data.view_pool=0", figures)
    return Check("cache", "ok", text, figures)


def check_compiler(probe: bool, device: torch.device) -> Check:
    """``--compile`` needs TorchInductor to compile for the device: probed when ``probe`` (a few
    seconds to a minute: it compiles a one-line function), else whether a C++ compiler is on the
    PATH (the CPU's requirement)."""
    from sim2real.inference import compiled

    if probe:
        try:
            compiled.check_compiler(device)
        except UserError as e:
            return Check("compile", "note", f"{e} (translate and evaluate run uncompiled)", {"available": False})
        return Check("compile", "ok", f"--compile works on {device}", {"available": True, "probed": True})
    cxx = os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++") or shutil.which("clang++")
    if not cxx:
        return Check("compile", "note", "no C++ compiler on the PATH: --compile is unavailable on the CPU",
                     {"available": False})
    return Check("compile", "ok", f"C++ compiler {cxx} (--compile on {device} not probed: sim2real doctor --compile)",
                 {"available": None, "compiler": cxx})


def check_fid() -> Check:
    try:
        s = fid_weights_status()
    except UserError as e:  # $SIM2REAL_FID_WEIGHTS names a file that is not there
        return Check("fid", "warn", str(e), {"path": None})
    if s["available"]:
        return Check("fid", "ok", f"FID Inception weights {s['path']}", {"path": s["path"]})
    return Check("fid", "note", f"{s['reason']}; realism is then the classifier two-sample test and the proxy",
                 {"path": None})


def check_video() -> Check:
    from sim2real.inference.video import pyav_has_libx264

    if pyav_has_libx264():
        return Check("video", "ok", "H.264 through PyAV's libx264", {"backend": "pyav"})
    return Check("video", "note", "PyAV has no libx264: videos go through the ffmpeg binary of imageio-ffmpeg",
                 {"backend": "imageio"})


def check_blend() -> Check:
    from sim2real.scene import blend

    py = blend.venv_python()
    if py is None:
        return Check("blend", "note", blend.SETUP_HINT, {"python": None})
    return Check("blend", "ok", f".blend files readable (Blender's module at {py})", {"python": str(py)})


def run_checks(compile_probe: bool = False) -> list[Check]:
    """Every check, in the order printed."""
    device = resolve_device("auto")
    return [check_torch(), check_gpu(), check_cpu(), check_shared_memory(), check_cache(),
            check_compiler(compile_probe, device), check_video(), check_fid(), check_blend()]


def as_json(checks: list[Check]) -> dict:
    return {c.name: asdict(c) for c in checks}
