"""Typed configuration: one dataclass tree, its plain-YAML round trip and the migration of older
layouts. A leaf: it imports nothing of the project but the error type and the file helpers.

Every size of the method is a field here, so one code path serves the paper preset (GPU) and the
tiny preset (tests on a 2-core CPU). The named presets, the method registry that resolves a tagged
``method`` section and the checks across sections live next to the methods:
:mod:`sim2real.presets` (``preset``, ``config_from_dict``, ``load_config``) and
:mod:`sim2real.validation`. Override any field from the command line with
``--set section.field=value``.
"""

from __future__ import annotations

import copy
import dataclasses
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import yaml

from sim2real.errors import UserError, reason
from sim2real.fileio import atomic_write_text


@dataclass
class TextureConfig:
    """Neural texture: objects x 6 planes x ``features`` x ``size`` x ``size``."""

    size: int = 512
    """Texels along each side of each of the 6 planes (paper: 512)."""
    features: int = 3
    """Learnable features per texel (paper: 3). 0: no neural texture, the translator's domain A
    is a_ref alone (the ablation 'ours_no_tex_vc')."""
    mapping: str = "box"
    """'box': each plane spans its object's bounding box (paper).
    'cube': one uniform scale, the box's largest side, so texels are square."""
    tanh: str = "interpolated"
    """Where the texture's tanh is applied: 'interpolated' (tanh of the interpolated value: O(pixels)
    per step) or 'texel' (tanh of every texel, then interpolation, as the authors' release)."""
    init_noise: float = 0.0
    """Standard deviation of band-limited Gaussian noise added to the flat start (before the tanh):
    3-D-anchored high-frequency input from step 0 (a lever of the detail study; 0 = the paper's
    flat start)."""
    init_noise_sigma: float = 1.5
    """Band limit of that noise: white noise blurred with a Gaussian of this many texels per plane."""
    init_lines: float = 0.0
    """Depth of a net of thin dark curves added to the start (before the tanh): the zero crossings
    of band-limited noise (one field per plane, shared by the features) lower every feature by up
    to this much. Winding, vessel- or septa-like lines fixed to the surface, on top of (or, with
    ``init_noise=0``, instead of) the noise; 0 = none."""
    init_lines_sigma: float = 4.0
    """Band limit of the noise whose zero crossings the lines follow (texels): curves a few sigma
    apart."""


@dataclass
class GeneratorConfig:
    """MUNIT encoder/decoder without styles (AdaIN replaced by instance norm)."""

    filters: int = 64
    """Channels after the first conv7; doubled at each downsampling."""
    downsamplings: int = 2
    res_blocks: int = 4
    """Residual blocks in the encoder and again in the decoder."""
    content_channels: int = 8
    """Content code squeezed to this many channels (authors' release: 8). 0 keeps the full width."""
    upsample_norm: str = "ln"
    """Normalisation in the decoder's upsampling convs ('ln' layer norm as MUNIT, 'in', 'none')."""
    pad_type: str = "reflect"


@dataclass
class DiscriminatorConfig:
    """Multi-scale LSGAN discriminator (pix2pixHD / MUNIT)."""

    filters: int = 64
    layers: int = 4
    scales: int = 3
    norm: str = "none"
    pad_type: str = "reflect"
    """Padding of the conv4 layers (MUNIT's configs: 'reflect')."""


@dataclass
class LossConfig:
    """Loss weights of the paper (supplementary, 'Losses') that every translator-based method
    shares; a method's own terms (view consistency, style reconstruction, recurrence, ...) and
    their weights live in its section, ``method``."""

    adv: float = 1.0
    cyc: float = 10.0
    rec: float = 10.0
    content: float = 1.0
    ssim_ab: float = 5.0
    """Weight of the a -> b structure term: by default 1 - MS-SSIM between grey a_ref and grey b_hat."""
    ab_structure: str = "ms_ssim"
    """What the a -> b structure term compares: 'ms_ssim' (the paper) or 'edges', the edge recall of
    b_hat at a_ref's edges, which charges neither the real domain's shading nor its texture
    (sim2real/losses/structure.py)."""
    edge_contrast: float = 0.02
    """'edges': the grey contrast per pixel that counts as an edge (tanh scale; chosen at 128x256)."""
    edge_sigma: float = 1.0
    """'edges': Gaussian blur (px) of both images before their gradients; 0: none."""
    edge_power: float = 1.0
    """'edges': a_ref's pixels weigh |gradient|^(2 edge_power): 2 leaves the weight to the outlines."""
    ssim_ba: float = 3.0
    """1 - MS-SSIM between grey b and grey a_hat_ref."""
    ssim_win: int = 11
    """MS-SSIM window (paper: 11, 5 scales; needs a short side of > 160 px)."""
    ssim_scales: int = 5


