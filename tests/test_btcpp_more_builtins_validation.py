"""The BehaviorTree.CPP built-ins Precondition, Switch2..Switch6, AsyncSequence, AsyncFallback,
UnsetBlackboard, SkipUnlessUpdated, WaitValueUpdate and WasEntryUpdated: declared ports and
located validation errors, XML <-> YAML conversion, the catalogue and the Groot2 palette, and
the blackboard's sequence ids (their behaviour is compared with BehaviorTree.CPP in
``test_btcpp_more_builtins.py``)."""

from __future__ import annotations

import pytest
from helpers import wrap, xml_mission

from bt_engine import FAILURE, REGISTRY, RUNNING, SKIPPED, SUCCESS
from bt_engine.blackboard import Scope
from bt_engine.catalogue import catalogue_text, groot_palette
from bt_engine.cli import main
from bt_engine.loading import load_xml, load_yaml
from bt_engine.node import NodeRuntimeError
from bt_engine.switch import check_string_equality, port_text
from bt_engine.validate import validate
from bt_engine.xml_io import dump_xml
from bt_engine.yaml_writer import dump_yaml

NEW = (
    "Precondition",
    "Switch2",
    "Switch3",
    "Switch4",
    "Switch5",
    "Switch6",
    "AsyncSequence",
    "AsyncFallback",
    "UnsetBlackboard",
    "SkipUnlessUpdated",
    "WaitValueUpdate",
    "WasEntryUpdated",
)


def problems(body: str) -> list[str]:
    return [str(p) for p in validate(load_xml("m.xml", text=wrap(body)), REGISTRY)]


def test_registered_as_builtins_with_btcpp_ports():
    ports = {
        "Precondition": {"if": None, "else": "FAILURE"},
        "Switch2": {"variable": None, "case_1": None, "case_2": None},
        "Switch6": {"variable": None, **{f"case_{k}": None for k in range(1, 7)}},
        "AsyncSequence": {},
        "AsyncFallback": {},
        "UnsetBlackboard": {"key": None},
        "SkipUnlessUpdated": {"entry": None},
        "WaitValueUpdate": {"entry": None},
        "WasEntryUpdated": {"entry": None},
    }
    for node_id in NEW:
        model = REGISTRY.get(node_id)
        assert model is not None and model.category == "built-in", node_id
    for node_id, want in ports.items():
        model = REGISTRY.get(node_id)
        got = {
            p.name: (p.default if isinstance(p.default, str) else None)
            for p in model.ports.values()
        }
        assert got == want, node_id
        assert all(p.direction == "input" for p in model.ports.values())
    assert REGISTRY.get("Precondition").ports["if"].required
    assert not REGISTRY.get("Switch3").ports["variable"].required  # BT.CPP: default branch
    assert (REGISTRY.get("Switch4").min_children, REGISTRY.get("Switch4").max_children) == (5, 5)
    assert REGISTRY.get("WasEntryUpdated").kind == "Action"
    assert REGISTRY.get("UnsetBlackboard").kind == "Action"


def test_precondition_no_longer_suggested_as_script_condition():
    assert problems('<Precondition if="true"><AlwaysSuccess/></Precondition>') == []
    (unknown,) = problems('<Precondtion if="true"><AlwaysSuccess/></Precondtion>')
    assert "did you mean 'Precondition'?" in unknown


