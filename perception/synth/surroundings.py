"""Surroundings of the pallets for the synthetic camera: floor, walls, stand boxes; mip maps.

Pure, cached functions (BGR uint8, read-only); :mod:`perception.synth.appearance` re-exports
them.
"""

from __future__ import annotations

import zlib
from functools import lru_cache

import cv2
import numpy as np

from perception.synth.woodgen import concrete, smooth_noise


@lru_cache(maxsize=8)
def floor_texture(w_px: int = 800, h_px: int = 600, joint_px: int = 200) -> np.ndarray:
    """Concrete floor (BGR uint8), row 0 at the floor's smallest x, column 0 at its largest y."""
    img = concrete(np.random.default_rng(zlib.crc32(b"btrun-floor")), h_px, w_px, joint_px=joint_px)
    out = img.astype(np.uint8)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=8)
def wall_texture(w_px: int = 800, h_px: int = 200) -> np.ndarray:
    """Warehouse wall (BGR uint8, row 0 at the top): painted block work, a dark base band."""
    rng = np.random.default_rng(zlib.crc32(b"btrun-wall"))
    lum = 0.82 + 0.02 * smooth_noise(rng, h_px, w_px, 4, 16)
    lum += 0.012 * rng.standard_normal((h_px, w_px), dtype=np.float32)
    img = np.stack([lum * 200.0, lum * 204.0, lum * 206.0], axis=-1)
    course = max(h_px // 20, 2)
    img[::course] *= 0.8  # mortar joints of the block work
    for r in range(0, h_px, course):
        off = (r // course % 2) * course
        img[r : r + course, off :: course * 2] *= 0.8
    for x in range(w_px // 10, w_px, w_px // 5):  # steel columns
        img[:, x : x + 3] = (120, 110, 60)
    band = int(h_px * 0.75)
    img[band:] = img[band:] * np.array([0.55, 0.45, 0.35], np.float32)  # dark base band
    img[band : band + 2] = (20, 170, 220)  # yellow line
    out = np.clip(img, 0, 255).astype(np.uint8)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=8)
def stand_texture(w_px: int = 300, h_px: int = 100) -> np.ndarray:
    """Front of the stand box under a raised pallet: a dark grey plastic crate with ribs."""
    rng = np.random.default_rng(zlib.crc32(b"btrun-stand"))
    img = concrete(rng, h_px, w_px) * np.array([0.55, 0.52, 0.5], np.float32)
    img[:, :: max(w_px // 24, 2)] *= 0.7
    img[:: max(h_px // 6, 2)] *= 0.75
    out = np.clip(img, 0, 255).astype(np.uint8)
    out.setflags(write=False)
    return out


def pyramid(tex: np.ndarray, levels: int = 6) -> list[np.ndarray]:
    """Mip levels of a texture (level k = ``tex`` reduced 2^k times) for minified drawing."""
    out = [np.ascontiguousarray(tex)]
    while len(out) < levels and min(out[-1].shape[:2]) >= 4:
        out.append(cv2.pyrDown(out[-1]))
    return out
