"""The file formats of an expected stock (and of a place list): CSV as WMSs and
spreadsheets export it (comma, semicolon or tab; UTF-8, UTF-16 or Windows-1252), an XLSX
workbook's first shown sheet, JSON (:mod:`nodes.stock_json`). Each reader returns
``(place, pallet, where the place is, where the pallet is, status)`` per row (``status``:
the row's ``status`` column, ``""`` without one) and the problems, located in the file;
:func:`nodes.expected_stock.read_expected` checks the rows against the world.
"""

from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass
from typing import Any

from bt_engine.spec import Loc, Problem
from nodes.stock_json import Entry

#: the most places an expected stock may list
MAX_EXPECTED_PLACES = 100_000

#: what may stand between the columns of a WMS's CSV export: a comma, or a semicolon (what a
#: spreadsheet writes where the decimal mark is a comma) or a tab
DELIMITERS = (",", ";", "\t")


#: Excel's first line naming the delimiter (``sep=;``), which it writes for a reader whose
#: locale would split at another
_SEP_LINE = re.compile(r'"?sep=(.)"?\r?')


@dataclass
class CsvRow:
    """A row of a CSV file: the line it starts on, its cells, and the column each cell
    starts at on that line (1-based, quotes and all: what an editor shows)."""

    line: int
    cells: list[str]
    cols: list[int]

    def col(self, index: int) -> int:
        """The column of cell ``index`` (the end of the line for a cell the row lacks)."""
        return self.cols[min(index, len(self.cols) - 1)]


def csv_rows(text: str) -> tuple[list[CsvRow], str]:
    """The rows of CSV ``text`` and the delimiter they were split at: the one of
    :data:`DELIMITERS` found most often in the first line (a comma if none is), so that
    ``place;pallet`` and tab-separated exports read as ``place,pallet`` does, or the one a
    ``sep=;`` first line names (that line is not a row). Each row knows its line and its
    cells' columns, so problems are located where they are, quoted cells, quoted line
    breaks and all. Raises :class:`csv.Error` for a file the csv module cannot read."""
    first, _, rest = text.partition("\n")
    named = _SEP_LINE.fullmatch(first)
    if named:
        delimiter, body, skipped = named.group(1), rest, 1
    else:
        bare = re.sub(r'"[^"]*"', "", first)  # a separator inside quotes separates nothing
        delimiter = max(DELIMITERS, key=lambda d: (bare.count(d), d == ","))
        body, skipped = text, 0
    lines = io.StringIO(body, newline="").readlines()  # as the reader splits them
    reader = csv.reader(io.StringIO(body, newline=""), delimiter=delimiter)
    rows: list[CsvRow] = []
    start = 1
    for cells in reader:
        raw = lines[start - 1] if start <= len(lines) else ""
        rows.append(CsvRow(start + skipped, cells, _columns(raw, delimiter)))
        start = reader.line_num + 1
    return rows, delimiter


def _columns(line: str, delimiter: str) -> list[int]:
    """Where each cell of CSV ``line`` starts (1-based); a delimiter inside quotes does not
    end a cell."""
    cols, quoted = [1], False
    for i, ch in enumerate(line):
        if ch == '"':
            quoted = not quoted
        elif ch == delimiter and not quoted:
            cols.append(i + 2)
    return cols


def export_text(data: bytes) -> str:
    """The text of a WMS's or a spreadsheet's text export: UTF-8 (with or without a byte
    order mark), UTF-16 with one (Excel's "Unicode Text") or without (told by its zero
    bytes), else Windows-1252 (Excel's "CSV"
    on Windows: a ``Kühlregal`` in a column btrun does not read must not refuse the file).
    Raises :class:`UnicodeDecodeError` (UTF-8's) for bytes none of them reads."""
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return data.decode("utf-16")
        except UnicodeDecodeError:
            pass
    head = data[:512]
    if len(head) >= 4 and head.count(0) * 4 >= len(head):  # UTF-16 saved without its mark
        little = head[1::2].count(0) >= head[0::2].count(0)
        try:
            return data.decode("utf-16-le" if little else "utf-16-be")
        except UnicodeDecodeError:
            pass
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        try:
            return data.decode("cp1252")
        except UnicodeDecodeError:
            raise exc from None