CASES = [
    # (body, location, fragment)
    ("<Precondition><AlwaysSuccess/></Precondition>", "m.xml:3:1", "needs port 'if'"),
    (
        '<Precondition if="x := (1 +"><AlwaysSuccess/></Precondition>',
        "m.xml:3:15",
        "port 'if' of Precondition: bad script 'x := (1 +'",
    ),
    ('<Precondition if="1 / 0"><AlwaysSuccess/></Precondition>', "m.xml:3:15", "bad script"),
    (
        '<Precondition if="true" else="IDLE"><AlwaysSuccess/></Precondition>',
        "m.xml:3:25",
        "port 'else' of Precondition: expected SUCCESS, FAILURE, SKIPPED or RUNNING",
    ),
    ('<Precondition if="true"/>', "m.xml:3:1", "takes 1 child; found 0"),
    (
        '<Precondition if="true" iff="x"><AlwaysSuccess/></Precondition>',
        "m.xml:3:25",
        "Precondition has no port 'iff'",
    ),
    (
        '<Switch2 variable="a" case_1="a"><AlwaysSuccess/><AlwaysSuccess/></Switch2>',
        "m.xml:3:1",
        "Switch2 is a control node and takes 3 children; found 2",
    ),
    (
        '<Switch2 variable="a" case_3="a"><AlwaysSuccess/><AlwaysSuccess/><AlwaysSuccess/>'
        "</Switch2>",
        "m.xml:3:23",
        "Switch2 has no port 'case_3'",
    ),
    (
        '<Switch3 variable="{bad key}"><AlwaysSuccess/><AlwaysSuccess/><AlwaysSuccess/>'
        "<AlwaysSuccess/></Switch3>",
        "m.xml:3:10",
        "not a valid blackboard reference",
    ),
    ("<AsyncSequence/>", "m.xml:3:1", "takes at least 1 child; found 0"),
    ('<AsyncFallback x="1"><AlwaysSuccess/></AsyncFallback>', "m.xml:3:16", "has no port 'x'"),
    ("<UnsetBlackboard/>", "m.xml:3:1", "UnsetBlackboard needs port 'key'"),
    (
        '<UnsetBlackboard key="a"><AlwaysSuccess/></UnsetBlackboard>',
        "m.xml:3:1",
        "takes no children; found 1",
    ),
    (
        "<SkipUnlessUpdated><AlwaysSuccess/></SkipUnlessUpdated>",
        "m.xml:3:1",
        "SkipUnlessUpdated needs port 'entry'",
    ),
    (
        '<WaitValueUpdate entry=""><AlwaysSuccess/></WaitValueUpdate>',
        "m.xml:3:18",
        "port 'entry' of WaitValueUpdate: expected an entry name",
    ),
    ('<WasEntryUpdated entry="a" value="1"/>', "m.xml:3:28", "has no port 'value'"),
    (
        '<SkipUnlessUpdated entry="a"><AlwaysSuccess/><AlwaysSuccess/></SkipUnlessUpdated>',
        "m.xml:3:1",
        "takes 1 child; found 2",
    ),
]


@pytest.mark.parametrize("body, where, fragment", CASES)
def test_bad_ports_are_located_errors(body, where, fragment):
    found = problems(body)
    assert len(found) == 1, found
    assert found[0].startswith(where + ":"), found
    assert fragment in found[0], found


def test_good_files_validate():
    for body in (
        '<Precondition if="a &gt; 1" else="SKIPPED"><AlwaysSuccess/></Precondition>',
        '<Precondition if="{code}"><AlwaysSuccess/></Precondition>',
        '<Switch2 variable="{v}" case_1="1" case_2="{w}"><AlwaysSuccess/><AlwaysSuccess/>'
        "<AlwaysFailure/></Switch2>",
        "<Switch2><AlwaysSuccess/><AlwaysSuccess/><AlwaysFailure/></Switch2>",
        "<AsyncSequence><AlwaysSuccess/></AsyncSequence>",
        '<UnsetBlackboard key="{k}"/>',
        '<SkipUnlessUpdated entry="v"><AlwaysSuccess/></SkipUnlessUpdated>',
        '<WaitValueUpdate entry="{@v}"><AlwaysSuccess/></WaitValueUpdate>',
        '<WasEntryUpdated entry="{v}"/>',
    ):
        assert problems(body) == [], body


def test_validate_cli_reports_located_errors(tmp_path, capsys):
    path = tmp_path / "m.xml"
    path.write_text(wrap('<Switch2 variable="a"><AlwaysSuccess/></Switch2>'))
    assert main(["validate", str(path)]) != 0
    err = capsys.readouterr().err
    assert f"{path}:3:1:" in err and "takes 3 children; found 1" in err


def test_yaml_and_xml_convert_both_ways():
    xml = wrap(
        '<Sequence><Precondition if="n &gt; 1" else="SKIPPED"><AlwaysSuccess/></Precondition>'
        '<Switch2 variable="{n}" case_1="1" case_2="2"><AlwaysSuccess/><AlwaysFailure/>'
        "<AlwaysSuccess/></Switch2><AsyncFallback><AlwaysFailure/><AlwaysSuccess/>"
        '</AsyncFallback><SkipUnlessUpdated entry="{n}"><WasEntryUpdated entry="n"/>'
        '</SkipUnlessUpdated><UnsetBlackboard key="n"/></Sequence>'
    )
    spec = load_xml("m.xml", text=xml)
    assert validate(spec, REGISTRY) == []
    yaml_text = dump_yaml(spec, REGISTRY)
    back = load_yaml("m.yaml", text=yaml_text)
    assert validate(back, REGISTRY) == []
    again = dump_xml(back)
    for fragment in (
        '<Precondition if="n &gt; 1" else="SKIPPED">',
        '<Switch2 variable="{n}" case_1="1" case_2="2">',
        "<AsyncFallback>",
        '<SkipUnlessUpdated entry="{n}">',
        '<WasEntryUpdated entry="n"/>',
        '<UnsetBlackboard key="n"/>',
    ):
        assert fragment in again, (fragment, again)


