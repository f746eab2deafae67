"""A plug-in that cannot be loaded (named in ``BTRUN_PLUGINS`` or installed) is refused
with one line that says which, where it was named and why, never a traceback, and nothing
runs (exit 2)."""

from __future__ import annotations

import json
import os
import re

import pytest
from helpers import REPO

from bt_engine import plugins
from bt_engine.cli import main


@pytest.fixture
def plugin_env(tmp_path, monkeypatch):
    """Set ``BTRUN_PLUGINS`` to a module written in ``tmp_path`` (fresh plug-in list)."""

    import sys

    import nodes  # noqa: F401  (btrun's own leaves registered before the snapshot below)
    from bt_engine.registry import REGISTRY

    module = []

    def use(spec: str, source: str | None = None) -> None:
        module.append(spec.partition(":")[0])
        if source is not None:
            (tmp_path / f"{module[-1]}.py").write_text(source)
        monkeypatch.syspath_prepend(str(tmp_path))
        monkeypatch.setenv("BTRUN_PLUGINS", spec)
        monkeypatch.setattr(plugins, "_loaded", None)

    saved = (dict(REGISTRY._models), dict(REGISTRY._aliases))
    yield use
    plugins._loaded = None  # the next test loads the installed plug-ins again
    REGISTRY._models, REGISTRY._aliases = saved  # no test leaf left registered
    for name in module:
        sys.modules.pop(name, None)


