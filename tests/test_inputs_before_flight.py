"""Inputs are checked before anything flies: a ``--set`` key (or a campaign's plain key) the
mission does not declare is refused with a "did you mean" (``bb.NAME`` passes on purpose),
and ``btrun validate --rig`` runs the nodes' pre-flight checks against the rig's world."""

from __future__ import annotations

import glob
import json
import os
import re

import pytest
from helpers import REPO

from bt_engine.cli import main
from bt_engine.inputs import declared_inputs
from bt_engine.loading import load_spec
from bt_engine.run_cmd import mission_time_limit, parse_sets

SQUARE = os.path.join(REPO, "missions", "square.xml")
AISLE_RIG = os.path.join(REPO, "rigs", "aisle.yaml")


def _err_lines(capsys) -> list[str]:
    return capsys.readouterr().err.strip().splitlines()


# -- 1. --set: the mission's inputs ---------------------------------------------------------


def test_a_misspelt_input_is_refused_before_anything_flies(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    assert main(["missions/square.xml", "--set", "hieght=2", "--out", str(out), "-q"]) == 2
    err = _err_lines(capsys)
    assert err[0].startswith("--set hieght: missions/square.xml has no input 'hieght'")
    assert "did you mean height?" in err[0] and "bb.hieght" in err[0]
    assert err[-1] == "1 problem found; nothing was run."
    assert not out.exists()  # no run folder: nothing was built


@pytest.mark.parametrize(
    ("value", "why"), [("abc", "expected a number, got 'abc'"), ("nan", "expected a finite number")]
)
def test_a_set_value_a_port_cannot_take_is_refused_before_anything_flies(
    tmp_path, capsys, value, why
) -> None:
    """``--set sweep_speed=abc`` (or ``nan``) used to pass the pre-flight checks and take off:
    the first leaf to read it after take-off aborted the mission. The ports that read a
    ``--set`` entry now convert it before flight, SubTree ports through their remapping."""
    out = tmp_path / "run"
    args = ["missions/inventory.xml", "--rig", AISLE_RIG, "--set", f"sweep_speed={value}"]
    assert main([*args, "--out", str(out), "-q"]) == 2
    err = _err_lines(capsys)
    assert err[0].startswith(f"--set sweep_speed={value}: {why}"), err
    assert "read as 'speed' by" in err[0] and "missions/inventory.xml:" in err[0]
    assert err[-1] == "1 problem found; nothing was run."
    assert not out.exists()
    # the same through a fleet's --set (every drone's mission)
    fleet = ["fleet", "fleets/site_4.yaml", "--set", f"sweep_speed={value}", "--out", str(out)]
    assert main(fleet) == 2
    assert f"--set sweep_speed={value}: {why}" in capsys.readouterr().err
    assert not (out / "drones").exists()  # nothing flew (the fleet's folder has its fleet.json)


def test_a_set_value_read_inside_a_subtree_is_converted_before_flight(tmp_path, capsys) -> None:
    """A ``--set`` entry reached only through a SubTree's remapping is checked too."""
    mission = tmp_path / "m.xml"
    mission.write_text(
        """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <SubTree ID="Wait" time="{pause}"/>
  </BehaviorTree>
  <BehaviorTree ID="Wait">
    <Sleep msec="{time}"/>
  </BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="Main"><input_port name="pause" default="10"/></SubTree>
  </TreeNodesModel>
</root>
"""
    )
    out = tmp_path / "run"
    assert main([str(mission), "--set", "pause=soon", "--out", str(out), "-q"]) == 2
    err = _err_lines(capsys)
    assert err[0].startswith("--set pause=soon: "), err
    assert "read as 'msec' by Sleep" in err[0]
    assert not out.exists()


def test_bb_prefix_sets_an_undeclared_entry_on_purpose(tmp_path) -> None:
    out = tmp_path / "run"
    args = [SQUARE, "--set", "bb.note=2", "--set", "height=0.8", "--out", str(out), "-q"]
    assert main([*args, "--no-report", "--no-mcap"]) == 0
    with open(out / "summary.json", encoding="utf-8") as f:
        bb = json.load(f)["blackboard"]
    assert bb["note"] == 2 and bb["height"] == 0.8


def test_parse_sets_splits_inputs_unchecked_entries_and_rig_settings() -> None:
    items = ["height=1.5", "bb.a.b=x", "world.scan_pallet=2B", "rig.wind.gust_std_mps=0.1"]
    bb, rig, problems = parse_sets(items, {"height"}, "m.xml")
    assert problems == []
    assert bb == {"height": 1.5, "a.b": "x"}  # bb. comes before the dotted-key rule
    assert rig == {"world.scan_pallet": "2B", "wind.gust_std_mps": "0.1"}
    _, _, problems = parse_sets(["bb.=1", "speeed=2"], {"speed"}, "m.xml")
    assert [str(p) for p in problems] == [
        "--set:1:1: no entry name after bb. in 'bb.=1'",
        "--set speeed: m.xml has no input 'speeed'; did you mean speed? (its inputs: speed; "
        "bb.speeed puts it on the blackboard unchecked)",
    ]
    assert parse_sets(["anything=1"])[2] == []  # no declared inputs given: unchecked


def test_declared_inputs_are_main_tree_ports_references_and_script_reads(tmp_path) -> None:
    path = tmp_path / "m.xml"
    path.write_text(
        """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence>
      <Script code="total := limit + 1"/>
      <Sleep msec="{pause}"/>
      <SubTree ID="Inner" _autoremap="true"/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Inner"><Sleep msec="{@inner_pause}"/></BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="Main"><input_port name="no_default"/></SubTree>
  </TreeNodesModel>
</root>
"""
    )
    assert declared_inputs(load_spec(str(path))) == {
        "limit",
        "pause",
        "inner_pause",
        "no_default",
        "max_time",  # btrun's own, in every mission
    }


_WAIT_TWICE = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence>
      <SubTree ID="Wait" ms="10"/>
      <SubTree ID="Wait" ms="{CALL}"/>
      <SubTree ID="Nap" _autoremap="true"/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Wait"><Sleep msec="{ms}"/></BehaviorTree>
  <BehaviorTree ID="Nap"><SubTree ID="Wait" ms="{nap}"/></BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="Wait"><input_port name="ms" type="int"/></SubTree>
  </TreeNodesModel>
</root>
"""


def test_an_entry_only_subtrees_read_with_their_own_value_is_no_input(tmp_path, capsys) -> None:
    """A SubTree's blackboard is its own: when every call gives ``ms`` a literal, ``--set
    ms=500`` would change nothing; it is refused, naming where ``ms`` is read. Passed in
    (``ms="{ms}"``) it is an input; ``nap`` reaches the root through ``_autoremap``."""
    path = tmp_path / "m.xml"
    path.write_text(_WAIT_TWICE.replace("{CALL}", "20"))
    assert declared_inputs(load_spec(str(path))) == {"nap", "max_time"}
    out = tmp_path / "run"
    assert main([str(path), "--set", "ms=500", "--out", str(out), "-q"]) == 2
    err = _err_lines(capsys)
    assert err[0].startswith(f"--set ms: {path} reads 'ms' only inside a SubTree ({path}:9:34)")
    assert "--set ms would change nothing" in err[0] and not out.exists()
    path.write_text(_WAIT_TWICE.replace("{CALL}", "{ms}"))
    assert declared_inputs(load_spec(str(path))) == {"ms", "nap", "max_time"}


_SET_PLAIN = re.compile(r"--set[ =]+[\"']?([A-Za-z_]\w*)=")
#: the docs' example of a refused key
_TYPOS = {"hieght"}


def test_every_plain_set_key_in_readme_and_docs_is_an_input_of_its_mission() -> None:
    """A documented ``--set name=...`` next to a mission file names one of its inputs."""
    missions = {
        os.path.basename(m): declared_inputs(load_spec(m))
        for m in glob.glob(os.path.join(REPO, "missions", "*.*"))
    }
    bad, checked = [], 0
    for path in ["README.md", *sorted(glob.glob(os.path.join(REPO, "docs", "*.md")))]:
        with open(os.path.join(REPO, path), encoding="utf-8") as f:
            for n, line in enumerate(f, 1):
                names = [m for m in missions if f"missions/{m}" in line]
                for key in _SET_PLAIN.findall(line):
                    for m in names:
                        checked += 1
                        if key not in missions[m] and key not in _TYPOS:
                            bad.append(f"{os.path.basename(path)}:{n}: {m} has no input {key}")
    assert not bad, "\n".join(bad)
    assert checked >= 8


# -- 1. campaigns -----------------------------------------------------------------------------


def _campaign(tmp_path, body: str) -> str:
    path = tmp_path / "c.yaml"
    path.write_text(f"name: c\nmissions: [{SQUARE}]\nseeds: [0]\n{body}")
    return str(path)


def test_a_campaign_grid_key_the_mission_does_not_declare_fails_the_dry_run(
    tmp_path, capsys
) -> None:
    path = _campaign(tmp_path, "grid: {hieght: [1.0, 1.5]}\n")
    assert main(["campaign", path, "--dry-run"]) == 2
    err = _err_lines(capsys)
    assert err[0].startswith(f"{path}:4:8: hieght: {SQUARE} has no input 'hieght'")
    assert "did you mean height?" in err[0]


def test_a_campaign_value_a_port_cannot_take_fails_the_dry_run(tmp_path, capsys) -> None:
    """Every value of a grid (and the bounds of a draw) goes through the ports that read it:
    ``height: [1.0, high]`` fails the dry run where the file wrote it, not run by run."""
    path = _campaign(tmp_path, "grid: {height: [1.0, high]}\n")
    assert main(["campaign", path, "--dry-run"]) == 2
    err = _err_lines(capsys)
    assert err[0].startswith(f"{path}:4:8: height=high: expected a number, got 'high'"), err
    assert "read as 'height' by TakeOff" in err[0]
    path = _campaign(tmp_path, "random: {height: {choice: [0.5, .nan]}}\n")
    assert main(["campaign", path, "--dry-run"]) == 2
    assert "height=nan: expected a finite number" in capsys.readouterr().err
    path = _campaign(tmp_path, "grid: {height: [1.0, 1.5]}\n")
    assert main(["campaign", path, "--dry-run"]) == 0, capsys.readouterr().err


def test_a_campaign_bb_key_passes_unchecked_and_is_no_rig_setting(tmp_path, capsys) -> None:
    path = _campaign(tmp_path, "set: {bb.note: 3, wind.gust_std_mps: 0.05}\n")
    assert main(["campaign", path, "--dry-run"]) == 0, capsys.readouterr().err


@pytest.mark.parametrize(
    "campaign", sorted(glob.glob(os.path.join(REPO, "campaigns", "*.yaml"))), ids=os.path.basename
)
def test_every_shipped_campaign_still_passes_its_dry_run(campaign, capsys) -> None:
    assert main(["campaign", campaign, "--dry-run"]) == 0, capsys.readouterr().err


# -- 2. btrun validate --rig ------------------------------------------------------------------

PLAN = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <InventoryPlan places="{places}" queue="{queue}"/>
  </BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="Main"><input_port name="places" default="all"/></SubTree>
  </TreeNodesModel>
</root>
"""


def test_validate_with_a_rig_runs_the_preflight_checks(tmp_path, capsys) -> None:
    path = tmp_path / "plan.xml"
    path.write_text(PLAN)
    assert main(["validate", str(path)]) == 0  # without --rig: as before
    capsys.readouterr()
    assert main(["validate", "--rig", AISLE_RIG, "--set", "places=A-1-1", str(path)]) == 2
    err = _err_lines(capsys)
    assert err[0] == "--set places: unknown place 'A-1-1' (did you mean 'A-01-1'?)"
    assert main(["validate", "--rig", AISLE_RIG, "--set", "places=A-01-1", str(path)]) == 0
    assert capsys.readouterr().out.strip() == f"{path}: ok"


def test_validate_checks_set_keys_and_rig_settings(tmp_path, capsys) -> None:
    argv = ["validate", "--set", "hieght=2", "--set", "world.nope=1", SQUARE]
    assert main(argv) == 2
    err = _err_lines(capsys)
    assert any("has no input 'hieght'; did you mean height?" in line for line in err)
    assert any(line.startswith("--set world.nope=1: unknown key") for line in err)


# -- 2. LookUpPlace's pre-flight check ------------------------------------------------------

LOOKUP = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence>
      <LookUpPlace place="A-1-1" row="{row}" facing_deg="{facing}"/>
      <LookUpPlace place="{next_place}" row="{row}" facing_deg="{facing}"/>
    </Sequence>
  </BehaviorTree>
</root>
"""


def test_validate_with_a_rig_refuses_a_literal_place_the_world_does_not_have(
    tmp_path, capsys
) -> None:
    path = tmp_path / "lookup.xml"
    path.write_text(LOOKUP)
    assert main(["validate", str(path)]) == 0  # no rig, no world: as before
    capsys.readouterr()
    assert main(["validate", "--rig", AISLE_RIG, str(path)]) == 2
    err = _err_lines(capsys)
    # the place read from the blackboard can only be checked in flight; validate warns that
    # nothing in this mission writes it
    assert "input port 'place' reads blackboard entry {next_place}" in err[0]
    assert err[1] == (f"{path}:4:7: LookUpPlace: unknown place 'A-1-1' (did you mean 'A-01-1'?)")
    assert err[-1] == "1 problem found; nothing was run."
    path.write_text(LOOKUP.replace("A-1-1", "A-01-1"))
    assert main(["validate", "--rig", AISLE_RIG, str(path)]) == 0


# -- 1. fleet files -------------------------------------------------------------------------


def test_a_fleet_set_key_the_mission_does_not_declare_is_refused_where_written(
    tmp_path,
) -> None:
    from bt_engine.spec import MissionError
    from nodes.fleet.spec import load_fleet

    path = tmp_path / "f.yaml"
    path.write_text(
        f"name: f\nmission: {REPO}/missions/inventory.xml\nrig: {AISLE_RIG}\n"
        "set: {bb.note: 1, wind.gust_std_mps: 0.05}\n"
        "drones:\n"
        "  - {name: cf1, pad: pad-1, set: {scan_sped: 0.1}}\n"
        "  - {name: cf2, pad: pad-2, set: {scan_speed: 0.1}}\n"
    )
    with pytest.raises(MissionError) as exc:
        load_fleet(str(path))
    (problem,) = exc.value.problems
    assert str(problem).startswith(f"{path}:6:46: scan_sped: ")
    assert "has no input 'scan_sped'; did you mean scan_speed?" in problem.message
    path.write_text(path.read_text().replace("scan_sped", "bb.scan_sped"))
    assert [d.name for d in load_fleet(str(path)).drones] == ["cf1", "cf2"]


# -- 3. list items of the world by index ----------------------------------------------------


def _row(world, i: int):
    return next(p for p in world.pallets if p.slot_name == f"row[{i}]")


@pytest.mark.parametrize("key", ["row_slots.2.y_m", "row_slots[2].y_m", "row_slots[ 2 ].y_m"])
def test_a_row_slot_is_moved_by_its_index(key) -> None:
    from drivers.sim.world import load_world

    world = load_world(os.path.join(REPO, "worlds", "warehouse.yaml"), {key: "-2.0"})
    moved = _row(world, 2)
    assert moved.identity == "4A" and moved.face_center_m[1] == pytest.approx(-2.0)
    assert _row(world, 3).face_center_m[1] == pytest.approx(-3.15)  # the others stay


def test_a_bad_list_index_is_refused_with_the_list_length(capsys) -> None:
    argv = ["validate", "--set", "world.row_slots[4].x_m=9", "--set", "world.row_slots.x.y_m=1"]
    assert main([*argv, SQUARE]) == 2
    err = _err_lines(capsys)
    assert (
        "--set world.row_slots[4].x_m=9: index 4 is out of range: world.row_slots has 4 items "
        "(world.row_slots.0 .. world.row_slots.3, or world.row_slots[0])"
    ) in err
    assert any(
        line.startswith("--set world.row_slots.x.y_m=1: 'x' is not an index: world.row_slots")
        for line in err
    )


def test_a_bad_input_is_refused_before_any_model_or_gallery_is_loaded(
    tmp_path, monkeypatch, capsys
) -> None:
    """The checks that load the models and build the demo gallery (PerceptionReady's) run
    last, once every cheaper check has passed: a bad ``--set`` value or an unknown place is
    refused at once, with no gallery built (it took a minute on the site: a fleet's
    refusal of ``sweep_speed=abc`` came after building its demo gallery)."""
    monkeypatch.setenv("BTRUN_CACHE_DIR", str(tmp_path / "cache"))
    for bad in (["--set", "sweep_speed=abc"], ["--set", "places=A-99-1"]):
        args = ["validate", "--rig", AISLE_RIG, *bad, "missions/inventory.xml"]
        assert main(args) == 2
        assert "1 problem found; nothing was run." in capsys.readouterr().err
    assert not (tmp_path / "cache" / "galleries").exists()  # nothing was built


# -- command-line numbers and the run folder ---------------------------------------------------


@pytest.mark.parametrize(
    "args, said",
    [
        (["--rate", "0"], "argument --rate: expected a tick rate in Hz > 0 and at most 1000"),
        (["--rate", "inf"], "argument --rate: expected a tick rate in Hz > 0"),  # ticked for ever
        (["--rate", "nan"], "argument --rate: expected a tick rate in Hz > 0"),  # a traceback
        (["--max-time", "nan"], "argument --max-time: expected a time in s > 0"),  # no limit
        (["--max-time", "-1"], "argument --max-time: expected a time in s > 0"),
        (["--realtime", "0"], "argument --realtime: expected a factor > 0 and at most 100"),
        (["--tick-budget", "0"], "argument --tick-budget: expected a time in s > 0"),  # traceback
    ],
)
def test_a_bad_number_on_the_command_line_is_one_line_and_exit_2(
    args, said, tmp_path, capsys
) -> None:
    out = tmp_path / "run"
    with pytest.raises(SystemExit) as exc:
        main(["missions/square.xml", *args, "--out", str(out), "-q"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err, err
    assert not out.exists()
    with pytest.raises(SystemExit) as exc:  # a fleet's options alike
        main(["fleet", "fleets/aisle_2.yaml", "--rate", "0", "--out", str(out)])
    assert exc.value.code == 2 and "argument --rate" in capsys.readouterr().err


def test_a_run_folder_that_cannot_be_made_is_refused_before_anything_flies(
    tmp_path, capsys
) -> None:
    """``--out`` naming a file (or a folder below one) ended in a traceback after the drone
    and its guard process were started; the guard then failed to write its record too."""
    a_file = tmp_path / "notes.txt"
    a_file.write_text("x\n")
    for out, said in (
        (a_file, "a file is there; the run folder must be a folder"),
        (a_file / "run", f"{a_file} is a file, so no folder can be made in it"),
    ):
        assert main(["missions/pallet_scan.xml", "--out", str(out), "-q"]) == 2
        err = _err_lines(capsys)
        assert err[0] == f"--out {out}: {said}", err
        assert err[-1] == "1 problem found; nothing was run."
        assert main(["fleet", "fleets/aisle_2.yaml", "--out", str(out)]) == 2
        err = _err_lines(capsys)
        assert err[0] == f"--out {out}: {said}", err
    assert a_file.read_text() == "x\n"


LIMITED = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Delay delay_msec="3000"><AlwaysSuccess/></Delay>
  </BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="Main">
      <input_port name="max_time" type="double" default="1">mission time limit, s</input_port>
    </SubTree>
  </TreeNodesModel>
</root>
"""


def test_a_mission_sets_its_own_time_limit(tmp_path, capsys) -> None:
    """A sweep of the site with battery changes and rescans can take longer than btrun's
    900 s default: a mission says how long it may take (its ``max_time`` input); ``--set
    max_time=`` and ``--max-time`` override it."""
    mission = tmp_path / "limited.xml"
    mission.write_text(LIMITED)

    def status(*extra: str) -> str:
        out = tmp_path / f"run{len(list(tmp_path.iterdir()))}"
        main([str(mission), "--out", str(out), "-q", "--no-report", *extra])
        capsys.readouterr()
        return json.load(open(out / "summary.json"))["status"]

    assert status() == "ABORTED"  # its own 1 s, not 900 s
    assert status("--set", "max_time=10") == "SUCCESS"
    assert status("--max-time", "10") == "SUCCESS"
    assert status("--set", "max_time=10", "--max-time", "1") == "ABORTED"
    assert main([str(mission), "--set", "max_time=soon", "--out", str(tmp_path / "x")]) == 2
    err = _err_lines(capsys)
    assert err[0] == (
        "--set max_time: the mission's time limit must be a time in s > 0, got 'soon'"
    ), err
    assert not (tmp_path / "x").exists()
    # btrun validate and btrun fleet --check say the same (validate said "ok")
    assert main(["validate", "--set", "max_time=0", str(mission)]) == 2
    assert _err_lines(capsys)[0].endswith("must be a time in s > 0, got 0")
    fleet = os.path.join(REPO, "fleets", "aisle_2.yaml")
    assert main(["fleet", fleet, "--check", "--set", "max_time=-3"]) == 2
    assert _err_lines(capsys)[0].endswith("must be a time in s > 0, got -3")
    for name, limit in (("inventory", 3600.0), ("inventory_per_place", 7200.0)):
        for suffix in (".xml", ".yaml"):  # both formats say the same
            spec = load_spec(os.path.join(REPO, "missions", name + suffix))
            assert mission_time_limit(spec, {}) == (limit, None)
    assert mission_time_limit(load_spec(SQUARE), {})[0] == 900.0


def test_a_battery_reserve_no_flight_can_keep_is_refused_before_flight(tmp_path, capsys) -> None:
    """``battery_reserve=150`` (a percentage) flew: every EnoughEnergy failed, the drone
    changed its battery again and again for 270 s and the run failed with nothing answered.
    Now one line, said once although five leaves read it."""
    out = tmp_path / "run"
    args = ["missions/inventory.xml", "--rig", AISLE_RIG, "--out", str(out), "-q"]
    assert main([*args, "--set", "battery_reserve=150"]) == 2
    assert _err_lines(capsys) == [
        "--set battery_reserve: reserve 150.0: expected 0 to 90 (charge to keep at touchdown, %)",
        "1 problem found; nothing was run.",
    ]
    assert not out.exists()
    assert main([*args, "--set", "battery_mode=nuclear"]) == 2  # failed at the first change
    assert _err_lines(capsys)[0] == "--set battery_mode: mode 'nuclear': expected swap or charge"


def test_declared_port_ranges_are_checked_before_flight(tmp_path, capsys) -> None:
    """A port may declare the numbers its node can work with (``input_port(..., low=,
    high=)``): ``height=-1`` or ``land_speed=0`` flew and failed in the air (or was refused
    by the Vehicle API after take-off); now each is one line before anything flies, at the
    ``--set`` through any SubTree's remapping, else where the mission file wrote it."""
    out = tmp_path / "run"
    assert main(["missions/square.xml", "--set", "height=-1", "--out", str(out), "-q"]) == 2
    assert _err_lines(capsys)[0] == (
        "--set height: height -1.0: expected 0.05 to 20 (height above the take-off point, m)"
    )
    assert not out.exists()
    inventory = ["validate", "missions/inventory.xml", "--rig", AISLE_RIG]
    assert main([*inventory, "--set", "scan_speed=0"]) == 2  # read inside lib/align_and_scan
    assert _err_lines(capsys)[0] == (
        "--set scan_speed: speed 0.0: expected 0.005 to 2 (scan speed along the face, m/s)"
    )
    square = open(SQUARE).read()
    written = tmp_path / "square.xml"
    written.write_text(
        square.replace('<Land name="land" speed="0.5"', '<Land name="land" speed="0"')
    )
    assert 'speed="0"' in written.read_text()
    line = square[: square.index('<Land name="land"')].count("\n") + 1
    for rig in (["--rig", "rigs/sim.yaml"], []):  # a literal: no rig needed to say it
        assert main(["validate", str(written), *rig]) == 2
        err = _err_lines(capsys)[0]
        assert err.startswith(f"{written}:{line}:") and (
            "port 'speed' of Land: speed 0.0: expected 0.01 to 3" in err
        ), err


def test_a_port_range_refuses_nan_and_inf_and_leaves_other_values_alone() -> None:
    from bt_engine.ports import FLOAT, input_port

    port = input_port("speed", FLOAT, 0.5, "m/s", low=0.01, high=3.0)
    assert port.out_of_range(0.5) is None and port.out_of_range(3.0) is None
    for bad in (0.0, 3.5, float("nan"), float("inf"), -float("inf")):
        assert port.out_of_range(bad) is not None, bad
    assert port.out_of_range("fast") is None and port.out_of_range(True) is None
    assert input_port("n", FLOAT, 1.0, low=0).out_of_range(-1) == "n -1: expected at least 0"
    assert input_port("x", FLOAT, 1.0).out_of_range(1e9) is None  # no range declared


def test_values_the_mission_file_gives_are_checked_before_flight(tmp_path, capsys) -> None:
    """A <TreeNodesModel> default (the main tree's, a SubTree's) that the port reading it
    cannot take passed `btrun validate` and took off, failing at the first tick that read
    it. Said at the node that reads it, with or without a rig."""
    mission = tmp_path / "m.xml"
    mission.write_text(
        """<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <Sequence>
      <TakeOff height="1"/>
      <SubTree ID="Hop"/>
      <Sleep msec="{nap}"/>
      <Land/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Hop">
    <GoTo pose="1;0;1" max_speed="{spd}"/>
  </BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="M">
      <input_port name="nap" type="int" default="soon"/>
    </SubTree>
    <SubTree ID="Hop">
      <input_port name="spd" type="double" default="fast"/>
    </SubTree>
  </TreeNodesModel>
</root>
"""
    )
    text = mission.read_text()
    goto = text[: text.index("<GoTo")].count("\n") + 1
    sleep = text[: text.index("<Sleep")].count("\n") + 1
    for args in (["validate", str(mission)], [str(mission), "--out", str(tmp_path / "r"), "-q"]):
        assert main(args) == 2
        err = _err_lines(capsys)
        assert any(
            line.startswith(f"{mission}:{goto}:") and "{spd}" in line and "got 'fast'" in line
            for line in err
        ), err
        assert any(line.startswith(f"{mission}:{sleep}:") and "'soon'" in line for line in err), err
    assert not (tmp_path / "r").exists()
    assert main([str(mission), "--set", "nap=100", "--out", str(tmp_path / "r2"), "-q"]) == 2
    assert not any("'soon'" in line for line in _err_lines(capsys))  # --set replaced it


def test_an_exponent_yaml_reads_as_text_is_said_so(tmp_path, capsys) -> None:
    """`capacity_mah: 1e308` is text to YAML 1.1 (no dot, no sign): "expected a number, got
    '1e308'" left the user puzzled."""
    rig = tmp_path / "r.yaml"
    rig.write_text("link: sim\nbattery:\n  capacity_mah: 1e3\n")
    assert main(["validate", str(rig)]) == 2
    assert "write 1.0e+3" in capsys.readouterr().err


def test_a_physics_rate_off_the_firmware_loop_and_a_negative_floor_are_refused(capsys) -> None:
    """sim.physics_rate_hz 333 (the docs say a multiple of 100) and a floor of negative size
    (it moved the answer's distance from 0.208 to 0.369) flew without a word."""
    assert main(["missions/square.xml", "--set", "sim.physics_rate_hz=333", "-q"]) == 2
    assert "physics_rate_hz 333: expected a multiple of 100" in capsys.readouterr().err
    assert main(["validate", "worlds/aisle.yaml", "--set", "world.floor.size_m=[-16,12]"]) == 2
    assert "floor size [-16.0, 12.0]: expected two lengths > 0" in capsys.readouterr().err


def test_a_missing_world_file_is_said_at_the_rig_line(tmp_path, capsys) -> None:
    """It was located at the missing file itself (``/nonexistent/world.yaml:1:1``)."""
    rig = tmp_path / "r.yaml"
    rig.write_text("link: sim\nworld:\n  path: /nonexistent/world.yaml\n")
    assert main(["validate", str(rig)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{rig}:3:9: world.path '/nonexistent/world.yaml': no such world file")


_NEEDS_TARGET = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence><TakeOff height="0.5"/><GoTo pose="{target}"/><Land/></Sequence>
  </BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="Main"><input_port name="target" type="string"/></SubTree>
  </TreeNodesModel>
</root>
"""


def test_a_mission_input_without_a_default_must_be_given(tmp_path, capsys) -> None:
    """A declared input nobody gives took off and aborted at the GoTo (``{target}, which is
    not set``); it is refused on the ground. Given, or written by the mission, it flies."""
    path = tmp_path / "m.xml"
    path.write_text(_NEEDS_TARGET)
    out = tmp_path / "run"
    assert main([str(path), "--out", str(out), "-q"]) == 2
    err = _err_lines(capsys)
    assert err[0] == (
        f"{path}:6:5: mission input 'target' has no default and nothing in the mission writes "
        "it: give it with --set target=VALUE (or a default in <TreeNodesModel>)"
    )
    assert not out.exists()
    args = ["--set", "target=1;0;0.5", "--out", str(out), "-q", "--no-report", "--no-mcap"]
    assert main([str(path), *args]) == 0
    path.write_text(
        _NEEDS_TARGET.replace("<Sequence>", "<Sequence><Script code=\"target := '1;0;0.5'\"/>")
    )
    assert main([str(path), "--out", str(tmp_path / "run2"), "-q", "--no-report", "--no-mcap"]) == 0


_LAPS = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence><Script code="done := laps + 1"/></Sequence>
  </BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="Main"><input_port name="laps" type="int" default="DEFAULT"/></SubTree>
  </TreeNodesModel>
</root>
"""


def test_a_declared_input_type_holds_for_its_default_and_set(tmp_path, capsys) -> None:
    """``type="int"`` was never used: ``default="five"`` validated, ``--set laps=three``
    took off (a script read it and failed in flight), ``--set laps=5.0`` was 5.0."""
    path = tmp_path / "m.xml"
    path.write_text(_LAPS.replace("DEFAULT", "five"))
    assert main(["validate", str(path)]) == 2
    assert (
        f"{path}:6:5: <TreeNodesModel> port 'laps' of 'Main': default 'five' is no int "
        "(type=\"int\"): expected a whole number, got 'five'"
    ) in capsys.readouterr().err
    path.write_text(_LAPS.replace("DEFAULT", "2"))
    out = tmp_path / "run"
    assert main([str(path), "--set", "laps=three", "--out", str(out), "-q"]) == 2
    assert _err_lines(capsys)[0] == (
        "--set laps=three: expected a whole number, got 'three' (the input is declared "
        f'type="int" at {path}:6:5)'
    )
    assert not out.exists()
    args = ["--set", "laps=5.0", "--out", str(out), "-q", "--no-report", "--no-mcap"]
    assert main([str(path), *args]) == 0
    with open(out / "summary.json", encoding="utf-8") as f:
        assert json.load(f)["blackboard"]["done"] == 6  # an int, not 6.0
