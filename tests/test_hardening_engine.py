"""Hostile mission files against the engine: nesting, file size and kind, includes, YAML
indentation, and the validation warnings (unknown blackboard entries, unbounded loops).

Every input ends in located problems (``file:line:col: message``) naming the limit, never in
a traceback, a hang or a read of a file outside the mission's folders.
"""

from __future__ import annotations

import os
import re
import threading

import pytest
from helpers import REPO, wrap

import nodes  # noqa: F401  (registers the drone leaves: GoTo)
from bt_engine import files, xml_io
from bt_engine import spec as spec_module
from bt_engine.builder import build_tree
from bt_engine.cli import main
from bt_engine.loading import convert_file, load_spec, load_xml, load_yaml
from bt_engine.node import MissionContext
from bt_engine.registry import REGISTRY
from bt_engine.spec import Loc, MissionError, MissionSpec, NodeSpec, Problem, TreeSpec
from bt_engine.validate import validate

LOCATED = re.compile(r"^.+:\d+:\d+: \S")
# the limits (bt_engine.spec), spelt out so that each test names the value it relies on
MAX_NESTING_DEPTH, MAX_SUBTREE_DEPTH, MAX_ATTRIBUTES = 200, 100, 256


def errors(spec: MissionSpec) -> list[str]:
    return [str(p) for p in validate(spec, REGISTRY)]


def warnings_of(spec: MissionSpec) -> tuple[list[str], list[str]]:
    """(errors, warnings) of ``spec``, as text."""
    found: list[Problem] = []
    errs = validate(spec, REGISTRY, found)
    return [str(p) for p in errs], [str(p) for p in found]


def chain_xml(n: int) -> str:
    """Trees A1..An, each using the next as a SubTree."""
    parts = ['<root BTCPP_format="4" main_tree_to_execute="A1">']
    parts += [
        f'<BehaviorTree ID="A{i}"><SubTree ID="A{i + 1}"/></BehaviorTree>' for i in range(1, n)
    ]
    parts.append(f'<BehaviorTree ID="A{n}"><AlwaysSuccess/></BehaviorTree></root>')
    return "\n".join(parts)


def nested_xml(depth: int) -> str:
    """One tree: ``depth - 1`` Inverters around an AlwaysSuccess (the root is level 1)."""
    return wrap("<Inverter>" * (depth - 1) + "<AlwaysSuccess/>" + "</Inverter>" * (depth - 1))


# ---------------------------------------------------------------------- 1. nesting depth


def test_limits_are_generous_module_constants():
    s = spec_module
    assert (s.MAX_NESTING_DEPTH, s.MAX_SUBTREE_DEPTH) == (MAX_NESTING_DEPTH, MAX_SUBTREE_DEPTH)
    assert (s.MAX_TREE_NODES, s.MAX_ATTRIBUTES) == (100_000, MAX_ATTRIBUTES)


def test_subtree_chain_3000_deep_is_a_located_problem_not_a_recursion_error():
    problems = errors(load_xml("chain.xml", text=chain_xml(3000)))
    assert len(problems) == 1, problems
    # the SubTree of line 102 is the 101st SubTree expanded
    assert problems[0].startswith("chain.xml:102:")
    assert "101 SubTrees deep" in problems[0] and "at most 100 deep" in problems[0]


def test_subtree_chain_3000_deep_cli(tmp_path, capsys):
    path = tmp_path / "chain.xml"
    path.write_text(chain_xml(3000))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "MAX_SUBTREE_DEPTH" in err
    assert all(LOCATED.match(line) for line in err.splitlines()[:-1])


def test_subtree_chain_at_the_limit_is_fine():
    assert errors(load_xml("chain.xml", text=chain_xml(MAX_SUBTREE_DEPTH + 1))) == []