#: how an old binary Office file (an .xls workbook, a .doc) starts
_OLE2 = b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1"


class NotText(ValueError):
    """A file that is no text at all (an old .xls workbook): said as what it is."""


def not_text(data: bytes) -> str:
    """ "" for text-like ``data``; :class:`NotText` for an old binary Excel workbook (read as
    Windows-1252 it was a header error that printed its binary to the terminal)."""
    if data.startswith(_OLE2):
        raise NotText("an old binary Excel workbook (.xls): save it as .xlsx or CSV")
    return ""


def byte_loc(path: str, data: bytes, offset: int) -> Loc:
    """``path:line:col`` of byte ``offset`` of ``data`` (the column counted in bytes)."""
    line_start = data.rfind(b"\n", 0, offset) + 1
    return Loc(path, data.count(b"\n", 0, offset) + 1, offset - line_start + 1)


def entries_csv(path: str, text: str) -> tuple[list[Entry], list[Problem]]:
    """(place, pallet, where the place is, where the pallet is, status) per CSV row."""
    try:
        rows, delimiter = csv_rows(text)
    except csv.Error as exc:
        return [], [Problem(Loc(path, 1, 1), f"not a readable CSV file: {exc}")]
    if not rows:
        return [], [Problem(Loc(path, 1, 1), "the expected stock is empty: a header place,pallet")]
    header = [c.strip().lower() for c in rows[0].cells]
    if "place" not in header or "pallet" not in header:
        got = delimiter.join(rows[0].cells)[:80].replace("\t", "\\t")
        return [], [
            Problem(
                Loc(path, rows[0].line, 1),
                f"expected a header 'place,pallet' (as a WMS exports; a ';' or a tab between "
                f"the columns reads too), got '{got}'",
            )
        ]
    twice = [h for h in ("place", "pallet") if header.count(h) > 1]
    if twice:
        return [], [
            Problem(
                Loc(path, rows[0].line, 1),
                f"two '{twice[0]}' columns in the header: which one is meant cannot be told",
            )
        ]
    pc, qc = header.index("place"), header.index("pallet")
    sc = header.index("status") if "status" in header else None
    out: list[Entry] = []
    problems = []
    for row in rows[1:]:
        cells = row.cells
        if not any(c.strip() for c in cells):
            continue  # a blank line
        place = cells[pc].strip() if pc < len(cells) else ""
        pallet = cells[qc].strip() if qc < len(cells) else ""
        where_place = Loc(path, row.line, row.col(pc))
        where_pallet = Loc(path, row.line, row.col(qc))
        if not place:
            problems.append(Problem(where_place, "a row without a place (expected place,pallet)"))
            continue
        extra = [c for c in cells[len(header) :] if c.strip()]
        if extra:  # "A-01-1,Box, large,1001": every column after the stray one is shifted
            problems.append(
                Problem(
                    Loc(path, row.line, row.col(len(header))),
                    f"'{place}': {len(cells)} cells where the header has {len(header)} "
                    f"({extra[0].strip()[:30]!r} past its last column): a '{delimiter}' inside "
                    "a cell shifts the columns after it; put that cell in double quotes",
                )
            )
            continue
        if qc >= len(cells):  # not "A-01-1," (empty): a line cut short is no answer
            problems.append(
                Problem(
                    where_place,
                    f"'{place}': the row ends before its pallet column (write "
                    f"'{place}{delimiter}' for a place that should be empty)",
                )
            )
            continue
        status = cells[sc].strip() if sc is not None and sc < len(cells) else ""
        out.append((place, pallet, where_place, where_pallet, status))
    return out, problems


