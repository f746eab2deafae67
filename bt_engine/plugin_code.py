"""Faults of a plug-in's code while a mission is checked or built, as located problems.

A node class whose ``__init__`` raises, or a port type whose ``convert`` raises something
other than :class:`~bt_engine.ports.PortValueError`, would otherwise end ``btrun validate``
or ``btrun run`` with a Python traceback. Here they become a
:class:`~bt_engine.spec.Problem` at the mission's node or attribute, naming the plug-in's
``file:line`` (:func:`bt_engine.node_checks.raised_at`).
"""

from __future__ import annotations

from typing import Any

from bt_engine.node_checks import said
from bt_engine.registry import SUBTREE, Registry
from bt_engine.spec import MissionSpec, Problem


def creation_said(model: Any, exc: BaseException) -> str:
    """The message of a node of ``model`` whose ``__init__`` raised ``exc``."""
    return f"{model.id} could not be created: {said(exc, model.cls)}"


def conversion_said(port: Any, node_type: str, value: Any, exc: BaseException) -> str:
    """The message of port ``port`` of ``node_type`` whose type raised ``exc`` (not a
    :class:`~bt_engine.ports.PortValueError`) converting ``value``."""
    kind = getattr(port.type, "name", type(port.type).__name__)
    return (
        f"port '{port.name}' of {node_type}: {value!r:.60} could not be converted to "
        f"{kind}: {said(exc, type(port.type))}"
    )


def creation_problems(spec: MissionSpec, registry: Registry) -> list[Problem]:
    """One problem per node type of the mission whose class cannot be created (its
    ``__init__(name, ctx)`` raises), at its first node: ``btrun validate`` says it, and
    nothing is built. Only classes with an ``__init__`` of their own (outside the engine)
    are tried, once each, with a mission context that has no vehicle and no resources. A
    ``sys.exit()`` in one is such a problem too (``SystemExit: 4 (raised at FILE:LINE)``)."""
    from bt_engine.clock import SimClock
    from bt_engine.node import MissionContext

    out: list[Problem] = []
    tried: set[str] = set()
    for tree in spec.trees.values():
        for root in [tree.root, *tree.extra_roots]:
            for node in root.walk() if root is not None else ():
                model = registry.get(node.type)
                if model is None or model.kind == SUBTREE or model.id in tried:
                    continue
                tried.add(model.id)
                init = getattr(model.cls.__init__, "__module__", "") or ""
                if init.startswith("bt_engine."):
                    continue  # the engine's own: it raises nothing
                try:
                    model.cls(node.name or model.id, MissionContext(SimClock()))
                except (Exception, SystemExit) as exc:  # noqa: BLE001 - a plug-in's code:
                    # said, located (a sys.exit() in it ended btrun with its code, silently;
                    # Ctrl-C still stops btrun)
                    out.append(Problem(node.type_loc or node.loc, creation_said(model, exc)))
    return out
