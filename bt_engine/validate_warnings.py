"""The warnings of :mod:`bt_engine.validate`: legal but probably wrong.

A script or an input port reads a blackboard entry that nothing in the mission writes or
declares (:data:`KNOWN_ENTRIES` lists the entries plug-ins write), and ``Repeat``/
``RetryUntilSuccessful`` with ``-1`` around children that never return RUNNING.
"""

from __future__ import annotations

from typing import Any

from bt_engine.node import ConditionNode, SyncActionNode
from bt_engine.ports import INT, PortValueError, blackboard_ref
from bt_engine.registry import CONTROL, DECORATOR, SUBTREE, Registry, suggest_name
from bt_engine.spec import MissionSpec, NodeSpec

#: Blackboard entries written from outside the tree (by runner hooks of plug-ins, such as
#: the safety supervisor's ``safety_state``): scripts may read them without a warning. A
#: plug-in adds the entries it writes here.
KNOWN_ENTRIES: set[str] = set()

#: Built-in controls and decorators that never return RUNNING unless a child does (or only
#: with a wake-up, which ticks the tree again at once): a loop around them never waits.
#: (Not RunOnce: it returns SKIPPED after its first run, which ends the loop.)
_PASS_THROUGH = frozenset(
    (
        "Sequence",
        "SequenceWithMemory",
        "ReactiveSequence",
        "Fallback",
        "ReactiveFallback",
        "IfThenElse",
        "WhileDoElse",
        "Inverter",
        "ForceSuccess",
        "ForceFailure",
        "Repeat",
        "RetryUntilSuccessful",
        "Timeout",
        "SubTree",
    )
)
#: Loop decorators and the port whose ``-1`` means forever.
_LOOPS = {"Repeat": "num_cycles", "RetryUntilSuccessful": "num_attempts"}


