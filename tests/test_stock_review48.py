"""Site stock review 48: the store, the expected stock, the exports and the gallery's names.

A run imported under a renamed folder keeps its history; btrun's own inventory export read
back as expected stock books no unknown place as empty; the discrepancy export says where a
pallet belongs; pallets are one pallet in any case; an SSCC a spreadsheet rounded is
refused; identities that are no file names are refused and never escape an export; history
and diff say which site a run was; a large JSON stock reads in linear time.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time

import cv2
import numpy as np
import pytest
from helpers import REPO

from bt_engine.cli import main
from bt_engine.spec import Loc
from drivers.rig.loader import load_rig
from nodes.console import export
from nodes.discrepancy import categorise, discrepancy_rows
from nodes.expected_stock import ExpectedStock, read_expected
from nodes.gallery.cli import crop_file_stem
from nodes.inventory_log import write_inventory
from nodes.stock_json import LineIndex, entries_json
from perception.expected import pallet_key, sides_of
from perception.gallery import Gallery, GalleryError, identity_problem
from store import InventoryStore

RIG = os.path.join(REPO, "rigs", "aisle.yaml")
MISSION = os.path.join(REPO, "missions", "inventory.xml")
WHERE = Loc("--set", 0, 0)


@pytest.fixture(scope="module")
def world():
    return load_rig(RIG).load_world(0)


def _folder(path, rows, started: str, flown_as: str | None = None, rig: str = "rigs/aisle.yaml"):
    """A finished run folder: ``rows`` as (place, answer, run that found it); the tick log
    header records the start and the folder the run flew in (``flown_as``: its name then)."""
    os.makedirs(path, exist_ok=True)
    full = [
        {"place": p, "answer": a, "status": "empty" if a == "empty" else "identified", "run": r}
        for p, a, r in rows
    ]
    write_inventory(str(path), full, [r[0] for r in rows])
    flown = os.path.join(os.path.dirname(str(path)), flown_as or os.path.basename(str(path)))
    header = {"mission": MISSION, "seed": 4, "rig": rig, "started": started, "run_dir": flown}
    with open(os.path.join(path, "ticks.jsonl"), "w") as f:
        f.write(json.dumps({"header": header}) + "\n")
    with open(os.path.join(path, "summary.json"), "w") as f:
        json.dump({"status": "SUCCESS"}, f)
    return str(path)


def _json_out(capsys):
    return json.loads(capsys.readouterr().out)


# -- F1: a run renamed to be imported keeps its history ---------------------------------


def test_a_run_renamed_to_import_it_beside_another_stations_run_keeps_its_history(tmp_path, capsys):
    """Station 2's inv-001 (another flight) renamed as the refusal says: its rows still say
    inv-001, and the store took them for station 1's: gone from history and --pallet."""
    store = f"sqlite:///{tmp_path}/site.sqlite"
    one = _folder(
        tmp_path / "s1" / "inv-001",
        [("A-03-2", "1054B", "inv-001"), ("A-01-1", "1055A", "inv-001")],
        "2026-11-01T08:00:00Z",
    )
    two = _folder(
        tmp_path / "s2" / "inv-001-station2",
        [("A-03-2", "1999B", "inv-001"), ("A-01-1", "1055A", "inv-001")],
        "2026-11-02T08:00:00Z",
        flown_as="inv-001",
    )
    assert main(["inventory", "import", one, two, "--store", store]) == 0
    capsys.readouterr()
    for place in ("A-03-2", "A-01-1"):  # a changed answer and the same one alike
        assert main(["inventory", "history", place, "--store", store, "--json"]) == 0
        assert [h["run"] for h in _json_out(capsys)] == ["inv-001", "inv-001-station2"]
    assert main(["inventory", "history", "--pallet", "1999", "--store", store, "--json"]) == 0
    assert [(h["run"], h["place"]) for h in _json_out(capsys)] == [("inv-001-station2", "A-03-2")]
    # importing again changes nothing
    assert main(["inventory", "import", two, "--store", store]) == 0
    capsys.readouterr()
    with InventoryStore.open(store) as s:
        assert {r["origin"] for r in s.rows("inv-001-station2")} == {"inv-001-station2"}


