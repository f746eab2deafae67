"""Inventory paper cuts: resumed fleet rows marked, grades of empty places, the resume
command of an interrupted fleet, fleet folders given to replay / a solo resume, the CSV's
blocks_seen and drone columns, the report's lead and the aisle's demo gallery name."""

from __future__ import annotations

import csv
import json
import os

from helpers import REPO

from bt_engine.cli import main
from bt_engine.spec import plural
from nodes.fleet.run import _print
from nodes.inventory_log import FORMAT, InventoryLog, grade

RIG = os.path.join(REPO, "rigs", "aisle.yaml")
MISSION = os.path.join(REPO, "missions", "inventory.xml")
FLEET = os.path.join(REPO, "fleets", "aisle_2.yaml")


def _csv(folder: str) -> dict[str, dict]:
    with open(os.path.join(folder, "inventory.csv"), encoding="utf-8") as f:
        return {r["place"]: r for r in csv.DictReader(f)}


def _fake_fleet_run(folder: str, rows: list[dict]) -> None:
    """A fleet run folder as an interrupted ``btrun fleet`` leaves it."""
    os.makedirs(os.path.join(folder, "drones", "cf1"))
    with open(os.path.join(folder, "fleet.json"), "w", encoding="utf-8") as f:
        json.dump({"fleet": FLEET, "seed": 0, "set": []}, f)
    with open(os.path.join(folder, "inventory.json"), "w", encoding="utf-8") as f:
        json.dump({"format": FORMAT, "planned": [r["place"] for r in rows], "rows": rows}, f)


def test_an_empty_place_answered_unknown_is_wrong_not_unknown() -> None:
    """Nothing stands there: only ``empty`` is right; ``unknown`` claims a pallet."""
    assert grade("unknown", None, {"115A"}) == "wrong"
    assert grade("empty", None, {"115A"}) == "right"
    assert grade("unknown", "103B", {"115A"}) == "unknown"


def test_a_fleet_resume_marks_carried_rows_and_counts_blocks(tmp_path, capsys) -> None:
    """Carried rows keep their run; new rows name the new fleet folder (not the drone's)."""
    old = str(tmp_path / "old")
    _fake_fleet_run(
        old,
        [
            {
                "place": "A-01-1",
                "answer": "109B",
                "status": "identified",
                "drone": "cf1",
                "run": "old",
            }
        ],
    )
    out = str(tmp_path / "new")
    code = main(
        ["fleet", FLEET, "--resume", old, "--set", "places=A-01-1;A-02-1"]
        + ["--out", out, "-q", "--no-report", "--no-mcap"]
    )
    assert code == 0
    rows = _csv(out)
    assert rows["A-01-1"]["run"] == "old"
    assert rows["A-02-1"]["run"] == "new"
    assert rows["A-02-1"]["drone"] in ("cf1", "cf2")
    assert rows["A-02-1"]["status"] == "identified"
    assert int(rows["A-02-1"]["blocks_seen"]) >= 3
    assert "1 carried over from the resumed run" in capsys.readouterr().out


def test_a_solo_run_names_its_drone_and_counts_blocks(tmp_path) -> None:
    """The ``drone`` column of a solo run is the rig's name; identified rows say how many
    blocks LocatePallet saw."""
    out = str(tmp_path / "solo")
    code = main(
        [MISSION, "--rig", RIG, "--set", "places=A-01-1", "--out", out]
        + ["-q", "--no-report", "--no-mcap"]
    )
    assert code == 0
    row = _csv(out)["A-01-1"]
    assert row["status"] == "identified"
    assert row["drone"] == "aisle"
    assert int(row["blocks_seen"]) >= 3


