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
