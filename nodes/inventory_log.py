"""The inventory of one run: a row per pallet place, written to disk as each place is done.

One :class:`InventoryLog` per mission (``ctx.resources["inventory"]``). ``RecordPlace``
adds rows; every row rewrites ``inventory.json`` and ``inventory.csv`` in the run folder
atomically (a temporary file flushed to disk, then renamed), so a process killed at any
moment leaves the inventory as it was after the last finished place, never a torn file.

``btrun MISSION --resume runs/<previous>`` hands the previous folder to the log: its rows
are carried over into the new run's files (marked with the run they came from), and
``InventoryPlan`` leaves their places out, so a finished place is never scanned twice and no
row is lost. Rows of places that could not be scanned (``not_scanned``) are not finished:
a resumed run tries them again.

In simulation the log knows the ground truth (which identity stands in each place, which
ones the demo gallery does not enrol) and grades every row; ``summary.json``'s
``inventory`` gives the counts and the accuracy.
"""

from __future__ import annotations

import csv
import io
import json
import os
import sys
from collections.abc import Callable
from typing import Any

from bt_engine.files import atomic_write_text
from bt_engine.spec import Loc, plural
from nodes import discrepancy
from nodes.console.files import carry_reviews
from nodes.expected_stock import ExpectedStock
from nodes.inventory_rows import (  # noqa: F401 - importable from here as before
    EMPTY,
    FIELDS,
    FINISHED,
    FORMAT,
    IDENTIFIED,
    MAX_INVENTORY_BYTES,
    MAX_INVENTORY_ROWS,
    MAX_ROW_TEXT,
    NOT_IDENTIFIED,
    NOT_SCANNED,
    TEXT_FIELDS,
    UNKNOWN,
    InventoryError,
    grade,
    read_inventory,
    safe_cell,
)
from nodes.place_evidence import carry_evidence


