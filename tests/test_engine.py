"""The engine, tick by tick on a simulated clock: statuses, blackboard scopes, timing."""

from __future__ import annotations

import json

import pytest
from helpers import wrap, xml_mission

from bt_engine import (
    REGISTRY,
    RUNNING,
    SUCCESS,
    Runner,
    SimClock,
    StatefulActionNode,
)
from bt_engine.ticklog import TickLog, read_log


def test_sequence_resumes_at_running_child_tick_by_tick():
    m = xml_mission(
        wrap(
            '<Sequence name="main"><Script code="n := 0"/><Sleep name="nap" msec="60"/>'
            '<Script name="after" code="n := n + 1"/></Sequence>'
        )
    )
    run = Runner(m, rate_hz=50)
    assert run.step() is RUNNING  # t=0.02: nap starts, until 0.08
    assert m.status_of("nap") == "RUNNING"
    assert m.status_of("after") == "IDLE"
    assert m.blackboard["n"] == 0
    run.step()
    run.step()  # t=0.06
    assert m.status_of("nap") == "RUNNING"
    assert run.step() is SUCCESS  # t=0.08
    assert m.blackboard["n"] == 1
    # the Sequence reset its children and the root went back to IDLE, as in BT.CPP
    assert m.status_of("main") == "IDLE" and m.status_of("nap") == "IDLE"


def test_timeout_fails_and_halts_child_on_the_simulated_clock():
    m = xml_mission(
        wrap('<Timeout name="limit" msec="100"><Sleep name="long" msec="1000"/></Timeout>')
    )
    run = Runner(m, rate_hz=100)
    ticks = run.run_until(lambda mm: mm.status.value != "RUNNING", max_ticks=50)
    assert m.status.value == "FAILURE"
    assert ticks == 11  # started at t=0.01, expired at t>=0.11
    assert m.status_of("long") == "IDLE"
    assert m.clock.now() == pytest.approx(0.11)


def test_delay_waits_on_mission_clock():
    m = xml_mission(wrap('<Delay delay_msec="50"><AlwaysSuccess/></Delay>'))
    run = Runner(m, rate_hz=100)
    assert run.run_until(lambda mm: mm.status is SUCCESS, 20) == 6


def test_subtree_remapping_literals_and_isolation():
    extra = (
        '<BehaviorTree ID="Inc"><Sequence><Script code="out := inp + 1"/>'
        '<Script code="private := 42"/></Sequence></BehaviorTree>'
    )
    m = xml_mission(
        wrap(
            '<Sequence><Script code="a := 1"/>'
            '<SubTree ID="Inc" inp="{a}" out="{b}"/>'
            '<SubTree ID="Inc" inp="10" out="{c}"/></Sequence>',
            extra,
        )
    )
    m.tick()
    assert m.blackboard["b"] == 2
    assert m.blackboard["c"] == 11  # the literal "10" converts in arithmetic
    assert "private" not in m.blackboard  # stays inside the subtree's scope
    assert any(k.endswith("/private") for k in m.blackboard)


def test_autoremap_shares_entries_except_private_ones():
    extra = (
        '<BehaviorTree ID="Set"><Sequence><Script code="shared := 5"/>'
        '<Script code="_mine := 1"/></Sequence></BehaviorTree>'
    )
    m = xml_mission(wrap('<SubTree ID="Set" _autoremap="true"/>', extra))
    m.tick()
    assert m.blackboard["shared"] == 5
    assert "_mine" not in m.blackboard


def test_root_reference_from_a_subtree():
    extra = '<BehaviorTree ID="S"><Script code="@top := 7"/></BehaviorTree>'
    m = xml_mission(wrap('<SubTree ID="S"/>', extra))
    m.tick()
    assert m.blackboard["top"] == 7


def test_two_missions_in_one_process_do_not_share_entries():
    xml = wrap('<Script code="x := x + 1"/>')
    a = xml_mission(xml, blackboard={"x": 1})
    b = xml_mission(xml, blackboard={"x": 100})
    a.tick()
    a.tick()
    b.tick()
    assert a.blackboard["x"] == 3 and b.blackboard["x"] == 101
    a.close()
    assert "x" not in a.blackboard and b.blackboard["x"] == 101


