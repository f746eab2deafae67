"""Perception leaves: PerceptionReady, DetectBlocks, BlockCount, IdentifyPallet, EnrollPallet.

The pallet-scan mission runs ``DetectBlocks`` beside the scan flight (in a Parallel): each
tick it takes the newest camera frame, detects the support blocks and feeds the block
sequencer, and it succeeds once three blocks are committed. ``IdentifyPallet`` embeds the
three crops (PCB) and matches them against the gallery; ``EnrollPallet`` adds them to it.
``PerceptionReady`` loads the models and opens the gallery before take-off, so a missing
weights file or a gallery of another model stops the mission on the ground.

Problems (bad weights, gallery, frames, a stalled camera) end the leaf with FAILURE and a
message in the run log; they never raise, so the tree (or the safety supervisor) lands.
"""

from __future__ import annotations

import os
import threading
from typing import Any

from bt_engine.node import (
    FAILURE,
    RUNNING,
    SUCCESS,
    ConditionNode,
    NodeRuntimeError,
    NodeStatus,
    StatefulActionNode,
    SyncActionNode,
)
from bt_engine.ports import ANY, BOOL, DURATION, FLOAT, INT, STRING, input_port, output_port
from bt_engine.registry import register
from nodes.common import is_realtime, vehicle_of
from nodes.identify import expected_for, identify_described
from nodes.perception_session import (
    DEMO,
    MIN_SCORE_DOC,
    BlockScan,
    PerceptionError,
    PerceptionSession,
    identification_record,
)
from perception.errors import ModelError
from perception.gallery import GalleryError

CATEGORY_PERCEPTION = "perception"

_DETECTOR = input_port("detector", STRING, "", "detector weights file (empty: the shipped model)")
_EMBEDDER = input_port("embedder", STRING, "", "embedder weights file (empty: the shipped model)")
_GALLERY = input_port(
    "gallery", STRING, DEMO, "gallery file (.sqlite), or demo: the world's pallets 1A..5B"
)


def _fail(node, reason: str) -> NodeStatus:
    node.ctx.log(f"{node.describe()} failed: {reason}")
    node.failure_reason = reason
    return FAILURE


def _camera_problem(vehicle: Any) -> str:
    """Why the vehicle cannot see the pallet ("" if it can, or if there is no vehicle)."""
    if vehicle is None:
        return ""
    camera = getattr(vehicle, "camera", None)
    if camera is None:
        return "the rig has no camera: enable the AI-deck (aideck.enabled: true)"
    if hasattr(camera, "renderer") and camera.renderer is None:
        return (
            "the simulated camera renders nothing (sensors.camera.renderer: none): "
            "use --set sensors.camera.renderer=pallet"
        )
    return ""


@register
class PerceptionReady(SyncActionNode):
    """Load the detector and the embedder and open the gallery (building the demo gallery on
    first use); FAILURE with the reason if any of them cannot be used. Put it before the
    take-off so nothing flies with a broken perception."""

    bt_id = "PerceptionReady"
    category = CATEGORY_PERCEPTION
    #: its pre-flight check loads the models and builds the demo gallery: run last, once
    #: every cheaper check has passed (bt_engine.mission.Mission.preflight)
    preflight_loads = True
    ports = (
        _DETECTOR,
        _EMBEDDER,
        _GALLERY,
        input_port("enrol", BOOL, False, "true: the gallery may be new or empty (enrolment)"),
        output_port("gallery_size", INT, "number of enrolled pallet sides"),
    )

    def preflight(self) -> list[Any]:
        """Load the models and open the gallery (building the demo gallery) before the first
        tick: in real time the drone does not wait for a tick that loads models. A problem
        is reported before anything flies. Inputs only known in flight are left to the
        tick."""
        try:
            self._load()
        except PerceptionError as exc:
            return [("gallery", str(exc))]
        except NodeRuntimeError:  # an input only known in flight (a blackboard entry): the
            return []  # tick (anything else is reported by the mission's preflight)
        return []

    def _load(self) -> Any:
        session = PerceptionSession.of(self.ctx)
        detector = session.detector(self.get_input("detector"))
        embedder = session.embedder(self.get_input("embedder"))
        return session.gallery(
            self.get_input("gallery"), embedder, create=self.get_input("enrol"), detector=detector
        )

    def tick_impl(self) -> NodeStatus:
        enrol = self.get_input("enrol")
        problem = _camera_problem(self.ctx.vehicle)
        if problem:
            return _fail(self, problem)
        try:
            g = self._load()  # loaded in preflight already: here it is a look-up
        except PerceptionError as exc:
            return _fail(self, str(exc))
        self.set_output("gallery_size", len(g))
        if len(g) == 0 and not enrol:
            return _fail(self, f"gallery {g.path} is empty: enrol pallets first")
        return SUCCESS


