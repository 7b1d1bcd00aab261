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
    """Horizontal field of view of random simulated views rendered on the fly."""
    workers: int = -1
    """DataLoader worker processes (ray casting and image decoding happen there); 0 loads in
    the training process. -1 (automatic): the CPU cores this process may use, shared among the
    ranks of its node, less one for the training process itself, at least 1 and at most
    ``AUTO_WORKERS_MAX``. On the 2-core dev CPU one worker makes 4.3 paper-size samples/s from
    fresh ray casts and 11 from cached views (benchmarks/bench_data.py), so 20 it/s needs 5 such
    workers (cached: 3)."""
    path_step_mm: float = 0.5
    """Camera motion per frame (mm) of the short linear paths that the video methods train on
    (data/triplets.py)."""
    min_overlap: float = 0.1
    """Fraction of view i's pixels that must be visible in view j; below it view j is redrawn,
    view i kept (up to 10 draws; then the j with the largest overlap is used)."""


@dataclass
class MethodConfig:
    """Base of every method's own config section (``TrainConfig.method``).

    A subclass is registered under its method's name (:func:`register_method_config`); in YAML
    the section is tagged with that name (``method: {name: ours, ...}``), so a config file
    round-trips to the same class. Fields whose defaults depend on the size preset come from
    :meth:`for_size`; :meth:`check` validates the section."""

    name: typing.ClassVar[str] = "base"

    @classmethod
    def for_size(cls, size: str) -> "MethodConfig":
        """The section's defaults for the size preset ``size`` ('paper', 'small', 'tiny')."""
        return cls()

    def check(self, cfg: "TrainConfig", need: typing.Callable[[bool, str, str, Any], None]) -> None:
        """Refuse out-of-range values with ``need(ok, 'method.<key>', what, value)``."""


METHOD_CONFIGS: dict[str, type[MethodConfig]] = {}
"""Registered method config sections by method name (filled by :mod:`sim2real.methods`)."""


def register_method_config(cls: type[MethodConfig]) -> type[MethodConfig]:
    METHOD_CONFIGS[cls.name] = cls
    return cls


def _method_configs() -> dict[str, type[MethodConfig]]:
    import sim2real.methods  # noqa: F401  (registers every method)

    return METHOD_CONFIGS


def _default_method() -> MethodConfig:
    return _method_configs()["ours"]()


@dataclass
class TrainConfig:
    method: MethodConfig = field(default_factory=_default_method)
    """The method and its own settings (sim2real/methods/): choose one with ``--method NAME``
    (a method or one of its named presets, :data:`sim2real.methods.METHOD_PRESETS`)."""
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


AUTO_WORKERS_MAX = 8
"""Upper bound of ``data.workers = -1`` (more rarely pays and costs shared memory per worker)."""


