"""The site store against what a user gets wrong: a mistyped store URL, a database that is
not a store, a run folder flown into twice, a renamed or moved copy imported, a fleet's
drone folder imported alone. Each is refused in one line, or recorded right."""

from __future__ import annotations

import json
import os
import shutil
import sqlite3

import pytest
from helpers import REPO
from test_store_runs import _run_folder

from bt_engine.cli import main
from store import InventoryStore, StoreError
from store.db import parse_url


@pytest.mark.parametrize(
    "text, said",
    [
        ("postgresql:/db.site/btrun", "expected postgresql://USER@HOST/DBNAME"),
        ("postgres:al:s3cret@db/btrun", "'postgres:al:***@db/btrun'"),
        ("host=db password=s3cret dbname=btrun", "a libpq key=value string"),
        ("mysql:/x", "expected sqlite:///FILE or postgresql://"),
    ],
)
def test_a_mistyped_store_url_is_not_taken_for_a_file(text, said, tmp_path, monkeypatch):
    """Without '://' a store argument was an SQLite path: a file named after the URL (or
    after a libpq string, password and all) was made where btrun ran."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(StoreError) as exc:
        parse_url(text)
    assert said in str(exc.value) and "s3cret" not in str(exc.value)
    assert main(["inventory", "runs", "--store", text]) == 2
    assert os.listdir(tmp_path) == []
    assert parse_url("runs/site.sqlite").target == "runs/site.sqlite"  # a path is a path


def test_a_database_that_is_not_a_store_is_left_as_it_was(tmp_path, capsys):
    """A gallery named by mistake was made a store (its tables added), even by a command
    that only reads; an empty file read as a store was given the store's tables."""
    gallery = tmp_path / "pallets.sqlite"
    with sqlite3.connect(gallery) as db:
        db.execute("CREATE TABLE sides (identity TEXT)")
    before = gallery.read_bytes()
    for create in (True, False):
        with pytest.raises(StoreError, match="not a btrun site store .it holds tables sides"):
            InventoryStore.open(str(gallery), create=create)
    assert main(["inventory", "runs", "--store", str(gallery)]) == 2
    assert "not a btrun site store" in capsys.readouterr().err
    assert gallery.read_bytes() == before
    empty = tmp_path / "empty.sqlite"
    sqlite3.connect(empty).close()
    assert main(["inventory", "history", "A-01-1", "--store", str(empty)]) == 2
    assert "no site store there yet" in capsys.readouterr().err
    with sqlite3.connect(empty) as db:
        assert db.execute("SELECT name FROM sqlite_master").fetchall() == []
    with InventoryStore.open(str(empty)) as s:  # a command that records makes it a store
        assert s.version() >= 1


def test_a_run_folder_is_not_flown_into_twice(tmp_path, capsys):
    """A second flight into --out DIR wrote its tick log and rows over the first's (its
    crops and report left beside them) and, in the store, mixed both flights' rows under
    the folder's name. Refused before anything starts; the first run is as it was."""
    square = os.path.join(REPO, "missions", "square.xml")
    out = tmp_path / "runs" / "a"
    assert main([square, "--out", str(out), "-q", "--no-report", "--store", "none"]) == 0
    log = (out / "ticks.jsonl").read_bytes()
    capsys.readouterr()
    assert main([square, "--out", str(out), "-q", "--no-report", "--store", "none"]) == 2
    err = capsys.readouterr().err
    assert f"--out {out}: holds a run already (its ticks.jsonl)" in err
    assert (out / "ticks.jsonl").read_bytes() == log
    fleet = os.path.join(REPO, "fleets", "aisle_2.yaml")
    assert main(["fleet", fleet, "--out", str(out), "-q", "--store", "none"]) == 2
    assert "holds a run already" in capsys.readouterr().err
    (tmp_path / "runs" / "new").mkdir()  # an empty folder is fine
    assert main([square, "--out", str(tmp_path / "runs" / "new"), "-q", "--no-report"]) == 0