@pytest.mark.parametrize(
    "spec, source, expected",
    [
        (
            "no_such_plugin_mod:PLUGIN",
            None,
            "btrun: plug-in 'no_such_plugin_mod:PLUGIN' (BTRUN_PLUGINS) could not be loaded: "
            "ModuleNotFoundError: No module named 'no_such_plugin_mod'",
        ),
        (
            "half_plugin:PLUGIN",
            "class P:\n    name = 'half'\n\nPLUGIN = P()\n",
            "btrun: plug-in 'half_plugin:PLUGIN' (BTRUN_PLUGINS) is not a plug-in object: it "
            "lacks load_target, write_report, commands",
        ),
        (
            "wrong_plugin:PLUGIN",
            "class P:\n    name = 3\n    load_target = 'sim'\n    write_report = None\n"
            "    commands = []\n\nPLUGIN = P()\n",
            "btrun: plug-in 'wrong_plugin:PLUGIN' (BTRUN_PLUGINS) is not a plug-in object: "
            "name is int, not a string; load_target is str, not a method or None; commands "
            "is list, not a method or a dict",
        ),
        (
            "typo_plugin:PLUGN",
            "PLUGIN = None\n",
            "could not be loaded: AttributeError: module 'typo_plugin' has no attribute 'PLUGN'",
        ),
        (
            "raising_plugin",
            "import os\n\nraise RuntimeError('no licence file')\n",
            "could not be loaded: RuntimeError: no licence file (",
        ),
        (
            "syntax_plugin",
            "import os\n\ndef leaf(:\n    pass\n",
            "syntax_plugin.py:3:10: SyntaxError: invalid syntax in 'def leaf(:'",
        ),
    ],
)
def test_a_plugin_that_cannot_load_is_one_line_and_exit_2(
    plugin_env, tmp_path, capsys, spec, source, expected
):
    plugin_env(spec, source)
    assert main(["missions/square.xml", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()
    if spec == "raising_plugin":  # where in the plug-in's own code it failed
        assert f"{tmp_path / 'raising_plugin.py'}:3)" in err
    if spec == "syntax_plugin":  # the whole path, not Python's bare file name
        assert f"{tmp_path / 'syntax_plugin.py'}:3:10:" in err


_LEAF = """
from bt_engine import StatefulActionNode, register, SUCCESS
from bt_engine.ports import INT, input_port


@register
class {cls}(StatefulActionNode):
    \"\"\"A leaf of a plug-in.\"\"\"

    bt_id = {bt_id!r}
    ports = {ports}

    def on_start(self):
        return SUCCESS
"""


@pytest.mark.parametrize(
    "bt_id, ports, expected",
    [
        ("TakeOff", "()", "a node called 'TakeOff' is already registered: give yours another"),
        ("Snap", '(input_port("a", INT, 1), input_port("a", INT, 2))', "port 'a': declared twice"),
        ("Bad Id", "()", "node ID 'Bad Id': expected an XML name: letters, digits, _, . and -"),
        (
            "Snap",
            '(input_port("count", INT, "three"),)',
            "port 'count': default 'three': expected a whole number",
        ),  # fmt: skip
        ("Snap", '(input_port("name", INT, 1),)', "port 'name': a reserved attribute name"),
        (  # every mission keeping the default would be refused before flight
            "Snap",
            '(input_port("count", INT, 9, low=1, high=5),)',
            "port 'count': default outside its range: count 9: expected 1 to 5",
        ),
        (
            "Snap",
            '(input_port("count", INT, 3, low=5, high=1),)',
            "port 'count': range 5 to 1 is empty",
        ),
        (
            "Snap",
            '(input_port("_x", INT, 1),)',
            "port '_x': expected an XML name: letters, digits, _, . and -, starting with a letter or _, not starting with _",
        ),
        # a type as <TreeNodesModel> writes it, a Python type, a direction, a range bound,
        # a plain tuple: each crashed every command later with a traceback
        (
            "Snap",
            '(input_port("speed", "float"),)',
            "port 'speed': type 'float' is not a port type",
        ),
        (
            "Snap",
            '(input_port("speed", float, 1.0),)',
            "port 'speed': type <class 'float'> is not a port type",
        ),
        ("Snap", '(input_port("n", INT, 1, low="a"),)', "port 'n': low must be a number, got 'a'"),
        ("Snap", '(("speed", INT),)', "a port must be declared with bt_engine.ports.input_port"),
    ],
)
def test_a_leaf_a_mission_could_not_use_is_refused_at_its_class(
    plugin_env, tmp_path, capsys, bt_id, ports, expected
):
    """A plug-in leaf whose ID or ports a mission file could not write, with a port declared
    twice or a default its type refuses (which would fail only in flight), is refused when
    the plug-in loads, located at the leaf's class in the plug-in's file."""
    from helpers import LEAF_PLUGIN_TAIL

    source = _LEAF.format(cls="Leaf", bt_id=bt_id, ports=ports) + LEAF_PLUGIN_TAIL
    plugin_env("leafy_plugin:PLUGIN", source)
    assert main(["validate", "missions/square.xml"]) == 2
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err, err
    line = source.splitlines().index("@register") + 1
    assert err.rstrip().endswith(f"({tmp_path / 'leafy_plugin.py'}:{line})")


def test_a_good_plugin_leaf_loads_and_validates(plugin_env, tmp_path, capsys):
    from helpers import LEAF_PLUGIN_TAIL

    ports = '(input_port("count", INT, 3),)'
    plugin_env("good_plugin:PLUGIN", _LEAF.format(cls="Leaf", bt_id="Snap", ports=ports) + LEAF_PLUGIN_TAIL)  # fmt: skip
    mission = tmp_path / "m.xml"
    mission.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Main"><Snap count="2"/></BehaviorTree></root>'
    )
    assert main(["validate", str(mission)]) == 0, capsys.readouterr().err


def test_a_leaf_only_plugin_may_give_none_and_a_dict_for_its_members(plugin_env, tmp_path, capsys):
    """``load_target = None``, ``write_report = None``, ``commands = {}`` (what the docs'
    "None: it flies nothing" reads as) is a plug-in that flies nothing: it was refused with
    "it lacks nothing"; its leaves now fly on btrun's own simulator."""
    source = _LEAF_ONLY.replace(
        "CLASS_BODY", "load_target = None\n    write_report = None\n    commands = {}"
    )
    plugin_env("leafonly_plugin:PLUGIN", source)
    assert _fly(tmp_path, '<Count2 n="{n}"/>')["n"] == 2
    assert [p.name for p in plugins.load_plugins()][-1] == "leaf-only"
    assert "fleet" in plugins.plugin_commands()  # its {} beside btrun's own commands


_LEAF_ONLY = """
from bt_engine import StatefulActionNode, register, RUNNING, SUCCESS
from bt_engine.ports import INT, output_port


@register
class Count2(StatefulActionNode):
    \"\"\"Count to two.\"\"\"

    bt_id = "Count2"
    ports = (output_port("n", INT, "the count"),)

    def on_start(self):
        self.k = 0
        return RUNNING

    def on_running(self):
        self.k += 1
        self.set_output("n", self.k)
        return SUCCESS if self.k == 2 else RUNNING


class _P:
    name = "leaf-only"
    CLASS_BODY


PLUGIN = _P()
"""


def test_the_docs_plugin_example_flies_as_written(plugin_env, tmp_path):
    """docs/engine.md's leaf and smallest plug-in, copied as a user would, fly a mission."""
    with open(os.path.join(REPO, "docs", "engine.md"), encoding="utf-8") as f:
        blocks = re.findall(r"```python\n(.*?)```", f.read(), re.S)
    plugin_env("photography:PLUGIN", blocks[0] + "\n\n" + blocks[1])
    assert _fly(tmp_path, '<Photograph count="4" taken="{taken}"/>')["taken"] == 4
    # and the page's own my_mission.xml
    with open(os.path.join(REPO, "docs", "engine.md"), encoding="utf-8") as f:
        mission = re.findall(r"```xml\n(<root.*?Photograph.*?)```", f.read(), re.S)[0]
    (tmp_path / "my_mission.xml").write_text(mission)
    out = tmp_path / "docs-run"
    args = [str(tmp_path / "my_mission.xml"), "--out", str(out), "-q", "--no-report", "--no-mcap"]
    assert main(args) == 0
    with open(out / "summary.json", encoding="utf-8") as f:
        assert json.load(f)["blackboard"]["taken"] == 4


def _fly(tmp_path, leaf: str) -> dict:
    """Fly take-off, ``leaf``, land on the default rig; the run's final blackboard."""
    mission = tmp_path / "my_mission.xml"
    mission.write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main">'
        f'<Sequence><TakeOff height="0.5"/>{leaf}<Land/></Sequence></BehaviorTree></root>'
    )
    out = tmp_path / "run"
    assert main([str(mission), "--out", str(out), "--quiet", "--no-report"]) == 0
    return json.loads((out / "summary.json").read_text())["blackboard"]


