"""The platform for a real (or SITL) Crazyflie: cflib link + mocap + Vehicle, in real time.

Unlike the lock-step simulator, the drone does not wait for the tree. A control thread runs
:meth:`Vehicle.control_step` at ``control.rate_hz`` on the (wall) mission clock, so
set-points leave at a steady rate whatever the tick rate and whoever else steps the platform
(the safety supervisor's recovery loop calls ``before_tick`` on its own). The Vehicle is not
thread-safe, so :attr:`CrazyfliePlatform.vehicle` is a :class:`LockedVehicle`: every method
call and attribute read of the tree, the supervisor or a script takes the same lock as each
control step. If the process hangs, set-points stop and the firmware's watchdog levels the
drone after 0.5 s and stops the motors after 2 s: the safe failure.

The platform is built from injected parts (a :class:`CrazyflieLink` for any cflib URI, a
pose source, a camera, the fault injector); :mod:`drivers.rig.factory` reads a rig and
assembles them, so software in the loop is just another ``udp://`` URI here.

Camera: with ``aideck.enabled`` the AI-deck stream (:class:`drivers.crazyflie.aideck_stream.
AIDeckStream`) is the Vehicle's camera source: ``vehicle.camera_frame()`` returns its newest
frame, stamped with the mission time its header arrived and the Vehicle's pose at that time
(interpolated in :meth:`CrazyfliePlatform.pose_at`), and ``health.camera`` tracks it; while
the TCP stream is down the camera counts as disconnected (unhealthy at once, which the safety
supervisor reports as ``camera_stalled``), and a connected stream that stops sending goes
stale after ``control.camera_stale_s``. With ``crazyflie.sitl: true`` (or
``aideck.emulator: true``) the factory starts the AI-deck emulator in-process on a free
loopback port; in SITL it renders the simulated drone's true pose.

``shutdown`` lands (bounded by ``crazyflie.shutdown_max_s``), cuts the motors if the drone
is still flying and the link is up, then sends a stop set-point + ``notify_setpoint_stop``
and closes the link (then stops the camera stream and the SITL emulators, after taking the
ground truth).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from drivers.crazyflie.cflib_link import CrazyflieLink
from drivers.vehicle.battery import percent_from_voltage
from drivers.vehicle.config import VehicleConfig
from drivers.vehicle.faults import FaultInjector
from drivers.vehicle.interfaces import PoseSource
from drivers.vehicle.types import FlightState, Pose
from drivers.vehicle.vehicle import Vehicle

#: Longest wait at shutdown for the drone to confirm it disarmed.
DISARM_CONFIRM_S = 1.0


class LockedVehicle:
    """A :class:`Vehicle` whose every attribute read and method call holds ``lock``."""

    def __init__(self, vehicle: Vehicle, lock: threading.RLock) -> None:
        object.__setattr__(self, "_v", vehicle)
        object.__setattr__(self, "_lock", lock)

    def __getattr__(self, name: str) -> Any:
        with self._lock:
            attr = getattr(self._v, name)
        if not callable(attr):
            return attr
        lock = self._lock

        def call(*args: Any, **kw: Any) -> Any:
            with lock:
                return attr(*args, **kw)

        return call

    def __setattr__(self, name: str, value: Any) -> None:
        with self._lock:
            setattr(self._v, name, value)


class CrazyfliePlatform:
    """Implements :class:`drivers.vehicle.platform.Platform` over a :class:`CrazyflieLink`."""

    def __init__(
        self,
        link: CrazyflieLink,
        config: VehicleConfig,
        pose_source: PoseSource | None,
        clock: Any,
        shutdown_max_s: float = 15.0,
        truth: Callable[[], dict] | None = None,
        on_close: list[Callable[[], None]] | None = None,
        faults: FaultInjector | None = None,
        sitl: Any = None,
        camera: Any = None,
        camera_emulator: Any = None,
    ) -> None:
        self.link, self.clock, self.config = link, clock, config
        self.sitl = sitl  # the in-process SitlSession, if any (tests, benches)
        self.camera = camera  # the AIDeckStream, if any
        self.camera_emulator = camera_emulator  # the in-process AIDeckEmulator, if any
        self.created_monotonic_s = time.monotonic()
        self.connect_started_monotonic_s = self.created_monotonic_s  # from_rig: link.open()
        self.camera_ready_s: float | None = None  # creation -> first frame at the Vehicle
        self.camera_ready_monotonic_s: float | None = None
        self._poses: deque[Pose] = deque(maxlen=300)  # recent Vehicle poses for pose_at()
        self._lock = threading.RLock()
        self.raw_vehicle = Vehicle(link, config, pose_source, camera)
        self.vehicle: Any = LockedVehicle(self.raw_vehicle, self._lock)
        self.faults = faults or FaultInjector()
        self.shutdown_max_s = shutdown_max_s
        self._truth, self._on_close = truth, list(on_close or [])
        self.final_truth: dict | None = None
        self.shutdown_reason: str | None = None
        self.max_tracking_error_m = 0.0
        self.step_times: deque[float] = deque(maxlen=20_000)  # wall time of each control step
        self._stop = threading.Event()
        self._closed = False
        self._thread = threading.Thread(target=self._loop, name="cf-control", daemon=True)
        self._thread.start()
        if camera is not None:
            if getattr(camera, "pose_fn", None) is None:
                camera.pose_fn = self.pose_at
            start = getattr(camera, "start", None)
            if start is not None:
                start()

    # ------------------------------------------------------------------ control thread
    def _loop(self) -> None:
        period = self.config.period_s
        clock = self.clock
        next_t = clock.now()
        while not self._stop.is_set():
            next_t += period
            delay = next_t - clock.now()
            if delay > 5 * period:  # the clock was set back (WallClock.restart_at): resync
                next_t = clock.now() + period
                delay = period
            if delay > 0:
                if self._stop.wait(delay):
                    break
            elif delay < -5 * period:  # stalled (e.g. a long tick): resynchronise
                next_t = clock.now()
            with self._lock:
                if self._stop.is_set():
                    break
                self.step_times.append(time.monotonic())
                self._control(clock.now())

    def _control(self, t_s: float) -> None:
        v = self.raw_vehicle
        cam = self.camera
        if cam is not None:
            v.camera_health.connected = bool(getattr(cam, "connected", True))
        v.control_step(t_s)
        pose = v.pose
        if not self._poses or pose.t_s > self._poses[-1].t_s:
            self._poses.append(pose)
        if self.camera_ready_s is None and v.camera_health.samples > 0:
            self.camera_ready_monotonic_s = time.monotonic()
            self.camera_ready_s = self.camera_ready_monotonic_s - self.created_monotonic_s
        ref = v.reference
        if ref is not None and v.is_flying:
            err = math.dist(v.position, ref.position)
            self.max_tracking_error_m = max(self.max_tracking_error_m, err)

    def pose_at(self, t_s: float) -> Pose:
        """The Vehicle's pose at mission time ``t_s``: interpolated between the poses of the
        last 3 s (position linearly, yaw the short way); the newest pose if ``t_s`` is later,
        the oldest if earlier. Called by the camera stream under the Vehicle lock."""
        cur = self.raw_vehicle.pose
        hist = self._poses
        if not hist or t_s >= hist[-1].t_s:
            a = b = cur if not hist or cur.t_s >= hist[-1].t_s else hist[-1]
        elif t_s <= hist[0].t_s:
            a = b = hist[0]
        else:
            i = len(hist) - 1
            while i > 0 and hist[i - 1].t_s > t_s:
                i -= 1
            a, b = hist[i - 1], hist[i]
        if a is b or b.t_s <= a.t_s:
            return Pose(a.x_m, a.y_m, a.z_m, a.yaw_rad, a.quaternion, t_s, a.source)
        f = (t_s - a.t_s) / (b.t_s - a.t_s)
        yaw = a.yaw_rad + f * math.remainder(b.yaw_rad - a.yaw_rad, 2.0 * math.pi)
        near = a if f < 0.5 else b
        return Pose(
            a.x_m + f * (b.x_m - a.x_m),
            a.y_m + f * (b.y_m - a.y_m),
            a.z_m + f * (b.z_m - a.z_m),
            math.remainder(yaw, 2.0 * math.pi),
            near.quaternion,
            t_s,
            near.source,
        )

    def between_steps(self) -> Any:
        """The lock the control thread steps under: held, no step runs (a context manager)."""
        return self._lock

    def clock_shifted(self, dt_s: float) -> None:
        """The mission clock was moved by ``dt_s`` (set back to 0 at the first tick), with
        :meth:`between_steps` held: the Vehicle's times move with it and the pose history
        (on the old times) is dropped."""
        self.raw_vehicle.shift_time(dt_s)
        self._poses.clear()

    # ------------------------------------------------------------------ Platform protocol
    def before_tick(self, t_s: float) -> None:
        """Fire scheduled faults (the control thread runs the Vehicle on its own)."""
        if not self._closed:
            with self._lock:
                self.faults.update(t_s)

    def after_tick(self, t_s: float) -> None:
        """Nothing: set-points go out from the control thread."""

    def shutdown(self, reason: str) -> None:
        """Land if flying (bounded), stop the motors, close the link (idempotent)."""
        if self._closed:
            return
        self.shutdown_reason = reason
        v = self.vehicle
        with self._lock:
            if v.is_flying and v.flight_state != FlightState.LANDING:
                v.land(0.5)
        end = time.monotonic() + self.shutdown_max_s
        while v.is_flying and time.monotonic() < end and self.link.connected:
            time.sleep(0.02)
        with self._lock:
            if v.is_flying and self.link.connected:
                v.emergency_stop()
            if not v.is_flying and v.is_armed and self.link.connected:
                v.disarm()
        # The disarm request travels over the radio: wait (bounded) until the drone's own
        # telemetry says disarmed, so the ground truth (and the summary) see what was done.
        end = time.monotonic() + DISARM_CONFIRM_S
        while not v.arming_confirmed and self.link.connected and time.monotonic() < end:
            time.sleep(0.02)
        self._stop.set()
        self._thread.join(timeout=1.0)
        self._closed = True
        try:
            self.link.close()
        finally:
            if self._truth is not None:
                time.sleep(0.05)  # let the emulator apply the stop set-point
                self.final_truth = self._truth()
            for fn in self._on_close:
                fn()

    def control_periods_s(self) -> list[float]:
        """Wall-clock intervals between control steps (for jitter figures)."""
        t = list(self.step_times)
        return [b - a for a, b in zip(t, t[1:], strict=False)]

    def summary(self) -> dict:
        """End state: vehicle view, link health, SITL ground truth (if any)."""
        v = self.vehicle
        periods = sorted(self.control_periods_s())
        voltage_v = round(v.battery.voltage_v, 3)
        out: dict[str, Any] = {
            "state": v.flight_state.value,
            "landed": v.is_landed,
            "crashed": v.is_crashed,
            "armed": v.is_armed,
            "battery": {  # the measured voltage and its gauge reading (docs/vehicle.md)
                "voltage_v": voltage_v,
                "percent_from_voltage": round(percent_from_voltage(voltage_v), 1),
            },
            "link": self.link.health(),
            "control": {
                "steps": len(self.step_times),
                "period_p99_ms": round(1000 * periods[int(0.99 * (len(periods) - 1))], 3)
                if periods
                else None,
            },
            "faults": self.faults.summary(),
            "shutdown_reason": self.shutdown_reason,
        }
        if self.camera is not None:
            out["camera"] = self.camera_summary()
        truth = self.final_truth
        if truth is None and self._truth is not None and not self._closed:
            truth = self._truth()
        if truth is not None:
            out["sitl"] = truth
            out["landed"] = truth["landed"]
            out["crashed"] = truth["crashed"]
            out["max_tracking_error_m"] = round(self.max_tracking_error_m, 4)
        return out

    def telemetry_row(self) -> dict:
        """Vehicle state for the per-tick log, plus whether the radio link is up."""
        row = self.vehicle.telemetry_row()
        row["link"] = self.link.connected
        return row

    def connect_to_ready_s(self) -> float | None:
        """Seconds from ``link.open()`` to ready: link up (TOCs, parameters, logs) and, with a
        camera, its first frame at the Vehicle; None while the camera has sent nothing."""
        if self.camera is None:
            return self.link.connect_time_s
        if self.camera_ready_monotonic_s is None:
            return None
        return self.camera_ready_monotonic_s - self.connect_started_monotonic_s

    def camera_summary(self) -> dict[str, Any]:
        """Camera stream figures: frames, rate, drops, reconnects, latency, health."""
        st = self.camera.stats()
        h = self.vehicle.health.camera
        out: dict[str, Any] = {
            "frames": st.frames,
            "fps": round(st.fps, 2),
            "dropped": st.dropped,
            "corrupt": st.corrupt,
            "skipped_before_poll": st.skipped,
            "reconnects": st.reconnects,
            "latency_mean_ms": None
            if math.isnan(st.latency_mean_s)
            else round(1000 * st.latency_mean_s, 2),
            "last_error": st.last_error,
            "frames_at_vehicle": h.samples,
            "connect_to_ready_s": None if (r := self.connect_to_ready_s()) is None else round(r, 3),
        }
        emu = self.camera_emulator
        if emu is not None:
            out["emulator"] = {
                "frames_sent": emu.frames_sent,
                "slots_skipped": emu.slots_skipped,
                "render_ms_mean": round(1000 * emu.render_s_mean, 2),
                "render_ms_max": round(1000 * emu.render_s_max, 2),
            }
        return out
