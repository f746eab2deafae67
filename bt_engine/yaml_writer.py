"""Writing a :class:`~bt_engine.spec.MissionSpec` as the hand-writable YAML mission format.

:func:`dump_yaml` writes what :func:`bt_engine.yaml_io.load_yaml` reads (see
``docs/mission-yaml.md``): XML attribute text becomes native YAML values through the
registry's port types, small attribute maps are written in flow style, comments are kept.
"""

from __future__ import annotations

from typing import Any

import yaml

from bt_engine.ports import BOOL, PortValueError, blackboard_ref
from bt_engine.registry import DECORATOR, REGISTRY, SUBTREE, Registry
from bt_engine.spec import MissionSpec, NodeSpec
from bt_engine.validate import CONDITION_ATTRS, SPECIAL_ATTRS
from bt_engine.yaml_io import PORT_KEYS

_WIDE = 1_000_000
FLOW_WIDTH = 100


def _fmt(value: Any) -> str:
    """A value as a one-line YAML flow value (strings quoted only when needed, with ``"``)."""
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_fmt(k)}: {_fmt(v)}" for k, v in value.items()) + "}"
    if not isinstance(value, (str, int, float, bool, type(None))):
        value = str(value)
    text = yaml.safe_dump([value], default_flow_style=True, width=_WIDE, allow_unicode=True)
    if text.startswith("['"):  # prefer "..." (escapes, and the usual look of "{key}")
        text = yaml.safe_dump(
            [value], default_flow_style=True, width=_WIDE, allow_unicode=True, default_style='"'
        )
    return text.strip()[1:-1]


def _comment_lines(comments: list[str], ind: int) -> list[str]:
    lines = [ln.strip() for c in comments for ln in (c.splitlines() or [""])]
    return [" " * ind + ("# " + ln if ln else "#") for ln in lines]


class _Dumper:
    def __init__(self, spec: MissionSpec, registry: Registry) -> None:
        self.spec = spec
        self.registry = registry

    def value(self, node: NodeSpec, key: str, value: Any) -> Any:
        """XML text -> native YAML value using the registry's port type, when one is known."""
        if not isinstance(value, str) or blackboard_ref(value) is not None:
            return value
        model = self.registry.get(node.type)
        if model is None or key in SPECIAL_ATTRS or key in CONDITION_ATTRS:
            return value
        if model.kind == SUBTREE:  # SubTree port literals are passed on as written
            port_type = BOOL if key == "_autoremap" else None
        else:
            port = model.ports.get(key)
            literal_ok = port is not None and (not port.writes or port.takes_literal)
            port_type = port.type if literal_ok else None
        try:
            return value if port_type is None else port_type.to_yaml(port_type.convert(value))
        except PortValueError:
            return value

    def item(self, node: NodeSpec, ind: int) -> list[str]:
        lines = self.node(node, ind + 2)
        lines[0] = " " * ind + "- " + lines[0][ind + 2 :]
        return _comment_lines(node.comments, ind) + lines

    def node(self, node: NodeSpec, ind: int) -> list[str]:
        pad, head = " " * ind, _fmt(node.type)
        attrs = [(_fmt(k), _fmt(self.value(node, k, a.value))) for k, a in node.attrs.items()]
        kids = node.children
        if not attrs and not kids:
            return [pad + head]
        if not kids:
            flow = f"{pad}{head}: {{" + ", ".join(f"{k}: {v}" for k, v in attrs) + "}"
            if len(flow) <= FLOW_WIDTH:
                return [flow]
        model = self.registry.get(node.type)
        single = len(kids) == 1 and model is not None and model.kind == DECORATOR
        lines = [pad + head + ":"]
        if not attrs and not single:
            for c in kids:
                lines += self.item(c, ind + 2)
            return lines
        lines += [f"{pad}  {k}: {v}" for k, v in attrs]
        if single:
            lines.append(pad + "  child:")
            lines += _comment_lines(kids[0].comments, ind + 4) + self.node(kids[0], ind + 4)
        elif kids:
            lines.append(pad + "  children:")
            for c in kids:
                lines += self.item(c, ind + 4)
        return lines

    def dump(self) -> str:
        spec = self.spec
        out = _comment_lines(spec.comments, 0) + ["btrun: 1"]
        main = spec.main_tree_id()
        if main:
            out.append(f"main: {_fmt(main)}")
        out.append("trees:")
        for tree in spec.trees.values():
            out += _comment_lines(tree.comments, 2)
            roots = [tree.root] + tree.extra_roots if tree.root is not None else []
            out.append(f"  {_fmt(tree.id)}:" + ("" if roots else " null"))
            if len(roots) == 1:
                out += _comment_lines(roots[0].comments, 4) + self.node(roots[0], 4)
            else:
                for r in roots:
                    out += self.item(r, 4)
        if spec.models:
            out.append("models:")
        for m in spec.models.values():
            out += [f"  {_fmt(m.id)}:", f"    kind: {_fmt(m.kind)}"]
            if m.description:
                out.append(f"    description: {_fmt(m.description)}")
            if m.ports:
                out.append("    ports:")
            for p in m.ports.values():
                fields = (p.direction, p.type, p.default, p.description)
                items = [
                    f"{k}: {_fmt(v)}"
                    for k, v in zip(PORT_KEYS, fields, strict=True)
                    # an empty default is a default (the input is optional), not none
                    if v is not None and (v != "" or k == "default")
                ]
                flow = f"      {_fmt(p.name)}: {{" + ", ".join(items) + "}"
                block = [f"      {_fmt(p.name)}:"] + ["        " + i for i in items]
                out += [flow] if len(flow) <= FLOW_WIDTH else block
        return "\n".join(out) + "\n"


def dump_yaml(spec: MissionSpec, registry: Registry | None = None) -> str:
    """Write a spec as hand-readable YAML (included trees are written inline).

    ``registry`` (default: the process-wide one) gives port types, so XML text such as
    ``"1;2;3"`` becomes ``[1.0, 2.0, 3.0]``; values of unknown ports stay text.
    """
    return _Dumper(spec, registry if registry is not None else REGISTRY).dump()
