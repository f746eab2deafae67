"""The ``pallet`` renderer through the simulator: frames reach the Vehicle's camera."""

from __future__ import annotations

import numpy as np
from helpers import sim_mission, wrap

from perception.white_balance import preprocess

HOVER = wrap(
    '<Sequence><TakeOff name="takeoff" height="0.255"/><Delay delay_msec="5000">'
    "<AlwaysSuccess/></Delay></Sequence>"
)


def _hover(seed: int, ticks: int):
    """Take off in front of the scan pallet (3A) and hover; returns the platform."""
    overrides = {"sensors.camera.renderer": "pallet", "sim.start_m": "[8.90, -0.05, 0.0]"}
    m, run, platform = sim_mission(HOVER, seed=seed, overrides=overrides)
    run.run_until(lambda mm: mm.ticks >= ticks, ticks + 1)
    return platform


def test_pallet_renderer_frames_through_the_simulator():
    platform = _hover(1, 200)  # 4 s: airborne at the scan height
    frame = platform.vehicle.camera_frame()
    assert frame is not None
    assert frame.image.shape == (244, 324) and frame.image.dtype == np.uint8
    renderer = platform.camera.renderer
    boxes = renderer.ground_truth(frame.pose)
    assert [b.block for b in boxes if b.visible == 1.0] == [1]  # the middle block of 3A
    assert boxes[0].identity == "3A"
    bgr = preprocess(frame.image, (1.77, 1.17, 1.49))
    b = boxes[0]
    inside = bgr[int(b.y1) + 3 : int(b.y2) - 3, int(b.x1) + 3 : int(b.x2) - 3].mean()
    gap = bgr[int(b.y1) + 3 : int(b.y2) - 3, int(b.x2) + 15 : int(b.x2) + 45].mean()
    assert inside > 1.8 * gap
    assert 60 < frame.image.mean() < 160  # the auto-exposure keeps the frame usable


def test_pallet_renderer_is_deterministic_per_seed():
    frames = []
    for _ in range(2):
        frames.append(_hover(5, 60).vehicle.camera_frame().image)
    assert np.array_equal(frames[0], frames[1])
