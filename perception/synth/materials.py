"""Surface textures of the non-pallet things the camera sees: stand boxes and rack steel.

:data:`MATERIALS` maps a material name (a world box's ``material``) to a function making its
texture (BGR uint8, read-only, deterministic). Rack steel is painted: blue uprights and
orange beams, the most common pallet-rack colours, with scuffs and bolt holes so the
detector meets real clutter beside the pallets.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from functools import partial

import numpy as np

from perception.synth.appearance import stand_texture
from perception.synth.woodgen import smooth_noise

#: paint colours (B, G, R) of rack steel
STEEL_BLUE = (150.0, 85.0, 30.0)
STEEL_ORANGE = (25.0, 110.0, 215.0)


def steel_texture(
    colour: tuple[float, float, float], w_px: int = 240, h_px: int = 60
) -> np.ndarray:
    """Painted rack steel of ``colour`` (BGR): a faint brushed grain, scuffs, a row of
    punched holes (uprights and beams both have them)."""
    rng = np.random.default_rng(zlib.crc32(repr(colour).encode()))
    lum = 1.0 + 0.05 * smooth_noise(rng, h_px, w_px, 3, 12)  # paint unevenness
    lum += 0.03 * np.linspace(-1.0, 1.0, h_px, dtype=np.float32)[:, None]  # rounded edge
    lum += 0.02 * rng.standard_normal((h_px, w_px), dtype=np.float32)
    img = lum[..., None] * np.asarray(colour, np.float32)[None, None, :]
    scuffs = rng.random((h_px, w_px)) < 0.004
    img[scuffs] = img[scuffs] * 0.55 + 60.0
    step = max(w_px // 16, 4)
    r = max(h_px // 12, 1)
    for x in range(step // 2, w_px, step):
        img[h_px // 2 - r : h_px // 2 + r + 1, x - r : x + r + 1] *= 0.25
    out = np.clip(img, 0, 255).astype(np.uint8)
    out.setflags(write=False)
    return out


MATERIALS: dict[str, Callable[[], np.ndarray]] = {
    "stand": stand_texture,
    "steel_blue": partial(steel_texture, STEEL_BLUE),
    "steel_orange": partial(steel_texture, STEEL_ORANGE),
    "steel_yellow": partial(steel_texture, (30.0, 190.0, 225.0)),
    "steel_green": partial(steel_texture, (60.0, 120.0, 40.0)),
    "steel_grey": partial(steel_texture, (120.0, 118.0, 112.0)),
    "steel_red": partial(steel_texture, (40.0, 40.0, 170.0)),
}
