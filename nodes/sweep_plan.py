"""The sweep's plan: which passes fly which places, and routes that go around the racks.

A *pass* flies one level of one rack face in one continuous line at the stand-off, past all
its places (``A/2``: rack A, level 2). :func:`plan_passes` orders a place list into passes:
a serpentine over the levels of each rack face (up one level, back along the next), the
faces taken nearest first, each pass flown from the end nearer to where the last one ended.
``PlanSweep`` writes that order as a queue of pass names (for BT.CPP's ``LoopString``) and
keeps the plan for ``SweepPass``.

Between passes, home and to the pad, the drone must go around racks, never through or over
them: :func:`nodes.rack_geometry.route` finds the shortest way through the aisles (a
visibility graph over the corners of the racks' footprints, grown by a clearance; the
geofence is respected). The ``FlyRoute`` leaf flies such a route.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from bt_engine.node import FAILURE, RUNNING, SUCCESS, NodeStatus, StatefulActionNode, SyncActionNode
from bt_engine.ports import ANY, DURATION, FLOAT, INT, VEC3, input_port, output_port
from bt_engine.registry import register
from bt_engine.spec import plural
from nodes.common import geofence_config, outside_geofence, vehicle_of
from nodes.inventory import CATEGORY_INVENTORY, PLANNED_PLACES, world_of
from nodes.rack_geometry import (  # noqa: F401 - importable from here as before
    CLEARANCE_M,
    CORNER_EXTRA_M,
    Footprint,
    footprints,
    route,
)


@dataclass
class PassSpec:
    """One pass: rack, level, places in flying order, the yaw facing the face, its
    direction along the face (unit x, y)."""

    name: str
    rack: str
    level: int
    places: list[str]
    look_rad: float
    direction: tuple[float, float]
    rows: dict[str, tuple[float, float, float]] = field(default_factory=dict)


@dataclass
class SweepPlan:
    """The passes of a sweep, by name and in order; the places left for the rescan."""

    passes: dict[str, PassSpec]
    order: list[str]
    #: places each pass left for the per-place scan, by pass name
    rescan: dict[str, list[str]] = field(default_factory=dict)

    def left_for_rescan(self) -> set[str]:
        """Every place a pass left for the per-place scan."""
        return {p for names in self.rescan.values() for p in names}


def _ends(spec: PassSpec) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    first, last = spec.rows[spec.places[0]], spec.rows[spec.places[-1]]
    return first, last


def plan_passes(places: list[str], world: Any, start: tuple[float, float, float]) -> SweepPlan:
    """``places`` as passes; see the module doc. Each pass's places are in flying order."""
    groups: dict[tuple[str, int], list[Any]] = {}
    for name in places:
        p = world.places[name]
        groups.setdefault((p.rack, p.level), []).append(p)
    faces: dict[str, list[int]] = {}
    for rack, level in groups:
        faces.setdefault(rack, []).append(level)
    passes: dict[str, PassSpec] = {}
    order: list[str] = []
    here = start
    left = set(faces)
    while left:
        best = None
        for rack in sorted(left):
            levels = sorted(faces[rack])
            for lv in (levels, levels[::-1]):
                ps = sorted(groups[(rack, lv[0])], key=lambda p: p.bay)
                for seq in (ps, ps[::-1]):
                    d = math.dist(here[:2], seq[0].row_m[:2]) + 0.3 * abs(here[2] - seq[0].row_m[2])
                    if best is None or d < best[0] - 1e-9:
                        best = (d, rack, lv, seq[0].bay < seq[-1].bay or len(seq) == 1)
        assert best is not None
        _, rack, levels, ascending = best
        left.discard(rack)
        for lv in levels:
            ps = sorted(groups[(rack, lv)], key=lambda p: p.bay, reverse=not ascending)
            look = math.radians(ps[0].look_deg)
            f = (math.cos(look), math.sin(look))
            right = (f[1], -f[0])  # the camera's right while facing the face
            # bays are numbered left to right seen from the aisle: ascending flies to the right
            direction = right if ascending else (-right[0], -right[1])
            name = f"{rack}/{lv}"
            passes[name] = PassSpec(
                name,
                rack,
                lv,
                [p.name for p in ps],
                look,
                direction,
                {p.name: tuple(p.row_m) for p in ps},
            )
            order.append(name)
            here = tuple(ps[-1].row_m)
            ascending = not ascending
    return SweepPlan(passes, order)


#: a pass line ends this far past its last place's outer block, m (a place is finished
#: 0.25 m past its last block: perception.sweep.SweepParams.finish_after_m)
PASS_TAIL_M = 0.3


