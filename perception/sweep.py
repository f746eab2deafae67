"""Answering pallet places on the fly: the blocks of every place a sweep pass flies by.

A sweep pass flies along a rack level at a stand-off, past many places. The map says where
each place's support blocks should be (the place's face centre, the block spacing of the
pallet model); the placement error of a racked pallet is a few centimetres. So, frame by
frame, every detected block can be put on the face plane of the place it belongs to and
matched to one of that place's three block slots. Per slot the best crop is kept (detector
score x sharpness, whole boxes only, the block near the image centre where it is seen
square on). Once the camera has passed a place, the place is finished:

* three slots with a crop: identify it (the caller runs the embedder and the gallery);
* no block anywhere on the place's face, though every slot was in good view at least
  once: ``empty``;
* anything else (one or two blocks, a block off its slot, a slot never in view because
  frames were dropped): ``rescan`` with the reason, for the per-place reactive scan.

:meth:`SweepCollector.wants` is the lock-step frame gate of a pass: a frame is rendered and
detected only when a slot still without a good crop is near the image centre, plus one frame
when the view moved ``max_gap_px`` since the last one (so an empty place is looked at, and a
block off its slot is seen). ``host_frame_s`` emulates a host that needs that long per frame:
a frame arriving while the previous one is still being processed is dropped, as the real-time
perception worker drops them.

Pure geometry and bookkeeping: no drone, no engine (``perception`` imports nothing of the
project but itself).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from perception.sequencer import Detection, crop_box, sharpness
from perception.synth.camera_model import CameraModel, CameraPose, world_to_optical

#: outcomes of a finished place
IDENTIFY, EMPTY, RESCAN = "identify", "empty", "rescan"


@dataclass(frozen=True)
class SweepParams:
    """How blocks are matched to slots and which frames a pass looks at."""

    #: a block matches a slot whose centre is this close along the face, m (placement error
    #: plus the estimate's error; slots are 0.53 m apart)
    match_along_m: float = 0.12
    #: ... and this close in height, m
    match_height_m: float = 0.09
    #: a block on a place's face (along its slots) but further off its row than
    #: ``match_height_m``, up to this far (half the levels' spacing: not the level above or
    #: below), is a pallet standing off its beam: the place is not answered empty, m ...
    off_row_max_m: float = 0.4
    #: ... once this many central sightings of such blocks were made
    off_row_min: int = 2
    #: sightings at two or more slots whose offsets from the map agree this closely ...
    agree_m: float = 0.04
    #: ... and are at least this far off it are a pallet off its place, not flickers
    #: (:meth:`PlaceWatch.off_place`; closer to its slots, a block is centred in the frames
    #: the gate picks and gets sightings enough), m. ``agree_m`` 0: not looked for (a
    #: second look flies slowly: a pallet there gets sightings a baseline apart)
    off_place_min_m: float = 0.05
    #: the block's box height may be this factor off the height the map predicts (a block on
    #: the wall behind an empty place, or on a neighbour level, is much smaller or larger)
    size_ratio: tuple[float, float] = (0.6, 1.7)
    #: a slot counts as looked at in a frame when it projects this close to the image's
    #: vertical centre line and inside the image, px
    look_px: float = 70.0
    #: a block sighted from camera positions at least this far apart ...
    parallax_baseline_m: float = 0.08
    #: ... whose face-plane position moves by at most this fraction of the camera's motion
    #: stands on the face plane (a block 0.4 m deeper at a 0.45 m stand-off moves by 0.47)
    parallax_max_slope: float = 0.3
    #: only boxes centred this close to the image's vertical centre line are matched to a
    #: slot: a block seen square on. Off to the side, the blocks of a neighbour's short face
    #: (0.4 and 0.8 m deeper) would project onto the face plane where an empty place's slots
    #: are. Boxes anywhere in the image that land on no slot are strays, kept for the
    #: parallax test (a pallet far off its place is not empty), px
    central_px: float = 45.0
    #: frames are wanted while a slot without a good crop projects this close to the image
    #: centre line, px
    want_px: float = 40.0
    #: a crop is taken only from a box at least this far from the image's left and right
    #: borders (a cut box is a partial block), px
    border_px: float = 3.0
    #: a frame is wanted anyway once the view moved this far since the last one, px
    max_gap_px: float = 110.0
    #: a place is finished once the camera is this far past its last slot, m
    finish_after_m: float = 0.25
    #: a frame counts only when the camera is this close to the pass line (its height, its
    #: distance from the faces): a drone that stepped aside for another, or was pushed off,
    #: looks at the slots from elsewhere, and what it sees there (or does not) is no
    #: evidence about them, m
    on_line_m: float = 0.1
    #: emulated processing time per frame of the host (lock-step only; 0: none dropped), s
    host_frame_s: float = 0.0
    #: boxes off to the side that land on no slot count as stray evidence too (a second,
    #: slow look sees a deeper thing from so many oblique angles that a few of its
    #: sightings line up on the face plane: it counts central boxes only)
    off_centre_strays: bool = True
    #: crops kept per block slot (their embeddings are averaged: several views of a block
    #: from a moving camera are steadier than the best one alone)
    views: int = 3
    #: a slot keeps wanting frames until it was sighted this many times (the parallax test
    #: needs two sightings a baseline apart)
    want_views: int = 3


@dataclass
class SlotCrop:
    """The best crop of one block slot so far."""

    crop: np.ndarray
    quality: float
    frame_index: int
    t_s: float
    box: tuple[float, float, float, float, float]
    along_error_m: float


@dataclass
class PlaceWatch:
    """One place of a pass: its slots, what was seen of them, and the outcome."""

    name: str
    along_m: float  # the place's centre along the pass line
    slots: np.ndarray  # (3, 3) world points of the block centres, left to right along the pass
    normal: np.ndarray  # (3,) out of the face, towards the aisle
    #: per slot, its best crops, best first (at most ``SweepParams.views`` each)
    crops: list[list[SlotCrop]] = field(default_factory=lambda: [[], [], []])
    looked: list[int] = field(default_factory=lambda: [0, 0, 0])
    #: per slot, every matched sighting: (camera along the pass, the box centre's ray on the
    #: face plane, along the pass), m. A block on the face plane stays put as the camera
    #: moves; something deeper (seen through an empty place) slides with it (parallax)
    hits: list[list[tuple[float, float]]] = field(default_factory=lambda: [[], [], []])
    stray: int = 0  # plausible blocks on the place's face that matched no slot
    #: their sightings (camera along, face-plane along), for the parallax test
    stray_hits: list[tuple[float, float]] = field(default_factory=list)
    #: central sightings of blocks on the place's face but off its row: (camera along,
    #: face-plane along, height above (+) or below (-) the row the map gives), m
    #: (``SweepParams.off_row_max_m``); they count once they stand on the face plane
    off_row: list[tuple[float, float, float]] = field(default_factory=list)
    outcome: str = ""
    reason: str = ""
    states: list[str] = field(default_factory=list)

    @property
    def blocks_seen(self) -> int:
        """Slots with a crop."""
        return sum(bool(c) for c in self.crops)

    def slot_state(self, k: int, max_slope: float, min_baseline_m: float) -> str:
        """``block`` (sightings that stay put on the face plane as the camera moves),
        ``deep`` (they slide with the camera: something behind the face plane), ``single``
        (too short a baseline to tell) or ``none`` (also when the sightings never spanned the
        baseline in four or more looks: a flicker; a block on the face is seen from every
        camera position it is in view of)."""
        state = hits_state(self.hits[k], max_slope, min_baseline_m)
        if state == "single" and self.looked[k] >= 4:
            return "none"
        return state

    def off_place(
        self, slot_along: list[float], states: list[str], agree_m: float, min_m: float
    ) -> tuple[int, float]:
        """(slots, offset m): two or more slots with sightings, none of them behind the
        face plane (``states``: :meth:`slot_state` per slot), that agree within ``agree_m``
        on one offset of at least ``min_m`` from the map's slots (``slot_along``: their
        positions along the pass, m); (0, 0.0) if not.

        A pallet racked well off its place is seen off the image centre in most of the
        frames its slots were looked at in, so each block may get too few sightings for
        the parallax test (``none``): flickers land at unrelated places, a pallet's three
        blocks are off alike."""
        if agree_m <= 0.0:
            return 0, 0.0
        errs = [
            float(np.median([h[1] - slot_along[k] for h in self.hits[k]]))
            for k in range(3)
            if self.hits[k] and states[k] != "deep"
        ]
        if len(errs) < 2 or max(errs) - min(errs) > agree_m:
            return 0, 0.0
        offset = float(np.median(errs))
        return (len(errs), offset) if abs(offset) >= min_m else (0, 0.0)

    def stray_blocks(self, max_slope: float, min_baseline_m: float) -> int:
        """Blocks off every slot that stand on the face plane (a pallet far off its place):
        sightings within 4 cm of each other on the face plane, from camera positions at
        least ``min_baseline_m`` apart but never more than 15 cm of travel from the next
        (the same thing seen in nearby frames, not two things that happen to project to the
        same spot from far apart). Things behind the face slide with the camera."""
        return plane_blocks(self.stray_hits, max_slope, min_baseline_m)

    def off_row_blocks(self, max_slope: float, min_baseline_m: float) -> int:
        """Blocks on the face plane but off the row the map gives (a pallet off its beam),
        by :meth:`stray_blocks`' test: something behind an empty place slides with the
        camera."""
        return plane_blocks([h[:2] for h in self.off_row], max_slope, min_baseline_m)

    def ordered_crops(self) -> list[np.ndarray]:
        """The crops in the order a scan commits them and the gallery enrols them: right to
        left in the image (a scan moves the camera to its left, so the blocks cross the
        image centre from the right-most one on)."""
        return [c[0].crop for c in reversed(self.crops) if c]

    def ordered_views(self) -> list[list[np.ndarray]]:
        """Every kept crop per block, blocks in :meth:`ordered_crops`' order."""
        return [[v.crop for v in c] for c in reversed(self.crops)]


