"""Procedural materials: smooth noise, wood grain, knots, end grain, chipboard, concrete.

Low-level building blocks of :mod:`perception.synth.appearance`. Every function takes a
``numpy.random.Generator`` and returns float32 arrays (luminance in about 0..1, or BGR in
0..255); nothing is cached here.
"""

from __future__ import annotations

import cv2
import numpy as np

Rng = np.random.Generator


def smooth_noise(rng: Rng, h: int, w: int, cells_y: int, cells_x: int) -> np.ndarray:
    """Band-limited noise (about zero mean, unit std) of shape (h, w): cubic-upsampled cells."""
    small = rng.standard_normal((max(cells_y, 2), max(cells_x, 2))).astype(np.float32)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


def wood_grain(
    rng: Rng,
    h: int,
    w: int,
    *,
    period_px: float,
    slope: float = 0.0,
    warp_px: float = 6.0,
    knots: list[tuple[float, float, float, float]] | None = None,
) -> np.ndarray:
    """Side-grain luminance (h, w) in 0..1: warped growth rings along x, fibres, knots.

    ``knots`` lists (x, y, rx, ry) in pixels; the rings bend around each knot and the knot
    itself is a dark ellipse with a few rings of its own.
    """
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    coord = yy + slope * xx
    coord += warp_px * smooth_noise(rng, h, w, 3, max(3, w // 60))
    coord += 0.35 * warp_px * smooth_noise(rng, h, w, 6, max(4, w // 25))
    knot_dark = np.zeros((h, w), np.float32)
    for kx, ky, rx, ry in knots or []:
        d2 = ((xx - kx) / (rx * 2.5)) ** 2 + ((yy - ky) / (ry * 2.5)) ** 2
        push = np.exp(-d2) * (ry * 2.2)
        coord += np.where(yy >= ky, push, -push)
        dk = np.sqrt(((xx - kx) / rx) ** 2 + ((yy - ky) / ry) ** 2)
        core = np.clip(1.2 - dk, 0.0, 1.0)
        rings = 0.5 + 0.5 * np.cos(dk * 9.0)
        knot_dark = np.maximum(knot_dark, core * (0.55 + 0.35 * rings))
    phase = coord / period_px
    ring = np.mod(phase, 1.0)
    # Early wood (light, wide) then late wood (dark, narrow): a skewed saw-tooth.
    late = np.clip((ring - 0.6) / 0.4, 0.0, 1.0) ** 1.5
    lum = 0.78 - 0.17 * late
    fibre = cv2.resize(
        rng.standard_normal((h, max(w // 18, 2)), dtype=np.float32),
        (w, h),
        interpolation=cv2.INTER_LINEAR,
    )
    lum += 0.045 * fibre + 0.03 * rng.standard_normal((h, w), dtype=np.float32)
    lum += 0.06 * smooth_noise(rng, h, w, 2, max(2, w // 120))
    lum *= 1.0 - 0.75 * knot_dark
    return np.clip(cv2.GaussianBlur(lum, (3, 3), 0.8), 0.0, 1.0)


def end_grain(rng: Rng, h: int, w: int, *, period_px: float) -> np.ndarray:
    """End-grain luminance (h, w): arcs of growth rings around a pith outside the board."""
    cx = rng.uniform(-0.3, 1.3) * w
    cy = rng.choice([-1.0, 1.0]) * rng.uniform(1.2, 4.0) * h + (h if rng.random() < 0.5 else 0)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r = np.sqrt((xx - cx) ** 2 + (yy - cy) ** 2)
    r += 2.0 * smooth_noise(rng, h, w, 3, max(3, w // 40))
    ring = np.mod(r / period_px, 1.0)
    lum = 0.62 - 0.22 * np.clip((ring - 0.7) / 0.3, 0.0, 1.0)
    lum += 0.06 * rng.standard_normal((h, w), dtype=np.float32)  # rough saw cut
    lum += 0.05 * smooth_noise(rng, h, w, 2, 4)
    return np.clip(lum, 0.0, 1.0)


def chipboard(rng: Rng, h: int, w: int) -> np.ndarray:
    """Pressed wood-chip block luminance (h, w): overlapping flakes of varying tone."""
    lum = 0.68 + 0.05 * smooth_noise(rng, h, w, max(h // 30, 2), max(w // 30, 2))
    lum = np.ascontiguousarray(lum, np.float32)
    n = h * w // 40
    xs, ys = rng.uniform(0, w, n), rng.uniform(0, h, n)
    ax, ay = rng.uniform(2.0, 9.0, n), rng.uniform(1.0, 3.5, n)
    ang = rng.normal(0.0, 25.0, n)
    tone = np.clip(0.68 + rng.normal(0.0, 0.09, n), 0.3, 0.95)
    for i in range(n):
        cv2.ellipse(
            lum,
            (int(xs[i]), int(ys[i])),
            (int(ax[i]), int(ay[i])),
            float(ang[i]),
            0,
            360,
            float(tone[i]),
            -1,
        )
    lum += 0.03 * rng.standard_normal((h, w), dtype=np.float32)
    lum = cv2.GaussianBlur(lum, (3, 3), 0.6)
    return np.clip(lum, 0.0, 1.0)


def colourise(lum: np.ndarray, base_bgr: np.ndarray, dark_bgr: np.ndarray) -> np.ndarray:
    """BGR float image: ``dark_bgr`` at luminance 0, ``base_bgr`` at about 0.8 and above."""
    t = np.clip(lum / 0.8, 0.0, 1.25)[..., None]
    return dark_bgr[None, None, :] * (1.0 - t) + base_bgr[None, None, :] * t


def blend(img: np.ndarray, alpha: np.ndarray, colour: tuple[float, float, float]) -> None:
    """In place: ``img = img * (1 - alpha) + colour * alpha`` (alpha (h, w) in 0..1)."""
    a = alpha[..., None]
    img *= 1.0 - a
    img += a * np.asarray(colour, np.float32)[None, None, :]


def concrete(rng: Rng, h: int, w: int, *, joint_px: int = 0) -> np.ndarray:
    """Warehouse concrete floor BGR (h, w): mottled grey, stains, optional saw-cut joints."""
    lum = 0.55 + 0.03 * smooth_noise(rng, h, w, h // 40 + 2, w // 40 + 2)
    lum += 0.03 * smooth_noise(rng, h, w, h // 8 + 2, w // 8 + 2)
    lum += 0.025 * rng.standard_normal((h, w), dtype=np.float32)
    stains = np.clip(smooth_noise(rng, h, w, h // 60 + 2, w // 60 + 2) - 1.2, 0.0, 1.0)
    lum -= 0.08 * stains
    img = np.stack([lum * 190.0, lum * 188.0, lum * 182.0], axis=-1)
    if joint_px > 0:
        img[::joint_px, :, :] *= 0.55
        img[:, ::joint_px, :] *= 0.55
    return np.clip(img, 0, 255)
