"""What the runner drives: a Platform owns one Vehicle and everything behind it.

The runner ticks the tree on a mission clock and calls, every tick::

    clock.advance(period)               # lock-step; a WallClock just runs
    platform.before_tick(clock.now())   # step sim + Vehicle control loop up to now
    tree.tick()                         # leaves read and command platform.vehicle
    platform.after_tick(clock.now())

At the end ``platform.shutdown(reason)`` lands or stops the drone and ``platform.summary()``
gives the ground truth for ``summary.json`` (key ``sim``).
"""

from __future__ import annotations

from typing import Protocol

from drivers.vehicle.faults import FaultInjector
from drivers.vehicle.vehicle import Vehicle


class Platform(Protocol):
    """One vehicle plus its link, sensors and (for the simulator) world."""

    vehicle: Vehicle
    faults: FaultInjector

    def before_tick(self, t_s: float) -> None:
        """Bring everything up to mission time ``t_s`` (lock-step: step physics + control)."""

    def after_tick(self, t_s: float) -> None:
        """Called after the tree was ticked at ``t_s``."""

    def shutdown(self, reason: str) -> None:
        """Land (or stop) the drone; the simulator may keep stepping until landed (bounded)."""

    def summary(self) -> dict:
        """Ground truth and end state for ``summary.json``."""

    def telemetry_row(self) -> dict:
        """A small dict of vehicle state for the per-tick log."""
