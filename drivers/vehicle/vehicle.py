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

import math
from collections.abc import Sequence

from drivers.vehicle.angles import path_facing_yaw_rad, wrap_angle_rad, yaw_error_rad
from drivers.vehicle.battery import percent_from_voltage
from drivers.vehicle.config import VehicleConfig
from drivers.vehicle.gate import GatedMotion, MotionGate
from drivers.vehicle.health import HealthTracker
from drivers.vehicle.interfaces import CameraSource, Link, LinkTelemetry, PoseSample, PoseSource
from drivers.vehicle.progress import MotionProgress
from drivers.vehicle.trajectory import (
    Limits,
    LineReference,
    PathReference,
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
    YawMode,
)

AIRBORNE = (FlightState.TAKING_OFF, FlightState.FLYING, FlightState.LANDING)
LAND_PRESS_MPS = 0.1  # descent speed asked for below the touch-down height while landing


class Vehicle:
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
        self._gated: GatedMotion | None = None  # the current gated motion (running or waiting)
        self.waits = 0  # motions that had to wait at the gate
        self.pauses = 0  # motions paused by a supervisor
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

    def takeoff(self, height_m: float = 1.0, speed_mps: float = 0.5) -> MotionProgress:
        """Climb ``height_m`` above the current position at ``speed_mps``.

        Refused (a failed progress, nothing sent) for a non-finite or non-positive height or
        speed, or a goal above ``control.max_altitude_m``.
        """
        p, yaw = self.position, self.yaw_rad
        why = _bad_numbers(height_m=height_m, speed_mps=speed_mps) or _not_positive(
            height_m=height_m, speed_mps=speed_mps
        )
        if why is None and p[2] + height_m - self._ground_ref_z() > self.config.max_altitude_m:
            why = (
                f"height_m={height_m!r} would climb above control.max_altitude_m="
                f"{self.config.max_altitude_m:g} m"
            )
        if why is not None:
            return self._refused("takeoff", why)
        goal = (p[0], p[1], p[2] + height_m)
        progress = self._new_motion("takeoff", goal, yaw, None, None, None)
        if self.flight_state in AIRBORNE:
            progress.fail("already flying")
            return progress
        if self.flight_state == FlightState.CRASHED:
            progress.fail("crashed")
            return progress
        if not self.is_armed:
            if not self.config.auto_arm:
                progress.fail("not armed")
                return progress
            self.arm()
        limits = self._limits(speed_mps)

        def begin(start: tuple[float, float, float], yaw0: float, t0: float) -> Reference:
            self._ground_z = start[2]
            self._flight_start_s = t0
            self.flight_state = FlightState.TAKING_OFF
            return LineReference(start, goal, yaw0, yaw0, limits, t0)

        self._launch(GatedMotion(progress, "takeoff", goal, yaw, limits, begin))
        return progress

    def go_to(
        self,
        x_m: float,
        y_m: float,
        z_m: float,
        yaw_mode: YawMode | int = YawMode.KEEP_YAW,
        yaw_rad: float = 0.0,
        speed_mps: float = 0.5,
        *,
        position_tolerance_m: float | None = None,
        yaw_tolerance_rad: float | None = None,
        timeout_s: float | None = None,
    ) -> MotionProgress:
        """Fly a straight line to (x, y, z) with a yaw chosen by ``yaw_mode``.

        PATH_FACING is computed at activation (current yaw kept if the horizontal distance is
        below 0.1 m); yaw always turns the shortest way. Refused (a failed progress, the
        current motion goes on) for non-finite numbers, a non-positive speed or tolerance, or a
        goal above ``control.max_altitude_m``.
        """
        why = _bad_motion(
            speed_mps, yaw_rad, position_tolerance_m, yaw_tolerance_rad, timeout_s,
            x_m=x_m, y_m=y_m, z_m=z_m,
        )  # fmt: skip
        if why is None:
            why = self._above_ceiling(float(z_m))
        if why is not None:
            return self._refused("go_to", why)
        start, start_yaw = self._start_state()
        goal = (float(x_m), float(y_m), float(z_m))
        goal_yaw = self._goal_yaw(YawMode(int(yaw_mode)), yaw_rad, start, goal, start_yaw)
        progress = self._new_motion(
            "go_to", goal, goal_yaw, position_tolerance_m, yaw_tolerance_rad, timeout_s
        )
        if self._refuse_unless_flying(progress):
            return progress
        limits = self._limits(speed_mps)
        self._launch(
            GatedMotion(
                progress,
                "go_to",
                goal,
                goal_yaw,
                limits,
                lambda s0, y0, t0: LineReference(s0, goal, y0, goal_yaw, limits, t0),
            )
        )
        return progress

    def follow_path(
        self,
        waypoints: Sequence[Sequence[float]],
        speed_mps: float = 0.5,
        yaw_mode: YawMode | int = YawMode.KEEP_YAW,
        yaw_rad: float = 0.0,
        *,
        position_tolerance_m: float | None = None,
        yaw_tolerance_rad: float | None = None,
        timeout_s: float | None = None,
    ) -> MotionProgress:
        """Fly through ``waypoints`` [(x, y, z), ...] at one speed profile along the path
        (refused like :meth:`go_to` for bad numbers)."""
        coords = {f"waypoints[{i}][{j}]": w[j] for i, w in enumerate(waypoints) for j in range(3)}
        why = _bad_motion(
            speed_mps, yaw_rad, position_tolerance_m, yaw_tolerance_rad, timeout_s, **coords
        )
        if why is None:
            why = next(
                (w for w in (self._above_ceiling(float(p[2])) for p in waypoints) if w), None
            )
        if why is not None:
            return self._refused("follow_path", why)
        start, start_yaw = self._start_state()
        points = [start] + [(float(w[0]), float(w[1]), float(w[2])) for w in waypoints]
        mode = YawMode(int(yaw_mode))
        yaws, yaw = [], start_yaw
        for a, b in zip(points, points[1:], strict=False):
            yaw = self._goal_yaw(mode, yaw_rad, a, b, yaw)
            yaws.append(yaw)
        progress = self._new_motion(
            "follow_path",
            points[-1],
            yaws[-1] if yaws else start_yaw,
            position_tolerance_m,
            yaw_tolerance_rad,
            timeout_s,
        )
        if not waypoints:
            progress.fail("empty path")
            return progress
        if self._refuse_unless_flying(progress):
            return progress
        limits = self._limits(speed_mps)
        rest = points[1:]
        self._launch(
            GatedMotion(
                progress,
                "follow_path",
                points[-1],
                yaws[-1],
                limits,
                lambda s0, y0, t0: PathReference([s0, *rest], yaws, y0, limits, t0),
                path=rest,
            )
        )
        return progress

    def hover(self) -> MotionProgress:
        """Stop smoothly (acceleration-limited) and hold position and yaw."""
        return self.stop()

    def stop(self) -> MotionProgress:
        """Cancel the current motion: decelerate at the acceleration limit and hold."""
        start, yaw = self._start_state()
        r = self._ref_sample
        vel = (r.vx_mps, r.vy_mps, r.vz_mps) if r is not None and self._ref else (0, 0, 0)
        ref = StopReference(start, vel, yaw, self._limits(None), self.now_s)
        progress = self._new_motion("hold", ref.goal, yaw, None, None, None)
        if self._refuse_unless_flying(progress):
            return progress
        self._ref = ref
        return progress

    def land(self, speed_mps: float = 0.5) -> MotionProgress:
        """Descend to the take-off height at ``speed_mps``, then stop the motors. A bad speed
        (non-finite, not positive) lands at the default 0.5 m/s instead: a landing is never
        refused."""
        if _bad_numbers(speed_mps=speed_mps) or _not_positive(speed_mps=speed_mps):
            speed_mps = 0.5
        start, yaw = self._start_state()
        goal = (start[0], start[1], self._ground_z)
        progress = self._new_motion("land", goal, yaw, None, None, None)
        if self._refuse_unless_flying(progress):
            return progress
        self._ref = LineReference(start, goal, yaw, yaw, self._limits(speed_mps), self.now_s)
        self.flight_state = FlightState.LANDING
        self._touchdown_since = None
        return progress

    def emergency_stop(self) -> None:
        """Cut the motors now (the drone falls). The current motion fails."""
        self.link.emergency_stop()
        if self._motion is not None:
            self._motion.fail("emergency stop")
        self._ref = None
        if self.flight_state != FlightState.CRASHED:
            self.flight_state = FlightState.EMERGENCY

    def pause(self, reason: str) -> bool:
        """Stop the running take-off, go-to or path at the acceleration limit and hold,
        keeping the request alive (its progress says ``waiting``); :meth:`resume` sends it
        on. For a supervisor keeping drones apart. False if there is nothing to pause."""
        gm = self._gated
        if (
            gm is None
            or gm.paused
            or not gm.progress.active
            or gm.progress.reached
            or self.flight_state not in (FlightState.FLYING, FlightState.TAKING_OFF)
        ):
            return False
        gm.make = gm.restart(self._ref)
        gm.paused = True
        gm.progress.waiting = f"paused: {reason}"
        self.pauses += 1
        self._hold()
        return True

    def resume(self) -> bool:
        """Send a paused motion on (through the gate again) from where the drone is."""
        gm = self._gated
        if gm is None or not gm.paused:
            return False
        gm.paused = False
        if gm.progress.active:
            self._try_start(gm)
        return True

    @property
    def paused(self) -> bool:
        """True while a supervisor holds the current motion."""
        return self._gated is not None and self._gated.paused

    # ------------------------------------------------------------------ loop
    def update(self, t_s: float) -> None:
        """Run every control step due up to mission time ``t_s`` (for asynchronous links)."""
        period = self.config.period_s
        while self._next_step_s <= t_s + 1e-9:
            self.control_step(self._next_step_s)
            self._next_step_s += period

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
    def _refused(self, kind: str, why: str) -> MotionProgress:
        """A failed progress for a refused request; the current motion is left alone."""
        self.refused_requests += 1
        pose = self.pose
        progress = MotionProgress(
            kind=kind,
            goal=pose.position,
            goal_yaw_rad=pose.yaw_rad,
            position_tolerance_m=self.config.position_tolerance_m,
            yaw_tolerance_rad=self.config.yaw_tolerance_rad,
            started_s=self.now_s,
            settle_time_s=self.config.settle_time_s,
        )
        progress.fail(f"refused: {why}")
        return progress

    def _ground_ref_z(self) -> float:
        return self._ground_z if self.flight_state in AIRBORNE else self.position[2]

    def _above_ceiling(self, z_m: float) -> str | None:
        ceiling = self._ground_ref_z() + self.config.max_altitude_m
        if z_m > ceiling:
            return f"z={z_m:g} m is above control.max_altitude_m ({ceiling:g} m here)"
        return None

    def _hold_here(self, why: str) -> None:
        """Never send a non-finite set-point: hold at the measured pose instead."""
        self.refused_setpoints += 1
        if self._motion is not None and self._motion.active:
            self._motion.fail(f"refused: {why}")
        pose = self.pose
        self._ref = StopReference(pose.position, (0.0, 0.0, 0.0), pose.yaw_rad,
                                  self._limits(None), self.now_s)  # fmt: skip

    def _limits(self, speed_mps: float | None) -> Limits:
        c = self.config
        speed = c.max_speed_mps if speed_mps is None else min(float(speed_mps), c.max_speed_mps)
        return Limits(
            max(speed, 1e-3),
            c.accel_mps2,
            math.radians(c.yaw_rate_dps),
            math.radians(c.yaw_accel_dps2),
        )

    def _start_state(self) -> tuple[tuple[float, float, float], float]:
        """Where a new reference starts: the current reference if any, else the pose."""
        r = self._ref_sample
        if r is not None and self._ref is not None and self.flight_state in AIRBORNE:
            if all(math.isfinite(v) for v in (*r.position, r.yaw_rad)):
                return r.position, r.yaw_rad
        pose = self.pose
        return pose.position, pose.yaw_rad

    def _goal_yaw(self, mode: YawMode, yaw_rad: float, start, goal, current: float) -> float:
        if mode == YawMode.FIXED_YAW:
            return wrap_angle_rad(float(yaw_rad))
        if mode == YawMode.PATH_FACING:
            return path_facing_yaw_rad(start, goal, current, self.config.path_facing_min_distance_m)
        return current

    def _launch(self, gm: GatedMotion) -> None:
        """Start a motion through the gate (or leave it waiting there)."""
        self._gated = gm
        self._try_start(gm)

    def _try_start(self, gm: GatedMotion) -> bool:
        """Ask the gate; start ``gm``'s reference from here if it may go, else hold."""
        start, yaw = self._start_state()
        why = self.motion_gate(self.name, gm.kind, start, gm.goal) if self.motion_gate else ""
        if why:
            if not gm.progress.waiting:
                self.waits += 1
            gm.progress.waiting = why
            self._hold()
            return False
        gm.progress.waiting = ""
        self._ref = gm.make(start, yaw, self.now_s)
        return True

    def _hold(self) -> None:
        """In the air: stop at the acceleration limit and hold (a waiting motion)."""
        if self.flight_state not in AIRBORNE or isinstance(self._ref, StopReference):
            return
        start, yaw = self._start_state()
        r = self._ref_sample
        vel = (r.vx_mps, r.vy_mps, r.vz_mps) if r is not None and self._ref else (0, 0, 0)
        self._ref = StopReference(start, vel, yaw, self._limits(None), self.now_s)

    def _new_motion(self, kind, goal, goal_yaw, pos_tol, yaw_tol, timeout_s) -> MotionProgress:
        c = self.config
        self._gated = None  # a new request replaces a waiting or paused one
        if self._motion is not None:
            self._motion.cancel(f"replaced by {kind}")
        self._motion = MotionProgress(
            kind=kind,
            goal=tuple(goal),
            goal_yaw_rad=goal_yaw,
            position_tolerance_m=c.position_tolerance_m if pos_tol is None else pos_tol,
            yaw_tolerance_rad=c.yaw_tolerance_rad if yaw_tol is None else yaw_tol,
            started_s=self.now_s,
            settle_time_s=c.settle_time_s,
            timeout_s=timeout_s,
        )
        return self._motion

    def _refuse_unless_flying(self, progress: MotionProgress) -> bool:
        if self.flight_state in AIRBORNE:
            self.flight_state = FlightState.FLYING
            return False
        progress.fail(f"not flying ({self.flight_state.value})")
        return True


