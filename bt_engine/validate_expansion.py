"""The checks of :mod:`bt_engine.validate` on the main tree once its SubTrees are expanded.

No SubTree may contain itself, SubTrees nest at most
:data:`~bt_engine.spec.MAX_SUBTREE_DEPTH` deep, nodes at most
:data:`~bt_engine.spec.MAX_NESTING_DEPTH` deep and the expanded tree has at most
:data:`~bt_engine.spec.MAX_TREE_NODES` nodes. One iterative pass, linear in the size of the
spec (a tree used many times is analysed once).
"""

from __future__ import annotations

from bt_engine.spec import (
    MAX_NESTING_DEPTH,
    MAX_SUBTREE_DEPTH,
    MAX_TREE_NODES,
    MissionSpec,
    NodeSpec,
    nesting_message,
)


def _chain(names: list[str]) -> str:
    """``A -> B -> C``, shortened in the middle when long."""
    if len(names) > 8:
        names = names[:3] + [f"... {len(names) - 6} more ..."] + names[-3:]
    return " -> ".join(names)


class _ExpansionChecks:
    """Mixed into :class:`bt_engine.validate._Validator`: uses its ``spec`` and ``add``."""

    spec: MissionSpec

    def subtree_refs(self, tree_id: str) -> list[tuple[NodeSpec, int, str]]:
        """``(SubTree node, its depth, target tree)`` of every SubTree of a defined tree."""
        root = self.spec.trees[tree_id].root
        if root is None:
            return []
        return [
            (node, depth, str(node.attrs["ID"].value))
            for node, depth in root.walk_depth()
            if node.type == "SubTree"
            and "ID" in node.attrs
            and str(node.attrs["ID"].value) in self.spec.trees
        ]

    def expansion(self, main: str) -> None:
        """Recursive SubTrees, and the depth and size of the main tree once expanded.

        One depth-first pass over the trees reachable from ``main`` (each tree once, with an
        explicit stack: a chain of thousands of SubTrees is fine), then the longest SubTree
        chain, the deepest node and the node count of every tree, children first.
        """
        trees = self.spec.trees
        refs: dict[str, list[tuple[NodeSpec, int, str]]] = {}
        state: dict[str, int] = {main: 1}  # 1: on the current path, 2: done
        order: list[str] = []  # trees in post-order: every tree after the trees it uses
        loops: set[int] = set()  # SubTree nodes that close a loop (left out below)
        refs[main] = self.subtree_refs(main)
        path, stack = [main], [iter(refs[main])]
        while stack:
            for node, _depth, target in stack[-1]:
                seen = state.get(target)
                if seen == 1:
                    loops.add(id(node))
                    self.add(
                        node.attrs["ID"].loc, "recursive SubTree: " + " -> ".join(path + [target])
                    )
                elif seen is None:
                    state[target] = 1
                    refs[target] = self.subtree_refs(target)
                    path.append(target)
                    stack.append(iter(refs[target]))
                    break
            else:
                stack.pop()
                done = path.pop()
                state[done] = 2
                order.append(done)
        chain: dict[str, int] = {}  # longest SubTree chain below a tree
        deep: dict[str, int] = {}  # deepest node once expanded (a tree's root is level 1)
        size: dict[str, int] = {}  # nodes once expanded (capped just above the limit)
        for tid in order:
            root = trees[tid].root
            local = list(root.walk_depth()) if root is not None else []
            used = [(n, d, t) for n, d, t in refs[tid] if id(n) not in loops]
            chain[tid] = max((1 + chain[t] for _, _, t in used), default=0)
            deep[tid] = max([d for _, d in local] + [d + deep[t] for _, d, t in used], default=0)
            size[tid] = min(len(local) + sum(size[t] for _, _, t in used), MAX_TREE_NODES + 1)
        if chain[main] > MAX_SUBTREE_DEPTH:
            self.too_many_subtrees(main, refs, loops, chain)
        elif deep[main] > MAX_NESTING_DEPTH:
            self.too_deep(main, refs, loops, deep)
        if size[main] > MAX_TREE_NODES:
            root = trees[main].root
            self.add(
                root.loc if root is not None else trees[main].loc,
                f"tree '{main}' has more than {MAX_TREE_NODES} nodes once its SubTrees are "
                f"expanded (each use of a SubTree is a copy); the limit is {MAX_TREE_NODES} "
                "(MAX_TREE_NODES)",
            )

    def too_many_subtrees(self, main: str, refs, loops: set[int], chain: dict[str, int]) -> None:
        """Report the SubTree where the longest chain passes MAX_SUBTREE_DEPTH."""
        names, tid = [main], main
        while True:
            node, _, target = max(
                ((n, d, t) for n, d, t in refs[tid] if id(n) not in loops),
                key=lambda r: chain[r[2]],
            )
            names.append(target)
            if len(names) - 1 > MAX_SUBTREE_DEPTH:
                self.add(
                    node.attrs["ID"].loc,
                    f"SubTree '{target}' is expanded {len(names) - 1} SubTrees deep "
                    f"({_chain(names)}, with {chain[target]} more below); SubTrees may nest "
                    f"at most {MAX_SUBTREE_DEPTH} deep (MAX_SUBTREE_DEPTH)",
                )
                return
            tid = target

    def too_deep(self, main: str, refs, loops: set[int], deep: dict[str, int]) -> None:
        """Report the first node nested deeper than MAX_NESTING_DEPTH once expanded."""
        names, tid, base = [main], main, 0
        while True:
            root = self.spec.trees[tid].root
            if root is None:
                return
            for node, depth in root.walk_depth():
                if base + depth > MAX_NESTING_DEPTH:
                    if base == 0 or any(d > MAX_NESTING_DEPTH for _, d in root.walk_depth()):
                        return  # too deep in this tree alone: reported with the tree
                    how = f" once SubTrees are expanded ({_chain(names)})"
                    self.add(node.loc, nesting_message(base + depth, how))
                    return
            _, d, tid = max(
                ((n, d, t) for n, d, t in refs[tid] if id(n) not in loops),
                key=lambda r: r[1] + deep[r[2]],
            )
            names.append(tid)
            base += d