class _WarningChecks:
    """Mixed into :class:`bt_engine.validate._Validator`: uses its ``spec``, ``registry``,
    ``warn``, ``nodes`` and ``scripts``."""

    spec: MissionSpec
    registry: Registry

    def written(self, creating: bool = False) -> set[str] | None:
        """Every entry something in the mission may write (scripts, output and inout ports,
        SubTree ports either way and their literals, unknown nodes' ports, SetBlackboard),
        whatever the scope; None when a SetBlackboard's key is chosen at run time. With
        ``creating``, a script's assignments count only with ``:=`` (the others need the
        entry to exist)."""
        names: set[str] = set()
        for node in self.nodes():
            model = self.registry.get(node.type)
            for _, script in self.scripts(node):
                names.update(script.creates if creating else script.writes)
            for key, attr in node.attrs.items():
                ref = blackboard_ref(attr.value)
                if model is not None and model.id == "SetBlackboard" and key == "output_key":
                    if ref is not None:
                        return None
                    names.add(str(attr.value).strip())
                if ref is None:
                    if model is not None and model.kind == SUBTREE and not key.startswith("_"):
                        names.add(key)  # a literal given to a SubTree port sets it inside
                    continue
                name = key if ref == "=" else ref
                if model is None or model.kind == SUBTREE:
                    names.update((name, key))
                elif key in model.ports and model.ports[key].writes:
                    names.add(name)
        return {n.lstrip("@") for n in names}

    def unknown_entries(self) -> None:
        """Warn about entries scripts read that nothing in the mission writes or declares.

        Written: :meth:`written`; declared: ports of every ``<TreeNodesModel>`` entry (the
        mission's inputs, SubTree ports), enum names and :data:`KNOWN_ENTRIES`. Scopes are
        ignored (an entry written anywhere counts), so a warning means the entry can only
        come from outside the tree: ``--set``, ``Mission(blackboard=...)`` or a plug-in.
        """
        written = self.written(creating=True)
        if written is None:
            return  # the entry a SetBlackboard writes is chosen at run time: anything may be
        known = set(KNOWN_ENTRIES) | written
        for m in self.spec.models.values():
            known.update(m.ports)
        for model in self.registry.models():
            for port in model.ports.values():
                known.update(getattr(port.type, "members", None) or ())
        reads: list[tuple[Any, str]] = []
        updates: list[tuple[Any, str]] = []  # (attribute, entry a script assigns with '=')
        port_reads: list[tuple[Any, str, str]] = []  # (attribute, entry, port)
        for node in self.nodes():
            model = self.registry.get(node.type)
            for attr, script in self.scripts(node):
                reads.extend((attr, name) for name in sorted(script.reads))
                needs = script.writes - script.creates - script.reads  # '+=' reads: said
                updates.extend((attr, name) for name in sorted(needs))
            if model is None or model.kind == SUBTREE:
                continue
            for key, attr in node.attrs.items():
                ref = blackboard_ref(attr.value)
                if ref is not None and key in model.ports and not model.ports[key].writes:
                    port_reads.append((attr, key if ref == "=" else ref, key))
        known = {k.lstrip("@") for k in known}
        for attr, name in reads:
            if name.lstrip("@") not in known:
                self.warn(
                    attr.loc,
                    f"script reads blackboard entry '{name}', which nothing in this mission "
                    "writes (no script assignment, output port or SetBlackboard) or declares "
                    "(<TreeNodesModel> port); unless it is set from outside (--set), the "
                    "script fails when it runs",
                )
        for attr, name in updates:
            if name.lstrip("@") not in known:
                self.warn(
                    attr.loc,
                    f"script assigns blackboard entry '{name}' with '=', which needs the "
                    "entry to exist, and nothing in this mission creates it (no ':=', output "
                    "port or SetBlackboard) or declares it (<TreeNodesModel> port); use ':=' "
                    "to create it: unless it is set from outside (--set), the script fails "
                    "when it runs",
                )
        for attr, name, key in port_reads:
            if name.lstrip("@") not in known:
                close = suggest_name(name.lstrip("@"), sorted(known))
                hint = f" (did you mean {{{close}}}?)" if close else ""
                self.warn(
                    attr.loc,
                    f"input port '{key}' reads blackboard entry {{{name}}}, which nothing in "
                    "this mission writes (no output port, script assignment or SetBlackboard) "
                    f"or declares (<TreeNodesModel> port){hint}; unless it is set from outside "
                    "(--set), the node fails when it runs",
                )

    def instant(self, root: NodeSpec) -> bool:
        """True if the subtree at ``root`` can never return RUNNING (and so never waits).

        Leaves: synchronous actions and conditions; controls and decorators: the built-in
        ones in ``_PASS_THROUGH`` over instant children (SubTrees expanded). Anything else
        (a node that may run for a while, an unknown one) may wait.
        """
        todo, seen = [root], set()
        while todo:
            node = todo.pop()
            model = self.registry.get(node.type)
            if model is None:
                return False
            if model.kind == SUBTREE:
                target = str(node.attrs["ID"].value) if "ID" in node.attrs else ""
                tree = self.spec.trees.get(target)
                if tree is None or tree.root is None:
                    return False
                if target not in seen:
                    seen.add(target)
                    todo.append(tree.root)
            elif node.children or model.kind in (CONTROL, DECORATOR):
                if model.id not in _PASS_THROUGH:
                    return False
                todo.extend(node.children)
            elif not issubclass(model.cls, (SyncActionNode, ConditionNode)):
                return False
        return True

    def reactive_children(self) -> None:
        """Warn about a reactive control with more than one child that can be RUNNING: it
        ticks its children from the first every tick, so an earlier one that runs again
        halts a later one, and the control may never end (a ReactiveSequence of two Hovers
        hovered until the time limit)."""
        for node in self.nodes():
            if node.type not in ("ReactiveSequence", "ReactiveFallback"):
                continue
            waiting = [c for c in node.children if not self.instant(c)]
            if len(waiting) > 1:
                shown = ", ".join(f"{c.type} ({c.loc})" for c in waiting[:3])
                self.warn(
                    node.type_loc or node.loc,
                    f"{node.type} has {len(waiting)} children that can be RUNNING ({shown}): "
                    "every tick starts again from its first child, so a later one is halted "
                    "whenever an earlier one runs again and it may never end; keep all but "
                    "the last instant (conditions)",
                )

    def btcpp_grouping(self) -> None:
        """Warn about a chain of ``-`` or ``/`` (or ``%``) that BehaviorTree.CPP 4 groups
        from the right: ``10 - 4 - 2`` is 4 in btrun (as in arithmetic) and 8 there, so the
        same file computes other numbers on a BT.CPP executor. Parentheses agree in both."""
        for node in self.nodes():
            for attr, script in self.scripts(node):
                for col in script.regrouped[:1]:
                    more = len(script.regrouped) - 1
                    self.warn(
                        attr.loc,
                        f"{script.source[max(0, col - 30) : col + 30]!r}: the operator at "
                        f"column {col + 1}{f' (and {more} more)' if more else ''} follows a "
                        "'-', '/' or '%' of the same precedence: "
                        "btrun groups them from the left (10 - 4 - 2 is 4), BehaviorTree.CPP 4 "
                        "from the right (8); add parentheses to mean the same in both",
                    )

    def unbounded_loops(self) -> None:
        """Warn about ``Repeat``/``RetryUntilSuccessful`` with -1 around instant children."""
        for node in self.nodes():
            model = self.registry.get(node.type)
            port = _LOOPS.get(model.id) if model is not None else None
            attr = node.attrs.get(port) if port else None
            if attr is None or len(node.children) != 1:
                continue
            try:
                forever = blackboard_ref(attr.value) is None and INT.convert(attr.value) == -1
            except PortValueError:
                continue
            if forever and self.instant(node.children[0]):
                until = "fails" if model.id == "Repeat" else "succeeds"
                self.warn(
                    attr.loc,
                    f'{model.id} {port}="-1" around children that never return RUNNING: '
                    f"the loop repeats within one tick and never ends unless the child {until} "
                    "(as in BehaviorTree.CPP); nothing else runs meanwhile, and the tree is not "
                    "halted on time. Bound the count, or add an action that takes time",
                )