def validate(cfg: TrainConfig) -> None:
    """Refuse a configuration whose values would fail later, or silently do something else.

    Checks every field's domain (the ``method`` section checks its own,
    :meth:`MethodConfig.check`), then the sizes that depend on each other (image
    size vs the generator's downsamplings, the discriminator's depth and the MS-SSIM window).
    Raises a :class:`UserError` naming the offending key.
    """
    from sim2real.losses.ssim import MS_SSIM_WEIGHTS, check_ssim_size
    from sim2real.losses.structure import STRUCTURES
    from sim2real.models.discriminator import min_input_side as dis_min_side
    from sim2real.models.layers import NORMS, PADS
    from sim2real.models.translator import min_input_side as gen_min_side
    from sim2real.scene.camera import FOV_RANGE_DEG, check_size

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

    g, d, L, o, dat = cfg.generator, cfg.discriminator, cfg.loss, cfg.optim, cfg.data
    at_least(g, "generator.", "filters", 1)
    at_least(g, "generator.", "downsamplings res_blocks content_channels", 0)
    choice(g.upsample_norm, "generator.upsample_norm", NORMS)
    choice(g.pad_type, "generator.pad_type", tuple(PADS))
    at_least(d, "discriminator.", "filters layers scales", 1)
    choice(d.norm, "discriminator.norm", NORMS)
    choice(d.pad_type, "discriminator.pad_type", tuple(PADS))
    for name in ("adv", "cyc", "rec", "content", "ssim_ab", "ssim_ba"):
        v = getattr(L, name)
        need(math.isfinite(v) and v >= 0, f"loss.{name}", "a finite weight >= 0", v)
    choice(L.ab_structure, "loss.ab_structure", STRUCTURES)
    need(math.isfinite(L.edge_contrast) and L.edge_contrast > 0, "loss.edge_contrast", "finite and > 0", L.edge_contrast)
    need(math.isfinite(L.edge_sigma) and L.edge_sigma >= 0, "loss.edge_sigma", "finite and >= 0", L.edge_sigma)
    need(math.isfinite(L.edge_power) and L.edge_power > 0, "loss.edge_power", "finite and > 0", L.edge_power)
    need(1 <= L.ssim_scales <= len(MS_SSIM_WEIGHTS), "loss.ssim_scales", f"in 1..{len(MS_SSIM_WEIGHTS)}", L.ssim_scales)
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
    need(math.isfinite(dat.path_step_mm) and dat.path_step_mm >= 0, "data.path_step_mm", "finite and >= 0",
         dat.path_step_mm)
    need(0 <= dat.min_overlap <= 1, "data.min_overlap", "a fraction in [0, 1]", dat.min_overlap)
    lo, hi = FOV_RANGE_DEG
    need(lo <= dat.fov_x_deg <= hi, "data.fov_x_deg", f"in [{lo:g}, {hi:g}] degrees", dat.fov_x_deg)
    check_size(dat.height, dat.width)
    if type(cfg.method).name not in _method_configs():
        raise UserError(f"unknown method '{type(cfg.method).name}'")
    cfg.method.check(cfg, need)

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
    cfg.generator = GeneratorConfig(filters=32)
    cfg.discriminator = DiscriminatorConfig(filters=32, scales=2)
    # 128 px short side: pytorch-msssim needs > 16 * (win - 1), so win 7 with 5 scales.
    cfg.loss = LossConfig(ssim_win=7)
    cfg.optim = OptimConfig(lr_halve_every=10_000)
    return cfg


def _tiny() -> TrainConfig:
    cfg = TrainConfig(iterations=20, checkpoint_every=10, log_every=5, image_every=10)
    cfg.data = DataConfig(height=64, width=128, workers=0)
    cfg.generator = GeneratorConfig(filters=8, res_blocks=1)
    cfg.discriminator = DiscriminatorConfig(filters=8, layers=2, scales=2)
    # 64 px short side: pytorch-msssim's limit allows only win 3 at 5 scales.
    cfg.loss = LossConfig(ssim_win=3)
    cfg.optim = OptimConfig(lr_halve_every=1_000)
    return cfg


PRESETS: dict[str, typing.Callable[[], TrainConfig]] = {
    "paper": _paper,
    "small": _small,
    "tiny": _tiny,
}
"""Size presets. The method section comes from :func:`sim2real.methods.method_config` for the
chosen method and size (e.g. the texture size and the view-consistency start)."""


def preset(name: str, method: str = "ours") -> TrainConfig:
    """Size preset ``name`` with method (or method preset) ``method``."""
    from sim2real.methods import method_config

    if name not in PRESETS:
        raise UserError(f"unknown preset '{name}' (choose from {', '.join(PRESETS)})")
    cfg = PRESETS[name]()
    cfg.method = method_config(method, name)
    return cfg


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


def from_dict(cls: type, data: dict, where: str = "") -> Any:
    """Build dataclass ``cls`` from a plain dict; unknown keys are an error. A method section is
    built as the class registered under its ``name`` tag."""
    if not isinstance(data, dict):
        raise UserError(f"config section '{where or cls.__name__}' must be a mapping")
    if cls is TrainConfig:
        data = migrate(data)
    if isinstance(cls, type) and issubclass(cls, MethodConfig):
        data = dict(data)
        name = data.pop("name", None)
        known = _method_configs()
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
            hint_m = " (choose the method with --method NAME)" if isinstance(getattr(target, last), MethodConfig) else ""
            raise UserError(f"config key '{key}' is a section; set one of its fields{hint_m}")
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
