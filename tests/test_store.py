"""The site store (store/): one interface on SQLite and on a real PostgreSQL server started
by the tests (conftest's ``postgresql_server``): schema and upgrade path, idempotent
recording, history, diff, two concurrent writers losing nothing, the recorder's thread."""

from __future__ import annotations

import multiprocessing
import os
import sqlite3
import threading
import time

import pytest

from store import InventoryStore, StoreError, default_url, parse_url, redact
from store.recorder import RunRecorder, start_recorder


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request, tmp_path) -> str:
    """A fresh empty store of each kind."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path}/site.sqlite"
    server = request.getfixturevalue("postgresql_server")
    name = "t_" + request.node.name.replace("[", "_").replace("]", "").replace("-", "_")[:50]
    return server.database(name.lower())


def _row(place: str, answer: str, status: str = "identified", **kw) -> dict:
    return {"place": place, "answer": answer, "status": status, **kw}


def test_urls_and_defaults(tmp_path, monkeypatch) -> None:
    assert parse_url("sqlite:///runs/site.sqlite").target == "runs/site.sqlite"
    assert parse_url("sqlite:////srv/site.sqlite").target == "/srv/site.sqlite"
    assert parse_url("site.sqlite").kind == "sqlite"
    pg = parse_url("postgresql://btrun:s3cret@db.site:5432/btrun")
    assert pg.kind == "postgresql" and "s3cret" not in pg.shown and "***" in pg.shown
    assert "s3cret" not in redact("postgresql://h/db?user=a&password=s3cret")
    with pytest.raises(StoreError, match="unknown scheme 'mysql'"):
        parse_url("mysql://h/db")
    monkeypatch.delenv("BTRUN_STORE", raising=False)
    assert default_url(str(tmp_path / "runs" / "inv-1")) == str(tmp_path / "runs" / "site.sqlite")
    assert default_url() == os.path.join("runs", "site.sqlite")
    monkeypatch.setenv("BTRUN_STORE", "postgresql://h/db")
    assert default_url("anything") == "postgresql://h/db"


def test_record_history_diff(store_url) -> None:
    with InventoryStore.open(store_url) as s:
        s.begin_run("inv-1", mission="missions/inventory.xml", seed=0, started=1000.0)
        s.record_rows("inv-1", [_row("A-01-1", "3A"), _row("A-01-2", "empty", "empty")])
        s.record_rows("inv-1", [_row("A-02-1", "4B", drone="cf2"), _row("A-04-1", "109A")])
        s.end_run("inv-1", "SUCCESS")
        s.begin_run("inv-2", started=2000.0, fleet="aisle_2")
        s.record_rows(
            "inv-2",
            [
                _row("A-01-1", "5A"),
                _row("A-01-2", "2B"),
                _row("A-02-1", "empty", "empty"),
                _row("A-03-1", "unknown", "unknown"),
                _row("A-04-1", "109B"),  # the same pallet, turned: not another one
            ],
        )
        # a re-record of the same run/place replaces: never a second row
        s.record_rows("inv-2", [_row("A-01-1", "5A", distance=0.25)])
        assert len(s.rows("inv-2")) == 5
        hist = s.history("A-01-1")
        assert [(h["run"], h["answer"]) for h in hist] == [("inv-1", "3A"), ("inv-2", "5A")]
        assert hist[1]["distance"] == 0.25 and hist[0]["run_status"] == "SUCCESS"
        assert [h["run"] for h in s.history("A-01-1", limit=1)] == ["inv-2"]
        changes = {d["place"]: d["change"] for d in s.diff("inv-1", "inv-2")}
        assert changes == {
            "A-01-1": "changed",
            "A-01-2": "appeared",
            "A-02-1": "disappeared",
            "A-03-1": "only in B",
            "A-04-1": "turned",
        }
        with pytest.raises(StoreError, match=r"no run 'inv-3' \(did you mean inv-[12]\?\)"):
            s.diff("inv-1", "inv-3")
        assert [r["run"] for r in s.runs()] == ["inv-1", "inv-2"]
        assert s.runs()[0]["rows"] == 4 and s.runs()[1]["status"] == "running"


def test_carried_rows_are_not_history_of_the_resumed_run(store_url) -> None:
    with InventoryStore.open(store_url) as s:
        s.begin_run("inv-1", started=1.0)
        s.record_rows("inv-1", [_row("A-01-1", "3A")])
        s.begin_run("inv-1-resumed", started=2.0)
        s.record_rows("inv-1-resumed", [_row("A-01-1", "3A", run="inv-1"), _row("A-01-2", "1B")])
        assert [h["run"] for h in s.history("A-01-1")] == ["inv-1"]
        assert not s.diff("inv-1", "inv-1-resumed")[0]["place"] == "A-01-1"


def test_a_run_name_of_another_folder_is_refused(store_url, tmp_path) -> None:
    with InventoryStore.open(store_url) as s:
        s.begin_run("inv-1", folder=str(tmp_path / "a" / "inv-1"))
        s.begin_run("inv-1", folder=str(tmp_path / "a" / "inv-1"))  # the same folder: fine
        with pytest.raises(StoreError, match="already recorded from .*--out"):
            s.check_run("inv-1", str(tmp_path / "b" / "inv-1"))


def test_schema_upgrade_path_and_newer_store(tmp_path) -> None:
    path = tmp_path / "site.sqlite"
    InventoryStore.open(str(path)).close()
    conn = sqlite3.connect(path)
    assert conn.execute("SELECT MAX(version) FROM store_schema").fetchone()[0] == 1
    conn.execute("INSERT INTO store_schema VALUES (99, 0)")
    conn.commit()
    conn.close()
    with pytest.raises(StoreError, match="store schema 99, this btrun knows up to 1"):
        InventoryStore.open(str(path))


def test_unreachable_postgresql_is_one_line_without_password() -> None:
    with pytest.raises(StoreError) as err:
        InventoryStore.open("postgresql://u:pw@127.0.0.1:1/db?connect_timeout=2")
    msg = str(err.value)
    assert "cannot connect" in msg and "pw" not in msg.replace("postgresql", "")
    assert "\n" not in msg


def _writer(url: str, run: str, places: int, barrier) -> None:
    s = InventoryStore.open(url)
    barrier.wait(60)  # a partner that failed to open must not leave this one waiting
    s.begin_run(run)
    for i in range(places):  # one transaction per row, as a flight records
        s.record_rows(run, [_row(f"P-{i:03d}", f"{i}A", drone=run)])
    s.end_run(run, "SUCCESS")
    s.close()


def test_two_fleets_writing_at_once_lose_nothing(store_url) -> None:
    """Two processes (two fleets) record into one store at the same moment: every row of
    both is there, and the store was created once."""
    ctx = multiprocessing.get_context("spawn")
    barrier = ctx.Barrier(2)
    places = 60
    procs = [
        ctx.Process(target=_writer, args=(store_url, run, places, barrier), daemon=True)
        for run in ("fleet-a", "fleet-b")
    ]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
    codes = [p.exitcode for p in procs]
    for p in procs:  # a writer still waiting would hold pytest's exit
        if p.is_alive():
            p.kill()
    assert codes == [0, 0]
    with InventoryStore.open(store_url) as s:
        assert s.version() == 1
        for run in ("fleet-a", "fleet-b"):
            assert len(s.rows(run)) == places and s.run(run)["status"] == "SUCCESS"
        assert len(s.history("P-007")) == 2


def test_threads_writing_at_once_lose_nothing(store_url) -> None:
    errors: list[BaseException] = []

    def write(run: str) -> None:
        try:
            with InventoryStore.open(store_url) as s:
                s.begin_run(run)
                for i in range(30):
                    s.record_rows(run, [_row(f"P-{i:02d}", "1A")])
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=write, args=(f"t{k}",)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    with InventoryStore.open(store_url) as s:
        assert sum(r["rows"] for r in s.runs()) == 120


def test_recorder_writes_changes_and_survives_a_store_that_goes_away(tmp_path) -> None:
    url = str(tmp_path / "site.sqlite")
    said: list[str] = []
    rec = start_recorder(url, "inv-1", str(tmp_path / "inv-1"), lambda: {"seed": 3}, said.append)
    rec.record([_row("A-01-1", "3A")])
    rec.record([_row("A-01-1", "3A"), _row("A-01-2", "empty", "empty")])
    assert rec.finish("SUCCESS", timeout=10)
    with InventoryStore.open(url) as s:
        assert s.run("inv-1")["status"] == "SUCCESS" and s.run("inv-1")["seed"] == 3
        assert len(s.rows("inv-1")) == 2
    # a store that fails mid-run: a message, the rows kept for later, no exception
    broken = RunRecorder(InventoryStore.open(url), str(tmp_path / "nowhere" / "x" / "y"), "inv-2")
    broken._say = said.append
    broken.store.close()  # the next write fails; reconnecting fails too (no such folder)
    broken.url = "postgresql://u@127.0.0.1:1/db?connect_timeout=1"
    broken.record([_row("A-01-1", "2B")])
    t0 = time.monotonic()
    assert broken.finish("SUCCESS", timeout=1.0) is False
    assert time.monotonic() - t0 < 5
    assert any("cannot record inv-2" in m and "run folder keeps every row" in m for m in said)


def test_many_opening_a_new_store_file_at_once_all_get_it(tmp_path) -> None:
    """Six writers opening a store file that does not exist yet, at the same moment (fleets
    started together on one store): every one opens it. Switching the new file to WAL used
    to answer "database is locked" at once, in about one such start in ten, without
    waiting for the busy timeout."""
    failed = []
    for attempt in range(80):
        url = f"sqlite:///{tmp_path / f'site{attempt}.sqlite'}"
        barrier = threading.Barrier(6)
        errors: list[BaseException] = []

        def open_it(url: str = url, barrier: threading.Barrier = barrier, errors=errors) -> None:
            try:
                barrier.wait(30)
                InventoryStore.open(url).close()
            except BaseException as exc:  # noqa: BLE001 - reported below
                errors.append(exc)

        threads = [threading.Thread(target=open_it) for _ in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        failed += [f"attempt {attempt}: {e}" for e in errors]
    assert not failed, failed[:3]


def test_rows_the_store_did_not_take_in_time_name_the_folder_to_import(tmp_path) -> None:
    """The end-of-run line printed a literal "<run folder>" for the user to fill in."""
    import sqlite3

    from store.recorder import start_recorder

    url, folder, said = f"sqlite:///{tmp_path}/site.sqlite", str(tmp_path / "inv-7"), []
    rec = start_recorder(url, "inv-7", folder, say=said.append)
    lock = sqlite3.connect(tmp_path / "site.sqlite", isolation_level=None)
    lock.execute("BEGIN EXCLUSIVE")  # another writer holds the store
    try:
        rec.record([_row("A-01-1", "3A")])
        assert rec.finish("SUCCESS", timeout=0.3) is False
    finally:
        lock.execute("ROLLBACK")
        lock.close()
    assert any(f"btrun inventory import {folder} --store" in m for m in said), said


def test_diff_tells_pallets_apart_as_history_does() -> None:
    """``pal-7A`` -> ``PAL-7B`` and ``0115A`` -> ``115B`` had been "changed" (another
    pallet): case and zero padding do not tell pallets apart, so they are "turned"; the
    same answer spelled otherwise is no change."""
    from store.diff import diff_rows

    a = [("A", "pal-7A"), ("B", "0115A"), ("C", "PAL-7A"), ("D", "109A"), ("E", "0109")]
    b = [("A", "PAL-7B"), ("B", "115B"), ("C", "pal-7a"), ("D", "110A"), ("E", "109")]
    rows_a = [{"place": p, "answer": x} for p, x in a]
    rows_b = [{"place": p, "answer": x} for p, x in b]
    assert [(r["place"], r["change"]) for r in diff_rows(rows_a, rows_b)] == [
        ("A", "turned"),
        ("B", "turned"),
        ("D", "changed"),
    ]
