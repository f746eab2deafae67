"""The block sequencer: turn per-frame detections into the pallet's three blocks, in order.

The drone flies along the pallet, so the blocks cross the image from left to right. The
reference mission's rule (its Algorithm 1) keeps, for each block, the crop taken while the
block is left of the image centre and within ``max_distance_left`` of it, and commits that
crop as "block N" once the block has moved right of the centre by more than
``min_distance_right``; then it waits for the next block. It stops after three blocks.

What this implementation adds to the reference rule:

* Several blocks may be in view at once. Detections are linked across frames into tracks
  (blocks only move one way), so a crop is never committed for the wrong block. (The
  reference kept one crop variable and never cleared it, so a stale crop could be committed
  twice when detections alternated between two blocks.)
* Within the left window it keeps the *best* crop of the block, not the last one: quality is
  detection score x sharpness (variance of the Laplacian, so motion blur loses) x
  completeness (a box cut by the image border is a partial block). A blurred or partial crop
  is not committed when a better one of the same block came in the same pass.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

try:  # OpenCV is a dependency of perception; keep the pure logic importable without it
    import cv2
except ImportError:  # pragma: no cover
    cv2 = None


@dataclass(frozen=True)
class Detection:
    """One detected block: pixel box ``(x1, y1, x2, y2)`` and detector score (0..1)."""

    x1: float
    y1: float
    x2: float
    y2: float
    score: float = 1.0

    @property
    def cx(self) -> float:
        """Horizontal centre in pixels."""
        return 0.5 * (self.x1 + self.x2)


@dataclass
class CommittedBlock:
    """A block the sequencer committed: its crop, quality, and where it was taken."""

    index: int
    crop: np.ndarray
    quality: float
    frame_index: int
    t_s: float
    box: Detection


@dataclass
class _Track:
    track_id: int
    cx: float
    seen_frame: int
    best_crop: np.ndarray | None = None
    best_quality: float = -1.0
    best_frame: int = -1
    best_t_s: float = 0.0
    best_box: Detection | None = None
    committed: bool = False


@dataclass
class SequencerParams:
    """The reference rule's two parameters (pixels) plus tracking and quality settings."""

    max_distance_left_px: float = 60.0
    min_distance_right_px: float = 20.0
    max_jump_px: float = 90.0  # a block moves at most this far between two frames
    lost_after_frames: int = 8
    border_px: float = 2.0  # a box this close to the image edge is a partial block
    partial_penalty: float = 0.2
    blocks: int = 3


def sharpness(crop: np.ndarray) -> float:
    """Variance of the Laplacian of the grey crop (higher = sharper)."""
    if crop.size == 0:
        return 0.0
    grey = crop if crop.ndim == 2 else crop.mean(axis=2)
    grey = np.asarray(grey, dtype=np.float32)
    if cv2 is not None:
        return float(cv2.Laplacian(grey, cv2.CV_32F).var())
    lap = (
        -4 * grey[1:-1, 1:-1] + grey[:-2, 1:-1] + grey[2:, 1:-1] + grey[1:-1, :-2] + grey[1:-1, 2:]
    )
    return float(lap.var()) if lap.size else 0.0


@dataclass
class BlockSequencer:
    """Feed frames with their detections; read :attr:`blocks` (committed, in order)."""

    params: SequencerParams = field(default_factory=SequencerParams)
    blocks: list[CommittedBlock] = field(default_factory=list)
    frames: int = 0
    _tracks: list[_Track] = field(default_factory=list)
    _next_id: int = 0

    @property
    def done(self) -> bool:
        """True once all blocks are committed."""
        return len(self.blocks) >= self.params.blocks

    def reset(self) -> None:
        """Forget everything (e.g. before a re-scan)."""
        self.blocks.clear()
        self._tracks.clear()
        self.frames = 0

    def quality(self, det: Detection, crop: np.ndarray, width: int) -> float:
        """Score of a crop: detection score x sharpness x completeness."""
        p = self.params
        q = max(det.score, 0.0) * (1.0 + sharpness(crop))
        if det.x1 <= p.border_px or det.x2 >= width - 1 - p.border_px:
            q *= p.partial_penalty
        return q

    def update(
        self, image: np.ndarray, detections: list[Detection], t_s: float = 0.0
    ) -> list[CommittedBlock]:
        """Process one frame; return the blocks committed by it (usually none)."""
        if self.done:
            return []
        self.frames += 1
        h, w = image.shape[:2]
        centre = 0.5 * w
        p = self.params
        tracks = self._link(detections)
        new: list[CommittedBlock] = []
        for det, track in tracks:
            dx = det.cx - centre
            if dx <= 0:
                if -dx <= p.max_distance_left_px and not track.committed:
                    crop = crop_box(image, det)
                    q = self.quality(det, crop, w)
                    if q > track.best_quality:
                        track.best_crop, track.best_quality = crop, q
                        track.best_frame, track.best_t_s, track.best_box = self.frames, t_s, det
            elif (
                dx > p.min_distance_right_px and track.best_crop is not None and not track.committed
            ):
                track.committed = True
                block = CommittedBlock(
                    len(self.blocks) + 1,
                    track.best_crop,
                    track.best_quality,
                    track.best_frame,
                    track.best_t_s,
                    track.best_box,
                )
                self.blocks.append(block)
                new.append(block)
                if self.done:
                    break
        return new

    def _link(self, detections: list[Detection]) -> list[tuple[Detection, _Track]]:
        """Assign detections to tracks (nearest previous position, never moving back much)."""
        p = self.params
        alive = [t for t in self._tracks if self.frames - t.seen_frame <= p.lost_after_frames]
        self._tracks = alive
        out: list[tuple[Detection, _Track]] = []
        used: set[int] = set()
        for det in sorted(detections, key=lambda d: -d.cx):  # rightmost first: oldest blocks
            best, best_d = None, None
            for t in alive:
                if t.track_id in used:
                    continue
                d = det.cx - t.cx
                if -p.max_jump_px * 0.25 <= d <= p.max_jump_px and (
                    best_d is None or abs(d) < abs(best_d)
                ):
                    best, best_d = t, d
            if best is None:
                best = _Track(self._next_id, det.cx, self.frames)
                self._next_id += 1
                self._tracks.append(best)
            used.add(best.track_id)
            best.cx, best.seen_frame = det.cx, self.frames
            out.append((det, best))
        out.sort(key=lambda dt: -dt[0].cx)
        return out


def crop_box(image: np.ndarray, det: Detection) -> np.ndarray:
    """The pixels of a detection's box (clipped to the image), a copy."""
    h, w = image.shape[:2]
    x1, y1 = max(int(round(det.x1)), 0), max(int(round(det.y1)), 0)
    x2, y2 = min(int(round(det.x2)), w), min(int(round(det.y2)), h)
    return image[y1:y2, x1:x2].copy()
