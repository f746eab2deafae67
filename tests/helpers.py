"""Helpers shared by tests: build missions from inline XML."""

from __future__ import annotations

import os

from bt_engine import Mission, SimClock
from bt_engine.xml_io import load_xml

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
def xml_mission(xml: str, path: str = "inline.xml", **kwargs) -> Mission:
    """Build a Mission from XML text (a SimClock unless one is given)."""
    kwargs.setdefault("clock", SimClock())
    return Mission(load_xml(path, text=xml), **kwargs)


def wrap(body: str, extra: str = "") -> str:
    """A one-tree mission document around ``body``."""
    return (
        '<root BTCPP_format="4" main_tree_to_execute="Main">\n'
        f'  <BehaviorTree ID="Main">\n{body}\n  </BehaviorTree>\n{extra}</root>\n'
    )
