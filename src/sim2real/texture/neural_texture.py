"""Neural texture of one scene and its differentiable triplanar projection (supplementary, Eq. 7).

Storage
-------
``texture`` is one parameter of shape ``(O, 6, S, S, N)``, channels last: O objects, the 6
axis-aligned planes ordered ``+x, -x, +y, -y, +z, -z`` (plane index ``p = 2a + (n_a < 0)``
for axis ``a``), S x S texels, N features. Plane ``p`` of axis ``a`` is parametrised by the
other two axes in increasing order, ``(u, v) = (y, z)`` for x, ``(x, z)`` for y and
``(x, y)`` for z; ``texture[o, p, i, j]`` is texel ``i`` along ``u`` and ``j`` along ``v``
(the paper's ``tex[o, p, x_p, y_p]``). The ``+a`` and ``-a`` planes are separate textures.

Texel coordinates
-----------------
A surface point ``s`` (mm) of object ``o`` gets normalised plane coordinates ``c`` in [0, 1]:

* ``mapping='box'`` (paper): ``c_u = (s_u - min_u) / (max_u - min_u)``, i.e. each plane
  spans its object's bounding box along its two in-plane axes (texels may be rectangular);
* ``mapping='cube'``: ``c_u = (s_u - centre_u) / L + 1/2`` with ``L`` the largest side of the
  box, one uniform scale for all axes, so texels are square (the box sits centred in
  the plane).

Texel coordinates are ``x_p = clamp(c_u (S - 1), 0, S - 1)`` and likewise ``y_p``: c = 0 and
c = 1 fall on the centres of the first and last texels (``align_corners=True``-like); points
outside the box are clamped to the border texels.

Projection
----------
With unit normal ``n`` the three planes facing ``n`` (``sign(n_a) e_a`` for each axis ``a``;
``n_a = 0`` picks ``+a``, whose weight is then 0) are sampled bilinearly,

    tex[o, p, x_p, y_p] = (1-dx)(1-dy) T[x0, y0] + (1-dx) dy T[x0, y1]
                          + dx (1-dy) T[x1, y0] + dx dy T[x1, y1],

    x0 = floor(x_p), x1 = min(x0 + 1, S - 1), dx = x_p - x0   (same for y),

which equals the supplementary's floor/ceil formula (where ``x_p`` is an integer the second
corner has weight 0). The three samples are summed with weights ``w_a = n_a^2 / |n|^2``
(``= n_a^2`` for unit normals; the division only guards against slightly unnormalised input)
and the network input is ``tanh`` of that weighted sum::

    a_tex = tanh( sum_a w_a tex[o, p_a, x_{p_a}, y_{p_a}] ).

As in the authors' release the network sees ``tanh(texture)``; we apply the tanh after the
interpolation (tanh of the interpolated value) rather than to every texel, which costs
O(pixels) instead of O(texels) per step and keeps the output in (-1, 1) all the same.
Background pixels (``object_id < 0``) are 0.

Implementation: the 12 corner texels per pixel (3 planes x 4 corners) are fetched with one
flat ``index_select`` from the channels-last texture viewed as ``(O*6*S*S, N)``; the
backward pass is one ``index_add``/``scatter_add``. DESIGN.md measured this formulation as
the fastest on CPU (73 ms forward + backward for a 256x512 view); this module measured
70-105 ms on the 2-core dev CPU for 5 objects at S = 512 (about 30 ms of it is zero-filling
the dense 94 MB texture gradient). No host sync: background pixels are computed with weight 0
instead of being filtered out.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from sim2real.config import TextureConfig

PLANES = ("+x", "-x", "+y", "-y", "+z", "-z")
"""Plane order along dimension 1 of the texture."""
MAPPINGS = ("box", "cube")
"""``texture.mapping`` options (see the module docstring)."""
NOISE_SHAPES = ("blobs", "lines")
"""The shapes of :meth:`NeuralTexture.add_noise` ('blobs': ``texture.init_noise``, 'lines':
``texture.init_lines``)."""
LINE_WIDTH = 0.12
"""Half-width of a 'lines' curve in units of the unit-variance noise: a texel darkens by
exp(-n^2 / (2 LINE_WIDTH^2)), so a curve is about 2.4 LINE_WIDTH sigma texels wide (FWHM)."""
TANH_MODES = ("interpolated", "texel")
"""``texture.tanh`` options: tanh after the interpolation (ours) or of every texel (the release)."""
IN_PLANE_AXES = ((1, 2), (0, 2), (0, 1))
"""(u, v) world axes spanning the planes of axis x, y, z."""
INIT_CLIP = 0.99
"""Initial colours mapped to [-1, 1] are clipped to +-INIT_CLIP before atanh (finite, trainable)."""
_MIN_EXTENT = 1e-6  # mm; a flat box side would otherwise divide by zero


class NeuralTexture(nn.Module):
    """Learnable triplanar textures of the O objects of one scene.

    Args:
        num_objects: O; object ids in the G-buffer index this dimension.
        bboxes: (O, 2, 3) per-object axis-aligned boxes in world mm, ``[:, 0]`` mins, ``[:, 1]`` maxs.
        colours: optional (O, C) initial colours in [0, 1] (the flat per-class reference albedos).
            Each texel of object o starts at ``atanh(clip(2 colour - 1))``, so that the network
            initially sees the flat colour in [-1, 1]. If C != N the columns are repeated
            cyclically to N features. None starts every texel at 0.
        cfg: size S, features N and mapping ('box' or 'cube').
    """

    texture: nn.Parameter
    bbox_min: torch.Tensor
    bbox_max: torch.Tensor

    def __init__(self, num_objects: int, bboxes, colours=None, cfg: TextureConfig | None = None):
        super().__init__()
        cfg = cfg if cfg is not None else TextureConfig()
        if cfg.mapping not in MAPPINGS:
            raise ValueError(f"texture.mapping must be 'box' or 'cube', got {cfg.mapping!r}")
        if cfg.size < 1 or cfg.features < 1:
            raise ValueError(f"texture.size and texture.features must be >= 1, got {cfg.size}, {cfg.features}")
        boxes = torch.as_tensor(np.asarray(bboxes, dtype=np.float32))
        if boxes.shape != (num_objects, 2, 3):
            raise ValueError(f"bboxes must have shape ({num_objects}, 2, 3), got {tuple(boxes.shape)}")
        self.num_objects = int(num_objects)
        self.size = int(cfg.size)
        self.features = int(cfg.features)
        self.mapping = cfg.mapping
        if cfg.tanh not in TANH_MODES:
            raise ValueError(f"texture.tanh must be one of {TANH_MODES}, got {cfg.tanh!r}")
        self.tanh_mode = cfg.tanh
        self.register_buffer("bbox_min", boxes[:, 0].clone())
        self.register_buffer("bbox_max", torch.maximum(boxes[:, 1], boxes[:, 0]).clone())
        # small index tables as non-persistent buffers: they follow .to(device), no per-call copy
        self.register_buffer("_axes", torch.arange(3), persistent=False)
        self.register_buffer("_u_ax", torch.tensor([a for a, _ in IN_PLANE_AXES]), persistent=False)
        self.register_buffer("_v_ax", torch.tensor([b for _, b in IN_PLANE_AXES]), persistent=False)
        init = torch.zeros(num_objects, 6, cfg.size, cfg.size, cfg.features)
        self.texture = nn.Parameter(init)
        if colours is not None:
            self.set_colours(colours)
        if cfg.init_noise > 0:
            self.add_noise(cfg.init_noise, cfg.init_noise_sigma, shape="blobs")
        if cfg.init_lines > 0:
            self.add_noise(cfg.init_lines, cfg.init_lines_sigma, shape="lines")

    @classmethod
    def from_colours(cls, bboxes, colours, cfg: TextureConfig | None = None) -> "NeuralTexture":
        """A texture whose objects start flat at ``colours`` (O, C) in [0, 1]."""
        return cls(len(colours), bboxes, colours, cfg)

    @torch.no_grad()
    def set_colours(self, colours) -> None:
        """Reset every texel of object o to ``atanh(clip(2 colours[o] - 1, +-INIT_CLIP))``."""
        col = torch.as_tensor(np.asarray(colours, dtype=np.float64))
        if col.ndim != 2 or col.shape[0] != self.num_objects:
            raise ValueError(f"colours must have shape ({self.num_objects}, C), got {tuple(col.shape)}")
        reps = math.ceil(self.features / col.shape[1])
        col = col.repeat(1, reps)[:, : self.features]
        pre = torch.atanh((2.0 * col - 1.0).clamp(-INIT_CLIP, INIT_CLIP))
        self.texture.copy_(pre.to(self.texture)[:, None, None, None, :].expand_as(self.texture))

    @torch.no_grad()
    def add_noise(self, std: float, sigma: float, generator: torch.Generator | None = None,
                  shape: str = "blobs") -> None:
        """Add band-limited noise to every plane: white noise blurred with a Gaussian of ``sigma``
        texels (separable, reflect padding), rescaled to unit standard deviation: ``n``.
        Neighbouring texels then correlate by exp(-1 / (4 sigma^2)) (0.895 at sigma 1.5).

        ``shape`` 'blobs': one ``n`` per feature, added times ``std``. 'lines': one ``n`` per plane,
        shared by the features, and every feature is lowered by ``std * exp(-n^2 / (2 w^2))``
        (w = :data:`LINE_WIDTH`): dark curves along the zero crossings of ``n``, winding loops that
        look like a net of septa or vessels, about 2.4 w sigma texels wide and a few sigma apart."""
        if shape not in NOISE_SHAPES:
            raise ValueError(f"noise shape must be one of {NOISE_SHAPES}, got {shape!r}")
        O, P, S, _, N = self.texture.shape
        fields = N if shape == "blobs" else 1
        noise = torch.randn((O * P * fields, 1, S, S), generator=generator)
        r = max(1, math.ceil(3 * sigma))
        x = torch.arange(-r, r + 1, dtype=torch.float32)
        k = torch.exp(-0.5 * (x / sigma) ** 2)
        k = k / k.sum()
        pad = min(r, S - 1)
        if pad > 0:
            noise = torch.nn.functional.pad(noise, (pad, pad, pad, pad), mode="reflect")
            kk = k[r - pad : r + pad + 1]
            noise = torch.nn.functional.conv2d(noise, kk.view(1, 1, 1, -1))
            noise = torch.nn.functional.conv2d(noise, kk.view(1, 1, -1, 1))
        noise = noise / noise.std().clamp_min(1e-12)
        if shape == "lines":
            noise = -torch.exp(-0.5 * (noise / LINE_WIDTH) ** 2)
        noise = (std * noise).reshape(O, P, fields, S, S).permute(0, 1, 3, 4, 2)
        self.texture.add_(noise.expand(O, P, S, S, N).to(self.texture))

    def plane_coords(self, object_id: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        """Normalised coordinates ``c`` (..., 3): c[..., k] is the position along world axis k in
        [0, 1] (unclamped) under the configured mapping. ``object_id`` must be >= 0."""
        lo = self.bbox_min.to(points.dtype)[object_id]
        hi = self.bbox_max.to(points.dtype)[object_id]
        if self.mapping == "box":
            return (points - lo) / (hi - lo).clamp_min(_MIN_EXTENT)
        side = (hi - lo).amax(dim=-1, keepdim=True).clamp_min(_MIN_EXTENT)
        return (points - 0.5 * (lo + hi)) / side + 0.5

    def forward(self, object_id: torch.Tensor, points: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """Project the texture into a view.

        Args:
            object_id: (B, H, W) long, -1 for background.
            points: (B, H, W, 3) world surface points, mm.
            normals: (B, H, W, 3) unit world normals.

        Returns:
            (B, N, H, W) features in (-1, 1); 0 on the background. Ids must be < O.
        """
        if object_id.shape != points.shape[:-1] or points.shape != normals.shape or points.shape[-1] != 3:
            raise ValueError(
                f"expected object_id (B,H,W), points and normals (B,H,W,3); got "
                f"{tuple(object_id.shape)}, {tuple(points.shape)}, {tuple(normals.shape)}"
            )
        B, H, W = object_id.shape
        S, N = self.size, self.features
        tex = self.texture
        dtype = tex.dtype
        oid = object_id.reshape(-1).long()
        fg = oid >= 0
        o = oid.clamp_min(0)
        keep = fg.unsqueeze(-1)  # background points/normals may be 0 or NaN: neutralise them
        pts = torch.where(keep, points.reshape(-1, 3).to(dtype), 0.0)
        nrm = torch.where(keep, normals.reshape(-1, 3).to(dtype), 0.0)

        # Axis-major layout (3, P): per-plane selections are cheap row copies, and the 12
        # gathers run in pixel order, so neighbouring pixels hit neighbouring texels.
        c = self.plane_coords(o, pts).t()  # (3, P)
        t = (c * (S - 1)).clamp(0, S - 1)  # texel coordinate along each world axis
        t0f = t.floor()
        frac = t - t0f
        t0 = t0f.long()
        t1 = (t0 + 1).clamp_max(S - 1)

        n_t = nrm.t()  # (3, P)
        n2 = n_t * n_t
        w_axis = n2 / n2.sum(0, keepdim=True).clamp_min(1e-12)  # (3, P), sums to 1 on foreground
        w_axis = w_axis * fg.to(dtype)
        plane = 2 * self._axes.unsqueeze(1) + (n_t < 0).long()  # +a: 2a, -a: 2a+1
        base = (o * 6 + plane) * (S * S)  # (3, P)

        iu0, iu1, du = (x.index_select(0, self._u_ax) for x in (t0, t1, frac))  # (3, P): planes of x, y, z
        iv0, iv1, dv = (x.index_select(0, self._v_ax) for x in (t0, t1, frac))
        row0, row1 = base + iu0 * S, base + iu1 * S
        idx = torch.stack((row0 + iv0, row0 + iv1, row1 + iv0, row1 + iv1), dim=1)  # (3, 4, P)
        wb = torch.stack(((1 - du) * (1 - dv), (1 - du) * dv, du * (1 - dv), du * dv), dim=1)
        weights = (wb * w_axis.unsqueeze(1)).reshape(12, -1, 1)

        texel = self.tanh_mode == "texel"
        flat = (torch.tanh(tex) if texel else tex).reshape(-1, N)  # 'texel': O(texels) per step
        gathered = flat.index_select(0, idx.reshape(-1)).reshape(12, -1, N)
        feat = (gathered * weights).sum(dim=0)  # (P, N); exactly 0 on background
        if not texel:
            feat = torch.tanh(feat)
        return feat.reshape(B, H, W, N).permute(0, 3, 1, 2).contiguous()

    def extra_repr(self) -> str:
        return (f"objects={self.num_objects}, size={self.size}, features={self.features}, mapping={self.mapping}, "
                f"tanh={self.tanh_mode}")
