"""Expected stock as JSON: a list of ``{"place", "pallet"}`` objects (or that list under
``"rows"``), or one ``{place: pallet}`` object. Each entry is located in the text
(``stock.json:LINE:COL``) by one forward pass: :class:`LineIndex` knows where every line
starts, so locating row *n* does not count the lines before it again (a 100,000-row file
took minutes when it did).
"""

from __future__ import annotations

import bisect
import json
import re

from bt_engine.spec import Loc, Problem

#: an entry: (place, pallet, where the place is, where the pallet is, its ``status``)
Entry = tuple[str, str, Loc, Loc, str]


class LineIndex:
    """Where each line of ``text`` starts: ``loc(offset)`` is ``path:line:col`` of a
    character offset (1-based, the column counted in characters), found by a binary
    search of the newlines, read once."""

    def __init__(self, path: str, text: str) -> None:
        self.path = path
        self.newlines = [m.start() for m in re.finditer("\n", text)]

    def loc(self, offset: int) -> Loc:
        """The location of character ``offset``."""
        k = bisect.bisect_left(self.newlines, offset)  # newlines before the offset
        line_start = self.newlines[k - 1] + 1 if k else 0
        return Loc(self.path, k + 1, offset - line_start + 1)


def _row_starts(text: str) -> list[int] | None:
    """The offset of every element of the JSON list of rows in ``text`` (the top-level list,
    or the one under ``"rows"``), found by decoding the elements one after another; None
    when the text is laid out otherwise."""
    dec = json.JSONDecoder()
    n = len(text)

    def skip(i: int) -> int:
        while i < n and text[i] in " \t\r\n":
            i += 1
        return i

    try:
        i = skip(0)
        if text[i] == "{":  # {"rows": [...], ...}: walk the keys to "rows"
            i += 1
            while True:
                key, i = dec.raw_decode(text, skip(i))
                i = skip(skip(i) + 1)  # the ':'
                if key == "rows":
                    break
                _, i = dec.raw_decode(text, i)
                i = skip(i)
                if text[i] != ",":
                    return None
                i += 1
        if text[i] != "[":
            return None
        i, starts = i + 1, []
        while True:
            i = skip(i)
            if text[i] == "]":
                return starts
            starts.append(i)
            _, i = dec.raw_decode(text, i)
            i = skip(i)
            if text[i] == ",":
                i += 1
    except (IndexError, ValueError, RecursionError):
        return None


def entries_json(path: str, text: str) -> tuple[list[Entry], list[Problem]]:
    """(place, pallet, where, where, status) per JSON entry: a list of {place, pallet}
    objects (or that list under "rows"; an object's ``status``, if it has one, as the CSV
    column), or a {place: pallet} object (no status); each located by a search of the text
    from the previous entry on."""
    try:
        data = json.loads(text, object_pairs_hook=list)
    except json.JSONDecodeError as exc:
        return [], [Problem(Loc(path, exc.lineno, exc.colno), f"not JSON: {exc.msg}")]
    except (ValueError, RecursionError) as exc:
        return [], [Problem(Loc(path, 1, 1), f"not JSON: {exc}")]
    if isinstance(data, list) and all(isinstance(p, tuple) for p in data):  # an object
        pairs = data
        keys = [k for k, _ in pairs]
        if keys == ["rows"] or ("rows" in keys and isinstance(dict(pairs)["rows"], list)):
            data = dict(pairs)["rows"]
        else:
            return _mapping(path, text, pairs)
    if not isinstance(data, list):
        return [], [Problem(Loc(path, 1, 1), "expected a list of {place, pallet} rows")]
    out: list[Entry] = []
    problems, pos, lines = [], 0, LineIndex(path, text)
    starts = _row_starts(text)
    if starts is not None and len(starts) != len(data):
        starts = None
    for i, item in enumerate(data):
        if starts is not None:  # where each row begins, whatever it is
            start = starts[i]
        else:
            start = text.find("{", pos)
            pos = start + 1 if start >= 0 else pos
        where = lines.loc(max(start, 0))
        obj = (
            # keys in any case, as CSV and XLSX headers ("Place", "PALLET")
            {str(k).strip().lower(): v for k, v in item}
            if isinstance(item, list) and all(isinstance(p, tuple) for p in item)
            else None
        )
        if obj is None or not isinstance(obj.get("place"), str):
            problems.append(
                Problem(
                    where,
                    f'rows[{i}]: expected {{"place": ..., "pallet": ...}} with the place as '
                    f"text, got {_shown(item)}",
                )
            )
            continue
        pallet = obj.get("pallet")
        if pallet is not None and (isinstance(pallet, bool) or not isinstance(pallet, (str, int))):
            problems.append(
                Problem(where, f"rows[{i}]: pallet must be text or null, got {_shown(pallet)}")
            )
            continue
        status = obj.get("status")
        status = status.strip() if isinstance(status, str) else ""
        out.append(
            (
                obj["place"].strip(),
                "" if pallet is None else str(pallet).strip(),
                where,
                where,
                status,
            )
        )
    return out, problems


def _shown(value: object, most: int = 60) -> str:
    """A JSON value as the file wrote it, shortened (the reader keeps objects as lists of
    pairs, which Python would print as ``[('x', 1)]``)."""

    def plain(v: object) -> object:
        if isinstance(v, list):
            if v and all(isinstance(p, tuple) and len(p) == 2 for p in v):
                return {str(k): plain(x) for k, x in v}
            return [plain(x) for x in v]
        return v

    text = json.dumps(plain(value), ensure_ascii=False)
    return text if len(text) <= most else text[: most - 3] + "..."


def _key_at(text: str, quoted: str, pos: int) -> tuple[int, int] | None:
    """(start, end) of the first ``quoted`` key from ``pos`` on, followed by white space and
    a ``:`` (``end`` after the ``:``), else None: what the search ``"KEY"\\s*:`` finds, without
    compiling a pattern per key (100,000 keys took half a minute of compiling)."""
    n = len(text)
    i = text.find(quoted, pos)
    while i >= 0:
        j = i + len(quoted)
        while j < n and text[j].isspace():
            j += 1
        if j < n and text[j] == ":":
            return i, j + 1
        i = text.find(quoted, i + 1)
    return None


def _mapping(path: str, text: str, pairs: list) -> tuple[list[Entry], list[Problem]]:
    out: list[Entry] = []
    problems, pos, lines = [], 0, LineIndex(path, text)
    for place, pallet in pairs:
        found = _key_at(text, '"' + json.dumps(place)[1:-1] + '"', pos)
        start = found[0] if found else pos
        pos = found[1] if found else pos
        where = lines.loc(start)
        if pallet is not None and (isinstance(pallet, bool) or not isinstance(pallet, (str, int))):
            problems.append(
                Problem(where, f"{place}: pallet must be text or null, got {_shown(pallet)}")
            )
            continue
        out.append((place.strip(), "" if pallet is None else str(pallet).strip(), where, where, ""))
    return out, problems


__all__ = ["Entry", "LineIndex", "entries_json"]
