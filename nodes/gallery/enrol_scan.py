"""Enrolment scans without a flight: what the AI-deck camera sees while it moves along a
canonical scan line in front of one pallet side standing alone in a canonical slot, run
through the same detector and block sequencer as a mission (:func:`scan_blocks`).

:func:`scan_frames` renders the whole scan; :func:`enrolment_frames` renders only the frames
the block sequencer needs (where each block crosses its window, from the camera model and
the scene), which is what lets a pool of thousands of sides be enrolled in minutes. The
demo gallery (:mod:`nodes.gallery.demo`) is built from these scans.
"""

from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from functools import lru_cache
from typing import Any

import numpy as np

from drivers.sim.world_schema import ENROLMENT_SLOT

ENROL_SPEED_MPS = 0.1  # camera speed along the scan line while enrolling
ENROL_RATE_HZ = 15.0
#: frames fed to the block sequencer while each block crosses its window (left of the image
#: centre by at most ``max_distance_left_px``): the sequencer keeps the sharpest of them
VIEWS_PER_BLOCK = 5
#: a block this far right of the centre (px) has been committed by the sequencer (its
#: ``min_distance_right_px`` 20 px, and a margin for the box's jitter)
COMMIT_PX = 24.0
#: at most this many frames between two frames looked at while a block is tracked (the
#: sequencer forgets a track unseen for ``lost_after_frames``, 8)
MAX_GAP_FRAMES = 6


#: Where every side is enrolled unless the world sets ``enrolment_slot``: the face centre
#: at (9.30, 0.0), facing -x, the block row at 0.255 m (on a stand), seen from a line
#: 0.40 m in front of it from 0.75 m right of the centre to 0.65 m left (blocks enter left
#: of the image centre and leave right of it, as the block sequencer needs).
CANONICAL_SLOT = ENROLMENT_SLOT
CANONICAL_ROW_Z_M = 0.255
#: the scan line's distance in front of the enrolled face, and its ends: from this far to
#: the camera's right of the face centre to this far to its left (m)
SCAN_DISTANCE_M = 0.40
SCAN_FROM_RIGHT_M = 0.75
SCAN_TO_LEFT_M = 0.65


def enrolment_slot(data: dict) -> dict:
    """The world's enrolment slot (``enrolment_slot``, else :data:`CANONICAL_SLOT`)."""
    slot = data.get("enrolment_slot")
    return dict(slot) if isinstance(slot, dict) else dict(CANONICAL_SLOT)


def enrolment_line(slot: dict) -> tuple[float, float, float, float, float]:
    """The enrolment scan line in front of ``slot``: (x, y) where it starts, (x, y) where it
    ends, the camera's yaw (deg): facing the face, moving to the camera's left."""
    n = _unit(slot["facing_deg"])  # the way the face looks
    yaw_deg = (slot["facing_deg"] + 180.0) % 360.0
    ahead = _unit(yaw_deg)
    left = (-ahead[1], ahead[0])
    cx = slot["x_m"] + n[0] * SCAN_DISTANCE_M
    cy = slot["y_m"] + n[1] * SCAN_DISTANCE_M
    return (
        cx - left[0] * SCAN_FROM_RIGHT_M,
        cy - left[1] * SCAN_FROM_RIGHT_M,
        cx + left[0] * SCAN_TO_LEFT_M,
        cy + left[1] * SCAN_TO_LEFT_M,
        yaw_deg,
    )


def _unit(deg: float) -> tuple[float, float]:
    """The unit vector ``deg`` from +x, exact along the axes (sin(180 deg) is 1.2e-16 in
    floats: the canonical line's ends stay the numbers they were written as)."""
    r = math.radians(deg)
    return round(math.cos(r), 15) + 0.0, round(math.sin(r), 15) + 0.0


