"""What the perception leaves share during one run: models, gallery, frames seen, answers.

One :class:`PerceptionSession` per mission (``ctx.resources["perception"]``) loads the block
detector and the PCB embedder once, opens the gallery once, turns camera frames into the
white-balanced BGR images the models take, and keeps what the flight report shows: the
frames with detections, the committed crops, every identification with its ranking, and the
frame-to-decision latency.

Every problem a user can cause (missing or corrupt weights, a gallery of another model, an
empty gallery, a frame of the wrong size or format) becomes a :class:`PerceptionError` whose
message says what was wrong and what was expected; the leaves turn it into a FAILURE with
that message, so the tree lands the drone instead of guessing.
"""

from __future__ import annotations

import math
import os
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nodes.perception_feed import FrameFeed, Observation, PerceptionWorker
from perception.errors import ModelError

FRAME_HW = (244, 324)  # the AI-deck camera: 324 x 244 pixels
DEMO = "demo"  # gallery name of the built-in demo gallery (the world's pallets)
MAX_RESULT_LINES = 5  # more identifications than this are counted, not listed
MIN_SCORE_DOC = "detection score threshold (0..1; unset: the detector's calibrated one)"


#: torch threads for the mission's models. One: the detector does a frame in about 4 ms on
#: one core, and two threads stall for hundreds of ms whenever the other core is busy (the
#: SITL emulators, the control thread or any other process), which a 15 frames/s stream
#: cannot afford.
TORCH_THREADS = 1


#: Models loaded in this process, by (kind, path), with the weights file's size and time:
#: a process that flies many missions (a campaign worker) loads each once; a changed file is
#: loaded again. Inference does not change a model, so runs stay independent.
_MODELS: dict[tuple[str, str], tuple[tuple[int, float] | None, Any]] = {}


def _cached(key: tuple[str, str], load: Callable[[], Any]) -> Any:
    path = key[1]
    try:
        st = os.stat(path) if path else None
        stamp = (st.st_size, st.st_mtime) if st else None
    except OSError:
        stamp = None
    hit = _MODELS.get(key)
    if hit is not None and hit[0] == stamp and (stamp is not None or not path):
        return hit[1]
    model = load()
    _MODELS[key] = (stamp, model)
    return model


def identification_record(
    match: Any, thresholds: Any, crops: list, *, t_s: float, key: str, node: str
) -> dict:
    """What :attr:`PerceptionSession.identifications` keeps of one answer (the report, the
    summary and a place's evidence read it): the answer, its ranking and texture figures,
    the thresholds used and the crops."""
    texture = None
    if match.texture_z is not None:
        texture = [
            match.texture_id,
            match.texture_z,
            match.texture_margin if math.isfinite(match.texture_margin or 0) else None,
            [z if math.isfinite(z) else None for z in match.texture_blocks or ()],
        ]
    return {
        "t_s": t_s,
        "key": key,
        "node": node,
        "pallet_id": match.pallet_id,
        "best_id": match.best_id,
        "distance": match.distance,
        "margin": match.margin,
        "known": match.known,
        "reason": match.reason,
        "thresholds": [thresholds.max_distance, thresholds.min_margin],
        "ranking": [[i, d, list(b)] for i, d, b in match.ranking],
        "texture": texture,
        "decided_by": match.decided_by if match.known else "",
        "expected": match.expected,
        "verified_expected": match.verified_expected,
        "crops": crops,
    }


class PerceptionError(Exception):
    """A perception problem with a message meant for the user (no traceback needed)."""


@dataclass
class BlockScan:
    """The blocks one scan committed (left to right), as DetectBlocks outputs them."""

    crops: list[np.ndarray] = field(default_factory=list)
    frames: list[int] = field(default_factory=list)  # camera frame index of each crop
    times_s: list[float] = field(default_factory=list)
    qualities: list[float] = field(default_factory=list)
    frames_seen: int = 0
    key: str = ""  # the blackboard entry DetectBlocks writes it to (the report names it)
    t_s: float = 0.0  # mission time the scan started

    @property
    def count(self) -> int:
        """Number of committed blocks."""
        return len(self.crops)

    def __repr__(self) -> str:  # the tick log shows this, not the pixels
        sizes = ", ".join(f"{c.shape[1]}x{c.shape[0]}" for c in self.crops)
        return f"BlockScan({self.count} blocks [{sizes}] from {self.frames_seen} frames)"


