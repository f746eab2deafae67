"""Synthetic AI-deck frames: geometry, ground-truth boxes, Bayer mosaic, blur."""

from __future__ import annotations

import math

import cv2
import numpy as np

from perception.synth.camera_model import CameraModel, CameraPose, project
from perception.synth.render import (
    Lighting,
    SensorModel,
    apply_sensor,
    render_frame,
    render_scene,
)
from perception.synth.scene import PalletSpec, Scene, SceneLight
from perception.white_balance import decode_raw

CAM = CameraModel()
LIGHT = SceneLight(0.6, (((4.0, 0.0, 4.0), 1.0), ((9.0, 0.0, 4.0), 1.0)), 4000.0)
# The reference scan slot: face at x = 9.30, centre y = -0.05, base on a 0.194 m stand.
SCENE = Scene.build(
    [PalletSpec("3", "A", 9.30, -0.05, 0.194, math.pi)],
    boxes=[((9.7, -0.05, 0.097), (0.4, 0.6, 0.097), 0.0)],
    light=LIGHT,
)
SCAN = CameraPose.from_yaw(8.90, -0.05, 0.255, 0.0)


def test_intrinsics_match_the_field_of_view():
    assert math.isclose(2 * math.degrees(math.atan(162 / CAM.fx)), 87.0)
    uv, z = project(CAM, SCAN, np.array([[9.30, -0.05, 0.255], [9.30, -0.45, 0.255]]))
    assert np.allclose(uv[0], (CAM.cx, CAM.cy)) and np.allclose(z, 0.40)
    assert uv[1, 0] > CAM.cx + 100  # -y is to the right in the image


def test_scan_pose_frame_and_boxes():
    raw, boxes = render_frame(CAM, SCAN, SCENE, np.random.default_rng(0), return_boxes=True)
    assert raw.shape == (244, 324) and raw.dtype == np.uint8
    assert [(b.block, b.identity) for b in boxes] == [(1, "3A")]  # the middle block, centred
    b = boxes[0]
    assert abs((b.x1 + b.x2) / 2 - 162) < 1.5 and abs((b.y1 + b.y2) / 2 - 122) < 1.5
    assert math.isclose(b.x2 - b.x1, CAM.fx * 0.145 / 0.40, rel_tol=0.02)
    assert b.visible == 1.0


def test_blocks_are_where_the_boxes_say():
    """From 0.4 m at y = -0.45 the right block and part of the middle one are in view.
    Robust check on the decoded frame: each box is much brighter than the dark fork opening
    beside it (same rows), and wood (red > blue after decoding) is inside the box."""
    pose = CameraPose.from_yaw(8.90, -0.45, 0.255, 0.0)
    raw, boxes = render_frame(CAM, pose, SCENE, np.random.default_rng(1), return_boxes=True)
    assert sorted(b.block for b in boxes) == [1, 2]
    grey = decode_raw(raw).astype(np.float32).mean(axis=2)
    full = next(b for b in boxes if b.block == 2)
    y1, y2 = int(full.y1) + 3, int(full.y2) - 3
    inside = grey[y1:y2, int(full.x1) + 3 : int(full.x2) - 3].mean()
    gap = grey[y1:y2, int(full.x1) - 40 : int(full.x1) - 10].mean()
    assert inside > 2.0 * gap
    part = next(b for b in boxes if b.block == 1)
    assert part.x1 <= 1 and 0.1 < part.visible < 0.9


def test_many_poses_boxes_brighter_than_surroundings():
    rng = np.random.default_rng(3)
    hits = 0
    for _ in range(20):
        pose = CameraPose.from_yaw(
            9.30 - rng.uniform(0.3, 0.7),
            rng.uniform(-0.6, 0.5),
            0.255 + rng.uniform(-0.04, 0.04),
            math.radians(rng.uniform(-10, 10)),
        )
        bgr, _ = render_scene(CAM, pose, SCENE)
        grey = bgr.astype(np.float32).mean(axis=2)
        _, boxes = render_frame(CAM, pose, SCENE, rng, return_boxes=True)
        for b in boxes:
            if b.visible < 1.0 or b.x2 - b.x1 < 20:
                continue
            inner = grey[int(b.y1) + 2 : int(b.y2) - 2, int(b.x1) + 2 : int(b.x2) - 2].mean()
            band = grey[int(b.y2) + 8 : int(b.y2) + 14, int(b.x1) : int(b.x2)]  # stand below
            assert inner > band.mean() + 20
            hits += 1
    assert hits >= 10


def test_bayer_round_trip_and_green_cast():
    colour = np.zeros((244, 324, 3), np.uint8)
    colour[:, :108] = (40, 120, 200)
    colour[:, 108:216] = (200, 90, 30)
    colour[:, 216:] = (128, 128, 128)
    clean = SensorModel(
        (1.0, 1.0, 1.0), vignetting=0.0, black_level=0.0, read_noise=0.0, shot_noise=0.0
    )
    raw = apply_sensor(colour, np.random.default_rng(0), sensor=clean)
    back = cv2.cvtColor(raw, cv2.COLOR_BayerBG2BGR)
    inner = (slice(4, -4), np.r_[4:100, 112:212, 220:320])
    assert np.abs(back[inner].astype(int) - colour[inner].astype(int)).max() <= 1
    white = np.full((244, 324, 3), 200, np.uint8)
    raw = apply_sensor(white, np.random.default_rng(0))
    b, g, r = decode_raw(raw).reshape(-1, 3).mean(axis=0)
    assert g > 1.15 * r and g > 1.15 * b  # the raw AI-deck image looks green


def test_motion_blur_smooths_along_the_motion():
    rng = np.random.default_rng(0)
    still = render_frame(CAM, SCAN, SCENE, rng, sensor=SensorModel(read_noise=0, shot_noise=0))
    moving = render_frame(
        CAM,
        SCAN,
        SCENE,
        rng,
        velocity=(0.0, 1.0, 0.0),
        lighting=Lighting(exposure_time_s=0.03),
        sensor=SensorModel(read_noise=0, shot_noise=0),
    )
    dx = lambda im: np.abs(np.diff(decode_raw(im).astype(float), axis=1)).mean()  # noqa: E731
    assert dx(moving) < 0.8 * dx(still)


def test_deterministic_per_seed_and_noise_differs_between_seeds():
    a = render_frame(CAM, SCAN, SCENE, np.random.default_rng(7))
    b = render_frame(CAM, SCAN, SCENE, np.random.default_rng(7))
    c = render_frame(CAM, SCAN, SCENE, np.random.default_rng(8))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_looking_away_renders_a_frame_without_boxes():
    # (how fast frames render is measured in bench/, not asserted here)
    rng = np.random.default_rng(0)
    away = CameraPose.from_yaw(5.0, 0.0, 1.0, math.pi)
    for pose in (SCAN, away):
        render_frame(CAM, pose, SCENE, rng)  # textures made once
    frame, boxes = render_frame(CAM, away, SCENE, rng, return_boxes=True)
    assert boxes == []
    assert frame.shape == (244, 324)


def test_degenerate_poses_do_not_fail():
    rng = np.random.default_rng(0)
    for pose in (
        CameraPose.from_yaw(0.0, 0.0, 0.0, 0.0),  # on the floor
        CameraPose.from_yaw(9.0, -0.05, 0.3, 0.0, pitch=math.radians(80)),
        CameraPose.from_yaw(9.0, -0.05, 0.3, 0.3, roll=math.radians(90)),
    ):
        assert render_frame(CAM, pose, SCENE, rng).shape == (244, 324)
