"""The racks on the floor as obstacles: their footprints (:class:`Footprint`) and the
shortest route around them (:func:`route`: a visibility graph over the footprints' grown
corners, the geofence respected). Plain geometry over a world's ``racks``; the sweep's plan
(:mod:`nodes.sweep_plan`), its passes and the inventory's look points use it."""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import Any

#: keep this far from a rack's footprint when flying around it, m
CLEARANCE_M = 0.45
#: the corners a route turns at are this much further out than the clearance, m
CORNER_EXTRA_M = 0.15


@dataclass(frozen=True)
class Footprint:
    """A rack's footprint on the floor: a rectangle in the rack's frame (``origin``, unit
    ``right`` along the bays, unit ``inward`` into the rack), ``length`` x ``depth``."""

    name: str
    origin: tuple[float, float]
    right: tuple[float, float]
    inward: tuple[float, float]
    length: float
    depth: float

    def local(self, p: tuple[float, float]) -> tuple[float, float]:
        """(along, in) of a floor point."""
        dx, dy = p[0] - self.origin[0], p[1] - self.origin[1]
        return (
            dx * self.right[0] + dy * self.right[1],
            dx * self.inward[0] + dy * self.inward[1],
        )

    def world(self, along: float, inward: float) -> tuple[float, float]:
        """The floor point at (along, in)."""
        return (
            self.origin[0] + self.right[0] * along + self.inward[0] * inward,
            self.origin[1] + self.right[1] * along + self.inward[1] * inward,
        )

    def crosses(self, a: tuple[float, float], b: tuple[float, float], grow: float) -> bool:
        """True if the segment a-b passes within ``grow`` of the footprint (Liang-Barsky)."""
        (a0, a1), (b0, b1) = self.local(a), self.local(b)
        lo, hi = (-grow, -grow), (self.length + grow, self.depth + grow)
        t0, t1 = 0.0, 1.0
        for p0, d, mn, mx in ((a0, b0 - a0, lo[0], hi[0]), (a1, b1 - a1, lo[1], hi[1])):
            if abs(d) < 1e-12:
                if p0 < mn or p0 > mx:
                    return False
                continue
            u0, u1 = (mn - p0) / d, (mx - p0) / d
            if u0 > u1:
                u0, u1 = u1, u0
            t0, t1 = max(t0, u0), min(t1, u1)
            if t0 > t1:
                return False
        return True

    def distance(self, p: tuple[float, float]) -> float:
        """How far a floor point is outside the footprint along the rack's axes (the
        largest grow :meth:`crosses` can use with it; 0 inside)."""
        a, i = self.local(p)
        return max(-a, a - self.length, -i, i - self.depth, 0.0)

    def corners(self, grow: float) -> list[tuple[float, float]]:
        """The footprint's corners, pushed out by ``grow``."""
        return [
            self.world(a, i)
            for a in (-grow, self.length + grow)
            for i in (-grow, self.depth + grow)
        ]


def footprints(world: Any) -> list[Footprint]:
    """The footprints of the world's racks (none for a world without racks)."""
    out = []
    for rack in getattr(world, "data", {}).get("racks") or []:
        f = math.radians(rack["facing_deg"])
        n = (math.cos(f), math.sin(f))
        right = (-n[1], n[0])
        out.append(
            Footprint(
                rack["name"],
                tuple(rack["origin_m"]),
                right,
                (-n[0], -n[1]),
                rack["bays"] * rack["bay_width_m"],
                rack["depth_m"],
            )
        )
    return out


def route(
    start: tuple[float, float, float],
    goal: tuple[float, float, float],
    racks: list[Footprint],
    inside: Any = None,
    clearance: float = CLEARANCE_M,
) -> list[tuple[float, float, float]] | None:
    """Waypoints from ``start`` to ``goal`` (goal included, start not) that keep
    ``clearance`` from every rack footprint: straight if nothing is in the way, else the
    shortest path over the footprints' grown corners. ``inside(p) -> bool`` rejects corners
    outside the flying area (the geofence). Heights go linearly from start to goal. None if
    no route exists."""
    a, b = (start[0], start[1]), (goal[0], goal[1])
    # a start or goal nearer a rack than the clearance (a scan point in front of a face) may
    # be left or reached: that rack's clearance shrinks to what they leave
    grown = [
        (r, max(0.0, min(clearance, r.distance(a) - 0.02, r.distance(b) - 0.02))) for r in racks
    ]

    def free(p: tuple[float, float], q: tuple[float, float]) -> bool:
        return not any(r.crosses(p, q, g) for r, g in grown)

    if free(a, b):
        return [tuple(goal)]  # type: ignore[list-item]
    nodes = [a, b]
    for r in racks:
        for c in r.corners(clearance + CORNER_EXTRA_M):
            if inside is None or inside((c[0], c[1], goal[2])):
                nodes.append(c)
    dist = {0: 0.0}
    prev: dict[int, int] = {}
    heap = [(0.0, 0)]
    done: set[int] = set()
    while heap:
        d, i = heapq.heappop(heap)
        if i in done:
            continue
        done.add(i)
        if i == 1:
            break
        for j in range(len(nodes)):
            if j in done or not free(nodes[i], nodes[j]):
                continue
            nd = d + math.dist(nodes[i], nodes[j])
            if nd < dist.get(j, math.inf) - 1e-12:
                dist[j], prev[j] = nd, i
                heapq.heappush(heap, (nd, j))
    if 1 not in done:
        return None
    path = [1]
    while path[-1] != 0:
        path.append(prev[path[-1]])
    pts = [nodes[k] for k in reversed(path)][1:]
    total = sum(math.dist(p, q) for p, q in zip([a] + pts, pts, strict=False)) or 1.0
    out, run, last = [], 0.0, a
    for p in pts:
        run += math.dist(last, p)
        last = p
        z = start[2] + (goal[2] - start[2]) * run / total
        out.append((p[0], p[1], z))
    out[-1] = tuple(goal)  # type: ignore[assignment]
    return out
