"""A goal outside the rig's geofence is refused before take-off (located where the mission
wrote it, or at ``--set``), not flown into: the supervisor would call it a breach, fly the
drone back inside and land, with the mission failed in the air."""

from __future__ import annotations

from bt_engine.cli import main

MISSION = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence>
      <TakeOff height="{climb}"/>
      <GoTo pose="1;0;1" relative="true"/>
      <GoTo pose="{goal}"/>
      <FollowPath path="1;0;1|2;0;1|3;0;1"/>
      <Land/>
    </Sequence>
  </BehaviorTree>
</root>
"""
BOX = "expected a point inside the rig's geofence (x -1.5 to 9.2, y -3 to 3, z -0.5 to 2.5 m)"


def _mission(tmp_path, climb: str = "1", goal: str = "2;0;1", path: str = "") -> str:
    text = MISSION.replace("{climb}", climb).replace("{goal}", goal)
    if path:
        text = text.replace("1;0;1|2;0;1|3;0;1", path)
    f = tmp_path / "m.xml"
    f.write_text(text)
    return str(f)


def test_goals_outside_the_geofence_are_refused_where_the_file_wrote_them(tmp_path, capsys):
    m = _mission(tmp_path, climb="4", goal="20;0;1", path="1;0;1|2;-5;1|3;0;1")
    out = tmp_path / "run"
    assert main([m, "--rig", "rigs/sim.yaml", "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"{m}:4:7: TakeOff: height 4 (the climb ends at z 4 m): {BOX}",
        f"{m}:6:7: GoTo: pose 20;0;1: {BOX}",
        f"{m}:7:7: FollowPath: path waypoint 2 (2;-5;1): {BOX}",
        "3 problems found; nothing was run.",
    ]
    assert not out.exists()  # nothing was built, nothing flew
    # btrun validate --rig says the same without building a drone
    assert main(["validate", m, "--rig", "rigs/sim.yaml"]) == 2
    assert f"{m}:4:7: TakeOff: height 4" in capsys.readouterr().err


def test_a_set_goal_outside_the_geofence_is_refused_at_the_set(tmp_path, capsys):
    out = tmp_path / "run"
    fixed = ["missions/pallet_scan_fixed.xml", "--out", str(out), "-q"]
    assert main([*fixed, "--set", "scan_start=8.9;-4;0.255"]) == 2  # read by three GoTos
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"--set scan_start: pose 8.9;-4;0.255: {BOX}",
        "1 problem found; nothing was run.",
    ]
    assert not out.exists()


def test_a_pallet_place_no_look_point_can_reach_is_refused_before_flight(tmp_path, capsys):
    """LocatePallet looks from ``look_distance`` in front of ``place``: a place whose look
    points all lie outside the geofence took off and failed there ("no look point ...
    could be flown to")."""
    out = tmp_path / "run"
    args = ["missions/pallet_scan.xml", "--out", str(out), "-q"]
    assert main([*args, "--set", "place=100;0;0.255"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == (
        "--set place: place 100;0;0.255: no look point 0.75 m in front of it lies inside "
        "the rig's geofence (x -1.5 to 9.2, y -3 to 3, z -0.5 to 2.5 m, 0.05 m clear of its "
        "walls)"
    )
    assert not out.exists()
    # the pallet itself may stand beyond the fence, as racks do: its look point is inside
    assert main(["validate", "missions/pallet_scan.xml", "--set", "place=9.8;0;0.255"]) == 0


def test_goals_inside_a_relative_offset_or_a_geofence_turned_off_pass(tmp_path, capsys):
    """An offset (``relative``) is not a point of the map; a rig without a geofence has
    nothing to check; a mission inside the box passes."""
    assert main(["validate", _mission(tmp_path), "--rig", "rigs/sim.yaml"]) == 0
    m = _mission(tmp_path, goal="20;0;1")
    off = ["--set", "safety.geofence.enabled=false"]
    assert main(["validate", m, "--rig", "rigs/sim.yaml", *off]) == 0
    capsys.readouterr()
    assert main(["validate", "missions/square.xml", "--rig", "rigs/sim.yaml"]) == 0
    site = ["validate", "missions/inventory.xml", "--rig", "rigs/site.yaml"]
    assert main([*site, "--set", "home=1;-10;9"]) == 2
    assert "--set home: pose 1;-10;9: expected a point inside" in capsys.readouterr().err


def test_a_rig_whose_geofence_is_inside_out_or_excludes_its_start_is_refused(tmp_path, capsys):
    """Each setting was in its own bounds, so ``min_m: [5, 5, 5]`` (above ``max_m`` on two
    axes) and a start outside the box loaded and flew: a breach at take-off."""
    rig = tmp_path / "rig.yaml"
    rig.write_text(
        "name: inside-out\nlink: sim\nsafety:\n  geofence:\n"
        "    min_m: [5, 5, 5]\n    max_m: [9.2, 3, 2.5]\n"
    )
    assert main(["rig", "check", str(rig)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == (
        f"{rig}:5:12: safety.geofence: min_m [5.0, 5.0, 5.0] must be below max_m "
        "[9.2, 3.0, 2.5] on every axis (not on y, z)"
    ), err
    rig.write_text("name: far\nlink: sim\nsim:\n  start_m: [20, 0, 0]\n")
    assert main(["rig", "check", str(rig)]) == 2
    assert capsys.readouterr().err.splitlines()[0] == (
        f"{rig}:4:12: sim.start_m [20.0, 0.0, 0.0]: the drone would start outside the "
        f"geofence (x -1.5 to 9.2, y -3 to 3, z -0.5 to 2.5 m): expected a start inside it"
    )
    # the start a --set moves outside is said at the --set; a geofence turned off passes
    sim = ["rig", "check", "rigs/sim.yaml"]
    assert main([*sim, "--set", "sim.start_m=[0,-4,0]"]) == 2
    assert capsys.readouterr().err.startswith("--set sim.start_m [0.0, -4.0, 0.0]: the drone")
    assert (
        main([*sim, "--set", "sim.start_m=[0,-4,0]", "--set", "safety.geofence.enabled=false"]) == 0
    )


def test_a_landing_pad_outside_the_geofence_is_refused_before_flight(capsys):
    args = ["validate", "missions/inventory.xml", "--rig", "rigs/site.yaml"]
    fence = ["--set", "safety.geofence.max_m=[7.9,9,2.5]", "--set", "landing_pads=pad-5;pad-1"]
    assert main([*args, *fence]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "--set landing_pads: pad 'pad-5' at x 1, y 10: expected a point inside the rig's "
        "geofence (x 0.1 to 7.9, y -11 to 9, z -0.5 to 2.5 m)",
        "1 problem found; nothing was run.",
    ]


def test_a_fleet_drone_starting_outside_the_geofence_is_refused_at_its_line(tmp_path, capsys):
    """A fleet's drones start on their own pads (the rig's own start does not count): one
    outside the geofence is said where the fleet file puts it, every drone in one go."""
    import os

    from helpers import REPO

    text = open(os.path.join(REPO, "fleets", "site_4.yaml")).read().replace("../", REPO + "/")
    fleet = tmp_path / "fleet.yaml"
    fleet.write_text(text.replace("{name: cf4, pad: pad-4,", "{name: cf4, start_m: [7.5, -12, 0],"))
    line = next(n for n, s in enumerate(fleet.read_text().splitlines(), 1) if "cf4" in s)
    assert main(["fleet", str(fleet), "--check"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith(f"{fleet}:{line}:") and err[0].endswith(
        "cf4: its start (7.5, -12, 0) is outside the rig's geofence (x 0.1 to 7.9, y -11 to "
        "10.8, z -0.5 to 2.5 m): expected a start inside it"
    ), err
    fence = ["--set", "safety.geofence.min_m=[0.1,-9,-0.5]"]
    assert main(["fleet", "fleets/site_4.yaml", "--check", *fence]) == 2
    err = capsys.readouterr().err.splitlines()
    assert [e.split(": ")[1] for e in err[:4]] == ["cf1", "cf2", "cf3", "cf4"], err
    assert err[-1] == "4 problems found; nothing was run."


def test_a_look_distance_that_puts_look_points_in_a_rack_or_outside_is_refused(capsys):
    """The inventory's rescans fly to each place's look point (LookUpPlace): a
    ``look_distance`` that puts them outside the geofence (or inside the rack across the
    aisle) failed every rescan in the air."""
    args = ["validate", "missions/inventory.xml", "--rig", "rigs/site.yaml"]
    assert main([*args, "--set", "look_distance=3"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == (
        "--set look_distance: look_distance 3: the points 3 m in front of 72 of the 144 "
        "places to answer would lie inside a rack or outside the rig's geofence, where no "
        "rescan can fly (first: B-01-1 at (0.05, 7.70): outside the geofence)"
    ), err
    # a geofence around aisle 2 alone: the sweep's lines and the look points of aisle 1
    # are outside it, which matters only when aisle 1 is to be answered
    aisle_2 = ["--set", "safety.geofence.min_m=[3.5,-11,-0.5]", "--set", "sim.start_m=[6,-10,0]"]
    assert main([*args, *aisle_2]) == 2
    err = capsys.readouterr().err.splitlines()
    assert "SweepPass 'pass': standoff 0.45: the points 0.45 m in front of 72 of the" in err[0]
    assert "LookUpPlace 'look_up': look_distance 0.75: the points" in err[1]
    from types import SimpleNamespace

    from drivers.rig.loader import load_rig
    from nodes.inventory import PLANNED_PLACES, reach_problems

    over = {"safety.geofence.min_m": "[3.5,-11,-0.5]", "sim.start_m": "[6,-10,0]"}
    rig = load_rig("rigs/site.yaml", over)
    world = rig.load_world(0)
    aisle_2_places = [n for n in world.places if n[0] in "CD"]
    for planned, problems in ((None, 1), (aisle_2_places, 0)):
        resources = {"rig": rig, PLANNED_PLACES: planned}
        node = SimpleNamespace(
            get_input=lambda name: 0.45,
            port_decl=lambda name: None,
            ctx=SimpleNamespace(resources=resources),
        )
        assert len(reach_problems(node, world, "standoff", "no pass can fly")) == problems
    from types import SimpleNamespace

    from drivers.rig.loader import load_rig
    from nodes.inventory import LookUpPlace, look_point
    from nodes.rack_geometry import footprints

    world = load_rig("rigs/site.yaml").load_world(0)
    # 2.5 m from rack A's faces is still in the 3 m aisle; 3.3 m is inside rack B
    p = look_point(world.places["A-01-1"], 3.3)
    assert [r.name for r in footprints(world) if r.distance(p[:2]) <= 0.0] == ["B"]
    node = SimpleNamespace(
        get_input=lambda name: 3.3, port_decl=lambda name: None, ctx=SimpleNamespace(resources={})
    )
    ((port, message),) = LookUpPlace._look_point_problems(node, world)
    assert port == "look_distance" and "inside rack B" in message


def test_a_pass_whose_run_up_leaves_the_geofence_is_refused_before_flight(capsys):
    """A pass starts ``lead`` before a rack's end block: with the fence 20 cm closer to
    rack A's end than the site's, the drone would fly the run-up of pass A/1 across it."""
    args = ["validate", "missions/inventory.xml", "--rig", "rigs/site.yaml"]
    tight = ["--set", "safety.geofence.min_m=[0.1,-8.6,-0.5]", "--set", "sim.start_m=[1,-8,0]"]
    assert main([*args, *tight]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].endswith(
        "SweepPass 'pass': pass A/1 would start or end at (0.40, -8.81), outside the rig's "
        "geofence (x 0.1 to 7.9, y -8.6 to 10.8, z -0.5 to 2.5 m, 0.05 m clear of its "
        "walls): its run-up (lead 0.5 m) and tail (0.3 m) past the rack's end blocks must "
        "lie inside it"
    ), err
    assert len(err) == 2  # one line, then the count
