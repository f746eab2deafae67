"""The simulated world: floor, pallets (EPAL geometry, identities and sides), obstacles, light.

Code here, data in ``worlds/*.yaml`` (rotorpy's split). :func:`load_world` validates a world
file with located errors; :class:`World` places the pallets and answers collision queries.

Pallet frame: origin at the centre of the footprint on the pallet's base; local x across the
width (0.8 m), local y along the length (1.2 m), z up. Side A is the long face at local -x,
side B the one at local +x. A *slot* gives the centre of the face that must be shown
(``x_m, y_m``, base height ``z_m``) and the direction that face looks to (``facing_deg``:
180 = towards -x). Identity "3A" in a slot means pallet 3 stands there showing side A.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from drivers.settings import (
    ConfigError,
    Marks,
    SettingProblem,
    apply_overrides,
    problem_at,
    written_by,
)
from drivers.settings_yaml import load_yaml_file
from drivers.sim.rack_layout import layout_problems
from drivers.sim.racks import (
    Place,
    draw_pose_error,
    draw_stock,
    generated_pallets,
    rack_boxes,
    rack_places,
    stock_pool,
    stock_problems,
)
from drivers.sim.shapes import Box
from drivers.sim.world_schema import LOOK, PAINTS, SIDE, SLOT, WOODS, WORLD_SCHEMA

__all__ = [
    "LOOK",
    "PAINTS",
    "SIDE",
    "SLOT",
    "WOODS",
    "WORLD_SCHEMA",
    "Box",
    "Place",
    "PlacedPallet",
    "World",
    "load_world",
]


@dataclass
class PlacedPallet:
    """A pallet in the world: identity shown, pose, support blocks of the shown face."""

    pallet_id: str
    shown_side: str
    identity: str
    x_m: float  # centre of the footprint
    y_m: float
    z_m: float  # base height
    yaw_rad: float  # yaw of the pallet's local x axis
    face_center_m: tuple[float, float, float]
    facing_rad: float
    body: Box
    blocks: list[Box] = field(default_factory=list)
    sides: dict = field(default_factory=dict)
    slot_name: str = "scan"  # "scan", "row[i]" or a rack place name (A-03-2)


def place_pallet(pallet: dict, side: str, slot: dict, geometry: dict) -> PlacedPallet:
    """Stand ``pallet`` in ``slot`` so that ``side`` faces the slot's direction (pure)."""
    g = geometry
    facing = math.radians(slot["facing_deg"])
    nx, ny = math.cos(facing), math.sin(facing)
    half_w = g["width_m"] / 2.0
    cx, cy = slot["x_m"] - nx * half_w, slot["y_m"] - ny * half_w
    # Side A is at local -x: local -x must point along the facing direction.
    yaw = facing + math.pi if side == "A" else facing
    yaw = math.remainder(yaw, 2.0 * math.pi)
    z0 = slot["z_m"]
    body = Box(
        f"pallet {pallet['id']}",
        cx,
        cy,
        z0 + g["height_m"] / 2,
        half_w,
        g["length_m"] / 2,
        g["height_m"] / 2,
        yaw,
    )
    blocks = []
    along_c, depth_c = g["corner_block_m"]
    along_m, depth_m = g["middle_block_m"]
    bz = z0 + g["board_m"] + g["block_height_m"] / 2
    tx, ty = -nx, -ny  # into the pallet
    lx, ly = -ny, nx  # along the face (left when looking at it... from the drone: right)
    offset = g["length_m"] / 2 - along_c / 2
    for k, (along, depth) in enumerate(
        ((along_c, depth_c), (along_m, depth_m), (along_c, depth_c))
    ):
        u = (-offset, 0.0, offset)[k]
        bx = slot["x_m"] + tx * depth / 2 + lx * u
        by = slot["y_m"] + ty * depth / 2 + ly * u
        blocks.append(
            Box(f"block {k + 1}", bx, by, bz, depth / 2, along / 2, g["block_height_m"] / 2, facing)
        )
    return PlacedPallet(
        pallet["id"],
        side,
        f"{pallet['id']}{side}",
        cx,
        cy,
        z0,
        yaw,
        (slot["x_m"], slot["y_m"], bz),
        facing,
        body,
        blocks,
        dict(pallet.get("sides") or {}),
    )