def test_recursive_subtree_still_reported_once_per_loop():
    xml = (
        '<root BTCPP_format="4" main_tree_to_execute="Main">'
        '<BehaviorTree ID="Main"><Sequence><SubTree ID="A"/><SubTree ID="A"/></Sequence>'
        "</BehaviorTree>"
        '<BehaviorTree ID="A"><SubTree ID="B"/></BehaviorTree>'
        '<BehaviorTree ID="B"><SubTree ID="A"/></BehaviorTree></root>'
    )
    problems = errors(load_xml("m.xml", text=xml))
    assert [p for p in problems if "recursive SubTree: Main -> A -> B -> A" in p], problems


def test_shared_subtrees_are_analysed_once_and_their_size_is_bounded(monkeypatch):
    """T0 uses T1 twice, T1 uses T2 twice...: 2**18 nodes once expanded, but each tree is
    walked a bounded number of times (not once per path: 2**18 walks)."""
    levels = 18
    parts = ['<root BTCPP_format="4" main_tree_to_execute="T0">']
    for i in range(levels):
        parts.append(
            f'<BehaviorTree ID="T{i}"><Sequence><SubTree ID="T{i + 1}"/>'
            f'<SubTree ID="T{i + 1}"/></Sequence></BehaviorTree>'
        )
    parts.append(f'<BehaviorTree ID="T{levels}"><AlwaysSuccess/></BehaviorTree></root>')
    spec = load_xml("fan.xml", text="\n".join(parts))
    calls = [0]
    walk = NodeSpec.walk

    def counted(self):
        calls[0] += 1
        if calls[0] > 50 * (levels + 1):
            raise AssertionError("trees are walked once per path, not once per tree")
        return walk(self)

    monkeypatch.setattr(NodeSpec, "walk", counted)
    problems = errors(spec)
    assert len(problems) == 1 and "more than 100000 nodes" in problems[0], problems
    assert "MAX_TREE_NODES" in problems[0] and problems[0].startswith("fan.xml:2:")


def test_nodes_nested_past_the_limit_in_one_file_are_located():
    problems = errors(load_xml("deep.xml", text=nested_xml(MAX_NESTING_DEPTH + 30)))
    assert len(problems) == 1, problems
    assert problems[0].startswith("deep.xml:3:")
    assert "nested 201 levels deep" in problems[0] and "at most 200 deep" in problems[0]
    assert errors(load_xml("ok.xml", text=nested_xml(MAX_NESTING_DEPTH))) == []


def test_elements_nested_thousands_deep_name_the_limit(tmp_path, capsys):
    path = tmp_path / "deep.xml"
    path.write_text(nested_xml(3000))
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert "MAX_NESTING_DEPTH" in err and "XML_PARSE_HUGE" not in err and "Traceback" not in err


def test_expanded_depth_through_subtrees_is_bounded():
    """8 SubTrees of 30 levels each: no tree is too deep, the expanded main tree is."""
    body = "<Inverter>" * 29 + "{}" + "</Inverter>" * 29
    parts = ['<root BTCPP_format="4" main_tree_to_execute="S0">']
    for i in range(8):
        parts.append(
            f'<BehaviorTree ID="S{i}">'
            + body.format(f'<SubTree ID="S{i + 1}"/>')
            + "</BehaviorTree>"
        )
    parts.append('<BehaviorTree ID="S8"><AlwaysSuccess/></BehaviorTree></root>')
    problems = errors(load_xml("exp.xml", text="\n".join(parts)))
    assert len(problems) == 1, problems
    assert "nested 201 levels deep once SubTrees are expanded (S0 -> S1" in problems[0]
    assert LOCATED.match(problems[0])


def test_conversion_refuses_too_deep_files(tmp_path):
    src = tmp_path / "deep.xml"
    src.write_text(nested_xml(MAX_NESTING_DEPTH + 30))
    problems = convert_file(str(src), str(tmp_path / "deep.yaml"), REGISTRY)
    assert problems and "MAX_NESTING_DEPTH" in problems[0].message
    assert not (tmp_path / "deep.yaml").exists()


