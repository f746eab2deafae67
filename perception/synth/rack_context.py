"""Pallet racks around a training pallet: what a drone sees when it scans a racked pallet.

A pallet on a rack beam looks unlike one on the floor or on a stand box: a painted steel
beam runs right under its bottom board, uprights stand at the bay's ends (in front of the
pallet's face plane), neighbour pallets stand beside it in wide bays, and the levels above
and below show more beams and pallets. A detector trained without this learns that a block
sits above a dark stand: on a rack its boxes grow down into the beam (the face estimate
then reads the block row as too tall, hence too near). :func:`rack_variant` draws one of a
finite set of rack layouts (so scenes can be cached) in the local frame of
:mod:`perception.synth.dataset`: the shown face centred at x = 0, y = 0, looking towards
-x, its base at ``base_z``.

Colours vary over the common rack paints (orange, blue, yellow, green, grey, red) so that
no colour is learned as "the beam".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: rack steel paints (materials of :mod:`perception.synth.materials`)
PAINTS = ("steel_orange", "steel_blue", "steel_yellow", "steel_green", "steel_grey", "steel_red")


@dataclass(frozen=True)
class RackVariant:
    """One rack layout around the training pallet (see the module doc)."""

    beam_paint: str
    upright_paint: str
    bay_width_m: float  # between upright centres
    offset_m: float  # the pallet's centre along the bay from the bay centre
    setback_m: float  # the pallet's face behind the front line
    beam_height_m: float
    level_gap_m: float  # to the levels above and below
    neighbours: tuple[float, ...]  # along-face offsets of neighbour pallets in the bay


def rack_variant(rng: np.random.Generator, length_m: float = 1.2) -> RackVariant:
    """A random rack layout: a one-pallet bay (1.3-1.5 m) or a wide bay with a neighbour
    pallet on one or both sides, beam 0.08-0.16 m, setback 0-0.1 m, paints at random."""
    paints = PAINTS
    wide = rng.random() < 0.4
    gap = float(rng.uniform(0.06, 0.15))
    if wide:
        sides = [s for s in (-1.0, 1.0) if rng.random() < 0.7] or [1.0]
        neighbours = tuple(s * (length_m + gap) for s in sides)
        bay = 3 * length_m + 4 * gap if len(sides) == 2 else 2 * length_m + 3 * gap
        offset = 0.0 if len(sides) == 2 else -sides[0] * (length_m + gap) / 2
    else:
        neighbours, bay, offset = (), length_m + float(rng.uniform(0.1, 0.3)), 0.0
        offset = float(rng.uniform(-0.05, 0.05))
    return RackVariant(
        paints[int(rng.integers(len(paints)))],
        paints[int(rng.integers(len(paints)))],
        round(bay, 3),
        round(offset, 3),
        round(float(rng.uniform(0.0, 0.1)), 3),
        round(float(rng.uniform(0.08, 0.16)), 3),
        round(float(rng.uniform(0.9, 1.6)), 3),
        neighbours,
    )


def rack_boxes(v: RackVariant, base_z: float, depth_m: float = 1.0) -> list[tuple]:
    """Boxes ((centre), (half sizes), yaw, material) of the rack's steel around a pallet at
    ``base_z``: beams under this level and the ones above and below, uprights at the bay's
    ends, front and back."""
    front = -v.setback_m  # x of the front line (the pallet's face is at x = 0)
    half_bay = v.bay_width_m / 2
    centre_y = -v.offset_m  # the bay centre, seen from the pallet
    out: list[tuple] = []
    upright = 0.08
    top = base_z + v.level_gap_m + 0.3
    for y in (centre_y - half_bay, centre_y + half_bay):
        for x in (front + upright / 2, front + depth_m - upright / 2):
            out.append(((x, y, top / 2), (upright / 2, upright / 2, top / 2), 0.0, v.upright_paint))
    levels = [base_z, base_z + v.level_gap_m, base_z - v.level_gap_m]
    for z in levels:
        if z < v.beam_height_m:
            continue  # that level stands on the floor: no beam
        for x in (front + 0.025, front + depth_m - 0.025):
            out.append(
                (
                    (x, centre_y, z - v.beam_height_m / 2),
                    (0.025, half_bay - upright / 2, v.beam_height_m / 2),
                    0.0,
                    v.beam_paint,
                )
            )
    return out


def neighbour_slots(v: RackVariant, base_z: float) -> list[tuple[float, float, float, float]]:
    """(face x, face y, base z, facing) of the pallets beside the training pallet in its bay
    and of those on the levels above and below (directly over and under it)."""
    slots = [(0.0, dy, base_z, math.pi) for dy in v.neighbours]
    for dz in (v.level_gap_m, -v.level_gap_m):
        z = base_z + dz
        if z >= 0.0 and (z >= v.beam_height_m or z < 0.01):
            slots.append((0.0, 0.0, max(z, 0.0), math.pi))
    return slots
