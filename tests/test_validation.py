"""Validation: every kind of bad mission is reported at once, located, and nothing runs."""

from __future__ import annotations

import re

import pytest
from helpers import wrap

from bt_engine import REGISTRY
from bt_engine.cli import main
from bt_engine.loading import load_xml
from bt_engine.validate import validate


def problems_of(xml: str) -> list[str]:
    return [str(p) for p in validate(load_xml("m.xml", text=xml), REGISTRY)]


def one(xml: str) -> str:
    found = problems_of(xml)
    assert len(found) == 1, found
    return found[0]


CASES = [
    # (body, expected location, expected fragment)
    ('<Sleeep msec="1"/>', "m.xml:3:1", "unknown node 'Sleeep'; did you mean 'Sleep'?"),
    ('<HoverMeasure t="1"/>', "m.xml:3:1", "needs its plug-in named in BTRUN_PLUGINS"),
    ('<Sleep msec="abc"/>', "m.xml:3:8", "expected a whole number, got 'abc'"),
    ("<Sleep/>", "m.xml:3:1", "Sleep needs port 'msec'"),
    ('<Sleep msec="1" colour="x"/>', "m.xml:3:17", "Sleep has no port 'colour'"),
    ('<Sleep msecs="1" msec="2"/>', "m.xml:3:8", "did you mean 'msec'?"),
    ('<AlwaysSuccess _skipif="true"/>', "m.xml:3:16", "did you mean '_skipIf'?"),
    ("<Inverter/>", "m.xml:3:1", "Inverter is a decorator node and takes 1 child; found 0"),
    (
        "<Inverter><AlwaysSuccess/><AlwaysFailure/></Inverter>",
        "m.xml:3:1",
        "takes 1 child; found 2",
    ),
    ("<Sequence/>", "m.xml:3:1", "takes at least 1 child; found 0"),
    ("<IfThenElse><AlwaysSuccess/></IfThenElse>", "m.xml:3:1", "takes 2 to 3 children; found 1"),
    ("<AlwaysSuccess><AlwaysSuccess/></AlwaysSuccess>", "m.xml:3:1", "takes no children; found 1"),
    ('<Script code="x := (1 +"/>', "m.xml:3:9", "bad script 'x := (1 +'"),
    ('<AlwaysSuccess _skipIf="a ==="/>', "m.xml:3:16", "_skipIf: bad script"),
    ('<SubTree ID="Nope"/>', "m.xml:3:10", "SubTree 'Nope' is not defined"),
    (
        '<Parallel success_count="two"><AlwaysSuccess/></Parallel>',
        "m.xml:3:11",
        "expected a whole number",
    ),
    (
        '<RunOnce then_skip="maybe"><AlwaysSuccess/></RunOnce>',
        "m.xml:3:10",
        "expected true or false",
    ),
    ('<Sleep msec="{bad key}"/>', "m.xml:3:8", "not a valid blackboard reference"),
    ('<Action ID="Sleeep" msec="1"/>', "m.xml:3:9", "unknown node 'Sleeep'"),
    ("<Action/>", "m.xml:3:1", "<Action> needs an ID"),
]


@pytest.mark.parametrize("body,where,fragment", CASES)
def test_each_problem_is_located_with_value_and_expectation(body, where, fragment):
    msg = one(wrap(body))
    assert msg.startswith(where + ": "), msg
    assert fragment in msg


def test_all_problems_are_reported_at_once():
    body = '<Sequence>\n<Sleeep/>\n<Sleep msec="x"/>\n<Inverter/>\n<SubTree ID="Q"/>\n</Sequence>'
    found = problems_of(wrap(body))
    assert len(found) == 4
    assert [int(p.split(":")[1]) for p in found] == [4, 5, 6, 7]


def test_output_port_bound_to_literal_is_an_error():
    from bt_engine.node import SyncActionNode
    from bt_engine.ports import FLOAT, output_port

    class Measure(SyncActionNode):
        """Write a measurement."""

        bt_id = "MeasureX"
        ports = (output_port("value", FLOAT, "measured value"),)

        def tick_impl(self):
            self.set_output("value", 1.0)
            from bt_engine.node import SUCCESS

            return SUCCESS

    reg = REGISTRY.copy()
    reg.register(Measure)
    spec = load_xml("m.xml", text=wrap('<MeasureX value="3"/>'))
    (p,) = validate(spec, reg)
    assert "output port 'value' of MeasureX is bound to the literal '3'" in str(p)
    assert "{value}" in str(p)
    assert not validate(load_xml("m.xml", text=wrap('<MeasureX value="{v}"/>')), reg)