def pass_line(
    spec: PassSpec, standoff: float, lead: float, places: list[str] | None = None
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Where a pass over ``places`` (default: all of the pass's, in flying order) starts and
    ends: ``standoff`` out from the faces, ``lead`` before the first block, and
    :data:`PASS_TAIL_M` after the last."""
    from perception.face import PalletModel

    names = places or spec.places
    half = max(abs(o) for o in PalletModel().offsets()) + 0.08
    d = spec.direction
    n = (-math.cos(spec.look_rad), -math.sin(spec.look_rad))  # out of the face

    def at(row: tuple[float, float, float], along: float) -> tuple[float, float, float]:
        return (
            row[0] + n[0] * standoff + d[0] * along,
            row[1] + n[1] * standoff + d[1] * along,
            row[2],
        )

    return at(spec.rows[names[0]], -(half + lead)), at(spec.rows[names[-1]], half + PASS_TAIL_M)


def pass_end_problems(node: Any, world: Any) -> list[tuple[str, str]]:
    """``(port, message)`` for a pass of the places to answer (:data:`PLANNED_PLACES`) that
    would start or end outside the rig's geofence: its run-up (``node``'s ``lead``) and
    tail past a rack's end blocks, at ``standoff``, as :func:`plan_passes` orders them
    from a simulated drone's start (a real drone's start is known only once it flies).
    The drone would fly there and breach the fence; refused before anything flies."""
    fence = geofence_config(node)
    names = node.ctx.resources.get(PLANNED_PLACES)
    rig = node.ctx.resources.get("rig")
    data = getattr(rig, "data", None)
    if fence is None or not names or not isinstance(data, dict) or data.get("link") != "sim":
        return []
    try:
        standoff, lead = float(node.get_input("standoff")), float(node.get_input("lead"))
    except Exception:  # noqa: BLE001 - written in flight: checked then
        return []
    if not (math.isfinite(standoff) and math.isfinite(lead)):
        return []
    start = tuple(float(v) for v in data["sim"]["start_m"])
    plan = plan_passes([n for n in names if n in world.places], world, start)  # type: ignore[arg-type]
    racks = footprints(world)
    for name in plan.order:
        line = pass_line(plan.passes[name], standoff, lead)
        for a, b, what in (
            (start, line[0], "to the start"),
            (line[-1], start, "back from the end"),
        ):
            if route(a, b, racks, lambda q: fence.inside(q, 0.1)) is None:
                return [
                    (
                        "standoff",
                        f"no way around the racks {what} of pass {name} (between the take-off "
                        f"point ({start[0]:.2f}, {start[1]:.2f}) and ({line[0][0]:.2f}, "
                        f"{line[0][1]:.2f})...({line[-1][0]:.2f}, {line[-1][1]:.2f})): a route "
                        f"keeps {CLEARANCE_M:g} m from every rack inside the geofence, so an "
                        f"aisle narrower than {2 * CLEARANCE_M:g} m plus the corners cannot be "
                        "flown through",
                    )
                ]
        for p in line:
            if not fence.inside(p, 0.05):
                return [
                    (
                        "lead",
                        f"pass {name} would start or end at ({p[0]:.2f}, {p[1]:.2f}), outside "
                        f"the rig's geofence ({fence.box_words()}, 0.05 m clear of its walls): "
                        f"its run-up (lead {lead:g} m) and tail ({PASS_TAIL_M:g} m) past the "
                        "rack's end blocks must lie inside it",
                    )
                ]
    return []


def route_length(ctx: Any, a: tuple[float, ...], b: tuple[float, ...]) -> float:
    """Length of the way from ``a`` to ``b`` around the racks of the run's world map
    (:func:`route`); a straight line without racks or without a way round."""
    world = world_of(ctx)
    racks = footprints(world) if world is not None else []
    if not racks:
        return math.dist(a, b)
    path = route(a, b, racks, geofence_inside(ctx))  # type: ignore[arg-type]
    if path is None:
        return math.dist(a, b)
    pts = [tuple(a), *path]
    return sum(math.dist(p, q) for p, q in zip(pts, pts[1:], strict=False))


def sweep_plan_of(ctx: Any) -> SweepPlan | None:
    """The plan ``PlanSweep`` made in this run (None before it ran)."""
    return ctx.resources.get("sweep_plan")


def geofence_inside(ctx: Any) -> Any:
    """``inside(p) -> bool`` of the rig's geofence (with a small clearance), or None."""
    supervisor = ctx.resources.get("safety")
    config = getattr(supervisor, "config", None)
    if config is None or not getattr(config, "geofence_enabled", False):
        return None
    return lambda p: config.inside(p, 0.1)


