"""A resumed inventory keeps what the console showed of the places it carries over: their
block crops and candidates, and the operators' review decisions (they had been left in the
interrupted run's folder: the continued run showed its carried unknowns without photos, and
exported them unreviewed)."""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
from console_helpers import make_run

from nodes.console.files import read_review, write_review
from nodes.console.paths import RunsRoot
from nodes.console.runs import run_info
from nodes.inventory_log import InventoryLog
from nodes.place_evidence import write_place_evidence

CROP = np.full((40, 30, 3), 90, np.uint8)


def _row(place: str, answer: str, status: str, drone: str = "aisle", run: str = "old") -> dict:
    return {"place": place, "answer": answer, "status": status, "drone": drone, "run": run}


def _decision(place: str, answer: str) -> dict:
    return {"place": place, "answer": answer, "decision": "confirm", "reviewer": "ana"}


def _previous(root, drone_dir: str = ".") -> str:
    """An interrupted run: A-01-1 identified, A-01-2 unknown (crops, a decision), A-02-1
    not scanned (a decision that must not follow it)."""
    rows = [_row("A-01-1", "101A", "identified"), _row("A-01-2", "", "unknown")]
    rows.append(_row("A-02-1", "", "not_scanned"))
    old = make_run(root, "old", rows, [r["place"] for r in rows])
    for place in ("A-01-1", "A-01-2", "A-02-1"):
        write_place_evidence(str(old / drone_dir), place, [CROP] * 3, [("101A", 0.2)])
    write_review(str(old), [_decision("A-01-2", "117B"), _decision("A-02-1", "103A")])
    return str(old)


def test_a_resumed_run_carries_its_places_crops_and_reviews(tmp_path):
    old = _previous(tmp_path)
    new = str(tmp_path / "new")
    log = InventoryLog(new, old)
    log.plan(["A-01-1", "A-01-2", "A-02-1"])
    log.record(_row("A-02-1", "103A", "identified", run="new"))
    for place in ("A-01-1", "A-01-2"):
        names = sorted(os.listdir(os.path.join(new, "places", place)))
        assert names == ["block_1.png", "block_2.png", "block_3.png", "candidates.json"]
        crop = cv2.imread(os.path.join(new, "places", place, "block_1.png"))
        assert crop is not None and crop.shape == CROP.shape
    # the place flown again keeps this run's own evidence (none written here): not the old
    assert not os.path.exists(os.path.join(new, "places", "A-02-1"))
    assert [d["place"] for d in read_review(new)] == ["A-01-2"]
    log.record(_row("A-02-1", "103A", "identified", run="new"))  # carried once, not again
    assert [d["place"] for d in read_review(new)] == ["A-01-2"]


def test_the_console_shows_a_resumed_fleets_carried_crops(tmp_path):
    old = _previous(tmp_path, "drones/cf1")
    os.makedirs(os.path.join(old, "drones", "cf1"), exist_ok=True)
    with open(os.path.join(old, "inventory.json"), encoding="utf-8") as f:
        doc = json.load(f)
    for r in doc["rows"]:
        r["drone"] = "cf1"
    with open(os.path.join(old, "inventory.json"), "w", encoding="utf-8") as f:
        json.dump(doc, f)
    new = tmp_path / "new"
    (new / "drones" / "cf2").mkdir(parents=True)
    (new / "drones" / "cf2" / "ticks.jsonl").write_text('{"header": {}}\n')
    log = InventoryLog(str(new), old, "fleet", run="new")
    log.plan(["A-01-1", "A-01-2", "A-02-1"])
    log.record(_row("A-02-1", "", "empty", drone="cf2", run="new"))
    info = run_info(RunsRoot(str(tmp_path)), "new", full=True)
    assert info["evidence"]["A-01-2"]["crops"] == [
        f"places/A-01-2/block_{i}.png" for i in (1, 2, 3)
    ]
    assert "A-02-1" not in info["evidence"]
    assert info["reviewed"] == 1 and info["review"][0]["answer"] == "117B"
