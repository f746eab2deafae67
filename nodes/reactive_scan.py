"""The reactive scan: the camera finds the pallet face and steers the scan along it.

Three leaves, meant to run in this order (``missions/pallet_scan.xml``):

* ``LocatePallet`` flies to a look point in front of where the map puts the pallet, holds,
  and turns the blocks it sees into a face estimate (:mod:`perception.face`): where the
  block row is, which way it faces, at what height. Nothing seen: it looks again from
  points further along the face, then fails with "no pallet found".
* ``AlignToPallet`` flies to the scan start the estimate gives (the stand-off distance in
  front of the face, square to it, at the block row's height, a little before the first
  block), looks again from there (closer, so more accurate) and corrects once.
* ``ScanFace`` (:mod:`nodes.scan_face`) runs beside ``DetectBlocks`` (a Parallel): it flies along the face, refits the
  face from every frame DetectBlocks processes and re-plans when the estimate moves; it goes
  past the expected end while blocks are still missing (up to ``extend``), and stops early
  once the blocks are committed.

LocatePallet and AlignToPallet look at the frames the rig's frame gate lets through (a
frame whose view barely moved since the last one looked at is skipped:
``perception.min_view_change_px``, ``max_frame_gap_s``). Every target is checked against
the safety geofence before it is flown, every leaf has a
time-out, and each FAILURE says why. The leaves use the Vehicle API only. Re-acquiring a
lost row is the mission's job: a second LocatePallet / AlignToPallet / ScanFace pass starts
from everything seen so far (the face tracker keeps the sightings of the whole run).
"""

from __future__ import annotations

import math
from typing import Any

from bt_engine.node import FAILURE, RUNNING, SUCCESS, NodeStatus, StatefulActionNode
from bt_engine.ports import ANY, DURATION, FLOAT, INT, STRING, VEC3, input_port, output_port
from bt_engine.registry import register
from nodes.common import (
    geofence_config,
    is_realtime,
    vehicle_of,
)
from nodes.perception_session import MIN_SCORE_DOC, PerceptionError, PerceptionSession

CATEGORY_SCAN = "reactive scan"
FIXED_YAW = 2
GEOFENCE_CLEARANCE_M = 0.05  # a target must be this far inside the geofence walls
#: frames taken at a look point that must reach the detector before LocatePallet may say
#: it saw no block there (lock-step always has them: 15 frames/s over its look_time)
MIN_LOOK_FRAMES = 3
STANDOFF_SLACK_M = 0.15  # stand off up to this much further to keep inside the geofence
#: A scan keeps at least this far in front of the place's *mapped* face line, however deep
#: its pallet stands: a neighbour may stand out of that line by its depth error plus the
#: swing of its corner (0.15 m + 0.6 m x sin 16.2 deg = 0.32 m at the site's limits), and
#: the drone is 0.06 m round. Scanning a deep pallet at the stand-off from its face had
#: taken the drone 0.2 m from the line, into a turned neighbour's corner.
MIN_MAP_CLEARANCE_M = 0.4

_DETECTOR = input_port("detector", STRING, "", "detector weights file (empty: the shipped model)")
_MIN_SCORE = input_port("min_score", FLOAT, None, MIN_SCORE_DOC)
FACE_PORT = input_port("face", ANY, description="LocatePallet's face estimate")
STANDOFF_PORT = input_port(
    "standoff", FLOAT, 0.4, "distance to keep from the face while scanning, m", low=0.1, high=3.0
)
_SPEED = input_port(
    "speed", FLOAT, 0.3, "speed of the positioning flights, m/s", low=0.01, high=3.0
)


def behind_the_map(face: Any, s: float, standoff: float) -> float:
    """How much further back than ``standoff`` the point of ``face`` at along-face ``s``
    must be to keep :data:`MIN_MAP_CLEARANCE_M` in front of the place's mapped face line
    (the line through ``face.prior`` square to ``face.map_facing_rad``); 0 when it does, or
    when the face has no mapped line."""
    facing = getattr(face, "map_facing_rad", None)
    if facing is None:
        return 0.0
    nx, ny = math.cos(facing), math.sin(facing)
    x, y, _ = face.point(s, standoff)
    clear = (face.prior[0] - x) * nx + (face.prior[1] - y) * ny
    if clear >= MIN_MAP_CLEARANCE_M - 1e-9:
        return 0.0
    return (MIN_MAP_CLEARANCE_M - clear) / max(math.cos(face.facing_rad - facing), 0.5)


