"""``ScanFace``, the reactive scan's third leaf (:mod:`nodes.reactive_scan` has the first
two and what the three share): it flies along the pallet face beside ``DetectBlocks``,
refits the face from the frames it processes and re-plans the line when the estimate
moves."""

from __future__ import annotations

import math

from bt_engine.node import RUNNING, SUCCESS, NodeStatus
from bt_engine.ports import ANY, DURATION, FLOAT, INT, input_port, output_port
from bt_engine.registry import register
from nodes.reactive_scan import FACE_PORT, STANDOFF_PORT, ReactiveLeaf


@register
class ScanFace(ReactiveLeaf):
    """Fly along the face at ``standoff`` and ``speed`` (run it beside DetectBlocks in a
    Parallel). Every ``replan_period`` the face is refitted from the frames DetectBlocks
    processed; the line is re-planned when it moved more than ``replan_tolerance``. At the
    expected end (``trail`` past the last block) it goes on by up to ``extend`` while fewer
    than ``blocks`` are committed (``count``) and the last block was not seen yet (once it has
    passed, going on cannot bring a missed block back: the mission scans again). SUCCESS once ``count`` reaches ``blocks``;
    FAILURE at the end of the extension, on a refused motion or after ``timeout``."""

    bt_id = "ScanFace"
    ports = (
        FACE_PORT,
        STANDOFF_PORT,
        input_port("speed", FLOAT, 0.07, "scan speed along the face, m/s", low=0.005, high=2.0),
        input_port("count", INT, 0, "blocks committed so far (DetectBlocks' count)"),
        input_port("blocks", INT, 3, "blocks to commit"),
        input_port("trail", FLOAT, 0.15, "go this far past the last block, m"),
        input_port("extend", FLOAT, 0.6, "go on by up to this much more while blocks are missing"),
        input_port("replan_period", DURATION, 0.5, "refit the face this often, s"),
        input_port("replan_tolerance", FLOAT, 0.03, "re-plan if the line moved this much, m"),
        input_port("timeout", DURATION, 90.0, "FAILURE if not done within this time, s"),
        output_port("face_out", ANY, "the face estimate at the end of the scan"),
    )

    def on_start(self) -> NodeStatus:
        refused = self.start_on_face()
        if refused is not None:
            return refused
        self.tracker = self.session.tracker or self.session.start_tracking()
        self.extended = self.recorded = False
        self.replans = 0
        self.end_s = self.face.last_s + self.get_input("trail")
        self.last_fit_s = self.now()
        self.fitted_sightings = len(self.tracker.sightings)
        return self._go() or self.on_running()

    def _go(self) -> NodeStatus | None:
        self.goal = self.face_target(self.face, self.end_s)
        why = self.fly(self.goal, self.face.facing_rad, self.get_input("speed"), 0.03)
        return self._fail(why) if why else None

    def _refit(self) -> NodeStatus | None:
        self.last_fit_s = self.now()
        if len(self.tracker.sightings) == self.fitted_sightings:
            return None
        self.fitted_sightings = len(self.tracker.sightings)
        face = self.face.refit(self.tracker)
        if face is None:
            return None
        end_s = max(self.end_s, face.last_s + self.get_input("trail"))
        old, self.face = self.goal, face
        self.set_output("face_out", face)
        new = self.face_target(face, end_s)
        if math.dist(old, new) > self.get_input("replan_tolerance"):
            self.end_s = end_s
            self.replans += 1
            self.ctx.log(f"{self.describe()}: re-planned on the refitted face: {face.describe()}")
            return self._go()
        return None

    def on_running(self) -> NodeStatus:
        if self.get_input("count") >= self.get_input("blocks"):
            self._done()
            return SUCCESS
        why = self.motion_problem()
        if why:
            return self._fail(why)
        if self.now() - self.last_fit_s >= self.get_input("replan_period") - 1e-9:
            status = self._refit()
            if status is not None:
                return status
        if self.progress is not None and self.progress.reached:
            f = self.face
            last_seen = f.hypotheses == 1 and f.saw_block_at(f.last_s)
            if not self.extended and self.get_input("extend") > 0 and not last_seen:
                self.extended = True
                self.end_s += self.get_input("extend")
                self.ctx.log(
                    f"{self.describe()}: {self.get_input('count')} of "
                    f"{self.get_input('blocks')} blocks at the end of the face: going on "
                    f"{self.get_input('extend'):g} m"
                )
                status = self._go()
                if status is not None:
                    return status
            else:
                self._done()
                where = "the last block has passed" if last_seen else "end of the scan"
                return self._fail(
                    f"{where} ({self.end_s - self.face.last_s:.2f} m past it) with "
                    f"{self.get_input('count')} of {self.get_input('blocks')} blocks committed"
                )
        if self.timed_out():
            return self._fail(f"time-out after {self.get_input('timeout'):g} s")
        return RUNNING

    def _done(self) -> None:
        if not getattr(self, "recorded", False):
            self.recorded = True
            self.set_output("face_out", self.face)
            self.record_face(self.face, "scanned")

    def on_halted(self) -> None:
        if getattr(self, "face", None) is not None:
            self._done()  # DetectBlocks finished first: the Parallel halts the scan
        super().on_halted()