class InventoryLog:
    """Rows by place, the plan, and the files; see the module doc."""

    def __init__(
        self,
        run_dir: str | None = None,
        resume_from: str | None = None,
        drone: str = "",
        truth: Callable[[], tuple[dict[str, str | None], set[str]] | None] | None = None,
        sink: Callable[[InventoryLog], None] | None = None,
        layout: dict[str, list] | None = None,
        run: str = "",
        recorder: Any = None,
    ) -> None:
        self.run_dir = run_dir
        #: the mission clock (``now() -> s``), for the pace (places per hour); None: the
        #: last row's time stands for the mission time
        self.now: Callable[[], float] | None = None
        #: the run's end (mission time), set as its summary is written: a fleet's drones
        #: share one clock, which runs on until the last drone lands; None: :attr:`now`
        self.mission_end_s: float | None = None
        #: the ``run`` column of new rows: the run folder's name (a fleet's drones give
        #: the fleet's folder, so carried-over rows stay told apart from new ones)
        self.run = run or (os.path.basename(os.path.normpath(run_dir)) if run_dir else "")
        self.drone = drone
        self.rows: dict[str, dict] = {}
        self.carried: set[str] = set()
        self.planned: list[str] = []
        self.truth_source = truth
        self.sink = sink
        #: the site store's recorder (``store.recorder.RunRecorder``; docs/store.md): takes
        #: every write's rows, never blocks or fails the run
        self.recorder = recorder
        #: place -> [rack, bay, level] (the report draws the racks from it)
        self.layout: dict[str, list] = dict(layout or {})
        self._plans: dict[str, list[str]] = {}  # a fleet's merged log: each drone's plan
        self._truth: tuple[dict[str, str | None], set[str]] | None = None
        #: what the WMS expects (``expected=`` of InventoryPlan); None: no discrepancies
        self.expected: ExpectedStock | None = None
        #: the expected pallets the gallery does not enrol (None: not known)
        self.expected_not_enrolled: list[str] | None = None
        #: the run continued (``--resume``): its carried places' crops and review decisions
        #: are copied into this run's folder on the first write (:meth:`_carry_files`)
        self.resume_from = resume_from
        self._files_carried = False
        if resume_from:
            for row in read_inventory(resume_from):
                self.rows[row["place"]] = dict(row)
                self.carried.add(row["place"])
            foreign = sorted(self.carried - set(self.layout)) if self.layout else []
            if foreign:  # another world: its answers would be graded against this one's
                shown = ", ".join(foreign[:4]) + (
                    f", ... ({len(foreign)} in all)" if len(foreign) > 4 else ""
                )
                raise InventoryError(
                    f"{resume_from} answered places this world does not have ({shown}): "
                    "resume it on the rig and world it flew (leave --rig and world settings out)"
                )

    @classmethod
    def of(cls, ctx: Any) -> InventoryLog:
        """The inventory of a mission context (created on first use from its resources:
        ``run_dir``, ``resume_from``, ``drone``, ``inventory_run``, the rig and seed for the
        ground truth). A solo run's ``drone`` column is the rig's ``name`` (``aisle``)."""
        log = ctx.resources.get("inventory")
        if log is None:
            res = ctx.resources
            rig = res.get("rig")
            rig_data = getattr(rig, "data", None)
            rig_name = rig_data.get("name") if isinstance(rig_data, dict) else None
            drone = res.get("drone") or getattr(rig, "name", "") or rig_name or ""

            world = res.get("world")
            if world is None and rig is not None:
                world = res["world"] = rig.load_world(res.get("seed") or 0)
            places = getattr(world, "places", None) or {}
            layout = {n: [p.rack, p.bay, p.level] for n, p in places.items()}

            def truth() -> tuple[dict[str, str | None], set[str]] | None:
                if world is None or getattr(rig, "kind", None) != "sim":
                    return None
                return world.places_truth(), set(world.not_enrolled())

            log = cls(
                res.get("run_dir"),
                res.get("resume_from"),
                drone,
                truth,
                res.get("inventory_sink"),
                layout,
                res.get("inventory_run") or "",
            )
            log.recorder = _recorder(res)
            log.now = ctx.clock.now if getattr(ctx, "clock", None) is not None else None
            ctx.resources["inventory"] = log
        return log

    @property
    def result_priority(self) -> int:
        """With an expected stock the discrepancy counts lead the console's lines."""
        return 1 if self.expected is not None else 0

    def expected_at(self, place: str) -> str | None:
        """The pallet the expected stock names for ``place`` (``103``), ``""`` when the
        place should be empty, None without an expected stock or when it does not list the
        place. Leaves verify a scan against it (:func:`nodes.identify.identify_scan`)."""
        return self.expected.at(place) if self.expected is not None else None

    # -- what is done ---------------------------------------------------------------------
    def finished(self) -> set[str]:
        """Places with a final answer (carried over or recorded in this run)."""
        return {p for p, r in self.rows.items() if r.get("status") in FINISHED}

    def plan(self, places: list[str]) -> list[str]:
        """Remember the places this run is to answer; return those not finished yet."""
        self.planned = list(places)
        done = self.finished()
        return [p for p in places if p not in done]

    # -- recording ------------------------------------------------------------------------
    def record(self, row: dict) -> dict:
        """Add (or replace) the row of ``row["place"]`` and write the files at once."""
        full = {k: row.get(k) for k in FIELDS}
        full["drone"] = full["drone"] or self.drone
        full["run"] = full["run"] or self.run
        self.rows[full["place"]] = full
        self.carried.discard(full["place"])
        self.write()
        return full

    def ordered_rows(self) -> list[dict]:
        """Rows in plan order (then any other place in the order recorded)."""
        order = {p: i for i, p in enumerate(self.planned)}
        return sorted(self.rows.values(), key=lambda r: order.get(r["place"], len(order)))

    def write(self) -> None:
        """Rewrite ``inventory.json`` and ``inventory.csv`` atomically (if there is a run
        folder), then hand the log to the sink (a fleet merging its drones' rows)."""
        rows = self.ordered_rows()
        if self.run_dir:
            os.makedirs(self.run_dir, exist_ok=True)
            self._carry_files()
            write_inventory(self.run_dir, rows, self.planned)
            if self.expected is not None:
                found = discrepancy.discrepancy_rows(
                    _with_planned(rows, self.planned), self.expected
                )
                discrepancy.write_discrepancies(self.run_dir, found, self.expected)
        if self.sink is not None:
            self.sink(self)
        if self.recorder is not None:
            self.recorder.record(rows)

    def _carry_files(self) -> None:
        """Once, in a resumed run's folder: the carried places' evidence (crops and
        candidates) and review decisions from the run it continues, so the console shows
        and exports them here as there. A copy that fails is said, never fatal."""
        if self._files_carried or not self.resume_from or not self.run_dir:
            return
        self._files_carried = True
        carried = {  # answered there (a place not scanned there is flown again here)
            p: str(self.rows[p].get("drone") or "")
            for p in self.carried
            if self.rows[p].get("status") in FINISHED
        }
        try:
            carry_evidence(self.resume_from, self.run_dir, carried)
            carry_reviews(self.resume_from, self.run_dir, set(carried))
        except OSError as exc:
            print(
                f"btrun: the resumed run's crops and reviews were not all carried over: {exc}",
                file=sys.stderr,
            )

    def absorb(self, other: InventoryLog) -> None:
        """Take ``other``'s rows and plan into this one (a fleet's merged inventory is the
        sink of every drone's log) and write the merged files."""
        self._plans[other.drone] = list(other.planned)
        if self.expected is None:
            self.expected = other.expected
        if self.expected_not_enrolled is None:
            self.expected_not_enrolled = other.expected_not_enrolled
        for place, row in other.rows.items():
            if place not in other.carried:
                self.rows[place] = dict(row)
                self.carried.discard(place)
        carried = [p for p in self.planned if p in self.carried]
        merged = carried + [p for plan in self._plans.values() for p in plan]
        self.planned = list(dict.fromkeys(merged))
        self.write()

    # -- reporting ------------------------------------------------------------------------
    def truth(self) -> tuple[dict[str, str | None], set[str]] | None:
        """(place -> identity or None, not-enrolled identities) in simulation, else None."""
        if self._truth is None and self.truth_source is not None:
            self._truth = self.truth_source()
        return self._truth

    def run_summary(self) -> dict[str, Any]:
        """``summary.json``'s ``inventory``: counts by answer and status, places not
        scanned, and in simulation the grade of every place and the accuracy."""
        rows = self.ordered_rows()
        out = summarise(rows, self.planned, self.truth(), len(self.carried))
        out["layout"] = dict(self.layout)  # every place of the map (the report draws racks)
        answered = sum(
            1 for r in rows if r.get("status") in FINISHED and r["place"] not in self.carried
        )
        if self.mission_end_s is not None:
            mission_s = self.mission_end_s
        else:
            mission_s = self.now() if self.now is not None else out["mission_time_s"]
        out.update(pace(answered, mission_s))
        if self.expected is not None:
            found = discrepancy.discrepancy_rows(_with_planned(rows, self.planned), self.expected)
            out["expected"] = self.expected.path
            out["expected_source"] = self.expected.source()
            if self.expected_not_enrolled is not None:
                out["expected_not_enrolled"] = {
                    "count": len(self.expected_not_enrolled),
                    "pallets": self.expected_not_enrolled[:100],
                }
            out["discrepancies"] = discrepancy.counts(found)
            out["discrepancy_rows"] = found
            truth = self.truth()
            if truth is not None:
                out["discrepancy_grades"] = discrepancy.grade_rows(found, self.expected, truth)
        return out

    def result_lines(self) -> list[str]:
        """``inventory: 16 places, 11 identified, 2 unknown, 2 empty, 1 not scanned`` and,
        in simulation, how many are right."""
        s = self.run_summary()
        if not s["places"]:
            return []
        parts = [plural(s["places"], "place")]
        for key in ("identified", "unknown", "empty", "not_identified", "not_scanned"):
            if s["status"].get(key):
                parts.append(f"{s['status'][key]} {key.replace('_', ' ')}")
        line = "inventory: " + ", ".join(parts)
        if s.get("carried_over"):
            line += f" ({s['carried_over']} carried over from the resumed run)"
        out = discrepancy_lines(s, self.run_dir) + [line]
        if s.get("places_per_hour") is not None:
            out.append(pace_line(s))
        if "right" in s:
            out.append(
                f"inventory against the simulator: {s['right']} of {s['places']} right, "
                f"{s['wrong']} wrong identities accepted"
            )
        if self.run_dir:
            out.append(f"inventory: {os.path.join(self.run_dir, 'inventory.csv')}")
            left = s["not_scanned_places"]
            if left and self.sink is None:  # a fleet's drone: the fleet prints its own
                mission = _mission_of(self.run_dir) or "MISSION"
                out.append(
                    f"{plural(len(left), 'place')} not answered: continue with "
                    f"btrun {mission} --resume {self.run_dir}"
                )
        return out


