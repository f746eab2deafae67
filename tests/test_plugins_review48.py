"""Review 48 of plug-ins: what a plug-in's code may return, raise or register.

* A tick that returns IDLE, a synchronous action that returns RUNNING and a condition whose
  ``check()`` returns neither True nor False are errors of that tick, located (as in
  BehaviorTree.CPP); an exception in a plug-in's tick names the plug-in's file:line.
* An enum name a plug-in gives another value than a registered node, or an ID equal to a
  built-in alias, is refused when the plug-in loads.
* A port type whose conversion raises, or a node whose ``__init__`` raises, is a located
  problem (exit 2), never a traceback, and ``btrun validate`` says it.
* The watchdog says how long it waited.

The campaign's part of the review is in ``test_campaign_review48.py``.
"""

from __future__ import annotations

import inspect
import json
import os
import sys
import time

import pytest
from helpers import LEAF_PLUGIN_TAIL, wrap, xml_mission

from bt_engine import Runner, plugins
from bt_engine.cli import main
from bt_engine.node import (
    FAILURE,
    IDLE,
    RUNNING,
    SUCCESS,
    ConditionNode,
    NodeRuntimeError,
    StatefulActionNode,
    SyncActionNode,
)
from bt_engine.ports import EnumType, PortType, input_port
from bt_engine.registry import REGISTRY


@pytest.fixture
def plugin_env(tmp_path, monkeypatch):
    """Set ``BTRUN_PLUGINS`` to a module written in ``tmp_path`` (fresh plug-in list); the
    registry is restored afterwards."""
    import nodes  # noqa: F401  (btrun's own leaves registered before the snapshot below)

    module = []

    def use(spec: str, source: str) -> None:
        module.append(spec.partition(":")[0])
        (tmp_path / f"{module[-1]}.py").write_text(source)
        monkeypatch.syspath_prepend(str(tmp_path))
        monkeypatch.setenv("BTRUN_PLUGINS", spec)
        monkeypatch.setattr(plugins, "_loaded", None)

    saved = (dict(REGISTRY._models), dict(REGISTRY._aliases))
    yield use
    plugins._loaded = None
    REGISTRY._models, REGISTRY._aliases = saved
    for name in module:
        sys.modules.pop(name, None)


def _mission(body: str, *leaves: type):
    reg = REGISTRY.copy()
    for cls in leaves:
        reg.register(cls)
    return xml_mission(wrap(body), registry=reg)


# --- F7: return values BehaviorTree.CPP rejects ------------------------------------------


class ReturnsIdle(SyncActionNode):
    """Returns IDLE."""

    def tick_impl(self):
        return IDLE


class SyncRunning(SyncActionNode):
    """A synchronous action that returns RUNNING."""

    def tick_impl(self):
        return RUNNING


class SaysNo(ConditionNode):
    """check() returns the text 'no'."""

    def check(self):
        return "no"


class NumpyCheck(ConditionNode):
    """check() returns a numpy bool; then the status FAILURE."""

    def check(self):
        import numpy as np

        self.calls = getattr(self, "calls", 0) + 1
        return np.float64(1.0) > 0.5 if self.calls == 1 else FAILURE


@pytest.mark.parametrize(
    "leaf, said",
    [
        (
            ReturnsIdle,
            "ReturnsIdle 'ReturnsIdle': returned IDLE: a tick returns SUCCESS, FAILURE, RUNNING",
        ),
        (
            SyncRunning,
            "SyncRunning 'SyncRunning': returned RUNNING, but a synchronous action (SyncActionNode)",
        ),
        (SaysNo, "SaysNo 'SaysNo': check() returned 'no' (str): a condition's check returns True"),
    ],
)
def test_a_return_value_btcpp_rejects_is_an_error_of_that_tick(leaf, said) -> None:
    m = _mission(f"<Sequence><{leaf.__name__}/><AlwaysSuccess/></Sequence>", leaf)
    with pytest.raises(NodeRuntimeError) as info:
        m.tick()
    assert str(info.value).startswith(f"inline.xml:3:11: {said}"), str(info.value)
    result = Runner(_mission(f"<Sequence><{leaf.__name__}/></Sequence>", leaf)).run(10)
    assert result.status == "ABORTED" and said in result.reason, result.reason


