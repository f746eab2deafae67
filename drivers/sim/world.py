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
    Field,
    Marks,
    SettingProblem,
    apply_overrides,
    load_yaml_file,
    problem_at,
)

F, M, L = Field, lambda children, doc="": Field("map", children=children, doc=doc), Field

SLOT = M(
    {
        "x_m": F("float", 0.0, "x of the centre of the shown face (m)"),
        "y_m": F("float", 0.0, "y of the centre of the shown face (m)"),
        "z_m": F("float", 0.0, "height of the pallet base (m); > 0 stands it on a stand box"),
        "facing_deg": F("float", 180.0, "direction the shown face looks to (deg, 180 = -x)"),
    }
)
# Pallet looks (perception.synth.looks names them; tests/test_rig_world.py checks the lists
# agree): the wood's tone, a paint, and ageing since enrolment.
WOODS = ("auto", "fresh", "pale", "yellowed", "orange", "brown", "grey", "silver", "dark", "wet")
PAINTS = ("auto", "none", "blue", "red", "green", "yellow", "black", "white", "grey", "brown")
SIDE = M(
    {
        "stamp": F("str", "EPAL", "brand stamp text on the blocks"),
        "wear": F("float", 0.3, "dirt and wear, 0 (new) .. 1 (very used)", min=0.0, max=1.0),
        "texture_seed": F("int", 0, "seed of the procedural wood texture"),
        "wood": F("choice", "auto", "wood tone (auto: pallet_look.wood)", choices=WOODS),
        "paint": F("choice", "auto", "paint (auto: pallet_look.paint)", choices=PAINTS),
        "age": F(
            "float",
            None,
            "ageing since enrolment 0..1 (default: pallet_look.age)",
            min=0.0,
            max=1.0,
            nullable=True,
        ),
    }
)
LOOK = M(
    {
        "wood": F(
            "choice", "auto", "wood tone of every side (auto: fresh, per pallet)", choices=WOODS
        ),
        "paint": F("choice", "none", "paint of every side", choices=PAINTS[1:]),
        "age": F(
            "float",
            0.0,
            "stains, dust, scratches, faded stamps since enrolment, 0..1 "
            "(the demo gallery enrols every side at 0)",
            min=0.0,
            max=1.0,
        ),
    },
    doc="the look of every pallet side unless the side sets its own (wood, paint, age)",
)
WORLD_SCHEMA = M(
    {
        "name": F("str", "world", "world name"),
        "floor": M(
            {
                "size_m": F("vec", [20.0, 10.0], "floor extent along x and y (m)", length=2),
                "origin_m": F(
                    "vec", [-2.0, -5.0], "corner of the floor with the smallest x, y", length=2
                ),
                "z_m": F("float", 0.0, "floor height (m)"),
                "texture": F("str", "concrete", "floor texture name (renderer)"),
            }
        ),
        "lighting": M(
            {
                "ambient": F("float", 0.6, "ambient light level 0..1", min=0.0, max=1.0),
                "colour_temperature_k": F("float", 4000.0, "light colour temperature (K)"),
                "lamps": L(
                    "list",
                    [],
                    "point lamps",
                    item=M(
                        {
                            "position_m": F("vec", [0.0, 0.0, 4.0], "lamp position (m)", length=3),
                            "intensity": F("float", 1.0, "relative intensity", min=0.0),
                        }
                    ),
                ),
            }
        ),
        "pallet_geometry": M(
            {
                "length_m": F("float", 1.2, "EPAL length"),
                "width_m": F("float", 0.8, "EPAL width"),
                "height_m": F("float", 0.144, "EPAL height"),
                "board_m": F("float", 0.022, "bottom and top board thickness"),
                "block_height_m": F("float", 0.078, "support block height"),
                "corner_block_m": F(
                    "vec", [0.145, 0.100], "corner block [along face, depth] (approx.)", length=2
                ),
                "middle_block_m": F(
                    "vec", [0.145, 0.145], "middle block [along face, depth] (approx.)", length=2
                ),
            }
        ),
        "pallets": L(
            "list",
            [],
            "physical pallets; each has two sides A and B",
            item=M(
                {
                    "id": F("str", None, "pallet number, e.g. '3'", required=True),
                    "sides": M({"A": SIDE, "B": SIDE}),
                }
            ),
        ),
        "pallet_look": LOOK,
        "scan_pallet": F(
            "str", "3A", "identity (pallet id + side) at the scan slot, or none (empty slot)"
        ),
        "scan_slot": SLOT,
        "placement_error": M(
            {
                "lateral_m": F("float", 0.0, "along the face, drawn in +-this (m)", min=0.0),
                "depth_m": F("float", 0.0, "away from the scan line, in +-this (m)", min=0.0),
                "height_m": F("float", 0.0, "base height, in +-this (m)", min=0.0),
                "yaw_deg": F("float", 0.0, "turn about the face centre, in +-this (deg)", min=0.0),
            },
            doc="how far the scanned pallet stands off its slot: each offset is drawn "
            "uniformly per seed (summary.json sim.placement_offset has the draw)",
        ),
        "placement_offset": M(
            {
                "lateral_m": F("float", 0.0, "along the face, to its left seen from in front (m)"),
                "depth_m": F("float", 0.0, "away from the scan line (m)"),
                "height_m": F("float", 0.0, "base height (m)"),
                "yaw_deg": F("float", 0.0, "turn about the face centre, counter-clockwise (deg)"),
            },
            doc="a fixed offset of the scanned pallet from its slot, added to the drawn "
            "placement error",
        ),
        "stand_size_m": F(
            "vec", [0.8, 1.2], "footprint of the stand under a raised slot", length=2
        ),
        "row_slots": L(
            "list", [], "slots the other pallets fill in id order (side A shown)", item=SLOT
        ),
        "obstacles": L(
            "list",
            [],
            "other box obstacles",
            item=M(
                {
                    "name": F("str", "box", "obstacle name"),
                    "center_m": F("vec", [0.0, 0.0, 0.5], "box centre (m)", length=3),
                    "size_m": F("vec", [1.0, 1.0, 1.0], "box size along its x, y, z (m)", length=3),
                    "yaw_deg": F("float", 0.0, "box yaw (deg)"),
                }
            ),
        ),
        "scan_line": M(
            {
                "x_m": F("float", 8.90, "x of the scan line (drone position while scanning)"),
                "y_from_m": F("float", -0.5, "scan start y"),
                "y_to_m": F("float", 0.5, "scan end y"),
                "z_m": F("float", 0.255, "scan height"),
                "yaw_deg": F("float", 0.0, "drone yaw while scanning"),
            },
            doc="where the mission scans (documentation for missions and the renderer)",
        ),
    }
)