#: the commercial anchor's pace: 8,000 pallet places in about six hours with one drone
ANCHOR_PLACES_PER_HOUR = 1300


def pace(answered: int, mission_time_s: float, drones: int = 1) -> dict[str, Any]:
    """``places_answered`` (in this run, carried-over rows not counted), ``places_per_hour``
    (per hour of mission time, battery changes included) and, for a fleet,
    ``places_per_hour_per_drone``; the anchor's figure beside them."""
    per_hour = round(answered * 3600.0 / mission_time_s, 1) if mission_time_s > 0 else None
    out: dict[str, Any] = {
        "places_answered": answered,
        "places_per_hour": per_hour,
        "anchor_places_per_hour": ANCHOR_PLACES_PER_HOUR,
    }
    if drones > 1:
        out["places_per_hour_per_drone"] = (
            round(per_hour / drones, 1) if per_hour is not None else None
        )
    return out


def pace_line(s: dict) -> str:
    """``inventory pace: 1,412 places per hour (per drone: 1,380; anchor 1,300)``."""
    line = f"inventory pace: {s['places_per_hour']:,.0f} places per hour of mission time"
    if s.get("places_per_hour_per_drone") is not None:
        line += f", {s['places_per_hour_per_drone']:,.0f} per drone"
    return line + f" (anchor {s.get('anchor_places_per_hour', ANCHOR_PLACES_PER_HOUR):,})"


