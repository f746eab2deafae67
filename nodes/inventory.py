"""Inventory leaves: InventoryPlan, LookUpPlace, RecordPlace.

An inventory mission (``missions/inventory.xml``) answers, for a list of named pallet places
(``A-03-2``: rack A, bay 3, level 2), which pallet stands there::

    InventoryPlan places=all queue={todo}            the places left to do (resume-aware)
    LoopString queue={todo} value={place_name}       one place per pass (BehaviorTree.CPP)
      LookUpPlace place={place_name}                 where it is (row point, facing)
      ... LocatePallet / AlignToPallet / scan / IdentifyPallet ...
      RecordPlace place={place_name} ...             one row, written to disk at once

The place map is the rig's world file (``racks:`` in ``worlds/aisle.yaml``), in simulation
and on a real drone alike. Rows go to ``inventory.csv`` / ``inventory.json`` in the run folder
(:mod:`nodes.inventory_log`).
"""

from __future__ import annotations

import csv
import fnmatch
import math
import os
import re
from typing import Any

from bt_engine.files import read_bytes
from bt_engine.node import FAILURE, SUCCESS, BTNode, NodeStatus, SyncActionNode
from bt_engine.ports import ANY, FLOAT, INT, STRING, input_port, output_port
from bt_engine.registry import register
from bt_engine.spec import Loc, Problem, plural
from drivers.settings import ConfigError
from nodes.common import geofence_config
from nodes.expected_stock import ExpectedStock, PlaceHints, read_expected
from nodes.inventory_log import (
    EMPTY,
    IDENTIFIED,
    NOT_IDENTIFIED,
    NOT_SCANNED,
    UNKNOWN,
    InventoryError,
    InventoryLog,
)
from nodes.place_evidence import write_place_evidence
from nodes.rack_geometry import footprints
from nodes.stock_files import NotText, byte_loc, csv_rows, export_text, not_text, xlsx_table
from perception.expected import pallet_key, pallet_of

CATEGORY_INVENTORY = "inventory"
MAX_PLACES = 10_000


def world_of(ctx: Any) -> Any:
    """The rig's world (the place map), loaded once per run; None without a rig."""
    world = ctx.resources.get("world")
    if world is None:
        rig = ctx.resources.get("rig")
        if rig is None:
            return None
        world = rig.load_world(ctx.resources.get("seed") or 0)
        ctx.resources["world"] = world
    return world


def all_places_order(world: Any) -> list[str]:
    """Every place, bay by bay, going up one bay and down the next (the short way)."""
    out: list[str] = []
    by_bay: dict[tuple[str, int], list[Any]] = {}
    for p in world.places.values():
        by_bay.setdefault((p.rack, p.bay), []).append(p)
    for k, (_, places) in enumerate(sorted(by_bay.items())):
        levels = sorted(places, key=lambda p: p.level, reverse=bool(k % 2))
        out += [p.name for p in levels]
    return out


def not_in_gallery(stock: ExpectedStock | None, session: Any) -> list[str] | None:
    """The pallets ``stock`` expects that no open gallery of the perception ``session``
    enrols (by pallet, without case: ``103`` is enrolled when ``103A`` is, ``pal-7`` when
    ``PAL-7A`` is), sorted; None when there is no stock or no gallery to tell."""
    galleries = session.galleries() if session is not None else []
    if stock is None or not galleries:
        return None
    enrolled = {pallet_key(i) for g in galleries for i in g.identities()}
    expected = {pallet_of(p) for p in stock.places.values() if p}
    return sorted(p for p in expected if pallet_key(p) not in enrolled)  # as the WMS wrote


