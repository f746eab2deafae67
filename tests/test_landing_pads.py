"""Landing on the nearest pad (nodes/landing_pads.py's NearestPad, the fleet file's
landing_pads): the drone lands where its work ended, not back across the aisle; a pad the
world does not have or another drone's pad is refused before anything flies."""

from __future__ import annotations

import math
import os

from helpers import REPO, problems_of_xml, sim_mission, wrap

from bt_engine.cli import main

AISLE = "rigs/aisle.yaml"  # pad-1 at (1.0, 2.8), pad-2 at (1.0, -2.8)


def _fly_and_land(goal_y: float, pads: str):
    xml = wrap(
        f"""    <Sequence>
      <TakeOff height="1.0" speed="0.5" takeoff_point="{{home}}"/>
      <GoTo pose="1.0;{goal_y};1.0" max_speed="1.0"/>
      <NearestPad home="{{home}}" pads="{pads}" point="{{landing_point}}" pad="{{pad}}"/>
      <FlyRoute pose="{{landing_point}}" max_speed="1.0"/>
      <Land speed="0.5"/>
    </Sequence>"""
    )
    m, runner, platform = sim_mission(xml, rig=AISLE, overrides={"sim.start_m": [1.0, 2.8, 0.0]})
    result = runner.run(max_time_s=60)
    assert result.status == "SUCCESS", result.reason
    return m.blackboard.get("pad"), platform.vehicle.position


def test_the_drone_lands_on_the_nearest_of_its_pads():
    pad, (x, y, z) = _fly_and_land(-2.0, "pad-2")
    assert pad == "pad-2"
    assert math.hypot(x - 1.0, y + 2.8) < 0.1 and z < 0.05  # on pad-2, not back home
    pad, (x, y, z) = _fly_and_land(2.0, "pad-2")
    assert pad == "home"  # the take-off pad is nearer
    assert math.hypot(x - 1.0, y - 2.8) < 0.1 and z < 0.05
    pad, (x, y, _) = _fly_and_land(-2.0, "")
    assert pad == "home" and math.hypot(x - 1.0, y - 2.8) < 0.1  # no pads: home


def test_a_pad_the_world_does_not_have_is_refused_before_flight(tmp_path, capsys):
    xml = wrap(
        """    <Sequence>
      <TakeOff height="1.0" speed="0.5" takeoff_point="{home}"/>
      <NearestPad home="{home}" pads="pad-2;pad-9" point="{p}"/>
      <Land/>
    </Sequence>"""
    )
    path = tmp_path / "m.xml"
    path.write_text(xml)
    out = tmp_path / "run"
    rig = os.path.join(REPO, AISLE)
    assert main([str(path), "--rig", rig, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{path}:5:" in err, err
    assert "unknown pad 'pad-9': expected one of the world's pads (pad-1, pad-2)" in err, err
    assert "pad-2'" not in err.replace("(pad-1, pad-2)", "")  # only the bad one
    assert not (out / "summary.json").exists()
    assert problems_of_xml(xml) == []  # the tree itself is valid: the world refuses it


def test_a_fleet_drone_lands_on_its_landing_pad_where_its_pass_ends(tmp_path):
    """The fleet file's landing_pads reach the drone's mission: one pass along the aisle
    from pad-1's end ends at pad-2's, and the drone lands there."""
    import json

    fleet = tmp_path / "fleet.yaml"
    fleet.write_text(
        f"name: t\nmission: {os.path.join(REPO, 'missions', 'inventory.xml')}\n"
        f"rig: {os.path.join(REPO, AISLE)}\nplaces: A-0*-1\n"
        "drones:\n  - {name: cf1, pad: pad-1, landing_pads: [pad-2]}\n"
    )
    out = tmp_path / "run"
    assert main(["fleet", str(fleet), "--out", str(out), "-q", "--no-report", "--no-mcap"]) == 0
    drone = out / "drones" / "cf1"
    summary = json.loads((drone / "summary.json").read_text())
    pose = summary["sim"]["final_pose"]
    x, y = pose["x_m"], pose["y_m"]
    assert summary["sim"]["landed"] and math.hypot(x - 1.0, y + 2.8) < 0.15, (x, y)
    assert summary["blackboard"]["landing_pads"] == "pad-2"


def test_a_landing_pad_set_on_the_command_line_is_checked_before_flight(tmp_path, capsys):
    out = tmp_path / "run"
    mission = os.path.join(REPO, "missions", "inventory.xml")
    rig = os.path.join(REPO, "rigs", "site.yaml")
    args = [mission, "--rig", rig, "--set", "landing_pads=pad-5;pad-12", "--out", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "--set landing_pads: unknown pad 'pad-12': expected one of the world's pads" in err
    assert "pad-5'" not in err.split("pads (")[0]  # pad-5 is the site's: only pad-12 refused
    assert not out.exists()
