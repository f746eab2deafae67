"""The site store from btrun's side: runs and fleets recording their rows (SQLite by
default, PostgreSQL with --store), ``btrun inventory history|diff|runs|import``, and an
unusable store refused before flight."""

from __future__ import annotations

import json
import os

import pytest
from helpers import REPO

from bt_engine.cli import main
from nodes.inventory_log import write_inventory
from store import InventoryStore

FLEET = os.path.join(REPO, "fleets", "aisle_2.yaml")
MISSION = os.path.join(REPO, "missions", "inventory.xml")


def _run_folder(path, rows: list[tuple[str, str, str]], status: str = "SUCCESS") -> str:
    """A finished inventory run folder written directly (no flight)."""
    os.makedirs(path, exist_ok=True)
    full = [
        {"place": p, "answer": a, "status": s, "drone": "cf1", "run": os.path.basename(path)}
        for p, a, s in rows
    ]
    write_inventory(str(path), full, [r[0] for r in rows])
    with open(os.path.join(path, "ticks.jsonl"), "w") as f:
        f.write(json.dumps({"header": {"mission": MISSION, "seed": 4, "rig": "rigs/aisle.yaml"}}))
        f.write("\n")
    with open(os.path.join(path, "summary.json"), "w") as f:
        json.dump({"status": status}, f)
    return str(path)


def test_import_history_diff_commands(tmp_path, capsys) -> None:
    store = f"sqlite:///{tmp_path}/site.sqlite"
    a = _run_folder(
        tmp_path / "inventory-20261101-080000",
        [("A-01-1", "3A", "identified"), ("A-01-2", "empty", "empty")],
    )
    b = _run_folder(
        tmp_path / "inventory-20261102-080000",
        [("A-01-1", "5B", "identified"), ("A-01-2", "2A", "identified")],
        status="FAILURE",
    )
    assert main(["inventory", "import", a, b, "--store", store]) == 0
    assert "imported inventory-20261102-080000: 2 rows" in capsys.readouterr().out
    assert main(["inventory", "import", a, "--store", store]) == 0  # again: no duplicate
    capsys.readouterr()
    assert main(["inventory", "history", "A-01-1", "--store", store, "--json"]) == 0
    hist = json.loads(capsys.readouterr().out)
    assert [(h["run"], h["answer"], h["run_status"]) for h in hist] == [
        ("inventory-20261101-080000", "3A", "SUCCESS"),
        ("inventory-20261102-080000", "5B", "FAILURE"),
    ]
    assert main(["inventory", "history", "A-01-1", "--store", store]) == 0
    out = capsys.readouterr().out
    assert "A-01-1: 2 runs" in out and "5B" in out and "cf1" in out
    assert main(["inventory", "diff", "inventory-20261101-080000", b, "--store", store]) == 0
    out = capsys.readouterr().out
    assert "1 appeared, 1 changed" in out and "3A" in out and "5B" in out
    assert main(["inventory", "runs", "--store", store, "--json"]) == 0
    runs = json.loads(capsys.readouterr().out)
    assert [(r["rows"], r["seed"]) for r in runs] == [(2, 4), (2, 4)]
    # unknown runs and places: one line, exit 2, did you mean
    assert main(["inventory", "diff", "inventory-20261101-08000", b, "--store", store]) == 2
    err = capsys.readouterr().err
    assert "did you mean inventory-20261101-080000?" in err and err.count("\n") == 1
    assert main(["inventory", "history", "A-1-1", "--store", store]) == 2
    assert "did you mean A-01-1?" in capsys.readouterr().err
    assert main(["inventory", "import", str(tmp_path / "nope"), "--store", store]) == 2
    assert "no such run folder" in capsys.readouterr().err


def test_an_unreachable_store_is_refused_before_flight(tmp_path, capsys) -> None:
    out = str(tmp_path / "f")
    bad = "postgresql://btrun:pw@127.0.0.1:1/site?connect_timeout=2"
    code = main(["fleet", FLEET, "--out", out, "--store", bad, "-q", "--set", "places=A-01-1"])
    err = capsys.readouterr().err
    assert code == 2 and "--store" in err and "cannot connect" in err and ":pw@" not in err
    assert "Traceback" not in err and not os.path.exists(os.path.join(out, "drones"))


