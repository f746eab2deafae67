"""Reading a campaign file's YAML with every value's place (``file:line:col``).

:func:`scan` refuses what a campaign file never needs (tags, anchors, aliases) before
anything is built; :class:`Reader` walks PyYAML's composed nodes (safe loader only) and
collects located :class:`~bt_engine.spec.Problem` s, each naming the offending value and
what was expected. :mod:`bt_engine.campaign.spec` builds the campaign with it.
"""

from __future__ import annotations

import os
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from bt_engine.files import file_kind
from bt_engine.spec import Loc, Problem

CORE = "tag:yaml.org,2002:"
_ALLOWED_TAGS = tuple(CORE + t for t in ("str", "int", "float", "bool", "null", "map", "seq"))
#: libyaml's safe loader when PyYAML has it, else PyYAML's own
SAFE = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class Reader:
    """Reads composed YAML nodes of one file into plain values, collecting located problems."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.base = os.path.dirname(os.path.abspath(path))
        self.problems: list[Problem] = []
        self.construct = yaml.constructor.SafeConstructor().construct_object

    def loc(self, node: Any) -> Loc:
        mark = getattr(node, "start_mark", node)
        return Loc(self.path, mark.line + 1, mark.column + 1)

    def bad(self, node: Any, message: str) -> None:
        """A problem at a node (or a :class:`Loc`)."""
        self.problems.append(Problem(node if isinstance(node, Loc) else self.loc(node), message))

    def value(self, node: Node) -> Any:
        """The plain value of a node (mappings and lists of scalars included)."""
        if isinstance(node, MappingNode):
            return {str(k.value): self.value(v) for k, v in node.value}
        if isinstance(node, SequenceNode):
            return [self.value(v) for v in node.value]
        return self.construct(node)

    def pairs(self, node: Node, where: str) -> list[tuple[str, Node, Node]]:
        """(key, key node, value node) of a mapping; problems for non-text or repeated keys."""
        if not isinstance(node, MappingNode):
            self.bad(node, f"{where}: expected a mapping, got {show(self, node)}")
            return []
        out, seen = [], set()
        for k, v in node.value:
            if not isinstance(k, ScalarNode) or not str(k.value).strip():
                self.bad(k, f"{where}: a key must be a plain name")
                continue
            if k.value in seen:
                self.bad(k, f"{where}: duplicate key '{k.value}'")
                continue
            seen.add(k.value)
            out.append((str(k.value), k, v))
        return out

    def number(self, node: Node, where: str, minimum: float | None = None) -> float | None:
        v = self.value(node)
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            self.bad(node, f"{where}: expected a number, got {show(self, node)}")
            return None
        if minimum is not None and not v > minimum:
            self.bad(node, f"{where}: expected a number above {minimum:g}, got {v!r}")
            return None
        return float(v)

    def integer(self, node: Node, where: str) -> int | None:
        v = self.value(node)
        if not isinstance(v, int) or isinstance(v, bool):
            self.bad(node, f"{where}: expected an integer, got {show(self, node)}")
            return None
        return v

    def text(self, node: Node, where: str) -> str | None:
        v = self.value(node)
        if not isinstance(v, str) or not v.strip():
            self.bad(node, f"{where}: expected text, got {show(self, node)}")
            return None
        return v

    def items(self, node: Node) -> list[Node]:
        """A list's items, or the node itself (one value written without a list)."""
        return list(node.value) if isinstance(node, SequenceNode) else [node]

    def file(self, node: Node, where: str, allow_null: bool = False) -> tuple[Any, Any]:
        """(as written, resolved path) of a file entry, or (None, None) for null."""
        v = self.value(node)
        if v is None and allow_null:
            return None, None
        if not isinstance(v, str) or not v.strip():
            want = "a file path or null" if allow_null else "a file path"
            self.bad(node, f"{where}: expected {want}, got {show(self, node)}")
            return "", None
        tried = [os.path.normpath(os.path.join(b, v)) for b in (self.base, os.getcwd())]
        found = next((p for p in tried if os.path.exists(p)), None)
        kind = file_kind(found) if found is not None else None
        if kind is not None:  # a FIFO, a device, a folder: never opened
            self.bad(node, f"{where}: '{v}' is {kind}, not a regular file")
            return v, None
        if found is None:
            self.bad(
                node,
                f"{where}: file '{v}' not found (looked in {' and '.join(dict.fromkeys(tried))}; "
                "paths are relative to the campaign file, then to the current folder)",
            )
        return v, found


def show(reader: Reader, node: Node) -> str:
    if isinstance(node, MappingNode):
        return "a mapping"
    if isinstance(node, SequenceNode):
        return "a list"
    if node.tag == CORE + "null":
        return "nothing"
    return repr(reader.construct(node))


def scan(text: str, path: str) -> list[Problem]:
    """Refuse tags, anchors and aliases (a campaign file holds plain values only)."""
    try:
        for ev in yaml.parse(text, Loader=SAFE):
            where = Loc(path, ev.start_mark.line + 1, ev.start_mark.column + 1)
            if isinstance(ev, yaml.AliasEvent) or getattr(ev, "anchor", None) is not None:
                return [Problem(where, "YAML anchors and aliases are not allowed; write it out")]
            tag = getattr(ev, "tag", None)
            if isinstance(ev, (yaml.ScalarEvent, yaml.CollectionStartEvent)) and tag:
                if tag not in _ALLOWED_TAGS:
                    return [Problem(where, f"YAML tag '{tag}' is not allowed (plain values only)")]
    except yaml.reader.ReaderError as exc:  # a NUL byte or another control character
        return [Problem(_position(text, path, exc.position), _character_text(exc))]
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = Loc(path, mark.line + 1, mark.column + 1) if mark else Loc(path, 1, 1)
        return [Problem(where, f"YAML syntax error: {exc.problem}")]
    except yaml.YAMLError as exc:  # pragma: no cover - any other refusal of the parser
        return [Problem(Loc(path, 1, 1), f"YAML error: {str(exc).splitlines()[0]}")]
    return []


def _position(text: str, path: str, position: int) -> Loc:
    """The place of character ``position`` of ``text``."""
    before = text[: max(position, 0)]
    line = before.count("\n") + 1
    return Loc(path, line, len(before) - (before.rfind("\n") + 1) + 1)


def _character_text(exc: yaml.reader.ReaderError) -> str:
    char = exc.character
    if char == 0:
        return "the file holds a NUL byte; a campaign file is YAML text"
    shown = f"#x{char:04x}" if isinstance(char, int) else repr(char)
    return f"character {shown} is not allowed in YAML ({exc.reason})"