@dataclass
class OptimConfig:
    lr_net: float = 1e-4
    lr_tex: float = 1e-3
    beta1: float = 0.5
    beta2: float = 0.999
    weight_decay: float = 1e-4
    """Applied to every parameter group, the texture included (authors' release)."""
    lr_halve_every: int = 100_000


@dataclass
class DataConfig:
    height: int = 256
    width: int = 512
    real_scale_min: float = 1.0
    """Real images are resized so that they cover height x width, times a random factor in
    [real_scale_min, real_scale_max], then randomly cropped to height x width."""
    real_scale_max: float = 1.2
    fov_x_deg: float = 75.0
    """Horizontal field of view of random simulated views rendered on the fly (a square-pixel
    camera with the principal point at the image centre)."""
    intrinsics: list[float] | None = None
    """A calibrated endoscope's pinhole intrinsics ``[fx, fy, cx, cy]``, in pixels of
    height x width, for every random view (training, view pools, the evaluation's views and
    trajectories) instead of ``fov_x_deg``'s; null: ``fov_x_deg``. Lens distortion is not
    modelled: give the intrinsics of undistorted frames (docs/own-data.md)."""
    workers: int = -1
    """DataLoader worker processes (ray casting and image decoding happen there); 0 loads in
    the training process. -1 (automatic): the project's worker rule
    (``sim2real.threads.worker_count``): the CPU cores this process may use, shared evenly among
    the ranks of its node, less one for the training process itself, at least 1, no fixed cap
    (fewer where ``/dev/shm`` cannot hold their samples, data/shm.py). One core makes 6.6
    paper-size samples/s from fresh ray casts, 17.5 from cached views and about 15 from a view
    pool (CPU time,
    benchmarks/bench_data.py, docs/gpu.md)."""
    path_step_mm: float = 0.5
    """Camera motion per frame (mm) of the short linear paths that the video methods train on
    (data/triplets.py)."""
    min_overlap: float = 0.1
    """Fraction of view i's pixels that must be visible in view j; below it view j is redrawn,
    view i kept (up to 10 draws; then the j with the largest overlap is used). Judged on a grid of
    at least 8,192 of view i's pixels (every 4th pixel of every 4th row at 256x512;
    data/pairs.py)."""
    view_pool: int = 0
    """Views per bare scene folder in ``--scenes``: N > 1 draws every training view from a fixed
    pool of N random poses per scene, ray-cast once before the first step into a memory-mapped
    cache (``$SIM2REAL_CACHE/views/``, shared by the loader workers, the DDP ranks, ``--resume``
    and later runs of the same scene, size, field of view, pool size and seed; data/viewpool.py).
    0: unlimited fresh random poses, two ray-cast per step. The presets for a GPU pool 3,000 views
    (the paper's count per scene): 2.25 MiB a 256x512 view, 6.6 GiB per scene; a cached sample
    costs a worker a third of a fresh one (benchmarks/bench_data.py, docs/gpu.md). Views folders
    and the video methods' paths (data/triplets.py) are not pooled."""


@dataclass
class MethodConfig:
    """Base of every method's own config section (``TrainConfig.method``).

    A subclass is registered under its method's name
    (:func:`sim2real.methods.base.register_method_config`); in YAML the section is tagged with that name (``method: {name: ours, ...}``), so a config file
    round-trips to the same class. Fields whose defaults depend on the size preset come from
    :meth:`for_size`; :meth:`check` validates the section."""

    name: typing.ClassVar[str] = "base"

    @classmethod
    def for_size(cls, size: str) -> "MethodConfig":
        """The section's defaults for the size preset ``size`` ('paper', 'small', 'tiny')."""
        return cls()

    def check(self, cfg: "TrainConfig", need: typing.Callable[[bool, str, str, Any], None]) -> None:
        """Refuse out-of-range values with ``need(ok, 'method.<key>', what, value)``."""


