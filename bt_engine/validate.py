"""Check a mission spec against the node registry before anything runs.

Every problem is collected (never just the first) and located ``file:line:col``, with the
offending value and what was expected. Nothing runs while any problem remains.

Besides errors, validation finds *warnings* (:class:`~bt_engine.spec.Problem` with
``severity="warning"``): things that are legal but probably wrong, such as a script reading
a blackboard entry nothing writes, or ``Repeat num_cycles="-1"`` around children that never
return RUNNING. :func:`validate` returns the errors only (a mission with warnings runs);
pass a list as ``warnings`` to collect the warnings too (``btrun validate`` prints them).

The main tree is checked once SubTrees are expanded: no SubTree may contain itself, SubTrees
nest at most :data:`~bt_engine.spec.MAX_SUBTREE_DEPTH` deep, nodes at most
:data:`~bt_engine.spec.MAX_NESTING_DEPTH` deep and the expanded tree has at most
:data:`~bt_engine.spec.MAX_TREE_NODES` nodes. Every walk here is iterative and linear in
the size of the spec (a tree used many times is analysed once).

The expanded-tree checks are in :mod:`bt_engine.validate_expansion`, the warnings in
:mod:`bt_engine.validate_warnings` (mixed into the validator here).
"""

from __future__ import annotations

import math
from typing import Any

from bt_engine.node_checks import said
from bt_engine.plugin_code import conversion_said, creation_problems
from bt_engine.ports import NO_DEFAULT, PortValueError, blackboard_ref, declared_type
from bt_engine.registry import CONTROL, DECORATOR, SUBTREE, Registry, suggest_name
from bt_engine.root_entries import root_entries
from bt_engine.spec import (
    MAX_NESTING_DEPTH,
    MAX_SUBTREE_DEPTH,
    WARNING,
    Loc,
    MissionSpec,
    NodeSpec,
    Problem,
    nesting_message,
    plural,
)
from bt_engine.validate_expansion import _ExpansionChecks
from bt_engine.validate_types import _TypeChecks
from bt_engine.validate_warnings import KNOWN_ENTRIES, _WarningChecks

CONDITION_ATTRS = (
    "_failureIf",
    "_successIf",
    "_skipIf",
    "_while",
    "_onHalted",
    "_onFailure",
    "_onSuccess",
    "_post",
)
SPECIAL_ATTRS = ("name", "_description", "_uid", "_fullpath")


def check_script(code: str) -> str | None:
    """Return an error message if ``code`` is not a valid script, or if a part of it made
    of literals alone always fails when it runs (``1 / 0``), else None."""
    from bt_engine.script import ScriptError, constant_failure, parse_script

    try:
        parse_script(code)
        failure = constant_failure(code)
        if failure is not None:
            raise failure
    except ScriptError as exc:
        where = f" at column {exc.column + 1}" if exc.column >= 0 else ""
        return f"{exc.message if hasattr(exc, 'message') else exc}{where}"
    return None


def _parsed(code: Any):
    """The parsed script of ``code``, or None (not text, a reference, or not valid)."""
    from bt_engine.script import ScriptError, parse_script

    if not isinstance(code, str) or blackboard_ref(code) is not None:
        return None
    try:
        return parse_script(code)
    except ScriptError:
        return None


def _order(p: Problem) -> tuple:
    return (p.loc.file, p.loc.line, p.loc.col, p.message)


