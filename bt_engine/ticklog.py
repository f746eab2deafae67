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
import re
import time
from collections.abc import Iterator
from datetime import datetime
from typing import IO, Any

from bt_engine.files import NotRegularFile, open_regular
from bt_engine.spec import Loc, MissionError, Problem

#: A blackboard value or message longer than this (as JSON) is logged as a note with its size
#: and SHA-1 instead (the full value stays on the blackboard; the in-memory trace and
#: summary.json keep the same note: :func:`summarise_value`).
VALUE_LIMIT_BYTES = 16_384
#: Messages logged per tick at most (the rest are counted).
MESSAGES_PER_TICK = 100
#: Past this many bytes the log keeps only tick, time and status per line (and says so).
LOG_LIMIT_BYTES = 256 * 1024 * 1024


def started_now() -> str:
    """The wall-clock time now, as a run records its start (``started`` in the tick log's
    header and in ``fleet.json``): ISO 8601 in UTC to the second, ``2026-11-27T14:20:01Z``."""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def started_at(record: Any) -> float | None:
    """A run record's (a tick log header's, ``fleet.json``'s) ``started`` in seconds since
    1970; None when it has none, or it is not an ISO 8601 time with its zone."""
    text = record.get("started") if isinstance(record, dict) else None
    if not isinstance(text, str) or len(text) > 40:
        return None
    try:
        when = datetime.fromisoformat(text)
    except ValueError:
        return None
    return when.timestamp() if when.tzinfo is not None else None


def run_started(name: str, *records: Any) -> float | None:
    """When a run started, seconds since 1970: the first of ``records`` (``fleet.json``, a
    tick log header) that says (:func:`started_at`), else the ``-YYYYMMDD-HHMMSS`` stamp
    of a default run folder's ``name`` (local time, as ``btrun`` names it); None if
    neither tells (a folder named with ``--out``, from before runs recorded their start)."""
    for record in records:
        started = started_at(record)
        if started is not None:
            return started
    m = re.search(r"(\d{8}-\d{6})$", name)
    if m:
        try:
            return time.mktime(time.strptime(m.group(1), "%Y%m%d-%H%M%S"))
        except (ValueError, OverflowError):
            pass
    return None


def header_path(header: Any, value: Any) -> str | None:
    """A path a tick log header names (``rig``, a ``--set gallery=FILE``) as the run meant
    it: a relative one joined to the folder the run was started from (the header's ``cwd``;
    a header from before it was recorded: as it stands). None if ``value`` is no path."""
    if not isinstance(value, str) or not value or "\0" in value:
        return None
    cwd = header.get("cwd") if isinstance(header, dict) else None
    if os.path.isabs(value) or not isinstance(cwd, str) or "\0" in cwd:
        return value
    return os.path.normpath(os.path.join(cwd, value))


def to_jsonable(value: Any, depth: int = 0) -> Any:
    """Convert a blackboard value to something JSON can hold (tuples -> lists, others -> repr)."""
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else repr(value)
    if depth > 6:
        return safe_repr(value)
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
    return safe_repr(value)


def safe_repr(value: Any) -> str:
    """``repr(value)``, or ``<Type: repr failed: why>`` when a plug-in's object cannot say
    what it is (a record must never end a run)."""
    try:
        return repr(value)
    except Exception as exc:
        return f"<{type(value).__name__}: repr failed: {type(exc).__name__}>"


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
        #: why the log could not be written any more (a full disk), and at which record
        self.failed: str | None = None
        self.records = 0
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
        if self.failed is None:
            try:
                self._f.write(line)
                self.records += 1
            except OSError as exc:  # a full disk: the flight goes on, the log stops here
                self._fail(exc)

    def _fail(self, exc: OSError) -> None:
        self.failed = f"{exc.strerror or exc} (the tick log stops after record {self.records})"

    def flush(self) -> None:
        """Flush to the OS (a write error stops the log, never the run)."""
        if self.failed is None:
            try:
                self._f.flush()
            except OSError as exc:
                self._fail(exc)

    def close(self) -> None:
        """Flush and close (a write error is kept in :attr:`failed`)."""
        if not self._f.closed:
            try:
                self._f.close()
            except OSError as exc:
                if self.failed is None:
                    self._fail(exc)


#: The longest line of a tick log read back, in bytes: a longer one is refused, not read.
MAX_LINE_BYTES = 64 * 1024 * 1024


def _path_or_none(v: Any) -> bool:
    return v is None or (isinstance(v, str) and "\0" not in v)


def _node_row(n: Any) -> bool:
    return (
        isinstance(n, list)
        and len(n) == 4
        and isinstance(n[0], str)
        and isinstance(n[1], str)
        and isinstance(n[2], int)
        and isinstance(n[3], list)
    )


