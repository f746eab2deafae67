"""The inventory and its discrepancies as a WMS import takes them: CSV and XLSX.

One line per place with the columns a warehouse management system's stock-count import
expects: ``place``, ``pallet`` (the identity; empty for an empty, unknown or not scanned
place), ``status`` (``identified``, ``reviewed`` when an operator decided it, ``unknown``,
``empty``, ``not_scanned``, or the run's own status), ``time`` (when the place was
answered, UTC ISO 8601: the start of the run that answered it, plus the row's mission time;
empty when that run's start is not known) and ``drone``. An empty ``pallet`` means an empty
place only with ``status`` ``empty``: an import must read both columns (btrun's own
expected-stock reader does, so the export read back as expected stock lists no
expectation for an unknown or not scanned place).
The discrepancies add ``expected``, ``category``, ``review`` and ``moved_from`` (where the
expected stock has the pallet found here: what a WMS needs to correct the booking). A
review decision replaces the run's answer in the export; the run's own files stay as they
were.
"""

from __future__ import annotations

import csv
import io
import time

from nodes.console.files import latest_by_place, safe_cell
from nodes.console.runs import discrepancy, needs_review, reviewed_discrepancies

COLUMNS = ("place", "pallet", "status", "time", "drone")
#: ``moved_from`` last: the columns before it stand where they stood before it was added
DISCREPANCY_COLUMNS = (*COLUMNS, "expected", "category", "review", "moved_from")
KINDS = ("inventory", "discrepancies")


def _iso(t: float | None) -> str:
    if t is None:
        return ""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))


def wms_rows(info: dict) -> list[dict]:
    """The inventory of a run (:func:`nodes.console.runs.run_info` with ``full``) as WMS
    lines, review decisions applied: every place the run planned, those it did not reach
    (an interrupted run) as ``not_scanned``, so that a WMS does not take a place missing
    from the file for one not in the count."""
    reviews = latest_by_place(info.get("review") or [])
    starts = info.get("run_starts") or {}  # a carried row counts from its own run's start
    out = []
    rows = list(info.get("rows") or [])
    answered = {r["place"] for r in rows}
    rows += [{"place": p, "status": "not_scanned"} for p in _planned(info) if p not in answered]
    for r in rows:
        answer, status = r.get("answer") or "", r.get("status") or ""
        d = reviews.get(r["place"])
        if d is not None:
            answer = d.get("answer") or "unknown"
            status = "reviewed" if answer != "unknown" else "unknown"
        elif status == "not_identified":
            status = "unknown"
        pallet = "" if answer in ("", "unknown", "empty") else answer
        t = r.get("mission_time_s")
        start = starts.get(r.get("run") or "", info["started"]) if starts else info["started"]
        when = start + t if isinstance(t, (int, float)) and start is not None else None
        out.append(
            {
                "place": r["place"],
                "pallet": pallet,
                "status": status,
                "time": _iso(when),
                "drone": r.get("drone") or "",
            }
        )
    return out


def _planned(info: dict) -> list[str]:
    return list(dict.fromkeys(p for p in info.get("planned") or [] if isinstance(p, str)))


def discrepancy_rows(info: dict) -> list[dict]:
    """The places that differ from what was expected: a discrepancy category of the run's
    expected stock, else (no expected stock) every exception of the review queue, and in
    simulation every answer graded ``wrong`` or ``missed``."""
    by_place = {r["place"]: r for r in info.get("rows") or []}
    reviews = latest_by_place(info.get("review") or [])
    grades, truth = info.get("grades") or {}, info.get("truth") or {}
    after_review = reviewed_discrepancies(list(by_place.values()), info.get("review") or [])
    out = []
    for line in wms_rows(info):
        row = by_place.get(line["place"]) or {"place": line["place"], "status": "not_scanned"}
        if line["place"] in after_review:  # the reviewed answer against the expected stock
            again = after_review[line["place"]]
            row = {**row, "discrepancy": again["category"], "moved_from": again["moved_from"]}
        category = discrepancy(row)
        if category is None and needs_review(row):
            category = "exception"
        if category is None and grades.get(line["place"]) in ("wrong", "missed"):
            category = grades[line["place"]]
        if category in (None, "", "confirmed"):
            continue
        expected = row.get("expected")
        if expected is None and line["place"] in truth:
            expected = truth[line["place"]] or "empty"
        d = reviews.get(line["place"])
        out.append(
            {
                **line,
                "expected": "" if expected is None else str(expected),
                "category": category,
                "review": f"{d['decision']} by {d.get('reviewer')}" if d else "",
                "moved_from": str(row.get("moved_from") or ""),
            }
        )
    return out


def table(info: dict, kind: str) -> tuple[tuple[str, ...], list[dict]]:
    """Columns and lines of export ``kind`` (``inventory`` or ``discrepancies``)."""
    if kind == "inventory":
        return COLUMNS, wms_rows(info)
    return DISCREPANCY_COLUMNS, discrepancy_rows(info)


def to_csv(columns: tuple[str, ...], lines: list[dict]) -> bytes:
    """CSV (UTF-8, header line)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\r\n")
    w.writerow(columns)
    for line in lines:
        w.writerow([safe_cell(line.get(c)) for c in columns])
    return buf.getvalue().encode("utf-8")


def to_xlsx(columns: tuple[str, ...], lines: list[dict], title: str) -> bytes:
    """An XLSX workbook (openpyxl) with one sheet ``title``: the header row, then a row per
    line, every cell text."""
    from openpyxl import Workbook

    wb = Workbook()
    ws = wb.active
    ws.title = title[:31]
    ws.append(list(columns))
    for r, line in enumerate(lines, start=2):
        for i, c in enumerate(columns, start=1):
            value = line.get(c)
            cell = ws.cell(row=r, column=i, value="" if value is None else str(value))
            cell.data_type = "s"  # text, never a formula: no "'" shown in front of "-42"
    for i, c in enumerate(columns):
        ws.column_dimensions[chr(ord("A") + i)].width = max(10, len(c) + 2)
    ws.freeze_panes = "A2"
    buf = io.BytesIO()
    wb.save(buf)
    return buf.getvalue()