@dataclass(frozen=True)
class Box:
    """An oriented box (yaw only): centre, half sizes, yaw; ``name`` says what it is."""

    name: str
    cx: float
    cy: float
    cz: float
    hx: float
    hy: float
    hz: float
    yaw_rad: float = 0.0

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
        self.data, self.path = data, path
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
        if scan_id in pallets:
            self.pallets.append(place_pallet(pallets[scan_id], scan_side, slot, g))
        others = [p for pid, p in pallets.items() if pid != scan_id]
        for pallet, slot in zip(others, data["row_slots"], strict=False):
            self.pallets.append(place_pallet(pallet, "A", slot, g))
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
        for ob in data["obstacles"]:
            cx, cy, cz = ob["center_m"]
            sx, sy, sz = ob["size_m"]
            self.boxes.append(
                Box(ob["name"], cx, cy, cz, sx / 2, sy / 2, sz / 2, math.radians(ob["yaw_deg"]))
            )
        self.max_top_z = max((b.top_z for b in self.boxes), default=-math.inf)

    def ground_truth(self) -> list[dict]:
        """Which pallet side stands where: per pallet its identity (pallet and side shown),
        footprint centre, base height, facing and the height of its block centre line (for
        ``summary.json``'s ``sim.pallets``; the first is the scanned pallet)."""
        g = self.data["pallet_geometry"]
        out = []
        empty = str(self.scan_pallet).strip().lower() in EMPTY
        for i, p in enumerate(self.pallets, start=1 if empty else 0):
            fx, fy, fz = p.face_center_m
            out.append(
                {
                    "identity": p.identity,
                    "slot": "scan" if i == 0 else f"row[{i - 1}]",
                    "centre_m": [round(p.x_m, 4), round(p.y_m, 4)],
                    "base_z_m": round(p.z_m, 4),
                    "face_centre_m": [round(fx, 4), round(fy, 4), round(fz, 4)],
                    "facing_deg": round(math.degrees(p.facing_rad), 2),
                    "block_centre_z_m": round(p.z_m + g["board_m"] + g["block_height_m"] / 2.0, 4),
                }
            )
        return out

    def identities(self) -> list[str]:
        """All identities ("1A", "1B", ...) that exist in the world file."""
        return identities(self.data)

    def pallet_at_scan(self) -> PlacedPallet | None:
        """The pallet standing at the scan slot (None when the slot is empty)."""
        if str(self.scan_pallet).strip().lower() in EMPTY:
            return None
        return self.pallets[0] if self.pallets else None

    def collision(self, x: float, y: float, z: float, radius_m: float) -> str | None:
        """Name of the box a sphere at (x, y, z) touches, or None (cheap when high up)."""
        if z - radius_m > self.max_top_z:
            return None
        for box in self.boxes:
            if box.distance_m(x, y, z) < radius_m:
                return box.name
        return None


