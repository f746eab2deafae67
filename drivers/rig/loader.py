"""Rig files: what a mission flies on (link, control loop, sensors, world, faults).

``load_rig(path, overrides)`` validates a rig file (every problem located as
``file:line:col: message``, unknown keys with a "did you mean"), applies ``--set`` overrides
and returns a :class:`Rig`; ``drivers.rig.factory.make_platform(rig, clock, seed)`` builds the
platform the runner drives. :data:`~drivers.rig.schema.RIG_SCHEMA` declares every setting (docs/rig-settings.md).
"""

from __future__ import annotations

import os
from typing import Any

from drivers.rig.paths import DEFAULT_RIG, REPO_ROOT
from drivers.rig.schema import RIG_SCHEMA
from drivers.safety.policies import SafetyConfig
from drivers.settings import ConfigError, Marks, SettingProblem, problem_at, written_by
from drivers.settings import (
    apply_overrides as _apply,
)
from drivers.settings_yaml import load_yaml_file

__all__ = ["ConfigError", "Rig", "RIG_SCHEMA", "apply_overrides", "load_rig", "REPO_ROOT"]


def apply_overrides(config: dict, overrides: dict[str, str] | None) -> dict:
    """Apply ``--set dotted.key=value`` overrides to validated rig data (type-checked).

    Raises :class:`ConfigError` (all problems at once; unknown keys with "did you mean").
    """
    return _apply(config, overrides, RIG_SCHEMA)


class Rig:
    """A validated rig: ``kind`` (link kind), ``data`` (settings), ``path`` (file)."""

    def __init__(self, data: dict, path: str, world_overrides: dict | None = None) -> None:
        self.data, self.path = data, path
        self.kind: str = data["link"]
        #: ``--set world.KEY=VALUE`` items for keys of the world file (``scan_slot.y_m``)
        self.world_overrides: dict[str, str] = dict(world_overrides or {})

    @property
    def realtime_factor(self) -> float | None:
        """Mission seconds per wall second when the rig asks for real time, else None."""
        clock = self.data.get("clock", {})
        return float(clock.get("realtime_factor", 1.0)) if clock.get("mode") == "realtime" else None

    def load_world(self, seed: int = 0) -> Any:
        """The rig's world (:class:`drivers.sim.world.World`), with ``world.scan_pallet``
        (which pallet side stands at the scan slot) and the ``--set world.KEY`` overrides
        applied; ``seed`` draws the world's placement error."""
        from drivers.sim.world import load_world

        overrides = dict(self.world_overrides)
        if self.data["world"]["scan_pallet"] is not None:
            overrides["scan_pallet"] = self.data["world"]["scan_pallet"]
        return load_world(self.world_path, overrides, seed)

    @property
    def world_path(self) -> str:
        """The world file, resolved relative to the rig file (then cwd, then the repo)."""
        p = self.data["world"]["path"]
        if os.path.isabs(p):
            return p
        for base in (os.path.dirname(os.path.abspath(self.path)), os.getcwd(), REPO_ROOT):
            candidate = os.path.normpath(os.path.join(base, p))
            if os.path.exists(candidate):
                return candidate
        return os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(self.path)), p))


