"""Training and validation crops of the PCB embedder, and their augmentation.

:func:`render_crops` renders block crops of synthetic pallet sides as the mission cuts them
(:func:`perception.synth.dataset.block_crops`). With ``variety`` every pallet gets a random
look over the range of real pallets (:func:`perception.synth.looks.random_look`) and every
crop random light, optics and sensor conditions, the AI-deck's Bayer JPEG included
(:func:`perception.synth.views.random_conditions`), from 0.25 to 1.2 m and up to 30 deg
off square. :func:`augment` then makes each training view: ageing drawn on the crop
(stains, dust, straps, film, overhangs, scratches, chips, moisture:
:mod:`perception.synth.ageing`), the sensor again (noise, Bayer JPEG), colour and gain,
lower resolution, the crop's scale, shift and rotation, erased patches; and it returns the
hidden part of the view, which the visibility head learns.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import time
from collections.abc import Callable

import cv2
import numpy as np

from perception.synth.ageing import age_image, random_ageing
from perception.synth.appearance import SideStyle, split_identity
from perception.synth.dataset import block_crops, identity_names
from perception.synth.looks import random_look
from perception.synth.views import (
    ConditionRanges,
    ViewConditions,
    random_conditions,
    resensor_crop,
)

BLOCKS = 3
Log = Callable[[str], None]
#: how the crops of one identity are taken: the original renderer's range ("plain"), the
#: broad training range ("varied"), the clean enrolment views ("enrol")
MODES = ("plain", "varied", "enrol")


def split_names(kind: str, pallets: int) -> list[str]:
    """Both sides of ``pallets`` synthetic pallets of split ``kind`` (tr, va, vu, te, tu)."""
    return identity_names(2 * pallets, prefix=kind)


#: the embedder's view conditions: milder extremes than the detector's
EMBEDDER_RANGES = ConditionRanges(
    exposure=(0.6, 1.6),
    contrast=(0.75, 1.2),
    gradient=0.3,
    kelvin=(3000.0, 6500.0),
    motion=(0.33, 6.0),
    defocus=(0.2, 1.5),
    noise=(0.33, 20.0),
    jpeg=(0.3, 15),
    downscale=(0.1, 2.5),
)


def view_conditions(rng: np.random.Generator) -> ViewConditions:
    """Conditions of the embedder's crops: as broad as the detector's in kind but not in
    extremes (a crop nobody could re-identify teaches nothing): exposure 0.6..1.6,
    3000..6500 K, motion blur in a third, defocus up to 1.5 px in a fifth, noise up to
    20 DN in a third, Bayer JPEG q15..95 in 30 %, lower resolution in 10 %."""
    return random_conditions(rng, EMBEDDER_RANGES)


def look_of(name: str) -> SideStyle:
    """The random look of identity ``name``: a function of the pallet id alone (both sides
    of a pallet, and every render of it whatever the render seed, look alike)."""
    pallet_id, _ = split_identity(name)
    return SideStyle(**random_look(np.random.default_rng([17, *pallet_id.encode()])))


def _render_identity(job: tuple[str, int, int, str]) -> list[list[np.ndarray]]:
    name, n, seed, mode = job
    rng = np.random.default_rng([seed, *name.encode()])
    if mode == "plain":
        return [block_crops(name, None, b, rng, n) for b in range(BLOCKS)]
    style = look_of(name)
    if mode == "enrol":  # the scan stand-off, square, nominal camera
        view = {"distance_m": (0.36, 0.44), "yaw_deg": 4.0, "conditions": ViewConditions()}
    else:
        view = {"distance_m": (0.25, 1.2), "yaw_deg": 30.0, "conditions": view_conditions}
    return [
        block_crops(name, None, b, rng, n, style=style, occlusion_probability=0.0, **view)
        for b in range(BLOCKS)
    ]


def render_crops(
    names: list[str],
    per_block: int,
    seed: int,
    jobs: int = 1,
    log: Log | None = None,
    mode: str = "plain",
) -> list[list[list[np.ndarray]]]:
    """Crops ``[identity][block][k]`` (``per_block`` each), deterministic in ``seed`` and
    each name whatever ``jobs`` (worker processes) is; ``mode``: see :data:`MODES`."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}")
    work = [(n, per_block, seed, mode) for n in names]
    out: list[list[list[np.ndarray]]] = []
    t0 = time.perf_counter()
    pool = mp.get_context("fork").Pool(jobs) if jobs > 1 else None
    try:
        it = pool.imap(_render_identity, work, chunksize=4) if pool else map(_render_identity, work)
        for i, crops in enumerate(it, 1):
            out.append(crops)
            if log and (i % 100 == 0 or i == len(work)):
                log(
                    f"  rendered {i}/{len(work)} identities "
                    f"({i * BLOCKS * per_block} crops, {time.perf_counter() - t0:.0f} s)"
                )
    finally:
        if pool:
            pool.close()
            pool.join()
    return out


