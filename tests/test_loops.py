"""The queue loops (LoopString, LoopInt, LoopDouble, LoopBool) tick by tick on the simulated
clock: literal and blackboard queues, if_empty, halts, errors, validation and conversion.
(``test_differential_loops.py`` compares them with BehaviorTree.CPP itself.)"""

from __future__ import annotations

from collections import deque

import pytest
from helpers import wrap, xml_mission

from bt_engine import FAILURE, REGISTRY, RUNNING, SKIPPED, SUCCESS, NodeStatus
from bt_engine.catalogue import groot_palette
from bt_engine.loading import load_xml, load_yaml
from bt_engine.loops import STATUS
from bt_engine.node import NodeRuntimeError
from bt_engine.ports import INT, STRING, PortValueError, QueueType, split_queue
from bt_engine.validate import validate
from bt_engine.xml_io import dump_xml
from bt_engine.yaml_writer import dump_yaml


def ticks(m, n: int) -> list[str]:
    return [m.tick().value for _ in range(n)]


def test_literal_queue_one_item_per_tick_then_if_empty():
    m = xml_mission(
        wrap(
            '<LoopString name="l" queue="A-01-1;A-02-1;A-03-1" value="{pallet}">'
            '<Script name="log" code="seen := seen .. pallet"/></LoopString>'
        ),
        blackboard={"seen": ""},
    )
    got = []
    for _ in range(4):
        got.append((m.tick(), m.blackboard["pallet"], m.status_of("l")))
    assert got == [
        (RUNNING, "A-01-1", "RUNNING"),
        (RUNNING, "A-02-1", "RUNNING"),
        (RUNNING, "A-03-1", "RUNNING"),
        (SUCCESS, "A-03-1", "IDLE"),  # the queue is empty: if_empty; the root is reset
    ]
    assert m.blackboard["seen"] == "A-01-1A-02-1A-03-1"
    # the literal is copied afresh when the loop starts again
    assert m.tick() is RUNNING and m.blackboard["pallet"] == "A-01-1"


def test_running_child_keeps_its_item():
    m = xml_mission(
        wrap('<LoopInt name="l" queue="1;2" value="{n}"><Sleep name="z" msec="30"/></LoopInt>')
    )
    values = []
    for _ in range(8):
        m.clock.advance(0.02)
        values.append((m.tick().value, m.blackboard["n"]))
    # each Sleep lasts two 20 ms ticks; the item is popped only when the child is not RUNNING
    assert values[:5] == [
        ("RUNNING", 1),
        ("RUNNING", 1),
        ("RUNNING", 2),
        ("RUNNING", 2),
        ("SUCCESS", 2),
    ]


def test_child_failure_ends_the_loop_with_failure():
    m = xml_mission(
        wrap(
            '<LoopInt name="l" queue="1;2;3" value="{n}">'
            '<ScriptCondition name="c" code="n != 2"/></LoopInt>'
        )
    )
    assert ticks(m, 3) == ["RUNNING", "FAILURE", "RUNNING"]  # then it restarts at 1
    assert m.blackboard["n"] == 1


@pytest.mark.parametrize(
    "if_empty, status",
    [("", SUCCESS), ("FAILURE", FAILURE), ("SKIPPED", SKIPPED), ("RUNNING", RUNNING)],
)
def test_if_empty(if_empty, status):
    attr = f' if_empty="{if_empty}"' if if_empty else ""
    m = xml_mission(wrap(f'<LoopString name="l" queue=""{attr}><AlwaysFailure/></LoopString>'))
    assert m.tick() is status
    assert m.node("l").child.bt_status.value == "IDLE"  # the child was never ticked


def test_blackboard_list_is_consumed():
    m = xml_mission(
        wrap('<LoopDouble name="l" queue="{heights}" value="{h}"><AlwaysSuccess/></LoopDouble>'),
        blackboard={"heights": [0.5, "1", 2]},
    )
    seen = []
    for _ in range(4):
        status = m.tick()
        seen.append((status.value, m.blackboard["h"], m.blackboard["heights"]))
    assert seen == [
        ("RUNNING", 0.5, [1.0, 2.0]),
        ("RUNNING", 1.0, [2.0]),
        ("RUNNING", 2.0, []),
        ("SUCCESS", 2.0, []),
    ]
    assert m.tick() is SUCCESS  # consumed: nothing left for the next run


@pytest.mark.parametrize(
    "queue",
    ["a;b", ("a", "b"), deque(["a", "b"]), ["a", "b"]],
    ids=["text", "tuple", "deque", "list"],
)
def test_blackboard_queue_forms(queue):
    m = xml_mission(
        wrap('<LoopString name="l" queue="{q}" value="{v}"><AlwaysSuccess/></LoopString>'),
        blackboard={"q": queue},
    )
    assert m.tick() is RUNNING and m.blackboard["v"] == "a" and m.blackboard["q"] == ["b"]


def test_a_script_refills_a_blackboard_queue():
    m = xml_mission(
        wrap(
            "<Sequence><Script code=\"q := '3;4'\"/>"
            '<LoopInt queue="{q}" value="{v}"><Script code="total += v"/></LoopInt></Sequence>'
        ),
        blackboard={"total": 0},
    )
    assert ticks(m, 6) == ["RUNNING", "RUNNING", "SUCCESS"] * 2
    assert m.blackboard["total"] == 14


