"""Motion capture as a :class:`~drivers.vehicle.interfaces.PoseSource`, on PyPI ``motioncapture``.

``motioncapture`` (the libmotioncapture bindings) talks to Vicon, OptiTrack, Qualisys and
VRPN servers, and has a ``mock`` system for tests. :class:`MocapSource` connects in a
background thread (``motioncapture.connect(type, {"hostname": host, ...})`` can block for a
long time on an unreachable Vicon, so never in the constructor), calls
``waitForNextFrame()`` (it releases the GIL) in a loop and queues one
:class:`~drivers.vehicle.interfaces.PoseSample` per frame that contains the rigid body. The Vehicle polls
them every control tick; each fresh sample becomes the Vehicle's pose and is forwarded to the
drone's estimator as an external pose (``Link.send_external_pose``, CRTP ``extpose``).

Frames and conventions
----------------------
* World frame: right-handed, **z up**, metres - Vicon's default and the Crazyflie's. For
  a system streaming **y up** (OptiTrack Motive's default) set ``up_axis: y``: positions
  become ``(x, -z, y)`` (a +90 deg rotation about x) and the quaternion's vector part is
  rotated the same way; better still, switch the mocap software to z-up streaming.
* Quaternions: ``motioncapture`` gives ``rotation.w, .x, .y, .z``; PoseSample, Pose and
  cflib's ``send_extpose`` take ``(qx, qy, qz, qw)``. The conversion happens here only.
* Yaw: ``atan2(2 (w z + x y), 1 - 2 (y^2 + z^2))`` (ZYX), in (-pi, pi]; the rigid body must
  be defined with its x axis along the drone's front (the Crazyflie's x arm direction).

Timing, staleness and drops
---------------------------
* ``motioncapture``'s Python API carries no frame time, so each frame is stamped with the
  host's monotonic clock on arrival; :meth:`MocapSource.poll` converts it to mission time
  (``t_s = now_s - (monotonic now - arrival)``).
* ``seq`` counts frame *slots* at the nominal rate: a gap of ``k`` periods between arrivals
  advances it by ``round(k)``, and a frame without the rigid body (occluded, untracked) uses a
  slot without a sample, so the Vehicle counts both as drops. ``dropouts`` in
  :meth:`MocapSource.stats` is the same count.
* A frame bit-identical to the previous one (a frozen server repeating itself; real noise
  makes exact repeats implausible) keeps the previous ``seq``: the Vehicle sees it as
  stale, not fresh. This is off for the ``mock`` system, whose poses are static.
* ``stale_s``: :meth:`MocapSource.stats` reports ``stale`` once no new pose came for that
  long (the Vehicle applies its own ``control.mocap_stale_s`` to the same samples).

Unreachable servers
-------------------
``motioncapture.connect("vicon", ...)`` towards a host where nothing answers blocks *while
holding the GIL* (observed with motioncapture 1.1): the whole process, control loop
included, freezes. So before each connect the server's TCP port (Vicon 801 or the port in
``host:port``, Qualisys 22222, VRPN 3883) is probed with a short time-out, and
``connect`` is only called once it accepts; until then ``stats().last_error`` says
``unreachable`` and the reader retries every ``reconnect_s``.
"""

from __future__ import annotations

import math
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers.vehicle.angles import yaw_from_quaternion
from drivers.vehicle.health import RateWindow
from drivers.vehicle.interfaces import PoseSample

__all__ = ["MOCAP_TYPES", "MocapSource", "MocapStats", "convert_pose"]

MOCAP_TYPES = ("vicon", "optitrack", "qualisys", "vrpn", "mock")
# TCP ports probed before connecting (NatNet/OptiTrack is UDP: not probed).
PROBE_PORTS = {"vicon": 801, "qualisys": 22222, "vrpn": 3883}

Quat = tuple[float, float, float, float]
Connect = Callable[[str, dict[str, str]], Any]


