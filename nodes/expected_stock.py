"""The expected stock: which pallet the warehouse's WMS says stands in each place.

A mission input of the inventory (``--set expected=stock.csv``), in the format a WMS
exports: a header ``place,pallet`` and one row per place; an empty ``pallet`` means the
place should be empty::

    place,pallet
    A-01-1,109
    A-01-2,
    A-02-1,106

or the same as JSON: a list of ``{"place": ..., "pallet": ...}`` objects (``null`` or
``""`` for an empty place), the list under ``"rows"``, or a ``{place: pallet}`` object; or
an XLSX workbook whose first shown sheet has a header row with ``place`` and ``pallet`` (read
with openpyxl; problems located as ``stock.xlsx:ROW:COLUMN``).
Pallets are named as the WMS names them (``103``); a side name (``103B``) stands for its
pallet, and case does not tell pallets apart (``PAL-7`` is ``pal-7``). A ``status`` column
(btrun's own inventory export read back) is honoured: a row whose pallet is empty because
the place was ``unknown`` or ``not_scanned`` lists no expectation, only ``empty`` (or no
status) means "should be empty". :func:`read_expected` reads it before flight (bounded, :mod:`bt_engine.files`) and
reports every problem where it is (``stock.csv:4:8: ...``): a bad header or bad JSON, an
unknown place (with a "did you mean"), a place listed twice, one pallet expected at two
places.
"""

from __future__ import annotations

import hashlib
import os
import re
import unicodedata
from dataclasses import dataclass, field
from typing import Any

from bt_engine.files import read_bytes
from bt_engine.spec import Loc, Problem, plural
from drivers.settings import did_you_mean
from nodes.stock_files import (
    MAX_EXPECTED_PLACES,
    ZIP_MAGIC,
    NotText,
    byte_loc,
    entries_csv,
    entries_xlsx,
    export_text,
    not_text,
    with_cells,
)
from nodes.stock_json import entries_json
from perception.expected import pallet_key, pallet_of
from perception.gallery import MAX_IDENTITY_CHARS

#: the largest expected-stock file read, bytes (100,000 places take ~2 MB as CSV)
MAX_EXPECTED_BYTES = 16_000_000
#: spellings of "no pallet here" in the pallet column (as WMS and database exports write it)
EMPTY_SPELLINGS = ("", "empty", "none", "-", "n/a", "null", "nil")
#: a ``status`` (btrun's inventory export) for which an empty pallet is no expectation: the
#: place was not known to be empty, only not identified or not looked at
NOT_KNOWN_STATUSES = ("unknown", "not_identified", "not_scanned", "not scanned")
#: unknown places that get a spelling hint (difflib over every place is slow on big files)
_HINTED = 50


def _canonical(name: str) -> str:
    """A place name without case and leading zeros in its numbers: ``a-1-1`` -> ``A-1-1``,
    as ``A-01-1`` -> ``A-1-1``."""
    return re.sub(r"\d+", lambda m: str(int(m.group())), name.strip().upper())


class PlaceHints:
    """`` (did you mean 'A-01-1'?)`` for an unknown place: the place that differs only in
    case or leading zeros first (``a-1-1``), else the closest spelling (for the first
    :data:`_HINTED` asked), else the range of the world's places."""

    def __init__(self, names: list[str]) -> None:
        self.names = names
        self._by_canon: dict[str, str] = {}
        for n in names:
            self._by_canon.setdefault(_canonical(n), n)
        self._asked = 0

    @property
    def canonical(self) -> dict[str, str]:
        """The world's places by their names without case and leading zeros."""
        return self._by_canon

    def hint(self, name: str) -> str:
        """The hint for unknown place ``name`` (with its leading space)."""
        same = self._by_canon.get(_canonical(name))
        if same is not None:
            return f" (did you mean '{same}'?)"
        self._asked += 1
        close = did_you_mean(name, self.names) if self._asked <= _HINTED else ""
        if not self.names:
            return close
        return close or f" (places: {self.names[0]} .. {self.names[-1]})"