#: The header's keys read back (``--resume`` takes mission, seed, rig_arg and sets; replay
#: the nodes): a test of the value and what it should be.
_HEADER_KEYS: dict[str, tuple[Any, str]] = {
    "mission": (_path_or_none, "a path or null"),
    "rig": (_path_or_none, "a path or null"),
    "rig_arg": (_path_or_none, "a path or null"),
    "cwd": (_path_or_none, "a path or null"),
    "seed": (lambda v: v is None or type(v) is int, "an integer or null"),
    "sets": (
        lambda v: isinstance(v, list) and all(isinstance(i, str) for i in v),
        "a list of KEY=VALUE strings",
    ),
    "rate_hz": (lambda v: v is None or type(v) in (int, float), "a number or null"),
    "started": (lambda v: isinstance(v, str), "an ISO 8601 time"),
    "nodes": (
        lambda v: isinstance(v, list) and all(_node_row(n) for n in v),
        "a list of [path, label, depth, flags]",
    ),
}


def _refused(path: str, line: int, col: int, message: str) -> MissionError:
    return MissionError([Problem(Loc(path, line, col), message)])


def _check_header(header: Any, path: str, number: int, text: str) -> dict:
    """The header of line ``number`` (its ``text``) if its keys have the right types, else
    :class:`MissionError` located at the first wrong key."""
    if not isinstance(header, dict):
        col = text.find('"header"') + 1 or 1
        raise _refused(path, number, col, f"'header' must be a JSON object, got {header!r:.60}")
    for key, (ok, want) in _HEADER_KEYS.items():
        if key in header and not ok(header[key]):
            col = text.find(f'"{key}"') + 1 or 1
            raise _refused(
                path, number, col, f"header '{key}' must be {want}, got {header[key]!r:.60}"
            )
    return header


def open_log(path: str) -> Any:
    """The tick log ``path`` opened for reading (binary); a located problem (``MissionError``)
    if it is no regular file or cannot be read."""
    try:
        return open_regular(path, what="tick logs")
    except NotRegularFile as exc:
        raise _refused(path, 1, 1, str(exc)) from None
    except (OSError, ValueError) as exc:
        why = getattr(exc, "strerror", None) or exc
        raise _refused(path, 1, 1, f"cannot read {path}: {why}") from None


def log_lines(f: IO[bytes]) -> Iterator[tuple[int, bytes, bool]]:
    """``(line number, raw line, too long)`` of an open tick log, blank lines left out; a
    line longer than :data:`MAX_LINE_BYTES` is read no further than that (the rest of it
    is skipped) and flagged."""
    number = 0
    while True:
        raw = f.readline(MAX_LINE_BYTES + 1)
        if not raw:
            return
        number += 1
        long = len(raw) > MAX_LINE_BYTES
        if long:
            rest = raw
            while rest and not rest.endswith(b"\n"):  # the rest of the line: skipped
                rest = f.readline(MAX_LINE_BYTES + 1)
        elif not raw.strip():
            continue
        yield number, raw, long


def read_log(path: str, header_only: bool = False) -> tuple[dict, list[dict]]:
    """Read a tick log: return ``(header, tick_records)``; a torn last line is ignored.
    ``header_only``: stop after the header line (``--resume`` needs nothing else, and a
    long run's log is large).

    A tick log comes from a run folder, which may have been tampered with: it is read only
    if it is a regular file (a FIFO or a device is refused before it is opened), line by
    line, none longer than :data:`MAX_LINE_BYTES`. Raises :class:`MissionError` with one
    located problem (``file:line:col: message``) for such a file, a first line that is not
    a JSON object, a line that is JSON but not an object, or a header key of the wrong type
    (``"seed": "x"``, ``"sets": 5``)."""
    header: dict = {}
    records: list[dict] = []
    with open_log(path) as f:
        first = True
        for number, raw, long in log_lines(f):
            if long:
                raise _refused(path, number, 1, f"line longer than {MAX_LINE_BYTES} bytes")
            try:
                rec = json.loads(raw)
            except ValueError:  # not JSON, not UTF-8: a torn last line, unless it is the first
                if first:
                    raise _refused(
                        path, number, 1, "not a tick log: the line is not JSON"
                    ) from None
                break
            if not isinstance(rec, dict):
                raise _refused(
                    path, number, 1, f"not a tick log: expected a JSON object, got {rec!r:.60}"
                )
            first = False
            if "header" in rec:
                text = raw.decode("utf-8", "replace")
                header = _check_header(rec["header"], path, number, text)
                if header_only:
                    break
            else:
                records.append(rec)
    return header, records