class _Validator(_ExpansionChecks, _WarningChecks, _TypeChecks):
    def __init__(self, spec: MissionSpec, registry: Registry) -> None:
        self.spec = spec
        self.registry = registry
        self.problems: list[Problem] = list(spec.load_problems)
        self.warnings: list[Problem] = []

    def add(self, loc, message: str) -> None:
        self.problems.append(Problem(loc, message))

    def warn(self, loc, message: str) -> None:
        self.warnings.append(Problem(loc, message, WARNING))

    def run(self) -> list[Problem]:
        spec = self.spec
        yaml = (spec.file or "").lower().endswith((".yaml", ".yml"))  # said in its own words
        if not spec.trees and not spec.load_problems:
            self.add(
                spec.root_loc or _file_loc(spec),
                "the mission has no tree (trees: is empty)"
                if yaml
                else "the mission has no <BehaviorTree>",
            )
        main = spec.main_tree_id()
        if spec.trees and main is None:
            self.add(
                spec.root_loc or _file_loc(spec),
                f"no main tree: set {'main:' if yaml else 'main_tree_to_execute'} to one of "
                + ", ".join(sorted(spec.trees)),
            )
        elif main is not None and main not in spec.trees and spec.trees:
            hint = suggest_name(main, list(spec.trees))
            self.add(
                spec.root_loc or _file_loc(spec),
                f"main tree '{main}' is not defined (trees: {', '.join(sorted(spec.trees))})"
                + (f"; did you mean '{hint}'?" if hint else ""),
            )
        for tree in spec.trees.values():
            if self.registry.get(tree.id) is not None:  # BT.CPP refuses it too
                self.add(
                    tree.loc,
                    f"tree '{tree.id}' has the name of a node ({tree.id}); give the "
                    "<BehaviorTree> another ID (BehaviorTree.CPP and Groot2 refuse the clash)",
                )
            for extra in tree.extra_roots:
                self.add(
                    extra.loc,
                    f"tree '{tree.id}' has {1 + len(tree.extra_roots)} root nodes; a "
                    "<BehaviorTree> takes exactly one (wrap them in a Sequence)",
                )
            if tree.root is not None:
                too_deep = False
                for node, depth in tree.root.walk_depth():
                    if depth > MAX_NESTING_DEPTH and not too_deep:
                        too_deep = True  # one problem per tree
                        self.add(node.loc, nesting_message(depth))
                    self.node(node)
        self.problems += creation_problems(spec, self.registry)  # a plug-in's __init__
        self.model_defaults()
        self.orphan_models()
        if main in spec.trees:
            self.expansion(main)
        self.unknown_entries()
        self.entry_types()
        if main in spec.trees:
            self.subtree_reads()
        self.unbounded_loops()
        self.btcpp_grouping()
        self.reactive_children()
        self.warnings = sorted(set(self.warnings), key=_order)
        return sorted(set(self.problems), key=_order)

    def model_defaults(self) -> None:
        """A ``<TreeNodesModel>`` port's default must be a value of its declared type
        (``type="int" default="five"`` was taken, and failed only where it was read)."""
        by_ports = port_read_entries(self.spec, self.registry)  # said there, with the node
        main = self.spec.models.get(self.spec.main_tree_id() or "")
        limit = main.ports.get("max_time") if main is not None else None
        if limit is not None and limit.default not in (None, ""):  # btrun's own input
            try:
                seconds = float(limit.default)
            except ValueError:
                seconds = math.nan
            if not (math.isfinite(seconds) and seconds > 0):  # btrun run refused it; so
                self.add(  # does btrun validate now
                    main.loc,
                    f"max_time: the mission's time limit must be a time in s > 0, got "
                    f"{limit.default!r}",
                )
        for model in self.spec.models.values():
            for port in model.ports.values():
                kind = declared_type(port.type)
                if kind is None or port.default in (None, "") or port.name in by_ports:
                    continue
                if port is limit:  # said above, as the time limit
                    continue
                try:
                    kind.convert(port.default)
                except PortValueError as exc:
                    self.add(
                        model.loc,
                        f"<TreeNodesModel> port '{port.name}' of '{model.id}': default "
                        f'{port.default!r} is no {port.type} (type="{port.type}"): {exc}',
                    )

    def orphan_models(self) -> None:
        """A ``<TreeNodesModel>`` SubTree entry that names no tree (``main`` for ``Main``):
        its ports (the mission's inputs, their defaults) are not the tree's, silently."""
        for model in self.spec.models.values():
            if model.kind != SUBTREE or model.id in self.spec.trees:
                continue
            hint = suggest_name(model.id, list(self.spec.trees))
            same = [t for t in self.spec.trees if t.lower() == model.id.lower()]
            hint = same[0] if same else hint
            self.warn(
                model.loc,
                f"<TreeNodesModel> entry SubTree '{model.id}' names no tree of this mission"
                + (f" (did you mean '{hint}'?)" if hint else "")
                + ": its ports are no tree's inputs",
            )

    def enum_names(self) -> set[str]:
        """Names scripts read that are no entries: enum members of every port type, and
        the entries plug-ins write from outside the tree (:data:`KNOWN_ENTRIES`)."""
        names = set(KNOWN_ENTRIES)
        for model in self.registry.models():
            for port in model.ports.values():
                names.update(getattr(port.type, "members", None) or ())
        return names

    # -- walks used by the warnings and by referenced_entries ------------------------------
    def nodes(self):
        """Every node of every tree."""
        for tree in self.spec.trees.values():
            if tree.root is not None:
                yield from tree.root.walk()

    def scripts(self, node: NodeSpec):
        """``(attribute, parsed script)`` of every valid script of ``node``."""
        for key, attr in node.attrs.items():
            code = (
                key in CONDITION_ATTRS
                or (key == "code" and node.type in ("Script", "ScriptCondition"))
                or (key == "if" and node.type == "Precondition")
            )
            script = _parsed(attr.value) if code else None
            if script is not None:
                yield attr, script

    def node(self, node: NodeSpec) -> None:
        if node.type == "?":
            return
        model = self.registry.get(node.type)
        loc = node.type_loc or node.loc
        if model is None:
            self.unknown(node)
            return
        n = len(node.children)
        lo, hi = model.min_children, model.max_children
        if model.kind == SUBTREE:
            lo, hi = 0, 0
        if n < lo or (hi is not None and n > hi):
            if hi == lo:
                want = plural(lo, "child", "children") if lo else "no children"
            elif hi is None:
                want = f"at least {plural(lo, 'child', 'children')}"
            else:
                want = f"{lo} to {hi} children"
            kind = {CONTROL: "control", DECORATOR: "decorator"}.get(model.kind, model.kind.lower())
            article = "an" if kind[:1] in "aeiou" else "a"
            self.add(loc, f"{node.type} is {article} {kind} node and takes {want}; found {n}")
        for key, attr in node.attrs.items():
            if key in CONDITION_ATTRS:
                err = check_script(str(attr.value))
                if err:
                    self.add(attr.loc, f"{key}: bad script {attr.value!r}: {err}")
        if model.kind == SUBTREE:
            self.subtree(node)
            return
        for key, attr in node.attrs.items():
            if key in SPECIAL_ATTRS or key in CONDITION_ATTRS:
                continue
            port = model.ports.get(key)
            if port is None:
                hint = suggest_name(key, list(model.ports))
                if key.startswith("_"):  # a pre/post-condition in the wrong case: _skipif
                    same = [a for a in CONDITION_ATTRS if a.lower() == key.lower()]
                    hint = same[0] if same else suggest_name(key, list(CONDITION_ATTRS)) or hint
                known = ", ".join(model.ports) or "none"
                self.add(
                    attr.loc,
                    f"{node.type} has no port '{key}' (ports: {known})"
                    + (f"; did you mean '{hint}'?" if hint else ""),
                )
                continue
            ref = blackboard_ref(attr.value)
            if ref is not None:
                continue
            if isinstance(attr.value, str) and attr.value.strip().startswith("{"):
                self.add(
                    attr.loc,
                    f"port '{key}': {attr.value!r} is not a valid blackboard reference "
                    "(expected {entry_name})",
                )
                continue
            if port.writes and not port.takes_literal:
                self.add(
                    attr.loc,
                    f"output port '{key}' of {node.type} is bound to the literal "
                    f"{attr.value!r}; expected a blackboard entry such as {{{key}}}",
                )
                continue
            try:
                value = port.type.convert(attr.value)
            except PortValueError as exc:
                self.add(attr.loc, f"port '{key}' of {node.type}: {exc}")
                continue
            except Exception as exc:  # noqa: BLE001 - a plug-in's port type: said, located
                self.add(attr.loc, conversion_said(port, node.type, attr.value, exc))
                continue
            outside = port.out_of_range(value) if port.reads else None
            if outside is not None:  # a literal: the file alone says it, no rig needed
                self.add(attr.loc, f"port '{key}' of {node.type}: {outside}")
                continue
            if node.type in ("Script", "ScriptCondition") and key == "code":
                err = check_script(str(attr.value))
                if err:
                    self.add(attr.loc, f"bad script {attr.value!r}: {err}")
        if node.type in ("Parallel", "ParallelAll"):
            self.parallel_counts(node, n)
        for port in model.ports.values():
            if port.required and port.name not in node.attrs:
                self.add(
                    loc,
                    f"{node.type} needs port '{port.name}' ({port.type.expected}"
                    + (f": {port.description}" if port.description else "")
                    + ")",
                )

    def parallel_counts(self, node: NodeSpec, children: int) -> None:
        """A literal count a Parallel cannot reach with its children: BehaviorTree.CPP (and
        btrun, tick for tick like it) raise when it is first ticked, which aborts the run;
        warned before flight (a count from the blackboard is only known then)."""
        for key in ("success_count", "failure_count", "max_failures"):
            attr = node.attrs.get(key)
            if attr is None or blackboard_ref(attr.value) is not None:
                continue
            try:
                value = int(str(attr.value).strip(), 10)
            except ValueError:
                continue  # said by the port's own check
            need = max(children + value + 1, 0) if value < 0 else value
            if need > children:
                self.warn(
                    attr.loc,
                    f"{node.type} {key}={value} but only {plural(children, 'child', 'children')}: "
                    "the run aborts when it is first ticked",
                )

    def subtree(self, node: NodeSpec) -> None:
        ident = node.attrs.get("ID")
        if ident is None:
            self.add(node.loc, 'SubTree needs an ID attribute naming a <BehaviorTree> (ID="...")')
            return
        target = str(ident.value)
        if target not in self.spec.trees:
            hint = suggest_name(target, list(self.spec.trees))
            self.add(
                ident.loc,
                f"SubTree '{target}' is not defined in this mission "
                f"(trees: {', '.join(sorted(self.spec.trees)) or 'none'})"
                + (f"; did you mean '{hint}'?" if hint else ""),
            )
            return
        model = self.spec.models.get(target)
        auto = node.attrs.get("_autoremap")
        if auto is not None and str(auto.value).strip().lower() not in ("true", "false", "1", "0"):
            self.add(  # BehaviorTree.CPP throws; anything else read as false hid the entries
                auto.loc,
                f"_autoremap {auto.value!r}: expected true or false",
            )
        for key, attr in node.attrs.items():
            if key in ("ID", "_autoremap") or key in SPECIAL_ATTRS or key in CONDITION_ATTRS:
                continue
            if key.startswith("_"):
                self.add(attr.loc, f"unknown attribute '{key}' on SubTree")
                continue
            if model is not None and key not in model.ports and not key.startswith("__"):
                hint = suggest_name(key, list(model.ports))
                self.add(
                    attr.loc,
                    f"SubTree '{target}' has no port '{key}' (its <TreeNodesModel> declares: "
                    f"{', '.join(model.ports) or 'none'})"
                    + (f"; did you mean '{hint}'?" if hint else ""),
                )
            elif model is not None and model.ports[key].direction != "input":
                if blackboard_ref(attr.value) is None:
                    self.add(
                        attr.loc,
                        f"output port '{key}' of SubTree '{target}' is bound to the literal "
                        f"{attr.value!r}; expected a blackboard entry such as {{{key}}}",
                    )
            elif blackboard_ref(attr.value) is None and not key.startswith("__"):
                self.literal_through_subtree(target, key, attr)
        if model is not None:
            auto = (
                str(node.attrs["_autoremap"].value).lower() in ("true", "1")
                if "_autoremap" in node.attrs
                else False
            )
            for p in model.ports.values():
                if p.name.startswith("__"):
                    continue
                if (
                    p.direction == "input"
                    and p.default is None
                    and p.name not in node.attrs
                    and not auto
                ):
                    self.add(
                        node.loc,
                        f"SubTree '{target}' needs port '{p.name}'"
                        + (f" ({p.description})" if p.description else ""),
                    )

    def literal_through_subtree(self, target: str, key: str, attr: Any) -> None:
        """A literal given to SubTree port ``key`` must convert to the type of every port
        that reads ``{key}`` inside ``target`` (through nested SubTrees too): a two-number
        "vector" handed to a GoTo ``pose`` is an error here, not 7 s into the flight."""
        seen: set[tuple[str, str]] = set()
        todo = [(target, key, [target])]
        while todo:
            tree_id, entry, chain = todo.pop()
            if (tree_id, entry) in seen or len(chain) > MAX_SUBTREE_DEPTH:
                continue
            seen.add((tree_id, entry))
            tree = self.spec.trees.get(tree_id)
            roots = [r for r in ([tree.root, *tree.extra_roots] if tree else []) if r]
            for node in (n for r in roots for n in r.walk()):
                for pname, a in node.attrs.items():
                    if blackboard_ref(a.value) != entry:
                        continue
                    if node.type == "SubTree":
                        inner = node.attrs.get("ID")
                        if inner is not None and str(inner.value) in self.spec.trees:
                            todo.append((str(inner.value), pname, [*chain, str(inner.value)]))
                        continue
                    model = self.registry.get(node.type)
                    port = model.ports.get(pname) if model is not None else None
                    if port is None or not port.reads:
                        continue
                    try:
                        port.type.convert(attr.value)
                    except Exception as exc:  # noqa: BLE001 - a plug-in's type too: said
                        via = " -> ".join(chain)
                        why = exc if isinstance(exc, PortValueError) else said(exc, None)
                        self.add(
                            attr.loc,
                            f"SubTree port '{key}' = {_brief(attr.value)} is read as port "
                            f"'{pname}' of {node.type} ({a.loc}, in {via}): {why}",
                        )
                        return

    def unknown(self, node: NodeSpec) -> None:
        loc = node.type_loc or node.loc
        if node.type in self.spec.trees:
            self.add(
                loc,
                f"'{node.type}' is a tree of this mission; use it as <SubTree ID=\"{node.type}\"/>",
            )
            return
        if node.type in self.spec.models:
            self.add(
                loc,
                f"node '{node.type}' is declared in <TreeNodesModel> but btrun has no "
                "implementation of it (is the package that provides it installed?)",
            )
            return
        hint = self.registry.suggest(node.type)
        self.add(
            loc,
            f"unknown node '{node.type}'"
            + (f"; did you mean '{hint}'?" if hint else "")
            + " (btrun nodes lists them all"
            + ("" if hint else "; a plug-in's node needs its plug-in named in BTRUN_PLUGINS")
            + ")",
        )


