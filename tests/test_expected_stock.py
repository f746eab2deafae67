"""Expected stock (a WMS export) and the discrepancy report (issue 28).

The expected stock is read and checked before flight, every problem located; each
inventory row becomes a discrepancy row in one of the categories; a scan is verified 1:1
against the pallet expected at its place before it is identified, and a look-alike of that
pallet does not verify; the inventory mission writes discrepancies.csv / .json in which
every injected discrepancy is reported in its category and agreeing places are confirmed.
"""

from __future__ import annotations

import csv
import json
import os

import pytest
from helpers import REPO

from bt_engine.spec import Loc
from drivers.rig.loader import load_rig
from nodes.discrepancy import categorise, counts_line, discrepancy_rows, grade_rows
from nodes.expected_stock import ExpectedStock, read_expected
from nodes.inventory_log import InventoryLog
from perception.expected import pallet_of, pallet_rank, sides_of

RIG = os.path.join(REPO, "rigs", "aisle.yaml")
MISSION = os.path.join(REPO, "missions", "inventory.xml")
WHERE = Loc("--set", 0, 0)


@pytest.fixture(scope="module")
def world():
    return load_rig(RIG).load_world(0)


def _read(tmp_path, name: str, text: str, world):
    path = tmp_path / name
    path.write_text(text)
    return read_expected(str(path), world, WHERE)


# -- reading and checking the expected stock ---------------------------------------------


def test_a_wms_csv_is_read_with_empty_places(tmp_path, world):
    stock, problems = _read(tmp_path, "s.csv", "place,pallet\nA-01-1,109\nA-01-2,\n", world)
    assert problems == []
    assert stock.places == {"A-01-1": "109", "A-01-2": None}
    assert stock.at("A-01-1") == "109" and stock.at("A-01-2") == "" and stock.at("A-02-1") is None
    assert stock.place_of("109B") == "A-01-1" and stock.place_of("110") is None


def test_a_whole_warehouse_export_reads_this_worlds_racks_only(tmp_path, world):
    # a WMS exports every zone; the aisle world has rack A only
    text = "place,pallet\nA-01-1,109\nK-01-1,PAL/2026/7\nK-01-2,\nZZ-44-3,110\nA-01-2,\n"
    stock, problems = _read(tmp_path, "s.csv", text, world)
    assert problems == []
    assert stock.places == {"A-01-1": "109", "A-01-2": None}
    assert stock.outside == 3 and stock.source()["rows_outside_world"] == 3
    assert "3 rows of racks K, ZZ, which this world does not have, left out" in (stock.outside_note)
    # a pallet the WMS has in another zone, found here: moved from there
    assert stock.place_of("pal/2026/7") == "K-01-1" and stock.place_of("110B") == "ZZ-44-3"
    assert stock.at("K-01-1") is None  # no expectation of this world


@pytest.mark.parametrize(
    "text, where, message",
    [
        # no row of this world at all: another site's file, not a zone of this one
        ("place,pallet\nK-01-1,1\nK-02-1,\n", (2, 1), "no row names a place of this world (its racks: A); the file names 2 places of rack K"),
        # this world's rack, a place it does not have: a typo, refused as before
        ("place,pallet\nA-01-1,1\nA-19-1,2\nK-01-1,3\n", (3, 1), "unknown place 'A-19-1'"),
        ("place,pallet\na-01-1,1\nK-01-1,3\n", (2, 1), "unknown place 'a-01-1' (did you mean 'A-01-1'?)"),
    ],
)  # fmt: skip
def test_rows_of_other_racks_never_hide_a_typo(tmp_path, world, text, where, message):
    _, problems = _read(tmp_path, "s.csv", text, world)
    assert len(problems) == 1, problems
    assert (problems[0].loc.line, problems[0].loc.col) == where
    assert message in problems[0].message


@pytest.mark.parametrize("delimiter", [";", "\t"])
def test_a_csv_with_semicolons_or_tabs_reads_as_with_commas(tmp_path, world, delimiter):
    """What a spreadsheet saves as CSV where the decimal mark is a comma (``place;pallet``),
    or a tab-separated export: the same stock, problems located alike."""
    text = f"Place{delimiter}Pallet\nA-01-1{delimiter}109\nA-01-2{delimiter}\nA-1-3{delimiter}5\n"
    stock, problems = _read(tmp_path, "s.csv", text, world)
    assert stock is None or stock.places.get("A-01-1") == "109"
    assert [(p.loc.line, p.loc.col) for p in problems] == [(4, 1)]
    assert "unknown place 'A-1-3'" in problems[0].message
    good = text.rsplit("A-1-3", 1)[0]
    stock, problems = _read(tmp_path, "s.csv", good, world)
    assert problems == [] and stock.places == {"A-01-1": "109", "A-01-2": None}