def test_recursive_subtrees_are_refused():
    xml = wrap(
        '<SubTree ID="A"/>',
        '<BehaviorTree ID="A"><SubTree ID="B"/></BehaviorTree>'
        '<BehaviorTree ID="B"><SubTree ID="A"/></BehaviorTree>',
    )
    msg = one(xml)
    assert "recursive SubTree: Main -> A -> B -> A" in msg


def test_no_main_tree():
    xml = (
        '<root BTCPP_format="4"><BehaviorTree ID="A"><AlwaysSuccess/></BehaviorTree>'
        '<BehaviorTree ID="B"><AlwaysSuccess/></BehaviorTree></root>'
    )
    assert "no main tree: set main_tree_to_execute to one of A, B" in one(xml)
    xml2 = xml.replace('BTCPP_format="4"', 'BTCPP_format="4" main_tree_to_execute="C"')
    assert "main tree 'C' is not defined" in one(xml2)


def test_single_tree_without_main_attribute_is_main():
    xml = '<root BTCPP_format="4"><BehaviorTree ID="Only"><AlwaysSuccess/></BehaviorTree></root>'
    assert problems_of(xml) == []


def test_xml_syntax_error_is_located():
    msg = one("<root>\n<BehaviorTree ID='A'>\n<Sequence>\n</BehaviorTree></root>")
    assert re.match(r"m\.xml:4:\d+: XML syntax error", msg), msg


def test_dtd_and_entities_are_refused():
    xml = (
        '<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY a "aaaa"><!ENTITY b "&a;&a;&a;">]>\n'
        '<root><BehaviorTree ID="A"><AlwaysSuccess name="&b;"/></BehaviorTree></root>'
    )
    assert one(xml).startswith("m.xml:2:1: DOCTYPE, DTD and entity declarations are not allowed")


