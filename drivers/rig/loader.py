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
from drivers.settings import ConfigError
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


def load_rig(path: str | None = None, overrides: dict[str, str] | None = None) -> Rig:
    """Load and validate a rig file (None -> the repo's ``rigs/sim.yaml``), apply overrides.

    ``world.path`` and ``world.scan_pallet`` are rig settings; any other ``world.KEY`` is a
    key of the world file (``world.scan_slot.y_m=0.15``, ``world.placement_error.yaw_deg=10``)
    applied when the world is loaded, with the world's own checks.

    The world file is validated too, so a bad world is reported before anything flies.
    """
    path = path or DEFAULT_RIG
    data = load_yaml_file(path, RIG_SCHEMA, what="rig files")
    rig_keys = RIG_SCHEMA.children["world"].children
    world_over = {
        k[len("world.") :]: v
        for k, v in (overrides or {}).items()
        if k.startswith("world.") and k.split(".")[1] not in rig_keys
    }
    rest = {k: v for k, v in (overrides or {}).items() if k[len("world.") :] not in world_over}
    data = apply_overrides(data, rest)
    rig = Rig(data, path, world_over)
    if rig.kind == "sim":
        rig.load_world()  # world checks (and the scan pallet) before anything flies
    return rig
