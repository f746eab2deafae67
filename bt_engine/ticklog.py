"""The tick log: one JSON object per line, flushed as it goes, so nothing is lost on a crash.

Each line holds the tick number, mission time, root status, the statuses that changed
(``{path: status}``), the blackboard entries written (``{entry: value}``) and, when a
vehicle is attached, a small telemetry record. ``btrun replay`` reads it back.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from typing import IO, Any

#: A blackboard value or message longer than this (as JSON) is logged as a note with its size
#: and SHA-1 instead (the full value stays on the blackboard; the in-memory trace and
#: summary.json keep the same note: :func:`summarise_value`).
VALUE_LIMIT_BYTES = 16_384
#: Messages logged per tick at most (the rest are counted).
MESSAGES_PER_TICK = 100
#: Past this many bytes the log keeps only tick, time and status per line (and says so).
LOG_LIMIT_BYTES = 256 * 1024 * 1024


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


#: the bytes JSON writes as they are (printable ASCII but the quote and the backslash)
_PLAIN = bytes(c for c in range(0x20, 0x7F) if c not in b'"\\')


def _bounded(value: Any) -> Any:
    """``value`` (already JSON-friendly) or, past :data:`VALUE_LIMIT_BYTES`, a short note."""
    if isinstance(value, (bool, int, float)) or value is None:
        return value
    if isinstance(value, str):
        if len(value) <= VALUE_LIMIT_BYTES // 4:
            return value
        if value.isascii():  # plain ASCII: its JSON is itself in quotes (no json.dumps)
            raw = value.encode("ascii")
            if not raw.translate(None, _PLAIN):
                if len(raw) + 2 <= VALUE_LIMIT_BYTES:
                    return value
                data = b'"' + raw + b'"'
                return _note(value, len(data), data)
    text = json.dumps(value, separators=(",", ":"))
    if len(text) <= VALUE_LIMIT_BYTES:
        return value
    return _note(value, len(text), text.encode("utf-8", "replace"))


def _note(value: Any, size: int, data: bytes) -> str:
    digest = hashlib.sha1(data).hexdigest()[:12]
    return f"<{type(value).__name__} of {size} bytes, sha1 {digest}: not logged>"


def summarise_value(value: Any) -> Any:
    """A blackboard value (or a message) as the tick log, the runner's trace and
    ``summary.json`` keep it: JSON-friendly (:func:`to_jsonable`, as a record's entry) and,
    past :data:`VALUE_LIMIT_BYTES` as JSON, a one-line note with its type, size and SHA-1."""
    return _bounded(to_jsonable(value, 2))


def summarise_messages(messages: list[Any]) -> list[Any]:
    """A tick's messages as the tick log keeps them: the first :data:`MESSAGES_PER_TICK`,
    each through :func:`summarise_value`, then a line counting the rest."""
    out = [summarise_value(m) for m in messages[:MESSAGES_PER_TICK]]
    extra = len(messages) - MESSAGES_PER_TICK
    if extra > 0:
        out.append(f"... {extra} more messages in this tick not logged")
    return out


class TickLog:
    """Append-only JSON-lines writer (line-buffered: each tick reaches the OS at once)."""

    def __init__(self, path: str, header: dict | None = None) -> None:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        self.path = path
        self.bytes_written = 0
        self.limited = False  # LOG_LIMIT_BYTES was reached
        self._f: IO[str] = open(path, "w", encoding="utf-8", buffering=1)
        if header is not None:
            self.write({"header": header})

    def write(self, record: dict) -> None:
        """Write one record as a JSON line (large values bounded, see the module limits)."""
        rec = to_jsonable(record)
        if "bb" in rec:
            rec["bb"] = {k: _bounded(v) for k, v in rec["bb"].items()}
        msgs = rec.get("messages")
        if msgs:
            rec["messages"] = summarise_messages(msgs)
        if self.bytes_written > LOG_LIMIT_BYTES and "header" not in rec:
            slim = {k: rec[k] for k in ("tick", "t", "status") if k in rec}
            if not self.limited:
                self.limited = True
                slim["messages"] = [
                    f"tick log limit of {LOG_LIMIT_BYTES} bytes reached: from here on only "
                    "tick, time and status are logged"
                ]
            rec = slim
        line = json.dumps(rec, separators=(",", ":")) + "\n"
        self.bytes_written += len(line)
        self._f.write(line)

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
