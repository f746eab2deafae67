"""The mission's perception path on rendered views, for the robustness evaluation.

:class:`Pipeline` renders three views of a pallet side (one aimed at each block) through
the synthetic camera, runs the detector, cuts the crop of the detection nearest the image
centre, and describes the crops with the embedder, as the mission does; :class:`SideScan`
holds what one side's views gave (the crops and the detector's counts against the
ground-truth boxes). :mod:`perception.robustness` runs the conditions through it (and
re-exports these names).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from perception.gallery import Match
from perception.sequencer import Detection
from perception.synth.appearance import EPAL, SideStyle, split_identity
from perception.synth.camera_model import CameraModel, CameraPose
from perception.synth.dataset import NOMINAL_LIGHT, _block_centre_z, _scene, _wb_factors
from perception.synth.render import SensorModel, block_boxes
from perception.synth.scene import SceneLight
from perception.synth.views import ViewConditions, develop, take_frame
from perception.verify import VerifyThresholds

#: stand-off of enrolment and of the reference scans (the mission's 0.4 m)
STANDOFF_M = 0.4
#: a detection this close to the image centre (px) is the block the camera looks at
CENTRE_TOLERANCE_PX = 80.0


@dataclass
class SideScan:
    """What one side's three views gave: crops (None where no block was found near the
    centre), and the detector's counts."""

    crops: list[np.ndarray | None]
    found: int = 0  # blocks of the side found (IoU >= 0.5 in the view aimed at them)
    tp: int = 0
    fp: int = 0
    gt: int = 0

    @property
    def complete(self) -> bool:
        """True if all three crops were cut."""
        return all(c is not None for c in self.crops)


def _iou(a: Sequence[float], b: Sequence[float]) -> float:
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


class Pipeline:
    """The mission's perception path on rendered views: detector, crop, embedder, gallery."""

    def __init__(
        self,
        detector: Any,
        embedder: Any,
        camera: CameraModel | None = None,
        texture: bool = True,
        verify_thresholds: VerifyThresholds | None = None,
    ) -> None:
        self.detector, self.embedder = detector, embedder
        self.camera = camera or CameraModel()
        self.factors = _wb_factors(SensorModel())
        self.texture = texture  # verify matches on the blocks' texture (perception.verify)
        self.verify_thresholds = verify_thresholds
        self.matches: list[tuple[str, bool, Match]] | None = None  # (name, enrolled, match)
        self.records: list[dict] | None = None  # scan_record() of every match

    def scan(
        self,
        identity: str,
        style: SideStyle,
        rng: np.random.Generator,
        distance_m: float = STANDOFF_M,
        yaw_deg: float = 0.0,
        view: ViewConditions | None = None,
        jitter: bool = True,
        light: SceneLight | None = None,
    ) -> SideScan:
        """Three views of a side, one aimed at each block, through the detector
        (``light``: the scene's lamps, default the nominal ones)."""
        pallet_id, side = split_identity(identity)
        base_z = 0.194
        scene = _scene(pallet_id, side, style, base_z, light or NOMINAL_LIGHT)
        out = SideScan([])
        for k, offset in enumerate(EPAL.block_offsets_m()):
            j = (lambda s: float(rng.uniform(-s, s))) if jitter else (lambda s: 0.0)
            yaw = math.radians(yaw_deg * (1 if rng.random() < 0.5 else -1) + j(3.0))
            d = distance_m * (1.0 + j(0.04))
            # Seen from in front (camera at -x looking +x), "right" is -y.
            y = -offset + j(0.03) - d * math.sin(yaw)
            pose = CameraPose.from_yaw(
                -d * math.cos(yaw),
                y,
                _block_centre_z(base_z) + j(0.02),
                yaw,
                pitch=math.radians(j(2.0)),
                roll=math.radians(j(2.0)),
            )
            cond = view or ViewConditions()
            if jitter and view is None:
                cond = ViewConditions(
                    exposure=float(rng.uniform(0.85, 1.15)),
                    colour_temperature_k=float(rng.uniform(3500, 4500)),
                )
            raw = take_frame(self.camera, pose, scene, rng, cond)
            bgr = develop(raw, self.factors, cond)
            dets = self.detector.detect(bgr)
            self._count(out, dets, block_boxes(self.camera, pose, scene), k)
            out.crops.append(_centre_crop(bgr, dets))
        return out

    @staticmethod
    def _count(out: SideScan, dets: list[Detection], gt: list, k: int) -> None:
        care = [b for b in gt if b.visible >= 0.5 and b.x2 - b.x1 >= 4]
        used: set[int] = set()
        for d in sorted(dets, key=lambda d: -d.score):
            box = (d.x1, d.y1, d.x2, d.y2)
            best, best_i = 0.0, -1
            for i, b in enumerate(care):
                v = _iou(box, (b.x1, b.y1, b.x2, b.y2))
                if i not in used and v > best:
                    best, best_i = v, i
            if best >= 0.5:
                used.add(best_i)
                out.tp += 1
                out.found += int(care[best_i].block == k)
            elif not any(_iou(box, (b.x1, b.y1, b.x2, b.y2)) >= 0.3 for b in gt if b not in care):
                out.fp += 1
        out.gt += len(care)

    def describe(self, crops: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray | None]:
        """Embeddings of three crops and, if the embedder gives them, their stripe
        visibilities."""
        d = self.embedder.describe(crops)
        return d.vectors, (d.visibility if self.embedder.occlusion_aware else None)


def _centre_crop(bgr: np.ndarray, dets: list[Detection]) -> np.ndarray | None:
    """The crop of the detection nearest the image centre (within the tolerance)."""
    if not dets:
        return None
    cx = bgr.shape[1] / 2
    d = min(dets, key=lambda d: abs(d.cx - cx))
    if abs(d.cx - cx) > CENTRE_TOLERANCE_PX:
        return None
    h, w = bgr.shape[:2]
    x1, y1 = max(int(round(d.x1)), 0), max(int(round(d.y1)), 0)
    x2, y2 = min(int(round(d.x2)), w), min(int(round(d.y2)), h)
    if x2 - x1 < 2 or y2 - y1 < 2:
        return None
    return bgr[y1:y2, x1:x2].copy()


__all__ = ["CENTRE_TOLERANCE_PX", "STANDOFF_M", "Pipeline", "SideScan"]
