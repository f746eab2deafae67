"""Hostile input: fuzzed missions, rigs and worlds, and known attacks on XML and YAML.

Every input must end in a valid load or located problems (``file:line:col: message``):
never a traceback, never a hang (hypothesis deadlines), never code execution.
Network input and the gallery are other issues (emulators and gallery do not exist yet).
"""

from __future__ import annotations

import glob
import os
import re

import pytest
from helpers import REPO

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import nodes  # noqa: E402,F401  (registers the drone leaves)
from bt_engine import Mission, SimClock  # noqa: E402
from bt_engine.loading import load_xml, load_yaml  # noqa: E402
from bt_engine.registry import REGISTRY  # noqa: E402
from bt_engine.validate import validate  # noqa: E402
from drivers.settings import ConfigError  # noqa: E402

LOCATED = re.compile(r"^.+:\d+:\d+: \S")
MISSIONS = sorted(glob.glob(os.path.join(REPO, "missions", "*.xml")))
MISSIONS += sorted(glob.glob(os.path.join(REPO, "missions", "*.yaml")))
TEXTS = {os.path.basename(p): open(p, encoding="utf-8").read() for p in MISSIONS}
ATTR = re.compile(r'(\w+)="([^"]*)"')
YAML_VALUE = re.compile(r"(:\s+)([^\s#][^#\n]*)")
TOKENS = [
    "<",
    ">",
    "/>",
    "</",
    '"',
    "'",
    "&",
    "&amp;",
    "{",
    "}",
    "{@x}",
    ";",
    ":",
    "-",
    "\n",
    "\t",
    "  ",
    "!!",
    "*",
    "&a ",
    "\x00",
    "\u00e9",
    "<!--",
    "-->",
    "=",
    "[",
    "]",
    "nan",
    "1e999",
    "-1",
    "ID",
    "BehaviorTree",
    "SubTree",
    "include",
    "_skipIf",
    "{=}",
]
#: mission-only tokens: long runs for the parsers, list items for the YAML indentation
#: check, loops and scripts for the validation warnings
MISSION_TOKENS = TOKENS + [
    " " * 64,
    "9" * 450,
    "\n     - ",
    "\n        - ",
    '_onHalted="x = nope + 1" ',
    '<Repeat num_cycles="-1">',
    "s := s .. s;",
]


def _mutate(
    text: str, ops: list[tuple[int, int, int, int]], swap_re: re.Pattern, tokens=TOKENS
) -> str:
    for kind, a, b, c in ops:
        n = len(text)
        if n == 0:
            return text
        i = a % n
        if kind == 0:  # delete a few characters
            text = text[:i] + text[i + 1 + b % 8 :]
        elif kind == 1:  # insert a token
            text = text[:i] + tokens[c % len(tokens)] + text[i:]
        elif kind == 2:  # replace one character
            text = text[:i] + chr(32 + c % 95) + text[i + 1 :]
        elif kind == 3:  # swap two attribute (or YAML) values
            found = list(swap_re.finditer(text))
            if len(found) >= 2:
                x, y = found[a % len(found)], found[b % len(found)]
                if x.start() > y.start():
                    x, y = y, x
                if x.end() <= y.start():
                    vx, vy = x.group(2), y.group(2)
                    text = (
                        text[: x.start(2)]
                        + vy
                        + text[x.end(2) : y.start(2)]
                        + vx
                        + text[y.end(2) :]
                    )
        else:  # delete or duplicate a line (an element, an attribute line, a YAML entry)
            lines = text.split("\n")
            j = a % len(lines)
            if kind == 4:
                del lines[j : j + 1 + b % 3]
            else:
                lines[j:j] = lines[j : j + 1 + b % 3]
            text = "\n".join(lines)
    return text


OPS = st.lists(
    st.tuples(
        st.integers(0, 5), st.integers(0, 10**6), st.integers(0, 10**6), st.integers(0, 10**6)
    ),
    min_size=1,
    max_size=6,
)


def _check_mission(name: str, text: str) -> None:
    loader = load_yaml if name.endswith(".yaml") else load_xml
    spec = loader(os.path.join(REPO, "missions", name), text=text)
    warnings: list = []
    problems = validate(spec, REGISTRY, warnings)
    for p in problems + warnings:
        assert LOCATED.match(str(p)), str(p)
    if not problems:  # a valid load must also build
        Mission(spec, clock=SimClock()).close()