def canonical_world_data(data: dict, identity: str) -> dict:
    """The world of an enrolment scan: ``identity`` alone in the enrolment slot
    (:func:`enrolment_slot`: its pallet, the world's geometry, lighting, floor and racks,
    but for a rack standing where the enrolled pallet does: :func:`clear_racks`; no other
    pallet, no obstacle, no placement error), as it looked when enrolled (no ageing)."""
    g = data["pallet_geometry"]
    out = dict(data)  # what changes is replaced below, the rest is shared (a pool of
    # thousands of pallets: a deep copy per side took a second)
    pallet_id = identity[:-1]
    out["pallets"] = [p for p in data["pallets"] if str(p["id"]) == pallet_id]
    base_z = CANONICAL_ROW_Z_M - g["board_m"] - g["block_height_m"] / 2.0
    slot = enrolment_slot(data)
    out["scan_slot"] = dict(slot, z_m=base_z)
    out["scan_pallet"] = identity
    out["row_slots"] = []
    out["obstacles"] = []
    out["racks"] = clear_racks(data.get("racks") or [], g, slot)
    for key in ("placement_error", "placement_offset"):
        out[key] = {k: 0.0 for k in out.get(key, {})}
    x0, y0, x1, y1, yaw_deg = enrolment_line(slot)
    # the world schema's scan line (x_m, y_from_m .. y_to_m) and where it ends along x
    out["scan_line"] = {
        "x_m": x0,
        "y_from_m": y0,
        "y_to_m": y1,
        "z_m": CANONICAL_ROW_Z_M,
        "yaw_deg": yaw_deg,
        "x_to_m": x1,
    }
    return unaged(out)


def clear_racks(racks: list[dict], geometry: dict, slot: dict | None = None) -> list[dict]:
    """The racks that leave the enrolment slot (``slot``, default :data:`CANONICAL_SLOT`)
    free. A world may put a rack there (a third aisle at x 9-10 m did), and its steel
    then stood inside and around the enrolled pallet, hid its blocks from the scan line,
    and enrolled those views (142 of 234 places right). A rack whose footprint overlaps
    the enrolled pallet's is left out of the enrolment scan; the others stay, so the
    worlds whose slot is clear enrol as before."""
    slot = slot or CANONICAL_SLOT
    f = math.radians(slot["facing_deg"])
    n, right = (math.cos(f), math.sin(f)), (-math.sin(f), math.cos(f))
    half, width = geometry["length_m"] / 2.0, geometry["width_m"]
    cx, cy = slot["x_m"], slot["y_m"]
    pallet = [
        (cx + right[0] * a - n[0] * d, cy + right[1] * a - n[1] * d)
        for a, d in ((-half, 0.0), (half, 0.0), (half, width), (-half, width))
    ]
    from drivers.sim.racks import rack_footprint

    return [rack for rack in racks if not _overlap(pallet, rack_footprint(rack))]


def enrolment_note(data: dict) -> str:
    """What a user should know of where the world's demo gallery is enrolled: the racks
    standing on the enrolment slot, which its scans leave out ('' if none)."""
    racks = data.get("racks") or []
    slot = enrolment_slot(data)
    kept = clear_racks(racks, data["pallet_geometry"], slot)
    left_out = [str(r["name"]) for r in racks if r not in kept]
    if not left_out:
        return ""
    where = f"({slot['x_m']:.2f}, {slot['y_m']:.2f})"
    return (
        f"the demo gallery's enrolment slot {where} stands on rack {', '.join(left_out)}, "
        "left out of its enrolment scans: the pallets are enrolled in a spot unlike the "
        "aisles, and many may be answered unknown; set enrolment_slot to a free spot that "
        "looks like the aisles (docs/inventory.md)"
    )


def _overlap(p: list[tuple[float, float]], q: list[tuple[float, float]]) -> bool:
    """True if the convex polygons ``p`` and ``q`` overlap (separating axis test)."""
    for poly in (p, q):
        for (x0, y0), (x1, y1) in zip(poly, poly[1:] + poly[:1], strict=True):
            ax, ay = y0 - y1, x1 - x0  # the edge's normal
            a = [ax * x + ay * y for x, y in p]
            b = [ax * x + ay * y for x, y in q]
            if max(a) <= min(b) or max(b) <= min(a):
                return False
    return True


def unaged(data: dict) -> dict:
    """The world's pallets as they were enrolled: every ``age`` (since enrolment) at 0."""
    out = dict(data)  # new pallet and side dicts where the age changes; ``data`` untouched
    out["pallet_look"] = dict(out.get("pallet_look") or {}, age=0.0)
    out["pallets"] = [_unaged_pallet(p) for p in out.get("pallets") or []]
    return out


