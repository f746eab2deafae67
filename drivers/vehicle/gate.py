"""Motions that wait: a gate for the airspace of several drones, and pauses.

A :class:`~drivers.vehicle.vehicle.Vehicle` may be given a ``motion_gate``: a function
``gate(vehicle_name, kind, way) -> str`` asked before a take-off, go-to or path starts
(``way``: the points it would fly through, from where it starts to its goal, a path's
waypoints between); "" lets it start, any other text is why it must wait (e.g. another drone
holds the corridor). A waiting motion holds the drone where it is and is asked again at
every control step; its :class:`~drivers.vehicle.progress.MotionProgress` stays active and
says why in ``waiting``, so the leaf that asked simply takes longer (its own time-out still
applies). While it waits, the gate may have it step aside out of another drone's way
(``Vehicle.step_aside``); it then goes on from there.

A supervisor may also ``pause`` a running motion (two drones too close): the drone stops at
the acceleration limit and holds; ``resume`` sends it on from where it stands to the same
goal (through the path's waypoints not yet reached), through the gate again.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from drivers.vehicle.progress import MotionProgress
from drivers.vehicle.trajectory import Limits, LineReference, PathReference, Reference

Vec3 = tuple[float, float, float]
#: gate(vehicle name, motion kind, way: start .. goal) -> "" (go) or why it must wait
MotionGate = Callable[[str, str, list[Vec3]], str]
#: make(start, start yaw, t0) -> the motion's reference from there
MakeReference = Callable[[Vec3, float, float], Reference]


@dataclass
class GatedMotion:
    """A motion the gate has let through (or is asked for): what it needs to start again."""

    progress: MotionProgress
    kind: str
    goal: Vec3
    goal_yaw_rad: float
    limits: Limits
    make: MakeReference
    path: list[Vec3] | None = None  # a path's waypoints (after its start)
    paused: bool = False

    def restart(self, ref: Reference | None) -> MakeReference:
        """How to go on after a pause from wherever the drone then is: the rest of the path
        (the waypoints after the segment ``ref`` was on), else straight to the goal."""
        if self.path is not None and isinstance(ref, PathReference):
            rest = self.path[ref.segment_index :]
            yaws = ref.segment_yaws_rad[ref.segment_index :]
            lim = self.limits
            self.path = rest  # what the gate is asked for from now on

            def make_path(start: Vec3, yaw: float, t0: float) -> Reference:
                return PathReference([start, *rest], yaws, yaw, lim, t0)

            return make_path
        goal, goal_yaw, lim = self.goal, self.goal_yaw_rad, self.limits

        def make_line(start: Vec3, yaw: float, t0: float) -> Reference:
            return LineReference(start, goal, yaw, goal_yaw, lim, t0)

        return make_line