def test_an_archived_copy_and_a_resumed_run_still_list_a_finding_once(tmp_path, capsys):
    """What the origin rule is for stays: a copy of the same flight under another name, and
    rows a resumed run carried over, are in the history of the run that found them."""
    store = f"sqlite:///{tmp_path}/site.sqlite"
    rows = [("A-03-2", "1054B", "inv-001"), ("A-01-1", "1055A", "inv-001")]
    one = _folder(tmp_path / "runs" / "inv-001", rows, "2026-11-01T08:00:00Z")
    copy = _folder(
        tmp_path / "archive" / "inv-001-2026", rows, "2026-11-01T08:00:00Z", flown_as="inv-001"
    )
    resumed = _folder(
        tmp_path / "runs" / "inv-002",
        [("A-03-2", "1054B", "inv-001"), ("A-01-2", "7A", "inv-002")],
        "2026-11-01T10:00:00Z",
    )
    assert main(["inventory", "import", one, copy, resumed, "--store", store]) == 0
    capsys.readouterr()
    assert main(["inventory", "history", "A-03-2", "--store", store, "--json"]) == 0
    assert [h["run"] for h in _json_out(capsys)] == ["inv-001"]
    assert main(["inventory", "history", "A-01-2", "--store", store, "--json"]) == 0
    assert [h["run"] for h in _json_out(capsys)] == ["inv-002"]


def test_rows_stored_before_the_fix_show_where_their_origin_run_differs(tmp_path):
    """A row whose origin run holds another answer at that place is not that run's finding
    (rows recorded before imports re-mapped them): it is shown."""
    with InventoryStore.open(f"sqlite:///{tmp_path}/s.sqlite") as s:
        s.begin_run("inv-001", started=1.0)
        s.record_rows("inv-001", [{"place": "A-03-2", "answer": "1054B", "status": "identified"}])
        s.begin_run("inv-001-station2", started=2.0)
        row = {"place": "A-03-2", "answer": "1999B", "status": "identified", "run": "inv-001"}
        s.record_rows("inv-001-station2", [row])
        assert [h["run"] for h in s.history("A-03-2")] == ["inv-001", "inv-001-station2"]


# -- F2: the inventory export read back as expected stock --------------------------------


def _info(rows: list[dict], planned: list[str], review: list | None = None) -> dict:
    return {"rows": rows, "planned": planned, "started": 0.0, "review": review or []}


def _inventory_rows() -> list[dict]:
    return [
        {"place": "A-01-1", "answer": "101A", "status": "identified", "mission_time_s": 5.0},
        {"place": "A-01-2", "answer": "empty", "status": "empty", "mission_time_s": 9.0},
        {"place": "A-02-1", "answer": "unknown", "status": "unknown", "mission_time_s": 14.0},
        {"place": "A-02-2", "answer": "unknown", "status": "not_identified"},
    ]


@pytest.mark.parametrize("kind", ["csv", "xlsx"])
def test_the_inventory_export_read_back_as_expected_stock_books_no_unknown_place_empty(
    tmp_path, world, kind
):
    rows = _inventory_rows()
    info = _info(rows, ["A-01-1", "A-01-2", "A-02-1", "A-02-2", "A-03-1"])
    columns, lines = export.table(info, "inventory")
    assert [line["pallet"] for line in lines] == ["101A", "", "", "", ""]  # as before
    data = (
        export.to_csv(columns, lines)
        if kind == "csv"
        else export.to_xlsx(columns, lines, "inventory")
    )
    path = tmp_path / f"inv.{kind}"
    path.write_bytes(data)
    stock, problems = read_expected(str(path), world, WHERE)
    assert problems == []
    # unknown, not identified and not scanned: no expectation; empty: expected empty
    assert stock.places == {"A-01-1": "101A", "A-01-2": None}
    found = discrepancy_rows(rows, stock)
    assert {r["place"]: r["category"] for r in found} == {
        "A-01-1": "confirmed",
        "A-01-2": "confirmed",
        "A-02-1": "unlisted",
        "A-02-2": "unlisted",
    }


