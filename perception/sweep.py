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

from perception.sequencer import Detection, sharpness
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
    #: the block's box height may be this factor off the height the map predicts (a block on
    #: the wall behind an empty place, or on a neighbour level, is much smaller or larger)
    size_ratio: tuple[float, float] = (0.6, 1.7)
    #: a slot counts as looked at in a frame when it projects this close to the image's
    #: vertical centre line and inside the image, px
    look_px: float = 70.0
    #: frames are wanted while a slot without a good crop projects this close to the image
    #: centre line, px
    want_px: float = 24.0
    #: a crop is taken only from a box at least this far from the image's left and right
    #: borders (a cut box is a partial block), px
    border_px: float = 3.0
    #: a frame is wanted anyway once the view moved this far since the last one, px
    max_gap_px: float = 110.0
    #: a place is finished once the camera is this far past its last slot, m
    finish_after_m: float = 0.25
    #: emulated processing time per frame of the host (lock-step only; 0: none dropped), s
    host_frame_s: float = 0.0


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
    crops: list[SlotCrop | None] = field(default_factory=lambda: [None, None, None])
    looked: list[int] = field(default_factory=lambda: [0, 0, 0])
    stray: int = 0  # plausible blocks on the place's face that matched no slot
    outcome: str = ""
    reason: str = ""

    @property
    def blocks_seen(self) -> int:
        """Slots with a crop."""
        return sum(c is not None for c in self.crops)

    def ordered_crops(self) -> list[np.ndarray]:
        """The crops in the order a scan commits them and the gallery enrols them: right to
        left in the image (a scan moves the camera to its left, so the blocks cross the
        image centre from the right-most one on)."""
        return [c.crop for c in reversed(self.crops) if c is not None]


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

    def along(self, p: tuple[float, float, float] | np.ndarray) -> float:
        """Position of ``p`` along the pass line, m."""
        return float(self.direction @ (np.asarray(p, float) - self.origin))

    def open(self) -> list[PlaceWatch]:
        """The places not finished yet."""
        return [w for w in self.watches if not w.outcome]

    # -- which frames ------------------------------------------------------------------------
    def _near(self, pose: CameraPose, reach_m: float = 2.0) -> list[PlaceWatch]:
        s = self.along(pose.position)
        return [w for w in self.watches if not w.outcome and abs(w.along_m - s) <= reach_m]

    def _columns(self, pose: CameraPose, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, t = world_to_optical(self.camera, pose)
        pc = pts @ R.T + t
        z = np.where(pc[:, 2] < 1e-6, 1e-6, pc[:, 2])
        u = self.camera.fx * pc[:, 0] / z + self.camera.cx
        return u, pc[:, 2]

    def wants(self, t_s: float, pose: CameraPose | None) -> bool:
        """Lock-step gate: process the frame captured at ``t_s`` from ``pose``?"""
        if pose is None:
            return False
        if t_s < self._busy_until - 1e-9:
            self.dropped += 1
            return False
        want = False
        for w in self._near(pose):
            u, depth = self._columns(pose, w.slots)
            for k in range(3):
                if depth[k] <= 0.05 or w.crops[k] is not None:
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

    # -- what a frame shows ------------------------------------------------------------------
    def add(
        self,
        pose: CameraPose,
        bgr: np.ndarray,
        dets: list[Detection],
        frame_index: int = 0,
        t_s: float = 0.0,
    ) -> None:
        """Match one processed frame's detections to the slots of the places near it."""
        self.frames += 1
        cam = self.camera
        h, w_px = bgr.shape[:2]
        R, t = world_to_optical(cam, pose)
        centre = pose.position
        near = self._near(pose)
        for w in near:
            u, depth = self._columns(pose, w.slots)
            for k in range(3):
                if depth[k] > 0.05 and abs(u[k] - cam.cx) <= self.params.look_px:
                    w.looked[k] += 1
        for det in dets:
            cy = 0.5 * (det.y1 + det.y2)
            ray = R.T @ np.array([(det.cx - cam.cx) / cam.fx, (cy - cam.cy) / cam.fx, 1.0])
            best: tuple[float, PlaceWatch, int, float] | None = None
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
                if abs(hit[2] - w.slots[1][2]) > self.params.match_height_m:
                    continue
                along = self.along(hit)
                errs = [abs(along - self.along(s)) for s in w.slots]
                k = int(np.argmin(errs))
                if errs[k] <= self.params.match_along_m:
                    if best is None or errs[k] < best[3]:
                        best = (errs[k], w, k, along - self.along(w.slots[k]))
                elif min(errs) <= 0.45:  # on this place's face, but on no slot
                    w.stray += 1
            if best is None:
                continue
            _, w, k, err = best
            if det.x1 <= self.params.border_px or det.x2 >= w_px - 1 - self.params.border_px:
                continue
            crop = _crop(bgr, det)
            if crop.size == 0:
                continue
            centred = 1.0 / (1.0 + abs(det.cx - cam.cx) / 40.0)
            q = max(det.score, 0.0) * (1.0 + sharpness(crop)) * centred
            cur = w.crops[k]
            if cur is None or q > cur.quality:
                box = (det.x1, det.y1, det.x2, det.y2, det.score)
                w.crops[k] = SlotCrop(crop, q, frame_index, t_s, box, err)
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

    def _decide(self, w: PlaceWatch, why: str = "") -> None:
        n = w.blocks_seen
        if n == 3:
            w.outcome, w.reason = IDENTIFY, ""
        elif n == 0 and w.stray == 0 and all(k > 0 for k in w.looked):
            w.outcome, w.reason = EMPTY, "no support block on the place's face in the pass"
        else:
            w.outcome = RESCAN
            if why and not all(k > 0 for k in w.looked):
                w.reason = why
            elif not all(k > 0 for k in w.looked):
                w.reason = f"slots in view {w.looked}: frames missing (dropped or too fast)"
            elif n == 0:
                w.reason = f"{w.stray} block sightings off the expected slots"
            else:
                w.reason = f"{n} of 3 blocks seen in the pass"


def _crop(image: np.ndarray, det: Detection) -> np.ndarray:
    h, w = image.shape[:2]
    x1, y1 = max(int(round(det.x1)), 0), max(int(round(det.y1)), 0)
    x2, y2 = min(int(round(det.x2)), w), min(int(round(det.y2)), h)
    return image[y1:y2, x1:x2].copy()
