"""The world file's schema: floor, light, pallets, slots, racks, stock, pads (with docs).

Validated by :func:`drivers.sim.world.load_world`; the rack, stock and pad parts come from
:mod:`drivers.sim.racks`.
"""

from __future__ import annotations

from drivers.settings import Field
from drivers.sim.racks import PAD, PALLET_POOL, RACK, STOCK

F, M, L = Field, lambda children, doc="": Field("map", children=children, doc=doc), Field

# Bounds of the numbers a world gives (generous: a hall of a kilometre, any turn written
# within a full turn either way; never 1e20 m or a pallet of no length, which the renderer
# cannot draw). ``_between(lo, hi)`` is the keyword pair of a Field.
XY_M = 1000.0  #: |x|, |y| of anything placed in the world (m)
Z_M = 100.0  #: |z| of a floor, a slot, a scan height (m)
TURN_DEG = 360.0  #: |angle| of a facing or a yaw (deg)


def _between(lo: float, hi: float) -> dict[str, float]:
    return {"min": lo, "max": hi}


XY, Z, TURN = _between(-XY_M, XY_M), _between(-Z_M, Z_M), _between(-TURN_DEG, TURN_DEG)

SLOT = M(
    {
        "x_m": F("float", 0.0, "x of the centre of the shown face (m)", **XY),
        "y_m": F("float", 0.0, "y of the centre of the shown face (m)", **XY),
        "z_m": F("float", 0.0, "height of the pallet base (m); > 0 stands it on a stand box", **Z),
        "facing_deg": F(
            "float", 180.0, "direction the shown face looks to (deg, 180 = -x)", **TURN
        ),
    }
)
#: Where the demo gallery enrols every pallet side unless the world says otherwise
#: (``enrolment_slot``): the centre of the enrolled face, facing -x. The shipped worlds keep
#: their racks and hall clear of it (the site's is just behind rack D, by the hall's edge).
ENROLMENT_SLOT = {"x_m": 9.30, "y_m": 0.0, "facing_deg": 180.0}
ENROLMENT = M(
    {
        "x_m": F("float", ENROLMENT_SLOT["x_m"], "x of the centre of the enrolled face (m)", **XY),
        "y_m": F("float", ENROLMENT_SLOT["y_m"], "y of the centre of the enrolled face (m)", **XY),
        "facing_deg": F(
            "float",
            ENROLMENT_SLOT["facing_deg"],
            "direction the enrolled face looks to (deg, 180 = -x)",
            **TURN,
        ),
    },
    doc="where the demo gallery enrols every pallet side: alone on a stand (its blocks at "
    "0.255 m), scanned from 0.40 m in front of it. Choose a spot that looks like where the "
    "world's pallets are seen: the same lamps above, the same kind of background behind "
    "(a wall, a rack's back). A rack standing on the spot is left out of the enrolment "
    "scans, and the spot then looks unlike the aisles (docs/inventory.md)",
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
                "z_m": F("float", 0.0, "floor height (m)", **Z),
                "texture": F("str", "concrete", "floor texture name (renderer)"),
            }
        ),
        "lighting": M(
            {
                "ambient": F("float", 0.6, "ambient light level 0..1", min=0.0, max=1.0),
                "colour_temperature_k": F(  # candle-light to blue sky (the renderer's span)
                    "float", 4000.0, "light colour temperature (K)", **_between(1000.0, 20000.0)
                ),
                "lamps": L(
                    "list",
                    [],
                    "point lamps",
                    item=M(
                        {
                            "position_m": F("vec", [0.0, 0.0, 4.0], "lamp position (m)", length=3),
                            "intensity": F(
                                "float", 1.0, "relative intensity", **_between(0.0, 100.0)
                            ),
                        }
                    ),
                ),
            }
        ),
        "pallet_geometry": M(
            {
                # a half pallet (0.6 x 0.4 m) to a big industrial one, with room either way
                "length_m": F("float", 1.2, "EPAL length", **_between(0.2, 3.0)),
                "width_m": F("float", 0.8, "EPAL width", **_between(0.2, 3.0)),
                "height_m": F("float", 0.144, "EPAL height", **_between(0.05, 0.5)),
                "board_m": F(
                    "float", 0.022, "bottom and top board thickness", **_between(0.005, 0.1)
                ),
                "block_height_m": F("float", 0.078, "support block height", **_between(0.02, 0.4)),
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
        "enrolment_slot": ENROLMENT,
        "placement_error": M(
            {
                "lateral_m": F(
                    "float", 0.0, "along the face, drawn in +-this (m)", **_between(0.0, 1.0)
                ),
                "depth_m": F(
                    "float", 0.0, "away from the scan line, in +-this (m)", **_between(0.0, 1.0)
                ),
                "height_m": F("float", 0.0, "base height, in +-this (m)", **_between(0.0, 1.0)),
                "yaw_deg": F(
                    "float",
                    0.0,
                    "turn about the face centre, in +-this (deg)",
                    **_between(0.0, 180.0),
                ),
            },
            doc="how far the scanned pallet stands off its slot: each offset is drawn "
            "uniformly per seed (summary.json sim.placement_offset has the draw)",
        ),
        "placement_offset": M(
            {
                "lateral_m": F(
                    "float",
                    0.0,
                    "along the face, to its left seen from in front (m)",
                    **_between(-1.0, 1.0),
                ),
                "depth_m": F("float", 0.0, "away from the scan line (m)", **_between(-1.0, 1.0)),
                "height_m": F("float", 0.0, "base height (m)", **_between(-1.0, 1.0)),
                "yaw_deg": F(
                    "float",
                    0.0,
                    "turn about the face centre, counter-clockwise (deg)",
                    **_between(-180.0, 180.0),
                ),
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
                    "yaw_deg": F("float", 0.0, "box yaw (deg)", **TURN),
                }
            ),
        ),
        "racks": L("list", [], "pallet racks with named places (drivers/sim/racks.py)", item=RACK),
        "stock": STOCK,
        "pallet_pool": PALLET_POOL,
        "pads": L("list", [], "landing / charging pads, one per drone", item=PAD),
        "scan_line": M(
            {
                "x_m": F("float", 8.90, "x of the scan line (drone position while scanning)", **XY),
                "y_from_m": F("float", -0.5, "scan start y", **XY),
                "y_to_m": F("float", 0.5, "scan end y", **XY),
                "z_m": F("float", 0.255, "scan height", **Z),
                "yaw_deg": F("float", 0.0, "drone yaw while scanning", **TURN),
            },
            doc="where the mission scans (documentation for missions and the renderer)",
        ),
    }
)
