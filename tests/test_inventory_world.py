"""The rack aisle: named places, racks that the drone can hit, stock drawn per seed, and the
place lists an inventory takes (names, patterns, CSV), refused with located errors."""

from __future__ import annotations

import os

import pytest
from helpers import REPO

from bt_engine.cli import main
from bt_engine.spec import Loc
from drivers.settings import ConfigError
from drivers.sim.world import load_world
from nodes.inventory import all_places_order, resolve_places

AISLE = os.path.join(REPO, "worlds", "aisle.yaml")
RIG = os.path.join(REPO, "rigs", "aisle.yaml")


def test_aisle_has_sixteen_named_places_on_two_levels():
    w = load_world(AISLE)
    assert len(w.places) == 16
    assert list(w.places)[:3] == ["A-01-1", "A-01-2", "A-02-1"]
    low, high = w.places["A-03-1"], w.places["A-03-2"]
    assert (low.bay, low.level, high.level) == (3, 1, 2)
    assert high.row_m[2] - low.row_m[2] == pytest.approx(0.8)  # beams at 0.2 and 1.0 m
    assert low.row_m[0] == pytest.approx(3.05)  # 0.05 m behind the front line x = 3.0
    assert w.places["A-01-1"].row_m[1] > w.places["A-08-1"].row_m[1]  # bays run to -y
    assert low.look_deg == pytest.approx(0.0)  # the drone looks along +x at the rack


def test_stock_is_drawn_per_seed_with_the_asked_empty_and_unknown_places():
    a, b, a2 = load_world(AISLE, seed=1), load_world(AISLE, seed=2), load_world(AISLE, seed=1)
    assert a.stock == a2.stock and a.stock != b.stock
    for w in (a, b):
        values = list(w.stock.values())
        assert values.count(None) == 2
        not_enrolled = {i for i in values if i and i[:-1] in ("115", "116")}
        assert len(not_enrolled) == 2
        pallets = [i[:-1] for i in values if i]
        assert len(pallets) == len(set(pallets)) == 14  # each pallet stands in one place
        racked = {p.slot_name: p.identity for p in w.pallets}
        assert racked == {k: v for k, v in w.stock.items() if v}
    assert set(a.not_enrolled()) == {"115A", "115B", "116A", "116B"}
    assert len(a.enrolled_identities()) == 28


def test_fixed_places_and_overrides():
    w = load_world(AISLE, {"stock.fixed.A-01-1": "101B", "stock.fixed.A-02-2": "none"}, seed=3)
    assert w.stock["A-01-1"] == "101B" and w.stock["A-02-2"] is None
    assert list(w.stock.values()).count("101B") == 1
    truth = {g["slot"]: g["identity"] for g in w.ground_truth()}
    assert truth["A-01-1"] == "101B" and "A-02-2" not in truth


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"stock.fixed.Z-01-1": "101A"}, "'Z-01-1' is not a place of this world"),
        ({"stock.fixed.A-01-1": "999A"}, "'999A' is not a pallet side of this world"),
        ({"stock.empty_places": "0", "pallet_pool.count": "10"}, "pool has only"),
        ({"stock.not_enrolled_places": "5"}, "not-enrolled pallet asked"),
        (
            {"stock.not_enrolled": "[115]", "stock.not_enrolled_places": "2"},
            "only 1 can have one (1 not-enrolled pallet free)",
        ),
    ],
)
def test_a_stock_the_world_cannot_fill_is_refused(overrides, message):
    with pytest.raises(ConfigError) as exc:
        load_world(AISLE, overrides)
    assert any(message in p for p in exc.value.problems), exc.value.problems


