"""The AI-deck camera in software in the loop: rigs/sitl.yaml streams the emulated deck's frames
(rendered from the simulated drone's true pose) over CPX/TCP to the real stream client, which
is the Vehicle's camera. Real time: every wait is a poll with a time-out."""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
from helpers import REPO, wait_until

from bt_engine.clock import WallClock
from drivers.crazyflie.cf_platform import CrazyfliePlatform
from drivers.rig.factory import make_platform
from drivers.rig.loader import load_rig
from drivers.safety.supervisor import SafetySupervisor
from drivers.sim.camera import SimCamera

SITL_RIG = os.path.join(REPO, "rigs", "sitl.yaml")

pytestmark = [pytest.mark.sitl, pytest.mark.slow]  # real-time emulators on 127.0.0.1


@contextmanager
def sitl_platform(**overrides: str) -> Iterator[tuple[Any, CrazyfliePlatform]]:
    """(rig, platform) of rigs/sitl.yaml on a fresh wall clock, shut down afterwards."""
    rig = load_rig(SITL_RIG, overrides or None)
    platform = make_platform(rig, WallClock(), 0)
    try:
        yield rig, platform
    finally:
        platform.shutdown("test done")


def test_stream_frames_reach_the_vehicle_with_time_and_pose() -> None:
    with sitl_platform() as (_, p):
        v, emu = p.vehicle, p.camera_emulator
        assert p.camera is not None and emu is not None and v.camera is p.camera
        wait_until(lambda: v.health.camera.samples >= 16, 10.0, "16 frames at the Vehicle")
        f = v.camera_frame()
        assert f is not None and isinstance(f.image, np.ndarray)
        # the simulator's format: raw 244 x 324 uint8 BayerBG, marked as SimCamera marks it
        assert f.image.shape == (244, 324) and f.image.dtype == np.uint8
        sim = SimCamera(15.0, lambda pose, t_s, previous=None: np.zeros((244, 324), np.uint8))
        sim.capture(0.0, f.pose)
        assert f.meta["format"] == sim.poll(1.0).meta["format"] == "bayer_bg"
        assert any(s.payload == f.meta["payload"] for s in emu.sent)  # bit-exact from the deck
        # on the platform's clock: after the clock started, not after now (no latency bound)
        assert 0.0 <= f.t_s <= p.clock.now()
        truth = p.sitl.true_pose()
        assert f.pose.source == "mocap" and math.dist(f.pose.position, truth.position) < 0.01
        h = v.health.camera
        assert h.connected and h.healthy and h.rate_hz > 0.0, h  # rate: bench/sitl_link.py
        st = p.camera.stats()
        assert st.dropped == 0 and st.corrupt == 0
        assert p.summary()["camera"]["frames_at_vehicle"] >= 16


def test_stream_disconnect_and_stall_in_flight_are_camera_faults() -> None:
    with sitl_platform(**{"aideck.reconnect_max_s": "0.5"}) as (rig, p):
        v = p.vehicle
        sup = SafetySupervisor.from_rig(rig, p)
        wait_until(lambda: v.health.camera.samples > 0, 10.0, "a frame at the Vehicle")
        prog = v.takeoff(0.4, 0.8)
        wait_until(lambda: prog.reached, 10.0, "the take-off to 0.4 m")
        f = v.camera_frame()
        assert f is not None and abs(f.pose.z_m - 0.4) < 0.05  # the pose at capture, flying

        def fault() -> bool:
            sup.after_tick(p.clock.now())  # report-only policy: never raises
            return sup.monitor.is_active("camera_stalled")

        assert not fault()
        p.faults.inject("camera_disconnect")  # the deck drops the client, refuses new ones
        wait_until(fault, 5.0, "camera_stalled after camera_disconnect", 0.02)
        h = v.health.camera
        assert not h.connected and not h.healthy
        p.faults.clear("camera_disconnect")
        wait_until(lambda: not fault(), 10.0, "the camera fault cleared after reconnecting", 0.02)
        assert p.camera.stats().reconnects >= 1
        p.faults.inject("camera_stall")  # connected, no frames: stale after camera_stale_s
        wait_until(fault, 5.0, "camera_stalled after camera_stall", 0.02)
        assert v.health.camera.connected
        p.faults.clear("camera_stall")
        wait_until(lambda: not fault(), 5.0, "the camera stall cleared", 0.02)
        assert [r.fault for r in sup.monitor.history] == ["camera_stalled", "camera_stalled"]
