"""Review 49 of btrun console: a review gallery per world (never another world's pallets), live
views that do not hold a browser's connections in hidden tabs and say when they are refused,
reviewed places recategorised in the discrepancies export, a refused token asked again, the
keyboard focus kept across redraws, a decision taken once on a double click, no export of a
run without rows, a Host allow-list on a LAN bind, and the smaller findings (unlisted places,
accuracy of an interrupted run, store-only runs, contrast and names of the rack drawings, a
damaged review file)."""

from __future__ import annotations

import argparse
import http.client
import json
import os
import socket
import sqlite3
import urllib.error
import urllib.request

import pytest
from console_helpers import REPO, TOKEN, browser_page, console, make_run, wait_for

from nodes.console import export
from nodes.console.app import ConsoleConfig
from nodes.console.cli import ConsoleError, ConsoleServer, allowed_hosts, make_config
from nodes.console.files import write_review
from nodes.console.paths import RunsRoot
from nodes.console.review import (
    WORLD_META,
    GalleryDesk,
    ReviewError,
    decide,
    gallery_choice,
    gallery_world,
)
from nodes.console.runs import run_info

RUN = "inventory-20261126-101500"


def _row(place: str, answer: str, status: str, **extra) -> dict:
    row = {"place": place, "answer": answer, "status": status, "best_id": None}
    row.update(distance=None, margin=None, blocks_seen=3, mission_time_s=10.0)
    row.update(drone="", run=RUN, reason=None, **extra)
    return row


_run = make_run


def _discrepancies(run, rows: list[dict]) -> None:
    doc = {"format": "btrun-discrepancies-1", "rows": rows}
    (run / "discrepancies.json").write_text(json.dumps(doc))


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


@pytest.fixture
def root(tmp_path):
    (tmp_path / "runs").mkdir()
    return tmp_path / "runs"


# ---- 1. a review gallery per world ---------------------------------------------------------
def _world_run(root, name: str, rig: str) -> None:
    header = {"rig": f"rigs/{rig}.yaml", "cwd": REPO, "seed": 0}
    _run(root, name, [_row("A-01-1", "unknown", "unknown")], ["A-01-1"], header)


def test_runs_of_two_worlds_get_a_review_gallery_each(root):
    """One site-gallery.sqlite per runs folder was copied from the first decision's world,
    and a site run's review then offered the aisle's pallets and enrolled the site's own
    again: each world now has its review gallery, named after it."""
    _world_run(root, "aisle-run", "aisle")
    _world_run(root, "site-run", "site")
    r = RunsRoot(str(root))
    aisle = gallery_choice(r, r.run_dir("aisle-run"), None)
    site = gallery_choice(r, r.run_dir("site-run"), None)
    assert aisle["source"] == site["source"] == "world"
    assert aisle["path"] != site["path"]
    assert os.path.basename(aisle["path"]).startswith("site-gallery-aisle-")
    assert os.path.basename(site["path"]).startswith("site-gallery-site-")
    assert os.path.dirname(aisle["path"]) == str(root)
    # a world whose demo gallery enrols other pallets (not_enrolled) is another world too
    header = {"rig": "rigs/site.yaml", "cwd": REPO, "seed": 0}
    header["sets"] = ["world.stock.not_enrolled=[1121,1122]"]
    _run(root, "site-other", [_row("A-01-1", "unknown", "unknown")], ["A-01-1"], header)
    other = gallery_choice(r, r.run_dir("site-other"), None)
    assert other["path"] not in (site["path"], aisle["path"]), other


