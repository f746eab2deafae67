"""A new leaf is one decorated class in one module: nothing else to edit.

Once its module is imported, the leaf validates in missions and shows in ``btrun nodes``, the
Groot2 palette and the Markdown node reference, all generated from the registry.
"""

from __future__ import annotations

import importlib
import sys
import textwrap

import pytest
from helpers import wrap
from lxml import etree

import nodes  # noqa: F401  (register the drone leaves before the registry snapshot)
from bt_engine.cli import main
from bt_engine.registry import REGISTRY

LEAF_MODULE = '''
"""A leaf defined outside btrun, as a user would write it."""

from bt_engine.node import SUCCESS, NodeStatus, SyncActionNode
from bt_engine.ports import FLOAT, input_port, output_port
from bt_engine.registry import register


@register
class MeasureShelfGap(SyncActionNode):
    """Measure the gap between two shelves (a test leaf).

    Writes ``gap`` = ``top`` - ``bottom``.
    """

    category = "test"
    ports = (
        input_port("top", FLOAT, 1.5, "upper shelf height, m"),
        input_port("bottom", FLOAT, description="lower shelf height, m"),
        output_port("gap", FLOAT, "the gap, m"),
    )

    def tick_impl(self) -> NodeStatus:
        self.set_output("gap", self.get_input("top") - self.get_input("bottom"))
        return SUCCESS
'''


@pytest.fixture
def new_leaf(tmp_path, monkeypatch):
    """Import a temporary module holding one decorated leaf; forget it afterwards."""
    name = "btrun_test_new_leaf"
    (tmp_path / f"{name}.py").write_text(textwrap.dedent(LEAF_MODULE))
    monkeypatch.syspath_prepend(str(tmp_path))
    saved = (dict(REGISTRY._models), dict(REGISTRY._aliases))
    assert "MeasureShelfGap" not in REGISTRY
    try:
        yield importlib.import_module(name)
    finally:
        REGISTRY._models, REGISTRY._aliases = saved
        sys.modules.pop(name, None)


def test_decorated_leaf_validates_in_a_mission(new_leaf, tmp_path, capsys):
    assert REGISTRY.get("MeasureShelfGap").cls is new_leaf.MeasureShelfGap
    good = tmp_path / "good.xml"
    good.write_text(wrap('<MeasureShelfGap bottom="0.4" gap="{gap}"/>'))
    assert main(["validate", str(good)]) == 0
    bad = tmp_path / "bad.xml"
    bad.write_text(wrap('<MeasureShelfGap botom="0.4" gap="{gap}"/>'))
    capsys.readouterr()
    assert main(["validate", str(bad)]) == 2
    out = capsys.readouterr().err
    assert "MeasureShelfGap needs port 'bottom'" in out
    assert "did you mean 'bottom'?" in out


def test_decorated_leaf_is_in_the_catalogue_palette_and_reference(new_leaf, tmp_path, capsys):
    assert main(["nodes", "--kind", "action"]) == 0
    listing = capsys.readouterr().out
    assert "MeasureShelfGap" in listing and "Measure the gap between two shelves" in listing
    assert "in  bottom: float (required) - lower shelf height, m" in listing

    palette = tmp_path / "palette.xml"
    assert main(["nodes", "--groot", str(palette)]) == 0
    node = etree.parse(str(palette)).getroot().find("TreeNodesModel/Action[@ID='MeasureShelfGap']")
    assert node is not None
    ports = {
        p.get("name"): (p.tag, p.get("type"), p.get("default"))
        for p in node
        if p.tag.endswith("_port")
    }
    assert ports == {
        "top": ("input_port", "double", "1.5"),
        "bottom": ("input_port", "double", None),
        "gap": ("output_port", "double", None),
    }

    reference = tmp_path / "nodes.md"
    assert main(["nodes", "--markdown", str(reference)]) == 0
    text = reference.read_text()
    assert "### MeasureShelfGap\n\n*Action* · test\n" in text
    assert "| `bottom` | input | float | *required* | lower shelf height, m |" in text
