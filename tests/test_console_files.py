"""What the console makes of a run folder's files when they are not what btrun wrote: files
linked out of the runs folder are not read, damaged rows are never exported as an empty
count, a damaged review file is not written over, unscanned places stay in the export, and
a run's relative paths are the run's, not the console's. No flight and no browser."""

from __future__ import annotations

import json
import os
import time
import urllib.parse

import pytest
from console_helpers import REPO, make_run
from test_console_security import _row

from nodes.console import export
from nodes.console.files import REVIEW_JSON, write_review
from nodes.console.paths import RunsRoot
from nodes.console.review import GalleryDesk, ReviewError, decide
from nodes.console.runs import list_runs, run_info, world_of

SECRET = "SECRET-FROM-OUTSIDE"


_run = make_run


@pytest.fixture
def root(tmp_path):
    (tmp_path / "runs").mkdir()
    return tmp_path / "runs"


def test_files_linked_out_of_the_runs_folder_are_not_read(root, tmp_path):
    """A run's summary, rows, review, candidates and tick log linked to files outside: the
    page, the list and the exports show none of them (the file server refused them already;
    the JSON readers did not)."""
    outside = tmp_path / "outside"
    outside.mkdir()
    other = _run(outside, "elsewhere", [_row("A-01-1", SECRET, "identified")], ["A-01-1"])
    (outside / "summary.json").write_text(json.dumps({"status": SECRET, "mission": SECRET}))
    write_review(str(outside), [{"place": "A-01-1", "answer": SECRET, "decision": "identity"}])
    (outside / "candidates.json").write_text(json.dumps({"candidates": [[SECRET, 0.1]]}))
    run = _run(root, "leak", [_row("A-01-2", "unknown", "unknown")], ["A-01-2"])
    os.replace(other / "inventory.json", outside / "inventory.json")
    (run / "inventory.json").unlink()
    for name in ("summary.json", "inventory.json", REVIEW_JSON):
        os.symlink(outside / name, run / name)
    (run / "places" / "A-01-2").mkdir(parents=True)
    os.symlink(outside / "candidates.json", run / "places" / "A-01-2" / "candidates.json")
    (run / "ticks.jsonl").unlink()
    os.symlink("/etc/passwd", run / "ticks.jsonl")
    runs = RunsRoot(str(root))
    info = run_info(runs, "leak", True)
    assert SECRET not in json.dumps(info) and "root:" not in json.dumps(info)
    assert "reached through a link" in info["error"] and info["rows_error"]
    assert info["status"] != SECRET and info["review"] == [] and info["tracks"] == {"drone": []}
    assert SECRET not in json.dumps(list_runs(runs))
    from nodes.console.live import RunFollower

    assert "root:" not in json.dumps(RunFollower(str(run)).poll())  # nor the live view


