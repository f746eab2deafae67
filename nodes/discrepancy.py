"""The discrepancy report: which places disagree with the expected stock (the WMS).

A warehouse's inventory team acts on a list of discrepancies, not on a list of pallets.
With an expected stock (:mod:`nodes.expected_stock`) every inventory row becomes one
discrepancy row, ``place, expected, found, category``:

=============  ==============================================================================
``confirmed``  found = expected (the same pallet, either side), or expected empty and empty
``mismatch``   a different enrolled pallet was found; ``moved_from`` names the place where
               the found pallet was expected, if any
``missing``    a pallet was expected and the place is empty
``unexpected`` the place was expected empty and holds a pallet (identified or not)
``unverified`` a pallet stands there but is neither verified as the expected one nor
               identified (``unknown``, or fewer than three blocks seen)
``not_scanned`` the place could not be looked at (no answer yet; a resumed run tries again)
``unlisted``   the place was flown but the expected stock does not list it
=============  ==============================================================================

``discrepancies.csv`` / ``discrepancies.json`` are rewritten atomically with the
inventory files (:mod:`nodes.inventory_log`). In simulation :func:`true_category` says
what each place's category should be, from the world's stock, so every row is graded.
"""

from __future__ import annotations

import csv
import io
import json
import os
from typing import Any

from bt_engine.files import atomic_write_text
from nodes.expected_stock import ExpectedStock
from nodes.inventory_rows import safe_cell
from perception.expected import pallet_key, pallet_of

CONFIRMED, MISMATCH, MISSING = "confirmed", "mismatch", "missing"
UNEXPECTED, UNVERIFIED = "unexpected", "unverified"
NOT_SCANNED, UNLISTED = "not_scanned", "unlisted"
#: the categories, in the order the console and the report give them
CATEGORIES = (CONFIRMED, MISMATCH, MISSING, UNEXPECTED, UNVERIFIED, NOT_SCANNED, UNLISTED)
FIELDS = ("place", "expected", "found", "category", "moved_from", "answer", "verified", "reason")
FORMAT = "btrun-discrepancies-1"
_EMPTY, _UNKNOWN = "empty", "unknown"


def categorise(expected: str | None, answer: str, status: str = "") -> tuple[str, str]:
    """(category, found) of one place: ``expected`` is the pallet expected (``""``:
    expected empty, None: not listed); ``answer`` the inventory row's answer (a side such
    as ``103B``, ``unknown``, ``empty``, or ``""`` when not scanned). ``found`` is the
    pallet found (``103``, as the gallery writes it), ``empty``, ``unknown``, or ``""``.
    Pallets are compared without case (:func:`perception.expected.pallet_key`)."""
    if not answer:
        return NOT_SCANNED, ""
    found = answer if answer in (_EMPTY, _UNKNOWN) else pallet_of(answer)
    if expected is None:
        return UNLISTED, found
    if expected == "":
        return (CONFIRMED if found == _EMPTY else UNEXPECTED), found
    if found == _EMPTY:
        return MISSING, found
    if found == _UNKNOWN:
        return UNVERIFIED, found
    return (CONFIRMED if pallet_key(found) == pallet_key(expected) else MISMATCH), found


def discrepancy_rows(rows: list[dict], stock: ExpectedStock) -> list[dict]:
    """One discrepancy row per inventory row (in its order)."""
    out = []
    for r in rows:
        place = r["place"]
        expected = stock.at(place)
        category, found = categorise(expected, r.get("answer") or "", r.get("status") or "")
        moved = ""
        if category in (MISMATCH, UNEXPECTED) and found not in (_UNKNOWN, _EMPTY):
            moved = stock.place_of(found) or ""  # where the stock expects what stands here
        out.append(
            {
                "place": place,
                "expected": expected or "",
                "found": found,
                "category": category,
                "moved_from": moved,
                "answer": r.get("answer") or "",
                "verified": r.get("decided_by") == "verified",
                "reason": r.get("reason") or "",
            }
        )
    return out


