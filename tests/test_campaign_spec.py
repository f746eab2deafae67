"""Campaign files: located problems before anything flies, rows, draws, metric paths and
``--dry-run`` (nothing here flies)."""

from __future__ import annotations

import os
import textwrap

import pytest
from helpers import REPO

from bt_engine.campaign.check import check_campaign
from bt_engine.campaign.metrics import metric_from_data, parse_path
from bt_engine.campaign.rows import expand
from bt_engine.campaign.spec import load_campaign
from bt_engine.cli import main
from bt_engine.spec import MissionError

SQUARE = os.path.join(REPO, "missions", "square.xml")


def write(tmp_path, text: str, name: str = "c.yaml") -> str:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return str(path)


def problems_of(path: str) -> list[str]:
    with pytest.raises(MissionError) as exc:
        c = load_campaign(path)
        check_campaign(c, expand(c))
    return [str(p) for p in exc.value.problems]


def test_file_problems_are_located_with_the_value_and_what_was_expected(tmp_path) -> None:
    path = write(
        tmp_path,
        f"""\
        missions: [{SQUARE}, nowhere.xml]
        seeds: {{start: 0, count: 0}}
        grid:
          wind.gust_std_mps: 0.1
        random:
          faults.gust.at_s: {{uniform: [5, 1]}}
        timout_s: 10
        metrics:
          right: {{equals: [blackboard.pallet_id]}}
          first: perception.blocks[x]
        """,
    )
    got = problems_of(path)
    assert f"{path}:1:{14 + len(SQUARE)}: missions: file 'nowhere.xml' not found" in got[0]
    assert any(p.startswith(f"{path}:2:26: seeds.count: expected at least 1, got 0") for p in got)
    assert any(
        p.startswith(f"{path}:4:22: grid.wind.gust_std_mps: expected a non-empty list") for p in got
    )
    assert any(
        p.startswith(f"{path}:6:21: random.faults.gust.at_s.uniform: expected [low, high]")
        and "got [5, 1]" in p
        for p in got
    )
    assert any(
        p.startswith(f"{path}:7:1: unknown key 'timout_s' (did you mean 'timeout_s'?)") for p in got
    )
    assert any(
        p.startswith(f"{path}:9:10: metrics.right: equals: expected a list of two") for p in got
    )
    assert any(p.startswith(f"{path}:10:10: metrics.first: selector [x]") for p in got)


def test_bad_settings_are_caught_through_the_plugin_where_the_file_sets_them(tmp_path) -> None:
    path = write(
        tmp_path,
        f"""\
        missions: [{SQUARE}]
        set:
          wind.gust_stdev_mps: 0.1
        grid:
          control.rate_hz: [100, fast]
        faults:
          - name: sag
            set:
              faults.battery_sag.at_s: {{uniform: [-5, 10]}}
        """,
    )
    got = problems_of(path)
    assert any(
        p.startswith(f"{path}:3:3: wind.gust_stdev_mps=0.1: unknown key 'wind.gust_stdev_mps'")
        and "did you mean 'wind.gust_std_mps'" in p
        for p in got
    ), got
    assert any(
        p.startswith(f"{path}:5:3: control.rate_hz=fast: control.rate_hz: expected a number")
        for p in got
    ), got
    assert any(
        p.startswith(f"{path}:9:7: faults.battery_sag.at_s=-5.0:") and "minimum" in p for p in got
    ), got


def test_a_key_set_twice_and_a_clashing_metric_are_refused(tmp_path) -> None:
    path = write(
        tmp_path,
        f"""\
        missions: [{SQUARE}]
        set: {{wind.gust_std_mps: 0.1}}
        grid: {{rig.wind.gust_std_mps: [0.2, 0.3]}}
        metrics: {{status: status}}
        """,
    )
    got = problems_of(path)
    assert any(
        p.startswith(f"{path}:3:8: grid: 'wind.gust_std_mps' is already set in set (line 2)")
        for p in got
    ), got
    assert any(p.startswith(f"{path}:4:11: metrics: 'status' is already a column") for p in got)


