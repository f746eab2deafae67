"""btrun console in a real browser (Debian's headless chromium through Playwright): a finished
fleet inventory's map and table against its inventory.csv, a review decision made on the
page and found in the gallery's history, the XLSX export read back, and a running run that
updates without a reload."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import re
import shutil
import threading

import pytest
from console_helpers import REPO, TOKEN, browser_page, console, screenshot, wait_for

from bt_engine.cli import main
from nodes.inventory_log import write_inventory

pytestmark = pytest.mark.slow

FLEET = "aisle_2-20261126-101500"
PLACES = "places=A-03-*;A-04-*;A-07-*;A-08-*"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> str:
    """A runs folder holding one finished fleet inventory (fleets/aisle_2.yaml, seed 0) of
    the bays with an empty place and both pallets the gallery does not know."""
    root = tmp_path_factory.mktemp("runs")
    out = root / FLEET
    fleet = os.path.join(REPO, "fleets", "aisle_2.yaml")
    args = ["--out", str(out), "-q", "--no-report", "--store", "none", "--set", PLACES]
    assert main(["fleet", fleet, *args]) == 0
    return str(root)


def _csv_rows(run_dir: str) -> list[dict]:
    with open(os.path.join(run_dir, "inventory.csv"), newline="") as f:
        return list(csv.DictReader(f))


def test_the_runs_page_lists_the_fleet(runs):
    with console(runs) as server, browser_page() as page:
        page.goto(server.url + "/")
        row = page.locator(f'#runs tr[data-run="{FLEET}"]')
        row.wait_for()
        cells = row.locator("td").all_inner_texts()
        assert cells[1].startswith("fleet (2 drones)")
        assert cells[2] == "inventory.xml" and cells[3] == "SUCCESS"
        assert cells[4] == "8/8" and cells[5] == "100 %"
        assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC([+-]\d\d(:\d\d)?)?", cells[-1]), cells
        screenshot(page, "runs")
        assert not page.errors


def test_the_map_and_table_match_inventory_csv(runs):
    rows = _csv_rows(os.path.join(runs, FLEET))
    with console(runs) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/{FLEET}")
        page.locator("#places tbody tr").first.wait_for()
        # the rack faces: one cell per place, with the row's answer and status
        cells = page.locator("#racks g.place")
        assert len(rows) == 8 and cells.count() == 16  # the rack's every place, 8 flown
        for r in rows:
            cell = page.locator(f'#racks g.place[data-place="{r["place"]}"]')
            assert cell.get_attribute("data-answer") == r["answer"]
            assert cell.get_attribute("data-status") == r["status"]
            assert cell.locator("text.cell-answer").text_content() == r["answer"]
        # the table: the same rows
        for r in rows:
            tr = page.locator(f'#places tr[data-place="{r["place"]}"]')
            assert tr.locator('td[data-key="answer"]').inner_text() == r["answer"]
            assert tr.locator('td[data-key="status"]').inner_text() == r["status"]
            assert tr.locator('td[data-key="drone"]').inner_text() == r["drone"]
        # the map: both drones, back on their pads, with their tracks
        assert page.locator("#map g.drone").count() == 2
        assert page.locator("#map polyline.track").count() == 2
        # sortable and filterable
        page.click('#places th[data-key="answer"]')
        answers = page.locator('#places td[data-key="answer"]').all_inner_texts()
        assert answers == sorted(answers, key=str.lower) or answers == sorted(answers)
        page.fill("#filter", "unknown")
        shown = page.locator("#places tbody tr")
        unknown = [r for r in rows if "unknown" in (r["answer"] + r["status"])]
        wait_for(lambda: shown.count() == len(unknown), what="the filtered table")
        page.fill("#filter", "")
        # a place's crops and candidates
        place = next(r["place"] for r in rows if r["status"] == "unknown")
        page.click(f'#racks g.place[data-place="{place}"]')
        detail = page.locator(f'#place-detail[data-place="{place}"]')
        detail.wait_for()
        crops = detail.locator("img.crop")
        assert crops.count() == 3
        wait_for(
            lambda: all(
                crops.nth(i).evaluate("img => img.complete && img.naturalWidth > 0")
                for i in range(3)
            ),
            what="the crops to load",
        )
        assert detail.locator("table.candidates tbody tr").count() == 5
        screenshot(page, "inventory")
        # by keyboard alone: a rack cell takes the focus and Enter opens it
        other = next(r["place"] for r in rows if r["place"] != place)
        page.focus(f'#racks g.place[data-place="{other}"]')
        page.keyboard.press("Enter")
        page.locator(f'#place-detail[data-place="{other}"]').wait_for()
        assert page.get_attribute("#filter", "aria-label") == "filter places"
        assert not page.errors


def test_a_review_decision_updates_the_gallery_with_an_audit_entry(runs, tmp_path):
    from perception.gallery import Gallery

    run_dir = os.path.join(runs, FLEET)
    before = hashlib.sha256(open(os.path.join(run_dir, "inventory.csv"), "rb").read()).digest()
    gallery = str(tmp_path / "site-gallery.sqlite")
    place = next(r["place"] for r in _csv_rows(run_dir) if r["status"] == "unknown")
    with console(runs, gallery=gallery) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/{FLEET}/review?token={TOKEN}")
        item = page.locator(f'.review-item[data-place="{place}"]')
        item.wait_for()
        assert "token" not in page.url  # taken out of the address bar
        assert item.locator("img.crop").count() == 3
        page.fill("#reviewer", "Ana Operator")
        item.locator('input[value="new_pallet"]').check()
        item.locator('input[name="new_name"]').fill("NEW-1")
        item.locator('input[name="reason"]').fill("label NEW-1 on the photo")
        screenshot(page, "review")
        item.locator("button[type=submit]").click()
        result = item.locator(".result.ok")
        result.wait_for(timeout=120_000)  # the first decision loads the embedder
        assert "recorded: NEW-1 (new_pallet) by Ana Operator" in result.inner_text()
        assert not page.errors
    with Gallery.open(gallery) as g:
        assert "NEW-1" in g.identities() and len(g.identities()) > 1  # the demo's + the new
        event = g.history("NEW-1")[-1]
    assert event["action"] == "enrol"
    assert event["run"] == f"console review {FLEET} {place} by Ana Operator"
    assert "label NEW-1 on the photo" in event["note"]
    review = json.load(open(os.path.join(run_dir, "review.json")))
    d = review["decisions"][-1]
    assert (d["place"], d["answer"], d["reviewer"]) == (place, "NEW-1", "Ana Operator")
    assert d["gallery_event"] == event["event"] and d["original_answer"] == "unknown"
    after = hashlib.sha256(open(os.path.join(run_dir, "inventory.csv"), "rb").read()).digest()
    assert after == before  # the run's own rows are never rewritten
    # reversible: btrun gallery rollback removes the reviewed enrolment
    assert main(["gallery", "rollback", gallery, "NEW-1"]) == 0
    with Gallery.open(gallery) as g:
        assert "NEW-1" not in g.identities()


def test_a_decision_made_meanwhile_elsewhere_is_said_not_overwritten(runs):
    """Two reviewers of one place were both "recorded" and the last won (their gallery
    changes both stayed). A page's change of mind replaces its own decision; a decision made
    since in another tab or console refuses it, and the page says by whom."""
    from nodes.console.paths import RunsRoot
    from nodes.console.review import GalleryDesk, decide

    run_dir = os.path.join(runs, FLEET)
    place = [r["place"] for r in _csv_rows(run_dir) if r["status"] == "unknown"][-1]

    def mine() -> list[tuple[str, str, int]]:
        if not os.path.exists(os.path.join(run_dir, "review.json")):
            return []
        doc = json.load(open(os.path.join(run_dir, "review.json")))
        return [
            (d["reviewer"], d["reason"], d["seq"]) for d in doc["decisions"] if d["place"] == place
        ]

    with console(runs) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/{FLEET}/review?token={TOKEN}")
        item = page.locator(f'.review-item[data-place="{place}"]')
        item.wait_for()
        page.fill("#reviewer", "Ana")
        item.locator('input[value="leave_unknown"]').check()
        for why in ("no label", "label torn"):  # the second replaces the first
            item.locator('input[name="reason"]').fill(why)
            item.locator("button[type=submit]").click()
            wait_for(lambda why=why: mine() and mine()[-1][1] == why, what=f"decision {why!r}")
            item.locator(".result.ok").wait_for()
        request = {"place": place, "decision": "leave_unknown", "reviewer": "Bob"}
        request["replaces"] = mine()[-1][2]
        decide(RunsRoot(runs), FLEET, request, None, GalleryDesk())  # another console
        item.locator('input[name="reason"]').fill("third look")
        item.locator("button[type=submit]").click()
        refused = item.locator(".result.error")
        refused.wait_for()
        assert f"{place} was decided by Bob at" in refused.inner_text()
        assert not page.errors
    assert [(who, why) for who, why, _ in mine()[-3:]] == [
        ("Ana", "no label"),
        ("Ana", "label torn"),
        ("Bob", ""),
    ]


def test_the_xlsx_export_reads_back(runs):
    from openpyxl import load_workbook

    rows = {r["place"]: r for r in _csv_rows(os.path.join(runs, FLEET))}
    review = os.path.join(runs, FLEET, "review.json")
    decisions = json.load(open(review))["decisions"] if os.path.exists(review) else []
    reviewed = {d["place"]: d for d in decisions}
    with console(runs) as server, browser_page() as page:
        page.goto(f"{server.url}/runs/{FLEET}")
        link = page.locator('a[data-export="inventory.xlsx"]')
        link.wait_for()
        with page.expect_download() as info:
            link.click()
        data = open(info.value.path(), "rb").read()
    sheet = load_workbook(io.BytesIO(data)).active
    lines = list(sheet.iter_rows(values_only=True))
    assert lines[0] == ("place", "pallet", "status", "time", "drone")
    assert len(lines) == 1 + len(rows)
    for place, pallet, status, when, drone in lines[1:]:
        r = rows[place]
        assert drone == r["drone"] and when and when.endswith("Z")
        if place in reviewed:
            assert (pallet or "") == (reviewed[place]["answer"] if status == "reviewed" else "")
        elif r["status"] == "identified":
            assert (pallet, status) == (r["answer"], "identified")
        else:
            assert pallet in (None, "") and status == r["status"]


def test_a_running_run_updates_the_page_without_a_reload(runs, tmp_path):
    """A run folder written as a run writes it (tick lines appended, inventory.json
    rewritten after each place): the drone moves and the places fill in on the open page."""
    live = tmp_path / "live"
    run = live / "inventory-20261126-120000"
    run.mkdir(parents=True)
    source = os.path.join(runs, FLEET, "drones", "cf1")
    with open(os.path.join(source, "ticks.jsonl"), "rb") as f:
        ticks = f.read().splitlines(keepends=True)
    done = json.load(open(os.path.join(source, "inventory.json")))
    rows, planned = done["rows"], done["planned"]
    log = open(run / "ticks.jsonl", "wb", buffering=0)
    log.writelines(ticks[:200])  # header and the take-off
    write_inventory(str(run), [], planned)
    step = threading.Event()
    stop = threading.Event()

    def writer() -> None:  # one place per step, and the ticks that led to it
        at = 200
        for k in range(len(rows)):
            step.wait(30)
            step.clear()
            if stop.is_set():
                return
            until = min(len(ticks), 200 + (k + 1) * (len(ticks) - 200) // len(rows))
            log.writelines(ticks[at:until])
            at = until
            write_inventory(str(run), rows[: k + 1], planned)

    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    try:
        with console(str(live)) as server, browser_page() as page:
            page.goto(f"{server.url}/runs/{run.name}")
            page.locator("#map g.drone").first.wait_for()
            assert page.locator("#run-status").inner_text() == "RUNNING"
            page.evaluate("window.__notReloaded = true")
            drone = page.locator("#map g.drone").first
            x0 = drone.get_attribute("data-x"), drone.get_attribute("data-y")
            for k, row in enumerate(rows[:3]):
                step.set()
                cell = f'#racks g.place[data-place="{row["place"]}"]'
                wait_for(
                    lambda c=cell, r=row: (
                        page.locator(c).get_attribute("data-answer") == (r["answer"] or "")
                    ),
                    what=f"{row['place']} on the page",
                )
                wait_for(
                    lambda n=k + 1: page.locator("#places tbody tr").count() == n,
                    what="the table row",
                )
            wait_for(
                lambda: (drone.get_attribute("data-x"), drone.get_attribute("data-y")) != x0,
                what="the drone to move on the map",
            )
            assert page.evaluate("window.__notReloaded") is True  # the same page, no reload
            screenshot(page, "live")
            assert not page.errors
    finally:
        stop.set()
        step.set()
        thread.join(5)
        log.close()


def test_the_next_inventory_flies_with_the_reviewed_gallery(runs, tmp_path):
    """Only the console's review decision makes the not-enrolled pallet known: the next
    inventory of its place, with --set gallery=, names it."""
    from nodes.console.paths import RunsRoot
    from nodes.console.review import GalleryDesk, decide

    run_dir = os.path.join(runs, FLEET)
    place = next(r["place"] for r in _csv_rows(run_dir) if r["status"] == "unknown")
    copy = tmp_path / "runs"
    shutil.copytree(run_dir, copy / FLEET, ignore=shutil.ignore_patterns("review.*"))
    gallery = str(tmp_path / "g.sqlite")
    request = {"place": place, "decision": "new_pallet", "new_name": "SEEN-1", "reviewer": "t"}
    decide(RunsRoot(str(copy)), FLEET, request, gallery, GalleryDesk())
    out = tmp_path / "next"
    mission = os.path.join(REPO, "missions", "inventory.xml")
    rig = os.path.join(REPO, "rigs", "aisle.yaml")
    args = [mission, "--rig", rig, "--set", f"places={place}", "--set", f"gallery={gallery}"]
    assert main([*args, "--out", str(out), "-q", "--no-report", "--store", "none"]) == 0
    row = json.load(open(out / "inventory.json"))["rows"][0]
    assert (row["place"], row["answer"], row["status"]) == (place, "SEEN-1", "identified")


def test_an_accuracy_short_of_all_is_never_shown_as_100_percent(runs, tmp_path):
    """A four-aisle fleet's 287 right of 288 was shown as "100 %" (a whole percentage), in
    the run list and on the run's page: one decimal, and 100 % only when every place was."""
    run_dir = os.path.join(runs, FLEET)
    copy = tmp_path / "runs"
    shutil.copytree(run_dir, copy / FLEET, ignore=shutil.ignore_patterns("review.*"))
    summary = copy / FLEET / "summary.json"
    s = json.loads(summary.read_text())
    s["inventory"]["accuracy"] = round(287 / 288, 4)
    summary.write_text(json.dumps(s))
    with console(str(copy)) as server, browser_page() as page:
        page.goto(server.url + "/")
        row = page.locator(f'#runs tr[data-run="{FLEET}"]')
        row.wait_for()
        assert row.locator("td").all_inner_texts()[5] == "99.7 %"
        page.goto(f"{server.url}/runs/{FLEET}")
        wait_for(lambda: "accuracy in simulation 99.7 %" in page.inner_text("body"))
        assert not page.errors


