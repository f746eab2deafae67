"""Progress of a motion request, as returned by every Vehicle motion method."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class MotionProgress:
    """Live progress of one motion request (take-off, go-to, path, hover, land, stop).

    The Vehicle updates it at every control step; a leaf reads it at every tick:

    * ``distance_m``: distance still to go (to the goal; along the rest of a path).
    * ``yaw_error_rad``: goal yaw minus measured yaw, wrapped to [-pi, pi].
    * ``reference_done``: the smooth reference has arrived at the goal.
    * ``reached``: reference done and position and yaw errors inside the tolerances.
    * ``settled``: ``reached`` has held for ``settle_time_s``.
    * ``failed`` / ``reason``: the request cannot complete (not armed, link lost, crashed,
      emergency stop, time-out). ``cancelled``: a newer request replaced this one.
    * ``waiting``: why the motion holds instead of going ("" while it goes): the airspace of
      a fleet is taken, or a supervisor paused it (see :mod:`drivers.vehicle.gate`).
    """

    kind: str
    goal: tuple[float, float, float]
    goal_yaw_rad: float
    position_tolerance_m: float
    yaw_tolerance_rad: float
    started_s: float
    settle_time_s: float = 0.3
    timeout_s: float | None = None
    distance_m: float = math.inf
    yaw_error_rad: float = 0.0
    reference_done: bool = False
    reached: bool = False
    settled: bool = False
    failed: bool = False
    cancelled: bool = False
    reason: str = ""
    waiting: str = ""
    elapsed_s: float = 0.0
    reached_since_s: float | None = None

    @property
    def active(self) -> bool:
        """True while the request is still being executed (not failed or cancelled)."""
        return not (self.failed or self.cancelled)

    @property
    def succeeded(self) -> bool:
        """Alias of ``reached`` for leaves that think in success/failure."""
        return self.reached

    def fail(self, reason: str) -> None:
        """Mark the request failed (idempotent: the first reason is kept)."""
        if not self.failed and not self.cancelled:
            self.failed, self.reason = True, reason

    def cancel(self, reason: str) -> None:
        """Mark the request replaced by a newer one."""
        if not self.failed and not self.cancelled:
            self.cancelled, self.reason = True, reason

    def update(
        self, t_s: float, distance_m: float, yaw_error_rad: float, reference_done: bool
    ) -> None:
        """Refresh the figures (called by the Vehicle at each control step)."""
        if not self.active:
            return
        self.elapsed_s = t_s - self.started_s
        self.distance_m, self.yaw_error_rad = distance_m, yaw_error_rad
        self.reference_done = reference_done
        inside = (
            reference_done
            and distance_m <= self.position_tolerance_m
            and abs(yaw_error_rad) <= self.yaw_tolerance_rad
        )
        # Once reached, a request stays reached (leaves may read it a tick late); "settled"
        # needs the errors to stay inside the tolerances for settle_time_s.
        self.reached = self.reached or inside
        if inside:
            if self.reached_since_s is None:
                self.reached_since_s = t_s
            if t_s - self.reached_since_s >= self.settle_time_s:
                self.settled = True
        elif not self.settled:
            self.reached_since_s = None
        if self.timeout_s is not None and not self.reached and self.elapsed_s > self.timeout_s:
            self.fail(f"timeout after {self.timeout_s:.1f} s")
