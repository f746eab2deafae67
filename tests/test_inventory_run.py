"""The per-place inventory's rows, grades and files; battery changes; resuming after a kill (the
sweep's own: tests/test_sweep.py)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest
from helpers import REPO, wait_until, xml_mission

from bt_engine.cli import main
from drivers.crazyflie.cflib_link import CrazyflieLink
from nodes.energy import needed_percent
from nodes.inventory_log import InventoryError, InventoryLog, grade, read_inventory

RIG = os.path.join(REPO, "rigs", "aisle.yaml")
MISSION = os.path.join(REPO, "missions", "inventory_per_place.xml")  # place by place


def test_grades_against_the_ground_truth():
    not_enrolled = {"115A"}
    assert grade("103B", "103B", not_enrolled) == "right"
    assert grade("103A", "103B", not_enrolled) == "wrong"
    assert grade("unknown", "103B", not_enrolled) == "unknown"
    assert grade("empty", "103B", not_enrolled) == "missed"
    assert grade("unknown", "115A", not_enrolled) == "right"  # not in the gallery
    assert grade("103B", "115A", not_enrolled) == "wrong"
    assert grade("empty", None, not_enrolled) == "right"
    assert grade("103B", None, not_enrolled) == "wrong"
    assert grade("", "103B", not_enrolled) == "not_scanned"


def test_rows_are_written_at_once_and_carried_over_by_a_resumed_run(tmp_path):
    first = InventoryLog(str(tmp_path / "a"), drone="cf1")
    assert first.plan(["A-01-1", "A-01-2", "A-02-2"]) == ["A-01-1", "A-01-2", "A-02-2"]
    first.record({"place": "A-01-1", "answer": "103B", "status": "identified", "distance": 0.2})
    first.record({"place": "A-01-2", "answer": "", "status": "not_scanned"})
    rows = read_inventory(str(tmp_path / "a"))
    assert [r["place"] for r in rows] == ["A-01-1", "A-01-2"] and rows[0]["drone"] == "cf1"
    csv = (tmp_path / "a" / "inventory.csv").read_text().splitlines()
    assert csv[0].startswith("place,answer,status") and csv[1].startswith("A-01-1,103B,identified")
    again = InventoryLog(str(tmp_path / "b"), resume_from=str(tmp_path / "a"))
    # a not-scanned place is flown again; an answered one never
    assert again.plan(["A-01-1", "A-01-2", "A-02-2"]) == ["A-01-2", "A-02-2"]
    again.record({"place": "A-02-2", "answer": "empty", "status": "empty"})
    kept = {r["place"]: r for r in read_inventory(str(tmp_path / "b"))}
    assert kept["A-01-1"]["answer"] == "103B" and kept["A-01-1"]["run"] == "a"
    s = again.run_summary()
    assert s["carried_over"] == 2 and s["status"] == {
        "identified": 1,
        "not_scanned": 1,
        "empty": 1,
    }


def test_a_damaged_inventory_is_refused(tmp_path):
    (tmp_path / "inventory.json").write_text('{"format": "something else"}')
    with pytest.raises(InventoryError, match="not a btrun inventory"):
        InventoryLog(str(tmp_path / "new"), resume_from=str(tmp_path))


def test_record_place_says_what_the_scan_found(tmp_path):
    xml = """<root BTCPP_format="4"><BehaviorTree ID="M"><Sequence>
      <RecordPlace place="A-01-1" pallet_id="104A" distance="0.21" margin="0.4"/>
      <RecordPlace place="A-01-2" blocks_seen="0"/>
      <RecordPlace place="A-02-1" blocks_seen="2"/>
      <RecordPlace place="A-02-2"/>
      <RecordPlace place="A-03-1" pallet_id="unknown"/>
    </Sequence></BehaviorTree></root>"""
    m = xml_mission(xml, resources={"run_dir": str(tmp_path)})
    m.tick()
    rows = {r["place"]: r for r in read_inventory(str(tmp_path))}
    assert (rows["A-01-1"]["answer"], rows["A-01-1"]["status"]) == ("104A", "identified")
    assert rows["A-01-1"]["distance"] == 0.21
    assert (rows["A-01-2"]["answer"], rows["A-01-2"]["status"]) == ("empty", "empty")
    assert (rows["A-02-1"]["answer"], rows["A-02-1"]["status"]) == ("unknown", "not_identified")
    assert (rows["A-02-2"]["answer"], rows["A-02-2"]["status"]) == ("", "not_scanned")
    assert (rows["A-03-1"]["answer"], rows["A-03-1"]["status"]) == ("unknown", "unknown")


def test_an_unknown_from_a_rescan_keeps_its_reason_and_the_blocks_it_used(tmp_path):
    """The rescan's RecordPlace is given no reason: the row had an empty reason and the
    blocks LocatePallet saw before the rescan (2), not the three the identification used
    (validation probe, fleet seed 303: five such rows)."""
    import types

    import numpy as np

    crops = [np.full((40, 30, 3), 90 + 20 * i, np.uint8) for i in range(3)]
    session = types.SimpleNamespace(
        faces=[{"stage": "located", "blocks_seen": 2}],
        identifications=[
            {
                "ranking": [["1071B", 0.55, [0.5, 0.6, 0.55]]],
                "reason": "margin 0.206 to 1071B below the threshold 0.251",
                "crops": crops,
            }
        ],
    )
    xml = """<root BTCPP_format="4"><BehaviorTree ID="M"><Sequence>
      <RecordPlace place="A-03-1" pallet_id="unknown" best_id="1026B"/>
    </Sequence></BehaviorTree></root>"""
    m = xml_mission(xml, resources={"run_dir": str(tmp_path), "perception": session})
    m.tick()
    row = read_inventory(str(tmp_path))[0]
    assert (row["answer"], row["status"]) == ("unknown", "unknown")
    assert row["reason"] == "margin 0.206 to 1071B below the threshold 0.251"
    assert row["blocks_seen"] == 3


def test_energy_needed_covers_the_way_there_the_work_and_the_way_back():
    need, seconds = needed_percent(0.25, 3.0, 2.0, 0.5, 40.0, 8.0, 15.0)
    assert seconds == pytest.approx(10.0 + 40.0 + 8.0)
    assert need == pytest.approx(0.25 * 58.0 + 15.0)


def test_a_real_battery_cannot_be_swapped_by_the_mission():
    why = CrazyflieLink.battery_service(None, "swap")  # type: ignore[arg-type]
    assert "swapped by hand" in why and "--resume" in why
    assert CrazyflieLink.battery_service(None, "charge") == ""  # type: ignore[arg-type]


@pytest.mark.slow
def test_a_battery_change_resumes_at_the_place_it_interrupted(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(
        [MISSION, "--rig", RIG, "--out", str(out), "-q", "--no-report",
         "--set", "places=A-02-1;A-02-2;A-03-1", "--set", "battery.initial_soc=0.4"]
    )  # fmt: skip
    assert code == 0, capsys.readouterr()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sim"]["battery"]["swaps"] == 1 and summary["sim"]["landed"]
    rows = read_inventory(str(out))
    assert [r["place"] for r in rows] == ["A-02-1", "A-02-2", "A-03-1"]  # none skipped
    times = [r["mission_time_s"] for r in rows]
    records = [json.loads(line) for line in (out / "ticks.jsonl").read_text().splitlines()[1:]]
    swap_t = next(r["t"] for r in records for msg in r.get("messages", ()) if "battery swap" in msg)
    # the charge ran short before a place; the change came between two rows, then that place
    assert times[0] < swap_t < times[-1]
    assert summary["inventory"]["status"].get("not_scanned", 0) == 0


@pytest.mark.slow
def test_resume_after_a_kill_in_the_middle_of_a_place(tmp_path):
    first = tmp_path / "first"
    places = "A-04-1;A-04-2;A-05-1"
    proc = subprocess.Popen(
        [sys.executable, "-m", "bt_engine.cli", MISSION, "--rig", RIG, "--out", str(first),
         "-q", "--no-report", "--seed", "2", "--set", f"places={places}"],
        cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        wait_until(lambda: len(read_inventory(str(first))) >= 1, 300, "the first row")
    finally:
        proc.send_signal(signal.SIGKILL)  # no clean-up of any kind
        proc.wait()
    done = read_inventory(str(first))  # a whole, valid file (written atomically)
    assert 1 <= len(done) < 3
    second = tmp_path / "second"
    code = main([MISSION, "--resume", str(first), "--out", str(second), "-q", "--no-report"])
    assert code == 0
    rows = read_inventory(str(second))
    assert [r["place"] for r in rows] == places.split(";")  # every place, once, in order
    assert rows[: len(done)] == done  # the finished rows, unchanged
    header = json.loads((second / "ticks.jsonl").read_text().splitlines()[0])["header"]
    assert header["seed"] == 2 and header["rig_arg"] == RIG  # taken from the first run
    flown = [
        msg.split()[1].rstrip(":")
        for line in (second / "ticks.jsonl").read_text().splitlines()[1:]
        for msg in json.loads(line).get("messages", ())
        if msg.startswith("inventory A-")
    ]
    assert flown == [r["place"] for r in rows[len(done) :]]  # no finished place flown again


def test_charging_on_the_pad_raises_the_charge_until_the_target():
    from helpers import sim_mission

    xml = """<root BTCPP_format="4"><BehaviorTree ID="M">
      <ChangeBattery mode="charge" duration="5" target_percent="80" check_period="20" settle="6"/>
    </BehaviorTree></root>"""
    m, run, pf = sim_mission(
        xml,
        rig="rigs/aisle.yaml",
        overrides={"battery.initial_soc": 0.3, "battery.charge_current_a": 5.0},
    )
    result = run.run(max_time_s=600)
    assert result.status == "SUCCESS", result.reason
    soc = pf.summary()["battery"]["soc"]
    assert 0.7 < soc < 0.95  # charged to about the target, then stopped
    assert not pf.drone.battery.charging
    # 0.3 -> 0.8 of 250 mAh at 4.9 A net: about 92 s of charging, read every 20 s
    assert 90.0 < result.mission_time_s < 200.0


def test_a_battery_change_in_flight_is_refused():
    from helpers import sim_mission

    xml = """<root BTCPP_format="4"><BehaviorTree ID="M"><Sequence>
      <TakeOff height="0.5"/><ChangeBattery mode="swap"/>
    </Sequence></BehaviorTree></root>"""
    m, run, pf = sim_mission(xml, rig="rigs/aisle.yaml")
    result = run.run(max_time_s=60)
    assert result.status == "FAILURE"
    assert "flying: land first" in result.reason
    assert pf.summary()["battery"]["swaps"] == 0


def test_a_battery_change_forgets_what_was_measured_on_the_old_battery():
    """The consumption measured in flight is kept on this battery however old it is (the
    sweep's look-ahead used the assumed endurance once the last measurement was 30 s old,
    after a per-place rescan), and forgotten when ChangeBattery puts in another."""
    import math

    from helpers import sim_mission

    from nodes.energy import RATE_KEY, measured_rate

    xml = """<root BTCPP_format="4"><BehaviorTree ID="M"><Sequence>
      <TakeOff height="0.5"/>
      <ReactiveSequence>
        <EnoughEnergy target="0;0;0.5" home="0;0;0" reserve="5" period="1"/>
        <Hover duration="25"/>
      </ReactiveSequence>
      <Hover duration="40"/>
      <Land/>
      <ChangeBattery mode="swap" duration="5"/>
    </Sequence></BehaviorTree></root>"""
    m, run, pf = sim_mission(xml, rig="rigs/aisle.yaml")
    seen = []
    run.hooks.append(
        type(
            "Watch",
            (),
            {
                "before_tick": lambda self, t: None,
                "after_tick": lambda self, t: seen.append(
                    (t, m.ctx.resources.get(RATE_KEY), measured_rate(m.ctx, t, math.inf))
                ),
                "shutdown": lambda self, reason: None,
            },
        )()
    )
    result = run.run(max_time_s=200)
    assert result.status == "SUCCESS", result.reason
    measured = [s for s in seen if s[1] is not None]
    assert measured, "EnoughEnergy measured no consumption in 25 s of flight"
    assert all(s[1][1] > 0 for s in measured)
    later = [s for s in measured if s[0] - s[1][0] > 30.0]  # measured over 30 s before
    assert later and all(s[2] == s[1][1] for s in later)  # kept at any age on this battery
    assert measured_rate(m.ctx, later[0][0]) is None  # the default age limit
    assert seen[-1][1] is None  # the swap forgot it


def test_the_sweep_look_ahead_uses_a_consumption_measured_minutes_ago(tmp_path):
    """EnoughEnergyForPass plans with the rate measured on this battery, not the assumed
    endurance, however old the measurement (a rescan can take minutes)."""
    from helpers import sim_mission

    from nodes.energy import RATE_KEY

    xml = """<root BTCPP_format="4"><BehaviorTree ID="M"><Sequence>
      <InventoryPlan places="all" queue="{todo}"/>
      <TakeOff height="0.5" takeoff_point="{home}"/>
      <PlanSweep places="{todo}" passes="{passes}"/>
      <EnoughEnergyForPass name="look_ahead" pass="A/1" home="{home}"/>
    </Sequence></BehaviorTree></root>"""
    m, run, _ = sim_mission(xml, rig="rigs/site.yaml", overrides={"battery.initial_soc": 0.4})
    m.ctx.resources["run_dir"] = str(tmp_path)
    m.ctx.resources[RATE_KEY] = (-120.0, 0.2)  # 12 %/min, measured two minutes before
    result = run.run(max_time_s=60)
    assert result.status == "FAILURE"  # not enough charge for the sweep: change first
    assert "at 12.00 %/min (measured)" in result.reason, result.reason


def test_a_reason_never_says_a_score_is_below_itself():
    from perception.expected import _below

    assert _below(3.296, 3.30) == "3.296 below 3.30"  # it read '3.30 below 3.30'
    assert _below(3.21, 3.3) == "3.21 below 3.30"