def test_an_interrupted_fleet_prints_its_resume_command(capsys) -> None:
    summary = {
        "fleet": "aisle_2",
        "status": "ABORTED",
        "mission_time_s": 10.0,
        "wall_time_s": 1.0,
        "drones": {
            "cf1": {
                "status": "ABORTED",
                "reason": "operator interrupt (Ctrl-C)",
                "mission_time_s": 10.0,
                "answered": 0,
                "places": 1,
            }
        },
        "inventory": {
            "places": 1,
            "status": {"not_scanned": 1},
            "not_scanned_places": ["A-01-1"],
        },
        "separation": {
            "closest_m": None,
            "minimum_m": 0.5,
            "violations": 0,
            "holds": 0,
            "airspace_waits": 0,
        },
    }
    _print(summary, "runs/x", "fleets/aisle_2.yaml")
    assert "btrun fleet fleets/aisle_2.yaml --resume runs/x" in capsys.readouterr().out


def test_a_fleet_folder_given_to_replay_or_a_solo_resume_says_where_to_go(tmp_path, capsys) -> None:
    folder = str(tmp_path / "fleetrun")
    _fake_fleet_run(folder, [])
    assert main(["replay", folder]) == 2
    err = capsys.readouterr().err
    assert os.path.join(folder, "drones", "cf1") in err
    assert main([MISSION, "--resume", folder]) == 2
    said = capsys.readouterr()
    assert "btrun fleet" in said.err + said.out and f"--resume {folder}" in said.err + said.out


def test_the_aisles_demo_gallery_is_named_by_its_rig(capsys) -> None:
    """``demo`` is the rig's world's demo gallery, in the gallery commands as in a mission."""
    assert main(["gallery", "list", "demo", "--rig", RIG]) == 0
    out = capsys.readouterr().out
    assert "aisle.yaml" in out and "114B" in out
    with open(os.path.join(REPO, "docs", "inventory.md"), encoding="utf-8") as f:
        assert "btrun gallery list demo --rig rigs/aisle.yaml" in f.read()


def test_the_report_leads_with_the_answer_and_tables_the_pallets() -> None:
    from nodes.report.html import _html

    pallet = {"identity": "109B", "slot": "A-01-1", "centre_m": [3.48, 4.94], "base_z_m": 0.2}
    summary = {
        "mission": "missions/inventory.xml",
        "status": "SUCCESS",
        "reason": "done",
        "sim": {"landed": True, "pallets": [pallet]},
        "inventory": {"places": 2, "status": {"identified": 2}, "right": 2, "wrong": 0},
    }
    page = _html(summary, None, [], [], [])
    assert page.index("<h2>Answer</h2>") < page.index("<h2>Run</h2>")
    assert "inventory: 2 places, 2 identified" in page
    assert "<td class=l>109B</td><td class=l>A-01-1</td>" in page
    assert '"identity"' not in page and "&quot;identity&quot;" not in page
    ident = {"pallet_id": "7A", "distance": 0.4, "margin": 0.5, "decided_by": "embedding"}
    solo = {"status": "SUCCESS", "perception": {"identifications": [ident]}}
    page = _html(solo, None, [], [], [])
    assert "pallet: 7A (distance 0.400, margin 0.500, decided by embedding)" in page
    assert page.index("<h2>Answer</h2>") < page.index("<h2>Run</h2>")


def test_the_fleet_report_leads_with_the_answer_too(tmp_path) -> None:
    from nodes.fleet.report import write_fleet_report

    drone = {
        "run_dir": "drones/cf1", "status": "SUCCESS", "reason": "done", "mission_time_s": 60.0,
        "answered": 2, "places": 2, "waits": 0, "pauses": 0, "collisions": 0,
    }  # fmt: skip
    summary = {
        "fleet": "aisle_2", "status": "SUCCESS", "seed": 0, "mission_time_s": 60.0,
        "wall_time_s": 5.0, "drones": {"cf1": drone},
        "separation": {"closest_m": None, "minimum_m": 0.5, "violations": 0, "holds": 0,
                       "airspace_waits": 0},
        "inventory": {"places": 2, "status": {"identified": 2}, "right": 2, "wrong": 0},
    }  # fmt: skip
    page = open(write_fleet_report(str(tmp_path), summary, {}, {})).read()
    assert page.index("<h2>Answer</h2>") < page.index("<h2>Drones</h2>")
    assert "inventory: 2 places, 2 identified" in page