@register
class DetectBlocks(StatefulActionNode):
    """Consume camera frames as they arrive, detect the support blocks and commit one crop
    per block, left to right (the block sequencer). A frame whose view barely moved since
    the last one processed is skipped (the rig's ``perception.min_view_change_px`` and
    ``max_frame_gap_s``; docs/performance.md). RUNNING until ``blocks`` are committed,
    then SUCCESS; run it in a Parallel beside the scan flight. ``count`` and ``scan`` are
    written whenever a block is committed, so they hold what was found if the scan ends
    first. FAILURE if the camera delivers no frame for ``stall_timeout``, on a frame of the
    wrong size or format, or after ``timeout``."""

    bt_id = "DetectBlocks"
    category = CATEGORY_PERCEPTION
    ports = (
        _DETECTOR,
        input_port("min_score", FLOAT, None, MIN_SCORE_DOC),
        input_port("max_distance_left_px", FLOAT, 60.0, "keep crops this close left of centre"),
        input_port("min_distance_right_px", FLOAT, 20.0, "commit once this far right of centre"),
        input_port("blocks", INT, 3, "blocks to commit before SUCCESS"),
        input_port(
            "max_row_offset_px",
            FLOAT,
            None,
            "ignore boxes centred farther than this above or below the image's middle row "
            "(another pallet's blocks); default: none ignored",
        ),
        input_port("stall_timeout", DURATION, 1.0, "FAILURE after this long without a frame, s"),
        input_port("timeout", DURATION, 120.0, "FAILURE if not done within this time, s"),
        output_port("count", INT, "blocks committed so far"),
        output_port("scan", ANY, "the committed crops (for IdentifyPallet / EnrollPallet)"),
    )

    def on_start(self) -> NodeStatus:
        from perception.sequencer import BlockSequencer, SequencerParams

        self.vehicle = vehicle_of(self)
        self.session = PerceptionSession.of(self.ctx)
        try:
            self.detector = self.session.detector(self.get_input("detector"))
        except PerceptionError as exc:
            return _fail(self, str(exc))
        params = SequencerParams(
            max_distance_left_px=self.get_input("max_distance_left_px"),
            min_distance_right_px=self.get_input("min_distance_right_px"),
            blocks=self.get_input("blocks"),
        )
        self.sequencer = BlockSequencer(params)
        self.min_score = self.get_input("min_score")
        self.row_offset_px = self.get_input("max_row_offset_px")
        self.stall_s, self.timeout_s = self.get_input("stall_timeout"), self.get_input("timeout")
        self.started_s = self.last_frame_s = self.now()
        frame = self.vehicle.camera_frame()
        self.last_index = frame.index if frame is not None else None  # only frames from now on
        self.feed = self.session.feed(self.vehicle, is_realtime(self))
        self.result = BlockScan(key=self.output_key("scan") or "", t_s=self.now())
        self.camera_index: dict[int, int] = {}  # sequencer frame number -> camera frame index
        self.session.scans.append(self.result)
        self.session.recent.clear()
        self.set_output("count", 0)
        self.set_output("scan", self.result)
        return self.on_running()

    def on_running(self) -> NodeStatus:
        now = self.now()
        frame = self.vehicle.camera_frame()
        if frame is not None and frame.index != self.last_index:  # the camera is alive
            self.last_index, self.last_frame_s = frame.index, now
        try:
            seen = self.session.observations(
                self.feed, self.vehicle, self.detector, self.min_score, now
            )
        except PerceptionError as exc:
            return _fail(self, str(exc))
        for obs in seen:
            status = self._process(obs)
            if status is not None:
                return status
        if now - self.last_frame_s >= self.stall_s - 1e-9:
            return _fail(
                self,
                f"camera stalled: no frame for {now - self.last_frame_s:.2f} s "
                f"({self.result.count} of {self.sequencer.params.blocks} blocks committed)",
            )
        if now - self.started_s >= self.timeout_s - 1e-9:
            return _fail(
                self,
                f"time-out after {self.timeout_s:g} s with {self.result.count} of "
                f"{self.sequencer.params.blocks} blocks",
            )
        return RUNNING

    def _process(self, obs: Any) -> NodeStatus | None:
        """Sequence one observation; SUCCESS once every block is committed."""
        frame = obs.frame
        self.camera_index[self.sequencer.frames + 1] = frame.index
        new = self.session.process(obs, self.sequencer, self.row_offset_px)
        r = self.result
        r.frames_seen += 1
        for block in new:
            r.crops.append(block.crop)
            r.frames.append(self.camera_index.get(block.frame_index, frame.index))
            r.times_s.append(block.t_s)
            r.qualities.append(block.quality)
        if new:
            self.set_output("count", r.count)
            self.set_output("scan", r)
        return SUCCESS if self.sequencer.done else None


