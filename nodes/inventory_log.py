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
from collections.abc import Callable
from typing import Any

from bt_engine.files import atomic_write_text

#: answers besides pallet identities
EMPTY, UNKNOWN = "empty", "unknown"
#: row statuses: what happened at the place
IDENTIFIED, NOT_IDENTIFIED, NOT_SCANNED = "identified", "not_identified", "not_scanned"
FINISHED = (IDENTIFIED, UNKNOWN, EMPTY, NOT_IDENTIFIED)
FIELDS = (
    "place",
    "answer",
    "status",
    "best_id",
    "distance",
    "margin",
    "blocks_seen",
    "mission_time_s",
    "drone",
    "run",
    "reason",
)
FORMAT = "btrun-inventory-1"


class InventoryError(Exception):
    """An inventory file that cannot be used (said in one line)."""


def grade(answer: str, truth: str | None, not_enrolled: set[str]) -> str:
    """How an answer compares with the ground truth: ``right``; ``wrong`` (an identity
    accepted that is not the one standing there); ``unknown`` (no identity where an
    enrolled pallet stands); ``missed`` (answered empty where a pallet stands);
    ``not_scanned`` (no answer)."""
    if not answer:
        return NOT_SCANNED
    if truth is None:
        return "right" if answer == EMPTY else ("unknown" if answer == UNKNOWN else "wrong")
    if answer == EMPTY:
        return "missed"
    if truth in not_enrolled:
        return "right" if answer == UNKNOWN else "wrong"
    if answer == UNKNOWN:
        return "unknown"
    return "right" if answer == truth else "wrong"


def read_inventory(run_dir: str) -> list[dict]:
    """The rows of ``run_dir/inventory.json`` ([] if the run wrote none); raises
    :class:`InventoryError` if the file is not a btrun inventory."""
    path = os.path.join(run_dir, "inventory.json")
    if not os.path.exists(path):
        return []
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except (OSError, ValueError) as exc:
        raise InventoryError(f"{path}: cannot be read as an inventory: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InventoryError(f"{path}: not a btrun inventory (format {FORMAT!r} expected)")
    rows = data.get("rows")
    if not isinstance(rows, list) or not all(
        isinstance(r, dict) and isinstance(r.get("place"), str) for r in rows
    ):
        raise InventoryError(f"{path}: 'rows' must be a list of rows with a place")
    return rows


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
    ) -> None:
        self.run_dir = run_dir
        self.run = os.path.basename(os.path.normpath(run_dir)) if run_dir else ""
        self.drone = drone
        self.rows: dict[str, dict] = {}
        self.carried: set[str] = set()
        self.planned: list[str] = []
        self.truth_source = truth
        self.sink = sink
        #: place -> [rack, bay, level] (the report draws the racks from it)
        self.layout: dict[str, list] = dict(layout or {})
        self._plans: dict[str, list[str]] = {}  # a fleet's merged log: each drone's plan
        self._truth: tuple[dict[str, str | None], set[str]] | None = None
        if resume_from:
            for row in read_inventory(resume_from):
                self.rows[row["place"]] = dict(row)
                self.carried.add(row["place"])

    @classmethod
    def of(cls, ctx: Any) -> InventoryLog:
        """The inventory of a mission context (created on first use from its resources:
        ``run_dir``, ``resume_from``, ``drone``, the rig and seed for the ground truth)."""
        log = ctx.resources.get("inventory")
        if log is None:
            res = ctx.resources
            rig = res.get("rig")
            drone = res.get("drone") or getattr(rig, "name", "") or ""

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
            )
            ctx.resources["inventory"] = log
        return log

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
            write_inventory(self.run_dir, rows, self.planned)
        if self.sink is not None:
            self.sink(self)

    def absorb(self, other: InventoryLog) -> None:
        """Take ``other``'s rows and plan into this one (a fleet's merged inventory is the
        sink of every drone's log) and write the merged files."""
        self._plans[other.drone] = list(other.planned)
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
        out = summarise(self.ordered_rows(), self.planned, self.truth(), len(self.carried))
        out["layout"] = dict(self.layout)  # every place of the map (the report draws racks)
        return out

    def result_lines(self) -> list[str]:
        """``inventory: 16 places, 11 identified, 2 unknown, 2 empty, 1 not scanned`` and,
        in simulation, how many are right."""
        s = self.run_summary()
        if not s["places"]:
            return []
        parts = [f"{s['places']} places"]
        for key in ("identified", "unknown", "empty", "not_identified", "not_scanned"):
            if s["status"].get(key):
                parts.append(f"{s['status'][key]} {key.replace('_', ' ')}")
        line = "inventory: " + ", ".join(parts)
        if s.get("carried_over"):
            line += f" ({s['carried_over']} carried over from the resumed run)"
        out = [line]
        if "right" in s:
            out.append(
                f"inventory against the simulator: {s['right']} of {s['places']} right, "
                f"{s['wrong']} wrong identities accepted"
            )
        if self.run_dir:
            out.append(f"inventory: {os.path.join(self.run_dir, 'inventory.csv')}")
        return out


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
    row), each written atomically."""
    doc = {"format": FORMAT, "planned": list(planned), "rows": rows}
    atomic_write_text(os.path.join(run_dir, "inventory.json"), json.dumps(doc, indent=1))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=FIELDS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in FIELDS})
    atomic_write_text(os.path.join(run_dir, "inventory.csv"), buf.getvalue())