EMPTY = ("none", "")  # scan_pallet values that leave the scan slot empty


def draw_placement(error: dict, seed: int, fixed: dict | None = None) -> dict[str, float]:
    """The scanned pallet's offsets for ``seed``: ``fixed`` plus each drawn uniformly in
    +-``error``'s range (just ``fixed`` when every range is zero, whatever the seed)."""
    import random

    rng = random.Random(f"placement-{seed}")
    out = {}
    for key in ("lateral_m", "depth_m", "height_m", "yaw_deg"):
        half = float(error.get(key) or 0.0)
        value = rng.uniform(-half, half)
        base = float((fixed or {}).get(key) or 0.0)
        out[key] = round(base + (value if half > 0 else 0.0), 4)
    return out


def offset_slot(slot: dict, offset: dict[str, float], floor_z_m: float) -> dict:
    """``slot`` moved by a placement offset: ``lateral_m`` along the face (to the left seen
    from in front of it), ``depth_m`` away from whoever faces it, ``height_m`` up (never
    below the floor), ``yaw_deg`` turned about the face centre."""
    facing = math.radians(slot["facing_deg"])
    nx, ny = math.cos(facing), math.sin(facing)
    lx, ly = ny, -nx  # seen from in front (looking along -facing), left is this way
    lat, dep = offset["lateral_m"], offset["depth_m"]
    out = dict(slot)
    out["x_m"] = slot["x_m"] + lx * lat - nx * dep
    out["y_m"] = slot["y_m"] + ly * lat - ny * dep
    out["z_m"] = max(floor_z_m, slot["z_m"] + offset["height_m"])
    out["facing_deg"] = slot["facing_deg"] + offset["yaw_deg"]
    return out