def test_a_gallery_started_for_another_world_is_refused(root, tmp_path):
    """A gallery the console started for the aisle, given as --gallery to review a site run:
    refused with both worlds named, before anything is learnt."""
    from perception.gallery import Gallery

    _world_run(root, "aisle-run", "aisle")
    _world_run(root, "site-run", "site")
    r = RunsRoot(str(root))
    aisle = gallery_choice(r, r.run_dir("aisle-run"), None)
    gallery = str(tmp_path / "g.sqlite")
    Gallery.create(gallery, "m1", 4).close()
    with sqlite3.connect(gallery) as conn:
        conn.execute("INSERT INTO meta VALUES (?, ?)", (WORLD_META, aisle["world"]))
    conn.close()
    request = {"place": "A-01-1", "decision": "new_pallet", "new_name": "X1", "reviewer": "d"}
    with pytest.raises(ReviewError) as exc:
        decide(r, "site-run", request, gallery, GalleryDesk())
    assert exc.value.status == 409
    assert aisle["world"] in str(exc.value) and "site-" in str(exc.value)
    # the page says so before any decision
    with console(str(root), gallery=gallery) as server:
        status, body = _get(f"{server.url}/api/runs/site-run")
    g = json.loads(body)["gallery"]
    assert status == 200 and g["path"] == gallery and aisle["world"] in g["problem"]
    assert g["identities"] == []


def test_a_new_review_gallery_records_its_world(root, tmp_path):
    """The copy of the demo gallery records the world it was made for (what refuses another
    world's runs later); the session is the run's rig with its world.* items."""
    from perception.gallery import Gallery

    _world_run(root, "site-run", "site")
    r = RunsRoot(str(root))
    choice = gallery_choice(r, r.run_dir("site-run"), None)
    demo_path = str(tmp_path / "demo.sqlite")
    Gallery.create(demo_path, "m1", 4).close()
    demo = Gallery.open(demo_path, "m1")

    class Emb:
        model_version = "m1"

    class Session:
        def embedder(self, path=""):
            return Emb()

        def gallery(self, spec, emb):
            assert spec == "demo"
            return demo

    desk = GalleryDesk()
    seen = []
    desk.session = lambda rig, sets=(): seen.append((rig, sets)) or Session()
    header_rig = os.path.join(REPO, "rigs", "site.yaml")
    _, g = desk.open(choice["path"], header_rig, ("world.x=1",), choice["world"])
    g.close()
    demo.close()
    assert seen == [(header_rig, ("world.x=1",))]
    assert gallery_world(choice["path"]) == choice["world"]


def test_the_review_page_names_the_gallery_of_the_run(root):
    _world_run(root, "site-run", "site")
    r = RunsRoot(str(root))
    path = gallery_choice(r, r.run_dir("site-run"), None)["path"]
    with console(str(root)) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/site-run/review")
        page.locator("#gallery-path").wait_for()
        assert page.inner_text("#gallery-path") == path
        note = page.inner_text("#gallery-note")
        assert "review gallery of this run's world site-" in note
        assert "copy of that world's demo gallery" in note
        assert not page.errors
        page.goto(f"{server.url}/runs/site-run")
        page.locator("#map").wait_for()
        assert page.get_attribute("#map", "aria-label").startswith("map, top view")
        assert not page.errors


# ---- 2. live views -------------------------------------------------------------------------
def _running(root):
    run = _run(root, "live-run", [_row("A-01-1", "101A", "identified")], ["A-01-1", "A-01-2"])
    return run


def _hide(page, hidden: bool) -> None:
    page.evaluate(
        """(hidden) => {
        Object.defineProperty(document, "hidden", { configurable: true, get: () => hidden });
        Object.defineProperty(document, "visibilityState", { configurable: true,
          get: () => (hidden ? "hidden" : "visible") });
        document.dispatchEvent(new Event("visibilitychange"));
    }""",
        hidden,
    )


def test_a_hidden_tab_lets_go_of_its_live_stream(root):
    """Each page of a running run held an event stream for good: six tabs took every
    connection a browser has for the console. A hidden tab closes it and says so; shown
    again, it follows the run again."""
    _running(root)
    with console(str(root)) as server, browser_page() as page:
        streams = server.app.state.streams
        page.goto(f"{server.url}/runs/live-run")
        page.locator("#run-status").wait_for()
        wait_for(lambda: streams["open"] == 1, what="the live stream")
        assert "live" in page.inner_text("#live-state")
        _hide(page, True)
        wait_for(lambda: streams["open"] == 0, what="the hidden tab to close its stream")
        assert "paused while this tab is hidden" in page.inner_text("#live-state")
        _hide(page, False)
        wait_for(lambda: streams["open"] == 1, what="the stream again")
        wait_for(lambda: "paused" not in page.inner_text("#live-state"), what="the note")
        assert not page.errors


