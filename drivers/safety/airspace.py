"""Keeping the drones of a fleet apart: corridor reservations and a separation guard.

Two layers, both over the Vehicle API only:

* :class:`Airspace` is every vehicle's ``motion_gate`` (:mod:`drivers.vehicle.gate`): before a
  take-off, go-to or path starts, its corridor (the polyline from where the drone is through
  a path's waypoints to its goal) must pass at least ``separation_m`` from every other
  drone's reserved corridor (the rest of its own way, or the point where it waits, hovers or
  stands on its pad). If it does, the
  corridor is reserved; if not, the motion waits (the drone holds) and asks again at every
  control step. A reservation shrinks as its drone flies it (:meth:`Airspace.after_step`).
  Two drones can wait for each other (each holds where the other must pass: a head-on
  swap of places): the gate finds such a cycle of waits and has one of its drones step
  aside, straight up or down out of the others' corridors (within its ceiling, the ground
  and the geofence it is given), where it waits until the way is clear.
* :class:`SeparationGuard` watches the drones' measured positions every step: when two come
  within ``separation_m + hold_margin_m`` plus the distance the closing drone needs to stop
  (:func:`stopping_m`: at its speed and acceleration limit), it pauses the one flying towards
  the other (the drone stops and holds, its motion kept) and resumes it once they are apart, so
  they never come closer than the minimum separation. It records the closest approach, the
  holds and any violation.
* A landing is never refused nor kept waiting, but it does not come down onto another
  drone: when a drone's way straight down passes within ``separation_m`` of another drone
  (one that stands where it would touch down, or its corridor), :meth:`Airspace.land_spot`
  gives the nearest free spot beside it (inside the geofence, clear of obstacles), and the
  drone moves over it at its height before it descends.

With contiguous place blocks per drone (``btrun fleet``) the gate alone keeps them apart;
the guard is the backstop for what the reservations did not foresee (gusts, tracking error).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

Vec3 = tuple[float, float, float]
#: a polyline: where a drone is, then the points it will fly through
Way = tuple[Vec3, ...]
#: a drone stepping aside is there this close to its aside point, m
ASIDE_REACHED_M = 0.1
#: how far beside its spot a landing may move when another drone is there, m
LAND_RINGS_M = (0.75, 1.0, 1.5, 2.0)


def segment_distance(a0: Vec3, a1: Vec3, b0: Vec3, b1: Vec3) -> float:
    """Closest distance between segments a0-a1 and b0-b1 (points when an end repeats)."""
    d1 = [a1[i] - a0[i] for i in range(3)]
    d2 = [b1[i] - b0[i] for i in range(3)]
    r = [a0[i] - b0[i] for i in range(3)]
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    eps = 1e-12
    if a <= eps and e <= eps:
        return math.dist(a0, b0)
    if a <= eps:
        s, t = 0.0, min(max(f / e, 0.0), 1.0)
    else:
        c = _dot(d1, r)
        if e <= eps:
            s, t = min(max(-c / a, 0.0), 1.0), 0.0
        else:
            b = _dot(d1, d2)
            denom = a * e - b * b
            s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > eps else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                s, t = min(max(-c / a, 0.0), 1.0), 0.0
            elif t > 1.0:
                s, t = min(max((b - c) / a, 0.0), 1.0), 1.0
    p = [a0[i] + d1[i] * s for i in range(3)]
    q = [b0[i] + d2[i] * t for i in range(3)]
    return math.dist(p, q)


def _dot(u: list[float], v: list[float]) -> float:
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


#: the guard reacts this late (a control step and the firmware's lag), s
REACTION_S = 0.1


def stopping_m(vehicle: Any) -> float:
    """How far ``vehicle`` flies before it stands once paused now: its reaction at its
    speed, then braking at its acceleration limit."""
    vel = vehicle.velocity
    speed = math.sqrt(vel.vx_mps**2 + vel.vy_mps**2 + vel.vz_mps**2)
    accel = max(float(vehicle.config.accel_mps2), 1e-3)
    return speed * REACTION_S + speed * speed / (2.0 * accel)


def way_distance(a: Way, b: Way) -> float:
    """Closest distance between two polylines (a single point is a polyline too)."""
    sa = list(zip(a, a[1:], strict=False)) or [(a[0], a[0])]
    sb = list(zip(b, b[1:], strict=False)) or [(b[0], b[0])]
    return min(segment_distance(p0, p1, q0, q1) for p0, p1 in sa for q0, q1 in sb)


@dataclass
class Airspace:
    """Corridor reservations of the vehicles of one fleet (one process)."""

    separation_m: float = 0.5
    #: a drone stepping aside ends this much farther than the separation from the others'
    #: corridors, m
    aside_margin_m: float = 0.25
    vehicles: dict[str, Any] = field(default_factory=dict)
    #: each drone's reservation: the polyline of the way still ahead of it (its position
    #: alone while it holds, waits or stands)
    corridors: dict[str, Way] = field(default_factory=dict)
    waits: int = 0
    #: steps aside that broke a mutual wait
    asides: int = 0
    events: list[dict] = field(default_factory=list)
    #: a waiting drone's request (its way) and the drone it waits for
    requests: dict[str, Way] = field(default_factory=dict)
    blocked_by: dict[str, str] = field(default_factory=dict)
    inside: dict[str, Callable[[Vec3], bool]] = field(default_factory=dict)
    #: whether a point is clear of the world's obstacles for the drone (None: no obstacles)
    clear: Callable[[Vec3], bool] | None = None
    #: landings moved beside another drone
    landings_moved: int = 0

    def add(self, vehicle: Any, inside: Callable[[Vec3], bool] | None = None) -> None:
        """Put ``vehicle`` (named uniquely) under this airspace's gate; ``inside`` says
        whether a point is one the drone may step aside to (its geofence)."""
        if vehicle.name in self.vehicles:
            raise ValueError(f"two vehicles named {vehicle.name!r} in one airspace")
        self.vehicles[vehicle.name] = vehicle
        if inside is not None:
            self.inside[vehicle.name] = inside
        self.corridors[vehicle.name] = (tuple(vehicle.position),)
        vehicle.motion_gate = self.gate
        vehicle.land_spot = self.land_spot

    def land_spot(self, name: str, start: Vec3, ground_z: float) -> Vec3 | None:
        """Where drone ``name``, landing from ``start``, should touch down: None for straight
        below (no other drone within the separation of that way down), else the nearest
        free spot beside it (rings of LAND_RINGS_M, every 30 deg, the one farthest from the
        others on the nearest ring): its way over at ``start``'s height and down keeps the
        separation from every other drone, inside its geofence and clear of obstacles.
        None too when no spot is free (it lands where it is: recorded by the guard)."""
        self.after_step(0.0)
        others = [c for o, c in self.corridors.items() if o != name]
        down: Way = (tuple(start), (start[0], start[1], ground_z))
        if all(way_distance(down, c) >= self.separation_m for c in others):
            return None
        inside = self.inside.get(name)
        for r in LAND_RINGS_M:
            best: tuple[float, Vec3] | None = None
            for k in range(12):
                a = math.radians(30 * k)
                x, y = start[0] + r * math.cos(a), start[1] + r * math.sin(a)
                above, spot = (x, y, start[2]), (x, y, ground_z)
                way: Way = (tuple(start), above, spot)
                gap = min((way_distance(way, c) for c in others), default=math.inf)
                if gap < self.separation_m:
                    continue
                if inside is not None and not (inside(above) and inside((x, y, ground_z + 0.1))):
                    continue
                if not self._clear_way(way):
                    continue
                if best is None or gap > best[0]:
                    best = (gap, spot)
            if best is not None:
                self.landings_moved += 1
                self.events.append(
                    {"landing": name, "moved_to": [round(c, 3) for c in best[1]], "m": r}
                )
                return best[1]
        return None

    def _clear_way(self, way: Way, step_m: float = 0.1) -> bool:
        """Whether every point along ``way`` (every ``step_m``) is clear of obstacles."""
        if self.clear is None:
            return True
        for a, b in zip(way, way[1:], strict=False):
            n = max(1, math.ceil(math.dist(a, b) / step_m))
            for i in range(n + 1):
                p = tuple(a[k] + (b[k] - a[k]) * i / n for k in range(3))
                if not self.clear(p):  # type: ignore[arg-type]
                    return False
        return True

    def blocking(self, name: str, way: Way) -> tuple[str, float] | None:
        """The first other drone whose corridor comes within the separation of ``way`` and
        the distance, or None."""
        for other, corridor in self.corridors.items():
            if other == name:
                continue
            d = way_distance(way, corridor)
            if d < self.separation_m:
                return other, d
        return None

    def gate(self, name: str, kind: str, way: list[Vec3]) -> str:
        """The vehicles' motion gate: "" (and ``way`` reserved) or why to wait."""
        self.after_step(0.0)  # the others' corridors as they are now
        want = tuple(tuple(float(c) for c in p) for p in way)
        hit = self.blocking(name, want)
        if hit is not None:
            self.waits += 1
            other, d = hit
            self.requests[name] = want
            self.blocked_by[name] = other
            self._break_cycle(name)
            return (
                f"airspace: {other}'s corridor passes {d:.2f} m from this {kind} "
                f"(minimum {self.separation_m:g} m)"
            )
        self.requests.pop(name, None)
        self.blocked_by.pop(name, None)
        self.corridors[name] = want
        return ""

    def wait_cycle(self, name: str) -> list[str] | None:
        """The drones waiting for each other in a ring through ``name`` (``name`` first), or
        None: each waits at the gate for the next one's corridor, the last for ``name``'s."""
        ring = [name]
        cur = self.blocked_by.get(name)
        while cur is not None and cur not in ring:
            if not self.vehicles[cur].waiting_at_gate:
                return None
            ring.append(cur)
            cur = self.blocked_by.get(cur)
        return ring if cur == name and len(ring) > 1 else None

    def _break_cycle(self, name: str) -> None:
        """If ``name`` waits in a ring, have one of the ring's drones (the first by name that
        has room) step aside out of the others' way; each drone at most once per motion, and
        another only once the first is where it stepped to and the ring still holds."""
        ring = self.wait_cycle(name)
        if ring is None:
            return
        for who in ring:  # one of them on its way aside: wait until it is there
            goal = self.vehicles[who].aside_goal
            if goal is not None and math.dist(self.vehicles[who].position, goal) > ASIDE_REACHED_M:
                return
        for who in sorted(ring):
            v = self.vehicles[who]
            if v.aside_goal is not None:
                continue
            q = self.aside_point(who, ring)
            if q is not None and v.step_aside(q) == "":  # (its reservation: after_step)
                self.asides += 1
                self.events.append(
                    {"aside": who, "ring": list(ring), "to": [round(c, 3) for c in q]}
                )
                return

    def aside_point(self, who: str, ring: list[str]) -> Vec3 | None:
        """A point straight above or below ``who`` (above first) clear of the ways the ring's
        drones ask for and of every other drone's reservation, reached without coming near
        any of them; None if neither has room (ceiling, ground, geofence)."""
        v = self.vehicles[who]
        p = tuple(v.position)
        clear = self.separation_m + self.aside_margin_m
        keep = []
        for other, corridor in self.corridors.items():
            if other != who:
                keep.append(corridor)
                if other in ring and other in self.requests:
                    keep.append(self.requests[other])
        inside = self.inside.get(who)
        for dz in (clear, -clear):
            q = (p[0], p[1], p[2] + dz)
            if inside is not None and not inside(q):
                continue
            if all(way_distance((q,), w) >= clear for w in keep) and all(
                way_distance((p, q), c) >= self.separation_m
                for other, c in self.corridors.items()
                if other != who
            ):
                return q
        return None

    def after_step(self, t_s: float) -> None:
        """Shrink every reservation to what is left of it: from where the drone is along the
        way of its running motion, or just where it is (a waiting motion holds none)."""
        for name, v in self.vehicles.items():
            m = v.motion
            moving = m is not None and m.active and not m.reached and not m.waiting and v.is_flying
            aside = v.aside_goal
            if moving:
                self.corridors[name] = tuple(v.way_ahead())
            elif aside is not None:  # stepping aside while it waits: that short way
                self.corridors[name] = (tuple(v.position), aside)
            else:
                self.corridors[name] = (tuple(v.position),)


