"""Training data of the block detector: rendered frames, augmentation, per-cell targets.

:func:`render_set` renders white-balanced frames of many synthetic pallet sides. With
``variety`` every pallet gets a random look over the whole range of real pallets (wood from
bleached grey to wet and dark, painted blocks, other face generators, marking styles:
:func:`perception.synth.looks.random_look`), half of them an ageing (stains, dust,
occluders: :func:`perception.synth.ageing.random_ageing`), and every frame random light,
optics and sensor conditions including the AI-deck's Bayer JPEG
(:func:`perception.synth.views.random_conditions`).

:func:`augment` adds geometry (flip, scale, shift), and :func:`colour_augment` colour
changes no renderer draws: any hue, saturation from none to strong, greyscale, swapped
channels, gamma, noise, blur, and random occluders of random shapes and colours. A block
must be found by its shape and place (a face under the deck board between two dark fork
openings), not by "this yellow-brown".
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from perception.detector import DetectorConfig
from perception.synth.ageing import random_ageing
from perception.synth.appearance import SideStyle, split_identity
from perception.synth.dataset import _wb_factors, render_detection_sample
from perception.synth.looks import hsv_to_bgr, random_look
from perception.synth.render import SensorModel
from perception.synth.views import ViewConditions, develop, random_conditions

Log = Callable[[str], None]
#: ground-truth blocks less visible than this are "don't care"
MIN_VISIBLE = 0.5
#: ground-truth blocks narrower than this (frame pixels) are "don't care"
MIN_WIDTH_PX = 4.0


@dataclass
class FrameSet:
    """Frames at the network input size and their boxes in frame pixels.

    ``images``: uint8 (N, h, w, 3); ``full``: the frames at full size (evaluation only, else
    None); ``boxes[i]``: float32 (k, 5) rows x1, y1, x2, y2, visible.
    """

    images: np.ndarray
    boxes: list[np.ndarray]
    full: list[np.ndarray] | None = None


def varied_style(
    name: str, seed: int, ageing_probability: float = 0.5, dark_paint: float = 0.0
) -> SideStyle:
    """A random look (and, with ``ageing_probability``, an ageing) for identity ``name``,
    deterministic in the pallet id and ``seed`` (both sides of a pallet share the look).

    ``dark_paint``: the share of pallets repainted black or another very dark colour
    (:func:`dark_paint_colour`), on top of the few that :func:`random_look` paints dark: a
    dark block between dark fork openings stands out by its shading only, the hardest
    look for the detector (black paint was its one colour below 99 % in bench/robustness.py).
    """
    pallet_id, side = split_identity(name)
    look = random_look(np.random.default_rng([seed, *pallet_id.encode()]))
    dark = np.random.default_rng([seed, *pallet_id.encode(), 11])
    if dark.random() < dark_paint:
        look["paint"] = dark_paint_colour(dark)
        look["paint_parts"] = "blocks" if dark.random() < 0.35 else "all"
    rng = np.random.default_rng([seed, *name.encode(), 7])
    ageing = random_ageing(rng) if rng.random() < ageing_probability else None
    return SideStyle(**look, ageing=ageing)


def dark_paint_colour(rng: np.random.Generator) -> tuple[float, float, float]:
    """A black or very dark paint (BGR): mostly near-neutral (black, charcoal), else any
    hue (dark blue, red, green), value 0.06 .. 0.3."""
    neutral = rng.random() < 0.6
    saturation = rng.uniform(0.0, 0.15) if neutral else rng.uniform(0.2, 0.8)
    bgr = hsv_to_bgr(rng.uniform(0, 360), saturation, rng.uniform(0.06, 0.3))
    return (round(bgr[0], 1), round(bgr[1], 1), round(bgr[2], 1))


def render_set(
    names: list[str],
    n: int,
    seed: int,
    config: DetectorConfig,
    *,
    wide_fraction: float = 0.0,
    keep_full: bool = False,
    variety: bool = False,
    distance_m: tuple[float, float] = (0.25, 0.8),
    yaw_deg: float = 15.0,
    rack_fraction: float = 0.0,
    dark_paint: float = 0.0,
    aim_fraction: float = 0.0,
    log: Log | None = None,
) -> FrameSet:
    """``n`` white-balanced renders, consecutive frames per identity (scene cache hits),
    deterministic in ``seed`` and ``names``. ``variety``: random looks, ageings and view
    conditions (see the module doc); ``rack_fraction``: the share of frames with the pallet
    on a rack beam among rack steel and neighbour pallets; ``dark_paint``: see
    :func:`varied_style`; ``aim_fraction``: the share of frames aimed at one block as the
    scan's views are (``aim_probability`` of
    :func:`perception.synth.dataset.render_detection_sample`)."""
    rng = np.random.default_rng(seed)
    factors = _wb_factors(SensorModel())
    h, w = config.input_hw
    images = np.empty((n, h, w, 3), np.uint8)
    boxes: list[np.ndarray] = []
    full: list[np.ndarray] = []
    per_id = max(1, math.ceil(n / len(names)))
    t0 = time.perf_counter()
    styles: dict[str, SideStyle] = {}
    for i in range(n):
        name = names[(i // per_id) % len(names)]
        lateral = 1.4 if rng.random() < wide_fraction else 0.7
        cond = None
        if variety:
            if name not in styles:  # one style at a time: bounded memory
                styles = {name: varied_style(name, seed, dark_paint=dark_paint)}
            cond = random_conditions(rng)
        raw, bb = render_detection_sample(
            rng,
            [name],
            styles=styles or None,
            lateral_m=lateral,
            distance_m=distance_m,
            yaw_deg=yaw_deg,
            conditions=cond,
            rack_probability=rack_fraction,
            aim_probability=aim_fraction,
        )
        bgr = develop(raw, factors, cond or ViewConditions())
        images[i] = cv2.resize(bgr, (w, h), interpolation=cv2.INTER_AREA)
        if keep_full:
            full.append(bgr)
        rows = [(b.x1, b.y1, b.x2, b.y2, b.visible) for b in bb]
        boxes.append(np.asarray(rows, np.float32).reshape(-1, 5))
        if log and ((i + 1) % 1000 == 0 or i + 1 == n):
            log(f"  rendered {i + 1}/{n} frames ({time.perf_counter() - t0:.0f} s)")
    return FrameSet(images, boxes, full if keep_full else None)


def augment(
    img: np.ndarray, boxes: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Random horizontal flip, scale (0.85..1.15) and shift (+-8 %) of an input-size image;
    boxes (input pixels, with visible) follow, clipped, their visible fraction reduced."""
    h, w = img.shape[:2]
    b = boxes.copy()
    if rng.random() < 0.5:
        img = img[:, ::-1]
        b[:, [0, 2]] = w - b[:, [2, 0]]
    s = rng.uniform(0.85, 1.15)
    tx = rng.uniform(-0.08, 0.08) * w + (1 - s) * w / 2
    ty = rng.uniform(-0.08, 0.08) * h + (1 - s) * h / 2
    m = np.array([[s, 0, tx], [0, s, ty]], np.float32)
    fill = tuple(float(v) for v in img.reshape(-1, 3).mean(0))
    img = cv2.warpAffine(
        np.ascontiguousarray(img), m, (w, h), flags=cv2.INTER_LINEAR, borderValue=fill
    )
    if len(b):
        b[:, [0, 2]] = b[:, [0, 2]] * s + tx
        b[:, [1, 3]] = b[:, [1, 3]] * s + ty
        area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
        b[:, 0:4:2] = b[:, 0:4:2].clip(0, w)
        b[:, 1:4:2] = b[:, 1:4:2].clip(0, h)
        clipped = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
        b[:, 4] *= np.where(area > 0, clipped / np.maximum(area, 1e-6), 0.0)
    return img, b


