"""Mission files in, mission files out: the one module that knows both formats.

:mod:`bt_engine.xml_io` and :mod:`bt_engine.yaml_io` each read and write one format and know
nothing of each other; an ``<include>`` (XML) or ``include:`` (YAML) of either format is
resolved here (:func:`include`) and handed to the right loader. :func:`load_spec` reads a
mission file of either format, :func:`convert_file` writes one format from the other.
"""

from __future__ import annotations

import os

from bt_engine.files import read_text
from bt_engine.registry import Registry
from bt_engine.spec import Loc, MissionSpec, Problem
from bt_engine.xml_io import dump_xml, merge_xml
from bt_engine.xml_io import load_xml as _load_xml
from bt_engine.yaml_io import dump_yaml, merge_yaml
from bt_engine.yaml_io import load_yaml as _load_yaml

#: Deepest chain of includes.
MAX_INCLUDE_DEPTH = 20


def merge_file(path: str, text: str, spec: MissionSpec, stack: tuple[str, ...]) -> None:
    """Load ``path`` (read into ``text``) into ``spec`` with the loader of its format."""
    if path.endswith((".yaml", ".yml")):
        merge_yaml(path, text, spec, stack, include)
    else:
        merge_xml(path, text, spec, stack, include)


def include(ref: str, loc: Loc, including: str, spec: MissionSpec, stack: tuple[str, ...]) -> None:
    """Resolve the include ``ref`` written at ``loc`` in the file ``including`` (relative to
    it) and merge it into ``spec``; loops, depth and missing files become problems."""
    full = os.path.normpath(os.path.join(os.path.dirname(including), ref))
    if os.path.abspath(full) in stack:
        chain = " -> ".join(os.path.basename(s) for s in stack) + f" -> {ref}"
        spec.load_problems.append(Problem(loc, f"include loop: {chain}"))
        return
    if len(stack) > MAX_INCLUDE_DEPTH:
        spec.load_problems.append(
            Problem(loc, f"includes nested more than {MAX_INCLUDE_DEPTH} deep")
        )
        return
    if not os.path.isfile(full):
        spec.load_problems.append(Problem(loc, f"included file not found: {full}"))
        return
    spec.includes.append(full)
    text = read_text(full, spec.load_problems, loc)
    if text is not None:
        merge_file(full, text, spec, stack + (os.path.abspath(full),))


def load_xml(path: str, text: str | None = None) -> MissionSpec:
    """Load an XML mission (includes of either format resolved)."""
    return _load_xml(path, text, include)


def load_yaml(path: str, text: str | None = None) -> MissionSpec:
    """Load a YAML mission (includes of either format resolved)."""
    return _load_yaml(path, text, include)


def load_spec(path: str) -> MissionSpec:
    """Read a mission file (``.xml``, ``.yaml``/``.yml``) into a spec (problems kept inside)."""
    ext = os.path.splitext(path)[1].lower()
    if ext in (".yaml", ".yml"):
        return load_yaml(path)
    if ext != ".xml" and os.path.exists(path):
        spec = MissionSpec(file=path)
        spec.load_problems.append(
            Problem(
                Loc(path, 1, 1), f"unknown mission file type '{ext}' (expected .xml, .yaml or .yml)"
            )
        )
        return spec
    if not os.path.exists(path):
        spec = MissionSpec(file=path)
        spec.load_problems.append(Problem(Loc(path, 0, 0), "mission file not found"))
        return spec
    return load_xml(path)


def convert_file(src: str, dst: str, registry: Registry | None = None) -> list[Problem]:
    """Convert a mission between XML and YAML (the format of ``dst`` by its extension).

    Nothing is written if ``src`` has load problems; they are returned. Returns ``[]`` on
    success.
    """
    spec = load_spec(src)
    if spec.load_problems:
        return sorted(spec.load_problems, key=lambda p: (p.loc.file, p.loc.line, p.loc.col))
    ext = os.path.splitext(dst)[1].lower()
    if ext in (".yaml", ".yml"):
        text = dump_yaml(spec, registry)
    elif ext == ".xml":
        roots = [r for t in spec.trees.values() for r in [t.root, *t.extra_roots] if r]
        for holder in [spec, *spec.trees.values(), *(n for r in roots for n in r.walk())]:
            holder.comments = [_xml_comment(c) for c in holder.comments]
        text = dump_xml(spec)
    else:
        return [
            Problem(Loc(dst, 0, 0), f"unknown output type '{ext}' (expected .xml, .yaml or .yml)")
        ]
    try:
        with open(dst, "w", encoding="utf-8") as f:
            f.write(text)
    except OSError as exc:
        return [Problem(Loc(dst, 0, 0), f"cannot write {dst}: {exc.strerror or exc}")]
    return []


def _xml_comment(text: str) -> str:
    """XML comments may not contain ``--`` (common in YAML comments such as ``# --- x ---``)."""
    while "--" in text:
        text = text.replace("--", "- -")
    return text
