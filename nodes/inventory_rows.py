"""The rows of an inventory: their fields and statuses, the file format, grading against the
ground truth, and reading ``inventory.json`` back, checked (``--resume``, the console, the
site store's importer).

:mod:`nodes.inventory_log` keeps the rows of a run and writes them; its names for what is
here are the same objects (importable from either module).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from typing import Any

from bt_engine.files import read_text
from bt_engine.spec import Loc, Problem

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
    "decided_by",
)
FORMAT = "btrun-inventory-1"
#: the columns of inventory.csv that hold text from outside btrun (a gallery's identities,
#: reasons quoting them): written so that a spreadsheet never runs them as a formula
TEXT_FIELDS = ("place", "answer", "best_id", "drone", "run", "reason")


def safe_cell(value: Any) -> str:
    """A text cell a spreadsheet will not run as a formula (CSV injection): ``'`` before a
    text that starts with ``=``, ``+``, ``-``, ``@`` (after spaces), a tab or a return."""
    text = "" if value is None else str(value)
    lead = text.lstrip(" ")[:1]  # " =2+2": an importer that trims would run it
    return "'" + text if text[:1] in ("\t", "\r") or lead in ("=", "+", "-", "@") else text


#: The most rows an inventory read back (``--resume``) may hold: far more places than any
#: warehouse map has; a larger file is refused before anything flies.
MAX_INVENTORY_ROWS = 100_000
#: The largest ``inventory.json`` read back, in bytes (100,000 rows as written take ~25 MB).
MAX_INVENTORY_BYTES = 64_000_000
#: The longest text in a row read back (a place name, an answer, a reason).
MAX_ROW_TEXT = 10_000


class InventoryError(Exception):
    """An inventory file that cannot be used, said in one line (``file:line:col: message``
    when the place in the file is known)."""

    def __init__(self, message: str, loc: Loc | None = None) -> None:
        super().__init__(f"{loc}: {message}" if loc is not None else message)
        self.message, self.loc = message, loc

    def problem(self) -> Problem:
        """As a located problem (at ``--resume`` when the place in the file is unknown)."""
        if self.loc is None:
            return Problem(Loc("--resume", 0, 0), self.message)
        return Problem(self.loc, self.message)


def grade(answer: str, truth: str | None, not_enrolled: set[str]) -> str:
    """How an answer compares with the ground truth: ``right``; ``wrong`` (an identity
    accepted that is not the one standing there); ``unknown`` (no identity where an
    enrolled pallet stands); ``missed`` (answered empty where a pallet stands);
    ``not_scanned`` (no answer). An empty place (``truth`` None) is graded by what stands
    there, nothing: only ``empty`` is right; ``unknown`` (a pallet claimed where none
    stands) is ``wrong`` like an identity, never the ``unknown`` grade, which is for an
    enrolled pallet left unidentified."""
    if not answer:
        return NOT_SCANNED
    if truth is None:
        return "right" if answer == EMPTY else "wrong"
    if answer == EMPTY:
        return "missed"
    if truth in not_enrolled:
        return "right" if answer == UNKNOWN else "wrong"
    if answer == UNKNOWN:
        return "unknown"
    return "right" if answer == truth else "wrong"


def _text(v: Any) -> bool:
    return v is None or (isinstance(v, str) and len(v) <= MAX_ROW_TEXT)


def _number(v: Any) -> bool:
    return v is None or (type(v) in (int, float) and math.isfinite(v))


#: What each key of a row read back must be: a test and what it should be.
_ROW_KEYS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "place": (
        lambda v: isinstance(v, str) and 0 < len(v) <= MAX_ROW_TEXT,
        "a place name",
    ),
    "answer": (_text, "text or null"),
    "status": (lambda v: v in (*FINISHED, NOT_SCANNED), f"one of {[*FINISHED, NOT_SCANNED]}"),
    "best_id": (_text, "text or null"),
    "distance": (_number, "a number or null"),
    "margin": (_number, "a number or null"),
    "blocks_seen": (lambda v: v is None or type(v) is int, "an integer or null"),
    "mission_time_s": (_number, "a number or null"),
    "drone": (_text, "text or null"),
    "run": (_text, "text or null"),
    "reason": (_text, "text or null"),
    "decided_by": (_text, "text or null"),
}


def _row_problem(row: Any) -> str | None:
    """What is wrong with one row read back (None: nothing)."""
    if not isinstance(row, dict):
        return f"expected a row (a JSON object), got {row!r:.60}"
    for key, value in row.items():
        if key not in _ROW_KEYS:
            return f"unknown key {key!r:.60} (a row has {', '.join(FIELDS)})"
        ok, want = _ROW_KEYS[key]
        if not ok(value):
            return f"{key}: expected {want}, got {value!r:.60}"
    if "place" not in row:
        return "a row needs a place"
    return None


def _row_loc(path: str, text: str, index: int) -> Loc:
    """Where row ``index`` starts in ``path`` (its text ``text``): decoded once more with the
    pure-Python scanner noting where each object starts (only to locate a refused row)."""
    starts: dict[int, int] = {}
    decoder = json.JSONDecoder()

    def parse_object(s_and_end: tuple[str, int], *args: Any) -> tuple[Any, int]:
        obj, end = json.decoder.JSONObject(s_and_end, *args)  # type: ignore[attr-defined]
        starts[id(obj)] = s_and_end[1] - 1
        return obj, end

    decoder.parse_object = parse_object  # type: ignore[assignment]
    decoder.scan_once = json.scanner.py_make_scanner(decoder)  # type: ignore[attr-defined]
    try:
        again = decoder.decode(text)  # alive while the ids are looked up
        offset = starts.get(id(again["rows"][index]))
    except (ValueError, LookupError, TypeError, RecursionError):
        offset = None
    if offset is None:
        return Loc(path, 1, 1)
    line_start = text.rfind("\n", 0, offset) + 1
    return Loc(path, text.count("\n", 0, offset) + 1, offset - line_start + 1)


def read_inventory(run_dir: str) -> list[dict]:
    """The rows of ``run_dir/inventory.json`` ([] if the run wrote none), schema-checked:
    raises :class:`InventoryError` (one located line) if the file is not a regular file, is
    larger than :data:`MAX_INVENTORY_BYTES`, is not a btrun inventory, holds more than
    :data:`MAX_INVENTORY_ROWS` rows or a row of the wrong shape (``"answer": ["3A"]``,
    ``"mission_time_s": "soon"``, an unknown key). A resumed run reads it before anything
    flies."""
    path = os.path.join(run_dir, "inventory.json")
    if not os.path.lexists(path):
        return []
    problems: list[Problem] = []
    text = read_text(path, problems, what="inventories", limit=MAX_INVENTORY_BYTES)
    if text is None:
        raise InventoryError(problems[0].message, problems[0].loc)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InventoryError(f"not JSON: {exc.msg}", Loc(path, exc.lineno, exc.colno)) from None
    except (ValueError, RecursionError) as exc:
        raise InventoryError(f"not JSON: {exc}", Loc(path, 1, 1)) from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InventoryError(f"not a btrun inventory (format {FORMAT!r} expected)", Loc(path, 1, 1))
    rows = data.get("rows")
    if not isinstance(rows, list):
        raise InventoryError("'rows' must be a list of rows", Loc(path, 1, 1))
    if len(rows) > MAX_INVENTORY_ROWS:
        raise InventoryError(
            f"{len(rows)} rows; an inventory holds at most {MAX_INVENTORY_ROWS}", Loc(path, 1, 1)
        )
    for i, row in enumerate(rows):
        why = _row_problem(row)
        if why is not None:
            raise InventoryError(f"rows[{i}]: {why}", _row_loc(path, text, i))
    return rows