@dataclass
class KeyFrame:
    """A frame worth showing in the report: the image and its detections."""

    index: int
    t_s: float
    image: np.ndarray  # BGR
    boxes: list[tuple[float, float, float, float, float]]  # x1, y1, x2, y2, score
    committed: list[int] = field(default_factory=list)  # block numbers whose crop came from here
    seq_frame: int = -1  # the sequencer's frame number (CommittedBlock.frame_index)
    committed_boxes: list[tuple[float, float, float, float]] = field(default_factory=list)


def frame_bgr(image: Any, fmt: str | None, factors: tuple[float, float, float]) -> np.ndarray:
    """The white-balanced BGR image of a camera frame (raw Bayer BG or already BGR).

    Raises :class:`PerceptionError` naming the offending shape and type when the frame is not
    a 244 x 324 uint8 Bayer image or a 244 x 324 x 3 uint8 BGR image.
    """
    from perception.white_balance import preprocess

    arr = np.asarray(image) if image is not None else None
    h, w = FRAME_HW
    expected = f"a {w}x{h} raw Bayer BG frame (uint8, {h}x{w}) or a BGR image (uint8, {h}x{w}x3)"
    if arr is None or arr.dtype != np.uint8 or arr.ndim not in (2, 3):
        what = "nothing" if arr is None else f"shape {arr.shape} of {arr.dtype}"
        raise PerceptionError(f"camera frame has {what}; expected {expected}")
    if arr.shape[:2] != (h, w) or (arr.ndim == 3 and arr.shape[2] != 3):
        raise PerceptionError(f"camera frame has shape {arr.shape}; expected {expected}")
    if arr.ndim == 2:
        if fmt not in (None, "bayer", "bayer_bg", "raw"):
            raise PerceptionError(f"camera frame format '{fmt}' is 2-D; expected {expected}")
        return preprocess(arr, factors)
    return arr