#: how a ZIP archive (an XLSX workbook) starts
ZIP_MAGIC = b"PK\x03\x04"
#: the header row is looked for in this many columns of an XLSX sheet
_XLSX_HEADER_COLUMNS = 50
#: ... and in this many rows (a report's title, date and blank lines above it)
_XLSX_HEADER_ROWS = 20


def _cell_text(value: Any) -> str:
    """A spreadsheet cell as the text a CSV export would hold (``1001`` for 1001.0)."""
    if value is None:
        return ""
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value).strip()


#: a spreadsheet keeps this many significant digits of a number: a number cell of more
#: digits (an 18-digit SSCC typed or imported as a number) is no longer the id it was
_EXACT_DIGITS = 15
_EXACT_DIGITS_BELOW = 10**_EXACT_DIGITS

#: what a spreadsheet shows for a formula that failed
_EXCEL_ERRORS = ("#N/A", "#REF!", "#DIV/0!", "#VALUE!", "#NAME?", "#NUM!", "#NULL!", "#SPILL!")


def _odd_cell(value: Any) -> str | None:
    """Why a spreadsheet cell is no name (a yes/no cell, a date, a fraction, a formula's
    error), else None."""
    import datetime

    if isinstance(value, bool):
        return f"a yes/no cell ({str(value).upper()}), not a name"
    if isinstance(value, (datetime.date, datetime.time, datetime.timedelta)):
        return f"a date or time cell ({value}), not a name"
    if isinstance(value, float) and not value.is_integer():
        return f"a number with a fraction ({value}), not a name"
    if isinstance(value, (int, float)) and abs(value) >= _EXACT_DIGITS_BELOW:
        digits = len(str(abs(int(value))))
        return (
            f"a number of {digits} digits ({_cell_text(value)}): a spreadsheet keeps "
            f"{_EXACT_DIGITS} significant digits, so a longer id (an SSCC) has lost its last "
            "ones; format the column as text and enter the ids again (or export them as text)"
        )
    if isinstance(value, str) and value.strip().upper() in _EXCEL_ERRORS:
        return f"a formula's error ({value.strip()}), not a name"
    return None


def _shown_sheet(wb: Any) -> Any:
    """The first sheet a spreadsheet shows (a hidden one before it is a lookup table)."""
    shown = [w for w in wb.worksheets if getattr(w, "sheet_state", "visible") == "visible"]
    return shown[0] if shown else wb.worksheets[0]