@register
class PlanSweep(SyncActionNode):
    """Order the places left to answer (``InventoryPlan``'s queue) into sweep passes: one
    per rack face and level, a serpentine over each face's levels, the faces nearest first
    from the drone. SUCCESS with ``passes`` (a queue of pass names such as ``A/2`` for
    LoopString); FAILURE without a world map."""

    bt_id = "PlanSweep"
    category = CATEGORY_INVENTORY
    ports = (
        input_port("places", ANY, description="the places left to answer (InventoryPlan's queue)"),
        output_port("passes", ANY, "pass names in flying order (LoopString's queue)"),
        output_port("count", INT, "passes planned"),
        output_port("first_point", ANY, "the first place's block row, x;y;z (EnoughEnergy)"),
    )

    def tick_impl(self) -> NodeStatus:
        world = world_of(self.ctx)
        if world is None or not getattr(world, "places", None):
            self.failure_reason = "a sweep needs a world with racks (e.g. --rig rigs/site.yaml)"
            return FAILURE
        places = [str(p) for p in (self.get_input("places") or [])]
        unknown = [p for p in places if p not in world.places]
        if unknown:
            self.failure_reason = f"unknown places {unknown[:3]}"
            return FAILURE
        v = self.ctx.vehicle
        start = tuple(v.position) if v is not None else (0.0, 0.0, 0.0)
        plan = plan_passes(places, world, start)
        self.ctx.resources["sweep_plan"] = plan
        self.ctx.log(
            f"sweep: {plural(len(places), 'place')} in {plural(len(plan.order), 'pass', 'passes')} "
            f"({', '.join(plan.order[:8])}{' ...' if len(plan.order) > 8 else ''})"
        )
        self.set_output("passes", list(plan.order))
        self.set_output("count", len(plan.order))
        if plan.order:
            first = plan.passes[plan.order[0]]
            self.set_output("first_point", first.rows[first.places[0]])
        elif v is not None:
            self.set_output("first_point", start)
        return SUCCESS


@register
class FlyRoute(StatefulActionNode):
    """Fly to ``pose`` around the racks of the world's map (never through or over them):
    straight when nothing is in the way, else through the aisles' ends. Yaw: PATH_FACING.
    SUCCESS at the goal; FAILURE if no route exists inside the geofence, on a refused
    motion or after ``timeout``."""

    bt_id = "FlyRoute"
    category = CATEGORY_INVENTORY
    ports = (
        input_port("pose", VEC3, description="goal x;y;z in m"),
        input_port("max_speed", FLOAT, 0.5, "speed, m/s", low=0.01, high=5.0),
        input_port("timeout", DURATION, 120.0, "FAILURE if not there within this time, s"),
    )

    def preflight(self) -> list[tuple[str, str]]:
        """A goal outside the rig's geofence, refused before anything flies."""
        try:
            pose = self.get_input("pose")
        except Exception:  # noqa: BLE001 - written in flight (the pads' point): checked then
            return []
        return outside_geofence(self, "pose", [pose])

    def on_start(self) -> NodeStatus:
        self.vehicle = vehicle_of(self)
        self.started_s = self.now()
        goal = tuple(float(v) for v in self.get_input("pose"))
        world = world_of(self.ctx)
        racks = footprints(world) if world is not None else []
        path = route(self.vehicle.position, goal, racks, geofence_inside(self.ctx))
        if path is None:
            x, y, z = goal
            self.failure_reason = (
                f"no way around the racks to ({x:.2f}, {y:.2f}, {z:.2f}): a route keeps "
                f"{CLEARANCE_M:g} m from every rack and stays inside the geofence"
            )
            return FAILURE
        if len(path) > 1:
            self.ctx.log(
                f"{self.describe()}: around the racks via "
                + ", ".join(f"({p[0]:.1f}, {p[1]:.1f})" for p in path[:-1])
            )
        self.progress = self.vehicle.follow_path(path, self.get_input("max_speed"), 1, 0.0)
        if self.progress.failed:
            self.failure_reason = self.progress.reason or "motion refused"
            return FAILURE
        return RUNNING

    def on_running(self) -> NodeStatus:
        p = self.progress
        if p.failed or p.cancelled:
            self.failure_reason = p.reason or "motion cancelled"
            return FAILURE
        if p.reached:
            return SUCCESS
        if self.now() - self.started_s >= self.get_input("timeout"):
            self.failure_reason = f"time-out after {self.get_input('timeout'):g} s"
            self.vehicle.hover()
            return FAILURE
        return RUNNING

    def on_halted(self) -> None:
        v = getattr(self, "vehicle", None)
        if v is not None and v.is_flying and v.motion is getattr(self, "progress", None):
            v.hover()