def test_what_an_override_broke_elsewhere_is_located_in_the_file():
    """A smaller pool leaves the file's not-enrolled list naming pallets it no longer has:
    said once for the list, at the file's line, with the override that broke it (it was
    ten lines, each blamed on a --set the user never wrote)."""
    site = os.path.join(REPO, "worlds", "site.yaml")
    with pytest.raises(ConfigError) as exc:
        load_world(site, {"pallet_pool.count": "100"})
    text = open(site).read()
    line = text[: text.index("not_enrolled: [")].count("\n") + 1
    bad = [p for p in exc.value.problems if "not pallet ids" in p.message]
    assert len(bad) == 1, exc.value.problems
    assert (bad[0].file, bad[0].line) == (site, line)
    assert "(10 ids)" in bad[0].message and "its 100 pallets: 1001 .. 1100" in bad[0].message
    assert bad[0].message.endswith("(with --set world.pallet_pool.count=100)")
    # a key the override wrote is still said as the --set
    with pytest.raises(ConfigError) as exc:
        load_world(site, {"stock.not_enrolled": "[1131, 9999]"})
    said = [p for p in exc.value.problems if p.file == "--set"]
    assert [p.message for p in said] == [
        "world.stock.not_enrolled[1]: '9999' is not a pallet id of this world "
        "(its 140 pallets: 1001 .. 1140)"
    ]


def test_a_world_wrong_alone_flies_as_an_override_fixes_it(tmp_path):
    """The world that flies is the file with its overrides: a pool too small for the file's
    stock is refused, located in the file, unless a --set fixes it (it was refused even
    then: the file's own check ran first). A problem the file keeps with the overrides is
    still said at its line, once."""
    text = open(AISLE).read().replace("count: 16,", "count: 12,")
    text = text.replace('not_enrolled: ["115", "116"]', 'not_enrolled: ["111", "112"]')
    small = tmp_path / "aisle.yaml"
    small.write_text(text)
    line = text[: text.index("\nstock:") + 1].count("\n") + 2
    with pytest.raises(ConfigError) as exc:
        load_world(str(small))
    (alone,) = exc.value.problems
    assert (alone.file, alone.line) == (str(small), line) and "pool has only 10" in alone.message
    for fix in ({"pallet_pool.count": "16"}, {"stock.empty_places": "6"}):
        assert len(load_world(str(small), fix, seed=1).places) == 16
    with pytest.raises(ConfigError) as exc:  # an override that leaves it: said in the file
        load_world(str(small), {"stock.placement_error.yaw_deg": "2", "stock.empty_places": "2"})
    assert [(p.file, p.line, p.message) for p in exc.value.problems] == [
        (alone.file, alone.line, alone.message)
    ]
    with pytest.raises(ConfigError) as exc:  # a side that is not there: said once, short
        load_world(AISLE, {"scan_pallet": "ZZ"})
    (said,) = exc.value.problems
    assert said.file == "--set" and "'ZZ' is not a pallet side" in said.message
    assert "101A, 101B, 102A, 102B, 103A, 103B, 104A, 104B, ..., 116B (32 sides)" in said.message


def test_a_bad_rack_in_a_file_is_located(tmp_path):
    text = open(AISLE).read().replace("levels_m: [0.20, 1.00]", "levels_m: [1.00, 0.20]")
    bad = tmp_path / "aisle.yaml"
    bad.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_world(str(bad))
    (problem,) = exc.value.problems
    assert problem.line == text[: text.index("levels_m: [1.00")].count("\n") + 1
    assert "levels must go up from the floor" in problem.message