def test_rows_cross_everything_and_draws_depend_on_the_row_not_its_position(tmp_path) -> None:
    text = f"""\
        missions: [{SQUARE}]
        seeds: {{start: 10, count: 3}}
        grid: {{speed: [0.5, 1.0]}}
        cycle: {{height: [1.0, 1.5]}}
        random: {{wind.gust_std_mps: {{uniform: [0.0, 0.2], round: 3}}}}
        faults:
          - {{name: none}}
          - {{name: gust, set: {{faults.gust.at_s: {{randint: [3, 9]}}}}, timeout_s: 30}}
        """
    c = load_campaign(write(tmp_path, text))
    rows = expand(c)
    assert len(rows) == 2 * 2 * 3
    assert c.parameters() == ["speed", "height", "wind.gust_std_mps", "faults.gust.at_s"]
    assert [r.seed for r in rows[:3]] == [10, 11, 12]
    assert [r.params["height"] for r in rows[:3]] == [1.0, 1.5, 1.0]
    assert [r.timeout_s for r in (rows[0], rows[-1])] == [600.0, 30.0]
    assert all(0.0 <= r.params["wind.gust_std_mps"] <= 0.2 for r in rows)
    assert "faults.gust.at_s" not in rows[0].params
    assert rows == expand(load_campaign(write(tmp_path, text)))  # a pure function
    more = load_campaign(write(tmp_path, text.replace("count: 3", "count: 4"), "more.yaml"))
    by_identity = {(r.fault, r.params["speed"], r.seed): r for r in expand(more)}
    for r in rows:  # the same draws and keys for the rows both campaigns share
        twin = by_identity[r.fault, r.params["speed"], r.seed]
        assert twin.params == r.params and twin.key == r.key
    assert "faults.gust.at_s=" in " ".join(rows[-1].set_items())