def test_a_condition_may_return_a_numpy_bool_or_a_status() -> None:
    m = _mission("<Sequence><NumpyCheck/></Sequence>", NumpyCheck)
    assert m.tick() is SUCCESS
    assert m.tick() is FAILURE


def test_btcpp_refuses_the_same_returns() -> None:
    """What BehaviorTree.CPP 4.8 does (behaviortreepy): the same two refusals; a skipped
    leaf is taken (so it is in btrun)."""
    bt = pytest.importorskip("behaviortreepy")
    f = bt.BehaviorTreeFactory()
    f.register_simple_action("RetIdle", lambda n: bt.NodeStatus.IDLE)
    f.register_simple_action("SyncRun", lambda n: bt.NodeStatus.RUNNING)
    f.register_simple_action("RetSkip", lambda n: bt.NodeStatus.SKIPPED)
    said = {}
    for leaf in ("RetIdle", "SyncRun", "RetSkip"):
        xml = (
            f'<root BTCPP_format="4"><BehaviorTree ID="M"><Sequence><{leaf}/>'
            "<AlwaysSuccess/></Sequence></BehaviorTree></root>"
        )
        try:
            said[leaf] = str(f.create_tree_from_text(xml, bt.Blackboard.create()).tick_once())
        except Exception as exc:  # noqa: BLE001
            said[leaf] = str(exc)
    assert "not allowed to set manually the status to IDLE" in said["RetIdle"]
    assert "SyncActionNode MUST never return RUNNING" in said["SyncRun"]
    assert "SUCCESS" in said["RetSkip"]


def test_a_leaf_returning_idle_in_flight_aborts_located_and_lands(plugin_env, tmp_path) -> None:
    plugin_env(
        "idle48:PLUGIN",
        "from bt_engine import SyncActionNode, register, IDLE\n\n\n@register\n"
        "class RetIdle(SyncActionNode):\n    def tick_impl(self):\n        return IDLE\n"
        + LEAF_PLUGIN_TAIL,
    )
    mission = tmp_path / "idle.xml"
    mission.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">\n'
        '<Sequence><TakeOff height="0.5"/><RetIdle/><Land/></Sequence></BehaviorTree></root>'
    )
    out = tmp_path / "run"
    assert main([str(mission), "--out", str(out), "-q", "--no-report", "--no-mcap"]) == 1
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ABORTED"
    assert summary["reason"].startswith(f"{mission}:2:34: RetIdle 'RetIdle': returned IDLE"), (
        summary
    )
    assert summary["sim"]["landed"] is True


# --- F9: an exception in a plug-in's tick names the plug-in's code ------------------------


class Boom(SyncActionNode):
    """Raises in its tick."""

    def tick_impl(self):
        raise ValueError("boom from plug-in")


class BoomKey(StatefulActionNode):
    """Raises KeyError on its second tick."""

    def on_start(self):
        return RUNNING

    def on_running(self):
        return {}["missing thing"]


def _line_of(cls: type, text: str) -> int:
    lines, first = inspect.getsourcelines(cls)
    return first + next(i for i, line in enumerate(lines) if text in line)


@pytest.mark.parametrize(
    "leaf, said, text",
    [
        (Boom, "ValueError: boom from plug-in", "raise ValueError"),
        (BoomKey, "KeyError: 'missing thing'", 'return {}["missing thing"]'),
    ],
)
def test_an_exception_in_a_plugin_tick_names_its_file_and_line(leaf, said, text) -> None:
    run = Runner(_mission(f"<Sequence><{leaf.__name__}/></Sequence>", leaf))
    result = run.run(10)
    where = f"{os.path.abspath(__file__)}:{_line_of(leaf, text)}"
    assert result.status == "ABORTED"
    assert result.reason.startswith(f"internal error in {leaf.__name__} (inline.xml:3:11)")
    assert result.reason.endswith(f"{said} (raised at {where})"), result.reason
    assert "Traceback" in run.error_traceback and text in run.error_traceback