def split_identity(identity: str) -> tuple[str, str]:
    """'3A' -> ('3', 'A')."""
    identity = str(identity).strip()
    return identity[:-1], identity[-1:].upper()


def identities(data: dict) -> list[str]:
    """Every pallet identity of a world's data."""
    return [f"{p['id']}{s}" for p in data["pallets"] for s in ("A", "B")]


def check_world(data: dict, marks: Marks, path: str) -> list[SettingProblem]:
    """Semantic checks of validated world data, located with ``marks`` (path -> loc)."""
    problems = []

    def where(key: str, message: str) -> SettingProblem:
        return problem_at(marks, key, path, message)

    seen = set()
    for i, p in enumerate(data["pallets"]):
        if p["id"] in seen:
            problems.append(where(f"pallets[{i}].id", f"duplicate pallet id '{p['id']}'"))
        seen.add(p["id"])
    known = identities(data)
    if data["scan_pallet"] not in known and str(data["scan_pallet"]).lower() not in EMPTY:
        problems.append(
            where(
                "scan_pallet",
                f"scan_pallet '{data['scan_pallet']}' is not a pallet "
                f"side of this world (known: {', '.join(known) or 'none'}; "
                "none leaves the slot empty)",
            )
        )
    if len(data["row_slots"]) < max(0, len(data["pallets"]) - 1):
        problems.append(
            where(
                "row_slots",
                f"{len(data['pallets']) - 1} pallets need row "
                f"slots but only {len(data['row_slots'])} are given",
            )
        )
    return problems


def load_world(path: str, overrides: dict[str, str] | None = None, seed: int = 0) -> World:
    """Load, validate and build the world at ``path``; ``overrides`` are ``--set`` style
    keys of the world file (``scan_slot.y_m``), reported as ``world.KEY``; ``seed`` draws
    the placement error."""
    marks: Marks = {}
    data = load_yaml_file(path, WORLD_SCHEMA, marks=marks)
    problems = check_world(data, marks, path)
    if overrides:
        data = apply_overrides(data, overrides, WORLD_SCHEMA, prefix="world.")
        scan = data["scan_pallet"]
        if scan not in identities(data) and str(scan).strip().lower() not in EMPTY:
            problems.append(
                SettingProblem(
                    "--set",
                    0,
                    0,
                    f"world.scan_pallet={data['scan_pallet']}: not a pallet side "
                    f"of {path} (known: {', '.join(identities(data))}; none leaves "
                    "the slot empty)",
                )
            )
    if problems:
        raise ConfigError(problems)
    return World(data, path, seed)
