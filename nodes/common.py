"""Shared port types and helpers for the drone leaves."""

from __future__ import annotations

import math
from typing import Any

from bt_engine.node import BTNode, NodeRuntimeError
from bt_engine.ports import EnumType
from bt_engine.spec import Loc, Problem

#: Aerostack2's yaw modes; names or integers are accepted in mission files.
YAW_MODE = EnumType("YawMode", {"KEEP_YAW": 0, "PATH_FACING": 1, "FIXED_YAW": 2})

CATEGORY_FLIGHT = "flight"
CATEGORY_CHECK = "checks"


def config_problems(exc: Any) -> list[Problem]:
    """The located problems of a settings error (a rig, world or fleet file's
    :class:`drivers.settings.ConfigError`), as the engine's :class:`Problem` s."""
    return [Problem(Loc(p.file, p.line, p.col), p.message) for p in exc.problems]


def limit_problems(node: BTNode, limits: Any) -> list[tuple[str, str]]:
    """``(port, message)`` for every numeric input of ``node`` outside its ``limits``
    (``(port, low, high, what it is)`` each), as a leaf's ``preflight`` returns them: the
    mission's value, its input's default or a ``--set``, refused before anything flies.
    A port not readable before flight (written in flight) is checked then."""
    out: list[tuple[str, str]] = []
    for port, lo, hi, what in limits:
        try:
            value = node.get_input(port)
        except Exception:  # noqa: BLE001 - written in flight: checked then
            continue
        if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
            continue
        if not (math.isfinite(value) and lo <= value <= hi):
            out.append((port, f"{port} {value!r}: expected {what}, {lo:g} to {hi:g}"))
    return out


def vehicle_of(node: BTNode) -> Any:
    """The vehicle a leaf flies, or a located error if the mission runs without one."""
    v = node.ctx.vehicle if node.ctx is not None else None
    if v is None:
        raise NodeRuntimeError(
            node, "needs a vehicle: run the mission with a rig (e.g. rigs/sim.yaml)"
        )
    return v


def is_realtime(node: BTNode) -> bool:
    """True when the mission runs on a wall clock (a real or SITL drone, ``--realtime``):
    then the drone does not wait for the tree, and slow work belongs off the tick thread."""
    clock = node.ctx.clock if node.ctx is not None else None
    return clock is not None and not getattr(clock, "is_simulated", True)


def angle_input(node: BTNode, rad_port: str, deg_port: str) -> float:
    """Read an angle given either in radians (``rad_port``) or degrees (``deg_port``)."""
    deg = node.get_input(deg_port)
    if deg is not None:
        return math.radians(deg)
    return node.get_input(rad_port)


def yaw_mode_value(name: str) -> int:
    """Integer of a yaw-mode name."""
    return YAW_MODE.value_of(name)
