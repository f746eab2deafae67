"""The hand-writable YAML mission format: loading, located problems, dumping, conversion."""

from __future__ import annotations

import os

import pytest

import bt_engine  # noqa: F401  (registers the built-in nodes)
from bt_engine import yaml_io
from bt_engine.clock import SimClock
from bt_engine.loading import convert_file, load_xml, load_yaml
from bt_engine.mission import Mission, load_spec
from bt_engine.node import SUCCESS, SyncActionNode
from bt_engine.ports import FLOAT, PATH, VEC3, EnumType, input_port, output_port
from bt_engine.registry import REGISTRY
from bt_engine.validate import validate
from bt_engine.xml_io import dump_xml
from bt_engine.yaml_writer import dump_yaml

YAW = EnumType("YawMode", {"KEEP_YAW": 0, "PATH_FACING": 1, "FIXED_YAW": 2})


class _Fly(SyncActionNode):
    """A test leaf with typed ports."""

    bt_id = "TestFly"
    ports = (
        input_port("pose", VEC3, description="target"),
        input_port("path", PATH, default=None),
        input_port("speed", FLOAT, 0.5),
        input_port("yaw_mode", YAW, "KEEP_YAW"),
        output_port("reached"),
    )

    def tick_impl(self):
        return SUCCESS


REG = REGISTRY.copy()
REG.register(_Fly)


def write(tmp_path, name: str, text: str) -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def problems_of(tmp_path, text: str, name: str = "m.yaml"):
    return load_yaml(write(tmp_path, name, text)).load_problems


EXAMPLE = """\
# Survey mission
# (header)

btrun: 1
main: Main
trees:
  # the main tree
  Main:
    Sequence:
      name: mission
      children:
        # go up first
        - TestFly: {pose: [1, 2, 0.5], yaw_mode: FIXED_YAW}
        - TestFly: {name: approach, pose: "{target}", speed: {scan_speed}}
        - Timeout:
            msec: 5000
            child:
              AlwaysSuccess:
        - SubTree: {ID: Scan, speed: "{scan_speed}", _autoremap: true}
        - TestFly:
            pose: [0, 0, 1]
            path: [[0, 0, 1], [1, 0, 1]]
        - AlwaysSuccess
  Scan:
    Sequence:
      - Script:
          code: "n := 0"
          _description: |
            zeroes n
            # not a comment
      # a comment
      - ScriptCondition: {code: "n == 0"}
models:
  Scan:
    kind: SubTree
    ports:
      speed: {direction: input, type: float, default: 0.07, description: scan speed in m/s}
"""


def test_example_loads_with_locations_and_native_values(tmp_path):
    spec = load_yaml(write(tmp_path, "m.yaml", EXAMPLE))
    assert spec.load_problems == []
    assert validate(spec, REG) == []
    assert spec.main_tree_id() == "Main"
    assert spec.comments == ["Survey mission", "(header)"]
    main = spec.trees["Main"]
    assert main.comments == ["the main tree"] and (main.loc.line, main.loc.col) == (8, 3)
    seq = main.root
    assert (seq.type, seq.name, seq.loc.line, seq.loc.col) == ("Sequence", "mission", 9, 5)
    assert [c.type for c in seq.children] == [
        "TestFly",
        "TestFly",
        "Timeout",
        "SubTree",
        "TestFly",
        "AlwaysSuccess",
    ]
    fly, approach, timeout, sub, fly2, _ = seq.children
    assert fly.comments == ["go up first"]
    assert (fly.loc.line, fly.loc.col) == (13, 11)
    assert fly.attrs["pose"].value == [1, 2, 0.5]
    assert (fly.attrs["yaw_mode"].loc.line, fly.attrs["yaw_mode"].loc.col) == (13, 40)
    assert approach.attrs["speed"].value == "{scan_speed}"  # the unquoted {key} form
    assert approach.attrs["pose"].value == "{target}"
    assert timeout.attrs["msec"].value == 5000
    assert [c.type for c in timeout.children] == ["AlwaysSuccess"]
    assert sub.attrs["ID"].value == "Scan" and sub.attrs["_autoremap"].value is True
    assert fly2.attrs["path"].value == [[0, 0, 1], [1, 0, 1]]
    scan = spec.trees["Scan"].root.children
    assert scan[0].attrs["_description"].value == "zeroes n\n# not a comment\n"
    assert scan[0].comments == [] and scan[1].comments == ["a comment"]
    port = spec.models["Scan"].ports["speed"]
    assert (port.direction, port.type, port.default) == ("input", "float", 0.07)