class World:
    """Placed pallets, stand and obstacles, with a cheap collision query for the drone.

    ``seed`` draws the scanned pallet's placement error (``placement_error``); the draw is
    in :attr:`placement_offset`.
    """

    def __init__(self, data: dict, path: str = "<world>", seed: int = 0) -> None:
        data = with_generated_pallets(data)
        self.data, self.path, self.seed = data, path, seed
        self.floor_z_m = data["floor"]["z_m"]
        g = data["pallet_geometry"]
        pallets = {p["id"]: p for p in data["pallets"]}
        self.scan_pallet = data["scan_pallet"]
        empty = str(self.scan_pallet).strip().lower() in EMPTY
        scan_id, scan_side = ("", "") if empty else split_identity(data["scan_pallet"])
        self.placement_offset = draw_placement(
            data["placement_error"], seed, data["placement_offset"]
        )
        slot = offset_slot(data["scan_slot"], self.placement_offset, self.floor_z_m)
        self.scan_slot = slot
        self.pallets: list[PlacedPallet] = []
        self.boxes: list[Box] = []
        #: rack places by name, in order (bay by bay, levels from the floor up)
        self.places: dict[str, Place] = {
            p.name: p for rack in data["racks"] for p in rack_places(rack, g)
        }
        #: which identity stands in each place for this seed (None: empty)
        self.stock: dict[str, str | None] = (
            draw_stock(list(self.places.values()), data, seed) if self.places else {}
        )
        #: each racked pallet's offset from its place (drawn per seed)
        self.place_offsets: dict[str, dict[str, float]] = {}
        if scan_id in pallets:
            placed = place_pallet(pallets[scan_id], scan_side, slot, g)
            self.pallets.append(placed)
        racked = set()
        for name, identity in self.stock.items():
            if identity is None:
                continue
            pid, side = split_identity(identity)
            if pid == scan_id or pid not in pallets:
                continue
            offset = draw_pose_error(data["stock"]["placement_error"], seed, name)
            self.place_offsets[name] = offset
            place_slot = offset_slot(self.places[name].slot, offset, self.floor_z_m)
            placed = place_pallet(pallets[pid], side, place_slot, g)
            placed.slot_name = name
            self.pallets.append(placed)
            racked.add(pid)
        others = [p for pid, p in pallets.items() if pid != scan_id and pid not in racked]
        for i, (pallet, row_slot) in enumerate(zip(others, data["row_slots"], strict=False)):
            placed = place_pallet(pallet, "A", row_slot, g)
            placed.slot_name = f"row[{i}]"
            self.pallets.append(placed)
        self.boxes += [p.body for p in self.pallets]
        if slot["z_m"] > 0.0 and self.pallets and not empty:
            sp = self.pallets[0]
            w, length = data["stand_size_m"]
            self.boxes.append(
                Box(
                    "stand",
                    sp.x_m,
                    sp.y_m,
                    slot["z_m"] / 2,
                    w / 2,
                    length / 2,
                    slot["z_m"] / 2,
                    sp.yaw_rad,
                )
            )
        for rack in data["racks"]:
            self.boxes += rack_boxes(rack)
        for ob in data["obstacles"]:
            cx, cy, cz = ob["center_m"]
            sx, sy, sz = ob["size_m"]
            self.boxes.append(
                Box(ob["name"], cx, cy, cz, sx / 2, sy / 2, sz / 2, math.radians(ob["yaw_deg"]))
            )
        self.max_top_z = max((b.top_z for b in self.boxes), default=-math.inf)
        self._grid = _BoxGrid(self.boxes)

    def ground_truth(self) -> list[dict]:
        """Which pallet side stands where: per pallet its identity (pallet and side shown),
        slot (``scan``, ``row[i]`` or a rack place), footprint centre, base height, facing
        and the height of its block centre line (for ``summary.json``'s ``sim.pallets``; the
        scanned pallet first)."""
        g = self.data["pallet_geometry"]
        out = []
        for p in self.pallets:
            fx, fy, fz = p.face_center_m
            out.append(
                {
                    "identity": p.identity,
                    "slot": p.slot_name,
                    "centre_m": [round(p.x_m, 4), round(p.y_m, 4)],
                    "base_z_m": round(p.z_m, 4),
                    "face_centre_m": [round(fx, 4), round(fy, 4), round(fz, 4)],
                    "facing_deg": round(math.degrees(p.facing_rad), 2),
                    "block_centre_z_m": round(p.z_m + g["board_m"] + g["block_height_m"] / 2.0, 4),
                }
            )
        return out

    def places_truth(self) -> dict[str, str | None]:
        """Rack place -> the identity standing there (None: empty), for this seed."""
        return dict(self.stock)

    def not_enrolled(self) -> list[str]:
        """Identities of the pallets the demo gallery leaves out (``stock.not_enrolled``)."""
        bad = set(stock_pool(self.data)[1]) if self.places else set()
        return [i for i in self.identities() if i[:-1] in bad]

    def enrolled_identities(self) -> list[str]:
        """The identities the demo gallery enrols: every side but the not-enrolled ones."""
        bad = set(self.not_enrolled())
        return [i for i in self.identities() if i not in bad]

    def pads(self) -> dict[str, tuple[float, float]]:
        """The landing / charging pads by name: (x, y) on the floor, m."""
        return {
            str(p["name"]): (float(p["position_m"][0]), float(p["position_m"][1]))
            for p in self.data.get("pads") or []
        }

    def identities(self) -> list[str]:
        """All identities ("1A", "1B", ...) that exist in the world file."""
        return identities(self.data)

    def pallet_at_scan(self) -> PlacedPallet | None:
        """The pallet standing at the scan slot (None when the slot is empty)."""
        if str(self.scan_pallet).strip().lower() in EMPTY:
            return None
        return self.pallets[0] if self.pallets else None

    def collision(self, x: float, y: float, z: float, radius_m: float) -> str | None:
        """Name of the box a sphere at (x, y, z) touches, or None (cheap when high up or
        far from every box: boxes are indexed on a 1 m grid)."""
        if z - radius_m > self.max_top_z:
            return None
        far = radius_m + 1e-9  # beyond this from a box's bounds, distance_m >= radius_m
        for box in self._grid.near(x, y, radius_m):
            ex, ey = box.reach_xy
            if abs(x - box.cx) - ex > far or abs(y - box.cy) - ey > far:
                continue  # the common case, without distance_m's trigonometry
            if box.distance_m(x, y, z) < radius_m:
                return box.name
        return None


