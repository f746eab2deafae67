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

The second check of blackboard scopes here: a SubTree call that leaves an entry its tree
reads unset (:meth:`_TypeChecks.subtree_reads`).
"""

from __future__ import annotations

from typing import Any

from bt_engine.ports import ANY, PortType, PortValueError, blackboard_ref
from bt_engine.registry import SUBTREE, Registry
from bt_engine.spec import MissionSpec, NodeSpec

_CALL_ATTRS = frozenset(("ID", "_autoremap", "name"))


def _auto(node: NodeSpec) -> bool:
    value = node.attrs.get("_autoremap")
    return value is not None and str(value.value).strip().lower() in ("true", "1")


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
    """Mixed into :class:`bt_engine.validate._Validator`: uses its ``spec``, ``registry``,
    ``add``, ``scripts`` and ``enum_names``."""

    spec: MissionSpec
    registry: Registry

    def subtree_reads(self) -> None:
        """Refuse a SubTree call that leaves an entry its tree reads unset: the tree's
        blackboard is its own, so an entry it reads and nothing in it writes must come in
        through the call (``home="{home}"``, ``_autoremap="true"``) or a default of its
        ``<TreeNodesModel>`` port; otherwise the first node reading it fails in flight."""
        own: dict[str, list[tuple[str, object]]] = {}
        for tree in self.spec.trees.values():
            unset = self._unwritten_reads(tree)
            if unset:
                own[tree.id] = unset
        if not own:
            return
        for tree in self.spec.trees.values():
            roots = [r for r in (tree.root, *tree.extra_roots) if r is not None]
            for node in (n for r in roots for n in r.walk()):
                target = str(node.attrs["ID"].value) if "ID" in node.attrs else ""
                if node.type != "SubTree" or target not in own or _auto(node):
                    continue
                model = self.spec.models.get(target)
                for name, loc in own[target]:
                    if name in node.attrs:
                        continue
                    if model is not None and name in model.ports:
                        if model.ports[name].default is not None:
                            continue
                    self.add(
                        node.loc,
                        f"SubTree '{target}' reads {{{name}}} ({loc}), but this call does not "
                        f"pass it in and nothing in '{target}' writes it (a SubTree's "
                        f'blackboard is its own): pass it ({name}="{{{name}}}") or call it '
                        'with _autoremap="true"',
                    )

    def _unwritten_reads(self, tree) -> list[tuple[str, object]]:
        """``(entry, where read)`` of the entries ``tree``'s nodes read that nothing in it
        may write (first read of each); [] when anything may be written (a SetBlackboard key
        chosen at run time, a SubTree called with ``_autoremap``)."""
        reads: dict[str, object] = {}
        written: set[str] = set()
        roots = [r for r in (tree.root, *tree.extra_roots) if r is not None]
        for node in (n for r in roots for n in r.walk()):
            model = self.registry.get(node.type)
            if node.type == "SubTree" and _auto(node):
                return []
            for attr, script in self.scripts(node):
                written.update(script.writes)
                for name in sorted(script.reads):
                    reads.setdefault(name, attr.loc)
            for key, attr in node.attrs.items():
                ref = blackboard_ref(attr.value)
                if model is not None and model.id == "SetBlackboard" and key == "output_key":
                    if ref is not None:
                        return []
                    written.add(str(attr.value).strip())
                if ref is None:
                    continue
                name = key if ref == "=" else ref
                if model is None or model.kind == SUBTREE:
                    if key not in _CALL_ATTRS:
                        written.add(name)  # a SubTree's port may write back; unknown: either
                    continue
                port = model.ports.get(key)
                if port is not None and port.writes:
                    written.add(name)
                elif port is not None:
                    reads.setdefault(name, attr.loc)
        skip = written | self.enum_names()
        return [(n, loc) for n, loc in reads.items() if n not in skip and not n.startswith("@")]

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
