"""Typed configuration: one dataclass tree, named presets, plain-YAML round trip.

Every size of the method is a field here, so one code path serves the paper
preset (GPU) and the tiny preset (tests on a 2-core CPU). Override any field
from the command line with ``--set section.field=value``.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import typing
from dataclasses import dataclass, field
from typing import Any

import yaml

from sim2real.errors import UserError


@dataclass
class TextureConfig:
    """Neural texture: objects x 6 planes x ``features`` x ``size`` x ``size``."""

    size: int = 512
    """Texels along each side of each of the 6 planes (paper: 512)."""
    features: int = 3
    """Learnable features per texel (paper: 3)."""
    mapping: str = "box"
    """'box': each plane spans its object's bounding box (paper).
    'cube': one uniform scale, the box's largest side, so texels are square."""


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
    """Loss weights of the paper (supplementary, 'Losses')."""

    adv: float = 1.0
    cyc: float = 10.0
    rec: float = 10.0
    content: float = 1.0
    ssim_ab: float = 5.0
    """1 - MS-SSIM between grey a_ref and grey b_hat."""
    ssim_ba: float = 3.0
    """1 - MS-SSIM between grey b and grey a_hat_ref."""
    ssim_win: int = 11
    """MS-SSIM window (paper: 11, 5 scales; needs a short side of > 160 px)."""
    ssim_scales: int = 5
    vc: float = 20.0
    """View-consistency weight once switched on."""
    vc_start: int = 10_000
    """Iteration from which the view-consistency weight is ``vc`` (0 before)."""
    vc_kind: str = "angle"
    """'angle' (lighting invariant, paper) or 'l1' (the ablation)."""


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
    """Horizontal field of view of random simulated views rendered on the fly."""
    workers: int = -1
    """DataLoader worker processes (ray casting and image decoding happen there); 0 loads in
    the training process. -1 (automatic): the CPU cores this process may use, shared among the
    ranks of its node, less one for the training process itself, at least 1 and at most
    ``AUTO_WORKERS_MAX``. On the 2-core dev CPU one worker makes 4.3 paper-size samples/s from
    fresh ray casts and 11 from cached views (benchmarks/bench_data.py), so 20 it/s needs 5 such
    workers (cached: 3)."""
    min_overlap: float = 0.1
    """Fraction of view i's pixels that must be visible in view j; below it view j is redrawn,
    view i kept (up to 10 draws; then the j with the largest overlap is used)."""


