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
from crtp_helpers import wait_for
from helpers import REPO

from bt_engine.clock import WallClock
from drivers.crazyflie.cf_platform import CrazyfliePlatform
from drivers.rig.factory import make_platform
from drivers.rig.loader import load_rig
from drivers.safety.supervisor import SafetySupervisor
from drivers.sim.camera import SimCamera

SITL_RIG = os.path.join(REPO, "rigs", "sitl.yaml")


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
        assert wait_for(lambda: v.health.camera.samples >= 16, 3.0)  # about 1 s of frames
        f = v.camera_frame()
        assert f is not None and isinstance(f.image, np.ndarray)
        # the simulator's format: raw 244 x 324 uint8 BayerBG, marked as SimCamera marks it
        assert f.image.shape == (244, 324) and f.image.dtype == np.uint8
        sim = SimCamera(15.0, lambda pose, t_s, previous=None: np.zeros((244, 324), np.uint8))
        sim.capture(0.0, f.pose)
        assert f.meta["format"] == sim.poll(1.0).meta["format"] == "bayer_bg"
        assert any(s.payload == f.meta["payload"] for s in emu.sent)  # bit-exact from the deck
        assert 0.0 <= p.clock.now() - f.t_s < 0.5
        truth = p.sitl.true_pose()
        assert f.pose.source == "mocap" and math.dist(f.pose.position, truth.position) < 0.01
        h = v.health.camera
        assert h.connected and h.healthy and 12.0 <= h.rate_hz <= 17.0, h
        st = p.camera.stats()
        assert st.dropped == 0 and st.corrupt == 0
        assert p.summary()["camera"]["frames_at_vehicle"] >= 16


def test_stream_disconnect_and_stall_in_flight_are_camera_faults() -> None:
    with sitl_platform(**{"aideck.reconnect_max_s": "0.5"}) as (rig, p):
        v = p.vehicle
        sup = SafetySupervisor.from_rig(rig, p)
        assert wait_for(lambda: v.health.camera.samples > 0, 3.0)
        prog = v.takeoff(0.4, 0.8)
        assert wait_for(lambda: prog.reached, 5.0)
        f = v.camera_frame()
        assert f is not None and abs(f.pose.z_m - 0.4) < 0.05  # the pose at capture, flying

        def fault() -> bool:
            sup.after_tick(p.clock.now())  # report-only policy: never raises
            return sup.monitor.is_active("camera_stalled")

        assert not fault()
        p.faults.inject("camera_disconnect")  # the deck drops the client, refuses new ones
        assert wait_for(fault, 1.0, 0.02)
        h = v.health.camera
        assert not h.connected and not h.healthy
        p.faults.clear("camera_disconnect")
        assert wait_for(lambda: not fault(), 3.0, 0.02)
        assert p.camera.stats().reconnects >= 1
        p.faults.inject("camera_stall")  # connected, no frames: stale after camera_stale_s
        assert wait_for(fault, 2.0, 0.02)
        assert v.health.camera.connected
        p.faults.clear("camera_stall")
        assert wait_for(lambda: not fault(), 1.0, 0.02)
        assert [r.fault for r in sup.monitor.history] == ["camera_stalled", "camera_stalled"]