# --- F2, F8: what a plug-in may not register ---------------------------------------------


def test_an_enum_name_with_another_value_is_refused_when_the_plugin_loads(
    plugin_env, tmp_path, capsys
) -> None:
    plugin_env(
        "enum48:PLUGIN",
        "from bt_engine import SyncActionNode, register, SUCCESS\n"
        "from bt_engine.ports import EnumType, input_port\n\n"
        'GIMBAL = EnumType("GimbalMode", {"FIXED_YAW": 7, "TRACK": 8})\n\n\n'
        "@register\nclass Gimbal(SyncActionNode):\n"
        '    ports = (input_port("mode", GIMBAL, "TRACK", "mode"),)\n\n'
        "    def tick_impl(self):\n        return SUCCESS\n" + LEAF_PLUGIN_TAIL,
    )
    mission = tmp_path / "m.xml"
    mission.write_text(wrap('<Script code="ym := FIXED_YAW"/>'))
    assert main(["validate", str(mission)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("btrun: plug-in 'enum48:PLUGIN' (BTRUN_PLUGINS) could not be loaded")
    assert "node 'Gimbal', port 'mode': enum name FIXED_YAW = 7 is already FIXED_YAW = 2" in err
    assert "port 'yaw_mode' of node 'GoTo': nodes.flight" in err
    assert err.endswith(f"({tmp_path / 'enum48.py'}:7)"), err


def test_an_enum_name_with_the_same_value_is_taken() -> None:
    import nodes  # noqa: F401

    class SameYaw(SyncActionNode):
        """Reuses FIXED_YAW = 2."""

        ports = (input_port("m", EnumType("Yaw2", {"FIXED_YAW": 2, "OTHER": 9}), "OTHER"),)

    reg = REGISTRY.copy()
    reg.register(SameYaw)
    assert "SameYaw" in reg


def test_an_id_or_alias_equal_to_a_builtin_alias_or_id_is_refused() -> None:
    class SequenceStar(SyncActionNode):
        """Collides with the v3 alias of SequenceWithMemory."""

    class Aliased(SyncActionNode):
        """Its alias collides with a node."""

        aliases = ("AlwaysSuccess",)

    reg = REGISTRY.copy()
    with pytest.raises(ValueError, match="'SequenceStar' is already an alias of node "):
        reg.register(SequenceStar)
    with pytest.raises(ValueError, match="alias 'AlwaysSuccess' of 'Aliased' is already a node"):
        reg.register(Aliased)
    assert reg.get("SequenceStar").id == "SequenceWithMemory"


def test_an_id_collision_names_the_node_that_holds_it() -> None:
    class AlwaysSuccess(SyncActionNode):
        """Collides with the built-in."""

    with pytest.raises(ValueError) as info:
        REGISTRY.copy().register(AlwaysSuccess)
    assert "(that one: bt_engine.leaves, " in str(info.value), str(info.value)
    assert os.path.join("bt_engine", "leaves.py:") in str(info.value)


# --- F3: a port type or __init__ that raises ----------------------------------------------

F3_PLUGIN = """from bt_engine import SyncActionNode, register, SUCCESS
from bt_engine.ports import PortType, input_port


class Angle(PortType):
    name = "angle"

    def convert(self, value):
        return float(str(value).rstrip("deg"))


@register
class Aim(SyncActionNode):
    ports = (input_port("angle", Angle(), "0deg", "angle"),)

    def tick_impl(self):
        return SUCCESS


@register
class BadInit(SyncActionNode):
    def __init__(self, name, ctx=None):
        super().__init__(name, ctx)
        raise RuntimeError("init exploded")

    def tick_impl(self):
        return SUCCESS
"""


@pytest.mark.parametrize(
    "leaf, said",
    [
        (
            '<Aim angle="ninety"/>',
            ":3:7: port 'angle' of Aim: 'ninety' could not be converted to angle: ValueError: "
            "could not convert string to float: 'ninety' (raised at {plugin}:9)",
        ),
        (
            "<BadInit/>",
            ":3:2: BadInit could not be created: RuntimeError: init exploded "
            "(raised at {plugin}:24)",
        ),
    ],
)
def test_a_port_type_or_init_that_raises_is_a_located_problem(
    plugin_env, tmp_path, capsys, leaf, said
) -> None:
    plugin_env("f3_48:PLUGIN", F3_PLUGIN + LEAF_PLUGIN_TAIL)
    mission = tmp_path / "m.xml"
    mission.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">\n'
        f"<Sequence>\n {leaf}\n</Sequence></BehaviorTree></root>"
    )
    expected = f"{mission}" + said.format(plugin=tmp_path / "f3_48.py")
    assert main(["validate", str(mission)]) == 2
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err, err
    out = tmp_path / "run"
    assert main([str(mission), "--out", str(out), "-q", "--no-report"]) == 2
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err, err
    assert not (out / "summary.json").exists()  # nothing flew


def test_a_port_type_that_raises_on_an_input_or_set_value_is_a_located_problem(
    plugin_env, tmp_path, capsys
) -> None:
    """The value reaching the port through a mission input (its default, or ``--set``)
    had been a traceback of validate and run (exit 1): only literals were located."""
    plugin_env("f3_48:PLUGIN", F3_PLUGIN + LEAF_PLUGIN_TAIL)
    mission = tmp_path / "m.xml"
    mission.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">\n'
        '<Sequence>\n <Aim angle="{a}"/>\n</Sequence></BehaviorTree>\n'
        '<TreeNodesModel><SubTree ID="Main"><input_port name="a" default="ninety"/>'
        "</SubTree></TreeNodesModel></root>"
    )
    converted = (
        "port 'angle' of Aim: 'ninety' could not be converted to angle: ValueError: could not "
        f"convert string to float: 'ninety' (raised at {tmp_path / 'f3_48.py'}:9)"
    )
    assert main(["validate", str(mission)]) == 2
    err = capsys.readouterr().err
    assert f"{mission}:3:2: {{a}}: the value the mission gives it" in err, err
    assert converted in err and "Traceback" not in err, err
    out = tmp_path / "run"
    for value in ("ninety", "x90"):
        assert main([str(mission), "--set", f"a={value}", "--out", str(out), "-q"]) == 2
        err = capsys.readouterr().err
        assert f"--set a={value}: " + converted.replace("ninety", value) in err, err
        assert f"(read as 'angle' by Aim ({mission}:3:2))" in err and "Traceback" not in err
    assert not out.exists()  # nothing flew
    assert main([str(mission), "--set", "a=90deg", "--out", str(out), "-q", "--no-report"]) == 0