def test_null_mapping_reference_forms(tmp_path):
    text = "trees:\n  T:\n    TestFly: {pose: {goal}, path: [{a}, [1, 2, 3]], reached: {=}}\n"
    spec = load_yaml(write(tmp_path, "m.yaml", text))
    attrs = spec.trees["T"].root.attrs
    assert attrs["pose"].value == "{goal}"
    assert attrs["path"].value == ["{a}", [1, 2, 3]]
    assert attrs["reached"].value == "{=}"
    assert spec.load_problems == []


def test_bare_names_lists_and_main_optional(tmp_path):
    spec = load_yaml(write(tmp_path, "m.yaml", "trees:\n  Only: AlwaysSuccess\n"))
    assert spec.load_problems == [] and spec.main_tree_id() == "Only"
    assert spec.trees["Only"].root.type == "AlwaysSuccess"


BAD = [
    ("syntax", "trees: [a, b\n", 2, 1, "YAML syntax error"),
    ("tab", "trees:\n\tT: A\n", 2, 1, "not tabs"),
    ("indent", "trees:\n  T:\n    Sequence:\n   - A\n", 4, 4, "YAML syntax error"),
    (
        "python tag",
        "trees:\n  T: !!python/object:os.system x\n",
        2,
        6,
        "'!!python/object:os.system'",
    ),
    ("custom tag", "trees:\n  T: !mine x\n", 2, 6, "YAML tag '!mine'"),
    ("set tag", "trees:\n  T: !!set {a}\n", 2, 6, "'!!set'"),
    ("anchor", "trees:\n  T: &a {AlwaysSuccess: null}\n", 2, 6, "anchors (&a)"),
    ("alias", "x: [1]\ntrees:\n  T: *a\n", 3, 6, "aliases (*a)"),
    ("two docs", "trees: {}\n---\ntrees: {}\n", 2, 1, "single document"),
    ("empty", "# nothing\n", 1, 1, "file is empty"),
    ("not mapping", "- a\n", 1, 1, "top level must be a mapping"),
    ("unknown key", "tress:\n  T: A\n", 1, 1, "did you mean 'trees'"),
    ("version", "btrun: 2\ntrees: {T: A}\n", 1, 8, "expected 1"),
    ("main", "main: [a]\ntrees: {T: A}\n", 1, 7, "main: expected the ID"),
    ("trees type", "trees: [A]\n", 1, 8, "trees: expected tree IDs"),
    ("dup key", "trees:\n  T: A\n  T: B\n", 3, 3, "duplicate key 'T' (first at"),
    ("empty tree", "trees:\n  T:\n", 2, 3, "tree 'T' is empty"),
    ("two keys", "trees:\n  T:\n    Sleep:\n    msec: 5\n", 4, 5, "found 2 keys (Sleep, msec)"),
    ("empty node", "trees:\n  T: {Sequence: [{}]}\n", 2, 18, "got an empty mapping"),
    ("null node", "trees:\n  T:\n    Sequence:\n      -\n", 4, 8, "expected a node"),
    ("number node", "trees:\n  T: {Sequence: [5]}\n", 2, 18, "got '5'"),
    ("list node", "trees:\n  T: {Sequence: [[A]]}\n", 2, 18, "got a list"),
    ("scalar value", "trees:\n  T: {Sleep: 500}\n", 2, 14, "expected attributes"),
    ("subtree id", "trees:\n  T: {SubTree: Scan}\n", 2, 16, "SubTree: {ID: Scan}"),
    (
        "children map",
        "trees:\n  T:\n    Sequence:\n      children: {A: null}\n",
        4,
        17,
        "children: expected a list",
    ),
    ("child list", "trees:\n  T:\n    Inverter:\n      child: [A, B]\n", 4, 14, "use `children:`"),
    (
        "child empty",
        "trees:\n  T:\n    Inverter:\n      child:\n",
        4,
        13,
        "child: expected a single node",
    ),
    ("both", "trees:\n  T:\n    Inverter:\n      child: A\n      children: [B]\n", 5, 7, "both"),
    ("map value", "trees:\n  T: {Sleep: {msec: {a: 1}}}\n", 2, 21, "got a mapping"),
    ("no value", "trees:\n  T:\n    Sleep:\n      msec:\n", 4, 7, "has no value"),
    ("include type", "include: [5]\ntrees: {T: A}\n", 1, 11, "include: expected a relative"),
    ("include missing", "include: nope.yaml\ntrees: {T: A}\n", 1, 10, "included file not found"),
    ("model kind", "trees: {T: A}\nmodels:\n  T: {kind: Tree}\n", 3, 13, "kind: expected one of"),
    ("model key", "trees: {T: A}\nmodels:\n  T: {kinds: SubTree}\n", 3, 7, "did you mean 'kind'"),
    (
        "direction",
        "trees: {T: A}\nmodels:\n  T:\n    ports: {a: {direction: in}}\n",
        4,
        28,
        "direction",
    ),
    (
        "port key",
        "trees: {T: A}\nmodels:\n  T:\n    ports: {a: {typ: int}}\n",
        4,
        17,
        "did you mean 'type'",
    ),
    (
        "port type",
        "trees: {T: A}\nmodels:\n  T:\n    ports: {a: 5}\n",
        4,
        16,
        "port 'a' of model 'T'",
    ),
    ("reader", "trees: {T: A\x07}\n", 1, 13, "unacceptable character"),
]