def test_a_refused_live_view_is_said_on_the_page(root, monkeypatch):
    """The 17th live view got 503 and the page went quiet: it says so, and checks again."""
    import nodes.console.app as app_module

    _running(root)
    monkeypatch.setattr(app_module, "MAX_STREAMS", 0)
    with console(str(root)) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/live-run")
        wait_for(
            lambda: "live view refused" in (page.text_content("#live-state") or ""),
            what="the refusal on the page",
        )
        assert "checks for changes every 10 s" in page.inner_text("#live-state")


# ---- 3. the export after a review ----------------------------------------------------------
def test_a_reviewed_place_is_recategorised_in_the_discrepancies(root):
    """A-02-1 was a mismatch (106 found, 109 expected, moved from A-01-1); the operator
    reviewed it as 109A: it is confirmed, not exported as a mismatch moved from A-01-1. A-03-1
    reviewed as 109B is a mismatch moved from A-02-1 (where 109 is expected)."""
    rows = [
        _row("A-01-1", "109B", "identified"),
        _row("A-02-1", "106A", "identified"),
        _row("A-03-1", "unknown", "unknown"),
    ]
    run = _run(root, RUN, rows, ["A-01-1", "A-02-1", "A-03-1"])
    _discrepancies(
        run,
        [
            {"place": "A-01-1", "expected": "106", "category": "mismatch", "moved_from": "A-02-1"},
            {"place": "A-02-1", "expected": "109", "category": "mismatch", "moved_from": "A-01-1"},
            {"place": "A-03-1", "expected": "110", "category": "unverified", "moved_from": ""},
        ],
    )
    decisions = [
        {"place": "A-02-1", "answer": "109A", "decision": "identity", "reviewer": "frank"},
        {"place": "A-03-1", "answer": "109B", "decision": "identity", "reviewer": "frank"},
    ]
    write_review(str(run), decisions)
    info = run_info(RunsRoot(str(root)), RUN, True)
    _, lines = export.table(info, "discrepancies")
    by = {line["place"]: line for line in lines}
    assert "A-02-1" not in by  # confirmed: no discrepancy left
    assert (by["A-03-1"]["category"], by["A-03-1"]["moved_from"]) == ("mismatch", "A-02-1")
    assert by["A-03-1"]["pallet"] == "109B" and by["A-03-1"]["status"] == "reviewed"
    assert (by["A-01-1"]["category"], by["A-01-1"]["moved_from"]) == ("mismatch", "A-02-1")
    # the runs page counts as the export does
    assert run_info(RunsRoot(str(root)), RUN)["discrepancies"] == {"mismatch": 2}


# ---- 4. a refused token, 6. a double click, 9. unlisted, damaged review ---------------------
def _review_run(root):
    rows = [_row("A-01-1", "unknown", "unknown"), _row("A-01-2", "unknown", "unknown")]
    run = _run(root, RUN, rows, ["A-01-1", "A-01-2"])
    _discrepancies(
        run,
        [
            {"place": "A-01-1", "expected": "", "category": "unlisted", "moved_from": ""},
            {"place": "A-01-2", "expected": "", "category": "unexpected", "moved_from": ""},
        ],
    )
    return run


def _decisions(run) -> list[dict]:
    path = run / "review.json"
    return json.loads(path.read_text())["decisions"] if path.exists() else []


def test_a_refused_token_can_be_typed_again(root):
    run = _review_run(root)
    with console(str(root)) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/{RUN}/review?token=wrong-token-123")
        item = page.locator('.review-item[data-place="A-01-1"]')
        item.wait_for()
        assert not page.locator("#token-field").is_visible()
        page.fill("#reviewer", "Ana")
        item.locator('input[value="leave_unknown"]').check()
        item.locator("button[type=submit]").click()
        item.locator(".result.error").wait_for()
        assert "refused the review token" in item.inner_text()
        assert page.locator("#token-field").is_visible()
        assert "refused" in page.inner_text("#token-state")
        page.fill("#token", TOKEN)
        page.locator("#token").dispatch_event("change")
        item.locator("button[type=submit]").click()
        item.locator(".result.ok").wait_for()
        assert "accepted" in page.inner_text("#token-state")
        assert not page.errors
    assert [d["reviewer"] for d in _decisions(run)] == ["Ana"]