def test_the_builder_locates_a_port_type_that_raises() -> None:
    """Without validation (a spec built directly), the builder says it too."""
    from bt_engine.builder import build_tree
    from bt_engine.clock import SimClock
    from bt_engine.loading import load_xml
    from bt_engine.node import MissionContext
    from bt_engine.spec import MissionError

    class Raw(PortType):
        name = "raw"

        def convert(self, value):
            raise TypeError("nope")

    class Takes(SyncActionNode):
        """A port of a type that raises."""

        ports = (input_port("v", Raw(), None, "v"),)

    reg = REGISTRY.copy()
    reg.register(Takes)
    spec = load_xml("b.xml", text=wrap('<Takes v="1"/>'))
    with pytest.raises(MissionError) as info:
        build_tree(spec, reg, MissionContext(SimClock()))
    assert "b.xml:3:8: port 'v' of Takes: '1' could not be converted to raw: TypeError: nope" in (
        str(info.value)
    )


# --- F10: the watchdog says how long it waited --------------------------------------------


def test_the_watchdog_says_how_long_it_waited_on_a_busy_host(monkeypatch) -> None:
    from bt_engine import watchdog as wd

    cpus = os.cpu_count() or 1
    monkeypatch.setattr(wd.os, "getloadavg", lambda: (3.0 * cpus, 0.0, 0.0))
    stops: list[str] = []
    w = wd.TickWatchdog(0.1, real_time=False, request_stop=stops.append)
    try:
        w.start_tick(1)
        try:
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline and not stops:
                time.sleep(0.01)
        except wd.TickOverrun:
            pass
        w.end_tick()
    finally:
        w.close()
    assert stops and "did not return within 0.3 s" in stops[0], stops
    assert "(the 0.1 s budget x3.0: a busy host)" in stops[0], stops