def test_dry_run_lists_the_rows_and_flies_nothing(tmp_path, capsys) -> None:
    path = write(
        tmp_path,
        f"""\
        missions: [{SQUARE}]
        seeds: [0, 1]
        grid: {{wind.gust_std_mps: [0.0, 0.1]}}
        """,
    )
    assert main(["campaign", path, "--dry-run", "--limit", "3"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["row", "mission", "rig", "world", "seed", "wind.gust_std_mps", "done"]
    assert out[3].split()[0] == "r00002" and out[3].split()[-1] == "0.1"
    assert "3 rows (4 in the campaign), 0 already finished" in out[-1]
    assert not os.path.exists(tmp_path / "runs")


def test_the_command_reports_located_problems_and_exits_2(tmp_path, capsys) -> None:
    path = write(tmp_path, "missions: []\nseeds: [1, 1]\n")
    assert main(["campaign", path, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert f"{path}:1:11: missions: expected at least one mission file" in err
    assert f"{path}:2:8: seeds: a seed is listed twice" in err
    assert not os.path.exists(tmp_path / "out")


@pytest.mark.parametrize(
    "data, value",
    [
        ("status", "SUCCESS"),
        ("blackboard.pallet_id", "3A"),
        ("perception.blocks[-1]", 3),
        ("motions[kind=GoTo].settle_s", [0.5, None]),
        ("motions[*].kind", ["TakeOff", "GoTo", "GoTo"]),
        ("sim.nothing.here", None),
        ({"equals": ["blackboard.pallet_id", "sim.scan_pallet"]}, True),
        ({"equals": ["status", {"value": "FAILURE"}]}, False),
        ({"length": "perception.blocks"}, 2),
        ({"max": "motions[kind=GoTo].settle_s"}, 0.5),
        ({"less": ["sim.scan_pallet", "mission_time_s"]}, None),  # str < float: no value
    ],
)
def test_metric_paths_and_operations(data, value) -> None:
    summary = {
        "status": "SUCCESS",
        "mission_time_s": 60.0,
        "blackboard": {"pallet_id": "3A"},
        "sim": {"scan_pallet": "3A"},
        "perception": {"blocks": [2, 3]},
        "motions": [
            {"kind": "TakeOff", "settle_s": 0.0},
            {"kind": "GoTo", "settle_s": 0.5},
            {"kind": "GoTo", "settle_s": None},
        ],
    }
    assert metric_from_data("m", data).evaluate(summary) == value


@pytest.mark.parametrize("bad", ["", "a..b", "a[", "a[1:2]", "a.[0]"])
def test_bad_metric_paths_say_what_is_wrong(bad) -> None:
    with pytest.raises(ValueError):
        parse_path(bad)


@pytest.mark.parametrize("name", ["square_quality.yaml", "pallet_scan.yaml", "faults.yaml"])
def test_the_project_campaigns_are_valid(name) -> None:
    c = load_campaign(os.path.join(REPO, "campaigns", name))
    assert check_campaign(c, expand(c)) >= 1


def test_the_example_of_docs_campaigns_md_is_valid(tmp_path, monkeypatch) -> None:
    import re

    with open(os.path.join(REPO, "docs", "campaigns.md"), encoding="utf-8") as f:
        (example,) = re.findall(r"```yaml\n(.*?)```", f.read(), re.S)
    monkeypatch.chdir(REPO)  # its paths are relative to the repository
    c = load_campaign(write(tmp_path, example))
    rows = expand(c)
    check_campaign(c, rows)
    assert len(rows) == 3 * 20 * 3 * 2  # faults x seeds x gusts x scan speeds
    assert c.parameters()[:3] == ["wind.gust_std_mps", "scan_speed", "world.scan_pallet"]


def test_a_row_key_covers_the_files_its_mission_includes(tmp_path) -> None:
    """Editing an included subtree runs the rows again (the key had held the mission file's
    own bytes only, so a resumed campaign kept results of the old subtree); a mission
    without includes keeps the key it had."""
    lib = tmp_path / "lib"
    lib.mkdir()
    (lib / "hop.xml").write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Hop"><AlwaysSuccess/></BehaviorTree></root>'
    )
    (tmp_path / "m.xml").write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Main"><include path="lib/hop.xml"/>'
        '<BehaviorTree ID="Main"><SubTree ID="Hop"/></BehaviorTree></root>'
    )
    text = "missions: [m.xml]\nseeds: {start: 0, count: 2}\n"
    path = write(tmp_path, text)
    first = [r.key for r in expand(load_campaign(path))]
    assert [r.key for r in expand(load_campaign(path))] == first
    (lib / "hop.xml").write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Hop"><AlwaysFailure/></BehaviorTree></root>'
    )
    second = [r.key for r in expand(load_campaign(path))]
    assert set(second).isdisjoint(first)
    # a mission without includes: its keys do not depend on this (the same as before)
    c = load_campaign(write(tmp_path, f"missions: [{SQUARE}]\nseeds: {{start: 0, count: 1}}\n"))
    assert not expand(c)._includes.get(SQUARE)


def test_an_unquoted_grid_or_set_value_is_read_as_set_reads_its_text(tmp_path) -> None:
    """A campaign's YAML had read ``mode: [off]`` as false (YAML 1.1) and ``[0042]`` as the
    octal 34, where ``--set mode=off`` gives the text off and ``--set pallet=0042`` 42: the
    dry run passed and the flights compared the text 'off' with false in the air."""
    path = write(
        tmp_path,
        f"""\
        missions: [{SQUARE}]
        seeds: {{start: 0, count: 1}}
        set:
          bb.label: 1:30
          bb.rate: 1e3
        grid:
          bb.mode: [off, "on", true]
          bb.pallet: [0042, '0042', 010]
          bb.speed: [0.5, [1, 2]]
        """,
    )
    c = load_campaign(path)
    assert c.fixed == {"bb.label": "1:30", "bb.rate": 1000.0}
    assert c.grid["bb.mode"] == ["off", "on", True]
    assert c.grid["bb.pallet"] == [42, "0042", 10]
    assert c.grid["bb.speed"] == [0.5, [1, 2]]