def counts(rows: list[dict]) -> dict[str, int]:
    """Rows per category (every category of :data:`CATEGORIES` up to ``unverified``, the
    others only when present)."""
    out = {c: 0 for c in CATEGORIES[:5]}
    for r in rows:
        out[r["category"]] = out.get(r["category"], 0) + 1
    return out


def counts_line(c: dict[str, int]) -> str:
    """``discrepancies: 12 confirmed, 1 mismatch, 1 missing, 1 unexpected, 1 unverified``."""
    parts = [f"{c.get(k, 0)} {k.replace('_', ' ')}" for k in CATEGORIES if k in c]
    return "discrepancies: " + ", ".join(parts)


def true_category(
    expected: str | None, truth: str | None, not_enrolled: set[str], stock: ExpectedStock
) -> tuple[str, str]:
    """(category, moved_from) the place should get, from the simulator's ground truth
    (``truth``: the side standing there, None: empty). A pallet the gallery does not
    enrol cannot be verified nor identified: ``unverified`` where a pallet is expected."""
    if expected is None:
        return UNLISTED, ""
    if truth is None:
        return (CONFIRMED if expected == "" else MISSING), ""
    if expected == "":
        return UNEXPECTED, stock.place_of(truth) or ""
    if truth in not_enrolled:
        return UNVERIFIED, ""
    if pallet_key(truth) == pallet_key(expected):
        return CONFIRMED, ""
    return MISMATCH, stock.place_of(truth) or ""


def grade_rows(
    rows: list[dict],
    stock: ExpectedStock,
    truth: tuple[dict[str, str | None], set[str]],
) -> dict[str, Any]:
    """Each discrepancy row against the ground truth: ``right`` when its category (and,
    for a mismatch, the pallet found) is the true one; false alarms (a place that agrees
    reported otherwise, not-scanned places aside) and injected discrepancies missed."""
    places, not_enrolled = truth
    grades, should = {}, {}
    for r in rows:
        if r["category"] == NOT_SCANNED:
            grades[r["place"]] = NOT_SCANNED
            continue
        cat, moved = true_category(
            stock.at(r["place"]), places.get(r["place"]), not_enrolled, stock
        )
        should[r["place"]] = cat
        ok = r["category"] == cat
        if ok and cat == MISMATCH:
            truth_found = pallet_key(places.get(r["place"]) or "")
            ok = pallet_key(r["found"]) == truth_found and r["moved_from"] == moved
        grades[r["place"]] = "right" if ok else "wrong"
    alarms = [p for p, c in should.items() if c == CONFIRMED and grades[p] == "wrong"]
    missed = [
        p for p, c in should.items() if c not in (CONFIRMED, UNLISTED) and grades[p] == "wrong"
    ]
    return {
        "right": sum(g == "right" for g in grades.values()),
        "wrong": sum(g == "wrong" for g in grades.values()),
        "false_alarms": alarms,
        "missed": missed,
        "grades": grades,
        "should_be": should,
    }


def write_discrepancies(run_dir: str, rows: list[dict], stock: ExpectedStock) -> None:
    """``discrepancies.json`` (format, the expected stock's file, counts, rows) and
    ``discrepancies.csv``, each written atomically."""
    doc = {
        "format": FORMAT,
        "expected": stock.path,
        "expected_source": stock.source(),
        "counts": counts(rows),
        "rows": rows,
    }
    atomic_write_text(os.path.join(run_dir, "discrepancies.json"), json.dumps(doc, indent=1))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=FIELDS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow(
            {
                k: (
                    "true"
                    if r.get(k) is True
                    else "false"
                    if r.get(k) is False
                    else safe_cell(r.get(k, ""))  # a WMS's cell "=HYPERLINK(...)" is text
                )
                for k in FIELDS
            }
        )
    atomic_write_text(os.path.join(run_dir, "discrepancies.csv"), buf.getvalue())


__all__ = [
    "CATEGORIES",
    "FIELDS",
    "categorise",
    "counts",
    "counts_line",
    "discrepancy_rows",
    "grade_rows",
    "true_category",
    "write_discrepancies",
]