def test_a_status_column_only_speaks_for_an_empty_pallet(tmp_path, world):
    """A WMS file's own status column, and a pallet named beside an 'unknown' status: the
    pallet stands; without a status column an empty pallet still means empty."""
    text = "place,pallet,status\nA-01-1,109,unknown\nA-01-2,,Blocked\nA-02-1,,NOT_SCANNED\n"
    stock, problems = read_expected(_write(tmp_path, "s.csv", text), world, WHERE)
    assert problems == [] and stock.places == {"A-01-1": "109", "A-01-2": None}
    text = json.dumps([{"place": "A-01-1", "pallet": None, "status": "unknown"}])
    stock, problems = read_expected(_write(tmp_path, "s.json", text), world, WHERE)
    assert problems == [] and stock.places == {}
    stock, problems = read_expected(
        _write(tmp_path, "p.csv", "place,pallet\nA-01-1,\n"), world, WHERE
    )
    assert stock.places == {"A-01-1": None}
    # listed twice is still listed twice, an expectation or not
    text = "place,pallet,status\nA-01-1,,unknown\nA-01-1,5,identified\n"
    _, problems = read_expected(_write(tmp_path, "t.csv", text), world, WHERE)
    assert [p.loc.line for p in problems] == [3] and "listed twice" in problems[0].message


def _write(tmp_path, name: str, text: str) -> str:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return str(path)


# -- F3: the discrepancy export says where a pallet belongs ------------------------------


def test_the_discrepancy_export_has_moved_from(tmp_path):
    rows = [
        {
            "place": "A-01-3",
            "answer": "1096A",
            "status": "identified",
            "discrepancy": "unexpected",
            "expected": "",
            "moved_from": "B-03-1",
        },
        {
            "place": "A-01-1",
            "answer": "1055A",
            "status": "identified",
            "discrepancy": "mismatch",
            "expected": "1054",
            "moved_from": "A-01-2",
        },
    ]
    columns, lines = export.table(_info(rows, ["A-01-3", "A-01-1"]), "discrepancies")
    assert columns[: len(export.COLUMNS) + 3] == (*export.COLUMNS, "expected", "category", "review")
    assert columns[-1] == "moved_from"
    assert [(x["place"], x["category"], x["moved_from"]) for x in lines] == [
        ("A-01-3", "unexpected", "B-03-1"),
        ("A-01-1", "mismatch", "A-01-2"),
    ]
    text = export.to_csv(columns, lines).decode()
    assert text.splitlines()[1].endswith(",unexpected,,B-03-1")


# -- F4: a pallet is one pallet in any case ----------------------------------------------


def test_pallets_compare_without_case(tmp_path, world):
    assert categorise("pal-7", "PAL-7") == ("confirmed", "PAL-7")
    assert categorise("pal-7", "PAL-7B") == ("confirmed", "PAL-7")  # the written form shown
    assert categorise("pal-8", "PAL-7") == ("mismatch", "PAL-7")
    assert pallet_key("Pal-7b") == pallet_key("PAL-7") == "pal-7"
    assert sides_of(["PAL-7A", "PAL-7B", "PAL-8A"], "pal-7") == ["PAL-7A", "PAL-7B"]
    stock = ExpectedStock("s.csv", {"A-01-1": "pal-7", "A-02-1": None})
    assert stock.place_of("PAL-7B") == "A-01-1"
    found = discrepancy_rows([{"place": "A-02-1", "answer": "PAL-7A"}], stock)
    assert (found[0]["category"], found[0]["moved_from"]) == ("unexpected", "A-01-1")
    text = "place,pallet\nA-01-1,PAL-7\nA-01-2,pal-7\nA-02-1,Pal-8A\nA-02-2,pal-8a\n"
    _, problems = read_expected(_write(tmp_path, "case.csv", text), world, WHERE)
    assert [(p.loc.line, p.loc.col) for p in problems] == [(3, 8), (5, 8)]
    assert problems[0].message.startswith(
        "pallet 'PAL-7' (written 'PAL-7' and 'pal-7') expected at two places: A-01-1 (line 2)"
    )
    assert "(written 'Pal-8A' and 'pal-8a')" in problems[1].message


