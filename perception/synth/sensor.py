"""Sensor stage of the synthetic AI-deck camera: a true-colour BGR frame -> raw BayerBG.

:func:`apply_sensor` blurs along the image-space motion (:func:`image_motion`,
:func:`motion_kernel`), takes the Bayer mosaic, and applies per-channel sensor gains (the
green cast), the illuminant's colour (:func:`illuminant_bgr`), vignetting, exposure, a
brightness gradient, contrast, shot and read noise (:class:`Lighting`, :class:`SensorModel`).
The raw frame is uint8 BayerBG as OpenCV reads it: red at even rows and even columns, blue at
odd rows and odd columns, green elsewhere. :func:`perception.synth.render.render_frame` runs
it on :func:`perception.synth.render.render_scene`'s image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from perception.synth.camera_model import CameraModel, CameraPose, world_to_optical


@dataclass(frozen=True)
class Lighting:
    """Per-frame light and exposure: overall gain, contrast about mid-grey, a linear
    brightness gradient (fractional change from the centre to the image edge, direction in
    the image), and the exposure time used for motion blur."""

    exposure: float = 1.0
    contrast: float = 1.0
    gradient: float = 0.0
    gradient_angle_rad: float = 0.0
    exposure_time_s: float = 0.02


@dataclass(frozen=True)
class SensorModel:
    """Raw sensor response: per-channel gains (B, G, R; green strongest = the green cast of
    the raw AI-deck image), vignetting (corner fall-off), black level, read noise (DN) and
    shot noise (variance per DN)."""

    channel_gain_bgr: tuple[float, float, float] = (0.78, 1.0, 0.70)
    vignetting: float = 0.25
    black_level: float = 3.0
    read_noise: float = 1.8
    shot_noise: float = 0.18


def illuminant_bgr(kelvin: float) -> tuple[float, float, float]:
    """Relative (B, G, R) of a light of colour temperature ``kelvin`` (green = 1; 5500 K
    neutral); a mild blackbody approximation (warm light: more red, less blue)."""
    t = math.log(max(kelvin, 1000.0) / 5500.0)
    return (float(np.clip(1.0 + 0.55 * t, 0.4, 1.6)), 1.0, float(np.clip(1.0 - 0.35 * t, 0.6, 1.6)))


@lru_cache(maxsize=8)
def _cfa(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat gather indices of the BayerBG mosaic (R at even/even) and per-pixel channel."""
    rows, cols = np.mgrid[0:height, 0:width]
    ch = np.ones((height, width), np.int64)  # green
    ch[(rows % 2 == 0) & (cols % 2 == 0)] = 2  # red
    ch[(rows % 2 == 1) & (cols % 2 == 1)] = 0  # blue
    idx = (rows * width + cols) * 3 + ch
    return idx.ravel(), ch


@lru_cache(maxsize=16)
def _static_gain(
    width: int, height: int, sensor: SensorModel, illuminant: tuple[float, float, float]
) -> np.ndarray:
    _, ch = _cfa(width, height)
    gains = np.asarray(sensor.channel_gain_bgr) * np.asarray(illuminant)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
    r2 = ((xx - (width - 1) / 2) ** 2 + (yy - (height - 1) / 2) ** 2) / (
        (width / 2) ** 2 + (height / 2) ** 2
    )
    vignette = 1.0 - sensor.vignetting * r2
    return (gains[ch] * vignette).astype(np.float32)


