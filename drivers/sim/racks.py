"""Pallet racks: named pallet places, rack steel, and which pallet stands where (per seed).

A world file may describe racks (``racks:``); each rack is a row of bays along a straight
front line, with pallet places on several levels. A place is named
``<rack>-<bay:02d>-<level>`` (``A-03-2``: rack A, third bay, second level from the floor),
as warehouse location codes are. Bays are numbered from the rack's ``origin_m`` to the right
as seen from the aisle (reading order); levels from the floor up.

Geometry of one bay, seen from above (the aisle at the bottom, the rack's front facing it)::

        back uprights  |                      |
                       |   pallet (0.8 deep)  |
                       |======================|  <- shown long face, setback_m behind
        front line  ---+----------------------+---  (front uprights, beams)
                       <----- bay_width ------>
                                aisle

``stock:`` says how the places are filled: which pallets of the world's pool stand in the
racks, how many places are empty and how many hold a pallet that is not enrolled (unknown to
the demo gallery), fixed assignments, and a small placement error per pallet; everything
else is drawn per seed (:func:`draw_stock`), so a seed fixes a whole warehouse state.
``pallet_pool:`` adds generated pallets to the world (ids ``first_id``, ``first_id + 1``, ...)
so that a large pool need not be written out by hand.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

from drivers.settings import Field
from drivers.sim.shapes import Box

F, M, L = Field, lambda children, doc="": Field("map", children=children, doc=doc), Field

RACK = M(
    {
        "name": F(
            "str",
            None,
            "rack (aisle side) letter or name, first part of place names",
            required=True,
        ),
        "origin_m": F(
            "vec", [0.0, 0.0], "x, y of the front line where bay 01 begins (m)", length=2
        ),
        "facing_deg": F("float", 180.0, "direction the rack's front looks to (deg, 180 = -x)"),
        "bays": F("int", 8, "number of bays (one pallet place per bay and level)", min=1, max=99),
        "bay_width_m": F("float", 1.40, "bay width between upright centres (m)", min=0.5),
        "levels_m": F(
            "list",
            [0.2, 1.0],
            "height of each level's beam top = pallet base (m), from the floor up",
            item=F("float", 0.0, "", min=0.0),
        ),
        "depth_m": F("float", 1.0, "rack depth, front to back uprights (m)", min=0.3),
        "height_m": F("float", 2.0, "upright height (m)", min=0.2),
        "setback_m": F(
            "float",
            0.05,
            "the pallet's shown face stands this far behind the front line (m)",
            min=0.0,
        ),
        "upright_m": F("float", 0.08, "upright section (m)", min=0.01),
        "beam_m": F("float", 0.10, "beam height (m)", min=0.01),
    }
)

POSE_ERROR = M(
    {
        "lateral_m": F("float", 0.0, "along the face, drawn in +-this (m)", min=0.0),
        "depth_m": F("float", 0.0, "in or out of the rack, in +-this (m)", min=0.0),
        "height_m": F("float", 0.0, "base height above the beam, in 0..this (m)", min=0.0),
        "yaw_deg": F("float", 0.0, "turn about the face centre, in +-this (deg)", min=0.0),
    },
    doc="how far each racked pallet stands off its place, drawn uniformly per seed and place",
)

STOCK = M(
    {
        "pallets": F(
            "list",
            None,
            "ids of the world's pallets that may stand in the racks (default: all)",
            item=F("str", None, ""),
            nullable=True,
        ),
        "empty_places": F("int", 0, "places left empty, drawn per seed", min=0),
        "not_enrolled": F(
            "list",
            [],
            "pallet ids the demo gallery leaves out: scans of them must answer unknown",
            item=F("str", None, ""),
        ),
        "not_enrolled_places": F(
            "int", 0, "places that hold a not-enrolled pallet, drawn per seed", min=0
        ),
        "fixed": F(
            "dict",
            {},
            "place -> identity (e.g. A-01-1: 12B) or none: fixed before the draw",
            item=F("str", None, ""),
        ),
        "placement_error": POSE_ERROR,
    },
    doc="which pallet stands in which rack place, drawn per seed",
)

PALLET_POOL = M(
    {
        "count": F("int", 0, "generated pallets added to the world's pallets", min=0, max=20_000),
        "first_id": F("int", 101, "id of the first generated pallet", min=1),
        "seed": F("int", 0, "seed of the generated stamps, wear and textures"),
    },
    doc="pallets generated from a seed (ids first_id, first_id+1, ...), added to pallets:",
)

PAD = M(
    {
        "name": F("str", None, "pad name (one drone per pad)", required=True),
        "position_m": F("vec", [0.0, 0.0], "x, y of the pad centre on the floor (m)", length=2),
    }
)


@dataclass(frozen=True)
class Place:
    """A named pallet place: its slot (shown face centre, base height, facing) and where a
    drone finds the block row (``row_m``) and which way it must look (``look_deg``)."""

    name: str
    rack: str
    bay: int
    level: int
    slot: dict  # x_m, y_m (face centre), z_m (base), facing_deg: as world slots
    row_m: tuple[float, float, float]  # centre of the block row (middle block's front face)
    look_deg: float  # drone yaw that faces the pallet

    def as_dict(self) -> dict:
        """JSON-friendly description (summary.json, inventory files)."""
        return {
            "name": self.name,
            "rack": self.rack,
            "bay": self.bay,
            "level": self.level,
            "row_m": [round(v, 4) for v in self.row_m],
            "look_deg": round(self.look_deg, 3),
        }


def place_name(rack: str, bay: int, level: int) -> str:
    """``A-03-2``: rack A, bay 3, level 2."""
    return f"{rack}-{bay:02d}-{level}"


def _frame(rack: dict) -> tuple[tuple[float, float], tuple[float, float]]:
    """Unit vectors: ``n`` out of the rack's front (towards the aisle) and ``right`` along
    the bays (to the right seen from the aisle)."""
    f = math.radians(rack["facing_deg"])
    n = (math.cos(f), math.sin(f))
    return n, (-n[1], n[0])


def rack_footprint(rack: dict) -> list[tuple[float, float]]:
    """The rack's corners on the floor (front left, front right, back right, back left)."""
    n, right = _frame(rack)
    (ox, oy), length, depth = rack["origin_m"], rack["bays"] * rack["bay_width_m"], rack["depth_m"]
    return [
        (ox + right[0] * a - n[0] * d, oy + right[1] * a - n[1] * d)
        for a, d in ((0.0, 0.0), (length, 0.0), (length, depth), (0.0, depth))
    ]