def _unaged_pallet(pallet: dict) -> dict:
    sides = pallet.get("sides")
    if not isinstance(sides, dict):
        return pallet
    unaged_sides = {k: dict(v, age=0.0) if isinstance(v, dict) else v for k, v in sides.items()}
    return dict(pallet, sides=unaged_sides)


def look_overrides(overrides: dict[str, str] | None) -> dict[str, str]:
    """The ``--set world.KEY`` items that change which pallets the demo gallery enrols and
    how they look (``pallet_look.*``, ``pallet_pool.*``, ``pallet_geometry.*`` and the
    stock's ``not_enrolled`` list, the pallets it must not know): the demo gallery enrols
    the pallets as the flight will see them (ageing aside). The rest of ``stock.*`` goes
    with them so that the world they make passes its checks (a longer ``not_enrolled``
    list with more ``not_enrolled_places``); only ``not_enrolled`` changes the gallery
    (:func:`appearance_key`)."""
    keep = ("pallet_look.", "pallet_pool.", "pallet_geometry.", "stock.", "enrolment_slot.")
    return {k: v for k, v in (overrides or {}).items() if k.startswith(keep)}


def scan_frames(
    world_path: str,
    identity: str,
    camera: dict | None,
    seed: int = 0,
    overrides: dict[str, str] | None = None,
) -> Iterator[tuple[np.ndarray, float]]:
    """Raw frames (and their times) of a camera moving along the canonical scan line in front
    of ``identity`` standing alone in the canonical slot; motion blur from the scan speed."""
    from drivers.sim.world import load_world

    data = load_world(world_path, look_overrides(overrides)).data
    renderer, poses = _canonical_scan(data, world_path, identity, camera, seed)
    for pose in poses:
        yield renderer(pose, pose.t_s), pose.t_s


def _canonical_scan(
    data: dict, world_path: str, identity: str, camera: dict | None, seed: int
) -> tuple[Any, tuple[Any, ...]]:
    """A renderer of ``identity`` alone in the canonical slot and the poses of the
    canonical scan line, one per frame at :data:`ENROL_RATE_HZ` (``pose.t_s``: its time)."""
    from drivers.sim.renderers.pallet import PalletRenderer
    from drivers.sim.world import World

    data = canonical_world_data(data, identity)
    world = World(data, world_path)
    line = data["scan_line"]
    renderer = PalletRenderer(world, camera, np.random.default_rng(seed))
    key = tuple(line[k] for k in ("x_m", "y_from_m", "x_to_m", "y_to_m", "z_m", "yaw_deg"))
    return renderer, _scan_poses(*key)


@lru_cache(maxsize=8)
def _scan_poses(
    x0: float, y0: float, x1: float, y1: float, z_m: float, yaw_deg: float
) -> tuple[Any, ...]:
    """The poses of a scan line from (x0, y0) to (x1, y1), one per frame (frozen: every
    side of a build shares them)."""
    from drivers.vehicle.types import Pose

    yaw = math.radians(yaw_deg)
    quaternion = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    length = math.hypot(x1 - x0, y1 - y0)
    ux, uy = (x1 - x0) / length, (y1 - y0) / length
    step = ENROL_SPEED_MPS / ENROL_RATE_HZ
    n = int(length / step) + 1
    return tuple(
        Pose(
            x0 + k * step * ux, y0 + k * step * uy, z_m, yaw, quaternion, k / ENROL_RATE_HZ, "enrol"
        )
        for k in range(n)
    )