def _file_loc(spec: MissionSpec) -> Loc:
    return Loc(spec.file, 1, 1)


def validate(
    spec: MissionSpec, registry: Registry, warnings: list[Problem] | None = None
) -> list[Problem]:
    """Return every error of ``spec`` (empty if it can run).

    Warnings (``severity="warning"``: the mission runs) are appended to ``warnings`` if a
    list is given.
    """
    v = _Validator(spec, registry)
    problems = v.run()
    if warnings is not None:
        warnings.extend(v.warnings)
    return problems


def referenced_entries(spec: MissionSpec, registry: Registry) -> set[str]:
    """Every blackboard entry the mission's trees name: ``{name}`` on any port (``{=}``
    names the port itself; ``{@name}`` the root scope's ``name``) and the entries valid
    scripts read, in every tree, whatever the scope."""
    v = _Validator(spec, registry)
    names: set[str] = set()
    for node in v.nodes():
        for _, script in v.scripts(node):
            names.update(script.reads)
        for key, attr in node.attrs.items():
            ref = blackboard_ref(attr.value)
            if ref is not None:
                names.add(key if ref == "=" else ref)
    return {n.lstrip("@") for n in names if n.lstrip("@")}


def port_read_entries(spec: MissionSpec, registry: Registry) -> set[str]:
    """The entries some node's input port reads (``{name}``), in any tree: their values are
    checked by those ports, which say where they are read."""
    names: set[str] = set()
    for tree in spec.trees.values():
        for root in (r for r in (tree.root, *tree.extra_roots) if r is not None):
            for node in root.walk():
                model = registry.get(node.type)
                if model is None or model.kind == SUBTREE:
                    continue
                for key, attr in node.attrs.items():
                    ref = blackboard_ref(attr.value)
                    port = model.ports.get(key)
                    if ref is not None and port is not None and port.reads:
                        names.add((key if ref == "=" else ref).lstrip("@"))
    return names


def written_entries(spec: MissionSpec, registry: Registry) -> set[str] | None:
    """Every entry something in the mission may write, whatever the scope; None when a
    SetBlackboard's key is chosen at run time (:meth:`_Validator.written`)."""
    return _Validator(spec, registry).written()


def root_inputs(spec: MissionSpec, registry: Registry) -> tuple[set[str], dict[str, Any]]:
    """``(names, inner)``: the entries the mission names that are on its root blackboard
    (what ``--set`` can change), and where the others are named (inside SubTrees that never
    see the root's entry; :func:`bt_engine.root_entries.root_entries`)."""
    v = _Validator(spec, registry)

    def reads_of(node: NodeSpec):
        for attr, script in v.scripts(node):
            for name in sorted(script.reads):
                yield name, attr.loc

    found = root_entries(spec, reads_of)
    if found is None:
        return referenced_entries(spec, registry), {}
    names, inner = found
    return {n for n in names if n}, inner


__all__ = [
    "validate",
    "check_script",
    "referenced_entries",
    "root_inputs",
    "written_entries",
    "port_read_entries",
    "CONDITION_ATTRS",
    "KNOWN_ENTRIES",
    "NO_DEFAULT",
]


def _brief(value: Any, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