# -- F5: an SSCC a spreadsheet rounded ---------------------------------------------------


def test_an_xlsx_number_of_more_than_15_digits_is_refused_at_its_cell(tmp_path, world):
    from openpyxl import Workbook

    wb = Workbook()
    ws = wb.active
    ws.title = "Stock"
    ws.append(["place", "pallet"])
    ws.append(["A-01-1", 340123450000000017])  # an SSCC entered as a number
    ws.append(["A-01-2", 3.4012345e17])  # what a spreadsheet keeps of it
    ws.append(["A-02-1", 123456789012345])  # 15 digits: kept whole
    path = tmp_path / "sscc.xlsx"
    wb.save(path)
    stock, problems = read_expected(str(path), world, WHERE)
    assert [(p.loc.line, p.loc.col) for p in problems] == [(2, 2), (3, 2)]
    assert "a number of 18 digits (340123450000000000)" in problems[0].message
    assert "format the column as text" in problems[0].message
    assert problems[0].message.endswith("(cell Stock!B2)")
    assert "(340123450000000000)" in problems[1].message
    assert stock.places == {"A-02-1": "123456789012345"}


# -- F6: identities that are no file names -----------------------------------------------


@pytest.mark.parametrize("name", ["a\nb", "x\x00", "a\u2028b", "", "P" * 65])
def test_an_identity_with_a_control_character_or_out_of_length_is_refused(name):
    assert identity_problem(name) is not None
    g = Gallery.create(":memory:", model_version="m", dim=4)
    with pytest.raises(GalleryError, match="enrol: identity"):
        g.enrol(name, np.eye(3, 4, dtype=np.float32))
    assert g.identities() == []


@pytest.mark.parametrize("name", ["PAL/2026/0001", "a\\b", "../../etc", "=cmd|' calc'!A0"])
def test_a_wms_id_with_slashes_is_kept_as_it_is(name):
    # a WMS's ids (PAL/2026/0001) are enrolled as they are: no identity names a file
    assert identity_problem(name) is None
    g = Gallery.create(":memory:", model_version="m", dim=4)
    g.enrol(name, np.eye(3, 4, dtype=np.float32))
    assert g.identities() == [name]