REF_DEFAULT_PLUGIN = """from bt_engine import SyncActionNode, register, SUCCESS
from bt_engine.ports import INT, input_port, output_port


@register
class Doubles(SyncActionNode):
    ports = (
        input_port("k", INT, "{kk}", "k, from the entry kk unless given"),
        input_port("same", INT, "{=}", "from the entry of its own name"),
        output_port("o", INT, "2 k + same"),
    )

    def tick_impl(self):
        self.set_output("o", 2 * self.get_input("k") + self.get_input("same"))
        return SUCCESS
"""


def test_a_port_default_naming_an_entry_reads_that_entry(plugin_env, tmp_path) -> None:
    """``input_port("k", INT, "{kk}")`` (BehaviorTree.CPP's ``InputPort<T>("k", "{kk}")``)
    passed loading and validation, then ABORTED the run at its first tick: the text
    ``{kk}`` was converted as the value."""
    plugin_env("refdef_50:PLUGIN", REF_DEFAULT_PLUGIN + LEAF_PLUGIN_TAIL)
    mission = tmp_path / "m.xml"
    mission.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">\n'
        '<Sequence><Script code="kk := 21; same := 1"/><Doubles o="{o}"/>'
        '<Doubles k="5" o="{o2}"/></Sequence></BehaviorTree></root>'
    )
    out = tmp_path / "run"
    assert main([str(mission), "--out", str(out), "-q", "--no-report"]) == 0
    blackboard = json.loads((out / "summary.json").read_text())["blackboard"]
    assert (blackboard["o"], blackboard["o2"]) == (43, 11)


CONTRACT_PLUGIN = """from bt_engine import SyncActionNode, register, SUCCESS
from bt_engine.ports import INT, output_port


@register
class Typo(SyncActionNode):
    ports = (output_port("count", INT, "how many"),)

    def tick_impl(self):
        self.set_output("cuont", 3)
        return SUCCESS
"""


def test_a_plugin_writing_an_undeclared_output_is_stopped_where_it_writes(
    plugin_env, tmp_path
) -> None:
    """``set_output("cuont", 3)`` had returned False and dropped the value: the run ended
    SUCCESS with nothing written (``get_input`` of an undeclared port was already an
    error)."""
    plugin_env("contract_50:PLUGIN", CONTRACT_PLUGIN + LEAF_PLUGIN_TAIL)
    mission = tmp_path / "m.xml"
    mission.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">\n'
        '<Typo count="{n}"/></BehaviorTree></root>'
    )
    out = tmp_path / "run"
    assert main([str(mission), "--out", str(out), "-q", "--no-report"]) == 1
    reason = json.loads((out / "summary.json").read_text())["reason"]
    assert reason == (
        f"{mission}:2:1: Typo 'Typo': output port 'cuont' is not declared by this node "
        "(its ports: count)"
    )