def rack_places(rack: dict, geometry: dict) -> list[Place]:
    """Every place of a rack, bay by bay, levels from the floor up."""
    n, right = _frame(rack)
    ox, oy = rack["origin_m"]
    row_dz = geometry["board_m"] + geometry["block_height_m"] / 2.0
    out = []
    for bay in range(1, rack["bays"] + 1):
        along = (bay - 0.5) * rack["bay_width_m"]
        fx = ox + right[0] * along - n[0] * rack["setback_m"]
        fy = oy + right[1] * along - n[1] * rack["setback_m"]
        for level, z in enumerate(rack["levels_m"], start=1):
            slot = {"x_m": fx, "y_m": fy, "z_m": z, "facing_deg": rack["facing_deg"]}
            look = math.degrees(
                math.remainder(math.radians(rack["facing_deg"]) + math.pi, math.tau)
            )
            out.append(
                Place(
                    place_name(rack["name"], bay, level),
                    rack["name"],
                    bay,
                    level,
                    slot,
                    (fx, fy, z + row_dz),
                    look,
                )
            )
    return out


def rack_boxes(rack: dict) -> list[Box]:
    """The rack's steel: front and back uprights at every bay boundary (blue) and a front
    and a back beam under every level of every bay (orange)."""
    n, right = _frame(rack)
    ox, oy = rack["origin_m"]
    yaw = math.radians(rack["facing_deg"])
    u, bw, depth = rack["upright_m"], rack["bay_width_m"], rack["depth_m"]
    boxes = []

    def at(along: float, inward: float) -> tuple[float, float]:
        return ox + right[0] * along - n[0] * inward, oy + right[1] * along - n[1] * inward

    h = rack["height_m"]
    for j in range(rack["bays"] + 1):
        for side, inward in (("front", u / 2), ("back", depth - u / 2)):
            x, y = at(j * bw, inward)
            boxes.append(
                Box(
                    f"rack {rack['name']} upright {j} {side}",
                    x,
                    y,
                    h / 2,
                    u / 2,
                    u / 2,
                    h / 2,
                    yaw,
                    "steel_blue",
                )
            )
    beam_depth = 0.05
    for bay in range(1, rack["bays"] + 1):
        for level, z in enumerate(rack["levels_m"], start=1):
            if z <= 0.0:
                continue  # a floor level stands on the floor: no beam
            bh = min(rack["beam_m"], z)
            for side, inward in (("front", beam_depth / 2), ("back", depth - beam_depth / 2)):
                x, y = at((bay - 0.5) * bw, inward)
                boxes.append(
                    Box(
                        f"rack {rack['name']} beam {bay:02d}-{level} {side}",
                        x,
                        y,
                        z - bh / 2,
                        beam_depth / 2,
                        (bw - u) / 2,
                        bh / 2,
                        yaw,
                        "steel_orange",
                    )
                )
    return boxes