def test_export_file_names_stay_in_the_folder_whatever_the_identity(tmp_path, capsys):
    crops = []
    rng = np.random.default_rng(3)
    for i in range(3):
        p = tmp_path / f"c{i}.png"
        cv2.imwrite(str(p), rng.integers(0, 255, (96, 64, 3), dtype=np.uint8))
        crops.append(str(p))
    g = str(tmp_path / "g.sqlite")
    assert main(["gallery", "enrol", g, "a\nb", "--crops", *crops]) == 2
    err = capsys.readouterr().err
    assert "line break" in err and err.count("\n") == 1 and "Traceback" not in err
    assert not os.path.exists(g)  # refused before the file is made
    assert main(["gallery", "enrol", g, "7A", "--crops", *crops]) == 0
    assert main(["gallery", "enrol", g, "PAL/2026/1", "--crops", *crops]) == 0
    # names enrolled before they were checked
    con = sqlite3.connect(g)
    for name in ("../../etc", "a\nb", "7a"):
        con.execute(
            "INSERT INTO entries SELECT ?, embeddings, created, source FROM entries "
            "WHERE identity = '7A'",
            (name,),
        )
        con.execute(
            "INSERT INTO crops SELECT ?, block, png FROM crops WHERE identity = '7A'", (name,)
        )
    con.commit()
    con.close()
    out = tmp_path / "x" / "y" / "out"
    assert main(["gallery", "export", g, str(out)]) == 0
    capsys.readouterr()
    written = sorted(os.listdir(out))
    assert len(written) == 2 + 5 * 3 and "7A_block_1.png" in written
    assert sorted(os.listdir(tmp_path / "x")) == ["y"] and sorted(
        os.listdir(tmp_path / "x" / "y")
    ) == ["out"]
    meta = json.loads((out / "entries.json").read_text())
    files = {e["identity"]: e["crop_files"] for e in meta["entries"]}
    assert len({f for names in files.values() for f in names}) == 15  # none shared
    assert all(os.path.exists(out / f) for names in files.values() for f in names)
    assert crop_file_stem("7A", set()) == "7A"
    assert "/" not in crop_file_stem("../../etc", set())


# -- F7: runs of different sites ---------------------------------------------------------


def test_history_shows_the_rig_and_diff_warns_of_two_sites(tmp_path, capsys):
    store = f"sqlite:///{tmp_path}/site.sqlite"
    site = _folder(
        tmp_path / "base11",
        [("A-01-1", "1055A", "base11"), ("A-01-2", "1060B", "base11")],
        "2026-11-01T08:00:00Z",
        rig="rigs/site.yaml",
    )
    aisle = _folder(
        tmp_path / "aisle-run", [("A-01-1", "105A", "aisle-run")], "2026-11-02T08:00:00Z"
    )
    assert main(["inventory", "import", site, aisle, "--store", store]) == 0
    capsys.readouterr()
    assert main(["inventory", "history", "A-01-1", "--store", store]) == 0
    out = capsys.readouterr().out
    assert "rig or fleet" in out and "site" in out and "aisle" in out
    assert "runs of 2 rigs or fleets (rig aisle, rig site)" in out
    assert main(["inventory", "history", "A-01-1", "--store", store, "--json"]) == 0
    assert [h["rig"] for h in _json_out(capsys)] == ["rigs/site.yaml", "rigs/aisle.yaml"]
    assert main(["inventory", "diff", "base11", "aisle-run", "--store", store]) == 0
    captured = capsys.readouterr()
    assert "warning: base11 was flown by rig site, aisle-run by rig aisle" in captured.err
    assert main(["inventory", "diff", "base11", "aisle-run", "--store", store, "--json"]) == 0
    assert "rig site" in _json_out(capsys)["warning"]
    assert main(["inventory", "diff", "base11", "base11", "--store", store, "--json"]) == 0
    assert "warning" not in _json_out(capsys)


# -- F8: JSON expected stock in linear time ----------------------------------------------


def test_json_rows_are_located_as_before(tmp_path):
    """The line index gives what counting the newlines before each offset gave."""
    text = '[\r\n {"place": "A",\n  "pallet": 1},\n\n{"place": "B"}]\n'

    def counted(offset: int) -> tuple[int, int]:
        line_start = text.rfind("\n", 0, offset) + 1
        return text.count("\n", 0, offset) + 1, offset - line_start + 1

    index = LineIndex("s.json", text)
    for offset in range(len(text) + 1):
        loc = index.loc(offset)
        assert (loc.line, loc.col) == counted(offset)
    entries, problems = entries_json("s.json", text)
    assert [(e[0], e[2].line, e[2].col) for e in entries] == [("A", 2, 2), ("B", 5, 1)]
    # a {place: pallet} object: each key found after the one before, never a value
    text = '{"A-01-1": "A-01-2",\n "A-01-2" \t: null, "A-\\u0030": 1}'
    entries, _ = entries_json("m.json", text)
    assert [(e[0], e[2].line, e[2].col) for e in entries] == [
        ("A-01-1", 1, 2),
        ("A-01-2", 2, 2),
        ("A-0", 2, 13),  # written otherwise than JSON writes it: after the key before
    ]