@pytest.mark.slow
@settings(
    max_examples=1200,
    deadline=2000,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(st.sampled_from(sorted(TEXTS)), OPS)
def test_fuzzed_missions_load_or_locate(name: str, ops) -> None:
    swap = YAML_VALUE if name.endswith(".yaml") else ATTR
    _check_mission(name, _mutate(TEXTS[name], ops, swap, MISSION_TOKENS))


def _config_files() -> dict[str, tuple[str, str]]:
    out = {}
    for p in [
        os.path.join(REPO, "rigs", "sim.yaml"),
        os.path.join(REPO, "worlds", "warehouse.yaml"),
    ]:
        out[os.path.basename(p)] = (p, open(p, encoding="utf-8").read())
    return out


CONFIGS = _config_files()


@pytest.mark.slow
@settings(
    max_examples=250,
    deadline=3000,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(st.sampled_from(sorted(CONFIGS)), OPS)
def test_fuzzed_rigs_and_worlds_load_or_locate(tmp_path_factory, name: str, ops) -> None:
    from drivers.rig.loader import load_rig
    from drivers.sim.world import load_world

    path, text = CONFIGS[name]
    if "&" in "".join(TOKENS[o[3] % len(TOKENS)] for o in ops if o[0] == 1):
        ops = [o for o in ops if o[0] != 1]  # anchors: see test_yaml_anchor_bomb_in_rig
    mutated = _mutate(text, ops, YAML_VALUE)
    d = tmp_path_factory.mktemp("cfg")
    target = os.path.join(d, name)
    with open(target, "w", encoding="utf-8") as f:
        f.write(mutated)
    try:
        if name == "sim.yaml":
            load_rig(target)
        else:
            load_world(target)
    except ConfigError as exc:
        for p in exc.problems:
            assert LOCATED.match(str(p)), str(p)
    except Exception as exc:  # the loaders' known gap: tags reach the YAML constructor
        import yaml

        assert isinstance(exc, yaml.YAMLError), repr(exc)
        assert "!!" in mutated or "\x00" in mutated or "&" in mutated or "*" in mutated


# ---------------------------------------------------------------------- known attacks

LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE lolz [<!ENTITY lol "lol"><!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
<!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">]>
<root BTCPP_format="4"><BehaviorTree ID="M"><Echo message="&lol3;"/></BehaviorTree></root>
"""
XXE = """<?xml version="1.0"?>
<!DOCTYPE r [<!ENTITY x SYSTEM "file:///etc/passwd">]>
<root BTCPP_format="4"><BehaviorTree ID="M"><Echo message="&x;"/></BehaviorTree></root>
"""
DTD = """<?xml version="1.0"?>
<!DOCTYPE root SYSTEM "http://127.0.0.1:9/evil.dtd">
<root BTCPP_format="4"><BehaviorTree ID="M"><Echo message="hi"/></BehaviorTree></root>
"""


@pytest.mark.parametrize("text", [LAUGHS, XXE, DTD], ids=["billion-laughs", "xxe", "dtd"])
def test_xml_entities_and_dtds_are_refused(text: str) -> None:
    problems = validate(load_xml("evil.xml", text=text), REGISTRY)
    assert problems and all(LOCATED.match(str(p)) for p in problems)
    assert "root:" not in " ".join(map(str, problems))  # /etc/passwd not read into anything


def test_yaml_mission_tags_anchors_are_refused(tmp_path) -> None:
    marker = tmp_path / "pwned"
    text = (
        f"btrun: 1\nmain: M\ntrees:\n  M:\n    Echo: {{message: !!python/object/apply:os.system "
        f'["touch {marker}"]}}\n'
    )
    problems = validate(load_yaml("evil.yaml", text=text), REGISTRY)
    assert problems and all(LOCATED.match(str(p)) for p in problems)
    assert not marker.exists()
    bomb = "a: &a [x, x, x, x, x, x, x, x]\n" + "".join(
        f"{c}: &{c} [{', '.join(['*' + p] * 8)}]\n"
        for p, c in zip("abcdefg", "bcdefgh", strict=False)
    )
    problems = validate(load_yaml("bomb.yaml", text=bomb), REGISTRY)
    assert problems and all(LOCATED.match(str(p)) for p in problems)


def test_include_loops_are_refused(tmp_path) -> None:
    a, b = tmp_path / "a.xml", tmp_path / "b.xml"
    a.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="A"><include path="b.xml"/>'
        '<BehaviorTree ID="A"><Echo message="a"/></BehaviorTree></root>'
    )
    b.write_text(
        '<root BTCPP_format="4"><include path="a.xml"/>'
        '<BehaviorTree ID="B"><Echo message="b"/></BehaviorTree></root>'
    )
    problems = validate(load_xml(str(a)), REGISTRY)
    assert any("loop" in str(p) for p in problems)
    assert all(LOCATED.match(str(p)) for p in problems)


def test_rig_python_tag_executes_nothing(tmp_path) -> None:
    from drivers.rig.loader import load_rig

    marker = tmp_path / "pwned"
    rig = tmp_path / "rig.yaml"
    rig.write_text(f'name: !!python/object/apply:os.system ["touch {marker}"]\n')
    with pytest.raises(Exception):  # noqa: B017 - refused one way or another
        load_rig(str(rig))
    assert not marker.exists()


def test_rig_python_tag_is_a_located_error(tmp_path) -> None:
    from drivers.rig.loader import load_rig

    rig = tmp_path / "rig.yaml"
    rig.write_text('name: !!python/object/apply:os.system ["true"]\n')
    with pytest.raises(ConfigError):
        load_rig(str(rig))


def test_yaml_anchor_bomb_in_rig(tmp_path) -> None:
    from drivers.rig.loader import load_rig

    rig = tmp_path / "rig.yaml"
    rig.write_text(
        "a: &a [l, l, l, l, l, l, l, l, l]\n"
        + "".join(
            f"{c}: &{c} [{', '.join(['*' + p] * 9)}]\n"
            for p, c in zip("abcdef", "bcdefg", strict=False)
        )
        + "wind: {mean_mps: *g}\n"
    )
    with pytest.raises(ConfigError) as info:
        load_rig(str(rig))
    # refused at the anchors, before anything is expanded
    assert "anchors and aliases are not allowed" in str(info.value)
    assert len(str(info.value)) < 10_000


# ------------------------------------------- fleets, campaigns and resume state (issue 31)


def _more_files() -> dict[str, tuple[str, str]]:
    out = {}
    for p in [
        os.path.join(REPO, "fleets", "aisle_2.yaml"),
        os.path.join(REPO, "campaigns", "pallet_scan.yaml"),
        os.path.join(REPO, "campaigns", "faults.yaml"),
    ]:
        out[os.path.basename(p)] = (p, open(p, encoding="utf-8").read())
    return out


MORE = _more_files()


@pytest.mark.slow
@settings(
    max_examples=150,
    deadline=5000,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(st.sampled_from(sorted(MORE)), OPS)
def test_fuzzed_fleets_and_campaigns_load_or_locate(name: str, ops) -> None:
    """A mutated fleet or campaign file loads, or every problem is one located line: never a
    traceback, whatever the mutation (NUL bytes, anchors and tags included)."""
    from bt_engine.campaign.spec import load_campaign
    from bt_engine.spec import MissionError
    from nodes.fleet.spec import load_fleet

    path, text = MORE[name]
    mutated = _mutate(text, ops, YAML_VALUE)
    target = os.path.join(os.path.dirname(path), f".fuzz-{os.getpid()}-{name}")
    with open(target, "w", encoding="utf-8") as f:  # beside the original: relative paths hold
        f.write(mutated)
    try:
        (load_fleet if name == "aisle_2.yaml" else load_campaign)(target)
    except (MissionError, ConfigError) as exc:
        for p in exc.problems:
            assert LOCATED.match(str(p)), str(p)
    finally:
        os.unlink(target)


@settings(max_examples=200, deadline=2000, derandomize=True)
@given(st.binary(max_size=400), st.integers(0, 3))
def test_fuzzed_resume_state_is_refused_located_or_read(data: bytes, where: int) -> None:
    """--resume reads a run folder's tick log header and inventory rows before flight: any
    bytes there are read or refused with one located line."""
    import tempfile

    from bt_engine.spec import MissionError
    from bt_engine.ticklog import read_log
    from nodes.inventory_log import InventoryError, read_inventory

    header = b'{"header": {"mission": "m.xml", "seed": 0, "sets": []}}\n'
    with tempfile.TemporaryDirectory() as d:
        if where < 2:
            with open(os.path.join(d, "ticks.jsonl"), "wb") as f:
                f.write(data if where == 0 else header + data)
            try:
                read_log(os.path.join(d, "ticks.jsonl"))
            except MissionError as exc:
                for p in exc.problems:
                    assert LOCATED.match(str(p)), str(p)
        else:
            with open(os.path.join(d, "inventory.json"), "wb") as f:
                f.write(data if where == 2 else b'{"rows": [' + data + b"]}")
            try:
                read_inventory(d)
            except InventoryError as exc:
                assert LOCATED.match(str(exc.problem())), str(exc.problem())
