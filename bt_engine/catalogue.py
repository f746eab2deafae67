"""Node catalogue generated from the registry: ``btrun nodes``, the Groot2 palette, docs.

Everything here is derived from node declarations (docstring + ports), the single source of
truth, so a new leaf shows up in all three as soon as it is registered.

Docstrings are reStructuredText: the listing shows them as plain text (literals and roles
unwrapped, the first paragraph whole, wrapped rather than cut) and the reference as Markdown
(code spans, literal blocks fenced); :func:`doc_blocks` is the small reader both use.
"""

from __future__ import annotations

import re
import textwrap
from typing import Literal

from lxml import etree

from bt_engine.ports import NO_DEFAULT, EnumType, Port, range_words
from bt_engine.registry import KINDS, NodeModel, Registry

GROOT_TYPES = {
    "float": "double",
    "int": "int",
    "bool": "bool",
    "string": "std::string",
    "any": "",
}


WIDTH = 100
"""Width the ``btrun nodes`` listing wraps at (fixed: the output does not depend on the terminal)."""

# :role:`target`, :role:`title <target>`, :domain:role:`~a.b`
_ROLE = re.compile(r":(?:\w+:)?\w+:`([^`]+)`")
_LITERAL = re.compile(r"``(.+?)``", re.S)
_INTERPRETED = re.compile(r"(?<![`\w])`([^`]+)`(?![`\w])")


def _role_target(text: str) -> str:
    m = re.fullmatch(r"(.*?)\s*<([^>]+)>", text, re.S)
    if m and m.group(1):
        return m.group(1)
    text = m.group(2) if m else text
    return text[1:].rsplit(".", 1)[-1] if text.startswith("~") else text


def doc_blocks(description: str) -> list[tuple[Literal["para", "literal"], str]]:
    """Split a reStructuredText docstring into ``("para", text)`` paragraphs (lines joined
    with spaces, a closing ``::`` turned into ``:``) and ``("literal", text)`` blocks (the
    indented block after a ``::``, dedented, line breaks kept)."""
    lines = description.strip().splitlines()
    blocks: list[tuple[Literal["para", "literal"], str]] = []
    i, literal_next = 0, False
    while i < len(lines):
        if not lines[i].strip():
            i += 1
            continue
        if literal_next and lines[i][:1].isspace():
            body = []
            while i < len(lines) and (not lines[i].strip() or lines[i][:1].isspace()):
                body.append(lines[i])
                i += 1
            blocks.append(("literal", textwrap.dedent("\n".join(body)).strip("\n")))
            literal_next = False
            continue
        para = []
        while i < len(lines) and lines[i].strip():
            para.append(lines[i].strip())
            i += 1
        text = " ".join(para)
        literal_next = text.endswith("::")
        if literal_next:
            text = text[:-2].rstrip() if text[:-2].endswith(" ") or text == "::" else text[:-1]
        if text:
            blocks.append(("para", text))
    return blocks


def plain_text(rst: str) -> str:
    """Inline reStructuredText as plain text: ``literal`` -> literal ('quoted' when it holds
    spaces), :role:`target` -> target, `interpreted` -> interpreted."""

    def literal(m: re.Match) -> str:
        t = " ".join(m.group(1).split())
        return f"'{t}'" if " " in t else t

    text = _LITERAL.sub(literal, rst)
    text = _ROLE.sub(lambda m: _role_target(m.group(1)), text)
    return _INTERPRETED.sub(lambda m: m.group(1), text)


def markdown_text(rst: str) -> str:
    """Inline reStructuredText as Markdown: literals, roles and interpreted text become code
    spans; a ``<`` outside them is escaped (it would open an HTML tag)."""
    out: list[str] = []
    pos = 0
    spans = re.compile(f"{_LITERAL.pattern}|{_ROLE.pattern}|{_INTERPRETED.pattern}", re.S)
    for m in spans.finditer(rst):
        out.append(rst[pos : m.start()].replace("<", "\\<"))
        if m.group(1) is not None:
            code = " ".join(m.group(1).split())
        elif m.group(2) is not None:
            code = _role_target(m.group(2))
        else:
            code = m.group(3)
        fence = "``" if "`" in code else "`"
        out.append(f"{fence}{code}{fence}" if fence == "`" else f"{fence} {code} {fence}")
        pos = m.end()
    out.append(rst[pos:].replace("<", "\\<"))
    return "".join(out)


def node_summary(m: NodeModel) -> str:
    """The node's first paragraph, whole, as plain text (the listing, the Groot2 palette)."""
    paras = [t for kind, t in doc_blocks(m.description) if kind == "para"]
    return plain_text(paras[0]) if paras else ""


def _groot_type(port: Port) -> str:
    if isinstance(port.type, EnumType):
        return port.type.name
    return GROOT_TYPES.get(port.type.name, port.type.name)


def _default_text(port: Port) -> str | None:
    if port.default is NO_DEFAULT or port.default is None:
        return None
    return port.type.to_text(port.default) if not isinstance(port.default, str) else port.default


def _shown_default(port: Port) -> str | None:
    """The default as the listing and the reference show it (an empty text as ``""``)."""
    text = _default_text(port)
    return '""' if text == "" else text


