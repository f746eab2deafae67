"""The tick log: one JSON object per line, flushed as it goes, so nothing is lost on a crash.

Each line holds the tick number, mission time, root status, the statuses that changed
(``{path: status}``), the blackboard entries written (``{entry: value}``) and, when a
vehicle is attached, a small telemetry record. ``btrun replay`` reads it back.
"""

from __future__ import annotations

import json
import math
import os
from typing import IO, Any


def to_jsonable(value: Any, depth: int = 0) -> Any:
    """Convert a blackboard value to something JSON can hold (tuples -> lists, others -> repr)."""
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else repr(value)
    if depth > 6:
        return repr(value)
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v, depth + 1) for v in (value if depth < 2 else value[:1000])]
    if isinstance(value, dict):
        items = list(value.items())
        # records and their status/blackboard maps are complete; only nested values are capped
        return {
            str(k): to_jsonable(v, depth + 1) for k, v in (items if depth < 2 else items[:1000])
        }
    tolist = getattr(value, "tolist", None)
    if callable(tolist) and getattr(value, "size", 1e9) <= 64:
        return to_jsonable(tolist(), depth + 1)
    shape = getattr(value, "shape", None)
    if shape is not None:
        return f"<{type(value).__name__} shape={tuple(shape)}>"
    return repr(value)


class TickLog:
    """Append-only JSON-lines writer (line-buffered: each tick reaches the OS at once)."""

    def __init__(self, path: str, header: dict | None = None) -> None:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        self.path = path
        self._f: IO[str] = open(path, "w", encoding="utf-8", buffering=1)
        if header is not None:
            self.write({"header": header})

    def write(self, record: dict) -> None:
        """Write one record as a JSON line."""
        self._f.write(json.dumps(to_jsonable(record), separators=(",", ":")) + "\n")

    def flush(self) -> None:
        """Flush to the OS."""
        self._f.flush()

    def close(self) -> None:
        """Flush and close."""
        if not self._f.closed:
            self._f.close()


def read_log(path: str) -> tuple[dict, list[dict]]:
    """Read a tick log: return ``(header, tick_records)``; a torn last line is ignored."""
    header: dict = {}
    records: list[dict] = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            line = line.strip()
            if not line:
                continue
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                break
            if "header" in rec:
                header = rec["header"]
            else:
                records.append(rec)
    return header, records