def generated_pallets(pool: dict) -> list[dict]:
    """The pallets a ``pallet_pool`` section adds (deterministic in its seed)."""
    rng = random.Random(f"pallet-pool-{pool['seed']}")
    out = []
    for k in range(pool["count"]):
        pid = pool["first_id"] + k
        sides = {}
        for j, side in enumerate(("A", "B"), start=1):
            sides[side] = {
                "stamp": rng.choice(("EPAL", "EPAL", "EUR")),
                "wear": round(rng.uniform(0.05, 0.8), 3),
                "texture_seed": pid * 10 + j,
            }
        out.append({"id": str(pid), "sides": sides})
    return out


EMPTY_NAMES = ("none", "empty", "")


def is_empty(identity: str | None) -> bool:
    """True for the spellings of "no pallet here"."""
    return identity is None or str(identity).strip().lower() in EMPTY_NAMES


def stock_pool(data: dict) -> tuple[list[str], list[str]]:
    """(enrolled pallet ids, not-enrolled pallet ids) that may stand in the racks."""
    ids = [p["id"] for p in data["pallets"]]
    stock = data["stock"]
    pool = ids if stock["pallets"] is None else [str(i) for i in stock["pallets"]]
    not_enrolled = {str(i) for i in stock["not_enrolled"]}
    return [i for i in pool if i not in not_enrolled], [i for i in pool if i in not_enrolled]


def draw_stock(places: list[Place], data: dict, seed: int) -> dict[str, str | None]:
    """Which identity stands in each place for ``seed`` (None: empty).

    Fixed places first; then ``empty_places`` and ``not_enrolled_places`` of the others are
    drawn; not-enrolled pallets fill the latter and enrolled pallets the rest, each pallet at
    most once and showing a side drawn at random. :func:`stock_problems` checks beforehand
    that the pool is large enough.
    """
    rng = random.Random(f"stock-{seed}")
    stock = data["stock"]
    enrolled, not_enrolled = stock_pool(data)
    out: dict[str, str | None] = {}
    used: set[str] = set()
    for name, identity in stock["fixed"].items():
        if is_empty(identity):
            out[name] = None
        else:
            out[name] = str(identity).strip()
            used.add(out[name][:-1])
    free = [p.name for p in places if p.name not in out]
    rng.shuffle(free)
    n_empty = min(stock["empty_places"], len(free))
    for name in free[:n_empty]:
        out[name] = None
    rest = free[n_empty:]
    unknown_pool = [i for i in not_enrolled if i not in used]
    known_pool = [i for i in enrolled if i not in used]
    rng.shuffle(unknown_pool)
    rng.shuffle(known_pool)
    n_unknown = min(stock["not_enrolled_places"], len(rest), len(unknown_pool))
    for name, pid in zip(rest[:n_unknown], unknown_pool, strict=False):
        out[name] = pid + rng.choice("AB")
    for name, pid in zip(rest[n_unknown:], known_pool, strict=False):
        out[name] = pid + rng.choice("AB")
    for name in rest[n_unknown + len(known_pool) :]:
        out[name] = None  # the pool ran out (stock_problems reports it at load time)
    return {p.name: out.get(p.name) for p in places}


def draw_pose_error(error: dict, seed: int, place: str) -> dict[str, float]:
    """One racked pallet's offset from its place for ``seed`` (see ``POSE_ERROR``)."""
    rng = random.Random(f"rack-placement-{seed}-{place}")
    out = {}
    for key in ("lateral_m", "depth_m", "yaw_deg"):
        half = float(error.get(key) or 0.0)
        out[key] = round(rng.uniform(-half, half), 4) if half > 0 else 0.0
    h = float(error.get("height_m") or 0.0)
    out["height_m"] = round(rng.uniform(0.0, h), 4) if h > 0 else 0.0
    return out