def enrolment_frames(
    data: dict,
    world_path: str,
    identity: str,
    camera: dict | None,
    seed: int = 0,
    per_block: int = VIEWS_PER_BLOCK,
) -> Iterator[tuple[np.ndarray | None, float]]:
    """The frames of the canonical scan (:func:`scan_frames`) that the block sequencer
    needs, and only those: per block, ``per_block`` frames spread over the stretch where it
    is left of the image centre by at most the sequencer's ``max_distance_left_px``, and
    the first frame where it is :data:`COMMIT_PX` right of it (where the block is, from
    the camera model and the scene: no detection). Each is rendered with the motion blur
    of the scan (from the previous frame's pose) and the auto-exposure of the scan (the
    frames it adapts on are rendered too, not detected). Every other frame of the scan is
    yielded as ``(None, t_s)``: not rendered, but counted by the sequencer (a block it
    tracked is lost after as many frames as in the whole scan). ``data``: the world's
    data, loaded once for many sides."""
    from drivers.sim.renderers.pallet import AE_PERIOD
    from perception.sequencer import SequencerParams

    renderer, poses = _canonical_scan(data, world_path, identity, camera, seed)
    window = SequencerParams().max_distance_left_px
    offsets = _block_offsets(renderer, poses)
    chosen: set[int] = set()
    for track in offsets.values():
        inside = [k for k, dx in track if -window <= dx <= 0.0]
        after = [k for k, dx in track if dx > COMMIT_PX]
        if not inside or not after:
            continue
        picks = np.linspace(inside[0], inside[-1], min(per_block, len(inside)))
        chosen.update(int(round(x)) for x in picks)
        # up to the commit, a frame every MAX_GAP_FRAMES: the sequencer keeps the track
        chosen.update(range(inside[-1], after[0], MAX_GAP_FRAMES))
        chosen.add(after[0])
    last = max(chosen, default=len(poses) - 1)
    rendered = chosen | set(range(0, last + 1, AE_PERIOD))
    for k in range(last + 1):
        if k not in rendered:
            yield None, poses[k].t_s  # the sequencer counts it: its tracks age as in a scan
            continue
        renderer.frames = k  # the auto-exposure adapts on the scan's own frames
        previous = (poses[k - 1].t_s, poses[k - 1]) if k else None
        raw = renderer(poses[k], poses[k].t_s, previous)
        yield (raw if k in chosen else None), poses[k].t_s


#: the blocks' image offsets along the canonical scan, by the scene's block geometry, the
#: camera and the poses (every side of a world has the same: only its texture differs)
_OFFSETS: OrderedDict[str, dict[int, list[tuple[int, float]]]] = OrderedDict()
_MAX_OFFSETS = 8
#: off: the offsets are worked out for every side, as before they were kept (benches)
CACHE_OFFSETS = True


def _block_offsets(renderer: Any, poses: Sequence[Any]) -> dict[int, list[tuple[int, float]]]:
    """Per block, ``(frame, box centre's offset from the image centre, px)`` of every frame
    of ``poses`` that sees the whole block face (the scene's ground truth: no detection).
    The ground truth reads only the camera, the poses and the corners and normals of the
    block faces (:func:`perception.synth.render.block_boxes`), so it is worked out once per
    such geometry (a 4,000-side build: once per worker, not 211 frames per side)."""
    geometry = [
        (q.normal.tobytes(), q.centre.tobytes(), [(k, c.tobytes()) for k, _, c in q.blocks])
        for q in renderer.scene.quads
        if q.blocks
    ]
    key = hashlib.sha1(repr((renderer.camera, poses, geometry)).encode()).hexdigest()
    offsets = _OFFSETS.get(key) if CACHE_OFFSETS else None
    if offsets is None:
        centre = renderer.camera.width / 2.0
        offsets = {}
        for k, pose in enumerate(poses):
            for box in renderer.ground_truth(pose):
                if box.visible >= 0.99:  # a whole block face, as the detector boxes it
                    offsets.setdefault(box.block, []).append((k, 0.5 * (box.x1 + box.x2) - centre))
        _OFFSETS[key] = offsets
        while len(_OFFSETS) > _MAX_OFFSETS:
            _OFFSETS.popitem(last=False)
    else:
        _OFFSETS.move_to_end(key)
    return offsets


def scan_blocks(
    frames: Iterator[tuple[np.ndarray | None, float]],
    detector: Any,
    factors: tuple[float, float, float],
    min_score: float | None = None,
) -> list[np.ndarray]:
    """The crops the block sequencer commits over a stream of raw frames (stops at three);
    a frame ``None`` was not looked at (:func:`enrolment_frames`): it detects nothing."""
    from perception.sequencer import BlockSequencer
    from perception.white_balance import preprocess

    seq = BlockSequencer()
    blank: np.ndarray | None = None
    for raw, t in frames:
        if raw is None:
            if blank is not None:
                seq.update(blank, [], t)
            continue
        bgr = preprocess(raw, factors)
        blank = bgr[:1, :]  # the sequencer reads only the width of a frame without boxes
        seq.update(bgr, detector.detect(bgr, min_score=min_score), t)
        if seq.done:
            break
    return [b.crop for b in seq.blocks]