def _fake_solo_run(folder: str, seed: int, rows: list[dict]) -> None:
    """A solo inventory run folder as an interrupted ``btrun run`` leaves it (flown on the
    site's rig with ``seed``)."""
    os.makedirs(folder)
    header = {
        "mission": MISSION,
        "rig": os.path.join(REPO, "rigs", "site.yaml"),
        "rig_arg": os.path.join(REPO, "rigs", "site.yaml"),
        "seed": seed,
        "sets": [],
    }
    with open(os.path.join(folder, "ticks.jsonl"), "w", encoding="utf-8") as f:
        f.write(json.dumps({"header": header}) + "\n")
    with open(os.path.join(folder, "inventory.json"), "w", encoding="utf-8") as f:
        json.dump({"format": FORMAT, "planned": [r["place"] for r in rows], "rows": rows}, f)


def test_a_resume_keeps_its_seed_and_its_world(tmp_path, capsys) -> None:
    """A resumed run continues in the world the carried answers were made in: another
    ``--seed`` (another simulated stock) or a rig whose world lacks the answered places
    (they were graded against the wrong world: '130 wrong identities accepted') is refused
    before anything flies, solo and fleet."""
    row = {"place": "B-07-2", "answer": "1042A", "status": "identified", "drone": "site"}
    solo = str(tmp_path / "solo")
    _fake_solo_run(solo, 777, [row])
    out = str(tmp_path / "new")
    assert main([MISSION, "--resume", solo, "--seed", "3", "--out", out, "-q"]) == 2
    err = capsys.readouterr().err
    assert f"--resume {solo} flew seed 777, not 3: a resumed run keeps its seed" in err
    assert main([MISSION, "--resume", solo, "--rig", RIG, "--out", out, "-q"]) == 2
    err = capsys.readouterr().err
    assert f"--resume {solo} answered places this world does not have (B-07-2)" in err
    assert not os.path.exists(out)
    fleet = str(tmp_path / "fleet")
    _fake_fleet_run(fleet, [row])  # flew fleets/aisle_2.yaml, seed 0
    assert main(["fleet", FLEET, "--resume", fleet, "--out", out, "--seed", "5"]) == 2
    assert f"{fleet} flew seed 0, not 5" in capsys.readouterr().err
    assert main(["fleet", FLEET, "--resume", fleet, "--out", out]) == 2
    assert "answered places this world does not have (B-07-2)" in capsys.readouterr().err
    assert not os.path.exists(out)


def test_a_resume_keeps_the_runs_settings_and_adds_the_new_ones(tmp_path) -> None:
    """``--set`` on a resume used to replace every setting of the interrupted run: a run of
    ``places=B-*`` resumed with ``--set battery_reserve=0.3`` planned the whole site."""
    import argparse

    from bt_engine.run_cmd import resume_settings

    folder = str(tmp_path / "solo")
    _fake_solo_run(folder, 777, [])
    with open(os.path.join(folder, "ticks.jsonl"), encoding="utf-8") as f:
        record = json.loads(f.readline())
    record["header"]["sets"] = ["places=B-*", "battery_reserve=0.2"]
    with open(os.path.join(folder, "ticks.jsonl"), "w", encoding="utf-8") as f:
        f.write(json.dumps(record) + "\n")
    args = argparse.Namespace(
        resume=folder, mission=MISSION, seed=None, rig=None, set=["battery_reserve=0.3"]
    )
    assert resume_settings(args) == []
    assert args.set == ["places=B-*", "battery_reserve=0.2", "battery_reserve=0.3"]
    assert args.seed == 777 and args.rig == os.path.join(REPO, "rigs", "site.yaml")