@pytest.mark.parametrize(
    ("text", "line", "col", "message"), [b[1:] for b in BAD], ids=[b[0] for b in BAD]
)
def test_problems_are_located(tmp_path, text, line, col, message):
    path = write(tmp_path, "m.yaml", text)
    problems = load_yaml(path).load_problems
    assert problems, "expected a problem"
    assert any(message in p.message for p in problems), problems
    p = next(p for p in problems if message in p.message)
    assert (p.loc.file, p.loc.line, p.loc.col) == (path, line, col), p


def test_validation_problems_point_at_yaml_keys(tmp_path):
    text = "trees:\n  T:\n    Sequence:\n      - TestFly: {pose: [1, 2], sped: 1}\n      - Sleeep\n"
    spec = load_yaml(write(tmp_path, "m.yaml", text))
    found = {(p.loc.line, p.loc.col): p.message for p in validate(spec, REG)}
    assert "three numbers" in found[(4, 19)]
    assert "did you mean 'speed'" in found[(4, 33)]
    assert "did you mean 'Sleep'" in found[(5, 9)]


def test_limits(tmp_path, monkeypatch):
    deep = "trees:\n  T: " + "[" * 300 + "]" * 300 + "\n"
    assert "nested more than" in problems_of(tmp_path, deep)[0].message
    monkeypatch.setattr(yaml_io, "MAX_YAML_NODES", 50)
    bomb = "trees:\n  T:\n    Sequence:\n" + "      - AlwaysSuccess\n" * 60
    assert "more than 50 YAML values" in problems_of(tmp_path, bomb)[0].message
    monkeypatch.setattr(yaml_io, "MAX_FILE_BYTES", 10)
    spec = load_yaml("big.yaml", "trees: {T: AlwaysSuccess}\n")
    assert "larger than 10 bytes" in spec.load_problems[0].message


def test_includes_and_loops(tmp_path):
    write(tmp_path, "common.yaml", "trees:\n  Common: AlwaysSuccess\n")
    write(
        tmp_path,
        "old.xml",
        '<root BTCPP_format="4"><BehaviorTree ID="Old"><AlwaysFailure/></BehaviorTree></root>',
    )
    main = write(
        tmp_path,
        "m.yaml",
        "include: [common.yaml, old.xml]\nmain: Main\ntrees:\n  Main: {SubTree: {ID: Common}}\n",
    )
    spec = load_yaml(main)
    assert spec.load_problems == [] and list(spec.trees) == ["Common", "Old", "Main"]
    assert validate(spec, REG) == []
    a = write(tmp_path, "a.yaml", "include: b.yaml\ntrees: {A: AlwaysSuccess}\n")
    b = write(tmp_path, "b.yaml", "include: [x.xml]\ntrees: {B: AlwaysSuccess}\n")
    write(tmp_path, "x.xml", '<root><include path="a.yaml"/></root>')
    problems = load_yaml(a).load_problems
    assert (
        len(problems) == 1
        and "include loop: a.yaml -> b.yaml -> x.xml -> a.yaml" in problems[0].message
    )
    assert (problems[0].loc.file, problems[0].loc.line) == (str(tmp_path / "x.xml"), 1)
    write(tmp_path, "self.yaml", "include: self.yaml\ntrees: {A: AlwaysSuccess}\n")
    p = load_yaml(str(tmp_path / "self.yaml")).load_problems
    assert [(x.loc.line, x.loc.col) for x in p] == [(1, 10)] and "include loop" in p[0].message
    dup = write(tmp_path, "d.yaml", "include: [common.yaml]\ntrees:\n  Common: AlwaysFailure\n")
    p = load_yaml(dup).load_problems
    assert "'Common' is defined twice" in p[0].message and (p[0].loc.file, p[0].loc.line) == (
        dup,
        3,
    )
    assert b