def not_enrolled_line(missing: list[str], stock: ExpectedStock) -> str:
    """The console line that says which expected pallets the gallery does not know."""
    expected = {pallet_of(p) for p in stock.places.values() if p}
    shown = ", ".join(missing[:8]) + (f", ... ({len(missing)} in all)" if len(missing) > 8 else "")
    return (
        f"expected stock: {len(missing)} of {plural(len(expected), 'expected pallet')} "
        f"not in the gallery ({shown}): their places cannot be verified 1:1 and come out as "
        "mismatch or unverified (is the WMS naming them as the gallery does?)"
    )


def _match(token: str, names: list[str], known: set[str]) -> list[str]:
    if any(c in token for c in "*?["):
        return [n for n in names if fnmatch.fnmatchcase(n, token)]
    return [token] if token in known else []


def resolve_places(
    spec: str, world: Any, where: Loc, base_dir: str = "."
) -> tuple[list[str], list[Problem]]:
    """The place names ``spec`` asks for, in order, without repeats, and what is wrong.

    ``spec`` is ``all`` (every place of the world, bay by bay), names or glob patterns
    separated by ``;`` or ``,`` (``A-01-1;A-02-*``), or a ``.csv`` file (or ``.xlsx``: its
    first sheet) whose ``place`` column (or first column) lists them; problems are located
    at ``where`` or in the file.
    """
    names = list(world.places) if world is not None else []
    if not names:
        return [], [
            Problem(
                where,
                "the rig's world has no pallet places (racks:); fly inventories in a "
                "world with racks, e.g. --rig rigs/aisle.yaml",
            )
        ]
    text = str(spec or "").strip()
    if text.lower() in ("", "all"):
        return all_places_order(world), []
    tokens: list[tuple[str, Loc]] = []
    problems: list[Problem] = []
    if text.lower().endswith((".csv", ".xlsx")):
        path = text if os.path.isabs(text) or os.path.exists(text) else os.path.join(base_dir, text)
        tokens, problems = _csv_tokens(path, where)
    else:
        tokens = [(t.strip(), where) for t in re.split(r"[;,]", text) if t.strip()]
    out: list[str] = []
    hints, known, seen = PlaceHints(names), set(names), set()
    for token, loc in tokens[:MAX_PLACES]:
        found = _match(token, names, known)
        if not found:
            problems.append(Problem(loc, f"unknown place '{token}'{hints.hint(token)}"))
        for n in found:
            if n not in seen:
                seen.add(n)
                out.append(n)
    if len(tokens) > MAX_PLACES:
        problems.append(Problem(where, f"more than {MAX_PLACES} places listed"))
    return out, problems


def _csv_tokens(path: str, where: Loc) -> tuple[list[tuple[str, Loc]], list[Problem]]:
    """Place names of a CSV file (or an XLSX workbook's first sheet) with their line and
    column (``place`` column or the first)."""
    read: list[Problem] = []  # a regular, bounded file (a FIFO would block)
    if path.lower().endswith(".xlsx"):
        data = read_bytes(path, read, where, what="place lists")
        if data is None:
            return [], [Problem(where, f"place list: {read[0].message}")]
        _, header, body, problems = xlsx_table(path, data, MAX_PLACES, ("place",))
        names = [h.lower() for h in header]
        if "place" in names:
            col, rows = names.index("place"), body
        else:  # no header: the first row is a place too
            col, rows = 0, [(1, header), *body]
        return [
            (r[col], Loc(path, i, col + 1)) for i, r in rows if col < len(r) and r[col]
        ], problems
    data = read_bytes(path, read, where, what="place lists")
    if data is None:
        return [], [Problem(where, f"place list: {read[0].message}")]
    try:
        text = not_text(data) or export_text(data)  # UTF-8, UTF-16 with its mark or cp1252
        rows, _ = csv_rows(text)  # a comma, a semicolon or a tab between the columns
    except (UnicodeDecodeError, NotText) as exc:
        why = exc if isinstance(exc, NotText) else "not UTF-8, UTF-16 or Windows-1252 text"
        return [], [
            Problem(
                byte_loc(path, data, getattr(exc, "start", 0)),
                f"{why}: expected a CSV file with a 'place' column or an XLSX workbook",
            )
        ]
    except csv.Error as exc:
        return [], [Problem(where, f"cannot read the place list {path}: {exc}")]
    if not rows:
        return [], [Problem(Loc(path, 1, 1), "the place list is empty")]
    header = [c.strip().lower() for c in rows[0].cells]
    col, start = (header.index("place"), 1) if "place" in header else (0, 0)
    return [
        (row.cells[col].strip(), Loc(path, row.line, row.col(col)))
        for row in rows[start:]
        if col < len(row.cells) and row.cells[col].strip()
    ], []