@pytest.mark.slow
def test_a_fleet_records_into_postgresql_and_history_diff_read_it(
    tmp_path, capsys, postgresql_server
) -> None:
    """Two fleet runs of two places each into PostgreSQL; the store holds every row the
    run folders hold; history and diff read them back."""
    url = postgresql_server.database("fleet_store")
    runs = []
    for k, seed in enumerate((0, 5)):
        out = str(tmp_path / f"aisle_2-{k}")
        args = ["fleet", FLEET, "--out", out, "--store", url, "--seed", str(seed), "-q"]
        args += ["--no-report", "--no-mcap", "--set", "places=A-01-1;A-08-1"]
        assert main(args) == 0
        runs.append(out)
    capsys.readouterr()
    with InventoryStore.open(url) as s:
        for out in runs:
            with open(os.path.join(out, "inventory.json")) as f:
                on_disk = {r["place"]: r["answer"] for r in json.load(f)["rows"]}
            name = os.path.basename(out)
            assert {r["place"]: r["answer"] for r in s.rows(name)} == on_disk
            assert s.run(name)["status"] == "SUCCESS" and s.run(name)["fleet"] == "aisle_2"
            assert {r["drone"] for r in s.rows(name)} == {"cf1", "cf2"}
    assert main(["inventory", "history", "A-08-1", "--store", url, "--json"]) == 0
    hist = json.loads(capsys.readouterr().out)
    assert [h["run"] for h in hist] == ["aisle_2-0", "aisle_2-1"]
    assert main(["inventory", "diff", "aisle_2-0", "aisle_2-1", "--store", url, "--json"]) == 0
    diff = json.loads(capsys.readouterr().out)
    assert diff["a"] == "aisle_2-0" and isinstance(diff["changes"], list)


@pytest.mark.slow
def test_a_solo_run_records_into_the_default_sqlite_store(tmp_path, monkeypatch) -> None:
    monkeypatch.delenv("BTRUN_STORE", raising=False)
    out = tmp_path / "runs" / "inv-1"
    args = [MISSION, "--rig", os.path.join(REPO, "rigs", "aisle.yaml"), "--out", str(out)]
    args += ["--set", "places=A-01-1", "-q", "--no-report", "--no-mcap"]
    assert main(args) == 0
    with InventoryStore.open(str(tmp_path / "runs" / "site.sqlite")) as s:
        run = s.run("inv-1")
        assert run["status"] == "SUCCESS" and run["mission"] == MISSION and run["seed"] == 0
        rows = s.rows("inv-1")
        assert [r["place"] for r in rows] == ["A-01-1"] and rows[0]["drone"] == "aisle"


def test_a_run_folder_without_a_date_keeps_its_start(tmp_path, capsys) -> None:
    """A folder named with --out, or copied, has no stamp in its name, and its files' times
    are the copy's: the store's import and the console's run list take the tick log
    header's ``started`` (a fleet: fleet.json's), not the files' times."""
    from nodes.console.paths import RunsRoot
    from nodes.console.runs import run_info

    root = tmp_path / "runs"
    run = _run_folder(root / "night-shift", [("A-01-1", "3A", "identified")])
    with open(os.path.join(run, "ticks.jsonl"), "w") as f:
        header = {"mission": MISSION, "seed": 4, "started": "2026-11-01T08:00:00Z"}
        f.write(json.dumps({"header": header}) + "\n")
    fleet = _run_folder(root / "copied-fleet", [("A-01-2", "5B", "identified")])
    with open(os.path.join(fleet, "fleet.json"), "w") as f:
        json.dump({"fleet": FLEET, "seed": 1, "started": "2026-11-02T08:00:00+00:00"}, f)
    when = {"night-shift": 1793520000.0, "copied-fleet": 1793606400.0}
    for name, started in when.items():
        assert run_info(RunsRoot(str(root)), name)["started"] == started
    store = f"sqlite:///{tmp_path}/site.sqlite"
    assert main(["inventory", "import", run, fleet, "--store", store]) == 0
    capsys.readouterr()
    assert main(["inventory", "runs", "--store", store, "--json"]) == 0
    runs = json.loads(capsys.readouterr().out)
    assert {r["run"]: r["started"] for r in runs} == when


