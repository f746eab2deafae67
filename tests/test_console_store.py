"""btrun console with the site store: the runs the store knows without a folder here are
listed (marked as from the store), a place's history across runs is served in order, bad
place names are refused, an unreachable store is one line and exit code 2 at start, and a
store lost later leaves the pages working from the runs folder with a note. A small run
folder and an SQLite store made here (PostgreSQL too when its binaries are there); no
flight and no browser."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import urllib.error
import urllib.request

import pytest
from console_helpers import REPO, TOKEN, browser_page

from nodes.console.app import ConsoleConfig
from nodes.console.cli import ConsoleError, ConsoleServer, make_config
from nodes.inventory_log import write_inventory
from store import InventoryStore, parse_url

HERE = "inventory-20261126-090000"  # a folder under runs/ and in the store
ELSEWHERE = "aisle_2-20261125-080000"  # only in the store (another ground station)
OLDEST = "inventory-20261120-070000"  # only in the store, flown first


def _row(place: str, answer: str, status: str) -> dict:
    return {"place": place, "answer": answer, "status": status, "drone": "aisle"}


def _record(url: str) -> None:
    """Three runs, recorded out of order: OLDEST, then HERE, then ELSEWHERE started between."""
    with InventoryStore.open(url) as s:
        s.begin_run(
            HERE,
            mission="missions/inventory.xml",
            rig="/gs1/btrun/rigs/site.yaml",
            started=3000.0,
            host="gs-1",
        )
        s.record_rows(HERE, [_row("A-01-1", "101", "identified"), _row("A-01-2", "", "unknown")])
        s.end_run(HERE, "SUCCESS")
        s.begin_run(OLDEST, mission="missions/inventory.xml", started=1000.0, host="gs-2")
        s.record_rows(OLDEST, [_row("A-01-1", "empty", "empty")])
        s.end_run(OLDEST, "SUCCESS")
        s.begin_run(ELSEWHERE, mission="fleets/aisle_2.yaml", fleet="aisle_2", started=2000.0)
        s.record_rows(
            ELSEWHERE,
            [
                _row("A-01-1", "101", "identified"),
                _row("A-01-2", "", "not_scanned"),
                _row("A-02-1", "7A", "identified"),
            ],
        )
        s.end_run(ELSEWHERE, "FAILURE")


@pytest.fixture
def runs(tmp_path) -> str:
    """runs/<HERE> with two rows (no store inside: the tests name one)."""
    root = tmp_path / "runs"
    run = root / HERE
    run.mkdir(parents=True)
    (run / "ticks.jsonl").write_text('{"header": {"mission": "missions/inventory.xml"}}\n')
    rows = [_row("A-01-1", "101", "identified"), _row("A-01-2", "unknown", "unknown")]
    write_inventory(str(run), [{**r, "run": HERE} for r in rows], ["A-01-1", "A-01-2"])
    return str(root)


@pytest.fixture
def sqlite_store(tmp_path) -> str:
    """An SQLite store beside the runs folder with the three runs."""
    url = f"sqlite:///{tmp_path / 'elsewhere' / 'site.sqlite'}"
    _record(url)
    return url


def _get(server: ConsoleServer, path: str) -> tuple[int, object]:
    """GET ``path``: the status and the JSON (or the text of a page)."""
    try:
        with urllib.request.urlopen(server.url + path, timeout=10) as r:
            status, body, kind = r.status, r.read(), r.headers.get("content-type", "")
    except urllib.error.HTTPError as exc:
        status, body, kind = exc.code, exc.read(), exc.headers.get("content-type", "")
    return status, json.loads(body) if kind.startswith("application/json") else body.decode()


def _serve(runs: str, url: str | None) -> ConsoleServer:
    return ConsoleServer(ConsoleConfig(runs, TOKEN, None, url), "127.0.0.1", 0).start()


def _check_listing_and_history(runs: str, url: str) -> None:
    server = _serve(runs, url)
    try:
        status, doc = _get(server, "/api/runs")
        assert status == 200 and doc["store_note"] is None
        assert doc["store"] == parse_url(url).shown  # no password
        by = {r["name"]: r for r in doc["runs"]}
        assert [r["name"] for r in doc["runs"]] == [HERE, ELSEWHERE, OLDEST]
        assert by[HERE]["source"] == "folder"
        other = by[ELSEWHERE]
        assert other["source"] == "store" and other["kind"] == "fleet"
        assert (other["mission"], other["status"]) == ("aisle_2.yaml", "FAILURE")
        assert (other["places"], other["answered"]) == (3, 2)
        assert _get(server, "/")[0] == 200
        status, doc = _get(server, "/api/places/A-01-1")
        assert status == 200
        assert [h["run"] for h in doc["history"]] == [OLDEST, ELSEWHERE, HERE]
        assert [h["answer"] for h in doc["history"]] == ["empty", "101", "101"]
        assert [h["here"] for h in doc["history"]] == [False, False, True]
        assert "folder" not in doc["history"][0]  # another station's paths are not shown
        rigs = [(h["rig"], h["fleet"]) for h in doc["history"]]
        assert rigs == [(None, None), (None, "aisle_2"), ("site.yaml", None)]
        status, page = _get(server, "/places/A-01-1")
        assert status == 200 and 'data-page="place"' in page
        with browser_page() as tab:  # the rig or fleet of each run, side by side
            tab.goto(f"{server.url}/places/A-01-1")
            tab.locator("#history tbody tr").first.wait_for()
            assert tab.inner_text("#history thead th:last-child") == "rig or fleet"
            cells = tab.locator("#history tbody td:last-child").all_inner_texts()
            assert cells == ["", "aisle_2 (fleet)", "site.yaml"]
            assert "flown by fleet aisle_2, rig site.yaml" in tab.inner_text("#history-rigs")
            assert not tab.errors
        status, doc = _get(server, f"/api/runs/{HERE}")
        assert status == 200 and doc["store"]
        status, doc = _get(server, "/api/places/A-01-9")
        assert status == 404 and "did you mean" in doc["error"]
        status, doc = _get(server, "/api/places/a-01-1")  # case and leading zeros first
        assert status == 404 and "did you mean A-01-1?" in doc["error"], doc
    finally:
        server.stop()


def test_runs_from_the_store_are_listed_and_a_places_history_is_in_order(runs, sqlite_store):
    _check_listing_and_history(runs, sqlite_store)


def test_the_same_on_postgresql(runs, postgresql_server):
    url = postgresql_server.database("console_store")
    _record(url)
    _check_listing_and_history(runs, url)


@pytest.mark.parametrize(
    "path",
    [
        "/api/places/..",
        "/api/places/..%2f..%2fsecret",
        "/api/places/%2e%2e",
        "/api/places/a%20b",
        "/api/places/-A-01-1",
        "/api/places/A-01-1%00",
        "/api/places/" + "A" * 65,
        "/places/..%2fx",
        "/places/a%5cb",
    ],
)
def test_bad_place_names_are_refused(runs, sqlite_store, path):
    server = _serve(runs, sqlite_store)
    try:
        status, _ = _get(server, path)
    finally:
        server.stop()
    assert status in (400, 404)


def test_without_a_store_the_console_is_the_runs_folder(runs):
    server = _serve(runs, None)
    try:
        status, doc = _get(server, "/api/runs")
        assert status == 200 and doc["store"] is None
        assert [r["name"] for r in doc["runs"]] == [HERE]
        status, doc = _get(server, "/api/places/A-01-1")
        assert status == 404 and "--store" in doc["error"]
    finally:
        server.stop()


def test_a_store_lost_later_leaves_the_runs_folder_with_a_note(runs, sqlite_store):
    server = _serve(runs, sqlite_store)
    try:
        assert len(_get(server, "/api/runs")[1]["runs"]) == 3
        path = sqlite_store.removeprefix("sqlite:///")
        for suffix in ("", "-wal", "-shm"):
            if os.path.exists(path + suffix):
                os.remove(path + suffix)
        server.app.state.site.close()
        status, doc = _get(server, "/api/runs")
        assert status == 200 and [r["name"] for r in doc["runs"]] == [HERE]
        assert "cannot be read" in doc["store_note"] and "no store file" in doc["store_note"]
        assert _get(server, f"/api/runs/{HERE}")[0] == 200
        status, doc = _get(server, "/api/places/A-01-1")
        assert status == 503 and "cannot be read" in doc["error"]
    finally:
        server.stop()


def _args(runs: str, store: str | None) -> argparse.Namespace:
    return argparse.Namespace(runs=runs, token=TOKEN, gallery=None, host="127.0.0.1", store=store)


def test_the_default_store_is_the_runs_folders_if_it_has_one(runs, monkeypatch):
    monkeypatch.delenv("BTRUN_STORE", raising=False)
    assert make_config(_args(runs, None)).store is None
    _record(os.path.join(runs, "site.sqlite"))
    assert make_config(_args(runs, None)).store == os.path.join(runs, "site.sqlite")
    assert make_config(_args(runs, "none")).store is None
    with pytest.raises(ConsoleError, match="--store: .*no store file"):
        make_config(_args(runs, os.path.join(runs, "nope.sqlite")))


def test_an_unreachable_store_is_one_line_and_exit_2(runs, tmp_path):
    for url in ("postgresql://btrun:s3cret@127.0.0.1:1/btrun", f"sqlite:///{tmp_path}/no.sqlite"):
        r = subprocess.run(
            [sys.executable, "-m", "btrun_launcher", "console", "--runs", runs, "--store", url],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("btrun console: --store: "), lines
        assert "s3cret" not in r.stderr