@register
class InventoryPlan(SyncActionNode):
    """Turn ``places`` into the queue of places still to answer: ``all`` (every place of the
    world, bay by bay, up one bay and down the next), names or patterns (``A-01-1;A-0?-2``),
    or a CSV or XLSX file with a ``place`` column. With ``--resume`` the places the interrupted run
    answered are left out. Unknown places are refused before anything flies (located).
    ``expected``: the WMS's expected stock (a ``place,pallet`` CSV, the same as JSON or XLSX),
    checked before flight and kept on the inventory, which then also writes the
    discrepancy report. SUCCESS with ``queue`` (for LoopString); FAILURE if the list or the
    expected stock cannot be used."""

    bt_id = "InventoryPlan"
    category = CATEGORY_INVENTORY
    ports = (
        input_port(
            "places", STRING, "all", "all, names/patterns (A-01-1;A-02-*), a .csv or .xlsx file"
        ),
        input_port(
            "expected",
            STRING,
            "",
            "expected stock: a place,pallet CSV (or JSON, or XLSX) as a WMS exports; empty: none",
        ),
        output_port("queue", ANY, "the places left to answer, in order (LoopString's queue)"),
        output_port("total", INT, "places planned (including those already answered)"),
        output_port("remaining", INT, "places left to answer"),
    )

    def _resolve(self) -> tuple[list[str], list[Problem]]:
        base = os.path.dirname(self.loc.file) if self.loc is not None else "."
        where = self.loc or Loc("<mission>")
        return resolve_places(self.get_input("places"), world_of(self.ctx), where, base)

    def _expected(self) -> tuple[ExpectedStock | None, list[Problem]]:
        base = os.path.dirname(self.loc.file) if self.loc is not None else "."
        where = self.loc or Loc("<mission>")
        return read_expected(self.get_input("expected"), world_of(self.ctx), where, base)

    def preflight(self) -> list[Any]:
        """Unknown places, a missing world or an unreadable list, expected stock or resumed
        inventory, before anything flies."""
        try:
            places, problems = self._resolve()
            if not problems:  # what the other leaves' checks look at (reach_problems)
                self.ctx.resources[PLANNED_PLACES] = list(places)
            stock, more = self._expected()
            problems += more
            if stock is not None and stock.outside_note and not more:
                self.ctx.log(stock.outside_note)  # before flight, as the gallery's loading
            InventoryLog.of(self.ctx)
        except ConfigError as exc:
            return [("places", f"the rig's world cannot be loaded: {exc}")]
        except InventoryError as exc:  # located in the resumed inventory file
            return [exc.problem()]
        out: list[Any] = []
        for p in problems:
            if p.loc == self.loc and p.message.startswith("expected stock"):
                out.append(("expected", p.message))
            elif p.loc == self.loc:  # the list itself (literal, --set or mission input)
                out.append(("places", p.message))
            else:
                out.append(p)  # a line of the CSV file
        return out

    def tick_impl(self) -> NodeStatus:
        try:
            places, problems = self._resolve()
            stock, more = self._expected()
            problems += more
            log = InventoryLog.of(self.ctx)
        except (ConfigError, InventoryError) as exc:
            self.failure_reason = str(exc)
            return FAILURE
        if problems:
            self.failure_reason = "; ".join(str(p) for p in problems[:3])
            return FAILURE
        todo = log.plan(places)
        log.expected = stock
        log.expected_not_enrolled = not_in_gallery(stock, self.ctx.resources.get("perception"))
        if log.expected_not_enrolled:
            self.ctx.log(not_enrolled_line(log.expected_not_enrolled, stock))
        done = len(places) - len(todo)
        self.ctx.log(
            f"inventory: {plural(len(places), 'place')} planned"
            + (f", {done} already answered (resumed)" if done else "")
            + (
                f"; expected stock {stock.path} ({plural(len(stock.places), 'place')})"
                if stock
                else ""
            )
        )
        log.write()
        self.set_output("queue", todo)
        self.set_output("total", len(places))
        self.set_output("remaining", len(todo))
        return SUCCESS


