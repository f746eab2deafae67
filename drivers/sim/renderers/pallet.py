"""The ``pallet`` camera renderer: the simulated world seen by the AI-deck camera.

A thin adapter from the simulator to :mod:`perception.synth` (which knows nothing of the
simulator): it turns the :class:`~drivers.sim.world.World` (pallets with identities and
sides, the stand under the scan pallet, obstacles, floor, lamps) into a
:class:`perception.synth.Scene` once, and each drone :class:`~drivers.vehicle.types.Pose` into a
camera pose. Every frame is a raw 244 x 324 uint8 BayerBG image like the real AI-deck's
(decode and white-balance it with :func:`perception.white_balance.preprocess`).

Per frame: motion blur from the pose change since the previous frame, noise from the given
random generator (deterministic per seed), and an auto-exposure that re-adapts every 15th
frame like the camera firmware of [study] (docs/references.md). Chosen by the rig with
``sensors.camera.renderer: pallet``.
"""

from __future__ import annotations

import hashlib
import json
import math
import random
from collections import OrderedDict
from typing import Any

import cv2
import numpy as np

from drivers.sim.world import World
from drivers.vehicle.angles import yaw_from_quaternion
from drivers.vehicle.types import Pose
from perception.synth.appearance import PalletGeometry, part_seed, world_side_style
from perception.synth.camera_model import CameraModel, CameraPose
from perception.synth.render import BlockBox, Lighting, block_boxes, render_frame
from perception.synth.scene import PalletSpec, Scene, SceneLight

AE_PERIOD = 15  # frames between auto-exposure updates ([study]: every 15th frame)
AE_TARGET = 95.0  # mean raw level the auto-exposure aims for
#: the textures of what lies this close ahead of the camera are made on a worker thread
#: before it comes into view (:func:`perception.synth.render.render_scene`): the same
#: frames, the second core making the pallets' faces while the first draws and flies
TEXTURE_LOOKAHEAD_M = 3.0


#: Scenes built in this process, by world (its data and seed): the drones of a fleet share
#: one, and a campaign worker reuses it for rows of the same world and seed. A scene is
#: static once built (its textures are made on first sight, deterministically), and the
#: per-frame noise comes from each renderer's own generator, so sharing changes no image.
_SCENES: OrderedDict[str, Scene] = OrderedDict()
MAX_SCENES = 4


def scene_from_world(world: World | None) -> Scene:
    """The synthetic scene of a simulated world (pallets, stand and obstacle boxes, floor),
    shared by every renderer of the same world data and seed in this process."""
    if world is None:
        return Scene.build([])
    key = hashlib.sha1(
        json.dumps([world.data, world.seed], sort_keys=True, default=repr).encode()
    ).hexdigest()
    scene = _SCENES.get(key)
    if scene is None:
        scene = _SCENES[key] = _build_scene(world)
        while len(_SCENES) > MAX_SCENES:
            _SCENES.popitem(last=False)
    else:
        _SCENES.move_to_end(key)
    return scene


def _build_scene(world: World) -> Scene:
    data = world.data
    geometry = PalletGeometry.from_dict(data["pallet_geometry"])
    pallets = []
    for p in world.pallets:
        look = data.get("pallet_look") or {}
        styles = tuple(
            (side, world_side_style(s, look, part_seed(p.pallet_id, side, "age")))
            for side, s in sorted((p.sides or {}).items())
            if s is not None
        )
        fx, fy, _ = p.face_center_m
        pallets.append(
            PalletSpec(p.pallet_id, p.shown_side, fx, fy, p.z_m, p.facing_rad, geometry, styles)
        )
    boxes = [
        ((b.cx, b.cy, b.cz), (b.hx, b.hy, b.hz), b.yaw_rad, b.material)
        for b in world.boxes
        if not b.name.startswith("pallet ")
    ]
    fl = data["floor"]
    li = data["lighting"]
    light = SceneLight(
        li["ambient"],
        tuple((tuple(lamp["position_m"]), lamp["intensity"]) for lamp in li["lamps"]),
        li["colour_temperature_k"],
    )
    floor = (tuple(fl["origin_m"]), tuple(fl["size_m"]), fl["z_m"])
    return Scene.build(pallets, boxes=boxes, floor=floor, light=light)


