"""What happens to a pallet side between its enrolment and a later scan, weeks after.

:class:`Ageing` lists the changes (new stains, dust, scratches, chipped edges, a new or a
faded stamp, moisture darkening, and things in front of the blocks: a strap, stretch film,
an overhanging load); :func:`age_image` draws them into a float32 BGR image (a block-face
texture, or a crop as a training augmentation) and returns how much each pixel was covered
(0 untouched .. 1 hidden), which is what the embedder's visibility head learns to predict.

Sizes are relative to the image, so the same :class:`Ageing` means the same thing on a
290 x 156 texture and on a 40 x 22 crop. Every operation is driven by the given
``numpy.random.Generator``: a seeded generator always ages a face the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from perception.synth.woodgen import blend, smooth_noise

Rng = np.random.Generator

#: things in front of a block: a strap, stretch film, an overhanging load, any shape
OCCLUDERS = ("strap", "film", "overhang", "shape")

_STAINS = ((22.0, 24.0, 28.0), (38.0, 52.0, 68.0), (30.0, 40.0, 50.0), (16.0, 16.0, 16.0))
_STRAPS = (
    (40, 120, 40),
    (30, 30, 30),
    (225, 225, 225),
    (170, 90, 20),
    (30, 170, 220),
    (40, 40, 190),
)


@dataclass(frozen=True)
class Ageing:
    """Changes to a pallet side after enrolment (all zero: unchanged).

    Attributes:
        seed: mixed into every draw (two ageings with other seeds differ in where).
        stains: fraction of each block face under new dark stains (oil, water, dirt), 0..1.
        dust: fraction of each block face under light dust, 0..1.
        scratches: number of new scratches per block face.
        chips: number of newly chipped edges per block face.
        new_stamp: a new ink stamp on each block face.
        fade_stamps: how much the existing stamps faded, 0 (not) .. 1 (gone).
        moisture: darkening by moisture, 0 .. 1 (soaked).
        occlusion: fraction of each block face hidden by ``occluder``, 0..1.
        occluder: one of :data:`OCCLUDERS`.
    """

    seed: int = 0
    stains: float = 0.0
    dust: float = 0.0
    scratches: int = 0
    chips: int = 0
    new_stamp: bool = False
    fade_stamps: float = 0.0
    moisture: float = 0.0
    occlusion: float = 0.0
    occluder: str = "strap"

    def __post_init__(self) -> None:
        for name in ("stains", "dust", "fade_stamps", "moisture", "occlusion"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"ageing {name} must be within 0..1, got {v}")
        if self.scratches < 0 or self.chips < 0:
            raise ValueError("ageing scratches and chips must be >= 0")
        if self.occluder not in OCCLUDERS:
            raise ValueError(f"unknown occluder {self.occluder!r} (known: {', '.join(OCCLUDERS)})")

    @property
    def changes_texture(self) -> bool:
        """True if anything at all changes."""
        return bool(
            self.stains or self.dust or self.scratches or self.chips or self.new_stamp
        ) or bool(self.fade_stamps or self.moisture or self.occlusion)

    @classmethod
    def gradual(cls, strength: float, seed: int = 0) -> Ageing:
        """A mild mix of everything at ``strength`` 0..1 (the world files' ``age`` key): at
        1, 10 % stains, 10 % dust, 3 scratches, 2 chips, a new stamp, half-faded stamps,
        some moisture."""
        s = float(np.clip(strength, 0.0, 1.0))
        return cls(
            seed=seed,
            stains=0.10 * s,
            dust=0.10 * s,
            scratches=int(round(3 * s)),
            chips=int(round(2 * s)),
            new_stamp=s >= 0.75,
            fade_stamps=0.5 * s,
            moisture=0.3 * s,
        )


def _blob_mask(rng: Rng, h: int, w: int, fraction: float, blobs: int) -> np.ndarray:
    """A soft mask covering about ``fraction`` of the image with ``blobs`` irregular blobs."""
    if fraction <= 0.0:
        return np.zeros((h, w), np.float32)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    field = np.zeros((h, w), np.float32)
    for _ in range(max(1, blobs)):
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        sx, sy = rng.uniform(0.08, 0.35) * w, rng.uniform(0.1, 0.45) * h
        field = np.maximum(field, np.exp(-(((xx - cx) / sx) ** 2 + ((yy - cy) / sy) ** 2)))
    field += 0.25 * smooth_noise(rng, h, w, max(3, h // 12), max(3, w // 12))
    thr = np.quantile(field, 1.0 - min(fraction, 0.999))
    soft = max(float(field.std()) * 0.08, 1e-4)
    return np.clip((field - thr) / soft + 0.5, 0.0, 1.0).astype(np.float32)


def stains(img: np.ndarray, rng: Rng, fraction: float) -> np.ndarray:
    """New dark stains (oil, water rings, dirt) over ``fraction`` of the image."""
    mask = _blob_mask(rng, *img.shape[:2], fraction, int(rng.integers(1, 4)))
    if not mask.any():
        return mask
    colour = _STAINS[int(rng.integers(len(_STAINS)))]
    inner = 0.85 + 0.15 * smooth_noise(rng, *img.shape[:2], 4, 6)
    alpha = mask * np.clip(rng.uniform(0.7, 0.95) * inner, 0, 1)
    blend(img, alpha, colour)
    return alpha


def dust(img: np.ndarray, rng: Rng, fraction: float) -> np.ndarray:
    """Light, grainy dust (cement, flour, sawdust) over ``fraction`` of the image."""
    h, w = img.shape[:2]
    mask = _blob_mask(rng, h, w, fraction, int(rng.integers(1, 4)))
    if not mask.any():
        return mask
    grey = float(rng.uniform(170, 215))
    colour = (grey * rng.uniform(0.9, 1.0), grey, grey * rng.uniform(1.0, 1.06))
    grain = np.clip(0.75 + 0.35 * rng.standard_normal((h, w), dtype=np.float32), 0.3, 1.0)
    alpha = mask * rng.uniform(0.5, 0.8) * grain
    blend(img, alpha, colour)
    return alpha


def scratches(img: np.ndarray, rng: Rng, n: int) -> np.ndarray:
    """``n`` new scratches: thin lines of lighter (fresh) or darker wood."""
    h, w = img.shape[:2]
    mask = np.zeros((h, w), np.float32)
    for _ in range(n):
        x0, y0 = rng.uniform(0, w), rng.uniform(0, h)
        length = rng.uniform(0.2, 0.6) * w
        a = rng.uniform(-0.6, 0.6) if rng.random() < 0.7 else rng.uniform(0, np.pi)
        x1, y1 = x0 + length * np.cos(a), y0 + length * np.sin(a)
        line = np.zeros((h, w), np.float32)
        thick = max(1, int(round(h / 80 * rng.uniform(0.8, 2.0))))
        cv2.line(line, (int(x0), int(y0)), (int(x1), int(y1)), 1.0, thick, cv2.LINE_AA)
        tone = img.reshape(-1, 3).mean(0) * (rng.uniform(1.25, 1.5) if rng.random() < 0.7 else 0.5)
        blend(img, line * 0.8, tuple(float(v) for v in np.clip(tone, 0, 255)))
        mask = np.maximum(mask, line * 0.5)
    return mask


def chips(img: np.ndarray, rng: Rng, n: int) -> np.ndarray:
    """``n`` chipped edges or corners: wood broken off, the gap showing dark or fresh wood."""
    h, w = img.shape[:2]
    mask = np.zeros((h, w), np.float32)
    for _ in range(n):
        edge = int(rng.integers(4))
        t = rng.uniform(0, 1)
        cx, cy = [(t * w, 0), (t * w, h - 1), (0, t * h), (w - 1, t * h)][edge]
        r = rng.uniform(0.05, 0.14) * min(h, w) * 2
        angles = np.sort(rng.uniform(0, 2 * np.pi, 7))
        pts = np.stack(
            [
                cx + r * rng.uniform(0.4, 1.0, 7) * np.cos(angles),
                cy + r * rng.uniform(0.4, 1.0, 7) * np.sin(angles),
            ],
            1,
        )
        chip = np.zeros((h, w), np.float32)
        cv2.fillPoly(chip, [pts.astype(np.int32)], 1.0, cv2.LINE_AA)
        shade = rng.uniform(25, 60) if rng.random() < 0.6 else rng.uniform(170, 215)
        blend(img, chip, (shade, shade * 1.08, shade * 1.18))
        mask = np.maximum(mask, chip)
    return mask


def new_stamp(img: np.ndarray, rng: Rng) -> np.ndarray:
    """A new ink stamp (a code or a mark in a box) somewhere on the image."""
    from perception.synth.marks import ink_text

    h, w = img.shape[:2]
    text = ("HT", "KD", "MB", "DB", "OK", "RE", "A1", "Q")[int(rng.integers(8))]
    text += f" {int(rng.integers(0, 99)):02d}"
    centre = (w * rng.uniform(0.25, 0.75), h * rng.uniform(0.25, 0.75))
    return ink_text(img, rng, text, centre, h * rng.uniform(0.16, 0.3), boxed=rng.random() < 0.5)


def moisture(img: np.ndarray, rng: Rng, amount: float) -> np.ndarray:
    """Darker, more saturated wood where water soaked in (from the bottom, or in patches)."""
    h, w = img.shape[:2]
    if amount <= 0:
        return np.zeros((h, w), np.float32)
    rise = np.clip(np.linspace(-0.5, 1.2, h, dtype=np.float32), 0, 1)[:, None] ** 1.5
    patches = np.clip(0.5 + 0.6 * smooth_noise(rng, h, w, 3, 5), 0, 1)
    wet = np.clip(amount * (0.6 * rise + 0.6 * patches), 0, 1)[..., None]
    mean = img.mean(axis=2, keepdims=True)
    img += (img - mean) * 0.35 * wet
    img *= 1.0 - 0.5 * wet
    return np.zeros((h, w), np.float32)  # the face is darker, not hidden


def occlude(img: np.ndarray, rng: Rng, fraction: float, occluder: str) -> np.ndarray:
    """Hide ``fraction`` of the image behind an ``occluder`` (see :data:`OCCLUDERS`)."""
    h, w = img.shape[:2]
    mask = np.zeros((h, w), np.float32)
    if fraction <= 0:
        return mask
    if occluder == "strap":  # a band across, upright or along, hiding `fraction` of the area
        upright = rng.random() < 0.6
        size = (w if upright else h) * fraction
        start = rng.uniform(0, (w if upright else h) - size)
        a, b = int(round(start)), int(round(start + size))
        if upright:
            mask[:, a:b] = 1.0
        else:
            mask[a:b, :] = 1.0
        colour = _STRAPS[int(rng.integers(len(_STRAPS)))]
        ridges = 1.0 + 0.08 * np.sin((np.arange(h)[:, None] + np.arange(w)[None, :]) * 0.9)
        strap = np.asarray(colour, np.float32)[None, None, :] * ridges[..., None]
        img[:] = img * (1 - mask[..., None]) + strap * mask[..., None]
        return mask
    if occluder == "film":  # stretch film over the top: translucent, glossy streaks
        rows = int(round(h * fraction))
        mask[:rows] = 1.0
        streaks = np.clip(0.5 + 0.5 * smooth_noise(rng, h, w, 2, max(4, w // 6)), 0, 1)
        alpha = mask * (0.7 + 0.25 * streaks)
        blend(img, alpha, (215.0, 212.0, 205.0))
        return mask
    if occluder == "overhang":  # a load standing over the edge: its front hides the top
        rows = int(round(h * fraction))
        mask[:rows] = 1.0
        tone = rng.uniform(30, 150)
        colour = (tone * 0.75, tone * 0.9, tone) if rng.random() < 0.6 else (tone,) * 3
        shade = np.linspace(1.1, 0.8, max(rows, 1), dtype=np.float32)[:, None, None]
        img[:rows] = np.asarray(colour, np.float32)[None, None, :] * shade
        return mask
    # any shape: an ellipse or polygon of random colour and texture, about `fraction` big
    for _ in range(8):
        shape = np.zeros((h, w), np.float32)
        r = np.sqrt(fraction * h * w / np.pi) * rng.uniform(0.9, 1.2)
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        cv2.ellipse(
            shape,
            (int(cx), int(cy)),
            (int(r * rng.uniform(0.7, 1.4)), int(r)),
            rng.uniform(0, 180),
            0,
            360,
            1.0,
            -1,
        )
        if abs(shape.mean() - fraction) < 0.35 * fraction + 0.02:
            break
    colour = rng.uniform(0, 255, 3)
    texture = 1.0 + rng.uniform(0, 0.3) * smooth_noise(rng, h, w, 4, 6)
    img[:] = (
        img * (1 - shape[..., None])
        + (colour[None, None, :] * texture[..., None]) * shape[..., None]
    )
    return shape


def age_image(img: np.ndarray, rng: Rng, ageing: Ageing) -> np.ndarray:
    """Apply ``ageing`` to a float32 BGR image in place; return the hidden fraction per pixel
    (0..1: stains, dust, chips and occluders; moisture and scratches hide nothing).

    Each change draws from its own generator (seeded from ``rng``), so a face aged a little
    more (more stains, a new scratch) keeps what it had: its stains grow where they were.
    """
    h, w = img.shape[:2]
    hidden = np.zeros((h, w), np.float32)
    seeds = rng.integers(0, 2**31, size=7)
    op = [np.random.default_rng(int(s)) for s in seeds]
    if ageing.moisture:
        moisture(img, op[0], ageing.moisture)
    if ageing.new_stamp:
        new_stamp(img, op[1])
    if ageing.scratches:
        scratches(img, op[2], ageing.scratches)
    if ageing.chips:
        hidden = np.maximum(hidden, chips(img, op[3], ageing.chips))
    if ageing.dust:
        hidden = np.maximum(hidden, dust(img, op[4], ageing.dust))
    if ageing.stains:
        hidden = np.maximum(hidden, stains(img, op[5], ageing.stains))
    if ageing.occlusion:
        hidden = np.maximum(hidden, occlude(img, op[6], ageing.occlusion, ageing.occluder))
    np.clip(img, 0, 255, out=img)
    return hidden


def progressive(step: int, steps: int = 10, seed: int = 0) -> Ageing:
    """Step ``step`` (1..``steps``) of a pallet ageing slowly between scans: at the last
    step 16 % stains, 12 % dust, 3 scratches, 2 chips, a new stamp (from 60 %), stamps 70 %
    faded, moisture 0.4; each step keeps what the previous one had and adds to it."""
    f = float(np.clip(step / steps, 0.0, 1.0))
    return Ageing(
        seed=seed,
        stains=0.16 * f,
        dust=0.12 * f,
        scratches=int(3 * f),
        chips=int(2 * f),
        new_stamp=f >= 0.6,
        fade_stamps=0.7 * f,
        moisture=0.4 * f,
    )


def random_ageing(rng: Rng, strength: float = 1.0) -> Ageing:
    """A random ageing for training: any mix of the changes, up to ``strength`` x (25 %
    stains, 25 % dust, 4 scratches, 3 chips, 45 % occlusion)."""
    s = strength

    def maybe(p: float, hi: float) -> float:
        return float(rng.uniform(0, hi * s)) if rng.random() < p else 0.0

    return Ageing(
        seed=int(rng.integers(1 << 30)),
        stains=maybe(0.35, 0.25),
        dust=maybe(0.25, 0.25),
        scratches=int(rng.integers(0, int(4 * s) + 1)) if rng.random() < 0.3 else 0,
        chips=int(rng.integers(0, int(3 * s) + 1)) if rng.random() < 0.3 else 0,
        new_stamp=bool(rng.random() < 0.15 * s),
        fade_stamps=maybe(0.2, 1.0),
        moisture=maybe(0.2, 0.8),
        occlusion=maybe(0.35, 0.45),
        occluder=str(rng.choice(OCCLUDERS)),
    )


__all__ = [
    "OCCLUDERS",
    "Ageing",
    "age_image",
    "chips",
    "dust",
    "moisture",
    "new_stamp",
    "occlude",
    "progressive",
    "random_ageing",
    "scratches",
    "stains",
]
