"""The motion-capture driver on ``motioncapture``'s mock system (no network, except the probe
of an unreachable server on 127.0.0.1)."""

from __future__ import annotations

import math
import threading
import time
from typing import Any

import motioncapture
import pytest
from helpers import wait_until

from drivers.crazyflie.mocap import MocapSource, convert_pose
from drivers.rig.loader import load_rig
from drivers.vehicle.interfaces import PoseSample


def _mock_body(name: str, xyz: tuple[float, float, float], yaw_deg: float) -> str:
    h = math.radians(yaw_deg) / 2.0
    return f"{name}({xyz[0]},{xyz[1]},{xyz[2]},{math.cos(h)},0,0,{math.sin(h)})"


def test_convert_pose_z_up_and_y_up() -> None:
    h = math.radians(30.0) / 2
    pos, q, yaw = convert_pose((1.0, 2.0, 3.0), math.cos(h), 0.0, 0.0, math.sin(h))
    assert pos == (1.0, 2.0, 3.0) and q[3] == pytest.approx(math.cos(h))  # (qx, qy, qz, qw)
    assert yaw == pytest.approx(math.radians(30.0))
    # y-up: "up" (0, 1, 0) becomes z; a turn about the y-up vertical is a yaw about z
    pos, q, yaw = convert_pose((0.5, 1.5, -2.0), math.cos(h), 0.0, math.sin(h), 0.0, "y")
    assert pos == (0.5, 2.0, 1.5)
    assert yaw == pytest.approx(math.radians(30.0)) and q[2] == pytest.approx(math.sin(h))


def test_mock_poses_timestamps_and_rate() -> None:
    body = _mock_body("cf", (0.5, -1.25, 0.75), 30.0)
    started = time.monotonic()
    with MocapSource("mock", rigid_body="cf", params={"rigid_bodies": body}) as src:
        assert src.expected_rate_hz() == 100.0
        wait_until(lambda: src.stats().samples >= 40, 10.0, "40 mocap samples")
        samples: list[PoseSample] = src.poll(1000.0)
        since_start_s = time.monotonic() - started
    assert len(samples) >= 40
    s = samples[-1]
    assert (s.x_m, s.y_m, s.z_m) == pytest.approx((0.5, -1.25, 0.75), abs=1e-6)
    assert s.yaw_rad == pytest.approx(math.radians(30.0), abs=1e-6)
    qx, qy, qz, qw = s.quaternion
    assert qz == pytest.approx(math.sin(math.radians(15.0)), abs=1e-6)
    times = [p.t_s for p in samples]
    assert all(b > a for a, b in zip(times, times[1:], strict=False))
    # stamped in the poller's clock: at or before "now" (1000 s), and not before the source
    # existed (a bound by causality; the rate itself is not asserted: wall clock)
    assert 1000.0 - since_start_s <= times[0] and times[-1] <= 1000.0
    seqs = [p.seq for p in samples]
    assert all(b > a for a, b in zip(seqs, seqs[1:], strict=False))


class GatedMock:
    """Wraps a real ``motioncapture`` mock; frames stop while ``gate`` is clear."""

    def __init__(self, real: Any) -> None:
        self.real, self.gate = real, threading.Event()
        self.gate.set()

    @property
    def rigidBodies(self) -> Any:  # noqa: N802  (motioncapture's name)
        return self.real.rigidBodies

    def waitForNextFrame(self) -> None:  # noqa: N802
        while not self.gate.wait(0.05):
            pass
        self.real.waitForNextFrame()


def test_staleness_and_dropouts_when_frames_stop() -> None:
    holder: dict[str, GatedMock] = {}

    def connect(kind: str, params: dict[str, str]) -> GatedMock:
        holder["m"] = GatedMock(motioncapture.connect(kind, params))
        return holder["m"]

    with MocapSource("mock", rigid_body="cf", stale_s=0.1, connect=connect) as src:
        wait_until(lambda: src.stats().samples >= 10, 10.0, "10 mocap samples")
        assert not src.stats().stale and src.connected
        before = src.stats().dropouts
        holder["m"].gate.clear()  # the mocap goes silent
        wait_until(lambda: src.stats().stale, 5.0, "the silent mocap to be stale")
        src.poll(0.0)
        time.sleep(0.3)
        assert src.poll(0.0) == []
        seq0 = src.stats().samples
        holder["m"].gate.set()
        wait_until(lambda: src.stats().samples >= seq0 + 3, 10.0, "3 samples after the silence")
        st = src.stats()
        assert not st.stale
        assert st.dropouts - before >= 30  # ~0.4 s of silence at 100 Hz counts as lost frames
        samples = src.poll(0.0)
        assert samples and samples[0].seq > seq0 + 30  # the Vehicle sees a seq gap too


