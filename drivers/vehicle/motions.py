"""The motion requests of the :class:`~drivers.vehicle.vehicle.Vehicle`: take-off, go-to,
path, hover/stop, land, emergency stop, pause/resume, and their checks.

A mixin of the Vehicle (its state lives there): each request validates its numbers (refused
with a reason, nothing sent, for non-finite or out-of-envelope values), makes a
:class:`~drivers.vehicle.progress.MotionProgress` and a smooth reference
(:mod:`drivers.vehicle.trajectory`), through the fleet's motion gate
(:mod:`drivers.vehicle.gate`) for take-offs, go-tos and paths.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from drivers.vehicle.angles import path_facing_yaw_rad, wrap_angle_rad
from drivers.vehicle.gate import GatedMotion
from drivers.vehicle.progress import MotionProgress
from drivers.vehicle.trajectory import (
    Limits,
    LineReference,
    PathReference,
    Reference,
    StopReference,
)
from drivers.vehicle.types import FlightState, YawMode

AIRBORNE = (FlightState.TAKING_OFF, FlightState.FLYING, FlightState.LANDING)
#: a step aside (:meth:`MotionRequests.step_aside`) flies at this speed, m/s ...
ASIDE_SPEED_MPS = 0.5
#: ... and never lower than this above the ground, m
ASIDE_MIN_HEIGHT_M = 0.3


class MotionRequests:
    """Motion requests and their helpers, mixed into the Vehicle."""

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
        # another drone where this one would touch down (a fleet's airspace): beside it
        spot = None
        if self.land_spot is not None and self.flight_state in AIRBORNE:
            spot = self.land_spot(self.name, start, self._ground_z)
        if spot is not None:
            goal = (spot[0], spot[1], self._ground_z)
        progress = self._new_motion("land", goal, yaw, None, None, None)
        if self._refuse_unless_flying(progress):
            return progress
        limits = self._limits(speed_mps)
        if spot is None:
            self._ref = LineReference(start, goal, yaw, yaw, limits, self.now_s)
        else:  # over at this height, then down
            over = (goal[0], goal[1], start[2])
            self._ref = PathReference([start, over, goal], [yaw, yaw], yaw, limits, self.now_s)
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
        self._aside = None
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

    def way_ahead(self) -> list[tuple[float, float, float]]:
        """Where the current motion still goes: the drone's position, then the waypoints of
        its path not reached yet (or its goal), also while it waits or is paused; only the
        position when no motion is under way."""
        p = tuple(self.position)
        m, ref, gm = self._motion, self._ref, self._gated
        if m is None or not m.active or m.reached:
            return [p]
        if not m.waiting and isinstance(ref, PathReference):
            return [p, *ref.points[ref.segment_index + 1 :]]
        if m.waiting and gm is not None and gm.path is not None:
            return [p, *gm.path]
        return [p, tuple(m.goal)]

    @property
    def waiting_at_gate(self) -> bool:
        """True while the current take-off, go-to or path waits for the gate (not paused)."""
        gm = self._gated
        return gm is not None and not gm.paused and gm.progress.active and bool(gm.progress.waiting)

    @property
    def aside_goal(self) -> tuple[float, float, float] | None:
        """Where the drone steps aside to while its motion waits (:meth:`step_aside`)."""
        return self._aside if self.waiting_at_gate else None

    def step_aside(self, point: Sequence[float], speed_mps: float = ASIDE_SPEED_MPS) -> str:
        """While the current motion waits at the gate, fly straight to ``point`` at
        ``speed_mps`` and hold there, still waiting: the gate is asked again at every
        control step and the motion starts from wherever the drone then is. For an airspace
        breaking a mutual wait (two drones each holding where the other must pass).
        "" when the drone steps aside, else why not (nothing is changed then)."""
        if not self.waiting_at_gate:
            return "no motion waiting at the gate"
        if self.flight_state != FlightState.FLYING:
            return f"not flying ({self.flight_state.value})"
        q = tuple(float(v) for v in point)
        if len(q) != 3 or not all(math.isfinite(v) for v in q):
            return f"not a point: {point!r}"
        high = self._above_ceiling(q[2])
        if high:
            return high
        if q[2] - self._ground_z < ASIDE_MIN_HEIGHT_M:
            return f"z={q[2]:g} m is less than {ASIDE_MIN_HEIGHT_M:g} m above the ground"
        start, yaw = self._start_state()
        self._ref = LineReference(start, q, yaw, yaw, self._limits(speed_mps), self.now_s)
        self._aside = q
        self.asides += 1
        return ""

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
        way = [start, *(gm.path if gm.path is not None else [gm.goal])]
        why = self.motion_gate(self.name, gm.kind, way) if self.motion_gate else ""
        if why:
            if not gm.progress.waiting:
                self.waits += 1
            gm.progress.waiting = why
            if self._aside is None:  # stepping aside: fly on there (it holds at its end)
                self._hold()
            return False
        gm.progress.waiting = ""
        self._aside = None
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
        self._aside = None
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