def age_crop(
    crop: np.ndarray, rng: np.random.Generator, strength: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """A crop aged at random (:func:`perception.synth.ageing.random_ageing`) and the hidden
    fraction of each of its pixels."""
    f = crop.astype(np.float32)
    hidden = age_image(f, rng, random_ageing(rng, strength))
    return np.clip(f, 0, 255).astype(np.uint8), hidden


def augment(
    crop: np.ndarray,
    rng: np.random.Generator,
    hw: tuple[int, int],
    ageing: float = 0.5,
    sensor: float = 0.4,
    colour: bool = True,
    strength: float = 0.8,
) -> tuple[np.ndarray, np.ndarray]:
    """One training view of a crop at ``hw`` and its hidden mask (same size, 0..1).

    In the order things happen to a real crop: ageing (probability ``ageing``, up to
    ``strength`` x the largest changes of :func:`perception.synth.ageing.random_ageing`),
    the sensor again (``sensor``: noise up to 20 DN, Bayer JPEG 15..95), colour and gain
    jitter (``colour``), a lower resolution, the crop's scale, shift and rotation, an
    erased patch.
    """
    hidden = np.zeros(crop.shape[:2], np.float32)
    if rng.random() < ageing:
        crop, hidden = age_crop(crop, rng, strength)
    if rng.random() < sensor:
        q = int(rng.integers(15, 96)) if rng.random() < 0.5 else 0
        crop = resensor_crop(crop, rng, float(rng.uniform(0, 20)), q)
    h, w = hw
    ch, cw = crop.shape[:2]
    sx, sy = w / cw * rng.uniform(0.9, 1.1), h / ch * rng.uniform(0.9, 1.1)
    ang = math.radians(rng.normal(0.0, 2.0))
    c, s = math.cos(ang), math.sin(ang)
    m = np.array([[sx * c, -sy * s, 0.0], [sx * s, sy * c, 0.0]], np.float32)
    centre = m[:, :2] @ np.array([cw / 2, ch / 2], np.float32)
    m[:, 2] = np.array([w / 2, h / 2]) - centre + rng.normal(0.0, 0.04, 2) * (w, h)
    out = cv2.warpAffine(crop, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    hid = cv2.warpAffine(hidden, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    f = out.astype(np.float32)
    if colour:
        f = _colour(f, rng)
    if rng.random() < 0.3:
        k = rng.uniform(0.3, 0.8)
        small = cv2.resize(
            f, (max(4, int(w * k)), max(4, int(h * k))), interpolation=cv2.INTER_AREA
        )
        f = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    if rng.random() < 0.25:
        eh, ew = int(h * rng.uniform(0.1, 0.4)), int(w * rng.uniform(0.1, 0.4))
        y, x = int(rng.integers(0, h - eh + 1)), int(rng.integers(0, w - ew + 1))
        f[y : y + eh, x : x + ew] = rng.uniform(0, 255, 3)
        hid[y : y + eh, x : x + ew] = 1.0
    f += rng.normal(0.0, rng.uniform(0.0, 3.0), f.shape).astype(np.float32)
    return np.clip(f, 0, 255).astype(np.uint8), np.clip(hid, 0, 1)


def _colour(f: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Gain, contrast, per-channel gain, a small hue turn, saturation, sometimes grey."""
    gain = rng.uniform(0.7, 1.35) * rng.normal(1.0, 0.06, 3)
    f = (f - 128.0) * rng.uniform(0.75, 1.25) + 128.0
    f = f * gain.astype(np.float32)
    if rng.random() < 0.4:
        hsv = cv2.cvtColor(np.clip(f, 0, 255).astype(np.uint8), cv2.COLOR_BGR2HSV).astype(
            np.float32
        )
        hsv[..., 0] = (hsv[..., 0] + rng.uniform(-8, 8)) % 180
        hsv[..., 1] *= rng.uniform(0.5, 1.4)
        f = cv2.cvtColor(np.clip(hsv, 0, 255).astype(np.uint8), cv2.COLOR_HSV2BGR).astype(
            np.float32
        )
    if rng.random() < 0.05:
        grey = f.mean(axis=2, keepdims=True)
        f = np.repeat(grey, 3, axis=2)
    return f


def stripe_visibility(hidden: np.ndarray, parts: int) -> np.ndarray:
    """Visible fraction (parts,) of each horizontal stripe of a hidden mask (h, w)."""
    h = hidden.shape[0]
    edges = np.linspace(0, h, parts + 1).round().astype(int)
    return np.array(
        [1.0 - float(hidden[a:b].mean()) for a, b in zip(edges[:-1], edges[1:], strict=True)],
        np.float32,
    )


__all__ = [
    "MODES",
    "age_crop",
    "augment",
    "look_of",
    "render_crops",
    "split_names",
    "stripe_visibility",
    "view_conditions",
]