_LONGEST = 200  # a place name longer than this is not one
#: a pallet name longer than a gallery identity could never be verified nor identified
_LONGEST_PALLET = MAX_IDENTITY_CHARS
#: the most problems of one expected-stock file said (a wrong file would print thousands)
MAX_PROBLEMS_SAID = 50


@dataclass
class ExpectedStock:
    """Place -> the pallet expected there (None: the place should be empty), from ``path``;
    ``locs`` says where each place was listed."""

    path: str
    places: dict[str, str | None] = field(default_factory=dict)
    locs: dict[str, Loc] = field(default_factory=dict)
    #: SHA-256 of the file's bytes as read (which WMS export a report was made against)
    sha256: str = ""
    #: rows left out because their rack is none of the world's (a whole-warehouse export's
    #: other zones): pallet (:func:`pallet_key`) -> its place, for ``moved_from``
    elsewhere: dict[str, str] = field(default_factory=dict)
    #: how many rows were left out so, and the line that says it (empty: none)
    outside: int = 0
    outside_note: str = ""
    _where: tuple[int, dict[str, str]] | None = field(default=None, repr=False, compare=False)

    def source(self) -> dict[str, Any]:
        """Which file the stock was read from: its absolute path and SHA-256 (and
        ``rows_outside_world``, the rows of other zones left out, when there were any)."""
        out: dict[str, Any] = {"path": os.path.abspath(self.path), "sha256": self.sha256}
        if self.outside:
            out["rows_outside_world"] = self.outside
        return out

    def at(self, place: str) -> str | None:
        """The pallet expected at ``place``: its name, ``""`` when the place should be
        empty, None when the stock does not list it."""
        if place not in self.places:
            return None
        return self.places[place] or ""

    def place_of(self, pallet: str) -> str | None:
        """The place where ``pallet`` (or a side of it: ``103B``) is expected, or None;
        a place of another zone of the warehouse when only such a row lists it."""
        if self._where is None or self._where[0] != len(self.places):
            index: dict[str, str] = {}
            for place, p in self.places.items():
                if p is not None:
                    index.setdefault(pallet_key(p), place)
            self._where = (len(self.places), index)  # one pass, not one per question
        key = pallet_key(pallet)
        return self._where[1].get(key) or self.elsewhere.get(key)