def convert_pose(
    position: Any, w: float, x: float, y: float, z: float, up_axis: str = "z"
) -> tuple[tuple[float, float, float], Quat, float]:
    """Mocap position and (w, x, y, z) rotation -> z-up position, (qx, qy, qz, qw), yaw."""
    px, py, pz = (float(v) for v in position)
    if up_axis == "y":  # +90 deg about x: (x, y, z) -> (x, -z, y), for points and axes
        px, py, pz = px, -pz, py
        x, y, z = x, -z, y
    n = math.sqrt(w * w + x * x + y * y + z * z) or 1.0
    q = (x / n, y / n, z / n, w / n)
    return (px, py, pz), q, yaw_from_quaternion(q)


@dataclass(frozen=True, slots=True)
class MocapStats:
    """Counters of a :class:`MocapSource` (``age_s``: monotonic time since the last new pose)."""

    connected: bool
    frames: int  # frames received (with or without the body)
    samples: int  # poses queued
    dropouts: int  # frame slots without a pose (time gaps + body missing)
    body_missing: int
    repeats: int  # bit-identical frames (frozen server)
    rate_hz: float  # frames with the body over the last second
    age_s: float
    stale: bool
    connects: int
    last_error: str


class MocapSource:
    """A :class:`~drivers.vehicle.interfaces.PoseSource` reading one rigid body from a mocap system."""

    def __init__(
        self,
        system_type: str = "vicon",
        host: str = "127.0.0.1",
        rigid_body: str = "cf",
        rate_hz: float = 100.0,
        stale_s: float = 0.1,
        up_axis: str = "z",
        freeze_detect: bool = True,
        params: dict[str, str] | None = None,
        connect: Connect | None = None,
        reconnect_s: float = 1.0,
        probe_s: float = 0.5,
        autostart: bool = True,
    ) -> None:
        if system_type not in MOCAP_TYPES:
            raise ValueError(f"mocap type {system_type!r} is not one of {MOCAP_TYPES}")
        if up_axis not in ("z", "y"):
            raise ValueError("up_axis is 'z' or 'y'")
        self.system_type, self.host, self.rigid_body = system_type, host, rigid_body
        self.rate_hz, self.stale_s, self.up_axis = float(rate_hz), float(stale_s), up_axis
        self.freeze_detect = freeze_detect and system_type != "mock"
        self.params = {str(k): str(v) for k, v in (params or {}).items()}
        self.reconnect_s, self.probe_s = reconnect_s, probe_s
        self._connect = connect
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._queue: deque[tuple[float, PoseSample]] = deque(maxlen=4096)
        self._thread: threading.Thread | None = None
        self._connected = False
        self._frames = self._samples = self._dropouts = 0
        self._missing = self._repeats = self._connects = 0
        self._slot = 0
        self._seq = 0
        self._last_arrival: float | None = None
        self._last_new = -math.inf
        self._last_key: tuple | None = None
        self._rate = RateWindow(1.0)
        self._last_error = ""
        if autostart:
            self.start()

    @classmethod
    def from_rig(cls, data: dict, **kwargs: Any) -> MocapSource:
        """Build from validated rig data (its ``mocap:`` section); ``kwargs`` override."""
        m = data["mocap"]
        args: dict[str, Any] = dict(
            system_type=m["type"],
            host=m["host"],
            rigid_body=m["rigid_body"],
            rate_hz=m["rate_hz"],
            stale_s=m["stale_s"],
            up_axis=m["up_axis"],
            freeze_detect=m["freeze_detect"],
            params=m["params"],
        )
        args.update(kwargs)
        return cls(**args)

    def connection_params(self) -> dict[str, str]:
        """The ``{str: str}`` passed to ``motioncapture.connect``."""
        p = {"hostname": self.host}
        if self.system_type == "mock":
            p = {
                "rigid_bodies": f"{self.rigid_body}(0,0,0,1,0,0,0)",
                "frequency": f"{self.rate_hz:g}",
            }
        p.update(self.params)
        return p

    # -- PoseSource ---------------------------------------------------------------------

    def expected_rate_hz(self) -> float:
        """The nominal frame rate (for drop accounting)."""
        return self.rate_hz

    def poll(self, now_s: float) -> list[PoseSample]:
        """Poses that arrived since the last poll (oldest first), stamped in mission time."""
        with self._lock:
            items = list(self._queue)
            self._queue.clear()
        mono = time.monotonic()
        out = []
        for arrival, s in items:
            t = now_s - max(0.0, mono - arrival)
            out.append(PoseSample(t, s.x_m, s.y_m, s.z_m, s.quaternion, s.yaw_rad, s.seq))
        return out

    # -- lifecycle ----------------------------------------------------------------------

    def start(self) -> None:
        """Start the reader thread (idempotent)."""
        if self._thread is None or not self._thread.is_alive():
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="mocap", daemon=True)
            self._thread.start()

    def close(self, timeout_s: float = 1.0) -> None:
        """Ask the reader to stop (it leaves after the next frame; the thread is a daemon)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)

    def __enter__(self) -> MocapSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def connected(self) -> bool:
        """True while frames are being read."""
        return self._connected

    def stats(self) -> MocapStats:
        """A snapshot of the counters."""
        with self._lock:
            now = time.monotonic()
            rate = self._rate.rate_hz(now)
            age = now - self._last_new
            return MocapStats(
                self._connected, self._frames, self._samples, self._dropouts, self._missing,
                self._repeats, rate, age, age > self.stale_s,
                self._connects, self._last_error,
            )  # fmt: skip

    # -- reader thread ------------------------------------------------------------------

    def probe(self, timeout_s: float = 0.5) -> bool:
        """True if the server's TCP port accepts a connection (or the type is not probed)."""
        port = PROBE_PORTS.get(self.system_type)
        if port is None or timeout_s <= 0:
            return True
        host = self.host
        if ":" in host and host.count(":") == 1:
            host, _, p = host.partition(":")
            port = int(p) if p.isdigit() else port
        try:
            socket.create_connection((host, port), timeout_s).close()
        except OSError as e:
            self._last_error = f"unreachable {host}:{port}: {e}"
            return False
        return True

    def _open(self) -> Any:
        if self._connect is not None:
            return self._connect(self.system_type, self.connection_params())
        import motioncapture

        return motioncapture.connect(self.system_type, self.connection_params())

    def _run(self) -> None:
        while not self._stop.is_set():
            if not self.probe(self.probe_s):
                self._stop.wait(self.reconnect_s)
                continue
            try:
                mc = self._open()
                self._connects += 1
                self._connected = True
                while not self._stop.is_set():
                    mc.waitForNextFrame()
                    self._on_frame(time.monotonic(), mc.rigidBodies)
            except Exception as e:  # a broken server must not kill the reader
                self._last_error = f"{type(e).__name__}: {e}"
            finally:
                self._connected = False
                self._last_arrival = None
            self._stop.wait(self.reconnect_s)

    def _on_frame(self, t: float, bodies: Any) -> None:
        """Account one frame that arrived at monotonic time ``t``."""
        with self._lock:
            self._frames += 1
            slots = 1
            if self._last_arrival is not None:
                slots = max(1, round((t - self._last_arrival) * self.rate_hz))
            self._last_arrival = t
            self._dropouts += slots - 1
            self._slot += slots
            body = bodies.get(self.rigid_body) if hasattr(bodies, "get") else None
            if body is None:
                self._missing += 1
                self._dropouts += 1
                return
            r = body.rotation
            pos, q, yaw = convert_pose(body.position, r.w, r.x, r.y, r.z, self.up_axis)
            key = (pos, q)
            if self.freeze_detect and key == self._last_key:
                self._repeats += 1
            else:
                self._seq = self._slot
                self._last_new = t
                self._rate.add(t)
            self._last_key = key
            self._samples += 1
            self._queue.append((t, PoseSample(0.0, *pos, q, yaw, self._seq)))