def test_damaged_rows_are_refused_not_exported_empty(root):
    """A truncated inventory.json (inventory.csv intact): the run's page says so and has no
    export; the export itself answers 409, never a header and no places."""
    from console_helpers import console
    from test_console_security import _raw

    rows = [_row(f"A-0{i}-1", f"10{i}A", "identified") for i in range(1, 5)]
    run = _run(root, "cut", rows, [r["place"] for r in rows])
    text = (run / "inventory.json").read_text()
    (run / "inventory.json").write_text(text[: len(text) // 2])
    info = run_info(RunsRoot(str(root)), "cut", True)
    assert info["rows_error"] and "not JSON" in info["error"]
    with console(str(root)) as server:
        for kind in ("inventory.csv", "inventory.xlsx", "discrepancies.csv"):
            status, body = _raw(server.port, "GET", f"/export/cut/{kind}")
            assert status == 409 and b"rows cannot be read" in body, (kind, status, body)
    (run / "summary.json").write_text('{"status": "SUCC')  # a summary cut short: said
    assert "summary.json cannot be read" in run_info(RunsRoot(str(root)), "cut")["error"]


def test_a_damaged_review_file_is_not_written_over(root):
    """Adding a decision to a review.json that cannot be read would have replaced it (and
    review.csv) with the new decision alone: the decisions it held were lost."""
    run = _run(root, "r", [_row("A-01-2", "unknown", "unknown")], ["A-01-2"])
    (run / REVIEW_JSON).write_text('{"format": "btrun-review-1", "decisions": [{"place": "A-0')
    before = (run / REVIEW_JSON).read_bytes()
    request = {"place": "A-01-2", "decision": "leave_unknown", "reviewer": "bob"}
    with pytest.raises(ReviewError) as exc:
        decide(RunsRoot(str(root)), "r", request, None, GalleryDesk())
    assert exc.value.status == 409 and "review.json" in str(exc.value)
    assert (run / REVIEW_JSON).read_bytes() == before and not (run / "review.csv").exists()
    # nor is a count exported without the operators' decisions: 409, as for damaged rows
    from console_helpers import console
    from test_console_security import _raw

    assert "review.json" in run_info(RunsRoot(str(root)), "r")["error"]
    with console(str(root)) as server:
        for kind in ("inventory.csv", "discrepancies.xlsx"):
            status, body = _raw(server.port, "GET", f"/export/r/{kind}")
            assert status == 409 and b"review decisions cannot be read" in body, (kind, body)
    (run / REVIEW_JSON).unlink()  # mended: the decision is taken, its cells defused
    request.update(reviewer="=cmd|' /C calc'!A0", reason="@SUM(A1)")
    decide(RunsRoot(str(root)), "r", request, None, GalleryDesk())
    line = (run / "review.csv").read_text().splitlines()[1]
    assert ",'=cmd|" in line and ",'@SUM(A1)," in line


def test_an_interrupted_runs_export_keeps_every_planned_place(root):
    """The places an interrupted run never reached are in the WMS export as not_scanned: a
    place missing from the file reads as one not in the count."""
    planned = [f"A-{b:02d}-1" for b in range(1, 6)]
    _run(root, "cut-short", [_row("A-01-1", "101A", "identified")], planned)
    info = run_info(RunsRoot(str(root)), "cut-short", True)
    lines = export.wms_rows(info)
    assert [(r["place"], r["status"]) for r in lines] == [("A-01-1", "identified")] + [
        (p, "not_scanned") for p in planned[1:]
    ]
    assert all(r["pallet"] == "" for r in lines[1:])
    assert export.table(info, "discrepancies")[1] == []  # no expected stock, no grades


def test_a_resumed_runs_carried_rows_keep_the_time_of_the_run_that_answered_them(root):
    """A carried row's mission time counts from its own run's start: the export stamped it
    with the resumed run's start plus that time (hours or days off for a WMS). A row of a
    run that cannot be found has no time rather than a wrong one; the run's own rows keep
    theirs after the folder is renamed (its name when it flew is recorded)."""
    first = {**_row("A-01-1", "101A", "identified"), "run": "inv-1"}
    _run(root, "inv-1", [first], ["A-01-1"], {"started": "2026-11-27T08:00:00Z"})
    rows = [first, {**_row("A-02-1", "102A", "identified"), "run": "inv-2"}]
    header = {"started": "2026-11-28T09:00:00Z", "run_dir": "/elsewhere/runs/inv-2"}
    _run(root, "inv-2 renamed", rows, ["A-01-1", "A-02-1"], header)
    lines = export.wms_rows(run_info(RunsRoot(str(root)), "inv-2 renamed", True))
    assert [(r["place"], r["time"]) for r in lines] == [
        ("A-01-1", "2026-11-27T08:00:10Z"),
        ("A-02-1", "2026-11-28T09:00:10Z"),
    ]
    os.rename(root / "inv-1", root / "gone")
    lines = export.wms_rows(run_info(RunsRoot(str(root)), "inv-2 renamed", True))
    assert [r["time"] for r in lines] == ["", "2026-11-28T09:00:10Z"]


def test_runs_are_listed_by_their_start_and_odd_names_are_said(root):
    """Newest started first, whatever the folders' times (a review or a copy touches them);
    a run under a name with spaces or accents is listed; one the console cannot serve is
    named, not silently left out."""
    for name, started in (("week 48", "10:00"), ("über", "11:00"), ("old", "09:00")):
        _run(root, name, [], ["A-01-1"], {"started": f"2026-11-27T{started}:00Z"})
    now = time.time()
    os.utime(root / "old", (now + 60, now + 60))  # the oldest run written to last
    _run(root, "-dash", [], ["A-01-1"])
    skipped: list[str] = []
    assert [r["name"] for r in list_runs(RunsRoot(str(root)), skipped)] == [
        "über",
        "week 48",
        "old",
    ]
    assert skipped == ["'-dash' (a name the console does not serve)"]


def test_a_runs_relative_rig_is_read_from_where_it_was_flown(root, tmp_path, monkeypatch):
    """The header's rig is relative to the folder btrun was started in (``cwd``): a console
    started elsewhere drew no places and seeded its review gallery from the default rig's
    world, which knows none of the run's pallets. A rig that is not on this machine is said
    before a gallery is made from another world."""
    monkeypatch.chdir(tmp_path)
    header = {"rig": "rigs/aisle.yaml", "seed": 0, "sets": []}
    assert world_of(header) is None  # from before the header kept cwd: not found here
    world = world_of({**header, "cwd": REPO})
    assert world is not None and len(world.places) == 16
    run = _run(root, "moved", [_row("A-01-2", "unknown", "unknown")], ["A-01-2"])
    (run / "ticks.jsonl").write_text(
        json.dumps({"header": {**header, "cwd": "/nowhere/else"}}) + "\n"
    )
    import numpy as np

    from nodes.place_evidence import write_place_evidence

    write_place_evidence(str(run), "A-01-2", [np.zeros((20, 30, 3), np.uint8)] * 3, [])
    request = {"place": "A-01-2", "decision": "new_pallet", "new_name": "P-1", "reviewer": "al"}
    with pytest.raises(ReviewError) as exc:
        decide(RunsRoot(str(root)), "moved", request, None, GalleryDesk())
    assert exc.value.status == 409 and "/nowhere/else/rigs/aisle.yaml" in str(exc.value)
    assert "not on this machine" in str(exc.value)
    assert not (root / "site-gallery.sqlite").exists()


def test_the_discrepancies_export_keeps_the_expected_places_not_scanned(root):
    """An interrupted run's own discrepancies.csv lists the expected places it never reached
    as not_scanned; the console's export and counts left them out (a WMS would never
    recount them)."""
    run = _run(root, "cut", [_row("A-01-1", "101A", "identified")], ["A-01-1", "A-02-1"])
    doc = {
        "format": "btrun-discrepancies-1",
        "rows": [
            {"place": "A-01-1", "expected": "101", "category": "confirmed"},
            {"place": "A-02-1", "expected": "102", "category": "not_scanned"},
        ],
    }
    (run / "discrepancies.json").write_text(json.dumps(doc))
    info = run_info(RunsRoot(str(root)), "cut", True)
    assert info["discrepancies"] == {"not_scanned": 1}
    lines = export.table(info, "discrepancies")[1]
    assert [(r["place"], r["category"], r["expected"]) for r in lines] == [
        ("A-02-1", "not_scanned", "102")
    ]


def test_an_export_of_a_run_named_in_any_script_downloads(root):
    """The download's file name went into a Latin-1 header: a 500 for '倉庫 Лагер'."""
    from console_helpers import console
    from test_console_security import _raw

    _run(root, "倉庫 Лагер", [_row("A-01-1", "101A", "identified")], ["A-01-1"])
    path = "/export/" + urllib.parse.quote("倉庫 Лагер") + "/inventory.csv"
    with console(str(root)) as server:
        status, body = _raw(server.port, "GET", path)
    assert status == 200 and b"A-01-1,101A" in body, (status, body)
    from nodes.console.app import attachment

    assert attachment("倉庫-inventory.csv") == (
        'attachment; filename="__-inventory.csv"; '
        "filename*=UTF-8''%E5%80%89%E5%BA%AB-inventory.csv"
    )


def test_a_run_that_went_silent_without_a_summary_ends_its_live_stream(root):
    """A run whose guard died with it writes no summary: its live stream said RUNNING for
    ever and held one of the console's stream slots."""
    from nodes.console.live import RunFollower
    from nodes.console.runs import RUNNING_WITHIN_S

    run = _run(root, "ghost", [_row("A-01-1", "101A", "identified")], ["A-01-1", "A-02-1"])
    follower = RunFollower(str(run))
    assert ("status", {"status": "INCOMPLETE"}) not in follower.poll() and not follower.done
    old = time.time() - RUNNING_WITHIN_S - 5
    for name in ("ticks.jsonl", "inventory.json"):
        os.utime(run / name, (old, old))
    assert ("status", {"status": "INCOMPLETE"}) in follower.poll() and follower.done


def test_xlsx_cells_are_text_never_formulas_and_show_as_written():
    """A cell the CSV defuses with a leading "'" is stored as text in XLSX: no formula runs,
    and '-42' shows as -42, not '-42 (the quote was visible in the spreadsheet)."""
    import io

    from openpyxl import load_workbook

    data = export.to_xlsx(("a", "b"), [{"a": "=cmd|' /C calc'!A0", "b": "-42"}], "t")
    ws = load_workbook(io.BytesIO(data)).active
    cells = list(ws.iter_rows(min_row=2))[0]
    assert [c.value for c in cells] == ["=cmd|' /C calc'!A0", "-42"]
    assert [c.data_type for c in cells] == ["s", "s"]


def test_a_runs_folder_past_the_listed_most_says_how_many_are_left_out(root, monkeypatch):
    """521 run folders showed 500 with no word of the others."""
    import nodes.console.runs as runs_mod

    monkeypatch.setattr(runs_mod, "MAX_RUNS", 3)
    for i in range(5):
        _run(root, f"run-{i}", [], ["A-01-1"], {"started": f"2026-11-2{i}T10:00:00Z"})
    skipped: list[str] = []
    assert len(list_runs(RunsRoot(str(root)), skipped)) == 3
    assert skipped == [
        "2 older runs (the newest 3 of 5 are listed; move old run folders to an archive folder)"
    ]


def test_audit_text_takes_no_format_characters_and_trimmed_formulas_are_defused(root):
    """A right-to-left override in a reviewer's name could disguise who decided; ' =2+2'
    ran as a formula in an importer that trims."""
    from nodes.console.files import safe_cell

    assert safe_cell(" =2+2") == "' =2+2" and safe_cell("A-01-1") == "A-01-1"
    run = _run(root, "r", [_row("A-01-2", "unknown", "unknown")], ["A-01-2"])
    request = {"place": "A-01-2", "decision": "leave_unknown", "reviewer": "ana\u202elive"}
    with pytest.raises(ReviewError, match="printable characters"):
        decide(RunsRoot(str(root)), "r", request, None, GalleryDesk())
    assert not (run / REVIEW_JSON).exists()


def test_a_link_to_a_run_in_the_runs_folder_is_not_a_second_run(root):
    """runs/linkin -> r1 was listed as a run of its own (decisions through it went to r1)."""
    _run(root, "r1", [_row("A-01-1", "101A", "identified")], ["A-01-1"])
    os.symlink(root / "r1", root / "linkin")
    skipped: list[str] = []
    assert [r["name"] for r in list_runs(RunsRoot(str(root)), skipped)] == ["r1"]
    assert skipped == ["'linkin' (a link to run 'r1')"]


def test_a_place_the_run_never_scanned_says_so_when_reviewed(root):
    """It said "no row for place 'A-02-1'" (404) for a place the run planned."""
    _run(root, "cut", [_row("A-01-1", "unknown", "unknown")], ["A-01-1", "A-02-1"])
    request = {"place": "A-02-1", "decision": "leave_unknown", "reviewer": "ana"}
    with pytest.raises(ReviewError, match="A-02-1 was not scanned") as exc:
        decide(RunsRoot(str(root)), "cut", request, None, GalleryDesk())
    assert exc.value.status == 409


@pytest.mark.parametrize(
    "name, refused", [("a\nb", True), ("unknown", True), ("PAL/2026/1", False)]
)
def test_a_review_names_pallets_as_a_gallery_does(root, name, refused):
    """A new pallet's name follows the gallery's rule: a WMS's own ids (PAL/2026/1) are
    names, a line break or an answer word is not (the console had its own, narrower rule)."""
    import numpy as np

    from nodes.place_evidence import write_place_evidence

    run = _run(root, "r", [_row("A-01-2", "unknown", "unknown")], ["A-01-2"])
    write_place_evidence(str(run), "A-01-2", [np.zeros((20, 30, 3), np.uint8)] * 3, [])
    request = {"place": "A-01-2", "decision": "new_pallet", "new_name": name, "reviewer": "al"}
    with pytest.raises(ReviewError) as exc:  # this run names no rig: refused after the name
        decide(RunsRoot(str(root)), "r", request, None, GalleryDesk())
    said = str(exc.value)
    assert ("cannot be a pallet identity" in said or "printable" in said) is refused, said


def test_the_runs_index_reads_a_finished_run_again_only_when_its_files_change(root, monkeypatch):
    """A refresh of the index read every run's inventory each time (about 3 s of CPU for
    500 site runs); it now reads a finished run again only when one of its files changed,
    and a run without a summary every time (RUNNING depends on the clock)."""
    from nodes.console import runs as runs_module

    done = _run(root, "done", [_row("A-01-1", "", "unknown")], ["A-01-1"])
    (done / "summary.json").write_text(json.dumps({"status": "SUCCESS"}))
    _run(root, "running", [], ["A-01-1"])
    read: list[str] = []
    real = runs_module.run_info

    def counted(r, name, full=False):
        read.append(name)
        return real(r, name, full)

    monkeypatch.setattr(runs_module, "run_info", counted)
    listed = {r["name"]: r for r in list_runs(RunsRoot(str(root)))}
    assert sorted(read) == ["done", "running"] and listed["done"]["reviewed"] == 0
    read.clear()
    list_runs(RunsRoot(str(root)))
    assert read == ["running"]
    write_review(str(done), [{"place": "A-01-1", "answer": "117B", "decision": "confirm"}])
    listed = {r["name"]: r for r in list_runs(RunsRoot(str(root)))}
    assert sorted(read) == ["done", "running", "running"] and listed["done"]["reviewed"] == 1