def test_a_narrow_window_and_a_cut_short_run(runs, tmp_path):
    """At 400 px the page is one column (the map kept its width, drawings and tables scroll
    sideways instead of the page); a bay's levels are drawn side by side on the map, not one
    over the other; a place not scanned is not counted as answered."""
    copy = tmp_path / "runs"
    shutil.copytree(
        os.path.join(runs, FLEET), copy / FLEET, ignore=shutil.ignore_patterns("review.*")
    )
    doc = json.load(open(copy / FLEET / "inventory.json"))
    doc["rows"][-1].update(answer="", status="not_scanned")
    write_inventory(str(copy / FLEET), doc["rows"], doc["planned"])
    with console(str(copy)) as server, browser_page() as page:
        page.set_viewport_size({"width": 400, "height": 900})
        page.goto(f"{server.url}/runs/{FLEET}")
        page.locator("#places tbody tr").first.wait_for()
        assert "7 of 8 places answered" in page.inner_text("#run-summary")
        width = page.evaluate("document.documentElement.scrollWidth")
        assert width <= 400, width
        assert page.evaluate("document.getElementById('map').getBoundingClientRect().width") > 300
        xs = {
            p: float(page.locator(f'#map rect[data-place="{p}"]').get_attribute("x"))
            for p in ("A-03-1", "A-03-2")
        }
        assert xs["A-03-1"] != xs["A-03-2"], xs
        assert not page.errors