@pytest.mark.parametrize("db", ["sqlite", "postgresql"])
def test_where_a_pallet_was_seen_run_by_run(tmp_path, capsys, request, db) -> None:
    """History took only a place: 'history 111' said "no row for place '111'"."""
    store = f"sqlite:///{tmp_path}/site.sqlite"
    if db == "postgresql":
        store = request.getfixturevalue("postgresql_server").database("pallet_history")
    a = _run_folder(
        tmp_path / "inventory-20261101-080000",
        [("A-01-1", "111A", "identified"), ("A-01-2", "1110B", "identified")],
    )
    b = _run_folder(tmp_path / "inventory-20261102-080000", [("B-03-2", "111B", "identified")])
    assert main(["inventory", "import", a, b, "--store", store]) == 0
    capsys.readouterr()
    assert main(["inventory", "history", "--pallet", "0111", "--store", store, "--json"]) == 0
    seen = [
        (h["run"][-15:-7], h["place"], h["answer"]) for h in json.loads(capsys.readouterr().out)
    ]
    assert seen == [("20261101", "A-01-1", "111A"), ("20261102", "B-03-2", "111B")]
    assert main(["inventory", "history", "111", "--store", store]) == 2
    assert "(where a pallet was seen: history --pallet 111)" in capsys.readouterr().err


@pytest.mark.parametrize("db", ["sqlite", "postgresql"])
def test_a_pallet_named_with_non_ascii_letters_is_found_in_any_case(
    tmp_path, capsys, request, db
) -> None:
    """SQLite's LOWER folds ASCII only: 'ÄB-7A' was never found on the default store, in
    any spelling, while PostgreSQL found it; a name both databases fold unlike Python
    (final sigma) is found as written."""
    store = f"sqlite:///{tmp_path}/site.sqlite"
    if db == "postgresql":
        store = request.getfixturevalue("postgresql_server").database("pallet_unicode")
    rows = [("A-01-1", "ÄB-7A", "identified"), ("A-01-2", "ΣΊΣΥΦΟΣ-3B", "identified")]
    a = _run_folder(tmp_path / "inventory-20261101-080000", rows)
    assert main(["inventory", "import", a, "--store", store]) == 0
    capsys.readouterr()
    for query, place in [("ÄB-7", "A-01-1"), ("äb-7", "A-01-1"), ("ΣΊΣΥΦΟΣ-3", "A-01-2")]:
        assert main(["inventory", "history", "--pallet", query, "--store", store, "--json"]) == 0
        found = json.loads(capsys.readouterr().out)
        assert [h["place"] for h in found] == [place], (query, found)


def test_a_damaged_store_is_one_line_not_a_traceback(tmp_path, capsys) -> None:
    """A store file with damaged pages opened, then history --pallet and diff ended in
    sqlite3.DatabaseError's traceback."""
    path = tmp_path / "site.sqlite"
    store = f"sqlite:///{path}"
    rows = [(f"A-{b:02d}-{lv}", f"{100 + b}A", "identified") for b in range(1, 40) for lv in (1, 2)]
    a = _run_folder(tmp_path / "inventory-20261101-080000", rows)
    b = _run_folder(tmp_path / "inventory-20261102-080000", rows)
    assert main(["inventory", "import", a, b, "--store", store]) == 0
    data = bytearray(path.read_bytes())
    page = 4096
    for n in range(1, len(data) // page):  # every page but the header's: garbage inside
        data[n * page + 200 : n * page + 1200] = b"\xa5" * 1000
    path.write_bytes(bytes(data))
    for wal in (tmp_path / "site.sqlite-wal", tmp_path / "site.sqlite-shm"):
        if wal.exists():
            wal.unlink()
    capsys.readouterr()
    names = [os.path.basename(a), os.path.basename(b)]
    for argv in (["history", "--pallet", "101"], ["diff", *names]):
        code = main(["inventory", *argv, "--store", store])
        err = capsys.readouterr().err
        assert "Traceback" not in err
        if code != 0:
            assert code == 2 and f"btrun inventory: {store}: the store" in err, err
            assert "the store cannot be used:" in err and "PRAGMA integrity_check" in err