def _deep_spec(depth: int) -> MissionSpec:
    node = NodeSpec("AlwaysSuccess", Loc("api", depth, 1))
    for i in range(depth - 1, 0, -1):
        node = NodeSpec("Inverter", Loc("api", i, 1), children=[node])
    spec = MissionSpec(file="api")
    spec.trees["Main"] = TreeSpec("Main", Loc("api", 1, 1), root=node)
    return spec


def test_walking_and_validating_a_5000_deep_spec_does_not_recurse():
    spec = _deep_spec(5000)
    assert sum(1 for _ in spec.trees["Main"].root.walk()) == 5000
    problems = errors(spec)
    assert problems == [
        "api:201:1: node nested 201 levels deep; nodes may nest "
        "at most 200 deep (MAX_NESTING_DEPTH)"
    ]


def test_building_an_unvalidated_deep_spec_is_a_located_error():
    from bt_engine.clock import SimClock

    with pytest.raises(MissionError) as info:
        build_tree(_deep_spec(3000), REGISTRY, MissionContext(SimClock()))
    assert "api:201:1:" in str(info.value) and "MAX_NESTING_DEPTH" in str(info.value)


# ---------------------------------------------------------- 2. file kinds and sizes


def test_fifo_is_refused_without_blocking(tmp_path):
    """The pre-fix reader opened the FIFO and blocked: a writer thread that opens it as soon
    as a reader does turns that into a wrong result instead of a hang."""
    fifo = tmp_path / "mission.xml"
    os.mkfifo(fifo)
    done = threading.Event()

    def writer() -> None:
        while not done.is_set():
            try:
                fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            except OSError:  # ENXIO: nobody reads it
                done.wait(0.001)
                continue
            os.write(fd, wrap("<AlwaysSuccess/>").encode())
            os.close(fd)
            return

    t = threading.Thread(target=writer, daemon=True)
    t.start()
    try:
        spec = load_spec(str(fifo))
    finally:
        done.set()
        t.join()
    assert [p.message for p in spec.load_problems] == [
        f"{fifo} is a named pipe (FIFO), not a regular file; missions are read from ordinary files"
    ]


def test_cli_refuses_a_fifo(tmp_path, capsys):
    fifo = tmp_path / "m.yaml"
    os.mkfifo(fifo)
    done = threading.Event()

    def writer() -> None:  # as above: a pre-fix reader gets an empty mission, not a hang
        while not done.is_set():
            try:
                os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
                return
            except OSError:
                done.wait(0.001)

    t = threading.Thread(target=writer, daemon=True)
    t.start()
    try:
        assert main(["validate", str(fifo)]) == 2
    finally:
        done.set()
        t.join()
    assert "named pipe (FIFO), not a regular file" in capsys.readouterr().err


@pytest.mark.parametrize("device", ["/dev/null", "/dev/zero"])
def test_symlink_to_a_device_is_refused_before_reading(tmp_path, device):
    if not os.path.exists(device):
        pytest.skip(f"no {device}")
    link = tmp_path / "mission.xml"
    link.symlink_to(device)
    problems: list[Problem] = []
    assert files.read_text(str(link), problems) is None
    assert len(problems) == 1 and "is a character device, not a regular file" in str(problems[0])


def test_reads_stop_after_the_limit_even_if_the_size_lies(monkeypatch):
    """/proc files say they are 0 bytes long: only MAX_FILE_BYTES + 1 bytes are read."""
    if not os.path.isfile("/proc/self/status"):
        pytest.skip("no /proc")
    monkeypatch.setattr(files, "MAX_FILE_BYTES", 20)
    problems: list[Problem] = []
    assert files.read_text("/proc/self/status", problems) is None
    assert "larger than 20 bytes" in problems[0].message