@pytest.mark.parametrize(
    "overrides, key, fragment",
    [
        ({"racks.0.bay_width_m": "1.0"}, "racks[0].bay_width_m", "pallet does not fit"),
        ({"racks.0.depth_m": "0.5"}, "racks[0].depth_m", "needs 0.85 m"),
        ({"racks.0.levels_m": "[0.2, 0.3]"}, "racks[0].levels_m", "at least 0.244 m apart"),
        (
            {"stock.placement_error.lateral_m": "0.15"},
            "stock.placement_error.lateral_m",
            "neighbouring bays overlap in rack A: at most 0.100 m",
        ),
        (
            {"stock.placement_error.depth_m": "0.2"},
            "stock.placement_error.depth_m",
            "through the back of the rack in rack A: at most 0.150 m",
        ),
        (
            {"stock.placement_error.height_m": "0.6"},
            "stock.placement_error.height_m",
            "into the beam of the level above in rack A: at most 0.556 m",
        ),
        (  # a pallet turned 90 deg was accepted: its side faced the aisle, half in the next bay
            {"stock.placement_error.yaw_deg": "90"},
            "stock.placement_error.yaw_deg",
            "90 deg turns a 1.2 x 0.8 m pallet into the next bay or through the rack's back: "
            "at most 16.2 deg there",
        ),
    ],
)
def test_a_rack_that_cannot_hold_its_pallets_is_refused(overrides, key, fragment):
    """Pallets that would overlap their neighbours, stand through the rack's back or in
    the beam above (the rack's sizes, or placement errors too large for them) are refused
    before anything flies, the message naming the key; errors within the room pass."""
    with pytest.raises(ConfigError) as exc:
        load_world(AISLE, overrides)
    (problem,) = exc.value.problems
    assert problem.message.startswith(f"world.{key}: ") and fragment in problem.message
    load_world(AISLE, {"stock.placement_error.lateral_m": "0.1", "stock.placement_error.depth_m": "0.15"})  # fmt: skip
    load_world(AISLE, {"stock.placement_error.yaw_deg": "16"})


def test_a_rack_too_shallow_in_a_file_is_located(tmp_path):
    text = open(AISLE).read()
    assert "    depth_m: 1.0\n" in text
    bad = tmp_path / "aisle.yaml"
    bad.write_text(text.replace("    depth_m: 1.0\n", "    depth_m: 0.6\n", 1))
    with pytest.raises(ConfigError) as exc:
        load_world(str(bad))
    (problem,) = exc.value.problems
    assert problem.line == text[: text.index("    depth_m: 1.0\n")].count("\n") + 1
    assert problem.message.startswith("0.6 m is too shallow for a 0.8 m deep pallet")


def test_the_rack_is_solid():
    w = load_world(AISLE)
    place = w.places["A-04-1"]
    x, y, _ = place.row_m
    assert w.collision(x - 0.4, y, 0.26, 0.06) is None  # the scan line, 0.4 m in front
    assert w.collision(3.0, 5.6 - 3 * 1.4, 0.5, 0.06).startswith("rack A upright 3")
    assert w.collision(3.02, y, 0.95, 0.06).startswith("rack A beam 04-2")
    inside = w.collision(x + 0.3, y, place.row_m[2], 0.06)
    assert inside == f"pallet {w.stock['A-04-1'][:-1]}" if w.stock["A-04-1"] else inside is None


def test_place_lists():
    w = load_world(AISLE)
    where = Loc("m.xml", 3, 5)
    order = all_places_order(w)
    assert order[:4] == ["A-01-1", "A-01-2", "A-02-2", "A-02-1"]  # up one bay, down the next
    assert resolve_places("all", w, where)[0] == order
    names, problems = resolve_places("A-02-*; A-01-1, A-02-1", w, where)
    assert names == ["A-02-1", "A-02-2", "A-01-1"] and problems == []
    _, problems = resolve_places("A-01-1;A-1-1", w, where)
    assert [str(p) for p in problems] == [
        "m.xml:3:5: unknown place 'A-1-1' (did you mean 'A-01-1'?)"
    ]


def test_a_csv_place_list_reports_bad_lines_where_they_are(tmp_path):
    w = load_world(AISLE)
    csv = tmp_path / "places.csv"
    csv.write_text("aisle,place\nA,A-03-2\nA,B-03-2\n")
    names, problems = resolve_places(str(csv), w, Loc("m.xml", 1, 1))
    assert names == ["A-03-2"]
    assert [str(p) for p in problems] == [
        f"{csv}:3:3: unknown place 'B-03-2' (did you mean 'A-03-2'?)"
    ]


