"""Shared port types and helpers for the drone leaves."""

from __future__ import annotations

import math
from typing import Any

from bt_engine.node import BTNode, NodeRuntimeError
from bt_engine.ports import EnumType
from bt_engine.spec import Loc, Problem
from drivers.safety.policies import SafetyConfig

#: Aerostack2's yaw modes; names or integers are accepted in mission files.
YAW_MODE = EnumType("YawMode", {"KEEP_YAW": 0, "PATH_FACING": 1, "FIXED_YAW": 2})

CATEGORY_FLIGHT = "flight"
CATEGORY_CHECK = "checks"


def config_problems(exc: Any) -> list[Problem]:
    """The located problems of a settings error (a rig, world or fleet file's
    :class:`drivers.settings.ConfigError`), as the engine's :class:`Problem` s."""
    return [Problem(Loc(p.file, p.line, p.col), p.message) for p in exc.problems]


def geofence_config(node: BTNode) -> Any:
    """The rig's safety settings (:class:`drivers.safety.policies.SafetyConfig`) when its
    geofence is on, else None: the running supervisor's, or before flight the rig's own
    (``rig`` in the run's resources)."""
    resources = node.ctx.resources if node.ctx is not None else {}
    config = getattr(resources.get("safety"), "config", None)
    if config is None:
        data = getattr(resources.get("rig"), "data", None)
        if not isinstance(data, dict) or not isinstance(data.get("safety"), dict):
            return None
        config = SafetyConfig.from_dict(data["safety"])
    return config if getattr(config, "geofence_enabled", False) else None


def outside_geofence(
    node: BTNode, port: str, points: Any, what: str = "", margin_m: float = 0.0
) -> list[tuple[str, str]]:
    """``(port, message)`` for each of ``points`` (x;y;z goals a leaf will fly to) outside
    the rig's geofence (or within ``margin_m`` of its walls), as a leaf's ``preflight``
    returns them: a goal the safety supervisor would call a breach is refused before
    take-off, not flown into. ``what`` replaces the port's name and value in the message."""
    config = geofence_config(node)
    if config is None:
        return []
    box = config.box_words()
    pts = list(points)
    out = []
    for i, p in enumerate(pts):
        if len(p) != 3 or config.inside(tuple(float(v) for v in p), margin_m):
            continue
        shown = ";".join(f"{float(v):g}" for v in p)
        which = what or (
            f"{port} waypoint {i + 1} ({shown})" if len(pts) > 1 else f"{port} {shown}"
        )
        out.append((port, f"{which}: expected a point inside the rig's geofence ({box})"))
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
