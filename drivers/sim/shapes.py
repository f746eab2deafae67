"""Solid shapes of the simulated world: oriented boxes (pallets, stands, racks, obstacles)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property


@dataclass(frozen=True)
class Box:
    """An oriented box (yaw only): centre, half sizes, yaw; ``name`` says what it is and
    ``material`` how the camera renderer draws it (``stand``: plain wood, ``steel_blue`` /
    ``steel_orange``: painted rack steel)."""

    name: str
    cx: float
    cy: float
    cz: float
    hx: float
    hy: float
    hz: float
    yaw_rad: float = 0.0
    material: str = "stand"

    def distance_m(self, x: float, y: float, z: float) -> float:
        """Distance from a point to the box (0 inside)."""
        dx, dy = x - self.cx, y - self.cy
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        lx, ly, lz = c * dx + s * dy, -s * dx + c * dy, z - self.cz
        ox = max(abs(lx) - self.hx, 0.0)
        oy = max(abs(ly) - self.hy, 0.0)
        oz = max(abs(lz) - self.hz, 0.0)
        return math.sqrt(ox * ox + oy * oy + oz * oz)

    @property
    def top_z(self) -> float:
        """Height of the box top."""
        return self.cz + self.hz

    @cached_property
    def reach_xy(self) -> tuple[float, float]:
        """Half sizes (x, y) of the box's axis-aligned bounds in the world."""
        c, s = abs(math.cos(self.yaw_rad)), abs(math.sin(self.yaw_rad))
        return c * self.hx + s * self.hy, s * self.hx + c * self.hy