def test_a_double_click_on_decide_records_one_decision(root):
    run = _review_run(root)
    with console(str(root)) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/{RUN}/review?token={TOKEN}")
        item = page.locator('.review-item[data-place="A-01-2"]')
        item.wait_for()
        page.fill("#reviewer", "Ana")
        item.locator('input[value="leave_unknown"]').check()
        item.locator("button[type=submit]").dblclick()
        item.locator(".result.ok").wait_for()
        wait_for(lambda: item.locator("button[type=submit]").is_enabled())  # no request left
        assert "recorded" in item.locator(".result").inner_text()
        item.locator("button[type=submit]").click()  # again, after the answer
        wait_for(lambda: "already recorded" in item.locator(".result").inner_text())
        assert not page.errors
    assert len(_decisions(run)) == 1


def test_the_same_decision_twice_is_recorded_once(root):
    run = _review_run(root)
    r = RunsRoot(str(root))
    request = {"place": "A-01-1", "decision": "leave_unknown", "reviewer": "bo", "reason": "x"}
    first = decide(r, RUN, request, None, GalleryDesk())
    again = decide(r, RUN, request, None, GalleryDesk())  # "replaces" missing: a 409 before
    assert again["already_recorded"] and again["seq"] == first["seq"]
    again = decide(r, RUN, {**request, "replaces": first["seq"]}, None, GalleryDesk())
    assert again["already_recorded"]
    assert len(_decisions(run)) == 1
    changed = decide(r, RUN, {**request, "reason": "y", "replaces": 1}, None, GalleryDesk())
    assert changed["seq"] == 2 and len(_decisions(run)) == 2


def test_unlisted_places_and_a_damaged_review_file_on_the_review_page(root):
    run = _review_run(root)
    with console(str(root)) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/{RUN}/review?token={TOKEN}")
        item = page.locator('.review-item[data-place="A-01-1"]')
        item.wait_for()
        assert "not in the expected stock (unlisted)" in item.inner_text()
        assert "expected empty" not in item.inner_text()
        other = page.locator('.review-item[data-place="A-01-2"]')
        assert "expected empty (unexpected)" in other.inner_text()
        # no world here: the page says no gallery can be taught, leave unknown still works
        assert "No gallery can be taught" in page.inner_text("#gallery-problem")
        assert item.locator('input[value="new_pallet"]').is_disabled()
        assert not item.locator("button[type=submit]").is_disabled()
        (run / "review.json").write_text("{ cut short")
        page.reload()
        page.locator("#review-error").wait_for()
        assert "cannot be recorded" in page.inner_text("#review-error")
        assert page.locator(".review-item button[type=submit]").first.is_disabled()
        assert not page.errors


# ---- 5. focus kept across redraws ----------------------------------------------------------
def test_redraws_keep_the_filter_and_the_keyboard_focus(root):
    rows = [_row(f"A-0{b}-{level}", "101A", "identified") for b in (1, 2) for level in (1, 2)]
    _run(root, RUN, rows, [r["place"] for r in rows])
    with console(str(root)) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/{RUN}")
        page.locator("#places tbody tr").first.wait_for()
        page.click("#filter")
        page.keyboard.type("A-0")
        page.evaluate("renderRun()")  # what a live update does
        page.keyboard.type("1")
        assert page.input_value("#filter") == "A-01"
        assert page.evaluate("document.activeElement.id") == "filter"
        page.focus('#racks g.place[data-place="A-02-1"]')
        page.keyboard.press("Enter")
        page.locator('#place-detail[data-place="A-02-1"]').wait_for()
        focused = page.evaluate("document.activeElement.getAttribute('data-place')")
        assert focused == "A-02-1"
        page.focus("#colour-by")
        page.keyboard.press("ArrowDown")
        assert page.evaluate("document.activeElement.id") == "colour-by"
        assert not page.errors