MISSION_XML = """\
<?xml version="1.0" encoding="UTF-8"?>
<!-- Behaviour check mission -->
<root BTCPP_format="4" main_tree_to_execute="Main">
  <!-- the main tree -->
  <BehaviorTree ID="Main">
    <!-- counts, waits and scans
         (two lines) -->
    <Sequence name="mission">
      <Script code="n := 0; flag := true; loops := 0"/>
      <!-- wait a bit -->
      <Sleep msec="300"/>
      <Fallback>
        <ScriptCondition code="n &gt; 2"/>
        <Repeat num_cycles="3">
          <Sequence>
            <Script code="n += 1"/>
            <Sleep msec="100"/>
          </Sequence>
        </Repeat>
      </Fallback>
      <Fallback>
        <Timeout msec="250"><Sleep msec="1000"/></Timeout>
        <Script code="timed_out := true"/>
      </Fallback>
      <SubTree ID="Scan" speed="{n}" out="{res}"/>
      <SubTree ID="Auto" _autoremap="true"/>
      <AlwaysFailure _skipIf="flag == true"/>
      <RetryUntilSuccessful num_attempts="3">
        <ScriptCondition code="loops &gt;= 2" _onFailure="loops += 1"/>
      </RetryUntilSuccessful>
      <Sleep name="final" msec="200" _onSuccess="done := 1"/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Scan">
    <Sequence>
      <ScriptCondition code="speed &gt;= 3"/>
      <Delay delay_msec="100"><Script code="out := speed * 2"/></Delay>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Auto">
    <Inverter><ScriptCondition code="n &lt; 0"/></Inverter>
  </BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="Scan">
      <input_port name="speed" type="float" default="0.07">scan speed</input_port>
      <output_port name="out"/>
    </SubTree>
  </TreeNodesModel>
</root>
"""


def test_round_trip_is_stable_and_keeps_comments(tmp_path):
    src = write(tmp_path, "m.xml", MISSION_XML)
    assert convert_file(src, str(tmp_path / "m1.yaml"), REG) == []
    yaml1 = (tmp_path / "m1.yaml").read_text()
    assert convert_file(str(tmp_path / "m1.yaml"), str(tmp_path / "m2.xml"), REG) == []
    assert convert_file(str(tmp_path / "m2.xml"), str(tmp_path / "m3.yaml"), REG) == []
    assert (tmp_path / "m3.yaml").read_text() == yaml1
    for text in (yaml1, (tmp_path / "m2.xml").read_text()):
        for c in (
            "Behaviour check mission",
            "the main tree",
            "counts, waits and scans",
            "(two lines)",
            "wait a bit",
        ):
            assert c in text
    assert yaml1.startswith("# Behaviour check mission\nbtrun: 1\nmain: Main\n")
    assert "- Sleep: {msec: 300}" in yaml1 and 'speed: "{n}"' in yaml1
    assert "_autoremap: true" in yaml1 and "child:" in yaml1
    spec = load_xml(str(tmp_path / "m2.xml"))
    assert spec.trees["Main"].root.comments == ["counts, waits and scans", "(two lines)"]
    assert spec.trees["Main"].comments == ["the main tree"]


def test_dump_converts_xml_text_with_port_types(tmp_path):
    xml = """<root BTCPP_format="4"><BehaviorTree ID="T"><Sequence>
      <TestFly pose="1;2;3" speed="0.5" yaw_mode="1" path="0;0;1|1;0;1" reached="{ok}"/>
      <TestFly pose="{goal}" speed="fast" other="7"/>
      <Sleep msec="20" name="42"/>
    </Sequence></BehaviorTree></root>"""
    spec = load_xml(write(tmp_path, "m.xml", xml))
    text = dump_yaml(spec, REG)
    assert (
        "      - TestFly:\n          pose: [1.0, 2.0, 3.0]\n          speed: 0.5\n"
        "          yaw_mode: PATH_FACING\n          path: [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]]\n"
        '          reached: "{ok}"\n'
    ) in text
    assert '- TestFly: {pose: "{goal}", speed: fast, other: "7"}' in text
    assert '- Sleep: {msec: 20, name: "42"}' in text
    back = load_yaml("x.yaml", text)
    assert back.load_problems == []
    fly = back.trees["T"].root.children[0]
    assert (
        fly.attrs["pose"].value == [1.0, 2.0, 3.0] and fly.attrs["yaw_mode"].value == "PATH_FACING"
    )
    assert 'pose="1;2;3"' in dump_xml(back)


