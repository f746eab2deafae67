"""BehaviorTree.CPP v4 XML (as drawn by Groot2) <-> :class:`~bt_engine.spec.MissionSpec`.

Parsing uses lxml with entity resolution, DTD loading and network access off; a file that
declares a DOCTYPE or entities is refused outright. lxml reports the line where a start tag
*ends*, so a small scanner over the source text finds where each tag and attribute begins,
giving exact ``file:line:col`` locations.

Accepted spellings: compact ``<GoTo .../>`` and explicit ``<Action ID="GoTo" .../>``;
``<Condition|Control|Decorator ID=...>``; v3 ``SequenceStar``, ``SubTreePlus`` and
``__autoremap``; a missing ``BTCPP_format``.

Work is bounded: at most ``MAX_ELEMENTS`` elements per file and
:data:`~bt_engine.spec.MAX_ATTRIBUTES` attributes per element (checked by the scanner, before
lxml parses anything), nodes nested at most :data:`~bt_engine.spec.MAX_NESTING_DEPTH` deep.
"""

from __future__ import annotations

import bisect
import os
import re
from collections.abc import Callable
from typing import Any

from lxml import etree

from bt_engine.files import read_text
from bt_engine.spec import (
    MAX_ATTRIBUTES,
    MAX_NESTING_DEPTH,
    AttrSpec,
    Loc,
    MissionSpec,
    ModelSpec,
    NodeSpec,
    PortModel,
    Problem,
    TreeSpec,
    nesting_message,
)

EXPLICIT_TAGS = ("Action", "Condition", "Control", "Decorator")
PORT_TAGS = {"input_port": "input", "output_port": "output", "inout_port": "inout"}

#: Most elements (tags) in one XML file.
MAX_ELEMENTS = 100_000

_NAME = r"[A-Za-z_:][\w.\-:]*"
_NAME_RE = re.compile(_NAME)
# An attribute value cannot hold "<" (XML forbids it), so a value scan stops at the next tag:
# an unterminated quote costs the rest of one tag, not the rest of the file per tag.
_ATTR = re.compile(r"\s*(" + _NAME + r")\s*=\s*(\"[^\"<]*\"|'[^'<]*')", re.S)


