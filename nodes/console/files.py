"""Bounded reads of a run folder's JSON files, and the review files beside its rows.

``review.json`` holds every review decision (oldest first) and ``review.csv`` the latest
per place (:mod:`nodes.console.review` takes the decisions); both are written atomically
and never touch ``inventory.csv`` / ``inventory.json``.
"""

from __future__ import annotations

import csv
import io
import json
import os
from typing import Any

from bt_engine.files import atomic_write_text, read_text

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
    """A JSON file read with a size limit; None if missing, unreadable or not JSON."""
    if not os.path.isfile(path):
        return None
    text = read_text(path, [], what="run files", limit=limit)
    if text is None:
        return None
    try:
        return json.loads(text)
    except (ValueError, RecursionError):
        return None


def read_header(ticks: str) -> dict:
    """The tick log's header (mission, rig, seed, sets); {} if unreadable."""
    try:
        with open(ticks, "rb") as f:
            head = json.loads(f.readline(4_000_000) or b"{}")
    except (OSError, ValueError, RecursionError):
        return {}
    header = head.get("header") if isinstance(head, dict) else None
    return header if isinstance(header, dict) else {}


def read_review(run_dir: str) -> list[dict]:
    """Every decision of ``review.json`` (oldest first); [] if none or unreadable."""
    doc = read_json(os.path.join(run_dir, REVIEW_JSON))
    if not isinstance(doc, dict) or doc.get("format") != REVIEW_FORMAT:
        return []
    decisions = doc.get("decisions")
    if not isinstance(decisions, list):
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
        w.writerow({k: "" if d.get(k) is None else d.get(k) for k in REVIEW_CSV_FIELDS})
    atomic_write_text(os.path.join(run_dir, REVIEW_CSV), buf.getvalue())