def test_a_plugin_command_named_as_btrun_s_own_is_refused(plugin_env, tmp_path, capsys):
    """A plug-in command called 'validate' broke every btrun call with argparse's
    traceback ("conflicting subparser")."""
    source = """
class _C:
    help = "x"

    def setup(self, parser):
        pass

    def run(self, args):
        return 0


class _P:
    name = "clash"
    load_target = None
    write_report = None
    commands = {"validate": _C()}


PLUGIN = _P()
"""
    plugin_env("clash_plugin:PLUGIN", source)
    assert main(["validate", "missions/square.xml"]) == 2
    err = capsys.readouterr().err
    assert "plug-in 'clash': command 'validate' is one of btrun's own commands" in err
    assert "Traceback" not in err


def test_a_preflight_that_returns_no_pairs_is_said(plugin_env, tmp_path, capsys):
    """A plug-in leaf's preflight() returning a bare string crashed the run ("too many
    values to unpack") after the platform was built."""
    from helpers import LEAF_PLUGIN_TAIL

    leaf = _LEAF.format(cls="Leaf", bt_id="Snap", ports="()")
    leaf += "\n    def preflight(self):\n        return ['just a string']\n"
    plugin_env("pf_plugin:PLUGIN", leaf + LEAF_PLUGIN_TAIL)
    mission = tmp_path / "m.xml"
    mission.write_text(
        '<root BTCPP_format="4"><BehaviorTree ID="Main"><Snap/></BehaviorTree></root>'
    )
    assert main([str(mission), "--out", str(tmp_path / "run"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "Snap: pre-flight check returned 'just a string'; expected (port, message)" in err
    assert "Traceback" not in err and not (tmp_path / "run").exists()


def test_a_leaf_that_returns_no_status_or_reads_an_undeclared_port_is_said(
    plugin_env, tmp_path, capsys
):
    """`return True` ended the run as `internal error ...: KeyError: True`; get_input of a
    port the leaf never declared said "has no value"."""
    from helpers import LEAF_PLUGIN_TAIL

    source = _LEAF.format(cls="Leaf", bt_id="Snap", ports="()").replace(
        "return SUCCESS", "return True"
    )
    source += (
        _LEAF.format(cls="Peek", bt_id="Peek", ports="()")
        .split("\n", 3)[3]
        .replace("return SUCCESS", "return self.get_input('nope')")
    )
    plugin_env("bad_leaf_plugin:PLUGIN", source + LEAF_PLUGIN_TAIL)
    for leaf, said in (
        ("Snap", "Snap 'Snap': returned True: a node returns SUCCESS, FAILURE or RUNNING"),
        ("Peek", "input port 'nope' is not declared by this node (its ports: none)"),
    ):
        mission = tmp_path / f"{leaf}.xml"
        mission.write_text(
            f'<root BTCPP_format="4"><BehaviorTree ID="Main"><{leaf}/></BehaviorTree></root>'
        )
        out = tmp_path / f"run-{leaf}"
        assert main([str(mission), "--out", str(out), "-q", "--no-report"]) == 1
        reason = json.loads((out / "summary.json").read_text())["reason"]
        assert said in reason and "KeyError" not in reason, reason
