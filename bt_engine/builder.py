"""Spec -> running tree of nodes, with one blackboard scope per mission and per SubTree.

Building recurses once per level of the expanded tree; validation bounds that depth
(:data:`~bt_engine.spec.MAX_NESTING_DEPTH`), and the builder checks it again, so an
unvalidated spec raises a located :class:`~bt_engine.spec.MissionError`, never a
``RecursionError``.
"""

from __future__ import annotations

from typing import Any

from bt_engine.blackboard import Scope
from bt_engine.node import POST_CONDITIONS, PRE_CONDITIONS, BTNode, MissionContext
from bt_engine.plugin_code import conversion_said, creation_said
from bt_engine.ports import PortValueError, blackboard_ref
from bt_engine.registry import SUBTREE, Registry
from bt_engine.script import parse_script
from bt_engine.spec import MAX_NESTING_DEPTH, MissionError, MissionSpec, NodeSpec, Problem
from bt_engine.spec import nesting_message as _nesting_message
from bt_engine.validate import SPECIAL_ATTRS


class _Builder:
    def __init__(self, spec: MissionSpec, registry: Registry, ctx: MissionContext) -> None:
        self.spec = spec
        self.registry = registry
        self.ctx = ctx
        self.nodes: list[BTNode] = []
        self.changes: list = []

    def build(self, tree_id: str, scope: Scope, path: str, depth: int = 1) -> BTNode:
        root = self.spec.trees[tree_id].root
        assert root is not None
        return self.node(root, scope, path, None, depth)

    def node(
        self,
        spec: NodeSpec,
        scope: Scope,
        parent_path: str,
        label: str | None = None,
        depth: int = 1,
    ) -> BTNode:
        if depth > MAX_NESTING_DEPTH:
            raise MissionError([Problem(spec.loc, _nesting_message(depth, " once built"))])
        model = self.registry.get(spec.type)
        assert model is not None, spec.type
        name = spec.name or model.id
        path = f"{parent_path}/{label or name}"
        try:
            node = model.cls(name, self.ctx)
        except Exception as exc:  # a plug-in's __init__: located, never a traceback
            problem = Problem(spec.type_loc or spec.loc, creation_said(model, exc))
            raise MissionError([problem]) from exc
        node.bt_id = model.id
        node.loc = spec.loc
        node.path = path
        node.scope = scope
        node.uid = len(self.nodes)
        node._changes = self.changes
        self.nodes.append(node)
        self.conditions(node, spec)
        if model.kind == SUBTREE:
            self.subtree(node, spec, scope, path, depth)
            return node
        for key, attr in spec.attrs.items():
            if key in SPECIAL_ATTRS or key.startswith("_"):
                continue
            port = model.ports[key]
            ref = blackboard_ref(attr.value)
            if ref is not None:
                node.bind_entry(key, key if ref == "=" else ref)
            else:
                try:
                    value = port.type.convert(attr.value)
                except Exception as exc:  # a plug-in's port type: located, not a traceback
                    said = str(exc) if isinstance(exc, PortValueError) else None
                    message = (
                        f"port '{key}' of {spec.type}: {said}"
                        if said is not None
                        else conversion_said(port, spec.type, attr.value, exc)
                    )
                    raise MissionError([Problem(attr.loc, message)]) from None
                node.bind_literal(key, value)
        for key, port in model.ports.items():  # a default naming an entry ("{kk}"), as
            # BehaviorTree.CPP's InputPort<T>("k", "{kk}", ...): the port reads that entry
            if key not in spec.attrs and isinstance(port.default, str):
                ref = blackboard_ref(port.default)
                if ref is not None:
                    node.bind_entry(key, key if ref == "=" else ref)
        labels = _child_labels(spec.children, self.registry)
        for child_spec, child_label in zip(spec.children, labels, strict=True):
            node.add_child(self.node(child_spec, scope, path, child_label, depth + 1))
        return node

    def conditions(self, node: BTNode, spec: NodeSpec) -> None:
        pre = [
            (i, parse_script(str(spec.attrs[k].value)))
            for i, k in enumerate(PRE_CONDITIONS)
            if k in spec.attrs
        ]
        post = {
            k: parse_script(str(spec.attrs[k].value)) for k in POST_CONDITIONS if k in spec.attrs
        }
        node._pre = pre or None
        node._post = post or None

    def subtree(self, node: BTNode, spec: NodeSpec, scope: Scope, path: str, depth: int) -> None:
        target = str(spec.attrs["ID"].value)
        auto_attr = spec.attrs.get("_autoremap")
        autoremap = auto_attr is not None and str(auto_attr.value).strip().lower() in ("true", "1")
        remap: dict[str, str] = {}
        literals: dict[str, Any] = {}
        for key, attr in spec.attrs.items():
            if key in ("ID", "_autoremap") or key in SPECIAL_ATTRS or key.startswith("_"):
                continue
            ref = blackboard_ref(attr.value)
            if ref is not None:
                remap[key] = key if ref == "=" else ref
            else:
                literals[key] = attr.value
        model = self.spec.models.get(target)
        defaults: dict[str, Any] = {}
        if model is not None:
            for p in model.ports.values():
                if p.name not in remap and p.name not in literals and p.default is not None:
                    defaults[p.name] = p.default
        child_scope = Scope(
            f"{path.split('/', 1)[-1]}", parent=scope, remap=remap, autoremap=autoremap
        )
        if autoremap:
            # BehaviorTree.CPP: under _autoremap the port is the parent's entry of that name
            # (a local default had hidden the parent's value and swallowed the tree's
            # writes); the default is read only while no scope holds the entry
            child_scope.defaults = defaults or None
        else:
            literals.update(defaults)
        child_scope.prefix = f"{scope.root.prefix}{path.split('/', 1)[-1]}/"
        for k, v in literals.items():
            child_scope._store[child_scope.prefix + k] = v
        node.subtree_id = target
        node.add_child(self.build(target, child_scope, path, depth + 1))


def _child_labels(children: list[NodeSpec], registry: Registry) -> list[str]:
    names = []
    for c in children:
        m = registry.get(c.type)
        names.append(c.name or (m.id if m else c.type))
    out = []
    for i, n in enumerate(names):
        if names.count(n) > 1:
            out.append(f"{n}[{names[:i].count(n)}]")
        else:
            out.append(n)
    return out


def build_tree(
    spec: MissionSpec,
    registry: Registry,
    ctx: MissionContext,
    namespace: str | None = None,
) -> tuple[BTNode, Scope, list[BTNode], list[BTNode]]:
    """Build the main tree of a *validated* spec.

    Returns ``(root, root_scope, nodes_in_preorder, change_list)``; ``change_list`` collects
    nodes whose status changed (the tree drains it after each tick).
    """
    main = spec.main_tree_id()
    scope = Scope("", namespace=namespace)
    b = _Builder(spec, registry, ctx)
    root = b.build(main, scope, main)
    return root, scope, b.nodes, b.changes