def test_a_resume_from_another_folder_reads_the_runs_own_files(tmp_path, monkeypatch) -> None:
    """``--set expected=stock.csv`` is relative to the folder the run was started from: a
    resume from another folder read that folder's ``stock.csv`` (another WMS file, no word
    said) or none. It now reads the run's own file; a same-named file found only here is
    refused rather than guessed."""
    import argparse

    from bt_engine.run_cmd import resume_settings

    folder = str(tmp_path / "solo")
    _fake_solo_run(folder, 777, [])
    started, other = tmp_path / "started", tmp_path / "other"
    started.mkdir()
    other.mkdir()
    (started / "stock.csv").write_text("place,pallet\n")
    (other / "stock.csv").write_text("place,pallet\n")
    with open(os.path.join(folder, "ticks.jsonl"), encoding="utf-8") as f:
        record = json.loads(f.readline())
    record["header"]["sets"] = ["expected=stock.csv", "battery_reserve=0.2"]
    record["header"]["cwd"] = str(started)
    with open(os.path.join(folder, "ticks.jsonl"), "w", encoding="utf-8") as f:
        f.write(json.dumps(record) + "\n")
    monkeypatch.chdir(other)

    def resumed(*sets: str):
        args = argparse.Namespace(resume=folder, mission=MISSION, seed=None, rig=None, set=[*sets])
        return resume_settings(args), args.set

    assert resumed() == ([], [f"expected={started / 'stock.csv'}", "battery_reserve=0.2"])
    os.remove(started / "stock.csv")  # moved away: the one here is not taken for it
    problems, _ = resumed()
    assert len(problems) == 1 and "--set expected=stock.csv named a file relative to" in str(
        problems[0]
    )
    assert resumed("expected=stock.csv")[0] == []  # given again: this folder's, on purpose
    # a fleet's record keeps its folder as well
    from nodes.fleet.check import common_sets, previous_run

    fleet = str(tmp_path / "fleet")
    _fake_fleet_run(fleet, [])
    (started / "stock.csv").write_text("place,pallet\n")
    with open(os.path.join(fleet, "fleet.json"), "w", encoding="utf-8") as f:
        record = {"fleet": FLEET, "seed": 0, "set": ["expected=stock.csv"], "places": None}
        json.dump({**record, "cwd": str(started)}, f)
    assert common_sets(None, ["x=1"], previous_run(fleet)) == [
        f"expected={started / 'stock.csv'}",
        "x=1",
    ]


def test_a_fleet_resume_flies_with_the_runs_settings_and_places(tmp_path, capsys) -> None:
    """A resumed fleet used to keep only its seed: a run of ``--set places=A-01-1;A-02-1``
    with an emptier stock, resumed, planned all 16 places in another stock. It now flies
    the settings and places in ``fleet.json``, with the new ``--set`` after them; and
    ``--check --resume`` checks what the resume would fly (it used to ignore ``--resume``)."""
    row = {"place": "A-01-1", "answer": "109B", "status": "identified", "drone": "cf1"}
    old = str(tmp_path / "old")
    _fake_fleet_run(old, [row])
    record = {
        "fleet": FLEET,
        "seed": 0,
        "set": ["world.stock.empty_places=3"],
        "places": ["A-01-1", "A-02-1"],
    }
    with open(os.path.join(old, "fleet.json"), "w", encoding="utf-8") as f:
        json.dump(record, f)
    assert main(["fleet", FLEET, "--check", "--resume", old]) == 0
    said = capsys.readouterr().out
    # one place left: one drone flies it, the other stays on its pad
    assert "cf1: 1 place," in said and "no place to fly" in said, said
    # the run's settings are checked again: a bad one stored there is refused
    record["set"].append("world.stock.empty_places=-2")
    with open(os.path.join(old, "fleet.json"), "w", encoding="utf-8") as f:
        json.dump(record, f)
    assert main(["fleet", FLEET, "--check", "--resume", old]) == 2
    assert "empty_places" in capsys.readouterr().err
    # ... and a new --set comes after them
    record["set"].pop()
    with open(os.path.join(old, "fleet.json"), "w", encoding="utf-8") as f:
        json.dump(record, f)
    assert main(["fleet", FLEET, "--check", "--resume", old, "--set", "places=all"]) == 0
    assert "1 place," not in capsys.readouterr().out
    # the checks of a resume are made by --check too
    assert main(["fleet", FLEET, "--check", "--resume", old, "--seed", "5"]) == 2
    assert f"{old} flew seed 0, not 5" in capsys.readouterr().err
    assert main(["fleet", FLEET, "--check", "--resume", str(tmp_path)]) == 2
    assert "is not a fleet run folder" in capsys.readouterr().err
    with open(os.path.join(old, "fleet.json"), "w", encoding="utf-8") as f:
        json.dump({"seed": 0, "set": "places=all"}, f)
    assert main(["fleet", FLEET, "--check", "--resume", old]) == 2
    assert "'set' is not a list of KEY=VALUE" in capsys.readouterr().err