def _with_planned(rows: list[dict], planned: list[str]) -> list[dict]:
    """The rows, and an empty (not scanned) row for each planned place without one."""
    have = {r["place"] for r in rows}
    return list(rows) + [
        {"place": p, "answer": "", "status": NOT_SCANNED} for p in planned if p not in have
    ]


def discrepancy_lines(s: dict, run_dir: str | None) -> list[str]:
    """The console's discrepancy lines of a summary's ``inventory`` (none without an
    expected stock): the counts per category first, in simulation how many rows are
    right, and where the report is."""
    if "discrepancies" not in s:
        return []
    out = [discrepancy.counts_line(s["discrepancies"])]
    missing = s.get("expected_not_enrolled") or {}
    if missing.get("count"):
        shown = ", ".join(missing["pallets"][:8]) + (", ..." if missing["count"] > 8 else "")
        out.append(
            f"discrepancies: {missing['count']} expected pallets not in the gallery ({shown}): "
            "their places could not be verified 1:1"
        )
    g = s.get("discrepancy_grades")
    if g:
        n = g["right"] + g["wrong"]
        out.append(
            f"discrepancies against the simulator: {g['right']} of {n} right, "
            f"{len(g['false_alarms'])} false alarms, {len(g['missed'])} missed"
        )
    if run_dir:
        out.append(f"discrepancies: {os.path.join(run_dir, 'discrepancies.csv')}")
    return out


