"""Camera and sensor shading of the stand-in real domain: one G-buffer + materials -> a frame.

Shading: one light on the camera with a distance falloff and a spot profile (the centre of the
view is brightest), wrapped Lambert diffuse plus Blinn-Phong specular (with the light on the
camera the half vector is the view direction) on normals perturbed by each material's bump
field, so wet highlights break up into glints; then lens vignetting, a filmic tone curve, sRGB,
an optional circular endoscope mask, a slight blur and sensor noise.

The light here is the stand-in scope's (:func:`scope_light_falloff`, 1 at a reference distance),
not the paper's reference rendering a_ref (:func:`sim2real.render.reference.paper_light_falloff`).
Not modelled: smoke, blood, instruments, tissue deformation, motion blur, lens distortion.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import cv2
import numpy as np

from sim2real.colour import GREY_WEIGHTS
from sim2real.realdomain.appearance import linear_to_srgb
from sim2real.realdomain.materials import SceneMaterial
from sim2real.render.gbuffer import GBuffer
from sim2real.scene.scene import LABEL_BACKGROUND


@dataclass
class RenderOptions:
    """Camera and sensor settings of the stand-in frames."""

    height: int = 256
    width: int = 512
    fov_x_deg: float = 75.0
    mask: bool = False
    """Black out the corners outside the endoscope's circular image (labels 255 there)."""
    mask_radius: float = 0.5
    """Radius of the circular mask as a fraction of the image width (0.5: the circle touches
    the left and right borders and cuts the corners)."""
    blur_px: float = 0.6
    """Gaussian blur sigma in pixels (0 = none)."""
    noise: float = 0.012
    """Sensor noise standard deviation at full brightness (0 = none)."""
    vignetting: float = 0.5
    """Brightness lost in the image corners by the lens (0 = none)."""
    saturation: float = 1.25
    """Colour saturation applied by the camera (1 = none)."""

    def to_json(self) -> dict:
        return asdict(self)


@dataclass
class RealFrame:
    """One stand-in frame and its intermediate buffers (float buffers are (H, W[, 3]))."""

    image: np.ndarray  # uint8 (H, W, 3) sRGB
    label: np.ndarray  # uint8 (H, W): class index, 255 = background
    albedo: np.ndarray  # float32 (H, W, 3) linear albedo, view independent; 0 on background
    shading: np.ndarray  # float32 (H, W) diffuse irradiance factor (light x falloff x cosine)
    specular: np.ndarray  # float32 (H, W) specular radiance added on top (linear)
    radiance: np.ndarray = field(repr=False, default=None)  # float32 (H, W, 3) before the camera


def scope_light_falloff(distance: np.ndarray, reference_mm: float) -> np.ndarray:
    """Irradiance from the light on the camera at ``distance`` mm, 1 at ``reference_mm``:
    (1 + a) / (a + (d / d_ref)^2) with a = 0.25: inverse square far away, softened close up
    (the light leaves the scope through an extended fibre bundle, not a point). Not the paper's
    a_ref falloff (:func:`sim2real.render.reference.paper_light_falloff`)."""
    a = 0.25
    x = np.asarray(distance, dtype=np.float32) / np.float32(reference_mm)
    return ((1.0 + a) / (a + x * x)).astype(np.float32)


