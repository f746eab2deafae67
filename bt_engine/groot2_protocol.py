"""Groot2's wire format, and the tree and blackboards as Groot2 reads them.

What :class:`~bt_engine.groot2.Groot2Server` sends: the request types and header sizes of
BehaviorTree.CPP's ``groot2_protocol.h``, the FULLTREE XML (:func:`describe_tree`) and the
BLACKBOARD payload (:func:`encode_blackboards`). The server thread, its sockets and the
status buffer are in :mod:`bt_engine.groot2`.

Wire format (facts of the protocol, little-endian):

* request: part 1 is a 6-byte header ``protocol (u8 = 2), type (u8), unique_id (u32)``;
  BLACKBOARD, HOOK_* and TOGGLE_RECORDING carry a second part;
* reply: part 1 is the 22-byte header (the request header with protocol 2, then a 16-byte
  tree UUID), part 2 the payload: FULLTREE the tree as XML with ``_uid`` / ``_fullpath``
  metadata, STATUS ``(uid u16, status u8)`` per node (IDLE after X is ``10 + X``),
  BLACKBOARD the requested blackboards (``;``-separated names) as a JSON object encoded in
  MessagePack (by the ``msgpack`` package; objects by their readable form: :func:`readable`);
* errors: ``["error", message]`` (a wrong header, a missing second part, an unknown type).
"""

from __future__ import annotations

from typing import Any

import msgpack

from bt_engine.catalogue import groot_palette
from bt_engine.mission import Mission
from bt_engine.node import BTNode, NodeStatus
from bt_engine.ports import NO_DEFAULT, number_text
from bt_engine.registry import SUBTREE
from bt_engine.ticklog import summarise_value

PROTOCOL_ID = 2
REQUEST_HEADER_SIZE = 6
REPLY_HEADER_SIZE = 22

FULLTREE, STATUS, BLACKBOARD = b"T", b"S", b"B"
HOOK_INSERT, HOOK_REMOVE, BREAKPOINT_REACHED, BREAKPOINT_UNLOCK = b"I", b"R", b"N", b"U"
HOOKS_DUMP, REMOVE_ALL_HOOKS, DISABLE_ALL_HOOKS = b"D", b"A", b"X"
TOGGLE_RECORDING, GET_TRANSITIONS = b"r", b"t"

#: BehaviorTree.CPP's ``NodeStatus`` numbers (the status buffer's byte)
STATUS_CODE = {"IDLE": 0, "RUNNING": 1, "SUCCESS": 2, "FAILURE": 3, "SKIPPED": 4}
IDLE_FROM = 10  # IDLE after status X is sent as 10 + X

#: bounds on the blackboard values one reply holds (nesting depth, values in all)
MAX_DEPTH = 8
MAX_ITEMS = 10_000


class Groot2Error(RuntimeError):
    """The server could not start (e.g. the port is in use)."""


# -- the tree as Groot2 expects it ---------------------------------------------------------
def _esc(text: str) -> str:
    return (
        text.replace("&", "&amp;")
        .replace("<", "&lt;")
        .replace(">", "&gt;")
        .replace('"', "&quot;")
        .replace("'", "&apos;")
    )