@pytest.mark.parametrize("shape, n", [("list", 30_000), ("map", 100_000)])
def test_a_large_json_stock_reads_in_linear_time(shape, n):
    """30,000 rows as a list took about 15 s, 100,000 as one object nearly two minutes
    (each row's line counted from the file's start, a pattern compiled per key); now a
    second or two."""
    if shape == "list":
        rows = [{"place": f"P-{i:05d}", "pallet": str(i)} for i in range(n)]
        text = json.dumps(rows, indent=2)
    else:
        text = json.dumps({f"P-{i:05d}": str(i) for i in range(n)}, indent=1)
    t0 = time.perf_counter()
    entries, problems = entries_json("big.json", text)
    took = time.perf_counter() - t0
    assert problems == [] and len(entries) == n
    assert entries[-1][2].line == (4 * n - 2 if shape == "list" else n + 1)
    assert took < 8.0, f"{took:.1f} s for {n} rows"


# -- F10: smaller ones -------------------------------------------------------------------


def test_store_hints_ignore_case(tmp_path, capsys):
    """difflib, case-sensitive, hinted D-05-2 for a-05-2 (and inv-8 for inv-7)."""
    store = f"sqlite:///{tmp_path}/site.sqlite"
    run = _folder(
        tmp_path / "Inv-7",
        [("A-05-2", "3A", "Inv-7"), ("D-05-2", "4A", "Inv-7")],
        "2026-11-01T08:00:00Z",
    )
    other = _folder(tmp_path / "inv-8", [("A-05-2", "3A", "inv-8")], "2026-11-02T08:00:00Z")
    assert main(["inventory", "import", run, other, "--store", store]) == 0
    capsys.readouterr()
    assert main(["inventory", "history", "a-05-2", "--store", store]) == 2
    assert "(did you mean A-05-2?)" in capsys.readouterr().err
    assert main(["inventory", "diff", "inv-7", "Inv-7", "--store", store]) == 2
    assert "(did you mean Inv-7?)" in capsys.readouterr().err


def test_a_pallet_name_too_long_is_located_at_the_pallet_and_held_to_the_gallerys_limit(
    tmp_path, world
):
    text = "place,pallet\nA-01-1," + "x" * 65 + "\nA-01-2," + "y" * 64 + "\nA-02-1,a\x01b\n"
    stock, problems = read_expected(_write(tmp_path, "s.csv", text), world, WHERE)
    assert [(p.loc.line, p.loc.col) for p in problems] == [(2, 8), (4, 8)]
    assert "a pallet name longer than 64 characters" in problems[0].message
    assert "control character in 'a\\x01b'" in problems[1].message
    assert stock.places == {"A-01-2": "y" * 64}
    text = "place,pallet\n" + "P" * 201 + ",5\n"
    _, problems = read_expected(_write(tmp_path, "t.csv", text), world, WHERE)
    assert problems[0].loc.col == 1 and "place name longer than 200" in problems[0].message


def test_expected_pallets_not_in_the_gallery_are_compared_without_case():
    """The start-up line listed 'pal-7' as not enrolled when the gallery held 'PAL-7A'."""
    from types import SimpleNamespace

    from nodes.inventory import not_in_gallery

    gallery = SimpleNamespace(identities=lambda: ["PAL-7A", "PAL-7B", "103A"])
    session = SimpleNamespace(galleries=lambda: [gallery])
    stock = SimpleNamespace(places={"A-01-1": "pal-7", "A-01-2": "103", "A-01-3": "Pal-9"})
    assert not_in_gallery(stock, session) == ["Pal-9"]