def plane_blocks(
    sightings: list[tuple[float, ...]], max_slope: float, min_baseline_m: float
) -> int:
    """How many blocks ``sightings`` (camera along, face-plane along) show standing on the
    face plane: sightings within 4 cm of each other on the face plane, from camera positions
    at least ``min_baseline_m`` apart but never more than 15 cm of travel from the next (the
    same thing seen in nearby frames, not two things that happen to project to the same spot
    from far apart). Things behind the face slide with the camera."""
    hits = sorted(sightings, key=lambda h: h[1])
    groups: list[list[tuple[float, ...]]] = []
    for h in hits:
        if groups and h[1] - groups[-1][0][1] <= 0.04:
            groups[-1].append(h)
        else:
            groups.append([h])

    def runs(g: list[tuple[float, ...]]) -> list[list[tuple[float, ...]]]:
        out: list[list[tuple[float, ...]]] = []  # sightings from nearby camera positions
        for h in sorted(g):
            if out and h[0] - out[-1][-1][0] <= 0.15:
                out[-1].append(h)
            else:
                out.append([h])
        return out

    return sum(
        any(len(r) >= 2 and hits_state(r, max_slope, min_baseline_m) == "block" for r in runs(g))  # type: ignore[arg-type]
        for g in groups
    )


def hits_state(hits: list[tuple[float, float]], max_slope: float, min_baseline_m: float) -> str:
    """See :meth:`PlaceWatch.slot_state`."""
    if not hits:
        return "none"
    cams = [h[0] for h in hits]
    if max(cams) - min(cams) < min_baseline_m:
        return "single"
    slope = float(np.polyfit(cams, [h[1] for h in hits], 1)[0])
    return "block" if abs(slope) <= max_slope else "deep"


