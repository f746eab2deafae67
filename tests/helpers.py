"""Helpers shared by tests: build missions from inline XML, wait on loopback peers."""

from __future__ import annotations

import contextlib
import importlib.util
import os
import sys
import time
from collections.abc import Callable, Iterator
from types import ModuleType

from bt_engine import Mission, SimClock
from bt_engine.loading import load_xml
from drivers.rig.factory import make_platform

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@contextlib.contextmanager
def bench_module(name: str) -> Iterator[ModuleType]:
    """``bench/<name>.py`` imported as the module ``bench_<name>`` (registered in
    ``sys.modules`` while in use: dataclasses look their module up)."""
    path = os.path.join(REPO, "bench", f"{name}.py")
    spec = importlib.util.spec_from_file_location(f"bench_{name}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(spec.name, None)


def wait_until(condition: Callable[[], object], timeout_s: float, what: str, step_s: float = 0.005):
    """Poll ``condition()`` every ``step_s`` until it is truthy; return that value.

    For tests that wait on something running in real time in another thread or process: an
    emulator or stream client on 127.0.0.1, a motion-capture reader, a ``btrun`` subprocess.
    Raises ``AssertionError("timed out after <timeout_s> s waiting for <what>")`` (a test
    failure naming what never happened) if it is still falsy after ``timeout_s`` seconds of
    wall time; the condition is evaluated one last time at the deadline.

    ``timeout_s`` only keeps a broken test from hanging: it is not a performance bound, so
    make it generous (seconds, not milliseconds); the wait ends as soon as the condition
    holds. Tests on a simulated clock never need this (step the clock instead of sleeping).
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(step_s)
    value = condition()
    if not value:
        raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
    return value


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
    xml_or_path: str,
    seed: int = 0,
    overrides: dict | None = None,
    rate_hz: float = 50.0,
    rig: str | None = None,
    **kw,
):
    """A mission flying the in-process simulator: returns ``(mission, runner, platform)``.

    ``xml_or_path`` is a mission file path or inline XML text; ``rig`` a rig file (relative
    to the repository; default rigs/sim.yaml).
    """
    import nodes  # noqa: F401  (registers the drone leaves)
    from bt_engine import Runner
    from bt_engine.mission import load_spec
    from drivers.rig.loader import load_rig

    clock = SimClock()
    rig = load_rig(os.path.join(REPO, rig) if rig else None, overrides)
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


#: The rest of a leaf-only test plug-in module: a plug-in object with no rig, report or
#: command of its own (the module's leaves register themselves when it is imported).
LEAF_PLUGIN_TAIL = """

class _Plugin:
    name = "test-leaves"

    def load_target(self, rig_path, overrides):
        return None

    def write_report(self, run_dir, trace, summary, mission):
        return None

    def commands(self):
        return {}


PLUGIN = _Plugin()
"""


def leaf_plugin_env(folder, module: str, leaves: str) -> dict[str, str]:
    """Write ``folder/<module>.py`` (the ``leaves`` source and :data:`LEAF_PLUGIN_TAIL`) and
    return an environment in which a ``btrun`` subprocess loads it as a plug-in."""
    with open(os.path.join(str(folder), f"{module}.py"), "w", encoding="utf-8") as f:
        f.write(leaves + LEAF_PLUGIN_TAIL)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join((str(folder), REPO))
    env["BTRUN_PLUGINS"] = f"{module}:PLUGIN"
    return env


def children(pid: int) -> set[int]:
    """The live child processes of ``pid`` (Linux /proc)."""
    out = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid and fields[0] != "Z":
                out.add(int(entry))
    return out


def cmdline(pid: int) -> str:
    """Process ``pid``'s command line, its arguments joined by spaces ("" once it is gone)."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""
