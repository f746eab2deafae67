"""Review 49, through the real command line: what btrun did with input it could not use.

* ``btrun replay`` replaced a ``run.mcap`` it could not read with an empty file (the bytes
  were gone), and a repair kept no copy of what it rewrote; a ``ticks.jsonl`` with an
  unreadable line was replayed up to it, with exit 0 and no word.
* ``--groot xyz`` / ``--foxglove 1668x`` became port 0 (any free port) without a word.
* A plug-in calling ``sys.exit()`` at import ended btrun with that code, silently.
* ``btrun convert`` wrote a mission with validation problems (exit 0, a warning).
* ``btrun campaign --dry-run`` passed grid values each run's pre-flight refuses (outside the
  rig's geofence); the campaign then recorded those rows CRASHED.
"""

from __future__ import annotations

import json
import os
import time

import pytest
from helpers import REPO

from bt_engine import plugins
from bt_engine.arg_types import port_number
from bt_engine.cli import main
from bt_engine.registry import REGISTRY

SQUARE = os.path.join(REPO, "missions", "square.xml")


def _exit_code(argv: list[str]) -> int:
    """``main(argv)``'s exit code, also when argparse exits."""
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)


# --- 1. replay: nothing of a run is lost ----------------------------------------------------

NODES = [["Main/seq", "Sequence 'seq'", 0, []], ["Main/seq/a", "AlwaysSuccess 'a'", 1, []]]


def _tick(n: int, **more) -> str:
    return json.dumps({"tick": n, "t": round(0.02 * n, 2), "status": "RUNNING", **more})


def _run_folder(tmp_path, lines: list[str], end: str = "\n") -> str:
    folder = tmp_path / "run"
    folder.mkdir()
    header = json.dumps({"header": {"seed": 0, "sets": [], "nodes": NODES}})
    (folder / "ticks.jsonl").write_text("\n".join([header, *lines]) + end)
    return str(folder)


def _mcap(path: str, messages: int = 60) -> bytes:
    """A complete small MCAP file at ``path`` (many chunks); returns its bytes."""
    from mcap.writer import CompressionType, Writer

    with open(path, "wb") as f:
        w = Writer(f, chunk_size=256, compression=CompressionType.NONE)
        w.start(profile="", library="test")
        schema = w.register_schema("s", "jsonschema", b"{}")
        channel = w.register_channel("/x", "json", schema)
        for i in range(messages):
            data = json.dumps({"i": i, "pad": "p" * 40}).encode()
            w.add_message(channel, log_time=i, data=data, publish_time=i)
        w.finish()
    with open(path, "rb") as f:
        return f.read()


def test_replay_leaves_a_run_mcap_it_cannot_read_as_it_is(tmp_path, capsys) -> None:
    folder = _run_folder(tmp_path, [_tick(1, changed={"Main/seq": "RUNNING"}), _tick(2)])
    mcap = os.path.join(folder, "run.mcap")
    garbage = os.urandom(3000)
    with open(mcap, "wb") as f:
        f.write(garbage)
    assert main(["replay", folder, "--all"]) == 0  # the tick log is replayed
    out, err = capsys.readouterr()
    assert "tick 2" in out
    said = f"{mcap}: not repaired: nothing in it could be recovered (reading stopped at byte 0 "
    assert said in err and "the file is left as it is" in err
    assert "repaired: 0 messages" not in err
    with open(mcap, "rb") as f:
        assert f.read() == garbage
    assert not any(name.startswith("run.mcap.") for name in os.listdir(folder))
    # --repair says it too, exit 2
    assert main(["replay", "--repair", folder]) == 2
    assert "nothing in it could be recovered" in capsys.readouterr().err
    with open(mcap, "rb") as f:
        assert f.read() == garbage


