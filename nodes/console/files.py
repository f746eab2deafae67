"""Bounded reads of a run folder's JSON files, and the review files beside its rows.

``review.json`` holds every review decision (oldest first) and ``review.csv`` the latest
per place (:mod:`nodes.console.review` takes the decisions); both are written atomically
and never touch ``inventory.csv`` / ``inventory.json``. Every file is read only when no
symbolic link leads to it (:func:`nodes.console.paths.plain`).
"""

from __future__ import annotations

import csv
import io
import json
import os
from typing import Any

from bt_engine.files import atomic_write_text, read_text
from nodes.console.paths import plain
from nodes.inventory_rows import safe_cell

#: the largest summary.json / fleet.json / review.json read, bytes
MAX_JSON_BYTES = 16_000_000
REVIEW_JSON, REVIEW_CSV = "review.json", "review.csv"
REVIEW_FORMAT = "btrun-review-1"
MAX_DECISIONS = 100_000
REVIEW_CSV_FIELDS = (
    "place",
    "answer",
    "decision",
    "reviewer",
    "time",
    "reason",
    "original_answer",
    "original_status",
    "drone",
    "gallery",
    "gallery_event",
)


def read_json(path: str, limit: int = MAX_JSON_BYTES) -> Any:
    """A JSON file read with a size limit; None if missing, reached through a link (see
    :func:`nodes.console.paths.plain`), unreadable or not JSON."""
    if not plain(path) or not os.path.isfile(path):
        return None
    text = read_text(path, [], what="run files", limit=limit)
    if text is None:
        return None
    try:
        return json.loads(text)
    except (ValueError, RecursionError):
        return None


def read_header(ticks: str) -> dict:
    """The tick log's header (mission, rig, cwd, seed, sets); {} if unreadable or reached
    through a link."""
    if not plain(ticks):
        return {}
    try:
        with open(ticks, "rb") as f:
            head = json.loads(f.readline(4_000_000) or b"{}")
    except (OSError, ValueError, RecursionError):
        return {}
    header = head.get("header") if isinstance(head, dict) else None
    return header if isinstance(header, dict) else {}


class ReviewFileError(Exception):
    """``review.json`` is there but cannot be read as a btrun review (one line)."""


def read_review(run_dir: str, strict: bool = False) -> list[dict]:
    """Every decision of ``review.json`` (oldest first); [] if none. An unreadable one reads
    as none for a page, and raises :class:`ReviewFileError` when ``strict`` (a decision is
    to be added: writing the file again would lose the decisions it held)."""
    path = os.path.join(run_dir, REVIEW_JSON)
    doc = read_json(path)
    decisions = doc.get("decisions") if isinstance(doc, dict) else None
    if not isinstance(decisions, list) or doc.get("format") != REVIEW_FORMAT:
        if strict and os.path.lexists(path):
            raise ReviewFileError(
                f"{REVIEW_JSON} of this run cannot be read as a btrun review "
                f"(format {REVIEW_FORMAT!r}): move it aside or mend it; nothing was written"
            )
        return []
    out = [d for d in decisions if isinstance(d, dict) and isinstance(d.get("place"), str)]
    return out[-MAX_DECISIONS:]


def latest_by_place(decisions: list[dict]) -> dict[str, dict]:
    """The latest decision of each place."""
    return {d["place"]: d for d in decisions}


def write_review(run_dir: str, decisions: list[dict]) -> None:
    """``review.json`` (every decision) and ``review.csv`` (the latest per place), each
    written atomically."""
    doc = {"format": REVIEW_FORMAT, "decisions": decisions}
    atomic_write_text(os.path.join(run_dir, REVIEW_JSON), json.dumps(doc, indent=1))
    buf = io.StringIO()
    w = csv.DictWriter(
        buf, fieldnames=REVIEW_CSV_FIELDS, lineterminator="\n", extrasaction="ignore"
    )
    w.writeheader()
    for d in latest_by_place(decisions).values():
        w.writerow({k: safe_cell(d.get(k)) for k in REVIEW_CSV_FIELDS})
    atomic_write_text(os.path.join(run_dir, REVIEW_CSV), buf.getvalue())


def carry_reviews(previous: str, run_dir: str, places: set[str]) -> int:
    """Copy the review decisions the previous run holds for ``places`` (those a resumed
    run carries over) into ``run_dir``'s review files, so an operator's decision on a
    place stays with its answer in the run that continues it. Nothing is written when the
    previous run has none, or when ``run_dir`` holds decisions already. Returns how many
    decisions were carried."""
    if os.path.lexists(os.path.join(run_dir, REVIEW_JSON)):
        return 0
    carried = [d for d in read_review(previous) if d["place"] in places]
    if carried:
        write_review(run_dir, carried)
    return len(carried)
