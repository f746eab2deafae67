"""A literal given to a SubTree port is checked against the ports that read it inside the
SubTree (through nested SubTrees): the mistake is reported at validation, not in flight."""

from __future__ import annotations

from helpers import problems_of_xml

INNER = """
  <BehaviorTree ID="Leg">
    <SubTree ID="Inner" where="{target}" pause="{pause}"/>
  </BehaviorTree>
  <BehaviorTree ID="Inner">
    <Sequence><GoTo pose="{where}"/><Sleep msec="{pause}"/></Sequence>
  </BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="Leg"><input_port name="target"/><input_port name="pause" default="10"/></SubTree>
    <SubTree ID="Inner"><input_port name="where"/><input_port name="pause"/></SubTree>
  </TreeNodesModel>
"""


def _mission(subtree: str) -> str:
    return (
        '<root BTCPP_format="4" main_tree_to_execute="M">\n'
        '  <BehaviorTree ID="M">\n    <Sequence>\n      <TakeOff height="1"/>\n'
        f"      {subtree}\n      <Land/>\n    </Sequence>\n  </BehaviorTree>\n{INNER}</root>\n"
    )


def test_a_two_number_vector_for_a_pose_is_an_error_at_the_subtree() -> None:
    problems = problems_of_xml(_mission('<SubTree ID="Leg" target="2;0"/>'))
    assert len(problems) == 1, problems
    p = problems[0]
    assert p.startswith("m.xml:5:25: SubTree port 'target' = '2;0'"), p
    assert "port 'pose' of GoTo" in p and "Leg -> Inner" in p and "three numbers" in p


def test_non_finite_and_wrong_typed_literals_through_subtrees() -> None:
    assert problems_of_xml(_mission('<SubTree ID="Leg" target="2;0;inf"/>'))
    assert problems_of_xml(_mission('<SubTree ID="Leg" target="2;0;1" pause="soon"/>'))


def test_good_literals_and_blackboard_references_pass() -> None:
    assert problems_of_xml(_mission('<SubTree ID="Leg" target="2;0;1" pause="20"/>')) == []
    assert problems_of_xml(_mission('<SubTree ID="Leg" target="{anything}"/>')) == []


def test_a_tree_named_like_a_node_is_refused_as_btcpp_does() -> None:
    xml = (
        '<root BTCPP_format="4" main_tree_to_execute="GoTo">\n'
        '  <BehaviorTree ID="GoTo">\n    <AlwaysSuccess/>\n  </BehaviorTree>\n</root>\n'
    )
    problems = problems_of_xml(xml)
    assert any("tree 'GoTo' has the name of a node" in p for p in problems), problems


def test_a_main_tree_input_default_goes_on_the_blackboard_as_its_set_would() -> None:
    """A main-tree input's default had gone on the blackboard as text ('3') while
    ``--set laps=3`` put the number 3 there: the summary's blackboard and a plug-in
    reading the entry without a port saw two types for one value."""
    from helpers import wrap, xml_mission

    from bt_engine.inputs import typed_inputs
    from bt_engine.run_inputs import parse_sets
    from bt_engine.xml_io import load_xml

    model = """  <TreeNodesModel>
    <SubTree ID="Main">
      <input_port name="laps" default="3"/>
      <input_port name="ratio" type="double" default="1"/>
      <input_port name="on" type="bool" default="true"/>
      <input_port name="route" default="1;2;3"/>
      <input_port name="code" default="010"/>
      <input_port name="mode" default="off"/>
    </SubTree>
  </TreeNodesModel>
"""
    xml = wrap('    <Script code="total := laps + ratio" />', model)
    defaults = xml_mission(xml).blackboard
    sets = ["laps=3", "ratio=1", "on=true", "route=1;2;3", "code=010", "mode=off"]
    given, _over, problems = parse_sets(sets, None, "inline.xml")
    assert not problems and not typed_inputs(load_xml("inline.xml", text=xml), given)  # run's
    given_mission = xml_mission(xml, blackboard=given).blackboard
    for name in ("laps", "ratio", "on", "route", "code", "mode"):
        assert defaults[name] == given_mission[name], name
        assert type(defaults[name]) is type(given_mission[name]), name
    assert defaults["laps"] == 3 and defaults["ratio"] == 1.0 and defaults["on"] is True
    assert defaults["route"] == "1;2;3"  # text, as a --set of it
    assert defaults["mode"] == "off"  # not YAML 1.1's false: a text port would read "false"


def test_a_text_input_keeps_its_text_and_a_set_value_never_crashes() -> None:
    """A ``type="std::string"`` input's default ``0042`` (and ``--set pallet=0042``) had
    gone on the blackboard as the number 42; ``1e3`` stayed text (YAML 1.1 reads an
    exponent only after a dot); a list nested 500 deep had crashed ``btrun run`` with a
    RecursionError traceback after ``validate`` said ok."""
    from helpers import wrap, xml_mission

    from bt_engine.inputs import parse_set_value, typed_inputs
    from bt_engine.run_inputs import parse_sets, set_texts
    from bt_engine.xml_io import load_xml

    model = """  <TreeNodesModel>
    <SubTree ID="Main">
      <input_port name="pallet" type="std::string" default="0042"/>
      <input_port name="word" type="std::string" default="true"/>
      <input_port name="rate" default="1e3"/>
    </SubTree>
  </TreeNodesModel>
"""
    xml = wrap('    <Script code="x := rate + rate" />', model)
    bb = xml_mission(xml).blackboard
    assert bb["pallet"] == "0042" and bb["word"] == "true" and bb["rate"] == 1000.0
    sets = ["pallet=0042", "word=true", "rate=1e3"]
    given, _, problems = parse_sets(sets, None, "inline.xml")
    assert not problems
    assert not typed_inputs(load_xml("inline.xml", text=xml), given, set_texts(sets))
    assert given == {"pallet": "0042", "word": "true", "rate": 1000.0}
    deep = "[" * 500 + "]" * 500
    assert parse_set_value(deep) == deep
    assert [parse_set_value(t) for t in ("1.5e3", "-1e-05", "1e", "e3")] == [
        1500.0,
        -1e-05,
        "1e",
        "e3",
    ]