def _recorder(resources: dict) -> Any:
    """The site store's recorder of a run (nodes.site.recording.recorder_for); a store that
    cannot be used is refused before flight, located at ``--store``."""
    from nodes.site.recording import recorder_for
    from store import StoreError

    try:
        return recorder_for(resources)
    except StoreError as exc:
        raise InventoryError(str(exc), Loc("--store", 0, 0)) from None


def _mission_of(run_dir: str) -> str | None:
    """The mission file a run flew, from its tick log's first line (the header), relative
    to the working directory when under it; None if unreadable."""
    try:
        with open(os.path.join(run_dir, "ticks.jsonl"), encoding="utf-8") as f:
            mission = json.loads(f.readline(1_000_000)).get("header", {}).get("mission")
    except (OSError, ValueError, AttributeError, RecursionError):
        return None
    if not isinstance(mission, str) or not mission:
        return None
    rel = os.path.relpath(mission)
    return mission if rel.startswith("..") else rel


def summarise(
    rows: list[dict],
    planned: list[str],
    truth: tuple[dict[str, str | None], set[str]] | None,
    carried: int = 0,
) -> dict[str, Any]:
    """Counts (and grades, with ``truth``) of inventory rows over the ``planned`` places."""
    by_place = {r["place"]: r for r in rows}
    places = list(dict.fromkeys(list(planned) + list(by_place)))
    status: dict[str, int] = {}
    answers: dict[str, int] = {}
    for p in places:
        r = by_place.get(p)
        st = r.get("status") if r else NOT_SCANNED
        status[st] = status.get(st, 0) + 1
        if r and r.get("answer"):
            answers[r["answer"]] = answers.get(r["answer"], 0) + 1
    out: dict[str, Any] = {
        "places": len(places),
        "rows": {p: by_place.get(p) for p in places},
        "status": status,
        "not_scanned_places": [
            p for p in places if (by_place.get(p) or {}).get("status", NOT_SCANNED) == NOT_SCANNED
        ],
        "carried_over": carried,
        "mission_time_s": max((r.get("mission_time_s") or 0.0 for r in rows), default=0.0),
    }
    if truth is not None:
        stock, not_enrolled = truth
        grades: dict[str, str] = {}
        for p in places:
            answer = (by_place.get(p) or {}).get("answer") or ""
            grades[p] = grade(answer, stock.get(p), not_enrolled)
        counts = {
            g: list(grades.values()).count(g)
            for g in ("right", "wrong", "unknown", "missed", NOT_SCANNED)
        }
        out.update(counts)
        out["accuracy"] = round(counts["right"] / len(places), 4) if places else None
        out["grades"] = grades
        out["truth"] = {p: stock.get(p) for p in places}
    return out


def write_inventory(run_dir: str, rows: list[dict], planned: list[str]) -> None:
    """``inventory.json`` (format, planned places, rows) and ``inventory.csv`` (one line per
    planned place: a place not answered (yet) is a ``not_scanned`` line, so that a run that
    ended early still lists every place for the WMS), each written atomically."""
    doc = {"format": FORMAT, "planned": list(planned), "rows": rows}
    atomic_write_text(os.path.join(run_dir, "inventory.json"), json.dumps(doc, indent=1))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=FIELDS, lineterminator="\n")
    w.writeheader()
    for r in _with_planned(rows, planned):
        w.writerow(
            {
                k: safe_cell(r.get(k))
                if k in TEXT_FIELDS
                else ("" if r.get(k) is None else r.get(k))
                for k in FIELDS
            }
        )
    atomic_write_text(os.path.join(run_dir, "inventory.csv"), buf.getvalue())