class ReactiveLeaf(StatefulActionNode):
    """What the three leaves share: the session, go-to with a geofence check, looking."""

    category = CATEGORY_SCAN

    def _fail(self, reason: str) -> NodeStatus:
        self.ctx.log(f"{self.describe()} failed: {reason}")
        self.failure_reason = reason
        if self.vehicle is not None and self.vehicle.is_flying:
            self.vehicle.hover()
        return FAILURE

    def setup_common(self) -> None:
        self.vehicle = vehicle_of(self)
        self.session = PerceptionSession.of(self.ctx)
        self.started_s = self.now()
        self.progress: Any = None
        self.feed = self.session.feed(self.vehicle, is_realtime(self))
        self.frame_times: list[float] = []  # when each frame looked at was taken

    def start_on_face(self) -> NodeStatus | None:
        """Set up (:meth:`setup_common`) and take the ``face`` input as :attr:`face`; the
        FAILURE to return if it is not LocatePallet's face output, else None."""
        self.setup_common()
        face = self.get_input("face")
        if not hasattr(face, "refit"):
            return self._fail(f"face must be LocatePallet's face output, got {type(face).__name__}")
        self.face = face
        return None

    def outside_geofence(self, p: tuple[float, float, float]) -> str:
        """Why ``p`` may not be flown to ("" if it may)."""
        supervisor = self.ctx.resources.get("safety")
        config = getattr(supervisor, "config", None)
        if config is None or not getattr(config, "geofence_enabled", False):
            return ""
        if config.inside(p, GEOFENCE_CLEARANCE_M):
            return ""
        lo, hi = config.geofence_min_m, config.geofence_max_m
        return (
            f"({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}) is outside the geofence "
            f"{tuple(lo)}..{tuple(hi)} (or within {GEOFENCE_CLEARANCE_M:g} m of its walls)"
        )

    def fly(self, p: tuple[float, float, float], yaw_rad: float, speed: float, tol: float) -> str:
        """Start a go-to (FIXED_YAW); return why it was refused ("" when it flies)."""
        why = self.outside_geofence(p)
        if why:
            return why
        self.progress = self.vehicle.go_to(
            p[0],
            p[1],
            p[2],
            FIXED_YAW,
            yaw_rad,
            speed,
            position_tolerance_m=tol,
            yaw_tolerance_rad=math.radians(5.0),
        )
        if self.progress.failed:
            return self.progress.reason or "go-to refused"
        return ""

    def face_target(self, face: Any, s: float) -> tuple[float, float, float]:
        """The point ``standoff`` in front of ``face`` at along-face ``s``; if the geofence
        does not allow it, the nearest point further back (up to ``STANDOFF_SLACK_M`` more)
        that it allows (the caller's go-to then says why if none)."""
        standoff = self.get_input("standoff")
        standoff += self._behind_the_map(face, s, standoff)
        p = face.point(s, standoff)
        extra = 0.0
        while self.outside_geofence(p) and extra < STANDOFF_SLACK_M - 1e-9:
            extra += 0.01
            q = face.point(s, standoff + extra)
            if not self.outside_geofence(q):
                if not getattr(self, "_slack_logged", False):
                    self._slack_logged = True
                    self.ctx.log(
                        f"{self.describe()}: standing {extra:.2f} m further back than the "
                        "stand-off to stay inside the geofence"
                    )
                return q
        return p

    def _behind_the_map(self, face: Any, s: float, standoff: float) -> float:
        """How much further back than ``standoff`` the point at along-face ``s`` must be to
        keep :data:`MIN_MAP_CLEARANCE_M` in front of the place's mapped face line (0 when it
        does, or when the face has no map line: a face found without a place)."""
        extra = behind_the_map(face, s, standoff)
        if extra > 0.0 and not getattr(self, "_deep_logged", False):
            self._deep_logged = True
            self.ctx.log(
                f"{self.describe()}: standing {extra:.2f} m further back than the stand-off: "
                f"the pallet stands deep, and the drone keeps {MIN_MAP_CLEARANCE_M:g} m in front "
                "of the place's mapped face (its neighbours may stand out of it)"
            )
        return extra

    def motion_problem(self) -> str:
        """Why the current motion stopped ("" while it runs or once it reached its goal)."""
        p = self.progress
        if p is None:
            return ""
        if p.failed or p.cancelled:
            return p.reason or "motion cancelled by another motion"
        return ""

    def look(self, detector: Any, min_score: float) -> str:
        """Feed what the detector saw since the last look (lock-step: the newest frame, if
        new and the rig's frame gate lets it through; real time: the perception worker's
        observations) into the face tracker; "" or why a frame could not be used (a frame
        of the wrong size or format)."""
        try:
            for obs in self.session.observations(
                self.feed, self.vehicle, detector, min_score, self.now()
            ):
                self.session.track(obs)
                self.frame_times.append(obs.frame.t_s)
        except PerceptionError as exc:
            return str(exc)
        return ""

    def timed_out(self) -> bool:
        """True once the leaf's ``timeout`` has passed."""
        return self.now() - self.started_s >= self.get_input("timeout") - 1e-9

    def record_face(self, face: Any, stage: str) -> None:
        """Keep ``face`` for summary.json / the report and log it."""
        rec = {"t_s": round(self.now(), 3), "node": self.describe(), "stage": stage}
        rec.update(face.as_dict())
        self.session.faces.append(rec)
        self.ctx.log(f"{self.describe()}: {face.describe()}")

    def on_halted(self) -> None:
        v = getattr(self, "vehicle", None)
        if v is not None and v.is_flying and v.motion is getattr(self, "progress", None):
            v.hover()