@pytest.mark.parametrize(
    "encoding, text",
    [
        ("utf-16", "Place\tPallet\tNote\nA-01-1\t109\tK\u00fchlregal\nA-1-3\t5\t\n"),
        ("cp1252", "Place;Pallet;Note\r\nA-01-1;109;K\u00fchlregal\r\nA-1-3;5;\r\n"),
        ("utf-8", "sep=;\nPlace;Pallet\nA-01-1;109\nA-1-3;5\n"),
        # UTF-16 without its byte order mark (a refused header full of NUL bytes before)
        ("utf-16-le", "place,pallet,note\nA-01-1,109,K\u00fchlregal\nA-1-3,5,\n"),
        ("utf-16-be", "place,pallet,note\nA-01-1,109,K\u00fchlregal\nA-1-3,5,\n"),
    ],
)
def test_what_excel_saves_reads_as_a_utf8_csv(tmp_path, world, encoding, text):
    """Excel's "Unicode Text" (UTF-16 with its byte order mark, tabs), its "CSV" on Windows
    (Windows-1252: a 'Kühlregal' in a column btrun does not read refused the file as "not
    UTF-8") and its ``sep=;`` first line read as the UTF-8 CSV does, located alike."""
    (tmp_path / "s.csv").write_bytes(text.encode(encoding))
    stock, problems = read_expected(str(tmp_path / "s.csv"), world, WHERE)
    line = 4 if text.startswith("sep=") else 3
    assert [(p.loc.line, p.loc.col) for p in problems] == [(line, 1)], problems
    assert "unknown place 'A-1-3'" in problems[0].message
    good = text.rsplit("A-1-3", 1)[0]
    (tmp_path / "s.csv").write_bytes(good.encode(encoding))
    stock, problems = read_expected(str(tmp_path / "s.csv"), world, WHERE)
    assert problems == [] and stock.places == {"A-01-1": "109"}


def test_problems_in_quoted_cells_are_located_where_an_editor_shows_them(tmp_path, world):
    """A WMS that quotes every cell, or a note with a comma or a line break in it: the
    column and line are the file's (they were counted from the cells' unquoted text and
    one line per row: col 8 for the pallet of '"A-01-1","109"')."""
    text = (
        '"place","pallet","note"\n'
        '"A-01-1","109","two lines:\nsecond"\n'
        '"A-01-2","109",""\n'
        '"note, with a comma","x",""\n'
    )
    _, problems = _read(tmp_path, "s.csv", text, world)
    assert [(p.loc.line, p.loc.col) for p in problems] == [(4, 10), (5, 1)], problems
    assert "pallet '109' expected at two places" in problems[0].message
    assert "unknown place 'note, with a comma'" in problems[1].message


def test_the_same_as_json_in_three_shapes(tmp_path, world):
    rows = '[{"place": "A-01-1", "pallet": "109"}, {"place": "A-01-2", "pallet": null}]'
    for text in (rows, '{"rows": ' + rows + "}", '{"A-01-1": "109", "A-01-2": null}'):
        stock, problems = _read(tmp_path, "s.json", text, world)
        assert problems == [] and stock.places == {"A-01-1": "109", "A-01-2": None}, text


@pytest.mark.parametrize(
    "name, text, where, message",
    [
        ("s.csv", "place,pallet\nA-01-1,109\nA-1-2,3\n", (3, 1), "unknown place 'A-1-2' (did you mean 'A-01-2'?)"),
        ("s.csv", "place,pallet\nA-01-1,109\na-02-1,3\n", (3, 1), "unknown place 'a-02-1' (did you mean 'A-02-1'?"),
        ("s.csv", "place,pallet\nA-01-1,109\nA-01-1,3\n", (3, 1), "place 'A-01-1' listed twice (first at line 2)"),
        ("s.csv", "place,pallet\nA-01-1,109\nA-02-1,109B\n", (3, 8), "pallet '109' (written '109' and '109B') expected at two places: A-01-1 (line 2)"),
        ("s.csv", "place,pallet\nA-01-1,PAL7A\nA-02-1,PAL7B\n", (3, 8), "'PAL7A' and 'PAL7B' are read as two sides of one pallet 'PAL7'"),
        ("s.csv", "location,pallet_id\nA-01-1,109\n", (1, 1), "expected a header 'place,pallet'"),
        ("s.csv", "", (1, 1), "the expected stock is empty"),
        ("s.json", '{"A-01-1": "109",\n "A-01-2": ', (2, 12), "not JSON"),
        ("s.json", '[{"place": "A-01-1", "pallet": "1"},\n {"place": "A-19-1", "pallet": "3"}]', (2, 2), "unknown place 'A-19-1'"),
        ("s.json", '[{"place": "A-01-1", "pallet": [1]}]', (1, 2), "pallet must be text or null"),
        # objects are said as the file wrote them, not as Python's [('x', 1)]
        ("s.json", '[{"place": "A-01-1", "pallet": {"x": 1}}]', (1, 2), 'pallet must be text or null, got {"x": 1}'),
        ("s.json", '[{"place": null, "pallet": "1"}]', (1, 2), 'with the place as text, got {"place": null, "pallet": "1"}'),
        # a line cut short is no "should be empty" (that is "A-01-1,"); nor is a JSON true
        ("s.csv", "place,pallet\nA-01-2,\nA-01-1\n", (3, 1), "'A-01-1': the row ends before its pallet column (write 'A-01-1,'"),
        ("s.csv", "place;pallet\nA-01-1\n", (2, 1), "(write 'A-01-1;' for a place that should be empty)"),
        ("s.json", '[{"place": "A-01-1", "pallet": true}]', (1, 2), "pallet must be text or null, got true"),
        ("s.json", '{"A-01-1": false}', (1, 2), "A-01-1: pallet must be text or null, got false"),
        # commas inside a quoted header cell of a semicolon file: split at the semicolons
        ("s.csv", 'place;pallet;"a,b,c,d"\nA-01-1;109;x\nA-1-2;3;y\n', (3, 1), "unknown place 'A-1-2'"),
        # a separator inside an unquoted cell shifts the pallet column: refused, not misread;
        # empty cells past the header (a spreadsheet's export) are fine
        ("s.csv", "place,note,pallet\nA-01-2,ok,109,,\nA-01-1,Box, large,110\n", (3, 19), "'A-01-1': 4 cells where the header has 3 ('110' past its last column)"),
    ],
)  # fmt: skip
def test_every_problem_is_located_in_the_file(tmp_path, world, name, text, where, message):
    _, problems = _read(tmp_path, name, text, world)
    assert len(problems) == 1, problems
    p = problems[0]
    assert (p.loc.file, p.loc.line, p.loc.col) == (str(tmp_path / name), *where)
    assert message in p.message


