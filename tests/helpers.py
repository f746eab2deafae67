"""Helpers shared by tests: build missions from inline XML."""

from __future__ import annotations

import os

from bt_engine import Mission, SimClock
from bt_engine.loading import load_xml
from drivers.rig.factory import make_platform

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


def sim_mission(
    xml_or_path: str, seed: int = 0, overrides: dict | None = None, rate_hz: float = 50.0, **kw
):
    """A mission flying the in-process simulator: returns ``(mission, runner, platform)``.

    ``xml_or_path`` is a mission file path or inline XML text.
    """
    import nodes  # noqa: F401  (registers the drone leaves)
    from bt_engine import Runner
    from bt_engine.mission import load_spec
    from drivers.rig.loader import load_rig

    clock = SimClock()
    rig = load_rig(None, overrides)
    platform = make_platform(rig, clock, seed)
    if xml_or_path.lstrip().startswith("<"):
        spec = load_xml("inline.xml", text=xml_or_path)
    else:
        spec = load_spec(xml_or_path)
    kw.setdefault("resources", {"rig": rig, "platform": platform, "seed": seed})
    mission = Mission(spec, clock=clock, vehicle=platform.vehicle, **kw)
    return mission, Runner(mission, rate_hz=rate_hz, hooks=[platform]), platform


def problems_of_xml(xml: str) -> list[str]:
    """Validation problems of inline XML against the default registry (drone leaves too)."""
    import nodes  # noqa: F401
    from bt_engine.registry import REGISTRY
    from bt_engine.validate import validate

    return [str(p) for p in validate(load_xml("m.xml", text=xml), REGISTRY)]
