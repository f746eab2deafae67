"""The btrun command: run folder, summary, exit codes, --set, show, nodes, replay, determinism."""

from __future__ import annotations

import contextlib
import io
import json
import os

import pytest
from helpers import REPO

from bt_engine.cli import main

SQUARE = os.path.join(REPO, "missions", "square.xml")
YAW = os.path.join(REPO, "missions", "yaw_test.xml")


def run_cli(*args: str) -> int:
    return main([*args])


@pytest.fixture(scope="module")
def yaw_run(tmp_path_factory):
    """``btrun missions/yaw_test.xml --no-report`` (seed 0) run once for the tests that only
    read its run folder or what it printed: (exit code, run folder, stdout)."""
    out = tmp_path_factory.mktemp("yaw") / "run"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        rc = run_cli(YAW, "--out", str(out), "--no-report")
    return rc, out, printed.getvalue()


def test_run_writes_summary_and_tick_log(yaw_run):
    rc, out, printed = yaw_run
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    for key in ("status", "reason", "ticks", "mission_time_s", "wall_time_s", "blackboard", "sim"):
        assert key in s
    assert s["status"] == "SUCCESS" and s["sim"]["landed"] is True
    lines = (out / "ticks.jsonl").read_text().splitlines()
    assert json.loads(lines[0])["header"]["nodes"]
    assert len(lines) == s["ticks"] + 1
    assert "SUCCESS" in printed and "run folder:" in printed and "x real time" in printed


def test_the_tick_log_header_says_when_the_run_started(yaw_run):
    """A run folder named with --out (or copied) has no date in its name and its files'
    times are those of the last write or of the copy: the header keeps the start."""
    import time

    from bt_engine.ticklog import header_path, read_log, started_at

    _rc, out, _printed = yaw_run
    header, _ = read_log(str(out / "ticks.jsonl"), header_only=True)
    started = started_at(header)
    assert started is not None and header["started"].endswith("Z")
    s = json.loads((out / "summary.json").read_text())
    assert started <= time.time() and time.time() - started < 3600
    assert started <= os.path.getmtime(out / "summary.json") - s["wall_time_s"] + 1.5
    # where it was started: the header's relative paths (rig, --set gallery=) are from there
    assert header["cwd"] == os.getcwd()
    assert header_path({"cwd": "/runs/here"}, "rigs/aisle.yaml") == "/runs/here/rigs/aisle.yaml"
    assert header_path({"cwd": "/runs/here"}, "/abs/rig.yaml") == "/abs/rig.yaml"
    assert header_path({}, "rigs/aisle.yaml") == "rigs/aisle.yaml"  # from before it was kept
    assert header_path({"cwd": "/x"}, None) is None
    assert started_at({"started": "2026-11-27T14:20:01Z"}) == 1795789201.0
    for bad in ("2026-11-27T14:20:01", "yesterday", 5, "9" * 50):
        assert started_at({"started": bad}) is None


def test_the_speed_keeps_its_decimal_below_10x():
    """The site fleet ran at 1.3x and was printed as '1x real time' (and 1.6x as '2x'):
    below 10x the decimal is what tells runs apart."""
    from bt_engine.run_cmd import real_time_words

    assert real_time_words(85.2, 65.4) == "1.3x real time"
    assert real_time_words(85.2, 53.0) == "1.6x real time"
    assert real_time_words(395.2, 54.5) == "7.3x real time"
    assert real_time_words(300.0, 10.0) == "30x real time"
    assert real_time_words(1.0, 0.0) == "- x real time"


def test_same_seed_same_tick_log_different_seed_differs(tmp_path):
    logs = []
    for name, seed in (("a", "5"), ("b", "5"), ("c", "6")):
        out = tmp_path / name
        assert run_cli(YAW, "--out", str(out), "--seed", seed, "-q", "--no-report") == 0
        lines = (out / "ticks.jsonl").read_text().splitlines()[1:]
        logs.append(lines)
    assert logs[0] == logs[1]
    assert logs[0] != logs[2]