#: ``ctx.resources`` key: the places InventoryPlan's pre-flight check resolved (the
#: places the mission is to answer), for the other leaves' checks
PLANNED_PLACES = "planned_places"
#: a look point must be this far inside the geofence's walls (LocatePallet's clearance)
LOOK_POINT_CLEARANCE_M = 0.05


def look_point(place: Any, distance_m: float) -> tuple[float, float, float]:
    """The point ``distance_m`` in front of ``place``'s block row, where the drone looks
    at it from (rounded to 0.1 mm)."""
    f = math.radians(place.look_deg)
    x, y, z = place.row_m
    return (round(x - math.cos(f) * distance_m, 4), round(y - math.sin(f) * distance_m, 4), z)


def reach_problems(node: BTNode, world: Any, port: str, why: str) -> list[tuple[str, str]]:
    """``(port, message)`` when the distance in ``node``'s input ``port`` puts the points
    that far in front of the places to answer (:data:`PLANNED_PLACES`, else all the world's:
    their look points, a sweep's pass lines)
    inside a rack or outside the rig's geofence (``why``: what then fails in the air), said
    once with the first such place, before anything flies."""
    try:
        d = float(node.get_input(port))
    except Exception:  # noqa: BLE001 - written in flight: checked then
        return []
    decl = node.port_decl(port)
    if not math.isfinite(d) or (decl is not None and decl.out_of_range(d) is not None):
        return []  # the range check says it
    racks = footprints(world)
    fence = geofence_config(node)
    bad: list[str] = []
    names = node.ctx.resources.get(PLANNED_PLACES) if node.ctx is not None else None
    names = [n for n in (names or world.places) if n in world.places]
    for place in (world.places[n] for n in names):
        p = look_point(place, d)
        inside = [r.name for r in racks if r.distance((p[0], p[1])) <= 0.0]
        if inside:
            bad.append(f"{place.name} at ({p[0]:.2f}, {p[1]:.2f}): inside rack {inside[0]}")
        elif fence is not None and not fence.inside(p, LOOK_POINT_CLEARANCE_M):
            bad.append(f"{place.name} at ({p[0]:.2f}, {p[1]:.2f}): outside the geofence")
    if not bad:
        return []
    return [
        (
            port,
            f"{port} {d:g}: the points {d:g} m in front of {len(bad)} of the "
            f"{len(names)} places to answer would lie inside a rack or outside the rig's "
            f"geofence, where {why} (first: {bad[0]})",
        )
    ]