def test_a_fleet_run_records_its_places_for_the_resume(tmp_path) -> None:
    """``fleet.json`` holds the settings and the planned places a resume flies with."""
    out = str(tmp_path / "run")
    code = main(
        ["fleet", FLEET, "--set", "places=A-01-1;A-02-1", "--set", "world.stock.empty_places=1"]
        + ["--out", out, "-q", "--no-report", "--no-mcap"]
    )
    assert code == 0
    with open(os.path.join(out, "fleet.json"), encoding="utf-8") as f:
        record = json.load(f)
    assert record["places"] == ["A-01-1", "A-02-1"]
    assert "world.stock.empty_places=1" in record["set"]
    assert not any(item.startswith("places=") for item in record["set"])


def test_counts_of_one_are_said_in_the_singular(tmp_path):
    """'1 places' and '1 drones' were printed: a count of one now takes the singular."""
    assert [plural(n, "place") for n in (0, 1, 2)] == ["0 places", "1 place", "2 places"]
    assert plural(1, "pass", "passes") == "1 pass" and plural(3, "pass", "passes") == "3 passes"
    assert plural(2, "child", "children") == "2 children"
    log = InventoryLog(str(tmp_path))
    log.plan(["A-01-1", "A-01-2"])
    log.record({"place": "A-01-1", "answer": "101A", "status": "identified"})
    assert log.result_lines()[0].startswith("inventory: 2 places, 1 identified")


def test_a_fleet_drones_pace_is_over_its_own_mission_time() -> None:
    """A fleet's drones share one clock, which runs on until the last drone lands: each
    drone's summary.json had the pace over the fleet's whole time (813.6 for all four,
    though one drone's own 36 places in 142.8 s are 908 per hour)."""
    from types import SimpleNamespace

    from bt_engine.summary import build_summary

    log = InventoryLog(None, None, "cf3")
    log.now = lambda: 159.3  # the fleet's clock when the summaries are written
    for b in range(1, 37):
        log.record({"place": f"A-{b:02d}-1", "answer": "", "status": "empty"})
    assert log.run_summary()["places_per_hour"] == round(36 * 3600 / 159.3, 1)
    result = SimpleNamespace(
        status="SUCCESS", reason="", ticks=1, mission_time_s=142.8, wall_time_s=1.0
    )
    mission = SimpleNamespace(
        ctx=SimpleNamespace(resources={"inventory": log}),
        blackboard={},
        leaf_failures={},
    )
    summary = build_summary(result, mission, mission_path="m.xml", seed=0, rate_hz=50.0)
    assert summary["inventory"]["places_per_hour"] == round(36 * 3600 / 142.8, 1) == 907.6