def load_rig(
    path: str | None = None, overrides: dict[str, str] | None = None, own_start: bool = True
) -> Rig:
    """Load and validate a rig file (None -> the repo's ``rigs/sim.yaml``), apply overrides.

    ``world.path`` and ``world.scan_pallet`` are rig settings; any other ``world.KEY`` is a
    key of the world file (``world.scan_slot.y_m=0.15``, ``world.placement_error.yaw_deg=10``)
    applied when the world is loaded, with the world's own checks.

    The world file is validated too, so a bad world is reported before anything flies.
    ``own_start=False`` leaves out the check that ``sim.start_m`` lies inside the geofence
    (a fleet's drones start on pads of their own, checked where the fleet file names them).
    """
    path = path or DEFAULT_RIG
    marks: Marks = {}
    data = load_yaml_file(path, RIG_SCHEMA, marks=marks, what="rig files")
    _check_rig(data, marks, path, {}, own_start)
    rig_keys = RIG_SCHEMA.children["world"].children
    world_over = {
        k[len("world.") :]: v
        for k, v in (overrides or {}).items()
        if k.startswith("world.") and k.split(".")[1] not in rig_keys
    }
    rest = {k: v for k, v in (overrides or {}).items() if k[len("world.") :] not in world_over}
    data = apply_overrides(data, rest)
    if rest:
        _check_rig(data, marks, path, rest, own_start)
    rig = Rig(data, path, world_over)
    if rig.kind == "sim":
        if not os.path.lexists(rig.world_path):  # said at the rig's line, not the missing file's
            p = data["world"]["path"]
            message = (
                f"world.path {p!r}: no such world file (looked beside the rig, in the working "
                "directory and in btrun's folder)"
            )
            raise ConfigError(
                [
                    SettingProblem("--set", 0, 0, message)
                    if written_by("world.path", rest)
                    else problem_at(marks, "world.path", path, message)
                ]
            )
        rig.load_world()  # world checks (and the scan pallet) before anything flies
    return rig


_FENCE = ("safety.geofence.min_m", "safety.geofence.max_m", "safety.geofence.enabled")


def rig_problems(data: dict, own_start: bool = True) -> list[tuple[tuple[str, ...], str]]:
    """``(keys, message)`` for what no single setting shows (``keys``: the settings that make
    it, located at the first): a geofence box whose minimum is not below its maximum on an
    axis, or a simulated drone that starts outside it (it would be in breach the moment it
    took off), a battery's critical level above its low one (the landing for low would
    never come first)."""
    rate = float(data["sim"]["physics_rate_hz"])
    if abs(rate / 100.0 - round(rate / 100.0)) > 1e-9:  # the firmware's 100 Hz loop steps
        return [  # a whole number of physics steps: 333 Hz ran it at another rate
            (
                ("sim.physics_rate_hz",),
                f"sim.physics_rate_hz {rate:g}: expected a multiple of 100 (the firmware's "
                "control loop runs at 100 Hz, a whole number of physics steps each)",
            )
        ]
    fence = SafetyConfig.from_dict(data["safety"])
    if fence.battery_critical_v >= fence.battery_low_v > 0.0:
        return [
            (
                ("safety.battery_critical_v", "safety.battery_low_v"),
                f"safety.battery_critical_v {fence.battery_critical_v:g} V must be below "
                f"battery_low_v {fence.battery_low_v:g} V (critical is the lower level)",
            )
        ]
    if not fence.geofence_enabled:
        return []
    lo, hi = fence.geofence_min_m, fence.geofence_max_m
    flat = [a for i, a in enumerate("xyz") if not lo[i] < hi[i]]
    if flat:
        return [
            (
                _FENCE,
                f"safety.geofence: min_m {list(lo)} must be below max_m {list(hi)} on every "
                f"axis (not on {', '.join(flat)})",
            )
        ]
    start = data["sim"]["start_m"]
    if own_start and data["link"] == "sim" and not fence.inside(tuple(start)):
        return [
            (
                ("sim.start_m", "link", *_FENCE),
                f"sim.start_m {list(start)}: the drone would start outside the geofence "
                f"({fence.box_words()}): expected a start inside it",
            )
        ]
    return []


def _check_rig(
    data: dict, marks: Marks, path: str, overrides: dict[str, str], own_start: bool
) -> None:
    """Raise :class:`ConfigError` with :func:`rig_problems`, located at the ``--set`` that
    wrote the key, else where the file wrote it (with the overrides named)."""
    problems = []
    for keys, message in rig_problems(data, own_start):
        if any(written_by(key, overrides) for key in keys):
            problems.append(SettingProblem("--set", 0, 0, message))
        else:
            given = ", ".join(f"--set {k}={v}" for k, v in overrides.items())
            where = problem_at(
                marks, keys[0], path, message + (f" (with {given})" if given else "")
            )
            problems.append(where)
    if problems:
        raise ConfigError(problems)
