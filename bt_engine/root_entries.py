"""Which blackboard entries of a mission live on its root blackboard, the one ``--set`` fills.

A SubTree has a blackboard of its own (BehaviorTree.CPP's rules, :mod:`bt_engine.blackboard`):
an entry it reads reaches the root only through a port remapped to ``{entry}``, through
``_autoremap="true"`` or as ``{@entry}``. A name read only inside SubTrees whose every call
gives it a literal (``<SubTree ID="Wait" ms="10"/>``) is no input of the mission: ``--set
ms=500`` would change nothing, so it is refused rather than silently ignored.
"""

from __future__ import annotations

from typing import Any

from bt_engine.ports import blackboard_ref
from bt_engine.spec import MAX_SUBTREE_DEPTH, MissionSpec, NodeSpec

#: Tree instances walked before giving up on scopes (every name then counts as an input).
MAX_INSTANCES = 20_000

_NOT_PORTS = frozenset(("ID", "_autoremap", "name"))


class _Frame:
    """How names of one SubTree instance resolve to root entries."""

    __slots__ = ("remap", "auto", "parent")

    def __init__(self, remap: dict[str, str | None], auto: bool, parent: _Frame | None) -> None:
        self.remap, self.auto, self.parent = remap, auto, parent

    def resolve(self, name: str) -> str | None:
        """The root entry ``name`` is in this instance, or None (the instance's own)."""
        frame: _Frame | None = self
        while frame is not None:
            if name.startswith("@"):
                return name[1:]
            if frame.parent is None:  # the main tree: its entries are the root's
                return name
            if name in frame.remap:
                return frame.remap[name]
            if not frame.auto or name.startswith("_"):
                return None
            frame = frame.parent
        return None  # pragma: no cover - the loop returns at the main tree


def _tree_refs(spec: MissionSpec, reads_of: Any) -> dict[str, list[tuple[str, Any]]]:
    """Per tree: ``(name, location)`` of every entry its nodes name (a SubTree call's
    ``{entry}`` is the calling tree's)."""
    out: dict[str, list[tuple[str, Any]]] = {}
    for tree in spec.trees.values():
        refs: list[tuple[str, Any]] = []
        roots = [r for r in (tree.root, *tree.extra_roots) if r is not None]
        for node in (n for r in roots for n in r.walk()):
            for name, loc in reads_of(node):
                refs.append((name, loc))
            for key, attr in node.attrs.items():
                ref = blackboard_ref(attr.value)
                if ref is not None and not (node.type == "SubTree" and key in _NOT_PORTS):
                    refs.append((key if ref == "=" else ref, attr.loc))
        out[tree.id] = refs
    return out


def _calls(node: NodeSpec, spec: MissionSpec) -> bool:
    return (
        node.type == "SubTree" and "ID" in node.attrs and str(node.attrs["ID"].value) in spec.trees
    )


def root_entries(spec: MissionSpec, reads_of: Any) -> tuple[set[str], dict[str, Any]] | None:
    """``(names, inner)``: the entries the mission's trees name that are on the root
    blackboard, and for the other names the location of one place that names them (inside a
    SubTree whose calls never pass the root's entry in). ``reads_of(node)`` yields
    ``(name, location)`` of the entries a node's scripts read. None when the trees are
    too many to walk (the caller then treats every name as the root's)."""
    main = spec.main_tree_id()
    if main not in spec.trees:
        return None
    refs = _tree_refs(spec, reads_of)
    names: set[str] = set()
    inner: dict[str, Any] = {}
    stack: list[tuple[str, _Frame, int]] = [(main, _Frame({}, False, None), 0)]
    walked = 0
    while stack:
        tree_id, frame, depth = stack.pop()
        walked += 1
        if walked > MAX_INSTANCES or depth > MAX_SUBTREE_DEPTH:
            return None
        for name, loc in refs[tree_id]:
            root = frame.resolve(name)
            if root is not None:
                names.add(root.lstrip("@"))
            else:
                inner.setdefault(name, loc)
        tree = spec.trees[tree_id]
        roots = [r for r in (tree.root, *tree.extra_roots) if r is not None]
        for node in (n for r in roots for n in r.walk()):
            if not _calls(node, spec):
                continue
            remap: dict[str, str | None] = {}
            for key, attr in node.attrs.items():
                if key in _NOT_PORTS:
                    continue
                ref = blackboard_ref(attr.value)
                remap[key] = frame.resolve(key if ref == "=" else ref) if ref else None
            auto = str(getattr(node.attrs.get("_autoremap"), "value", "")).lower() in ("true", "1")
            stack.append((str(node.attrs["ID"].value), _Frame(remap, auto, frame), depth + 1))
    return names, {k: v for k, v in inner.items() if k not in names}
