"""Splitting an inventory's places between the drones of a fleet.

``bays`` (the default) cuts the place list into one block of neighbouring bays per drone,
about the same number of places each and never splitting a bay (two drones never work on
one bay at once), gives each drone the block nearest its start (trying every assignment:
at most 4! = 24); every block is flown in the list's direction, so the drones sweep the
aisle side by side, a block apart. ``faces`` gives each drone whole rack faces (a sweep flies
a face's levels one after the other; two drones never share a face): faces are dealt out so
that the busiest drone has as few places as can be and, among such deals, a drone's faces
lie close together (both faces of one aisle rather than faces in two aisles, whose drone
would cross the others' way); with fewer faces than drones, the faces' levels are dealt
(with fewer levels too: blocks of bays). ``round_robin`` deals
the places out in turn (drones then meet often: the airspace keeps them apart, at a cost in
time).
"""

from __future__ import annotations

import itertools
import math
from typing import Any


def _centre(places: list[str], world: Any) -> tuple[float, float, float]:
    pts = [world.places[p].row_m for p in places]
    return tuple(sum(p[k] for p in pts) / len(pts) for k in range(3))  # type: ignore[return-value]


def bay_blocks(places: list[str], world: Any, n: int) -> list[list[str]]:
    """``places`` (in order) cut into ``n`` blocks of whole bays of about equal size."""
    bays: list[list[str]] = []
    index: dict[tuple[str, int], int] = {}
    for name in places:
        p = world.places[name]
        key = (p.rack, p.bay)
        if key not in index:
            index[key] = len(bays)
            bays.append([])
        bays[index[key]].append(name)
    blocks: list[list[str]] = [[] for _ in range(n)]
    total, done, k = len(places), 0, 0
    for i, bay in enumerate(bays):
        # the next block once this one has its share (and never leave a later one empty)
        left = len(bays) - i
        while k < n - 1 and blocks[k] and (done >= total * (k + 1) / n or left <= n - 1 - k):
            k += 1
        blocks[k] += bay
        done += len(bay)
    return blocks


def face_blocks(places: list[str], world: Any, n: int) -> list[list[str]]:
    """``places`` cut into ``n`` groups of whole rack faces (of whole face levels when there
    are fewer faces than drones; of bays when there are fewer face levels too), about equal
    in places, each in the list's order."""
    return face_deals(places, world, n)[0]


def face_deals(places: list[str], world: Any, n: int) -> list[list[list[str]]]:
    """The equally good ways :func:`face_blocks` may cut ``places`` (one, or several that
    tie: the fleet takes the one nearest its drones' starts)."""
    groups: dict[tuple, list[str]] = {}
    racks = {world.places[p].rack for p in places}
    by_level = len(racks) < n
    for name in places:
        p = world.places[name]
        groups.setdefault((p.rack, p.level) if by_level else (p.rack,), []).append(name)
    if len(groups) < n:  # fewer face levels than drones: blocks of bays, as split: bays
        return [bay_blocks(places, world, n)]
    order = {name: i for i, name in enumerate(places)}
    keys = sorted(groups, key=lambda k: order[groups[k][0]])  # in the list's order
    if len(keys) <= MAX_FACES_SEARCHED:
        deals = _nearest_deals(keys, groups, world, n)
    else:  # too many ways to try: largest first to the drone with the fewest places
        blocks: list[list[str]] = [[] for _ in range(n)]
        for key in sorted(groups, key=lambda k: (-len(groups[k]), k)):
            k = min(range(n), key=lambda i: (len(blocks[i]), i))
            blocks[k] += groups[key]
        deals = [blocks]
    return [[sorted(b, key=order.__getitem__) for b in blocks] for blocks in deals]


#: faces (or face levels) dealt out by trying every way (the ways to cut 10 into 4 groups:
#: 34,105); more are dealt largest first
MAX_FACES_SEARCHED = 10


def _nearest_deals(
    keys: list[tuple], groups: dict[tuple, list[str]], world: Any, n: int
) -> list[list[list[str]]]:
    """The faces (``groups``) cut into ``n`` groups with the fewest places for the busiest
    drone and, among those, the shortest flights between a drone's faces (from the aisle
    side of one to the next, in the list's order): two faces of one aisle rather than two
    faces back to back, or in two aisles (a drone given both would cross the others' way).
    Every cut that ties on both."""
    where = {k: _aisle_point(groups[k], world) for k in keys}
    best: tuple[int, float] | None = None
    ties: list[list[list[tuple]]] = []
    for parts in _partitions(keys, n):
        busiest = max(sum(len(groups[k]) for k in part) for part in parts)
        travel = sum(
            math.dist(where[a], where[b]) for part in parts for a, b in itertools.pairwise(part)
        )
        cost = (busiest, round(travel, 6))
        if best is None or cost < best:
            best, ties = cost, [parts]
        elif cost == best:
            ties.append(parts)
    return [[[name for k in part for name in groups[k]] for part in parts] for parts in ties]


def _aisle_point(places: list[str], world: Any, standoff_m: float = 0.5) -> tuple:
    """Where a drone scans ``places`` from, on average: ``standoff_m`` in front of their
    block rows, on the aisle side."""
    pts = []
    for name in places:
        p = world.places[name]
        yaw = math.radians(p.look_deg)
        x, y, z = p.row_m
        pts.append((x - standoff_m * math.cos(yaw), y - standoff_m * math.sin(yaw), z))
    return tuple(sum(q[i] for q in pts) / len(pts) for i in range(3))


def _partitions(items: list, n: int) -> Any:
    """Every way to cut ``items`` into ``n`` non-empty groups, each once (the groups keep
    the items' order)."""
    if n == 1:
        yield [list(items)]
        return
    if len(items) == n:
        yield [[i] for i in items]
        return
    if len(items) < n:
        return
    last, rest = items[-1], items[:-1]
    for parts in _partitions(rest, n - 1):  # the last item alone
        yield [*parts, [last]]
    for parts in _partitions(rest, n):  # or joining one of the groups
        for k in range(n):
            yield [*parts[:k], [*parts[k], last], *parts[k + 1 :]]


def split_places(
    places: list[str], world: Any, starts: dict[str, tuple[float, float, float]], mode: str = "bays"
) -> dict[str, list[str]]:
    """Each drone's places (by drone name, in flying order); see the module doc."""
    names = list(starts)
    if not places:
        return {n: [] for n in names}
    if mode == "round_robin":
        return {n: places[i :: len(names)] for i, n in enumerate(names)}
    if mode == "faces":
        deals = face_deals(places, world, len(names))
    else:
        deals = [bay_blocks(places, world, len(names))]
    best: tuple[float, list[list[str]], tuple[int, ...]] | None = None
    for blocks in deals:  # of equally good deals, the one nearest the drones' starts
        centres = [_centre(b, world) if b else None for b in blocks]
        for perm in itertools.permutations(range(len(names))):
            cost = sum(
                math.dist(starts[names[d]], centres[b])  # type: ignore[arg-type]
                for d, b in enumerate(perm)
                if blocks[b]
            )
            if best is None or cost < best[0] - 1e-9:
                best = (cost, blocks, perm)
    assert best is not None
    # Every block is flown in the list's direction: the drones sweep the aisle side by side,
    # a block apart, instead of starting at the ends where their blocks meet.
    return {names[d]: list(best[1][b]) for d, b in enumerate(best[2])}
