"""Small pure angle maths: wrapping, shortest-way differences, path-facing yaw, quaternions."""

from __future__ import annotations

import math

TWO_PI = 2.0 * math.pi


def wrap_angle_rad(angle_rad: float) -> float:
    """Wrap an angle to [-pi, pi).

    >>> round(wrap_angle_rad(math.radians(190)), 6) == round(math.radians(-170), 6)
    True
    """
    return (angle_rad + math.pi) % TWO_PI - math.pi


def yaw_error_rad(target_rad: float, current_rad: float) -> float:
    """Shortest signed rotation from ``current_rad`` to ``target_rad``, in [-pi, pi).

    From +170 deg to -170 deg the answer is +20 deg, not -340 deg.
    """
    return wrap_angle_rad(target_rad - current_rad)


def path_facing_yaw_rad(
    start: tuple[float, float, float],
    goal: tuple[float, float, float],
    current_yaw_rad: float,
    min_distance_m: float = 0.1,
) -> float:
    """Yaw that faces from ``start`` to ``goal`` in the horizontal plane.

    If the horizontal distance is below ``min_distance_m`` the heading is ill-defined and the
    current yaw is kept (Aerostack2's PATH_FACING rule).
    """
    dx, dy = goal[0] - start[0], goal[1] - start[1]
    if math.hypot(dx, dy) < min_distance_m:
        return current_yaw_rad
    return math.atan2(dy, dx)


def quaternion_from_yaw(yaw_rad: float) -> tuple[float, float, float, float]:
    """Quaternion (qx, qy, qz, qw) of a pure rotation about z."""
    return (0.0, 0.0, math.sin(yaw_rad / 2.0), math.cos(yaw_rad / 2.0))


def quaternion_from_euler(
    roll_rad: float, pitch_rad: float, yaw_rad: float
) -> tuple[float, float, float, float]:
    """Quaternion (qx, qy, qz, qw) from ZYX Euler angles."""
    cr, sr = math.cos(roll_rad / 2), math.sin(roll_rad / 2)
    cp, sp = math.cos(pitch_rad / 2), math.sin(pitch_rad / 2)
    cy, sy = math.cos(yaw_rad / 2), math.sin(yaw_rad / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def yaw_from_quaternion(q: tuple[float, float, float, float]) -> float:
    """Yaw (rad) of a quaternion (qx, qy, qz, qw), ZYX convention."""
    qx, qy, qz, qw = q
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
