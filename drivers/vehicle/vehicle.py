"""The Vehicle API: what a mission leaf reads from and asks of one drone.

The Vehicle sits between the leaves and a :class:`~drivers.vehicle.interfaces.Link` (plus an optional
mocap :class:`~drivers.vehicle.interfaces.PoseSource` and :class:`~drivers.vehicle.interfaces.CameraSource`)::

    leaf --go_to()--> Vehicle --reference--> control step (rate_hz) --set-point--> Link
    leaf <--pose, progress, health-- Vehicle <--telemetry, mocap, frames-- sources

Motion requests never block: each returns a :class:`~drivers.vehicle.progress.MotionProgress` that the
control step refreshes. :meth:`control_step` (or :meth:`update`) must be called at the
control rate; the platform does it (lock-step: inside ``before_tick``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

from drivers.vehicle.angles import yaw_error_rad
from drivers.vehicle.battery import percent_from_voltage
from drivers.vehicle.config import VehicleConfig
from drivers.vehicle.gate import GatedMotion, MotionGate, Vec3
from drivers.vehicle.health import HealthTracker
from drivers.vehicle.interfaces import CameraSource, Link, LinkTelemetry, PoseSample, PoseSource
from drivers.vehicle.motions import AIRBORNE, MotionRequests
from drivers.vehicle.progress import MotionProgress
from drivers.vehicle.trajectory import (
    Reference,
    RefSample,
    StopReference,
)
from drivers.vehicle.types import (
    BatteryState,
    CameraFrame,
    FlightState,
    HealthReport,
    Pose,
    Velocity,
)

LAND_PRESS_MPS = 0.1  # descent speed asked for below the touch-down height while landing


class Vehicle(MotionRequests):
    """One drone as the mission sees it (see the module docstring and docs/vehicle.md)."""

    def __init__(
        self,
        link: Link,
        config: VehicleConfig | None = None,
        mocap: PoseSource | None = None,
        camera: CameraSource | None = None,
        name: str = "cf",
    ) -> None:
        self.name = name
        self.link, self.mocap, self.camera = link, mocap, camera
        self.config = config or VehicleConfig()
        c = self.config
        self.now_s = 0.0
        self.flight_state = FlightState.LANDED
        self.link_health = HealthTracker("link", c.link_stale_s)
        self.mocap_health = HealthTracker("mocap", c.mocap_stale_s)
        self.camera_health = HealthTracker("camera", c.camera_stale_s)
        self.mocap_health.connected = mocap is not None
        self.camera_health.connected = camera is not None
        self._telemetry: LinkTelemetry | None = None
        self._mocap: PoseSample | None = None
        self._mocap_seq = -1
        self._frame: CameraFrame | None = None
        self._ref: Reference | None = None
        self._ref_sample: RefSample | None = None
        self._motion: MotionProgress | None = None
        self._armed_cmd = False
        self._armed_cmd_s = -math.inf
        self._ground_z = 0.0
        self._flight_start_s = 0.0
        self._touchdown_since: float | None = None
        self._battery_v: float | None = None
        self._takeoff_v: float | None = None  # resting voltage just before take-off
        self._sag_v: float | None = None  # load sag measured early in the flight
        self._next_step_s = 0.0
        #: the airspace of a fleet: asked before a take-off, go-to or path starts (gate.py)
        self.motion_gate: MotionGate | None = None
        #: the airspace's landing spot (name, start, ground z) -> a spot beside, or None for
        #: straight down; a landing is never refused nor kept waiting (motions.land)
        self.land_spot: Callable[[str, Vec3, float], Vec3 | None] | None = None
        self._gated: GatedMotion | None = None  # the current gated motion (running or waiting)
        self.waits = 0  # motions that had to wait at the gate
        self.pauses = 0  # motions paused by a supervisor
        self._aside: tuple[float, float, float] | None = None  # stepping aside while waiting
        self.asides = 0  # steps aside out of another drone's way (gate.py)
        self.setpoints_sent = 0
        self.refused_requests = 0  # motion requests refused (non-finite, out of envelope)
        self.refused_setpoints = 0  # non-finite set-points held back (never sent)

    # ------------------------------------------------------------------ reading
    @property
    def pose(self) -> Pose:
        """Best pose: fresh mocap if configured and healthy, else the onboard estimate."""
        m = self._mocap
        if (
            m is not None
            and self.config.pose_source == "mocap"
            and self.now_s - self.mocap_health.last_new_s <= self.config.mocap_stale_s
        ):
            return Pose(m.x_m, m.y_m, m.z_m, m.yaw_rad, m.quaternion, m.t_s, "mocap")
        tel = self._telemetry
        if tel is not None:
            return Pose(tel.x_m, tel.y_m, tel.z_m, tel.yaw_rad, tel.quaternion, tel.t_s, "onboard")
        if m is not None:  # stale mocap is still better than nothing
            return Pose(m.x_m, m.y_m, m.z_m, m.yaw_rad, m.quaternion, m.t_s, "mocap")
        return Pose(0.0, 0.0, 0.0, 0.0)

    @property
    def position(self) -> tuple[float, float, float]:
        """Position (x, y, z) in metres."""
        return self.pose.position

    @property
    def yaw_rad(self) -> float:
        """Yaw in radians, [-pi, pi)."""
        return self.pose.yaw_rad

    @property
    def velocity(self) -> Velocity:
        """World-frame velocity from the onboard estimate."""
        tel = self._telemetry
        if tel is None:
            return Velocity()
        return Velocity(tel.vx_mps, tel.vy_mps, tel.vz_mps)

    @property
    def is_flying(self) -> bool:
        """True while taking off, flying or landing."""
        return self.flight_state in AIRBORNE

    @property
    def is_landed(self) -> bool:
        """True when on the ground with the motors stopped."""
        return self.flight_state == FlightState.LANDED

    @property
    def is_crashed(self) -> bool:
        """True after a crash (hard landing, collision, tumble)."""
        return self.flight_state == FlightState.CRASHED

    @property
    def is_armed(self) -> bool:
        """Armed state as reported by the drone (a newer request wins until confirmed)."""
        tel = self._telemetry
        if tel is None or self._armed_cmd_s >= tel.t_s:
            return self._armed_cmd
        return tel.armed

    @property
    def arming_confirmed(self) -> bool:
        """True once the drone's telemetry, newer than the last arm/disarm request, agrees."""
        tel = self._telemetry
        return tel is not None and tel.t_s > self._armed_cmd_s and tel.armed == self._armed_cmd

    @property
    def battery(self) -> BatteryState:
        """Battery voltage (filtered over ~1 s, as measured under load), state-of-charge
        estimate and low flag.

        ``percent`` does not sag under load: the Crazyflie reports only the loaded voltage,
        so in flight the Vehicle adds back the sag it measured over the first
        :data:`SAG_SETTLE_S` of the flight (resting voltage before take-off minus the hover
        voltage) and reads the open-circuit curve there (``sag_v`` is that estimate).
        """
        v = self._battery_v if self._battery_v is not None else 0.0
        sag = 0.0
        if self.flight_state in AIRBORNE and v > 0.0:
            if self._sag_v is not None:
                sag = self._sag_v
            elif self._takeoff_v is not None:
                sag = max(0.0, self._takeoff_v - v)  # settling: read as at take-off
        return BatteryState(
            v, percent_from_voltage(v + sag), 0.0 < v < self.config.low_battery_v, sag
        )

    @property
    def health(self) -> HealthReport:
        """Health of the link, the mocap and the camera at the current time."""
        t = self.now_s
        return HealthReport(
            t,
            self.link_health.report(t),
            self.mocap_health.report(t),
            self.camera_health.report(t),
        )

    def camera_frame(self) -> CameraFrame | None:
        """The latest camera frame (with capture time and pose at capture), or None."""
        return self._frame

    @property
    def reference(self) -> RefSample | None:
        """The reference sampled at the last control step (None before the first motion)."""
        return self._ref_sample

    @property
    def motion(self) -> MotionProgress | None:
        """Progress of the current motion request (None if none was made)."""
        return self._motion

    def telemetry_row(self) -> dict:
        """Vehicle state for the per-tick log (reported pose, reference, battery, state)."""
        p = self.pose
        r = self.reference
        row = {
            "x": round(p.x_m, 4),
            "y": round(p.y_m, 4),
            "z": round(p.z_m, 4),
            "yaw": round(p.yaw_rad, 4),
            "state": self.flight_state.value,
            "vbat": round(self.battery.voltage_v, 3),
        }
        if r is not None:
            row.update(
                ref_x=round(r.x_m, 4),
                ref_y=round(r.y_m, 4),
                ref_z=round(r.z_m, 4),
                ref_yaw=round(r.yaw_rad, 4),
            )
        return row

    # ------------------------------------------------------------------ asking
    def arm(self) -> bool:
        """Arm the motors. Returns True if the request was sent."""
        self._armed_cmd, self._armed_cmd_s = True, self.now_s
        return bool(self.link.arm(True))

    def disarm(self) -> bool:
        """Disarm; refused (False) while airborne."""
        if self.is_flying:
            return False
        self._armed_cmd, self._armed_cmd_s = False, self.now_s
        return bool(self.link.arm(False))

    def battery_service(self, kind: str) -> str:
        """Ask for a battery service on the ground: ``swap`` (a fresh battery), ``charge``
        or ``stop_charging`` (a charging pad's current). Returns "" when done, else why it
        cannot be done (in flight, the link cannot do it: a real battery is swapped by
        hand)."""
        if self.is_flying:
            return "the drone is flying: land first"
        service = getattr(self.link, "battery_service", None)
        if service is None:
            return "this link offers no battery service"
        why = service(kind)
        if not why and kind == "swap":
            # a new cell: forget the old one's filtered voltage and sag, read it afresh
            self._battery_v = self._sag_v = self._takeoff_v = None
        return why

    # ------------------------------------------------------------------ loop
    def update(self, t_s: float) -> None:
        """Run every control step due up to mission time ``t_s`` (for asynchronous links)."""
        period = self.config.period_s
        while self._next_step_s <= t_s + 1e-9:
            self.control_step(self._next_step_s)
            self._next_step_s += period

    def shift_time(self, dt_s: float) -> None:
        """Move every time the Vehicle keeps by ``dt_s``: the mission clock was set back to
        0 at the first tick (connecting and the preflight are not mission time). Called on
        the ground, between control steps (the platform's lock held), before any motion."""
        self.now_s += dt_s
        self._armed_cmd_s += dt_s
        self._flight_start_s += dt_s
        self._next_step_s += dt_s
        if self._touchdown_since is not None:
            self._touchdown_since += dt_s
        for h in (self.link_health, self.mocap_health, self.camera_health):
            h.shift(dt_s)
        for name in ("_telemetry", "_mocap", "_frame"):
            rec = getattr(self, name)
            if rec is not None:
                setattr(self, name, dataclasses.replace(rec, t_s=rec.t_s + dt_s))

    def control_step(self, t_s: float) -> None:
        """One control step: read sources, update state and progress, send a set-point."""
        self.now_s = t_s
        self._ingest(t_s)
        gm = self._gated
        if gm is not None and gm.progress.waiting and not gm.paused and gm.progress.active:
            self._try_start(gm)  # waiting at the gate: ask again
        self._update_flight_state(t_s)
        ref = self._ref.sample(t_s) if self._ref is not None else None
        self._ref_sample = ref
        self._update_progress(t_s, ref)
        if ref is not None and self.flight_state in AIRBORNE:
            self._send(ref)

    def _ingest(self, t_s: float) -> None:
        for tel in self.link.poll(t_s):
            self._telemetry = tel
            self.link_health.sample(t_s)
            v = tel.battery_v
            if self._battery_v is None and self._takeoff_v is None:
                self._takeoff_v = v  # the first sample: the motors have not loaded it yet
            self._battery_v = (
                v if self._battery_v is None else self._battery_v + 0.01 * (v - self._battery_v)
            )
        if self.flight_state in AIRBORNE:
            settled = t_s - self._flight_start_s >= SAG_SETTLE_S
            if self._sag_v is None and self._takeoff_v is not None and settled:
                self._sag_v = max(0.0, self._takeoff_v - (self._battery_v or 0.0))
        else:
            self._takeoff_v, self._sag_v = self._battery_v, None
        self.link_health.connected = self.link.connected
        if self.mocap is not None:
            for m in self.mocap.poll(t_s):
                fresh = m.seq > self._mocap_seq
                if fresh and self._mocap_seq >= 0 and m.seq > self._mocap_seq + 1:
                    self.mocap_health.drop(m.seq - self._mocap_seq - 1)
                self.mocap_health.sample(t_s, changed=fresh)
                if fresh:
                    self._mocap, self._mocap_seq = m, m.seq
                    self.link.send_external_pose(m.x_m, m.y_m, m.z_m, m.quaternion)
        if self.camera is not None:
            frame = self.camera.poll(t_s)
            if frame is not None:
                self._frame = frame
                self.camera_health.sample(t_s)

    def _update_flight_state(self, t_s: float) -> None:
        tel = self._telemetry
        if tel is not None and (tel.crashed or tel.tumbled):
            if self.flight_state != FlightState.CRASHED and self._motion is not None:
                self._motion.fail("crashed")
            self.flight_state = FlightState.CRASHED
            self._ref = None
            return
        state = self.flight_state
        link_ok = t_s - self.link_health.last_new_s <= self.config.link_stale_s
        if state in AIRBORNE and self._motion is not None and not link_ok:
            self._motion.fail("link lost")
        if state in AIRBORNE and tel is not None and link_ok and not tel.motors_running:
            # Motors stopped without our asking (firmware watchdog, supervisor).
            if t_s - self._flight_start_s > 0.5:
                if self._motion is not None:
                    self._motion.fail("motors stopped")
                self.flight_state, self._ref = FlightState.EMERGENCY, None
                return
        if state == FlightState.TAKING_OFF and self._motion is not None and self._motion.reached:
            self.flight_state = FlightState.FLYING
        if state == FlightState.LANDING and self._ref is not None and tel is not None:
            r = self._ref.sample(t_s)
            low = self.position[2] - self._ground_z < self.config.landed_height_m
            if r.done and low and abs(tel.vz_mps) < 0.1:
                if self._touchdown_since is None:
                    self._touchdown_since = t_s
                elif t_s - self._touchdown_since >= 0.2:
                    self.link.send_stop_setpoint()
                    self.flight_state, self._ref = FlightState.LANDED, None
                    if self._motion is not None:
                        self._motion.reached = self._motion.settled = True
                        self._motion.reference_done = True
            else:
                self._touchdown_since = None
        if state == FlightState.EMERGENCY and tel is not None and not tel.motors_running:
            if abs(tel.vz_mps) < 0.05 and self.position[2] - self._ground_z < 0.05:
                self.flight_state = FlightState.LANDED

    def _update_progress(self, t_s: float, ref: RefSample | None) -> None:
        m = self._motion
        if m is None or not m.active or ref is None or self._ref is None:
            return
        pose = self.pose
        if m.waiting:  # holding for the airspace or paused: the goal is still ahead
            m.update(
                t_s,
                math.dist(pose.position, m.goal),
                yaw_error_rad(m.goal_yaw_rad, pose.yaw_rad),
                False,
            )
            return
        if m.kind == "land":
            m.update(
                t_s,
                self._ref.remaining_m(pose.position),
                yaw_error_rad(m.goal_yaw_rad, pose.yaw_rad),
                False,
            )
            return
        m.update(
            t_s,
            self._ref.remaining_m(pose.position),
            yaw_error_rad(m.goal_yaw_rad, pose.yaw_rad),
            ref.done,
        )

    def _send(self, ref: RefSample) -> None:
        c = self.config
        if not all(
            math.isfinite(v)
            for v in (ref.x_m, ref.y_m, ref.z_m, ref.yaw_rad, ref.vx_mps, ref.vy_mps, ref.vz_mps)
        ):
            self._hold_here("non-finite reference")
            return
        self.setpoints_sent += 1
        # Feed-forward velocity: the reference velocity led by the firmware velocity loop's lag
        # (v_ref + lead * a_ref), so the drone's *actual* velocity follows v_ref.
        lead_xy, lead_z = c.velocity_lead_s, c.velocity_lead_z_s
        fx = ref.vx_mps + lead_xy * ref.ax_mps2
        fy = ref.vy_mps + lead_xy * ref.ay_mps2
        fz = ref.vz_mps + lead_z * ref.az_mps2
        # A landing never asks to climb, and below the touch-down height it presses down at
        # LAND_PRESS_MPS: the braking feed-forward near the floor would otherwise lift a
        # drone that touched down a little early back off the floor.
        landing = self.flight_state == FlightState.LANDING
        low = landing and self.position[2] - self._ground_z < c.landed_height_m
        if c.setpoint_mode == "velocity":
            x, y, z = self.position
            vx = fx + c.velocity_kp * (ref.x_m - x)
            vy = fy + c.velocity_kp * (ref.y_m - y)
            vz = fz + c.velocity_kp * (ref.z_m - z)
            if landing:
                vz = min(vz, -LAND_PRESS_MPS if low else 0.0)
            speed = math.sqrt(vx * vx + vy * vy + vz * vz)
            if speed > c.max_speed_mps:
                k = c.max_speed_mps / speed
                vx, vy, vz = vx * k, vy * k, vz * k
            rate = ref.yaw_rate_radps + c.yaw_kp * yaw_error_rad(ref.yaw_rad, self.yaw_rad)
            if not all(math.isfinite(v) for v in (vx, vy, vz, rate)):
                self._hold_here("non-finite velocity set-point")
                return
            self.link.send_velocity_setpoint(vx, vy, vz, rate)
            return
        # Position mode: the firmware sends v_sp = Kp * (sp - p); lead_s = 1 / Kp turns the
        # offset lead_s * (feed-forward velocity) into exactly that feed-forward velocity.
        lead = c.lead_s
        z_sp = ref.z_m + lead * fz
        if not all(math.isfinite(v) for v in (fx, fy, fz, z_sp)):
            self._hold_here("non-finite position set-point")
            return
        self.link.send_position_setpoint(
            ref.x_m + lead * fx,
            ref.y_m + lead * fy,
            min(z_sp, ref.z_m - (lead * LAND_PRESS_MPS if low else 0.0)) if landing else z_sp,
            ref.yaw_rad,
        )

    # ------------------------------------------------------------------ helpers
    def _hold_here(self, why: str) -> None:
        """Never send a non-finite set-point: hold at the measured pose instead."""
        self.refused_setpoints += 1
        if self._motion is not None and self._motion.active:
            self._motion.fail(f"refused: {why}")
        pose = self.pose
        self._ref = StopReference(pose.position, (0.0, 0.0, 0.0), pose.yaw_rad,
                                  self._limits(None), self.now_s)  # fmt: skip


#: Seconds of flight after which the load sag of the battery voltage is measured (the ~1 s
#: voltage filter has settled on the hover load by then).
SAG_SETTLE_S = 4.0