def _xlsx(path, rows: list[list]) -> str:
    from openpyxl import Workbook

    wb = Workbook()
    ws = wb.active
    ws.title = "Stock"
    for row in rows:
        ws.append(row)
    wb.save(path)
    return str(path)


def test_a_wms_xlsx_is_read_as_its_csv_would_be(tmp_path, world):
    """A workbook as a WMS exports it (header row in any case and order, numbers as
    numbers, an empty cell for an empty place, blank rows) reads as the CSV; problems are
    located at row:column of its first sheet."""
    rows = [["Pallet", "Place", "note"], [109, "A-01-1", "x"], [None, "A-01-2"], [], [110.0, "A-02-1"]]  # fmt: skip
    stock, problems = read_expected(_xlsx(tmp_path / "s.xlsx", rows), world, WHERE)
    assert problems == []
    assert stock.places == {"A-01-1": "109", "A-01-2": None, "A-02-1": "110"}
    bad = [["place", "pallet"], ["A-01-1", 109], ["A-1-2", 3], ["A-02-1", "109B"], [None, 4]]
    path = _xlsx(tmp_path / "bad.xlsx", bad)
    _, problems = read_expected(path, world, WHERE)
    got = sorted((p.loc.line, p.loc.col, p.message.split(" (")[0]) for p in problems)
    assert got == [
        (3, 1, "unknown place 'A-1-2'"),
        (4, 2, "pallet '109'"),
        (5, 1, "a row without a place"),
    ]
    assert all(p.loc.file == path for p in problems)


def test_xlsx_cells_that_are_no_pallet_name_are_refused(tmp_path, world):
    """A formula whose result no spreadsheet saved reads as an empty cell, i.e. "this place
    should be empty": a false `unexpected` for the pallet found there. Error cells, yes/no
    cells, dates and fractions were taken as pallet names. Columns not read may hold
    anything."""
    import datetime

    rows = [
        ["place", "pallet", "checked"],
        ["A-01-1", "=VLOOKUP(A2,Sheet2!A:B,2,0)", datetime.date(2026, 11, 1)],
        ["A-01-2", "#N/A"],
        ["A-02-1", True],
        ["A-02-2", 109.5],
        ["A-03-1", datetime.datetime(2026, 1, 2)],
        ["A-03-2", None, True],
        ["A-04-1", 104, "#REF!"],
    ]
    _, problems = read_expected(_xlsx(tmp_path / "s.xlsx", rows), world, WHERE)
    assert [(p.loc.line, p.loc.col, p.message.split(" (")[0]) for p in problems] == [
        (2, 2, "a formula without a saved result"),
        (3, 2, "a formula's error"),
        (4, 2, "a yes/no cell"),
        (5, 2, "a number with a fraction"),
        (6, 2, "a date or time cell"),
    ]
    assert "open and save it" in problems[0].message
    # a spreadsheet user looks for a cell: each problem names it as the spreadsheet does
    assert [p.message.rsplit(" (cell ", 1)[1] for p in problems] == [
        "Stock!B2)",
        "Stock!B3)",
        "Stock!B4)",
        "Stock!B5)",
        "Stock!B6)",
    ]
    from nodes.stock_files import cell_name

    assert cell_name("My stock", 10, 27) == "'My stock'!AA10"


def test_a_wrong_file_says_its_first_problems_only(tmp_path, world):
    text = "place,pallet\n" + "".join(f"A-{i:04d}-9,{i}\n" for i in range(2000))
    _, problems = _read(tmp_path, "s.csv", text, world)
    assert len(problems) == 51 and problems[-1].message == "... and 1950 more problems in this file"