def colour_augment(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Colour and texture changes of a BGR uint8 image (see the module doc)."""
    out = np.ascontiguousarray(img)
    if rng.random() < 0.6:
        hsv = cv2.cvtColor(out, cv2.COLOR_BGR2HSV).astype(np.float32)
        if rng.random() < 0.6:
            hsv[..., 0] = (hsv[..., 0] + rng.uniform(0, 180)) % 180
        hsv[..., 1] *= rng.uniform(0.0, 1.6)
        out = cv2.cvtColor(np.clip(hsv, 0, 255).astype(np.uint8), cv2.COLOR_HSV2BGR)
    if rng.random() < 0.15:
        out = cv2.cvtColor(cv2.cvtColor(out, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR)
    if rng.random() < 0.15:
        out = np.ascontiguousarray(out[..., rng.permutation(3)])
    f = out.astype(np.float32)
    if rng.random() < 0.5:
        f = 255.0 * (f / 255.0) ** rng.uniform(0.6, 1.6)
        f = (f - 128.0) * rng.uniform(0.7, 1.3) + 128.0 + rng.uniform(-25, 25)
    if rng.random() < 0.3:
        _occluders(f, rng)
    if rng.random() < 0.15:
        f = cv2.GaussianBlur(f, (0, 0), rng.uniform(0.5, 1.3))
    if rng.random() < 0.3:
        f += rng.normal(0.0, rng.uniform(2, 12), f.shape).astype(np.float32)
    return np.clip(f, 0, 255).astype(np.uint8)


def _occluders(f: np.ndarray, rng: np.random.Generator) -> None:
    """1-3 random shapes (band, rectangle, ellipse) of a random colour or noise, in place."""
    h, w = f.shape[:2]
    for _ in range(int(rng.integers(1, 4))):
        mask = np.zeros((h, w), np.uint8)
        kind = rng.integers(3)
        x, y = int(rng.uniform(0, w)), int(rng.uniform(0, h))
        sw, sh = int(rng.uniform(0.03, 0.2) * w), int(rng.uniform(0.03, 0.25) * h)
        if kind == 0:  # a strap: a long thin band
            if rng.random() < 0.5:
                mask[:, x : x + max(2, sw // 3)] = 1
            else:
                mask[y : y + max(2, sh // 3), :] = 1
        elif kind == 1:
            mask[y : y + sh, x : x + sw] = 1
        else:
            cv2.ellipse(mask, (x, y), (sw, sh), rng.uniform(0, 180), 0, 360, 1, -1)
        m = mask.astype(bool)
        if rng.random() < 0.5:
            f[m] = rng.uniform(0, 255, 3)
        else:
            f[m] = rng.uniform(0, 255) + rng.normal(0, 30, (int(m.sum()), 3))


def build_targets(
    boxes: list[np.ndarray], config: DetectorConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-cell training targets for a batch; boxes in input pixels (x1, y1, x2, y2, vis).

    A cared-for block makes positive the cells whose centres lie within ``r`` cells of its
    centre on each axis (``r`` 0.5..1.25 cells, growing with its size; the closest block
    wins a shared cell). The same region around a "don't care" block is ignored.

    Returns:
        obj (N, cells) float 0/1, weight (N, cells) float 0 (ignored) / 1, and target boxes
        (N, cells, 4) x1, y1, x2, y2 in input pixels (valid where obj is 1).
    """
    gh, gw = config.grid_hw
    st = config.stride
    n = len(boxes)
    obj = np.zeros((n, gh, gw), np.float32)
    weight = np.ones((n, gh, gw), np.float32)
    tbox = np.zeros((n, gh, gw, 4), np.float32)
    dist = np.full((n, gh, gw), np.inf, np.float32)
    ccx = (np.arange(gw, dtype=np.float32) + 0.5) * st
    ccy = (np.arange(gh, dtype=np.float32) + 0.5) * st
    scale = config.input_hw[1] / config.frame_hw[1]
    for i, bb in enumerate(boxes):
        for x1, y1, x2, y2, vis in bb:
            bw, bh = x2 - x1, y2 - y1
            if bw <= 0 or bh <= 0:
                continue
            cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
            rx = float(np.clip(0.25 * bw / st, 0.5, 1.25))
            ry = float(np.clip(0.25 * bh / st, 0.5, 1.25))
            dx = np.abs(ccx - cx) / st
            dy = np.abs(ccy - cy) / st
            region = (dy[:, None] < ry) & (dx[None, :] < rx)
            if not region.any():  # centre cell always
                gy, gx = min(int(cy // st), gh - 1), min(int(cx // st), gw - 1)
                region[gy, gx] = True
            care = vis >= MIN_VISIBLE and bw >= MIN_WIDTH_PX * scale
            if not care:
                weight[i][region & (obj[i] == 0)] = 0.0
                continue
            d = dy[:, None] ** 2 + dx[None, :] ** 2
            take = region & (d < dist[i])
            dist[i][take] = d[take]
            obj[i][take] = 1.0
            weight[i][take] = 1.0
            tbox[i][take] = (x1, y1, x2, y2)
    return obj.reshape(n, -1), weight.reshape(n, -1), tbox.reshape(n, -1, 4)


__all__ = [
    "MIN_VISIBLE",
    "MIN_WIDTH_PX",
    "FrameSet",
    "augment",
    "build_targets",
    "colour_augment",
    "dark_paint_colour",
    "render_set",
    "varied_style",
]