def _text(value: Any) -> str:
    """A native attribute value (from a YAML mission) as the XML writer spells it (50.0 ->
    "50"), so the tree Groot2 gets is the one BehaviorTree.CPP reads from the XML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return ";".join(_text(v) for v in value)
    if isinstance(value, float):
        return number_text(value)
    return str(value)


def _default(port) -> str | None:
    d = port.default
    if d is None or d is NO_DEFAULT:
        return None
    try:
        return d if isinstance(d, str) else port.type.to_text(d)
    except Exception:  # a default without a text form: leave it out
        return None


class _Subtree:
    """One SubTree instance (or the main tree): its ID, full path, nodes and scope."""

    def __init__(self, tree_id: str, fullpath: str, scope: Any) -> None:
        self.tree_id = tree_id
        self.fullpath = fullpath
        self.scope = scope
        self.nodes: list[BTNode] = []
        self.xml: list[str] = []


def describe_tree(mission: Mission) -> tuple[str, list[_Subtree]]:
    """The FULLTREE XML of ``mission`` (as BehaviorTree.CPP's ``WriteTreeToXML`` with metadata
    and built-in models) and its SubTree instances in BehaviorTree.CPP's order.

    Node UIDs are BehaviorTree.CPP's: pre-order over the expanded tree, from 1.
    """
    spec, registry, nodes = mission.spec, mission.registry, mission.nodes
    main = spec.main_tree_id()
    subtrees: list[_Subtree] = []
    counter = [0]

    def visit(node_spec, sub: _Subtree, depth: int) -> None:
        model = registry.get(node_spec.type)
        node = nodes[counter[0]]
        counter[0] += 1
        uid = node.uid + 1
        sub.nodes.append(node)
        pad = "    " * depth
        attrs: dict[str, str] = {}
        if model.kind == SUBTREE:
            target = str(node_spec.attrs["ID"].value)
            own = node_spec.name or f"{target}::{uid}"
            fullpath = f"{sub.fullpath}/{own}" if sub.fullpath else own
            attrs["ID"] = target
            attrs["_fullpath"] = fullpath
        else:
            attrs["name"] = node_spec.name or model.id
        attrs["_uid"] = str(uid)
        for key, attr in node_spec.attrs.items():
            if key in ("name", "ID", "_autoremap", "_description", "_uid", "_fullpath"):
                continue
            attrs[key] = _text(attr.value)
        if model.kind != SUBTREE:
            for port in model.ports.values():
                if port.name not in attrs and port.direction != "output":
                    d = _default(port)
                    if d is not None:
                        attrs[port.name] = d
        head = f"{pad}<{model.id}" + "".join(f' {k}="{_esc(v)}"' for k, v in attrs.items())
        if model.kind == SUBTREE:
            sub.xml.append(head + "/>")
            child = _Subtree(target, fullpath, node.children[0].scope)
            subtrees.append(child)
            visit(spec.trees[target].root, child, 2)
        elif node_spec.children:
            sub.xml.append(head + ">")
            for c in node_spec.children:
                visit(c, sub, depth + 1)
            sub.xml.append(f"{pad}</{model.id}>")
        else:
            sub.xml.append(head + "/>")

    top = _Subtree(main, "", mission.scope)
    subtrees.append(top)
    visit(spec.trees[main].root, top, 2)
    if counter[0] != len(nodes):  # the builder and this walk must agree on the pre-order
        raise Groot2Error(f"tree walk found {counter[0]} nodes, the mission has {len(nodes)}")
    lines = ['<root BTCPP_format="4">']
    for sub in subtrees:
        lines.append(
            f'    <BehaviorTree ID="{_esc(sub.tree_id)}" _fullpath="{_esc(sub.fullpath)}">'
        )
        lines += sub.xml
        lines.append("    </BehaviorTree>")
    palette = groot_palette(registry, include_builtins=True)
    start, end = palette.find("<TreeNodesModel"), palette.rfind("</TreeNodesModel>")
    if start >= 0 and end > start:
        lines.append("    " + palette[start : end + len("</TreeNodesModel>")].strip())
    elif start >= 0:
        lines.append("    <TreeNodesModel/>")
    lines.append("</root>")
    return "\n".join(lines) + "\n", subtrees


# -- blackboard values as JSON (MessagePack-encoded by the msgpack package) ------------------
#: the integers MessagePack holds (int64 .. uint64); others are sent as floats
_INT_MIN, _INT_MAX = -(1 << 63), (1 << 64) - 1


def _utf8(text: str) -> str:
    """``text`` if it encodes as UTF-8, else with the lone surrogates replaced (MessagePack
    strings are UTF-8; Groot2's JSON refuses anything else)."""
    if text.isascii():
        return text
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return text.encode("utf-8", "replace").decode("utf-8")
    return text


def readable(value: Any) -> Any:
    """An object without a JSON form (a plug-in's result: a face estimate, a block scan) as
    Groot2 shows it: its ``as_dict()`` if it has one, else its repr as summary.json keeps
    it, either through :func:`bt_engine.ticklog.summarise_value` (JSON-friendly, and past
    :data:`~bt_engine.ticklog.VALUE_LIMIT_BYTES` as JSON a one-line note with type, size and
    SHA-1). Never raises: an object whose ``as_dict()`` and repr both fail is named by its
    type."""
    try:
        as_dict = getattr(value, "as_dict", None)
        if callable(as_dict):
            return summarise_value(as_dict())
    except Exception:  # a broken as_dict: the repr below
        pass
    try:
        return summarise_value(value)
    except Exception:
        return f"<{type(value).__name__} without a readable form>"


def _to_json(value: Any, depth: int = 0, budget: list[int] | None = None) -> Any:
    """A JSON-able copy of a blackboard value (bounded: depth, items); objects by
    :func:`readable`; None past the bounds."""
    budget = budget if budget is not None else [MAX_ITEMS]
    budget[0] -= 1
    if budget[0] < 0 or depth > MAX_DEPTH:
        return None
    if value is None or isinstance(value, (bool, float)):
        return value
    if isinstance(value, int):
        return value if _INT_MIN <= value <= _INT_MAX else float(value)
    if isinstance(value, str):
        return _utf8(value)
    if isinstance(value, NodeStatus):
        return value.value
    if isinstance(value, (list, tuple)):
        return [_to_json(v, depth + 1, budget) for v in value[:MAX_ITEMS]]
    if isinstance(value, dict):
        return {
            _utf8(str(k)): _to_json(v, depth + 1, budget)
            for k, v in list(value.items())[:MAX_ITEMS]
        }
    tolist = getattr(value, "tolist", None)  # numpy arrays and scalars
    if callable(tolist):
        try:
            return _to_json(tolist(), depth + 1, budget)
        except Exception:
            return None
    return _to_json(readable(value), depth + 1, budget)


def encode_blackboards(blackboards: dict[str, Any]) -> bytes:
    """The BLACKBOARD payload: ``blackboards`` (JSON values, :meth:`Groot2Server.blackboards`)
    in MessagePack, encoded by the ``msgpack`` package (strings as str, never bin).

    BehaviorTree.CPP writes it with nlohmann's ``to_msgpack`` and Groot2 reads it with
    ``from_msgpack``: both use MessagePack's smallest integer forms, as msgpack does; a
    float goes as float64 here where nlohmann writes float32 when that is exact, the same
    value to Groot2."""
    return msgpack.packb(blackboards, use_bin_type=True)