# ---- 7. no rows, no export -----------------------------------------------------------------
def test_a_run_without_inventory_json_is_not_exported(root):
    half = root / "half"
    half.mkdir()
    (half / "ticks.jsonl").write_text('{"header": {"mission": "missions/inventory.xml"}}\n')
    with console(str(root)) as server:
        for kind in ("inventory.csv", "discrepancies.xlsx"):
            status, body = _get(f"{server.url}/export/half/{kind}")
            assert status == 409 and b"no inventory.json" in body, (status, body)
        status, body = _get(f"{server.url}/api/runs/half")
        assert json.loads(body)["no_inventory"] is True


# ---- 8. the Host allow-list of a LAN bind --------------------------------------------------
def _status(server: ConsoleServer, host: str) -> int:
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
    try:
        conn.request("GET", "/api/runs", headers={"Host": f"{host}:{server.port}"})
        return conn.getresponse().status
    finally:
        conn.close()


def test_a_lan_bind_keeps_a_host_allow_list(root):
    args = argparse.Namespace(
        runs=str(root), token=TOKEN, gallery=None, host="0.0.0.0", store="none"
    )
    args.allow_host = ["ground.site.example"]
    hosts = make_config(args).hosts
    assert "*" not in hosts
    assert socket.gethostname().lower() in hosts and "localhost" in hosts
    assert "ground.site.example" in hosts
    assert "192.168.1.20" in allowed_hosts("192.168.1.20", [])
    config = ConsoleConfig(str(root), TOKEN, hosts=hosts)
    server = ConsoleServer(config, "127.0.0.1", 0).start()
    try:
        assert _status(server, "rebind.attacker.example") == 400
        assert _status(server, "ground.site.example") == 200
        assert _status(server, socket.gethostname().lower()) == 200
        assert _status(server, "localhost") == 200
    finally:
        server.stop()


def test_ipv6_hosts_are_named_as_browsers_send_them(root):
    """An IPv6 address could not be allowed (``--allow-host`` refused every ``:``), and a
    bind to an IPv6 address was listed unbracketed in another spelling than browsers send."""
    hosts = allowed_hosts("FD00:0:0::20", ["FD00::21", "[fd00::22]", "ground.example"])
    assert {"[fd00::20]", "[fd00::21]", "[fd00::22]", "ground.example"} <= set(hosts)
    for bad in ["fd00::21:8080x", "[ground.example]", "host:8080"]:
        with pytest.raises(ConsoleError, match="an IPv6 address"):
            allowed_hosts("127.0.0.1", [bad])
    config = ConsoleConfig(str(root), TOKEN, hosts=hosts)
    server = ConsoleServer(config, "127.0.0.1", 0).start()
    try:
        assert _status(server, "[fd00::21]") == 200  # _status adds the port
        assert _status(server, "[fd00::99]") == 400
    finally:
        server.stop()


# ---- 9. accuracy of an interrupted run, store-only runs, the rack drawings -----------------
def test_an_interrupted_runs_accuracy_is_over_the_places_answered(root):
    rows = [_row("A-01-1", "101A", "identified"), _row("A-01-2", "", "not_scanned")]
    rows += [_row("A-02-1", "", "not_scanned"), _row("A-02-2", "", "not_scanned")]
    run = _run(root, RUN, rows, [r["place"] for r in rows])
    grades = {"A-01-1": "right", "A-01-2": "not_scanned"}
    grades.update({"A-02-1": "not_scanned", "A-02-2": "not_scanned"})
    summary = {"status": "ABORTED", "inventory": {"accuracy": 0.25, "grades": grades}}
    (run / "summary.json").write_text(json.dumps(summary))
    info = run_info(RunsRoot(str(root)), RUN)
    assert (info["accuracy"], info["accuracy_over"]) == (1.0, "answered")
    with console(str(root)) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/{RUN}")
        page.locator("#run-summary").wait_for()
        text = page.inner_text("#run-summary")
        assert "100 % of the places answered (3 not scanned)" in text, text
        page.goto(server.url + "/")
        cells = page.locator(f'#runs tr[data-run="{RUN}"] td').all_inner_texts()
        assert cells[4] == "1/4" and cells[5] == "100 % of 1", cells
        assert not page.errors


