"""The blackboard type check of :mod:`bt_engine.validate`: a port that reads an entry as a
type no value written to it by another port can convert to.

BehaviorTree.CPP refuses a tree whose ports give one blackboard entry two different strong
types. btrun converts a value when a port reads it (an ``int`` read as a ``float`` is fine),
so it refuses only pairs that cannot work: the writer's type has no value the reader's type
converts (a ``float`` read as a ``vec3``, a ``bool`` read as a number, an enum read as
another enum with no member in common). Such a mission would fail when the reader runs,
perhaps minutes into a flight; it is refused before anything flies.

Entries are matched within one ``<BehaviorTree>`` (its own blackboard scope) and across
trees for ``{@entry}`` (the root blackboard). Values passed through SubTree ports and
written by scripts or ``SetBlackboard`` are not typed here.
"""

from __future__ import annotations

from typing import Any

from bt_engine.ports import ANY, PortType, PortValueError, blackboard_ref
from bt_engine.registry import SUBTREE, Registry
from bt_engine.spec import MissionSpec, NodeSpec


def converts_from(reader: PortType, writer: PortType) -> bool:
    """True if some value a port of type ``writer`` may hold converts to type ``reader``
    (always true when either type takes anything)."""
    if reader is ANY or reader.name == "any":
        return True
    samples = writer.samples()
    if samples is None:
        return True
    for value in samples:
        try:
            reader.convert(value)
        except PortValueError:
            continue
        return True
    return False


def _entry(key: str, value: Any) -> str | None:
    ref = blackboard_ref(value)
    if ref is None:
        return None
    return key if ref == "=" else ref


class _TypeChecks:
    """Mixed into :class:`bt_engine.validate._Validator`: uses its ``spec``, ``registry``
    and ``add``."""

    spec: MissionSpec
    registry: Registry

    def entry_types(self) -> None:
        """Refuse every input port whose entry is written, in the same scope, only as a type
        it cannot read (one problem per reading port and writer type)."""
        scopes: dict[str, tuple[list, list]] = {}
        main = self.spec.main_tree_id()
        for tree in self.spec.trees.values():
            roots = [r for r in (tree.root, *tree.extra_roots) if r is not None]
            for node in (n for r in roots for n in r.walk()):
                self._ports_of(node, "@" if tree.id == main else tree.id, scopes)
        for writers, readers in scopes.values():
            if not writers or not readers:
                continue
            for node, key, port, attr in readers:
                said: set[str] = set()
                for w_node, w_key, w_port, w_attr in writers:
                    if w_attr is attr or w_port.type.name in said:
                        continue
                    if converts_from(port.type, w_port.type):
                        continue
                    said.add(w_port.type.name)
                    entry = blackboard_ref(attr.value)
                    self.add(
                        attr.loc,
                        f"port '{key}' of {node.type} reads {{{entry}}} as {port.type.name} "
                        f"({port.type.expected}), but port '{w_key}' of {w_node.type} "
                        f"({w_attr.loc}) writes it as {w_port.type.name}: no "
                        f"{w_port.type.name} converts to {port.type.name}; use another "
                        "entry, or a port of a matching type",
                    )

    def _ports_of(self, node: NodeSpec, tree_id: str, scopes: dict) -> None:
        model = self.registry.get(node.type)
        if model is None or model.kind == SUBTREE:
            return
        for key, attr in node.attrs.items():
            port = model.ports.get(key)
            name = _entry(key, attr.value) if port is not None else None
            if name is None:
                continue
            # the main tree's own scope is the root blackboard, which {@entry} names anywhere
            scope = "@/" + name.lstrip("@") if name.startswith("@") else f"{tree_id}/{name}"
            writers, readers = scopes.setdefault(scope, ([], []))
            if port.writes:
                writers.append((node, key, port, attr))
            if port.reads:
                readers.append((node, key, port, attr))