class _BoxGrid:
    """Boxes indexed by the 1 m floor cells their footprint (plus a margin) covers."""

    CELL_M = 1.0
    MARGIN_M = 0.3  # queries with a larger radius look at every box

    def __init__(self, boxes: list[Box]) -> None:
        self.boxes = boxes
        self.cells: dict[tuple[int, int], list[Box]] = {}
        c = self.CELL_M
        for b in boxes:
            r = math.hypot(b.hx, b.hy) + self.MARGIN_M
            for i in range(math.floor((b.cx - r) / c), math.floor((b.cx + r) / c) + 1):
                for j in range(math.floor((b.cy - r) / c), math.floor((b.cy + r) / c) + 1):
                    self.cells.setdefault((i, j), []).append(b)

    def near(self, x: float, y: float, radius_m: float) -> list[Box]:
        """Boxes that may lie within ``radius_m`` of (x, y)."""
        if radius_m > self.MARGIN_M:
            return self.boxes
        return self.cells.get((math.floor(x / self.CELL_M), math.floor(y / self.CELL_M)), [])


def with_generated_pallets(data: dict) -> dict:
    """``data`` with its ``pallet_pool`` expanded into ``pallets`` (the pool's count set to
    0, so expanding twice adds nothing)."""
    pool = data.get("pallet_pool") or {}
    if not pool.get("count"):
        return data
    out = dict(data)
    out["pallets"] = list(data["pallets"]) + generated_pallets(pool)
    out["pallet_pool"] = dict(pool, count=0)
    return out


def split_identity(identity: str) -> tuple[str, str]:
    """'3A' -> ('3', 'A')."""
    identity = str(identity).strip()
    return identity[:-1], identity[-1:].upper()


def identities(data: dict) -> list[str]:
    """Every pallet identity of a world's data (generated pallets included)."""
    return [f"{p['id']}{s}" for p in with_generated_pallets(data)["pallets"] for s in ("A", "B")]


def known_words(known: list[str], shown: int = 8) -> str:
    """The pallet sides a message names: all of a few, else the first ones, the last and
    how many (a site's pool has hundreds)."""
    if not known:
        return "none"
    if len(known) <= shown + 2:
        return ", ".join(known)
    return f"{', '.join(known[:shown])}, ..., {known[-1]} ({len(known)} sides)"


def check_world(data: dict, marks: Marks, path: str) -> list[SettingProblem]:
    """Semantic checks of validated world data, located with ``marks`` (path -> loc)."""
    return [problem_at(marks, key, path, message) for key, message in _world_problems(data)]


