"""Reading the hand-writable YAML mission format into a :class:`~bt_engine.spec.MissionSpec`.

See ``docs/mission-yaml.md`` for the schema. Parsing uses PyYAML's safe loader only (libyaml's
``CSafeLoader`` when available) and walks the composed node graph, so every tree, node and attribute keeps the
``file:line:col`` of its key. YAML tags (other than the core scalar ones), anchors and
aliases are refused, file size, node count, nesting depth and attributes per node
(:data:`~bt_engine.spec.MAX_ATTRIBUTES`) are capped. A list item indented differently from
the items before it is reported as such, not as PyYAML's parser error. PyYAML drops
comments, so full-line ``#`` comments are recovered from the source text: a run of them
directly above a node (or tree) is attached to it, and leading ones become the file header.
:mod:`bt_engine.yaml_writer` writes a spec back as YAML.
"""

from __future__ import annotations

import os
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from bt_engine.files import MAX_FILE_BYTES, read_text
from bt_engine.registry import KINDS, SUBTREE, suggest_name
from bt_engine.spec import (
    MAX_ATTRIBUTES,
    AttrSpec,
    Loc,
    MissionSpec,
    ModelSpec,
    NodeSpec,
    PortModel,
    Problem,
    TreeSpec,
)
from bt_engine.xml_io import Include

TOP_KEYS = ("btrun", "main", "include", "trees", "models")
MODEL_KEYS = ("kind", "description", "ports")
PORT_KEYS = ("direction", "type", "default", "description")
DIRECTIONS = ("input", "output", "inout")
MAX_YAML_NODES = 200_000
MAX_DEPTH = 200
_CORE = "tag:yaml.org,2002:"
ALLOWED_TAGS = tuple(_CORE + t for t in ("str", "int", "float", "bool", "null"))
#: libyaml's SafeLoader when PyYAML has it (same safe constructor, ~30x faster), else PyYAML's
_SAFE = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _text(node: Node) -> bool:
    return isinstance(node, ScalarNode) and node.tag == _CORE + "str" and node.value != ""


def _null(node: Node) -> bool:
    return isinstance(node, ScalarNode) and node.tag == _CORE + "null"


def _kind(node: Node) -> str:
    if isinstance(node, (MappingNode, SequenceNode)):
        return "a mapping" if isinstance(node, MappingNode) else "a list"
    return "nothing" if _null(node) else repr(node.value)


_BAD = object()  # a value that was reported as a problem