def test_too_many_attributes_on_one_element_is_refused_before_parsing():
    attrs = " ".join(f'a{i}="1"' for i in range(MAX_ATTRIBUTES + 1))
    spec = load_xml("attrs.xml", text=wrap(f"<AlwaysSuccess {attrs}/>"))
    assert [str(p) for p in spec.load_problems] == [
        f"attrs.xml:3:1: <AlwaysSuccess> has more than {MAX_ATTRIBUTES} attributes; the limit "
        f"is {MAX_ATTRIBUTES} (MAX_ATTRIBUTES); refusing to load it"
    ]


def test_too_many_elements_in_one_file_is_refused(monkeypatch):
    monkeypatch.setattr(xml_io, "MAX_ELEMENTS", 50)
    spec = load_xml("many.xml", text=wrap("<Sequence>" + "<AlwaysSuccess/>" * 60 + "</Sequence>"))
    assert len(spec.load_problems) == 1
    assert "more than 50 elements" in spec.load_problems[0].message
    assert LOCATED.match(str(spec.load_problems[0]))


def test_too_many_attributes_in_yaml_is_refused():
    attrs = ", ".join(f"a{i}: 1" for i in range(MAX_ATTRIBUTES + 1))
    spec = load_yaml("attrs.yaml", text=f"btrun: 1\ntrees:\n  Main:\n    GoTo: {{{attrs}}}\n")
    problems = errors(spec)
    assert len(problems) == 1 and "MAX_ATTRIBUTES" in problems[0], problems[:3]


# -------------------------------------------------------------------------- 5. includes


def _mission(folder, name: str, include: str) -> str:
    path = folder / name
    path.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Main">'
        f'<include path="{include}"/>'
        '<BehaviorTree ID="Main"><SubTree ID="Lib"/></BehaviorTree></root>'
    )
    return str(path)


def _library(path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Lib"><AlwaysSuccess/></BehaviorTree></root>'
    )


@pytest.mark.parametrize("target", ["/etc/passwd", "/proc/self/environ"])
def test_include_of_a_system_file_is_refused_unread(tmp_path, target):
    path = _mission(tmp_path, "m.xml", target)
    spec = load_spec(path)
    assert [str(p) for p in spec.load_problems] == [
        f"{path}:1:61: include outside the mission folder: {target}"
        + ("" if os.path.realpath(target) == target else f" ({os.path.realpath(target)})")
        + f" (allowed: {os.path.realpath(tmp_path)}; add --include-path)"
    ]
    assert spec.includes == []


def test_include_outside_the_folder_needs_an_include_path(tmp_path):
    (tmp_path / "mission").mkdir()
    _library(tmp_path / "shared" / "lib.xml")
    path = _mission(tmp_path / "mission", "m.xml", "../shared/lib.xml")
    problems = errors(load_spec(path))
    assert "include outside the mission folder: ../shared/lib.xml (" in problems[0], problems
    assert errors(load_spec(path, include_paths=[str(tmp_path / "shared")])) == []


def test_include_through_a_symlink_out_of_the_folder_is_refused(tmp_path):
    (tmp_path / "mission").mkdir()
    _library(tmp_path / "elsewhere" / "lib.xml")
    (tmp_path / "mission" / "lib.xml").symlink_to(tmp_path / "elsewhere" / "lib.xml")
    path = _mission(tmp_path / "mission", "m.xml", "lib.xml")
    problems = errors(load_spec(path))
    assert "include outside the mission folder: lib.xml (" in problems[0], problems


def test_subfolders_of_the_mission_folder_are_allowed(tmp_path):
    _library(tmp_path / "lib" / "deeper" / "lib.xml")
    assert errors(load_spec(_mission(tmp_path, "m.xml", "lib/deeper/lib.xml"))) == []


def test_yaml_include_outside_is_refused(tmp_path):
    (tmp_path / "m").mkdir()
    _library(tmp_path / "lib.xml")
    path = tmp_path / "m" / "m.yaml"
    path.write_text(
        "btrun: 1\ninclude: ../lib.xml\nmain: Main\ntrees:\n  Main: {SubTree: {ID: Lib}}\n"
    )
    problems = errors(load_spec(str(path)))
    assert problems[0].startswith(f"{path}:2:10: include outside the mission folder"), problems
    assert errors(load_yaml(str(path), include_paths=[str(tmp_path)])) == []


def test_repository_missions_with_includes_still_load():
    for name in ("enroll_pallet.xml", "inspect_two_pallets.xml"):
        assert errors(load_spec(os.path.join(REPO, "missions", name))) == []


def test_cli_include_path_option(tmp_path, capsys):
    (tmp_path / "mission").mkdir()
    _library(tmp_path / "shared" / "lib.xml")
    path = _mission(tmp_path / "mission", "m.xml", "../shared/lib.xml")
    shared = str(tmp_path / "shared")
    assert main(["validate", path]) == 2
    assert "add --include-path" in capsys.readouterr().err
    assert main(["validate", "--include-path", shared, path]) == 0
    assert main(["show", path, "--include-path", shared]) == 0
    assert "Lib" in capsys.readouterr().out
    out = str(tmp_path / "m.yaml")
    assert main(["convert", path, out]) == 2
    assert main(["convert", path, out, "--include-path", shared]) == 0
    run = str(tmp_path / "run")
    assert main(["run", path, "--out", run, "-q", "--no-report"]) == 2
    assert main(["run", path, "--include-path", shared, "--out", run, "-q", "--no-report"]) == 0


# ------------------------------------------------------------------ 6. YAML indentation

MISINDENTED = {
    "less": (
        "btrun: 1\ntrees:\n  Main:\n    Sequence:\n      - AlwaysSuccess\n"
        "     - AlwaysFailure\n      - AlwaysSuccess\n",
        (6, 6),
    ),
    "more after a mapping": (
        "btrun: 1\ntrees:\n  Main:\n    Sequence:\n      - Sleep:\n          msec: 5\n"
        "        - AlwaysFailure\n",
        (7, 9),
    ),
    "children": (
        "btrun: 1\ntrees:\n  Main:\n    Sequence:\n      name: s\n      children:\n"
        "        - AlwaysSuccess\n       - AlwaysFailure\n",
        (8, 8),
    ),
    "more after a name": (
        "btrun: 1\ntrees:\n  Main:\n    Sequence:\n      - AlwaysSuccess\n"
        "        - AlwaysFailure\n",
        (6, 9),
    ),
}


@pytest.mark.parametrize("case", sorted(MISINDENTED))
def test_misindented_list_item_is_explained_at_its_line(case):
    text, (line, col) = MISINDENTED[case]
    problems = errors(load_yaml("m.yaml", text=text))
    assert len(problems) == 1, problems
    assert problems[0].startswith(f"m.yaml:{line}:{col}: this list item is indented differently ")
    assert "YAML syntax error" not in problems[0]


def test_nested_lists_and_dedents_are_not_misindented():
    text = (
        "btrun: 1\ntrees:\n  Main:\n    Sequence:\n      - Fallback:\n          - AlwaysFailure\n"
        "          - AlwaysSuccess\n      - AlwaysSuccess\n"
    )
    assert errors(load_yaml("m.yaml", text=text)) == []


# ---------------------------------------------------------- 7. unknown blackboard entries


def test_script_reading_an_entry_nothing_writes_is_a_located_warning():
    spec = load_xml("m.xml", text=wrap('<GoTo pose="5;0;1" _onHalted="x := missing_entry + 1"/>'))
    errs, warns = warnings_of(spec)
    assert errs == []  # still valid: --set may supply it
    assert len(warns) == 1, warns
    assert warns[0].startswith("m.xml:3:20: warning: script reads blackboard entry 'missing_entry'")