def read_expected(
    spec: str, world: Any, where: Loc, base_dir: str = "."
) -> tuple[ExpectedStock | None, list[Problem]]:
    """The expected stock of file ``spec`` (None if ``spec`` is empty), and every problem,
    located in the file (or at ``where`` when the file cannot be read)."""
    text_spec = str(spec or "").strip()
    if not text_spec:
        return None, []
    path = (
        text_spec
        if os.path.isabs(text_spec) or os.path.exists(text_spec)
        else os.path.join(base_dir, text_spec)
    )
    read: list[Problem] = []
    data = read_bytes(path, read, where, what="expected stocks", limit=MAX_EXPECTED_BYTES)
    if data is None:
        return None, [Problem(where, f"expected stock: {read[0].message}")]
    sheet = ""  # an XLSX's sheet: its problems name their cells, and rows are no lines
    if path.lower().endswith((".xlsx", ".xlsm")) or data.startswith(ZIP_MAGIC):
        entries, problems, sheet = entries_xlsx(path, data)
    else:
        try:
            text = not_text(data) or export_text(data)
        except (UnicodeDecodeError, ValueError) as exc:
            return None, [
                Problem(
                    byte_loc(path, data, getattr(exc, "start", 0)),
                    f"{exc if isinstance(exc, NotText) else 'not UTF-8, UTF-16 or Windows-1252 text'}"
                    ": expected CSV, JSON or an XLSX workbook",
                )
            ]
        text = text.removesuffix("\x1a")  # a DOS end-of-file byte (old WMS exports)
        if path.lower().endswith(".json") or text.lstrip()[:1] in ("[", "{"):
            entries, problems = entries_json(path, text)
        else:
            entries, problems = entries_csv(path, text)
    line = "row" if sheet else "line"
    names = list(getattr(world, "places", None) or {})
    known, hints = set(names), PlaceHints(names)
    racks = {_rack(n) for n in names}
    outside: dict[str, int] = {}  # rack -> rows of racks this world does not have
    first_outside: Loc | None = None
    in_world = 0  # rows of this world's racks, accepted or not
    stock = ExpectedStock(path, sha256=hashlib.sha256(data).hexdigest())
    pallet_at: dict[str, tuple[str, Loc, str]] = {}
    seen: dict[str, Loc] = {}  # every place listed, an expectation or not
    if len(entries) > MAX_EXPECTED_PLACES:  # said first: the rest is not read
        problems.insert(
            0,
            Problem(
                entries[MAX_EXPECTED_PLACES][2], f"more than {MAX_EXPECTED_PLACES} places listed"
            ),
        )
    for place, pallet, where_place, where_pallet, status in entries[:MAX_EXPECTED_PLACES]:
        place, pallet = plain_name(place), plain_name(pallet)
        bad = _name_problem(place, pallet, where_place, where_pallet)
        if bad is not None:
            problems.append(bad)
            continue
        in_world += _rack(place) in racks
        if names and place not in known:
            if _elsewhere(place, racks, hints):
                # another zone of the warehouse (a whole-warehouse export): left out
                outside[_rack(place)] = outside.get(_rack(place), 0) + 1
                first_outside = first_outside or where_place
                if pallet.lower() not in EMPTY_SPELLINGS:
                    stock.elsewhere.setdefault(pallet_key(pallet), place)
                continue
            problems.append(Problem(where_place, f"unknown place '{place}'{hints.hint(place)}"))
            continue
        if place in seen:
            problems.append(
                Problem(
                    where_place,
                    f"place '{place}' listed twice (first at {line} {seen[place].line}); one "
                    "row per place",
                )
            )
            continue
        seen[place] = where_place
        empty = pallet.lower() in EMPTY_SPELLINGS
        if empty and status.lower() in NOT_KNOWN_STATUSES:
            continue  # btrun's export of a place it could not tell: no expectation
        stock.places[place] = None if empty else pallet
        stock.locs[place] = where_place
        if empty:
            continue
        key = pallet_key(pallet)
        if key in pallet_at:
            other, loc, written = pallet_at[key]
            said = _twice(written, pallet)
            problems.append(
                Problem(
                    where_pallet,
                    f"{said}: {other} ({line} {loc.line}) and {place}; a pallet stands in one "
                    "place",
                )
            )
        else:
            pallet_at[key] = (place, where_place, pallet)
    if not entries and not problems:
        problems.append(Problem(Loc(path, 1, 1), "the expected stock lists no place"))
    if outside:
        problems += _outside(stock, outside, first_outside, racks, in_world > 0)
    problems = with_cells(path, sheet, problems)  # an XLSX: Stock!B6 besides row:column
    if len(problems) > MAX_PROBLEMS_SAID:  # a wrong file altogether: the first ones say it
        more = len(problems) - MAX_PROBLEMS_SAID
        problems = problems[:MAX_PROBLEMS_SAID] + [
            Problem(Loc(path, 1, 1), f"... and {more} more problems in this file")
        ]
    return stock, problems


#: a place name as the world names places (rack-bay-level, ``A-01-1``): only such a name of
#: a rack the world does not have is another zone's; anything else is a problem
_PLACE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9]{0,15}-\d{1,4}-\d{1,3}")


def _rack(place: str) -> str:
    """The rack a place name starts with (``A`` of ``A-01-1``), in capitals."""
    return place.split("-", 1)[0].strip().upper()


def _elsewhere(place: str, racks: set[str], hints: PlaceHints) -> bool:
    """Whether ``place`` names a place of a rack ``racks`` does not hold (another zone of
    the warehouse), not a misspelt place of this world."""
    return (
        bool(_PLACE_NAME.fullmatch(place))
        and _rack(place) not in racks
        and _canonical(place) not in hints.canonical
    )