def test_renamed_moved_and_drone_folders_imported(tmp_path, capsys):
    """A renamed copy's rows name the folder's old name as the run that found them: the
    place history hid them all (and suggested the very place typed). A moved folder of a
    run already recorded is the same flight. A fleet's drone folder alone is refused."""
    store = f"sqlite:///{tmp_path}/site.sqlite"
    first = _run_folder(tmp_path / "night", [("A-01-1", "3A", "identified")])
    with open(os.path.join(first, "ticks.jsonl"), "w") as f:
        header = {"mission": "m.xml", "seed": 4, "started": "2026-11-01T08:00:00Z"}
        f.write(json.dumps({"header": header}) + "\n")
    week = tmp_path / "archive" / "week48"
    shutil.copytree(first, week)
    assert main(["inventory", "import", str(week), "--store", store]) == 0
    capsys.readouterr()
    assert main(["inventory", "history", "A-01-1", "--store", store, "--json"]) == 0
    assert [(h["run"], h["answer"]) for h in json.loads(capsys.readouterr().out)] == [
        ("week48", "3A")
    ]
    moved = tmp_path / "elsewhere" / "night"
    assert main(["inventory", "import", first, "--store", store]) == 0
    shutil.move(first, moved)
    assert main(["inventory", "import", str(moved), "--store", store]) == 0  # same flight
    other = _run_folder(tmp_path / "other" / "night", [("A-01-1", "5B", "identified")])
    capsys.readouterr()
    assert main(["inventory", "import", other, "--store", store]) == 2  # another flight
    assert "rename the folder to import it" in capsys.readouterr().err
    fleet = tmp_path / "fleet-run"
    drone = _run_folder(fleet / "drones" / "cf1", [("A-02-1", "4A", "identified")])
    (fleet / "fleet.json").write_text(json.dumps({"seed": 0}))
    assert main(["inventory", "import", drone, "--store", store]) == 2
    assert "import the fleet's folder" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args",
    [
        ["inventory", "history", "A-01-1", "--limit", "0"],
        ["inventory", "runs", "--limit", "-1"],
        ["gallery", "list", "g.sqlite", "--page", "0"],
        ["gallery", "list", "g.sqlite", "--per-page", "0"],
    ],
)
def test_counts_below_one_are_refused(args, capsys):
    """--limit 0 and -1 showed everything, --page 0 the first page."""
    try:
        rc = main(args)
    except SystemExit as exc:
        rc = exc.code
    assert rc == 2 and "a whole number >= 1" in capsys.readouterr().err


def test_a_killed_fleet_imports_with_its_drones_status(tmp_path, capsys):
    """A fleet killed outright writes no summary of its own (each drone's guard writes the
    drone's): it was imported as still `running`."""
    store = f"sqlite:///{tmp_path}/site.sqlite"
    fleet = tmp_path / "killed-fleet"
    _run_folder(fleet / "drones" / "cf1", [("A-01-1", "3A", "identified")])
    _run_folder(fleet / "drones" / "cf2", [("A-02-1", "4A", "identified")], status="ABORTED")
    (fleet / "fleet.json").write_text(json.dumps({"seed": 0}))
    shutil.copy(fleet / "drones" / "cf1" / "inventory.json", fleet / "inventory.json")
    assert main(["inventory", "import", str(fleet), "--store", store]) == 0
    capsys.readouterr()
    assert main(["inventory", "runs", "--store", store, "--json"]) == 0
    (run,) = json.loads(capsys.readouterr().out)
    assert run["status"] == "ABORTED"


@pytest.mark.parametrize("option", ["--groot", "--foxglove"])
def test_a_port_number_out_of_range_is_refused(option, capsys):
    """--groot 99999 said it served there and listened on 34463 (the number wrapped)."""
    try:
        rc = main(["missions/square.xml", option, "99999"])
    except SystemExit as exc:
        rc = exc.code
    assert rc == 2 and "expected a TCP port 1 to" in capsys.readouterr().err


def test_a_critical_battery_level_above_the_low_one_is_refused(tmp_path, capsys):
    rig = tmp_path / "r.yaml"
    rig.write_text("link: sim\nsafety: {battery_low_v: 3.0, battery_critical_v: 3.5}\n")
    assert main(["validate", str(rig)]) == 2
    err = capsys.readouterr().err
    assert f"{rig}:2:" in err and "battery_critical_v 3.5 V must be below battery_low_v 3 V" in err


def test_an_import_of_several_folders_checks_them_all_first(tmp_path, capsys):
    """It stopped at the first bad folder with exit 2 and no word of the good one before it,
    which it had already recorded."""
    store = f"sqlite:///{tmp_path}/site.sqlite"
    good = _run_folder(tmp_path / "night", [("A-01-1", "3A", "identified")])
    bad = tmp_path / "scan"
    bad.mkdir()
    assert main(["inventory", "import", good, str(bad), "--store", store]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: not an inventory run (no inventory.json)" in err
    assert "nothing imported (1 folder refused)" in err
    assert main(["inventory", "runs", "--store", store, "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == []
