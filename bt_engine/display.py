"""Showing trees: text (with statuses), Graphviz dot, and the live terminal view.

For a mission in Python, :func:`mission_tree_text` and :func:`blackboard_text` are btrun's
equivalents of py_trees' ``unicode_tree`` and ``unicode_blackboard``. py_trees' blackboard
displays list only the keys a py_trees ``Client`` registered (``Blackboard.keys()`` reads
the clients' metadata), and btrun keeps each mission's entries in its own namespace of
py_trees' storage without clients (``bt_engine.blackboard``), so they show nothing for a
btrun mission.
"""

from __future__ import annotations

import shutil
import subprocess
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from bt_engine.spec import MissionSpec, NodeSpec
from bt_engine.xml_io import value_to_text

if TYPE_CHECKING:
    from bt_engine.mission import Mission

STATUS_STYLE = {
    "RUNNING": "bold yellow",
    "SUCCESS": "green",
    "FAILURE": "bold red",
    "SKIPPED": "dim cyan",
    "IDLE": "dim",
}
STATUS_MARK = {"RUNNING": "*", "SUCCESS": "+", "FAILURE": "x", "SKIPPED": "~", "IDLE": " "}


@dataclass
class Row:
    """One line of a displayed tree."""

    path: str
    label: str
    depth: int
    last_flags: tuple[bool, ...]


def _node_label(node: NodeSpec) -> str:
    name = node.name
    head = node.type if not name or name == node.type else f"{node.type} '{name}'"
    attrs = " ".join(f"{k}={value_to_text(a.value)}" for k, a in node.attrs.items() if k != "name")
    return f"{head} {attrs}".rstrip()


def spec_rows(spec: MissionSpec) -> list[Row]:
    """Rows of the main tree with SubTrees expanded (the same pre-order as the built tree)."""
    rows: list[Row] = []
    main = spec.main_tree_id()
    if main is None or main not in spec.trees:
        return rows

    def walk(node: NodeSpec, depth: int, flags: tuple[bool, ...], stack: tuple[str, ...]) -> None:
        rows.append(Row("", _node_label(node), depth, flags))
        kids: list[NodeSpec] = list(node.children)
        if node.type == "SubTree":
            target = str(node.attrs["ID"].value) if "ID" in node.attrs else ""
            if target in spec.trees and target not in stack and spec.trees[target].root:
                kids = [spec.trees[target].root]
                stack = stack + (target,)
        for i, c in enumerate(kids):
            walk(c, depth + 1, flags + (i == len(kids) - 1,), stack)

    walk(spec.trees[main].root, 0, (), (main,))
    return rows


def tree_lines(rows: list[Row], statuses: Iterable[str] | None = None) -> list[str]:
    """Plain text lines with box-drawing branches and optional status marks."""
    st = list(statuses) if statuses is not None else None
    out = []
    for i, r in enumerate(rows):
        prefix = ""
        for f in r.last_flags[:-1]:
            prefix += "    " if f else "│   "
        if r.last_flags:
            prefix += "└── " if r.last_flags[-1] else "├── "
        mark = ""
        if st is not None and i < len(st):
            mark = f"[{STATUS_MARK.get(st[i], '?')}] "
        out.append(
            f"{mark}{prefix}{r.label}"
            + (f"  {st[i]}" if st is not None and i < len(st) and st[i] != "IDLE" else "")
        )
    return out


def mission_tree_text(mission: Mission) -> str:
    """The mission's tree as ``btrun show`` prints it, each node with its status now
    (``[*] ... RUNNING``, ``[+] ... SUCCESS``, ``[x] ... FAILURE``, ``[~] ... SKIPPED``)."""
    title = f"{mission.spec.main_tree_id()}  (tick {mission.ticks})"
    rows = spec_rows(mission.spec)
    return "\n".join([title, *tree_lines(rows, mission.statuses().values())])


def blackboard_text(mission: Mission) -> str:
    """The mission's blackboard, one ``key : value`` line per entry (the value's repr), sorted;
    a SubTree instance's own entries are named by its path (``square/corner_1/pose``)."""
    items = sorted(mission.scope.all_items().items())
    width = max((len(k) for k, _ in items), default=0)
    lines = [f"{k:<{width}} : {v!r}" for k, v in items]
    return "\n".join(["Blackboard", *(f"  {line}" for line in lines)])


def tree_rich(rows: list[Row], statuses: list[str]):
    """A rich renderable of the tree coloured by status."""
    from rich.text import Text

    text = Text()
    for i, r in enumerate(rows):
        prefix = ""
        for f in r.last_flags[:-1]:
            prefix += "    " if f else "│   "
        if r.last_flags:
            prefix += "└── " if r.last_flags[-1] else "├── "
        s = statuses[i] if i < len(statuses) else "IDLE"
        text.append(prefix, style="dim")
        text.append(r.label, style=STATUS_STYLE.get(s, ""))
        if s != "IDLE":
            text.append(f"  {s}", style=STATUS_STYLE.get(s, ""))
        text.append("\n")
    return text


def dot_source(spec: MissionSpec) -> str:
    """Graphviz dot text of the main tree (SubTrees expanded)."""
    rows = spec_rows(spec)
    lines = ["digraph mission {", '  node [shape=box, fontname="Helvetica", fontsize=10];']
    stack: list[int] = []
    for i, r in enumerate(rows):
        label = r.label.replace('"', '\\"')
        lines.append(f'  n{i} [label="{label}"];')
        while len(stack) > r.depth:
            stack.pop()
        if stack:
            lines.append(f"  n{stack[-1]} -> n{i};")
        stack.append(i)
    lines.append("}")
    return "\n".join(lines) + "\n"


def render_dot(dot: str, fmt: str, out_path: str) -> None:
    """Render dot text to ``svg`` or ``png`` with Graphviz's ``dot`` program."""
    exe = shutil.which("dot")
    if exe is None:
        raise RuntimeError(
            f"--format {fmt} needs Graphviz's 'dot' program (apt-get install graphviz); "
            "--format dot writes the source instead"
        )
    subprocess.run([exe, f"-T{fmt}", "-o", out_path], input=dot.encode(), check=True)


class LiveView:
    """Live tree + progress line on a terminal (rich), refreshed at most ``fps`` times/s."""

    def __init__(self, rows: list[Row], title: str, fps: float = 8.0) -> None:
        from rich.console import Console
        from rich.live import Live

        self.rows = rows
        self.title = title
        self.console = Console()
        self.live = Live(console=self.console, auto_refresh=False, transient=False)
        self.min_dt = 1.0 / fps
        self._last = 0.0
        self._gone = False  # the terminal went away: draw nothing more, fly on

    def __enter__(self) -> LiveView:
        try:
            self.live.__enter__()
        except OSError:
            self._gone = True
        return self

    def __exit__(self, *exc) -> None:
        if not self._gone:
            try:
                self.live.__exit__(*exc)
            except OSError:
                self._gone = True

    def update(self, statuses: list[str], progress: str, force: bool = False) -> None:
        """Redraw if enough wall time has passed (or ``force``). A terminal that went away
        (EIO, a closed pipe) ends the drawing, never the flight."""
        now = time.monotonic()
        if self._gone or (not force and now - self._last < self.min_dt):
            return
        self._last = now
        from rich.console import Group
        from rich.panel import Panel
        from rich.text import Text

        try:
            self.live.update(
                Group(Panel(tree_rich(self.rows, statuses), title=self.title), Text(progress)),
                refresh=True,
            )
        except OSError:
            self._gone = True