def camera_pose(pose: Pose) -> CameraPose:
    """Camera pose of a drone pose: the quaternion if it agrees with the yaw, else the yaw."""
    q = pose.quaternion
    if abs(math.remainder(yaw_from_quaternion(q) - pose.yaw_rad, 2.0 * math.pi)) < 1e-3:
        return CameraPose.from_quaternion(pose.x_m, pose.y_m, pose.z_m, q)
    return CameraPose.from_yaw(pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad)


class PalletRenderer:
    """``renderer(pose, t_s) -> raw Bayer frame`` over a world; see the module doc."""

    def __init__(self, world: World | None, camera: dict | None, rng: Any) -> None:
        self.camera = CameraModel.from_dict(camera)
        self.scene = scene_from_world(world)
        if isinstance(rng, np.random.Generator):
            self.rng = rng
        else:
            self.rng = np.random.default_rng((rng or random.Random(0)).getrandbits(64))
        # A fixed, gentle light gradient per run (lamps are off-centre in a real hall).
        self.gradient = float(self.rng.uniform(0.0, 0.12))
        self.gradient_angle = float(self.rng.uniform(-math.pi, math.pi))
        self.exposure = 1.0
        self.frames = 0
        self._last: tuple[float, CameraPose, float] | None = None

    def _motion(
        self,
        pose: Pose,
        cam: CameraPose,
        t_s: float,
        previous: tuple[float, Pose] | None = None,
    ) -> tuple[tuple, float] | None:
        last = self._last
        if previous is not None:
            last = (previous[0], camera_pose(previous[1]), previous[1].yaw_rad)
        self._last = (t_s, cam, pose.yaw_rad)
        if last is None or t_s <= last[0]:
            return None
        dt = t_s - last[0]
        v = ((cam.x - last[1].x) / dt, (cam.y - last[1].y) / dt, (cam.z - last[1].z) / dt)
        yaw_rate = math.remainder(pose.yaw_rad - last[2], 2.0 * math.pi) / dt
        return v, yaw_rate

    def __call__(
        self, pose: Pose, t_s: float, previous: tuple[float, Pose] | None = None
    ) -> np.ndarray:
        """The raw frame seen from ``pose`` at mission time ``t_s``; motion blur from the
        ``previous`` frame's ``(t_s, pose)`` if given, else from the last rendered frame."""
        cam = camera_pose(pose)
        motion = self._motion(pose, cam, t_s, previous)
        velocity, yaw_rate = motion if motion is not None else (None, 0.0)
        lighting = Lighting(
            exposure=self.exposure, gradient=self.gradient, gradient_angle_rad=self.gradient_angle
        )
        threads = cv2.getNumThreads()
        cv2.setNumThreads(1)  # tiny images: OpenCV's thread pool costs more than it saves
        try:
            raw = render_frame(
                self.camera,
                cam,
                self.scene,
                self.rng,
                velocity=velocity,
                yaw_rate=yaw_rate,
                lighting=lighting,
                lookahead_m=TEXTURE_LOOKAHEAD_M,
            )
        finally:
            cv2.setNumThreads(threads)
        self.frames += 1
        if self.frames % AE_PERIOD == 1:
            mean = float(raw[::4, ::4].mean()) + 1.0
            self.exposure = float(np.clip(self.exposure * (AE_TARGET / mean) ** 0.8, 0.3, 4.0))
        return raw  # type: ignore[return-value]

    def ground_truth(self, pose: Pose) -> list[BlockBox]:
        """Boxes of the support blocks visible from ``pose`` (for tests and training)."""
        return block_boxes(self.camera, camera_pose(pose), self.scene)


def make_pallet_renderer(
    world: World | None = None, camera: dict | None = None, rng: Any = None, **_: Any
) -> PalletRenderer:
    """The ``pallet`` renderer (see :data:`drivers.sim.renderers.RENDERERS`)."""
    return PalletRenderer(world, camera, rng)