def test_pre_and_post_conditions():
    m = xml_mission(
        wrap(
            '<Sequence><AlwaysSuccess name="skipped" _skipIf="flag"/>'
            '<AlwaysFailure name="forced" _successIf="flag" _onSuccess="done := true"/>'
            '<AlwaysSuccess name="post" _post="count := count + 1"/></Sequence>'
        ),
        blackboard={"flag": True, "count": 0},
    )
    recorder = Runner(m)
    assert recorder.step() is SUCCESS
    assert m.blackboard["done"] is True and m.blackboard["count"] == 1
    # as in BT.CPP, a skipped node keeps its previous status; only its parent sees SKIPPED
    assert m.status_of("skipped") == "IDLE"
    assert "Main/Sequence/skipped" not in recorder.trace[-1].get("done", {})


def test_while_precondition_halts_running_node():
    m = xml_mission(wrap('<Sleep name="s" msec="1000" _while="go"/>'), blackboard={"go": True})
    run = Runner(m)
    run.step()
    assert m.status_of("s") == "RUNNING"
    m.blackboard["go"] = False
    run.step()
    assert m.status.value == "SKIPPED"


def test_node_lookup_by_name_and_path_and_errors():
    m = xml_mission(
        wrap(
            '<Sequence name="root"><AlwaysSuccess/><AlwaysSuccess/>'
            '<Sleep name="nap" msec="1"/></Sequence>'
        )
    )
    assert m.node("nap").path == "Main/root/nap"
    assert m.node("Main/root/AlwaysSuccess[1]").bt_id == "AlwaysSuccess"
    with pytest.raises(KeyError, match="ambiguous"):
        m.node("AlwaysSuccess")
    with pytest.raises(KeyError, match="no node"):
        m.node("nope")


def test_missing_blackboard_input_aborts_with_located_message():
    m = xml_mission(wrap('<Sleep msec="{delay}"/>'), path="missions/x.xml")
    result = Runner(m).run(max_time_s=1)
    assert result.status == "ABORTED"
    assert result.reason.startswith(
        "missions/x.xml:3:1: Sleep 'Sleep': input port 'msec' reads "
        "blackboard entry {delay}, which is not set"
    )


class Exploding(StatefulActionNode):
    """Raises on its second tick (a bug in a leaf)."""

    bt_id = "Exploding"

    def on_start(self):
        return RUNNING

    def on_running(self):
        raise ZeroDivisionError("boom")


def test_exception_in_a_leaf_aborts_and_halts():
    reg = REGISTRY.copy()
    reg.register(Exploding)
    m = xml_mission(
        wrap('<Parallel success_count="2"><Exploding/><Sleep name="s" msec="5000"/></Parallel>'),
        registry=reg,
    )
    run = Runner(m)
    result = run.run(max_time_s=10)
    assert result.status == "ABORTED"
    assert "internal error in Exploding (inline.xml:3:29): ZeroDivisionError: boom" in result.reason
    assert "Traceback" in run.error_traceback
    assert m.status_of("s") == "IDLE"  # halted


class Exiting(StatefulActionNode):
    """Calls sys.exit on its second tick (a plug-in written as a script)."""

    bt_id = "Exiting"

    def on_start(self):
        return RUNNING

    def on_running(self):
        import sys

        sys.exit(7)


def test_sys_exit_in_a_leaf_aborts_halts_and_lands_instead_of_ending_btrun():
    """A plug-in's sys.exit() in a tick went past the runner: btrun ended with the drone in
    the air (only its guard was left to land it) and wrote no summary of its own."""
    reg = REGISTRY.copy()
    reg.register(Exiting)
    m = xml_mission(
        wrap('<Parallel success_count="2"><Exiting/><Sleep name="s" msec="5000"/></Parallel>'),
        registry=reg,
    )
    result = Runner(m).run(max_time_s=10)
    assert result.status == "ABORTED"
    assert result.reason == "a node called sys.exit(7) in Exiting (inline.xml:3:29)"
    assert m.status_of("s") == "IDLE"  # halted