class _YamlLoader:
    def __init__(
        self,
        file: str,
        text: str,
        spec: MissionSpec,
        stack: tuple[str, ...],
        include: Include | None = None,
    ) -> None:
        self.file, self.text, self.spec, self.stack = file, text, spec, stack
        self.include = include
        self.top = len(stack) <= 1
        self.lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
        self.claimed: set[int] = set()  # 1-based lines already used (comments, scalars)
        self.construct = yaml.constructor.SafeConstructor().construct_object

    def problem(self, where: Any, message: str) -> None:
        loc = where if isinstance(where, Loc) else self.loc(where)
        self.spec.load_problems.append(Problem(loc, message))

    def loc(self, node: Any) -> Loc:
        mark = getattr(node, "start_mark", node)
        return Loc(self.file, mark.line + 1, mark.column + 1)

    # -- parsing --------------------------------------------------------------------------
    def run(self) -> None:
        if len(self.text) > MAX_FILE_BYTES:
            self.problem(Loc(self.file, 1, 1), f"file is larger than {MAX_FILE_BYTES} bytes")
            return
        if not self._scan_events():
            return
        try:
            root = yaml.compose(self.text, Loader=_SAFE)
        except yaml.YAMLError as exc:
            self._syntax(exc)
            return
        if not isinstance(root, MappingNode):
            got = "the file is empty" if root is None else f"got {_kind(root)}"
            where = Loc(self.file, 1, 1) if root is None else root
            self.problem(where, f"the top level must be a mapping with `trees:` ({got})")
            return
        self._claim_scalars(root)
        if self.top:
            self.spec.root_loc = self.loc(root)
            for line in range(1, root.start_mark.line + 1):
                self._claim_comment(line, self.spec.comments)
        for name, key, value in self._pairs(root):
            if self.top:
                self.spec.comments.extend(self._comments_above(key))
            if name == "btrun":
                if not (value.tag == _CORE + "int" and value.value.strip() == "1"):
                    self.problem(
                        value,
                        f"btrun: {_kind(value)} is not a supported format version (expected 1)",
                    )
            elif name == "main":
                if not _text(value):
                    self.problem(value, f"main: expected the ID of a tree, got {_kind(value)}")
                elif self.top:
                    self.spec.main_tree, self.spec.root_loc = value.value, self.loc(value)
            elif name == "include":
                for item in value.value if isinstance(value, SequenceNode) else [value]:
                    if _text(item):
                        self._include(item)
                    else:
                        self.problem(
                            item, f"include: expected a relative file path, got {_kind(item)}"
                        )
            elif name == "trees" and self._mapping(
                value, "trees", "tree IDs mapped to their root node"
            ):
                for tid, tkey, tval in self._pairs(value):
                    self._tree(tid, tkey, tval)
            elif name == "models" and self._mapping(
                value, "models", "node IDs mapped to {kind, ports}"
            ):
                for mid, mkey, mval in self._pairs(value):
                    self._model(mid, mkey, mval)
            elif name not in TOP_KEYS:
                self._unknown_key(key, name, TOP_KEYS, "top-level key")

    def _scan_events(self) -> bool:
        """Refuse tags, anchors, aliases, too many values and too deep nesting before composing.

        The first refusal stops loading (one located problem is enough).
        """
        depth, count = 0, 0
        try:
            for ev in yaml.parse(self.text, Loader=_SAFE):
                depth -= isinstance(ev, yaml.CollectionEndEvent)
                if isinstance(ev, yaml.AliasEvent):
                    msg = f"YAML aliases (*{ev.anchor}) are not allowed in mission files"
                    self.problem(ev, msg + "; write the value out")
                    return False
                if not isinstance(ev, (yaml.ScalarEvent, yaml.CollectionStartEvent)):
                    continue
                if ev.anchor is not None:
                    self.problem(
                        ev, f"YAML anchors (&{ev.anchor}) are not allowed in mission files"
                    )
                    return False
                if ev.tag is not None and ev.tag not in ALLOWED_TAGS:
                    tag = ev.tag.replace(_CORE, "!!", 1) if ev.tag.startswith(_CORE) else ev.tag
                    self.problem(
                        ev, f"YAML tag '{tag}' is not allowed in mission files (only plain values)"
                    )
                    return False
                count += 1
                depth += isinstance(ev, yaml.CollectionStartEvent)
                if depth > MAX_DEPTH or count > MAX_YAML_NODES:
                    what = f"more than {MAX_YAML_NODES} YAML values"
                    what = f"nested more than {MAX_DEPTH} deep" if depth > MAX_DEPTH else what
                    self.problem(ev, f"the file has {what}; refusing to load it")
                    return False
        except yaml.YAMLError as exc:
            self._syntax(exc)
            return False
        return True

    # -- list items indented differently from their siblings -------------------------------
    def _item_col(self, i: int) -> int | None:
        """The 0-based column of the ``-`` of a list item on line ``i`` (0-based), or None."""
        text = self.lines[i] if 0 <= i < len(self.lines) else ""
        rest = text.lstrip(" ")
        return len(text) - len(rest) if rest == "-" or rest.startswith("- ") else None

    def _misindented(self, i: int) -> Problem | None:
        """A problem if line ``i`` (0-based) is a list item whose ``-`` lines up with no
        open list above it (and it does not start a new list under a ``key:`` line)."""
        col = self._item_col(i)
        if col is None:
            return None
        low, above, first = len(self.lines[i]), None, True
        for j in range(i - 1, -1, -1):  # up the lines that enclose line i
            text = self.lines[j]
            rest = text.lstrip(" ")
            if not rest or rest.startswith("#"):
                continue
            indent = len(text) - len(rest)
            if first and rest.rstrip().endswith(":") and indent <= col:
                return None  # the first item of a list under "key:"
            first = False
            if indent < low:
                low = indent
                item = self._item_col(j)
                if item == col:
                    return None  # lines up with the items of an enclosing list
                if item is not None and above is None:
                    above = item
            if low == 0:
                break
        if above is None:
            return None
        return Problem(
            Loc(self.file, i + 1, col + 1),
            f"this list item is indented differently from the ones before it (its '-' is in "
            f"column {col + 1}, the item above has it in column {above + 1}); the items of "
            "one list must line up",
        )

    def _syntax(self, exc: yaml.YAMLError) -> None:
        bad = yaml.reader.Reader.NON_PRINTABLE.search(self.text)
        if isinstance(exc, yaml.reader.ReaderError) and bad:
            before = self.text[: bad.start()]
            loc = Loc(self.file, before.count("\n") + 1, bad.start() - before.rfind("\n"))
            self.problem(loc, f"YAML syntax error: unacceptable character {bad.group()!r}")
            return
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        if mark is not None:  # the item itself, or the line before the one YAML stopped at
            found = self._misindented(mark.line) or self._misindented(mark.line - 1)
            if found is not None:
                self.spec.load_problems.append(found)
                return
        msg = getattr(exc, "problem", None) or str(exc)
        if getattr(exc, "context", None):
            msg += f" ({exc.context})"
        line = (
            self.lines[mark.line][: mark.column + 1] if mark and mark.line < len(self.lines) else ""
        )
        if "\t" in line:
            msg += "; indent with spaces, not tabs"
        self.problem(mark or Loc(self.file, 1, 1), f"YAML syntax error: {msg}")

    def _pairs(self, mapping: MappingNode):
        """Yield ``(name, key_node, value_node)``; report non-scalar and duplicate keys."""
        seen: dict[str, Loc] = {}
        for key, value in mapping.value:
            if not (isinstance(key, ScalarNode) and key.value):
                self.problem(key, f"expected a name as key, got {_kind(key)}")
            elif key.value in seen:
                self.problem(key, f"duplicate key '{key.value}' (first at {seen[key.value]})")
            else:
                seen[key.value] = self.loc(key)
                yield key.value, key, value

    def _mapping(self, node: Node, what: str, expected: str) -> bool:
        if not isinstance(node, MappingNode) and not _null(node):
            self.problem(node, f"{what}: expected {expected}, got {_kind(node)}")
        return isinstance(node, MappingNode)

    def _unknown_key(self, key: Node, name: str, known: tuple[str, ...], what: str) -> None:
        hint = suggest_name(name, list(known))
        tail = f"; did you mean '{hint}'?" if hint else ""
        self.problem(key, f"unknown {what} '{name}' (expected {', '.join(known)}){tail}")

    # -- comments -------------------------------------------------------------------------
    def _claim_scalars(self, root: Node) -> None:
        """Lines inside (multi-line) scalars are never comments."""
        todo = [root]
        while todo:
            n = todo.pop()
            if isinstance(n, ScalarNode):
                end = n.end_mark.line + (n.end_mark.column > 0)
                self.claimed.update(range(n.start_mark.line + 1, end + 1))
            else:
                todo.extend(
                    n.value if isinstance(n, SequenceNode) else [x for kv in n.value for x in kv]
                )

    def _claim_comment(self, line: int, out: list[str]) -> bool:
        text = self.lines[line - 1].strip() if 0 < line <= len(self.lines) else ""
        if not text.startswith("#") or line in self.claimed:
            return False
        self.claimed.add(line)
        out.append(text[1:].strip())
        return True

    def _comments_above(self, node: Node) -> list[str]:
        """The run of full-line comments directly above ``node`` (each is used only once)."""
        line, found = node.start_mark.line, []  # 1-based number of the line above
        while line > 0 and self._claim_comment(line, found):
            line -= 1
        return found[::-1]

    # -- trees and nodes ------------------------------------------------------------------
    def _tree(self, tid: str, key: Node, value: Node) -> None:
        loc = self.loc(key)
        if tid in self.spec.trees:
            self.problem(
                loc, f"tree '{tid}' is defined twice (first at {self.spec.trees[tid].loc})"
            )
            return
        tree = self.spec.trees[tid] = TreeSpec(tid, loc, comments=self._comments_above(key))
        nodes = [] if _null(value) else value.value if isinstance(value, SequenceNode) else [value]
        if not nodes:
            eg = f"`{tid}: {{Sequence: [...]}}`"
            self.problem(loc, f"tree '{tid}' is empty: expected its root node, e.g. {eg}")
            return
        roots = [self._node(n) for n in nodes]
        tree.root, tree.extra_roots = roots[0], roots[1:]

    def _node(self, n: Node) -> NodeSpec:
        bad = NodeSpec("?", self.loc(n))  # stands in for a wrong node, so parents stay right
        if isinstance(n, ScalarNode) and _text(n):
            if not n.style and n.end_mark.line > n.start_mark.line:
                # "- A\n    - B" is the plain text "A - B" to YAML: B is indented too far
                for j in range(n.start_mark.line + 1, n.end_mark.line + 1):
                    col = self._item_col(j)
                    if col is not None:
                        self.problem(
                            Loc(self.file, j + 1, col + 1),
                            "this list item is indented differently from the ones before it "
                            f"(more than the item above), so YAML reads it as more of the text "
                            f"{n.value[:60]!r}; the items of one list must line up",
                        )
                        return bad
            notes = self._comments_above(n)
            return NodeSpec(n.value, bad.loc, tag=n.value, comments=notes, type_loc=bad.loc)
        if not isinstance(n, MappingNode) or not n.value:
            got = "an empty mapping" if isinstance(n, MappingNode) else _kind(n)
            eg = "a type name such as AlwaysSuccess, or `GoTo: {pose: [1, 0, 1]}`"
            self.problem(n, f"expected a node ({eg}), got {got}")
            return bad
        if len(n.value) > 1:
            names = [k.value for k, _ in n.value if isinstance(k, ScalarNode)]
            self.problem(
                n.value[1][0],
                f"a node is a mapping with one key, its type; found {len(n.value)} keys "
                f"({', '.join(names)}). Put the attributes inside the node, indented under "
                f"'{names[0]}:' or as `{names[0]}: {{...}}`",
            )
            return bad
        key, value = n.value[0]
        if not _text(key):
            self.problem(key, f"expected a node type name, got {_kind(key)}")
            return bad
        kloc = self.loc(key)
        node = NodeSpec(
            key.value, kloc, tag=key.value, comments=self._comments_above(key), type_loc=kloc
        )
        if isinstance(value, SequenceNode):
            node.children = [self._node(c) for c in value.value]
        elif isinstance(value, MappingNode) and len(value.value) > MAX_ATTRIBUTES:
            self.problem(
                value,
                f"{key.value} has {len(value.value)} attributes; the limit is "
                f"{MAX_ATTRIBUTES} (MAX_ATTRIBUTES)",
            )
            return bad
        elif isinstance(value, MappingNode):
            self._attrs(node, value)
        elif not _null(value):
            hint = f" (write `SubTree: {{ID: {value.value}}}`)" if key.value == "SubTree" else ""
            want = "attributes `{port: value}`, a list of children or nothing"
            self.problem(value, f"{key.value}: expected {want}; got {_kind(value)}{hint}")
        return node

    def _attrs(self, node: NodeSpec, mapping: MappingNode) -> None:
        child_key = None
        for name, key, value in self._pairs(mapping):
            if name in ("child", "children") and child_key is not None:
                self.problem(key, f"{node.type} has both `{child_key}:` and `{name}:`; use one")
            elif name == "children" and isinstance(value, SequenceNode):
                child_key, node.children = name, [self._node(c) for c in value.value]
            elif name == "child" and not isinstance(value, SequenceNode) and not _null(value):
                child_key, node.children = name, [self._node(value)]
            elif name == "children":
                want, hint = (
                    "a list of nodes (`- Type: ...` lines)",
                    "use `child:` for a single node",
                )
                self.problem(value, f"children: expected {want}, got {_kind(value)}; {hint}")
            elif name == "child":
                hint = "; use `children:` for a list" if isinstance(value, SequenceNode) else ""
                self.problem(value, f"child: expected a single node, got {_kind(value)}{hint}")
            elif _null(value):
                hint = f'write {name}: "" for empty text'
                self.problem(key, f"attribute '{name}' of {node.type} has no value ({hint})")
            elif (val := self._value(value, name)) is not _BAD:
                node.attrs["_autoremap" if name == "__autoremap" else name] = AttrSpec(
                    val, self.loc(key)
                )

    def _value(self, n: Node, name: str) -> Any:
        """A native value; a one-key mapping with no value is the blackboard reference ``{key}``."""
        if isinstance(n, ScalarNode):
            if (
                n.tag in ALLOWED_TAGS[1:]
            ):  # int, float, bool, null; others (timestamps...) stay text
                return self.construct(n)
            return n.value
        if isinstance(n, SequenceNode):
            items = [self._value(c, name) for c in n.value]
            return _BAD if _BAD in items else items
        (k, v), *more = n.value or [(None, None)]
        if not more and isinstance(k, ScalarNode) and k.value and _null(v):
            return "{" + k.value + "}"
        want = "a value (number, text, true/false or a list)"
        self.problem(
            n, f"'{name}': expected {want}, got a mapping; a reference is written \"{{entry}}\""
        )
        return _BAD

    # -- models and includes --------------------------------------------------------------
    def _fields(self, node: Node, what: str, known: tuple[str, ...]):
        """Yield ``(name, value_node, native_value)`` of a model or port mapping."""
        if self._mapping(node, what, "a mapping with " + ", ".join(known)):
            for name, key, value in self._pairs(node):
                if name not in known:
                    self._unknown_key(key, name, known, f"key of {what}")
                    continue
                val = None if _null(value) or name == "ports" else self._value(value, name)
                if val is not _BAD:
                    yield name, value, val

    def _model(self, mid: str, key: Node, value: Node) -> None:
        model = ModelSpec(mid, SUBTREE, self.loc(key))
        for name, node, val in self._fields(value, f"model '{mid}'", MODEL_KEYS):
            if name == "kind" and val not in KINDS:
                self.problem(node, f"kind: expected one of {', '.join(KINDS)}, got {_kind(node)}")
            elif name == "kind" or name == "description":
                setattr(model, name, "" if val is None else str(val))
            elif self._mapping(node, "ports", "port names mapped to {direction, type, ...}"):
                for pname, _pkey, pvalue in self._pairs(node):
                    port = model.ports[pname] = PortModel(pname, "input")
                    what = f"port '{pname}' of model '{mid}'"
                    for field, fnode, fval in self._fields(pvalue, what, PORT_KEYS):
                        if field == "direction" and fval not in DIRECTIONS:
                            want = ", ".join(DIRECTIONS)
                            self.problem(
                                fnode, f"direction: expected one of {want}, got {_kind(fnode)}"
                            )
                        elif field == "default":
                            port.default = fval
                        else:
                            setattr(port, field, "" if fval is None else str(fval))
        self.spec.models.setdefault(mid, model)

    def _include(self, item: ScalarNode) -> None:
        if self.include is None:
            self.problem(self.loc(item), "includes are resolved by bt_engine.loading.load_spec")
            return
        self.include(item.value, self.loc(item), self.file, self.spec, self.stack)


def merge_yaml(
    path: str, text: str, spec: MissionSpec, stack: tuple[str, ...], include: Include | None
) -> None:
    """Load the YAML file ``path`` (already read into ``text``) into ``spec``.

    ``stack`` holds the absolute paths of the files being loaded, this one last; only the
    first file of the stack sets the main tree and the header comments. ``include``
    resolves ``include:`` entries.
    """
    _YamlLoader(path, text, spec, stack, include).run()


def load_yaml(path: str, text: str | None = None, include: Include | None = None) -> MissionSpec:
    """Load a YAML mission into a spec; problems land in ``load_problems``, never raised.

    Includes need ``include`` (:func:`bt_engine.loading.load_spec` passes it)."""
    spec = MissionSpec(file=path)
    if text is None:
        text = read_text(path, spec.load_problems)
        if text is None:
            return spec
    merge_yaml(path, text, spec, (os.path.abspath(path),), include)
    return spec