def _world_problems(data: dict) -> list[tuple[str, str]]:
    """(key, message) for every semantic problem of validated world data (unlocated)."""
    problems = []
    size = data["floor"]["size_m"]
    if not all(s > 0 for s in size):
        problems.append(("floor.size_m", f"floor size {list(size)}: expected two lengths > 0 (m)"))
    data = with_generated_pallets(data)
    seen = set()
    for i, p in enumerate(data["pallets"]):
        if p["id"] in seen:
            problems.append((f"pallets[{i}].id", f"duplicate pallet id '{p['id']}'"))
        seen.add(p["id"])
    known = identities(data)
    if data["scan_pallet"] not in known and str(data["scan_pallet"]).lower() not in EMPTY:
        problems.append(
            (
                "scan_pallet",
                f"scan_pallet '{data['scan_pallet']}' is not a pallet "
                f"side of this world (known: {known_words(known)}; "
                "none leaves the slot empty)",
            )
        )
    if not data["racks"] and len(data["row_slots"]) < max(0, len(data["pallets"]) - 1):
        problems.append(
            (
                "row_slots",
                f"{len(data['pallets']) - 1} pallets need row "
                f"slots but only {len(data['row_slots'])} are given",
            )
        )
    problems += _geometry_problems(data["pallet_geometry"])
    problems += layout_problems(data)
    places = [p for rack in data["racks"] for p in rack_places(rack, data["pallet_geometry"])]
    problems += stock_problems(data, places)
    return problems


def _geometry_problems(g: dict) -> list[tuple[str, str]]:
    """(key, message) for a pallet geometry whose parts do not fit together: the boards and
    blocks taller than the pallet, the blocks wider than its face or deeper than it (each
    value alone in its range, the pallet not buildable: drawing it failed deep in numpy)."""
    out = []
    stack = 3 * g["board_m"] + g["block_height_m"]
    if stack > g["height_m"] + 1e-9:
        out.append(
            (
                "pallet_geometry.height_m",
                f"pallet height {g['height_m']:g} m: expected at least 3 boards and a block "
                f"({3 * g['board_m']:g} + {g['block_height_m']:g} = {stack:g} m; a EPAL: "
                "0.144 m)",
            )
        )
    corner, middle = g["corner_block_m"], g["middle_block_m"]
    blocks = 2 * corner[0] + middle[0]
    if not all(v > 0 for v in (*corner, *middle)):
        out.append(
            (
                "pallet_geometry.corner_block_m",
                f"block sizes {list(corner)} and {list(middle)}: expected lengths > 0 (m)",
            )
        )
    elif blocks > g["length_m"] + 1e-9:
        out.append(
            (
                "pallet_geometry.length_m",
                f"pallet length {g['length_m']:g} m: its three blocks along the face take "
                f"{blocks:g} m (2 x {corner[0]:g} + {middle[0]:g})",
            )
        )
    elif max(corner[1], middle[1]) > g["width_m"] + 1e-9:
        out.append(
            (
                "pallet_geometry.width_m",
                f"pallet width {g['width_m']:g} m: its blocks are {max(corner[1], middle[1]):g} "
                "m deep",
            )
        )
    return out


def load_world(path: str, overrides: dict[str, str] | None = None, seed: int = 0) -> World:
    """Load, validate and build the world at ``path``; ``overrides`` are ``--set`` style
    keys of the world file (``scan_slot.y_m``), reported as ``world.KEY``; ``seed`` draws
    the placement error."""
    marks: Marks = {}
    data = load_yaml_file(path, WORLD_SCHEMA, marks=marks, what="world files")
    if not overrides:
        problems = check_world(data, marks, path)
    else:
        # the world that flies is the file with the overrides: its problems count, and a
        # problem of the file alone that an override fixes does not. Each is said where it
        # comes from: in the file when the file alone has it, as --set when an override
        # wrote that key, else in the file with the overrides named (a stock the pool
        # cannot fill once --set emptied fewer places, ...)
        alone = set(_world_problems(data))
        data = apply_overrides(data, overrides, WORLD_SCHEMA, prefix="world.")
        given = ", ".join(f"--set world.{k}={v}" for k, v in overrides.items())
        problems = []
        for key, message in _world_problems(data):
            if (key, message) in alone:
                problems.append(problem_at(marks, key, path, message))
            elif written_by(key, overrides):
                problems.append(SettingProblem("--set", 0, 0, f"world.{key}: {message}"))
            else:
                problems.append(problem_at(marks, key, path, f"{message} (with {given})"))
    if problems:
        raise ConfigError(problems)
    return World(data, path, seed)