def test_store_only_runs_are_in_start_order_with_unknown_planned_places(root, tmp_path):
    from store import InventoryStore

    _run(root, "inventory-20261126-090000", [_row("A-01-1", "101A", "identified")], ["A-01-1"])
    url = f"sqlite:///{tmp_path / 'site.sqlite'}"
    newest = "inventory-20261127-090000"
    with InventoryStore.open(url) as s:
        s.begin_run(newest, mission="missions/inventory.xml", started=1_900_000_000.0)
        rows = [{"place": "A-01-1", "answer": "101A", "status": "identified", "drone": ""}]
        s.record_rows(newest, rows)
        s.end_run(newest, "ABORTED")
    config = ConsoleConfig(str(root), TOKEN, store=url)
    server = ConsoleServer(config, "127.0.0.1", 0).start()
    try:
        status, body = _get(server.url + "/api/runs")
        doc = json.loads(body)
        assert [r["name"] for r in doc["runs"]] == [newest, "inventory-20261126-090000"]
        assert doc["runs"][0]["places_known"] is False
        with browser_page() as page:
            page.goto(server.url + "/")
            page.locator(f'#runs tr[data-run="{newest}"]').wait_for()
            cells = page.locator(f'#runs tr[data-run="{newest}"] td').all_inner_texts()
            assert cells[4] == "1/?", cells
    finally:
        server.stop()


def _contrast(a: str, b: str) -> float:
    def lum(h: str) -> float:
        c = [int(h[i : i + 2], 16) / 255 for i in (1, 3, 5)]
        c = [x / 12.92 if x <= 0.04045 else ((x + 0.055) / 1.055) ** 2.4 for x in c]
        return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]

    hi, lo = sorted((lum(a), lum(b)), reverse=True)
    return (hi + 0.05) / (lo + 0.05)


def test_rack_cells_are_readable_and_the_drawings_named(root):
    rows = [
        _row("A-01-1", "101A", "identified"),
        _row("A-01-2", "empty", "empty"),
        _row("A-02-1", "unknown", "not_identified"),
        _row("A-02-2", "unknown", "unknown"),
    ]
    run = _run(root, RUN, rows, [r["place"] for r in rows])
    write_review(str(run), [{"place": "A-02-2", "answer": "9A", "decision": "identity"}])
    with console(str(root)) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/{RUN}")
        page.locator("#racks g.place").first.wait_for()
        for scheme in ("status", "grade", "discrepancy"):
            page.select_option("#colour-by", scheme)
            colours = page.evaluate(
                "Object.values(COLOURS[document.getElementById('colour-by').value])"
            )
            for fill in colours:
                ink = page.evaluate(f"inkFor('{fill}')")
                text = "#000000" if ink == "ink-dark" else "#ffffff"
                assert _contrast(fill, text) >= 4.5, (scheme, fill, ink)
            cells = page.locator("#racks g.place")
            for k in range(cells.count()):
                fill = cells.nth(k).locator("rect").get_attribute("fill")
                shown = (
                    cells.nth(k)
                    .locator("text.cell-answer")
                    .evaluate("t => getComputedStyle(t).fill")
                )
                assert shown.startswith("rgb("), shown
                rgb = [int(x) for x in shown[shown.index("(") + 1 : -1].split(",")]
                text = "#" + "".join(f"{x:02x}" for x in rgb)
                assert _contrast(fill, text) >= 4.5, (scheme, fill, text)
        for rack in page.locator("svg.rack").all():
            assert (rack.get_attribute("aria-label") or "").startswith("rack ")
        if page.locator("#map").count():  # a run with a world: the map is named too
            assert page.get_attribute("#map", "aria-label").startswith("map, top view")
        assert not page.errors