def xlsx_table(
    path: str,
    data: bytes,
    limit: int,
    needs: tuple[str, ...] = (),
    odd: dict[tuple[int, int], str] | None = None,
) -> tuple[str, list[str], list[tuple[int, list[str]]], list[Problem]]:
    """The first shown sheet of the XLSX workbook ``data`` (openpyxl; formulas by their saved
    results): its title, its header row (cells as text, trailing empty cells left out) and
    the non-blank rows below it as (row number, cells as text: ``1001`` for 1001.0) up to
    ``limit`` rows, only as many columns as the header has; or the problems (located at
    ``path``:1:1, or at the row past the limit). The header is the first of the sheet's
    first :data:`_XLSX_HEADER_ROWS` rows that holds every name of ``needs`` (any case): a
    WMS report may have a title and a date above it. Without one, it is the first row.
    ``odd`` (if given) gets (row, column from 0) -> why for each body cell that is no name
    (:func:`_odd_cell`)."""
    from openpyxl import load_workbook

    try:
        wb = load_workbook(io.BytesIO(data), read_only=True, data_only=True)
    except Exception as exc:  # a third party's parser of any file: one located line
        return "", [], [], [Problem(Loc(path, 1, 1), f"not a readable XLSX workbook: {exc}")]
    try:
        if not wb.worksheets:
            return "", [], [], [Problem(Loc(path, 1, 1), "the workbook has no sheet")]
        ws = _shown_sheet(wb)
        top = ws.iter_rows(
            values_only=True, max_col=_XLSX_HEADER_COLUMNS, max_row=_XLSX_HEADER_ROWS
        )
        found = [[_cell_text(c) for c in row] for row in top]
        at = next(
            (
                r
                for r, cells in enumerate(found, start=1)
                if needs and set(needs) <= {c.lower() for c in cells}
            ),
            1,
        )
        header = list(found[at - 1]) if found else []
        while header and not header[-1]:
            header.pop()
        rows: list[tuple[int, list[str]]] = []
        if not header:
            return ws.title, header, rows, []
        body = ws.iter_rows(min_row=at + 1, values_only=True, max_col=len(header))
        for i, row in enumerate(body, start=at + 1):
            if i > limit + at:
                return ws.title, header, rows, [Problem(Loc(path, i, 1), f"more than {limit} rows")]
            cells = [_cell_text(c) for c in row]
            if any(cells):
                rows.append((i, cells))
                if odd is not None:
                    for j, c in enumerate(row):
                        why = _odd_cell(c)
                        if why:
                            odd[(i, j)] = why
        return ws.title, header, rows, []
    except Exception as exc:  # a sheet openpyxl cannot read to the end
        return "", [], [], [Problem(Loc(path, 1, 1), f"not a readable XLSX workbook: {exc}")]
    finally:
        wb.close()


def cell_name(sheet: str, row: int, col: int) -> str:
    """A spreadsheet's name of a cell: ``Stock!B6`` (``'My stock'!AA10``)."""
    letters = ""
    while col > 0:
        col, rem = divmod(col - 1, 26)
        letters = chr(ord("A") + rem) + letters
    quoted = sheet if sheet.replace("_", "").isalnum() else "'" + sheet.replace("'", "''") + "'"
    return f"{quoted}!{letters}{row}"


def entries_xlsx(path: str, data: bytes) -> tuple[list[Entry], list[Problem], str]:
    """(place, pallet, where, where, status) per row of the first sheet of an XLSX
    workbook (as a WMS exports it: a header row with ``place`` and ``pallet``), located as
    ``file:row:column``, the problems, and the sheet's title (for :func:`with_cells`)."""
    odd: dict[tuple[int, int], str] = {}
    title, header, rows, problems = xlsx_table(
        path, data, MAX_EXPECTED_PLACES, ("place", "pallet"), odd
    )
    entries, problems = _xlsx_entries(path, data, title, header, rows, problems, odd)
    return entries, problems, title


def _xlsx_entries(
    path: str, data: bytes, title: str, header: list, rows: list, problems: list, odd: dict
) -> tuple[list[Entry], list[Problem]]:
    if problems and not rows:
        return [], problems
    names = [h.lower() for h in header]
    if "place" not in names or "pallet" not in names:
        return [], [
            Problem(
                Loc(path, 1, 1),
                f"expected a header row with 'place' and 'pallet' in the first "
                f"{_XLSX_HEADER_ROWS} rows of the first sheet ('{title}'), got "
                f"'{','.join(header)[:80]}'",
            )
        ]
    twice = [h for h in ("place", "pallet") if names.count(h) > 1]
    if twice:
        return [], [
            Problem(
                Loc(path, 1, 1),
                f"two '{twice[0]}' columns in the header row of sheet '{title}': which one is "
                "meant cannot be told",
            )
        ]
    pc, qc = names.index("place"), names.index("pallet")
    sc = names.index("status") if "status" in names else None
    unsaved = _unsaved_formulas(
        data, {i for i, cells in rows if not cells[qc : qc + 1] or not cells[qc]}, qc
    )
    merged = _merged_cells(data, {pc, qc})
    out: list[Entry] = []
    for i, cells in rows:
        place = cells[pc] if pc < len(cells) else ""
        pallet = cells[qc] if qc < len(cells) else ""
        if not place:
            problems.append(Problem(Loc(path, i, pc + 1), "a row without a place"))
            continue
        why = odd.get((i, pc)) or odd.get((i, qc))
        col = pc if (i, pc) in odd else qc
        for c in (pc, qc):
            if why is None and (i, c) in merged:
                col, why = (
                    c,
                    (
                        f"a merged cell ({merged[(i, c)]}): one value over several rows, which "
                        "only its first row holds (the others would read as empty places); "
                        "unmerge it and give each row its own value"
                    ),
                )
        if why is None and i in unsaved:
            why = (
                f"a formula without a saved result ({unsaved[i][:40]}): the workbook was "
                "written by a program, not saved by a spreadsheet; open and save it"
            )
        if why is not None:
            problems.append(Problem(Loc(path, i, col + 1), why))
            continue
        status = cells[sc] if sc is not None and sc < len(cells) else ""
        out.append((place, pallet, Loc(path, i, pc + 1), Loc(path, i, qc + 1), status))
    return out, problems


