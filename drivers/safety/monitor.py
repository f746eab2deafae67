"""The fault monitor: pure fault logic, fed one :class:`Observation` per tick.

It tracks which faults are active, since when, and decides when the supervisor must take over
(a fault whose grace period ran out, or any actionable fault once the tree has stopped
running while the drone is airborne). A fake clock is enough to test it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from drivers.safety.policies import FAULTS, LATCHED, SafetyConfig


@dataclass(frozen=True)
class Observation:
    """What the monitor sees at one tick. ``None`` means "not available / not monitored"."""

    t_s: float
    airborne: bool
    landing: bool = False
    crashed: bool = False
    link_ok: bool = True
    mocap_ok: bool | None = None
    camera_ok: bool | None = None
    battery_v: float | None = None
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tree_running: bool = True


@dataclass
class FaultRecord:
    """One detection of a fault: when it started, when it cleared (None: still active)."""

    fault: str
    t_s: float
    cleared_s: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly form."""
        return {
            "fault": self.fault,
            "t_s": round(self.t_s, 3),
            "cleared_s": None if self.cleared_s is None else round(self.cleared_s, 3),
        }


class FaultMonitor:
    """Pure fault logic: feed :meth:`update` one observation per tick."""

    def __init__(self, config: SafetyConfig) -> None:
        self.config = config
        self.since: dict[str, float] = {}  # active fault -> detection time
        self.history: list[FaultRecord] = []
        self._open: dict[str, FaultRecord] = {}

    def conditions(self, o: Observation) -> dict[str, bool]:
        """Which observed fault conditions hold in ``o`` (before latching)."""
        c = self.config
        up = o.airborne
        v = o.battery_v
        return {
            "crash": o.crashed,
            "battery_critical": up and v is not None and 0.0 < v < c.battery_critical_v,
            "link_lost": up and not o.link_ok,
            "geofence": up and c.geofence_enabled and not c.inside(o.position),
            "mocap_lost": up and o.mocap_ok is False,
            "battery_low": up and v is not None and 0.0 < v < c.battery_low_v,
            "camera_stalled": up and o.camera_ok is False,
        }

    def active(self) -> list[str]:
        """Active faults, most severe first."""
        return [f for f in FAULTS if f in self.since]

    def is_active(self, fault: str) -> bool:
        """True if ``fault`` is active (``any``: any fault at all)."""
        return bool(self.since) if fault == "any" else fault in self.since

    def actionable(self) -> list[str]:
        """Active faults whose policy does something (not ``report``), most severe first."""
        return [f for f in self.active() if self.config.policies[f].action != "report"]

    def update(self, o: Observation) -> str | None:
        """Update the fault states; return the fault to act on now, or None.

        The supervisor acts on the most severe actionable fault whose grace period is over, or
        at once on any actionable fault if the tree is no longer running while the drone is
        airborne. While the drone is landing (the tree is bringing it down) it waits, unless
        the policy cuts the motors.
        """
        for name, cond in self.conditions(o).items():
            if cond and name not in self.since:
                self.since[name] = o.t_s
                rec = FaultRecord(name, o.t_s)
                self.history.append(rec)
                self._open[name] = rec
            elif not cond and name in self.since and name not in LATCHED:
                del self.since[name]
                self._open.pop(name).cleared_s = o.t_s
        for name in self.actionable():
            pol = self.config.policies[name]
            if pol.action == "motors_off":
                return name
            if not o.airborne:
                continue
            if not o.tree_running:
                return name
            if o.landing:
                continue
            if o.t_s - self.since[name] >= pol.grace_s - 1e-9:
                return name
        return None