def test_external_entity_is_never_read(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOPSECRET")
    xml = (
        f'<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY x SYSTEM "file://{secret}">]>\n'
        '<root><BehaviorTree ID="A"><AlwaysSuccess name="&x;"/></BehaviorTree></root>'
    )
    found = problems_of(xml)
    assert found and "TOPSECRET" not in " ".join(found)


def test_models_of_unknown_nodes_matter_only_where_used():
    model = (
        '<TreeNodesModel><Action ID="FancyThing"><input_port name="a"/></Action></TreeNodesModel>'
    )
    assert problems_of(wrap("<AlwaysSuccess/>", model)) == []
    msg = one(wrap('<FancyThing a="1"/>', model))
    assert "declared in <TreeNodesModel> but btrun has no implementation" in msg


def test_subtree_ports_checked_against_tree_nodes_model():
    extra = (
        '<BehaviorTree ID="Scan"><AlwaysSuccess/></BehaviorTree>'
        '<TreeNodesModel><SubTree ID="Scan"><input_port name="speed"/>'
        '<output_port name="found"/></SubTree></TreeNodesModel>'
    )
    assert problems_of(wrap('<SubTree ID="Scan" speed="0.1" found="{f}"/>', extra)) == []
    assert "SubTree 'Scan' has no port 'sped'" in one(
        wrap('<SubTree ID="Scan" speed="1" sped="1" found="{f}"/>', extra)
    )
    assert "needs port 'speed'" in one(wrap('<SubTree ID="Scan" found="{f}"/>', extra))
    assert "output port 'found' of SubTree 'Scan' is bound to the literal" in one(
        wrap('<SubTree ID="Scan" speed="1" found="3"/>', extra)
    )


def test_include_loop_and_missing_include(tmp_path):
    a = tmp_path / "a.xml"
    b = tmp_path / "b.xml"
    a.write_text(
        '<root main_tree_to_execute="A"><include path="b.xml"/>'
        '<BehaviorTree ID="A"><SubTree ID="B"/></BehaviorTree></root>'
    )
    b.write_text(
        '<root><include path="a.xml"/><BehaviorTree ID="B"><AlwaysSuccess/></BehaviorTree></root>'
    )
    from bt_engine.mission import check_file

    _, problems = check_file(str(a), REGISTRY)
    assert len(problems) == 1 and "include loop: a.xml -> b.xml -> a.xml" in str(problems[0])
    b.write_text('<root><BehaviorTree ID="B"><AlwaysSuccess/></BehaviorTree></root>')
    _, problems = check_file(str(a), REGISTRY)
    assert problems == []
    a.write_text(
        '<root><include path="missing.xml"/><BehaviorTree ID="A"><AlwaysSuccess/></BehaviorTree></root>'
    )
    _, problems = check_file(str(a), REGISTRY)
    assert "included file not found" in str(problems[0])


def test_two_libraries_sharing_a_helper_read_it_once(tmp_path):
    """x.xml and y.xml both include common.xml: its tree was 'defined twice (first at' the
    very same place), so two libraries sharing a helper could not be used together."""
    from bt_engine.mission import check_file

    (tmp_path / "lib").mkdir()
    lib = '<root><include path="common.xml"/><BehaviorTree ID="{0}"><SubTree ID="Common"/></BehaviorTree></root>'
    for name in ("X", "Y"):
        (tmp_path / "lib" / f"{name.lower()}.xml").write_text(lib.format(name))
    common = '<root><BehaviorTree ID="Common"><AlwaysSuccess/></BehaviorTree></root>'
    (tmp_path / "lib" / "common.xml").write_text(common)
    main_xml = tmp_path / "main.xml"
    main_xml.write_text(
        '<root main_tree_to_execute="Main"><include path="lib/x.xml"/><include path="lib/y.xml"/>'
        '<BehaviorTree ID="Main"><Sequence><SubTree ID="X"/><SubTree ID="Y"/></Sequence>'
        "</BehaviorTree></root>"
    )
    assert check_file(str(main_xml), REGISTRY)[1] == []
    (tmp_path / "lib" / "other.xml").write_text(common)  # a second file defining it: refused
    (tmp_path / "lib" / "y.xml").write_text(lib.format("Y").replace("common.xml", "other.xml"))
    assert "tree 'Common' is defined twice" in str(check_file(str(main_xml), REGISTRY)[1][0])


def test_cli_validate_exit_code_and_no_traceback(tmp_path, capsys):
    bad = tmp_path / "bad.xml"
    bad.write_text(wrap('<Sequence><Sleeep/><Sleep msec="x"/></Sequence>'))
    good = tmp_path / "good.xml"
    good.write_text(wrap("<AlwaysSuccess/>"))
    assert main(["validate", str(good)]) == 0
    assert main(["validate", str(good), str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:3:11: unknown node 'Sleeep'" in err
    assert "2 problems found; nothing was run." in err
    assert "Traceback" not in err
    # `btrun run` refuses to fly an invalid mission with the same messages
    assert main([str(bad), "--out", str(tmp_path / "run")]) == 2
    assert not (tmp_path / "run").exists()


def test_v3_spellings_load():
    xml = (
        '<root main_tree_to_execute="Main"><BehaviorTree ID="Main"><SequenceStar>'
        '<Action ID="AlwaysSuccess"/><Condition ID="AlwaysSuccess"/>'
        '<SubTreePlus ID="S" __autoremap="1"/></SequenceStar></BehaviorTree>'
        '<BehaviorTree ID="S"><AlwaysSuccess/></BehaviorTree></root>'
    )
    assert problems_of(xml) == []


@pytest.mark.slow
def test_validate_says_what_it_builds_as_it_goes(tmp_path, monkeypatch, capsys):
    """`btrun validate --rig` builds a missing demo gallery, as a run would (for thousands
    of pallets, minutes): it says so and shows the build's progress on stderr, not minutes
    of silence; stdout keeps the verdict."""
    monkeypatch.setenv("BTRUN_CACHE_DIR", str(tmp_path))
    assert main(["validate", "--rig", "rigs/sim.yaml", "missions/pallet_scan.xml"]) == 0
    out, err = capsys.readouterr()
    assert out.strip() == "missions/pallet_scan.xml: ok"
    assert "building the demo gallery" in err and "sides enrolled in" in err
    assert err.startswith("[wall ")


@pytest.mark.parametrize(
    "argv, expected",
    [
        (
            ["vaildate", "missions/square.xml"],
            "btrun: unknown command 'vaildate' (did you mean 'validate'?)",
        ),  # fmt: skip
        (["flet", "fleets/aisle_2.yaml"], "btrun: unknown command 'flet' (did you mean 'fleet'?)"),
        (["square"], "square:1:1: mission file not found (did you mean 'missions/square.xml'?)"),
        (
            ["missions/sqare.xml"],
            "missions/sqare.xml:1:1: mission file not found (did you mean 'missions/square.xml'?)",
        ),  # fmt: skip
        (["nosuch.xml"], "nosuch.xml:1:1: mission file not found\n"),
    ],
)
def test_a_misspelt_command_or_mission_gets_a_did_you_mean(tmp_path, capsys, argv, expected):
    """`btrun MISSION` is short for `btrun run MISSION`: a word that is neither a command
    nor a file, close to a command, is said to be a misspelt command (it used to be run as
    a mission, with argparse's 'unrecognized arguments'); a missing mission file names the
    closest one by name. Nothing runs (exit 2)."""
    assert main([*argv, "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(expected) and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_converting_a_mission_that_would_not_fly_is_refused(tmp_path, capsys):
    """btrun convert wrote an invalid mission with exit 0 (later: with a warning); now its
    problems are said as validate says them, exit 2, and nothing is written."""
    from bt_engine.cli import main

    src = tmp_path / "m.xml"
    src.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Main"><Sleep msec="abc"/></BehaviorTree></root>'
    )
    assert main(["convert", str(src), str(tmp_path / "m.yaml")]) == 2
    err = capsys.readouterr().err
    assert not (tmp_path / "m.yaml").exists() and f"{src}:1:" in err, err


def test_an_entry_read_as_a_type_its_writer_cannot_give_is_refused():
    """A float written by LoopDouble and read as RunOnce's bool can never work: refused at
    the reading port, naming the writer; a float read as a whole number may (2.0) work."""
    loop = '<LoopDouble queue="1.5;2" value="{v}"><AlwaysSuccess/></LoopDouble>'
    found = one(
        wrap(f'<Sequence>{loop}\n<RunOnce then_skip="{{v}}"><AlwaysSuccess/></RunOnce></Sequence>')
    )
    assert found.startswith("m.xml:4:10: port 'then_skip' of RunOnce reads {v} as bool")
    assert "port 'value' of LoopDouble (m.xml:3:37) writes it as float" in found
    assert "no float converts to bool" in found
    assert problems_of(wrap(f'<Sequence>{loop}<Sleep msec="{{v}}"/></Sequence>')) == []
    # another tree has a blackboard of its own; {@v} is the main tree's {v}
    sub = f'<Sequence>{loop}<SubTree ID="Other"/></Sequence>'
    for entry in ("v", "@v"):
        other = f'<BehaviorTree ID="Other"><RunOnce then_skip="{{{entry}}}">'
        other += "<AlwaysSuccess/></RunOnce></BehaviorTree>"
        found = [p for p in problems_of(wrap(sub, other)) if "as bool" in p]
        assert found == [] if entry == "v" else "reads {@v} as bool" in found[0]


@pytest.mark.parametrize(
    "attr, fragment",
    [
        ('<Sleep msec="1_000"/>', "got '1_000'"),  # int("1_000") is 1000 to Python
        ('<Delay delay_msec="１０"><AlwaysSuccess/></Delay>', "got '１０'"),
        ('<Timeout msec="٣"><AlwaysSuccess/></Timeout>', "got '٣'"),
        ('<Script code="x := ١٠"/>', "unexpected character '١'"),
    ],
)
def test_numbers_python_reads_but_a_reader_would_not_are_refused(attr, fragment):
    """``max_speed="0_5"`` flew at 5 m/s: ``float`` reads ``_`` between digits, and digits
    of any script; BehaviorTree.CPP reads neither."""
    found = one(wrap(attr))
    assert ("(plain digits)" in found or "Script" in attr) and fragment in found


def test_a_set_value_is_a_number_only_when_written_as_one():
    """YAML 1.1 read ``--set n=010`` as 8, ``1:30`` as 90 and ``0_5`` as 5."""
    from bt_engine.inputs import parse_set_value
    from bt_engine.ports import FLOAT, PortValueError, Vec3Type

    assert [parse_set_value(t) for t in ("010", "1.5", "-2", "1:30", "0_5")] == [
        10,
        1.5,
        -2,
        "1:30",
        "0_5",
    ]
    for port, text in ((FLOAT, "0_5"), (FLOAT, "１０"), (Vec3Type(), "1_0;0;1")):
        with pytest.raises(PortValueError, match="plain digits"):
            port.convert(text)


def test_an_output_that_cannot_be_written_is_said_not_a_traceback(tmp_path, capsys):
    """``btrun show --output`` and ``btrun nodes --groot/--markdown`` raised on a missing
    folder or a folder; ``convert`` to a FIFO blocked for ever."""
    import os

    missing = str(tmp_path / "no" / "x.dot")
    assert main(["show", "--format", "dot", "--output", missing, "missions/square.xml"]) == 2
    assert main(["nodes", "--groot", str(tmp_path / "no" / "p.xml")]) == 2
    assert main(["nodes", "--markdown", str(tmp_path)]) == 2
    fifo = str(tmp_path / "f.xml")
    os.mkfifo(fifo)
    assert main(["convert", "missions/square.xml", fifo]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert f"btrun show: cannot write {missing}: No such file or directory" in err
    assert f"btrun nodes: cannot write {tmp_path}: a folder" in err
    assert f"cannot write {fifo}: not a regular file" in err


@pytest.mark.parametrize(
    "body, fragment",
    [
        ('<Sleep msec="-1"/>', "msec -1: expected at least 0"),
        ('<Timeout msec="-5"><AlwaysSuccess/></Timeout>', "msec -5: expected at least 0"),
        ('<Delay delay_msec="-1"><AlwaysSuccess/></Delay>', "delay_msec -1: expected at least 0"),
        (
            '<Repeat num_cycles="-2"><AlwaysSuccess/></Repeat>',
            "num_cycles -2: expected at least -1",
        ),
        (
            '<RetryUntilSuccessful num_attempts="-7"><AlwaysSuccess/></RetryUntilSuccessful>',
            "num_attempts -7: expected at least -1",
        ),
    ],
)
def test_counts_and_times_no_node_can_use_are_refused(body, fragment):
    """A negative time, or a loop count below -1 (a typo for -1, forever), was accepted: the
    Repeat then never ticked its child and succeeded."""
    assert fragment in one(wrap(body))


_GO_HOME = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence>
      <Script code="home := 1"/>
      <SubTree ID="GoHome"CALL/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="GoHome"><Sleep msec="{home}"/></BehaviorTree>
  MODEL
</root>
"""


@pytest.mark.parametrize(
    "call, model, refused",
    [
        ("", "", True),
        (' home="{home}"', "", False),
        (' home="5"', "", False),
        (' _autoremap="true"', "", False),
        (' _autoremap="True "', "", False),
        (
            "",
            '<TreeNodesModel><SubTree ID="GoHome"><input_port name="home" default="5"/>'
            "</SubTree></TreeNodesModel>",
            False,
        ),
    ],
)
def test_a_subtree_call_that_leaves_an_entry_it_reads_unset_is_refused(call, model, refused):
    """A SubTree's blackboard is its own: a call that neither passes {home} nor autoremaps
    took off and aborted at the SubTree's first read (the "nothing writes" warning counted
    the main tree's write)."""
    found = problems_of(_GO_HOME.replace("CALL", call).replace("MODEL", model))
    if not refused:
        assert found == []
        return
    assert found == [
        "m.xml:5:7: SubTree 'GoHome' reads {home} (m.xml:8:36), but this call does not pass it "
        "in and nothing in 'GoHome' writes it (a SubTree's blackboard is its own): pass it "
        '(home="{home}") or call it with _autoremap="true"'
    ]


def test_autoremap_takes_true_or_false_only():
    """``_autoremap="flase"`` was read as false, silently (BehaviorTree.CPP throws)."""
    found = problems_of(_GO_HOME.replace("CALL", ' _autoremap="flase"').replace("MODEL", ""))
    assert "m.xml:5:28: _autoremap 'flase': expected true or false" in found


def test_a_literal_given_to_a_subtree_port_counts_as_written():
    """``<SubTree ID="Sub" p="10"/>`` sets {p} inside: no "nothing writes" warning."""
    xml = wrap(
        '<SubTree ID="Sub" p="10"/>', '<BehaviorTree ID="Sub"><Sleep msec="{p}"/></BehaviorTree>'
    )
    warnings: list = []
    assert validate(load_xml("m.xml", text=xml), REGISTRY, warnings) == [] and warnings == []


def test_a_model_naming_no_tree_is_warned_and_a_port_declared_twice_refused():
    """``<SubTree ID="main">`` for tree Main lost the mission's inputs silently; a port
    declared twice kept the last."""
    model = '<TreeNodesModel><SubTree ID="main"><input_port name="h" default="1"/></SubTree></TreeNodesModel>'
    warnings: list = []
    spec = load_xml("m.xml", text=wrap("<AlwaysSuccess/>", model))
    assert validate(spec, REGISTRY, warnings) == []
    assert [str(w) for w in warnings] == [
        "m.xml:5:17: warning: <TreeNodesModel> entry SubTree 'main' names no tree of this "
        "mission (did you mean 'Main'?): its ports are no tree's inputs"
    ]
    twice = model.replace('ID="main"', 'ID="Main"').replace(
        "</SubTree>", '<input_port name="h" default="2"/></SubTree>'
    )
    assert "port 'h' of model 'Main' is declared twice" in one(wrap("<AlwaysSuccess/>", twice))


def test_a_time_limit_default_no_run_could_take_is_a_validation_error():
    """``max_time`` default="-5": btrun validate said ok and btrun run refused it."""
    model = (
        '<TreeNodesModel><SubTree ID="Main"><input_port name="max_time" type="double" '
        'default="-5"/></SubTree></TreeNodesModel>'
    )
    assert one(wrap("<AlwaysSuccess/>", model)) == (
        "m.xml:5:17: max_time: the mission's time limit must be a time in s > 0, got '-5'"
    )


def test_a_yaml_mission_is_told_in_yaml_words(tmp_path):
    """'set main_tree_to_execute' is XML: a YAML mission has a main: key."""
    from bt_engine.mission import check_file

    path = tmp_path / "m.yaml"
    path.write_text("btrun: 1\ntrees:\n  A: {AlwaysSuccess: {}}\n  B: {AlwaysSuccess: {}}\n")
    assert [str(p) for p in check_file(str(path), REGISTRY)[1]] == [
        f"{path}:1:1: no main tree: set main: to one of A, B"
    ]


def test_a_parallel_count_its_children_cannot_reach_is_warned_before_flight():
    """It aborted the run in the air, when first ticked (as BehaviorTree.CPP raises then)."""
    xml = wrap('<Parallel success_count="3"><AlwaysSuccess/><AlwaysSuccess/></Parallel>')
    warnings: list = []
    assert validate(load_xml("m.xml", text=xml), REGISTRY, warnings) == []
    assert [w.message for w in warnings] == [
        "Parallel success_count=3 but only 2 children: the run aborts when it is first ticked"
    ]


def test_a_reactive_control_with_two_waiting_children_is_warned():
    """ReactiveSequence[Hover, Hover] hovered until the mission's time limit."""
    two = '<ReactiveSequence><Sleep msec="300"/><Sleep msec="300"/></ReactiveSequence>'
    one_waits = '<ReactiveSequence><AlwaysSuccess/><Sleep msec="300"/></ReactiveSequence>'
    for body, n in ((two, 1), (one_waits, 0)):
        warnings: list = []
        assert validate(load_xml("m.xml", text=wrap(body)), REGISTRY, warnings) == []
        assert len([w for w in warnings if "children that can be RUNNING" in w.message]) == n
