"""Training data from the synthetic camera: detector samples, re-identification crops, names.

- :func:`render_detection_sample`: a raw Bayer frame of one random pallet side from a random
  pose around the scan geometry, with its ground-truth block boxes (detector training).
- :func:`block_crops`: BGR crops of one support block as the mission would cut them from
  white-balanced frames, under varied pose, scale, blur, light and partial occlusion
  (re-identification training and evaluation).
- :func:`identity_names`: many synthetic identities ("p0001A", "p0001B", ...) beyond the
  world's ten, so an embedder can be trained on hundreds and evaluated on held-out ones.

Local scene: the pallet's shown face is centred at x = 0, y = 0 and looks towards -x, its
base on a stand of random height; the camera stands at x = -distance. Everything is
deterministic for a given ``numpy.random.Generator`` state.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache

import cv2
import numpy as np

from perception.synth.appearance import EPAL, SideStyle, split_identity
from perception.synth.camera_model import CameraModel, CameraPose
from perception.synth.render import BlockBox, Lighting, SensorModel, block_boxes, render_frame
from perception.synth.scene import PalletSpec, Scene, SceneLight
from perception.synth.views import ViewConditions, develop, take_frame
from perception.white_balance import calibrate, preprocess, render_white_target

Conditions = ViewConditions | Callable[[np.random.Generator], ViewConditions] | None

NOMINAL_K = 4000.0  # colour temperature the white balance is calibrated under
#: the lamps of the local scenes: one in front of the face and above it, one behind it
NOMINAL_LIGHT = SceneLight(0.6, (((-1.5, 0.0, 4.0), 1.0), ((0.5, 1.0, 4.0), 0.7)), NOMINAL_K)


def identity_names(n: int, prefix: str = "p", start: int = 1) -> list[str]:
    """``n`` synthetic identities, both sides of consecutive pallets: p0001A, p0001B, p0002A..."""
    return [f"{prefix}{start + i // 2:04d}{'AB'[i % 2]}" for i in range(n)]


def _stand_height(rng: np.random.Generator) -> float:
    """Base height of the pallet: on the floor or on a stand (0.05 m steps up to 0.3 m)."""
    return 0.0 if rng.random() < 0.3 else 0.05 * int(rng.integers(1, 7))


def _block_centre_z(base_z: float) -> float:
    return base_z + EPAL.board_m + EPAL.block_height_m / 2


@lru_cache(maxsize=64)
def _scene(
    pallet_id: str,
    side: str,
    style: SideStyle | None,
    base_z: float,
    light: SceneLight = NOMINAL_LIGHT,
) -> Scene:
    pallet = PalletSpec(
        pallet_id, side, 0.0, 0.0, base_z, math.pi, EPAL, (((side, style),) if style else ())
    )
    stand = ((0.4, 0.0, base_z / 2), (0.4, 0.6, base_z / 2), 0.0)
    return Scene.build(
        [pallet],
        boxes=[stand] if base_z > 0.01 else [],
        floor=((-6.0, -6.0), (12.0, 12.0), 0.0),
        light=light,
    )


#: rack layouts the training scenes draw from (a finite set, so racked scenes are cached too)
RACK_VARIANTS = 24


@lru_cache(maxsize=48)
def _rack_scene(
    pallet_id: str, side: str, style: SideStyle | None, base_z: float, variant: int
) -> Scene:
    """The pallet on a rack beam at ``base_z``: rack steel around it, neighbour pallets in
    wide bays and on the levels above and below (:mod:`perception.synth.rack_context`),
    each neighbour with a look of its own."""
    from perception.synth.looks import random_look
    from perception.synth.rack_context import neighbour_slots, rack_boxes, rack_variant

    light = NOMINAL_LIGHT
    v = rack_variant(np.random.default_rng([variant, 31]))
    pallets = [
        PalletSpec(
            pallet_id, side, 0.0, 0.0, base_z, math.pi, EPAL, (((side, style),) if style else ())
        )
    ]
    for k, (x, y, z, facing) in enumerate(neighbour_slots(v, base_z)):
        name = f"{pallet_id}n{variant}-{k}"
        look = SideStyle(**random_look(np.random.default_rng([variant, k, *name.encode()])))
        pallets.append(PalletSpec(name, "AB"[k % 2], x, y, z, facing, EPAL, (("AB"[k % 2], look),)))
    return Scene.build(
        pallets,
        boxes=rack_boxes(v, base_z),
        floor=((-6.0, -6.0), (12.0, 12.0), 0.0),
        light=light,
    )


def _random_light(rng: np.random.Generator) -> tuple[float, Lighting]:
    kelvin = float(rng.uniform(3000.0, 6000.0))
    lighting = Lighting(
        exposure=float(rng.uniform(0.7, 1.4)),
        contrast=float(rng.uniform(0.8, 1.2)),
        gradient=float(rng.uniform(0.0, 0.3)),
        gradient_angle_rad=float(rng.uniform(-math.pi, math.pi)),
        exposure_time_s=float(rng.uniform(0.01, 0.04)),
    )
    return kelvin, lighting


def render_detection_sample(
    rng: np.random.Generator,
    identities: list[str] | None = None,
    *,
    camera: CameraModel | None = None,
    styles: dict[str, SideStyle] | None = None,
    distance_m: tuple[float, float] = (0.25, 0.8),
    lateral_m: float = 0.7,
    yaw_deg: float = 15.0,
    height_m: float = 0.05,
    blur_probability: float = 0.3,
    conditions: ViewConditions | None = None,
    rack_probability: float = 0.0,
    aim_probability: float = 0.0,
) -> tuple[np.ndarray, list[BlockBox]]:
    """A raw Bayer frame and its ground-truth block boxes, everything randomised.

    Pallet identity from ``identities`` (default: 100 synthetic ones; ``styles`` maps
    identity -> :class:`SideStyle`), distance, lateral offset along the face, yaw, height
    around the block centre line, stand height, light, exposure, blur, noise.
    ``conditions``: take the frame under these instead (light, optics, sensor noise,
    Bayer JPEG; see :mod:`perception.synth.views`; develop it with
    :func:`perception.synth.views.develop` for the lower resolution).
    ``rack_probability``: the share of frames with the pallet on a rack beam, among rack
    steel and neighbour pallets (:func:`_rack_scene`); 0 draws nothing more from ``rng``.
    ``aim_probability``: the share of frames taken as the scan takes them, the camera aimed
    at one block (any of the three, within 4 cm) instead of anywhere along the face; an end
    block seen this way has open space on one side, which random poses rarely centre at a
    long distance. 0 draws nothing more from ``rng``.
    """
    camera = camera or CameraModel()
    identities = identities or identity_names(100)
    identity = identities[int(rng.integers(len(identities)))]
    pallet_id, side = split_identity(identity)
    base_z = _stand_height(rng)
    kelvin, lighting = _random_light(rng)
    style = (styles or {}).get(identity)
    if rack_probability > 0.0 and rng.random() < rack_probability:
        base_z = 0.05 * int(rng.integers(3, 33))  # beams at 0.15 .. 1.6 m
        scene = _rack_scene(pallet_id, side, style, base_z, int(rng.integers(RACK_VARIANTS)))
    else:
        scene = _scene(pallet_id, side, style, base_z)
    d = rng.uniform(*distance_m)
    aimed = aim_probability > 0.0 and rng.random() < aim_probability
    y = rng.uniform(-lateral_m, lateral_m)
    z = _block_centre_z(base_z) + rng.uniform(-height_m, height_m)
    yaw = math.radians(rng.uniform(-yaw_deg, yaw_deg))
    x = -d
    if aimed:  # on the ray through the block's centre, as the scan's views are
        offset = EPAL.block_offsets_m()[int(rng.integers(3))]
        x, y = -d * math.cos(yaw), -offset + rng.uniform(-0.04, 0.04) - d * math.sin(yaw)
    pose = CameraPose.from_yaw(
        x,
        y,
        z,
        yaw,
        pitch=math.radians(rng.normal(0.0, 2.0)),
        roll=math.radians(rng.normal(0.0, 2.0)),
    )
    return _shoot(
        camera, pose, scene, rng, conditions, blur_probability, (0.5, 0.1), lighting, kelvin
    )


def _shoot(
    camera: CameraModel,
    pose: CameraPose,
    scene: Scene,
    rng: np.random.Generator,
    conditions: ViewConditions | None,
    blur_probability: float,
    blur_mps: tuple[float, float],
    lighting: Lighting,
    kelvin: float,
) -> tuple[np.ndarray, list[BlockBox]]:
    """A raw frame and its block boxes: under ``conditions`` if given, else with the
    renderer's light (``lighting``, ``kelvin``) and, in ``blur_probability`` of the frames,
    motion blur from a sideways and vertical speed up to ``blur_mps``."""
    if conditions is not None:
        return take_frame(camera, pose, scene, rng, conditions), block_boxes(camera, pose, scene)
    velocity = None
    if rng.random() < blur_probability:
        vy, vz = blur_mps
        velocity = (0.0, float(rng.uniform(-vy, vy)), float(rng.uniform(-vz, vz)) if vz else 0.0)
    return render_frame(
        camera,
        pose,
        scene,
        rng,
        velocity=velocity,
        lighting=lighting,
        colour_temperature_k=kelvin,
        return_boxes=True,
    )


@lru_cache(maxsize=4)
def _wb_factors(sensor: SensorModel) -> tuple[float, float, float]:
    return calibrate(render_white_target(np.random.default_rng(1), colour_temperature_k=NOMINAL_K))


def _occlude(crop: np.ndarray, rng: np.random.Generator, max_fraction: float) -> None:
    """Cover a band from one edge (a fork, a strap, a shadow, the frame border) in place."""
    h, w = crop.shape[:2]
    f = rng.uniform(0.05, max_fraction)
    colour = (rng.uniform(10, 80),) * 3 if rng.random() < 0.7 else tuple(rng.uniform(60, 200, 3))
    edge = int(rng.integers(4))
    if edge == 0:
        crop[:, : max(1, int(w * f))] = colour
    elif edge == 1:
        crop[:, w - max(1, int(w * f)) :] = colour
    elif edge == 2:
        crop[: max(1, int(h * f))] = colour
    else:
        crop[h - max(1, int(h * f)) :] = colour


def block_crops(
    identity: str,
    side: str | None,
    block_index: int,
    rng: np.random.Generator,
    n: int,
    *,
    camera: CameraModel | None = None,
    style: SideStyle | None = None,
    distance_m: tuple[float, float] = (0.25, 0.8),
    occlusion_probability: float = 0.3,
    max_occlusion: float = 0.3,
    blur_probability: float = 0.3,
    min_size_px: int = 8,
    yaw_deg: float = 15.0,
    conditions: Conditions = None,
) -> list[np.ndarray]:
    """``n`` white-balanced BGR crops of block ``block_index`` (0, 1, 2 left to right) of a
    pallet side, as the mission's detector would cut them.

    ``identity`` is "3A" / "p0001B" (``side`` None) or a pallet id with ``side`` "A"/"B".
    Each crop comes from a full synthetic frame (random pose with the block in view: distance,
    lateral offset, yaw +-15 deg, height +-5 cm; light, colour temperature, exposure, blur,
    noise), decoded and white-balanced with factors calibrated at 4000 K, cut along the
    ground-truth box with jittered margins, sometimes partly occluded. Crops keep their
    native size (about 20..100 px wide). ``yaw_deg``: the largest yaw off square;
    ``conditions``: light, optics and sensor of every frame (a :class:`ViewConditions`,
    or a function drawing one from the generator; default: the renderer's own light,
    exposure, motion blur and noise).
    """
    camera = camera or CameraModel()
    pallet_id, side = split_identity(identity, side)
    factors = _wb_factors(SensorModel())
    offset = EPAL.block_offsets_m()[block_index]
    # Seen from in front (camera at -x looking +x), "right" is -y.
    block_y = -offset
    crops: list[np.ndarray] = []
    attempts = 0
    while len(crops) < n and attempts < 20 * n:
        attempts += 1
        base_z = _stand_height(rng)
        kelvin, lighting = _random_light(rng)
        scene = _scene(pallet_id, side, style, base_z)
        d = rng.uniform(*distance_m)
        yaw = math.radians(rng.uniform(-yaw_deg, yaw_deg))
        # Aim roughly at the block: lateral position so the block lands near the centre.
        y = block_y - d * math.tan(yaw) + rng.uniform(-0.25, 0.25) * d
        pose = CameraPose.from_yaw(
            -d,
            y,
            _block_centre_z(base_z) + rng.uniform(-0.05, 0.05),
            yaw,
            pitch=math.radians(rng.normal(0, 2)),
            roll=math.radians(rng.normal(0, 2)),
        )
        cond = conditions(rng) if callable(conditions) else conditions
        raw, boxes = _shoot(
            camera, pose, scene, rng, cond, blur_probability, (0.4, 0.0), lighting, kelvin
        )
        box = next(
            (b for b in boxes if b.block == block_index and b.identity == f"{pallet_id}{side}"),
            None,
        )
        if box is None or box.visible < 0.7 or box.x2 - box.x1 < min_size_px:
            continue
        bgr = develop(raw, factors, cond) if cond is not None else preprocess(raw, factors)
        w, h = box.x2 - box.x1, box.y2 - box.y1
        x1 = int(round(box.x1 - w * rng.uniform(-0.06, 0.12)))
        x2 = int(round(box.x2 + w * rng.uniform(-0.06, 0.12)))
        y1 = int(round(box.y1 - h * rng.uniform(-0.06, 0.12)))
        y2 = int(round(box.y2 + h * rng.uniform(-0.06, 0.12)))
        x1, y1 = max(x1, 0), max(y1, 0)
        x2, y2 = min(x2, camera.width), min(y2, camera.height)
        if x2 - x1 < min_size_px or y2 - y1 < 4:
            continue
        crop = np.ascontiguousarray(bgr[y1:y2, x1:x2])
        if rng.random() < occlusion_probability:
            _occlude(crop, rng, max_occlusion)
        crops.append(crop)
    return crops


def crop_to(crop: np.ndarray, size_hw: tuple[int, int] = (384, 128)) -> np.ndarray:
    """Resize a crop to the embedder's input (height, width), e.g. PCB's 384 x 128."""
    return cv2.resize(crop, (size_hw[1], size_hw[0]), interpolation=cv2.INTER_LINEAR)


__all__ = [
    "block_crops",
    "crop_to",
    "identity_names",
    "render_detection_sample",
]