def test_convert_command(tmp_path):
    src = tmp_path / "m.xml"
    src.write_text(
        wrap(
            '<Switch3 variable="b" case_1="a" case_2="b" case_3="c"><AlwaysFailure/>'
            "<AlwaysSuccess/><AlwaysFailure/><AlwaysFailure/></Switch3>"
        )
    )
    out = tmp_path / "m.yaml"
    assert main(["convert", str(src), str(out)]) == 0
    m = xml_mission(dump_xml(load_yaml(str(out), text=out.read_text())))
    assert m.tick() is SUCCESS


def test_catalogue_and_groot_palette():
    text = catalogue_text(REGISTRY)
    for node_id in NEW:
        assert f"  {node_id} " in text, node_id
    palette = groot_palette(REGISTRY, include_builtins=True)
    assert '<Decorator ID="Precondition">' in palette
    assert '<input_port name="if" type="std::string">' in palette
    assert '<input_port name="else" type="NodeStatus" default="FAILURE">' in palette
    assert '<Control ID="Switch6">' in palette and 'name="case_6" type="std::string"' in palette
    assert '<Control ID="AsyncSequence"' in palette
    assert '<Action ID="UnsetBlackboard">' in palette
    assert '<Decorator ID="WaitValueUpdate">' in palette
    assert '<input_port name="entry">' in palette  # BT::Any: no type
    assert "Precondition" not in groot_palette(REGISTRY)  # Groot2 knows the built-ins


def test_sequence_ids():
    root = Scope("", namespace="/btrun/test_sequence_ids")
    try:
        assert root.sequence_id("a") == 0
        root.set("a", 1)
        root.set("a", 1)  # the same value is a write too
        assert root.sequence_id("a") == 2
        sub = Scope("sub", parent=root, remap={"x": "a"})
        sub.set("x", 3)
        assert root.sequence_id("a") == 3 and sub.sequence_id("x") == 3
        assert sub.sequence_id("@a") == 3
        sub.unset_local("x")  # remapped: left alone
        assert root.get("a") == 3
        sub.set("own", 1)
        sub.unset_local("own")
        assert not sub.has("own") and sub.sequence_id("own") == 0
        root.unset_local("a")
        assert root.sequence_id("a") == 0
        root.set("a", 5)
        assert root.sequence_id("a") == 1  # a new entry counts from 0 again, as in BT.CPP
        root._store[root.prefix + "lit"] = "0.07"  # how the builder stores a SubTree literal
        assert root.sequence_id("lit") == 1
        root.set("lit", "0.08")
        assert root.sequence_id("lit") == 2
        root.unset("lit")
        assert root.sequence_id("lit") == 0
    finally:
        root.clear()
    assert not any(k.startswith(root.prefix) for k in root.seq)


def test_nodes_in_a_mission():
    m = xml_mission(
        wrap(
            '<Sequence><Script code="n := 2"/><Switch2 variable="{n}" case_1="1" case_2="2.0">'
            '<AlwaysFailure/><Script code="hit := 1"/><AlwaysFailure/></Switch2>'
            '<UnsetBlackboard key="n"/><WaitValueUpdate entry="n"><AlwaysSuccess/>'
            "</WaitValueUpdate></Sequence>"
        )
    )
    assert m.tick() is RUNNING  # n was removed: WaitValueUpdate waits for it
    assert m.blackboard["hit"] == 1 and "n" not in m.blackboard
    m.blackboard["n"] = 7
    assert m.tick() is SUCCESS  # the Sequence resumes at WaitValueUpdate: n was written


def test_precondition_status_from_the_blackboard_and_script_errors():
    m = xml_mission(
        wrap('<Precondition if="false" else="{st}"><AlwaysFailure/></Precondition>'),
        blackboard={"st": "skipped"},
    )
    assert m.tick() is SKIPPED
    m = xml_mission(wrap('<Precondition if="missing == 1"><AlwaysSuccess/></Precondition>'))
    with pytest.raises(NodeRuntimeError, match="m.xml|Precondition"):
        m.tick()
    m = xml_mission(
        wrap(
            '<Sequence><Script code="c := \'x := (\'"/><Precondition if="{c}">'
            "<AlwaysSuccess/></Precondition></Sequence>"
        )
    )
    with pytest.raises(NodeRuntimeError, match="bad script"):
        m.tick()
    m = xml_mission(wrap('<Precondition if="true"><AlwaysFailure/></Precondition>'))
    assert m.tick() is FAILURE


def test_string_equality_and_port_text():
    assert check_string_equality("a", "a") and not check_string_equality("a", "b")
    assert check_string_equality("1.5", "1")  # BT.CPP 4.8: the leading int of each text
    assert check_string_equality("FIXED", "2", {"FIXED": 2})
    assert not check_string_equality("1e-310", "0")  # std::stod underflow throws
    assert port_text(True) == "1" and port_text(3) == "3" and port_text(1.5) == "1.500000"
    assert port_text([1]) is None
