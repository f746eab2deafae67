"""Conditions on the vehicle: IsFlying, IsAtPosition, IsYawWithin, BatteryAbove, IsHealthy.

Use them to guard actions, e.g. in a ReactiveSequence::

    ReactiveSequence
    ├── BatteryAbove percent=25
    └── GoTo pose=8.9;-0.5;0.255
"""

from __future__ import annotations

import math

from bt_engine.node import ConditionNode, NodeRuntimeError
from bt_engine.ports import BOOL, FLOAT, VEC3, input_port
from bt_engine.registry import register
from nodes.common import CATEGORY_CHECK, angle_input, vehicle_of


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@register
class IsFlying(ConditionNode):
    """SUCCESS while the drone is in the air (taking off, flying or landing)."""

    bt_id = "IsFlying"
    category = CATEGORY_CHECK

    def check(self) -> bool:
        return vehicle_of(self).is_flying


@register
class IsAtPosition(ConditionNode):
    """SUCCESS if the drone is within ``threshold`` metres of ``pose`` ("x;y;z")."""

    bt_id = "IsAtPosition"
    category = CATEGORY_CHECK
    ports = (
        input_port("pose", VEC3, description="position x;y;z in m"),
        input_port("threshold", FLOAT, 0.03, "distance tolerance in m"),
    )

    def check(self) -> bool:
        x, y, z = self.get_input("pose")
        px, py, pz = vehicle_of(self).position
        return math.dist((x, y, z), (px, py, pz)) <= self.get_input("threshold")


@register
class IsYawWithin(ConditionNode):
    """SUCCESS if the yaw is within ``threshold_deg`` of ``angle`` (rad) / ``angle_deg``.

    The error is wrapped to [-180, 180] degrees: +170 and -170 are 20 degrees apart.
    """

    bt_id = "IsYawWithin"
    category = CATEGORY_CHECK
    ports = (
        input_port("angle", FLOAT, 0.0, "yaw in rad"),
        input_port("angle_deg", FLOAT, None, "yaw in degrees (overrides angle)"),
        input_port("threshold_deg", FLOAT, 15.0, "tolerance in degrees"),
    )

    def check(self) -> bool:
        target = angle_input(self, "angle", "angle_deg")
        err = _wrap(target - vehicle_of(self).yaw_rad)
        return abs(math.degrees(err)) <= self.get_input("threshold_deg")


@register
class BatteryAbove(ConditionNode):
    """SUCCESS while the battery is above ``percent`` (0-100) or ``volts``; give one of them.

    ``percent`` is the Vehicle's state-of-charge estimate, corrected for the voltage sag under
    load (it does not drop when the motors spin up); ``volts`` is the measured (loaded)
    voltage. On FAILURE the reason gives the value read.
    """

    bt_id = "BatteryAbove"
    category = CATEGORY_CHECK
    ports = (
        input_port("percent", FLOAT, None, "minimum charge in %"),
        input_port("volts", FLOAT, None, "minimum voltage in V"),
    )

    def check(self) -> bool:
        pct, volts = self.get_input("percent"), self.get_input("volts")
        if (pct is None) == (volts is None):
            raise NodeRuntimeError(self, "give exactly one of 'percent' or 'volts'")
        b = vehicle_of(self).battery
        ok = b.percent > pct if pct is not None else b.voltage_v > volts
        self.failure_reason = (
            ""
            if ok
            else (
                f"battery at {b.percent:.1f} % (state of charge; {b.voltage_v:.2f} V under load), "
                f"not above {pct:g} %"
                if pct is not None
                else f"battery at {b.voltage_v:.2f} V (under load), not above {volts:g} V"
            )
        )
        return ok


@register
class IsHealthy(ConditionNode):
    """SUCCESS if the chosen sources are fresh: ``link`` and ``mocap`` (default), ``camera``."""

    bt_id = "IsHealthy"
    category = CATEGORY_CHECK
    ports = (
        input_port("link", BOOL, True, "require a fresh link"),
        input_port("mocap", BOOL, True, "require fresh motion capture"),
        input_port("camera", BOOL, False, "require a fresh camera stream"),
    )

    def check(self) -> bool:
        h = vehicle_of(self).health
        return all(
            getattr(h, name).healthy for name in ("link", "mocap", "camera") if self.get_input(name)
        )