@dataclass
class TrainConfig:
    method: MethodConfig = field(default_factory=MethodConfig)
    """The method and its own settings (sim2real/methods/): choose one with ``--method NAME``
    (a method or one of its named presets, :data:`sim2real.presets.METHOD_PRESETS`). A bare
    ``TrainConfig()`` holds the untagged base section; :func:`sim2real.presets.preset` fills it."""
    iterations: int = 500_000
    checkpoint_every: int = 5_000
    keep_checkpoints: bool = False
    """Besides ``last.pt`` keep a ``step_NNNNNNN.pt`` copy of every checkpoint."""
    log_every: int = 100
    image_every: int = 5_000
    seed: int = 0
    device: str = "auto"
    """'auto' (CUDA when available), 'cpu' or 'cuda'."""
    amp: bool = True
    """bf16 autocast and channels-last on CUDA; CPU always runs fp32."""
    deterministic: bool = False
    generator: GeneratorConfig = field(default_factory=GeneratorConfig)
    discriminator: DiscriminatorConfig = field(default_factory=DiscriminatorConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    data: DataConfig = field(default_factory=DataConfig)



def to_dict(cfg: Any) -> dict:
    """Plain nested dict of a config; a method section starts with its ``name`` tag."""
    out = {"name": type(cfg).name} if isinstance(cfg, MethodConfig) else {}
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        out[f.name] = to_dict(v) if dataclasses.is_dataclass(v) else copy.deepcopy(v)
    return out


def differences(a: Any, b: Any) -> list[tuple[str, Any, Any]]:
    """``(dotted key, value in a, value in b)`` for every field where configs ``a`` and ``b``
    differ, in field order (a key that only one of them has is given with None for the other,
    e.g. when their methods differ)."""

    def flat(d: dict, prefix: str = "") -> dict:
        out = {}
        for k, v in d.items():
            out.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: v})
        return out

    fa, fb = flat(to_dict(a)), flat(to_dict(b))
    keys = list(fa) + [k for k in fb if k not in fa]
    return [(k, fa.get(k), fb.get(k)) for k in keys if fa.get(k) != fb.get(k)]


def _migrate_noise_shape(data: dict) -> dict:
    """``method.texture.init_noise_shape`` (runs of 2026-12-03, before the line net had keys of its
    own): 'blobs' is today's ``init_noise``; 'lines' drew the same net as ``init_lines`` with the
    noise's amplitude and sigma, and no noise."""
    method = data.get("method")
    tex = method.get("texture") if isinstance(method, dict) else None
    if not isinstance(tex, dict) or "init_noise_shape" not in tex:
        return data
    data = copy.deepcopy(data)
    tex = data["method"]["texture"]
    shape = tex.pop("init_noise_shape")
    if shape == "lines":
        tex["init_lines"], tex["init_lines_sigma"] = tex.get("init_noise", 0.0), tex.get("init_noise_sigma", 1.5)
        tex["init_noise"] = 0.0
    elif shape != "blobs":
        raise UserError(f"config key 'method.texture.init_noise_shape' (former) must be blobs or lines, got {shape!r}")
    return data


def migrate(data: dict) -> dict:
    """An older config dict -> today's layout. Format 1 (checkpoints before methods had their own
    section: ``method`` a string, ``texture`` top level, ``loss.vc*``), and the former
    ``init_noise_shape`` key. Newer dicts pass unchanged."""
    if not isinstance(data, dict):
        return data
    data = _migrate_noise_shape(data)
    if not isinstance(data.get("method"), str):
        return data
    data = copy.deepcopy(data)
    old = data.pop("method")
    if old not in ("ours", "ours_no_vc"):
        raise UserError(f"this run was trained with the former method '{old}', which no longer exists "
                        "(its texture channels were zeros; 'ours_no_tex_vc' now feeds a_ref alone): train it again")
    loss = data.get("loss", {})
    section = {"name": "ours", "texture": data.pop("texture", {})}
    for key in ("vc", "vc_start", "vc_kind"):
        if key in loss:
            section[key] = loss.pop(key)
    if old == "ours_no_vc":
        section["vc"] = 0.0
    data["method"] = section
    return data