def test_world_setting_and_rig_errors_are_located(tmp_path, capsys):
    out = tmp_path / "run"
    assert (
        run_cli(YAW, "--out", str(out), "-q", "--no-report", "--set", "world.scan_pallet=2B") == 0
    )
    assert json.loads((out / "summary.json").read_text())["sim"]["scan_pallet"] == "2B"
    assert run_cli(YAW, "--out", str(tmp_path / "x"), "--set", "world.scan_palet=2B") == 2
    err = capsys.readouterr().err
    assert "scan_palet" in err and "did you mean" in err and "Traceback" not in err
    assert run_cli(YAW, "--set", "noequals") == 2
    assert "expected KEY=VALUE" in capsys.readouterr().err


def test_failure_exit_code_and_reason(tmp_path, capsys):
    bad = tmp_path / "timeout.xml"
    bad.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="M"><Sequence><TakeOff/>'
        '<GoTo name="far" pose="5;0;1" timeout="1"/></Sequence></BehaviorTree></root>'
    )
    out = tmp_path / "run"
    assert run_cli(str(bad), "--out", str(out), "--no-report") == 1
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "FAILURE" and "GoTo 'far' failed" in s["reason"]
    assert s["sim"]["landed"] is True  # shutdown landed the drone
    assert "time-out after 1 s" in capsys.readouterr().out


def test_show_text_and_dot(tmp_path, capsys):
    assert run_cli("show", SQUARE) == 0
    text = capsys.readouterr().out
    assert "└── Land 'land'" in text and "GoTo 'goto'" in text
    dot = tmp_path / "t.dot"
    assert run_cli("show", SQUARE, "--format", "dot", "-o", str(dot)) == 0
    assert dot.read_text().startswith("digraph mission")


def test_nodes_catalogue_groot_palette_and_markdown(tmp_path, capsys):
    assert run_cli("nodes") == 0
    listing = capsys.readouterr().out
    for name in ("GoTo", "TakeOff", "Sequence", "IsHealthy", "Timeout"):
        assert name in listing
    pal = tmp_path / "palette.xml"
    assert run_cli("nodes", "--groot", str(pal)) == 0
    from lxml import etree

    root = etree.parse(str(pal)).getroot()
    goto = root.find("TreeNodesModel/Action[@ID='GoTo']")
    names = {p.get("name") for p in goto}
    assert {"pose", "max_speed", "yaw_mode", "pos_threshold"} <= names
    assert root.find("TreeNodesModel/Condition[@ID='IsFlying']") is not None
    md = tmp_path / "nodes.md"
    assert run_cli("nodes", "--markdown", str(md)) == 0
    assert "### GoTo" in md.read_text()


def test_docs_node_reference_is_up_to_date():
    """docs/nodes.md is generated from the declarations; regenerate it when they change."""
    import nodes  # noqa: F401
    from bt_engine.catalogue import catalogue_markdown
    from bt_engine.registry import REGISTRY

    with open(os.path.join(REPO, "docs", "nodes.md"), encoding="utf-8") as f:
        assert f.read() == catalogue_markdown(REGISTRY), "run: btrun nodes --markdown docs/nodes.md"


def test_replay_shows_tree_at_a_tick(yaw_run, tmp_path, capsys):
    rc, out, _ = yaw_run
    assert rc == 0
    assert run_cli("replay", str(out), "--tick", "200") == 0
    shown = capsys.readouterr().out
    assert shown.startswith("tick 200") and "RUNNING" in shown
    assert run_cli("replay", str(out), "--tick", "999999") == 2
    assert run_cli("replay", str(tmp_path / "nothing")) == 2


@pytest.mark.parametrize("args", [["validate"], ["show"], ["convert", "a.xml"]])
def test_usage_errors_exit_2(args):
    with pytest.raises(SystemExit) as e:
        run_cli(*args)
    assert e.value.code == 2