def test_an_xlsx_report_with_a_title_above_its_header(tmp_path, world):
    """A WMS report often puts a title and a date above the table: the header row is
    looked for in the first rows, and problems keep the sheet's own row numbers."""
    rows = [["Stock report"], ["2026-11-27"], [], ["Place", "Pallet"], ["A-01-1", 109], ["A-1-2", 3]]  # fmt: skip
    stock, problems = read_expected(_xlsx(tmp_path / "s.xlsx", rows), world, WHERE)
    assert [(p.loc.line, p.loc.col) for p in problems] == [(6, 1)], problems
    stock, problems = read_expected(_xlsx(tmp_path / "s.xlsx", rows[:5]), world, WHERE)
    assert problems == [] and stock.places == {"A-01-1": "109"}


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("s.xlsx", b"place,pallet\nA-01-1,1\n", "not a readable XLSX workbook"),
        ("s.csv", b"PK\x03\x04 a zip", "not a readable XLSX workbook"),
        (
            "s.csv",
            b"place,pallet\nA-01-1,\x81\x8d\n",  # no UTF-8, and bytes Windows-1252 lacks
            "2:8: not UTF-8, UTF-16 or Windows-1252 text: expected CSV, JSON or an XLSX",
        ),
        (  # an old binary workbook: read as Windows-1252 it printed its bytes as a header
            "s.xls",
            b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(range(256)) * 4,
            "1:1: an old binary Excel workbook (.xls): save it as .xlsx or CSV",
        ),
    ],
)
def test_a_file_that_is_no_stock_says_what_was_expected(tmp_path, world, name, content, message):
    (tmp_path / name).write_bytes(content)
    _, problems = read_expected(str(tmp_path / name), world, WHERE)
    assert len(problems) == 1
    p = problems[0]
    assert message in f"{p.loc.line}:{p.loc.col}: {p.message}" or message in p.message
    if message[:1].isdigit():  # located in the file, where an editor shows it
        assert p.loc.file == str(tmp_path / name)


def test_an_xlsx_without_the_header_names_its_sheet(tmp_path, world):
    path = _xlsx(tmp_path / "s.xlsx", [["location", "id"], ["A-01-1", 1]])
    _, problems = read_expected(path, world, WHERE)
    (p,) = problems
    assert (p.loc.line, p.loc.col) == (1, 1)
    assert (
        "header row with 'place' and 'pallet' in the first 20 rows of the first sheet ('Stock')"
        in p.message
    )


def test_a_missing_file_is_reported_at_the_input(tmp_path, world):
    stock, problems = read_expected(str(tmp_path / "nope.csv"), world, WHERE)
    assert stock is None and problems[0].loc == WHERE
    assert "expected stock" in problems[0].message and "nope.csv" in problems[0].message
    assert read_expected("", world, WHERE) == (None, [])