def groot_palette(registry: Registry, include_builtins: bool = False) -> str:
    """Return a ``<root><TreeNodesModel>`` document Groot2 can import as a palette.

    Groot2 already knows BehaviorTree.CPP's built-ins, so they are left out by default.
    """
    root = etree.Element("root", BTCPP_format="4")
    tnm = etree.SubElement(root, "TreeNodesModel")
    for m in registry.models():
        if m.kind == "SubTree" or (m.category == "built-in" and not include_builtins):
            continue
        el = etree.SubElement(tnm, m.kind, ID=m.id)
        for p in m.ports.values():
            pe = etree.SubElement(el, f"{p.direction}_port", name=p.name)
            t = _groot_type(p)
            if t:
                pe.set("type", t)
            d = _default_text(p)
            if d is not None:
                pe.set("default", d)
            if p.description:
                pe.text = p.description
        summary = node_summary(m)
        if summary:
            meta = etree.SubElement(el, "MetadataFields")
            etree.SubElement(meta, "Metadata", description=summary)
    etree.indent(root, space="  ")
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n' + etree.tostring(root, encoding="unicode") + "\n"
    )


def port_line(p: Port) -> str:
    """One-line description of a port for text output."""
    req = (
        "required"
        if p.required
        else f"default {_shown_default(p)}"
        if _default_text(p) is not None
        else "optional"
    )
    arrow = {"input": "in ", "output": "out", "inout": "i/o"}[p.direction]
    desc = f" - {plain_text(p.description)}" if p.description else ""
    span = range_words(p.low, p.high)
    req += f"; {span}" if span else ""
    return f"{arrow} {p.name}: {p.type.name} ({req}){desc}"


def _verbose_lines(m: NodeModel) -> list[str]:
    """The description after its first paragraph, as plain text, wrapped; literal blocks
    are kept as they are."""
    out: list[str] = []
    for kind, text in doc_blocks(m.description)[1:]:
        if out:
            out.append("      |")
        if kind == "literal":
            out.extend(f"      |     {line}".rstrip() for line in text.splitlines())
        else:
            out.extend(
                textwrap.wrap(
                    plain_text(text),
                    WIDTH,
                    initial_indent="      | ",
                    subsequent_indent="      | ",
                    break_long_words=False,
                    break_on_hyphens=False,
                )
            )
    return out


def catalogue_text(registry: Registry, kind: str | None = None, verbose: bool = False) -> str:
    """The ``btrun nodes`` listing: nodes grouped by kind, each with its first paragraph
    (wrapped at :data:`WIDTH`, never cut) and its ports; ``verbose`` adds the rest of the
    description."""
    lines: list[str] = []
    for k in KINDS:
        if kind and k.lower() != kind.lower():
            continue
        models = [m for m in registry.models() if m.kind == k]
        if not models:
            continue
        lines.append(f"{k} nodes:")
        for m in models:
            head = f"  {m.id:<24} "
            summary = node_summary(m)
            lines.extend(
                textwrap.wrap(
                    summary,
                    WIDTH,
                    initial_indent=head,
                    subsequent_indent=" " * len(head),
                    break_long_words=False,
                    break_on_hyphens=False,
                )
                if summary
                else [head.rstrip()]
            )
            for p in m.ports.values():
                lines.append(f"      {port_line(p)}")
            if verbose:
                lines.extend(_verbose_lines(m))
        lines.append("")
    return "\n".join(lines)


def _cell(text: str) -> str:
    """A Markdown table cell: a ``|`` would end the cell."""
    return text.replace("|", "\\|")


def _md_node(m: NodeModel) -> list[str]:
    out = [f"### {m.id}", "", f"*{m.kind}*" + (f" · {m.category}" if m.category else ""), ""]
    blocks = doc_blocks(m.description)
    for kind, text in blocks:
        if kind == "literal":
            out += ["```text", text, "```", ""]
        else:
            out += [markdown_text(text), ""]
    if not blocks:
        out += ["(no description)", ""]
    if m.ports:
        out.append("| port | direction | type | default | description |")
        out.append("|---|---|---|---|---|")
        for p in m.ports.values():
            t = p.type.expected if isinstance(p.type, EnumType) else p.type.name
            d = _shown_default(p)
            d = "*required*" if p.required else ("" if d is None else f"`{d}`")
            desc = markdown_text(p.description).replace("|", "\\|")
            span = range_words(p.low, p.high)
            desc += f" ({span})" if span else ""
            out.append(f"| `{p.name}` | {p.direction} | {_cell(t)} | {_cell(d)} | {desc} |")
        out.append("")
    return out


def catalogue_markdown(registry: Registry) -> str:
    """The generated node reference (``docs/nodes.md``)."""
    out = [
        "# Node reference",
        "",
        "Generated by `btrun nodes --markdown docs/nodes.md` from the node declarations;",
        "do not edit by hand.",
        "",
    ]
    for k in KINDS:
        models = [m for m in registry.models() if m.kind == k]
        if not models:
            continue
        out += [f"## {k} nodes", ""]
        for m in models:
            out += _md_node(m)
    return "\n".join(out)