def test_script_assigning_with_equals_an_entry_nothing_creates_is_a_located_warning():
    body = '<Sequence><Script code="y = 3"/><Script code="z := 1; z = 2; w += 1"/></Sequence>'
    errs, warns = warnings_of(load_xml("m.xml", text=wrap(body)))
    assert errs == []  # still valid: --set may create it
    assert len(warns) == 2, warns  # y; w's '+=' reads it, said once; z was created
    assert warns[0].startswith(
        "m.xml:3:19: warning: script assigns blackboard entry 'y' with '=', which needs"
    )
    assert "use ':=' to create it" in warns[0]
    assert "reads blackboard entry 'w'" in warns[1]
    created = '<Sequence><Script code="y := 0"/><Script code="y = 3"/></Sequence>'
    assert warnings_of(load_xml("m.xml", text=wrap(created))) == ([], [])


@pytest.mark.parametrize(
    ("code", "fragment"),
    [
        ("a := 5 % 0", "operator '%': modulo by zero at column 8"),
        ("c := n > 1 ? 'a' - 1 : 2", "operator '-': expected a number, got string 'a'"),
        ("a := (1 + 2) / (3 - 3)", "division by zero"),
    ],
)
def test_script_part_made_of_literals_that_always_fails_is_refused(code, fragment):
    errs, _ = warnings_of(load_xml("m.xml", text=wrap(f'<Script code="{code}"/>')))
    assert len(errs) == 1 and errs[0].startswith("m.xml:3:"), errs
    assert fragment in errs[0]


def test_literal_parts_that_never_run_or_never_fail_are_valid():
    for code in ("b := false ? 1 / 0 : 2", "b := false &amp;&amp; 1 / 0", "b := 'a' .. 1 + 2"):
        errs, _ = warnings_of(load_xml("m.xml", text=wrap(f'<Script code="{code}"/>')))
        assert errs == [], (code, errs)


def test_entries_written_or_declared_anywhere_are_not_warned_about():
    body = (
        "<Sequence>"
        '<Script code="a := 1"/>'
        '<SetBlackboard output_key="b" value="2"/>'
        '<SetBlackboard output_key="{c}" value="3"/>'
        '<ScriptCondition code="a + b + c + d + e + FIXED_YAW &gt; 0"/>'
        '<SubTree ID="Sub" e="{e}"/>'
        "</Sequence>"
    )
    extra = (
        '<BehaviorTree ID="Sub"><Script code="e := 1"/></BehaviorTree>'
        '<TreeNodesModel><SubTree ID="Main"><input_port name="d" default="1"/></SubTree>'
        '<SubTree ID="Sub"><output_port name="e"/></SubTree></TreeNodesModel>'
    )
    errs, warns = warnings_of(load_xml("m.xml", text=wrap(body, extra)))
    assert errs == [] and warns == []


def test_entry_written_by_an_output_port_is_known():
    body = '<Sequence><ScriptCondition code="seen &gt; 0"/></Sequence>'
    errs, warns = warnings_of(load_xml("m.xml", text=wrap(body)))
    assert len(warns) == 1 and "'seen'" in warns[0]
    # an output port bound to {seen} writes it
    model = next(m for m in REGISTRY.models() if any(p.writes for p in m.ports.values()))
    port = next(p for p in model.ports.values() if p.writes)
    node = NodeSpec(model.id, Loc("m.xml", 9, 1), {port.name: _attr("{seen}")})
    spec = load_xml("m.xml", text=wrap(body))
    spec.trees["Main"].root.children.append(node)
    assert warnings_of(spec)[1] == []


