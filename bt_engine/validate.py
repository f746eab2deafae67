"""Check a mission spec against the node registry before anything runs.

Every problem is collected (never just the first) and located ``file:line:col``, with the
offending value and what was expected. Nothing runs while any problem remains.
"""

from __future__ import annotations

from bt_engine.ports import NO_DEFAULT, PortValueError, blackboard_ref
from bt_engine.registry import CONTROL, DECORATOR, SUBTREE, Registry, suggest_name
from bt_engine.spec import MissionSpec, NodeSpec, Problem

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
    """Return an error message if ``code`` is not a valid script, else None."""
    from bt_engine.script import ScriptError, parse_script

    try:
        parse_script(code)
    except ScriptError as exc:
        where = f" at column {exc.column + 1}" if exc.column >= 0 else ""
        return f"{exc.message if hasattr(exc, 'message') else exc}{where}"
    return None


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" + ("" if n == 1 else "s")


class _Validator:
    def __init__(self, spec: MissionSpec, registry: Registry) -> None:
        self.spec = spec
        self.registry = registry
        self.problems: list[Problem] = list(spec.load_problems)

    def add(self, loc, message: str) -> None:
        self.problems.append(Problem(loc, message))

    def run(self) -> list[Problem]:
        spec = self.spec
        if not spec.trees and not spec.load_problems:
            self.add(spec.root_loc or _file_loc(spec), "the mission has no <BehaviorTree>")
        main = spec.main_tree_id()
        if spec.trees and main is None:
            self.add(
                spec.root_loc or _file_loc(spec),
                "no main tree: set main_tree_to_execute to one of " + ", ".join(sorted(spec.trees)),
            )
        elif main is not None and main not in spec.trees and spec.trees:
            hint = suggest_name(main, list(spec.trees))
            self.add(
                spec.root_loc or _file_loc(spec),
                f"main tree '{main}' is not defined (trees: {', '.join(sorted(spec.trees))})"
                + (f"; did you mean '{hint}'?" if hint else ""),
            )
        for tree in spec.trees.values():
            for extra in tree.extra_roots:
                self.add(
                    extra.loc,
                    f"tree '{tree.id}' has {1 + len(tree.extra_roots)} root nodes; a "
                    "<BehaviorTree> takes exactly one (wrap them in a Sequence)",
                )
            if tree.root is not None:
                for node in tree.root.walk():
                    self.node(node)
        if main in spec.trees:
            self.cycles(main, [main])
        return sorted(
            set(self.problems), key=lambda p: (p.loc.file, p.loc.line, p.loc.col, p.message)
        )

    def cycles(self, tree_id: str, chain: list[str]) -> None:
        root = self.spec.trees[tree_id].root
        if root is None:
            return
        for node in root.walk():
            if node.type != "SubTree":
                continue
            sub = node.attrs.get("ID")
            if sub is None or sub.value not in self.spec.trees:
                continue
            target = str(sub.value)
            if target in chain:
                self.add(sub.loc, "recursive SubTree: " + " -> ".join(chain + [target]))
                continue
            self.cycles(target, chain + [target])

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
                want = _plural(lo, "child") if lo else "no children"
            elif hi is None:
                want = f"at least {_plural(lo, 'child')}"
            else:
                want = f"{lo} to {hi} children"
            kind = {CONTROL: "control", DECORATOR: "decorator"}.get(model.kind, model.kind.lower())
            self.add(loc, f"{node.type} is a {kind} node and takes {want}; found {n}")
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
            if port.writes:
                self.add(
                    attr.loc,
                    f"output port '{key}' of {node.type} is bound to the literal "
                    f"{attr.value!r}; expected a blackboard entry such as {{{key}}}",
                )
                continue
            try:
                port.type.convert(attr.value)
            except PortValueError as exc:
                self.add(attr.loc, f"port '{key}' of {node.type}: {exc}")
                continue
            if node.type in ("Script", "ScriptCondition") and key == "code":
                err = check_script(str(attr.value))
                if err:
                    self.add(attr.loc, f"bad script {attr.value!r}: {err}")
        for port in model.ports.values():
            if port.required and port.name not in node.attrs:
                self.add(
                    loc,
                    f"{node.type} needs port '{port.name}' ({port.type.expected}"
                    + (f": {port.description}" if port.description else "")
                    + ")",
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
            + " (btrun nodes lists them all)",
        )


def _file_loc(spec: MissionSpec):
    from bt_engine.spec import Loc

    return Loc(spec.file, 1, 1)


def validate(spec: MissionSpec, registry: Registry) -> list[Problem]:
    """Return every problem of ``spec`` (empty if it can run)."""
    return _Validator(spec, registry).run()


__all__ = ["validate", "check_script", "CONDITION_ATTRS", "NO_DEFAULT"]