class PerceptionSession:
    """Models, gallery and records of one run; see the module doc."""

    def __init__(self, rig: Any = None, log: Callable[[str], None] | None = None) -> None:
        self.rig = rig
        data = getattr(rig, "data", None) or {}
        camera = (data.get("sensors") or {}).get("camera") or {}
        self.camera: dict = dict(camera)
        self.factors = tuple(float(f) for f in camera.get("white_balance", (1.0, 1.0, 1.0)))
        self.gate_settings: dict = dict(data.get("perception") or {})
        self.log = log or (lambda msg: None)
        self._detectors: dict[str, Any] = {}
        self._embedders: dict[str, Any] = {}
        self._galleries: dict[tuple[str, str], Any] = {}
        self.recent: deque[KeyFrame] = deque(maxlen=45)  # frames with detections, newest last
        self.key_frames: list[KeyFrame] = []  # frames the committed crops came from
        self.scans: list[BlockScan] = []
        self.identifications: list[dict] = []
        self.enrolments: list[dict] = []
        self.latencies_ms: list[float] = []
        self.frames = 0
        self.detections = 0
        self.frames_skipped = 0  # new frames a leaf's frame gate skipped (view barely moved)
        self.tracker: Any = None  # perception.face.FaceTracker while a reactive scan runs
        self.faces: list[dict] = []  # face estimates of the reactive leaves, for the report
        self.worker: PerceptionWorker | None = None  # real time: detection off the tick thread
        self._detect_with: tuple[Any, float | None] | None = None  # the worker's detector
        self.decision_ms: deque[float] = deque(maxlen=20_000)  # capture -> leaf used it

    @classmethod
    def of(cls, ctx: Any) -> PerceptionSession:
        """The session of a mission context (created on first use)."""
        session = ctx.resources.get("perception")
        if session is None:
            session = cls(ctx.resources.get("rig"), ctx.log)
            ctx.resources["perception"] = session
        return session

    # -- models and gallery -------------------------------------------------------------------
    def detector(self, path: str = "") -> Any:
        """The block detector (``""``: the shipped weights), loaded once."""
        if path not in self._detectors:
            from perception.detector import BlockDetector

            try:
                self._detectors[path] = _cached(
                    ("detector", path),
                    lambda: BlockDetector.load(path or None, threads=TORCH_THREADS),
                )
            except ModelError as exc:
                raise PerceptionError(f"block detector: {exc}") from None
        return self._detectors[path]

    def embedder(self, path: str = "") -> Any:
        """The PCB embedder (``""``: the shipped weights), loaded once."""
        if path not in self._embedders:
            from perception.embedder import BlockEmbedder

            try:
                self._embedders[path] = _cached(
                    ("embedder", path),
                    lambda: BlockEmbedder.load(path or None, threads=TORCH_THREADS),
                )
            except ModelError as exc:
                raise PerceptionError(f"block embedder: {exc}") from None
        return self._embedders[path]

    def world_path(self) -> str | None:
        """The rig's world file, if the rig has one."""
        wp = getattr(self.rig, "world_path", None)
        return wp if wp and os.path.exists(wp) else None

    def gallery(self, spec: str, embedder: Any, create: bool = False, detector: Any = None) -> Any:
        """Open the gallery ``spec`` for ``embedder``'s model (``"demo"``: the demo gallery of
        the rig's world, built on first use; ``create``: make an empty file if missing)."""
        from perception.gallery import Gallery, GalleryError
        from perception.gallery_pg import is_gallery_url

        key = (spec, embedder.model_version)
        if key in self._galleries:
            return self._galleries[key]
        try:
            if spec == DEMO:
                from nodes.gallery.demo import ensure_demo_gallery

                world = self.world_path()
                if world is None:
                    raise PerceptionError(
                        "the demo gallery needs a rig with a world (e.g. rigs/sim.yaml); "
                        "give gallery=<file.sqlite> instead"
                    )
                from drivers.settings import ConfigError

                try:
                    path = ensure_demo_gallery(
                        world,
                        detector or self.detector(),
                        embedder,
                        self.camera,
                        log=self.log,
                        overrides=getattr(self.rig, "world_overrides", None),
                    )
                except ConfigError as exc:  # the world of the gallery fails its checks
                    raise PerceptionError(f"demo gallery: {exc}") from None
                g = Gallery.open(path, embedder.model_version)
            elif is_gallery_url(spec):  # postgresql://...#NAME: a gallery in the site store
                try:
                    g = Gallery.open(spec, embedder.model_version)
                except GalleryError as exc:
                    if not create or "no such gallery" not in str(exc):
                        raise
                    g = Gallery.create(spec, embedder.model_version, embedder.dim, exist_ok=True)
                    g.set_thresholds(embedder.thresholds)
            elif os.path.exists(spec):
                g = Gallery.open(spec, embedder.model_version)
            elif create:
                g = Gallery.create(spec, embedder.model_version, embedder.dim)
                g.set_thresholds(embedder.thresholds)
            else:
                raise PerceptionError(
                    f"gallery '{spec}' does not exist: enrol pallets first "
                    "(missions/enroll_pallet.xml or btrun gallery enrol), or use gallery=demo"
                )
            # read the embeddings and build the search index now, on the ground, not at the
            # first identification
            aware = getattr(embedder, "occlusion_aware", False)
            g.prepare_search(embedder.config.parts if aware else 1)
        except GalleryError as exc:
            raise PerceptionError(f"gallery: {exc}") from None
        self._galleries[key] = g
        return g

    def galleries(self) -> list[Any]:
        """The galleries opened so far (PerceptionReady opens the mission's)."""
        return list(self._galleries.values())

    def close(self) -> None:
        """Stop the perception worker; close the open galleries."""
        if self.worker is not None:
            self.worker.close()
        for g in self._galleries.values():
            g.close()
        self._galleries.clear()

    # -- frames ------------------------------------------------------------------------------
    def frame_gate(self) -> Any:
        """A new :class:`perception.frame_gate.FrameGate` for one leaf, from the rig's
        ``perception`` settings (each leaf processes its first frame)."""
        from perception.frame_gate import FrameGate, FrameGateParams
        from perception.synth.camera_model import CameraModel

        g = self.gate_settings
        defaults = FrameGateParams()
        params = FrameGateParams(
            float(g.get("min_view_change_px", defaults.min_view_change_px)),
            float(g.get("max_frame_gap_s", defaults.max_frame_gap_s)),
            float(g.get("view_depth_m", defaults.view_depth_m)),
        )
        return FrameGate(CameraModel.from_dict(self.camera), params)

    def wants(self, gate: Any, frame: Any) -> bool:
        """True if ``gate`` lets the new camera ``frame`` through (its view changed enough,
        or enough time passed); a skipped frame is never rendered nor detected."""
        from perception.synth.camera_model import CameraPose

        pose = getattr(frame, "pose", None)
        cam = None
        if pose is not None and getattr(pose, "source", "") != "none":
            cam = CameraPose.from_quaternion(pose.x_m, pose.y_m, pose.z_m, pose.quaternion)
        if gate.wants(frame.t_s, cam):
            return True
        self.frames_skipped += 1
        return False

    def start_tracking(self) -> Any:
        """A new face tracker (:class:`perception.face.FaceTracker`) fed with every frame
        processed from now on, for the rig's camera model."""
        from perception.face import FaceTracker
        from perception.synth.camera_model import CameraModel

        self.tracker = FaceTracker(CameraModel.from_dict(self.camera))
        self.tracker_place = None
        return self.tracker

    def tracker_for(self, place: Any) -> Any:
        """The face tracker of the pallet place ``place`` (x, y, z): the running one if it
        tracks that place (a second LocatePallet pass keeps everything seen so far), a new
        one for a new place (an inventory: what was seen at one place must not shape the
        next place's face)."""
        key = tuple(round(float(v), 4) for v in place) if place is not None else None
        if self.tracker is None or getattr(self, "tracker_place", None) != key:
            self.start_tracking()
            self.tracker_place = key
        return self.tracker

    def _track(self, frame: Any, dets: list) -> None:
        pose = getattr(frame, "pose", None)
        if self.tracker is not None and pose is not None:
            boxes = [(d.x1, d.y1, d.x2, d.y2) for d in dets]
            self.tracker.add_frame(pose.position, pose.quaternion, boxes)

    # -- observations: detection in the step (lock-step) or on the worker (real time) -------
    def feed(self, vehicle: Any, realtime: bool) -> FrameFeed:
        """A leaf's feed, from now on (frames already there are not its). In real time it
        has no gate (the worker takes the newest frame whenever it is free)."""
        frame = vehicle.camera_frame()
        if realtime:
            w = self.worker
            return FrameFeed(None, w.seq if w else 0, None, w.errors if w else 0)
        return FrameFeed(frame.index if frame is not None else None, 0, self.frame_gate())

    def observations(
        self, feed: FrameFeed, vehicle: Any, detector: Any, min_score: float | None, now_s: float
    ) -> list[Observation]:
        """What the detector saw since the feed's last call, oldest first. Lock-step
        (``feed.seq`` unused): the newest frame, detected now, if it is new and the feed's
        gate wants it. Real time: the worker's observations since the last call (the
        worker is started on first use). Raises :class:`PerceptionError` for a frame the
        models cannot take (a wrong size or format)."""
        if feed.gate is None:  # real time
            self._detect_with = (detector, min_score)
            if self.worker is None:
                self.worker = PerceptionWorker(vehicle.camera_frame, self._worker_detect)
            if self.worker.errors > feed.errors:  # a frame the models could not take
                feed.errors = self.worker.errors
                raise PerceptionError(self.worker.last_error)
            out = self.worker.since(feed.seq)
            if out:
                feed.seq = out[-1].seq
        else:
            frame = vehicle.camera_frame()
            if frame is None or frame.index == feed.last_index:
                return []
            feed.last_index = frame.index
            if not self.wants(feed.gate, frame):
                return []
            t0 = time.perf_counter()
            bgr, dets = self.detect_frame(frame, detector, min_score)
            out = [Observation(frame, bgr, dets, 0, (time.perf_counter() - t0) * 1e3)]
        for obs in out:
            self.decision_ms.append(max(0.0, now_s - obs.frame.t_s) * 1e3)
        return out

    def _worker_detect(self, frame: Any) -> tuple[np.ndarray, list]:
        detector, min_score = self._detect_with  # type: ignore[misc]
        return self.detect_frame(frame, detector, min_score)

    def detect_frame(
        self, frame: Any, detector: Any, min_score: float | None
    ) -> tuple[np.ndarray, list]:
        """White-balance one camera frame and detect its blocks (counted for the summary)."""
        t0 = time.perf_counter()
        bgr = frame_bgr(frame.image, (frame.meta or {}).get("format"), self.factors)
        dets = detector.detect(bgr, min_score=min_score)
        self.latencies_ms.append((time.perf_counter() - t0) * 1e3)
        self.frames += 1
        self.detections += len(dets)
        return bgr, dets

    def track(self, obs: Observation) -> list:
        """Feed one observation to the face tracker only (no sequencer); its boxes."""
        self._track(obs.frame, obs.dets)
        return obs.dets

    def process(
        self, obs: Observation, sequencer: Any, max_row_offset_px: float | None = None
    ) -> list:
        """Feed one observation to the sequencer (and the face tracker, if one runs); return
        new commits. ``max_row_offset_px``: the sequencer only gets boxes whose centre is at
        most this far above or below the image's middle row (the scanned row; not the
        blocks of a pallet below or above it)."""
        frame, bgr, dets = obs.frame, obs.bgr, obs.dets
        row = dets
        if max_row_offset_px is not None:
            mid = 0.5 * (bgr.shape[0] - 1)
            row = [d for d in dets if abs(0.5 * (d.y1 + d.y2) - mid) <= max_row_offset_px]
        committed = sequencer.update(bgr, row, frame.t_s)
        self._track(frame, dets)
        if dets:
            boxes = [(d.x1, d.y1, d.x2, d.y2, d.score) for d in dets]
            self.recent.append(
                KeyFrame(frame.index, frame.t_s, bgr, boxes, seq_frame=sequencer.frames)
            )
        for block in committed:
            source = next((k for k in self.recent if k.seq_frame == block.frame_index), None)
            if source is not None:
                source.committed.append(block.index)
                b = block.box
                source.committed_boxes.append((b.x1, b.y1, b.x2, b.y2))
                if all(source is not k for k in self.key_frames):
                    self.key_frames.append(source)
        return committed

    def result_lines(self) -> list[str]:
        """The run's headline for the terminal: every identification (its blackboard key,
        unless it is the usual ``pallet_id``), its answer and how sure it is, or why it
        failed; and what was enrolled (``btrun`` prints these after the status line)."""
        out = []
        if len(self.identifications) > MAX_RESULT_LINES:  # an inventory: count, do not list
            known = sum(1 for r in self.identifications if r.get("known"))
            failed = sum(1 for r in self.identifications if "failed" in r)
            unknown = len(self.identifications) - known - failed
            out.append(
                f"pallets: {len(self.identifications)} identifications, {known} known, "
                f"{unknown} unknown, {failed} failed (each in summary.json perception)"
            )
        for r in self.identifications[: 0 if out else None]:
            key = r.get("key") or ""
            label = "pallet:" if key in ("", "pallet_id") else f"pallet {{{key}}}:"
            if "failed" in r:
                out.append(f"{label} failed in {r.get('node', 'IdentifyPallet')}: {r['failed']}")
                continue
            extra = f"distance {r['distance']:.3f}, margin {r['margin']:.3f}"
            if not r["known"]:
                extra += f", closest {r['best_id']}"
            out.append(f"{label} {r['pallet_id']} ({extra})")
        out += [f"enrolled: {e['name']} in {e['gallery']}" for e in self.enrolments]
        return out

    def run_summary(self) -> dict:
        """What ``summary.json`` records under ``perception`` (see :meth:`summary`)."""
        return self.summary()

    def summary(self) -> dict:
        """Figures for ``summary.json``: frames, detections, latency, answers."""
        lat = np.asarray(self.latencies_ms) if self.latencies_ms else None
        out: dict[str, Any] = {
            "frames_processed": self.frames,
            "frames_skipped": self.frames_skipped,
            "detections": self.detections,
            "blocks": [s.count for s in self.scans],
        }
        if lat is not None:
            out["frame_to_decision_ms"] = {
                "p50": round(float(np.percentile(lat, 50)), 2),
                "p95": round(float(np.percentile(lat, 95)), 2),
                "max": round(float(lat.max()), 2),
            }
        w = self.worker
        out["mode"] = "worker thread" if w is not None else "in the tick"
        out["frames_dropped"] = w.dropped if w is not None else 0
        if self.decision_ms:
            dec = np.asarray(self.decision_ms)
            out["capture_to_decision_ms"] = {
                "p50": round(float(np.percentile(dec, 50)), 1),
                "p95": round(float(np.percentile(dec, 95)), 1),
            }
        if self.identifications:
            out["identifications"] = [
                {k: v for k, v in rec.items() if k != "crops"} for rec in self.identifications
            ]
        if self.enrolments:
            out["enrolments"] = self.enrolments
        if self.faces:
            out["faces"] = self.faces
        return out