def test_a_stateful_action_without_on_running_or_a_condition_without_check_is_said() -> None:
    """They loaded and validated, then ABORTED in the air with an empty
    NotImplementedError. A class without ``on_start`` (called on every first tick) or a
    condition without ``check`` is refused when it registers; ``on_running`` is needed only
    by an action that returns RUNNING, so its absence is said, located, when it does."""
    from bt_engine import StatefulActionNode

    class NoStart(StatefulActionNode):
        """Never starts."""

    class NoCheck(ConditionNode):
        """Checks nothing."""

    for cls, said in ((NoStart, "on_start"), (NoCheck, "check")):
        with pytest.raises(ValueError, match=f"{cls.__name__} does not define {said}"):
            REGISTRY.copy().register(cls)

    class NoRun(StatefulActionNode):
        """Starts, never goes on."""

        def on_start(self):
            return RUNNING

    reg = REGISTRY.copy()
    reg.register(NoRun)
    res = Runner(xml_mission(wrap("<NoRun/>"), "r.xml", registry=reg)).run(5)
    assert (res.status, res.reason) == (
        "ABORTED",
        "r.xml:3:1: NoRun 'NoRun': NoRun returned RUNNING but does not define on_running "
        "(called on every tick while it is RUNNING)",
    ), res.reason


FAULTY_HOOKS_PLUGIN = """from bt_engine import StatefulActionNode, SyncActionNode, register, RUNNING, SUCCESS


@register
class HaltRaises(StatefulActionNode):
    def on_start(self):
        return RUNNING

    def on_running(self):
        return RUNNING

    def on_halted(self):
        raise RuntimeError("boom in on_halted")


@register
class PreflightRaises(SyncActionNode):
    def preflight(self):
        raise RuntimeError("preflight exploded")

    def tick_impl(self):
        return SUCCESS
"""


def test_a_halt_or_preflight_that_raises_names_its_node_and_line(
    plugin_env, tmp_path, capsys
) -> None:
    """Both had lost where they came from: ``halting the tree failed: RuntimeError: ...``
    and ``pre-flight check failed: RuntimeError: ...`` without the node, its line or the
    plug-in's file:line, unlike the same error in a tick."""
    plugin_env("hooks_50:PLUGIN", FAULTY_HOOKS_PLUGIN + LEAF_PLUGIN_TAIL)
    plugin = tmp_path / "hooks_50.py"
    mission = tmp_path / "m.xml"
    mission.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">\n'
        "<HaltRaises/></BehaviorTree></root>"
    )
    out = tmp_path / "run"
    assert main([str(mission), "--out", str(out), "-q", "--no-report", "--max-time", "1"]) == 1
    reason = json.loads((out / "summary.json").read_text())["reason"]
    assert (
        f"halting the tree failed in HaltRaises ({mission}:2:1): RuntimeError: boom in "
        f"on_halted (raised at {plugin}:13)"
    ) in reason, reason
    mission.write_text(mission.read_text().replace("HaltRaises", "PreflightRaises"))
    assert main(["validate", str(mission)]) == 0  # a check that runs before flight only
    capsys.readouterr()
    assert main([str(mission), "--out", str(tmp_path / "run2"), "-q"]) == 2
    assert (
        f"{mission}:2:1: PreflightRaises: pre-flight check failed: RuntimeError: preflight "
        f"exploded (raised at {plugin}:19)"
    ) in capsys.readouterr().err


def test_a_keyboard_interrupt_a_node_raises_is_not_told_as_an_operators(tmp_path) -> None:
    """A plug-in raising KeyboardInterrupt in a tick had been reported as "operator
    interrupt (Ctrl-C)", without its node or line: the blame on the operator."""
    from bt_engine.node import StatefulActionNode as Stateful

    class CtrlC(Stateful):
        """Raises KeyboardInterrupt on its second tick."""

        def on_start(self):
            return RUNNING

        def on_running(self):
            raise KeyboardInterrupt

    reg = REGISTRY.copy()
    reg.register(CtrlC)
    m = xml_mission(wrap("<CtrlC/>"), "k.xml", registry=reg)
    res = Runner(m).run(5)
    assert res.status == "ABORTED"
    assert res.reason == (
        "a node raised KeyboardInterrupt in CtrlC (k.xml:3:1) (no operator interrupt came)"
    ), res.reason