@register
class BlockCount(ConditionNode):
    """SUCCESS if at least ``min`` blocks were committed (``count`` from DetectBlocks)."""

    bt_id = "BlockCount"
    category = CATEGORY_PERCEPTION
    ports = (
        input_port("count", INT, description="blocks committed (DetectBlocks' count)"),
        input_port("min", INT, 3, "blocks needed"),
    )

    def check(self) -> bool:
        return self.get_input("count") >= self.get_input("min")


def _scan_crops(node, scan) -> list:
    if not isinstance(scan, BlockScan):
        raise PerceptionError(f"scan must be DetectBlocks' scan output, got {type(scan).__name__}")
    if scan.count < 3:
        raise PerceptionError(f"the scan committed {scan.count} of 3 blocks; need all three")
    return scan.crops[:3]


@register
class IdentifyPallet(StatefulActionNode):
    """Embed the three block crops and match them against the gallery: ``pallet_id`` is the
    closest enrolled side, or ``unknown`` when its mean block distance is above
    ``max_distance`` or its margin to the runner-up is below ``min_margin`` (defaults: the
    thresholds stored in the gallery, calibrated with the model). With ``verify_texture``
    the best candidates are also compared on the blocks' texture with their enrolment crops:
    a side whose texture matches far above every other pallet's is identified even when it
    aged or is seen from farther away, and an answer whose texture does not match is
    ``unknown``. With ``place`` and an expected stock naming a pallet there, the scan is
    first verified 1:1 against that pallet (``decided_by`` ``verified``) and identified
    1:N only if it does not verify (:mod:`nodes.identify`). SUCCESS with an answer
    (``unknown`` included); FAILURE if there are not three crops or the gallery cannot be
    used."""

    bt_id = "IdentifyPallet"
    category = CATEGORY_PERCEPTION
    ports = (
        input_port("scan", ANY, description="DetectBlocks' scan output"),
        _GALLERY,
        _EMBEDDER,
        input_port(
            "max_distance", FLOAT, None, "unknown above this mean distance (default: gallery)"
        ),
        input_port("min_margin", FLOAT, None, "unknown below this margin (default: gallery)"),
        input_port("top_k", INT, 5, "length of the ranking"),
        input_port(
            "update_gallery",
            BOOL,
            False,
            "after a confident answer (distance and margin well inside the thresholds) add "
            "this scan as a view of the side (bounded, in the gallery's history, can be "
            "rolled back); never from an unconfident one",
        ),
        input_port(
            "verify_texture",
            BOOL,
            True,
            "verify the best candidates on the blocks' texture against their enrolment crops",
        ),
        input_port(
            "place",
            STRING,
            "",
            "the inventory place scanned: verify 1:1 first against the pallet the expected "
            "stock names there (empty: identify only)",
        ),
        output_port("pallet_id", STRING, "identity (e.g. 3A) or unknown"),
        output_port("best_id", STRING, "closest identity, even when the answer is unknown"),
        output_port("distance", FLOAT, "mean block distance to the closest identity"),
        output_port("margin", FLOAT, "runner-up distance minus the best distance"),
        output_port("ranking", ANY, "top_k [identity, mean distance] pairs, best first"),
        output_port("gallery_updated", BOOL, "true if this scan was added to the gallery"),
        output_port(
            "decided_by",
            STRING,
            "embedding, texture, embedding+texture or verified (empty if unknown)",
        ),
    )

    #: real time: FAILURE if an identification on its thread takes longer than this, s
    MAX_IDENTIFY_S = 60.0

    def on_start(self) -> NodeStatus:
        """Read the inputs; identify now (lock-step) or on a thread of its own (real time:
        embedding and texture verification take a few hundred ms, which the tick thread,
        and the drone hovering meanwhile, must not wait for)."""
        self._job: dict[str, Any] | None = None
        try:
            inputs = self._inputs()
        except (PerceptionError, GalleryError, ModelError) as exc:
            return self._failed(exc)
        if not is_realtime(self):
            try:
                found = self._compute(inputs)
            except (PerceptionError, GalleryError, ModelError) as exc:
                return self._failed(exc)
            return self._finish(inputs, *found)
        job: dict[str, Any] = {"inputs": inputs, "started_s": self.now()}
        done = threading.Event()

        def work() -> None:
            try:
                job["found"] = self._compute(inputs)
            except BaseException as exc:  # handed to the tick thread
                job["error"] = exc
            finally:
                done.set()

        job["done"] = done
        threading.Thread(target=work, name="identify", daemon=True).start()
        self._job = job
        return RUNNING

    def on_running(self) -> NodeStatus:
        """Real time: RUNNING until the identification thread is done."""
        job = self._job
        if job is None:  # pragma: no cover - halted and ticked again without a start
            return FAILURE
        if not job["done"].is_set():
            if self.now() - job["started_s"] > self.MAX_IDENTIFY_S:
                self._job = None
                return self._failed(
                    PerceptionError(f"identification took longer than {self.MAX_IDENTIFY_S:g} s")
                )
            return RUNNING
        self._job = None
        error = job.get("error")
        if isinstance(error, (PerceptionError, GalleryError, ModelError)):
            return self._failed(error)
        if error is not None:
            raise error
        return self._finish(job["inputs"], *job["found"])

    def on_halted(self) -> None:
        """The thread (if any) finishes on its own; its answer is not used."""
        self._job = None

    def _inputs(self) -> dict[str, Any]:
        from perception.gallery import Thresholds

        session = PerceptionSession.of(self.ctx)
        crops = _scan_crops(self, self.get_input("scan"))
        embedder = session.embedder(self.get_input("embedder"))
        g = session.gallery(self.get_input("gallery"), embedder)
        th = g.thresholds
        md, mm = self.get_input("max_distance"), self.get_input("min_margin")
        return {
            "session": session,
            "crops": crops,
            "embedder": embedder,
            "gallery": g,
            "thresholds": Thresholds(
                th.max_distance if md is None else md, th.min_margin if mm is None else mm
            ),
            "top_k": self.get_input("top_k"),
            "verify": self.get_input("verify_texture"),
            "update": self.get_input("update_gallery"),
            "gallery_name": self.get_input("gallery"),
            "expected": expected_for(self.ctx, self.get_input("place")),
        }

    def _compute(self, i: dict[str, Any]) -> tuple[Any, str]:
        """Embed and match (and update the gallery if asked): the slow part."""
        crops, embedder, g, th = i["crops"], i["embedder"], i["gallery"], i["thresholds"]
        desc = embedder.describe(crops)
        vis = desc.visibility if embedder.occlusion_aware else None
        match = identify_described(
            g,
            desc.vectors,
            vis,
            crops,
            th,
            expected=i["expected"],
            top_k=i["top_k"],
            verify_texture=i["verify"],
        )
        return match, self._update(i, match, desc.vectors, vis)

    def _failed(self, exc: Exception) -> NodeStatus:
        session = PerceptionSession.of(self.ctx)
        key = self.output_key("pallet_id") or ""
        session.identifications.append(
            {"t_s": self.now(), "key": key, "node": self.describe(), "failed": str(exc)}
        )
        return _fail(self, str(exc))

    def _finish(self, i: dict[str, Any], match: Any, update: str) -> NodeStatus:
        session, th, crops = i["session"], i["thresholds"], i["crops"]
        key = self.output_key("pallet_id") or ""
        ranking = [[ident, round(d, 4)] for ident, d, _ in match.ranking]
        record = identification_record(
            match, th, crops, t_s=self.now(), key=key, node=self.describe()
        )
        record["gallery_update"] = update
        session.identifications.append(record)
        self.set_output("gallery_updated", bool(update and update.startswith("added")))
        self.set_output("pallet_id", match.pallet_id)
        self.set_output("best_id", match.best_id)
        self.set_output("distance", match.distance)
        self.set_output("margin", match.margin)
        self.set_output("ranking", ranking)
        self.set_output("decided_by", match.decided_by if match.known else "")
        note = f" ({match.decided_by})" if match.known else ""
        if not match.known:
            note = f" ({match.reason}; closest {match.best_id})"
        self.ctx.log(
            f"pallet {match.pallet_id}: distance {match.distance:.3f}, margin {match.margin:.3f}{note}"
        )
        if update:
            self.ctx.log(f"gallery update: {update}")
        return SUCCESS

    def _update(self, i: dict[str, Any], match: Any, vectors: Any, vis: Any) -> str:
        """Add the scan to the gallery if asked and confident; what happened ("" if not asked)."""
        if not i["update"]:
            return ""
        if match.verified_expected:  # a 1:1 bar, not the open-set confidence updates need
            return "not updated: verified against the expected stock, not identified"
        if i["gallery_name"] == DEMO:
            return "not updated: the demo gallery is generated (use your own gallery file)"
        run = os.path.basename(str(self.ctx.resources.get("run_dir") or "")) or "mission"
        run = f"{run} t={self.now():.1f} s"
        decision = i["gallery"].update(
            match, vectors, vis, run=run, thresholds=i["thresholds"], crops=i["crops"]
        )
        if decision.update:
            return f"added a view to {match.pallet_id} ({decision.reason})"
        return f"not updated: {decision.reason}"


