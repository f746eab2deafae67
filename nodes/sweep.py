"""SweepPass: fly one rack level in one continuous line and answer its places on the fly.

The pass (planned by ``PlanSweep``, :mod:`nodes.sweep_plan`) starts a little before the first
place not answered yet and ends a little past the last: the drone goes there around the
racks (transit speed), turns to face the rack, then flies the line at ``speed`` and
``standoff`` from the faces. While it flies, the detector looks at the frames a pallet's
blocks are expected to be centred in (:class:`perception.sweep.SweepCollector`; real time:
every frame the perception worker gets to), each block is matched to its place's slot, and
each place is answered as the drone passes it:

* three blocks: identified against the gallery (``IdentifyPallet``'s matching, texture
  verification included): the pallet side, or ``unknown`` for a pallet the gallery does not
  know; an answer near the thresholds is left to the rescan instead;
* no block on its face: ``empty``;
* anything else (a block or two, frames missing): left for the rescan (``rescan`` output,
  the reactive per-place scan after the passes), with a ``not_scanned`` row meanwhile.

Every answer is a row of ``inventory.csv`` at once (:class:`nodes.inventory_log.InventoryLog`)
with its crops and candidates (:mod:`nodes.place_evidence`). Halted (the battery ran low: a
``ReactiveSequence`` with ``EnoughEnergy`` on ``next_point``), the places answered so far stay
answered; run again, the pass starts at the first place not answered, not at the level's
start. In real time, identifications run on a thread of their own so the tick never waits.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

from bt_engine.node import FAILURE, RUNNING, SUCCESS, NodeStatus, StatefulActionNode
from bt_engine.ports import ANY, BOOL, DURATION, FLOAT, INT, STRING, input_port, output_port
from bt_engine.registry import register
from bt_engine.spec import plural
from nodes.common import is_realtime, vehicle_of
from nodes.inventory import CATEGORY_INVENTORY, reach_problems, world_of
from nodes.inventory_log import EMPTY, IDENTIFIED, NOT_SCANNED, UNKNOWN, InventoryLog
from nodes.perception_feed import FrameFeed
from nodes.perception_session import (
    DEMO,
    MIN_SCORE_DOC,
    PerceptionError,
    PerceptionSession,
)
from nodes.place_evidence import write_place_evidence
from nodes.sweep_identify import Identifications
from nodes.sweep_plan import (
    footprints,
    geofence_inside,
    pass_end_problems,
    pass_line,
    route,
    sweep_plan_of,
)

FIXED_YAW = 2
#: The sweep's own acceptance of an answer the gallery's thresholds left unknown only on the
#: margin: the embedding's closest side is also the one whose blocks' texture matches best,
#: with at least this texture score, within the gallery's distance threshold and at least
#: this margin. Several averaged views of a block from a moving camera at 0.45 m sit a little
#: farther from their enrolment than one close, slow scan, so the margin calibrated for that
#: scan (0.251) sends right answers to the rescan; two tests agreeing on the same side are
#: what keeps an impostor out. Chosen on validation seed 100 of the site (every enrolled
#: place it left on the margin had texture = embedding, z 1.76 .. 3.13, margin 0.13 .. 0.249;
#: no never-enrolled pallet came within 0.754 of the distance or had the texture agree);
#: reported on held-out seeds (docs/performance.md, Sweep).
SWEEP_TEXTURE_Z = 1.5
SWEEP_MIN_MARGIN = 0.12


def sweep_accepts(match: Any, max_distance: float) -> bool:
    """True if the sweep takes the closest side of an unknown ``match`` (see
    :data:`SWEEP_TEXTURE_Z`)."""
    return (
        not match.known
        and match.texture_id is not None
        and match.texture_id == match.best_id
        and match.texture_z is not None
        and match.texture_z >= SWEEP_TEXTURE_Z
        and match.distance <= max_distance
        and match.margin >= SWEEP_MIN_MARGIN
    )


#: an unknown answer whose best distance is within this factor of the gallery's distance
#: threshold (it failed on the margin or the texture: an enrolled pallet seen badly, or a
#: close impostor) is rescanned rather than answered; farther, it is a pallet the gallery
#: does not know (validation seeds: docs/performance.md, Sweep)
RESCAN_DISTANCE_FACTOR = 1.0
#: a block slot sighted once (perception.sweep.PlaceWatch.slot_state): no parallax check
SINGLE = "single"
#: a second look flies slowly enough for this many sightings of each block while it is near
#: the image centre (about 0.2 m of flight at the stand-off), on a host that drops frames
SECOND_LOOK_SIGHTINGS = 3
CENTRAL_TRAVEL_M = 0.2


def _round(v: Any, nd: int = 4) -> Any:
    return round(float(v), nd) if isinstance(v, (int, float)) and math.isfinite(v) else None


@register
class SweepPass(StatefulActionNode):
    """Fly the pass ``pass`` (a name from PlanSweep's ``passes``) and answer each of its
    places as the drone passes it: identified, ``unknown`` or ``empty``, written to the
    inventory at once; places the pass could not answer go to ``rescan``. SUCCESS at the end
    of the line (also when every place was answered before); FAILURE on a refused motion,
    a perception or gallery error, or after ``timeout``."""

    bt_id = "SweepPass"
    category = CATEGORY_INVENTORY
    ports = (
        input_port("pass", STRING, description="pass name (PlanSweep's passes, e.g. A/2)"),
        input_port("gallery", STRING, DEMO, "gallery file (.sqlite) or demo"),
        input_port("speed", FLOAT, 0.8, "speed along the pass, m/s", low=0.02, high=2.0),
        input_port("standoff", FLOAT, 0.45, "distance from the pallet faces, m", low=0.2, high=1.5),
        input_port("transit_speed", FLOAT, 1.0, "speed to the pass start, m/s", low=0.05, high=3.0),
        input_port(
            "lead",
            FLOAT,
            0.5,
            "start this far before the first block (a run-up), m",
            low=0.0,
            high=3.0,
        ),
        input_port("detector", STRING, "", "detector weights file (empty: the shipped model)"),
        input_port("min_score", FLOAT, None, MIN_SCORE_DOC),
        input_port(
            "host_frame_time",
            DURATION,
            0.0,
            "lock-step: emulate a host that needs this long per frame (frames arriving "
            "meanwhile are dropped, as in real time), s",
            low=0.0,
            high=5.0,
        ),
        input_port(
            "rescan_places",
            BOOL,
            True,
            "hand the places the pass could not answer to the per-place scan (rescan); "
            "false: they stay not_scanned (a resumed run flies them again)",
        ),
        input_port(
            "second_look_speed",
            FLOAT,
            0.3,
            "a place the pass could not answer is flown past again at this speed right away "
            "(a few seconds) before it is left for the per-place scan; 0: never, m/s",
            low=0.0,
            high=2.0,
        ),
        input_port("second_looks", INT, 4, "at most this many second looks per pass"),
        input_port("timeout", DURATION, 180.0, "FAILURE if the pass is not done within this, s"),
        output_port(
            "next_point", ANY, "where the next place is scanned from, x;y;z (EnoughEnergy)"
        ),
        output_port("answered", INT, "places this pass answered"),
        output_port("rescan", ANY, "places left for the per-place scan (LoopString's queue)"),
    )

    def preflight(self) -> list[tuple[str, str]]:
        """A ``standoff`` that puts the pass lines inside a rack or outside the rig's
        geofence (every pass would fail in the air), or a pass whose run-up or tail lies
        outside the geofence, before anything flies."""
        try:
            world = world_of(self.ctx)
        except Exception:  # noqa: BLE001 - a bad world is said by the rig's own checks
            return []
        if world is None or not world.places:
            return []
        out = reach_problems(self, world, "standoff", "no pass can fly")
        return out or pass_end_problems(self, world)

    # -- start -------------------------------------------------------------------------------
    def on_start(self) -> NodeStatus:
        from perception.face import PalletModel
        from perception.sweep import PassPlace, SweepCollector, SweepParams
        from perception.synth.camera_model import CameraModel

        self.vehicle = vehicle_of(self)
        self.started_s = self.now()
        self.session = PerceptionSession.of(self.ctx)
        self.jobs: Identifications | None = None
        self.progress: Any = None
        plan = sweep_plan_of(self.ctx)
        name = self.get_input("pass")
        spec = plan.passes.get(name) if plan is not None else None
        if spec is None:
            known = ", ".join(plan.order[:6]) if plan else "none: run PlanSweep first"
            return self._fail(f"unknown pass '{name}' (passes: {known})")
        self.plan, self.spec = plan, spec
        self.log = InventoryLog.of(self.ctx)
        done = self.log.finished() | plan.left_for_rescan()
        todo = [p for p in spec.places if p not in done]
        self.set_output("answered", 0)
        self._rescan_output()
        if not todo:
            return SUCCESS
        try:
            self.detector = self.session.detector(self.get_input("detector"))
            self.embedder = self.session.embedder("")
            self.gallery = self.session.gallery(self.get_input("gallery"), self.embedder)
        except PerceptionError as exc:
            return self._fail(str(exc))
        standoff, lead = self.get_input("standoff"), self.get_input("lead")
        model = PalletModel()
        self.start_point, self.end_point = pass_line(spec, standoff, lead, todo)
        n = (-math.cos(spec.look_rad), -math.sin(spec.look_rad))  # out of the face
        self.points = {
            p: (r[0] + n[0] * standoff, r[1] + n[1] * standoff, r[2])
            for p, r in ((p, spec.rows[p]) for p in todo)
        }
        places = [PassPlace(p, spec.rows[p], spec.look_rad) for p in todo]
        params = SweepParams(host_frame_s=self.get_input("host_frame_time"))

        def collector(places: list[Any], start: Any, end: Any, params: SweepParams = params) -> Any:
            return SweepCollector(
                CameraModel.from_dict(self.session.camera),
                places,
                start,
                end,
                model.offsets(),
                model.block_height_m,
                params,
            )

        self.collector = self.main = collector(places, self.start_point, self.end_point)
        # a second look: one place, more views of each block (the drone is slow)

        world = world_of(self.ctx)

        def second(place: str, a: Any, b: Any) -> Any:
            # the place and its neighbours on the level (planned or not): their blocks are
            # theirs, not strays that would keep an empty place from being answered empty
            me = world.places[place]
            near = [
                PassPlace(q.name, tuple(q.row_m), spec.look_rad)
                for q in world.places.values()
                if q.rack == me.rack and q.level == me.level and abs(q.bay - me.bay) == 1
            ]
            return collector(
                [PassPlace(place, spec.rows[place], spec.look_rad), *near],
                a,
                b,
                replace(params, views=5, want_views=5, off_centre_strays=False, agree_m=0.0),
            )

        self.second = second
        self.relook: list[str] = []  # places waiting for a second look
        self.frame_times: list[float] = []  # of the frames looked at (the host's pace)
        self.relooked: set[str] = set()
        self.realtime = is_realtime(self)
        self.jobs = Identifications(self, self.realtime)
        self.answered = 0
        self.set_output("next_point", self.points[todo[0]])
        path = route(
            self.vehicle.position,
            self.start_point,
            footprints(world) if world is not None else [],
            geofence_inside(self.ctx),
        )
        if path is None:
            return self._fail(f"no way around the racks to the start of pass {name}")
        self.phase = "transit"
        self.progress = self.vehicle.follow_path(
            path, self.get_input("transit_speed"), FIXED_YAW, spec.look_rad
        )
        if self.progress.failed:
            return self._fail(self.progress.reason or "motion refused")
        self.ctx.log(
            f"sweep {name}: {plural(len(todo), 'place')}, {todo[0]} .. {todo[-1]}, "
            f"at {self.get_input('speed'):g} m/s"
        )
        return RUNNING

    def _fail(self, reason: str) -> NodeStatus:
        self.ctx.log(f"{self.describe()} failed: {reason}")
        self.failure_reason = reason
        jobs = getattr(self, "jobs", None)
        if jobs is not None:  # its worker thread ends (what it had not finished is lost)
            jobs.drain()
        v = getattr(self, "vehicle", None)
        if v is not None and v.is_flying:
            v.hover()
        return FAILURE

    # -- running -----------------------------------------------------------------------------
    def on_running(self) -> NodeStatus:
        p = self.progress
        if p is not None and (p.failed or p.cancelled):
            return self._fail(p.reason or "motion cancelled")
        if self.now() - self.started_s >= self.get_input("timeout"):
            return self._fail(f"time-out after {self.get_input('timeout'):g} s")
        if self.phase == "transit":
            if not p.reached:
                return RUNNING
            return self._fly_line("pass", self.end_point, self.get_input("speed"))
        if self.phase in ("pass", "second"):
            try:
                self._look()
            except PerceptionError as exc:
                return self._fail(str(exc))
            if self.phase == "pass":
                for w in self.collector.finish_passed(self.vehicle.position):
                    self._answer(w)
                self._next_point()
                if p.reached:
                    for w in self.collector.finish_all(
                        "the pass ended before the place was in view"
                    ):
                        self._answer(w)
                    self.phase = "finishing"
            elif p.reached:  # the second look is over: its answer, then on along the pass
                for w in self.collector.finish_all("not seen whole on the second look"):
                    if w.name == self.looking:
                        self._answer(w)
                self.collector = self.main
                if self.main.open():
                    return self._fly_line("pass", self.end_point, self.get_input("speed"))
                self.phase = "finishing"
        elif self.phase == "back" and p.reached:
            name = self.looking = self.relook.pop(0)
            a, b = pass_line(self.spec, self.get_input("standoff"), 0.3, [name])
            self.collector = self.second(name, a, b)
            return self._fly_line("second", b, self._second_look_speed())
        status = self._collect()
        if status is not None:
            return status
        if self.relook and self.phase in ("pass", "finishing"):
            return self._second_look()
        if self.phase == "finishing" and self.jobs.idle():
            self.ctx.log(
                f"sweep {self.spec.name}: {self.answered} answered, "
                f"{len(self.relooked)} looked at again, "
                f"{len(self.plan.rescan.get(self.spec.name, []))} left for the rescan, "
                f"{self.main.frames} frames looked at"
                + (f", {self.main.dropped} dropped" if self.main.dropped else "")
            )
            self.jobs.drain()  # idle: nothing is lost; its worker thread ends
            return SUCCESS
        return RUNNING

    def _fly_line(self, phase: str, goal: Any, speed: float) -> NodeStatus:
        """Fly along the face to ``goal`` at ``speed``, looking (``phase``: pass, second)."""
        self.phase = phase
        self.feed = (
            self.session.feed(self.vehicle, True)
            if self.realtime
            else FrameFeed(None, 0, self.collector)
        )
        return self._go(goal, speed, 0.1)

    def _go(self, goal: Any, speed: float, tolerance_m: float) -> NodeStatus:
        """Along the face to ``goal``, facing it."""
        self.progress = self.vehicle.go_to(
            *goal,
            FIXED_YAW,
            self.spec.look_rad,
            speed,
            position_tolerance_m=tolerance_m,
            yaw_tolerance_rad=math.radians(10.0),
        )
        if self.progress.failed:
            return self._fail(self.progress.reason or "motion refused")
        return RUNNING

    def _second_look_speed(self) -> float:
        """``second_look_speed``, or slower on a host that takes long per frame (emulated
        in lock-step, measured in real time): each block must be sighted a few times."""
        per_frame = max(self.get_input("host_frame_time"), 1.0 / 15.0)
        if self.realtime and len(self.frame_times) >= 2:
            t = sorted(self.frame_times[-30:])
            per_frame = max(per_frame, (t[-1] - t[0]) / (len(t) - 1))
        slowest = CENTRAL_TRAVEL_M / (SECOND_LOOK_SIGHTINGS * per_frame)
        return max(0.03, min(self.get_input("second_look_speed"), slowest))

    def _second_look(self) -> NodeStatus:
        """Back along the face to just before the next place to look at again."""
        name = self.relook[0]
        a, _ = pass_line(self.spec, self.get_input("standoff"), 0.3, [name])
        self.ctx.log(f"sweep {self.spec.name}: a second look at {name}")
        self.phase = "back"
        return self._go(a, self.get_input("transit_speed"), 0.05)

    def _look(self) -> None:
        from perception.synth.camera_model import CameraPose

        for obs in self.session.observations(
            self.feed, self.vehicle, self.detector, self.get_input("min_score"), self.now()
        ):
            self.frame_times.append(obs.frame.t_s)
            pose = obs.frame.pose
            cam = CameraPose.from_quaternion(pose.x_m, pose.y_m, pose.z_m, pose.quaternion)
            self.collector.add(cam, obs.bgr, obs.dets, obs.frame.index, obs.frame.t_s)

    def _next_point(self) -> None:
        for w in self.collector.watches:
            if not w.outcome:
                self.set_output("next_point", self.points[w.name])
                return
        self.set_output("next_point", self.end_point)

    # -- answers -----------------------------------------------------------------------------
    def _answer(self, w: Any) -> None:
        from perception.sweep import EMPTY as SWEEP_EMPTY
        from perception.sweep import IDENTIFY

        if w.outcome == IDENTIFY:
            self.jobs.submit(w)
        elif w.outcome == SWEEP_EMPTY:
            self._record(w, EMPTY, EMPTY, None, w.reason)
        else:
            self._to_rescan(w, w.reason)

    def _to_rescan(self, w: Any, reason: str) -> None:
        if (
            self.get_input("second_look_speed") > 0
            and w.name not in self.relooked
            and len(self.relooked) < self.get_input("second_looks")
        ):
            self.relooked.add(w.name)
            self.relook.append(w.name)
            self.ctx.log(f"inventory {w.name}: not answered by the pass ({reason})")
            return
        self.plan.rescan.setdefault(self.spec.name, []).append(w.name)
        self._record(w, "", NOT_SCANNED, None, f"sweep: {reason}; rescan")
        self._rescan_output()

    def _rescan_output(self) -> None:
        """``rescan``: the places this pass left that have no answer yet (a pass flown again
        after a battery change keeps those of its first attempt); none without
        ``rescan_places``."""
        if not self.get_input("rescan_places"):
            self.set_output("rescan", [])
            return
        done = self.log.finished()
        left = self.plan.rescan.get(self.spec.name, [])
        self.set_output("rescan", [p for p in left if p not in done])

    def _collect(self) -> NodeStatus | None:
        for w, match, error in self.jobs.done():
            if error is not None:
                if isinstance(error, PerceptionError):
                    return self._fail(str(error))
                raise error
            th = self.gallery.thresholds
            if sweep_accepts(match, th.max_distance):
                match = replace(
                    match,
                    pallet_id=match.best_id,
                    known=True,
                    decided_by="embedding+texture (sweep views)",
                    reason="",
                )
            near = match.distance <= th.max_distance * RESCAN_DISTANCE_FACTOR
            if not match.known and near and not match.verified_expected:
                self._to_rescan(w, f"unsure: {match.reason} (closest {match.best_id})")
                continue
            if not match.known and SINGLE in (getattr(w, "states", None) or ()):
                # a block sighted once was never checked for parallax: what shows through an
                # empty place is not a pallet the gallery does not know
                self._to_rescan(w, "not identified, and a block was seen only once")
                continue
            status = IDENTIFIED if match.known else UNKNOWN
            self._record(w, match.pallet_id, status, match, "" if match.known else match.reason)
        return None

    def _record(self, w: Any, answer: str, status: str, match: Any, reason: str) -> None:
        row = self.log.record(
            {
                "place": w.name,
                "answer": answer,
                "status": status,
                "best_id": match.best_id if match is not None else None,
                "distance": _round(match.distance) if match is not None else None,
                "margin": _round(match.margin) if match is not None else None,
                "blocks_seen": w.blocks_seen,
                "mission_time_s": round(self.now(), 2),
                "reason": reason or None,
                "decided_by": (match.decided_by or None)
                if match is not None and match.known
                else None,
            }
        )
        if status != NOT_SCANNED:
            self.answered += 1
            self.set_output("answered", self.answered)
        states = ",".join(getattr(w, "states", []) or [])
        self.ctx.log(f"inventory {row['place']}: {answer or '-'} ({status}; sweep; {states})")
        run_dir = self.ctx.resources.get("run_dir")
        if run_dir and status != NOT_SCANNED:
            ranking = [(r[0], r[1]) for r in (match.ranking if match is not None else [])]
            try:
                write_place_evidence(run_dir, w.name, w.ordered_crops(), ranking)
            except (OSError, ValueError) as exc:
                self.ctx.log(f"inventory {w.name}: evidence not written: {exc}")

    def on_halted(self) -> None:
        """Stopped (the battery): the places answered stay; pending identifications are
        still recorded when they finish; open places are flown again next time."""
        if self.jobs is not None:
            for w, match, error in self.jobs.drain():
                if error is None:
                    status = IDENTIFIED if match.known else UNKNOWN
                    self._record(w, match.pallet_id, status, match, "")
        v = getattr(self, "vehicle", None)
        if v is not None and v.is_flying and v.motion is getattr(self, "progress", None):
            v.hover()