@register
class LookUpPlace(SyncActionNode):
    """Where a named place is in the world's map: ``row`` is the centre of its block row
    (x;y;z, for LocatePallet's ``place``) and ``facing_deg`` the drone yaw that faces it.
    FAILURE for a name the map does not have."""

    bt_id = "LookUpPlace"
    category = CATEGORY_INVENTORY
    ports = (
        input_port("place", STRING, description="place name, e.g. A-03-2"),
        output_port("row", ANY, "centre of the place's block row, x;y;z in m"),
        output_port("facing_deg", FLOAT, "drone yaw that faces the pallet, degrees"),
        output_port("level", INT, "rack level (1 = lowest)"),
        input_port(
            "look_distance",
            FLOAT,
            0.75,
            "distance in front of the face for look_point, m",
            low=0.1,
            high=5.0,
        ),
        output_port(
            "look_point",
            ANY,
            "the point look_distance in front of the block row, x;y;z (FlyRoute there first "
            "where racks may stand in the way)",
        ),
    )

    def preflight(self) -> list[Any]:
        """A literal ``place`` the rig's world does not have is refused before anything
        flies, with a "did you mean" (as InventoryPlan's places). A place read from the
        blackboard is only known in flight: the tick checks it."""
        try:
            world = world_of(self.ctx)
        except ConfigError as exc:
            return [("place", f"the rig's world cannot be loaded: {exc}")]
        if world is None:  # no rig: nothing to check against
            return []
        if self.input_entry("place") is not None:
            return self._look_point_problems(world)
        name = str(self.get_input("place") or "").strip()
        names = list(world.places)
        if name in world.places:
            return []
        if not names:
            return [
                (
                    "place",
                    f"unknown place '{name}': the rig's world has no pallet places (racks:); "
                    "fly inventories in a world with racks, e.g. --rig rigs/aisle.yaml",
                )
            ]
        return [("place", f"unknown place '{name}'{PlaceHints(names).hint(name)}")]

    def _look_point_problems(self, world: Any) -> list[tuple[str, str]]:
        return reach_problems(self, world, "look_distance", "no rescan can fly")

    def tick_impl(self) -> NodeStatus:
        world = world_of(self.ctx)
        name = self.get_input("place").strip()
        place = (world.places if world is not None else {}).get(name)
        if place is None:
            self.failure_reason = f"unknown place '{name}'"
            return FAILURE
        self.set_output("row", tuple(round(v, 4) for v in place.row_m))
        self.set_output("facing_deg", place.look_deg)
        self.set_output("level", place.level)
        self.set_output("look_point", look_point(place, self.get_input("look_distance")))
        return SUCCESS