def _outside(
    stock: ExpectedStock, outside: dict[str, int], first: Loc | None, racks: set[str], any_in: bool
) -> list[Problem]:
    """Rows whose rack the world does not have: left out, said in ``stock.outside_note``
    (a whole-warehouse export names every zone); an error when no row is of this world."""
    n = sum(outside.values())
    theirs = sorted(outside)
    shown = ", ".join(theirs[:8]) + (f", ... ({len(theirs)} racks)" if len(theirs) > 8 else "")
    shown = ("racks " if len(theirs) > 1 else "rack ") + shown
    mine = ", ".join(sorted(racks)[:12])
    if not any_in:
        return [
            Problem(
                first or Loc(stock.path, 1, 1),
                f"no row names a place of this world (its racks: {mine}); the file names "
                f"{plural(n, 'place')} of {shown}: the expected stock of another site?",
            )
        ]
    stock.outside = n
    stock.outside_note = (
        f"expected stock {stock.path}: {plural(n, 'row')} of {shown}, which this world does "
        f"not have, left out (another zone of the warehouse); "
        f"{plural(len(stock.places), 'place')} of this world read"
    )
    return []


#: an id a spreadsheet saved as a number: ``1,02346E+17`` (an SSCC in scientific
#: notation, a comma or point as decimal mark) or ``109,0`` / ``109.0``
_MANGLED_NUMBER = re.compile(r"\d+(?:[.,]\d+[eE][+-]?|[eE][+-])\d+|\d+[.,]0+")


def plain_name(text: str) -> str:
    """A WMS cell's name as the gallery and the world spell theirs: compatibility forms
    folded (NFKC: full-width digits and letters of an East-Asian input method, ``１０９`` ->
    ``109``) and invisible format characters dropped (a zero-width space or joiner, a soft
    hyphen, a byte-order mark copied from a web page), then stripped. They had been kept,
    and every place became a "mismatch 109 -> 109" printed alike."""
    if text.isascii():
        return text
    folded = unicodedata.normalize("NFKC", text)
    return "".join(c for c in folded if unicodedata.category(c) != "Cf").strip()


def _name_problem(place: str, pallet: str, where_place: Loc, where_pallet: Loc) -> Problem | None:
    """A name that is none (too long, a control character), located at its own cell."""
    if len(place) > _LONGEST:
        return Problem(where_place, f"a place name longer than {_LONGEST} characters")
    if len(pallet) > _LONGEST_PALLET:
        return Problem(
            where_pallet,
            f"a pallet name longer than {_LONGEST_PALLET} characters (a gallery holds "
            f"identities of at most {MAX_IDENTITY_CHARS}: it could never be verified)",
        )
    if _MANGLED_NUMBER.fullmatch(pallet):
        return Problem(
            where_pallet,
            f"'{pallet}' is a number a spreadsheet rewrote (scientific notation or a decimal "
            "part): the id it was has lost digits or gained some; export the column as text",
        )
    for name, where in ((place, where_place), (pallet, where_pallet)):
        if any(ord(c) < 32 or ord(c) == 127 for c in name):
            shown = name.encode("unicode_escape").decode()[:60]
            return Problem(where, f"a control character in '{shown}': not a name")
    return None


def _twice(written: str, pallet: str) -> str:
    """How one pallet written ``written`` at one place and ``pallet`` at another is said."""
    key = pallet_key(pallet)
    if written == pallet:
        return f"pallet '{pallet}' expected at two places"
    if written.casefold() == pallet.casefold() or key in (written.casefold(), pallet.casefold()):
        # 109 and 109B (the pallet and one of its sides), PAL-7 and pal-7, 0111 and 111
        return (
            f"pallet '{pallet_of(written)}' (written '{written}' and '{pallet}') expected at "
            "two places"
        )
    # 7A and 7B: read as the two sides of pallet 7
    return (
        f"'{written}' and '{pallet}' are read as two sides of one pallet '{pallet_of(written)}' "
        "(a name ending in a digit and a letter names a side), expected at two places"
    )


__all__ = [
    "EMPTY_SPELLINGS",
    "NOT_KNOWN_STATUSES",
    "MAX_EXPECTED_PLACES",
    "PlaceHints",
    "ExpectedStock",
    "read_expected",
]