def test_btrun_refuses_a_bad_expected_stock_before_anything_flies(tmp_path, capsys):
    from bt_engine.cli import main

    bad = tmp_path / "stock.csv"
    bad.write_text("place,pallet\nA-01-1,109\nA-01-1,110\nA-09-9,\n")
    code = main([MISSION, "--rig", RIG, "--set", f"expected={bad}", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code != 0
    assert f"{bad}:3:1: place 'A-01-1' listed twice" in err
    assert f"{bad}:4:1: unknown place 'A-09-9'" in err
    assert not (tmp_path / "r" / "ticks.jsonl").exists()


# -- categories -----------------------------------------------------------------------------


def test_pallets_and_sides():
    assert pallet_of("103B") == "103" and pallet_of("7A") == "7" and pallet_of("PAL-X") == "PAL-X"
    assert sides_of(["103A", "103B", "1103A", "10A"], "103") == ["103A", "103B"]
    assert sides_of(["103A", "103B"], "103B") == ["103A", "103B"]
    # a WMS's or a spreadsheet's zero padding names the same pallet (it was a mismatch)
    assert pallet_of("0111") == pallet_of("00111B") == "111" and pallet_of("000") == "0"
    assert sides_of(["111A", "111B", "1110A"], "0111") == ["111A", "111B"]
    ranking = [("5A", 0.3, ()), ("5B", 0.31, ()), ("7A", 0.4, ()), ("9B", 0.5, ())]
    assert pallet_rank(ranking, "7")[0] == 2 and pallet_rank(ranking, "8") == (None, None)


@pytest.mark.parametrize(
    "expected, answer, category, found",
    [
        ("103", "103B", "confirmed", "103"),
        ("103A", "103B", "confirmed", "103"),  # the other side of the same pallet
        ("", "empty", "confirmed", "empty"),
        ("103", "104A", "mismatch", "104"),
        ("103", "empty", "missing", "empty"),
        ("", "104A", "unexpected", "104"),
        ("", "unknown", "unexpected", "unknown"),
        ("103", "unknown", "unverified", "unknown"),  # unknown where a pallet is expected
        ("103", "", "not_scanned", ""),
        ("0103", "103B", "confirmed", "103"),
        (None, "104A", "unlisted", "104"),
    ],
)
def test_categories(expected, answer, category, found):
    assert categorise(expected, answer) == (category, found)


def _stock(places: dict) -> ExpectedStock:
    return ExpectedStock("stock.csv", dict(places))


def test_discrepancy_rows_name_where_a_found_pallet_was_expected():
    stock = _stock({"A-01-1": "101", "A-01-2": "102", "A-02-1": None, "A-02-2": "104"})
    rows = [
        {"place": "A-01-1", "answer": "102A", "status": "identified"},  # swapped
        {"place": "A-01-2", "answer": "101B", "status": "identified", "decided_by": "texture"},
        {"place": "A-02-1", "answer": "104A", "status": "identified"},  # moved here
        {"place": "A-02-2", "answer": "empty", "status": "empty"},
    ]
    out = {r["place"]: r for r in discrepancy_rows(rows, stock)}
    assert out["A-01-1"]["category"] == "mismatch" and out["A-01-1"]["moved_from"] == "A-01-2"
    assert out["A-01-2"]["moved_from"] == "A-01-1"
    assert (out["A-02-1"]["category"], out["A-02-1"]["found"]) == ("unexpected", "104")
    # an unexpected pallet the stock expects elsewhere says where (the operator matched the
    # 'missing' A-02-2 and the 'unexpected' A-02-1 by hand)
    assert out["A-02-1"]["moved_from"] == "A-02-2"
    assert out["A-02-2"]["category"] == "missing"


def test_grading_against_the_ground_truth():
    stock = _stock({"A-01-1": "101", "A-01-2": "102", "A-02-1": None, "A-02-2": "115"})
    truth = ({"A-01-1": "101A", "A-01-2": "103B", "A-02-1": None, "A-02-2": "115A"}, {"115A"})
    rows = [
        {"place": "A-01-1", "answer": "101A"},  # confirmed, right
        {"place": "A-01-2", "answer": "unknown"},  # should be mismatch (103): missed
        {"place": "A-02-1", "answer": "unknown"},  # should be confirmed: a false alarm
        {"place": "A-02-2", "answer": "unknown"},  # 115 is not enrolled: unverified, right
    ]
    g = grade_rows(discrepancy_rows(rows, stock), stock, truth)
    assert g["grades"] == {
        "A-01-1": "right",
        "A-01-2": "wrong",
        "A-02-1": "wrong",
        "A-02-2": "right",
    }
    assert g["false_alarms"] == ["A-02-1"] and g["missed"] == ["A-01-2"]


def test_the_log_writes_the_report_and_leads_with_the_counts(tmp_path):
    log = InventoryLog(str(tmp_path), drone="cf1")
    log.expected = _stock({"A-01-1": "101", "A-01-2": None, "A-02-1": "102"})
    log.plan(["A-01-1", "A-01-2", "A-02-1"])
    assert log.expected_at("A-01-1") == "101" and log.expected_at("A-01-2") == ""
    assert log.expected_at("A-09-9") is None
    log.record(
        {"place": "A-01-1", "answer": "101A", "status": "identified", "decided_by": "verified"}
    )
    log.record({"place": "A-01-2", "answer": "103B", "status": "identified"})
    with open(tmp_path / "discrepancies.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["place"] for r in rows] == ["A-01-1", "A-01-2", "A-02-1"]  # not scanned yet too
    assert [r["category"] for r in rows] == ["confirmed", "unexpected", "not_scanned"]
    assert rows[0]["verified"] == "true" and list(rows[0])[:4] == [
        "place",
        "expected",
        "found",
        "category",
    ]
    doc = json.loads((tmp_path / "discrepancies.json").read_text())
    assert doc["counts"]["confirmed"] == 1 and doc["counts"]["unexpected"] == 1
    lines = log.result_lines()
    assert lines[0] == counts_line(log.run_summary()["discrepancies"])
    assert lines[0].startswith("discrepancies: 1 confirmed, 0 mismatch, 0 missing, 1 unexpected")


def test_the_run_folders_csv_files_never_hold_a_formula(tmp_path):
    """A WMS cell "=HYPERLINK(...)" (or a gallery identity "=cmd|...") went into the run
    folder's discrepancies.csv and inventory.csv as it was: a spreadsheet opening them runs
    it. Text cells are written as the console's exports write them; the JSON keeps them."""
    log = InventoryLog(str(tmp_path), drone="cf1")
    log.expected = _stock({"A-01-1": '=HYPERLINK("http://x","y")', "A-01-2": None})
    log.plan(["A-01-1", "A-01-2"])
    log.record({"place": "A-01-1", "answer": "unknown", "status": "unknown"})
    log.record({"place": "A-01-2", "answer": "=cmd|' calc'!A0", "status": "identified"})
    with open(tmp_path / "discrepancies.csv", newline="") as f:
        disc = {r["place"]: r for r in csv.DictReader(f)}
    assert disc["A-01-1"]["expected"] == '\'=HYPERLINK("http://x","y")'
    with open(tmp_path / "inventory.csv", newline="") as f:
        inv = {r["place"]: r for r in csv.DictReader(f)}
    assert inv["A-01-2"]["answer"] == "'=cmd|' calc'!A0"
    doc = json.loads((tmp_path / "inventory.json").read_text())
    assert doc["rows"][1]["answer"] == "=cmd|' calc'!A0"  # as recorded


def test_a_fleets_merged_folder_gets_the_report_too(tmp_path):
    merged = InventoryLog(str(tmp_path / "fleet"), drone="fleet")
    drone = InventoryLog(
        str(tmp_path / "fleet" / "drones" / "cf1"), drone="cf1", sink=merged.absorb
    )
    drone.expected = _stock({"A-01-1": "101", "A-01-2": "102"})
    drone.plan(["A-01-1", "A-01-2"])
    drone.record({"place": "A-01-1", "answer": "102B", "status": "identified"})
    with open(tmp_path / "fleet" / "discrepancies.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["place"], r["category"], r["moved_from"]) for r in rows] == [
        ("A-01-1", "mismatch", "A-01-2"),
        ("A-01-2", "not_scanned", ""),
    ]
    assert merged.run_summary()["discrepancies"]["mismatch"] == 1


def test_without_an_expected_stock_nothing_changes(tmp_path):
    log = InventoryLog(str(tmp_path))
    log.plan(["A-01-1"])
    log.record({"place": "A-01-1", "answer": "101A", "status": "identified"})
    assert not (tmp_path / "discrepancies.csv").exists()
    assert "discrepancies" not in log.run_summary()
    assert log.result_lines()[0].startswith("inventory: 1 place, 1 identified")


# -- verification against the expected pallet ----------------------------------------------


@pytest.mark.slow
def test_a_look_alike_of_the_expected_pallet_does_not_verify():
    """Rendered through the mission's detector and embedder: the expected pallet verifies
    1:1 (also aged), a look-alike of it standing where it should be (the same wood, stamp
    and wear, other grain) does not, nor does another enrolled pallet; the answer for the
    look-alike is never the expected pallet."""
    import numpy as np

    import perception.robustness as rb
    from nodes.identify import identify_described
    from perception.detector import BlockDetector
    from perception.embedder import BlockEmbedder
    from perception.expected import check_expected
    from perception.synth.ageing import Ageing
    from perception.synth.appearance import SideStyle

    pipe = rb.Pipeline(BlockDetector.load(), BlockEmbedder.load())
    names = ["lk0001A", "lk0001B", "lk0002A", "lk0002B", "lk0003A", "lk0003B"]
    g, n, _ = rb.enrol_gallery(pipe, names, rb.Condition("t", "clean"), seed=5)
    assert n == len(names)
    rng = np.random.default_rng(11)

    def scan(name: str, seed: int, ageing=None):
        style = SideStyle(texture_seed=rb.SEED0 + seed, ageing=ageing)
        s = pipe.scan(name, style, rng)
        assert s.complete
        vec, vis = pipe.describe(s.crops)
        return vec, vis, s.crops

    genuine = scan("lk0002A", 2, Ageing(stains=0.12, seed=3))  # enrolled as index 2
    assert check_expected(g, *genuine, "lk0002").verified
    twin = scan("lk0002A", 60_000)  # same pallet id and side: same look, other grain
    check = check_expected(g, *twin, "lk0002")
    assert not check.verified and check.reason.startswith("not lk0002")
    answer = identify_described(g, *twin, g.thresholds, expected="lk0002")
    assert not answer.verified_expected and not answer.pallet_id.startswith("lk0002")
    other = scan("lk0003B", 5)
    assert not check_expected(g, *other, "lk0002").verified
    assert identify_described(g, *other, g.thresholds, expected="lk0002").pallet_id in (
        "lk0003B",
        "unknown",
    )


# -- the mission, end to end ------------------------------------------------------------


def _injected(world) -> tuple[list[str], dict[str, str | None], dict[str, str]]:
    """(places to fly, expected stock, the category each flown place must get) built from
    the world's ground truth with a swap, a missing, an unexpected and a moved pallet, an
    unverifiable one (not enrolled) and agreeing places."""
    truth, ne = world.places_truth(), set(world.not_enrolled())
    full = [p for p, t in truth.items() if t and t not in ne]
    empty = [p for p, t in truth.items() if t is None]
    unknown = [p for p, t in truth.items() if t in ne]
    placed = {pallet_of(t) for t in truth.values() if t}
    spare = [
        i for i in sorted({pallet_of(i) for i in world.enrolled_identities()}) if i not in placed
    ]
    pal = {p: pallet_of(truth[p]) for p in full}
    same, swap_a, swap_b, moved, unexpected = full[:5]
    far = "K-07-3"  # a whole-warehouse export: a place of another zone, left out
    expected: dict[str, str | None] = {
        same: pal[same],
        swap_a: pal[swap_b],
        swap_b: pal[swap_a],
        moved: spare[0],  # expected another pallet; its own is expected at `far`
        far: pal[moved],  # (not in this world)
        unexpected: None,
        empty[0]: spare[1],  # expected a pallet, empty
        empty[1]: None,  # expected empty, empty
        unknown[0]: pallet_of(truth[unknown[0]]),  # a pallet the gallery does not enrol
    }
    want = {
        same: "confirmed",
        swap_a: "mismatch",
        swap_b: "mismatch",
        moved: "mismatch",
        unexpected: "unexpected",
        empty[0]: "missing",
        empty[1]: "confirmed",
        unknown[0]: "unverified",
    }
    return list(want), expected, want


@pytest.mark.slow
def test_the_mission_reports_every_injected_discrepancy(tmp_path, world, capsys):
    from bt_engine.cli import main

    places, expected, want = _injected(world)
    stock = tmp_path / "stock.csv"
    stock.write_text("place,pallet\n" + "".join(f"{p},{q or ''}\n" for p, q in expected.items()))
    out = tmp_path / "run"
    code = main(
        [MISSION, "--rig", RIG, "--out", str(out), "--set", f"expected={stock}",
         "--set", "places=" + ";".join(places)]
    )  # fmt: skip
    printed = capsys.readouterr().out
    assert code == 0, printed
    with open(out / "discrepancies.csv", newline="") as f:
        rows = {r["place"]: r for r in csv.DictReader(f)}
    assert {p: r["category"] for p, r in rows.items()} == want
    truth = world.places_truth()
    swap_a, swap_b, moved = [p for p, c in want.items() if c == "mismatch"]
    assert rows[swap_a]["moved_from"] == swap_b and rows[swap_b]["moved_from"] == swap_a
    far = next(p for p, q in expected.items() if p not in want and q)
    assert rows[moved]["found"] == pallet_of(truth[moved]) and rows[moved]["moved_from"] == far
    summary = json.loads((out / "summary.json").read_text())
    ids = summary["perception"]["identifications"]
    verified = {r.get("pallet_id") for r in ids if r.get("verified_expected")}
    same = next(p for p, c in want.items() if c == "confirmed" and truth[p])
    assert truth[same] in verified  # the agreeing pallet was verified 1:1, not searched
    inv = summary["inventory"]
    assert inv["discrepancies"]["mismatch"] == 3 and inv["wrong"] == 0
    # the one expected pallet the gallery does not enrol is said before and after
    unknown = next(p for p, c in want.items() if c == "unverified")
    assert inv["expected_not_enrolled"] == {"count": 1, "pallets": [expected[unknown]]}
    assert "expected stock: 1 of 6 expected pallets not in the gallery" in printed
    assert "1 row of rack K, which this world does not have, left out" in printed
    g = inv["discrepancy_grades"]
    assert g["wrong"] == 0 and g["false_alarms"] == [] and g["missed"] == []
    lines = printed.splitlines()
    after = lines[next(i for i, ln in enumerate(lines) if ln.startswith("SUCCESS")) + 1 :]
    result = [ln for ln in after if not ln.startswith("pallet")]
    assert result[0].startswith("discrepancies: 2 confirmed, 3 mismatch, 1 missing, 1 unexpected")
    from nodes.report.html import answer_section
    from nodes.report.inventory import inventory_section

    answer = answer_section(summary)
    assert answer.index("discrepancies: 2 confirmed") < answer.index("inventory: 8 places")
    section = inventory_section(str(tmp_path), summary)
    assert section.index("Discrepancies against the expected stock") < section.index("<img")


def test_odd_headers_sheets_and_names(tmp_path, world):
    """Two 'place' columns (the first one won), a control character in a name, a hidden
    lookup sheet before the stock (it was read), more rows than a stock may have (cut
    without a word)."""
    from openpyxl import Workbook

    _, problems = _read(tmp_path, "a.csv", "place,pallet,place\nA-01-1,109,A-02-1\n", world)
    assert [p.message for p in problems] == [
        "two 'place' columns in the header: which one is meant cannot be told"
    ]
    _, problems = _read(tmp_path, "b.csv", "place,pallet\nA-01-1,10\x009\n", world)
    assert [(p.loc.line, p.message) for p in problems] == [
        (2, "a control character in '10\\x009': not a name")
    ]
    wb = Workbook()
    wb.active.title = "lookup"
    wb.active.append(["place", "pallet"])
    wb.active.append(["A-01-1", 999])
    wb.active.sheet_state = "hidden"
    stock_sheet = wb.create_sheet("Stock")
    stock_sheet.append(["place", "pallet"])
    stock_sheet.append(["A-01-1", 109])
    wb.active = 1
    wb.save(tmp_path / "s.xlsx")
    stock, problems = read_expected(str(tmp_path / "s.xlsx"), world, WHERE)
    assert problems == [] and stock.places == {"A-01-1": "109"}
    many = "place,pallet\n" + "A-01-1,1\n" * 100_001
    _, problems = _read(tmp_path, "c.csv", many, world)
    assert problems[0].message == "more than 100000 places listed"
    assert problems[0].loc.line == 100_002


def test_the_report_names_the_file_it_was_made_against(tmp_path, world, monkeypatch):
    """summary.json and discrepancies.json name the expected stock by its absolute path and
    SHA-256: a relative name alone could not tell later which WMS export was used."""
    import hashlib

    text = "place,pallet\nA-01-1,109\n"
    monkeypatch.chdir(tmp_path)
    stock, problems = _read(tmp_path, "s.csv", text, world)
    assert problems == []
    digest = hashlib.sha256(text.encode()).hexdigest()
    assert stock.source() == {"path": str(tmp_path / "s.csv"), "sha256": digest}
    log = InventoryLog(str(tmp_path / "run"), drone="cf1")
    log.expected = stock
    log.plan(["A-01-1"])
    log.record({"place": "A-01-1", "answer": "109A", "status": "identified"})
    assert log.run_summary()["expected_source"]["sha256"] == digest
    doc = json.loads((tmp_path / "run" / "discrepancies.json").read_text())
    assert doc["expected_source"] == stock.source()


def test_an_unknown_place_is_hinted_by_case_and_leading_zeros_first():
    """difflib alone pointed at real, wrong places on the site: 'b-03-2' -> 'D-03-2',
    'A-1-1' -> 'A-12-1' (an operator following the hint would count the wrong rack)."""
    from nodes.expected_stock import PlaceHints

    hints = PlaceHints(["A-01-1", "A-12-1", "B-03-2", "D-03-2"])
    assert hints.hint("b-03-2") == " (did you mean 'B-03-2'?)"
    assert hints.hint("A-1-1") == " (did you mean 'A-01-1'?)"
    assert hints.hint("Q-99-9") == " (places: A-01-1 .. D-03-2)"


def test_the_spellings_of_no_pallet_a_wms_or_database_writes_are_empty(tmp_path, world):
    text = "place,pallet\nA-01-1,EMPTY\nA-01-2,n/a\nA-02-1,NULL\nA-02-2,-\nA-03-1,nil\n"
    stock, problems = _read(tmp_path, "s.csv", text, world)
    assert problems == [] and set(stock.places.values()) == {None}


def test_a_file_wrong_throughout_counts_every_problem(tmp_path, world, capsys):
    """50 problems are said, and the count is of all of them (it said '51 problems found'
    under '... and 19950 more')."""
    from bt_engine.cli import _print_problems

    text = "place,pallet\n" + "".join(f"A-{i:03d}-9,{i}\n" for i in range(120))
    _, problems = _read(tmp_path, "s.csv", text, world)
    assert len(problems) == 51 and problems[-1].message == "... and 70 more problems in this file"
    _print_problems(problems)
    assert capsys.readouterr().err.splitlines()[-1] == "120 problems found; nothing was run."


@pytest.mark.parametrize(
    "text, where",
    [
        ('[{"place": "A-01-1", "pallet": "1"}, "x",\n  {"place": "A-09-1", "pallet": "3"}]', [(1, 38), (2, 3)]),
        ('{"rows": ["x",\n {"place": "A-09-1", "pallet": "3"}]}', [(1, 11), (2, 2)]),
    ],
)  # fmt: skip
def test_a_json_row_that_is_no_object_does_not_shift_the_rows_after_it(
    tmp_path, world, text, where
):
    """Rows were found by searching for the next '{': a row "x" made the next row's problem
    point at the object after it (or at 1:1)."""
    _, problems = _read(tmp_path, "s.json", text, world)
    assert [(p.loc.line, p.loc.col) for p in problems] == where, problems
    assert "expected {" in problems[0].message and "unknown place 'A-09-1'" in problems[1].message


def test_a_workbooks_rows_are_rows_not_lines(tmp_path, world):
    rows = [["place", "pallet"], ["A-01-1", 109], ["A-01-1", 110]]
    _, problems = read_expected(_xlsx(tmp_path / "s.xlsx", rows), world, WHERE)
    assert [p.message for p in problems] == [
        "place 'A-01-1' listed twice (first at row 2); one row per place (cell Stock!A3)"
    ]


def test_a_merged_pallet_cell_is_refused_at_each_row_it_covers(tmp_path, world):
    """openpyxl gives a merged range's value to its first cell only: the rows below read
    as "this place should be empty", a false `unexpected`, without a word."""
    from openpyxl import Workbook

    wb = Workbook()
    ws = wb.active
    ws.title = "Stock"
    for row in [["rack", "place", "pallet"], ["A", "A-01-1", 109], ["A", "A-01-2", None]]:
        ws.append(row)
    ws.append(["A", "A-02-1", 110])
    ws.merge_cells("C2:C3")
    ws.merge_cells("A2:A4")  # a column not read may be merged
    ws.merge_cells("D2:E2")  # and a merge along one row changes nothing
    path = str(tmp_path / "merged.xlsx")
    wb.save(path)
    _, problems = read_expected(path, world, WHERE)
    assert [(p.loc.line, p.loc.col) for p in problems] == [(2, 3), (3, 3)]
    assert problems[0].message.startswith("a merged cell (C2:C3): one value over several rows")
    assert problems[1].message.endswith("(cell Stock!C3)")


def test_invisible_and_full_width_characters_in_names_are_folded(tmp_path, world):
    """A zero-width space copied from a web WMS, full-width digits of an East-Asian input
    method and a DOS end-of-file byte were kept in the names: every place became a
    "mismatch 109 -> 109" printed alike."""
    text = "place,pallet\nA-01-1,109\u200b\n\uff21-01-2,\uff11\uff11\uff10\nA-02-1,\ufeff111B\n\x1a"
    stock, problems = _read(tmp_path, "s.csv", text, world)
    assert problems == []
    assert stock.places == {"A-01-1": "109", "A-01-2": "110", "A-02-1": "111B"}


def test_ids_a_spreadsheet_rewrote_as_numbers_are_refused_in_csv_too(tmp_path, world):
    """A German Excel saves an SSCC column typed as number as ``1,02346E+17`` and 109 as
    ``109,0``: they were read as names (false mismatches); the XLSX reader refused them."""
    text = "place;pallet\nA-01-1;1,02346E+17\nA-01-2;109,0\nA-02-1;109.00\nA-02-2;12E4\n"
    _, problems = _read(tmp_path, "s.csv", text, world)
    assert [(p.loc.line, p.loc.col) for p in problems] == [(2, 8), (3, 8), (4, 8)]
    assert "a number a spreadsheet rewrote" in problems[0].message


def test_json_keys_are_read_in_any_case_as_csv_headers(tmp_path, world):
    text = '[{"Place": "A-01-1", "PALLET": "109"}, {"place": "A-01-2", "Pallet": null}]'
    stock, problems = _read(tmp_path, "s.json", text, world)
    assert problems == [] and stock.places == {"A-01-1": "109", "A-01-2": None}