def from_dict(cls: type, data: dict, where: str = "", sections: Mapping[str, type] | None = None) -> Any:
    """Build dataclass ``cls`` from a plain dict; unknown keys are an error. A method section is
    built as the class that ``sections`` (name -> :class:`MethodConfig` subclass; the method
    registry, which :func:`sim2real.presets.config_from_dict` passes) gives for its ``name`` tag."""
    if not isinstance(data, dict):
        raise UserError(f"config section '{where or cls.__name__}' must be a mapping")
    if cls is TrainConfig:
        data = migrate(data)
    if isinstance(cls, type) and issubclass(cls, MethodConfig):
        data = dict(data)
        name = data.pop("name", None)
        known = sections or {}
        if name not in known:
            raise UserError(f"config section '{where}' names unknown method {name!r} (known: {', '.join(known)})")
        cls = known[name]
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        key = f"{where}.{sorted(unknown)[0]}" if where else sorted(unknown)[0]
        raise UserError(f"unknown config key '{key}'")
    kwargs = {}
    for name, value in data.items():
        hint = hints[name]
        if dataclasses.is_dataclass(hint):
            kwargs[name] = from_dict(hint, value, f"{where}.{name}" if where else name, sections)
        else:
            kwargs[name] = _coerce(value, hint, f"{where}.{name}" if where else name)
    return cls(**kwargs)


_NUMBERS = list[float] | None  # an optional list of numbers (data.intrinsics)


def _coerce(value: Any, hint: Any, key: str) -> Any:
    try:
        if hint is bool:
            if isinstance(value, str):
                if value.lower() in ("1", "true", "yes", "on"):
                    return True
                if value.lower() in ("0", "false", "no", "off"):
                    return False
                raise ValueError(value)
            return bool(value)
        if hint is int:
            if isinstance(value, float) and not value.is_integer():
                raise ValueError(value)
            return int(float(value)) if isinstance(value, str) else int(value)
        if hint is float:
            return float(value)
        if hint is str:
            return str(value)
        if hint == _NUMBERS:
            if value is None or value == "":
                return None
            if not isinstance(value, (list, tuple)) or any(isinstance(v, bool) for v in value):
                raise ValueError(value)
            return [float(v) for v in value]
    except (TypeError, ValueError):
        expects = "a list of numbers or null" if hint == _NUMBERS else hint.__name__
        raise UserError(f"config key '{key}' expects {expects}, got {value!r}") from None
    return value


def override(cfg: Any, assignments: list[str]) -> Any:
    """Apply ``section.field=value`` strings to a copy of ``cfg``."""
    cfg = copy.deepcopy(cfg)
    for item in assignments:
        if "=" not in item:
            raise UserError(f"override '{item}' must look like section.field=value")
        key, raw = item.split("=", 1)
        target = cfg
        parts = key.strip().split(".")
        for part in parts[:-1]:
            if not dataclasses.is_dataclass(target) or not hasattr(target, part):
                raise UserError(f"unknown config key '{key}'")
            target = getattr(target, part)
        last = parts[-1]
        if not dataclasses.is_dataclass(target) or last not in {f.name for f in dataclasses.fields(target)}:
            raise UserError(f"unknown config key '{key}'")
        hint = typing.get_type_hints(type(target))[last]
        if dataclasses.is_dataclass(hint):
            hint_m = " (choose the method with --method NAME)" if isinstance(getattr(target, last), MethodConfig) else ""
            raise UserError(f"config key '{key}' is a section; set one of its fields{hint_m}")
        setattr(target, last, _coerce(yaml.safe_load(raw) if raw else raw, hint, key))
    return cfg


def save_yaml(cfg: Any, path) -> None:
    atomic_write_text(path, yaml.safe_dump(to_dict(cfg), sort_keys=False))


def read_yaml(path) -> dict:
    """The plain dict of a YAML config file; one clear error when it cannot be read."""
    try:
        with open(path) as f:
            data = yaml.safe_load(f)
    except OSError as e:
        raise UserError(f"cannot read config {path}: {reason(e)}") from None
    except yaml.YAMLError as e:  # its message spans three lines: say where and what in one
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        raise UserError(f"cannot read config {path}: not valid YAML ({where}{getattr(e, 'problem', None) or reason(e)})") from None
    if data is not None and not isinstance(data, dict):
        raise UserError(f"config {path} must hold a mapping of sections")
    return data or {}