def circular_mask(height: int, width: int, radius: float) -> np.ndarray:
    """Coverage in [0, 1] (float32, H x W) of the endoscope's circular image, anti-aliased over
    one pixel; ``radius`` is a fraction of the width."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    r = np.hypot(xx + 0.5 - width / 2, yy + 0.5 - height / 2)
    return np.clip(radius * width - r + 0.5, 0.0, 1.0).astype(np.float32)


def render_frame(g: GBuffer, material: SceneMaterial, options: RenderOptions | None = None, seed: int = 0) -> RealFrame:
    """Shade one G-buffer with the scene's solid textures (see the module docstring)."""
    opt = options or RenderOptions()
    app = material.appearance
    h, w = g.height, g.width
    hit = g.mask.reshape(-1)
    idx = np.nonzero(hit)[0]
    pts = g.points.reshape(-1, 3)[idx]
    nrm = g.normal.reshape(-1, 3)[idx].astype(np.float32)
    dist = g.distance.reshape(-1)[idx].astype(np.float32)
    eye = g.camera.position.astype(np.float32)
    v = eye[None] - pts.astype(np.float32)
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
    ndv0 = np.clip(np.einsum("ij,ij->i", nrm, v), 0.0, 1.0)
    focal = float(g.K[0, 0])
    footprint = dist / focal / np.sqrt(np.maximum(ndv0, 0.15))  # mm per pixel on the surface

    s = material.surface(g.object_id.reshape(-1)[idx], pts, nrm, footprint)
    # Bump mapping: tilt the normal against the tangential part of the height gradient.
    b = s["bump"]
    b_t = b - np.einsum("ij,ij->i", b, nrm)[:, None] * nrm
    nb = nrm - b_t
    nb /= np.maximum(np.linalg.norm(nb, axis=1, keepdims=True), 1e-9)
    ndv = np.clip(np.einsum("ij,ij->i", nb, v), 0.0, 1.0)
    nd = nrm - s["diffuse_bump"][:, None] * b_t
    nd /= np.maximum(np.linalg.norm(nd, axis=1, keepdims=True), 1e-9)
    ndv_d = np.clip(np.einsum("ij,ij->i", nd, v), 0.0, 1.0)
    wrap = s["wrap"]
    diffuse = np.clip((ndv_d + wrap) / (1.0 + wrap), 0.0, 1.0)
    # The light sits on the camera: distance falloff times the spot profile of the light guide.
    axis = g.world_to_camera[2, :3].astype(np.float32)
    cos_axis = np.clip(-(v @ axis), 0.0, 1.0)
    light = scope_light_falloff(dist, app.light_reference_mm) * cos_axis**6.0
    # Normalised Blinn-Phong: the peak grows with the shininess, as on a wet surface.
    spec = s["specular"] * (s["shininess"] + 8.0) / 8.0 * ndv ** s["shininess"] + s["sheen"] * ndv**6
    spec *= np.clip(ndv0 * 3.0, 0.0, 1.0)  # no highlights on silhouettes of the smooth mesh
    rad = light[:, None] * (s["albedo"] * diffuse[:, None] + spec[:, None] * np.array([1.0, 0.97, 0.92], np.float32))

    def full(a, channels=0):
        out = np.zeros((h * w, channels) if channels else h * w, np.float32)
        out[idx] = a
        return out.reshape((h, w, channels) if channels else (h, w))

    albedo_img = full(s["albedo"], 3)
    shading_img = full(light * diffuse)
    spec_img = full(light * spec)
    radiance = full(rad, 3)

    # Camera: lens vignetting, exposure, filmic shoulder, sRGB, blur, noise, mask.
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx + 0.5 - w / 2) ** 2 + (yy + 0.5 - h / 2) ** 2) / (0.25 * (w * w + h * h))
    x = radiance * (1.0 - opt.vignetting * r2)[..., None] * (2.0 * app.exposure)
    white = 4.0
    x = x * (1.0 + x / (white * white)) / (1.0 + x)
    img = linear_to_srgb(x)
    # The camera's colour processing: a mild saturation boost, as endoscope video has.
    grey = img @ np.array(GREY_WEIGHTS, np.float32)
    img = grey[..., None] + opt.saturation * (img - grey[..., None])
    if opt.blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), opt.blur_px)
    if opt.noise > 0:
        rng = np.random.default_rng(seed)
        lum_noise = rng.normal(0.0, 1.0, (h, w, 1)).astype(np.float32)
        chroma = rng.normal(0.0, 0.4, (h, w, 3)).astype(np.float32)
        img = img + opt.noise * (lum_noise + chroma) * np.sqrt(np.clip(img, 0.05, 1.0))
    label = g.labels()
    if opt.mask:
        m = circular_mask(h, w, opt.mask_radius)
        img *= m[..., None]
        label[m < 0.5] = LABEL_BACKGROUND
    image = (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return RealFrame(image=image, label=label, albedo=albedo_img, shading=shading_img, specular=spec_img, radiance=radiance)