def look_points(
    place: Any, facing_rad: float, distance_m: float, step_m: float, count: int
) -> list[tuple[float, float, float]]:
    """Where ``LocatePallet`` looks from: ``distance_m`` in front of ``place`` (facing
    ``facing_rad``), then ``step_m`` to either side in turn, ``count`` points in all."""
    x, y, z = place
    nx, ny = math.cos(facing_rad), math.sin(facing_rad)
    lx, ly = -ny, nx
    out = []
    for k in range(max(1, count)):
        u = ((k + 1) // 2) * step_m * (1 if k % 2 else -1) if k else 0.0
        out.append((x - nx * distance_m + lx * u, y - ny * distance_m + ly * u, z))
    return out


@register
class LocatePallet(ReactiveLeaf):
    """Find the pallet face near where the map puts it. Fly to ``look_distance`` in front of
    ``place`` (the mapped centre of the block row, x;y;z), facing ``facing_deg``; hold for
    ``look_time`` while the detector looks (and on until at least 3 frames taken there
    reached it: a stalled camera or a busy host never makes a place empty); fit the face
    (:mod:`perception.face`). If no block is seen, look again from points ``search_step``
    to either side (``search_points`` in all). SUCCESS with ``face``; FAILURE "no pallet
    found" (``blocks_seen`` 0: an empty place), or on a refused motion or after ``timeout``
    (``blocks_seen`` -1: it could not look)."""

    bt_id = "LocatePallet"
    ports = (
        input_port("place", VEC3, description="mapped centre of the block row, x;y;z in m"),
        input_port("facing_deg", FLOAT, 0.0, "mapped drone yaw that faces the pallet, degrees"),
        input_port(
            "look_distance",
            FLOAT,
            0.75,
            "distance from the face to look from, m",
            low=0.1,
            high=5.0,
        ),
        input_port("look_time", DURATION, 1.0, "time to hold and look at each look point, s"),
        input_port(
            "search_step",
            FLOAT,
            0.6,
            "spacing of further look points along the face, m",
            low=0.05,
            high=5.0,
        ),
        input_port("search_points", INT, 3, "look points to try (1 = only the mapped one)"),
        input_port(
            "window", FLOAT, 0.45, "the row centre may be this far along the face from place, m"
        ),
        input_port(
            "depth_window",
            FLOAT,
            0.5,
            "the face may be this much nearer or farther than place, m (farther: something "
            "behind an empty place)",
        ),
        input_port(
            "rise",
            FLOAT,
            0.4,
            "the row may stand this much above place (a pallet standing off its beam), m; "
            "below it, 0.15 m",
            low=0.0,
            high=2.0,
        ),
        _SPEED,
        input_port("pos_threshold", FLOAT, 0.05, "look point position tolerance, m"),
        _DETECTOR,
        _MIN_SCORE,
        input_port("timeout", DURATION, 60.0, "FAILURE if not done within this time, s"),
        output_port("face", ANY, "the face estimate (for AlignToPallet and ScanFace)"),
        output_port(
            "blocks_seen",
            INT,
            "distinct blocks seen: -1 until it has looked, 0 when it looked and saw none "
            "(no pallet found)",
        ),
    )

    def on_start(self) -> NodeStatus:
        self.setup_common()
        try:
            self.detector = self.session.detector(self.get_input("detector"))
        except PerceptionError as exc:
            return self._fail(str(exc))
        self.prior = self.get_input("place")
        self.tracker = self.session.tracker_for(self.prior)
        self.facing = math.radians(self.get_input("facing_deg"))
        self.set_output("blocks_seen", -1)  # not looked yet (0: looked, saw no block)
        if self.tracker.sightings:  # a second pass: everything seen so far counts
            face = self._fit()
            if face is not None:
                return self._found(face)
        self.point_index = self.looked = 0
        self.refused: list[str] = []
        self.looking_since: float | None = None
        return self._next_point() or self.on_running()

    def _fit(self) -> Any:
        face = self.tracker.fit(
            self.facing,
            self.prior,
            self.get_input("window"),
            depth_window_m=self.get_input("depth_window"),
            height_above_m=max(self.get_input("rise"), 0.15),
        )
        if face is not None:
            face.map_facing_rad = self.facing  # the place's mapped face line: prior, facing
        return face

    def _look_points(self) -> list[tuple[float, float, float]]:
        return look_points(
            self.prior,
            self.facing,
            self.get_input("look_distance"),
            self.get_input("search_step"),
            self.get_input("search_points"),
        )

    def preflight(self) -> list[tuple[str, str]]:
        """A ``place`` none of whose look points lies inside the rig's geofence (it would
        take off and fail there), refused before anything flies."""
        try:
            place = tuple(float(v) for v in self.get_input("place"))
            points = look_points(
                place,
                math.radians(self.get_input("facing_deg")),
                self.get_input("look_distance"),
                self.get_input("search_step"),
                self.get_input("search_points"),
            )
        except Exception:  # noqa: BLE001 - written in flight (an inventory's rows): checked then
            return []
        if self.port_decl("look_distance").out_of_range(self.get_input("look_distance")):
            return []  # the range check says it
        config = geofence_config(self)
        if config is None or any(config.inside(p, GEOFENCE_CLEARANCE_M) for p in points):
            return []  # one look point it can fly to is enough
        shown = ";".join(f"{v:g}" for v in place)
        return [
            (
                "place",
                f"place {shown}: no look point {self.get_input('look_distance'):g} m in front "
                f"of it lies inside the rig's geofence ({config.box_words()}, "
                f"{GEOFENCE_CLEARANCE_M:g} m clear of its walls)",
            )
        ]

    def _next_point(self) -> NodeStatus | None:
        points = self._look_points()
        while self.point_index < len(points):
            p = points[self.point_index]
            self.point_index += 1
            why = self.fly(p, self.facing, self.get_input("speed"), self.get_input("pos_threshold"))
            if not why:
                self.looking_since = None
                self.looked += 1
                return None
            self.refused.append(why)
            self.ctx.log(f"{self.describe()}: skipping look point: {why}")
        x, y, z = self.prior
        if not self.looked:
            return self._fail(
                f"no look point near ({x:.2f}, {y:.2f}, {z:.2f}) could be flown to: "
                + "; ".join(self.refused)
            )
        refused = f" ({len(self.refused)} more refused)" if self.refused else ""
        self.set_output("blocks_seen", 0)
        return self._fail(
            f"no pallet found near ({x:.2f}, {y:.2f}, {z:.2f}): no support block seen from "
            f"{self.looked} look point(s){refused}"
        )

    def _found(self, face: Any) -> NodeStatus:
        self.record_face(face, "located")
        self.set_output("face", face)
        self.set_output("blocks_seen", face.blocks_seen)
        return SUCCESS

    def on_running(self) -> NodeStatus:
        why = self.motion_problem()
        if why:
            return self._fail(why)
        if self.looking_since is None:
            if self.progress is not None and self.progress.reached:
                self.looking_since = self.now()
                self.vehicle.hover()
                self.progress = None
        else:
            why = self.look(self.detector, self.get_input("min_score"))
            if why:
                return self._fail(why)
            looked = sum(t >= self.looking_since - 1e-9 for t in self.frame_times)
            done = self.now() - self.looking_since >= self.get_input("look_time") - 1e-9
            if done and looked < MIN_LOOK_FRAMES:
                # a host behind: too few frames taken here reached the detector to say the
                # place is empty; look on (within the time-out), never answer "no block"
                if self.timed_out():
                    return self._fail(
                        f"{looked} frame(s) taken at the look point reached the detector in "
                        f"{self.get_input('timeout'):g} s (at least {MIN_LOOK_FRAMES} are "
                        "needed to say there is no pallet): the camera or the host is behind"
                    )
            elif done:
                face = self._fit()
                if face is not None:
                    return self._found(face)
                status = self._next_point()
                if status is not None:
                    return status
        if self.timed_out():
            return self._fail(f"time-out after {self.get_input('timeout'):g} s")
        return RUNNING


@register
class AlignToPallet(ReactiveLeaf):
    """Fly to the start of the scan the face estimate gives: ``standoff`` in front of the
    face, square to it, at the block row's height, ``lead`` before the first block; look from
    there for ``look_time``, refit and correct once if the start moved by more than
    ``tolerance``. SUCCESS with the refined ``face``; FAILURE on a refused motion (e.g.
    outside the geofence) or after ``timeout``."""

    bt_id = "AlignToPallet"
    ports = (
        FACE_PORT,
        STANDOFF_PORT,
        input_port("lead", FLOAT, 0.15, "start this far before the first block, m"),
        _SPEED,
        input_port("look_time", DURATION, 0.6, "time to look from the start, s"),
        input_port("tolerance", FLOAT, 0.02, "correct the start if it moved more than this, m"),
        _DETECTOR,
        _MIN_SCORE,
        input_port("timeout", DURATION, 40.0, "FAILURE if not done within this time, s"),
        output_port("face_out", ANY, "the refined face estimate"),
    )

    def on_start(self) -> NodeStatus:
        refused = self.start_on_face()
        if refused is not None:
            return refused
        try:
            self.detector = self.session.detector(self.get_input("detector"))
        except PerceptionError as exc:
            return self._fail(str(exc))
        self.tracker = self.session.tracker or self.session.start_tracking()
        self.corrected = False
        self.looking_since: float | None = None
        return self._go() or self.on_running()

    def _start_point(self) -> tuple[float, float, float]:
        return self.face_target(self.face, self.face.first_s - self.get_input("lead"))

    def _go(self) -> NodeStatus | None:
        self.goal = self._start_point()
        why = self.fly(self.goal, self.face.facing_rad, self.get_input("speed"), 0.03)
        return self._fail(why) if why else None

    def on_running(self) -> NodeStatus:
        why = self.motion_problem()
        if why:
            return self._fail(why)
        if self.looking_since is None:
            # Look on the way too: seen from places apart, the blocks triangulate.
            why = self.look(self.detector, self.get_input("min_score"))
            if why:
                return self._fail(why)
            if self.progress is not None and self.progress.reached:
                self.looking_since = self.now()
        else:
            why = self.look(self.detector, self.get_input("min_score"))
            if why:
                return self._fail(why)
            if self.now() - self.looking_since >= self.get_input("look_time") - 1e-9:
                face = self.face.refit(self.tracker)
                if face is not None:
                    self.face = face
                moved = math.dist(self._start_point(), self.goal)
                if moved > self.get_input("tolerance") and not self.corrected:
                    self.corrected = True
                    self.looking_since = None
                    status = self._go()
                    if status is not None:
                        return status
                else:
                    self.record_face(self.face, "aligned")
                    self.set_output("face_out", self.face)
                    return SUCCESS
        if self.timed_out():
            return self._fail(f"time-out after {self.get_input('timeout'):g} s")
        return RUNNING