def test_dump_quotes_and_long_lines():
    spec = load_yaml(
        "m.yaml",
        "trees:\n  T:\n    Script:\n      code: \"a := 'x, y'\\nb := 1 # c\"\n"
        '      name: "null"\n      _skipIf: "' + "x == 1 && " * 12 + 'true"\n',
    )
    assert spec.load_problems == []
    text = dump_yaml(spec)
    assert "    Script:\n      code: " in text  # too long for a flow mapping
    again = load_yaml("m.yaml", text)
    assert {k: a.value for k, a in again.trees["T"].root.attrs.items()} == {
        k: a.value for k, a in spec.trees["T"].root.attrs.items()
    }


def _ticks(spec, n=50):
    mission = Mission(spec, clock=SimClock())
    out = []
    for _ in range(n):
        mission.clock.advance(0.05)
        mission.tick()
        out.append((list(mission.statuses()), list(mission.statuses().values())))
    bb = dict(mission.blackboard)
    mission.close()
    return out, bb


def test_xml_and_yaml_missions_tick_identically(tmp_path):
    src = write(tmp_path, "m.xml", MISSION_XML)
    dst = str(tmp_path / "m.yaml")
    assert convert_file(src, dst, REG) == []
    xml_run, xml_bb = _ticks(load_spec(src))
    yaml_run, yaml_bb = _ticks(load_spec(dst))
    seen = {s for _, statuses in xml_run for s in statuses}
    assert {"RUNNING", "SUCCESS", "FAILURE"} <= seen
    for i, (a, b) in enumerate(zip(xml_run, yaml_run, strict=True)):
        assert a == b, f"tick {i + 1} differs"
    # reaching `done` needs the _skipIf'd AlwaysFailure skipped and RetryUntilSuccessful retrying
    assert xml_bb == yaml_bb and xml_bb["done"] == 1 and xml_bb["res"] == 6


def test_hand_written_yaml_runs(tmp_path):
    text = """\
trees:
  Main:
    Sequence:
      - Script: {code: "x := 2"}
      - SubTree: {ID: Sub, v: {x}, y: "{y}", _autoremap: false}
      - ScriptCondition: {code: "y == 4"}
  Sub:
    Script: {code: "y := v * 2"}
"""
    spec = load_yaml(write(tmp_path, "m.yaml", text))
    spec.main_tree = "Main"
    mission = Mission(spec, clock=SimClock())
    assert mission.tick() is SUCCESS
    mission.close()


def test_convert_file_refuses_and_reports(tmp_path):
    bad = write(tmp_path, "bad.yaml", "trees: [\n")
    dst = tmp_path / "bad.xml"
    problems = convert_file(bad, str(dst), REG)
    assert problems and problems[0].loc.file == bad and not dst.exists()
    ok = write(
        tmp_path, "ok.yaml", "# -- header --\ntrees:\n  T:\n    # a -- b -\n    AlwaysSuccess\n"
    )
    problems = convert_file(ok, str(tmp_path / "ok.txt"), REG)
    assert "unknown output type" in problems[0].message
    assert convert_file(ok, str(tmp_path / "ok.xml"), REG) == []
    spec = load_xml(str(tmp_path / "ok.xml"))
    assert spec.load_problems == [] and spec.trees["T"].root.comments == ["a - - b"]
    assert convert_file(str(tmp_path / "missing.xml"), str(tmp_path / "x.yaml"), REG)
    assert not os.path.exists(tmp_path / "x.yaml")


def test_an_empty_default_survives_the_round_trip(tmp_path):
    """A mission input declared with default="" is optional; its YAML must say so (the
    inventory's ``expected`` stock: empty means none)."""
    path = tmp_path / "m.xml"
    path.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="M"><BehaviorTree ID="M">'
        '<AlwaysSuccess/></BehaviorTree><TreeNodesModel><SubTree ID="M">'
        '<input_port name="stock" default="">none</input_port>'
        "</SubTree></TreeNodesModel></root>"
    )
    out = tmp_path / "m.yaml"
    convert_file(str(path), str(out))
    assert 'default: ""' in out.read_text()
    again = load_yaml(str(out))
    assert again.models["M"].ports["stock"].default == ""