def test_interrupt_halts_and_calls_shutdown_hooks():
    calls = []

    class Hook:
        def before_tick(self, t):
            calls.append(("before", round(t, 3)))

        def shutdown(self, reason):
            calls.append(("shutdown", reason))

    m = xml_mission(wrap('<Sleep name="s" msec="100000"/>'))
    run = Runner(m, rate_hz=10, hooks=[Hook()])
    run.on_tick = lambda r: r.interrupt() if r.mission.ticks == 3 else None
    result = run.run()
    assert result.status == "ABORTED" and "Ctrl-C" in result.reason
    assert calls[:3] == [("before", 0.1), ("before", 0.2), ("before", 0.3)]
    assert calls[-1][0] == "shutdown"
    assert m.status_of("s") == "IDLE"


def test_tick_log_is_flushed_per_tick_and_replayable(tmp_path):
    m = xml_mission(wrap('<Sequence><Script code="a := 1"/><Sleep msec="40"/></Sequence>'))
    path = tmp_path / "ticks.jsonl"
    log = TickLog(str(path), {"nodes": [[n.path, n.name, 0, []] for n in m.nodes]})
    run = Runner(m, log=log)
    run.step()
    # readable before the run ends: nothing is buffered in the process
    lines = path.read_text().splitlines()
    assert len(lines) == 2 and json.loads(lines[1])["bb"] == {"a": 1}
    run.run()
    header, recs = read_log(str(path))
    assert recs[-1]["status"] == "SUCCESS"
    from bt_engine.replay import states_at

    st, bb = states_at(header, recs, 1)
    assert st[0] == "RUNNING" and bb == {"a": 1}


def test_same_mission_same_trace():
    xml = wrap(
        '<Repeat num_cycles="3"><Sequence><Script code="i := i + 1"/><Sleep msec="30"/>'
        "</Sequence></Repeat>"
    )
    traces = []
    for _ in range(2):
        m = xml_mission(xml, blackboard={"i": 0})
        r = Runner(m)
        r.run()
        traces.append(r.trace)
    assert traces[0] == traces[1]
    assert traces[0][-1]["status"] == "SUCCESS"


def test_py_trees_can_display_a_btrun_tree():
    import py_trees

    m = xml_mission(wrap('<Sequence name="s"><AlwaysSuccess/></Sequence>'))
    m.tick()
    text = py_trees.display.unicode_tree(m.root, show_status=True)
    assert "s" in text


def test_clock_is_injected_not_read_from_time():
    clock = SimClock(start_s=100.0)
    mm = xml_mission(wrap('<Sleep msec="500"/>'), clock=clock)
    r = Runner(mm, rate_hz=10)
    r.run()
    assert clock.now() == pytest.approx(100.6)


def test_changes_are_net_complete_and_bounded(tmp_path):
    """A leaf that goes IDLE->SUCCESS->IDLE within a tick is 'done', not 'changed'; a tick
    log record keeps every change of a large tree; undrained changes do not pile up."""
    body = (
        "<ReactiveSequence>"
        + "<AlwaysSuccess/>" * 1500
        + '<Sleep name="s" msec="1000"/></ReactiveSequence>'
    )
    m = xml_mission(wrap(body))
    log = TickLog(str(tmp_path / "t.jsonl"))
    run = Runner(m, log=log)
    run.step()
    first = run.trace[-1]
    assert len(first["changed"]) == 2  # the ReactiveSequence and the Sleep
    assert len(first["done"]) == 1500
    run.step()
    assert "changed" not in run.trace[-1]
    log.close()
    _, recs = read_log(str(tmp_path / "t.jsonl"))
    assert len(recs[0]["done"]) == 1500
    for _ in range(20):
        m.tick()  # nobody drains
    assert len(m._changes) <= 3100  # one tick worth, not twenty


def test_a_handled_failure_is_still_the_reason_when_the_tree_fails_later():
    # the cause fails in one tick, the fallback's clean-up runs for two more, then the tree
    # fails through a decorator: the reason names the leaf that caused it
    m = xml_mission(
        wrap(
            '<Fallback><AlwaysFailure name="cause"/>'
            '<ForceFailure><Sequence><Delay delay_msec="20"><AlwaysSuccess/></Delay>'
            '<AlwaysSuccess name="cleanup"/></Sequence></ForceFailure></Fallback>'
        )
    )
    run = Runner(m, rate_hz=100)
    result = run.run(max_time_s=1.0)
    assert result.status == "FAILURE" and m.ticks >= 3
    assert m.last_failure.startswith("AlwaysFailure 'cause' failed")