def test_halt_restarts_a_literal_queue_but_not_a_blackboard_one():
    body = (
        '<Parallel success_count="2"><LoopString name="lit" queue="a;b;c" value="{x}">'
        '<Sleep msec="1000"/></LoopString><LoopString name="bb" queue="{q}" value="{y}">'
        '<Sleep msec="1000"/></LoopString></Parallel>'
    )
    m = xml_mission(wrap(body), blackboard={"q": ["a", "b", "c"]})
    assert m.tick() is RUNNING and (m.blackboard["x"], m.blackboard["y"]) == ("a", "a")
    m.halt()  # both loops halted while their child runs: item "a" is lost for the second
    assert m.node("lit").bt_status.value == "IDLE" and m.blackboard["q"] == ["b", "c"]
    assert m.tick() is RUNNING and (m.blackboard["x"], m.blackboard["y"]) == ("a", "b")


def test_unusable_blackboard_queues_raise_located_errors():
    xml = wrap('<LoopInt name="l" queue="{q}" value="{v}"><AlwaysSuccess/></LoopInt>')
    with pytest.raises(NodeRuntimeError, match=r"inline.xml:\d+:\d+: .*\{q\}, which is not set"):
        xml_mission(xml).tick()
    with pytest.raises(NodeRuntimeError, match=r"item 2 of the queue: expected a whole number"):
        xml_mission(xml, blackboard={"q": [1, "two"]}).tick()
    with pytest.raises(NodeRuntimeError, match="which is None"):
        xml_mission(xml, blackboard={"q": None}).tick()
    with pytest.raises(NodeRuntimeError, match="expected a queue"):
        xml_mission(xml, blackboard={"q": {"a": 1}}).tick()


def test_split_queue_is_btcpp_split_string():
    assert split_queue("") == []
    assert split_queue("a") == ["a"]
    assert split_queue("a;b;") == ["a", "b"]
    assert split_queue("a;;b") == ["a", "", "b"]
    assert split_queue(";") == [""]
    assert split_queue(" a ; b") == [" a ", " b"]  # texts keep their spaces, as in BT.CPP


def test_queue_and_status_types():
    q = QueueType(INT)
    assert q.convert("1;2;3") == [1, 2, 3] and q.convert([1, "2"]) == [1, 2]
    assert q.convert(7) == [7] and q.convert("") == []
    assert q.to_text([1, 2]) == "1;2" and q.to_yaml([1, 2]) == [1, 2]
    with pytest.raises(PortValueError, match="item 2 of the queue"):
        q.convert("1;x")
    with pytest.raises(PortValueError, match="contains ';'"):
        QueueType(STRING).convert(["a;b"])
    assert STATUS.convert("failure") is FAILURE and STATUS.convert(SKIPPED) is SKIPPED
    for bad in ("IDLE", NodeStatus.IDLE, "done", 2):
        with pytest.raises(PortValueError):
            STATUS.convert(bad)


def test_validation():
    def problems(body: str) -> list[str]:
        return [str(p) for p in validate(load_xml("m.xml", text=wrap(body)), REGISTRY)]

    assert problems('<LoopString queue="a;b"><AlwaysSuccess/></LoopString>') == []
    assert problems('<LoopString queue="{q}" value="{v}"><AlwaysSuccess/></LoopString>') == []
    (missing,) = problems('<LoopString value="{v}"><AlwaysSuccess/></LoopString>')
    assert "LoopString needs port 'queue'" in missing
    (bad_item,) = problems('<LoopInt queue="1;x"><AlwaysSuccess/></LoopInt>')
    assert "port 'queue' of LoopInt: item 2 of the queue" in bad_item
    (bad_status,) = problems('<LoopInt queue="1" if_empty="IDLE"><AlwaysSuccess/></LoopInt>')
    assert "port 'if_empty' of LoopInt: expected SUCCESS, FAILURE, SKIPPED or RUNNING" in (
        bad_status
    )
    (literal_out,) = problems('<LoopInt queue="1" value="3"><AlwaysSuccess/></LoopInt>')
    assert "output port 'value' of LoopInt is bound to the literal" in literal_out
    (no_child,) = problems('<LoopBool queue="true"/>')
    assert "LoopBool is a decorator node and takes 1 child; found 0" in no_child


def test_yaml_and_xml_spellings_convert_both_ways():
    yaml_text = (
        "btrun: 1\ntrees:\n  Main:\n    LoopString:\n      queue: [A-01, A-02]\n"
        '      value: "{p}"\n      child: AlwaysSuccess\n'
    )
    spec = load_yaml("m.yaml", text=yaml_text)
    assert validate(spec, REGISTRY) == []
    xml = dump_xml(spec)
    assert 'queue="A-01;A-02"' in xml
    back = dump_yaml(load_xml("m.xml", text=xml), REGISTRY)
    assert "queue: [A-01, A-02]" in back
    m = xml_mission(xml)
    assert m.tick() is RUNNING and m.blackboard["p"] == "A-01"


def test_catalogue_shows_the_ports():
    model = REGISTRY.get("LoopString")
    assert model.kind == "Decorator" and model.category == "built-in"
    queue = model.ports["queue"]
    assert queue.direction == "inout" and queue.required and queue.takes_literal
    palette = groot_palette(REGISTRY, include_builtins=True)
    assert '<inout_port name="queue" type="string queue">' in palette
    assert '<input_port name="if_empty" type="NodeStatus" default="SUCCESS">' in palette
