"""The in-memory mission spec that both XML and YAML load to.

Every element keeps the file, line and column it came from so that validation and run-time
errors can point at it. The spec is plain data: it can be validated, built into a running
tree, or written back to either format.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

#: Deepest nesting of nodes, within one tree and in the main tree once SubTrees are expanded
#: (the root node is level 1). Real missions stay far below; the engine builds, ticks and
#: halts trees recursively, so this also keeps Python's recursion limit out of reach.
MAX_NESTING_DEPTH = 200
#: Longest chain of SubTrees expanded inside each other (Main -> A -> B is 2).
MAX_SUBTREE_DEPTH = 100
#: Most nodes in the main tree once SubTrees are expanded (each use of a SubTree is a copy).
MAX_TREE_NODES = 100_000
#: Most attributes (ports) on one node or element.
MAX_ATTRIBUTES = 256

ERROR, WARNING = "error", "warning"


def plural(n: int, word: str, many: str | None = None) -> str:
    """``n`` and ``word`` in the number ``n`` asks for: ``1 place``, ``3 places``
    (``many``: an irregular plural, e.g. ``plural(2, "child", "children")``)."""
    return f"{n} {word if n == 1 else (many or word + 's')}"


def nesting_message(depth: int, how: str = "") -> str:
    """The problem of a node nested ``depth`` levels deep (more than MAX_NESTING_DEPTH)."""
    return (
        f"node nested {depth} levels deep{how}; nodes may nest at most {MAX_NESTING_DEPTH} "
        "deep (MAX_NESTING_DEPTH)"
    )


@dataclass(frozen=True)
class Loc:
    """A place in a file (1-based line and column)."""

    file: str
    line: int = 0
    col: int = 0

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.col}"

    @property
    def is_option(self) -> bool:
        """True for a command-line option (``--set``, ``--resume``) rather than a file."""
        return self.line == 0 and self.file.startswith("--")


@dataclass(frozen=True)
class Problem:
    """One thing wrong with an input file.

    ``severity`` is ``"error"`` (nothing may run) or ``"warning"`` (worth a look, but the
    mission runs; printed as ``file:line:col: warning: message``).
    """

    loc: Loc
    message: str
    severity: str = ERROR

    def __str__(self) -> str:
        where = f"{self.loc.file} " if self.loc.is_option else f"{self.loc}: "
        if self.severity == WARNING:
            return f"{where}warning: {self.message}"
        return f"{where}{self.message}"


class MissionError(Exception):
    """One or more located problems with mission (or rig/world) files; nothing may run."""

    def __init__(self, problems: list[Problem]) -> None:
        self.problems = sorted(problems, key=lambda p: (p.loc.file, p.loc.line, p.loc.col))
        super().__init__("\n".join(str(p) for p in self.problems))


@dataclass
class AttrSpec:
    """One attribute of a node: its raw value (text from XML, native from YAML) and place."""

    value: Any
    loc: Loc


@dataclass
class NodeSpec:
    """One node of a tree as written in the file.

    ``type`` is the node's registered ID (``GoTo``, ``Sequence``, ``SubTree``). ``tag`` is the
    element spelling used (``Action`` for ``<Action ID="GoTo">``), kept for faithful output.
    """

    type: str
    loc: Loc
    attrs: dict[str, AttrSpec] = field(default_factory=dict)
    children: list[NodeSpec] = field(default_factory=list)
    tag: str = ""
    comments: list[str] = field(default_factory=list)
    type_loc: Loc | None = None

    @property
    def name(self) -> str | None:
        """The ``name`` attribute, if any."""
        a = self.attrs.get("name")
        return None if a is None else str(a.value)

    def walk(self):
        """Yield this node and all its descendants, depth first (pre-order, no recursion)."""
        todo = [self]
        while todo:
            node = todo.pop()
            yield node
            todo.extend(reversed(node.children))

    def walk_depth(self, depth: int = 1):
        """Yield ``(node, depth)`` pre-order; this node is at ``depth`` (no recursion)."""
        todo = [(self, depth)]
        while todo:
            node, d = todo.pop()
            yield node, d
            todo.extend((c, d + 1) for c in reversed(node.children))


@dataclass
class PortModel:
    """A port as declared in a ``<TreeNodesModel>`` (used for SubTrees and unknown nodes)."""

    name: str
    direction: str
    type: str = ""
    default: Any = None
    description: str = ""


@dataclass
class ModelSpec:
    """A ``<TreeNodesModel>`` entry."""

    id: str
    kind: str
    loc: Loc
    ports: dict[str, PortModel] = field(default_factory=dict)
    description: str = ""


@dataclass
class TreeSpec:
    """One ``<BehaviorTree ID=...>``: exactly one root node."""

    id: str
    loc: Loc
    root: NodeSpec | None = None
    comments: list[str] = field(default_factory=list)
    extra_roots: list[NodeSpec] = field(default_factory=list)


@dataclass
class MissionSpec:
    """A whole mission: its trees, the main tree, node models and where it came from."""

    file: str
    trees: dict[str, TreeSpec] = field(default_factory=dict)
    main_tree: str | None = None
    models: dict[str, ModelSpec] = field(default_factory=dict)
    format_version: str | None = "4"
    comments: list[str] = field(default_factory=list)
    includes: list[str] = field(default_factory=list)
    root_loc: Loc | None = None
    #: problems found while loading (kept so validation can report everything at once)
    load_problems: list[Problem] = field(default_factory=list)

    def main_tree_id(self) -> str | None:
        """The tree to run: the named main tree, or the only tree if there is one."""
        if self.main_tree:
            return self.main_tree
        if len(self.trees) == 1:
            return next(iter(self.trees))
        return None