@dataclass(frozen=True)
class PassPlace:
    """A place handed to a pass: name, face centre of its block row (x, y, z), the yaw
    that faces it (rad)."""

    name: str
    row: tuple[float, float, float]
    look_rad: float


def slot_points(
    row: tuple[float, float, float], look_rad: float, offsets: list[float]
) -> np.ndarray:
    """World points of the block centres of a place, ordered left to right as the camera
    facing it sees them (image column order)."""
    f = np.array([math.cos(look_rad), math.sin(look_rad), 0.0])
    right = np.array([f[1], -f[0], 0.0])  # the camera's right
    c = np.asarray(row, float)
    return np.array([c + right * o for o in sorted(offsets)])


class SweepCollector:
    """Matches the detections of a pass to the places' block slots; see the module doc."""

    def __init__(
        self,
        camera: CameraModel,
        places: list[PassPlace],
        start: tuple[float, float, float],
        end: tuple[float, float, float],
        offsets: list[float],
        block_height_m: float,
        params: SweepParams | None = None,
    ) -> None:
        self.camera, self.params = camera, params or SweepParams()
        self.block_height_m = block_height_m
        p0, p1 = np.asarray(start, float), np.asarray(end, float)
        d = p1 - p0
        d[2] = 0.0
        n = float(np.linalg.norm(d)) or 1.0
        self.origin, self.direction = p0, d / n
        self.watches: list[PlaceWatch] = []
        for pl in places:
            f = np.array([math.cos(pl.look_rad), math.sin(pl.look_rad), 0.0])
            slots = slot_points(pl.row, pl.look_rad, offsets)
            self.watches.append(PlaceWatch(pl.name, self.along(pl.row), slots, -f))
        self.frames = self.dropped = 0
        self._busy_until = -math.inf
        self._last_want: CameraPose | None = None

    def on_line(self, p: tuple[float, float, float] | np.ndarray) -> bool:
        """True if a camera at ``p`` is on the pass line (within ``on_line_m`` in height
        and across it)."""
        r = np.asarray(p, float) - self.origin
        across = abs(float(self.direction[0] * r[1] - self.direction[1] * r[0]))
        tol = self.params.on_line_m
        return abs(float(r[2])) <= tol and across <= tol

    def along(self, p: tuple[float, float, float] | np.ndarray) -> float:
        """Position of ``p`` along the pass line, m."""
        return float(self.direction @ (np.asarray(p, float) - self.origin))

    def open(self) -> list[PlaceWatch]:
        """The places not finished yet."""
        return [w for w in self.watches if not w.outcome]

    # -- which frames ------------------------------------------------------------------------
    def _near(
        self, pose: CameraPose, reach_m: float = 2.0, finished: bool = False
    ) -> list[PlaceWatch]:
        s = self.along(pose.position)
        return [
            w for w in self.watches if (finished or not w.outcome) and abs(w.along_m - s) <= reach_m
        ]

    def _columns(self, pose: CameraPose, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, t = world_to_optical(self.camera, pose)
        pc = pts @ R.T + t
        z = np.where(pc[:, 2] < 1e-6, 1e-6, pc[:, 2])
        u = self.camera.fx * pc[:, 0] / z + self.camera.cx
        return u, pc[:, 2]

    def wants(self, t_s: float, pose: CameraPose | None) -> bool:
        """Lock-step gate: process the frame captured at ``t_s`` from ``pose``?"""
        if pose is None or not self.on_line(pose.position):
            return False
        if t_s < self._busy_until - 1e-9:
            self.dropped += 1
            return False
        want = False
        for w in self._near(pose):
            u, depth = self._columns(pose, w.slots)
            for k in range(3):
                if depth[k] <= 0.05 or self._sighted(w.hits[k]):
                    continue
                if abs(u[k] - self.camera.cx) <= self.params.want_px:
                    want = True
        if not want and self._last_want is not None:
            moved = (self.along(pose.position) - self.along(self._last_want.position)) * (
                self.camera.fx / 0.6
            )
            want = abs(moved) >= self.params.max_gap_px
        elif self._last_want is None:
            want = True
        if want:
            self._last_want = pose
            self._busy_until = t_s + self.params.host_frame_s
        return want

    def _sighted(self, hits: list[tuple[float, float]]) -> bool:
        """Enough sightings of a slot: ``want_views`` of them, a parallax baseline apart."""
        if len(hits) < self.params.want_views:
            return False
        cams = [h[0] for h in hits]
        return max(cams) - min(cams) >= self.params.parallax_baseline_m

    # -- what a frame shows ------------------------------------------------------------------
    def add(
        self,
        pose: CameraPose,
        bgr: np.ndarray,
        dets: list[Detection],
        frame_index: int = 0,
        t_s: float = 0.0,
    ) -> None:
        """Match one processed frame's detections to the slots of the places near it (none
        from a camera off the pass line)."""
        if not self.on_line(pose.position):
            return
        self.frames += 1
        cam = self.camera
        h, w_px = bgr.shape[:2]
        R, t = world_to_optical(cam, pose)
        centre = pose.position
        near = self._near(pose, finished=True)  # a finished place still owns its blocks
        for w in near:
            if w.outcome:
                continue
            u, depth = self._columns(pose, w.slots)
            for k in range(3):
                if depth[k] > 0.05 and abs(u[k] - cam.cx) <= self.params.look_px:
                    w.looked[k] += 1
        for det in dets:
            central = abs(det.cx - cam.cx) <= self.params.central_px
            cy = 0.5 * (det.y1 + det.y2)
            ray = R.T @ np.array([(det.cx - cam.cx) / cam.fx, (cy - cam.cy) / cam.fx, 1.0])
            best: tuple[float, PlaceWatch, int, float] | None = None
            stray: tuple[float, PlaceWatch, float] | None = None
            off_row: tuple[float, PlaceWatch, float, float] | None = None  # |dz|, w, along, dz
            for w in near:
                denom = float(w.normal @ ray)
                if denom >= -1e-6:  # the ray does not meet the face from the front
                    continue
                dist = float(w.normal @ (w.slots[1] - centre)) / denom
                if dist <= 0.05:
                    continue
                hit = centre + ray * dist
                expected_h = cam.fx * self.block_height_m / (dist * float(np.linalg.norm(ray)))
                ratio = (det.y2 - det.y1) / max(expected_h, 1e-6)
                lo, hi = self.params.size_ratio
                if not lo <= ratio <= hi:
                    continue
                dz = float(hit[2] - w.slots[1][2])
                if abs(dz) > self.params.match_height_m:
                    if abs(dz) <= self.params.off_row_max_m and (
                        off_row is None or abs(dz) < off_row[0]
                    ):
                        a = self.along(hit)
                        if min(abs(a - self.along(sl)) for sl in w.slots) <= 0.45:
                            off_row = (abs(dz), w, a, dz)
                    continue
                along = self.along(hit)
                errs = [abs(along - self.along(s)) for s in w.slots]
                k = int(np.argmin(errs))
                if errs[k] <= self.params.match_along_m:
                    if best is None or errs[k] < best[0]:
                        best = (errs[k], w, k, along - self.along(w.slots[k]))
                elif min(errs) <= 0.45 and (stray is None or min(errs) < stray[0]):
                    stray = (min(errs), w, along)  # on this place's face, but on no slot
            if best is None:
                if off_row is not None and central and not off_row[1].outcome:
                    _, ow, along_hit, dz_hit = off_row  # a pallet off its beam?
                    ow.off_row.append((self.along(centre), along_hit, dz_hit))
                if (
                    stray is not None
                    and not stray[1].outcome
                    and (central or self.params.off_centre_strays)
                ):  # on no place's slot
                    stray[1].stray += 1
                    stray[1].stray_hits.append((self.along(centre), stray[2]))
                continue
            if not central:  # off to the side: only a stray's evidence, never a slot's
                continue
            _, w, k, err = best
            if w.outcome:
                continue
            w.hits[k].append((self.along(centre), self.along(w.slots[k]) + err))
            if det.x1 <= self.params.border_px or det.x2 >= w_px - 1 - self.params.border_px:
                continue
            crop = crop_box(bgr, det)
            if crop.size == 0:
                continue
            centred = 1.0 / (1.0 + abs(det.cx - cam.cx) / 40.0)
            q = max(det.score, 0.0) * (1.0 + sharpness(crop)) * centred
            box = (det.x1, det.y1, det.x2, det.y2, det.score)
            kept = w.crops[k]
            kept.append(SlotCrop(crop, q, frame_index, t_s, box, err))
            kept.sort(key=lambda c: -c.quality)
            del kept[self.params.views :]
        del h

    # -- finishing places --------------------------------------------------------------------
    def finish_passed(self, position: tuple[float, float, float]) -> list[PlaceWatch]:
        """Places the camera at ``position`` has passed: finished now, with their outcome."""
        s = self.along(position)
        out = []
        for w in self.watches:
            if w.outcome:
                continue
            last = max(self.along(p) for p in w.slots)
            if s >= last + self.params.finish_after_m:
                self._decide(w)
                out.append(w)
        return out

    def finish_all(self, why: str = "") -> list[PlaceWatch]:
        """Finish every open place (the pass ended or was stopped)."""
        out = []
        for w in self.watches:
            if not w.outcome:
                self._decide(w, why)
                out.append(w)
        return out

    def _off_row(self, w: PlaceWatch) -> int:
        """Blocks seen on ``w``'s face plane off its row (:meth:`PlaceWatch.off_row_blocks`)."""
        p = self.params
        return w.off_row_blocks(p.parallax_max_slope, p.parallax_baseline_m)

    def _decide(self, w: PlaceWatch, why: str = "") -> None:
        p = self.params
        states = [w.slot_state(k, p.parallax_max_slope, p.parallax_baseline_m) for k in range(3)]
        w.states = states
        n = w.blocks_seen
        # a crop whose sightings are a flicker (one in four or more looks: none) is not
        # enough alone: three flickers in an empty place are not a pallet. A pallet's slot
        # can read none when a second look cut its sightings short, so two slots on the
        # face plane (block) or too briefly seen to tell (single) are enough
        solid = sum(st in ("block", "single") for st in states)
        slot_along = [self.along(s) for s in w.slots]
        off_slots, offset = w.off_place(slot_along, states, p.agree_m, p.off_place_min_m)
        if n == 3 and "deep" not in states and solid >= 2:
            w.outcome, w.reason = IDENTIFY, ""
        elif (
            all(st in ("none", "deep") for st in states)
            and w.stray_blocks(p.parallax_max_slope, p.parallax_baseline_m) == 0
            and all(k > 0 for k in w.looked)
            and not off_slots
            and (len(w.off_row) < p.off_row_min or not self._off_row(w))
        ):
            w.outcome = EMPTY
            deep = states.count("deep")
            w.reason = "no support block on the place's face in the pass" + (
                f" ({deep} seen behind it)" if deep else ""
            )
        else:
            w.outcome = RESCAN
            if why and not all(k > 0 for k in w.looked):
                w.reason = why
            elif not all(k > 0 for k in w.looked):
                w.reason = f"slots in view {w.looked}: frames missing (dropped or too fast)"
            elif off_slots and solid < 2:
                w.reason = (
                    f"blocks at {off_slots} slots, each seen too briefly, all "
                    f"{offset * 100:+.0f} cm along the face from the map: a pallet off its "
                    f"place? ({', '.join(states)})"
                )
            elif n == 0 and len(w.off_row) >= p.off_row_min and self._off_row(w):
                dz = float(np.median([h[2] for h in w.off_row]))
                w.reason = (
                    f"{len(w.off_row)} block sightings {dz * 100:+.0f} cm off the row the map "
                    "gives: a pallet off its beam?"
                )
            elif n == 0:
                w.reason = f"{w.stray} block sightings off the expected slots"
            else:
                w.reason = f"{solid} of 3 blocks seen on the face in the pass ({', '.join(states)})"


def fuse_views(
    vectors: np.ndarray, visibility: np.ndarray, counts: list[int], parts: int
) -> tuple[np.ndarray, np.ndarray]:
    """One descriptor per block from several views: ``vectors`` (sum(counts), dim) are the
    embedder's rows (per-stripe unit vectors, concatenated and scaled by 1/sqrt(parts)),
    ``counts`` how many consecutive rows belong to each block. Each stripe is the
    visibility-weighted mean of its views, normalised again; the visibility the mean of
    the views'. Returns (blocks, dim) and (blocks, parts)."""
    vecs, vis = np.asarray(vectors, np.float32), np.asarray(visibility, np.float32)
    dim = vecs.shape[1]
    out_v = np.zeros((len(counts), dim), np.float32)
    out_s = np.zeros((len(counts), parts), np.float32)
    start = 0
    for b, n in enumerate(counts):
        v = vecs[start : start + n].reshape(n, parts, dim // parts)
        s = vis[start : start + n]
        w = s[:, :, None] + 1e-3
        m = (v * w).sum(axis=0)
        norm = np.linalg.norm(m, axis=1, keepdims=True)
        m = m / np.where(norm < 1e-9, 1.0, norm)
        out_v[b] = (m / np.sqrt(parts)).reshape(dim)
        out_s[b] = s.mean(axis=0)
        start += n
    return out_v, out_s
