"""How one frame is taken: light, optics, sensor and the AI-deck's stream, as one value.

:class:`ViewConditions` gathers what changes a frame besides the scene and the pose:
exposure, contrast, colour temperature, motion blur, defocus, extra sensor noise, the
JPEG compression the AI-deck applies to the raw Bayer mosaic before streaming it, and a
lower resolution. :func:`take_frame` renders a raw frame under them, :func:`develop`
decodes and white-balances it the way the mission does, and :func:`random_conditions`
draws conditions over a broad range for training.

``bayer_jpeg`` and ``resensor_crop`` reproduce the sensor-side damage on their own: the
first on a raw frame, the second on a crop (an augmentation that re-mosaics the crop,
adds noise, compresses and demosaics it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from perception.synth.camera_model import CameraModel, CameraPose
from perception.synth.render import Lighting, SensorModel, apply_sensor, illuminant_bgr
from perception.synth.render import render_scene as _render_scene
from perception.synth.scene import Scene
from perception.white_balance import preprocess


@dataclass(frozen=True)
class ViewConditions:
    """Everything about one frame except the scene and the pose.

    Attributes:
        exposure: overall gain (1: the renderer's nominal exposure).
        contrast: contrast about mid-grey.
        gradient: brightness change from the image centre to its edge (fraction).
        colour_temperature_k: light colour (None: the scene's lamps).
        motion_px: horizontal smear over the exposure, in pixels (sign = direction).
        defocus_px: Gaussian blur of the optics (sigma, pixels).
        noise_dn: extra Gaussian read noise on the raw frame (standard deviation, DN).
        jpeg_quality: 0 streams raw; 1..100 streams the Bayer mosaic as a JPEG of that
            quality (what the AI-deck's JPEG mode does).
        downscale: the decoded frame is shrunk by this factor and scaled back (>= 1).
    """

    exposure: float = 1.0
    contrast: float = 1.0
    gradient: float = 0.0
    colour_temperature_k: float | None = None
    motion_px: float = 0.0
    defocus_px: float = 0.0
    noise_dn: float = 0.0
    jpeg_quality: int = 0
    downscale: float = 1.0

    def __post_init__(self) -> None:
        if self.exposure <= 0 or self.contrast <= 0:
            raise ValueError("exposure and contrast must be > 0")
        if not 0 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be 0 (raw) or 1..100, got {self.jpeg_quality}")
        if self.downscale < 1.0 or self.noise_dn < 0 or self.defocus_px < 0:
            raise ValueError("downscale must be >= 1, noise_dn and defocus_px >= 0")


def bayer_jpeg(raw: np.ndarray, quality: int) -> np.ndarray:
    """The raw Bayer mosaic (H, W) after a JPEG round trip at ``quality`` (greyscale JPEG
    of the mosaic, as the AI-deck streams it; the colour filter pattern is compressed as
    if it were image detail)."""
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(raw), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)


def add_noise(raw: np.ndarray, rng: np.random.Generator, sigma_dn: float) -> np.ndarray:
    """Raw frame plus Gaussian noise of ``sigma_dn`` (clipped to 0..255, uint8)."""
    if sigma_dn <= 0:
        return raw
    noisy = raw.astype(np.float32) + rng.normal(0.0, sigma_dn, raw.shape).astype(np.float32)
    return np.clip(noisy + 0.5, 0, 255).astype(np.uint8)


def take_frame(
    camera: CameraModel,
    pose: CameraPose,
    scene: Scene,
    rng: np.random.Generator,
    cond: ViewConditions = ViewConditions(),
    sensor: SensorModel | None = None,
) -> np.ndarray:
    """Raw 244 x 324 Bayer frame of ``scene`` from ``pose`` under ``cond`` (before the
    resolution change, which :func:`develop` applies)."""
    bgr, _ = _render_scene(camera, pose, scene)
    if cond.defocus_px > 0:
        bgr = cv2.GaussianBlur(bgr, (0, 0), cond.defocus_px)
    lighting = Lighting(
        exposure=cond.exposure,
        contrast=cond.contrast,
        gradient=cond.gradient,
        gradient_angle_rad=float(rng.uniform(-math.pi, math.pi)),
    )
    kelvin = cond.colour_temperature_k or scene.light.colour_temperature_k
    raw = apply_sensor(
        bgr,
        rng,
        lighting=lighting,
        sensor=sensor or SensorModel(),
        illuminant=illuminant_bgr(kelvin),
        blur=(cond.motion_px, 0.0),
    )
    raw = add_noise(raw, rng, cond.noise_dn)
    if cond.jpeg_quality:
        raw = bayer_jpeg(raw, cond.jpeg_quality)
    return raw


def develop(
    raw: np.ndarray, factors: tuple[float, float, float], cond: ViewConditions = ViewConditions()
) -> np.ndarray:
    """Decode and white-balance a raw frame (the mission's preprocessing), then apply the
    condition's lower resolution (shrink by ``downscale`` and scale back)."""
    bgr = preprocess(raw, factors)
    if cond.downscale > 1.0:
        h, w = bgr.shape[:2]
        small = cv2.resize(
            bgr,
            (max(4, round(w / cond.downscale)), max(4, round(h / cond.downscale))),
            interpolation=cv2.INTER_AREA,
        )
        bgr = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    return bgr


@dataclass(frozen=True)
class ConditionRanges:
    """What :func:`random_conditions` draws from: (low, high) ranges, and for the optional
    effects (share of frames, largest strength)."""

    exposure: tuple[float, float] = (0.55, 1.8)  # log-uniform
    contrast: tuple[float, float] = (0.6, 1.3)
    gradient: float = 0.35
    kelvin: tuple[float, float] = (2700.0, 7000.0)
    motion: tuple[float, float] = (0.33, 8.0)  # share, largest blur (px, either way)
    defocus: tuple[float, float] = (0.2, 2.0)  # share, largest (px; at least 0.4)
    noise: tuple[float, float] = (0.33, 24.0)  # share, largest (DN; at least 2)
    jpeg: tuple[float, int] = (0.4, 8)  # share, lowest quality (up to 95)
    downscale: tuple[float, float] = (0.15, 3.0)  # share, largest factor (at least 1.3)


def random_conditions(
    rng: np.random.Generator, ranges: ConditionRanges = ConditionRanges()
) -> ViewConditions:
    """Broad training conditions (the defaults, the detector's): exposure 0.55..1.8,
    contrast 0.6..1.3, 2700..7000 K, motion blur in a third of the frames, defocus in a
    fifth, extra noise up to 24 DN in a third, Bayer JPEG (quality 8..95) in 40 %, lower
    resolution in 15 %; ``ranges`` narrows or widens them."""
    r = ranges
    return ViewConditions(
        exposure=float(np.exp(rng.uniform(np.log(r.exposure[0]), np.log(r.exposure[1])))),
        contrast=float(rng.uniform(*r.contrast)),
        gradient=float(rng.uniform(0.0, r.gradient)),
        colour_temperature_k=float(rng.uniform(*r.kelvin)),
        motion_px=float(rng.uniform(-r.motion[1], r.motion[1]))
        if rng.random() < r.motion[0]
        else 0.0,
        defocus_px=float(rng.uniform(0.4, r.defocus[1])) if rng.random() < r.defocus[0] else 0.0,
        noise_dn=float(rng.uniform(2.0, r.noise[1])) if rng.random() < r.noise[0] else 0.0,
        jpeg_quality=int(rng.integers(r.jpeg[1], 96)) if rng.random() < r.jpeg[0] else 0,
        downscale=float(rng.uniform(1.3, r.downscale[1])) if rng.random() < r.downscale[0] else 1.0,
    )


def mosaic(bgr: np.ndarray, dy: int = 0, dx: int = 0) -> np.ndarray:
    """The BayerBG mosaic of a BGR image (R at even/even), the pattern shifted by (dy, dx)."""
    h, w = bgr.shape[:2]
    rows = (np.arange(h)[:, None] + dy) % 2
    cols = (np.arange(w)[None, :] + dx) % 2
    ch = np.where((rows == 0) & (cols == 0), 2, np.where((rows == 1) & (cols == 1), 0, 1))
    return np.take_along_axis(bgr, ch[..., None], axis=2)[..., 0]


def resensor_crop(
    crop: np.ndarray,
    rng: np.random.Generator,
    noise_dn: float = 0.0,
    jpeg_quality: int = 0,
) -> np.ndarray:
    """A BGR uint8 crop taken through the sensor again: re-mosaicked (random phase), noise of
    ``noise_dn``, a JPEG of the mosaic at ``jpeg_quality`` (0: none), demosaicked."""
    h, w = crop.shape[:2]
    if h < 4 or w < 4:
        return crop
    dy, dx = int(rng.integers(2)), int(rng.integers(2))
    raw = mosaic(crop, dy, dx)
    raw = add_noise(raw, rng, noise_dn)
    if jpeg_quality:
        raw = bayer_jpeg(raw, jpeg_quality)
    padded = np.pad(raw, ((dy, 0), (dx, 0)), mode="reflect")  # pattern back to R at (0, 0)
    return cv2.cvtColor(padded, cv2.COLOR_BayerBG2BGR)[dy:, dx:]


__all__ = [
    "ViewConditions",
    "add_noise",
    "bayer_jpeg",
    "develop",
    "mosaic",
    "ConditionRanges",
    "random_conditions",
    "resensor_crop",
    "take_frame",
]