#: Seconds of flight after which the load sag of the battery voltage is measured (the ~1 s
#: voltage filter has settled on the hover load by then).
SAG_SETTLE_S = 4.0


def _bad_motion(
    speed_mps: object,
    yaw_rad: object,
    position_tolerance_m: object,
    yaw_tolerance_rad: object,
    timeout_s: object,
    **coords: object,
) -> str | None:
    """Why a go-to or path request is refused (non-finite numbers; a speed, tolerance or
    time-out not above zero), or None."""
    limits = {
        "speed_mps": speed_mps,
        "position_tolerance_m": position_tolerance_m,
        "yaw_tolerance_rad": yaw_tolerance_rad,
        "timeout_s": timeout_s,
    }
    return _bad_numbers(yaw_rad=yaw_rad, **coords, **limits) or _not_positive(**limits)


def _bad_numbers(**values: object) -> str | None:
    """Why one of ``values`` (None: not given) is not a finite number, or None."""
    for name, v in values.items():
        if v is None:
            continue
        if isinstance(v, bool):
            return f"{name}={v!r} is not a number"
        try:
            f = float(v)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            return f"{name}={v!r} is not a number"
        if not math.isfinite(f):
            return f"{name}={v!r} is not finite"
    return None


def _not_positive(**values: object) -> str | None:
    """Why one of ``values`` (None: not given) is not above zero, or None."""
    for name, v in values.items():
        if v is not None and float(v) <= 0.0:  # type: ignore[arg-type]
            return f"{name}={v!r} must be above zero"
    return None