@pytest.mark.parametrize("delimiter", [";", "\t"])
def test_a_place_list_with_semicolons_or_tabs_reads_as_with_commas(tmp_path, delimiter):
    """A spreadsheet saved as CSV where the decimal mark is a comma separates the columns
    with ';' (a tab-separated export too): the place column is found and located alike."""
    w = load_world(AISLE)
    csv = tmp_path / "places.csv"
    csv.write_text(
        delimiter.join(["aisle", "place"]) + f"\nA{delimiter}A-03-2\nA{delimiter}B-03-2\n"
    )
    names, problems = resolve_places(str(csv), w, Loc("m.xml", 1, 1))
    assert names == ["A-03-2"]
    assert [str(p) for p in problems] == [
        f"{csv}:3:3: unknown place 'B-03-2' (did you mean 'A-03-2'?)"
    ]


@pytest.mark.parametrize(
    "encoding, text",
    [
        ("utf-16", "Aisle\tPlace\nK\u00fchl\tA-03-2\nK\u00fchl\tB-03-2\n"),
        ("cp1252", "Aisle;Place\r\nK\u00fchl;A-03-2\r\nK\u00fchl;B-03-2\r\n"),
        ("utf-8", "sep=;\nAisle;Place\nA;A-03-2\nA;B-03-2\n"),
    ],
)
def test_a_place_list_excel_saved_reads_as_a_utf8_one(tmp_path, encoding, text):
    """Excel's "Unicode Text" (UTF-16), its Windows "CSV" (Windows-1252) and its ``sep=;``
    first line: the place column found, problems located at the file's own lines."""
    w = load_world(AISLE)
    csv = tmp_path / "places.csv"
    csv.write_bytes(text.encode(encoding))
    names, problems = resolve_places(str(csv), w, Loc("m.xml", 1, 1))
    assert names == ["A-03-2"]
    line = 4 if text.startswith("sep=") else 3
    assert [(p.loc.line, p.loc.col) for p in problems] == [(line, 3 if encoding == "utf-8" else 6)]
    assert "unknown place 'B-03-2'" in problems[0].message


def test_an_xlsx_place_list_with_or_without_a_header(tmp_path):
    """A workbook's first sheet lists places as the CSV does: its ``Place`` column (any
    case) or, without that header, its first column from the first row; problems located
    at row:column."""
    from openpyxl import Workbook

    w = load_world(AISLE)
    for rows, name in (
        ([["aisle", "Place"], ["A", "A-03-2"], [], ["A", "A-0?-1"], ["A", "B-03-2"]], "h.xlsx"),
        ([["A-03-2"], ["A-0?-1"], ["B-03-2"]], "n.xlsx"),
    ):
        wb = Workbook()
        for row in rows:
            wb.active.append(row)
        wb.save(tmp_path / name)
        names, problems = resolve_places(str(tmp_path / name), w, Loc("m.xml", 1, 1))
        assert names[:2] == ["A-03-2", "A-01-1"] and "B-03-2" not in names
        line, col = (5, 2) if name == "h.xlsx" else (3, 1)
        assert [str(p) for p in problems] == [
            f"{tmp_path / name}:{line}:{col}: unknown place 'B-03-2' (did you mean 'A-03-2'?)"
        ]


def test_btrun_refuses_unknown_places_before_anything_flies(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(
        ["missions/inventory.xml", "--rig", RIG, "--set", "places=A-01-1;A-99-1", "--out", str(out)]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert "--set places: unknown place 'A-99-1'" in err
    assert "nothing was run" in err
    assert not out.exists()  # no run folder: nothing flew


def test_btrun_refuses_an_inventory_in_a_world_without_places(tmp_path, capsys):
    code = main(["missions/inventory.xml", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2
    assert "missions/inventory.xml:" in err and "has no pallet places" in err