def _fit_problems(data: dict) -> list[tuple[str, str]]:
    """(key, message) where a rack cannot hold its pallets: a pallet wider than the space
    between the uprights, shallower than the rack, or taller than the space under the
    next level's beam; or placement errors (``stock.placement_error``) by which pallets of
    neighbouring bays could overlap, a pallet stand through the rack's back or reach the
    beam above (each said once, with the racks it concerns)."""
    out: list[tuple[str, str]] = []
    g = data["pallet_geometry"]
    length, width, height = g["length_m"], g["width_m"], g["height_m"]
    err = (data.get("stock") or {}).get("placement_error") or {}
    lat, dep, up = (float(err.get(k) or 0.0) for k in ("lateral_m", "depth_m", "height_m"))
    lat_room: dict[str, float] = {}  # rack -> the most lateral error its bays allow
    dep_room: dict[str, float] = {}
    up_room: dict[str, float] = {}
    for i, r in enumerate(data.get("racks") or []):
        key, name = f"racks[{i}]", r["name"]
        clear = r["bay_width_m"] - r["upright_m"]
        if clear < length:
            out.append(
                (
                    f"{key}.bay_width_m",
                    f"{r['bay_width_m']:g} m bays with {r['upright_m']:g} m uprights leave "
                    f"{clear:.2f} m: a {length:g} m pallet does not fit",
                )
            )
        else:
            lat_room[name] = (r["bay_width_m"] - length) / 2.0
        need = r["setback_m"] + width
        if need > r["depth_m"] + 1e-9:
            out.append(
                (
                    f"{key}.depth_m",
                    f"{r['depth_m']:g} m is too shallow for a {width:g} m deep pallet "
                    f"standing {r['setback_m']:g} m behind the front line: needs {need:.2f} m",
                )
            )
        else:
            dep_room[name] = r["depth_m"] - need
        levels = r["levels_m"] or []
        gaps = [b - a for a, b in zip(levels, levels[1:], strict=False) if b > a]
        if gaps and min(gaps) < height + r["beam_m"] - 1e-9:
            out.append(
                (
                    f"{key}.levels_m",
                    f"levels {min(gaps):.3f} m apart: a {height:g} m pallet reaches the "
                    f"{r['beam_m']:g} m beam of the level above; at least "
                    f"{height + r['beam_m']:.3f} m apart",
                )
            )
        elif gaps:
            up_room[name] = min(gaps) - height - r["beam_m"]
    for value, room, field, what in (
        (lat, lat_room, "lateral_m", "lets pallets of neighbouring bays overlap"),
        (dep, dep_room, "depth_m", "pushes pallets through the back of the rack"),
        (up, up_room, "height_m", "raises pallets into the beam of the level above"),
    ):
        over = sorted(n for n, m in room.items() if value > m + 1e-9)
        if over:
            most = min(room[n] for n in over)
            out.append(
                (
                    f"stock.placement_error.{field}",
                    f"{value:g} m {what} in rack{'s' if len(over) > 1 else ''} "
                    f"{', '.join(over)}: at most {most:.3f} m there",
                )
            )
    yaw = float(err.get("yaw_deg") or 0.0)
    # the whole gap to a neighbour standing on its place (lateral errors get half of it)
    gap = 2 * min(lat_room.values(), default=math.inf)
    rooms = (gap, min(dep_room.values(), default=math.inf))
    if yaw > 0 and not _turn_fits(yaw, length, width, rooms):
        # turned about its face centre, a pallet's back corners swing sideways and the far
        # side of its front edge goes deeper: alone (no other error, its neighbour on its
        # place) neither may reach the neighbouring bay's pallet or the rack's back
        most = max(t / 10 for t in range(901) if _turn_fits(t / 10, length, width, rooms))
        out.append(
            (
                "stock.placement_error.yaw_deg",
                f"{yaw:g} deg turns a {length:g} x {width:g} m pallet into the next bay or "
                f"through the rack's back: at most {most:g} deg there",
            )
        )
    return out


def _turn_fits(deg: float, length: float, width: float, rooms: tuple[float, float]) -> bool:
    """Whether a pallet turned by up to ``deg`` about its face centre stays within
    ``rooms`` (sideways, backwards, m) of its footprint."""
    for t in (deg * i / 50 for i in range(51)):
        a = math.radians(min(t, 90.0))
        side = (length / 2) * math.cos(a) + width * math.sin(a) - length / 2
        back = (length / 2) * math.sin(a) + width * math.cos(a) - width
        if side > rooms[0] + 1e-9 or back > rooms[1] + 1e-9:
            return False
    return True