@register
class RecordPlace(SyncActionNode):
    """Write the answer for ``place`` as one inventory row (at once, atomically, in the run
    folder's ``inventory.csv`` / ``inventory.json``). With ``pallet_id`` (IdentifyPallet's
    answer) the row is that identity or ``unknown``. Without it the row says what the scan
    found: ``empty`` when LocatePallet looked and saw no block (``blocks_seen`` 0),
    ``unknown`` (not identified) when a pallet was seen but not three blocks, ``not_scanned``
    when the place could not be looked at (``blocks_seen`` -1). Always SUCCESS."""

    bt_id = "RecordPlace"
    category = CATEGORY_INVENTORY
    ports = (
        input_port("place", STRING, description="place name"),
        input_port("pallet_id", STRING, "", "IdentifyPallet's answer (empty: no answer)"),
        input_port("best_id", STRING, "", "closest gallery entry"),
        input_port("distance", FLOAT, None, "match distance"),
        input_port("margin", FLOAT, None, "match margin"),
        input_port("blocks_seen", INT, -1, "LocatePallet's blocks_seen (without an answer)"),
        input_port("reason", STRING, "", "why there is no answer (for the row)"),
        input_port(
            "decided_by",
            STRING,
            "",
            "IdentifyPallet's decided_by (verified: the expected pallet, verified 1:1)",
        ),
        output_port("recorded", INT, "rows recorded so far in this run"),
    )

    def _optional(self, name: str) -> Any:
        return self.get_input(name) if self.has_input(name) else None

    def tick_impl(self) -> NodeStatus:
        pallet = (self.get_input("pallet_id") or "").strip()
        seen = self.get_input("blocks_seen")
        reason = self.get_input("reason") or ""
        if pallet:
            answer = pallet
            status = UNKNOWN if pallet == UNKNOWN else IDENTIFIED
        elif seen == 0:
            answer, status = EMPTY, EMPTY
            reason = reason or "no support block seen at the place"
        elif seen is not None and seen > 0:
            answer, status = UNKNOWN, NOT_IDENTIFIED
            reason = (
                reason or f"a pallet is there ({seen} blocks seen) but three were never committed"
            )
        else:
            answer, status = "", NOT_SCANNED
            reason = reason or "the place could not be looked at"
        log = InventoryLog.of(self.ctx)
        ident = self._last_identification()
        if pallet and (seen is None or seen < 0) and self.input_entry("blocks_seen") is None:
            seen = self._blocks_located()
            crops = len(ident.get("crops") or ()) if ident else 0
            if crops and (seen is None or seen < crops):  # a rescan saw more than its locate
                seen = crops
        if pallet == UNKNOWN and not reason and ident:  # why the identification said unknown
            reason = str(ident.get("reason") or "")
        row = log.record(
            {
                "place": self.get_input("place").strip(),
                "answer": answer,
                "status": status,
                "best_id": self.get_input("best_id") or None,
                "distance": _round(self._optional("distance")) if pallet else None,
                "margin": _round(self._optional("margin")) if pallet else None,
                "blocks_seen": seen,
                "mission_time_s": round(self.now(), 2),
                "reason": reason or None,
                "decided_by": (self.get_input("decided_by") or None) if pallet else None,
            }
        )
        self.ctx.log(f"inventory {row['place']}: {answer or '-'} ({status})")
        self._write_evidence(row["place"])
        self.set_output("recorded", len(log.rows) - len(log.carried))
        return SUCCESS

    def _write_evidence(self, place: str) -> None:
        """``places/<place>/``: the crops and top candidates of the last identification since
        the previous row (:mod:`nodes.place_evidence`; the console shows them). Evidence is
        never a reason to stop an inventory: a failure is one tick-log message."""
        session = self.ctx.resources.get("perception")
        idents = getattr(session, "identifications", None) or []
        mark = self.ctx.resources.get("inventory_idents_mark", 0)
        self.ctx.resources["inventory_idents_mark"] = len(idents)
        run_dir = self.ctx.resources.get("run_dir")
        found = [r for r in idents[mark:] if "ranking" in r]
        if not run_dir or not found:
            return
        try:
            last = found[-1]
            ranking = [(str(r[0]), float(r[1])) for r in last.get("ranking") or ()]
            write_place_evidence(run_dir, place, last.get("crops"), ranking)
        except (OSError, ValueError, TypeError, IndexError) as exc:
            self.ctx.log(f"inventory {place}: evidence not written: {exc}")

    def _last_identification(self) -> dict | None:
        """The last identification since the previous row (its answer, reason and crops),
        or None."""
        session = self.ctx.resources.get("perception")
        idents = getattr(session, "identifications", None) or []
        mark = self.ctx.resources.get("inventory_idents_mark", 0)
        found = [r for r in idents[mark:] if "ranking" in r]
        return found[-1] if found else None

    def _blocks_located(self) -> int | None:
        """How many blocks LocatePallet saw at this place, when the mission does not pass
        ``blocks_seen`` with an answer: the last face located since the previous row (the
        perception session keeps every face of the reactive leaves); None if there is none."""
        session = self.ctx.resources.get("perception")
        faces = getattr(session, "faces", None) or []
        mark = self.ctx.resources.get("inventory_faces_mark", 0)
        self.ctx.resources["inventory_faces_mark"] = len(faces)
        located = [f for f in faces[mark:] if f.get("stage") == "located"]
        seen = located[-1].get("blocks_seen") if located else None
        return seen if type(seen) is int else None


def _round(value: Any) -> Any:
    """A finite number rounded for the row, else None (JSON has no inf)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return round(v, 4) if math.isfinite(v) else None