@lru_cache(maxsize=4)
def _grids(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    return (xx - (width - 1) / 2) / (width / 2), (yy - (height - 1) / 2) / (height / 2)


@lru_cache(maxsize=4)
def _noise_bank(n: int) -> np.ndarray:
    return np.random.default_rng(20240611).standard_normal(4 * n).astype(np.float32)


def motion_kernel(du: float, dv: float) -> np.ndarray | None:
    """Linear blur kernel for an image-space smear (du, dv) in pixels (None if < 1 px)."""
    length = math.hypot(du, dv)
    if length < 1.0:
        return None
    n = int(math.ceil(length)) | 1
    k = np.zeros((n, n), np.float32)
    c = n // 2
    cv2.line(
        k,
        (int(round(c - du / 2)), int(round(c - dv / 2))),
        (int(round(c + du / 2)), int(round(c + dv / 2))),
        1.0,
        1,
        cv2.LINE_AA,
    )
    return k / k.sum()


def image_motion(
    camera: CameraModel,
    pose: CameraPose,
    velocity: tuple[float, float, float],
    yaw_rate: float,
    depth_m: float,
    exposure_time_s: float,
) -> tuple[float, float]:
    """Smear (du, dv) in pixels at the image centre over one exposure: translation at
    ``depth_m`` plus the yaw rotation (rad/s)."""
    R, _ = world_to_optical(camera, pose)
    vc = R @ np.asarray(velocity, float)
    f = camera.fx
    depth = max(depth_m, 0.05) if math.isfinite(depth_m) else 5.0
    du = -f * vc[0] / depth + f * yaw_rate
    dv = -f * vc[1] / depth
    return du * exposure_time_s, dv * exposure_time_s


def apply_sensor(
    bgr: np.ndarray,
    rng: np.random.Generator,
    *,
    lighting: Lighting = Lighting(),
    sensor: SensorModel = SensorModel(),
    illuminant: tuple[float, float, float] = (1.0, 1.0, 1.0),
    blur: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """True-colour BGR uint8 -> raw BayerBG uint8 (blur, mosaic, gains, noise, clipping)."""
    h, w = bgr.shape[:2]
    k = motion_kernel(*blur)
    if k is not None:
        bgr = cv2.filter2D(bgr, -1, k, borderType=cv2.BORDER_REPLICATE)
    raw8 = np.empty((h, w), np.uint8)  # BayerBG as OpenCV reads it: R at (even, even)
    raw8[0::2, 0::2] = bgr[0::2, 0::2, 2]
    raw8[0::2, 1::2] = bgr[0::2, 1::2, 1]
    raw8[1::2, 0::2] = bgr[1::2, 0::2, 1]
    raw8[1::2, 1::2] = bgr[1::2, 1::2, 0]
    gain = _gain_map(
        w,
        h,
        sensor,
        tuple(float(v) for v in illuminant),
        lighting.exposure,
        lighting.gradient,
        lighting.gradient_angle_rad,
    )
    raw = cv2.multiply(raw8, gain, dtype=cv2.CV_32F)
    if lighting.contrast != 1.0:
        raw -= 100.0
        raw *= lighting.contrast
        raw += 100.0
    sigma = cv2.LUT(cv2.convertScaleAbs(raw), _sigma_lut(sensor.shot_noise, sensor.read_noise))
    bank = _noise_bank(h * w)
    off = int(rng.integers(0, bank.size - h * w))
    raw += cv2.multiply(sigma, bank[off : off + h * w].reshape(h, w))
    # |x + black| saturated to uint8: values below -black (rare noise) fold back up.
    return cv2.convertScaleAbs(raw, alpha=1.0, beta=sensor.black_level)


@lru_cache(maxsize=8)
def _sigma_lut(shot: float, read: float) -> np.ndarray:
    """Noise standard deviation per signal level 0..255: sqrt(shot * x + read^2)."""
    return np.sqrt(np.arange(256, dtype=np.float32) * shot + read * read).astype(np.float32)


@lru_cache(maxsize=64)
def _gain_map(
    w: int,
    h: int,
    sensor: SensorModel,
    illuminant: tuple[float, float, float],
    exposure: float,
    gradient: float,
    angle: float,
) -> np.ndarray:
    """Per-pixel gain: Bayer channel gain x illuminant x vignetting x exposure x gradient."""
    gain = _static_gain(w, h, sensor, illuminant) * np.float32(exposure)
    if gradient:
        gx, gy = _grids(w, h)
        gain = gain * (1.0 + gradient * math.cos(angle) * gx + gradient * math.sin(angle) * gy)
    return gain.astype(np.float32)


__all__ = [
    "Lighting",
    "SensorModel",
    "apply_sensor",
    "illuminant_bgr",
    "image_motion",
    "motion_kernel",
]