class _Positions:
    """Start offsets of every start tag and its attributes, in document order."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.line_starts = [0] + [m.end() for m in re.finditer("\n", text)]
        self.tags: list[tuple[int, dict[str, int]]] = []
        self.doctype_at: int | None = None
        #: ``(offset, message)`` if the file has too many elements or attributes on one
        self.too_much: tuple[int, str] | None = None
        self._scan()

    def _scan(self) -> None:
        t = self.text
        i = t.find("<")
        while i != -1:
            if t.startswith("<!--", i):
                j = t.find("-->", i + 4)
                i = t.find("<", j + 3 if j != -1 else len(t))
                continue
            if t.startswith("<![CDATA[", i):
                j = t.find("]]>", i)
                i = t.find("<", j + 3 if j != -1 else len(t))
                continue
            if t.startswith("<!", i):
                if self.doctype_at is None:
                    self.doctype_at = i
                i = t.find("<", i + 2)
                continue
            if t.startswith("<?", i) or t.startswith("</", i):
                i = t.find("<", i + 2)
                continue
            m = _NAME_RE.match(t, i + 1)
            attrs: dict[str, int] = {}
            pos = m.end() if m else i + 1
            count = 0
            while True:
                am = _ATTR.match(t, pos)
                if not am:
                    break
                count += 1
                if count > MAX_ATTRIBUTES:
                    name = m.group() if m else "?"
                    self.too_much = (
                        i,
                        f"<{name}> has more than {MAX_ATTRIBUTES} attributes; the limit is "
                        f"{MAX_ATTRIBUTES} (MAX_ATTRIBUTES)",
                    )
                    return
                attrs[am.group(1)] = am.start(1)
                pos = am.end()
            if len(self.tags) >= MAX_ELEMENTS:
                self.too_much = (
                    i,
                    f"the file has more than {MAX_ELEMENTS} elements; the limit is "
                    f"{MAX_ELEMENTS} (MAX_ELEMENTS)",
                )
                return
            self.tags.append((i, attrs))
            i = t.find("<", pos)

    def loc(self, file: str, offset: int) -> Loc:
        line = bisect.bisect_right(self.line_starts, offset)
        return Loc(file, line, offset - self.line_starts[line - 1] + 1)


def _is_element(el: Any) -> bool:
    return isinstance(el.tag, str)


#: ``include(ref, loc, including_file, spec, stack)``: resolve and merge an included file.
Include = Callable[[str, Loc, str, MissionSpec, tuple[str, ...]], None]


class _Loader:
    def __init__(
        self,
        file: str,
        text: str,
        spec: MissionSpec,
        stack: tuple[str, ...],
        include: Include | None = None,
    ) -> None:
        self.file = file
        self.include = include
        self.text = text
        self.spec = spec
        self.stack = stack
        self.problems = spec.load_problems
        self.pos = _Positions(text)
        self.locs: dict[Any, tuple[Loc, dict[str, Loc]]] = {}

    def problem(self, loc: Loc, message: str) -> None:
        self.problems.append(Problem(loc, message))

    def run(self) -> None:
        if self.pos.doctype_at is not None:
            self.problem(
                self.pos.loc(self.file, self.pos.doctype_at),
                "DOCTYPE, DTD and entity declarations are not allowed in mission files",
            )
            return
        if self.pos.too_much is not None:
            offset, message = self.pos.too_much
            self.problem(self.pos.loc(self.file, offset), message + "; refusing to load it")
            return
        parser = etree.XMLParser(
            resolve_entities=False,
            no_network=True,
            load_dtd=False,
            dtd_validation=False,
            huge_tree=False,
            remove_comments=False,
            remove_pis=True,
        )
        try:
            root = etree.fromstring(self.text.encode("utf-8"), parser)
        except etree.XMLSyntaxError as exc:
            line, col = exc.position if exc.position else (exc.lineno or 0, 0)
            msg = re.sub(r",? line \d+, column \d+.*$", "", str(exc.msg or exc)[:500])
            if "Excessive depth" in msg:  # libxml2 stops at 256 levels (without XML_PARSE_HUGE)
                msg = (
                    "elements nested more than 256 deep; nodes may nest at most "
                    f"{MAX_NESTING_DEPTH} deep (MAX_NESTING_DEPTH)"
                )
            self.problem(Loc(self.file, line, col), f"XML syntax error: {msg}")
            return
        elements = [el for el in root.iter() if _is_element(el)]
        for el, (off, attrs) in zip(elements, self.pos.tags, strict=False):
            self.locs[el] = (
                self.pos.loc(self.file, off),
                {k: self.pos.loc(self.file, v) for k, v in attrs.items()},
            )
        self._root(root)

    def loc(self, el: Any) -> Loc:
        return self.locs.get(el, (Loc(self.file, el.sourceline or 0, 1), {}))[0]

    def attr_loc(self, el: Any, name: str) -> Loc:
        entry = self.locs.get(el)
        if entry and name in entry[1]:
            return entry[1][name]
        return self.loc(el)

    def _root(self, root: Any) -> None:
        spec = self.spec
        top = not self.stack[:-1]
        if root.tag != "root":
            self.problem(self.loc(root), f"the top element must be <root>, not <{root.tag}>")
            return
        if top:
            spec.root_loc = self.loc(root)
            spec.format_version = root.get("BTCPP_format")
            if spec.format_version not in (None, "3", "4"):
                self.problem(
                    self.attr_loc(root, "BTCPP_format"),
                    f'BTCPP_format="{spec.format_version}" is not supported (expected "4", or "3")',
                )
            main = root.get("main_tree_to_execute")
            if main:
                spec.main_tree = main
        pending: list[str] = []
        for child in root:
            if not _is_element(child):
                pending.append(_comment_text(child))
                continue
            if child.tag == "BehaviorTree":
                self._tree(child, pending)
            elif child.tag == "TreeNodesModel":
                self._models(child)
            elif child.tag == "include":
                self._include(child)
            else:
                self.problem(
                    self.loc(child),
                    f"unexpected <{child.tag}> under <root> (expected <BehaviorTree>, "
                    "<TreeNodesModel> or <include>)",
                )
            pending = []
        if top and pending:
            spec.comments.extend(pending)
        if top:
            before = root.getprevious()
            head = []
            while before is not None:
                if not _is_element(before):
                    head.insert(0, _comment_text(before))
                before = before.getprevious()
            spec.comments[:0] = head

    def _tree(self, el: Any, comments: list[str]) -> None:
        tid = el.get("ID")
        loc = self.loc(el)
        if not tid:
            self.problem(loc, "<BehaviorTree> needs an ID attribute")
            return
        if tid in self.spec.trees:
            self.problem(
                self.attr_loc(el, "ID"),
                f"tree '{tid}' is defined twice (first at {self.spec.trees[tid].loc})",
            )
            return
        tree = TreeSpec(tid, loc, comments=list(comments))
        nodes = []
        pending: list[str] = []
        for child in el:
            if not _is_element(child):
                pending.append(_comment_text(child))
                continue
            nodes.append(self._node(child, pending, 1))
            pending = []
        if not nodes:
            self.problem(loc, f"tree '{tid}' is empty: a <BehaviorTree> needs exactly one child")
        else:
            tree.root = nodes[0]
            tree.extra_roots = nodes[1:]
        self.spec.trees[tid] = tree

    def _node(self, el: Any, comments: list[str], depth: int) -> NodeSpec:
        tag = el.tag
        loc = self.loc(el)
        if depth > MAX_NESTING_DEPTH:
            self.problem(loc, nesting_message(depth))
            return NodeSpec("?", loc, tag=str(tag))  # its children are not read
        attrs = {}
        for name, value in el.attrib.items():
            # v3 spellings of a shared blackboard (Aerostack2 files use __shared_blackboard)
            key = "_autoremap" if name in ("__autoremap", "__shared_blackboard") else name
            attrs[key] = AttrSpec(value, self.attr_loc(el, name))
        node_type = tag
        type_loc = loc
        if tag in EXPLICIT_TAGS:
            ident = attrs.pop("ID", None)
            if ident is None:
                self.problem(loc, f'<{tag}> needs an ID attribute naming the node (e.g. ID="GoTo")')
                node_type = "?"
            else:
                node_type = str(ident.value)
                type_loc = ident.loc
        elif tag in ("SubTree", "SubTreePlus"):
            node_type = "SubTree"
        spec = NodeSpec(node_type, loc, attrs, tag=tag, comments=list(comments), type_loc=type_loc)
        pending: list[str] = []
        for child in el:
            if not _is_element(child):
                pending.append(_comment_text(child))
                continue
            spec.children.append(self._node(child, pending, depth + 1))
            pending = []
            if depth == MAX_NESTING_DEPTH:
                break  # one problem for the first child too deep is enough
        return spec

    def _models(self, el: Any) -> None:
        for m in el:
            if not _is_element(m):
                continue
            mid = m.get("ID")
            if not mid:
                self.problem(self.loc(m), f"<{m.tag}> in <TreeNodesModel> needs an ID")
                continue
            model = ModelSpec(mid, m.tag, self.loc(m), description=(m.text or "").strip())
            for p in m:
                if not _is_element(p):
                    continue
                if p.tag == "MetadataFields":
                    continue
                direction = PORT_TAGS.get(p.tag)
                pname = p.get("name")
                if direction is None or not pname:
                    self.problem(
                        self.loc(p),
                        f"<{p.tag}> in model '{mid}': expected <input_port|output_port|"
                        'inout_port name="...">',
                    )
                    continue
                if pname in model.ports:  # the last one silently won
                    self.problem(self.loc(p), f"port '{pname}' of model '{mid}' is declared twice")
                    continue
                model.ports[pname] = PortModel(
                    pname, direction, p.get("type", ""), p.get("default"), (p.text or "").strip()
                )
            self.spec.models.setdefault(mid, model)

    def _include(self, el: Any) -> None:
        path = el.get("path")
        loc = self.loc(el)
        if not path:
            self.problem(loc, '<include> needs a path attribute (e.g. path="scan.xml")')
            return
        if el.get("ros_pkg"):
            self.problem(self.attr_loc(el, "ros_pkg"), "ros_pkg includes are not supported")
            return
        if self.include is None:
            self.problem(loc, "includes are resolved by bt_engine.loading.load_spec")
            return
        self.include(path, self.attr_loc(el, "path"), self.file, self.spec, self.stack)


def _comment_text(node: Any) -> str:
    return (node.text or "").strip() if isinstance(node, etree._Comment) else ""


def merge_xml(
    path: str, text: str, spec: MissionSpec, stack: tuple[str, ...], include: Include | None
) -> None:
    """Load the XML file ``path`` (already read into ``text``) into ``spec``; ``stack`` holds
    the files being loaded, this one last; ``include`` resolves ``<include>`` elements."""
    _Loader(path, text, spec, stack, include).run()


def load_xml(path: str, text: str | None = None, include: Include | None = None) -> MissionSpec:
    """Load a BehaviorTree.CPP XML mission into a spec; problems land in ``load_problems``.

    Includes need ``include`` (:func:`bt_engine.loading.load_spec` passes it)."""
    spec = MissionSpec(file=path)
    if text is None:
        text = read_text(path, spec.load_problems)
        if text is None:
            return spec
    merge_xml(path, text, spec, (os.path.abspath(path),), include)
    return spec


# ---------------------------------------------------------------------------- writing


def value_to_text(value: Any) -> str:
    """Write a spec attribute value (native from YAML, or text) as XML attribute text."""
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        if value and all(isinstance(v, (list, tuple)) for v in value):
            return "|".join(value_to_text(v) for v in value)
        return ";".join(value_to_text(v) for v in value)
    if isinstance(value, float) and value.is_integer():
        return str(int(value)) if abs(value) < 1e15 else repr(value)
    return str(value)


def _comment(text: str) -> Any:
    # XML forbids "--" inside a comment and a trailing "-"; YAML comments often have both.
    safe = re.sub(r"-(?=-)", "- ", text).rstrip("-")
    return etree.Comment(f" {safe} ")


def _write_node(node: NodeSpec, parent: Any) -> None:
    for c in node.comments:
        parent.append(_comment(c))
    el = etree.SubElement(parent, node.type)
    for k, a in node.attrs.items():
        el.set(k, value_to_text(a.value))
    for child in node.children:
        _write_node(child, el)


def dump_xml(spec: MissionSpec) -> str:
    """Write a spec as BehaviorTree.CPP v4 XML (compact node syntax, Groot2-loadable)."""
    root = etree.Element("root", BTCPP_format="4")
    main = spec.main_tree_id()
    if main:
        root.set("main_tree_to_execute", main)
    for tree in spec.trees.values():
        for c in tree.comments:
            root.append(_comment(c))
        bt = etree.SubElement(root, "BehaviorTree", ID=tree.id)
        if tree.root is not None:
            _write_node(tree.root, bt)
    if spec.models:
        tnm = etree.SubElement(root, "TreeNodesModel")
        for m in spec.models.values():
            me = etree.SubElement(tnm, m.kind, ID=m.id)
            for p in m.ports.values():
                pe = etree.SubElement(me, f"{p.direction}_port", name=p.name)
                if p.type:
                    pe.set("type", p.type)
                if p.default is not None:
                    pe.set("default", value_to_text(p.default))
                if p.description:
                    pe.text = p.description
    head = "".join(etree.tostring(_comment(c), encoding="unicode") + "\n" for c in spec.comments)
    etree.indent(root, space="  ")
    body = etree.tostring(root, encoding="unicode")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + head + body + "\n"