def test_a_repair_keeps_the_original_beside_it_and_never_overwrites_a_backup(
    tmp_path, capsys
) -> None:
    from mcap.reader import make_reader

    folder = _run_folder(tmp_path, [_tick(1)])
    mcap = os.path.join(folder, "run.mcap")
    whole = _mcap(mcap)
    torn = whole[: len(whole) // 2]  # what a kill leaves: no summary, no footer
    with open(mcap, "wb") as f:
        f.write(torn)
    assert main(["replay", "--repair", folder]) == 0
    out = capsys.readouterr().out
    assert f"the original is kept as {mcap}.orig" in out and "reading stopped at byte" in out
    with open(f"{mcap}.orig", "rb") as f:
        assert f.read() == torn
    with open(mcap, "rb") as f:
        kept = sum(1 for _ in make_reader(f).iter_messages())
    assert 0 < kept < 60

    # one damaged record early: what came before is kept, and the original too, under a
    # name no backup has
    damaged = bytearray(whole[: len(whole) - 200])
    damaged[len(whole) // 3] ^= 0xFF
    with open(mcap, "wb") as f:
        f.write(damaged)
    assert main(["replay", "--repair", mcap]) == 0
    assert f"the original is kept as {mcap}.orig.1" in capsys.readouterr().out
    with open(f"{mcap}.orig", "rb") as f:
        assert f.read() == torn  # the first backup is untouched
    with open(f"{mcap}.orig.1", "rb") as f:
        assert f.read() == bytes(damaged)


def test_a_tick_log_with_an_unreadable_line_is_replayed_and_said(tmp_path, capsys) -> None:
    lines = [_tick(1, changed={"Main/seq": "RUNNING"}), "{not json"]
    lines += [_tick(n, changed={"Main/seq/a": "SUCCESS" if n % 2 else "RUNNING"}) for n in (3, 4)]
    lines += ['{"tick": "five"}', _tick(6, changed={"Main/seq": "SUCCESS"}), '{"tick": 7, "t']
    folder = _run_folder(tmp_path, lines, end="")  # the last line cut by a kill
    log = os.path.join(folder, "ticks.jsonl")
    assert main(["replay", folder, "--all"]) == 0
    out, err = capsys.readouterr()
    assert "tick 6" in out and "root RUNNING" in out  # read past the bad lines
    assert f"{log}:3:1: warning: the line is not JSON: line skipped" in err
    assert f"{log}:6:1: warning: a tick record has a whole-number 'tick', got 'five'" in err
    cut = f"{log}:8:1: warning: the last line is cut short (a run killed while writing it?): "
    assert err.count(cut + "replayed up to tick 6") == 1
    assert "Traceback" not in err
    # --tick reaches ticks after the bad line
    assert main(["replay", folder, "--tick", "4"]) == 0
    assert "tick 4" in capsys.readouterr().out


# --- 2. --groot / --foxglove: a port is a number ----------------------------------------------


BAD_PORTS = [
    ("--groot", "xyz"),
    ("--groot", "1668x"),
    ("--foxglove", "1668x"),
    ("--foxglove", "1_668"),
]


@pytest.mark.parametrize("option, value", BAD_PORTS)
def test_a_port_that_is_no_number_is_refused(tmp_path, capsys, option, value) -> None:
    out = tmp_path / "run"
    assert _exit_code([SQUARE, option, value, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"argument {option}: expected a TCP port 1 to" in err and f"got '{value}'" in err
    assert not out.exists()


def test_zero_still_means_any_free_port() -> None:
    assert port_number()("0") == 0 and port_number(65534)(" 1667 ") == 1667


# --- 3. a plug-in that calls sys.exit() at import ---------------------------------------------


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    """Write ``tmp_path/<module>.py`` and name it in ``BTRUN_PLUGINS`` (fresh plug-in list;
    the registry is restored afterwards)."""
    import nodes  # noqa: F401  (btrun's own leaves registered before the snapshot below)

    def use(module: str, source: str) -> str:
        path = tmp_path / f"{module}.py"
        path.write_text(source)
        monkeypatch.syspath_prepend(str(tmp_path))
        monkeypatch.setenv("BTRUN_PLUGINS", f"{module}:PLUGIN")
        monkeypatch.setattr(plugins, "_loaded", None)
        return str(path)

    saved = (dict(REGISTRY._models), dict(REGISTRY._aliases))
    yield use
    plugins._loaded = None
    REGISTRY._models, REGISTRY._aliases = saved


def test_a_plugin_calling_sys_exit_at_import_is_a_located_error(plugin, capsys) -> None:
    path = plugin("review49_exit", "import sys\nsys.exit(3)\n")
    assert main(["validate", SQUARE]) == 2
    err = capsys.readouterr().err
    assert err == (
        "btrun: plug-in 'review49_exit:PLUGIN' (BTRUN_PLUGINS) could not be loaded: it called "
        f"sys.exit(3) while being imported ({path}:2)\n"
    )


def test_ctrl_c_while_a_plugin_is_imported_still_stops_btrun(plugin) -> None:
    plugin("review49_ctrl_c", "raise KeyboardInterrupt\n")
    with pytest.raises(KeyboardInterrupt):
        main(["validate", SQUARE])


def test_a_node_calling_sys_exit_when_created_is_said_by_validate(plugin, tmp_path, capsys):
    path = plugin(
        "review49_node_exit",
        "import sys\n"
        "from bt_engine.node import SUCCESS, SyncActionNode\n"
        "from bt_engine.registry import register\n\n\n"
        "@register\n"
        "class ExitsWhenMade(SyncActionNode):\n"
        "    def __init__(self, name, ctx=None):\n"
        "        super().__init__(name, ctx)\n"
        "        sys.exit(4)\n\n"
        "    def tick_impl(self):\n"
        "        return SUCCESS\n\n\n"
        "class _P:\n"
        "    name = 'exit-node'\n"
        "    load_target = write_report = None\n"
        "    commands = {}\n\n\n"
        "PLUGIN = _P()\n",
    )
    mission = tmp_path / "m.xml"
    mission.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Main">\n<ExitsWhenMade/>\n'
        "</BehaviorTree></root>\n"
    )
    assert main(["validate", str(mission)]) == 2
    err = capsys.readouterr().err
    assert f"{mission}:2:1: ExitsWhenMade could not be created: SystemExit: 4 (raised at " in err
    assert f"{path}:10)" in err


# --- 4. convert: nothing written from a mission with problems ---------------------------------


def test_convert_of_a_mission_with_a_validation_problem_writes_nothing(tmp_path, capsys):
    src = tmp_path / "m.xml"
    src.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Main">\n'
        '<GoTo pose="1;0;1" yaw_mode="FIXD_YAW"/>\n'
        "</BehaviorTree></root>\n"
    )
    dest = tmp_path / "m.yaml"
    assert main(["convert", str(src), str(dest)]) == 2
    out, err = capsys.readouterr()
    assert f"{src}:2:" in err and "got 'FIXD_YAW'" in err and "wrote" not in out
    assert not dest.exists()
    dest.write_text("kept\n")  # an existing output stays as it was
    assert main(["convert", str(src), str(dest)]) == 2
    assert dest.read_text() == "kept\n"
    # a good mission still converts
    src.write_text(src.read_text().replace("FIXD_YAW", "FIXED_YAW"))
    assert main(["convert", str(src), str(dest)]) == 0
    assert "GoTo" in dest.read_text()


# --- 5. campaign: values each run's pre-flight refuses are refused before anything runs --------


def _campaign(tmp_path, grid: str, name: str = "c.yaml") -> str:
    path = tmp_path / name
    path.write_text(f"missions: [{SQUARE}]\nseeds: [0, 1]\nmax_time_s: 60\ngrid:\n{grid}")
    return str(path)


def test_a_grid_value_outside_the_geofence_is_refused_by_the_dry_run(tmp_path, capsys) -> None:
    path = _campaign(tmp_path, "  speed: [0.5, 1.0]\n  height: [1.0, 2.7]\n")
    assert main(["campaign", path, "--dry-run"]) == 2
    out, err = capsys.readouterr()
    lines = err.splitlines()
    assert lines[0].startswith(
        f"{path}:6:3: height: height 2.7 (the climb ends at z 2.7 m): expected a point inside "
        "the rig's geofence (x "
    ), err
    assert lines[0].endswith("(rig (default), with speed=0.5)")  # said once, not per speed
    assert lines[1:] == ["1 problem found; nothing was run."] and "r00000" not in out
    # the campaign itself: refused before anything runs
    out_dir = tmp_path / "out"
    assert main(["campaign", path, "--out", str(out_dir), "--workers", "1"]) == 2
    assert "height 2.7" in capsys.readouterr().err and not out_dir.exists()


def test_a_rig_setting_of_the_grid_is_part_of_the_check(tmp_path, capsys) -> None:
    grid = "  safety.geofence.max_m: [[9.2, 3, 3.5], [9.2, 3, 2.5]]\n  height: [1.0, 2.7]\n"
    assert main(["campaign", _campaign(tmp_path, grid), "--dry-run"]) == 2
    (line, _) = capsys.readouterr().err.splitlines()
    assert "height 2.7" in line and "z -0.5 to 2.5 m" in line
    assert line.endswith("with safety.geofence.max_m=[9.2, 3, 2.5])")


def test_many_combinations_inside_the_geofence_are_checked_quickly(tmp_path, capsys) -> None:
    heights = ", ".join(f"{0.5 + 0.05 * i:.2f}" for i in range(20))
    speeds = ", ".join(f"{0.2 + 0.05 * i:.2f}" for i in range(20))
    path = _campaign(tmp_path, f"  height: [{heights}]\n  speed: [{speeds}]\n")
    t0 = time.perf_counter()
    assert main(["campaign", path, "--dry-run"]) == 0
    assert time.perf_counter() - t0 < 20.0  # 400 flights, one mission built (about 0.5 s)
    assert "800 rows (800 in the campaign)" in capsys.readouterr().out


def test_replay_cuts_a_huge_blackboard_value_and_says_its_length(tmp_path, capsys) -> None:
    """A 10,000-point route on the blackboard had been printed in full at every tick."""
    route = ";".join(f"{i}.5" for i in range(10_000))
    lines = [_tick(1, changed={"Main/seq": "RUNNING"}, bb={"route": route, "n": 3})]
    folder = _run_folder(tmp_path, lines)
    assert main(["replay", folder, "--tick", "1"]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("blackboard: "))
    assert len(line) < 400, len(line)
    assert "n=3" in line and "route='0.5;1.5;2.5" in line
    assert f"({len(repr(route)):,} characters in all)" in line