@dataclass
class TrainConfig:
    method: str = "ours"
    """Training variant (engine/method.py): 'ours', 'ours_no_vc' (lambda_vc = 0) or
    'ours_no_tex_vc' (zeros instead of the neural texture, no L_vc)."""
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
    texture: TextureConfig = field(default_factory=TextureConfig)
    generator: GeneratorConfig = field(default_factory=GeneratorConfig)
    discriminator: DiscriminatorConfig = field(default_factory=DiscriminatorConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    data: DataConfig = field(default_factory=DataConfig)


AUTO_WORKERS_MAX = 8
"""Upper bound of ``data.workers = -1`` (more rarely pays and costs shared memory per worker)."""


def validate(cfg: TrainConfig) -> None:
    """Refuse a configuration whose values would fail later, or silently do something else.

    Checks every field's domain (``method`` is checked where it is looked up,
    :func:`sim2real.engine.method.get_method`), then the sizes that depend on each other (image
    size vs the generator's downsamplings, the discriminator's depth and the MS-SSIM window).
    Raises a :class:`UserError` naming the offending key.
    """
    from sim2real.losses.consistency import VC_KINDS
    from sim2real.losses.ssim import MS_SSIM_WEIGHTS, check_ssim_size
    from sim2real.models.discriminator import min_input_side as dis_min_side
    from sim2real.models.layers import NORMS, PADS
    from sim2real.models.translator import min_input_side as gen_min_side
    from sim2real.scene.camera import FOV_RANGE_DEG, check_size
    from sim2real.texture.neural_texture import MAPPINGS

    def need(ok: bool, key: str, what: str, value: Any) -> None:
        if not ok:
            raise UserError(f"config key '{key}' must be {what}, got {value!r}")

    def at_least(section: Any, prefix: str, names: str, low: int) -> None:
        for name in names.split():
            v = getattr(section, name)
            need(v >= low, prefix + name, f">= {low}", v)

    def choice(value: str, key: str, options) -> None:
        need(value in options, key, "one of " + ", ".join(options), value)

    choice(cfg.device, "device", ("auto", "cpu", "cuda"))
    at_least(cfg, "", "iterations checkpoint_every log_every image_every", 1)
    at_least(cfg, "", "seed", 0)

    t, g, d, L, o, dat = cfg.texture, cfg.generator, cfg.discriminator, cfg.loss, cfg.optim, cfg.data
    at_least(t, "texture.", "size features", 1)
    choice(t.mapping, "texture.mapping", MAPPINGS)
    at_least(g, "generator.", "filters", 1)
    at_least(g, "generator.", "downsamplings res_blocks content_channels", 0)
    choice(g.upsample_norm, "generator.upsample_norm", NORMS)
    choice(g.pad_type, "generator.pad_type", tuple(PADS))
    at_least(d, "discriminator.", "filters layers scales", 1)
    choice(d.norm, "discriminator.norm", NORMS)
    choice(d.pad_type, "discriminator.pad_type", tuple(PADS))
    for name in ("adv", "cyc", "rec", "content", "ssim_ab", "ssim_ba", "vc"):
        v = getattr(L, name)
        need(math.isfinite(v) and v >= 0, f"loss.{name}", "a finite weight >= 0", v)
    need(1 <= L.ssim_scales <= len(MS_SSIM_WEIGHTS), "loss.ssim_scales", f"in 1..{len(MS_SSIM_WEIGHTS)}", L.ssim_scales)
    at_least(L, "loss.", "vc_start", 0)
    choice(L.vc_kind, "loss.vc_kind", VC_KINDS)
    for name in ("lr_net", "lr_tex"):
        v = getattr(o, name)
        need(math.isfinite(v) and v > 0, f"optim.{name}", "a finite learning rate > 0", v)
    for name in ("beta1", "beta2"):
        v = getattr(o, name)
        need(0 <= v < 1, f"optim.{name}", "in [0, 1)", v)
    need(math.isfinite(o.weight_decay) and o.weight_decay >= 0, "optim.weight_decay", "finite and >= 0", o.weight_decay)
    at_least(o, "optim.", "lr_halve_every", 1)
    need(math.isfinite(dat.real_scale_max) and 0 < dat.real_scale_min <= dat.real_scale_max, "data.real_scale_min",
         f"> 0 and <= data.real_scale_max ({dat.real_scale_max})", dat.real_scale_min)
    at_least(dat, "data.", "workers", -1)
    need(0 <= dat.min_overlap <= 1, "data.min_overlap", "a fraction in [0, 1]", dat.min_overlap)
    lo, hi = FOV_RANGE_DEG
    need(lo <= dat.fov_x_deg <= hi, "data.fov_x_deg", f"in [{lo:g}, {hi:g}] degrees", dat.fov_x_deg)
    check_size(dat.height, dat.width)

    step = 2**g.downsamplings
    if dat.height % step or dat.width % step:
        raise UserError(f"data.height and data.width must be multiples of {step} (2**generator.downsamplings), "
                        f"got {dat.height}x{dat.width}")
    short = min(dat.height, dat.width)
    for side, what in ((gen_min_side(g), f"generator.downsamplings={g.downsamplings}"),
                       (dis_min_side(d), f"discriminator.scales={d.scales} with discriminator.layers={d.layers}")):
        if short < side:
            raise UserError(f"{what} needs images of at least {side} px on the short side, "
                            f"got {dat.height}x{dat.width} (data.height x data.width)")
    if L.ssim_ab or L.ssim_ba:
        try:
            check_ssim_size(dat.height, dat.width, L.ssim_win)
        except ValueError as e:
            raise UserError(str(e)) from None


def _paper() -> TrainConfig:
    return TrainConfig()


def _small() -> TrainConfig:
    cfg = TrainConfig(iterations=20_000, checkpoint_every=1_000, log_every=50, image_every=500)
    cfg.data = DataConfig(height=128, width=256)
    cfg.texture = TextureConfig(size=256)
    cfg.generator = GeneratorConfig(filters=32)
    cfg.discriminator = DiscriminatorConfig(filters=32, scales=2)
    # 128 px short side: pytorch-msssim needs > 16 * (win - 1), so win 7 with 5 scales.
    cfg.loss = LossConfig(ssim_win=7, vc_start=2_000)
    cfg.optim = OptimConfig(lr_halve_every=10_000)
    return cfg


def _tiny() -> TrainConfig:
    cfg = TrainConfig(iterations=20, checkpoint_every=10, log_every=5, image_every=10)
    cfg.data = DataConfig(height=64, width=128, workers=0)
    cfg.texture = TextureConfig(size=64)
    cfg.generator = GeneratorConfig(filters=8, res_blocks=1)
    cfg.discriminator = DiscriminatorConfig(filters=8, layers=2, scales=2)
    # 64 px short side: pytorch-msssim's limit allows only win 3 at 5 scales.
    cfg.loss = LossConfig(ssim_win=3, vc_start=5)
    cfg.optim = OptimConfig(lr_halve_every=1_000)
    return cfg


PRESETS: dict[str, typing.Callable[[], TrainConfig]] = {
    "paper": _paper,
    "small": _small,
    "tiny": _tiny,
}


def preset(name: str) -> TrainConfig:
    if name not in PRESETS:
        raise UserError(f"unknown preset '{name}' (choose from {', '.join(PRESETS)})")
    return PRESETS[name]()


def to_dict(cfg: Any) -> dict:
    return dataclasses.asdict(cfg)


def differences(a: Any, b: Any) -> list[tuple[str, Any, Any]]:
    """``(dotted key, value in a, value in b)`` for every field where configs ``a`` and ``b``
    (of one dataclass type) differ, in field order."""

    def flat(d: dict, prefix: str = "") -> dict:
        out = {}
        for k, v in d.items():
            out.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: v})
        return out

    fa, fb = flat(to_dict(a)), flat(to_dict(b))
    return [(k, fa[k], fb[k]) for k in fa if fa[k] != fb[k]]


def from_dict(cls: type, data: dict, where: str = "") -> Any:
    """Build dataclass ``cls`` from a plain dict; unknown keys are an error."""
    if not isinstance(data, dict):
        raise UserError(f"config section '{where or cls.__name__}' must be a mapping")
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
            kwargs[name] = from_dict(hint, value, f"{where}.{name}" if where else name)
        else:
            kwargs[name] = _coerce(value, hint, f"{where}.{name}" if where else name)
    return cls(**kwargs)


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
    except (TypeError, ValueError):
        raise UserError(f"config key '{key}' expects {hint.__name__}, got {value!r}") from None
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
            raise UserError(f"config key '{key}' is a section; set one of its fields")
        setattr(target, last, _coerce(yaml.safe_load(raw) if raw else raw, hint, key))
    return cfg


def save_yaml(cfg: Any, path) -> None:
    from sim2real.fileio import atomic_write_text

    atomic_write_text(path, yaml.safe_dump(to_dict(cfg), sort_keys=False))


def load_yaml(path, cls: type = TrainConfig) -> Any:
    try:
        with open(path) as f:
            data = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as e:
        raise UserError(f"cannot read config {path}: {e}") from None
    return from_dict(cls, data or {})