def test_an_input_port_reading_an_entry_nothing_writes_is_a_located_warning():
    """A typo in a ``{reference}`` (``{passs}`` for the loop's ``{pass}``) was found only in
    flight, after take-off ("reads blackboard entry {passs}, which is not set"): validate
    now warns at the attribute, with the closest entry the mission does write."""
    body = (
        "<Sequence>"
        '<Script code="target := &apos;1;0;1&apos;"/>'
        '<GoTo pose="{targte}"/>'
        '<GoTo pose="{target}"/>'
        '<GoTo pose="{home}"/>'
        "</Sequence>"
    )
    extra = (
        '<TreeNodesModel><SubTree ID="Main"><input_port name="home"/></SubTree></TreeNodesModel>'
    )
    errs, warns = warnings_of(load_xml("m.xml", text=wrap(body, extra)))
    assert errs == []  # still valid: --set may supply it
    assert len(warns) == 1, warns
    assert warns[0].startswith(
        "m.xml:3:61: warning: input port 'pose' reads blackboard entry {targte}, which nothing "
    ), warns
    assert "(did you mean {target}?)" in warns[0]


def _attr(value):
    from bt_engine.spec import AttrSpec

    return AttrSpec(value, Loc("m.xml", 9, 5))


# ------------------------------------------------------------------- 8. unbounded loops

LOOPS = {
    "repeat over sync": ('<Repeat num_cycles="-1"><AlwaysSuccess/></Repeat>', True),
    "retry over condition": (
        '<RetryUntilSuccessful num_attempts="-1"><ScriptCondition code="false"/>'
        "</RetryUntilSuccessful>",
        True,
    ),
    "repeat over sequence of scripts": (
        '<Repeat num_cycles="-1"><Sequence><Script code="a := 1"/>'
        '<SetBlackboard output_key="b" value="1"/></Sequence></Repeat>',
        True,
    ),
    "repeat over a sync subtree": ('<Repeat num_cycles="-1"><SubTree ID="Sync"/></Repeat>', True),
    "repeat over sleep": ('<Repeat num_cycles="-1"><Sleep msec="10"/></Repeat>', False),
    "repeat over an async subtree": (
        '<Repeat num_cycles="-1"><SubTree ID="Slow"/></Repeat>',
        False,
    ),
    "bounded repeat": ('<Repeat num_cycles="5"><AlwaysSuccess/></Repeat>', False),
    "count from the blackboard": ('<Repeat num_cycles="{n}"><AlwaysSuccess/></Repeat>', False),
    "repeat over flight": ('<Repeat num_cycles="-1"><GoTo pose="1;0;1"/></Repeat>', False),
}
SUBTREES = (
    '<BehaviorTree ID="Sync"><Inverter><AlwaysFailure/></Inverter></BehaviorTree>'
    '<BehaviorTree ID="Slow"><Sequence><AlwaysSuccess/><Delay delay_msec="5">'
    "<AlwaysSuccess/></Delay></Sequence></BehaviorTree>"
)


@pytest.mark.parametrize("case", sorted(LOOPS))
def test_unbounded_loop_around_instant_children_is_a_warning(case):
    body, warned = LOOPS[case]
    errs, warns = warnings_of(load_xml("m.xml", text=wrap(body, SUBTREES)))
    assert errs == []
    loops = [w for w in warns if "never return RUNNING" in w]
    assert bool(loops) is warned, warns
    if warned:
        assert re.match(
            r"m\.xml:3:\d+: warning: (Repeat num_cycles|RetryUntilSuccessful num_attempts)=\"-1\"",
            loops[0],
        )


def test_cli_prints_warnings_and_passes(tmp_path, capsys):
    path = tmp_path / "loop.xml"
    path.write_text(wrap('<Repeat num_cycles="-1"><AlwaysSuccess/></Repeat>'))
    assert main(["validate", str(path)]) == 0
    captured = capsys.readouterr()
    assert captured.out == f"{path}: ok\n"
    assert captured.err.startswith(f'{path}:3:9: warning: Repeat num_cycles="-1" around children')


def test_error_format_is_unchanged():
    assert str(Problem(Loc("m.xml", 3, 4), "boom")) == "m.xml:3:4: boom"
    assert str(Problem(Loc("m.xml", 3, 4), "hm", "warning")) == "m.xml:3:4: warning: hm"