def _id_span(ids: set[str]) -> str:
    """The pallet ids of a world, said briefly: ``its pallets: 1001 .. 1100`` (or a few)."""
    if not ids:
        return "it has no pallets"
    order = sorted(ids, key=lambda i: (len(i), i))
    if len(order) <= 4:
        return "its pallets: " + ", ".join(order)
    return f"its {len(order)} pallets: {order[0]} .. {order[-1]}"


def stock_problems(data: dict, places: list[Place]) -> list[tuple[str, str]]:
    """(key, message) for every inconsistency of racks, stock and pads (located by the
    caller): duplicate names, fixed entries naming unknown places or identities, a pallet
    used twice, a pool too small for the places to fill."""
    problems: list[tuple[str, str]] = []
    names = [r["name"] for r in data["racks"]]
    for i, name in enumerate(names):
        if names.index(name) != i:
            problems.append((f"racks[{i}].name", f"duplicate rack name '{name}'"))
        levels = data["racks"][i]["levels_m"]
        if not levels:
            problems.append((f"racks[{i}].levels_m", "a rack needs at least one level"))
        elif any(b <= a for a, b in zip(levels, levels[1:], strict=False)):
            problems.append(
                (f"racks[{i}].levels_m", f"levels must go up from the floor, got {levels}")
            )
    problems += _fit_problems(data)
    pads = [p["name"] for p in data["pads"]]
    for i, name in enumerate(pads):
        if pads.index(name) != i:
            problems.append((f"pads[{i}].name", f"duplicate pad name '{name}'"))
    if not places:
        return problems
    ids = {p["id"] for p in data["pallets"]}
    stock = data["stock"]
    for key in ("pallets", "not_enrolled"):  # one problem per list, at its first bad id
        bad = [(j, str(pid)) for j, pid in enumerate(stock[key] or []) if str(pid) not in ids]
        if bad:
            names = ", ".join(f"'{pid}'" for _, pid in bad[:4]) + (", ..." if len(bad) > 4 else "")
            what = "is not a pallet id" if len(bad) == 1 else f"({len(bad)} ids) are not pallet ids"
            problems.append(
                (f"stock.{key}[{bad[0][0]}]", f"{names} {what} of this world ({_id_span(ids)})")
            )
    known_places = {p.name for p in places}
    used: dict[str, str] = {}
    for name, identity in stock["fixed"].items():
        key = f"stock.fixed.{name}"
        if name not in known_places:
            hint = ", ".join(sorted(known_places)[:4])
            problems.append((key, f"'{name}' is not a place of this world (places: {hint}, ...)"))
        if is_empty(identity):
            continue
        pid, side = str(identity)[:-1], str(identity)[-1:].upper()
        if pid not in ids or side not in ("A", "B"):
            problems.append(
                (key, f"'{identity}' is not a pallet side of this world (e.g. {sorted(ids)[0]}A)")
            )
        elif pid in used:
            problems.append(
                (
                    key,
                    f"pallet {pid} already stands in {used[pid]}: a pallet can stand in one place",
                )
            )
        else:
            used[pid] = name
    enrolled, not_enrolled = stock_pool(data)
    free = len(known_places - set(stock["fixed"]))
    fill = free - stock["empty_places"]
    if fill < 0:
        problems.append(
            (
                "stock.empty_places",
                f"{stock['empty_places']} empty places asked but only {free} places are not fixed",
            )
        )
        return problems
    n_unknown = stock["not_enrolled_places"]
    spare_unknown = len([i for i in not_enrolled if i not in used])
    if n_unknown > min(fill, spare_unknown):
        problems.append(
            (
                "stock.not_enrolled_places",
                f"{n_unknown} places with a not-enrolled pallet asked but only "
                f"{min(fill, spare_unknown)} can have one ({spare_unknown} not-enrolled "
                f"{'pallet' if spare_unknown == 1 else 'pallets'} free)",
            )
        )
    spare_known = len([i for i in enrolled if i not in used])
    if fill - n_unknown > spare_known:
        problems.append(
            (
                "stock",
                f"{fill - n_unknown} places to fill with enrolled pallets but the pool has only "
                f"{spare_known} free: add pallets (pallet_pool.count) or empty places",
            )
        )
    return problems
