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

    Every pixel gets the same float32 operations as a whole-image formulation would give
    it (``tests/test_relief_speed.py`` compares against it), but the pixel grid is a row
    and a column (broadcast), a knot is drawn in its bounding boxes only (where its push
    and its core are not 0), and ``np.mod`` (slow) is the exactly equal ``x - floor(x)``.
    """
    yy = np.arange(h, dtype=np.float32)[:, None]
    xx = np.arange(w, dtype=np.float32)[None, :]
    coord = yy + slope * xx
    coord += warp_px * smooth_noise(rng, h, w, 3, max(3, w // 60))
    coord += 0.35 * warp_px * smooth_noise(rng, h, w, 6, max(4, w // 25))
    knot_dark = None
    for kx, ky, rx, ry in knots or []:
        tx, ty = ((xx - kx) / (rx * 2.5)) ** 2, ((yy - ky) / (ry * 2.5)) ** 2
        # the rings' push: exp(-d2) is exactly 0 from d2 = 104 on (below the least float32),
        # so only in the box where one of the two terms is under 120
        cols, rows = np.flatnonzero(tx[0] < 120.0), np.flatnonzero(ty[:, 0] < 120.0)
        if cols.size and rows.size:
            c, r = np.s_[cols[0] : cols[-1] + 1], np.s_[rows[0] : rows[-1] + 1]
            push = np.exp(-(tx[:, c] + ty[r])) * (ry * 2.2)
            coord[r, c] += np.where(yy[r] >= ky, push, -push)
        # the dark core: 1.2 - dk <= 0 more than a pixel outside the ellipse dk < 1.2
        x0, x1 = max(0, int(kx - 1.2 * rx) - 2), min(w, int(kx + 1.2 * rx) + 3)
        y0, y1 = max(0, int(ky - 1.2 * ry) - 2), min(h, int(ky + 1.2 * ry) + 3)
        if x1 <= x0 or y1 <= y0:
            continue
        if knot_dark is None:
            knot_dark = np.zeros((h, w), np.float32)
        dk = np.sqrt(((xx[:, x0:x1] - kx) / rx) ** 2 + ((yy[y0:y1] - ky) / ry) ** 2)
        core = np.clip(1.2 - dk, 0.0, 1.0)
        rings = 0.5 + 0.5 * np.cos(dk * 9.0)
        box = knot_dark[y0:y1, x0:x1]
        np.maximum(box, core * (0.55 + 0.35 * rings), out=box)
    phase = coord / period_px
    ring = phase - np.floor(phase)  # np.mod(phase, 1.0), bit for bit
    # Early wood (light, wide) then late wood (dark, narrow): a skewed saw-tooth.
    late = np.clip((ring - 0.6) / 0.4, 0.0, 1.0)
    dark = late > 0.0  # 0 ** 1.5 is 0: the power only where it is not
    late[dark] = late[dark] ** 1.5
    lum = 0.78 - 0.17 * late
    fibre = cv2.resize(
        rng.standard_normal((h, max(w // 18, 2)), dtype=np.float32),
        (w, h),
        interpolation=cv2.INTER_LINEAR,
    )
    lum += 0.045 * fibre + 0.03 * rng.standard_normal((h, w), dtype=np.float32)
    lum += 0.06 * smooth_noise(rng, h, w, 2, max(2, w // 120))
    if knot_dark is not None:  # without knots the factor is 1.0 everywhere
        lum *= 1.0 - 0.75 * knot_dark
    return np.clip(cv2.GaussianBlur(lum, (3, 3), 0.8), 0.0, 1.0)


def end_grain(rng: Rng, h: int, w: int, *, period_px: float) -> np.ndarray:
    """End-grain luminance (h, w): arcs of growth rings around a pith outside the board."""
    cx = rng.uniform(-0.3, 1.3) * w
    cy = rng.choice([-1.0, 1.0]) * rng.uniform(1.2, 4.0) * h + (h if rng.random() < 0.5 else 0)
    yy = np.arange(h, dtype=np.float32)[:, None]
    xx = np.arange(w, dtype=np.float32)[None, :]
    r = np.sqrt((xx - cx) ** 2 + (yy - cy) ** 2)
    r += 2.0 * smooth_noise(rng, h, w, 3, max(3, w // 40))
    phase = r / period_px
    ring = phase - np.floor(phase)  # np.mod(phase, 1.0), bit for bit
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
    # as Python numbers once (int() truncates as astype does): the loop is call overhead
    xs, ys = xs.astype(np.int64).tolist(), ys.astype(np.int64).tolist()
    ax, ay = ax.astype(np.int64).tolist(), ay.astype(np.int64).tolist()
    for x, y, a, b, angle, t in zip(xs, ys, ax, ay, ang.tolist(), tone.tolist(), strict=True):
        cv2.ellipse(lum, (x, y), (a, b), angle, 0, 360, t, -1)
    lum += 0.03 * rng.standard_normal((h, w), dtype=np.float32)
    lum = cv2.GaussianBlur(lum, (3, 3), 0.6)
    return np.clip(lum, 0.0, 1.0)


def colourise(lum: np.ndarray, base_bgr: np.ndarray, dark_bgr: np.ndarray) -> np.ndarray:
    """BGR float image: ``dark_bgr`` at luminance 0, ``base_bgr`` at about 0.8 and above
    (channel by channel: numpy is slow over a last axis of 3)."""
    t = np.clip(lum / 0.8, 0.0, 1.25)
    u = 1.0 - t
    out = np.empty((*t.shape, 3), np.result_type(dark_bgr, base_bgr, t))
    for c in range(3):
        np.add(dark_bgr[c] * u, base_bgr[c] * t, out=out[..., c])
    return out


def blend(img: np.ndarray, alpha: np.ndarray, colour: tuple[float, float, float]) -> None:
    """In place: ``img = img * (1 - alpha) + colour * alpha`` (alpha (h, w) in 0..1)."""
    col = np.asarray(colour, np.float32)
    if img.dtype != np.float32 or alpha.dtype != np.float32 or img.shape != (*alpha.shape, 3):
        a = alpha[..., None]
        img *= 1.0 - a
        img += a * col[None, None, :]
        return
    keep = 1.0 - alpha  # the same float32 operations, channel by channel (much faster)
    for c in range(3):
        channel = img[..., c]
        channel *= keep
        channel += alpha * col[c]


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