@dataclass
class SeparationGuard:
    """Pause a drone flying towards another one that is too close; see the module doc."""

    vehicles: dict[str, Any]
    separation_m: float = 0.5
    hold_margin_m: float = 0.2
    min_distance_m: float = math.inf
    min_pair: tuple[str, str] | None = None
    violations: int = 0
    holds: int = 0
    held: dict[str, str] = field(default_factory=dict)  # paused drone -> the one it yields to
    events: list[dict] = field(default_factory=list)
    _last_violation: set = field(default_factory=set)
    _held_at: dict[str, float] = field(default_factory=dict)  # paused drone -> distance then

    def after_step(self, t_s: float) -> None:
        """Check every pair of drones in the air; pause or resume."""
        names = list(self.vehicles)
        hold_at = self.separation_m + self.hold_margin_m
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                va, vb = self.vehicles[a], self.vehicles[b]
                if not (va.is_flying or vb.is_flying):
                    continue
                pa, pb = va.position, vb.position
                d = math.dist(pa, pb)
                if d < self.min_distance_m:
                    self.min_distance_m, self.min_pair = d, (a, b)
                pair = (a, b)
                if d < self.separation_m and pair not in self._last_violation:
                    self.violations += 1
                    self._last_violation.add(pair)
                    self.events.append(
                        {"t_s": round(t_s, 3), "violation": [a, b], "m": round(d, 3)}
                    )
                elif d >= self.separation_m:
                    self._last_violation.discard(pair)
                if d < hold_at + max(stopping_m(va), stopping_m(vb)):
                    self._hold_closer(t_s, a, b, d, hold_at)
        for name, other in list(self.held.items()):
            v, o = self.vehicles[name], self.vehicles[other]
            d = math.dist(v.position, o.position)
            # apart by more than when it was held (else it would creep closer, held again
            # and again), the other gone down, or its way turned away
            far = d > max(hold_at, self._held_at.get(name, 0.0)) + 0.1
            if far or not o.is_flying or not self._closing(v, o):
                del self.held[name]
                self._held_at.pop(name, None)
                if v.resume():
                    self.events.append({"t_s": round(t_s, 3), "resumed": name, "m": round(d, 3)})

    def _closing(self, v: Any, o: Any) -> bool:
        """True if ``v``'s way (towards its next point, else its velocity) brings it nearer
        ``o`` and the line it flies passes within the hold distance of ``o`` (two drones
        flying side by side a metre apart are not closing in)."""
        p, q = v.position, o.position
        to_o = [q[k] - p[k] for k in range(3)]
        ahead = None
        for point in v.way_ahead()[1:]:
            if math.dist(point, p) >= 0.05:
                ahead = [point[k] - p[k] for k in range(3)]
                break
        if ahead is None:
            vel = v.velocity
            ahead = [vel.vx_mps, vel.vy_mps, vel.vz_mps]
        n = math.sqrt(_dot(ahead, ahead))
        if n < 1e-9:
            return False
        along = _dot(ahead, to_o) / n
        miss = math.sqrt(max(_dot(to_o, to_o) - along * along, 0.0))
        return along > 0.0 and miss < self.separation_m + self.hold_margin_m

    def _hold_closer(self, t_s: float, a: str, b: str, d: float, hold_at: float) -> None:
        va, vb = self.vehicles[a], self.vehicles[b]
        for name, v, o, other in ((a, va, vb, b), (b, vb, va, a)):
            if name in self.held or not v.is_flying or not o.is_flying:
                continue  # (a drone on the ground is kept clear of by the corridors)
            if d >= hold_at + stopping_m(v) or not self._closing(v, o):
                continue
            if other in self.held and self.held[other] == name:
                continue  # the other already yields to this one
            if v.pause(f"{other} is {d:.2f} m away"):
                self.held[name] = other
                self._held_at[name] = d
                self.holds += 1
                self.events.append(
                    {"t_s": round(t_s, 3), "held": name, "for": other, "m": round(d, 3)}
                )
                return

    def summary(self) -> dict:
        """Closest approach, holds, violations (summary.json ``separation``)."""
        return {
            "minimum_m": self.separation_m,
            "closest_m": round(self.min_distance_m, 3)
            if math.isfinite(self.min_distance_m)
            else None,
            "closest_pair": list(self.min_pair) if self.min_pair else None,
            "violations": self.violations,
            "holds": self.holds,
            "events": self.events[:200],
        }