@register
class EnrollPallet(SyncActionNode):
    """Add the scanned pallet side to the gallery as ``identity`` (e.g. 7A), with its three
    crops; creates the gallery file if needed. FAILURE if there are not three crops, or the
    identity is enrolled already and ``replace`` is false. (The port is not called ``name``:
    that attribute is every node's instance name.)"""

    bt_id = "EnrollPallet"
    category = CATEGORY_PERCEPTION
    ports = (
        input_port("identity", STRING, description="pallet side to enrol, e.g. 7A"),
        input_port("scan", ANY, description="DetectBlocks' scan output"),
        input_port(
            "gallery", STRING, "pallets.sqlite", "gallery file (.sqlite), created if missing"
        ),
        _EMBEDDER,
        input_port("replace", BOOL, True, "replace an existing entry of the same name"),
        output_port("gallery_size", INT, "number of enrolled pallet sides after enrolling"),
    )

    def tick_impl(self) -> NodeStatus:
        from perception.gallery_views import png_bytes

        session = PerceptionSession.of(self.ctx)
        name = self.get_input("identity").strip()
        try:
            if self.get_input("gallery") == DEMO:
                raise PerceptionError("the demo gallery is generated: enrol into your own file")
            crops = _scan_crops(self, self.get_input("scan"))
            embedder = session.embedder(self.get_input("embedder"))
            g = session.gallery(self.get_input("gallery"), embedder, create=True)
            desc = embedder.describe(crops)
            g.enrol(
                name,
                desc.vectors,
                [png_bytes(c) for c in crops],
                source=f"mission at t={self.now():.1f} s",
                replace=self.get_input("replace"),
                visibility=desc.visibility if embedder.occlusion_aware else None,
                run=os.path.basename(str(self.ctx.resources.get("run_dir") or "")),
            )
        except (PerceptionError, GalleryError, ModelError) as exc:
            return _fail(self, str(exc))
        session.enrolments.append({"t_s": self.now(), "name": name, "gallery": g.path})
        self.set_output("gallery_size", len(g))
        self.ctx.log(f"enrolled {name} in {g.path} ({len(g)} sides)")
        return SUCCESS
