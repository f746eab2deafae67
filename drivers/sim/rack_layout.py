"""Where racks and pads stand on the floor, checked: rack names that can start a place
name, racks that do not stand in one another, pads clear of every rack. A world whose pad
stood on a rack passed every check (the drone would take off inside its steel); racks that
overlapped were only found through a place of one inside the other, said at the mission."""

from __future__ import annotations

import math
import re

from drivers.sim.racks import rack_footprint

#: a rack name is the first part of its place names (``A`` in ``A-01-1``): letters and
#: digits, starting with a letter, no hyphen (place names are split at hyphens)
_RACK_NAME = re.compile(r"[A-Za-z][A-Za-z0-9]{0,15}")
#: a pad must stand this far clear of a rack's footprint (the drone's 0.06 m and margin), m
PAD_CLEARANCE_M = 0.15


def _inside(p: tuple[float, float], poly: list[tuple[float, float]], grow: float = 0.0) -> bool:
    """``p`` inside the convex polygon ``poly`` (corners in order), grown by ``grow``."""
    n = len(poly)
    sign = 0.0
    for i in range(n):
        (ax, ay), (bx, by) = poly[i], poly[(i + 1) % n]
        sign += (bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax)
    orient = 1.0 if sign >= 0 else -1.0
    for i in range(n):
        (ax, ay), (bx, by) = poly[i], poly[(i + 1) % n]
        edge = math.hypot(bx - ax, by - ay) or 1.0
        side = orient * ((bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax)) / edge
        if side < -grow:
            return False
    return True


def _overlap(a: list[tuple[float, float]], b: list[tuple[float, float]]) -> bool:
    """Two convex polygons overlap (separating axis test; touching is not overlapping)."""
    for poly in (a, b):
        for i in range(len(poly)):
            (ax, ay), (bx, by) = poly[i], poly[(i + 1) % len(poly)]
            nx, ny = ay - by, bx - ax
            pa = [nx * x + ny * y for x, y in a]
            pb = [nx * x + ny * y for x, y in b]
            if max(pa) <= min(pb) + 1e-9 or max(pb) <= min(pa) + 1e-9:
                return False
    return True


def layout_problems(data: dict) -> list[tuple[str, str]]:
    """(key, message) for racks whose names cannot start a place name, levels above a
    rack's top, racks that stand in one another, and pads on a rack (the drone would take
    off inside its steel)."""
    problems: list[tuple[str, str]] = []
    racks = data["racks"]
    for i, rack in enumerate(racks):
        name = str(rack["name"])
        if not _RACK_NAME.fullmatch(name):
            problems.append(
                (
                    f"racks[{i}].name",
                    f"rack name {name!r}: expected a letter, then up to 15 letters or digits "
                    "(it starts every place name, as A in A-01-1)",
                )
            )
        top = rack.get("height_m")
        pallet = float(data["pallet_geometry"].get("height_m") or 0.0)
        high = [lv for lv in rack["levels_m"] if top is not None and lv + pallet > float(top)]
        if high:
            problems.append(
                (
                    f"racks[{i}].levels_m",
                    f"rack {name}: level {high[0]:g} m with its {pallet:g} m pallet reaches "
                    f"above the rack's top (height_m {float(top):g} m)",
                )
            )
    feet = [rack_footprint(r) for r in racks]
    for j in range(len(racks)):
        for i in range(j):
            if _overlap(feet[i], feet[j]):
                problems.append(
                    (
                        f"racks[{j}].origin_m",
                        f"rack {racks[j]['name']} stands in rack {racks[i]['name']}: their "
                        "footprints overlap (origin_m, facing_deg, bays x bay_width_m, depth_m)",
                    )
                )
    for k, pad in enumerate(data["pads"]):
        x, y = (float(v) for v in pad["position_m"])
        for i, foot in enumerate(feet):
            if _inside((x, y), foot, PAD_CLEARANCE_M):
                problems.append(
                    (
                        f"pads[{k}].position_m",
                        f"pad {pad['name']} at ({x:.2f}, {y:.2f}) stands on rack "
                        f"{racks[i]['name']} (or within {PAD_CLEARANCE_M:g} m of it): a drone "
                        "would take off inside its steel",
                    )
                )
                break
    return problems
