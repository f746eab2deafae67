"""Reference generation: turn a motion request into a smooth, time-parameterised reference.

Pure maths, no I/O. A reference is sampled once per control step with :meth:`sample`; it
returns a :class:`RefSample` (position, velocity, yaw, yaw rate). Positions follow a
trapezoidal speed profile (speed and acceleration limited) along a straight line or a
polyline; yaw turns the shortest way with a trapezoidal profile (yaw-rate and yaw-acceleration
limited).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.vehicle.angles import wrap_angle_rad

Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class RefSample:
    """One reference sample: position (m), velocity (m/s), yaw (rad), yaw rate (rad/s).

    ``ax_mps2``.. is the reference acceleration (m/s^2): the Vehicle feeds it forward to
    make up for the lag of the firmware's velocity loop (see ``VehicleConfig.velocity_lead_s``).
    """

    x_m: float
    y_m: float
    z_m: float
    vx_mps: float
    vy_mps: float
    vz_mps: float
    yaw_rad: float
    yaw_rate_radps: float
    done: bool
    ax_mps2: float = 0.0
    ay_mps2: float = 0.0
    az_mps2: float = 0.0

    @property
    def position(self) -> Vec3:
        """The reference position (x, y, z) in metres."""
        return (self.x_m, self.y_m, self.z_m)


def trapezoid_duration_s(distance: float, speed_max: float, accel_max: float) -> float:
    """Time to travel ``distance`` from rest to rest with speed and acceleration limits."""
    if distance <= 0.0:
        return 0.0
    t_acc = speed_max / accel_max
    d_acc = 0.5 * accel_max * t_acc * t_acc
    if 2.0 * d_acc >= distance:  # triangular profile: never reaches speed_max
        return 2.0 * math.sqrt(distance / accel_max)
    return 2.0 * t_acc + (distance - 2.0 * d_acc) / speed_max


def trapezoid_profile(
    distance: float, speed_max: float, accel_max: float, t_s: float
) -> tuple[float, float]:
    """Distance travelled and speed at time ``t_s`` of a rest-to-rest trapezoidal move.

    Works for any non-negative ``distance`` (metres or radians); clamps at both ends.
    """
    s, v, _ = trapezoid_state(distance, speed_max, accel_max, t_s)
    return s, v


def trapezoid_state(
    distance: float, speed_max: float, accel_max: float, t_s: float
) -> tuple[float, float, float]:
    """Distance, speed and acceleration at ``t_s`` of a rest-to-rest trapezoidal move."""
    if distance <= 0.0 or t_s <= 0.0:
        return 0.0, 0.0, 0.0
    v_peak = min(speed_max, math.sqrt(distance * accel_max))
    t_acc = v_peak / accel_max
    d_acc = 0.5 * accel_max * t_acc * t_acc
    t_cruise = (distance - 2.0 * d_acc) / v_peak
    t_total = 2.0 * t_acc + t_cruise
    if t_s >= t_total:
        return distance, 0.0, 0.0
    if t_s < t_acc:
        return 0.5 * accel_max * t_s * t_s, accel_max * t_s, accel_max
    if t_s < t_acc + t_cruise:
        return d_acc + v_peak * (t_s - t_acc), v_peak, 0.0
    t_dec = t_total - t_s
    return distance - 0.5 * accel_max * t_dec * t_dec, accel_max * t_dec, -accel_max


def slew_yaw(
    yaw_rad: float,
    yaw_rate_radps: float,
    target_rad: float,
    rate_max: float,
    accel_max: float,
    dt_s: float,
) -> tuple[float, float]:
    """One step of a rate- and acceleration-limited yaw follower (shortest way).

    Returns the new (yaw, yaw rate). Used where the target changes during a motion (paths).
    """
    err = wrap_angle_rad(target_rad - yaw_rad)
    want = math.copysign(min(rate_max, math.sqrt(2.0 * accel_max * abs(err))), err)
    step = accel_max * dt_s
    rate = yaw_rate_radps + max(-step, min(step, want - yaw_rate_radps))
    if abs(err) < 1e-4 and abs(rate) < step:
        return wrap_angle_rad(target_rad), 0.0
    return wrap_angle_rad(yaw_rad + rate * dt_s), rate


@dataclass(frozen=True)
class Limits:
    """Motion limits shared by all references."""

    speed_mps: float = 0.5
    accel_mps2: float = 1.0
    yaw_rate_radps: float = math.radians(90.0)
    yaw_accel_radps2: float = math.radians(180.0)


class Reference:
    """Base class: a reference that starts at ``t0_s`` and can be sampled at any later time."""

    t0_s: float = 0.0
    goal: Vec3 = (0.0, 0.0, 0.0)
    goal_yaw_rad: float = 0.0
    duration_s: float = 0.0

    def sample(self, t_s: float) -> RefSample:
        """The reference at mission time ``t_s``."""
        raise NotImplementedError

    def remaining_m(self, position: Vec3) -> float:
        """Distance still to go from ``position`` (straight-line to the goal by default)."""
        return math.dist(position, self.goal)


class HoldReference(Reference):
    """Hold a fixed position and yaw."""

    def __init__(self, point: Vec3, yaw_rad: float, t0_s: float) -> None:
        self.t0_s, self.goal, self.goal_yaw_rad = t0_s, tuple(point), yaw_rad
        self._sample = RefSample(*self.goal, 0.0, 0.0, 0.0, yaw_rad, 0.0, True)

    def sample(self, t_s: float) -> RefSample:
        return self._sample


class LineReference(Reference):
    """Straight line from ``start`` to ``goal``; yaw from ``start_yaw`` the shortest way."""

    def __init__(
        self,
        start: Vec3,
        goal: Vec3,
        start_yaw_rad: float,
        goal_yaw_rad: float,
        limits: Limits,
        t0_s: float,
    ) -> None:
        self.t0_s, self.start, self.goal = t0_s, tuple(start), tuple(goal)
        self.limits = limits
        self.length_m = math.dist(start, goal)
        self._unit = (
            tuple((g - s) / self.length_m for s, g in zip(start, goal, strict=True))
            if self.length_m > 1e-9
            else (0.0, 0.0, 0.0)
        )
        self.start_yaw_rad = start_yaw_rad
        self.goal_yaw_rad = wrap_angle_rad(goal_yaw_rad)
        self.yaw_delta_rad = wrap_angle_rad(goal_yaw_rad - start_yaw_rad)
        self.duration_s = max(
            trapezoid_duration_s(self.length_m, limits.speed_mps, limits.accel_mps2),
            trapezoid_duration_s(
                abs(self.yaw_delta_rad), limits.yaw_rate_radps, limits.yaw_accel_radps2
            ),
        )

    def sample(self, t_s: float) -> RefSample:
        lim, tau = self.limits, t_s - self.t0_s
        s, v, acc = trapezoid_state(self.length_m, lim.speed_mps, lim.accel_mps2, tau)
        ux, uy, uz = self._unit
        a, w = trapezoid_profile(
            abs(self.yaw_delta_rad), lim.yaw_rate_radps, lim.yaw_accel_radps2, tau
        )
        sign = 1.0 if self.yaw_delta_rad >= 0 else -1.0
        sx, sy, sz = self.start
        return RefSample(
            sx + ux * s,
            sy + uy * s,
            sz + uz * s,
            ux * v,
            uy * v,
            uz * v,
            wrap_angle_rad(self.start_yaw_rad + sign * a),
            sign * w,
            tau >= self.duration_s,
            ux * acc,
            uy * acc,
            uz * acc,
        )


class PathReference(Reference):
    """Polyline through waypoints at one trapezoidal speed profile along the arc length.

    Speed is continuous along the path; direction changes at corners are left to the
    position loop to round off. ``segment_yaws_rad`` gives the target yaw of each segment;
    yaw follows it with :func:`slew_yaw` (the sampler must be called with increasing time).
    """

    def __init__(
        self,
        points: list[Vec3],
        segment_yaws_rad: list[float],
        start_yaw_rad: float,
        limits: Limits,
        t0_s: float,
    ) -> None:
        if len(points) < 2:
            raise ValueError("a path needs a start and at least one waypoint")
        self.t0_s, self.points, self.limits = t0_s, [tuple(p) for p in points], limits
        self.goal = self.points[-1]
        self.segment_yaws_rad = list(segment_yaws_rad)
        self.goal_yaw_rad = wrap_angle_rad(self.segment_yaws_rad[-1])
        self.seg_len = [math.dist(a, b) for a, b in zip(points, points[1:], strict=False)]
        self.cum = [0.0]
        for length in self.seg_len:
            self.cum.append(self.cum[-1] + length)
        self.length_m = self.cum[-1]
        self.duration_s = trapezoid_duration_s(self.length_m, limits.speed_mps, limits.accel_mps2)
        self._yaw, self._yaw_rate, self._last_t = start_yaw_rad, 0.0, t0_s
        self.segment_index = 0
        self._yaw_settled = False

    def _locate(self, s: float) -> int:
        i = self.segment_index
        while i < len(self.seg_len) - 1 and s > self.cum[i + 1]:
            i += 1
        return i

    def sample(self, t_s: float) -> RefSample:
        lim, tau = self.limits, t_s - self.t0_s
        s, v, acc = trapezoid_state(self.length_m, lim.speed_mps, lim.accel_mps2, tau)
        i = self.segment_index = self._locate(s)
        a, b, length = self.points[i], self.points[i + 1], self.seg_len[i]
        f = (s - self.cum[i]) / length if length > 1e-9 else 1.0
        u = [(bb - aa) / length if length > 1e-9 else 0.0 for aa, bb in zip(a, b, strict=True)]
        dt = max(0.0, t_s - self._last_t)
        self._last_t = t_s
        target = self.segment_yaws_rad[i]
        self._yaw, self._yaw_rate = slew_yaw(
            self._yaw, self._yaw_rate, target, lim.yaw_rate_radps, lim.yaw_accel_radps2, dt
        )
        yaw_done = abs(wrap_angle_rad(self.goal_yaw_rad - self._yaw)) < 1e-3
        return RefSample(
            a[0] + (b[0] - a[0]) * f,
            a[1] + (b[1] - a[1]) * f,
            a[2] + (b[2] - a[2]) * f,
            u[0] * v,
            u[1] * v,
            u[2] * v,
            self._yaw,
            self._yaw_rate,
            tau >= self.duration_s and yaw_done,
            u[0] * acc,
            u[1] * acc,
            u[2] * acc,
        )

    def remaining_m(self, position: Vec3) -> float:
        """Distance to the current segment's end plus the lengths of the segments after it."""
        i = self.segment_index
        return math.dist(position, self.points[i + 1]) + (self.length_m - self.cum[i + 1])