def with_cells(path: str, sheet: str, problems: list[Problem]) -> list[Problem]:
    """``problems`` located in sheet ``sheet`` of the workbook ``path`` with the cell's name
    added to their message (``... (cell Stock!B6)``): a spreadsheet user looks for a cell,
    not a line."""
    if not sheet:
        return problems
    return [
        Problem(p.loc, f"{p.message} (cell {cell_name(sheet, p.loc.line, p.loc.col)})", p.severity)
        if p.loc.file == path and p.loc.line > 0 and p.loc.col > 0
        else p
        for p in problems
    ]


def _merged_cells(data: bytes, cols: set[int]) -> dict[tuple[int, int], str]:
    """(row, column from 0) -> the range (``C16:C17``) of every cell of the first shown
    sheet in columns ``cols`` that a merged range spanning more than one row covers: a
    spreadsheet shows the value on every row, openpyxl gives it to the first cell only."""
    from openpyxl import load_workbook
    from openpyxl.utils.cell import range_boundaries

    found: dict[tuple[int, int], str] = {}
    try:
        wb = load_workbook(io.BytesIO(data), read_only=True, data_only=True)
        try:
            ws = _shown_sheet(wb)
            with wb._archive.open(ws._worksheet_path) as f:  # read-only sheets hide them
                xml = f.read()
        finally:
            wb.close()
    except Exception:  # noqa: BLE001 - read once already; this pass only adds a reason
        return found
    for ref in re.findall(rb'<(?:\w+:)?mergeCell\s+ref="([A-Z]+[0-9]+:[A-Z]+[0-9]+)"', xml):
        text = ref.decode()
        c0, r0, c1, r1 = range_boundaries(text)
        if r1 == r0:
            continue
        for c in range(c0 - 1, c1):
            if c in cols:
                for r in range(r0, r1 + 1):
                    found[(r, c)] = text
    return found


def _unsaved_formulas(data: bytes, rows: set[int], col: int) -> dict[int, str]:
    """Row -> formula of the first sheet's cells in column ``col`` (from 0) of ``rows``
    that hold a formula: read as values they are empty when no spreadsheet saved their
    result, and an empty pallet means "this place should be empty"."""
    if not rows:
        return {}
    from openpyxl import load_workbook

    found: dict[int, str] = {}
    try:
        wb = load_workbook(io.BytesIO(data), read_only=True, data_only=False)
        try:
            ws = _shown_sheet(wb)
            body = ws.iter_rows(min_row=min(rows), max_row=max(rows), values_only=True)
            for i, row in enumerate(body, start=min(rows)):
                v = row[col] if col < len(row) else None
                if i in rows and isinstance(v, str) and v.startswith("="):
                    found[i] = v
        finally:
            wb.close()
    except Exception:  # noqa: BLE001 - read once already; this pass only adds a reason
        return found
    return found
