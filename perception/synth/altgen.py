"""Other block-face generators than the project's wood model (:mod:`perception.synth.woodgen`).

A detector or embedder trained on one generator's wood learns that generator's quirks. These
families draw block faces in other ways, each as luminance (0..1) that
:func:`perception.synth.woodgen.colourise` turns into the side's colours:

* :func:`flake`: oriented strand board: large, sharp-edged, overlapping flakes;
* :func:`noise`: anisotropic multi-octave noise (any fibrous or mottled material);
* :func:`pattern`: random shapes, bars and glyphs on a mottled ground (pure domain
  randomisation: nothing wood-like);
* :func:`plank`: another wood model (sinusoidal rings over fractal turbulence, or end grain
  with its pith, radial checks and saw marks). **Held out of training**: the robustness bench
  uses it to test faces from "another generator".

All take a ``numpy.random.Generator`` and return float32 (h, w) arrays.
"""

from __future__ import annotations

import cv2
import numpy as np

from perception.synth.woodgen import smooth_noise

Rng = np.random.Generator


def _fbm(rng: Rng, h: int, w: int, octaves: int, cells: tuple[int, int]) -> np.ndarray:
    """Fractal noise: ``octaves`` of :func:`smooth_noise`, each twice as fine, half as strong."""
    out = np.zeros((h, w), np.float32)
    cy, cx = cells
    amp = 1.0
    for _ in range(octaves):
        out += amp * smooth_noise(rng, h, w, cy, cx)
        cy, cx, amp = cy * 2, cx * 2, amp * 0.5
    return out


def flake(rng: Rng, h: int, w: int) -> np.ndarray:
    """Oriented strand board: big polygonal flakes with hard edges, mostly along one axis."""
    lum = np.full((h, w), float(rng.uniform(0.55, 0.75)), np.float32)
    angle = rng.uniform(0, 180)
    for _ in range(int(h * w / rng.uniform(150, 400))):
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        ax, ay = rng.uniform(8, 30), rng.uniform(2, 7)
        pts = cv2.ellipse2Poly(
            (int(cx), int(cy)), (int(ax), int(ay)), int(angle + rng.normal(0, 20)), 0, 360, 45
        )
        pts = pts + rng.integers(-2, 3, pts.shape)
        cv2.fillPoly(lum, [pts.astype(np.int32)], float(np.clip(rng.normal(0.65, 0.12), 0.2, 1.0)))
    lum += 0.025 * rng.standard_normal((h, w), dtype=np.float32)
    return np.clip(lum, 0.0, 1.0)


def noise(rng: Rng, h: int, w: int) -> np.ndarray:
    """Anisotropic fractal noise: fibres or mottles at a random scale and direction."""
    stretch = rng.uniform(1.0, 8.0)
    big = max(h, w) * 2
    base = _fbm(rng, big, big, 4, (max(2, int(big / 40 / stretch)), max(2, int(big / 40))))
    m = cv2.getRotationMatrix2D((big / 2, big / 2), rng.uniform(0, 180), 1.0)
    base = cv2.warpAffine(base, m, (big, big), borderMode=cv2.BORDER_REFLECT)
    y0, x0 = (big - h) // 2, (big - w) // 2
    lum = base[y0 : y0 + h, x0 : x0 + w]
    lum = 0.65 + rng.uniform(0.06, 0.16) * lum / (lum.std() + 1e-6)
    return np.clip(lum, 0.0, 1.0).astype(np.float32)


def pattern(rng: Rng, h: int, w: int) -> np.ndarray:
    """Random rectangles, discs, bars and glyphs of random tones on a mottled ground."""
    lum = 0.6 + 0.08 * _fbm(rng, h, w, 3, (3, 4))
    for _ in range(int(rng.integers(4, 14))):
        tone = float(rng.uniform(0.15, 1.0))
        kind = rng.integers(4)
        x, y = int(rng.uniform(0, w)), int(rng.uniform(0, h))
        s = int(rng.uniform(4, max(6, h / 2)))
        if kind == 0:
            cv2.rectangle(lum, (x, y), (x + s, y + int(s * rng.uniform(0.3, 1.5))), tone, -1)
        elif kind == 1:
            cv2.circle(lum, (x, y), s // 2, tone, int(rng.choice([-1, 2, 3])), cv2.LINE_AA)
        elif kind == 2:
            x2, y2 = int(rng.uniform(0, w)), int(rng.uniform(0, h))
            cv2.line(lum, (x, y), (x2, y2), tone, int(rng.integers(1, 6)), cv2.LINE_AA)
        else:
            letters = list("ABCDEFGHKMNPRSTUVWXZ0123456789")
            glyph = "".join(rng.choice(letters, int(rng.integers(1, 4))))
            mask = np.zeros((h, w), np.uint8)  # putText draws on 8-bit images only
            cv2.putText(mask, glyph, (x, y), int(rng.integers(0, 8)), s / 22.0, 255, 2, cv2.LINE_AA)
            a = mask.astype(np.float32) / 255.0
            lum = lum * (1 - a) + tone * a
    lum += 0.02 * rng.standard_normal((h, w), dtype=np.float32)
    return np.clip(lum, 0.0, 1.0).astype(np.float32)


def plank(rng: Rng, h: int, w: int) -> np.ndarray:
    """Another wood model (held out of training): side grain as sinusoidal rings over fractal
    turbulence, or end grain around a pith with radial checks; saw marks across."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    turb = _fbm(rng, h, w, 4, (2, max(2, w // 50)))
    if rng.random() < 0.5:
        freq = rng.uniform(0.25, 0.7)
        phase = yy * freq + rng.uniform(4, 12) * turb + rng.uniform(0, 6.28)
        lum = 0.7 + 0.12 * np.sin(phase) ** 3 + 0.05 * np.sin(phase * 3.1)
    else:
        px, py = rng.uniform(-0.3, 1.3) * w, rng.uniform(-0.2, 1.2) * h
        r = np.hypot(xx - px, yy - py) + rng.uniform(2, 6) * turb
        lum = 0.68 + 0.14 * np.cos(r * rng.uniform(0.6, 1.4)) ** 5
        ang = np.arctan2(yy - py, xx - px)
        for a in rng.uniform(-np.pi, np.pi, int(rng.integers(1, 4))):
            crack = np.exp(-(((np.angle(np.exp(1j * (ang - a)))) * r / 1.5) ** 2))
            lum -= 0.35 * crack * (r > rng.uniform(3, 15))
    period = rng.uniform(5, 14)
    lum += 0.04 * np.sin(2 * np.pi * (xx * rng.uniform(0.9, 1.1) + yy * 0.2) / period)
    lum += 0.04 * rng.standard_normal((h, w), dtype=np.float32)
    return np.clip(cv2.GaussianBlur(lum.astype(np.float32), (3, 3), 0.7), 0.0, 1.0)


GENERATORS = {"flake": flake, "noise": noise, "pattern": pattern, "plank": plank}


def face_luminance(generator: str, rng: Rng, h: int, w: int) -> np.ndarray:
    """Luminance of a block face drawn by ``generator`` (a key of :data:`GENERATORS`).

    Raises:
        ValueError: an unknown generator name.
    """
    if generator not in GENERATORS:
        raise ValueError(f"unknown face generator {generator!r} (known: {', '.join(GENERATORS)})")
    return GENERATORS[generator](rng, h, w)


__all__ = ["GENERATORS", "face_luminance", "flake", "noise", "pattern", "plank"]