class StopReference(Reference):
    """Decelerate from ``velocity`` at the acceleration limit, then hold where it stops."""

    def __init__(
        self, start: Vec3, velocity: Vec3, yaw_rad: float, limits: Limits, t0_s: float
    ) -> None:
        self.t0_s, self.start, self.limits, self.goal_yaw_rad = t0_s, tuple(start), limits, yaw_rad
        speed = math.sqrt(sum(c * c for c in velocity))
        self._unit = tuple(c / speed for c in velocity) if speed > 1e-9 else (0.0, 0.0, 0.0)
        self.speed0 = speed
        self.duration_s = speed / limits.accel_mps2
        d = 0.5 * speed * self.duration_s
        self.goal = tuple(p + u * d for p, u in zip(self.start, self._unit, strict=True))

    def sample(self, t_s: float) -> RefSample:
        tau = min(max(0.0, t_s - self.t0_s), self.duration_s)
        v = self.speed0 - self.limits.accel_mps2 * tau
        acc = -self.limits.accel_mps2 if tau < self.duration_s else 0.0
        s = self.speed0 * tau - 0.5 * self.limits.accel_mps2 * tau * tau
        ux, uy, uz = self._unit
        sx, sy, sz = self.start
        return RefSample(
            sx + ux * s,
            sy + uy * s,
            sz + uz * s,
            ux * v,
            uy * v,
            uz * v,
            self.goal_yaw_rad,
            0.0,
            t_s - self.t0_s >= self.duration_s,
            ux * acc,
            uy * acc,
            uz * acc,
        )