def test_missing_body_counts_dropouts() -> None:
    params = {"rigid_bodies": _mock_body("other", (0, 0, 0), 0)}
    with MocapSource("mock", rigid_body="cf", params=params) as src:
        wait_until(lambda: src.stats().frames >= 10, 10.0, "10 mocap frames")
        st = src.stats()
        assert st.samples == 0 and st.body_missing >= 10 and st.dropouts >= 10 and st.stale
        assert src.poll(0.0) == []


def test_frozen_server_repeats_are_not_fresh() -> None:
    # A "vicon" that repeats a bit-identical pose: same seq every frame -> stale to the Vehicle.
    params = {"rigid_bodies": _mock_body("cf", (1, 2, 3), 0), "frequency": "100"}

    def connect(kind: str, p: dict[str, str]) -> Any:
        return motioncapture.connect("mock", p)  # never a real Vicon: its connect holds the GIL

    with MocapSource("vicon", rigid_body="cf", params=params, connect=connect, probe_s=0) as src:
        wait_until(lambda: src.stats().frames >= 15, 10.0, "15 mocap frames")
        st = src.stats()
        assert st.repeats >= 10 and st.stale
        assert len({p.seq for p in src.poll(0.0)}) == 1


def test_connect_errors_retry_without_crashing() -> None:
    calls = []

    def connect(kind: str, params: dict[str, str]) -> Any:
        calls.append(params)
        raise RuntimeError("no server")

    # optitrack (NatNet over UDP) is not probed, so connect is called (and fails) directly
    with MocapSource("optitrack", host="127.0.0.1", connect=connect, reconnect_s=0.05) as src:
        wait_until(lambda: len(calls) >= 3, 5.0, "3 connection attempts")
        assert "no server" in src.stats().last_error and not src.connected
    assert calls[0] == {"hostname": "127.0.0.1"}


def test_from_rig_and_validation() -> None:
    rig = load_rig(None, {"mocap.type": "mock", "mocap.rigid_body": "cf2", "mocap.rate_hz": "120"})
    src = MocapSource.from_rig(rig.data, autostart=False)
    assert (src.system_type, src.rigid_body, src.rate_hz, src.up_axis) == ("mock", "cf2", 120, "z")
    assert src.connection_params() == {"rigid_bodies": "cf2(0,0,0,1,0,0,0)", "frequency": "120"}
    with pytest.raises(ValueError):
        MocapSource("kinect", autostart=False)


@pytest.mark.sitl  # a probe and a listening socket on 127.0.0.1
def test_unreachable_server_is_probed_not_connected() -> None:
    """Vicon's connect blocks holding the GIL if nobody answers: probe the port first."""
    import socket

    calls: list[dict[str, str]] = []

    def connect(kind: str, params: dict[str, str]) -> Any:
        calls.append(params)
        raise RuntimeError("stop here")

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    closed_port = s.getsockname()[1]
    s.close()
    host = f"127.0.0.1:{closed_port}"
    with MocapSource("vicon", host=host, connect=connect, reconnect_s=0.05) as src:
        wait_until(
            lambda: src.stats().last_error.startswith("unreachable"), 5.0, "an unreachable probe"
        )
        time.sleep(0.2)
        assert calls == []
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    host = f"127.0.0.1:{srv.getsockname()[1]}"
    try:
        with MocapSource("vicon", host=host, connect=connect, reconnect_s=0.05):
            wait_until(lambda: len(calls) >= 1, 5.0, "a connection attempt")
        assert calls[0] == {"hostname": host}
    finally:
        srv.close()
