"""A landing never comes down onto another drone: two drones of a fleet sent to the same
point (an absolute GoTo in a shared mission) used to land one on top of the other, and the
fleet said SUCCESS. The second now lands beside the first; drones that touch fail the fleet."""

from __future__ import annotations

import json
import math
import os

from helpers import REPO

from bt_engine.cli import main
from drivers.safety.airspace import Airspace

RIG = os.path.join(REPO, "rigs", "aisle.yaml")
SAME_POINT = """<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <Sequence>
      <TakeOff height="1.0"/>
      <GoTo pose="1.0;0.0;1.0" timeout="60s"/>
      <Land/>
    </Sequence>
  </BehaviorTree>
</root>
"""


def _fly_same_point(tmp_path) -> tuple[int, dict]:
    """Two drones of a fleet flying SAME_POINT: exit code and summary.json."""
    (tmp_path / "m.xml").write_text(SAME_POINT)
    (tmp_path / "f.yaml").write_text(
        f"name: same\nmission: m.xml\nrig: {RIG}\n"
        "drones:\n  - {name: cf1, pad: pad-1}\n  - {name: cf2, pad: pad-2}\n"
    )
    out = tmp_path / "run"
    args = ["fleet", str(tmp_path / "f.yaml"), "--out", str(out), "--no-report", "--store", "none"]
    code = main(args)
    return code, json.loads((out / "summary.json").read_text())


def test_the_second_drone_lands_beside_the_first(tmp_path, capsys):
    code, s = _fly_same_point(tmp_path)
    assert code == 0
    assert s["status"] == "SUCCESS" and s["collisions"]["drones"] == 0
    sep = s["separation"]
    assert sep["landings_moved"] == 1 and sep["violations"] == 0
    assert sep["closest_m"] >= 0.5, sep  # the two standing drones included
    assert "1 landing moved beside a drone there" in capsys.readouterr().out


def test_a_landing_spot_beside_keeps_the_separation_inside_the_fence_and_clear():
    """Straight down when nothing is below; else the nearest ring's spot farthest from the
    others, inside the geofence and clear of obstacles; None when nothing is free."""

    class V:
        def __init__(self, name, p):
            self.name, self.position, self.motion, self.aside_goal = name, p, None, None
            self.is_flying = False

    air = Airspace(0.5)
    standing = V("a", (1.0, 0.0, 0.0))
    air.add(standing)
    air.add(V("b", (3.0, 3.0, 0.0)))
    assert air.land_spot("b", (3.0, 3.0, 1.0), 0.0) is None  # nothing below it
    spot = air.land_spot("b", (1.0, 0.0, 1.0), 0.0)
    assert spot is not None and math.dist(spot, standing.position) >= 0.75 - 1e-9
    assert air.landings_moved == 1
    air.inside["b"] = lambda p: p[0] <= 1.2  # a fence just past the standing drone
    air.clear = lambda p: p[1] >= -0.05  # an obstacle on the -y side
    spot = air.land_spot("b", (1.0, 0.0, 1.0), 0.0)
    assert spot is not None and spot[0] <= 1.2 and spot[1] > 0
    air.clear = lambda p: False  # nowhere free: straight down (the guard records it)
    assert air.land_spot("b", (1.0, 0.0, 1.0), 0.0) is None


def test_drones_that_touch_fail_the_fleet(tmp_path, monkeypatch, capsys):
    """Where no spot beside is free the drone lands where it is: on the other one. That is
    a collision: the fleet fails, says which drones, and exits 1."""
    monkeypatch.setattr(Airspace, "land_spot", lambda self, name, start, ground_z: None)
    code, s = _fly_same_point(tmp_path)
    assert code == 1
    assert s["status"] == "FAILURE" and s["collisions"]["drones"] == 1
    assert sorted(s["collisions"]["drone_pair"]) == ["cf1", "cf2"]
    assert "collision: cf1 and cf2 came within" in capsys.readouterr().out
