"""Splitting an inventory's places between the drones of a fleet.

``bays`` (the default) cuts the place list into one block of neighbouring bays per drone,
about the same number of places each and never splitting a bay (two drones never work on
one bay at once), gives each drone the block nearest its start (trying every assignment:
at most 4! = 24); every block is flown in the list's direction, so the drones sweep the
aisle side by side, a block apart. ``faces`` gives each drone whole rack faces (a sweep flies
a face's levels one after the other; two drones never share a face): faces are dealt out so
that the drones get about the same number of places (largest first to the drone with the
fewest), or, with fewer faces than drones, the faces' levels are (with fewer levels too:
blocks of bays). ``round_robin`` deals
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
    groups: dict[tuple, list[str]] = {}
    racks = {world.places[p].rack for p in places}
    by_level = len(racks) < n
    for name in places:
        p = world.places[name]
        groups.setdefault((p.rack, p.level) if by_level else (p.rack,), []).append(name)
    if len(groups) < n:  # fewer face levels than drones: blocks of bays, as split: bays
        return bay_blocks(places, world, n)
    blocks: list[list[str]] = [[] for _ in range(n)]
    for key in sorted(groups, key=lambda k: (-len(groups[k]), k)):
        k = min(range(n), key=lambda i: (len(blocks[i]), i))
        blocks[k] += groups[key]
    order = {name: i for i, name in enumerate(places)}
    return [sorted(b, key=order.__getitem__) for b in blocks]


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
        blocks = face_blocks(places, world, len(names))
    else:
        blocks = bay_blocks(places, world, len(names))
    best: tuple[float, tuple[int, ...]] | None = None
    for perm in itertools.permutations(range(len(names))):
        cost = sum(
            math.dist(starts[names[d]], _centre(blocks[b], world))
            for d, b in enumerate(perm)
            if blocks[b]
        )
        if best is None or cost < best[0] - 1e-9:
            best = (cost, perm)
    assert best is not None
    # Every block is flown in the list's direction: the drones sweep the aisle side by side,
    # a block apart, instead of starting at the ends where their blocks meet.
    return {names[d]: list(blocks[b]) for d, b in enumerate(best[1])}
